"""Physics checks of the clean-room generator (nothing here refers to the tool under test)."""
import csv
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.integrate import solve_ivp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import drive_train_generator as g  # noqa: E402

TWO_PI = 2 * math.pi


def _holds(u, min_len):
    """(start, end) index pairs of runs of equal command at least min_len samples long."""
    out, k = [], 0
    while k < u.size:
        j = k
        while j + 1 < u.size and u[j + 1] == u[k]:
            j += 1
        if j - k + 1 >= min_len:
            out.append((k, j))
        k = j + 1
    return out


# --------------------------------------------------------------------- steady state
@pytest.mark.parametrize("gear_ratio", [1.0, 10.0])
@pytest.mark.parametrize("servo", ["kinematic", "cascade"])
def test_clean_plant_follows_command_at_steady_state(gear_ratio, servo):
    rec = g.generate("none", 7, excitation="steps", duration_s=12.0, bits=16,
                     nominal={"gear_ratio": gear_ratio, "servo": servo})
    u, X, y = rec["command_rad"], rec["state"], rec["angle_rad"]
    q = TWO_PI / 2**16
    holds = _holds(u, 1000)  # at least 1 s: shaft transient decays as exp(-10.3 t)
    assert len(holds) >= 2
    for _, end in holds:
        assert abs(X[end, 2] - u[end] / gear_ratio) < 1e-6
        assert abs(X[end, 0] - u[end]) < 1e-6
        assert abs(y[end] - u[end] / gear_ratio) <= q / 2 + 1e-6


def test_quantisation_is_round_to_nearest_and_counts_match_angle():
    rec = g.generate("none", 3, excitation="multisine", duration_s=2.0, bits=12)
    q = TWO_PI / 4096
    assert np.allclose(rec["angle_rad"], rec["encoder_counts"] * q, atol=0, rtol=0)
    assert np.max(np.abs(rec["angle_rad"] - rec["state"][:, 2])) <= q / 2 + 1e-12


def test_noise_is_white_with_requested_std():
    a = g.generate("none", 5, excitation="multisine", duration_s=5.0, bits=24, noise_rad=1e-3)
    resid = a["angle_rad"] - a["state"][:, 2]
    assert abs(resid.std() - 1e-3) < 0.05e-3
    r1 = np.corrcoef(resid[1:], resid[:-1])[0, 1]
    assert abs(r1) < 0.05


# ----------------------------------------------------------------- exact sampling
def _reference_solution(nom, u, fs, x0, rtol=1e-12, atol=1e-14):
    A, B = g.linear_matrices(nom)
    x = np.array(x0, float)
    X = [x]
    for k in range(u.size - 1):
        sol = solve_ivp(lambda t, s: A @ s + B * u[k], (k / fs, (k + 1) / fs), x,
                        method="DOP853", rtol=rtol, atol=atol)
        x = sol.y[:, -1]
        X.append(x)
    return np.array(X)


@pytest.mark.parametrize("servo", ["kinematic", "cascade"])
def test_exact_sampling_matches_finer_integration(servo):
    nom = g.nominal_parameters(servo=servo)
    fs = 1000.0
    r, _ = g.make_reference("chirp", 11, 1500, fs)
    u = r * nom["gear_ratio"]
    x0 = g.initial_state(nom, "none", {}, float(u[0]))
    X = g.simulate_linear(nom, u, fs, x0)
    X10 = g.simulate_linear(nom, u, fs, x0, substeps=10)
    assert np.max(np.abs(X[:, [0, 2]] - X10[:, [0, 2]])) < 1e-11
    Xref = _reference_solution(nom, u, fs, x0)
    assert np.max(np.abs(X[:, [0, 2]] - Xref[:, [0, 2]])) < 1e-9
    # the solve_ivp path used for the dynamic effects, on the nominal right-hand side
    Xode = g.simulate_nonlinear(g.make_rhs(nom, "none", {}), u, fs, x0)
    assert np.max(np.abs(X[:, [0, 2]] - Xode[:, [0, 2]])) < 1e-9


@pytest.mark.parametrize("effect,zero", [("cogging", {"torque_nm": 0.0}),
                                         ("gravity", {"mgr_nm": 0.0}),
                                         ("coulomb", {"coulomb_nm": 0.0}),
                                         ("backlash", {"half_width_rad": 0.0}),
                                         ("hysteresis", {"torque_nm": 0.0})])
