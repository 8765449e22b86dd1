"""The CANopen master against the simulated CiA 402 drive and CiA 406 encoder, SYNC by SYNC on a simulated
clock (:mod:`clocked_canopen`: no thread, no sleep; nothing here depends on how busy the machine is).

The expectations are CiA 301 / CiA 402 semantics, not what the code happens to give: SYNC k is the sample
instant k (the master's cyclic task, exactly every period); in cyclic synchronous position (0x6060 = 8) the
drive applies at SYNC k the target 0x607A last received before it; in interpolated position (0x6060 = 7) it
takes one interpolation data record (0x60C1) from its FIFO (0x60C4) per SYNC, and an empty FIFO holds the
last one (an underrun); a synchronous TPDO answers its SYNC, possibly one SYNC later (0x1800:2 = 1 on a
device that sends what it latched at the previous SYNC: legal, and configured on the master)."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols import cia402
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.errors import TransportError
from rig.runner import run_experiment
from rig.transports.canopen_link import CanOpenTransport
from sim_backend.canopen_behaviour import DriveBehaviour, EncoderBehaviour
from sim_backend.canopen_nodes import SimulatedCanOpenRig
from sim_backend.plant_config import load_plant_config

from clocked_canopen import ClockedCanBus
from clocked_line import SimulatedClock
from sim_rigs import CONFIGS, ListSink

DRIVE = DriveScaling(1 << 17)
LEAD_S = 0.1  # the master's default lead
BUFFER_RECORDS = 64  # the simulated drive's 0x60C4:1/2 (configs/eds/sim_drive_cia402.eds)


def _gearbox(rate_hz: float, directory):
    text = (CONFIGS / "plants" / "precision_gearbox.toml").read_text()
    text = text.replace("sample_period_s = 0.001", f"sample_period_s = {1 / rate_hz!r}")
    path = directory / f"plant_{rate_hz:g}.toml"
    path.write_text(text)
    return load_plant_config(path).gearbox(seed=4)


@contextlib.contextmanager
def _clocked_rig(tmp_path, *, rate_hz: float = 1000.0, mode: str = "ip_buffer", drive_behaviour=None,
                 encoder_behaviour=None, transport_options=None, counts_drops: bool = False, **faults):
    """(bus, transport, rig, clock): the master and the simulated nodes on one :class:`ClockedCanBus`."""
    clock = SimulatedClock(100.0)
    bus = ClockedCanBus(clock)
    gearbox = _gearbox(rate_hz, tmp_path)
    rig = SimulatedCanOpenRig(gearbox, channel="clocked", clock=clock, drive_behaviour=drive_behaviour,
                              encoder_behaviour=encoder_behaviour, **faults)
    transport = CanOpenTransport("virtual", "clocked", encoder=gearbox.encoder, sample_period_s=1 / rate_hz,
                                 drive=DRIVE, timing=BringUpTiming(), mode=mode, lead_s=LEAD_S, name="clocked",
                                 clock=clock, **(transport_options or {}))
    bus.master(transport, counts_drops=counts_drops)
    bus.devices(rig)
    try:
        yield bus, transport, rig, clock
    finally:
        transport.close()
        rig.close()


def _command(num_samples: int) -> np.ndarray:
    return 0.2 * np.sin(2 * np.pi * np.arange(num_samples) / 250)


def _run(bus, transport, clock, command, *, stall_at=None, stall_s=0.0, feedback_timeout_s=0.5):
    stalled = []

    def progress(done: int, _held: int) -> None:
        if stall_at is not None and done >= stall_at and not stalled:
            stalled.append((clock(), transport.device_sample))
            bus.stall(stall_s)

    sink = ListSink()
    summary = run_experiment(transport, command, sink, feedback_timeout_s=feedback_timeout_s, clock=clock,
                             progress=progress)
    return summary, sink, stalled


def _flags(sink) -> np.ndarray:
    return np.array([row[4] for row in sink.rows])


def _answered_rows_equal_the_offline_simulation(sink, rate_hz: float, tmp_path) -> None:
    """The logged angles are the plant's response to the logged commands (the commands really applied)."""
    command = np.array([row[1] for row in sink.rows])
    angle = np.array([row[2] for row in sink.rows])
    answered = (_flags(sink) & SampleFlag.LOST) == 0
    expected = _gearbox(rate_hz, tmp_path).simulate(command).measured_angle_rad
    np.testing.assert_array_equal(angle[answered], expected[answered])


