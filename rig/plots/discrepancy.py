"""Figures and page of ``rig diagnose --report``: measured against simulated before and after, the residual with
the disagreement windows marked, and the signature that decided each added effect."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from identify.border_lifting import direction_signal
from identify.effect_signatures import delay_regressor
from identify.model_discrepancy import DiscrepancyReport, DiscrepancyResult, DiscrepancyStep
from identify.model_discrepancy.comparison import restarted_run
from rig.report import ReportFigure, ReportSection, write_report


ZOOM_SAMPLES = 200
"""A record longer than 5 times this is also drawn over this many samples from the start of the validation
segment: at the report's width a free run of thousands of samples is a solid band."""


def _run_words(result: DiscrepancyResult) -> str:
    """How the models were run against the record: freely, or restarted from the measured angle."""
    if result.restart_window_samples is None:
        return "free-run simulation"
    return f"run restarted from the measured angle every {result.restart_window_samples} samples"


def comparison_figure(result: DiscrepancyResult, angle_rad: NDArray[np.float64], time_s: NDArray[np.float64],
                      name: str = "measured_vs_simulated") -> ReportFigure:
    """Measured angle with the start and final model's free-run simulations, and both residuals; a long
    record also over :data:`ZOOM_SAMPLES` samples from the start of the validation segment (right). With nothing
    added the final model is the start model: it is drawn once (a second line would hide the first)."""
    added = bool(result.steps)
    zoom = None
    if time_s.size > 5 * ZOOM_SAMPLES:
        start = min(result.estimation_samples, time_s.size - ZOOM_SAMPLES)
        zoom = slice(start, start + ZOOM_SAMPLES)

    def draw_column(top, bottom, where: slice) -> None:
        t = time_s[where]
        top.plot(t, angle_rad[where], lw=1.2, color="black", label="measured")
        start_label = "start model" if added else "model (nothing added)"
        top.plot(t, result.initial.simulated_rad[where], lw=0.8, color="tab:red", label=start_label)
        if added:
            top.plot(t, result.final.simulated_rad[where], lw=0.8, ls="--", color="tab:green", label="final model")
        top.set_ylabel("load angle y [rad]")
        bottom.plot(t, result.initial.residual_rad[where], lw=0.7, color="tab:red", label=start_label)
        if added:
            bottom.plot(t, result.final.residual_rad[where], lw=0.7, color="tab:green", label="final model")
        for sign in (-1.0, 1.0):
            bottom.axhline(sign * result.noise_bound_rad, color="gray", lw=0.8, ls=":")
        if t[0] <= time_s[result.estimation_samples] <= t[-1]:
            bottom.axvline(time_s[result.estimation_samples], color="tab:blue", lw=0.8)
        bottom.set_ylabel("residual y - y_sim [rad]")
        bottom.set_xlabel("time [s]")

    def draw(figure) -> None:
        if zoom is None:
            top, bottom = figure.subplots(2, 1, sharex=True)
            draw_column(top, bottom, slice(None))
        else:
            grid = figure.subplots(2, 2, sharex="col", width_ratios=(3, 2))
            draw_column(grid[0, 0], grid[1, 0], slice(None))
            draw_column(grid[0, 1], grid[1, 1], zoom)
            for axes in grid[:, 0]:
                axes.axvspan(time_s[zoom.start], time_s[zoom.stop - 1], color="tab:orange", alpha=0.2, lw=0)
            grid[0, 1].set_title(f"zoom: {ZOOM_SAMPLES} samples of the validation segment", fontsize=9)
            top, bottom = grid[0, 0], grid[1, 0]
        # Above the panels, not in them: a free run fills its panel, and a legend inside would hide some of it.
        figure.legend(*top.get_legend_handles_labels(), loc="outside upper center", ncols=3, fontsize=8)

    zoom_text = (f" Right: the shaded {ZOOM_SAMPLES} samples from the start of the validation segment."
                 if zoom is not None else "")
    band = (f"the noise bound +-{result.noise_bound_rad:.3g} rad (dotted) and the start of the validation segment "
            "(blue line)")
    if added:
        what = (f"Measured load angle against the {_run_words(result)} of the start model (red) and of the final "
                f"model (green, dashed); below, the residuals with {band}. Gap {result.initial.gap_rad:.3g} rad "
                f"before, {result.final.gap_rad:.3g} rad after: the green residual should stay inside the dotted band.")
    else:
        what = (f"Measured load angle against the {_run_words(result)} of the model (red; nothing was added, so the "
                f"start model is the final one); below, its residual with {band}. Gap {result.initial.gap_rad:.3g} "
                "rad: where the residual leaves the dotted band, the model and the record disagree.")
    return ReportFigure(
        name,
        f"{what}{zoom_text}",
        draw, size_in=(9.5, 5.0) if zoom is not None else (7.5, 5.0))


