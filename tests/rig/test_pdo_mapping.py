"""The PDO mapping of a network, as another master's start-up writes it by SDO (CiA 301 7.5.2.35-38) or as a
DCF gives it (CiA 306)."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.protocols.pdo_mapping import MappedObject, mapping_from_dcf, mapping_from_sdo_writes


def _download(node: int, index: int, sub: int, value: int, size: int) -> list[tuple[int, bytes]]:
    """An expedited SDO download with its size indicated (CiA 301 7.2.4.3.3) and the server's confirmation."""
    command = 0x23 | ((4 - size) << 2)
    request = bytes((command, index & 0xFF, index >> 8, sub)) + value.to_bytes(size, "little") + bytes(4 - size)
    return [(0x600 + node, request), (0x580 + node, bytes((0x60, index & 0xFF, index >> 8, sub, 0, 0, 0, 0)))]


def _tpdo2_configured(node: int, cob_id: int) -> list[tuple[int, bytes]]:
    """TPDO2 of ``node`` set up as the standard's procedure does it: disabled, count 0, two entries, count 2,
    enabled on ``cob_id``."""
    return [*_download(node, 0x1801, 1, cob_id | 1 << 31, 4), *_download(node, 0x1A01, 0, 0, 1),
            *_download(node, 0x1A01, 1, 0x60640020, 4), *_download(node, 0x1A01, 2, 0x60410010, 4),
            *_download(node, 0x1A01, 0, 2, 1), *_download(node, 0x1801, 1, cob_id, 4)]


def test_a_start_up_s_sdo_writes_give_the_mapping_and_its_frames_decode():
    mapping = mapping_from_sdo_writes(_tpdo2_configured(3, 0x283), "trace")
    pdo = mapping.carrying(3, 0x6041, receive=False)
    assert pdo is not None and pdo.cob_id == 0x283 and pdo.number == 2
    assert pdo.objects == (MappedObject(0x6064, 0, 32), MappedObject(0x6041, 0, 16))
    frame = (-1234).to_bytes(4, "little", signed=True) + (0x1237).to_bytes(2, "little")
    values = pdo.decode(frame)
    assert values == {(0x6064, 0): (-1234) & 0xFFFFFFFF, (0x6041, 0): 0x1237}
    assert pdo.decode(frame[:5]) is None  # shorter than its mapping
    assert mapping.carrying(3, 0x6041, receive=True) is None and mapping.carrying(4, 0x6041, receive=False) is None


def test_an_aborted_write_changes_nothing_and_a_disabled_pdo_is_not_there():
    writes = _tpdo2_configured(3, 0x283)
    aborted = [(0x603, writes[8][1]), (0x583, bytes((0x80, 0x01, 0x1A, 0x01, 0x30, 0x00, 0x09, 0x06)))]
    mapping = mapping_from_sdo_writes([*writes[:8], *aborted, *writes[10:]], "trace")
    assert mapping is None  # the count of 2 was refused: it stays 0, the PDO maps nothing
    disabled = mapping_from_sdo_writes(writes[:-2], "trace")  # never enabled again: bit 31 of its COB-ID set
    assert disabled is None
    default_cob = mapping_from_sdo_writes([w for w in writes if w[1][1:3] != bytes((0x01, 0x18))], "trace")
    assert default_cob is not None and default_cob.carrying(3, 0x6064, receive=False).cob_id == 0x283  # CiA 301 7.3.5


def test_a_dcf_gives_the_mapping_with_its_node_id(tmp_path):
    dcf = tmp_path / "encoder.dcf"
    dcf.write_text("[DeviceComissioning]\nNodeID=9\n\n[1800sub1]\nParameterName=COB-ID\nParameterValue=$NODEID+0x1A0\n"
                   "\n[1A00sub0]\nParameterValue=1\n\n[1A00sub1]\nParameterValue=0x60040020\n")
    mapping = mapping_from_dcf({9: dcf})
    pdo = mapping.carrying(9, 0x6004, receive=False)
    assert pdo is not None and pdo.cob_id == 0x1A9 and pdo.objects == (MappedObject(0x6004, 0, 32),)
    empty = tmp_path / "empty.dcf"
    empty.write_text("[1000]\nParameterValue=0x192\n")
    with pytest.raises(ValueError, match=r"empty\.dcf: maps no PDO of node 9"):
        mapping_from_dcf({9: empty})


def test_the_pdos_a_start_up_writes_are_known_disabled_ones_too():
    writes = [*_tpdo2_configured(3, 0x283), *_download(3, 0x1400, 1, 0x203 | 1 << 31, 4)]  # RPDO1 disabled
    mapping = mapping_from_sdo_writes(writes, "trace")
    assert set(mapping.pdos) == {0x283}
    assert {(3, False, 2), (3, True, 1)} <= mapping.configured


def test_a_start_up_that_maps_some_pdos_keeps_this_driver_s_mapping_for_the_others():
    """A master that configures only the drive's TPDO2 (0x6064 then 0x6041) and leaves the rest as they were:
    the statusword is read where the writes put it, the target and the encoder from this driver's mapping."""
    import can

    from rig.trace_import import _canopen_mapping

    frames = [(0.001 * k, k, can.Message(arbitration_id=cob, data=data, is_extended_id=False))
              for k, (cob, data) in enumerate(_tpdo2_configured(3, 0x283))]
    mapping = _canopen_mapping(Path("t.blf"), frames, 3, 9, None)
    assert mapping.carrying(3, 0x6041, receive=False).cob_id == 0x283  # written, before the assumed TPDO1
    assert mapping.carrying(3, 0x607A, receive=True).cob_id == 0x203 and mapping.carrying(9, 0x6004, receive=False)
    assert "this driver's mapping for the PDOs they leave alone" in mapping.source
