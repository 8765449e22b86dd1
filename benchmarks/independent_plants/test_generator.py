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


# gain_heating: the sensor's gain error alpha T follows its temperature rise T, heated by the
# copper loss s tau_out^2 through C T' = P - T/R (see the generator's docstring).

@pytest.mark.parametrize("servo", ["kinematic", "cascade"])
@pytest.mark.parametrize("excitation", list(g.EXCITATIONS))
def test_gain_heating_reaches_final_gain_error(servo, excitation):
    rec = g.generate("gain_heating", 21, excitation=excitation, duration_s=4.0, bits=16,
                     nominal={"servo": servo})
    tr = rec["truth"]
    p = tr["parameters"]
    gain = np.asarray(tr["gain_error_series"])
    th, y, clean = rec["state"][:, 2], rec["angle_rad"], rec["clean_angle_rad"]
    T = tr["duration_s"]
    assert 0.04 <= abs(p["final_gain_error"]) <= 0.15
    assert 0.5 * T <= p["thermal_time_constant_s"] <= 5.0 * T
    assert p["heated"] and p["loss_coefficient_w_per_nm2"] > 0
    # T(0) = 0: exact at the start; the drawn gain error exactly at the last sample
    assert gain.size == th.size and gain[0] == 0.0
    assert abs(gain[-1] - p["final_gain_error"]) < 1e-12
    assert p["achieved_final_gain_error"] == gain[-1]
    # T >= 0, so the gain error keeps the sign of alpha, which is that of the final error
    assert np.sign(p["temperature_coefficient_per_k"]) == np.sign(p["final_gain_error"])
    assert p["temperature_coefficient_sign"] == np.sign(p["final_gain_error"])
    assert np.all(gain * np.sign(p["final_gain_error"]) >= 0)
    assert abs(p["final_temperature_rise_k"] * p["temperature_coefficient_per_k"]
               - p["final_gain_error"]) < 1e-12
    # measurement only: the plant is the nominal twin, the sensor reads (1 + g) theta
    assert np.array_equal(rec["state"], rec["nominal_state"])
    assert np.allclose(clean, (1 + gain) * th, rtol=0, atol=1e-12)
    q = TWO_PI / 2**16
    assert np.max(np.abs(y - (1 + gain) * th)) <= q / 2 + 1e-12
    # effect size as for every measurement effect: deviation from the nominal twin
    dev = gain * th
    assert abs(tr["effect_size"]["max_abs_rad"] - np.max(np.abs(dev))) < 1e-12
    assert tr["excited"] == (np.max(np.abs(dev)) > q / 2)


@pytest.mark.parametrize("servo,N", [("kinematic", 1.0), ("cascade", 3.0)])
def test_gain_heating_integrates_the_thermal_model(servo, N):
    """Re-integrate C T' = s tau_out^2 - T/R with an independent integrator, the power held
    at the square of the cycle-mean gear-output torque N clean_torque_nm[k] over
    [t_k-1, t_k] (the docstring's zero-order hold), from T(0) = 0."""
    rec = g.generate("gain_heating", 5, excitation="chirp", duration_s=0.4,
                     nominal={"servo": servo, "gear_ratio": N})
    tr = rec["truth"]
    p, fs = tr["parameters"], tr["fs_hz"]
    R, C = p["thermal_resistance_k_per_w"], p["thermal_capacitance_j_per_k"]
    assert abs(R * C - p["thermal_time_constant_s"]) < 1e-12 * p["thermal_time_constant_s"]
    tau_out = N * rec["clean_torque_nm"]
    P = p["loss_coefficient_w_per_nm2"] * tau_out**2
    temp = [0.0]
    for kk in range(1, tau_out.size):
        sol = solve_ivp(lambda t, x: [(P[kk] - x[0] / R) / C], ((kk - 1) / fs, kk / fs),
                        [temp[-1]], method="DOP853", rtol=1e-12, atol=1e-14)
        temp.append(sol.y[0, -1])
    gain = np.asarray(tr["gain_error_series"])
    expected = p["temperature_coefficient_per_k"] * np.array(temp)
    assert np.max(np.abs(gain - expected)) < 1e-9 * abs(p["final_gain_error"])
    assert abs(p["final_temperature_rise_k"] - temp[-1]) < 1e-9 * temp[-1]


