"""Clean-room record generator for a position-controlled drive train.

Written from physics alone, to produce records whose truth is known for testing a
model-discrepancy tool.  Nothing here was taken from the tool's code.

Plant (continuous time)
-----------------------
State ``x = [theta_m, omega_m, theta_l, omega_l (, z)]``; ``theta_m`` is the motor angle
(motor side, rad), ``theta_l`` the load angle (load side, rad), ``N`` the gear ratio
(motor rad per load rad), ``phi = theta_m / N`` the gear output angle.

Servo, ``servo="kinematic"`` (default): a stiff position loop whose motor angle is not
disturbed by the shaft torque (infinitely strong drive)::

    theta_m'' = wc^2 (u - theta_m) - 2 zeta wc theta_m'     wc = 2 pi * 60 Hz, zeta = 0.7

Servo, ``servo="cascade"`` (option): a motor of inertia ``J_m`` driven by a P-position /
P-velocity cascade designed on the rigid train, so the shaft torque does load the motor::

    J_m' = N^2 J_m,  J_t = J_m' + J_l,  K_v = 2 zeta wc J_t,  K_p = wc / (2 zeta)
    J_m' phi'' = K_v (K_p (u/N - phi) - phi') - tau_s

Shaft and load (both servos)::

    Delta = phi - theta_l,  Delta' = phi' - theta_l'
    tau_s = k Delta + c Delta'                                  (nominal shaft)
    J_l theta_l'' = tau_s - b theta_l' + tau_effect(theta_l, theta_l')

The command ``u`` is the commanded motor position, produced by a digital controller at
``fs`` and held constant between samples (zero-order hold).  Sample ``k`` of the record
is the encoder reading of ``theta_l(t_k)``; the command ``u_k`` acts on ``[t_k, t_k+1)``,
so the measured angle responds to the command one sample later (as on a real rig).

Exact sampling: the nominal plant and the measurement-only effects are linear in the
state, so they are discretised exactly with the matrix exponential of the augmented
matrix ``[[A, B], [0, 0]] / fs``.  Effects that change the dynamics are integrated with
``scipy.integrate.solve_ivp`` (LSODA, rtol 1e-10, atol 1e-12) interval by interval, one
call per run of equal commands, so the integrator never steps across a command jump.

Encoder: absolute, ``B`` bits per revolution, ``q = 2 pi / 2^B`` (12 bit: 1.534 mrad,
16 bit: 0.0959 mrad).  ``counts = round((theta_meas + noise) / q)`` (mid-tread, error in
+-q/2), multi-turn unless the wrap effect says otherwise, ``angle_rad = counts * q``.
Optional white Gaussian noise of standard deviation ``noise_rad`` is added before
quantisation.

Initial state: at rest, motor at ``u_0``; the load at the static equilibrium of the
train with the effect present (solved by Newton's method for gravity and cogging),
Bouc-Wen state 0, backlash twist 0 (centre of the play).

Drive torque (second measured channel)
--------------------------------------
What a servo drive reports as its "torque actual value" (CiA 402 object 0x6077): an
INTEGER16 in per mille of the motor's rated torque (object 0x6076, nominal
``rated_torque_nm``, default 2.0 N m).  It is the torque the drive supplies, so a load torque
(gravity) shows in it and a sensor error (eccentricity) does not.

Gear-output side torque of the drive, ``tau_out``, and its motor-side value (reported)::

    cascade:    tau_out = K_v (K_p (u/N - phi) - phi')  (= J_m' phi'' + tau_s)
    kinematic:  tau_out = J_m' phi'' + tau_s,   J_m' = N^2 J_m,
                phi'' = (wc^2 (u - theta_m) - 2 zeta wc theta_m') / N
    tau_motor = tau_out / N      (positive in the direction of positive theta_m)

``tau_s`` is the exact shaft torque of the effect (backlash dead band and clip, Bouc-Wen
term T_h w).  The kinematic motor has no dynamics of its own; ``motor_inertia_kg_m2``
(default 0.002 kg m^2, kept in ``nominal.json`` for both servos) is used there only for
this reading.

Sampling convention: sample k is the mean of ``tau_motor`` over the control cycle
``[t_k-1, t_k]`` that ends at the angle's instant t_k (the command held there is u_k-1),
as a drive whose current measurement is averaged over its cycle reports it.  By the
momentum balance of the train (the shaft torque is internal) this is exact from the
sampled states::

    tau_motor,k = [J_m' (phi'_k - phi'_k-1) + J_l (theta_l'_k - theta_l'_k-1)
                   + b (theta_l,k - theta_l,k-1) - int_{t_k-1}^{t_k} tau_effect dt] fs / N

with the load-torque effect's integral taken by Gauss-Legendre on the integrator's own
steps (dense output of the same solve_ivp call; the sampled states do not change).
Sample 0: the train has been at rest under u_0, and the value is the static torque.
Why not the instantaneous value at t_k: the held command makes the drive torque jump by
``wc^2 J (u_k - u_k-1) / N`` at every update (J = J_m' kinematic, J_m' + J_l cascade), a
sawtooth of +-0.85 v N m per rad/s of load speed v in the cascade; a sample at t_k would
be dominated by it.  The cycle mean keeps only a small trace of it: the motor speed sampled
at t_k is offset by alpha v (alpha = -0.012 kinematic, -0.034 cascade N = 1, at 1 kHz), so
the mean looks like an inertia (1 + alpha) J_m'.  The record also holds the instantaneous
value just before t_k (state x_k, command u_k-1) as ``clean_torque_instant_nm``.

Reading::

    torque_permille = clip(round((tau_motor + n_k) / (rated/1000)), -32768, 32767)
    torque_nm = torque_permille * rated / 1000

n_k white Gaussian, std ``torque_noise_nm`` (default 0), from its own random stream
(``[seed, 4]``), so the angle, its noise and the excitation are those of a record without it.
At rest with gravity: tau_motor = m g r sin(theta_l - theta_0) / N.

Nominal parameters (defaults; ``nominal.json`` records them)
------------------------------------------------------------
gear_ratio 1, load_inertia_kg_m2 0.004, shaft_stiffness_nm_per_rad 150,
shaft_damping_nm_s_per_rad 0.0775 (shaft damping ratio ~0.05), viscous_friction_nm_s_per_rad
0.005, position_loop_bandwidth_hz 60, position_loop_damping_ratio 0.7,
motor_inertia_kg_m2 0.002 (cascade; kinematic: torque reading only), rated_torque_nm 2.0.
Shaft resonance sqrt(k/J_l) = 193.6 rad/s = 30.8 Hz.  A load torque of 1 N m twists the
shaft by 1/k = 6.67 mrad = 4.3 counts at 12 bit.

Effects (``truth.json`` records the drawn values; ranges are uniform unless noted)
---------------------------------------------------------------------------------
none          nominal plant only.
eccentricity  measurement: y = theta + a1 sin(theta + p1) + a2 sin(2 theta + p2);
              a1 in [0.5, 3] mrad, a2 in [0.1, 1] mrad, phases in [-pi, pi).
wrap          measurement: inside [wrap_start_s, wrap_end_s) the encoder reports only its
              single-turn reading, wrapped to (-pi, pi] (counts in (-2^(B-1), 2^(B-1)]);
              start in [0.2, 0.5] T, end in [0.6, 1.0] T.  Needs motion through +-pi to show
              (``truth.effect_size.wrap_jumps``).
gain_drift    measurement: y = (1 + g(t)) theta, g(t) = g_end (1 - e^(-t/tau)) / (1 - e^(-T/tau))
              (thermal first-order drift from 0 to g_end); |g_end| in [0.06, 0.15] with a
              random sign, tau in [0.3, 3] T.
gain_heating  measurement: the sensor's scale factor has a temperature coefficient alpha and
              the sensor is heated by the motor's copper losses, so its gain error follows
              the work the drive does, not a fixed exponential of time:
                  P(t) = s tau_out(t)^2            (copper loss, s = loss coefficient)
                  C T' = P - T / R,  T(0) = 0      (sensor temperature rise above ambient)
                  y = (1 + alpha T(t)) theta,      g(t) = alpha T(t)  (the gain error)
              tau_out is the noise-free gear-output-side drive torque, the cycle mean the
              torque channel reports (tau_out,k = N clean_torque_nm[k], mean over
              [t_k-1, t_k]).  P is held at s tau_out,k^2 over [t_k-1, t_k] (zero-order hold;
              the ripple of the torque inside a cycle is not squared in), and the ODE is
              integrated exactly over each interval:
                  T_k = e^(-h/tau_th) T_k-1 + (1 - e^(-h/tau_th)) R s tau_out,k^2,  h = 1/fs.
              tau_th = R C in [0.5, 5] T; |g(T_end)| (the gain error at the last sample)
              in [0.04, 0.15] with a random sign, which is the sign of alpha (T >= 0).
              Conventions (only alpha R s and tau_th are observable): |alpha| = 2e-3 /K,
              R = 1 K/W; the loss coefficient s is solved after the torque is simulated so
              that alpha T(t_end) equals the drawn final gain error.  If the drive torque
              stays below 1e-6 N m throughout, nothing heats: s = 0, g = 0, not excited.
              truth.gain_error_series holds g at every sample.
cogging       load torque: tau = -T_c sin(n_c theta_l + p_c); T_c in [0.03, 0.3] N m,
              n_c integer in [6, 36], p_c in [-pi, pi).
stribeck      load torque: tau = -(F_c + (F_s - F_c) exp(-(v/v_s)^2)) tanh(v/eps) (the -b v
              part is the nominal viscous friction, not added twice); F_c in [0.03, 0.3] N m,
              F_s/F_c in [1.3, 2.5], v_s log-uniform in [0.01, 0.1] rad/s, eps = 1e-3 rad/s.
coulomb       load torque: tau = -F_c tanh(v/eps); F_c in [0.03, 0.3] N m, eps = 1e-3 rad/s.
gravity       load torque: tau = -m g r sin(theta_l - theta_0); m g r in [0.1, 1.0] N m,
              theta_0 (hanging angle) in [-pi, pi).
hysteresis    shaft: internal dry friction of the coupling as a Bouc-Wen element in parallel
              with the spring-damper (a series element was specified; see README for why):
              tau_s = k Delta + c Delta' + T_h w,
              w' = (Delta'/d_h) (1 - |w|^n (beta sgn(Delta' w) + gamma)), beta = gamma = 1/2,
              so w in [-1, 1] and the hysteretic torque T_h w saturates at +-T_h after a
              twist of order d_h past each reversal (stiffness k + T_h/d_h just after a
              reversal, k once saturated).  T_h in [0.03, 0.3] N m, d_h in [0.2, 2] mrad,
              n in [1, 2].  Rate independent and dissipative (loops run clockwise).
backlash      shaft: dead band of total width 2 b_h: tau_s = 0 while |Delta| < b_h, else
              k (Delta -+ b_h) + c Delta', clipped so the contact never pulls (with
              b_h = 0 both flanks touch and the shaft is the nominal linear one);
              b_h in [0.5, 5] mrad.

Excitations (load-side reference r(t), command u = N r, centre c in [-pi, pi) from the seed)
--------------------------------------------------------------------------------------------
chirp      c + A sin(2 pi (f0 t + (f1 - f0) t^2 / (2T))), A = 0.5 rad, f0 = 0.2 Hz, f1 in [3, 8] Hz.
multisine  c + sum of 12 sines, log-spaced 0.2..5 Hz, random phases, peak scaled to A = 0.5 rad.
steps      random levels in c +- A (A = 1 rad) held for 0.3..1.5 s, joined by half-cosine
           moves of peak acceleration 200 rad/s^2 (bare 1 rad steps through a 60 Hz servo
           would twist the shaft by ~1 rad, i.e. ~200 N m: not a plausible drive).
ramp       from c forward n_rev revolutions and back (n_rev in [2, 4], A overrides it),
           trapezoidal speed with 10 % of each leg accelerating.
prbs       bare steps c +- A (A = 0.01 rad, 6.5 counts at 12 bit) from a 10-bit
           maximum-length LFSR clocked every 20..100 ms.
The same seed gives the same excitation and noise for every effect (separate random
streams: excitation 1, effect 2, angle noise 3, torque noise 4), so a record with an effect and its nominal twin differ only by the effect.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.signal import lfilter

TWO_PI = 2.0 * math.pi

NOMINAL_DEFAULTS = {
    "gear_ratio": 1.0,
    "load_inertia_kg_m2": 0.004,
    "shaft_stiffness_nm_per_rad": 150.0,
    "shaft_damping_nm_s_per_rad": 0.0775,
    "viscous_friction_nm_s_per_rad": 0.005,
    "position_loop_bandwidth_hz": 60.0,
    "position_loop_damping_ratio": 0.7,
    "motor_inertia_kg_m2": 0.002,
    "servo": "kinematic",
    "rated_torque_nm": 2.0,
}

RTOL = 1e-10
ATOL = 1e-12
ODE_METHOD = "LSODA"

# Stream tags for np.random.default_rng([seed, tag]): independent of call order.
_STREAM_EXCITATION = 1
_STREAM_EFFECT = 2
_STREAM_NOISE = 3
_STREAM_TORQUE_NOISE = 4  # drive torque noise: a new stream, so angles stay as they were

INT16_MIN, INT16_MAX = -32768, 32767

# gain_heating conventions: only alpha R s and tau_th are observable, so |alpha| and R are
# fixed and the loss coefficient s is solved from the drawn final gain error.
HEATING_TEMPCO_PER_K = 2e-3        # |alpha|, 0.2 %/K: final temperature rise 20..75 K
HEATING_THERMAL_RESISTANCE_K_PER_W = 1.0
HEATING_TORQUE_FLOOR_NM = 1e-6     # max |tau_out| below this: no heating, effect not excited


# ----------------------------------------------------------------------------- effects
@dataclass(frozen=True)
class EffectSpec:
    name: str
    kind: str  # "none" | "measurement" | "load_torque" | "shaft"
    ranges: dict  # parameter -> (low, high, "uniform"|"loguniform"|"int"|"fixed"|"signed")
    description: str
    extra_state: int = 0


def _eff(name, kind, description, ranges, extra_state=0):
    return EffectSpec(name, kind, ranges, description, extra_state)


PI = math.pi
EFFECTS = {
    e.name: e
    for e in [
        _eff("none", "none", "nominal plant only", {}),
        _eff("eccentricity", "measurement",
             "y = theta + a1 sin(theta + p1) + a2 sin(2 theta + p2)",
             {"a1_rad": (0.5e-3, 3e-3, "uniform"), "phase1_rad": (-PI, PI, "uniform"),
              "a2_rad": (0.1e-3, 1e-3, "uniform"), "phase2_rad": (-PI, PI, "uniform")}),
        _eff("wrap", "measurement",
             "single-turn reading wrapped to (-pi, pi] inside [wrap_start_s, wrap_end_s)",
             {"wrap_start_fraction": (0.2, 0.5, "uniform"),
              "wrap_end_fraction": (0.6, 1.0, "uniform")}),
        _eff("gain_drift", "measurement",
             "y = (1 + g(t)) theta, first-order drift of g from 0 to g_end",
             {"final_gain_error": (0.06, 0.15, "signed"),
              "time_constant_fraction": (0.3, 3.0, "uniform")}),
        _eff("gain_heating", "measurement",
             "y = (1 + alpha T(t)) theta, sensor temperature rise T heated by the copper "
             "loss s tau_out^2 through a first-order thermal model C T' = s tau_out^2 - T/R",
             {"final_gain_error": (0.04, 0.15, "signed"),
              "thermal_time_constant_fraction": (0.5, 5.0, "uniform")}),
        _eff("cogging", "load_torque", "tau = -T_c sin(n_c theta_l + p_c)",
             {"torque_nm": (0.03, 0.3, "uniform"), "periods_per_rev": (6, 36, "int"),
              "phase_rad": (-PI, PI, "uniform")}),
        _eff("stribeck", "load_torque",
             "tau = -(F_c + (F_s - F_c) exp(-(v/v_s)^2)) tanh(v/eps)",
             {"coulomb_nm": (0.03, 0.3, "uniform"), "static_to_coulomb": (1.3, 2.5, "uniform"),
              "stribeck_velocity_rad_per_s": (0.01, 0.1, "loguniform"),
              "smoothing_velocity_rad_per_s": (1e-3, 1e-3, "fixed")}),
        _eff("coulomb", "load_torque", "tau = -F_c tanh(v/eps)",
             {"coulomb_nm": (0.03, 0.3, "uniform"),
              "smoothing_velocity_rad_per_s": (1e-3, 1e-3, "fixed")}),
        _eff("gravity", "load_torque", "tau = -m g r sin(theta_l - theta_0)",
             {"mgr_nm": (0.1, 1.0, "uniform"), "hanging_angle_rad": (-PI, PI, "uniform")}),
        _eff("hysteresis", "shaft",
             "Bouc-Wen dry internal friction of the coupling, parallel to the shaft spring",
             {"torque_nm": (0.03, 0.3, "uniform"),
              "presliding_twist_rad": (0.2e-3, 2e-3, "uniform"),
              "exponent": (1.0, 2.0, "uniform")}, extra_state=1),
        _eff("backlash", "shaft", "dead band |Delta| < b_h with no torque, contact never pulls",
             {"half_width_rad": (0.5e-3, 5e-3, "uniform")}),
    ]
}


def draw_effect_parameters(effect: str, seed: int, duration_s: float, overrides: dict) -> dict:
    """Draw the effect parameters from the seed; ``overrides`` replace drawn values."""
    spec = EFFECTS[effect]
    rng = np.random.default_rng([seed, _STREAM_EFFECT])
    params = {}
    for name, (lo, hi, how) in spec.ranges.items():
        if how == "uniform":
            v = float(rng.uniform(lo, hi))
        elif how == "loguniform":
            v = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        elif how == "int":
            v = int(rng.integers(lo, hi + 1))
        elif how == "signed":
            v = float(rng.uniform(lo, hi) * rng.choice([-1.0, 1.0]))
        elif how == "fixed":
            v = float(lo)
        else:  # pragma: no cover
            raise ValueError(how)
        params[name] = v
    # derived, time-based parameters
    if effect == "wrap":
        params["wrap_start_s"] = params.pop("wrap_start_fraction") * duration_s
        params["wrap_end_s"] = params.pop("wrap_end_fraction") * duration_s
    if effect == "gain_drift":
        params["time_constant_s"] = params.pop("time_constant_fraction") * duration_s
    if effect == "gain_heating":
        params["thermal_time_constant_s"] = (params.pop("thermal_time_constant_fraction")
                                             * duration_s)
    if effect == "stribeck":
        params["static_nm"] = params["coulomb_nm"] * params.pop("static_to_coulomb")
    allowed = set(params)
    for k, v in overrides.items():
        if k not in allowed:
            raise ValueError(f"effect {effect!r} has no parameter {k!r}; it has {sorted(allowed)}")
        params[k] = int(v) if isinstance(params[k], int) else float(v)
    if effect == "stribeck" and params["static_nm"] < 0:
        raise ValueError("static_nm must be >= 0")
    if effect == "gain_heating" and not params["thermal_time_constant_s"] > 0:
        raise ValueError("thermal_time_constant_s must be > 0")
    return params


# ------------------------------------------------------------------------- excitations
def _lfsr10(n_bits: int, state: int) -> np.ndarray:
    """Maximum-length 10-bit LFSR (x^10 + x^7 + 1), period 1023."""
    out = np.empty(n_bits, dtype=float)
    s = state & 0x3FF or 1
    for i in range(n_bits):
        bit = ((s >> 9) ^ (s >> 6)) & 1
        out[i] = 1.0 if (s & 1) else -1.0
        s = ((s << 1) | bit) & 0x3FF
    return out


EXCITATIONS = ("chirp", "multisine", "steps", "ramp", "prbs")


def make_reference(excitation: str, seed: int, n: int, fs: float, amplitude_rad=None):
    """Load-side reference r_k (rad) and a description of how it was made."""
    rng = np.random.default_rng([seed, _STREAM_EXCITATION])
    t = np.arange(n) / fs
    T = n / fs
    centre = float(rng.uniform(-PI, PI))
    info = {"name": excitation, "seed": seed, "centre_rad": centre}
    if excitation == "chirp":
        A = 0.5 if amplitude_rad is None else amplitude_rad
        f0, f1 = 0.2, float(rng.uniform(3.0, 8.0))
        r = centre + A * np.sin(TWO_PI * (f0 * t + (f1 - f0) * t**2 / (2 * T)))
        info.update(amplitude_rad=A, f0_hz=f0, f1_hz=f1, sweep="linear")
    elif excitation == "multisine":
        A = 0.5 if amplitude_rad is None else amplitude_rad
        freqs = np.geomspace(0.2, 5.0, 12)
        phases = rng.uniform(-PI, PI, freqs.size)
        s = np.sin(TWO_PI * freqs[None, :] * t[:, None] + phases[None, :]).sum(axis=1)
        s *= A / np.max(np.abs(s))
        r = centre + s
        info.update(amplitude_rad=A, frequencies_hz=freqs.tolist(), phases_rad=phases.tolist())
    elif excitation == "steps":
        A = 1.0 if amplitude_rad is None else amplitude_rad
        a_max = 200.0  # rad/s^2, peak acceleration of each move between held levels
        r = np.empty(n)
        k, level, moves = 0, centre, 0
        while k < n:
            hold = max(1, int(round(rng.uniform(0.3, 1.5) * fs)))
            new = centre + float(rng.uniform(-A, A))
            dist = new - level
            # half-cosine move: peak acceleration (pi^2/2) |dist| / tau^2 = a_max
            m = min(n - k, max(1, int(math.ceil(math.sqrt(PI**2 * abs(dist) / (2 * a_max)) * fs))))
            s = np.arange(1, m + 1) / m
            r[k:k + m] = level + dist * 0.5 * (1 - np.cos(PI * s))
            r[k + m:k + m + hold] = new
            level = new
            k += m + hold
            moves += 1
        info.update(amplitude_rad=A, hold_s=[0.3, 1.5], moves=moves,
                    move_shape="half-cosine", move_peak_acceleration_rad_per_s2=a_max)
    elif excitation == "ramp":
        n_rev = float(rng.uniform(2.0, 4.0)) if amplitude_rad is None else amplitude_rad / TWO_PI
        D = n_rev * TWO_PI
        leg = T / 2
        ta = 0.1 * leg
        v = D / (leg - ta)  # trapezoid: accelerate ta, cruise, decelerate ta
        acc = v / ta

        def leg_pos(s):
            s = np.clip(s, 0.0, leg)
            p = np.where(s < ta, 0.5 * acc * s**2,
                         np.where(s < leg - ta, 0.5 * acc * ta**2 + v * (s - ta),
                                  D - 0.5 * acc * (leg - s) ** 2))
            return p

        r = centre + np.where(t < leg, leg_pos(t), D - leg_pos(t - leg))
        info.update(revolutions=n_rev, travel_rad=D, cruise_speed_rad_per_s=v,
                    acceleration_rad_per_s2=acc, shape="forward then back, trapezoidal speed")
    elif excitation == "prbs":
        A = 0.01 if amplitude_rad is None else amplitude_rad
        clock = max(1, int(round(rng.uniform(0.02, 0.1) * fs)))
        bits = _lfsr10(n // clock + 1, int(rng.integers(1, 1024)))
        r = centre + A * np.repeat(bits, clock)[:n]
        info.update(amplitude_rad=A, clock_s=clock / fs, register="10-bit LFSR x^10+x^7+1")
    else:
        raise ValueError(f"unknown excitation {excitation!r}; choose from {EXCITATIONS}")
    return r, info


# ---------------------------------------------------------------------------- plant
def nominal_parameters(**overrides) -> dict:
    p = dict(NOMINAL_DEFAULTS)
    for k, v in overrides.items():
        if k not in p:
            raise ValueError(f"unknown nominal parameter {k!r}")
        p[k] = v
    if p["servo"] not in ("kinematic", "cascade"):
        raise ValueError("servo must be 'kinematic' or 'cascade'")
    return p


def linear_matrices(nom: dict):
    """A (4x4), B (4,) of the nominal plant, state [theta_m, omega_m, theta_l, omega_l]."""
    N = nom["gear_ratio"]
    J = nom["load_inertia_kg_m2"]
    k = nom["shaft_stiffness_nm_per_rad"]
    c = nom["shaft_damping_nm_s_per_rad"]
    b = nom["viscous_friction_nm_s_per_rad"]
    wc = TWO_PI * nom["position_loop_bandwidth_hz"]
    z = nom["position_loop_damping_ratio"]
    A = np.zeros((4, 4))
    B = np.zeros(4)
    A[0, 1] = 1.0
    A[2, 3] = 1.0
    # load: J w_l' = k (th_m/N - th_l) + c (w_m/N - w_l) - b w_l
    A[3, 0] = k / (N * J)
    A[3, 1] = c / (N * J)
    A[3, 2] = -k / J
    A[3, 3] = -(c + b) / J
    if nom["servo"] == "kinematic":
        A[1, 0] = -wc**2
        A[1, 1] = -2 * z * wc
        B[1] = wc**2
    else:
        Jm = N**2 * nom["motor_inertia_kg_m2"]  # reflected to the load side
        Jt = Jm + J
        Kv = 2 * z * wc * Jt
        Kp = wc / (2 * z)
        # phi'' = [Kv (Kp (u/N - phi) - phi') - tau_s] / Jm ; omega_m' = N phi''
        # tau_s = k (phi - th_l) + c (phi' - w_l), phi = th_m / N
        A[1, 0] = N * (-Kv * Kp / N - k / N) / Jm
        A[1, 1] = N * (-Kv / N - c / N) / Jm
        A[1, 2] = N * k / Jm
        A[1, 3] = N * c / Jm
        B[1] = N * Kv * Kp / N / Jm
    return A, B


def discretise(A: np.ndarray, B: np.ndarray, dt: float):
    """Exact zero-order-hold discretisation via the augmented matrix exponential."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A
    M[:n, n] = B
    E = expm(M * dt)
    return E[:n, :n], E[:n, n]


