"""Turn a CAN trace of a rig run (BLF, ASC, TRC, candump ``.log``, python-can ``.csv``) into a rig log.

The trace is read with python-can's readers (``can.LogReader`` chooses by suffix) and decoded with the rig's
own codec, so a capture of CANalyzer, PCAN-View or ``candump`` on the rig's bus gives the log ``rig run`` would
have written, for raw-CAN (``can://``) and CANopen (``canopen://``) rigs. Every sample is accounted for.

Raw CAN (``configs/raw_can.dbc`` or the config's ``dbc``):

* sample k is the k-th RIG_SETPOINT (its ``seq``, unwrapped from 16 bits, must count up from the first one);
  ``time_s = k * sample_period_s`` and ``command_rad`` is its ``target_counts`` in radians (the drive's scaling),
  which is what the runner logs (the command as the drive receives it);
* its reading is the RIG_FEEDBACK + RIG_DRIVE_FEEDBACK (v1, v2) or RIG_DRIVE_TICK (v3) pair with the same
  ``seq``, decoded as the transport
  decodes it (signed counts, the angle continuous with the previous reading), filed as the runner files it:
  only while at most :func:`~rig.runner.answer_window_cycles` later setpoints have been sent (else it is stale
  and the sample LOST),
  a second copy marks DUPLICATE, a fault state in its statusword FAULT; a RIG_FAULT frame marks the sample
  of the last setpoint sent FAULT;
* LATE is judged from the trace's time stamps against the first setpoint's (``t0 + k T`` plus the config's
  ``late_tolerance_s`` for a setpoint; ``t0 + (k+1) T`` for its reading): the trace's clock, not the host's
  monotonic clock of the run, so a LATE flag near the tolerance may differ from the run's own log;
* protocols v2 and v3 (the device owns the clock: RIG_START, and a RIG_TICK_APPLIED or RIG_DRIVE_TICK with
  each tick): a setpoint's seq is its tick, every reading of a tick of the run is filed (no pending window:
  the device, not the host, decides the instant), the command logged is the target in force at the tick
  (v2: ``applied_counts``; v3: the setpoint of tick k - ``applied_age``, for 255 the target of the tick
  before, before any setpoint the ``actual_counts`` of the RIG_STATUS answering RIG_START, as the DBC says)
  and a HELD tick is flagged HELD; LATE is not judged (the ticks carry no instant of their own).

CANopen (SYNC + drive RPDO1 + TPDOs, the mapping :mod:`rig.transports.canopen_link` sets up: drive TPDO1
0x6041 + 0x6064 (+ the torque actual value 0x6077, where the trace's start-up mapped it: the log's
``drive_torque``) at 0x180 + node, drive TPDO2 0x6062 at 0x280 + node where the drive sends it, encoder TPDO1
0x6004 at 0x180 + node; node-IDs and TPDO latencies from the config), frames taken in time-stamp order:

* the streaming mode is the last value the master wrote to 0x6060 by SDO before the first RPDO1 (the
  trace's start-up; a trace that starts later takes the config's ``mode``, which must then not be
  ``"auto"``);
* cyclic synchronous position (8): sample 0's SYNC is the one after the first RPDO1; sample s's target is
  the RPDO1 sent after SYNC s - 1; the target in force at SYNC s is the last RPDO1 before it (HELD, with
  that command, when it is not sample s's own);
* interpolated position (7): RPDO1 k is setpoint k, a record into the drive's buffer, and RPDO2 a hold
  record (:mod:`rig.transports.interpolation_feed`); sample 0's SYNC is the one after the drive's answer to
  the SDO write of controlword bit 4 when that answer came before the next SYNC, otherwise the first after
  the first record whose drive statusword shows bit 12 (ip mode active); each SYNC from it takes the oldest
  record of the buffer (a hold record, or an empty buffer, holds the last one: HELD, with that command);
* each TPDO is filed under the last SYNC before its time stamp (minus its latency in cycles), as the
  transport files it; a complete set is the reading (DUPLICATE for a second one, AMBIGUOUS when SYNCs came
  closer than one cycle's bus time or the drive's 0x6062 is not the target in force, NOT_FOLLOWED, FAULT);
* LATE when a SYNC's spacing is off the period by more than ``late_tolerance_s``; these are the SYNCs'
  own time stamps, so the flags equal the run's;
* the samples run to the last RPDO1's (a run whose last setpoints were all HELD ends earlier), and a
  sample whose setpoint never reached the bus and that has no reading takes the previous command (the
  trace does not hold the value the host had queued); for the same reason a CSP target the master limited
  on its way back to the plan after a stall is logged with the value on the bus but not flagged LIMITED.

Both set the log's acquisition start (``acquisition_start_utc``) to the time stamp of sample 0's first frame
(the first setpoint; the SYNC of sample 0) where the trace's clock is the wall clock (:func:`_wall_clock`).

Error frames and malformed frames of ours are counted (``frame_errors`` in the summary) and ridden through, as
the transport does. A trace that cannot be read, or whose setpoints do not follow one another, raises
:class:`~rig.protocols.errors.LogFileError` naming the frame (its index in the trace and its time stamp).
"""