def _sync_times(bus) -> list[float]:
    return [when for when, cob_id, _ in bus.frames if cob_id == 0x80]


def _stall_instants(stalled, stall_s: float, period_s: float) -> tuple[int, int]:
    """The instant the host had heard of when it stalled (it had queued up to that one's predecessor + the
    lead: the runner tops up before it waits; the stall starts at that SYNC's time) and the last instant
    whose SYNC fell in the stall."""
    (_, heard), = stalled
    return heard, heard + math.floor(stall_s / period_s + 1e-9)


# -- start-up and the lead -------------------------------------------------------------------------------------

@pytest.mark.parametrize("rate_hz", [1000.0, 2000.0])
def test_the_fifo_is_filled_to_its_capacity_and_the_lead_is_kept_sync_by_sync(rate_hz, tmp_path):
    """Interpolated position (0x6060 = 7): the lead of 100 ms is 100 records at 1 kHz and 200 at 2 kHz, more
    than the drive's FIFO takes, so the FIFO stands at its capacity (0x60C4:2) less the master's margin at
    every SYNC, the rest waiting in the host's queue; each SYNC takes one record; nothing is held."""
    from rig.transports.interpolation_feed import IP_BUFFER_MARGIN_RECORDS

    samples = 400
    with _clocked_rig(tmp_path, rate_hz=rate_hz) as (bus, transport, rig, clock):
        summary, sink, _ = _run(bus, transport, clock, _command(samples))
        levels, capacity = rig.ip_levels, transport._ip_capacity
    period_s = 1 / rate_hz
    lead = round(LEAD_S * rate_hz)
    assert transport.mode == "ip_buffer" and capacity == BUFFER_RECORDS and transport.lead_samples == lead
    assert summary.samples == samples and summary.lost == summary.held == summary.late == summary.stale == 0
    full = capacity - IP_BUFFER_MARGIN_RECORDS
    # from the last setpoint on, hold records keep the FIFO full: the drive never finds it empty (a drive that
    # faults on an underflow ends the run without a fault, whatever the host does before the stop)
    assert levels[:samples] == [full] * samples
    assert levels[samples:] and all(level == full for level in levels[samples:]) and rig.ip_underruns == 0
    assert math.isclose(summary.min_lead_s, LEAD_S, abs_tol=1e-9)  # every record queued exactly the lead ahead
    syncs = np.array(_sync_times(bus))  # the master's cyclic SYNC: exactly every period
    np.testing.assert_allclose(np.diff(syncs), period_s, rtol=0, atol=1e-9)
    commands = [row[1] for row in sink.rows]
    assert commands == [DRIVE.quantize_rad(value) for value in _command(samples)]
    assert [row[0] for row in sink.rows] == pytest.approx([k * period_s for k in range(samples)])
    _answered_rows_equal_the_offline_simulation(sink, rate_hz, tmp_path)


@pytest.mark.parametrize("rate_hz", [1000.0, 2000.0])
def test_in_csp_each_target_is_on_the_bus_between_the_sync_before_and_its_own(rate_hz, tmp_path):
    """Cyclic synchronous position (0x6060 = 8, forced): target k is received after SYNC k-1 and before
    SYNC k (CiA 402: the drive applies at each SYNC the last target received), so the lead on the bus is
    one period whatever the host's queue holds; the host's lead is the configured one."""
    samples = 300
    with _clocked_rig(tmp_path, rate_hz=rate_hz, mode="csp") as (bus, transport, rig, clock):
        summary, sink, _ = _run(bus, transport, clock, _command(samples))
    assert transport.mode == "csp" and summary.samples == samples and summary.lost == summary.held == 0
    assert math.isclose(summary.min_lead_s, LEAD_S, abs_tol=1e-9)
    expected = [DRIVE.counts_from_rad(value) for value in _command(samples)]
    between, targets = 0, {}  # SYNCs seen since the first target; target counts by the SYNC they precede
    for _, cob_id, data in bus.frames:
        if cob_id == 0x80 and targets:
            between += 1
        elif cob_id == 0x201:
            assert between not in targets, f"two targets before SYNC {between}"
            targets[between] = int.from_bytes(data, "little", signed=True)
    assert [targets.get(k) for k in range(samples)] == expected
    _answered_rows_equal_the_offline_simulation(sink, rate_hz, tmp_path)


