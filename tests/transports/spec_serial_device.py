"""A minimal serial rig device written only from ``docs/serial_protocol.md`` (its sections and tables are
cited), to keep the spec honest: it imports nothing from ``rig`` or ``sim_backend``. It speaks protocol v1
(sections 1-15) and v2 (section 16: the device owns the sample clock); ``protocol_version=1`` makes it a
v1-only device that drops HELLO as an unknown type.

Plant: the drive's actual position is its target (an ideal drive); the load encoder is an unsigned 16-bit
single-turn encoder geared 1:1 to the drive, read through a fixed gain: 2^17 drive counts per revolution,
2^16 encoder counts per revolution, so ``encoder = floor(actual / 2) mod 2^16``.

Time. The device's logic takes its time from ``clock`` (a function returning seconds) and does what is due
when :meth:`feed` hands it bytes from the host or :meth:`run_due` asks it to catch up; nothing in the logic
sleeps or starts a thread. Two ways to run it:

* on a pty with a thread on the wall clock (``start()``/``close()`` or a ``with`` block): the real driver
  opens :attr:`port`;
* scripted (``output=`` a function that takes the device's bytes, ``clock=`` a simulated clock): the test
  feeds the host's bytes, moves the clock and calls :meth:`run_due`; every tick happens exactly when the
  test says, whatever the machine's load.
"""

from __future__ import annotations

import os
import select
import struct
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass

# -- section 2: framing ---------------------------------------------------------------------------------------


def crc16_ccitt_false(data: bytes) -> int:
    """Polynomial 0x1021, initial value 0xFFFF, not reflected, no final XOR."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def cobs_encode(data: bytes) -> bytes:
    out, block = bytearray(), bytearray()
    for byte in data:
        if byte == 0:
            out += bytes([len(block) + 1]) + block
            block.clear()
        else:
            block.append(byte)
            if len(block) == 254:
                out += b"\xff" + block
                block.clear()
    out += bytes([len(block) + 1]) + block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes | None:
    out, index = bytearray(), 0
    while index < len(data):
        code = data[index]
        if code == 0 or index + code > len(data):
            return None
        out += data[index + 1:index + code]
        index += code
        if code < 255 and index < len(data):
            out.append(0)
    return bytes(out)


# -- section 3 (v1) and section 16.1 (v2): messages --------------------------------------------------------

SETPOINT, CONTROL, STATUS_REQUEST, ERROR_REQUEST, HELLO, START = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
FEEDBACK, STATUS, FAULT, ERROR, DEVICE_INFO, TICK = 0x81, 0x82, 0x83, 0x84, 0x85, 0x86
BODIES_V1 = {SETPOINT: "<i", CONTROL: "<H", STATUS_REQUEST: "<", ERROR_REQUEST: "<",
             FEEDBACK: "<HiI", STATUS: "<Hi", FAULT: "<H", ERROR: "<H"}
BODIES = BODIES_V1 | {HELLO: "<B", START: "<", DEVICE_INFO: "<BHI", TICK: "<HiIiBH"}
TICK_HELD = 0x01  # section 16.1, tick_flags bit 0


def frame(kind: int, seq: int, *fields: int) -> bytes:
    payload = struct.pack("<BH", kind, seq) + struct.pack(BODIES[kind], *fields)
    return cobs_encode(payload + struct.pack("<H", crc16_ccitt_false(payload))) + b"\x00"


def parse(chunk: bytes, known: dict[int, str] = BODIES) -> tuple[int, int, tuple[int, ...]] | None:
    """Section 2's receiving rules; a type not in ``known`` is dropped like a damaged frame (section 3)."""
    raw = cobs_decode(chunk)
    if raw is None or len(raw) < 5:
        return None
    payload, (crc,) = raw[:-2], struct.unpack("<H", raw[-2:])
    if crc16_ccitt_false(payload) != crc:
        return None
    kind, seq = struct.unpack("<BH", payload[:3])
    if kind not in known or len(payload) - 3 != struct.calcsize(known[kind]):
        return None
    return kind, seq, struct.unpack(known[kind], payload[3:])


# -- section 5: statusword and controlword --------------------------------------------------------------------

