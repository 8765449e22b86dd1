"""A simulated rig behind a serial port: the device side of ``docs/serial_protocol.md`` on a pty pair.

The host opens :attr:`SimulatedSerialDevice.port` (``/dev/pts/N``) with pyserial as it would open
``/dev/ttyUSB0``. ``rig run`` starts the device as threads of its own process; ``python -m
sim_backend.device_process serial PLANT.toml`` (:mod:`sim_backend.device_process`) runs it in a process of its
own, as a real device is a microcontroller with its own clock (the benchmark does, so that a pause of the driver
does not stop the device's clock).

Protocol v2 (the default, ``protocol_version=2``; spec section 16): a HELLO puts the device in v2 mode; it
queues SETPOINTs by tick number in a buffer of ``buffer_capacity`` setpoints and, from START on, ticks at
the plant's own sample period on a thread of its own: at tick k it applies setpoint k (or holds the previous
target, flagged HELD, when k is not in the buffer), steps the gearbox once and sends TICK k. The gearbox is
stepped once per tick from tick 0 on and stands exactly still before it, so a run equals the offline
simulation of the commands the device applied (which the host logs), whatever the host's timing.

Protocol v1 (``protocol_version=1``, or a v2 device that got no HELLO): each SETPOINT frame advances the
simulated gearbox exactly one sample and is answered by one FEEDBACK frame with the same sequence number.
"""

from __future__ import annotations

import collections
import math
import os
import random
import select
import threading
import time
import tty
from collections.abc import Callable, Iterable

from rig.protocols import cia402
from rig.protocols.serial_frames import (
    PROTOCOL_VERSION, TICK_HELD, FrameDecoder, MessageType, SerialMessage, encode_frame, unwrap_seq,
)
from sim_backend.device_record import REQUESTS_KEPT, AppliedTargets, DeviceRecord, TickLateness
from sim_backend.plant import SimulatedGearbox

__all__ = ["SimulatedSerialDevice", "serial_device_process"]


