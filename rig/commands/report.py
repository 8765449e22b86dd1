"""``rig report RESULTS... --out DIR``: a static HTML page with PNG figures from the files a user has.

RESULTS may be, in any order and mixed:

* experiment logs (``rig-log v1``) or plain CSV files with columns ``t,u,y``: signals and loop timing;
* the JSON printed by ``rig identify output-backlash --json`` (one file per method; several are shown side by
  side): interval table, interval figure and the Bode magnitude of the linear-block box; the file written by
  its ``--save`` adds the backlash band, the feasible polygons and the inner-signal bounds;
* the JSON printed by ``rig identify hammerstein --json``: poles, borders and singular values;
* the JSON printed by ``rig diagnose --json``: the missing effects and how much each closed the gap.

Each file is recognised by its content (the log header, or the JSON keys); anything else is refused with a
message naming the file and what was expected.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig import exit_codes

__all__ = ["ResultFile", "read_result_file", "register", "report_sections", "run", "write_result_report"]

DESCRIPTION = """\
Write a static HTML report (index.html and PNG figures) from result files:

  experiment logs (rig-log v1) or CSV files with columns t,u,y     signals and sample-period jitter
  JSON of `rig identify output-backlash --json` (one per method)  intervals side by side, Bode of the box
  file of `rig identify output-backlash --save FILE`             the same, plus polygons, band, inner bounds
  JSON of `rig identify hammerstein --json`                      poles, borders, singular values
  JSON of `rig diagnose --json`                                  missing effects and the gap they closed