def test_gain_heating_follows_the_work_not_the_clock():
    """Unlike gain_drift (a fixed exponential in time, concave, never falling), the heated
    sensor cools while the drive rests and heats late when the drive works late."""
    # steps: after each move's transient (0.3 s) the drive holds with almost no torque, so
    # T cools as exp(-t / tau_th); the gain error shrinks there.
    for servo in ("kinematic", "cascade"):
        rec = g.generate("gain_heating", 3, excitation="steps", duration_s=10.0,
                         nominal={"servo": servo})
        p = rec["truth"]["parameters"]
        gain = np.abs(np.asarray(rec["truth"]["gain_error_series"]))
        holds = _holds(rec["command_rad"], 600)
        assert len(holds) >= 3
        for start, end in holds:
            a = start + 300
            cooled = gain[a] * math.exp(-(end - a) / 1000.0 / p["thermal_time_constant_s"])
            assert gain[end] < gain[a]
            assert abs(gain[end] / cooled - 1) < 5e-3  # pure cooling, bar the shaft's ripple
        # and it heats during the moves: net rise from one hold to the next
        ends = [end for _, end in holds]
        assert np.all(np.diff(gain[ends]) > 0)
    # chirp: the torque grows as f^2 and the loss as f^4, so little heat comes before mid-
    # record; gain_drift has |g(T/2)| >= |g_end| / 2 for every time constant.
    for seed in range(3):
        rec = g.generate("gain_heating", seed, excitation="chirp", duration_s=10.0)
        gain = np.asarray(rec["truth"]["gain_error_series"])
        assert abs(gain[gain.size // 2]) < 0.25 * abs(gain[-1])


@pytest.mark.parametrize("servo", ["kinematic", "cascade"])
def test_gain_heating_without_torque_is_not_excited(servo):
    # zero amplitude: the drive never works, the sensor never heats; no division by zero
    rec = g.generate("gain_heating", 4, excitation="chirp", duration_s=1.0, amplitude_rad=0.0,
                     nominal={"servo": servo})
    tr = rec["truth"]
    assert np.max(np.abs(rec["clean_torque_nm"])) < g.HEATING_TORQUE_FLOOR_NM
    assert not tr["parameters"]["heated"]
    assert tr["parameters"]["loss_coefficient_w_per_nm2"] == 0.0
    assert np.all(np.asarray(tr["gain_error_series"]) == 0.0)
    assert np.array_equal(rec["clean_angle_rad"], rec["state"][:, 2])
    assert tr["effect_size"]["max_abs_rad"] == 0.0 and not tr["excited"]
    json.dumps(tr)  # still a valid truth.json


def test_gain_heating_parameters_can_be_fixed():
    rec = g.generate("gain_heating", 1, excitation="prbs", duration_s=2.0,
                     final_gain_error=-0.1, thermal_time_constant_s=1.5)
    p = rec["truth"]["parameters"]
    assert p["thermal_time_constant_s"] == 1.5 and p["temperature_coefficient_sign"] == -1
    assert abs(rec["truth"]["gain_error_series"][-1] + 0.1) < 1e-12
    with pytest.raises(ValueError):
        g.generate("gain_heating", 1, duration_s=0.1, thermal_time_constant_s=0.0)


def test_gain_drift_records_unchanged_by_gain_heating():
    # sha256 as in _checksum, recorded with the generator before gain_heating was added
    # (commit c257f9d), numpy 2.4.6 / scipy 1.17.1 on this machine.
    a = g.generate("gain_drift", 1000, excitation="steps", duration_s=2.0, noise_rad=2e-4)
    assert _checksum(a) == "bf3abc0e3feb24fd153fac8f28f2e4b66dad208e128745677290ddc1f88125b6"
    b = g.generate("gain_drift", 1000, excitation="chirp", duration_s=2.0,
                   nominal={"servo": "cascade"})
    assert _checksum(b) == "8fc556a58087b3ef7aac9794801555b8a66289772719135a463bfdb6a8b793a8"


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
                    "--bits", "16", "--noise", "1e-4", "--param", "mgr_nm=0.5",
                    "--torque-noise", "0.01"], check=True)
    with open(out / "record.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time_s", "command_rad", "angle_rad", "encoder_counts", "torque_nm",
                       "torque_permille"]
    assert len(rows) == 2001
    truth = json.loads((out / "truth.json").read_text())
    nominal = json.loads((out / "nominal.json").read_text())
    assert truth["effect"] == "gravity" and truth["parameters"]["mgr_nm"] == 0.5
    assert nominal["shaft_stiffness_nm_per_rad"] == 150.0
    # kinematic servo: the motor inertia is kept, for the torque reading only
    assert nominal["motor_inertia_kg_m2"] == 0.002 and nominal["rated_torque_nm"] == 2.0
    assert truth["torque"]["noise_std_nm"] == 0.01 and truth["torque"]["rated_torque_nm"] == 2.0
    q = TWO_PI / 2**16
    for row in rows[1:50]:
        assert abs(float(row[2]) - int(row[3]) * q) < 1e-15
        assert float(row[4]) == int(row[5]) * 2.0 / 1000


