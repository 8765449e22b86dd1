"""``rig run CONFIG.toml --experiment EXP.toml --out LOG``: drive a rig (real or simulated) with an
experiment's excitation at the config's fixed rate and write a rig log (``rig-log v1``, or ``v2`` with the
drive's torque).

A rig config with a ``[simulation]`` table runs against simulated devices started by
:func:`rig.transports.simulated.simulated_rig` (the table of simulated devices beside the transport registry).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import sys
import time
import warnings
from pathlib import Path
from typing import Any

from rig import exit_codes
from rig.sinks import ForwardingSink

__all__ = ["DEFAULT_CONFIG", "load_command_file", "register", "run"]

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "sim_canopen.toml"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="drive a rig (real or simulated) with an experiment and write a log",
        description=(
            "Stream the excitation of an experiment config to the rig of a rig config at its fixed sample rate, "
            "with software limits, a feedback watchdog and a controlled stop on any fault or Ctrl-C, and write "
            "every sample (flagged LOST/LATE/DUPLICATE/FAULT) to a rig log (v2 with the drive's torque where the "
            "link reports it). A rig config with a [simulation] table starts simulated devices that answer on the "
            "real protocol."
        ),
    )
    parser.add_argument("config", metavar="CONFIG.toml", nargs="?", default=str(DEFAULT_CONFIG),
                        help="rig config (configs/sim_*.toml, configs/rig_*.toml; default: the simulated CANopen rig, "
                             "configs/sim_canopen.toml)")
    parser.add_argument("--experiment", metavar="EXP.toml", required=True,
                        help="experiment config (configs/experiments/*.toml), or a CSV, .mf4/.mdf or .mat file with a command_rad column "
                             "(one value per sample; an optional time_s column must step by the rig's period)")
    parser.add_argument("--out", metavar="LOG", required=True,
                        help="log file to write (CSV, rig-log v1, or v2 with the drive's torque); an existing file is "
                             "refused unless --force, and a file another run is writing always is")
    parser.add_argument("--force", action="store_true", help="replace an existing --out log (and --can-trace file)")
    parser.add_argument("--duration", type=duration_s, default=None, metavar="S",
                        help="run for S seconds, or S with a unit: 90s, 20min, 8h (the excitation is cut, or "
                             "repeated cyclically to fill S, produced as it is sent: any length)")
    parser.add_argument("--can-trace", metavar="FILE.blf", default=None,
                        help="CAN transports: write every frame to FILE (.blf, .asc, .log, .csv or .trc)")
    parser.add_argument("--sim-faults", metavar="SPEC", default=None,
                        help="simulated rigs only: inject wire faults, e.g. 'drop=0.001,burst=20@500' or "
                             "'fault=0x2310@300' (all wires), 'heartbeat@400' (canopen), 'garbage=0.01', "
                             "'bitflip=0.001', 'unplug@400' (serial); see docs/reference/faults.md")
    parser.add_argument("--sim-faults-seed", metavar="N", type=int, default=0,
                        help="seed of the random faults (default 0): the same seed repeats the same faults")
    parser.add_argument("--live", action="store_true",
                        help="show the command, the load angle and the lost/held counters as the run goes: a "
                             "matplotlib window when there is a display, else a text plot on stderr; the view "
                             "drops frames when it falls behind, never samples")
    parser.add_argument("--trend-window", metavar="LENGTH", default="60s",
                        help="with --live on the steady_staircase experiment: the view also shows the guaranteed "
                             "bounds on the play of the latest complete window of this length (as `rig trend "
                             "--window`; 60s, 5min, 1h; default 60s), bounded in a process of its own")
    from rig.runner import RunSummary

    keys = ", ".join(f'"{name}"' for name in ("log", *RunSummary.SAVED))
    parser.add_argument("--json", action="store_true",
                        help=f'print the run summary as JSON: {{"kind": "{RunSummary.KIND}", "version": '
                             f'{RunSummary.VERSION}, {keys}}} (rig report reads it)')
    parser.set_defaults(handler=run)


_DURATION_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0}


def duration_s(text: str) -> float:
    """``--duration``: seconds, or a number with a unit ``s``, ``min`` or ``h`` (``8h`` is 28800)."""
    stripped = text.strip()
    factor = 1.0
    for unit, seconds in _DURATION_UNITS.items():
        if stripped.endswith(unit):
            stripped, factor = stripped[:-len(unit)].strip(), seconds
            break
    try:
        value = float(stripped) * factor
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds or a number with s, min or h (8h), got {text!r}") from None
    return value


def load_command_file(path: str | Path, sample_period_s: float) -> Any:
    """An excitation read from a CSV, MDF4 or MAT file with a ``command_rad`` column (and optionally ``time_s``).

    A CSV file is read from disk as the run sends it (:class:`~rig.command_source.CsvCommandFile`: only its
    rows are counted now, and its first chunk read); an MDF4 or MAT file is read whole (its library reads
    whole channels)."""
    import numpy as np

    from rig.command_source import CsvCommandFile
    from rig.experiment_config import Excitation
    from rig.measurement_files import measurement_format, read_table
    from rig.protocols.errors import LogFileError

    if measurement_format(path) is None:  # CSV
        streamed = CsvCommandFile(path, sample_period_s)
        return Excitation(name=Path(path).stem, kind="file", command_rad=streamed.head(streamed.chunk_samples),
                          seed=None, source=str(path), streamed=streamed)
    table = read_table(path, ("command_rad",), optional_columns=("time_s",))
    if "time_s" in table and table["time_s"].size > 1:
        steps = np.diff(table["time_s"])
        bad = np.flatnonzero(~np.isclose(steps, sample_period_s, rtol=1e-6, atol=1e-12))
        if bad.size:
            raise LogFileError(f"{path}: time_s steps by {steps[bad[0]]:g} s after row {bad[0] + 1}, but the rig samples "
                               f"every {sample_period_s:g} s")
    return Excitation(name=Path(path).stem, kind="file", command_rad=table["command_rad"], seed=None,
                      source=str(path))


class FlagCounter(ForwardingSink):
    """A sink that counts the LOST, HELD and LATE rows it passes on to ``sink`` (the progress bar's counters:
    exact, since every row goes through it)."""

    def __init__(self, sink: Any) -> None:
        from identify.experiment_record import SampleFlag

        super().__init__(sink)
        self._lost, self._held, self._late = int(SampleFlag.LOST), int(SampleFlag.HELD), int(SampleFlag.LATE)
        self.lost = self.held = self.late = 0

    def append(self, time_s: float, command_rad: float, angle_rad: float, encoder_counts: int | None = None,
               flags: int = 0, **columns: float) -> None:
        super().append(time_s, command_rad, angle_rad, encoder_counts, flags, **columns)
        if flags:
            self.lost += bool(flags & self._lost)
            self.held += bool(flags & self._held)
            self.late += bool(flags & self._late)


def _slow_fmu_plant(config: Any) -> str:
    """What to say when a simulated rig's FMU plant takes longer than half a sample period a sample (the
    simulated devices step it every period: it falls behind the rig's clock); "" otherwise."""
    sim = config.simulation
    seconds = None if sim is None else sim.fmu_seconds_per_sample
    if seconds is None or seconds <= 0.5 * config.sample_period_s:
        return ""
    return (f"the simulated plant {sim.plant_path.name} (an FMU) took {1e3 * seconds:.3g} ms a sample when "
            f"{config.source} was loaded, against a sample period of {1e3 * config.sample_period_s:.3g} ms: the "
            "simulated devices step it every period, so it falls behind the rig's clock and the run may miss its "
            "feedback watchdog; lower sample_rate_hz, export the model for co-simulation (its own solver), or "
            "simplify it")


