"""The transport registry, rig configs and ``rig run`` end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig import transports
from rig.cli import main
from rig.log_file import read_log
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError, TransportError
from rig.rig_config import load_rig_config
from rig.runner import RunSummary
from rig.transports import open_transport, parse_transport_url
from sim_backend.plant_config import load_plant_config
from sim_rigs import CONFIGS, no_leaks, write_test_config  # noqa: F401  (no_leaks is a fixture)

ENCODER = EncoderResolution(bits=12)


def test_urls_name_the_transport_and_any_python_can_interface():
    assert parse_transport_url("canopen://pcan/PCAN_USBBUS1") == (
        "canopen", {"interface": "pcan", "channel": "PCAN_USBBUS1"})
    assert parse_transport_url("can://kvaser/0") == ("can", {"interface": "kvaser", "channel": "0"})
    assert parse_transport_url("serial:///dev/ttyUSB0") == ("serial", {"port": "/dev/ttyUSB0"})
    with pytest.raises(ConfigError, match=r"unknown transport 'modbus://x' \(known: canopen://, can://, serial://\)"):
        parse_transport_url("modbus://x")
    with pytest.raises(ConfigError, match="'nosuchcard' is no python-can interface"):
        parse_transport_url("canopen://nosuchcard/0")


def test_udp_multicast_urls_carry_the_port_of_the_group_and_only_it_has_one():
    assert parse_transport_url("canopen://udp_multicast:43200/239.74.1.2") == (
        "canopen", {"interface": "udp_multicast", "channel": "239.74.1.2", "port": 43200})
    assert parse_transport_url("can://udp_multicast/239.74.1.2") == (
        "can", {"interface": "udp_multicast", "channel": "239.74.1.2"})
    with pytest.raises(ConfigError, match="a port belongs to udp_multicast only, not to socketcan"):
        parse_transport_url("can://socketcan:43200/can0")
    with pytest.raises(ConfigError, match="expected a UDP port 1..65535"):
        parse_transport_url("can://udp_multicast:99999/239.74.1.2")


def test_unknown_options_are_rejected_not_ignored():
    with pytest.raises(ConfigError, match=r"\[baud_rate\] not an option of the serial transport \(accepted: .*baudrate"):
        open_transport("serial:///dev/ttyUSB0", encoder=ENCODER, sample_period_s=1e-3, baud_rate=9600)


def test_a_missing_driver_fails_only_when_chosen_with_a_clear_message(monkeypatch):
    monkeypatch.setitem(transports.BACKENDS, "serial", ("rig.transports._no_such_driver", "X", "pyserial"))
    assert parse_transport_url("can://virtual/a")[0] == "can"  # other transports are unaffected
    with pytest.raises(TransportError, match="the serial transport needs pyserial"):
        open_transport("serial:///dev/ttyUSB0", encoder=ENCODER, sample_period_s=1e-3)


def test_an_absent_port_is_a_transport_error_and_leaves_nothing_open(no_leaks):
    transport = open_transport("serial:///dev/no_such_tty", encoder=ENCODER, sample_period_s=1e-3)
    with pytest.raises(TransportError, match="cannot open serial port /dev/no_such_tty"):
        transport.open()
    assert not transport.is_open


@pytest.mark.parametrize("name", ["sim_serial", "rig_serial", "sim_canopen", "sim_can"])
def test_shipped_configs_validate(name):
    config = load_rig_config(CONFIGS / f"{name}.toml")
    assert config.scheme == name.split("_")[1] and config.sample_rate_hz == 1000.0
    assert (config.simulation is not None) == name.startswith("sim")


def test_the_serial_template_follows_the_specs_v2_timing():
    """docs/serial_protocol.md 16.5: a lead of 250 ms rides through the host stalls measured; the host's feedback
    watchdog must not stop a run for less silence than the lead covers, and gives up (with its grace) before
    the device's own v2 link watchdog (at least 0.5 s after START, 16.4) stops the drive on its own."""
    from rig.runner import WATCHDOG_GRACE
    from rig.transports.serial_link import DEFAULT_LEAD_S

    config = load_rig_config(CONFIGS / "rig_serial.toml")
    assert config.options["lead_s"] == DEFAULT_LEAD_S == 0.25
    assert DEFAULT_LEAD_S <= config.feedback_timeout_s and (1 + WATCHDOG_GRACE) * config.feedback_timeout_s < 0.5


