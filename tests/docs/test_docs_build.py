"""The documentation site (docs/, Sphinx + MyST) builds, its internal links hold, and its examples run.

- The site is built once per session exactly as ``scripts/build_docs`` builds it (``-W --keep-going``: every
  warning fails, among them a link to a page or heading that does not exist and a docstring whose markup does
  not parse).
- Every relative link and image in the built HTML points at a file of the build, and every ``#anchor`` at an
  id in that file. External links are not followed (no network at test time).
- The built site is self-contained: no page loads a script, style sheet or font from the network (the equations
  are MathML, written when the site is built), so it reads the same offline.
- The command-line reference is generated from ``rig.cli.build_parser``: every command and option is on it.
- The README stays a short entry point whose quick start holds exactly the two commands CI runs.
- Shell and Python blocks marked ``:class: tested`` in the pages are run, in page order, in a scratch directory
  with ``configs/`` linked in and ``rig`` on the path (this source tree's code). Blocks marked
  ``tested-realdata`` use ``../shared/realdata`` and run only with ``RIG_REALDATA=1``, like the other tests
  on real records.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

EXAMPLE_TIMEOUT_S = 120.0
"""Per block: the tested blocks take a few seconds each; the margin is for a machine shared with other work."""


def test_the_build_script_builds_with_warnings_as_errors() -> None:
    script = (ROOT / "scripts" / "build_docs").read_text()
    assert "-W --keep-going" in script and "build/docs" in script
    assert os.access(ROOT / "scripts" / "build_docs", os.X_OK)


def test_every_page_is_built(site: Path) -> None:
    pages = [path.relative_to(DOCS).with_suffix(".html") for path in DOCS.rglob("*.md") if "_ext" not in path.parts]
    missing = [str(page) for page in pages if not (site / page).is_file()]
    assert not missing, f"pages not built: {missing}"
    assert {"index.html", "reference/cli.html", "reference/api/index.html"} <= {
        str(path.relative_to(site)) for path in site.rglob("*.html")}


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.targets: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if values.get("id"):
            self.ids.add(values["id"])
        if tag == "a" and values.get("name"):
            self.ids.add(values["name"])
        for key in ("href", "src"):
            if values.get(key):
                self.targets.append(values[key])


def _parse(path: Path) -> _Links:
    links = _Links()
    links.feed(path.read_text(encoding="utf-8"))
    return links


def test_internal_links_and_anchors_resolve(site: Path) -> None:
    parsed = {path: _parse(path) for path in site.rglob("*.html")}
    broken = []
    for page, links in parsed.items():
        for target in links.targets:
            parts = urlsplit(target)
            if parts.scheme or parts.netloc or target.startswith(("mailto:", "javascript:")):
                continue  # external: not followed without a network
            file = (page.parent / unquote(parts.path)).resolve() if parts.path else page
            if not file.exists():
                broken.append(f"{page.relative_to(site)}: {target} (no such file)")
            elif parts.fragment and file.suffix == ".html":
                ids = parsed[file].ids if file in parsed else _parse(file).ids
                if unquote(parts.fragment) not in ids:
                    broken.append(f"{page.relative_to(site)}: {target} (no id {parts.fragment!r})")
    assert not broken, "broken internal links:\n" + "\n".join(broken[:40])


_LOADED_LINKS = {"stylesheet", "icon", "preload", "modulepreload", "manifest"}
"""The <link rel> kinds a browser fetches when it shows the page (index, search, next... are navigation)."""


class _Resources(HTMLParser):
    """What a page loads when it is shown: script sources, style sheets and other <link> resources, images and
    frames, and url(...) in inline styles (a link a reader may follow, <a href>, is not loaded)."""

    def __init__(self) -> None:
        super().__init__()
        self.loaded: list[str] = []
        self.equations = 0

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if tag in ("script", "img", "iframe", "source", "embed") and values.get("src"):
            self.loaded.append(values["src"])
        if tag == "link" and values.get("href") and set((values.get("rel") or "").split()) & _LOADED_LINKS:
            self.loaded.append(values["href"])
        self.loaded += re.findall(r"url\(['\"]?([^'\")]+)", values.get("style") or "")
        self.equations += tag == "math"


def test_the_site_loads_nothing_from_the_network_and_its_equations_are_mathml(site: Path) -> None:
    remote = []
    equations = 0
    for page in sorted(site.rglob("*.html")):
        resources = _Resources()
        resources.feed(page.read_text(encoding="utf-8"))
        equations += resources.equations
        remote += [f"{page.relative_to(site)}: {url}" for url in resources.loaded
                   if urlsplit(url).scheme in ("http", "https") or url.startswith("//")]
    for sheet in sorted(site.rglob("*.css")):
        remote += [f"{sheet.relative_to(site)}: {url}" for url in re.findall(
            r"(?:url\(['\"]?|@import\s+['\"])((?:https?:)?//[^'\")\s]+)", sheet.read_text(encoding="utf-8"))]
    assert not remote, "the site loads from the network:\n" + "\n".join(remote[:20])
    method_page = (site / "methods" / "set_membership.html").read_text(encoding="utf-8")
    assert equations > 50 and "<math" in method_page and "\\begin{cases}" not in method_page
    drive_train = (site / "reference" / "api" / "identify.drive_train.html").read_text(encoding="utf-8")
    assert "<mtable" in drive_train and not re.search(r"<mi>&(amp;)?</mi>", drive_train)  # aligned at &, not "&"


def _commands(parser: argparse.ArgumentParser, words: tuple[str, ...] = ("rig",)):
    yield words, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*words, name))


def test_the_cli_reference_has_every_command_and_option(site: Path) -> None:
    from rig.cli import build_parser

    page = site / "reference" / "cli.html"
    ids = _parse(page).ids
    text = page.read_text(encoding="utf-8")
    for words, parser in _commands(build_parser()):
        assert "cli-" + "-".join(words) in ids, f"no section for {' '.join(words)}"
        for action in parser._actions:
            for option in action.option_strings:
                if option not in ("-h", "--help"):
                    assert option in text, f"{' '.join(words)} {option} is missing from the CLI reference"


def test_readme_is_a_short_entry_point_with_the_two_quick_start_commands() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 150
    quick_start = readme.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    commands = [line.split("#", 1)[0].strip() for line in quick_start.splitlines() if line.startswith("./scripts/")]
    assert commands == ["./scripts/demo", "./scripts/test"]
    assert "exec ./scripts/test" in (ROOT / ".ci" / "run").read_text()
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme):
        if not urlsplit(target).scheme:
            assert (ROOT / target).exists(), f"README links to {target}, which does not exist"


# ---------------------------------------------------------------------------------------------------------------
# The examples of the pages
# ---------------------------------------------------------------------------------------------------------------

_BLOCK = re.compile(r"^```\{code-block\} (?P<language>\w+)\n(?P<options>(?::[\w-]+:[^\n]*\n)*)\n?(?P<body>.*?)^```\s*$",
                    re.M | re.S)


def _tested_blocks(page: Path, tag: str) -> list[tuple[str, str]]:
    blocks = []
    for match in _BLOCK.finditer(page.read_text(encoding="utf-8")):
        classes = re.search(r"^:class:\s*(.*)$", match["options"], re.M)
        if classes and tag in classes.group(1).split():
            blocks.append((match["language"], match["body"]))
    return blocks


def _realdata_shared() -> Path | None:
    for parent in ROOT.parents:
        if (parent / "shared" / "realdata").is_dir():
            return parent / "shared"
    return None


TAGS = ("tested", "tested-realdata") if os.environ.get("RIG_REALDATA") == "1" else ("tested",)
PAGES_WITH_EXAMPLES = [(page, tag) for page in sorted(DOCS.rglob("*.md")) for tag in TAGS if _tested_blocks(page, tag)]


def test_the_tutorials_have_tested_examples() -> None:
    tested = {page.relative_to(DOCS).as_posix() for page, _ in PAGES_WITH_EXAMPLES}
    for page in ("tutorials/first_run.md", "tutorials/backlash_bounds.md", "tutorials/hammerstein.md",
                 "tutorials/model_discrepancy.md", "tutorials/endurance.md"):
        assert page in tested


@pytest.mark.parametrize(("page", "tag"), PAGES_WITH_EXAMPLES,
                         ids=[f"{page.relative_to(DOCS).as_posix()}:{tag}" for page, tag in PAGES_WITH_EXAMPLES])
def test_page_examples_run(page: Path, tag: str, tmp_path: Path) -> None:
    work = tmp_path / "work"
    work.mkdir()
    (work / "configs").symlink_to(ROOT / "configs")
    if tag == "tested-realdata":
        shared = _realdata_shared()
        assert shared is not None, "RIG_REALDATA=1 but no shared/realdata beside the checkout"
        (tmp_path / "shared").symlink_to(shared)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "rig"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m rig.cli "$@"\n')
    shim.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
           "MPLBACKEND": "Agg"}
    for number, (language, body) in enumerate(_tested_blocks(page, tag)):
        if language == "python":
            script = work / f"example_{number}.py"
            script.write_text(body)
            command = [sys.executable, str(script)]
        else:
            command = ["bash", "-euo", "pipefail", "-c", body]
        result = subprocess.run(command, cwd=work, env=env, capture_output=True, text=True, timeout=EXAMPLE_TIMEOUT_S)
        assert result.returncode == 0, (f"{page.relative_to(DOCS)} block {number} ({language}) exited "
                                        f"{result.returncode}:\n{body}\n--- stdout\n{result.stdout[-3000:]}\n"
                                        f"--- stderr\n{result.stderr[-3000:]}")