SWITCH_ON_DISABLED, READY_TO_SWITCH_ON, SWITCHED_ON = 0x0040, 0x0021, 0x0023
OPERATION_ENABLED, QUICK_STOP_ACTIVE, FAULT_STATE = 0x0027, 0x0007, 0x0008
VOLTAGE, REMOTE, TARGET_REACHED, FOLLOWS_TARGET = 0x0010, 0x0200, 0x0400, 0x1000
TRANSITIONS = {  # (state, controlword) -> next state; any other pair leaves the state
    (SWITCH_ON_DISABLED, 0x0006): READY_TO_SWITCH_ON,
    (READY_TO_SWITCH_ON, 0x0007): SWITCHED_ON, (READY_TO_SWITCH_ON, 0x000F): OPERATION_ENABLED,
    (READY_TO_SWITCH_ON, 0x0000): SWITCH_ON_DISABLED, (READY_TO_SWITCH_ON, 0x0002): SWITCH_ON_DISABLED,
    (SWITCHED_ON, 0x0000): SWITCH_ON_DISABLED, (SWITCHED_ON, 0x0002): SWITCH_ON_DISABLED,
    (SWITCHED_ON, 0x0006): READY_TO_SWITCH_ON, (SWITCHED_ON, 0x000F): OPERATION_ENABLED,
    (OPERATION_ENABLED, 0x0007): SWITCHED_ON, (OPERATION_ENABLED, 0x0006): READY_TO_SWITCH_ON,
    (OPERATION_ENABLED, 0x0002): QUICK_STOP_ACTIVE, (OPERATION_ENABLED, 0x0000): SWITCH_ON_DISABLED,
    (QUICK_STOP_ACTIVE, 0x0000): SWITCH_ON_DISABLED,
}

WATCHDOG_BEFORE_FIRST_SETPOINT_S = 1.5  # section 10; in v2 until START (section 16.4)
WATCHDOG_STREAMING_S = 0.1  # section 10: >= max(10 T, 50 ms) once v1 streaming began, 100 ms suggested
WATCHDOG_TICKING_S = 1.0  # section 16.4: >= 0.5 s after START, 1 s suggested (ride through host stalls)


@dataclass(frozen=True)
class TickRecord:
    """What the device did at one tick of a v2 session (section 16.3): the fields of the TICK it sent."""

    statusword: int
    actual_counts: int
    encoder_counts: int
    applied_counts: int
    held: bool
    buffer_level: int