@pytest.mark.parametrize("underflow", ["hold", "fault", "fault_after_first"])
@pytest.mark.parametrize("capacity", [4, 16, 64])
def test_every_buffer_size_and_underflow_behaviour_runs_clean_through_a_stall(capacity, underflow, tmp_path):
    """Interpolated position on the strict drive (CiA 301 RPDO semantics, CiA 402 buffer): buffers of 4, 16
    and 64 records (0x60C4:2), a drive that holds on an empty buffer and the two that fault on one (maxon EPOS:
    at any SYNC with ip mode active; others once a record was taken), and the 0x60C2 it needs: the run is
    clean through a host stall longer than the lead and through its end, each row is what the drive applied
    at that SYNC, and the drive never finds its buffer empty."""
    behaviour = DriveBehaviour(ip_underflow=underflow, requires_ip_period=True)
    with _clocked_rig(tmp_path, drive_behaviour=behaviour) as (bus, transport, rig, clock):
        rig.drive.set_data(0x60C4, 2, capacity.to_bytes(4, "little"))
        summary, sink, stalled = _run(bus, transport, clock, _command(400), stall_at=150, stall_s=0.1505)
        faults, underruns, state = list(rig.faults), rig.ip_underruns, rig.state
    assert transport.mode == "ip_buffer" and transport._ip_capacity == capacity
    assert stalled and summary.samples == 400 and summary.lost == 0 and summary.held > 0
    assert not faults and underruns == 0 and state is cia402.DriveState.SWITCH_ON_DISABLED
    assert not np.any(_flags(sink) & SampleFlag.unusable()), np.flatnonzero(_flags(sink) & SampleFlag.unusable())
    _answered_rows_equal_the_offline_simulation(sink, 1000.0, tmp_path)


# -- host stalls -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("mode", ["ip_buffer", "csp"])
def test_a_host_stall_shorter_than_the_lead_holds_nothing(mode, tmp_path):
    stall_s = 0.0655  # 65.5 periods at 1 kHz, within the 100-period lead
    with _clocked_rig(tmp_path, mode=mode) as (bus, transport, rig, clock):
        summary, sink, stalled = _run(bus, transport, clock, _command(400), stall_at=150, stall_s=stall_s)
    assert stalled and summary.samples == 400 and summary.lost == summary.held == summary.late == 0
    # the first setpoint queued after the stall had the lead less the stall
    assert math.isclose(summary.min_lead_s, LEAD_S - stall_s, abs_tol=1e-9)
    assert [row[1] for row in sink.rows] == [DRIVE.quantize_rad(value) for value in _command(400)]
    _answered_rows_equal_the_offline_simulation(sink, 1000.0, tmp_path)