class SimulatedSerialDevice:
    """Drive + load encoder of a simulated gearbox, answering on a pty.

    Parameters
    ----------
    gearbox
        The plant; stepped once per SETPOINT frame received in OPERATION ENABLED.
    drive_counts_per_revolution
        Drive position scaling (target counts -> motor radians).
    silent_seqs
        Sample numbers whose FEEDBACK is not sent (the plant still steps): injected frame loss.
    fault_at_seq
        Sample number at which the drive goes to FAULT (error code ``fault_code``) and reports it.
    garbage_probability, bitflip_probability, truncate_probability
        Injected line noise (:mod:`sim_backend.faults`): random bytes before a reply, one bit of a reply
        flipped, or a reply cut short, each with this probability per reply (drawn from ``seed``).
    reply_lag
        ``(seconds, first sample)``: from that sample on, every reply leaves this much later (a device
        that answers late).
    disable_at_seq
        At this sample the drive drops out of OPERATION ENABLED without a fault (enable input or safe
        torque off lost): it answers that setpoint with its new statusword and follows no target after.
    unplug_at_seq
        At this sample the device closes its end of the port, like a USB adapter pulled out; its own link
        watchdog disables the drive.

    The legal behaviours of the real variety (defaults: today's quick, well-behaved device):

    status_delay_s
        Every answer to a request (STATUS, ERROR) leaves this much later (a slow bring-up).
    fault_reset_delay_s
        After the rising edge of controlword bit 7 the drive stays in FAULT this long (``math.inf``: the
        fault cannot be reset).
    boot_fault_code
        The device starts in FAULT with this error code (readable with ERROR_REQUEST).
    lost_status_after_enable
        This many STATUS answers from the transition to OPERATION ENABLED on are lost (the host must send
        the request again; a repeated request number is answered without being applied twice).
    boot_banner
        Bytes the device writes before its first answer (a boot message, a leading 0x00).
    copy_target_at_enable
        False: the drive keeps its old target at the transition to OPERATION ENABLED instead of taking its
        actual position (the spec requires the copy); it holds still until the first SETPOINT, which it
        then servoes to from wherever it stands (with ``following_error_counts``: faults if that is far).
        (A drive that servoed to its stale target at once could not be helped by the host on this
        protocol, which has no way to write the target before enabling: the spec's rule prevents that.)
    following_error_counts
        A SETPOINT target farther than this from the actual position faults the drive with 0x8611
        (position following error), as a real drive does instead of jumping.
    initial_actual_counts
        The drive's actual position at power-up.
    fault_frame_lost
        The FAULT frame of ``fault_at_seq`` is lost on the line; the host sees only the faulted
        statusword (in that sample's FEEDBACK) and must read the code with ERROR_REQUEST.

    Protocol v2 (sample numbers in the fault options above are tick numbers in v2 mode):

    protocol_version
        2 (default): the device answers HELLO and runs its own tick clock in v2 mode; 1: a v1 device, which
        drops HELLO and START as unknown types.
    buffer_capacity
        Setpoints the device's buffer holds (v2), reported in DEVICE_INFO: 1024 (6 KB) by default, so that the
        transport's default 250 ms lead fits at 2 kHz (500 setpoints) with room to spare.
    sample_period_s
        The device's tick period (default: the gearbox's sample period), reported in DEVICE_INFO.
    clock
        The device's clock in seconds (``time.perf_counter``). The threads of :meth:`start` wait on the wall
        clock; a simulated clock is for scripted use without them: :meth:`handle` the host's messages,
        :meth:`run_due` the ticks the clock has reached (:meth:`next_tick_s` says when the next one is).
    """

    def __init__(self, gearbox: SimulatedGearbox, *, drive_counts_per_revolution: int = 1 << 17,
                 silent_seqs: Iterable[int] = (), fault_at_seq: int | None = None, fault_code: int = 0x7500,
                 garbage_probability: float = 0.0, bitflip_probability: float = 0.0,
                 truncate_probability: float = 0.0, reply_lag: tuple[float, int] | None = None,
                 unplug_at_seq: int | None = None, disable_at_seq: int | None = None, seed: int = 0,
                 status_delay_s: float = 0.0, fault_reset_delay_s: float = 0.0, boot_fault_code: int | None = None,
                 lost_status_after_enable: int = 0, boot_banner: bytes = b"", copy_target_at_enable: bool = True,
                 following_error_counts: int | None = None, initial_actual_counts: int = 0,
                 fault_frame_lost: bool = False, protocol_version: int = PROTOCOL_VERSION, buffer_capacity: int = 1024,
                 sample_period_s: float | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        if protocol_version not in (1, 2):
            raise ValueError(f"protocol_version: expected 1 or 2, got {protocol_version!r}")
        if not 1 <= int(buffer_capacity) <= 0xFFFF:
            raise ValueError(f"buffer_capacity: expected 1..65535 setpoints, got {buffer_capacity!r}")
        self._clock = clock
        self.protocol_version = int(protocol_version)
        self.buffer_capacity = int(buffer_capacity)
        self.sample_period_s = float(gearbox.sample_period_s if sample_period_s is None else sample_period_s)
        self.mode = 1  # the protocol of this session: 2 from an answered HELLO until the drive leaves OPERATION ENABLED
        self.buffer: dict[int, int] = {}  # v2: tick -> target counts
        self.ticks = 0  # v2: the next tick's number (ticks done)
        self.held_ticks = 0
        self.applied_targets = AppliedTargets()  # sample k: the target applied (DeviceRecord)
        self.lateness = TickLateness()  # how late the tick thread ran the ticks
        self.dropped_setpoints = 0  # v2: late (tick passed) or beyond the buffer's capacity
        self._ticking_since: float | None = None  # v2: host time of tick 0 (START), None: not ticking
        self._lock = threading.RLock()  # the serve and tick threads share the drive's state
        self._write_lock = threading.Lock()
        self._delayed_ticks: collections.deque[tuple[float, bytes]] = collections.deque()
        self.gearbox = gearbox
        self.drive = cia402.DriveScaling(int(drive_counts_per_revolution))
        self.silent_seqs = frozenset(int(seq) & 0xFFFF for seq in silent_seqs)
        self.fault_at_seq = fault_at_seq
        self.fault_code = fault_code
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self.error_code = 0
        if boot_fault_code is not None:
            self.state, self.error_code = cia402.DriveState.FAULT, int(boot_fault_code)
        self.controlword = 0
        self.target_counts = 0
        self.actual_counts = int(initial_actual_counts)
        self.setpoints = 0
        self.controlwords: list[int] = []
        # the last REQUESTS_KEPT requests received, repeats included
        self.requests: collections.deque[tuple[MessageType, int]] = collections.deque(maxlen=REQUESTS_KEPT)
        self.status_delay_s = float(status_delay_s)
        self.fault_reset_delay_s = float(fault_reset_delay_s)
        self.lost_status_after_enable = int(lost_status_after_enable)
        self.boot_banner = bytes(boot_banner)
        self.copy_target_at_enable = bool(copy_target_at_enable)
        self.following_error_counts = following_error_counts
        self.fault_frame_lost = bool(fault_frame_lost)
        self._last_start_seq: int | None = None
        self.lost_answers = 0
        self._to_lose = 0
        self._last_control_seq: int | None = None
        self._reset_due: float | None = None
        self._answered = False
        self.frame_errors = 0
        self.garbage_probability = float(garbage_probability)
        self.bitflip_probability = float(bitflip_probability)
        self.truncate_probability = float(truncate_probability)
        self.reply_lag = reply_lag
        self.unplug_at_seq = unplug_at_seq
        self.disable_at_seq = disable_at_seq
        self.encoder_counts = 0
        self.unplugged = False
        self._rng = random.Random(seed)
        self._decoder = FrameDecoder()
        self._master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        self.port = os.ttyname(self._slave_fd)
        self._stop = threading.Event()
        self._wake = threading.Event()  # START or the stop: the tick thread looks again
        self._thread: threading.Thread | None = None
        self._tick_thread: threading.Thread | None = None

    def start(self) -> SimulatedSerialDevice:
        self._thread = threading.Thread(target=self._serve, name=f"sim-serial-{self.port}", daemon=True)
        self._thread.start()
        if self.protocol_version >= 2:
            self._tick_thread = threading.Thread(target=self._tick_loop, name=f"sim-serial-tick-{self.port}", daemon=True)
            self._tick_thread.start()
        return self

    def close(self) -> None:
        """Stop the device threads and close the pty (idempotent); records taken before stay readable."""
        self._stop.set()
        self._wake.set()
        for name in ("_thread", "_tick_thread"):
            thread = getattr(self, name)
            if thread is not None:
                thread.join(timeout=2.0)
                setattr(self, name, None)
        for fd_name in ("_master_fd", "_slave_fd"):
            fd = getattr(self, fd_name)
            if fd is not None:
                os.close(fd)
                setattr(self, fd_name, None)
        self.applied_targets.close()

    def record(self) -> DeviceRecord:
        """What the device did (v2: tick k's target; v1: the target of each setpoint applied)."""
        with self._lock:
            return DeviceRecord(self.applied_targets.array(), tuple(self.controlwords), self.held_ticks,
                                self.lateness.delay_max_s if self._tick_thread is not None else None,
                                stalls=tuple(self.lateness.stalls))

    def __enter__(self) -> SimulatedSerialDevice:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- device loop ----------------------------------------------------------------------------------------

    def _serve(self) -> None:
        delayed: collections.deque[tuple[float, bytes]] = collections.deque()  # (due time, reply), in order
        while not self._stop.is_set():
            timeout_s = 0.05 if not delayed else min(0.05, max(0.0, delayed[0][0] - self._clock()))
            fd = self._master_fd
            if fd is None:
                return  # unplugged (by the tick thread)
            try:
                ready, _, _ = select.select([fd], [], [], timeout_s)
            except (OSError, ValueError):
                return
            while delayed and delayed[0][0] <= self._clock():
                self._write(delayed.popleft()[1])
            if not ready:
                continue
            try:
                data = os.read(fd, 4096)
            except OSError:
                return
            for message in self._decoder.feed(data):
                if self._unplugs_at(message):
                    self._unplug()
                    return
                with self._lock:
                    reply = self.handle(message)
                if not reply:
                    continue
                reply = self._line_noise(reply)
                if not self._answered:
                    self._answered = True
                    reply = self.boot_banner + reply  # boot output comes before the first frame
                lag = 0.0
                if self.reply_lag is not None and self.setpoints > self.reply_lag[1]:
                    lag = self.reply_lag[0]
                if message.type is not MessageType.SETPOINT:
                    lag = max(lag, self.status_delay_s)
                if lag:
                    delayed.append((self._clock() + lag, reply))  # latency, not throughput
                elif not self._write(reply):
                    return
            self.frame_errors = self._decoder.errors

    def _write(self, data: bytes) -> bool:
        """Write whole frames (the serve and tick threads both write); False once the port is gone."""
        with self._write_lock:
            if self._master_fd is None:
                return False
            try:
                os.write(self._master_fd, data)
            except OSError:
                return False
        return True

    # -- protocol v2: the device's own tick clock ------------------------------------------------------------

    def _tick_loop(self) -> None:
        """Tick k at ``START + k T`` (absolute deadlines: a late wake-up catches up, it does not shift later
        ticks); TICK frames with a reply lag leave from here too, in order."""
        while not self._stop.is_set():
            with self._lock:
                since, due = self._ticking_since, None
                if since is not None:
                    due = since + self.ticks * self.sample_period_s
            wake = [when for when in (due, self._delayed_ticks[0][0] if self._delayed_ticks else None) if when]
            timeout_s = 0.05 if not wake else min(0.05, max(0.0, min(wake) - self._clock()))
            if timeout_s > 0:
                self._wake.wait(timeout_s)
                self._wake.clear()
            now = self._clock()
            while self._delayed_ticks and self._delayed_ticks[0][0] <= now:
                self._write(self._delayed_ticks.popleft()[1])
            if due is None or now < due:
                continue
            with self._lock:
                if self._ticking_since != since:
                    continue  # stopped (or restarted) meanwhile
                if self.unplug_at_seq is not None and self.ticks == self.unplug_at_seq:
                    self._unplug()
                    return
                lagged = self.reply_lag is not None and self.ticks > self.reply_lag[1]
                self.lateness.observe(len(self.applied_targets), now - due)
                frames = self.tick()
            if not frames:
                continue
            frames = self._line_noise(frames)
            if lagged:
                self._delayed_ticks.append((now + self.reply_lag[0], frames))
            elif not self._write(frames):
                return

    def tick(self) -> bytes:
        """Run the device's next tick k (v2): apply setpoint k from the buffer, or hold the previous target
        and flag the tick HELD; step the gearbox once; return the TICK frame (and a FAULT frame before it).
        Public so that tests can script ticks without the thread."""
        with self._lock:
            if self._ticking_since is None or self.state is not cia402.DriveState.OPERATION_ENABLED:
                return b""
            k = self.ticks
            self.ticks += 1
            for stale in [seq for seq in self.buffer if seq < k]:  # cannot happen: refused on arrival
                del self.buffer[stale]
            if self.fault_at_seq is not None and k == self.fault_at_seq:
                fault = self._fault(self.fault_code)
                self._end_session()
                tick = self._tick_frame(k, self._statusword(), self.target_counts, 0)
                return tick if self.fault_frame_lost else fault + tick
            if self.disable_at_seq is not None and k == self.disable_at_seq:
                self.state = cia402.DriveState.SWITCH_ON_DISABLED
                self._end_session()
                return self._tick_frame(k, cia402.statusword_for(self.state), self.target_counts, 0)
            held = k not in self.buffer
            target = self.target_counts if held else self.buffer.pop(k)
            fault = self._servo_to(target)
            if fault:
                self._end_session()
                return fault + self._tick_frame(k, self._statusword(), self.target_counts, 0)
            self.target_counts = target
            self.applied_targets.append(target)
            sample = self.gearbox.step(self.drive.rad_from_counts(target))
            self.encoder_counts = sample.encoder_counts
            self.setpoints += 1
            self.held_ticks += held
            if (k & 0xFFFF) in self.silent_seqs:
                return b""
            return self._tick_frame(k, self._statusword() | cia402.STATUSWORD_TARGET_REACHED, target,
                                    TICK_HELD if held else 0)

    def next_tick_s(self) -> float:
        """When the next tick is due on the device's clock: ``START + k T`` (inf while not ticking)."""
        with self._lock:
            return math.inf if self._ticking_since is None else self._ticking_since + self.ticks * self.sample_period_s

    def run_due(self) -> bytes:
        """Every tick the device's clock has reached, in order (:meth:`tick` each, without the thread): the
        frames they send."""
        frames = bytearray()
        while self.next_tick_s() <= self._clock():
            done = self.ticks
            frames += self.tick()
            if self.ticks == done:  # no longer ticking (not enabled)
                break
        return bytes(frames)

    def _tick_frame(self, k: int, statusword: int, applied_counts: int, flags: int) -> bytes:
        return encode_frame(MessageType.TICK, k, statusword, self.actual_counts, self.encoder_counts & 0xFFFFFFFF,
                            applied_counts, flags, len(self.buffer))

    def _end_session(self) -> None:
        """The drive left OPERATION ENABLED: the tick clock stops, the buffer empties, and the device is back
        in v1 mode until the next HELLO."""
        self._ticking_since = None
        self.buffer.clear()
        self.mode = 1

    def _hello(self, message: SerialMessage) -> bytes:
        (host_version,) = message.fields
        if self.state is not cia402.DriveState.OPERATION_ENABLED:  # the mode changes only while not enabled
            self.mode = max(1, min(int(host_version), self.protocol_version))
        return encode_frame(MessageType.DEVICE_INFO, message.seq, self.mode, self.buffer_capacity,
                            round(self.sample_period_s * 1e9))

    def _start(self, message: SerialMessage) -> bytes:
        if (message.seq != self._last_start_seq and self.mode >= 2 and self._ticking_since is None
                and self.state is cia402.DriveState.OPERATION_ENABLED):
            self._ticking_since = self._clock()  # tick 0 is now
            self._wake.set()
        self._last_start_seq = message.seq
        return self._status(message.seq)

    def _queue_setpoint(self, message: SerialMessage) -> bytes:
        """v2: SETPOINT k goes into the buffer for tick k; one for a tick that has passed, or beyond the
        buffer's capacity, is dropped (the tick it was for is HELD)."""
        if self.state is not cia402.DriveState.OPERATION_ENABLED:
            return b""
        k = unwrap_seq(message.seq, self.ticks)
        if k < self.ticks or (k not in self.buffer and len(self.buffer) >= self.buffer_capacity):
            self.dropped_setpoints += 1
            return b""
        self.buffer[k] = message.fields[0]
        return b""

    def _unplugs_at(self, message: SerialMessage) -> bool:
        return (self.unplug_at_seq is not None and message.type is MessageType.SETPOINT and self.mode < 2
                and message.seq == self.unplug_at_seq & 0xFFFF)  # v2: at tick unplug_at_seq (_tick_loop)

    def _unplug(self) -> None:
        """The port disappears; the drive's link watchdog disables it (a real drive's communication
        watchdog, e.g. CiA 402 0x6007 abort connection option code)."""
        with self._lock:
            self.state = cia402.DriveState.SWITCH_ON_DISABLED
            self._end_session()
            self.unplugged = True
        with self._write_lock:
            fd, self._master_fd = self._master_fd, None
        if fd is not None:
            os.close(fd)

    def _line_noise(self, reply: bytes) -> bytes:
        """The reply as the line delivers it: maybe one bit flipped (not in the 0x00 delimiter, so the
        frame's CRC fails), maybe cut short (an early delimiter), maybe preceded by random bytes."""
        if self.bitflip_probability and self._rng.random() < self.bitflip_probability:
            noisy = bytearray(reply)
            noisy[self._rng.randrange(len(reply) - 1)] ^= 1 << self._rng.randrange(8)
            reply = bytes(noisy)
        if self.truncate_probability and self._rng.random() < self.truncate_probability:
            reply = reply[:self._rng.randrange(1, len(reply) - 1)] + b"\x00"
        if self.garbage_probability and self._rng.random() < self.garbage_probability:
            reply = self._rng.randbytes(self._rng.randint(1, 16)) + reply
        return reply

    def handle(self, message: SerialMessage) -> bytes:
        """The bytes the device answers to ``message`` (public so that tests can script exchanges)."""
        self._finish_fault_reset()
        if message.type is MessageType.CONTROL:
            self.requests.append((message.type, message.seq))
            if message.seq != self._last_control_seq:  # a repeated request number is answered, not applied again
                self._last_control_seq = message.seq
                reply = self._control(message.fields[0])
                if reply:
                    return reply
            return self._status(message.seq)
        if message.type is MessageType.STATUS_REQUEST:
            self.requests.append((message.type, message.seq))
            return self._status(message.seq)
        if message.type is MessageType.ERROR_REQUEST:
            self.requests.append((message.type, message.seq))
            return encode_frame(MessageType.ERROR, message.seq, self.error_code)
        if self.protocol_version >= 2 and message.type is MessageType.HELLO:
            self.requests.append((message.type, message.seq))
            return self._hello(message)
        if self.protocol_version >= 2 and message.type is MessageType.START:
            self.requests.append((message.type, message.seq))
            return self._start(message)
        if message.type is MessageType.SETPOINT:
            return self._queue_setpoint(message) if self.mode >= 2 else self._setpoint(message)
        return b""  # v1: HELLO and START are unknown types, dropped unanswered

    def _control(self, controlword: int) -> bytes:
        """Apply a controlword; returns a FAULT frame if the transition faulted the drive."""
        self.controlwords.append(controlword)
        previous_state = self.state
        rising = controlword & 0x0080 and not self.controlword & 0x0080
        self.state = cia402.next_state(self.state, controlword, self.controlword)
        self.controlword = controlword
        if previous_state is cia402.DriveState.FAULT and self.state is not previous_state:
            if self.fault_reset_delay_s > 0:  # the reset takes time: still FAULT until then
                self.state = previous_state
                if rising:
                    self._reset_due = self._clock() + self.fault_reset_delay_s
            else:
                self.error_code = 0
        if previous_state is cia402.DriveState.OPERATION_ENABLED and self.state is not previous_state:
            self._end_session()
        if self.state is cia402.DriveState.OPERATION_ENABLED and previous_state is not self.state:
            self._to_lose = self.lost_status_after_enable
            if self.copy_target_at_enable:
                self.target_counts = self.actual_counts  # no jump on enable
        return b""

    def _finish_fault_reset(self) -> None:
        if self._reset_due is not None and self._clock() >= self._reset_due:
            self._reset_due = None
            if self.state is cia402.DriveState.FAULT:
                self.state, self.error_code = cia402.DriveState.SWITCH_ON_DISABLED, 0

    def _servo_to(self, target_counts: int) -> bytes:
        """Move to ``target_counts`` at once, or fault with a following error if it is too far."""
        window = self.following_error_counts
        if window is not None and abs(target_counts - self.actual_counts) > window:
            return self._fault(0x8611)
        self.actual_counts = target_counts
        return b""

    def _fault(self, code: int) -> bytes:
        """Enter FAULT: the FAULT frame goes out before any statusword that says FAULT."""
        self.state, self.error_code = cia402.DriveState.FAULT, code
        return encode_frame(MessageType.FAULT, 0, code)

    def _statusword(self) -> int:
        word = cia402.statusword_for(self.state, target_reached=self.state is cia402.DriveState.QUICK_STOP_ACTIVE)
        if self.state is cia402.DriveState.OPERATION_ENABLED:
            word |= cia402.STATUSWORD_FOLLOWS_TARGET  # bit 12: the drive follows the SETPOINT targets
        return word

    def _status(self, seq: int) -> bytes:
        if self._to_lose > 0:
            self._to_lose -= 1
            self.lost_answers += 1
            return b""
        return encode_frame(MessageType.STATUS, seq, self._statusword(), self.actual_counts)

    def _setpoint(self, message: SerialMessage) -> bytes:
        if self.state is not cia402.DriveState.OPERATION_ENABLED:
            return b""  # a drive not enabled ignores targets; the host sees the sample as lost
        if self.fault_at_seq is not None and message.seq == self.fault_at_seq & 0xFFFF:
            fault = self._fault(self.fault_code)
            if self.fault_frame_lost:
                return encode_frame(MessageType.FEEDBACK, message.seq, self._statusword(), self.actual_counts,
                                    self.encoder_counts & 0xFFFFFFFF)
            return fault
        if self.disable_at_seq is not None and message.seq == self.disable_at_seq & 0xFFFF:
            self.state = cia402.DriveState.SWITCH_ON_DISABLED
            return encode_frame(MessageType.FEEDBACK, message.seq, cia402.statusword_for(self.state),
                                self.actual_counts, self.encoder_counts & 0xFFFFFFFF)
        (target,) = message.fields
        fault = self._servo_to(target)
        if fault:
            return fault
        self.target_counts = target
        self.applied_targets.append(target)
        command_rad = self.drive.rad_from_counts(self.target_counts)
        sample = self.gearbox.step(command_rad)
        self.encoder_counts = sample.encoder_counts
        self.setpoints += 1
        if message.seq in self.silent_seqs:
            return b""
        return encode_frame(MessageType.FEEDBACK, message.seq, self._statusword() | cia402.STATUSWORD_TARGET_REACHED,
                            self.actual_counts, sample.encoder_counts & 0xFFFFFFFF)
