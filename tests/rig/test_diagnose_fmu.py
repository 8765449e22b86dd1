"""``rig diagnose DATA --model plant.fmu``: an effect hidden around the user's FMU is named
with an interval that holds the truth; a bad FMU is a clear error before any work."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identify.black_box_effects import AROUND_BLACK_BOX
from identify.effect_catalogue import EFFECTS
from identify.plant_blocks import DeadZone, OutputBacklash, PlantModel
from rig import exit_codes
from rig.cli import main
from rig.protocols.encoder_counts import EncoderResolution
from sim_backend.fmu_plant import open_fmu_block

PERIOD_S = 0.01
ENCODER = EncoderResolution(bits=12, signed=True)
NOISE_BOUND_RAD = ENCODER.quantization_bound_rad + 2e-5  # half a count, and a margin for the rounding


def alternating_steps() -> np.ndarray:
    """Steps between levels of alternating sign and various sizes (each held 0.7 s, smoothed over 8 samples),
    so that both sides of an input effect and both directions of a play are seen in both segments."""
    levels = [0.3, -0.5, 0.9, -0.2, 0.6, -0.8, 0.15, -0.4, 0.7, -0.65, 0.25, -0.9, 0.5, -0.3, 0.8, -0.15]
    steps = np.concatenate([np.zeros(20), *(np.full(70, level) for level in levels)])
    return np.convolve(steps, np.ones(8) / 8)[: steps.size]


def write_record(path, command: np.ndarray, angle: np.ndarray) -> None:
    time_s = np.arange(command.size) * PERIOD_S
    path.write_text("t,u,y\n" + "".join(f"{t!r},{u!r},{y!r}\n" for t, u, y in
                                         zip(time_s.tolist(), command.tolist(), angle.tolist())))


HIDDEN = {
    # an effect before the input of the pythonfmu FMU (FMI 2.0): the workflow re-simulates the FMU for every
    # trial of the dead zone's edges
    "dead_zone": (lambda fmu: PlantModel((DeadZone(left_rad=-0.06, right_rad=0.08), fmu)),
                  {"left_rad": -0.06, "right_rad": 0.08}),
    # an effect after the output of the C servo as FMI 3.0 co-simulation (the same model, about three times
    # faster per sample)
    "backlash": (lambda fmu: PlantModel((fmu, OutputBacklash(m_l=1.0, c_l_rad=0.03, m_r=1.0, c_r_rad=0.02))),
                 {"c_l_rad": 0.03, "c_r_rad": 0.02}),
}


def fmu_for(hidden: str, request) -> object:
    if hidden == "dead_zone":
        return request.getfixturevalue("test_fmus")["gearbox_servo"]
    return request.getfixturevalue("c_servo_fmus")[("3.0", "CoSimulation")]


@pytest.mark.parametrize("hidden", sorted(HIDDEN))
def test_an_effect_hidden_around_the_fmu_is_named_with_its_truth_in_the_interval(hidden, request, tmp_path, capsys):
    fmu_path = fmu_for(hidden, request)
    truth_model, truth = HIDDEN[hidden]
    command = alternating_steps()
    angle = ENCODER.rad_from_counts(ENCODER.counts_from_rad(truth_model(open_fmu_block(fmu_path, PERIOD_S))
                                                            .simulate(command)))
    data = tmp_path / "measured.csv"
    write_record(data, command, np.asarray(angle, dtype=float))
    code = main(["diagnose", str(data), "--model", str(fmu_path), "--noise-bound", repr(NOISE_BOUND_RAD), "--json"])
    assert code == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    # a play's map is also friction without stiction behind the loop: fitted, its mechanism left open
    assert document["verdict"] == ("ambiguous" if hidden == "backlash" else "named"), document["verdict_reason"]
    assert [entry["effect"] for entry in document["missing_effects"]] == [hidden]
    intervals = document["missing_effects"][0]["parameter_intervals"]
    for name, value in truth.items():
        low, high = intervals[name]
        assert low <= value <= high, (name, value, intervals[name])
        assert high - low < 0.01  # a few noise bounds wide, not a range that holds anything
    assert document["gap_final"] <= 0.05 * document["gap_initial"]
    note = document["fmu"]
    assert (note["file"], note["input"], note["output"]) == (str(fmu_path), "command", "angle")
    assert note["effects_tried"][hidden] == AROUND_BLACK_BOX[EFFECTS[hidden].placement]
    tried = {candidate["effect"] for candidate in document["candidates"]}
    assert tried == set(note["effects_tried"]) and not tried & set(note["effects_skipped"])


def test_the_text_output_names_the_fmu_and_where_effects_go(test_fmus, tmp_path, capsys):
    fmu_path = test_fmus["gearbox_servo"]
    command = alternating_steps()
    angle = ENCODER.rad_from_counts(ENCODER.counts_from_rad(open_fmu_block(fmu_path, PERIOD_S).apply(command)))
    data = tmp_path / "clean.csv"
    write_record(data, command, np.asarray(angle, dtype=float))
    code = main(["diagnose", str(data), "--model", str(fmu_path), "--noise-bound", repr(NOISE_BOUND_RAD)])
    assert code == exit_codes.SUCCESS
    out = capsys.readouterr().out
    assert f"start model   {fmu_path}" in out
    assert "fmu           input 'command', output 'angle'" in out
    assert "EXPLAINED" in out  # the FMU alone explains data simulated from it


@pytest.mark.parametrize(("fmu", "extra", "expected"), [
    ("missing", [], "missing.fmu: [file] no such FMU file"),
    ("two_port_gearbox", [], "2 real inputs (command, load_torque_nm): say which one is the commanded angle "
                             "with --fmu-input NAME"),
    ("two_port_gearbox", ["--fmu-input", "command"], "2 real outputs (angle, speed)"),
    ("windows_only", [], "no binary for this platform"),
    ("toml", ["--fmu-input", "command"], "--fmu-input chooses a variable of an FMU: give --model PLANT.fmu"),
])
def test_a_bad_fmu_is_refused_before_any_work_with_what_to_do(fmu, extra, expected, test_fmus, tmp_path, capsys):
    data = tmp_path / "data.csv"
    write_record(data, alternating_steps(), alternating_steps())
    model = {"missing": tmp_path / "missing.fmu", "toml": tmp_path / "plant.toml"}.get(fmu) or test_fmus.get(fmu)
    code = main(["diagnose", str(data), "--model", str(model), "--noise-bound", "0.001", *extra])
    assert code == exit_codes.BAD_INPUT
    assert expected in capsys.readouterr().err
