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
simulated device to a transport. What it finds is a :class:`rig.demo_outcome.DemoOutcome`, drawn by
:mod:`rig.demo_report`; neither of those imports this module.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from identify.experiment_record import ExperimentRecord, SampleFlag
from rig.demo_outcome import (FULL_PLAN, NOMINAL_MODEL_FILE, QUICK_PLAN, DemoOutcome, DemoPlan, DemoRun, TrueGearbox,
                              format_summary, reproduce_commands, summary_rows, true_gearbox)
from rig.demo_report import write_demo_report
from rig.protocols.errors import TransportError

if TYPE_CHECKING:
    from identify.excitation_design import FilterPoleDesign
    from sim_backend.plant_config import PlantConfig

__all__ = ["DEMO_STEPS", "FULL_PLAN", "QUICK_PLAN", "SimulatedRigSession", "format_summary", "last_valid_values",
           "reproduce_commands", "run_demo", "staircase_filter_pole", "summary_rows"]
# FULL_PLAN, QUICK_PLAN, format_summary, reproduce_commands and summary_rows live in rig.demo_outcome; `rig demo`
# reads them here.

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
TRANSPORTS = ("canopen", "can", "serial")
SIMULATED_RIG_PENDING_CYCLES = 100
"""The simulated devices share the driver's process: when the host stalls they stall too, so their
feedback arrives late but is never really lost; file it up to 100 cycles after its instant (a later answer
finds its row final: LOST)."""


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
            max_lost: int = 0, kind: str = "demo", parameters: dict | None = None) -> ExperimentRecord:
        """Stream ``command_rad`` from rest; return a record with at most ``max_lost`` samples off the
        design (unusable, or HELD: the drive applied an earlier setpoint than the designed one, which a
        cyclic excitation cannot tolerate).

        A host too busy to keep the rate loses samples (they are flagged in the log). An experiment that
        lost more than ``max_lost`` is run again from rest, up to :attr:`max_attempts` times; so is one whose
        link failed (the simulated devices run in this process: a host stall longer than the feedback
        watchdog starves them too, which on a real rig would be a fault). The repeats are counted in
        :attr:`retries`. The log goes to ``out_dir/logs/<name>.csv`` when kept, its excitation recorded as
        ``kind`` with ``parameters`` (as an experiment config would give them), so that the commands that read
        a log by its excitation (``rig identify output-backlash --steady``) take the demo's logs too.
        """
        problem = ""
        for attempt in range(1, self.max_attempts + 1):
            try:
                record = self._run_once(name, command_rad, keep_log=keep_log, kind=kind, parameters=parameters)
            except TransportError as err:  # the link itself is in this process: a stall, not a broken wire
                problem = f"the link failed ({err})"
            else:
                if _samples_off_design(record) <= max_lost:
                    return record
                problem = (f"{_samples_off_design(record)} samples were lost, faulted or held (at most {max_lost} "
                           "can be used)")
            self.retries[name] = attempt
        other_wire = ", or try --transport serial" if self.transport != "serial" else ""
        raise TransportError(f"{name}: in each of {self.max_attempts} attempts {problem}; the host cannot keep the "
                             f"rig's rate: close other programs and run again{other_wire}")

    def _run_once(self, name: str, command_rad: NDArray[np.float64], *, keep_log: bool, kind: str = "demo",
                  parameters: dict | None = None) -> ExperimentRecord:
        import tempfile

        from rig.experiment_config import Excitation
        from rig.log_file import LogWriter, read_log
        from rig.log_metadata import experiment_log_metadata
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
            excitation = Excitation(name=name, kind=kind, command_rad=command_rad, seed=None,
                                    parameters=dict(parameters or {}))
            transport = open_transport(url, **self.config.transport_options())
            writer = LogWriter(log_path, experiment_log_metadata(self.config, excitation, gearbox, command_rad.size),
                               flush_every=100, flush_interval_s=0.1, stamp_start=True,
                               drive_torque_unit=transport.drive_torque_unit)
            progress = self.progress(name, command_rad.size) if self.progress else None
            summary = run_experiment(transport, command_rad, writer,
                                     feedback_timeout_s=self.config.feedback_timeout_s,
                                     late_tolerance_s=self.config.late_tolerance_s,
                                     pending_cycles=SIMULATED_RIG_PENDING_CYCLES, progress=progress)
            record = read_log(log_path)
        self.runs[name] = DemoRun(name, record, log_path if keep_log and self.out_dir else None,
                                  summary.late, summary.lost, held=summary.held,
                                  lead_s=transport.lead_samples * transport.sample_period_s,
                                  min_lead_s=summary.min_lead_s)
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


