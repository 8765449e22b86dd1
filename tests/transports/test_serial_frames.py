"""The serial protocol codec: COBS, CRC-16 and resynchronisation, as byte-level scripted exchanges."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given, strategies as st

from rig.protocols.serial_frames import (
    FrameDecoder, FrameError, MessageType, cobs_decode, cobs_encode, crc16, decode_frame, encode_frame, unwrap_seq,
)


def test_crc_is_ccitt_false_with_its_published_check_value():
    assert crc16(b"123456789") == 0x29B1


@given(st.binary(max_size=600))
def test_cobs_round_trip_and_no_zero_bytes(data):
    encoded = cobs_encode(data)
    assert 0 not in encoded
    assert cobs_decode(encoded) == data


def test_feedback_frame_bytes_as_documented():
    # docs/serial_protocol.md, worked example: FEEDBACK seq 0xFFFF, statusword 0x0027, actual -5, encoder 4095
    frame = encode_frame(MessageType.FEEDBACK, 0xFFFF, 0x0027, -5, 4095)
    assert frame.hex() == "0581ffff2707fbffffffff0f0103102e00"
    message = decode_frame(frame[:-1])
    assert (message.type, message.seq, message.fields) == (MessageType.FEEDBACK, 0xFFFF, (0x27, -5, 4095))


def test_decoder_resynchronises_after_garbage_and_counts_the_damage():
    good = encode_frame(MessageType.SETPOINT, 7, 123456)
    decoder = FrameDecoder()
    # garbage ending in a delimiter, a good frame split across two reads, then a good frame
    assert decoder.feed(b"\x13\x37\x00" + good[:4]) == []
    messages = decoder.feed(good[4:] + good)
    assert [(m.type, m.seq, m.fields) for m in messages] == [(MessageType.SETPOINT, 7, (123456,))] * 2
    assert decoder.errors == 1


def test_crc_error_drops_only_the_damaged_frame():
    frame = bytearray(encode_frame(MessageType.SETPOINT, 1, 1000))
    frame[4] ^= 0x01  # one bit flipped in the body (0xE8 of the target 1000 = 0x03E8)
    decoder = FrameDecoder()
    messages = decoder.feed(bytes(frame) + encode_frame(MessageType.SETPOINT, 2, 2000))
    assert [m.seq for m in messages] == [2]
    assert decoder.errors == 1 and "CRC mismatch" in decoder.last_error


def test_decode_names_what_is_wrong():
    with pytest.raises(FrameError, match="unknown message type 0x55"):
        payload = bytes([0x55, 0, 0])
        decode_frame(cobs_encode(payload + crc16(payload).to_bytes(2, "little")))
    with pytest.raises(FrameError, match="SETPOINT body has 2 bytes, expected 4"):
        payload = bytes([0x01, 0, 0, 1, 2])
        decode_frame(cobs_encode(payload + crc16(payload).to_bytes(2, "little")))


def test_a_stream_without_delimiters_is_discarded_and_the_next_frame_decodes():
    decoder = FrameDecoder()
    assert decoder.feed(bytes(range(1, 200))) == []
    assert decoder.errors == 1
    assert [m.seq for m in decoder.feed(b"\x00" + encode_frame(MessageType.CONTROL, 3, 6))] == [3]


@pytest.mark.parametrize(("seq16", "reference", "expected"), [
    (0, 65535, 65536), (65535, 65536, 65535), (5, 5, 5), (3, 131074, 131075)])
def test_sequence_numbers_unwrap_to_the_nearest_sample(seq16, reference, expected):
    assert unwrap_seq(seq16, reference) == expected


DOC = Path(__file__).resolve().parents[2] / "docs" / "serial_protocol.md"


@pytest.mark.parametrize(("kind", "seq", "fields", "wire"), [
    (MessageType.CONTROL, 1, (0x0006,), "03 02 01 02 06 03 9d 89 00"),
    (MessageType.STATUS, 1, (0x0231, 1000), "03 82 01 05 31 02 e8 03 01 03 a2 50 00"),
    (MessageType.ERROR_REQUEST, 7, (), "03 04 07 03 cb 89 00"),
    (MessageType.ERROR, 7, (0x2310,), "03 84 07 05 10 23 85 fc 00"),
    (MessageType.STATUS, 0, (0x0250, 0), "02 82 01 03 50 02 01 01 01 03 b0 55 00"),
])
def test_the_specs_worked_examples_are_the_bytes_on_the_wire(kind, seq, fields, wire):
    assert encode_frame(kind, seq, *fields).hex(" ") == wire
    assert f"`{wire}`" in DOC.read_text()


def test_the_specs_frame_sizes_and_bandwidth_table_hold():
    from rig.protocols.serial_frames import frame_bytes_on_wire, link_load

    text = DOC.read_text()
    for kind in MessageType:
        assert re.search(rf"\| {kind.value:#04x} \| {kind.name} \|.*\| {frame_bytes_on_wire(kind)} \|", text), kind
    assert link_load(1000.0, 115_200).bits_per_cycle == 280
    for baud, rate in re.findall(r"^\| ([\d ]+) \| ([\d ]+) Hz \|$", text, flags=re.M):
        assert int(link_load(1.0, int(baud.replace(" ", ""))).max_rate_hz) == int(rate.replace(" ", ""))