@pytest.mark.parametrize("mode", ["ip_buffer", "csp"])
def test_a_host_stall_longer_than_the_lead_holds_exactly_the_instants_beyond_it(mode, tmp_path):
    """150.5 periods of stall with a 100-period lead: the setpoints the host had queued cover the instants
    up to the one it had heard of plus the lead less one; every later instant in the stall is HELD, nothing
    is lost, and the lead is kept again after it. Interpolated position: the drive takes hold records, never
    an empty FIFO, and the two hold records in its FIFO when the stall ends are taken first. CSP: the targets
    ramp back to the plan at twice its own largest step, those samples LIMITED."""
    period_s, stall_s, samples = 1e-3, 0.1505, 500
    lead = round(LEAD_S / period_s)
    command = _command(samples)
    with _clocked_rig(tmp_path, mode=mode) as (bus, transport, rig, clock):
        summary, sink, stalled = _run(bus, transport, clock, command, stall_at=150, stall_s=stall_s)
        levels = rig.ip_levels
    heard, last_in_stall = _stall_instants(stalled, stall_s, period_s)
    in_stall = list(range(heard + lead, last_in_stall + 1))
    held = np.flatnonzero(_flags(sink) & SampleFlag.HELD).tolist()
    assert len(in_stall) == 51 and held[:51] == in_stall and held == list(range(held[0], held[-1] + 1))
    assert summary.held == len(held) and summary.lost == 0 and summary.samples == samples
    commands = [row[1] for row in sink.rows]
    plan = [DRIVE.quantize_rad(v) for v in command]
    if mode == "ip_buffer":  # the drive's own account: at these SYNCs it took a hold record, never an empty FIFO
        assert len(held) == 51 + 2 and not any(level == 0 for level in levels[:samples]) and rig.ip_underruns == 0
        assert commands[held[0]:held[-1] + 1] == [commands[held[0] - 1]] * len(held)  # the last target, held
        # after the stall the drive takes the later records at later instants, each logged as applied
        assert commands[held[-1] + 1:] == plan[held[0]:samples - len(held)]
        slack = 3 * period_s  # the two hold records' instants after the stall's last
    else:  # CSP: targets that missed their SYNC are dropped; the ramp back (LIMITED) meets the plan, then in time
        assert held == in_stall
        limited = np.flatnonzero(_flags(sink) & SampleFlag.LIMITED).tolist()
        assert limited and limited == list(range(held[-1] + 1, limited[-1] + 1))
        plan_step = max(abs(b - a) for a, b in zip(plan, plan[1:]))
        ramp = np.abs(np.diff(commands[held[0] - 1:limited[-1] + 2]))
        assert ramp.max() <= 2 * plan_step + 1e-12
        assert commands[limited[-1] + 1:] == plan[limited[-1] + 1:]
        slack = period_s
    # the smallest lead is negative: the first setpoint queued after the stall came after its instant, by
    # the stall less the lead (the master measures it in whole periods, so up to one period more)
    assert LEAD_S - stall_s - slack - 1e-9 <= summary.min_lead_s <= LEAD_S - stall_s + 1e-9
    _answered_rows_equal_the_offline_simulation(sink, 1000.0, tmp_path)


@pytest.mark.parametrize("mode", ["ip_buffer", "csp"])
def test_after_a_stall_the_applied_target_never_steps_beyond_the_rate_limit(mode, tmp_path):
    """A 150.5 ms stall with a 100 ms lead holds 51 samples while the plan moves on. CSP: the next target
    would jump from the held one to the plan (0.25 rad here); it ramps back at the rate limit instead, each
    ramped sample LIMITED with the target really applied. Interpolated position: the records follow one another
    in order after the held instants, so no step exceeds the plan's own."""
    from rig.transports.base import CommandLimits

    limit = 10.0  # rad/s; the command's own largest rate is 5.03 rad/s
    command = _command(600)
    with _clocked_rig(tmp_path, mode=mode, transport_options={"limits": CommandLimits(rate_max_rad_per_s=limit)}
                      ) as (bus, transport, rig, clock):
        summary, sink, stalled = _run(bus, transport, clock, command, stall_at=150, stall_s=0.1505)
    applied = np.array([row[1] for row in sink.rows])
    step = np.abs(np.diff(applied)) * DRIVE.counts_per_revolution / (2 * np.pi)  # counts per period
    assert stalled and summary.lost == 0 and len(sink.rows) == 600
    assert step.max() <= limit * 1e-3 * DRIVE.counts_per_revolution / (2 * np.pi) + 1e-6  # 1632 counts
    held = (_flags(sink) & SampleFlag.HELD) != 0
    if mode == "csp":  # the ramp is flagged LIMITED, as on every device-clocked wire, and ends on the plan
        limited = (_flags(sink) & SampleFlag.LIMITED) != 0
        designed = np.array([DRIVE.quantize_rad(value) for value in command])
        assert held.sum() == 51 and limited.sum() > 0 and not np.any(held & limited)
        assert np.all(applied[~(held | limited)] == designed[~(held | limited)])
        assert np.all(applied[-100:] == designed[-100:])
    _answered_rows_equal_the_offline_simulation(sink, 1000.0, tmp_path)


