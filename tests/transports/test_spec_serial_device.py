"""The real driver (``rig run`` through ``rig.cli.main``, or :func:`rig.runner.run_experiment`) against a
device written only from ``docs/serial_protocol.md`` (:mod:`spec_serial_device`, which imports nothing of
ours), on a pty with the device ticking on its own wall-clock thread: if one of these fails, the spec and
the driver disagree, and the spec is what a firmware author has.

These runs use real threads and real time, so they assert accounting (every sample filed under its own
number with the values the device sent, HELD samples logging the command the device applied, every count
equal to the flags in the log), never timing: how many samples a busy machine holds is not asserted here
(held = 0 with a lead far above the host's jitter, exact HELD counts, the link watchdogs: tick by tick on a
simulated clock in ``test_spec_serial_v2_clocked.py``). Watchdogs on both sides are seconds long, so that
only a link that is really gone trips them: on a shared 2-core machine at load 16 the whole test process
was seen frozen for over a second."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig import exit_codes
from rig.cli import main
from rig.log_file import read_log
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError
from rig.runner import run_experiment
from rig.transports.base import Setpoint
from rig.transports.serial_link import SerialTransport

from sim_rigs import ListSink, no_leaks  # noqa: F401  (a fixture)
from spec_serial_device import CONTROL, ERROR_REQUEST, HELLO, START, SWITCH_ON_DISABLED, SpecSerialDevice

RATE_HZ = 200.0
SAMPLES = 200
DRIVE = DriveScaling(1 << 17)
LEAD_S = 0.5  # the lead of the v2 runs here: 100 setpoints at 200 Hz
WATCHDOG_S = 5.0  # the host's feedback watchdog and the device's link watchdog once streaming


def _device(**options) -> SpecSerialDevice:
    return SpecSerialDevice(watchdog_streaming_s=WATCHDOG_S, watchdog_ticking_s=WATCHDOG_S, **options)


def _rig_config(tmp_path, port: str, transport: str = "", feedback_timeout_s: float = WATCHDOG_S) -> str:
    path = tmp_path / "spec_rig.toml"
    path.write_text(f"""
name = "spec_rig"
sample_rate_hz = {RATE_HZ}

[transport]
url = "serial://{port}"
baudrate = 115200
reply_timeout_s = 0.3
{transport}

[drive]
counts_per_revolution = 131072

[encoder]
bits = 16
signed = false

[limits]
position_min_rad = -3.0
position_max_rad = 3.0
rate_max_rad_per_s = 50.0

