"""CANopen interpolated position mode with the drive's FIFO (mode = "ip_buffer", CiA 402 0x6060 = 7,
0x60C1, 0x60C4): setpoints go into the drive's buffer ahead of its SYNCs; a buffer that runs dry holds
the last record, and the log says so (HELD, the command really applied), sample for sample."""

from __future__ import annotations

import contextlib
import time

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.errors import ConfigError
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


def test_a_host_stall_longer_than_the_lead_empties_the_buffer_and_every_sample_says_so(tmp_path, no_leaks):
    """300 ms of host stall at the 200 Hz test rate: the lead (100 ms = 20 samples, within half the drive's
    64-record buffer) runs out, the drive holds its
    last record for the rest, the log files every instant with the record really applied."""
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
    assert held.size >= 300 * 200 // 1000 - 20 - 5 and summary.held == held.size
    assert held.size <= underruns


def test_ip_buffer_needs_the_buffer_objects_in_the_eds(tmp_path):
    from rig.transports.canopen_link import DEFAULT_DRIVE_EDS

    config = load_rig_config(write_test_config("canopen", tmp_path))
    eds = eds_without(DEFAULT_DRIVE_EDS, [0x60C4], tmp_path / "drive.eds")
    with pytest.raises(ConfigError, match=r"has no object 0x60C4; the master needs it for the interpolation buffer"):
        open_transport(config.url, **dict(config.transport_options(), drive_eds=str(eds), mode="ip_buffer"))
