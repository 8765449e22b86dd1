"""Log files: round trip, crash safety under SIGKILL, damaged and foreign files, plain t,u,y CSV."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from rig.log_file import LogWriter, read_experiment_data, read_log, write_log
from rig.protocols.errors import LogFileError

META = ExperimentMetadata(sample_period_s=1e-3, source="cerone2009", transport="offline", encoder_bits=12,
                          noise_kind="uniform", noise_bound_rad=7.7e-4, excitation="prbs", excitation_seed=3,
                          seed=2009, config={"plant": "configs/plants/cerone2009.toml"}, software_version="0.1.0")
ROOT = Path(__file__).resolve().parents[2]


def sample_record() -> ExperimentRecord:
    rng = np.random.default_rng(0)
    n = 200
    angle = rng.normal(0, 0.3, n)
    flags = np.zeros(n, dtype=np.uint8)
    flags[[5, 17]] = SampleFlag.LOST
    flags[30] = SampleFlag.LATE | SampleFlag.LIMITED
    angle[[5, 17]] = math.nan
    return ExperimentRecord(time_s=np.arange(n) * 1e-3, command_rad=rng.uniform(-1, 1, n), angle_rad=angle,
                            encoder_counts=rng.integers(-2048, 2048, n), flags=flags, metadata=META)


def test_log_round_trip_is_exact(tmp_path):
    original = sample_record()
    path = tmp_path / "run.csv"
    write_log(path, original)
    again = read_log(path)
    assert again.metadata == original.metadata
    for name in ("time_s", "command_rad", "encoder_counts", "flags"):
        assert np.array_equal(getattr(again, name), getattr(original, name)), name
    assert np.array_equal(again.angle_rad, original.angle_rad, equal_nan=True)
    assert again.lost_count == 2
    assert read_experiment_data(path).metadata == original.metadata


def test_log_opens_without_this_package_in_numpy(tmp_path):
    path = tmp_path / "run.csv"
    write_log(path, sample_record())
    table = np.genfromtxt(path, delimiter=",", names=True, skip_header=3)  # the 3 comment lines
    assert table.dtype.names == ("time_s", "command_rad", "angle_rad", "encoder_counts", "flags")
    np.testing.assert_array_equal(table["time_s"], sample_record().time_s)
    assert np.isnan(table["angle_rad"][5]) and table["flags"][5] == 1
    header = path.read_text().splitlines()[:4]
    assert header[0] == "# rig-log v1" and header[1].startswith('# metadata {"sample_period_s": 0.001')


WRITER = """
import sys, time
from identify.experiment_record import ExperimentMetadata
from rig.log_file import LogWriter
log = LogWriter(sys.argv[1], ExperimentMetadata(sample_period_s=0.001, source="kill-test"), flush_every=1)
k = 0
while True:
    log.append(k * 0.001, k * 0.5, -k * 0.25, encoder_counts=k)
    k += 1
    print(k, flush=True)