def staircase_filter_pole(design: FilterPoleDesign, amplitudes_rad: list[float], rate_max_rad_per_s: float,
                          sample_period_s: float) -> tuple[float, str]:
    """The pole a of the filtered staircase and why: the search's reference pole ā, or slower where the
    drive's rate limit requires (the first step of the largest half-wave, (1 - a) 2 max β, within it).

    The search (Appendix of Cerone et al. 2009) accepts a faster pole when the steady output of its step
    moves by at most 2Δη; the strips of eqs. (14)-(15) absorb only α_s = 2Δη |ū_s| / r̄_F of such a move
    at amplitude ū_s, and the staircase's half-waves jump by about 2ū_s. An overshoot of x_t that the play
    holds (through a lightly damped torsion mode) can then put the true backlash outside D_γ while the
    search sees nothing; ā is the pole the Appendix takes as slow enough that x_t does not overshoot.
    ``design`` is the search's result.
    """
    rate_limited = 1.0 - 0.99 * rate_max_rad_per_s * sample_period_s / (2 * max(amplitudes_rad))
    reference = float(design.reference_pole)
    reason = (f"the reference pole ā of the search, which accepted a = {design.filter_pole:.3g} by a test that "
              f"tolerates a {design.threshold_rad:.3g} rad move of the steady output (2Δη): more than the strips "
              "of D_γ absorb at the staircase's smaller amplitudes, if an overshoot of x_t is held by the play")
    if rate_limited > reference:
        return rate_limited, f"slower than the reference pole ā = {reference:g}, for the drive's rate limit"
    return reference, reason


DEMO_STEPS = 9
"""Steps that :func:`run_demo` reports through ``steps``: filter pole, staircase, PRBS, cyclic, two
set-membership methods, Hammerstein, discrepancy and the report."""


