"""Model-discrepancy workflow: find where a simulation model and a measurement disagree, name the missing
physical effect, add it with fitted parameters, and show the validated gap shrink.

The workflow runs on one record (u_t, y_t), t = 0..N-1, with a known bound delta on the measurement error
(|e_t| <= delta, the noise bound of set-membership identification, eq. (4) of Cerone et al. 2009). One module
per step:

1. **Start** (:mod:`.start_model`) from a given :class:`~identify.plant_blocks.PlantModel` or, without one,
   from the best low-order linear model (:func:`fit_linear_model`: output-error fit, order chosen by
   validation error).
2. **Disagree** (:mod:`.disagreement`, :func:`disagreement`): free-run simulation y^_t of the model on the
   measured input (or its restarted run, step 9), residual r_t = y_t - y^_t; a sample is *falsified* when
   |r_t| > delta (it cannot be explained by the model plus admissible noise); falsified samples are grouped
   into windows.
3. **Candidates** (:mod:`.candidates`): the effects of :mod:`identify.effect_catalogue` (blocks, parameters,
   placement, guesses, "vanished"), each placed into the model; each leaves a signature in r_t
   (:mod:`identify.effect_signatures`).
4. **Fit** (:mod:`.fit`): every candidate is inserted into the model (a :mod:`.chain`), its parameters (with
   the linear block's coefficients when the start model was fitted) are fitted on the estimation segment
   (its first :data:`~.thresholds.FIT_MAX_SAMPLES` on a long record, the starts of the fit ranked on the first
   :data:`~.thresholds.START_SCREEN_SAMPLES`; the effect kept is polished on all of it; a resonance from a
   fitted start is started also from the modes of linear models of order 3-4, :func:`.start_model.record_modes`;
   a drive-train effect in a given linear model's two-mass form is fitted also in the other splits of its inertia
   between motor and load that follow the model, :func:`.candidates.split_family`),
   and the gap g = sqrt(mean r_t^2) is measured on the validation segment.
5. **Judge** (:mod:`.judgement`): the effect whose penalised gap g_after (1 + penalty * n_parameters) is
   lowest is kept when its reduction of the gap is clearly above ``min_reduction``, both over the validation
   blocks and over :data:`REFIT_FOLDS` cross-validation refits of the whole record; rivals within their
   uncertainty are followed to the end of their own searches. The rounds (:mod:`.search`) repeat until the
   falsified fraction on the validation segment is at most ``consistent_fraction`` or no candidate helps.
6. **Verdict** (:mod:`.verdict`). First, what the record cannot tell apart (:mod:`.left_open`): a named effect
   whose look-alike (catalogue ``look_alikes``: a weight, a sensor error once per revolution, an offset) fits as
   well is dropped and listed with it; one whose map is also another mechanism's keeps its sizes, listed with
   that mechanism; a round left open lists the look-alikes that fit as well. Then one of :data:`VERDICTS`: ``explained`` when the start model already agrees,
   ``named`` when effects were kept, ``ambiguous`` when the best candidate has rivals within their
   uncertainty or its reduction straddles the acceptance, ``unexplained`` when nothing helps, and
   ``not_excited`` when a segment never sees the command turn or the output moves while command and model
   rest. The verdict judges the whole record: ``explained`` needs agreement on the estimation segment too
   (a start model that agrees with the validation segment only is judged again on the estimation segment
   alone, split as a record is, :func:`.pipeline._judged_where_it_disagrees`),
   and a gross disagreement of the measurement with itself, found before any model runs
   (:func:`gross_disagreements`: a sensor wrap, jumps of 2 pi between consecutive samples; glitches,
   isolated spikes), is reported with its sample ranges (:class:`GrossDisagreement`, the result's
   ``findings``); the workflow judges the rest of the record with it put aside, and such a record is never
   ``explained``.
   A named map that two mechanisms draw alike (an output backlash and Coulomb friction without stiction behind
   the position loop) stays in the model, and the verdict is ``ambiguous`` between the mechanisms.
7. **Intervals** (:mod:`.intervals`): the named effects' parameters and the gap reduction with their range
   over cross-validation refits.
8. **Open world** (:mod:`.open_world`): a small black box of the final residual, fitted on the estimation
   segment and judged on the validation segment, measures the structure the final model left; the verdict
   says how much of the gap remains unexplained, and is lowered to ``ambiguous`` when the black box takes more
   off what remains than the named effects took off the start model's gap (:class:`ResidualStructure`).
9. **Restarted** (:mod:`.comparison`): when the free run names nothing and leaves only drive-train effects
   open (a resonance may be open beside them, and stays so), those candidates are judged again, steps 2-8 on windows that restart the drive train's load from the
   measured angle (a multi-step-ahead prediction error): a load rattling in a play, which no free run follows,
   is named there; only a name left open can come out, and the record is never ``explained`` by it.
10. **The drive's torque** (:mod:`.drive_torque`): given the torque the drive reported, a weight the angle left
    open beside the sensor errors that sag it alike is looked for in the torque: when the drive carries it, the
    record is diagnosed again without those sensor errors and the weight is named.

:mod:`.pipeline` runs the steps (:func:`diagnose_model`, settings :class:`DiagnoseOptions` in
:mod:`.options`); :mod:`.result` holds the result types (:class:`DiscrepancyResult`, the JSON
:class:`DiscrepancyReport`); every threshold and tuned setting, with its reason and evidence, is in
:mod:`.thresholds`.

The start model and all fits use only the estimation segment; every number quoted as a gap is measured on
the validation segment, which the fits never see.
"""

from __future__ import annotations

from identify.effect_catalogue import EFFECT_NAMES
from identify.model_discrepancy.candidates import drive_train_like, rigid_train_like, two_mass_train_like
from identify.model_discrepancy.disagreement import disagreement, gross_disagreements
from identify.model_discrepancy.options import DiagnoseOptions
from identify.model_discrepancy.pipeline import diagnose_model
from identify.model_discrepancy.result import (
    ACCEPTANCES,
    VERDICTS,
    CandidateResult,
    Disagreement,
    DisagreementWindow,
    DiscrepancyReport,
    DiscrepancyResult,
    DiscrepancyStep,
    GrossDisagreement,
    LinearFit,
    MissingEffect,
    ResidualStructure,
)
from identify.model_discrepancy.start_model import fit_linear_model
from identify.model_discrepancy.thresholds import ESTIMATION_FRACTION, REFIT_FOLDS, VALIDATION_BLOCKS

__all__ = [
    "DisagreementWindow",
    "Disagreement",
    "DiscrepancyStep",
    "DiscrepancyResult",
    "DiscrepancyReport",
    "MissingEffect",
    "LinearFit",
    "EFFECT_NAMES",
    "CandidateResult",
    "DiagnoseOptions",
    "diagnose_model",
    "disagreement",
    "gross_disagreements",
    "GrossDisagreement",
    "ResidualStructure",
    "fit_linear_model",
    "drive_train_like",
    "rigid_train_like",
    "two_mass_train_like",
    "VERDICTS",
    "ACCEPTANCES",
    "ESTIMATION_FRACTION",
    "REFIT_FOLDS",
    "VALIDATION_BLOCKS",
]
