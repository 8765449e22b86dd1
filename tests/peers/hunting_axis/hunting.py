"""Clean-room generator: a rotary axis hunting under a digital PID position loop.

See README.md for the physics and every assumption.
"""
import math

import numpy as np
from scipy.signal import lfilter

T = 1e-3                      # sample period [s]
COUNT = 2.0 * math.pi / 4096  # 12-bit encoder resolution [rad]
NOISE_STD = 1e-4              # Gaussian measurement noise [rad]
REST_TRANSIENT_S = 0.2        # start of each rest stretch ignored for the truths


# ----------------------------------------------------------------------------
# parameters
# ----------------------------------------------------------------------------
def draw_parameters(rng):
    J = 2e-4 * rng.uniform(0.85, 1.15)
    # controller designed on the nominal inertia 2e-4 (the controller does not
    # know the true J); PD part from (s + w)^3 with w = 40 rad/s, integral gain
    # doubled (Ki = 2 J w^3) to speed up hunting; nominal loop: min zeta ~0.57
    Jn = 2e-4
    w = 40.0
    Kp = 3 * Jn * w ** 2
    Kd = 3 * Jn * w
    Ki = 2 * Jn * w ** 3
    tau_d = 2e-3               # first-order filter on the derivative term [s]
    Tc = rng.uniform(0.03, 0.05)            # Coulomb torque [N m]
    Ts = Tc * rng.uniform(1.8, 2.1)         # static (breakaway) torque [N m]
    b = 2e-4 * rng.uniform(0.5, 1.5)          # viscous [N m s/rad]
    return dict(J=J, Tc=Tc, Ts=Ts, b=b, Kp=Kp, Ki=Ki, Kd=Kd, tau_d=tau_d,
                u_max=0.5, J_nominal=Jn)


# ----------------------------------------------------------------------------
# command: raised-cosine moves separated by rests
# ----------------------------------------------------------------------------
def make_command(rng):
    """Moves (+ | - + | - + | - + | -) with a rest after the 1st, 3rd, 5th, 7th move.
    7 moves, 6 direction reversals, 4 rest stretches."""
    signs = [+1, -1, +1, -1, +1, -1, +1]
    rest_after = {0, 2, 4, 6}
    pieces = []
    pos = 0.0
    for i, s in enumerate(signs):
        amp = s * rng.uniform(0.5, 1.0)
        Tm = rng.uniform(0.30, 0.45)
        n = int(round(Tm / T))
        k = np.arange(1, n + 1)
        pieces.append(pos + amp * 0.5 * (1 - np.cos(np.pi * k / n)))
        pos += amp
        if i in rest_after:
            nr = int(round(rng.uniform(2.2, 2.5) / T))
            pieces.append(np.full(nr, pos))
    r = np.concatenate([[0.0], np.concatenate(pieces)])
    return r


def rest_stretches(r, min_len=200):
    """(start, stop) sample indices of maximal runs where the command is constant."""
    still = np.r_[False, np.diff(r) == 0.0]
    out, i, N = [], 0, len(r)
    while i < N:
        if still[i]:
            j = i
            while j < N and still[j]:
                j += 1
            if j - i >= min_len:
                out.append((i, j))
            i = j
        else:
            i += 1
    return out


# ----------------------------------------------------------------------------
# exact event-driven integration of the mechanics over one sample (torque held)
# ----------------------------------------------------------------------------
def _free(th, om, a_const, k, t):
    """Solve J om' = F - b om (k = b/J, a_const = F/J) exactly over time t."""
    if k == 0.0:
        return th + om * t + 0.5 * a_const * t * t, om + a_const * t
    w_inf = a_const / k
    e = -math.expm1(-k * t)          # 1 - exp(-k t)
    return th + w_inf * t + (om - w_inf) * e / k, om + (w_inf - om) * e