# ------------------------------------------------------------------- drive torque
# The drive torque reading is the motor-side torque averaged over the control cycle
# [t_k-1, t_k] (see "Drive torque" in the generator's docstring).

@pytest.mark.parametrize("servo,N", [("kinematic", 1.0), ("cascade", 10.0)])
def test_drive_holds_the_weight_at_rest(servo, N):
    """At rest J_l theta'' = 0 = tau_s - m g r sin(theta_l - theta_0): the drive supplies
    tau_out = tau_s = m g r sin(theta_l - theta_0), i.e. that / N on the motor."""
    rec = g.generate("gravity", 6, excitation="steps", duration_s=8.0, bits=16, mgr_nm=0.8,
                     nominal={"servo": servo, "gear_ratio": N})
    p = rec["truth"]["parameters"]
    count = rec["nominal"]["rated_torque_nm"] / 1000
    th = rec["state"][:, 2]
    expected = p["mgr_nm"] * np.sin(th - p["hanging_angle_rad"]) / N
    holds = _holds(rec["command_rad"], 1000)  # >= 1 s: transients decay as exp(-10.3 t)
    assert holds
    at_rest = [0] + [end for _, end in holds]
    for k in at_rest:
        assert abs(rec["torque_permille"][k] - expected[k] / count) <= 1.0
        assert abs(rec["clean_torque_nm"][k] - expected[k]) < 1e-4  # vs 0.01..0.8 N m
    assert np.ptp(expected[at_rest]) > 0.1 * p["mgr_nm"] / N  # several different angles


@pytest.mark.parametrize("servo", ["kinematic", "cascade"])
def test_eccentricity_moves_the_angle_not_the_torque_gravity_moves_the_torque(servo):
    kw = dict(excitation="ramp", duration_s=4.0, amplitude_rad=2 * TWO_PI,
              nominal={"servo": servo})
    nom = g.generate("none", 1, **kw)
    ecc = g.generate("eccentricity", 1, **kw)
    grav = g.generate("gravity", 1, mgr_nm=0.5, **kw)
    assert ecc["truth"]["effect_size"]["max_abs_counts"] > 0.5  # the angle does change
    assert np.max(np.abs(ecc["clean_torque_nm"] - nom["clean_torque_nm"])) <= 1e-9
    assert np.array_equal(ecc["torque_permille"], nom["torque_permille"])
    # gravity: the drive supplies the weight on top of the nominal torque.  The remainder is
    # the change of the train's own inertial torque, led by J_t Delta theta'' with the extra
    # twist Delta theta ~ mgr sin(.)/k: J_t w^2 mgr / k with w <= 7 rad/s (2 turns out and
    # back in 4 s) -> 2e-3 mgr; 0.02 mgr allows ten times that for the ramp's corners.
    p = grav["truth"]["parameters"]
    th = grav["state"][:, 2]
    s = np.sin(th - p["hanging_angle_rad"])
    weight = p["mgr_nm"] * 0.5 * (s[1:] + s[:-1])  # cycle mean (trapezoid)
    dtau = (grav["clean_torque_nm"] - nom["clean_torque_nm"])[1:]
    assert np.max(np.abs(dtau - weight)) < 0.02 * p["mgr_nm"]
    assert 0.95 * p["mgr_nm"] < np.max(np.abs(dtau)) < 1.05 * p["mgr_nm"]


