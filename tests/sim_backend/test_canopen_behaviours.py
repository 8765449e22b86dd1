"""Each legal behaviour of the simulated CANopen devices (sim_backend.canopen_behaviour), scripted from
canopen's own master objects over the ``virtual`` interface. Timing: generous deadlines, and only lower
bounds on how long the device takes (it may never be early)."""

from __future__ import annotations

import re
import time

import canopen
import pytest

from canopen_bench import (  # noqa: F401  (no_leaks is a fixture)
    FAULT, OPERATION_ENABLED, QUICK_STOP_ACTIVE, SWITCH_ON_DISABLED, SWITCHED_ON, bench, collect, gearbox, is_state,
    no_leaks, wait_until,
)
from identify.validation import InvalidInputError
from rig.protocols.encoder_counts import EncoderResolution
from sim_backend.canopen_behaviour import DriveBehaviour, EncoderBehaviour, error_register_for
from sim_backend.canopen_nodes import DRIVE_EDS, ENCODER_EDS, SimulatedCanOpenRig, u32_range
from sim_backend.eds_variants import eds_with, eds_without


def _csp_enabled(b, *, sync_period_s: float | None = 0.005) -> None:
    """Pre-operational set-up by SDO, SYNC running, OPERATIONAL, CSP, target = actual, enabled."""
    b.drive.nmt.state = "PRE-OPERATIONAL"
    b.drive.sdo[0x6060].raw = 8
    wait_until(lambda: b.drive.sdo[0x6061].raw == 8, "0x6061 = 8")
    if sync_period_s:
        b.sync_every(sync_period_s)
    b.operational()
    b.drive.sdo[0x607A].raw = b.drive.sdo[0x6064].raw
    b.enable()


def _reset_fault(b) -> None:
    b.controlwords(0x00, 0x80)
    b.wait_state(SWITCH_ON_DISABLED, "SWITCH ON DISABLED after the fault reset")
    b.controlwords(0x00)


# -- 1. target not copied at enable, following error ---------------------------------------------------------

def test_a_standard_drive_keeps_a_stale_target_and_faults_with_a_following_error(no_leaks):
    behaviour = DriveBehaviour(copy_target_on_enable=False, following_error_window_counts=4096)
    with bench(drive_behaviour=behaviour) as b:
        b.drive.nmt.state = "PRE-OPERATIONAL"
        assert b.drive.sdo[0x6065].raw == 4096
        b.drive.sdo[0x6060].raw = 8
        b.drive.sdo[0x607A].raw = 10000  # stale: the plant is at 0
        b.sync_every(0.005)
        b.operational()
        b.controlwords(0x06, 0x07, 0x0F)
        word = b.wait_state(FAULT, "FAULT after enabling with a stale target")
        assert word & 0x2000  # statusword bit 13 in CSP: following error
        assert b.drive.sdo[0x603F].raw == 0x8611
        assert b.drive.sdo[0x1001].raw == error_register_for(0x8611) == 0x21
        wait_until(lambda: 0x8611 in b.emcy_codes(), "EMCY 0x8611")
        assert b.rig.gearbox.samples == 0  # the drive never moved
        assert b.drive.sdo[0x607A].raw == 10000  # and did not touch the target

        _reset_fault(b)
        assert not b.statusword() & 0x2000
        b.drive.sdo[0x607A].raw = b.drive.sdo[0x6064].raw  # what a master must do
        b.enable()
        wait_until(lambda: b.rig.gearbox.samples > 3, "the plant steps")
        b.drive.sdo[0x607A].raw = 3000  # within the window
        wait_until(lambda: b.drive.sdo[0x6064].raw == 3000, "0x6064 follows a step within the window")
        b.drive.sdo[0x607A].raw = 3000 + 5000  # a jump above the window
        b.wait_state(FAULT, "FAULT on a target jump above the window")
        assert b.rig.faults == [0x8611, 0x8611] and b.drive.sdo[0x6064].raw == 3000


def test_a_forgiving_drive_copies_the_target_and_a_stale_power_on_target_is_possible(no_leaks):
    with bench(drive_behaviour=DriveBehaviour(initial_target_counts=10000)) as b:
        b.drive.nmt.state = "PRE-OPERATIONAL"
        assert b.drive.sdo[0x607A].raw == 10000
        b.drive.sdo[0x6060].raw = 8
        b.sync_every(0.005)
        b.operational()
        b.enable()
        assert b.drive.sdo[0x607A].raw == b.drive.sdo[0x6064].raw == 0  # copied at enable: no jump


