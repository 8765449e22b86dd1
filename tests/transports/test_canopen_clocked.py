"""The CANopen master against the simulated CiA 402 drive and CiA 406 encoder, SYNC by SYNC on a simulated
clock (:mod:`clocked_canopen`: no thread, no sleep; nothing here depends on how busy the machine is).

The expectations are CiA 301 / CiA 402 semantics, not what the code happens to give: SYNC k is the sample
instant k (the master's cyclic task, exactly every period); in cyclic synchronous position (0x6060 = 8) the
drive applies at SYNC k the target 0x607A last received before it; in interpolated position (0x6060 = 7) it
takes one interpolation data record (0x60C1) from its FIFO (0x60C4) per SYNC, and an empty FIFO holds the
last one (an underrun); a synchronous TPDO answers its SYNC, possibly one SYNC later (0x1800:2 = 1 on a
device that sends what it latched at the previous SYNC: legal, and configured on the master)."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols import cia402
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.errors import TransportError
from rig.runner import run_experiment
from rig.transports.canopen_link import CanOpenTransport
from sim_backend.canopen_behaviour import DriveBehaviour, EncoderBehaviour
from sim_backend.canopen_nodes import SimulatedCanOpenRig
from sim_backend.plant_config import load_plant_config

from clocked_canopen import ClockedCanBus
from clocked_line import SimulatedClock
from sim_rigs import CONFIGS, ListSink

DRIVE = DriveScaling(1 << 17)
LEAD_S = 0.1  # the master's default lead
BUFFER_RECORDS = 64  # the simulated drive's 0x60C4:1/2 (configs/eds/sim_drive_cia402.eds)


def _gearbox(rate_hz: float, directory):
    text = (CONFIGS / "plants" / "precision_gearbox.toml").read_text()
    text = text.replace("sample_period_s = 0.001", f"sample_period_s = {1 / rate_hz!r}")
    path = directory / f"plant_{rate_hz:g}.toml"
    path.write_text(text)
    return load_plant_config(path).gearbox(seed=4)


@contextlib.contextmanager
def _clocked_rig(tmp_path, *, rate_hz: float = 1000.0, mode: str = "ip_buffer", drive_behaviour=None,
                 encoder_behaviour=None, transport_options=None, **faults):
    """(bus, transport, rig, clock): the master and the simulated nodes on one :class:`ClockedCanBus`."""
    clock = SimulatedClock(100.0)
    bus = ClockedCanBus(clock)
    gearbox = _gearbox(rate_hz, tmp_path)
    rig = SimulatedCanOpenRig(gearbox, channel="clocked", clock=clock, drive_behaviour=drive_behaviour,
                              encoder_behaviour=encoder_behaviour, **faults)
    transport = CanOpenTransport("virtual", "clocked", encoder=gearbox.encoder, sample_period_s=1 / rate_hz,
                                 drive=DRIVE, timing=BringUpTiming(), mode=mode, lead_s=LEAD_S, name="clocked",
                                 clock=clock, **(transport_options or {}))
    bus.master(transport)
    bus.devices(rig)
    try:
        yield bus, transport, rig, clock
    finally:
        transport.close()
        rig.close()


def _command(num_samples: int) -> np.ndarray:
    return 0.2 * np.sin(2 * np.pi * np.arange(num_samples) / 250)


def _run(bus, transport, clock, command, *, stall_at=None, stall_s=0.0, feedback_timeout_s=0.5):
    stalled = []

    def progress(done: int, _held: int) -> None:
        if stall_at is not None and done >= stall_at and not stalled:
            stalled.append((clock(), transport.device_sample))
            bus.stall(stall_s)

    sink = ListSink()
    summary = run_experiment(transport, command, sink, feedback_timeout_s=feedback_timeout_s, clock=clock,
                             progress=progress)
    return summary, sink, stalled


def _flags(sink) -> np.ndarray:
    return np.array([row[4] for row in sink.rows])


def test_smoke(tmp_path):
    with _clocked_rig(tmp_path) as (bus, transport, rig, clock):
        summary, sink, _ = _run(bus, transport, clock, _command(300))
    print(summary)
    assert summary.lost == 0