def simulate_linear(nom: dict, u: np.ndarray, fs: float, x0: np.ndarray, substeps: int = 1):
    """Exact sampled response of the nominal plant to the held command u (state at t_k)."""
    A, B = linear_matrices(nom)
    Ad, Bd = discretise(A, B, 1.0 / (fs * substeps))
    X = np.empty((u.size, 4))
    x = np.array(x0, dtype=float)
    X[0] = x
    for k in range(u.size - 1):
        for _ in range(substeps):
            x = Ad @ x + Bd * u[k]
        X[k + 1] = x
    return X


def _load_torque_fn(effect: str, p: dict):
    if effect == "cogging":
        Tc, nc, ph = p["torque_nm"], p["periods_per_rev"], p["phase_rad"]
        return lambda th, v: -Tc * math.sin(nc * th + ph)
    if effect == "stribeck":
        Fc, Fs, vs, eps = p["coulomb_nm"], p["static_nm"], p["stribeck_velocity_rad_per_s"], \
            p["smoothing_velocity_rad_per_s"]
        return lambda th, v: -(Fc + (Fs - Fc) * math.exp(-(v / vs) ** 2)) * math.tanh(v / eps)
    if effect == "coulomb":
        Fc, eps = p["coulomb_nm"], p["smoothing_velocity_rad_per_s"]
        return lambda th, v: -Fc * math.tanh(v / eps)
    if effect == "gravity":
        mgr, th0 = p["mgr_nm"], p["hanging_angle_rad"]
        return lambda th, v: -mgr * math.sin(th - th0)
    return None


