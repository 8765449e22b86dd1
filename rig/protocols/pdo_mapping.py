"""The PDO mapping of a CANopen network as a trace or a device configuration file shows it (CiA 301 7.4.8 and
7.5.2.35-38; CiA 306 for the files), so that a capture of another master's run can be decoded.

A master configures each PDO by SDO at start-up: it disables the PDO (bit 31 of its COB-ID, 0x1400-0x15FF or
0x1800-0x19FF sub 1), clears the mapping count (0x1600-0x17FF or 0x1A00-0x1BFF sub 0), writes the entries
(sub 1..n, each ``index << 16 | sub << 8 | bit length``), sets the count and enables the PDO again.
:func:`mapping_from_sdo_writes` replays the confirmed expedited SDO downloads of a trace (CiA 301 7.2.4.3.3: a
request the server answered with 0x60, not an abort) and :func:`mapping_from_dcf` reads a DCF or EDS
(``[1A00sub1] ParameterValue=0x60410010``, ``$NODEID`` allowed). A PDO never given a COB-ID has the pre-defined
connection set's (CiA 301 7.3.5: RPDO n at 0x200 + 0x100 (n - 1) + node-ID, TPDO n at 0x180 + 0x100 (n - 1) +
node-ID, n = 1..4).
"""

from __future__ import annotations

import configparser
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

__all__ = ["MappedObject", "Pdo", "PdoMapping", "mapping_from_dcf", "mapping_from_sdo_writes"]

_COB_INVALID = 1 << 31
_RPDO_COMM, _RPDO_MAP, _TPDO_COMM, _TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00


@dataclass(frozen=True)
class MappedObject:
    """One mapping entry: object ``index``:``subindex`` in ``bits`` bits."""

    index: int
    subindex: int
    bits: int

    @classmethod
    def from_entry(cls, entry: int) -> MappedObject:
        return cls((entry >> 16) & 0xFFFF, (entry >> 8) & 0xFF, entry & 0xFF)

    def __str__(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X} ({self.bits} bit)"


@dataclass(frozen=True)
class Pdo:
    """A PDO of node ``node_id``: ``receive`` (RPDO: the node receives it) or a TPDO, number ``number`` (1-512),
    its COB-ID and its mapped objects in frame order."""

    node_id: int
    receive: bool
    number: int
    cob_id: int
    objects: tuple[MappedObject, ...]

    def decode(self, data: bytes) -> dict[tuple[int, int], int] | None:
        """The raw (unsigned) value of each mapped object, by ``(index, subindex)``; None when the frame is
        shorter than the mapping."""
        value = int.from_bytes(bytes(data), "little")
        if 8 * len(data) < sum(entry.bits for entry in self.objects):
            return None
        out: dict[tuple[int, int], int] = {}
        offset = 0
        for entry in self.objects:
            out[(entry.index, entry.subindex)] = (value >> offset) & ((1 << entry.bits) - 1)
            offset += entry.bits
        return out

    @property
    def name(self) -> str:
        return f"node {self.node_id} {'RPDO' if self.receive else 'TPDO'}{self.number} (COB-ID 0x{self.cob_id:03X})"


@dataclass(frozen=True)
class PdoMapping:
    """The valid PDOs of a network, by COB-ID; ``source`` says where the mapping came from; ``configured``: every
    ``(node-ID, receive, number)`` whose parameters it wrote, the PDOs it disabled included."""

    pdos: Mapping[int, Pdo]
    source: str
    configured: frozenset[tuple[int, bool, int]] = frozenset()

    def carrying(self, node_id: int, index: int, subindex: int = 0, *, receive: bool) -> Pdo | None:
        """The PDO of ``node_id`` in that direction that maps ``index``:``subindex``: one that was configured
        (:attr:`configured`) before one assumed, then the lowest-numbered."""
        found = [pdo for pdo in self.pdos.values() if pdo.node_id == node_id and pdo.receive == receive
                 and any((entry.index, entry.subindex) == (index, subindex) for entry in pdo.objects)]
        return min(found, key=lambda pdo: ((pdo.node_id, pdo.receive, pdo.number) not in self.configured,
                                           pdo.number)) if found else None


