"""PID against closed forms on a first-order test plant, and as a python-control system."""

import control as ct
import numpy as np
import pytest

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.linearize import linearize
from sarcomere.controllers.pid import PID, PIDGains, imc_gains
from sarcomere.dynamics import hanging_load
from sarcomere.dynamics.errors import ParameterError

DT = 0.01


def _run(pid: PID, r: float, steps: int, a=0.9, b=0.1, y0=0.0):
    """``y+ = a y + b u`` under the controller; returns y and u per sample."""
    pid.reset({"u": 0.0})
    y, ys, us = y0, [], []
    for k in range(steps):
        u = pid.checked(k * DT, {"y": y}, {"y": r})["u"]
        ys.append(y)
        us.append(u)
        y = a * y + b * u
    return np.array(ys), np.array(us)


def test_proportional_steady_state_error_is_the_closed_form():
    kp = 3.0
    pid = PID(DT, "y", "u", -100, 100, PIDGains(kp))
    y, _ = _run(pid, 1.0, 400)
    K = 0.1 / (1 - 0.9)  # plant DC gain
    assert y[-1] == pytest.approx(K * kp / (1 + K * kp), rel=1e-9)


def test_integral_removes_the_error():
    pid = PID(DT, "y", "u", -100, 100, PIDGains(1.0, ki=20.0))
    y, _ = _run(pid, 1.0, 2000)
    assert y[-1] == pytest.approx(1.0, abs=1e-9)


def test_derivative_filter_is_backward_euler_of_kd_s_over_tf_s_plus_1():
    kd, tf = 2.0, 0.05
    pid = PID(DT, "y", "u", -1e3, 1e3, PIDGains(0.0, kd=kd, tf=tf))
    pid.reset({"u": 0.0})
    us = [pid.checked(k * DT, {"y": 0.0 if k == 0 else 1.0}, {"y": 0.0})["u"] for k in range(6)]
    a = tf / (tf + DT)
    expected = [0.0] + [-kd / (tf + DT) * a ** (k - 1) for k in range(1, 6)]
    np.testing.assert_allclose(us, expected, rtol=1e-12)


def test_back_calculation_limits_windup():
    """An unreachable reference for 5 s, then a reachable one: with back-calculation the
    output is there a second later; with the integral left to wind up it is still held
    at the bound."""

    def error_1s_later(tt):
        pid = PID(DT, "y", "u", 0.0, 1.0, PIDGains(0.5, ki=5.0, tt=tt))
        pid.reset({"u": 0.0})
        y, ys = 0.0, []
        for k in range(1500):
            r = 2.0 if k < 500 else 0.5  # 2 needs u = 2, above the bound 1
            u = pid.checked(k * DT, {"y": y}, {"y": r})["u"]
            assert 0.0 <= u <= 1.0
            y = 0.9 * y + 0.1 * u
            ys.append(y)
        return abs(ys[600] - 0.5)

    assert error_1s_later(0.05) < 0.01
    assert error_1s_later(1e9) > 0.3


def test_imc_gains_of_a_first_order_plant():
    K, tau, lam = 2.0, 0.3, 0.1
    kp, ki = imc_gains(ct.ss(ct.tf([K], [tau, 1])), lam)
    assert ki == pytest.approx(1 / (K * lam))
    assert kp == pytest.approx(tau / (K * lam))


@pytest.mark.parametrize(
    ("key", "value"), [("tf", -1.0), ("tt", 0.0), ("kq", 1.0), ("closed_loop_s", 0.0)]
)
def test_bad_settings_name_the_setting(key, value):
    m = hanging_load(1, load_kg=0.02)
    op = operating_point(m, {"regulator.p_cmd": 5e4})
    task = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0, "u_max": 1e5}
    with pytest.raises(ParameterError, match=rf"'pid\.{key}'"):
        make_controller("pid", m, op, DT, {**task, key: value})


