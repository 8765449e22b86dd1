"""The simulated devices' record of what they applied: serialisation, the alignment of a log with it, stalls."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from sim_backend.device_record import DEVICE_STALL_S, AppliedTargets, DeviceRecord, TickLateness


def test_a_record_written_reopens_equal_with_its_targets_beside_it(tmp_path):
    record = DeviceRecord((0, 5, -9), (6, 7, 15, 2, 0), 1, 0.02, 3, ((4, 0.5),), position_before_counts=0)
    record.write(tmp_path / "record.json")
    document = json.loads((tmp_path / "record.json").read_text())
    assert document["version"] == 2 and document["applied_targets"] == {
        "file": "record.json.targets", "count": 3, "dtype": np.dtype("=i4").str}
    assert (tmp_path / "record.json.targets").stat().st_size == 3 * 4
    assert DeviceRecord.read(tmp_path / "record.json") == record
    assert DeviceRecord.read(tmp_path / "record.json") != dataclasses.replace(record, applied_targets=(0, 5, -8))


def test_an_old_or_foreign_record_and_a_short_targets_file_are_refused_saying_what_to_do(tmp_path):
    path = tmp_path / "record.json"
    DeviceRecord((1, 2, 3), (), 0).write(path)
    document = json.loads(path.read_text())
    with pytest.raises(ValueError, match="version 1 .*targets inline.* run the device again"):
        DeviceRecord.from_dict({**document, "version": 1, "applied_targets": [1, 2, 3]}, tmp_path)
    with pytest.raises(ValueError, match="not a device_record version 2: kind 'log'"):
        DeviceRecord.from_dict({**document, "kind": "log"}, tmp_path)
    (tmp_path / "record.json.targets").write_bytes(bytes(8))
    with pytest.raises(ValueError, match=r"record.json.targets: the record's applied targets file has 8 bytes, "
                                         r"expected 3 targets of 4 bytes; write the record again"):
        DeviceRecord.read(path)


def test_applied_targets_past_a_block_read_back_in_order_and_stay_readable_once_closed():
    targets = AppliedTargets()
    values = np.arange(-5, 2 * AppliedTargets.BLOCK_SAMPLES + 7) * 1001
    for value in values[:10].tolist():
        targets.append(value)
    early = targets.array()
    for value in values[10:].tolist():
        targets.append(value)
    assert len(targets) == values.size
    np.testing.assert_array_equal(early, values[:10])  # an array taken earlier does not change
    targets.close()
    np.testing.assert_array_equal(targets.array(), values)
    np.testing.assert_array_equal(early, values[:10])
    with pytest.raises(OverflowError):
        AppliedTargets().append(1 << 31)  # a target is an INTEGER32


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
