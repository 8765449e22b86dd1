"""The runner's safety and accounting against a simulated rig with injected faults."""

from __future__ import annotations

import numpy as np

from rig.protocols.cia402 import DriveState
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.errors import DeviceFault, TransportError
from rig.runner import run_experiment
from rig.transports import CommandLimits, CommandRefused
from sim_rigs import ListSink, excitation, no_leaks, simulated  # noqa: F401  (no_leaks is a fixture)


def _run(transport, config, command, sink, **kwargs):
    return run_experiment(transport, command, sink, feedback_timeout_s=config.feedback_timeout_s,
                          late_tolerance_s=config.late_tolerance_s, **kwargs)


TRANSPORTS = ["serial", "canopen", "can"]


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_commands_beyond_the_limits_are_refused_before_the_drive_is_enabled(kind, tmp_path, no_leaks):
    command = excitation(40)
    command[30] = 12.5  # position limit is 12 rad
    sink = ListSink()
    with simulated(kind, tmp_path) as (config, transport, _, drive):
        with pytest.raises(CommandRefused, match=r"setpoint 30: position 12.5 rad is outside the limits \[-12, 12\]"):
            _run(transport, config, command, sink)
        assert drive.setpoints == 0
        assert drive.controlwords == []  # checked against the actual position read before enabling
        assert drive.state is DriveState.SWITCH_ON_DISABLED
    assert sink.closed and sink.rows == []


def test_rate_limit_counts_the_jump_from_the_actual_position(tmp_path, no_leaks):
    command = np.full(10, 5.0)  # from the actual position 0: 5 rad in one 5 ms sample = 1000 rad/s, allowed
    command[5] = -11.0  # a 16 rad jump in 5 ms: 3200 rad/s
    with simulated("serial", tmp_path) as (config, transport, _, drive):
        transport.limits = CommandLimits(-12.0, 12.0, 1500.0)
        with pytest.raises(CommandRefused, match=r"setpoint 5: rate 3200 rad/s .* exceeds the limit 1500 rad/s"):
            _run(transport, config, command, ListSink())
        assert drive.setpoints == 0


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_lost_feedback_is_flagged_per_sample_and_the_run_continues(kind, tmp_path, no_leaks):
    command = excitation(40)
    sink = ListSink()
    with simulated(kind, tmp_path, silent_seqs=[3, 17, 18]) as (config, transport, _, drive):
        summary = _run(transport, config, command, sink)
        # device-clocked (CANopen, serial and raw CAN v2): the drive goes on sampling (holding the last target)
        # until the stop
        assert drive.setpoints >= 40
    flags = np.array([row[4] for row in sink.rows])
    lost = np.flatnonzero(flags & SampleFlag.LOST)
    assert set(lost) >= {3, 17, 18}
    assert summary.lost == len(lost) and len(sink.rows) == 40
    assert all(np.isnan(sink.rows[k][2]) and sink.rows[k][3] is None for k in (3, 17, 18))


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_device_fault_stops_the_run_and_the_log_is_complete_up_to_it(kind, tmp_path, no_leaks):
    sink = ListSink()
    with simulated(kind, tmp_path, fault_at_seq=25, fault_code=0x7500) as (config, transport, _, drive):
        with pytest.raises(DeviceFault, match=r"\(code 0x7500: communication \(additional modules\)\)"):
            _run(transport, config, excitation(40), sink)
        assert drive.setpoints == 25
    assert sink.closed and len(sink.rows) == 26
    assert sink.rows[25][4] & SampleFlag.FAULT  # the sample the drive did not follow is unusable
    assert not any(row[4] & SampleFlag.FAULT for row in sink.rows[:25])


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_watchdog_stops_a_run_whose_feedback_stopped(kind, tmp_path, no_leaks):
    sink = ListSink()
    with simulated(kind, tmp_path, silent_seqs=range(10, 1000)) as (config, transport, _, drive):
        with pytest.raises(TransportError, match=r"no feedback for .* \(watchdog 0.05 s\)"):
            run_experiment(transport, excitation(200), sink, feedback_timeout_s=0.05, late_tolerance_s=0.0025)
        assert drive.controlwords[-2:] == [0x02, 0x00]
    flags = np.array([row[4] for row in sink.rows])
    # serial, raw CAN v2: the host knows the device's instants only from its ticks' frames, so the rows end at
    # the last one heard
    assert sink.closed and (10 < len(sink.rows) if kind == "canopen" else 10 <= len(sink.rows)) < 200
    assert np.all(flags[10:] & SampleFlag.LOST) and not np.any(flags[:10] & SampleFlag.LOST)


