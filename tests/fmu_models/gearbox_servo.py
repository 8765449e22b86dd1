"""A test FMU: a position-controlled gearbox whose load angle follows the command as a second-order loop
(8 Hz, damping 0.7), integrated by RK4 within each communication step. The model-discrepancy tests hide
an effect around it and ask `rig diagnose --model` to find it."""

import math
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class GearboxServo(Fmi2Slave):
    """A position-controlled gearbox: the load angle follows the commanded angle as a second-order loop."""

    author = "gearbox-rig tests"
    description = "second-order servo: angle'' = w^2 (command - angle) - 2 zeta w angle'"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.command = 0.0
        self.angle = 0.0
        self.speed = 0.0
        self.natural_frequency_hz = 8.0
        self.damping_ratio = 0.7
        self.register_variable(Real("command", causality=Fmi2Causality.input))
        self.register_variable(Real("angle", causality=Fmi2Causality.output))
        self.register_variable(Real("natural_frequency_hz", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))
        self.register_variable(Real("damping_ratio", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))

    def do_step(self, current_time, step_size):
        w = 2.0 * math.pi * self.natural_frequency_hz
        h = step_size / 4.0
        for _ in range(4):  # RK4 sub-steps with the command held
            def f(x, v):
                return v, w * w * (self.command - x) - 2.0 * self.damping_ratio * w * v
            k1 = f(self.angle, self.speed)
            k2 = f(self.angle + 0.5 * h * k1[0], self.speed + 0.5 * h * k1[1])
            k3 = f(self.angle + 0.5 * h * k2[0], self.speed + 0.5 * h * k2[1])
            k4 = f(self.angle + h * k3[0], self.speed + h * k3[1])
            self.angle += h / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            self.speed += h / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        return True
