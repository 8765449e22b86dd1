"""Serial protocol v2 (docs/serial_protocol.md, section 16), scripted: the real host transport and the
simulated device joined without a port or threads (every frame the host writes is handled at once, the
device's frames wait until the host polls, and the device ticks only when the test says), so each test
reads like a line trace and depends on no timing. Then the runs: v2 against the simulated device, and v1
devices still driven host-paced."""

from __future__ import annotations

import math

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.cia402 import BringUpTiming, DriveScaling, DriveState
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError, DeviceFault, TransportError
from rig.protocols.serial_frames import FrameDecoder, MessageType, SerialMessage, decode_frame, encode_frame
from rig.runner import run_experiment
from rig.transports.base import Setpoint
from rig.transports.serial_link import SerialTransport
from sim_backend.plant_config import load_plant_config
from sim_backend.serial_device import SimulatedSerialDevice

from clocked_line import SimulatedClock
from sim_rigs import CONFIGS, ListSink, excitation, no_leaks, simulated  # noqa: F401  (no_leaks is a fixture)

PERIOD_S = 0.005
DRIVE = DriveScaling(1 << 17)


class Wire:
    """A host transport and a simulated device on one scripted line; :attr:`trace` is what crossed it. The
    transport's clock (``clock``, simulated) moves one period with each tick, and by its timeout when the host
    polls an empty line."""

    def __init__(self, transport: SerialTransport, device: SimulatedSerialDevice, clock: SimulatedClock) -> None:
        self.transport, self.device, self.clock = transport, device, clock
        self.trace: list[tuple[str, str, int, tuple[int, ...]]] = []
        self._to_host = bytearray()
        self._device_decoder = FrameDecoder()
        transport._connect = lambda: None
        transport._write = self._host_writes
        transport._poll = self._host_polls

    def _host_writes(self, data: bytes) -> None:
        for message in self._device_decoder.feed(data):
            self.trace.append(("->", message.type.name, message.seq, message.fields))
            self._to_host += self.device.handle(message)

    def _host_polls(self, timeout_s: float) -> bool:
        if not self._to_host:
            self.clock.advance_to(self.clock() + timeout_s)
            return False
        data, self._to_host = bytes(self._to_host), bytearray()
        for message in FrameDecoder().feed(data):
            self.trace.append(("<-", message.type.name, message.seq, message.fields))
            self.transport._dispatch(message, self.clock())
        return True

    def tick(self, ticks: int = 1) -> None:
        for _ in range(ticks):
            self.clock.advance_to(self.clock() + PERIOD_S)
            self._to_host += self.device.tick()

    def sent(self, name: str) -> list[tuple[int, tuple[int, ...]]]:
        return [(seq, fields) for way, kind, seq, fields in self.trace if way == "->" and kind == name]


class _FromOne:
    """A session's request numbers from 1, as in the spec's worked examples (the host picks a random origin)."""

    @staticmethod
    def randrange(_stop: int) -> int:
        return 0


@pytest.fixture
def line(monkeypatch):
    """``line(**device_options, protocol=..., lead_s=...)`` -> a :class:`Wire`; devices closed afterwards."""
    from rig.transports import serial_link

    monkeypatch.setattr(serial_link, "REQUEST_ORIGINS", _FromOne())
    devices = []

    def make(*, protocol: str = "auto", lead_s: float = 0.05, **device_options) -> Wire:
        gearbox = load_plant_config(CONFIGS / "plants" / "precision_gearbox.toml").gearbox(seed=0)
        device = SimulatedSerialDevice(gearbox, **{"sample_period_s": PERIOD_S, **device_options})
        devices.append(device)
        clock = SimulatedClock(1000.0)
        transport = SerialTransport("scripted", encoder=EncoderResolution(bits=12, signed=True), sample_period_s=PERIOD_S,
                                    drive=DRIVE, timing=BringUpTiming(poll_interval_s=0.0), reply_timeout_s=0.01,
                                    protocol=protocol, lead_s=lead_s, name="scripted", clock=clock)
        return Wire(transport, device, clock)

    yield make
    for device in devices:
        device.close()


def _tick_samples(wire: Wire) -> list:
    samples = []
    while (sample := wire.transport.receive(0.0)) is not None:
        samples.append(sample)
    return samples


# -- the handshake ----------------------------------------------------------------------------------------------

def test_hello_is_answered_with_version_capacity_and_period_and_sets_the_lead(line):
    wire = line(buffer_capacity=64)
    wire.transport.prepare()
    assert wire.trace[:4] == [("->", "STATUS_REQUEST", 1, ()), ("<-", "STATUS", 1, (0x0240, 0)),
                              ("->", "HELLO", 2, (2,)), ("<-", "DEVICE_INFO", 2, (2, 64, 5_000_000))]
    assert wire.transport.version == 2 and wire.device.mode == 2
    assert wire.transport.lead_samples == 10  # ceil(50 ms / 5 ms)
    assert wire.device.controlwords == []  # nothing enabling before the handshake is done
    wire.transport.close()


