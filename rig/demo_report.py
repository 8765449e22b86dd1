"""The report of ``rig demo``: the summary table, the experiments and every identification figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rig.demo_outcome import NOMINAL_MODEL_FILE, SUMMARY_HEADER, DemoOutcome, reproduce_commands, summary_rows
from rig.plots.discrepancy import discrepancy_section
from rig.plots.experiment import RunTiming, runs_timing_figure, signal_figure
from rig.plots.hammerstein import hammerstein_figures
from rig.plots.set_membership import default_result_figures
from rig.report import ReportSection, write_report


def demo_report_sections(outcome: DemoOutcome) -> list[ReportSection]:
    """The demo's report, section by section."""
    truth = outcome.truth
    runs = outcome.runs
    plan = outcome.plan
    backlash, u_min, u_max = truth.backlash, -plan.cyclic_range_rad, plan.cyclic_range_rad

    # On Table I cycles an output play acts like input borders: ascending from rest at u_min the load holds
    # until the play is taken up, descending from u_max likewise (unit static gain of the linear part).
    def ascending(u: float) -> float:
        return max(backlash.m_l * (u_min + backlash.c_l_rad), backlash.m_r * (u - backlash.c_r_rad))

    def descending(u: float) -> float:
        return min(backlash.m_r * (u_max - backlash.c_r_rad), backlash.m_l * (u + backlash.c_l_rad))
    experiments = [name for name in ("staircase", "prbs", "cyclic") if name in runs]
    sections = [
        ReportSection(
            "Summary",
            text=(f"The simulated precision gearbox (1:4, play c_l = {truth.backlash.c_l_rad:.4g} rad and "
                  f"c_r = {truth.backlash.c_r_rad:.4g} rad on the motor side, friction, a torsion mode, 12-bit load "
                  f"encoder) was driven over the {outcome.transport} transport. Set-membership bounds are "
                  f"guaranteed for the noise bound {outcome.noise_bound_rad:.3g} rad when the model structure "
                  "holds (a linear block, then an output backlash, reached at steady state without an overshoot of "
                  "the inner signal that the play would hold). Friction and the encoder's drift lie outside that "
                  "structure; the table's row on "
                  "D_γ says whether the exact feasible set holds the true backlash, as the polygon figure draws it. "
                  "The Hammerstein and discrepancy rows are estimates (no paper-method column); the Hammerstein "
                  "structure puts the play before the drive loop, where this gearbox has it after, so its play is "
                  "an approximation."),
            table_header=SUMMARY_HEADER,
            table_rows=tuple(summary_rows(outcome)),
        ),
        ReportSection(
            "The same numbers from the command line",
            text=("Each experiment's log is in logs/ of this directory (staircase.csv, prbs.csv, cyclic.csv), and the "
                  f"nominal model the diagnosis starts from is {NOMINAL_MODEL_FILE}. Run in this directory, these "
                  "commands print the summary's numbers again: they read the logs as the demo did and use its "
                  "settings (the table rounds to five digits)."),
            commands=tuple(line for what, command in reproduce_commands(outcome) for line in (f"# {what}", command)),
        ),
        ReportSection(
            "Experiments",
            text=("Every experiment was streamed at the rig's fixed rate by the same runner that drives a real rig. "
                  f"On the {outcome.transport} wire the device's clock owns the sample instants: the log's time "
                  "column is the instant k·T the device sampled at, so the timing figure shows what is known "
                  "instead (last figure), the samples flagged HELD, LATE or LOST and how far ahead of its instant "
                  f"each setpoint was queued. The staircase is filtered with a = {outcome.filter_pole:.4g}: "
                  f"{outcome.filter_pole_reason}."),
            figures=(*(signal_figure(runs[name].record, f"signals_{name}") for name in experiments),
                     runs_timing_figure([RunTiming(name, runs[name].record, runs[name].lead_s, runs[name].min_lead_s)
                                         for name in experiments], "timing")),
        ),
        ReportSection(
            "Set-membership bounds (Cerone, Piga, Regruto 2009)",
            text=(f"Backlash from {outcome.steady_input_rad.size} steady-state points of the staircase filtered "
                  f"with a = {outcome.filter_pole:.4g}; linear block (na = {plan.na}, nk = {plan.nk}, nb = {plan.nb}, "
                  f"unit static gain) from the PRBS experiment, by the paper's method and by the coupled one."),
            figures=tuple(default_result_figures(
                outcome.set_membership, "sm_", sample_period_s=truth.linear.sample_period_s,
                true_backlash=truth.backlash, true_linear=truth.linear,
                true_values={**truth.backlash_values, **truth.theta(plan.na, plan.nk, plan.nb)})),
        ),
        ReportSection(
            "Hammerstein model (Pouliquen et al. 2013)",
            text=("The gearbox's play sits after the drive loop, so the Hammerstein structure (nonlinearity first) "
                  "is an approximation here; the true borders drawn are what the play gives on Table I cycles."),
            figures=tuple(hammerstein_figures(
                outcome.hammerstein, "hammerstein_", true_poles=np.roots(np.r_[1.0, truth.linear.a]),
                true_ascending=ascending, true_descending=descending,
                sample_period_s=truth.linear.sample_period_s)),
        ),
    ]
    cyclic = runs["cyclic"].record
    sections.append(discrepancy_section(outcome.discrepancy, cyclic.command_rad, cyclic.angle_rad,
                                        truth.linear.sample_period_s,
                                        "the cyclic experiment, against the nominal gearbox model without its play"))
    return sections


def write_demo_report(outcome: DemoOutcome, out_dir: str | Path) -> Path:
    """Write the demo's report to ``out_dir/index.html`` (figures beside it); return the index path."""
    return write_report(out_dir, f"rig demo: simulated precision gearbox over {outcome.transport}",
                        demo_report_sections(outcome))
