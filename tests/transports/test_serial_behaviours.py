"""The serial and raw-CAN links against the legal behaviours of real devices (docs/serial_protocol.md,
sections 5, 6, 9 and 11): lost answers retried, slow answers and fault resets waited for, boot output skipped,
the error code read, the first command checked against the actual position before enabling, the encoder's
width and first-reading branch, statusword bit 12."""

from __future__ import annotations

import math

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols import cia402
from rig.protocols.cia402 import DriveState
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import DeviceFault, TransportError
from rig.protocols.serial_frames import MessageType, SerialMessage, decode_frame, encode_frame
from rig.runner import run_experiment
from rig.transports.base import CommandLimits, CommandRefused
from rig.transports.serial_link import SerialTransport

from sim_rigs import ListSink, excitation, no_leaks, simulated  # noqa: F401  (no_leaks is a fixture)


def _run(config, transport, command, sink=None):
    return run_experiment(transport, command, sink if sink is not None else ListSink(),
                          feedback_timeout_s=config.feedback_timeout_s, late_tolerance_s=config.late_tolerance_s,
                          pending_cycles=50)


def _assert_disabled_after_stop(device, transport):
    assert device.controlwords[-2:] == [cia402.CONTROLWORD_QUICK_STOP, cia402.CONTROLWORD_DISABLE_VOLTAGE]
    assert device.state is DriveState.SWITCH_ON_DISABLED
    assert transport.stop_report is not None and transport.stop_report.disabled


# -- lost answers ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["serial", "can"])
def test_a_lost_status_answer_right_after_enabling_is_retried_and_the_run_completes(kind, tmp_path, no_leaks):
    """The finding: one lost STATUS answer right after enabling gave exit 3 and nothing else was sent."""
    with simulated(kind, tmp_path, lost_status_after_enable=1) as (config, transport, _, device):
        transport.reply_timeout_s = 0.1
        summary = _run(config, transport, excitation(40))
        assert summary.samples == 40 and summary.lost == 0
        assert device.lost_answers == 1 and transport.retries == 1
        controls = [seq for name, seq in device.requests if name in (MessageType.CONTROL, "RIG_CONTROL")]
        assert len(controls) == len(set(controls)) + 1  # the same request number, sent twice
        assert device.controlwords.count(cia402.CONTROLWORD_ENABLE_OPERATION) == 1  # applied once
        _assert_disabled_after_stop(device, transport)


@pytest.mark.parametrize("kind", ["serial", "can"])
def test_answers_lost_beyond_the_retries_end_in_a_stop_that_disables(kind, tmp_path, no_leaks):
    with simulated(kind, tmp_path, lost_status_after_enable=3) as (config, transport, _, device):
        transport.reply_timeout_s, transport.reply_retries = 0.05, 1
        with pytest.raises(TransportError, match=r"no (RIG_)?STATUS answer to .* 2 attempts") as raised:
            _run(config, transport, excitation(40))
        _assert_disabled_after_stop(device, transport)
        assert "quick stop sent, then disable sent" in " ".join(raised.value.__notes__)


def test_a_statusword_that_cannot_be_decoded_during_the_stop_still_disables(tmp_path, no_leaks, monkeypatch):
    """The finding: a decode error during the stop sent 0x0002 but never 0x0000."""
    from sim_backend.serial_device import SimulatedSerialDevice

    statusword = SimulatedSerialDevice._statusword
    monkeypatch.setattr(SimulatedSerialDevice, "_statusword", lambda self: (
        0x007F if self.state is DriveState.QUICK_STOP_ACTIVE else statusword(self)))  # no CiA 402 state
    with simulated("serial", tmp_path) as (config, transport, _, device):
        summary = _run(config, transport, excitation(20))
        assert summary.samples == 20
        assert device.controlwords[-2:] == [cia402.CONTROLWORD_QUICK_STOP, cia402.CONTROLWORD_DISABLE_VOLTAGE]
        assert device.state is DriveState.SWITCH_ON_DISABLED
        assert transport.stop_report.steps == ("quick stop sent", "disable sent")


# -- slow and unusual devices -------------------------------------------------------------------------------

