"""Participants of a co-simulation: one interface for a Co-Simulation FMU (FMI 2.0 or
3.0, through fmpy) and for a native model (the stepping :class:`Simulator`).

A participant has a ``name``, the names of its ``inputs`` and ``outputs``, their
``units``, and five operations: ``start(t0, inputs)`` (initialise at ``t0`` with the
given input values, states at the equilibrium of those inputs), ``set(values)``,
``get(names)``, ``do_step(t, h)`` and ``close()``. A failure of any operation is a
:class:`ParticipantError` carrying the status (``"error"``, ``"fatal"``, ``"discard"``,
...) for the master to report with the time.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Mapping, Sequence
from ctypes import byref

import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi3 import FMU3Slave
from fmpy.logging import addLoggerProxy

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError, SarcomereError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulator import Simulator

from .archive import OpenedFmu

STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
"""FMI status labels by code (FMI 2.0; FMI 3.0 has the first five)."""


class ParticipantError(SarcomereError):
    """An operation of a participant failed with ``status`` (an FMI status label)."""

    def __init__(self, participant: str, status: str, detail: str) -> None:
        super().__init__(f"{participant} returned {status}: {detail}")
        self.participant = participant
        self.status = status


_SINKS: dict[str, Callable[[int, bytes], None]] = {}
"""Where each live FMI 2.0 instance's messages go, by instance name."""
_SERIAL = itertools.count(1)


def _dispatch(env, instance: bytes | None, status: int, category, message: bytes) -> None:
    sink = _SINKS.get(instance.decode(errors="replace") if instance else "")
    if sink is not None:
        sink(status, message)


_FMI2_LOGGER = fmi2CallbackLoggerTYPE(_dispatch)
"""The one FMI 2.0 logger of the process. fmpy's printf-formatting proxy
(``addLoggerProxy``) holds a single, process-wide target: a logger per instance would
send every FMU's messages to the instance installed last, and crash the process on the
next message once that instance was collected. This one lives as long as the module and
hands each message to its instance's sink."""


def fmi2_callbacks(instance_name: str, sink: Callable[[int, bytes], None]):
    """FMI 2.0 callbacks whose messages from ``instance_name`` reach ``sink(status,
    message)`` (until :func:`forget_fmi2_sink`), formatted by fmpy's proxy."""
    _SINKS[instance_name] = sink
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _FMI2_LOGGER
    callbacks.allocateMemory = defaultCallbacks.allocateMemory
    callbacks.freeMemory = defaultCallbacks.freeMemory
    addLoggerProxy(byref(callbacks))  # the proxy's target: always the same logger
    return callbacks


def forget_fmi2_sink(instance_name: str) -> None:
    """Stop routing ``instance_name``'s messages (its instance is freed)."""
    _SINKS.pop(instance_name, None)


def _unknown(owner: str, names: Sequence[str], known: Sequence[str], what: str) -> None:
    bad = [n for n in names if n not in known]
    if bad:
        raise ParameterError(what, bad[:5], f"{what} of '{owner}': {list(known)[:20]}")


