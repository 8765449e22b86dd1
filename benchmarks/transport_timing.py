"""Sample timing of the rig driver against its simulated devices, per wire, at 1 kHz and 2 kHz, in four
conditions the script sets up and tears down itself:

(a) ``idle``: nothing else of ours runs;
(b) ``busy``: one CPU-hog process per core (both cores busy);
(c) ``stall``: idle, plus a 50 ms pause of the driver's own thread every 5 s (``--sim-faults stall``);
(d) ``hog``: two CPU-bound processes at normal priority for the whole run, and every simulated device in a
    process of its own (``python -m sim_backend.device_process``: serial on a pty, CAN on python-can's
    ``udp_multicast``, the CANopen SYNC from the devices' process), as a real device has its own CPU: a starved
    host can no longer starve its device with it, and what it costs shows. Each row is judged against the
    device's own record of what it applied at every SYNC or tick (``DeviceRecord``): rows whose logged command
    differs from it ("wrong", goal 0), HELD rows, and for each stretch of HELD rows whether it began during a
    pause of the host (two turns of the runner further apart than the lead) that explains it, or else during a
    stall of the device's own clock (its process starved: it then makes up the ticks in a burst beyond the
    host's lead, which a real device would not do), or else while the host's rows lagged the device's clock by
    more than the lead without one such pause (a host with too little CPU to keep up). Also the device's latest tick, frames dropped at a full
    udp_multicast receive buffer (host / device), and how the run ended (exit status as ``rig run`` would
    give it, and the stop). The host waits for a starved device process rather than stop the run
    (``PATIENT_WITH_A_DEVICE_PROCESS``: SDO and heartbeat timeouts of 5 s, raw-CAN replies of 2 s).

Per row: samples, lost (goal 0), held (setpoints that missed the device's instant; goal 0), the smallest
lead of a setpoint over its instant, late samples, CPU per 1000 samples, the CAN bus load, and who stalled:
the longest gap between two rows the runner filed (a pause of the host, stalls included, or a silence of
the device) and the longest garbage collection of the driver's process during the run. Every wire runs
on the device's clock with its default lead (CANopen 100 ms; serial and raw CAN as their configs and the
device's buffer allow, the lead column of the hog table): ``canopen`` with the default ``mode = "auto"``,
which streams interpolated position into the simulated drive's 64-record buffer (the lead sits in the
drive, at most the buffer less 2 records); ``canopen-csp`` forces cyclic synchronous position (one target
per SYNC, on the bus right after the SYNC before it: under one period of lead on the bus); ``serial`` and
``can`` speak protocol v2 (the device ticks, setpoints tagged with their tick). A v1 device is host-paced
and "held" does not apply to it (n/a).

The simulated serial device runs in a process of its own (``python -m sim_backend.serial_device``, on a pty),
as a real device is a microcontroller with its own clock: it shares neither the GIL nor the garbage
collector's pauses with the driver (``--devices thread`` runs it as a thread of the driver's process
instead, as ``rig run`` does). On a machine so loaded that the device's own process is starved, its ticks
run late and catch up in a burst, and ticks beyond the lead are HELD, which a real device would not do. In
``idle``, ``busy`` and ``stall`` the CAN devices run in the driver's process (python-can's virtual bus is
in-process; ``--devices process`` moves them out), so they compete with it for the GIL and both cores: a
pause of the whole process (a full garbage collection, a starved process) stops their clock too, and they
catch up in a burst that the lead has to cover. "CPU per 1000 samples" is the driver's process (without a
device in a process of its own). Usage::

    python benchmarks/transport_timing.py                   # 5 s per case
    python benchmarks/transport_timing.py --duration 60 --conditions idle busy stall
    python benchmarks/transport_timing.py --duration 60 --conditions hog --transports serial can canopen
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
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

from identify.experiment_record import SampleFlag  # noqa: E402
from rig.exit_codes import BAD_INPUT, DEVICE_FAULT, SUCCESS, UNEXPECTED_ERROR  # noqa: E402
from rig.protocols.errors import ConfigError, RigError  # noqa: E402
from rig.rig_config import load_rig_config  # noqa: E402
from rig.runner import run_experiment  # noqa: E402
from rig.transports import open_transport  # noqa: E402
from rig.transports.simulated import (PATIENT_WITH_A_DEVICE_PROCESS, start_device_process,  # noqa: E402
                                     start_simulated_devices)
from sim_backend.plant_config import load_plant_config  # noqa: E402

STALL_S = 0.05
HOGS = 2  # the hog condition's CPU-bound processes (normal priority), whatever the number of cores


class _Rows:
    """The rows of a run (command and flags), for comparing them with the device's record."""

    def __init__(self) -> None:
        self.command_rad: list[float] = []
        self.flags: list[int] = []

    def append(self, time_s, command_rad, angle_rad, encoder_counts=None, flags=0) -> None:
        self.command_rad.append(command_rad)
        self.flags.append(int(flags))

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


