"""The steady-state points of a filtered-staircase log (Cerone, Piga, Regruto 2009, Section 3): at the end of
every half-wave, the command and the last usable angle of the settled tail.

One definition for every reader of such a log: ``rig identify output-backlash --steady``, ``rig trend`` and
``rig demo`` (which bounds the backlash from its own staircase log, so that the command it states gives the
same points).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.experiment_config import REPEAT_FILTERED

__all__ = ["STEADY_TAIL_FRACTION", "StaircasePlan", "StaircaseSteadyPoints", "staircase_plan", "staircase_steady_samples"]

STEADY_TAIL_FRACTION = 0.1
"""The last 10 % of a half-wave is at steady state: a LOST end sample is replaced by the last valid sample in
that tail."""


@dataclass(frozen=True)
class StaircaseSteadyPoints:
    """The steady-state points of a staircase log: ``ends`` the last sample of each half-wave that has a
    usable settled tail, ``taken`` the sample whose angle was used (the last usable one of the tail),
    ``command_rad`` ū and ``angle_rad`` ȳ there; ``unusable_ends``: the half-waves whose whole tail was
    unusable (left out when asked, else refused); ``wrapped_ends``: the first half-wave after each wrap of an
    excitation repeated sample by sample (left out when asked)."""

    ends: Any
    taken: Any
    command_rad: Any
    angle_rad: Any
    unusable_ends: Any
    samples_per_half_wave: int
    tail: int
    wrapped_ends: Any = ()


@dataclass(frozen=True)
class StaircasePlan:
    """Where a staircase log's steady-state points fall: ``ends`` the last sample of each half-wave within one
    cycle of ``cycle`` samples (the excitation as logged: cut or repeated), ``tail`` the settled tail of each
    half-wave (its last :data:`STEADY_TAIL_FRACTION`) in which the last usable angle is the point's, and
    ``steps_at_wrap`` whether the command steps unfiltered from the last level to the first at each repetition
    (an excitation repeated sample by sample, ``rig run --duration``: the first half-wave after a wrap is no
    steady state)."""

    ends: Any
    cycle: int
    samples_per_half_wave: int
    tail: int
    steps_at_wrap: bool

    def after_wrap(self, indices: Any) -> Any:
        """Which of the half-wave ends ``indices`` (sample numbers of the log) are the first after a wrap that
        steps (all False where none does)."""
        import numpy as np

        indices = np.asarray(indices)
        return (indices >= self.cycle) & (indices % self.cycle == self.ends[0]) & self.steps_at_wrap


def staircase_plan(config: Any, path: Path | str) -> StaircasePlan:
    """The :class:`StaircasePlan` of a log's metadata ``config`` (``config.excitation``: kind filtered_staircase,
    ``samples_per_half_wave``, ``amplitudes_rad``; ``config.excitation_samples`` when the log cuts or repeats the
    excitation); ``path`` names the log in errors."""
    from collections.abc import Mapping

    from identify.excitation_design import staircase_steady_state_indices

    config = config if isinstance(config, Mapping) else {}
    excitation = config.get("excitation") if isinstance(config.get("excitation"), Mapping) else {}
    kind = excitation.get("kind")
    parameters = excitation.get("parameters") if isinstance(excitation.get("parameters"), Mapping) else {}
    if kind != "filtered_staircase":
        raise ValueError(
            f"{path}: --steady takes the log of the steady_staircase experiment (excitation kind "
            f"filtered_staircase), but this log's excitation is {kind or 'not recorded'} (metadata config.excitation"
            "): record it with `rig run --experiment configs/experiments/steady_staircase.toml`, or give a CSV "
            "with one u, y row per steady-state point")
    try:
        half = int(parameters["samples_per_half_wave"])
        count = len(parameters["amplitudes_rad"])
        ends = staircase_steady_state_indices(count, half)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path}: the metadata's config.excitation.parameters lack samples_per_half_wave or "
                         f"amplitudes_rad ({type(err).__name__}: {str(err)[:80]}); the log was not written by "
                         "`rig run` or `rig simulate`") from None
    cycle = int(config.get("excitation_samples") or (ends[-1] + 1))
    steps = cycle == ends[-1] + 1 and config.get("excitation_repeat") != REPEAT_FILTERED
    return StaircasePlan(ends, cycle, half, max(1, int(STEADY_TAIL_FRACTION * half)), steps)


def staircase_steady_samples(record, path: Path, *, skip_unusable: bool = False,
                             skip_after_wrap: bool = False) -> StaircaseSteadyPoints:
    """The steady-state points of the staircase log ``record`` read from ``path`` (named in errors): the
    half-wave ends from its metadata (:func:`staircase_plan`), and at each the last usable angle of the settled
    tail. A tail without a usable sample is refused naming its line, or with ``skip_unusable`` left out and
    listed. With ``skip_after_wrap`` the first half-wave after each repetition of an excitation repeated sample
    by sample (``rig run --duration``) is left out and listed: the command steps there unfiltered from the last
    level to the first, the inner signal overshoots and the output stops inside the dead band (a log whose
    ``config.excitation_repeat`` says the staircase was filtered across repetitions has no such step)."""
    import numpy as np

    plan = staircase_plan(record.metadata.config, path)
    half, tail = plan.samples_per_half_wave, plan.tail
    n = len(record)
    indices = np.concatenate([plan.ends + start for start in range(0, n, plan.cycle)])
    indices = indices[indices < n]
    wrapped = np.empty(0, dtype=np.int64)
    if skip_after_wrap:
        after_wrap = plan.after_wrap(indices)
        wrapped, indices = indices[after_wrap], indices[~after_wrap]
    if indices.size < 2:
        raise ValueError(f"{path}: the log holds {n} samples, fewer than two half-waves of {half} samples: run "
                         "the whole staircase")
    valid = record.valid_mask
    # the last usable sample of each tail [end - tail + 1, end]: the running index of the last usable sample
    last_usable = np.maximum.accumulate(np.where(valid, np.arange(n), -1))
    taken = last_usable[indices]
    usable = taken >= indices - tail + 1
    if not np.all(usable) and not skip_unusable:
        position = int(np.flatnonzero(~usable)[0])
        index = int(indices[position])
        raise ValueError(f"{path}: line {index + 5} and the {tail - 1} samples before it (the settled tail of "
                         f"half-wave {position + 1}) are all LOST or unusable: no steady-state value there; "
                         "record the staircase again")
    kept = indices[usable]
    return StaircaseSteadyPoints(kept, taken[usable], record.command_rad[kept], record.angle_rad[taken[usable]],
                                 indices[~usable], half, tail, wrapped)
