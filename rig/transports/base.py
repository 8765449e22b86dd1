"""The rig-level transport interface: a setpoint out, a timestamped feedback sample back.

After python-can's ``can/bus.py``: the public behaviour (state checks, software limits, sequence
bookkeeping, timeouts, fault propagation, idempotent stop and close, context manager) is written once
here; a backend implements a small seam:

``_open()``
    Bring the link and devices up and the drive to OPERATION ENABLED with its target at the actual
    position; return the drive's actual position in radians.
``_send(setpoint)``
    Put one setpoint on the wire (and, on CANopen, the SYNC that makes the devices sample).
``_recv_internal(timeout_s)``
    Return the next :class:`FeedbackSample` that arrived, or None after ``timeout_s``.
``_stop()``
    Controlled stop: quick stop, then disable. Must not raise for a link that is already gone.
``_close()``
    Release the bus/port and every thread. Must be idempotent.

Backends report asynchronous device faults (EMCY, heartbeat loss, a FAULT frame) from their receive
threads with :meth:`Transport._report_fault`; the next :meth:`send`/:meth:`receive` raises them.
"""

from __future__ import annotations

import math
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from rig.protocols.cia402 import DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError, RigError, TransportError

__all__ = ["CommandLimits", "CommandRefused", "DriveScaling", "FeedbackSample", "Setpoint", "Transport",
           "check_trace_path"]

TRACE_SUFFIXES = (".blf", ".asc", ".log", ".csv", ".trc")


def check_trace_path(path: str | None) -> str | None:
    """Validate a raw-frame trace file name for python-can's writers (by suffix). SqliteWriter (``.db``)
    is refused: it buffers in a thread and drops frames when the disk cannot keep up."""
    if path is None:
        return None
    suffix = Path(path).suffix.lower()
    if suffix not in TRACE_SUFFIXES:
        raise ConfigError("<transport>", "trace_path", f"{path}: expected a trace file ending in "
                                                       f"{', '.join(TRACE_SUFFIXES)} (not .db: SqliteWriter drops frames)")
    return str(path)


class CommandRefused(RigError, ValueError):
    """A setpoint beyond the configured software limits; it was not sent."""


@dataclass(frozen=True)
class Setpoint:
    """One position command for the drive.

    Attributes
    ----------
    seq
        Sample number (0, 1, 2, ...); the backend puts its low bits on the wire.
    position_rad
        Drive (motor shaft) position target in radians.
    """

    seq: int
    position_rad: float


@dataclass(frozen=True)
class FeedbackSample:
    """What the rig measured for one sample.

    Attributes
    ----------
    seq
        The sample number this feedback answers (unwrapped from the wire's sequence/SYNC counter).
    encoder_counts
        Load encoder position value as the device reports it.
    load_angle_rad
        ``encoder_counts`` in radians (:meth:`EncoderResolution.rad_from_counts`, continuous across wraps).
    drive_position_rad
        The drive's position actual value (0x6064) in radians.
    statusword
        The drive's CiA 402 statusword (0x6041).
    host_time_s
        ``time.perf_counter()`` when the host received the sample.
    """

    seq: int
    encoder_counts: int
    load_angle_rad: float
    drive_position_rad: float
    statusword: int
    host_time_s: float


@dataclass(frozen=True)
class CommandLimits:
    """Software limits on the drive command, checked before anything is sent.

    Attributes
    ----------
    position_min_rad, position_max_rad
        Allowed range of the position target.
    rate_max_rad_per_s
        Largest allowed |change of target| / sample period.
    """

    position_min_rad: float = -math.inf
    position_max_rad: float = math.inf
    rate_max_rad_per_s: float = math.inf

    def check(self, position_rad: float, previous_rad: float, sample_period_s: float, seq: int) -> None:
        """Raise :class:`CommandRefused` naming the sample if ``position_rad`` breaks a limit."""
        if not math.isfinite(position_rad):
            raise CommandRefused(f"setpoint {seq}: position {position_rad!r} rad is not finite")
        if not self.position_min_rad <= position_rad <= self.position_max_rad:
            raise CommandRefused(
                f"setpoint {seq}: position {position_rad:.6g} rad is outside the limits "
                f"[{self.position_min_rad:.6g}, {self.position_max_rad:.6g}] rad")
        rate = abs(position_rad - previous_rad) / sample_period_s
        if rate > self.rate_max_rad_per_s * (1 + 1e-12):
            raise CommandRefused(
                f"setpoint {seq}: rate {rate:.6g} rad/s (from {previous_rad:.6g} to {position_rad:.6g} rad) exceeds "
                f"the limit {self.rate_max_rad_per_s:.6g} rad/s")