def test_the_real_canopen_template_validates_once_it_names_real_eds_files(tmp_path):
    text = (CONFIGS / "rig_canopen.toml").read_text()
    with pytest.raises(ConfigError, match=r"rig_canopen.toml: \[transport.drive_eds\] no such EDS file /path/to/your_drive"):
        load_rig_config(CONFIGS / "rig_canopen.toml")
    text = text.replace("/path/to/your_drive.eds", str(CONFIGS / "eds" / "sim_drive_cia402.eds"))
    text = text.replace("/path/to/your_encoder.eds", str(CONFIGS / "eds" / "sim_encoder_cia406.eds"))
    (tmp_path / "rig.toml").write_text(text)
    config = load_rig_config(tmp_path / "rig.toml")
    assert config.url == "canopen://socketcan/can0" and config.options["bitrate"] == 1_000_000


def test_config_errors_name_the_file_and_the_key(tmp_path):
    path = write_test_config("serial", tmp_path)
    path.write_text(path.read_text().replace("baudrate = ", "baud = "))
    with pytest.raises(ConfigError, match=r"sim_serial_test.toml: \[transport.baud\] not an option of the serial"):
        load_rig_config(path)
    path = write_test_config("serial", tmp_path)
    path.write_text(path.read_text().replace("position_max_rad = 12.0", "position_max_rad = -13.0"))
    with pytest.raises(ConfigError, match=r"\[limits.position_max_rad\] expected a number > position_min_rad"):
        load_rig_config(path)


