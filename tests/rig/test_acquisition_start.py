"""A log records when its acquisition started (UTC, ISO 8601); an old log without it reads as unknown, and the
MDF export takes it as the file's start time."""

from __future__ import annotations

import json
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from identify.experiment_record import ExperimentMetadata, utc_timestamp
from identify.validation import InvalidInputError
from rig import exit_codes
from rig.cli import main
from rig.log_file import count_samples, read_experiment_data, read_log, write_log
from rig.protocols.errors import LogFileError
from rig.record_import import read_measurement

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> tuple[Path, datetime, datetime]:
    """A short run on the simulated serial rig, with the UTC clock read before and after it."""
    folder = tmp_path_factory.mktemp("start")
    log = folder / "run.csv"
    before = datetime.now(timezone.utc)
    assert main(["run", str(CONFIGS / "sim_serial.toml"), "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--duration", "0.2", "--out", str(log), "--json"]) == exit_codes.SUCCESS
    return log, before, datetime.now(timezone.utc)


def test_a_run_log_records_its_acquisition_start_in_utc(run_log):
    log, before, after = run_log
    record = read_log(log)
    start = record.metadata.acquisition_start
    assert start is not None and start.utcoffset() == timedelta(0)
    assert before <= start <= after
    assert record.metadata.acquisition_start_utc.endswith("Z")
    assert count_samples(log) == len(record)
    lines = log.read_text().splitlines()
    assert lines[4].startswith('# start {"acquisition_start_utc": "')  # with the first sample, after the header
    table = np.genfromtxt(log, delimiter=",", names=True, skip_header=3)  # readable without this package
    assert table.size == len(record)


def test_an_old_log_without_a_start_reads_as_unknown_and_says_so(run_log, tmp_path, capsys):
    log, _, _ = run_log
    old = tmp_path / "old.csv"
    lines = [line for line in log.read_text().splitlines(keepends=True) if not line.startswith("# start ")]
    header = json.loads(lines[1][len("# metadata "):])
    header.pop("acquisition_start_utc")
    lines[1] = "# metadata " + json.dumps(header) + "\n"
    old.write_text("".join(lines))
    record = read_log(old)
    assert record.metadata.acquisition_start_utc is None and record.metadata.acquisition_start is None
    assert main(["inspect", str(old)]) == exit_codes.SUCCESS
    assert "acquisition_start_utc" in (out := capsys.readouterr().out) and "unknown (not recorded" in out
    assert main(["export", str(old), "--out", str(tmp_path / "old.mf4")]) == exit_codes.SUCCESS
    assert "records no acquisition start" in capsys.readouterr().err


def test_mdf_export_takes_the_acquisition_start_as_its_start_time(run_log, tmp_path, capsys):
    asammdf = pytest.importorskip("asammdf")
    log, _, _ = run_log
    record = read_log(log)
    out = tmp_path / "run.mf4"
    assert main(["export", str(log), "--out", str(out), "--json"]) == exit_codes.SUCCESS
    assert json.loads(capsys.readouterr().out)["acquisition_start_utc"] == record.metadata.acquisition_start_utc
    with asammdf.MDF(out) as mdf:
        written = mdf.header.start_time
    assert abs((written - record.metadata.acquisition_start).total_seconds()) < 1e-6
    assert read_experiment_data(out).metadata.acquisition_start_utc == record.metadata.acquisition_start_utc
    again = tmp_path / "again.csv"
    write_log(again, read_experiment_data(out))  # a rewritten record keeps its start, it is not stamped anew
    assert read_log(again).metadata.acquisition_start_utc == record.metadata.acquisition_start_utc


def test_a_foreign_mdf_start_time_is_the_records_start(tmp_path):
    asammdf = pytest.importorskip("asammdf")
    start = datetime(2024, 11, 5, 8, 30, 0, 250000, tzinfo=timezone.utc)
    path = tmp_path / "canape.mf4"
    t = 0.5 + np.arange(200) * 0.001
    with asammdf.MDF(version="4.10") as mdf:
        mdf.append([asammdf.Signal(np.sin(t * 7), t, name="u", unit="rad"),
                    asammdf.Signal(np.sin(t * 7 - 0.1), t, name="y", unit="rad")])
        mdf.header.start_time = start
        mdf.save(path, overwrite=True)
    record, _ = read_measurement(path)
    assert record.metadata.acquisition_start == start + timedelta(seconds=0.5)


def test_the_start_is_checked_and_written_in_utc():
    assert utc_timestamp("2025-03-04T10:15:02.5+01:00") == "2025-03-04T09:15:02.500000Z"
    metadata = ExperimentMetadata(sample_period_s=0.001, acquisition_start_utc="2025-03-04T09:15:02Z")
    assert ExperimentMetadata.from_dict(metadata.to_dict()) == metadata
    with pytest.raises(InvalidInputError, match="no time zone"):
        ExperimentMetadata(sample_period_s=0.001, acquisition_start_utc="2025-03-04T09:15:02")
    with pytest.raises(InvalidInputError, match="ISO 8601"):
        ExperimentMetadata(sample_period_s=0.001, acquisition_start_utc="yesterday")


def test_a_damaged_start_line_is_named(run_log, tmp_path):
    log, _, _ = run_log
    damaged = tmp_path / "damaged.csv"
    damaged.write_text(log.read_text().replace('{"acquisition_start_utc": "', '{"acquisition_start_utc": "x', 1))
    with pytest.raises(LogFileError, match=r"damaged\.csv: line 5: the start line is damaged"):
        read_log(damaged)
