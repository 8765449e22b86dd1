"""Real-log import: per-sample JSON records, --columns, --units, --valid, spikes, irregular
sampling, and error messages that echo at most one short line of the file."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rig import exit_codes
from rig.cli import main
from rig.record_import import (
    ECHO_LIMIT,
    ImportOptions,
    RecordImportError,
    parse_columns,
    parse_units,
    read_measurement,
    remove_spikes,
)

KSCALE_COLUMNS = {"t": "timestamp", "u": "goal_position", "y": "position"}


def kscale_like(path, samples=400, jitter=0.0015, spikes=(), enable_until=None, seed=0):
    """A file shaped like the K-Scale sysid logger's: metadata plus entries[] with one object per sample."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(np.full(samples, 0.01) + rng.uniform(-jitter, jitter, samples))
    u = 0.8 * np.sin(2 * np.pi * 0.7 * t)
    y = np.round(np.concatenate(([0.0], u[:-1])) / (2 * np.pi / 4096)) * (2 * np.pi / 4096)
    y = y.copy()
    for index in spikes:
        y[index] -= math.pi
    entries = [{"timestamp": float(a), "goal_position": float(b), "position": float(c), "speed": 0.0,
                "torque_enable": enable_until is None or k < enable_until} for k, (a, b, c) in enumerate(zip(t, u, y))]
    path.write_text(json.dumps({"kp": 8, "sample_rate": 100.0, "entries": entries}))
    return t, u, y


def test_json_records_are_read_with_the_named_columns_spikes_replaced_and_jitter_resampled(tmp_path):
    path = tmp_path / "servo.json"
    t, u, y = kscale_like(path, spikes=(57, 201))
    record, report = read_measurement(path, ImportOptions(columns=KSCALE_COLUMNS))
    assert report.spike_samples == (57, 201)
    assert any("2 one-sample read failure(s)" in note for note in report.notes)
    assert report.resampled and any("irregular sampling" in note and "spread" in note for note in report.notes)
    assert record.metadata.sample_period_s == pytest.approx(np.median(np.diff(t)))
    assert np.ptp(np.diff(record.time_s)) < 1e-9
    # after the repair no sample is a pi away from the command: the spikes are gone
    assert np.max(np.abs(record.angle_rad - np.interp(record.time_s, t, np.concatenate(([0.0], u[:-1]))))) < 0.1


def test_units_convert_counts_and_degrees_to_radians():
    assert parse_units("counts:4096") == pytest.approx(2 * math.pi / 4096)
    assert parse_units("deg") == pytest.approx(math.pi / 180)
    assert parse_units("rad") == 1.0
    with pytest.raises(ValueError, match="counts:N"):
        parse_units("counts:zero")


def test_counts_in_a_csv_are_read_as_radians(tmp_path):
    path = tmp_path / "counts.csv"
    t = np.arange(300) * 0.01
    counts = np.round(500 * np.sin(t * 3))
    path.write_text("time,cmd,pos\n" + "".join(f"{float(a)!r},{float(b)!r},{float(b)!r}\n" for a, b in zip(t, counts)))
    record, report = read_measurement(path, ImportOptions(columns=parse_columns("t=time,u=cmd,y=pos"),
                                                          units="counts:4096"))
    assert record.angle_rad == pytest.approx(counts * 2 * math.pi / 4096)
    assert not report.resampled and report.spikes == 0


def test_valid_keeps_the_stretch_where_the_flag_holds(tmp_path):
    path = tmp_path / "drop.json"
    kscale_like(path, jitter=0.0, enable_until=150)
    record, report = read_measurement(path, ImportOptions(columns=KSCALE_COLUMNS, valid="torque_enable"))
    assert record.angle_rad.size == 150 and report.kept_samples == (0, 150)
    assert any("kept samples 0..149" in note for note in report.notes)


