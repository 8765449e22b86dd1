"""The whole chain with the drive's torque: `rig run` on the simulated servo over CANopen, the log's torque column,
`rig diagnose`'s workflow with and without it.

The simulated rig is ``configs/sim_pendulum_canopen.toml``: the STS3215 servo with a pendulum arm
(``configs/plants/pendulum_servo.toml``) behind a CiA 402 drive whose TPDO1 carries its torque actual value 0x6077
(``configs/eds/sim_servo_drive_cia402.eds``). Two truths, one model (the plant without the arm's weight):

* ``weight``: the plant as it is: the arm's weight sags the servo;
* ``sensor error``: no weight, and a once-per-revolution error of the load encoder sized and phased to the weight's
  sag on this command (fitted offline: a sin(angle) + b cos(angle) + c on the sag), so the angle shows the same
  bend; the drive feels nothing of it.

Each record is run through the CANopen master (in-process, on python-can's virtual bus, in real time) and diagnosed
from the model without the weight, once from the angle alone and once with the log's ``drive_torque`` column and its
scale (the summary's ``drive_torque_nm_per_unit``). The table gives the verdict, the names and what the torque check
said: T, the once-per-revolution torque found (per mille of the rated torque), and W, the torque a weight giving
the angle's sag would put on the drive through the model's drive train.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python benchmarks/discrepancy_rig_torque.py [--duration 25] [--noise-bound 0.002]``.
"""

from __future__ import annotations

import argparse
import math
import re
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
WEIGHT_KEYS = ("pendulum_mass_kg", "pendulum_length_m")


def slow_sine(duration_s: float, sample_period_s: float) -> np.ndarray:
    """1.2 rad at 0.05 Hz, faded in over 5 s: the arm swings slowly through +-69 degrees."""
    t = np.arange(int(round(duration_s / sample_period_s))) * sample_period_s
    return 1.2 * np.sin(2 * math.pi * 0.05 * t) * np.minimum(1.0, t / 5.0)


def plant_texts(command: np.ndarray) -> dict[str, str]:
    """Plant TOML texts: the model (no weight), and the two truths."""
    from sim_backend.plant_config import plant_config_from_toml_text

    base = (CONFIGS / "plants" / "pendulum_servo.toml").read_text()
    model = "\n".join(line for line in base.splitlines() if not line.startswith(WEIGHT_KEYS)) + "\n"
    with_weight = plant_config_from_toml_text(base).plant.simulate(command)
    without = plant_config_from_toml_text(model).plant.simulate(command)
    settled = slice(command.size // 5, None)
    basis = np.c_[np.sin(without), np.cos(without), np.ones_like(without)][settled]
    (a, b, _), *_ = np.linalg.lstsq(basis, (with_weight - without)[settled], rcond=None)
    sensor = (model + "\n[[blocks]]\ntype = \"encoder_error\"\n"
              f"once_per_rev_rad = {math.hypot(a, b)!r}\nonce_per_rev_phase_rad = {math.atan2(b, a)!r}\n")
    return {"model": model, "weight": base, "sensor error": sensor}


def run_on_rig(plant_text: str, command: np.ndarray, folder: Path, name: str) -> Path:
    """``rig run`` of ``command`` on the simulated servo with ``plant_text``; the log's path."""
    import contextlib
    import io

    from rig.cli import main

    plant = folder / f"{name}.toml"
    plant.write_text(plant_text)
    rig = (CONFIGS / "sim_pendulum_canopen.toml").read_text()
    rig = rig.replace('plant = "plants/pendulum_servo.toml"', f'plant = "{plant}"')
    rig = rig.replace('drive_eds = "eds/sim_servo_drive_cia402.eds"',
                      f'drive_eds = "{CONFIGS / "eds" / "sim_servo_drive_cia402.eds"}"')
    config = folder / f"rig_{name}.toml"
    config.write_text(rig)
    experiment = folder / f"{name}_command.csv"
    experiment.write_text("command_rad\n" + "".join(f"{value!r}\n" for value in command.tolist()))
    log = folder / f"{name}.csv"
    with contextlib.redirect_stdout(io.StringIO()):  # the run's JSON summary: the log has it too
        code = main(["run", str(config), "--experiment", str(experiment), "--out", str(log), "--json"])
    if code != 0:
        raise SystemExit(f"rig run failed for {name} (exit {code})")
    return log


def diagnose(log: Path, model_text: str, noise_bound_rad: float, with_torque: bool) -> tuple[str, float]:
    from identify.model_discrepancy import diagnose_model
    from rig.log_file import read_log, unusable_as_missing
    from sim_backend.plant_config import plant_config_from_toml_text

    record = read_log(log)
    angle, _ = unusable_as_missing(record)
    started = time.perf_counter()
    result = diagnose_model(record.command_rad, angle, noise_bound_rad, record.sample_period_s,
                            plant_config_from_toml_text(model_text).plant,
                            drive_torque=record.drive_torque if with_torque else None,
                            drive_torque_nm_per_unit=record.metadata.extra["summary"].get("drive_torque_nm_per_unit"))
    names = ", ".join(result.missing_effects) or "nothing named"
    left_open = result.ambiguous_between or tuple(candidate.effect for candidate in result.undecided)
    if left_open:
        names += f"; left open: {' or '.join(left_open)}"
    beyond = re.search(r"encoder_error would give the output of \w+ as well, but only as an error of (\S+) rad",
                       result.verdict_reason)
    if beyond:  # a look-alike fitted beyond what a working device has: the reason says so
        names += f" (an encoder error of {beyond.group(1)} rad would fit, beyond a working encoder's)"
    check = result.load_torque_check
    check = "" if check is None else (f"; torque check {check.outcome} (T {check.torque:.3g} +- {check.torque_sigma:.2g}, "
                                      f"a weight giving the sag: W {check.weight_torque:.3g})")
    return f"{result.verdict}: {names}{check}", time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=25.0, help="seconds of the slow sine (default 25)")
    parser.add_argument("--noise-bound", type=float, default=0.002, help="rad (default 0.002)")
    args = parser.parse_args()
    command = slow_sine(args.duration, 0.01)
    texts = plant_texts(command)
    print(f"slow sine of 1.2 rad at 0.05 Hz, {command.size} samples at 100 Hz; noise bound {args.noise_bound:g} rad")
    print("| truth | torque samples | angle alone | with the drive's torque | seconds (alone, with) |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as directory:
        for truth in ("weight", "sensor error"):
            log = run_on_rig(texts[truth], command, Path(directory), truth.replace(" ", "_"))
            from rig.log_file import read_log

            torque = read_log(log).drive_torque
            samples = 0 if torque is None else int(np.isfinite(torque).sum())
            alone, alone_s = diagnose(log, texts["model"], args.noise_bound, False)
            with_torque, with_s = diagnose(log, texts["model"], args.noise_bound, True)
            print(f"| {truth} | {samples} of {command.size} | {alone} | {with_torque} | {alone_s:.1f}, {with_s:.1f} |")


if __name__ == "__main__":
    main()
