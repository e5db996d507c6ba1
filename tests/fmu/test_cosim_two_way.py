"""A two-way co-simulation (benchmarks/studies/cosim_coupling.py): the muscle and a
spring-coupled load as two native participants against the same system as one model;
first-order convergence of the held coupling, and the instability of a stiff spring at a
large step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.studies import cosim_coupling as study
from sarcomere.dynamics.errors import ParameterError
from sarcomere.fmu import export_fmu, open_fmu
from sarcomere.fmu.cosim import CosimError

pytestmark = pytest.mark.slow  # exports, builds and runs FMUs: the full suite (CI)

COMMAND = (2e4, 8e4, 0.02)
"""0.02 -> 0.08 MPa at 20 ms [Pa, Pa, s]."""


def _error(c: float, h: float, ordering: str, stop: float, ref, signal: str) -> np.ndarray:
    r = study.cosimulate_split(c, h, ordering, "hold", COMMAND, stop)
    every = round(h / (ref.index[1] - ref.index[0]))
    return np.abs(r[f"load.{signal}"] - ref[signal][::every])


def test_gauss_seidel_hold_converges_at_first_order():
    """A held input lags (or leads) its source by up to a step, an O(h) input error:
    the global error is O(h). The study measures slopes 1.00 +- 0.02 from 4 ms down to
    0.25 ms (docs/cosim.md), so 2 -> 1 ms is in the asymptotic range; an input fed a step
    late or early (a wrong ordering) still gives order 1 but twice the error, and a
    coupling that ignored the loop's second direction would not converge at all."""
    stop = 0.08
    ref = study.monolithic_run(200.0, COMMAND, stop, np.linspace(0, stop, 81))
    scale = np.ptp(ref["mass.s"])
    assert scale > 2e-4  # the load rises by 0.29 mm by 80 ms
    e2, e1 = (
        np.max(_error(200.0, h, "gauss-seidel", stop, ref, "mass.s")) / scale for h in (2e-3, 1e-3)
    )
    order = math.log2(e2 / e1)
    assert 0.9 < order < 1.1, (e2, e1, order)
    assert e1 < 0.05  # 3.2e-2 of the rise at 1 ms


def test_a_stiff_spring_at_a_large_step_is_unstable():
    """At 1e4 N/m (relative mode 133 Hz) Gauss-Seidel with hold is stable at 0.25 ms and
    unstable at 1 ms: the linear step map's spectral radius crosses 1 between them, and
    the nonlinear run's error grows; at 3e4 N/m and 1 ms the muscle is torn out of its
    physical domain and the run stops with the participant, time and cause named."""
    c, stop = 1e4, 0.2
    ref = study.monolithic_run(c, COMMAND, stop, np.linspace(0, stop, 801))
    assert study.amplification(c, 2.5e-4, "gauss-seidel", "hold", COMMAND[1]) < 1
    assert study.amplification(c, 1e-3, "gauss-seidel", "hold", COMMAND[1]) > 1
    stable = _error(c, 2.5e-4, "gauss-seidel", stop, ref, "sensor.f")
    unstable = _error(c, 1e-3, "gauss-seidel", stop, ref, "sensor.f")
    assert not study.diverges(stable) and np.max(stable) < 0.1 * study.start_force()
    assert study.diverges(unstable) and np.max(unstable) > 10 * np.max(stable)

    with pytest.raises(CosimError) as info:
        study.cosimulate_split(3e4, 1e-3, "gauss-seidel", "hold", COMMAND, stop)
    err = info.value
    assert err.participant == "model 'muscle'" and "physical domain" in str(err)
    assert COMMAND[2] < err.time < stop and err.result.index[-1] == pytest.approx(err.time)


def test_the_held_coupling_acts_as_a_delay_against_the_physical_damping():
    """A force held with an effective delay tau is a negative damping c tau on the masses'
    relative mode: Jacobi with hold (tau = h) is stable up to h* = d / c, with d the
    mode's physical damping; Gauss-Seidel, whose second participant sees the new
    position, goes about four times further (the study: 1.00-1.03 and 3.8-3.9 for
    c >= 1e4 N/m, where the spring's mode is clear of the muscle's)."""
    c = 3e4
    d = study.relative_mode_damping(c, COMMAND[1])
    bracket = (1e-6, 1e-2)
    jacobi = study.critical_step(c, "jacobi", "hold", COMMAND[1], bracket)
    gauss = study.critical_step(c, "gauss-seidel", "hold", COMMAND[1], bracket)
    assert jacobi * c / d == pytest.approx(1.0, abs=0.1)
    assert gauss / jacobi == pytest.approx(3.8, abs=0.4)


@pytest.fixture(scope="module")
def load_fmu(tmp_path_factory):
    """The load participant's model as an FMI 2.0 FMU (its spring's ``c`` a parameter)."""
    path = tmp_path_factory.mktemp("fmu") / "load.fmu"
    return export_fmu(study.load_participant_model(200.0), path)


def test_the_load_as_its_fmu_couples_as_the_native_load(load_fmu):
    """The same loop with the load as its exported FMU (Radau IIA inside): the coupling
    error is the native load's to 1 %, and a stiff spring at a large step still tears the
    muscle out of its domain (the spring's stiffness set as the FMU's parameter)."""
    stop = 0.08
    ref = study.monolithic_run(200.0, COMMAND, stop, np.linspace(0, stop, 81))
    scale = np.ptp(ref["mass.s"])
    native = np.max(_error(200.0, 1e-3, "gauss-seidel", stop, ref, "mass.s")) / scale
    with open_fmu(load_fmu) as fmu:
        r = study.cosimulate_split(200.0, 1e-3, "gauss-seidel", "hold", COMMAND, stop, load_fmu=fmu)
    fmu_error = np.max(np.abs(r["load.mass.s"] - ref["mass.s"])) / scale
    assert fmu_error == pytest.approx(native, rel=0.01)
    with open_fmu(load_fmu) as fmu:
        with pytest.raises(CosimError, match="model 'muscle' returned error"):
            study.cosimulate_split(3e4, 1e-3, "gauss-seidel", "hold", COMMAND, 0.2, load_fmu=fmu)


@pytest.mark.parametrize(
    "args, name",
    [
        ((200.0, 0.0, "jacobi", "hold"), "'h'"),
        ((200.0, 1e-3, "parallel", "hold"), "'ordering'"),
        ((200.0, 1e-3, "jacobi", "cubic"), "'inputs'"),
        ((-1.0, 1e-3, "jacobi", "hold"), "'c'"),
    ],
)
def test_the_analysis_refuses_bad_arguments(args, name):
    with pytest.raises(ParameterError, match=name):
        study.amplification(*args, COMMAND[1])
