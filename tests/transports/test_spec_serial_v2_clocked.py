"""Protocol v2 tick by tick on a simulated clock (no pty, no thread, no sleep: nothing here depends on how
busy the machine is). The real host transport and runner (:func:`rig.runner.run_experiment`, its
:class:`~rig.sample_ledger.SampleLedger`) drive the device written only from the spec
(:mod:`spec_serial_device`) through :class:`clocked_line.ClockedLine`; the device ticks exactly at
``START + k T`` on the simulated clock, so lead, buffer levels, HELD samples and the lead the host measured
are exact numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import DeviceFault
from rig.runner import run_experiment
from rig.transports.serial_link import SerialTransport

from clocked_line import ClockedLine, SimulatedClock, check_the_way_back_to_the_plan
from sim_rigs import ListSink
from spec_serial_device import (
    CONTROL, DEVICE_INFO, HELLO, SETPOINT, START, STATUS, SWITCH_ON_DISABLED, TICK, SpecSerialDevice, frame, parse,
)

PERIOD_S = 0.005
DRIVE = DriveScaling(1 << 17)
SAMPLES = 200
LEAD_S = 0.05
LEAD = 10  # ceil(LEAD_S / PERIOD_S) setpoints


def _command(num_samples: int = SAMPLES) -> np.ndarray:
    return 0.2 * np.sin(2 * np.pi * np.arange(num_samples) / 50)


@pytest.fixture
def rig():
    """``rig(**device_options)`` -> (line, transport, device, clock) on one simulated clock."""

    def make(*, lead_s: float = LEAD_S, protocol: str = "auto", **device_options):
        clock = SimulatedClock(1000.0)
        line: ClockedLine | None = None
        device = SpecSerialDevice(clock=clock, output=lambda data: line.device_writes(data), **device_options)
        transport = SerialTransport("simulated", encoder=EncoderResolution(bits=16), sample_period_s=PERIOD_S,
                                    drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0), reply_timeout_s=0.3,
                                    protocol=protocol, lead_s=lead_s, name="clocked", clock=clock)
        line = ClockedLine(transport, clock, feed=device.feed, next_event_s=device.next_event_s,
                           run_due=device.run_due)
        return line, transport, device, clock

    return make


def _run(line: ClockedLine, transport, clock, command, *, stall_at: int | None = None, stall_s: float = 0.0,
         feedback_timeout_s: float = 0.5):
    """run_experiment on the simulated clock; the host stalls ``stall_s`` once ``stall_at`` rows are logged."""
    stalled = []

    def progress(done: int, _held: int) -> None:
        if stall_at is not None and done >= stall_at and not stalled:
            stalled.append(clock())
            line.stall(stall_s)

    sink = ListSink()
    summary = run_experiment(transport, command, sink, feedback_timeout_s=feedback_timeout_s, clock=clock,
                             progress=progress)
    return summary, sink, stalled


def _flags(sink: ListSink) -> np.ndarray:
    return np.array([row[4] for row in sink.rows])


# -- the run, tick by tick ---------------------------------------------------------------------------------------

def test_the_host_keeps_the_lead_and_every_row_is_the_devices_tick(rig):
    line, transport, device, clock = rig()
    command = _command()
    summary, sink, _ = _run(line, transport, clock, command)
    assert summary.samples == SAMPLES and summary.lost == summary.held == summary.late == summary.duplicate == summary.stale == 0
    assert transport.lead_samples == LEAD and device.sessions == 1
    # tick k found setpoint k and left k+1 .. k+LEAD-1 queued: the host topped the buffer up every tick, and
    # after the last setpoint the level runs down
    assert [device.ticks[k].buffer_level for k in range(SAMPLES)] == [min(LEAD - 1, SAMPLES - 1 - k)
                                                                      for k in range(SAMPLES)]
    assert not any(device.ticks[k].held for k in range(SAMPLES)) and device.dropped_setpoints == {}
    # every setpoint sent after START was queued exactly LEAD ticks ahead of its tick
    assert math.isclose(summary.min_lead_s, LEAD * PERIOD_S, rel_tol=1e-9)
    # row k is tick k: time k T, the command applied (= the design, quantised), the counts the device sent
    times, commands, _, counts, flags = zip(*sink.rows)
    np.testing.assert_allclose(times, np.arange(SAMPLES) * PERIOD_S, rtol=0, atol=1e-12)
    assert list(commands) == [DRIVE.quantize_rad(value) for value in command]
    assert list(commands) == [DRIVE.rad_from_counts(device.ticks[k].applied_counts) for k in range(SAMPLES)]
    assert list(counts) == [device.ticks[k].encoder_counts for k in range(SAMPLES)] and not any(flags)
    # the device went on ticking (holding the last target) until the host had every row final, then stopped
    assert all(device.ticks[k].held for k in device.ticks if k >= SAMPLES)
    assert device.state == SWITCH_ON_DISABLED and device.mode == 1
    assert device.controlwords == [0x0006, 0x0007, 0x000F, 0x0002, 0x0000]


def test_a_run_interrupted_before_start_never_starts_the_devices_clock(rig):
    """Ctrl-C while the first setpoints are queued, before START: the runner files what had come before the
    stop, and that never sends START: the device never ticks, and ends disabled."""
    line, transport, device, clock = rig()
    send = transport.send

    def interrupted(setpoint):
        if setpoint.seq == LEAD // 2:
            raise KeyboardInterrupt
        return send(setpoint)

    transport.send = interrupted
    with pytest.raises(KeyboardInterrupt):
        run_experiment(transport, _command(), ListSink(), feedback_timeout_s=0.5, clock=clock)
    assert not device.ticks and device.state == SWITCH_ON_DISABLED


def test_a_host_stall_shorter_than_the_lead_costs_nothing(rig):
    line, transport, device, clock = rig()
    stall_s = 0.0325  # 6.5 ticks, within the 10-tick lead
    summary, sink, stalled = _run(line, transport, clock, _command(), stall_at=80, stall_s=stall_s)
    assert stalled and summary.samples == SAMPLES and summary.lost == summary.held == 0
    assert not any(_flags(sink)) and device.dropped_setpoints == {}
    # the smallest lead: the setpoint queued first after the stall had the lead less the stall, rounded
    # to the tick the host last heard of before it
    assert LEAD * PERIOD_S - stall_s - PERIOD_S < summary.min_lead_s < LEAD * PERIOD_S - stall_s + PERIOD_S
    # the buffer ran down by one a tick while the host stalled (6 ticks fell in it), never to empty
    assert min(device.ticks[k].buffer_level for k in range(SAMPLES - LEAD)) == LEAD - 1 - math.floor(stall_s / PERIOD_S)


def test_a_host_stall_longer_than_the_lead_holds_exactly_the_ticks_it_outlasts(rig):
    """The buffer runs dry LEAD ticks after the host's last top-up; every tick from then to the stall's end
    is HELD with the last target, logged with that command; none is lost and the run goes on."""
    line, transport, device, clock = rig()
    stall_s = 0.1025  # 20.5 ticks
    command = _command()
    summary, sink, (stall_start,) = _run(line, transport, clock, command, stall_at=80, stall_s=stall_s)
    assert summary.samples == SAMPLES and summary.lost == 0
    heard, last_in_stall = _stall_ticks(device, stall_start, stall_s)
    expected_held = list(range(heard + LEAD, last_in_stall + 1))
    held = np.flatnonzero(_flags(sink) & SampleFlag.HELD).tolist()
    assert held == expected_held and summary.held == len(held) == 11 and summary.late == 0
    commands = [row[1] for row in sink.rows]
    assert commands[held[0]:held[-1] + 1] == [commands[held[0] - 1]] * len(held)  # the last target, held
    # none for a tick it had heard of (spec 16.3); one for a tick that had passed unheard of is dropped there
    assert set(device.dropped_setpoints) <= set(held)
    assert math.isclose(summary.min_lead_s, -(last_in_stall - held[0]) * PERIOD_S - (
        stall_start + stall_s - device_tick_s(device, last_in_stall)), rel_tol=1e-9)
    # after the stall the lead is kept again: every later tick has its own setpoint, on the way back to the plan
    # (LIMITED) and then the plan's
    limited = np.flatnonzero(_flags(sink) & SampleFlag.LIMITED)
    assert limited.tolist() == list(range(held[-1] + 1, held[-1] + 1 + limited.size))
    assert all(commands[k] == DRIVE.quantize_rad(command[k]) for k in range(held[-1] + 1 + limited.size, SAMPLES))


def device_tick_s(device: SpecSerialDevice, k: int) -> float:
    return device._tick0_s + k * device.period_s


def _stall_ticks(device: SpecSerialDevice, stall_start: float, stall_s: float) -> tuple[int, int]:
    """The tick the host had last heard of when it stalled (it had queued up to that one's predecessor +
    LEAD: the runner tops up before it waits), and the last tick before the stall ended."""
    heard = max(k for k in device.ticks if device_tick_s(device, k) <= stall_start)
    return heard, max(k for k in device.ticks if device_tick_s(device, k) <= stall_start + stall_s)


def test_a_setpoint_lost_on_the_line_is_one_held_sample(rig):
    line, transport, device, clock = rig(lost_setpoints=(50,))
    summary, sink, _ = _run(line, transport, clock, _command())
    assert summary.held == 1 and summary.lost == 0
    assert np.flatnonzero(_flags(sink) & SampleFlag.HELD).tolist() == [50]
    assert sink.rows[50][1] == sink.rows[49][1] != sink.rows[51][1]


# -- the device's link watchdog in v2 (spec section 16.4) --------------------------------------------------------

def test_the_v2_watchdog_rides_through_a_long_stall_and_stops_a_host_that_is_gone(rig):
    """0.9 s without a frame from the host: within the device's v2 bound (1 s), the drive holds its target
    (safe) and the run goes on; 1.2 s: the host is taken for gone, the device stops the drive itself."""
    line, transport, device, clock = rig()
    summary, sink, (stall_start,) = _run(line, transport, clock, _command(), stall_at=40, stall_s=0.9,
                                         feedback_timeout_s=2.0)
    assert not device.watchdog_expired and summary.samples == SAMPLES and summary.lost == 0
    heard, last_in_stall = _stall_ticks(device, stall_start, 0.9)
    assert last_in_stall >= SAMPLES and summary.held == SAMPLES - (heard + LEAD)  # every row after the lead ran out
    line, transport, device, clock = rig()
    with pytest.raises(DeviceFault, match=r"left OPERATION ENABLED without a fault \(unprompted STATUS"):
        _run(line, transport, clock, _command(), stall_at=40, stall_s=1.2, feedback_timeout_s=2.0)
    assert device.watchdog_expired and device.state == SWITCH_ON_DISABLED and device.mode == 1


# -- the device's own rules, frame by frame (spec section 16.2-16.3) ---------------------------------------------

def _device(**options) -> tuple[SpecSerialDevice, SimulatedClock, list]:
    clock, out = SimulatedClock(), []
    device = SpecSerialDevice(clock=clock, output=lambda data: out.extend(
        parse(chunk) for chunk in data.split(b"\x00") if chunk), **options)
    return device, clock, out


def _enable(device: SpecSerialDevice, first_seq: int = 1) -> int:
    for seq, word in enumerate((0x0006, 0x0007, 0x000F), start=first_seq):
        device.feed(frame(CONTROL, seq, word))
    return first_seq + 3


def test_the_spec_devices_buffer_replaces_drops_late_and_overflow_and_start_acts_once():
    device, clock, out = _device(buffer_capacity=3)
    device.feed(frame(HELLO, 1, 2))
    assert out[-1] == (DEVICE_INFO, 1, (2, 3, 5_000_000)) and device.mode == 2
    seq = _enable(device, 2)
    device.feed(frame(HELLO, seq, 2))  # in OPERATION ENABLED: answered with the mode, which does not change
    assert out[-1] == (DEVICE_INFO, seq, (2, 3, 5_000_000))
    for k, target in ((0, 10), (1, 20), (0, 11), (2, 30), (3, 40)):  # 0 replaced; 3 finds the buffer full
        device.feed(frame(SETPOINT, k, target))
    assert device.dropped_setpoints == {3: "buffer full"} and not any(kind == TICK for kind, *_ in out)
    device.feed(frame(START, seq + 1))
    assert out[-2][0] == STATUS and out[-1] == (TICK, 0, (0x1637, 11, 5, 11, 0, 2))  # tick 0 at START
    device.feed(frame(START, seq + 2))  # while ticking: answered, changes nothing
    clock.advance_to(0.0125)  # ticks 1 and 2 are due
    device.run_due()
    assert [fields[3:] for kind, _, fields in out if kind == TICK] == [(11, 0, 2), (20, 0, 1), (30, 0, 0)]
    device.feed(frame(SETPOINT, 2, 99))  # tick 2 has passed
    assert device.dropped_setpoints[2] == "late"
    clock.advance_to(0.015)
    device.run_due()
    assert out[-1] == (TICK, 3, (0x1637, 30, 15, 30, 1, 0))  # nothing for tick 3: held, flagged
    assert device.sessions == 1 and [k for k in device.ticks] == [0, 1, 2, 3]


def test_the_spec_device_without_hello_streams_the_v1_way_and_a_session_ends_with_operation_enabled():
    device, clock, out = _device()
    _enable(device)
    device.feed(frame(SETPOINT, 0, 8))
    assert out[-1][0] != TICK and out[-1][1] == 0 and device.feedback == {0: 4}  # FEEDBACK: v1 mode
    device.feed(frame(CONTROL, 4, 0x0007))  # out of OPERATION ENABLED
    device.feed(frame(HELLO, 5, 2))
    _enable(device, 6)
    device.feed(frame(SETPOINT, 0, 8))
    device.feed(frame(START, 9))
    assert device.sessions == 1 and device.ticks[0].applied_counts == 8
    device.feed(frame(CONTROL, 10, 0x0002))  # quick stop: the session ends
    clock.advance_to(1.0)
    device.run_due()
    assert device.mode == 1 and list(device.ticks) == [0] and device.next_event_s() == math.inf


# -- the simulated rig's own device (sim_backend) on the same clock ----------------------------------------------

@pytest.fixture
def simulated_rig(tmp_path):
    """(line, transport, device, clock, gearbox factory) for ``SimulatedSerialDevice`` on a simulated clock."""
    from sim_backend.plant_config import load_plant_config
    from sim_backend.serial_device import SimulatedSerialDevice

    from clocked_line import simulated_device_line
    from sim_rigs import write_test_plant

    plant = load_plant_config(write_test_plant(tmp_path))
    devices = []

    def make(**device_options):
        clock = SimulatedClock(1000.0)
        device = SimulatedSerialDevice(plant.gearbox(seed=3), clock=clock, buffer_capacity=64, **device_options)
        devices.append(device)
        transport = SerialTransport("simulated", encoder=EncoderResolution(bits=12, signed=True),  # the plant's
                                    sample_period_s=PERIOD_S, drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0),
                                    reply_timeout_s=0.3, lead_s=LEAD_S, name="clocked", clock=clock)
        return simulated_device_line(transport, clock, device), transport, device, clock, lambda: plant.gearbox(seed=3)

    yield make
    for device in devices:
        device.close()


def test_the_simulated_device_ticks_on_the_clock_and_its_run_equals_the_offline_simulation(simulated_rig):
    """A 20.5-tick host stall with a 10-tick lead: exactly 11 HELD rows, and the logged angles equal the
    offline simulation of the commands logged (those the device applied), whatever the host did."""
    line, transport, device, clock, fresh_gearbox = simulated_rig()
    summary, sink, _ = _run(line, transport, clock, _command(), stall_at=80, stall_s=0.1025)
    assert summary.samples == SAMPLES and summary.lost == 0 and summary.held == 11
    levels = [message.fields[5] for message in line.to_host if message.type.name == "TICK"][:SAMPLES]
    assert max(levels) == LEAD - 1 and levels[:80] == [LEAD - 1] * 80  # the lead kept until the stall
    _, commands, angles, _, flags = (np.array(column, dtype=float) for column in zip(*sink.rows))
    held = np.flatnonzero(flags.astype(int) & SampleFlag.HELD)
    assert held.size == 11 and np.all(np.diff(held) == 1) and np.all(commands[held] == commands[held[0] - 1])
    np.testing.assert_array_equal(angles, fresh_gearbox().simulate(commands).measured_angle_rad)
    assert device.dropped_setpoints <= 11 and device.mode == 1


def test_a_tick_that_never_comes_is_one_lost_row(simulated_rig):
    line, transport, device, clock, _ = simulated_rig(silent_seqs=(70,))
    summary, sink, _ = _run(line, transport, clock, _command())
    flags = _flags(sink)
    assert summary.lost == 1 and np.flatnonzero(flags & SampleFlag.LOST).tolist() == [70] and summary.held == 0
    assert math.isnan(sink.rows[70][2]) and not any(flags[:70]) and not any(flags[71:])


def test_the_v1_link_watchdog_stops_the_drive_and_the_host_hears_of_it(rig):
    """Section 10, v1 (the device got no HELLO): streaming host-paced, then the host falls silent. Within
    the device's 100 ms nothing happens; past it the device disables the drive and says so with an
    unprompted STATUS (seq 0), which stops the host's stream."""
    from rig.transports.base import Setpoint

    line, transport, device, clock = rig(protocol="v1")
    transport.open()
    try:
        for k in range(10):
            line.stall(PERIOD_S)
            transport.send(Setpoint(k, 0.0))
            assert transport.receive(timeout_s=0.0).seq == k  # FEEDBACK at once
        line.stall(0.099)  # since the last SETPOINT
        assert not device.watchdog_expired
        line.stall(0.002)
        assert device.watchdog_expired and device.state == SWITCH_ON_DISABLED and device.unprompted == [0x0240]
        with pytest.raises(DeviceFault, match=r"left OPERATION ENABLED without a fault \(unprompted STATUS 0x0240"):
            transport.receive(timeout_s=0.0)
    finally:
        transport.close()
    assert device.controlwords[-2:] == [0x0002, 0x0000]


