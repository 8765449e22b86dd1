"""Reference pages generated from the code, so that they cannot drift from it.

Directives (usable from MyST Markdown as ```` ```{rig-cli} ```` fences):

``rig-cli``
    The whole ``rig`` command line, walked from :func:`rig.cli.build_parser`: one section per command and
    subcommand with its usage, description and every argument with its help text (argparse's own
    ``%(default)s`` expansion). Each section carries the label ``cli-rig-COMMAND`` (``cli-rig-identify-hammerstein``)
    for ``{ref}`` links.
``rig-transport-options SCHEME``
    The ``[transport]`` keys a rig config accepts for ``canopen``, ``can`` or ``serial``: the keyword
    parameters of the transport class that the config loader passes on, each with its default and the
    description from the class's numpy-style "Parameters" section.
``rig-effects``
    The catalogue of effects that ``rig diagnose`` tries (:data:`identify.effect_catalogue.EFFECTS`).
``rig-module-doc MODULE``
    A module's docstring, where the config formats are written down next to the code that reads them.
``rig-block-types``
    The ``type`` values of a plant TOML's ``[[blocks]]`` (:data:`sim_backend.plant_config.BLOCK_TYPES`) and the
    keys of a ``drive_train`` block.
"""

from __future__ import annotations

import argparse
import inspect
import re
from pathlib import Path
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]

# Options of a transport class that a rig config does not set as [transport] keys: the URL gives the interface,
# channel and port; the loader passes the other tables' values and the clock.
NOT_CONFIG_KEYS = frozenset({"self", "encoder", "sample_period_s", "limits", "drive", "timing", "name", "clock",
                             "interface", "channel", "port"})


def _paragraphs(text: str) -> list[nodes.Node]:
    """argparse description text as docutils nodes: blocks with indented lines stay preformatted."""
    out: list[nodes.Node] = []
    for block in re.split(r"\n\s*\n", text.strip("\n")):
        lines = block.splitlines()
        if any(line.startswith(" ") for line in lines[1:]) or any(line.startswith("  ") for line in lines):
            out.append(nodes.literal_block(block, block, language="text"))
        else:
            out.append(nodes.paragraph(text=" ".join(line.strip() for line in lines)))
    return out


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """(name, one-line help, parser) of each subcommand, in the order they were added."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
            for name, sub in action.choices.items():
                found.append((name, helps.get(name, ""), sub))
    return found


def _argument_list(parser: argparse.ArgumentParser) -> nodes.definition_list:
    formatter = parser._get_formatter()
    items = nodes.definition_list()
    for action in parser._actions:
        if isinstance(action, (argparse._SubParsersAction, argparse._HelpAction)) or action.help == argparse.SUPPRESS:
            continue
        if action.option_strings:
            metavar = "" if action.nargs == 0 else " " + formatter._format_args(action, action.dest.upper())
            term = ", ".join(f"{option}{metavar}" for option in action.option_strings)
        else:
            term = formatter._format_args(action, action.dest)
        help_text = formatter._expand_help(action) if action.help else ""
        if action.required and action.option_strings:
            help_text += " (required)"
        item = nodes.definition_list_item()
        item += nodes.term("", "", nodes.literal(term, term))
        definition = nodes.definition()
        definition += nodes.paragraph(text=help_text)
        item += definition
        items += item
    return items


class RigCliDirective(SphinxDirective):
    """``rig-cli``: the command line reference, generated from the parser."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from rig.cli import build_parser

        parser = build_parser()
        return self._command_sections(parser, ["rig"], "")

    def _section(self, words: list[str], summary: str, parser: argparse.ArgumentParser) -> nodes.section:
        label = "cli-" + "-".join(words)
        section = nodes.section(ids=[label], names=[label])
        self.state.document.note_explicit_target(section)
        title = " ".join(words)
        section += nodes.title("", "", nodes.literal(title, title))
        if summary:
            section += nodes.paragraph(text=summary[0].upper() + summary[1:] + ".")
        usage = parser.format_usage().strip()
        section += nodes.literal_block(usage, usage, language="text")
        if parser.description:
            section.extend(_paragraphs(parser.description))
        arguments = _argument_list(parser)
        if len(arguments):
            section += arguments
        return section

    def _command_sections(self, parser: argparse.ArgumentParser, words: list[str], summary: str) -> list[nodes.Node]:
        section = self._section(words, summary, parser)
        subcommands = _subparsers(parser)
        if subcommands:
            listing = nodes.bullet_list()
            for name, help_text, _ in subcommands:
                target = "cli-" + "-".join([*words, name])
                reference = nodes.reference("", "", nodes.literal(f"{' '.join(words)} {name}", f"{' '.join(words)} {name}"),
                                            refid=target)
                paragraph = nodes.paragraph("", "", reference, nodes.Text(f": {help_text}"))
                listing += nodes.list_item("", paragraph)
            section += listing
        if parser.epilog:
            section += nodes.literal_block(parser.epilog.strip(), parser.epilog.strip(), language="text")
        nested: list[nodes.Node] = [section]
        for name, help_text, sub in subcommands:
            nested.extend(self._command_sections(sub, [*words, name], help_text))
        if len(words) == 1:  # top level: the commands as siblings of the overview, each a section of the page
            return nested
        section.extend(nested[1:])
        return [section]


