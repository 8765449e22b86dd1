"""Results of the model-discrepancy workflow (the last step, "show"): the disagreement of a model with a record,
the start linear model, each effect added, every candidate judged, the whole result and the report that
``rig diagnose --json`` writes and ``rig report`` reads (``to_dict``/``from_dict`` with ``kind`` and
``version``).

These types hold numbers; the steps that compute them are :mod:`.disagreement`, :mod:`.start_model`,
:mod:`.judgement`, :mod:`.verdict` and :mod:`.intervals`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from identify.plant_blocks import LinearBlock, PlantModel
from identify.result_format import check_kind, malformed, tagged
from identify.validation import InvalidInputError

if TYPE_CHECKING:  # (drive_torque reaches this module through open_world: the class is read where it is used)
    from identify.model_discrepancy.drive_torque import LoadTorqueCheck


VERDICTS = ("explained", "named", "ambiguous", "unexplained", "not_excited")
"""The verdicts: the start model already agrees within the noise bound; effects were found (named); two or
more candidates fit within their uncertainty of each other (all listed, none chosen); nothing helps; the
data cannot show the effects (the command never reverses, a segment too short, or an input the record does
not contain)."""


@dataclass(frozen=True)
class DisagreementWindow:
    """A run of samples where falsified samples cluster: [start, stop) sample indices."""

    start: int
    stop: int
    falsified_samples: int
    peak_residual_rad: float


GROSS_KINDS = ("sensor_wrap", "glitch")
"""What a gross disagreement looks like (:class:`GrossDisagreement`): a single-turn reading that jumped by 2 pi
at +-pi, or an isolated spike."""


@dataclass(frozen=True)
class GrossDisagreement:
    """A disagreement of the measurement with itself, found on the whole record before any model runs
    (:func:`~identify.model_discrepancy.disagreement.gross_disagreements`): where it is and what it looks like.

    Attributes
    ----------
    kind
        One of :data:`GROSS_KINDS`: ``"sensor_wrap"`` (the reading jumps by 2 pi between consecutive samples
        and stays off by a whole turn until it jumps back: a single-turn sensor wrapped at +-pi) or
        ``"glitch"`` (a run of at most a few samples far off, then back).
    ranges
        The samples concerned, [start, stop) each: the samples a whole turn off, or the spikes.
    """

    kind: str
    ranges: tuple[tuple[int, int], ...]

    def __post_init__(self) -> None:
        if self.kind not in GROSS_KINDS:
            raise InvalidInputError(f"kind: expected one of {', '.join(GROSS_KINDS)}, got {self.kind!r}")

    @property
    def samples(self) -> int:
        return sum(stop - start for start, stop in self.ranges)

    def ranges_text(self, most: int = 6) -> str:
        """"1203-1850, 2400-2710" (stop inclusive in words), at most ``most`` ranges then "and n more"."""
        words = [f"{start}" if stop == start + 1 else f"{start}-{stop - 1}" for start, stop in self.ranges[:most]]
        more = len(self.ranges) - most
        return ", ".join(words) + (f" and {more} more" if more > 0 else "")

    def text(self) -> str:
        """In words, where and what: "sensor wrap at samples 1203-1850 (...)"."""
        if self.kind == "sensor_wrap":
            return (f"sensor wrap at samples {self.ranges_text()} ({self.samples} samples a whole turn off: the "
                    "reading jumps by 2 pi between consecutive samples, a single-turn angle wrapped at +-pi; "
                    "measurement side, not the model)")
        return (f"glitch at samples {self.ranges_text()} (isolated spikes: the reading leaves and comes back "
                "within a few samples; measurement side, not the model)")

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "ranges": [[int(a), int(b)] for a, b in self.ranges], "text": self.text()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GrossDisagreement:
        return cls(str(data["kind"]), tuple((int(a), int(b)) for a, b in data["ranges"]))


@dataclass(frozen=True)
class Disagreement:
    """Free-run residual r_t = y_t - y^_t of a model against the measurement (step 2).

    Attributes
    ----------
    simulated_rad
        y^_t, the model's free-run output on the measured input.
    residual_rad
        r_t = y_t - y^_t.
    falsified
        |r_t| > noise bound delta: samples the model cannot explain with admissible noise.
    falsified_fraction
        Fraction of falsified samples on the validation segment.
    gap_rad
        sqrt(mean r_t^2) on the validation segment.
    windows
        Where falsified samples cluster (whole record).
    """

    simulated_rad: NDArray[np.float64]
    residual_rad: NDArray[np.float64]
    falsified: NDArray[np.bool_]
    falsified_fraction: float
    gap_rad: float
    windows: tuple[DisagreementWindow, ...]


@dataclass(frozen=True)
class LinearFit:
    """The start linear model (step 1) and how its order was chosen."""

    block: LinearBlock
    order: int
    validation_gap_by_order_rad: dict[int, float]


@dataclass(frozen=True)
class DiscrepancyStep:
    """One effect added to the model (step 4).

    Attributes
    ----------
    effect
        One of :data:`EFFECT_NAMES`.
    parameters
        The fitted parameters of the effect (units in the names).
    evidence
        The signature scores of the residual before the effect was added (0 = no sign of it, 1 = the
        residual is entirely this signature), and the validated gap every candidate reached.
    gap_before_rad, gap_after_rad
        Validated gap before and after adding the effect.
    falsified_fraction_before, falsified_fraction_after
        Fraction of validation samples with |r_t| > delta before and after.
    """

    effect: str
    parameters: dict[str, float]
    evidence: dict[str, Any]
    gap_before_rad: float
    gap_after_rad: float
    falsified_fraction_before: float
    falsified_fraction_after: float
    model: PlantModel = field(repr=False)


@dataclass(frozen=True)
class ResidualStructure:
    """What the black box of the final residual found (the open-world check,
    :func:`~identify.model_discrepancy.open_world.residual_structure`).

    Attributes
    ----------
    explained_fraction
        Share of the validation residual's mean square the black box, fitted on the estimation segment,
        predicts (0 when it predicts nothing; it can be negative on held-out data, reported as 0).
    gap_rad
        RMS of the validation residual before the black box (the final validated gap).
    gap_after_black_box_rad
        RMS of what the black box leaves of it.
    """

    explained_fraction: float
    gap_rad: float
    gap_after_black_box_rad: float

    def to_dict(self) -> dict[str, Any]:
        return {"explained_fraction": self.explained_fraction, "gap": self.gap_rad,
                "gap_after_black_box": self.gap_after_black_box_rad}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ResidualStructure:
        return cls(float(data["explained_fraction"]), float(data["gap"]), float(data["gap_after_black_box"]))


@dataclass(frozen=True)
class DiscrepancyResult:
    """The whole workflow (step 5).

    Attributes
    ----------
    steps
        The effects added, in order; empty when the start model already explains the data.
    start_model, final_model
        The model before and after.
    initial, final
        The disagreement of the start and final model.
    consistent
        True if the final model's falsified fraction on the validation segment is at most the tolerance.
    unexplained
        A plain-language statement of what is left.
    estimation_samples
        The first ``estimation_samples`` samples are the estimation segment, the rest the validation one.
    linear_fit
        How the start linear model was chosen (None when a model was given).
    findings
        Gross disagreements of the measurement found on the whole record (:class:`GrossDisagreement`: a sensor
        wrap, glitches); the workflow ran on the record with a wrap undone and glitches left out, and a record
        with findings is never ``explained``.
    load_torque_check
        What the drive's torque says of a weight the angle named or left open beside a sensor error
        (:class:`~identify.model_discrepancy.drive_torque.LoadTorqueCheck`); None without a torque, or when the
        angle neither named a weight nor left one open.
    """

    steps: tuple[DiscrepancyStep, ...]
    start_model: PlantModel
    final_model: PlantModel
    initial: Disagreement
    final: Disagreement
    consistent: bool
    unexplained: str
    estimation_samples: int
    noise_bound_rad: float
    linear_fit: LinearFit | None = None
    verdict: str = "unexplained"
    verdict_reason: str = ""
    candidates: tuple[CandidateResult, ...] = ()
    ambiguous_between: tuple[str, ...] = ()
    parameter_intervals: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    gap_reduction: dict[str, Any] | None = None
    excitation: dict[str, Any] = field(default_factory=dict)
    operating_point_rad: float = 0.0
    undecided: tuple[CandidateResult, ...] = ()
    findings: tuple[GrossDisagreement, ...] = ()
    residual_structure: ResidualStructure | None = None
    restart_window_samples: int | None = None
    load_torque_check: LoadTorqueCheck | None = None

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise InvalidInputError(f"verdict: expected one of {', '.join(VERDICTS)}, got {self.verdict!r}")

    @property
    def missing_effects(self) -> tuple[str, ...]:
        return tuple(step.effect for step in self.steps)

    @property
    def gap_reduction_fraction(self) -> float:
        """1 - g_final / g_initial on the validation segment."""
        return 1.0 - self.final.gap_rad / self.initial.gap_rad if self.initial.gap_rad > 0 else 0.0

    def report(self) -> DiscrepancyReport:
        """What the workflow found, without the models and signals: the content of :meth:`to_dict`."""
        reduction: dict[str, Any] = {"value": float(self.gap_reduction_fraction)}
        if self.gap_reduction is not None:
            reduction.update(self.gap_reduction)
        return DiscrepancyReport(
            verdict=self.verdict, verdict_reason=self.verdict_reason, noise_bound_rad=float(self.noise_bound_rad),
            missing_effects=tuple(MissingEffect(
                step.effect, {k: float(v) for k, v in step.parameters.items()},
                {k: (float(lo), float(hi)) for k, (lo, hi) in self.parameter_intervals.get(step.effect, {}).items()},
                float(step.gap_before_rad), float(step.gap_after_rad)) for step in self.steps),
            ambiguous_between=tuple(self.ambiguous_between), candidates=tuple(self.candidates),
            gap_initial_rad=float(self.initial.gap_rad), gap_final_rad=float(self.final.gap_rad),
            gap_reduction=reduction, falsified_fraction_initial=float(self.initial.falsified_fraction),
            falsified_fraction_final=float(self.final.falsified_fraction), excitation=dict(self.excitation),
            operating_point_rad=float(self.operating_point_rad), undecided=tuple(self.undecided),
            findings=tuple(self.findings), residual_structure=self.residual_structure,
            restart_window_samples=self.restart_window_samples, load_torque_check=self.load_torque_check)

    def to_dict(self) -> dict[str, Any]:
        """The ``rig diagnose --json`` document, ``self.report().to_dict()`` (:meth:`DiscrepancyReport.to_dict`)."""
        return self.report().to_dict()

    def to_pandas(self) -> Any:
        """``self.report().to_pandas()`` (:meth:`DiscrepancyReport.to_pandas`)."""
        return self.report().to_pandas()


@dataclass(frozen=True)
class MissingEffect:
    """One effect the workflow added: its fitted parameters with their cross-validated intervals and the
    validated gap before and after (an entry of :attr:`DiscrepancyReport.missing_effects`)."""

    effect: str
    parameters: dict[str, float]
    parameter_intervals: dict[str, tuple[float, float]]
    gap_before_rad: float
    gap_after_rad: float


@dataclass(frozen=True)
class DiscrepancyReport:
    """What :func:`diagnose_model` found, as the ``rig diagnose --json`` document holds it (kind
    ``"model_discrepancy"``, version 6): the verdict with its reason, the missing effects with intervals,
    the candidates with their gaps, uncertainties and gap reductions, the candidates of the last round whose
    reduction straddles the acceptance (``undecided``: an ambiguous verdict after the effects named, if any),
    the gaps and falsified fractions before and after, the excitation check, the operating point and the
    gross disagreements of the measurement (``findings``).
    :meth:`DiscrepancyResult.report` makes one."""

    verdict: str
    verdict_reason: str
    noise_bound_rad: float
    missing_effects: tuple[MissingEffect, ...]
    ambiguous_between: tuple[str, ...]
    candidates: tuple[CandidateResult, ...]
    gap_initial_rad: float
    gap_final_rad: float
    gap_reduction: dict[str, Any]
    falsified_fraction_initial: float
    falsified_fraction_final: float
    excitation: dict[str, Any]
    operating_point_rad: float
    undecided: tuple[CandidateResult, ...] = ()
    findings: tuple[GrossDisagreement, ...] = ()
    residual_structure: ResidualStructure | None = None
    restart_window_samples: int | None = None
    load_torque_check: LoadTorqueCheck | None = None

    KIND = "model_discrepancy"
    VERSION = 7
    READS = (1, 2, 3, 4, 5, 6, 7)
    """Version 2 added ``undecided`` and each candidate's ``reduction``, ``reduction_interval`` and
    ``acceptance``; version 3 each candidate's ``validation_interval``, ``fold_reductions`` and
    ``refit_interval`` (the interval judged, ``reduction_interval``, is then made of both:
    :func:`_reduction_judged`); version 4 ``findings`` (the gross disagreements of the measurement:
    :class:`GrossDisagreement`, each with ``kind``, ``ranges`` and ``text``); version 5 ``residual_structure``
    (the open-world check: :class:`ResidualStructure`, null when not judged); version 6
    ``restart_window_samples`` (null: the models were compared by their free runs; a number: on windows of that
    many samples restarting the load from the measured angle, :mod:`.comparison`); version 7 ``load_torque_check``
    (what the drive's torque says of a weight, :class:`~identify.model_discrepancy.drive_torque.LoadTorqueCheck`;
    null when no torque was given or the angle neither named a weight nor left one open). :meth:`from_dict` reads versions 1 to 6 too (no undecided candidates, no intervals; no refits; no findings; no residual structure;
    free runs)."""

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise InvalidInputError(f"verdict: expected one of {', '.join(VERDICTS)}, got {self.verdict!r}")

    def to_pandas(self) -> Any:
        """The named effects' parameters as a ``pandas.DataFrame``: one row per parameter, columns ``effect``,
        ``parameter``, ``value``, ``lower``, ``upper`` (the cross-validated interval; NaN where none), and the
        verdict, its reason and ``ambiguous_between`` in ``attrs``. Needs pandas (not a dependency)."""
        from identify.result_format import require_pandas

        pandas = require_pandas("DiscrepancyReport.to_pandas()")
        nan = float("nan")
        rows = [(step.effect, name, value, *step.parameter_intervals.get(name, (nan, nan)))
                for step in self.missing_effects for name, value in step.parameters.items()]
        table = pandas.DataFrame(rows, columns=["effect", "parameter", "value", "lower", "upper"])
        table.attrs.update(verdict=self.verdict, verdict_reason=self.verdict_reason,
                           ambiguous_between=list(self.ambiguous_between))
        return table

    def to_dict(self) -> dict[str, Any]:
        """``kind``, ``version`` and the documented keys of the ``rig diagnose --json`` report: ``verdict``,
        ``verdict_reason``, ``noise_bound``, ``missing_effects`` (with ``parameter_intervals``), ``ambiguous_between``,
        ``candidates``, ``gap_initial``, ``gap_final``, ``gap_reduction``, ``falsified_fraction_initial``,
        ``falsified_fraction_final``, ``excitation``, ``operating_point``, ``undecided``, ``findings``,
        ``residual_structure``, ``restart_window_samples``, ``load_torque_check``."""
        return tagged(self.KIND, self.VERSION, {
            "verdict": self.verdict,
            "verdict_reason": self.verdict_reason,
            "noise_bound": float(self.noise_bound_rad),
            "missing_effects": [
                {
                    "effect": step.effect,
                    "parameters": {k: float(v) for k, v in step.parameters.items()},
                    "parameter_intervals": {k: [float(lo), float(hi)] for k, (lo, hi)
                                            in step.parameter_intervals.items()},
                    "gap_before": float(step.gap_before_rad),
                    "gap_after": float(step.gap_after_rad),
                }
                for step in self.missing_effects
            ],
            "ambiguous_between": list(self.ambiguous_between),
            "candidates": [candidate.to_dict() for candidate in self.candidates],
            "gap_initial": float(self.gap_initial_rad),
            "gap_final": float(self.gap_final_rad),
            "gap_reduction": dict(self.gap_reduction),
            "falsified_fraction_initial": float(self.falsified_fraction_initial),
            "falsified_fraction_final": float(self.falsified_fraction_final),
            "excitation": dict(self.excitation),
            "operating_point": float(self.operating_point_rad),
            "undecided": [candidate.to_dict() for candidate in self.undecided],
            "findings": [finding.to_dict() for finding in self.findings],
            "residual_structure": None if self.residual_structure is None else self.residual_structure.to_dict(),
            "restart_window_samples": self.restart_window_samples,
            "load_torque_check": None if self.load_torque_check is None else self.load_torque_check.to_dict(),
        })

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DiscrepancyReport:
        """Inverse of :meth:`to_dict`; keys a command added beside (``rig diagnose``'s ``import``) are
        ignored. A document of another kind or version is a ResultFormatError naming both."""
        check_kind(data, cls.KIND, cls.READS)
        with malformed(cls.KIND):
            return cls(
                verdict=str(data["verdict"]), verdict_reason=str(data["verdict_reason"]),
                noise_bound_rad=float(data["noise_bound"]),
                missing_effects=tuple(MissingEffect(
                    str(e["effect"]), {str(k): float(v) for k, v in e["parameters"].items()},
                    {str(k): (float(lo), float(hi)) for k, (lo, hi) in e["parameter_intervals"].items()},
                    float(e["gap_before"]), float(e["gap_after"])) for e in data["missing_effects"]),
                ambiguous_between=tuple(str(name) for name in data["ambiguous_between"]),
                candidates=tuple(CandidateResult.from_dict(c) for c in data["candidates"]),
                gap_initial_rad=float(data["gap_initial"]), gap_final_rad=float(data["gap_final"]),
                gap_reduction=dict(data["gap_reduction"]),
                falsified_fraction_initial=float(data["falsified_fraction_initial"]),
                falsified_fraction_final=float(data["falsified_fraction_final"]),
                excitation=dict(data["excitation"]), operating_point_rad=float(data["operating_point"]),
                undecided=tuple(CandidateResult.from_dict(c) for c in data.get("undecided", ())),
                findings=tuple(GrossDisagreement.from_dict(f) for f in data.get("findings", ())),
                residual_structure=None if data.get("residual_structure") is None
                else ResidualStructure.from_dict(data["residual_structure"]),
                restart_window_samples=None if data.get("restart_window_samples") is None
                else int(data["restart_window_samples"]),
                load_torque_check=None if data.get("load_torque_check") is None
                else _load_torque_check(data["load_torque_check"]))


@dataclass(frozen=True)
class CandidateResult:
    """One candidate tried in one round: its validated gap with an uncertainty (spread over validation
    blocks, :data:`VALIDATION_BLOCKS`), the penalised gap it was ranked by, the fitted parameters, whether
    it vanished, whether its penalised gap passes the acceptance (``helps``), and the reduction of the gap
    with its interval and what that interval says (``acceptance``, :func:`_acceptance`: one of
    :data:`ACCEPTANCES`; empty, and the reduction NaN, in documents of version 1, which had no interval).

    ``reduction_interval`` is the interval judged (:func:`_reduction_judged`), made of ``validation_interval``
    (the spread over the validation blocks) and, for the candidates the acceptance weighs
    (:func:`_judged_by_refits`: a round's best candidate and its peers), ``refit_interval`` (the spread of
    the penalised reductions ``fold_reductions`` of :data:`REFIT_FOLDS` cross-validation refits over the
    whole record, :func:`_refit_reduction`): the refit interval when it is clear and the validated reduction
    reaches the acceptance, else the union of the two. For the other candidates, and in documents of version 2,
    ``refit_interval`` is None (JSON null), ``fold_reductions`` empty and the interval judged the validation
    one."""

    round: int
    effect: str
    gap_rad: float
    gap_uncertainty_rad: float
    penalised_gap_rad: float
    parameters: dict[str, float]
    vanished: bool
    helps: bool
    reduction: float = math.nan
    reduction_interval: tuple[float, float] = (math.nan, math.nan)
    acceptance: str = ""
    validation_interval: tuple[float, float] = (math.nan, math.nan)
    fold_reductions: tuple[float, ...] = ()
    refit_interval: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"round": self.round, "effect": self.effect, "gap": float(self.gap_rad),
                "gap_uncertainty": float(self.gap_uncertainty_rad), "penalised_gap": float(self.penalised_gap_rad),
                "parameters": {k: float(v) for k, v in self.parameters.items()}, "vanished": bool(self.vanished),
                "helps": bool(self.helps), "reduction": float(self.reduction),
                "reduction_interval": [float(v) for v in self.reduction_interval], "acceptance": self.acceptance,
                "validation_interval": [float(v) for v in self.validation_interval],
                "fold_reductions": [float(v) for v in self.fold_reductions],
                "refit_interval": None if self.refit_interval is None else [float(v) for v in self.refit_interval]}

    def interval_parts(self) -> str:
        """The parts of the interval judged, in words: "validation blocks 8 to 21 %, 8 refits 3 to 30 %" (each
        only when known; empty for a document of version 1)."""
        parts = []
        if all(math.isfinite(v) for v in self.validation_interval):
            low, high = self.validation_interval
            parts.append(f"validation blocks {100 * low:.0f} to {100 * high:.0f} %")
        if self.refit_interval is not None:
            low, high = self.refit_interval
            parts.append(f"{len(self.fold_reductions)} refits {100 * low:.0f} to {100 * high:.0f} %")
        return ", ".join(parts)

    def interval_text(self) -> str:
        """The interval of the gap reduction judged, with its parts: "8 to 70 % (validation blocks 8 to 61 %,
        8 refits 30 to 70 %)"; the verdict, the text output and the report all say it so."""
        low, high = self.reduction_interval
        parts = self.interval_parts()
        return f"{100 * low:.0f} to {100 * high:.0f} %" + (f" ({parts})" if parts else "")

    def reduction_text(self) -> str:
        """The validated gap reduction and its interval (:meth:`interval_text`): "42 %, 8 to 70 % (...)"."""
        return f"{100 * self.reduction:.0f} %, {self.interval_text()}"

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CandidateResult:
        """Inverse of :meth:`to_dict` (a version-1 entry has no reduction or acceptance; a version-2 entry no
        refits, its interval is the validation one)."""
        low, high = data.get("reduction_interval", (math.nan, math.nan))
        v_low, v_high = data.get("validation_interval", (low, high))
        refits = data.get("refit_interval")
        return cls(int(data["round"]), str(data["effect"]), float(data["gap"]), float(data["gap_uncertainty"]),
                   float(data["penalised_gap"]), {str(k): float(v) for k, v in data["parameters"].items()},
                   bool(data["vanished"]), bool(data["helps"]), float(data.get("reduction", math.nan)),
                   (float(low), float(high)), str(data.get("acceptance", "")), (float(v_low), float(v_high)),
                   tuple(float(v) for v in data.get("fold_reductions", ())),
                   None if refits is None else (float(refits[0]), float(refits[1])))


ACCEPTANCES = ("clear", "undecided", "rejected", "vanished")
"""What a candidate's gap reduction says against the required ``min_reduction`` (:func:`_acceptance`): its
whole interval above it (the effect may be named), the interval straddling it (the record cannot tell
whether the effect is there: reported, not named), the whole interval below it, or the fitted effect does
nothing (its catalogue ``vanished``)."""


def _load_torque_check(data: Mapping[str, Any]) -> LoadTorqueCheck:
    from identify.model_discrepancy.drive_torque import LoadTorqueCheck

    return LoadTorqueCheck.from_dict(dict(data))
