"""The experiment runner: stream an excitation into the rig and account for every sample.

Two loops, chosen by the link (:attr:`~rig.transports.base.Transport.lead_samples`); both file feedback
by its sample number in one :class:`~rig.sample_ledger.SampleLedger`, which hands rows to the sink in
order once they can no longer change, and both run the transport's one bring-up and one teardown:

* **Device-clocked** (``lead_samples > 0``: CANopen, serial v2, raw CAN v2/v3): the device's clock owns the
  sample instants. The runner keeps the setpoints ``lead_samples`` ahead of the last instant the device
  passed and files what the device reports, taking turns (at most half the lead's setpoints queued, and
  answers filed, per turn: a device whose answers never stop coming still gets its setpoints); row k is at k T. A setpoint that missed its instant is HELD (the command logged is
  the one the drive applied), an instant off the period is LATE (:func:`_run_device_clocked`).
* **Host-paced** (serial and raw CAN, protocol v1): absolute deadlines ``t_k = t_0 + k T`` (no drift: a
  late cycle does not shift the ones after it). Per cycle k the runner waits for ``t_k``
  (:func:`wait_until`), sends setpoint k, and files the feedback that arrives until sample k is answered
  or ``t_{k+1}`` comes; behind schedule it catches up, sending setpoints no closer than half a period
  (:data:`CATCH_UP_SPACING`) and never closer than the bus time of one cycle (``Transport.min_cycle_s``).
  LATE: the cycle started more than ``late_tolerance_s`` after ``t_k``, or its feedback arrived after
  ``t_{k+1}``.

Both flag LOST (no feedback within ``pending_cycles`` cycles; angle NaN), DUPLICATE (a second answer for
one sample), FAULT, NOT_FOLLOWED (CiA 402 CSP statusword bit 12 clear) and AMBIGUOUS (which instant a
reading answers is uncertain). Safety: the transport is prepared (devices configured, the drive's actual
position read, nothing enabled), the command's first chunk is checked against the software limits starting
from that actual position, and only then is the drive enabled; the chunks after it are checked as the run
goes, each before any of its samples is sent (:class:`~rig.command_check.CheckedCommand`: one beyond a limit
ends the run); a feedback watchdog stops the run when nothing arrives for ``feedback_timeout_s``; any error,
device fault, refused chunk or Ctrl-C ends with the controlled stop (quick stop, then disable) and the log
closed, complete up to the stop.

The command is a :class:`~rig.command_source.CommandSource` produced as it is sent (an array is wrapped as
one), and nothing the runner keeps grows with the run's length (the ledger holds the rows not yet final, the
send lateness is summarised in bounded memory: :class:`SendLateness`), so a run of hours starts at once and
keeps flat memory.
"""

from __future__ import annotations

import contextlib
import gc
import math
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.result_format import check_kind, malformed, tagged
from rig.command_check import CheckedCommand, check_command  # noqa: F401 - (rig.runner.check_command, as before)
from rig.command_source import CommandSource, as_command_source
from rig.protocols.cia402 import DriveState
from rig.protocols.errors import DeviceFault, TransportError
from rig.sample_ledger import SampleLedger
from rig.transports.base import Setpoint, Transport

__all__ = ["RunSummary", "SampleSink", "SendLateness", "answer_window_cycles", "run_experiment",
           "send_lateness_quantiles", "wait_until"]


