"""The FMI 2.0 calls one by one (fmpy's low-level classes): directional derivatives,
initialisation, saved states, several instances, reset, logging and misuse."""

from __future__ import annotations

import ctypes
import math

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from sarcomere.dynamics.assemblies import HOOK_MASS_KG, hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.fmu import codegen
from sarcomere.fmu import export as export_module

#: Every test here runs an FMU that the session compiles: the fast loop leaves them to
#: the full suite (README: `-m "not slow"` leaves out the compiling cases).
pytestmark = pytest.mark.slow

P_CMD = "regulator.p_cmd"
LENGTH = "myofibril.length"


@pytest.fixture(scope="module")
def model():
    return hanging_load(3, load_kg=0.05)


def _start(fmu, values: dict | None = None, loaded=None):
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    if values:
        fmu.setReal([loaded.vr[k] for k in values], list(values.values()))
    fmu.exitInitializationMode()


def _command(fmu, loaded, value: float) -> None:
    """A new pressure command after initialisation (a step from the equilibrium at 0)."""
    fmu.setReal([loaded.vr[P_CMD]], [value])


def _get(fmu, loaded, name: str) -> float:
    return fmu.getReal([loaded.vr[name]])[0]


def test_directional_derivatives_equal_casadi_jacobians(step_loaded, model):
    fmi = step_loaded
    fmu = fmi.instance(cosim=False)
    _start(fmu)
    fmu.enterContinuousTimeMode()
    p = model.parameters()
    x0 = fmu.getReal([fmi.vr[n] for n in model.state_names])
    x = np.array(x0) * (1 + 0.01 * np.sin(np.arange(model.nx)))
    u = np.array([3e4])
    fmu.setContinuousStates((ctypes.c_double * model.nx)(*x), model.nx)
    fmu.setReal([fmi.vr[P_CMD]], u.tolist())
    knowns = [fmi.vr[n] for n in model.state_names + model.input_names]
    ders = [fmi.vr[f"der({n})"] for n in model.state_names]
    outs = [fmi.vr[n] for n in model.output_names]
    J = np.array(
        [fmu.getDirectionalDerivative(ders + outs, [k], [1.0]) for k in knowns]
    ).T  # column per known
    A, B, C, D = (np.array(v) for v in model.function("jac")(x, [], u, p))
    expected = np.block([[A, B], [C, D]])
    scale = np.maximum(np.abs(expected).max(axis=1, keepdims=True), 1e-300)
    np.testing.assert_allclose(J / scale, expected / scale, rtol=0, atol=1e-12)
    assert np.count_nonzero(A) > model.nx  # a real Jacobian, not a trivial one
    fmu.terminate()
    fmu.freeInstance()


def test_initial_equilibrium_follows_parameters(step_loaded, model):
    fmi = step_loaded
    fmu = fmi.instance()
    _start(fmu, {"load.m": 0.101, P_CMD: 5e4}, fmi)
    eq = solve_equilibrium(model, {P_CMD: 5e4}, {"load.m": 0.101})
    assert _get(fmu, fmi, LENGTH) == pytest.approx(eq[LENGTH], rel=1e-9)
    fmu.doStep(0.0, 0.01)
    assert _get(fmu, fmi, LENGTH) == pytest.approx(eq[LENGTH], rel=1e-9)  # stays at rest
    fmu.freeInstance()


def test_a_tunable_parameter_changes_in_step_mode(step_loaded, model):
    fmi = step_loaded
    fmu = fmi.instance()
    _start(fmu, None, fmi)
    rest = _get(fmu, fmi, LENGTH)
    fmu.setReal([fmi.vr["load.m"]], [0.101])  # 50 g more hung on at t = 0
    for k in range(1000):
        fmu.doStep(k * 0.005, 0.005)
    eq = solve_equilibrium(model, {P_CMD: 0.0}, {"load.m": 0.101})
    assert _get(fmu, fmi, LENGTH) == pytest.approx(eq[LENGTH], rel=1e-6)  # settled there
    assert eq[LENGTH] > rest + 1e-3
    fmu.freeInstance()