def friction_torque(effect: str, params: dict, velocity):
    """Vectorised effect friction torque (for checks); zero for non-friction effects."""
    f = _load_torque_fn(effect, params)
    if effect not in ("stribeck", "coulomb"):
        return np.zeros_like(np.asarray(velocity, dtype=float))
    return np.array([f(0.0, float(v)) for v in np.atleast_1d(velocity)])


def _load_torque_vec(effect: str, p: dict):
    """Vectorised (numpy) form of _load_torque_fn: same formulas, array arguments."""
    if effect == "cogging":
        Tc, nc, ph = p["torque_nm"], p["periods_per_rev"], p["phase_rad"]
        return lambda th, v: -Tc * np.sin(nc * th + ph)
    if effect == "stribeck":
        Fc, Fs, vs, eps = p["coulomb_nm"], p["static_nm"], p["stribeck_velocity_rad_per_s"], \
            p["smoothing_velocity_rad_per_s"]
        return lambda th, v: -(Fc + (Fs - Fc) * np.exp(-(v / vs) ** 2)) * np.tanh(v / eps)
    if effect == "coulomb":
        Fc, eps = p["coulomb_nm"], p["smoothing_velocity_rad_per_s"]
        return lambda th, v: -Fc * np.tanh(v / eps)
    if effect == "gravity":
        mgr, th0 = p["mgr_nm"], p["hanging_angle_rad"]
        return lambda th, v: -mgr * np.sin(th - th0)
    return None


