"""The raw-CAN frame layout of the rig, described by ``configs/raw_can.dbc`` and coded with cantools.

The DBC file is the specification (open it in any CAN tool); this module only loads it and turns
``(message name, signal values)`` into python-can messages and back, for the host
(:mod:`rig.transports.raw_can`) and the simulated responder alike. Every message carries a 16-bit
sequence number ``seq``: the sample number for RIG_SETPOINT and its two answers, the request number for
RIG_CONTROL/RIG_STATUS_REQUEST and RIG_STATUS.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_DBC", "RawCanCodec"]

DEFAULT_DBC = Path(__file__).resolve().parents[2] / "configs" / "raw_can.dbc"
REQUIRED_MESSAGES = ("RIG_CONTROL", "RIG_STATUS_REQUEST", "RIG_SETPOINT", "RIG_STATUS", "RIG_FEEDBACK",
                     "RIG_DRIVE_FEEDBACK", "RIG_FAULT")


class RawCanCodec:
    """Encoder/decoder for the messages of a rig DBC file.

    Parameters
    ----------
    dbc_path
        The DBC file; it must define every message of :data:`REQUIRED_MESSAGES` (a rig may move them to
        other identifiers).
    """

    def __init__(self, dbc_path: str | Path = DEFAULT_DBC) -> None:
        import cantools

        self.path = Path(dbc_path)
        try:
            self.database = cantools.database.load_file(str(self.path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as err:
            raise ValueError(f"{self.path}: cannot read the DBC file: {err}") from err
        names = {message.name for message in self.database.messages}
        missing = [name for name in REQUIRED_MESSAGES if name not in names]
        if missing:
            raise ValueError(f"{self.path}: the DBC file lacks the messages {', '.join(missing)}")
        self._by_id = {message.frame_id: message for message in self.database.messages}
        self.frame_ids = {message.name: message.frame_id for message in self.database.messages}
        self.lengths = {message.name: message.length for message in self.database.messages}

    def encode(self, name: str, **signals: int) -> Any:
        """A python-can message ``name`` with ``signals``; ``seq`` is taken modulo 2**16."""
        import can

        message = self.database.get_message_by_name(name)
        if "seq" in signals:
            signals["seq"] &= 0xFFFF
        data = message.encode(signals, scaling=False, strict=True)
        return can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=message.is_extended_frame)

    def decode(self, msg: Any) -> tuple[str, dict[str, int]] | None:
        """``(message name, signals)``, or None for a frame that is not ours (other traffic on the bus).
        Raises ValueError for a frame of ours with a wrong length."""
        message = self._by_id.get(msg.arbitration_id)
        if message is None or msg.is_remote_frame:
            return None
        if len(msg.data) != message.length:
            raise ValueError(f"{message.name} (0x{message.frame_id:03X}) has {len(msg.data)} data bytes, "
                             f"expected {message.length}")
        return message.name, dict(message.decode(bytes(msg.data), decode_choices=False, scaling=False))