def test_a_tunable_parameter_waits_for_event_mode_in_model_exchange(step_loaded):
    fmi = step_loaded
    fmu = fmi.instance(cosim=False)
    _start(fmu, None, fmi)
    fmu.enterContinuousTimeMode()
    with pytest.raises(FMICallException):
        fmu.setReal([fmi.vr["load.m"]], [0.06])
    assert "load.m is a tunable parameter; after initialisation" in fmi.errors()[-1]
    fmu.enterEventMode()
    fmu.setReal([fmi.vr["load.m"]], [0.06])
    assert fmu.getReal([fmi.vr["load.m"]]) == [0.06]
    fmu.freeInstance()


def test_load_m_is_the_whole_end_mass_and_a_massless_end_is_refused(step_loaded):
    """docs/fmu.md, Variables: ``load.m`` is the mass at the chain's end with the 1 g hook
    (step-50g: 51 g; a scene's ``load = "0 g"`` is ``load.m`` = 1 g, which runs); 0, a
    massless end the ODE divides by, is refused naming the range, as in a scene."""
    fmi = step_loaded
    (start,) = [v.start for v in fmi.md.modelVariables if v.name == "load.m"]
    assert float(start) == pytest.approx(0.051, rel=1e-12)
    fmu = fmi.instance()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    with pytest.raises(FMICallException):
        fmu.setReal([fmi.vr["load.m"]], [0.0])
    assert fmi.errors()[-1].startswith("set real: load.m = 0 is outside [9.99")
    fmu.setReal([fmi.vr["load.m"]], [HOOK_MASS_KG])  # the hook alone: no payload
    fmu.exitInitializationMode()
    _command(fmu, fmi, 1e5)
    fmu.doStep(0.0, 0.05)
    assert _get(fmu, fmi, LENGTH) < 0.17  # contracting with nothing but the hook
    fmu.freeInstance()


def test_states_set_by_the_importer_are_kept(step_loaded):
    fmi = step_loaded
    fmu = fmi.instance()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    s0 = _get(fmu, fmi, "load.s")
    fmu.setReal([fmi.vr["load.s"]], [s0 + 1e-3])
    fmu.exitInitializationMode()
    assert _get(fmu, fmi, "load.s") == s0 + 1e-3
    fmu.doStep(0.0, 0.002)
    assert _get(fmu, fmi, "load.v") < -1e-3  # released from 1 mm below rest, it rises
    fmu.freeInstance()


def test_saved_state_restores_and_serializes(step_loaded):
    fmi = step_loaded
    fmu = fmi.instance()
    _start(fmu, None, fmi)
    _command(fmu, fmi, 1e5)
    t = 0.0
    for _ in range(20):
        fmu.doStep(t, 0.002)
        t += 0.002
    state = fmu.getFMUstate()
    raw = fmu.serializeFMUstate(state)
    fmu.freeFMUstate(state)
    after = []
    for _ in range(20):
        fmu.doStep(t + 0.002 * len(after), 0.002)
        after.append(_get(fmu, fmi, LENGTH))
    other = fmi.instance(name="other")
    _start(other, None, fmi)
    restored = other.deSerializeFMUstate(raw)
    other.setFMUstate(restored)
    other.freeFMUstate(restored)
    again = []
    for _ in range(20):
        other.doStep(t + 0.002 * len(again), 0.002)
        again.append(_get(other, fmi, LENGTH))
    assert again == after
    assert after[-1] < after[0]  # moving: the comparison is not of constants
    fmu.freeInstance()
    other.fmi2FreeInstance(other.component)


