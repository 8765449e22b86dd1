"""The real driver (``rig run``, or :func:`rig.runner.run_experiment`) against a raw-CAN device written only
from ``configs/raw_can.dbc`` and the spec (:mod:`spec_raw_can_device`, which imports nothing of ours), on
python-can's ``virtual`` bus with the device ticking on its own wall-clock thread. As for the serial spec
device (``test_spec_serial_device.py``), these runs assert accounting, never timing, and both sides'
watchdogs are seconds long; the tick-by-tick behaviour is in ``test_spec_raw_can_v2_clocked.py``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig import exit_codes
from rig.cli import main
from rig.log_file import read_log
from rig.protocols.cia402 import DriveScaling

from sim_rigs import no_leaks  # noqa: F401  (a fixture)
from spec_raw_can_device import RIG_DRIVE_FEEDBACK, RIG_DRIVE_TICK, RIG_FEEDBACK, RIG_TICK_APPLIED, SpecRawCanDevice
from spec_serial_device import HELLO, START, SWITCH_ON_DISABLED

RATE_HZ = 200.0
SAMPLES = 200
DRIVE = DriveScaling(1 << 17)
LEAD_S = 0.5  # 100 setpoints
WATCHDOG_S = 5.0  # the host's feedback watchdog and the device's link watchdog once streaming


def _rig_config(tmp_path, channel: str, transport: str = "") -> str:
    path = tmp_path / "spec_can_rig.toml"
    path.write_text(f"""
name = "spec_can_rig"
sample_rate_hz = {RATE_HZ}

[transport]
url = "can://virtual/{channel}"
bitrate = 1000000
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
feedback_timeout_s = {WATCHDOG_S}
late_tolerance_s = 0.0025
""")
    return str(path)


def _command() -> np.ndarray:
    k = np.arange(SAMPLES)
    return -0.001 + 0.5 * np.sin(2 * np.pi * k / 80) * np.minimum(1.0, k / 40)


def _run(tmp_path, device: SpecRawCanDevice, capsys, transport: str = "") -> tuple[int, dict | None, str]:
    path = tmp_path / "command.csv"
    path.write_text("command_rad\n" + "\n".join(repr(float(value)) for value in _command()) + "\n")
    code = main(["run", _rig_config(tmp_path, device.channel, transport), "--experiment", str(path),
                 "--out", str(tmp_path / "run.csv"), "--json"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out) if captured.out.strip() else None, captured.err


@pytest.fixture
def device(tmp_path):
    """``device(**options)`` -> a started :class:`SpecRawCanDevice` on a bus of this test's own."""
    devices = []

    def make(**options) -> SpecRawCanDevice:
        spec = SpecRawCanDevice(channel=f"spec_can_{tmp_path.name}", sample_period_ns=5_000_000,
                                watchdog_streaming_s=WATCHDOG_S, watchdog_ticking_s=WATCHDOG_S, **options)
        devices.append(spec.start())
        return spec

    yield make
    for spec in devices:
        spec.close()


def _assert_rows_are_the_devices_ticks(log, device: SpecRawCanDevice) -> None:
    ticks = [device.ticks[k] for k in range(SAMPLES)]
    np.testing.assert_allclose(log.time_s, np.arange(SAMPLES) / RATE_HZ, rtol=0, atol=1e-12)
    assert log.encoder_counts.tolist() == [tick.encoder_counts for tick in ticks]
    assert ((log.flags & SampleFlag.HELD) != 0).tolist() == [tick.held for tick in ticks]
    assert log.command_rad.tolist() == [DRIVE.rad_from_counts(tick.applied_counts) for tick in ticks]
    assert not np.any(log.flags & SampleFlag.LOST)


@pytest.mark.parametrize("version, order", [(3, (RIG_FEEDBACK, RIG_DRIVE_TICK)), (3, (RIG_DRIVE_TICK, RIG_FEEDBACK)),
                                            (2, (RIG_FEEDBACK, RIG_DRIVE_FEEDBACK, RIG_TICK_APPLIED)),
                                            (2, (RIG_TICK_APPLIED, RIG_DRIVE_FEEDBACK, RIG_FEEDBACK))],
                         ids=["v3-feedback-first", "v3-drive-first", "v2-feedback-first", "v2-applied-first"])