"""


def test_writer_killed_with_sigkill_leaves_every_flushed_sample_readable(tmp_path):
    path = tmp_path / "killed.csv"
    process = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True,
                               cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        reported = 0
        while reported < 2000:
            line = process.stdout.readline()
            assert line, "the writer stopped on its own"
            reported = int(line)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
        process.stdout.close()
    assert process.returncode == -signal.SIGKILL
    # every sample the writer had finished (and so flushed) before we read its report is in the file
    record = read_log(path)
    assert len(record) >= reported
    k = np.arange(len(record))
    np.testing.assert_array_equal(record.time_s, k * 0.001)
    np.testing.assert_array_equal(record.command_rad, k * 0.5)
    np.testing.assert_array_equal(record.encoder_counts, k)


def test_torn_last_line_is_dropped_with_a_warning(tmp_path):
    path = tmp_path / "torn.csv"
    write_log(path, sample_record())
    text = path.read_text()
    path.write_text(text[:-7])  # cut the last line short
    with pytest.warns(UserWarning, match="last line is incomplete"):
        record = read_log(path)
    assert len(record) == 199


def test_writer_flushes_by_count_and_refuses_an_unwritable_path(tmp_path):
    path = tmp_path / "batched.csv"
    with LogWriter(path, META, flush_every=10) as log:
        for k in range(15):
            log.append(k * 1e-3, 0.0, 0.0)
        assert path.read_text().count("\n") == 4 + 10  # header + the first flushed batch
    assert len(read_log(path)) == 15 and read_log(path).encoder_counts is None
    with pytest.raises(LogFileError, match="cannot open the log for writing"):
        LogWriter(tmp_path / "no-such-dir" / "run.csv", META)
    with LogWriter(tmp_path / "x.csv", META) as log:
        log.append(0.0, 0.0, 0.0)
        with pytest.raises(ValueError, match="times must increase"):
            log.append(0.0, 0.0, 0.0)
        with pytest.raises(ValueError, match="flag it LOST"):
            log.append(1.0, 0.0, math.nan)


@pytest.mark.parametrize(("mutate", "message"), [
    (lambda text: "time,u\n1,2\n", "line 1: expected '# rig-log v1'"),
    (lambda text: text.replace("# rig-log v1", "# rig-log v7"), "unsupported log format"),
    (lambda text: text.replace('# metadata {"', "# metadata {'"), "line 2: the metadata is not valid JSON"),
    (lambda text: text.replace("time_s,command_rad", "time,command_rad"), "line 4: expected columns"),
    (lambda text: text.replace("\n0.002,", "\n0.002,zero", 1), "line 7, column command_rad"),
    (lambda text: text.replace("\n0.003,", "\n0.0001,", 1), r"line 8, column time_s: sample 3 .*increase"),
    (lambda text: text.replace(",0\n", ",0,0\n", 1), "line 5: expected 5 values, got 6"),
    (lambda text: "", "the file is empty"),
])
def test_damaged_or_foreign_logs_are_named(tmp_path, mutate, message):
    path = tmp_path / "bad.csv"
    write_log(path, sample_record())
    path.write_text(mutate(path.read_text()))
    with pytest.raises(LogFileError, match=message):
        read_log(path)


def test_plain_t_u_y_csv_is_accepted_and_checked(tmp_path):
    path = tmp_path / "foreign.csv"
    path.write_text("# exported by another tool\nt,u,y,temperature\n0.0,0.1,0.0,20\n0.01,0.2,0.05,20\n0.02,0.3,0.1,20\n")
    record = read_experiment_data(path)
    np.testing.assert_array_equal(record.command_rad, [0.1, 0.2, 0.3])
    assert record.encoder_counts is None and record.sample_period_s == pytest.approx(0.01)
    assert record.metadata.transport == "csv"
    path.write_text("t,u,y\n0.0,0.1,0.0\n0.0,0.2,0.05\n")
    with pytest.raises(LogFileError, match="column t must increase"):
        read_experiment_data(path)
    path.write_text("time,input,output\n0,1,2\n")
    with pytest.raises(LogFileError, match="missing column"):
        read_experiment_data(path)


def test_metadata_with_numpy_values_is_written_as_plain_json(tmp_path):
    meta = ExperimentMetadata(sample_period_s=1e-3, config={"amplitudes_rad": np.linspace(0, 1, 3), "bits": np.int64(12)})
    path = tmp_path / "np.csv"
    with LogWriter(path, meta) as log:
        log.append(0.0, 0.0, 0.0)
    assert read_log(path).metadata.config == {"amplitudes_rad": [0.0, 0.5, 1.0], "bits": 12}
    with pytest.raises(ValueError, match="metadata: .*inf"):
        LogWriter(tmp_path / "nan.csv", ExperimentMetadata(sample_period_s=1e-3, config={"bound": math.inf}))


def test_read_input_output_takes_a_log_or_a_plain_u_y_csv(tmp_path):
    from rig.log_file import read_input_output

    plain = tmp_path / "plain.csv"
    plain.write_text("u,y\n1.0,0.5\n2.0,0.25\n")
    u, y = read_input_output(plain)
    assert u.tolist() == [1.0, 2.0] and y.tolist() == [0.5, 0.25]


def test_read_input_output_refuses_a_t_column_that_goes_back(tmp_path):
    from rig.log_file import read_input_output

    pasted = tmp_path / "pasted.csv"
    pasted.write_text("t,u,y\n0.0,1.0,0.5\n0.001,2.0,0.25\n0.0,1.0,0.5\n")
    with pytest.raises(LogFileError, match=r"pasted.csv: column t must increase .* data row 3 has t = 0.0 after "
                                           r"0.001: are two records pasted together"):
        read_input_output(pasted)


def test_a_log_in_other_units_is_refused_naming_the_column(tmp_path):
    path = tmp_path / "run.csv"
    write_log(path, sample_record())
    text = path.read_text()
    path.write_text(text.replace("angle_rad=rad", "angle_rad=deg", 1))
    with pytest.raises(LogFileError, match=r"run.csv: line 3: angle_rad is in 'deg', expected 'rad'; convert the "
                                           r"column to rad"):
        read_log(path)


def test_a_sample_period_that_contradicts_the_time_column_is_refused(tmp_path):
    path = tmp_path / "run.csv"
    write_log(path, sample_record())
    path.write_text(path.read_text().replace('"sample_period_s": 0.001', '"sample_period_s": 0.01', 1))
    with pytest.raises(LogFileError, match=r"line 2: the metadata says sample_period_s = 0.01 s, but time_s steps "
                                           r"by 0.001 s \(median\)"):
        read_log(path)


def test_a_summary_after_the_last_sample_reads_into_the_metadata_and_other_readers_skip_it(tmp_path):
    from rig.log_file import count_samples

    path = tmp_path / "run.csv"
    record = sample_record()
    with LogWriter(path, record.metadata) as log:
        log.append_many(record.time_s, record.command_rad, record.angle_rad, record.encoder_counts, record.flags)
        log.write_summary({"frame_errors": 3, "stop": "quick stop sent, then disable sent"})
        with pytest.raises(LogFileError, match="no sample may follow"):
            log.append(1.0, 0.0, 0.0)
    again = read_log(path)
    assert again.metadata.extra["summary"] == {"frame_errors": 3, "stop": "quick stop sent, then disable sent"}
    assert len(again) == len(record) == count_samples(path)
    table = np.genfromtxt(path, delimiter=",", names=True, skip_header=3)  # '#' lines are comments to numpy
    assert table.size == len(record)


def _with_torque(record: ExperimentRecord) -> ExperimentRecord:
    torque = np.round(np.linspace(-250.0, 310.0, len(record)))
    torque[[5, 17, 40]] = math.nan  # LOST samples have none, and a drive may miss one
    metadata = ExperimentMetadata.from_dict({**record.metadata.to_dict(),
                                             "extra": {"drive_torque_unit": "permille_of_rated_torque"}})
    return ExperimentRecord(time_s=record.time_s, command_rad=record.command_rad, angle_rad=record.angle_rad,
                            encoder_counts=record.encoder_counts, flags=record.flags, metadata=metadata,
                            drive_torque=torque)


def test_a_log_with_the_drive_torque_is_v2_and_reopens_with_it_and_its_unit(tmp_path):
    original = _with_torque(sample_record())
    path = tmp_path / "run.csv"
    write_log(path, original)
    lines = path.read_text().splitlines()
    assert lines[0] == "# rig-log v2" and lines[2].endswith(" drive_torque=permille_of_rated_torque")
    assert lines[3] == "time_s,command_rad,angle_rad,encoder_counts,flags,drive_torque"
    again = read_log(path)
    assert again == original
    assert again.metadata.extra["drive_torque_unit"] == "permille_of_rated_torque"
    table = np.genfromtxt(path, delimiter=",", names=True, skip_header=3)  # still the 3 comment lines
    np.testing.assert_array_equal(table["drive_torque"], original.drive_torque)
    from rig.commands.inspect import summary

    assert summary(str(path))["drive_torque_samples"] == len(original) - 3  # rig inspect: 3 samples without one
    # without the torque the log stays v1, which readers of v1 open
    write_log(tmp_path / "plain.csv", sample_record())
    assert (tmp_path / "plain.csv").read_text().startswith("# rig-log v1\n")
    assert read_log(tmp_path / "plain.csv").drive_torque is None


def test_a_torque_for_a_log_without_its_column_is_refused_by_name(tmp_path):
    with LogWriter(tmp_path / "run.csv", META) as log:
        with pytest.raises(ValueError, match="has no drive_torque column.*drive_torque_unit"):
            log.append(0.0, 0.0, 0.0, 1, 0, drive_torque=12.0)
    with LogWriter(tmp_path / "empty.csv", META, drive_torque_unit="permille_of_rated_torque") as log:
        log.append(0.0, 0.0, 0.0, 1, 0)  # a drive that would not map its torque: the column stays empty
    assert read_log(tmp_path / "empty.csv").drive_torque is None


@pytest.mark.parametrize(("mutate", "message"), [
    (lambda text: text.replace(",drive_torque\n", "\n", 1), r"line 4: expected columns .*drive_torque \(rig-log v2\)"),
    (lambda text: text.replace("# rig-log v2", "# rig-log v1"), r"line 4: expected columns .*flags \(rig-log v1\)"),
    (lambda text: text.replace(",-250.0\n", ",-2.5e\n", 1), "line 5, column drive_torque: '-2.5e' is not a number"),
])
def test_a_damaged_v2_log_is_named(tmp_path, mutate, message):
    path = tmp_path / "bad.csv"
    write_log(path, _with_torque(sample_record()))
    path.write_text(mutate(path.read_text()))
    with pytest.raises(LogFileError, match=message):
        read_log(path)
