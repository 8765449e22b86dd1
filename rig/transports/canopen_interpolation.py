"""Interpolated position on the CANopen master (:class:`~rig.transports.canopen_link.CanOpenTransport`,
``mode = "ip_buffer"``): records into the drive's buffer in the bus order of their echoes, ip mode enabled
once the buffer holds the lead, sample 0 found from the statusword's bit 12, one record taken per SYNC, hold
records where the buffer would run dry (:mod:`rig.transports.interpolation_feed` keeps the master's copy of
the buffer; docs/rig_driver.md says why each rule is there).

:class:`CanOpenInterpolation` is a part of the transport, not a class of its own: its methods work on the
transport's bus, lock and sample bookkeeping, and are called from the transport's send, receive and SYNC
paths.
"""

from __future__ import annotations

from typing import Any

from rig.protocols import cia402
from rig.protocols.errors import DeviceFault, TransportError

__all__ = ["IP_ENABLE_AFTER_SYNC_WAIT_PERIODS", "IP_START_SYNCS", "CanOpenInterpolation"]

IP_ENABLE_AFTER_SYNC_WAIT_PERIODS = 3
"""How long (in sample periods) the master waits for a SYNC to send controlword bit 4 right after; a SYNC
producer that stalls longer does not hold up the start, bit 4 then goes out when the wait ends."""

IP_START_SYNCS = 50
"""SYNCs the drive may take after controlword bit 4 (enable ip mode) before its statusword shows bit 12 (ip
mode active); a drive that never shows it does not interpolate (0x60C2 not accepted, a drive-internal
reason), and the run stops saying so."""


