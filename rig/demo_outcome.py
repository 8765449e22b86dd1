"""What ``rig demo`` runs and what it found: the plan, the true gearbox, the outcome and its summary table.

The lowest module of the demo: :mod:`rig.demo` runs the chain and builds a :class:`DemoOutcome`,
:mod:`rig.demo_report` draws one; both import this module and neither imports the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.experiment_record import ExperimentRecord
from identify.plant_blocks import Delay, LinearBlock, OutputBacklash, PlantModel, Resonance
from rig.report import format_interval

__all__ = ["FULL_PLAN", "NOMINAL_MODEL_FILE", "QUICK_PLAN", "SUMMARY_HEADER", "DemoOutcome", "DemoPlan", "DemoRun",
           "TrueGearbox", "format_summary", "reproduce_commands", "summary_rows", "true_gearbox"]


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
        return self.backlash.m_l * self.backlash.c_l_rad + self.backlash.m_r * self.backlash.c_r_rad

    @property
    def backlash_values(self) -> dict[str, float]:
        """γ = (m_l, c_l, m_r, c_r) by name, as the bounds name them."""
        backlash = self.backlash
        return {"m_l": backlash.m_l, "c_l": backlash.c_l_rad, "m_r": backlash.m_r, "c_r": backlash.c_r_rad}

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
    """One experiment streamed over the wire.

    ``late``, ``held`` and ``min_lead_s`` are those of :class:`rig.runner.RunSummary`: ``late`` counts the
    samples flagged LATE, ``held`` those flagged HELD. On a device-clocked link a LATE sample is one whose instant was off the
    period by more than the late tolerance (over CANopen: the spacing of the SYNCs on the bus, which on the
    simulated rig come from a host thread and jitter with the machine's load); its value is exact, its time
    k T is not. ``lead_s`` is how far ahead of the device's sample instants the setpoints were queued (0:
    host-paced).
    """

    name: str
    record: ExperimentRecord
    log_path: Path | None
    late: int
    lost: int
    held: int = 0
    lead_s: float = 0.0
    min_lead_s: float = math.nan


@dataclass(frozen=True)
class DemoOutcome:
    """Everything the demo measured and identified.

    ``filter_pole`` is the pole of the staircase that was run (:func:`rig.demo.staircase_filter_pole`),
    ``filter_design`` the search of the Appendix; ``filter_pole_reason`` says why the one was chosen.
    """

    transport: str
    truth: TrueGearbox
    plan: DemoPlan
    noise_bound_rad: float
    filter_design: Any
    filter_pole: float
    runs: dict[str, DemoRun]
    steady_input_rad: NDArray[np.float64]
    steady_output_rad: NDArray[np.float64]
    set_membership: dict[str, Any]  # method -> OutputBacklashIdentification
    hammerstein: Any
    discrepancy: Any
    filter_pole_reason: str = ""
    report_index: Path | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    retries: dict[str, int] = field(default_factory=dict)  # experiment -> runs repeated after lost or held samples

    def truth_in_backlash_set(self, method: str) -> dict[str, bool]:
        """Per side, whether the true (m, m·c) lies in the exact feasible set D_γ of ``method``'s result
        (:meth:`identify.feasible_parameter_set.BacklashFeasibleSet.contains`); empty when the set is."""
        result = self.set_membership[method]
        if result.backlash.is_empty:
            return {}
        truth = self.truth.backlash
        return result.backlash.contains(truth.m_l, truth.c_l_rad, truth.m_r, truth.c_r_rad)


def _membership_text(sides: dict[str, bool]) -> str:
    if not sides:
        return "empty set"
    return ", ".join(f"{side} {'inside' if inside else 'OUTSIDE'}" for side, inside in sides.items())


def _interval_cell(result: Any, group: str, name: str) -> str:
    if result.is_empty:
        return "empty set"
    bounds = (result.backlash_intervals if group == "backlash" else result.linear_intervals)[name]
    return format_interval(bounds.lower, bounds.upper)


def summary_rows(outcome: DemoOutcome) -> list[tuple[str, str, str, str]]:
    """(quantity, true, paper method, coupled method or estimate) rows of the demo's summary table.

    Every verdict here is the one the figures draw: the backlash membership row is
    :meth:`DemoOutcome.truth_in_backlash_set`, the Hammerstein play
    :meth:`identify.hammerstein_model.HammersteinModel.play_at_nodes` (as the borders figure quotes it), the
    discrepancy's play the sum of the fitted c with their cross-validated intervals.
    """
    truth = outcome.truth
    rows: list[tuple[str, str, str, str]] = []
    paper, coupled = outcome.set_membership["paper"], outcome.set_membership["coupled"]
    for name, value in truth.backlash_values.items():
        rows.append((f"backlash {name}", f"{value:.5g}", _interval_cell(paper, "backlash", name),
                     _interval_cell(coupled, "backlash", name)))
    rows.append(("backlash: true (m, m·c) in the exact set D_γ", "-",
                 _membership_text(outcome.truth_in_backlash_set("paper")),
                 _membership_text(outcome.truth_in_backlash_set("coupled"))))
    for name, value in truth.theta(outcome.plan.na, outcome.plan.nk, outcome.plan.nb).items():
        rows.append((f"linear {name}", f"{value:.5g}", _interval_cell(paper, "linear", name),
                     _interval_cell(coupled, "linear", name)))
    model = outcome.hammerstein
    rows.append(("Hammerstein play [rad]", f"{truth.play_rad:.4g}", "-", model.play_at_nodes().describe()))
    true_poles = np.sort_complex(np.roots(np.r_[1.0, truth.linear.a]))
    dominant = true_poles[np.argmax(np.abs(true_poles))]
    rows.append(("Hammerstein slowest pole |p|", f"{abs(dominant):.4f}", "-",
                 f"{model.max_pole_magnitude:.4f} (order {model.order}, given)"))
    diagnosis = outcome.discrepancy
    found = ", ".join(diagnosis.missing_effects) or "none"
    others = [effect for effect in diagnosis.ambiguous_between if effect not in diagnosis.missing_effects]
    rows.append(("discrepancy: missing effect", "backlash", "-",
                 f"{found}, or {' or '.join(others)}: ambiguous (the section says what tells them apart)"
                 if diagnosis.verdict == "ambiguous" and others else found))
    backlash_step = next((step for step in diagnosis.steps if step.effect == "backlash"), None)
    if backlash_step is not None:
        keys = [key for key in backlash_step.parameters if key.startswith("c_")]
        fitted = sum(backlash_step.parameters[key] for key in keys)
        intervals = diagnosis.parameter_intervals.get("backlash", {})
        cell = f"{fitted:.4g}"
        if all(key in intervals for key in keys):
            low, high = (sum(intervals[key][end] for key in keys) for end in (0, 1))
            cell += f" in {format_interval(low, high, digits=4)}"
        rows.append(("discrepancy: fitted play c_l + c_r [rad]", f"{truth.play_rad:.4g}", "-", cell))
    rows.append(("discrepancy: gap of the nominal model [rad]", "-", "-", f"{diagnosis.initial.gap_rad:.3g}"))
    rows.append((f"discrepancy: gap with {found} [rad]", "-", "-", f"{diagnosis.final.gap_rad:.3g}"))
    return rows


SUMMARY_HEADER = ("quantity", "true", "paper method", "coupled method or estimate")

NOMINAL_MODEL_FILE = "nominal_model.toml"
"""The model the demo diagnoses (the simulated gearbox with its play replaced by the gear ratio), written in the
report directory beside ``logs/`` as a plant config that ``rig diagnose --model`` reads."""


def reproduce_commands(outcome: DemoOutcome) -> tuple[tuple[str, str], ...]:
    """(what it gives, command): the ``rig`` commands that compute the summary's numbers again from the logs the
    demo saved, run in its report directory. The demo reads those logs as these commands do (the command as
    sent, the staircase's steady points as ``--steady`` takes them) with the same settings, so they print the
    same numbers."""
    plan = outcome.plan
    noise = repr(float(outcome.noise_bound_rad))
    bounds = (f"rig identify output-backlash --steady logs/staircase.csv --dynamic logs/prbs.csv --noise-bound {noise} "
              f"--na {plan.na} --nk {plan.nk} --nb {plan.nb} --filter-step {float(plan.filter_step_amplitude_rad)!r}")
    return (
        ("backlash and linear rows, paper method", f"{bounds} --method paper"),
        ("backlash and linear rows, coupled method", f"{bounds} --method coupled"),
        ("Hammerstein rows", f"rig identify hammerstein logs/cyclic.csv --num-nodes {plan.num_nodes} "
                             f"--hold-samples {plan.hold_samples} --order {plan.na}"),
        ("discrepancy rows", f"rig diagnose logs/cyclic.csv --model {NOMINAL_MODEL_FILE} --noise-bound {noise}"),
    )


def format_summary(outcome: DemoOutcome) -> str:
    """The demo's summary table as text."""
    rows = [SUMMARY_HEADER, *summary_rows(outcome)]
    widths = [max(len(row[column]) for row in rows) for column in range(4)]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)) for row in rows]
    lines.insert(1, "  ".join("-" * width for width in widths))
    runs = outcome.runs
    samples = sum(len(run.record) for run in runs.values())
    lost = sum(run.lost for run in runs.values())
    late = sum(run.late for run in runs.values())
    held = sum(run.held for run in runs.values())
    lines.append("")
    lines.append(f"{len(runs)} experiments over {outcome.transport}: {samples} samples, {lost} lost, {held} held, "
                 f"{late} late (sampled at an instant off the period: values exact, time column nominal); "
                 f"noise bound {outcome.noise_bound_rad:.3g} rad")
    lines.append(f"staircase filter pole a = {outcome.filter_pole:.4g}: {outcome.filter_pole_reason}")
    if outcome.retries:
        lines.append("repeated after lost or held samples (busy host): "
                     + ", ".join(f"{name} x{count}" for name, count in outcome.retries.items()))
    if math.isfinite(sum(outcome.timings_s.values())):
        lines.append("time per step: " + ", ".join(f"{key} {value:.1f} s" for key, value in outcome.timings_s.items()))
    return "\n".join(lines)
