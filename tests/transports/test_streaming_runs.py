"""Runs without a length limit, on the simulated clock (no pty, no thread, no sleep: nothing here depends on how
busy the machine is): the real serial v2 host transport and runner against the simulated rig's serial device
at 1 kHz (:mod:`clocked_line`). The command is produced and checked a chunk at a time as it is sent
(:class:`rig.command_source.CommandSource`, :class:`rig.command_check.CheckedCommand`); every sample is in
the log, memory does not grow with the run, and a chunk beyond a limit later in the run stops the drive."""

from __future__ import annotations

import collections
import gc
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from identify.excitation_design import staircase_reference
from identify.experiment_record import SampleFlag
from rig.command_source import CHUNK_SAMPLES, ArrayCommand, CsvCommandFile, FilteredRepeatCommand
from rig.log_file import LogWriter, read_log
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import LogFileError
from rig.runner import run_experiment
from rig.transports.base import CommandLimits, CommandRefused
from rig.transports.serial_link import SerialTransport

from clocked_line import SimulatedClock, simulated_device_line

ROOT = Path(__file__).resolve().parents[2]
PLANT = ROOT / "configs" / "plants" / "precision_gearbox.toml"  # 1 kHz
PERIOD_S = 0.001
DRIVE = DriveScaling(1 << 17)


def _clocked_rig(limits: CommandLimits | None = None, **device_options):
    """(transport, device, clock) on one simulated clock."""
    from sim_backend.plant_config import load_plant_config
    from sim_backend.serial_device import SimulatedSerialDevice

    clock = SimulatedClock(1000.0)
    device = SimulatedSerialDevice(load_plant_config(PLANT).gearbox(seed=3), clock=clock, buffer_capacity=64,
                                   **device_options)
    transport = SerialTransport("simulated", encoder=EncoderResolution(bits=12, signed=True),
                                sample_period_s=PERIOD_S, drive=DRIVE, limits=limits,
                                timing=BringUpTiming(poll_interval_s=0.0), reply_timeout_s=0.3, lead_s=0.05,
                                name="clocked", clock=clock)
    line = simulated_device_line(transport, clock, device)
    line.to_host = collections.deque(maxlen=64)  # the test line's record of every message: only the last
    return transport, device, clock


@pytest.fixture
def clocked_rig():
    """``make(limits=None, **device_options)`` -> (transport, device, clock) on one simulated clock."""
    devices = []

    def make(limits: CommandLimits | None = None, **device_options):
        transport, device, clock = _clocked_rig(limits, **device_options)
        devices.append(device)
        return transport, device, clock

    yield make
    for device in devices:
        device.close()


def _log(path: Path) -> LogWriter:
    return LogWriter(path, {"sample_period_s": PERIOD_S, "encoder_bits": 12, "source": "clocked"}, flush_every=1000)


class CountingSink:
    def __init__(self) -> None:
        self.rows = self.flagged = 0

    def append(self, time_s, command_rad, angle_rad, encoder_counts=None, flags=0) -> None:
        self.rows += 1
        self.flagged += bool(flags)

    def close(self) -> None:
        pass


def test_a_long_run_accounts_for_every_sample_across_the_wrap_of_the_wire_sequence(clocked_rig, tmp_path):
    """67 000 samples (67 s at 1 kHz; the wire's 16-bit sample number wraps at 65 536) of a staircase repeated
    and filtered as it is sent: one log row per sample at k T, the command as generated, LOST exactly where
    the device kept its answer, no other flag."""
    samples = 67_000
    silent = {1_000, 40_000, 65_535}  # (the device compares 16 bits: 1 000 is silent again at 66 536)
    transport, device, _ = clocked_rig(silent_seqs=silent)
    command = FilteredRepeatCommand(staircase_reference([0.05, 0.1, 0.2], 700), 0.95, 1, samples)
    summary = run_experiment(transport, command, _log(tmp_path / "long.csv"), feedback_timeout_s=0.5,
                             clock=transport.clock)
    record = read_log(tmp_path / "long.csv")
    assert summary.samples == record.time_s.size == samples
    np.testing.assert_allclose(record.time_s, np.arange(samples) * PERIOD_S, rtol=0, atol=1e-9)
    planned = command.to_array()
    np.testing.assert_array_equal(record.command_rad, [DRIVE.quantize_rad(value) for value in planned.tolist()])
    lost = {seq for seq in range(samples) if seq & 0xFFFF in silent}
    assert lost == {1_000, 40_000, 65_535, 66_536}
    assert set(np.flatnonzero(record.flags).tolist()) == lost
    assert all(record.flags[seq] == SampleFlag.LOST for seq in lost)
    assert summary.lost == len(lost) and summary.held == summary.late == summary.duplicate == 0
    assert record.metadata.extra["summary"]["stop"].endswith("ends SWITCH ON DISABLED")


