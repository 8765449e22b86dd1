"""A simulated device in a process of its own, as a real device has its own CPU: it shares neither the GIL nor
the garbage collector's pauses with the driver, and a host that is starved does not starve its device with it.

``python -m sim_backend.device_process KIND PLANT.toml [options]`` runs one of

* ``serial``: :class:`~sim_backend.serial_device.SimulatedSerialDevice` on a pty;
* ``canopen``: :class:`~sim_backend.canopen_nodes.SimulatedCanOpenRig` (drive and encoder) on a python-can
  interface that joins processes (``--interface udp_multicast --channel GROUP --port PORT``), with
  ``--produce-sync`` also the SYNC producer on the devices' clock (:class:`SyncProducer`; the master then
  listens, ``sync_producer = "external"``);
* ``can``: :class:`~sim_backend.raw_can_device.SimulatedRawCanDevice` on such an interface.

The child writes its address (the pty path, or the channel) as one line on stdout, serves until its stdin
closes, then writes its :class:`~sim_backend.device_record.DeviceRecord` (``--record FILE``: what it applied at
every SYNC or tick; the targets in ``FILE.targets`` beside it) and ends. :func:`device_process` is the parent's
side: it starts the child, yields a :class:`DeviceProcess` with the address, and on exit stops the child and
reads the record (its targets mapped from the file, which the mapping keeps after the temporary directory is
removed, as POSIX keeps a mapped file that is unlinked).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import random
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from sim_backend.device_record import DeviceRecord, TickLateness

__all__ = ["DeviceProcess", "SyncProducer", "device_process", "main", "multicast_group", "unused_udp_port"]

KINDS = ("serial", "canopen", "can")
STOP_TIMEOUT_S = 30.0  # a child on a loaded machine may take a while to write its record and end
SYNC_COB_ID = 0x80  # CiA 301's default SYNC COB-ID (0x1005)
SYNC_MIN_SPACING = 0.9  # a late SYNC catches up, never closer than this many periods to the one before


@dataclasses.dataclass
class DeviceProcess:
    """A running device child: its ``address`` (pty path or channel), ``pid``, and once it has ended, its
    ``record``."""

    address: str
    pid: int
    record: DeviceRecord | None = None


def unused_udp_port(low: int = 40000, high: int = 60000) -> int:
    """A UDP port no socket of this host is bound to now (``/proc/net/udp``): every bus on one udp_multicast
    port hears every group joined on it, so each simulated rig takes a port of its own."""
    used = set()
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        with contextlib.suppress(OSError), open(table) as lines:
            used.update(int(line.split()[1].rsplit(":", 1)[1], 16) for line in list(lines)[1:])
    return random.choice([port for port in range(low, high) if port not in used])


def multicast_group() -> str:
    """A multicast group of the administratively scoped range (239/8), as python-can's default is."""
    return f"239.74.{random.randrange(1, 255)}.{random.randrange(1, 255)}"


@contextlib.contextmanager
def device_process(kind: str, plant_path: str | os.PathLike, **options: Any) -> Iterator[DeviceProcess]:
    """Run ``python -m sim_backend.device_process KIND PLANT`` with ``options`` (the command-line options as
    keyword arguments: ``seed=3``, ``interface="udp_multicast"``, ``produce_sync=True``); yield the running
    :class:`DeviceProcess`; on exit close its stdin, wait for it and read its record.

    Raises
    ------
    RuntimeError
        The child ended without naming its address, did not end within :data:`STOP_TIMEOUT_S` (it is then
        killed), or ended without a record.
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    with tempfile.TemporaryDirectory(prefix="sim-device-") as directory:
        record_path = Path(directory) / "record.json"
        command = [sys.executable, "-m", "sim_backend.device_process", kind, str(plant_path), "--record", str(record_path)]
        for name, value in options.items():
            if value is None or value is False:
                continue
            command.append(f"--{name.replace('_', '-')}")
            if value is not True:
                command.append(str(value))
        root = Path(__file__).resolve().parents[1]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])))
        child = subprocess.Popen(command, cwd=root, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            address = child.stdout.readline().strip()
            if not address:
                raise RuntimeError(f"{' '.join(command)} ended without naming its address (exit code {child.wait()})")
            running = DeviceProcess(address, child.pid)
            yield running
        finally:
            child.stdin.close()
            child.stdout.close()
            try:
                child.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
                raise RuntimeError(f"the simulated {kind} device (pid {child.pid}) did not end within "
                                   f"{STOP_TIMEOUT_S:g} s of its release: killed") from None
        if not record_path.exists():
            raise RuntimeError(f"the simulated {kind} device (pid {child.pid}) ended (exit code {child.returncode}) "
                               "without writing its record")
        running.record = DeviceRecord.read(record_path)


class SyncProducer:
    """SYNC on ``bus`` every ``period_s`` on the devices' clock, from a thread of the device process (a SYNC
    producer node of the rig, CiA 301 0x1005 bit 30): SYNC k is due at t_0 + k T; one that comes late (the
    device process was starved) goes out at once but never closer than :data:`SYNC_MIN_SPACING` periods to
    the one before, and the following ones return to the grid. With ``devices`` (a
    :class:`~sim_backend.canopen_nodes.SimulatedCanOpenRig`) the next SYNC waits until the devices have answered
    this one (its echo: at most :data:`ANSWER_TIMEOUT_PERIODS` periods, a lost echo is not waited for): a real
    drive answers within microseconds, and a starved simulated one then delays its whole cycle instead of
    answering after the next SYNC. :attr:`lateness` says how late the SYNCs went out (their samples: the
    devices' ``setpoints``)."""

    ANSWER_TIMEOUT_S = 1.0  # a lost echo costs this once; a starved process is waited for

    def __init__(self, bus: Any, period_s: float, devices: Any = None) -> None:
        self.bus, self.period_s, self.devices = bus, float(period_s), devices
        self.lateness = TickLateness()
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-sync-producer", daemon=True)

    def __enter__(self) -> SyncProducer:
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def stop(self) -> None:
        """No more SYNCs (idempotent)."""
        self._stopped.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        import can

        message = can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)
        start = last = time.perf_counter()
        k = 0
        while not self._stopped.is_set():
            instant = start + k * self.period_s
            due = max(instant, last + SYNC_MIN_SPACING * self.period_s)
            remaining = due - time.perf_counter()
            if remaining > 0 and self._stopped.wait(remaining):
                return
            answered = None if self.devices is None else self.devices.syncs_answered
            try:
                self.bus.send(message)
            except can.CanError:
                return  # the bus is going down
            last = time.perf_counter()
            self.lateness.observe(0 if self.devices is None else self.devices.setpoints, last - instant)
            k += 1
            if answered is not None:
                self.devices.wait_for_answers(answered + 1, self.ANSWER_TIMEOUT_S)


