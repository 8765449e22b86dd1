"""Signatures a missing physical effect leaves in the free-run residual r_t = y_t - y^_t.

Each score is the fraction of the residual's energy sum r_t^2 that a characteristic regressor of the effect
explains by least squares (0: no sign of the effect, 1: the residual is exactly that signature), computed from
the measured input u_t, the measured output y_t and the model's simulated output y^_t:

* ``backlash``: r_t ~ c * s_t with s_t = the direction of the last motion of y^ (sign of the last nonzero
  increment): a residual that changes sign at direction reversals;
* ``coulomb_friction``: the same direction regressor, and (in the details) stick-slip: samples where the
  measured output is flat while the model moves, followed by a jump;
* ``dead_zone``: r_t ~ -clip(y^_t, -w, w) with w a tenth of the range: the output stuck near zero;
* ``saturation``: r_t ~ -(y^_t - clip(y^_t, -q, q)) with q the 85 % quantile of |y^|: residual growing with
  |u| at the extremes;
* ``delay``: r_t ~ y^_{t-d} - y^_t, the residual a model d samples early leaves, for the lag d = 1..59
  that explains most (``delay_samples`` in the details, with the lags of the largest cross-correlation of r
  with the model's velocity and with the input's increments u_t - u_{t-1});
* ``resonance``: the share of the residual's power (Welch spectrum) within three bins of its peak, and the
  peak frequency;
* ``offset``: r_t ~ o + drift * t T;
* ``gain_error``: r_t ~ e y^_t (the measured output is (1 + e) times the model's); the details give e;
* ``gain_drift``: r_t ~ e0 y^_t + dg (1 - exp(-t T / L)) y^_t, L the record's length: a gain that changes over
  the record;
* ``load_friction``: r_t ~ -c sign(v^_t), v^ the model's velocity: friction inside the dynamics holds the
  load back against its motion (a lag of constant size while it moves, the load left short where it stops);
* ``gravity``: r_t ~ alpha sin(y^_t) + beta cos(y^_t): a position-dependent load sags the output by
  -(m g l / (J omega_n^2)) sin(y^ - theta_0) (the details give the sag amplitude hypot(alpha, beta) and
  theta_0 = atan2(beta, alpha));
* ``rate_limit``: r_t ~ -T sum_{s<=t} (v^_s - clip(v^_s, -q, q)) with q the 85 % quantile of |v^| over the
  moving samples: the lag a speed limit accumulates while the model moves faster than it (the details give
  the model's and the measurement's peak speeds);
* ``torque_limit``: the same with the model's acceleration a^ and its 85 % quantile (the lag behind an
  acceleration limit is the double sum); the details give the model's peak acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal as scipy_signal

from identify.border_lifting import direction_signal
from identify.effect_catalogue import EFFECT_NAMES  # re-exported: the names live in the catalogue

__all__ = ["EFFECT_NAMES", "SignatureScore", "delay_regressor", "signature_scores"]



@dataclass(frozen=True)
class SignatureScore:
    """How strongly the residual shows one effect's signature."""

    effect: str
    score: float
    details: dict[str, Any] = field(default_factory=dict)


def _explained(residual: NDArray[np.float64], *regressors: NDArray[np.float64]) -> float:
    """Share of sum r^2 explained by least squares on ``regressors`` (no intercept unless given)."""
    energy = float(np.dot(residual, residual))
    if energy == 0.0:
        return 0.0
    phi = np.column_stack(regressors)
    if not np.any(phi):
        return 0.0
    theta, *_ = np.linalg.lstsq(phi, residual, rcond=None)
    left = residual - phi @ theta
    return float(max(0.0, 1.0 - float(np.dot(left, left)) / energy))


def delay_regressor(simulated_rad: NDArray[np.float64], lag_samples: int) -> NDArray[np.float64]:
    """y^_{t-d} - y^_t (held at y^_0 before the record): exactly the residual a model d = ``lag_samples``
    samples early leaves."""
    y_hat = np.asarray(simulated_rad, dtype=float)
    lag = min(max(int(lag_samples), 0), y_hat.size)
    return np.concatenate((np.full(lag, y_hat[0]), y_hat[: y_hat.size - lag])) - y_hat


