"""CANopen transport: a CiA 402 drive in interpolated position or cyclic synchronous position mode and a
CiA 406 load encoder.

The transport is one class in four modules: this one (bring-up glue, streaming, filing the answers), its
start-up steps by SDO (:mod:`rig.transports.canopen_startup`), interpolated position
(:mod:`rig.transports.canopen_interpolation`, with the master's copy of the drive's buffer in
:mod:`rig.transports.interpolation_feed`), and what it knows of object dictionaries and PDOs
(:mod:`rig.transports.canopen_dictionary`); the SYNC thread is :mod:`rig.transports.canopen_sync`.

Before anything is sent, the EDS files are checked for every object the master needs (a missing one is a
:class:`ConfigError` naming it and what it is for). Start-up, all by SDO, in :meth:`_prepare` (nothing in
it can enable the drive):

1. NMT pre-operational for both nodes; producer heartbeat (0x1017) on both; 0x6502 (supported drive
   modes), where present, must offer the streaming mode; mode of operation 0x6060 = 7 (interpolated
   position) or 8 (cyclic synchronous position), or 6 (homing) first if ``skip_homing`` is false; the SYNC
   period in every object that holds it, 0x1006 (communication cycle period) and 0x60C2 (interpolation
   time period, CiA 402 types).
2. PDO mapping: drive RPDO1 = target position 0x607A (synchronous) or the interpolation data record 0x60C1:1
   (asynchronous, with RPDO2 for hold records); drive TPDO1 = statusword 0x6041 + position actual
   value 0x6064, and the torque actual value 0x6077 where the EDS makes it PDO-mappable (the log's
   ``drive_torque``; a drive that refuses it streams without it, with a warning); encoder TPDO1 = position
   value 0x6004; TPDOs synchronous (transmission type 1: every SYNC). Every PDO's communication and mapping parameters are then read back: a device with static PDOs
   refuses the writes (or canopen skips what the EDS marks read-only), so the master decodes the layout
   the device really sends, and refuses one that lacks an object or answers other than every SYNC,
   naming the object.
3. The encoder's scaling, 0x6001 (measuring units per revolution) and 0x6002 (total measuring range; 0 on
   a 32-bit encoder, read as 2**32), or 0x6501/0x6502 where the EDS has no scaling objects, and its code
   sequence 0x6000 bit 0 are checked against ``[encoder]``. 0x6004 is UNSIGNED32; ``signed`` says
   whether the counts are to be read as two's complement.
4. NMT operational; the mode handshake: 0x6061 must show the mode within ``mode_switch_timeout_s``; the
   actual position 0x6064 is read and written into the target 0x607A, so that enabling cannot move the
   motor (a standard drive servoes to whatever 0x607A holds).

The base class then walks the drive to OPERATION ENABLED by SDO on 0x6040/0x6041 (paced polling, fault
reset on a rising edge; :mod:`rig.protocols.cia402`), and after optional homing (mode 6, method 0x6098)
the target is set to the actual position again before the streaming mode (8 or 7) is taken. Every exit
after that ends in quick stop, then disable, then NMT pre-operational
(:class:`~rig.transports.base.Transport`).

Streaming, and filing each TPDO under the SYNC it answers: :mod:`rig.transports.canopen_filing`.

In OPERATION ENABLED, a sample whose statusword has bit 12 clear ("target ignored" in cyclic synchronous
position) is marked ``target_ignored`` (the runner flags it NOT_FOLLOWED). A drive FAULT in the statusword,
an EMCY that is not a warning (``emcy_warning_codes``; warnings are collected in ``warnings``), a heartbeat
older than ``heartbeat_timeout_s`` on the host's receive clock, or a heartbeat that reports an NMT state
other than OPERATIONAL stop the run, naming the node; on a drive fault 0x603F is read by SDO for the
message.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rig.protocols import cia402
from rig.protocols.can_bus_load import bus_load
from rig.protocols.can_interfaces import open_bus
from rig.protocols.can_error_frames import ERROR_FRAME_FILTERS, describe_error_frame, is_bus_off, is_rx_overflow
from rig.protocols.errors import ConfigError, DeviceFault, TransportError, error_code_meaning
from rig.transports.base import FeedbackSample, Setpoint, Transport, check_trace_path
from rig.transports.canopen_dictionary import (DRIVE_OBJECTS, ENCODER_OBJECTS, IP_BUFFER_OBJECTS, PdoLayout,
                                               emcy_prefixes, is_warning, load_object_dictionary, require_objects)
from rig.transports.canopen_filing import CanOpenSampleFiling
from rig.transports.canopen_interpolation import CanOpenInterpolation
from rig.transports.canopen_receive_checks import CanOpenReceiveChecks
from rig.transports.canopen_startup import CanOpenStartUp
from rig.transports.canopen_sync import SYNC_COB_ID, ErrorFrameListener, SyncThread, sync_message
from rig.transports.interpolation_feed import InterpolationFeed

__all__ = ["CanOpenTransport", "DEFAULT_DRIVE_EDS", "DEFAULT_ENCODER_EDS"]

logger = logging.getLogger(__name__)

_CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "eds"
DEFAULT_DRIVE_EDS = _CONFIGS / "sim_drive_cia402.eds"
DEFAULT_ENCODER_EDS = _CONFIGS / "sim_encoder_cia406.eds"
# data bytes of the frames of one cycle: SYNC, drive RPDO1 (0x607A), drive TPDO1 (0x6041 + 0x6064),
# encoder TPDO1 (0x6004)
CYCLE_FRAME_BYTES = (0, 4, 6, 4)
TORQUE_TPDO_BYTES = 2  # 0x6077 torque actual value in the drive's TPDO1, where its EDS makes it PDO-mappable
DEMAND_TPDO_BYTES = 4  # drive TPDO2 = 0x6062 position demand value, where the drive has it (latency check)
_NMT_STATES = {0x00: "INITIALISING", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
_NMT_OPERATIONAL = 0x05
SYNC_ECHO_TIMEOUT_S = 0.5  # the start-up probe's wait for the echo of a SYNC


class CanOpenTransport(CanOpenStartUp, CanOpenSampleFiling, CanOpenInterpolation, CanOpenReceiveChecks, Transport):
    """The rig over CANopen.

    Parameters
    ----------
    interface, channel, port
        python-can interface name and channel (from ``canopen://INTERFACE/CHANNEL``), and the UDP port of
        ``canopen://udp_multicast:PORT/GROUP`` (:mod:`rig.protocols.can_interfaces`).
    bitrate
        Bus bit rate; the cycle's frames must fit at the sample rate or the constructor raises
        :class:`ConfigError` (worst-case bit stuffing, :mod:`rig.protocols.can_bus_load`).
    drive_node_id, encoder_node_id
        Node-IDs.
    drive_eds, encoder_eds
        Object dictionaries (the vendor's EDS for a real device; the simulated devices' by default); in a rig
        config, a relative path is relative to the config file, and a simulated rig's devices are built from
        them too.
    heartbeat_ms
        Producer heartbeat time written to 0x1017 of both nodes.
    heartbeat_timeout_s
        A node whose last heartbeat is older than this stops the run.
    sdo_timeout_s
        SDO response timeout.
    skip_homing
        True (default): stream from the actual position without homing. False: after enabling, home the
        drive first (mode 6 with ``homing_method`` in 0x6098, start with controlword bit 4, wait for
        statusword bit 12 "homing attained"; bit 13 is a homing error), then switch to CSP.
    homing_method
        CiA 402 homing method (0x6098); 37 = home on the current position (no motion).
    homing_timeout_s
        How long homing may take.
    mode_switch_timeout_s
        How long the drive may take to show a new mode of operation in 0x6061 after 0x6060 was written.
    mode
        ``"auto"`` (default): ``"ip_buffer"`` where the drive has an interpolation buffer (its EDS lists
        0x60C1 and 0x60C4, 0x6502 bit 6 says interpolated position is supported where the EDS has 0x6502,
        and 0x60C4 holds at least :data:`~rig.transports.interpolation_feed.AUTO_IP_BUFFER_RECORDS` (16)), else ``"csp"``. ``"csp"``: cyclic
        synchronous position (0x6060 = 8): one target per SYNC, put on the bus right after the SYNC before
        it, so its lead on the bus is under one period whatever ``lead_s`` is (a receive thread that misses
        that window holds the sample). ``"ip_buffer"``: interpolated position with the drive's FIFO of
        interpolation data records (0x6060 = 7, records 0x60C1:1, buffer 0x60C4: capacity read from sub 1
        and 2, cleared and enabled by sub 6): the runner queues setpoints ``lead_s`` ahead and the master
        keeps the drive's buffer filled from that queue up to :data:`IP_BUFFER_MARGIN_RECORDS` below its
        capacity (:meth:`_top_up_ip_buffer`), and the drive takes one per SYNC; an empty buffer at a SYNC
        (an underrun) holds the last record and the sample is logged HELD. The master
        follows the buffer from the bus order of its own RPDOs and the SYNCs, so every sample logs the record
        really applied.
    sync_producer
        ``"master"`` (default): this master produces SYNC from a cyclic task (python-can ``send_periodic``:
        the kernel's broadcast manager on SocketCAN, the interface's own periodic sending where it has one,
        a thread elsewhere), started once the PDOs are configured, before the drive is enabled, and stopped
        after the controlled stop. ``"external"``: another node (a drive or PLC) produces SYNC at the
        sample rate; the master only listens.
    lead_s
        How far ahead of the device's sample instants the runner queues setpoints (default 100 ms, as Klipper schedules ahead); the
        target for sample k goes on the bus right after SYNC k-1, from the receive thread.
    drive_tpdo_latency_cycles, encoder_tpdo_latency_cycles
        The node answers SYNC k after SYNC k + this many (0: before the next SYNC; 1: a device that sends
        the values latched at the previous SYNC, or whose answer takes longer than a period). The drive's is
        checked while streaming where its EDS has 0x6062 (position demand value) and a second TPDO: the
        master maps 0x6062 there, and a demand value that is the previous sample's target stops the run
        saying what to set; an encoder has no such object, so its latency can only be configured. In
        interpolated position a drive that takes each record as the end point of the segment to the next SYNC
        (CiA 402 linear interpolation: its 0x6062 at SYNC k is record k - 1) looks exactly like one that
        answers a SYNC late while streaming; set ``ip_record_is_segment_end`` for it instead.
    ip_record_is_segment_end
        In interpolated position, the drive takes each record as the end point of the segment to the next
        SYNC (CiA 402 linear interpolation leaves open which end of a segment a record is): its 0x6062 at
        SYNC k is the record it took at SYNC k - 1, and its axis reaches a record one SYNC after taking it.
        The demand value is then checked one SYNC back; the statusword and the encoder keep their own
        latencies, so sample 0 (the first SYNC with bit 12) and the encoder's readings are filed where the
        drive sent them, and the log shows the interpolator's one-sample lag between command and angle.
    emcy_warning_codes
        EMCY codes that are warnings, logged and ridden through: comma-separated hex prefixes of the code
        (``"0x4"``, the default, is every temperature code 0x4xxx of CiA 301 Table 21; ``"0x4210,0xFF"``
        names one code and one class; ``""`` stops on every EMCY). Any other EMCY, from either node, stops
        the run; a drive FAULT in the statusword always does.
    trace_path
        Write every frame on the bus (sent and received) to this file with python-can's writers
        (``.blf``, ``.asc``, ``.log``, ``.csv``, ``.trc``; not ``.db``: SqliteWriter drops frames under load).
    """

    RECENT_SAMPLES = 4096
    """Samples whose SYNC time, target in force and instant error are kept (and SYNCs found bunched), for filing
    answers that come late: far more than a pending window, and no more, so that a run of hours keeps flat
    memory."""

    def __init__(self, interface: str, channel: str, *, port: int | None = None, bitrate: int = 1_000_000,
                 drive_node_id: int = 1,
                 encoder_node_id: int = 2, drive_eds: str = str(DEFAULT_DRIVE_EDS),
                 encoder_eds: str = str(DEFAULT_ENCODER_EDS), heartbeat_ms: int = 100,
                 heartbeat_timeout_s: float = 0.5, sdo_timeout_s: float = 0.5, skip_homing: bool = True,
                 homing_method: int = 37, homing_timeout_s: float = 30.0, mode_switch_timeout_s: float = 1.0,
                 mode: str = "auto", sync_producer: str = "master", lead_s: float = 0.1, drive_tpdo_latency_cycles: int = 0,
                 encoder_tpdo_latency_cycles: int = 0, ip_record_is_segment_end: bool = False,
                 emcy_warning_codes: str = "0x4", trace_path: str | None = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.interface, self.channel, self.port, self.bitrate = interface, channel, port, int(bitrate)
        self.drive_node_id, self.encoder_node_id = int(drive_node_id), int(encoder_node_id)
        self.drive_eds, self.encoder_eds = str(drive_eds), str(encoder_eds)
        self.heartbeat_ms = int(heartbeat_ms)
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.sdo_timeout_s = float(sdo_timeout_s)
        self.skip_homing = bool(skip_homing)
        if not -128 <= int(homing_method) <= 127:
            raise ConfigError("<transport>", "homing_method", f"expected a CiA 402 homing method (-128..127), got {homing_method}")
        self.homing_method = int(homing_method)
        self.homing_timeout_s = float(homing_timeout_s)
        if self.drive_node_id == self.encoder_node_id or not all(
                1 <= node <= 127 for node in (self.drive_node_id, self.encoder_node_id)):
            raise ConfigError("<transport>", "drive_node_id", "node-IDs must differ and lie in 1..127")
        self.mode_switch_timeout_s = float(mode_switch_timeout_s)
        if mode not in ("auto", "csp", "ip_buffer"):
            raise ConfigError("<transport>", "mode", f"expected \"auto\", \"csp\" or \"ip_buffer\", got {mode!r}")
        self.mode_requested = mode
        if sync_producer not in ("master", "external"):
            raise ConfigError("<transport>", "sync_producer", f"expected \"master\" or \"external\", got {sync_producer!r}")
        self.sync_producer = sync_producer
        if not lead_s > 0:
            raise ConfigError("<transport>", "lead_s", f"expected a lead > 0 s, got {lead_s!r}")
        self.lead_s = float(lead_s)
        self.latency_cycles = {}
        for part, value in (("drive", drive_tpdo_latency_cycles), ("encoder", encoder_tpdo_latency_cycles)):
            if not 0 <= int(value) <= 8:
                raise ConfigError("<transport>", f"{part}_tpdo_latency_cycles", f"expected 0..8 SYNC periods, got {value}")
            self.latency_cycles[part] = int(value)
        self.latency_cycles["demand"] = self.latency_cycles["drive"]
        self.ip_record_is_segment_end = bool(ip_record_is_segment_end)
        self.emcy_warning_prefixes = emcy_prefixes(emcy_warning_codes)
        self._drive_od = load_object_dictionary("drive_eds", self.drive_eds, self.drive_node_id)
        self._encoder_od = load_object_dictionary("encoder_eds", self.encoder_eds, self.encoder_node_id)
        require_objects("drive_eds", self.drive_eds, self._drive_od, DRIVE_OBJECTS + (
            () if self.skip_homing else ((0x6098, "the homing method (skip_homing = false)"),)) + (
            IP_BUFFER_OBJECTS if mode == "ip_buffer" else ()))
        has_ip_buffer = all(index in self._drive_od for index, _ in IP_BUFFER_OBJECTS)
        self._use_mode("ip_buffer" if mode == "ip_buffer" or (mode == "auto" and has_ip_buffer) else "csp")
        if 0x1006 not in self._drive_od and 0x60C2 not in self._drive_od:
            raise ConfigError("<transport>", "drive_eds", (
                f"{self.drive_eds} has neither 0x1006 (communication cycle period) nor 0x60C2 (interpolation time "
                "period): the master must tell the drive the SYNC period it interpolates over; use the vendor's "
                "EDS with one of them"))
        require_objects("encoder_eds", self.encoder_eds, self._encoder_od, ENCODER_OBJECTS)
        if not (0x6001 in self._encoder_od or 0x6501 in self._encoder_od):
            raise ConfigError("<transport>", "encoder_eds", (
                f"{self.encoder_eds} has neither 0x6001/0x6002 (measuring units per revolution, total measuring "
                "range) nor 0x6501 (single-turn resolution): the master checks the encoder's resolution against "
                "[encoder]; use the vendor's EDS"))
        self.trace_path = check_trace_path(trace_path)
        self._trace = None
        self._checks_latency = {0x6062, 0x1801, 0x1A01} <= set(self._drive_od)
        self._offers_torque = 0x6077 in self._drive_od and bool(getattr(self._drive_od[0x6077], "pdo_mappable", False))
        sync, target, drive_feedback, encoder_feedback = CYCLE_FRAME_BYTES
        frames = (sync, target, drive_feedback + (TORQUE_TPDO_BYTES if self._offers_torque else 0), encoder_feedback,
                  *((DEMAND_TPDO_BYTES,) if self._checks_latency else ()))
        self.load = bus_load(frames, 1.0 / self.sample_period_s, self.bitrate)
        if self.load.load > 1.0:
            raise ConfigError("<transport>", "bitrate", (
                f"{self.bitrate} bit/s cannot carry {1 / self.sample_period_s:g} Hz: one cycle takes "
                f"{self.load.bits_per_cycle} bit ({100 * self.load.load:.0f}% load); the limit is "
                f"{self.load.max_rate_hz:.0f} Hz"))
        self.network = None
        self._drive = None
        self._encoder = None
        self._rpdo: PdoLayout | None = None
        self._hold_rpdo: PdoLayout | None = None  # interpolated position: RPDO2, the hold records
        self._drive_tpdo: PdoLayout | None = None
        self._drive_torque_nm_per_unit: float | None = None  # 0x6076 / 1e6, read where 0x6077 is mapped
        self._demand_tpdo: PdoLayout | None = None
        self._encoder_tpdo: PdoLayout | None = None
        self._mode = self._streaming_mode  # the mode of operation last written to 0x6060
        self._ip_capacity = 0  # records the drive's interpolation buffer takes (0x60C4)
        self._feed: InterpolationFeed | None = None  # interpolated position: queue, records on the bus, the FIFO
        self._period_written = ""  # 0x60C2 as written, for messages
        self._rpdo_transmission_type = 1
        self._jitter_max_s = 0.0  # the largest |SYNC spacing - period| while streaming
        self._ramped: set[int] = set()  # CSP samples whose target was limited on its way back to the plan
        self._ip_enabled_at: int | None = None  # the SYNC count when controlword bit 4 went out
        self._ip_answered_at: int | None = None  # the SYNC count when the drive confirmed it (SDO response)
        self._before_origin: list[tuple[str, Any, float, float]] = []  # TPDOs after bit 4, before bit 12 was seen
        # the SYNCs sample 0 may be at, when the statusword and the SDO answer leave more than one (the demand
        # value 0x6062 decides: CanOpenInterpolation._choose_ip_origin)
        self._ip_origin_choices: tuple[int, ...] = ()
        self._dry_since: int | None = None  # the SYNC count since which the buffer has been empty
        self._last_target_counts = 0
        self._watching = False  # from OPERATION ENABLED on: a FAULT statusword or a heartbeat not OPERATIONAL stops the run
        self._heartbeats: dict[int, tuple[float, int]] = {}  # node-ID -> (host receive time, NMT state)
        self._heartbeat_count: dict[int, int] = {}  # node-ID -> heartbeats received (_await_heartbeats)
        # the bus order of SYNCs and RPDOs, as the interface echoes them (see "Streaming" in the docstring)
        self._echo_probe = threading.Event()
        self._sync_task: Any = None
        self._sync_count = 0  # SYNCs seen on the bus since the producer started
        # (bus time, count) of the recent SYNCs
        self._syncs: collections.deque[tuple[float, int]] = collections.deque(maxlen=self.RECENT_SAMPLES)
        self._unfiled: list[tuple[str, Any, float, float]] = []  # TPDOs after the last SYNC: filed at the next
        self._origin: int | None = None  # the SYNC count of sample 0
        self._queue: dict[int, int] = {}  # sample -> target counts, queued by the runner, not yet on the bus
        self._queued_at: dict[int, float] = {}  # sample -> host time it was queued (for the lead)
        self._rpdo_sent: collections.deque[tuple[int, int]] = collections.deque()  # (sample, counts), echo due
        self._in_force: tuple[int, int] = (-1, 0)  # (sample, counts) of the last RPDO on the bus
        self._applied: dict[int, tuple[int, bool, bool]] = {}  # sample -> (target counts in force, held, limited)
        self._instant_errors: dict[int, float] = {}  # sample -> SYNC spacing minus the period (s)
        self._ambiguous: set[int] = set()  # SYNC counts whose answers cannot be filed for certain
        self._device_sample = -1
        self._latency_evidence = 0  # samples in a row whose 0x6062 was an earlier target (_check_latency)
        # does the configured TPDO latency file the drive's answers under the right SYNC? None until 0x6062
        # shows a changed target (_check_latency); the rows before wait in _unconfirmed
        self._filed_right: bool | None = None
        self._unconfirmed: collections.deque[FeedbackSample] = collections.deque()
        self._fault_sample: int | None = None  # the last sample instant passed when a fault was reported
        self._min_lead_s = float("inf")
        self._lock = threading.Lock()
        self._parts: dict[int, dict[str, Any]] = {}
        self._ready: collections.deque[FeedbackSample] = collections.deque()
        self._arrived = threading.Condition(self._lock)
        self._emcy: tuple[str, int, int] | None = None  # (role, node-ID, EMCY code; 0: FAULT in the statusword)
        self._init_receive_checks()  # frames lost on receive (rig.transports.canopen_receive_checks)

    @property
    def drive_torque_unit(self) -> str | None:
        """Per mille of the rated torque where the drive's EDS makes 0x6077 PDO-mappable: the master maps it into
        the drive's TPDO1 (a drive that then refuses it streams without it, noted in ``warnings``)."""
        return cia402.TORQUE_ACTUAL_UNIT if self._offers_torque else None

    @property
    def drive_torque_nm_per_unit(self) -> float | None:
        """The drive's rated torque 0x6076 (mN m) / 10^6, read at bring-up where 0x6077 is mapped."""
        return self._drive_torque_nm_per_unit

    @property
    def min_cycle_s(self) -> float:
        """One cycle's frames on the bus (worst-case bit stuffing): two SYNCs closer than this are bunched."""
        return 1.0 / self.load.max_rate_hz

    def _use_mode(self, mode: str) -> None:
        """Stream in ``mode`` (``"csp"`` or ``"ip_buffer"``; see the class docstring)."""
        self.mode = mode
        self._streaming_mode = (cia402.INTERPOLATED_POSITION_MODE if mode == "ip_buffer"
                                else cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE)
        self.latency_cycles["demand"] = self.demand_latency_cycles(interpolating=mode == "ip_buffer")

    def demand_latency_cycles(self, interpolating: bool) -> int:
        """How many SYNCs back the drive's 0x6062 is filed: its TPDO latency, plus one in interpolated
        position for a drive that takes each record as the end point of the segment to the next SYNC."""
        return self.latency_cycles["drive"] + int(interpolating and self.ip_record_is_segment_end)

    @property
    def lead_samples(self) -> int:
        return self._samples_ahead(self.lead_s)

    @property
    def sync_jitter_max_s(self) -> float:
        return self._jitter_max_s if self._origin is not None else math.nan

    # -- seam ----------------------------------------------------------------------------------------------

    @property
    def drive_label(self) -> str:
        return f"{self.name} drive {self.drive_node_id}"

    def _connect(self) -> None:
        try:
            import canopen
        except ImportError as err:  # pragma: no cover - canopen is a dependency
            raise TransportError("the canopen transport needs the canopen package: pip install canopen") from err
        with self._translated_errors("start-up"):
            self.network = self._join_bus(canopen)
            self._start_drop_count()
            self.network.sync.cob_id = SYNC_COB_ID
            self.network.subscribe(SYNC_COB_ID, self._on_sync_echo)
            self.network.notifier.add_listener(ErrorFrameListener(self._on_error_frame))
            if self.trace_path is not None:
                import can

                self._trace = can.Logger(self.trace_path)
                self.network.notifier.add_listener(self._trace)
            self._drive = self.network.add_node(self.drive_node_id, self._drive_od)
            self._encoder = self.network.add_node(self.encoder_node_id, self._encoder_od)
            for node in (self._drive, self._encoder):
                node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout_s
                self.network.subscribe(0x700 + node.id, self._on_heartbeat)

    def _join_bus(self, canopen: Any) -> Any:
        """A ``canopen.Network`` connected to the configured interface, receiving its own frames (the SYNC
        and RPDO echoes, see the module docstring), with python-can's notifier thread feeding it. The seam a
        scripted test replaces with a bus on a simulated clock (``tests/transports/clocked_canopen.py``)."""
        network = canopen.Network(open_bus(
            self.interface, self.channel, port=self.port, bitrate=self.bitrate, own_frames=True,
            can_filters=None if self.trace_path is not None else self._receive_filters()))
        network.connect()
        return network

    def _wait_for(self, ready: Any, timeout_s: float) -> bool:
        """Wait on the host's clock, up to ``timeout_s``, until ``ready()`` (evaluated with the lock held)
        is true; whether it is. Every wait of the master for the bus goes through here (the receive thread
        notifies :attr:`_arrived` on every SYNC, TPDO sample, heartbeat and fault), so a scripted test can
        move a simulated clock instead of blocking."""
        with self._arrived:
            return self._arrived.wait_for(ready, timeout_s)

    def _pause_clock(self) -> float:
        return self.clock()  # the bring-up's deadlines on the link's clock, which _pause lets pass

    def _await_heartbeats(self, timeout_s: float) -> None:
        """Wait for a heartbeat from each node received after this call (both have just been told to go
        OPERATIONAL; CiA 301 0x1017 heartbeat producer), at most ``timeout_s``."""
        nodes = {"drive": self.drive_node_id, "encoder": self.encoder_node_id}
        with self._lock:
            seen = {node_id: self._heartbeat_count.get(node_id, 0) for node_id in nodes.values()}

        def heard() -> bool:
            return all(self._heartbeat_count.get(node_id, 0) > count for node_id, count in seen.items())

        if not self._wait_for(heard, timeout_s):
            silent = [f"{role} {node_id}" for role, node_id in nodes.items()
                      if self._heartbeat_count.get(node_id, 0) <= seen[node_id]]
            raise TransportError(f"{self.name}: no heartbeat (0x700 + node-ID) from {', '.join(silent)} within "
                                 f"{timeout_s:g} s of NMT start (0x1017 = {self.heartbeat_ms} ms was written); check "
                                 "that the node is powered and on the bus")

    def _prepare(self) -> float:
        """Steps 1-4 of the module docstring up to, not including, the first enabling controlword."""
        with self._translated_errors("start-up"):
            drive, encoder = self._drive, self._encoder
            for node in (drive, encoder):
                node.nmt.state = "PRE-OPERATIONAL"
                self._sdo_write(node, "drive" if node is drive else "encoder", 0x1017, 0, self.heartbeat_ms,
                                "the producer heartbeat time the master watches")
            self._choose_streaming_mode(drive)
            self._rpdo = self._map_target_rpdo(drive)
            self._check_supported_modes(drive)
            self._take_first_mode(drive)
            self._write_cycle_period(drive)
            self._hold_rpdo = self._map_hold_rpdo(drive)
            self._drive_tpdo = self._map_drive_tpdo(drive)
            self._encoder_tpdo = self._map_pdo(encoder.tpdo, "encoder", [(0x6004, 0, self._encoder_value_bits())],
                                               0x180 + self.encoder_node_id)
            if self.mode == "ip_buffer":
                self._configure_ip_buffer(drive)
            self._demand_tpdo = self._map_demand_tpdo(drive)
            if self.trace_path is None:  # the PDOs' COB-IDs as read back (a static PDO keeps its own)
                self.network.bus.set_filters(self._receive_filters())
            self._check_encoder(encoder)
            self.network.subscribe(self._rpdo.cob_id, self._on_rpdo_echo)
            if self._hold_rpdo is not None:  # (the same buffer: the echoes of both in bus order)
                self.network.subscribe(self._hold_rpdo.cob_id, self._on_rpdo_echo)
            self.network.subscribe(0x580 + self.drive_node_id, self._on_drive_sdo_response)
            self._start_sync()
            drive.tpdo[1].add_callback(self._on_drive_tpdo)
            encoder.tpdo[1].add_callback(self._on_encoder_tpdo)
            if self._demand_tpdo is not None:
                drive.tpdo[2].add_callback(self._on_demand_tpdo)
            for role, node in (("drive", drive), ("encoder", encoder)):
                node.emcy.add_callback(lambda entry, role=role, node_id=node.id: self._on_emcy(role, node_id, entry))
                node.nmt.state = "OPERATIONAL"
            self._await_heartbeats(max(3 * self.heartbeat_ms / 1000, 0.5))
            self._wait_for_mode(drive)
            return self._hold_at_actual_position(drive)

    def _write_controlword(self, controlword: int) -> None:
        with self._translated_errors(f"controlword 0x{controlword:04X}"):
            self._drive.sdo[0x6040].raw = controlword

    def _read_statusword(self) -> int:
        with self._translated_errors("statusword"):
            return self._drive.sdo[0x6041].raw

    def _read_error_code(self) -> int | None:
        if self._drive is None or 0x603F not in self._drive.object_dictionary:
            return None
        return self._drive.sdo[0x603F].raw

    def _after_enabled(self) -> float | None:
        """Homing (``skip_homing = false``), then the streaming mode from where homing left the drive, its
        target again at the actual position; in interpolated position mode, bit 4 of the controlword
        enables the interpolation; the NMT states are watched from here on."""
        moved_to = None
        if not self.skip_homing:
            with self._translated_errors("homing"):
                self._home(self._drive)
                self._set_mode(self._drive, self._streaming_mode)
                self._wait_for_mode(self._drive)
                moved_to = self._hold_at_actual_position(self._drive)
        if self.mode == "ip_buffer":  # bit 4 (enable ip mode) once the buffer holds the lead: _start_interpolation
            with self._lock:
                self._feed = InterpolationFeed(self._ip_capacity, self.lead_samples, self._in_force[1])
        self._await_syncs_in_operation()
        self._say_sync_jitter()
        self._watching = True
        return moved_to

    def _say_sync_jitter(self) -> None:
        """The SYNC's jitter over the bring-up, from the echoes' bus time stamps, logged; where SYNC comes
        from a thread of this process (the interface has no periodic task of its own), also a warning in
        the run summary: a host that is busy delays SYNCs, and a drive with a SYNC watchdog of a few cycles
        (CiA 301 0x1006 with 0x1007, many drives' 0x8700 "SYNC lost") may fault."""
        with self._lock:
            stamps = [bus_time for bus_time, _ in self._syncs]
        spacing = [b - a for a, b in zip(stamps, stamps[1:])]
        if not spacing:
            return
        worst = max(abs(gap - self.sample_period_s) for gap in spacing)
        logger.info("%s: SYNC jitter over the bring-up: %.3g ms over %d periods", self.name, 1e3 * worst, len(spacing))
        if isinstance(self._sync_task, SyncThread):
            self._ride_through(
                f"SYNC comes from a thread of this process ({self.interface} has no periodic sending of its own): "
                f"jitter up to {1e3 * worst:.3g} ms over the bring-up's {len(spacing)} periods, more when the host "
                "is busy; a drive with a SYNC watchdog may fault (EMCY 0x8700); SocketCAN's kernel broadcast "
                "manager or an interface with hardware periodic sending keeps SYNC on time")

    def _await_syncs_in_operation(self) -> None:
        """Let :data:`SYNCS_BEFORE_STREAMING` SYNCs pass after the drive reached OPERATION ENABLED, so that
        the first sample's TPDOs were latched after it even from a drive that answers a SYNC later than
        configured: such a drive is then caught by its 0x6062 (the latency check), not mistaken for one
        that dropped out of OPERATION ENABLED."""
        with self._lock:
            target = self._sync_count + SYNCS_BEFORE_STREAMING
        timeout_s = SYNC_ECHO_TIMEOUT_S + 10 * SYNCS_BEFORE_STREAMING * self.sample_period_s
        if not self._wait_for(lambda: self._sync_count >= target, timeout_s):
            raise TransportError(f"{self.name}: SYNC stopped after the drive was enabled (none for "
                                 f"{timeout_s:g} s); check the SYNC producer")

    def _before_stop(self) -> None:
        """A drive whose heartbeat says STOPPED (CiA 301 0x1029 error behaviour) answers no SDO: bring it to
        pre-operational first, so that the quick stop and disable reach it."""
        if self._feed is not None:
            with self._lock:
                self._feed.streaming = False  # no more hold records: the stop ends the stream
        last = self._heartbeats.get(self.drive_node_id)
        if last is not None and last[1] == 0x04 and self._drive is not None:
            self._drive.nmt.state = "PRE-OPERATIONAL"

    def _stop_harder(self) -> list[str]:
        """The drive was not seen disabled after quick stop and disable: NMT stop (the node leaves
        OPERATIONAL; a CiA 402 drive reacts as its 0x6007 abort connection option says), then NMT reset node,
        the last resort CiA 301 (7.2.8.2.1) offers: the node restarts with its power stage off, and answers
        SDO again once its boot-up message is seen."""
        if self._drive is None or self.network is None:
            return []
        self._watching = False
        steps = []
        for command, name in ((0x02, "NMT stop"), (0x81, "NMT reset node")):
            try:
                self._drive.nmt.send_command(command)
                steps.append(f"{name} sent")
            except Exception as err:  # noqa: BLE001 - the next step is tried anyway
                steps.append(f"{name} failed ({err})")
        try:
            self._drive.nmt.wait_for_bootup(max(2.0, 3 * self.heartbeat_ms / 1000))
            steps.append("boot-up seen")
        except Exception:  # noqa: BLE001 - a node that does not restart: the report says the state is unknown
            steps.append("no boot-up seen")
        return steps

    def _release_devices(self) -> None:
        """NMT pre-operational for both nodes: no more PDOs, SDO still answers."""
        self._watching = False
        for node in (self._drive, self._encoder):
            if node is not None and self.network is not None:
                try:
                    node.nmt.state = "PRE-OPERATIONAL"
                except Exception:  # noqa: BLE001 - best effort: a node off the bus
                    pass
        self._stop_sync()  # the SYNC ran from configuration to the end of the stop (CiA 301)

    @contextlib.contextmanager
    def _translated_errors(self, doing: str) -> Iterator[None]:
        """canopen's and python-can's errors as the driver's (:class:`DeviceFault`, :class:`TransportError`);
        ``doing`` names the step in the message ("start-up", "homing", "controlword 0x000F")."""
        import can
        import canopen

        try:
            yield
        except canopen.SdoAbortedError as err:
            raise DeviceFault(self.name, err.code, f"refused a {doing} SDO: {err}") from err
        except (canopen.SdoCommunicationError, canopen.nmt.NmtError) as err:
            raise TransportError(f"{self.name}: no answer to a {doing} SDO: {err}") from err
        except (OSError, can.CanError) as err:
            raise TransportError(f"{self.name}: CAN {self.interface}/{self.channel} failed ({doing}): {err}") from err

    def _receive_filters(self) -> list[dict[str, int]]:
        """The frames the master listens to (in the kernel on SocketCAN): its SYNC and RPDO echoes, and
        each node's EMCY, TPDO, SDO response and heartbeat. The echoes of its SDO requests and other nodes'
        traffic never reach Python. A trace records every frame, so it runs without filters."""
        cob_ids = [SYNC_COB_ID]
        for node_id in (self.drive_node_id, self.encoder_node_id):
            cob_ids += [0x80 + node_id, 0x180 + node_id, 0x580 + node_id, 0x700 + node_id]
        cob_ids += [layout.cob_id for layout in (self._rpdo, self._hold_rpdo, self._drive_tpdo, self._demand_tpdo,
                                                 self._encoder_tpdo) if layout is not None]
        return [{"can_id": cob_id, "can_mask": 0x7FF, "extended": False}
                for cob_id in sorted(set(cob_ids))] + ERROR_FRAME_FILTERS

    def _start_sync(self) -> None:
        """See :meth:`_start_sync_producer`; waits for the first SYNC on the bus."""
        self._echo_probe.clear()
        if self.sync_producer == "master":
            self._start_sync_producer()
        self._await_first_sync()

    def _start_sync_producer(self) -> None:
        """SYNC from a cyclic task at the sample period: python-can's ``send_periodic`` where the interface
        or the kernel does it (SocketCAN's broadcast manager: hrtimer precision, no Python in the timing),
        else our own :class:`SyncThread`, which, unlike python-can's thread fallback, never sends two SYNCs
        closer than one cycle's bus time when it catches up after a stall (a SYNC wins arbitration over the
        answers to the one before it, which would then be filed under the wrong sample)."""
        import can

        bus = self.network.bus
        if isinstance(bus, can.BusABC) and type(bus)._send_periodic_internal is can.BusABC._send_periodic_internal:
            # python-can would start its thread, which sends a first SYNC at once: SyncThread numbers its sends
            # from the first SYNC on the bus, to tell a late SYNC from a lost echo (canopen_receive_checks)
            self._sync_task = SyncThread(bus, self.sample_period_s, self.min_cycle_s)
            return
        task = bus.send_periodic(sync_message(), self.sample_period_s)
        if type(task).__name__ == "ThreadBasedCyclicSendTask":
            task.stop()
            task = SyncThread(bus, self.sample_period_s, self.min_cycle_s)
        self._sync_task = task

    def _await_first_sync(self) -> None:
        """Start the SYNC producer (``sync_producer = "master"``: a cyclic task at the sample period, from
        now until after the stop) and wait for the first SYNC on the bus: the master numbers the samples by
        the SYNCs it sees, and files each TPDO by its bus timestamp between two of them, so it needs its
        own frames echoed back (or the external producer's SYNC)."""
        if not self._wait_for(self._echo_probe.is_set, SYNC_ECHO_TIMEOUT_S + 10 * self.sample_period_s):
            if self.sync_producer == "external":
                raise TransportError(
                    f"{self.name}: no SYNC (COB-ID 0x{SYNC_COB_ID:02X}) from the external producer within "
                    f"{SYNC_ECHO_TIMEOUT_S:g} s (sync_producer = \"external\"): start the node that produces it, "
                    "or let this master produce SYNC (sync_producer = \"master\")")
            raise TransportError(
                f"{self.name}: the CAN interface {self.interface}/{self.channel} did not echo a transmitted SYNC "
                f"within {SYNC_ECHO_TIMEOUT_S:g} s; the CANopen master needs its own frames back "
                "(python-can receive_own_messages; on SocketCAN keep the default loopback on) to attribute "
                "each TPDO to its SYNC")

    def _stop_sync(self) -> None:
        task, self._sync_task = self._sync_task, None
        if task is not None:
            task.stop()

    def _send(self, setpoint: Setpoint) -> None:
        """CSP: queue setpoint ``seq``; the receive thread puts it on the bus right after SYNC ``seq - 1``,
        so that it is in force at SYNC ``seq`` whatever the host does. Interpolated position: queued, and
        on the bus as soon as the drive's buffer has room (:meth:`_top_up_ip_buffer`)."""
        self._raise_device_fault()
        self._check_heartbeats()
        with self._lock:
            counts = self.drive.counts_from_rad(setpoint.position_rad)
            if self._origin is not None:  # the lead counts once the drive's clock runs the samples (before it,
                self._queued_at[setpoint.seq] = self.clock()  # the first setpoint is just ahead by design)
            if self._feed is not None:
                self._feed.queue_setpoint(setpoint.seq, counts)
                self._put_records_on_bus()
                return
            self._queue[setpoint.seq] = counts
            if self._origin is None:
                return
            behind = self._device_sample - setpoint.seq  # >= -1: its slot right after SYNC seq - 1 has passed
            if behind >= 0:  # its SYNC is past: the device held the previous target (the sample is HELD)
                del self._queue[setpoint.seq]
                self._queued_at.pop(setpoint.seq, None)
                self._min_lead_s = min(self._min_lead_s, -(behind + 1) * self.sample_period_s)
            elif behind == -1:  # late, but its SYNC may still be ahead: the RPDO echoes will tell
                self._min_lead_s = min(self._min_lead_s, 0.0)
                self._put_target_on_bus(setpoint.seq)
                self._queued_at.pop(setpoint.seq, None)

    def end_of_stream(self) -> None:
        if self._feed is not None:
            with self._lock:
                self._feed.finished = True
                self._put_records_on_bus()

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        if self._feed is not None and self._origin is None:  # interpolated position, before sample 0
            if self._ip_enabled_at is None:
                deadline = self.clock() + timeout_s
                self._wait_for(lambda: self._feed.ready_to_start() or self._emcy is not None
                               or self._fault is not None, timeout_s)
                timeout_s = max(deadline - self.clock(), 0.0)
            self._start_interpolation()
        self._wait_for(lambda: self._ready or self._emcy is not None or self._fault is not None, timeout_s)
        sample = self._received_without_starting()
        if sample is not None:
            return sample
        self._raise_device_fault()
        self._check_heartbeats()
        return None

    def _received_without_starting(self) -> FeedbackSample | None:
        """The next sample filed (none after an EMCY); once the run has failed, the rows still waiting for the
        latency's evidence are filed AMBIGUOUS first (:meth:`_report_once_filed_right`)."""
        with self._lock:
            if self._fault is not None and self._unconfirmed:
                self._release_unconfirmed(filed_right=False)
            if self._emcy is None and self._ready:
                return self._ready.popleft()
        return None

    def _close(self) -> None:
        try:
            self._stop_sync()
        except Exception:  # noqa: BLE001 - the bus is gone already
            pass
        self._stop_drop_count()
        network, self.network = self.network, None
        if network is not None:
            try:
                network.disconnect()
            except Exception:  # noqa: BLE001 - already down
                pass
        self._trace = None  # the network's notifier stopped (closed) it with its other listeners

    # -- receive side (python-can notifier thread) -----------------------------------------------------------

    def _on_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        """A heartbeat (CiA 301 0x700 + node-ID): its age is measured on the host's own receive clock
        (interfaces stamp frames with clocks that need not be Unix time), and from OPERATION ENABLED on a
        node that reports any NMT state but OPERATIONAL stops the run."""
        if not data:
            return
        node_id, state = can_id - 0x700, data[0] & 0x7F
        with self._arrived:
            self._heartbeats[node_id] = (self.clock(), state)
            self._heartbeat_count[node_id] = self._heartbeat_count.get(node_id, 0) + 1
            self._arrived.notify_all()  # (wakes _await_heartbeats)
        if self._watching and state != _NMT_OPERATIONAL and self._emcy is None:  # an EMCY names the cause better
            role = "drive" if node_id == self.drive_node_id else "encoder"
            self._report_fault(DeviceFault(f"{self.name} {role} {node_id}", None, (
                f"left OPERATIONAL: its heartbeat says {_NMT_STATES.get(state, f'NMT state 0x{state:02X}')} "
                "(a node that stops its PDOs on an error, CiA 301 0x1029); the samples stop here")))
            with self._arrived:
                self._arrived.notify_all()

    def _on_error_frame(self, message: Any) -> None:
        """An error frame (canopen's own listener ignores them): bus-off stops the run, others are counted."""
        self._count_frame_errors(f"CAN error frame {bytes(message.data).hex()}")
        if is_rx_overflow(message):
            with self._arrived:
                self._check_rx_overflow(describe_error_frame(message))
        if is_bus_off(message):
            self._report_fault(TransportError(
                f"{self.name}: the CAN controller went bus off ({describe_error_frame(message)}): nothing can be "
                "sent or received; check wiring, termination and the bit rate of every node"))
            with self._arrived:
                self._arrived.notify_all()

    def _on_emcy(self, role: str, node_id: int, entry: Any) -> None:
        """EMCY by error class: 0x00xx (error reset) is nothing, a code in ``emcy_warning_codes`` is logged
        in :attr:`warnings` and ridden through, any other code stops the run naming the node that sent it."""
        code = entry.code
        if code & 0xFF00 == 0:
            return
        if is_warning(code, self.emcy_warning_prefixes):
            self._ride_through(f"{role} {node_id}: EMCY 0x{code:04X} ({error_code_meaning(code)}), ridden "
                               "through (emcy_warning_codes)")
            return
        with self._arrived:
            if self._emcy is None:
                self._emcy = (role, node_id, code)
                self._fault_sample = self._device_sample
            self._arrived.notify_all()

    def _raise_device_fault(self) -> None:
        with self._lock:
            emcy = self._emcy
        if emcy is None or self._fault is not None:
            return
        role, node_id, emcy_code = emcy
        if role == "drive":
            try:
                error_code = self._read_error_code()
            except Exception:  # noqa: BLE001 - the fault may have taken the SDO server down too
                error_code = None
            where = "0x603F = " + ("unreadable" if error_code is None else f"0x{error_code:04X}")
            source = f"EMCY 0x{emcy_code:04X} from node {node_id}" if emcy_code else "FAULT in the statusword"
            code = error_code or emcy_code or None
            self._report_fault(DeviceFault(self.drive_label, code, f"fault ({source}; {where})"))
        else:
            self._report_fault(DeviceFault(f"{self.name} encoder {node_id}", emcy_code,
                                           f"fault (EMCY 0x{emcy_code:04X} from node {node_id})"))
        self.raise_fault()

    def _check_heartbeats(self) -> None:
        now = self.clock()
        for role, node_id in (("drive", self.drive_node_id), ("encoder", self.encoder_node_id)):
            last = self._heartbeats.get(node_id)
            if last is not None and now - last[0] > self.heartbeat_timeout_s:
                self._report_fault(DeviceFault(f"{self.name} {role} {node_id}", None, (
                    f"heartbeat lost (none for {now - last[0]:.3g} s, timeout {self.heartbeat_timeout_s:g} s)")))
                self.raise_fault()


SYNCS_BEFORE_STREAMING = 2
"""SYNCs between OPERATION ENABLED and the first setpoint (:meth:`CanOpenTransport._await_syncs_in_operation`)."""
