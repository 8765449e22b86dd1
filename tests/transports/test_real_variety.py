"""The CANopen master against the legal variety of real devices (sim_backend.canopen_behaviour): every
behaviour either runs clean, with every sample filed under its own instant, or stops with the drive
disabled and a message naming the device and the object or code.

The expected outcome of each behaviour is written here, from the standard, not read from the driver.
"""

from __future__ import annotations

import contextlib
import time

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig.protocols.cia402 import DriveState
from rig.protocols.errors import ConfigError, RigError
from rig.rig_config import load_rig_config
from rig.demo import SIMULATED_RIG_PENDING_CYCLES
from rig.runner import run_experiment
from rig.transports import open_transport
from sim_backend.canopen_behaviour import OPTIONAL_OBJECTS_MISSING, real_variety
from sim_backend.eds_variants import eds_without
from sim_backend.plant_config import load_plant_config

from sim_rigs import ListSink, excitation, no_leaks, write_test_config  # noqa: F401  (no_leaks is a fixture)

CLEAN = "runs clean"
VARIETY = real_variety()
# name -> (expected outcome, what the message must name, master options, fault injected at sample 20)
EXPECTED = {
    "forgiving (default)": (CLEAN, None, {}, None),
    "target not copied at enable": (CLEAN, None, {}, None),
    "stale target within the window (moves at enable)": (CLEAN, None, {}, None),
    "stale target beyond the window (0x8611 at enable)": (CLEAN, None, {}, None),
    "fault reset takes 20 ms": (CLEAN, None, {}, "before"),
    "mode switch takes 0.5 s": (CLEAN, None, {}, None),
    "enable only with SYNC running": (CLEAN, None, {}, None),
    "SYNC watchdog 50 ms (0x8700)": (CLEAN, None, {}, None),
    "TPDOs one SYNC late": ("stops", r"drive_tpdo_latency_cycles = 1", {}, None),
    "encoder TPDO one SYNC late": (CLEAN, None, {"encoder_tpdo_latency_cycles": 1}, None),
    "static PDOs": (CLEAN, None, {}, None),
    "static encoder TPDO every 2nd SYNC": ("stops", r"encoder 2.*transmission type 2 \(0x1800:02", {}, None),
    "static 2-byte encoder TPDO": (CLEAN, None, {}, None),
    "quick stop option 2 (to SWITCH ON DISABLED)": (CLEAN, None, {}, None),
    "quick stop option 6 (stays in QUICK STOP ACTIVE)": (CLEAN, None, {}, None),
    "pre-operational on fault": ("stops", r"drive 1 \(code 0x2310", {}, 20),
    "stopped on fault": ("stops", r"drive 1 \(code 0x2310", {}, 20),
    "encoder temperature warning at sample 20": (CLEAN, None, {}, None),
    # interpolated position (CiA 402 0x60C1/0x60C4): a master that fills the buffer before controlword bit 4
    # and never lets it run dry, and writes 0x60C2 = the SYNC period, runs clean on each of these
    "interpolation buffer underflow faults (EPOS-like, 0x8600)": (CLEAN, None, {}, None),
    "underflow faults after the first record (0x8600)": (CLEAN, None, {}, None),
    "needs 0x60C2 = SYNC period (0x6320)": (CLEAN, None, {}, None),
    "interpolation buffer of 16 records": (CLEAN, None, {}, None),
    "interpolation buffer of 4 records": (CLEAN, None, {}, None),
    "interpolation buffer of 3 records": (CLEAN, None, {}, None),  # auto: too small to stream into, CSP
    "small buffer, faults on underflow": (CLEAN, None, {}, None),
}


def test_every_behaviour_of_the_variety_has_an_expected_outcome():
    assert set(EXPECTED) == set(VARIETY)


@contextlib.contextmanager
def _rig_with(tmp_path, name: str, master_options: dict, fault_at: int | None):
    from rig.transports.simulated import start_simulated_devices

    drive_behaviour, encoder_behaviour = VARIETY[name]
    config = load_rig_config(write_test_config("canopen", tmp_path))
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    injection = {"fault_at_seq": fault_at, "fault_code": 0x2310} if isinstance(fault_at, int) else {}
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, gearbox, stack, drive_behaviour=drive_behaviour,
                                           encoder_behaviour=encoder_behaviour, **injection)
        drive_eds, encoder_eds = rig.write_eds(tmp_path)  # what the vendor ships for these devices
        transport = open_transport(url, **dict(config.transport_options(), drive_eds=str(drive_eds),
                                                encoder_eds=str(encoder_eds), **master_options))
        stack.callback(transport.close)
        if fault_at == "before":
            rig.inject_fault(0x2310)  # the drive is in FAULT when the master comes
        yield config, transport, rig


