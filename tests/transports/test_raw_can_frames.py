"""The raw-CAN frame layout (configs/raw_can.dbc) as scripted exchanges, and raw-frame traces."""

from __future__ import annotations

import can
import pytest

from rig.cli import main
from rig.protocols.raw_can_frames import RawCanCodec
from sim_backend.plant_config import load_plant_config
from sim_backend.raw_can_device import SimulatedRawCanDevice
from sim_rigs import CONFIGS, no_leaks, write_test_plant, write_test_config  # noqa: F401  (no_leaks is a fixture)

CODEC = RawCanCodec()


def test_frames_have_the_documented_identifiers_and_little_endian_layout():
    setpoint = CODEC.encode("RIG_SETPOINT", seq=0x10001, target_counts=-5)  # seq is sent modulo 2**16
    assert (setpoint.arbitration_id, bytes(setpoint.data)) == (0x110, bytes.fromhex("0100fbffffff"))
    feedback = can.Message(arbitration_id=0x190, data=bytes.fromhex("07002702ff0f0000"), is_extended_id=False)
    assert CODEC.decode(feedback) == ("RIG_FEEDBACK", {"seq": 7, "statusword": 0x0227, "encoder_counts": 4095})
    assert CODEC.decode(can.Message(arbitration_id=0x7FF, data=b"\x01")) is None  # other traffic: not ours
    with pytest.raises(ValueError, match=r"RIG_FEEDBACK \(0x190\) has 3 data bytes, expected 8"):
        CODEC.decode(can.Message(arbitration_id=0x190, data=b"\x01\x02\x03", is_extended_id=False))


def test_scripted_exchange_with_the_simulated_responder(tmp_path):
    """Bring-up, one setpoint, a fault: (TX, frame) / (RX, frame) pairs, no threads."""
    gearbox = load_plant_config(write_test_plant(tmp_path)).gearbox(seed=2)
    device = SimulatedRawCanDevice(gearbox, channel="unused", fault_at_seq=1, fault_code=0x2310)
    answers: list[tuple[str, dict]] = []
    device._send = lambda name, **signals: answers.append((name, signals))  # capture instead of a bus

    def tx(name, **signals):
        answers.clear()
        device.on_message_received(CODEC.encode(name, **signals))
        return list(answers)

    assert tx("RIG_CONTROL", seq=1, controlword=0x06) == [("RIG_STATUS", {"seq": 1, "statusword": 0x0231, "actual_counts": 0})]
    assert tx("RIG_CONTROL", seq=2, controlword=0x07)[0][1]["statusword"] == 0x0233
    assert tx("RIG_SETPOINT", seq=0, target_counts=1000) == []  # not enabled yet: ignored, plant not stepped
    assert tx("RIG_CONTROL", seq=3, controlword=0x0F)[0][1]["statusword"] == 0x0237
    expected = load_plant_config(write_test_plant(tmp_path)).gearbox(seed=2).step(1000 * 2 * 3.141592653589793 / 131072)
    assert tx("RIG_SETPOINT", seq=0, target_counts=1000) == [
        ("RIG_FEEDBACK", {"seq": 0, "statusword": 0x1637, "encoder_counts": expected.encoder_counts & 0xFFFFFFFF}),
        ("RIG_DRIVE_FEEDBACK", {"seq": 0, "actual_counts": 1000})]
    assert tx("RIG_SETPOINT", seq=1, target_counts=2000) == [("RIG_FAULT", {"error_code": 0x2310})]
    assert tx("RIG_STATUS_REQUEST", seq=4)[0][1]["statusword"] & 0x4F == 0x08  # FAULT
    assert device.setpoints == 1


