"""The runner's sample ledger, scripted: feedback filed by sample number, rows final in order."""

from __future__ import annotations

import math

import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.cia402 import DriveState, statusword_for
from rig.sample_ledger import SampleLedger
from rig.transports.base import FeedbackSample

ENABLED = statusword_for(DriveState.OPERATION_ENABLED) | 0x1000


def _feedback(seq: int, angle: float = 0.5, **fields) -> FeedbackSample:
    values = dict(seq=seq, encoder_counts=seq, load_angle_rad=angle, drive_position_rad=0.0, statusword=ENABLED,
                  host_time_s=0.0)
    values.update(fields)
    return FeedbackSample(**values)


def _release_all(ledger: SampleLedger, device_sample: int) -> list:
    rows = []
    while (row := ledger.next_final(device_sample)) is not None:
        rows.append((row.seq, row.time_s, row.command_rad, row.angle_rad, row.flags))
        ledger.release()
    return rows


def test_feedback_out_of_order_fills_its_own_rows_and_rows_leave_in_order_once_final():
    ledger = SampleLedger(sample_period_s=0.01, pending_cycles=2)
    for seq in range(4):
        ledger.open_row(seq, command_rad=0.1 * seq)
    ledger.file(_feedback(2, angle=2.0))
    ledger.file(_feedback(0, angle=0.0))
    assert _release_all(ledger, device_sample=1) == []  # row 0 could still change until instant 2
    rows = _release_all(ledger, device_sample=3)
    assert [(row[0], row[1], row[4]) for row in rows] == [(0, 0.0, 0), (1, 0.01, int(SampleFlag.LOST))]
    assert rows[0][3] == 0.0 and math.isnan(rows[1][3]) and len(ledger) == 2  # rows 2, 3 still open
    assert ledger.counts["lost"] == 1


def test_a_held_sample_logs_the_command_really_applied_and_late_counts_only_late_rows():
    """HELD (a setpoint that missed its instant) and LATE (an instant off the period) are two flags, counted
    apart: ``late`` is the number of rows flagged LATE, as ``rig run --json`` reports it."""
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=1, late_tolerance_s=0.0005)
    for seq, command in enumerate((1.0, 2.0, 3.0)):
        ledger.open_row(seq, command)
    ledger.file(_feedback(0, applied_position_rad=1.0))
    ledger.file(_feedback(1, held=True, applied_position_rad=1.0))  # setpoint 1 came after its SYNC
    ledger.file(_feedback(2, applied_position_rad=3.0, instant_error_s=0.0008))  # its SYNC 0.8 ms off
    rows = _release_all(ledger, device_sample=5)
    assert [(row[2], row[4]) for row in rows] == [(1.0, 0), (1.0, int(SampleFlag.HELD)), (3.0, int(SampleFlag.LATE))]
    assert ledger.counts["held"] == ledger.counts["late"] == 1


def test_a_target_limited_on_the_way_back_to_the_plan_logs_the_command_applied_flagged_limited():
    """After a stall the host sent a target nearer the one in force than the plan (0.25, not 0.5): the row logs
    0.25, LIMITED and not HELD (the device applied what it was sent)."""
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=0)
    ledger.open_row(0, 0.5)
    ledger.file(_feedback(0, applied_position_rad=0.25, limited=True))
    (row,) = _release_all(ledger, device_sample=0)
    assert (row[2], row[4]) == (0.25, int(SampleFlag.LIMITED)) and ledger.counts["held"] == 0


def test_a_second_answer_marks_the_sample_duplicate_and_an_answer_to_no_open_row_is_stale():
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=1)
    ledger.open_row(0, 0.0)
    ledger.file(_feedback(0))
    ledger.file(_feedback(0))
    ledger.file(_feedback(7))
    assert ledger.counts["duplicate"] == 1 and ledger.counts["stale"] == 1
    (row,) = _release_all(ledger, device_sample=3)
    assert row[4] == int(SampleFlag.DUPLICATE)


