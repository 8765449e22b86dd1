"""The runner's book of samples: one row per sample number, feedback filed by its number, rows handed to
the log in order once they can no longer change.

A device-clocked run (:attr:`rig.transports.base.Transport.lead_samples` > 0) queues setpoints ahead of
the device; the device samples at its own instants and the transport reports, per sample, what the device
measured and which target was really in force. The ledger turns that into log rows:

* a row is opened when its setpoint is queued (``command_rad`` = the setpoint, flags = LOST);
* :meth:`SampleLedger.file` fills it from the feedback: LOST cleared, HELD and the command actually
  applied when the setpoint missed its instant, LIMITED (and the command applied) when the host sent a target
  nearer the one in force than the plan on its way back to the plan after a stall, LATE when the instant itself was off the period, NOT_FOLLOWED when the drive ignored it, AMBIGUOUS when
  the instant it answers is uncertain or, HELD, the command in force is not known (the row keeps a command
  that was not applied: unusable), FAULT in a fault state, DUPLICATE when a second answer comes for
  the same sample;
* :meth:`SampleLedger.next_final` / :meth:`SampleLedger.release` hand rows to the log oldest first, once
  their instant lies ``pending_cycles`` instants behind the device (a later answer could still come until
  then); a row leaves the ledger only after the sink took it.

Per sample everything is a dictionary lookup or a deque operation: no linear scans.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

from identify.experiment_record import SampleFlag
from rig.protocols.cia402 import DriveState, state_from_statusword_or_none
from rig.transports.base import FeedbackSample

__all__ = ["LedgerRow", "SampleLedger"]

_LOST, _LATE, _DUPLICATE, _LIMITED, _FAULT, _NOT_FOLLOWED, _HELD, _AMBIGUOUS = (int(flag) for flag in (
    SampleFlag.LOST, SampleFlag.LATE, SampleFlag.DUPLICATE, SampleFlag.LIMITED, SampleFlag.FAULT,
    SampleFlag.NOT_FOLLOWED, SampleFlag.HELD, SampleFlag.AMBIGUOUS))
_FAULT_STATES = (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
_MAX_EARLY = 1 << 16
"""Samples kept for rows not yet opened, at most (a device far ahead of the host: memory stays bounded)."""


@dataclass
class LedgerRow:
    """One sample as it goes to the log."""

    seq: int
    time_s: float
    command_rad: float
    angle_rad: float = float("nan")
    counts: int | None = None
    flags: int = _LOST
    drive_torque: float | None = None


@dataclass
class SampleLedger:
    """Rows by sample number (see the module docstring).

    Parameters
    ----------
    sample_period_s
        The device's sample period: row k is at time k T.
    pending_cycles
        A row is final this many sample instants after its own.
    late_tolerance_s
        A sample whose instant was further than this off the period is flagged LATE (its value is real,
        its time not exactly k T).
    num_samples
        The run's samples: rows 0 to ``num_samples - 1``. The device goes on sampling after the last one
        until the run stops it; those answers belong to no sample of the run and are dropped, not counted
        stale (stale is an answer that came too late for its sample, or answers a setpoint never sent).
    """

    sample_period_s: float
    pending_cycles: int
    late_tolerance_s: float = float("inf")
    num_samples: int = 1 << 62
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("lost", "held", "late", "duplicate", "stale", "not_followed"), 0))
    _rows: dict[int, LedgerRow] = field(default_factory=dict)
    _order: collections.deque[int] = field(default_factory=collections.deque)
    _answered: set[int] = field(default_factory=set)
    _early: dict[int, FeedbackSample] = field(default_factory=dict)
    written: int = 0
    """Rows below this sample number are in the sink."""
    _first_fault: int | None = None
    """The first sample filed with a fault in its statusword (:attr:`first_fault`)."""

    def open_row(self, seq: int, command_rad: float, *, late: bool = False) -> LedgerRow:
        """The row of setpoint ``seq`` (queued with ``command_rad``), LOST until its feedback is filed (at
        once if that came first: see :meth:`file`); ``late``: a host-paced setpoint that left after its
        deadline (flagged LATE)."""
        row = LedgerRow(seq, seq * self.sample_period_s, command_rad, flags=_LOST | (_LATE if late else 0))
        self._rows[seq] = row
        self._order.append(seq)
        early = self._early.pop(seq, None)
        if early is not None:
            self.counts["stale"] -= 1  # counted stale while it had no row
            self.file(early)
        return row

    def answered(self, seq: int) -> bool:
        return seq in self._answered

    def awaits(self, seq: int) -> bool:
        """Row ``seq`` is open and has no answer yet (an answer now is fresh feedback)."""
        return seq in self._rows and seq not in self._answered

    @property
    def all_answered(self) -> bool:
        return len(self._answered) == len(self._order)

    def file(self, sample: FeedbackSample, *, late: bool = False) -> DriveState | None:
        """File one feedback sample under its number; returns the drive state its statusword shows (the
        runner stops when that is not OPERATION ENABLED). ``late``: a host-paced answer that came after
        the next deadline (flagged LATE: the value is real, its time is not).

        A sample for a number beyond the last row opened is kept until its row opens: the device passed that
        instant before the host had queued its setpoint (a host stall longer than the lead, on a link that
        hears of the device's instants only when the host reads; the sample says HELD)."""
        if sample.seq >= self.num_samples:  # the device sampling on after the run's last sample
            return state_from_statusword_or_none(sample.statusword)
        row = self._rows.get(sample.seq)
        if row is None and sample.seq > self.last_opened:
            if len(self._early) < _MAX_EARLY and sample.seq not in self._early:
                self._early[sample.seq] = sample
            self.counts["stale"] += 1  # until its row opens (never, if it answers no setpoint of this run)
            return state_from_statusword_or_none(sample.statusword)
        if row is None:
            self.counts["stale"] += 1  # final already (LOST), or an answer to no setpoint of this run
            return None
        if sample.seq in self._answered:
            self.counts["duplicate"] += 1
            row.flags |= _DUPLICATE
            return None
        self._answered.add(sample.seq)
        row.angle_rad, row.counts, row.drive_torque = sample.load_angle_rad, sample.encoder_counts, sample.drive_torque
        row.flags &= ~_LOST
        if sample.held:
            row.flags |= _HELD
        if sample.limited:
            row.flags |= _LIMITED
        if late or abs(sample.instant_error_s) > self.late_tolerance_s:
            row.flags |= _LATE
        if sample.applied_position_rad is not None:
            row.command_rad = sample.applied_position_rad  # the data stay true: the command really applied
        elif sample.held:  # held, and what was in force is not known: the designed command was not applied
            row.flags |= _AMBIGUOUS
        if sample.target_ignored:
            row.flags |= _NOT_FOLLOWED
        if sample.ambiguous:
            row.flags |= _AMBIGUOUS
        state = state_from_statusword_or_none(sample.statusword)
        if state in _FAULT_STATES or (state is not None and state is not DriveState.OPERATION_ENABLED):
            row.flags |= _FAULT
            if self._first_fault is None or row.seq < self._first_fault:
                self._first_fault = row.seq
        return state

    def mark_fault(self, seq: int) -> None:
        """The device faulted during sample ``seq`` (the last one opened when the fault was raised)."""
        if seq in self._rows:
            self._rows[seq].flags |= _FAULT

    @property
    def last_opened(self) -> int:
        return self._order[-1] if self._order else -1

    def next_final(self, device_sample: int) -> LedgerRow | None:
        """The oldest row if it can no longer change (its instant lies ``pending_cycles`` instants behind
        ``device_sample``), else None. It stays in the ledger until :meth:`release`: a row leaves only after
        the sink took it, so Ctrl-C landing in between loses nothing."""
        if self._order and self._order[0] <= device_sample - self.pending_cycles:
            return self._rows[self._order[0]]
        return None

    def release(self) -> None:
        """Drop the oldest row (the sink has it) and count its flags."""
        seq = self._order.popleft()
        row = self._rows.pop(seq)
        self._answered.discard(seq)
        self.counts["lost"] += bool(row.flags & _LOST)
        self.counts["held"] += bool(row.flags & _HELD)
        self.counts["late"] += bool(row.flags & _LATE)
        self.counts["not_followed"] += bool(row.flags & _NOT_FOLLOWED)

    def write_final(self, newest: int, sink) -> None:
        """Hand every row that is final at ``newest`` (:meth:`next_final`) to ``sink.append``, oldest first,
        each once, even if Ctrl-C lands between the append and the release. The drive's torque goes as the
        keyword ``drive_torque``, only from a link that reports it."""
        while (row := self.next_final(newest)) is not None:
            if row.seq >= self.written:
                if row.drive_torque is None:
                    sink.append(row.time_s, row.command_rad, row.angle_rad, row.counts, row.flags)
                else:
                    sink.append(row.time_s, row.command_rad, row.angle_rad, row.counts, row.flags,
                                drive_torque=row.drive_torque)
                self.written = row.seq + 1
            self.release()

    @property
    def first_fault(self) -> int | None:
        """The first sample whose statusword showed a fault, also after its row went to the sink (a loaded host
        can write it final before the fault stops the run: the run then ended one sample later, the stop
        marked as a second FAULT row)."""
        return self._first_fault

    def __len__(self) -> int:
        return len(self._order)
