"""The report of ``rig demo``: the summary table, the experiments and every identification figure."""

from __future__ import annotations

from pathlib import Path

from rig.demo import DemoOutcome, summary_rows
from rig.plots.experiment import signal_figure, timing_figure
from rig.report import ReportSection, write_report


def demo_report_sections(outcome: DemoOutcome) -> list[ReportSection]:
    """The demo's report, section by section."""
    truth = outcome.truth
    runs = outcome.runs
    sections = [
        ReportSection(
            "Summary",
            text=(f"The simulated precision gearbox (1:4, play c_l = {truth.backlash.c_l:.4g} rad and "
                  f"c_r = {truth.backlash.c_r:.4g} rad on the motor side, friction, a torsion mode, 12-bit load "
                  f"encoder) was driven over the {outcome.transport} transport. Set-membership bounds are "
                  f"guaranteed for the noise bound {outcome.noise_bound_rad:.3g} rad when the model structure "
                  "holds; friction and encoder drift are outside that structure, so a true value outside its "
                  "interval points at them, not at a numerical error."),
            table_header=("quantity", "true", "paper method", "coupled method / estimate"),
            table_rows=tuple(summary_rows(outcome)),
        ),
        ReportSection(
            "Experiments",
            text="Every experiment was streamed at the rig's fixed rate by the same runner that drives a real rig.",
            figures=tuple(figure for name in ("staircase", "prbs", "cyclic") if name in runs
                          for figure in (signal_figure(runs[name].record, f"signals_{name}"),
                                         timing_figure(runs[name].record, f"timing_{name}"))),
        ),
    ]
    return sections


def write_demo_report(outcome: DemoOutcome, out_dir: str | Path) -> Path:
    """Write the demo's report to ``out_dir/index.html`` (figures beside it); return the index path."""
    return write_report(out_dir, f"rig demo: simulated precision gearbox over {outcome.transport}",
                        demo_report_sections(outcome))
