"""What every controller refuses, through the one registry and the one base class: a
non-finite measurement or reference (``checked``), an input range that does not hold the
operating point, and a size-like setting outside its range (horizon, degree, iteration
and substep counts, samples of a run)."""

import math

import pytest

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.loop import MAX_SAMPLES, run_closed_loop
from sarcomere.controllers.receding import MAX_HORIZON
from sarcomere.dynamics import hanging_load
from sarcomere.dynamics.errors import ParameterError

DT = 0.01
L, P, POUT = "myofibril.length", "regulator.p_cmd", "regulator.p_out"
TASK = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5}
KINDS = {  # label: (slug, own settings)
    "pid": ("pid", {}),
    "lqi": ("lqi", {}),
    "lqi_ekf": ("lqi", {"estimator": "ekf"}),
    "lmpc": ("lmpc", {}),
    "lmpc_ekf": ("lmpc", {"estimator": "ekf"}),
    "nmpc": ("nmpc", {}),
}


@pytest.fixture(scope="module")
def plant():
    m = hanging_load(1, load_kg=0.02)
    return m, operating_point(m, {P: 5e4})


@pytest.fixture(scope="module")
def controllers(plant):
    m, op = plant
    return {
        k: make_controller(slug, m, op, DT, {**TASK, **own}) for k, (slug, own) in KINDS.items()
    }


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("bad", [math.nan, math.inf, None])
def test_checked_refuses_a_non_finite_or_missing_measurement(plant, controllers, kind, bad):
    """Before, a NaN length gave the PID a command of 0.0 without error (issue 16, bug 9)."""
    m, op = plant
    c = controllers[kind]
    c.reset({P: float(op.u[0])})
    y = {n: op[n] for n in c.outputs}
    assert L in y
    if bad is None:
        del y[L]
    else:
        y[L] = bad
    with pytest.raises(ParameterError, match=rf"'{c.slug}\.y\.myofibril\.length' = {bad}"):
        c.checked(0.0, y, {L: op[L]})
    assert c.stats.solve_times_s == []  # refused before the update ran


@pytest.mark.parametrize("kind", list(KINDS))
def test_checked_refuses_a_non_finite_reference(plant, controllers, kind):
    m, op = plant
    c = controllers[kind]
    c.reset({P: float(op.u[0])})
    y = {n: op[n] for n in c.outputs}
    with pytest.raises(ParameterError, match=rf"'{c.slug}\.r\.myofibril\.length' = nan"):
        c.checked(0.0, y, {L: math.nan})
    # and the finite case passes: at the operating point the command is its input
    assert c.checked(0.0, y, {L: op[L]})[P] == pytest.approx(5e4, abs=5.0)


@pytest.mark.parametrize("slug", ["pid", "lqi", "lmpc", "nmpc"])
@pytest.mark.parametrize(
    ("bounds", "key", "allowed"),
    [
        ({"u_max": 1.0}, "u_max", r"\[50000, 600000\] Pa"),  # below the operating 50 kPa
        ({"u_min": 6e4, "u_max": 1e5}, "u_min", r"\[0, 50000\] Pa"),
        ({"u_min": 5e4, "u_max": 5e4}, "u_max", r"\[50000, 600000\] Pa and > u_min = 50000"),
        ({"u_min": 1e5, "u_max": 0.0}, "u_min", r"\[0, 50000\] Pa"),  # reversed
        ({"u_min": -1e4}, "u_min", r"\[0, 50000\] Pa"),  # below the input's own range
        ({"u_max": 7e5}, "u_max", r"\[50000, 600000\] Pa"),  # above p_max
        ({"u_max": math.nan}, "u_max", "a finite number"),
        ({"u_min": "0 Pa"}, "u_min", "a finite number"),
    ],
)
def test_an_input_range_that_cannot_hold_the_operating_point_is_refused(
    plant, slug, bounds, key, allowed
):
    """``u_max = 1 Pa`` for an LQI at 50 kPa was accepted silently (issue 16)."""
    m, op = plant
    with pytest.raises(ParameterError, match=rf"'{slug}\.{key}'.*allowed: {allowed}"):
        make_controller(slug, m, op, DT, {**TASK, **bounds})


@pytest.mark.parametrize(
    ("slug", "key", "value", "allowed"),
    [
        ("lmpc", "horizon", 10**6, rf"\[1, {MAX_HORIZON}\]"),  # was std::bad_alloc
        ("lmpc", "horizon", MAX_HORIZON + 1, rf"\[1, {MAX_HORIZON}\]"),
        ("lmpc", "horizon", 0, rf"\[1, {MAX_HORIZON}\]"),
        ("lmpc", "horizon", 10.0, rf"\[1, {MAX_HORIZON}\]"),
        ("nmpc", "horizon", 10**6, rf"\[1, {MAX_HORIZON}\]"),
        ("nmpc", "degree", 6, r"\[1, 5\]"),
    ],
)
def test_size_settings_out_of_range_name_the_setting_value_and_range(
    plant, slug, key, value, allowed
):
    m, op = plant
    with pytest.raises(ParameterError, match=rf"'{slug}\.{key}' = {value!r}.*integer in {allowed}"):
        make_controller(slug, m, op, DT, {**TASK, key: value})


@pytest.mark.parametrize("substeps", [0, 51, 10**6, True])
def test_ekf_substeps_out_of_range_are_refused(plant, substeps):
    m, op = plant
    task = {**TASK, "estimator": "ekf", "ekf": {"substeps": substeps}}
    with pytest.raises(ParameterError, match=r"'ekf\.substeps'.*integer in \[1, 50\]"):
        make_controller("lqi", m, op, DT, task)


def test_the_longest_horizon_is_accepted(plant):
    """The upper end of the range is usable: the LMPC builds and holds the operating point."""
    m, op = plant
    c = make_controller("lmpc", m, op, DT, {**TASK, "horizon": MAX_HORIZON})
    y = {n: op[n] for n in c.outputs}
    assert c.checked(0.0, y, {L: op[L]})[P] == pytest.approx(5e4, abs=1e-3)


def test_a_run_of_more_than_max_samples_is_refused(plant, controllers):
    m, op = plant
    with pytest.raises(ParameterError, match=r"'stop_time' = 1000000000000\.0.*\[0\.01, 10000\] s"):
        run_closed_loop(m, controllers["pid"], op, lambda t: op[L], 1e12, output=L)
    assert MAX_SAMPLES * DT == pytest.approx(1e4)


@pytest.mark.parametrize("p_op", [0.0, 1e5])
def test_an_operating_point_at_a_bound_is_accepted(plant, p_op):
    """Starting vented (at u_min) or at u_max is a usable loop: only the other way moves."""
    m, _ = plant
    op = operating_point(m, {P: p_op})
    c = make_controller("pid", m, op, DT, TASK)
    c.reset({P: p_op})
    assert c.checked(0.0, {L: op[L]}, {L: op[L]})[P] == pytest.approx(p_op, abs=1e-6)


@pytest.mark.parametrize("slug", ["lqi", "lmpc", "nmpc"])
def test_an_empty_measured_list_for_an_ekf_is_refused_not_replaced(plant, slug):
    """Issue 24 (poor): ``measured = []`` with an EKF silently took the default signals."""
    m, op = plant
    task = {**TASK, "estimator": "ekf", "measured": []}
    with pytest.raises(ParameterError, match=rf"'{slug}\.measured' = \[\].*at least one signal"):
        make_controller(slug, m, op, DT, task)
