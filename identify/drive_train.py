"""A physical drive train: position-controlled motor, gear with play, compliant shaft with internal friction,
load with friction and gravity, integrated with fixed sub-steps per sample.

The series blocks of :mod:`identify.plant_blocks` apply one effect after another to a signal; here the
effects act on each other inside the dynamics (the friction opposes the load's own velocity, the play opens
and closes with the motion of two inertias, the drive's limits act on the torque that moves them). The block
has the same interface as every plant block (:meth:`DriveTrain.apply`, :meth:`DriveTrain.stepper`), so it
sits in a :class:`~identify.plant_blocks.PlantModel` chain: its input is the commanded load angle (rad), its
output the load angle (rad).

Model (all quantities referred to the load side of the gear, ratio N = ``gear_ratio`` motor rad per load rad;
phi = motor angle / N, J_m' = N^2 J_m, tau_drive = N tau_motor):

.. math::

    J_m' \\ddot\\phi &= \\tau_{drive} - \\tau_{shaft} - N^2 d_m \\dot\\phi \\\\
    J_l \\ddot\\theta &= \\tau_{shaft} - \\tau_{friction} - m g l \\sin(\\theta - \\theta_0)

* **Shaft with play** (the "dead-zone model" of the modelling part of Nordin and Gutman 2002, "Controlling
  mechanical systems with backlash - a survey", Automatica 38:1633-1649): with the twist
  Delta = phi - theta and the play of total width b, tau_shaft = k dz(Delta) + d dDelta/dt, dz(Delta) = Delta - b/2 for Delta > b/2,
  Delta + b/2 for Delta < -b/2, 0 inside. The damping term is handled as in Modelica's
  ``Modelica.Mechanics.Rotational.Components.ElastoBacklash``: inside the play the torque is 0 (no damping
  across an open gap); in contact, tau_c = k dz(Delta), tau_d = d dDelta/dt and
  tau_shaft = 0 if tau_c + tau_d <= 0 else tau_c + min(tau_c, tau_d) (for Delta > b/2; mirrored for
  Delta < -b/2), so the contact never pulls and the torque is continuous at the start of contact
  (|tau_d| <= |tau_c|). With b = 0 it is the plain spring-damper k Delta + d dDelta/dt.
* **Dry friction inside the shaft** (a coupling's or a flexspline's internal friction, the hysteresis of
  its torque against its twist): the friction model of Dahl (1976), "Solid friction damping of mechanical
  vibrations", AIAA Journal 14:1675-1682, in parallel with the spring: tau_shaft gains T_h w with
  dw/dx = (1 - w sgn(dx)) / d_h, x the spring's deflection dz(Delta), T_h the torque at which the friction
  slides and d_h its presliding twist (its stiffness T_h / d_h at w = 0). The friction's torque stays
  within +-T_h and is a function of the deflection's path, not of its rate. Over a drift of the deflection
  by dx the equation is solved exactly, w <- s + (w - s) exp(-|dx| / d_h) with s = sgn(dx), so |w| never
  exceeds 1 however stiff the friction. While a play is open the shaft carries no torque and the friction
  relaxes (w = 0).
* **Load friction**: Coulomb T_c, viscous d_v and static (breakaway) T_s >= T_c, with the stick model of
  Karnopp (1985), "Computer simulation of stick-slip friction in mechanical dynamic systems", J. Dyn. Sys.
  Meas. Control 107:100-103: a load at rest stays at rest while the net torque on it,
  |tau_shaft - tau_gravity| <= T_s (the friction balances it); otherwise it slides with
  tau_friction = T_c sign(omega) + d_v omega. Karnopp's zero-velocity band is the set of velocities that
  the sliding friction T_c brings to zero within one half sub-step (an implicit Coulomb step), so a stuck
  load has omega exactly 0 and never drifts, and no band width has to be tuned.
* **Gravity**: m g l sin(theta - theta_0) with theta_0 the angle at which the arm hangs straight down.
* **Drive**: a cascaded position loop (P or PI position controller giving a velocity reference, with
  velocity feedforward, then a P velocity loop giving the torque), tuned as a second-order servo with
  bandwidth f_n and damping ratio zeta on the nominal rigid inertia J = J_m' + J_l:

  .. math::

      v_{ref} &= \\mathrm{clip}(K_p (e + K_i \\textstyle\\int e\\,dt) + f \\dot r,\\ \\pm\\Omega/N), \\quad
      e = r - \\theta_{fb} \\\\
      \\tau_{drive} &= \\mathrm{clip}(K_v (v_{ref} - \\dot\\phi),\\ \\pm N \\tau_{max}), \\quad
      K_v = 2 \\zeta \\omega_n J,\\ K_p = \\omega_n / (2 \\zeta),

  so that a rigid load without friction follows r with the second-order response
  omega_n^2 / (s^2 + 2 zeta omega_n s + omega_n^2) (for f = 0 and K_i = 0; with f = 1 a ramp is followed
  without velocity lag). theta_fb is the motor angle (the drive's own encoder, ``position_feedback =
  "motor"``) or the load angle (an output-shaft encoder, as in hobby servos, ``"load"``). Omega is the
  motor speed limit (rad/s at the motor) and tau_max the motor torque limit (N m at the motor).

Sampling: the command r_t is held over the sample (zero-order hold) and its feedforward rate is the
backward difference (r_t - r_{t-1}) / T. ``step(r_t)`` returns the load angle at the start of the sample,
before r_t acts (strictly proper, like a ZOH-discretised linear block with b0 = 0), then integrates the
sample.

Integration: Störmer-Verlet (kick-drift-kick leapfrog) with a fixed number of sub-steps per sample,
:attr:`DriveTrain.substeps_per_sample`. For conservative forces (springs, play, gravity) it is symplectic
and second order, so the energy of an undamped, undriven train stays bounded with an error of order
(h omega)^2; the velocity-dependent torques (dampers, velocity loop) are evaluated explicitly at the start
of each half kick, the load friction implicitly inside each half kick. The sub-step rule: h omega_max <=
:data:`SUBSTEP_PHASE_RAD` where omega_max is the fastest rate of the linearised train (the shaft's
two-mass mode, stiffened by the shaft's friction just after a reversal, the velocity loop acting on the motor
alone while the play is open, the position loop, the pendulum, and the damping rates), i.e.
``ceil(T omega_max / SUBSTEP_PHASE_RAD)`` sub-steps per sample, with SUBSTEP_PHASE_RAD = 0.04 (its docstring
says why). The per-sample recurrence is one function compiled with numba (``_run_kernel``, cached on disk):
``apply``, ``simulate`` and ``step`` all run it, so stepping gives ``apply`` bit for bit; IEEE arithmetic
without fast-math, so a run is deterministic and equal to the pure Python recurrence it replaced
(``tests/identify/drive_train_reference.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.validation import InvalidInputError, as_signal, finite

__all__ = [
    "MAX_SUBSTEPS_PER_SAMPLE",
    "POSITION_FEEDBACK",
    "RECORD_COLUMNS",
    "SUBSTEP_PHASE_RAD",
    "DriveTrain",
    "DriveTrainStepper",
    "DriveTrainTrajectory",
]

SUBSTEP_PHASE_RAD = 0.04
"""Largest h omega_max per sub-step. Störmer-Verlet on a linear mode of frequency omega keeps a modified
energy exactly; the true energy then oscillates with a relative amplitude of about (h omega)^2 / 4, here
4e-4. The kinks of the play (contact opens and closes inside a sub-step) add to it: a shaft pre-twisted
into contact and ringing through the play for 3 s stayed within 4.1e-4 (8.7e-4 at 0.05), inside the 1e-3 the
energy test asks for. The explicit damping and velocity-loop terms are stable for h rate < 2 and accurate
to a few parts in a thousand here."""

MAX_SUBSTEPS_PER_SAMPLE = 20000
"""More sub-steps than this per sample is refused: the train is so stiff against the sample period that a
run would take minutes; lower the stiffness or the gains, or sample faster."""

POSITION_FEEDBACK = ("motor", "load")
"""Where the drive's position loop measures: the motor encoder (angle / N) or the load (output) encoder."""

