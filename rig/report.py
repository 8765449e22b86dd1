"""Static HTML reports with PNG figures (``rig report`` and ``rig demo``).

A report is a list of :class:`ReportSection`; each holds a short text, an optional table and
:class:`ReportFigure` objects. A figure is a drawing function plus a caption that says what to look for,
so the plotting code (``rig.plots.*``) stays separate from the page layout. matplotlib is imported here
only, with the non-interactive Agg backend.
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

FIGURE_DPI = 110

ROUNDING_OF_ZERO = 1e-9
"""A bound whose magnitude is below this fraction of its interval's width is the solver's rounding of 0
(an LP vertex at ``-1.15e-14`` for a dead band that starts at 0) and is printed as 0."""


def format_bound(value: float, width: float, digits: int = 5) -> str:
    """``value`` with ``digits`` significant digits; 0 when it is rounding of 0 next to ``width``
    (:data:`ROUNDING_OF_ZERO`); ``inf`` and ``-inf`` as such."""
    if math.isfinite(width) and abs(value) <= ROUNDING_OF_ZERO * abs(width):
        return "0"
    return f"{value:.{digits}g}"


def format_interval(lower: float, upper: float, digits: int = 5, unit: str = "") -> str:
    """``[lower, upper]`` as a report prints it (see :func:`format_bound`), with `` unit`` when given."""
    width = upper - lower if upper > lower else 0.0
    suffix = f" {unit}" if unit and unit != "-" else ""
    return f"[{format_bound(lower, width, digits)}, {format_bound(upper, width, digits)}]{suffix}"


@dataclass(frozen=True)
class ReportFigure:
    """One PNG figure of a report.

    Parameters
    ----------
    name
        File stem of the PNG (letters, digits, ``-`` and ``_``).
    caption
        What the reader should look for in the figure.
    draw
        Draws into the given matplotlib ``Figure``; every axis it creates must carry a label with units.
    size_in
        Figure size (width, height) in inches.
    """

    name: str
    caption: str
    draw: Callable[[Any], None]
    size_in: tuple[float, float] = (7.0, 4.0)

    def __post_init__(self) -> None:
        if not re.fullmatch(r"[A-Za-z0-9_-]+", self.name):
            raise ValueError(f"figure name {self.name!r}: use letters, digits, '-' and '_' only")


@dataclass(frozen=True)
class ReportSection:
    """A titled part of a report: a paragraph, an optional table, optional commands (shown as typed, one a
    line) and its figures."""

    title: str
    text: str = ""
    table_header: tuple[str, ...] = ()
    table_rows: tuple[tuple[str, ...], ...] = ()
    figures: tuple[ReportFigure, ...] = field(default_factory=tuple)
    commands: tuple[str, ...] = ()


def write_report(out_dir: str | Path, title: str, sections: Sequence[ReportSection]) -> Path:
    """Render every figure to ``out_dir/<name>.png`` and write ``out_dir/index.html``; return its path.

    Raises ``ValueError`` if two figures share a name (one would overwrite the other).
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from rig.output_paths import atomic_output, mark_report_dir

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    mark_report_dir(out_dir)  # rig may write this directory again; a directory of the user's it refuses
    names = [figure.name for section in sections for figure in section.figures]
    duplicated = sorted({name for name in names if names.count(name) > 1})
    if duplicated:
        raise ValueError(f"report figures must have distinct names; repeated: {', '.join(duplicated)}")

    body: list[str] = [f"<h1>{html.escape(title)}</h1>"]
    for section in sections:
        body.append(f"<h2>{html.escape(section.title)}</h2>")
        if section.text:
            body.extend(f"<p>{html.escape(paragraph)}</p>" for paragraph in section.text.split("\n\n"))
        if section.table_rows:
            body.append(_html_table(section.table_header, section.table_rows))
        if section.commands:
            body.append(f"<pre>{html.escape(chr(10).join(section.commands))}</pre>")
        for report_figure in section.figures:
            figure = Figure(figsize=report_figure.size_in, layout="constrained")
            report_figure.draw(figure)
            figure.savefig(out_dir / f"{report_figure.name}.png", dpi=FIGURE_DPI)
            body.append(
                "<figure>"
                f'<img src="{report_figure.name}.png" alt="{html.escape(report_figure.caption)}">'
                f"<figcaption>{html.escape(report_figure.caption)}</figcaption></figure>"
            )
    page = (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>\n<body>\n"
        + "\n".join(body)
        + "\n</body></html>\n"
    )
    index = out_dir / "index.html"
    with atomic_output(index, force=True) as written:  # a reader never sees half a page
        written.write_text(page, encoding="utf-8")
    return index


def missing_images(index_path: str | Path) -> list[str]:
    """Return the image sources referenced by ``index_path`` that do not exist or are empty."""
    index_path = Path(index_path)
    sources = re.findall(r'<img src="([^"]+)"', index_path.read_text(encoding="utf-8"))
    return [source for source in sources
            if not (index_path.parent / source).is_file() or (index_path.parent / source).stat().st_size == 0]


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    head = "".join(f"<th>{html.escape(cell)}</th>" for cell in header)
    lines = "".join("<tr>" + "".join(f"<td>{html.escape(cell)}</td>" for cell in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{lines}</tbody></table>"


_STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:60rem;margin:2rem auto;padding:0 1rem;color:#222}"
    "table{border-collapse:collapse;margin:1rem 0}td,th{border:1px solid #bbb;padding:.25rem .6rem;"
    "text-align:right;font-variant-numeric:tabular-nums}th{background:#f0f0f0}"
    "figure{margin:1.5rem 0}img{max-width:100%}figcaption{font-size:.9rem;color:#555}"
    "pre{white-space:pre-wrap;background:#f6f6f6;padding:.5rem .8rem;font-size:.85rem}"
)