class FmuParticipant:
    """A Co-Simulation FMU opened by :func:`~.archive.open_fmu` (kept open by the caller).

    Parameters
    ----------
    fmu : OpenedFmu
        The extracted, checked FMU.
    name : str
        The participant's name in connections (``"muscle"``).
    params : mapping of str to float, optional
        Parameter values [SI] set in initialisation mode.
    expose : sequence of str, optional
        Variables besides the outputs that connections may read, e.g. the states (local
        variables, readable by ``getReal`` / ``getFloat64``) an exact-state controller
        takes; listed after the outputs in ``outputs``.
    """

    def __init__(
        self,
        fmu: OpenedFmu,
        name: str,
        params: Mapping[str, float] | None = None,
        expose: Sequence[str] = (),
    ) -> None:
        md = fmu.description
        self.name = name
        self._version = fmu.fmi_version
        reals = [v for v in md.modelVariables if v.type in ("Real", "Float64")]
        self._vr = {v.name: v.valueReference for v in reals}
        self.inputs = tuple(v.name for v in reals if v.causality == "input")
        outputs = [v.name for v in reals if v.causality == "output"]
        _unknown(name, list(expose), list(self._vr), "variables")
        self.outputs = tuple(dict.fromkeys([*outputs, *expose]))
        self.units = {
            v.name: (v.unit or (v.declaredType.unit if v.declaredType else None)) or "1"
            for v in reals
        }
        parameters = [v.name for v in reals if v.causality == "parameter"]
        self._params = dict(params or {})
        _unknown(name, list(self._params), parameters, "parameters")
        self._who = f"FMU '{name}' ({fmu.path.name})"
        self._instance = f"{name}#{next(_SERIAL)}"  # unique: routes its FMI 2.0 messages
        cls = FMU2Slave if self._version == 2 else FMU3Slave
        cwd = os.getcwd()  # fmpy enters the binary's folder to load it and, on failure,
        try:  # stays there
            self._slave = cls(
                guid=md.guid if self._version == 2 else md.instantiationToken,
                unzipDirectory=str(fmu.folder),
                modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName=self._instance,
            )
        except Exception as err:  # fmpy raises a bare Exception (or OSError, AttributeError)
            raise ParticipantError(
                self._who, "fatal", f"loading its binary failed: {err}"
            ) from None
        finally:
            os.chdir(cwd)
        self._live = False
        self._log: list[str] = []  # the FMU's messages of status warning and worse

    def _logged(self, status: int, message: bytes) -> None:
        if status >= 1:
            self._log.append(message.decode(errors="replace"))

    def _call(self, what: str, fn, *args):
        seen = len(self._log)
        try:
            return fn(*args)
        except FMICallException as err:
            said = "; ".join(self._log[seen:]) or "no message"
            raise ParticipantError(
                self._who, STATUS[err.status], f"{what} failed: {said}"
            ) from None

    def _instantiate(self, *args) -> None:
        """Instantiate; a NULL instance (fmpy raises a bare Exception) is a fatal
        ParticipantError with the FMU's own messages."""
        seen = len(self._log)
        try:
            self._slave.instantiate(*args)
        except Exception as err:
            said = "; ".join(self._log[seen:]) or "no message"
            raise ParticipantError(
                self._who, "fatal", f"instantiate failed ({err}): {said}"
            ) from None

    def _set(self, values: Mapping[str, float]) -> None:
        if values:
            setter = self._slave.setReal if self._version == 2 else self._slave.setFloat64
            refs = [self._vr[n] for n in values]
            self._call("set", setter, refs, [float(v) for v in values.values()])

    def start(self, t0: float, inputs: Mapping[str, float]) -> None:
        _unknown(self.name, list(inputs), self.inputs, "inputs")
        s = self._slave
        if self._version == 2:
            self._callbacks = fmi2_callbacks(self._instance, self._logged)  # kept alive
            self._instantiate(False, self._callbacks)
        else:
            self._instantiate(
                False, False, False, False, lambda env, st, cat, msg: self._logged(st, msg)
            )
        self._live = True
        if self._version == 2:
            self._call("setupExperiment", s.setupExperiment, None, t0)
            self._call("enterInitializationMode", s.enterInitializationMode)
        else:
            self._call("enterInitializationMode", s.enterInitializationMode, None, t0)
        self._set({**self._params, **inputs})
        self._call("exitInitializationMode", s.exitInitializationMode)

    def set(self, values: Mapping[str, float]) -> None:
        self._set(values)

    def get(self, names: Sequence[str]) -> dict[str, float]:
        getter = self._slave.getReal if self._version == 2 else self._slave.getFloat64
        values = self._call("get", getter, [self._vr[n] for n in names])
        return dict(zip(names, values, strict=True))

    def do_step(self, t: float, h: float) -> None:
        self._call("doStep", self._slave.doStep, t, h)

    def close(self) -> None:
        """Terminate and free the instance (errors ignored: the instance may have failed)."""
        if self._live:
            self._live = False
            try:
                self._slave.terminate()
            except FMICallException:
                pass
            self._slave.freeInstance()
        forget_fmi2_sink(self._instance)