def test_after_a_whole_process_stall_the_drive_never_steps_beyond_the_rate_limit(tmp_path):
    """CSP with the master's whole process descheduled for 40 ms (its receive side too): when it runs again it
    handles the stall's SYNC echoes one after the other and puts a target on the bus for each; all of them
    reach the drive after their SYNCs, and the drive takes the last at the next SYNC. Each is limited from
    the target in force at the SYNC it answers, not from the one sent before it, so the drive's own record
    never steps further than the rate limit allows from one SYNC to the next."""
    from rig.transports.base import CommandLimits

    limit = 10.0  # rad/s; the command's own largest rate is 5.03 rad/s
    step_counts = limit * 1e-3 * DRIVE.counts_per_revolution / (2 * np.pi)  # 1632 counts per period
    command = _command(600)
    with _clocked_rig(tmp_path, mode="csp",
                      transport_options={"limits": CommandLimits(rate_max_rad_per_s=limit)}) as (bus, transport, rig,
                                                                                                   clock):
        stalled = []

        def progress(done: int, _held: int) -> None:
            if done >= 150 and not stalled:
                stalled.append(done)
                bus.stall_receive(0.0405)

        summary = run_experiment(transport, command, ListSink(), feedback_timeout_s=0.5, clock=clock,
                                 progress=progress)
        applied = np.array(rig.record().applied_targets, dtype=float)
    assert stalled and summary.samples == 600
    assert np.abs(np.diff(applied)).max() <= step_counts + 1


# -- devices that answer late, devices that fall silent --------------------------------------------------------

def test_a_drive_answering_each_sync_one_sync_late_is_no_drop_out(tmp_path):
    """TPDOs that carry, after SYNC k+1, what was latched at SYNC k (legal, CiA 301; configured on the
    master): every sample is filed under its own instant, none lost or held, no fault."""
    late = {"drive_tpdo_latency_cycles": 1, "encoder_tpdo_latency_cycles": 1}
    with _clocked_rig(tmp_path, mode="csp", drive_behaviour=DriveBehaviour(tpdo_latency_cycles=1),
                      encoder_behaviour=EncoderBehaviour(tpdo_latency_cycles=1), transport_options=late) as (
                          bus, transport, rig, clock):
        summary, sink, _ = _run(bus, transport, clock, _command(300))
        state = rig.state
    assert summary.samples == 300 and summary.lost == summary.held == summary.duplicate == summary.late == 0
    assert summary.stop.endswith("ends SWITCH ON DISABLED") and state is cia402.DriveState.SWITCH_ON_DISABLED
    _answered_rows_equal_the_offline_simulation(sink, 1000.0, tmp_path)


@pytest.mark.parametrize("rest", [0, 5])
def test_a_drive_answering_later_than_configured_is_named_as_such_not_as_a_drop_out(tmp_path, rest):
    """Both nodes answer one SYNC later than configured. The run stops naming the setting, and no row it
    logged is filed as certain: until a changed target comes back in 0x6062 at its own sample, nothing
    shows which SYNC a frame answers (the rows of a command at rest look the same either way). The rows
    that waited for that evidence are in the log, AMBIGUOUS, not LOST."""
    from rig.protocols.errors import DeviceFault

    command = np.concatenate([np.full(rest, _command(1)[0]), _command(300)])
    sink = ListSink()
    with _clocked_rig(tmp_path, mode="csp", drive_behaviour=DriveBehaviour(tpdo_latency_cycles=1),
                      encoder_behaviour=EncoderBehaviour(tpdo_latency_cycles=1)) as (bus, transport, rig, clock):
        with pytest.raises(DeviceFault, match=r"set drive_tpdo_latency_cycles = 1") as caught:
            run_experiment(transport, command, sink, feedback_timeout_s=0.5, clock=clock)
        state = rig.state
    assert "left OPERATION ENABLED" not in str(caught.value)
    assert state is cia402.DriveState.SWITCH_ON_DISABLED
    flags = _flags(sink)  # the last row: the faulted sample
    assert flags.size >= rest + 2 and flags[-1] & SampleFlag.FAULT
    assert np.all(flags[:-1] & SampleFlag.AMBIGUOUS), flags
    assert not np.any(flags[:-1] & SampleFlag.LOST), flags  # every answer that came is in the log


