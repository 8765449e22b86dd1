"""The simulated CiA 402 drive's torque objects: the motor rated torque 0x6076 (UNSIGNED32, mN m) and the torque
actual value 0x6077 (INTEGER16, per mille of the rated torque), for a drive whose EDS has them
(``configs/eds/sim_servo_drive_cia402.eds``). Only a plant that models a motor (a drive_train block) gives the
torque; a drive whose EDS promises 0x6077 on a plant without one is refused, never served a made-up value."""

from __future__ import annotations

import math

from identify.drive_train import DriveTrain
from identify.validation import InvalidInputError
from sim_backend.plant import SimulatedGearbox

__all__ = ["DriveTorque", "drive_torque_of"]

DEFAULT_RATED_TORQUE_MNM = 1000
"""0x6076 of a drive train without a torque limit: 1 N m."""


class DriveTorque:
    """0x6076 and 0x6077 of one simulated drive.

    The rated torque at power-on is the drive train's motor torque limit (rounded to the mN m of 0x6076, at least
    1), so that the torque actual value spans +-1000 per mille at the limit; without a limit, 1 N m. 0x6076 is
    writable (CiA 402 sets it from the motor's data); 0x6077 is per mille of the value it holds. A torque beyond
    the INTEGER16 range saturates, as a drive's 0x6077 does."""

    def __init__(self, gearbox: SimulatedGearbox) -> None:
        trains = gearbox.plant.find(DriveTrain)
        limit = trains[0].motor_torque_limit_nm if trains else math.inf
        self.rated_torque_mnm = max(1, round(1000.0 * limit)) if math.isfinite(limit) else DEFAULT_RATED_TORQUE_MNM

    @staticmethod
    def per_mille(torque_nm: float, rated_torque_mnm: int) -> int:
        """0x6077 for a motor torque of ``torque_nm`` and a rated torque 0x6076 of ``rated_torque_mnm`` (> 0)."""
        value = round(1e6 * torque_nm / rated_torque_mnm)
        return max(-32768, min(32767, value))


def drive_torque_of(gearbox: SimulatedGearbox, drive_eds: str, has_torque_object: bool) -> DriveTorque | None:
    """The torque objects of a drive whose EDS (``drive_eds``) has 0x6077, None for one whose EDS has not; refuses
    an EDS with 0x6077 on a plant that gives no motor torque."""
    if not has_torque_object:
        return None
    if not gearbox.gives_motor_torque:
        raise InvalidInputError(
            f"drive_eds: {drive_eds} has the torque actual value 0x6077, but the plant {gearbox.name!r} models no "
            "motor (no drive_train block), so the simulated drive has no torque to report; use "
            "configs/eds/sim_drive_cia402.eds, or a drive_train plant")
    return DriveTorque(gearbox)
