"""The simulated CANopen nodes' side of the bus (:class:`sim_backend.canopen_nodes.SimulatedCanOpenRig`): on
python-can's ``virtual`` bus, frames in one bus order, TPDOs stamped with their wire time, and every frame's
bits counted for the bus load (:class:`WireTimeBus`); on another interface (``udp_multicast``, the devices in a
process of their own), the same offer without the wire time (:class:`InterfaceBus`)."""

from __future__ import annotations

import threading
from collections.abc import Callable

import can
from can.interfaces.virtual import VirtualBus

from rig.protocols.can_bus_load import frame_bits
from sim_backend.virtual_bus_order import one_bus_order

__all__ = ["FrameCounter", "InterfaceBus", "WireTimeBus"]


class FrameCounter(can.Listener):
    """Counts the bits of every frame on the bus, received or sent by the simulated nodes (worst-case
    bit stuffing)."""

    def __init__(self, clock: Callable[[], float]) -> None:
        self.frames = 0
        self.bits = 0
        self.started = clock()
        self._lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:  # the notifier thread and the heartbeat threads both count
            self.frames += 1
            self.bits += frame_bits(msg.dlc, extended=msg.is_extended_id)


class WireTimeBus(VirtualBus):
    """python-can's virtual bus, but TPDOs can carry their wire time: the SYNC's timestamp plus the bits
    on the wire since, at the bus's bit rate, as a real bus with hardware timestamps would show them,
    however late the simulated device's thread got to answer."""

    def __init__(self, channel: str, counter: FrameCounter) -> None:
        one_bus_order()  # every node sees the frames in one order, as on a real bus
        super().__init__(channel=channel, receive_own_messages=False, preserve_timestamps=False)
        self._stamp_lock = threading.Lock()
        self.counter = counter

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        with self._stamp_lock:
            if self._is_shutdown:
                return  # a heartbeat timer racing the shutdown: a node off the bus sends nothing
            self.counter.on_message_received(msg)
            try:
                super().send(msg, timeout)
            except can.CanOperationError:
                if not self._is_shutdown:
                    raise

    def send_at(self, msg: can.Message, wire_time: float) -> None:
        with self._stamp_lock:
            if self._is_shutdown:
                return
            self.counter.on_message_received(msg)
            msg.timestamp = wire_time
            self.preserve_timestamps = True
            try:
                super().send(msg)
            finally:
                self.preserve_timestamps = False


class InterfaceBus:
    """A python-can bus on any interface (:func:`rig.protocols.can_interfaces.open_bus`) with what the simulated
    nodes ask of :class:`WireTimeBus`. ``send_at`` sends now: no interface carries a time stamp to the
    receiver, which stamps each frame on arrival. Every frame is counted once: as received where the interface
    hands a bus its own frames back (udp_multicast), else also as sent."""

    def __init__(self, bus: can.BusABC, counter: FrameCounter, *, echoes_own_frames: bool) -> None:
        self.bus = bus
        self.counter = counter
        self._counts_sent = not echoes_own_frames

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._counts_sent:
            self.counter.on_message_received(msg)
        self.bus.send(msg, timeout)

    def send_at(self, msg: can.Message, wire_time: float) -> None:
        self.send(msg)

    def __getattr__(self, name: str) -> object:
        return getattr(self.bus, name)  # recv, send_periodic, shutdown, fileno, channel_info: the bus's own