def test_slow_answers_during_bring_up_are_waited_for(tmp_path, no_leaks):
    with simulated("serial", tmp_path, status_delay_s=0.02) as (config, transport, _, device):
        summary = _run(config, transport, excitation(20))
        assert summary.samples == 20 and summary.lost == 0 and transport.retries == 0
        _assert_disabled_after_stop(device, transport)


def test_a_slow_fault_reset_is_waited_for_and_the_code_is_read_first(tmp_path, no_leaks):
    with simulated("serial", tmp_path, boot_fault_code=0x3220, fault_reset_delay_s=0.2) as (
            config, transport, _, device):
        summary = _run(config, transport, excitation(20))
        assert summary.samples == 20 and summary.lost == 0
        kinds = [kind for kind, _ in device.requests]
        assert kinds.index(MessageType.ERROR_REQUEST) < kinds.index(MessageType.CONTROL)  # read when first seen
        # bit 7 clear first, so that the reset is a rising edge whatever the device last received
        assert device.controlwords[:2] == [cia402.CONTROLWORD_DISABLE_VOLTAGE, cia402.CONTROLWORD_FAULT_RESET]
        assert device.error_code == 0


def test_a_fault_that_cannot_be_reset_is_named_by_the_code_read_from_the_device(tmp_path, no_leaks):
    with simulated("serial", tmp_path, boot_fault_code=0x5441, fault_reset_delay_s=math.inf) as (config, transport, _,
                                                                                               device):
        transport.timing = cia402.BringUpTiming(fault_reset_timeout_s=0.1)
        with pytest.raises(DeviceFault, match=r"\(code 0x5441: safe torque off / enable input inactive\): the drive "
                                              r"stays in FAULT 0.1 s after a fault reset"):
            _run(config, transport, excitation(20))
        assert device.setpoints == 0 and device.state is DriveState.FAULT


def test_a_fault_frame_lost_on_the_line_still_names_the_code(tmp_path, no_leaks):
    sink = ListSink()
    with simulated("serial", tmp_path, fault_at_seq=12, fault_code=0x2310, fault_frame_lost=True) as (
            config, transport, _, device):
        with pytest.raises(DeviceFault, match=r"\(code 0x2310: .*\): the drive reports FAULT in its statusword \(no "
                                              r"FAULT frame came"):
            _run(config, transport, excitation(40), sink)
        assert any(kind is MessageType.ERROR_REQUEST for kind, _ in device.requests)
    assert sink.rows[12][4] & SampleFlag.FAULT


def test_boot_output_and_a_leading_zero_are_skipped_and_not_counted(tmp_path, no_leaks):
    with simulated("serial", tmp_path, boot_banner=b"\x00\x13Bootloader 2.1\r\nstarting app\r\n\x00") as (
            config, transport, _, device):
        summary = _run(config, transport, excitation(20))
        assert summary.samples == 20 and summary.lost == 0 and summary.frame_errors == 0


def test_a_drive_that_keeps_its_old_target_at_enable_does_not_jump_on_the_first_setpoint(tmp_path, no_leaks):
    """The device does not copy actual to target at enable and faults on a far target (following error):
    the host's first setpoint is checked against the actual position before enabling, so it is near."""
    start = 2000  # drive counts, 0.096 rad
    with simulated("serial", tmp_path, copy_target_at_enable=False, following_error_counts=500,
                   initial_actual_counts=start) as (config, transport, _, device):
        first = transport.drive.rad_from_counts(start)
        summary = _run(config, transport, first + 0.01 * np.sin(np.arange(40) / 5))
        assert summary.samples == 40 and summary.lost == 0 and device.state is DriveState.SWITCH_ON_DISABLED


def test_a_first_command_far_from_the_actual_position_is_refused_before_enabling(tmp_path, no_leaks):
    with simulated("serial", tmp_path, copy_target_at_enable=False, following_error_counts=500,
                   initial_actual_counts=200_000) as (config, transport, _, device):
        transport.limits = CommandLimits(-12.0, 12.0, 50.0)
        with pytest.raises(CommandRefused, match=r"setpoint 0: the first command 0 rad is 9.58738 rad from the "
                                                 r"drive's actual position"):
            _run(config, transport, np.zeros(20))
        assert device.controlwords == [] and device.setpoints == 0  # never enabled


