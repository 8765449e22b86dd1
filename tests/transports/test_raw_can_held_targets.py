"""Raw CAN v3 on a simulated clock: every row carries the target the device really applied, or is flagged
unusable when the host cannot know it; ticks that arrive while the host waits for RIG_START's answer are
kept; statusword bit 12 clear is NOT_FOLLOWED as on serial. The spec device (:mod:`spec_raw_can_device`) on
:class:`clocked_line.ClockedBus`, with the bus between them scripted: answers delayed or lost, tick frames
lost, the statusword changed."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.runner import run_experiment
from rig.transports.raw_can import RawCanTransport

from clocked_line import ClockedBus, SimulatedClock
from sim_rigs import ListSink
from spec_raw_can_device import RIG_DRIVE_TICK, RIG_FEEDBACK, RIG_STATUS, SpecRawCanDevice

PERIOD_S = 0.005
DRIVE = DriveScaling(1 << 17)
RIG_START, RIG_SETPOINT = 259, 272


class ScriptedBus(ClockedBus):
    """A :class:`ClockedBus` whose device-to-host side can be scripted: ``answer_start_after_s`` holds the
    RIG_STATUS answering RIG_START back while the device lives through that much of its clock (it ticks
    meanwhile; the DBC allows 100 ms), ``lose_start_answers`` drops that many of those answers, and
    ``deliver(arbitration_id, data)`` may drop (None) or change a frame of the device's."""

    def __init__(self, transport, clock, device, *, answer_start_after_s: float = 0.0, lose_start_answers: int = 0,
                 deliver=None) -> None:
        super().__init__(transport, clock, device)
        self.answer_start_after_s, self.lose_start_answers = answer_start_after_s, lose_start_answers
        self.deliver = deliver or (lambda arbitration_id, data: data)
        self._start_seq: bytes | None = None
        self._held_answer: tuple[float, int, bytes] | None = None
        self.setpoints: list[tuple[int, int]] = []

    def device_sends(self, arbitration_id: int, data: bytes) -> None:
        if arbitration_id == RIG_STATUS and self._start_seq is not None and data[:2] == self._start_seq:
            self._start_seq = None
            if self.lose_start_answers > 0:
                self.lose_start_answers -= 1
                return
            if self.answer_start_after_s:  # the device ticks meanwhile; its answer comes after those ticks
                self._held_answer = (self.clock() + self.answer_start_after_s, arbitration_id, bytes(data))
                self.answer_start_after_s = 0.0  # once
                return
        data = self.deliver(arbitration_id, bytes(data))
        if data is not None:
            super().device_sends(arbitration_id, data)

    def recv(self, timeout: float | None = None):
        if self._held_answer is not None:
            release = self._held_answer[0]
            if not self._to_host and timeout and self.clock() < release <= self.clock() + timeout:
                self.stall(release - self.clock())  # nothing else comes before it: the host waits for it
            if self.clock() >= release:
                super().device_sends(*self._held_answer[1:])
                self._held_answer = None
        return super().recv(timeout)

    def send(self, message, timeout=None) -> None:
        if message.arbitration_id == RIG_START:
            self._start_seq = bytes(message.data[:2])
        if message.arbitration_id == RIG_SETPOINT:  # (seq, the last tick the host had heard of when it sent it)
            self.setpoints.append((struct.unpack_from("<H", message.data)[0], self.transport.device_sample))
        super().send(message, timeout)


def _rig(*, period_s=PERIOD_S, lead_s=0.05, reply_timeout_s=0.3, device_options=None, **bus_options):
    clock = SimulatedClock(500.0)
    bus: ScriptedBus | None = None
    device = SpecRawCanDevice(clock=clock, output=lambda arbitration_id, data: bus.device_sends(arbitration_id, data),
                              sample_period_ns=round(period_s * 1e9), **{"buffer_capacity": 255, **(device_options or {})})
    transport = RawCanTransport("virtual", "clocked", encoder=EncoderResolution(bits=16), sample_period_s=period_s,
                                drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0),
                                reply_timeout_s=reply_timeout_s, lead_s=lead_s, name="clocked", clock=clock)
    bus = ScriptedBus(transport, clock, device, **bus_options)
    return bus, transport, device, clock