[watchdog]
feedback_timeout_s = {feedback_timeout_s}
late_tolerance_s = 0.0025
""")
    return str(path)


def _command(tmp_path) -> tuple[str, np.ndarray]:
    """Starts just below zero (an unsigned encoder's first reading near 2 pi if unwrapped wrongly)."""
    k = np.arange(SAMPLES)
    command = -0.001 + 0.5 * np.sin(2 * np.pi * k / 80) * np.minimum(1.0, k / 40)
    path = tmp_path / "command.csv"
    path.write_text("command_rad\n" + "\n".join(repr(float(value)) for value in command) + "\n")
    return str(path), command


def _run(tmp_path, device: SpecSerialDevice, capsys, transport: str = "",
         feedback_timeout_s: float = WATCHDOG_S) -> tuple[int, str, str]:
    experiment, _ = _command(tmp_path)
    code = main(["run", _rig_config(tmp_path, device.port, transport, feedback_timeout_s), "--experiment", experiment,
                 "--out", str(tmp_path / "run.csv"), "--json"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _transport(device: SpecSerialDevice, **options) -> SerialTransport:
    return SerialTransport(device.port, baudrate=115200, encoder=EncoderResolution(bits=16),
                           sample_period_s=1 / RATE_HZ, drive=DRIVE, timing=BringUpTiming(), name="spec", **options)


def _assert_rows_are_the_devices_ticks(log, device: SpecSerialDevice) -> None:
    """Row k is tick k: its time k T, the encoder counts the device sent in TICK k, HELD exactly where the
    device held, and the command column the target the device applied (spec section 16.3)."""
    assert len(log.encoder_counts) == SAMPLES and set(range(SAMPLES)) <= set(device.ticks)
    ticks = [device.ticks[k] for k in range(SAMPLES)]
    np.testing.assert_allclose(log.time_s, np.arange(SAMPLES) / RATE_HZ, rtol=0, atol=1e-12)
    assert log.encoder_counts.tolist() == [tick.encoder_counts for tick in ticks]
    assert ((log.flags & SampleFlag.HELD) != 0).tolist() == [tick.held for tick in ticks]
    assert log.command_rad.tolist() == [DRIVE.rad_from_counts(tick.applied_counts) for tick in ticks]
    assert not np.any(log.flags & SampleFlag.LOST)  # TICKs come in tick order: a row waits for its own


def _assert_v1_rows_are_the_devices_feedback(log, device: SpecSerialDevice, result: dict) -> None:
    """Host-paced: a busy host may lose samples (flagged and counted); every other row holds exactly the
    counts the device sent for its seq."""
    lost = (log.flags & SampleFlag.LOST) != 0
    assert result["lost"] == np.count_nonzero(lost) and len(log.flags) == SAMPLES
    kept = np.flatnonzero(~lost)
    assert log.encoder_counts[kept].tolist() == [device.feedback[k] for k in kept]


# -- protocol v2 (spec section 16) ------------------------------------------------------------------------------

def test_the_driver_runs_a_v2_device_written_from_the_spec(tmp_path, capsys, no_leaks):
    """Boot output, the first DEVICE_INFO lost (the host's second HELLO gets it: section 16.2), a lost STATUS
    right after enabling: the run is v2, every sample is the device's tick under its own number with the
    command the device applied, nothing lost, and the drive ends disabled."""
    with _device(lost_device_info=1, lost_status_after_enable=1, boot_output=b"\x00boot v2.0 ok\r\n\x00") as device:
        code, out, err = _run(tmp_path, device, capsys, transport=f"lead_s = {LEAD_S}\nprotocol = \"v2\"")
    assert code == exit_codes.SUCCESS, err
    result = json.loads(out)
    assert result["samples"] == SAMPLES and result["lost"] == 0
    assert result["frame_errors"] == 0 and result["not_followed"] == 0 and not result["warnings"]
    # the smallest lead of a setpoint sent after START over its tick: never more than the lead
    assert result["min_lead_s"] <= LEAD_S
    assert device.sessions == 1 and device.mode == 1  # one session, ended by the stop (section 16.2)
    hellos = [seq for kind, seq in device.requests if kind == HELLO]
    assert len(hellos) == 2 and len(set(hellos)) == 1  # the same request sent again after the lost answer
    assert [kind for kind, _ in device.requests].count(START) == 1
    log = read_log(tmp_path / "run.csv")
    _assert_rows_are_the_devices_ticks(log, device)
    held = (log.flags & SampleFlag.HELD) != 0
    assert result["held"] == np.count_nonzero(held) == len(device.dropped_setpoints)  # each held one came late
    _, command = _command(tmp_path)
    assert log.command_rad[~held].tolist() == [DRIVE.quantize_rad(value) for value in command[~held]]
    count_rad = 2 * np.pi / 2**16  # the encoder reads the drive through a fixed gain; the first reading near 0
    assert np.all(np.abs(log.angle_rad - log.command_rad) <= count_rad) and -0.002 < log.angle_rad[0] < 0
    assert "ends SWITCH ON DISABLED" in log.metadata.extra["summary"]["stop"]
    assert device.controlwords == [0x0006, 0x0007, 0x000F, 0x0002, 0x0000] and device.state == SWITCH_ON_DISABLED
    # device-clocked: judged by held and the smallest lead, which the log's summary line keeps too; the host's
    # send lateness is not measured
    assert result["version"] == 4 and result["send_lateness_max_s"] is None and result["sync_jitter_max_s"] is None
    assert log.metadata.extra["summary"]["sample_clock"] == "device"
    assert log.metadata.extra["summary"]["min_lead_s"] == result["min_lead_s"]


def test_setpoints_lost_on_the_line_are_held_ticks_logging_the_command_applied(tmp_path, capsys, no_leaks):
    """An underrun the host cannot prevent (three SETPOINTs lost to line noise): the device holds the last
    target at those ticks and says HELD; the log keeps the samples with the command really applied."""
    with _device(lost_setpoints=(120, 121, 122)) as device:
        code, out, err = _run(tmp_path, device, capsys, transport=f"lead_s = {LEAD_S}")
    assert code == exit_codes.SUCCESS, err
    result = json.loads(out)
    log = read_log(tmp_path / "run.csv")
    _assert_rows_are_the_devices_ticks(log, device)
    held = np.flatnonzero(log.flags & SampleFlag.HELD)
    assert result["samples"] == SAMPLES and result["lost"] == 0 and result["held"] == held.size >= 3
    assert {120, 121, 122} <= set(held.tolist())  # (a busy host may add its own)
    assert log.command_rad[120:123].tolist() == [log.command_rad[119]] * 3  # held at tick 119's target
    _, command = _command(tmp_path)
    assert not math.isclose(log.command_rad[121], DRIVE.quantize_rad(command[121]))  # not what was designed


def test_a_host_stall_longer_than_the_lead_holds_samples_and_loses_none(no_leaks):
    """The driver's thread stalls 0.3 s with a 50 ms lead: the device goes on ticking on its own clock, the
    ticks the stall outlasted are HELD with the command applied, none is lost, and the run goes on."""
    stall_s, lead_s = 0.3, 0.05
    command = 0.2 * np.sin(2 * np.pi * np.arange(SAMPLES) / 50)
    stalled = []

    def progress(done: int, _late: int) -> None:
        if done >= 60 and not stalled:
            stalled.append(done)
            time.sleep(stall_s)  # the host's own thread, not the device's

    sink = ListSink()
    with _device() as device:
        transport = _transport(device, lead_s=lead_s)
        summary = run_experiment(transport, command, sink, feedback_timeout_s=WATCHDOG_S, progress=progress)
    assert summary.samples == SAMPLES and summary.lost == 0 and stalled
    flags = np.array([row[4] for row in sink.rows])
    held = np.flatnonzero(flags & SampleFlag.HELD)
    # the stall outlasts the lead by 250 ms = 50 ticks after row 60; a busy machine only stalls the host longer
    assert summary.held == held.size and np.count_nonzero(held > 60) >= round((stall_s - lead_s) * RATE_HZ) - 1
    assert summary.min_lead_s < 0
    assert [row[1] for row in sink.rows] == [DRIVE.rad_from_counts(device.ticks[k].applied_counts)
                                             for k in range(SAMPLES)]
    assert all(device.ticks[k].held for k in held)
    # the host sends no setpoint for a tick that has passed; one sent in time by its estimate of the device's
    # clock that a busy machine still delivered late is dropped there, and that tick is HELD
    assert set(device.dropped_setpoints) <= set(held.tolist())


# -- version handshake and v1 devices (spec section 16.2) -------------------------------------------------------

def test_a_v1_device_is_driven_the_v1_way_and_the_summary_says_so(tmp_path, capsys, no_leaks):
    """Boot output with a leading 0x00, a lost STATUS answer right after enabling, a device that drops HELLO
    (an unknown type): bring-up, every sample filed under its own seq with the value the device sent, the
    stop leaves the device disabled."""
    with _device(protocol_version=1, lost_status_after_enable=1, boot_output=b"\x00boot v1.0 ok\r\n\x00") as device:
        code, out, err = _run(tmp_path, device, capsys)
    assert code == exit_codes.SUCCESS, err
    result = json.loads(out)
    assert result["samples"] == SAMPLES
    assert result["frame_errors"] == 0 and result["not_followed"] == 0  # the boot output is not line noise
    # a v1 device (it drops HELLO, spec section 16.2) is driven host-paced, and the summary says so
    assert result["min_lead_s"] is None and result["held"] == 0
    assert any("driven as a protocol v1 device" in warning for warning in result["warnings"])
    assert [kind for kind, _ in device.requests].count(HELLO) == 0  # dropped: never a request it saw
    log = read_log(tmp_path / "run.csv")
    assert log.metadata.extra["summary"]["frame_errors"] == 0
    assert "ends SWITCH ON DISABLED" in log.metadata.extra["summary"]["stop"]
    # host-paced: judged by the send lateness after each deadline, in the summary and the log's summary line
    lateness = [result[f"send_lateness_{name}_s"] for name in ("p50", "p99", "max")]
    assert 0.0 <= lateness[0] <= lateness[1] <= lateness[2]
    assert log.metadata.extra["summary"]["sample_clock"] == "host"
    assert [log.metadata.extra["summary"][f"send_lateness_{name}_s"] for name in ("p50", "p99", "max")] == lateness
    _assert_v1_rows_are_the_devices_feedback(log, device, result)  # every sample under its own seq
    # the encoder reads the drive through a fixed gain: within one count of the command; the first
    # reading (65525 counts, a load just below zero) is -0.001 rad, not near 2 pi
    count_rad = 2 * np.pi / 2**16
    kept = ~np.isnan(log.angle_rad)
    assert np.all(np.abs(log.angle_rad[kept] - log.command_rad[kept]) <= count_rad)
    assert not kept[0] or -0.002 < log.angle_rad[0] < 0
    # the lost answer to enable operation: the same request re-sent, answered, not applied twice
    controls = [seq for kind, seq in device.requests if kind == CONTROL]
    assert len(controls) == len(set(controls)) + 1
    assert device.controlwords == [0x0006, 0x0007, 0x000F, 0x0002, 0x0000]
    assert device.state == SWITCH_ON_DISABLED


def test_a_v2_device_whose_two_device_info_answers_are_lost_fails_safe(tmp_path, capsys, no_leaks):
    """Spec section 16.2: the device is in v2 mode, the host took it for v1. Its SETPOINTs are queued, never
    answered, never applied (no START): the drive holds still, the feedback watchdog stops the run."""
    with _device(lost_device_info=2) as device:  # (nothing ever arrives: a short feedback watchdog is safe)
        code, out, err = _run(tmp_path, device, capsys, feedback_timeout_s=0.5)
    assert code != exit_codes.SUCCESS and "no feedback for" in err
    assert device.sessions == 0 and device.ticks == {} and device.feedback == {} and device.actual == 0
    assert device.controlwords[-2:] == [0x0002, 0x0000] and device.state == SWITCH_ON_DISABLED


def test_a_v1_device_that_answers_hello_with_version_1_is_driven_the_v1_way(no_leaks):
    with _device(protocol_version=1, knows_hello=True) as device:
        transport = _transport(device)
        try:
            transport.open()
            assert transport.version == 1 and transport.lead_samples == 0
            assert [kind for kind, _ in device.requests].count(HELLO) == 1  # answered at once
            transport.send(Setpoint(0, 0.0))
            assert transport.receive(timeout_s=WATCHDOG_S).seq == 0 and device.feedback == {0: 0}
        finally:
            transport.close()
    assert device.sessions == 0 and device.state == SWITCH_ON_DISABLED


def test_protocol_v2_refuses_a_v1_device_before_enabling_it(tmp_path, capsys, no_leaks):
    with _device(protocol_version=1) as device:
        code, _, err = _run(tmp_path, device, capsys, transport='protocol = "v2"')
    assert code != exit_codes.SUCCESS
    assert "speaks only protocol v1 (it drops HELLO)" in err and 'protocol = "auto"' in err
    assert device.controlwords == [] and device.feedback == {}


def test_protocol_v1_drives_a_v2_device_host_paced(tmp_path, capsys, no_leaks):
    """Section 16.2: a v2 device must still work with a host that never sends HELLO."""
    with _device() as device:
        code, out, err = _run(tmp_path, device, capsys, transport='protocol = "v1"')
    assert code == exit_codes.SUCCESS, err
    result = json.loads(out)
    assert result["samples"] == SAMPLES and result["min_lead_s"] is None
    assert device.sessions == 0 and device.ticks == {} and sorted(device.feedback) == list(range(SAMPLES))
    _assert_v1_rows_are_the_devices_feedback(read_log(tmp_path / "run.csv"), device, result)


# -- faults and the watchdog, in both protocols ------------------------------------------------------------------

@pytest.mark.parametrize("version", [1, 2])
def test_a_fault_the_reset_cannot_clear_is_named_with_the_code_read_by_error_request(tmp_path, capsys, no_leaks,
                                                                                        version):
    with _device(protocol_version=version, boot_fault_code=0x5441, fault_clears=False) as device:
        code, _, err = _run(tmp_path, device, capsys)
    assert code == exit_codes.DEVICE_FAULT
    assert "(code 0x5441: safe torque off / enable input inactive)" in err and "stays in FAULT" in err
    assert any(kind == ERROR_REQUEST for kind, _ in device.requests)
    assert 0x000F not in device.controlwords and not device.feedback and not device.ticks  # never enabled


@pytest.mark.parametrize("version", [1, 2])
def test_a_fault_whose_fault_frame_is_lost_is_named_from_error_request(tmp_path, capsys, no_leaks, version):
    with _device(protocol_version=version, fault_at_sample=60, fault_code=0x2310, fault_frame_lost=True) as device:
        code, _, err = _run(tmp_path, device, capsys)
    assert code == exit_codes.DEVICE_FAULT
    assert "(code 0x2310: continuous over-current on the device output side)" in err
    assert "no FAULT frame came" in err
    log = read_log(tmp_path / "run.csv")
    assert not np.any(log.flags[:60] & SampleFlag.FAULT) and device.controlwords[-2:] == [0x0002, 0x0000]
    if version == 1:
        assert log.flags[60] & SampleFlag.FAULT
    else:  # section 16.3: the tick clock stopped with the fault, the faulted tick is the last sample (flagged
        # FAULT when the host had queued its setpoint; a host behind the device, HELD, has no row for it)
        assert max(device.ticks) == 60 and device.mode == 1 and not np.any(log.flags[:60] & SampleFlag.LOST)
        assert len(log.flags) in (60, 61) and (len(log.flags) == 60 or log.flags[60] & SampleFlag.FAULT)


def test_a_device_ticking_at_another_rate_is_refused_before_enabling(no_leaks):
    with _device(sample_period_ns=1_000_000) as device:
        transport = _transport(device)
        with pytest.raises(ConfigError, match=r"200 Hz, but the device ticks every 1000000 ns \(1000 Hz"):
            transport.open()
    assert device.controlwords == []
