"""A simulated rig on the raw-CAN protocol of ``configs/raw_can.dbc``: a responder on a python-can bus
(the ``virtual`` interface in tests) around a simulated gearbox.

Protocol v3 (the default, ``protocol_version=3``), v4 (v3 with RIG_DEVICE_INFO_V4's two-byte buffer capacity) and
v2 (the DBC's comments on RIG_HELLO, RIG_START,
RIG_DEVICE_INFO, RIG_TICK_APPLIED and RIG_DRIVE_TICK, and the serial spec's section 16, which they mirror):
after RIG_HELLO the device buffers RIG_SETPOINTs by tick number and, from RIG_START on, ticks at the plant's
sample period on a thread of its own: tick k applies setpoint k (or holds the previous target, flagged HELD),
steps the gearbox once and sends, in v3, RIG_FEEDBACK and RIG_DRIVE_TICK for k (the target in force as the
age of the setpoint applied), in v2 RIG_FEEDBACK, RIG_DRIVE_FEEDBACK and RIG_TICK_APPLIED. The gearbox stands
still before tick 0, so a run equals the offline simulation of the commands applied, which the host logs.

Protocol v1 (``protocol_version=1``, or without RIG_HELLO): each RIG_SETPOINT received in OPERATION ENABLED
advances the gearbox exactly one sample and is answered by RIG_FEEDBACK and RIG_DRIVE_FEEDBACK with the
same sequence number. RIG_CONTROL runs the CiA 402 state machine (:mod:`rig.protocols.cia402`).
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable, Iterable

import can

from rig.protocols import cia402
from rig.protocols.can_bus_load import frame_bits
from rig.protocols.can_interfaces import open_bus, receive_drops
from rig.protocols.raw_can_frames import DEFAULT_DBC, RawCanCodec
from rig.protocols.serial_frames import unwrap_seq
from sim_backend.device_record import REQUESTS_KEPT, AppliedTargets, DeviceRecord, TickLateness
from sim_backend.plant import SimulatedGearbox
from sim_backend.virtual_bus_order import one_bus_order

__all__ = ["SimulatedRawCanDevice"]

HOST_FRAMES = ("RIG_CONTROL", "RIG_STATUS_REQUEST", "RIG_HELLO", "RIG_START", "RIG_SETPOINT")
"""The frames the device receives (configs/raw_can.dbc: those the host sends)."""


class SimulatedRawCanDevice(can.Listener):
    """Drive + load encoder of a simulated gearbox answering raw CAN frames.

    Parameters
    ----------
    gearbox
        The plant; stepped once per RIG_SETPOINT in OPERATION ENABLED.
    channel
        The python-can channel (the host joins the same one).
    interface, port
        Its interface (default ``virtual``: in this process); ``udp_multicast`` with its ``port`` puts the device
        in a process of its own (:mod:`sim_backend.can_device_process`).
    drive_counts_per_revolution
        Drive position scaling.
    dbc_path
        The frame layout.
    silent_seqs, fault_at_seq, fault_code
        Fault injection: samples whose answers are not sent (the plant still steps); the sample at which
        the drive faults (RIG_FAULT with ``fault_code``) instead of moving.
    error_frame_at
        ``(error class bits, sample)``: an error frame (:mod:`rig.protocols.can_error_frames`) goes on the
        bus before that sample's answers, e.g. a protocol violation or bus-off.
    disable_at_seq
        The sample at which the drive drops out of OPERATION ENABLED without a fault (enable input or safe
        torque off lost): it answers with its new statusword and follows no target after.
    lost_status_after_enable
        This many RIG_STATUS answers from the transition to OPERATION ENABLED on are lost; the host sends
        the request again with the same ``seq``, which the device answers without applying it twice.
    protocol_version, buffer_capacity, sample_period_s
        3 (default), 4 or 2: answers RIG_HELLO and ticks on its own clock in v3 (v4: the same ticks, the buffer
        capacity in two bytes of RIG_DEVICE_INFO_V4, up to 65535; or v2) mode, buffering ``buffer_capacity``
        setpoints, every ``sample_period_s`` (default: the gearbox's); 1: a v1 device, which ignores RIG_HELLO
        and RIG_START. In v2/v3 mode the sample numbers of the fault options are tick numbers.
    clock
        The device's clock in seconds (``time.perf_counter``). The threads of :meth:`start` wait on the wall
        clock; for a simulated clock use :meth:`start_scripted` instead (no thread), hand it the host's frames
        with :meth:`on_message_received` and run the ticks the clock has reached with :meth:`run_due`.
    """

    def __init__(self, gearbox: SimulatedGearbox, *, channel: str, interface: str = "virtual", port: int | None = None,
                 drive_counts_per_revolution: int = 1 << 17,
                 dbc_path: str = str(DEFAULT_DBC), bitrate: int = 1_000_000, silent_seqs: Iterable[int] = (),
                 fault_at_seq: int | None = None, fault_code: int = 0x7500,
                 disable_at_seq: int | None = None, error_frame_at: tuple[int, int] | None = None,
                 lost_status_after_enable: int = 0, protocol_version: int = 3, buffer_capacity: int = 255,
                 sample_period_s: float | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        if protocol_version not in (1, 2, 3, 4):
            raise ValueError(f"protocol_version: expected 1, 2, 3 or 4, got {protocol_version!r}")
        most = 65535 if protocol_version >= 4 else 255  # RIG_DEVICE_INFO_V4's two bytes, RIG_DEVICE_INFO's one
        if not 1 <= int(buffer_capacity) <= most:
            raise ValueError(f"buffer_capacity: expected 1..{most} setpoints, got {buffer_capacity!r}")
        self._clock = clock
        self.protocol_version, self.buffer_capacity = int(protocol_version), int(buffer_capacity)
        self.sample_period_s = float(gearbox.sample_period_s if sample_period_s is None else sample_period_s)
        self.mode = 1
        self.buffer: dict[int, int] = {}
        self.ticks = 0
        self.held_ticks = 0
        self.applied_targets = AppliedTargets()  # tick k: the target applied (DeviceRecord)
        self.lateness = TickLateness()  # how late the tick thread ran the ticks
        self.dropped_setpoints = 0
        self.target_counts = 0
        self._applied_tick: int | None = None  # the tick whose setpoint is in force (None: the enable position)
        self._ticking_since: float | None = None
        self._last_start_seq: int | None = None
        self._stop = threading.Event()
        self._tick_thread: threading.Thread | None = None
        self.gearbox = gearbox
        self.channel, self.interface, self.port = channel, interface, port
        self.drive = cia402.DriveScaling(int(drive_counts_per_revolution))
        self.codec = RawCanCodec(dbc_path)
        self.bitrate = int(bitrate)
        self.silent_seqs = frozenset(int(seq) & 0xFFFF for seq in silent_seqs)
        self.fault_at_seq = fault_at_seq
        self.fault_code = fault_code
        self.disable_at_seq = disable_at_seq
        self.error_frame_at = error_frame_at
        self.encoder_counts = 0
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self.controlword = 0
        self.controlwords: list[int] = []
        # the last REQUESTS_KEPT requests received, repeats included
        self.requests: collections.deque[tuple[str, int]] = collections.deque(maxlen=REQUESTS_KEPT)
        self.lost_status_after_enable = int(lost_status_after_enable)
        self.lost_answers = 0
        self._to_lose = 0
        self._last_control_seq: int | None = None
        self.actual_counts = 0
        self.setpoints = 0
        self.frames = 0
        self.bits = 0
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._lock = threading.Lock()
        self._state_lock = threading.RLock()  # the notifier and the tick thread share the drive's state

    def start(self) -> SimulatedRawCanDevice:
        if self.interface == "virtual":
            one_bus_order()  # every node sees the frames in one order, as on a real bus
            self._bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        else:  # an acceptance filter for the host's frames: its own, which udp_multicast hands back, cost no decoding
            self._bus = open_bus(self.interface, self.channel, port=self.port, bitrate=self.bitrate, can_filters=[
                {"can_id": self.codec.frame_ids[name], "can_mask": 0x7FF, "extended": False} for name in HOST_FRAMES
                if name in self.codec.frame_ids])
        self._notifier = can.Notifier(self._bus, [self], timeout=0.05)
        if self.protocol_version >= 2:
            self._stop.clear()
            self._tick_thread = threading.Thread(target=self._tick_loop, name=f"sim-can-tick-{self.channel}", daemon=True)
            self._tick_thread.start()
        return self

    def start_scripted(self, bus) -> SimulatedRawCanDevice:
        """Send through ``bus`` (anything with python-can's ``send(msg)``) with no thread: a scripted test hands
        the device the host's frames (:meth:`on_message_received`) and ticks it (:meth:`run_due`)."""
        self._bus = bus
        return self

    def next_tick_s(self) -> float:
        """When the next tick is due on the device's clock: ``START + k T`` (inf while not ticking)."""
        with self._state_lock:
            return math.inf if self._ticking_since is None else self._ticking_since + self.ticks * self.sample_period_s

    def run_due(self) -> None:
        """Every tick the device's clock has reached, in order (:meth:`tick` each, without the thread)."""
        while self.next_tick_s() <= self._clock():
            done = self.ticks
            self.tick()
            if self.ticks == done:  # no longer ticking (not enabled)
                break

    def close(self) -> None:
        """Stop the receive and tick threads and leave the bus (idempotent); records taken before stay readable."""
        self._stop.set()
        if self._tick_thread is not None:
            self._tick_thread.join(timeout=2.0)
            self._tick_thread = None
        if self._notifier is not None:
            self._notifier.stop()
            self._notifier = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
        self.applied_targets.close()

    def record(self) -> DeviceRecord:
        """What the device did (v2-v4: tick k's target; v1: the target of each setpoint applied)."""
        with self._state_lock:
            clocked = self.protocol_version >= 2 and self._tick_thread is not None
            return DeviceRecord(self.applied_targets.array(), tuple(self.controlwords), self.held_ticks,
                                self.lateness.delay_max_s if clocked else None,
                                None if self._bus is None else receive_drops(self._bus), tuple(self.lateness.stalls))

    def __enter__(self) -> SimulatedRawCanDevice:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _send(self, name: str, **signals: int) -> None:
        msg = self.codec.encode(name, **signals)
        self._count(msg)
        self._bus.send(msg)

    def _count(self, msg: can.Message) -> None:
        with self._lock:
            self.frames += 1
            self.bits += frame_bits(msg.dlc, extended=msg.is_extended_id)

    def on_message_received(self, msg: can.Message) -> None:
        with self._state_lock:
            self._on_message(msg)

    def _on_message(self, msg: can.Message) -> None:
        self._count(msg)
        try:
            decoded = self.codec.decode(msg)
        except ValueError:
            return  # a malformed frame of ours: a real device drops it too
        if decoded is None:
            return
        name, signals = decoded
        if name == "RIG_CONTROL":
            self.requests.append((name, signals["seq"]))
            if signals["seq"] != self._last_control_seq:  # a repeated seq is answered, not applied again
                self._last_control_seq = signals["seq"]
                controlword = signals["controlword"]
                self.controlwords.append(controlword)
                previous_state = self.state
                self.state = cia402.next_state(self.state, controlword, self.controlword)
                self.controlword = controlword
                if previous_state is cia402.DriveState.OPERATION_ENABLED and self.state is not previous_state:
                    self._end_session()
                if self.state is cia402.DriveState.OPERATION_ENABLED and previous_state is not self.state:
                    self._to_lose = self.lost_status_after_enable  # the target starts at the actual position
                    self.target_counts = self.actual_counts
            self._status(signals["seq"])
        elif name == "RIG_HELLO" and self.protocol_version >= 2:
            self.requests.append((name, signals["seq"]))
            if self.state is not cia402.DriveState.OPERATION_ENABLED:
                self.mode = max(1, min(signals["version"], self.protocol_version))
            if self.mode >= 4:  # (the DBC's RIG_DEVICE_INFO_V4: the version is the frame's)
                self._send("RIG_DEVICE_INFO_V4", seq=signals["seq"], buffer_capacity=self.buffer_capacity,
                           sample_period_ns=round(self.sample_period_s * 1e9))
                return
            self._send("RIG_DEVICE_INFO", seq=signals["seq"], version=self.mode, buffer_capacity=self.buffer_capacity,
                       sample_period_ns=round(self.sample_period_s * 1e9))
        elif name == "RIG_START" and self.protocol_version >= 2:
            self.requests.append((name, signals["seq"]))
            if (signals["seq"] != self._last_start_seq and self.mode >= 2 and self._ticking_since is None
                    and self.state is cia402.DriveState.OPERATION_ENABLED):
                self._ticking_since = self._clock()  # tick 0 is now
                self._applied_tick = None  # the target in force is the position held since enabling
            self._last_start_seq = signals["seq"]
            self._status(signals["seq"])
        elif name == "RIG_SETPOINT" and self.mode >= 2:
            self._queue_setpoint(signals["seq"], signals["target_counts"])
        elif name == "RIG_STATUS_REQUEST":
            self.requests.append((name, signals["seq"]))
            self._status(signals["seq"])
        elif name == "RIG_SETPOINT":
            self._setpoint(signals["seq"], signals["target_counts"])

    def _status(self, seq: int) -> None:
        if self._to_lose > 0:
            self._to_lose -= 1
            self.lost_answers += 1
            return
        self._send("RIG_STATUS", seq=seq, statusword=cia402.statusword_for(self.state), actual_counts=self.actual_counts)

    def _setpoint(self, seq: int, target_counts: int) -> None:
        if self.state is not cia402.DriveState.OPERATION_ENABLED:
            return
        if self.error_frame_at is not None and seq == self.error_frame_at[1] & 0xFFFF:
            self._bus.send(can.Message(arbitration_id=self.error_frame_at[0], is_error_frame=True, dlc=8,
                                       data=bytes(8), is_extended_id=False))
        if self.fault_at_seq is not None and seq == self.fault_at_seq & 0xFFFF:
            self.state = cia402.DriveState.FAULT
            self._send("RIG_FAULT", error_code=self.fault_code)
            return
        if self.disable_at_seq is not None and seq == self.disable_at_seq & 0xFFFF:
            self.state = cia402.DriveState.SWITCH_ON_DISABLED
            self._send("RIG_FEEDBACK", seq=seq, statusword=cia402.statusword_for(self.state),
                       encoder_counts=self.encoder_counts & 0xFFFFFFFF)
            self._send("RIG_DRIVE_FEEDBACK", seq=seq, actual_counts=self.actual_counts)
            return
        sample = self.gearbox.step(self.drive.rad_from_counts(target_counts))
        self.encoder_counts = sample.encoder_counts
        self.actual_counts = target_counts
        self.applied_targets.append(target_counts)
        self.setpoints += 1
        if seq in self.silent_seqs:
            return
        statusword = self._following_statusword()
        self._send("RIG_FEEDBACK", seq=seq, statusword=statusword, encoder_counts=sample.encoder_counts & 0xFFFFFFFF)
        self._send("RIG_DRIVE_FEEDBACK", seq=seq, actual_counts=self.actual_counts)

    # -- protocol v2: the device's own tick clock ------------------------------------------------------------

    def _end_session(self) -> None:
        self._ticking_since = None
        self.buffer.clear()
        self.mode = 1

    def _queue_setpoint(self, seq: int, target_counts: int) -> None:
        if self.state is not cia402.DriveState.OPERATION_ENABLED:
            return
        k = unwrap_seq(seq, self.ticks)
        if k < self.ticks or (k not in self.buffer and len(self.buffer) >= self.buffer_capacity):
            self.dropped_setpoints += 1  # too late (its tick has passed) or the buffer is full: that tick is HELD
            return
        self.buffer[k] = target_counts

    def _tick_loop(self) -> None:
        """Tick k at ``START + k T`` (absolute deadlines: a late wake-up catches up)."""
        while not self._stop.is_set():
            with self._state_lock:
                since = self._ticking_since
                due = None if since is None else since + self.ticks * self.sample_period_s
            wait_s = 0.02 if due is None else min(0.02, due - self._clock())
            if wait_s > 0:
                self._stop.wait(wait_s)
                continue
            with self._state_lock:
                if self._ticking_since == since:
                    self.lateness.observe(len(self.applied_targets), self._clock() - due)
                    self.tick()

    def tick(self) -> None:
        """Run the next tick k (v2): apply setpoint k or hold the previous target (HELD), step the gearbox once,
        send the tick's three frames. Public so that tests can script ticks without the thread."""
        with self._state_lock:
            if self._ticking_since is None or self.state is not cia402.DriveState.OPERATION_ENABLED:
                return
            k = self.ticks
            self.ticks += 1
            if self.error_frame_at is not None and k == self.error_frame_at[1]:
                self._bus.send(can.Message(arbitration_id=self.error_frame_at[0], is_error_frame=True, dlc=8,
                                           data=bytes(8), is_extended_id=False))
            if self.fault_at_seq is not None and k == self.fault_at_seq:
                self.state = cia402.DriveState.FAULT
                self._end_session()
                self._send("RIG_FAULT", error_code=self.fault_code)
                return
            if self.disable_at_seq is not None and k == self.disable_at_seq:
                mode = self.mode
                self.state = cia402.DriveState.SWITCH_ON_DISABLED
                self._end_session()
                self._tick_frames(k, mode, cia402.statusword_for(self.state), False)
                return
            held = k not in self.buffer
            if not held:
                self.target_counts, self._applied_tick = self.buffer.pop(k), k
            sample = self.gearbox.step(self.drive.rad_from_counts(self.target_counts))
            self.encoder_counts = sample.encoder_counts
            self.actual_counts = self.target_counts
            self.applied_targets.append(self.target_counts)
            self.setpoints += 1
            self.held_ticks += held
            if (k & 0xFFFF) not in self.silent_seqs:
                self._tick_frames(k, self.mode, self._following_statusword(), held)

    def _following_statusword(self) -> int:
        """The statusword of a sample in OPERATION ENABLED: at the target, and bit 12 set (the drive follows the
        targets, as in CiA 402 cyclic synchronous position mode; the serial spec's section 5)."""
        return cia402.statusword_for(self.state, target_reached=True) | cia402.STATUSWORD_FOLLOWS_TARGET

    def _tick_frames(self, k: int, mode: int, statusword: int, held: bool) -> None:
        """The frames of tick k: RIG_FEEDBACK, then (v3) RIG_DRIVE_TICK or (v2) RIG_DRIVE_FEEDBACK and
        RIG_TICK_APPLIED (the DBC's comments on RIG_DRIVE_TICK and RIG_TICK_APPLIED)."""
        self._send("RIG_FEEDBACK", seq=k, statusword=statusword, encoder_counts=self.encoder_counts & 0xFFFFFFFF)
        if mode >= 3:
            self._send("RIG_DRIVE_TICK", seq=k, actual_counts=self.actual_counts, buffer_level=min(len(self.buffer), 255),
                       applied_age=self._applied_age(k))
            return
        self._send("RIG_DRIVE_FEEDBACK", seq=k, actual_counts=self.actual_counts)
        self._send("RIG_TICK_APPLIED", seq=k, applied_counts=self.target_counts, tick_flags=1 if held else 0,
                   buffer_level=len(self.buffer))

    def _applied_age(self, k: int) -> int:
        """RIG_DRIVE_TICK's ``applied_age`` at tick k: k - (the tick whose setpoint is in force), 255 when that
        is 255 or more ticks ago or no setpoint was applied since RIG_START (the DBC's comment)."""
        return 255 if self._applied_tick is None else min(k - self._applied_tick, 255)