# ---------------------------------------------------------------------- drive torque
def shaft_torque(nom: dict, effect: str, p: dict, X: np.ndarray) -> np.ndarray:
    """Shaft torque tau_s (gear-output side, N m) at the sampled states, as in make_rhs."""
    N = nom["gear_ratio"]
    k = nom["shaft_stiffness_nm_per_rad"]
    c = nom["shaft_damping_nm_s_per_rad"]
    d = X[:, 0] / N - X[:, 2]
    dd = X[:, 1] / N - X[:, 3]
    if effect == "hysteresis":
        return k * d + c * dd + p["torque_nm"] * X[:, 4]
    if effect == "backlash" and p["half_width_rad"] > 0.0:
        bh = p["half_width_rad"]
        return np.where(d > bh, np.maximum(k * (d - bh) + c * dd, 0.0),
                        np.where(d < -bh, np.minimum(k * (d + bh) + c * dd, 0.0), 0.0))
    return k * d + c * dd


def instantaneous_drive_torque(nom: dict, effect: str, p: dict, X: np.ndarray,
                               u_held: np.ndarray) -> np.ndarray:
    """Motor-side drive torque at the states X under the held commands u_held (N m).

    cascade:   tau_out = K_v (K_p (u/N - phi) - phi')
    kinematic: tau_out = J_m' phi'' + tau_s, phi'' = (wc^2 (u - theta_m) - 2 zeta wc omega_m)/N
    motor side tau_out / N.  (The reported reading is the cycle mean, see drive_torque.)
    """
    N = nom["gear_ratio"]
    Jm = N**2 * nom["motor_inertia_kg_m2"]
    wc = TWO_PI * nom["position_loop_bandwidth_hz"]
    zeta = nom["position_loop_damping_ratio"]
    phi, dphi = X[:, 0] / N, X[:, 1] / N
    if nom["servo"] == "kinematic":
        ddphi = (wc * wc * (u_held - X[:, 0]) - 2.0 * zeta * wc * X[:, 1]) / N
        tau_out = Jm * ddphi + shaft_torque(nom, effect, p, X)
    else:
        Kv = 2 * zeta * wc * (Jm + nom["load_inertia_kg_m2"])
        Kp = wc / (2 * zeta)
        tau_out = Kv * (Kp * (u_held / N - phi) - dphi)
    return tau_out / N


