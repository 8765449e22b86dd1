"""Figures of a captured experiment: the signals, and what is known of the timing of its samples.

The log's time column is the device's sample instant k·T on a device-clocked wire (the runner writes the
instant the device sampled at, :mod:`rig.sample_ledger`): its spacing is T by construction, and plotting
its deviation from T plots float64 rounding. What such a log knows of the timing is per sample, the flags
(HELD: the setpoint missed its instant; LATE: the instant was off the period; LOST ...), and per run, how
far ahead the setpoints were queued and the smallest lead seen (:class:`rig.runner.RunSummary`). A time
column that does not lie on k·T (a trace recorded by another tool, a host-paced log of an older version) is
measured, and its period deviation is drawn.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from identify.experiment_record import ExperimentRecord, SampleFlag
from rig.report import ReportFigure

__all__ = ["TIMING_FLAGS", "RunTiming", "runs_timing_figure", "signal_figure", "timing_figure"]

TIMING_FLAGS = (SampleFlag.HELD, SampleFlag.LATE, SampleFlag.LOST, SampleFlag.AMBIGUOUS, SampleFlag.DUPLICATE,
                SampleFlag.NOT_FOLLOWED, SampleFlag.FAULT)
"""The flags that say a sample was not taken at its instant with its own setpoint. The timing figure draws
a row for HELD and LATE (what a device-clocked run is judged by) and for each other one that occurs."""

ZOOM_REVERSALS = 60
"""A command that reverses more often than this over the record is drawn again over a window of
:data:`WINDOW_REVERSALS` of them: at the report's width its whole trace is a solid block."""
WINDOW_REVERSALS = 20


def _reversals(command_rad: NDArray[np.float64]) -> NDArray[np.int64]:
    """Sample indices where the command's direction of motion changes."""
    step = np.sign(np.diff(command_rad))
    moving = np.flatnonzero(step != 0)
    return moving[1:][np.diff(step[moving]) != 0]