@pytest.mark.parametrize("fault_at", [84, 95, 105])
def test_a_fault_during_a_host_stall_files_every_tick_before_it(rig, fault_at):
    """Before the lead ran out (84), within the lead (95), past the rows the host had opened (105): every
    tick up to the faulted one is a row, with its values, and the faulted one is the last, flagged FAULT."""
    line, transport, device, clock = rig(fault_at_sample=fault_at, fault_code=0x2310)
    sink, stalled = ListSink(), []

    def progress(done: int, _held: int) -> None:
        if done >= 80 and not stalled:
            stalled.append(clock())
            line.stall(0.1025)

    with pytest.raises(DeviceFault, match=r"0x2310"):
        run_experiment(transport, _command(), sink, feedback_timeout_s=0.5, clock=clock, progress=progress)
    flags = _flags(sink)
    assert len(sink.rows) == fault_at + 1 and flags[fault_at] & SampleFlag.FAULT
    assert not np.any(flags[:fault_at] & (SampleFlag.FAULT | SampleFlag.LOST))
    assert [row[3] for row in sink.rows[:fault_at]] == [device.ticks[k].encoder_counts for k in range(fault_at)]


def test_a_faulted_tick_that_comes_in_a_later_read_than_its_fault_frame_is_filed(rig):
    """Section 16.3: the FAULT frame goes out before the TICK of the faulted tick; the host may read the two in
    different reads (the TICK still on the line when the FAULT frame was read). The faulted tick is a row,
    flagged FAULT with the values the device sent, not LOST."""
    from rig.protocols.serial_frames import FrameDecoder, MessageType

    clock = SimulatedClock(1000.0)
    held_back = bytearray()
    seen = {"fault": False, "read": False}

    class SplitLine(ClockedLine):
        def device_writes(self, data: bytes) -> None:
            for chunk in bytes(data).split(b"\x00")[:-1] if data.endswith(b"\x00") else [bytes(data)]:
                if seen["fault"]:
                    held_back.extend(chunk + b"\x00")
                    continue
                super().device_writes(chunk + b"\x00")
                seen["fault"] = any(m.type is MessageType.FAULT for m in FrameDecoder().feed(chunk + b"\x00"))

        def _host_polls(self, timeout_s: float) -> bool:
            if held_back and seen["read"]:  # the FAULT frame was read in an earlier read: now the rest
                rest = bytes(held_back)
                held_back.clear()
                ClockedLine.device_writes(self, rest)
            delivered = super()._host_polls(timeout_s)
            seen["read"] = seen["read"] or (seen["fault"] and delivered)
            return delivered

    line: ClockedLine | None = None
    device = SpecSerialDevice(clock=clock, output=lambda data: line.device_writes(data), fault_at_sample=100,
                              fault_code=0x2310)
    transport = SerialTransport("simulated", encoder=EncoderResolution(bits=16), sample_period_s=PERIOD_S,
                                drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0), reply_timeout_s=0.3,
                                lead_s=LEAD_S, name="clocked", clock=clock)
    line = SplitLine(transport, clock, feed=device.feed, next_event_s=device.next_event_s, run_due=device.run_due)
    sink = ListSink()
    with pytest.raises(DeviceFault, match=r"0x2310"):
        run_experiment(transport, _command(), sink, feedback_timeout_s=0.5, clock=clock)
    flags = _flags(sink)
    assert seen["read"] and len(sink.rows) == 101
    assert flags[100] & SampleFlag.FAULT and not flags[100] & SampleFlag.LOST
    assert sink.rows[100][3] == device.ticks[100].encoder_counts
    assert not np.any(flags[:100] & (SampleFlag.FAULT | SampleFlag.LOST))


