"""``rig import TRACE``: the trace of ``rig run --can-trace`` gives back the run's own log
sample for sample in every trace format, raw CAN and CANopen (HELD samples too), a missing frame is a LOST sample, and damaged or foreign traces get
an error naming the frame."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import can
import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig import exit_codes
from rig.cli import main
from rig.log_file import read_log
from rig.protocols.errors import LogFileError
from rig.rig_config import load_rig_config
from rig.trace_import import import_trace

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "transports"))  # the clocked bus

from live_rig import CONFIGS, RATE_HZ, sim_rig_config  # noqa: E402


def _run(directory: Path, trace: Path, seconds: float = 0.1, kind: str = "can", *options: str,
         mode: str | None = None) -> Path:
    log = directory / "run.csv"
    config = sim_rig_config(directory, kind, mode, bus="import")
    assert main(["run", str(config), "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(log), "--duration", repr(seconds), "--can-trace", str(trace), "--json", *options]) == 0
    return log


def _assert_same_samples(run_log: Path, imported_log: Path, ignore_late: bool = True) -> None:
    run, imported = read_log(run_log), read_log(imported_log)
    np.testing.assert_array_equal(imported.time_s, run.time_s)
    np.testing.assert_array_equal(imported.command_rad, run.command_rad)
    np.testing.assert_array_equal(imported.angle_rad, run.angle_rad)
    np.testing.assert_array_equal(imported.encoder_counts, run.encoder_counts)
    # LATE is the host's judgement of its own monotonic clock; the import judges it from the trace's stamps
    mask = ~np.uint8(SampleFlag.LATE) if ignore_late else np.uint8(0xFF)
    np.testing.assert_array_equal(imported.flags & mask, run.flags & mask)
    assert imported.metadata.sample_period_s == run.metadata.sample_period_s
    assert imported.metadata.source == run.metadata.source and imported.metadata.encoder_bits == 12
    # the acquisition start from the trace's wall-clock stamps where it has them (BLF, candump), the date of the
    # run; none from a trace whose stamps count from its own start
    stamped = imported.metadata.acquisition_start
    if stamped is not None:
        assert abs((stamped - run.metadata.acquisition_start).total_seconds()) < 1.0


@pytest.mark.parametrize("kind, suffix", [("can", ".blf"), ("can", ".asc"), ("can", ".log"), ("can", ".trc"),
                                          ("canopen", ".blf"), ("canopen", ".asc")])
def test_the_trace_of_a_run_imports_as_the_runs_log(kind, suffix, tmp_path, capsys):
    trace = tmp_path / f"run{suffix}"
    log = _run(tmp_path, trace, 0.1, kind)
    capsys.readouterr()
    imported = tmp_path / "imported.csv"
    assert main(["import", str(trace), "--config", str(tmp_path / f"sim_{kind}.toml"), "--out", str(imported),
                 "--json"]) == exit_codes.SUCCESS
    result = json.loads(capsys.readouterr().out)
    assert result["samples"] == 20 and result["frame_errors"] == 0
    if suffix in (".blf", ".log"):
        assert read_log(imported).metadata.acquisition_start is not None
    # CANopen: the device's SYNC spacing decides LATE, and the trace has the SYNCs: every flag is compared
    _assert_same_samples(log, imported, ignore_late=kind == "can")


@pytest.mark.parametrize("mode", ["ip_buffer", "csp"])
def test_a_canopen_trace_with_held_samples_imports_as_the_runs_log(mode, tmp_path):
    """A host stall longer than the lead: the drive held earlier targets (CSP) or ran out of records
    (interpolated position), and the trace shows which. On the simulated clock (:mod:`clocked_canopen`), so
    the stall holds exactly the instants beyond the lead whatever the machine's load: 30.5 periods of stall
    at 200 Hz with the 20-period lead of 100 ms hold 11."""
    from rig.runner import run_experiment
    from rig.transports import parse_transport_url
    from rig.transports.canopen_link import CanOpenTransport
    from sim_backend.canopen_nodes import SimulatedCanOpenRig
    from sim_backend.plant_config import load_plant_config

    from clocked_canopen import ClockedCanBus
    from clocked_line import SimulatedClock
    from sim_rigs import ListSink

    config = load_rig_config(sim_rig_config(tmp_path, "canopen", mode, bus="import"))
    trace, stall_s, period_s = tmp_path / "run.blf", 0.1525, 1 / RATE_HZ
    clock = SimulatedClock(100.0)
    bus = ClockedCanBus(clock)
    rig = SimulatedCanOpenRig(load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed),
                              channel="clocked", clock=clock)
    _, where = parse_transport_url(config.url)
    transport = CanOpenTransport(**where, **config.transport_options(), clock=clock, trace_path=str(trace))
    bus.master(transport)
    bus.devices(rig)
    stalled, sink = [], ListSink()

    def stall(done: int, _held: int) -> None:
        if done >= 10 and not stalled:
            stalled.append(transport.device_sample)
            bus.stall(stall_s)

    try:
        command = 0.5 * np.sin(2 * np.pi * np.arange(120) / 40)
        summary = run_experiment(transport, command, sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s, clock=clock, progress=stall)
    finally:
        transport.close()
        rig.close()
    flags = np.array([row[4] for row in sink.rows])
    (heard,) = stalled  # the runner had queued up to this instant's predecessor + the lead
    lead = transport.lead_samples
    # the instants of the stall, then interpolated position's two hold records, or CSP's ramp back to the plan
    in_stall = list(range(heard + lead, heard + int(stall_s / period_s) + 1))
    held = np.flatnonzero(flags & SampleFlag.HELD).tolist()
    assert lead == 20 and len(in_stall) == 11 and held[:11] == in_stall and summary.held == len(held)
    assert held == list(range(held[0], held[-1] + 1)) and len(held) == (13 if mode == "ip_buffer" else 11)
    limited = np.flatnonzero(flags & SampleFlag.LIMITED).tolist()  # CSP's ramp back to the plan
    assert (limited[0] == held[-1] + 1 and limited == list(range(limited[0], limited[-1] + 1))) if mode == "csp" \
        else not limited
    record = import_trace(trace, config)
    np.testing.assert_allclose(record.time_s, [row[0] for row in sink.rows], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(record.command_rad, [row[1] for row in sink.rows])
    np.testing.assert_array_equal(record.angle_rad, [row[2] for row in sink.rows])
    np.testing.assert_array_equal(record.encoder_counts, [row[3] for row in sink.rows])
    # every flag, LATE too (the trace has the SYNCs), but LIMITED on CSP's ramp back to the plan after the
    # stall: the trace holds the targets the drive took, not the plan they were limited from
    ramp = (flags & SampleFlag.LIMITED) != 0
    np.testing.assert_array_equal(record.flags[~ramp], flags[~ramp])
    np.testing.assert_array_equal(record.flags[ramp], flags[ramp] & ~np.int64(SampleFlag.LIMITED))


@pytest.mark.parametrize("seconds, stall_ms", [(0.8, 400), (2.4, 1700)], ids=["hold", "hold-past-254-ticks"])
def test_a_raw_can_v3_trace_with_held_samples_imports_as_the_runs_log(seconds, stall_ms, tmp_path, capsys):
    """RIG_DRIVE_TICK's applied_age names the setpoint in force (DBC); past 254 ticks (1.27 s at 200 Hz) it is
    255 and the import, as the host, takes the target of the tick before."""
    trace = tmp_path / "run.blf"
    log = _run(tmp_path, trace, seconds, "can", "--sim-faults", f"stall={stall_ms}@10")  # lead 250 ms: 50 ticks
    held = json.loads(capsys.readouterr().out)["held"]
    assert held > (254 if stall_ms > 1600 else 0)
    assert any(frame.arbitration_id == 0x193 for frame in can.BLFReader(str(trace)))  # v3: RIG_DRIVE_TICK
    record = import_trace(trace, load_rig_config(tmp_path / "sim_can.toml"))
    imported = tmp_path / "imported.csv"
    from rig.log_file import write_log

    write_log(imported, record)
    assert record.count_flag(SampleFlag.HELD) == held
    _assert_same_samples(log, imported)


def test_a_missing_feedback_frame_is_a_lost_sample(tmp_path):
    log = _run(tmp_path, tmp_path / "run.blf")
    frames = list(can.BLFReader(str(tmp_path / "run.blf")))
    dropped = next(index for index, frame in enumerate(frames)
                   if frame.arbitration_id == 0x190 and frame.data[0] == 7)  # RIG_FEEDBACK of sample 7
    edited = tmp_path / "edited.asc"
    with can.Logger(str(edited)) as writer:
        for index, frame in enumerate(frames):
            if index != dropped:
                writer.on_message_received(frame)
    record = import_trace(edited, load_rig_config(tmp_path / "sim_can.toml"))
    run = read_log(log)
    assert record.flags[7] & SampleFlag.LOST and np.isnan(record.angle_rad[7])
    keep = np.arange(len(run)) != 7
    np.testing.assert_array_equal(record.angle_rad[keep], run.angle_rad[keep])


def test_damaged_and_foreign_traces_are_named(tmp_path, capsys):
    config = sim_rig_config(tmp_path, "can", bus="import")
    damaged = tmp_path / "damaged.blf"
    damaged.write_bytes(b"LOGG" + b"\x07" * 300)
    assert main(["import", str(damaged), "--config", str(config), "--out", str(tmp_path / "o.csv")]) == 2
    assert f"{damaged}: no CAN frame could be read from it" in capsys.readouterr().err
    foreign = tmp_path / "foreign.asc"
    with can.Logger(str(foreign)) as writer:
        for k in range(5):
            writer.on_message_received(can.Message(arbitration_id=0x123, data=bytes([k]), timestamp=k * 0.01,
                                                   is_extended_id=False))
    with pytest.raises(LogFileError, match=r"no RIG_SETPOINT frame \(0x110\) in 5 frames"):
        import_trace(foreign, load_rig_config(config))
    skipping = tmp_path / "skipping.asc"
    with can.Logger(str(skipping)) as writer:
        for index, seq in enumerate((0, 1, 3)):
            writer.on_message_received(can.Message(arbitration_id=0x110, data=bytes([seq, 0, 0, 0, 0, 0]),
                                                   timestamp=index * 0.005, is_extended_id=False))
    with pytest.raises(LogFileError, match=r"frame 2 at .* RIG_SETPOINT seq 3 does not follow seq 1"):
        import_trace(skipping, load_rig_config(config))


def test_a_serial_rig_is_refused_and_the_output_is_checked_first(tmp_path, capsys):
    trace = tmp_path / "t.asc"
    with can.Logger(str(trace)) as writer:
        writer.on_message_received(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
    assert main(["import", str(trace), "--config", str(CONFIGS / "sim_serial.toml"), "--out",
                 str(tmp_path / "o.csv")]) == exit_codes.BAD_INPUT
    assert "the serial transport has no CAN frames" in capsys.readouterr().err
    assert main(["import", str(trace), "--config", str(sim_rig_config(tmp_path, "canopen", bus="import")), "--out",
                 str(tmp_path / "o.csv")]) == exit_codes.BAD_INPUT
    assert "no node 1 RPDO1 (COB-ID 0x201)" in capsys.readouterr().err
    assert main(["import", str(trace), "--config", str(sim_rig_config(tmp_path, "can", bus="import")), "--out",
                 str(tmp_path / "missing" / "o.csv")]) == exit_codes.WRITE_FAILED


def test_a_canopen_trace_that_starts_after_the_start_up_needs_the_mode_in_the_config(tmp_path, capsys):
    trace = tmp_path / "run.blf"
    log = _run(tmp_path, trace, 0.1, "canopen")
    capsys.readouterr()
    frames = list(can.BLFReader(str(trace)))
    first_rpdo = next(index for index, frame in enumerate(frames) if frame.arbitration_id == 0x201)
    late = tmp_path / "late.blf"
    with can.Logger(str(late)) as writer:  # the last SYNCs before streaming, none of the start-up's SDOs
        for frame in frames[first_rpdo - 20:]:
            if frame.arbitration_id != 0x601:
                writer.on_message_received(frame)
    with pytest.raises(LogFileError, match=r"no SDO write of 0x6060 before it .* set mode = \"ip_buffer\" or "
                                           r"\"csp\" in the config's \[transport\]"):
        import_trace(late, load_rig_config(tmp_path / "sim_canopen.toml"))
    told = sim_rig_config(tmp_path, "canopen", "ip_buffer", bus="import")
    record = import_trace(late, load_rig_config(told))
    run = read_log(log)
    np.testing.assert_array_equal(record.command_rad, run.command_rad)
    np.testing.assert_array_equal(record.angle_rad, run.angle_rad)


def _ip_start_frames(answer_after_sync: bool, first_bit_12: int) -> list:
    """An interpolated-position start on drive node 1, as (time stamp, index, frame): two records, SYNC 1,
    the SDO write of controlword 0x001F (bit 4, enable ip mode) and the drive's answer (after SYNC 2 when
    ``answer_after_sync``), then SYNCs 2-4 each followed by the drive's statusword, bit 12 (ip mode active)
    set from SYNC ``first_bit_12`` on."""
    def frame(cob: int, data: bytes) -> can.Message:
        return can.Message(arbitration_id=cob, data=data, is_extended_id=False)

    sync, record = frame(0x080, b""), frame(0x201, (0).to_bytes(4, "little"))
    request = frame(0x601, bytes((0x2B, 0x40, 0x60, 0x00, 0x1F, 0x00, 0, 0)))
    answer = frame(0x581, bytes((0x60, 0x40, 0x60, 0x00, 0, 0, 0, 0)))
    status = [frame(0x181, (0x0637 | (0x1000 if n >= first_bit_12 else 0)).to_bytes(2, "little")
                    + (0).to_bytes(4, "little")) for n in range(5)]
    order = [record, record, sync, request] + ([sync, answer] if answer_after_sync else [answer, sync])
    order += [status[2], sync, status[3], sync, status[4]]
    return [(0.001 * index, index, message) for index, message in enumerate(order)]


@pytest.mark.parametrize(("answer_after_sync", "first_bit_12", "origin"),
                         [(False, 2, 2), (False, 3, 2), (True, 3, 3), (True, 4, 4)])
def test_interpolated_position_starts_where_the_bus_order_says(answer_after_sync, first_bit_12, origin):
    """Sample 0 of an imported interpolated-position trace, by the transport's rule: the drive answered the
    SDO write of bit 4 before the next SYNC (2), so it took its first record at that SYNC, whatever a
    statusword sent late says; when the answer came after a SYNC, the first statusword with bit 12 decides."""
    from rig.trace_import import _ip_origin, _our_mapping

    frames = _ip_start_frames(answer_after_sync, first_bit_12)
    status_pdo = _our_mapping(1, 2).pdos[0x181]
    assert _ip_origin(frames, 0x080, 0x201, 1, latency=0, status_pdo=status_pdo) == origin


def test_the_drive_torque_in_a_canopen_trace_imports_as_the_runs_torque_column(tmp_path, capsys):
    # the simulated servo's drive maps its torque actual value 0x6077 into TPDO1: the start-up's SDO writes in the
    # trace say so, and the import decodes it as the run did
    config = Path(__file__).resolve().parents[2] / "configs" / "sim_pendulum_canopen.toml"
    trace, log, imported = tmp_path / "run.blf", tmp_path / "run.csv", tmp_path / "imported.csv"
    command = tmp_path / "swing.csv"  # 0.6 s of a swing from rest at 100 Hz
    command.write_text("command_rad\n" + "".join(f"{0.5 * np.sin(np.pi * k / 30):.12f}\n" for k in range(60)))
    assert main(["run", str(config), "--experiment", str(command), "--out", str(log), "--can-trace", str(trace),
                 "--json"]) == exit_codes.SUCCESS
    assert main(["import", str(trace), "--config", str(config), "--out", str(imported), "--json"]) == exit_codes.SUCCESS
    capsys.readouterr()
    run, again = read_log(log), read_log(imported)
    assert run.drive_torque is not None and np.isfinite(run.drive_torque).all()
    np.testing.assert_array_equal(again.drive_torque, run.drive_torque)
    assert again.metadata.extra["drive_torque_unit"] == run.metadata.extra["drive_torque_unit"]
    _assert_same_samples(log, imported, ignore_late=False)
