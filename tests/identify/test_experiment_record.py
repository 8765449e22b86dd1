"""ExperimentRecord validates itself and counts its flags."""

from __future__ import annotations

import math

import numpy as np
import pytest

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from identify.validation import InvalidInputError

META = ExperimentMetadata(sample_period_s=1e-3, source="cerone2009", transport="offline", encoder_bits=12,
                          noise_kind="uniform", noise_bound_rad=7.7e-4, excitation="prbs", excitation_seed=3)


def record(**changes):
    values = dict(time_s=np.arange(5) * 1e-3, command_rad=np.zeros(5), angle_rad=np.zeros(5),
                  encoder_counts=np.arange(5), flags=None, metadata=META)
    values.update(changes)
    return ExperimentRecord(**values)


def test_flags_give_the_valid_mask_and_lost_count():
    flags = np.array([0, SampleFlag.LOST, SampleFlag.LATE, SampleFlag.DUPLICATE, SampleFlag.LOST | SampleFlag.LIMITED])
    rec = record(angle_rad=[0.0, math.nan, 0.1, 0.1, math.nan], flags=flags)
    np.testing.assert_array_equal(rec.valid_mask, [True, False, True, False, False])
    assert rec.lost_count == 2
    assert rec.count_flag(SampleFlag.LIMITED) == 1
    assert rec.sample_period_s == 1e-3 and len(rec) == 5
    assert record().flags.dtype == np.uint8 and not record().flags.any()


@pytest.mark.parametrize(("changes", "message"), [
    ({"angle_rad": np.zeros(4)}, "angle_rad has 4"),
    ({"time_s": [0.0, 1e-3, 1e-3, 3e-3, 4e-3]}, "time_s: sample 2 .* times must increase strictly"),
    ({"angle_rad": [0.0, math.nan, 0.0, 0.0, 0.0]}, "angle_rad: sample 1 .* LOST flag"),
    ({"flags": [SampleFlag.LOST, 0, 0, 0, 0]}, "a LOST sample must have angle NaN"),
    ({"command_rad": [0.0, 0.0, math.inf, 0.0, 0.0]}, "command_rad: sample 2"),
    ({"flags": [256, 0, 0, 0, 0]}, "flags: sample 0 is 256; expected SampleFlag bits"),
    ({"metadata": {"sample_period_s": 1e-3}}, "metadata: expected ExperimentMetadata"),
    ({"encoder_counts": [0.5, 1, 2, 3, 4]}, "encoder_counts: expected integer"),
])
def test_invalid_records_are_refused_with_the_sample_named(changes, message):
    with pytest.raises(InvalidInputError, match=message):
        record(**changes)


def test_record_arrays_are_read_only_copies():
    angles = np.zeros(5)
    rec = record(angle_rad=angles)
    angles[0] = 1.0
    assert rec.angle_rad[0] == 0.0
    with pytest.raises(ValueError):
        rec.angle_rad[0] = 2.0


def test_metadata_round_trips_through_a_plain_dict_and_keeps_unknown_keys():
    data = META.to_dict()
    assert ExperimentMetadata.from_dict(data) == META
    gaussian = ExperimentMetadata(sample_period_s=0.01, noise_kind="gaussian", noise_bound_rad=math.inf)
    assert gaussian.to_dict()["noise_bound_rad"] == "inf"
    assert ExperimentMetadata.from_dict(gaussian.to_dict()).noise_bound_rad == math.inf
    newer = ExperimentMetadata.from_dict({"sample_period_s": 0.01, "rig_temperature_c": 21.5})
    assert newer.extra["rig_temperature_c"] == 21.5
    with pytest.raises(InvalidInputError, match="sample_period_s"):
        ExperimentMetadata(sample_period_s=0.0)


def test_the_nominal_grid_is_told_from_a_measured_time_column():
    nominal = record(time_s=2.5 + np.arange(5) * 1e-3)
    assert nominal.time_column_is_nominal()
    np.testing.assert_allclose(nominal.period_deviation_s, 0.0, atol=1e-12)
    measured = record(time_s=[0.0, 1.0e-3, 2.2e-3, 3.0e-3, 4.0e-3])
    assert not measured.time_column_is_nominal()
    np.testing.assert_allclose(measured.period_deviation_s, [0.0, 0.2e-3, -0.2e-3, 0.0], atol=1e-12)
