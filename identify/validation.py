"""Checks on user-supplied signals and parameters, shared by every method in ``identify``.

Every failure raises :class:`InvalidInputError` (a ``ValueError``) whose message names the argument,
the offending sample where there is one, and what was expected, so that a user never has to read a
traceback from inside numpy or scipy.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

F = TypeVar("F", bound=Callable[..., Any])


class InvalidInputError(ValueError):
    """An argument given to an identification routine cannot be used as it is."""


OptionsT = TypeVar("OptionsT")


def with_options(function_name: str, options: OptionsT | None, defaults: Callable[[], OptionsT],
                 option_values: Mapping[str, Any]) -> OptionsT:
    """The settings of a function that takes an options dataclass or its fields as keywords: ``options``
    (or ``defaults()``) with ``option_values`` replacing fields. A keyword that is no field raises the
    TypeError Python gives for an unexpected keyword, listing the fields."""
    base = options if options is not None else defaults()
    names = [field.name for field in dataclasses.fields(base)]  # type: ignore[arg-type]
    unknown = sorted(set(option_values) - set(names))
    if unknown:
        raise TypeError(f"{function_name}() got an unexpected keyword argument {unknown[0]!r} (the options are "
                        f"{', '.join(names)})")
    return dataclasses.replace(base, **option_values)  # type: ignore[type-var]


def as_signal(name: str, values: ArrayLike, *, min_samples: int = 1, missing_allowed: bool = False) -> NDArray[np.float64]:
    """Return ``values`` as a finite 1-D float array, or raise naming ``name`` and the bad sample.

    With ``missing_allowed``, NaN marks a sample that was not measured (a LOST sample of
    :class:`identify.experiment_record.ExperimentRecord`, or one its flags make unusable) and is kept; an
    infinite value is still refused.

    Parameters
    ----------
    name
        The argument's public name, used in the error message.
    values
        Anything numpy can turn into a 1-D array of floats.
    min_samples
        The fewest samples the caller can work with.
    missing_allowed
        Keep NaN (a sample not measured); the caller sets those samples aside.
    """
    try:
        signal = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"{name}: expected a 1-D array of numbers, got {type(values).__name__}") from err
    if signal.ndim != 1:
        raise InvalidInputError(f"{name}: expected a 1-D array, got shape {signal.shape}")
    if signal.size < min_samples:
        raise InvalidInputError(f"{name}: expected at least {min_samples} samples, got {signal.size}")
    if missing_allowed and signal.size and np.all(np.isnan(signal)):
        raise InvalidInputError(f"{name}: all {signal.size} samples are missing (NaN): nothing was measured")
    bad = np.flatnonzero(np.isinf(signal) if missing_allowed else ~np.isfinite(signal))
    if bad.size:
        raise InvalidInputError(
            f"{name}: sample {bad[0]} is {signal[bad[0]]} ({bad.size} non-finite samples in all); "
            "remove or interpolate them before identification"
        )
    return signal


def same_length(**signals: NDArray[np.float64]) -> int:
    """Return the common length of ``signals`` or raise naming the lengths that differ."""
    lengths = {name: len(signal) for name, signal in signals.items()}
    if len(set(lengths.values())) > 1:
        described = ", ".join(f"{name} has {n}" for name, n in lengths.items())
        raise InvalidInputError(f"signals must have the same number of samples: {described}")
    return next(iter(lengths.values()))


def finite(name: str, value: float) -> float:
    """Return ``value`` as a float if it is a finite number, else raise naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"{name}: expected a number, got {value!r}") from err
    if not np.isfinite(number):
        raise InvalidInputError(f"{name}: expected a finite number, got {value!r}")
    return number


def finite_coefficients(name: str, values: Any) -> tuple[float, ...]:
    """Return ``values`` as a tuple of floats if each is a finite number, else raise naming ``name[index]``."""
    try:
        numbers = tuple(float(v) for v in values)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"{name}: expected a sequence of numbers, got {values!r}") from err
    for index, number in enumerate(numbers):
        if not np.isfinite(number):
            raise InvalidInputError(f"{name}[{index}]: expected a finite number, got {number!r}")
    return numbers


def positive(name: str, value: float) -> float:
    """Return ``value`` as a float if it is finite and > 0, else raise naming ``name``."""
    number = float(value)
    if not np.isfinite(number) or number <= 0.0:
        raise InvalidInputError(f"{name}: expected a finite number > 0, got {value!r}")
    return number


def varying(name: str, signal: NDArray[np.float64], what_to_do: str) -> NDArray[np.float64]:
    """Return ``signal`` if it takes more than one value; a constant input excites nothing, so no method can
    identify from it (the error names the signal, its value and ``what_to_do``)."""
    if signal.size and np.ptp(signal) == 0.0:
        raise InvalidInputError(f"{name}: the input is constant ({float(signal[0]):g} in all {signal.size} samples), "
                                f"so it excites nothing; {what_to_do}")
    return signal


def renamed_parameters(**new_of_old: str) -> Callable[[F], F]:
    """Accept the documented old keyword names of a function's parameters (``u=`` for ``input_rad=``) with a
    DeprecationWarning; positional calls are unchanged. ``@renamed_parameters(u="input_rad")``."""
    def decorate(function: F) -> F:
        @functools.wraps(function)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            for old, new in new_of_old.items():
                if old in kwargs:
                    if new in kwargs:
                        raise TypeError(f"{function.__name__}() got both {old}= and {new}=; {old} is the old name")
                    warnings.warn(f"{function.__name__}({old}=...) is deprecated: the parameter is now {new}",
                                  DeprecationWarning, stacklevel=2)
                    kwargs[new] = kwargs.pop(old)
            return function(*args, **kwargs)
        return wrapper  # type: ignore[return-value]
    return decorate