Save the JSON with e.g. `rig identify hammerstein run.csv --json > hammerstein.json`. The frequency axis
of the Bode figure is in Hz when --sample-period is given or an experiment log is among the files, else in
cycles per sample. The command prints the path of index.html."""

EXPECTED = ("a rig-log v1 experiment log, a CSV file with columns t,u,y, or the JSON printed by "
            "`rig identify output-backlash --json`, `rig identify hammerstein --json` or `rig diagnose --json`")


@dataclass(frozen=True)
class ResultFile:
    """One input of the report: its path, its kind and its content.

    ``kind`` is ``"experiment"`` (``content`` an :class:`identify.experiment_record.ExperimentRecord`),
    ``"output_backlash"``, ``"hammerstein"`` or ``"diagnose"`` (``content`` the parsed JSON object).
    """

    path: Path
    kind: str
    content: Any

    @property
    def slug(self) -> str:
        """The file stem reduced to the characters a figure name allows."""
        return re.sub(r"[^A-Za-z0-9_-]+", "_", self.path.stem).strip("_") or "result"


def _json_kind(document: Any) -> str | None:
    if not isinstance(document, dict):
        return None
    keys = set(document)
    if {"missing_effects", "gap_initial", "gap_final"} <= keys:
        return "diagnose"
    if {"order", "poles", "borders", "singular_values"} <= keys:
        return "hammerstein"
    if {"backlash", "linear", "method"} <= keys or (document.get("empty") is True and "method" in keys):
        return "output_backlash"
    return None


MAX_JSON_BYTES = 256 << 20
"""Largest result JSON read (a --save file of a million samples is about 40 MB)."""


def _short(value: Any, limit: int = 80) -> str:
    """At most ``limit`` characters of ``value`` for a message (never a whole array or file)."""
    text = value if isinstance(value, str) else repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _check_hammerstein(document: dict[str, Any], path: Path) -> None:
    """Refuse a malformed `rig identify hammerstein --json` document before anything is drawn from it."""
    import numpy as np

    from rig.protocols.errors import LogFileError

    try:
        order = document["order"]
        if isinstance(order, bool) or not isinstance(order, int) or order < 1:
            raise ValueError(f"order is {_short(repr(order))}, expected an integer >= 1")
        def numbers(key: str, value: Any) -> Any:
            try:
                return np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"{key}: expected numbers, got {_short(value, 40)}") from None

        poles = numbers("poles", document["poles"])
        if poles.ndim != 2 or poles.shape[1] != 2 or not np.all(np.isfinite(poles)):
            raise ValueError("poles: expected a list of [real, imaginary] pairs of finite numbers")
        for side in ("ascending", "descending"):
            border = document["borders"][side]
            u, h = numbers(f"borders.{side}.u", border["u"]), numbers(f"borders.{side}.h", border["h"])
            if u.ndim != 1 or u.shape != h.shape or u.size < 2 or not np.all(np.isfinite(u) & np.isfinite(h)):
                raise ValueError(f"borders.{side}: expected lists u and h of the same length >= 2, finite numbers")
        singular = numbers("singular_values", document["singular_values"])
        if singular.ndim != 1 or singular.size < 1 or not np.all(np.isfinite(singular)):
            raise ValueError("singular_values: expected a list of finite numbers")
    except KeyError as err:
        raise LogFileError(f"{path}: key {err} is missing; expected the JSON of `rig identify hammerstein --json` "
                           "unchanged (write it again with that command)") from None
    except (TypeError, ValueError) as err:
        raise LogFileError(f"{path}: not the JSON of `rig identify hammerstein --json`: {_short(str(err), 160)}; "
                           "write it again with that command") from None


def read_result_file(path: str | Path) -> ResultFile:
    """Recognise and read one result file.

    Raises
    ------
    FileNotFoundError
        The path is not a file.
    rig.protocols.errors.LogFileError
        The file is none of the known kinds; the message names the file and what was expected.
    """
    from identify.validation import InvalidInputError
    from rig.log_file import read_experiment_data
    from rig.protocols.errors import LogFileError

    from rig.signal_files import check_input_file

    path = check_input_file(path, EXPECTED)
    from rig.measurement_files import measurement_format

    if measurement_format(path) is not None:  # binary: an MDF4 or MAT file is an experiment or nothing
        return ResultFile(path, "experiment", read_experiment_data(path))
    with path.open("rb") as handle:
        head = handle.read(4096)
    nul = head.find(b"\0")
    if nul >= 0:
        raise LogFileError(f"{path}: not a text file (NUL bytes at byte {nul}); expected {EXPECTED}")
    if head.removeprefix(b"\xef\xbb\xbf").startswith(b"# rig-log"):
        return ResultFile(path, "experiment", read_experiment_data(path))
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
        kind = _json_kind(document)
        if kind == "hammerstein":
            _check_hammerstein(document, path)
        if kind is None:
            keys = _short(", ".join(sorted(document))) if isinstance(document, dict) else type(document).__name__
            raise LogFileError(
                f"{path}: JSON with keys [{keys}] is not a result this command knows; expected the JSON of "
                "`rig identify output-backlash --json` (keys backlash, linear, method), `rig identify hammerstein "
                "--json` (keys order, poles, borders, singular_values) or `rig diagnose --json` (keys "
                "missing_effects, gap_initial, gap_final)")
        return ResultFile(path, kind, document)
    try:
        return ResultFile(path, "experiment", read_experiment_data(path))
    except (LogFileError, InvalidInputError, ValueError) as err:
        reason = str(err).removeprefix(f"{path}: ")
        raise LogFileError(f"{path}: not a result file ({reason}); expected {EXPECTED}") from None


# ----------------------------------------------------------------------------------------------------------
# sections
# ----------------------------------------------------------------------------------------------------------


def _intervals(document: dict[str, Any], group: str, path: Path) -> dict[str, Any]:
    from identify.feasible_parameter_set import ParameterInterval

    def number(value: Any) -> float:
        return float(value)  # the JSON writes infinite bounds as the strings "inf"/"-inf"; float() reads both

    out = {}
    for name, values in document.get(group, {}).items():
        try:
            out[name] = ParameterInterval(number(values["lower"]), number(values["upper"]))
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{path}: {group}.{name}: expected an object with numbers lower and upper, got "
                             f"{_short(values)}") from None
    return out


def _experiment_section(result: ResultFile, used: set[str]):
    import numpy as np

    from rig.plots.experiment import signal_figure, timing_figure
    from rig.report import ReportSection

    record = result.content
    slug = _unique(result.slug, used)
    jitter = np.diff(record.time_s) - record.sample_period_s
    text = (f"{result.path.name}: {len(record)} samples at a nominal period of {record.sample_period_s * 1e3:g} ms "
            f"({record.metadata.transport or 'unknown transport'}); {record.lost_count} lost samples; largest period "
            f"deviation {float(np.max(np.abs(jitter))) * 1e6 if jitter.size else 0.0:.0f} us.")
    return ReportSection(f"Experiment: {result.path.name}", text=text,
                         figures=(signal_figure(record, f"signals_{slug}"), timing_figure(record, f"timing_{slug}")))


def _set_membership_section(results: list[ResultFile], sample_period_s: float | None, used: set[str]):
    from rig.plots.set_membership import (linear_block_bode_figure, parameter_intervals_figure, parameter_sort_key,
                                          parameter_unit)
    from rig.report import ReportSection

    methods: dict[str, dict[str, Any]] = {}
    paragraphs = ["Guaranteed bounds of a linear block followed by an output backlash (Cerone, Piga and Regruto "
                  "2009): every parameter consistent with the data, the noise bound and the model structure lies "
                  "in its interval."]
    for result in results:
        document = result.content
        label = str(document.get("method", result.slug))
        if label in methods:
            label = _unique(f"{label} ({result.slug})", set(methods))
        if document.get("empty"):
            paragraphs.append(f"{result.path.name} ({label} method): EMPTY feasible set. "
                              f"{document.get('explanation', '')}")
            continue
        methods[label] = {**_intervals(document, "backlash", result.path), **_intervals(document, "linear", result.path)}
        if "invertible_samples" in document and "samples" in document:
            paragraphs.append(f"{result.path.name} ({label} method): {document['invertible_samples']} of "
                              f"{document['samples']} dynamic samples invertible.")
    figures = []
    header: tuple[str, ...] = ()
    rows: tuple[tuple[str, ...], ...] = ()
    if methods:
        names = sorted({name for per in methods.values() for name in per}, key=parameter_sort_key)
        header = ("parameter", "unit", *(f"{label} {end}" for label in methods for end in ("lower", "upper")))
        rows = tuple((name, parameter_unit(name),
                      *(f"{getattr(per[name], end):.6g}" if name in per else "-"
                        for per in methods.values() for end in ("lower", "upper")))
                     for name in names)
        base = _unique("set_membership", used)
        figures.append(parameter_intervals_figure(methods, f"{base}_intervals"))
        if any(re.fullmatch(r"b\d+", name) for per in methods.values() for name in per):
            figures.append(linear_block_bode_figure(methods, f"{base}_bode", sample_period_s=sample_period_s))
    for result in results:
        if "data" in result.content and not result.content.get("empty"):
            figures += _saved_set_figures(result, sample_period_s, used)
    return ReportSection("Set membership: output backlash and linear block", text="\n\n".join(paragraphs),
                         table_header=header, table_rows=rows, figures=tuple(figures))


def _saved_set_figures(result: ResultFile, sample_period_s: float | None, used: set[str]) -> list:
    """The backlash band, the feasible polygons and the inner-signal bounds of a ``--save`` file,
    recomputed exactly from the data it holds (D_γ and the inner bounds are closed-form, eqs. (11)-(28);
    the costly linear-block bounds are read from the file)."""
    from identify.feasible_parameter_set import bound_backlash_parameters
    from identify.inner_signal_bounds import bound_inner_signal
    from rig.plots.set_membership import backlash_characteristic_figure, feasible_polygons_figure, inner_signal_figure

    data = result.content["data"]
    try:
        noise = float(data["noise_bound_rad"])
        backlash = bound_backlash_parameters(data["steady"]["u"], data["steady"]["y"], noise,
                                             filter_step_amplitude_rad=data.get("filter_step_rad"))
        inner = None if backlash.is_empty else bound_inner_signal(data["dynamic"]["y"], noise, backlash)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{result.path}: data: expected steady.u, steady.y, dynamic.y and noise_bound_rad as "
                         f"written by `rig identify output-backlash --save` ({_short(str(err), 160)})") from None
    slug = _unique(f"set_membership_{result.slug}", used)
    figures = [backlash_characteristic_figure(backlash, f"{slug}_backlash"),
               feasible_polygons_figure(backlash, f"{slug}_polygons")]
    if inner is not None:
        figures.append(inner_signal_figure(inner, f"{slug}_inner", sample_period_s=sample_period_s))
    return figures


def _hammerstein_section(result: ResultFile, sample_period_s: float | None, used: set[str]):
    from rig.plots.hammerstein import borders_figure, poles_figure, singular_values_figure
    from rig.report import ReportSection

    document = result.content
    slug = _unique(f"hammerstein_{result.slug}", used)
    rows = [("order", str(document["order"]))]
    rows += [(f"pole {k + 1}", f"{re_part:+.6f} {im_part:+.6f}j") for k, (re_part, im_part) in enumerate(document["poles"])]
    if "stable" in document:
        rows.append(("stable", "yes" if document["stable"] else
                     f"NO: a pole has |p| = {float(document.get('max_pole_magnitude', float('nan'))):.4g} >= 1"))
    for key, label in (("mu0", "mu0 = H[u_min] [rad]"), ("fit_percent", "simulation fit [%]"),
                       ("residual_rms", "residual RMS [rad]"), ("split", "B and mu estimated")):
        if key in document:
            value = document[key]
            rows.append((label, f"{value:.6g}" if isinstance(value, (int, float)) else str(value)))
    text = (f"{result.path.name}: Hammerstein model with input backlash or switch identified by subspace "
            "(Pouliquen et al. 2013).")
    return ReportSection(f"Hammerstein model: {result.path.name}", text=text, table_header=("quantity", "value"),
                         table_rows=tuple(rows),
                         figures=(poles_figure(document, f"{slug}_poles", sample_period_s=sample_period_s),
                                  borders_figure(document, f"{slug}_borders"),
                                  singular_values_figure(document, f"{slug}_singular_values")))


def _diagnose_section(result: ResultFile, used: set[str]):
    from rig.report import ReportFigure, ReportSection

    document = result.content
    slug = _unique(f"diagnose_{result.slug}", used)
    effects = list(document.get("missing_effects") or [])
    try:
        gap_initial = float(document["gap_initial"])
        gap_final = float(document["gap_final"])
        steps = [(str(e["effect"]), float(e["gap_before"]), float(e["gap_after"]), dict(e.get("parameters", {})))
                 for e in effects]
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{result.path}: expected the JSON of `rig diagnose --json` (missing_effects with effect, "
                         f"parameters, gap_before, gap_after; gap_initial; gap_final): {_short(err)}") from None
    intervals = {str(e["effect"]): e.get("parameter_intervals") or {} for e in effects}

    def shown(name: str, key: str, value) -> str:
        if not isinstance(value, (int, float)):
            return f"{key} = {value}"
        interval = intervals.get(name, {}).get(key)
        within = (f" [{float(interval[0]):.4g}, {float(interval[1]):.4g}]"
                  if isinstance(interval, (list, tuple)) and len(interval) == 2 else "")
        return f"{key} = {value:.4g}{within}"

    rows = tuple((name, ", ".join(shown(name, key, value) for key, value in parameters.items()) or "-",
                  f"{before:.4g}", f"{after:.4g}") for name, before, after, parameters in steps)
    fractions = ""
    if "falsified_fraction_initial" in document and "falsified_fraction_final" in document:
        fractions = (f" Samples outside the noise bound: {100 * float(document['falsified_fraction_initial']):.1f} % "
                     f"before, {100 * float(document['falsified_fraction_final']):.1f} % after.")
    named = ", ".join(name for name, *_ in steps) or "none"
    verdict = _diagnose_verdict(document, bool(steps))
    from rig.commands.diagnose import VERDICT_WORDS

    reason = str(document.get("verdict_reason") or "")
    text = (f"{result.path.name}: verdict {VERDICT_WORDS.get(verdict, verdict)}"
            f"{': ' + reason if reason else ''}. Missing effects named, in order: {named}. Free-run RMS error on "
            f"the validation segment {gap_initial:.4g} rad before, {gap_final:.4g} rad after.{fractions}"
            f"{_candidates_text(document)}")
    labels = ["start model"] + [f"+ {name}" for name, *_ in steps]
    gaps = [gap_initial] + [after for _, _, after, _ in steps]

    def draw(figure) -> None:
        axes = figure.subplots()
        positions = range(len(gaps))
        axes.bar(positions, gaps, color=["tab:gray"] + ["tab:green"] * (len(gaps) - 1))
        axes.set_xticks(list(positions), labels, fontsize=8)
        axes.set_xlabel("model [-]")
        axes.set_ylabel("validation gap (free-run RMS) [rad]")
        axes.grid(True, axis="y", lw=0.3, alpha=0.5)

    reduction = (1.0 - gap_final / gap_initial) * 100.0 if gap_initial > 0 else 0.0
    caption = (f"Model discrepancy: the free-run RMS error on the validation segment for the start model and after "
               f"each effect added ({named}); the gap went from {gap_initial:.4g} to {gap_final:.4g} rad "
               f"({reduction:.0f} % smaller). Look for each added effect lowering the bar clearly; a last bar still far "
               "above the noise level means something is still unexplained.")
    return ReportSection(f"Model discrepancy: {result.path.name}", text=text,
                         table_header=("missing effect", "parameters", "gap before [rad]", "gap after [rad]"),
                         table_rows=rows, figures=(ReportFigure(f"{slug}_gap", caption, draw, size_in=(6.5, 3.5)),))


def _candidates_text(document: dict) -> str:
    """The first round's candidates with their validated gaps, best first (empty for older JSON)."""
    candidates = [c for c in document.get("candidates") or [] if isinstance(c, dict) and c.get("round") == 0]
    try:
        ranked = sorted(candidates, key=lambda c: float(c["penalised_gap"]))
        words = "; ".join(f"{c['effect']} {float(c['gap']):.3g} +- {float(c['gap_uncertainty']):.2g} rad"
                          + (" (vanished)" if c.get("vanished") else "") for c in ranked)
    except (KeyError, TypeError, ValueError):
        return ""
    return f" Candidates tried first, with their validated gaps: {words}." if words else ""


