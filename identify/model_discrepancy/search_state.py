"""The state the search carries from round to round and hands to the checks after it (:mod:`.search`,
:mod:`.left_open`): the model so far, its disagreement, the effects added, and what was left open."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from identify.model_discrepancy.chain import _Chain
from identify.model_discrepancy.result import CandidateResult, Disagreement, DiscrepancyStep


@dataclass
class _Search:
    """The state of the greedy search of step 4 (the model so far, its disagreement, the effects added)."""

    chain: _Chain
    current: Disagreement
    steps: list[DiscrepancyStep]
    tried: list[CandidateResult]
    ambiguous_between: tuple[str, ...] = ()
    validation_error_rad: NDArray[np.float64] | None = None
    undecided: tuple[CandidateResult, ...] = ()
    look_alike_reason: str = ""
    """Set when a named effect was dropped for a look-alike the record cannot separate from it
    (:func:`_look_alikes_checked`): the verdict's reason."""
    mechanism_reason: str = ""
    """Set when a named effect's map is also another mechanism's (:func:`_mechanisms_left_open`): said after
    what the named map explains."""
    beyond_device_reason: str = ""
    """Set when a bounded look-alike would give a named effect's output only at a size no working device has
    (catalogue ``bounded_look_alikes``, :func:`_look_alikes_checked`): said after the verdict, so that the user
    who has such a device knows what else the record allows."""
