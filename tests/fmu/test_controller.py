"""The PID controller FMU (fmu/controller.py over fmu/sampled.py): valid, Co-Simulation only,
and sample for sample the Python controller's law (the same CasADi Function) on a
measurement sequence that saturates and winds; the doStep semantics of docs/fmu.md."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Model,
    FMU2Slave,
)
from fmpy.fmi3 import FMU3Model, FMU3Slave
from fmpy.validation import validate_fmu

from sarcomere.controllers.base import Controller
from sarcomere.controllers.linearize import operating_point
from sarcomere.controllers.lqi import make_lqi
from sarcomere.controllers.pid import make_pid
from sarcomere.dynamics import hanging_load
from sarcomere.dynamics.errors import ParameterError
from sarcomere.fmu.controller import export_controller_fmu, pid_system
from sarcomere.fmu.export import MAX_SAMPLES, fmi_headers
from sarcomere.fmu.participants import fmi2_callbacks
from sarcomere.fmu.sampled import export_sampled_fmu

pytestmark = pytest.mark.slow  # exports, builds and runs FMUs: the full suite (CI)

DT = 0.01
"""Sample period [s]."""
U0 = 5e4
"""Operating pressure and bias [Pa]."""
TASK = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0.0, "u_max": 1e5}


@pytest.fixture(scope="module")
def plant():
    m = hanging_load(n=1, load_kg=0.02)
    return m, operating_point(m, {"regulator.p_cmd": U0})


@pytest.fixture(scope="module")
def pid(plant):
    m, op = plant
    return make_pid(m, op, DT, {**TASK, "kd": -50.0})


@pytest.fixture(scope="module", params=[2, 3])
def fmu(request, plant, pid, tmp_path_factory):
    """(path, FMI version, extracted folder) of the PID's FMU."""
    folder = tmp_path_factory.mktemp("ctl")
    path = export_controller_fmu(pid, plant[0], folder / "pid.fmu", U0, request.param)
    return path, request.param, extract(str(path), unzipdir=str(folder / "unzipped"))


def _measurements(op, n: int = 300) -> tuple[np.ndarray, float]:
    """A measured length that swings the PID into both bounds, and the reference."""
    rng = np.random.default_rng(1)
    y0 = op["myofibril.length"]
    return y0 + 2e-3 * np.sin(np.arange(n) * 0.05) + 1e-4 * rng.standard_normal(n), y0


def _python(pid, ys, r) -> np.ndarray:
    pid.reset({"regulator.p_cmd": U0})
    y, ref = pid.output, {pid.output: r}
    return np.array([pid.update(k * DT, {y: v}, ref)[pid.input] for k, v in enumerate(ys)])


MESSAGES: list[str] = []
"""What the FMI 2.0 instances logged."""


def _fmu_commands(s, ys, r) -> list[float]:
    """The controller FMU ``s`` stepped once per measurement (reference ``r``), its
    commands; the slave is closed afterwards."""
    got = []
    for k, y in enumerate(ys):
        s.set(reference=r, measurement=y)
        s.step(k * DT, DT)
        got.append(s.get("command"))
    s.close()
    return got


def _callbacks(instance_name: str = "c"):
    """FMI 2.0 callbacks through the project's one process-wide logger."""
    return fmi2_callbacks(instance_name, lambda status, msg: MESSAGES.append(msg.decode()))


class Slave:
    """A Co-Simulation instance of the FMU, stepped by hand."""

    def __init__(self, fmu, t0: float = 0.0, model_identifier: str = "pid") -> None:
        path, version, folder = fmu
        md = read_model_description(path)
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        cls, guid = (FMU2Slave, md.guid) if version == 2 else (FMU3Slave, md.instantiationToken)
        self.s = cls(
            guid=guid, unzipDirectory=folder, modelIdentifier=model_identifier, instanceName="c"
        )
        self.v = version
        self.s.instantiate(callbacks=_callbacks()) if version == 2 else self.s.instantiate()
        if version == 2:
            self.s.setupExperiment(startTime=t0)
            self.s.enterInitializationMode()
        else:
            self.s.enterInitializationMode(startTime=t0)
        self.s.exitInitializationMode()

    def set(self, **values) -> None:
        setter = self.s.setReal if self.v == 2 else self.s.setFloat64
        setter([self.vr[k] for k in values], [float(v) for v in values.values()])

    def get(self, name: str) -> float:
        getter = self.s.getReal if self.v == 2 else self.s.getFloat64
        return getter([self.vr[name]])[0]

    def step(self, t: float, h: float) -> None:
        self.s.doStep(t, h)

    def close(self) -> None:
        self.s.terminate()
        self.s.freeInstance()