STANDARD_GRAVITY_M_PER_S2 = 9.80665


def _positive(name: str, value: float) -> float:
    number = finite(name, value)
    if number <= 0.0:
        raise InvalidInputError(f"{name}: expected a finite number > 0, got {value!r}")
    return number


def _non_negative(name: str, value: float) -> float:
    number = finite(name, value)
    if number < 0.0:
        raise InvalidInputError(f"{name}: expected a finite number >= 0, got {value!r}")
    return number


def _limit(name: str, value: float) -> float:
    """A limit: > 0, and math.inf for none."""
    try:
        number = float(value)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"{name}: expected a number > 0 or inf (no limit), got {value!r}") from err
    if math.isnan(number) or number <= 0.0:
        raise InvalidInputError(f"{name}: expected a number > 0 or inf (no limit), got {value!r}")
    return number


@dataclass(frozen=True)
class DriveTrain:
    """Position-controlled motor, gear with play between the two inertias, compliant shaft (optionally with dry
    friction inside it), load with Coulomb, viscous and static friction and an optional gravity torque; the model
    of the module docstring.

    Parameters
    ----------
    sample_period_s
        Sample period T of the command and the output.
    gear_ratio
        N > 0: motor radians per load radian (a reducer has N > 1).
    motor_inertia_kg_m2
        J_m > 0, the rotor's inertia at the motor shaft (plus anything rigidly on it before the play).
    load_inertia_kg_m2
        J_l > 0, the load's inertia about its axis (for a pendulum arm at least m l^2).
    shaft_stiffness_nm_per_rad
        k > 0, the torsional stiffness between the gear and the load, at the load side (N m per load rad);
        ``math.inf``: a rigid shaft (see :attr:`rigid`; no play then).
    shaft_damping_nm_s_per_rad
        d >= 0, the shaft's damping at the load side; it acts only in contact (Modelica ElastoBacklash).
    play_rad
        b >= 0, total width of the play between the two inertias, in load radians (no contact while
        |phi - theta| < b/2).
    shaft_friction_nm
        T_h >= 0, the dry friction inside the shaft (Dahl's model, module docstring): the torque at which it
        slides, at the load side (0: none; a rigid shaft has none).
    shaft_presliding_twist_rad
        d_h > 0, the friction's presliding twist (load rad): its stiffness at zero friction torque is
        T_h / d_h, and after a reversal it reaches 1 - 1/e of its swing within d_h.
    position_loop_bandwidth_hz
        f_n > 0, natural frequency of the closed position loop on the nominal rigid train.
    position_loop_damping_ratio
        zeta > 0 of the closed position loop.
    velocity_feedforward
        f in [0, 1]: the fraction of the command's rate added to the velocity reference (1: ramps are
        followed without velocity lag).
    position_integral_gain_per_s
        K_i >= 0 of the PI position controller K_p (1 + K_i / s) (0: P only). Integration stops while the
        velocity reference or the torque is at its limit (anti-windup by conditional integration).
    position_feedback
        ``"motor"`` (the drive's motor encoder, angle / N) or ``"load"`` (an encoder on the output).
    motor_speed_limit_rad_per_s
        Omega > 0, the largest velocity reference, in rad/s at the motor (``math.inf``: none).
    motor_torque_limit_nm
        tau_max > 0, the largest torque the drive gives, in N m at the motor (``math.inf``: none).
    motor_viscous_damping_nm_s_per_rad
        d_m >= 0, viscous damping at the motor shaft (bearings, back-EMF of an open winding).
    coulomb_friction_nm
        T_c >= 0, the load's sliding friction torque.
    static_friction_nm
        T_s >= T_c, the breakaway torque of a load at rest (T_s = T_c: no stiction beyond Coulomb).
    viscous_friction_nm_s_per_rad
        d_v >= 0, the load's viscous friction.
    pendulum_mass_kg, pendulum_length_m
        m >= 0 and l >= 0 of the gravity torque m g l sin(theta - theta_0) (0: no gravity).
    gravity_m_per_s2
        g > 0.
    hanging_angle_rad
        theta_0, the load angle at which the arm hangs straight down.
    initial_angle_rad
        Load and motor (referred) angle at rest before the first sample; the play starts centred.
    drive_enabled
        False: the drive gives no torque (torque off); the load moves the motor back through the gear.

    Examples
    --------
    A rigid 1:10 train following a unit step with the second-order response of its position loop:

    >>> train = DriveTrain(sample_period_s=1e-3, gear_ratio=10.0, motor_inertia_kg_m2=1e-5,
    ...                    load_inertia_kg_m2=1e-2, shaft_stiffness_nm_per_rad=1e3,
    ...                    shaft_damping_nm_s_per_rad=0.5, position_loop_bandwidth_hz=5.0,
    ...                    position_loop_damping_ratio=1.0)
    >>> y = train.apply(np.ones(2000))
    >>> round(float(y[-1]), 3)
    1.0
    """

    sample_period_s: float
    gear_ratio: float
    motor_inertia_kg_m2: float
    load_inertia_kg_m2: float
    shaft_stiffness_nm_per_rad: float
    shaft_damping_nm_s_per_rad: float = 0.0
    play_rad: float = 0.0
    shaft_friction_nm: float = 0.0
    shaft_presliding_twist_rad: float = 1.0e-3
    position_loop_bandwidth_hz: float = 5.0
    position_loop_damping_ratio: float = 0.7
    velocity_feedforward: float = 0.0
    position_integral_gain_per_s: float = 0.0
    position_feedback: str = "motor"
    motor_speed_limit_rad_per_s: float = math.inf
    motor_torque_limit_nm: float = math.inf
    motor_viscous_damping_nm_s_per_rad: float = 0.0
    coulomb_friction_nm: float = 0.0
    static_friction_nm: float = 0.0
    viscous_friction_nm_s_per_rad: float = 0.0
    pendulum_mass_kg: float = 0.0
    pendulum_length_m: float = 0.0
    gravity_m_per_s2: float = STANDARD_GRAVITY_M_PER_S2
    hanging_angle_rad: float = 0.0
    initial_angle_rad: float = 0.0
    drive_enabled: bool = True

    def __post_init__(self) -> None:
        positive_fields = ("sample_period_s", "gear_ratio", "motor_inertia_kg_m2", "load_inertia_kg_m2",
                           "position_loop_bandwidth_hz",
                           "position_loop_damping_ratio", "gravity_m_per_s2", "shaft_presliding_twist_rad")
        for name in positive_fields:
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        non_negative_fields = ("shaft_damping_nm_s_per_rad", "play_rad", "shaft_friction_nm",
                               "position_integral_gain_per_s",
                               "motor_viscous_damping_nm_s_per_rad", "coulomb_friction_nm", "static_friction_nm",
                               "viscous_friction_nm_s_per_rad", "pendulum_mass_kg", "pendulum_length_m")
        for name in non_negative_fields:
            object.__setattr__(self, name, _non_negative(name, getattr(self, name)))
        for name in ("hanging_angle_rad", "initial_angle_rad"):
            object.__setattr__(self, name, finite(name, getattr(self, name)))
        for name in ("shaft_stiffness_nm_per_rad", "motor_speed_limit_rad_per_s", "motor_torque_limit_nm"):
            object.__setattr__(self, name, _limit(name, getattr(self, name)))
        feedforward = finite("velocity_feedforward", self.velocity_feedforward)
        if not 0.0 <= feedforward <= 1.0:
            raise InvalidInputError(f"velocity_feedforward: expected a fraction from 0 to 1, got {feedforward:g}")
        object.__setattr__(self, "velocity_feedforward", feedforward)
        if self.position_feedback not in POSITION_FEEDBACK:
            raise InvalidInputError(
                f"position_feedback: expected one of {', '.join(POSITION_FEEDBACK)}, got {self.position_feedback!r}"
            )
        if not isinstance(self.drive_enabled, (bool, np.bool_)):
            raise InvalidInputError(f"drive_enabled: expected True or False, got {self.drive_enabled!r}")
        object.__setattr__(self, "drive_enabled", bool(self.drive_enabled))
        if self.rigid and self.play_rad > 0.0:
            raise InvalidInputError(
                f"play_rad: a rigid shaft (shaft_stiffness_nm_per_rad = inf) has no play, got {self.play_rad:g}; "
                "give a finite stiffness for a train with play"
            )
        if self.rigid and self.shaft_friction_nm > 0.0:
            raise InvalidInputError(
                f"shaft_friction_nm: a rigid shaft (shaft_stiffness_nm_per_rad = inf) does not twist, so it has no "
                f"friction inside it, got {self.shaft_friction_nm:g}; give a finite stiffness for a shaft with friction"
            )
        if self.static_friction_nm < self.coulomb_friction_nm:
            raise InvalidInputError(
                f"static_friction_nm: expected static_friction_nm >= coulomb_friction_nm "
                f"({self.coulomb_friction_nm:g}), got {self.static_friction_nm:g}"
            )
        point_mass_inertia = self.pendulum_mass_kg * self.pendulum_length_m**2
        if self.load_inertia_kg_m2 < point_mass_inertia * (1.0 - 1e-12):
            raise InvalidInputError(
                f"load_inertia_kg_m2: expected at least the pendulum's point-mass inertia m l^2 = "
                f"{point_mass_inertia:g} kg m^2, got {self.load_inertia_kg_m2:g}"
            )
        substeps = self.substeps_per_sample
        if substeps > MAX_SUBSTEPS_PER_SAMPLE:
            raise InvalidInputError(
                f"shaft_stiffness_nm_per_rad: the train's fastest rate {self.fastest_rate_rad_per_s:g} rad/s needs "
                f"{substeps} sub-steps per sample of {self.sample_period_s:g} s (at most {MAX_SUBSTEPS_PER_SAMPLE}); "
                "lower the stiffness, the loop bandwidth or the inertia ratio, or sample faster"
            )

    # -- derived quantities ------------------------------------------------------------------------------

    @property
    def rigid(self) -> bool:
        """An infinitely stiff shaft: motor and load move as one inertia N^2 J_m + J_l,

        .. math:: (J_m' + J_l) \\ddot\\theta = \\tau_{drive} - N^2 d_m \\dot\\theta - \\tau_{friction}
                  - m g l \\sin(\\theta - \\theta_0),

        the limit k -> inf of the module docstring's equations (the shaft damping then plays no part). The
        sub-step rule drops the shaft's rates, so a rigid train needs far fewer sub-steps than a stiff one:
        the form the model-discrepancy workflow fits (:mod:`identify.effect_catalogue`, placement
        ``"dynamics"``)."""
        return math.isinf(self.shaft_stiffness_nm_per_rad)

    @property
    def reflected_motor_inertia_kg_m2(self) -> float:
        """N^2 J_m: the motor's inertia seen from the load side."""
        return self.gear_ratio**2 * self.motor_inertia_kg_m2

    @property
    def total_inertia_kg_m2(self) -> float:
        """N^2 J_m + J_l: the rigid train's inertia at the load side (the position loop is tuned on it)."""
        return self.reflected_motor_inertia_kg_m2 + self.load_inertia_kg_m2

    @property
    def natural_frequency_rad_per_s(self) -> float:
        """omega_n = 2 pi f_n of the position loop."""
        return 2.0 * math.pi * self.position_loop_bandwidth_hz

    @property
    def position_gain_per_s(self) -> float:
        """K_p = omega_n / (2 zeta): velocity reference (load rad/s) per rad of position error."""
        return self.natural_frequency_rad_per_s / (2.0 * self.position_loop_damping_ratio)

    @property
    def velocity_gain_nm_s_per_rad(self) -> float:
        """K_v = 2 zeta omega_n (N^2 J_m + J_l), at the load side: torque per load rad/s of velocity error."""
        return 2.0 * self.position_loop_damping_ratio * self.natural_frequency_rad_per_s * self.total_inertia_kg_m2

    @property
    def servo_stiffness_nm_per_rad(self) -> float:
        """K_v K_p = omega_n^2 (N^2 J_m + J_l): the static stiffness of the P position loop at the load side."""
        return self.velocity_gain_nm_s_per_rad * self.position_gain_per_s

    @property
    def gravity_torque_nm(self) -> float:
        """m g l: the largest gravity torque (arm horizontal)."""
        return self.pendulum_mass_kg * self.gravity_m_per_s2 * self.pendulum_length_m

    @property
    def shaft_peak_stiffness_nm_per_rad(self) -> float:
        """k + 2 T_h / d_h: the shaft's stiffness just after a reversal of a sliding friction (Dahl's slope
        (1 - w sgn(dx)) / d_h is 2 / d_h at w = -sgn(dx)); k without friction."""
        return self.shaft_stiffness_nm_per_rad + 2.0 * self.shaft_friction_nm / self.shaft_presliding_twist_rad

    @property
    def fastest_rate_rad_per_s(self) -> float:
        """omega_max of the sub-step rule: the largest of the shaft's two-mass frequency at its peak
        stiffness sqrt((k + 2 T_h / d_h) (1/J_m' + 1/J_l)), its damping rate d (1/J_m' + 1/J_l), the
        pendulum's sqrt(m g l / J_l), the motor damping rate d_m N^2 / J_m' and, with the drive on, the velocity
        loop acting on the motor alone K_v / J_m' (the play open), omega_n, K_p and K_i."""
        motor = self.reflected_motor_inertia_kg_m2
        load = self.load_inertia_kg_m2
        if self.rigid:  # one inertia: no shaft mode, and the velocity loop acts on the whole train
            motor = load = self.total_inertia_kg_m2
            rates = [math.sqrt(self.gravity_torque_nm / load),
                     self.motor_viscous_damping_nm_s_per_rad * self.gear_ratio**2 / motor]
        else:
            compliance = 1.0 / motor + 1.0 / load
            rates = [
                math.sqrt(self.shaft_peak_stiffness_nm_per_rad * compliance),
                self.shaft_damping_nm_s_per_rad * compliance,
                math.sqrt(self.gravity_torque_nm / load),
                self.motor_viscous_damping_nm_s_per_rad / self.motor_inertia_kg_m2,
            ]
        if self.drive_enabled:
            rates += [self.velocity_gain_nm_s_per_rad / motor, self.natural_frequency_rad_per_s,
                      self.position_gain_per_s, self.position_integral_gain_per_s]
        return max(rates)

    @property
    def substeps_per_sample(self) -> int:
        """ceil(T omega_max / SUBSTEP_PHASE_RAD), at least 1 (module docstring)."""
        return max(1, math.ceil(self.sample_period_s * self.fastest_rate_rad_per_s / SUBSTEP_PHASE_RAD))

    # -- the block interface -------------------------------------------------------------------------------

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        """Run a whole command (load rad) from rest; the same numbers as stepping :meth:`stepper`."""
        return self.stepper().run(as_signal("signal", signal))[:, 0].copy()

    def stepper(self) -> DriveTrainStepper:
        """A fresh stepper at rest at ``initial_angle_rad``."""
        return DriveTrainStepper(self)

    def simulate(self, command_rad: ArrayLike) -> DriveTrainTrajectory:
        """Run a whole command from rest and return every state and torque at the sample instants."""
        command = as_signal("command_rad", command_rad)
        record = self.stepper().run(command)
        column = {name: record[:, index] for index, name in enumerate(RECORD_COLUMNS)}
        ratio = self.gear_ratio
        return DriveTrainTrajectory(
            time_s=np.arange(command.size) * self.sample_period_s, command_rad=command,
            load_angle_rad=column["load_angle_rad"].copy(),
            load_velocity_rad_per_s=column["load_velocity_rad_per_s"].copy(),
            motor_angle_rad=column["motor_angle_referred_rad"] * ratio,
            motor_velocity_rad_per_s=column["motor_velocity_referred_rad_per_s"] * ratio,
            motor_torque_nm=column["drive_torque_nm"] / ratio, shaft_torque_nm=column["shaft_torque_nm"].copy(),
            friction_torque_nm=column["friction_torque_nm"].copy(), stuck=column["stuck"] != 0.0,
        )

    def energy_j(self, trajectory: DriveTrainTrajectory) -> NDArray[np.float64]:
        """Kinetic + shaft + gravity energy at each sample: 1/2 J_m w_m^2 + 1/2 J_l w^2 + 1/2 k dz(Delta)^2
        + m g l (1 - cos(theta - theta_0)) (what an undamped, undriven train without friction conserves)."""
        half = 0.5 * self.play_rad
        twist = trajectory.motor_angle_rad / self.gear_ratio - trajectory.load_angle_rad
        dead = np.where(twist > half, twist - half, np.where(twist < -half, twist + half, 0.0))
        shaft = 0.0 if self.rigid else 0.5 * self.shaft_stiffness_nm_per_rad * dead**2
        return (0.5 * self.motor_inertia_kg_m2 * trajectory.motor_velocity_rad_per_s**2
                + 0.5 * self.load_inertia_kg_m2 * trajectory.load_velocity_rad_per_s**2
                + shaft
                + self.gravity_torque_nm * (1.0 - np.cos(trajectory.load_angle_rad - self.hanging_angle_rad)))


