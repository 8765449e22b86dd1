"""The drive's torque as a second measured channel: it shows a weight on the load that the angle alone cannot
tell from a sensor error.

From the angle alone, a torque ~ sin of the load angle (gravity) and a once-per-revolution encoder error look
alike behind a stiff servo (:func:`~identify.model_discrepancy.left_open._look_alikes_checked`): the weight only
deflects the load by its torque over the stiffness. The drive must supply the weight's torque and never feels
the sensor's error, so the torque it reports (the CiA 402 torque actual value, object 0x6077, or a current
reading in any unit) tells the two apart.

The check (:func:`load_torque_check`) fits the torque record, by least squares, with

.. math::

    \\tau_k = \\sum_{i=0}^{L} a_i \\hat y_{k-i} + \\sum_{i=0}^{L} d_i u_{k-i} + c
              + T_s \\sin \\hat y_k + T_c \\cos \\hat y_k + e_k,

where u is the command and y^ the start model's free run (the harmonic of the model's angle, not of the
measured one, whose own disagreement, a play's lag say, would leak into it). For a plant whose torque is a
linear function of its state and command (motor and load inertias, shaft, servo), the lagged command and model
output span that function exactly once L reaches the plant's order (:data:`TORQUE_LAGS`), so what the lags
cannot take is the torque the start model does not hold: T = |(T_s, T_c)| is the once-per-revolution torque
beyond the straight line in the angle that the lags (which hold y^ itself) take, i.e. a sine's bend. The torque
the fit leaves must then be noise (:func:`_colour`): a torque that only projects on the harmonic over the
angles the record covers (cogging, a friction's or a play's) leaves the rest of itself. The angle's own
disagreement with the start model, r = y - y^, is fitted with a constant and the same harmonic, S its
amplitude. Standard deviations are from the Newey-West (Bartlett) covariance over :data:`TORQUE_HAC_WINDOW_S`
of lags, since neither residual is white.

A weight hanging at theta_0 pulls with -m g l sin(theta - theta_0), the drive holds it with +m g l sin(theta -
theta_0), and the load sags by -C m g l sin(theta - theta_0) (C > 0 the static compliance of servo and shaft):
the torque's harmonic and the angle's are in opposite phase. The outcome is ``load_torque`` when both harmonics
are :data:`TORQUE_SIGNIFICANT_SIGMAS` standard deviations from zero, in opposite phase within
:data:`TORQUE_PHASE_TOLERANCE_RAD`, and the torque left is no more coloured than
:data:`TORQUE_MAX_RESIDUAL_COLOUR`.

The torque's absence alone does not exclude a weight: with a torque under T + 3 sigma, a weight would need a
compliance of at least S / (T + 3 sigma), and neither the angle nor the drive's torque bounds the compliance from
above (a light load on a soft shaft rings at the same frequency as a heavy one on a stiff shaft). A start model
with physical units does: the weight the workflow fitted to the sag in its drive train (gravity's m g l at the
load), over the train's gear ratio and the record's N m per unit of torque, is the torque W such a weight puts
on the drive. The outcome is ``no_load_torque`` when the sag is there and T + :data:`TORQUE_ABSENT_SIGMAS` sigma
stays under W / :data:`TORQUE_EXCLUSION_MARGIN`: no weight the model's servo and shaft would sag so is carried,
unless they are that many times softer than the model says. Else ``undecided``, and the text gives the least
compliance a weight would need, for a user who knows the shaft.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.plant_blocks import PlantModel
from identify.result_format import number
from identify.model_discrepancy.open_world import delayed_columns
from identify.model_discrepancy.thresholds import (
    TORQUE_ABSENT_SIGMAS,
    TORQUE_EXCLUSION_MARGIN,
    TORQUE_HAC_WINDOW_S,
    TORQUE_LAGS,
    TORQUE_MAX_RESIDUAL_COLOUR,
    TORQUE_PHASE_TOLERANCE_RAD,
    TORQUE_SIGNIFICANT_SIGMAS,
)

OUTCOMES = ("load_torque", "no_load_torque", "undecided")
SAG_LOOK_ALIKES = ("encoder_error", "offset", "gain_error", "gain_drift")
"""The sensor errors that read like a weight's sag: a once-per-revolution error (gravity's look-alike in the
catalogue), and over a short span of angles an offset and a gain error (the sine's value and slope there), or a
gain and zero that drift (a slope and a value that change over the record: on a weight's steps, what the steps'
sags leave). The drive feels none of them: they are not tried again once its torque shows the weight."""


@dataclass(frozen=True)
class LoadTorqueCheck:
    """What the drive's torque says of a once-per-revolution load torque (module docstring).

    Attributes
    ----------
    outcome
        One of :data:`OUTCOMES`.
    torque, torque_sigma
        T, the once-per-revolution torque in the drive's torque beyond the start model's, and its standard
        deviation (the torque record's unit).
    torque_hanging_angle_rad
        The angle a weight giving that torque would hang at (the torque is zero and rising there).
    residual_colour
        The torque's residual after the fit, its variance over half that of its differences (:func:`_colour`):
        about 1 when the weight was all that was missing, far above for cogging, a play's or a friction's torque.
    sag_rad, sag_sigma_rad
        S, the angle's once-per-revolution disagreement with the start model, and its standard deviation.
    sag_hanging_angle_rad
        The angle a weight giving that sag would hang at.
    weight_torque
        W, the once-per-revolution torque a weight giving that sag would put on the drive (the torque record's
        unit), from a start model with physical units (module docstring); NaN where it has none.
    """

    outcome: str
    torque: float
    torque_sigma: float
    torque_hanging_angle_rad: float
    residual_colour: float
    sag_rad: float
    sag_sigma_rad: float
    sag_hanging_angle_rad: float
    weight_torque: float = math.nan

    @property
    def phase_apart_rad(self) -> float:
        """How far apart the hanging angles of the torque and of the sag are (0 for a weight)."""
        return abs(math.remainder(self.torque_hanging_angle_rad - self.sag_hanging_angle_rad, 2.0 * math.pi))

    def text(self) -> str:
        figures = (f"the drive's torque holds {self.torque:.3g} +- {self.torque_sigma:.2g} once per revolution "
                   f"(a weight hanging at {self.torque_hanging_angle_rad:.2f} rad), the angle sags by "
                   f"{self.sag_rad:.3g} +- {self.sag_sigma_rad:.2g} rad (hanging at {self.sag_hanging_angle_rad:.2f} rad)")
        if self.outcome == "load_torque":
            return (f"{figures}: the drive carries the weight that sags the angle, {self.sag_rad / self.torque:.3g} rad "
                    "per unit of torque, so the sag is a load torque, not the sensor's")
        bound = self.torque + TORQUE_ABSENT_SIGMAS * self.torque_sigma
        if self.outcome == "no_load_torque":
            return (f"{figures}: a weight sagging the angle so through the start model's servo and shaft would put "
                    f"{self.weight_torque:.3g} on the drive, which shows under {bound:.3g}, less than 1/"
                    f"{TORQUE_EXCLUSION_MARGIN:g} of it: no weight is carried (unless servo and shaft are more than "
                    f"{TORQUE_EXCLUSION_MARGIN:g} times softer than the model says), so the sag is the sensor's")
        if self.residual_colour > TORQUE_MAX_RESIDUAL_COLOUR:
            return (f"{figures}; the torque left beside it is not noise (its variance {self.residual_colour:.3g} times "
                    "what its sample-to-sample steps give white noise): another torque (cogging, friction, a play) is "
                    "there, or the drive filters its reading, so a weight alone is not shown")
        if self.sag_rad < TORQUE_SIGNIFICANT_SIGMAS * self.sag_sigma_rad:
            return f"{figures}: the sag is not resolved, so the torque cannot be matched to it"
        if self.torque >= TORQUE_SIGNIFICANT_SIGMAS * self.torque_sigma:
            return f"{figures}: the torque is not in phase with the sag, so it does not explain it"
        return (f"{figures}: no weight shows in the torque; one under {bound:.3g} would need a compliance of at least "
                f"{self.sag_rad / bound:.3g} rad per unit of torque to sag the angle so, which a stiffer servo and "
                "shaft exclude (the sag is then the sensor's)")

    def to_dict(self) -> dict[str, Any]:
        return {name: (getattr(self, name) if name == "outcome" else number(getattr(self, name))) for name in _FIELDS}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LoadTorqueCheck:
        """From :meth:`to_dict`; a document without ``weight_torque`` (written before it was known) has NaN."""
        return cls(**{name: (data[name] if name == "outcome" else float(data[name])) for name in _FIELDS
                      if name in data})


_FIELDS = ("outcome", "torque", "torque_sigma", "torque_hanging_angle_rad", "residual_colour", "sag_rad",
           "sag_sigma_rad", "sag_hanging_angle_rad", "weight_torque")


def load_torque_check(u: NDArray[np.float64], y: NDArray[np.float64], torque: NDArray[np.float64],
                      start_model: PlantModel, period: float, weight_torque: float = math.nan) -> LoadTorqueCheck:
    """The check of the module docstring on one record (absolute angles; NaN marks a sample not measured, in
    the angle or the torque); ``weight_torque``: W, where the start model gives it."""
    y_hat = np.asarray(start_model.simulate(u), dtype=float)
    window = max(1, int(round(TORQUE_HAC_WINDOW_S / period)))
    usable = np.isfinite(y) & np.isfinite(torque)
    usable[:TORQUE_LAGS] = False
    angle = y_hat[usable]
    harmonic = np.column_stack([np.sin(angle), np.cos(angle)])
    design = np.column_stack([delayed_columns((y_hat, u), range(TORQUE_LAGS + 1))[usable], np.ones(angle.size), harmonic])
    coefficients, covariance, residual = _hac_least_squares(design, torque[usable], window)
    torque_amplitude, torque_sigma, torque_phase = _harmonic(coefficients[-2:], covariance[-2:, -2:])
    sag_design = np.column_stack([np.ones(angle.size), harmonic])
    sag_coefficients, sag_covariance, _ = _hac_least_squares(sag_design, (y - y_hat)[usable], window)
    sag, sag_sigma, sag_phase = _harmonic(sag_coefficients[1:], sag_covariance[1:, 1:])
    # T_s sin y + T_c cos y = T sin(y + p) = T sin(y - theta_0): a weight at theta_0 = -p in the torque, and at
    # theta_0 = pi - p in the angle (which sags by -C m g l sin(y - theta_0))
    check = LoadTorqueCheck("undecided", torque_amplitude, torque_sigma, math.remainder(-torque_phase, 2.0 * math.pi),
                            _colour(residual), sag, sag_sigma,
                            math.remainder(math.pi - sag_phase, 2.0 * math.pi), float(weight_torque))
    sagged = sag >= TORQUE_SIGNIFICANT_SIGMAS * sag_sigma
    carried = (sagged and torque_amplitude >= TORQUE_SIGNIFICANT_SIGMAS * torque_sigma
               and check.residual_colour <= TORQUE_MAX_RESIDUAL_COLOUR
               and check.phase_apart_rad <= TORQUE_PHASE_TOLERANCE_RAD)
    if carried:
        return replace(check, outcome="load_torque")
    if sagged and torque_amplitude + TORQUE_ABSENT_SIGMAS * torque_sigma < weight_torque / TORQUE_EXCLUSION_MARGIN:
        return replace(check, outcome="no_load_torque")  # (a NaN weight_torque compares False)
    return check


def _harmonic(pair: NDArray[np.float64], covariance: NDArray[np.float64]) -> tuple[float, float, float]:
    """Amplitude, its standard deviation and phase p of a sin y + b cos y = A sin(y + p)."""
    amplitude = math.hypot(pair[0], pair[1])
    direction = pair / amplitude if amplitude > 0.0 else np.array([1.0, 0.0])
    sigma = math.sqrt(max(float(direction @ covariance @ direction), 0.0))
    return amplitude, sigma, math.atan2(pair[1], pair[0])


def _colour(residual: NDArray[np.float64]) -> float:
    """The residual's variance over half the variance of its sample-to-sample differences: 1 for white noise,
    far above it for a torque the fit leaves that changes slower than the sampling (cogging passing the shaft
    mode, a play's, a friction's), or for a reading the drive filtered."""
    steps = np.diff(residual)
    denominator = 0.5 * float(steps @ steps) / steps.size
    return float(np.var(residual)) / denominator if denominator > 0.0 else math.inf


def _hac_least_squares(design: NDArray[np.float64], target: NDArray[np.float64],
                       window: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Least squares with the Newey-West (Bartlett kernel) covariance of the coefficients over ``window`` lags;
    the columns are scaled to unit norm first (the lags are nearly collinear)."""
    scale = np.linalg.norm(design, axis=0)
    scale[scale == 0.0] = 1.0
    scaled = design / scale
    coefficients, *_ = np.linalg.lstsq(scaled, target, rcond=None)
    residual = target - scaled @ coefficients
    inverse = np.linalg.pinv(scaled.T @ scaled)
    moments = scaled * residual[:, None]
    meat = moments.T @ moments
    for lag in range(1, min(window, residual.size - 1) + 1):
        weight = 1.0 - lag / (window + 1.0)
        cross = moments[lag:].T @ moments[:-lag]
        meat += weight * (cross + cross.T)
    covariance = inverse @ meat @ inverse
    return coefficients / scale, covariance / np.outer(scale, scale), residual