def declared_sources(folder: Path) -> list[str]:
    """The C files an unzipped FMU declares for a rebuild (FMI 2.0 ``SourceFiles``, FMI 3.0
    ``sources/buildDescription.xml``, as fmpy reads both)."""
    md = read_model_description(str(folder))
    return [f for c in md.buildConfigurations for s in c.sourceFileSets for f in s.sourceFiles]


def rebuild_errors(folder: Path, names: list[str]) -> str:
    """What gcc says building the declared ``names`` from the archive's own sources and the
    FMI headers alone ("" if they build)."""
    src = folder / "sources"
    cmd = ["gcc", "-shared", "-fPIC", "-std=c11", "-I", str(src), "-I", str(fmi_headers())]
    cmd += [str(src / n) for n in names] + ["-o", str(folder / "rebuilt.so"), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    return done.stderr if done.returncode else ""


def test_the_declared_sources_rebuild_from_the_archive(fmu):
    folder = Path(fmu[2])
    names = declared_sources(folder)
    assert f"fmi{fmu[1]}.c" in names and "sm_casadi.c" in names
    assert rebuild_errors(folder, names) == ""


def test_controller_fmu_validates_and_is_co_simulation_only(fmu):
    path, version, folder = fmu
    assert validate_fmu(str(path)) == []
    md = read_model_description(path)
    assert md.modelExchange is None and md.coSimulation is not None
    by_name = {v.name: v for v in md.modelVariables}
    assert by_name["command"].causality == "output" and by_name["command"].variability == "discrete"
    assert (by_name["measurement"].unit, by_name["command"].unit) == ("m", "Pa")
    assert by_name["kp"].variability == "tunable" and by_name["bias"].variability == "fixed"
    assert float(md.defaultExperiment.stepSize) == DT


def test_controller_fmu_equals_the_python_pid_step_by_step(fmu, plant, pid):
    path, version, folder = fmu
    ys, r = _measurements(plant[1])
    expected = _python(pid, ys, r)
    assert np.any(expected == 0.0) and np.any(expected == 1e5)  # both bounds: anti-windup
    assert np.sum((expected > 0) & (expected < 1e5)) > 50  # and the linear range
    s = Slave(fmu)
    assert s.get("command") == U0  # before the first sample: the bias
    got = _fmu_commands(s, ys, r)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12 * 1e5)


def test_fmpy_simulation_of_the_controller_fmu_equals_the_python_pid(fmu, plant, pid):
    path, _, _ = fmu
    ys, r = _measurements(plant[1])
    t = np.arange(len(ys)) * DT
    rows = [row for k in range(len(ys)) for row in ((t[k], r, ys[k]), (t[k] + DT, r, ys[k]))]
    dtype = [("time", float), ("reference", float), ("measurement", float)]
    res = simulate_fmu(
        str(path),
        fmi_type="CoSimulation",
        stop_time=t[-1] + DT,
        output_interval=DT,
        input=np.array(rows, dtype=dtype),
        output=["command"],
    )
    assert res["command"][0] == U0
    np.testing.assert_allclose(res["command"][1:], _python(pid, ys, r), rtol=1e-12, atol=1e-7)


def test_steps_shorter_longer_and_off_the_sample_grid(fmu, plant, pid):
    """h = T/4: the samples at the instants, outputs held between; h = 2.5 T: every
    instant inside the step, on the held inputs; a start time of 1 s: first sample there."""
    path, version, folder = fmu
    ys, r = _measurements(plant[1], 12)
    expected = _python(pid, ys, r)
    s = Slave(fmu, t0=1.0)
    for k in range(4):
        for j in range(4):
            s.set(reference=r, measurement=ys[k])
            s.step(1.0 + k * DT + j * DT / 4, DT / 4)
            assert s.get("command") == pytest.approx(expected[k], rel=1e-12)
    s.close()
    pid.reset({"regulator.p_cmd": U0})  # 0, 1, 2 at ys[0]; 3, 4 at ys[3]
    held = [ys[0]] * 3 + [ys[3]] * 2
    want = [pid.update(0, {pid.output: y}, {pid.output: r})[pid.input] for y in held]
    s = Slave(fmu)
    s.set(reference=r, measurement=ys[0])
    s.step(0.0, 2.5 * DT)  # instants 0, T, 2T
    assert s.get("command") == pytest.approx(want[2], rel=1e-12)
    s.set(reference=r, measurement=ys[3])
    s.step(2.5 * DT, 2.5 * DT)  # instants 3T, 4T
    assert s.get("command") == pytest.approx(want[4], rel=1e-12)
    s.close()