def signal_figure(record: ExperimentRecord, name: str) -> ReportFigure:
    """Command and measured load angle against time (and the drive's torque, where the log has it), with unusable
    samples marked; a command that reverses more than :data:`ZOOM_REVERSALS` times is also drawn over a window of
    the first ones (right column)."""
    reversals = _reversals(record.command_rad)
    window = None
    if reversals.size > ZOOM_REVERSALS:  # from a little before the first reversal, WINDOW_REVERSALS of them
        first, last = int(reversals[0]), int(reversals[WINDOW_REVERSALS])
        start = max(0, first - (last - first) // 5)
        window = (float(record.time_s[start]), float(record.time_s[min(last + 1, len(record) - 1)]))
    unusable = ~record.valid_mask
    torque_unit = str(record.metadata.extra.get("drive_torque_unit", "its unit")).replace("_", " ")
    rows = 2 if record.drive_torque is None else 3

    def draw_column(axes, where: slice) -> None:
        time_s = record.time_s[where]
        axes[0].step(time_s, record.command_rad[where], where="post", lw=0.8, color="tab:blue")
        axes[0].set_ylabel("command u [rad]")
        axes[1].plot(time_s, record.angle_rad[where], lw=0.8, color="tab:green")
        for time_of_sample in time_s[unusable[where]]:
            axes[1].axvline(time_of_sample, color="tab:red", lw=0.5, alpha=0.6)
        axes[1].set_ylabel("load angle y [rad]")
        if record.drive_torque is not None:
            axes[2].plot(time_s, record.drive_torque[where], lw=0.8, color="tab:purple")
            axes[2].set_ylabel(f"drive torque\n[{torque_unit}]", fontsize=8)
        axes[-1].set_xlabel("time [s]")

    def draw(figure) -> None:
        if window is None:
            draw_column(figure.subplots(rows, 1, sharex=True), slice(None))
            return
        grid = figure.subplots(rows, 2, sharex="col", width_ratios=(2, 3))
        draw_column(grid[:, 0], slice(None))
        inside = np.flatnonzero((record.time_s >= window[0]) & (record.time_s <= window[1]))
        draw_column(grid[:, 1], slice(int(inside[0]), int(inside[-1]) + 1))
        for axes in grid[:, 0]:
            axes.axvspan(*window, color="tab:orange", alpha=0.2, lw=0)
        grid[0, 1].set_title(f"zoom: {window[0]:.3g}-{window[1]:.3g} s", fontsize=9)

    zoom_text = (f" The command reverses {reversals.size} times; right: the shaded window "
                 f"{window[0]:.3g}-{window[1]:.3g} s drawn sample by sample.") if window is not None else ""
    panels = ("command (top) and measured load angle (bottom)" if record.drive_torque is None else
              f"command (top), measured load angle (middle) and the drive's torque (bottom, {torque_unit})")
    return ReportFigure(
        name, f"{record.metadata.excitation or 'experiment'}: {panels} "
        f"over {len(record)} samples; red lines mark the {int(np.count_nonzero(unusable))} unusable "
        f"samples ({record.lost_count} lost).{zoom_text} Look for a clean response with no gaps.", draw,
        size_in=(9.0, 4.5 + 1.5 * (rows - 2)) if window is not None else (7.0, 4.5 + 1.5 * (rows - 2)))


def timing_figure(record: ExperimentRecord, name: str, *, lead_s: float | None = None,
                  min_lead_s: float | None = None) -> ReportFigure:
    """What is known of the timing of the samples: the flags over time and, when given, the run's lead.

    On a log whose time column is the nominal grid (:meth:`ExperimentRecord.time_column_is_nominal`, every
    device-clocked log): one row per flag of :data:`TIMING_FLAGS` with a tick at each flagged sample, and a panel with how
    far ahead of the device's instants the setpoints were queued (``lead_s``) and the smallest lead seen
    (``min_lead_s``; negative: a setpoint came too late and the sample is HELD). On a measured time column:
    the deviation of each period from T over time and as a histogram, LATE samples marked.
    """
    if not record.time_column_is_nominal():
        return _period_deviation_figure(record, name)
    period_s = record.sample_period_s
    counts = {flag: record.count_flag(flag) for flag in TIMING_FLAGS}
    rows = [flag for flag in TIMING_FLAGS if flag in (SampleFlag.HELD, SampleFlag.LATE) or counts[flag]]
    flagged = {flag: record.time_s[(record.flags & int(flag)) != 0] for flag in rows}
    leads_ms = {}
    if lead_s is not None and lead_s > 0:
        leads_ms["queued ahead"] = lead_s * 1e3
        if min_lead_s is not None and math.isfinite(min_lead_s):
            leads_ms["smallest lead"] = min_lead_s * 1e3

    def draw(figure) -> None:
        if leads_ms:
            flag_axes, lead_axes = figure.subplots(1, 2, width_ratios=(3, 1))
        else:
            flag_axes, lead_axes = figure.subplots(), None
        offsets = list(range(len(rows)))
        flag_axes.eventplot([flagged[flag] for flag in rows], lineoffsets=offsets, linelengths=0.7,
                            colors="tab:red", linewidths=0.8)
        flag_axes.set_yticks(offsets, [f"{flag.name} ({counts[flag]})" for flag in rows], fontsize=7)
        flag_axes.set_ylim(len(rows) - 0.5, -0.5)
        flag_axes.set_xlim(float(record.time_s[0]), float(record.time_s[-1]) + period_s)
        flag_axes.set_xlabel("device's sample instant k·T [s]")
        flag_axes.set_ylabel("flag (samples) [-]")
        if lead_axes is not None:
            labels = list(leads_ms)
            values = [leads_ms[label] for label in labels]
            lead_axes.bar(labels, values, color=["tab:gray", "tab:blue"][: len(values)])
            lead_axes.axhline(0.0, color="k", lw=0.8)
            lead_axes.set_ylabel("lead [ms]")
            lead_axes.tick_params(axis="x", labelsize=7)
            lead_axes.set_xlabel("setpoint before its instant [-]", fontsize=8)
            lead_axes.set_ylim(min(0.0, min(values)) * 1.2 - 0.05 * max(values), 1.15 * max(values))

    flagged_total = int(np.count_nonzero(record.flags & int(sum(TIMING_FLAGS))))
    lead_text = ""
    if leads_ms:
        lead_text = f" Setpoints were queued {leads_ms['queued ahead']:.3g} ms ahead of the device's instants"
        lead_text += (f"; the smallest lead seen was {leads_ms['smallest lead']:.3g} ms (below 0: the setpoint "
                      "missed its instant and the sample is HELD)." if "smallest lead" in leads_ms
                      else "; the link did not measure the smallest lead.")
    caption = (f"Timing of the {len(record)} samples. The log's time column is the nominal grid k·T "
               f"(T = {period_s * 1e3:g} ms: on a device-clocked wire, the device's own sample instants), so its "
               f"spacing carries no jitter to plot; drawn instead are the samples flagged as not taken at their "
               f"instant with their own setpoint: {flagged_total} of {len(record)} ("
               + ", ".join(f"{counts[flag]} {flag.name}" for flag in TIMING_FLAGS if counts[flag])
               + ("" if flagged_total else "none") + f").{lead_text} "
               + (f"These {flagged_total} samples are set aside by the analysis commands (their rows do not carry "
                  "the command applied at the sample's own instant, or carry none); a run on a quieter host, with "
                  "a longer lead, shows none." if flagged_total else
                  "Every sample was taken at its instant with its own setpoint.")
               + (" A smallest lead well above 0 leaves room for host stalls." if "smallest lead" in leads_ms else ""))
    return ReportFigure(name, caption, draw, size_in=(8.0, 1.6 + 0.3 * len(rows)))


@dataclass(frozen=True)
class RunTiming:
    """One run as :func:`runs_timing_figure` draws it: its log and what its :class:`rig.runner.RunSummary`
    knew of the lead (``lead_s`` 0: a host-paced run; ``min_lead_s`` nan: not measured)."""

    name: str
    record: ExperimentRecord
    lead_s: float = 0.0
    min_lead_s: float = math.nan


_FLAG_COLOURS = {SampleFlag.HELD: "tab:red", SampleFlag.LATE: "tab:orange", SampleFlag.LOST: "k"}


def runs_timing_figure(runs: Sequence[RunTiming], name: str) -> ReportFigure:
    """The timing of several device-clocked runs in one figure: per run, a row with a tick at each sample
    flagged with one of :data:`TIMING_FLAGS` (HELD red, LATE orange, LOST black, others purple) over the
    run's duration, and the lead: how far ahead of the device's instants the setpoints were queued and the
    smallest lead seen (below 0: a setpoint missed its instant and the sample is HELD)."""
    if not runs:
        raise ValueError("runs: expected at least one run")
    counts = [{flag: run.record.count_flag(flag) for flag in TIMING_FLAGS} for run in runs]
    leads = [(run.lead_s * 1e3, run.min_lead_s * 1e3 if math.isfinite(run.min_lead_s) else math.nan) for run in runs]

    def row_label(run: RunTiming, count: dict[SampleFlag, int]) -> str:
        flagged = ", ".join(f"{count[flag]} {flag.name}" for flag in TIMING_FLAGS if count[flag]) or "none flagged"
        return f"{run.name}\n{len(run.record)} samples, {flagged}"

    def draw(figure) -> None:
        flag_axes, lead_axes = figure.subplots(1, 2, width_ratios=(3, 2), sharey=True)
        for row, run in enumerate(runs):
            record = run.record
            time_s = record.time_s - record.time_s[0]
            flag_axes.plot([0.0, float(time_s[-1])], [row, row], color="0.8", lw=6, solid_capstyle="butt")
            for flag in TIMING_FLAGS:
                at = time_s[(record.flags & int(flag)) != 0]
                if at.size:
                    flag_axes.plot(at, np.full(at.size, row), "|", ms=12, color=_FLAG_COLOURS.get(flag, "tab:purple"),
                                   label=flag.name)
        flag_axes.set_yticks(range(len(runs)), [row_label(run, count) for run, count in zip(runs, counts)],
                             fontsize=7)
        flag_axes.set_ylim(len(runs) + 0.3, -0.5)  # a free band at the bottom for the legends
        flag_axes.set_xlabel("time in the run (device's instants k·T) [s]")
        flag_axes.set_ylabel("run, flagged samples [-]")
        handles, labels = flag_axes.get_legend_handles_labels()
        if handles:
            unique = dict(zip(labels, handles))
            flag_axes.legend(unique.values(), unique.keys(), loc="lower right", fontsize=7, ncol=len(unique))
        rows = np.arange(len(runs))
        lead_axes.barh(rows - 0.18, [queued for queued, _ in leads], height=0.34, color="tab:gray",
                       label="queued ahead")
        smallest = np.array([low for _, low in leads])
        measured = np.isfinite(smallest)
        lead_axes.barh(rows[measured] + 0.18, smallest[measured], height=0.34, color="tab:blue",
                       label="smallest lead seen")
        lead_axes.axvline(0.0, color="k", lw=0.8)
        lead_axes.set_xlabel("setpoint ahead of its instant [ms]")
        lead_axes.set_ylabel("same runs [-]")
        lead_axes.legend(loc="lower right", fontsize=7, ncol=2)

    lines = []
    for run, count, (queued, smallest) in zip(runs, counts, leads):
        flagged = sum(count.values())
        text = f"{run.name}: {flagged} of {len(run.record)} samples flagged"
        if queued > 0:
            text += f", queued {queued:.3g} ms ahead" + (f", smallest lead {smallest:.3g} ms"
                                                        if math.isfinite(smallest) else ", smallest lead not measured")
        else:
            text += ", host-paced (no lead)"
        lines.append(text)
    caption = ("Timing of the runs as the device saw it. Each log's time column is the device's own sample instant "
               f"k·T, so its spacing carries no jitter to plot; left, the samples flagged as not taken at their "
               "instant with their own setpoint (HELD, LATE, LOST ...) over each run; right, how far ahead of its "
               "instant each setpoint was queued and the smallest lead seen (below 0 the setpoint missed its "
               f"instant and the sample is HELD). {'; '.join(lines)}. "
               + ("Each tick on the left is a sample the analysis commands set aside; a clean run has none, and a "
                  "smallest lead well above 0 leaves room for host stalls." if any(sum(c.values()) for c in counts)
                  else "No run has a flagged sample; a smallest lead well above 0 leaves room for host stalls."))
    return ReportFigure(name, caption, draw, size_in=(9.0, 1.2 + 0.55 * len(runs)))


def _period_deviation_figure(record: ExperimentRecord, name: str) -> ReportFigure:
    """Deviation of each measured sample period from the nominal one, over time and as a histogram."""
    nominal_s = record.sample_period_s
    deviation_us = record.period_deviation_s * 1e6
    late = record.count_flag(SampleFlag.LATE)
    p99 = float(np.percentile(np.abs(deviation_us), 99)) if deviation_us.size else 0.0

    def draw(figure) -> None:
        trace_axes, histogram_axes = figure.subplots(1, 2, width_ratios=(2, 1))
        trace_axes.plot(record.time_s[1:], deviation_us, lw=0.6)
        late_mask = (record.flags[1:] & SampleFlag.LATE) != 0
        trace_axes.plot(record.time_s[1:][late_mask], deviation_us[late_mask], "r.", ms=3, label="late")
        trace_axes.set_xlabel("time [s]")
        trace_axes.set_ylabel("period - nominal [us]")
        if np.any(late_mask):
            trace_axes.legend(loc="upper right")
        histogram_axes.hist(deviation_us, bins=40, orientation="horizontal", color="tab:gray")
        histogram_axes.set_xlabel("samples [-]")
        histogram_axes.set_ylabel("period - nominal [us]")

    return ReportFigure(
        name, f"Measured sample periods (the time column is not the nominal grid k·T) against the nominal "
        f"{nominal_s * 1e3:g} ms: p99 |deviation| = {p99:.3g} us, {late} late samples"
        + (" (red: taken further from their instant than the late tolerance, and flagged LATE)." if late else
           ": every period within the late tolerance.")
        + " A narrow band around zero is a steady loop.", draw)