def drive_torque(nom: dict, effect: str, p: dict, X: np.ndarray, u: np.ndarray, fs: float,
                 load_integral: np.ndarray | None = None) -> np.ndarray:
    """Motor-side drive torque, mean over the control cycle [t_k-1, t_k] (N m).

    By the momentum balance of the whole train (the shaft torque is internal)::

        tau_out,k = [J_m' (phi'_k - phi'_k-1) + J_l (theta_l'_k - theta_l'_k-1)
                     + b (theta_l,k - theta_l,k-1) - int tau_effect dt] * fs

    reported as tau_out,k / N.  ``load_integral[k]`` is the integral of the load-torque
    effect over the cycle (zero for the other effects).  Sample 0: the train has been at
    rest under u_0, so the instantaneous torque there is the cycle mean.
    """
    N = nom["gear_ratio"]
    Jm = N**2 * nom["motor_inertia_kg_m2"]
    Jl = nom["load_inertia_kg_m2"]
    b = nom["viscous_friction_nm_s_per_rad"]
    tau = np.empty(X.shape[0])
    tau[0] = instantaneous_drive_torque(nom, effect, p, X[:1], u[:1])[0]
    impulse = (Jm * np.diff(X[:, 1] / N) + Jl * np.diff(X[:, 3]) + b * np.diff(X[:, 2]))
    if load_integral is not None:
        impulse = impulse - load_integral[1:]
    tau[1:] = impulse * fs / N
    return tau


def torque_reading(tau: np.ndarray, rated_nm: float, noise: np.ndarray):
    """CiA 402 torque actual value: per mille of rated torque, rounded, INTEGER16."""
    permille = np.clip(np.round((tau + noise) / (rated_nm / 1000.0)), INT16_MIN, INT16_MAX)
    permille = permille.astype(np.int64)
    return permille, permille * rated_nm / 1000.0


def make_rhs(nom: dict, effect: str, p: dict):
    """Right-hand side f(t, x, u) of the plant with the effect (dynamic effects)."""
    N = nom["gear_ratio"]
    J = nom["load_inertia_kg_m2"]
    k = nom["shaft_stiffness_nm_per_rad"]
    c = nom["shaft_damping_nm_s_per_rad"]
    b = nom["viscous_friction_nm_s_per_rad"]
    wc = TWO_PI * nom["position_loop_bandwidth_hz"]
    zeta = nom["position_loop_damping_ratio"]
    kinematic = nom["servo"] == "kinematic"
    if not kinematic:
        Jm = N**2 * nom["motor_inertia_kg_m2"]
        Kv = 2 * zeta * wc * (Jm + J)
        Kp = wc / (2 * zeta)
    load_tau = _load_torque_fn(effect, p)

    if effect == "hysteresis":
        Th, dh, nh = p["torque_nm"], p["presliding_twist_rad"], p["exponent"]
    if effect == "backlash":
        bh = p["half_width_rad"]

    def rhs(t, x, u):
        th_m, w_m, th_l, w_l = x[0], x[1], x[2], x[3]
        phi, dphi = th_m / N, w_m / N
        d, dd = phi - th_l, dphi - w_l
        dz = None
        if effect == "hysteresis":
            w = x[4]
            aw = abs(w) ** nh
            # beta = gamma = 1/2: 1 - |w|^n when loading (dd w > 0), 1 when unloading
            dz = (dd / dh) * (1.0 - aw) if dd * w > 0 else dd / dh
            tau_s = k * d + c * dd + Th * w
        elif effect == "backlash" and bh > 0.0:
            # each flank can only push: clip the contact torque at zero (no pulling)
            if d > bh:
                tau_s = max(k * (d - bh) + c * dd, 0.0)
            elif d < -bh:
                tau_s = min(k * (d + bh) + c * dd, 0.0)
            else:
                tau_s = 0.0
        else:
            tau_s = k * d + c * dd
        tau_l = tau_s - b * w_l
        if load_tau is not None:
            tau_l += load_tau(th_l, w_l)
        dw_l = tau_l / J
        if kinematic:
            dw_m = wc * wc * (u - th_m) - 2.0 * zeta * wc * w_m
        else:
            dw_m = N * (Kv * (Kp * (u / N - phi) - dphi) - tau_s) / Jm
        if dz is None:
            return [w_m, dw_m, w_l, dw_l]
        return [w_m, dw_m, w_l, dw_l, dz]

    return rhs


_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(4)


def _interval_integrals(ode_sol, f, edges: np.ndarray) -> np.ndarray:
    """Integrals of f(state) over [edges[i], edges[i+1]] along a dense solve_ivp solution.

    4-point Gauss-Legendre on every integrator step inside each interval (the steps are
    those the error control chose for the dynamics, so a sharp feature such as a tanh
    friction reversal is covered by short steps).
    """
    lo, hi = edges[0], edges[-1]
    inner = ode_sol.ts[(ode_sol.ts > lo) & (ode_sol.ts < hi)]
    cuts = np.union1d(edges, inner)
    a, b = cuts[:-1], cuts[1:]
    half, mid = 0.5 * (b - a), 0.5 * (b + a)
    nodes = (mid[:, None] + half[:, None] * _GAUSS_X[None, :]).ravel()
    vals = np.asarray(f(ode_sol(nodes)), dtype=float).reshape(a.size, _GAUSS_X.size)
    pieces = half * (vals @ _GAUSS_W)
    owner = np.searchsorted(edges, mid) - 1  # sample interval holding each piece
    return np.bincount(owner, weights=pieces, minlength=edges.size - 1)


