"""CANopen interpolated position mode with the drive's FIFO (mode = "ip_buffer", CiA 402 0x6060 = 7,
0x60C1, 0x60C4): setpoints go into the drive's buffer ahead of its SYNCs; a buffer that runs dry holds
the last record, and the log says so (HELD, the command really applied), sample for sample."""

from __future__ import annotations

import contextlib
import time

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.errors import ConfigError, DeviceFault
from rig.rig_config import load_rig_config
from rig.runner import run_experiment
from rig.transports import open_transport
from sim_backend.eds_variants import eds_without
from sim_backend.plant_config import load_plant_config

from sim_rigs import ListSink, excitation, no_leaks, write_test_config  # noqa: F401  (no_leaks is a fixture)


@contextlib.contextmanager
def _ip_rig(tmp_path):
    from rig.transports.simulated import start_simulated_devices

    path = write_test_config("canopen", tmp_path)
    path.write_text(path.read_text().replace("sdo_timeout_s = 0.5", 'sdo_timeout_s = 0.5\nmode = "ip_buffer"'))
    config = load_rig_config(path)
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, gearbox, stack)
        transport = open_transport(url, **config.transport_options())
        stack.callback(transport.close)
        yield config, transport, rig


def _equals_the_offline_simulation_of_the_logged_command(config, sink) -> np.ndarray:
    _, command, angle, counts, flags = (np.array(column, dtype=object) for column in zip(*sink.rows))
    flags = flags.astype(int)
    answered = (flags & SampleFlag.LOST) == 0
    expected = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed).simulate(
        command.astype(float))
    np.testing.assert_array_equal(angle[answered].astype(float), expected.measured_angle_rad[answered])
    return flags


def test_the_drive_takes_one_record_per_sync_from_its_buffer(tmp_path, no_leaks):
    sink = ListSink()
    with _ip_rig(tmp_path) as (config, transport, rig):
        summary = run_experiment(transport, excitation(120), sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s)
        mode, capacity = int.from_bytes(rig.drive.get_data(0x6060, 0), "little"), transport._ip_capacity
        underruns, overruns = rig.ip_underruns, rig.ip_overruns
    assert mode == 7 and capacity == 64 and overruns == 0
    flags = _equals_the_offline_simulation_of_the_logged_command(config, sink)
    held = np.flatnonzero(flags & SampleFlag.HELD)
    assert len(sink.rows) == 120 and summary.lost == 0
    assert summary.held == held.size <= underruns  # every sample the buffer ran dry for is logged HELD


def test_a_host_stall_longer_than_the_lead_holds_the_drive_and_every_sample_says_so(tmp_path, no_leaks):
    """300 ms of host stall at the 200 Hz test rate: the lead (100 ms = 20 samples) runs out, hold records keep
    the drive at its last record for the rest (its buffer never runs dry: a drive that faults on an underflow
    rides the stall through), the log files every instant with the record really applied."""
    sink = ListSink()
    stalled = []

    def stall(done: int, late: int) -> None:
        if done >= 40 and not stalled:
            stalled.append(done)
            time.sleep(0.3)

    with _ip_rig(tmp_path) as (config, transport, rig):
        summary = run_experiment(transport, excitation(200), sink, feedback_timeout_s=1.0,
                                 late_tolerance_s=config.late_tolerance_s, progress=stall)
        underruns = rig.ip_underruns
    flags = _equals_the_offline_simulation_of_the_logged_command(config, sink)
    held = np.flatnonzero(flags & SampleFlag.HELD)
    assert summary.lost == 0 and len(sink.rows) == 200
    # how many instants the stall spans depends on how the loaded host runs the simulated SYNC thread, so
    # the count is not asserted, only that the log accounts for them and the buffer never ran dry
    assert held.size > 0 and underruns == 0 and summary.held == held.size


