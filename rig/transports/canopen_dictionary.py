"""What the CANopen master knows of a device's object dictionary: the EDS it loads and checks for the objects
it needs, the layout of a PDO as the device reports it (CiA 301 0x1600/0x1A00), the form of a period in CiA
402's 0x60C2, and the EMCY codes a run rides through."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.protocols.errors import ConfigError

__all__ = ["ASYNCHRONOUS_RPDO", "DRIVE_OBJECTS", "ENCODER_OBJECTS", "IP_BUFFER_OBJECTS", "PdoLayout", "emcy_prefixes",
           "interpolation_time_period", "is_warning", "load_object_dictionary", "require_objects"]


ASYNCHRONOUS_RPDO = 255
"""RPDO transmission type for interpolation records: event-driven, applied on arrival (CiA 301 7.2.2.2), so
that every record sent reaches the drive's buffer; a synchronous RPDO (0..240) keeps only the last frame
received before a SYNC."""


@dataclass(frozen=True)
class PdoLayout:
    """Where each mapped object sits in one PDO's data, as the device's mapping parameter says
    (CiA 301 0x1600/0x1A00: entries of index, sub-index and length in bits, packed in order).

    Attributes
    ----------
    where
        The PDO in messages ("TPDO1 of drive 1 (0x1800/0x1A00)").
    cob_id
        Its COB-ID as read back.
    fields
        Object index -> (byte offset, byte length).
    length
        Data bytes of the PDO.
    """

    where: str
    cob_id: int
    fields: dict[int, tuple[int, int]]
    length: int

    @classmethod
    def from_pdo(cls, pdo: Any, where: str) -> PdoLayout:
        fields: dict[int, tuple[int, int]] = {}
        offset = 0
        for variable in pdo:
            size = variable.length // 8
            fields.setdefault(variable.index, (offset, size))
            offset += size
        return cls(where, int(pdo.cob_id), fields, offset)

    def describe(self) -> str:
        return ", ".join(f"0x{index:04X} ({8 * size} bit)" for index, (_, size) in self.fields.items()) or "nothing"

    def value(self, data: bytes, index: int, signed: bool = False) -> int:
        """The value of object ``index`` in ``data``; ValueError if the frame is shorter than the mapping."""
        offset, size = self.fields[index]
        if len(data) < offset + size:
            raise ValueError(f"{self.where}: {len(data)} bytes, the mapping needs {offset + size}")
        return int.from_bytes(data[offset:offset + size], "little", signed=signed)

    def pack(self, values: dict[int, int]) -> bytes:
        """The PDO's data with ``values`` (index -> integer, two's complement where negative)."""
        data = bytearray(self.length)
        for index, (offset, size) in self.fields.items():
            data[offset:offset + size] = (values[index] & ((1 << 8 * size) - 1)).to_bytes(size, "little")
        return bytes(data)


DRIVE_OBJECTS = (
    (0x1017, "the producer heartbeat time the master sets and watches"),
    (0x1400, "RPDO1 communication parameter (the target's PDO)"), (0x1600, "RPDO1 mapping"),
    (0x1800, "TPDO1 communication parameter (statusword and actual position)"), (0x1A00, "TPDO1 mapping"),
    (0x6040, "the controlword"), (0x6041, "the statusword"), (0x6060, "modes of operation"),
    (0x6061, "modes of operation display (the mode handshake)"), (0x6064, "position actual value"),
    (0x607A, "target position"),
)
IP_BUFFER_OBJECTS = (
    (0x60C1, "the interpolation data records (mode = \"ip_buffer\")"),
    (0x60C4, "the interpolation buffer's size and its clear/enable (mode = \"ip_buffer\")"),
)
ENCODER_OBJECTS = (
    (0x1017, "the producer heartbeat time the master sets and watches"),
    (0x1800, "TPDO1 communication parameter (the position value's PDO)"), (0x1A00, "TPDO1 mapping"),
    (0x6004, "position value"),
)


def interpolation_time_period(period_s: float, largest_value: int) -> tuple[int, int] | None:
    """``period_s`` as CiA 402's 0x60C2 holds it: (value, index) with value x 10^index s equal to the period
    (to 1 ppm) and 1 <= value <= ``largest_value`` (255 for the standard's UNSIGNED8 sub 1), the smallest
    value that does; None where none does (a period of 1/3 ms).

    >>> interpolation_time_period(1e-3, 255), interpolation_time_period(250e-6, 255), interpolation_time_period(1 / 3000, 255)
    ((1, -3), (25, -5), None)
    """
    for index in range(3, -10, -1):
        value = period_s / 10.0 ** index
        whole = round(value)
        if 1 <= whole <= largest_value and abs(value - whole) <= 1e-6 * value:
            return whole, index
    return None


def load_object_dictionary(key: str, path: str, node_id: int) -> Any:
    import canopen

    if not Path(path).is_file():
        raise ConfigError("<transport>", key, f"no such EDS file {path}")
    try:
        return canopen.import_od(path, node_id)
    except Exception as err:  # noqa: BLE001 - canopen raises whatever its parsers raise
        raise ConfigError("<transport>", key, f"{path} is not a readable EDS/DCF file: {err}") from err


def require_objects(key: str, path: str, od: Any, objects: tuple[tuple[int, str], ...]) -> None:
    """Refuse an EDS that lacks an object the master needs, naming it and what it is needed for."""
    for index, purpose in objects:
        if index not in od:
            raise ConfigError("<transport>", key, (
                f"{path} has no object 0x{index:04X}; the master needs it for {purpose}; use the vendor's EDS "
                "of this device (a device without it cannot be driven by this master)"))


def emcy_prefixes(text: str) -> tuple[str, ...]:
    """``"0x4, 0x8130"`` -> ("4", "8130"): hex prefixes an EMCY code's four hex digits are matched against."""
    prefixes = []
    for item in str(text).split(","):
        item = item.strip().lower()
        if not item:
            continue
        digits = item[2:] if item.startswith("0x") else item
        if not (1 <= len(digits) <= 4 and all(char in "0123456789abcdef" for char in digits)):
            raise ConfigError("<transport>", "emcy_warning_codes", (
                f"{item!r} is not a hex EMCY code or prefix (expected e.g. \"0x4\" or \"0x4210, 0xFF\")"))
        prefixes.append(digits)
    return tuple(prefixes)


def is_warning(code: int, prefixes: tuple[str, ...]) -> bool:
    digits = f"{code:04x}"
    return any(digits.startswith(prefix) for prefix in prefixes)
