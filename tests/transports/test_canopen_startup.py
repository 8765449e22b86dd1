"""CANopen specifics against the simulated nodes: SDO configuration, encoder resolution, heartbeat loss,
bus load."""

from __future__ import annotations

import contextlib

import pytest

from rig.commands.run import start_simulated_devices
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
    with simulated("canopen", tmp_path) as (config, transport, _, rig):
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
                                              r"\(0x6501, 0x6002\), but the config says 8192 and 8192"):
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
    with pytest.raises(ConfigError, match=r"\[transport.bitrate\] 1000000 bit/s cannot carry 3000 Hz: one cycle takes 372 bit \(112% load\); "
                                          r"the limit is 2688 Hz"):
        load_rig_config(path)
    path.write_text(path.read_text().replace("bitrate = 1000000", "bitrate = 500000").replace(
        "sample_rate_hz = 3000.0", "sample_rate_hz = 1000.0"))
    assert load_rig_config(path).sample_rate_hz == 1000.0  # 74% of 500 kbit/s


def test_the_simulated_bus_reports_its_load(tmp_path, no_leaks):
    with simulated("canopen", tmp_path) as (config, transport, _, rig):
        summary = run_experiment(transport, excitation(60), ListSink(), feedback_timeout_s=0.5,
                                 late_tolerance_s=0.0025)
        frames, load = rig.frames, rig.bus_load()
    assert frames >= 4 * summary.samples  # SYNC, RPDO and two TPDOs per sample, plus SDO and heartbeats
    assert 0 < load < 1


def test_homing_runs_before_streaming_when_not_skipped(tmp_path, no_leaks):
    path = write_test_config("canopen", tmp_path)
    path.write_text(path.read_text().replace("sdo_timeout_s = 0.5", "sdo_timeout_s = 0.5\nskip_homing = false"))
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


def _unopened_canopen_transport():
    from rig.transports.canopen_link import CanOpenTransport

    return CanOpenTransport("virtual", "unused", encoder=EncoderResolution(bits=12, signed=True),
                            sample_period_s=1e-3)


def test_tpdos_are_filed_under_the_sync_echo_before_their_bus_timestamp():
    transport = _unopened_canopen_transport()
    transport._unechoed.extend([7, 8, 9])
    for bus_time in (10.000, 10.001, 10.002):  # the interface hands back our SYNCs 7, 8, 9
        transport._on_sync_echo(0x80, b"", bus_time)
    # the host read the answers to SYNC 7 only after SYNC 9 was on the bus: the bus time files them
    transport._file("drive", (0x0637, 100), 10.0003)
    transport._file("encoder", -1, 10.0004)
    sample = transport._ready.popleft()
    assert (sample.seq, sample.encoder_counts, sample.statusword) == (7, -1, 0x0637)
    assert transport._sync_before(9.999) is None  # before any SYNC of ours: not an answer


def test_a_tpdo_ahead_of_its_sync_echo_waits_for_the_echo():
    """The device may answer SYNC 5 before the interface gives the master the echo of SYNC 5 (on the
    virtual bus the device's queue gets the SYNC first): the answer must not be filed under SYNC 4."""
    transport = _unopened_canopen_transport()
    transport._unechoed.extend([4, 5])
    transport._on_sync_echo(0x80, b"", 20.000)  # SYNC 4
    transport._file("drive", (0x0637, 100), 20.0013)  # answers SYNC 5, whose echo is not back yet
    transport._file("encoder", 3, 20.0014)
    assert not transport._ready
    transport._on_sync_echo(0x80, b"", 20.0010)  # SYNC 5
    sample = transport._ready.popleft()
    assert sample.seq == 5 and sample.encoder_counts == 3
    assert not transport._ready and not transport._held


def test_an_interface_that_does_not_echo_our_frames_is_refused_at_start_up(tmp_path, monkeypatch, no_leaks):
    import canopen

    from rig.protocols.errors import TransportError

    connect = canopen.Network.connect

    def connect_without_echo(self, *args, **kwargs):
        kwargs["receive_own_messages"] = False
        return connect(self, *args, **kwargs)

    monkeypatch.setattr(canopen.Network, "connect", connect_without_echo)
    monkeypatch.setattr("rig.transports.canopen_link.SYNC_ECHO_TIMEOUT_S", 0.05)
    config = load_rig_config(write_test_config("canopen", tmp_path))
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, gearbox, stack)
        transport = stack.enter_context(open_transport(url, **config.transport_options()))
        with pytest.raises(TransportError, match="did not echo a transmitted SYNC.*receive_own_messages"):
            transport.open()
        assert rig.state is not DriveState.OPERATION_ENABLED  # refused before the drive was enabled