def step_mech(th, om, stuck, u, p, h=T):
    """Advance (angle, velocity, stuck flag) by h with constant motor torque u.

    Slip: J om' = u - Tc sign(om) - b om.  Stick: om = 0 while |u| <= Ts.
    Velocity zero crossings are located exactly (closed form); at a zero
    crossing the axis sticks if |u| <= Ts, otherwise it reverses."""
    J, Tc, Ts, b = p["J"], p["Tc"], p["Ts"], p["b"]
    k = b / J
    t_left = h
    for _ in range(6):
        if t_left <= 0.0:
            break
        if stuck or om == 0.0:
            if Ts > 0.0 and abs(u) <= Ts:
                return th, 0.0, True
            stuck = False
            s = 1.0 if u > 0 else (-1.0 if u < 0 else 0.0)
            if s == 0.0:
                return th, 0.0, False
            om = 0.0
        else:
            s = 1.0 if om > 0 else -1.0
        a_const = (u - Tc * s) / J
        # time at which om reaches zero (if it does within t_left)
        if k == 0.0:
            tz = -om / a_const if a_const * om < 0 else math.inf
        else:
            w_inf = a_const / k
            if w_inf * om < 0 or (w_inf == 0.0):
                ratio = w_inf / (w_inf - om)
                tz = -math.log(ratio) / k if ratio > 0 else math.inf
            else:
                tz = math.inf
        if om == 0.0:
            tz = math.inf          # just broke away, accelerating in direction s
        if tz >= t_left:
            th, om = _free(th, om, a_const, k, t_left)
            return th, om, False
        th, _ = _free(th, om, a_const, k, tz)
        om = 0.0
        t_left -= tz
        stuck = abs(u) <= Ts and Ts > 0.0
    return th, om, stuck


# ----------------------------------------------------------------------------
# closed loop simulation
# ----------------------------------------------------------------------------
def simulate(r, p, rng=None, ideal_sensor=False):
    """Return clean load angle at the sample instants, measured angle, torque."""
    N = len(r)
    alpha = math.exp(-T / p["tau_d"])
    th, om, stuck = 0.0, 0.0, True
    I = 0.0
    d = 0.0
    y_prev = 0.0
    theta = np.empty(N)
    y = np.empty(N)
    u_log = np.empty(N)
    noise = np.zeros(N) if (ideal_sensor or rng is None) else rng.normal(0.0, NOISE_STD, N)
    for n in range(N):
        theta[n] = th
        if ideal_sensor:
            ym = th
        else:
            ym = COUNT * round(th / COUNT) + noise[n]
        y[n] = ym
        e = r[n] - ym
        I += T * e
        d = alpha * d + (1 - alpha) * (ym - y_prev) / T
        y_prev = ym
        u = p["Kp"] * e + p["Ki"] * I - p["Kd"] * d
        u = min(max(u, -p["u_max"]), p["u_max"])
        u_log[n] = u
        th, om, stuck = step_mech(th, om, stuck, u, p)
    return theta, y, u_log


# ----------------------------------------------------------------------------
# nominal (friction-free) discrete closed loop, exact ZOH
# ----------------------------------------------------------------------------
def nominal_model(p):
    """Closed loop r -> theta, polynomials in q^-1. Plant 1/(J s^2) with ZOH:
    G = T^2/(2J) (q^-1 + q^-2) / (1 - q^-1)^2.  Controller:
    u = Kp e + Ki T/(1-q^-1) e - Kd (1-alpha)(1-q^-1)/(T (1-alpha q^-1)) y."""
    J = p["J_nominal_used"] if "J_nominal_used" in p else p["J"]
    Kp, Ki, Kd = p["Kp"], p["Ki"], p["Kd"]
    alpha = math.exp(-T / p["tau_d"])
    P = np.polynomial.polynomial
    Bg = np.array([0.0, 1.0, 1.0]) * T * T / (2 * J)
    Ag = np.array([1.0, -2.0, 1.0])
    one_m_q = np.array([1.0, -1.0])
    one_m_aq = np.array([1.0, -alpha])
    Dc = P.polymul(one_m_q, one_m_aq)
    Nr = P.polyadd(Kp * Dc, Ki * T * one_m_aq)
    Ny = P.polyadd(Nr, Kd * (1 - alpha) / T * P.polymul(one_m_q, one_m_q))
    A = P.polyadd(P.polymul(Ag, Dc), P.polymul(Bg, Ny))
    B = P.polymul(Bg, Nr)
    B = B / A[0]
    A = A / A[0]
    return list(map(float, A)), list(map(float, B))


# ----------------------------------------------------------------------------
# limit-cycle truths
# ----------------------------------------------------------------------------
def cycle_stats(x):
    """Half peak-to-peak and zero-crossing period of x minus its mean."""
    z = x - x.mean()
    amp = 0.5 * (z.max() - z.min())
    s = np.sign(z)
    # carry forward sign through exact zeros
    for i in range(1, len(s)):
        if s[i] == 0:
            s[i] = s[i - 1]
    up = np.where((s[:-1] < 0) & (s[1:] > 0))[0]
    # sub-sample crossing instants by linear interpolation
    tc = (up + (-z[up]) / (z[up + 1] - z[up])) * T
    period = float(np.mean(np.diff(tc))) if len(tc) >= 2 else float("nan")
    return float(amp), period, len(tc)