@dataclass(frozen=True)
class DriveTrainTrajectory:
    """A run of :class:`DriveTrain` at the sample instants t = k T (the states before command k acts; the
    torques are those acting at that instant, with command k).

    Attributes
    ----------
    time_s, command_rad
        Sample instants and the command (load rad).
    load_angle_rad, load_velocity_rad_per_s
        theta and its rate (the output of :meth:`DriveTrain.apply` is ``load_angle_rad``).
    motor_angle_rad, motor_velocity_rad_per_s
        At the motor shaft (N phi and N dphi/dt).
    motor_torque_nm
        The drive's torque at the motor shaft (within +-``motor_torque_limit_nm``).
    shaft_torque_nm
        The torque the shaft transmits to the load (0 while the play is open).
    friction_torque_nm
        The load's friction torque (opposing its motion, or balancing the load while stuck).
    stuck
        True while the load sticks (Karnopp).
    """

    COLUMNS = ("load_angle_rad", "load_velocity_rad_per_s", "motor_angle_rad", "motor_velocity_rad_per_s",
               "motor_torque_nm", "shaft_torque_nm", "friction_torque_nm")

    time_s: NDArray[np.float64]
    command_rad: NDArray[np.float64]
    load_angle_rad: NDArray[np.float64]
    load_velocity_rad_per_s: NDArray[np.float64]
    motor_angle_rad: NDArray[np.float64]
    motor_velocity_rad_per_s: NDArray[np.float64]
    motor_torque_nm: NDArray[np.float64]
    shaft_torque_nm: NDArray[np.float64]
    friction_torque_nm: NDArray[np.float64]
    stuck: NDArray[np.bool_]

    def __post_init__(self) -> None:
        count = len(self.time_s)
        for name in ("command_rad", *self.COLUMNS, "stuck"):
            if len(getattr(self, name)) != count:
                raise InvalidInputError(f"{name}: expected {count} samples, got {len(getattr(self, name))}")


