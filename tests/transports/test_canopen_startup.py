"""CANopen specifics against the simulated nodes: SDO configuration, encoder resolution, heartbeat loss,
bus load."""

from __future__ import annotations

import contextlib

import pytest

from rig.transports.simulated import start_simulated_devices
from rig.protocols.encoder_counts import EncoderResolution
from rig.runner import run_experiment
from rig.transports import open_transport
from sim_backend.plant_config import load_plant_config

from rig.protocols.can_bus_load import bus_load, frame_bits
from rig.protocols.cia402 import DriveState
from rig.protocols.errors import ConfigError, DeviceFault
from rig.rig_config import load_rig_config
from rig.transports import Setpoint
from sim_rigs import (  # noqa: F401  (no_leaks is a fixture)
    CONFIGS, ListSink, excitation, no_leaks, simulated, write_test_config,
)


def _u(node, index, subindex=0, signed=False):
    return int.from_bytes(node.get_data(index, subindex), "little", signed=signed)


def test_start_up_configures_csp_mode_pdos_and_heartbeats_by_sdo(tmp_path, no_leaks):
    with simulated("canopen", tmp_path, {"mode": "csp"}) as (config, transport, _, rig):
        transport.open()
        drive, encoder = rig.drive, rig.encoder
        assert _u(drive, 0x6060, signed=True) == 8  # cyclic synchronous position
        assert _u(drive, 0x1006) == 5000  # communication cycle period in microseconds (200 Hz)
        assert _u(drive, 0x1017) == _u(encoder, 0x1017) == 100
        assert [_u(drive, 0x1600, sub) for sub in range(2)] == [1, 0x607A0020]
        assert [_u(drive, 0x1A00, sub) for sub in range(3)] == [2, 0x60410010, 0x60640020]
        assert [_u(encoder, 0x1A00, sub) for sub in range(2)] == [1, 0x60040020]
        assert _u(drive, 0x1800, 2) == _u(encoder, 0x1800, 2) == 1  # synchronous, every SYNC
        assert drive.nmt.state == encoder.nmt.state == "OPERATIONAL"
        transport.send(Setpoint(0, 0.5))
        sample = transport.receive(timeout_s=1.0)
        assert sample.seq == 0 and _u(drive, 0x607A, signed=True) == config.drive.counts_from_rad(0.5)
        transport.close()
        assert drive.nmt.state == "PRE-OPERATIONAL"


def test_an_encoder_whose_resolution_differs_from_the_config_is_refused(tmp_path, no_leaks):
    config = load_rig_config(write_test_config("canopen", tmp_path))
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=1)
    with contextlib.ExitStack() as stack:
        url, _ = start_simulated_devices(config, gearbox, stack)
        options = dict(config.transport_options(), encoder=EncoderResolution(bits=13, signed=True))
        transport = open_transport(url, **options)
        with pytest.raises(DeviceFault, match=r"reports 4096 counts per revolution and a range of 4096 counts "
                                              r"\(0x6001, 0x6002\), but the config says 8192 and 8192"):
            transport.open()
        assert not transport.is_open


def test_heartbeat_loss_stops_the_run(tmp_path, no_leaks):
    sink = ListSink()
    with simulated("canopen", tmp_path, stop_heartbeat_at_seq=5) as (config, transport, _, rig):
        with pytest.raises(DeviceFault, match=r"heartbeat lost \(none for .* s, timeout 0.5 s\)"):
            run_experiment(transport, excitation(400), sink, feedback_timeout_s=1.0, late_tolerance_s=0.0025)
        assert rig.controlwords[-2:] == [0x02, 0x00]
    assert sink.closed and 5 < len(sink.rows) < 400


def test_the_cycle_fits_the_bus_and_a_rate_it_cannot_carry_is_rejected(tmp_path):
    # SYNC (0 bytes) + RPDO (4) + drive TPDO (6) + encoder TPDO (4), worst-case stuffing and 3 bit IFS
    assert [frame_bits(n) for n in (0, 4, 6, 4)] == [58, 98, 118, 98]
    load = bus_load((0, 4, 6, 4), 1000.0, 1_000_000)
    assert load.bits_per_cycle == 372 and load.load == pytest.approx(0.372)
    assert load.max_rate_hz == pytest.approx(2688.17, abs=0.01)
    path = tmp_path / "fast.toml"
    text = (CONFIGS / "sim_canopen.toml").read_text().replace("late_tolerance_s = 0.0005", "late_tolerance_s = 0.0001")
    text = text.replace('plant = "plants/', f'plant = "{CONFIGS}/plants/')
    path.write_text(text.replace("sample_rate_hz = 1000.0", "sample_rate_hz = 3000.0"))
    # with the drive's TPDO2 (0x6062 position demand value, 4 bytes: 98 bit) for the latency check: 470 bit
    with pytest.raises(ConfigError, match=r"\[transport.bitrate\] 1000000 bit/s cannot carry 3000 Hz: one cycle takes 470 bit \(141% load\); "
                                          r"the limit is 2128 Hz"):
        load_rig_config(path)
    path.write_text(path.read_text().replace("bitrate = 1000000", "bitrate = 500000").replace(
        "sample_rate_hz = 3000.0", "sample_rate_hz = 1000.0"))
    assert load_rig_config(path).sample_rate_hz == 1000.0  # 94% of 500 kbit/s