def _nmt_state_after_teardown(node, timeout_s: float = 2.0) -> str:
    """The node's NMT state once it has taken the master's last NMT command. NMT is unconfirmed (CiA 301): the
    master sends it and returns, and the simulated node takes it on its own receive thread, which a loaded
    host may run a moment later; wait (bounded) for it to leave OPERATIONAL before judging."""
    deadline = time.monotonic() + timeout_s
    while node.nmt.state == "OPERATIONAL" and time.monotonic() < deadline:
        time.sleep(0.005)
    return node.nmt.state


@pytest.mark.parametrize("mode", ["auto", "csp"])  # auto: interpolated position where the drive can take it
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_the_master_runs_clean_or_stops_safely_on_each_real_behaviour(name, mode, tmp_path, no_leaks):
    outcome, message, master_options, fault_at = EXPECTED[name]
    sink = ListSink()
    with _rig_with(tmp_path, name, {"mode": mode, **master_options}, fault_at) as (config, transport, rig):
        try:
            # the simulated nodes answer from threads of this process, which a loaded host can starve for
            # longer than the lead: give their answers the demo's window (SIMULATED_RIG_PENDING_CYCLES)
            # a run expected to stop gets room to: a TPDO latency shows on samples whose target changed (every 4th
            # here), and the master stops at the third in a row; a changed target whose 0x6062 looked in time
            # restarts the count, which once in seven loaded full runs left 60 samples without a stop
            samples = 60 if outcome == CLEAN else 240
            summary = run_experiment(transport, excitation(samples), sink, feedback_timeout_s=config.feedback_timeout_s,
                                     late_tolerance_s=config.late_tolerance_s,
                                     pending_cycles=SIMULATED_RIG_PENDING_CYCLES)
            error = None
        except RigError as err:
            error = " ".join([str(err), *getattr(err, "__notes__", ())])
        end_state, nmt = rig.state, _nmt_state_after_teardown(rig.drive)
    assert end_state in (DriveState.SWITCH_ON_DISABLED, DriveState.FAULT), end_state  # never left enabled
    assert nmt in ("PRE-OPERATIONAL", "STOPPED")
    if outcome == CLEAN:
        assert error is None, error
        flags = np.array([row[4] for row in sink.rows])
        assert len(sink.rows) == 60 and summary.lost == 0
        unusable = int(SampleFlag.unusable())
        assert not np.any(flags & unusable), f"unusable samples: {np.flatnonzero(flags & unusable)}"
        if "temperature warning" in name:
            assert any("EMCY 0x4210" in warning and "encoder 2" in warning for warning in summary.warnings)
    else:
        assert error is not None and __import__("re").search(message, error), error
        assert sink.closed


@pytest.mark.parametrize("name", sorted(OPTIONAL_OBJECTS_MISSING))
def test_a_vendor_eds_without_an_optional_object_is_driven_or_refused_naming_it(name, tmp_path):
    device, indices = OPTIONAL_OBJECTS_MISSING[name]
    config = load_rig_config(write_test_config("canopen", tmp_path))
    source = config.options.get(f"{device}_eds")
    from rig.transports.canopen_link import DEFAULT_DRIVE_EDS, DEFAULT_ENCODER_EDS

    source = source or (DEFAULT_DRIVE_EDS if device == "drive" else DEFAULT_ENCODER_EDS)
    eds = eds_without(source, indices, tmp_path / f"{device}.eds")
    options = dict(config.transport_options(), **{f"{device}_eds": str(eds)})
    url = config.url
    # optional for this master: 0x603F (only decorates messages), 0x6098 (homing only), 0x6502, 0x6501, 0x1006
    # (the SYNC period then goes to 0x60C2 alone)
    open_transport(url, **options)
    if indices == (0x1006,):  # without 0x60C2 as well, the SYNC period has nowhere to go
        eds = eds_without(source, (0x1006, 0x60C2), tmp_path / f"{device}_no_period.eds")
        with pytest.raises(ConfigError, match=r"neither 0x1006 \(communication cycle period\) nor 0x60C2"):
            open_transport(url, **dict(options, drive_eds=str(eds)))
