"""What a simulated device really did, sample by sample: the judge of a host's log (every logged command must
be the target the device applied at that sample), kept by every simulated device and written by one that runs
in a process of its own (:mod:`sim_backend.device_process`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["DEVICE_STALL_S", "DeviceRecord", "TickLateness"]

DEVICE_STALL_S = 0.01
"""A tick (or SYNC) this much after its instant is a stall of the device's own process (:class:`TickLateness`)."""


@dataclass(frozen=True)
class DeviceRecord:
    """One run of a simulated device.

    Attributes
    ----------
    applied_targets
        Sample k (the k-th SYNC or tick from the first target on): the target in drive counts the device
        applied, its own or the one it held.
    controlwords
        Every controlword received, in order.
    held
        Samples the device held because their target had not come: ticks without their setpoint (serial, raw
        CAN) or SYNCs that found the interpolation buffer empty (CANopen; a CSP drive cannot tell).
    tick_delay_max_s
        The latest any tick (or SYNC the device process produced) ran after its instant on the device's clock:
        how much the device itself was starved. None where the device does not keep the clock.
    receive_drops
        Frames the device's receive queue dropped when full (udp_multicast), None where unknown.
    position_before_counts
        The target in force before sample 0 (the position the drive held since it was enabled), where the device
        counts its samples from its first target (a CANopen drive); None where sample 0 is the host's (a tick
        number on the wire: serial, raw CAN).
    stalls
        ``(sample, delay_s)`` for every stall of the device's clock: the first tick of each run of ticks more than
        :data:`DEVICE_STALL_S` after their instants (the device then catches up in a burst), and the largest delay
        of the run.
    """

    applied_targets: tuple[int, ...]
    controlwords: tuple[int, ...]
    held: int
    tick_delay_max_s: float | None = None
    receive_drops: int | None = None
    stalls: tuple[tuple[int, float], ...] = ()
    position_before_counts: int | None = None

    KIND = "device_record"
    VERSION = 1

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.KIND, "version": self.VERSION, "applied_targets": list(self.applied_targets),
                "controlwords": list(self.controlwords), "held": self.held,
                "tick_delay_max_s": self.tick_delay_max_s, "receive_drops": self.receive_drops,
                "stalls": [list(stall) for stall in self.stalls], "position_before_counts": self.position_before_counts}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DeviceRecord:
        if data.get("kind") != cls.KIND or data.get("version") != cls.VERSION:
            raise ValueError(f"not a {cls.KIND} version {cls.VERSION}: kind {data.get('kind')!r}, "
                             f"version {data.get('version')!r}")
        return cls(tuple(int(v) for v in data["applied_targets"]), tuple(int(v) for v in data["controlwords"]),
                   int(data["held"]), data.get("tick_delay_max_s"), data.get("receive_drops"),
                   tuple((int(sample), float(delay)) for sample, delay in data.get("stalls", ())),
                   data.get("position_before_counts"))

    def row_offset(self, logged_counts: Sequence[int]) -> int:
        """The offset o such that a host's log row k is the device's sample k + o (``logged_counts``: the row's
        commands in drive counts). 0 where sample 0 is the host's. A device that counts its samples from its first
        target (:attr:`position_before_counts`) did not count the SYNCs whose target came too late for the host's
        sample 0 (HELD rows at the start): row and sample are then aligned where the target first moves off that
        position, as the conformance peer's judge does; a log or record that never moves gives 0."""
        if self.position_before_counts is None:
            return 0
        start = self.position_before_counts
        row = next((k for k, counts in enumerate(logged_counts) if counts != start), None)
        sample = next((k for k, counts in enumerate(self.applied_targets) if counts != start), None)
        return 0 if row is None or sample is None else sample - row

    def wrong_rows(self, logged_counts: Sequence[int], usable: Sequence[bool]) -> int:
        """How many usable rows of a log (``logged_counts``: the commands in drive counts) name another target than
        the device applied at that row's sample (:meth:`row_offset`). A row before the device's first sample is
        right when it names the position the drive held (:attr:`position_before_counts`); a usable row beyond
        the record is wrong."""
        offset = self.row_offset(logged_counts)
        wrong = 0
        for k, (counts, ok) in enumerate(zip(logged_counts, usable)):
            sample = k + offset
            if sample < 0:
                applied = self.position_before_counts
            else:
                applied = self.applied_targets[sample] if sample < len(self.applied_targets) else None
            wrong += bool(ok) and counts != applied
        return wrong


class TickLateness:
    """How late a device's clock ran its ticks: the latest (:attr:`delay_max_s`) and its stalls (see
    :attr:`DeviceRecord.stalls`)."""

    def __init__(self) -> None:
        self.delay_max_s = 0.0
        self.stalls: list[tuple[int, float]] = []
        self._stalled = False

    def observe(self, sample: int, delay_s: float) -> None:
        """The tick of ``sample`` ran ``delay_s`` after its instant."""
        self.delay_max_s = max(self.delay_max_s, delay_s)
        stalled = delay_s > DEVICE_STALL_S
        if stalled and not self._stalled:
            self.stalls.append((sample, delay_s))
        elif stalled:
            first, delay_max_s = self.stalls[-1]
            self.stalls[-1] = (first, max(delay_max_s, delay_s))
        self._stalled = stalled