DIAGNOSE_CONSISTENT_FRACTION = 0.01
"""A diagnosis JSON written before the verdict existed counts as explained only if at most this fraction of
validation samples stays falsified (the workflow's default ``consistent_fraction``)."""


def _diagnose_verdict(document: dict, named: bool) -> str:
    """The document's verdict; for JSON without one, the verdict its numbers imply (never "explained" while
    samples stay falsified)."""
    verdict = document.get("verdict")
    if isinstance(verdict, str):
        return verdict
    if named:
        return "named"
    final = document.get("falsified_fraction_final")
    if isinstance(final, (int, float)) and final <= DIAGNOSE_CONSISTENT_FRACTION:
        return "explained"
    return "unexplained"


def _unique(name: str, used: set[str]) -> str:
    candidate, counter = name, 2
    while candidate in used:
        candidate = f"{name}_{counter}"
        counter += 1
    used.add(candidate)
    return candidate


def report_sections(results: list[ResultFile], *, sample_period_s: float | None = None) -> list:
    """The report's sections: experiments, then set membership (all methods together), Hammerstein models and
    discrepancy diagnoses, each in the order given.

    ``sample_period_s`` sets the frequency axis of the Bode and pole figures; without it the first experiment
    log's period is used, if any.
    """
    experiments = [result for result in results if result.kind == "experiment"]
    if sample_period_s is None and experiments:
        sample_period_s = float(experiments[0].content.sample_period_s)
    used: set[str] = set()
    sections = [_named(result, _experiment_section, result, used) for result in experiments]
    backlash_results = [result for result in results if result.kind == "output_backlash"]
    if backlash_results:
        sections.append(_named(backlash_results, _set_membership_section, backlash_results, sample_period_s, used))
    sections += [_named(result, _hammerstein_section, result, sample_period_s, used) for result in results
                 if result.kind == "hammerstein"]
    sections += [_named(result, _diagnose_section, result, used) for result in results if result.kind == "diagnose"]
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

    results = [read_result_file(path) for path in paths]
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
                        help="experiment log, t,u,y CSV, or saved JSON of rig identify/diagnose --json")
    parser.add_argument("--out", required=True, metavar="DIR", help="directory for index.html and the PNG figures")
    parser.add_argument("--title", default="rig report", help="page title (default: rig report)")
    parser.add_argument("--sample-period", type=_positive_float, default=None, metavar="S",
                        help="sample period in seconds for frequency axes (default: from the first log, if any)")
    parser.add_argument("--json", action="store_true", help='print {"report": PATH, "figures": N}')
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from rig.output_paths import check_output_dir, writing

    check_output_dir(args.out, "--out", inputs=args.results)  # before the files are read and drawn
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