class DriveTrainStepper:
    """Advances a :class:`DriveTrain` one sample per :meth:`step` (Störmer-Verlet sub-steps, compiled)."""

    __slots__ = ("_constants", "_substeps", "_ratio", "_state", "_command", "_record", "samples")

    def __init__(self, train: DriveTrain) -> None:
        self._ratio = train.gear_ratio
        self._substeps = train.substeps_per_sample
        self._constants = _kernel_constants(train)
        self._state = np.empty(_STATE_SIZE)
        self._command = np.empty(1)
        self._record = np.zeros((1, _RECORD_SIZE))
        self.reset(train.initial_angle_rad)

    def reset(self, angle_rad: float) -> None:
        """Back to rest at ``angle_rad`` (load and referred motor angle), play centred, integrator empty."""
        self._state[:] = _rest_state(finite("angle_rad", angle_rad))
        self._record[:] = 0.0
        self.samples = 0

    def run(self, command_rad: NDArray[np.float64]) -> NDArray[np.float64]:
        """Advance over a whole (finite) command; one row of :data:`RECORD_COLUMNS` per sample."""
        record = np.empty((command_rad.size, _RECORD_SIZE))
        # a fresh writable copy: one compiled signature (a read-only input would compile a second one)
        _run_kernel(self._state, self._constants, self._substeps, np.array(command_rad, dtype=np.float64), record)
        if command_rad.size:
            self._record[0] = record[-1]
        self.samples += command_rad.size
        return record

    # the states (phi, omega_phi: the motor angle and rate referred to the load side, / N)
    @property
    def phi(self) -> float:
        return float(self._state[_PHI])

    @phi.setter
    def phi(self, value: float) -> None:
        self._state[_PHI] = value

    @property
    def omega_phi(self) -> float:
        return float(self._state[_OMEGA_PHI])

    @omega_phi.setter
    def omega_phi(self, value: float) -> None:
        self._state[_OMEGA_PHI] = value

    @property
    def theta(self) -> float:
        return float(self._state[_THETA])

    @theta.setter
    def theta(self, value: float) -> None:
        self._state[_THETA] = value

    @property
    def omega(self) -> float:
        return float(self._state[_OMEGA])

    @omega.setter
    def omega(self, value: float) -> None:
        self._state[_OMEGA] = value

    @property
    def stuck(self) -> bool:
        """True while the load sticks (Karnopp)."""
        return bool(self._state[_STUCK])

    # states and torques in the units of the motor shaft / load
    @property
    def load_angle_rad(self) -> float:
        return self.theta

    @property
    def load_velocity_rad_per_s(self) -> float:
        return self.omega

    @property
    def motor_angle_rad(self) -> float:
        return self.phi * self._ratio

    @property
    def motor_velocity_rad_per_s(self) -> float:
        return self.omega_phi * self._ratio

    @property
    def motor_torque_nm(self) -> float:
        """The drive's torque at the motor shaft at the start of the last sample."""
        return float(self._record[0, RECORD_COLUMNS.index("drive_torque_nm")]) / self._ratio

    @property
    def shaft_torque_nm(self) -> float:
        """The shaft's torque on the load at the start of the last sample."""
        return float(self._record[0, RECORD_COLUMNS.index("shaft_torque_nm")])

    @property
    def friction_torque_nm(self) -> float:
        """The load's friction torque over the first half sub-step of the last sample."""
        return float(self._record[0, RECORD_COLUMNS.index("friction_torque_nm")])

    def step(self, x: float) -> float:
        """Hold command ``x`` (load rad) over one sample; return the load angle at the sample's start."""
        r = float(x)
        if not math.isfinite(r):
            raise InvalidInputError(f"x: sample {self.samples} is {x!r}; expected a finite angle in rad")
        self._command[0] = r
        _run_kernel(self._state, self._constants, self._substeps, self._command, self._record)
        self.samples += 1
        return float(self._record[0, 0])