class NativeParticipant:
    """A flattened model stepped by the :class:`Simulator`, interchangeable with its FMU:
    it starts at the equilibrium of its start inputs as the exported FMU does, holds its
    inputs over each step, and reads any named signal.

    Parameters
    ----------
    model : Model
        A flattened model (with no algebraic unknowns or with them: any the simulator runs).
    name : str
        The participant's name in connections.
    params : mapping of str to object, optional
        Parameter overrides by name (units allowed).
    settings : SolverSettings, optional
        The simulator's method and tolerances.
    expose : sequence of str, optional
        Signals besides the outputs that connections may read (e.g. states), as
        :class:`FmuParticipant`.
    """

    def __init__(
        self,
        model: Model,
        name: str,
        params: Mapping[str, object] | None = None,
        settings: SolverSettings | None = None,
        expose: Sequence[str] = (),
    ) -> None:
        self.name = name
        self.model = model
        self.inputs = tuple(model.input_names)
        _unknown(name, list(expose), model.signal_names, "signals")
        # as its FMU (every signal can be read by get)
        self.outputs = tuple(dict.fromkeys([*model.output_names, *expose]))
        self.units = {n: model.unit(n) for n in model.signal_names}
        self._params = dict(params or {})
        self._sim = Simulator(model, settings)
        self._u: dict[str, float] = {}

    def _guard(self, what: str, fn, *args):
        try:
            return fn(*args)
        except SarcomereError as err:
            raise ParticipantError(f"model '{self.name}'", "error", f"{what}: {err}") from None

    def _finite(self, what: str, values: Mapping[str, float]) -> None:
        bad = {n: v for n, v in values.items() if not np.isfinite(v)}
        if bad:  # refused when set, as an FMU does (solve_equilibrium would accept a NaN)
            raise ParticipantError(f"model '{self.name}'", "error", f"{what}: {bad} not finite")

    def start(self, t0: float, inputs: Mapping[str, float]) -> None:
        _unknown(self.name, list(inputs), self.inputs, "inputs")
        self._finite("start", inputs)
        m = self.model
        start = m.u0(m.parameters(self._params))
        self._u = {**dict(zip(m.input_names, start, strict=True)), **inputs}
        eq = self._guard("equilibrium", solve_equilibrium, m, self._u, self._params)
        self._guard("reset", self._sim.reset, eq.x, eq.z, self._params, t0)

    def set(self, values: Mapping[str, float]) -> None:
        self._finite("set", values)
        self._u.update(values)

    def get(self, names: Sequence[str]) -> dict[str, float]:
        """Signals at the present state and the inputs as set (after ``start``, the start
        inputs; the simulator's own would be the model's defaults): an output that feeds
        through from an input reads as an FMU's does. Algebraic unknowns are those of the
        last step (the master never sets inputs between a step and a read)."""
        sim, m = self._sim, self.model
        u = np.array([self._u[n] for n in m.input_names], dtype=float)
        values = np.array(m.signals_function(list(names))(sim.x, sim.z, u, sim.p)).ravel()
        return dict(zip(names, values.tolist(), strict=True))

    def do_step(self, t: float, h: float) -> None:
        if not np.isclose(t, self._sim.t, rtol=0, atol=1e-12 * max(1.0, abs(t))):
            raise ParticipantError(
                f"model '{self.name}'",
                "error",
                f"doStep at {t:g} s, but it is at {self._sim.t:g} s",
            )
        self._guard(f"step to {t + h:g} s", self._sim.step, self._u, h)

    def close(self) -> None:
        """Nothing to free."""
