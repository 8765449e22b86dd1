"""The result of a Hammerstein identification (Pouliquen et al., CDC 2013; :mod:`identify.hammerstein_subspace`
computes it): the linear part G(q) as a state-space model and transfer function, the ascending and descending
borders of the input nonlinearity at the path nodes (eq. (3)), the play they leave at each node, and what the
optional output-error refinement did. A model simulates itself on a new input and is saved and read back as a
tagged result (:mod:`identify.result_format`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.signal
from numpy.typing import ArrayLike, NDArray

from identify.border_lifting import PathNodes, lifted_input
from identify.plant_blocks import InputBacklash, PiecewiseLinearBorder
from identify.result_format import check_kind, malformed, tagged
from identify.validation import InvalidInputError, as_signal, positive, renamed_parameters

__all__ = ["HammersteinModel", "NodePlay", "RefinementReport"]


@dataclass(frozen=True)
class RefinementReport:
    """What the optional output-error refinement did (``identify_hammerstein(..., refine=True)``).

    Attributes
    ----------
    rms_before_rad, rms_after_rad
        Root mean square output error on the identification data before (subspace estimate) and after.
    evaluations
        Number of residual evaluations of :func:`scipy.optimize.least_squares`.
    converged
        The optimiser's own success flag.
    message
        The optimiser's message.
    applied
        Whether the refined model replaced the subspace estimate (it does unless the output error did not
        decrease or the refined G is unstable).
    """

    rms_before_rad: float
    rms_after_rad: float
    evaluations: int
    converged: bool
    message: str
    applied: bool


@dataclass(frozen=True)
class NodePlay:
    """The play seen at the output, read at the nodes: the gap P_d(u_i) - P_a(u_i) at each ascending node
    u_i, with P_d interpolated there (eq. (3); :meth:`HammersteinModel.play_at_nodes`).

    On Table I cycles a play between two parallel lines gives the same gap at every interior node (the paths
    meet at u_min and u_max), so the median over the interior nodes is its estimate and their spread the
    only uncertainty the subspace method offers (it gives no interval); for curved borders the gap varies
    with u and the median is only a typical value.

    Attributes
    ----------
    nodes_rad
        The ascending nodes u_i.
    gaps_rad
        P_d(u_i) - P_a(u_i) at each of them.
    """

    nodes_rad: NDArray[np.float64]
    gaps_rad: NDArray[np.float64]

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    @property
    def interior_gaps_rad(self) -> NDArray[np.float64]:
        """The gaps without the end nodes, where both paths meet (all of them for two nodes)."""
        return self.gaps_rad[1:-1] if self.gaps_rad.size > 2 else self.gaps_rad

    @property
    def median_rad(self) -> float:
        return float(np.median(self.interior_gaps_rad))

    @property
    def lowest_rad(self) -> float:
        return float(np.min(self.interior_gaps_rad))

    @property
    def highest_rad(self) -> float:
        return float(np.max(self.interior_gaps_rad))

    def describe(self) -> str:
        """The estimate with its spread, as the demo's table and the border figure's caption both state it."""
        return (f"{self.median_rad:.4g} (median gap P_d - P_a at {self.interior_gaps_rad.size} interior nodes; "
                f"spread {self.lowest_rad:.3g}..{self.highest_rad:.3g}) rad")


def _frozen(name: str, values: ArrayLike, shape: tuple[int, ...]) -> NDArray[np.float64]:
    array = np.array(values, dtype=float).reshape(shape)
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(f"{name}: expected finite entries")
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class HammersteinModel:
    """An identified Hammerstein model y = μ0 + G(q)(H[u] - μ0) with G(1) = 1 (eqs. (1), (4)-(6), A.2).

    The linear part is x(t+1) = A x(t) + B w(t), y(t) - μ0 = C x(t) + D w(t) with w = H[u] - μ0 = μ z(t).

    Attributes
    ----------
    A, B, C, D
        State-space matrices of G(q): A (n, n), B (n,), C (n,), D scalar (0 when no feedthrough).
    mu0
        μ0 = H[u_min], the common start of both paths (A.1); it is also the output at rest at u_min.
    ascending_border, descending_border
        The paths P_a, P_d of eq. (3) as piecewise-linear functions of u, offset μ0 included; their
        ``nodes_u`` and ``values`` are the node table.
    mu_ascending, mu_descending
        Node slopes μ_i^a, μ_i^d (eq. (3)).
    singular_values
        Singular values of the PI-MOESP projection (eq. (12)), largest first: look for the gap.
    order
        n, chosen from ``singular_values`` or given.
    past_horizon, future_horizon
        p and f of the block-Hankel matrices; ``num_columns`` is j.
    split
        ``"rank1"`` (eq. (14)) or ``"separate"`` (Remark 5).
    initial_state
        x(0) estimated with B and D (used for the fit diagnostics only; :meth:`simulate` starts at rest).
    fit_percent
        100 (1 - |y - y_model| / |y - mean(y)|) on the identification data (simulation, not prediction).
    residual_rms_rad
        RMS of y - y_model on the identification data.
    mu0_hold_rad
        The paper's μ0: the output mean over the hold (None if ``mu0_rad`` was given).
    refinement
        Report of the output-error refinement, or None if it was not run.
    """

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    D: float
    mu0: float
    nodes: PathNodes
    mu_ascending: NDArray[np.float64]
    mu_descending: NDArray[np.float64]
    singular_values: NDArray[np.float64]
    order: int
    past_horizon: int
    future_horizon: int
    num_columns: int
    split: str
    initial_state: NDArray[np.float64]
    fit_percent: float
    residual_rms_rad: float
    mu0_hold_rad: float | None = None
    refinement: RefinementReport | None = None
    ascending_border: PiecewiseLinearBorder = field(init=False)
    descending_border: PiecewiseLinearBorder = field(init=False)

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    def __post_init__(self) -> None:
        n = int(self.order)
        object.__setattr__(self, "A", _frozen("A", self.A, (n, n)))
        object.__setattr__(self, "B", _frozen("B", self.B, (n,)))
        object.__setattr__(self, "C", _frozen("C", self.C, (n,)))
        object.__setattr__(self, "initial_state", _frozen("initial_state", self.initial_state, (n,)))
        object.__setattr__(self, "D", float(self.D))
        object.__setattr__(self, "mu0", float(self.mu0))
        object.__setattr__(self, "mu_ascending",
                           _frozen("mu_ascending", self.mu_ascending, (len(self.nodes.ascending) - 1,)))
        object.__setattr__(self, "mu_descending",
                           _frozen("mu_descending", self.mu_descending, (len(self.nodes.descending) - 1,)))
        object.__setattr__(self, "singular_values",
                           _frozen("singular_values", self.singular_values, (np.size(self.singular_values),)))
        object.__setattr__(self, "ascending_border",
                           _border(self.nodes.ascending, self.mu_ascending, self.mu0))
        object.__setattr__(self, "descending_border",
                           _border(self.nodes.descending, self.mu_descending, self.mu0))

    @property
    def mu(self) -> NDArray[np.float64]:
        """μ of eq. (4): ascending slopes then descending slopes."""
        return np.concatenate((self.mu_ascending, self.mu_descending))

    @property
    def poles(self) -> NDArray[np.complex128]:
        """Eigenvalues of A (the poles of G)."""
        return np.linalg.eigvals(self.A)

    @property
    def stable(self) -> bool:
        """Every pole strictly inside the unit circle (|p| < 1). An identified G with a pole on or outside it
        grows without bound in a free run: the data or the order do not support the model."""
        return bool(np.all(np.abs(self.poles) < 1.0))

    @property
    def max_pole_magnitude(self) -> float:
        """The largest |p| (>= 1: not stable)."""
        return float(np.max(np.abs(self.poles))) if self.order else 0.0

    def natural_frequencies_hz(self, sample_period_s: float) -> NDArray[np.float64]:
        """|ln p| / (2π T) of every pole, distinct values ascending (a complex pair counts once)."""
        with np.errstate(divide="ignore"):
            frequencies = np.abs(np.log(self.poles.astype(complex))) / (2 * np.pi * positive("sample_period_s",
                                                                                             sample_period_s))
        return np.unique(np.round(frequencies, 12))

    def pole_distance(self, true_poles: ArrayLike) -> float:
        """The distance from the farthest true pole to its nearest identified pole (nan if either is empty)."""
        truth = np.atleast_1d(np.asarray(true_poles, dtype=complex))
        estimated = self.poles
        if estimated.size == 0 or truth.size == 0:
            return float("nan")
        return float(np.max(np.min(np.abs(truth[:, None] - estimated[None, :]), axis=1)))

    def play_at_nodes(self) -> NodePlay:
        """The gaps P_d(u_i) - P_a(u_i) at the ascending nodes (eq. (3)): the play seen at the output."""
        nodes_rad = np.asarray(self.ascending_border.nodes_u, dtype=float)
        gaps_rad = (np.interp(nodes_rad, self.descending_border.nodes_u, self.descending_border.values)
                    - np.asarray(self.ascending_border.values, dtype=float))
        return NodePlay(nodes_rad, gaps_rad)

    @property
    def largest_play_rad(self) -> float:
        """max over the ascending nodes of P_d(u) - P_a(u) (:meth:`play_at_nodes`)."""
        return float(np.max(self.play_at_nodes().gaps_rad))

    @property
    def transfer_function(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(numerator, denominator) of G, coefficients of q^0, q^-1, ..., q^-n; denominator[0] = 1."""
        return _state_space_to_tf(self.A, self.B, self.C, self.D)

    def to_control(self, sample_period_s: float | bool = True) -> Any:
        """G(q) as python-control's discrete-time ``TransferFunction``, with sample time ``sample_period_s``
        (the record's; True: discrete, period unspecified). Needs ``pip install control``."""
        from identify.control_systems import discrete_transfer_function

        numerator, denominator = self.transfer_function
        return discrete_transfer_function(numerator, denominator, sample_period_s, "HammersteinModel.to_control()")

    @property
    def static_gain(self) -> float:
        """G(1) = D + C (I - A)^-1 B; 1 by construction (A.2)."""
        return float(self.D + self.C @ np.linalg.solve(np.eye(self.order) - self.A, self.B))

    def frequency_response(self, omega_rad_per_sample: ArrayLike) -> NDArray[np.complex128]:
        """G(e^{jω}) at normalised angular frequencies ω (rad/sample, 0..π)."""
        omega = np.atleast_1d(np.asarray(omega_rad_per_sample, dtype=float))
        numerator, denominator = self.transfer_function
        _, response = scipy.signal.freqz(numerator, denominator, worN=omega)
        return response

    @renamed_parameters(u="input_rad")
    def nonlinearity_output(self, input_rad: ArrayLike, *, nonlinearity: Literal["paths", "backlash"] = "paths",
                            initial_direction: int = 0) -> NDArray[np.float64]:
        """H[u(t)] of the identified model.

        ``"paths"`` is eq. (2), H = δ P_a(u) + (1 - δ) P_d(u): exact for a switch and, for a backlash, for
        inputs that reverse only at u_min and u_max (Table I). ``"backlash"`` runs a play operator between
        the identified paths, v(t) = min(P_d(u), max(P_a(u), v(t-1))) from v(-1) = μ0, which also covers
        a backlash driven by inputs that reverse inside the interval.
        """
        signal = as_signal("input_rad", input_rad)
        if nonlinearity == "paths":
            return self.mu0 + lifted_input(signal, self.nodes, initial_direction=initial_direction) @ self.mu
        if nonlinearity == "backlash":
            block = InputBacklash(self.ascending_border, self.descending_border, initial_output_rad=self.mu0)
            return block.apply(signal)
        raise InvalidInputError(f"nonlinearity: expected 'paths' or 'backlash', got {nonlinearity!r}")

    @renamed_parameters(u="input_rad")
    def simulate(self, input_rad: ArrayLike, *, nonlinearity: Literal["paths", "backlash"] = "paths",
                 initial_direction: int = 0) -> NDArray[np.float64]:
        """Output of the identified model for the input u (``input_rad``), starting at rest at u_min (output μ0).

        See :meth:`nonlinearity_output` for ``nonlinearity``.
        """
        deviation = self.nonlinearity_output(input_rad, nonlinearity=nonlinearity,
                                             initial_direction=initial_direction) - self.mu0
        numerator, denominator = self.transfer_function
        return self.mu0 + scipy.signal.lfilter(numerator, denominator, deviation)

    KIND = "hammerstein_model"
    VERSION = 1

    def to_pandas(self) -> Any:
        """The identified borders as a ``pandas.DataFrame``: one row per node of each path, columns ``path``
        (``ascending``/``descending``), ``node_rad`` and ``border_rad`` (H at the node; the first ascending
        node holds μ0). The dynamics (A, B, C, D, poles) stay on the model. Needs pandas (not a dependency)."""
        from identify.result_format import require_pandas

        pandas = require_pandas("HammersteinModel.to_pandas()")
        rows = [(path, float(node), float(border(node)))
                for path, nodes, border in (("ascending", self.nodes.ascending, self.ascending_border),
                                            ("descending", self.nodes.descending, self.descending_border))
                for node in nodes]
        return pandas.DataFrame(rows, columns=["path", "node_rad", "border_rad"])

    def to_dict(self) -> dict[str, Any]:
        """The ``rig identify hammerstein --json`` document: ``kind`` ``"hammerstein_model"``, ``version`` 1,
        order, poles [[re, im]], stable and the largest |p|, A, B, C, D, mu0, borders, singular values, the
        horizons and fit, and what :meth:`from_dict` needs besides (nodes, slopes, initial state)."""
        return tagged(self.KIND, self.VERSION, {
            "order": self.order,
            "poles": [[float(p.real), float(p.imag)] for p in self.poles],
            "stable": self.stable,
            "max_pole_magnitude": self.max_pole_magnitude,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D,
            "mu0": self.mu0,
            "borders": {
                "ascending": {"u": list(self.ascending_border.nodes_u), "h": list(self.ascending_border.values)},
                "descending": {"u": list(self.descending_border.nodes_u), "h": list(self.descending_border.values)},
            },
            "singular_values": self.singular_values.tolist(),
            "split": self.split,
            "past_horizon": self.past_horizon,
            "future_horizon": self.future_horizon,
            "fit_percent": self.fit_percent,
            "residual_rms": self.residual_rms_rad,
            "refinement": None if self.refinement is None else {
                "rms_before": self.refinement.rms_before_rad, "rms_after": self.refinement.rms_after_rad,
                "applied": self.refinement.applied, "evaluations": self.refinement.evaluations,
                "converged": self.refinement.converged, "message": self.refinement.message,
            },
            "nodes": {"ascending": list(self.nodes.ascending), "descending": list(self.nodes.descending)},
            "mu_ascending": self.mu_ascending.tolist(),
            "mu_descending": self.mu_descending.tolist(),
            "num_columns": self.num_columns,
            "initial_state": self.initial_state.tolist(),
            "mu0_hold": self.mu0_hold_rad,
        })

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> HammersteinModel:
        """Inverse of :meth:`to_dict` (poles, stability and borders are recomputed); a document of another
        kind or version is a ResultFormatError naming both, a malformed one names the key."""
        check_kind(data, cls.KIND, (cls.VERSION,))
        with malformed(cls.KIND):
            order = data["order"]
            if isinstance(order, bool) or not isinstance(order, int) or order < 1:
                raise ValueError(f"order is {order!r}, expected an integer >= 1")
            refined = data["refinement"]
            refinement = None if refined is None else RefinementReport(
                float(refined["rms_before"]), float(refined["rms_after"]), int(refined["evaluations"]),
                bool(refined["converged"]), str(refined["message"]), bool(refined["applied"]))
            hold = data["mu0_hold"]

            def numbers(key: str, shape: tuple[int, ...]) -> NDArray[np.float64]:
                try:
                    values = np.asarray(data[key], dtype=float)
                except (TypeError, ValueError):
                    raise ValueError(f"{key}: expected numbers, got {str(data[key])[:40]}") from None
                if values.shape != shape or not np.all(np.isfinite(values)):
                    raise ValueError(f"{key}: expected {' x '.join(map(str, shape)) or 'one'} finite numbers, got "
                                     f"shape {values.shape}")
                return values

            nodes = PathNodes(tuple(data["nodes"]["ascending"]), tuple(data["nodes"]["descending"]))
            return cls(A=numbers("A", (order, order)), B=numbers("B", (order,)), C=numbers("C", (order,)),
                       D=float(data["D"]), mu0=float(data["mu0"]), nodes=nodes,
                       mu_ascending=numbers("mu_ascending", (len(nodes.ascending) - 1,)),
                       mu_descending=numbers("mu_descending", (len(nodes.descending) - 1,)),
                       singular_values=numbers("singular_values", (np.size(data["singular_values"]),)), order=order,
                       past_horizon=int(data["past_horizon"]), future_horizon=int(data["future_horizon"]),
                       num_columns=int(data["num_columns"]), split=str(data["split"]),
                       initial_state=data["initial_state"], fit_percent=float(data["fit_percent"]),
                       residual_rms_rad=float(data["residual_rms"]), mu0_hold_rad=None if hold is None else float(hold),
                       refinement=refinement)


def _border(nodes: tuple[float, ...], slopes: NDArray[np.float64], mu0: float) -> PiecewiseLinearBorder:
    """Node values of eq. (3): P(n_0) = μ0, P(n_i) = μ0 + Σ_{l<=i} μ_l (n_l - n_{l-1})."""
    values = mu0 + np.concatenate(([0.0], np.cumsum(slopes * np.diff(nodes))))
    return PiecewiseLinearBorder(tuple(nodes), tuple(float(v) for v in values))


def _state_space_to_tf(A: NDArray[np.float64], B: NDArray[np.float64], C: NDArray[np.float64],
                       D: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    n = A.shape[0]
    numerator, denominator = scipy.signal.ss2tf(A, B.reshape(n, 1), C.reshape(1, n), np.array([[D]]))
    return np.atleast_1d(np.squeeze(numerator)).astype(float), np.asarray(denominator, dtype=float)
