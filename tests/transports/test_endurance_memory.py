"""Memory that does not grow with a run's length, on every wire: the real host transport and runner against the
simulated device of that wire (serial, CANopen, raw CAN), driver and device in one process on one simulated
clock (:mod:`clocked_line`, :mod:`clocked_canopen`: nothing here depends on how busy the machine is). A run of
10 N samples holds no more traced memory at its end than a run of N, beyond a small allowance: the device keeps
what it applied on disk (:class:`sim_backend.device_record.AppliedTargets`), not in a list, and the record
still judges every row of the host's log."""

from __future__ import annotations

import collections
import contextlib
import gc
import tracemalloc
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.runner import run_experiment
from sim_backend.plant_config import load_plant_config

from clocked_canopen import ClockedCanBus
from clocked_line import ClockedBus, SimulatedClock, SimulatedRawCanEndpoint, simulated_device_line

ROOT = Path(__file__).resolve().parents[2]
PLANT = ROOT / "configs" / "plants" / "precision_gearbox.toml"  # 1 kHz
PERIOD_S = 0.001
DRIVE = DriveScaling(1 << 17)
WIRES = ("serial", "canopen", "can")
SHORT_SAMPLES = 1_000
RECENT_SAMPLES = 256
"""The windows of recent samples (the CANopen master's SYNCs and targets in force, the drive's buffer levels; 4096
in a run) shrunk, so that a run of N samples fills them as one of 10 N does."""
GROWTH_ALLOWANCE_BYTES = 48 * 1024
"""What a run of 10 N samples may hold beyond a run of N: the device's unwritten block of applied targets (at
most 16 kB), the CANopen master's window of targets in force between half full and full (about 30 kB), whatever
N is. A list of the applied targets grew by 36 bytes a sample: 324 kB for the 9 000 samples more."""


@contextlib.contextmanager
def _clocked_wire(wire: str) -> Iterator[tuple[object, object, SimulatedClock]]:
    """(transport, device, clock): ``wire``'s host transport and simulated device on one simulated clock. The
    test buses' own transcripts of every frame keep only their last frames (they are the test's, not the
    product's)."""
    gearbox = load_plant_config(PLANT).gearbox(seed=3)
    clock = SimulatedClock(100.0)
    if wire == "serial":
        from rig.transports.serial_link import SerialTransport
        from sim_backend.serial_device import SimulatedSerialDevice

        device = SimulatedSerialDevice(gearbox, clock=clock, buffer_capacity=64)
        transport = SerialTransport("simulated", encoder=EncoderResolution(bits=12, signed=True),
                                    sample_period_s=PERIOD_S, drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0),
                                    reply_timeout_s=0.3, lead_s=0.05, name="clocked", clock=clock)
        line = simulated_device_line(transport, clock, device)
        line.to_host = collections.deque(maxlen=64)
    elif wire == "can":
        from rig.transports.raw_can import RawCanTransport
        from sim_backend.raw_can_device import SimulatedRawCanDevice

        device = SimulatedRawCanDevice(gearbox, channel="unused", clock=clock)
        transport = RawCanTransport("virtual", "clocked", encoder=EncoderResolution(bits=12, signed=True),
                                    sample_period_s=PERIOD_S, drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0),
                                    reply_timeout_s=0.3, lead_s=0.05, name="clocked", clock=clock)
        endpoint = SimulatedRawCanEndpoint(device)
        bus = ClockedBus(transport, clock, endpoint)
        endpoint.connect(bus)
        bus.to_host = collections.deque(maxlen=64)
    else:
        from rig.transports.canopen_link import CanOpenTransport
        from sim_backend.canopen_nodes import SimulatedCanOpenRig

        device = SimulatedCanOpenRig(gearbox, channel="clocked", clock=clock)
        transport = CanOpenTransport("virtual", "clocked", encoder=gearbox.encoder, sample_period_s=PERIOD_S,
                                     drive=DRIVE, timing=BringUpTiming(), name="clocked", clock=clock)
        bus = ClockedCanBus(clock)
        bus.frames = collections.deque(maxlen=64)
        bus.master(transport)
        bus.devices(device)
    try:
        yield transport, device, clock
    finally:
        transport.close()
        device.close()


class _Rows:
    """The logged commands in drive counts and whether each row is usable, as plain integers in bounded memory."""

    def __init__(self, num_samples: int) -> None:
        self.counts = np.zeros(num_samples, dtype=np.int64)
        self.flags = np.zeros(num_samples, dtype=np.int64)
        self.rows = 0

    def append(self, time_s, command_rad, angle_rad, encoder_counts=None, flags=0) -> None:
        self.counts[self.rows] = DRIVE.counts_from_rad(command_rad)
        self.flags[self.rows] = int(flags)
        self.rows += 1

    def close(self) -> None:
        pass


def _held_after_run(wire: str, num_samples: int) -> tuple[int, int]:
    """(bytes allocated during a run of ``num_samples`` on ``wire`` and still held at its end, with the transport
    and device still open; rows the device's record judged wrong)."""
    from identify.experiment_record import SampleFlag

    command = 0.1 * np.sin(2 * np.pi * np.arange(num_samples) / 1000)
    rows = _Rows(num_samples)
    with _clocked_wire(wire) as (transport, device, clock):
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        summary = run_experiment(transport, command, rows, feedback_timeout_s=0.5, clock=clock)
        gc.collect()
        held = tracemalloc.get_traced_memory()[0] - before
        record = device.record()
    assert summary.samples == rows.rows == num_samples and summary.lost == summary.held == 0
    usable = (rows.flags & int(SampleFlag.unusable())) == 0
    return held, record.wrong_rows(rows.counts.tolist(), usable.tolist())


@pytest.mark.parametrize("wire", WIRES)
def test_a_run_ten_times_as_long_holds_no_more_memory(wire, monkeypatch):
    """N and 10 N samples at 1 kHz: what the run still holds at its end (device, transport, runner; traced
    allocations, no log file) grows by less than :data:`GROWTH_ALLOWANCE_BYTES`, and the device's record still
    finds every logged command the one it applied."""
    from rig.transports.canopen_link import CanOpenTransport

    monkeypatch.setattr(CanOpenTransport, "RECENT_SAMPLES", RECENT_SAMPLES)
    monkeypatch.setattr("sim_backend.interpolation_buffer.LEVELS_KEPT", RECENT_SAMPLES)
    _held_after_run(wire, 200)  # (imports and caches of a first run, untraced)
    tracemalloc.start()
    try:
        short, short_wrong = _held_after_run(wire, SHORT_SAMPLES)
        long, long_wrong = _held_after_run(wire, 10 * SHORT_SAMPLES)
    finally:
        tracemalloc.stop()
    assert short_wrong == long_wrong == 0
    assert long - short < GROWTH_ALLOWANCE_BYTES, (
        f"{wire}: {short} bytes held after {SHORT_SAMPLES} samples, {long} after {10 * SHORT_SAMPLES}")
