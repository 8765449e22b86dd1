"""``rig demo [--out DIR] [--transport canopen|can|serial]``: the whole chain on the simulated rig."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

from rig import exit_codes


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run the whole chain on the simulated rig and write a report",
        description=(
            "Drive the simulated precision gearbox over a real wire protocol: design and run the steady-state "
            "experiment, the PRBS and the cyclic random experiments, bound the backlash and the linear block "
            "by set membership (paper and coupled methods), identify the Hammerstein model, and diagnose a "
            "nominal model that lacks the backlash. Prints a summary table and writes an HTML report."
        ),
    )
    parser.add_argument("--out", type=Path, default=Path("demo-report"), metavar="DIR",
                        help="report directory (default: ./demo-report): a new or empty one, or an earlier report of "
                             "rig; another non-empty directory is refused unless --force")
    parser.add_argument("--force", action="store_true", help="write into an --out directory that holds other files")
    parser.add_argument("--transport", choices=("canopen", "can", "serial"), default="canopen",
                        help="wire protocol between the driver and the simulated rig (default: canopen)")
    parser.add_argument("--quick", action="store_true", help="shorter experiments (for tests and a first look)")
    parser.add_argument("--json", action="store_true",
                        help='print {"report": path, "rows": [[quantity, true, paper, coupled], ...], "commands": '
                             '[...]} as JSON (the commands give the rows again from the saved logs, run in --out)')
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from rig.demo import FULL_PLAN, QUICK_PLAN, format_summary, reproduce_commands, run_demo, summary_rows
    from rig.output_paths import check_report_dir, mark_report_dir, writing

    check_report_dir(args.out, "--out", force=args.force)  # before minutes of experiments
    steps, progress = _progress_bars(per_sample=sys.stderr.isatty()) if not args.json else (None, None)
    with writing(args.out, "--out"):
        args.out.mkdir(parents=True, exist_ok=True)
        mark_report_dir(args.out)  # its logs go in first
        outcome = run_demo(args.out, args.transport, QUICK_PLAN if args.quick else FULL_PLAN, steps, progress)
    commands = [command for _, command in reproduce_commands(outcome)]
    if args.json:
        print(json.dumps({"report": str(outcome.report_index), "rows": [list(row) for row in summary_rows(outcome)],
                          "commands": commands}))
    else:
        print(format_summary(outcome))
        print(f"\nreport: {outcome.report_index}")
        print(f"the same numbers from the saved logs, run in {args.out}:")
        print("\n".join(f"  {command}" for command in commands))
    return exit_codes.SUCCESS


def _progress_bars(per_sample: bool) -> tuple[Callable, Callable | None]:
    """On a terminal, a bar over the demo's steps and a per-sample bar under it for each experiment;
    elsewhere a line per step (all on stderr)."""
    from tqdm import tqdm

    from rig.demo import DEMO_STEPS

    steps_bar = tqdm(total=DEMO_STEPS, unit="step", file=sys.stderr, position=0, disable=not per_sample,
                     bar_format="{desc} |{bar}| {n_fmt}/{total_fmt} steps [{elapsed}]")

    @contextlib.contextmanager
    def step(description: str) -> Iterator[None]:
        if per_sample:
            steps_bar.set_description_str(description)
        else:
            print(f"- {description}", file=sys.stderr, flush=True)
        yield
        steps_bar.update(1)
        if steps_bar.n >= DEMO_STEPS:
            steps_bar.close()

    def experiment(name: str, samples: int) -> Callable[[int, int], None]:
        bar = tqdm(total=samples, desc=f"  {name}", unit="sample", file=sys.stderr, leave=False, position=1,
                   mininterval=0.2)

        def update(done: int, late: int) -> None:
            bar.n = done
            if done == samples:
                bar.close()
            elif done % 100 == 0:
                bar.set_postfix(late=late, refresh=False)
                bar.refresh()

        return update

    return step, (experiment if per_sample else None)