# -- the compiled recurrence ----------------------------------------------------------------------------------

RECORD_COLUMNS = ("load_angle_rad", "load_velocity_rad_per_s", "motor_angle_referred_rad",
                  "motor_velocity_referred_rad_per_s", "stuck", "drive_torque_nm", "shaft_torque_nm",
                  "friction_torque_nm")
"""One row per sample of :func:`_run_kernel`: the states at the sample's start (the motor's referred to the
load side, angle / N), then the torques of its first half sub-step at the load side."""

_RECORD_SIZE = len(RECORD_COLUMNS)
_PHI, _OMEGA_PHI, _THETA, _OMEGA, _INTEGRAL, _PREVIOUS_COMMAND, _STUCK, _SHAFT_FRICTION_STATE = range(8)
_STATE_SIZE = 8


def _rest_state(angle_rad: float) -> NDArray[np.float64]:
    """At rest at ``angle_rad``, play centred, integrator empty, load stuck, the shaft's friction relaxed
    (w = 0) (the kernel's state layout)."""
    state = np.zeros(_STATE_SIZE)
    state[[_PHI, _THETA, _PREVIOUS_COMMAND]] = angle_rad
    state[_STUCK] = 1.0
    return state


def _kernel_constants(train: DriveTrain) -> NDArray[np.float64]:
    """The train's constants at the load side, in the order :func:`_run_kernel` unpacks them."""
    ratio = train.gear_ratio
    return np.array([
        train.reflected_motor_inertia_kg_m2,
        train.load_inertia_kg_m2,
        train.total_inertia_kg_m2,
        train.shaft_stiffness_nm_per_rad,
        train.shaft_damping_nm_s_per_rad,
        0.5 * train.play_rad,
        train.motor_viscous_damping_nm_s_per_rad * ratio * ratio,
        train.coulomb_friction_nm,
        train.static_friction_nm,
        train.viscous_friction_nm_s_per_rad,
        train.gravity_torque_nm,
        train.hanging_angle_rad,
        float(train.drive_enabled),
        float(train.position_feedback == "load"),
        float(train.rigid),
        train.position_gain_per_s,
        train.position_integral_gain_per_s,
        train.velocity_feedforward,
        train.velocity_gain_nm_s_per_rad,
        train.motor_speed_limit_rad_per_s / ratio,
        train.motor_torque_limit_nm * ratio,
        train.sample_period_s,
        train.shaft_friction_nm,
        train.shaft_presliding_twist_rad,
    ])


