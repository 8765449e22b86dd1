"""A simulated rig whose plant is the user's FMU: ``rig run`` over the real wire gives the
samples of the FMU simulated offline on the logged command, and a bad FMU plant is named when the rig
config is loaded."""

from __future__ import annotations

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig import exit_codes
from rig.cli import main
from rig.log_file import read_log
from rig.protocols.errors import ConfigError
from rig.rig_config import load_rig_config
from sim_backend.plant_config import load_simulated_plant

from sim_rigs import CONFIGS, no_leaks, write_test_config  # noqa: F401  (no_leaks is a fixture)


def fmu_rig_config(kind: str, directory, fmu_path, extra: str = "") -> str:
    """``configs/sim_<kind>.toml`` at the test rate with the FMU as its ``[simulation] plant``."""
    path = write_test_config(kind, directory)
    lines = [f'plant = "{fmu_path}"' if line.startswith("plant =") else line
             for line in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n" + extra)
    return str(path)


@pytest.mark.parametrize("kind", ["canopen", "can", "serial"])
def test_a_run_with_an_fmu_plant_gives_the_fmu_simulated_offline_on_the_logged_command(kind, test_fmus, tmp_path,
                                                                                      no_leaks):
    config_path = fmu_rig_config(kind, tmp_path, test_fmus["gearbox_servo"])
    log_path = tmp_path / "run.csv"
    code = main(["run", config_path, "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(log_path), "--duration", "1.0"])
    assert code == exit_codes.SUCCESS
    record = read_log(log_path)
    config = load_rig_config(config_path)
    assert record.command_rad.size == 200 and record.metadata.config["rig"]["simulation"]["plant"] == \
        str(test_fmus["gearbox_servo"])
    lost = (record.flags & SampleFlag.LOST) != 0
    assert np.count_nonzero(~lost) > 150
    # the device stepped the FMU once per sample instant with the command it applied (a HELD sample logs the
    # target really in force): the offline run of that command, read by the same encoder, is the log
    offline = load_simulated_plant(config.simulation.plant_path, sample_period_s=config.sample_period_s,
                                   encoder=config.encoder).gearbox(seed=config.simulation.seed)
    expected = offline.simulate(record.command_rad)
    np.testing.assert_array_equal(record.angle_rad[~lost], expected.measured_angle_rad[~lost])
    np.testing.assert_array_equal(record.encoder_counts[~lost], expected.encoder_counts[~lost])
    assert np.ptp(expected.load_angle_rad) > 1.0  # the PRBS of +-1 rad moved the FMU's load


def test_a_model_exchange_fmu_is_stepped_once_per_sync_too(c_servo_fmus, tmp_path, no_leaks):
    fmu_path = c_servo_fmus[("3.0", "ModelExchange")]
    config_path = fmu_rig_config("canopen", tmp_path, fmu_path)
    log_path = tmp_path / "run.csv"
    assert main(["run", config_path, "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(log_path), "--duration", "0.5"]) == exit_codes.SUCCESS
    record = read_log(log_path)
    config = load_rig_config(config_path)
    lost = (record.flags & SampleFlag.LOST) != 0
    expected = load_simulated_plant(fmu_path, sample_period_s=config.sample_period_s,
                                    encoder=config.encoder).gearbox().simulate(record.command_rad)
    np.testing.assert_array_equal(record.angle_rad[~lost], expected.measured_angle_rad[~lost])
    # A model-exchange FMU costs the in-process device far more a sample than a co-simulation one, and more the
    # busier the host (BENCHMARKS.md, "FMU plants"), so some samples may be LOST (under load 14 over a quarter
    # were): a quarter received is ample to compare the dynamics by.
    assert np.count_nonzero(~lost) > 25


def test_an_fmu_plant_with_several_inputs_is_named_when_the_config_loads(test_fmus, tmp_path):
    with pytest.raises(ConfigError) as error:
        load_rig_config(fmu_rig_config("canopen", tmp_path, test_fmus["two_port_gearbox"]))
    message = str(error.value)
    assert "sim_canopen_test.toml: [simulation.plant]" in message
    assert "2 real inputs (command, load_torque_nm)" in message and 'fmu_input = "NAME" in [simulation]' in message
    config = load_rig_config(fmu_rig_config("canopen", tmp_path, test_fmus["two_port_gearbox"],
                                            'fmu_input = "command"\nfmu_output = "angle"\n'))
    assert (config.simulation.fmu_input, config.simulation.fmu_output) == ("command", "angle")


def test_fmu_variables_given_for_a_toml_plant_are_refused(tmp_path):
    path = write_test_config("canopen", tmp_path)
    path.write_text(path.read_text() + 'fmu_input = "command"\n')
    with pytest.raises(ConfigError, match=r"\[simulation.fmu_input\] chooses a variable of an FMU plant"):
        load_rig_config(path)
