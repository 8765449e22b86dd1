"""The real driver (``rig run`` through ``rig.cli.main``) against a device written only from
``docs/serial_protocol.md`` (:mod:`spec_serial_device`, which imports nothing of ours): if one of these fails,
the spec and the driver disagree, and the spec is what a firmware author has."""

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
from rig.protocols.errors import DeviceFault
from rig.transports.base import Setpoint
from rig.transports.serial_link import SerialTransport

from sim_rigs import no_leaks  # noqa: F401  (a fixture)
from spec_serial_device import CONTROL, ERROR_REQUEST, SWITCH_ON_DISABLED, SpecSerialDevice

RATE_HZ = 200.0
SAMPLES = 200


def _rig_config(tmp_path, port: str) -> str:
    path = tmp_path / "spec_rig.toml"
    path.write_text(f"""
name = "spec_rig"
sample_rate_hz = {RATE_HZ}

[transport]
url = "serial://{port}"
baudrate = 115200
reply_timeout_s = 0.3

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
feedback_timeout_s = 0.5
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


def _run(tmp_path, device: SpecSerialDevice, capsys) -> tuple[int, str, str]:
    experiment, _ = _command(tmp_path)
    code = main(["run", _rig_config(tmp_path, device.port), "--experiment", experiment,
                 "--out", str(tmp_path / "run.csv"), "--json"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_the_driver_runs_a_device_written_from_the_spec(tmp_path, capsys, no_leaks):
    """Boot output with a leading 0x00, a lost STATUS answer right after enabling: bring-up, every sample
    filed under its own seq with the value the device sent, the stop leaves the device disabled."""
    with SpecSerialDevice(lost_status_after_enable=1, boot_output=b"\x00boot v1.0 ok\r\n\x00") as device:
        code, out, err = _run(tmp_path, device, capsys)
    assert code == exit_codes.SUCCESS, err
    result = json.loads(out)
    assert result["samples"] == SAMPLES and result["lost"] == 0
    assert result["frame_errors"] == 0 and result["not_followed"] == 0  # the boot output is not line noise
    # a v1 device (it drops HELLO, spec section 16.2) is driven host-paced, and the summary says so
    assert result["min_lead_s"] is None and result["held"] == 0
    assert any("driven as a protocol v1 device" in warning for warning in result["warnings"])
    log = read_log(tmp_path / "run.csv")
    assert log.metadata.extra["summary"]["frame_errors"] == 0
    assert "ends SWITCH ON DISABLED" in log.metadata.extra["summary"]["stop"]
    # every sample under its own seq, with the counts the device sent for that seq
    assert log.encoder_counts.tolist() == [device.feedback[k] for k in range(SAMPLES)]
    # the encoder reads the drive through a fixed gain: within one count of the command; the first
    # reading (65525 counts, a load just below zero) is -0.001 rad, not near 2 pi
    count_rad = 2 * np.pi / 2**16
    assert np.all(np.abs(log.angle_rad - log.command_rad) <= count_rad)
    assert -0.002 < log.angle_rad[0] < 0
    # the lost answer to enable operation: the same request re-sent, answered, not applied twice
    controls = [seq for kind, seq in device.requests if kind == CONTROL]
    assert len(controls) == len(set(controls)) + 1
    assert device.controlwords == [0x0006, 0x0007, 0x000F, 0x0002, 0x0000]
    assert device.state == SWITCH_ON_DISABLED


def test_a_fault_the_reset_cannot_clear_is_named_with_the_code_read_by_error_request(tmp_path, capsys, no_leaks):
    with SpecSerialDevice(boot_fault_code=0x5441, fault_clears=False) as device:
        code, _, err = _run(tmp_path, device, capsys)
    assert code == exit_codes.DEVICE_FAULT
    assert "(code 0x5441: safe torque off / enable input inactive)" in err and "stays in FAULT" in err
    assert any(kind == ERROR_REQUEST for kind, _ in device.requests)
    assert 0x000F not in device.controlwords and not device.feedback  # never enabled, nothing streamed


def test_a_fault_whose_fault_frame_is_lost_is_named_from_error_request(tmp_path, capsys, no_leaks):
    with SpecSerialDevice(fault_at_sample=60, fault_code=0x2310, fault_frame_lost=True) as device:
        code, _, err = _run(tmp_path, device, capsys)
    assert code == exit_codes.DEVICE_FAULT
    assert "(code 0x2310: continuous over-current on the device output side)" in err
    assert "no FAULT frame came" in err
    log = read_log(tmp_path / "run.csv")
    assert log.flags[60] & SampleFlag.FAULT
    assert device.controlwords[-2:] == [0x0002, 0x0000]


def test_the_devices_link_watchdog_stops_the_drive_and_the_host_hears_of_it(no_leaks):
    """A host that falls silent after enabling: the device's own watchdog (spec section 10) disables the
    drive and says so with an unprompted STATUS (seq 0), which stops the host's stream."""
    with SpecSerialDevice() as device:
        transport = SerialTransport(device.port, baudrate=115200, encoder=EncoderResolution(bits=16),
                                    sample_period_s=1 / RATE_HZ, drive=DriveScaling(1 << 17),
                                    timing=BringUpTiming(), name="spec")
        try:
            transport.open()
            for k in range(10):
                transport.send(Setpoint(k, 0.0))
                assert transport.receive(timeout_s=1.0).seq == k
            deadline = time.monotonic() + 5.0
            while not device.watchdog_expired and time.monotonic() < deadline:
                time.sleep(0.01)  # the host is silent (stalled)
            assert device.watchdog_expired and device.state == SWITCH_ON_DISABLED
            with pytest.raises(DeviceFault, match=r"left OPERATION ENABLED without a fault \(unprompted STATUS"):
                transport.receive(timeout_s=1.0)
        finally:
            transport.close()
    assert math.isclose(transport.initial_position_rad, 0.0)