class _Builder:
    """Communication and mapping parameters per (node, PDO) as they are written, then the valid PDOs."""

    def __init__(self) -> None:
        self.cob_ids: dict[tuple[int, bool, int], int] = {}
        self.counts: dict[tuple[int, bool, int], int] = {}
        self.entries: dict[tuple[int, bool, int], dict[int, int]] = {}

    def write(self, node_id: int, index: int, subindex: int, value: int) -> None:
        for base_comm, base_map, receive in ((_RPDO_COMM, _RPDO_MAP, True), (_TPDO_COMM, _TPDO_MAP, False)):
            if base_comm <= index < base_comm + 0x200 and subindex == 1:
                self.cob_ids[(node_id, receive, index - base_comm + 1)] = value
            elif base_map <= index < base_map + 0x200:
                key = (node_id, receive, index - base_map + 1)
                if subindex == 0:
                    self.counts[key] = value
                else:
                    self.entries.setdefault(key, {})[subindex] = value

    def mapping(self, source: str) -> PdoMapping:
        pdos: dict[int, Pdo] = {}
        for key, count in self.counts.items():
            node_id, receive, number = key
            cob_id = self.cob_ids.get(key)
            if cob_id is None:
                if number > 4:
                    continue  # no pre-defined COB-ID beyond the fourth PDO
                cob_id = (0x200 if receive else 0x180) + 0x100 * (number - 1) + node_id
            if cob_id & _COB_INVALID or count == 0:
                continue
            entries = self.entries.get(key, {})
            objects = tuple(MappedObject.from_entry(entries[sub]) for sub in range(1, count + 1) if sub in entries)
            if len(objects) != count:
                continue  # a count written without its entries: not a usable mapping
            pdos[cob_id & 0x7FF] = Pdo(node_id, receive, number, cob_id & 0x7FF, objects)
        return PdoMapping(pdos, source, frozenset({*self.cob_ids, *self.counts, *self.entries}))


def _expedited_download(data: bytes) -> tuple[int, int, int] | None:
    """(index, subindex, value) of an expedited SDO download request (CiA 301 7.2.4.3.3), else None."""
    if len(data) != 8 or data[0] & 0xE2 != 0x22:
        return None
    size = 4 - ((data[0] >> 2) & 3) if data[0] & 0x01 else 4
    return int.from_bytes(data[1:3], "little"), data[3], int.from_bytes(data[4:4 + size], "little")


def mapping_from_sdo_writes(frames: Iterable[tuple[int, bytes]], source: str) -> PdoMapping | None:
    """The PDO mapping the confirmed expedited SDO downloads among ``frames`` (``(COB-ID, data)`` in bus
    order) set up; None when they set up no PDO. A write counts once its server answered it (0x60 with the
    same index and sub-index, on 0x580 + node-ID); an abort (0x80) leaves the object as it was."""
    builder = _Builder()
    pending: dict[int, tuple[int, int, int]] = {}
    for cob_id, data in frames:
        if 0x601 <= cob_id <= 0x67F:
            request = _expedited_download(bytes(data))
            if request is not None:
                pending[cob_id - 0x600] = request
        elif 0x581 <= cob_id <= 0x5FF and len(data) == 8:
            node_id = cob_id - 0x580
            request = pending.pop(node_id, None)
            if request is not None and data[0] == 0x60 and (int.from_bytes(data[1:3], "little"), data[3]) == request[:2]:
                builder.write(node_id, *request)
    mapping = builder.mapping(source)
    return mapping if mapping.pdos else None


_SECTION = re.compile(r"^(?P<index>[0-9A-Fa-f]{4})(?:sub(?P<sub>[0-9A-Fa-f]+))?$")


def _value(text: str, node_id: int) -> int:
    text = text.strip().replace("$NODEID", str(node_id)).replace("$nodeid", str(node_id))
    return sum(int(term, 0) for term in text.split("+"))


def mapping_from_dcf(files: Mapping[int, str | Path]) -> PdoMapping:
    """The PDO mapping the DCF (or EDS) of each node gives (CiA 306: ``[1A00sub1]`` with ``ParameterValue``,
    else ``DefaultValue``; ``$NODEID`` replaced by the node's ID), ``files`` by node-ID. Raises ``ValueError``
    naming the file that cannot be read or maps no PDO."""
    builder = _Builder()
    for node_id, path in files.items():
        parser = configparser.ConfigParser(strict=False, interpolation=None)
        parser.optionxform = str  # type: ignore[assignment, method-assign]
        try:
            with open(path, encoding="utf-8", errors="replace") as handle:
                parser.read_file(handle)
        except (OSError, configparser.Error) as err:
            raise ValueError(f"{path}: not a readable DCF/EDS file ({err})") from None
        mapped = False
        for section in parser.sections():
            match = _SECTION.match(section)
            if match is None:
                continue
            index, sub = int(match["index"], 16), int(match["sub"] or "0", 16)
            if not _RPDO_COMM <= index < _TPDO_MAP + 0x200:
                continue
            text = parser[section].get("ParameterValue") or parser[section].get("DefaultValue")
            if not text:
                continue
            try:
                builder.write(node_id, index, sub, _value(text, node_id))
            except ValueError:
                raise ValueError(f"{path}: [{section}] value {text!r} is not a number") from None
            mapped = mapped or index >= _RPDO_MAP and (index < _TPDO_COMM or index >= _TPDO_MAP)
        if not mapped:
            raise ValueError(f"{path}: maps no PDO of node {node_id} (no [1600sub0]..[1BFFsub0] sections): give "
                             "the DCF the configuration tool wrote for that node")
    return builder.mapping(", ".join(f"node {node}: {path}" for node, path in files.items()))
