"""The simulated gearbox: plant model, measurement noise and load encoder, one sample per call.

Signal path per sample t (Cerone et al. 2009, eq. (4), with the encoder of DESIGN.md section 4)::

    command_rad --PlantModel--> w_t (load_angle_rad, the truth)
                 + eta_t (noise) --EncoderResolution.counts_from_rad--> encoder_counts
                 encoder_counts --rad_from_counts--> measured_angle_rad

``step(command_rad)`` advances one sample (the simulated CANopen, CAN and serial devices tick it once per
SYNC or received frame); ``simulate(command_rad)`` runs a whole array from rest and gives the same numbers
as stepping a fresh gearbox built with the same seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.backlash_wear import PlayTrace, simulate_with_play, wearing_backlash_of
from identify.plant_blocks import PlantModel
from identify.validation import InvalidInputError, as_signal, positive
from rig.protocols.encoder_counts import EncoderResolution
from sim_backend.noise import NoiseModel, NoNoise

__all__ = ["GearboxSample", "GearboxTrajectory", "SimulatedGearbox"]


@dataclass(frozen=True)
class GearboxSample:
    """One sample of the simulated gearbox.

    Attributes
    ----------
    load_angle_rad
        The true (noise-free) load angle w_t.
    measured_angle_rad
        What the rig measures: the encoder reading of w_t + eta_t, converted back to radians (continuous
        across the encoder's wrap).
    encoder_counts
        The position value the CiA 406 device reports (wrapped, signed or not, with direction and offset).
    motor_torque_nm
        The motor's torque at the sample's instant, for a plant that models a motor (a drive_train block;
        :attr:`SimulatedGearbox.gives_motor_torque`), else None.
    """

    load_angle_rad: float
    measured_angle_rad: float
    encoder_counts: int
    motor_torque_nm: float | None = None


@dataclass(frozen=True)
class GearboxTrajectory:
    """A whole run: the arrays of :class:`GearboxSample` fields plus time and command, and for a plant whose
    backlash wears (:mod:`identify.backlash_wear`) the true half-widths of the play at every sample."""

    time_s: NDArray[np.float64]
    command_rad: NDArray[np.float64]
    load_angle_rad: NDArray[np.float64]
    measured_angle_rad: NDArray[np.float64]
    encoder_counts: NDArray[np.int64]
    play: PlayTrace | None = None

    def __post_init__(self) -> None:
        lengths = {len(getattr(self, name)) for name in
                   ("time_s", "command_rad", "load_angle_rad", "measured_angle_rad", "encoder_counts")}
        if self.play is not None:
            lengths.add(len(self.play))
        if len(lengths) != 1:
            raise InvalidInputError(f"GearboxTrajectory: arrays of different lengths {sorted(lengths)}")

    def __len__(self) -> int:
        return len(self.time_s)


@dataclass
class SimulatedGearbox:
    """A gearbox on a simulated rig: :class:`~identify.plant_blocks.PlantModel`, noise and encoder.

    Parameters
    ----------
    plant
        The physics, in signal order.
    encoder
        The load encoder's resolution and counting convention.
    noise
        Additive measurement noise on the load angle (:mod:`sim_backend.noise`); quantisation only by
        default. A model given by an SNR must be :meth:`calibrated_for` a command before stepping.
    sample_period_s
        The rig's sample period; defaults to the plant's.
    seed
        Seed of the noise generator; None draws one from the OS and records it in :attr:`seed`.
    name
        A label recorded in logs (e.g. the plant config's name).
    """

    plant: PlantModel
    encoder: EncoderResolution
    noise: NoiseModel = field(default_factory=NoNoise)
    sample_period_s: float | None = None
    seed: int | None = None
    name: str = "simulated gearbox"

    def __post_init__(self) -> None:
        if not isinstance(self.plant, PlantModel):
            raise InvalidInputError(f"plant: expected a PlantModel, got {type(self.plant).__name__}")
        if not isinstance(self.encoder, EncoderResolution):
            raise InvalidInputError(f"encoder: expected an EncoderResolution, got {type(self.encoder).__name__}")
        period = self.sample_period_s if self.sample_period_s is not None else self.plant.sample_period_s
        if period is None:
            raise InvalidInputError("sample_period_s: the plant has no block with a sample period, so give one")
        self.sample_period_s = positive("sample_period_s", period)
        plant_period = self.plant.sample_period_s
        if plant_period is not None and not math.isclose(plant_period, self.sample_period_s, rel_tol=1e-12):
            raise InvalidInputError(
                f"sample_period_s: {self.sample_period_s:g} s differs from the plant's {plant_period:g} s"
            )
        if self.seed is None:
            self.seed = int(np.random.SeedSequence().entropy % (1 << 63))
        self.reset()

    # -- properties recorded in logs ---------------------------------------------------------------------

    @property
    def noise_bound_rad(self) -> float:
        """Bound of the additive noise alone (``inf`` for Gaussian noise)."""
        return float(self.noise.noise_bound_rad)

    @property
    def gives_motor_torque(self) -> bool:
        """Whether the plant models a motor whose torque :meth:`step` reports (a drive_train block)."""
        return getattr(self._stepper, "motor_torque_nm", None) is not None

    @property
    def measurement_error_bound_rad(self) -> float:
        """|measured - true| <= additive bound + half a count of the encoder."""
        return self.noise_bound_rad + self.encoder.quantization_bound_rad

    # -- running -----------------------------------------------------------------------------------------

    def reset(self) -> None:
        """Back to rest, and restart the noise from :attr:`seed`."""
        self._stepper = self.plant.stepper()
        if getattr(self.noise, "needs_reference", False):
            self._noise = None
        else:
            self._noise = self.noise.sampler(np.random.default_rng(self.seed))
        self.samples = 0

    def calibrated_for(self, command_rad: ArrayLike) -> SimulatedGearbox:
        """A fresh gearbox whose SNR-given noise level is fixed from the noise-free response to
        ``command_rad`` (the same gearbox, reset, if the noise level is already absolute)."""
        command = as_signal("command_rad", command_rad, min_samples=2)
        noise = self.noise
        if getattr(noise, "needs_reference", False):
            noise = noise.resolved(self.plant.simulate(command))
        return SimulatedGearbox(self.plant, self.encoder, noise, self.sample_period_s, self.seed, self.name)

    def step(self, command_rad: float) -> GearboxSample:
        """Advance one sample with the drive commanded to ``command_rad`` and read the encoder."""
        if self._noise is None:
            raise InvalidInputError(
                f"noise: {self.noise.kind} noise is given as an SNR; use calibrated_for(command) to fix its level "
                "before stepping"
            )
        load = self._stepper.step(command_rad)
        noisy = load + self._noise.next()
        counts = self.encoder.counts_from_rad(noisy)
        measured = self.encoder.rad_from_counts(counts, near_rad=noisy)
        self.samples += 1
        return GearboxSample(load_angle_rad=load, measured_angle_rad=measured, encoder_counts=counts,
                             motor_torque_nm=getattr(self._stepper, "motor_torque_nm", None))

    def simulate(self, command_rad: ArrayLike) -> GearboxTrajectory:
        """Run a whole command array from rest with the noise restarted from :attr:`seed`; equal, sample for
        sample, to stepping ``self.calibrated_for(command_rad)`` from rest. Leaves this gearbox reset."""
        command = as_signal("command_rad", command_rad)
        gearbox = self.calibrated_for(command) if getattr(self.noise, "needs_reference", False) else self
        if wearing_backlash_of(self.plant) is None:
            load, play = self.plant.simulate(command), None
        else:
            load, play = simulate_with_play(self.plant, command)
        noise = gearbox.noise.sampler(np.random.default_rng(self.seed)).draw(command.size)
        noisy = load + noise
        counts = self.encoder.counts_from_rad(noisy)
        measured = self.encoder.rad_from_counts(counts, near_rad=noisy)
        self.reset()
        return GearboxTrajectory(
            time_s=np.arange(command.size) * self.sample_period_s,
            command_rad=command,
            load_angle_rad=load,
            measured_angle_rad=np.asarray(measured, dtype=float),
            encoder_counts=np.asarray(counts, dtype=np.int64),
            play=play,
        )
