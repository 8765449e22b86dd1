"""``rig simulate`` and ``rig inspect`` end to end, and the experiment configs behind them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from identify.cyclic_excitation import cyclic_random_excitation
from rig.cli import main
from rig.experiment_config import load_experiment_config
from rig.log_file import read_log
from rig.protocols.errors import ConfigError
from sim_backend.plant_config import load_plant_config

ROOT = Path(__file__).resolve().parents[2]
PLANTS = ROOT / "configs" / "plants"
EXPERIMENTS = ROOT / "configs" / "experiments"


def test_simulate_writes_a_log_that_matches_the_simulated_gearbox(tmp_path, capsys):
    out = tmp_path / "switch.csv"
    code = main(["simulate", str(PLANTS / "pouliquen2013_switch.toml"), "--excitation",
                 str(EXPERIMENTS / "hammerstein_cyclic.toml"), "--out", str(out), "--seed", "9", "--json"])
    assert code == 0
    assert json.loads(capsys.readouterr().out) == {"log": str(out), "samples": 4100}
    record = read_log(out)
    excitation = cyclic_random_excitation(4100, -3.0, 3.0, 50, np.random.default_rng(9))
    np.testing.assert_array_equal(record.command_rad, excitation)
    expected = load_plant_config(PLANTS / "pouliquen2013_switch.toml").gearbox(seed=10).simulate(excitation)
    np.testing.assert_array_equal(record.angle_rad, expected.measured_angle_rad)
    np.testing.assert_array_equal(record.encoder_counts, expected.encoder_counts)
    meta = record.metadata
    assert (meta.source, meta.transport, meta.encoder_bits, meta.excitation_seed, meta.seed) == (
        "pouliquen2013_switch", "offline", 16, 9, 10)
    assert meta.noise_kind == "coloured" and meta.noise_bound_rad == np.inf
    assert meta.config["noise"]["std_rad"] > 0  # the SNR was turned into a level and recorded
    # the log carries the whole plant description: it rebuilds the same truth
    from sim_backend.plant_config import plant_config_from_toml_text

    assert plant_config_from_toml_text(meta.config["plant_toml"]).blocks == load_plant_config(
        PLANTS / "pouliquen2013_switch.toml").blocks


def test_inspect_reports_samples_lost_and_period_as_json(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", str(PLANTS / "pouliquen2013_backlash.toml"), "--excitation",
                 str(EXPERIMENTS / "hammerstein_cyclic.toml"), "--out", str(out)]) == 0
    assert "samples     4100" in capsys.readouterr().out
    assert main(["inspect", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 4100 and info["lost"] == 0 and info["sample_period_s"] == 0.001
    assert info["encoder_bits"] == 16 and info["excitation_seed"] == 2013 and info["seed"] == 4302
    assert main(["inspect", str(out)]) == 0
    assert "lost" in capsys.readouterr().out


def test_inspect_names_what_is_wrong_with_a_damaged_file(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("# rig-log v1\n# metadata {\"sample_period_s\": 0.001}\n# units\ntime_s,command_rad,angle_rad,encoder_counts,flags\n"
                   "0.0,0.0,0.0,0,0\n0.001,0.0,oops,1,0\n")
    assert main(["inspect", str(bad)]) == 2
    assert "line 6, column angle_rad: 'oops' is not a number" in capsys.readouterr().err
    foreign = tmp_path / "foreign.csv"
    foreign.write_text("t,u,y\n0,0,0\n0.5,1,0.2\n1.0,1,0.25\n")
    assert main(["inspect", str(foreign), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 3 and info["sample_period_s"] == 0.5 and info["transport"] == "csv"


def test_simulate_reports_config_errors_with_exit_code_2(tmp_path, capsys):
    exc = tmp_path / "exc.toml"
    exc.write_text('seed = 1\n[excitation]\nkind = "cyclic_random"\nnum_samples = 10\nu_min = 1.0\nu_max = -1.0\n')
    code = main(["simulate", str(PLANTS / "cerone2009.toml"), "--excitation", str(exc), "--out", str(tmp_path / "x.csv")])
    assert code == 2
    assert f"{exc}: [excitation.u_min]" in capsys.readouterr().err


def test_experiment_config_seed_override_and_unknown_keys(tmp_path):
    a = load_experiment_config(EXPERIMENTS / "hammerstein_cyclic.toml")
    b = load_experiment_config(EXPERIMENTS / "hammerstein_cyclic.toml", seed=2013)
    c = load_experiment_config(EXPERIMENTS / "hammerstein_cyclic.toml", seed=1)
    assert np.array_equal(a.command_rad, b.command_rad) and not np.array_equal(a.command_rad, c.command_rad)
    assert a.command_rad.size == 4100 and np.all(a.command_rad[:51] == -3.0)
    bad = tmp_path / "bad.toml"
    bad.write_text('[excitation]\nkind = "cyclic_random"\nnum_samples = 10\nu_min = -1.0\nu_max = 1.0\numax = 2\n')
    with pytest.raises(ConfigError, match=r"\[excitation.umax\] unknown key"):
        load_experiment_config(bad)
    bad.write_text('[excitation]\nkind = "chirp"\n')
    with pytest.raises(ConfigError, match=r"\[excitation.kind\] expected one of prbs, filtered_staircase, cyclic_random"):
        load_experiment_config(bad)
    unseeded = tmp_path / "unseeded.toml"
    unseeded.write_text('[excitation]\nkind = "cyclic_random"\nnum_samples = 10\nu_min = -1.0\nu_max = 1.0\n')
    drawn = load_experiment_config(unseeded)
    assert np.array_equal(load_experiment_config(unseeded, seed=drawn.seed).command_rad, drawn.command_rad)


def test_logged_noise_bound_covers_noise_and_encoder_rounding(tmp_path):
    out = tmp_path / "precision.csv"
    assert main(["simulate", str(PLANTS / "precision_gearbox.toml"), "--excitation",
                 str(EXPERIMENTS / "hammerstein_cyclic.toml"), "--out", str(out), "--json"]) == 0
    record = read_log(out)
    gearbox = load_plant_config(PLANTS / "precision_gearbox.toml").gearbox()
    assert record.metadata.noise_bound_rad == pytest.approx(2e-4 + np.pi / 4096)
    assert record.metadata.noise_bound_rad == pytest.approx(gearbox.measurement_error_bound_rad)
    assert record.metadata.config["additive_noise_bound_rad"] == 2e-4


def test_inspect_warns_about_a_torn_last_line(tmp_path, capsys):
    out = tmp_path / "torn.csv"
    assert main(["simulate", str(PLANTS / "cerone2009.toml"), "--excitation",
                 str(EXPERIMENTS / "hammerstein_cyclic.toml"), "--out", str(out), "--json"]) == 0
    capsys.readouterr()
    out.write_text(out.read_text()[:-3])
    assert main(["inspect", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    info = json.loads(captured.out)
    assert info["samples"] == 4099 and "last line is incomplete" in info["warnings"][0]
    assert "rig: warning:" in captured.err


def test_steady_staircase_through_the_cerone_plant_gives_the_steady_state_points_of_eqs_11_12(tmp_path):
    from identify.excitation_design import staircase_steady_state_indices

    out = tmp_path / "staircase.csv"
    assert main(["simulate", str(PLANTS / "cerone2009.toml"), "--excitation",
                 str(EXPERIMENTS / "steady_staircase.toml"), "--out", str(out), "--json"]) == 0
    record = read_log(out)
    parameters = record.metadata.config["excitation"]["parameters"]
    amplitudes = np.array(parameters["amplitudes_rad"])
    np.testing.assert_allclose(amplitudes, np.linspace(0.6, 3.0, 50))
    steady = staircase_steady_state_indices(50, parameters["samples_per_half_wave"])
    u, y = record.command_rad[steady], record.angle_rad[steady]
    np.testing.assert_allclose(u[0::2], amplitudes, atol=1e-8)
    np.testing.assert_allclose(u[1::2], -amplitudes, atol=1e-8)
    bound = record.metadata.noise_bound_rad
    assert bound == pytest.approx(2 * np.pi / 4096, rel=1e-6)
    # eq. (11) on the positive half-waves, eq. (12) on the negative ones, within |eta| <= Delta eta
    assert np.max(np.abs(y[0::2] - 0.252 * (u[0::2] - 0.0349))) <= bound
    assert np.max(np.abs(y[1::2] - 0.248 * (u[1::2] + 0.0698))) <= bound


def test_prbs_experiment_is_the_plus_minus_one_sequence_of_section_6():
    excitation = load_experiment_config(EXPERIMENTS / "prbs.toml")
    assert excitation.command_rad.size == 100
    assert set(excitation.command_rad.tolist()) == {-1.0, 1.0}
    assert excitation.kind == "prbs" and excitation.seed == 100
