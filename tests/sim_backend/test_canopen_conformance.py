"""Our simulated CiA 402 drive driven by a master we did not write: canopen's
``canopen.profiles.p402.BaseNode402`` over python-can's ``virtual`` interface (NMT, the state machine,
the mode of operation through 0x6060/0x6061 and 0x6502, PDO set-up read from the drive, CSP targets by
RPDO + SYNC moving the plant, a fault cleared by BaseNode402's own fault reset, homing)."""

from __future__ import annotations

import pytest

from canopen_bench import DRIVE_EDS, FAULT, bench, is_state, no_leaks, wait_until  # noqa: F401
from sim_backend.eds_variants import eds_without

CSP = "CYCLIC SYNCHRONOUS POSITION"


def _stream(b, target: int) -> None:
    """One CSP target by RPDO1 (0x607A); the running SYNC applies it."""
    b.drive.rpdo_pointers[0x607A].raw = target
    b.drive.rpdo_pointers[0x607A].pdo_parent.transmit()


def test_base_node_402_runs_our_drive_through_nmt_state_machine_csp_pdos_and_fault_reset(no_leaks):
    with bench() as b:
        drive, encoder = b.drive, b.encoder
        b.sync_every(0.005)  # CiA 301: the SYNC producer runs from configuration to the end
        for node in (drive, encoder):
            node.nmt.state = "PRE-OPERATIONAL"
            node.sdo[0x1017].raw = 50
        drive.nmt.wait_for_heartbeat(timeout=2.0)
        assert drive.nmt.state == "PRE-OPERATIONAL"
        drive.setup_402_state_machine()  # reads every RPDO/TPDO's communication and mapping by SDO
        assert 0x6041 in drive.tpdo_values and 0x6064 in drive.tpdo_values and 0x607A in drive.rpdo_pointers
        encoder.tpdo.read()
        b.operational()
        wait_until(lambda: drive.nmt.state == "OPERATIONAL", "heartbeat says OPERATIONAL")

        assert drive.is_op_mode_supported(CSP) and drive.is_op_mode_supported("HOMING")  # 0x6502 bits 7, 5
        assert not drive.is_op_mode_supported("PROFILED VELOCITY")
        drive.op_mode = CSP  # writes 0x6060, waits for 0x6061
        assert drive.op_mode == CSP

        drive.check_statusword()
        assert drive.state == "SWITCH ON DISABLED"
        actual = drive.tpdo_values[0x6064]
        _stream(b, actual)  # the master's duty before enabling: target = actual position
        drive.state = "OPERATION ENABLED"
        assert drive.state == "OPERATION ENABLED"
        drive.check_statusword()
        assert drive.statusword & 0x1000  # CSP: drive follows the command value

        samples = b.rig.gearbox.samples
        start_counts = encoder.tpdo[1][0x6004].raw
        for target in (2000, 6000, 12000):
            _stream(b, target)
            wait_until(lambda target=target: drive.tpdo_values[0x6064] == target, f"0x6064 reaches {target}")
        assert b.rig.gearbox.samples > samples
        wait_until(lambda: encoder.tpdo[1][0x6004].raw != start_counts, "the load encoder sees the plant move")

        b.rig.inject_fault(0x7500)
        wait_until(lambda: drive.state == "FAULT", "BaseNode402 sees FAULT in the TPDO")
        wait_until(lambda: 0x7500 in b.emcy_codes(), "EMCY 0x7500")
        assert drive.is_faulted()
        assert drive.sdo[0x603F].raw == 0x7500 and drive.sdo[0x1001].raw & 0x01
        drive.reset_from_fault()  # BaseNode402's own: controlword 0, then the 0x80 edge, then enable
        assert drive.state == "OPERATION ENABLED"
        assert drive.sdo[0x1001].raw == 0

        position = drive.tpdo_values[0x6064]
        _stream(b, position + 3000)
        wait_until(lambda: drive.tpdo_values[0x6064] == position + 3000, "moves again after the reset")

        assert drive.homing(timeout=2.0)  # mode 6, method 37 in 0x6098 (home on the current position)
        drive.op_mode = CSP
        assert drive.op_mode == CSP
        drive.state = "SWITCH ON DISABLED"
        assert drive.state == "SWITCH ON DISABLED"
        for node in (drive, encoder):
            node.nmt.state = "PRE-OPERATIONAL"


