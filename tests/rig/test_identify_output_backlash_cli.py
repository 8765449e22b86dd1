"""``rig identify output-backlash``: JSON fields of the issue, table output, empty set exit code, bad input."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.output_backlash_identification import OutputBacklashIdentification
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from rig import exit_codes
from rig.cli import main

PLANT = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
NOISE = 2 * np.pi / 2**12


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cerone")
    rng = np.random.default_rng(0)
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    steady_y = PLANT.simulate(staircase)[steady] + rng.uniform(-NOISE, NOISE, steady.size)
    order = rng.permutation(steady.size)  # positive and negative half-waves mixed
    steady_csv = folder / "steady.csv"
    steady_csv.write_text("u,y\n" + "".join(f"{float(staircase[steady][k])!r},{float(steady_y[k])!r}\n" for k in order))
    u = prbs_sequence(100, 1.0, rng=rng)
    y = PLANT.simulate(u) + rng.uniform(-NOISE, NOISE, u.size)
    dynamic_csv = folder / "dynamic.csv"
    dynamic_csv.write_text("t,u,y\n" + "".join(f"{0.01 * k!r},{float(a)!r},{float(b)!r}\n" for k, (a, b) in enumerate(zip(u, y))))
    return steady_csv, dynamic_csv


def _args(files, *extra: str) -> list[str]:
    steady, dynamic = files
    return ["identify", "output-backlash", "--steady", str(steady), "--dynamic", str(dynamic),
            "--noise-bound", repr(NOISE), "--na", "2", "--nk", "1", "--nb", "2", *extra]


def test_json_has_exactly_the_documented_keys_and_bounds_contain_the_truth(files, capsys) -> None:
    assert main(_args(files, "--json")) == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    # the documented keys, the kind and version, the whole result for from_dict, and the samples
    # set aside (none here)
    assert set(document) == {"backlash", "linear", "method", "invertible_samples", "samples", "kind", "version",
                             "noise_bound_rad", "backlash_set", "inner_signal", "linear_bounds", "set_aside"}
    assert document["set_aside"]["samples"] == 0 and document["set_aside"]["equations_left_out"] == 0
    assert (document["kind"], document["version"]) == ("output_backlash", 1)
    reopened = OutputBacklashIdentification.from_dict(document)
    result_document = {key: value for key, value in document.items() if key != "set_aside"}  # set_aside: the data's
    assert reopened.to_dict() == result_document
    assert reopened.linear_intervals["a1"].lower == document["linear"]["a1"]["lower"]
    assert list(document["backlash"]) == ["m_l", "c_l", "m_r", "c_r"]
    assert list(document["linear"]) == ["a1", "a2", "b1", "b2"]
    assert document["method"] == "coupled" and document["samples"] == 100
    assert 50 < document["invertible_samples"] < 100
    truth = {"m_l": 0.248, "c_l": 0.0698, "m_r": 0.252, "c_r": 0.0349, "a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8}
    for group in ("backlash", "linear"):
        for name, bounds in document[group].items():
            assert set(bounds) == {"lower", "upper", "center"}
            assert bounds["lower"] <= truth[name] <= bounds["upper"]
    # how tight each guaranteed interval is: its width over the span of the verified inner values (>= 1)
    linear = document["linear_bounds"]
    ratios = linear["outer_inner_ratio"]
    assert set(ratios) == {"a1", "a2", "b1", "b2"}
    for name, ratio in ratios.items():
        outer = document["linear"][name]
        span = linear["inner_upper"][name] - linear["inner_lower"][name]
        assert ratio == pytest.approx((outer["upper"] - outer["lower"]) / span)
        assert 1.0 - 1e-9 <= ratio < 1.5, (name, ratio)  # 100 samples, 12 bits: close to exact


def test_paper_method_table_output(files, capsys) -> None:
    assert main(_args(files, "--method", "paper")) == exit_codes.SUCCESS
    out = capsys.readouterr().out
    assert "method paper" in out and "half-width" in out
    assert "outer/inner" not in out  # the paper method has no verified inner values
    for name in ("m_l", "c_l", "m_r", "c_r", "a1", "a2", "b1", "b2"):
        assert f"\n{name} " in out


def test_too_small_noise_bound_exits_with_the_explanation(files, capsys) -> None:
    steady, dynamic = files
    code = main(["identify", "output-backlash", "--steady", str(steady), "--dynamic", str(dynamic),
                 "--noise-bound", "1e-5", "--na", "2", "--nk", "1", "--nb", "2"])
    assert code == exit_codes.EMPTY_FEASIBLE_SET
    err = capsys.readouterr().err
    assert "empty feasible set" in err and "noise bound is too small" in err


def test_bad_input_exits_2_naming_the_problem(files, tmp_path, capsys) -> None:
    broken = tmp_path / "broken.csv"
    broken.write_text("u,z\n1,2\n")
    steady, dynamic = files
    assert main(["identify", "output-backlash", "--steady", str(broken), "--dynamic", str(dynamic),
                 "--noise-bound", "1e-3", "--na", "2", "--nk", "1", "--nb", "2"]) == exit_codes.BAD_INPUT
    assert "missing column(s) y" in capsys.readouterr().err
    assert main(_args(files)[:-6] + ["--na", "2", "--nk", "3", "--nb", "2"]) == exit_codes.BAD_INPUT
    assert "nb: expected nb >= nk" in capsys.readouterr().err


def test_a_per_sample_record_given_as_steady_says_which_option_it_belongs_to(files, capsys) -> None:
    _, dynamic = files
    assert main(["identify", "output-backlash", "--steady", str(dynamic), "--dynamic", str(dynamic),
                 "--noise-bound", repr(NOISE), "--na", "2", "--nk", "1", "--nb", "2"]) == exit_codes.BAD_INPUT
    err = capsys.readouterr().err
    assert "dynamic.csv: --steady takes one row per steady-state point" in err
    assert "this is a per-sample record" in err and "pass a record of every sample as --dynamic" in err


def test_several_pairs_are_bounded_in_parallel_and_a_bad_one_is_reported(files, tmp_path, capsys) -> None:
    steady, dynamic = files
    assert main(_args(files, "--json")) == exit_codes.SUCCESS
    single = json.loads(capsys.readouterr().out)
    copy = tmp_path / "dynamic_copy.csv"
    copy.write_text(dynamic.read_text())
    missing = tmp_path / "missing.csv"
    code = main(["identify", "output-backlash", "--steady", str(steady), "--dynamic", str(dynamic),
                 "--steady", str(steady), "--dynamic", str(missing), "--steady", str(steady), "--dynamic", str(copy),
                 "--noise-bound", repr(NOISE), "--na", "2", "--nk", "1", "--nb", "2", "--jobs", "2", "--json"])
    assert code == exit_codes.BAD_INPUT  # one pair failed; the others still came out
    batch = json.loads(capsys.readouterr().out)
    assert (batch["kind"], batch["version"]) == ("batch", 1)
    results = batch["results"]
    assert [entry["dynamic"] for entry in results] == [str(dynamic), str(missing), str(copy)]
    assert results[0]["bounds"] == single and results[2]["bounds"] == single  # same as one at a time
    assert "missing.csv: no such file (dynamic data)" in results[1]["error"]


def test_unpaired_steady_and_dynamic_files_are_refused(files, capsys) -> None:
    steady, dynamic = files
    code = main(["identify", "output-backlash", "--steady", str(steady), "--steady", str(steady), "--dynamic",
                 str(dynamic), "--noise-bound", repr(NOISE), "--na", "2", "--nk", "1", "--nb", "2"])
    assert code == exit_codes.BAD_INPUT
    assert "give them in pairs (got 2 --steady and 1 --dynamic)" in capsys.readouterr().err


@pytest.fixture(scope="module")
def long_files(tmp_path_factory):
    """A 900-sample record: long enough to be bounded window by window."""
    folder = tmp_path_factory.mktemp("cerone_long")
    rng = np.random.default_rng(3)
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    steady_y = PLANT.simulate(staircase)[steady] + rng.uniform(-NOISE, NOISE, steady.size)
    steady_csv = folder / "steady.csv"
    steady_csv.write_text("u,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(staircase[steady], steady_y)))
    u = prbs_sequence(900, 1.0, rng=rng)
    y = PLANT.simulate(u) + rng.uniform(-NOISE, NOISE, u.size)
    dynamic_csv = folder / "dynamic.csv"
    dynamic_csv.write_text("u,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(u, y)))
    return steady_csv, dynamic_csv


def test_long_record_shows_progress_and_says_which_windowing_it_used(long_files, capsys) -> None:
    assert main(_args(long_files, "--joint-samples", "400", "--windows")) == exit_codes.SUCCESS
    captured = capsys.readouterr()
    assert "method coupled" in captured.out
    assert "windowing          5 windows of 200 samples (overlap 20)" in captured.out
    assert "overlapping parts of 400 samples jointly" in captured.out
    assert "then the box of a partitioned into cells" in captured.out  # 900 samples <= --partition-samples 1000
    assert "outer/inner        not computed: the verified inner values are computed for records bounded with the " \
           "inner signal eliminated (not --windows, few gaps) or of up to --joint-samples (400) samples, this one " \
           "has 900" in captured.out
    assert "window pass 1: 5/5" in captured.err and "joint relaxation of 3 part(s) of up to 400 samples: 3/3" in captured.err
    # --json keeps stdout one JSON object: the documented keys and the result's own; the
    # progress goes to stderr
    assert main(_args(long_files, "--joint-samples", "400", "--partition-samples", "0", "--json", "--windows")
                ) == exit_codes.SUCCESS
    captured = capsys.readouterr()
    assert "partitioned" not in json.loads(captured.out)["linear_bounds"]["windowing"]
    # 900 samples > --joint-samples 400: no verified inner values, so no tightness figure, and the text says so
    assert json.loads(captured.out)["linear_bounds"]["outer_inner_ratio"] is None
    assert set(json.loads(captured.out)) >= {"backlash", "linear", "method", "invertible_samples", "samples", "kind",
                                             "version"}
    assert "window pass 1" in captured.err


def test_a_long_record_of_few_gaps_is_bounded_with_the_inner_signal_eliminated_and_shows_its_tightness(
        long_files, capsys) -> None:
    # 900 samples > --joint-samples 400, yet no windows: the trajectory relaxation and its partition, and the
    # verified inner values (their LPs have a few columns), so --json carries outer_inner_ratio
    assert main(_args(long_files, "--joint-samples", "400", "--json")) == exit_codes.SUCCESS
    captured = capsys.readouterr()
    document = json.loads(captured.out)
    assert document["linear_bounds"]["windowing"].startswith("all 900 samples in the trajectory relaxation")
    assert "then the box of a partitioned into cells" in document["linear_bounds"]["windowing"]
    ratios = document["linear_bounds"]["outer_inner_ratio"]
    assert set(ratios) == {"a1", "a2", "b1", "b2"} and all(1.0 <= ratio <= 1.1 for ratio in ratios.values()), ratios
    truth = {"a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8}
    for name, value in truth.items():
        assert document["linear"][name]["lower"] <= value <= document["linear"][name]["upper"]
    assert "partition of the box of a" in captured.err  # the progress goes to stderr


def test_windows_of_one_record_run_in_worker_processes_with_the_same_bounds(long_files, capsys) -> None:
    options = ("--joint-samples", "400", "--partition-samples", "0", "--json", "--windows")
    assert main(_args(long_files, *options)) == exit_codes.SUCCESS
    serial = json.loads(capsys.readouterr().out)
    assert main(_args(long_files, *options, "--jobs", "2")) == exit_codes.SUCCESS
    assert json.loads(capsys.readouterr().out) == serial
    assert main(_args(long_files, "--jobs", "-1")) == exit_codes.BAD_INPUT
    assert "--jobs: expected 0 (all cores)" in capsys.readouterr().err


def _window_task_that_dies_in_the_joint_parts(task, retries_too: bool):
    """A worker dying as in a HiGHS stack overflow in the dual simplex (BENCHMARKS.md, set-membership
    bounds against the record length), by SIGKILL: in every joint part, or (``retries_too`` False) only in
    those not solved again by the interior-point method."""
    import os
    import signal

    import identify.linear_block_bounds.windows as module

    if task[0] == "joint" and (retries_too or not task[-1]):
        os.kill(os.getpid(), signal.SIGKILL)
    return module._ORIGINAL_WINDOW_TASK(task)


def _bounds_without_and_with_dying_workers(long_files, capsys, monkeypatch, retries_too: bool) -> tuple[dict, dict]:
    """The ``--json`` documents of a long record (--jobs 1, the default) bounded as it is and with the worker
    of every joint part killed (:func:`_window_task_that_dies_in_the_joint_parts`)."""
    import identify.linear_block_bounds.windows as module

    options = ("--joint-samples", "400", "--partition-samples", "0", "--json", "--windows")
    assert main(_args(long_files, *options)) == exit_codes.SUCCESS
    whole = json.loads(capsys.readouterr().out)
    monkeypatch.setattr(module, "_ORIGINAL_WINDOW_TASK", module._window_task, raising=False)
    monkeypatch.setattr(module, "_window_task", functools.partial(_window_task_that_dies_in_the_joint_parts,
                                                                 retries_too=retries_too))
    assert main(_args(long_files, *options)) == exit_codes.SUCCESS
    return whole, json.loads(capsys.readouterr().out)


def test_a_solver_crash_with_one_job_costs_the_worker_not_the_command(long_files, capsys, monkeypatch) -> None:
    """With --jobs 1 (the default) the windows and parts still run in a worker process: a crash inside HiGHS
    kills that worker (and the retry's), and the command ends with valid, looser bounds and a note saying why."""
    whole, crashed = _bounds_without_and_with_dying_workers(long_files, capsys, monkeypatch, retries_too=True)
    assert len(crashed["notes"]) == 1 and "BrokenProcessPool" in crashed["notes"][0]
    for name, interval in whole["linear"].items():
        looser = crashed["linear"][name]
        assert looser["lower"] <= interval["lower"] and interval["upper"] <= looser["upper"]


def test_the_tasks_a_dead_worker_left_are_solved_again_by_the_interior_point_method(long_files, capsys,
                                                                                      monkeypatch) -> None:
    """The pool starts anew after the lost worker (rig.batch.RenewingProcessPool) and the unfinished parts are
    solved once more by the interior-point method: the bounds are the method's (no note), not the looser ones."""
    whole, retried = _bounds_without_and_with_dying_workers(long_files, capsys, monkeypatch, retries_too=False)
    assert "notes" not in retried
    for name, interval in whole["linear"].items():
        again = retried["linear"][name]
        width = interval["upper"] - interval["lower"]  # the interior point's certificate differs by its rounding
        assert again["lower"] == pytest.approx(interval["lower"], abs=1e-3 * width)
        assert again["upper"] == pytest.approx(interval["upper"], abs=1e-3 * width)


def test_moment_samples_adds_the_moment_cuts_says_so_and_never_widens_a_bound(files, capsys) -> None:
    assert main(_args(files, "--partition-samples", "0", "--json")) == exit_codes.SUCCESS
    plain = json.loads(capsys.readouterr().out)
    assert "moment" not in plain["linear_bounds"]["windowing"]  # off by default
    assert main(_args(files, "--partition-samples", "0", "--moment-samples", "100")) == exit_codes.SUCCESS
    table = capsys.readouterr().out
    assert "method coupled" in table
    assert "windowing          all 100 samples in the trajectory relaxation (inner signal eliminated)" in table
    assert "rounds, then cuts from the moment (SDP)" in table
    rows: dict[str, list[str]] = {}
    for line in table.splitlines():  # the first row of each name: the outer bounds (the verified inner values follow)
        if line.split()[:1] in (["a1"], ["a2"], ["b1"], ["b2"]):
            rows.setdefault(line.split()[0], line.split()[1:3])
    for name, bounds in plain["linear"].items():
        lower, upper = (float(value) for value in rows[name])
        # the table prints 8 significant digits
        assert bounds["lower"] - 1e-7 <= lower <= upper <= bounds["upper"] + 1e-7
    assert main(_args(files, "--moment-samples", "-1")) == exit_codes.BAD_INPUT
    assert "moment_samples: expected an integer >= 0, got -1" in capsys.readouterr().err