def run_demo(out_dir: Path | None, transport: str = "canopen", plan: DemoPlan = FULL_PLAN,
             steps: Callable[[str], contextlib.AbstractContextManager[Any]] | None = None,
             progress: Callable[[str, int], Callable[[int, int], None] | None] | None = None) -> DemoOutcome:
    """Run the whole chain and return what it found; writes the logs (``logs/``), the nominal model it diagnoses
    (:data:`rig.demo_outcome.NOMINAL_MODEL_FILE`) and a report under ``out_dir``. Every method reads the logs as
    the commands of :func:`rig.demo_outcome.reproduce_commands` read them, so those give the same numbers.

    ``steps(description)`` is entered around each step (the command line shows a progress bar with it);
    ``progress(name, samples)`` returns the per-sample callback of each experiment.
    """
    import time

    from identify.border_lifting import PathNodes
    from identify.cyclic_excitation import cyclic_random_excitation
    from identify.excitation_design import design_filter_pole, filtered_staircase, prbs_sequence
    from identify.hammerstein_subspace import identify_hammerstein
    from identify.model_discrepancy import diagnose_model
    from identify.output_backlash_identification import bound_output_backlash_system
    from rig.staircase_points import staircase_steady_samples
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
        filter_pole, filter_pole_reason = staircase_filter_pole(
            design, amplitudes, session.config.limits.rate_max_rad_per_s, session.config.sample_period_s)
        staircase = filtered_staircase(amplitudes, filter_pole, plan.samples_per_half_wave)
        steady_record = session.run("staircase", staircase, max_lost=staircase.size // 100, kind="filtered_staircase",
                                    parameters={"amplitudes_rad": amplitudes, "filter_pole": filter_pole,
                                                "samples_per_half_wave": plan.samples_per_half_wave})
        steady = staircase_steady_samples(steady_record, Path("staircase"), skip_unusable=True)
    rng = np.random.default_rng(plan.seed)
    with timed("prbs", "run the PRBS experiment"):
        prbs = session.run("prbs", prbs_sequence(plan.prbs_samples, plan.prbs_amplitude_rad, rng))
    with timed("cyclic", "run the cyclic random experiment"):
        # No lost sample is filled in: the play is a few counts, and interpolating a burst of samples across
        # the random jumps of the excitation biases the borders by more than that.
        cyclic = session.run("cyclic", cyclic_random_excitation(
            plan.cyclic_samples, -plan.cyclic_range_rad, plan.cyclic_range_rad, plan.hold_samples, rng))
    # From here on every method reads the logs as the commands of demo_outcome.reproduce_commands read them: the
    # command as sent over the wire (quantised by the drive's position unit), the steady points as --steady
    # takes them.

    set_membership = {}
    for method in ("paper", "coupled"):
        with timed(f"set_membership_{method}", f"bound backlash and linear block ({method} method)"):
            set_membership[method] = bound_output_backlash_system(
                steady.command_rad, steady.angle_rad, prbs.command_rad, prbs.angle_rad, noise_bound, na=plan.na,
                nk=plan.nk, nb=plan.nb, method=method, filter_step_amplitude_rad=plan.filter_step_amplitude_rad)
    with timed("hammerstein", "identify the Hammerstein model"):
        hammerstein = identify_hammerstein(
            cyclic.command_rad, cyclic.angle_rad,  # nodes over the range of u as sent, as the command's default
            PathNodes.uniform(np.min(cyclic.command_rad), np.max(cyclic.command_rad), plan.num_nodes),
            hold_samples=plan.hold_samples, order=plan.na)  # the order of the drive loop and torsion mode
    with timed("discrepancy", "diagnose a nominal model that lacks the backlash"):
        discrepancy = diagnose_model(cyclic.command_rad, cyclic.angle_rad, noise_bound, truth.linear.sample_period_s,
                                     model=truth.nominal_without_backlash())

    outcome = DemoOutcome(
        transport=transport, truth=truth, plan=plan, noise_bound_rad=noise_bound, filter_design=design,
        filter_pole=filter_pole, filter_pole_reason=filter_pole_reason,
        runs=dict(session.runs), steady_input_rad=steady.command_rad, steady_output_rad=steady.angle_rad,
        set_membership=set_membership, hammerstein=hammerstein, discrepancy=discrepancy, timings_s=timings,
        retries=dict(session.retries))
    if out_dir is not None:
        with timed("report", "write the report"):
            _write_nominal_model(plant_config, truth, out_dir / NOMINAL_MODEL_FILE)
            index = write_demo_report(outcome, out_dir)
        outcome = replace(outcome, report_index=index, timings_s=timings)
    return outcome


def _write_nominal_model(plant_config: PlantConfig, truth: TrueGearbox, path: Path) -> None:
    """The model the discrepancy step diagnoses, as a plant config for ``rig diagnose --model``."""
    from rig.output_paths import atomic_output
    from sim_backend.plant_config import plant_config_to_toml

    nominal = replace(plant_config, name=f"{plant_config.name} without its play", enabled=(),
                      blocks=truth.nominal_without_backlash().blocks,
                      description="the demo's nominal model: the simulated gearbox with its play replaced by the gear "
                                  "ratio (rig demo diagnoses what it lacks)")
    with atomic_output(path, force=True) as written:
        written.write_text(plant_config_to_toml(nominal), encoding="utf-8")
