"""The user's model as an FMU: the block's sampling against the exact discretisation of
the model inside the test FMU, stepping equal to a whole run, and the errors a user meets (a missing file,
several inputs or outputs, no binary for this platform, not an FMU)."""

from __future__ import annotations

import math
import pickle
import subprocess
import sys

import numpy as np
import pytest
from scipy import signal

from identify.black_box_effects import AROUND_BLACK_BOX, effects_around_black_box, is_black_box
from identify.effect_catalogue import EFFECT_NAMES, EFFECTS, SEARCHED_EFFECT_NAMES
from identify.plant_blocks import DeadZone, PlantModel
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError
from sim_backend.fmu_plant import FmuBlock, _unpacked, describe_fmu, open_fmu_block
from sim_backend.plant_config import load_simulated_plant

PERIOD_S = 0.01


def servo_zoh(command: np.ndarray, period_s: float) -> np.ndarray:
    """The model inside tests/fmu_models/gearbox_servo.py, angle'' = w^2 (u - angle) - 2 zeta w angle' with
    8 Hz and zeta 0.7, discretised exactly for a zero-order-hold input and run from rest: y_t = C x_t."""
    w = 2 * math.pi * 8.0
    a = np.array([[0.0, 1.0], [-w * w, -2 * 0.7 * w]])
    b = np.array([[0.0], [w * w]])
    ad, bd, *_ = signal.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), period_s, method="zoh")
    x, out = np.zeros(2), []
    for u in command:
        out.append(x[0])
        x = ad @ x + bd[:, 0] * u
    return np.array(out)


def test_the_block_samples_the_fmu_with_the_input_held_for_one_period(test_fmus):
    block = open_fmu_block(test_fmus["gearbox_servo"], PERIOD_S)
    assert (block.input_name, block.output_name, block.interface, block.fmi_version) == \
        ("command", "angle", "co_simulation", "2.0")
    rng = np.random.default_rng(3)
    command = np.repeat(rng.uniform(-1.0, 1.0, 40), 12)
    out = block.apply(command)
    # sample t is the output at t T, before the input u_t has acted: one sample later than the input, as the
    # zero-order-hold discretisation gives (its numerator has no b0); RK4 with 4 sub-steps per period is
    # within 1e-5 rad of the exact discretisation here
    assert out[0] == 0.0
    np.testing.assert_allclose(out, servo_zoh(command, PERIOD_S), atol=1e-5)
    assert np.max(np.abs(out)) > 0.5


@pytest.mark.parametrize("version", ["2.0", "3.0"])
@pytest.mark.parametrize("interface", ["CoSimulation", "ModelExchange"])
def test_fmi_2_and_3_co_simulation_and_model_exchange_sample_the_same_model(version, interface, c_servo_fmus):
    block = open_fmu_block(c_servo_fmus[(version, interface)], PERIOD_S)
    assert block.fmi_version == version
    assert block.interface == {"CoSimulation": "co_simulation", "ModelExchange": "model_exchange"}[interface]
    rng = np.random.default_rng(4)
    command = np.repeat(rng.uniform(-1.0, 1.0, 30), 10)
    out = block.apply(command)
    # the C servo integrates the same model by RK4 with 16 sub-steps (co-simulation) or is integrated by
    # CVode here (model exchange, relative tolerance 1e-8, through the events of its indicator angle - 0.5)
    np.testing.assert_allclose(out, servo_zoh(command, PERIOD_S), atol=1e-6)
    assert np.count_nonzero(np.diff(np.sign(out - 0.5))) >= 4  # the event indicator crossed zero
    stepper = block.stepper()
    np.testing.assert_array_equal([stepper.step(x) for x in command], out)
    stepper.close()


def test_whole_runs_reuse_instances_only_where_the_fmu_reset_restores_the_initial_state(c_servo_fmus):
    command = np.repeat([0.4, -0.7, 0.9], 60)
    for fmu in (("2.0", "CoSimulation"), "broken_reset"):
        block = open_fmu_block(c_servo_fmus[fmu], PERIOD_S)
        stepper = block.stepper()
        fresh = np.array([stepper.step(x) for x in command])
        stepper.close()
        for shift in (0.0, 0.1, 0.2):  # different inputs: no run comes from the cache of runs
            stepper = block.stepper()
            expected = np.array([stepper.step(x) for x in command + shift])
            stepper.close()
            np.testing.assert_array_equal(block.apply(command + shift), expected)
        np.testing.assert_array_equal(block.apply(command), fresh)
        # the first reuse was checked against a fresh instance: the broken reset was caught there
        assert _unpacked(block.path).reset_works["co_simulation"] is (fmu != "broken_reset")


def test_stepping_equals_a_whole_run_and_the_block_pickles(test_fmus):
    block = open_fmu_block(test_fmus["gearbox_servo"], PERIOD_S)
    command = np.sin(np.linspace(0.0, 12.0, 300))
    stepper = block.stepper()
    stepped = np.array([stepper.step(x) for x in command])
    stepper.close()
    np.testing.assert_array_equal(stepped, block.apply(command))
    again = pickle.loads(pickle.dumps(block))  # a worker process re-opens the file from the block's fields
    assert again == block
    np.testing.assert_array_equal(again.apply(command), stepped)
    # in a chain, like any block; the workflow sees a black box
    chained = PlantModel((DeadZone(-0.1, 0.1), block))
    np.testing.assert_array_equal(chained.simulate(command), block.apply(DeadZone(-0.1, 0.1).apply(command)))
    assert is_black_box(chained) and not is_black_box(PlantModel((DeadZone(-0.1, 0.1),)))