def test_one_do_step_runs_at_most_max_samples(fmu, plant):
    """A doStep over more than MAX_SAMPLES instants is refused with a message (bounded work
    per call: an NMPC's doStep(0, 10) ran 1000 samples in 9.5 s, and the longest step
    accepted would have run for weeks); the instance goes on."""
    s = Slave(fmu)
    y = plant[1]["myofibril.length"]
    s.set(reference=y, measurement=y)
    MESSAGES.clear()
    with pytest.raises(FMICallException):
        s.step(0.0, (MAX_SAMPLES + 0.5) * DT)
    if fmu[1] == 2:
        assert f"holds {MAX_SAMPLES + 1} sample instants (period 0.01 s), more than" in MESSAGES[-1]
    s.step(0.0, MAX_SAMPLES * DT)  # the most in one call
    s.step(MAX_SAMPLES * DT, DT)
    s.close()


def test_a_tunable_gain_takes_effect_at_the_next_sample(fmu, plant, pid):
    path, version, folder = fmu
    s = Slave(fmu)
    y = plant[1]["myofibril.length"]
    s.set(reference=y - 1e-4, measurement=y)
    s.set(kp=0.0, ki=0.0)
    s.step(0.0, DT)
    assert s.get("command") == U0  # no error term left: the bias
    with pytest.raises(FMICallException):
        s.set(bias=1e4)  # fixed: the start state depends on it
    s.close()


def test_model_exchange_is_refused(fmu, pid, plant, tmp_path):
    path, version, folder = fmu
    md = read_model_description(path)
    cls, guid = (FMU2Model, md.guid) if version == 2 else (FMU3Model, md.instantiationToken)
    me = cls(guid=guid, unzipDirectory=folder, modelIdentifier="pid", instanceName="me")
    with pytest.raises(Exception, match="instantiate"):
        me.instantiate(callbacks=_callbacks("me")) if version == 2 else me.instantiate()
    if version == 2:
        assert "sampled system (period 0.01 s): Co-Simulation only" in MESSAGES[-1]
    system = pid_system(pid, plant[0], U0)
    with pytest.raises(ParameterError, match="no continuous-time form"):
        export_sampled_fmu(system, tmp_path / "me.fmu", interface="ModelExchange")


def test_bad_controller_exports_are_refused(plant, pid, tmp_path):
    m, op = plant

    class Hold(Controller):
        def update(self, t, y, r):
            return {TASK["input"]: U0}

    with pytest.raises(ParameterError, match="bias"):
        export_controller_fmu(pid, m, tmp_path / "c.fmu", 2e5)
    hold = Hold(DT, [TASK["input"]], [TASK["output"]], {TASK["input"]: 0}, {TASK["input"]: 1e5})
    with pytest.raises(ParameterError, match="a PID, an LQI, an NMPC or an LMPC"):
        export_controller_fmu(hold, m, tmp_path / "c.fmu", U0)
    on_ekf = make_lqi(m, op, DT, {**TASK, "feedforward": "linear", "estimator": "ekf"})
    with pytest.raises(ParameterError, match="full-state LQI"):
        export_controller_fmu(on_ekf, m, tmp_path / "c.fmu", U0)


@pytest.fixture(scope="module")
def lqi(plant):
    m, op = plant
    return make_lqi(m, op, DT, TASK)  # the equilibria feed-forward: interpolated tables


@pytest.fixture(scope="module", params=[2, 3])
def lqi_fmu(request, plant, lqi, tmp_path_factory):
    folder = tmp_path_factory.mktemp("lqi")
    path = export_controller_fmu(lqi, plant[0], folder / "lqi.fmu", U0, request.param)
    return path, request.param, extract(str(path), unzipdir=str(folder / "unzipped"))


