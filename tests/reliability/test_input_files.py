"""Reliability of the inputs: bounded reads, every CSV layout a user's tool writes (BOM, column order, text
columns, line ends; refused: duplicate columns, other separators named), time columns checked (holes, milliseconds,
jitter), a constant output refused, one-line messages that name the file, and the staircase log accepted by
`rig identify output-backlash --steady`."""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rig import exit_codes
from rig.cli import main
from rig.log_file import read_experiment_data, read_input_output, read_log, write_log
from rig.protocols.errors import LogFileError
from rig.signal_files import MAX_LINE_BYTES, read_signal_table

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _error(capsys, code: int, expected_code: int, *parts: str) -> str:
    err = capsys.readouterr().err
    assert code == expected_code, err
    assert err.startswith("rig: error: ") and err.count("\n") == 1 and len(err) < 700, err
    for part in parts:
        assert part in err, err
    return err


def _signals(n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    u = np.repeat(rng.uniform(-1, 1, n // 20 + 1), 20)[:n]
    y = np.convolve(u, [0.0, 0.3, 0.2, 0.1])[:n] + rng.uniform(-1e-4, 1e-4, n)
    return t, u, y


# --- bounded reads ------------------------------------------------------------------------------------------

def test_dev_zero_a_sparse_file_and_a_directory_are_refused_at_once(tmp_path, capsys):
    if Path("/dev/zero").exists():
        _error(capsys, main(["inspect", "/dev/zero"]), exit_codes.BAD_INPUT, "/dev/zero: is a character device, "
               "not a regular file")
    sparse = tmp_path / "sparse.csv"
    with sparse.open("wb") as handle:
        handle.truncate(2 << 30)  # 2 GB of zeros, no disk used
    _error(capsys, main(["inspect", str(sparse)]), exit_codes.BAD_INPUT, "not a CSV file (NUL bytes at byte 0)")
    _error(capsys, main(["diagnose", str(tmp_path), "--noise-bound", "0.01"]), exit_codes.BAD_INPUT,
           f"{tmp_path}: is a directory")
    crashed = tmp_path / "crashed.csv"  # a power cut can leave zeros after the last written block
    crashed.write_bytes(b"t,u,y\n0,1,2\n0.001,1,2\n" + b"\0" * 4096)
    _error(capsys, main(["inspect", str(crashed)]), exit_codes.BAD_INPUT, "NUL bytes at byte 22")
    endless = tmp_path / "endless.csv"
    endless.write_bytes(b"t,u,y\n" + b"1" * (MAX_LINE_BYTES + 10))
    _error(capsys, main(["inspect", str(endless)]), exit_codes.BAD_INPUT, "line 2 is longer than")


def test_a_rig_log_padded_with_zeros_names_the_byte(tmp_path):
    from identify.experiment_record import ExperimentMetadata, ExperimentRecord

    t, u, y = _signals(20)
    path = tmp_path / "log.csv"
    write_log(path, ExperimentRecord(t, u, y, None, None, ExperimentMetadata(sample_period_s=1e-3)))
    size = path.stat().st_size
    with path.open("ab") as handle:
        handle.write(b"\0" * 100)
    with pytest.raises(LogFileError, match=f"NUL bytes at byte {size}"):
        read_log(path)


# --- CSV layouts --------------------------------------------------------------------------------------------

extra_columns = st.lists(st.sampled_from(["note", "temperature", "date", "empty"]), unique=True, max_size=3)


@FAST
@given(order=st.permutations(["t", "u", "y"]), extra=extra_columns, bom=st.booleans(),
       newline=st.sampled_from(["\n", "\r\n"]), comment=st.booleans())
def test_every_column_layout_is_read_alike(tmp_path, order, extra, bom, newline, comment):
    t, u, y = _signals(40)
    values = {"t": t, "u": u, "y": y}
    cells = {"note": lambda k: "ok" if k % 3 else "step here", "temperature": lambda k: f"{20 + k * 0.01:.2f}",
             "date": lambda k: f"2026-12-01T10:00:{k % 60:02d}", "empty": lambda k: ""}
    names = [*order, *extra]
    rows = [",".join(names)] + [",".join(repr(float(values[name][k])) if name in values else cells[name](k)
                                         for name in names) for k in range(t.size)]
    text = ("# exported\n" if comment else "") + newline.join(rows) + newline
    path = tmp_path / "layout.csv"
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
    record = read_experiment_data(path)
    np.testing.assert_array_equal(record.command_rad, u)
    np.testing.assert_array_equal(record.angle_rad, y)
    got_u, got_y = read_input_output(path)
    np.testing.assert_array_equal(got_u, u)
    table = read_signal_table(path, ("u", "y"))
    assert ("temperature" in table) == ("temperature" in extra)  # numbers kept, text ignored
    assert not {"note", "date", "empty"} & set(table)


@FAST
@given(columns=st.lists(st.sampled_from(["t", "u", "y", "x"]), min_size=4, max_size=6).filter(
    lambda names: {"t", "u", "y"} <= set(names) and len(set(names)) < len(names)))
def test_a_column_given_twice_is_refused(tmp_path, columns):
    path = tmp_path / "twice.csv"
    path.write_text(",".join(columns) + "\n" + ",".join(["0"] * len(columns)) + "\n")
    repeated = sorted(name for name in columns if columns.count(name) > 1)[0]
    with pytest.raises(LogFileError, match=f"column {repeated} appears {columns.count(repeated)} times"):
        read_signal_table(path, ("u", "y"))


@FAST
@given(encoding=st.sampled_from(["utf-8", "utf-8-sig", "utf-16", "latin-1", "cp1252"]),
       note=st.sampled_from(["plain", "température", "Drehmoment µ"]))
def test_utf8_with_or_without_bom_is_read_and_other_encodings_are_named(tmp_path, encoding, note):
    t, u, y = _signals(20)
    text = f"# {note}\nt,u,y\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t.tolist(), u.tolist(), y.tolist()))
    path = tmp_path / "encoded.csv"
    path.write_bytes(text.encode(encoding))
    if encoding.startswith("utf-8") or (note == "plain" and encoding != "utf-16"):
        np.testing.assert_array_equal(read_experiment_data(path).angle_rad, y)
        return
    first = 2 + next((k for k, character in enumerate(note) if ord(character) > 127), 0)  # after "# "
    expected = ("the file is UTF-16 encoded" if encoding == "utf-16"
                else f"not a text file \\(byte {first} is not UTF-8\\); expected a CSV file \\(save it as UTF-8\\)")
    with pytest.raises(LogFileError, match=expected):
        read_experiment_data(path)


@pytest.mark.parametrize("separator, decimal, expected", [
    (";", ".", "looks like ';'-separated: write it with ','"),
    (";", ",", "looks like ';'-separated with decimal commas"),
    ("\t", ".", "looks like tab-separated"),
    (",", ",", "decimal commas (0,5)"),
])
def test_other_separators_and_decimal_commas_are_named_with_the_fix(tmp_path, capsys, separator, decimal,
                                                                    expected):
    t, u, y = _signals(30)
    rows = [separator.join(["t", "u", "y"])] + [separator.join(f"{v:.4f}".replace(".", decimal) for v in row)
                                                for row in zip(t, u, y)]
    path = tmp_path / "other.csv"
    path.write_text("\n".join(rows) + "\n")
    _error(capsys, main(["inspect", str(path)]), exit_codes.BAD_INPUT, str(path), expected)


def test_bom_and_text_columns_are_accepted_by_every_command(tmp_path, capsys):
    t, u, y = _signals(400)
    path = tmp_path / "bom.csv"
    path.write_bytes(b"\xef\xbb\xbf" + ("t,u,y,comment\n" + "".join(
        f"{a!r},{b!r},{c!r},{'hold' if k < 20 else 'run'}\n"
        for k, (a, b, c) in enumerate(zip(t.tolist(), u.tolist(), y.tolist())))).encode())
    assert main(["inspect", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["samples"] == 400
    from identify.experiment_record import ExperimentMetadata, ExperimentRecord

    log = tmp_path / "log.csv"
    write_log(log, ExperimentRecord(t, u, y, None, None, ExperimentMetadata(sample_period_s=1e-3)))
    bom_log = tmp_path / "bom_log.csv"
    bom_log.write_bytes(b"\xef\xbb\xbf" + log.read_bytes())
    assert main(["inspect", str(bom_log), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["samples"] == 400


# --- time columns -------------------------------------------------------------------------------------------

def _write(path: Path, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> Path:
    path.write_text("t,u,y\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t.tolist(), u.tolist(), y.tolist())))
    return path


@FAST
@given(hole_at=st.integers(20, 250), missing=st.integers(1, 1000))
def test_a_hole_in_t_is_refused_naming_the_row_and_the_samples_missing(tmp_path, hole_at, missing):
    t, u, y = _signals()
    t = t.copy()
    t[hole_at:] += missing * 1e-3
    path = _write(tmp_path / "hole.csv", t, u, y)
    with pytest.raises(LogFileError, match=f"data row {hole_at + 1}: a hole: .*about {missing} samples missing"):
        read_experiment_data(path)


@FAST
@given(scale=st.sampled_from([1e3, 1e6]), rate=st.sampled_from([100.0, 1000.0, 10000.0]))
def test_t_in_milliseconds_or_microseconds_is_refused_with_the_conversion(tmp_path, scale, rate):
    t, u, y = _signals()
    path = _write(tmp_path / "ms.csv", np.arange(t.size) / rate * scale, u, y)
    if scale / rate < 1.0:  # 10 kHz in ms steps by 0.1: a legitimate-looking period, nothing to tell
        read_experiment_data(path)
        return
    with pytest.raises(LogFileError, match="t must be in seconds; if it is in milliseconds, divide it by 1000"):
        read_experiment_data(path)


@FAST
@given(spread=st.floats(0.02, 0.3), seed=st.integers(0, 100))
def test_uneven_t_gives_a_warning_with_the_spread_and_a_wild_one_is_refused(tmp_path, spread, seed):
    t, u, y = _signals()
    rng = np.random.default_rng(seed)
    steps = 1e-3 * (1 + rng.uniform(-spread, spread, t.size - 1))
    steps[0] = 1e-3 * (1 + spread)
    path = _write(tmp_path / "uneven.csv", np.concatenate([[0.0], np.cumsum(steps)]), u, y)
    with pytest.warns(UserWarning, match=r"column t is uneven \(steps from .* spread [0-9.]+ %\)"):
        record = read_experiment_data(path)
    assert record.sample_period_s == pytest.approx(1e-3, rel=spread)
    steps[5] = 3e-4  # two samples at nearly one instant
    _write(path, np.concatenate([[0.0], np.cumsum(steps)]), u, y)
    with pytest.raises(LogFileError, match="data row 7: t steps by only"):
        read_experiment_data(path)


def test_a_rig_log_with_a_hole_names_the_line_and_the_metadata_period(tmp_path):
    from identify.experiment_record import ExperimentMetadata, ExperimentRecord

    t, u, y = _signals(50)
    t = t.copy()
    t[30:] += 1.0  # a second cut out
    path = tmp_path / "cut.csv"
    write_log(path, ExperimentRecord(t, u, y, None, None, ExperimentMetadata(sample_period_s=1e-3)))
    with pytest.raises(LogFileError, match="line 35: time_s steps by 1.001 s .* the metadata .* says the period is"):
        read_log(path)


def test_the_warning_is_one_line_note_on_the_command_line(tmp_path, capsys):
    _, u, y = _signals(400)
    hold = tmp_path / "hold.csv"  # 5 % jitter: a warning, not a refusal
    hold_u = np.concatenate([np.full(40, -1.0), u])
    hold_t = np.concatenate([[0.0], np.cumsum(1e-3 * (1 + 0.05 * (np.arange(hold_u.size - 1) % 2)))])
    _write(hold, hold_t, hold_u, np.concatenate([np.full(40, -0.6), y]))
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        code = main(["identify", "hammerstein", str(hold), "--json"])
    err = capsys.readouterr().err
    assert code in (exit_codes.SUCCESS, exit_codes.BAD_INPUT), err  # the note comes first, whatever follows
    notes = [line for line in err.splitlines() if line.startswith("rig: note: ")]
    assert notes and "column t is uneven" in notes[0], err
    assert "warnings.warn" not in err and "UserWarning" not in err


# --- a constant output --------------------------------------------------------------------------------------

def test_a_constant_output_asks_whether_the_encoder_is_connected(tmp_path, capsys):
    t, u, _ = _signals(400)
    u = np.concatenate([np.full(40, -1.0), u[40:]])
    path = _write(tmp_path / "unplugged.csv", t, u, np.zeros_like(u))
    for command in (["diagnose", str(path), "--noise-bound", "0.001"], ["identify", "hammerstein", str(path)]):
        _error(capsys, main(command), exit_codes.BAD_INPUT, str(path), "the output is constant",
               "is the encoder connected?")


# --- messages -----------------------------------------------------------------------------------------------

def test_messages_name_the_file_and_stay_on_one_short_line(tmp_path, capsys):
    plant = tmp_path / "plant.toml"
    plant.write_bytes(b'name = "caf\xe9"\n')
    data = _write(tmp_path / "data.csv", *_signals(400))
    _error(capsys, main(["diagnose", str(data), "--noise-bound", "0.001", "--model", str(plant)]),
           exit_codes.BAD_INPUT, f"{plant}: [<file>] not a text file (byte 11 is not UTF-8)")
    from identify.experiment_record import ExperimentMetadata, ExperimentRecord

    t, u, y = _signals(30)
    log = tmp_path / "log.csv"
    write_log(log, ExperimentRecord(t, u, y, None, None, ExperimentMetadata(sample_period_s=1e-3)))
    lines = log.read_text().splitlines()
    for flag, expected in (("999", "line 10, column flags: 999 is not a combination of the SampleFlag bits"),):
        damaged = lines[:9] + [lines[9].rsplit(",", 1)[0] + "," + flag] + lines[10:]
        log.write_text("\n".join(damaged) + "\n")
        _error(capsys, main(["inspect", str(log)]), exit_codes.BAD_INPUT, expected)
    big = tmp_path / "big.json"
    big.write_text(json.dumps({"backlash": {"m_l": list(range(30_000))}, "linear": {}, "method": "paper"}))
    _error(capsys, main(["report", str(big), "--out", str(tmp_path / "r1")]), exit_codes.BAD_INPUT, str(big))
    keys = tmp_path / "keys.json"
    keys.write_text(json.dumps({f"key{k}": k for k in range(20_000)}))
    _error(capsys, main(["report", str(keys), "--out", str(tmp_path / "r2")]), exit_codes.BAD_INPUT, str(keys))


@pytest.fixture(scope="module")
def hammerstein_document():
    from identify.border_lifting import PathNodes
    from identify.cyclic_excitation import cyclic_random_excitation
    from identify.hammerstein_subspace import identify_hammerstein
    from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash

    u = cyclic_random_excitation(1200, -3.0, 3.0, hold_samples=50, rng=0)
    G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)
    y = PlantModel((pouliquen2013_backlash(), G)).simulate(u)
    return identify_hammerstein(u, y, PathNodes.uniform(-3.0, 3.0, 8), hold_samples=50).to_dict()


@pytest.mark.parametrize("damage, expected", [
    ({"A": [[0.5]]}, "A: expected 2 x 2 finite numbers, got shape (1, 1)"),
    ({"singular_values": ["x"]}, "singular_values: expected numbers, got ['x']"),
    ({"order": "two"}, "order is 'two', expected an integer >= 1"),
    ({"mu_ascending": [1.0, 2.0]}, "mu_ascending: expected 7 finite numbers, got shape (2,)"),
    ({"nodes": {"ascending": [0.0, 1.0]}}, "key 'descending' is missing"),
])
def test_a_malformed_result_json_is_named_before_anything_is_drawn(tmp_path, capsys, hammerstein_document, damage,
                                                                   expected):
    path = tmp_path / "model.json"
    path.write_text(json.dumps({**hammerstein_document, **damage}))
    _error(capsys, main(["report", str(path), "--out", str(tmp_path / "r")]), exit_codes.BAD_INPUT,
           f"{path}: kind 'hammerstein_model': ", expected, "write it again with the command that made it")
    assert not (tmp_path / "r" / "index.html").exists()
    path.write_text('{"order": 2,\n "poles": [1, 2,]}')
    _error(capsys, main(["report", str(path), "--out", str(tmp_path / "r")]), exit_codes.BAD_INPUT,
           f"{path}: line 2, column 17: invalid JSON")


def test_orders_beyond_the_record_and_an_unreachable_feasible_set_are_explained():
    from identify.feasible_parameter_set import bound_backlash_parameters
    from identify.linear_block_bounds import bound_linear_block
    from identify.validation import InvalidInputError

    u = np.array([1.0, 2, 3, -1, -2, -3])
    result = bound_backlash_parameters(u, np.array([3.0, 2, 1, -1, -2, -3]), 1e-300)
    assert result.is_empty and "inf" not in result.explanation.message
    assert "noise bound is in radians and not far too small" in result.explanation.message
    with pytest.raises(InvalidInputError, match="need 1000000000 past samples before the first equation, but the "
                                                "record has 50 samples") as caught:
        bound_linear_block(np.ones(50), np.zeros(50), np.ones(50), na=1_000_000_000, nk=1, nb=2)
    assert "-9" not in str(caught.value)


# --- the staircase log --------------------------------------------------------------------------------------

def test_the_staircase_log_is_accepted_by_steady_and_the_points_are_counted(tmp_path, capsys):
    from identify.excitation_design import filtered_staircase, staircase_steady_state_indices
    from rig.commands.identify_output_backlash import staircase_steady_points

    plant = CONFIGS / "plants" / "cerone2009.toml"
    logs = {}
    for name in ("steady_staircase", "prbs"):
        logs[name] = tmp_path / f"{name}.csv"
        assert main(["simulate", str(plant), "--excitation", str(CONFIGS / "experiments" / f"{name}.toml"),
                     "--out", str(logs[name]), "--json"]) == 0
    capsys.readouterr()
    code = main(["identify", "output-backlash", "--steady", str(logs["steady_staircase"]), "--dynamic",
                 str(logs["prbs"]), "--noise-bound", "0.0015339815193446808", "--na", "2", "--nk", "1", "--nb", "2",
                 "--method", "paper"])
    out = capsys.readouterr().out
    assert code == exit_codes.SUCCESS, out
    assert "(100 points: the end of each half-wave of 100 samples of the staircase log)" in out
    u, y, _ = staircase_steady_points(logs["steady_staircase"])
    ends = staircase_steady_state_indices(50, 100)
    np.testing.assert_allclose(u, filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)[ends])
    np.testing.assert_array_equal(y, read_log(logs["steady_staircase"]).angle_rad[ends])
    _error(capsys, main(["identify", "output-backlash", "--steady", str(logs["prbs"]), "--dynamic", str(logs["prbs"]),
                         "--noise-bound", "0.0015", "--na", "2", "--nk", "1", "--nb", "2"]), exit_codes.BAD_INPUT,
           "this log's excitation is prbs")


def test_a_lost_end_sample_is_taken_from_the_settled_tail(tmp_path):
    from identify.experiment_record import SampleFlag
    from rig.commands.identify_output_backlash import staircase_steady_points

    path = tmp_path / "stair.csv"
    assert main(["simulate", str(CONFIGS / "plants" / "cerone2009.toml"), "--excitation",
                 str(CONFIGS / "experiments" / "steady_staircase.toml"), "--out", str(path), "--json"]) == 0
    record = read_log(path)
    flags = record.flags.copy()
    flags[99] = SampleFlag.LOST  # the end of the first half-wave
    angle = record.angle_rad.copy()
    angle[99] = np.nan
    from dataclasses import replace

    write_log(path, replace(record, flags=flags, angle_rad=angle))
    u, y, description = staircase_steady_points(path)
    assert y[0] == record.angle_rad[98] and u.size == 100
    assert "1 of them taken up to 9 samples early" in description


def test_a_half_wave_whose_whole_settled_tail_is_lost_is_left_out_not_the_whole_log(tmp_path):
    """A burst of LOST samples over one half-wave's settled tail costs that steady-state point only (leaving a
    point out can only widen the feasible set): the rest are bounded and the description says which was left
    out; a log with fewer than two usable points left is refused, saying how many."""
    from dataclasses import replace

    from identify.experiment_record import SampleFlag
    from rig.commands.identify_output_backlash import staircase_steady_points

    path = tmp_path / "stair.csv"
    assert main(["simulate", str(CONFIGS / "plants" / "cerone2009.toml"), "--excitation",
                 str(CONFIGS / "experiments" / "steady_staircase.toml"), "--out", str(path), "--json"]) == 0
    record = read_log(path)
    flags, angle = record.flags.copy(), record.angle_rad.copy()
    flags[170:230], angle[170:230] = SampleFlag.LOST, np.nan  # the whole tail of the second half-wave (190-199)
    write_log(path, replace(record, flags=flags, angle_rad=angle))
    u, y, description = staircase_steady_points(path)
    assert u.size == 99 and y[1] == record.angle_rad[299]
    assert "1 half-wave left out (line 204: its whole settled tail LOST or unusable)" in description
    flags[:], angle[:] = SampleFlag.LOST, np.nan
    flags[90:100], angle[90:100] = record.flags[90:100], record.angle_rad[90:100]
    write_log(path, replace(record, flags=flags, angle_rad=angle))
    with pytest.raises(ValueError, match=r"1 of the 100 half-waves has a usable settled tail"):
        staircase_steady_points(path)


# --- progress -----------------------------------------------------------------------------------------------

def test_diagnose_shows_its_steps_on_a_terminal(tmp_path, capsys, monkeypatch):
    from identify.discrepancy_cases import hidden_effect_record

    record = hidden_effect_record(("backlash",), 3, num_samples=1500)
    data = _write(tmp_path / "data.csv", np.arange(record.command_rad.size) * record.sample_period_s,
                  record.command_rad, record.angle_rad)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert main(["diagnose", str(data), "--noise-bound", repr(record.noise_bound_rad)]) == 0
    err = capsys.readouterr().err
    assert f"rig: diagnosing {data} (1500 samples" in err
    assert "s] start: linear model of order" in err and "s] added backlash" in err