@numba.njit(cache=True)
def _drive_torque(error, velocity, rate, integral, kp, ki, kv, speed_limit, torque_limit):
    """The drive's cascade (module docstring): v_ref = clip(K_p (e + K_i int e) + f dr/dt, +-Omega/N),
    tau = clip(K_v (v_ref - velocity), +-N tau_max). Returns tau and whether either limit clipped."""
    reference = kp * (error + ki * integral) + rate
    clipped = False
    if reference > speed_limit:
        reference, clipped = speed_limit, True
    elif reference < -speed_limit:
        reference, clipped = -speed_limit, True
    drive = kv * (reference - velocity)
    if drive > torque_limit:
        drive, clipped = torque_limit, True
    elif drive < -torque_limit:
        drive, clipped = -torque_limit, True
    return drive, clipped


@numba.njit(cache=True)
def _deflection(twist, half_play):
    """dz(Delta): the spring's deflection, 0 inside the play (module docstring)."""
    if twist > half_play:
        return twist - half_play
    if twist < -half_play:
        return twist + half_play
    return 0.0


@numba.njit(cache=True)
def _shaft_torque(twist, twist_rate, stiffness, damping, half_play, friction):
    """Dead-zone shaft (Nordin and Gutman 2002) with ElastoBacklash's damping rule, its internal friction
    torque ``friction`` (T_h w) acting with the spring (module docstring)."""
    if half_play == 0.0:
        return stiffness * twist + friction + damping * twist_rate
    if twist > half_play:
        spring = stiffness * (twist - half_play) + friction
        damper = damping * twist_rate
        return 0.0 if spring + damper <= 0.0 else spring + (spring if spring < damper else damper)
    if twist < -half_play:
        spring = stiffness * (twist + half_play) + friction
        damper = damping * twist_rate
        return 0.0 if spring + damper >= 0.0 else spring + (spring if spring > damper else damper)
    return 0.0