def test_the_simulated_bus_reports_its_load(tmp_path, no_leaks):
    with simulated("canopen", tmp_path) as (config, transport, _, rig):
        summary = run_experiment(transport, excitation(60), ListSink(), feedback_timeout_s=0.5,
                                 late_tolerance_s=0.0025)
        frames, load = rig.frames, rig.bus_load()
    assert frames >= 4 * summary.samples  # SYNC, RPDO and two TPDOs per sample, plus SDO and heartbeats
    assert 0 < load < 1


def test_homing_runs_before_streaming_when_not_skipped(tmp_path, no_leaks):
    path = write_test_config("canopen", tmp_path)
    path.write_text(path.read_text().replace("sdo_timeout_s = 0.5", 'sdo_timeout_s = 0.5\nskip_homing = false\nmode = "csp"'))
    config = load_rig_config(path)
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, gearbox, stack)
        transport = stack.enter_context(open_transport(url, **config.transport_options()))
        transport.open()
        assert rig.homed and _u(rig.drive, 0x6098, signed=True) == 37
        assert _u(rig.drive, 0x6060, signed=True) == 8  # back in cyclic synchronous position for streaming
        assert rig.controlwords == [0x06, 0x07, 0x0F, 0x1F, 0x0F]  # enable, start homing, then CSP
        transport.send(Setpoint(0, 0.1))
        assert transport.receive(timeout_s=1.0).seq == 0


def _unopened_canopen_transport(**options):
    from rig.transports.canopen_link import CanOpenTransport

    return CanOpenTransport("virtual", "unused", encoder=EncoderResolution(bits=12, signed=True),
                            sample_period_s=1e-3, **options)


class _RecordingNetwork:
    """Stands in for canopen.Network in scripted exchanges: records the frames the master sends."""

    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes]] = []
        self.echoed = 0

    def send_message(self, can_id: int, data: bytes) -> None:
        self.sent.append((can_id, bytes(data)))

    def next_echo(self) -> tuple[int, bytes]:
        """The COB-ID and data of the oldest frame sent whose echo the script has not yet given the master."""
        self.echoed += 1
        return self.sent[self.echoed - 1]


def _streaming_canopen_transport(**options):
    """A transport in the state streaming leaves it in, driven by scripted bus events (canopen
    test_sdo.py style): SYNC echoes, RPDO echoes and TPDOs with their bus timestamps, no threads."""
    from rig.transports.canopen_dictionary import PdoLayout

    transport = _unopened_canopen_transport(**{"mode": "csp", **options})
    transport.network = _RecordingNetwork()
    transport._rpdo = PdoLayout("RPDO1 of drive 1", 0x201, {0x607A: (0, 4)}, 4)
    transport._in_force = (-1, 0)
    return transport


def test_a_tpdo_is_filed_under_the_last_sync_before_its_bus_timestamp_once_the_next_sync_is_seen():
    transport = _streaming_canopen_transport()
    transport._origin = 1  # the first SYNC seen is sample 0
    transport._on_sync_echo(0x80, b"", 10.000)  # sample 0
    transport._file("drive", (0x1637, 100, None), 10.0003)
    transport._file("encoder", -1, 10.0004)
    assert not transport._ready  # the bus order around it is known only at the next SYNC
    transport._on_sync_echo(0x80, b"", 10.001)  # sample 1
    sample = transport._ready.popleft()
    assert (sample.seq, sample.encoder_counts, sample.statusword) == (0, -1, 0x1637)
    assert transport._sync_before(9.999) is None  # before any SYNC: answers nothing of ours


def test_a_tpdo_that_reaches_the_host_before_the_echo_of_its_sync_is_filed_under_that_sync():
    """The device may answer SYNC 1 before the interface gives the master the echo of SYNC 1 (on the
    virtual bus the device's queue gets the SYNC first): the answer must not be filed under SYNC 0."""
    transport = _streaming_canopen_transport()
    transport._origin = 1
    transport._on_sync_echo(0x80, b"", 20.000)  # sample 0
    transport._file("drive", (0x1637, 100, None), 20.0013)  # answers sample 1, whose echo is not back yet
    transport._file("encoder", 3, 20.0014)
    transport._on_sync_echo(0x80, b"", 20.0010)  # sample 1
    assert not transport._ready
    transport._on_sync_echo(0x80, b"", 20.0020)  # sample 2: now the order is known
    sample = transport._ready.popleft()
    assert sample.seq == 1 and sample.encoder_counts == 3 and not transport._ready