def signature_scores(command_rad: NDArray[np.float64], angle_rad: NDArray[np.float64],
                     simulated_rad: NDArray[np.float64], noise_bound_rad: float,
                     sample_period_s: float) -> dict[str, SignatureScore]:
    """Score every effect of :data:`EFFECT_NAMES` on the residual (module docstring gives each regressor).

    Parameters
    ----------
    command_rad, angle_rad, simulated_rad
        u_t, the measured y_t (NaN where not measured) and the model's free-run y^_t, same length.
    noise_bound_rad
        delta, the bound on the measurement error.
    sample_period_s
        T.
    """
    y_hat = np.asarray(simulated_rad, dtype=float)
    y = np.asarray(angle_rad, dtype=float)
    y = np.where(np.isnan(y), y_hat, y)  # a sample not measured (NaN) has no residual: it shows no signature
    r = y - y_hat
    delta = float(noise_bound_rad)
    moving_threshold = max(1e-12, 1e-3 * float(np.ptp(y_hat)) / max(1.0, np.sqrt(y_hat.size)))
    direction = direction_signal(y_hat, threshold=moving_threshold)
    scores: dict[str, SignatureScore] = {}

    backlash = _explained(r, direction)
    reversals = int(np.count_nonzero(np.diff(direction) != 0))
    scores["backlash"] = SignatureScore("backlash", backlash, {"direction_reversals": reversals})
    # play between the inertias leaves the load on the side of the last direction too (it coasts on, or
    # stops within the play): the same regressor s_t; the fit, not this score, tells the two apart
    scores["shaft_play"] = SignatureScore("shaft_play", backlash, {"direction_reversals": reversals})
    # so does dry friction inside the shaft (the load stops up to T_h / k off, on the side it came from)
    scores["shaft_friction"] = SignatureScore("shaft_friction", backlash, {"direction_reversals": reversals})

    model_moves = np.abs(np.diff(y_hat)) > 2.0 * delta / 10.0
    measured_flat = np.abs(np.diff(y)) <= 2.0 * delta
    stuck = model_moves & measured_flat
    jumps = np.abs(np.diff(y)) > 4.0 * np.abs(np.diff(y_hat)) + 2.0 * delta
    stick_slip = int(np.count_nonzero(jumps[1:] & stuck[:-1]))
    scores["coulomb_friction"] = SignatureScore(
        "coulomb_friction", backlash * (1.0 if stick_slip else 0.5),
        {"stuck_while_model_moves_fraction": float(np.mean(stuck)), "stick_slip_jumps": stick_slip},
    )

    width = 0.1 * float(np.max(np.abs(y_hat))) if y_hat.size else 0.0
    scores["dead_zone"] = SignatureScore("dead_zone", _explained(r, np.clip(y_hat, -width, width)),
                                         {"band_rad": width})

    level = float(np.quantile(np.abs(y_hat), 0.85))
    scores["saturation"] = SignatureScore("saturation", _explained(r, y_hat - np.clip(y_hat, -level, level)),
                                          {"level_rad": level})

    velocity = np.diff(y_hat, prepend=y_hat[0])
    lags = np.arange(0, min(60, r.size // 4))
    centred = r - r.mean()
    correlation = [float(np.dot(centred[lag:], velocity[: velocity.size - lag])) for lag in lags]
    input_steps = np.diff(np.asarray(command_rad, dtype=float), prepend=float(command_rad[0]))
    input_correlation = [float(np.dot(centred[lag:], input_steps[: input_steps.size - lag])) for lag in lags]
    lagged = [_explained(r, delay_regressor(y_hat, int(lag))) for lag in lags[1:]]
    best_lag = 1 + int(np.argmax(lagged)) if lagged else 0
    scores["delay"] = SignatureScore("delay", max(lagged, default=0.0), {
        "delay_samples": best_lag,
        "lag_of_peak_correlation_samples": int(lags[int(np.argmax(np.abs(correlation)))]),
        "lag_of_peak_residual_input_correlation_samples": int(lags[int(np.argmax(np.abs(input_correlation)))]),
    })

    segment = min(r.size, 512)
    frequencies, power = scipy_signal.welch(centred, fs=1.0 / sample_period_s, nperseg=segment)
    if power.size > 8 and float(np.sum(power[1:])) > 0.0:
        peak = 1 + int(np.argmax(power[1:]))
        band = power[max(1, peak - 3): peak + 4]
        share = float(np.sum(band) / np.sum(power[1:]))
        narrow = float(power[peak] / max(np.median(power[1:]), 1e-300))
        scores["resonance"] = SignatureScore("resonance", share if narrow > 20.0 else 0.0,
                                             {"peak_frequency_hz": float(frequencies[peak]),
                                              "peak_to_median_power": narrow})
    else:
        scores["resonance"] = SignatureScore("resonance", 0.0, {})

    time_s = np.arange(r.size) * sample_period_s
    scores["offset"] = SignatureScore("offset", _explained(r, np.ones_like(r), time_s),
                                      {"mean_residual_rad": float(np.mean(r))})

    energy = float(np.dot(y_hat, y_hat))
    relative_error = float(np.dot(r, y_hat)) / energy if energy > 0.0 else 0.0
    scores["gain_error"] = SignatureScore("gain_error", _explained(r, y_hat), {"relative_error": relative_error})
    settling = -np.expm1(-time_s / max(r.size * sample_period_s, sample_period_s))
    scores["gain_drift"] = SignatureScore("gain_drift", _explained(r, y_hat, settling * y_hat), {})
    scores["encoder_error"] = _encoder_error_score(r, y_hat)
    scores.update(_drive_train_scores(y, y_hat, r, sample_period_s))
    return scores


def _encoder_error_score(r: NDArray[np.float64], y_hat: NDArray[np.float64]) -> SignatureScore:
    """A sensor error once and twice per revolution of the angle: r ~ c1 sin y^ + s1 cos y^ + c2 sin 2y^ +
    s2 cos 2y^ (least squares); ``details`` the four coefficients, the starts of the catalogue's fit."""
    regressors = (np.sin(y_hat), np.cos(y_hat), np.sin(2.0 * y_hat), np.cos(2.0 * y_hat))
    phi = np.column_stack(regressors)
    coefficients = np.linalg.lstsq(phi, r, rcond=None)[0] if np.any(r) else np.zeros(4)
    keys = ("sin_rad", "cos_rad", "sin2_rad", "cos2_rad")
    return SignatureScore("encoder_error", _explained(r, *regressors),
                          {key: float(value) for key, value in zip(keys, coefficients)})


def _drive_train_scores(y: NDArray[np.float64], y_hat: NDArray[np.float64], r: NDArray[np.float64],
                        period: float) -> dict[str, SignatureScore]:
    """The signatures of the drive-train effects (module docstring: ``load_friction`` .. ``torque_limit``)."""
    speed = np.gradient(y_hat) / period
    measured_speed = np.gradient(y) / period
    moving = np.abs(speed) > 1e-6 * max(float(np.max(np.abs(speed))), 1e-300)
    out = {"load_friction": SignatureScore("load_friction", _explained(r, -np.sign(speed) * moving), {})}
    sin, cos = np.sin(y_hat), np.cos(y_hat)
    theta, *_ = np.linalg.lstsq(np.column_stack((sin, cos)), r, rcond=None)
    out["gravity"] = SignatureScore("gravity", _explained(r, sin, cos), {
        "sag_amplitude_rad": float(np.hypot(theta[0], theta[1])),
        "hanging_angle_rad": float(np.arctan2(theta[1], -theta[0])) if np.any(theta) else 0.0})
    acceleration = np.gradient(speed) / period
    for name, rate, integrations in (("rate_limit", speed, 1), ("torque_limit", acceleration, 2)):
        level = float(np.quantile(np.abs(rate[moving]), 0.85)) if np.any(moving) else 0.0
        regressor = rate - np.clip(rate, -level, level)
        for _ in range(integrations):
            regressor = -np.cumsum(regressor) * period
        out[name] = SignatureScore(name, _explained(r, regressor), {
            "model_peak_rad_per_s" if integrations == 1 else "model_peak_rad_per_s2": float(np.max(np.abs(rate))),
            **({"measured_peak_rad_per_s": float(np.max(np.abs(measured_speed)))} if integrations == 1 else {})})
    return out