@pytest.mark.parametrize("kind", TRANSPORTS)
def test_ctrl_c_ends_with_a_controlled_stop_and_a_closed_log(kind, tmp_path, no_leaks):
    sink = ListSink()

    def interrupt_at_15(done: int, late: int) -> None:
        if done >= 15:  # (not ==: a device-clocked run makes rows final in bursts on a busy host, 14 -> 17)
            raise KeyboardInterrupt

    with simulated(kind, tmp_path) as (config, transport, _, drive):
        with pytest.raises(KeyboardInterrupt):
            _run(transport, config, excitation(40), sink, progress=interrupt_at_15)
        assert drive.controlwords[-2:] == [0x02, 0x00]
        assert not transport.is_open
        sampled = drive.setpoints
    # the device kept its own clock until the stop: every instant it sampled is logged
    assert sink.closed and 15 <= len(sink.rows) <= sampled
    assert [row[0] for row in sink.rows] == pytest.approx([k * config.sample_period_s for k in range(len(sink.rows))])


def test_ctrl_c_while_a_sample_is_being_written_loses_no_sample(tmp_path, no_leaks):
    class InterruptedOnce(ListSink):
        """Ctrl-C lands as the 11th row is handed over, before it is stored."""

        def append(self, *row) -> None:
            if len(self.rows) == 10 and not getattr(self, "interrupted", False):
                self.interrupted = True
                raise KeyboardInterrupt
            super().append(*row)

    sink = InterruptedOnce()
    with simulated("serial", tmp_path) as (config, transport, _, _drive):
        with pytest.raises(KeyboardInterrupt):
            _run(transport, config, excitation(40), sink)
    times = [row[0] for row in sink.rows]
    assert sink.closed and len(times) > 10
    assert times == sorted(set(times))  # every sample once, in order
    assert np.allclose(np.diff(times), times[1] - times[0])  # none skipped


def test_the_watchdog_fires_only_after_the_host_has_listened_through_the_silence():
    """A host paused for 0.3 s (a frozen process) finds the 0.1 s watchdog overdue the moment it wakes; it
    listens for another half of it before giving up, and an answer in that time keeps the run going."""
    from rig.runner import WATCHDOG_GRACE, FeedbackWatchdog

    watchdog = FeedbackWatchdog(0.1, now=10.0)
    assert not watchdog.expired(10.09)
    assert not watchdog.expired(10.3)  # woke up after the pause: overdue, but not heard out yet
    assert not watchdog.expired(10.3 + 0.9 * WATCHDOG_GRACE * 0.1)
    watchdog.fed(10.34)  # the answers that queued during the pause
    assert not watchdog.expired(10.43)
    assert not watchdog.expired(10.45)  # overdue again: listening
    assert watchdog.expired(10.45 + 1.1 * WATCHDOG_GRACE * 0.1)  # a silent device: stopped
    assert "no feedback for 0.16 s (watchdog 0.1 s)" in watchdog.message("rig", 10.5)


def test_a_run_streams_with_the_heap_frozen_and_unfreezes_it(tmp_path, no_leaks):
    """The objects alive before the run are out of the collector's reach while it streams (a full collection
    of them was an 85 ms pause of the runner), and back in it afterwards."""
    import gc

    frozen: list[int] = []
    with simulated("can", tmp_path) as (config, transport, _, _):
        run_experiment(transport, excitation(20), ListSink(), feedback_timeout_s=config.feedback_timeout_s,
                       progress=lambda done, _late: frozen.append(gc.get_freeze_count()))
    assert frozen and min(frozen) > 1000 and gc.get_freeze_count() == 0