class Transport(ABC):
    """A link to a rig: drive (setpoints) plus load encoder (feedback).

    Parameters
    ----------
    encoder
        Resolution and counting convention of the load encoder (decodes counts into radians).
    sample_period_s
        The rig's sample period (used by the rate limit).
    limits
        Software command limits; setpoints beyond them raise :class:`CommandRefused` and are not sent.
    drive
        Drive position scaling.
    name
        Label in messages and logs (e.g. the URL).

    Examples
    --------
    >>> with open_transport("serial:///dev/ttyUSB0", encoder=..., sample_period_s=1e-3) as link:  # doctest: +SKIP
    ...     link.open()
    ...     sent = link.send(Setpoint(0, link.initial_position_rad))
    ...     sample = link.receive(timeout_s=0.01)
    """

    def __init__(self, *, encoder: EncoderResolution, sample_period_s: float, limits: CommandLimits | None = None,
                 drive: DriveScaling | None = None, name: str = "") -> None:
        if not isinstance(encoder, EncoderResolution):
            raise TypeError(f"encoder: expected an EncoderResolution, got {type(encoder).__name__}")
        if not (math.isfinite(sample_period_s) and sample_period_s > 0):
            raise ValueError(f"sample_period_s: expected a number > 0, got {sample_period_s!r}")
        self.encoder = encoder
        self.sample_period_s = float(sample_period_s)
        self.limits = limits or CommandLimits()
        self.drive = drive or DriveScaling()
        self.name = name or type(self).__name__
        self.initial_position_rad = 0.0
        self.frame_errors = 0
        self._state = "closed"
        self._previous_rad = 0.0
        self._fault: RigError | None = None
        self._fault_lock = threading.Lock()
        self._last_angle_rad: float | None = None

    # -- public behaviour, written once ------------------------------------------------------------------

    @property
    def min_cycle_s(self) -> float:
        """The shortest time between two setpoints the link carries: on CAN, the bus time of one cycle's
        frames (a SYNC sent sooner would overtake the previous cycle's answers, since it wins arbitration)."""
        return 0.0

    @property
    def is_open(self) -> bool:
        return self._state == "open"

    def open(self) -> None:
        """Bring the rig up (drive in OPERATION ENABLED at its actual position). On failure everything
        already started is closed again before the error propagates."""
        if self._state == "open":
            return
        try:
            self.initial_position_rad = float(self._open())
        except BaseException:
            self._safe_close()
            raise
        self._previous_rad = self.initial_position_rad
        self._state = "open"

    def send(self, setpoint: Setpoint) -> Setpoint:
        """Check ``setpoint`` against the limits, send it, and return it as the drive receives it (its
        position quantised to drive counts)."""
        self._require_open()
        self.raise_fault()
        self.limits.check(setpoint.position_rad, self._previous_rad, self.sample_period_s, setpoint.seq)
        sent = Setpoint(setpoint.seq, self.drive.quantize_rad(setpoint.position_rad))
        self._send(sent)
        self._previous_rad = sent.position_rad
        return sent

    def receive(self, timeout_s: float) -> FeedbackSample | None:
        """The next feedback sample, or None if none arrives within ``timeout_s`` (>= 0)."""
        self._require_open()
        deadline = time.perf_counter() + max(timeout_s, 0.0)
        while True:
            self.raise_fault()
            remaining = deadline - time.perf_counter()
            sample = self._recv_internal(max(remaining, 0.0))
            if sample is not None:
                return sample
            if remaining <= 0:
                self.raise_fault()
                return None

    def stop(self) -> None:
        """Controlled stop (quick stop, then disable); safe to call at any time, any number of times."""
        if self._state == "open":
            self._state = "stopping"
            try:
                self._stop()
            finally:
                self._state = "stopped"

    def close(self) -> None:
        """Stop if running, then release the link (idempotent)."""
        try:
            self.stop()
        finally:
            self._safe_close()

    def raise_fault(self) -> None:
        """Raise the fault a device reported asynchronously, if any."""
        with self._fault_lock:
            fault = self._fault
        if fault is not None:
            raise fault

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()

    # -- helpers for backends ------------------------------------------------------------------------------

    def _report_fault(self, fault: RigError) -> None:
        """Record an asynchronous fault (first one wins); called from receive threads."""
        with self._fault_lock:
            if self._fault is None:
                self._fault = fault

    def _decode_encoder(self, counts: int) -> float:
        """Counts -> radians, continuous with the previous reading (the one conversion, in the codec)."""
        angle = self.encoder.rad_from_counts(counts, near_rad=self._last_angle_rad)
        self._last_angle_rad = angle
        return angle

    def _require_open(self) -> None:
        if self._state != "open":
            raise TransportError(f"{self.name}: the transport is {self._state}; call open() first")

    def _safe_close(self) -> None:
        if self._state != "closed":
            self._state = "closed"
        self._close()

    # -- the seam ----------------------------------------------------------------------------------------

    @abstractmethod
    def _open(self) -> float: ...

    @abstractmethod
    def _send(self, setpoint: Setpoint) -> None: ...

    @abstractmethod
    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None: ...

    @abstractmethod
    def _stop(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