@pytest.mark.parametrize("mode", ["csp", "ip_buffer"])
def test_a_command_at_rest_for_longer_than_the_wait_for_the_latencys_evidence_runs_clean(tmp_path, mode):
    """A correctly configured drive and a command that rests for 80 samples first (the cyclic experiment's
    hold at u_min, Pouliquen et al. 2013, Section III): the rows at rest wait for the first changed target's
    0x6062 at most half the lead, then go out as filed: every row clean, none lost."""
    from rig.transports.canopen_filing import LATENCY_UNCONFIRMED_HOLD_LEADS

    rest = 80
    command = np.concatenate([np.zeros(rest), _command(200)[1:]])
    with _clocked_rig(tmp_path, mode=mode) as (bus, transport, rig, clock):
        summary, sink, _ = _run(bus, transport, clock, command)
        hold = int(LATENCY_UNCONFIRMED_HOLD_LEADS * transport.lead_samples)
    assert 0 < hold < rest
    assert summary.samples == len(command) and summary.lost == 0
    assert not np.any(_flags(sink) & SampleFlag.unusable()), np.flatnonzero(_flags(sink) & SampleFlag.unusable())
    _answered_rows_equal_the_offline_simulation(sink, 1000.0, tmp_path)


def test_a_run_interrupted_before_interpolation_started_never_starts_it(tmp_path):
    """Ctrl-C while the first setpoints are queued, before the drive's buffer is started: the runner files what
    had come before the stop, and that never sets controlword bit 4 (enable ip mode): the drive takes no record
    and ends disabled."""
    with _clocked_rig(tmp_path) as (bus, transport, rig, clock):
        send = transport.send

        def interrupted(setpoint):
            if setpoint.seq == 80:
                raise KeyboardInterrupt
            return send(setpoint)

        transport.send = interrupted
        with pytest.raises(KeyboardInterrupt):
            run_experiment(transport, _command(400), ListSink(), feedback_timeout_s=0.5, clock=clock)
        controlwords, state = list(rig.controlwords), rig.state
    assert transport.mode == "ip_buffer"
    assert not any(word & 0x10 for word in controlwords), controlwords  # bit 4: enable ip mode
    assert state is cia402.DriveState.SWITCH_ON_DISABLED


def test_the_feedback_watchdog_stops_a_silent_drive_and_the_drive_ends_disabled(tmp_path):
    """The drive's TPDOs stop after sample 100 (its heartbeat goes on): the runner's watchdog stops the run
    once nothing has come for feedback_timeout_s and the grace after it, on the simulated clock; the stop
    is the one teardown: quick stop, then disable."""
    from rig.runner import WATCHDOG_GRACE

    timeout_s = 0.2
    with _clocked_rig(tmp_path, mode="csp", silent_drive_seqs=range(100, 100_000)) as (bus, transport, rig, clock):
        with pytest.raises(TransportError, match=r"no feedback for ([0-9.]+) s \(watchdog 0.2 s\)") as caught:
            _run(bus, transport, clock, _command(2000), feedback_timeout_s=timeout_s)
        state, controlwords = rig.state, rig.controlwords
    last_tpdo = max(i for i, (_, cob_id, _) in enumerate(bus.frames) if cob_id == 0x181)
    fed_s = bus.frames[last_tpdo][0]  # the watchdog reads when the last answer was received (the host's clock
    # reads the bus in whole periods here: up to one period before the frame's own time)
    quick_stop_s = next(when for when, cob_id, data in bus.frames if cob_id == 0x601 and data[1:3] == b"\x40\x60"
                        and int.from_bytes(data[4:6], "little") == cia402.CONTROLWORD_QUICK_STOP)
    assert (1 + WATCHDOG_GRACE) * timeout_s - 1e-3 < quick_stop_s - fed_s <= (1 + WATCHDOG_GRACE) * timeout_s + 2e-3
    silence_s = float(str(caught.value).split("no feedback for ")[1].split(" s")[0])
    assert silence_s >= (1 + WATCHDOG_GRACE) * timeout_s - 1e-9
    assert "stopping at sample" in str(caught.value)
    assert controlwords[-2:] == [cia402.CONTROLWORD_QUICK_STOP, cia402.CONTROLWORD_DISABLE_VOLTAGE]
    assert state is cia402.DriveState.SWITCH_ON_DISABLED


