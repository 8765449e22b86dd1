"""The serial rig protocol: COBS-framed binary messages with a CRC-16 and a sequence counter.

The full specification, written for firmware authors, is ``docs/serial_protocol.md``. In short, a frame
on the wire is::

    COBS( type:u8 | seq:u16 | body | crc:u16 ) 0x00

All integers little-endian. ``crc`` is CRC-16/CCITT-FALSE (polynomial 0x1021, initial value 0xFFFF, no
reflection, no final XOR; ``binascii.crc_hqx(data, 0xFFFF)``; check value 0x29B1 for ``b"123456789"``)
over ``type | seq | body``. COBS removes every zero byte from the frame, so 0x00 only ever delimits frames:
after garbage or a lost byte, the receiver resynchronises at the next 0x00 (:class:`FrameDecoder`).

Message types (host -> device below 0x80, device -> host from 0x80)::

    0x01 SETPOINT    seq = sample number   body: target_counts:i32 (drive position, drive counts)
    0x02 CONTROL     seq = request number  body: controlword:u16 (CiA 402)
    0x03 STATUS_REQUEST seq = request number  (no body)
    0x04 ERROR_REQUEST  seq = request number  (no body)
    0x81 FEEDBACK    seq = sample number   body: statusword:u16, actual_counts:i32, encoder_counts:u32
    0x82 STATUS      seq = request number  body: statusword:u16, actual_counts:i32   (seq 0: unprompted)
    0x83 FAULT       seq = 0               body: error_code:u16 (CiA 402 0x603F codes)
    0x84 ERROR       seq = request number  body: error_code:u16 (0x0000: no error)

Protocol v2 (the device owns the sample clock; a v1 device drops these types as unknown)::

    0x05 HELLO       seq = request number  body: version:u8 (the highest the host speaks, 2)
    0x06 START       seq = request number  (no body; answered by STATUS): the device's tick 0 is now
    0x85 DEVICE_INFO seq = request number  body: version:u8, buffer_capacity:u16, sample_period_ns:u32
    0x86 TICK        seq = tick number k   body: statusword:u16, actual_counts:i32, encoder_counts:u32,
                                                 applied_counts:i32, tick_flags:u8, buffer_level:u16

In v2, SETPOINT's seq is the device tick k it is for (queued in the device's buffer until tick k).

The encoder value is the position value in its low n+m bits: zero-extended to 32 bits for an unsigned
encoder, sign-extended (a 32-bit two's complement) for a signed one (decode with ``signed=True``).
Request numbers run 1..65535 (0 is never a request: it marks unprompted STATUS); a request whose answer
is lost is sent again with the same number, and the device answers a repeated number without applying
the request twice.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass
from enum import IntEnum

from rig.protocols.can_bus_load import BusLoad

__all__ = [
    "FrameDecoder", "FrameError", "MessageType", "PROTOCOL_VERSION", "SerialMessage", "TICK_HELD", "UART_BITS_PER_BYTE", "cobs_decode", "cobs_encode",
    "crc16", "decode_frame", "encode_frame", "frame_bytes_on_wire", "link_load", "unwrap_seq",
]

MAX_PAYLOAD = 64
UART_BITS_PER_BYTE = 10
"""8N1: a start bit, 8 data bits, a stop bit."""


class FrameError(ValueError):
    """A frame that cannot be decoded (bad COBS, bad CRC, unknown type, wrong length)."""


class MessageType(IntEnum):
    SETPOINT = 0x01
    CONTROL = 0x02
    STATUS_REQUEST = 0x03
    ERROR_REQUEST = 0x04
    HELLO = 0x05
    START = 0x06
    FEEDBACK = 0x81
    STATUS = 0x82
    FAULT = 0x83
    ERROR = 0x84
    DEVICE_INFO = 0x85
    TICK = 0x86


PROTOCOL_VERSION = 2
"""The highest protocol version this host speaks (``docs/serial_protocol.md``, section 16)."""
TICK_HELD = 0x01
"""TICK ``tick_flags`` bit 0: no setpoint for this tick was in the buffer; the device held the previous target."""


_BODY_FORMATS: dict[MessageType, struct.Struct] = {
    MessageType.SETPOINT: struct.Struct("<i"),
    MessageType.CONTROL: struct.Struct("<H"),
    MessageType.STATUS_REQUEST: struct.Struct("<"),
    MessageType.ERROR_REQUEST: struct.Struct("<"),
    MessageType.FEEDBACK: struct.Struct("<HiI"),
    MessageType.STATUS: struct.Struct("<Hi"),
    MessageType.FAULT: struct.Struct("<H"),
    MessageType.ERROR: struct.Struct("<H"),
    MessageType.HELLO: struct.Struct("<B"),
    MessageType.START: struct.Struct("<"),
    MessageType.DEVICE_INFO: struct.Struct("<BHI"),
    MessageType.TICK: struct.Struct("<HiIiBH"),
}
_HEADER = struct.Struct("<BH")
_CRC = struct.Struct("<H")


@dataclass(frozen=True)
class SerialMessage:
    """One decoded message: its type, its 16-bit sequence number and its body fields in order."""

    type: MessageType
    seq: int
    fields: tuple[int, ...]


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (``binascii.crc_hqx`` with initial value 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing (Cheshire and Baker 1999): the result contains no zero byte."""
    out = bytearray([0])
    code_index, code = 0, 1
    for byte in data:
        if byte:
            out.append(byte)
            code += 1
        if not byte or code == 0xFF:
            out[code_index] = code
            code_index, code = len(out), 1
            out.append(0)
    out[code_index] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`FrameError` on a malformed block."""
    out = bytearray()
    index = 0
    while index < len(data):
        code = data[index]
        end = index + code
        if code == 0 or end > len(data):
            raise FrameError(f"COBS block at byte {index} is malformed (code {code}, {len(data)} bytes)")
        block = data[index + 1:end]
        if 0 in block:
            raise FrameError(f"COBS block at byte {index} contains a zero byte")
        out += block
        index = end
        if code < 0xFF and index < len(data):
            out.append(0)
    return bytes(out)


def encode_frame(kind: MessageType, seq: int, *fields: int) -> bytes:
    """The bytes on the wire for one message, delimiter included."""
    payload = _HEADER.pack(int(kind), seq & 0xFFFF) + _BODY_FORMATS[kind].pack(*fields)
    return cobs_encode(payload + _CRC.pack(crc16(payload))) + b"\x00"


def decode_frame(encoded: bytes) -> SerialMessage:
    """Decode one frame without its 0x00 delimiter; raises :class:`FrameError` naming what is wrong."""
    raw = cobs_decode(encoded)
    if len(raw) < _HEADER.size + _CRC.size:
        raise FrameError(f"frame of {len(raw)} bytes is shorter than a header and a CRC")
    payload, (crc,) = raw[:-_CRC.size], _CRC.unpack(raw[-_CRC.size:])
    if crc16(payload) != crc:
        raise FrameError(f"CRC mismatch: frame says 0x{crc:04X}, payload gives 0x{crc16(payload):04X}")
    kind_value, seq = _HEADER.unpack(payload[:_HEADER.size])
    try:
        kind = MessageType(kind_value)
    except ValueError:
        raise FrameError(f"unknown message type 0x{kind_value:02X}") from None
    body = payload[_HEADER.size:]
    layout = _BODY_FORMATS[kind]
    if len(body) != layout.size:
        raise FrameError(f"{kind.name} body has {len(body)} bytes, expected {layout.size}")
    return SerialMessage(kind, seq, layout.unpack(body))


class FrameDecoder:
    """Split a byte stream into messages, resynchronising at the next 0x00 after any damage.

    ``feed(data)`` returns the messages completed by ``data``; damaged frames are counted in
    :attr:`errors` (with the last reason in :attr:`last_error`) and skipped.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.errors = 0
        self.last_error = ""

    def feed(self, data: bytes) -> list[SerialMessage]:
        self._buffer += data
        messages: list[SerialMessage] = []
        while True:
            end = self._buffer.find(0)
            if end < 0:
                if len(self._buffer) > 2 * MAX_PAYLOAD:  # no delimiter for too long: garbage
                    self.errors += 1
                    self.last_error = f"{len(self._buffer)} bytes without a frame delimiter"
                    self._buffer.clear()
                return messages
            chunk = bytes(self._buffer[:end])
            del self._buffer[:end + 1]
            if not chunk:
                continue  # consecutive delimiters (a sender may flush the line with a 0x00)
            try:
                messages.append(decode_frame(chunk))
            except FrameError as err:
                self.errors += 1
                self.last_error = str(err)
        return messages


