"""Linear dynamics handed to python-control (``pip install control``; not a dependency of this package): the
identified models' linear parts as its discrete-time ``TransferFunction``, for the field's tools (Bode plots,
margins, controller design)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["discrete_transfer_function", "require_control"]


def require_control(what: str) -> Any:
    """The ``control`` module, or ImportError saying that ``what`` needs it and how to install it."""
    try:
        import control
    except ImportError as err:
        raise ImportError(f"{what} needs python-control, which is not installed: pip install control") from err
    return control


def discrete_transfer_function(numerator_q: Sequence[float], denominator_q: Sequence[float], dt: float | bool,
                               what: str) -> Any:
    """``control.TransferFunction`` of B(q^-1) / A(q^-1) (coefficients of q^0, q^-1, ...; A's first is not 0)
    with sample time ``dt`` (True: discrete, period unspecified). Both are padded to one length, which makes
    them the coefficients of the same powers of z, highest first."""
    control = require_control(what)
    order = max(len(numerator_q), len(denominator_q))
    numerator = [float(v) for v in numerator_q] + [0.0] * (order - len(numerator_q))
    denominator = [float(v) for v in denominator_q] + [0.0] * (order - len(denominator_q))
    return control.tf(numerator, denominator, dt)
