"""Raw-CAN protocols v3 (the default) and v2 tick by tick on a simulated clock (no bus thread, no sleep): the real
:class:`~rig.transports.raw_can.RawCanTransport` and runner drive the raw-CAN device written only from
``configs/raw_can.dbc`` and the spec (:mod:`spec_raw_can_device`) through :class:`clocked_line.ClockedBus`."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError, DeviceFault
from rig.runner import run_experiment
from rig.transports.raw_can import RawCanTransport

from clocked_line import ClockedBus, SimulatedClock, check_the_way_back_to_the_plan
from sim_rigs import ListSink
from spec_raw_can_device import (
    AGE_OLD, RIG_DRIVE_FEEDBACK, RIG_DRIVE_TICK, RIG_FEEDBACK, RIG_TICK_APPLIED, SpecRawCanDevice,
)
from spec_serial_device import SWITCH_ON_DISABLED

PERIOD_S = 0.005
DRIVE = DriveScaling(1 << 17)
SAMPLES = 200
LEAD = 10  # the default 50 ms lead here at 5 ms


@pytest.fixture
def rig():
    def make(period_s=PERIOD_S, **device_options):
        clock = SimulatedClock(500.0)
        bus: ClockedBus | None = None
        device = SpecRawCanDevice(clock=clock, output=lambda arbitration_id, data: bus.device_sends(arbitration_id,
                                                                                                   data),
                                  sample_period_ns=round(period_s * 1e9), **device_options)
        transport = RawCanTransport("virtual", "clocked", encoder=EncoderResolution(bits=16),
                                    sample_period_s=period_s, drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0),
                                    reply_timeout_s=0.3, lead_s=LEAD * PERIOD_S, name="clocked", clock=clock)
        bus = ClockedBus(transport, clock, device)
        return bus, transport, device, clock

    return make


def _drive_ticks(bus: ClockedBus) -> dict[int, tuple[int, int, int]]:
    """The RIG_DRIVE_TICK frames the host received (DBC: seq, actual_counts, buffer_level, applied_age), by seq."""
    return {seq: (actual, level, age) for arbitration_id, data in bus.to_host if arbitration_id == RIG_DRIVE_TICK
            for seq, actual, level, age in [struct.unpack("<HiBB", data)]}


def _run(bus: ClockedBus, transport, clock, *, stall_at=None, stall_s=0.0, feedback_timeout_s=0.5, samples=SAMPLES):
    stalled = []

    def progress(done: int, _held: int) -> None:
        if stall_at is not None and done >= stall_at and not stalled:
            stalled.append(clock())
            bus.stall(stall_s)

    sink = ListSink()
    command = 0.2 * np.sin(2 * np.pi * np.arange(samples) / 50)
    summary = run_experiment(transport, command, sink, feedback_timeout_s=feedback_timeout_s, clock=clock,
                             progress=progress)
    return summary, sink, command, stalled


def test_the_raw_can_host_keeps_the_lead_tick_by_tick(rig):
    bus, transport, device, clock = rig()
    summary, sink, command, _ = _run(bus, transport, clock)
    assert summary.samples == SAMPLES and summary.lost == summary.held == summary.duplicate == 0
    assert [device.ticks[k].buffer_level for k in range(SAMPLES)] == [min(LEAD - 1, SAMPLES - 1 - k)
                                                                      for k in range(SAMPLES)]
    assert math.isclose(summary.min_lead_s, LEAD * PERIOD_S, rel_tol=1e-9)
    assert [row[1] for row in sink.rows] == [DRIVE.quantize_rad(value) for value in command]
    assert [row[3] for row in sink.rows] == [device.ticks[k].encoder_counts for k in range(SAMPLES)]
    ticks = _drive_ticks(bus)  # v3: two frames a tick, the buffer level and applied_age in RIG_DRIVE_TICK
    assert [ticks[k][1] for k in range(SAMPLES)] == [min(LEAD - 1, SAMPLES - 1 - k) for k in range(SAMPLES)]
    assert [ticks[k][2] for k in range(SAMPLES)] == [0] * SAMPLES
    assert not any(arbitration_id in (RIG_DRIVE_FEEDBACK, RIG_TICK_APPLIED) for arbitration_id, _ in bus.to_host)
    assert device.state == SWITCH_ON_DISABLED and device.controlwords == [0x0006, 0x0007, 0x000F, 0x0002, 0x0000]


def test_a_raw_can_host_stall_longer_than_the_lead_holds_exactly_the_ticks_it_outlasts(rig):
    bus, transport, device, clock = rig()
    summary, sink, command, (stall_start,) = _run(bus, transport, clock, stall_at=80, stall_s=0.1025)
    tick_s = [device._tick0_s + k * PERIOD_S for k in range(max(device.ticks) + 1)]
    heard = max(k for k, when in enumerate(tick_s) if when <= stall_start)
    last_in_stall = max(k for k, when in enumerate(tick_s) if when <= stall_start + 0.1025)
    held = np.flatnonzero(np.array([row[4] for row in sink.rows]) & SampleFlag.HELD).tolist()
    assert held == list(range(heard + LEAD, last_in_stall + 1)) and summary.held == 11 and summary.lost == 0
    assert [row[1] for row in sink.rows][held[0]:held[-1] + 1] == [sink.rows[held[0] - 1][1]] * 11
    assert set(device.dropped_setpoints) <= set(held)  # sent before the host had heard of their ticks
    ticks = _drive_ticks(bus)  # the age counts up through the hold from the last setpoint applied; levels exact
    assert [ticks[k][2] for k in held] == list(range(1, 12))
    assert [ticks[k][1] for k in held] == [0] * 11 and ticks[held[0] - 1][1] == LEAD - 1 - (held[0] - 1 - heard)


@pytest.mark.parametrize("stall_s", [1.4, 0.9])
def test_a_raw_can_v3_hold_past_254_ticks_logs_the_target_of_the_tick_before(rig, stall_s):
    """applied_age saturates at 255 (DBC): the host takes the target of the tick before, so a hold longer than
    254 ticks (1.4 s at 5 ms, less the lead) still logs the command applied, and the data stay true."""
    bus, transport, device, clock = rig(watchdog_ticking_s=5.0)
    summary, sink, _, _ = _run(bus, transport, clock, stall_at=40, stall_s=stall_s, feedback_timeout_s=5.0,
                               samples=500)
    held = np.flatnonzero(np.array([row[4] for row in sink.rows]) & SampleFlag.HELD)
    held_count = round(stall_s / PERIOD_S) - LEAD + 1
    assert summary.held == held.size == held_count and summary.lost == 0 and np.all(np.diff(held) == 1)
    assert (held_count > AGE_OLD) == (stall_s > 1.3)
    assert [row[1] for row in sink.rows][held[0]:held[-1] + 1] == [sink.rows[held[0] - 1][1]] * held_count
    assert [sink.rows[k][1] for k in held] == [DRIVE.rad_from_counts(device.ticks[k].applied_counts) for k in held]
    ages = [_drive_ticks(bus)[k & 0xFFFF][2] for k in held]
    assert ages == [min(age, AGE_OLD) for age in range(1, held_count + 1)]


def test_a_v2_raw_can_device_is_still_driven_with_its_three_tick_frames(rig):
    bus, transport, device, clock = rig(protocol_version=2)
    summary, sink, _, _ = _run(bus, transport, clock, stall_at=80, stall_s=0.1025)
    assert transport.version == 2 and summary.samples == SAMPLES and summary.lost == 0 and summary.held == 11
    assert sum(arbitration_id == RIG_TICK_APPLIED for arbitration_id, _ in bus.to_host) >= SAMPLES
    assert not any(arbitration_id == RIG_DRIVE_TICK for arbitration_id, _ in bus.to_host)
    held = np.flatnonzero(np.array([row[4] for row in sink.rows]) & SampleFlag.HELD)
    assert [sink.rows[k][1] for k in held] == [DRIVE.rad_from_counts(device.ticks[k].applied_counts) for k in held]


def test_the_raw_can_v2_watchdog_rides_through_a_stall_and_is_heard_when_it_stops_the_drive(rig):
    """The DBC says nothing of a link watchdog; the serial spec it refers to does (sections 10, 16.4): 0.9 s
    of silence is ridden through holding, 1.2 s stops the drive, and the host hears it from the unprompted
    RIG_STATUS (seq 0) instead of waiting out its feedback watchdog (the run is long enough for the stop to fall
    within its samples: the ticks the device sent before it are all filed first)."""
    bus, transport, device, clock = rig()
    summary, *_ = _run(bus, transport, clock, stall_at=40, stall_s=0.9, feedback_timeout_s=2.0)
    assert not device.watchdog_expired and summary.samples == SAMPLES and summary.lost == 0 and summary.held > 0
    bus, transport, device, clock = rig()
    with pytest.raises(DeviceFault, match=r"left OPERATION ENABLED without a fault \(unprompted RIG_STATUS 0x0240: SWITCH_ON_DISABLED"):
        _run(bus, transport, clock, stall_at=40, stall_s=1.2, feedback_timeout_s=2.0, samples=400)
    assert device.watchdog_expired and device.state == SWITCH_ON_DISABLED


# -- the simulated rig's own raw-CAN device (sim_backend) on the same clock --------------------------------------

def test_the_simulated_raw_can_device_ticks_on_the_clock_and_its_run_equals_the_offline_simulation(tmp_path):
    from sim_backend.plant_config import load_plant_config
    from sim_backend.raw_can_device import SimulatedRawCanDevice

    from clocked_line import SimulatedRawCanEndpoint
    from sim_rigs import write_test_plant

    plant = load_plant_config(write_test_plant(tmp_path))
    clock = SimulatedClock(500.0)
    device = SimulatedRawCanDevice(plant.gearbox(seed=3), channel="unused", clock=clock)
    transport = RawCanTransport("virtual", "clocked", encoder=EncoderResolution(bits=12, signed=True),  # the plant's
                                sample_period_s=PERIOD_S, drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0),
                                reply_timeout_s=0.3, lead_s=LEAD * PERIOD_S, name="clocked", clock=clock)
    endpoint = SimulatedRawCanEndpoint(device)
    bus = ClockedBus(transport, clock, endpoint)
    endpoint.connect(bus)
    summary, sink, _, _ = _run(bus, transport, clock, stall_at=80, stall_s=0.1025)
    device.close()
    assert summary.samples == SAMPLES and summary.lost == 0 and summary.held == 11 >= device.dropped_setpoints
    _, commands, angles, _, flags = (np.array(column, dtype=float) for column in zip(*sink.rows))
    held = np.flatnonzero(flags.astype(int) & SampleFlag.HELD)
    assert np.all(np.diff(held) == 1) and np.all(commands[held] == commands[held[0] - 1])
    np.testing.assert_array_equal(angles, plant.gearbox(seed=3).simulate(commands).measured_angle_rad)


@pytest.mark.parametrize("fault_at", [84, 95, 105])
def test_a_raw_can_fault_during_a_host_stall_ends_the_log_with_the_faulted_tick(rig, fault_at):
    """RIG_FAULT comes before the frames of the faulted tick (DBC): before the lead ran out (84), within it
    (95), past the rows the host had opened (105), the faulted tick is the log's last row, flagged FAULT."""
    bus, transport, device, clock = rig(fault_at_sample=fault_at, fault_code=0x2310)
    sink, stalled = ListSink(), []

    def progress(done: int, _held: int) -> None:
        if done >= 80 and not stalled:
            stalled.append(clock())
            bus.stall(0.1025)

    with pytest.raises(DeviceFault, match=r"0x2310"):
        run_experiment(transport, np.zeros(SAMPLES), sink, feedback_timeout_s=0.5, clock=clock, progress=progress)
    flags = np.array([row[4] for row in sink.rows])
    assert len(sink.rows) == fault_at + 1 and flags[fault_at] & SampleFlag.FAULT
    assert not np.any(flags[:fault_at] & (SampleFlag.FAULT | SampleFlag.LOST))
    assert [row[3] for row in sink.rows[:fault_at]] == [device.ticks[k].encoder_counts for k in range(fault_at)]


