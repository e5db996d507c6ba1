"""The NMPC and LMPC controller FMUs (fmu/controller.py, nmpc_system, lmpc_system): valid
FMI 2.0 and 3.0, and sample for sample the Python controller (the same law Function,
generated to C) in a closed loop on a plant; a prediction parameter tunable like
``set_parameters``; the refusals."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract
from fmpy.validation import validate_fmu

from sarcomere.controllers import make_controller
from sarcomere.controllers.linearize import operating_point
from sarcomere.controllers.lmpc import LinearMPC, LMPCSettings
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.dynamics import hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.simulation.simulator import Simulator
from sarcomere.fmu.controller import export_controller_fmu
from sarcomere.scenarios.studies.mpc_nlp import ConvergedNMPC

from .test_controller import Slave, declared_sources, rebuild_errors

pytestmark = pytest.mark.slow  # exports and runs FMUs: the full suite (CI)

DT = 0.01
"""Sample period [s]."""
U0 = 3e4
"""Operating pressure and bias [Pa]."""
SETTINGS = NMPCSettings(horizon=10, integral_gain=5.0, linear_solver="qr")
"""A short horizon keeps the generated C small; the integral action is on."""


@pytest.fixture(scope="module")
def plant():
    """The plant (exact flow law, 20 g) and the NMPC's prediction (smooth, no clamp)."""
    plant = hanging_load(1, load_kg=0.02)
    pred = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    return plant, pred, solve_equilibrium(plant, {"regulator.p_cmd": U0})


@pytest.fixture(scope="module")
def nmpc(plant):
    _, pred, op = plant
    return NonlinearMPC(pred, op.u, DT, SETTINGS)


@pytest.fixture(scope="module", params=[2, 3])
def fmu(request, plant, nmpc, tmp_path_factory):
    folder = tmp_path_factory.mktemp("nmpc")
    path = export_controller_fmu(nmpc, plant[0], folder / "nmpc.fmu", U0, request.param)
    return path, request.param, extract(str(path), unzipdir=str(folder / "unzipped"))


def _closed_loop(plant, nmpc, n: int = 80, extra=()) -> tuple[list[dict], list[float], list[float]]:
    """The Python controller on the plant: the signals it read (and ``extra``), the
    references and its commands (a 1 mm shortening at 0.1 s, 1.5 mm lengthening at 0.45 s)."""
    m, _, op = plant
    sim = Simulator(m)
    sim.reset(op.x, op.z, None, 0.0)
    y0, out = op["myofibril.length"], nmpc.settings.output
    nmpc.reset({"regulator.p_cmd": U0})
    read, refs, cmds = [], [], []
    for k in range(n):
        t = k * DT
        r = y0 - (1e-3 if t >= 0.1 else 0.0) + (1.5e-3 if t >= 0.45 else 0.0)
        y = sim.signals([*nmpc.outputs, *extra])
        u = nmpc.update(t, y, {out: r})
        read.append(y), refs.append(r), cmds.append(u["regulator.p_cmd"])
        sim.step(u, DT)
    return read, refs, cmds


def _fmu_commands(fmu, nmpc, read, refs, params=None, ident="nmpc", extra=()) -> list[float]:
    s = Slave(fmu, model_identifier=ident)
    if params:
        s.set(**params)
    out, got = nmpc.settings.output, []
    for k, (y, r) in enumerate(zip(read, refs, strict=True)):
        states = {n: y[n] for n in (*nmpc.model.state_names, *extra)}
        s.set(reference=r, measurement=y[out], **states)
        s.step(k * DT, DT)
        got.append(s.get("command"))
    s.close()
    return got


def test_the_nmpc_fmu_validates_and_equals_the_python_nmpc(fmu, plant, nmpc):
    """80 samples of a closed loop (steps both ways, the rate limit and the integral shift
    active): the FMU fed the signals the Python NMPC read gives its commands to 1e-9."""
    path, _, _ = fmu
    assert validate_fmu(str(path)) == []
    read, refs, want = _closed_loop(plant, nmpc)
    assert nmpc.stats.fallbacks == 0
    moves = np.abs(np.diff(want))
    assert np.sum(np.isclose(moves, SETTINGS.rate_max * DT, rtol=1e-6)) >= 3  # rate-limited
    assert nmpc._offset != 0.0  # the integral shift took part
    got = _fmu_commands(fmu, nmpc, read, refs)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * SETTINGS.u_max)


def test_a_prediction_parameter_is_tunable_like_set_parameters(fmu, plant, nmpc):
    """The FMU's ``load.m`` (a run-time parameter of the prediction) set to 40 g gives the
    commands of the Python NMPC after ``set_parameters({"load.m": 0.04})``."""
    read, refs, _ = _closed_loop(plant, nmpc, 30)
    nmpc.reset({"regulator.p_cmd": U0})
    nmpc.set_parameters({"load.m": 0.04})
    out, want = nmpc.settings.output, []
    for k, (y, r) in enumerate(zip(read, refs, strict=True)):
        want.append(nmpc.update(k * DT, y, {out: r})["regulator.p_cmd"])
    nmpc.reset({"regulator.p_cmd": U0})  # the nominal load again (the next export's start)
    got = _fmu_commands(fmu, nmpc, read, refs, {"load.m": 0.04})
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * SETTINGS.u_max)
    nominal = _fmu_commands(fmu, nmpc, read, refs)
    assert np.max(np.abs(np.subtract(got, nominal))) > 100.0  # the load mattered [Pa]


