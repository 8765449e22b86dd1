"""Experiment configs (``configs/experiments/*.toml``): which excitation to send, how long, with which seed.

The signals come from ``identify``'s generators, so the rig sends exactly what the methods were designed
for: :func:`identify.excitation_design.prbs_sequence` (the PRBS of Cerone et al. 2009, Section 4),
:func:`identify.excitation_design.filtered_staircase` (the filtered square-wave staircase of their
Section 3.1 and Appendix) and :func:`identify.cyclic_excitation.cyclic_random_excitation` (Table I of
Pouliquen et al. 2013). The format::

    name = "prbs"                        # optional (default: the file name)
    description = "..."                  # optional
    seed = 7                             # seed of the excitation's random generator

    [excitation]
    kind = "prbs"                        # prbs | filtered_staircase | cyclic_random
    num_samples = 100                    # the generator's own arguments (see EXCITATION_KINDS' readers)
    amplitude_rad = 1.0

``filtered_staircase`` takes ``amplitudes_rad = [...]`` or ``amplitude_min_rad``, ``amplitude_max_rad`` and
``num_amplitudes`` (equally spaced), plus ``filter_pole``, ``samples_per_half_wave`` and optionally
``filter_order`` and ``shuffle``; ``cyclic_random`` takes ``num_samples``, ``u_min``, ``u_max`` and optionally
``hold_samples`` and ``samples_per_step``; ``prbs`` takes ``num_samples``, ``amplitude_rad`` and optionally
``register_bits``.

Every key is validated (unknown keys are rejected) and errors name the file and the key.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from identify.validation import InvalidInputError
from rig.protocols.config_schema import ConfigTable, load_toml

if TYPE_CHECKING:
    from rig.command_source import CommandSource

__all__ = ["EXCITATION_KINDS", "Excitation", "load_experiment_config"]


REPEAT_FILTERED = "reference, filtered across repetitions"
"""``config.excitation_repeat`` of a log whose staircase was repeated before its filter
(:meth:`Excitation.repeated`): no unfiltered step at the wraps."""
REPEAT_SAMPLES = "samples"
"""``config.excitation_repeat`` of a log whose excitation was repeated sample by sample."""


@dataclass(frozen=True)
class Excitation:
    """A generated excitation and what is needed to generate it again.

    ``streamed``: a command read from disk as it is sent (a CSV command file), too long maybe to hold; then
    ``command_rad`` holds only its first chunk, and :attr:`cycle_samples` is its length."""

    name: str
    kind: str
    command_rad: NDArray[np.float64]
    seed: int | None
    parameters: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    source: str = "<memory>"
    streamed: CommandSource | None = None

    @property
    def cycle_samples(self) -> int:
        """The samples of one pass of the excitation (before :meth:`repeated` cuts or repeats it)."""
        if self.streamed is not None and self.streamed.num_samples is not None:
            return self.streamed.num_samples
        return int(self.command_rad.size)

    def metadata(self) -> dict[str, Any]:
        """What a log records about the excitation."""
        return {"name": self.name, "kind": self.kind, "seed": self.seed, "parameters": dict(self.parameters),
                "source": self.source}

    @property
    def repetition(self) -> str:
        """How :meth:`repeated` repeats this excitation (a log's ``config.excitation_repeat``)."""
        return REPEAT_FILTERED if self.kind == "filtered_staircase" else REPEAT_SAMPLES

    def stream(self, num_samples: int | None) -> CommandSource:
        """The command of :meth:`repeated` as a :class:`~rig.command_source.CommandSource`, produced a chunk at
        a time as a run sends it (``num_samples`` None: repeated until the run is stopped), so that a run of
        hours holds a few thousand samples of it at a time. The same samples as :meth:`repeated`.

        Raises
        ------
        InvalidInputError
            ``num_samples`` < 1, or a staircase whose parameters no longer generate its command.
        """
        from rig.command_source import ArrayCommand, CyclicCommand, FilteredRepeatCommand, RepeatedSource

        count = None if num_samples is None else int(num_samples)
        if count is not None and count < 1:
            raise InvalidInputError(f"num_samples: expected at least 1, got {num_samples!r}")
        if self.streamed is not None:
            return self.streamed if count == self.streamed.num_samples else RepeatedSource(self.streamed, count)
        if count is not None and count <= self.command_rad.size:
            return ArrayCommand(self.command_rad[:count])
        if self.kind != "filtered_staircase":
            return CyclicCommand(self.command_rad, count)
        reference = self._staircase_reference()
        source = FilteredRepeatCommand(reference, float(self.parameters["filter_pole"]),
                                       int(self.parameters.get("filter_order", 1)), count)
        if not np.array_equal(source.head(self.command_rad.size), self.command_rad):  # one cycle: bounded
            raise InvalidInputError(f"{self.source}: the staircase could not be generated again from its "
                                    "parameters; repeat it with fewer samples than one cycle")
        return source

    def _staircase_reference(self) -> NDArray[np.float64]:
        """The unfiltered square-wave reference of a filtered staircase, its amplitudes in the order used."""
        from identify.excitation_design import staircase_reference

        amplitudes = np.asarray(self.parameters["amplitudes_rad"], dtype=float)
        if self.parameters.get("shuffle"):
            amplitudes = np.random.default_rng(self.seed).permutation(amplitudes)  # the order generated
        return staircase_reference(amplitudes, int(self.parameters["samples_per_half_wave"]))

    def repeated(self, num_samples: int) -> NDArray[np.float64]:
        """The command cut, or repeated cyclically, to ``num_samples`` samples.

        A filtered staircase is repeated before its filter: the square-wave reference (with the amplitudes in
        the order this excitation used) is repeated and filtered once, so the command stays filtered across
        each repetition and every cycle's samples are those of the first after the filter has settled.
        Repeating the filtered samples themselves would step the command from the last level back to 0
        unfiltered at each wrap: the inner signal overshoots there and the first half-wave after it is no
        steady-state point of eqs. (11)-(12) of Cerone et al. (2009). Other excitations repeat as they are.
        """
        count = int(num_samples)
        if count < 1:
            raise InvalidInputError(f"num_samples: expected at least 1, got {num_samples!r}")
        if self.streamed is not None:
            return self.stream(count).to_array()
        if self.kind != "filtered_staircase" or count <= self.command_rad.size:
            return np.resize(self.command_rad, count)
        from identify.excitation_design import lowpass_filter

        reference = self._staircase_reference()
        repeats = -(-count // reference.size)
        command = lowpass_filter(np.tile(reference, repeats), float(self.parameters["filter_pole"]),
                                 int(self.parameters.get("filter_order", 1)))[:count]
        if not np.array_equal(command[:self.command_rad.size], self.command_rad):
            raise InvalidInputError(f"{self.source}: the staircase could not be generated again from its "
                                    "parameters; repeat it with fewer samples than one cycle")
        return command


def _prbs(table: ConfigTable, rng: np.random.Generator) -> tuple[NDArray[np.float64], dict[str, Any]]:
    from identify.excitation_design import prbs_sequence

    parameters = {"num_samples": table.integer("num_samples", minimum=1),
                  "amplitude_rad": table.number("amplitude_rad", minimum=0.0, exclusive_minimum=True)}
    if table.has("register_bits"):
        parameters["register_bits"] = table.integer("register_bits", minimum=2, maximum=32)
    return _call(table, prbs_sequence, parameters, rng), parameters


def _filtered_staircase(table: ConfigTable, rng: np.random.Generator) -> tuple[NDArray[np.float64], dict[str, Any]]:
    from identify.excitation_design import filtered_staircase

    if table.has("amplitudes_rad"):
        amplitudes = table.numbers("amplitudes_rad", min_length=1)
    else:  # M amplitudes equally spaced, as in Section 6 (50 values from 0.6 to 3)
        low = table.number("amplitude_min_rad", minimum=0.0, exclusive_minimum=True)
        high = table.number("amplitude_max_rad", minimum=low)
        count = table.integer("num_amplitudes", minimum=1)
        amplitudes = np.linspace(low, high, count).tolist()
    parameters = {"amplitudes_rad": amplitudes,
                  "filter_pole": table.number("filter_pole", minimum=0.0),
                  "samples_per_half_wave": table.integer("samples_per_half_wave", minimum=1),
                  "filter_order": table.integer("filter_order", 1, minimum=1),
                  "shuffle": table.boolean("shuffle", False)}
    return _call(table, filtered_staircase, parameters, rng), parameters


def _cyclic_random(table: ConfigTable, rng: np.random.Generator) -> tuple[NDArray[np.float64], dict[str, Any]]:
    from identify.cyclic_excitation import cyclic_random_excitation

    parameters = {"num_samples": table.integer("num_samples", minimum=1),
                  "u_min": table.number("u_min"), "u_max": table.number("u_max"),
                  "hold_samples": table.integer("hold_samples", 0, minimum=0),
                  "samples_per_step": table.integer("samples_per_step", 1, minimum=1)}
    arguments = {"u_min": "input_min_rad", "u_max": "input_max_rad"}  # the config keys keep the paper's letters
    return _call(table, cyclic_random_excitation, parameters, rng, arguments), parameters


EXCITATION_KINDS: dict[str, Callable[[ConfigTable, np.random.Generator], tuple[NDArray[np.float64], dict[str, Any]]]] = {
    "prbs": _prbs,
    "filtered_staircase": _filtered_staircase,
    "cyclic_random": _cyclic_random,
}
"""``kind`` in ``[excitation]`` -> reader that validates the keys and calls identify's generator."""


def _call(table: ConfigTable, function: Callable[..., Any], parameters: dict[str, Any],
          rng: np.random.Generator, arguments: dict[str, str] | None = None) -> NDArray[np.float64]:
    """``function(**parameters, rng=rng)``, a config key renamed to the parameter ``arguments`` maps it to; an
    InvalidInputError becomes the config error of the key it names."""
    arguments = arguments or {}
    try:
        signal = function(**{arguments.get(key, key): value for key, value in parameters.items()}, rng=rng)
    except InvalidInputError as err:
        named = str(err).split(":", 1)[0].split(",")[0].strip()
        key = {parameter: key for key, parameter in arguments.items()}.get(named, named)
        raise table.error(key if key in parameters else "<table>", str(err)) from err
    return np.asarray(signal, dtype=float)


def load_experiment_config(path: str | Path, seed: int | None = None) -> Excitation:
    """Read an experiment config and generate its excitation; ``seed`` overrides the file's ``seed``.

    Raises :class:`~rig.protocols.errors.ConfigError` naming the file and key on any invalid entry.
    """
    root = load_toml(path)
    name = root.string("name", Path(path).stem)
    description = root.string("description", "")
    file_seed = root.integer("seed", None, minimum=0)
    table = root.table("excitation")
    kind = table.string("kind", choices=tuple(EXCITATION_KINDS))
    used_seed = seed if seed is not None else file_seed
    rng = np.random.default_rng(used_seed)
    if used_seed is None:
        used_seed = int(rng.bit_generator.seed_seq.entropy % (1 << 63))  # record the drawn seed
        rng = np.random.default_rng(used_seed)
    command, parameters = EXCITATION_KINDS[kind](table, rng)
    table.finish()
    root.finish()
    if command.ndim != 1 or command.size == 0 or not np.all(np.isfinite(command)):
        raise root.error("excitation", f"the {kind} generator returned no usable signal (shape {command.shape})")
    return Excitation(name=name, kind=kind, command_rad=command, seed=used_seed, parameters=parameters,
                      description=description, source=str(path))
