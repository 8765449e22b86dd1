"""The drive's torque as a second measured channel (:mod:`identify.model_discrepancy.drive_torque`): a weight on
the load and a once-per-revolution sensor error sag the angle alike, but only the weight is in the torque the drive
reports. The records come from the clean-room generator (``benchmarks/independent_plants``, used as a data source
only), whose torque actual value is the cycle mean of the motor's torque in thousandths of 2 N m, here with a
Gaussian noise of 5 mN m."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from identify.model_discrepancy import DiscrepancyReport, diagnose_model
from identify.model_discrepancy.drive_torque import load_torque_check
from identify.plant_blocks import PlantModel
from identify.validation import InvalidInputError

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
import model_discrepancy_confusion as confusion  # noqa: E402

TORQUE_NOISE_NM = 0.005


def _record(effect: str, seed: int, excitation: str, servo: str = "kinematic") -> dict:
    return confusion.generator_module().generate(
        effect, seed, excitation=excitation, duration_s=confusion.INDEPENDENT_DURATION_S[excitation], bits=12,
        noise_rad=confusion.NOISE_STD_RAD, torque_noise_nm=TORQUE_NOISE_NM, nominal={"servo": servo})


class _AbsoluteBlock:
    """The generator's nominal block run from rest at the record's first command (as the workflow's start model
    is, from its operating point)."""

    def __init__(self, record: dict) -> None:
        self.block = confusion.nominal_linear_block(record["nominal"])
        self.u0 = float(record["command_rad"][0])

    def simulate(self, u):
        return self.block.apply(np.asarray(u) - self.u0) + self.u0


def _check(record: dict):
    return load_torque_check(record["command_rad"], record["angle_rad"], record["torque_nm"], _AbsoluteBlock(record),
                             float(record["nominal"]["sample_period_s"]))


@pytest.mark.parametrize("servo", ["kinematic", "cascade"])
@pytest.mark.parametrize("seed, excitation", [(1000, "steps"), (1002, "multisine")])
def test_a_weight_shows_in_the_torque_with_its_size_and_hanging_angle(servo, seed, excitation):
    record = _record("gravity", seed, excitation, servo)
    truth = record["truth"]["parameters"]
    check = _check(record)
    assert check.outcome == "load_torque", check.text()
    # the drive holds m g r (gear ratio 1): within 4 standard deviations and 10 % (the cycle mean's trace of the
    # hold, a few per cent of the motor's inertia, and the weight's own sag of the state)
    assert abs(check.torque - truth["mgr_nm"]) <= 4.0 * check.torque_sigma + 0.1 * truth["mgr_nm"]
    assert abs(math.remainder(check.torque_hanging_angle_rad - truth["hanging_angle_rad"], 2 * math.pi)) < 0.15


@pytest.mark.parametrize("effect", ["eccentricity", "none"])
@pytest.mark.parametrize("seed, excitation", [(1000, "steps"), (1001, "chirp"), (1002, "multisine"), (1003, "prbs")])
def test_no_weight_is_shown_where_the_drive_carries_none(effect, seed, excitation):
    check = _check(_record(effect, seed, excitation))
    assert check.outcome == "undecided", check.text()
    assert check.torque <= 4.0 * check.torque_sigma


def test_a_torque_the_harmonic_only_projects_on_is_not_taken_for_a_weight():
    # cogging at 27 periods per revolution on a chirp: over the chirp's angles its once-per-revolution projection
    # is significant and in phase with the angle's, but the rest of it (passing the shaft mode) is left in the
    # torque, which is then far from white
    check = _check(_record("cogging", 1005, "chirp", "cascade"))
    assert check.torque >= 4.0 * check.torque_sigma and check.phase_apart_rad < 0.5
    assert check.outcome == "undecided" and check.residual_colour > 10.0, check.text()
    assert "not noise" in check.text()


@pytest.mark.slow
def test_the_angle_alone_leaves_the_weight_open_and_the_torque_leaves_a_sensor_error_open():
    weight = _record("gravity", 1004, "steps")
    model = PlantModel((confusion.nominal_linear_block(weight["nominal"]),))
    delta = confusion.independent_noise_bound(weight["nominal"])
    alone = diagnose_model(weight["command_rad"], weight["angle_rad"], delta, 1e-3, model)
    assert alone.verdict == "ambiguous" and "gravity" in alone.ambiguous_between and not alone.missing_effects
    assert alone.load_torque_check is None
    eccentric = _record("eccentricity", 1000, "steps")
    sensor = diagnose_model(eccentric["command_rad"], eccentric["angle_rad"], delta, 1e-3, model,
                            drive_torque=eccentric["torque_nm"])
    assert sensor.verdict == "ambiguous" and "gravity" not in sensor.missing_effects
    assert sensor.load_torque_check is not None and sensor.load_torque_check.outcome == "undecided"
    assert "no weight shows in the torque" in sensor.verdict_reason


@pytest.mark.slow
def test_the_torque_shows_the_sine_the_angles_short_span_cannot():
    # a multisine's angles span 0.9 rad: the weight's sag departs from a straight line by less than the noise
    # bound there, so the angle alone names gravity and leaves its shape open; the torque's harmonic is the bend
    # of the sine beyond the straight line (the lags hold the angle itself), resolved at 12 standard deviations
    record = _record("gravity", 1002, "multisine")
    model = PlantModel((confusion.nominal_linear_block(record["nominal"]),))
    result = diagnose_model(record["command_rad"], record["angle_rad"],
                            confusion.independent_noise_bound(record["nominal"]), 1e-3, model,
                            drive_torque=record["torque_nm"])
    assert result.missing_effects == ("gravity",) and result.verdict == "named", result.verdict_reason


def test_a_torque_of_another_length_is_refused_by_name():
    u = np.sin(np.linspace(0.0, 20.0, 400))
    with pytest.raises(InvalidInputError, match="drive_torque"):
        diagnose_model(u, u, 1e-3, 1e-3, drive_torque=np.zeros(399))


def _files(tmp_path, record: dict) -> tuple[Path, Path]:
    """The record as another tool's CSV (columns t, u, y, torque) and as the rig log a run with the drive's
    torque writes (rig-log v2, its drive_torque column)."""
    from identify.experiment_record import ExperimentMetadata, ExperimentRecord
    from rig.log_file import write_log

    csv = tmp_path / "run.csv"
    csv.write_text("t,u,y,torque\n" + "".join(
        f"{t!r},{u!r},{y!r},{q!r}\n" for t, u, y, q in zip(record["time_s"].tolist(), record["command_rad"].tolist(),
                                                          record["angle_rad"].tolist(), record["torque_nm"].tolist())))
    log = tmp_path / "rig_log.csv"
    period = float(record["nominal"]["sample_period_s"])
    write_log(log, ExperimentRecord(
        time_s=np.arange(record["time_s"].size) * period, command_rad=record["command_rad"],
        angle_rad=record["angle_rad"], encoder_counts=None, flags=None, drive_torque=record["torque_nm"],
        metadata=ExperimentMetadata(sample_period_s=period, extra={"drive_torque_unit": "N_m"})))
    return csv, log


def test_the_torque_is_read_alike_from_a_named_column_and_from_a_rig_log(tmp_path):
    from rig.record_import import ImportOptions, read_measurement

    record = _record("gravity", 1004, "steps", "cascade")
    csv, log = _files(tmp_path, record)
    from_csv, _ = read_measurement(csv, ImportOptions(columns={"t": "t", "u": "u", "y": "y", "tau": "torque"}))
    from_log, _ = read_measurement(log)
    np.testing.assert_array_equal(from_csv.drive_torque, record["torque_nm"])
    np.testing.assert_array_equal(from_log.drive_torque, record["torque_nm"])
    np.testing.assert_array_equal(from_log.angle_rad, from_csv.angle_rad)


@pytest.mark.slow
def test_rig_diagnose_reads_the_torque_of_a_rig_log_and_names_the_weight_the_angle_alone_leaves_open(tmp_path, capsys):
    from rig import exit_codes
    from rig.cli import main

    # behind the cascade servo the angle alone leaves this weight open beside a gain error (over its 1.7 rad the
    # sine's slope); the drive feels no sensor error. The log's drive_torque column is read without --columns.
    record = _record("gravity", 1004, "steps", "cascade")
    block = confusion.nominal_linear_block(record["nominal"])
    model = tmp_path / "model.toml"
    model.write_text('name = "two_mass"\nsample_period_s = 0.001\n[encoder]\nbits = 12\n[noise]\nkind = "uniform"\n'
                     'bound_rad = 0.0001\n[[blocks]]\ntype = "linear"\n'
                     f"a = [{', '.join(repr(float(v)) for v in block.a)}]\n"
                     f"b = [{', '.join(repr(float(v)) for v in block.b)}]\n")
    _, data = _files(tmp_path, record)
    bound = repr(confusion.independent_noise_bound(record["nominal"]))
    assert main(["diagnose", str(data), "--model", str(model), "--noise-bound", bound, "--json"]) == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    assert [entry["effect"] for entry in document["missing_effects"]] == ["gravity"]
    assert document["load_torque_check"]["outcome"] == "load_torque"
    truth = record["truth"]["parameters"]["mgr_nm"]
    check = document["load_torque_check"]
    assert abs(check["torque"] - truth) <= 4.0 * check["torque_sigma"] + 0.1 * truth
    assert document["verdict"] == "named" and "drive carries the weight" in document["verdict_reason"]
    assert document["version"] == 7
    assert DiscrepancyReport.from_dict(document).load_torque_check.to_dict() == check