def test_a_saved_state_stays_with_its_instance_type(step_loaded):
    """A state saved by a Co-Simulation instance (in step mode) is refused by a Model
    Exchange instance and the other way round, as a handle and serialised: else doStep
    would run on a Model Exchange instance, setContinuousStates on a Co-Simulation one."""
    fmi = step_loaded
    cosim, me = fmi.instance(name="cs"), fmi.instance(cosim=False, name="me")
    _start(cosim, None, fmi)
    _start(me, None, fmi)
    for source, target, kinds in (
        (cosim, me, ("Co-Simulation", "Model Exchange")),
        (me, cosim, ("Model Exchange", "Co-Simulation")),
    ):
        state = source.getFMUstate()
        raw = source.serializeFMUstate(state)
        expected = f"a state of a {kinds[0]} instance cannot be set on a {kinds[1]} instance"
        with pytest.raises(FMICallException):
            target.setFMUstate(state)
        assert fmi.errors()[-1] == f"fmi2SetFMUstate: {expected}"
        with pytest.raises(FMICallException):
            target.deSerializeFMUstate(raw)
        assert fmi.errors()[-1] == f"fmi2DeSerializeFMUstate: {expected}"
        source.freeFMUstate(state)
    cosim.doStep(0.0, 0.001)  # each unchanged, in its own mode
    me.enterContinuousTimeMode()
    cosim.freeInstance()
    me.freeInstance()


def test_instances_are_independent_and_reset(step_loaded):
    fmi = step_loaded
    a, b = fmi.instance(name="a"), fmi.instance(name="b")
    _start(a, None, fmi)
    _command(a, fmi, 1e5)
    _start(b, None, fmi)
    rest = _get(b, fmi, LENGTH)
    for k in range(50):
        a.doStep(k * 0.002, 0.002)
        b.doStep(k * 0.002, 0.002)
    assert _get(a, fmi, LENGTH) < rest - 1e-3
    assert _get(b, fmi, LENGTH) == pytest.approx(rest, rel=1e-12)
    a.reset()
    _start(a, None, fmi)
    assert _get(a, fmi, LENGTH) == rest
    a.fmi2FreeInstance(a.component)
    b.freeInstance()


def test_variable_communication_steps(step_loaded):
    fmi = step_loaded
    fixed, varying = fmi.instance(name="fixed"), fmi.instance(name="varying")
    for fmu in (fixed, varying):
        _start(fmu, None, fmi)
        _command(fmu, fmi, 1e5)
    rest = _get(fixed, fmi, LENGTH)
    for k in range(10):
        fixed.doStep(k * 0.01, 0.01)
    t = 0.0
    for h in (0.0005, 0.0235, 0.001, 0.075):
        varying.doStep(t, h)
        t += h
    assert t == pytest.approx(0.1, abs=1e-15)
    a, b = _get(fixed, fmi, LENGTH), _get(varying, fmi, LENGTH)
    assert a == pytest.approx(b, rel=1e-6)
    assert a < rest - 1e-3  # it moved: the comparison is not of two resting states
    fixed.freeInstance()
    varying.fmi2FreeInstance(varying.component)


def test_logging_categories(step_loaded):
    fmi = step_loaded
    fmu = fmi.instance(logging_on=True)
    _start(fmu, None, fmi)
    fmu.doStep(0.0, 0.002)
    assert not [m for m in fmi.messages if m[1] == "logSolver"]
    fmu.setDebugLogging(True, ["logSolver"])
    fmu.doStep(0.002, 0.0025)
    assert any(c == "logSolver" and " Radau IIA steps" in m for _, c, m in fmi.messages)
    with pytest.raises(FMICallException):
        fmu.setDebugLogging(True, ["logEverything"])
    assert "unknown log category 'logEverything'" in fmi.errors()[-1]
    fmu.freeInstance()


# --- misuse: an error status and a log message, never a crash -------------------------
def _before_init(fmu, fmi):
    fmu.doStep(0.0, 0.001)