def test_as_iosystem_closes_the_loop_with_the_linear_plant():
    """interconnect(PID system, discretised linearisation): the same samples as the
    Python loop of ``update`` on that plant, and zero steady-state error."""
    m = hanging_load(1, load_kg=0.02)
    op = operating_point(m, {"regulator.p_cmd": 5e4})
    task = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0, "u_max": 1e5}
    pid = make_controller("pid", m, op, DT, task)
    plant = linearize(m, op, ["myofibril.length"], dt=DT)
    loop = ct.interconnect(
        [plant, pid.as_iosystem(op, m)],
        inplist=["reference"],
        outlist=["myofibril__length", "regulator__p_cmd"],
    )
    n = 150
    t = np.arange(n) * DT
    dr = -1e-3
    resp = ct.input_output_response(loop, t, np.full(n, dr))
    y_io, u_io = resp.outputs
    # the same loop by hand: update() on absolute values, plant in deviations
    pid.reset({"regulator.p_cmd": float(op.u[0])})
    x, y0 = np.zeros(m.nx), op["myofibril.length"]
    for k in range(n):
        dy = float((plant.C @ x)[0])
        u = pid.update(t[k], {"myofibril.length": y0 + dy}, {"myofibril.length": y0 + dr})
        du = u["regulator.p_cmd"] - op.u[0]
        assert dy == pytest.approx(y_io[k], abs=1e-12)
        assert du == pytest.approx(u_io[k], rel=1e-9, abs=1e-6)
        x = plant.A @ x + plant.B[:, 0] * du
    assert y_io[-1] == pytest.approx(dr, rel=1e-3)


@pytest.mark.parametrize("dt", [1e-4, 0.2])
def test_sample_time_outside_what_the_plant_allows_is_refused(dt):
    """Below 1 ms, or slower than the regulator's 50 ms lag (the slowest time constant)."""
    m = hanging_load(1, load_kg=0.02)
    op = operating_point(m, {"regulator.p_cmd": 5e4})
    task = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0, "u_max": 1e5}
    with pytest.raises(ParameterError, match=r"'pid\.dt'.*0\.05\] s"):
        make_controller("pid", m, op, dt, task)
    make_controller("pid", m, op, 0.04, task)  # just inside


def test_rate_limit_clamps_the_change_per_sample():
    """rate_max 10 /s at 10 ms: the command moves at most 0.1 per sample, and a step that
    asks for a jump ramps at exactly that rate until the law catches up."""
    pid = PID(DT, "y", "u", -100, 100, PIDGains(5.0, ki=20.0), rate_max=10.0)
    y, u = _run(pid, 1.0, 1500)
    steps = np.diff(np.concatenate([[0.0], u]))
    assert np.max(np.abs(steps)) <= 0.1 + 1e-12
    np.testing.assert_allclose(steps[:5], 0.1, rtol=1e-12)  # 5 * 1 asked: held at +0.1
    assert y[-1] == pytest.approx(1.0, abs=1e-6)  # the integral still removes the error


def test_back_calculation_holds_the_integral_at_the_rate_limit():
    """The measurement held at 0 and r = 1: the command ramps at the rate limit while the
    law asks for more. The back-calculation sees the rate-held command, so the integral
    tracks what the command did (``u - kp e`` with ``tt = kp / ki``), far below the
    ``ki dt e`` per sample an integral blind to the rate limit would gather; back at
    r = y the command falls from where the ramp stopped, not from a wound-up value.

    With ``tt = kp / ki`` and ``a = dt / tt`` the law gives ``I+ = (1 - a) I + a u``: a
    first-order filter of the command, which on a ramp of ``rate dt`` per sample settles
    ``(1 - a) rate dt / a`` behind it."""
    kp, ki, rate = 2.0, 40.0, 10.0
    pid = PID(DT, "y", "u", -100, 100, PIDGains(kp, ki=ki, tt=kp / ki), rate_max=rate)
    pid.reset({"u": 0.0})
    n = 50
    for k in range(n):
        u = pid.checked(k * DT, {"y": 0.0}, {"y": 1.0})["u"]
        assert u == pytest.approx(rate * DT * (k + 1), rel=1e-12)  # held by the rate
    integral = pid._state[0]
    blind = ki * DT * 1.0 * n  # 20: the windup without the rate in the anti-windup
    a = DT * ki / kp
    assert integral == pytest.approx(u - (1 - a) * rate * DT / a, abs=1e-3)
    assert integral < 0.25 * blind
    u_next = pid.checked(n * DT, {"y": 0.0}, {"y": 0.0})["u"]  # error gone
    assert u_next < u  # the command comes down at once, nothing to unwind first


def test_rate_limit_is_refused_unless_positive_and_in_the_io_system():
    with pytest.raises(ParameterError, match=r"'pid\.rate_max'"):
        PID(DT, "y", "u", -1, 1, PIDGains(1.0), rate_max=0.0)
    m = hanging_load(1, load_kg=0.02)
    op = operating_point(m, {"regulator.p_cmd": 5e4})
    task = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0, "u_max": 1e5}
    pid = make_controller("pid", m, op, DT, {**task, "rate_max": 2e6})
    assert pid.du_max == pytest.approx(2e4)
    with pytest.raises(ParameterError, match=r"'pid\.rate_max'.*no rate limit"):
        pid.as_iosystem(op, m)