def test_an_encoder_tpdo_delayed_past_two_syncs_costs_exactly_its_sample_and_the_one_it_lands_in(tmp_path):
    """The encoder's answer to SYNC 100 goes on the bus 2.4 periods late, after SYNCs 101 and 102: the master
    files a TPDO under the last SYNC before it on the bus, so sample 100 has no encoder value (LOST) and
    sample 102 two (DUPLICATE: unusable, never silently wrong); every other sample is the plant's answer."""
    period_s = 1e-3
    with _clocked_rig(tmp_path, mode="csp", delayed_tpdo=(2.4 * period_s, 100)) as (bus, transport, rig, clock):
        summary, sink, _ = _run(bus, transport, clock, _command(300))
    flags = _flags(sink)
    assert np.flatnonzero(flags & SampleFlag.LOST).tolist() == [100]
    assert np.flatnonzero(flags & SampleFlag.DUPLICATE).tolist() == [102]
    assert not np.any(flags & SampleFlag.AMBIGUOUS) and summary.lost == 1 and summary.duplicate == 1
    clean = (flags & (SampleFlag.LOST | SampleFlag.DUPLICATE)) == 0
    command = np.array([row[1] for row in sink.rows])
    expected = _gearbox(1000.0, tmp_path).simulate(command).measured_angle_rad
    np.testing.assert_array_equal(np.array([row[2] for row in sink.rows])[clean], expected[clean])


# -- a receive queue that loses frames ---------------------------------------------------------------------------

DROP_AT = 150  # the sample after which the master's receive stream loses a frame


def _once(wanted):
    """A ``drop_from_master`` rule that deletes the first frame for which ``wanted(frame, own)`` is true."""
    done = []

    def drops(frame, own) -> bool:
        if not done and wanted(frame, own):
            done.append(frame)
            return True
        return False

    return drops


def _sync_echo(transport):
    """The echo of the SYNC of sample DROP_AT + 1."""
    return _once(lambda frame, own: own and frame.arbitration_id == 0x80 and transport._origin is not None
                 and transport._sync_count == transport._origin + DROP_AT)


def _rpdo_echo(transport):
    """The echo of the first target (CSP) or interpolation record (IP) put on the bus after sample DROP_AT."""
    return _once(lambda frame, own: own and frame.arbitration_id in (0x201, 0x301)
                 and transport.device_sample >= DROP_AT)


def _drive_tpdo(transport):
    return _once(lambda frame, own: not own and frame.arbitration_id == 0x181 and transport.device_sample >= DROP_AT)


def _run_losing_frames(tmp_path, mode, rule, *, counts_drops=False, demand=True, samples=400):
    """Run with ``rule(transport)`` deleting frames from the master's receive stream: (the error that ended the
    run or None, the summary or None, rows, usable rows' commands judged against what the drive applied: the
    number of usable rows that are wrong, the drive's final state, frames deleted). ``demand`` False: the
    master does not map the drive's 0x6062 (as for a drive whose EDS lacks it or a second TPDO), so nothing
    but the bus order tells it which command the drive applied."""
    with _clocked_rig(tmp_path, mode=mode, counts_drops=counts_drops) as (bus, transport, rig, clock):
        transport._checks_latency = demand
        bus.drop_from_master(rule(transport))
        sink, failure, summary = ListSink(), None, None
        try:
            summary = run_experiment(transport, _command(samples), sink, feedback_timeout_s=0.5, clock=clock)
        except TransportError as err:
            failure = err
        record, state, dropped = rig.record(), rig.state, bus.master_drops
    flags = _flags(sink)
    usable = (flags & SampleFlag.unusable()) == 0
    logged = [DRIVE.counts_from_rad(row[1]) for row in sink.rows]
    return failure, summary, sink, record.wrong_rows(logged, usable.tolist()), state, dropped


