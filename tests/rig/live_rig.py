"""The simulated rig of the ``rig run --live`` tests: ``configs/sim_canopen.toml`` at a modest rate."""

from __future__ import annotations

from pathlib import Path

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
RATE_HZ = 200.0  # as the transport tests: a modest rate that a loaded CI host keeps


def live_rig_config(directory: Path) -> Path:
    """``configs/sim_canopen.toml`` at 200 Hz with a lenient watchdog, on a bus of its own."""
    plant = (CONFIGS / "plants" / "precision_gearbox.toml").read_text()
    plant = plant.replace("sample_period_s = 0.001", f"sample_period_s = {1 / RATE_HZ!r}")
    plant = plant.replace("frequency_hz = 120.0", "frequency_hz = 40.0")  # below this rate's Nyquist frequency
    (directory / "plant.toml").write_text(plant)
    lines = []
    for line in (CONFIGS / "sim_canopen.toml").read_text().splitlines():
        if line.startswith("sample_rate_hz"):
            line = f"sample_rate_hz = {RATE_HZ!r}"
        elif line.startswith("plant ="):
            line = f'plant = "{directory / "plant.toml"}"'
        elif line.startswith("feedback_timeout_s"):
            line = "feedback_timeout_s = 0.5"
        elif line.startswith("url = "):
            line = f'url = "canopen://virtual/live_{directory.name}"'
        lines.append(line)
    path = directory / "sim_canopen.toml"
    path.write_text("\n".join(lines) + "\n")
    return path