# -- 2. slow fault reset -------------------------------------------------------------------------------------

def test_a_fault_reset_takes_the_drive_its_time(no_leaks):
    delay_s = 0.3
    with bench(drive_behaviour=DriveBehaviour(fault_reset_delay_s=delay_s)) as b:
        _csp_enabled(b)
        b.rig.inject_fault(0x7500)
        b.wait_state(FAULT, "FAULT")
        b.controlwords(0x00)
        started = time.monotonic()
        b.controlwords(0x80)  # rising edge of bit 7
        word = b.statusword()
        if time.monotonic() - started < delay_s:
            assert is_state(word, FAULT)  # still FAULT while the reset takes its time
        b.controlwords(0x00, 0x80)  # another edge while resetting does not restart or skip anything
        b.wait_state(SWITCH_ON_DISABLED, "SWITCH ON DISABLED after the reset delay")
        assert time.monotonic() - started >= delay_s
        assert b.drive.sdo[0x1001].raw == 0


# -- 3. slow mode switch, statusword bit 12 --------------------------------------------------------------------

def test_the_mode_display_follows_late_and_the_drive_holds_until_it_follows(no_leaks):
    delay_s = 0.4
    with bench(drive_behaviour=DriveBehaviour(mode_switch_delay_s=delay_s)) as b:
        b.drive.nmt.state = "PRE-OPERATIONAL"
        b.sync_every(0.005)
        b.operational()
        started = time.monotonic()
        b.drive.sdo[0x6060].raw = 8
        b.enable()  # the master does not wait for 0x6061: it enables in the old mode
        b.drive.sdo[0x607A].raw = 5000
        word, mode = b.statusword(), b.drive.sdo[0x6061].raw
        demand, actual = b.drive.sdo[0x6062].raw, b.drive.sdo[0x6064].raw
        if time.monotonic() - started < delay_s:  # all read before the switch
            assert mode == 0 and not word & 0x1000  # bit 12: not following the command value
            assert demand == actual == 0  # holding its position
        wait_until(lambda: b.drive.sdo[0x6061].raw == 8, "0x6061 = 8")
        assert time.monotonic() - started >= delay_s
        wait_until(lambda: b.statusword() & 0x1000, "bit 12 once in CSP")
        wait_until(lambda: b.drive.sdo[0x6064].raw == 5000, "follows 0x607A")
        assert b.drive.sdo[0x6062].raw == 5000


# -- 4. enable only with SYNC running, SYNC loss ---------------------------------------------------------------

def test_enable_waits_for_sync_and_sync_loss_faults_the_drive(no_leaks):
    behaviour = DriveBehaviour(enable_requires_sync=True, sync_loss_timeout_s=0.3)
    with bench(drive_behaviour=behaviour) as b:
        b.drive.nmt.state = "PRE-OPERATIONAL"
        b.drive.sdo[0x1006].raw = 10_000  # 10 ms
        b.drive.sdo[0x6060].raw = 8
        b.operational()
        b.controlwords(0x06, 0x07, 0x0F)
        time.sleep(0.2)
        assert is_state(b.statusword(), SWITCHED_ON)  # no SYNC yet: transition 4 waits
        b.sync_every(0.01)
        b.wait_state(OPERATION_ENABLED, "OPERATION ENABLED once SYNC runs")
        b.stop_sync()
        b.wait_state(FAULT, "FAULT on SYNC loss")
        assert b.drive.sdo[0x603F].raw == 0x8700 and b.drive.sdo[0x1001].raw == 0x11
        wait_until(lambda: 0x8700 in b.emcy_codes(), "EMCY 0x8700")


# -- 5. TPDO latency, 0x6062 -----------------------------------------------------------------------------------

