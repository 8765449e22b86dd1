"""``rig report``: a page from an experiment log and the saved JSON of identify/diagnose; foreign files refused.

Also the documented Chromium check script, on the path that needs no browser (Chromium not installed)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identify.cyclic_excitation import cyclic_random_excitation
from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.experiment_record import ExperimentMetadata, ExperimentRecord
from identify.model_discrepancy import CandidateResult, DiscrepancyReport, MissingEffect
from identify.output_backlash_identification import bound_output_backlash_system
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel, pouliquen2013_backlash
from report_inputs import printed_to, write_csv
from rig import exit_codes
from rig.cli import main
from rig.commands.report import read_result_file, report_sections
from rig.log_file import write_log
from rig.report import missing_images

SM_PLANT = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 0.01), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
NOISE = 1e-3
DIAGNOSIS = DiscrepancyReport(
    verdict="named", verdict_reason="backlash closes the gap", noise_bound_rad=1e-3,
    missing_effects=(MissingEffect("backlash", {"width_rad": 0.02}, {}, 0.01, 0.002),), ambiguous_between=(),
    candidates=(), gap_initial_rad=0.01, gap_final_rad=0.002, gap_reduction={"value": 0.8},
    falsified_fraction_initial=0.4, falsified_fraction_final=0.01, excitation={}, operating_point_rad=0.0)
DIAGNOSE = DIAGNOSIS.to_dict()
REPO = Path(__file__).resolve().parents[2]




@pytest.fixture(scope="module")
def data(tmp_path_factory):
    folder = tmp_path_factory.mktemp("report_inputs")
    rng = np.random.default_rng(0)
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 6)), 0.8125, 100)
    steady = staircase_steady_state_indices(6, 100)
    write_csv(folder / "steady.csv", "u,y", staircase[steady],
         SM_PLANT.simulate(staircase)[steady] + rng.uniform(-NOISE, NOISE, steady.size))
    u = prbs_sequence(60, 1.0, rng=1)
    y = SM_PLANT.simulate(u) + rng.uniform(-NOISE, NOISE, u.size)
    write_log(folder / "prbs.log", ExperimentRecord(np.arange(u.size) * 0.01, u, y, None, None,
                                                    ExperimentMetadata(sample_period_s=0.01, excitation="prbs")))
    cyclic = cyclic_random_excitation(1200, -3.0, 3.0, hold_samples=50, rng=0)
    G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)
    write_csv(folder / "cyclic.csv", "u,y", cyclic, PlantModel((pouliquen2013_backlash(), G)).simulate(cyclic))
    (folder / "diagnose.json").write_text(json.dumps(DIAGNOSE))
    return folder


def test_report_from_a_log_and_the_json_of_identify_and_diagnose(data, capsys, tmp_path):
    common = ["identify", "output-backlash", "--steady", str(data / "steady.csv"), "--dynamic", str(data / "prbs.log"),
              "--noise-bound", repr(NOISE), "--na", "2", "--nk", "1", "--nb", "2", "--json"]
    paper = printed_to(capsys, [*common, "--method", "paper"], data / "paper.json")
    coupled = printed_to(capsys, common, data / "coupled.json")
    out = tmp_path / "report"
    code = main(["report", str(data / "prbs.log"), str(paper), str(coupled), str(data / "diagnose.json"),
                 "--out", str(out), "--json"])
    assert code == exit_codes.SUCCESS
    printed = json.loads(capsys.readouterr().out)
    index = Path(printed["report"])
    assert index == (out / "index.html").resolve() and index.is_file()
    # 2 experiment figures (signals, timing), intervals + Bode for both methods together, the backlash band,
    # polygons and inner-signal bounds once (both methods share them), 1 discrepancy figure.
    assert printed["figures"] == 7  # the prbs log has nothing of its timing: no timing figure
    assert missing_images(index) == []
    page = index.read_text(encoding="utf-8")
    assert page.count("<img ") == 7 and "set_membership_paper_polygons.png" in page
    for title in ("Experiment: prbs.log", "Set membership", "Model discrepancy: diagnose.json"):
        assert title in page
    # The interval table shows each method's bounds as printed by `rig identify output-backlash --json`.
    coupled_a1 = json.loads(coupled.read_text())["linear"]["a1"]
    assert f"{coupled_a1['lower']:.6g}" in page and f"{coupled_a1['upper']:.6g}" in page
    assert "paper lower" in page and "coupled upper" in page
    # The Bode axis is in Hz, taken from the log's sample period (10 ms: Nyquist 50 Hz).
    assert "Nyquist frequency 50 Hz" in page
    assert "went from 0.01 to 0.002 rad (80 % smaller)" in page


def test_the_json_of_identify_hammerstein_gives_its_three_figures(data, capsys):
    hammerstein = printed_to(capsys, ["identify", "hammerstein", str(data / "cyclic.csv"), "--json"],
                           data / "hammerstein.json")
    result = read_result_file(hammerstein)
    assert result.kind == "hammerstein_model"
    (section,) = report_sections([result], sample_period_s=0.01)
    assert [figure.name for figure in section.figures] == [
        "hammerstein_hammerstein_poles", "hammerstein_hammerstein_borders", "hammerstein_hammerstein_singular_values"]
    assert ("order", "2") in section.table_rows
    assert "natural frequencies 2.25 Hz" in section.figures[0].caption


def test_report_prints_the_index_path_and_shows_an_empty_set(data, capsys, tmp_path):
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 6)), 0.8125, 100)
    steady = staircase_steady_state_indices(6, 100)
    wrong = SM_PLANT.simulate(staircase)[steady] + 20 * NOISE * np.resize([1.0, -1.0, 0.0], steady.size)
    u = prbs_sequence(60, 1.0, rng=1)
    result = bound_output_backlash_system(staircase[steady], wrong, u, SM_PLANT.simulate(u), NOISE, na=2, nk=1, nb=2,
                                          method="paper")
    assert result.is_empty
    empty = data / "empty.json"
    empty.write_text(json.dumps(result.to_dict()))
    code = main(["report", str(empty), "--out", str(tmp_path / "r"), "--sample-period", "0.001"])
    assert code == exit_codes.SUCCESS
    index = Path(capsys.readouterr().out.strip())
    assert index == (tmp_path / "r" / "index.html").resolve()
    page = index.read_text(encoding="utf-8")
    assert "EMPTY feasible set" in page and result.explanation.split(":")[1].strip()[:30] in page
    assert missing_images(index) == []


def test_foreign_files_are_refused_with_the_file_and_what_was_expected(data, capsys, tmp_path):
    foreign = tmp_path / "foreign.csv"
    foreign.write_text("hello,world\n1,2\n")
    code = main(["report", str(data / "prbs.log"), str(foreign), "--out", str(tmp_path / "r")])
    assert code == exit_codes.BAD_INPUT
    error = capsys.readouterr().err
    assert f"{foreign}: not a result file" in error and "missing column(s) t, u, y" in error
    assert "rig identify output-backlash --json" in error
    assert not (tmp_path / "r" / "index.html").exists()

    other_json = tmp_path / "settings.json"
    other_json.write_text(json.dumps({"speed": 3, "name": "x"}))
    assert main(["report", str(other_json), "--out", str(tmp_path / "r")]) == exit_codes.BAD_INPUT
    error = capsys.readouterr().err
    assert f"{other_json}: JSON without a 'kind' key (keys [name, speed])" in error
    assert "output_backlash v1, hammerstein_model v1, model_discrepancy v1/2/3/4/5/6/7, run_summary v1/2/3/4, batch v1" in error

    binary = tmp_path / "figure.png"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe")
    assert main(["report", str(binary), "--out", str(tmp_path / "r")]) == exit_codes.BAD_INPUT
    assert f"{binary}: not a text file" in capsys.readouterr().err

    assert main(["report", str(tmp_path / "nowhere.json"), "--out", str(tmp_path / "r")]) == exit_codes.BAD_INPUT
    assert "nowhere.json: no such file" in capsys.readouterr().err


def test_chromium_check_script_says_how_to_install_chromium(tmp_path):
    (tmp_path / "index.html").write_text("<html><body></body></html>")
    completed = subprocess.run([sys.executable, str(REPO / "scripts" / "check_report_in_chromium"), str(tmp_path),
                                "--chromium", str(tmp_path / "no-such-chromium")],
                               capture_output=True, text=True, timeout=60, check=False)
    assert completed.returncode == 3
    assert "Chromium is not installed" in completed.stderr and "apt-get install chromium" in completed.stderr
    missing = subprocess.run([sys.executable, str(REPO / "scripts" / "check_report_in_chromium"),
                              str(tmp_path / "absent")], capture_output=True, text=True, timeout=60, check=False)
    assert missing.returncode == 2 and "no such file" in missing.stderr


def test_a_saved_output_backlash_result_reopens_and_draws_polygons_band_and_inner_bounds(data, capsys, tmp_path):
    saved = tmp_path / "coupled_saved.json"
    printed = printed_to(capsys, ["identify", "output-backlash", "--steady", str(data / "steady.csv"), "--dynamic",
                                str(data / "prbs.log"), "--noise-bound", repr(NOISE), "--na", "2", "--nk", "1",
                                "--nb", "2", "--json", "--save", str(saved)], tmp_path / "printed.json")
    document = json.loads(saved.read_text())
    assert document["format"] == "rig output-backlash result v1"
    assert {key: document[key] for key in json.loads(printed.read_text())} == json.loads(printed.read_text())
    assert len(document["data"]["dynamic"]["y"]) == document["samples"] == 60
    out = tmp_path / "report"
    assert main(["report", str(data / "prbs.log"), str(saved), "--out", str(out), "--json"]) == exit_codes.SUCCESS
    printed_report = json.loads(capsys.readouterr().out)
    # signals + timing, intervals + Bode, and from the saved data: backlash band, polygons, inner-signal bounds
    assert printed_report["figures"] == 6  # the prbs log: no (empty) timing figure
    index = Path(printed_report["report"])
    page = index.read_text(encoding="utf-8")
    assert missing_images(index) == [] and page.count("<img ") == 6
    for name in ("_backlash.png", "_polygons.png", "_inner.png"):
        assert f"set_membership_coupled_saved{name}" in page


def test_a_saved_result_with_damaged_data_names_the_file_and_the_key(data, capsys, tmp_path):
    document = json.loads(printed_to(capsys, ["identify", "output-backlash", "--steady", str(data / "steady.csv"),
                                            "--dynamic", str(data / "prbs.log"), "--noise-bound", repr(NOISE), "--na",
                                            "2", "--nk", "1", "--nb", "2", "--json", "--method", "paper"],
                                   tmp_path / "printed.json").read_text())
    del document["backlash_set"]["left"]
    damaged = tmp_path / "damaged.json"
    damaged.write_text(json.dumps(document))
    assert main(["report", str(damaged), "--out", str(tmp_path / "out")]) == exit_codes.BAD_INPUT
    assert f"{damaged}: kind 'backlash_feasible_set': key 'left' is missing" in capsys.readouterr().err


@pytest.mark.parametrize("document, words", [
    ({"kind": "hammerstein_model", "version": 9}, "kind 'hammerstein_model' version 9 cannot be read"),
    ({"kind": "gearbox_photo", "version": 1}, "kind 'gearbox_photo' version 1 cannot be read"),
    ({**DIAGNOSE, "version": 8}, "kind 'model_discrepancy' version 8 cannot be read"),
])
def test_a_kind_or_version_it_cannot_read_is_named(document, words, capsys, tmp_path):
    path = tmp_path / "result.json"
    path.write_text(json.dumps(document))
    assert main(["report", str(path), "--out", str(tmp_path / "out")]) == exit_codes.BAD_INPUT
    error = capsys.readouterr().err
    assert f"{path}: {words}" in error and "model_discrepancy v1" in error


@pytest.mark.parametrize("changes, words", [
    ({"verdict": "unexplained", "missing_effects": (), "gap_final_rad": 0.01, "falsified_fraction_final": 0.95},
     "UNEXPLAINED"),
    ({"verdict": "ambiguous", "verdict_reason": "delay and resonance fit equally well", "missing_effects": (),
      "ambiguous_between": ("delay", "resonance")}, "AMBIGUOUS"),
    ({"verdict": "explained", "missing_effects": (), "falsified_fraction_initial": 0.0,
      "falsified_fraction_final": 0.0}, "EXPLAINED"),
    ({"verdict": "ambiguous", "verdict_reason": "backlash named; then gravity cannot be told",
      "ambiguous_between": ("gravity",),
      "undecided": (CandidateResult(1, "gravity", 0.0017, 2e-4, 0.0018, {"gravity_per_inertia_rad_per_s2": 11.0},
                                    False, True, 0.1, (0.04, 0.22), "undecided"),)},
     "Undecided after backlash, not named (gap reduction within its uncertainty around the acceptance): "
     "gravity 10 %, 4 to 22 %"),
])
def test_the_report_states_the_verdict_of_the_diagnosis(changes, words, tmp_path):
    path = tmp_path / "diagnose.json"
    path.write_text(json.dumps(dataclasses.replace(DIAGNOSIS, **changes).to_dict()))
    (section,) = report_sections([read_result_file(path)])
    assert words in section.text
    if words == "UNEXPLAINED":
        assert "95.0 % after" in section.text


def test_the_report_shows_intervals_and_candidate_gaps_of_a_diagnosis(tmp_path):
    from identify.discrepancy_cases import hidden_effect_record
    from identify.model_discrepancy import diagnose_model

    record = hidden_effect_record(("backlash",), 11)
    document = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                              record.nominal_model).to_dict()
    path = tmp_path / "diagnose.json"
    path.write_text(json.dumps(document))
    (section,) = report_sections([read_result_file(path)])
    low, high = document["missing_effects"][0]["parameter_intervals"]["c_l_rad"]
    assert f"[{low:.4g}, {high:.4g}]" in section.table_rows[0][1]
    assert "AMBIGUOUS between backlash and coulomb_friction" in section.title  # the play's map, its mechanism open
    assert "Verdict AMBIGUOUS" in section.text
    assert "Candidates tried first" in section.text and "delay" in section.text


def test_an_offline_simulation_is_reported_as_one_without_a_timing_figure(tmp_path, capsys):
    """A `rig simulate` log had no wire and no clock: the page says so, and draws no timing figure (it was
    called device-clocked, with an empty figure and a lead "not in this log")."""
    log = tmp_path / "sim.csv"
    assert main(["simulate", str(REPO / "configs" / "plants" / "cerone2009.toml"), "--excitation",
                 str(REPO / "configs" / "experiments" / "prbs.toml"), "--out", str(log)]) == exit_codes.SUCCESS
    capsys.readouterr()
    assert main(["report", str(log), "--out", str(tmp_path / "page")]) == exit_codes.SUCCESS
    index = Path(capsys.readouterr().out.strip())
    page = index.read_text(encoding="utf-8")
    assert "an offline simulation (rig simulate): no wire and no clock" in page
    assert "device-clocked" not in page and page.count("<img ") == 1 and missing_images(index) == []


def test_a_fitted_effect_that_is_not_the_whole_story_is_headed_so():
    """An ambiguous verdict that keeps fitted effects without rivals (the open-world check found most of what
    they leave predictable) is not headed as if the effect were simply named."""
    from rig.plots.discrepancy import verdict_heading

    report = dataclasses.replace(DIAGNOSIS, verdict="ambiguous", ambiguous_between=(),
                                 verdict_reason="backlash lowers the gap; a black box predicts 77 % of what remains")
    assert verdict_heading(report) == "AMBIGUOUS: backlash fitted, not the whole story"
    assert verdict_heading(dataclasses.replace(report, verdict="named")) == "NAMED backlash"


def test_the_gap_figure_of_an_ambiguous_diagnosis_draws_the_candidates_it_left_open(tmp_path):
    """An offset the model lacks, over a small motion, is also a load that depends on the angle: neither is
    added, and the verdict says both fit. The figure drew only the start model's bar, and its caption read that
    bar as something unexplained; it now draws the two candidates beside it, hatched, with their gaps."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from identify.model_discrepancy import diagnose_model

    nominal = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362), sample_period_s=0.001)
    square = 0.01 * np.sign(np.sin(np.arange(3000) / 37.0))
    angle = nominal.apply(square) + 0.004 + np.random.default_rng(1).uniform(-2e-4, 2e-4, square.size)
    document = diagnose_model(square, angle, 0.001, 0.001, PlantModel((nominal,))).to_dict()
    assert document["verdict"] == "ambiguous" and document["missing_effects"] == []
    path = tmp_path / "diagnose.json"
    path.write_text(json.dumps(document))
    (section,) = report_sections([read_result_file(path)])
    (figure_spec,) = section.figures
    figure = Figure(figsize=figure_spec.size_in, layout="constrained")
    figure_spec.draw(figure)
    FigureCanvasAgg(figure).draw()
    (axes,) = figure.axes
    gaps = {candidate["effect"]: candidate["gap"] for candidate in document["candidates"] if candidate["round"] == 0}
    between = document["ambiguous_between"]
    labels = [label.get_text() for label in axes.get_xticklabels()]
    assert labels == ["start model"] + [f"{name}?\n(not added)" for name in between]
    heights = [bar.get_height() for bar in axes.patches]
    np.testing.assert_allclose(heights, [document["gap_initial"]] + [gaps[name] for name in between])
    assert all(gaps[name] < 0.1 * document["gap_initial"] for name in between)  # what the verdict says: both fit
    for name in between:
        assert f"{name} {gaps[name]:.4g} rad" in figure_spec.caption
    assert "Hatched: the candidates the diagnosis left open" in figure_spec.caption