SPREAD_COVERAGE = 0.5
"""Windows of falsified samples that cover at least this fraction of the record are not a cluster: the caption
says the start model misses throughout."""


def windows_figure(result: DiscrepancyResult, time_s: NDArray[np.float64], name: str = "disagreement_windows") -> ReportFigure:
    """The start model's residual with the falsified samples and the windows where they cluster."""

    def draw(figure) -> None:
        axes = figure.subplots()
        residual = result.initial.residual_rad
        axes.plot(time_s, residual, lw=0.7, color="tab:red")
        falsified = result.initial.falsified
        axes.plot(time_s[falsified], residual[falsified], ".", ms=2, color="black")
        for window in result.initial.windows:
            axes.axvspan(time_s[window.start], time_s[min(window.stop, time_s.size - 1)], color="tab:orange", alpha=0.2)
        for sign in (-1.0, 1.0):
            axes.axhline(sign * result.noise_bound_rad, color="gray", lw=0.8, ls=":")
        axes.set_xlabel("time [s]")
        axes.set_ylabel("residual of start model [rad]")

    windows = result.initial.windows
    covered = sum(window.stop - window.start for window in windows) / max(1, time_s.size)
    if not windows:
        where = ", no window where they cluster."
    elif covered >= SPREAD_COVERAGE:
        where = (f", the shaded {'span covers' if len(windows) == 1 else f'{len(windows)} spans cover'} "
                 f"{100 * covered:.0f} % of the record: they do not cluster, the start model misses throughout.")
    elif len(windows) == 1:
        where = ", the shaded span is the one window where they cluster."
    else:
        where = f", shaded spans are the {len(windows)} windows where they cluster."
    return ReportFigure(
        name,
        f"Residual of the start model (red line); black dots are the samples the noise bound cannot explain "
        f"({100 * result.initial.falsified_fraction:.1f} % of the validation segment){where}",
        draw)