def _multisine_derivative_bound(rec, order):
    """Upper bound of |r^(order)| of the multisine reference (sum of the sines' sizes)."""
    info = rec["truth"]["excitation"]
    t = rec["time_s"]
    w = TWO_PI * np.array(info["frequencies_hz"])
    s = np.sin(w[None, :] * t[:, None] + np.array(info["phases_rad"])[None, :]).sum(axis=1)
    scale = info["amplitude_rad"] / np.max(np.abs(s))
    return scale * np.sum(w**order)


def _zoh_velocity_offset(nom, fs):
    """alpha: in a steady ramp of speed v under the held (staircase) command, the motor
    speed sampled at t_k is (1 + alpha) v, though its cycle mean is v.  Periodic state of
    the motor law alone (the docstring's), its shaft tied to a load moving smoothly at v."""
    from scipy.linalg import expm
    N, h = nom["gear_ratio"], 1.0 / fs
    Jm = N**2 * nom["motor_inertia_kg_m2"]
    k, c = nom["shaft_stiffness_nm_per_rad"], nom["shaft_damping_nm_s_per_rad"]
    wc, z = TWO_PI * nom["position_loop_bandwidth_hz"], nom["position_loop_damping_ratio"]
    Kv, Kp = 2 * z * wc * (Jm + nom["load_inertia_kg_m2"]), wc / (2 * z)
    M = np.zeros((5, 5))  # [phi, phi', theta_l, theta_l' (= v, constant), held u/N]
    M[0, 1] = M[2, 3] = 1.0
    if nom["servo"] == "kinematic":
        M[1, [0, 1, 4]] = -wc**2, -2 * z * wc, wc**2
    else:
        M[1, :] = [-(Kv * Kp + k) / Jm, -(Kv + c) / Jm, k / Jm, c / Jm, Kv * Kp / Jm]
    E = expm(M * h)
    v, x = 1.0, np.array([0.0, 1.0, 0.0, 1.0])
    for kk in range(400):  # the ripple settles within a few cycles
        x = E[:4, :4] @ x + E[:4, 4] * v * kk * h
    return x[1] / v - 1.0


