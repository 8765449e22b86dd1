"""``rig report RESULTS... --out DIR``: a static HTML page with PNG figures from the files a user has.

RESULTS may be, in any order and mixed:

* experiment logs (``rig-log v1``) or plain CSV files with columns ``t,u,y``: signals and loop timing;
* result JSON as the commands write it with ``--json`` or ``--save``, read by its ``kind`` and ``version``
  keys (never guessed from the other keys):

  - ``output_backlash`` (``rig identify output-backlash``; one file per method, shown side by side): interval
    table, interval figure, Bode magnitude of the linear-block box, backlash band, feasible polygons and
    inner-signal bounds;
  - ``hammerstein_model`` (``rig identify hammerstein``): poles, borders and singular values;
  - ``model_discrepancy`` (``rig diagnose``): the verdict, the missing effects and how much each closed the gap;
  - ``run_summary`` (``rig run --json``): what the run did (samples, lost, late or held, stop), as a table;
  - ``batch`` (any of these commands given several files): every result it holds, and the files that failed.

Each result type reads itself (``from_dict``); a kind or version this version cannot read is refused with a
message naming the file, the kind and version found, and those it reads.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from identify.experiment_record import OFFLINE_TRANSPORT
from rig import exit_codes

__all__ = ["ResultFile", "read_result_file", "read_result_files", "readable_kinds", "register", "report_sections", "run",
           "write_result_report"]

DESCRIPTION = """\
Write a static HTML report (index.html and PNG figures) from result files:

  experiment logs (rig-log v1, v2) or CSV files with columns t,u,y     signals and timing (device-clocked:
                                                                   HELD samples, smallest lead; else the
                                                                   period jitter, send lateness)
  JSON of `rig identify output-backlash --json` or --save FILE    intervals side by side (one file per
    (kind output_backlash)                                         method), Bode of the box, polygons,
                                                                   backlash band, inner-signal bounds
  JSON of `rig identify hammerstein --json` (kind hammerstein_model)  poles, borders, singular values
  JSON of `rig diagnose --json` (kind model_discrepancy)           verdict, missing effects, gap closed
  JSON of `rig run --json` (kind run_summary)                      samples, lost, late/held, smallest
                                                                   lead or send lateness, stop
  JSON of any of these commands given several files (kind batch)  every result in it

Result JSON is read by its "kind" and "version" keys; a kind or version this version cannot read is
refused with both named.
Save the JSON with e.g. `rig identify hammerstein run.csv --json > hammerstein.json`. The frequency axis
of the Bode figure is in Hz when --sample-period is given or the experiment logs among the files share one
period, else in cycles per sample (logs of different periods: the page says so). The command prints the path of index.html."""

EXPECTED = ("a rig log, a CSV file with columns t,u,y, or the JSON printed by "
            "`rig identify output-backlash --json`, `rig identify hammerstein --json`, `rig diagnose --json` "
            "(one file or several) or `rig run --json`")


@dataclass(frozen=True)
class ResultFile:
    """One input of the report: its path, its kind and its content.

    ``kind`` is ``"experiment"`` (``content`` an :class:`identify.experiment_record.ExperimentRecord`),
    ``"output_backlash"`` (an :class:`identify.output_backlash_identification.OutputBacklashIdentification`),
    ``"hammerstein_model"`` (an :class:`identify.hammerstein_model.HammersteinModel`),
    ``"model_discrepancy"`` (an :class:`identify.model_discrepancy.DiscrepancyReport`), ``"run_summary"`` (a
    :class:`rig.runner.RunSummary`) or ``"error"`` (the
    message of a file a batch command could not process). ``entry`` names the file an entry of a batch file
    (kind ``"batch"``) came from; it is None for a file that holds one result.
    """

    path: Path
    kind: str
    content: Any
    entry: str | None = None

    @property
    def name(self) -> str:
        """The file's name, with the batch entry it came from."""
        return self.path.name if self.entry is None else f"{self.path.name} [{self.entry}]"

    @property
    def slug(self) -> str:
        """The file stem (and entry) reduced to the characters a figure name allows."""
        stem = self.path.stem if self.entry is None else f"{self.path.stem}_{Path(self.entry).stem}"
        return re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_") or "result"


MAX_JSON_BYTES = 256 << 20
"""Largest result JSON read (a --save file of a million samples is about 80 MB)."""


