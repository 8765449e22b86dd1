"""The settings of the workflow (:class:`DiagnoseOptions`), checked when built; their defaults are entries of
the threshold table (:mod:`.thresholds`).
"""

from __future__ import annotations

from dataclasses import dataclass

from identify.effect_catalogue import EFFECT_NAMES, SEARCHED_EFFECT_NAMES
from identify.validation import InvalidInputError

from identify.model_discrepancy.thresholds import (
    COMPLEXITY_PENALTY,
    CONSISTENT_FRACTION,
    ESTIMATION_FRACTION,
    MAX_DELAY_SAMPLES,
    MAX_EFFECTS,
    MAX_EVALUATIONS,
    MIN_REDUCTION,
)


@dataclass(frozen=True)
class DiagnoseOptions:
    """The settings of :func:`diagnose_model`, checked when built (an :class:`InvalidInputError` names the
    field). ``diagnose_model(u, y, delta, T, model, options)`` or the same fields as keywords.

    Attributes
    ----------
    estimation_fraction
        The first fraction of the record is the estimation segment, the rest the validation segment.
    candidates
        Effect names to try (default :data:`SEARCHED_EFFECT_NAMES`: all of :data:`EFFECT_NAMES` but those
        tried only as the look-alike of a named effect, the encoder error).
    max_effects
        Stop after this many effects.
    complexity_penalty
        A candidate's penalised gap is g_after (1 + penalty * n_parameters).
    min_reduction
        A candidate is kept only if g_after (1 + penalty n) <= (1 - min_reduction) g_before.
    consistent_fraction
        The model is consistent with the noise bound when at most this fraction of validation samples is
        falsified.
    max_delay_samples
        Longest delay tried.
    max_evaluations
        Function evaluations per least-squares polish.
    from_operating_point
        Start the free run from rest at the record's first command u_0, not from zero: when the record starts
        at rest (its first :data:`OPERATING_POINT_SAMPLES` angles within two noise bounds of each other) nearer
        u_0 than zero, and u_0 is further than :data:`OPERATING_POINT_MIN_NOISE_BOUNDS` noise bounds from zero,
        the workflow runs on u - u_0 and y - u_0, and the models it returns are wrapped as u_0 + M(u - u_0).
        Parameters of position-dependent effects (dead-zone edges, saturation limits) are then relative to u_0.
    """

    estimation_fraction: float = ESTIMATION_FRACTION
    candidates: tuple[str, ...] = SEARCHED_EFFECT_NAMES
    max_effects: int = MAX_EFFECTS
    complexity_penalty: float = COMPLEXITY_PENALTY
    min_reduction: float = MIN_REDUCTION
    consistent_fraction: float = CONSISTENT_FRACTION
    max_delay_samples: int = MAX_DELAY_SAMPLES
    max_evaluations: int = MAX_EVALUATIONS
    from_operating_point: bool = True

    def __post_init__(self) -> None:
        if not 0.2 <= self.estimation_fraction <= 0.9:
            raise InvalidInputError(f"estimation_fraction: expected 0.2 .. 0.9, got {self.estimation_fraction!r}")
        object.__setattr__(self, "candidates", tuple(self.candidates))
        unknown = [name for name in self.candidates if name not in EFFECT_NAMES]
        if unknown:
            raise InvalidInputError(f"candidates: unknown effect {unknown[0]!r}; expected some of "
                                    f"{', '.join(EFFECT_NAMES)}")