def test_the_devices_samples_after_the_runs_last_are_dropped_not_stale():
    """A device samples on after the last setpoint until the run stops it: those answers belong to no sample
    of the run (not stale, which means too late for its sample); one for an unopened row within the run is."""
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=1, num_samples=2)
    ledger.open_row(0, 0.0)
    ledger.file(_feedback(1))  # before its row opens (counted until it does)
    ledger.open_row(1, 0.0)
    for seq in (2, 3, 4):
        ledger.file(_feedback(seq))
    assert ledger.counts["stale"] == 0
    ledger.file(_feedback(0))
    assert [row[0] for row in _release_all(ledger, device_sample=5)] == [0, 1]


@pytest.mark.parametrize(("fields", "flag"), [
    ({"target_ignored": True}, SampleFlag.NOT_FOLLOWED),
    ({"ambiguous": True}, SampleFlag.AMBIGUOUS),
    ({"instant_error_s": 0.0007}, SampleFlag.LATE),
    ({"statusword": statusword_for(DriveState.FAULT)}, SampleFlag.FAULT),
])
def test_what_the_device_said_about_a_sample_becomes_its_flag(fields, flag):
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=0, late_tolerance_s=0.0005)
    ledger.open_row(0, 0.0)
    ledger.file(_feedback(0, **fields))
    (row,) = _release_all(ledger, device_sample=0)
    assert row[4] == int(flag)


def test_a_sample_within_the_late_tolerance_is_not_late():
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=0, late_tolerance_s=0.0005)
    ledger.open_row(0, 0.0)
    ledger.file(_feedback(0, instant_error_s=-0.0004))
    assert _release_all(ledger, device_sample=0)[0][4] == 0


def test_a_sample_that_comes_before_its_row_is_filed_when_the_row_opens():
    """A device that passed instant 3 before the host queued setpoint 3 (a host stall longer than the lead,
    on serial v2, where the host hears of the device's instants only when it reads): not stale, HELD."""
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=1)
    for seq in range(3):
        ledger.open_row(seq, 0.1 * seq)
        ledger.file(_feedback(seq, applied_position_rad=0.1 * seq))
    ledger.file(_feedback(3, angle=3.0, held=True, applied_position_rad=0.2))
    assert ledger.counts["stale"] == 1  # no row yet
    ledger.open_row(3, 0.3)
    assert ledger.counts["stale"] == 0
    rows = _release_all(ledger, device_sample=5)
    assert rows[3][2:] == (0.2, 3.0, int(SampleFlag.HELD)) and ledger.counts["lost"] == 0


def test_the_first_fault_is_remembered_after_its_row_went_to_the_sink():
    # a loaded host wrote the fault's row final before the fault stopped the run; the runner then took the
    # stop's instant as the fault's and logged one sample more, flagged FAULT twice (clean-clone run: 122
    # samples where the fault came at sample 120)
    ledger = SampleLedger(sample_period_s=0.001, pending_cycles=1)
    for seq in range(3):
        ledger.open_row(seq, 0.0)
    ledger.file(_feedback(0))
    ledger.file(_feedback(1, statusword=statusword_for(DriveState.FAULT)))
    ledger.file(_feedback(2, statusword=statusword_for(DriveState.FAULT)))
    rows = _release_all(ledger, device_sample=2)
    assert [row[0] for row in rows] == [0, 1] and rows[1][4] & SampleFlag.FAULT
    assert ledger.first_fault == 1


def test_a_held_sample_whose_applied_command_is_unknown_is_unusable_not_logged_as_the_design():
    """A HELD answer that cannot say which target was in force: the row's command (the designed one) was not
    applied, so the row is flagged AMBIGUOUS (unusable) besides HELD; one that says it logs it."""
    ledger = SampleLedger(sample_period_s=0.01, pending_cycles=1)
    for seq in range(3):
        ledger.open_row(seq, command_rad=0.1 * seq)
    ledger.file(_feedback(0))
    ledger.file(_feedback(1, held=True))
    ledger.file(_feedback(2, held=True, applied_position_rad=0.0))
    rows = _release_all(ledger, device_sample=3)
    assert [(row[2], row[4]) for row in rows] == [
        (0.0, 0), (0.1, int(SampleFlag.HELD | SampleFlag.AMBIGUOUS)), (0.0, int(SampleFlag.HELD))]
    assert SampleFlag.AMBIGUOUS & SampleFlag.unusable()