def test_ip_buffer_needs_the_buffer_objects_in_the_eds(tmp_path):
    from rig.transports.canopen_link import DEFAULT_DRIVE_EDS

    config = load_rig_config(write_test_config("canopen", tmp_path))
    eds = eds_without(DEFAULT_DRIVE_EDS, [0x60C4], tmp_path / "drive.eds")
    with pytest.raises(ConfigError, match=r"has no object 0x60C4; the master needs it for the interpolation buffer"):
        open_transport(config.url, **dict(config.transport_options(), drive_eds=str(eds), mode="ip_buffer"))


def _auto_rig(tmp_path, drive_eds=None, supported_modes=None, **behaviour):
    """A simulated rig driven with the default ``mode = "auto"``; ``supported_modes`` overrides the drive's
    0x6502, ``behaviour`` the drive's :class:`DriveBehaviour` (e.g. static PDOs)."""
    from rig.transports.simulated import start_simulated_devices
    from sim_backend.canopen_behaviour import DriveBehaviour

    config = load_rig_config(write_test_config("canopen", tmp_path))
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    stack = contextlib.ExitStack()
    url, rig = start_simulated_devices(config, gearbox, stack, drive_behaviour=DriveBehaviour(**behaviour))
    if supported_modes is not None:
        rig.drive.set_data(0x6502, 0, supported_modes.to_bytes(4, "little"))
    eds = rig.write_eds(tmp_path)[0] if drive_eds is None else drive_eds(tmp_path)
    transport = open_transport(url, **dict(config.transport_options(), drive_eds=str(eds)))
    stack.callback(transport.close)
    return stack, config, transport, rig


def _without_the_buffer(tmp_path):
    from rig.transports.canopen_link import DEFAULT_DRIVE_EDS

    return eds_without(DEFAULT_DRIVE_EDS, [0x60C1, 0x60C4], tmp_path / "drive_without_buffer.eds")


@pytest.mark.parametrize(("case", "options", "expected_mode"), [
    ("a drive with a 64-record buffer", {}, "ip_buffer"),
    ("an EDS without 0x60C1/0x60C4", {"drive_eds": _without_the_buffer}, "csp"),
    ("0x6502 without interpolated position (bit 6)", {"supported_modes": 0b1010_0000}, "csp"),
    ("a static RPDO1 that carries 0x607A", {"static_pdos": True}, "csp"),
])
def test_auto_mode_uses_the_drives_buffer_where_it_has_one_and_csp_elsewhere(case, options, expected_mode,
                                                                             tmp_path, no_leaks):
    sink = ListSink()
    stack, config, transport, rig = _auto_rig(tmp_path, **options)
    with stack:
        summary = run_experiment(transport, excitation(40), sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s)
        mode_of_operation = int.from_bytes(rig.drive.get_data(0x6060, 0), "little", signed=True)
    assert transport.mode == expected_mode
    assert mode_of_operation == {"ip_buffer": 7, "csp": 8}[expected_mode]
    assert summary.lost == 0 and len(sink.rows) == 40
    _equals_the_offline_simulation_of_the_logged_command(config, sink)


class _RecordingNetwork:
    """Stands in for canopen.Network in scripted exchanges: records the frames the master sends."""

    def __init__(self) -> None:
        self.sent: list[int] = []
        self.frames: list[tuple[int, bytes]] = []
        self.echoed = 0

    def send_message(self, can_id: int, data: bytes) -> None:
        self.sent.append(int.from_bytes(data, "little", signed=True))
        self.frames.append((can_id, bytes(data)))

    def next_echo(self) -> tuple[int, bytes]:
        """The COB-ID and data of the oldest frame sent whose echo the script has not yet given the master."""
        self.echoed += 1
        return self.frames[self.echoed - 1]