def test_the_lqi_fmu_equals_the_python_lqi(lqi_fmu, plant, lqi):
    """A full-state LQI: the plant's states are inputs by name. Random states and lengths
    around the operating point and a reference that steps beyond both ends of the
    feed-forward table: the same commands, both bounds and the windup guard included."""
    path, version, folder = lqi_fmu
    assert validate_fmu(str(path)) == []
    m, op = plant
    rng = np.random.default_rng(2)
    s = Slave((path, version, folder), model_identifier="lqi")
    lqi.reset({TASK["input"]: U0})
    got, want = [], []
    for k in range(200):
        x = op.x * (1 + 1e-5 * rng.standard_normal(m.nx))
        y = op["myofibril.length"] + 2e-4 * np.sin(0.1 * k)
        r = op["myofibril.length"] + (-0.05 if k < 60 else 0.0 if k < 140 else 0.05)
        states = dict(zip(m.state_names, x, strict=True))
        want.append(lqi.update(k * DT, {**states, lqi.output: y}, {lqi.output: r})[lqi.input])
        s.set(reference=r, measurement=y, **states)
        s.step(k * DT, DT)
        got.append(s.get("command"))
    s.close()
    want = np.array(want)
    assert np.any(want == 0.0) and np.any(want == 1e5)
    assert np.sum((want > 0) & (want < 1e5)) > 20, np.sum((want > 0) & (want < 1e5))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * 1e5)


def test_a_serialized_state_keeps_the_sample_grid(fmu, plant):
    """An instance started at 5 ms (half a period) samples at 5 ms + k T; its state,
    serialised and restored into an instance started at 0, still does."""
    _, version, _ = fmu
    ys, r = _measurements(plant[1], 8)
    names = ("getFMUstate", "serializeFMUstate", "deSerializeFMUstate", "setFMUstate")
    if version == 3:
        names = ("getFMUState", "serializeFMUState", "deserializeFMUState", "setFMUState")

    def steps(s: Slave, ks) -> list[float]:
        out = []
        for k in ks:
            s.set(reference=r, measurement=ys[k])
            s.step(0.005 + k * DT / 2, DT / 2)
            out.append(s.get("command"))
        return out

    s = Slave(fmu, t0=0.005)
    get, serialize, _, _ = (getattr(s.s, n) for n in names)
    steps(s, range(3))
    raw = serialize(get())
    tail = steps(s, range(3, 8))
    s.close()
    assert len(set(tail)) > 1  # samples at 0.025 and 0.035 s changed the command
    s = Slave(fmu, t0=0.0)
    _, _, deserialize, restore = (getattr(s.s, n) for n in names)
    restore(deserialize(raw))
    assert steps(s, range(3, 8)) == tail
    s.close()


def test_rate_limited_controller_fmus_equal_the_python_controllers(plant, tmp_path):
    """rate_max 0.2 MPa/s (2 kPa per sample): the FMUs feed their held command back to the
    law (``du_max`` a parameter) and give the Python PID's and LQI's commands, the rate
    limit held on many samples."""
    m, op = plant
    ys, r = _measurements(op, 200)
    task = {**TASK, "rate_max": 2e5}
    pid = make_pid(m, op, DT, {**task, "kd": -50.0})
    path = export_controller_fmu(pid, m, tmp_path / "pid.fmu", U0, 2)
    s = Slave((path, 2, extract(str(path), unzipdir=str(tmp_path / "pid"))))
    assert s.get("du_max") == pytest.approx(2e3)
    got = _fmu_commands(s, ys, r)
    want = _python(pid, ys, r)
    moves = np.abs(np.diff(np.concatenate([[U0], want])))
    assert np.sum(np.isclose(moves, 2e3, rtol=1e-12)) > 10 and moves.max() <= 2e3 * (1 + 1e-12)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * 1e5)
    lqi = make_lqi(m, op, DT, {**task, "feedforward": "linear"})
    path = export_controller_fmu(lqi, m, tmp_path / "lqi.fmu", U0, 2)
    s = Slave((path, 2, extract(str(path), unzipdir=str(tmp_path / "lqi"))), model_identifier="lqi")
    lqi.reset({TASK["input"]: U0})
    states = {n: float(v) for n, v in zip(m.state_names, op.x, strict=True)}
    got, want = [], []
    for k in range(60):
        ref = op["myofibril.length"] + (-0.05 if k < 30 else 0.0)
        y = op["myofibril.length"]
        want.append(lqi.update(k * DT, {**states, lqi.output: y}, {lqi.output: ref})[lqi.input])
        s.set(reference=ref, measurement=y, **states)
        s.step(k * DT, DT)
        got.append(s.get("command"))
    s.close()
    moves = np.abs(np.diff(np.concatenate([[U0], want])))
    assert np.sum(np.isclose(moves, 2e3, rtol=1e-12)) > 10 and moves.max() <= 2e3 * (1 + 1e-12)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * 1e5)
