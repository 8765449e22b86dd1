"""Sample timing of the rig driver against its simulated devices, per wire, at 1 kHz and 2 kHz, in three
conditions the script sets up and tears down itself:

(a) ``idle``: nothing else of ours runs;
(b) ``busy``: one CPU-hog process per core (both cores busy);
(c) ``stall``: idle, plus a 50 ms pause of the driver's own thread every 5 s (``--sim-faults stall``).

Per row: samples, lost (goal 0), held (setpoints that missed the device's instant; goal 0), the smallest
lead of a setpoint over its instant, late samples, CPU per 1000 samples, the CAN bus load, and who stalled:
the longest gap between two rows the runner filed (a pause of the host, stalls included, or a silence of
the device) and the longest garbage collection of the driver's process during the run. Every wire runs
on the device's clock with the default lead (100 ms): ``canopen`` with the default ``mode = "auto"``,
which streams interpolated position into the simulated drive's 64-record buffer (the lead sits in the
drive, at most the buffer less 2 records); ``canopen-csp`` forces cyclic synchronous position (one target
per SYNC, on the bus right after the SYNC before it: under one period of lead on the bus); ``serial`` and
``can`` speak protocol v2 (the device ticks, setpoints tagged with their tick). A v1 device is host-paced
and "held" does not apply to it (n/a).

The simulated serial device runs in a process of its own (``python -m sim_backend.serial_device``, on a pty),
as a real device is a microcontroller with its own clock: it shares neither the GIL nor the garbage
collector's pauses with the driver (``--serial-device thread`` runs it as a thread of the driver's process
instead, as ``rig run`` does). On a machine so loaded that the device's own process is starved, its ticks
run late and catch up in a burst, and ticks beyond the lead are HELD, which a real device would not do. The CAN devices run in
the driver's process (python-can's virtual bus is in-process), so they compete with it for the GIL and both
cores: a pause of the whole process (a full garbage collection, a starved process) stops their clock too,
and they catch up in a burst that the lead has to cover. "CPU per 1000 samples" is the driver's process
(for serial: without the device's). Usage::

    python benchmarks/transport_timing.py                   # 5 s per case
    python benchmarks/transport_timing.py --duration 60 --conditions idle busy stall
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rig.transports.simulated import start_simulated_devices  # noqa: E402
from rig.protocols.errors import ConfigError  # noqa: E402
from rig.rig_config import load_rig_config  # noqa: E402
from rig.runner import run_experiment  # noqa: E402
from rig.transports import open_transport  # noqa: E402
from sim_backend.plant_config import load_plant_config  # noqa: E402
from sim_backend.serial_device import serial_device_process  # noqa: E402


class _NullSink:
    def append(self, *row: object) -> None:
        pass

    def close(self) -> None:
        pass


def _config(kind: str, rate_hz: float, directory: Path):
    wire = "canopen" if kind == "canopen-csp" else kind
    text = (ROOT / "configs" / f"sim_{wire}.toml").read_text()
    if kind == "canopen-csp":  # cyclic synchronous position instead of the default's drive buffer
        text = text.replace("sdo_timeout_s = 0.5", 'sdo_timeout_s = 0.5\nmode = "csp"')
    text = text.replace("sample_rate_hz = 1000.0", f"sample_rate_hz = {rate_hz!r}")
    text = text.replace('plant = "plants/', f'plant = "{ROOT / "configs" / "plants"}/')
    text = text.replace("late_tolerance_s = 0.0005", f"late_tolerance_s = {0.5 / rate_hz!r}")
    # a shared, loaded machine can stall the process for more than the template's 0.1 s: measure, don't stop
    text = text.replace("feedback_timeout_s = 0.1", "feedback_timeout_s = 2.0")
    path = directory / f"{kind}_{rate_hz:g}.toml"
    path.write_text(text)
    return load_rig_config(path)


def measure(kind: str, rate_hz: float, duration_s: float, directory: Path, pending_cycles: int,
            stall_every_s: float | None = None, serial_device: str = "process") -> dict[str, object]:
    config = _config(kind, rate_hz, directory)
    # the plant's physics stay at its own 1 kHz; only the wall-clock rate of the loop changes here
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    num_samples = int(round(duration_s * rate_hz))
    command = 0.5 * np.sin(2 * np.pi * 0.5 * np.arange(num_samples) / rate_hz)
    stalls = [] if stall_every_s is None else [int(k * stall_every_s * rate_hz)
                                               for k in range(1, int(duration_s / stall_every_s) + 1)]

    progress_s: list[float] = []  # when the runner filed each row: the longest gap is the host's longest pause
    gc_pauses_s = [0.0]
    gc_started = [0.0]

    def stall(done: int, late: int) -> None:
        progress_s.append(time.perf_counter())
        while stalls and done >= stalls[0]:
            stalls.pop(0)
            time.sleep(STALL_S)

    def gc_timer(phase: str, info: dict) -> None:
        if phase == "start":
            gc_started[0] = time.perf_counter()
        else:
            gc_pauses_s.append(time.perf_counter() - gc_started[0])

    with contextlib.ExitStack() as stack:
        clocked = {"sample_period_s": 1.0 / rate_hz} if kind in ("serial", "can") else {}  # the device's own tick
        if kind == "serial" and serial_device == "process":
            port = stack.enter_context(serial_device_process(
                config.simulation.plant_path, seed=config.simulation.seed, sample_period_s=1.0 / rate_hz,
                drive_counts_per_revolution=config.drive.counts_per_revolution))
            url, device = f"serial://{port}", None
        else:
            url, device = start_simulated_devices(config, gearbox, stack, **clocked)
        transport = open_transport(url, **config.transport_options())
        gc.callbacks.append(gc_timer)  # the collections of the run only
        try:
            summary = run_experiment(transport, command, _NullSink(), feedback_timeout_s=config.feedback_timeout_s,
                                     late_tolerance_s=config.late_tolerance_s, pending_cycles=pending_cycles,
                                     progress=stall)
        finally:
            gc.callbacks.remove(gc_timer)
        measured_load = device.bus_load() if hasattr(device, "bus_load") else None
        if measured_load is None and hasattr(device, "bits"):
            measured_load = device.bits / (summary.wall_s * device.bitrate)
    device_clocked = not np.isnan(summary.min_lead_s)
    row: dict[str, object] = {
        "transport": kind, "rate_hz": rate_hz, "samples": summary.samples, "lost": summary.lost,
        "held": summary.held if device_clocked else None,
        "min_lead_ms": 1e3 * summary.min_lead_s if device_clocked else None,
        "late": summary.late, "duplicate": summary.duplicate, "load_average": os.getloadavg()[0],
        "cpu_ms_per_1000": 1e6 * summary.cpu_s / max(summary.samples, 1),
        "host_gap_ms": 1e3 * float(np.max(np.diff(progress_s), initial=0.0)), "gc_ms": 1e3 * max(gc_pauses_s),
    }
    load = getattr(transport, "load", None)
    if load is not None:
        row.update(bus_load_pct=100 * load.load, bus_limit_hz=load.max_rate_hz,
                   measured_load_pct=None if measured_load is None else 100 * measured_load)
    return row


STALL_S = 0.05


@contextlib.contextmanager
def condition(name: str):
    """``busy``: one CPU-hog process per core for the duration of the block."""
    hogs = []
    if name == "busy":
        hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 2)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=5.0, help="seconds per case (default 5)")
    parser.add_argument("--rates", type=float, nargs="+", default=[1000.0, 2000.0])
    parser.add_argument("--transports", nargs="+", default=["canopen", "canopen-csp", "serial", "can"],
                        choices=["canopen", "canopen-csp", "serial", "can"])
    parser.add_argument("--conditions", nargs="+", default=["idle", "busy", "stall"],
                        choices=["idle", "busy", "stall"])
    parser.add_argument("--pending-cycles", type=int, default=4,
                        help="feedback later than this many cycles is LOST (the runner's default: 4)")
    parser.add_argument("--serial-device", choices=["process", "thread"], default="process",
                        help="run the simulated serial device in a process of its own (default) or as a thread of "
                             "the driver's process")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        for name in args.conditions:
            with condition(name):
                for kind in args.transports:
                    for rate in args.rates:
                        try:
                            row = measure(kind, rate, args.duration, Path(directory), args.pending_cycles,
                                          stall_every_s=5.0 if name == "stall" else None,
                                          serial_device=args.serial_device)
                        except ConfigError as err:  # e.g. a rate the bus cannot carry: refused on load
                            row = {"transport": kind, "rate_hz": rate, "refused": err.problem}
                        rows.append({"condition": name, **row})
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"# transport timing, {args.duration:g} s per case, Python {platform.python_version()}, "
          f"{platform.machine()}, {os.cpu_count()} cores, simulated serial device: {args.serial_device}, CAN devices "
          f"in-process, stall = {1e3 * STALL_S:g} ms every 5 s, load average {os.getloadavg()[0]:.2f} at the end")
    print("| condition | transport | rate | samples | lost | held | min lead | late | duplicate | CPU per 1000 "
          "samples | load avg | link load (worst case / measured) | longest host gap | longest gc |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        if "refused" in row:
            print(f"| {row['condition']} | {row['transport']} | {row['rate_hz']:.0f} Hz | refused on load: "
                  f"{row['refused'][:90]} |||||||||||")
            continue
        measured = "n/a" if row.get("measured_load_pct") is None else f"{row['measured_load_pct']:.1f}%"
        can = f"{row['bus_load_pct']:.1f}% / {measured}" if "bus_load_pct" in row else "n/a"
        held = "n/a" if row["held"] is None else row["held"]
        lead = "n/a" if row["min_lead_ms"] is None else f"{row['min_lead_ms']:.1f} ms"
        print(f"| {row['condition']} | {row['transport']} | {row['rate_hz']:.0f} Hz | {row['samples']} | {row['lost']} | "
              f"{held} | {lead} | {row['late']} | {row['duplicate']} | {row['cpu_ms_per_1000']:.0f} ms | "
              f"{row['load_average']:.2f} | {can} | {row['host_gap_ms']:.1f} ms | {row['gc_ms']:.1f} ms |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
