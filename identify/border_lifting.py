"""Lifting of a backlash or switch input into a linear regression, Section II-B of Pouliquen et al. (2013).

With the direction signal δ(t) and continuous piecewise-linear paths (eq. (3)), the output of an input
backlash or switch driven by the cyclic excitation of Table I is linear in the node slopes μ (eq. (4))::

    H[u(t)] = μ0 + μ z(t),  z(t) = [P_1^a(u) δ, ..., P_na^a(u) δ, P_1^d(u) (1-δ), ..., P_nd^d(u) (1-δ)]

This module builds δ(t), the basis functions P_i and z(t) for any node placement (the ascending and
descending paths may have different nodes, Remark 3), and checks that a recorded input follows the cyclic
design closely enough for the lifting to hold (:func:`check_cyclic_input`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.validation import InvalidInputError, as_signal

__all__ = [
    "PathNodes",
    "uniform_nodes",
    "direction_signal",
    "path_indicator",
    "piecewise_linear_basis",
    "lifted_input",
    "check_cyclic_input",
]

CYCLIC_REQUIREMENT = (
    "The method needs a cyclic excitation that sweeps from u_min up to u_max and back down again, many times, "
    "through every segment of both paths (configs/experiments/hammerstein_cyclic.toml, Table I of Pouliquen et "
    "al. 2013): step or PRBS data that hold a few levels in between do not"
)
"""What every complaint about the shape of the input adds: the record is not the excitation the method is for."""


def _nodes(name: str, values: ArrayLike) -> tuple[float, ...]:
    nodes = as_signal(name, values, min_samples=2)
    steps = np.diff(nodes)
    if np.any(steps <= 0.0):
        bad = int(np.flatnonzero(steps <= 0.0)[0]) + 1
        raise InvalidInputError(
            f"{name}: expected strictly increasing nodes, node {bad} is {float(nodes[bad])} after {float(nodes[bad - 1])}"
        )
    return tuple(float(v) for v in nodes)


@dataclass(frozen=True)
class PathNodes:
    """The nodes n_0 < n_1 < ... of the ascending and descending paths (eq. (3), Remark 3).

    Both paths start at u_min and end at u_max (the working interval of the identification); the interior
    nodes, and their number, may differ between the paths.

    Parameters
    ----------
    ascending, descending
        Node positions, each with ``ascending[0] == descending[0] == u_min`` and the same last node u_max.
    """

    ascending: tuple[float, ...]
    descending: tuple[float, ...]

    def __post_init__(self) -> None:
        ascending = _nodes("ascending_nodes", self.ascending)
        descending = _nodes("descending_nodes", self.descending)
        if ascending[0] != descending[0] or ascending[-1] != descending[-1]:
            raise InvalidInputError(
                "ascending_nodes, descending_nodes: both paths must span the same interval [u_min; u_max], got "
                f"[{ascending[0]}; {ascending[-1]}] and [{descending[0]}; {descending[-1]}]"
            )
        object.__setattr__(self, "ascending", ascending)
        object.__setattr__(self, "descending", descending)

    @classmethod
    def uniform(cls, input_min_rad: float, input_max_rad: float, num_nodes: int) -> PathNodes:
        """``num_nodes`` equally spaced nodes on [u_min; u_max] = [``input_min_rad``; ``input_max_rad``] for
        both paths (n_p = num_nodes - 1)."""
        nodes = uniform_nodes(input_min_rad, input_max_rad, num_nodes)
        return cls(tuple(nodes), tuple(nodes))

    @property
    def u_min(self) -> float:
        """u_min, the first node of both paths [rad]."""
        return self.ascending[0]

    @property
    def u_max(self) -> float:
        """u_max, the last node of both paths [rad]."""
        return self.ascending[-1]

    @property
    def num_lifted_inputs(self) -> int:
        """Dimension of z(t): n_p^a + n_p^d (2 n_p in the paper)."""
        return len(self.ascending) + len(self.descending) - 2


def uniform_nodes(input_min_rad: float, input_max_rad: float, num_nodes: int) -> NDArray[np.float64]:
    """``num_nodes`` equally spaced nodes from u_min = ``input_min_rad`` to u_max = ``input_max_rad``
    inclusive (n_p + 1 nodes, eq. (3))."""
    low, high = float(input_min_rad), float(input_max_rad)
    if not (np.isfinite(low) and np.isfinite(high) and low < high):
        raise InvalidInputError(f"input_min_rad, input_max_rad: expected finite numbers with input_min_rad < "
                                f"input_max_rad, got {input_min_rad!r}, {input_max_rad!r}")
    if int(num_nodes) != num_nodes or num_nodes < 2:
        raise InvalidInputError(f"num_nodes: expected an integer >= 2 (u_min and u_max at least), got {num_nodes!r}")
    nodes = np.linspace(low, high, int(num_nodes))
    nodes[-1] = high
    return nodes


def direction_signal(values: ArrayLike, *, threshold: float = 0.0) -> NDArray[np.float64]:
    """s_t in {-1, 0, +1}: the sign of the last increment of ``values`` up to t larger than ``threshold`` (in
    the unit of ``values``) in
    size (0 before the first). The one direction of motion of the package: the paper's δ(t)
    (:func:`path_indicator`) and the backlash and friction signatures of :mod:`identify.effect_signatures`
    both read it.

    Parameters
    ----------
    values
        The signal (a command, or a model's output).
    threshold
        Increments of at most this size are no motion (0: any change is; use a small positive value for
        a signal with rounding noise).
    """
    signal = np.asarray(values, dtype=float)
    if signal.size == 0:
        return np.zeros(0)
    steps = np.diff(signal, prepend=signal[0])
    sign = np.where(steps > threshold, 1.0, np.where(steps < -threshold, -1.0, np.nan))
    sign[0] = 0.0 if np.isnan(sign[0]) else sign[0]
    index = np.where(~np.isnan(sign), np.arange(sign.size), 0)
    np.maximum.accumulate(index, out=index)
    return sign[index]


def path_indicator(input_rad: ArrayLike, *, initial_direction: int = 0) -> NDArray[np.int8]:
    """δ(t) of Section II-B: 1 if u(t) > u(t-1), 0 if u(t) < u(t-1), δ(t-1) if u(t) = u(t-1); that is, 1 on
    the ascending path and 0 on the descending one (:func:`direction_signal` +1 and -1).

    Parameters
    ----------
    input_rad
        The input signal u.
    initial_direction
        δ(-1), used until the input first moves (0: the input came down to u(0), as at the end of a Table I
        cycle or a hold at u_min).
    """
    signal = as_signal("input_rad", input_rad)
    if initial_direction not in (0, 1):
        raise InvalidInputError(f"initial_direction: expected 0 (descending) or 1 (ascending), got {initial_direction!r}")
    direction = direction_signal(signal)
    return np.where(direction == 0.0, initial_direction, direction > 0.0).astype(np.int8)


def piecewise_linear_basis(input_rad: ArrayLike, nodes: ArrayLike) -> NDArray[np.float64]:
    """P_i(u(t)), i = 1..n_p, of eq. (3): 0 below n_{i-1}, u - n_{i-1} on the segment, n_i - n_{i-1} above.

    Returns
    -------
    ndarray, shape (len(input_rad), len(nodes) - 1)
    """
    signal = as_signal("input_rad", input_rad)
    node_array = np.asarray(_nodes("nodes", nodes))
    return np.clip(signal[:, None] - node_array[None, :-1], 0.0, np.diff(node_array)[None, :])


def lifted_input(input_rad: ArrayLike, nodes: PathNodes, *, initial_direction: int = 0) -> NDArray[np.float64]:
    """The lifted input z(t) of eq. (4), one row per sample, ascending columns first.

    Returns
    -------
    ndarray, shape (len(input_rad), nodes.num_lifted_inputs)
        ``[P^a(u) δ, P^d(u) (1 - δ)]``; with μ the node slopes, H[u(t)] = μ0 + z(t) μ.
    """
    signal = as_signal("input_rad", input_rad)
    delta = path_indicator(signal, initial_direction=initial_direction).astype(float)[:, None]
    return np.hstack((piecewise_linear_basis(signal, nodes.ascending) * delta,
                      piecewise_linear_basis(signal, nodes.descending) * (1.0 - delta)))


def check_cyclic_input(
    input_rad: ArrayLike,
    nodes: PathNodes,
    *,
    initial_direction: int = 0,
    tolerance_rad: float | None = None,
    min_visits: int = 1,
) -> None:
    """Raise :class:`InvalidInputError` unless the input u (``input_rad``) drives the paths the way Table I does.

    The lifting of eq. (4) holds for a backlash only if every ascending run starts at u_min and every
    descending run at u_max (Section II-B: the paths are then unique), and the slopes μ_i are identifiable
    only if every node segment of each path is visited. The checks, in order:

    1. every sample lies in [u_min; u_max] (the message names the first that does not);
    2. every reversal happens at an end of the interval (names the sample and the value it turned at);
    3. each path is traversed (ascending reaches u_max, descending reaches u_min);
    4. each segment ]n_{i-1}; n_i[ of each path holds at least ``min_visits`` samples on that path (names
       the path, the segment and its nodes).

    Parameters
    ----------
    tolerance_rad
        How far from u_min/u_max a sample may be and still count as being there; default 1e-9 of the range.
    """
    signal = as_signal("input_rad", input_rad)
    low, high = nodes.u_min, nodes.u_max
    tol = 1e-9 * (high - low) if tolerance_rad is None else float(tolerance_rad)
    outside = np.flatnonzero((signal < low - tol) | (signal > high + tol))
    if outside.size:
        k = int(outside[0])
        raise InvalidInputError(
            f"input_rad: sample {k} is {float(signal[k])}, outside the node interval [{low}; {high}] "
            f"({outside.size} samples outside); widen the nodes or clip the data"
        )
    delta = path_indicator(signal, initial_direction=initial_direction)
    turns = np.flatnonzero(np.diff(delta.astype(np.int8)) != 0) + 1  # delta changes at sample k
    # the turning point is the last sample before the first move in the new direction
    turning_values = signal[turns - 1]
    bad_up = (delta[turns] == 1) & (turning_values > low + tol)
    bad_down = (delta[turns] == 0) & (turning_values < high - tol)
    bad = np.flatnonzero(bad_up | bad_down)
    if bad.size:
        k = int(turns[bad[0]])
        if bad_up[bad[0]]:
            raise InvalidInputError(
                f"input_rad: sample {k - 1} turns from descending to ascending at {float(signal[k - 1])}, above u_min = {low}; "
                "Table I reverses only at u_min and u_max, otherwise a backlash leaves the identified paths. "
                + CYCLIC_REQUIREMENT
            )
        raise InvalidInputError(
            f"input_rad: sample {k - 1} turns from ascending to descending at {float(signal[k - 1])}, below u_max = {high}; "
            "Table I reverses only at u_min and u_max, otherwise a backlash leaves the identified paths. "
                + CYCLIC_REQUIREMENT
        )
    moves = np.flatnonzero(np.diff(signal) != 0.0)
    if moves.size:
        first = int(moves[0])  # the first run starts at sample `first` and must start at an end
        rising = signal[first + 1] > signal[first]
        if rising and signal[first] > low + tol:
            raise InvalidInputError(
                f"input_rad: the first ascending run starts at sample {first} from {float(signal[first])}, above u_min = {low}; "
                "trim the data so that it starts at u_min (Table I: u(0) = u_min)"
            )
        if not rising and signal[first] < high - tol:
            raise InvalidInputError(
                f"input_rad: the first descending run starts at sample {first} from {float(signal[first])}, below u_max = {high}; "
                "trim the data so that it starts at u_min (Table I: u(0) = u_min)"
            )
    if not np.any((delta == 1) & (signal >= high - tol)):
        raise InvalidInputError(f"input_rad: the ascending path is never traversed up to u_max = {high}. " + CYCLIC_REQUIREMENT)
    if not np.any((delta == 0) & (signal <= low + tol)):
        raise InvalidInputError(f"input_rad: the descending path is never traversed down to u_min = {low}. " + CYCLIC_REQUIREMENT)
    for path, path_nodes, on_path in (("ascending", nodes.ascending, delta == 1),
                                      ("descending", nodes.descending, delta == 0)):
        values = signal[on_path]
        for i in range(1, len(path_nodes)):
            a, b = path_nodes[i - 1], path_nodes[i]
            visits = int(np.count_nonzero((values > a) & (values < b)))
            if visits < min_visits:
                raise InvalidInputError(
                    f"input_rad: segment {i} ]{a:g}; {b:g}[ of the {path} path is visited by {visits} samples "
                    f"(at least {min_visits} needed to estimate its slope); move or remove nodes, or excite longer. "
                    + CYCLIC_REQUIREMENT
                )
