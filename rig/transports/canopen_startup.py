"""The start-up steps of the CANopen master (:class:`~rig.transports.canopen_link.CanOpenTransport`), all by
SDO and none of them able to enable the drive: the SYNC period, the streaming mode and its fall-backs, the PDO
mapping read back from the device, the interpolation buffer, the mode handshake, homing, the encoder's
scaling. Every SDO names the node, the object and the value when it fails (:meth:`CanOpenStartUp._sdo`).

:class:`CanOpenStartUp` is a part of the transport, not a class of its own: it works on the transport's
nodes, configuration and state, and the transport's ``_prepare`` and ``_after_enabled`` call it in order.
"""

from __future__ import annotations

import struct
from typing import Any

from rig.protocols import cia402
from rig.protocols.errors import ConfigError, DeviceFault, TransportError
from rig.transports.canopen_dictionary import ASYNCHRONOUS_RPDO, PdoLayout, interpolation_time_period
from rig.transports.interpolation_feed import AUTO_IP_BUFFER_RECORDS, MIN_IP_BUFFER_RECORDS

__all__ = ["CanOpenStartUp", "MODE_NAMES"]

MODE_NAMES = {cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE: "cyclic synchronous position", cia402.HOMING_MODE: "homing",
              cia402.INTERPOLATED_POSITION_MODE: "interpolated position"}


