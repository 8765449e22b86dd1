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
from identify.model_discrepancy.drive_torque import LoadTorqueCheck, load_torque_check
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


def _check(record: dict, weight_torque: float = math.nan):
    return load_torque_check(record["command_rad"], record["angle_rad"], record["torque_nm"], _AbsoluteBlock(record),
                             float(record["nominal"]["sample_period_s"]), weight_torque)


def _diagnosed_against_the_servo(record: dict):
    """The record diagnosed with the drive's torque (N m, gear ratio 1) from the generator's nominal servo as our
    drive train, with physical units, so that the torque can exclude a weight."""
    model = PlantModel((confusion.nominal_drive_train(record["nominal"]),))
    return diagnose_model(record["command_rad"], record["angle_rad"],
                          confusion.independent_noise_bound(record["nominal"]), 1e-3, model,
                          drive_torque=record["torque_nm"], drive_torque_nm_per_unit=1.0)


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


def test_a_torque_well_under_what_the_sags_weight_would_put_on_the_drive_excludes_the_weight():
    # the eccentric record's sag is 7 standard deviations from zero, its torque holds none; W is what a weight
    # giving that sag would put on the drive (the pipeline takes it from the start model's drive train)
    record = _record("eccentricity", 1000, "steps", "cascade")
    check = _check(record)
    assert check.outcome == "undecided" and check.sag_rad >= 5.0 * check.sag_sigma_rad, check.text()
    bound = check.torque + 3.0 * check.torque_sigma
    excluded = _check(record, weight_torque=3.3 * bound)
    assert excluded.outcome == "no_load_torque" and "the sag is the sensor's" in excluded.text()
    assert _check(record, weight_torque=2.7 * bound).outcome == "undecided"  # within the model's margin of 3
    assert LoadTorqueCheck.from_dict(json.loads(json.dumps(excluded.to_dict()))) == excluded
    older = {key: value for key, value in check.to_dict().items() if key != "weight_torque"}
    assert math.isnan(LoadTorqueCheck.from_dict(older).weight_torque)  # a document written before W was known


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
def test_a_drive_train_model_lets_the_torque_exclude_the_weight_and_leave_the_sensor_errors_open():
    # the start model is the generator's nominal servo as our drive train, with physical units: the weight the
    # sag needs (N m at the drive, gear ratio 1, the torque in N m) is over 3 times the torque's upper bound, so
    # gravity is excluded, and the sensor errors that read like the sag are searched: over this record's angles
    # the once-per-revolution error, an offset and a gain error stay alike (listed, none named)
    record = _record("eccentricity", 1002, "multisine", "cascade")
    result = _diagnosed_against_the_servo(record)
    check = result.load_torque_check
    assert check is not None and check.outcome == "no_load_torque", result.verdict_reason
    assert check.weight_torque > 3.0 * (check.torque + 3.0 * check.torque_sigma)
    assert "gravity" not in (*result.missing_effects, *result.ambiguous_between)
    assert "encoder_error" in (*result.missing_effects, *result.ambiguous_between), result.verdict_reason
    assert "no weight is carried" in result.verdict_reason and "gravity not tried" in result.verdict_reason


@pytest.mark.slow
def test_a_weight_the_drive_carries_is_named_where_a_drifting_gain_reads_like_its_steps():
    # the servo as our drive train: the angle alone leaves this weight open beside a drifting gain (what the sags
    # of its steps leave is a slope and a value that change over the record) and the encoder error; the drive
    # carries the weight, so the sensor errors that read like the sag are not tried again, the drifting gain among
    # them (it was, and the weight stayed open beside it)
    record = _record("gravity", 1012, "steps", "cascade")
    result = _diagnosed_against_the_servo(record)
    assert result.load_torque_check is not None and result.load_torque_check.outcome == "load_torque"
    assert result.verdict == "named" and result.missing_effects == ("gravity",), result.verdict_reason
    assert "gain_drift not tried" in result.verdict_reason


@pytest.mark.slow
def test_a_large_sensor_error_the_angle_leaves_open_beside_a_weight_is_named_by_the_torque():
    # a once-per-revolution sensor error of 30 mrad: from the angle alone gravity or the sensor error; the drive
    # carries no weight (a weight giving the sag would put 3.8 N m on it), and the sensor error is named and sized
    record = confusion.generator_module().generate(
        "eccentricity", 1000, excitation="steps", duration_s=confusion.INDEPENDENT_DURATION_S["steps"], bits=12,
        noise_rad=confusion.NOISE_STD_RAD, torque_noise_nm=TORQUE_NOISE_NM, nominal={"servo": "cascade"},
        a1_rad=0.03, a2_rad=0.0)
    result = _diagnosed_against_the_servo(record)
    assert result.missing_effects == ("encoder_error",) and result.load_torque_check.outcome == "no_load_torque"
    assert result.steps[0].parameters["once_per_rev_rad"] == pytest.approx(0.03, rel=0.1)


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
    with pytest.raises(InvalidInputError, match="drive_torque_nm_per_unit"):
        diagnose_model(u, u, 1e-3, 1e-3, drive_torque=np.zeros(400), drive_torque_nm_per_unit=0.0)


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


def test_rig_diagnose_takes_the_torques_scale_from_the_option_or_a_rig_logs_summary(tmp_path):
    from identify.experiment_record import ExperimentMetadata
    from rig.commands.diagnose import _torque_scale
    from rig.log_file import LogWriter
    from rig.record_import import ImportOptions, read_measurement

    record = _record("gravity", 1004, "steps", "cascade")
    csv, log = _files(tmp_path, record)
    assert _torque_scale(read_measurement(log)[0]) is None  # no summary: a log of a run that did not end
    summarised = tmp_path / "summarised.csv"
    with LogWriter(summarised, ExperimentMetadata(sample_period_s=1e-3), drive_torque_unit="permille_of_rated_torque") as out:
        for k in range(50):
            out.append(k * 1e-3, 0.01 * k, 0.01 * k, drive_torque=float(k))
        out.write_summary({"drive_torque_nm_per_unit": 0.00239})
    assert _torque_scale(read_measurement(summarised)[0]) == 0.00239
    columns = ImportOptions(columns={"t": "t", "u": "u", "y": "y", "tau": "torque"})
    from_csv = read_measurement(csv, columns)[0]
    assert _torque_scale(from_csv) is None  # another tool's column: no scale known
    assert _torque_scale(from_csv, 1.0) == 1.0  # unless --torque-scale gives it
    assert _torque_scale(read_measurement(summarised)[0], 0.002) == 0.002  # which overrides the summary's


def test_rig_diagnose_refuses_a_torque_scale_that_is_not_positive_by_its_option(tmp_path, capsys):
    from rig import exit_codes
    from rig.cli import main

    csv, _ = _files(tmp_path, _record("gravity", 1004, "steps", "cascade"))
    code = main(["diagnose", str(csv), "--noise-bound", "0.002", "--columns", "t=t,u=u,y=y,tau=torque",
                 "--torque-scale", "0"])
    assert code != exit_codes.SUCCESS and "--torque-scale" in capsys.readouterr().err


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