def _driver_memory(samples: int, chunk_samples: int) -> int:
    """Bytes held by the driver's code (allocated in files under rig/ and alive) near the end of a run of
    ``samples`` samples, taken at the same place in the command's last chunk whatever the run's length."""
    transport, device, _ = _clocked_rig()
    held = []

    def progress(done: int, _held: int) -> None:
        if not held and done >= samples - 100 and tracemalloc.is_tracing():
            snapshot = tracemalloc.take_snapshot().filter_traces([tracemalloc.Filter(True, str(ROOT / "rig" / "*"))])
            held.append(sum(stat.size for stat in snapshot.statistics("filename")))

    command = ArrayCommand(0.1 * np.sin(2 * np.pi * np.arange(samples) / 1000), chunk_samples=chunk_samples)
    try:
        summary = run_experiment(transport, command, CountingSink(), feedback_timeout_s=0.5, clock=transport.clock,
                                 progress=progress)
    finally:
        device.close()
    assert summary.samples == samples
    return held[0] if held else 0


def test_the_drivers_memory_does_not_grow_with_the_run():
    """4 times the samples, the same memory: the runner holds a few chunks of the command and the rows not
    yet final, nothing per sample (it used to hold the whole command as a list, 32 bytes a sample, and an
    array of the send lateness)."""
    chunk = 512
    _driver_memory(300, chunk)  # (imports and caches of a first run, untraced)
    tracemalloc.start()
    try:
        gc.collect()  # (the rigs of the runs before: a run freezes the heap it starts with)
        short = _driver_memory(2 * chunk, chunk)
        gc.collect()
        long = _driver_memory(8 * chunk, chunk)
    finally:
        tracemalloc.stop()
    assert 0 < short and abs(long - short) < 4 * 1024, (short, long)  # (6 * 512 floats more: 98 kB)


def test_a_chunk_beyond_a_limit_later_in_the_run_stops_the_drive_before_any_of_its_samples(clocked_rig, tmp_path):
    """The drive is enabled on a first chunk within the limits; the chunk of sample 12 411 (the fourth) puts
    it outside them. It is found while the run goes, ahead of time: the run ends with the controlled stop,
    no setpoint of that chunk was sent, the error names the sample and the limit, and the log holds every
    sample up to the stop."""
    bad = 3 * CHUNK_SAMPLES + 123
    command = 0.2 * np.sin(2 * np.pi * np.arange(5 * CHUNK_SAMPLES) / 500)
    command[bad] = 0.6
    transport, device, clock = clocked_rig(limits=CommandLimits(position_min_rad=-0.5, position_max_rad=0.5))
    with pytest.raises(CommandRefused, match=rf"setpoint {bad}: position 0.599978 rad is outside the limits "
                                             r"\[-0.5, 0.5\] rad; .* stopped before sending any sample of this chunk"):
        run_experiment(transport, command, _log(tmp_path / "stopped.csv"), feedback_timeout_s=0.5, clock=clock)
    # quick stop, then disable, confirmed
    assert device.controlwords[-2:] == [0x0002, 0x0000] and transport.stop_report.confirmed
    assert transport.stop_report.final_state.name == "SWITCH_ON_DISABLED"
    applied = np.array([DRIVE.rad_from_counts(counts) for counts in device.record().applied_targets.tolist()])
    assert CHUNK_SAMPLES < applied.size < 3 * CHUNK_SAMPLES  # stopped while sending the chunks before it
    assert np.all(np.abs(applied) <= 0.2 + 1e-4)
    record = read_log(tmp_path / "stopped.csv")
    rows = record.time_s.size
    assert CHUNK_SAMPLES < rows <= applied.size  # every instant the device passed before the stop
    np.testing.assert_allclose(record.time_s, np.arange(rows) * PERIOD_S, rtol=0, atol=1e-9)
    assert not np.any(record.flags[:rows - 100])  # answered; the last instants before the stop may be LOST
    assert record.metadata.extra["summary"]["stop"].endswith("ends SWITCH ON DISABLED")