def test_a_device_that_remembers_an_earlier_hosts_last_request_number_is_still_brought_up(rig, monkeypatch):
    """Section 6: the device remembers the number of the last CONTROL it applied, also across host sessions (it
    cannot tell them apart). An earlier host whose session ended after its first CONTROL left 4 there (STATUS_REQUEST
    1, HELLO 2, STATUS_REQUEST 3, CONTROL 4): a host counting from 1 again would have its first CONTROL taken for a
    repeat and never applied. Each session's numbers start at a random origin (seeded here)."""
    import random

    from rig.transports import serial_link

    monkeypatch.setattr(serial_link, "REQUEST_ORIGINS", random.Random(11))
    line, transport, device, clock = rig()
    device.last_applied_request = 4
    transport.timing = BringUpTiming(poll_interval_s=0.0, enable_timeout_s=0.5)
    summary, sink, _ = _run(line, transport, clock, _command(50))
    assert summary.samples == 50 and summary.lost == 0
    assert device.controlwords[:3] == [0x0006, 0x0007, 0x000F]


# -- the way back to the plan after a stall (README, "Safety") ---------------------------------------------------

RATE_LIMIT_RAD_PER_S = 6.0
"""0.03 rad a tick at 5 ms: above the command's largest step (0.0251 rad), far below the 0.27 rad the plan moves
while a 20.5-tick stall holds 11 ticks."""