def simulate_nonlinear(rhs, u: np.ndarray, fs: float, x0, *, method=ODE_METHOD, rtol=RTOL,
                       atol=ATOL, quad=None):
    """Integrate with solve_ivp over each run of equal held commands; state at t_k.

    With ``quad`` (a vectorised function of the state, shape (n_state, m) -> (m,)), also
    return ``Q`` with ``Q[k] = integral of quad(x(t)) over [t_k-1, t_k]`` (``Q[0] = 0``),
    taken from the dense output of the same integration (which leaves the steps and the
    sampled states unchanged).
    """
    n = u.size
    x = np.array(x0, dtype=float)
    X = np.empty((n, x.size))
    X[0] = x
    Q = np.zeros(n) if quad is not None else None
    k = 0
    while k < n - 1:
        j = k + 1
        while j < n - 1 and u[j] == u[k]:
            j += 1
        uk = float(u[k])
        t_eval = np.arange(k + 1, j + 1) / fs
        sol = solve_ivp(lambda t, y: rhs(t, y, uk), (k / fs, j / fs), x, method=method,
                        t_eval=t_eval, rtol=rtol, atol=atol, dense_output=quad is not None)
        if not sol.success:  # pragma: no cover
            raise RuntimeError(f"integration failed at t={k / fs}: {sol.message}")
        X[k + 1:j + 1] = sol.y.T
        if quad is not None:
            Q[k + 1:j + 1] = _interval_integrals(sol.sol, quad, np.arange(k, j + 1) / fs)
        x = sol.y[:, -1]
        k = j
    if quad is not None:
        return X, Q
    return X


def initial_state(nom: dict, effect: str, p: dict, u0: float) -> np.ndarray:
    """At rest, motor at u0, load at the static equilibrium with the effect present."""
    N = nom["gear_ratio"]
    k = nom["shaft_stiffness_nm_per_rad"]
    phi = u0 / N
    th = phi
    f = _load_torque_fn(effect, p) if effect in ("gravity", "cogging") else None
    if f is not None:
        # k (phi - th) + tau(th) = 0 ; Newton with a numerical derivative
        for _ in range(100):
            g = k * (phi - th) + f(th, 0.0)
            h = 1e-7
            dg = -k + (f(th + h, 0.0) - f(th - h, 0.0)) / (2 * h)
            step = g / dg
            th -= step
            if abs(step) < 1e-15:
                break
    x0 = [u0, 0.0, th, 0.0]
    if nom["servo"] == "cascade" and f is not None:
        # the motor loop needs a static torque: its P-position error carries it
        Jm = N**2 * nom["motor_inertia_kg_m2"]
        wc = TWO_PI * nom["position_loop_bandwidth_hz"]
        zeta = nom["position_loop_damping_ratio"]
        Kv = 2 * zeta * wc * (Jm + nom["load_inertia_kg_m2"])
        Kp = wc / (2 * zeta)
        # Kv Kp (u0/N - phi) = k (phi - th)  and  k (phi - th) = -f(th)  -> solve jointly
        for _ in range(100):
            tau_needed = -f(th, 0.0)
            phi = u0 / N - tau_needed / (Kv * Kp)
            th_new = th
            for _ in range(50):
                g = k * (phi - th_new) + f(th_new, 0.0)
                dg = -k + (f(th_new + 1e-7, 0.0) - f(th_new - 1e-7, 0.0)) / 2e-7
                th_new -= g / dg
            if abs(th_new - th) < 1e-15:
                th = th_new
                break
            th = th_new
        x0 = [phi * N, 0.0, th, 0.0]
    if EFFECTS[effect].extra_state:
        x0.append(0.0)
    return np.array(x0, dtype=float)


# ---------------------------------------------------------------------- measurement
def heating_gain_error(p: dict, tau_out: np.ndarray, fs: float):
    """Gain error g_k = alpha T_k of the self-heated sensor (effect ``gain_heating``).

    ``tau_out[k]`` is the noise-free gear-output-side drive torque, mean over [t_k-1, t_k]
    (``tau_out[0]``, the static torque before t = 0, is not used: T(0) = 0).  The copper
    loss P = s tau_out,k^2 is held over [t_k-1, t_k], and C T' = P - T/R is integrated
    exactly there: T_k = a T_k-1 + (1 - a) R P_k, a = exp(-1/(fs tau_th)).  The loss
    coefficient s is solved so that alpha T at the last sample is ``final_gain_error``.
    Returns (g, info); info holds the solved and fixed thermal quantities.
    """
    g_end = float(p["final_gain_error"])
    tau_th = float(p["thermal_time_constant_s"])
    R = HEATING_THERMAL_RESISTANCE_K_PER_W
    alpha = math.copysign(HEATING_TEMPCO_PER_K, g_end)
    a = math.exp(-1.0 / (fs * tau_th))
    n = tau_out.size
    T1 = np.zeros(n)  # temperature rise for s = 1 W per (N m)^2
    if n > 1:
        T1[1:] = lfilter([(1.0 - a) * R], [1.0, -a], np.asarray(tau_out[1:], float) ** 2)
    heated = bool(n > 1 and np.max(np.abs(tau_out[1:])) >= HEATING_TORQUE_FLOOR_NM
                  and T1[-1] > 0.0)
    s = float(abs(g_end) / (HEATING_TEMPCO_PER_K * T1[-1])) if heated else 0.0
    T = s * T1
    g = alpha * T
    info = {
        "temperature_coefficient_per_k": alpha,
        "temperature_coefficient_sign": int(math.copysign(1, g_end)),
        "thermal_resistance_k_per_w": R,
        "thermal_capacitance_j_per_k": tau_th / R,
        "loss_coefficient_w_per_nm2": s,
        "final_temperature_rise_k": float(T[-1]),
        "peak_temperature_rise_k": float(np.max(T)),
        "achieved_final_gain_error": float(g[-1]),
        "peak_abs_gain_error": float(np.max(np.abs(g))),
        "heated": heated,
    }
    return g, info


def measure(effect: str, p: dict, t: np.ndarray, theta: np.ndarray,
            gain_error: np.ndarray | None = None) -> np.ndarray:
    """Noise-free, unquantised sensor angle for the measurement effects.

    ``gain_error`` is g_k of ``gain_heating`` (from heating_gain_error)."""
    if effect == "eccentricity":
        return (theta + p["a1_rad"] * np.sin(theta + p["phase1_rad"])
                + p["a2_rad"] * np.sin(2 * theta + p["phase2_rad"]))
    if effect == "gain_drift":
        T = t[-1] + (t[1] - t[0]) if t.size > 1 else 1.0
        tau = p["time_constant_s"]
        g = p["final_gain_error"] * (1 - np.exp(-t / tau)) / (1 - math.exp(-T / tau))
        return (1.0 + g) * theta
    if effect == "gain_heating":
        return (1.0 + gain_error) * theta
    return theta.copy()


def quantise(angle: np.ndarray, bits: int) -> np.ndarray:
    q = TWO_PI / 2**bits
    return np.round(angle / q).astype(np.int64)