def test_dynamic_effect_with_zero_size_equals_exact_nominal(effect, zero):
    rec = g.generate(effect, 2, excitation="chirp", duration_s=1.5, bits=16, **zero)
    assert np.max(np.abs(rec["state"][:, 2] - rec["nominal_state"][:, 2])) < 1e-9


# ----------------------------------------------------------------- energy and signs
@pytest.mark.parametrize("effect", ["stribeck", "coulomb"])
@pytest.mark.parametrize("seed", range(5))
def test_friction_opposes_motion(effect, seed):
    p = g.draw_effect_parameters(effect, seed, 10.0, {})
    v = np.concatenate([-np.geomspace(10, 1e-6, 200), [0.0], np.geomspace(1e-6, 10, 200)])
    tau = g.friction_torque(effect, p, v)
    assert np.all(tau * v <= 0)
    big = np.abs(v) > max(50 * p["smoothing_velocity_rad_per_s"],
                          5 * p.get("stribeck_velocity_rad_per_s", 0.0))
    assert np.allclose(np.abs(tau[big]) / p["coulomb_nm"], 1.0, atol=0.02 * (
        p.get("static_nm", p["coulomb_nm"]) / p["coulomb_nm"]))


def _free_decay(effect, params, fs=1000.0, n=800):
    nom = g.nominal_parameters()
    x0 = np.array([0.0, 0.0, 0.02, 0.0] + ([0.0] if effect == "hysteresis" else []))
    u = np.zeros(n)
    X = g.simulate_nonlinear(g.make_rhs(nom, effect, params), u, fs, x0)
    k, J = nom["shaft_stiffness_nm_per_rad"], nom["load_inertia_kg_m2"]
    E = 0.5 * J * X[:, 3] ** 2 + 0.5 * k * (X[:, 0] - X[:, 2]) ** 2
    return X, E


@pytest.mark.parametrize("effect", ["none", "coulomb", "stribeck"])
def test_energy_never_increases_in_free_decay(effect):
    p = g.draw_effect_parameters(effect, 4, 1.0, {})
    X, E = _free_decay(effect, p)
    assert np.all(np.diff(E) <= 1e-12 * E[0])
    assert abs(X[-1, 3]) < 2e-3  # the load has (nearly) come to rest
    if effect != "none":
        # dry friction stops the swing in finite time: the kinetic energy left after the
        # first few periods is far below that of the viscously damped nominal swing
        X0, _ = _free_decay("none", {})
        assert np.max(np.abs(X[400:, 3])) < 0.5 * np.max(np.abs(X0[400:, 3]))


def _cruise_masks(rec):
    """Samples of the two constant-speed legs of the ramp, 2 s after each acceleration."""
    t = rec["time_s"]
    T = rec["truth"]["duration_s"]
    leg = T / 2
    ta = 0.1 * leg
    fwd = (t > ta + 2.0) & (t < leg - ta)
    back = (t > leg + ta + 2.0) & (t < T - ta)
    return fwd, back


def test_friction_twists_shaft_forward_when_driving_forward():
    rec = g.generate("coulomb", 1, excitation="ramp", duration_s=10.0, bits=16, coulomb_nm=0.2)
    X = rec["state"]
    twist = X[:, 0] - X[:, 2]
    nom = g.nominal_parameters()
    k, b = nom["shaft_stiffness_nm_per_rad"], nom["viscous_friction_nm_s_per_rad"]
    vc = rec["truth"]["excitation"]["cruise_speed_rad_per_s"]
    fwd, back = _cruise_masks(rec)
    assert fwd.sum() > 1000 and back.sum() > 1000
    assert np.allclose(X[fwd, 3], vc, rtol=1e-4)  # held command: sampled ripple
    assert np.allclose(twist[fwd], (0.2 + b * vc) / k, atol=3e-6)  # ZOH ripple
    assert np.allclose(twist[back], -(0.2 + b * vc) / k, atol=3e-6)


