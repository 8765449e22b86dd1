"""Soak: a long run at 1 kHz over the simulated CANopen rig with random frame loss.

Prints whether memory stays bounded (RSS sampled over the run), whether every sample is accounted for
(received + flagged LOST = sent, from the log written to disk), and whether any thread, virtual CAN bus or
file descriptor outlives the run.

    .venv/bin/python benchmarks/soak_canopen.py [--duration 600] [--drop 0.001]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from identify.experiment_record import SampleFlag  # noqa: E402
from rig.log_metadata import experiment_log_metadata  # noqa: E402
from rig.transports.simulated import simulated_rig  # noqa: E402
from rig.experiment_config import load_experiment_config  # noqa: E402
from rig.log_file import LogWriter, read_log  # noqa: E402
from rig.rig_config import load_rig_config  # noqa: E402
from rig.runner import run_experiment  # noqa: E402
from rig.transports import open_transport  # noqa: E402
from sim_backend.faults import parse_fault_spec  # noqa: E402


def rss_mib() -> float:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    parser.add_argument("--drop", type=float, default=0.001, help="random feedback frame loss (default 0.001)")
    args = parser.parse_args()
    from can.interfaces import virtual

    config = load_rig_config(ROOT / "configs" / "sim_canopen.toml")
    excitation = load_experiment_config(ROOT / "configs" / "experiments" / "prbs.toml")
    command = np.resize(excitation.command_rad, int(round(args.duration * config.sample_rate_hz)))
    faults = parse_fault_spec(f"drop={args.drop!r}")
    threads_before, buses_before, fds_before = set(threading.enumerate()), set(virtual.channels), open_fds()
    rss: list[tuple[float, float]] = [(0.0, rss_mib())]
    started = time.perf_counter()

    def sample_rss(done: int, late: int) -> None:
        if done % 10_000 == 0:
            rss.append((time.perf_counter() - started, rss_mib()))

    with tempfile.TemporaryDirectory() as directory:
        out = Path(directory) / "soak.csv"
        with contextlib.ExitStack() as stack:
            url, gearbox = stack.enter_context(simulated_rig(config, command, faults))
            transport = open_transport(url, **config.transport_options())
            log = LogWriter(out, experiment_log_metadata(config, excitation, gearbox, command.size,
                                                         {"spec": f"drop={args.drop!r}", "seed": 0}),
                            flush_every=10, flush_interval_s=0.05)  # as rig run writes its logs
            # a shared, loaded machine can stall this process for more than the config's 0.1 s watchdog:
            # the soak measures accounting and leaks, so it does not stop on a stall
            summary = run_experiment(transport, command, log, feedback_timeout_s=2.0,
                                     late_tolerance_s=config.late_tolerance_s, progress=sample_rss)
        rss.append((time.perf_counter() - started, rss_mib()))
        record = read_log(out)
    time.sleep(0.2)
    leaked_threads = [t.name for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    leaked_buses = sorted(set(virtual.channels) - buses_before)
    lost_flagged = int(np.count_nonzero(record.flags & SampleFlag.LOST))
    received = int(np.count_nonzero(np.isfinite(record.angle_rad)))
    injected = len(faults.lost_feedback(command.size))
    first_half = max(value for t, value in rss if t <= rss[-1][0] / 2)
    print(f"# soak: {args.duration:g} s at {config.sample_rate_hz:g} Hz over simulated CANopen, "
          f"{100 * args.drop:g} % random feedback loss, load average {os.getloadavg()[0]:.2f}")
    print("| sent | in log | received | flagged LOST (injected) | received + lost = sent | late (%) "
          "| RSS start / peak first half / peak / end (MiB) | leaked threads / buses / fds |")
    print("|---|---|---|---|---|---|---|---|")
    peak = max(value for _, value in rss)
    print(f"| {summary.samples} | {record.num_samples} | {received} | {lost_flagged} ({injected}) | "
          f"{'yes' if received + lost_flagged == summary.samples == record.num_samples else 'NO'} | "
          f"{summary.late} ({100 * summary.late / summary.samples:.2f} %) | "
          f"{rss[0][1]:.0f} / {first_half:.0f} / {peak:.0f} / {rss[-1][1]:.0f} | "
          f"{len(leaked_threads)} / {len(leaked_buses)} / {open_fds() - fds_before} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