@pytest.mark.parametrize("stall_s", [0.1025, 0.4025])
def test_after_a_stall_the_device_steps_back_to_the_plan_within_the_rate_limit(rig, stall_s):
    """The host stalls past its lead: the device holds its last target while the plan moves on. The setpoints
    queued after the stall start from the target the device reported in force and ramp to the plan at most the
    rate limit's step a tick (the device never takes the jump), each such row LIMITED with the target applied;
    then the plan again."""
    from rig.transports.base import CommandLimits

    line, transport, device, clock = rig()
    transport.limits = CommandLimits(rate_max_rad_per_s=RATE_LIMIT_RAD_PER_S)
    command = _command()
    summary, sink, _ = _run(line, transport, clock, command, stall_at=80, stall_s=stall_s)
    assert summary.samples == SAMPLES and summary.lost == 0 and summary.held > 0
    limited = check_the_way_back_to_the_plan(sink, device, command, DRIVE, RATE_LIMIT_RAD_PER_S * PERIOD_S)
    held = np.flatnonzero(_flags(sink) & SampleFlag.HELD)
    assert limited.size > 0 and limited[0] == held[-1] + 1  # the ramp starts at the first tick not held
    assert [row[1] for row in sink.rows[limited[-1] + 1:]] == [DRIVE.quantize_rad(value)
                                                                for value in command[limited[-1] + 1:]]
    assert set(device.dropped_setpoints) <= set(held)


def test_after_a_stall_the_ramp_starts_from_the_target_in_force_without_a_rate_limit(rig):
    """No rate limit configured: the way back still steps at most twice the plan's own largest step
    (:data:`rig.transports.base.CATCH_UP_FACTOR`), as on CANopen."""
    from rig.transports.base import CATCH_UP_FACTOR

    line, transport, device, clock = rig()
    command = 0.4 * np.sin(2 * np.pi * np.arange(SAMPLES) / 100)
    summary, sink, _ = _run(line, transport, clock, command, stall_at=80, stall_s=0.2025)
    plan_step = np.abs(np.diff([DRIVE.quantize_rad(value) for value in command])).max()
    limited = check_the_way_back_to_the_plan(sink, device, command, DRIVE, CATCH_UP_FACTOR * plan_step)
    assert summary.lost == 0 and limited.size > 0
