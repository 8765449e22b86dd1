"""The user's simulation model as an FMU (FMI 2.0 or 3.0, co-simulation or model exchange), as a plant block.

An FMU exported from a Modelica tool or Simulink becomes one :class:`FmuBlock`: a block with the interface of
:mod:`identify.plant_blocks` (``apply(signal)`` from rest, ``stepper().step(x)`` one sample), so it sits in
a :class:`~identify.plant_blocks.PlantModel` like the TOML blocks. That is the whole seam: ``rig diagnose
--model plant.fmu`` hands the model-discrepancy workflow a chain holding the FMU, and the workflow adds the
catalogue's input-side effects before it and the output-side effects after it
(:mod:`identify.black_box_effects` says which effects can go around a black box); the simulated rig steps
the same block once per SYNC or per command frame. ``identify`` never sees fmpy.

What the FMU file describes, and the checks of the user's choices against it (input and output, their units,
parameters, a binary for this platform), are in :mod:`sim_backend.fmu_description`; :func:`open_fmu_block`
runs them before it makes the block. The names of that module listed in this one's ``__all__`` are re-exported
here, so a caller may import them from either.

Sampling (the FMI 2.0 / 3.0 co-simulation step, "Co-Simulation" chapter of the FMI standards): sample t is
the FMU's output at time t T, read after its input was set to u_t (a direct feedthrough shows at once);
the FMU then advances from t T to (t+1) T with u_t held (zero-order hold, as a drive holds its setpoint for
one period). An FMU without direct feedthrough therefore answers one sample later, like a linear block with
b0 = 0. A co-simulation FMU advances with its own solver (``doStep``); a model-exchange FMU is integrated
here with fmpy's CVode (BDF) from sample to sample, with the input held, time, state and step events
handled at the instant CVode locates them (the event iteration of the FMI "Model Exchange" chapter), and
the integrator restarted where the input jumps. A co-simulation interface is used when the FMU has one.

Everything is deterministic: the same input gives the same output, stepping equals :meth:`FmuBlock.apply`
sample for sample, and an FMU is read from the file at run time only (nothing is downloaded).
"""

from __future__ import annotations

import atexit
import math
import os
import shutil
import tempfile
import threading
import weakref
from abc import ABC, abstractmethod
from collections import OrderedDict, deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.validation import InvalidInputError, as_signal, positive
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError
from sim_backend.fmu_description import (
    INTERFACES, REAL_TYPES, FmuDescription, FmuParameter, FmuVariable, angle_scale, check_fmu_parameters,
    check_platform, choose_variable, describe_fmu, is_fmu_path, parse_parameter_assignments)

__all__ = ["FmuBlock", "FmuDescription", "FmuParameter", "FmuVariable", "check_fmu_parameters", "describe_fmu",
           "fmu_plant_config", "is_fmu_path", "open_fmu_block", "parse_parameter_assignments",
           "time_fmu_steps"]

MODEL_EXCHANGE_RELATIVE_TOLERANCE = 1e-8
"""CVode's relative tolerance for a model-exchange FMU: tight, because the workflow compares free runs to
the noise bound of an encoder (a few 1e-4 rad on angles of order 1 rad)."""

_FMI_WARNING = 1
_FMI_STATUS = {1: "Warning", 2: "Discard", 3: "Error", 4: "Fatal", 5: "Pending"}

_KEPT_LOG_MESSAGES = 20

_CACHED_RUNS = 16
"""Free runs of one block kept per process (:meth:`FmuBlock.apply`): the workflow simulates the same FMU
input many times while it fits effects after the FMU's output."""


# ----------------------------------------------------------------------------------------------------------
# The extracted FMU, once per process
# ----------------------------------------------------------------------------------------------------------


