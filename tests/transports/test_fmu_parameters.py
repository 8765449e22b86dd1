"""FMU parameters set from the rig config (``[simulation] fmu_parameters``) and from ``rig diagnose
--fmu-parameter``, checked against the model description; an FMU's input and output in degrees converted;
``rig inspect model.fmu`` lists the parameters; a plant too slow for the rig's clock is named when the run fails."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fmu_models.build import build_python_fmu, with_model_description
from rig import exit_codes
from rig.cli import main
from rig.protocols.errors import ConfigError
from rig.rig_config import load_rig_config
from sim_backend.fmu_plant import describe_fmu, open_fmu_block
from sim_backend.plant_config import load_simulated_plant

from sim_rigs import CONFIGS, no_leaks, write_test_config  # noqa: F401  (no_leaks is a fixture)

PERIOD_S = 0.01
DAMPING = '<ScalarVariable name="damping_ratio" valueReference="3" causality="parameter" variability="tunable">'


def _rig_config(directory, fmu_path, extra: str = "", kind: str = "serial") -> str:
    path = write_test_config(kind, directory)
    lines = [f'plant = "{fmu_path}"' if line.startswith("plant =") else line
             for line in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n" + extra)
    return str(path)


@pytest.fixture(scope="module")
def ranged_fmu(test_fmus, tmp_path_factory):
    """The gearbox servo with damping_ratio limited to [0.05, 2] and natural_frequency_hz made a calculated
    parameter (which cannot be set)."""
    folder = tmp_path_factory.mktemp("ranged")
    return with_model_description(test_fmus["gearbox_servo"], folder / "ranged.fmu", {
        '<Real start="0.7"/>': '<Real start="0.7" min="0.05" max="2"/>',
        'name="natural_frequency_hz" valueReference="2" causality="parameter"':
            'name="natural_frequency_hz" valueReference="2" causality="calculatedParameter"'})


def test_a_parameter_changes_the_fmu_and_is_kept_through_instance_reuse(test_fmus):
    command = np.repeat([0.0, 1.0, -0.5, 0.8], 60)
    nominal = open_fmu_block(test_fmus["gearbox_servo"], PERIOD_S)
    light = open_fmu_block(test_fmus["gearbox_servo"], PERIOD_S, parameters={"damping_ratio": 0.1})
    assert light.parameters == (("damping_ratio", 3, "Real", 0.1),)
    out_nominal, out_light = nominal.apply(command), light.apply(command)
    assert np.max(out_light) > np.max(out_nominal) + 0.3  # far less damping: a large overshoot
    assert np.max(out_nominal) < 1.1
    # whole runs reuse a reset instance: the parameter is set again after each reset, and the nominal one
    # again gets the start value
    np.testing.assert_array_equal(light.apply(command + 0.0), out_light)
    np.testing.assert_array_equal(nominal.apply(command * 1.0 + 0.0), out_nominal)
    stepper = light.stepper()
    np.testing.assert_array_equal([stepper.step(x) for x in command], out_light)
    stepper.close()


def test_unknown_unsettable_and_out_of_range_parameters_are_named_with_what_they_accept(ranged_fmu):
    with pytest.raises(ConfigError) as error:
        open_fmu_block(ranged_fmu, PERIOD_S, parameters={"damping": 0.5})
    message = str(error.value)
    assert str(ranged_fmu) in message and "[fmu_parameters.damping]" in message
    assert "no variable 'damping'" in message and "damping_ratio" in message
    with pytest.raises(ConfigError, match=r"\[fmu_parameters\.natural_frequency_hz\] cannot be set \(causality "
                                          r"calculatedParameter, variability tunable.*damping_ratio"):
        open_fmu_block(ranged_fmu, PERIOD_S, parameters={"natural_frequency_hz": 5.0})
    with pytest.raises(ConfigError, match=r"\[fmu_parameters\.angle\] is not a parameter of the FMU \(causality output"):
        open_fmu_block(ranged_fmu, PERIOD_S, parameters={"angle": 5.0})
    with pytest.raises(ConfigError, match=r"\[fmu_parameters\.damping_ratio\] 3\.5 is outside the range the FMU "
                                          r"accepts: a real number in \[0\.05, 2\] \(start 0\.7\)"):
        open_fmu_block(ranged_fmu, PERIOD_S, parameters={"damping_ratio": 3.5})
    with pytest.raises(ConfigError, match=r"expected a real number in \[0\.05, 2\].*got 'high'"):
        open_fmu_block(ranged_fmu, PERIOD_S, parameters={"damping_ratio": "high"})
    assert open_fmu_block(ranged_fmu, PERIOD_S, parameters={"damping_ratio": 2}).parameters[0][3] == 2.0


def test_the_rig_config_sets_fmu_parameters_and_names_bad_ones(test_fmus, ranged_fmu, tmp_path):
    config = load_rig_config(_rig_config(tmp_path, test_fmus["gearbox_servo"],
                                         "fmu_parameters = { damping_ratio = 0.1 }\n"))
    assert config.simulation.fmu_parameters == {"damping_ratio": 0.1}
    plant = load_simulated_plant(config.simulation.plant_path, sample_period_s=config.sample_period_s,
                                 encoder=config.encoder, fmu_parameters=config.simulation.fmu_parameters)
    assert plant.plant.blocks[0].parameters == (("damping_ratio", 3, "Real", 0.1),)
    with pytest.raises(ConfigError) as error:
        load_rig_config(_rig_config(tmp_path, ranged_fmu, "fmu_parameters = { damping_ratio = 9.0 }\n"))
    message = str(error.value)
    assert "sim_serial_test.toml: [simulation.fmu_parameters]" in message and "ranged.fmu" in message
    assert "9.0 is outside the range" in message and "[0.05, 2]" in message
    plain = write_test_config("serial", tmp_path)
    plain.write_text(plain.read_text() + "fmu_parameters = { damping_ratio = 0.1 }\n")
    with pytest.raises(ConfigError, match=r"\[simulation\.fmu_parameters\] sets parameters of an FMU plant"):
        load_rig_config(plain)


def test_a_run_on_a_rig_with_fmu_parameters_logs_the_parameterised_plant(test_fmus, tmp_path, no_leaks):
    config_path = _rig_config(tmp_path, test_fmus["gearbox_servo"], "fmu_parameters = { damping_ratio = 0.1 }\n")
    log = tmp_path / "run.csv"
    assert main(["run", config_path, "--experiment", str(CONFIGS / "experiments" / "prbs.toml"), "--out", str(log),
                 "--duration", "0.5", "--json"]) == exit_codes.SUCCESS
    from identify.experiment_record import SampleFlag
    from rig.log_file import read_log

    record = read_log(log)
    config = load_rig_config(config_path)
    lost = (record.flags & SampleFlag.LOST) != 0
    expected = load_simulated_plant(config.simulation.plant_path, sample_period_s=config.sample_period_s,
                                    encoder=config.encoder, fmu_parameters={"damping_ratio": 0.1}
                                    ).gearbox(seed=config.simulation.seed).simulate(record.command_rad)
    np.testing.assert_array_equal(record.angle_rad[~lost], expected.measured_angle_rad[~lost])


def test_diagnose_takes_fmu_parameters_on_the_command_line(test_fmus, ranged_fmu, tmp_path, capsys):
    rng = np.random.default_rng(2)
    command = np.repeat(rng.uniform(-1, 1, 25), 24)
    truth = open_fmu_block(test_fmus["gearbox_servo"], PERIOD_S, parameters={"damping_ratio": 0.3}).apply(command)
    data = tmp_path / "servo.csv"
    data.write_text("t,u,y\n" + "".join(f"{k * PERIOD_S!r},{float(u)!r},{float(y)!r}\n"
                                        for k, (u, y) in enumerate(zip(command, truth))))
    code = main(["diagnose", str(data), "--model", str(test_fmus["gearbox_servo"]), "--fmu-parameter",
                 "damping_ratio=0.3", "--noise-bound", "0.001", "--json"])
    captured = capsys.readouterr()
    assert code == exit_codes.SUCCESS, captured.err
    result = json.loads(captured.out)
    assert result["verdict"] == "explained" and result["fmu"]["parameters"] == {"damping_ratio": 0.3}
    assert main(["diagnose", str(data), "--model", str(ranged_fmu), "--fmu-parameter", "damping_ratio=7",
                 "--noise-bound", "0.001"]) == exit_codes.BAD_INPUT
    err = capsys.readouterr().err
    assert "ranged.fmu" in err and "[--fmu-parameter.damping_ratio] 7 is outside" in err and "Traceback" not in err
    assert main(["diagnose", str(data), "--fmu-parameter", "damping_ratio=0.3", "--noise-bound", "0.001"]) == \
        exit_codes.BAD_INPUT
    assert "--fmu-parameter sets a parameter of an FMU: give --model PLANT.fmu" in capsys.readouterr().err


def test_rig_inspect_lists_an_fmus_parameters(ranged_fmu, capsys):
    assert main(["inspect", str(ranged_fmu)]) == exit_codes.SUCCESS
    out = capsys.readouterr().out
    assert "damping_ratio: a real number in [0.05, 2] (start 0.7), tunable" in out
    assert "natural_frequency_hz: a real number (start 8), tunable calculatedParameter; cannot be set" in out
    assert main(["inspect", str(ranged_fmu), "--json"]) == exit_codes.SUCCESS
    info = json.loads(capsys.readouterr().out)
    damping = next(p for p in info["parameters"] if p["name"] == "damping_ratio")
    assert (damping["min"], damping["max"], damping["start"], damping["settable"]) == (0.05, 2.0, "0.7", True)
    assert [v["name"] for v in info["inputs"]] == ["command"]


def test_an_fmu_in_degrees_is_converted_and_another_unit_refused(test_fmus, tmp_path):
    command = np.repeat([0.0, 0.4, -0.3], 80)
    nominal = open_fmu_block(test_fmus["gearbox_servo"], PERIOD_S).apply(command)
    degrees = with_model_description(test_fmus["gearbox_servo"], tmp_path / "degrees.fmu", {
        '<Real start="0"/>': '<Real start="0" unit="deg"/>', "<Real/>": '<Real unit="deg"/>'})
    block = open_fmu_block(degrees, PERIOD_S)
    assert describe_fmu(degrees).outputs[0].unit == "deg"
    np.testing.assert_allclose(block.apply(command), nominal, atol=1e-12)  # rad in, deg inside, rad out
    output_only = with_model_description(test_fmus["gearbox_servo"], tmp_path / "out_deg.fmu",
                                         {"<Real/>": '<Real unit="deg"/>'})
    np.testing.assert_allclose(open_fmu_block(output_only, PERIOD_S).apply(command), nominal * math.pi / 180, atol=1e-12)
    metres = with_model_description(test_fmus["gearbox_servo"], tmp_path / "metres.fmu", {"<Real/>": '<Real unit="m"/>'})
    with pytest.raises(ConfigError, match=r"metres\.fmu: \[--fmu-output\] the FMU's output 'angle' is in 'm', which is "
                                          r"no angle unit"):
        open_fmu_block(metres, PERIOD_S)


def test_a_plant_too_slow_for_the_rigs_clock_is_named_when_the_run_fails(tmp_path, capsys, no_leaks):
    slow = build_python_fmu("slow_servo", tmp_path)
    config_path = _rig_config(tmp_path, slow)
    config = load_rig_config(config_path)
    assert config.simulation.fmu_seconds_per_sample > 0.2
    code = main(["run", config_path, "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(tmp_path / "run.csv"), "--duration", "0.5"])
    err = capsys.readouterr().err
    assert code == exit_codes.DEVICE_FAULT, err
    assert "likely cause: the simulated plant SlowServo.fmu (an FMU) took" in err
    assert "falls behind the rig's clock" in err
