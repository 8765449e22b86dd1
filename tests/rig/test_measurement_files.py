"""``rig export`` and the MDF4 / MAT readers: round trips, the file layout, foreign files
with channels t,u,y, and the errors for missing channels, damaged files and a missing asammdf."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.io import loadmat, savemat

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from rig import exit_codes
from rig.cli import main
from rig.log_file import read_experiment_data, read_input_output, read_log, write_log
from rig.protocols.errors import LogFileError

asammdf = pytest.importorskip("asammdf")

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    """A simulated log (100 samples, encoder counts) with one LOST sample and a run summary."""
    folder = tmp_path_factory.mktemp("export")
    simulated = folder / "simulated.csv"
    assert main(["simulate", str(CONFIGS / "plants" / "cerone2009.toml"), "--excitation",
                 str(CONFIGS / "experiments" / "prbs.toml"), "--out", str(simulated)]) == exit_codes.SUCCESS
    record = read_log(simulated)
    flags = record.flags.copy()
    flags[7] = SampleFlag.LOST
    flags[9] = SampleFlag.LATE | SampleFlag.HELD
    angle = record.angle_rad.copy()
    angle[7] = np.nan
    metadata = ExperimentMetadata.from_dict({**record.metadata.to_dict(),
                                             "extra": {"summary": {"frame_errors": 2, "stop": "quick stop <ok> & off"}}})
    path = folder / "run.csv"
    write_log(path, dataclasses.replace(record, angle_rad=angle, flags=flags, metadata=metadata))
    return path


def _same_record(a: ExperimentRecord, b: ExperimentRecord) -> None:
    np.testing.assert_array_equal(a.time_s, b.time_s)
    np.testing.assert_array_equal(a.command_rad, b.command_rad)
    np.testing.assert_array_equal(a.angle_rad, b.angle_rad)  # NaN where LOST, on both sides
    np.testing.assert_array_equal(a.encoder_counts, b.encoder_counts)
    np.testing.assert_array_equal(a.flags, b.flags)
    assert a.metadata == b.metadata


def test_log_to_mdf4_diagnoses_like_the_csv(log, tmp_path, capsys):
    log = log.parent / "simulated.csv"  # diagnose takes no LOST sample
    mdf = tmp_path / "run.mf4"
    assert main(["export", str(log), "--format", "mdf", "--out", str(mdf)]) == exit_codes.SUCCESS
    capsys.readouterr()
    results = []
    for data in (log, mdf):
        assert main(["diagnose", str(data), "--noise-bound", "0.002", "--json"]) == exit_codes.SUCCESS
        results.append(json.loads(capsys.readouterr().out))
    assert results[0] == results[1]
    assert results[0]["missing_effects"]  # a real diagnosis, not two empty ones
    _same_record(read_log(log), read_experiment_data(mdf))


def test_log_to_mat_reads_back_identical_arrays(log, tmp_path, capsys):
    mat = tmp_path / "run.mat"
    assert main(["export", str(log), "--out", str(mat), "--json"]) == exit_codes.SUCCESS
    written = json.loads(capsys.readouterr().out)
    assert written == {"log": str(log), "out": str(mat), "format": "mat", "samples": 100,
                       "acquisition_start_utc": read_log(log).metadata.acquisition_start_utc}
    original = read_log(log)
    _same_record(original, read_experiment_data(mat))
    u, y = read_input_output(mat)
    np.testing.assert_array_equal(u, original.command_rad)
    # what MATLAB's load sees: column vectors and a metadata struct
    contents = loadmat(mat, simplify_cells=False)
    assert contents["angle_rad"].shape == (100, 1) and contents["encoder_counts"].dtype == np.int64
    struct = loadmat(mat, simplify_cells=True)["metadata"]
    assert struct["sample_period_s"] == 0.001 and struct["source"] == "cerone2009"
    assert json.loads(struct["rig_log_json"])["extra"]["summary"]["frame_errors"] == 2


@pytest.mark.parametrize("suffix", [".mf4", ".mat", ".csv"])
def test_the_drive_torque_of_a_v2_log_survives_the_export(log, tmp_path, capsys, suffix):
    record = read_log(log)
    torque = np.linspace(-300.0, 300.0, len(record))
    torque[7] = np.nan  # the LOST sample has none
    metadata = ExperimentMetadata.from_dict({**record.metadata.to_dict(),
                                             "extra": {**record.metadata.extra, "drive_torque_unit": "permille_of_rated_torque"}})
    source = tmp_path / "torque.csv"
    write_log(source, dataclasses.replace(record, metadata=metadata, drive_torque=torque))
    out = tmp_path / f"exported{suffix}"
    assert main(["export", str(source), "--out", str(out)]) == exit_codes.SUCCESS
    again = read_experiment_data(out)
    np.testing.assert_array_equal(again.drive_torque, torque)
    assert again.metadata.extra["drive_torque_unit"] == "permille_of_rated_torque"
    _same_record(read_log(source), again)


def test_mdf4_layout_names_units_comments_and_history(log, tmp_path):
    mdf_path = tmp_path / "run.mf4"
    assert main(["export", str(log), "--out", str(mdf_path)]) == exit_codes.SUCCESS
    with asammdf.MDF(mdf_path) as mdf:
        assert mdf.version == "4.10"
        units = {name: mdf.get(name).unit for name in ("time_s", "command_rad", "angle_rad", "encoder_counts")}
        assert units == {"time_s": "s", "command_rad": "rad", "angle_rad": "rad", "encoder_counts": "counts"}
        assert "LOST" in mdf.get("flags").comment
        assert mdf.get("encoder_counts").samples.dtype == np.int64
        assert "cerone2009" in mdf.header.comment and 'name="rig_metadata"' in mdf.header.comment
        assert any("<tool_id>rig</tool_id>" in entry.comment for entry in mdf.file_history)
    back = tmp_path / "back.csv"
    assert main(["export", str(mdf_path), "--out", str(back)]) == exit_codes.SUCCESS
    assert back.read_text() == log.read_text()  # byte for byte, the summary line too


def _foreign_mdf(path: Path, channels: dict[str, np.ndarray], period_s: float = 0.001) -> None:
    size = next(iter(channels.values())).size
    with asammdf.MDF(version="4.10") as mdf:
        mdf.append([asammdf.Signal(values, np.arange(size) * period_s, name=name, unit="rad")
                    for name, values in channels.items()])
        mdf.save(path, overwrite=True)


def test_foreign_mdf_and_mat_with_t_u_y_are_read(tmp_path, capsys):
    u = np.sin(np.arange(200) * 0.1)
    y = 0.5 * u
    mdf = tmp_path / "canape.mf4"
    _foreign_mdf(mdf, {"u": u, "y": y, "other": np.ones(200)})  # t is the master time
    record = read_experiment_data(mdf)
    assert record.metadata.sample_period_s == pytest.approx(0.001)
    np.testing.assert_array_equal(record.angle_rad, y)
    mat = tmp_path / "matlab.mat"
    savemat(mat, {"t": np.arange(200) * 0.002, "u": u, "y": y, "notes": "hand-made"})  # row vectors, MATLAB style
    record = read_experiment_data(mat)
    assert record.metadata.sample_period_s == pytest.approx(0.002)
    np.testing.assert_array_equal(record.command_rad, u)
    assert main(["inspect", str(mat), "--json"]) == exit_codes.SUCCESS
    assert json.loads(capsys.readouterr().out)["samples"] == 200


def test_a_missing_channel_names_the_file_and_lists_the_present_ones(tmp_path, capsys):
    mdf = tmp_path / "wrong.mf4"
    _foreign_mdf(mdf, {"input": np.zeros(10), "output": np.zeros(10)})
    with pytest.raises(LogFileError, match=r"wrong\.mf4: no channel 'u'.*the file has: input, output, time"):
        read_experiment_data(mdf)
    mat = tmp_path / "wrong.mat"
    savemat(mat, {"t": np.arange(10.0), "u": np.zeros(10)})
    assert main(["diagnose", str(mat), "--noise-bound", "0.01"]) == exit_codes.BAD_INPUT
    err = capsys.readouterr().err
    assert "wrong.mat: no channel 'y'" in err and "the file has: t, u" in err


def test_damaged_files_get_a_clear_error(tmp_path, capsys):
    for name in ("damaged.mf4", "damaged.mat"):
        path = tmp_path / name
        path.write_bytes(b"this is not a measurement file\n" * 10)
        assert main(["inspect", str(path)]) == exit_codes.BAD_INPUT
        err = capsys.readouterr().err
        assert f"{path}: not a readable" in err and "Traceback" not in err


def test_export_checks_the_output_before_the_work(log, tmp_path, capsys):
    assert main(["export", str(log), "--out", str(tmp_path / "missing" / "run.mf4")]) == exit_codes.WRITE_FAILED
    assert "the directory" in capsys.readouterr().err
    assert main(["export", str(log), "--format", "mdf", "--out", str(tmp_path / "run.mat")]) == exit_codes.BAD_INPUT
    assert "must be named .mf4 or .mdf" in capsys.readouterr().err
    assert main(["export", str(log), "--out", str(log)]) == exit_codes.WRITE_FAILED  # csv onto its own input


def test_without_asammdf_the_error_names_the_extra(log, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "asammdf", None)  # import asammdf raises ImportError
    assert main(["export", str(log), "--out", str(tmp_path / "run.mf4")]) == exit_codes.BAD_INPUT
    assert "pip install 'gearbox-rig[mdf]'" in capsys.readouterr().err
    assert not (tmp_path / "run.mf4").exists()


def test_rig_run_takes_its_excitation_from_a_mat_file(tmp_path, capsys):
    mat = tmp_path / "excitation.mat"
    command = np.linspace(0, 0.02, 50)
    savemat(mat, {"command_rad": command, "time_s": np.arange(50) * 0.001})
    log = tmp_path / "run.csv"
    assert main(["run", str(CONFIGS / "sim_serial.toml"), "--experiment", str(mat), "--out", str(log),
                 "--json"]) == exit_codes.SUCCESS
    record = read_log(log)
    assert len(record) == 50 and record.metadata.excitation == "excitation"
    np.testing.assert_allclose(record.command_rad, command, atol=1e-4)  # quantised to drive counts


def test_rig_report_draws_an_exported_mdf4_log(log, tmp_path, capsys):
    mdf = tmp_path / "run.mf4"
    assert main(["export", str(log), "--out", str(mdf)]) == exit_codes.SUCCESS
    out = tmp_path / "report"
    assert main(["report", str(mdf), "--out", str(out), "--json"]) == exit_codes.SUCCESS
    assert (out / "index.html").is_file() and "run.mf4" in (out / "index.html").read_text()
