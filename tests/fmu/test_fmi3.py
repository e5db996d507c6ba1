"""The FMI 3.0 FMU: validation, fmpy runs against the native simulation, the calls that
differ from FMI 2.0 (the independent variable, array counts) and misuse."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Model, FMU3Slave, fmi3FMUState
from fmpy.validation import validate_fmu

from sarcomere.dynamics.assemblies import isometric

#: Every test here runs an FMU that the session compiles: the fast loop leaves them to
#: the full suite (README: `-m "not slow"` leaves out the compiling cases).
pytestmark = pytest.mark.slow

SIGNALS = ["sensor.f", "myofibril.aps1.chamber.p_gauge", "myofibril.actin1.T"]


def test_fmi3_fmu_validates(iso_fmu3):
    assert validate_fmu(str(iso_fmu3)) == []
    md = read_model_description(iso_fmu3)
    assert md.fmiVersion == "3.0"
    (time,) = [v for v in md.modelVariables if v.causality == "independent"]
    assert (time.name, time.valueReference) == ("time", 0)  # as the Reference FMUs
    assert "sources/buildDescription.xml" in zipfile.ZipFile(iso_fmu3).namelist()


@pytest.mark.parametrize("fmu", ["iso_fmu", "iso_fmu3"])
def test_no_output_depends_on_value_reference_0(fmu, request):
    """OMSimulator refuses an FMI 3.0 FMU whose output depends on value reference 0 (legal,
    but the Reference FMUs give 0 to ``time``): 0 is time in FMI 3.0 and unused in 2.0."""
    md = read_model_description(request.getfixturevalue(fmu))
    by_vr = {v.valueReference: v for v in md.modelVariables}
    assert len(by_vr) == len(md.modelVariables)  # unique
    if md.fmiVersion == "3.0":
        assert by_vr[0].name == "time"
    else:
        assert 0 not in by_vr
    assert any(o.dependencies for o in md.outputs)  # the check below is not vacuous
    for unknown in md.outputs + md.derivatives + md.initialUnknowns:
        deps = unknown.dependencies or []  # FMI 2.0 initial unknowns: the default
        assert all(d.valueReference != 0 for d in deps), unknown.variable.name


@pytest.mark.parametrize(
    ("fmi_type", "options"),
    [("CoSimulation", {}), ("ModelExchange", {"relative_tolerance": 1e-8})],
)
def test_fmi3_matches_native(iso_fmu3, iso_native, fmi_type, options):
    dt = np.dtype([("time", float), ("regulator.p_cmd", float)])
    sig = np.array([(0.0, 1e4), (0.05, 1e4), (0.05, 8e4), (0.5, 8e4)], dtype=dt)
    r = simulate_fmu(
        str(iso_fmu3),
        fmi_type=fmi_type,
        stop_time=0.5,
        output_interval=0.001,
        input=sig,
        output=SIGNALS,
        **options,
    )
    keep = len(r) - 1 - np.unique(r["time"][::-1], return_index=True)[1]
    r = r[np.sort(keep)]
    np.testing.assert_allclose(r["time"], iso_native.index, rtol=0, atol=1e-12)
    for n in SIGNALS:
        ref = iso_native[n]
        assert np.max(np.abs(r[n] - ref)) < 1e-4 * np.max(np.abs(ref)), n


class _Fmu3:
    def __init__(self, fmu, folder):
        with zipfile.ZipFile(fmu) as zf:
            zf.extractall(folder)
        self.md = read_model_description(fmu)
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.folder = folder
        self.errors: list[str] = []

    def instance(self, cosim=True, name="instance", **options):
        cls = FMU3Slave if cosim else FMU3Model
        fmu = cls(
            guid=self.md.guid,
            unzipDirectory=str(self.folder),
            modelIdentifier=self.md.coSimulation.modelIdentifier,
            instanceName=name,
        )

        def log(env, status, category, message):
            if status == 3:
                self.errors.append(message.decode())

        fmu.instantiate(logMessage=log, **options)
        return fmu


@pytest.fixture
def fmi3(iso_fmu3, tmp_path):
    return _Fmu3(iso_fmu3, tmp_path / "unzipped")


def test_fmi3_calls(fmi3):
    fmu = fmi3.instance()
    fmu.enterInitializationMode(startTime=0.25)
    fmu.exitInitializationMode()
    fmu.setFloat64([fmi3.vr["regulator.p_cmd"]], [5e4])
    t = 0.25
    for h in (0.001, 0.004, 0.0025):
        _, _, _, last = fmu.doStep(t, h)
        t += h
        assert last == t
    assert fmu.getFloat64([fmi3.vr["time"]]) == [t]
    assert fmu.getFloat64([fmi3.vr["sensor.f"]])[0] > 0.01
    state = fmu.getFMUState()
    raw = fmu.serializeFMUState(state)
    f_now = fmu.getFloat64([fmi3.vr["sensor.f"]])
    fmu.doStep(t, 0.01)
    fmu.setFMUState(fmu.deserializeFMUState(raw))
    assert fmu.getFloat64([fmi3.vr["sensor.f"]]) == f_now
    fmu.terminate()
    fmu.freeInstance()


def test_fmi3_directional_derivatives(fmi3):
    model = isometric(1)
    fmu = fmi3.instance(cosim=False)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    states = [fmi3.vr[n] for n in model.state_names]
    x = np.array(fmu.getFloat64(states))
    u = np.array(fmu.getFloat64([fmi3.vr["regulator.p_cmd"]]))
    ders = [fmi3.vr[f"der({n})"] for n in model.state_names]
    outs = [fmi3.vr[n] for n in model.output_names]
    knowns = states + [fmi3.vr["regulator.p_cmd"]]
    J = np.array([fmu.getDirectionalDerivative(ders + outs, [k], [1.0]) for k in knowns]).T
    A, B, C, D = (np.array(v) for v in model.function("jac")(x, [], u, model.parameters()))
    expected = np.block([[A, B], [C, D]])
    scale = np.maximum(np.abs(expected).max(axis=1, keepdims=True), 1e-300)
    np.testing.assert_allclose(J / scale, expected / scale, rtol=0, atol=1e-12)
    fmu.freeInstance()


def test_event_and_continuous_time_mode_belong_to_their_instances(fmi3):
    """A Co-Simulation instance has event mode only if instantiated with eventModeUsed
    (then it enters it after initialisation, as the Reference FMUs), and never
    continuous-time mode (Model Exchange's)."""
    fmu = _started(fmi3.instance())
    with pytest.raises(FMICallException):
        fmu.enterEventMode()
    assert fmi3.errors[-1] == (
        "fmi3EnterEventMode: this Co-Simulation instance was instantiated without eventModeUsed"
    )
    fmu.doStep(0.0, 0.001)  # still in step mode
    fmu.freeInstance()
    fmu = _started(fmi3.instance(name="events", eventModeUsed=True))
    with pytest.raises(FMICallException):  # in event mode after initialisation
        fmu.doStep(0.0, 0.001)
    assert fmi3.errors[-1] == "doStep is not allowed in event mode"
    fmu.enterEventMode()
    with pytest.raises(FMICallException):
        fmu.fmi3EnterContinuousTimeMode(fmu.component)
    assert fmi3.errors[-1] == "fmi3EnterContinuousTimeMode: not a Model Exchange instance"
    fmu.enterStepMode()
    fmu.doStep(0.0, 0.001)
    fmu.freeInstance()


def _started(fmu):
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu


def _past_the_stop_time(fmu, vr):
    fmu.enterInitializationMode(startTime=0.0, stopTime=0.01)
    fmu.exitInitializationMode()
    fmu.doStep(0.0, 0.005)
    fmu.doStep(0.005, 0.0051)


def _a_freed_state(fmu, vr):
    state = _started(fmu).getFMUState()
    copy = fmi3FMUState(state.value)  # fmpy sets the freed handle to NULL
    fmu.freeFMUState(state)
    fmu.setFMUState(copy)  # refused by the registry of live states, never read


@pytest.mark.parametrize(
    ("misuse", "message"),
    [
        (_past_the_stop_time, "ends at t = 0.0101 s, past the stop time 0.01 s given at set-up"),
        (_a_freed_state, "fmi3SetFMUState: this FMU state was freed already"),
        (lambda f, v: f.doStep(0.0, 0.001), "doStep is not allowed in instantiated"),
        (lambda f, v: f.setFloat64([v["time"]], [1.0]), "time is the independent variable"),
        (lambda f, v: _started(f).getFloat64([len(v)]), "unknown value reference"),
        (lambda f, v: f.getAdjointDerivative([0], [0], [1.0]), "providesAdjointDerivatives"),
        (lambda f, v: f.deserializeFMUState(b"x" * 10), "refused (wrong size)"),
    ],
)
def test_fmi3_misuse(fmi3, misuse, message):
    fmu = fmi3.instance()
    with pytest.raises(FMICallException) as info:
        misuse(fmu, fmi3.vr)
    assert info.value.status == 3
    assert any(message in m for m in fmi3.errors), fmi3.errors
    fmu.freeInstance()
