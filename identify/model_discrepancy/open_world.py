"""Step 7 of the workflow, the open-world check: how much structure the final model's residual still holds, and
whether the named effects are the whole story.

The catalogue is closed; the plant is not. After the verdict, a small black box of the residual is fitted on the
estimation segment and judged on the validation segment: least squares of r_t = y_t - y^_t on signals the model
side knows (:func:`black_box_features`): the command and the model's output at a few lags (a linear mismatch, a
mode), the direction of the model's motion (a hysteresis), harmonics of the model's angle (anything periodic in
the position: gravity, cogging, a sensor error), a constant and a ramp (an offset, a drift). The share of the
validated residual's mean square it predicts on samples it never saw is structure the final model left. The
measured angle is never a regressor: r = y - y^ would be predicted from itself.

The verdict says it (:func:`open_world_checked`):

* named effects with structure left: "Y % of the disagreement remains unexplained; a black box predicts Z % of
  what remains" is added to the reason, so a named effect is never presented as the whole story;
* when the black box predicts most of what remains (:data:`OPEN_WORLD_NOT_WHOLE_STORY`), or takes more off
  the remaining gap than the named effects took off the start model's, the record holds something the
  catalogue lacks and the named effects may only stand in for it: the verdict is lowered to ``ambiguous`` (the
  fitted effects stay in the model, with the reason);
* a record where nothing was added says how much structure its disagreement has (unexplained: structure the
  catalogue does not hold; ambiguous: as the candidates left open would).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from identify.model_discrepancy.result import Disagreement, DiscrepancyStep, ResidualStructure
from identify.model_discrepancy.thresholds import (
    OPEN_WORLD_HARMONICS,
    OPEN_WORLD_LAGS,
    OPEN_WORLD_MIN_EXPLAINED,
    OPEN_WORLD_NOT_WHOLE_STORY,
)

__all__ = ["black_box_features", "open_world_checked", "residual_structure"]


def delayed_columns(signals: tuple[NDArray[np.float64], ...], lags: tuple[int, ...] | range) -> NDArray[np.float64]:
    """Each signal delayed by each of ``lags`` samples, one column each (signal by signal), the first samples
    repeating the signal's first value (the record was at rest before it began)."""
    n = signals[0].size
    return np.column_stack([np.concatenate((np.full(lag, signal[0]), signal[:n - lag])) if lag else signal
                            for signal in signals for lag in lags])


def black_box_features(u: NDArray[np.float64], simulated: NDArray[np.float64]) -> NDArray[np.float64]:
    """The black box's regressors, one column each (module docstring): u and y^ delayed by each of
    :data:`OPEN_WORLD_LAGS` samples (the first samples repeat the first value), the sign of y^'s last move
    (held while y^ rests), sin and cos of k y^ for k = 1 .. :data:`OPEN_WORLD_HARMONICS`, 1 and t / N."""
    n = u.size
    columns = list(delayed_columns((u, simulated), OPEN_WORLD_LAGS).T)
    moves = np.sign(np.diff(simulated, prepend=simulated[0]))
    direction = np.zeros(n)
    if np.any(moves):  # the last direction of motion, held through rests
        held = np.maximum.accumulate(np.where(moves != 0, np.arange(n), -1))
        direction = np.where(held >= 0, moves[np.maximum(held, 0)], 0.0)
    columns.append(direction)
    for k in range(1, OPEN_WORLD_HARMONICS + 1):
        columns += [np.sin(k * simulated), np.cos(k * simulated)]
    columns += [np.ones(n), np.arange(n) / n]
    return np.column_stack(columns)


def residual_structure(u: NDArray[np.float64], y: NDArray[np.float64], final: Disagreement,
                       n_est: int) -> ResidualStructure:
    """The black box of ``final``'s residual: fitted on the estimation segment's measured samples, judged on the
    validation segment's (module docstring). Columns are scaled to unit RMS before the least squares (the lags
    of u and y^ are nearly collinear; ``lstsq`` drops what the data cannot resolve)."""
    measured = ~np.isnan(y)
    residual = np.where(measured, final.residual_rad, 0.0)
    features = black_box_features(u, final.simulated_rad)
    scale = np.sqrt(np.mean(features[:n_est] ** 2, axis=0))
    features = features / np.where(scale > 0, scale, 1.0)
    fit_rows = np.flatnonzero(measured[:n_est])
    check_rows = n_est + np.flatnonzero(measured[n_est:])
    theta, *_ = np.linalg.lstsq(features[fit_rows], residual[fit_rows], rcond=1e-9)
    held_out = residual[check_rows]
    left = held_out - features[check_rows] @ theta
    gap = float(np.sqrt(np.mean(held_out ** 2))) if held_out.size else 0.0
    after = float(np.sqrt(np.mean(left ** 2))) if left.size else 0.0
    explained = 1.0 - (after / gap) ** 2 if gap > 0 else 0.0
    return ResidualStructure(max(0.0, explained), gap, min(after, gap))


def open_world_checked(verdict: str, reason: str, u: NDArray[np.float64], y: NDArray[np.float64],
                       initial: Disagreement, final: Disagreement, steps: Sequence[DiscrepancyStep],
                       consistent: bool, n_est: int) -> tuple[str, str, ResidualStructure | None]:
    """The verdict and reason with what the black box of the final residual says (module docstring), and the
    black box's result (None for a record the final model already explains, or not judged)."""
    if consistent or verdict not in ("named", "ambiguous", "unexplained"):
        return verdict, reason, None
    structure = residual_structure(u, y, final, n_est)
    if structure.explained_fraction < OPEN_WORLD_MIN_EXPLAINED:
        return verdict, reason, structure
    predicted = (f"a black box of the command, the model's output and its angle, fitted on the estimation "
                 f"segment, predicts {100 * structure.explained_fraction:.0f} % of the remaining residual's mean "
                 f"square on the validation segment (gap {structure.gap_rad:.3g} -> "
                 f"{structure.gap_after_black_box_rad:.3g} rad)")
    if not steps:  # ambiguous: the candidates left open may hold that structure; unexplained: none does
        what = ("as the candidates left open would" if verdict == "ambiguous" else
                "the disagreement has structure the catalogue does not hold")
        return verdict, f"{reason}; {predicted}: {what}", structure
    named = ", ".join(step.effect for step in steps)
    remains = final.gap_rad / initial.gap_rad if initial.gap_rad > 0 else 1.0
    said = f"{reason}; {100 * remains:.0f} % of the validated gap remains unexplained after {named}: {predicted}"
    named_took = initial.gap_rad - final.gap_rad
    black_box_took = structure.gap_rad - structure.gap_after_black_box_rad
    if verdict == "named" and (structure.explained_fraction >= OPEN_WORLD_NOT_WHOLE_STORY
                               or black_box_took > named_took):
        how_much = (f"more than {named} took off the start model's gap ({named_took:.3g} rad)"
                    if black_box_took > named_took else "most of what remains")
        return "ambiguous", (f"{said}, {how_much}: the record holds an effect outside the catalogue, which {named} "
                             "may only stand in for, so it is not named as the whole story (the fitted model keeps "
                             "it)"), structure
    return verdict, f"{said}: an effect outside the catalogue may be there as well", structure