def test_logs_of_different_periods_leave_the_frequency_axes_per_sample_and_say_so(tmp_path, capsys):
    """Which period a result came from is not in its file: logs of 1 ms and 10 ms must not lend the first one's
    period to a model fitted on 10-ms data (its poles were drawn at 22.5 Hz instead of 2.25 Hz)."""
    cyclic = cyclic_random_excitation(1200, -3.0, 3.0, hold_samples=50, rng=0)
    G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)
    data = write_csv(tmp_path / "cyclic.csv", "u,y", cyclic, PlantModel((pouliquen2013_backlash(), G)).simulate(cyclic))
    assert main(["identify", "hammerstein", str(data), "--json"]) == exit_codes.SUCCESS
    hammerstein = tmp_path / "hammerstein.json"
    hammerstein.write_text(capsys.readouterr().out)
    logs = []
    for period in (0.001, 0.01):
        u = prbs_sequence(60, 1.0, rng=1)
        logs.append(tmp_path / f"prbs_{period:g}.log")
        write_log(logs[-1], ExperimentRecord(np.arange(u.size) * period, u, 0.5 * u, None, None,
                                             ExperimentMetadata(sample_period_s=period, excitation="prbs")))
    files = [read_result_file(path) for path in (*logs, hammerstein)]
    (section,) = [s for s in report_sections(files) if s.title.startswith("Hammerstein")]
    assert "Frequencies are per sample: the logs were sampled every 1, 10 ms" in section.text
    assert "Hz" not in section.figures[0].caption
    # one period among the logs, or one given, is used as before
    (one,) = [s for s in report_sections(files[1:]) if s.title.startswith("Hammerstein")]
    assert "per sample" not in one.text and "Hz" in one.figures[0].caption


def test_a_log_with_nothing_of_its_timing_gets_no_empty_timing_figure(tmp_path):
    """A log on the nominal grid with no flag and no run summary drew an empty box as its timing figure."""
    u = prbs_sequence(60, 1.0, rng=1)
    log = tmp_path / "prbs.log"
    write_log(log, ExperimentRecord(np.arange(u.size) * 0.01, u, 0.5 * u, None, None,
                                    ExperimentMetadata(sample_period_s=0.01, excitation="prbs")))
    (section,) = report_sections([read_result_file(log)])
    assert [figure.name for figure in section.figures] == ["signals_prbs"]
    assert "No timing figure: the time column is the nominal grid" in section.text
