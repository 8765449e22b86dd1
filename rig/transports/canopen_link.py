"""CANopen transport: a CiA 402 drive in cyclic synchronous position mode and a CiA 406 load encoder.

Start-up (all by SDO, before any PDO flows):

1. NMT pre-operational for both nodes; producer heartbeat (0x1017) set on both, communication cycle
   period (0x1006) on the drive; mode of operation 0x6060 = 8 (cyclic synchronous position), or 6
   (homing) first if ``skip_homing`` is false.
2. PDO mapping: drive RPDO1 = target position 0x607A; drive TPDO1 = statusword 0x6041 + position actual
   value 0x6064; encoder TPDO1 = position value 0x6004; TPDOs synchronous (transmission type 1: every SYNC).
3. Encoder resolution read from 0x6501 (single-turn) and 0x6002 (total range) and checked against the
   config (whose ``signed`` says how to read 0x6004, since vendors differ).
4. NMT operational; the drive walked to OPERATION ENABLED through the CiA 402 state machine (fault reset
   on a rising edge; the drive's target starts at its actual position, so enabling does not jump);
   optional homing (mode 6, method 0x6098), then mode 8.

Each sample: RPDO1 with the target, then SYNC, both from the runner's own scheduler (never triggered by
TPDO arrival). The TPDOs answering that SYNC make one :class:`FeedbackSample`. TPDOs carry no SYNC
counter, so each TPDO is attributed to the last SYNC on the bus before it, comparing bus timestamps
only: the master receives its own SYNC frames back (``receive_own_messages``, SocketCAN's echo of a
transmitted frame), stamped by the same interface clock as the TPDOs, and echoes come back in the order
the SYNCs were sent, so the k-th echo is SYNC k. The host's own clock never enters: a TPDO that reaches
Python late, or a SYNC whose transmission the host delayed, is still filed under the right sample,
provided the device put its answer on the bus before the next SYNC. An interface that does not echo
transmitted frames is refused at start-up with a message saying so. A second answer to one SYNC is
reported again and the runner flags the sample DUPLICATE (unusable).
EMCY from either node, a drive FAULT in the statusword, or a heartbeat older than ``heartbeat_timeout_s``
stop the run; on a fault the drive's error code 0x603F is read by SDO for the message.
"""

from __future__ import annotations

import collections
import struct
import threading
import time
from pathlib import Path
from typing import Any

from rig.protocols import cia402
from rig.protocols.can_bus_load import bus_load
from rig.protocols.can_error_frames import ERROR_FRAME_FILTERS, describe_error_frame, is_bus_off
from rig.protocols.errors import ConfigError, DeviceFault, TransportError
from rig.transports.base import FeedbackSample, Setpoint, Transport, check_trace_path

__all__ = ["CanOpenTransport", "DEFAULT_DRIVE_EDS", "DEFAULT_ENCODER_EDS"]

_CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "eds"
DEFAULT_DRIVE_EDS = _CONFIGS / "sim_drive_cia402.eds"
DEFAULT_ENCODER_EDS = _CONFIGS / "sim_encoder_cia406.eds"
# data bytes of the frames of one cycle: SYNC, drive RPDO1 (0x607A), drive TPDO1 (0x6041 + 0x6064),
# encoder TPDO1 (0x6004)
CYCLE_FRAME_BYTES = (0, 4, 6, 4)
_DRIVE_TPDO = struct.Struct("<Hi")  # 0x6041 statusword, 0x6064 position actual value
_ENCODER_TPDO = struct.Struct("<I")  # 0x6004 position value
_RPDO = struct.Struct("<i")  # 0x607A target position
SYNC_COB_ID = 0x80  # CiA 301 default (0x1005); the master produces the SYNC
SYNC_ECHO_TIMEOUT_S = 0.5  # the start-up probe's wait for the echo of a SYNC


