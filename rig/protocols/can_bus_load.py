"""CAN bus load: how many bits a cycle of frames takes, and which sample rate a bus can carry.

A classical CAN data frame with an 11-bit identifier and n data bytes has 47 + 8n bits, of which the
34 + 8n bits from the start of frame to the end of the CRC are subject to bit stuffing (one stuff bit
after five equal bits, so at most (34 + 8n - 1) / 4 of them in the worst case); three bits of
interframe space follow (Davis, Burns, Bril, Lukkien 2007, "Controller Area Network (CAN) schedulability
analysis: refuted, revisited and revised", eq. (1)). An extended (29-bit) identifier adds 20 bits, 18 of
them stuffable.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["BusLoad", "bus_load", "frame_bits"]

INTERFRAME_BITS = 3


def frame_bits(data_bytes: int, *, extended: bool = False, worst_case_stuffing: bool = True) -> int:
    """Bits on the wire for one data frame with ``data_bytes`` bytes (interframe space included)."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"data_bytes: expected 0..8 for classical CAN, got {data_bytes}")
    stuffable = (54 if extended else 34) + 8 * data_bytes
    fixed = (67 if extended else 47) + 8 * data_bytes
    stuff = (stuffable - 1) // 4 if worst_case_stuffing else 0
    return fixed + stuff + INTERFRAME_BITS


@dataclass(frozen=True)
class BusLoad:
    """Load of a cyclic frame set on a bus.

    Attributes
    ----------
    bits_per_cycle
        Sum of :func:`frame_bits` over the frames of one cycle.
    load
        Fraction of the bit rate used at ``rate_hz`` (1.0 = the bus is full).
    max_rate_hz
        The highest cycle rate the bus can carry with these frames.
    """

    bits_per_cycle: int
    bitrate: int
    rate_hz: float
    load: float
    max_rate_hz: float


def bus_load(frame_data_bytes: Sequence[int], rate_hz: float, bitrate: int) -> BusLoad:
    """Load of one frame per entry of ``frame_data_bytes`` sent each cycle at ``rate_hz`` on a
    ``bitrate`` bit/s bus (worst-case bit stuffing)."""
    if bitrate <= 0 or rate_hz <= 0:
        raise ValueError(f"bitrate and rate_hz must be > 0, got {bitrate} and {rate_hz}")
    bits = sum(frame_bits(n) for n in frame_data_bytes)
    return BusLoad(bits, int(bitrate), float(rate_hz), bits * rate_hz / bitrate, bitrate / bits)
