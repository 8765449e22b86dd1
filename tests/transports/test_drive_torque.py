"""The drive's torque actual value (CiA 402 0x6077) from the CANopen master to the log: mapped into the drive's
TPDO1 beside 0x6041 and 0x6064 where the drive's EDS makes it PDO-mappable, filed with the statusword and position
of the same SYNC, written as the log's ``drive_torque`` column (rig-log v2); a drive that will not map it is
streamed without it, and says so.

The simulated servo (``configs/sim_pendulum_canopen.toml``: a drive_train plant behind
``configs/eds/sim_servo_drive_cia402.eds``) reports the motor's torque at each SYNC in per mille of its rated
torque 0x6076; the truth here is the drive train run offline on the commands the log says were applied."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest

from identify.drive_train import DriveTrain
from identify.experiment_record import SampleFlag
from identify.validation import InvalidInputError
from rig.demo import SIMULATED_RIG_PENDING_CYCLES
from rig.log_file import LogWriter, read_log
from rig.protocols.cia402 import DriveState
from rig.rig_config import load_rig_config
from rig.runner import run_experiment
from rig.transports import open_transport
from rig.transports.canopen_link import DEFAULT_DRIVE_EDS
from sim_backend.canopen_behaviour import DriveBehaviour
from sim_backend.canopen_nodes import SimulatedCanOpenRig
from sim_backend.plant_config import load_plant_config

from sim_rigs import no_leaks  # noqa: F401  (a fixture)

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
PENDULUM = CONFIGS / "sim_pendulum_canopen.toml"
SAMPLES = 250  # 2.5 s at 100 Hz


def _command(samples: int = SAMPLES) -> np.ndarray:
    t = np.arange(samples) * 0.01
    return 0.9 * np.sin(2 * np.pi * 0.5 * t) * np.minimum(1.0, t / 0.5)


def _gearbox(config):
    return load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)


@contextlib.contextmanager
def _pendulum_run(tmp_path, **device_options):
    """Run the pendulum's simulated CANopen rig over :func:`_command`; yield the log read back, the run's summary,
    the simulated rig and the transport. With ``device_options``, the master loads the EDS the simulated devices
    write of themselves (as a vendor's)."""
    from rig.transports.simulated import start_simulated_devices

    config = load_rig_config(PENDULUM)
    path = tmp_path / "run.csv"
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, _gearbox(config), stack, **device_options)
        options = config.transport_options()
        if device_options:
            drive_eds, encoder_eds = rig.write_eds(tmp_path)
            options.update(drive_eds=str(drive_eds), encoder_eds=str(encoder_eds))
        transport = open_transport(url, **options)
        log = LogWriter(path, {"sample_period_s": config.sample_period_s, "source": "test"},
                        drive_torque_unit=transport.drive_torque_unit)
        summary = run_experiment(transport, _command(), log, feedback_timeout_s=config.feedback_timeout_s,
                                 pending_cycles=SIMULATED_RIG_PENDING_CYCLES)
        yield read_log(path), summary, rig, transport


def test_the_log_holds_the_motor_torque_the_drive_had_at_each_sample(tmp_path, no_leaks):
    with _pendulum_run(tmp_path) as (record, summary, rig, transport):
        rated_mnm = int.from_bytes(rig.drive.get_data(0x6076, 0), "little")
        end_state = rig.state
    assert end_state is DriveState.SWITCH_ON_DISABLED
    assert summary.lost == 0 and record.command_rad.size == SAMPLES
    assert not np.any(record.flags & int(SampleFlag.unusable()))
    assert transport.drive_torque_unit == "permille_of_rated_torque"
    assert record.metadata.extra["drive_torque_unit"] == "permille_of_rated_torque"
    # 0x6076 is the drive train's motor torque limit in mN m (8.522 mN m -> 9); the master read it for the summary
    assert rated_mnm == 9 and transport.drive_torque_nm_per_unit == pytest.approx(9e-6, rel=1e-12)
    assert record.metadata.extra["summary"]["drive_torque_nm_per_unit"] == transport.drive_torque_nm_per_unit
    train = _gearbox(load_rig_config(PENDULUM)).plant.find(DriveTrain)[0]
    truth = train.simulate(record.command_rad).motor_torque_nm  # from rest, on the targets applied at each SYNC
    expected = np.clip(np.round(1e6 * truth / rated_mnm), -32768, 32767)
    # the same instant: a torque filed one SYNC off would differ by the swing's change per sample (tens of per mille)
    assert np.array_equal(record.drive_torque, expected), np.flatnonzero(record.drive_torque != expected)[:5]
    assert np.ptp(record.drive_torque) > 200  # the swing is in it, not a constant


def test_a_drive_whose_pdo_will_not_take_the_torque_is_streamed_without_it(tmp_path, no_leaks):
    # static PDOs: TPDO1 stays 0x6041 + 0x6064 (read-only mapping), though the EDS lists 0x6077 as mappable
    with _pendulum_run(tmp_path, drive_behaviour=DriveBehaviour(static_pdos=True)) as (record, summary, rig, _):
        end_state = rig.state
    assert end_state is DriveState.SWITCH_ON_DISABLED
    assert summary.lost == 0 and record.command_rad.size == SAMPLES
    assert not np.any(record.flags & int(SampleFlag.unusable()))
    assert record.drive_torque is None  # the column is there (v2) and empty: not measured
    warning = next(text for text in summary.warnings if "0x6077" in text)
    assert "drive 1" in warning and "not logged" in warning and "TPDO1" in warning


