"""How a model is compared with the record: its free run from rest over the whole record, or, when the free run
cannot follow the record, its run on short windows that restart the load from the measured angle: a
multi-step-ahead prediction error, the simpler sibling of multiple shooting (which fits each window's initial
state as well), both in Ribeiro, Tiels, Umenberger, Schön and Aguirre (2020), "On the smoothness of nonlinear
system identification", Automatica 121, 109158: a free run's cost can grow ragged exponentially with its length
where the model is not contractive, as a rattling play is not.

A load that rattles in a gear's play makes the free run a poor comparison: which flank it meets, and when,
depends on its motion so finely that a play a tenth of a percent wider can move the simulated angle by a dozen
noise bounds, so the free run's error against the play is shallow and ragged (the true play lowers it by a tenth
to a fifth on a steps record) and a fit of the play stops far from its width. Restarted every
:data:`~.thresholds.RESTART_WINDOW_S`, the run keeps the load's simulated velocity and the rest of the drive
train's state, and moves the load angle by the output error of the sample before: within a window the model has
to predict the motion from where the load really is, which a right play does and a wrong one does not. The
error against the play then has a deep minimum at the true width (``benchmarks/restarted_comparison.py``).

The comparison in force is set for a block of code by :func:`restarted_every` and read by :func:`simulated`,
the one function every residual of the workflow comes from; outside such a block the free run is used. Only a
model with a :class:`~identify.drive_train.DriveTrain` can be restarted (its load angle is a state); any
other model runs free under either comparison.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

import numpy as np
from numpy.typing import NDArray

from identify.drive_train import DriveTrain
from identify.plant_blocks import Block, PlantModel

_RESTART_SAMPLES: ContextVar[int | None] = ContextVar("restart_samples", default=None)


@contextmanager
def restarted_every(samples: int) -> Iterator[None]:
    """Within the block, every model with a drive train is compared on windows of ``samples`` samples that
    restart its load from the measured angle (:func:`simulated`)."""
    if samples < 2:
        raise ValueError(f"samples: expected a window of at least 2 samples, got {samples}")
    token = _RESTART_SAMPLES.set(int(samples))
    try:
        yield
    finally:
        _RESTART_SAMPLES.reset(token)


def restartable(model: PlantModel) -> bool:
    """Whether ``model`` has a load state to restart (a drive train)."""
    return any(isinstance(block, DriveTrain) for block in model.blocks)


def simulated(model: PlantModel, u: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """The model's output on command ``u`` under the comparison in force: its free run from rest, or its run
    restarted every window from the measured ``y`` (NaN: not measured, no restart there)."""
    window = _RESTART_SAMPLES.get()
    if window is None:
        return free_run(model, u)
    return restarted_run(model, u, y, window)


TRAIN_RUNS_KEPT = 4
"""How many runs of a drive train (with the blocks before it, on one command) :func:`free_run` keeps per thread:
a fit of a sensor's effect runs one train hundreds of times, and the search moves between a few."""

_TRAIN_RUNS = threading.local()


def free_run(model: PlantModel, u: NDArray[np.float64]) -> NDArray[np.float64]:
    """``model.simulate(u)``, bit for bit, with the run of its blocks up to its last drive train kept for the next
    runs of the same blocks on the same command (:data:`TRAIN_RUNS_KEPT`): a fit of an effect after the train (a
    sensor's offset, gain or once-per-revolution error) moves only the blocks after it, and the train's kernel
    is most of what a run costs."""
    blocks = model.blocks
    at = max((i for i, block in enumerate(blocks) if isinstance(block, DriveTrain)), default=None)
    if at is None:
        return np.asarray(model.simulate(u), dtype=float)
    through_train = blocks[:at + 1]
    runs: list[tuple[tuple[Block, ...], NDArray[np.float64], NDArray[np.float64]]] = getattr(_TRAIN_RUNS, "runs", [])
    _TRAIN_RUNS.runs = runs
    for kept_blocks, command, output in runs:
        if command.shape == u.shape and _same_blocks(kept_blocks, through_train) and np.array_equal(command, u):
            break
    else:
        output = np.asarray(PlantModel(through_train).simulate(u), dtype=float)
        runs.insert(0, (through_train, np.array(u, dtype=float), output))
        del runs[TRAIN_RUNS_KEPT:]
    signal = output.copy()
    for block in blocks[at + 1:]:
        signal = block.apply(signal)
    return np.asarray(signal, dtype=float)


def _same_blocks(a: tuple[Block, ...], b: tuple[Block, ...]) -> bool:
    """Whether two chains of blocks are equal field by field (a block holding an array compares as different)."""
    try:
        return bool(a == b)
    except ValueError:
        return False


def restarted_run(model: PlantModel, u: NDArray[np.float64], y: NDArray[np.float64],
                  window: int) -> NDArray[np.float64]:
    """The output of ``model`` on ``u``, its last drive train's load angle moved at the start of every window of
    ``window`` samples by the output error of the sample before, y_{k-1} - y^_{k-1} (the blocks after the drive
    train are taken to pass a small change of the load angle on unscaled, as a sensor's offset, gain or
    once-per-revolution error do). The blocks before the drive train run free; the train keeps every other
    state (the load's velocity, the motor's angle and velocity, the controller's integral). A model without a
    drive train has no load to restart: its free run."""
    if not restartable(model):
        return np.asarray(model.simulate(u), dtype=float)
    blocks = model.blocks
    at = max(i for i, block in enumerate(blocks) if isinstance(block, DriveTrain))
    train = blocks[at]
    assert isinstance(train, DriveTrain)
    command = np.asarray(PlantModel(blocks[:at]).simulate(u) if at else u, dtype=float)
    after = [block.stepper() for block in blocks[at + 1:]]
    stepper = train.stepper()
    out = np.empty(command.size)
    for start in range(0, command.size, window):
        if start:
            error = y[start - 1] - out[start - 1]
            if np.isfinite(error):
                stepper.theta = stepper.theta + float(error)
        load = stepper.run(command[start:start + window])[:, 0]
        for block in after:
            load = np.array([block.step(float(v)) for v in load])
        out[start:start + window] = load
    return out
