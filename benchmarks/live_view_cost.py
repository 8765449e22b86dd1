"""What ``rig run --live`` costs the capture.

Two tables:

1. The sample path: microseconds per row that the runner spends handing a row to the log, without the view
   (``LogWriter.append``) and with it (:class:`rig.live_view.ObservedSink`: the same append, then the
   feed's counters and a deque append), for 100 000 rows, best of 9.
2. Whole runs of the simulated CANopen rig at 1 kHz (``configs/sim_canopen.toml``), each in a process of its
   own: without the view, with the terminal view (stderr into a file: a frame every 2 s), with the terminal
   view as on a terminal (10 frames a second, ``--tty-rate``), and with a renderer that takes 0.5 s a frame.
   Per row: samples, lost, held (setpoints that missed the device's instant), the smallest lead, the
   process's CPU seconds, and the rows the view did not show.

The simulated devices run in the driver's process (python-can's virtual bus is in-process) and share the
two cores with the view's thread: on a real rig the drive keeps its own clock. Usage::

    python benchmarks/live_view_cost.py                 # 5 s runs
    python benchmarks/live_view_cost.py --duration 20 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

VARIANTS = ("no view", "terminal (file)", "terminal (10 fps)", "slow renderer (0.5 s/frame)")


def sample_path_table(rows: int = 100_000, repeats: int = 9) -> list[tuple[str, float]]:
    from identify.experiment_record import ExperimentMetadata
    from rig.live_view import LiveFeed, ObservedSink
    from rig.log_file import LogWriter

    names = ("LogWriter.append", "ObservedSink.append (--live)")
    best = dict.fromkeys(names, float("inf"))
    with tempfile.TemporaryDirectory() as folder:
        for attempt in range(repeats):  # the two interleaved, so that a busy moment of the host hits both
            for name in names:
                log = LogWriter(Path(folder) / f"{attempt}.csv", ExperimentMetadata(sample_period_s=1e-3),
                                flush_every=10, flush_interval_s=0.05)
                sink = log if name.startswith("LogWriter") else ObservedSink(log, LiveFeed())
                started = timeit.default_timer()
                for k in range(rows):
                    sink.append(k * 1e-3, 0.5, 0.49, 1234, 0)
                best[name] = min(best[name], timeit.default_timer() - started)
                log.close()
    return [(name, 1e6 * seconds / rows) for name, seconds in best.items()]


def _one_run(variant: str, duration: float, out: Path) -> dict:
    """In a child process: one ``rig run`` in ``variant``; prints its JSON with CPU seconds and the view line."""
    import contextlib
    import io

    from rig import live_view
    from rig.cli import main

    os.environ.pop("DISPLAY", None)
    os.environ["MPLBACKEND"] = "Agg"
    if variant == "terminal (10 fps)":
        real = live_view.TerminalRenderer

        def as_on_a_terminal(stream):
            renderer = real(stream)
            renderer.min_interval_s = live_view.FRAME_INTERVAL_S
            return renderer
        live_view.choose_renderer = as_on_a_terminal
    elif variant.startswith("slow"):
        class Slow(live_view.TerminalRenderer):
            min_interval_s = 0.0

            def draw(self, frame):
                super().draw(frame)
                time.sleep(0.5)
        live_view.choose_renderer = Slow
    argv = ["run", str(ROOT / "configs" / "sim_canopen.toml"), "--experiment",
            str(ROOT / "configs" / "experiments" / "prbs.toml"), "--out", str(out), "--duration", repr(duration),
            "--json"]
    if variant != "no view":
        argv.append("--live")
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(argv)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    result = json.loads(stdout.getvalue()) if code == 0 else {"error": stderr.getvalue().strip()[-200:]}
    view = [line for line in stderr.getvalue().splitlines() if line.startswith("live view:")]
    result.update(cpu_s=usage.ru_utime + usage.ru_stime, view=view[-1] if view else "")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=5.0, help="seconds per run (default 5)")
    parser.add_argument("--repeats", type=int, default=1, help="runs per variant (default 1)")
    parser.add_argument("--child", nargs=3, metavar=("VARIANT", "DURATION", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_one_run(args.child[0], float(args.child[1]), Path(args.child[2]))))
        return

    print(f"load average at start: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
    print("\n1. sample path, microseconds per row (100 000 rows, best of 9)")
    for name, microseconds in sample_path_table():
        print(f"   {name:<30} {microseconds:8.3f} us")

    print(f"\n2. rig run on the simulated CANopen rig, 1 kHz, {args.duration:g} s")
    print(f"   {'variant':<30} {'samples':>7} {'lost':>5} {'held':>5} {'min lead ms':>11} {'CPU s':>6}  view")
    with tempfile.TemporaryDirectory() as folder:
        for repeat in range(args.repeats):
            for number, variant in enumerate(VARIANTS):
                out = Path(folder) / f"{repeat}-{number}.csv"
                child = subprocess.run([sys.executable, __file__, "--child", variant, repr(args.duration), str(out)],
                                       capture_output=True, text=True, check=True)
                row = json.loads(child.stdout.strip().splitlines()[-1])
                if "error" in row:
                    print(f"   {variant:<30} error: {row['error']}")
                    continue
                lead = "n/a" if row["min_lead_s"] is None else f"{1e3 * row['min_lead_s']:.3g}"
                shown = row["view"].split("skipped while drawing, ")[-1].split(" (the log")[0] if row["view"] else "-"
                print(f"   {variant:<30} {row['samples']:>7} {row['lost']:>5} {row['held']:>5} {lead:>11} "
                      f"{row['cpu_s']:>6.2f}  {shown}")
    print(f"load average at end: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")


if __name__ == "__main__":
    main()
