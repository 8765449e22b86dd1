"""The device-clocked loop gives queueing setpoints and filing ticks each their turn: a scripted link whose
device ticks faster than the host reads (the host throttled, the device in a process of its own) never runs
dry, and the setpoints must still go out, and the feedback watchdog must not trip while ticks arrive. No
thread, no sleep: the link's clock moves only when the host reads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols import cia402
from rig.protocols.cia402 import BringUpTiming, DriveState
from rig.protocols.encoder_counts import EncoderResolution
from rig.runner import run_experiment
from rig.transports.base import FeedbackSample, Setpoint, Transport

from clocked_line import SimulatedClock
from sim_rigs import ListSink

PERIOD_S = 1e-3


class ScriptedDriveLink(Transport):
    """A link whose drive is the CiA 402 state machine alone, answered at once (the scripted links below add
    what they send and receive)."""

    _statusword = cia402.statusword_for(DriveState.SWITCH_ON_DISABLED)

    def _connect(self) -> None:
        pass

    def _prepare(self) -> float:
        return 0.0

    def _write_controlword(self, controlword: int) -> None:
        state = cia402.next_state(cia402.state_from_statusword(self._statusword), controlword, 0)
        self._statusword = cia402.statusword_for(state) | (cia402.STATUSWORD_FOLLOWS_TARGET
                                                           if state is DriveState.OPERATION_ENABLED else 0)

    def _read_statusword(self) -> int:
        return self._statusword


class FloodingLink(ScriptedDriveLink):
    """A device that ticks every ``PERIOD_S`` from the first receive on, and a host that needs ``read_cost_s``
    of its clock for every TICK it reads: with ``read_cost_s > PERIOD_S`` the host never catches up, so every
    receive finds a tick waiting (the input never runs dry). A setpoint counts as in time when it was sent
    before its tick's instant; otherwise the tick is HELD with the target of the tick before.

    ``starved_after``: this many receives without a setpoint in between fail the test (the device's link
    watchdog would have stopped the drive)."""

    def __init__(self, *, lead: int, read_cost_s: float, total: int, starved_after: int = 400,
                 hears_every_tick_at_once: bool = False, stall_at: int | None = None, stall_s: float = 0.0,
                 stamps_arrival: bool = False) -> None:
        self.link_clock = SimulatedClock(100.0)
        super().__init__(encoder=EncoderResolution(bits=16), sample_period_s=PERIOD_S, name="flood",
                         clock=self.link_clock, timing=BringUpTiming(poll_interval_s=0.0))
        self._lead, self.read_cost_s, self.total, self.starved_after = lead, read_cost_s, total, starved_after
        self._statusword = cia402.statusword_for(DriveState.SWITCH_ON_DISABLED)
        self.sent: dict[int, tuple[float, float]] = {}  # seq -> (host time sent, position)
        self.receives_without_send = self.most_receives_without_send = 0
        self._tick0_s: float | None = None
        self._in_force = 0.0
        self.applied: list[float] = []  # per tick, the target in force
        # like a link that reads everything received in one read (serial): the device's position is the last
        # tick that has arrived, though the host has filed only the oldest of them
        self.hears_every_tick_at_once = hears_every_tick_at_once
        self.sends_since_receive = self.most_sends_between_receives = 0
        self._next_unread = 0
        self.stall_at, self.stall_s = stall_at, stall_s
        self.stamps_arrival = stamps_arrival  # host_time_s: when the tick reached the host, not when it was read

    @property
    def lead_samples(self) -> int:
        return self._lead

    def _send(self, setpoint: Setpoint) -> None:
        self.sent[setpoint.seq] = (self.link_clock(), setpoint.position_rad)
        self.receives_without_send = 0
        if self._tick0_s is not None and setpoint.seq > self._device_sample:  # ahead of the device, once it runs
            self.sends_since_receive += 1
            self.most_sends_between_receives = max(self.most_sends_between_receives, self.sends_since_receive)

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        if len(self.sent) < self.total:  # setpoints still to send
            self.receives_without_send += 1
        self.most_receives_without_send = max(self.most_receives_without_send, self.receives_without_send)
        if self.receives_without_send > self.starved_after:
            raise AssertionError(f"{self.receives_without_send} ticks read and no setpoint sent: the device's "
                                 "link watchdog stops the drive")
        self.sends_since_receive = 0
        if self._tick0_s is None:
            self._tick0_s = self.link_clock()
        self.link_clock.advance_to(self.link_clock() + self.read_cost_s)
        k = self._next_unread  # the oldest tick not read yet
        instant = self._tick0_s + k * PERIOD_S
        if instant > self.link_clock():  # not there yet: the host waits for it, at most timeout_s
            if instant > self.link_clock() + timeout_s:
                self.link_clock.advance_to(self.link_clock() + timeout_s)
                return None
            self.link_clock.advance_to(instant)
        if k == self.stall_at:  # the host stalls right after reading this tick
            self.link_clock.advance_to(self.link_clock() + self.stall_s)
        self._next_unread += 1
        sent = self.sent.get(k)
        held = sent is None or sent[0] > instant
        if not held:
            self._in_force = sent[1]
        self._device_sample = max(self._device_sample, k)
        if self.hears_every_tick_at_once:
            self._device_sample = math.floor((self.link_clock() - self._tick0_s) / PERIOD_S + 1e-9)
        self.applied.append(self._in_force)
        return FeedbackSample(seq=k, encoder_counts=k, load_angle_rad=0.0, drive_position_rad=self._in_force,
                              statusword=self._statusword, held=held,
                              host_time_s=max(instant, self.link_clock() - 1.0) if self.stamps_arrival
                              else self.link_clock(),
                              applied_position_rad=self._in_force)

    def _close(self) -> None:
        pass


@pytest.mark.parametrize("lead_samples", [1, 16, 250])
def test_setpoints_are_queued_every_turn_while_ticks_never_stop_arriving(lead_samples):
    """The host reads a tick every 1.5 ms while the device ticks every 1 ms: there is always a tick to file.
    The runner still queues setpoints between ticks (bounded work per turn), and the watchdog, fed with the
    time each tick was received, does not trip: the run completes with every row filed."""
    link = FloodingLink(lead=lead_samples, read_cost_s=1.5e-3, total=600)
    sink = ListSink()
    command = 0.01 * np.sin(np.arange(600) / 20)
    summary = run_experiment(link, command, sink, feedback_timeout_s=0.05, clock=link.link_clock)
    assert summary.samples == 600 and summary.lost == 0
    assert link.most_receives_without_send <= max(1, lead_samples // 2)
    assert sorted(link.sent) == list(range(600))
    held = np.flatnonzero(np.array([row[4] for row in sink.rows]) & SampleFlag.HELD)
    assert summary.held == held.size > 0  # once the host's lead is used up, its setpoints come too late
    assert [row[3] for row in sink.rows] == list(range(600))
    assert [row[1] for row in sink.rows] == link.applied[:600]  # the target in force, HELD or not


def test_a_device_far_ahead_gets_at_most_half_the_lead_of_setpoints_a_turn():
    """The link hears of every tick that has arrived at once (the device's position jumps by hundreds while the
    host has filed only the oldest): setpoints ahead of the device still go out at most half the lead a turn
    (the whole lead only before the device runs), so that the link carries no burst of hundreds of them
    (which overruns a CAN adapter's receive queue), and every row is still the tick the device reported."""
    link = FloodingLink(lead=40, read_cost_s=1.5e-3, total=600, hears_every_tick_at_once=True)
    sink = ListSink()
    summary = run_experiment(link, 0.01 * np.sin(np.arange(600) / 20), sink, feedback_timeout_s=0.05,
                             clock=link.link_clock)
    assert summary.samples == 600 and summary.lost == 0 and sorted(link.sent) == list(range(600))
    assert link.most_sends_between_receives <= 20
    assert [row[1] for row in sink.rows] == link.applied[:600]


class AutoClock:
    """A host clock that moves 20 us every time it is read (the host's own computing), and jumps when the host
    waits on the link (:class:`SlowAnswerV1Link`)."""

    def __init__(self, start_s: float = 50.0) -> None:
        self.now_s = start_s

    def __call__(self) -> float:
        self.now_s += 20e-6
        return self.now_s


class SlowAnswerV1Link(ScriptedDriveLink):
    """A protocol v1 (host-paced) device that answers each SETPOINT 0.2 ms after it arrives, except the
    setpoints in ``late``, whose FEEDBACK reaches the host ``late[seq]`` seconds after it (a device process
    descheduled on a loaded host)."""

    def __init__(self, clock: AutoClock, late: dict[int, float]) -> None:
        super().__init__(encoder=EncoderResolution(bits=16), sample_period_s=PERIOD_S, name="v1", clock=clock,
                         timing=BringUpTiming(poll_interval_s=0.0))
        self.host_clock, self.late = clock, late
        self._statusword = cia402.statusword_for(DriveState.SWITCH_ON_DISABLED)
        self._answers: list[tuple[float, int]] = []  # (arrival at the host, seq)

    def _send(self, setpoint: Setpoint) -> None:
        self._answers.append((self.host_clock.now_s + self.late.get(setpoint.seq, 2e-4), setpoint.seq))
        self._answers.sort()

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        end = self.host_clock.now_s + timeout_s
        if not self._answers or self._answers[0][0] > end:
            self.host_clock.now_s = max(self.host_clock.now_s, end)  # waited out the timeout
            return None
        arrival, seq = self._answers.pop(0)
        self.host_clock.now_s = max(self.host_clock.now_s, arrival)
        return FeedbackSample(seq=seq, encoder_counts=seq, load_angle_rad=0.0, drive_position_rad=0.0,
                              statusword=self._statusword, host_time_s=self.host_clock.now_s)

    def _close(self) -> None:
        pass


def test_a_v1_answer_that_comes_10_ms_late_at_1_khz_is_filed_late_not_lost():
    """Host-paced (v1) at 1 kHz on a loaded 2-core host: the device's FEEDBACK for sample 50 reaches the host
    10 ms (10 periods) after its SETPOINT. It is the device's answer to that setpoint (its seq says so): filed
    LATE, not written off LOST while the host still listens (spec section 8: 20 ms, at least 4 periods)."""
    clock = AutoClock()
    link = SlowAnswerV1Link(clock, late={50: 0.010})
    sink = ListSink()
    summary = run_experiment(link, np.zeros(120), sink, feedback_timeout_s=0.1, clock=clock)
    flags = [row[4] for row in sink.rows]
    assert summary.samples == 120 and summary.lost == summary.stale == 0
    assert flags[50] == SampleFlag.LATE and sink.rows[50][3] == 50


def test_a_host_behind_a_one_setpoint_buffer_catches_up_in_one_turn():
    """Lead 1 (a device buffering one setpoint), a link that hears of every tick that has arrived at once, and
    a host stall of 20 ms after tick 100: the setpoints of the instants that passed meanwhile (HELD either
    way) go out in one turn, and the next one is again ahead of the device, so the stall costs the ticks it
    outlasted and no more (at one setpoint a turn the host would stay behind for tens of turns)."""
    link = FloodingLink(lead=1, read_cost_s=0.4e-3, total=400, hears_every_tick_at_once=True, stall_at=100,
                        stall_s=0.02)
    sink = ListSink()
    summary = run_experiment(link, 0.01 * np.sin(np.arange(400) / 20), sink, feedback_timeout_s=0.05,
                             clock=link.link_clock)
    held = np.flatnonzero(np.array([row[4] for row in sink.rows]) & SampleFlag.HELD)
    assert summary.samples == 400 and summary.lost == 0
    assert held.tolist() == list(range(101, 101 + held.size)) and held.size <= 21
    assert [row[1] for row in sink.rows] == link.applied[:400]


def test_a_backlog_of_ticks_received_long_ago_does_not_trip_the_watchdog_while_more_keep_coming():
    """Each tick is stamped with when it reached the host, and the host files them ever later (1.5 ms a tick
    against the device's 1 ms): the oldest waiting tick is soon more than the watchdog's 50 ms (and its grace)
    old, yet the device is not silent, there is always more to read. Every tick filed feeds the watchdog, so
    it trips only after the host has listened through a silence (its grace) in which nothing was filed."""
    link = FloodingLink(lead=16, read_cost_s=1.5e-3, total=600, stamps_arrival=True)
    sink = ListSink()
    summary = run_experiment(link, 0.01 * np.sin(np.arange(600) / 20), sink, feedback_timeout_s=0.05,
                             clock=link.link_clock)
    assert summary.samples == 600 and summary.lost == 0
