"""The CANopen master's proof that its receive stream is whole (:class:`~rig.transports.canopen_link.CanOpenTransport`).

The master tells which SYNC is which sample, which target (CSP) or interpolation record (IP) was in force at each
SYNC, and under which SYNC each TPDO goes, from the order of the frames it receives, its own SYNCs and RPDOs
among them (their echoes: SocketCAN's loopback, python-can's ``receive_own_messages``). A frame lost on receive
(a full socket receive buffer, a controller's RX overrun) breaks that: a lost SYNC echo shifts every later sample
by one instant, a lost RPDO echo leaves the master with the wrong target in force or a wrong copy of the drive's
interpolation buffer. A lost TPDO only costs its sample (LOST), but where the loss is seen only as a count, the
master cannot tell which frame it was.

What shows a loss:

* **Its own RPDOs come back in the order sent** (one socket's frames leave and are echoed in the order they were
  sent): an echo that is not the oldest RPDO whose echo is due shows that the ones before it were lost on receive
  (they reached the bus: a later frame of the same socket did). Consecutive RPDOs may carry the same value; an
  echo is then matched to the first of them, and the sample that depends on which of them it was waits
  (below).
* **Its own SYNCs come back once each**: from a cyclic task of the kernel or the interface (SocketCAN's broadcast
  manager, hardware periodic sending) two SYNC echoes 1.5 periods or more apart have a SYNC between them that
  the master did not receive. From the master's :class:`~rig.transports.canopen_sync.SyncThread` (a thread of
  this process, late whenever the host is busy) a long gap is a late SYNC only if the thread's own two sends
  were that far apart (:meth:`~rig.transports.canopen_sync.SyncThread.longest_spacing_s`). An external producer's
  SYNCs can only be checked by the count below.
* **The interface's count of frames its receive queue dropped** (udp_multicast and SocketCAN: the socket's
  ``sk_drops``, what SO_RXQ_OVFL reports; :func:`rig.protocols.can_interfaces.receive_drop_counter`), read at
  every SYNC echo: a rise says frames after the previous SYNC echo were lost, not which.
* **An error frame with an RX overflow** of the CAN controller (``CAN_ERR_CRTL_RX_OVERFLOW``).

What the master does: it stops the run (:class:`TransportError` naming what was lost and what to do), and every
sample from the first one the loss can have touched is reported AMBIGUOUS; the base class's stop ends it, as
every stop, in quick stop and disable. A run is not continued with the bookkeeping re-derived: nothing in the
cycle's frames proves it right again in general (0x6062 repeats whenever the command holds a value, 0x60C4:4 is
read by SDO only), and a receive queue that overflows is a host that does not keep up with the rate.

A sample whose row depends on an echo still due is held back (not reported) until that echo, or a loss, is
known: in CSP a target put on the bus before its SYNC's echo was seen and not yet echoed (it may have crossed its
SYNC, HELD, or had its echo lost, in force) whose value differs from the one assumed in force; in IP a SYNC that
found the master's copy of the buffer empty with records on the bus. Every later sample waits behind it, so
samples are reported in order.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
from dataclasses import dataclass
from typing import Any

from rig.protocols.errors import TransportError
from rig.transports.canopen_sync import SyncThread

__all__ = ["MISSING_SYNC_PERIODS", "CanOpenReceiveChecks", "OwnFrame"]

MISSING_SYNC_PERIODS = 1.5
"""Two echoes of a precise SYNC producer's SYNCs at least this many periods apart have one between them that was
not received (the time stamps' jitter is far below half a period)."""
RECEIVE_ADVICE = ("the host's receive queue does not keep up: use a faster or less loaded host, a lower sample "
                  "rate, or a larger receive buffer (net.core.rmem_max; SocketCAN: also the interface's RX ring)")


@dataclass(frozen=True)
class OwnFrame:
    """An RPDO the master put on the bus, its echo due: ``serial`` in sending order, ``after_sync`` the SYNC
    count the master had seen when it sent it (it can be in force from the next SYNC on)."""

    serial: int
    cob_id: int
    data: bytes
    after_sync: int


class CanOpenReceiveChecks:
    """The checks and the hold-back of the module docstring, as methods of the CANopen transport (called with
    its lock held, from its send and receive paths)."""

    def _init_receive_checks(self) -> None:
        self._own_rpdos: collections.deque[OwnFrame] = collections.deque()
        self._own_serial = 0
        self._waits_for: dict[int, int] = {}  # sample -> serial of the RPDO whose echo its row waits for
        self._held_back: collections.deque[Any] = collections.deque()  # FeedbackSamples, in order
        self._untrusted_from: int | None = None  # the first sample the loss can have touched
        self._receive_losses: list[str] = []
        self._own_frames_lost = 0
        self._drop_counter: Any = None
        self._drops_at_start = 0
        self._drops_seen = 0

    # -- the interface's count ----------------------------------------------------------------------------

    def _open_drop_counter(self) -> Any:
        """The interface's count of frames its receive queue dropped (a function), or None. A seam: a scripted
        bus replaces it."""
        from rig.protocols.can_interfaces import receive_drop_counter

        return receive_drop_counter(self.network.bus, self.interface)

    def _start_drop_count(self) -> None:
        self._drop_counter = self._open_drop_counter()
        if self._drop_counter is not None:
            self._drops_at_start = self._drops_seen = self._drop_counter()

    def _stop_drop_count(self) -> None:
        counter, self._drop_counter = self._drop_counter, None
        if counter is not None:
            with contextlib.suppress(OSError):
                self._drops_seen = counter()
            close = getattr(counter, "close", None)
            if close is not None:
                close()

    @property
    def receive_drops(self) -> int:
        """Frames lost on receive: the interface's count since the link opened where it keeps one, else the
        master's own frames (SYNCs, RPDOs) it found missing."""
        if self._drop_counter is not None or self._drops_seen != self._drops_at_start:
            return self._drops_seen - self._drops_at_start
        return self._own_frames_lost

    def _check_drop_count(self) -> None:
        """At a SYNC echo, before it is counted: frames the queue dropped since the previous SYNC echo was read
        lie after that echo in the stream, so the sample of that SYNC is the first they can touch."""
        if self._drop_counter is None:
            return
        try:
            drops = self._drop_counter()
        except OSError:
            return
        if drops > self._drops_seen:
            new, self._drops_seen = drops - self._drops_seen, drops
            self._receive_broken(f"the interface's receive queue dropped {new} frame{'s' * (new != 1)} (its own "
                                 "count; which ones it does not say)", self._sync_count)

    def _check_rx_overflow(self, description: str) -> None:
        """An error frame reporting the controller's RX overflow: frames before it were lost to the host."""
        self._receive_broken(f"the CAN controller's receive buffer overflowed ({description})", self._sync_count)

    # -- the master's own RPDOs ---------------------------------------------------------------------------

    def _own_rpdo_sent(self, cob_id: int, data: bytes) -> OwnFrame:
        self._own_serial += 1
        frame = OwnFrame(self._own_serial, cob_id, bytes(data), self._sync_count)
        self._own_rpdos.append(frame)
        return frame

    def _own_rpdo_unsent(self, frame: OwnFrame) -> None:
        """Putting ``frame`` on the bus failed: no echo will come."""
        with contextlib.suppress(ValueError):
            self._own_rpdos.remove(frame)

    def _own_rpdo_echoed(self, cob_id: int, data: bytes) -> bool:
        """The echo of one of the master's RPDOs: matched to the oldest due with that COB-ID and data; the ones
        due before it were lost on receive. Whether the bookkeeping still holds."""
        data = bytes(data)
        due = list(self._own_rpdos)
        index = next((i for i, frame in enumerate(due) if (frame.cob_id, frame.data) == (cob_id, data)), None)
        if index is None:
            self._receive_broken(f"an echo of RPDO 0x{cob_id:03X} ({data.hex()}) that the master has not sent, or "
                                 "not once more", self._sync_count)
            return False
        lost = due[:index]
        for _ in range(index + 1):
            self._own_rpdos.popleft()
        matched = due[index]
        if lost:
            self._own_frames_lost += len(lost)
            names = ", ".join(f"RPDO 0x{frame.cob_id:03X} ({frame.data.hex()})" for frame in lost[:3])
            self._receive_broken(f"the echo of {len(lost)} of its own frame{'s' * (len(lost) != 1)} never came "
                                 f"({names}{', ...' if len(lost) > 3 else ''})", lost[0].after_sync)
            return False
        # another frame due with the same value: this echo may be that one's, the one matched lost; the samples
        # that depend on the matched one wait for the last of them
        same = next((frame for frame in reversed(self._own_rpdos) if (frame.cob_id, frame.data) == (cob_id, data)),
                    None)
        for sample, serial in list(self._waits_for.items()):
            if serial <= matched.serial:
                if same is None:
                    del self._waits_for[sample]
                else:
                    self._waits_for[sample] = same.serial
        self._report_held_back()
        return True

    def _wait_for_rpdo_echo(self, sample: int, in_force_counts: int, *, any_value: bool = False) -> None:
        """At the SYNC of ``sample``: if an RPDO whose echo is due carries another value than ``in_force_counts``
        (``any_value``: any RPDO due), the row of ``sample`` waits for that echo (module docstring)."""
        waited = [frame for frame in self._own_rpdos if any_value or frame.data != self._packed(in_force_counts)]
        if waited:
            self._waits_for[sample] = waited[-1].serial

    def _packed(self, counts: int) -> bytes:
        return bytes(self._rpdo.pack({index: counts for index in self._rpdo.fields}))

    # -- SYNCs --------------------------------------------------------------------------------------------

    def _check_sync_spacing(self, timestamp: float) -> None:
        """At a SYNC echo of the master's own producer, before it is counted: a gap that shows a SYNC between
        this echo and the one before that the master did not receive."""
        if self.sync_producer != "master" or not self._syncs:
            return
        gap = timestamp - self._syncs[-1][0]
        period = self.sample_period_s
        if isinstance(self._sync_task, SyncThread):
            # a thread's SYNC is late when the host is busy: lost only if the thread sent it sooner than the gap
            # says (by more than half the shortest spacing it keeps, well above the time stamps' jitter)
            spacing = self._sync_task.longest_spacing_s(self._sync_count + 1)
            if spacing is None or gap <= spacing + 0.5 * min(period, self.min_cycle_s):
                return
            missing = max(1, round((gap - spacing) / period))
        elif gap >= MISSING_SYNC_PERIODS * period:
            missing = round(gap / period) - 1
        else:
            return
        self._own_frames_lost += missing
        self._receive_broken(f"{missing} SYNC echo{'es' * (missing != 1)} never came ({1e3 * gap:.3g} ms between "
                             f"two SYNC echoes, period {1e3 * period:.3g} ms)", self._sync_count)

    # -- the reaction -------------------------------------------------------------------------------------

    def _receive_broken(self, what: str, from_sync: int) -> None:
        """A loss the bookkeeping cannot ride through: the samples from SYNC ``from_sync`` on are AMBIGUOUS, the
        ones held back are reported so, and the run stops (module docstring)."""
        first = 0 if self._origin is None else max(0, from_sync - self._origin)
        if self._untrusted_from is None or first < self._untrusted_from:
            self._untrusted_from = first
        self._receive_losses.append(what)
        self._waits_for.clear()
        self._report_held_back()
        where = "before streaming" if self._origin is None else f"at sample {first}"
        self._report_fault(TransportError(
            f"{self.name}: frames were lost on receive {where}: {what}. The master tells which target the drive "
            f"applied at each SYNC from the order of the frames it receives, so the samples from {first} on are "
            f"flagged AMBIGUOUS and the run stops; {RECEIVE_ADVICE}"))
        self._arrived.notify_all()

    def _untrusted(self, seq: int) -> bool:
        return self._untrusted_from is not None and seq >= self._untrusted_from

    def _report(self, sample: Any) -> None:
        """A complete sample to the runner, or held back behind one whose row waits for an echo."""
        if self._untrusted(sample.seq) and not sample.ambiguous:
            sample = dataclasses.replace(sample, ambiguous=True)
        if self._held_back or sample.seq in self._waits_for:
            self._held_back.append(sample)
            return
        self._ready.append(sample)
        self._arrived.notify_all()

    def _report_held_back(self) -> None:
        while self._held_back and self._held_back[0].seq not in self._waits_for:
            sample = self._held_back.popleft()
            if self._untrusted(sample.seq) and not sample.ambiguous:
                sample = dataclasses.replace(sample, ambiguous=True)
            self._ready.append(sample)
            self._arrived.notify_all()