@pytest.mark.parametrize("kind", ["serial", "canopen", "can"])
def test_rig_run_writes_a_log_equal_to_the_offline_simulation(kind, tmp_path, capsys, no_leaks):
    config_path = write_test_config(kind, tmp_path)
    out = tmp_path / "run.csv"
    code = main(["run", str(config_path), "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(out), "--duration", "0.3", "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["log"] == str(out) and result["samples"] == 60 and result["rate_hz"] > 0
    # the document is the run summary's own (kind and version first), with the keys --json always printed
    assert list(result)[:14] == ["kind", "version", "log", "samples", "lost", "late", "rate_hz", "held", "min_lead_s",
                                 "not_followed", "duplicate", "frame_errors", "warnings", "stop"]
    assert (result["kind"], result["version"]) == ("run_summary", 4)
    assert RunSummary.from_dict(result).to_dict() == result
    # every simulated wire is device-clocked: judged by held and min_lead_s, no host send lateness
    assert result["min_lead_s"] is not None and result["send_lateness_p99_s"] is None
    # CANopen's instants are the SYNCs: their jitter is measured, and a SYNC from a thread of the host (python-can's
    # virtual bus has no periodic sending) is said to be one
    assert (result["sync_jitter_max_s"] is not None) == (kind == "canopen")
    assert any("SYNC comes from a thread of this process" in warning for warning in result["warnings"]) == (
        kind == "canopen")
    record = read_log(out)
    assert record.num_samples == 60 and record.metadata.transport.startswith(f"{kind}://")
    assert record.metadata.sample_period_s == 0.005 and record.metadata.seed == 4
    lost = (record.flags & SampleFlag.LOST) != 0
    assert result["lost"] == lost.sum() and result["late"] == ((record.flags & SampleFlag.LATE) != 0).sum()
    config = load_rig_config(config_path)
    expected = load_plant_config(config.simulation.plant_path).gearbox(seed=4).simulate(record.command_rad)
    np.testing.assert_array_equal(record.angle_rad[~lost], expected.measured_angle_rad[~lost])
    # PRBS of +-1 rad (Cerone 2009), 100 samples cut to 60, quantised to the drive's counts
    assert np.all(np.abs(np.abs(record.command_rad) - 1.0) < np.pi / 131072)


def test_rig_run_refuses_an_experiment_beyond_the_limits_with_exit_code_2(tmp_path, capsys, no_leaks):
    config_path = write_test_config("serial", tmp_path)
    config_path.write_text(config_path.read_text().replace("position_max_rad = 12.0", "position_max_rad = 0.5"))
    code = main(["run", str(config_path), "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(tmp_path / "run.csv")])
    assert code == 2
    assert "outside the limits [-12, 0.5] rad" in capsys.readouterr().err


def test_rig_run_defaults_to_the_simulated_canopen_rig(tmp_path, capsys, no_leaks):
    out = tmp_path / "default.csv"
    assert main(["run", "--experiment", str(CONFIGS / "experiments" / "prbs.toml"), "--out", str(out),
                 "--duration", "0.05", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["samples"] == 50
    record = read_log(out)
    assert record.metadata.transport == "canopen://virtual/sim_canopen" and record.metadata.sample_period_s == 0.001


def test_rig_run_streams_a_command_file(tmp_path, capsys, no_leaks):
    command = np.round(0.3 * np.sin(np.arange(30) / 5.0), 4).tolist()
    path = tmp_path / "command.csv"
    path.write_text("time_s,command_rad\n" + "".join(f"{k * 0.005!r},{value!r}\n" for k, value in enumerate(command)))
    out = tmp_path / "run.csv"
    assert main(["run", str(write_test_config("serial", tmp_path)), "--experiment", str(path), "--out", str(out),
                 "--json"]) == 0
    record = read_log(out)
    np.testing.assert_allclose(record.command_rad, command, atol=np.pi / 131072)  # quantised to drive counts
    assert record.metadata.excitation == "command"
    path.write_text("time_s,command_rad\n0.0,0.1\n0.01,0.2\n")
    assert main(["run", str(write_test_config("serial", tmp_path)), "--experiment", str(path), "--out",
                 str(tmp_path / "second.csv")]) == 2
    assert "time_s steps by 0.01 s after row 1, but the rig samples every 0.005 s" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["serial", "canopen"])
def test_ctrl_c_on_rig_run_stops_the_rig_and_leaves_a_complete_log(kind, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run.csv"
    process = subprocess.Popen(
        [sys.executable, "-m", "rig.cli", "run", str(write_test_config(kind, tmp_path)), "--experiment",
         str(CONFIGS / "experiments" / "prbs.toml"), "--out", str(out), "--duration", "60", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=CONFIGS.parent,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # also when the suite runs in the background
    try:
        deadline = time.monotonic() + 30
        while (not out.exists() or out.read_text().count("\n") < 20) and time.monotonic() < deadline:
            time.sleep(0.05)  # wait until samples are streaming
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == 130, stderr
    assert "rig: interrupted" in stderr
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a torn last line would warn
        record = read_log(out)  # closed cleanly: every row readable
    assert 10 <= record.num_samples < 12000
    assert np.all(np.diff(record.time_s) > 0)


def test_a_short_device_clocked_run_says_nothing_meaningless(tmp_path, capsys, no_leaks):
    """Every setpoint of a short run is queued before the device starts: the smallest lead is not measured,
    and the summary says so in words; no line prints a number it does not have ("nan")."""
    out = tmp_path / "run.csv"
    assert main(["run", str(CONFIGS / "sim_serial.toml"), "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(out), "--duration", "0.1"]) == 0
    printed = capsys.readouterr().out
    assert "nan" not in printed.lower() and "send lateness" not in printed
    assert "held        0 (setpoints that missed their instant; smallest lead" in printed
