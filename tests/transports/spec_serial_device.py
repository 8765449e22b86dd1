"""A minimal serial rig device written only from ``docs/serial_protocol.md`` (its sections and tables are
cited), to keep the spec honest: it imports nothing from ``rig`` or ``sim_backend``.

Plant: the drive's actual position is its target (an ideal drive); the load encoder is an unsigned 16-bit
single-turn encoder geared 1:1 to the drive, read through a fixed gain: 2^17 drive counts per revolution,
2^16 encoder counts per revolution, so ``encoder = floor(actual / 2) mod 2^16``.
"""

from __future__ import annotations

import os
import select
import struct
import threading
import time
import tty

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


# -- section 3: messages --------------------------------------------------------------------------------------

SETPOINT, CONTROL, STATUS_REQUEST, ERROR_REQUEST = 0x01, 0x02, 0x03, 0x04
FEEDBACK, STATUS, FAULT, ERROR = 0x81, 0x82, 0x83, 0x84
BODIES = {SETPOINT: "<i", CONTROL: "<H", STATUS_REQUEST: "<", ERROR_REQUEST: "<",
          FEEDBACK: "<HiI", STATUS: "<Hi", FAULT: "<H", ERROR: "<H"}


def frame(kind: int, seq: int, *fields: int) -> bytes:
    payload = struct.pack("<BH", kind, seq) + struct.pack(BODIES[kind], *fields)
    return cobs_encode(payload + struct.pack("<H", crc16_ccitt_false(payload))) + b"\x00"


def parse(chunk: bytes) -> tuple[int, int, tuple[int, ...]] | None:
    raw = cobs_decode(chunk)
    if raw is None or len(raw) < 5:
        return None
    payload, (crc,) = raw[:-2], struct.unpack("<H", raw[-2:])
    if crc16_ccitt_false(payload) != crc:
        return None
    kind, seq = struct.unpack("<BH", payload[:3])
    if kind not in BODIES or len(payload) - 3 != struct.calcsize(BODIES[kind]):
        return None
    return kind, seq, struct.unpack(BODIES[kind], payload[3:])


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

WATCHDOG_BEFORE_FIRST_SETPOINT_S = 1.5  # section 10
WATCHDOG_STREAMING_S = 0.1


class SpecSerialDevice:
    """The device on a pty (:attr:`port`); ``start()`` / ``close()``, or use it as a context manager.

    Parameters
    ----------
    lost_status_after_enable
        This many STATUS answers from the transition to OPERATION ENABLED on are "lost on the line".
    boot_output
        Written before the first frame (section 11).
    boot_fault_code
        Boot in FAULT with this code; ``fault_clears`` says whether a fault reset clears it.
    fault_at_sample, fault_code, fault_frame_lost
        Fault while applying this SETPOINT (section 9); ``fault_frame_lost``: the FAULT frame is lost on
        the line, only the faulted statusword (in that sample's FEEDBACK) reaches the host.
    """

    def __init__(self, *, lost_status_after_enable: int = 0, boot_output: bytes = b"",
                 boot_fault_code: int | None = None, fault_clears: bool = True, fault_at_sample: int | None = None,
                 fault_code: int = 0x2310, fault_frame_lost: bool = False) -> None:
        self.state = SWITCH_ON_DISABLED
        self.error_code = 0
        if boot_fault_code is not None:
            self.state, self.error_code = FAULT_STATE, boot_fault_code
        self.fault_clears = fault_clears
        self.fault_at_sample, self.fault_code, self.fault_frame_lost = fault_at_sample, fault_code, fault_frame_lost
        self.lost_status_after_enable = lost_status_after_enable
        self.boot_output = boot_output
        self.target = self.actual = 0
        self.previous_controlword = 0
        self.last_control_seq = 0  # section 6: 0 is never a request number
        self.controlwords: list[int] = []  # applied
        self.requests: list[tuple[int, int]] = []  # (type, seq) received, repeats included
        self.feedback: dict[int, int] = {}  # seq -> encoder_counts sent
        self.unprompted: list[int] = []  # statuswords sent with seq 0
        self.watchdog_expired = False
        self._to_lose = 0
        self._watchdog_deadline: float | None = None
        self._streaming = False
        self._sent_anything = False
        self._buffer = bytearray()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="spec-serial-device", daemon=True)

    def start(self) -> SpecSerialDevice:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            os.close(fd)

    def __enter__(self) -> SpecSerialDevice:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- the loop ---------------------------------------------------------------------------------------------

    def _serve(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.01)
            if self._watchdog_deadline is not None and time.monotonic() > self._watchdog_deadline:
                self._watchdog_expires()
            if not ready:
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:
                return
            self._buffer += data
            while (end := self._buffer.find(0)) >= 0:
                chunk = bytes(self._buffer[:end])
                del self._buffer[:end + 1]
                message = parse(chunk) if chunk else None
                if message is not None:
                    self._handle(*message)
            if len(self._buffer) > 128:
                self._buffer.clear()

    def _write(self, data: bytes) -> None:
        if not self._sent_anything:
            data, self._sent_anything = self.boot_output + data, True
        os.write(self._master, data)

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
        self._write(frame(STATUS, seq, self._statusword(), self.actual))

    def _handle(self, kind: int, seq: int, fields: tuple[int, ...]) -> None:
        if self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) and self._watchdog_deadline is not None:
            self._watchdog_deadline = time.monotonic() + (
                WATCHDOG_STREAMING_S if self._streaming else WATCHDOG_BEFORE_FIRST_SETPOINT_S)
        if kind == CONTROL:
            self.requests.append((kind, seq))
            if seq != self.last_control_seq:
                self.last_control_seq = seq
                self._apply(fields[0])
            self._status(seq)
        elif kind == STATUS_REQUEST:
            self.requests.append((kind, seq))
            self._status(seq)
        elif kind == ERROR_REQUEST:
            self.requests.append((kind, seq))
            self._write(frame(ERROR, seq, self.error_code))
        elif kind == SETPOINT and self.state == OPERATION_ENABLED:
            self._setpoint(seq, fields[0])

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
            self._watchdog_deadline = time.monotonic() + WATCHDOG_BEFORE_FIRST_SETPOINT_S
        if next_state not in (OPERATION_ENABLED, QUICK_STOP_ACTIVE):
            self._watchdog_deadline = None
        self.state = next_state

    def _setpoint(self, seq: int, target: int) -> None:
        self._streaming = True
        if seq == self.fault_at_sample:
            self.state, self.error_code = FAULT_STATE, self.fault_code
            self._watchdog_deadline = None
            if not self.fault_frame_lost:
                self._write(frame(FAULT, 0, self.fault_code))  # section 9: before any faulted statusword
            self._write(frame(FEEDBACK, seq, self._statusword(), self.actual, (self.actual // 2) & 0xFFFF))
            return
        self.target = self.actual = target
        encoder = (self.actual // 2) & 0xFFFF  # unsigned 16-bit: zero-extended
        self.feedback[seq] = encoder
        self._write(frame(FEEDBACK, seq, self._statusword() | TARGET_REACHED, self.actual, encoder))

    def _watchdog_expires(self) -> None:
        """Section 10: quick stop, disable, unprompted STATUS with seq 0."""
        self._watchdog_deadline = None
        self.watchdog_expired = True
        self.state = SWITCH_ON_DISABLED  # the ideal drive is at rest at once
        self.unprompted.append(self._statusword())
        self._write(frame(STATUS, 0, self._statusword(), self.actual))