@pytest.mark.parametrize("latency", [0, 1, 2])
def test_tpdos_carry_the_values_latched_latency_syncs_earlier(latency, no_leaks):
    with bench(drive_behaviour=DriveBehaviour(tpdo_latency_cycles=latency),
               encoder_behaviour=EncoderBehaviour(tpdo_latency_cycles=latency)) as b:
        drive = b.drive
        drive.nmt.state = "PRE-OPERATIONAL"
        drive.tpdo.read()
        drive.tpdo[2].clear()
        drive.tpdo[2].add_variable(0x6062)  # position demand value beside the actual position
        drive.tpdo[2].add_variable(0x6064)
        drive.tpdo[2].trans_type = 1
        drive.tpdo[2].enabled = True
        drive.tpdo[2].save()
        drive.rpdo.read()
        b.encoder.tpdo.read()
        drive.sdo[0x6060].raw = 8
        b.operational()
        b.controlwords(0x06, 0x07, 0x0F)
        assert is_state(b.statusword(), OPERATION_ENABLED)
        answers, encoder_answers = collect(drive.tpdo[2]), collect(b.encoder.tpdo[1])
        targets = [1000 * (k + 1) for k in range(6)]
        seen, counts = [], []
        for target in targets:
            drive.rpdo[1][0x607A].raw = target
            drive.rpdo[1].transmit()  # synchronous (0x1400:2 = 1): the SYNC behind it in bus order applies it
            b.syncs(1)
            seen.append(answers.get(timeout=2.0))
            counts.append(encoder_answers.get(timeout=2.0)[0x6004])
        expected = [0] * latency + targets[:len(targets) - latency]
        assert [answer[0x6062] for answer in seen] == expected
        assert [answer[0x6064] for answer in seen] == expected
        truth = [box.encoder_counts & 0xFFFFFFFF for box in _plant_run(targets)]
        assert counts[latency:] == truth[:len(truth) - latency]


def _plant_run(targets):
    from rig.protocols.cia402 import DriveScaling

    box, scaling = gearbox(), DriveScaling()
    return [box.step(scaling.rad_from_counts(target)) for target in targets]


# -- 6. static PDOs, transmission type n, 2-byte layout ----------------------------------------------------

def test_static_pdo_parameters_refuse_writes_and_keep_the_eds_layout(tmp_path, no_leaks):
    with bench(drive_behaviour=DriveBehaviour(static_pdos=True),
               encoder_behaviour=EncoderBehaviour(static_pdos=True)) as b:
        b.drive.nmt.state = "PRE-OPERATIONAL"
        for node, index, subindex, value in ((b.drive, 0x1800, 2, 2), (b.drive, 0x1A00, 0, 0), (b.drive, 0x1600, 1, 0),
                                             (b.drive, 0x1400, 2, 1), (b.encoder, 0x1800, 1, 0x182),
                                             (b.encoder, 0x1A00, 1, 0x60040010)):
            with pytest.raises(canopen.SdoAbortedError) as refused:
                node.sdo.download(index, subindex, value.to_bytes(4 if index in (0x1A00, 0x1600) and subindex
                                                                  or (index, subindex) == (0x1800, 1) else 1, "little"))
            assert refused.value.code == 0x06010002, (hex(index), subindex)
        b.drive.tpdo.read()
        assert [(variable.index, variable.length) for variable in b.drive.tpdo[1]] == [(0x6041, 16), (0x6064, 32)]
        drive_eds, encoder_eds = b.rig.write_eds(tmp_path)
    master_od = canopen.import_od(str(drive_eds), 1)
    assert master_od[0x1800][2].access_type == "ro" and master_od[0x1A00][1].access_type == "ro"
    assert canopen.import_od(str(encoder_eds), 2)[0x1A00][0].access_type == "ro"
    assert canopen.import_od(str(DRIVE_EDS), 1)[0x1800][2].access_type == "rw"  # the default device is configurable


def test_a_static_transmission_type_sends_the_tpdo_after_every_nth_sync(no_leaks):
    with bench(encoder_behaviour=EncoderBehaviour(static_pdos=True, static_tpdo_transmission_type=3)) as b:
        b.encoder.nmt.state = "PRE-OPERATIONAL"
        b.encoder.tpdo.read()
        assert b.encoder.tpdo[1].trans_type == 3
        answers = collect(b.encoder.tpdo[1])
        b.operational(b.encoder)
        b.syncs(12)
        wait_until(lambda: answers.qsize() >= 4, "4 encoder TPDOs")
        time.sleep(0.1)
        assert answers.qsize() == 4


def test_a_transmission_type_written_by_the_master_is_honoured(no_leaks):
    with bench() as b:
        b.encoder.nmt.state = "PRE-OPERATIONAL"
        b.encoder.tpdo.read()
        b.encoder.tpdo[1].trans_type = 2
        b.encoder.tpdo[1].save()
        answers = collect(b.encoder.tpdo[1])
        b.operational(b.encoder)
        b.syncs(10)
        wait_until(lambda: answers.qsize() >= 5, "5 encoder TPDOs")
        time.sleep(0.1)
        assert answers.qsize() == 5


