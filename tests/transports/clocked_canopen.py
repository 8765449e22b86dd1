"""The real CANopen master (:class:`rig.transports.canopen_link.CanOpenTransport`, its canopen network) and
the simulated CiA 402 drive and CiA 406 encoder (:class:`sim_backend.canopen_nodes.SimulatedCanOpenRig`, real
``canopen.LocalNode`` objects) on one scripted CAN bus and one simulated clock: no notifier thread, no
cyclic-send thread, no sleep, so a test of the master's timing depends on nothing but the code.

The rules, those of :mod:`clocked_line` for a bus:

* A frame goes on the bus at the clock's present time (stamped with it; a TPDO with the wire time the
  drive computed) and reaches every other node, and the sender itself where it receives its own frames
  (the master: ``receive_own_messages``, its SYNC and RPDO echoes), in bus order: each frame reaches all
  nodes before the next one does, so the frames a node sends in answer to a SYNC follow that SYNC.
* Time passes only while the host waits (:meth:`ClockedCanBus.wait_for`, the master's ``_wait_for`` and
  ``_pause``) or stalls (:meth:`ClockedCanBus.stall`): the clock moves event by event (a SYNC or heartbeat
  of a cyclic task, a tick of the drive's clock, a delayed TPDO) and the nodes do what falls due. The
  master's own computing and an SDO exchange take no time.
* The SYNC producer is the master's own: ``send_periodic`` on this bus gives a cyclic task on the simulated
  clock (SYNC k exactly at ``t_0 + k T``), as SocketCAN's broadcast manager would; so do the nodes'
  heartbeats (canopen's ``PeriodicMessageTask``).
* A frame the master sends while it holds its lock (a target put on the bus from the runner's thread)
  reaches the bus when the lock is released, at the same instant: the receive thread would wait for that
  lock too.
* :meth:`ClockedCanBus.drop_from_master` deletes chosen frames from the master's receive stream only (an
  RX overrun of its receive queue: the frame was on the bus and every other node got it), and
  ``master_drops`` counts them, as an interface's drop counter would.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable
from typing import Any

import can

from clocked_line import SimulatedClock


class _CyclicTask:
    """A cyclic frame on the simulated clock: the first at once, then exactly every ``period_s``
    (python-can's ``CyclicSendTaskABC`` interface: ``stop``, ``modify_data``)."""

    def __init__(self, bus: ClockedCanBus, sender: ClockedCanEndpoint, message: can.Message, period_s: float) -> None:
        self.bus, self.sender, self.message, self.period_s = bus, sender, message, float(period_s)
        self.start_s, self.sent = bus.clock(), 0

    @property
    def next_due_s(self) -> float:
        return self.start_s + self.sent * self.period_s

    def fire(self) -> None:
        self.sent += 1
        self.bus.send(self.sender, self.message)

    def modify_data(self, message: can.Message) -> None:
        self.message = message

    def stop(self) -> None:
        self.bus.stop_task(self)


class ClockedCanEndpoint:
    """One node's connection to a :class:`ClockedCanBus`: the python-can bus a ``canopen.Network`` sends
    through, and the notifier that feeds it (:meth:`join`)."""

    channel_info = "clocked CAN bus"

    def __init__(self, bus: ClockedCanBus, receive_own_messages: bool) -> None:
        self.bus, self.receive_own_messages = bus, receive_own_messages
        self.network: Any = None
        self.listeners: list[Any] = []  # added by add_listener: they see every frame, the node's own too
        self.exception = None  # (python-can Notifier interface)
        self.filters: list[dict[str, int]] | None = None
        self.drops: Callable[[can.Message, bool], bool] | None = None  # (frame, own) -> lost on receive
        self.dropped = 0
        self.backlog: collections.deque[tuple[can.Message, bool]] | None = None  # receive side starved: queued

    # -- as a python-can bus -----------------------------------------------------------------------------
    def send(self, message: can.Message, timeout: float | None = None) -> None:
        self.bus.send(self, message)

    def send_at(self, message: can.Message, wire_time: float) -> None:
        self.bus.send(self, message, timestamp=wire_time)

    def send_periodic(self, message: can.Message, period: float, *args: Any, **kwargs: Any) -> _CyclicTask:
        return self.bus.start_task(self, message, period)

    def set_filters(self, filters: list[dict[str, int]] | None = None) -> None:
        self.filters = filters  # kept for inspection; the network ignores what it does not subscribe to

    def shutdown(self) -> None:
        self.bus.leave(self)

    # -- as its notifier ---------------------------------------------------------------------------------
    def join(self, network: Any) -> None:
        """Feed ``network`` (a ``canopen.Network`` built on this endpoint) with the bus's frames."""
        self.network = network
        network.notifier = self

    def add_listener(self, listener: Any) -> None:
        self.listeners.append(listener)

    def stop(self, timeout: float | None = None) -> None:
        for listener in self.listeners:
            listener.stop()

    def deliver(self, message: can.Message, own: bool) -> None:
        if self.backlog is not None:
            self.backlog.append((message, own))
            return
        if self.drops is not None and (self.receive_own_messages or not own) and self.drops(message, own):
            self.dropped += 1
            return
        if self.network is not None and (self.receive_own_messages or not own):
            for listener in self.network.listeners:  # canopen's MessageListener: network.notify(...)
                listener.on_message_received(message)
        for listener in list(self.listeners):
            listener.on_message_received(message)


class ClockedCanBus:
    """The bus and the clock (see the module docstring). ``master(transport)`` and ``devices(rig)`` put
    the two sides on it; ``frames`` is every frame in bus order, ``(timestamp, arbitration_id, data)``."""

    def __init__(self, clock: SimulatedClock) -> None:
        self.clock = clock
        self.frames: list[tuple[float, int, bytes]] = []
        self._endpoints: list[ClockedCanEndpoint] = []
        self._in_flight: collections.deque[tuple[ClockedCanEndpoint, can.Message]] = collections.deque()
        self._tasks: list[_CyclicTask] = []
        self._devices: list[Any] = []
        self._delivering = False
        self._hold: Callable[[], bool] = lambda: False
        self._master: ClockedCanEndpoint | None = None
        self._master_drops: Callable[[can.Message, bool], bool] | None = None

    # -- the two sides ----------------------------------------------------------------------------------
    def master(self, transport: Any, *, counts_drops: bool = False) -> None:
        """Put ``transport`` (a :class:`CanOpenTransport` built with ``clock=`` this bus's clock) on the
        bus: its network joins here, and its waits move the simulated clock. ``counts_drops``: its interface
        counts the frames :meth:`drop_from_master` deletes (as udp_multicast and SocketCAN count receive
        queue overflows); otherwise it has no drop counter (as python-can's virtual interface)."""

        def join_bus(canopen: Any) -> Any:
            endpoint = self.endpoint(receive_own_messages=True)
            endpoint.drops, self._master = self._master_drops, endpoint
            network = canopen.Network(endpoint)
            endpoint.join(network)
            return network

        transport._join_bus = join_bus
        transport._open_drop_counter = lambda: (lambda: self.master_drops) if counts_drops else None
        transport._wait_for = lambda ready, timeout_s: self.wait_for(ready, timeout_s, transport._lock)
        transport._pause = self.stall
        self._hold = transport._lock.locked

    def drop_from_master(self, drops: Callable[[can.Message, bool], bool]) -> None:
        """Delete from the master's receive stream every frame for which ``drops(frame, own)`` is true (``own``:
        the echo of a frame the master sent); the other nodes still receive it."""
        self._master_drops = drops
        if self._master is not None:
            self._master.drops = drops

    @property
    def master_drops(self) -> int:
        """Frames deleted from the master's receive stream so far."""
        return 0 if self._master is None else self._master.dropped

    def devices(self, rig: Any) -> None:
        """Start ``rig`` (a :class:`SimulatedCanOpenRig` built with ``clock=`` this bus's clock) on the bus."""
        self._devices.append(rig)
        rig.start(self.endpoint(receive_own_messages=False))

    def endpoint(self, *, receive_own_messages: bool) -> ClockedCanEndpoint:
        endpoint = ClockedCanEndpoint(self, receive_own_messages)
        self._endpoints.append(endpoint)
        return endpoint

    def leave(self, endpoint: ClockedCanEndpoint) -> None:
        if endpoint in self._endpoints:
            self._endpoints.remove(endpoint)
        self._tasks = [task for task in self._tasks if task.sender is not endpoint]

    # -- frames -------------------------------------------------------------------------------------------
    def send(self, sender: ClockedCanEndpoint, message: can.Message, timestamp: float | None = None) -> None:
        if sender not in self._endpoints:
            return  # a node that left the bus sends nothing
        frame = can.Message(arbitration_id=message.arbitration_id, data=bytes(message.data),
                            is_extended_id=message.is_extended_id, is_remote_frame=message.is_remote_frame,
                            is_error_frame=message.is_error_frame, dlc=message.dlc,
                            timestamp=self.clock() if timestamp is None else timestamp)
        self.frames.append((frame.timestamp, frame.arbitration_id, bytes(frame.data)))
        self._in_flight.append((sender, frame))
        if not self._hold():
            self.deliver()

    def deliver(self) -> None:
        """Every frame in flight to every node, in bus order (frames sent meanwhile queue behind)."""
        if self._delivering:
            return
        self._delivering = True
        try:
            while self._in_flight:
                sender, frame = self._in_flight.popleft()
                for endpoint in list(self._endpoints):
                    endpoint.deliver(frame, own=endpoint is sender)
        finally:
            self._delivering = False

    def start_task(self, sender: ClockedCanEndpoint, message: can.Message, period_s: float) -> _CyclicTask:
        task = _CyclicTask(self, sender, message, period_s)
        self._tasks.append(task)
        return task

    def stop_task(self, task: _CyclicTask) -> None:
        if task in self._tasks:
            self._tasks.remove(task)

    # -- time ---------------------------------------------------------------------------------------------
    def next_event_s(self) -> float:
        due = [task.next_due_s for task in self._tasks] + [rig.next_event_s() for rig in self._devices]
        return min(due, default=math.inf)

    def _run_due(self) -> None:
        now = self.clock()
        while True:
            due = [task for task in self._tasks if task.next_due_s <= now]
            if not due:
                break
            min(due, key=lambda task: task.next_due_s).fire()
        for rig in self._devices:
            rig.run_due()
        self.deliver()

    def _advance_to(self, when_s: float) -> None:
        self.clock.advance_to(max(when_s, self.clock()))
        self._run_due()

    def stall(self, seconds: float) -> None:
        """``seconds`` pass with the host's thread doing nothing; the nodes, the cyclic tasks and the master's
        receive side live through them event by event."""
        self.deliver()
        end = self.clock() + seconds
        while (when := self.next_event_s()) <= end:
            self._advance_to(when)
        self.clock.advance_to(end)

    def stall_receive(self, seconds: float) -> None:
        """``seconds`` pass with the master's receive side starved as well as its host thread (a whole process
        descheduled): the frames of the stall queue up in its receive buffer, and when it runs again it
        handles them in bus order, one after the other, before any frame it sends meanwhile reaches the
        nodes (they all go on the bus after the backlog, before the next event)."""
        assert self._master is not None
        self._master.backlog = collections.deque()
        try:
            self.stall(seconds)
        finally:
            backlog, self._master.backlog = self._master.backlog, None
        held, self._hold = self._hold, lambda: True  # the master's frames wait behind the backlog
        try:
            for message, own in backlog:
                self._master.deliver(message, own)
        finally:
            self._hold = held
        self.deliver()

    def wait_for(self, ready: Callable[[], bool], timeout_s: float, lock: Any) -> bool:
        """The host waits until ``ready()`` (checked with ``lock`` held) or ``timeout_s`` has passed: the
        clock moves to the next event, or to the end of the wait, whichever comes first."""
        end = self.clock() + max(timeout_s, 0.0)
        while True:
            self.deliver()
            with lock:
                if ready():
                    return True
            if self.clock() >= end:
                return False
            self._advance_to(min(self.next_event_s(), end))