def _numpy_parameters(cls: type) -> dict[str, str]:
    """Parameter name -> description from the "Parameters" section of each class in the MRO's docstring."""
    found: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        doc = inspect.cleandoc(vars(klass).get("__doc__") or "")
        match = re.search(r"^Parameters\n-+\n(.*?)(?:\n\n[A-Z][A-Za-z ]+\n-+\n|\Z)", doc, re.S | re.M)
        if not match:
            continue
        names: list[str] = []
        lines: list[str] = []
        for line in match.group(1).splitlines() + [""]:
            if line and not line.startswith(" "):
                for name in names:
                    found[name] = " ".join(lines).strip()
                names = [part.strip() for part in line.split(",")]
                lines = []
            elif line.strip():
                lines.append(line.strip())
        for name in names:
            found[name] = " ".join(lines).strip()
    return found


def _default_text(value: Any) -> str:
    if value is None:
        return "(none)"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        path = Path(value)
        if path.is_absolute() and ROOT in path.parents:
            value = str(path.relative_to(ROOT))
        return f'"{value}"'
    return repr(value)


def _table(header: list[str], rows: list[list[str]], widths: list[int]) -> list[str]:
    """An RST list-table (cells are parsed as RST)."""
    lines = [".. list-table::", "   :header-rows: 1", f"   :widths: {' '.join(map(str, widths))}", ""]
    for row in [header, *rows]:
        for index, cell in enumerate(row):
            lead = "   * - " if index == 0 else "     - "
            lines.append(lead + (cell if cell.strip() else "\\ "))
    return lines


class _RstDirective(SphinxDirective):
    """A directive whose output is written as reStructuredText (list tables, roles of the docstrings)."""

    def _parse(self, lines: list[str]) -> list[nodes.Node]:
        if type(self.state).__module__.startswith("myst_parser"):  # in a Markdown page: parse it as RST there
            lines = ["````{eval-rst}", *lines, "````"]
        container = nodes.container()
        self.state.nested_parse(StringList(lines, source=f"<{self.name}>"), self.content_offset, container)
        return list(container.children)


class TransportOptionsDirective(_RstDirective):
    """``rig-transport-options SCHEME``: the [transport] keys of a rig config for one transport."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        from rig.rig_config import _option_defaults
        from rig.transports import _accepted_options, transport_class

        cls = transport_class(self.arguments[0])
        descriptions = _numpy_parameters(cls)
        defaults = _option_defaults(cls)
        rows = []
        for key in sorted(_accepted_options(cls) - NOT_CONFIG_KEYS):
            rows.append([f"``{key}``", f"``{_default_text(defaults.get(key))}``",
                         descriptions.get(key, "").replace("\n", " ") or "(not described)"])
        return self._parse(_table(["key", "default", "meaning"], rows, [20, 20, 60]))


class EffectsDirective(_RstDirective):
    """``rig-effects``: the effect catalogue."""

    def run(self) -> list[nodes.Node]:
        from identify.effect_catalogue import EFFECTS

        rows = []
        for name, effect in EFFECTS.items():
            keys = ", ".join(f"``{key.key}``" for key in effect.toml_keys)
            reported = ", ".join(f"``{parameter.name}`` ({parameter.unit})" for parameter in effect.parameters)
            signature = effect.signature.replace("*", r"\*").replace("|", r"\|").replace("_", r"\_")
            rows.append([f"``{name}``", effect.placement, f"``{effect.toml_type}``: {keys}", reported, signature])
        return self._parse(_table(["name", "placement", "plant TOML", "reported parameters", "signature in the residual"],
                                  rows, [12, 9, 24, 22, 33]))


class BlockTypesDirective(_RstDirective):
    """``rig-block-types``: the plant TOML block types and the drive train's keys."""

    def run(self) -> list[nodes.Node]:
        from sim_backend.plant_config import BLOCK_TYPES, DRIVE_TRAIN_KEYS

        rows = [[f"``{kind}``", f"``{cls.__module__}.{cls.__qualname__}``"] for kind, (cls, _) in BLOCK_TYPES.items()]
        lines = _table(["type", "block class"], rows, [30, 70])
        lines += ["", "Keys of a ``drive_train`` block: " + ", ".join(f"``{key}``" for key in DRIVE_TRAIN_KEYS) + "."]
        return self._parse(lines)


_LITERAL_SPAN = re.compile(r"(``.+?``)")


def _escape_bars(line: str) -> str:
    """``|x|`` outside inline literals as plain bars: the docstrings write absolute values and norms so, and use
    no RST substitutions."""
    parts = _LITERAL_SPAN.split(line)
    return "".join(part if index % 2 else part.replace("|", "\\|") for index, part in enumerate(parts))


def plain_bars_in_docstrings(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """autodoc-process-docstring: escape ``|`` in prose, leaving literal blocks (after ``::``) and doctests alone."""
    literal_indent: int | None = None
    for index, line in enumerate(lines):
        stripped = line.strip()
        indent = len(line) - len(line.lstrip())
        if literal_indent is not None:
            if not stripped or indent > literal_indent:
                continue
            literal_indent = None
        if stripped.endswith("::"):
            literal_indent = indent
        if stripped.startswith(">>>") or stripped.startswith("..."):
            continue
        lines[index] = _escape_bars(line)


class ModuleDocDirective(_RstDirective):
    """``rig-module-doc MODULE``: a module's docstring (the config formats live there), parsed as RST."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        import importlib

        lines = inspect.getdoc(importlib.import_module(self.arguments[0])).splitlines()
        plain_bars_in_docstrings(self.env.app, "module", self.arguments[0], None, None, lines)
        return self._parse(lines)


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("rig-module-doc", ModuleDocDirective)
    app.connect("autodoc-process-docstring", plain_bars_in_docstrings)
    app.add_directive("rig-cli", RigCliDirective)
    app.add_directive("rig-transport-options", TransportOptionsDirective)
    app.add_directive("rig-effects", EffectsDirective)
    app.add_directive("rig-block-types", BlockTypesDirective)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