def test_a_static_two_byte_encoder_tpdo(no_leaks):
    encoder = EncoderResolution(bits=12, offset_counts=0x0ABC)
    with bench(plant=gearbox(encoder),
               encoder_behaviour=EncoderBehaviour(static_pdos=True, static_tpdo_mapping=(0x60040010,))) as b:
        b.encoder.nmt.state = "PRE-OPERATIONAL"
        b.encoder.tpdo.read()
        assert [(variable.index, variable.length) for variable in b.encoder.tpdo[1]] == [(0x6004, 16)]
        frames = []
        b.network.subscribe(0x180 + 2, lambda can_id, data, timestamp: frames.append(bytes(data)))
        b.operational(b.encoder)
        b.syncs(2)
        wait_until(lambda: len(frames) >= 2, "two encoder TPDOs")
        assert all(len(frame) == 2 for frame in frames)


# -- 7. quick stop option code 0x605A ---------------------------------------------------------------------------

@pytest.mark.parametrize("option, settles_in", [(None, QUICK_STOP_ACTIVE), (0, SWITCH_ON_DISABLED),
                                                (2, SWITCH_ON_DISABLED), (6, QUICK_STOP_ACTIVE)])
def test_quick_stop_follows_the_option_code(option, settles_in, no_leaks):
    with bench(drive_behaviour=DriveBehaviour(quick_stop_option=option, quick_stop_ramp_s=0.05)) as b:
        _csp_enabled(b)
        if option is not None:
            assert b.drive.sdo[0x605A].raw == option
        b.controlwords(0x02)  # quick stop
        word = b.wait_state(settles_in, f"{settles_in} after quick stop")
        time.sleep(0.15)  # well past the ramp: it stays there
        assert is_state(b.statusword(), settles_in), hex(word)
        if option == 6:
            b.controlwords(0x0F)  # transition 16: back to OPERATION ENABLED
            b.wait_state(OPERATION_ENABLED, "OPERATION ENABLED again (transition 16)")
        b.controlwords(0x00)
        b.wait_state(SWITCH_ON_DISABLED, "disable voltage")


def test_the_quick_stop_option_is_an_object_the_master_may_rewrite(no_leaks):
    with bench(drive_behaviour=DriveBehaviour(quick_stop_option=2, quick_stop_ramp_s=0.05)) as b:
        _csp_enabled(b)
        b.drive.sdo[0x605A].raw = 6
        b.controlwords(0x02)
        time.sleep(0.2)
        assert is_state(b.statusword(), QUICK_STOP_ACTIVE)


# -- 8. fault side effects: 0x1001, NMT state ----------------------------------------------------------------

@pytest.mark.parametrize("nmt_on_fault, heartbeat_state", [
    (None, "OPERATIONAL"), ("pre-operational", "PRE-OPERATIONAL"), ("stopped", "STOPPED")])
def test_a_fault_sets_the_error_register_and_may_change_the_nmt_state(nmt_on_fault, heartbeat_state, no_leaks):
    behaviour = DriveBehaviour(nmt_on_fault=nmt_on_fault, emcy_error_reset=True)
    with bench(drive_behaviour=behaviour, sdo_timeout_s=0.3) as b:
        b.drive.sdo[0x1017].raw = 20
        _csp_enabled(b)
        assert b.drive.sdo[0x1001].raw == 0
        b.rig.inject_fault(0x3210)  # DC link over-voltage
        wait_until(lambda: 0x3210 in b.emcy_codes(), "EMCY 0x3210")
        assert b.drive.emcy.log[-1].register == 0x05  # generic + voltage
        wait_until(lambda: b.drive.nmt.state == heartbeat_state, f"heartbeat says {heartbeat_state}")
        if nmt_on_fault == "stopped":
            with pytest.raises(canopen.SdoCommunicationError):
                b.drive.sdo[0x1001].raw  # noqa: B018  (STOPPED: no SDO)
            b.drive.nmt.state = "PRE-OPERATIONAL"
            wait_until(lambda: b.drive.nmt.state == "PRE-OPERATIONAL", "heartbeat says PRE-OPERATIONAL")
        assert b.drive.sdo[0x1001].raw == 0x05 and b.drive.sdo[0x603F].raw == 0x3210
        _reset_fault(b)
        assert b.drive.sdo[0x1001].raw == 0
        wait_until(lambda: b.emcy_codes()[-1] == 0x0000, "EMCY 0x0000 (error reset)")
        assert not b.drive.emcy.active


