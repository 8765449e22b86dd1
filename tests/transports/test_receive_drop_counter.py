"""The interface's own count of frames its receive queue dropped (:func:`rig.protocols.can_interfaces.receive_drop_counter`),
read on a real udp_multicast socket whose buffer is made to overflow, and an RX-overflow error frame."""

from __future__ import annotations

import socket

import can

from rig.protocols.can_error_frames import CAN_ERR_CRTL, is_rx_overflow
from rig.protocols.can_interfaces import open_bus, receive_drop_counter, receive_drops


def test_the_drop_count_of_a_full_udp_multicast_receive_buffer_is_the_kernels():
    """A receiver that does not read while its (smallest) buffer fills: the counter reads what /proc/net/udp says,
    and a bus without a socket of its own (python-can's virtual interface) has no counter."""
    port, group = 43517, "239.74.163.9"  # (a port of its own: every bus of the host on one port hears every group)
    receiver = open_bus("udp_multicast", group, port=port)
    sender = open_bus("udp_multicast", group, port=port)
    try:
        with socket.fromfd(receiver.fileno(), socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)  # the kernel's minimum: a few frames
        counter = receive_drop_counter(receiver, "udp_multicast")
        assert counter is not None and counter() == 0
        for k in range(500):
            sender.send(can.Message(arbitration_id=0x181, data=k.to_bytes(4, "little"), is_extended_id=False))
        dropped = counter()
        assert dropped > 0 and dropped == receive_drops(receiver)
        counter.close()
    finally:
        sender.shutdown()
        receiver.shutdown()
    virtual = can.Bus(interface="virtual", channel="drop-counter-test")
    try:
        assert receive_drop_counter(virtual, "virtual") is None
    finally:
        virtual.shutdown()


def test_an_error_frame_with_the_controllers_rx_overflow_is_told_apart():
    """linux/can/error.h: class CAN_ERR_CRTL, data[1] bit CAN_ERR_CRTL_RX_OVERFLOW (0x01); TX overflow (0x02) and
    other classes are not a receive loss."""
    def frame(can_id: int, status: int) -> can.Message:
        return can.Message(arbitration_id=can_id, is_error_frame=True, dlc=8, data=bytes([0, status, 0, 0, 0, 0, 0, 0]))

    assert is_rx_overflow(frame(CAN_ERR_CRTL, 0x01))
    assert not is_rx_overflow(frame(CAN_ERR_CRTL, 0x02)) and not is_rx_overflow(frame(0x040, 0x01))
