"""Section 9 of BENCHMARKS.md ("Every script and its section") and the documentation's benchmarks page name every
script in ``benchmarks/``, and only section headings that BENCHMARKS.md has.

- Section 9 has a row for every script, ``benchmarks/*.py`` and ``benchmarks/independent_plants/*.py``, and no
  row for a script that is gone; each row's command runs that script.
- Each row names the sections of its figures by their exact headings, in double quotes, or says
  "no figures" (a script whose output is not in BENCHMARKS.md).
- Every double-quoted name on ``docs/benchmarks.md`` is a heading of BENCHMARKS.md.
- The built page shows every script and every heading of section 9 (it includes the section, so the scripts are
  listed once).
"""

from __future__ import annotations

import re
from html import unescape
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS = ROOT / "BENCHMARKS.md"
PAGE = ROOT / "docs" / "benchmarks.md"
SCRIPTS = ROOT / "benchmarks"
SCRIPT_LIST = "9. Every script and its section"
NO_FIGURES = "no figures"

_QUOTED = re.compile(r'"([^"\n]+)"')
_CELL_BORDER = re.compile(r"(?<!\\)\|")


def _headings() -> set[str]:
    return set(re.findall(r"^#{1,6} (.+?)\s*$", BENCHMARKS.read_text(encoding="utf-8"), re.M))


def _script_list() -> dict[str, tuple[str, str]]:
    """Section 9's table: script (relative to benchmarks/) -> (where its figures are, its command)."""
    text = BENCHMARKS.read_text(encoding="utf-8")
    assert f"\n## {SCRIPT_LIST}\n" in text, f"BENCHMARKS.md has no section '## {SCRIPT_LIST}'"
    section = text.split(f"\n## {SCRIPT_LIST}\n", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [cell.strip() for cell in _CELL_BORDER.split(line.strip())[1:-1]]
        if len(cells) != 3 or set(cells[0]) <= set("-: ") or cells[0] == "script":
            continue  # not a row, or the header and its rule
        rows[cells[0].strip("`")] = (cells[1], cells[2])
    return rows


def _scripts() -> list[str]:
    return sorted(path.relative_to(SCRIPTS).as_posix()
                  for path in [*SCRIPTS.glob("*.py"), *SCRIPTS.glob("independent_plants/*.py")])


def test_section_9_has_a_row_and_a_command_for_every_script() -> None:
    rows = _script_list()
    missing = [script for script in _scripts() if script not in rows]
    assert not missing, (f"BENCHMARKS.md, section '{SCRIPT_LIST}': no row for {missing}; add "
                         "| `SCRIPT` | \"HEADING\" | COMMAND | with the heading of the section that holds its figures")
    gone = sorted(set(rows) - set(_scripts()))
    assert not gone, f"BENCHMARKS.md, section '{SCRIPT_LIST}': rows for scripts not in benchmarks/: {gone}"
    no_command = [script for script, (_, command) in rows.items() if Path(script).name not in command]
    assert not no_command, f"BENCHMARKS.md, section '{SCRIPT_LIST}': the command does not run {no_command}"


def test_section_9_names_only_headings_of_benchmarks_md() -> None:
    headings = _headings()
    unnamed, unknown = [], []
    for script, (where, _) in _script_list().items():
        names = _QUOTED.findall(where)
        if not names and not where.startswith(NO_FIGURES):
            unnamed.append(script)
        unknown += [f"{script}: \"{name}\"" for name in names if name not in headings]
    assert not unnamed, (f"BENCHMARKS.md, section '{SCRIPT_LIST}': {unnamed} name no section; quote the heading "
                         f"of the section with the figures, or write '{NO_FIGURES}'")
    assert not unknown, (f"BENCHMARKS.md, section '{SCRIPT_LIST}' names sections that have no heading in "
                         "BENCHMARKS.md (quote the heading exactly):\n" + "\n".join(unknown))


def test_the_docs_page_names_only_headings_of_benchmarks_md() -> None:
    headings = _headings()
    unknown = [name for name in _QUOTED.findall(PAGE.read_text(encoding="utf-8")) if name not in headings]
    assert not unknown, (f"{PAGE.relative_to(ROOT)} quotes section names that are not headings of BENCHMARKS.md "
                         f"(quote the heading exactly): {unknown}")


def test_the_built_page_shows_every_script_and_its_sections(site: Path) -> None:
    html = (site / "benchmarks.html").read_text(encoding="utf-8")
    text = unescape(re.sub(r"<[^>]+>", "", html))
    missing = [script for script in _scripts() if script not in text]
    assert not missing, f"{PAGE.relative_to(ROOT)} (built) does not list {missing}"
    sections = {name for where, _ in _script_list().values() for name in _QUOTED.findall(where)}
    missing = sorted(name for name in sections if name.replace("`", "") not in text)
    assert not missing, f"{PAGE.relative_to(ROOT)} (built) does not name the sections {missing}"


_CITED_SECTION = re.compile(r'BENCHMARKS\.md`?,?\s+(?:section \d+\s+)?\(?"([^"\n]+)"')


def test_every_docs_page_cites_sections_benchmarks_md_has() -> None:
    # a page that sends the reader to "BENCHMARKS.md, "HEADING"" must name a heading the file has
    headings = _headings()
    wrong = []
    for path in sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]:
        text = " ".join(path.read_text(encoding="utf-8").split())  # citations wrap across lines
        wrong += [f"{path.relative_to(ROOT)}: {name!r}" for name in _CITED_SECTION.findall(text)
                  if name not in headings]
    assert not wrong, "cited sections that BENCHMARKS.md has no heading for (rename to the heading): " + "; ".join(wrong)
