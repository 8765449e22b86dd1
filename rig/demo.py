"""``rig demo``: the whole chain on the simulated rig, over a real transport.

The simulated precision gearbox (``configs/plants/precision_gearbox.toml``: 1:4 ratio, asymmetric play,
friction, a torsion mode, 12-bit load encoder) is served by simulated devices on the chosen wire protocol,
and every experiment is streamed to it by the same runner that drives a real rig:

1. the filter-pole search of the steady-state experiment (Cerone et al. 2009, Appendix), one step
   experiment per trial pole, then the filtered square-wave staircase (Section 3);
2. the PRBS experiment (Section 4) and the cyclic random experiment (Pouliquen et al. 2013, Table I);
3. set-membership bounds on the backlash and the linear block, with the paper's method and the coupled one;
4. the Hammerstein subspace identification;
5. the model-discrepancy workflow against a nominal model that lacks the backlash.

This module is application layer: it is one of the two places (with :mod:`rig.commands.run`) that wires a
simulated device to a transport.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.experiment_record import ExperimentRecord, SampleFlag
from identify.plant_blocks import Delay, LinearBlock, OutputBacklash, PlantModel, Resonance
from rig.protocols.errors import TransportError

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
TRANSPORTS = ("canopen", "can", "serial")
SIMULATED_RIG_PENDING_CYCLES = 100
"""The simulated devices share the driver's process: when the host stalls they stall too, so their
feedback arrives late but is never really lost; file it up to 100 ms late (flagged LATE)."""


@dataclass(frozen=True)
class DemoPlan:
    """What the demo runs; :data:`FULL_PLAN` is the default, :data:`QUICK_PLAN` a shorter one for tests.

    Amplitudes are motor-side command angles in radians (the gearbox reduces 1:4).
    """

    staircase_amplitudes_rad: tuple[float, ...]
    samples_per_half_wave: int
    filter_step_amplitude_rad: float
    reference_pole: float
    pole_tolerance: float
    prbs_samples: int
    prbs_amplitude_rad: float
    cyclic_samples: int
    cyclic_range_rad: float
    hold_samples: int
    num_nodes: int
    na: int = 4
    nk: int = 2
    nb: int = 5
    seed: int = 2026


FULL_PLAN = DemoPlan(
    staircase_amplitudes_rad=tuple(np.linspace(1.0, 4.0, 8)), samples_per_half_wave=400,
    filter_step_amplitude_rad=4.0, reference_pole=0.95, pole_tolerance=0.02,
    prbs_samples=120, prbs_amplitude_rad=2.0,
    cyclic_samples=4100, cyclic_range_rad=2.0, hold_samples=50, num_nodes=8,
)
QUICK_PLAN = replace(
    FULL_PLAN, staircase_amplitudes_rad=tuple(np.linspace(1.0, 4.0, 5)), samples_per_half_wave=300,
    pole_tolerance=0.05, prbs_samples=60, cyclic_samples=1500,
)


@dataclass(frozen=True)
class TrueGearbox:
    """The simulated gearbox's parameters in the structures the methods estimate."""

    backlash: OutputBacklash
    linear: LinearBlock  # delay, drive loop and torsion mode in one A(q^-1), B(q^-1)
    plant: PlantModel

    @property
    def play_rad(self) -> float:
        """Total play seen at the load, m_l c_l + m_r c_r: the gap between the two backlash lines."""
        return self.backlash.m_l * self.backlash.c_l + self.backlash.m_r * self.backlash.c_r

    def nominal_without_backlash(self) -> PlantModel:
        """The plant with its play replaced by the bare gear ratio: the model a user would start from."""
        blocks = self.plant.blocks
        index = next(k for k, block in enumerate(blocks) if isinstance(block, OutputBacklash))
        ratio = LinearBlock((), (0.5 * (self.backlash.m_l + self.backlash.m_r),), self.linear.sample_period_s)
        return self.plant.without(OutputBacklash).with_block(ratio, index)

    def theta(self, na: int, nk: int, nb: int) -> dict[str, float]:
        """θ = (a_1..a_na, b_nk..b_nb) of :attr:`linear`, named as the bounds name them."""
        a = np.zeros(na)
        a[: len(self.linear.a)] = self.linear.a
        b = np.zeros(nb + 1)
        b[: len(self.linear.b)] = self.linear.b
        return {**{f"a{i + 1}": float(a[i]) for i in range(na)}, **{f"b{i}": float(b[i]) for i in range(nk, nb + 1)}}