def test_the_lead_is_capped_by_the_devices_buffer(line):
    wire = line(buffer_capacity=4)
    wire.transport.prepare()
    assert wire.transport.lead_samples == 4
    wire.transport.close()


def test_a_v1_device_drops_hello_and_is_driven_host_paced(line):
    wire = line(protocol_version=1)
    wire.transport.prepare()
    assert wire.sent("HELLO") == [(2, (2,)), (2, (2,))]  # once more after a lost answer, same request number
    assert wire.transport.version == 1 and wire.transport.lead_samples == 0
    assert "driven as a protocol v1 device (host-paced" in wire.transport.warnings[0]
    wire.transport.enable()
    wire.transport.send(Setpoint(0, 0.01))  # v1: one SETPOINT, one FEEDBACK, no START
    assert wire.transport.receive(0.0).seq == 0 and wire.sent("START") == []
    wire.transport.close()


def test_protocol_v1_sends_no_hello_and_a_v2_device_then_streams_the_v1_way(line):
    wire = line(protocol="v1")
    wire.transport.open()
    wire.transport.send(Setpoint(0, 0.01))
    sample = wire.transport.receive(0.0)
    assert wire.sent("HELLO") == [] and wire.device.mode == 1
    assert [kind for _, kind, _, _ in wire.trace[-2:]] == ["SETPOINT", "FEEDBACK"] and sample.seq == 0
    wire.transport.close()


def test_protocol_v2_refuses_a_v1_device_before_enabling_it(line):
    wire = line(protocol="v2", protocol_version=1)
    with pytest.raises(TransportError, match=r"speaks only protocol v1 \(it drops HELLO\); set \[transport\] protocol"):
        wire.transport.prepare()
    assert wire.device.controlwords == []


def test_a_device_ticking_at_another_period_is_refused_naming_both(line):
    wire = line(sample_period_s=0.001)
    with pytest.raises(ConfigError, match=r"200 Hz, but the device ticks every 1000000 ns \(1000 Hz, DEVICE_INFO\)"):
        wire.transport.prepare()
    assert wire.device.controlwords == []


# -- streaming ------------------------------------------------------------------------------------------------

def test_setpoints_queued_ahead_are_applied_at_their_ticks_and_an_underrun_is_held(line):
    wire = line()
    transport, device = wire.transport, wire.device
    transport.open()
    targets = [DRIVE.quantize_rad(0.001 * (k + 1)) for k in range(5)]
    for k in range(3):
        transport.send(Setpoint(k, targets[k]))
    assert transport.receive(0.0) is None  # the first receive sends START: tick 0 is now
    assert wire.sent("START") and device.ticks == 0 and sorted(device.buffer) == [0, 1, 2]
    assert wire.trace[-1][:3] == ("<-", "STATUS", wire.sent("START")[0][0])
    wire.tick(4)  # ticks 0, 1, 2 have their setpoints; tick 3 finds the buffer empty
    samples = _tick_samples(wire)
    ticks = [(way, kind, seq, fields) for way, kind, seq, fields in wire.trace if kind == "TICK"]
    assert [fields[4:] for *_, fields in ticks] == [(0, 2), (0, 1), (0, 0), (1, 0)]  # (flags, buffer level)
    assert [sample.seq for sample in samples] == [0, 1, 2, 3]
    assert [sample.held for sample in samples] == [False, False, False, True]
    # the HELD tick carries the command really applied: the previous target
    assert [sample.applied_position_rad for sample in samples] == targets[:3] + [targets[2]]
    assert transport.device_sample == 3 and device.held_ticks == 1
    written = len(wire.sent("SETPOINT"))
    transport.send(Setpoint(3, targets[3]))  # for a tick the device has reported: it would be dropped there
    assert len(wire.sent("SETPOINT")) == written and device.dropped_setpoints == 0 and transport.min_lead_s <= 0
    transport.send(Setpoint(4, targets[4]))
    wire.tick()
    (sample,) = _tick_samples(wire)
    assert (sample.seq, sample.held, sample.applied_position_rad) == (4, False, targets[4])
    assert device.setpoints == device.ticks == 5  # the plant stepped once per tick, held ones included
    transport.close()
    assert device.mode == 1 and device.buffer == {} and device.tick() == b""  # the session ended with the stop


def test_a_fault_frame_comes_before_the_tick_it_happened_in(line):
    wire = line(fault_at_seq=1, fault_code=0x2310)
    transport = wire.transport
    transport.open()
    for k in range(3):
        transport.send(Setpoint(k, 0.0))
    transport.receive(0.0)
    wire.tick(3)  # tick 1 faults; the clock stops, so there is no tick 2
    with pytest.raises(DeviceFault, match=r"0x2310"):
        _tick_samples(wire)
    kinds = [kind for _, kind, _, _ in wire.trace if kind in ("TICK", "FAULT")]
    assert kinds == ["TICK", "FAULT", "TICK"]
    assert transport.fault_sample == 1 and wire.device.ticks == 2 and wire.device.setpoints == 1
    transport.close()