def test_targets_go_on_the_bus_right_after_the_previous_sync_and_a_late_one_is_held():
    transport = _streaming_canopen_transport()
    for seq, counts in ((0, 10), (1, 20)):
        transport._send(Setpoint(seq, transport.drive.rad_from_counts(counts)))
    assert transport.network.sent == []  # queued: nothing goes out before a SYNC
    transport._on_sync_echo(0x80, b"", 1.000)  # SYNC count 1: target 0 goes out, for the next SYNC
    assert transport.network.sent == [(0x201, (10).to_bytes(4, "little"))]
    transport._on_rpdo_echo(*transport.network.next_echo(), 1.0002)
    transport._on_sync_echo(0x80, b"", 1.001)  # sample 0 (target 0 in force); target 1 goes out
    transport._on_rpdo_echo(*transport.network.next_echo(), 1.0012)
    transport._on_sync_echo(0x80, b"", 1.002)  # sample 1: target 1 in force; nothing queued for sample 2
    transport._on_sync_echo(0x80, b"", 1.003)  # sample 2: held at target 1
    transport._send(Setpoint(2, transport.drive.rad_from_counts(30)))  # came after its SYNC: dropped
    assert [sent[1] for sent in transport.network.sent] == [(10).to_bytes(4, "little"), (20).to_bytes(4, "little")]
    assert transport._applied[0] == (10, False, False) and transport._applied[1] == (20, False, False)
    assert transport._applied[2] == (20, True, False)  # HELD: the command really applied is logged
    assert transport.device_sample == 2 and transport.min_lead_s < 0


def test_a_target_whose_rpdo_reaches_the_bus_after_its_sync_is_held():
    """The receive thread put target 1 on the bus, but the bus carried it after SYNC 1: the echoes' order
    says sample 1 ran with target 0."""
    transport = _streaming_canopen_transport()
    transport._send(Setpoint(0, transport.drive.rad_from_counts(10)))
    transport._send(Setpoint(1, transport.drive.rad_from_counts(20)))
    transport._on_sync_echo(0x80, b"", 1.000)
    transport._on_rpdo_echo(*transport.network.next_echo(), 1.0002)
    transport._on_sync_echo(0x80, b"", 1.001)  # sample 0; target 1 sent ...
    transport._on_sync_echo(0x80, b"", 1.002)  # ... but SYNC 1 came first on the bus
    transport._on_rpdo_echo(*transport.network.next_echo(), 1.0021)
    assert transport._applied[1] == (10, True, False)


def test_a_configured_tpdo_latency_files_each_answer_under_the_sync_it_answers():
    """A device that answers SYNC k after SYNC k + 1 (tpdo_latency_cycles = 1)."""
    transport = _streaming_canopen_transport(drive_tpdo_latency_cycles=1, encoder_tpdo_latency_cycles=1)
    transport._origin = 1
    for bus_time in (5.000, 5.001):  # samples 0, 1
        transport._on_sync_echo(0x80, b"", bus_time)
    transport._file("drive", (0x1637, 7, None), 5.0013)  # between SYNC 1 and 2: the answer to SYNC 0
    transport._file("encoder", 42, 5.0014)
    transport._on_sync_echo(0x80, b"", 5.002)
    assert transport._ready.popleft().seq == 0


def test_an_interface_that_does_not_echo_our_frames_is_refused_at_start_up(tmp_path, monkeypatch, no_leaks):
    from rig.protocols.errors import TransportError

    # the bus is opened as on an interface that echoes by itself, so it is not asked to, and does not
    monkeypatch.setattr("rig.protocols.can_interfaces.echoes_own_frames", lambda interface: True)
    monkeypatch.setattr("rig.transports.canopen_link.SYNC_ECHO_TIMEOUT_S", 0.05)
    config = load_rig_config(write_test_config("canopen", tmp_path))
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, gearbox, stack)
        transport = stack.enter_context(open_transport(url, **config.transport_options()))
        with pytest.raises(TransportError, match="did not echo a transmitted SYNC.*receive_own_messages"):
            transport.open()
        assert rig.state is not DriveState.OPERATION_ENABLED  # refused before the drive was enabled