class CanOpenTransport(Transport):
    """The rig over CANopen.

    Parameters
    ----------
    interface, channel
        python-can interface name and channel (from ``canopen://INTERFACE/CHANNEL``).
    bitrate
        Bus bit rate; the cycle's frames must fit at the sample rate or the constructor raises
        :class:`ConfigError` (worst-case bit stuffing, :mod:`rig.protocols.can_bus_load`).
    drive_node_id, encoder_node_id
        Node-IDs.
    drive_eds, encoder_eds
        Object dictionaries (the vendor's EDS for a real device; the simulated devices' by default).
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
    trace_path
        Write every frame on the bus (sent and received) to this file with python-can's writers
        (``.blf``, ``.asc``, ``.log``, ``.csv``, ``.trc``; not ``.db``: SqliteWriter drops frames under load).
    """

    def __init__(self, interface: str, channel: str, *, bitrate: int = 1_000_000, drive_node_id: int = 1,
                 encoder_node_id: int = 2, drive_eds: str = str(DEFAULT_DRIVE_EDS),
                 encoder_eds: str = str(DEFAULT_ENCODER_EDS), heartbeat_ms: int = 100,
                 heartbeat_timeout_s: float = 0.5, sdo_timeout_s: float = 0.5, skip_homing: bool = True,
                 homing_method: int = 37, homing_timeout_s: float = 30.0, trace_path: str | None = None,
                 **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.interface, self.channel, self.bitrate = interface, channel, int(bitrate)
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
        for key, path in (("drive_eds", self.drive_eds), ("encoder_eds", self.encoder_eds)):
            if not Path(path).is_file():
                raise ConfigError("<transport>", key, f"no such EDS file {path}")
        self.trace_path = check_trace_path(trace_path)
        self._trace = None
        self.load = bus_load(CYCLE_FRAME_BYTES, 1.0 / self.sample_period_s, self.bitrate)
        if self.load.load > 1.0:
            raise ConfigError("<transport>", "bitrate", (
                f"{self.bitrate} bit/s cannot carry {1 / self.sample_period_s:g} Hz: one cycle takes "
                f"{self.load.bits_per_cycle} bit ({100 * self.load.load:.0f}% load); the limit is "
                f"{self.load.max_rate_hz:.0f} Hz"))
        self.network = None
        self._drive = None
        self._encoder = None
        self._rpdo_cob_id = 0x200 + self.drive_node_id
        self._syncs: collections.deque[tuple[float, int]] = collections.deque(maxlen=4096)  # (bus time, seq)
        self._unechoed: collections.deque[int] = collections.deque()  # SYNCs sent, echo not yet back
        self._echo_probe = threading.Event()
        self._sync_sent_at = -float("inf")  # host time just after the last SYNC left (perf_counter)
        self._held: list[tuple[str, Any, float, float]] = []  # TPDOs waiting for an echo (_file_locked)
        self._lock = threading.Lock()
        self._parts: dict[int, dict[str, Any]] = {}
        self._ready: collections.deque[FeedbackSample] = collections.deque()
        self._arrived = threading.Condition(self._lock)
        self._emcy: tuple[str, int] | None = None

    @property
    def min_cycle_s(self) -> float:
        """One cycle's frames on the bus (worst-case bit stuffing): SYNCs/commands are never closer."""
        return 1.0 / self.load.max_rate_hz

    # -- seam ----------------------------------------------------------------------------------------------

    def _open(self) -> float:
        try:
            import canopen
        except ImportError as err:  # pragma: no cover - canopen is a dependency
            raise TransportError("the canopen transport needs the canopen package: pip install canopen") from err
        try:
            self.network = canopen.Network()
            self.network.connect(interface=self.interface, channel=self.channel, bitrate=self.bitrate,
                                 receive_own_messages=True,  # SYNC echoes: see the module docstring
                                 can_filters=None if self.trace_path is not None else self._receive_filters())
            self.network.sync.cob_id = SYNC_COB_ID
            self.network.subscribe(SYNC_COB_ID, self._on_sync_echo)
            self.network.notifier.add_listener(_ErrorFrameListener(self._on_error_frame))
            if self.trace_path is not None:
                import can

                self._trace = can.Logger(self.trace_path)
                self.network.notifier.add_listener(self._trace)
            self._drive = self.network.add_node(self.drive_node_id, self.drive_eds)
            self._encoder = self.network.add_node(self.encoder_node_id, self.encoder_eds)
            for node in (self._drive, self._encoder):
                node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout_s
                node.nmt.state = "PRE-OPERATIONAL"
            return self._configure(canopen)
        except (canopen.SdoAbortedError,) as err:
            raise DeviceFault(self.name, err.code, f"refused a start-up SDO: {err}") from err
        except (canopen.SdoCommunicationError, canopen.nmt.NmtError) as err:
            raise TransportError(f"{self.name}: no answer during start-up: {err}") from err
        except OSError as err:
            raise TransportError(f"{self.name}: cannot open CAN {self.interface}/{self.channel}: {err}") from err
        except Exception as err:
            import can

            if isinstance(err, can.CanError):
                raise TransportError(f"{self.name}: CAN {self.interface}/{self.channel} failed: {err}") from err
            raise

    def _configure(self, canopen: Any) -> float:
        drive, encoder = self._drive, self._encoder
        for node in (drive, encoder):
            node.sdo[0x1017].raw = self.heartbeat_ms
        drive.sdo[0x1006].raw = int(round(self.sample_period_s * 1e6))
        drive.sdo[0x6060].raw = cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE if self.skip_homing else cia402.HOMING_MODE
        self._map_pdo(drive.rpdo, 1, [0x607A], 0x200 + self.drive_node_id)
        self._map_pdo(drive.tpdo, 1, [0x6041, 0x6064], 0x180 + self.drive_node_id)
        self._map_pdo(encoder.tpdo, 1, [0x6004], 0x180 + self.encoder_node_id)
        self._check_encoder_resolution(encoder)
        self._require_sync_echo()
        drive.tpdo[1].add_callback(self._on_drive_tpdo)
        encoder.tpdo[1].add_callback(self._on_encoder_tpdo)
        for node in (drive, encoder):
            node.emcy.add_callback(lambda entry, node_id=node.id: self._on_emcy(node_id, entry))
            node.nmt.state = "OPERATIONAL"
        for node in (drive, encoder):
            node.nmt.wait_for_heartbeat(timeout=max(3 * self.heartbeat_ms / 1000, 0.5))
        cia402.bring_to_operation_enabled(
            lambda word: drive.sdo[0x6040].__setattr__("raw", word), lambda: drive.sdo[0x6041].raw,
            f"{self.name} drive {self.drive_node_id}", timeout_s=10 * self.sdo_timeout_s,
            read_fault_code=lambda: drive.sdo[0x603F].raw)
        if not self.skip_homing:
            self._home(drive)
        actual = drive.sdo[0x6064].raw
        self._rpdo_cob_id = drive.rpdo[1].cob_id
        return self.drive.rad_from_counts(actual)

    def _receive_filters(self) -> list[dict[str, int]]:
        """The frames the master listens to (in the kernel on SocketCAN): its SYNC echo, and each node's
        EMCY, TPDO1, SDO response and heartbeat. The echoes of its own RPDOs and SDO requests and other
        nodes' traffic never reach Python. A trace records every frame, so it runs without filters."""
        cob_ids = [SYNC_COB_ID]
        for node_id in (self.drive_node_id, self.encoder_node_id):
            cob_ids += [0x80 + node_id, 0x180 + node_id, 0x580 + node_id, 0x700 + node_id]
        return [{"can_id": cob_id, "can_mask": 0x7FF, "extended": False} for cob_id in cob_ids] + ERROR_FRAME_FILTERS

    def _require_sync_echo(self) -> None:
        """Send one SYNC while the nodes are pre-operational (no PDO answers it) and wait for its echo:
        without echoes no TPDO could be attributed to its SYNC."""
        self._echo_probe.clear()
        self.network.sync.transmit()
        if not self._echo_probe.wait(SYNC_ECHO_TIMEOUT_S):
            raise TransportError(
                f"{self.name}: the CAN interface {self.interface}/{self.channel} did not echo a transmitted SYNC "
                f"within {SYNC_ECHO_TIMEOUT_S:g} s; the CANopen master needs its own frames back "
                "(python-can receive_own_messages; on SocketCAN keep the default loopback on) to attribute "
                "each TPDO to its SYNC")

    def _home(self, drive: Any) -> None:
        """Homing mode: start with bit 4, wait for "homing attained", then cyclic synchronous position."""
        drive.sdo[0x6098].raw = self.homing_method
        drive.sdo[0x6040].raw = cia402.CONTROLWORD_START_HOMING
        deadline = time.monotonic() + self.homing_timeout_s
        while True:
            statusword = drive.sdo[0x6041].raw
            if statusword & cia402.STATUSWORD_HOMING_ERROR:
                raise DeviceFault(f"{self.name} drive {self.drive_node_id}", drive.sdo[0x603F].raw or None,
                                  f"homing (method {self.homing_method}) failed: statusword 0x{statusword:04X}")
            if statusword & cia402.STATUSWORD_HOMING_ATTAINED:
                break
            if time.monotonic() > deadline:
                raise DeviceFault(f"{self.name} drive {self.drive_node_id}", None,
                                  f"homing did not finish within {self.homing_timeout_s:g} s")
            time.sleep(0.01)
        drive.sdo[0x6040].raw = cia402.CONTROLWORD_ENABLE_OPERATION
        drive.sdo[0x6060].raw = cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE

    @staticmethod
    def _map_pdo(pdos: Any, number: int, indices: list[int], cob_id: int) -> None:
        pdos.read()
        pdo = pdos[number]
        pdo.clear()
        for index in indices:
            pdo.add_variable(index)
        pdo.cob_id = cob_id
        pdo.trans_type = 1
        pdo.enabled = True
        pdo.save()

    def _check_encoder_resolution(self, encoder: Any) -> None:
        per_revolution = encoder.sdo[0x6501].raw
        total = encoder.sdo[0x6002].raw
        expected = (self.encoder.counts_per_revolution, self.encoder.modulus)
        if (per_revolution, total) != expected:
            raise DeviceFault(f"{self.name} encoder {self.encoder_node_id}", None, (
                f"reports {per_revolution} counts per revolution and a range of {total} counts (0x6501, 0x6002), "
                f"but the config says {expected[0]} and {expected[1]} ([encoder] bits, multi_turn_bits)"))

    def _send(self, setpoint: Setpoint) -> None:
        self._raise_device_fault()
        self._check_heartbeats()
        try:
            target = _RPDO.pack(self.drive.counts_from_rad(setpoint.position_rad))  # RPDO1 = 0x607A
            self.network.send_message(self._rpdo_cob_id, target)
        except Exception as err:
            raise TransportError(f"{self.name}: sending setpoint {setpoint.seq} failed: {err}") from err
        # SYNC k+1 must reach the bus after the answers to SYNC k (it would win arbitration over them): the
        # runner spaces its deadlines, this also covers a host that delayed the transmission of SYNC k.
        wait_s = self._sync_sent_at + self.min_cycle_s - time.perf_counter()
        if wait_s > 0:
            time.sleep(wait_s)
        with self._lock:
            self._unechoed.append(setpoint.seq)
        try:
            self.network.sync.transmit()
            self._sync_sent_at = time.perf_counter()
        except Exception as err:
            with self._lock:
                self._unechoed.remove(setpoint.seq)  # never on the bus: no echo will come
            raise TransportError(f"{self.name}: sending SYNC {setpoint.seq} failed: {err}") from err

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        with self._arrived:
            if not self._ready and self._emcy is None:
                self._arrived.wait(timeout_s)
            if self._emcy is None and self._ready:
                return self._ready.popleft()
        self._raise_device_fault()
        self._check_heartbeats()
        return None

    def _stop(self) -> None:
        drive = self._drive
        if drive is None:
            return
        for controlword in (cia402.CONTROLWORD_QUICK_STOP, cia402.CONTROLWORD_DISABLE_VOLTAGE):
            try:
                drive.sdo[0x6040].raw = controlword
            except Exception:  # noqa: BLE001 - the link or drive is gone: nothing more to do from here
                break
        try:
            for node in (self._drive, self._encoder):
                node.nmt.state = "PRE-OPERATIONAL"  # no more PDOs
        except Exception:  # noqa: BLE001
            pass

    def _close(self) -> None:
        network, self.network = self.network, None
        if network is not None:
            try:
                network.disconnect()
            except Exception:  # noqa: BLE001 - already down
                pass
        self._trace = None  # the network's notifier stopped (closed) it with its other listeners

    # -- receive side (python-can notifier thread) -----------------------------------------------------------

    def _on_drive_tpdo(self, pdo: Any) -> None:
        statusword, actual = _DRIVE_TPDO.unpack_from(pdo.data)  # the mapping written at start-up
        self._file("drive", (statusword, actual), pdo.timestamp)
        if cia402.state_from_statusword_or_none(statusword) in (cia402.DriveState.FAULT,
                                                                 cia402.DriveState.FAULT_REACTION_ACTIVE):
            with self._arrived:
                if self._emcy is None:
                    self._emcy = ("drive", 0)
                self._arrived.notify_all()

    def _on_encoder_tpdo(self, pdo: Any) -> None:
        (raw,) = _ENCODER_TPDO.unpack_from(pdo.data)
        counts = raw - (1 << 32) if self.encoder.signed and raw >= 1 << 31 else raw
        self._file("encoder", counts, pdo.timestamp)

    def _on_sync_echo(self, can_id: int, data: bytes, timestamp: float) -> None:
        """Our own SYNC back from the interface with its bus timestamp; echoes come in sending order."""
        with self._arrived:
            if not self._unechoed:
                self._echo_probe.set()  # the start-up probe, or another master's SYNC
                return
            self._syncs.append((timestamp, self._unechoed.popleft()))
            held, self._held = self._held, []
            for part, value, tpdo_time, received in held:
                self._file_locked(part, value, tpdo_time, received)

    def _sync_before(self, timestamp: float) -> int | None:
        """The sample number of the last SYNC on the bus before bus time ``timestamp`` (None: the frame
        answers no SYNC of ours, e.g. it is left over from start-up)."""
        for bus_time, seq in reversed(self._syncs):
            if bus_time <= timestamp:
                return seq
        return None

    def _file(self, part: str, value: Any, timestamp: float) -> None:
        with self._arrived:
            self._file_locked(part, value, timestamp, time.perf_counter())

    def _file_locked(self, part: str, value: Any, timestamp: float, received: float) -> None:
        """File one TPDO under its SYNC. While a SYNC we sent has not echoed yet, a TPDO stamped after
        the last echo may answer that SYNC (a device can answer before the interface hands the master its
        echo): it is held until the next echo says which SYNC came before it."""
        if self._unechoed and (not self._syncs or self._syncs[-1][0] <= timestamp):
            self._held.append((part, value, timestamp, received))
            return
        seq = self._sync_before(timestamp)
        if seq is None:
            return  # an answer to no SYNC of ours (e.g. left over from start-up)
        parts = self._parts.setdefault(seq, {})
        parts[part] = value
        # complete: report the sample; a node answering the same SYNC again (a repeated frame, or a frame
        # delayed past the next SYNC and filed there) reports it again, and the runner flags it DUPLICATE
        if "drive" in parts and "encoder" in parts:
            statusword, actual = parts["drive"]
            self._ready.append(FeedbackSample(
                seq=seq, encoder_counts=parts["encoder"], load_angle_rad=self._decode_encoder(parts["encoder"]),
                drive_position_rad=self.drive.rad_from_counts(actual), statusword=statusword,
                host_time_s=received))
            self._arrived.notify_all()
        if len(self._parts) > 512:
            for old in sorted(self._parts)[:256]:
                del self._parts[old]

    def _on_error_frame(self, message: Any) -> None:
        """An error frame (canopen's own listener ignores them): bus-off stops the run, others are counted."""
        self.frame_errors += 1
        if is_bus_off(message):
            self._report_fault(TransportError(
                f"{self.name}: the CAN controller went bus off ({describe_error_frame(message)}): nothing can be "
                "sent or received; check wiring, termination and the bit rate of every node"))
            with self._arrived:
                self._arrived.notify_all()

    def _on_emcy(self, node_id: int, entry: Any) -> None:
        if entry.code & 0xFF00 == 0:
            return  # error reset / no error
        with self._arrived:
            if self._emcy is None:
                self._emcy = (f"node {node_id}", entry.code)
            self._arrived.notify_all()

    def _raise_device_fault(self) -> None:
        with self._lock:
            emcy = self._emcy
        if emcy is None or self._fault is not None:
            return
        source, emcy_code = emcy
        try:
            error_code = self._drive.sdo[0x603F].raw
        except Exception:  # noqa: BLE001 - the fault may have taken the SDO server down too
            error_code = None
        code = error_code if error_code else emcy_code
        self._report_fault(DeviceFault(f"{self.name} drive {self.drive_node_id}", code,
                                       f"fault (EMCY 0x{emcy_code:04X} from {source}; 0x603F = "
                                       f"{'unreadable' if error_code is None else f'0x{error_code:04X}'})"))
        self.raise_fault()

    def _check_heartbeats(self) -> None:
        now = time.time()
        for role, node in (("drive", self._drive), ("encoder", self._encoder)):
            last = node.nmt.timestamp
            if last is not None and now - last > self.heartbeat_timeout_s:
                fault = DeviceFault(f"{self.name} {role} {node.id}", None,
                                    f"heartbeat lost (none for {now - last:.3g} s, timeout {self.heartbeat_timeout_s:g} s)")
                self._report_fault(fault)
                self.raise_fault()


class _ErrorFrameListener:
    """python-can listener passing error frames to ``callback`` (notifier thread)."""

    def __init__(self, callback: Any) -> None:
        self.callback = callback

    def on_message_received(self, message: Any) -> None:
        if message.is_error_frame:
            self.callback(message)

    __call__ = on_message_received  # python-can's notifier calls its listeners

    def on_error(self, exc: Exception) -> None:  # the notifier's own receive errors: nothing to add
        pass

    def stop(self) -> None:
        pass