def test_the_device_buffer_replaces_a_repeated_tick_and_drops_what_it_cannot_hold(line):
    wire = line(buffer_capacity=2)
    device = wire.device
    for seq, word in enumerate((0x0006, 0x0007, 0x000F), start=1):
        device.handle(SerialMessage(MessageType.CONTROL, seq, (word,)))
    info = decode_frame(device.handle(SerialMessage(MessageType.HELLO, 4, (2,)))[:-1])
    assert info.fields == (1, 2, 5_000_000)  # HELLO in OPERATION ENABLED does not change the mode
    device.handle(SerialMessage(MessageType.CONTROL, 5, (0x0007,)))  # disable operation: not enabled any more
    assert decode_frame(device.handle(SerialMessage(MessageType.HELLO, 6, (2,)))[:-1]).fields == (2, 2, 5_000_000)
    device.handle(SerialMessage(MessageType.CONTROL, 7, (0x000F,)))
    for seq, target in ((0, 10), (1, 20), (0, 11), (2, 30)):  # tick 0 replaced; tick 2 finds the buffer full
        assert device.handle(SerialMessage(MessageType.SETPOINT, seq, (target,))) == b""
    assert device.buffer == {0: 11, 1: 20} and device.dropped_setpoints == 1
    assert device.tick() == b""  # no tick before START
    device.handle(SerialMessage(MessageType.START, 8, ()))
    assert decode_frame(device.tick()[:-1]).fields[3:] == (11, 0, 1)  # applied 11, not held, 1 left


def test_tick_numbers_unwrap_past_65535(line):
    wire = line()
    transport = wire.transport
    transport.version, transport._device_sample = 2, 0xFFFE
    transport._dispatch(SerialMessage(MessageType.TICK, 0xFFFF, (0x1637, 0, 0, 0, 0, 5)), 0.0)
    transport._dispatch(SerialMessage(MessageType.TICK, 0x0000, (0x1637, 0, 0, 0, 0, 5)), 0.0)
    assert [sample.seq for sample in transport._feedback] == [0xFFFF, 0x10000] and transport.device_sample == 0x10000


# -- runs ------------------------------------------------------------------------------------------------------

def test_a_v1_simulated_device_is_driven_host_paced_and_equals_the_offline_simulation(tmp_path, no_leaks):
    command = excitation(40)
    sink = ListSink()
    with simulated("serial", tmp_path, protocol_version=1) as (config, transport, _, device):
        summary = run_experiment(transport, command, sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s)
        assert transport.version == 1 and transport.lead_samples == 0 and device.ticks == 0
        assert device.setpoints == 40  # one plant step per SETPOINT: host-paced
        plant_path, seed = config.simulation.plant_path, config.simulation.seed
    assert math.isnan(summary.min_lead_s) and summary.held == 0 and "protocol v1" in summary.warnings[0]
    _, sent, angle, _, flags = (np.array(column, dtype=object) for column in zip(*sink.rows))
    lost = (np.array(flags, dtype=int) & SampleFlag.LOST) != 0
    expected = load_plant_config(plant_path).gearbox(seed=seed).simulate(sent.astype(float))
    np.testing.assert_array_equal(angle[~lost].astype(float), expected.measured_angle_rad[~lost])


def test_a_v2_run_reports_its_lead_and_every_row_is_a_tick(tmp_path, no_leaks):
    sink = ListSink()
    with simulated("serial", tmp_path) as (config, transport, _, device):
        # more samples than the default lead (250 ms, 50 at the test's 200 Hz): some setpoints go after START
        summary = run_experiment(transport, excitation(80), sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s)
        assert transport.lead_samples == 50
        assert transport.version == 2 and device.ticks >= 80 and device.state is DriveState.SWITCH_ON_DISABLED
    flags = np.array([row[4] for row in sink.rows])
    assert len(sink.rows) == 80 and summary.held == np.count_nonzero(flags & SampleFlag.HELD)
    assert summary.lost == np.count_nonzero(flags & SampleFlag.LOST) and not summary.warnings
    assert not math.isnan(summary.min_lead_s)


def test_the_simulated_serial_device_in_a_process_of_its_own_serves_a_run(tmp_path, no_leaks):
    """``python -m sim_backend.device_process serial`` (the benchmark's device: its own GIL and clock, as a real
    microcontroller): a v2 run, and the log equals the offline simulation of the commands the device applied."""
    import contextlib

    from rig.rig_config import load_rig_config
    from rig.transports import open_transport
    from rig.transports.simulated import start_device_process
    from sim_rigs import write_test_config

    config = load_rig_config(write_test_config("serial", tmp_path))
    sink = ListSink()
    with contextlib.ExitStack() as stack:
        url, _ = start_device_process(config, stack)
        transport = open_transport(url, **config.transport_options())
        summary = run_experiment(transport, excitation(80), sink, feedback_timeout_s=2.0,
                                 late_tolerance_s=config.late_tolerance_s)
    assert transport.version == 2 and summary.samples == 80 and summary.lost == 0
    _, commands, angles, _, _ = (np.array(column, dtype=float) for column in zip(*sink.rows))
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    np.testing.assert_array_equal(angles, gearbox.simulate(commands).measured_angle_rad)