def _own_udp_drops() -> int | None:
    """Datagrams dropped at a full receive buffer, summed over this process's UDP sockets (/proc/net/udp)."""
    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            target = os.readlink(f"/proc/self/fd/{fd}")
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    drops = None
    with contextlib.suppress(OSError), open("/proc/net/udp") as lines:
        for line in list(lines)[1:]:
            fields = line.split()
            if fields[9] in inodes:
                drops = (drops or 0) + int(fields[-1])
    return drops


def _held_stretches(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) sample of every run of HELD rows."""
    held = np.flatnonzero(flags & int(SampleFlag.HELD))
    if not held.size:
        return []
    breaks = np.flatnonzero(np.diff(held) > 1)
    return list(zip(held[np.r_[0, breaks + 1]].tolist(), held[np.r_[breaks, held.size - 1]].tolist()))


def _during(stretch: tuple[int, int], stalls: list[tuple[int, float]], period_s: float, lead: int) -> bool:
    """Whether a stretch of HELD rows began during one of ``stalls`` ((sample, seconds)): a pause of D seconds of
    the host after the runner had written row w (or of the device's clock at its sample w, which it then makes
    up in a burst) holds the samples from about w + lead to w + D / T."""
    first = stretch[0]
    return any(sample <= first <= sample + math.ceil(stall_s / period_s) + lead for sample, stall_s in stalls)


def _host_behind(turns: list[tuple[float, int]], period_s: float, lead: int) -> list[tuple[int, float]]:
    """(rows written, lag) at every turn of the runner whose rows lagged the device's clock by more than the
    lead: the row w is due at t_0 + w T, t_0 taken from the turn that was least behind. A host that falls behind
    without one pause longer than the lead (too little CPU to keep up), or a device stall, shows here."""
    written = [(when, done) for when, done in turns if done > 0]
    if not written:
        return []
    origin = min(when - done * period_s for when, done in written)
    return [(done, lag) for when, done in written if (lag := when - origin - done * period_s) > lead * period_s]


def _exit_status(err: BaseException | None) -> int:
    """The exit status ``rig run`` gives a run that ended with ``err``."""
    if err is None:
        return SUCCESS
    if isinstance(err, ConfigError):
        return BAD_INPUT
    return DEVICE_FAULT if isinstance(err, RigError) else UNEXPECTED_ERROR


def measure(kind: str, rate_hz: float, duration_s: float, directory: Path, pending_cycles: int,
            stall_every_s: float | None = None, devices: str = "thread", canopen_sync: str = "device",
            device_nice: int = 0) -> dict[str, object]:
    """One row: ``kind`` at ``rate_hz`` for ``duration_s``, its devices in the driver's process (``devices =
    "thread"``) or in one of their own (``"process"``, at niceness ``device_nice``; the CANopen SYNC then from
    the devices' process, or with ``canopen_sync = "host"`` from the driver's)."""
    config = _config(kind, rate_hz, directory)
    # the plant's physics stay at its own 1 kHz; only the wall-clock rate of the loop changes here
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    num_samples = int(round(duration_s * rate_hz))
    command = 0.5 * np.sin(2 * np.pi * 0.5 * np.arange(num_samples) / rate_hz)
    stalls = [] if stall_every_s is None else [int(k * stall_every_s * rate_hz)
                                               for k in range(1, int(duration_s / stall_every_s) + 1)]

    turns: list[tuple[float, int]] = []  # (when, rows written) at each turn of the runner: the host's pauses
    gc_pauses_s = [0.0]
    gc_started = [0.0]
    host_drops: list[int | None] = [None]
    drops_read_at = [-math.inf]

    def stall(done: int, held: int) -> None:
        now = time.perf_counter()
        if devices == "process" and now - drops_read_at[0] > 0.5:  # (read while the transport's socket is open)
            host_drops[0], drops_read_at[0] = _own_udp_drops(), now
        turns.append((now, done))
        while stalls and done >= stalls[0]:
            stalls.pop(0)
            time.sleep(STALL_S)

    def gc_timer(phase: str, info: dict) -> None:
        if phase == "start":
            gc_started[0] = time.perf_counter()
        else:
            gc_pauses_s.append(time.perf_counter() - gc_started[0])

    rows = _Rows()
    failure: BaseException | None = None
    summary = None
    in_process_device = None
    with contextlib.ExitStack() as stack:
        clocked = {"sample_period_s": 1.0 / rate_hz} if kind in ("serial", "can") else {}  # the device's own tick
        options = dict(config.transport_options())
        if devices == "process":
            device_sync = config.scheme == "canopen" and canopen_sync == "device"
            url, running = start_device_process(config, stack, sample_period_s=1.0 / rate_hz, produce_sync=device_sync)
            if device_nice:
                _renice(running.pid, device_nice)
            options.update(PATIENT_WITH_A_DEVICE_PROCESS[config.scheme])
            if device_sync:
                options["sync_producer"] = "external"
        else:
            running = None
            url, in_process_device = start_simulated_devices(config, gearbox, stack, **clocked)
        transport = open_transport(url, **options)
        gc.callbacks.append(gc_timer)  # the collections of the run only
        try:
            summary = run_experiment(transport, command, rows, feedback_timeout_s=config.feedback_timeout_s,
                                     late_tolerance_s=config.late_tolerance_s, pending_cycles=pending_cycles,
                                     progress=stall)
        except Exception as err:  # noqa: BLE001  (the row reports how the run ended)
            failure = err
        finally:
            gc.callbacks.remove(gc_timer)
        measured_load = in_process_device.bus_load() if hasattr(in_process_device, "bus_load") else None
        if measured_load is None and hasattr(in_process_device, "bits") and summary is not None:
            measured_load = in_process_device.bits / (summary.wall_s * in_process_device.bitrate)
        record = in_process_device.record() if in_process_device is not None else None
    if running is not None:
        record = running.record
    flags = np.array(rows.flags, dtype=int)
    period = 1.0 / rate_hz
    lead = transport.lead_samples
    gaps = np.diff([when for when, _ in turns]) if len(turns) > 1 else np.zeros(0)
    host_stalls = [(turns[i][1], float(gap)) for i, gap in enumerate(gaps) if gap > lead * period]
    host_behind = _host_behind(turns, period, lead)
    stretches = _held_stretches(flags)
    logged = [transport.drive.counts_from_rad(value) for value in rows.command_rad]
    usable = (flags & int(SampleFlag.unusable())) == 0
    offset = record.row_offset(logged)
    wrong = record.wrong_rows(logged, usable.tolist())
    device_clocked = lead > 0
    row: dict[str, object] = {
        "transport": kind, "rate_hz": rate_hz, "devices": devices, "samples": len(rows.flags),
        "lost": int(np.count_nonzero(flags & int(SampleFlag.LOST))),
        "wrong": wrong, "row_offset": offset, "held": int(np.count_nonzero(flags & int(SampleFlag.HELD))) if device_clocked else None,
        "held_stretches": [{"first": first, "last": last,
                            "during_host_stall": _during((first, last), host_stalls, period, lead),
                            "during_device_stall": _during((first, last), list(record.stalls), period, lead),
                            "host_behind": _during((first, last), host_behind, period, lead)}
                           for first, last in stretches],
        "lead_ms": 1e3 * lead * period, "host_stalls_over_lead": len(host_stalls),
        "exit": _exit_status(failure),
        "stop": (summary.stop if summary is not None else " ".join([str(failure), *getattr(failure, "__notes__", ())])),
        "device_tick_delay_max_ms": None if record.tick_delay_max_s is None else 1e3 * record.tick_delay_max_s,
        "device_stalls": len(record.stalls),
        "rx_drops_host": host_drops[0], "rx_drops_device": record.receive_drops,
        "load_average": os.getloadavg()[0],
        "host_gap_ms": 1e3 * float(np.max(gaps, initial=0.0)), "gc_ms": 1e3 * max(gc_pauses_s),
    }
    if summary is not None:
        row.update(min_lead_ms=1e3 * summary.min_lead_s if device_clocked else None, late=summary.late,
                   duplicate=summary.duplicate, cpu_ms_per_1000=1e6 * summary.cpu_s / max(summary.samples, 1))
    load = getattr(transport, "load", None)
    if load is not None:
        row.update(bus_load_pct=100 * load.load, bus_limit_hz=load.max_rate_hz,
                   measured_load_pct=None if measured_load is None else 100 * measured_load)
    return row


def _renice(pid: int, nice: int) -> None:
    """Every thread of process ``pid`` at niceness ``nice`` (Linux keeps a niceness per thread; below 0 needs
    the privilege to raise a priority, CAP_SYS_NICE)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            os.setpriority(os.PRIO_PROCESS, int(task.name), nice)
        except PermissionError as err:
            raise SystemExit(f"--device-nice {nice}: {err}; run as a user allowed to raise priorities, or "
                             "leave the device at the driver's priority (--device-nice 0)") from err


