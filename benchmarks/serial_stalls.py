"""Who stalls in a serial v2 run: time stamps of the host's setpoints and reads, of the simulated device's
ticks, and of the driver process's garbage collections, for one case of ``transport_timing.py``.

The simulated device runs as a thread of the driver's process here (``--devices thread`` of
``transport_timing.py``), so that its tick thread can be timed: a tick that runs late while the host was also
silent, at the time of a long collection, is a pause of the whole process, not of one side. Prints the
longest of each kind of gap, when it came, and every collection longer than 10 ms. Usage::

    python benchmarks/serial_stalls.py --condition busy --rate 2000 --duration 20
"""

from __future__ import annotations

import argparse
import gc
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import transport_timing  # noqa: E402
from rig.transports.serial_link import SerialTransport  # noqa: E402
from sim_backend.serial_device import SimulatedSerialDevice  # noqa: E402


def _longest_gap(stamps_s: list[float], origin_s: float) -> str:
    if len(stamps_s) < 2:
        return "n/a"
    gaps = np.diff(stamps_s)
    i = int(np.argmax(gaps))
    return f"{1e3 * gaps[i]:.1f} ms, ending at {stamps_s[i + 1] - origin_s:.3f} s"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--condition", choices=["idle", "busy"], default="busy")
    parser.add_argument("--rate", type=float, default=2000.0)
    parser.add_argument("--duration", type=float, default=20.0)
    args = parser.parse_args()
    ticks: list[tuple[float, float]] = []  # (when the tick ran, when it was due)
    sends: list[float] = []
    reads: list[float] = []
    collections: list[tuple[int, float, float]] = []  # (generation, start, duration)
    started = [0.0]
    tick, send, poll = SimulatedSerialDevice.tick, SerialTransport._send, SerialTransport._poll

    def timed_tick(device):
        due = None if device._ticking_since is None else device._ticking_since + device.ticks * device.sample_period_s
        now = time.perf_counter()
        frames = tick(device)
        if due is not None:
            ticks.append((now, due))
        return frames

    def timed_send(transport, setpoint):
        sends.append(time.perf_counter())
        return send(transport, setpoint)

    def timed_poll(transport, timeout_s):
        got = poll(transport, timeout_s)
        if got:
            reads.append(time.perf_counter())
        return got

    def gc_timer(phase: str, info: dict) -> None:
        if phase == "start":
            started[0] = time.perf_counter()
        else:
            collections.append((info["generation"], started[0], time.perf_counter() - started[0]))

    SimulatedSerialDevice.tick, SerialTransport._send, SerialTransport._poll = timed_tick, timed_send, timed_poll
    gc.callbacks.append(gc_timer)
    with tempfile.TemporaryDirectory() as directory, transport_timing.condition(args.condition):
        row = transport_timing.measure("serial", args.rate, args.duration, Path(directory), 4, devices="thread")
    origin = ticks[0][1] if ticks else 0.0
    print(f"# serial {args.rate:g} Hz, {args.condition}, {args.duration:g} s, device as a thread: {row['samples']} "
          f"samples, {row['lost']} lost, {row['held']} held, min lead {row['min_lead_ms']:.1f} ms, load average "
          f"{row['load_average']:.2f}; times from the device's tick 0")
    late = np.array([ran - due for ran, due in ticks])
    if late.size:
        i = int(np.argmax(late))
        print(f"device tick thread: latest tick {1e3 * late[i]:.1f} ms after its instant, at {ticks[i][0] - origin:.3f} s;"
              f" {int(np.sum(late > 0.02))} ticks more than 20 ms late")
    print(f"host setpoints: longest gap {_longest_gap(sends, origin)}")
    print(f"host reads: longest gap {_longest_gap(reads, origin)}")
    longest = max(collections, key=lambda c: c[2], default=None)
    if longest is not None:
        print(f"garbage collections: {len(collections)}, longest {1e3 * longest[2]:.1f} ms (generation {longest[0]}) "
              f"at {longest[1] - origin:.3f} s")
    for generation, start, duration in collections:
        if duration > 0.01:
            print(f"  collection of generation {generation} at {start - origin:.3f} s: {1e3 * duration:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