@pytest.mark.parametrize("servo", ["kinematic", "cascade"])
@pytest.mark.parametrize("N", [1.0, 3.0])
def test_slow_motion_torque_is_rigid_body_torque(servo, N):
    """0.2..5 Hz multisine: tau_motor ~ [((1 + alpha) J_m' + J_l) theta^(2) + b theta^(1)] / N.

    Exactly, the cycle mean is [J_m' Delta phi' + J_l Delta theta' + b Delta theta] fs, with
    phi = theta + Delta.  The motor speed sampled at t_k carries the held command's ripple,
    alpha theta^(1) (_zoh_velocity_offset; alpha = -0.012 kinematic, -0.034 / -0.014 cascade
    N = 1 / 3), whence the apparent motor inertia (1 + alpha) J_m'.  Neglected: J_m' Delta^(2) with the quasi-static twist Delta = (J_l theta^(2) + b
    theta^(1)) / k, i.e. J_m' (J_l theta^(4) + b theta^(3)) / k; the cycle mean against the
    mid-cycle value, J_t h^2/24 theta^(4); the finite differences below, 5 h^2/24 J_t
    theta^(4).  theta^(4) and theta^(3) are bounded by the sum of the sines' sizes; the
    factor 2 covers the servo and shaft gains (<= 1.03 below 5 Hz) and the next order in
    (f / 30.8 Hz)^2.
    """
    rec = g.generate("none", 2, excitation="multisine", duration_s=4.0,
                     nominal={"servo": servo, "gear_ratio": N})
    nom = g.nominal_parameters(servo=servo, gear_ratio=N)
    Jm = N**2 * nom["motor_inertia_kg_m2"]
    Jl, k = nom["load_inertia_kg_m2"], nom["shaft_stiffness_nm_per_rad"]
    b, h = nom["viscous_friction_nm_s_per_rad"], 1.0 / rec["truth"]["fs_hz"]
    th = rec["state"][:, 2]  # true load angle (noise-free, unquantised)
    kk = np.arange(1500, th.size - 1)  # after 1.5 s: start-up transient down by exp(-15)
    d1 = (th[kk] - th[kk - 1]) / h  # theta' at t_k - h/2
    d2 = (th[kk + 1] - th[kk] - th[kk - 1] + th[kk - 2]) / (2 * h * h)  # theta'' there
    alpha = _zoh_velocity_offset(nom, 1.0 / h)
    assert -0.05 < alpha < 0  # a small correction, not a fitted factor
    rigid = (((1 + alpha) * Jm + Jl) * d2 + b * d1) / N
    tau = rec["clean_torque_nm"][kk]
    B4, B3 = _multisine_derivative_bound(rec, 4), _multisine_derivative_bound(rec, 3)
    tol = 2 * ((Jm * Jl / k + (Jm + Jl) * h * h / 4) * B4 + Jm * b / k * B3) / N
    assert tol < 0.05 * np.max(np.abs(rigid))  # a real check of the torque, not a free pass
    assert np.max(np.abs(tau - rigid)) < tol


@pytest.mark.parametrize("effect,servo,N", [("gravity", "cascade", 10.0),
                                            ("coulomb", "kinematic", 1.0),
                                            ("hysteresis", "cascade", 1.0)])
def test_reading_is_the_cycle_mean_of_the_instantaneous_torque(effect, servo, N):
    """Integrate the instantaneous drive torque (written here from the docstring's laws)
    over each cycle with an independent integrator; compare with the record."""
    rec = g.generate(effect, 3, excitation="multisine", duration_s=0.15,
                     nominal={"servo": servo, "gear_ratio": N})
    nom = g.nominal_parameters(servo=servo, gear_ratio=N)
    p = rec["truth"]["parameters"]
    X, u, fs = rec["state"], rec["command_rad"], rec["truth"]["fs_hz"]
    Jm = N**2 * nom["motor_inertia_kg_m2"]
    Jl, k, c = nom["load_inertia_kg_m2"], nom["shaft_stiffness_nm_per_rad"], \
        nom["shaft_damping_nm_s_per_rad"]
    wc, z = TWO_PI * nom["position_loop_bandwidth_hz"], nom["position_loop_damping_ratio"]
    Kv, Kp = 2 * z * wc * (Jm + Jl), wc / (2 * z)
    rhs = g.make_rhs(nom, effect, p)

    def tau_motor(x, uk):
        if servo == "cascade":
            return Kv * (Kp * (uk / N - x[0] / N) - x[1] / N) / N
        d, dd = x[0] / N - x[2], x[1] / N - x[3]
        tau_s = k * d + c * dd + (p["torque_nm"] * x[4] if effect == "hysteresis" else 0.0)
        return (Jm * (wc**2 * (uk - x[0]) - 2 * z * wc * x[1]) / N + tau_s) / N

    for kk in range(1, u.size):
        uk = u[kk - 1]  # the command held over [t_k-1, t_k)
        sol = solve_ivp(lambda t, y: list(rhs(t, y[:-1], uk)) + [tau_motor(y, uk)],
                        ((kk - 1) / fs, kk / fs), list(X[kk - 1]) + [0.0], method="DOP853",
                        rtol=1e-12, atol=1e-14)
        # 1e-6 N m: ~100x the effect of the record's rtol 1e-10 on J fs Delta omega
        assert abs(sol.y[-1, -1] * fs - rec["clean_torque_nm"][kk]) < 1e-6
    # sample 0: at rest under u_0, the instantaneous torque
    assert abs(tau_motor(X[0], u[0]) - rec["clean_torque_nm"][0]) < 1e-9