def _short(value: Any, limit: int = 80) -> str:
    """At most ``limit`` characters of ``value`` for a message (never a whole array or file)."""
    text = value if isinstance(value, str) else repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _readers() -> dict[str, tuple[tuple[int, ...], Any]]:
    """kind -> (the versions read, the result type's from_dict); a type that reads older versions lists them in
    ``READS`` (the run summary, the model discrepancy), the others read their ``VERSION``."""
    from identify.hammerstein_subspace import HammersteinModel
    from identify.model_discrepancy import DiscrepancyReport
    from identify.output_backlash_identification import OutputBacklashIdentification
    from rig.runner import RunSummary

    return {cls.KIND: (getattr(cls, "READS", (cls.VERSION,)), cls.from_dict)
            for cls in (OutputBacklashIdentification, HammersteinModel, DiscrepancyReport, RunSummary)}


def readable_kinds() -> str:
    """The kinds and versions this command reads, for messages and the help."""
    from rig.batch import BATCH_KIND, BATCH_VERSION

    kinds = [f"{kind} v{'/'.join(str(v) for v in versions)}" for kind, (versions, _) in _readers().items()]
    return ", ".join([*kinds, f"{BATCH_KIND} v{BATCH_VERSION}"])


def _results_of(document: Any, path: Path) -> list[ResultFile]:
    """Dispatch on the document's ``kind`` (never on its other keys); a batch gives one entry per file."""
    from identify.result_format import ResultFormatError, kind_of
    from rig.batch import BATCH_KIND, BATCH_VERSION
    from rig.protocols.errors import LogFileError

    kind, version = kind_of(document)
    if kind is None:
        keys = _short(", ".join(sorted(document))) if isinstance(document, dict) else type(document).__name__
        raise LogFileError(f"{path}: JSON without a 'kind' key (keys [{keys}]): not a result file of this version "
                           f"(an older one, or not written by rig); this command reads the kinds {readable_kinds()} "
                           "as the --json and --save options write them: write it again with the command")
    if kind == BATCH_KIND and version == BATCH_VERSION:
        entries = document.get("results")
        if not isinstance(entries, list) or not entries:
            raise LogFileError(f"{path}: kind batch: expected a non-empty list 'results'")
        out = []
        for number, entry in enumerate(entries, 1):
            if not isinstance(entry, dict):
                raise LogFileError(f"{path}: kind batch: results[{number - 1}] is not a JSON object")
            name = str(entry.get("file") or entry.get("dynamic") or f"entry {number}")
            if "error" in entry:
                out.append(ResultFile(path, "error", str(entry["error"]), entry=name))
                continue
            inner = [value for value in entry.values() if kind_of(value)[0] is not None]
            if len(inner) != 1:
                raise LogFileError(f"{path}: kind batch: results[{number - 1}] ({name}) holds neither one result "
                                   "(an object with a 'kind') nor an 'error'")
            out += [dataclasses.replace(result, entry=name) for result in _results_of(inner[0], path)]
        return out
    readers = _readers()
    if kind not in readers or isinstance(version, bool) or version not in readers[kind][0]:
        raise LogFileError(f"{path}: kind {_short(kind, 40)!r} version {_short(version, 20)} cannot be read by this "
                           f"version of rig report, which reads {readable_kinds()}")
    try:
        return [ResultFile(path, kind, readers[kind][1](document))]
    except ResultFormatError as err:
        raise LogFileError(f"{path}: {_short(str(err), 200)}; write it again with the command that made it "
                           "(--json or --save), unchanged") from None


