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
            "noise with S + 1 (both are recorded in the log); without it the configs' seeds are used. A plant "
            "whose backlash wears (backlash_growth) also gets LOG's truth file, LOG with .truth.csv for its "
            "suffix: the true play over time (rig.truth_file)."
        ),
    )
    parser.add_argument("plant", metavar="PLANT.toml", help="plant config (configs/plants/*.toml)")
    parser.add_argument("--excitation", metavar="EXC.toml", required=True,
                        help="experiment config (configs/experiments/*.toml)")
    parser.add_argument("--out", metavar="LOG", required=True,
                        help="log file to write (CSV, rig-log v1); an existing file is refused unless --force")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")
    parser.add_argument("--seed", type=int, default=None, metavar="S", help="seed of the excitation (S) and noise (S+1)")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="cut the excitation or repeat it cyclically to S seconds (an endurance run: "
                             "--duration 3600); the simulated clock runs as fast as the computer does")
    parser.add_argument("--json", action="store_true", help='print {"log": path, "samples": N} as JSON')
    parser.set_defaults(handler=run)


def _json_number(value: float) -> float | str:
    return value if math.isfinite(value) else str(value)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from identify import __version__
    from identify.backlash_wear import wearing_backlash_of
    from identify.experiment_record import OFFLINE_TRANSPORT, ExperimentMetadata
    from rig.experiment_config import load_experiment_config
    from rig.log_file import LogWriter
    from rig.truth_file import truth_path_for, write_play_truth
    from sim_backend.plant_config import describe_noise, load_plant_config, plant_config_to_toml

    from rig.output_paths import atomic_output, check_output_file

    if args.seed is not None and args.seed < 0:
        raise ValueError(f"--seed: expected an integer >= 0, got {args.seed}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration: expected a number of seconds > 0, got {args.duration}")
    check_output_file(args.out, "--out", inputs=[args.plant, args.excitation], force=args.force)
    plant_config = load_plant_config(args.plant)
    excitation = load_experiment_config(args.excitation, seed=args.seed)
    gearbox = plant_config.gearbox(seed=None if args.seed is None else args.seed + 1)
    truth_path = None
    if wearing_backlash_of(gearbox.plant) is not None:
        truth_path = truth_path_for(args.out)
        check_output_file(truth_path, "--out's truth file", inputs=[args.plant, args.excitation, args.out],
                          force=args.force)
    command = excitation.command_rad
    if args.duration is not None:
        command = excitation.repeated(max(1, int(round(args.duration / gearbox.sample_period_s))))
    run_ = gearbox.simulate(command)
    noise = gearbox.calibrated_for(command).noise  # the SNR-given level, resolved
    metadata = ExperimentMetadata(
        sample_period_s=gearbox.sample_period_s,
        source=plant_config.name,
        transport=OFFLINE_TRANSPORT,
        encoder_bits=gearbox.encoder.bits,
        noise_kind=noise.kind,
        noise_bound_rad=noise.noise_bound_rad + gearbox.encoder.quantization_bound_rad,  # |y_t - w_t| <= this
        excitation=excitation.name,
        excitation_seed=excitation.seed,
        seed=gearbox.seed,
        config={"plant": str(args.plant), "plant_toml": plant_config_to_toml(plant_config),
                "excitation": excitation.metadata(), "noise": describe_noise(noise),
                "num_samples": int(command.size),
                "excitation_samples": int(excitation.command_rad.size),  # cut or repeated cyclically to num_samples
                "excitation_repeat": excitation.repetition,
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
    truth_rows = None
    if truth_path is not None and run_.play is not None:
        with atomic_output(truth_path, "--out's truth file", force=args.force) as written:
            truth_rows = write_play_truth(written, run_.time_s, run_.play, Path(args.out).name,
                                          gearbox.sample_period_s)
    if args.json:
        document = {"log": str(args.out), "samples": len(run_)}
        if truth_path is not None:
            document["truth"] = str(truth_path)
        print(json.dumps(document))
    else:
        print(f"plant       {plant_config.name} ({args.plant})")
        print(f"excitation  {excitation.name} ({excitation.kind}, seed {excitation.seed})")
        print(f"noise       {noise.kind}, bound {noise.noise_bound_rad:g} rad, seed {gearbox.seed}")
        print(f"samples     {len(run_)} at {gearbox.sample_period_s:g} s")
        print(f"log         {args.out}")
        if truth_path is not None and run_.play is not None:
            print(f"truth       {truth_path} ({truth_rows} rows: the play wears from "
                  f"{run_.play.play_rad[0]:.6g} to {run_.play.play_rad[-1]:.6g} rad)")
    sys.stdout.flush()
    return exit_codes.SUCCESS