_FAULT_STATES = (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
WATCHDOG_GRACE = 0.5
"""How long, as a share of ``feedback_timeout_s``, the host goes on listening once the silence exceeds it
(:class:`FeedbackWatchdog`)."""
PENDING_CYCLES = 4
"""Feedback is still filed under its sample this many cycles after the sample was sent (at least; host-paced:
see :func:`answer_window_cycles`)."""
LATE_ANSWER_WINDOW_S = 0.02
"""Host-paced links file an answer (LATE) at least this long after its setpoint: on the 2-core test machine
with both cores busy, a v1 device's FEEDBACK reached the host 4-5 ms after its SETPOINT at 1 kHz (the device's
process descheduled), which a window of 4 periods wrote off as LOST although the device had sent it."""
CATCH_UP_SPACING = 0.5
"""Behind schedule, consecutive setpoints are still sent at least this many periods apart."""
WAKE_MARGIN_S = 300e-6
"""The loop sleeps until this long before a deadline, then polls: a sleeping thread wakes up to a few
hundred microseconds late (timer slack, a virtual machine's scheduler), a polling one within microseconds
(median send lateness 80 -> 30 us at 1 kHz on the 2-core CI host)."""


class FeedbackWatchdog:
    """Stops a run whose device has gone silent for ``timeout_s`` (``feedback_timeout_s``).

    The silence must also last while the host listens: once it exceeds ``timeout_s``, the host goes on
    listening for another :data:`WATCHDOG_GRACE` of it before giving up, so that a host that was itself
    paused (a garbage collection, a frozen or swapped-out process) first hears the answers that queued
    meanwhile, and a simulated device in the host's own process has a moment to catch up with its clock."""

    def __init__(self, timeout_s: float, now: float) -> None:
        self.timeout_s = float(timeout_s)
        self.last_feedback = now
        self._overdue_since: float | None = None

    def fed(self, now: float) -> None:
        """An answer came at ``now``."""
        self.last_feedback, self._overdue_since = now, None

    def expired(self, now: float) -> bool:
        """Whether the device has been silent for longer than the watchdog allows, as heard at ``now``."""
        if now - self.last_feedback <= self.timeout_s:
            return False
        if self._overdue_since is None:
            self._overdue_since = now
        return now - self._overdue_since > WATCHDOG_GRACE * self.timeout_s

    def message(self, transport_name: str, now: float) -> str:
        return (f"{transport_name}: no feedback for {now - self.last_feedback:.3g} s (watchdog "
                f"{self.timeout_s:g} s)")


def answer_window_cycles(sample_period_s: float, pending_cycles: int = PENDING_CYCLES) -> int:
    """Host-paced links: how many cycles after its setpoint an answer is still filed under its sample,
    ``max(pending_cycles, ceil(LATE_ANSWER_WINDOW_S / T))`` (4 periods at 200 Hz, 20 at 1 kHz;
    ``docs/serial_protocol.md`` section 8)."""
    return max(int(pending_cycles), math.ceil(LATE_ANSWER_WINDOW_S / sample_period_s - 1e-9))


def wait_until(deadline: float, clock: Callable[[], float] = time.perf_counter) -> None:
    """Return at ``clock() >= deadline``, within microseconds of it (see :data:`WAKE_MARGIN_S`)."""
    remaining = deadline - clock()
    if remaining > WAKE_MARGIN_S:
        time.sleep(remaining - WAKE_MARGIN_S)
    while clock() < deadline:
        time.sleep(0)  # releases the interpreter lock, so receive threads still run


@contextlib.contextmanager
def frozen_heap() -> Iterator[None]:
    """For the length of a run, the objects alive at its start (the imported modules, the transport, the
    command) sit in the garbage collector's permanent generation (:func:`gc.freeze`); :func:`gc.unfreeze` on
    exit returns them to the oldest generation (garbage among them is freed by a later collection).

    Without it a full (generation 2) collection during the run scans every one of them: about 120 000
    objects in the driver's process, 85 ms of CPU measured on the 2-core test machine, during which neither
    the runner nor a simulated device in the same process runs; with the core shared with another process
    that is the ~205 ms starvation that HELD a serial 2 kHz run (BENCHMARKS.md). Collections during
    the run then scan only the objects the run itself made."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


class SampleSink(Protocol):
    """Where samples go (:class:`rig.log_file.LogWriter` is one)."""

    def append(self, time_s: float, command_rad: float, angle_rad: float, encoder_counts: int | None = None,
               flags: int = 0) -> None: ...
    # from a link that reports the drive's torque (:attr:`rig.transports.base.Transport.drive_torque_unit`),
    # each row also comes with the keyword ``drive_torque`` (:meth:`rig.sample_ledger.SampleLedger.write_final`)

    def close(self) -> None: ...

    # optional: ``write_summary(mapping)`` is called once before ``close`` with what is known only at the end
    # (``frame_errors``, ``stop``); :class:`rig.log_file.LogWriter` writes it after the last sample.


@dataclass(frozen=True)
class RunSummary:
    """What a run did.

    Attributes
    ----------
    samples
        Samples written (sent setpoints).
    lost, late, duplicate, not_followed
        Samples with the LOST, LATE, DUPLICATE, NOT_FOLLOWED flag (a HELD sample is counted in ``held``, and in
        ``late`` only when it is flagged LATE too).
    stale
        Feedback frames that arrived after their sample was declared lost (dropped).
    frame_errors
        Damaged frames the transport discarded (CRC, COBS, unknown type).
    rate_hz
        Achieved rate: samples / (time of the last send - time of the first send) * (samples - 1) / samples.
    send_lateness_s
        Host-paced links: actual send time minus its deadline t_k (the loop's timing jitter) of the first
        :data:`SendLateness.EXACT_SAMPLES` samples (bounded: a run of hours does not keep one per sample; the
        quantiles below cover every sample); empty on device-clocked links, where the device's clock fixes the
        instants.
    cpu_s, wall_s
        Process CPU time and wall time of the streaming loop.
    not_followed
        Samples with the NOT_FOLLOWED flag.
    held
        Device-clocked links: samples whose setpoint missed its instant (HELD).
    min_lead_s
        Device-clocked links: the smallest lead of a setpoint over its sample instant (nan otherwise).
    stop
        What the controlled stop did (:class:`~rig.protocols.cia402.StopReport`, as text).
    warnings
        Device warnings ridden through (e.g. an encoder's temperature EMCY).
    log
        The log file the samples went to, when the caller knows it (the runner writes to a
        :class:`SampleSink`; ``rig run`` sets it with :func:`dataclasses.replace`).
    send_lateness_p50_s, send_lateness_p99_s, send_lateness_max_s
        Host-paced links: the median, 99th percentile and largest send lateness of every sample
        (:class:`SendLateness`: exact up to :data:`SendLateness.EXACT_SAMPLES` samples, then within 0.5 % from a
        fixed histogram; the largest always exact), what judges the host's timing (a LATE sample is one above
        ``late_tolerance_s``); nan on device-clocked links, judged by ``held`` and ``min_lead_s``.
    sync_jitter_max_s
        CANopen: the largest deviation of two SYNCs' spacing from the period while streaming (a SYNC from a
        thread of the host is late when the host is busy); nan on links without a SYNC.
    receive_drops
        CANopen: frames lost on receive (the interface's count of its receive queue's drops where it keeps one,
        udp_multicast and SocketCAN; else the master's own SYNCs and RPDOs whose echo never came). A loss stops
        the run: the samples from it on are AMBIGUOUS (:mod:`rig.transports.canopen_receive_checks`).

    The summary serialises itself (:meth:`to_dict`, :meth:`from_dict`; kind ``"run_summary"``, version 4,
    the conventions of :mod:`identify.result_format`): that document is what ``rig run --json`` prints.
    """

    samples: int
    lost: int
    late: int
    duplicate: int
    stale: int
    frame_errors: int
    rate_hz: float
    send_lateness_s: NDArray[np.float64] = field(compare=False)  # not saved (to_dict): == compares what is
    cpu_s: float
    wall_s: float
    not_followed: int = 0
    held: int = 0
    min_lead_s: float = math.nan
    stop: str = ""
    warnings: tuple[str, ...] = ()
    log: str | None = None
    send_lateness_p50_s: float = math.nan
    send_lateness_p99_s: float = math.nan
    send_lateness_max_s: float = math.nan
    sync_jitter_max_s: float = math.nan
    receive_drops: int = 0

    KIND: ClassVar[str] = "run_summary"
    VERSION: ClassVar[int] = 4
    READS: ClassVar[tuple[int, ...]] = (1, 2, 3, 4)
    """Versions :meth:`from_dict` reads: version 1 (before the send lateness was added) has no
    ``send_lateness_*`` keys, versions 1 and 2 no ``sync_jitter_max_s``: read as nan (not measured); versions
    1 to 3 no ``receive_drops``: read as 0 (not counted)."""
    SAVED: ClassVar[tuple[str, ...]] = (
        "samples", "lost", "late", "rate_hz", "held", "min_lead_s", "not_followed", "duplicate", "frame_errors",
        "warnings", "stop", "stale", "cpu_s", "wall_s", "send_lateness_p50_s", "send_lateness_p99_s",
        "send_lateness_max_s", "sync_jitter_max_s", "receive_drops")
    """The fields in the document after ``kind``, ``version`` and ``log``, in this order (the first twelve
    keys are those ``rig run --json`` always printed; version 2 added the next three, version 3
    ``sync_jitter_max_s``, version 4 ``receive_drops``)."""
    MAYBE_NAN: ClassVar[tuple[str, ...]] = ("min_lead_s", "send_lateness_p50_s", "send_lateness_p99_s",
                                            "send_lateness_max_s", "sync_jitter_max_s")
    """The times that are nan when the link does not measure them: null in the document."""

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    def to_pandas(self) -> Any:
        """The summary as a one-row ``pandas.DataFrame`` of :meth:`to_dict`'s values (``warnings`` joined by
        "; "). Needs pandas (not a dependency)."""
        from identify.result_format import require_pandas

        pandas = require_pandas("RunSummary.to_pandas()")
        values = self.to_dict()
        values["warnings"] = "; ".join(values.get("warnings") or ())
        return pandas.DataFrame([values])

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": "run_summary", "version": 4, "log": ..., "samples": ..., ...}`` (:attr:`SAVED`), plain
        JSON values: ``min_lead_s`` is null when the link is host-paced and the ``send_lateness_*`` when it is
        device-clocked (nan in the summary), ``warnings`` a list. The per-sample ``send_lateness_s`` is not
        written (it grows with the run: 8 bytes a sample); :meth:`from_dict` gives an empty array for it."""
        values: dict[str, Any] = {"log": self.log}
        for name in self.SAVED:
            value = getattr(self, name)
            if name in self.MAYBE_NAN:
                value = None if math.isnan(value) else float(value)
            elif name == "warnings":
                value = list(value)
            values[name] = value
        return tagged(self.KIND, self.VERSION, values)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunSummary:
        """Inverse of :meth:`to_dict`; a document of another kind or version is a ResultFormatError naming
        both, a missing or malformed key is one naming the key."""
        check_kind(data, cls.KIND, cls.READS)
        with malformed(cls.KIND):
            counts = {}
            for name in ("samples", "lost", "late", "held", "not_followed", "duplicate", "frame_errors", "stale",
                         "receive_drops"):
                if name == "receive_drops" and data["version"] < 4:
                    continue  # (not counted before version 4: the field's default, 0)
                value = data[name]
                if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                    raise ValueError(f"{name} is {value!r}, expected an integer >= 0")
                counts[name] = value
            seconds = {}
            added_in = {"send_lateness_p50_s": 2, "send_lateness_p99_s": 2, "send_lateness_max_s": 2,
                        "sync_jitter_max_s": 3}  # keys an earlier version lacks: nan, the fields' default
            for name in ("rate_hz", "cpu_s", "wall_s", "min_lead_s", *added_in):
                if data["version"] < added_in.get(name, 1):
                    continue
                value = data[name]
                if value is None and name in cls.MAYBE_NAN:
                    value = math.nan
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise ValueError(f"{name} is {value!r}, expected a number")
                seconds[name] = float(value)
            warnings = data["warnings"]
            if not isinstance(warnings, list) or not all(isinstance(w, str) for w in warnings):
                raise ValueError(f"warnings is {warnings!r}, expected a list of strings")
            stop, log = data["stop"], data["log"]
            if not isinstance(stop, str):
                raise ValueError(f"stop is {stop!r}, expected a string")
            if log is not None and not isinstance(log, str):
                raise ValueError(f"log is {log!r}, expected a path or null")
            return cls(**counts, **seconds, send_lateness_s=np.zeros(0), stop=stop, warnings=tuple(warnings),
                       log=log)


def send_lateness_quantiles(send_lateness_s: NDArray[np.float64]) -> dict[str, float]:
    """The median, 99th percentile and largest send lateness (``send_lateness_p50_s``, ``_p99_s``, ``_max_s``
    of :class:`RunSummary`; linear interpolation between samples, :func:`numpy.quantile`); nan for no
    sample."""
    if send_lateness_s.size == 0:
        return {"send_lateness_p50_s": math.nan, "send_lateness_p99_s": math.nan, "send_lateness_max_s": math.nan}
    p50, p99 = np.quantile(send_lateness_s, (0.5, 0.99))
    return {"send_lateness_p50_s": float(p50), "send_lateness_p99_s": float(p99),
            "send_lateness_max_s": float(np.max(send_lateness_s))}


class SendLateness:
    """The send lateness of a host-paced run (each setpoint's send time after its deadline), summarised in
    bounded memory whatever the run's length.

    The first :data:`EXACT_SAMPLES` values are kept: up to there the quantiles are exact
    (:func:`send_lateness_quantiles`). After that every value goes into a fixed histogram of :data:`BINS`
    bins whose edges grow by :data:`BIN_RATIO` from :data:`SMALLEST_S` (values below it share the first bin,
    values above :data:`LARGEST_S` the last): a quantile is then the geometric middle of its bin, within half
    a bin (0.5 %) of the exact one for lateness between 0.1 us and 100 s. The largest value, the first and
    the last are always exact."""

    EXACT_SAMPLES: ClassVar[int] = 1 << 16
    SMALLEST_S: ClassVar[float] = 1e-7
    LARGEST_S: ClassVar[float] = 100.0
    BIN_RATIO: ClassVar[float] = 1.01
    BINS: ClassVar[int] = math.ceil(math.log(LARGEST_S / SMALLEST_S) / math.log(BIN_RATIO)) + 1

    def __init__(self) -> None:
        self.count = 0
        self.first = self.last = math.nan
        self.max = -math.inf
        self._exact = np.empty(self.EXACT_SAMPLES)
        self._histogram: list[int] | None = None
        self._scale = 1.0 / math.log(self.BIN_RATIO)

    def add(self, lateness_s: float) -> None:
        if self.count < self.EXACT_SAMPLES:
            self._exact[self.count] = lateness_s
            if self.count == 0:
                self.first = lateness_s
        else:
            if self._histogram is None:
                self._histogram = [0] * self.BINS
                for value in self._exact.tolist():
                    self._histogram[self._bin(value)] += 1
            self._histogram[self._bin(lateness_s)] += 1
        self.count += 1
        self.last = lateness_s
        if lateness_s > self.max:
            self.max = lateness_s

    def _bin(self, value: float) -> int:
        if value <= self.SMALLEST_S:
            return 0
        return min(self.BINS - 1, 1 + int(math.log(value / self.SMALLEST_S) * self._scale))

    @property
    def kept(self) -> NDArray[np.float64]:
        """The values of the first :data:`EXACT_SAMPLES` samples (a copy)."""
        return self._exact[:min(self.count, self.EXACT_SAMPLES)].copy()

    def quantiles(self) -> dict[str, float]:
        """``send_lateness_p50_s``, ``_p99_s``, ``_max_s`` of every value added (nan for none)."""
        if self._histogram is None:
            return send_lateness_quantiles(self._exact[:self.count])
        cumulative = np.cumsum(self._histogram)
        out = {}
        for name, q in (("send_lateness_p50_s", 0.5), ("send_lateness_p99_s", 0.99)):
            index = int(np.searchsorted(cumulative, q * (self.count - 1) + 1))
            low = 0.0 if index == 0 else self.SMALLEST_S * self.BIN_RATIO ** (index - 1)
            high = self.SMALLEST_S * self.BIN_RATIO ** index
            out[name] = min(math.sqrt(low * high) if low > 0 else high / 2, self.max)
        out["send_lateness_max_s"] = float(self.max)
        return out


def _write_summary(sink: SampleSink, transport: Transport, failure: BaseException | None,
                   timing: Mapping[str, Any] | None = None) -> None:
    """Hand the sink what is known only at the end (``frame_errors``, ``stop``, the link's ``warnings`` (what it
    rode through or did without, e.g. a drive torque it could not map) and, once the run started, its ``timing``:
    ``sample_clock`` ``"host"`` with the send lateness quantiles, or ``"device"`` with ``min_lead_s``; nan as
    None), if it takes it."""
    write_summary = getattr(sink, "write_summary", None)
    if write_summary is None:
        return
    known = {name: None if isinstance(value, float) and math.isnan(value) else value
             for name, value in (timing or {}).items()}
    scale = transport.drive_torque_nm_per_unit  # for a log with the drive's torque: N m per unit of its column
    try:
        write_summary({"frame_errors": transport.frame_errors, "receive_drops": transport.receive_drops,
                       "stop": str(transport.stop_report or ""), "warnings": list(transport.warnings),
                       **({} if scale is None else {"drive_torque_nm_per_unit": scale}), **known})
    except Exception:
        if failure is None:
            raise  # otherwise what ended the run is the error to report, not this one


def _check_and_enable(transport: Transport, command: CheckedCommand) -> None:
    """After :meth:`Transport.prepare`: check the command's first chunk from the actual position, then enable.
    Homing can move the actual position after enabling: the first chunk is then checked again from there (a
    refusal stops the drive)."""
    checked_from = transport.initial_position_rad
    command.check_first()
    transport.enable()
    if transport.initial_position_rad != checked_from:
        command.recheck_first()


@frozen_heap()
def run_experiment(transport: Transport, command_rad: CommandSource | ArrayLike, sink: SampleSink, *,
                   feedback_timeout_s: float = 0.1, late_tolerance_s: float | None = None,
                   pending_cycles: int = PENDING_CYCLES,
                   progress: Callable[[int, int], None] | None = None,
                   clock: Callable[[], float] = time.perf_counter) -> RunSummary:
    """Open ``transport``, stream ``command_rad`` at its sample period into the rig, write every sample to
    ``sink``, and stop and close everything whatever happens (with the heap frozen: :func:`frozen_heap`).

    Parameters
    ----------
    transport
        A transport not yet opened; it is opened here and always closed (controlled stop first).
    command_rad
        The drive position targets, one per sample: a :class:`~rig.command_source.CommandSource` produced
        chunk by chunk as the run sends it (any length, or open-ended), or an array (wrapped as one).
    sink
        Receives one row per sample (time, command as sent, load angle, encoder counts, flags); always
        closed, also on error.
    feedback_timeout_s
        Watchdog: stop with :class:`TransportError` when no feedback arrives for this long, and for half
        as long again while the host listens (:class:`FeedbackWatchdog`).
    late_tolerance_s
        A cycle starting later than this after its deadline is LATE (default: half a period).
    pending_cycles
        Feedback is still filed under its sample (flagged LATE) up to this many cycles after the sample
        was sent (host-paced: at least :data:`LATE_ANSWER_WINDOW_S`, :func:`answer_window_cycles`); later,
        the sample is LOST. A simulated rig, whose devices share the driver's process and
        only stall with it, can afford a long window.
    progress
        Called as ``progress(samples_done, late_so_far)`` after each sample.

    Raises
    ------
    CommandRefused
        A command beyond the software limits: in its first chunk, the drive was never enabled; in a later
        one (checked ahead while the run goes), the run ends with the controlled stop before any sample of
        that chunk is sent, the log complete up to the stop.
    DeviceFault, TransportError
        The device faulted or the link failed; the log holds every sample up to the stop.
    """
    source = as_command_source(command_rad)
    try:
        # a link whose handshake decides who owns the sample clock (serial v2) knows lead_samples only now
        transport.prepare()
    except BaseException as err:
        try:
            transport.close()
            transport.note_stop(err)
            _write_summary(sink, transport, err)
        finally:
            sink.close()
        raise
    command = CheckedCommand(transport, source)
    if transport.lead_samples > 0:
        return _run_device_clocked(transport, command, sink, feedback_timeout_s=feedback_timeout_s,
                                   late_tolerance_s=0.5 * transport.sample_period_s if late_tolerance_s is None
                                   else float(late_tolerance_s),
                                   pending_cycles=pending_cycles, progress=progress, clock=clock)
    period = transport.sample_period_s
    tolerance = 0.5 * period if late_tolerance_s is None else float(late_tolerance_s)
    pending_cycles = answer_window_cycles(period, pending_cycles)
    ledger = SampleLedger(period, pending_cycles)
    lateness = SendLateness()
    cpu_start, wall_start = time.process_time(), clock()
    sent_count = 0
    failure: BaseException | None = None

    def take(sample) -> None:
        """File a feedback sample under its sample number; stop if the drive left OPERATION ENABLED."""
        now = clock()
        if ledger.awaits(sample.seq):
            watchdog.fed(now)
        state = ledger.file(sample, late=now > start + (sample.seq + 1) * period)  # after the next deadline
        if state is not None and state is not DriveState.OPERATION_ENABLED and state not in _FAULT_STATES:
            raise DeviceFault(f"{transport.name} drive", None, (
                f"left OPERATION ENABLED without a fault at sample {sample.seq} (now {state.name}: enable input "
                "or safe torque off lost?); it no longer follows the targets"))

    switch_interval = sys.getswitchinterval()
    # Receive threads (pyserial readers, python-can notifiers, simulated devices) need the GIL within a
    # fraction of a period, not after the default 5 ms.
    sys.setswitchinterval(min(switch_interval, period / 4))
    start = math.inf
    watchdog = FeedbackWatchdog(feedback_timeout_s, math.inf)
    try:
        _check_and_enable(transport, command)
        start = clock() + 2 * period
        catch_up_spacing = max(CATCH_UP_SPACING * period, transport.min_cycle_s)
        watchdog.fed(start)
        last_send = -math.inf
        k = 0
        while command.contains(k):
            value = command.value(k)  # checked (and the samples ahead checked a little further)
            command.release_below(k)
            deadline = start + k * period
            # behind schedule, catch up at most twice as fast: devices expect setpoints about a period
            # apart, not in a burst
            send_at = max(deadline, last_send + catch_up_spacing)
            now = clock()
            if send_at - now > 0:
                wait_until(send_at, clock)
                now = clock()
            last_send = now
            late_s = now - deadline
            lateness.add(late_s)
            if watchdog.expired(now):
                stale = ledger.counts["stale"]
                too_late = (f"; {stale} answers came more than {pending_cycles} cycles after their setpoint (a "
                            "device answering that late cannot be used at this rate)" if stale else "")
                raise TransportError(f"{watchdog.message(transport.name, now)}, stopping at sample {k}{too_late}")
            sent = transport.send(Setpoint(k, value))
            ledger.open_row(k, sent.position_rad, late=late_s > tolerance)
            sent_count += 1
            # Take what arrives until sample k is answered or the next deadline comes; when behind
            # schedule, only drain what is there, so that the loop catches up (answers of the last
            # pending_cycles samples are still filed when they come later).
            next_deadline = deadline + period
            while not ledger.answered(k):
                sample = transport.receive(max(next_deadline - clock(), 0.0))
                if sample is None:
                    break
                take(sample)
            ledger.write_final(k, sink)
            if progress is not None:
                progress(k + 1, ledger.counts["late"])
            k += 1
        grace_end = clock() + pending_cycles * period
        while len(ledger) and not ledger.all_answered and clock() < grace_end:
            sample = transport.receive(max(grace_end - clock(), 0.0))
            if sample is not None:
                take(sample)
    except BaseException as err:
        if isinstance(err, DeviceFault):
            ledger.mark_fault(ledger.last_opened)  # the drive did not follow this setpoint
        failure = err
        raise
    finally:
        sys.setswitchinterval(switch_interval)
        try:
            transport.close()
            if failure is not None:
                transport.note_stop(failure)
        finally:
            try:
                ledger.write_final(sent_count - 1 + pending_cycles, sink)
                quantiles = lateness.quantiles()
                _write_summary(sink, transport, failure, {"sample_clock": "host", **quantiles})
            finally:
                sink.close()
        transport.check_stopped(failure)  # the log is complete; a stop not confirmed outranks every other end
    counts = ledger.counts
    wall = clock() - wall_start
    rate = 0.0
    if sent_count > 1:
        rate = (sent_count - 1) / ((sent_count - 1) * period + lateness.last - lateness.first)
    return RunSummary(samples=sent_count, lost=counts["lost"], late=counts["late"], duplicate=counts["duplicate"],
                      stale=counts["stale"], frame_errors=transport.frame_errors, rate_hz=rate,
                      send_lateness_s=lateness.kept, cpu_s=time.process_time() - cpu_start, wall_s=wall,
                      not_followed=counts["not_followed"], stop=str(transport.stop_report or ""),
                      warnings=tuple(transport.warnings), **quantiles)


def _run_device_clocked(transport: Transport, command: CheckedCommand, sink: SampleSink, *,
                        feedback_timeout_s: float, late_tolerance_s: float, pending_cycles: int,
                        progress: Callable[[int, int], None] | None, clock: Callable[[], float]) -> RunSummary:
    """:func:`run_experiment` on a link whose device owns the sample clock (``lead_samples`` > 0).

    A producer and a consumer in one loop, neither of them timed by the host: setpoints are queued as far
    as ``transport.lead_samples`` ahead of the last sample instant the device passed
    (``transport.device_sample``), feedback is filed by its sample number (the
    instant; :class:`SampleLedger`), and rows go to the sink once final. Rows are sample instants: after a
    drive's interpolation buffer ran dry, its later records are applied at later instants, and each row
    logs the one really applied. Row k's time is the device's instant k T (a sample whose instant was
    off the period by more than ``late_tolerance_s`` is flagged LATE); a setpoint that missed its instant
    is logged HELD with the command really in force. A host stall shorter than the lead costs
    nothing; a longer one costs HELD samples, never lost ones. After a failure, the rows of every instant
    the device passed are written (up to the faulted sample for a device fault); setpoints queued for
    instants that never came are not samples and are not written.
    """
    period = transport.sample_period_s
    # the device, not the host, fixes each instant: a row can wait for an answer as long as the lead lasts
    # (an answer that a busy host reads late is still filed under its instant, never LOST)
    pending_cycles = max(pending_cycles, transport.lead_samples)
    ledger = SampleLedger(period, pending_cycles, late_tolerance_s,  # an open-ended command: once its end is known
                          **({} if command.total is None else {"num_samples": command.total}))
    cpu_start, wall_start = time.process_time(), clock()
    first_answer = last_answer = math.nan
    failure: BaseException | None = None

    next_seq = next_row = 0  # the next setpoint to queue; the next row (sample instant) to open
    filed_to = -1  # the highest instant whose answer was filed: rows before it are settled
    watchdog = FeedbackWatchdog(feedback_timeout_s, clock())

    def take(sample) -> DriveState | None:
        """File one answer; every instant the device passed has its row, setpoint or not (a drive's buffer
        that ran dry takes the later records at later instants), and the answer says what was applied."""
        nonlocal next_row, filed_to, first_answer, last_answer
        while next_row <= sample.seq and command.contains(next_row):
            ledger.open_row(next_row, transport.drive.quantize_rad(command.value(next_row)))
            next_row += 1
        state = ledger.file(sample)
        filed_to = max(filed_to, sample.seq)
        watchdog.fed(sample.host_time_s)  # when this answer was received, not when the turn began
        # (the device goes on answering after the run's last instant: not the run's rate)
        if command.total is None or sample.seq < command.total:
            last_answer = sample.host_time_s
            if math.isnan(first_answer):
                first_answer = last_answer
        return state

    def file_what_arrived() -> None:
        """After a failure (Ctrl-C, SIGTERM, a link error), before the stop: file the answers the transport
        has already received (a turn files at most a batch, and a fault is raised before the answers that
        came with it), so that no row whose answer came is written LOST. Best effort: a link error ends it."""
        known = command.total if command.total is not None else max(next_seq, next_row, transport.device_sample + 1)
        for _ in range(known + 2 * pending_cycles):
            try:
                sample = transport.receive_received()
            except Exception:  # noqa: BLE001 - the error that ended the run is the one to report
                return
            if sample is None:
                return
            try:
                take(sample)
            except Exception:  # noqa: BLE001 - a chunk of the command that cannot be read: the stop comes first
                return

    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(min(switch_interval, period / 4))  # receive threads need the GIL within a period
    try:
        _check_and_enable(transport, command)
        lead = transport.lead_samples
        batch = max(1, lead // 2)  # setpoints queued, answers filed per turn: the queue never falls more than
        # this behind, and neither side floods the link (a burst of frames overruns a CAN adapter's receive queue)
        watchdog.fed(clock())
        ended = False  # transport.end_of_stream() called
        while command.total is None or ledger.written < command.total:
            # turn 1: queue the setpoints due (as far as ``lead`` ahead of the last instant the device passed):
            # those of instants already passed (HELD; they keep the limits' chain and their rows) and, once the
            # device runs, at most ``batch`` ahead of it (the whole lead before its first answer)
            device = transport.device_sample
            last_to_queue = min(device + lead, max(next_seq - 1, device) + (batch if filed_to >= 0 else lead))
            while next_seq <= last_to_queue and command.contains(next_seq):
                sent = transport.send(Setpoint(next_seq, command.value(next_seq)))
                if next_seq == next_row:
                    ledger.open_row(next_row, sent.position_rad)
                    next_row += 1
                next_seq += 1
                if next_seq == command.total:
                    transport.end_of_stream()
                    ended = True
            if command.total is not None:
                ledger.num_samples = command.total  # (answers past the end belong to no sample of the run)
                if not ended and next_seq == command.total:  # an open-ended command whose end came just now
                    transport.end_of_stream()
                    ended = True
            command.release_below(min(next_seq, next_row))
            # turn 2: file at most ``batch`` answers, then queue again: a device whose answers never stop
            # coming (a host slower than the device's clock) still gets its setpoints
            sample = transport.receive(period)
            filed = 0
            while sample is not None:
                state = take(sample)
                if state is not None and state is not DriveState.OPERATION_ENABLED and state not in _FAULT_STATES:
                    raise DeviceFault(f"{transport.name} drive", None, (
                        f"left OPERATION ENABLED without a fault at sample {sample.seq} (now {state.name}: enable "
                        "input or safe torque off lost?); it no longer follows the targets"))
                filed += 1
                sample = transport.receive(0.0) if filed < batch else None
            now = clock()
            if watchdog.expired(now):
                raise TransportError(f"{watchdog.message(transport.name, now)}, stopping at sample "
                                     f"{max(transport.device_sample, 0)}")
            # final: the rows the device has passed whose answers, which come in order, are all filed (an
            # answer the transport still holds is never written off as LOST)
            ledger.write_final(min(device, filed_to), sink)
            if progress is not None:
                progress(ledger.written, ledger.counts["held"])
    except BaseException as err:
        failure = err
        raise
    finally:
        sys.setswitchinterval(switch_interval)
        if failure is not None and transport.is_open:
            file_what_arrived()
        stop_at = transport.device_sample  # the last instant the device passed before the stop
        try:
            transport.close()
            if failure is not None:
                transport.note_stop(failure)
        finally:
            try:
                if failure is not None:
                    last = stop_at
                    if isinstance(failure, DeviceFault):  # the instant the fault was seen is the last sample
                        faulted = [seq for seq in (ledger.first_fault, transport.fault_sample) if seq is not None]
                        last = min(faulted) if faulted else max(stop_at, 0)
                        ledger.mark_fault(last)
                    ledger.write_final(last + pending_cycles, sink)
                else:
                    assert command.total is not None  # the loop ends only at the command's end
                    ledger.write_final(command.total + pending_cycles, sink)
                timing = {"sample_clock": "device", "min_lead_s": transport.min_lead_s}
                _write_summary(sink, transport, failure, timing)
            finally:
                sink.close()
        transport.check_stopped(failure)  # the log is complete; a stop not confirmed outranks every other end
    answered = ledger.written - ledger.counts["lost"]
    rate = (answered - 1) / (last_answer - first_answer) if answered > 1 and last_answer > first_answer else 0.0
    held = ledger.counts["held"]
    return RunSummary(samples=ledger.written, lost=ledger.counts["lost"], late=ledger.counts["late"],
                      duplicate=ledger.counts["duplicate"],
                      stale=ledger.counts["stale"], frame_errors=transport.frame_errors, rate_hz=rate,
                      send_lateness_s=np.zeros(0), cpu_s=time.process_time() - cpu_start, wall_s=clock() - wall_start,
                      not_followed=ledger.counts["not_followed"], held=held, min_lead_s=transport.min_lead_s,
                      sync_jitter_max_s=transport.sync_jitter_max_s, receive_drops=transport.receive_drops,
                      stop=str(transport.stop_report or ""), warnings=tuple(transport.warnings))
