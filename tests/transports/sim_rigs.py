"""Helpers shared by the transport tests: simulated rigs at a modest rate (200 Hz) for every transport."""

from __future__ import annotations

import contextlib
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from rig.rig_config import load_rig_config

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
TEST_RATE_HZ = 200.0


def write_test_plant(directory: Path) -> Path:
    """The precision gearbox plant, run at the test rate."""
    text = (CONFIGS / "plants" / "precision_gearbox.toml").read_text()
    text = text.replace("sample_period_s = 0.001", f"sample_period_s = {1 / TEST_RATE_HZ!r}")
    text = text.replace("frequency_hz = 120.0", "frequency_hz = 40.0")  # below the test rate's Nyquist frequency
    path = directory / "plant_test_rate.toml"
    path.write_text(text)
    return path


def write_test_config(kind: str, directory: Path) -> Path:
    """``configs/sim_<kind>.toml`` at the test rate, pointing at the test plant."""
    plant = write_test_plant(directory)
    text = (CONFIGS / f"sim_{kind}.toml").read_text()
    lines = []
    for line in text.splitlines():
        if line.startswith("sample_rate_hz"):
            line = f"sample_rate_hz = {TEST_RATE_HZ!r}"
        elif line.startswith("plant ="):
            line = f'plant = "{plant}"'
        elif line.startswith("late_tolerance_s"):
            line = "late_tolerance_s = 0.0025"
        elif line.startswith("feedback_timeout_s"):
            line = "feedback_timeout_s = 0.5"
        elif line.startswith("lead_s"):
            continue  # the transport's default lead (0.25 s), shorter than the tests' runs: the lead is measured
        elif line.startswith(("url = \"canopen://virtual/", "url = \"can://virtual/")):
            scheme = line.split('"')[1].split(":")[0]
            line = f'url = "{scheme}://virtual/test_{directory.name}"'  # one bus per test
        lines.append(line)
    path = directory / f"sim_{kind}_test.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _open_fds() -> set[str]:
    return {os.readlink(f"/proc/self/fd/{fd}") for fd in os.listdir("/proc/self/fd")
            if os.path.exists(f"/proc/self/fd/{fd}")}


@pytest.fixture
def no_leaks():
    """Fail the test if it leaves threads running, python-can virtual buses connected or ptys open."""
    from can.interfaces import virtual

    before = set(threading.enumerate())
    channels_before = set(virtual.channels)
    fds_before = _open_fds()
    yield
    for _ in range(50):
        leaked = [thread for thread in threading.enumerate() if thread not in before and thread.is_alive()]
        if not leaked:
            break
        threading.Event().wait(0.02)
    else:
        raise AssertionError(f"threads leaked: {[thread.name for thread in leaked]}")
    buses = {channel: len(queues) for channel, queues in virtual.channels.items() if channel not in channels_before}
    assert not buses, f"virtual CAN buses left connected: {buses}"
    ptys = sorted(fd for fd in _open_fds() - fds_before if fd.startswith(("/dev/pts", "/dev/ptmx")))
    assert not ptys, f"ptys left open: {ptys}"


@contextlib.contextmanager
def simulated(kind: str, directory: Path, transport_options: dict | None = None, **fault_injection):
    """(config, transport, gearbox, simulated drive) for a simulated rig of ``kind``; everything closed on exit.
    ``transport_options`` override the config's (e.g. ``{"mode": "csp"}``)."""
    from rig.transports.simulated import start_simulated_devices
    from rig.transports import open_transport
    from sim_backend.plant_config import load_plant_config

    config = load_rig_config(write_test_config(kind, directory))
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    with contextlib.ExitStack() as stack:
        url, drive = start_simulated_devices(config, gearbox, stack, **fault_injection)
        transport = open_transport(url, **dict(config.transport_options(), **(transport_options or {})))
        stack.callback(transport.close)
        yield config, transport, gearbox, drive


class ListSink:
    def __init__(self) -> None:
        self.rows: list[tuple] = []
        self.closed = False

    def append(self, time_s, command_rad, angle_rad, encoder_counts=None, flags=0) -> None:
        self.rows.append((time_s, command_rad, angle_rad, encoder_counts, int(flags)))

    def close(self) -> None:
        self.closed = True


def excitation(num_samples: int = 120) -> np.ndarray:
    rng = np.random.default_rng(5)
    return np.repeat(rng.uniform(-1.0, 1.0, num_samples // 4), 4)  # held random levels, within the rate limit
