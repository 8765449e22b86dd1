"""The CANopen master's sample clock: SYNC, the targets put on the bus around it, and each TPDO filed under the
SYNC it answers (a mixin of :class:`rig.transports.canopen_link.CanOpenTransport`, whose ``__init__`` holds the
state it uses).

Streaming (the device's clock owns the sample instants): SYNC runs from a cyclic task at the sample period, from
configuration to the end of the stop (``_start_sync``), or from an external producer. The runner queues setpoints
``lead_s`` ahead (``_send``). In cyclic synchronous position, right after SYNC k-1 is seen the receive thread puts
target k on the bus (:meth:`_on_sync_echo`), so it is in force at SYNC k whatever the runner's thread does
meanwhile; in interpolated position (``mode``), the receive thread keeps the drive's buffer of records filled from
the queue at every SYNC (:mod:`rig.transports.canopen_interpolation`). The master receives its own frames back
(``receive_own_messages``, SocketCAN's echo of a transmitted frame), stamped by the same interface clock as the
TPDOs and in bus order, so it knows which target was last on the bus before each SYNC: a target that came too late
leaves its sample HELD with the command really applied. TPDOs carry no SYNC counter: each is filed under the last
SYNC before its bus timestamp once the next SYNC has been seen (the order around it is known only then), minus the
node's ``*_tpdo_latency_cycles``. The host's own clock never enters the filing. An interface that does not echo
transmitted frames is refused at start-up; a frame lost on receive (an own echo missing, the interface's drop count
rising) stops the run with the samples from it on AMBIGUOUS (:mod:`rig.transports.canopen_receive_checks`). A
second answer to one SYNC is reported again and the runner flags the sample DUPLICATE; two SYNCs closer than one
cycle's bus time flag their samples AMBIGUOUS.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from rig.protocols import cia402
from rig.protocols.errors import DeviceFault, TransportError
from rig.transports.base import FeedbackSample

__all__ = ["CanOpenSampleFiling", "LATENCY_EVIDENCE_SAMPLES", "LATENCY_UNCONFIRMED_HOLD_LEADS"]

LATENCY_EVIDENCE_SAMPLES = 3
"""Samples in a row whose 0x6062 is an earlier sample's target before the run stops for a wrong TPDO
latency: a wrong latency shows on every sample whose target changed, a target that crossed its SYNC on a
bus whose receivers see concurrent frames in different orders (python-can's virtual bus) on one."""

LATENCY_UNCONFIRMED_HOLD_LEADS = 0.5
"""How long, as a fraction of the lead, a row waits for a changed target to confirm the TPDO latency before it
is reported as filed: the lead is about the feedback watchdog's timeout, so half of it leaves the other half for
a busy host. A latency refuted later than that (a command at rest for longer at its start) leaves those first
rows filed under the configured latency, as every row was before this wait."""


class CanOpenSampleFiling:
    """The receive thread's side of streaming: the TPDOs decoded, the SYNC echoes counted into sample instants,
    the CSP targets put on the bus right after each SYNC, and every answer filed under its sample."""

    def _on_drive_tpdo(self, pdo: Any) -> None:
        layout = self._drive_tpdo
        try:
            statusword = layout.value(pdo.data, 0x6041)
            actual = layout.value(pdo.data, 0x6064, signed=True)
            torque = layout.value(pdo.data, 0x6077, signed=True) if 0x6077 in layout.fields else None
        except ValueError:
            self._count_frame_errors("drive TPDO shorter than its mapping")  # CiA 301: a PDO length error
            return
        self._file("drive", (statusword, actual, torque), pdo.timestamp)
        if self._watching and cia402.state_from_statusword_or_none(statusword) in (
                cia402.DriveState.FAULT, cia402.DriveState.FAULT_REACTION_ACTIVE):  # before: the bring-up's
            with self._arrived:
                if self._emcy is None:
                    self._emcy = ("drive", self.drive_node_id, 0)
                    self._fault_sample = self._device_sample
                self._arrived.notify_all()

    def _on_demand_tpdo(self, pdo: Any) -> None:
        try:
            demand = self._demand_tpdo.value(pdo.data, 0x6062, signed=True)
        except ValueError:
            self._count_frame_errors("demand TPDO shorter than its mapping")
            return
        self._file("demand", demand, pdo.timestamp)

    def _on_encoder_tpdo(self, pdo: Any) -> None:
        try:
            raw = self._encoder_tpdo.value(pdo.data, 0x6004)  # UNSIGNED32 (CiA 406)
        except ValueError:
            self._count_frame_errors("encoder TPDO shorter than its mapping")
            return
        bits = 8 * self._encoder_tpdo.fields[0x6004][1]
        counts = raw - (1 << bits) if self.encoder.signed and raw >= 1 << (bits - 1) else raw
        self._file("encoder", counts, pdo.timestamp)

    def _on_sync_echo(self, can_id: int, data: bytes, timestamp: float) -> None:
        """A SYNC on the bus (our own, echoed by the interface with its bus timestamp, or the external
        producer's): it is a sample instant. Here, in bus order:

        1. TPDOs stamped before it are filed under the last SYNC before them (minus ``tpdo_latency_cycles``);
        2. if it is sample s's SYNC, the target in force (the last RPDO the bus carried before it) is
           recorded: setpoint s, or an earlier one if s came too late (HELD);
        3. the target for the next SYNC goes on the bus now (if the runner has queued it)."""
        with self._arrived:
            self._echo_probe.set()
            self._check_drop_count()
            self._check_sync_spacing(timestamp)
            self._sync_count += 1
            count = self._sync_count
            if self._syncs and timestamp - self._syncs[-1][0] < self.min_cycle_s:
                # SYNCs bunched (a thread-based producer catching up): the higher-priority SYNC may have
                # overtaken the answers to the one before it, so neither sample can be filed for certain
                self._ambiguous.update((count - 1, count))
            self._syncs.append((timestamp, count))
            self._arrived.notify_all()  # (also wakes _await_syncs_in_operation)
            unfiled, self._unfiled = self._unfiled, []
            for item in unfiled:
                if item[2] < timestamp:
                    self._file_locked(*item)
                else:
                    self._unfiled.append(item)
            if self._feed is not None:
                if self._origin is None:
                    self._origin_from_the_answer(count)
                self._take_ip_record(count)
                self._put_records_on_bus()
            else:
                self._record_csp_target(count)
            if self._origin is not None and count >= self._origin:
                sample = count - self._origin
                if len(self._syncs) > 1:  # how far this instant is off the period (a thread-driven SYNC's jitter)
                    error = timestamp - self._syncs[-2][0] - self.sample_period_s
                    self._instant_errors[sample] = error
                    self._jitter_max_s = max(self._jitter_max_s, abs(error))
                self._device_sample = sample
                self._arrived.notify_all()
            if len(self._applied) > self.RECENT_SAMPLES:
                for old in sorted(self._applied)[:self.RECENT_SAMPLES // 2]:
                    del self._applied[old]
                    self._instant_errors.pop(old, None)
                self._ambiguous = {count for count in self._ambiguous if count > old + self._origin}

    def _record_csp_target(self, count: int) -> None:
        """CSP at SYNC ``count``: record the target in force (the last RPDO on the bus before it: setpoint
        s, or an earlier one if s came too late, HELD), then put the target for the next SYNC on the bus."""
        if self._origin is not None and count >= self._origin:
            sample = count - self._origin
            in_force_sample, counts = self._in_force
            ramped = sample in self._ramped
            self._ramped.discard(sample)
            held = in_force_sample != sample
            self._applied[sample] = (counts, held, ramped and not held)
            self._wait_for_rpdo_echo(sample, counts)  # a target due may have been in force: its echo tells
            queued = self._queued_at.pop(sample, None)
            if queued is not None:
                self._min_lead_s = min(self._min_lead_s, self.clock() - queued)
        if self._origin is None:
            if 0 in self._queue:
                self._origin = count + 1
                self._put_target_on_bus(0)
            return
        upcoming = count + 1 - self._origin
        for stale in [seq for seq in self._queue if seq < upcoming]:  # came after their SYNC: HELD
            del self._queue[stale]
        if upcoming in self._queue:
            self._put_target_on_bus(upcoming)

    def _put_target_on_bus(self, sample: int) -> None:
        """CSP: target ``sample`` onto the bus, no farther than :attr:`catch_up_step_rad` (the rate limit's
        step, and twice the plan's own largest) from any target the drive can have in force when it takes
        this one: the one in force at the SYNC just seen, and those sent since (echo due): after a stall
        that held samples the plan may have moved on, and the targets ramp back to it, each of those samples
        LIMITED with the target really applied (as on every device-clocked wire, :meth:`_toward_plan`)."""
        planned = self._queue.pop(sample)
        # the drive steps from the target in force at the SYNC just seen to this one, or, if this one comes
        # late, to a target sent before it whose echo is still due: limited from all of them (after a stall
        # the master may answer several old SYNCs in a row, each target late, the drive taking only the last)
        possible = [self._in_force[1], *(counts for _, counts in self._rpdo_sent)]
        counts = self._toward_plan(planned, min(possible), max(possible))
        if counts != planned:
            self._ramped.add(sample)
        self._rpdo_sent.append((sample, counts))
        data = self._rpdo.pack({index: counts for index in self._rpdo.fields})
        own = self._own_rpdo_sent(self._rpdo.cob_id, data)
        try:
            self.network.send_message(self._rpdo.cob_id, data)
        except Exception as err:  # noqa: BLE001 - in the notifier thread: report, the runner raises it
            self._own_rpdo_unsent(own)
            self._rpdo_sent.pop()
            self._report_fault(TransportError(f"{self.name}: sending the target of sample {sample} failed: {err}"))

    def _on_rpdo_echo(self, can_id: int, data: bytes, timestamp: float) -> None:
        """Our own RPDO back from the interface: CSP: from here on, until the next one, this target is in
        force; interpolated position: this record is in the drive's buffer now."""
        with self._arrived:
            self._own_rpdo_echoed(can_id, data)  # (a loss stops the run: the rows from it on are flagged)
            if self._feed is not None:
                self._feed.echoed()
                self._arrived.notify_all()  # (wakes _recv_internal waiting to start the interpolation)
            elif self._rpdo_sent:
                self._in_force = self._rpdo_sent.popleft()

    def _sync_before(self, timestamp: float) -> int | None:
        """The count of the last SYNC on the bus before bus time ``timestamp`` (None: before the first)."""
        for bus_time, count in reversed(self._syncs):
            if bus_time <= timestamp:
                return count
        return None

    def _file(self, part: str, value: Any, timestamp: float) -> None:
        """A TPDO waits until the SYNC after it has been seen: only then is the bus order around it known
        (a device can answer before the interface hands the master the echo of the SYNC it answers)."""
        with self._arrived:
            self._unfiled.append((part, value, timestamp, self.clock()))

    def _file_locked(self, part: str, value: Any, timestamp: float, received: float) -> None:
        """File one TPDO under the sample of the SYNC it answers."""
        count = self._sync_before(timestamp)
        if (count is not None and self._origin is None and self._ip_enabled_at is not None
                and self._find_ip_origin(part, value, timestamp, received, count - self.latency_cycles[part])):
            return  # kept until sample 0 is known
        if count is None or self._origin is None:
            return  # before streaming (the drive's TPDOs run from NMT operational on)
        seq = count - self.latency_cycles[part] - self._origin
        if seq < 0:
            return
        parts = self._parts.setdefault(seq, {})
        parts[part] = value
        # complete: report the sample; a node answering the same SYNC again (a repeated frame, or a frame
        # delayed past the next SYNC and filed there) reports it again, and the runner flags it DUPLICATE
        if "drive" in parts and "encoder" in parts and ("demand" in parts or self._demand_tpdo is None):
            statusword, actual, torque = parts["drive"]
            counts, held, limited = self._applied.get(seq, (None, False, False))
            ambiguous = (bool(self._ambiguous)
                         and any(seq + self._origin + latency in self._ambiguous for latency in self.latency_cycles.values()))
            if "demand" in parts and counts is not None:
                mismatch = parts["demand"] != counts
                ambiguous = ambiguous or mismatch
                self._check_latency(seq, parts["demand"] if mismatch else None)
            self._report_once_filed_right(FeedbackSample(
                seq=seq, encoder_counts=parts["encoder"], load_angle_rad=self._decode_encoder(parts["encoder"]),
                drive_position_rad=self.drive.rad_from_counts(actual), statusword=statusword,
                host_time_s=received, target_ignored=self._target_ignored(statusword), held=held, limited=limited,
                applied_position_rad=None if counts is None else self.drive.rad_from_counts(counts),
                ambiguous=ambiguous, instant_error_s=self._instant_errors.get(seq, 0.0), drive_torque=torque))
        if len(self._parts) > 512:
            for old in sorted(self._parts)[:256]:
                del self._parts[old]

    def _report_once_filed_right(self, sample: FeedbackSample) -> None:
        """Report ``sample`` once the drive's 0x6062 has had the chance to show whether the configured latency
        files its answers under the right SYNC. Before a changed target has come back at its own sample, a row
        at rest reads the same whichever SYNC it answers, so the rows wait (in order) for the evidence:
        AMBIGUOUS once the latency is refuted or the run fails; released as they are once a changed target came
        back in time, or when a row has waited :data:`LATENCY_UNCONFIRMED_HOLD_LEADS` of the lead (the
        runner's feedback watchdog counts rows handed out, so a row cannot wait longer). Without a mapped
        0x6062 nothing can tell, and every row is reported at once."""
        if self._filed_right is not None or self._demand_tpdo is None:
            self._report(sample if self._filed_right is not False else dataclasses.replace(sample, ambiguous=True))
            return
        self._unconfirmed.append(sample)
        hold = max(1, int(LATENCY_UNCONFIRMED_HOLD_LEADS * self.lead_samples))
        while self._unconfirmed and self._unconfirmed[0].seq <= sample.seq - hold:
            self._report(self._unconfirmed.popleft())

    def _release_unconfirmed(self, *, filed_right: bool) -> None:
        """The latency confirmed (``filed_right``) or refuted: the rows waiting for the evidence go to the
        runner, as they are or AMBIGUOUS."""
        self._filed_right = filed_right
        while self._unconfirmed:
            sample = self._unconfirmed.popleft()
            self._report(sample if filed_right else dataclasses.replace(sample, ambiguous=True))

    def _check_latency(self, seq: int, demand: int | None) -> None:
        """Compare the drive's 0x6062 for sample ``seq`` with the target in force at its SYNC (``demand``
        None: they agree). A demand that is an earlier sample's target is evidence that the drive answers
        later than ``drive_tpdo_latency_cycles`` says; a wrong latency shows on every sample whose target
        changed, so after :data:`LATENCY_EVIDENCE_SAMPLES` such samples in a row the run stops saying what
        to set. A single mismatch (a target that reached the drive on the other side of its SYNC than the
        echoes say) only makes that sample AMBIGUOUS. The first changed target that comes back at its own
        sample confirms the latency (:meth:`_report_once_filed_right`)."""
        counts = self._applied[seq][0]
        if demand is None:
            if self._applied.get(seq - 1, (counts,))[0] != counts:
                self._latency_evidence = 0  # a changed target the drive reported in time
                if self._filed_right is None:
                    self._release_unconfirmed(filed_right=True)
            return
        for late in range(1, 4):
            earlier = self._applied.get(seq - late)
            if earlier is not None and earlier[0] == demand and earlier[0] != counts:
                self._latency_evidence += 1
                if self._latency_evidence < LATENCY_EVIDENCE_SAMPLES:
                    return
                configured = self.latency_cycles["drive"]
                if self.mode == "ip_buffer" and late == 1:
                    # CiA 402 linear interpolation leaves open which end of a segment a record is; on the bus a
                    # drive that takes record k as the end point of the segment k..k+1 (0x6062 at SYNC k is
                    # record k - 1, the segment's start) sends what a late one sends, and the same setting
                    # files both right (the encoder's latency is its own)
                    self._release_unconfirmed(filed_right=False)
                    self._report_fault(DeviceFault(self.drive_label, None, (
                        f"its position demand value 0x6062 at sample {seq} is the record of sample {seq - 1} "
                        f"({LATENCY_EVIDENCE_SAMPLES} samples in a row): either it takes each interpolation record "
                        "as the end point of the segment to the next SYNC (CiA 402 linear interpolation, 0x6062 "
                        "showing the segment's start: set ip_record_is_segment_end = true), or it answers SYNC k "
                        f"after SYNC k + {configured + 1} (set drive_tpdo_latency_cycles = {configured + 1}); the "
                        "two look the same on the bus while streaming: its manual says which (a drive whose "
                        "statusword shows bit 12 at the SYNC after it confirmed controlword bit 4 answers in time)")))
                    return
                self._release_unconfirmed(filed_right=False)
                self._report_fault(DeviceFault(self.drive_label, None, (
                    f"answers SYNC k after SYNC k + {configured + late}: its position demand value 0x6062 at sample "
                    f"{seq} is the target of sample {seq - late} ({LATENCY_EVIDENCE_SAMPLES} samples in a row); set "
                    f"drive_tpdo_latency_cycles = {configured + late} (and check encoder_tpdo_latency_cycles)")))
                return

    def _target_ignored(self, statusword: int) -> bool:
        """CiA 402 cyclic synchronous position: statusword bit 12 clear in OPERATION ENABLED means the
        drive does not follow 0x607A (still switching mode, or a drive-internal reason)."""
        return (self._mode == self._streaming_mode  # bit 12: follows the target (CSP), ip mode active (IP)
                and cia402.state_from_statusword_or_none(statusword) is cia402.DriveState.OPERATION_ENABLED
                and not statusword & cia402.STATUSWORD_FOLLOWS_TARGET)