def test_the_driver_runs_a_clocked_raw_can_device_written_from_the_dbc(tmp_path, capsys, no_leaks, device, version,
                                                                       order):
    """v3 and v2: every sample is the device's tick with the command it applied, nothing lost, whatever order
    the frames of a tick come in (the DBC did not fix it); the drive ends disabled."""
    spec = device(protocol_version=version, tick_frame_order=order, lost_status_after_enable=1)
    code, result, err = _run(tmp_path, spec, capsys, transport=f'lead_s = {LEAD_S}\nprotocol = "v2"')
    spec.close()
    assert code == exit_codes.SUCCESS, err
    assert result["samples"] == SAMPLES and result["lost"] == result["duplicate"] == 0
    assert result["min_lead_s"] <= LEAD_S and not result["warnings"]
    assert [kind for kind, _ in spec.requests].count(START) == 1 and spec.sessions == 1
    log = read_log(tmp_path / "run.csv")
    _assert_rows_are_the_devices_ticks(log, spec)
    held = (log.flags & SampleFlag.HELD) != 0
    assert result["held"] == np.count_nonzero(held) == len(spec.dropped_setpoints)
    assert log.command_rad[~held].tolist() == [DRIVE.quantize_rad(value) for value in _command()[~held]]
    assert spec.controlwords == [0x0006, 0x0007, 0x000F, 0x0002, 0x0000] and spec.state == SWITCH_ON_DISABLED


def test_setpoints_lost_on_the_bus_are_held_ticks_logging_the_command_applied(tmp_path, capsys, no_leaks, device):
    spec = device(lost_setpoints=(120, 121))
    code, result, err = _run(tmp_path, spec, capsys, transport=f"lead_s = {LEAD_S}")
    spec.close()
    assert code == exit_codes.SUCCESS, err
    log = read_log(tmp_path / "run.csv")
    _assert_rows_are_the_devices_ticks(log, spec)
    held = np.flatnonzero(log.flags & SampleFlag.HELD)
    assert result["samples"] == SAMPLES and result["lost"] == 0 and result["held"] == held.size >= 2
    assert {120, 121} <= set(held.tolist())  # (a busy host may add its own)
    assert log.command_rad[120:122].tolist() == [log.command_rad[119]] * 2


def test_a_v1_raw_can_device_is_driven_host_paced_and_the_summary_says_so(tmp_path, capsys, no_leaks, device):
    spec = device(protocol_version=1)
    code, result, err = _run(tmp_path, spec, capsys)
    spec.close()
    assert code == exit_codes.SUCCESS, err
    assert result["samples"] == SAMPLES and result["min_lead_s"] is None
    assert any("protocol v1" in warning for warning in result["warnings"])
    assert HELLO not in [kind for kind, _ in spec.requests] and sorted(spec.feedback) == list(range(SAMPLES))
    log = read_log(tmp_path / "run.csv")
    lost = (log.flags & SampleFlag.LOST) != 0  # host-paced: a busy host may lose some, flagged and counted
    assert result["lost"] == np.count_nonzero(lost)
    kept = np.flatnonzero(~lost)
    assert log.encoder_counts[kept].tolist() == [spec.feedback[k] for k in kept]


def test_protocol_v2_refuses_a_v1_raw_can_device_before_enabling_it(tmp_path, capsys, no_leaks, device):
    spec = device(protocol_version=1)
    code, _, err = _run(tmp_path, spec, capsys, transport='protocol = "v2"')
    spec.close()
    assert code != exit_codes.SUCCESS and "v1" in err and spec.controlwords == []


def test_a_v2_raw_can_fault_is_named_by_rig_fault_and_its_tick_is_the_last_sample(tmp_path, capsys, no_leaks,
                                                                                  device):
    spec = device(fault_at_sample=60, fault_code=0x2310)
    code, _, err = _run(tmp_path, spec, capsys)
    spec.close()
    assert code == exit_codes.DEVICE_FAULT and "0x2310" in err
    log = read_log(tmp_path / "run.csv")
    # the log ends at the faulted tick; flagged FAULT when the host had queued its setpoint (a host that fell
    # behind the device, HELD, has no row for it: the runner opens no row on the fault)
    assert len(log.flags) in (60, 61) and (len(log.flags) == 60 or log.flags[60] & SampleFlag.FAULT)
    assert not np.any(log.flags[:60] & (SampleFlag.FAULT | SampleFlag.LOST))
    assert max(spec.ticks) == 60 and spec.controlwords[-2:] == [0x0002, 0x0000]


@pytest.mark.parametrize("version", [1, 2])
def test_a_raw_can_fault_whose_rig_fault_is_lost_stops_the_run_at_the_faulted_statusword(
        tmp_path, capsys, no_leaks, device, version):
    """RIG_FAULT lost on the bus: the faulted statusword in RIG_FEEDBACK alone must stop the run as a device
    fault (the serial spec's section 9, which the raw-CAN protocol follows), not as a silent link."""
    spec = device(protocol_version=version, fault_at_sample=60, fault_frame_lost=True)
    code, _, err = _run(tmp_path, spec, capsys)
    spec.close()
    assert code == exit_codes.DEVICE_FAULT, err
    assert "reports FAULT in its statusword 0x0218 at sample 60 (no RIG_FAULT frame" in err
    assert "no feedback" not in err  # not taken for a silent link after waiting out the feedback watchdog
    log = read_log(tmp_path / "run.csv")
    before = SampleFlag.FAULT | (SampleFlag.LOST if version == 2 else 0)  # host-paced v1 may lose some on a busy host
    assert log.flags[60] & SampleFlag.FAULT and not np.any(log.flags[:60] & before)
