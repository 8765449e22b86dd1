"""CAN error frames as python-can reports them (``Message.is_error_frame``), after the SocketCAN error
classes of ``linux/can/error.h``: the class bits are in the frame's identifier.

A bus-off controller sends and receives nothing more, so the transports stop the run; any other error
frame (protocol violation, controller warning, missing acknowledge, ...) is counted in ``frame_errors`` and
ridden through.
"""

from __future__ import annotations

from typing import Any

__all__ = ["CAN_ERR_BUSOFF", "ERROR_FRAME_FILTERS", "describe_error_frame", "is_bus_off", "is_rx_overflow"]

CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CRTL_RX_OVERFLOW = 0x01  # data[1] of a controller-problem error frame: the RX buffer overflowed

_CLASSES = ((CAN_ERR_TX_TIMEOUT, "TX timeout"), (CAN_ERR_LOSTARB, "lost arbitration"),
            (CAN_ERR_CRTL, "controller problem"), (CAN_ERR_PROT, "protocol violation"),
            (CAN_ERR_TRX, "transceiver status"), (CAN_ERR_ACK, "no acknowledge"), (CAN_ERR_BUSOFF, "bus off"),
            (CAN_ERR_BUSERROR, "bus error"), (CAN_ERR_RESTARTED, "controller restarted"))

ERROR_FRAME_FILTERS = [{"can_id": bit, "can_mask": 0x7FF, "extended": False} for bit, _ in _CLASSES
                       if bit != CAN_ERR_BUSERROR]
"""Receive filters that let the usual error frames through python-can's software filtering (the virtual
interface); SocketCAN delivers error frames by its separate error mask anyway. 0x080 (bus error) is left
out: it is the SYNC identifier, which a CANopen master passes already."""


def is_bus_off(message: Any) -> bool:
    """True for an error frame that reports bus-off."""
    return bool(message.is_error_frame and message.arbitration_id & CAN_ERR_BUSOFF)


def is_rx_overflow(message: Any) -> bool:
    """True for an error frame in which the CAN controller reports that its receive buffer overflowed
    (``CAN_ERR_CRTL`` with ``CAN_ERR_CRTL_RX_OVERFLOW`` in data[1]): frames on the bus were lost to the host."""
    data = bytes(message.data or b"")
    return bool(message.is_error_frame and message.arbitration_id & CAN_ERR_CRTL and len(data) > 1
                and data[1] & CAN_ERR_CRTL_RX_OVERFLOW)


def describe_error_frame(message: Any) -> str:
    """'bus off', 'protocol violation, no acknowledge', ... from the error class bits."""
    names = [name for bit, name in _CLASSES if message.arbitration_id & bit]
    return ", ".join(names) or f"error frame 0x{message.arbitration_id:03X}"