def read_result_files(path: str | Path) -> list[ResultFile]:
    """Recognise and read one result file: the results it holds (several for a batch file).

    Raises
    ------
    FileNotFoundError
        The path is not a file.
    rig.protocols.errors.LogFileError
        The file is none of the known kinds, or a JSON document of a kind or version this version cannot
        read; the message names the file, the kind and version found and those it reads.
    """
    from identify.validation import InvalidInputError
    from rig.log_file import read_experiment_data
    from rig.protocols.errors import LogFileError

    from rig.signal_files import check_input_file

    path = check_input_file(path, EXPECTED)
    from rig.measurement_files import measurement_format

    if measurement_format(path) is not None:  # binary: an MDF4 or MAT file is an experiment or nothing
        return [ResultFile(path, "experiment", read_experiment_data(path))]
    with path.open("rb") as handle:
        head = handle.read(4096)
    nul = head.find(b"\0")
    if nul >= 0:
        raise LogFileError(f"{path}: not a text file (NUL bytes at byte {nul}); expected {EXPECTED}")
    if head.removeprefix(b"\xef\xbb\xbf").startswith(b"# rig-log"):
        return [ResultFile(path, "experiment", read_experiment_data(path))]
    if head.removeprefix(b"\xef\xbb\xbf").lstrip().startswith((b"{", b"[")):
        if path.stat().st_size > MAX_JSON_BYTES:
            raise LogFileError(f"{path}: {path.stat().st_size} bytes is too large for a result JSON (at most "
                               f"{MAX_JSON_BYTES}); expected {EXPECTED}")
        try:
            text = path.read_bytes().decode("utf-8").removeprefix("\ufeff")
        except UnicodeDecodeError as err:
            raise LogFileError(f"{path}: not a text file (byte {err.start} is not UTF-8); expected {EXPECTED}") from None
        try:
            document = json.loads(text)
        except json.JSONDecodeError as err:
            raise LogFileError(f"{path}: line {err.lineno}, column {err.colno}: invalid JSON ({err.msg}); save the "
                               "output of the --json option unchanged, e.g. `rig diagnose run.csv --json > "
                               "diagnosis.json`") from None
        except RecursionError:
            raise LogFileError(f"{path}: the JSON is nested too deeply; expected {EXPECTED}") from None
        return _results_of(document, path)
    try:
        return [ResultFile(path, "experiment", read_experiment_data(path))]
    except (LogFileError, InvalidInputError, ValueError) as err:
        reason = str(err).removeprefix(f"{path}: ")
        raise LogFileError(f"{path}: not a result file ({reason}); expected {EXPECTED}") from None


def read_result_file(path: str | Path) -> ResultFile:
    """:func:`read_result_files` of a file that holds one result (a batch file is refused: use that)."""
    from rig.protocols.errors import LogFileError

    results = read_result_files(path)
    if len(results) != 1:
        raise LogFileError(f"{path}: a batch file of {len(results)} results; read it with read_result_files")
    return results[0]


# ----------------------------------------------------------------------------------------------------------
# sections
# ----------------------------------------------------------------------------------------------------------


def _experiment_section(result: ResultFile, used: set[str]):
    from rig.plots.experiment import signal_figure, timing_figure
    from rig.report import ReportSection

    record = result.content
    slug = _unique(result.slug, used)
    text = (f"{result.path.name}: {len(record)} samples at a nominal period of {record.sample_period_s * 1e3:g} ms "
            f"({record.metadata.transport or 'unknown transport'}); {record.lost_count} lost samples; "
            f"{_timing_text(record)}.")
    figures = [signal_figure(record, f"signals_{slug}")]
    if _nothing_of_timing(record):
        text += (" No timing figure: the time column is the nominal grid k·T, no sample is flagged HELD, LATE or "
                 "LOST, and the log has no run summary; there is nothing of its timing to draw.")
    elif record.metadata.transport != OFFLINE_TRANSPORT:  # an offline simulation has no timing to draw
        figures.append(timing_figure(record, f"timing_{slug}"))
    return ReportSection(f"Experiment: {result.path.name}", text=text, figures=tuple(figures))


def _nothing_of_timing(record) -> bool:
    """Whether a log holds nothing of its timing: a nominal time column (no jitter to plot), no timing flag, no
    run summary (no lead): its timing figure would be an empty box."""
    import numpy as np

    from rig.plots.experiment import TIMING_FLAGS

    return (record.metadata.transport != OFFLINE_TRANSPORT and not record.metadata.extra.get("summary")
            and record.time_column_is_nominal()
            and not np.any(record.flags & int(sum(TIMING_FLAGS))))