def _start(kind: str, args: Any, stack: contextlib.ExitStack) -> tuple[Any, str, SyncProducer | None]:
    """The device of ``kind`` on ``args`` (started in ``stack``), its address, and its SYNC producer."""
    from sim_backend.plant_config import load_plant_config

    gearbox = load_plant_config(args.plant).gearbox(seed=args.seed)
    if kind == "serial":
        from sim_backend.serial_device import SimulatedSerialDevice

        device = stack.enter_context(SimulatedSerialDevice(
            gearbox, drive_counts_per_revolution=args.drive_counts_per_revolution,
            buffer_capacity=args.buffer_capacity, sample_period_s=args.sample_period_s))
        return device, device.port, None
    if args.channel is None:
        raise SystemExit(f"{kind}: --channel is required")
    bus_options = {"channel": args.channel, "interface": args.interface, "port": args.port, "bitrate": args.bitrate,
                   "drive_counts_per_revolution": args.drive_counts_per_revolution}
    if kind == "can":
        from sim_backend.raw_can_device import SimulatedRawCanDevice

        device = stack.enter_context(SimulatedRawCanDevice(
            gearbox, buffer_capacity=min(args.buffer_capacity, 255), sample_period_s=args.sample_period_s,
            **bus_options))
        return device, args.channel, None
    from sim_backend.canopen_nodes import SimulatedCanOpenRig

    eds = {key: value for key, value in (("drive_eds", args.drive_eds), ("encoder_eds", args.encoder_eds)) if value}
    rig = stack.enter_context(SimulatedCanOpenRig(gearbox, drive_node_id=args.drive_node_id,
                                                  encoder_node_id=args.encoder_node_id, **eds, **bus_options))
    producer = None
    if args.produce_sync:
        period_s = gearbox.sample_period_s if args.sample_period_s is None else args.sample_period_s
        producer = stack.enter_context(SyncProducer(rig.network.bus, period_s, rig))
    return rig, args.channel, producer


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sim_backend.device_process KIND PLANT.toml [options]`` (see the module docstring)."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m sim_backend.device_process", description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=KINDS)
    parser.add_argument("plant", help="plant TOML (configs/plants/*.toml)")
    parser.add_argument("--seed", type=int, default=None, help="the plant's noise seed (default: the plant's)")
    parser.add_argument("--sample-period-s", type=float, default=None,
                        help="tick (serial, can) or SYNC (canopen --produce-sync) period; default: the plant's")
    parser.add_argument("--drive-counts-per-revolution", type=int, default=1 << 17)
    parser.add_argument("--buffer-capacity", type=int, default=1024,
                        help="setpoints buffered (serial v2; raw CAN: at most 255)")
    parser.add_argument("--interface", default="udp_multicast", help="python-can interface (canopen, can)")
    parser.add_argument("--channel", default=None, help="python-can channel: the multicast group (canopen, can)")
    parser.add_argument("--port", type=int, default=None, help="udp_multicast's UDP port")
    parser.add_argument("--bitrate", type=int, default=1_000_000, help="for the bus load (canopen, can)")
    parser.add_argument("--drive-node-id", type=int, default=1)
    parser.add_argument("--encoder-node-id", type=int, default=2)
    parser.add_argument("--drive-eds", default=None, help="canopen: the drive's EDS (default: configs/eds/sim_drive_cia402.eds)")
    parser.add_argument("--encoder-eds", default=None, help="canopen: the encoder's EDS (default: configs/eds/sim_encoder_cia406.eds)")
    parser.add_argument("--produce-sync", action="store_true", help="canopen: produce SYNC on the devices' clock")
    parser.add_argument("--record", default=None,
                        help="write the DeviceRecord here at the end (JSON; its targets in FILE.targets beside it)")
    args = parser.parse_args(argv)
    with contextlib.ExitStack() as stack:
        device, address, producer = _start(args.kind, args, stack)
        sys.stdout.write(address + "\n")
        sys.stdout.flush()
        sys.stdin.read()  # until the parent closes the pipe (or ends)
        if producer is not None:
            producer.stop()  # no sample after the record is taken
        record = device.record()
        if producer is not None:
            record = dataclasses.replace(record, tick_delay_max_s=producer.lateness.delay_max_s,
                                         stalls=tuple(producer.lateness.stalls))
    if args.record is not None:
        record.write(args.record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
