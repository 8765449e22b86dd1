"""The host's view of a clocked, buffering device (:mod:`rig.transports.tick_buffer`), step by step: which
setpoint is sent with which target, and the estimate of the device's clock."""

from __future__ import annotations

from rig.transports.tick_buffer import TickBuffer

PERIOD_S = 0.01
STEP = 10  # drive counts a tick


def _toward_plan(plan: int, lowest: int, highest: int) -> int:
    return min(max(plan, highest - STEP), lowest + STEP)


def test_after_a_hold_the_targets_step_from_the_one_in_force_and_a_reported_tick_gets_none():
    ticks = TickBuffer(PERIOD_S, in_force_counts=0)
    ticks.heard(0, 100.0)  # tick k at 100 + k T
    ticks.in_force(5, 0)  # the device held 0 up to tick 5; the plan is at 100 by now
    assert ticks.place(5, 100, 100.0, reported=5, toward_plan=_toward_plan) is None
    sent = [ticks.place(k, 100, 100.0, reported=5, toward_plan=_toward_plan) for k in range(6, 10)]
    assert sent == [10, 20, 30, 40] and all(ticks.limited(k) for k in range(6, 10)) and not ticks.limited(6)


def test_a_setpoint_that_may_miss_its_tick_keeps_the_target_before_it_possible():
    """Setpoints sent after (or just before) their ticks' estimated instants may be dropped by the device, which
    then holds the target before them: the next one stays within a step of both, and a report settles it."""
    ticks = TickBuffer(PERIOD_S, in_force_counts=0)
    ticks.heard(0, 100.0)
    now = 100.0 + 7.5 * PERIOD_S  # ticks 1..7 have passed unheard of; tick 8 is a quarter period away
    assert [ticks.place(k, 100, now, reported=0, toward_plan=_toward_plan) for k in (1, 2, 8)] == [10, 10, 10]
    assert ticks.place(20, 100, now, reported=0, toward_plan=_toward_plan) == 10  # in time, but 8 may miss
    assert ticks.place(21, 100, now, reported=0, toward_plan=_toward_plan) == 20  # 20 is taken: from there
    ticks.in_force(21, 0)  # the device says it held 0 after all (20 lost on the way): the next steps from 0
    assert ticks.place(22, 100, now, reported=21, toward_plan=_toward_plan) == 10


def test_the_estimate_of_the_devices_clock_follows_a_crystal_100_ppm_slow_for_an_hour():
    """Each report reaches the host 0.2 ms after its tick, every 50th one 3 ms late; the device's ticks (50 ms)
    are 100 ppm longer than the host's seconds say. After an hour the estimate of a tick's instant is within
    0.5 ms of the truth (the window's 5 s of drift); the earliest arrival of all ticks since the start would be
    0.36 s early, and every setpoint would look as if it might miss its tick."""
    period_s = 0.05
    ticks = TickBuffer(period_s, in_force_counts=0)
    true_period = period_s * (1 + 1e-4)
    last = round(3600 / period_s)
    for k in range(0, last + 1):
        ticks.heard(k, 50.0 + k * true_period + (3e-3 if k % 50 == 0 else 2e-4))
    assert abs(ticks.instant_s(last + 10) - (50.0 + (last + 10) * true_period)) < 0.5e-3