def test_the_simulated_plant_of_a_rig_config_can_be_an_fmu(test_fmus):
    encoder = EncoderResolution(bits=12, signed=True)
    config = load_simulated_plant(test_fmus["gearbox_servo"], sample_period_s=0.005, encoder=encoder)
    gearbox = config.gearbox(seed=1)
    assert gearbox.sample_period_s == 0.005 and gearbox.encoder == encoder
    command = np.repeat([0.0, 0.8, -0.4], 100)
    trajectory = gearbox.simulate(command)
    (block,) = config.plant.blocks
    np.testing.assert_array_equal(trajectory.load_angle_rad, block.apply(command))
    # the measurement is the FMU's output read by the rig's encoder, within half a count
    assert np.max(np.abs(trajectory.measured_angle_rad - trajectory.load_angle_rad)) <= encoder.quantization_bound_rad


def test_several_inputs_or_outputs_need_a_choice_that_names_them(test_fmus):
    path = test_fmus["two_port_gearbox"]
    description = describe_fmu(path)
    assert [v.name for v in description.inputs] == ["command", "load_torque_nm"]
    with pytest.raises(ConfigError) as error:
        open_fmu_block(path, PERIOD_S)
    message = str(error.value)
    assert str(path) in message and "2 real inputs" in message and "command, load_torque_nm" in message
    assert "--fmu-input NAME" in message
    with pytest.raises(ConfigError, match=r"2 real outputs \(angle, speed\).*--fmu-output NAME"):
        open_fmu_block(path, PERIOD_S, input_name="command")
    with pytest.raises(ConfigError, match=r"no real input 'torque'; its real inputs: command, load_torque_nm"):
        open_fmu_block(path, PERIOD_S, input_name="torque", output_name="angle")
    block = open_fmu_block(path, PERIOD_S, input_name="command", output_name="angle")
    steady = block.apply(np.ones(400))[-1]
    assert steady == pytest.approx(1.0, abs=1e-9)  # the lag settles on the command (no load torque)


def test_a_missing_file_or_a_file_that_is_no_fmu_is_named(tmp_path):
    with pytest.raises(ConfigError, match=r"missing\.fmu: \[file\] no such FMU file"):
        open_fmu_block(tmp_path / "missing.fmu", PERIOD_S)
    text = tmp_path / "plant.fmu"
    text.write_text("name = 'a plant TOML with the wrong suffix'\n")
    with pytest.raises(ConfigError, match=r"plant\.fmu: \[file\] not an FMU \(a zip archive holding modelDescription"):
        open_fmu_block(text, PERIOD_S)


def test_an_fmu_without_a_binary_for_this_platform_says_which_it_has(test_fmus):
    with pytest.raises(ConfigError) as error:
        open_fmu_block(test_fmus["windows_only"], PERIOD_S)
    message = str(error.value)
    assert "[binaries] the FMU has no binary for this platform (linux64" in message
    assert "it has binaries for: win64" in message and "Export it from your tool for this platform" in message


def test_only_effects_outside_the_dynamics_are_tried_around_a_black_box(monkeypatch):
    kept, skipped = effects_around_black_box()
    assert set(kept) | set(skipped) == set(SEARCHED_EFFECT_NAMES)
    assert all(EFFECTS[name].placement in AROUND_BLACK_BOX for name in kept)
    assert {"dead_zone", "saturation", "delay", "backlash", "offset", "gain_error"} <= set(kept)
    # an effect realised inside the dynamics (a placement the black box has no place for) is skipped, with why
    from dataclasses import replace

    inside = replace(EFFECTS["coulomb_friction"], name="load_friction", placement="drive_train")
    monkeypatch.setitem(EFFECTS, "load_friction", inside)
    kept, skipped = effects_around_black_box((*EFFECT_NAMES, "load_friction"))
    assert "load_friction" not in kept
    assert "inside the model's dynamics" in skipped["load_friction"] and "'drive_train'" in skipped["load_friction"]


def test_a_block_refuses_a_non_finite_command(test_fmus):
    block = open_fmu_block(test_fmus["gearbox_servo"], PERIOD_S)
    stepper = block.stepper()
    stepper.step(0.1)
    with pytest.raises(ValueError, match="sample 1 is nan"):
        stepper.step(float("nan"))
    stepper.close()
    with pytest.raises(ValueError, match="interface"):
        FmuBlock(path=block.path, sample_period_s=PERIOD_S, input_name="command", output_name="angle",
                 interface="scheduled_execution")


def test_fmpy_loads_only_when_an_fmu_is_used():
    # identify never sees fmpy; the FMU module and the commands import it only to read an FMU
    code = (
        "import sys, pkgutil, importlib, identify\n"
        "for info in pkgutil.walk_packages(identify.__path__, 'identify.'):\n"
        "    importlib.import_module(info.name)\n"
        "import sim_backend.fmu_plant, sim_backend.plant_config, rig.rig_config, rig.commands.diagnose\n"
        "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] in ('fmpy', 'pythonfmu'))))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == ""
