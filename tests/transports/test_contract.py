"""One contract suite, run over every transport against its simulated device (after python-can's
back2back tests): bring-up, streaming, sample accounting, values equal to the offline simulation of the
same plant and excitation, controlled stop, clean shutdown without leaked threads."""

from __future__ import annotations

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.runner import run_experiment
from rig.transports import Setpoint
from sim_backend.plant_config import load_plant_config

from sim_rigs import ListSink, excitation, no_leaks, simulated  # noqa: F401  (no_leaks is a fixture)

TRANSPORTS = ["serial", "canopen", "can"]
NUM_SAMPLES = 120


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_bring_up_enables_the_drive_without_a_jump(kind, tmp_path, no_leaks):
    with simulated(kind, tmp_path) as (config, transport, gearbox, _):
        transport.open()
        assert transport.is_open and transport.initial_position_rad == 0.0
        sent = transport.send(Setpoint(0, 0.25))
        sample = transport.receive(timeout_s=1.0)
        assert sample.seq == 0
        assert sample.drive_position_rad == pytest.approx(0.25, abs=config.drive.rad_from_counts(1))
        assert sent.position_rad == config.drive.quantize_rad(0.25)
        transport.close()
        assert not transport.is_open


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_streamed_run_equals_the_offline_simulation(kind, tmp_path, no_leaks):
    command = excitation()
    sink = ListSink()
    with simulated(kind, tmp_path) as (config, transport, gearbox, _):
        summary = run_experiment(transport, command, sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s)
        plant_path = config.simulation.plant_path
        seed = config.simulation.seed
        period = config.sample_period_s
    assert sink.closed and summary.samples == len(sink.rows) == NUM_SAMPLES
    time_s, sent, angle, counts, flags = (np.array(column, dtype=object) for column in zip(*sink.rows))
    np.testing.assert_allclose(time_s.astype(float), np.arange(NUM_SAMPLES) * period)
    flags = flags.astype(int)
    held = (flags & SampleFlag.HELD) != 0  # device-clocked (CANopen, serial and raw CAN v2): a target that missed its instant
    # commands are the excitation quantised to drive counts (131072 per revolution: < 2.4e-5 rad); a HELD
    # sample logs the target really in force, the one before it
    np.testing.assert_allclose(sent[~held].astype(float), command[~held], atol=np.pi / 131072)
    for k in np.flatnonzero(held):
        assert sent[k] == sent[k - 1] or sent[k] in command[:k]
    lost = (flags & SampleFlag.LOST) != 0
    assert summary.lost == lost.sum() and summary.duplicate == 0 and summary.held == held.sum()
    assert set(np.unique(flags & ~int(SampleFlag.LATE | SampleFlag.HELD))) <= {0, int(SampleFlag.LOST)}
    assert (~lost).sum() > 0
    # the device stepped the plant once per sample instant: the same numbers as simulating the logged command
    expected = load_plant_config(plant_path).gearbox(seed=seed).simulate(sent.astype(float))
    np.testing.assert_array_equal(angle[~lost].astype(float), expected.measured_angle_rad[~lost])
    np.testing.assert_array_equal(counts[~lost].astype(int), expected.encoder_counts[~lost])
    assert np.all(np.isnan(angle[lost].astype(float)))


def _i32(node, index: int) -> int:
    return int.from_bytes(node.get_data(index, 0), "little", signed=True)


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_close_does_a_controlled_stop_and_is_idempotent(kind, tmp_path, no_leaks):
    with simulated(kind, tmp_path) as (config, transport, gearbox, drive):
        transport.open()
        transport.send(Setpoint(0, 0.0))
        assert transport.receive(timeout_s=1.0).seq == 0
        transport.close()
        transport.close()
        # bring-up (interpolated position: bit 4 enables the interpolation); quick stop, then disable voltage
        interpolation = [0x1F] if getattr(transport, "mode", None) == "ip_buffer" else []
        assert drive.controlwords == [0x06, 0x07, 0x0F, *interpolation, 0x02, 0x00]
        if kind == "canopen":  # the cyclic SYNC goes on until the stop: the drive held the one target
            assert drive.setpoints >= 1 and _i32(drive.drive, 0x607A) == 0
        else:  # serial, raw CAN v2: the device ticks on its own clock until the stop, holding the one target
            assert drive.setpoints >= 1 and drive.target_counts == 0 and drive.ticks == drive.setpoints


@pytest.mark.parametrize("kind", ["canopen", "can"])
def test_a_device_in_a_process_of_its_own_applied_every_command_the_log_says(kind, tmp_path, no_leaks):
    """The simulated devices in a process of their own (``sim_backend.device_process``: CAN on udp_multicast,
    the CANopen SYNC from the devices' clock): every sample is filed or flagged, and every logged command is the
    target the device applied at that sample (its record), the angle what its plant did with it. Only accounting
    is asserted: a busy machine may hold, delay or lose samples, never misfile one; the watchdogs are generous."""
    import contextlib

    from rig.rig_config import load_rig_config
    from rig.transports import open_transport
    from rig.transports.simulated import PATIENT_WITH_A_DEVICE_PROCESS, start_device_process
    from sim_rigs import write_test_config

    config = load_rig_config(write_test_config(kind, tmp_path))
    sink = ListSink()
    with contextlib.ExitStack() as stack:
        url, device = start_device_process(config, stack, produce_sync=kind == "canopen")
        sync = {"sync_producer": "external"} if kind == "canopen" else {}
        transport = open_transport(url, **{**config.transport_options(), **PATIENT_WITH_A_DEVICE_PROCESS[kind], **sync})
        stack.callback(transport.close)
        summary = run_experiment(transport, excitation(), sink, feedback_timeout_s=10.0,
                                 late_tolerance_s=config.late_tolerance_s)
    record = device.record
    assert summary.samples == len(sink.rows) == NUM_SAMPLES and len(record.applied_targets) >= NUM_SAMPLES
    time_s, sent, angle, _, flags = (np.array(column, dtype=object) for column in zip(*sink.rows))
    np.testing.assert_allclose(time_s.astype(float), np.arange(NUM_SAMPLES) * config.sample_period_s)
    flags = flags.astype(int)
    lost = (flags & SampleFlag.LOST) != 0
    held = (flags & SampleFlag.HELD) != 0
    assert summary.lost == lost.sum() and summary.held == held.sum()
    logged = np.array([config.drive.counts_from_rad(value) for value in sent.astype(float)])
    offset = record.row_offset(logged)  # (rows HELD before a late first target are no samples of the drive's)
    rows = np.flatnonzero(((flags & int(SampleFlag.unusable())) == 0) & (np.arange(NUM_SAMPLES) + offset >= 0))
    applied = np.array(record.applied_targets)
    np.testing.assert_array_equal(logged[rows], applied[rows + offset])
    expected = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed).simulate(
        np.array([config.drive.rad_from_counts(counts) for counts in applied]))
    np.testing.assert_array_equal(angle[rows].astype(float), expected.measured_angle_rad[rows + offset])
    assert record.controlwords[:3] == (0x06, 0x07, 0x0F) and record.controlwords[-2:] == (0x02, 0x00)
