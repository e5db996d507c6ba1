"""Tests of sarcomere.dynamics.studies.stability: predicted limits, classification, oscillations."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sarcomere.dynamics.results import Result
from sarcomere.dynamics.studies import stability as st
from sarcomere.dynamics.studies import workprecision as wp


@pytest.fixture(scope="module")
def short_step():
    """The step scenario for one APS, 0.3 s."""
    return dataclasses.replace(wp.scenarios(1)["step"], t_final=0.3, n_out=31)


@pytest.fixture(scope="module")
def prediction(short_step):
    return st.predicted(st.trajectory_spectrum(short_step, 31))


def test_prediction_follows_the_fastest_eigenvalue(short_step, prediction):
    sp = st.trajectory_spectrum(short_step, 31)
    lam = max(sp["max_abs_eig_1_s"])
    assert 1e3 < lam < 1e4  # pressure modes near -2.7e3 1/s
    rk4 = prediction["rk4"]["trajectory_s"]
    assert rk4 == pytest.approx(min(sp["h_max_rk4_s"]))
    assert rk4 <= prediction["rk4"]["initial_s"]
    assert prediction["euler"]["trajectory_s"] < rk4


def test_runs_below_the_limit_are_fine_and_far_above_blow_up(short_step, prediction):
    h = prediction["rk4"]["trajectory_s"]
    below = st.classify(short_step, "rk4", 0.8 * h)
    assert below["class"] == "fine", below
    assert not below["guard_warned"]
    above = st.classify(short_step, "rk4", 2.0 * h)
    assert above["class"] == "blown_up", above
    assert above["guard_warned"]


@pytest.mark.slow  # compiles rodas for the one-unit chain (1.1 s)
def test_rodas_held_far_above_the_rk4_limit_is_fine_until_accuracy_fails(short_step, prediction):
    """Rodas5P is L-stable: held at 2x and 10x RK4's predicted limit (RK4 blows up at 2x)
    it stays fine with no step rejected; at 50 ms its error (24 %) fails the accuracy
    criterion, and it never blows up. (Between them the classification is not monotone:
    at 3x a period-2 pressure content of 1.05e-4 > 1e-4 is flagged, the stiff modes'
    errors alternating in sign under R(z) < 0, |R| <= 0.12, for z < -6.5.)"""
    h = prediction["rk4"]["trajectory_s"]
    out = st.rosenbrock_steps(short_step, (2 * h, 10 * h, 0.05))
    for r in out["runs"]:
        assert r["n_rejected"] == 0 and r["n_steps"] >= round(short_step.t_final / r["step_s"])
    assert [r["class"] for r in out["runs"]] == ["fine", "fine", "silently_wrong"], out
    assert 0.01 < out["runs"][2]["error_l2"] < 1.0
    assert out["observed"] == {"largest_fine_s": 10 * h, "first_failure_s": 0.05}
    assert out["predicted"]["trajectory_s"] is None


def test_observed_limit_from_classified_runs():
    runs = [
        {"step_s": 1.0, "class": "fine"},
        {"step_s": 2.0, "class": "silently_wrong"},
        {"step_s": 3.0, "class": "fine"},
        {"step_s": 4.0, "class": "blown_up"},
    ]
    assert st.observed(runs) == {"largest_fine_s": 1.0, "first_failure_s": 2.0}


def test_spurious_period_two_oscillation_is_detected(short_step):
    t = np.linspace(0.0, short_step.t_final, 301)
    p = 1e5 * (1 - np.exp(-t / 0.05))
    names = st._pressure_names(short_step)
    ref = Result("time", "s", t, {n: p for n in names}, {})
    wobble = 50.0 * (-1.0) ** np.arange(len(t))  # 50 Pa, sign flipping every step
    bad = Result("time", "s", t, {n: p + wobble for n in names}, {})
    late, early = st.oscillation(short_step, bad, ref)
    assert late == pytest.approx(100.0 / 1e5, rel=1e-2) and late > st.OSC_TOL
    smooth = Result("time", "s", t, {n: p * (1 + 1e-3) for n in names}, {})
    assert st.oscillation(short_step, smooth, ref)[0] < st.OSC_TOL


def test_r_lam_override_reaches_every_tube(short_step):
    sc = st.with_r_lam(short_step, 0.995)
    assert dict(sc.params) == {"myofibril.tube1.r_lam": 0.995}