def _timing_text(record) -> str:
    """What the log says of its timing. Device-clocked (the run's summary line says ``sample_clock``
    ``"device"``, or, in a log without it, the time column is the nominal grid k·T): the HELD count and the
    smallest lead the run measured, since the time column carries no jitter. Otherwise (host-paced, or data
    of another tool): the largest deviation of a period from T in the measured time column, and the send
    lateness quantiles when the run recorded them."""
    import math

    import numpy as np

    from identify.experiment_record import SampleFlag

    if record.metadata.transport == OFFLINE_TRANSPORT:
        return "an offline simulation (rig simulate): no wire and no clock, every sample at its instant k·T"
    summary = record.metadata.extra.get("summary", {})
    clock = summary.get("sample_clock")
    if clock == "device" or (clock is None and record.time_column_is_nominal()):
        lead = summary.get("min_lead_s")
        lead_text = (f"smallest lead of a setpoint over its instant {lead * 1e3:.3g} ms" if lead is not None
                     else "the smallest lead is not in this log")
        return (f"device-clocked (the time column is the device's sample instants k·T, no jitter to measure): "
                f"{record.count_flag(SampleFlag.HELD)} HELD samples (setpoints that missed their instant), "
                f"{lead_text}")
    jitter_s = record.period_deviation_s
    largest_us = float(np.max(np.abs(jitter_s))) * 1e6 if jitter_s.size else 0.0
    text = f"{'host-paced: ' if clock == 'host' else ''}largest period deviation {largest_us:.0f} us in the time column"
    quantiles = [(name, summary.get(f"send_lateness_{name}_s")) for name in ("p50", "p99", "max")]
    if all(value is not None and math.isfinite(value) for _, value in quantiles):
        text += ", send lateness " + ", ".join(f"{name} {value * 1e6:.0f} us" for name, value in quantiles)
    return text


def _set_membership_section(results: list[ResultFile], sample_period_s: float | None, used: set[str]):
    from rig.plots.set_membership import (backlash_characteristic_figure, feasible_polygons_figure, inner_signal_figure,
                                          linear_block_bode_figure, parameter_intervals_figure, parameter_sort_key,
                                          parameter_unit)
    from rig.report import ReportSection

    methods: dict[str, Any] = {}
    paragraphs = ["Guaranteed bounds of a linear block followed by an output backlash (Cerone, Piga and Regruto "
                  "2009): every parameter consistent with the data, the noise bound and the model structure lies "
                  "in its interval."]
    for result in results:
        identification = result.content
        label = identification.method
        if label in methods:
            label = _unique(f"{label} ({result.slug})", set(methods))
        if identification.is_empty:
            paragraphs.append(f"{result.name} ({label} method): EMPTY feasible set. {identification.explanation}")
            continue
        methods[label] = identification
        inner = identification.inner_signal
        paragraphs.append(f"{result.name} ({label} method): {inner.num_invertible} of {inner.lower_rad.size} "
                          "dynamic samples invertible.")
    figures = []
    header: tuple[str, ...] = ()
    rows: tuple[tuple[str, ...], ...] = ()
    if methods:
        intervals = {label: {**result.backlash_intervals, **result.linear_intervals}
                     for label, result in methods.items()}
        names = sorted({name for per in intervals.values() for name in per}, key=parameter_sort_key)
        header = ("parameter", "unit", *(f"{label} {end}" for label in methods for end in ("lower", "upper")))
        rows = tuple((name, parameter_unit(name),
                      *(f"{getattr(per[name], end):.6g}" if name in per else "-"
                        for per in intervals.values() for end in ("lower", "upper")))
                     for name in names)
        base = _unique("set_membership", used)
        figures.append(parameter_intervals_figure(methods, f"{base}_intervals"))
        figures.append(linear_block_bode_figure(methods, f"{base}_bode", sample_period_s=sample_period_s))
    drawn: list[dict[str, Any]] = []  # the methods share stages 1 and 2: one set of their figures per data set
    for result in results:
        identification = result.content
        if identification.backlash.is_empty:
            continue
        stages = {"backlash": identification.backlash.to_dict(),
                  "inner": None if identification.inner_signal is None else identification.inner_signal.to_dict()}
        if stages in drawn:
            continue
        drawn.append(stages)
        slug = _unique(f"set_membership_{result.slug}", used)
        figures += [backlash_characteristic_figure(identification, f"{slug}_backlash"),
                    feasible_polygons_figure(identification, f"{slug}_polygons")]
        if identification.inner_signal is not None:
            figures.append(inner_signal_figure(identification, f"{slug}_inner", sample_period_s=sample_period_s))
    return ReportSection("Set membership: output backlash and linear block", text="\n\n".join(paragraphs),
                         table_header=header, table_rows=rows, figures=tuple(figures))