def test_the_lmpc_fmu_equals_the_python_lmpc_at_its_linearisation(plant, tmp_path):
    """An LMPC without a disturbance filter, a soft tension bound (the tension an input by
    name): valid, and the Python LMPC's commands to 1e-9 over the closed loop, during
    which it does not re-linearise (the FMU keeps its linearisation)."""
    m, _, op = plant
    tension = "myofibril.actin0.T"
    # the move weight this test was written at (at the tuned 3e-7 the command moves 10 kPa)
    s = LMPCSettings(horizon=10, disturbance="none", soft_min=((tension, 0.05),), weight_du=1e-7)
    lmpc = LinearMPC(m, op.x, op.u, DT, s)
    path = export_controller_fmu(lmpc, m, tmp_path / "lmpc.fmu", U0, 3)
    assert validate_fmu(str(path)) == []
    read, refs, want = _closed_loop(plant, lmpc, extra=[tension])
    assert lmpc.relinearizations == 1 and lmpc.stats.fallbacks == 0  # the one at reset
    assert np.ptp(want) > 2e4  # it moved [Pa]
    fmu = (path, 3, extract(str(path), unzipdir=str(tmp_path / "x")))
    _declares_no_rebuild(Path(fmu[2]))
    got = _fmu_commands(fmu, lmpc, read, refs, ident="lmpc", extra=[tension])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * s.u_max)


def _declares_no_rebuild(folder: Path) -> None:
    """A law calling DAQP (whose sources the archive lacks: `daqp/api.h`) declares no
    sources for a rebuild (they failed to compile from the archive), but ships its own."""
    assert declared_sources(folder) == []
    assert (folder / "sources" / "sm_casadi.c").is_file()
    everything = sorted(p.name for p in (folder / "sources").glob("*.c"))
    assert "daqp/api.h" in rebuild_errors(folder, everything)  # why nothing is declared


def _held(fmu, y: dict, r: float, n: int, names) -> list[float]:
    """An LMPC FMU instance stepped ``n`` samples on held inputs (the signals ``y``, the
    reference ``r``): its commands every 100 samples."""
    s = Slave(fmu, model_identifier="lmpc")
    s.set(reference=r, **{k: y[k] for k in names})
    got = []
    for k in range(n):
        s.step(k * DT, DT)
        if k % 100 == 99:
            got.append(s.get("command"))
    s.close()
    return got


def test_lmpc_fmu_instances_step_in_parallel_threads(plant, tmp_path):
    """Four instances of one LMPC FMU (one loaded binary, whose generated DAQP call keeps
    its solver memory once) stepped at once in four threads give the commands of one
    instance alone (two calls that met failed with "not finite")."""
    m, _, op = plant
    lmpc = LinearMPC(m, op.x, op.u, DT, LMPCSettings(horizon=10, disturbance="none"))
    path = export_controller_fmu(lmpc, m, tmp_path / "lmpc.fmu", U0, 2)
    fmu = (path, 2, extract(str(path), unzipdir=str(tmp_path / "x")))
    _declares_no_rebuild(Path(fmu[2]))
    y = {**dict(zip(m.state_names, op.x, strict=True)), "measurement": op["myofibril.length"]}
    args = (fmu, y, op["myofibril.length"] - 1e-3, 2000, list(y))
    alone = _held(*args)
    with ThreadPoolExecutor(4) as pool:
        runs = [pool.submit(_held, *args) for _ in range(4)]
        assert [run.result() for run in runs] == [alone] * 4
    assert np.ptp(alone) > 0  # it moved


def test_controllers_without_an_exported_law_are_refused(plant, tmp_path):
    m, pred, op = plant
    task = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0.0}
    task["u_max"] = 1e5
    lin = operating_point(m, {"regulator.p_cmd": U0})
    cases = {
        "on an EKF": make_controller("nmpc", m, lin, DT, {**task, "estimator": "ekf"}),
        "disturbance 'load'": make_controller("lmpc", m, lin, DT, task),
        "ipopt": ConvergedNMPC(pred, op.u, DT, NMPCSettings(horizon=10), solver="ipopt"),
    }
    qpoases = NonlinearMPC(pred, op.u, DT, NMPCSettings(horizon=10, qp_solver="qpoases"))
    with pytest.raises(ParameterError, match="nmpc.qp_solver.*C code generation"):
        export_controller_fmu(qpoases, m, tmp_path / "x.fmu", U0)
    backoff = NonlinearMPC(pred, op.u, DT, NMPCSettings(horizon=10, backoff=1.0))
    with pytest.raises(ParameterError, match="nmpc.backoff"):
        export_controller_fmu(backoff, m, tmp_path / "x.fmu", U0)
    lapack = NonlinearMPC(pred, op.u, DT, NMPCSettings(horizon=10, linear_solver="lapacklu"))
    with pytest.raises(ParameterError, match="nmpc.linear_solver.*'qr'"):
        export_controller_fmu(lapack, m, tmp_path / "x.fmu", U0)
    for what, ctl in cases.items():
        with pytest.raises(ParameterError, match="controller") as err:
            export_controller_fmu(ctl, m, tmp_path / "x.fmu", U0)
        assert what in str(err.value), str(err.value)