def true_gearbox(plant: PlantModel) -> TrueGearbox:
    """Collapse the plant's delay, linear blocks and resonances into one A, B (in signal order)."""
    a_poly, b_poly = np.array([1.0]), np.array([1.0])
    for block in plant.blocks:
        if isinstance(block, Resonance):
            block = block.to_linear_block()
        if isinstance(block, LinearBlock):
            a_poly = np.convolve(a_poly, np.r_[1.0, block.a])
            b_poly = np.convolve(b_poly, block.b)
        elif isinstance(block, Delay):
            b_poly = np.r_[np.zeros(block.samples), b_poly]
    (backlash,) = plant.find(OutputBacklash)
    linear = LinearBlock(tuple(a_poly[1:]), tuple(b_poly), plant.sample_period_s or 1.0)
    return TrueGearbox(backlash, linear, plant)


@dataclass(frozen=True)
class DemoRun:
    """One experiment streamed over the wire."""

    name: str
    record: ExperimentRecord
    log_path: Path | None
    late: int
    lost: int


@dataclass(frozen=True)
class DemoOutcome:
    """Everything the demo measured and identified."""

    transport: str
    truth: TrueGearbox
    plan: DemoPlan
    noise_bound_rad: float
    filter_design: Any
    filter_pole: float  # the pole used: the design's, or slower where the drive's rate limit requires
    runs: dict[str, DemoRun]
    steady_input_rad: NDArray[np.float64]
    steady_output_rad: NDArray[np.float64]
    set_membership: dict[str, Any]  # method -> OutputBacklashIdentification
    hammerstein: Any
    discrepancy: Any
    report_index: Path | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    retries: dict[str, int] = field(default_factory=dict)  # experiment -> runs repeated after lost or held samples


class SimulatedRigSession:
    """Streams experiments to a freshly started simulated rig (plant at rest) over ``transport``."""

    def __init__(self, transport: str, out_dir: Path | None,
                 progress: Callable[[str, int], Callable[[int, int], None] | None] | None = None) -> None:
        from rig.rig_config import load_rig_config

        if transport not in TRANSPORTS:
            raise ValueError(f"--transport: expected one of {', '.join(TRANSPORTS)}, got {transport!r}")
        self.transport = transport
        self.config = load_rig_config(CONFIG_DIR / f"sim_{transport}.toml")
        self.out_dir = out_dir
        self.progress = progress
        self.runs: dict[str, DemoRun] = {}
        self.retries: dict[str, int] = {}
        self.max_attempts = 5

    def run(self, name: str, command_rad: NDArray[np.float64], *, keep_log: bool = True,
            max_lost: int = 0) -> ExperimentRecord:
        """Stream ``command_rad`` from rest; return a record with at most ``max_lost`` samples off the
        design (unusable, or HELD: the drive applied an earlier setpoint than the designed one, which a
        cyclic excitation cannot tolerate).

        A host too busy to keep the rate loses samples (they are flagged in the log). An experiment that
        lost more than ``max_lost`` is run again from rest, up to :attr:`max_attempts` times; the repeats
        are counted in :attr:`retries`. The log goes to ``out_dir/logs/<name>.csv`` when kept.
        """
        for attempt in range(1, self.max_attempts + 1):
            record = self._run_once(name, command_rad, keep_log=keep_log)
            if _samples_off_design(record) <= max_lost:
                return record
            self.retries[name] = attempt
        raise TransportError(f"{name}: {_samples_off_design(record)} samples were lost, faulted or held "
                           f"(at most {max_lost} can be used) in each of {self.max_attempts} attempts; the host "
                           "cannot keep the rig's rate: close other programs and run again, or try --transport serial")

    def _run_once(self, name: str, command_rad: NDArray[np.float64], *, keep_log: bool) -> ExperimentRecord:
        import tempfile

        from rig.commands.run import experiment_log_metadata
        from rig.experiment_config import Excitation
        from rig.log_file import LogWriter, read_log
        from rig.runner import run_experiment
        from rig.transports import open_transport
        from rig.transports.simulated import simulated_rig

        with contextlib.ExitStack() as stack:
            if keep_log and self.out_dir is not None:
                log_path = self.out_dir / "logs" / f"{name}.csv"
                log_path.parent.mkdir(parents=True, exist_ok=True)
            else:
                log_path = Path(stack.enter_context(tempfile.TemporaryDirectory())) / f"{name}.csv"
            url, gearbox = stack.enter_context(simulated_rig(self.config, command_rad))
            excitation = Excitation(name=name, kind="demo", command_rad=command_rad, seed=None)
            writer = LogWriter(log_path, experiment_log_metadata(self.config, excitation, gearbox, command_rad.size),
                               flush_every=100, flush_interval_s=0.1)
            progress = self.progress(name, command_rad.size) if self.progress else None
            summary = run_experiment(open_transport(url, **self.config.transport_options()), command_rad, writer,
                                     feedback_timeout_s=self.config.feedback_timeout_s,
                                     late_tolerance_s=self.config.late_tolerance_s,
                                     pending_cycles=SIMULATED_RIG_PENDING_CYCLES, progress=progress)
            record = read_log(log_path)
        self.runs[name] = DemoRun(name, record, log_path if keep_log and self.out_dir else None,
                                  summary.late, summary.lost)
        return record