def _hammerstein_section(result: ResultFile, sample_period_s: float | None, used: set[str]):
    import numpy as np

    from rig.plots.hammerstein import borders_figure, poles_figure, singular_values_figure
    from rig.report import ReportSection

    model = result.content
    slug = _unique(f"hammerstein_{result.slug}", used)
    rows = [("order", str(model.order))]
    rows += [(f"pole {k + 1}", f"{pole.real:+.6f} {pole.imag:+.6f}j") for k, pole in enumerate(model.poles)]
    rows.append(("stable", "yes" if model.stable else
                 f"NO: a pole has |p| = {float(np.max(np.abs(model.poles))):.4g} >= 1"))
    rows += [("mu0 = H[u_min] [rad]", f"{model.mu0:.6g}"), ("simulation fit [%]", f"{model.fit_percent:.6g}"),
             ("residual RMS [rad]", f"{model.residual_rms_rad:.6g}"), ("B and mu estimated", model.split)]
    text = (f"{result.name}: Hammerstein model with input backlash or switch identified by subspace "
            "(Pouliquen et al. 2013).")
    return ReportSection(f"Hammerstein model: {result.name}", text=text, table_header=("quantity", "value"),
                         table_rows=tuple(rows),
                         figures=(poles_figure(model, f"{slug}_poles", sample_period_s=sample_period_s),
                                  borders_figure(model, f"{slug}_borders"),
                                  singular_values_figure(model, f"{slug}_singular_values")))


def _diagnose_section(result: ResultFile, used: set[str]):
    from rig.plots.discrepancy import diagnosis_summary, verdict_heading
    from rig.report import ReportFigure, ReportSection

    report = result.content
    slug = _unique(f"diagnose_{result.slug}", used)
    steps = report.missing_effects

    def shown(step, key: str, value: float) -> str:
        interval = step.parameter_intervals.get(key)
        within = f" [{interval[0]:.4g}, {interval[1]:.4g}]" if interval is not None else ""
        return f"{key} = {value:.4g}{within}"

    rows = tuple((step.effect, ", ".join(shown(step, key, value) for key, value in step.parameters.items()) or "-",
                  f"{step.gap_before_rad:.4g}", f"{step.gap_after_rad:.4g}") for step in steps)
    gap_initial, gap_final = report.gap_initial_rad, report.gap_final_rad
    fractions = (f" Samples outside the noise bound: {100 * report.falsified_fraction_initial:.1f} % before, "
                 f"{100 * report.falsified_fraction_final:.1f} % after.")
    named = ", ".join(step.effect for step in steps) or "none"
    text = (f"{result.name}: {diagnosis_summary(report)} Free-run RMS error on the validation segment "
            f"{gap_initial:.4g} rad before, {gap_final:.4g} rad after.{fractions}")
    labels = ["start model"] + [f"+ {step.effect}" for step in steps]
    gaps = [gap_initial] + [step.gap_after_rad for step in steps]
    open_candidates = _open_candidates(report)

    def draw(figure) -> None:
        axes = figure.subplots()
        positions = range(len(gaps))
        axes.bar(positions, gaps, color=["tab:gray"] + ["tab:green"] * (len(gaps) - 1))
        if open_candidates:  # left open by the verdict: hatched, beside the final model, never part of it
            tried = range(len(gaps), len(gaps) + len(open_candidates))
            axes.bar(tried, [candidate.gap_rad for candidate in open_candidates], color="white",
                     edgecolor="tab:orange", hatch="//")
            positions = range(len(gaps) + len(open_candidates))
        axes.set_xticks(list(positions), labels + [f"{candidate.effect}?\n(not added)" for candidate in open_candidates],
                        fontsize=8)
        axes.set_xlabel("model [-]")
        axes.set_ylabel("validation gap (free-run RMS) [rad]")
        axes.grid(True, axis="y", lw=0.3, alpha=0.5)

    reduction = 100.0 * float(report.gap_reduction.get("value", 0.0))
    caption = (f"Model discrepancy: the free-run RMS error on the validation segment for the start model and after "
               f"each effect added ({named}); the gap went from {gap_initial:.4g} to {gap_final:.4g} rad "
               f"({reduction:.0f} % smaller). Look for each added effect lowering the bar clearly; a last bar still far "
               "above the noise level means something is still unexplained.")
    if open_candidates:
        caption += (" Hatched: the candidates the diagnosis left open, with the validated gap each reached when tried ("
                    + "; ".join(f"{candidate.effect} {candidate.gap_rad:.4g} rad" for candidate in open_candidates)
                    + "); the verdict says why none of them was added, so a low hatched bar is an explanation still "
                      "to decide between, not an unexplained rest.")
    return ReportSection(f"Model discrepancy: {result.name}, {verdict_heading(report)}", text=text,
                         table_header=("missing effect", "parameters", "gap before [rad]", "gap after [rad]"),
                         table_rows=rows, figures=(ReportFigure(f"{slug}_gap", caption, draw, size_in=(6.5, 3.5)),))