def _run(bus, transport, clock, samples, *, stall_at=None, stall_s=0.0, feedback_timeout_s=0.5):
    stalled = []

    def progress(done: int, _held: int) -> None:
        if stall_at is not None and done >= stall_at and not stalled:
            stalled.append(clock())
            bus.stall(stall_s)

    sink = ListSink()
    command = 0.2 * np.sin(2 * np.pi * np.arange(samples) / 50)
    summary = run_experiment(transport, command, sink, feedback_timeout_s=feedback_timeout_s, clock=clock,
                             progress=progress)
    return summary, sink


def _rows_agree_with_the_device(sink, device, rows) -> None:
    """Every row in ``rows``: the command applied at that tick, its HELD flag, the encoder value sent."""
    for k in rows:
        _, command, _, counts, flags = sink.rows[k]
        tick = device.ticks[k]
        assert (command, bool(flags & SampleFlag.HELD), counts) == (
            DRIVE.rad_from_counts(tick.applied_counts), tick.held, tick.encoder_counts), k


def test_ticks_that_arrive_before_the_start_answer_are_filed():
    """A legal answer 90 ms after RIG_START (the DBC gives the device 100 ms): the 18 ticks the device sent
    meanwhile are samples like the others, none of them LOST."""
    bus, transport, device, clock = _rig(answer_start_after_s=0.09)
    summary, sink = _run(bus, transport, clock, 200)
    assert summary.samples == 200 and summary.lost == 0
    assert summary.held == sum(device.ticks[k].held for k in range(200))  # the lead ran out while it waited
    _rows_agree_with_the_device(sink, device, range(200))


def test_a_lost_start_answer_holds_past_254_ticks_and_every_row_carries_the_target_applied():
    """RIG_START's answer is lost once: the device ticks (applying its lead of 50 setpoints, then holding) while
    the host waits 0.6 s to send RIG_START again; the hold outlasts 254 ticks (applied_age 255), and the host
    still logs, for every tick it heard, the target the device applied."""
    bus, transport, device, clock = _rig(period_s=0.001, reply_timeout_s=0.6, lose_start_answers=1,
                                         device_options={"watchdog_ticking_s": 5.0})
    summary, sink = _run(bus, transport, clock, 1000, feedback_timeout_s=1.0)
    held = [k for k in range(1000) if device.ticks[k].held]
    assert len(held) > 300 and summary.lost == 0 and summary.held == len(held)
    _rows_agree_with_the_device(sink, device, range(1000))
    assert not any(row[4] & SampleFlag.AMBIGUOUS for row in sink.rows)
    # the setpoints of the ticks that passed during the wait are not put on the bus (the device drops them):
    # hundreds of useless frames at once would crowd the ticks' frames and the host's own receive queue
    assert all(seq > heard for seq, heard in bus.setpoints)


def test_a_hold_whose_target_the_host_cannot_know_is_flagged_unusable_with_a_reason():
    """The host stalls for 2.5 s (500 ticks at 5 ms), and the tick frames of ticks 100..400 are lost on the
    bus: tick 401 says applied_age 255 and the host has heard of no tick in the 255 before it, so it cannot
    know the target in force (it did send setpoints for those ticks). Such rows are HELD and AMBIGUOUS
    (unusable), never the designed command as if applied, and the summary says why."""
    lost_ticks = range(100, 401)

    def deliver(arbitration_id, data):
        if arbitration_id in (RIG_FEEDBACK, RIG_DRIVE_TICK) and struct.unpack_from("<H", data)[0] in lost_ticks:
            return None
        return data

    bus, transport, device, clock = _rig(deliver=deliver, device_options={"watchdog_ticking_s": 5.0})
    summary, sink = _run(bus, transport, clock, 800, stall_at=40, stall_s=2.5, feedback_timeout_s=5.0)
    flags = np.array([row[4] for row in sink.rows])
    assert np.all(flags[list(lost_ticks)] & SampleFlag.LOST)
    unknown = np.flatnonzero(flags & SampleFlag.AMBIGUOUS).tolist()
    assert unknown and unknown[0] == 401 and all(flags[k] & SampleFlag.HELD for k in unknown)
    assert all(device.ticks[k].held for k in unknown)
    # the latest target known (tick 99's), not the designed command of the row
    assert {sink.rows[k][1] for k in unknown} == {DRIVE.rad_from_counts(device.ticks[99].applied_counts)}
    known = [k for k in range(800) if not flags[k] & (SampleFlag.LOST | SampleFlag.AMBIGUOUS)]
    _rows_agree_with_the_device(sink, device, known)
    assert any("target in force is not known" in warning for warning in summary.warnings)