def wrap_counts(counts: np.ndarray, bits: int) -> np.ndarray:
    """Single-turn reading: counts in (-2^(B-1), 2^(B-1)], i.e. angles in (-pi, pi]."""
    full, half = 2**bits, 2 ** (bits - 1)
    return np.mod(counts + half - 1, full) - half + 1


# ------------------------------------------------------------------------- generate
def generate(effect: str, seed: int, *, excitation: str = "multisine", duration_s: float = 10.0,
             fs_hz: float = 1000.0, bits: int = 12, noise_rad: float = 0.0,
             amplitude_rad: float | None = None, nominal: dict | None = None,
             torque_noise_nm: float = 0.0, **effect_params) -> dict:
    """Make one record.

    Returns a dict with ``time_s``, ``command_rad`` (motor-side command), ``angle_rad``
    (measured load angle), ``encoder_counts``, ``nominal`` (parameters), ``truth`` (effect,
    parameters, excitation, effect size) and ``state`` (true sampled states, columns
    theta_m, omega_m, theta_l, omega_l[, w]) plus ``clean_angle_rad`` (noise-free,
    unquantised sensor angle before wrapping).

    Drive torque channel (motor side, see "Drive torque" in the module docstring):
    ``torque_permille`` (int, CiA 402 0x6077), ``torque_nm`` (= permille * rated / 1000),
    ``clean_torque_nm`` (noise-free, unquantised cycle mean), ``clean_torque_instant_nm``
    (instantaneous value just before t_k, with u_k-1; not what is reported) and
    ``nominal_torque_nm`` (cycle mean of the nominal twin).

    ``gain_heating`` adds ``truth["gain_error_series"]`` (g_k = alpha T_k per sample) and the
    solved thermal quantities to ``truth["parameters"]`` (see heating_gain_error).
    """
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; choose from {sorted(EFFECTS)}")
    if bits < 2 or bits > 30:
        raise ValueError("bits must be in 2..30")
    nom = nominal_parameters(**(nominal or {}))
    n = int(round(duration_s * fs_hz))
    if n < 2:
        raise ValueError("record needs at least two samples")
    t = np.arange(n) / fs_hz
    ref, exc_info = make_reference(excitation, seed, n, fs_hz, amplitude_rad)
    u = nom["gear_ratio"] * ref
    params = draw_effect_parameters(effect, seed, n / fs_hz, effect_params)
    spec = EFFECTS[effect]

    # nominal twin (exact), also used as the plant for measurement-only effects
    x0_nom = initial_state(nom, "none", {}, float(u[0]))
    X_nom = simulate_linear(nom, u, fs_hz, x0_nom)
    load_integral = None
    if spec.kind == "load_torque":
        rhs = make_rhs(nom, effect, params)
        f_load = _load_torque_vec(effect, params)
        X, load_integral = simulate_nonlinear(
            rhs, u, fs_hz, initial_state(nom, effect, params, float(u[0])),
            quad=lambda y: f_load(y[2], y[3]))
    elif spec.kind == "shaft":
        rhs = make_rhs(nom, effect, params)
        X = simulate_nonlinear(rhs, u, fs_hz, initial_state(nom, effect, params, float(u[0])))
    else:
        X = X_nom
    theta_l = X[:, 2]
    # drive torque (motor side), cycle mean over [t_k-1, t_k]; command held there is u_k-1
    tau_clean = drive_torque(nom, effect, params, X, u, fs_hz, load_integral)
    gain_error = None
    if effect == "gain_heating":  # heated by the gear-output-side torque N tau_motor
        gain_error, heating = heating_gain_error(params, nom["gear_ratio"] * tau_clean, fs_hz)
        params.update(heating)
    clean = measure(effect, params, t, theta_l, gain_error)

    noise = np.random.default_rng([seed, _STREAM_NOISE]).normal(0.0, 1.0, n) * noise_rad
    counts = quantise(clean + noise, bits)
    q = TWO_PI / 2**bits
    size = {}
    if effect == "wrap":
        inside = (t >= params["wrap_start_s"]) & (t < params["wrap_end_s"])
        counts = np.where(inside, wrap_counts(counts, bits), counts)
        jumps = np.abs(np.diff(counts)) > 2 ** (bits - 1)
        size.update(wrapped_samples=int(inside.sum()), wrap_jumps=int(jumps.sum()),
                    wrap_jump_times_s=(t[1:][jumps]).tolist()[:50])
    angle = counts * q
    dev = clean - X_nom[:, 2]
    size.update(rms_rad=float(np.sqrt(np.mean(dev**2))), max_abs_rad=float(np.max(np.abs(dev))),
                rms_counts=float(np.sqrt(np.mean(dev**2)) / q),
                max_abs_counts=float(np.max(np.abs(dev)) / q))
    if effect == "wrap":
        excited = size["wrap_jumps"] > 0 or bool(np.any(
            np.abs(counts * q - (clean + noise)) > PI))
    elif effect == "none":
        excited = False
    else:
        excited = size["max_abs_rad"] > q / 2
    rated = float(nom["rated_torque_nm"])
    tau_nom = drive_torque(nom, "none", {}, X_nom, u, fs_hz)
    u_held = np.concatenate([u[:1], u[:-1]])
    tau_inst = instantaneous_drive_torque(nom, effect, params, X, u_held)
    tau_noise = (np.random.default_rng([seed, _STREAM_TORQUE_NOISE]).normal(0.0, 1.0, n)
                 * torque_noise_nm)
    torque_permille, torque_nm = torque_reading(tau_clean, rated, tau_noise)
    tdev = tau_clean - tau_nom
    truth_torque = {
        "quantity": "drive torque actual value (CiA 402 object 0x6077), motor side",
        "units": "per mille of rated_torque_nm (object 0x6076), INTEGER16; torque_nm = "
                 "torque_permille * rated_torque_nm / 1000",
        "convention": TORQUE_CONVENTION,
        "rated_torque_nm": rated,
        "count_nm": rated / 1000.0,
        "noise_std_nm": torque_noise_nm,
        "motor_inertia_kg_m2": nom["motor_inertia_kg_m2"],
        "clipped_samples": int(np.sum((torque_permille == INT16_MIN)
                                      | (torque_permille == INT16_MAX))),
        "effect_size": {"rms_nm": float(np.sqrt(np.mean(tdev**2))),
                        "max_abs_nm": float(np.max(np.abs(tdev))),
                        "max_abs_counts": float(np.max(np.abs(tdev)) / (rated / 1000.0)),
                        "note": "clean drive torque minus that of the nominal twin"},
    }
    truth = {
        "effect": effect,
        "kind": spec.kind,
        "description": spec.description,
        "parameters": params,
        "parameter_ranges": {k: list(v) for k, v in spec.ranges.items()},
        "seed": seed,
        "excitation": exc_info,
        "duration_s": n / fs_hz,
        "fs_hz": fs_hz,
        "encoder_bits": bits,
        "count_rad": q,
        "noise_std_rad": noise_rad,
        "effect_size": size,
        "excited": bool(excited),
        "effect_size_note": ("deviation of the noise-free, unquantised sensor angle from the "
                             "nominal twin (same command, nominal initial state)"),
        "generator": "cleanroom drive_train_generator.py",
        "torque": truth_torque,
    }
    if effect == "gain_heating":
        truth["gain_error_series"] = gain_error.tolist()
        truth["gain_error_note"] = (
            "gain_error_series[k] = alpha T(t_k): angle = (1 + g) theta_l before noise and "
            "quantisation; T from C T' = s tau_out^2 - T/R, tau_out = gear_ratio x the clean "
            "cycle-mean drive torque, held over [t_k-1, t_k] (zero-order hold), integrated "
            "exactly; T(0) = 0")
    return {
        "time_s": t,
        "command_rad": u,
        "angle_rad": angle,
        "encoder_counts": counts,
        "clean_angle_rad": clean,
        "state": X,
        "nominal_state": X_nom,
        "nominal": nominal_description(nom, fs_hz, bits, noise_rad, torque_noise_nm),
        "truth": truth,
        "torque_permille": torque_permille,
        "torque_nm": torque_nm,
        "clean_torque_nm": tau_clean,
        "clean_torque_instant_nm": tau_inst,
        "nominal_torque_nm": tau_nom,
    }