def test_the_first_chunk_is_checked_before_enabling(clocked_rig, tmp_path):
    """A sample beyond a limit in the first chunk is refused with the drive never enabled, as always."""
    command = np.zeros(3 * CHUNK_SAMPLES)
    command[CHUNK_SAMPLES - 1] = 0.6
    transport, device, clock = clocked_rig(limits=CommandLimits(position_max_rad=0.5))
    with pytest.raises(CommandRefused, match=rf"^setpoint {CHUNK_SAMPLES - 1}: position 0.599978 rad is outside"):
        run_experiment(transport, command, _log(tmp_path / "refused.csv"), feedback_timeout_s=0.5, clock=clock)
    assert 0x000F not in device.controlwords and device.record().applied_targets.size == 0
    with pytest.raises(LogFileError, match="the log has a header but no samples"):
        read_log(tmp_path / "refused.csv")


def test_a_command_file_is_read_as_it_is_sent_and_a_bad_row_later_stops_the_run(clocked_rig, tmp_path):
    """A CSV command file streamed from disk: a row that is no number, in the third chunk, ends the run with
    the controlled stop once the run reads that far ahead, naming the line; the log keeps what came before."""
    values = 0.1 * np.sin(np.arange(3 * CHUNK_SAMPLES) / 200)
    lines = [f"{value!r}" for value in values.tolist()]
    lines[2 * CHUNK_SAMPLES + 5] = "oops"
    path = tmp_path / "command.csv"
    path.write_text("# a command\ncommand_rad\n" + "\n".join(lines) + "\n")
    source = CsvCommandFile(path, PERIOD_S)
    assert source.num_samples == 3 * CHUNK_SAMPLES
    np.testing.assert_array_equal(source.head(100), values[:100])
    transport, device, clock = clocked_rig()
    with pytest.raises(LogFileError, match=rf"line {2 * CHUNK_SAMPLES + 8}, column command_rad: 'oops' is not a "):
        run_experiment(transport, source, _log(tmp_path / "run.csv"), feedback_timeout_s=0.5, clock=clock)
    assert device.controlwords[-2:] == [0x0002, 0x0000] and transport.stop_report.confirmed
    record = read_log(tmp_path / "run.csv")
    assert 0 < record.time_s.size < 2 * CHUNK_SAMPLES
    np.testing.assert_array_equal(record.command_rad[:100], [DRIVE.quantize_rad(v) for v in values[:100].tolist()])


def test_sources_yield_the_same_command_every_time_and_in_bounded_chunks():
    command = FilteredRepeatCommand(staircase_reference([0.1, 0.3], 1500), 0.9, 2, 5 * CHUNK_SAMPLES + 17)
    first, again = list(command.chunks()), list(command.chunks())
    assert [chunk.size for chunk in first] == [CHUNK_SAMPLES] * 5 + [17]
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert np.array_equal(ArrayCommand(np.arange(10.0), chunk_samples=4).to_array(), np.arange(10.0))
    assert [chunk.size for chunk in ArrayCommand(np.arange(10.0), chunk_samples=4).chunks()] == [4, 4, 2]