@pytest.mark.parametrize("demand", [True, False], ids=["with 0x6062", "without 0x6062"])
@pytest.mark.parametrize("mode", ["csp", "ip_buffer"])
@pytest.mark.parametrize("lost", ["sync echo", "rpdo echo"])
def test_a_lost_echo_of_the_masters_own_frame_stops_the_run_and_no_wrong_row_is_usable(lost, mode, demand,
                                                                                        tmp_path):
    """The master numbers the samples by its SYNC echoes and knows the target (CSP) or record (IP) in force
    from its RPDO echoes in bus order. One of them lost from its receive queue (an RX overrun: the frame was on
    the bus, the drive got it) breaks that bookkeeping: from there no row is logged usable unless it carries the
    command the drive applied; the run stops naming the lost frame, and the drive ends quick-stopped and
    disabled as after every stop."""
    rule = _sync_echo if lost == "sync echo" else _rpdo_echo
    failure, _, sink, wrong, state, dropped = _run_losing_frames(tmp_path, mode, rule, demand=demand)
    assert dropped == 1
    assert wrong == 0
    assert failure is not None and "receive" in str(failure) and "lost" in str(failure)
    assert ("SYNC" if lost == "sync echo" else "RPDO") in str(failure)
    assert state is cia402.DriveState.SWITCH_ON_DISABLED
    flags = _flags(sink)
    usable = np.flatnonzero((flags & SampleFlag.unusable()) == 0)
    assert usable.size and usable.max() <= DROP_AT + 1  # nothing after the loss is usable
    assert len(sink.rows) > DROP_AT  # the rows before it are kept


@pytest.mark.parametrize("mode", ["csp", "ip_buffer"])
def test_a_lost_drive_tpdo_costs_its_sample_only(mode, tmp_path):
    """A drive TPDO lost on receive, on an interface without a drop counter: that sample is LOST (it never had
    both answers), everything else is usable and right; the master's own bookkeeping is untouched."""
    failure, summary, sink, wrong, state, dropped = _run_losing_frames(tmp_path, mode, _drive_tpdo)
    assert dropped == 1 and failure is None and wrong == 0
    assert summary.lost == 1 and summary.samples == 400
    assert np.flatnonzero(_flags(sink) & SampleFlag.unusable()).tolist() == [DROP_AT]


@pytest.mark.parametrize("mode", ["csp", "ip_buffer"])
def test_a_drop_the_interface_counts_stops_the_run_whatever_frame_it_was(mode, tmp_path):
    """Where the interface counts the frames its receive queue dropped (udp_multicast, SocketCAN: the socket's
    drop count, the one SO_RXQ_OVFL reports), a rise says frames were lost without saying which: the master
    cannot prove any later row right, so it stops, counts the drop in the run summary's receive_drops, and no
    usable row is wrong."""
    failure, _, sink, wrong, state, dropped = _run_losing_frames(tmp_path, mode, _drive_tpdo, counts_drops=True)
    assert dropped == 1 and wrong == 0
    assert failure is not None and "dropped 1 frame" in str(failure)
    assert state is cia402.DriveState.SWITCH_ON_DISABLED
    usable = np.flatnonzero((_flags(sink) & SampleFlag.unusable()) == 0)
    assert usable.max() <= DROP_AT + 1


@pytest.mark.parametrize("mode", ["ip_buffer", "csp"])
def test_the_achieved_rate_counts_the_runs_own_answers_only(mode, tmp_path):
    """The drive goes on answering SYNCs while the run ends (its pending window, the stop): those answers are
    no samples of the run, and counting them halved the rate of a short run (100 samples at 1 kHz said 500 Hz).
    On the simulated clock the rate is the period's."""
    with _clocked_rig(tmp_path, mode=mode) as (bus, transport, rig, clock):
        summary, sink, _ = _run(bus, transport, clock, _command(100))
    assert summary.samples == 100 and summary.lost == 0
    assert summary.rate_hz == pytest.approx(1000.0, rel=0.02)
