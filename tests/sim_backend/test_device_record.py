"""The simulated devices' record of what they applied: serialisation, the alignment of a log with it, stalls."""

from __future__ import annotations

import pytest

from sim_backend.device_record import DEVICE_STALL_S, DeviceRecord, TickLateness


def test_a_record_survives_its_dict_and_refuses_another_kind():
    record = DeviceRecord((0, 5, 9), (6, 7, 15, 2, 0), 1, 0.02, 3, ((4, 0.5),), position_before_counts=0)
    assert DeviceRecord.from_dict(record.to_dict()) == record
    with pytest.raises(ValueError, match="not a device_record version 1"):
        DeviceRecord.from_dict({**record.to_dict(), "version": 2})


def test_rows_held_before_a_drives_late_first_target_are_no_samples_of_the_drive():
    # the host's sample 0 and 1 came too late: it logs them HELD at the enable position (100), and the drive, which
    # counts its samples from its first target on, took target 2 as its sample 0
    record = DeviceRecord((130, 160, 190), (), 0, position_before_counts=100)
    assert record.row_offset([100, 100, 130, 160, 190]) == -2
    assert record.wrong_rows([100, 100, 130, 160, 190], [True] * 5) == 0
    assert record.wrong_rows([100, 100, 130, 160, 999, 190], [True] * 6) == 2  # row 4, and row 5 beyond the record
    assert record.wrong_rows([100, 100, 130, 160, 999, 190], [True] * 4 + [False] * 2) == 0
    assert record.row_offset([100, 100]) == 0  # nothing moved: nothing to align by


def test_a_device_whose_ticks_are_numbered_on_the_wire_needs_no_alignment():
    assert DeviceRecord((100, 100, 130), (), 2).row_offset([100, 100, 130]) == 0


def test_a_stall_is_one_run_of_late_ticks_with_its_largest_delay():
    lateness = TickLateness()
    for sample, delay_s in [(0, 0.0), (1, 0.3), (2, 0.2), (3, 0.001), (4, 2 * DEVICE_STALL_S), (5, 0.0)]:
        lateness.observe(sample, delay_s)
    assert lateness.stalls == [(1, 0.3), (4, 2 * DEVICE_STALL_S)] and lateness.delay_max_s == 0.3