# -- 9. CiA 406 encoder objects, 32-bit encoders, warnings ---------------------------------------------------

def test_the_encoder_reports_its_resolution_in_the_cia_406_objects(no_leaks):
    with bench(plant=gearbox(EncoderResolution(bits=12, multi_turn_bits=4, direction=-1))) as b:
        sdo = b.encoder.sdo
        b.encoder.nmt.state = "PRE-OPERATIONAL"
        assert (sdo[0x6001].raw, sdo[0x6002].raw, sdo[0x6501].raw, sdo[0x6502].raw) == (4096, 65536, 4096, 16)
        assert sdo[0x6000].raw & 1 == 1  # code sequence: counting down
        sdo[0x6001].raw = 4096  # unchanged: accepted
        with pytest.raises(canopen.SdoAbortedError) as refused:
            sdo[0x6002].raw = 1 << 20  # no scaling function
        assert refused.value.code == 0x06090030


def test_a_32_bit_encoder_writes_its_range_as_0_and_streams_counts_above_2_to_the_31(no_leaks):
    encoder = EncoderResolution(bits=16, multi_turn_bits=16, offset_counts=(1 << 32) - 10)
    with bench(plant=gearbox(encoder)) as b:
        sdo = b.encoder.sdo
        b.encoder.nmt.state = "PRE-OPERATIONAL"
        assert (sdo[0x6001].raw, sdo[0x6002].raw, sdo[0x6502].raw) == (65536, 0, 0)  # 2**32 and 2**16 do not fit
        b.encoder.tpdo.read()
        answers = collect(b.encoder.tpdo[1])
        _csp_enabled(b, sync_period_s=None)
        b.syncs(1)
        assert answers.get(timeout=2.0)[0x6004] == (1 << 32) - 10
    assert u32_range(1 << 32) == 0 and u32_range(4096) == 4096
    with pytest.raises(InvalidInputError, match="UNSIGNED32"):
        SimulatedCanOpenRig(gearbox(EncoderResolution(bits=17, multi_turn_bits=16)), channel="unused")


def test_an_encoder_temperature_warning_does_not_stop_the_encoder(no_leaks):
    behaviour = EncoderBehaviour(emcy_warning_at_seq=3, emcy_warning_cleared_at_seq=8)
    with bench(encoder_behaviour=behaviour, drive_behaviour=DriveBehaviour(emcy_warning_at_seq=4)) as b:
        b.encoder.tpdo.read()
        answers = collect(b.encoder.tpdo[1])
        _csp_enabled(b, sync_period_s=None)
        b.syncs(5)
        wait_until(lambda: 0x4210 in b.emcy_codes(b.encoder), "encoder EMCY 0x4210")
        warning = b.encoder.emcy.log[0]
        assert warning.register == 0x09  # generic + temperature (CiA 301: bit 0 with every error)
        wait_until(lambda: b.emcy_codes(b.drive) == [0x4210], "the drive's own warning, at sample 4")
        assert b.encoder.sdo[0x1001].raw == 0x09
        word = b.statusword()
        assert word & 0x0080 and is_state(word, OPERATION_ENABLED)  # CiA 402 bit 7: warning, still enabled
        b.syncs(5)
        wait_until(lambda: answers.qsize() >= 10, "the encoder keeps answering")
        wait_until(lambda: b.emcy_codes(b.encoder)[-1] == 0x0000, "warning cleared: EMCY 0x0000")
        assert b.encoder.sdo[0x1001].raw == 0 and is_state(b.statusword(), OPERATION_ENABLED)


# -- 10. EDS variants without optional objects ---------------------------------------------------------------