def generate(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    p = draw_parameters(rng)
    r = make_command(rng)
    theta, y, u = simulate(r, p, rng=rng)
    p_nom = dict(p, J_nominal_used=p["J_nominal"])
    a, b = nominal_model(p_nom)
    rests = rest_stretches(r)
    i0, i1 = max(rests, key=lambda s: s[1] - s[0])
    j0 = i0 + int(REST_TRANSIENT_S / T)
    amp, per, ncross = cycle_stats(theta[j0:i1])
    truth = dict(
        limit_cycle_period_s=per,
        limit_cycle_amplitude_rad=amp,
        limit_cycle_window=(int(j0), int(i1)),
        upward_zero_crossings=ncross,
        inertia_kgm2=p["J"],
        coulomb_torque_Nm=p["Tc"],
        static_torque_Nm=p["Ts"],
        viscous_Nms_per_rad=p["b"],
        Kp=p["Kp"], Ki=p["Ki"], Kd=p["Kd"],
        derivative_filter_tau_s=p["tau_d"],
        torque_limit_Nm=p["u_max"],
        controller_design_inertia_kgm2=p["J_nominal"],
        encoder_count_rad=COUNT,
        noise_std_rad=NOISE_STD,
        clean_angle_rad=theta,
        torque_Nm=u,
        rest_stretches=rests,
    )
    return {
        "command_rad": r,
        "angle_rad": y,
        "sample_period_s": T,
        "nominal_a": a,
        "nominal_b": b,
        "noise_bound_rad": 0.5 * COUNT + 4.5 * NOISE_STD,
        "truth": truth,
    }


# ----------------------------------------------------------------------------
def verify_nominal(seed=0):
    """Friction-free, ideal-sensor nonlinear sim (plant inertia = design inertia)
    vs the discrete linear model: must agree to 1e-6 rad."""
    rng = np.random.default_rng(seed)
    p = draw_parameters(rng)
    r = make_command(rng)
    p0 = dict(p, J=p["J_nominal"], Tc=0.0, Ts=0.0, b=0.0)
    theta, _, u = simulate(r, p0, ideal_sensor=True)
    assert np.max(np.abs(u)) < p0["u_max"], "saturation active in verification"
    a, b = nominal_model(p0)
    lin = lfilter(b, a, r)
    err = float(np.max(np.abs(lin - theta)))
    gain = sum(b) / sum(a)
    return err, gain, a, b


if __name__ == "__main__":
    err, gain, a, b = verify_nominal(0)
    print(f"nominal model check: max |linear - nonlinear(no friction)| = {err:.3e} rad;"
          f" static gain = {gain:.12f}")
    assert err < 1e-6 and abs(gain - 1) < 1e-9
    print("nominal_a =", a)
    print("nominal_b =", b)
    ok_all = True
    for seed in range(5):
        d = generate(seed)
        t = d["truth"]
        th = t["clean_angle_rad"]
        hunts = []
        for (i0, i1) in t["rest_stretches"]:
            j0 = i0 + int(REST_TRANSIENT_S / T)
            amp, per, nc = cycle_stats(th[j0:i1])
            hunts.append((amp, per, nc))
        ok = all(h[0] > 1e-3 and h[2] >= 2 for h in hunts) and t["upward_zero_crossings"] >= 4
        ok_all &= ok
        print(f"seed {seed}: period {t['limit_cycle_period_s']*1e3:7.2f} ms, "
              f"amplitude {t['limit_cycle_amplitude_rad']*1e3:6.2f} mrad, "
              f"cycles(longest rest) {t['upward_zero_crossings']-1}, "
              f"J {t['inertia_kgm2']:.3e}, Tc {t['coulomb_torque_Nm']:.4f}, "
              f"Ts {t['static_torque_Nm']:.4f}, b {t['viscous_Nms_per_rad']:.2e}, "
              f"N {len(d['command_rad'])}, hunts {'OK' if ok else 'NO'}")
        print("   per rest stretch (amp mrad, period ms, up-crossings):",
              [(round(h[0]*1e3, 2), round(h[1]*1e3, 1), h[2]) for h in hunts])
    assert ok_all, "some record does not hunt"
    print("all records hunt")
