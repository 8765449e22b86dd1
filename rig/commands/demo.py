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
                        help="report directory (default: ./demo-report)")
    parser.add_argument("--transport", choices=("canopen", "can", "serial"), default="canopen",
                        help="wire protocol between the driver and the simulated rig (default: canopen)")
    parser.add_argument("--quick", action="store_true", help="shorter experiments (for tests and a first look)")
    parser.add_argument("--json", action="store_true",
                        help='print {"report": path, "rows": [[quantity, true, paper, coupled], ...]} as JSON')
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from rig.demo import FULL_PLAN, QUICK_PLAN, format_summary, run_demo, summary_rows

    steps, progress = _progress_bars(per_sample=sys.stderr.isatty()) if not args.json else (None, None)
    outcome = run_demo(args.out, args.transport, QUICK_PLAN if args.quick else FULL_PLAN, steps, progress)
    if args.json:
        print(json.dumps({"report": str(outcome.report_index), "rows": [list(row) for row in summary_rows(outcome)]}))
    else:
        print(format_summary(outcome))
        print(f"\nreport: {outcome.report_index}")
    return exit_codes.SUCCESS


def _progress_bars(per_sample: bool) -> tuple[Callable, Callable | None]:
    """A line per step, and on a terminal a per-sample bar for each experiment (both on stderr)."""
    from tqdm import tqdm

    @contextlib.contextmanager
    def step(description: str) -> Iterator[None]:
        print(f"- {description}", file=sys.stderr, flush=True)
        yield

    def experiment(name: str, samples: int) -> Callable[[int, int], None]:
        bar = tqdm(total=samples, desc=f"  {name}", unit="sample", file=sys.stderr, leave=False,
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