def _open_candidates(report) -> list:
    """The candidates a diagnosis left open and did not add, as tried in the round after the last effect added:
    those it is ambiguous between when it added none of them, then the undecided ones. (When it added one of
    them, the others are other mechanisms of the same fitted map, which the verdict's reason names; no bar of
    theirs would say more.)"""
    named = {step.effect for step in report.missing_effects}
    between = [] if named & set(report.ambiguous_between) else list(report.ambiguous_between)
    tried = {candidate.effect: candidate for candidate in report.candidates
             if candidate.round == len(report.missing_effects)}
    open_candidates = [tried[name] for name in between if name in tried]
    return open_candidates + [candidate for candidate in report.undecided
                              if candidate.effect not in {shown.effect for shown in open_candidates}]


def _run_summary_section(result: ResultFile):
    """What ``rig run`` did, as its summary says (no figure: the log itself draws the signals and timing)."""
    import math

    from rig.report import ReportSection

    summary = result.content
    rows = [("log", summary.log or "-"), ("samples", str(summary.samples)), ("lost", str(summary.lost)),
            ("late", str(summary.late)), ("duplicate", str(summary.duplicate))]
    if not math.isnan(summary.min_lead_s):  # device-clocked: a late setpoint is a HELD sample
        rows += [("held", str(summary.held)), ("smallest lead [ms]", f"{1e3 * summary.min_lead_s:.3g}")]
    if not math.isnan(summary.send_lateness_max_s):  # host-paced: the loop's own timing
        rows += [(f"send lateness {name} [us]", f"{1e6 * value:.0f}") for name, value in
                 (("p50", summary.send_lateness_p50_s), ("p99", summary.send_lateness_p99_s),
                  ("max", summary.send_lateness_max_s))]
    rows += [("not followed", str(summary.not_followed)), ("frame errors", str(summary.frame_errors)),
             ("achieved rate [Hz]", f"{summary.rate_hz:.6g}"), ("stop", summary.stop or "-")]
    rows += [("warning", warning) for warning in summary.warnings]
    text = (f"{result.name}: the summary `rig run --json` printed. Give the log file too to see the signals and "
            "the loop timing.")
    return ReportSection(f"Run: {result.name}", text=text, table_header=("quantity", "value"), table_rows=tuple(rows))



def _errors_section(results: list[ResultFile]):
    from rig.report import ReportSection

    return ReportSection("Files the batch commands could not process",
                         text="\n\n".join(f"{result.name}: {result.content}" for result in results))


def _unique(name: str, used: set[str]) -> str:
    candidate, counter = name, 2
    while candidate in used:
        candidate = f"{name}_{counter}"
        counter += 1
    used.add(candidate)
    return candidate