def test_eds_variants_without_optional_objects_load_and_run(tmp_path, no_leaks):
    drive_eds = eds_without(DRIVE_EDS, [0x1006, 0x603F, 0x6098, 0x6502], tmp_path / "drive_minimal.eds")
    encoder_eds = eds_without(ENCODER_EDS, [0x6501, 0x6002], tmp_path / "encoder_minimal.eds")
    drive_od, encoder_od = canopen.import_od(str(drive_eds), 1), canopen.import_od(str(encoder_eds), 2)
    assert not {0x1006, 0x603F, 0x6098, 0x6502} & set(drive_od.indices) and 0x6041 in drive_od
    assert not {0x6501, 0x6002} & set(encoder_od.indices) and 0x6004 in encoder_od
    text = drive_eds.read_text()
    optional = int(re.search(r"\[OptionalObjects\]\s*SupportedObjects=(\d+)", DRIVE_EDS.read_text())[1])
    assert "0x603F" not in text and f"SupportedObjects={optional - 4}" in text  # the object list renumbered (4 dropped)
    with bench(drive_eds=drive_eds, encoder_eds=encoder_eds,
               drive_behaviour=DriveBehaviour(enable_requires_sync=True)) as b:
        with pytest.raises(canopen.SdoAbortedError) as missing:
            b.drive.sdo.upload(0x603F, 0)
        assert missing.value.code == 0x06020000  # object does not exist
        _csp_enabled(b)
        b.rig.inject_fault(0x7500)
        b.wait_state(FAULT, "FAULT without 0x603F")
        wait_until(lambda: 0x7500 in b.emcy_codes(), "EMCY still says which fault")


def test_eds_with_marks_pdo_parameters_read_only_and_changes_defaults(tmp_path):
    out = eds_with(DRIVE_EDS, tmp_path / "drive_static.eds", static_pdos=True, defaults={(0x6065, 0): 1000})
    od = canopen.import_od(str(out), 1)
    assert all(od[index][sub].access_type in ("ro", "const") for index in (0x1400, 0x1600, 0x1800, 0x1A00)
               for sub in od[index].subindices)
    assert od[0x6065].default == 1000 and od[0x6041].access_type == "ro" and od[0x6040].access_type == "rww"
    with pytest.raises(KeyError, match="0x1234"):
        eds_with(DRIVE_EDS, tmp_path / "x.eds", defaults={(0x1234, 0): 1})


# -- the behaviour objects themselves --------------------------------------------------------------------------

def test_behaviours_are_validated_and_default_to_the_old_devices():
    assert DriveBehaviour().non_default() == {} and EncoderBehaviour().non_default() == {}
    assert DriveBehaviour(fault_reset_delay_s=0.02).non_default() == {"fault_reset_delay_s": 0.02}
    for bad in ({"tpdo_latency_cycles": -1}, {"static_tpdo_transmission_type": 2}, {"quick_stop_option": 9},
                {"nmt_on_fault": "reset"}, {"fault_reset_delay_s": -1.0}, {"sync_loss_timeout_s": 0},
                {"static_pdos": True, "static_tpdo_mapping": (0x60040000,)}):
        with pytest.raises(InvalidInputError):
            DriveBehaviour(**bad)
    assert [error_register_for(code) for code in (0x0000, 0x7500, 0x2310, 0x4210, 0x8130, 0x8611, 0x8700, 0xFF01)] == [
        0x00, 0x01, 0x03, 0x09, 0x11, 0x21, 0x11, 0x81]


def test_every_named_device_of_the_variety_starts_and_closes(tmp_path, no_leaks):
    from sim_backend.canopen_behaviour import OPTIONAL_OBJECTS_MISSING, real_variety

    variety = real_variety()
    assert variety["forgiving (default)"] == (DriveBehaviour(), EncoderBehaviour())
    for name, (drive_behaviour, encoder_behaviour) in variety.items():
        rig = SimulatedCanOpenRig(gearbox(), channel=f"variety_{abs(hash(name))}", drive_behaviour=drive_behaviour,
                                  encoder_behaviour=encoder_behaviour)
        with rig:
            assert rig.drive.nmt.state == "PRE-OPERATIONAL", name
    for name, (device, indices) in OPTIONAL_OBJECTS_MISSING.items():
        source = DRIVE_EDS if device == "drive" else ENCODER_EDS
        path = eds_without(source, indices, tmp_path / f"{device}_{'_'.join(f'{i:04X}' for i in indices)}.eds")
        with SimulatedCanOpenRig(gearbox(), channel=f"variety_eds_{abs(hash(name))}", **{f"{device}_eds": path}) as rig:
            node = rig.drive if device == "drive" else rig.encoder
            assert not set(indices) & set(node.object_dictionary.indices), name