class CanOpenInterpolation:
    """The interpolated position steps (module docstring), as methods of the CANopen transport."""

    def _take_ip_record(self, count: int) -> None:
        """Interpolated position at SYNC ``count`` (from the first SYNC whose statusword showed bit 12, ip
        mode active: sample 0): the drive takes the oldest record of its buffer (the master's copy of the
        buffer follows the bus order of its RPDO echoes). A hold record, or an empty buffer (an underrun),
        leaves the sample HELD at the record before."""
        if self._origin is None or count < self._origin:
            return
        sample = count - self._origin
        record = self._feed.take()
        if record is None or record.sample is None:
            if self._dry_since is None:
                self._dry_since = count  # (after the run's last record the buffer runs dry for good: no lead)
            self._applied[sample] = (self._in_force[1], True, False)
            self._wait_for_rpdo_echo(sample, self._in_force[1], any_value=True)  # one due may be in the drive
            return
        self._in_force = (record.sample, record.counts)
        queued = self._queued_at.pop(record.sample, None)
        if queued is not None:  # (a SYNC replayed once sample 0 was known happened that many periods ago)
            at = self.clock() - (self._sync_count - count) * self.sample_period_s
            self._min_lead_s = min(self._min_lead_s, at - queued)
        if self._dry_since is not None:  # the buffer ran dry for these instants: a negative lead
            self._min_lead_s = min(self._min_lead_s, -(count - self._dry_since) * self.sample_period_s)
            self._dry_since = None
        self._applied[sample] = (record.counts, False, False)

    def _check_buffer_position(self, buffered: int) -> None:
        """Before ip mode is enabled: where the drive counts the records of its FIFO in 0x60C4:4 (buffer
        position), that count must be what the echoes say went in, else the records are not all reaching
        the buffer and the run stops. CiA 402 defines sub 4 for ring buffers; many FIFO drives leave it at a
        constant (0 or 1): a value that is not a count is only noted, and the records are then checked each
        sample against 0x6062 (position demand value) where the drive has it."""
        if not self._has_sub(self._drive, 0x60C4, 4):
            return
        try:
            with self._translated_errors("interpolation buffer position (0x60C4:4)"):
                in_drive = self._drive.sdo[0x60C4][4].raw
        except DeviceFault as err:  # write-only or not implemented on this drive: nothing to learn from it
            self._ride_through(f"drive {self.drive_node_id}: 0x60C4:4 not readable ({err})")
            return
        if in_drive == buffered:
            return
        if 1 < in_drive < buffered:
            raise DeviceFault(self.drive_label, None, (
                f"holds {in_drive} records in its interpolation buffer (0x60C4:4 buffer position) after {buffered} "
                f"were sent on {self._rpdo.where} with transmission type {self._rpdo_transmission_type}: the "
                "records do not all reach the buffer; use mode = \"csp\""))
        check = "0x6062 each sample" if self._demand_tpdo is not None else "nothing (no 0x6062 in its TPDOs)"
        self._ride_through(f"drive {self.drive_node_id}: 0x60C4:4 (buffer position) reads {in_drive} with {buffered} "
                           f"records sent; not a count of its FIFO, so arrival is checked by {check}")

    def _put_records_on_bus(self) -> None:
        """Interpolated position: put what :meth:`InterpolationFeed.to_send` says on the bus (queued records
        while the drive's buffer has room; while streaming, hold records where it would run low).
        Called with the lock held, from the runner's thread as it queues and from the receive thread at
        every SYNC: the lead is kept in the host's queue and the drive's buffer together, so a stall of the
        runner's thread shorter than the lead costs nothing, and a pause of the whole process is ridden
        through for as long as the drive's buffer lasts."""
        for record in self._feed.to_send():
            rpdo = self._rpdo if record.sample is not None or self._hold_rpdo is None else self._hold_rpdo
            data = rpdo.pack({index: record.counts for index in rpdo.fields})
            own = self._own_rpdo_sent(rpdo.cob_id, data)
            try:
                self.network.send_message(rpdo.cob_id, data)
            except Exception as err:  # noqa: BLE001 - in the notifier thread: report, the runner raises it
                self._own_rpdo_unsent(own)
                self._feed.unsent(record)
                what = "a hold record" if record.sample is None else f"the record of sample {record.sample}"
                self._report_fault(TransportError(f"{self.name}: sending {what} failed: {err}"))
                return

    def _start_interpolation(self) -> None:
        """Interpolated position, before sample 0: once the drive's buffer holds the lead (or every setpoint
        there is), check that the records really are in it (0x60C4:4 buffer position, where the EDS has it),
        then set controlword bit 4 (enable ip mode). Sample 0 is the first SYNC whose statusword shows bit 12
        (:meth:`_file_locked`); a drive that does not show it within :data:`IP_START_SYNCS` SYNCs stops the
        run, saying so. Bit 4 goes out right after a SYNC: a drive that confirms it before the next SYNC fixes
        sample 0 by the bus order alone (:meth:`_origin_from_the_answer`)."""
        with self._lock:
            enabled_at, ready = self._ip_enabled_at, self._feed.ready_to_start()
            buffered = self._feed.buffered
        if enabled_at is not None:
            if self._sync_count - enabled_at > IP_START_SYNCS:
                raise DeviceFault(self.drive_label, None, (
                    f"does not interpolate: statusword bit 12 (ip mode active) still clear {IP_START_SYNCS} SYNCs "
                    f"after controlword bit 4 (enable ip mode), with {buffered} records in its buffer (0x60C4); "
                    f"{self._cycle_period_text()} was written; check what the drive needs to start interpolated "
                    "position (its manual, 0x60C2 interpolation time period), or use mode = \"csp\""))
            return
        if not ready:
            return
        self._check_buffer_position(buffered)
        with self._arrived:  # right after a SYNC, so that the drive has most of a period to confirm it
            seen = self._sync_count
            self._arrived.wait_for(lambda: self._sync_count != seen, IP_ENABLE_AFTER_SYNC_WAIT_PERIODS
                                   * self.sample_period_s)
            self._ip_enabled_at = self._sync_count
        self._write_controlword(cia402.CONTROLWORD_ENABLE_INTERPOLATION)

    def _on_drive_sdo_response(self, can_id: int, data: bytes, timestamp: float) -> None:
        """An SDO response from the drive, in bus order with the SYNC echoes: the answer to controlword bit 4
        (enable ip mode) bounds the SYNC at which the drive can first have taken a record
        (:meth:`_find_ip_origin`)."""
        with self._lock:
            if self._ip_enabled_at is not None and self._ip_answered_at is None:
                self._ip_answered_at = self._sync_count

    def _origin_from_the_answer(self, count: int) -> bool:
        """SYNC ``count``, before sample 0 is known: where the drive confirmed bit 4 before any SYNC passed
        after the request went out, it took its first record at the next SYNC, this one if it is that one:
        sample 0 by the bus order alone (a statusword that comes late cannot shift it). Whether it is."""
        if (self._ip_enabled_at is None or self._ip_answered_at != self._ip_enabled_at
                or count != self._ip_answered_at + 1):
            return False
        self._origin = count
        self._feed.streaming = True
        kept, self._before_origin = self._before_origin, []
        for item in kept:
            self._file_locked(*item)
        return True

    def _find_ip_origin(self, part: str, value: Any, timestamp: float, received: float, answers: int) -> bool:
        """Interpolated position, after controlword bit 4: the first SYNC whose drive statusword shows bit 12
        (ip mode active) is sample 0, the first at which the drive took a record. Until it is seen, TPDOs are
        kept; then the records taken at the SYNCs since are replayed, and the kept TPDOs filed. Whether this
        TPDO was kept (the caller files it otherwise).

        The statusword's SYNC depends on ``drive_tpdo_latency_cycles``, which a user may have set for a drive
        that answers in time but takes each record as the end point of its segment (its 0x6062 lags a SYNC,
        as a late drive's does): such a statusword is filed up to that many SYNCs early. Where the drive
        confirmed bit 4 after one or more SYNCs, so that sample 0 may also be one of the SYNCs after the
        statusword's, the drive's 0x6062 decides between them (:meth:`_choose_ip_origin`)."""
        if answers <= self._ip_enabled_at:
            return False
        if self._ip_answered_at is not None and self._ip_answered_at == self._ip_enabled_at:
            return False  # sample 0 follows from the bus order (_origin_from_the_answer), not from a statusword
        item = (part, value, timestamp, received)
        if self._ip_origin_choices:
            return self._choose_ip_origin(item)
        if part != "drive" or not value[0] & cia402.STATUSWORD_IP_MODE_ACTIVE:
            self._before_origin.append(item)
            return True
        latest = None if self._ip_answered_at is None else self._ip_answered_at + 1
        if latest is not None and answers > latest:
            # the drive took its bit 4 before its SDO answer, so its first record went at SYNC <= latest; a
            # statusword that says later was sent later than drive_tpdo_latency_cycles says
            configured = self.latency_cycles["drive"]
            self._report_fault(DeviceFault(self.drive_label, None, (
                f"answers SYNC k after SYNC k + {configured + answers - latest} or later: its statusword shows bit 12 "
                f"(ip mode active) first in the answer filed under SYNC {answers - self._ip_enabled_at} after "
                f"controlword bit 4, which it had confirmed by SYNC {latest - self._ip_enabled_at}; set "
                f"drive_tpdo_latency_cycles = {configured + answers - latest} (and check encoder_tpdo_latency_cycles)")))
            self._arrived.notify_all()
            return False
        if latest is not None and self._demand_tpdo is not None:
            self._ip_origin_choices = tuple(range(answers, min(latest, answers + self.latency_cycles["drive"]) + 1))
        if len(self._ip_origin_choices) > 1:
            return self._choose_ip_origin(item)
        syncs = (self._sync_count if latest is None else latest - 1) - self._ip_enabled_at  # before its answer
        self._ride_through(
            f"drive {self.drive_node_id}: confirmed controlword bit 4 (enable ip mode) only after "
            f"{'more than ' if latest is None else ''}{syncs} SYNC(s), so sample 0 is where its statusword first "
            f"shows bit 12 under drive_tpdo_latency_cycles = "
            f"{self.latency_cycles['drive']}; were the drive later than that, every row would be filed as many "
            "samples late, and nothing on the bus would show it (a drive that confirms bit 4 within a period fixes "
            "sample 0 by the bus order)")
        self._set_ip_origin(answers)
        return False

    def _choose_ip_origin(self, item: tuple[str, Any, float, float]) -> bool:
        """Sample 0 is one of :attr:`_ip_origin_choices` (the statusword's SYNC first): the one under which
        the drive's 0x6062 is the record it holds, once a demand value tells them apart (their records
        differ there). The statusword's, where a demand value fits none of them (the latency check then
        speaks while streaming) or no demand value has told them apart while the drive's buffer lasts half
        its records (the master sends no more until sample 0 is known). Whether ``item`` was kept."""
        self._before_origin.append(item)
        choices = self._ip_origin_choices
        chosen = None
        for part, value, timestamp, _ in self._before_origin:
            count = self._sync_before(timestamp)
            if part != "demand" or count is None:
                continue
            expected = [self._ip_record_counts(count - self.latency_cycles["demand"] - origin) for origin in choices]
            if None in expected or len(set(expected)) < len(expected):
                continue
            chosen = choices[expected.index(value)] if value in expected else choices[0]
            break
        if chosen is None and self._sync_count - choices[0] <= max(1, self._feed.buffered // 2):
            return True
        self._before_origin.pop()  # (the caller files it)
        self._set_ip_origin(choices[0] if chosen is None else chosen)
        return False

    def _ip_record_counts(self, sample: int) -> int | None:
        """Before sample 0 is known: the record the drive holds at ``sample`` (the position it held before the
        first, for a negative one), None past the records in its buffer."""
        if sample < 0:
            return self._in_force[1]
        return self._feed.buffer[sample].counts if sample < self._feed.buffered else None

    def _set_ip_origin(self, origin: int) -> None:
        """Sample 0 is SYNC ``origin``: the records the drive took at the SYNCs since are replayed, and the kept
        TPDOs filed."""
        self._origin = origin
        self._ip_origin_choices = ()
        self._feed.streaming = True
        stamps = dict((count, bus_time) for bus_time, count in self._syncs)
        for count in range(origin, self._sync_count):  # (this SYNC's own record is taken by the caller)
            if count in stamps and count - 1 in stamps:  # its instant's error, as _on_sync_echo records it
                self._instant_errors[count - origin] = stamps[count] - stamps[count - 1] - self.sample_period_s
            self._take_ip_record(count)
        self._device_sample = self._sync_count - 1 - origin
        kept, self._before_origin = self._before_origin, []
        for item in kept:
            self._file_locked(*item)