def test_at_2_khz_a_v3_device_is_driven_and_a_v2_device_is_refused_naming_its_limit(rig):
    """1 Mbit/s: a v3 cycle is 394 bit (2538 Hz), a v2 cycle 512 bit (1953 Hz): the v2 device is refused after
    the handshake, before anything enabled it."""
    bus, transport, device, clock = rig(period_s=0.0005)
    summary, *_ = _run(bus, transport, clock)
    assert transport.version == 3 and summary.samples == SAMPLES and summary.lost == summary.held == 0
    assert transport.load.bits_per_cycle == 394 and round(transport.load.max_rate_hz) == 2538
    bus, transport, device, clock = rig(period_s=0.0005, protocol_version=2)
    with pytest.raises(ConfigError, match=r"device speaks raw-CAN protocol v2 \(3 frames a tick, 512 bit.*at most 1953 Hz"):
        _run(bus, transport, clock)
    assert device.controlwords == []


# -- the way back to the plan after a stall (README, "Safety") ---------------------------------------------------

@pytest.mark.parametrize("version", [2, 3, 4])
@pytest.mark.parametrize("stall_s", [0.1025, 0.4025])
def test_after_a_stall_the_raw_can_device_steps_back_to_the_plan_within_the_rate_limit(rig, version, stall_s):
    """As on serial: after a stall past the lead the device holds its last target while the plan moves on
    (0.27 rad in 11 ticks, or far more); the setpoints sent after it ramp from the target the device reported
    in force to the plan at most the rate limit's step (0.03 rad) a tick, each such row LIMITED with the target
    applied. The host reads the ticks that came during the stall a few a turn, so for a while it has not heard
    of the ticks that passed and sends them setpoints the device drops: those, sent after their ticks' instants
    on the host's estimate of the device's clock, may miss them, and the ramp steps from the held target
    whichever of them the device takes."""
    from rig.transports.base import CommandLimits

    bus, transport, device, clock = rig(protocol_version=version)
    transport.limits = CommandLimits(rate_max_rad_per_s=6.0)
    summary, sink, command, _ = _run(bus, transport, clock, stall_at=80, stall_s=stall_s)
    assert transport.version == version and summary.samples == SAMPLES and summary.lost == 0 and summary.held > 0
    limited = check_the_way_back_to_the_plan(sink, device, command, DRIVE, 6.0 * PERIOD_S)
    held = np.flatnonzero(np.array([row[4] for row in sink.rows]) & SampleFlag.HELD)
    assert limited.size > 0 and limited[0] == held[-1] + 1
    assert [row[1] for row in sink.rows[limited[-1] + 1:]] == [DRIVE.quantize_rad(value)
                                                                for value in command[limited[-1] + 1:]]
    assert device.dropped_setpoints and set(device.dropped_setpoints) <= set(held)
