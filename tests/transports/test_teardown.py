"""One bring-up, one teardown (rig.transports.base): whatever fails once the first enabling controlword
has gone out, the drive ends quick-stopped and disabled, on every wire.

Each test breaks one step of the bring-up or of the stop (a lost answer, a refused write, homing that
never ends) and reads the simulated drive's own state machine afterwards.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.protocols import cia402
from rig.protocols.cia402 import DriveState
from rig.protocols.errors import DeviceFault, DriveMayBeEnabled, TransportError
from rig.runner import run_experiment

from sim_rigs import ListSink, excitation, no_leaks, simulated  # noqa: F401  (no_leaks is a fixture)

TRANSPORTS = ["serial", "canopen", "can"]
ENABLING = [cia402.CONTROLWORD_SHUTDOWN, cia402.CONTROLWORD_SWITCH_ON, cia402.CONTROLWORD_ENABLE_OPERATION]


class _LostAnswer:
    """Wraps a transport seam method: the ``fail_at``-th call raises as if the device's answer was lost."""

    def __init__(self, method, fail_at: int, error: Exception) -> None:
        self.method, self.fail_at, self.error, self.calls = method, fail_at, error, 0

    def __call__(self, *args):
        self.calls += 1
        if self.calls == self.fail_at:
            raise self.error
        return self.method(*args)


def _assert_quick_stopped_and_disabled(drive, transport) -> None:
    assert drive.controlwords[-2:] == [cia402.CONTROLWORD_QUICK_STOP, cia402.CONTROLWORD_DISABLE_VOLTAGE]
    assert drive.state is DriveState.SWITCH_ON_DISABLED
    assert transport.stop_report is not None and transport.stop_report.disabled
    assert not transport.is_open


@pytest.mark.parametrize("kind", TRANSPORTS)
@pytest.mark.parametrize("step", [1, 2, 3])
def test_a_lost_answer_at_each_enabling_step_ends_disabled(kind, step, tmp_path, no_leaks):
    """The answer to the 1st/2nd/3rd enabling controlword (shutdown, switch on, enable operation) is lost:
    the bring-up fails, and the teardown still quick-stops and disables the drive."""
    with simulated(kind, tmp_path) as (_, transport, _, drive):
        write, calls = transport._write_controlword, []

        def write_then_lose_the_answer(controlword):
            calls.append(controlword)
            write(controlword)  # the device got it; its confirmation never comes back
            if len(calls) == step:
                raise TransportError("no answer (injected)")

        transport._write_controlword = write_then_lose_the_answer
        with pytest.raises(TransportError, match="no answer") as raised:
            transport.open()
        assert drive.controlwords[:step] == ENABLING[:step]
        _assert_quick_stopped_and_disabled(drive, transport)
        assert "quick stop sent, then disable sent; ends SWITCH ON DISABLED" in " ".join(raised.value.__notes__)


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_a_statusword_that_cannot_be_read_after_enabling_ends_disabled(kind, tmp_path, no_leaks):
    with simulated(kind, tmp_path) as (_, transport, _, drive):
        transport._read_statusword = _LostAnswer(transport._read_statusword, 3, TransportError("no answer (injected)"))
        with pytest.raises(TransportError):
            transport.open()
        _assert_quick_stopped_and_disabled(drive, transport)


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_a_failed_quick_stop_still_disables(kind, tmp_path, no_leaks):
    """The stop itself fails at its first step: disable is still sent, and the report says so."""
    with simulated(kind, tmp_path) as (_, transport, _, drive):
        write = transport._write_controlword

        def quick_stop_lost(controlword):
            if controlword == cia402.CONTROLWORD_QUICK_STOP:
                raise TransportError("quick stop lost (injected)")
            write(controlword)

        transport.open()
        transport._write_controlword = quick_stop_lost
        report = transport.stop()
        assert report.steps == ("quick stop failed (quick stop lost (injected))", "disable sent")
        assert drive.controlwords[-1] == cia402.CONTROLWORD_DISABLE_VOLTAGE
        assert drive.state is DriveState.SWITCH_ON_DISABLED and report.disabled


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_an_error_while_streaming_ends_disabled_and_says_so(kind, tmp_path, no_leaks):
    sink = ListSink()
    with simulated(kind, tmp_path, fault_at_seq=12, fault_code=0x2310) as (config, transport, _, drive):
        with pytest.raises(DeviceFault) as raised:
            run_experiment(transport, excitation(40), sink, feedback_timeout_s=config.feedback_timeout_s,
                           late_tolerance_s=config.late_tolerance_s, pending_cycles=50)
        assert drive.controlwords[-2:] == [cia402.CONTROLWORD_QUICK_STOP, cia402.CONTROLWORD_DISABLE_VOLTAGE]
        notes = " ".join(raised.value.__notes__)
        assert "quick stop sent, then disable sent" in notes
    assert sink.closed