@pytest.mark.parametrize("kind", ["can", "canopen"])
def test_can_trace_records_every_setpoint_frame(kind, tmp_path, capsys, no_leaks):
    trace = tmp_path / "run.blf"
    code = main(["run", str(write_test_config(kind, tmp_path)), "--experiment",
                 str(CONFIGS / "experiments" / "prbs.toml"), "--out", str(tmp_path / "run.csv"), "--duration", "0.1",
                 "--can-trace", str(trace), "--json"])
    assert code == 0
    frames = list(can.BLFReader(str(trace)))
    setpoint_id = 0x110 if kind == "can" else 0x201  # RIG_SETPOINT, or the drive's RPDO1
    assert sum(frame.arbitration_id == setpoint_id for frame in frames) == 20
    answers = sum(frame.arbitration_id == (0x190 if kind == "can" else 0x182) for frame in frames)
    # CANopen: the devices answer every SYNC, which runs from configuration to the end of the stop; raw CAN v2:
    # the device answers each of its ticks, from RIG_START to the stop (at least one per setpoint)
    assert answers > 20 if kind == "canopen" else answers >= 20
    if kind == "can":
        assert sum(frame.arbitration_id == 0x193 for frame in frames) == answers  # v3: RIG_DRIVE_TICK with each
        assert not any(frame.arbitration_id in (0x191, 0x192) for frame in frames)  # no v2 tick frames


def test_sqlite_traces_and_serial_traces_are_refused(tmp_path, capsys):
    args = ["--experiment", str(CONFIGS / "experiments" / "prbs.toml"), "--out", str(tmp_path / "run.csv")]
    assert main(["run", str(write_test_config("can", tmp_path)), *args, "--can-trace", str(tmp_path / "t.db")]) == 2
    assert "not .db: SqliteWriter drops frames" in capsys.readouterr().err
    assert main(["run", str(write_test_config("serial", tmp_path)), *args, "--can-trace", str(tmp_path / "t.blf")]) == 2
    assert "--can-trace: the serial transport has no CAN frames to trace" in capsys.readouterr().err


def test_scripted_v2_exchange_with_the_simulated_responder(tmp_path):
    """Protocol v2 (the DBC's RIG_HELLO ... RIG_TICK_APPLIED): handshake, setpoints buffered by tick, START, ticks
    applied or HELD with the target in force, a late setpoint dropped; no threads (ticks run when called)."""
    gearbox = load_plant_config(write_test_plant(tmp_path)).gearbox(seed=2)
    device = SimulatedRawCanDevice(gearbox, channel="unused", buffer_capacity=8)
    answers: list[tuple[str, dict]] = []
    device._send = lambda name, **signals: answers.append((name, signals))

    def tx(name, **signals):
        answers.clear()
        device.on_message_received(CODEC.encode(name, **signals))
        return list(answers)

    assert tx("RIG_HELLO", seq=1, version=2) == [
        ("RIG_DEVICE_INFO", {"seq": 1, "version": 2, "buffer_capacity": 8, "sample_period_ns": 5_000_000})]
    for seq, word in enumerate((0x06, 0x07, 0x0F), start=2):
        tx("RIG_CONTROL", seq=seq, controlword=word)
    assert tx("RIG_SETPOINT", seq=0, target_counts=1000) == [] and tx("RIG_SETPOINT", seq=1, target_counts=2000) == []
    answers.clear()
    device.tick()
    assert answers == [] and device.ticks == 0  # no tick before START
    assert tx("RIG_START", seq=5)[0][0] == "RIG_STATUS"
    answers.clear()
    device.tick(), device.tick(), device.tick()
    applied = [signals for name, signals in answers if name == "RIG_TICK_APPLIED"]
    assert applied == [{"seq": 0, "applied_counts": 1000, "tick_flags": 0, "buffer_level": 1},
                       {"seq": 1, "applied_counts": 2000, "tick_flags": 0, "buffer_level": 0},
                       {"seq": 2, "applied_counts": 2000, "tick_flags": 1, "buffer_level": 0}]  # underrun: HELD
    encoder = [signals["encoder_counts"] for name, signals in answers if name == "RIG_FEEDBACK"]
    expected = load_plant_config(write_test_plant(tmp_path)).gearbox(seed=2).simulate(
        [1000 * 2 * 3.141592653589793 / 131072] + [2000 * 2 * 3.141592653589793 / 131072] * 2)
    assert encoder == [int(value) & 0xFFFFFFFF for value in expected.encoder_counts]  # one plant step per tick
    assert tx("RIG_SETPOINT", seq=2, target_counts=3000) == [] and device.dropped_setpoints == 1  # too late
    tx("RIG_CONTROL", seq=6, controlword=0x02)  # quick stop: the session ends
    assert device.mode == 1 and device.buffer == {}


