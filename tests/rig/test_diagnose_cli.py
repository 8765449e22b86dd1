"""``rig diagnose``: the documented JSON keys on a hidden-backlash record, the report, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from identify.discrepancy_cases import hidden_effect_record
from identify.model_discrepancy import diagnose_model
from rig import exit_codes
from rig.cli import main
from rig.plots.discrepancy import comparison_figure, signature_figure, windows_figure
from rig.report import missing_images
from plot_checks import unlabelled_axes
from nominal_model import NOMINAL_TOML


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("diagnose")
    record = hidden_effect_record(("backlash",), 3)
    time_s = np.arange(record.command_rad.size) * record.sample_period_s
    data = folder / "data.csv"
    data.write_text("t,u,y\n" + "".join(f"{t!r},{u!r},{y!r}\n" for t, u, y in
                                         zip(time_s.tolist(), record.command_rad.tolist(), record.angle_rad.tolist())))
    model = folder / "nominal.toml"
    model.write_text(NOMINAL_TOML)
    return folder, data, model, record


def test_json_fits_the_hidden_backlash_leaves_its_mechanism_open_and_writes_the_report(files, capsys):
    folder, data, model, record = files
    report = folder / "report"
    code = main(["diagnose", str(data), "--model", str(model), "--noise-bound", repr(record.noise_bound_rad),
                 "--json", "--report", str(report)])
    assert code == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    # the play's map is named and fitted; from command and angle alone it is also friction without stiction
    assert document["verdict"] == "ambiguous" and document["ambiguous_between"] == ["backlash", "coulomb_friction"]
    assert {"noise_bound", "candidates", "gap_reduction", "verdict_reason"} <= set(document)
    assert [entry["effect"] for entry in document["missing_effects"]] == ["backlash"]
    truth = record.true_model.blocks[1]
    parameters = document["missing_effects"][0]["parameters"]
    assert parameters["c_l_rad"] == pytest.approx(truth.c_l_rad, abs=1e-3)
    assert parameters["c_r_rad"] == pytest.approx(truth.c_r_rad, abs=1e-3)
    assert document["gap_final"] <= 0.05 * document["gap_initial"]
    index = report / "index.html"
    assert index.is_file() and missing_images(index) == []
    page = index.read_text()
    assert "backlash" in page and "signature_1_backlash.png" in page
    assert "Model discrepancy: AMBIGUOUS between backlash and coulomb_friction" in page and "Verdict AMBIGUOUS" in page
    low, high = document["missing_effects"][0]["parameter_intervals"]["c_l_rad"]
    assert f"c_l_rad = {parameters['c_l_rad']:.4g} [{low:.4g}, {high:.4g}]" in page  # each value with its interval


def test_the_report_page_is_headed_by_an_ambiguous_verdict_never_by_no_missing_effect(tmp_path, capsys):
    """An ambiguous diagnosis (an offset or an angle-dependent sensor error over a small motion) is said on
    the page as on stdout: its heading and first words carry the verdict and the candidates."""
    from identify.plant_blocks import LinearBlock

    nominal = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362), sample_period_s=0.001)
    small = 0.01 * np.sign(np.sin(np.arange(3000) / 37.0))  # +-0.01 rad from rest
    angle = nominal.apply(small) + 0.004 + np.random.default_rng(1).uniform(-2e-4, 2e-4, small.size)
    data = tmp_path / "small.csv"
    data.write_text("t,u,y\n" + "".join(f"{0.001 * k!r},{u!r},{y!r}\n" for k, (u, y) in
                                         enumerate(zip(small.tolist(), angle.tolist()))))
    model = tmp_path / "nominal.toml"
    model.write_text(NOMINAL_TOML)  # the same block
    report = tmp_path / "report"
    assert main(["diagnose", str(data), "--model", str(model), "--noise-bound", "0.001", "--json", "--report",
                 str(report)]) == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    between = document["ambiguous_between"]
    # over so small a motion an offset, a weight and a sensor error once per revolution are one constant
    assert document["verdict"] == "ambiguous" and "offset" in between and len(between) >= 2
    assert set(between) <= {"offset", "gravity", "encoder_error"}
    page = (report / "index.html").read_text()
    assert "No missing effect found" not in page
    assert f"Model discrepancy: AMBIGUOUS between {', '.join(between[:-1])} and {between[-1]}" in page
    assert "Verdict AMBIGUOUS" in page


def test_text_output_names_the_effect(files, capsys):
    _, data, model, record = files
    assert main(["diagnose", str(data), "--model", str(model), "--noise-bound", "0.001"]) == exit_codes.SUCCESS
    out = capsys.readouterr().out
    assert "step 1: backlash" in out and "final gap" in out
    assert "verdict       AMBIGUOUS" in out and "candidates 1" in out
    assert "mechanism     not told: backlash or coulomb_friction" in out and "cross-validation folds" in out
    # the named candidate's line gives both parts of its interval: which one named it can be read there
    (line,) = [line for line in out.splitlines() if line.startswith("candidates 1")]
    assert "(clear: reduction " in line and "(validation blocks " in line and "8 refits" in line


def test_figures_label_their_axes_with_units(files):
    _, _, _, record = files
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    time_s = np.arange(record.command_rad.size) * record.sample_period_s
    figures = [comparison_figure(result, record.angle_rad, time_s), windows_figure(result, time_s),
               signature_figure(result.steps[0], 1, result.initial.residual_rad, result.initial.simulated_rad,
                                record.command_rad, time_s, result.noise_bound_rad)]
    for figure in figures:
        assert unlabelled_axes(figure) == []
        assert figure.caption
    # the backlash's signature is the residual per direction of motion: one box per direction, not three
    # values overplotted on a continuous axis
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    drawn = Figure(figsize=figures[2].size_in)
    figures[2].draw(drawn)
    labels = [label.get_text() for label in drawn.axes[0].get_xticklabels()]
    assert [label.split(" (")[0] for label in labels] == ["moving down", "at rest", "moving up"]
    assert not drawn.axes[0].get_lines()[0].get_marker() == "."


@pytest.mark.parametrize(("effect", "caption"), [("delay", "samples early leaves"),
                                                 ("gain_error", "proportional to the model's output")])
def test_delay_and_gain_signature_figures_show_their_own_regressor(effect, caption):
    record = hidden_effect_record((effect,), 5)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    assert result.missing_effects[:1] == (effect,)
    time_s = np.arange(record.command_rad.size) * record.sample_period_s
    figure = signature_figure(result.steps[0], 1, result.initial.residual_rad, result.initial.simulated_rad,
                              record.command_rad, time_s, result.noise_bound_rad)
    assert unlabelled_axes(figure) == []
    assert caption in figure.caption


def test_bad_noise_bound_and_mismatched_period_exit_with_bad_input(files, tmp_path, capsys):
    _, data, model, _ = files
    assert main(["diagnose", str(data), "--noise-bound", "-1"]) == exit_codes.BAD_INPUT
    assert "noise_bound_rad" in capsys.readouterr().err
    other = tmp_path / "slow.toml"
    other.write_text(NOMINAL_TOML.replace("sample_period_s = 0.001", "sample_period_s = 0.01"))
    assert main(["diagnose", str(data), "--model", str(other), "--noise-bound", "0.001"]) == exit_codes.BAD_INPUT
    assert "sample_period_s" in capsys.readouterr().err


def test_several_files_are_diagnosed_in_parallel_and_a_bad_one_is_reported(files, tmp_path, capsys):
    folder, data, model, record = files
    broken = tmp_path / "broken.csv"
    broken.write_text("t,u,y\n0,1,x\n")
    report = tmp_path / "reports"
    code = main(["diagnose", str(data), str(broken), str(data), "--model", str(model), "--noise-bound",
                 repr(record.noise_bound_rad), "--jobs", "2", "--json", "--report", str(report)])
    assert code == exit_codes.BAD_INPUT  # one file failed; the others still came out
    printed = capsys.readouterr().out
    batch = json.loads(printed)
    assert (batch["kind"], batch["version"]) == ("batch", 1)
    results = batch["results"]
    assert [entry["file"] for entry in results] == [str(data), str(broken), str(data)]
    for entry in (results[0], results[2]):
        assert [effect["effect"] for effect in entry["diagnosis"]["missing_effects"]] == ["backlash"]
    assert results[0]["diagnosis"] == results[2]["diagnosis"]  # the same file gives the same answer in any process
    assert "broken.csv" in results[1]["error"] and "line 2" in results[1]["error"]
    assert missing_images(report / "data" / "index.html") == []

    # `rig report` reads the batch file the command wrote: both diagnoses, and the file that failed
    saved = tmp_path / "batch.json"
    saved.write_text(printed)
    assert main(["report", str(saved), "--out", str(tmp_path / "page")]) == exit_codes.SUCCESS
    page = Path(capsys.readouterr().out.strip()).read_text(encoding="utf-8")
    assert page.count("Model discrepancy: batch.json [") == 2
    assert "could not process" in page and "broken.csv" in page