def report_sections(results: list[ResultFile], *, sample_period_s: float | None = None) -> list:
    """The report's sections: experiments, then set membership (all methods together), Hammerstein models,
    discrepancy diagnoses and run summaries, each in the order given.

    ``sample_period_s`` sets the frequency axis of the Bode and pole figures; without it the experiment logs'
    period is used when they all share one. Logs of different periods cannot say which one the results came
    from: the axes are then per sample, and the sections of the results say so.
    """
    import dataclasses

    experiments = [result for result in results if result.kind == "experiment"]
    periods = sorted({float(result.content.sample_period_s) for result in experiments})
    period_note = ""
    if sample_period_s is None and len(periods) == 1:
        sample_period_s = periods[0]
    elif sample_period_s is None and len(periods) > 1:
        period_note = (f" Frequencies are per sample: the logs were sampled every "
                       f"{', '.join(f'{1e3 * period:g}' for period in periods)} ms, and which of them the results "
                       "came from is not in the files; give --sample-period for hertz.")
    used: set[str] = set()
    sections = [_named(result, _experiment_section, result, used) for result in experiments]
    backlash_results = [result for result in results if result.kind == "output_backlash"]
    if backlash_results:
        sections.append(_named(backlash_results, _set_membership_section, backlash_results, sample_period_s, used))
    sections += [_named(result, _hammerstein_section, result, sample_period_s, used) for result in results
                 if result.kind == "hammerstein_model"]
    if period_note:
        sections = [dataclasses.replace(section, text=section.text + period_note)
                    if section.title.startswith(("Set membership", "Hammerstein")) else section
                    for section in sections]
    sections += [_named(result, _diagnose_section, result, used) for result in results
                 if result.kind == "model_discrepancy"]
    sections += [_named(result, _run_summary_section, result) for result in results if result.kind == "run_summary"]
    errors = [result for result in results if result.kind == "error"]
    if errors:
        sections.append(_errors_section(errors))
    return sections


def _named(results: ResultFile | list[ResultFile], build: Any, *arguments: Any):
    """``build(*arguments)``, with any error of a malformed document (while building the section or later,
    while drawing its figures) turned into one line naming the file(s)."""
    import dataclasses

    names = ", ".join(str(result.path) for result in (results if isinstance(results, list) else [results]))

    def failed(err: Exception) -> ValueError:
        return ValueError(f"{names}: cannot use this file for the report ({type(err).__name__}: "
                          f"{_short(str(err), 120)}); expected {EXPECTED}, written unchanged")

    try:
        section = build(*arguments)
    except (KeyError, TypeError, IndexError, AttributeError) as err:
        raise failed(err) from None
    except ValueError as err:
        if str(err).startswith(names.split(", ")[0]):
            raise
        raise failed(err) from None

    def guarded(draw: Any) -> Any:
        def draw_named(figure: Any) -> None:
            try:
                draw(figure)
            except (KeyError, TypeError, IndexError, AttributeError, ValueError) as err:
                raise failed(err) from None
        return draw_named

    return dataclasses.replace(section, figures=tuple(dataclasses.replace(figure, draw=guarded(figure.draw))
                                                      for figure in section.figures))


def write_result_report(paths: list[str | Path], out_dir: str | Path, *, title: str = "rig report",
                        sample_period_s: float | None = None) -> tuple[Path, int]:
    """Read every result file, write the report to ``out_dir``; return (index.html path, number of figures)."""
    from rig.report import write_report

    results = [result for path in paths for result in read_result_files(path)]
    sections = report_sections(results, sample_period_s=sample_period_s)
    index = write_report(out_dir, title, sections)
    return index, sum(len(section.figures) for section in sections)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not value > 0.0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number of seconds > 0, got {text!r}")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "report",
        help="write an HTML report with figures from logs and identification results",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("results", nargs="+", metavar="RESULT",
                        help="experiment log, t,u,y CSV, or saved JSON of rig identify/diagnose/run --json")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="directory for index.html and the PNG figures: a new or empty one, or an earlier report "
                             "of rig (another non-empty directory is refused unless --force)")
    parser.add_argument("--force", action="store_true", help="write into a --out directory that holds other files")
    parser.add_argument("--title", default="rig report", help="page title (default: rig report)")
    parser.add_argument("--sample-period", type=_positive_float, default=None, metavar="S",
                        help="sample period in seconds for frequency axes (default: the logs' period when they share one)")
    parser.add_argument("--json", action="store_true", help='print {"report": PATH, "figures": N}')
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from rig.output_paths import check_report_dir, writing

    check_report_dir(args.out, "--out", inputs=args.results, force=args.force)  # before the files are read and drawn
    with writing(args.out, "--out"):
        index, count = write_result_report(args.results, args.out, title=args.title,
                                           sample_period_s=args.sample_period)
    index = index.resolve()
    if args.json:
        print(json.dumps({"report": str(index), "figures": count}))
    else:
        print(index)
    sys.stdout.flush()
    return exit_codes.SUCCESS