class SpecSerialDevice:
    """The device, on a pty (:attr:`port`) served by a wall-clock thread, or scripted through ``output``.

    Parameters
    ----------
    protocol_version
        The highest protocol the device speaks (section 16.1): 2, or 1 for a v1-only device that does not
        know HELLO and START and drops them as unknown types (section 16.2, step 1).
    knows_hello
        A v1 device that knows HELLO and answers it with version 1 (section 16.1, DEVICE_INFO ``version``);
        default: only a v2 device knows it.
    buffer_capacity, sample_period_ns
        Reported in DEVICE_INFO (section 16.1): the setpoint buffer and the tick period T.
    clock
        The device's clock in seconds (``time.monotonic`` on the pty; a simulated clock when scripted).
    output
        Scripted use: called with every byte string the device sends, instead of writing to a pty.
    lost_status_after_enable
        This many STATUS answers from the transition to OPERATION ENABLED on are "lost on the line".
    lost_device_info
        This many DEVICE_INFO answers are lost on the line (section 16.2: the host tries HELLO twice).
    lost_setpoints
        SETPOINTs with these seq values are lost on the line, each once (in v2: that tick is HELD).
    watchdog_streaming_s, watchdog_ticking_s
        The link watchdog once v1 streaming began (section 10: at least max(10 T, 50 ms), 100 ms suggested)
        and after START in v2 (section 16.4: at least 0.5 s, 1 s suggested). The bounds are lower bounds: a
        device on a shared, loaded test machine may choose seconds.
    boot_output
        Written before the first frame (section 11).
    boot_fault_code
        Boot in FAULT with this code; ``fault_clears`` says whether a fault reset clears it.
    fault_at_sample, fault_code, fault_frame_lost
        Fault while applying this sample (section 9; in v2 at this tick, section 16.3); ``fault_frame_lost``:
        the FAULT frame is lost on the line, only the faulted statusword reaches the host.
    """

    def __init__(self, *, protocol_version: int = 2, knows_hello: bool | None = None, buffer_capacity: int = 64, sample_period_ns: int = 5_000_000,
                 clock: Callable[[], float] = time.monotonic, output: Callable[[bytes], object] | None = None,
                 lost_status_after_enable: int = 0, lost_device_info: int = 0,
                 lost_setpoints: tuple[int, ...] = (), watchdog_streaming_s: float = WATCHDOG_STREAMING_S,
                 watchdog_ticking_s: float = WATCHDOG_TICKING_S, boot_output: bytes = b"",
                 boot_fault_code: int | None = None, fault_clears: bool = True, fault_at_sample: int | None = None,
                 fault_code: int = 0x2310, fault_frame_lost: bool = False) -> None:
        self.protocol_version = protocol_version
        knows_hello = protocol_version >= 2 if knows_hello is None else knows_hello
        self._known_types = BODIES_V1 | ({HELLO: BODIES[HELLO]} if knows_hello else {})
        if protocol_version >= 2:
            self._known_types = BODIES
        self.buffer_capacity, self.sample_period_ns = buffer_capacity, sample_period_ns
        self._clock = clock
        self.state = SWITCH_ON_DISABLED
        self.error_code = 0
        if boot_fault_code is not None:
            self.state, self.error_code = FAULT_STATE, boot_fault_code
        self.fault_clears = fault_clears
        self.fault_at_sample, self.fault_code, self.fault_frame_lost = fault_at_sample, fault_code, fault_frame_lost
        self.lost_status_after_enable = lost_status_after_enable
        self._device_info_to_lose = lost_device_info
        self._setpoints_to_lose = set(lost_setpoints)
        self.boot_output = boot_output
        self.watchdog_streaming_s, self.watchdog_ticking_s = watchdog_streaming_s, watchdog_ticking_s
        self.target = self.actual = 0
        self.previous_controlword = 0
        self.last_applied_request = 0  # sections 6 and 16.3: CONTROL and START act once per number; 0 is none
        self.controlwords: list[int] = []  # applied
        self.requests: list[tuple[int, int]] = []  # (type, seq) received, repeats included
        self.feedback: dict[int, int] = {}  # v1: seq -> encoder_counts sent
        self.unprompted: list[int] = []  # statuswords sent with seq 0
        self.watchdog_expired = False
        # protocol v2 (section 16)
        self.mode = 1  # section 16.2: v1 until a HELLO is answered with 2, and again when the session ends
        self.sessions = 0  # v2 sessions started (START applied)
        self.ticks: dict[int, TickRecord] = {}  # tick number (unwrapped) -> the TICK sent
        self.dropped_setpoints: dict[int, str] = {}  # sample number -> "late" or "buffer full" (section 16.3)
        self._queue: dict[int, int] = {}  # tick number -> target_counts, at most buffer_capacity entries
        self._next_tick: int | None = None  # None: not ticking
        self._tick0_s = 0.0
        self._to_lose = 0
        self._watchdog_deadline: float | None = None
        self._streaming = False
        self._sent_anything = False
        self._buffer = bytearray()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = self._slave = -1
        if output is None:
            output = self._open_link()
            self._thread = threading.Thread(target=self._serve, name=f"spec-device-{id(self):x}", daemon=True)
        self._output = output

    def _open_link(self) -> Callable[[bytes], object]:
        """The pty the host opens (:attr:`port`); returns how the device writes to it."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        return lambda data: os.write(self._master, data)

    def _close_link(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    @property
    def period_s(self) -> float:
        return self.sample_period_ns * 1e-9

    def start(self) -> SpecSerialDevice:
        if self._thread is None:
            raise RuntimeError("a scripted SpecSerialDevice (output=...) has no thread: call feed() and run_due()")
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._close_link()

    def __enter__(self) -> SpecSerialDevice:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- time: everything due by the clock's now ------------------------------------------------------------------

    def feed(self, data: bytes) -> None:
        """Bytes from the host, received now (section 2's receiving rules), then whatever is due by now."""
        self._buffer += data
        while (end := self._buffer.find(0)) >= 0:
            chunk = bytes(self._buffer[:end])
            del self._buffer[:end + 1]
            message = parse(chunk, self._known_types) if chunk else None
            if message is not None:
                self._handle(*message)
        if len(self._buffer) > 128:
            self._buffer.clear()
        self.run_due()

    def run_due(self) -> None:
        """Ticks (section 16.3) and the link watchdog's expiry (section 10), in time order, up to now."""
        now = self._clock()
        while (when := self.next_event_s()) <= now:
            if self._watchdog_deadline is not None and self._watchdog_deadline <= when:
                self._watchdog_expires()
            else:
                self._tick()

    def next_event_s(self) -> float:
        """When the next tick or the link watchdog's expiry is due on the device's clock (inf: nothing)."""
        tick = self._tick0_s + self._next_tick * self.period_s if self._next_tick is not None else float("inf")
        watchdog = self._watchdog_deadline if self._watchdog_deadline is not None else float("inf")
        return min(tick, watchdog)

    def _serve(self) -> None:
        while not self._stop.is_set():
            timeout_s = min(0.01, max(0.0, self.next_event_s() - self._clock()))
            ready, _, _ = select.select([self._master], [], [], timeout_s)
            data = b""
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    return
            self.feed(data)

    # -- frames in and out -----------------------------------------------------------------------------------------

    def _send(self, kind: int, seq: int, *fields: int) -> None:
        """One message to the host, framed as section 2 says."""
        self._write(frame(kind, seq, *fields))

    def _write(self, data: bytes) -> None:
        if not self._sent_anything:
            data, self._sent_anything = self.boot_output + data, True
        self._output(data)

    def _statusword(self) -> int:
        word = self.state | REMOTE
        if self.state != SWITCH_ON_DISABLED:
            word |= VOLTAGE
        if self.state == OPERATION_ENABLED:
            word |= FOLLOWS_TARGET
        if self.state == QUICK_STOP_ACTIVE:
            word |= TARGET_REACHED  # the ideal drive is at rest at once
        return word

    def _status(self, seq: int) -> None:
        if self._to_lose:
            self._to_lose -= 1
            return
        self._send(STATUS, seq, self._statusword(), self.actual)

    def _handle(self, kind: int, seq: int, fields: tuple[int, ...]) -> None:
        if kind == SETPOINT and seq in self._setpoints_to_lose:
            self._setpoints_to_lose.discard(seq)  # lost on the line: the device never sees it
            return
        if self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) and self._watchdog_deadline is not None:
            self._restart_watchdog()  # section 10: every valid frame
        if kind == CONTROL:
            self.requests.append((kind, seq))
            if seq != self.last_applied_request:
                self.last_applied_request = seq
                self._apply(fields[0])
            self._status(seq)
        elif kind == STATUS_REQUEST:
            self.requests.append((kind, seq))
            self._status(seq)
        elif kind == ERROR_REQUEST:
            self.requests.append((kind, seq))
            self._send(ERROR, seq, self.error_code)
        elif kind == HELLO:
            self.requests.append((kind, seq))
            self._hello(seq, fields[0])
        elif kind == START:
            self.requests.append((kind, seq))
            self._start(seq)
        elif kind == SETPOINT and self.state == OPERATION_ENABLED:
            if self.mode >= 2:
                self._queue_setpoint(seq, fields[0])
            else:
                self._setpoint(seq, fields[0])

    def _restart_watchdog(self) -> None:
        if self.mode >= 2:  # section 16.4
            timeout_s = self.watchdog_ticking_s if self._next_tick is not None else WATCHDOG_BEFORE_FIRST_SETPOINT_S
        else:  # section 10
            timeout_s = self.watchdog_streaming_s if self._streaming else WATCHDOG_BEFORE_FIRST_SETPOINT_S
        self._watchdog_deadline = self._clock() + timeout_s

    # -- section 5: the state machine -----------------------------------------------------------------------------

    def _apply(self, controlword: int) -> None:
        self.controlwords.append(controlword)
        previous, self.previous_controlword = self.previous_controlword, controlword
        if self.state == FAULT_STATE:
            if controlword & 0x0080 and not previous & 0x0080 and self.fault_clears:
                self.state, self.error_code = SWITCH_ON_DISABLED, 0
            return
        next_state = TRANSITIONS.get((self.state, controlword), self.state)
        if next_state == OPERATION_ENABLED and self.state != OPERATION_ENABLED:
            self.target = self.actual  # section 5: no jump on enable
            self._to_lose = self.lost_status_after_enable
            self._streaming = False
            self.state = next_state
            self._restart_watchdog()  # section 10: armed on entering OPERATION ENABLED
            return
        if self.state == OPERATION_ENABLED and next_state != OPERATION_ENABLED:
            self._end_session()
        if next_state not in (OPERATION_ENABLED, QUICK_STOP_ACTIVE):
            self._watchdog_deadline = None
        self.state = next_state

    def _fault(self) -> None:
        """Section 9: the FAULT frame before any faulted statusword (the caller sends that one)."""
        self.state, self.error_code = FAULT_STATE, self.fault_code
        self._watchdog_deadline = None
        self._end_session()
        if not self.fault_frame_lost:
            self._send(FAULT, 0, self.fault_code)

    def _watchdog_expires(self) -> None:
        """Section 10 (and 16.4): quick stop, disable, unprompted STATUS with seq 0; the session ends."""
        self._watchdog_deadline = None
        self.watchdog_expired = True
        self._end_session()
        self.state = SWITCH_ON_DISABLED  # the ideal drive is at rest at once
        self.unprompted.append(self._statusword())
        self._send(STATUS, 0, self._statusword(), self.actual)

    # -- sections 8 (v1): one FEEDBACK per SETPOINT -----------------------------------------------------------------

    def _setpoint(self, seq: int, target: int) -> None:
        self._streaming = True
        if seq == self.fault_at_sample:
            self._fault()
            self._send(FEEDBACK, seq, self._statusword(), self.actual, (self.actual // 2) & 0xFFFF)
            return
        self.target = self.actual = target
        encoder = (self.actual // 2) & 0xFFFF  # unsigned 16-bit: zero-extended
        self.feedback[seq] = encoder
        self._send(FEEDBACK, seq, self._statusword() | TARGET_REACHED, self.actual, encoder)

    # -- section 16: protocol v2, the device owns the sample clock ----------------------------------------------

    def _hello(self, seq: int, host_version: int) -> None:
        """Section 16.2: the session's protocol := min(host's, device's), but never in OPERATION ENABLED."""
        if self.state != OPERATION_ENABLED:
            self.mode = max(1, min(host_version, self.protocol_version))
        if self._device_info_to_lose:
            self._device_info_to_lose -= 1
            return
        self._send(DEVICE_INFO, seq, self.mode, self.buffer_capacity, self.sample_period_ns)

    def _start(self, seq: int) -> None:
        """Section 16.3: in v2 mode, OPERATION ENABLED and not ticking, tick 0 is now; once per request number."""
        if seq != self.last_applied_request:
            self.last_applied_request = seq
            if self.mode >= 2 and self.state == OPERATION_ENABLED and self._next_tick is None:
                self._tick0_s, self._next_tick = self._clock(), 0
                self.sessions += 1
                self._restart_watchdog()  # the bound after START (section 16.4)
        self._status(seq)  # answered first; tick 0 follows (feed runs what is due after the frame)

    def _queue_setpoint(self, seq: int, target: int) -> None:
        """Section 16.3, queueing: seq unwrapped near the next tick; late ones and overflow are dropped."""
        next_tick = self._next_tick if self._next_tick is not None else 0
        k = next_tick + ((seq - next_tick + 0x8000) & 0xFFFF) - 0x8000
        if k < next_tick:
            self.dropped_setpoints[k] = "late"
        elif k not in self._queue and len(self._queue) >= self.buffer_capacity:
            self.dropped_setpoints[k] = "buffer full"
        else:
            self._queue[k] = target  # a second SETPOINT for a tick still buffered replaces the first

    def _tick(self) -> None:
        """Section 16.3, each tick k: apply setpoint k or hold (HELD), sample, send TICK k."""
        assert self._next_tick is not None
        k = self._next_tick
        self._next_tick = k + 1
        target = self._queue.pop(k, None)
        for stale in [tick for tick in self._queue if tick < k]:  # there should be none
            del self._queue[stale]
        held = target is None
        applied = self.target if held else target
        if k == self.fault_at_sample:  # the drive faults during this tick and does not move
            self._fault()
            statusword = self._statusword()
        else:
            self.target = self.actual = applied
            statusword = self._statusword() | TARGET_REACHED
        encoder = (self.actual // 2) & 0xFFFF  # as in FEEDBACK (section 4)
        record = TickRecord(statusword, self.actual, encoder, applied, held, len(self._queue))
        self.ticks[k] = record
        self._send(TICK, k & 0xFFFF, statusword, self.actual, encoder, applied,
                   TICK_HELD if held else 0, record.buffer_level)

    def _end_session(self) -> None:
        """Section 16.2: the tick clock stops, the buffer is emptied, the device is back in v1 mode."""
        self._next_tick = None
        self._queue.clear()
        self.mode = 1
