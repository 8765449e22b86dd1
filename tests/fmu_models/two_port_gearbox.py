"""A test FMU with two real inputs and two real outputs (a gearbox with a load torque and a speed output):
the command line must be told which input is the commanded angle and which output the load angle."""

from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class TwoPortGearbox(Fmi2Slave):
    author = "gearbox-rig tests"
    description = "first-order lag from command to angle; load_torque_nm shifts it by compliance"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.command = 0.0
        self.load_torque_nm = 0.0
        self.angle = 0.0
        self.speed = 0.0
        self.register_variable(Real("command", causality=Fmi2Causality.input))
        self.register_variable(Real("load_torque_nm", causality=Fmi2Causality.input))
        self.register_variable(Real("angle", causality=Fmi2Causality.output))
        self.register_variable(Real("speed", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        time_constant_s = 0.03
        target = self.command - 0.01 * self.load_torque_nm
        previous = self.angle
        self.angle += step_size / (time_constant_s + step_size) * (target - self.angle)
        self.speed = (self.angle - previous) / step_size
        return True