@numba.njit(cache=True)
def _dahl_state(state, deflection_change, presliding_twist):
    """Dahl's friction state w after the deflection moved by ``deflection_change`` (exact: module docstring)."""
    if deflection_change == 0.0:
        return state
    target = 1.0 if deflection_change > 0.0 else -1.0
    return target + (state - target) * math.exp(-abs(deflection_change) / presliding_twist)


@numba.njit(cache=True)
def _load_half_kick(omega, external, stuck, inertia, kick, coulomb, static, viscous):
    """One half kick of the load's velocity under the external torque with Karnopp's stick test and an
    implicit Coulomb/viscous step (module docstring). Returns omega, the friction torque and stuck."""
    momentum = inertia * omega + kick * external
    if stuck and -static <= external <= static:
        return omega, external, True  # sticks: friction balances the load (omega is 0)
    if -kick * coulomb <= momentum <= kick * coulomb:
        return 0.0, momentum / kick, True  # sliding friction stops the load within this half kick
    sliding = coulomb if momentum > 0.0 else -coulomb
    omega = (momentum - kick * sliding) / (inertia + kick * viscous)
    return omega, sliding + viscous * omega, False


@numba.njit(cache=True)
def _run_kernel(state, constants, substeps, commands, record):
    """Advance ``state`` (layout of :func:`_rest_state`) over ``commands`` (load rad, held per sample) by
    ``substeps`` Störmer-Verlet sub-steps per sample, writing one row of :data:`RECORD_COLUMNS` per sample.
    A rigid train (:attr:`DriveTrain.rigid`) is the one inertia J = N^2 J_m + J_l with the same drive,
    friction and gravity; the motor follows the load and the shaft torque is the share of the net torques
    that passes the gear (J_l / J of the drive's, J_m' / J of the load's)."""
    (motor_inertia, load_inertia, rigid_inertia, stiffness, damping, half_play, motor_damping, coulomb, static,
     viscous, gravity, hanging, drive_on, load_feedback, rigid, kp, ki, feedforward, kv, speed_limit,
     torque_limit, period, shaft_friction, presliding_twist) = (
        constants[0], constants[1], constants[2], constants[3], constants[4], constants[5], constants[6],
        constants[7], constants[8], constants[9], constants[10], constants[11], constants[12] != 0.0,
        constants[13] != 0.0, constants[14] != 0.0, constants[15], constants[16], constants[17], constants[18],
        constants[19], constants[20], constants[21], constants[22], constants[23])
    load_share = load_inertia / rigid_inertia
    h = period / substeps
    kick = 0.5 * h
    phi, omega_phi, theta, omega = state[0], state[1], state[2], state[3]
    integral, previous, stuck, dahl = state[4], state[5], state[6] != 0.0, state[7]
    for sample in range(commands.size):
        r = commands[sample]
        record[sample, 0], record[sample, 1], record[sample, 2], record[sample, 3] = theta, omega, phi, omega_phi
        record[sample, 4] = 1.0 if stuck else 0.0
        rate = feedforward * (r - previous) / period
        previous = r
        for substep in range(substeps):
            integrating = True
            for half in range(2):
                feedback = theta if load_feedback or rigid else phi
                drive, clipped = 0.0, False
                if drive_on:
                    drive, clipped = _drive_torque(r - feedback, omega if rigid else omega_phi, rate, integral, kp, ki,
                                                   kv, speed_limit, torque_limit)
                if clipped:
                    integrating = False
                weight = gravity * math.sin(theta - hanging) if gravity != 0.0 else 0.0
                if rigid:
                    omega, friction, stuck = _load_half_kick(omega, drive - motor_damping * omega - weight, stuck,
                                                             rigid_inertia, kick, coulomb, static, viscous)
                    shaft = 0.0
                    if substep == 0 and half == 0:
                        shaft = load_share * (drive - motor_damping * omega) + (1.0 - load_share) * (friction + weight)
                else:
                    shaft = _shaft_torque(phi - theta, omega_phi - omega, stiffness, damping, half_play,
                                          shaft_friction * dahl)
                    omega_phi += kick * (drive - shaft - motor_damping * omega_phi) / motor_inertia
                    omega, friction, stuck = _load_half_kick(omega, shaft - weight, stuck, load_inertia, kick, coulomb,
                                                             static, viscous)
                if substep == 0 and half == 0:
                    record[sample, 5], record[sample, 6], record[sample, 7] = drive, shaft, friction
                if half == 0:
                    before = _deflection(phi - theta, half_play) if shaft_friction != 0.0 else 0.0
                    theta += h * omega
                    if not rigid:
                        phi += h * omega_phi
                    if shaft_friction != 0.0:
                        after = _deflection(phi - theta, half_play)
                        dahl = 0.0 if after == 0.0 and half_play > 0.0 else _dahl_state(dahl, after - before,
                                                                                         presliding_twist)
            if drive_on and integrating and ki != 0.0:
                integral += h * (r - (theta if load_feedback or rigid else phi))
        if rigid:
            phi, omega_phi = theta, omega
    state[0], state[1], state[2], state[3] = phi, omega_phi, theta, omega
    state[4], state[5], state[6], state[7] = integral, previous, 1.0 if stuck else 0.0, dahl
