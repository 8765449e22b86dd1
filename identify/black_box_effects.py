"""Which effects of the catalogue can be added around a black-box model (an FMU).

A black box is a block the workflow cannot look inside: it has an input and an output and nothing else
(``black_box = True`` on the block, as :class:`sim_backend.fmu_plant.FmuBlock` sets it). The
model-discrepancy workflow adds an effect in series (:mod:`identify.effect_catalogue`, ``Effect.placement``):

* ``"input"`` effects (dead zone, saturation, delay) are maps of the command: they go before the black box's
  input;
* ``"output"`` effects (backlash, Coulomb friction as the catalogue models it, a stick-slip twist after the
  drive; a resonance, a mode between the gearbox and the encoder) and ``"end"`` effects (offset and drift,
  gain error) act on what the black box gives: they go after its output.

An effect that sits *inside* the dynamics (any other placement: an effect realised by changing or replacing
the model's linear dynamics or its drive train, such as friction on the load's own inertia, play between two
inertias, gravity on the load, a torque limit) cannot be added to a model whose dynamics it cannot see;
those are skipped with the reason :func:`effects_around_black_box` states.

With a chain that has no linear block of its own (the black box alone), the workflow's placement rule
(``_insert_index`` of :mod:`identify.model_discrepancy.candidates`) already puts ``input`` effects at the front and the
others at the end, so this module only chooses the candidates.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from identify.effect_catalogue import SEARCHED_EFFECT_NAMES, effect
from identify.plant_blocks import PlantModel

__all__ = ["AROUND_BLACK_BOX", "effects_around_black_box", "is_black_box", "placements_text"]

AROUND_BLACK_BOX = {
    "input": "before the model's input",
    "output": "after the model's output",
    "end": "after the model's output, at the very end",
}
"""The placements an effect can have around a black box, and where that puts it."""


def is_black_box(model: PlantModel | None) -> bool:
    """True when ``model`` holds a block that declares itself a black box (``black_box = True``)."""
    return model is not None and any(getattr(block, "black_box", False) for block in model.blocks)


def effects_around_black_box(candidates: Iterable[str] = SEARCHED_EFFECT_NAMES) -> tuple[tuple[str, ...], dict[str, str]]:
    """Split ``candidates`` into those that can be added around a black box and those that cannot.

    Returns the names that can (in their order) and, for each one that cannot, the reason in words."""
    kept: list[str] = []
    skipped: dict[str, str] = {}
    for name in candidates:
        placement = effect(name).placement
        if placement in AROUND_BLACK_BOX:
            kept.append(name)
        else:
            skipped[name] = (f"sits inside the model's dynamics (placement {placement!r}): it cannot be added around a "
                             "black box; model it inside the FMU, or describe the plant as a TOML drive train")
    return tuple(kept), skipped


def placements_text(names: Sequence[str]) -> dict[str, str]:
    """For each of ``names`` that can be added around a black box, where it goes (for the command's output)."""
    return {name: AROUND_BLACK_BOX[effect(name).placement] for name in names
            if effect(name).placement in AROUND_BLACK_BOX}
