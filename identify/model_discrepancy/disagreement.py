"""Step 2 of the workflow, the disagreement: the free-run residual r_t = y_t - y^_t of a model on the measured
command, the samples it falsifies (|r_t| > delta, the noise bound of eq. (4) of Cerone et al. 2009), the
windows where they cluster, and the validated gap g = sqrt(mean r_t^2) every later step compares.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.plant_blocks import PlantModel
from identify.validation import InvalidInputError, as_signal, positive, same_length

from identify.model_discrepancy.chain import _measured_error
from identify.model_discrepancy.result import Disagreement, DisagreementWindow
from identify.model_discrepancy.thresholds import (
    FAILED_RUN_ERROR_RAD,
    WINDOW_MERGE_GAP_SAMPLES,
    WINDOW_MIN_FALSIFIED_SAMPLES,
)


def _windows(falsified: NDArray[np.bool_], residual: NDArray[np.float64], merge_gap: int,
             min_falsified: int) -> tuple[DisagreementWindow, ...]:
    index = np.flatnonzero(falsified)
    if index.size == 0:
        return ()
    breaks = np.flatnonzero(np.diff(index) > merge_gap)
    starts = np.concatenate(([index[0]], index[breaks + 1]))
    stops = np.concatenate((index[breaks], [index[-1]])) + 1
    windows = []
    for start, stop in zip(starts.tolist(), stops.tolist()):
        count = int(np.count_nonzero(falsified[start:stop]))
        if count >= min_falsified:
            windows.append(DisagreementWindow(start, stop, count, float(np.max(np.abs(residual[start:stop])))))
    return tuple(windows)


def disagreement(model: PlantModel, command_rad: ArrayLike, angle_rad: ArrayLike, noise_bound_rad: float,
                 estimation_samples: int | None = None, *, merge_gap_samples: int = WINDOW_MERGE_GAP_SAMPLES,
                 min_window_samples: int = WINDOW_MIN_FALSIFIED_SAMPLES) -> Disagreement:
    """Free-run residual of ``model`` against the measurement and the samples it falsifies.

    A sample is falsified when |y_t - y^_t| > delta, the noise bound of eq. (4) of Cerone et al. (2009):
    no admissible noise sequence can explain it. Falsified samples less than ``merge_gap_samples`` apart
    form one window; windows with fewer than ``min_window_samples`` falsified samples are dropped.

    Parameters
    ----------
    model
        The model, simulated from rest on the whole command.
    command_rad, angle_rad
        u_t and the measured y_t; NaN marks a sample not measured: its residual is 0, it is never falsified,
        and the fraction and the gap are over the measured samples.
    noise_bound_rad
        delta > 0.
    estimation_samples
        Samples before the validation segment; the fraction and gap are computed on the rest
        (default: 0, the whole record).
    """
    u = as_signal("command_rad", command_rad, min_samples=2)
    y = as_signal("angle_rad", angle_rad, min_samples=2, missing_allowed=True)
    same_length(command_rad=u, angle_rad=y)
    delta = positive("noise_bound_rad", noise_bound_rad)
    start = 0 if estimation_samples is None else int(estimation_samples)
    if not 0 <= start < u.size:
        raise InvalidInputError(f"estimation_samples: expected 0 <= n < {u.size}, got {estimation_samples!r}")
    simulated = np.asarray(model.simulate(u), dtype=float)
    residual = _measured_error(y, simulated)
    if not np.all(np.isfinite(residual)):
        residual = np.where(np.isfinite(residual), residual, FAILED_RUN_ERROR_RAD)
    falsified = np.abs(residual) > delta
    tail = residual[start:]
    measured = max(int(np.count_nonzero(~np.isnan(y[start:]))), 1)  # the fraction and gap of measured samples
    return Disagreement(
        simulated_rad=simulated,
        residual_rad=residual,
        falsified=falsified,
        falsified_fraction=float(np.count_nonzero(falsified[start:]) / measured),
        gap_rad=float(np.sqrt(np.sum(tail * tail) / measured)),
        windows=_windows(falsified, residual, merge_gap_samples, min_window_samples),
    )