def test_the_simulated_drive_faults_on_a_target_beyond_its_following_error_window():
    """What the check above prevents (scripted, no threads)."""
    from sim_backend.plant_config import load_plant_config
    from sim_backend.serial_device import SimulatedSerialDevice
    from sim_rigs import CONFIGS

    gearbox = load_plant_config(CONFIGS / "plants" / "precision_gearbox.toml").gearbox(seed=0)
    device = SimulatedSerialDevice(gearbox, copy_target_at_enable=False, following_error_counts=500)
    try:
        for seq, word in enumerate((0x0006, 0x0007, 0x000F), start=1):
            device.handle(SerialMessage(MessageType.CONTROL, seq, (word,)))
        reply = decode_frame(device.handle(SerialMessage(MessageType.SETPOINT, 0, (10_000,)))[:-1])
        assert (reply.type, reply.fields) == (MessageType.FAULT, (0x8611,))
        answer = decode_frame(device.handle(SerialMessage(MessageType.ERROR_REQUEST, 9, ()))[:-1])
        assert (answer.type, answer.seq, answer.fields) == (MessageType.ERROR, 9, (0x8611,))
    finally:
        device.close()


# -- the FEEDBACK fields ----------------------------------------------------------------------------------------

def _serial(encoder: EncoderResolution) -> SerialTransport:
    return SerialTransport("/dev/null", encoder=encoder, sample_period_s=1e-3)


def test_the_first_reading_of_an_unsigned_encoder_just_below_zero_is_a_small_negative_angle():
    """The finding: a load just below zero was logged near 2 pi. Later readings stay continuous."""
    transport = _serial(EncoderResolution(bits=12))
    transport._dispatch(SerialMessage(MessageType.FEEDBACK, 0, (0x1637, 0, 4091)), 0.0)
    transport._dispatch(SerialMessage(MessageType.FEEDBACK, 1, (0x1637, 0, 3)), 0.0)
    first, second = transport._feedback
    assert math.isclose(first.load_angle_rad, -5 * 2 * math.pi / 4096)
    assert math.isclose(second.load_angle_rad, 3 * 2 * math.pi / 4096)


@pytest.mark.parametrize(("signed", "raw", "expected"), [(True, 0xFFFFFFFB, -5), (False, 0x00000FFB, 4091)])
def test_encoder_values_are_sign_or_zero_extended(signed, raw, expected):
    transport = _serial(EncoderResolution(bits=12, signed=signed))
    transport._dispatch(SerialMessage(MessageType.FEEDBACK, 0, (0x1637, 0, raw)), 0.0)
    assert transport._feedback[0].encoder_counts == expected


def test_an_encoder_value_wider_than_configured_stops_the_run_naming_it():
    transport = _serial(EncoderResolution(bits=12, signed=True))
    transport._dispatch(SerialMessage(MessageType.FEEDBACK, 0, (0x1637, 0, 0x00000FFB)), 0.0)  # not sign-extended
    assert not transport._feedback
    with pytest.raises(TransportError, match=r"encoder_counts 0x00000FFB is no 12-bit signed \(sign-extended\) "
                                             r"position value; check \[encoder\]"):
        transport.raise_fault()


def test_statusword_bit_12_clear_in_operation_enabled_flags_the_sample_not_followed():
    transport = _serial(EncoderResolution(bits=12))
    transport._dispatch(SerialMessage(MessageType.FEEDBACK, 0, (0x0637, 0, 0)), 0.0)
    transport._dispatch(SerialMessage(MessageType.FEEDBACK, 1, (0x1637, 0, 0)), 0.0)
    assert [sample.target_ignored for sample in transport._feedback] == [True, False]


def test_request_numbers_skip_zero_which_marks_unprompted_status():
    transport = _serial(EncoderResolution(bits=12))
    sent = []
    transport._write = sent.append
    transport._request = 0xFFFE
    transport.reply_timeout_s, transport.reply_retries = 0.001, 0
    transport._poll = lambda timeout_s: False
    for _ in range(2):
        with pytest.raises(TransportError):
            transport._read_statusword()
    assert [decode_frame(frame[:-1]).seq for frame in sent] == [0xFFFF, 1]
    assert encode_frame(MessageType.STATUS_REQUEST, 1) == sent[1]