def _nan_input(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.setReal([fmi.vr[P_CMD]], [math.nan])


def _input_above_range(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.setReal([fmi.vr[P_CMD]], [7e5])


def _parameter_below_range(fmu, fmi):
    fmu.setupExperiment(startTime=0.0)
    fmu.setReal([fmi.vr["load.m"]], [-0.01])


def _unknown_value_reference(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.getReal([len(fmi.vr) + 5])


def _value_reference_0(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.getReal([0])  # time's in FMI 3.0; no variable of an FMI 2.0 FMU


def _past_the_stop_time(fmu, fmi):
    fmu.setupExperiment(startTime=0.0, stopTime=0.01)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.doStep(0.0, 0.005)
    fmu.doStep(0.005, 0.0051)


def _fixed_parameter_after_init(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.setReal([fmi.vr["myofibril.actin0.l"]], [0.033])


def _set_a_state_in_step_mode(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.setReal([fmi.vr["load.s"]], [0.2])


def _set_an_output(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.setReal([fmi.vr[LENGTH]], [0.1])


def _wrong_communication_point(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.doStep(0.5, 0.001)


def _bad_step_size(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.doStep(0.0, -0.001)


def _garbage_state(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.deSerializeFMUstate(b"\x00" * 64)


def _states_outside_the_domain(fmu, fmi):
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([fmi.vr["myofibril.aps1.expansion.s"]], [-0.05])  # stretch 1 - 5 cm / 2 cm
    fmu.exitInitializationMode()


def _get_an_integer(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.getInteger([1])


def _set_a_string(fmu, fmi):
    _start(fmu, None, fmi)
    fmu.setString([1], ["x"])


def _no_equilibrium(fmu, fmi):
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([fmi.vr["myofibril.actin0.l"]], [0.001])  # a thread shorter than its anchors
    fmu.exitInitializationMode()


@pytest.mark.parametrize(
    ("misuse", "message"),
    [
        (_before_init, "doStep is not allowed in instantiated"),
        (_nan_input, "regulator.p_cmd = nan is outside"),
        (_input_above_range, "regulator.p_cmd = 700000 is outside [0, 600000]"),
        (_parameter_below_range, "load.m = -0.01"),
        (_unknown_value_reference, "unknown value reference"),
        (_value_reference_0, "unknown value reference 0"),
        (_past_the_stop_time, "ends at t = 0.0101 s, past the stop time 0.01 s given at set-up"),
        (_fixed_parameter_after_init, "myofibril.actin0.l is a fixed parameter"),
        (_set_a_state_in_step_mode, "load.s is a state; it can be set only before the end"),
        (_set_an_output, "myofibril.length is an output and cannot be set"),
        (_wrong_communication_point, "is not the FMU's time"),
        (_bad_step_size, "step size -0.001 is not a finite number > 0"),
        (_garbage_state, "refused (wrong size)"),
        (_states_outside_the_domain, "myofibril.aps1.yeoh.lambda = -1.5 is outside"),
        (_no_equilibrium, "equilibrium not found: scaled residual"),
        (_get_an_integer, "fmi2GetInteger: this FMU has no variables of that type"),
        (_set_a_string, "fmi2SetString: this FMU has no variables of that type"),
    ],
)
def test_misuse_is_an_error_with_a_message(step_loaded, misuse, message):
    fmi = step_loaded
    fmu = fmi.instance()
    with pytest.raises(FMICallException) as info:
        misuse(fmu, fmi)
    assert info.value.status == 3
    assert any(message in m for m in fmi.errors()), fmi.errors()
    fmu.freeInstance()


def test_leaving_the_domain_in_a_step_is_an_error_until_reset(step_loaded):
    fmi = step_loaded
    fmu = fmi.instance()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    # 2000 times the air at rest: the threads are pulled straight and stretched past
    # their breaking strain (THREAD_STRAIN_MAX) at 0.35 ms; steps of 0.05 ms
    fmu.setReal([fmi.vr["myofibril.aps1.chamber.m_air"]], [1e-2])
    fmu.exitInitializationMode()
    start = _get(fmu, fmi, LENGTH)
    with pytest.raises(FMICallException):
        for k in range(20):
            good = _get(fmu, fmi, LENGTH)
            fmu.doStep(k * 5e-5, 5e-5)
    assert k == 6
    msg = "doStep to t = 0.00035 s: myofibril.actin0.strain_b = 0.19"  # the thread breaks
    assert msg in fmi.errors()[-1]
    assert _get(fmu, fmi, LENGTH) == good != start  # readable at the last good point
    with pytest.raises(FMICallException):
        fmu.doStep(0.0, 0.01)
    assert "doStep is not allowed in error state" in fmi.errors()[-1]
    fmu.reset()
    _start(fmu, None, fmi)
    assert _get(fmu, fmi, LENGTH) == start  # the start again
    fmu.freeInstance()


def test_freeing_twice_is_logged_not_a_crash(step_loaded):
    fmi = step_loaded
    fmu = fmi.instance(name="twice")
    _start(fmu, None, fmi)
    fmu.fmi2FreeInstance(fmu.component)
    fmu.fmi2FreeInstance(fmu.component)
    assert fmi.errors() == ["fmi2FreeInstance: this instance was freed already"]
    with pytest.raises(FMICallException):
        fmu.doStep(0.0, 0.001)
    assert fmi.errors()[-1] == "fmi2DoStep: this instance was freed already"


def test_a_state_of_another_fmu_is_refused(step_loaded, load, iso_fmu):
    other = load(iso_fmu)
    iso = other.instance(name="iso")
    _start(iso, None, other)
    foreign = iso.getFMUstate()
    fmu = step_loaded.instance()
    _start(fmu, None, step_loaded)
    with pytest.raises(FMICallException):
        fmu.setFMUstate(foreign)
    assert step_loaded.errors()[-1] == "fmi2SetFMUstate: not a state of this FMU"
    assert _get(fmu, step_loaded, LENGTH) > 0.17  # unchanged: still the 3-APS chain
    iso.freeFMUstate(foreign)
    iso.freeInstance()
    fmu.freeInstance()


@pytest.mark.parametrize(
    ("tamper", "why"),
    [
        (lambda b, head: b[:30] + b"X" + b[31:], "not a state of this FMU"),
        (lambda b, head: b[:head] + np.float64(np.nan).tobytes() + b[head + 8 :], "not finite"),
        (lambda b, head: b[:-24] + np.float64(3.0).tobytes() + b[-16:], "unknown mode"),
    ],
)
def test_a_tampered_serialized_state_is_refused(step_loaded, tamper, why):
    fmi = step_loaded
    fmu = fmi.instance()
    _start(fmu, None, fmi)
    state = fmu.getFMUstate()
    raw = fmu.serializeFMUstate(state)
    head = len(b"sarcomere-fmu-state-1\0") + len(fmi.md.guid) + 1  # then t, x, u, p, flags
    assert fmu.deSerializeFMUstate(raw)  # the untouched bytes load
    with pytest.raises(FMICallException):
        fmu.deSerializeFMUstate(tamper(raw, head))
    assert why in fmi.errors()[-1]
    fmu.freeInstance()


def test_a_do_step_too_long_for_its_integrator_names_its_length(step_loaded):
    """doStep(0, 4e6 s) after a 0.5 MPa step (step-50g's muscle): radau.c's smallest
    step is 10 machine epsilons of the step's end, 9e-9 s, which the filling's first steps
    need to undercut: the message says that the step's length limits (it said "too small
    (10 machine epsilons of t)" at t = 0)."""
    fmu = step_loaded.instance()
    _start(fmu, None, step_loaded)
    _command(fmu, step_loaded, 5e5)
    with pytest.raises(FMICallException):
        fmu.doStep(0.0, 4e6)
    message = step_loaded.errors()[-1]
    assert (
        "the step size became too small (below 8.88e-09 s, 10 machine epsilons of this " in message
    )
    assert "doStep's length 4e+06 s: it is the step's end that limits; take shorter" in message
    fmu.freeInstance()


@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
def test_a_do_step_past_its_step_limit_is_reported(tmp_path, monkeypatch, load):
    """An FMU built with at most 3 Radau IIA steps per doStep: a 0.1 s step through the
    filling after a pressure step needs more, and doStep fails naming the limit and the
    time reached."""
    monkeypatch.setattr(codegen, "CS_MAX_STEPS", 3)
    fmi = load(export_module.export_fmu(hanging_load(1), tmp_path / "strict.fmu"))
    fmu = fmi.instance(logging_on=True)
    _start(fmu, None, fmi)
    _command(fmu, fmi, 1e5)
    with pytest.raises(FMICallException):
        fmu.doStep(0.0, 0.1)
    message = fmi.errors()[-1]
    assert "too many steps" in message and "after 3 steps" in message
    assert "rtol 1e-08" in message
    fmu.freeInstance()