def test_hysteresis_dissipates_and_stays_bounded():
    rec = g.generate("hysteresis", 9, excitation="multisine", duration_s=5.0)
    p = rec["truth"]["parameters"]
    X = rec["state"]
    w, d = X[:, 4], X[:, 0] - X[:, 2]
    assert np.max(np.abs(w)) <= 1.0 + 1e-6
    work = np.sum(p["torque_nm"] * 0.5 * (w[1:] + w[:-1]) * np.diff(d))
    assert work > 0
    # free decay from a twisted shaft: the hysteretic element takes energy out
    Xf, E = _free_decay("hysteresis", p)
    Wh = np.cumsum(p["torque_nm"] * 0.5 * (Xf[1:, 4] + Xf[:-1, 4]) * np.diff(Xf[:, 0] - Xf[:, 2]))
    assert Wh[-1] > 0


# ------------------------------------------------------------------ static balance
@pytest.mark.parametrize("effect", ["gravity", "cogging"])
def test_static_equilibrium_of_position_torques(effect):
    rec = g.generate(effect, 6, excitation="steps", duration_s=12.0, bits=16)
    p = rec["truth"]["parameters"]
    nom = g.nominal_parameters()
    k = nom["shaft_stiffness_nm_per_rad"]
    u, X = rec["command_rad"], rec["state"]
    f = g._load_torque_fn(effect, p)
    holds = _holds(u, 1000)
    assert holds
    for _, end in holds:
        th = X[end, 2]
        assert abs(k * (u[end] - th) + f(th, 0.0)) < 1e-4  # N m, vs 0.03..1 N m effects
        assert abs(X[end, 3]) < 1e-4


def test_backlash_lag_is_half_width_plus_viscous_twist():
    bh = 3e-3
    rec = g.generate("backlash", 1, excitation="ramp", duration_s=10.0, bits=16, half_width_rad=bh)
    X = rec["state"]
    nom = g.nominal_parameters()
    k, b = nom["shaft_stiffness_nm_per_rad"], nom["viscous_friction_nm_s_per_rad"]
    vc = rec["truth"]["excitation"]["cruise_speed_rad_per_s"]
    lag = X[:, 0] - X[:, 2]
    fwd, back = _cruise_masks(rec)
    assert np.allclose(lag[fwd], bh + b * vc / k, atol=3e-6)
    assert np.allclose(lag[back], -(bh + b * vc / k), atol=3e-6)


# ---------------------------------------------------------------- measurement effects
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_eccentricity_amplitude_at_once_and_twice_per_rev(seed):
    rec = g.generate("eccentricity", seed, excitation="ramp", duration_s=10.0, bits=16)
    p = rec["truth"]["parameters"]
    th = rec["state"][:, 2]
    err = rec["angle_rad"] - th
    M = np.column_stack([np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th), np.ones_like(th)])
    c, *_ = np.linalg.lstsq(M, err, rcond=None)
    a1, a2 = math.hypot(c[0], c[1]), math.hypot(c[2], c[3])
    assert abs(a1 - p["a1_rad"]) < 5e-6
    assert abs(a2 - p["a2_rad"]) < 5e-6
    assert abs(math.atan2(c[1], c[0]) - p["phase1_rad"]) % TWO_PI < 1e-2 or \
        abs(abs(math.atan2(c[1], c[0]) - p["phase1_rad"]) - TWO_PI) < 1e-2
    assert abs(c[4]) < 5e-6


def test_wrap_makes_two_pi_jumps_only_inside_window():
    rec = g.generate("wrap", 4, excitation="ramp", duration_s=10.0, bits=12)
    p, t = rec["truth"]["parameters"], rec["time_s"]
    y, clean = rec["angle_rad"], rec["clean_angle_rad"]
    q = TWO_PI / 4096
    inside = (t >= p["wrap_start_s"]) & (t < p["wrap_end_s"])
    assert np.all(y[inside] > -math.pi) and np.all(y[inside] <= math.pi + 1e-12)
    assert np.all(np.abs(y[~inside] - clean[~inside]) <= q / 2 + 1e-12)
    # inside, the reading equals the true angle modulo one turn
    d = y[inside] - clean[inside]
    assert np.all(np.abs(d - TWO_PI * np.round(d / TWO_PI)) <= q / 2 + 1e-12)
    steps = np.diff(y)
    jumps = np.abs(steps) > math.pi
    assert jumps.sum() >= 2
    # every jump is a whole number of turns; strictly inside the window exactly one turn
    assert np.all(np.abs(steps[jumps] / TWO_PI - np.round(steps[jumps] / TWO_PI)) < 0.02)
    strictly = jumps & inside[1:] & inside[:-1]
    assert strictly.sum() >= 1
    assert np.all(np.abs(np.abs(steps[strictly]) - TWO_PI) < 0.1)
    # one jump per crossing of an odd multiple of pi by the true angle inside the window
    # (plus the entry/exit of the window, where the turn count appears or disappears)
    idx = np.flatnonzero(inside)
    turns = np.floor((clean[idx] + math.pi) / TWO_PI)
    crossings = int(np.sum(turns[1:] != turns[:-1]))
    assert crossings >= 1
    inner = jumps[idx[0]:idx[-1]].sum()
    assert inner == crossings
    assert rec["truth"]["effect_size"]["wrap_jumps"] == jumps.sum()