def frame_bytes_on_wire(kind: MessageType) -> int:
    """Bytes one ``kind`` frame takes on the wire: COBS of header, body and CRC, plus the delimiter (COBS adds
    one code byte per 254 bytes of payload, so exactly one for every frame of this protocol)."""
    payload = _HEADER.size + _BODY_FORMATS[kind].size + _CRC.size
    return payload + 1 + payload // 254 + 1


def link_load(rate_hz: float, baudrate: int, bits_per_byte: int = UART_BITS_PER_BYTE) -> BusLoad:
    """Load of the per-sample exchange (one SETPOINT down, its FEEDBACK back) on a UART at ``baudrate``.

    Both frames of a sample cross the line one after the other within one sample period (the device
    answers a SETPOINT after its last byte arrived, and the FEEDBACK must be back before the next
    deadline), so their bits add up even though the line is full duplex: 11 + 17 bytes, 280 bit on 8N1.
    Returns a :class:`rig.protocols.can_bus_load.BusLoad` (``load`` > 1: the link cannot carry the rate).
    """
    if baudrate <= 0 or rate_hz <= 0:
        raise ValueError(f"baudrate and rate_hz must be > 0, got {baudrate} and {rate_hz}")
    bits = bits_per_byte * (frame_bytes_on_wire(MessageType.SETPOINT) + frame_bytes_on_wire(MessageType.FEEDBACK))
    return BusLoad(bits, int(baudrate), float(rate_hz), bits * rate_hz / baudrate, baudrate / bits)


def unwrap_seq(seq16: int, reference: int) -> int:
    """The integer sequence number nearest ``reference`` whose low 16 bits are ``seq16``."""
    return reference + ((seq16 - reference + 0x8000) & 0xFFFF) - 0x8000
