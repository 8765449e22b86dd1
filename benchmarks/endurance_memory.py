"""Memory of long runs: whether the driver (and a simulated device) keep flat memory however long a run lasts.

(a) ``real``: per wire (serial, CANopen, raw CAN), a run of ``--minutes`` of real time at 1 kHz, the simulated
    device in a process of its own (``python -m sim_backend.device_process``, as ``benchmarks/transport_timing.py``
    runs it under ``hog``: serial on a pty, CAN on python-can's ``udp_multicast``, the CANopen SYNC from the
    devices' process), the log written to disk as ``rig run`` writes it. The resident set (VmRSS) of the driver's
    process and of the device's is sampled every 10 s; the table gives the samples and the least-squares slope
    in MiB/min over those from the first minute on (or the second half of a shorter run). Goal: no growth (the
    log's page cache is the kernel's, not the process's). Every row is then judged against the device's own
    record of what it applied (``DeviceRecord.wrong_rows``; goal 0).
(b) ``clocked``: ``--hours`` at 1 kHz on a simulated clock, driver and simulated serial device in one process
    (the scripted line of ``tests/transports/clocked_line.py``: no pty, no thread, no sleep), the log written to
    disk: samples, every sample accounted for (rows logged, LOST / HELD / late, the device's record as long as
    the run, wrong rows), wall time, and the process's resident set when the run starts and its peak (VmHWM,
    reset at the start where Linux lets a process reset it) at the end of the run, before the log is read back
    to judge it. Run it in a process of its own (``--parts clocked``) for a peak that is the run's alone.

Usage::

    python benchmarks/endurance_memory.py                              # 10 min per wire, then 8 h clocked
    python benchmarks/endurance_memory.py --minutes 1 --hours 0.05     # a smoke run
    python benchmarks/endurance_memory.py --parts clocked --hours 1
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(1, str(ROOT / "tests" / "transports"))  # the scripted line of the clocked run

from identify.excitation_design import staircase_reference  # noqa: E402
from identify.experiment_record import SampleFlag  # noqa: E402
from rig.command_source import FilteredRepeatCommand  # noqa: E402
from rig.log_file import LogWriter  # noqa: E402
from rig.protocols.cia402 import DriveScaling  # noqa: E402
from rig.runner import run_experiment  # noqa: E402
from rig.transports import open_transport  # noqa: E402
from rig.transports.simulated import PATIENT_WITH_A_DEVICE_PROCESS, start_device_process  # noqa: E402
from sim_backend.device_record import DeviceRecord  # noqa: E402
from transport_timing import _config as timing_config  # noqa: E402  (the rigs of the timing benchmark)

RATE_HZ = 1000.0
RSS_EVERY_S = 10.0
WIRES = ("serial", "canopen", "can")
PLANT = ROOT / "configs" / "plants" / "precision_gearbox.toml"  # 1 kHz


def _status_mib(pid: int | str, field: str) -> float | None:
    """A memory field of /proc/PID/status (VmRSS, VmHWM, RssAnon) in MiB; None once the process is gone."""
    with contextlib.suppress(OSError), open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return None


def _reset_peak_rss() -> bool:
    """Start VmHWM afresh from the present resident set (``/proc/self/clear_refs``: 5, Linux 4.0 on); whether it
    could."""
    try:
        with open("/proc/self/clear_refs", "w") as clear_refs:
            clear_refs.write("5")
    except OSError:
        return False
    return True


def _command(num_samples: int) -> FilteredRepeatCommand:
    """A filtered staircase repeated for the whole run, generated a chunk at a time as it is sent."""
    return FilteredRepeatCommand(staircase_reference([0.05, 0.1, 0.2], 700), 0.95, 1, num_samples)


def _log(path: Path, source: str) -> LogWriter:
    """A log written as ``rig run`` writes its own (flushed every 10 samples or 50 ms)."""
    return LogWriter(path, {"sample_period_s": 1 / RATE_HZ, "encoder_bits": 12, "source": source},
                     flush_every=10, flush_interval_s=0.05)


def _wrong_rows(log_path: Path, rows: int, record: DeviceRecord, drive: DriveScaling) -> int:
    """Usable logged rows whose command is not the target the device applied at that sample, the log read a
    million rows at a time."""
    import pandas

    counts = np.empty(rows, dtype=np.int64)
    usable = np.empty(rows, dtype=bool)
    done = 0
    for chunk in pandas.read_csv(log_path, comment="#", usecols=["command_rad", "flags"], chunksize=1 << 20):
        size = len(chunk)
        counts[done:done + size] = np.rint(chunk["command_rad"].to_numpy() * drive.counts_per_revolution
                                           / (2 * math.pi))
        usable[done:done + size] = (chunk["flags"].to_numpy() & int(SampleFlag.unusable())) == 0
        done += size
    if done != rows:
        raise RuntimeError(f"{log_path}: {done} rows read back, {rows} written")
    return record.wrong_rows(counts, usable)


def _slope_mib_per_min(times_s: list[float], mib: list[float | None]) -> float:
    """Least-squares slope over the samples from the first minute on (the second half of a shorter run)."""
    start = min(60.0, times_s[-1] / 2)
    points = [(t, m) for t, m in zip(times_s, mib) if t >= start and m is not None]
    if len(points) < 2:
        return math.nan
    t, m = np.array(points).T
    return float(np.polyfit(t / 60.0, m, 1)[0])


def real_time_run(wire: str, minutes: float, directory: Path) -> dict[str, object]:
    """(a) One wire for ``minutes`` at 1 kHz, its device in a process of its own."""
    config = timing_config(wire, RATE_HZ, directory)
    num_samples = int(round(minutes * 60 * RATE_HZ))
    samples: list[tuple[float, float | None, float | None]] = []  # (run time, driver MiB, device MiB)
    started = [0.0]
    log_path = directory / f"{wire}.csv"
    with contextlib.ExitStack() as stack:
        device_sync = wire == "canopen"
        url, running = start_device_process(config, stack, sample_period_s=1 / RATE_HZ, produce_sync=device_sync)
        options = dict(config.transport_options(), **PATIENT_WITH_A_DEVICE_PROCESS[config.scheme])
        if device_sync:
            options["sync_producer"] = "external"
        transport = stack.enter_context(contextlib.closing(open_transport(url, **options)))

        def progress(done: int, _late: int) -> None:
            now = time.perf_counter()
            if not samples:
                started[0] = now
            if not samples or now - started[0] >= len(samples) * RSS_EVERY_S:
                samples.append((now - started[0], _status_mib("self", "VmRSS"), _status_mib(running.pid, "VmRSS")))

        summary = run_experiment(transport, _command(num_samples), _log(log_path, wire),
                                 feedback_timeout_s=config.feedback_timeout_s, late_tolerance_s=config.late_tolerance_s,
                                 progress=progress)
        samples.append((time.perf_counter() - started[0], _status_mib("self", "VmRSS"),
                        _status_mib(running.pid, "VmRSS")))
    wrong = _wrong_rows(log_path, summary.samples, running.record, transport.drive)
    times = [t for t, _, _ in samples]
    return {"wire": wire, "samples": summary.samples, "lost": summary.lost, "held": summary.held, "wrong": wrong,
            "record": running.record.applied_targets.size, "rss": samples,
            "driver_slope": _slope_mib_per_min(times, [d for _, d, _ in samples]),
            "device_slope": _slope_mib_per_min(times, [d for _, _, d in samples]),
            "log_mib": log_path.stat().st_size / 2**20, "load": os.getloadavg()[0]}


def clocked_run(hours: float, directory: Path) -> dict[str, object]:
    """(b) ``hours`` at 1 kHz on a simulated clock, driver and serial device in this process."""
    import collections

    from clocked_line import SimulatedClock, simulated_device_line
    from rig.protocols.cia402 import BringUpTiming
    from rig.protocols.encoder_counts import EncoderResolution
    from rig.transports.serial_link import SerialTransport
    from sim_backend.plant_config import load_plant_config
    from sim_backend.serial_device import SimulatedSerialDevice

    num_samples = int(round(hours * 3600 * RATE_HZ))
    clock = SimulatedClock(100.0)
    drive = DriveScaling(1 << 17)
    log_path = directory / "clocked.csv"
    with contextlib.closing(SimulatedSerialDevice(load_plant_config(PLANT).gearbox(seed=3), clock=clock,
                                                  buffer_capacity=64)) as device:
        transport = SerialTransport("simulated", encoder=EncoderResolution(bits=12, signed=True),
                                    sample_period_s=1 / RATE_HZ, drive=drive, reply_timeout_s=0.3, lead_s=0.05,
                                    timing=BringUpTiming(poll_interval_s=0.0), name="clocked", clock=clock)
        line = simulated_device_line(transport, clock, device)
        line.to_host = collections.deque(maxlen=64)  # (the scripted line's transcript: the test's, not the driver's)
        log = _log(log_path, "clocked")
        start_mib, peak_reset = _status_mib("self", "VmRSS"), _reset_peak_rss()
        wall = time.perf_counter()
        summary = run_experiment(transport, _command(num_samples), log, feedback_timeout_s=0.5, clock=clock)
        wall_s = time.perf_counter() - wall
        peak_mib = _status_mib("self", "VmHWM")
        record = device.record()
    return {"hours": hours, "samples": summary.samples, "rows": log.samples, "lost": summary.lost,
            "held": summary.held, "late": summary.late, "record": record.applied_targets.size,
            "wrong": _wrong_rows(log_path, log.samples, record, drive), "wall_s": wall_s, "peak_mib": peak_mib,
            "start_mib": start_mib, "peak_reset": peak_reset,
            "log_mib": log_path.stat().st_size / 2**20, "load": os.getloadavg()[0]}


def _print_real(rows: list[dict[str, object]], minutes: float) -> None:
    print(f"\n(a) {minutes:g} min of real time at 1 kHz per wire, device in a process of its own: VmRSS (MiB) of the "
          f"driver / the device, every {RSS_EVERY_S:g} s from the run's first sample, and at its end")
    print("| run time | " + " | ".join(str(row["wire"]) for row in rows) + " |")
    print("|---|" + "---|" * len(rows))

    def cell(sample: tuple[float, float | None, float | None]) -> str:
        return f"{sample[1]:.1f} / " + ("gone" if sample[2] is None else f"{sample[2]:.1f}")

    for i in range(max(len(row["rss"]) - 1 for row in rows)):
        print(f"| {i * RSS_EVERY_S:.0f} s | " + " | ".join(cell(row["rss"][i]) if i < len(row["rss"]) - 1 else ""
                                                          for row in rows) + " |")
    print("| end | " + " | ".join(f"{cell(row['rss'][-1])} ({row['rss'][-1][0]:.0f} s)" for row in rows) + " |")
    print("\n| wire | samples | lost | held | wrong | device record | slope driver | slope device | log | "
          "load avg |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['wire']} | {row['samples']} | {row['lost']} | {row['held']} | {row['wrong']} | "
              f"{row['record']} | {row['driver_slope']:+.3f} MiB/min | {row['device_slope']:+.3f} MiB/min | "
              f"{row['log_mib']:.0f} MiB | {row['load']:.2f} |", flush=True)


def _print_clocked(row: dict[str, object]) -> None:
    print(f"\n(b) {row['hours']:g} h at 1 kHz on a simulated clock, driver and serial device in one process")
    peak = "peak RSS in the run" if row["peak_reset"] else "peak RSS of the process"
    print(f"| samples | rows logged | lost | held | late | device record | wrong | wall time | RSS at the start / "
          f"{peak} | log | load avg |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    print(f"| {row['samples']} | {row['rows']} | {row['lost']} | {row['held']} | {row['late']} | {row['record']} | "
          f"{row['wrong']} | {row['wall_s']:.0f} s | {row['start_mib']:.1f} / {row['peak_mib']:.1f} MiB | "
          f"{row['log_mib']:.0f} MiB | {row['load']:.2f} |", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="(a) real time per wire (default 10)")
    parser.add_argument("--hours", type=float, default=8.0, help="(b) simulated hours (default 8)")
    parser.add_argument("--parts", nargs="+", choices=["real", "clocked"], default=["real", "clocked"])
    parser.add_argument("--wires", nargs="+", choices=WIRES, default=list(WIRES), help="(a) the wires")
    args = parser.parse_args()
    blas = {name: os.environ.get(name) for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    print(f"# endurance memory, Python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f} at the start, BLAS threads {blas}")
    with tempfile.TemporaryDirectory(prefix="endurance-") as directory:
        if "real" in args.parts:
            rows = []
            for wire in args.wires:
                rows.append(real_time_run(wire, args.minutes, Path(directory)))
                print(f"# {wire} done, load average {os.getloadavg()[0]:.2f}", file=sys.stderr, flush=True)
            _print_real(rows, args.minutes)
        if "clocked" in args.parts:
            _print_clocked(clocked_run(args.hours, Path(directory)))
    print(f"\n# load average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