class _EncoderObjects:
    """An encoder node's object dictionary and SDO answers, for the resolution check alone."""

    def __init__(self, values: dict[int, int]) -> None:
        self.object_dictionary = set(values)
        self.sdo = {index: type("Entry", (), {"raw": value})() for index, value in values.items()}


@pytest.mark.parametrize(("bits", "multi_turn_bits", "values"), [
    (12, 0, {0x6001: 4096, 0x6002: 4096, 0x6000: 0}),
    (16, 16, {0x6001: 65536, 0x6002: 0, 0x6000: 0}),  # 2**32 does not fit UNSIGNED32: a 32-bit encoder says 0
    (12, 4, {0x6501: 4096, 0x6502: 16}),  # an EDS without the scaling objects: the physical resolution
])
def test_the_encoder_resolution_is_read_from_the_cia_406_scaling_objects(bits, multi_turn_bits, values):
    from rig.transports.canopen_link import CanOpenTransport

    transport = CanOpenTransport("virtual", "unused", encoder=EncoderResolution(bits=bits, multi_turn_bits=multi_turn_bits),
                                 sample_period_s=1e-3)
    transport._check_encoder(_EncoderObjects(values))  # accepted: no exception


def test_an_encoder_counting_the_other_way_is_refused_naming_the_code_sequence():
    from rig.transports.canopen_link import CanOpenTransport

    transport = CanOpenTransport("virtual", "unused", encoder=EncoderResolution(bits=12), sample_period_s=1e-3)
    with pytest.raises(DeviceFault, match=r"counts down with the angle \(0x6000 bit 0, code sequence = 1\).*"
                                          r"set \[encoder\] direction = -1"):
        transport._check_encoder(_EncoderObjects({0x6001: 4096, 0x6002: 4096, 0x6000: 1}))


def test_one_demand_value_off_is_an_ambiguous_sample_and_three_in_a_row_a_wrong_latency():
    """0x6062 (position demand value) beside each sample: one that shows the previous target is a target
    that crossed its SYNC (AMBIGUOUS); three in a row is a device answering a SYNC later than configured."""
    from rig.protocols.errors import DeviceFault
    from rig.transports.canopen_dictionary import PdoLayout
    from rig.transports.canopen_filing import LATENCY_EVIDENCE_SAMPLES

    transport = _streaming_canopen_transport()
    transport._demand_tpdo = PdoLayout("TPDO2 of drive 1", 0x281, {0x6062: (0, 4)}, 4)
    count = 12
    for sample in range(count):  # a new target for every sample
        transport._send(Setpoint(sample, transport.drive.rad_from_counts(100 * sample)))
    clock = iter(1.0 + k / 1000 for k in range(100))

    def sync() -> float:
        at = next(clock)
        transport._on_sync_echo(0x80, b"", at)  # records the target in force, puts the next one on the bus
        transport._on_rpdo_echo(*transport.network.next_echo(), at + 0.0001)
        return at

    def answer(demand: int) -> None:
        at = sync()
        for part, value in (("drive", (0x1637, demand, None)), ("encoder", 5), ("demand", demand)):
            transport._file(part, value, at + 0.0003)

    sync()  # the first SYNC: target 0 goes out for the next one
    for demand in (0, 0, 200, 300):  # sample 1's demand is sample 0's target: one crossing
        answer(demand)
    sync()  # files the answers to the last SYNC
    samples = {sample.seq: sample for sample in transport._ready}
    assert samples[1].ambiguous and not samples[0].ambiguous and not samples[2].ambiguous
    transport.raise_fault()  # no fault from a single crossing
    for sample in range(5, 5 + LATENCY_EVIDENCE_SAMPLES + 1):  # from here the drive answers one SYNC late
        answer(100 * (sample - 1))
    sync()
    with pytest.raises(DeviceFault, match=r"set drive_tpdo_latency_cycles = 1"):
        transport.raise_fault()


def test_the_interpolation_time_period_takes_the_form_cia402_0x60c2_holds():
    """0x60C2: sub 1 an UNSIGNED8 value, sub 2 an INTEGER8 power of ten (seconds): 1 ms is 1 x 10^-3, not
    1000 x 10^-6, which does not fit sub 1; a period with no exact form (1/3 ms) has none."""
    from rig.transports.canopen_dictionary import interpolation_time_period

    assert interpolation_time_period(1e-3, 255) == (1, -3)
    assert interpolation_time_period(250e-6, 255) == (25, -5)  # the smallest value that holds it exactly
    assert interpolation_time_period(5e-3, 255) == (5, -3)
    assert interpolation_time_period(1 / 3000, 255) is None and interpolation_time_period(333e-6, 255) is None
    assert interpolation_time_period(333e-6, 65535) == (333, -6)  # a drive whose sub 1 is wider