@contextlib.contextmanager
def _naming_a_slow_plant(slow_plant: str) -> Any:
    """A link failure on a rig whose simulated FMU plant is too slow names the plant as the likely cause."""
    from rig.protocols.errors import TransportError

    try:
        yield
    except TransportError as err:
        if slow_plant:
            err.add_note("likely cause: " + slow_plant)
        raise


def _live_trend(args: argparse.Namespace, metadata: Any, sample_period_s: float) -> Any:
    """The live view's trend of the play (:class:`rig.live_trend.LiveTrend`) on the steady staircase with a finite
    noise bound; None for another experiment (whose ``--trend-window`` is checked all the same)."""
    from rig.staircase_points import staircase_plan
    from rig.commands.trend import parse_window
    from rig.live_trend import LiveTrend

    window_s = parse_window(args.trend_window)
    noise_bound = metadata.noise_bound_rad
    if noise_bound is None or not (math.isfinite(noise_bound) and noise_bound > 0):
        return None
    try:
        plan = staircase_plan(metadata.config, args.experiment)
    except ValueError:  # not the staircase: nothing to trend
        return None
    return LiveTrend(plan, sample_period_s, window_s, noise_bound)


def run(args: argparse.Namespace) -> int:
    from rig.experiment_config import load_experiment_config
    from rig.log_file import LogWriter
    from rig.log_metadata import experiment_log_metadata
    from rig.output_paths import check_output_file, claim_output_file
    from rig.rig_config import load_rig_config
    from rig.runner import run_experiment
    from rig.transports import open_transport
    from rig.transports.simulated import simulated_rig

    config = load_rig_config(args.config)
    inputs = [args.config, args.experiment]
    check_output_file(args.out, "--out", inputs=inputs, force=args.force)  # before the devices start and the drive is enabled
    if args.can_trace is not None:
        if config.scheme not in ("canopen", "can"):
            raise ValueError(f"--can-trace: the {config.scheme} transport has no CAN frames to trace")
        from rig.transports.base import check_trace_path

        check_trace_path(args.can_trace)
        check_output_file(args.can_trace, "--can-trace", inputs=[*inputs, args.out], force=args.force)
        if Path(args.can_trace).resolve() == Path(args.out).resolve():
            raise ValueError(f"--can-trace {args.can_trace}: is the --out log too: give the trace its own file")
    num_samples = None
    if args.duration is not None:
        if not (math.isfinite(args.duration) and args.duration > 0):
            raise ValueError(f"--duration: expected a number of seconds > 0, got {args.duration}")
        num_samples = max(1, int(round(args.duration * config.sample_rate_hz)))
    if Path(args.experiment).suffix.lower() in (".csv", ".mf4", ".mdf", ".mat"):
        excitation = load_command_file(args.experiment, config.sample_period_s)
    else:
        excitation = load_experiment_config(args.experiment)
    if num_samples is None:
        num_samples = excitation.cycle_samples
    command = excitation.stream(num_samples)  # produced chunk by chunk as the run sends it
    faults = None
    if args.sim_faults is not None:
        from sim_backend.faults import parse_fault_spec

        if config.simulation is None:
            raise ValueError(f"--sim-faults: {config.source} is a real rig (no [simulation] table); faults are "
                             "injected only into simulated devices")
        faults = parse_fault_spec(args.sim_faults, seed=args.sim_faults_seed)
    slow_plant = _slow_fmu_plant(config)
    if slow_plant:
        warnings.warn(slow_plant, stacklevel=1)
    claimed = claim_output_file(args.out, "--out", force=args.force)  # a second run on it stops here
    with contextlib.ExitStack() as stack, _naming_a_slow_plant(slow_plant):
        stack.callback(claimed.release)
        if args.can_trace is not None:  # claimed as the log is; python-can's writer opens it by name
            trace = claim_output_file(args.can_trace, "--can-trace", force=args.force)
            stack.callback(trace.release)
        gearbox = None
        url = config.url
        if config.simulation is not None:
            url, gearbox = stack.enter_context(simulated_rig(config, command, faults))
        options = config.transport_options()
        if args.can_trace is not None:
            options["trace_path"] = args.can_trace
            trace.hand_over()
        transport = open_transport(url, **options)
        injected = None if faults is None else {"spec": args.sim_faults, "seed": args.sim_faults_seed}
        metadata = experiment_log_metadata(config, excitation, gearbox, num_samples, injected)
        view = None
        if args.live:  # on the sink: the view sees each row after the log has it (rig/live_view.py)
            from rig.live_view import open_live_view

            view = stack.enter_context(open_live_view(num_samples, config.sample_period_s, sys.stderr,
                                                      trend=_live_trend(args, metadata, config.sample_period_s)))
        log = LogWriter(args.out, metadata, flush_every=10, flush_interval_s=0.05, claimed=claimed, stamp_start=True,
                        drive_torque_unit=transport.drive_torque_unit)
        sink = log if view is None else view.observe(log)
        bar = flags = None
        if not args.json and not args.live and sys.stderr.isatty():
            from tqdm import tqdm

            # tqdm shows the time elapsed and the time left; the postfix, the rows flagged so far
            bar = stack.enter_context(tqdm(total=num_samples, unit="sample", file=sys.stderr))
            sink = flags = FlagCounter(sink)
        stalls = list(faults.host_stalls) if faults is not None else []

        def progress(done: int, late: int) -> None:
            while stalls and done >= stalls[0][0]:  # --sim-faults stall=MS@K: the driver's own thread pauses
                time.sleep(stalls.pop(0)[1])
            if bar is not None and flags is not None and (done % 50 == 0 or done == num_samples):
                bar.n = done
                bar.set_postfix(lost=flags.lost, held=flags.held, late=flags.late, refresh=True)
        summary = run_experiment(transport, command, sink, feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s,
                                 progress=progress if bar is not None or stalls else None)
    if view is not None:
        print(view.summary_line(), file=sys.stderr)
    summary = dataclasses.replace(summary, log=str(args.out))
    if args.json:
        print(json.dumps(summary.to_dict()))
    else:
        print(f"rig         {config.name} ({url})")
        print(f"experiment  {excitation.name} ({excitation.kind}, seed {excitation.seed})")
        print(f"samples     {summary.samples} at {config.sample_rate_hz:g} Hz (achieved {summary.rate_hz:.6g} Hz)")
        print(f"lost        {summary.lost}")
        if not math.isnan(summary.send_lateness_max_s):  # the host owns the clock: it measured its sends
            print(f"late        {summary.late}")
            print(f"send lateness p50 {1e6 * summary.send_lateness_p50_s:.0f} us, p99 "
                  f"{1e6 * summary.send_lateness_p99_s:.0f} us, max {1e6 * summary.send_lateness_max_s:.0f} us "
                  "(each setpoint's send after its deadline)")
        else:  # the device owns the clock: a late setpoint is a HELD sample, logged with the command applied
            lead = ("not measured on this run" if math.isnan(summary.min_lead_s)
                    else f"{1e3 * summary.min_lead_s:.3g} ms")
            print(f"held        {summary.held} (setpoints that missed their instant; smallest lead {lead})")
        if not math.isnan(summary.sync_jitter_max_s):
            print(f"sync jitter {1e3 * summary.sync_jitter_max_s:.3g} ms at most (SYNC spacing off the period)")
        print(f"duplicate   {summary.duplicate}")
        if summary.not_followed:
            print(f"not followed {summary.not_followed} (the drive ignored the target: statusword bit 12 clear)")
        print(f"frame errors {summary.frame_errors} (CRC failures, malformed or CAN error frames; ridden through)")
        for warning in summary.warnings:
            print(f"warning     {warning}")
        print(f"stop        {summary.stop}")
        print(f"log         {Path(args.out)}")
    sys.stdout.flush()
    return exit_codes.SUCCESS
