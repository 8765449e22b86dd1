"""Counts <-> radians: quantisation within half a count, wrap-around, sign, direction, offset, multi-turn."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from identify.validation import InvalidInputError
from rig.protocols.encoder_counts import EncoderResolution


def test_quantization_error_is_within_half_a_count_for_every_angle_of_a_revolution():
    for bits in (8, 12, 15):
        encoder = EncoderResolution(bits=bits, signed=True)
        angles = np.linspace(-math.pi + 1e-9, math.pi - 1e-9, 100_001)
        decoded = encoder.rad_from_counts(encoder.counts_from_rad(angles), near_rad=angles)  # +pi rounds to -pi
        assert np.max(np.abs(decoded - angles)) <= math.pi / 2**bits + 1e-12
        assert encoder.quantization_bound_rad == pytest.approx(math.pi / 2**bits)


def test_single_turn_unsigned_wraps_at_2_to_the_n():
    encoder = EncoderResolution(bits=12)
    assert encoder.counts_from_rad(0.0) == 0
    assert encoder.counts_from_rad(2 * math.pi - 1e-6) == 0  # rounds up to 4096, which wraps to 0
    assert encoder.counts_from_rad(2 * math.pi + math.pi / 2) == 1024
    assert encoder.counts_from_rad(-encoder.count_rad) == 4095
    assert encoder.rad_from_counts(4095) == pytest.approx(2 * math.pi - encoder.count_rad)
    assert encoder.rad_from_counts(4095, near_rad=0.0) == pytest.approx(-encoder.count_rad)
    with pytest.raises(InvalidInputError, match="counts: expected position values from 0 to 4095"):
        encoder.rad_from_counts(4096)


def test_signed_direction_and_offset_as_a_cia406_device_reports_them():
    encoder = EncoderResolution(bits=10, signed=True, direction=-1, offset_counts=100)
    counts = encoder.counts_from_rad(np.array([0.0, encoder.count_rad * 3, -encoder.count_rad * 3]))
    np.testing.assert_array_equal(counts, [100, 97, 103])
    assert encoder.counts_from_rad(encoder.count_rad * 200) == -100
    assert encoder.rad_from_counts(-100) == pytest.approx(encoder.count_rad * 200)
    np.testing.assert_allclose(encoder.rad_from_counts(counts), [0.0, encoder.count_rad * 3, -encoder.count_rad * 3])


def test_multi_turn_counter_keeps_whole_revolutions():
    encoder = EncoderResolution(bits=12, multi_turn_bits=4, signed=True)
    assert encoder.range_rad == pytest.approx(16 * 2 * math.pi)
    angle = 5.25 * 2 * math.pi
    assert encoder.counts_from_rad(angle) == 5 * 4096 + 1024
    assert encoder.rad_from_counts(encoder.counts_from_rad(-angle)) == pytest.approx(-angle)
    # past the end of the counter it wraps at 2**16
    assert encoder.counts_from_rad(8 * 2 * math.pi) == -(1 << 15)


@settings(max_examples=200, deadline=None)
@given(bits=st.integers(1, 24), multi=st.integers(0, 8), signed=st.booleans(), direction=st.sampled_from((1, -1)),
       offset=st.integers(0, 2**32), turns=st.floats(-3.0, 3.0))
def test_round_trip_is_within_half_a_count_modulo_the_range(bits, multi, signed, direction, offset, turns):
    encoder = EncoderResolution(bits=bits, multi_turn_bits=multi, signed=signed, direction=direction,
                                offset_counts=offset % (1 << (bits + multi)))
    angle = turns * 2 * math.pi
    decoded = encoder.rad_from_counts(encoder.counts_from_rad(angle), near_rad=angle)
    assert abs(decoded - angle) <= encoder.quantization_bound_rad * (1 + 1e-9) + 1e-12


def test_invalid_resolutions_are_rejected_by_name():
    with pytest.raises(InvalidInputError, match="bits: expected an integer from 1 to 32"):
        EncoderResolution(bits=0)
    with pytest.raises(InvalidInputError, match="direction"):
        EncoderResolution(bits=12, direction=2)
    with pytest.raises(InvalidInputError, match="offset_counts: expected an integer from 0 to 4095"):
        EncoderResolution(bits=12, offset_counts=4096)
    with pytest.raises(InvalidInputError, match="angle_rad"):
        EncoderResolution(bits=12).counts_from_rad(float("nan"))


def test_one_sample_at_a_time_gives_the_same_counts_and_angles_as_arrays():
    rng = np.random.default_rng(0)
    for encoder in (EncoderResolution(12, signed=True), EncoderResolution(10, 3, False, -1, 77)):
        angles = rng.uniform(-30, 30, 3000)
        # exact half-count ties round to even in both paths
        angles[:300] = (np.arange(300) - 150 + 0.5) * encoder.count_rad
        counts = encoder.counts_from_rad(angles)
        assert np.array_equal(counts, [encoder.counts_from_rad(float(a)) for a in angles])
        decoded = encoder.rad_from_counts(counts, near_rad=angles)
        assert np.array_equal(decoded, [encoder.rad_from_counts(int(c), near_rad=float(a)) for c, a in zip(counts, angles)])