def test_base_node_402_needs_0x6502_to_set_a_mode(tmp_path, no_leaks):
    """What BaseNode402 required that our drive lacked: the supported drive modes 0x6502 (it checks the
    mode's bit before writing 0x6060); a vendor EDS without it cannot have its mode set this way."""
    variant = eds_without(DRIVE_EDS, [0x6502], tmp_path / "drive_without_6502.eds")
    with bench(drive_eds=variant) as b:
        b.drive.nmt.state = "PRE-OPERATIONAL"
        with pytest.raises(KeyError):
            b.drive.op_mode = CSP
        b.drive.sdo[0x6060].raw = 8  # the mode itself still works by SDO
        assert b.drive.sdo[0x6061].raw == 8


def test_a_fault_with_the_drive_enabled_is_visible_to_base_node_402_by_tpdo(no_leaks):
    with bench(fault_at_seq=3, fault_code=0x2310) as b:
        b.sync_every(0.005)
        b.drive.nmt.state = "PRE-OPERATIONAL"
        b.drive.setup_402_state_machine()
        b.operational(b.drive)
        b.drive.op_mode = CSP
        b.drive.check_statusword()
        b.drive.state = "OPERATION ENABLED"
        wait_until(lambda: b.drive.is_faulted(), "FAULT at sample 3")
        assert is_state(b.drive.statusword, FAULT)
        wait_until(lambda: 0x2310 in b.emcy_codes(), "EMCY 0x2310 (current)")
        assert b.drive.emcy.log[-1].register == 0x03  # generic + current
        drive_samples = b.rig.setpoints
        b.drive.reset_from_fault()
        assert b.drive.state == "OPERATION ENABLED"
        # an injected fault happens once: the drive re-enabled by BaseNode402 streams on (it used to fault
        # again at once, since the sample count does not advance in FAULT)
        wait_until(lambda: b.rig.setpoints > drive_samples + 10, "streams after the reset")
        assert b.rig.faults == [0x2310] and b.drive.state == "OPERATION ENABLED"


def test_base_node_402_with_controlword_and_mode_display_in_pdos(no_leaks):
    """BaseNode402's preferred set-up: controlword in a cyclic RPDO, statusword and 0x6061 in the TPDO,
    configured by canopen's own PdoMap.save() and read back by setup_402_state_machine()."""
    with bench() as b:
        drive = b.drive
        drive.nmt.state = "PRE-OPERATIONAL"
        drive.pdo.read()
        drive.rpdo[1].clear()
        drive.rpdo[1].add_variable(0x6040)
        drive.rpdo[1].add_variable(0x607A)
        drive.rpdo[1].enabled = True
        drive.rpdo[1].save()
        drive.tpdo[1].clear()
        for index in (0x6041, 0x6064, 0x6061):
            drive.tpdo[1].add_variable(index)
        drive.tpdo[1].trans_type = 1
        drive.tpdo[1].enabled = True
        drive.tpdo[1].save()
        drive.setup_402_state_machine()
        assert {0x6040, 0x607A} <= set(drive.rpdo_pointers) and 0x6061 in drive.tpdo_values
        b.sync_every(0.005)
        b.operational(drive)
        drive.sdo[0x6060].raw = 8
        wait_until(lambda: drive.tpdo_values[0x6061] == 8, "0x6061 = 8 by TPDO")
        assert drive.op_mode == CSP  # read from the TPDO now
        drive.rpdo_pointers[0x607A].raw = drive.tpdo_values[0x6064]
        drive.rpdo_pointers[0x6040].raw = 0
        drive.rpdo[1].start(0.005)  # a synchronous RPDO is periodic for BaseNode402: it only updates values
        drive.state = "OPERATION ENABLED"
        drive.rpdo_pointers[0x607A].raw = 4000
        wait_until(lambda: drive.tpdo_values[0x6064] == 4000, "0x6064 reaches 4000")
        b.rig.inject_fault(0x7500)
        wait_until(lambda: drive.is_faulted(), "FAULT by TPDO")
        drive.reset_from_fault()
        assert drive.state == "OPERATION ENABLED"
        drive.state = "SWITCH ON DISABLED"
        drive.rpdo[1].stop()