def signature_figure(step: DiscrepancyStep, number: int, residual_rad: NDArray[np.float64],
                     simulated_rad: NDArray[np.float64], command_rad: NDArray[np.float64],
                     time_s: NDArray[np.float64], noise_bound_rad: float) -> ReportFigure:
    """The signature of the effect added in ``step``: the residual against the quantity that reveals it."""
    effect = step.effect
    moving = max(1e-12, 1e-3 * float(np.ptp(simulated_rad)) / max(1.0, np.sqrt(simulated_rad.size)))
    if effect in ("backlash", "coulomb_friction"):
        x, x_label = direction_signal(simulated_rad, threshold=moving), "direction of motion of the model [-1 / +1]"
        what = "the residual switches level with the direction of motion"
    elif effect in ("dead_zone", "saturation"):
        x, x_label = command_rad, "command u [rad]"
        what = ("the residual departs from zero near u = 0" if effect == "dead_zone"
                else "the residual grows with |u| at the extremes")
    elif effect == "delay":
        lag = int(round(step.parameters["samples"]))
        x = delay_regressor(simulated_rad, lag)
        x_label = f"model delayed by {lag} samples minus model, y^(t-{lag}) - y^(t) [rad]"
        what = f"the residual is what a model {lag} samples early leaves"
    elif effect == "gain_error":
        x, x_label = simulated_rad, "model output y^ [rad]"
        what = "the residual is proportional to the model's output"
    elif effect in ("load_friction", "rate_limit"):
        period = float(time_s[1] - time_s[0]) if time_s.size > 1 else 1.0
        x, x_label = np.gradient(simulated_rad) / period, "speed of the model dy^/dt [rad/s]"
        what = ("the residual opposes the model's motion" if effect == "load_friction"
                else "the residual grows where the model moves faster than the drive can")
    elif effect == "torque_limit":
        period = float(time_s[1] - time_s[0]) if time_s.size > 1 else 1.0
        x = np.gradient(np.gradient(simulated_rad) / period) / period
        x_label = "acceleration of the model d2y^/dt2 [rad/s^2]"
        what = "the residual grows where the model accelerates harder than the drive can"
    elif effect == "gain_drift":
        x, x_label = time_s, "time [s]"
        what = "the residual is a multiple of the model's output that changes over the record"
    elif effect == "gravity":
        x, x_label = simulated_rad, "model angle y^ [rad]"
        what = "the residual follows the sine of the angle: a position-dependent load"
    elif effect == "encoder_error":
        x, x_label = simulated_rad, "model angle y^ [rad]"
        what = "the residual is the same at the same angle, once or twice per revolution"
    else:
        x, x_label = time_s, "time [s]"
        what = ("a narrow peak in the spectrum of the residual" if effect == "resonance"
                else "the residual follows a constant plus a slow drift")
    score = step.evidence.get("signature_scores", {}).get(effect)
    scored = f"signature score {score:.2f}; " if score is not None else ""

    def draw(figure) -> None:
        if effect == "resonance":
            axes = figure.subplots()
            period = float(time_s[1] - time_s[0]) if time_s.size > 1 else 1.0
            spectrum = np.abs(np.fft.rfft(residual_rad - residual_rad.mean())) * 2.0 / residual_rad.size
            axes.semilogy(np.fft.rfftfreq(residual_rad.size, period), np.maximum(spectrum, 1e-12), lw=0.7)
            axes.axvline(step.parameters["frequency_hz"], color="tab:green", lw=0.8)
            axes.set_xlabel("frequency [Hz]")
            axes.set_ylabel("residual amplitude [rad]")
            return
        axes = figure.subplots()
        if effect in ("backlash", "coulomb_friction"):  # three directions, not a continuous axis: one box each
            present = [(level, name) for level, name in ((-1.0, "moving down"), (0.0, "at rest"), (1.0, "moving up"))
                       if np.any(x == level)]
            groups = [residual_rad[(x == level) & np.isfinite(residual_rad)] for level, _ in present]
            axes.boxplot(groups, positions=[level for level, _ in present], widths=0.5, showfliers=False)
            axes.set_xticks([level for level, _ in present],
                            [f"{name} ({group.size})" for (_, name), group in zip(present, groups)])
        else:
            axes.plot(x, residual_rad, ".", ms=2, alpha=0.5)
        for sign in (-1.0, 1.0):
            axes.axhline(sign * noise_bound_rad, color="gray", lw=0.8, ls=":")
        axes.set_xlabel(x_label)
        axes.set_ylabel("residual before this step [rad]")

    return ReportFigure(
        f"signature_{number}_{effect}",
        f"Step {number}, {effect.replace('_', ' ')}: {what} ({scored}the effect was chosen "
        f"because it lowered the validated gap from {step.gap_before_rad:.3g} to {step.gap_after_rad:.3g} rad).",
        draw)


VERDICT_WORDS = {
    "explained": "EXPLAINED: the start model already agrees with the data",
    "named": "NAMED: missing effects found",
    "ambiguous": "AMBIGUOUS: the data cannot decide between candidates, or whether one is there, or which "
                 "mechanism draws a fitted map",
    "unexplained": "UNEXPLAINED: no candidate effect helps",
    "not_excited": "NOT EXCITED: the data cannot show the effects",
}
"""The verdict of :data:`identify.model_discrepancy.VERDICTS` in words (text output and report)."""


def verdict_heading(report: DiscrepancyReport) -> str:
    """The verdict of a diagnosis as a page heading says it: ``AMBIGUOUS between gravity and offset``,
    ``NAMED backlash``, ``EXPLAINED``, ... (never a heading a verdict contradicts)."""
    word = report.verdict.replace("_", " ").upper()
    if report.verdict == "ambiguous" and report.ambiguous_between:
        listed = list(report.ambiguous_between)
        return f"{word} between {', '.join(listed[:-1])} and {listed[-1]}" if len(listed) > 1 else f"{word}: {listed[0]}"
    if report.missing_effects:
        fitted = ", ".join(step.effect for step in report.missing_effects)
        return f"{word}: {fitted} fitted, not the whole story" if report.verdict == "ambiguous" else f"{word} {fitted}"
    return word


