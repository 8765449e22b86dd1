"""``rig simulate PLANT.toml --excitation EXC.toml --out LOG``: run an excitation through the simulated
plant offline (no wire) and write a ``rig-log v1`` file."""

from __future__ import annotations

import argparse
import json
import math
import sys

from rig import exit_codes


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="run an excitation through a simulated plant offline and write a log",
        description=(
            "Run the excitation of an experiment config through the simulated gearbox of a plant config, "
            "offline (no wire), and write a rig-log v1 file. --seed S seeds the excitation with S and the "
            "noise with S + 1 (both are recorded in the log); without it the configs' seeds are used."
        ),
    )
    parser.add_argument("plant", metavar="PLANT.toml", help="plant config (configs/plants/*.toml)")
    parser.add_argument("--excitation", metavar="EXC.toml", required=True,
                        help="experiment config (configs/experiments/*.toml)")
    parser.add_argument("--out", metavar="LOG", required=True,
                        help="log file to write (CSV, rig-log v1); an existing file is refused unless --force")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")
    parser.add_argument("--seed", type=int, default=None, metavar="S", help="seed of the excitation (S) and noise (S+1)")
    parser.add_argument("--json", action="store_true", help='print {"log": path, "samples": N} as JSON')
    parser.set_defaults(handler=run)


def _json_number(value: float) -> float | str:
    return value if math.isfinite(value) else str(value)


def run(args: argparse.Namespace) -> int:
    from identify import __version__
    from identify.experiment_record import ExperimentMetadata
    from rig.experiment_config import load_experiment_config
    from rig.log_file import LogWriter
    from sim_backend.plant_config import describe_noise, load_plant_config, plant_config_to_toml

    from rig.output_paths import atomic_output, check_output_file

    if args.seed is not None and args.seed < 0:
        raise ValueError(f"--seed: expected an integer >= 0, got {args.seed}")
    check_output_file(args.out, "--out", inputs=[args.plant, args.excitation], force=args.force)
    plant_config = load_plant_config(args.plant)
    excitation = load_experiment_config(args.excitation, seed=args.seed)
    gearbox = plant_config.gearbox(seed=None if args.seed is None else args.seed + 1)
    run_ = gearbox.simulate(excitation.command_rad)
    noise = gearbox.calibrated_for(excitation.command_rad).noise  # the SNR-given level, resolved
    metadata = ExperimentMetadata(
        sample_period_s=gearbox.sample_period_s,
        source=plant_config.name,
        transport="offline",
        encoder_bits=gearbox.encoder.bits,
        noise_kind=noise.kind,
        noise_bound_rad=noise.noise_bound_rad + gearbox.encoder.quantization_bound_rad,  # |y_t - w_t| <= this
        excitation=excitation.name,
        excitation_seed=excitation.seed,
        seed=gearbox.seed,
        config={"plant": str(args.plant), "plant_toml": plant_config_to_toml(plant_config),
                "excitation": excitation.metadata(), "noise": describe_noise(noise),
                "additive_noise_bound_rad": _json_number(noise.noise_bound_rad),
                "quantization_bound_rad": gearbox.encoder.quantization_bound_rad,
                "encoder": {"bits": gearbox.encoder.bits, "multi_turn_bits": gearbox.encoder.multi_turn_bits,
                            "signed": gearbox.encoder.signed, "direction": gearbox.encoder.direction,
                            "offset_counts": gearbox.encoder.offset_counts}},
        software_version=__version__,
    )
    with atomic_output(args.out, "--out", force=args.force) as written, LogWriter(written, metadata,
                                                                                    flush_every=4096,
                                                                                    stamp_start=True) as log:
        log.append_many(run_.time_s, run_.command_rad, run_.measured_angle_rad, run_.encoder_counts)
    if args.json:
        print(json.dumps({"log": str(args.out), "samples": len(run_)}))
    else:
        print(f"plant       {plant_config.name} ({args.plant})")
        print(f"excitation  {excitation.name} ({excitation.kind}, seed {excitation.seed})")
        print(f"noise       {noise.kind}, bound {noise.noise_bound_rad:g} rad, seed {gearbox.seed}")
        print(f"samples     {len(run_)} at {gearbox.sample_period_s:g} s")
        print(f"log         {args.out}")
    sys.stdout.flush()
    return exit_codes.SUCCESS
