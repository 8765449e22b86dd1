"""Opening a python-can bus for the driver and the simulated devices alike: what an interface needs beyond its
name and channel.

Most interfaces take ``interface``, ``channel`` and ``bitrate`` and nothing else. ``udp_multicast`` is the
one that joins processes (``virtual`` joins only the threads of one), so a simulated device runs there in a
process of its own, as a real device has its own CPU. It differs from an adapter in three ways that matter here:

* it hands every bus of the host its own frames back (multicast loopback), always: python-can refuses
  ``receive_own_messages=True`` for it, and a node that must not hear itself tells its frames apart by ID;
* its address is a multicast group (the channel) and a UDP port (python-can's default 43113): every bus of the
  host on one port hears every group joined on it, so two rigs on one host need two ports;
* its receive queue is the socket's buffer, ``net.core.rmem_default`` (about 200 kB, some 300 frames: 40 ms of
  a 2 kHz CANopen cycle, own frames included). A process that stops reading for longer loses frames, as an
  adapter does on an RX overrun, and nothing tells the reader. :func:`open_bus` asks for
  :data:`RECEIVE_BUFFER_BYTES` (the kernel caps it at ``net.core.rmem_max``), and :func:`receive_drops`
  reads the kernel's count of datagrams dropped on a full buffer.

Frames carry no time stamp across it: the receiving socket stamps each frame on arrival (``SO_TIMESTAMPNS``),
as an adapter without hardware time stamps does.
"""

from __future__ import annotations

import os
import socket
import sys
from typing import Any

__all__ = ["PORT_INTERFACES", "RECEIVE_BUFFER_BYTES", "echoes_own_frames", "open_bus", "receive_drop_counter",
           "receive_drops"]

UDP_MULTICAST = "udp_multicast"
PORT_INTERFACES = frozenset({UDP_MULTICAST})
"""Interfaces whose address has a port besides the channel (``can://udp_multicast:PORT/GROUP``)."""
RECEIVE_BUFFER_BYTES = 4 << 20
"""The receive buffer asked for on udp_multicast: 4 MB hold about 5000 frames, 0.6 s of a 2 kHz CANopen cycle."""


def echoes_own_frames(interface: str) -> bool:
    """Whether every bus on ``interface`` receives the frames it sent itself, whatever it asks for."""
    return interface == UDP_MULTICAST


def open_bus(interface: str, channel: str, *, port: int | None = None, bitrate: int | None = None,
             own_frames: bool = False, can_filters: list[dict[str, Any]] | None = None) -> Any:
    """A python-can bus on ``interface``/``channel``. ``own_frames``: the bus must receive what it sends (the
    CANopen master's SYNC and RPDO echoes); udp_multicast does so always and is not asked. ``port`` only for
    :data:`PORT_INTERFACES`. Raises what ``can.Bus`` raises."""
    import can

    arguments: dict[str, Any] = {"interface": interface, "channel": channel}
    if bitrate is not None:
        arguments["bitrate"] = bitrate
    if can_filters is not None:
        arguments["can_filters"] = can_filters
    if port is not None:
        if interface not in PORT_INTERFACES:
            raise ValueError(f"a port is for {', '.join(sorted(PORT_INTERFACES))}, not {interface}")
        arguments["port"] = int(port)
    if own_frames and not echoes_own_frames(interface):
        arguments["receive_own_messages"] = True
    bus = can.Bus(**arguments)
    if interface == UDP_MULTICAST:
        _set_receive_buffer(bus, RECEIVE_BUFFER_BYTES)
    return bus


_SO_MEMINFO = 55  # Linux (4.6+): struct sk_meminfo of the socket; SK_MEMINFO_DROPS is its ninth u32
_SK_MEMINFO_DROPS = 8
_SOCKET_FAMILIES = {UDP_MULTICAST: (socket.AF_INET, socket.SOCK_DGRAM),
                    "socketcan": (getattr(socket, "AF_CAN", -1), socket.SOCK_RAW)}


def receive_drop_counter(bus: Any, interface: str) -> Any:
    """A function that returns how many frames the receive queue of ``bus`` has dropped since it opened, cheap
    enough to call at every SYNC; None where the interface keeps no such count.

    udp_multicast and SocketCAN queue received frames in the socket's receive buffer; a frame that finds it full
    is dropped and counted in the socket's ``sk_drops`` (the count SocketCAN hands out as SO_RXQ_OVFL and
    ``/proc/net/udp`` shows as ``drops``), read here with ``getsockopt(SO_MEMINFO)`` on a duplicate of the bus's
    socket (closed with the function's ``close``)."""
    if interface not in _SOCKET_FAMILIES:
        return None
    family, kind = _SOCKET_FAMILIES[interface]
    try:
        sock = socket.fromfd(bus.fileno(), family, kind)
    except (OSError, ValueError, NotImplementedError, AttributeError):
        return None
    try:
        sock.getsockopt(socket.SOL_SOCKET, _SO_MEMINFO, 4 * (_SK_MEMINFO_DROPS + 1))
    except OSError:  # another system, or a kernel without SO_MEMINFO
        sock.close()
        return None

    def drops() -> int:
        info = sock.getsockopt(socket.SOL_SOCKET, _SO_MEMINFO, 4 * (_SK_MEMINFO_DROPS + 1))
        return int.from_bytes(info[4 * _SK_MEMINFO_DROPS:4 * (_SK_MEMINFO_DROPS + 1)], sys.byteorder)

    drops.close = sock.close  # type: ignore[attr-defined]
    return drops


def _socket_of(bus: Any) -> socket.socket:
    """A duplicate of the bus's socket (closing it leaves the bus's own open)."""
    return socket.fromfd(bus.fileno(), socket.AF_INET, socket.SOCK_DGRAM)


def _set_receive_buffer(bus: Any, size_bytes: int) -> None:
    with _socket_of(bus) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size_bytes)


def receive_drops(bus: Any) -> int | None:
    """Datagrams the kernel dropped because the receive buffer of ``bus`` (udp_multicast) was full, since it
    opened (the ``drops`` column of ``/proc/net/udp``); None where that cannot be read (another interface,
    another system, a closed bus)."""
    try:
        with _socket_of(bus) as sock:
            inode = str(os.fstat(sock.fileno()).st_ino)
        for table in ("/proc/net/udp", "/proc/net/udp6"):
            with open(table) as lines:
                next(lines)
                for line in lines:
                    fields = line.split()
                    if fields[9] == inode:
                        return int(fields[-1])
    except (OSError, ValueError, NotImplementedError, AttributeError, StopIteration, IndexError):
        return None  # (AttributeError: a bus without a socket of its own)
    return None
