"""The real CANopen master (:class:`rig.transports.canopen_link.CanOpenTransport` through
:func:`rig.runner.run_experiment`) against a CiA 402 drive and a CiA 406 encoder written only from the
standards (:mod:`spec_cia402_drive`, which imports nothing of ours), on python-can's ``virtual`` bus with
the devices answering on their own notifier thread. If one of these fails, the standards and the master
disagree, and the standards are what a drive vendor has.

What the drive implements, by standard clause and object, and where its choice differs from our simulated
drive (``sim_backend/canopen_nodes.py``):

* CiA 301 NMT: boot-up to PRE-OPERATIONAL, PDOs only in OPERATIONAL; heartbeat producer from 0x1017
  (canopen's ``NmtSlave``).
* CiA 301 PDOs, read from 0x1400/0x1600 and 0x1800-0x1803/0x1A00-0x1A03 when the node enters OPERATIONAL:
  TPDOs by their transmission type in 0x18xx:2 (1..240: after every n-th SYNC; 0: at a SYNC when the data
  changed). The RPDO is synchronous (transmission type 0..240): its data are taken up at the next SYNC
  (CiA 301's synchronous RPDO), where the simulated drive takes them up on reception. TPDOs carry the wire
  time a bus with hardware time stamps gives them (the SYNC's time stamp plus the bits since).
* CiA 301 EMCY and 0x1001: on a fault, and the error reset (0x0000) once it is cleared, always sent (the
  simulated drive sends it only as a configured behaviour).
* CiA 402 state machine strictly by the transition table: a controlword that codes no transition from the
  current state does nothing; "switch on + enable operation" from READY TO SWITCH ON does 3 and 4; fault
  reset on the rising edge of bit 7 only, in FAULT only (15), and it takes ``fault_reset_s``; a fault goes
  through FAULT REACTION ACTIVE (13) for ``fault_reaction_s`` before FAULT (14), where the simulated drive
  goes to FAULT at once.
* CiA 402 quick stop option code 0x605A = 2 (ramp, then SWITCH ON DISABLED by itself) or 6 (ramp, then stay
  in QUICK STOP ACTIVE with bit 10 set, 16 back to OPERATION ENABLED possible); the simulated drive by default
  stays in QUICK STOP ACTIVE until disable voltage.
* CiA 402 modes of operation 0x6060/0x6061: 0x6061 follows 0x6060 ``mode_switch_s`` later (the simulated
  drive at once); 0x6502 = pp, ip, csp (no homing).
* No copy of the actual position into 0x607A on enable (the simulated drive copies it): 0x607A holds a stale
  value from power-on, so a master that did not set the target to the actual position would move the motor.
* Cyclic synchronous position (0x6060 = 8): the demand 0x6062 at SYNC k is the target 0x607A in force.
* Interpolated position (0x6060 = 7), linear (0x60C0 = 0, the only one accepted): the record taken at SYNC k
  is the END point of the segment k..k+1, so the demand 0x6062 (and the actual position) at SYNC k is the
  record taken at SYNC k - 1; the simulated drive's demand at SYNC k is the record it took there. Buffer
  0x60C4: sub 1 maximum (32 here, 64 there), sub 2 actual size (24 by default, writable up to sub 1), sub 3
  0 = FIFO (the only one accepted), sub 6 buffer clear (0 clears and disables access, 1 enables). Records
  written while access is disabled, or into a full buffer, are discarded (whatever the mode; the simulated
  drive takes them only in mode 7). Records are consumed only with controlword bit 4 and statusword bit 12
  set; bit 4 low pauses (the master never clears it mid-run, so no test here reaches that branch); an
  underrun holds the last record. While streaming, this lag is exactly what a drive that jumps to each
  record and answers one SYNC late sends (``sim_backend``'s "TPDOs one SYNC late"), so the master is told
  ``ip_record_is_segment_end = true`` for these runs; untold, it stops naming both causes
  (:func:`test_the_interpolation_lag_looks_like_a_tpdo_latency_and_the_master_says_both`). Told a TPDO
  latency instead, it would file the statusword one SYNC early, and sample 0 with it whenever the drive's
  answer to controlword bit 4 came after a SYNC (a loaded host).
* CiA 406 encoder: position value 0x6004 (UNSIGNED32; the load, gear ratio 1), 0x6001 measuring units per
  revolution, 0x6002 total measuring range, 0x6000 code sequence; its TPDO as the drive's.

These runs use real threads and real time, so they assert accounting (every sample filed, the command the
log says was applied equal to the command the drive took up at that SYNC, the encoder counts those it
latched there), never timing; the watchdogs are seconds long (``test_spec_serial_device.py`` says why), and
the devices answer from threads of this process, which a loaded host starves with it, so their answers get
the demo's filing window (``SIMULATED_RIG_PENDING_CYCLES``), as ``test_real_variety.py`` gives them.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.demo import SIMULATED_RIG_PENDING_CYCLES
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import DeviceFault
from rig.runner import run_experiment
from rig.transports.canopen_link import CanOpenTransport

from sim_rigs import ListSink, no_leaks  # noqa: F401  (a fixture)
from spec_cia402_drive import EMCY_FOLLOWING_ERROR, FAULT, SWITCH_ON_DISABLED, SpecCia402Rig

RATE_HZ = 200.0
SAMPLES = 120
DRIVE = DriveScaling(1 << 17)
WATCHDOG_S = 3.0
START_COUNTS = 12_345  # the drive's position at power-on
DISABLED_STATES = (SWITCH_ON_DISABLED, FAULT)  # the power stage off; QUICK STOP ACTIVE is not


def _options(mode: str) -> dict:
    """Interpolated position: the drive takes each record as the end point of its segment (see the module
    docstring); the master is told so."""
    return {} if mode == "csp" else {"ip_record_is_segment_end": True}


def _transport(rig: SpecCia402Rig, mode: str, **options) -> CanOpenTransport:
    return CanOpenTransport("virtual", rig.channel, mode=mode, heartbeat_ms=100, heartbeat_timeout_s=WATCHDOG_S,
                            sdo_timeout_s=1.0, encoder=EncoderResolution(bits=14, multi_turn_bits=4),
                            sample_period_s=1 / RATE_HZ, drive=DRIVE, timing=BringUpTiming(), name="spec402",
                            **{**_options(mode), **options})


def _command() -> np.ndarray:
    """Held random levels around the drive's position at power-on (every target changes every 4 samples)."""
    start_rad = DRIVE.rad_from_counts(START_COUNTS)
    rng = np.random.default_rng(7)
    return start_rad + np.repeat(rng.uniform(-0.5, 0.5, SAMPLES // 4), 4)


def _run(rig: SpecCia402Rig, mode: str, sink=None, progress=None, **options):
    sink = ListSink() if sink is None else sink
    transport = _transport(rig, mode, **options)
    try:
        summary = run_experiment(transport, _command(), sink, feedback_timeout_s=WATCHDOG_S, progress=progress,
                                 pending_cycles=SIMULATED_RIG_PENDING_CYCLES)
    finally:
        transport.close()
    return transport, summary, sink


def _streamed_cycles(rig: SpecCia402Rig, origin_sync: int | None = None) -> list:
    """The drive's SYNCs from sample 0 on. ``origin_sync``: the number of sample 0's SYNC, as the master
    counts them (from the first SYNC on the bus, as the drive does); a CSP target that reached the bus after
    its SYNC is logged HELD, and the drive takes it up one SYNC later, so only the master's count says which
    SYNC is sample 0. None: the SYNC that took the first interpolation record."""
    if origin_sync is None:
        first = next(i for i, cycle in enumerate(rig.cycles) if cycle.record_taken)
    else:
        first = next(i for i, cycle in enumerate(rig.cycles) if cycle.sync == origin_sync)
    before = rig.cycles[:first]
    assert before, "the master streams only after a few SYNCs in OPERATION ENABLED"
    assert {cycle.demand_counts for cycle in before} == {rig.enable_positions[0]}  # no motion at enable
    return rig.cycles[first:]


def _assert_log_is_what_the_drive_did(rig: SpecCia402Rig, transport: CanOpenTransport, summary, sink) -> None:
    mode = transport.mode
    cycles = _streamed_cycles(rig, transport._origin)
    _, command, _, counts, flags = (np.array(column, dtype=object) for column in zip(*sink.rows))
    flags = flags.astype(int)
    assert len(sink.rows) == SAMPLES and summary.lost == 0 and not np.any(flags & SampleFlag.LOST)
    assert not np.any(flags & (SampleFlag.AMBIGUOUS | SampleFlag.DUPLICATE | SampleFlag.NOT_FOLLOWED))
    assert len(cycles) >= SAMPLES
    applied = [DRIVE.rad_from_counts(cycle.in_force_counts) for cycle in cycles[:SAMPLES]]
    assert command.astype(float).tolist() == applied  # the command the drive took up at each sample's SYNC
    assert counts.astype(int).tolist() == [cycle.encoder_counts for cycle in cycles[:SAMPLES]]
    held = (flags & SampleFlag.HELD) != 0
    assert summary.held == np.count_nonzero(held)
    if mode != "csp":  # interpolated position: HELD exactly where the buffer was empty at the SYNC
        assert held.tolist() == [not cycle.record_taken for cycle in cycles[:SAMPLES]]
    sent = DRIVE.rad_from_counts(np.array([DRIVE.counts_from_rad(value) for value in _command()])).tolist()
    assert [c for c, h, s in zip(command.astype(float).tolist(), held, sent) if not h] == [
        s for s, h in zip(sent, held) if not h]  # a sample not HELD had its own setpoint applied


def _rig(tmp_path, **options) -> SpecCia402Rig:
    return SpecCia402Rig(f"spec402_{tmp_path.name}", start_position_counts=START_COUNTS, **options)


def _assert_stopped(rig: SpecCia402Rig, quick_stopped: bool = True) -> None:
    """The drive's power stage off (a faulted drive stays in FAULT: its controlwords do nothing there),
    after a quick stop (transition 11) unless it faulted, and both nodes PRE-OPERATIONAL. Called with the
    rig still on the bus: NMT is unconfirmed (CiA 301), and the nodes take the master's last command on
    their own receive thread, which a loaded host may run a moment later (bounded wait)."""
    deadline = time.monotonic() + WATCHDOG_S
    while "OPERATIONAL" in rig.nmt_states and time.monotonic() < deadline:
        time.sleep(0.005)
    assert rig.nmt_states == ("PRE-OPERATIONAL", "PRE-OPERATIONAL")
    assert rig.state in DISABLED_STATES
    assert (11 in rig.transitions) == quick_stopped


@pytest.mark.parametrize("mode, quick_stop_option", [("auto", 2), ("ip_buffer", 6), ("csp", 2), ("csp", 6)])
def test_a_clean_run_logs_what_the_standard_drive_applied(tmp_path, no_leaks, mode, quick_stop_option):
    with _rig(tmp_path, quick_stop_option=quick_stop_option) as rig:
        transport, summary, sink = _run(rig, mode)
        _assert_stopped(rig)
    assert rig.records_discarded == 0
    assert transport.mode == ("csp" if mode == "csp" else "ip_buffer")  # auto: the drive has a buffer
    assert rig.mode_display == (8 if mode == "csp" else 7)
    _assert_log_is_what_the_drive_did(rig, transport, summary, sink)
    assert transport.stop_report.disabled
    if quick_stop_option == 6:  # stayed in QUICK STOP ACTIVE until the master's disable voltage (12)
        assert rig.transitions[-2:] == [11, 12] and rig.state == SWITCH_ON_DISABLED


def test_the_interpolation_lag_looks_like_a_tpdo_latency_and_the_master_says_both(tmp_path, no_leaks):
    """CiA 402 linear interpolation: the demand 0x6062 at SYNC k is the record taken at SYNC k - 1 (the
    segment's start), so every changed record shows in 0x6062 one sample late, although the TPDOs answer
    their own SYNC. On the bus that is what a drive that jumps to each record and answers one SYNC late
    sends too, so while streaming the master cannot tell them apart: untold, it stops after 3 such samples,
    naming both causes and the setting for each (the runs above are told ip_record_is_segment_end)."""
    with _rig(tmp_path) as rig:
        with pytest.raises(DeviceFault, match=(r"end point of the segment .* set ip_record_is_segment_end = true"
                                               r"\), or it answers SYNC k after SYNC k \+ 1 \(set "
                                               r"drive_tpdo_latency_cycles = 1\)")):
            _run(rig, "auto", ip_record_is_segment_end=False)
        _assert_stopped(rig)
    cycles = _streamed_cycles(rig)
    assert [cycle.demand_counts for cycle in cycles[1:]] == [cycle.in_force_counts for cycle in cycles[:-1]]


def test_told_a_tpdo_latency_for_the_interpolation_lag_the_master_finds_sample_0_by_the_demand(tmp_path, no_leaks):
    """The other setting the message above offers for this drive, drive_tpdo_latency_cycles = 1, files its
    statusword one SYNC early, so a statusword alone would put sample 0 a SYNC before the drive's first
    record. The SDO answer to controlword bit 4 bounds it only when it comes before the next SYNC; this
    drive's SDO server answers 2.5 periods late, so the master must take the SYNC at which the drive's 0x6062
    shows the records it holds: every command logged is the record the drive took at that SYNC."""
    with _rig(tmp_path, sdo_server_delay_s=2.5 / RATE_HZ) as rig:
        transport, summary, sink = _run(rig, "ip_buffer", ip_record_is_segment_end=False,
                                        drive_tpdo_latency_cycles=1)
        _assert_stopped(rig)
    first_record = next(cycle.sync for cycle in rig.cycles if cycle.record_taken)
    assert transport._origin == first_record
    _assert_log_is_what_the_drive_did(rig, transport, summary, sink)


@pytest.mark.parametrize("mode", ["ip_buffer", "csp"])
def test_a_drive_fault_mid_run_stops_the_run_and_the_drive_ends_disabled(tmp_path, no_leaks, mode):
    """A following error (IP: at record 40; CSP: injected after 40 samples): FAULT REACTION ACTIVE, EMCY
    0x8611, then FAULT; the master stops naming the code; the drive's controlwords in FAULT do nothing."""
    def fault_at_40(done: int, late: int) -> None:
        # once, at the first report of 40 samples or more: a device-clocked loop reports per batch it files
        if mode == "csp" and done >= 40 and not rig.faults:
            rig.fault(EMCY_FOLLOWING_ERROR)

    with _rig(tmp_path, following_error_at_record=None if mode == "csp" else 40) as rig:
        with pytest.raises(DeviceFault, match="0x8611"):
            _run(rig, mode, progress=fault_at_40)
        _assert_stopped(rig, quick_stopped=False)
    assert rig.faults == [EMCY_FOLLOWING_ERROR] and rig.state == FAULT


def test_an_encoder_emcy_mid_run_stops_the_run_and_the_drive_ends_disabled(tmp_path, no_leaks):
    sent = []

    def emcy_at_40(done: int, late: int) -> None:
        # once, at the first report of 40 samples or more: the device-clocked loop reports per batch it files,
        # and on a busy machine a batch can pass 40 without reporting it
        if done >= 40 and not sent:
            sent.append(done)
            rig.encoder_emcy(0x5000)  # CiA 301: device hardware

    with _rig(tmp_path) as rig:
        with pytest.raises(DeviceFault, match="0x5000"):
            _run(rig, "auto", progress=emcy_at_40)
        _assert_stopped(rig)
    assert rig.state == SWITCH_ON_DISABLED  # option 2: the quick stop ends there by itself


class _FailingSink(ListSink):
    def append(self, *row, **columns) -> None:
        if len(self.rows) == 30:
            raise OSError("disk full (injected)")
        super().append(*row, **columns)


@pytest.mark.parametrize("mode", ["auto", "csp"])
def test_the_host_failing_mid_run_leaves_the_drive_disabled(tmp_path, no_leaks, mode):
    with _rig(tmp_path, quick_stop_option=6) as rig:
        with pytest.raises(OSError, match="disk full"):
            _run(rig, mode, sink=_FailingSink())
        _assert_stopped(rig)
    assert rig.transitions[-2:] == [11, 12]  # option 6: QUICK STOP ACTIVE until the master's disable voltage


def _rig_config(tmp_path, channel: str, mode: str) -> str:
    path = tmp_path / "spec_rig.toml"
    path.write_text(f"""
name = "spec402_rig"
sample_rate_hz = {RATE_HZ}

[transport]
url = "canopen://virtual/{channel}"
heartbeat_ms = 100
heartbeat_timeout_s = {WATCHDOG_S}
sdo_timeout_s = 1.0
mode = "{mode}"
ip_record_is_segment_end = {str(_options(mode).get("ip_record_is_segment_end", False)).lower()}

[drive]
counts_per_revolution = {1 << 17}

[encoder]
bits = 14
multi_turn_bits = 4
signed = false

[limits]
position_min_rad = -3.0
position_max_rad = 3.0
rate_max_rad_per_s = 500.0

[watchdog]
feedback_timeout_s = {WATCHDOG_S}
late_tolerance_s = 0.0025
""")
    return str(path)


@pytest.mark.parametrize("mode", ["ip_buffer", "csp"])
def test_the_trace_of_a_run_against_the_standard_drive_imports_as_its_log(tmp_path, no_leaks, mode):
    """``rig import`` files the trace as the run filed it, sample for sample (LATE is judged from the trace's
    stamps, so not compared)."""
    from rig.rig_config import load_rig_config
    from rig.trace_import import import_trace
    from rig.transports import parse_transport_url

    trace, sink = tmp_path / "run.blf", ListSink()
    with _rig(tmp_path) as rig:
        config = load_rig_config(_rig_config(tmp_path, rig.channel, mode))
        transport = CanOpenTransport(**parse_transport_url(config.url)[1], **config.transport_options(),
                                     trace_path=str(trace))
        try:
            summary = run_experiment(transport, _command(), sink, feedback_timeout_s=WATCHDOG_S,
                                     pending_cycles=SIMULATED_RIG_PENDING_CYCLES)
        finally:
            transport.close()
    _assert_log_is_what_the_drive_did(rig, transport, summary, sink)
    record = import_trace(trace, config)
    flags = np.array([row[4] for row in sink.rows])
    np.testing.assert_array_equal(record.command_rad, [row[1] for row in sink.rows])
    np.testing.assert_array_equal(record.encoder_counts, [row[3] for row in sink.rows])
    np.testing.assert_array_equal(record.flags & ~np.uint8(SampleFlag.LATE), flags & ~np.uint8(SampleFlag.LATE))


def test_a_drive_found_in_fault_is_reset_on_a_rising_edge_and_streams(tmp_path, no_leaks):
    """The drive faulted before the master came (FAULT REACTION ACTIVE, then FAULT): the bring-up's fault
    reset (a rising edge of bit 7, transition 15, which this drive takes ``fault_reset_s`` to complete) clears
    it, and the run is clean."""
    with _rig(tmp_path, fault_reset_s=0.05) as rig:
        rig.fault(0x2310)  # CiA 301: continuous over-current
        transport, summary, sink = _run(rig, "csp")
        _assert_stopped(rig)
    assert rig.faults == [0x2310] and rig.transitions[:3] == [13, 14, 15]
    _assert_log_is_what_the_drive_did(rig, transport, summary, sink)
