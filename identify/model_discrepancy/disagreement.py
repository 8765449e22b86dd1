"""Step 2 of the workflow, the disagreement: the free-run residual r_t = y_t - y^_t of a model on the measured
command, the samples it falsifies (|r_t| > delta, the noise bound of eq. (4) of Cerone et al. 2009), the
windows where they cluster, and the validated gap g = sqrt(mean r_t^2) every later step compares; and before
any model runs, the gross disagreements of the measurement with itself over the whole record
(:func:`gross_disagreements`: a sensor wrap, glitches), which no model effect can explain.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.plant_blocks import PlantModel
from identify.validation import InvalidInputError, as_signal, positive, same_length

from identify.model_discrepancy import comparison
from identify.model_discrepancy.chain import _measured_error
from identify.model_discrepancy.result import Disagreement, DisagreementWindow, GrossDisagreement
from identify.model_discrepancy.thresholds import (
    FAILED_RUN_ERROR_RAD,
    GLITCH_ISOLATION_SAMPLES,
    GLITCH_MAX_SAMPLES,
    GLITCH_MIN_NOISE_BOUNDS,
    WRAP_JUMP_TOLERANCE_RAD,
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
    """Residual of ``model`` against the measurement (its free run, or its restarted run under
    :func:`.comparison.restarted_every`) and the samples it falsifies.

    A sample is falsified when |y_t - y^_t| > delta, the noise bound of eq. (4) of Cerone et al. (2009):
    no admissible noise sequence can explain it. Falsified samples less than ``merge_gap_samples`` apart
    form one window; windows with fewer than ``min_window_samples`` falsified samples are dropped.

    Parameters
    ----------
    model
        The model, run on the whole command (from rest, or restarted: :mod:`.comparison`).
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
    simulated = comparison.simulated(model, u, y)
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


def _runs(mask: NDArray[np.bool_]) -> tuple[tuple[int, int], ...]:
    """The [start, stop) runs of True in ``mask``."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return tuple(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def _wraps(u: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Whole turns to add to each sample to undo a sensor wrap (0 where none): a jump of the measured angle
    between consecutive measured samples within :data:`WRAP_JUMP_TOLERANCE_RAD` of +-2 pi while the command
    moves less than half a turn there. The turns are counted from the most common level, so the samples a
    wrap moved are the minority (a record that starts wrapped is put right too)."""
    measured = np.flatnonzero(~np.isnan(y))
    turns = np.zeros(y.size)
    if measured.size < 2:
        return turns
    step = np.diff(y[measured])
    command_step = np.abs(u[measured[1:]] - u[measured[:-1]])
    whole = np.round(step / (2.0 * np.pi))
    wrapped = ((whole != 0) & (np.abs(step - 2.0 * np.pi * whole) <= WRAP_JUMP_TOLERANCE_RAD)
               & (command_step < np.pi))
    if not np.any(wrapped):
        return turns
    level = np.concatenate(([0.0], np.cumsum(np.where(wrapped, -whole, 0.0))))
    values, counts = np.unique(level, return_counts=True)
    level -= values[int(np.argmax(counts))]
    turns[measured] = level
    if measured[0] > 0:
        turns[:measured[0]] = level[0]
    # an unmeasured sample takes the level of the measured sample before it
    filled = np.maximum.accumulate(np.where(~np.isnan(y), np.arange(y.size), 0))
    return turns[filled]


def _glitches(y: NDArray[np.float64], delta: float) -> NDArray[np.bool_]:
    """Samples of isolated spikes: a run of at most :data:`GLITCH_MAX_SAMPLES` measured samples each more than
    :data:`GLITCH_MIN_NOISE_BOUNDS` noise bounds from the straight line between the measured samples around
    it, on the same side, those two within a quarter of the smallest departure of each other, and the reading
    smooth for :data:`GLITCH_ISOLATION_SAMPLES` on each side (its second differences under a quarter of the
    departure)."""
    spike = np.zeros(y.size, dtype=bool)
    measured = np.flatnonzero(~np.isnan(y))
    values = y[measured]
    limit = GLITCH_MIN_NOISE_BOUNDS * delta
    n = values.size
    for length in range(1, GLITCH_MAX_SAMPLES + 1):
        if n < length + 2:
            break
        before, after = values[:n - length - 1], values[length + 1:]
        smallest = np.full(before.size, np.inf)
        sign = np.zeros(before.size)
        same_side = np.ones(before.size, dtype=bool)
        for k in range(1, length + 1):
            line = before + (after - before) * k / (length + 1)
            departure = values[k:n - length - 1 + k] - line
            if k == 1:
                sign = np.sign(departure)
            else:
                same_side &= np.sign(departure) == sign
            smallest = np.minimum(smallest, np.abs(departure))
        found = same_side & (smallest > limit) & (np.abs(after - before) <= 0.25 * smallest)
        for start in np.flatnonzero(found):
            # isolated: around it the reading is smooth (its second differences, centred on the samples
            # outside the run and its two neighbours, stay under a quarter of the departure); an oscillation
            # makes many short excursions side by side, a glitch one
            left = values[max(start - GLITCH_ISOLATION_SAMPLES - 1, 0):start + 1]
            right = values[start + length + 1:start + length + GLITCH_ISOLATION_SAMPLES + 3]
            rough = max((float(np.max(np.abs(np.diff(side, 2)))) for side in (left, right) if side.size >= 3),
                        default=0.0)
            if rough <= 0.25 * smallest[start]:
                spike[measured[start + 1:start + 1 + length]] = True
    return spike


def gross_disagreements(command_rad: ArrayLike, angle_rad: ArrayLike, noise_bound_rad: float
                        ) -> tuple[tuple[GrossDisagreement, ...], NDArray[np.float64]]:
    """The gross disagreements of a measurement with itself, over the whole record, and the record with them
    put aside: a sensor wrap (jumps of 2 pi between consecutive samples, :data:`WRAP_JUMP_TOLERANCE_RAD`)
    undone by whole turns, and glitches (isolated spikes, :data:`GLITCH_MIN_NOISE_BOUNDS`,
    :data:`GLITCH_MAX_SAMPLES`) marked not measured (NaN).

    They are found on the measurement alone, before any model runs (a start model fitted to a wrapped
    record would be fitted to the wrap), and are measurement-side findings: no effect of the model explains
    them, so a record that has them is never ``explained``.

    Parameters
    ----------
    command_rad, angle_rad
        u_t and the measured y_t; NaN marks a sample not measured.
    noise_bound_rad
        delta > 0.

    Returns
    -------
    findings, angle_rad
        The findings (a wrap first, then glitches; empty when none) and the angle with them put aside.
    """
    u = as_signal("command_rad", command_rad, min_samples=2)
    y = as_signal("angle_rad", angle_rad, min_samples=2, missing_allowed=True)
    same_length(command_rad=u, angle_rad=y)
    delta = positive("noise_bound_rad", noise_bound_rad)
    findings = []
    turns = _wraps(u, y)
    if np.any(turns != 0):
        findings.append(GrossDisagreement("sensor_wrap", _runs(turns != 0)))
        y = y + 2.0 * np.pi * turns
    spikes = _glitches(y, delta)
    if np.any(spikes):
        findings.append(GrossDisagreement("glitch", _runs(spikes)))
        y = np.where(spikes, np.nan, y)
    return tuple(findings), y