def test_the_receive_thread_keeps_the_drives_buffer_full_from_the_hosts_queue():
    """Scripted (no threads): 100 setpoints queued (a 100 ms lead at 1 kHz) into a 64-record buffer. The
    buffer is filled to its margin at once; each SYNC takes a record and the receive thread puts the next
    queued one on the bus, so the runner's thread may stall for its whole lead without an underrun."""
    from rig.protocols.encoder_counts import EncoderResolution
    from rig.transports import Setpoint
    from rig.transports.canopen_dictionary import PdoLayout
    from rig.transports.canopen_link import CanOpenTransport
    from rig.transports.interpolation_feed import IP_BUFFER_MARGIN_RECORDS, InterpolationFeed

    transport = CanOpenTransport("virtual", "unused", encoder=EncoderResolution(bits=12, signed=True),
                                 sample_period_s=1e-3, mode="ip_buffer", lead_s=0.1)
    transport.network = _RecordingNetwork()
    transport._rpdo = PdoLayout("RPDO1 of drive 1", 0x201, {0x60C1: (0, 4)}, 4)
    transport._feed = InterpolationFeed(64, transport.lead_samples, 0)
    assert transport.lead_samples == 100  # the lead is the host's: queue and buffer together
    for seq in range(100):
        transport._send(Setpoint(seq, transport.drive.rad_from_counts(seq)))
    full = 64 - IP_BUFFER_MARGIN_RECORDS
    assert transport.network.sent == list(range(full))  # in order, up to the margin, the rest queued
    for record in range(full):
        transport._on_rpdo_echo(*transport.network.next_echo(), 1.0)  # the bus carried them: in the drive's buffer now
    assert transport._feed.ready_to_start()  # the buffer holds the lead it can: ip mode may be enabled
    transport._origin, transport._feed.streaming = 1, True  # (bit 12 seen at the first SYNC after bit 4)
    for count in range(1, 39):  # the runner's thread queues nothing more: 38 SYNCs pass
        transport._on_sync_echo(0x80, b"", 1.0 + count * 1e-3)
        transport._on_rpdo_echo(*transport.network.next_echo(), 1.0 + count * 1e-3 + 2e-4)
    assert transport.network.sent == list(range(100))  # every queued record went in, one per SYNC
    assert not any(held for _, held, _ in transport._applied.values())
    assert [transport._applied[sample][0] for sample in range(38)] == list(range(38))


def test_a_drive_that_never_shows_ip_mode_active_stops_the_run_naming_bit_12_and_the_period_written():
    """Scripted: controlword bit 4 went out, SYNCs pass, the statusword never shows bit 12 (a drive that does
    not accept its 0x60C2, or refuses to interpolate for a reason of its own): the run stops saying so, not
    with advice about the TPDO latency."""
    from rig.protocols.encoder_counts import EncoderResolution
    from rig.transports.canopen_dictionary import PdoLayout
    from rig.transports.canopen_interpolation import IP_START_SYNCS
    from rig.transports.canopen_link import CanOpenTransport
    from rig.transports.interpolation_feed import InterpolationFeed

    transport = CanOpenTransport("virtual", "unused", encoder=EncoderResolution(bits=12, signed=True),
                                 sample_period_s=1e-3, mode="ip_buffer", lead_s=0.1)
    transport.network = _RecordingNetwork()
    transport._rpdo = PdoLayout("RPDO1 of drive 1", 0x201, {0x60C1: (0, 4)}, 4)
    transport._feed = InterpolationFeed(64, transport.lead_samples, 0)
    transport._period_written = "0x60C2 (interpolation time period) = 1 x 10^-3 s"
    transport._ip_enabled_at = 5
    transport._sync_count = 5 + IP_START_SYNCS
    transport._start_interpolation()  # still within the drive's allowance
    transport._sync_count += 1
    with pytest.raises(DeviceFault, match=r"does not interpolate: statusword bit 12 \(ip mode active\) still clear "
                                          r"50 SYNCs after controlword bit 4 .*0x60C2 \(interpolation time period\) = "
                                          r"1 x 10\^-3 s was written") as raised:
        transport._start_interpolation()
    assert "drive_tpdo_latency_cycles" not in str(raised.value)
