"""MDF4 and MAT files of other tools read with the channel map and units of CSV and JSON records: --columns,
--units and --valid for every format, and an MDF channel's own unit converted or refused with what to pass."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.io import savemat

from rig import exit_codes
from rig.channel_units import UnitMismatchWarning
from rig.cli import main
from rig.log_file import read_experiment_data
from rig.record_import import ImportOptions, RecordImportError, read_measurement

asammdf = pytest.importorskip("asammdf")

PERIOD_S = 0.002
INCA_COLUMNS = {"t": "t", "u": "MotCtl_phiSetpoint", "y": "Enc_phiLoad"}


def _signals(samples: int = 300) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(samples) * PERIOD_S
    u = 0.6 * np.sin(2 * np.pi * 1.5 * t) + 0.2 * np.sin(2 * np.pi * 4.1 * t)
    y = np.concatenate(([0.0], 0.9 * u[:-1]))
    return t, u, y


def _mdf(path: Path, channels: dict[str, tuple[np.ndarray, str]], period_s: float = PERIOD_S) -> Path:
    """An MDF4 file as INCA or CANape writes one: one group, master time, each channel with its unit."""
    size = next(iter(channels.values()))[0].size
    with asammdf.MDF(version="4.10") as mdf:
        mdf.append([asammdf.Signal(values, np.arange(size) * period_s, name=name, unit=unit)
                    for name, (values, unit) in channels.items()])
        mdf.save(path, overwrite=True)
    return path


def test_mdf_channels_in_degrees_are_read_in_radians_with_named_channels(tmp_path):
    t, u, y = _signals()
    path = _mdf(tmp_path / "inca.mf4", {"MotCtl_phiSetpoint": (np.degrees(u), "deg"),
                                         "Enc_phiLoad": (np.degrees(y), "°"), "Drv_iq": (np.ones(t.size), "A")})
    record, report = read_measurement(path, ImportOptions(columns=INCA_COLUMNS))
    np.testing.assert_allclose(record.command_rad, u, atol=1e-12)
    np.testing.assert_allclose(record.angle_rad, y, atol=1e-12)
    assert record.metadata.sample_period_s == pytest.approx(PERIOD_S)
    assert not report.notes


def test_mdf_channels_in_degrees_named_t_u_y_are_converted_without_options(tmp_path):
    t, u, y = _signals()
    path = _mdf(tmp_path / "plain.mf4", {"u": (np.degrees(u), "deg"), "y": (np.degrees(y), "deg")})
    for record in (read_experiment_data(path), read_measurement(path)[0]):
        np.testing.assert_allclose(record.command_rad, u, atol=1e-12)
        np.testing.assert_allclose(record.angle_rad, y, atol=1e-12)


def test_revolutions_and_counts_with_a_stated_resolution(tmp_path):
    t, u, y = _signals()
    path = _mdf(tmp_path / "rev.mf4", {"u": (u / (2 * np.pi), "rev"), "y": (y / (2 * np.pi), "rev")})
    record, _ = read_measurement(path)
    np.testing.assert_allclose(record.angle_rad, y, atol=1e-12)
    counts_u, counts_y = np.round(u / (2 * np.pi) * 4096), np.round(y / (2 * np.pi) * 4096)
    path = _mdf(tmp_path / "counts.mf4", {"u": (counts_u, "counts"), "y": (counts_y, "cnt")})
    record, _ = read_measurement(path, ImportOptions(units="counts:4096"))
    np.testing.assert_allclose(record.angle_rad, counts_y * 2 * np.pi / 4096, atol=1e-12)


def test_counts_without_a_resolution_and_unknown_units_are_refused_naming_channel_and_what_to_pass(tmp_path, capsys):
    t, u, y = _signals()
    path = _mdf(tmp_path / "counts.mf4", {"u": (np.round(u * 600), "counts"), "y": (np.round(y * 600), "counts")})
    with pytest.raises(RecordImportError, match=r"counts\.mf4: channel 'u' is in 'counts'.*--units counts:N"):
        read_measurement(path)
    assert main(["diagnose", str(path), "--noise-bound", "0.01"]) == exit_codes.BAD_INPUT
    err = capsys.readouterr().err
    assert "channel 'u' is in 'counts'" in err and "--units counts:N" in err and "Traceback" not in err
    path = _mdf(tmp_path / "linear.mf4", {"u": (u, "mm"), "y": (y, "mm")})
    with pytest.raises(RecordImportError, match=r"linear\.mf4: channel 'u' is in 'mm', which is no angle unit"):
        read_measurement(path)
    with pytest.raises(Exception, match=r"channel 'u' is in 'mm'"):
        read_experiment_data(path)  # rig inspect, report and export read the same units


def test_stated_units_that_contradict_the_file_win_with_a_warning(tmp_path):
    t, u, y = _signals()
    path = _mdf(tmp_path / "mislabelled.mf4", {"u": (u, "deg"), "y": (y, "deg")})
    with pytest.warns(UnitMismatchWarning) as caught:
        record, _ = read_measurement(path, ImportOptions(units="rad"))
    assert [str(w.message).split(": ", 1)[1] for w in caught] == [
        f"channel '{name}' is in 'deg' in the file, but --units rad was given: read as rad (drop --units to use the "
        "file's unit)" for name in ("u", "y")]
    np.testing.assert_allclose(record.angle_rad, y, atol=1e-12)
    path = _mdf(tmp_path / "agrees.mf4", {"u": (np.degrees(u), "deg"), "y": (np.degrees(y), "deg")})
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        record, _ = read_measurement(path, ImportOptions(units="deg"))
    np.testing.assert_allclose(record.angle_rad, y, atol=1e-12)


def test_valid_and_columns_for_mdf_and_mat_as_for_csv(tmp_path):
    t, u, y = _signals()
    enabled = (np.arange(t.size) >= 50) & (np.arange(t.size) < 260)
    options = ImportOptions(columns=INCA_COLUMNS, units="deg", valid="Drv_stEnable")
    mdf = _mdf(tmp_path / "canape.mf4", {"MotCtl_phiSetpoint": (np.degrees(u), ""), "Enc_phiLoad": (np.degrees(y), ""),
                                         "Drv_stEnable": (enabled.astype(np.uint8), "")})
    mat = tmp_path / "matlab.mat"
    savemat(mat, {"t": t, "MotCtl_phiSetpoint": np.degrees(u), "Enc_phiLoad": np.degrees(y),
                  "Drv_stEnable": enabled.astype(float)})
    csv = tmp_path / "table.csv"
    csv.write_text("t,MotCtl_phiSetpoint,Enc_phiLoad,Drv_stEnable\n" + "".join(
        f"{float(a)!r},{float(b)!r},{float(c)!r},{int(d)}\n" for a, b, c, d in zip(t, np.degrees(u), np.degrees(y), enabled)))
    results = [read_measurement(path, options) for path in (mdf, mat, csv)]
    for record, report in results:
        assert report.kept_samples == (50, 260)
        np.testing.assert_allclose(record.angle_rad, y[50:260], atol=1e-12)
        np.testing.assert_allclose(record.command_rad, u[50:260], atol=1e-12)
    with pytest.raises(RecordImportError, match=r"matlab\.mat: no channel 'Enc_phiLod'.*--columns"):
        read_measurement(mat, ImportOptions(columns={**INCA_COLUMNS, "y": "Enc_phiLod"}))


def test_the_cli_takes_columns_units_and_valid_for_mdf(tmp_path, capsys):
    t, u, y = _signals(600)
    u = 0.4 * np.sign(np.sin(2 * np.pi * 2.0 * t))  # reverses often: excites what diagnose needs
    y = np.concatenate(([0.0], u[:-1]))
    mdf = _mdf(tmp_path / "inca.mf4", {"MotCtl_phiSetpoint": (np.degrees(u), "deg"),
                                        "Enc_phiLoad": (np.degrees(y), "deg")})
    code = main(["diagnose", str(mdf), "--columns", "u=MotCtl_phiSetpoint,y=Enc_phiLoad", "--noise-bound", "0.01",
                 "--json"])
    captured = capsys.readouterr()
    assert code == exit_codes.SUCCESS, captured.err
    assert json.loads(captured.out)["kind"] == "model_discrepancy"
    assert math.isfinite(json.loads(captured.out)["gap_initial"])