@contextlib.contextmanager
def cpu_hogs(count: int):
    """``count`` CPU-bound processes (a busy loop each, normal priority) for the duration of the block."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


@contextlib.contextmanager
def condition(name: str):
    """``busy``: one CPU-hog process per core; ``hog``: :data:`HOGS` of them; for the duration of the block."""
    with cpu_hogs({"busy": os.cpu_count() or 2, "hog": HOGS}.get(name, 0)):
        yield


def _refused_row(row: dict[str, object]) -> str:
    """A table row for a case refused on load (e.g. a rate the bus cannot carry)."""
    return (f"| {row['condition']} | {row['transport']} | {row['rate_hz']:.0f} Hz | refused on load: "
            f"{str(row['refused'])[:90]} |||||||||||")


def _print_timing_table(rows: list[dict[str, object]]) -> None:
    print("| condition | transport | rate | samples | lost | held | min lead | late | duplicate | CPU per 1000 "
          "samples | load avg | link load (worst case / measured) | longest host gap | longest gc |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        if "refused" in row:
            print(_refused_row(row))
            continue
        if "late" not in row:
            print(f"| {row['condition']} | {row['transport']} | {row['rate_hz']:.0f} Hz | {row['samples']} | "
                  f"{row['lost']} | exit {row['exit']}: {row['stop'][:100]} ||||||||||")
            continue
        measured = "n/a" if row.get("measured_load_pct") is None else f"{row['measured_load_pct']:.1f}%"
        can = f"{row['bus_load_pct']:.1f}% / {measured}" if "bus_load_pct" in row else "n/a"
        held = "n/a" if row["held"] is None else row["held"]
        lead = "n/a" if row["min_lead_ms"] is None else f"{row['min_lead_ms']:.1f} ms"
        print(f"| {row['condition']} | {row['transport']} | {row['rate_hz']:.0f} Hz | {row['samples']} | {row['lost']} | "
              f"{held} | {lead} | {row['late']} | {row['duplicate']} | {row['cpu_ms_per_1000']:.0f} ms | "
              f"{row['load_average']:.2f} | {can} | {row['host_gap_ms']:.1f} ms | {row['gc_ms']:.1f} ms |")


def _stretches_cell(row: dict[str, object]) -> str:
    stretches = row["held_stretches"]
    if not stretches:
        return "none"
    host = sum(stretch["during_host_stall"] for stretch in stretches)
    device = sum(stretch["during_device_stall"] and not stretch["during_host_stall"] for stretch in stretches)
    behind = sum(stretch["host_behind"] and not (stretch["during_host_stall"] or stretch["during_device_stall"])
                 for stretch in stretches)
    other = [f"{s['first']}-{s['last']}" for s in stretches
             if not (s["during_host_stall"] or s["during_device_stall"] or s["host_behind"])]
    return (f"{len(stretches)}: {host} in a host stall > lead, {device} in a device stall, {behind} with the host "
            "behind by > lead" + (f", {len(other)} else ({', '.join(other[:3])})" if other else ""))


def _optional(value: object, unit: str = "", digits: int = 1) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}{unit}" if isinstance(value, float) else f"{value}{unit}"


def _print_device_table(rows: list[dict[str, object]]) -> None:
    print("| condition | transport | rate | samples | lost | wrong | held | held stretches | lead / host stalls "
          "> lead / longest host gap | min lead | device's latest tick (its stalls > 10 ms) | rx drops host / device "
          "| exit, stop | load avg |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        if "refused" in row:
            print(_refused_row(row))
            continue
        stop = str(row["stop"]).replace("|", "/")
        print(f"| {row['condition']} | {row['transport']} | {row['rate_hz']:.0f} Hz | {row['samples']} | {row['lost']} | "
              f"{row['wrong']} | {_optional(row['held'])} | {_stretches_cell(row)} | {row['lead_ms']:.0f} ms / "
              f"{row['host_stalls_over_lead']} / {row['host_gap_ms']:.0f} ms | "
              f"{_optional(row.get('min_lead_ms'), ' ms')} | {_optional(row['device_tick_delay_max_ms'], ' ms')} "
              f"({row['device_stalls']} stalls) | "
              f"{_optional(row['rx_drops_host'])} / {_optional(row['rx_drops_device'])} | "
              f"{row['exit']}, {stop[:110]} | {row['load_average']:.2f} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=5.0, help="seconds per case (default 5)")
    parser.add_argument("--rates", type=float, nargs="+", default=[1000.0, 2000.0])
    parser.add_argument("--transports", nargs="+", default=["canopen", "canopen-csp", "serial", "can"],
                        choices=["canopen", "canopen-csp", "serial", "can"])
    parser.add_argument("--conditions", nargs="+", default=["idle", "busy", "stall"],
                        choices=["idle", "busy", "stall", "hog"])
    parser.add_argument("--pending-cycles", type=int, default=4,
                        help="feedback later than this many cycles is LOST (the runner's default: 4)")
    parser.add_argument("--devices", choices=["auto", "process", "thread"], default="auto",
                        help="auto (default): the serial device in a process of its own and the CAN devices in the "
                             "driver's, every device in its own process under hog; process or thread: all of them")
    parser.add_argument("--canopen-sync", choices=["device", "host"], default="device",
                        help="CANopen devices in a process of their own: SYNC from their process (default; the "
                             "master listens, sync_producer = \"external\") or from the driver's (a thread)")
    parser.add_argument("--device-nice", type=int, default=0,
                        help="niceness of a device's own process (default 0, as the driver and the hogs): below 0 "
                             "it stands for a device with a CPU of its own, so that its process is not starved "
                             "by the hogs and only the host's stalls show (needs CAP_SYS_NICE)")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        for name in args.conditions:
            with condition(name):
                for kind in args.transports:
                    devices = args.devices
                    if devices == "auto":
                        devices = "process" if name == "hog" or kind == "serial" else "thread"
                    for rate in args.rates:
                        try:
                            row = measure(kind, rate, args.duration, Path(directory), args.pending_cycles,
                                          stall_every_s=5.0 if name == "stall" else None, devices=devices,
                                          canopen_sync=args.canopen_sync, device_nice=args.device_nice)
                        except ConfigError as err:  # e.g. a rate the bus cannot carry: refused on load
                            row = {"transport": kind, "rate_hz": rate, "refused": err.problem}
                        rows.append({"condition": name, **row})
                        if name == "hog" and not args.json:
                            print(json.dumps({"condition": name, **row}), file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    blas = {name: os.environ.get(name) for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    print(f"# transport timing, {args.duration:g} s per case, Python {platform.python_version()}, "
          f"{platform.machine()}, {os.cpu_count()} cores, devices: {args.devices}, CANopen SYNC with its devices in a "
          f"process: {args.canopen_sync}, device process niceness {args.device_nice}, stall = {1e3 * STALL_S:g} ms every 5 s, load average "
          f"{os.getloadavg()[0]:.2f} at the end, BLAS threads {blas}")
    timing = [row for row in rows if row["condition"] != "hog"]
    hog = [row for row in rows if row["condition"] == "hog"]
    if timing:
        _print_timing_table(timing)
    if hog:
        _print_device_table(hog)
    return 0


if __name__ == "__main__":
    sys.exit(main())
