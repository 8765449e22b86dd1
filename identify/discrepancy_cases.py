"""Hidden-effect test records for the model-discrepancy workflow: a linear gearbox model plus
effects with randomised parameters of realistic size, read by an n-bit absolute encoder.

The nominal model is the drive position loop of ``configs/plants/precision_gearbox.toml`` (30 Hz,
zeta 0.7, zero-order hold at 1 kHz, one sample of latency). Effect sizes (drawn by each catalogue entry's
``random_block``, :mod:`identify.effect_catalogue`; motor-side radians, input range about +-1 rad): backlash half-widths 0.01-0.04 rad; dead zone edges 0.03-0.10 rad; each saturation limit
at 50-75 % of the largest command on its side that both the estimation and the validation segment reach;
delay 3-15 samples; Coulomb friction breakaway twist 0.015-0.04 rad with sliding 40-75 % of it; resonance
60-200 Hz with damping 0.02-0.08; gain error 3-15 % either way (a wrong gear ratio or encoder resolution).

The drive-train effects (placement ``"dynamics"``) replace the nominal linear block with the rigid drive
train of the same response (:func:`identify.model_discrepancy.rigid_train_like`) holding them: friction on
the load whose Coulomb part holds the loop within 8-25 mrad (breakaway 1-1.5 times it, viscous up to a
fifth of the loop's damping); an arm whose weight sags the loop by 10-40 mrad when horizontal, hanging
within +-0.5 rad of zero; a speed limit at 40-70 % and a torque limit at 30-60 % of the peak speed or
acceleration that both segments reach; a play of 20-60 mrad (total width) between the motor and the load
inertia, closed by the catalogue's contact shaft (``PLAY_CONTACT_FREQUENCY_RATIO``); dry friction inside a
compliant shaft (its mode at twice the loop's bandwidth, damping ratio 0.05) holding 2-6 mrad of twist. Several
dynamics effects go into the one train. An effect inside the shaft needs the model to have the shaft
(catalogue ``needs_shaft``): its record's nominal model is that train with the shaft and without the effects,
the model a user of a two-mass drive train has; every other record's is the linear loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from identify.drive_train import DriveTrain
from identify.effect_catalogue import effect
from identify.model_discrepancy import ESTIMATION_FRACTION, rigid_train_like
from identify.plant_blocks import Block, LinearBlock, PlantModel

__all__ = ["HiddenEffectRecord", "NOMINAL_LINEAR", "hidden_effect_record", "random_effect", "step_excitation"]

SAMPLE_PERIOD_S = 0.001
NOMINAL_LINEAR = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362),
                             sample_period_s=SAMPLE_PERIOD_S)
"""The drive position loop of the precision gearbox (30 Hz, zeta 0.7, ZOH at 1 kHz, one sample latency)."""


@dataclass(frozen=True)
class HiddenEffectRecord:
    """A simulated measurement and the truth behind it."""

    command_rad: NDArray[np.float64]
    angle_rad: NDArray[np.float64]
    noise_bound_rad: float
    sample_period_s: float
    nominal_model: PlantModel
    true_model: PlantModel
    effects: tuple[str, ...]


def step_excitation(num_samples: int, rng: np.random.Generator, amplitude_rad: float = 1.0) -> NDArray[np.float64]:
    """Random steps held 40-250 samples, levels uniform in +-``amplitude_rad``, every third level small
    (within 15 % of the amplitude) so that behaviour near zero is seen, every other transition a step, the others ramps of 1-400 samples."""
    samples = int(num_samples)
    out = np.empty(samples)
    k, level, index = 0, 0.0, 0
    while k < samples:
        hold = int(rng.integers(40, 250))
        target = amplitude_rad * rng.uniform(-1.0, 1.0) * (0.15 if index % 3 == 2 else 1.0)
        ramp = 1 if index % 2 else int(rng.integers(1, 400))
        segment = np.concatenate((np.linspace(level, target, ramp + 1)[1:], np.full(hold, target)))
        out[k: k + segment.size] = segment[: samples - k]
        k += segment.size
        level, index = target, index + 1
    return out


def random_effect(name: str, rng: np.random.Generator, command_rad: NDArray[np.float64]) -> tuple[Block, int | None]:
    """A block of effect ``name`` with random realistic parameters (the catalogue's ``random_block``) and
    where it goes in the chain (0: before the linear block, None: after it; a dynamics effect's block is a
    drive train whose fields :func:`hidden_effect_record` merges into the nominal one)."""
    entry = effect(name)
    block = entry.random_block(rng, command_rad, ESTIMATION_FRACTION, SAMPLE_PERIOD_S)
    return block, (0 if entry.placement == "input" else None)


def hidden_effect_record(effects: tuple[str, ...], seed: int, num_samples: int = 3000, encoder_bits: int = 12,
                         noise_amplitude_rad: float = 2.0e-4) -> HiddenEffectRecord:
    """Simulate the nominal linear model plus ``effects`` (possibly none) on a random step excitation of
    ``num_samples`` samples, and measure the output with an ``encoder_bits`` absolute encoder (one count
    2 pi / 2^bits) plus uniform noise of at most ``noise_amplitude_rad``; the noise bound is half a count plus
    ``noise_amplitude_rad``."""
    rng = np.random.default_rng(seed)
    samples, noise_rad = int(num_samples), float(noise_amplitude_rad)
    u = step_excitation(samples, rng)
    model = nominal = PlantModel((NOMINAL_LINEAR,))
    for name in effects:
        block, index = random_effect(name, rng, u)
        entry = effect(name)
        if entry.placement == "dynamics":  # its fields go into the train that replaces the linear block
            at = next(i for i, b in enumerate(model.blocks) if isinstance(b, (LinearBlock, DriveTrain)))
            train = model.blocks[at]
            if isinstance(train, LinearBlock):
                train = rigid_train_like(train, u)
            train = replace(train, **{key.key: getattr(block, key.key) for key in entry.toml_keys})
            model = PlantModel(model.blocks[:at] + (train,) + model.blocks[at + 1:])
            if entry.needs_shaft:  # the model knows the shaft the effect acts in
                shaft = ("shaft_stiffness_nm_per_rad", "shaft_damping_nm_s_per_rad")
                nominal = PlantModel((replace(rigid_train_like(NOMINAL_LINEAR, u),
                                              **{key: getattr(block, key) for key in shaft}),))
        elif index is None:
            model = model.with_block(block)
        else:
            model = model.with_block(block, index)
    x = model.simulate(u) + rng.uniform(-noise_rad, noise_rad, samples)
    count = 2.0 * math.pi / 2 ** encoder_bits
    y = np.round(x / count) * count
    return HiddenEffectRecord(u, y, 0.5 * count + noise_rad, SAMPLE_PERIOD_S, nominal, model, tuple(effects))