from __future__ import annotations

import collections
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from rig.protocols import cia402
from rig.protocols.cia402 import DriveState, state_from_statusword_or_none
from rig.protocols.errors import ConfigError, LogFileError
from rig.protocols.pdo_mapping import MappedObject, Pdo, PdoMapping, mapping_from_dcf, mapping_from_sdo_writes
from rig.protocols.serial_frames import unwrap_seq
from rig.runner import answer_window_cycles
from rig.signal_files import check_input_file

__all__ = ["TRACE_SUFFIXES", "import_trace"]

TRACE_SUFFIXES = (".blf", ".asc", ".trc", ".log", ".csv")
_FAULT_STATES = (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
_LOST, _LATE, _DUPLICATE, _FAULT, _HELD = (int(flag) for flag in (
    SampleFlag.LOST, SampleFlag.LATE, SampleFlag.DUPLICATE, SampleFlag.FAULT, SampleFlag.HELD))


def _frames(path: Path) -> Any:
    """``(index, message)`` of every frame of the trace; a frame the reader cannot parse raises an error naming it."""
    import can

    try:
        reader = can.LogReader(str(path))
    except (ValueError, NotImplementedError) as err:
        raise LogFileError(f"{path}: not a CAN trace python-can reads ({err}); expected "
                           f"{', '.join(TRACE_SUFFIXES)}") from None
    except Exception as err:  # a damaged header: BLFParseError, struct.error, UnicodeDecodeError ...
        raise LogFileError(f"{path}: cannot read the trace: {type(err).__name__}: {err}") from None
    index = -1
    try:
        with reader:
            for index, message in enumerate(reader):
                yield index, message
    except LogFileError:
        raise
    except Exception as err:
        raise LogFileError(f"{path}: frame {index + 1} (after the frame at index {index}) cannot be read: "
                           f"{type(err).__name__}: {err}; the trace is damaged") from None


def import_trace(trace: str | Path, config: Any, *, dcf: Mapping[int, str | Path] | None = None) -> ExperimentRecord:
    """The rig log of the run captured in ``trace`` on the rig of ``config`` (a loaded rig config); raw CAN
    or CANopen by the config's transport. ``dcf``: CANopen, the DCF (or EDS) file of each node by node-ID, whose
    PDO mapping decodes a trace that starts after the start-up's SDO writes."""
    path = check_input_file(trace, f"a CAN trace ({', '.join(TRACE_SUFFIXES)})")
    if path.suffix.lower() not in TRACE_SUFFIXES:
        raise LogFileError(f"{path}: unknown trace suffix {path.suffix or '(none)'!r}; expected "
                           f"{', '.join(TRACE_SUFFIXES)} (python-can's readers choose by suffix)")
    if config.scheme == "can":
        return _import_raw_can(path, config)
    if config.scheme == "canopen":
        return _import_canopen(path, config, dcf)
    raise ConfigError(config.source, "transport.url", f"the {config.scheme} transport has no CAN frames: a trace "
                      "is imported for can:// and canopen:// rigs")


class _Row:
    __slots__ = ("command_rad", "angle_rad", "counts", "flags", "drive_torque")

    def __init__(self, command_rad: float) -> None:
        self.command_rad, self.angle_rad, self.counts, self.flags = command_rad, math.nan, 0, _LOST
        self.drive_torque = math.nan


def _import_raw_can(path: Path, config: Any) -> ExperimentRecord:
    from rig.protocols.raw_can_frames import DEFAULT_DBC, RawCanCodec

    try:
        codec = RawCanCodec(config.options.get("dbc") or DEFAULT_DBC)
    except ValueError as err:
        raise ConfigError(config.source, "transport.dbc", str(err)) from err
    period, tolerance = config.sample_period_s, config.late_tolerance_s
    window = answer_window_cycles(period)
    encoder, drive = config.encoder, config.drive
    rows: list[_Row] = []
    received: set[int] = set()
    parts: dict[int, dict[str, Any]] = {}
    last_seq, first_seq, t0 = 0, None, None
    device_clocked = False  # protocol v2/v3: RIG_START / RIG_TICK_APPLIED / RIG_DRIVE_TICK seen
    sent_counts: list[int] = []  # row -> the target_counts of its RIG_SETPOINT
    start_seq, in_force = None, None  # v3: RIG_START's request number; (row, counts) of the target in force
    applied: dict[int, tuple[int | None, bool]] = {}  # v2/v3: row -> (target counts in force, HELD), first copy
    early: dict[int, list[tuple[float, int, int, float]]] = {}  # v2/v3: readings of ticks ahead of their setpoint
    last_angle: float | None = None
    frame_errors = frames = 0

    def file_reading(k: int, reading: tuple[float, int, int, float]) -> None:
        """Reading ``(angle, counts, statusword, time stamp)`` of sample k, filed as the runner files it."""
        angle, counts, statusword, stamp = reading
        row = rows[k]
        if k in received:
            row.flags |= _DUPLICATE
            return
        received.add(k)
        row.angle_rad, row.counts = angle, counts
        row.flags &= ~_LOST
        if state_from_statusword_or_none(statusword) in _FAULT_STATES:
            row.flags |= _FAULT
        if stamp - t0 > (k + 1) * period:
            row.flags |= _LATE

    for index, message in _frames(path):
        frames += 1
        if message.is_error_frame:
            frame_errors += 1
            continue
        try:
            decoded = codec.decode(message)
        except ValueError:
            frame_errors += 1  # a frame of ours with a wrong length: the transport rides through it too
            continue
        if decoded is None:
            continue
        name, signals = decoded
        where = f"frame {index} at {message.timestamp:.6f} s"
        if name == "RIG_SETPOINT":
            if first_seq is None:
                first_seq = last_seq = signals["seq"]
                t0 = message.timestamp
            else:
                seq = unwrap_seq(signals["seq"], last_seq)
                if seq != last_seq + 1:
                    raise LogFileError(
                        f"{path}: {where}: RIG_SETPOINT seq {signals['seq']} does not follow seq "
                        f"{last_seq & 0xFFFF} (expected {(last_seq + 1) & 0xFFFF}): the trace misses setpoints or holds "
                        "more than one run; cut it to one run (a run's setpoints count up by one)")
                last_seq = seq
            k = last_seq - first_seq
            row = _Row(drive.rad_from_counts(signals["target_counts"]))
            sent_counts.append(signals["target_counts"])
            if message.timestamp - t0 > k * period + tolerance:
                row.flags |= _LATE
            rows.append(row)
        elif name == "RIG_FAULT":
            if rows:
                rows[-1].flags |= _FAULT
        elif name == "RIG_START":
            device_clocked, start_seq = True, signals["seq"]
        elif name == "RIG_STATUS" and start_seq is not None and signals["seq"] == start_seq:
            in_force, start_seq = (-1, signals["actual_counts"]), None  # before any setpoint: the enable position
        elif name == "RIG_DRIVE_TICK" and first_seq is not None:
            device_clocked = True
            k = unwrap_seq(signals["seq"], last_seq) - first_seq
            age = signals["applied_age"]
            if age < 255:
                counts = sent_counts[k - age] if 0 <= k - age < len(sent_counts) else None
            else:  # 255: the target of the tick before, which the latest tick read (within 255) still had
                counts = in_force[1] if in_force is not None and in_force[0] >= k - 255 else None
            if counts is not None and (in_force is None or k > in_force[0]):
                in_force = (k, counts)
            applied.setdefault(k, (counts, age > 0))
        elif name == "RIG_TICK_APPLIED" and first_seq is not None:
            device_clocked = True
            k = unwrap_seq(signals["seq"], last_seq) - first_seq
            applied.setdefault(k, (signals["applied_counts"], bool(signals["tick_flags"] & 1)))
        if name in ("RIG_FEEDBACK", "RIG_DRIVE_FEEDBACK", "RIG_DRIVE_TICK") and first_seq is not None:
            seq = unwrap_seq(signals["seq"], last_seq)
            pair = parts.setdefault(seq, {})
            pair["RIG_FEEDBACK" if name == "RIG_FEEDBACK" else "drive"] = signals
            if len(pair) < 2:
                continue
            del parts[seq]
            raw = pair["RIG_FEEDBACK"]["encoder_counts"]
            counts = raw - (1 << 32) if encoder.signed and raw >= 1 << 31 else raw
            angle = encoder.rad_from_counts(counts, near_rad=0.0 if last_angle is None else last_angle)
            last_angle = angle
            k = seq - first_seq
            reading = (angle, counts, pair["RIG_FEEDBACK"]["statusword"], message.timestamp)
            if device_clocked and k >= len(rows):  # a tick (HELD) before its setpoint was sent, if it ever is
                early.setdefault(k, []).append(reading)
                continue
            if not 0 <= k < len(rows) or (not device_clocked and k < len(rows) - 1 - window):
                continue  # answers no setpoint of the run, or came after its sample was written (LOST)
            file_reading(k, reading)
    for k, readings in early.items():
        for reading in readings:
            if k < len(rows):
                file_reading(k, reading)
    for k, (counts, held) in applied.items():  # a HELD tick comes before its late setpoint (if that is sent)
        if 0 <= k < len(rows):
            if counts is not None:
                rows[k].command_rad = drive.rad_from_counts(counts)
            if held:
                rows[k].flags |= _HELD
    if frames == 0:
        raise LogFileError(f"{path}: no CAN frame could be read from it: the trace is empty, damaged, or not a "
                           f"{path.suffix} file (python-can's reader for {path.suffix} found nothing)")
    if not rows:
        raise LogFileError(f"{path}: no RIG_SETPOINT frame (0x{codec.frame_ids['RIG_SETPOINT']:03X}) in {frames} "
                           f"frames: not a capture of a run on the raw-CAN rig of {config.source}")
    from rig import __version__
    from rig.log_metadata import rig_config_metadata

    metadata = ExperimentMetadata(
        sample_period_s=period, source=config.name, transport=config.url, encoder_bits=encoder.bits,
        config={"rig": rig_config_metadata(config), "num_samples": len(rows)}, software_version=__version__,
        acquisition_start_utc=_wall_clock(t0),
        extra={"imported_from": {"trace": str(path), "frames": frames, "first_seq": first_seq},
               "summary": {"frame_errors": frame_errors}})
    n = len(rows)
    flags = np.array([row.flags & ~_LATE if device_clocked else row.flags for row in rows], dtype=np.uint8)
    return ExperimentRecord(time_s=np.arange(n) * period, command_rad=np.array([row.command_rad for row in rows]),
                            angle_rad=np.array([row.angle_rad for row in rows]),
                            encoder_counts=np.array([row.counts for row in rows], dtype=np.int64), flags=flags,
                            metadata=metadata)


def _streams_interpolated_position(path: Path, link: Any, mode_written: int | None, index: int,
                                   stamp: float) -> bool:
    """Whether the run the trace holds streamed interpolated position (7) or CSP (8): the 0x6060 the
    master wrote before its first RPDO1 (frame ``index``), else the config's ``mode``."""
    if mode_written == cia402.INTERPOLATED_POSITION_MODE:
        return True
    if mode_written == cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE:
        return False
    if mode_written is not None:
        raise LogFileError(f"{path}: frame {index} at {stamp:.6f} s: the drive streams in mode of operation "
                           f"{mode_written} (0x6060), neither interpolated position (7) nor CSP (8)")
    if link.mode_requested == "auto":
        raise LogFileError(f"{path}: frame {index} at {stamp:.6f} s is the first RPDO1, and the trace holds no "
                           "SDO write of 0x6060 before it (it starts after the start-up): it cannot tell "
                           "interpolated position from CSP; set mode = \"ip_buffer\" or \"csp\" in the "
                           "config's [transport]")
    return link.mode == "ip_buffer"


def _ip_origin(frames: list[tuple[float, int, Any]], sync_id: int, rpdo_id: int, drive_node: int,
               latency: int, status_pdo: Pdo) -> int | None:
    """The count of sample 0's SYNC in interpolated position, by the transport's rule: where the drive
    answered the SDO write of controlword bit 4 (enable ip mode) before a SYNC passed after the request, the
    SYNC after its answer (the bus order alone); otherwise the first SYNC after the first record whose drive
    statusword (TPDO1, filed as the transport files it, ``latency`` cycles back) shows bit 12 (ip mode
    active). None if there is neither."""
    syncs = first_record = 0
    enabled_at = answered_at = None
    for _, _, message in frames:
        cob, data = message.arbitration_id, bytes(message.data)
        if cob == sync_id:
            syncs += 1
        elif cob == rpdo_id and not first_record:
            first_record = syncs or -1
        elif cob == 0x600 + drive_node and first_record and enabled_at is None and _writes_ip_enable(data):
            enabled_at = syncs
        elif cob == 0x580 + drive_node and enabled_at is not None and answered_at is None:
            answered_at = syncs
            if answered_at == enabled_at:
                return answered_at + 1
        elif cob == status_pdo.cob_id and first_record:
            values = status_pdo.decode(data)
            answers = syncs - latency
            if values is not None and answers > max(first_record, 0) \
                    and values[STATUSWORD] & cia402.STATUSWORD_IP_MODE_ACTIVE:
                return answers
    return None


EARLIEST_WALL_CLOCK_S = 946684800.0  # 2000-01-01 UTC
"""Trace time stamps from this on are the wall clock (BLF, candump); smaller ones count from the start of the
trace (many ASC and TRC files), which says nothing of the date."""


def _wall_clock(stamp: float | None) -> str | None:
    """The UTC instant of a trace's time stamp, or None when it is not a wall-clock time."""
    from datetime import datetime, timezone

    from identify.experiment_record import utc_timestamp

    if stamp is None or not EARLIEST_WALL_CLOCK_S <= stamp < 1e11:
        return None
    return utc_timestamp(datetime.fromtimestamp(stamp, tz=timezone.utc))


def _signed32(raw: int) -> int:
    return raw - (1 << 32) if raw >= 1 << 31 else raw


def _writes_ip_enable(data: bytes) -> bool:
    """An expedited SDO download (CiA 301 7.2.4.3.3) of controlword 0x6040 sub 0 with bit 4 (enable ip mode)."""
    return (len(data) == 8 and data[0] & 0xE0 == 0x20 and data[1:4] == bytes((0x40, 0x60, 0))
            and int.from_bytes(data[4:6], "little") & 0x10 != 0)


STATUSWORD, POSITION_ACTUAL, POSITION_DEMAND, TARGET_POSITION = (0x6041, 0), (0x6064, 0), (0x6062, 0), (0x607A, 0)
INTERPOLATION_RECORD, ENCODER_POSITION, TORQUE_ACTUAL = (0x60C1, 1), (0x6004, 0), (0x6077, 0)
"""The objects the import reads (CiA 402: statusword, position actual value, position demand value, target
position, interpolation data record 1, torque actual value; CiA 406: position value)."""


def _our_mapping(drive_node: int, encoder_node: int) -> PdoMapping:
    """The PDOs :mod:`rig.transports.canopen_link` sets up: drive RPDO1 (the target, or the interpolation record)
    and RPDO2 (a hold record), drive TPDO1 0x6041 + 0x6064 and TPDO2 0x6062, encoder TPDO1 0x6004."""
    def pdo(node: int, receive: bool, number: int, *objects: tuple[int, int, int]) -> Pdo:
        cob_id = (0x200 if receive else 0x180) + 0x100 * (number - 1) + node
        return Pdo(node, receive, number, cob_id, tuple(MappedObject(*entry) for entry in objects))

    pdos = (pdo(drive_node, True, 1, (0x607A, 0, 32)), pdo(drive_node, True, 2, (0x60C1, 1, 32)),
            pdo(drive_node, False, 1, (0x6041, 0, 16), (0x6064, 0, 32)), pdo(drive_node, False, 2, (0x6062, 0, 32)),
            pdo(encoder_node, False, 1, (0x6004, 0, 32)))
    return PdoMapping({p.cob_id: p for p in pdos}, "the mapping this program's master sets up")


def _canopen_mapping(path: Path, frames: list[tuple[float, int, Any]], drive_node: int, encoder_node: int,
                     dcf: Mapping[int, str | Path] | None) -> PdoMapping:
    """The PDO mapping of the captured run: from the DCFs given, else from the SDO writes of the trace's
    start-up, else the one this program's master sets up."""
    if dcf:
        try:
            return mapping_from_dcf(dcf)
        except ValueError as err:
            raise LogFileError(str(err)) from None
    ours = _our_mapping(drive_node, encoder_node)
    written = mapping_from_sdo_writes(((message.arbitration_id, bytes(message.data)) for _, _, message in frames),
                                      f"the SDO writes in {path}")
    if written is None:
        return ours
    # a PDO the start-up did not configure keeps the mapping it had (this driver's, where its COB-ID is free)
    kept = {cob: pdo for cob, pdo in ours.pdos.items()
            if cob not in written.pdos and (pdo.node_id, pdo.receive, pdo.number) not in written.configured}
    return PdoMapping({**kept, **written.pdos}, written.source if not kept else
                      f"{written.source}, and this driver's mapping for the PDOs they leave alone",
                      written.configured)


def _import_canopen(path: Path, config: Any, dcf: Mapping[int, str | Path] | None = None) -> ExperimentRecord:
    """SYNC + the drive's target RPDO + TPDOs, decoded by the PDO mapping of the run (:func:`_canopen_mapping`:
    another master's too), each TPDO filed under the last SYNC before its time stamp, as
    :mod:`rig.transports.canopen_link` files them; frames are taken in time-stamp order."""
    from rig.transports import parse_transport_url, transport_class
    from rig.transports.canopen_sync import SYNC_COB_ID

    link = transport_class("canopen")(**parse_transport_url(config.url)[1], **config.transport_options())
    drive_node, encoder_node = link.drive_node_id, link.encoder_node_id
    sdo_request_id = 0x600 + drive_node
    period, tolerance = config.sample_period_s, config.late_tolerance_s
    encoder, drive = config.encoder, config.drive
    frames = sorted(((message.timestamp, index, message) for index, message in _frames(path)
                     if not message.is_error_frame), key=lambda item: (item[0], item[1]))
    mapping = _canopen_mapping(path, frames, drive_node, encoder_node, dcf)
    target_pdo = (mapping.carrying(drive_node, *TARGET_POSITION, receive=True)
                  or mapping.carrying(drive_node, *INTERPOLATION_RECORD, receive=True))
    status_pdo = mapping.carrying(drive_node, *STATUSWORD, receive=False)
    encoder_pdo = mapping.carrying(encoder_node, *ENCODER_POSITION, receive=False)
    for found, what in ((target_pdo, f"the target (0x607A or 0x60C1:01) to drive node {drive_node}"),
                        (status_pdo, f"the statusword 0x6041 of drive node {drive_node}"),
                        (encoder_pdo, f"the position value 0x6004 of encoder node {encoder_node}")):
        if found is None:
            raise LogFileError(f"{path}: no PDO carries {what} in {mapping.source}: give the node-IDs of the run in "
                               f"{config.source} ([transport] drive_node_id, encoder_node_id), or the nodes' DCF "
                               "files (rig import --dcf NODE=FILE)")
    assert target_pdo is not None and status_pdo is not None and encoder_pdo is not None
    hold_pdo = next((pdo for pdo in mapping.pdos.values() if pdo.node_id == drive_node and pdo.receive
                     and pdo is not target_pdo and any((e.index, e.subindex) == INTERPOLATION_RECORD
                                                       for e in pdo.objects)), None)
    rpdo_id, hold_id = target_pdo.cob_id, None if hold_pdo is None else hold_pdo.cob_id
    target_object = next((e.index, e.subindex) for e in target_pdo.objects
                         if (e.index, e.subindex) in (TARGET_POSITION, INTERPOLATION_RECORD))
    # the parts of a reading, by the PDO that carries each (a statusword and a position may share one)
    readings: dict[int, list[tuple[str, tuple[int, int]]]] = {}
    torque_pdo = mapping.carrying(drive_node, *TORQUE_ACTUAL, receive=False)
    for part, pdo, obj in (("status", status_pdo, STATUSWORD), ("encoder", encoder_pdo, ENCODER_POSITION),
                           ("demand", mapping.carrying(drive_node, *POSITION_DEMAND, receive=False), POSITION_DEMAND),
                           ("torque", torque_pdo, TORQUE_ACTUAL)):
        if pdo is not None:
            readings.setdefault(pdo.cob_id, []).append((part, obj))
    torque_bits = 0 if torque_pdo is None else next(entry.bits for entry in torque_pdo.objects
                                                    if (entry.index, entry.subindex) == TORQUE_ACTUAL)
    demand_pdo = mapping.carrying(drive_node, *POSITION_DEMAND, receive=False)
    frame_errors = 0
    has_demand = demand_pdo is not None and any(message.arbitration_id == demand_pdo.cob_id for _, _, message in frames)
    ip_origin = _ip_origin(frames, SYNC_COB_ID, rpdo_id, drive_node, link.latency_cycles["drive"], status_pdo)
    syncs: list[float] = []
    origin: int | None = None
    in_force: tuple[int, int] = (-1, 0)
    applied: dict[int, tuple[int, bool]] = {}
    instant_errors: dict[int, float] = {}
    ambiguous: set[int] = set()
    rpdos: list[tuple[int, int]] = []
    mode_written: int | None = None  # the last 0x6060 the master wrote by SDO before streaming
    interpolating = False  # interpolated position: the RPDOs are records into the drive's buffer
    buffer: collections.deque[tuple[int, int]] = collections.deque()
    unfiled: list[tuple[str, Any, float]] = []
    parts: dict[int, dict[str, Any]] = {}
    answers: dict[int, list[dict[str, Any]]] = {}
    last_angle: float | None = None

    def file(part: str, value: Any, stamp: float) -> None:
        nonlocal last_angle
        count = next((number for number in range(len(syncs), 0, -1) if syncs[number - 1] <= stamp), None)
        if count is None or origin is None:
            return
        latency = (link.demand_latency_cycles(interpolating) if part == "demand"
                   else link.latency_cycles["encoder" if part == "encoder" else "drive"])
        seq = count - latency - origin
        if seq < 0:
            return
        pair = parts.setdefault(seq, {})
        pair[part] = value
        if "status" in pair and "encoder" in pair and ("demand" in pair or not has_demand):
            angle = encoder.rad_from_counts(pair["encoder"], near_rad=0.0 if last_angle is None else last_angle)
            last_angle = angle
            answers.setdefault(seq, []).append({**pair, "angle": angle})

    for stamp, index, message in frames:
        cob = message.arbitration_id
        if cob == SYNC_COB_ID:
            syncs.append(stamp)
            count = len(syncs)
            if count > 1 and stamp - syncs[-2] < link.min_cycle_s:
                ambiguous.update((count - 1, count))
            pending, unfiled = unfiled, []
            for item in pending:
                if item[2] < stamp:
                    file(*item)
                else:
                    unfiled.append(item)
            if interpolating and origin is None and count == ip_origin:
                origin = count
            if origin is not None and count >= origin:
                sample = count - origin
                if interpolating:
                    record = buffer.popleft() if buffer else None
                    held = record is None or record[0] is None
                    in_force = in_force if record is None else (in_force[0] if held else record[0], record[1])
                else:
                    held = in_force[0] != sample
                applied[sample] = (in_force[1], held)
                if count > 1:
                    instant_errors[sample] = stamp - syncs[-2] - period
        elif cob == sdo_request_id and not rpdos:
            data = bytes(message.data)  # an expedited SDO download (CiA 301 7.2.4.3.3) of 0x6060 sub 0
            if len(data) == 8 and data[0] & 0xE0 == 0x20 and data[1:4] == bytes((0x60, 0x60, 0)):
                mode_written = int.from_bytes(data[4:5], "little", signed=True)
        elif cob == hold_id and interpolating:
            values = hold_pdo.decode(bytes(message.data)) if hold_pdo is not None else None
            if values is None:
                frame_errors += 1
                continue
            buffer.append((None, _signed32(values[INTERPOLATION_RECORD])))
        elif cob == rpdo_id:
            values = target_pdo.decode(bytes(message.data))
            if values is None:
                frame_errors += 1
                continue
            counts = _signed32(values[target_object])
            if not rpdos:
                interpolating = _streams_interpolated_position(path, link, mode_written, index, stamp)
            if interpolating:
                sample = len(rpdos)  # record k is setpoint k
                buffer.append((sample, counts))
            else:
                if origin is None:
                    origin = len(syncs) + 1
                sample = len(syncs) + 1 - origin  # put on the bus right after SYNC sample - 1
                in_force = (sample, counts)
            rpdos.append((sample, counts))
        elif cob in readings:
            values = mapping.pdos[cob].decode(bytes(message.data))
            if values is None:
                frame_errors += 1
                continue
            for part, obj in readings[cob]:
                raw = values[obj]
                if part == "demand":
                    value: Any = _signed32(raw)
                elif part == "encoder":
                    value = raw - (1 << 32) if encoder.signed and raw >= 1 << 31 else raw
                elif part == "torque":  # INTEGER16 (CiA 402)
                    value = raw - (1 << torque_bits) if raw >= 1 << (torque_bits - 1) else raw
                else:
                    value = raw
                unfiled.append((part, value, stamp))
    if origin is None:
        raise LogFileError(f"{path}: no {target_pdo.name} in {len(frames)} frames (the PDO that carries the drive's "
                           f"target in {mapping.source}): not a capture of a run on the CANopen rig of {config.source}")
    total = max(sample for sample, _ in rpdos) + 1
    targets: dict[int, int] = {}
    for sample, counts in rpdos:
        targets.setdefault(sample, counts)
    rows: list[_Row] = []
    for seq in range(total):
        command = drive.rad_from_counts(targets[seq]) if seq in targets else math.nan
        row = _Row(command)
        found = answers.get(seq, [])
        if found:
            answer = found[0]
            statusword = answer["status"]
            counts, held = applied.get(seq, (None, False))
            row.angle_rad, row.counts = answer["angle"], answer["encoder"]
            row.drive_torque = float(answer.get("torque", math.nan))
            row.flags &= ~_LOST
            if held:
                row.flags |= int(SampleFlag.HELD)
            if abs(instant_errors.get(seq, 0.0)) > tolerance:
                row.flags |= _LATE
            if counts is not None:
                row.command_rad = drive.rad_from_counts(counts)
            state = state_from_statusword_or_none(statusword)
            if state is DriveState.OPERATION_ENABLED and not statusword & (1 << 12):
                row.flags |= int(SampleFlag.NOT_FOLLOWED)
            if any(seq + origin + latency in ambiguous for latency in link.latency_cycles.values()) or (
                    "demand" in answer and counts is not None and answer["demand"] != counts):
                row.flags |= int(SampleFlag.AMBIGUOUS)
            if state in _FAULT_STATES or (state is not None and state is not DriveState.OPERATION_ENABLED):
                row.flags |= _FAULT
            if len(found) > 1:
                row.flags |= _DUPLICATE
        if math.isnan(row.command_rad):
            row.command_rad = rows[-1].command_rad if rows else 0.0
        rows.append(row)
    from rig import __version__
    from rig.log_metadata import rig_config_metadata

    metadata = ExperimentMetadata(
        sample_period_s=period, source=config.name, transport=config.url, encoder_bits=encoder.bits,
        config={"rig": rig_config_metadata(config), "num_samples": len(rows)}, software_version=__version__,
        acquisition_start_utc=_wall_clock(syncs[origin - 1] if origin <= len(syncs) else None),
        extra={"imported_from": {"trace": str(path), "frames": len(frames), "origin_sync": origin,
                                 "pdo_mapping": mapping.source},
               "summary": {"frame_errors": frame_errors},
               **({} if torque_pdo is None else {"drive_torque_unit": cia402.TORQUE_ACTUAL_UNIT})})
    n = len(rows)
    return ExperimentRecord(time_s=np.arange(n) * period, command_rad=np.array([row.command_rad for row in rows]),
                            angle_rad=np.array([row.angle_rad for row in rows]),
                            encoder_counts=np.array([row.counts for row in rows], dtype=np.int64),
                            flags=np.array([row.flags for row in rows], dtype=np.uint8), metadata=metadata,
                            drive_torque=None if torque_pdo is None else np.array([row.drive_torque for row in rows]))