def test_gain_drift_reaches_final_gain_error():
    rec = g.generate("gain_drift", 8, excitation="ramp", duration_s=10.0, bits=16)
    p = rec["truth"]["parameters"]
    th, y = rec["state"][:, 2], rec["angle_rad"]
    assert 0.06 <= abs(p["final_gain_error"]) <= 0.15
    # at the start the sensor is exact, at the end scaled by 1 + g_end
    q = TWO_PI / 2**16
    assert abs(y[0] - th[0]) <= q
    T = rec["truth"]["duration_s"]
    t = rec["time_s"][-1]
    tau = p["time_constant_s"]
    g_end = p["final_gain_error"] * (1 - math.exp(-t / tau)) / (1 - math.exp(-T / tau))
    assert abs(y[-1] - (1 + g_end) * th[-1]) <= q


# ------------------------------------------------------------- seeds, ranges, files
@pytest.mark.parametrize("effect", sorted(g.EFFECTS))
def test_parameters_within_documented_ranges(effect):
    spec = g.EFFECTS[effect]
    for seed in range(30):
        p = g.draw_effect_parameters(effect, seed, 10.0, {})
        for name, (lo, hi, how) in spec.ranges.items():
            if name in p:
                v = abs(p[name]) if how == "signed" else p[name]
                assert lo <= v <= hi, (name, v)


def test_same_seed_same_record_and_nominal_twin_shares_command_and_noise():
    a = g.generate("eccentricity", 12, excitation="chirp", duration_s=1.0, noise_rad=5e-4)
    b = g.generate("eccentricity", 12, excitation="chirp", duration_s=1.0, noise_rad=5e-4)
    c = g.generate("none", 12, excitation="chirp", duration_s=1.0, noise_rad=5e-4)
    assert np.array_equal(a["angle_rad"], b["angle_rad"])
    assert np.array_equal(a["command_rad"], c["command_rad"])
    assert json.dumps(a["truth"]) == json.dumps(b["truth"])


def test_overrides_are_checked():
    with pytest.raises(ValueError):
        g.generate("cogging", 1, duration_s=0.1, no_such_parameter=1.0)
    r = g.generate("cogging", 1, duration_s=0.1, torque_nm=0.1, periods_per_rev=12)
    assert r["truth"]["parameters"]["torque_nm"] == 0.1
    assert r["truth"]["parameters"]["periods_per_rev"] == 12


def test_cli_writes_record_truth_and_nominal(tmp_path):
    out = tmp_path / "rec"
    here = os.path.dirname(os.path.abspath(__file__))
    subprocess.run([sys.executable, os.path.join(here, "drive_train_generator.py"), "gravity", "3",
                    "--out", str(out), "--excitation", "steps", "--duration", "2",
                    "--bits", "16", "--noise", "1e-4", "--param", "mgr_nm=0.5"], check=True)
    with open(out / "record.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time_s", "command_rad", "angle_rad", "encoder_counts"]
    assert len(rows) == 2001
    truth = json.loads((out / "truth.json").read_text())
    nominal = json.loads((out / "nominal.json").read_text())
    assert truth["effect"] == "gravity" and truth["parameters"]["mgr_nm"] == 0.5
    assert nominal["shaft_stiffness_nm_per_rad"] == 150.0
    q = TWO_PI / 2**16
    for row in rows[1:50]:
        assert abs(float(row[2]) - int(row[3]) * q) < 1e-15
