"""The rig-level transport interface: a setpoint out, a timestamped feedback sample back.

After python-can's ``can/bus.py``: the public behaviour (state checks, software limits, sequence
bookkeeping, timeouts, fault propagation, the one bring-up and the one teardown, idempotent stop and
close, context manager) is written once here; a backend implements a small seam:

``_connect()``
    Open the bus or port. Nothing is sent to the drive that could enable it.
``_prepare()``
    Configure the devices (PDOs, mode of operation, watchdogs) and make the drive's target equal to its
    actual position; return that actual position in radians. Still nothing that enables the drive.
``_write_controlword(controlword)``, ``_read_statusword()``
    One CiA 402 controlword to the drive (confirmed by the device), one statusword read. The base class
    walks the state machine with them (:func:`rig.protocols.cia402.bring_to_operation_enabled`) and
    stops with them (:func:`rig.protocols.cia402.quick_stop_then_disable`).
``_read_error_code()``
    The drive's error code (CiA 402 0x603F) for a message, or None where the link cannot read it.
``_after_enabled()``
    Anything that needs the drive enabled before streaming (homing); may return a new actual position.
``_before_stop()``
    Make the drive reachable for the stop's controlwords (CANopen: a node that went to NMT STOPPED on a
    fault answers no SDO until it is pre-operational again). Best effort.
``_stop_harder()``
    When the quick stop and disable did not leave the drive seen disabled: what more the link can do
    (CANopen: NMT stop, then NMT reset node). The run then ends with exit status 3 whatever follows.
``_release_devices()``
    After the stop: take the devices off the cyclic traffic (CANopen: NMT pre-operational). Best effort.
``_send(setpoint)``
    Put one setpoint on the wire (and, on CANopen, the SYNC that makes the devices sample).
``_recv_internal(timeout_s)``
    Return the next :class:`FeedbackSample` that arrived, or None after ``timeout_s``.
``_close()``
    Release the bus/port and every thread. Must be idempotent.

Bring-up is :meth:`Transport.prepare` (link up, devices configured, actual position read) then
:meth:`Transport.enable`; a caller checks its whole command against the actual position between the two,
so a refused experiment never enables the drive. Once the first enabling controlword has gone out, every
exit (an exception in the bring-up, in streaming, in the stop itself, a signal) runs the same teardown:
quick stop, then disable, then :meth:`_release_devices`, each step attempted even when an earlier one
failed; what it did (:class:`~rig.protocols.cia402.StopReport`) is attached to the exception that ended
the run as a note and kept in :attr:`Transport.stop_report`.

Backends report asynchronous device faults (EMCY, heartbeat loss, a FAULT frame) from their receive
threads with :meth:`Transport._report_fault`; the next :meth:`send`/:meth:`receive` raises them.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from rig.protocols import cia402
from rig.protocols.cia402 import BringUpTiming, DriveScaling, StopReport
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError, DriveMayBeEnabled, RigError, TransportError

logger = logging.getLogger(__name__)
"""Bring-up, stop, device warnings ridden through and damaged frames (``rig -v`` shows them; ``-vv`` the
damaged frames one by one)."""

__all__ = ["BringUpTiming", "CommandLimits", "CommandRefused", "DriveScaling", "FeedbackSample", "Setpoint",
           "Transport", "check_trace_path"]

TRACE_SUFFIXES = (".blf", ".asc", ".log", ".csv", ".trc")
CATCH_UP_FACTOR = 2.0
"""After a stall, a device-clocked link brings the target back to the plan at most this many times the plan's
own largest step per sample (:attr:`Transport.catch_up_step_rad`): fast enough to meet a plan moving at
its own top speed, never a jump the plan does not make."""


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
        The host's clock (:attr:`Transport.clock`, ``time.perf_counter()``) when the host received the sample.
    target_ignored
        The drive said it did not follow the target in this sample (CiA 402 cyclic synchronous position
        mode: statusword bit 12 clear in OPERATION ENABLED); the runner flags the sample NOT_FOLLOWED.
    held
        On a device-clocked link (:attr:`Transport.lead_samples` > 0): setpoint ``seq`` missed this
        sample's instant, and the device held an earlier one; the runner flags the sample HELD.
    applied_position_rad
        On a device-clocked link: the drive target actually in force at this sample's instant (equal to
        setpoint ``seq`` unless ``held``).
    ambiguous
        Which instant this reading answers is not certain (CANopen: its SYNC and the next came closer than
        the bus time of one cycle, so the answers may have been pushed behind the next SYNC); the runner
        flags the sample AMBIGUOUS (unusable) instead of filing it silently under a guess.
    instant_error_s
        On a device-clocked link: how far this sample's instant was off the period (its SYNC's spacing
        from the one before minus the period); the runner flags the sample LATE beyond its tolerance.
    limited
        On a device-clocked link: the host did not send the planned setpoint ``seq`` but one nearer the target
        in force before it (:meth:`Transport._toward_plan`, on the way back to the plan after a stall);
        ``applied_position_rad`` is what the drive took, and the runner flags the sample LIMITED.
    drive_torque
        The torque the drive reported at this sample's instant, in its own unit
        (:attr:`Transport.drive_torque_unit`), or None from a link that does not carry it.
    """

    seq: int
    encoder_counts: int
    load_angle_rad: float
    drive_position_rad: float
    statusword: int
    host_time_s: float
    target_ignored: bool = False
    held: bool = False
    applied_position_rad: float | None = None
    ambiguous: bool = False
    instant_error_s: float = 0.0
    limited: bool = False
    drive_torque: float | None = None


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
                f"the limit {self.rate_max_rad_per_s:.6g} rad/s ([limits] rate_max_rad_per_s): at "
                f"{1 / sample_period_s:g} Hz one step may be at most {self.rate_max_rad_per_s * sample_period_s:.4g} "
                "rad; narrow the experiment's range (a cyclic experiment jumps from u_max to u_min in one sample), "
                "or raise the limit if the drive can follow")


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
    timing
        Deadlines and pacing of the CiA 402 bring-up and stop (:class:`~rig.protocols.cia402.BringUpTiming`).
    name
        Label in messages and logs (e.g. the URL).
    clock
        The host's clock in seconds (:func:`time.perf_counter`); every timeout and timestamp of the link reads
        it. A scripted test passes a simulated clock that moves only when the host waits.

    Examples
    --------
    >>> with open_transport("serial:///dev/ttyUSB0", encoder=..., sample_period_s=1e-3) as link:  # doctest: +SKIP
    ...     link.prepare()                     # configured, actual position read, not enabled
    ...     link.enable()                      # OPERATION ENABLED at that position
    ...     sent = link.send(Setpoint(0, link.initial_position_rad))
    ...     sample = link.receive(timeout_s=0.01)
    """

    def __init__(self, *, encoder: EncoderResolution, sample_period_s: float, limits: CommandLimits | None = None,
                 drive: DriveScaling | None = None, timing: BringUpTiming | None = None, name: str = "",
                 clock: Callable[[], float] = time.perf_counter) -> None:
        if not isinstance(encoder, EncoderResolution):
            raise TypeError(f"encoder: expected an EncoderResolution, got {type(encoder).__name__}")
        if not (math.isfinite(sample_period_s) and sample_period_s > 0):
            raise ValueError(f"sample_period_s: expected a number > 0, got {sample_period_s!r}")
        self.encoder = encoder
        self.sample_period_s = float(sample_period_s)
        self.limits = limits or CommandLimits()
        self.drive = drive or DriveScaling()
        self.timing = timing or BringUpTiming()
        self.name = name or type(self).__name__
        self.clock = clock
        self.initial_position_rad = 0.0
        self.frame_errors = 0
        self.stop_report: StopReport | None = None
        # the command's largest step among the samples the runner has checked so far (it checks a chunk ahead
        # of those sent; catch_up_step_rad); inf until the runner's first check
        self.plan_step_rad = math.inf
        self.warnings: list[str] = []  # device warnings ridden through (e.g. an encoder's EMCY 0x4210)
        self._state = "closed"
        self._enabling_sent = False
        self._previous_rad = 0.0
        self._fault: RigError | None = None
        self._fault_lock = threading.Lock()
        self._last_angle_rad: float | None = None
        # a device-clocked backend keeps these up to date from what the device reports
        self._device_sample = -1
        self._min_lead_s = math.inf
        self._fault_sample: int | None = None

    # -- public behaviour, written once ------------------------------------------------------------------

    @property
    def min_cycle_s(self) -> float:
        """The shortest time between two setpoints the link carries: on CAN, the bus time of one cycle's
        frames (a SYNC sent sooner would overtake the previous cycle's answers, since it wins arbitration)."""
        return 0.0

    @property
    def drive_torque_unit(self) -> str | None:
        """The unit of :attr:`FeedbackSample.drive_torque` where this link may report the drive's torque (known
        before it opens, so that the log can give it a column), else None (the default)."""
        return None

    @property
    def drive_torque_nm_per_unit(self) -> float | None:
        """N m per unit of :attr:`FeedbackSample.drive_torque`, where the link learnt it at bring-up (a CiA 402
        drive's rated torque 0x6076), else None; the log's summary records it."""
        return None

    @property
    def lead_samples(self) -> int:
        """How many setpoints may be queued ahead of the device's own sample clock. 0 (the default): the
        link has no device clock, and the runner paces the samples from the host (one setpoint, one answer).
        A device-clocked link (CANopen with a cyclic SYNC) takes setpoints ahead and files each answer under
        the sample instant the device really used."""
        return 0

    @property
    def device_sample(self) -> int:
        """On a device-clocked link: the number of the last sample instant the device has passed (-1
        before the first)."""
        return self._device_sample

    @property
    def min_lead_s(self) -> float:
        """On a device-clocked link: the smallest time seen between a setpoint being queued and its sample
        instant (negative: a setpoint that came too late and was HELD); nan when none was measured."""
        return self._min_lead_s if math.isfinite(self._min_lead_s) else math.nan

    @property
    def catch_up_step_rad(self) -> float:
        """The largest step a device-clocked link lets the target make when it goes back to the plan after
        a stall held samples: the rate limit's step, and at most :data:`CATCH_UP_FACTOR` times the command's
        own largest step (:attr:`plan_step_rad`, set by the runner's check: that of the samples checked so
        far, which include every sample sent), so that a plan that moves smoothly is never met with a jump
        even where no rate limit is configured."""
        return min(self.limits.rate_max_rad_per_s * self.sample_period_s, CATCH_UP_FACTOR * self.plan_step_rad)

    def _toward_plan(self, plan_counts: int, lowest_counts: int, highest_counts: int | None = None) -> int:
        """The drive target (counts) to send instead of ``plan_counts`` when the target in force at the sample
        before is any of ``lowest_counts`` .. ``highest_counts`` (one target: ``highest_counts`` None): the one
        nearest the plan that is at most :attr:`catch_up_step_rad` (in whole counts, at least 1) from every one
        of them. The one rule of every device-clocked link's way back to the plan after a stall."""
        highest_counts = lowest_counts if highest_counts is None else highest_counts
        step_rad = self.catch_up_step_rad
        if not math.isfinite(step_rad):
            return plan_counts
        step = max(1, math.floor(step_rad * self.drive.counts_per_revolution / (2 * math.pi) + 1e-9))
        return min(max(plan_counts, highest_counts - step), lowest_counts + step)

    @property
    def sync_jitter_max_s(self) -> float:
        """On a link whose sample instants are a bus's SYNC: the largest deviation of two SYNCs' spacing from
        the sample period while streaming; nan where the link has no such clock."""
        return math.nan

    @property
    def receive_drops(self) -> int:
        """Frames the link lost on receive (a receive queue that overflowed), where it can tell; 0 otherwise."""
        return 0

    @property
    def fault_sample(self) -> int | None:
        """On a device-clocked link: the sample instant at which the device reported its fault (None: no
        fault, or not known)."""
        return self._fault_sample if self._fault_sample is None or self._fault_sample >= 0 else None

    @property
    def is_open(self) -> bool:
        return self._state == "open"

    @property
    def drive_label(self) -> str:
        """How messages name the drive (e.g. ``"canopen://socketcan/can0 drive 1"``)."""
        return f"{self.name} drive"

    def open(self) -> None:
        """Bring the rig up: :meth:`prepare`, then :meth:`enable`."""
        if self._state == "open":
            return
        if self._state == "closed":
            self.prepare()
        self.enable()

    def prepare(self) -> float:
        """Open the link, configure the devices and read the drive's actual position (also kept in
        :attr:`initial_position_rad`), with the drive's target set to it; the drive is not enabled yet.
        On failure everything started is closed again before the error propagates."""
        if self._state != "closed":
            raise TransportError(f"{self.name}: the transport is {self._state}; prepare() comes first, once")
        self._state = "preparing"
        self._enabling_sent, self.stop_report = False, None
        self._last_angle_rad = None  # the first reading of this run unwraps near 0 (_decode_encoder)
        logger.info("%s: connecting and configuring the devices", self.name)
        try:
            self._connect()
            self.initial_position_rad = float(self._prepare())
        except BaseException as err:
            self._teardown(err)
            raise
        self._previous_rad = self.initial_position_rad
        self._state = "prepared"
        logger.info("%s: prepared; the drive's actual position is %.9g rad", self.name, self.initial_position_rad)
        return self.initial_position_rad

    def enable(self) -> None:
        """Bring the drive to OPERATION ENABLED (at the position :meth:`prepare` read). From the first
        enabling controlword on, any failure ends in the teardown (quick stop, then disable) before the
        error propagates."""
        if self._state != "prepared":
            raise TransportError(f"{self.name}: the transport is {self._state}; call prepare() first")
        self._enabling_sent = True
        try:
            cia402.bring_to_operation_enabled(self._write_controlword, self._read_statusword, self.drive_label,
                                              timing=self.timing, read_fault_code=self._read_error_code,
                                              clock=self._pause_clock, sleep=self._pause)
            moved_to = self._after_enabled()
            if moved_to is not None:
                self.initial_position_rad = float(moved_to)
                self._previous_rad = self.initial_position_rad
        except BaseException as err:
            self._teardown(err)
            raise
        self._state = "open"
        logger.info("%s: OPERATION ENABLED at %.9g rad", self.drive_label, self.initial_position_rad)

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
        deadline = self.clock() + max(timeout_s, 0.0)
        while True:
            self.raise_fault()
            remaining = deadline - self.clock()
            sample = self._recv_internal(max(remaining, 0.0))
            if sample is not None:
                return sample
            if remaining <= 0:
                self.raise_fault()
                return None

    def stop(self) -> StopReport | None:
        """Controlled stop: quick stop, then disable (if the drive was ever sent an enabling controlword),
        then the devices released (:meth:`_release_devices`). Safe to call at any time, any number of
        times: it runs once per bring-up."""
        if self._enabling_sent and self.stop_report is None:
            self._state = "stopping"
            try:
                self._before_stop()
            except Exception:  # noqa: BLE001 - the stop is attempted anyway
                logger.debug("%s: before the stop", self.name, exc_info=True)
            report = cia402.quick_stop_then_disable(self._write_controlword, self._read_statusword,
                                                    timing=self.timing, clock=self._pause_clock, sleep=self._pause)
            self.stop_report = report if report.disabled else self._escalate_stop(report)
            logger.info("%s: %s", self.drive_label, self.stop_report)
            self._release()
            self._state = "stopped"
        elif self._state in ("preparing", "prepared"):
            self._release()
        return self.stop_report

    def _escalate_stop(self, report: StopReport) -> StopReport:
        """The quick stop and disable did not leave the drive seen disabled: take the further steps the link
        offers (:meth:`_stop_harder`), read the state again, and say so in the report (``escalated``: the run
        cannot end with exit status 0 whatever the drive says now)."""
        steps = list(report.steps)
        try:
            steps += self._stop_harder()
        except Exception as err:  # noqa: BLE001 - nothing more can be done; the report says so
            steps.append(f"escalation failed ({err})")
        final = None
        try:
            final = cia402.state_from_statusword(self._read_statusword())
        except Exception:  # noqa: BLE001 - a node that was reset or stopped may not answer
            logger.debug("%s: state after the escalated stop", self.name, exc_info=True)
        # what the drive said when the stop failed (what it says after a reset is in final_state)
        return StopReport(tuple(steps), final, report.final_state or report.last_seen, escalated=True)

    def check_stopped(self, cause: BaseException | None = None) -> None:
        """Raise :class:`~rig.protocols.errors.DriveMayBeEnabled` if the drive was enabled and its stop was
        not confirmed (:attr:`StopReport.confirmed`); ``cause`` is whatever else ended the run (chained, and
        named in the message after the warning)."""
        report = self.stop_report
        if report is None or report.confirmed:
            return
        last = report.last_seen or report.final_state
        raise DriveMayBeEnabled(self.drive_label, str(report),
                                None if last is None else last.name.replace("_", " "), cause) from cause

    def end_of_stream(self) -> None:
        """The runner has sent the run's last setpoint. A link that keeps its device's buffer from running
        dry may fill it now (CANopen interpolated position: hold records up to its capacity, so a host stall
        between the last sample and the stop cannot empty it); nothing on other links."""

    def close(self) -> None:
        """Stop if the drive was enabled, then release the link (idempotent)."""
        try:
            self.stop()
        finally:
            self._safe_close()

    def _release(self) -> None:
        try:
            self._release_devices()
        except Exception:  # noqa: BLE001 - best effort: the drive is already disabled or unreachable
            logger.debug("%s: releasing the devices", self.name, exc_info=True)

    def _teardown(self, err: BaseException) -> None:
        """The one exit path after a failure in the bring-up: stop (quick stop and disable if an enabling
        command went out), release the devices, close the link, and say on ``err`` what the stop did."""
        try:
            self.stop()
        finally:
            self._safe_close()
        self.note_stop(err)

    def note_stop(self, err: BaseException) -> None:
        """Attach what the controlled stop did to ``err`` (once), so that the message of whatever ended
        the run says it: ``"... drive 1: quick stop sent, then disable sent; ends SWITCH ON DISABLED"``."""
        if self.stop_report is None:
            return
        note = f"{self.drive_label}: {self.stop_report}"
        if note not in getattr(err, "__notes__", ()):
            err.add_note(note)

    def receive_received(self) -> FeedbackSample | None:
        """After a failure, before the stop: the next answer the link has already received, without raising
        the fault that ended the run (so that no row whose answer came is written LOST); None when there is
        none. Never waits, and never starts what the run had not started (interpolation, the device's clock)."""
        self._require_open()
        return self._received_without_starting()

    def _received_without_starting(self) -> FeedbackSample | None:
        """:meth:`receive_received` of a backend (the base has no receive queue of its own: nothing)."""
        return None

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

    def _samples_ahead(self, lead_s: float, capacity: int | None = None) -> int:
        """``lead_s`` in whole sample periods (at least 1), at most ``capacity`` (a device's buffer)."""
        lead = max(1, math.ceil(lead_s / self.sample_period_s - 1e-9))
        return lead if capacity is None else min(capacity, lead)

    def _report_fault(self, fault: RigError) -> None:
        """Record an asynchronous fault (first one wins); called from receive threads."""
        with self._fault_lock:
            if self._fault is None:
                self._fault = fault
        logger.debug("%s: reported: %s", self.name, fault)

    def _ride_through(self, warning: str) -> None:
        """A device warning that does not stop the run: kept in :attr:`warnings` (the run summary lists them)
        and logged."""
        self.warnings.append(warning)
        logger.info("%s: %s", self.name, warning)

    def _count_frame_errors(self, what: str, count: int = 1) -> None:
        """``count`` damaged frames discarded (:attr:`frame_errors`); ``what`` says which, for ``rig -vv``."""
        if count:
            self.frame_errors += count
            logger.debug("%s: %d damaged frame(s) discarded: %s", self.name, count, what)

    def _decode_encoder(self, counts: int) -> float:
        """Counts -> radians, continuous with the previous reading (the one conversion, in the codec).

        The first reading of a run has no previous one: it is taken as the equivalent angle nearest 0 rad
        (within R/2 of it, R the encoder's range :attr:`EncoderResolution.range_rad`), signed encoder or not,
        so a load standing just below zero reads a small negative angle, never one near R = 2 pi."""
        near = 0.0 if self._last_angle_rad is None else self._last_angle_rad
        angle = self.encoder.rad_from_counts(counts, near_rad=near)
        self._last_angle_rad = angle
        return angle

    def _require_open(self) -> None:
        if self._state != "open":
            raise TransportError(f"{self.name}: the transport is {self._state}; call open() first")

    def _safe_close(self) -> None:
        self._state = "closed"
        self._close()

    # -- the seam ----------------------------------------------------------------------------------------

    @abstractmethod
    def _connect(self) -> None: ...

    @abstractmethod
    def _prepare(self) -> float: ...

    @abstractmethod
    def _write_controlword(self, controlword: int) -> None: ...

    @abstractmethod
    def _read_statusword(self) -> int: ...

    def _read_error_code(self) -> int | None:
        return None

    def _after_enabled(self) -> float | None:
        return None

    def _pause(self, seconds: float) -> None:
        """The host waits ``seconds`` between the polls of the bring-up and the stop (a backend whose
        scripted tests run the devices on a simulated clock lets them live through the pause)."""
        time.sleep(seconds)

    def _pause_clock(self) -> float:
        """The clock the bring-up's and the stop's deadlines are read on: the one :meth:`_pause` lets pass."""
        return time.monotonic()

    def _before_stop(self) -> None:
        return None

    def _release_devices(self) -> None:
        return None

    def _stop_harder(self) -> list[str]:
        """After a quick stop and disable that did not leave the drive seen disabled: the further steps the
        link offers, one phrase each for the report (none on a link without them)."""
        return []

    @abstractmethod
    def _send(self, setpoint: Setpoint) -> None: ...

    @abstractmethod
    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None: ...

    @abstractmethod
    def _close(self) -> None: ...
