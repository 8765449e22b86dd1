"""The simulated rigs of the ``rig run --live`` and ``rig import`` tests: ``configs/sim_<kind>.toml`` at a modest
rate, on a bus of its own."""

from __future__ import annotations

from pathlib import Path

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
RATE_HZ = 200.0  # as the transport tests: a modest rate that a loaded CI host keeps


def sim_rig_config(directory: Path, kind: str = "canopen", mode: str | None = None, bus: str = "live") -> Path:
    """``configs/sim_<kind>.toml`` at 200 Hz with a lenient watchdog, on the virtual bus ``<bus>_<directory>``;
    ``mode`` sets the CANopen streaming mode."""
    plant = (CONFIGS / "plants" / "precision_gearbox.toml").read_text()
    plant = plant.replace("sample_period_s = 0.001", f"sample_period_s = {1 / RATE_HZ!r}")
    plant = plant.replace("frequency_hz = 120.0", "frequency_hz = 40.0")  # below this rate's Nyquist frequency
    (directory / "plant.toml").write_text(plant)
    lines = []
    for line in (CONFIGS / f"sim_{kind}.toml").read_text().splitlines():
        if line.startswith("sample_rate_hz"):
            line = f"sample_rate_hz = {RATE_HZ!r}"
        elif line.startswith("plant ="):
            line = f'plant = "{directory / "plant.toml"}"'
        elif line.startswith("feedback_timeout_s"):
            line = "feedback_timeout_s = 0.5"
        elif line.startswith("url = "):
            scheme = line.split('"')[1].split(":")[0]
            line = f'url = "{scheme}://virtual/{bus}_{directory.name}"'  # one bus per test
        elif line.startswith("sdo_timeout_s") and mode is not None:
            line += f'\nmode = "{mode}"'
        lines.append(line)
    path = directory / f"sim_{kind}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path
