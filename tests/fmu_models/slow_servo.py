"""A test FMU that takes 0.8 s a communication step (a model far too slow for the rig's clock): the simulated
rig stepping it misses the feedback watchdog, and the run's error must name the plant as the cause."""

import time

from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class SlowServo(Fmi2Slave):
    author = "gearbox-rig tests"
    description = "first-order lag that sleeps 0.8 s a step"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.command = 0.0
        self.angle = 0.0
        self.register_variable(Real("command", causality=Fmi2Causality.input))
        self.register_variable(Real("angle", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        time.sleep(0.8)
        self.angle += 0.5 * (self.command - self.angle)
        return True