def test_torque_quantisation_noise_and_clipping():
    a = g.generate("none", 5, excitation="multisine", duration_s=5.0)
    count = a["nominal"]["rated_torque_nm"] / 1000
    assert a["torque_permille"].dtype.kind == "i"
    assert np.array_equal(a["torque_nm"], a["torque_permille"] * a["nominal"]["rated_torque_nm"]
                          / 1000)
    assert np.max(np.abs(a["torque_nm"] - a["clean_torque_nm"])) <= count / 2 + 1e-12
    # noise: a new random stream, so the angle is untouched
    sigma = 0.01  # 5 counts
    b = g.generate("none", 5, excitation="multisine", duration_s=5.0, torque_noise_nm=sigma)
    assert np.array_equal(a["encoder_counts"], b["encoder_counts"])
    assert np.array_equal(a["clean_torque_nm"], b["clean_torque_nm"])
    resid = b["torque_nm"] - b["clean_torque_nm"]
    n = resid.size
    expected = math.sqrt(sigma**2 + count**2 / 12)  # noise + rounding (sigma >> count)
    # 5 standard errors: sd of a sample std ~ s / sqrt(2 (n - 1)), of a mean s / sqrt(n)
    assert abs(resid.std() - expected) < 5 * expected / math.sqrt(2 * (n - 1))
    assert abs(resid.mean()) < 5 * expected / math.sqrt(n)
    assert abs(np.corrcoef(resid[1:], resid[:-1])[0, 1]) < 5 / math.sqrt(n)
    # INTEGER16: a tiny rated torque overflows, and the reading saturates
    c = g.generate("none", 5, excitation="multisine", duration_s=1.0,
                   nominal={"rated_torque_nm": 1e-5})
    raw = c["clean_torque_nm"] / 1e-8
    assert np.all(c["torque_permille"] >= -32768) and np.all(c["torque_permille"] <= 32767)
    assert np.all(c["torque_permille"][raw > 32767.5] == 32767)
    assert np.all(c["torque_permille"][raw < -32768.5] == -32768)
    assert c["truth"]["torque"]["clipped_samples"] == int(np.sum(np.abs(raw) > 32767.5))
    assert c["truth"]["torque"]["clipped_samples"] > 0


def _checksum(rec):
    import hashlib
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(rec["encoder_counts"], dtype="<i8").tobytes())
    h.update(np.ascontiguousarray(rec["angle_rad"], dtype="<f8").tobytes())
    return h.hexdigest()


def test_angles_are_those_of_the_generator_before_the_torque_channel():
    # sha256 of encoder_counts (<i8) then angle_rad (<f8), recorded with the generator as it
    # was before the torque channel was added (commit d502ca4), with numpy/scipy 1.17.1 on
    # this machine; a different BLAS or libm may change the last bits of the states.
    a = g.generate("eccentricity", 12, excitation="chirp", duration_s=1.0, noise_rad=5e-4,
                   torque_noise_nm=0.01)
    assert _checksum(a) == "0cd7447c198719907f390ee3d19e32f7989c61e959c29a7a05ec0dfd4b12a1c7"
    b = g.generate("gravity", 3, excitation="steps", duration_s=1.0, noise_rad=2e-4,
                   nominal={"servo": "cascade"}, torque_noise_nm=0.01)
    assert _checksum(b) == "7040d29100a8c469a8049f242c74496cdfc39457d26af5191617d6bcad44a991"