def diagnosis_summary(report: DiscrepancyReport) -> str:
    """The verdict in words with its reason, the effects named, the undecided candidates and the first round's
    candidates: one text for every page that shows a diagnosis (``rig diagnose --report``, ``rig report``)."""
    named = ", ".join(step.effect for step in report.missing_effects) or "none"
    reason = report.verdict_reason
    return (f"Verdict {VERDICT_WORDS.get(report.verdict, report.verdict)}{': ' + reason if reason else ''}. "
            f"Missing effects named, in order: {named}.{_undecided_text(report)}{_candidates_text(report)}")


def _undecided_text(report) -> str:
    """The candidates whose gap reduction straddles the acceptance (an ambiguous verdict after the effects
    named, if any), with their numbers; empty when there are none."""
    if not report.undecided:
        return ""
    after = (f" after {', '.join(step.effect for step in report.missing_effects)}" if report.missing_effects else "")
    words = "; ".join(f"{c.effect} {c.reduction_text()}" for c in report.undecided)
    return (f" Undecided{after}, not named (gap reduction within its uncertainty around the acceptance): "
            f"{words}.")


def _candidates_text(report) -> str:
    """The first round's candidates with their validated gaps, best first."""
    ranked = sorted((c for c in report.candidates if c.round == 0), key=lambda c: c.penalised_gap_rad)
    words = "; ".join(f"{c.effect} {c.gap_rad:.3g} +- {c.gap_uncertainty_rad:.2g} rad"
                      + (" (vanished)" if c.vanished else "") for c in ranked)
    return f" Candidates tried first, with their validated gaps: {words}." if words else ""


def discrepancy_section(result: DiscrepancyResult, command_rad: NDArray[np.float64], angle_rad: NDArray[np.float64],
                        sample_period_s: float, source: str = "") -> ReportSection:
    """The report section of one diagnosis: the table of added effects and every figure."""
    time_s = np.arange(command_rad.size) * sample_period_s
    report = result.report()

    def shown(effect: str, key: str, value: float) -> str:
        interval = result.parameter_intervals.get(effect, {}).get(key)
        return f"{key} = {value:.4g}" + (f" [{interval[0]:.4g}, {interval[1]:.4g}]" if interval is not None else "")

    rows = tuple(
        (str(number), step.effect, ", ".join(shown(step.effect, k, v) for k, v in step.parameters.items()),
         f"{step.gap_before_rad:.4g}", f"{step.gap_after_rad:.4g}", f"{100 * step.falsified_fraction_after:.1f}")
        for number, step in enumerate(result.steps, 1)
    )
    figures = [comparison_figure(result, angle_rad, time_s), windows_figure(result, time_s)]
    residual = result.initial.residual_rad
    simulated = result.initial.simulated_rad
    for number, step in enumerate(result.steps, 1):
        figures.append(signature_figure(step, number, residual, simulated, command_rad, time_s, result.noise_bound_rad))
        simulated = (step.model.simulate(command_rad) if result.restart_window_samples is None
                     else restarted_run(step.model, command_rad, angle_rad, result.restart_window_samples))
        residual = angle_rad - simulated
    text = (
        f"{diagnosis_summary(report)}\n\n"
        f"Data {source}: {command_rad.size} samples; the fits use the first {result.estimation_samples}, the gaps "
        f"(RMS error of the {_run_words(result)}) are measured on the rest. "
        f"Noise bound {result.noise_bound_rad:.4g} rad. "
        f"Gap {result.initial.gap_rad:.4g} rad -> {result.final.gap_rad:.4g} rad; falsified samples "
        f"{100 * result.initial.falsified_fraction:.1f} % -> {100 * result.final.falsified_fraction:.1f} %.\n\n"
        f"{result.unexplained[0].upper()}{result.unexplained[1:]}."
    )
    section = ReportSection(
        f"Model discrepancy: {verdict_heading(report)}", text,
        ("step", "effect", "parameters [interval]", "gap before [rad]", "gap after [rad]", "falsified after [%]"), rows,
        tuple(figures))
    return section


def write_discrepancy_report(out_dir: Path, result: DiscrepancyResult, command_rad: NDArray[np.float64],
                             angle_rad: NDArray[np.float64], sample_period_s: float, source: str = "") -> Path:
    """Write the figures and ``index.html`` of one diagnosis to ``out_dir``; return the page's path."""
    section = discrepancy_section(result, command_rad, angle_rad, sample_period_s, source)
    return write_report(out_dir, "Model discrepancy diagnosis", [section])