def test_a_device_process_is_built_from_the_eds_the_rig_config_names(tmp_path):
    from rig.transports.simulated import PATIENT_WITH_A_DEVICE_PROCESS, start_device_process

    config = load_rig_config(PENDULUM)
    path = tmp_path / "run.csv"
    with contextlib.ExitStack() as stack:  # the devices in a process of their own, producing SYNC on their clock
        url, _ = start_device_process(config, stack, produce_sync=True)
        transport = open_transport(url, **{**config.transport_options(), **PATIENT_WITH_A_DEVICE_PROCESS["canopen"],
                                           "sync_producer": "external"})
        with LogWriter(path, {"sample_period_s": config.sample_period_s},
                       drive_torque_unit=transport.drive_torque_unit) as log:
            summary = run_experiment(transport, _command(100), log, feedback_timeout_s=2.0)
    record = read_log(path)
    assert not any("0x6077" in warning for warning in summary.warnings)
    assert record.drive_torque is not None and np.isfinite(record.drive_torque[record.valid_mask]).all()
    assert np.ptp(record.drive_torque) > 100


def test_the_master_offers_the_torque_column_only_where_the_drive_eds_has_a_mappable_0x6077():
    config = load_rig_config(PENDULUM)
    options = config.transport_options()
    with_torque = open_transport(config.url, **options)
    without = open_transport(config.url, **{**options, "drive_eds": str(DEFAULT_DRIVE_EDS)})
    assert with_torque.drive_torque_unit == "permille_of_rated_torque" and without.drive_torque_unit is None
    # the bus-load check counts the two bytes more in the drive's TPDO1 (8 instead of 6 data bytes)
    assert with_torque.load.bits_per_cycle > without.load.bits_per_cycle


def test_a_simulated_drive_never_makes_up_a_torque_its_plant_does_not_model():
    config = load_rig_config(CONFIGS / "sim_canopen.toml")  # precision gearbox: blocks without a motor
    with pytest.raises(InvalidInputError, match=r"0x6077.*no drive_train block.*sim_drive_cia402\.eds"):
        SimulatedCanOpenRig(_gearbox(config), channel="unused",
                            drive_eds=CONFIGS / "eds" / "sim_servo_drive_cia402.eds")


# -- against a drive written from CiA 301/402 alone (tests/peers/torque_drive, which never read this project) -------

@pytest.fixture
def torque_peer():
    """The clean-room peer's harness; python-can's virtual bus as it was before (the harness orders its deliveries
    for the run, as a CAN bus does)."""
    import sys

    from can.interfaces import virtual

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "peers"))
    from torque_drive import harness

    send = virtual.VirtualBus.send
    yield harness
    virtual.VirtualBus.send = send


def _rows_at_their_syncs(record, history, counts_per_revolution: int) -> list[tuple[int, dict]]:
    """(row, the peer's SYNC entry) for every usable row: the peer's entries from the SYNC whose applied target is the
    first row's command on, one per row. The offset is the one under which the rows' commands are the targets the
    drive applied."""
    usable = np.flatnonzero((record.flags & int(SampleFlag.unusable())) == 0)
    targets = np.rint(record.command_rad * counts_per_revolution / (2 * np.pi)).astype(int)
    applied = [entry for entry in history if entry.get("target") is not None]
    best = max(range(len(applied) - len(targets) + 1),
               key=lambda offset: sum(applied[offset + k]["target"] == targets[k] for k in usable))
    return [(int(k), applied[best + k]) for k in usable]


@pytest.mark.parametrize("variant", ["mappable", "static", "refuses"])
def test_a_clean_room_drive_gets_its_torque_logged_or_the_run_says_why_not(variant, torque_peer, tmp_path):
    result = torque_peer.run_rig(variant, tmp_path, samples=300)
    assert result["exit"] == 0, result["stderr_tail"]
    assert result["final_state"] == "SWITCH ON DISABLED"
    record = read_log(result["log"])
    assert record.command_rad.size == 300 and not np.any(record.flags & int(SampleFlag.LOST))
    if variant == "mappable":  # TPDO1 = 0x6041 + 0x6064 + 0x6077, each row's torque the one latched at its SYNC
        rows = _rows_at_their_syncs(record, result["history"], torque_peer.CPR)
        assert all(entry["target"] == round(record.command_rad[k] * torque_peer.CPR / (2 * np.pi)) for k, entry in rows)
        assert [record.drive_torque[k] for k, _ in rows] == [entry["torque_permille"] for _, entry in rows]
        assert len({entry["torque_permille"] for _, entry in rows}) > 10  # the torque moves with the command
        assert not result["aborts"]
        # the peer's rated torque 0x6076 is 2390 mN m (its README): the summary gives N m per unit of the column
        assert record.metadata.extra["summary"]["drive_torque_nm_per_unit"] == pytest.approx(2.39e-3, rel=1e-12)
    else:  # a static TPDO1 (abort 0x06010002) or a device that will not map 0x6077 (abort 0x06040041)
        assert record.drive_torque is None and record.metadata.extra["drive_torque_unit"] == "permille_of_rated_torque"
        code = {"static": "0x06010002", "refuses": "0x06040041"}[variant]
        assert any(abort[-1] == code for abort in result["aborts"])
        summary = record.metadata.extra["summary"]
        assert any("0x6077 is not logged" in warning and code in warning for warning in summary["warnings"])