def test_homing_that_never_finishes_ends_disabled_and_pre_operational(tmp_path, no_leaks, monkeypatch):
    """The finding of the issue: homing never finished and the drive stayed OPERATION ENABLED, homing."""
    from sim_backend.canopen_nodes import SimulatedCanOpenRig

    monkeypatch.setattr(SimulatedCanOpenRig, "homed", property(lambda self: False, lambda self, value: None),
                        raising=False)
    with simulated("canopen", tmp_path) as (_, transport, _, rig):
        transport.skip_homing, transport.homing_timeout_s = False, 0.2
        with pytest.raises(DeviceFault, match=r"homing did not finish within 0.2 s") as raised:
            transport.open()
        assert rig.controlwords[-2:] == [cia402.CONTROLWORD_QUICK_STOP, cia402.CONTROLWORD_DISABLE_VOLTAGE]
        assert rig.state is DriveState.SWITCH_ON_DISABLED
        assert rig.drive.nmt.state == rig.encoder.nmt.state == "PRE-OPERATIONAL"
        assert "ends SWITCH ON DISABLED" in raised.value.__notes__[0]


def test_a_failure_before_enabling_sends_no_controlword(tmp_path, no_leaks):
    """A start-up SDO refused before the state machine: nothing enabling went out, so nothing is stopped,
    and the nodes are released (pre-operational)."""
    with simulated("canopen", tmp_path, refuse_sdo_index=0x6060) as (_, transport, _, rig):
        with pytest.raises(DeviceFault, match=r"0x06090030"):
            transport.open()
        assert rig.controlwords == [] and transport.stop_report is None
        assert rig.drive.nmt.state == "PRE-OPERATIONAL"


@pytest.mark.parametrize("kind", TRANSPORTS)
@pytest.mark.parametrize("lost", ["both", "disable"])
def test_a_stop_the_drive_does_not_answer_is_reported_as_not_confirmed(kind, lost, tmp_path, no_leaks):
    """The stop's controlwords get no answer (``both``), or only the disable is lost while the quick stop
    left the drive in QUICK STOP ACTIVE: the run must not end as if the drive were off. The error says
    first that the drive may still be enabled and what the host last saw; on CANopen the master escalates
    to NMT stop and NMT reset node (CiA 301's last resort)."""
    sink = ListSink()
    with simulated(kind, tmp_path) as (config, transport, _, drive):
        write = transport._write_controlword
        stopping = {cia402.CONTROLWORD_DISABLE_VOLTAGE} | (
            {cia402.CONTROLWORD_QUICK_STOP} if lost == "both" else set())

        def unanswered(controlword):
            if transport._state == "stopping" and controlword in stopping:
                raise TransportError("no answer (injected)")
            write(controlword)

        transport._write_controlword = unanswered
        # held in QUICK STOP ACTIVE: the state a drive with 0x605A = 5..8 stays in, whatever the simulation's option
        transport._read_statusword = (lambda read=transport._read_statusword: read()
                                      if transport._state != "stopping" or lost == "both"
                                      else cia402.statusword_for(DriveState.QUICK_STOP_ACTIVE))
        with pytest.raises(DriveMayBeEnabled) as raised:
            run_experiment(transport, excitation(40), sink, feedback_timeout_s=config.feedback_timeout_s,
                           late_tolerance_s=config.late_tolerance_s)
        seen = "OPERATION ENABLED" if lost == "both" else "QUICK STOP ACTIVE"
        message = str(raised.value)
        assert message.startswith(f"{transport.drive_label}: the drive MAY STILL BE ENABLED (last seen {seen})")
        assert transport.stop_report.escalated and not transport.stop_report.confirmed
        if kind == "canopen":
            assert "NMT stop sent, then NMT reset node sent" in message
    assert sink.closed and len(sink.rows) == 40  # the log is complete before the error


def test_rig_run_exits_with_a_device_error_when_the_stop_is_not_confirmed(tmp_path, capsys, monkeypatch, no_leaks):
    """`rig run` never exits 0 unless it saw the drive disabled."""
    from rig import exit_codes
    from rig.cli import main
    from rig.transports.base import Transport

    from sim_rigs import write_test_config

    original = Transport.stop

    def stop_unanswered(self):
        def lost(controlword):
            raise TransportError("no answer (injected)")
        if self._state == "open":
            self._write_controlword = lost
        return original(self)

    monkeypatch.setattr(Transport, "stop", stop_unanswered)
    config = write_test_config("serial", tmp_path)
    experiment = Path(__file__).resolve().parents[2] / "configs" / "experiments" / "prbs.toml"
    code = main(["run", str(config), "--experiment", str(experiment), "--out", str(tmp_path / "run.csv"),
                 "--duration", "0.3"])
    err = capsys.readouterr().err
    assert code == exit_codes.DEVICE_FAULT
    assert err.startswith("rig: device error:") and "MAY STILL BE ENABLED (last seen OPERATION ENABLED)" in err