class _Unpacked:
    """An FMU extracted into a temporary directory (removed at exit), with its model description, the last
    runs of :meth:`FmuBlock.apply` and the instances it may reuse."""

    def __init__(self, path: str) -> None:
        from fmpy import extract, read_model_description

        self.path = path
        self.model_description = read_model_description(path, validate=False)
        self.directory = extract(path, unzipdir=tempfile.mkdtemp(prefix="rig-fmu-"))
        atexit.register(shutil.rmtree, self.directory, True)
        self.libraries: list[Any] = []
        self.lock = threading.Lock()
        self.runs: OrderedDict[tuple[Any, ...], NDArray[np.float64]] = OrderedDict()
        self.log: deque[str] = deque(maxlen=_KEPT_LOG_MESSAGES)
        self.idle: dict[str, list[Any]] = {interface: [] for interface in INTERFACES}
        self.reset_works: dict[str, bool | None] = {interface: None for interface in INTERFACES}
        """Per interface: None until :meth:`FmuBlock.apply` has compared a run of a reset instance with a
        run of a fresh one, then whether they agreed."""

    def log_fmi2(self, component: Any, instance_name: bytes, status: int, category: bytes, message: bytes) -> None:
        """The FMU's log messages (FMI 2.0 logger): kept for error messages, never printed (a library must not
        print: ``rig diagnose --json`` writes one JSON document to standard output)."""
        self._keep(status, message)

    def log_fmi3(self, environment: Any, status: int, category: bytes, message: bytes) -> None:
        """The FMI 3.0 logMessage callback, as :meth:`log_fmi2`."""
        self._keep(status, message)

    def _keep(self, status: int, message: bytes | None) -> None:
        text = (message or b"").decode("utf-8", "replace").strip()
        self.log.append(f"[{_FMI_STATUS.get(status, 'OK')}] {text[:200]}")

    def last_message(self) -> str:
        return f" (the FMU's last log message: {self.log[-1]})" if self.log else ""

    def keep_loaded(self, fmu: Any) -> None:
        """Hold one more reference to the instance's shared library for the life of the process: fmpy closes
        the library with each freed instance, and an FMU whose library is unloaded and loaded again between
        instances (pythonfmu's embeds Python) may keep state that does not survive it."""
        with self.lock:
            if not self.libraries:
                import ctypes

                self.libraries.append(ctypes.CDLL(fmu.dll._name))


_UNPACKED: dict[tuple[str, int, int], _Unpacked] = {}
_UNPACKED_LOCK = threading.Lock()


def _unpacked(path: str) -> _Unpacked:
    """The extraction of ``path`` (a new one when the file changed since: same size and time, same FMU)."""
    status = os.stat(path)
    key = (os.path.abspath(path), status.st_mtime_ns, status.st_size)
    with _UNPACKED_LOCK:
        if key not in _UNPACKED:
            _UNPACKED[key] = _Unpacked(path)
        return _UNPACKED[key]