def _samples_off_design(record: ExperimentRecord) -> int:
    """Samples unusable, or HELD (the command really applied is not the designed one)."""
    held = (record.flags & int(SampleFlag.HELD)) != 0
    return int(np.count_nonzero(~record.valid_mask | held))


def last_valid_values(record: ExperimentRecord, indices: NDArray[np.int64], max_age: int) -> NDArray[np.float64]:
    """The measured angle at each of ``indices`` or, where that sample was lost, at the last usable sample
    at most ``max_age`` samples before it (at steady state the output no longer moves)."""
    valid = record.valid_mask
    values = np.empty(indices.size)
    for position, index in enumerate(indices):
        usable = np.flatnonzero(valid[max(0, index - max_age): index + 1])
        if usable.size == 0:
            raise TransportError(f"{record.metadata.excitation}: samples {index - max_age}..{index} were all lost; "
                               "no steady-state value can be read there")
        values[position] = record.angle_rad[max(0, index - max_age) + usable[-1]]
    return values


DEMO_STEPS = 9
"""Steps that :func:`run_demo` reports through ``steps``: filter pole, staircase, PRBS, cyclic, two
set-membership methods, Hammerstein, discrepancy and the report."""


def run_demo(out_dir: Path | None, transport: str = "canopen", plan: DemoPlan = FULL_PLAN,
             steps: Callable[[str], contextlib.AbstractContextManager[Any]] | None = None,
             progress: Callable[[str, int], Callable[[int, int], None] | None] | None = None) -> DemoOutcome:
    """Run the whole chain and return what it found; writes logs and a report under ``out_dir``.

    ``steps(description)`` is entered around each step (the command line shows a progress bar with it);
    ``progress(name, samples)`` returns the per-sample callback of each experiment.
    """
    import time

    from identify.border_lifting import PathNodes
    from identify.cyclic_excitation import cyclic_random_excitation
    from identify.excitation_design import (design_filter_pole, filtered_staircase, prbs_sequence,
                                            staircase_steady_state_indices)
    from identify.hammerstein_subspace import identify_hammerstein
    from identify.model_discrepancy import diagnose_model
    from identify.output_backlash_identification import bound_output_backlash_system
    from sim_backend.plant_config import load_plant_config

    step = steps or (lambda description: contextlib.nullcontext())
    session = SimulatedRigSession(transport, out_dir, progress)
    plant_config = load_plant_config(session.config.simulation.plant_path)
    truth = true_gearbox(plant_config.plant)
    gearbox = plant_config.gearbox(seed=session.config.simulation.seed)
    noise_bound = gearbox.measurement_error_bound_rad
    timings: dict[str, float] = {}

    @contextlib.contextmanager
    def timed(key: str, description: str) -> Iterator[None]:
        start = time.perf_counter()
        with step(description):
            yield
        timings[key] = time.perf_counter() - start

    trial_count = 0
    steady_tail = plan.samples_per_half_wave // 10  # the last 10 % of a half-wave is at steady state

    def run_step_experiment(command: NDArray[np.float64]) -> NDArray[np.float64]:
        nonlocal trial_count
        trial_count += 1
        record = session.run(f"pole_trial_{trial_count:02d}", command, keep_log=False, max_lost=steady_tail)
        return last_valid_values(record, np.array([len(record) - 1]), steady_tail)  # the search reads y[-1]

    with timed("filter_pole", "search the filter pole (step experiments over the wire)"):
        design = design_filter_pole(run_step_experiment, plan.filter_step_amplitude_rad,
                                    reference_pole=plan.reference_pole, num_samples=plan.samples_per_half_wave,
                                    noise_bound_rad=noise_bound, pole_tolerance=plan.pole_tolerance)
    amplitudes = list(plan.staircase_amplitudes_rad)
    with timed("staircase", "run the filtered staircase"):
        # A slower pole than the design's fastest one is as good for steady state; take one slow enough that
        # the first step of the largest half-wave, (1 - a) 2 max(β), stays within the drive's rate limit.
        limits = session.config.limits
        rate_limited_pole = 1.0 - 0.99 * limits.rate_max_rad_per_s * session.config.sample_period_s / (2 * max(amplitudes))
        filter_pole = max(design.filter_pole, rate_limited_pole)
        staircase = filtered_staircase(amplitudes, filter_pole, plan.samples_per_half_wave)
        steady_index = staircase_steady_state_indices(len(amplitudes), plan.samples_per_half_wave)
        steady_record = session.run("staircase", staircase, max_lost=staircase.size // 100)
        steady_output = last_valid_values(steady_record, steady_index, steady_tail)
    rng = np.random.default_rng(plan.seed)
    with timed("prbs", "run the PRBS experiment"):
        prbs = prbs_sequence(plan.prbs_samples, plan.prbs_amplitude_rad, rng)
        prbs_output = session.run("prbs", prbs).angle_rad
    with timed("cyclic", "run the cyclic random experiment"):
        cyclic = cyclic_random_excitation(plan.cyclic_samples, -plan.cyclic_range_rad, plan.cyclic_range_rad,
                                          plan.hold_samples, rng)
        # No lost sample is filled in: the play is a few counts, and interpolating a burst of samples across
        # the random jumps of the excitation biases the borders by more than that.
        cyclic_output = session.run("cyclic", cyclic).angle_rad

    set_membership = {}
    for method in ("paper", "coupled"):
        with timed(f"set_membership_{method}", f"bound backlash and linear block ({method} method)"):
            set_membership[method] = bound_output_backlash_system(
                staircase[steady_index], steady_output, prbs, prbs_output, noise_bound, na=plan.na, nk=plan.nk,
                nb=plan.nb, method=method, filter_step_amplitude_rad=plan.filter_step_amplitude_rad)
    with timed("hammerstein", "identify the Hammerstein model"):
        hammerstein = identify_hammerstein(
            cyclic, cyclic_output, PathNodes.uniform(-plan.cyclic_range_rad, plan.cyclic_range_rad, plan.num_nodes),
            hold_samples=plan.hold_samples, order=plan.na)  # the order of the drive loop and torsion mode
    with timed("discrepancy", "diagnose a nominal model that lacks the backlash"):
        discrepancy = diagnose_model(cyclic, cyclic_output, noise_bound, truth.linear.sample_period_s,
                                     model=truth.nominal_without_backlash())

    outcome = DemoOutcome(
        transport=transport, truth=truth, plan=plan, noise_bound_rad=noise_bound, filter_design=design,
        filter_pole=filter_pole,
        runs=dict(session.runs), steady_input_rad=staircase[steady_index], steady_output_rad=steady_output,
        set_membership=set_membership, hammerstein=hammerstein, discrepancy=discrepancy, timings_s=timings,
        retries=dict(session.retries))
    if out_dir is not None:
        from rig.demo_report import write_demo_report

        with timed("report", "write the report"):
            index = write_demo_report(outcome, out_dir)
        outcome = replace(outcome, report_index=index, timings_s=timings)
    return outcome


def summary_rows(outcome: DemoOutcome) -> list[tuple[str, str, str, str]]:
    """(quantity, true, paper bounds, coupled bounds or estimate) rows of the demo's summary table."""
    truth = outcome.truth
    rows: list[tuple[str, str, str, str]] = []
    paper, coupled = outcome.set_membership["paper"], outcome.set_membership["coupled"]

    def interval(result: Any, group: str, name: str) -> str:
        if result.is_empty:
            return "empty set"
        bounds = (result.backlash_intervals if group == "backlash" else result.linear_intervals)[name]
        return f"[{bounds.lower:.5g}, {bounds.upper:.5g}]"

    backlash_truth = {"m_l": truth.backlash.m_l, "c_l": truth.backlash.c_l, "m_r": truth.backlash.m_r,
                      "c_r": truth.backlash.c_r}
    for name, value in backlash_truth.items():
        rows.append((f"backlash {name}", f"{value:.5g}", interval(paper, "backlash", name),
                     interval(coupled, "backlash", name)))
    for name, value in truth.theta(outcome.plan.na, outcome.plan.nk, outcome.plan.nb).items():
        rows.append((f"linear {name}", f"{value:.5g}", interval(paper, "linear", name),
                     interval(coupled, "linear", name)))
    model = outcome.hammerstein
    gap = np.asarray(model.descending_border.values)[1:-1] - np.asarray(model.ascending_border.values)[1:-1]
    rows.append(("Hammerstein play [rad]", f"{truth.play_rad:.4g}", "-", f"{float(np.median(gap)):.4g} (median gap)"))
    true_poles = np.sort_complex(np.roots(np.r_[1.0, truth.linear.a]))
    dominant = true_poles[np.argmax(np.abs(true_poles))]
    estimated = model.poles[np.argmax(np.abs(model.poles))]
    rows.append(("Hammerstein slowest pole |p|", f"{abs(dominant):.4f}", "-",
                 f"{abs(estimated):.4f} (order {model.order}, given)"))
    diagnosis = outcome.discrepancy
    found = ", ".join(diagnosis.missing_effects) or "none"
    rows.append(("discrepancy: missing effect", "backlash", "-", found))
    backlash_step = next((step for step in diagnosis.steps if step.effect == "backlash"), None)
    if backlash_step is not None:
        fitted = sum(value for key, value in backlash_step.parameters.items() if key.startswith("c_"))
        rows.append(("discrepancy: fitted play [rad]", f"{truth.play_rad:.4g}", "-", f"{fitted:.4g}"))
    rows.append(("discrepancy: gap [rad]", "-", f"{diagnosis.initial.gap_rad:.3g} (nominal)",
                 f"{diagnosis.final.gap_rad:.3g} (with {found})"))
    return rows


def format_summary(outcome: DemoOutcome) -> str:
    """The demo's summary table as text."""
    header = ("quantity", "true", "paper method", "coupled method / estimate")
    rows = [header, *summary_rows(outcome)]
    widths = [max(len(row[column]) for row in rows) for column in range(4)]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)) for row in rows]
    lines.insert(1, "  ".join("-" * width for width in widths))
    runs = outcome.runs
    samples = sum(len(run.record) for run in runs.values())
    lost = sum(run.lost for run in runs.values())
    late = sum(run.late for run in runs.values())
    lines.append("")
    lines.append(f"{len(runs)} experiments over {outcome.transport}: {samples} samples, {lost} lost, {late} late; "
                 f"filter pole a = {outcome.filter_pole:.4g} (search: {outcome.filter_design.filter_pole:.4g}); "
                 f"noise bound {outcome.noise_bound_rad:.3g} rad")
    if outcome.retries:
        lines.append("repeated after lost or held samples (busy host): "
                     + ", ".join(f"{name} x{count}" for name, count in outcome.retries.items()))
    if math.isfinite(sum(outcome.timings_s.values())):
        lines.append("time per step: " + ", ".join(f"{key} {value:.1f} s" for key, value in outcome.timings_s.items()))
    return "\n".join(lines)