TORQUE_CONVENTION = (
    "motor-side electromagnetic torque tau_out / N, positive in the direction of positive "
    "theta_m; sample k is its mean over the control cycle [t_k-1, t_k] (command u_k-1 held), "
    "= [J_m' (phi'_k - phi'_k-1) + J_l (theta_l'_k - theta_l'_k-1) + b (theta_l,k - "
    "theta_l,k-1) - int tau_effect dt] fs / N; sample 0 is the static torque under u_0. "
    "cascade: tau_out = K_v (K_p (u/N - phi) - phi'); kinematic: tau_out = J_m' phi'' + tau_s "
    "with J_m' = N^2 motor_inertia_kg_m2")


def nominal_description(nom: dict, fs_hz: float, bits: int, noise_rad: float,
                        torque_noise_nm: float = 0.0) -> dict:
    d = {k: v for k, v in nom.items()}
    if nom["servo"] == "kinematic":
        d["motor_inertia_note"] = ("kinematic servo: the motor inertia does not enter the "
                                   "motion; it is used only for the drive torque reading "
                                   "(tau_out = J_m' phi'' + tau_s)")
    d.update(
        sample_rate_hz=fs_hz,
        sample_period_s=1.0 / fs_hz,
        encoder_bits=bits,
        count_rad=TWO_PI / 2**bits,
        noise_std_rad=noise_rad,
        quantisation="round to nearest count (error within +-count/2), multi-turn",
        command="motor-side position, held between samples; load reference = command / gear_ratio",
        equations={
            "servo_kinematic": "theta_m'' = wc^2 (u - theta_m) - 2 zeta wc theta_m', "
                               "wc = 2 pi position_loop_bandwidth_hz; motor not loaded by shaft",
            "servo_cascade": "J_m' phi'' = K_v (K_p (u/N - phi) - phi') - tau_s, J_m' = N^2 J_m, "
                             "K_v = 2 zeta wc (J_m' + J_l), K_p = wc / (2 zeta)",
            "shaft": "tau_s = k (theta_m/N - theta_l) + c (theta_m'/N - theta_l')",
            "load": "J_l theta_l'' = tau_s - b theta_l'",
            "measurement": "angle = q round((theta_l + noise) / q), q = 2 pi / 2^bits",
            "drive_torque": "torque_permille = clip(round((tau_motor + noise) / "
                            "(rated_torque_nm / 1000)), -32768, 32767), tau_motor = tau_out / N "
                            "averaged over the control cycle ending at t_k",
        },
        torque_channel={"object": "0x6077 torque actual value, INTEGER16, per mille of "
                                  "rated torque (0x6076)",
                        "side": "motor",
                        "rated_torque_nm": nom["rated_torque_nm"],
                        "count_nm": nom["rated_torque_nm"] / 1000.0,
                        "noise_std_nm": torque_noise_nm,
                        "convention": TORQUE_CONVENTION},
        shaft_resonance_hz=math.sqrt(nom["shaft_stiffness_nm_per_rad"]
                                     / nom["load_inertia_kg_m2"]) / TWO_PI,
        effects="none (this is the model without any extra effect)",
    )
    return d


# ------------------------------------------------------------------------------ CLI
def write_record(rec: dict, out: str) -> None:
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "record.csv"), "w", newline="\n") as fh:
        fh.write("time_s,command_rad,angle_rad,encoder_counts,torque_nm,torque_permille\n")
        for t, u, y, c, tq, tp in zip(rec["time_s"], rec["command_rad"], rec["angle_rad"],
                                      rec["encoder_counts"], rec["torque_nm"],
                                      rec["torque_permille"]):
            fh.write(f"{float(t)!r},{float(u)!r},{float(y)!r},{int(c)},{float(tq)!r},{int(tp)}\n")
    with open(os.path.join(out, "truth.json"), "w") as fh:
        json.dump(rec["truth"], fh, indent=2)
        fh.write("\n")
    with open(os.path.join(out, "nominal.json"), "w") as fh:
        json.dump(rec["nominal"], fh, indent=2)
        fh.write("\n")


def _parse_value(s: str):
    try:
        return int(s)
    except ValueError:
        return float(s)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("effect", choices=sorted(EFFECTS))
    ap.add_argument("seed", type=int)
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument("--excitation", default="multisine", choices=EXCITATIONS)
    ap.add_argument("--duration", type=float, default=10.0, help="seconds (default 10)")
    ap.add_argument("--fs", type=float, default=1000.0, help="sample rate, Hz (default 1000)")
    ap.add_argument("--bits", type=int, default=12, help="encoder bits per revolution")
    ap.add_argument("--noise", type=float, default=0.0,
                    help="white noise std (rad), added before quantisation")
    ap.add_argument("--torque-noise", type=float, default=0.0,
                    help="drive torque white noise std (N m, motor side), added before "
                         "rounding to per mille of the rated torque")
    ap.add_argument("--amplitude", type=float, default=None,
                    help="excitation amplitude, rad (ramp: total travel)")
    ap.add_argument("--gear-ratio", type=float, default=None)
    ap.add_argument("--servo", choices=("kinematic", "cascade"), default=None)
    ap.add_argument("--nominal", action="append", default=[], metavar="KEY=VALUE",
                    help="override a nominal parameter (repeatable)")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                    help="fix an effect parameter instead of drawing it (repeatable)")
    a = ap.parse_args(argv)
    nominal = {}
    for kv in a.nominal:
        key, val = kv.split("=", 1)
        nominal[key] = val if key == "servo" else float(val)
    if a.gear_ratio is not None:
        nominal["gear_ratio"] = a.gear_ratio
    if a.servo is not None:
        nominal["servo"] = a.servo
    params = {}
    for kv in a.param:
        key, val = kv.split("=", 1)
        params[key] = _parse_value(val)
    rec = generate(a.effect, a.seed, excitation=a.excitation, duration_s=a.duration, fs_hz=a.fs,
                   bits=a.bits, noise_rad=a.noise, amplitude_rad=a.amplitude, nominal=nominal,
                   torque_noise_nm=a.torque_noise, **params)
    write_record(rec, a.out)
    s = rec["truth"]["effect_size"]
    print(f"{a.effect} seed {a.seed}: {len(rec['time_s'])} samples -> {a.out}; "
          f"effect rms {s['rms_rad']:.3g} rad ({s['rms_counts']:.2f} counts), "
          f"max {s['max_abs_rad']:.3g} rad; excited={rec['truth']['excited']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
