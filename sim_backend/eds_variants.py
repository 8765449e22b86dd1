"""EDS files of the real variety, made from our own: without optional objects, with read-only (static) PDO
parameters, with other defaults.

A vendor's EDS lists only the objects its device has and marks what it does not let a master change; these
functions derive such files from ``configs/eds`` so that tests (the drivers' and the devices') can try the
variety without shipping a file per case::

    eds_without(DRIVE_EDS, [0x603F, 0x6098], tmp_path / "drive_minimal.eds")

The functions work on the EDS text (``configparser``, as canopen reads it), so what they write is exactly
what both canopen's master (``RemoteNode``) and our simulated devices (``LocalNode``) load.
"""

from __future__ import annotations

import configparser
import io
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

__all__ = [
    "PDO_PARAMETER_RANGES", "eds_text", "eds_with", "eds_without", "is_pdo_parameter", "load_eds_text",
    "static_pdo_access", "with_entries", "without_objects",
]

PDO_PARAMETER_RANGES = ((0x1400, 0x15FF), (0x1600, 0x17FF), (0x1800, 0x19FF), (0x1A00, 0x1BFF))
"""RPDO communication, RPDO mapping, TPDO communication, TPDO mapping parameters (CiA 301)."""

_OBJECT_LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")
_SECTION = re.compile(r"^([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]+)|Value|Name)?$")


def is_pdo_parameter(index: int) -> bool:
    """Whether ``index`` is a PDO communication or mapping parameter."""
    return any(low <= index <= high for low, high in PDO_PARAMETER_RANGES)


def _parse(text: str) -> configparser.RawConfigParser:
    parser = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    parser.optionxform = str  # EDS keys are case-sensitive for canopen
    parser.read_string(text)
    return parser


def _render(parser: configparser.RawConfigParser, header: str) -> str:
    out = io.StringIO()
    out.write(header)
    parser.write(out, space_around_delimiters=False)
    return out.getvalue()


def _header(text: str) -> str:
    lines = []
    for line in text.splitlines():
        if not line.startswith(";"):
            break
        lines.append(line)
    return "\n".join(lines) + "\n" if lines else ""


def _index_of(section: str) -> int | None:
    match = _SECTION.match(section)
    return int(match.group(1), 16) if match else None


def eds_text(path: str | Path) -> str:
    """The text of an EDS file."""
    return Path(path).read_text()


def load_eds_text(text: str, name: str = "variant.eds") -> io.StringIO:
    """A file-like object canopen's ``import_od`` (and so ``LocalNode``/``RemoteNode``) accepts: it needs a
    ``name`` ending in ``.eds``."""
    handle = io.StringIO(text)
    handle.name = name
    return handle


def without_objects(text: str, indices: Iterable[int]) -> str:
    """``text`` without the objects ``indices`` (all their sub-entries), and without them in the
    [MandatoryObjects]/[OptionalObjects]/[ManufacturerObjects] lists (renumbered)."""
    drop = {int(index) for index in indices}
    parser = _parse(text)
    for section in list(parser.sections()):
        if _index_of(section) in drop:
            parser.remove_section(section)
    for listing in _OBJECT_LISTS:
        if not parser.has_section(listing):
            continue
        count = int(parser.get(listing, "SupportedObjects", fallback="0"), 0)
        kept = [parser.get(listing, str(number)) for number in range(1, count + 1)
                if parser.has_option(listing, str(number))]
        kept = [entry for entry in kept if int(entry, 0) not in drop]
        for option in list(parser.options(listing)):
            parser.remove_option(listing, option)
        parser.set(listing, "SupportedObjects", str(len(kept)))
        for number, entry in enumerate(kept, start=1):
            parser.set(listing, str(number), entry)
    return _render(parser, _header(text))


def with_entries(text: str, *, access: Mapping[tuple[int, int], str] | None = None,
                 defaults: Mapping[tuple[int, int], int | str] | None = None) -> str:
    """``text`` with the ``AccessType`` of some entries changed (``{(index, subindex): "ro"}``) and some
    ``DefaultValue``\\ s (``{(index, subindex): value}``); subindex 0 of a plain variable is the object
    itself. Raises ``KeyError`` naming an entry the file does not have."""
    parser = _parse(text)
    for key, option, values in (("access", "AccessType", access or {}), ("default", "DefaultValue", defaults or {})):
        for (index, subindex), value in values.items():
            section = _section(parser, index, subindex)
            if section is None:
                raise KeyError(f"{key}: the EDS has no entry 0x{index:04X} sub {subindex}")
            if option == "DefaultValue" and isinstance(value, int):
                value = f"0x{value:X}" if value >= 0 else str(value)
            parser.set(section, option, str(value))
    return _render(parser, _header(text))


def static_pdo_access(text: str) -> dict[tuple[int, int], str]:
    """``{(index, subindex): "ro"}`` for every writable PDO parameter entry of ``text`` (a device whose PDO
    layout is fixed)."""
    parser = _parse(text)
    access = {}
    for section in parser.sections():
        match = _SECTION.match(section)
        if not match or match.group(2) is None or not is_pdo_parameter(int(match.group(1), 16)):
            continue
        if "w" in parser.get(section, "AccessType", fallback="").lower():
            access[(int(match.group(1), 16), int(match.group(2), 16))] = "ro"
    return access


def _section(parser: configparser.RawConfigParser, index: int, subindex: int) -> str | None:
    for name in (f"{index:04X}sub{subindex:X}", f"{index:04x}sub{subindex:x}", f"{index:04X}sub{subindex}"):
        if parser.has_section(name):
            return name
    if subindex == 0:
        for name in (f"{index:04X}", f"{index:04x}"):
            if parser.has_section(name) and not parser.has_option(name, "SubNumber"):
                return name
    return None


def eds_without(path: str | Path, indices: Iterable[int], out: str | Path) -> Path:
    """Write the EDS ``path`` without the objects ``indices`` to ``out`` (e.g. a vendor file that lacks
    the optional 0x1006, 0x603F, 0x6098, 0x6502 or 0x6501/0x6002); returns ``out``."""
    out = Path(out)
    out.write_text(without_objects(eds_text(path), indices))
    return out


def eds_with(path: str | Path, out: str | Path, *, access: Mapping[tuple[int, int], str] | None = None,
             defaults: Mapping[tuple[int, int], int | str] | None = None, static_pdos: bool = False) -> Path:
    """Write the EDS ``path`` to ``out`` with entries changed (:func:`with_entries`); ``static_pdos`` marks
    every PDO communication and mapping entry read-only. Returns ``out``."""
    text = eds_text(path)
    changes = dict(static_pdo_access(text)) if static_pdos else {}
    changes.update(access or {})
    out = Path(out)
    out.write_text(with_entries(text, access=changes, defaults=defaults))
    return out
