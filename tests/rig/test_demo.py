"""`rig demo` end to end on the simulated rig over CANopen (the quick plan keeps it short)."""

import html
import json
import re

import numpy as np
import pytest

from identify.plant_blocks import Delay, LinearBlock, OutputBacklash, PlantModel, Resonance
from rig.cli import main
from rig.demo_outcome import true_gearbox
from rig.protocols.errors import TransportError
from rig.report import missing_images


def test_true_gearbox_collapses_delay_linear_and_resonance_into_one_transfer_function():
    period = 1e-3
    blocks = (Delay(1), LinearBlock((-0.9,), (0.0, 0.1), period), Resonance(50.0, 0.05, period),
              OutputBacklash(0.25, 0.01, 0.25, 0.01))
    truth = true_gearbox(PlantModel(blocks))
    u = np.random.default_rng(0).normal(size=300)
    linear_only = PlantModel(blocks[:3]).simulate(u)
    np.testing.assert_allclose(truth.linear.apply(u), linear_only, atol=1e-12)
    assert truth.theta(na=3, nk=2, nb=4).keys() == {"a1", "a2", "a3", "b2", "b3", "b4"}
    assert truth.play_rad == pytest.approx(0.005)


def _quick_demo(out):
    """(out, the --json result) of `rig demo --quick` writing its report to ``out``."""
    import contextlib
    import io

    printed = io.StringIO()
    # serial: the wire whose simulated device loses the fewest samples on a busy host (BENCHMARKS.md);
    # CANopen and raw CAN are covered by the transport contract tests.
    with contextlib.redirect_stdout(printed):
        assert main(["demo", "--quick", "--transport", "serial", "--out", str(out), "--json"]) == 0
    return out, json.loads(printed.getvalue())


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory, worker_id):
    """(report directory, the --json result) of one `rig demo --quick` per test run, shared by the tests of its
    outputs. Under pytest-xdist the first worker to need it runs it in the run's common temporary directory while
    the others wait on a lock, then read it (the tests only read the report directory)."""
    if worker_id == "master":
        return _quick_demo(tmp_path_factory.mktemp("demo") / "report")
    import fcntl

    shared = tmp_path_factory.getbasetemp().parent  # one per run, above each worker's own
    with open(shared / "quick_demo.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        saved = shared / "quick_demo.json"
        if not saved.exists():
            _, result = _quick_demo(shared / "quick_demo")
            saved.write_text(json.dumps(result), encoding="utf-8")
        return shared / "quick_demo", json.loads(saved.read_text(encoding="utf-8"))


def test_demo_writes_a_complete_report_and_bounds_contain_the_truth(quick_demo):
    out, result = quick_demo
    index = out / "index.html"
    assert result["report"] == str(index)
    assert missing_images(index) == []
    page = index.read_text()
    assert len(re.findall(r"<img ", page)) >= 6
    assert (out / "logs" / "prbs.csv").is_file() and (out / "logs" / "staircase.csv").is_file()
    # its logs are logs like any run's: the staircase log records its excitation, and --steady takes it
    from rig.commands.identify_output_backlash import staircase_steady_points
    from rig.log_file import read_log

    excitation = read_log(out / "logs" / "staircase.csv").metadata.config["excitation"]
    assert excitation["kind"] == "filtered_staircase"
    steady_u, _, described = staircase_steady_points(out / "logs" / "staircase.csv")
    assert steady_u.size == 2 * len(excitation["parameters"]["amplitudes_rad"]) and "half-wave" in described
    rows = {row[0]: row for row in result["rows"]}
    # The staircase uses the reference pole (no overshoot of x_t for the play to hold), so the structure of the
    # method holds on the steady-state points: every bound contains the true value and the exact set D_γ the
    # true point, on both sides (the table says what the polygon figure draws); coupled bounds lie in the paper's.
    for name in ("backlash m_l", "backlash c_l", "backlash m_r", "backlash c_r", "linear a1", "linear b3"):
        true = float(rows[name][1])
        for column in (2, 3):
            lower, upper = (float(x) for x in rows[name][column].strip("[]").split(","))
            assert lower - 1e-9 <= true <= upper + 1e-9, (name, column, rows[name])
    membership = rows["backlash: true (m, m·c) in the exact set D_γ"]
    assert membership[2] == membership[3] == "left inside, right inside"
    paper = [float(x) for x in rows["linear a1"][2].strip("[]").split(",")]
    coupled = [float(x) for x in rows["linear a1"][3].strip("[]").split(",")]
    assert paper[0] <= coupled[0] and coupled[1] <= paper[1]
    play_true = float(rows["Hammerstein play [rad]"][1])
    play_estimate = float(rows["Hammerstein play [rad]"][3].split()[0])
    assert play_estimate == pytest.approx(play_true, abs=0.0015)  # one count of the 12-bit encoder
    low, high = (float(x) for x in re.search(r"spread ([-0-9.e]+)\.\.([-0-9.e]+)\)",
                                             rows["Hammerstein play [rad]"][3]).groups())
    assert low - 0.01 * abs(low) <= play_estimate <= high + 0.01 * abs(high)  # printed to 3 digits
    # The diagnosis of the nominal model (gear ratio, no play) must name the backlash and shrink the gap; its
    # play comes with the cross-validated interval.
    assert rows["discrepancy: missing effect"][3].split(", ")[0] == "backlash"
    fitted, interval = rows["discrepancy: fitted play c_l + c_r [rad]"][3].split(" in ")
    assert float(fitted) == pytest.approx(play_true, abs=0.0015)
    low, high = (float(x) for x in interval.strip("[]").split(","))
    assert low <= float(fitted) <= high
    gap_before = float(rows["discrepancy: gap of the nominal model [rad]"][3])
    gap_after = float(rows["discrepancy: gap with backlash [rad]"][3])
    assert gap_after < 0.5 * gap_before
    assert all(row[2] == "-" for name, row in rows.items() if name.startswith(("discrepancy", "Hammerstein")))
    assert "Model discrepancy" in page
    headings = re.findall(r"<h2>(.*?)</h2>", page)
    assert not [heading for heading in headings if heading.lower().count("model discrepancy") > 1], headings


def test_the_commands_the_demo_states_give_its_numbers_from_its_saved_logs(quick_demo, monkeypatch, capsys):
    """What a user does to check the demo: run, in its report directory, the commands it states (the report's
    section and the --json "commands"), on its saved logs, and find the summary's numbers (to the digits the
    table prints)."""
    import shlex

    from identify.hammerstein_subspace import HammersteinModel
    from rig.report import format_interval

    out, result = quick_demo
    page = (out / "index.html").read_text(encoding="utf-8")
    assert len(result["commands"]) == 4 and all(html.escape(command) in page for command in result["commands"])
    monkeypatch.chdir(out)
    printed = {}
    for command in result["commands"]:
        words = shlex.split(command)
        assert words[0] == "rig"
        assert main([*words[1:], "--json"]) == 0, command
        key = words[2] if words[1] == "identify" else words[1]
        printed[f"{key} {words[-1]}" if key == "output-backlash" else key] = json.loads(capsys.readouterr().out)
    rows = {row[0]: row for row in result["rows"]}
    for column, method in ((2, "paper"), (3, "coupled")):
        bounds = printed[f"output-backlash {method}"]
        for group, names in (("backlash", ("m_l", "c_l", "m_r", "c_r")),
                             ("linear", ("a1", "a2", "a3", "a4", "b2", "b3", "b4", "b5"))):
            for name in names:
                interval = bounds[group][name]
                assert rows[f"{group} {name}"][column] == format_interval(interval["lower"], interval["upper"]), \
                    (method, name)
    model = HammersteinModel.from_dict(printed["hammerstein"])
    assert rows["Hammerstein play [rad]"][3] == model.play_at_nodes().describe()
    assert rows["Hammerstein slowest pole |p|"][3].startswith(f"{model.max_pole_magnitude:.4f} ")
    diagnosis = printed["diagnose"]
    (backlash,) = [effect for effect in diagnosis["missing_effects"] if effect["effect"] == "backlash"]
    named = ", ".join(effect["effect"] for effect in diagnosis["missing_effects"])
    assert rows["discrepancy: missing effect"][3].startswith(named)
    if diagnosis["verdict"] == "ambiguous":  # the table row says so, as the section's verdict does
        assert "ambiguous" in rows["discrepancy: missing effect"][3]
        assert all(effect in rows["discrepancy: missing effect"][3] for effect in diagnosis["ambiguous_between"])
    fitted = rows["discrepancy: fitted play c_l + c_r [rad]"][3]
    assert fitted.startswith(f"{backlash['parameters']['c_l_rad'] + backlash['parameters']['c_r_rad']:.4g} in ")
    assert rows["discrepancy: gap of the nominal model [rad]"][3] == f"{diagnosis['gap_initial']:.3g}"
    assert rows["discrepancy: gap with backlash [rad]"][3] == f"{diagnosis['gap_final']:.3g}"


def test_the_demo_page_shows_every_figure_in_chromium(quick_demo, tmp_path):
    """The page a newcomer opens first, in a browser: every figure loads and lies within the page."""
    from chromium_check import check_page, require_chromium

    require_chromium()
    out, _ = quick_demo
    # signals of three experiments and their timing; five set-membership figures; three Hammerstein figures;
    # the diagnosis's comparison, disagreement windows and one signature per effect added
    effects = len(re.findall(r"<tr><td>\d+</td>", (out / "index.html").read_text(encoding="utf-8")))
    check_page(out / "index.html", tmp_path, figures=4 + 5 + 3 + 2 + effects)


def lossy_record():
    from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag

    angle = np.arange(10.0)
    flags = np.zeros(10, dtype=np.uint8)
    flags[[4, 9]] = SampleFlag.LOST
    angle[[4, 9]] = np.nan
    return ExperimentRecord(np.arange(10) * 1e-3, np.zeros(10), angle, None, flags,
                            ExperimentMetadata(sample_period_s=1e-3, excitation="staircase"))


def test_lost_steady_state_samples_take_the_last_usable_one_within_the_tail():
    from rig.demo import last_valid_values

    record = lossy_record()
    np.testing.assert_array_equal(last_valid_values(record, np.array([3, 4, 9]), max_age=2), [3.0, 3.0, 8.0])
    with pytest.raises(TransportError, match=r"samples 4\.\.4 were all lost"):
        last_valid_values(record, np.array([4]), max_age=0)


def test_the_report_and_the_outcome_do_not_import_the_demo_runner():
    """The import cycle rig.demo <-> rig.demo_report is gone: neither the report nor the outcome imports
    rig.demo, at module level or inside a function (a lazy import is a cycle too)."""
    import ast
    import importlib.util

    for module in ("rig.demo_report", "rig.demo_outcome"):
        tree = ast.parse(open(importlib.util.find_spec(module).origin, encoding="utf-8").read())
        imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
        imported |= {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
        assert "rig.demo" not in imported, module
        assert "rig.demo_outcome" in imported or module == "rig.demo_outcome"


def test_the_staircase_pole_keeps_the_true_backlash_in_the_exact_set_where_the_search_s_pole_does_not():
    """Why the demo filters its staircase with the reference pole: offline, without noise (the load angle
    itself), a staircase with the pole the search accepts on the precision gearbox drives x_t through the
    torsion mode into an overshoot that the play holds, and D_γ then excludes the true backlash."""
    from types import SimpleNamespace

    from identify.excitation_design import filtered_staircase, staircase_steady_state_indices
    from identify.feasible_parameter_set import bound_backlash_parameters
    from rig.demo import CONFIG_DIR, staircase_filter_pole
    from rig.demo_outcome import QUICK_PLAN
    from rig.rig_config import load_rig_config
    from sim_backend.plant_config import load_plant_config

    config = load_rig_config(CONFIG_DIR / "sim_serial.toml")
    plant_config = load_plant_config(config.simulation.plant_path)
    truth = true_gearbox(plant_config.plant)
    noise_bound = plant_config.gearbox(seed=0).measurement_error_bound_rad
    amplitudes = list(QUICK_PLAN.staircase_amplitudes_rad)
    steady = staircase_steady_state_indices(len(amplitudes), QUICK_PLAN.samples_per_half_wave)
    # the search's pole is the fastest one the drive's rate limit allows (the search itself accepts a = 0)
    search = SimpleNamespace(filter_pole=0.0, reference_pole=QUICK_PLAN.reference_pole, threshold_rad=2 * noise_bound)
    chosen, _ = staircase_filter_pole(search, amplitudes, config.limits.rate_max_rad_per_s, config.sample_period_s)
    fastest = 1.0 - 0.99 * config.limits.rate_max_rad_per_s * config.sample_period_s / (2 * max(amplitudes))
    assert chosen == QUICK_PLAN.reference_pole > fastest
    inside = {}
    for pole in (fastest, chosen):
        staircase = filtered_staircase(amplitudes, pole, QUICK_PLAN.samples_per_half_wave)
        load = plant_config.plant.simulate(staircase)[steady]
        backlash_set = bound_backlash_parameters(staircase[steady], load, noise_bound,
                                                 filter_step_amplitude_rad=QUICK_PLAN.filter_step_amplitude_rad)
        gearbox = truth.backlash
        inside[pole] = backlash_set.contains(gearbox.m_l, gearbox.c_l_rad, gearbox.m_r, gearbox.c_r_rad)
    assert inside[chosen] == {"left": True, "right": True}
    assert not all(inside[fastest].values()), inside[fastest]


def test_an_experiment_whose_link_fails_on_a_busy_host_is_run_again_and_then_reported(monkeypatch):
    from rig.demo import SimulatedRigSession

    session = SimulatedRigSession("serial", None)
    attempts = []

    def stalled(name, command_rad, *, keep_log, **_excitation):
        attempts.append(name)
        if len(attempts) < 3:
            raise TransportError("serial:///dev/pts/0: no feedback for 0.1 s (watchdog 0.1 s)")
        return lossy_record()

    monkeypatch.setattr(session, "_run_once", stalled)
    assert len(session.run("prbs", np.zeros(10), max_lost=2)) == 10
    assert session.retries == {"prbs": 2} and len(attempts) == 3
    attempts.clear()
    monkeypatch.setattr(session, "_run_once", lambda *a, **k: (_ for _ in ()).throw(
        TransportError("serial:///dev/pts/0: no feedback for 0.1 s")))
    message = (r"cyclic: in each of 5 attempts the link failed \(serial.*no feedback"
               r".*close other programs and run again$")
    with pytest.raises(TransportError, match=message):
        session.run("cyclic", np.zeros(10))
