"""A plant of four poles for tests of the discrepancy workflow: a stiff position servo turning a load through
a compliant shaft, as an exact zero-order-hold linear block."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from identify.plant_blocks import LinearBlock


def servo_and_shaft_block(period: float = 1e-3) -> LinearBlock:
    """A stiff 60 Hz, zeta 0.7 servo turning a load of 0.004 kg m^2 through a shaft of 150 N m/rad, 0.0775 N m s/rad
    (a 30.8 Hz mode, zeta 0.05), the load's angle read: state (phi, phi', theta, theta'), phi'' = w^2 (u - phi)
    - 2 zeta w phi', J theta'' = k (phi - theta) + c (phi' - theta'), discretised exactly with a zero-order hold."""
    w, zeta, k, c, inertia = 2 * math.pi * 60.0, 0.7, 150.0, 0.0775, 0.004
    a = np.array([[0, 1, 0, 0], [-w * w, -2 * zeta * w, 0, 0], [0, 0, 0, 1],
                  [k / inertia, c / inertia, -k / inertia, -c / inertia]])
    augmented = np.zeros((5, 5))
    augmented[:4, :4], augmented[1, 4] = a, w * w
    discrete = expm(augmented * period)
    return LinearBlock.from_state_space(discrete[:4, :4], discrete[:4, 4], (0.0, 0.0, 1.0, 0.0), 0.0, period)