# ----------------------------------------------------------------------------------------------------------
# The block
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FmuBlock:
    """An FMU as a plant block: input ``input_name`` (the commanded angle, rad), output ``output_name`` (the
    load angle, rad), sampled every ``sample_period_s`` (module docstring).

    Build one with :func:`open_fmu_block`, which checks the file, the variables and the platform binary.
    The block pickles as its fields (a worker process re-opens the file).

    Attributes
    ----------
    black_box
        Always True: the workflow cannot look inside, so effects can only be added before its input or
        after its output (:mod:`identify.black_box_effects`).
    """

    path: str
    sample_period_s: float
    input_name: str
    output_name: str
    interface: str = "co_simulation"
    input_reference: int = 0
    output_reference: int = 0
    fmi_version: str = "2.0"
    parameters: tuple[tuple[str, int, str, Any], ...] = ()
    """Values set before initialisation: (name, value reference, type, value), checked by
    :func:`~sim_backend.fmu_description.check_fmu_parameters`; the others keep the start values the FMU was
    exported with."""
    input_per_rad: float = 1.0
    """The FMU's input unit per radian (1 for rad; 180/pi for an input in deg)."""
    output_rad_per_unit: float = 1.0
    """Radians per unit of the FMU's output (1 for rad; pi/180 for an output in deg)."""
    black_box = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "sample_period_s", positive("sample_period_s", self.sample_period_s))
        if self.interface not in INTERFACES:
            raise InvalidInputError(f"interface: expected one of {', '.join(INTERFACES)}, got {self.interface!r}")

    @property
    def name(self) -> str:
        return Path(self.path).name

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        """Run a whole input signal (rad) from the FMU's initial state; equal, sample for sample, to stepping
        a fresh :meth:`stepper`. The last few runs are kept (the FMU is deterministic)."""
        u = as_signal("signal", signal)
        unpacked = _unpacked(self.path)
        key = (self.interface, self.input_reference, self.output_reference, self.sample_period_s, self.parameters,
               self.input_per_rad, self.output_rad_per_unit, u.tobytes())
        with unpacked.lock:
            cached = unpacked.runs.get(key)
            if cached is not None:
                unpacked.runs.move_to_end(key)
                return cached.copy()
        out = self._run(unpacked, u)
        with unpacked.lock:
            unpacked.runs[key] = out
            while len(unpacked.runs) > _CACHED_RUNS:
                unpacked.runs.popitem(last=False)
        return out.copy()

    def _run(self, unpacked: _Unpacked, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """One free run on an idle instance brought back to its initial state by the FMI reset (instantiating
        costs fmpy about 20 ms, more than a whole run of a fast FMU), or on a fresh one. The first reuse is
        checked against a fresh instance on the same input; an FMU whose reset does not give the same run
        gets a fresh instance every time."""
        with unpacked.lock:
            works = unpacked.reset_works[self.interface]
            idle = unpacked.idle[self.interface].pop() if works is not False and unpacked.idle[self.interface] else None
        try:
            stepper = self.stepper(reuse=idle)
        except Exception:  # an FMU whose reset fails: fresh instances from now on
            if idle is None:
                raise
            _free(idle)
            with unpacked.lock:
                unpacked.reset_works[self.interface] = False
            stepper, idle = self.stepper(), None
        out = _drive(stepper, u)
        if idle is not None and works is None:
            fresh = _drive(self.stepper(), u, keep=False)
            agree = bool(np.array_equal(out, fresh))
            with unpacked.lock:
                unpacked.reset_works[self.interface] = agree
            if not agree:
                with unpacked.lock:
                    for instance in unpacked.idle[self.interface]:
                        _free(instance)
                    unpacked.idle[self.interface].clear()
                return fresh
        return out

    def stepper(self, reuse: Any = None) -> FmuStepper:
        """A fresh instance of the FMU at its initial state, advanced one sample per ``step(x)`` (``reuse``: an
        idle fmpy instance of this FMU to reset instead of instantiating one)."""
        unpacked = _unpacked(self.path)
        if self.interface == "co_simulation":
            return _CoSimulationStepper(unpacked, self, reuse)
        return _ModelExchangeStepper(unpacked, self, reuse)


def _drive(stepper: FmuStepper, u: NDArray[np.float64], keep: bool = True) -> NDArray[np.float64]:
    """Step ``stepper`` through ``u``; then hand its instance back for reuse (``keep``) or free it."""
    try:
        out = np.fromiter((stepper.step(x) for x in u.tolist()), dtype=float, count=u.size)
    except BaseException:
        stepper.close()
        raise
    if keep:
        stepper.release()
    else:
        stepper.close()
    return out


def open_fmu_block(path: str | os.PathLike[str], sample_period_s: float, input_name: str | None = None,
                   output_name: str | None = None, *,
                   options: tuple[str, str] = ("--fmu-input", "--fmu-output"),
                   parameters: Any = None, parameters_key: str = "fmu_parameters") -> FmuBlock:
    """Check an FMU and make its block.

    The input and output are found automatically when the FMU has one real input and one real output;
    otherwise ``input_name`` / ``output_name`` choose (errors name the file, list the variables and say
    which of ``options`` to give). An input or output in deg or rev is converted (the block takes and gives
    rad); another unit is refused. ``parameters`` (``{name: value}``) are checked against the model
    description (:func:`~sim_backend.fmu_description.check_fmu_parameters`, errors naming ``parameters_key``)
    and set before each initialisation. The FMU's binary for this platform must be present."""
    description = describe_fmu(path)
    source = description.path
    input_variable = choose_variable(description, "input", input_name, options[0])
    output_variable = choose_variable(description, "output", output_name, options[1])
    input_scale = angle_scale(description, input_variable, "input", options[0])
    output_scale = angle_scale(description, output_variable, "output", options[1])
    checked = check_fmu_parameters(description, parameters or {}, parameters_key)
    interface = "co_simulation" if "co_simulation" in description.interfaces else "model_exchange"
    check_platform(description, interface)
    block = FmuBlock(path=source, sample_period_s=sample_period_s, input_name=input_variable.name,
                     output_name=output_variable.name, interface=interface,
                     input_reference=input_variable.value_reference,
                     output_reference=output_variable.value_reference, fmi_version=description.fmi_version,
                     parameters=checked, input_per_rad=1.0 / input_scale, output_rad_per_unit=output_scale)
    try:  # load the binary once now: a library that does not load is a clear error here, not mid-run
        block.stepper().close()
    except ConfigError:
        raise
    except Exception as err:
        raise ConfigError(source, "binaries", f"the FMU's binary for this platform does not load or does not "
                                              f"instantiate: {err}") from err
    return block


def time_fmu_steps(block: FmuBlock, samples: int = 50, budget_s: float = 0.5) -> float:
    """Seconds one sample of ``block`` takes (the mean over up to ``samples`` steps of a square wave, fewer
    when they take longer than ``budget_s``): what a simulated rig's device spends on the plant every period."""
    import time

    stepper = block.stepper()
    try:
        start = time.perf_counter()
        done = 0
        for done in range(1, samples + 1):
            stepper.step(0.1 if (done // 5) % 2 else -0.1)
            if time.perf_counter() - start > budget_s:
                break
        return (time.perf_counter() - start) / max(done, 1)
    finally:
        stepper.close()


def fmu_plant_config(path: str | os.PathLike[str], sample_period_s: float, encoder: EncoderResolution, *,
                     seed: int | None = None, input_name: str | None = None, output_name: str | None = None,
                     options: tuple[str, str] = ("fmu_input", "fmu_output"), parameters: Any = None) -> Any:
    """The simulated plant of a rig config whose ``[simulation] plant`` is an FMU: the FMU's block, the rig's
    encoder and sample period, and no noise beyond the encoder's quantisation (put noise in the FMU if the
    model has it)."""
    from sim_backend.noise import NoNoise
    from sim_backend.plant_config import PlantConfig

    block = open_fmu_block(path, sample_period_s, input_name, output_name, options=options, parameters=parameters)
    return PlantConfig(name=Path(path).stem, sample_period_s=sample_period_s, encoder=encoder, noise=NoNoise(),
                       blocks=(block,), seed=seed, description=f"FMU {Path(path).name}", source=str(path))


# ----------------------------------------------------------------------------------------------------------
# Steppers
# ----------------------------------------------------------------------------------------------------------


class FmuStepper(ABC):
    """Advances one FMU instance by one sample per :meth:`step`; frees the instance on :meth:`close` (or when
    garbage-collected)."""

    def __init__(self, unpacked: _Unpacked, block: FmuBlock, reuse: Any = None) -> None:
        from ctypes import c_double, c_uint32

        from fmpy.simulation import instantiate_fmu

        self.block = block
        self.period = block.sample_period_s
        self.samples = 0
        self.time = 0.0
        self._unpacked = unpacked
        kind = "CoSimulation" if block.interface == "co_simulation" else "ModelExchange"
        self.is_fmi3 = block.fmi_version.startswith("3.")
        if reuse is None:
            logger = unpacked.log_fmi3 if self.is_fmi3 else unpacked.log_fmi2
            fmu = instantiate_fmu(unpacked.directory, unpacked.model_description, kind, logger=logger)
            unpacked.keep_loaded(fmu)
        else:
            fmu = reuse
            fmu.reset()  # FMI 2.0 fmi2Reset / 3.0 fmi3Reset: as if just instantiated
        self.fmu = fmu
        self._finalizer = weakref.finalize(self, _free, fmu)
        for name, reference, kind, value in block.parameters:  # before initialisation, as FMI asks of fixed ones
            try:
                _set_parameter(fmu, self.is_fmi3, reference, kind, value)
            except Exception as err:  # fmpy raises FMICallException for a status above Warning
                raise InvalidInputError(f"{block.name}: setting parameter {name!r} = {value!r} failed: {err}"
                                        f"{unpacked.last_message()}") from err
        self._finalizer.atexit = False  # at exit the process ends: freeing then races threads still stepping
        # the FMI functions themselves on arrays made once: fmpy's setReal/getReal build new arrays and go
        # through its call logger on every call (three calls a sample: about half the time of a fast FMU)
        self._functions = fmu._functions
        input_ref, output_ref = (c_uint32 * 1)(block.input_reference), (c_uint32 * 1)(block.output_reference)
        value = self._value = (c_double * 1)()
        component = self._component = fmu.component
        if self.is_fmi3:
            set_float, get_float = self._functions["fmi3SetFloat64"], self._functions["fmi3GetFloat64"]
            self._set = lambda: set_float(component, input_ref, 1, value, 1)
            self._get = lambda: get_float(component, output_ref, 1, value, 1)
        else:
            set_real, get_real = self._functions["fmi2SetReal"], self._functions["fmi2GetReal"]
            self._set = lambda: set_real(component, input_ref, 1, value)
            self._get = lambda: get_real(component, output_ref, 1, value)

    def _check(self, function: str, status: int) -> None:
        """fmpy's rule: a status above Warning (Discard, Error, Fatal) is a failure."""
        if status > _FMI_WARNING:
            raise InvalidInputError(f"{self.block.name}: {function} failed with FMI status "
                                    f"{_FMI_STATUS.get(status, status)} at sample {self.samples} (t = {self.time:g} s)"
                                    f"{self._unpacked.last_message()}")

    def _write_input(self, x: float) -> None:
        self._value[0] = x * self.block.input_per_rad
        status = self._set()
        if status:
            self._check("setting the input " + repr(self.block.input_name), status)

    def _read_output(self) -> float:
        status = self._get()
        if status:
            self._check("getting the output " + repr(self.block.output_name), status)
        return float(self._value[0]) * self.block.output_rad_per_unit

    def step(self, x: float) -> float:
        """Hold input ``x`` (rad) from this sample instant on and return the output at it (module docstring)."""
        value = float(x)
        if not math.isfinite(value):
            raise InvalidInputError(f"x: sample {self.samples} is {x!r}; expected a finite angle in rad")
        if self.samples:
            self._advance((self.samples - 1) * self.period, self.samples * self.period)
        self.time = self.samples * self.period
        self._input_changed(value)
        output = self._read_output()
        if not math.isfinite(output):
            raise InvalidInputError(f"{self.block.name}: output {self.block.output_name!r} is {output!r} at sample "
                                    f"{self.samples} (t = {self.time:g} s)")
        self.samples += 1
        return output

    @abstractmethod
    def _advance(self, start_s: float, stop_s: float) -> None:
        """Advance the instance from ``start_s`` to ``stop_s`` with the input held."""

    def _input_changed(self, value: float) -> None:
        self._write_input(value)

    def close(self) -> None:
        """Terminate and free the FMU instance."""
        self._finalizer()

    def release(self) -> None:
        """Hand the instance to :meth:`FmuBlock.apply` for reuse instead of freeing it (freed if this FMU's
        reset was found not to restore its initial state)."""
        with self._unpacked.lock:
            if self._unpacked.reset_works[self.block.interface] is not False and self._finalizer.detach() is not None:
                self._unpacked.idle[self.block.interface].append(self.fmu)
                return
        self.close()


def _set_parameter(fmu: Any, is_fmi3: bool, reference: int, kind: str, value: Any) -> None:
    """Set one parameter through fmpy's setter of its type."""
    if kind == "Boolean":
        fmu.setBoolean([reference], [bool(value)])
    elif kind in REAL_TYPES:
        setter = (fmu.setFloat32 if kind == "Float32" else fmu.setFloat64) if is_fmi3 else fmu.setReal
        setter([reference], [float(value)])
    else:
        setter = getattr(fmu, f"set{kind}") if is_fmi3 else fmu.setInteger
        setter([reference], [int(value)])


def _free(fmu: Any) -> None:
    try:
        fmu.terminate()
    except Exception:  # an instance that failed mid-run may refuse terminate; free it all the same
        pass
    try:
        fmu.freeInstance()
    except Exception:
        pass


class _CoSimulationStepper(FmuStepper):
    """FMI co-simulation: the FMU's own solver advances it from one communication point to the next."""

    def __init__(self, unpacked: _Unpacked, block: FmuBlock, reuse: Any = None) -> None:
        from ctypes import byref, c_bool, c_double

        super().__init__(unpacked, block, reuse)
        fmu = self.fmu
        if self.is_fmi3:
            fmu.enterInitializationMode(startTime=0.0)
        else:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        component, period = self._component, self.period
        if self.is_fmi3:  # fmi3DoStep(..., eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime)
            do_step, self._terminate = self._functions["fmi3DoStep"], c_bool()
            flags = (byref(c_bool()), byref(self._terminate), byref(c_bool()), byref(c_double()))
            self._do_step = lambda start_s: do_step(component, start_s, period, True, *flags)
        else:
            do_step = self._functions["fmi2DoStep"]
            self._do_step = lambda start_s: do_step(component, start_s, period, 1)

    def _advance(self, start_s: float, stop_s: float) -> None:
        status = self._do_step(start_s)
        if status:
            self._check("doStep", status)
        if self.is_fmi3 and self._terminate.value:
            raise InvalidInputError(f"{self.block.name}: the FMU asked to terminate at t = {stop_s:g} s "
                                    f"(sample {self.samples})")


class _HeldInput:
    """fmpy's solver re-applies the inputs at each root-function call; ours are held between samples."""

    def apply(self, time: float, continuous: bool = True, discrete: bool = True, after_event: bool = False) -> None:
        return None

    def nextEvent(self, time: float) -> float:  # noqa: N802 (fmpy's name)
        return math.inf


class _ModelExchangeStepper(FmuStepper):
    """FMI model exchange: CVode integrates the FMU's derivatives between samples with the input held;
    events are handled by the FMI event iteration (enter event mode, update discrete states until none is
    needed, back to continuous time), and the integrator restarts after each event and input jump."""

    def __init__(self, unpacked: _Unpacked, block: FmuBlock, reuse: Any = None) -> None:
        super().__init__(unpacked, block, reuse)
        from fmpy.sundials import CVodeSolver

        fmu = self.fmu
        description = unpacked.model_description
        if self.is_fmi3:
            fmu.enterInitializationMode(startTime=0.0)
        else:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        self.next_event_s = math.inf
        self._update_discrete_states(0.0)
        fmu.enterContinuousTimeMode()
        self.needs_completed_step = bool(description.modelExchange.needsCompletedIntegratorStep)
        self._failures: list[str] = []
        prefix = "fmi3" if self.is_fmi3 else "fmi2"
        derivatives = "GetContinuousStateDerivatives" if self.is_fmi3 else "GetDerivatives"
        callbacks = {key: self._callback(prefix + name) for key, name in (
            ("get_x", "GetContinuousStates"), ("set_x", "SetContinuousStates"), ("get_dx", derivatives),
            ("get_z", "GetEventIndicators"), ("get_nominals", "GetNominalsOfContinuousStates"),
            ("set_time", "SetTime"))}
        self.solver = CVodeSolver(
            nx=description.numberOfContinuousStates, nz=description.numberOfEventIndicators, **callbacks,
            input=_HeldInput(), startTime=0.0, maxStep=block.sample_period_s,
            relativeTolerance=MODEL_EXCHANGE_RELATIVE_TOLERANCE)
        self._held: float | None = None

    def _callback(self, function: str) -> Any:
        """The FMI function ``function`` for CVode's callbacks, called on the library directly. fmpy's wrappers
        raise on a failed call, but an exception raised inside CVode's ctypes callback is printed and lost
        (the integration goes on with whatever the FMU left); here a failed call is noted and raised by
        :meth:`_advance` when the solver returns."""
        call, component, failures = self._functions[function], self._component, self._failures

        def checked(*args: Any) -> None:
            status = call(component, *args)
            if status > _FMI_WARNING and not failures:
                failures.append(f"{function} failed with FMI status {_FMI_STATUS.get(status, status)}")

        return checked

    def _update_discrete_states(self, time_s: float) -> None:
        fmu = self.fmu
        needed, terminate = True, False
        while needed and not terminate:
            result = fmu.updateDiscreteStates() if self.is_fmi3 else fmu.newDiscreteStates()
            needed, terminate, _, _, defined, next_time = result
            self.next_event_s = float(next_time) if defined else math.inf
        if terminate:
            raise InvalidInputError(f"{self.block.name}: the FMU asked to terminate at t = {time_s:g} s")

    def _event(self, time_s: float) -> None:
        self.fmu.enterEventMode()
        self._update_discrete_states(time_s)
        self.fmu.enterContinuousTimeMode()
        self.solver.reset(time_s)

    def _input_changed(self, value: float) -> None:
        if self._held == value:
            return
        self._write_input(value)
        if self._held is not None:  # a jump of the input: the derivatives jump, restart the integrator
            self.solver.reset(self.time)
        self._held = value

    def _advance(self, start_s: float, stop_s: float) -> None:
        time_s = start_s
        while time_s < stop_s and not math.isclose(time_s, stop_s, rel_tol=1e-12, abs_tol=1e-12 * self.period):
            target = min(stop_s, self.next_event_s)
            time_event = math.isclose(target, self.next_event_s, rel_tol=1e-12, abs_tol=1e-12 * self.period)
            try:
                state_event, _, time_s = self.solver.step(time_s, target)
            except RuntimeError as err:  # fmpy's report of a CVode failure
                raise InvalidInputError(f"{self.block.name}: CVode cannot integrate the model-exchange FMU from "
                                        f"t = {time_s:g} s (sample {self.samples}): {err}; check the model, or "
                                        "export it for co-simulation (its own solver)"
                                        f"{self._unpacked.last_message()}") from err
            if self._failures:
                raise InvalidInputError(f"{self.block.name}: {self._failures[0]} while CVode integrated it near "
                                        f"t = {time_s:g} s (sample {self.samples}){self._unpacked.last_message()}")
            self.fmu.setTime(time_s)
            step_event = False
            if self.needs_completed_step:
                step_event, terminate = self.fmu.completedIntegratorStep()
                if terminate:
                    raise InvalidInputError(f"{self.block.name}: the FMU asked to terminate at t = {time_s:g} s")
            if state_event or step_event or (time_event and math.isclose(time_s, target, rel_tol=1e-12)):
                self._event(time_s)
        self.fmu.setTime(stop_s)