def test_statusword_bit_12_clear_is_not_followed_on_raw_can_as_on_serial():
    """A drive that does not follow the target (bit 12 clear in OPERATION ENABLED, serial spec section 5, which
    the DBC points to) is flagged NOT_FOLLOWED in every row, not logged as following."""

    def deliver(arbitration_id, data):
        if arbitration_id == RIG_FEEDBACK:
            seq, statusword, encoder = struct.unpack("<HHI", data)
            return struct.pack("<HHI", seq, statusword & ~0x1000, encoder)
        return data

    bus, transport, device, clock = _rig(deliver=deliver)
    summary, sink = _run(bus, transport, clock, 100)
    assert summary.samples == 100 and summary.not_followed == 100
    assert all(row[4] & SampleFlag.NOT_FOLLOWED for row in sink.rows)


@pytest.mark.parametrize(("version", "capacity", "lead", "held"), [(4, 600, 500, 0), (3, 255, 255, 146)])
def test_at_2_khz_a_v4_device_holds_the_whole_250_ms_lead_and_a_v3_device_caps_it_at_255(version, capacity, lead,
                                                                                         held):
    """RIG_DEVICE_INFO's one-byte capacity caps the lead at 255 ticks, 127.5 ms at 2 kHz; a v4 device says its
    capacity in two bytes (RIG_DEVICE_INFO_V4), so the default 250 ms lead (500 setpoints) fits and a 200 ms
    host stall costs nothing. A v3 device is still driven, with the lead it can hold: the same stall holds
    the 146 ticks it outlasts."""
    bus, transport, device, clock = _rig(period_s=0.0005, lead_s=0.25, device_options={
        "protocol_version": version, "buffer_capacity": capacity, "watchdog_ticking_s": 5.0})
    summary, sink = _run(bus, transport, clock, 1500, stall_at=600, stall_s=0.2, feedback_timeout_s=1.0)
    assert transport.version == version and transport.lead_samples == lead
    assert summary.samples == 1500 and summary.lost == 0 and summary.held == held
    _rows_agree_with_the_device(sink, device, range(1500))


def test_a_fault_among_the_ticks_that_came_before_the_start_answer_stops_the_run_after_filing_them():
    """The drive faults at tick 5, while the host still waits for RIG_START's answer (90 ms, legal): the ticks
    before it and the faulted one are samples like any (the faulted one flagged FAULT); the run stops after
    them, naming the code."""
    from rig.protocols.errors import DeviceFault

    bus, transport, device, clock = _rig(answer_start_after_s=0.09,
                                         device_options={"fault_at_sample": 5, "fault_code": 0x2310})
    sink = ListSink()
    with pytest.raises(DeviceFault, match=r"0x2310"):
        run_experiment(transport, np.zeros(200), sink, feedback_timeout_s=0.5, clock=clock)
    flags = [row[4] for row in sink.rows]
    assert len(flags) == 6 and flags[5] & SampleFlag.FAULT
    assert not any(flag & (SampleFlag.LOST | SampleFlag.FAULT) for flag in flags[:5])
    assert [row[3] for row in sink.rows[:5]] == [device.ticks[k].encoder_counts for k in range(5)]