def test_a_gap_in_the_samples_is_refused_and_irregular_sampling_can_be_refused(tmp_path):
    path = tmp_path / "gap.json"
    kscale_like(path, jitter=0.0)
    document = json.loads(path.read_text())
    del document["entries"][100:110]
    path.write_text(json.dumps(document))
    with pytest.raises(RecordImportError, match="samples are missing"):
        read_measurement(path, ImportOptions(columns=KSCALE_COLUMNS))
    kscale_like(path)
    with pytest.raises(RecordImportError, match="irregular sampling"):
        read_measurement(path, ImportOptions(columns=KSCALE_COLUMNS, irregular="refuse"))


def test_a_spike_rule_leaves_fast_real_motion_alone():
    t = np.arange(500) * 0.01
    y = np.where(t > 2.0, 1.0, 0.0)  # a real step: departs from one neighbour only
    cleaned, spikes = remove_spikes(y)
    assert spikes == () and np.array_equal(cleaned, y)


def test_errors_about_json_name_the_keys_and_never_echo_the_file(tmp_path, capsys):
    path = tmp_path / "big.json"
    kscale_like(path, samples=3000)
    assert path.stat().st_size > 100_000
    code = main(["diagnose", str(path), "--noise-bound", "0.002"])
    assert code == exit_codes.BAD_INPUT
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and len(err) < 400 + len(str(path))
    assert "timestamp" in err and "--columns" in err
    (tmp_path / "broken.json").write_text('{"entries": [' + "1," * 50000)
    with pytest.raises(RecordImportError) as info:
        read_measurement(tmp_path / "broken.json")
    assert len(str(info.value)) < ECHO_LIMIT + 200 + len(str(tmp_path))


def test_diagnose_reads_json_records_and_reports_the_import_in_json(tmp_path, capsys):
    path = tmp_path / "servo.json"
    kscale_like(path, samples=600, spikes=(300,))
    code = main(["diagnose", str(path), "--columns", "t=timestamp,u=goal_position,y=position", "--valid",
                 "torque_enable", "--noise-bound", "0.002", "--json"])
    assert code == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    assert document["import"]["spikes"] == 1 and document["import"]["resampled"]
    assert document["verdict"] in ("explained", "named", "ambiguous", "unexplained", "not_excited")


def test_identify_hammerstein_reads_json_records_in_degrees(tmp_path, capsys):
    from identify.cyclic_excitation import cyclic_random_excitation
    from identify.plant_blocks import InputBacklash, LinearBlock, PiecewiseLinearBorder, PlantModel

    u = cyclic_random_excitation(100 + 1500, -3.0, 3.0, 100, rng=1)
    nodes = (-3.0, -1.0, 1.0, 3.0)
    plant = PlantModel((InputBacklash(PiecewiseLinearBorder(nodes, (-1.0, -0.8, 0.6, 1.0)),
                                      PiecewiseLinearBorder(nodes, (-1.0, -0.4, 0.9, 1.0)), initial_output_rad=-1.0),
                        LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)))
    y = plant.simulate(u)
    entries = [{"time": 0.01 * k, "cmd": float(np.degrees(a)), "pos": float(np.degrees(b))}
               for k, (a, b) in enumerate(zip(u, y))]
    path = tmp_path / "cyclic.json"
    path.write_text(json.dumps(entries))
    code = main(["identify", "hammerstein", str(path), "--columns", "t=time,u=cmd,y=pos", "--units", "deg",
                 "--nodes=-3,-1,1,3", "--json"])
    assert code == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    assert document["stable"] is True
    # nodes in rad fit only a command converted from degrees; G's two poles have |p| = sqrt(0.9048)
    assert [math.hypot(re, im) for re, im in document["poles"]] == pytest.approx([math.sqrt(0.9048)] * 2, abs=1e-6)


def test_an_error_quoting_a_huge_one_line_header_is_cut(tmp_path):
    path = tmp_path / "wide.csv"
    path.write_text(",".join(f"column_{k}" for k in range(20000)) + "\n" + ",".join("1" for _ in range(20000)) + "\n")
    with pytest.raises(RecordImportError) as info:
        read_measurement(path)
    message = str(info.value)
    assert "\n" not in message and len(message) < 500