def test_scripted_v3_exchange_reports_the_target_in_force_by_its_age(tmp_path):
    """Protocol v3 (the DBC's RIG_DRIVE_TICK): two frames a tick; applied_age 0 for setpoint k applied, k - j
    while the setpoint of tick j is held, 255 before any setpoint of the session was applied."""
    gearbox = load_plant_config(write_test_plant(tmp_path)).gearbox(seed=2)
    device = SimulatedRawCanDevice(gearbox, channel="unused", buffer_capacity=8)
    answers: list[tuple[str, dict]] = []
    device._send = lambda name, **signals: answers.append((name, signals))

    def tx(name, **signals):
        answers.clear()
        device.on_message_received(CODEC.encode(name, **signals))
        return list(answers)

    assert tx("RIG_HELLO", seq=1, version=3)[0][1]["version"] == 3
    for seq, word in enumerate((0x06, 0x07, 0x0F), start=2):
        tx("RIG_CONTROL", seq=seq, controlword=word)
    tx("RIG_SETPOINT", seq=1, target_counts=2000), tx("RIG_SETPOINT", seq=2, target_counts=3000)
    tx("RIG_START", seq=5)
    answers.clear()
    for _ in range(5):
        device.tick()
    assert [name for name, _ in answers] == ["RIG_FEEDBACK", "RIG_DRIVE_TICK"] * 5
    assert [signals for name, signals in answers if name == "RIG_DRIVE_TICK"] == [
        {"seq": 0, "actual_counts": 0, "buffer_level": 2, "applied_age": 255},  # HELD before any setpoint
        {"seq": 1, "actual_counts": 2000, "buffer_level": 1, "applied_age": 0},
        {"seq": 2, "actual_counts": 3000, "buffer_level": 0, "applied_age": 0},
        {"seq": 3, "actual_counts": 3000, "buffer_level": 0, "applied_age": 1},  # HELD: setpoint 2 in force
        {"seq": 4, "actual_counts": 3000, "buffer_level": 0, "applied_age": 2}]
    assert device.held_ticks == 3


def test_a_v1_raw_can_device_is_driven_host_paced(tmp_path, no_leaks):
    from rig.runner import run_experiment
    from sim_rigs import ListSink, excitation, simulated

    sink = ListSink()
    with simulated("can", tmp_path, protocol_version=1) as (config, transport, _, device):
        summary = run_experiment(transport, excitation(20), sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s)
        assert transport.version == 1 and transport.lead_samples == 0 and device.setpoints == 20 and device.ticks == 0
    assert len(sink.rows) == 20 and summary.held == 0 and "protocol v1" in summary.warnings[0]


def test_protocol_v2_refuses_a_v1_raw_can_device_before_enabling_it(tmp_path, no_leaks):
    from rig.protocols.errors import TransportError
    from sim_rigs import simulated

    with simulated("can", tmp_path, protocol_version=1) as (_, transport, _, device):
        transport.protocol, transport.reply_timeout_s = "v2", 0.05
        with pytest.raises(TransportError, match=r"no RIG_DEVICE_INFO answer to RIG_HELLO: the device speaks only "
                                                 r"protocol v1"):
            transport.prepare()
        assert device.controlwords == [] and [name for name, _ in device.requests] == ["RIG_STATUS_REQUEST"]