class CanOpenStartUp:
    """The start-up steps (module docstring), as methods of the CANopen transport."""

    def _write_cycle_period(self, drive: Any) -> None:
        """The SYNC period, in every object of the drive that holds it: 0x1006 (CiA 301 communication cycle
        period, UNSIGNED32 microseconds) and 0x60C2 (CiA 402 interpolation time period: sub 1 the value, sub 2
        its power of ten in seconds; :func:`interpolation_time_period` fits the value to sub 1's type)."""
        period_us = int(round(self.sample_period_s * 1e6))
        if 0x1006 in drive.object_dictionary:
            self._sdo_write(drive, "drive", 0x1006, 0, period_us, "the SYNC period")
        if 0x60C2 not in drive.object_dictionary:
            return
        largest = (1 << {0x05: 8, 0x06: 16, 0x07: 32}.get(drive.object_dictionary[0x60C2][1].data_type, 8)) - 1
        found = interpolation_time_period(self.sample_period_s, largest)
        if found is None:
            problem = (f"a sample period of {self.sample_period_s:g} s has no exact form value x 10^index with the "
                       f"value in 1..{largest}, as the drive's 0x60C2 (interpolation time period) holds it")
            if self.mode == "ip_buffer":
                raise ConfigError("<transport>", "sample_rate_hz", (
                    f"{problem}; choose a rate whose period it holds (1 ms, 500 us, 250 us, 2 ms ...) or mode = \"csp\""))
            self._ride_through(f"drive {self.drive_node_id}: 0x60C2 not written: {problem}")
            return
        value, index = found
        self._sdo_write(drive, "drive", 0x60C2, 1, value, "the interpolation time period's value")
        self._sdo_write(drive, "drive", 0x60C2, 2, index, "the interpolation time period's power of ten")
        self._period_written = f"0x60C2 (interpolation time period) = {value} x 10^{index} s"

    def _cycle_period_text(self) -> str:
        return self._period_written or f"0x1006 (communication cycle period) = {int(round(self.sample_period_s * 1e6))} us"

    def _sdo_write(self, node: Any, role: str, index: int, subindex: int, value: int, purpose: str) -> None:
        """One start-up SDO write; a failure names the node, the object (index:sub and its EDS name), the
        value, and what to do."""
        self._sdo(node, role, index, subindex, purpose, value)

    def _sdo_read(self, node: Any, role: str, index: int, subindex: int, purpose: str) -> int:
        """One start-up SDO read, named as :meth:`_sdo_write` names a write."""
        return self._sdo(node, role, index, subindex, purpose)

    def _sdo(self, node: Any, role: str, index: int, subindex: int, purpose: str, value: int | None = None) -> int:
        import canopen

        single = isinstance(node.object_dictionary[index], canopen.objectdictionary.ODVariable)
        variable = node.sdo[index] if single else node.sdo[index][subindex]
        name = f" ({variable.od.name})" if variable.od.name else ""
        where = f"{self.name} {role} {node.id}"
        what = (f"read of 0x{index:04X}:{subindex:02X}{name}" if value is None
                else f"write 0x{index:04X}:{subindex:02X}{name} = {value}") + f" ({purpose})"
        try:
            if value is None:
                return variable.raw
            variable.raw = value
            return value
        except canopen.SdoAbortedError as err:
            raise DeviceFault(where, err.code, (
                f"refused the start-up {what}: {err}; check the object in the device's manual and its EDS")) from err
        except canopen.SdoCommunicationError as err:
            raise TransportError(f"{where}: no answer to the start-up {what}: {err}; check that the node is "
                                 "powered, on the bus, and at this node-ID") from err
        except (ValueError, OverflowError, struct.error) as err:  # encoded by the EDS type before anything is sent
            raise ConfigError("<transport>", "drive_eds" if role == "drive" else "encoder_eds", (
                f"the EDS's type for the {what} cannot hold the value: {err}")) from err

    def _has_sub(self, node: Any, index: int, subindex: int) -> bool:
        od = node.object_dictionary
        return index in od and subindex in getattr(od[index], "subindices", {})

    def _supported_modes(self, drive: Any) -> int | None:
        """0x6502 (supported drive modes), where the EDS has it: bit 7 cyclic synchronous position, bit 6
        interpolated position, bit 5 homing."""
        if 0x6502 not in drive.object_dictionary:
            return None
        return self._sdo_read(drive, "drive", 0x6502, 0, "the drive modes it supports")

    def _choose_streaming_mode(self, drive: Any) -> None:
        """Read the interpolation buffer's capacity; with ``mode = "auto"``, fall back from interpolated
        position to CSP where the drive cannot take it (0x6502 bit 6 clear, or a buffer of fewer than
        :data:`AUTO_IP_BUFFER_RECORDS` records in 0x60C4), with a warning saying why."""
        if self.mode != "ip_buffer":
            return
        supported = self._supported_modes(drive)
        can_interpolate = supported is None or bool(supported >> 6 & 1)
        # the buffer's capacity: the smaller of 0x60C4 sub 1 (maximum) and sub 2 (actual buffer size)
        self._ip_capacity = min(self._sdo_read(drive, "drive", 0x60C4, 1, "the interpolation buffer's capacity"),
                                self._sdo_read(drive, "drive", 0x60C4, 2, "the interpolation buffer's size")
                                ) if can_interpolate else 0
        if self._ip_capacity < AUTO_IP_BUFFER_RECORDS and self.mode_requested == "auto":
            self._fall_back_to_csp(
                "0x6502 does not offer interpolated position" if not can_interpolate else
                f"its interpolation buffer holds {self._ip_capacity} records (0x60C4:1/2), fewer than the "
                f"{AUTO_IP_BUFFER_RECORDS} mode = \"auto\" takes it for (mode = \"ip_buffer\" streams into 4 or more)")
        elif self._ip_capacity < MIN_IP_BUFFER_RECORDS and can_interpolate:
            raise DeviceFault(self.drive_label, None, (
                f"its interpolation buffer holds {self._ip_capacity} records (0x60C4:1/2); mode = \"ip_buffer\" "
                f"needs at least {MIN_IP_BUFFER_RECORDS}: use mode = \"csp\" or \"auto\""))

    def _map_target_rpdo(self, drive: Any) -> PdoLayout:
        """RPDO1 carries the target: 0x607A (target position), synchronous (CSP: one target per SYNC, the
        last frame before the SYNC is the one in force), or 0x60C1:1 (interpolation data record),
        asynchronous (:data:`ASYNCHRONOUS_RPDO`: every record sent reaches the buffer). With ``mode =
        "auto"``, a drive whose RPDO1 cannot carry records that way streams CSP, with a warning naming why."""
        def mapped() -> PdoLayout:
            if self.mode == "ip_buffer":
                return self._map_pdo(drive.rpdo, "drive", [(0x60C1, 1, 32)], 0x200 + self.drive_node_id,
                                     transmission_type=ASYNCHRONOUS_RPDO)
            return self._map_pdo(drive.rpdo, "drive", [(0x607A, 0, 32)], 0x200 + self.drive_node_id)

        try:
            layout = mapped()
        except DeviceFault as err:
            if self.mode_requested != "auto" or self.mode != "ip_buffer":
                raise
            self._fall_back_to_csp(f"{err}")
            layout = mapped()
        self._rpdo_transmission_type = ASYNCHRONOUS_RPDO if self.mode == "ip_buffer" else 1
        return layout

    def _map_hold_rpdo(self, drive: Any) -> PdoLayout | None:
        """Interpolated position: RPDO2 carries the hold records (:mod:`rig.transports.interpolation_feed`)
        into the same buffer as RPDO1's setpoints, asynchronous too, so that a trace of the bus tells a hold
        record from a setpoint of the same value. A drive without a second RPDO it lets the master map takes
        them on RPDO1 (noted in ``warnings``: its traces cannot tell them apart)."""
        if self.mode != "ip_buffer":
            return None
        if 0x1401 in drive.object_dictionary and 0x1601 in drive.object_dictionary:
            try:
                return self._map_pdo(drive.rpdo, "drive", [(0x60C1, 1, 32)], 0x300 + self.drive_node_id, number=2,
                                     transmission_type=ASYNCHRONOUS_RPDO)
            except DeviceFault as err:
                why = str(err)
        else:
            why = "its EDS has no RPDO2 (0x1401/0x1601)"
        self._ride_through(f"drive {self.drive_node_id}: hold records go on RPDO1 with the setpoints ({why}); a "
                           "trace of the bus cannot tell a hold record from a repeated setpoint")
        return None

    def _fall_back_to_csp(self, why: str) -> None:
        """``mode = "auto"``: interpolated position cannot be used on this drive; stream CSP and say why."""
        self._use_mode("csp")
        self._ride_through(f"drive {self.drive_node_id}: interpolated position not used, cyclic synchronous "
                           f"position instead: {why}")

    def _check_supported_modes(self, drive: Any) -> None:
        """The streaming mode, and homing where it is used, against 0x6502 where the EDS has it."""
        supported = self._supported_modes(drive)
        if supported is None:
            return
        needed = ([(6, "interpolated position")] if self.mode == "ip_buffer" else [(7, "cyclic synchronous position")])
        needed += [] if self.skip_homing else [(5, "homing")]
        for bit, name in needed:
            if not supported >> bit & 1:
                raise DeviceFault(self.drive_label, None, (
                    f"does not support {name} mode (0x6502 supported drive modes = 0x{supported:08X}, bit {bit} "
                    "clear)"))

    def _configure_ip_buffer(self, drive: Any) -> None:
        """The interpolation buffer (CiA 402 0x60C4): linear interpolation (0x60C0 = 0 where present),
        cleared and enabled (sub 6: 0, then 1)."""
        if 0x60C0 in drive.object_dictionary:
            self._sdo_write(drive, "drive", 0x60C0, 0, 0, "linear interpolation")
        self._sdo_write(drive, "drive", 0x60C4, 6, 0, "clear the interpolation buffer")
        self._sdo_write(drive, "drive", 0x60C4, 6, 1, "enable access to the interpolation buffer")

    def _take_first_mode(self, drive: Any) -> None:
        """0x6060 = the streaming mode (or homing first). With ``mode = "auto"``, a drive that refuses
        interpolated position (SDO abort on 0x6060 = 7, though its EDS lists the objects) streams CSP, with
        a warning naming the refusal."""
        try:
            self._set_mode(drive, self._streaming_mode if self.skip_homing else cia402.HOMING_MODE)
        except DeviceFault as err:
            if not (self.skip_homing and self.mode == "ip_buffer" and self.mode_requested == "auto"
                    and err.code is not None and err.code > 0xFFFF):
                raise
            self._fall_back_to_csp(str(err))
            self._rpdo = self._map_target_rpdo(drive)
            self._set_mode(drive, self._streaming_mode)

    def _set_mode(self, drive: Any, mode: int) -> None:
        self._sdo_write(drive, "drive", 0x6060, 0, mode, f"mode of operation: {MODE_NAMES.get(mode, 'unknown')}")
        self._mode = mode

    def _wait_for_mode(self, drive: Any) -> None:
        """The mode handshake: 0x6061 (modes of operation display) must show the mode written to 0x6060
        within ``mode_switch_timeout_s``; until then the drive still runs the old mode."""
        deadline = self.clock() + self.mode_switch_timeout_s
        while True:
            shown = drive.sdo[0x6061].raw
            shown = shown - 256 if shown > 127 else shown  # INTEGER8
            if shown == self._mode:
                return
            if self.clock() > deadline:
                raise DeviceFault(self.drive_label, None, (
                    f"did not take mode {self._mode} ({MODE_NAMES.get(self._mode, 'unknown')}) within "
                    f"{self.mode_switch_timeout_s:g} s: 0x6061 (modes of operation display) still shows {shown}; "
                    "a drive that switches slowly needs a larger mode_switch_timeout_s"))
            self._pause(self.timing.poll_interval_s)

    def _hold_at_actual_position(self, drive: Any) -> float:
        """Write the actual position (0x6064) into the target (0x607A), so that enabling, or switching to
        cyclic synchronous position, does not move the motor (a standard drive servoes to whatever 0x607A
        holds); return that position in radians."""
        actual = self._sdo_read(drive, "drive", 0x6064, 0, "the actual position the target is set to")
        self._sdo_write(drive, "drive", 0x607A, 0, actual, "the target at the actual position, so that nothing moves")
        with self._lock:
            self._in_force = (-1, actual)  # the drive holds this target until the first RPDO
        return self.drive.rad_from_counts(actual)

    def _home(self, drive: Any) -> None:
        """Homing mode: start with bit 4, wait for "homing attained" (statusword bit 12; bit 13 is a homing
        error), at most ``homing_timeout_s``."""
        drive.sdo[0x6098].raw = self.homing_method
        drive.sdo[0x6040].raw = cia402.CONTROLWORD_START_HOMING
        deadline = self.clock() + self.homing_timeout_s
        while True:
            statusword = drive.sdo[0x6041].raw
            if statusword & cia402.STATUSWORD_HOMING_ERROR:
                raise DeviceFault(self.drive_label, cia402.fault_code_or_none(self._read_error_code),
                                  f"homing (method {self.homing_method}) failed: statusword 0x{statusword:04X}")
            if statusword & cia402.STATUSWORD_HOMING_ATTAINED:
                break
            if self.clock() > deadline:
                raise DeviceFault(self.drive_label, None,
                                  f"homing did not finish within {self.homing_timeout_s:g} s (homing_timeout_s)")
            self._pause(max(self.timing.poll_interval_s, 0.01))
        drive.sdo[0x6040].raw = cia402.CONTROLWORD_ENABLE_OPERATION

    def _map_pdo(self, pdos: Any, role: str, needed: list[tuple[int, int, int]], cob_id: int,
                 number: int = 1, transmission_type: int = 1) -> PdoLayout:
        """Map PDO ``number`` of ``pdos`` to the ``needed`` objects ``(index, sub-index, bits)`` with
        ``transmission_type`` (1: synchronous, every SYNC), then read its communication and mapping
        parameters back from the device: a device with static PDOs refuses the writes (or canopen skips
        entries its EDS marks read-only), and what the master decodes must be what the device sends. A
        layout that carries the needed objects is used as it is; one that does not is refused naming the
        object, and the refusal the device gave, if any."""
        import canopen

        pdo = pdos[number]
        kind = f"{'RPDO' if pdo.com_record.od.index < 0x1800 else 'TPDO'}{number}"
        node_id = pdos.node.id
        where = f"{kind} of {role} {node_id} (0x{pdo.com_record.od.index:04X}/0x{pdo.map_array.od.index:04X})"
        pdos.read()
        pdo.clear()
        for index, subindex, _ in needed:
            pdo.add_variable(index, subindex)
        pdo.cob_id = cob_id
        pdo.trans_type = transmission_type
        pdo.enabled = True
        refused = ""
        try:
            pdo.save()
        except canopen.SdoAbortedError as err:  # a static PDO: the read-back below says whether its layout serves
            refused = f" (the device refused its configuration: SDO abort 0x{err.code:08X})"
        pdo.read()
        layout = PdoLayout.from_pdo(pdo, where)
        device = f"{self.name} {role} {node_id}"
        if not pdo.enabled:
            raise DeviceFault(device, None, f"{where} stays disabled after configuration (COB-ID bit 31 set){refused}")
        if pdo.trans_type != transmission_type and (kind.startswith("TPDO") or transmission_type != 1):
            needs = ("1, an answer to every SYNC" if transmission_type == 1 else
                     f"{transmission_type} (asynchronous: a synchronous RPDO keeps only the last frame before a "
                     "SYNC, CiA 301, and interpolation records would be lost)")
            raise DeviceFault(device, None, (
                f"{where} has transmission type {pdo.trans_type} (0x{pdo.com_record.od.index:04X}:02){refused}; the "
                f"master needs {needs}: set it with the vendor's tool"))
        for index, _, bits in needed:
            if index not in layout.fields:
                raise DeviceFault(device, None, (
                    f"{where} does not map 0x{index:04X} (it maps {layout.describe()}){refused or ', not writable on this device'}; "
                    "the master needs it there"))
            if layout.fields[index][1] * 8 < bits:
                raise DeviceFault(device, None, (
                    f"{where} maps only {layout.fields[index][1] * 8} bits of 0x{index:04X}; the master needs {bits}"))
        sent = {index for index, _, _ in needed}
        if kind.startswith("RPDO") and set(layout.fields) - sent:
            extra = ", ".join(f"0x{index:04X}" for index in sorted(set(layout.fields) - sent))
            raise DeviceFault(device, None, (
                f"{where} maps {extra} besides the target (not writable on this device); the master sends "
                "only the target"))
        return layout

    def _map_drive_tpdo(self, drive: Any) -> PdoLayout:
        """Drive TPDO1 = statusword 0x6041 + position actual value 0x6064, and the torque actual value 0x6077
        (CiA 402, INTEGER16) where the drive's EDS makes it PDO-mappable; a drive that refuses to map it (a
        static PDO, or an EDS that promises more than the device does) streams without it, noted in
        ``warnings``, its log's torque column empty."""
        needed, cob_id = [(0x6041, 0, 16), (0x6064, 0, 32)], 0x180 + self.drive_node_id
        if self.drive_torque_unit is not None:
            try:
                layout = self._map_pdo(drive.tpdo, "drive", [*needed, (0x6077, 0, 16)], cob_id)
            except DeviceFault as err:
                self._ride_through(f"drive {self.drive_node_id}: its torque actual value 0x6077 is not logged ({err})")
            else:
                self._drive_torque_nm_per_unit = self._rated_torque_nm_per_mille(drive)
                return layout
        return self._map_pdo(drive.tpdo, "drive", needed, cob_id)

    def _rated_torque_nm_per_mille(self, drive: Any) -> float | None:
        """N m per unit of 0x6077: the motor rated torque 0x6076 (UNSIGNED32, mN m) / 1000, where the drive has it
        (else None: the log's torque stays in per mille of a rated torque the summary cannot name)."""
        if 0x6076 not in drive.object_dictionary:
            return None
        try:
            rated_mnm = self._sdo_read(drive, "drive", 0x6076, 0, "the rated torque 0x6077 is per mille of")
        except (DeviceFault, TransportError) as err:
            self._ride_through(f"drive {self.drive_node_id}: the motor rated torque 0x6076 is not known ({err})")
            return None
        return rated_mnm * 1e-6 if rated_mnm > 0 else None

    def _map_demand_tpdo(self, drive: Any) -> PdoLayout | None:
        """Drive TPDO2 = 0x6062 (position demand value: the target the drive applied at that SYNC), for the
        latency check; a drive that cannot map it is streamed without the check (noted in ``warnings``)."""
        if not self._checks_latency:
            return None
        try:
            return self._map_pdo(drive.tpdo, "drive", [(0x6062, 0, 32)], 0x280 + self.drive_node_id, number=2)
        except DeviceFault as err:
            self._ride_through(f"drive {self.drive_node_id}: the TPDO latency is not checked ({err})")
            return None

    def _encoder_value_bits(self) -> int:
        """Bits of 0x6004 the configured encoder needs in its TPDO."""
        return min(32, max(8, self.encoder.bits + self.encoder.multi_turn_bits))

    def _check_encoder(self, encoder: Any) -> None:
        """CiA 406: the position value's scaling is 0x6001 (measuring units per revolution) and 0x6002
        (total measuring range); where the EDS lacks them, 0x6501 (physical single-turn resolution) and
        0x6502 (number of distinguishable revolutions) stand in. A total range of 2**32 does not fit the
        UNSIGNED32 of 0x6002: a 32-bit encoder reports 0 there, read as 2**32. 0x6000 bit 0 (code
        sequence) must agree with ``[encoder] direction``."""
        od = encoder.object_dictionary
        expected = (self.encoder.counts_per_revolution, self.encoder.modulus)
        per_revolution_index = 0x6001 if 0x6001 in od else 0x6501
        per_revolution = encoder.sdo[per_revolution_index].raw
        if 0x6002 in od:
            objects = f"0x{per_revolution_index:04X}, 0x6002"
            total = encoder.sdo[0x6002].raw
        else:
            objects = f"0x{per_revolution_index:04X}, 0x6502"
            total = per_revolution * max(encoder.sdo[0x6502].raw, 1)
        if total == 0:
            total = 1 << 32
        device = f"{self.name} encoder {self.encoder_node_id}"
        if (per_revolution, total) != expected:
            raise DeviceFault(device, None, (
                f"reports {per_revolution} counts per revolution and a range of {total} counts ({objects}), "
                f"but the config says {expected[0]} and {expected[1]} ([encoder] bits, multi_turn_bits)"))
        if 0x6000 in od:
            counts_down = bool(encoder.sdo[0x6000].raw & 0x0001)
            if counts_down != (self.encoder.direction < 0):
                raise DeviceFault(device, None, (
                    f"counts {'down' if counts_down else 'up'} with the angle (0x6000 bit 0, code sequence = "
                    f"{int(counts_down)}), but the config says direction = {self.encoder.direction}; set [encoder] "
                    f"direction = {-1 if counts_down else 1}"))
