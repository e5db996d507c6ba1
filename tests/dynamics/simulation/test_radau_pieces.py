"""``radau`` integrates a whole run in one C call (``radau_runs.c``): every piece (input
breakpoint, chunk of output points) restarted as one call per piece would, the states
checked finite and inside the physical domain in C. The same numbers, failures and
partial results as the per-piece path (taken when a progress callback is given), and
one integrator memory per thread."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from sarcomere.dynamics import Simulator
from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.signals import Ramp, Sine, Staircase, Step
from sarcomere.dynamics.simulation import simulator
from sarcomere.dynamics.simulation.settings import METHODS
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

P_MAX = 2e5


class Oscillator(Component):
    """``x'' = (u / 1e5 - x) w^2 - 2 zeta w x'``, x <= x_high: a lightly damped second-order
    lag driven by ``u`` [Pa] in [0, P_MAX]."""

    def __init__(self, name: str, x_high: float) -> None:
        super().__init__(name)
        self.x_high = x_high

    def build(self, b) -> None:
        w = b.parameter("w", 40.0, "1/s", "natural frequency", low=1e-3)
        zeta = b.parameter("zeta", 0.05, "1", "damping ratio", low=0.0)
        u = b.input("u", "Pa", "command", low=0.0, high=P_MAX)
        x = b.state("x", 0.0, "m", "position", high=self.x_high)
        v = b.state("v", 0.0, "m/s", "velocity")
        b.der(x, v)
        b.der(v, (u / 1e5 - x) * w**2 - 2 * zeta * w * v)


def model(x_high: float = math.inf):
    sys = System("osc")
    sys.add(Oscillator("osc", x_high))
    return sys.flatten()


SETTINGS = SolverSettings("radau", rtol=1e-7, atol=1e-10)


def both(m, *args, **kw):
    """(one call, one call per piece): ``simulate`` without and with a progress callback,
    and the number of one-call runs the first made."""
    calls = []
    method = METHODS["radau"]
    original = method.pieces

    def counting(run):
        calls.append(len(run.ends))
        return original(run)

    object.__setattr__(method, "pieces", counting)
    try:
        one = simulate(m, *args, settings=SETTINGS, **kw)
    finally:
        object.__setattr__(method, "pieces", original)
    per_piece = simulate(m, *args, settings=SETTINGS, progress=lambda f: None, **kw)
    return one, per_piece, calls


@pytest.mark.slow  # 3 compiles (held, ramp, sine): seconds each on a loaded machine
def test_one_call_equals_one_call_per_piece():
    """Random held inputs (staircases, steps: several breakpoints) and smooth ones (a ramp
    and a sine: the signals law) over random grids, with more points than a chunk: the
    states, inputs and counters of the one call equal those of one call per piece, bit
    for bit."""
    m = model()
    for seed in range(3):
        rng = np.random.default_rng(seed)
        t_final = float(rng.uniform(0.5, 2.0))
        levels = tuple(float(v) for v in rng.uniform(0, P_MAX, size=3))
        held = Staircase(levels=levels, dwell=t_final / 4, unit="Pa")
        step = Step(final=float(rng.uniform(0, P_MAX)), time=float(rng.uniform(0, t_final)))
        n_points = int(rng.integers(simulator.CHUNK_POINTS + 1, 2 * simulator.CHUNK_POINTS + 500))
        grid = np.sort(rng.uniform(0, t_final, n_points))
        grid = np.unique(np.concatenate([[0.0], grid, [t_final]]))
        _check_equal(m, t_final, grid, (held, step, SMOOTH[seed % 2]))


SMOOTH = (
    Ramp(final=1.5e5, duration=0.25, start=0.1, unit="Pa"),
    Sine(amplitude=5e4, offset=1e5, frequency=3.0, unit="Pa"),
)


def _check_equal(m, t_final, grid, signals) -> None:
    for signal in signals:
        one, per_piece, calls = both(m, t_final, {"osc.u": signal}, t_out=grid)
        assert calls == [one.meta["n_segments"]] and calls[0] >= 2  # several pieces, one call
        for name in ("osc.x", "osc.v", "osc.u"):
            np.testing.assert_array_equal(one[name], per_piece[name])
        counters = ("n_steps", "n_rhs", "n_jac", "n_lu", "n_segments")
        assert {k: one.meta[k] for k in counters} == {k: per_piece.meta[k] for k in counters}


def test_a_breakpoint_between_output_points_is_integrated_to_and_left_out():
    """A step at 0.123 s on a 10 ms grid: the piece ends at the breakpoint (not an output
    time), which the one call integrates to and leaves out of the result."""
    m = model()
    one, per_piece, _ = both(m, 0.5, {"osc.u": Step(final=1e5, time=0.123)}, output_interval=0.01)
    assert 0.123 not in one["time"]
    np.testing.assert_array_equal(one["osc.x"], per_piece["osc.x"])
    assert one.meta["n_segments"] == 2


def test_a_strided_output_grid_is_read_as_its_own_times():
    """``t_out`` a strided view (``grid[::4]``, or a column of a CSV's 2-D array): the one
    call read its memory as contiguous, integrated to the wrong times (every row of the
    grid, not every 4th) and returned states 2 mm off on the n = 3 chain, silently."""
    m = model()
    grid = np.linspace(0.0, 1.0, 1001)
    assert not grid[::4].flags.c_contiguous
    u = {"osc.u": 1e5}  # held, no breakpoint: one piece, its times not copied
    strided = simulate(m, 1.0, u, t_out=grid[::4], settings=SETTINGS)
    copied = simulate(m, 1.0, u, t_out=grid[::4].copy(), settings=SETTINGS)
    np.testing.assert_array_equal(strided["osc.x"], copied["osc.x"])
    tight = SolverSettings("cvodes", rtol=1e-10, atol=1e-13)
    reference = simulate(m, 1.0, u, t_out=grid[::4].copy(), settings=tight)
    np.testing.assert_allclose(strided["osc.x"], reference["osc.x"], atol=1e-5)


@pytest.mark.slow  # two runs to the failure each way, a compile on a cold cache
def test_the_domain_check_in_c_fails_as_the_python_one():
    """x overshoots its bound 1.2 m after the step at 0.3 s: the one call stops at the
    first output point outside, with the message, time, state and partial result of the
    per-piece path (which checks in Python), and the Simulator stays at the last piece
    that passed."""
    m = model(x_high=1.2)
    errors = []
    for progress in (None, lambda f: None):
        with pytest.raises(SolverError, match="left the physical domain: osc.x = ") as info:
            simulate(
                m,
                1.0,
                {"osc.u": Step(final=1e5, time=0.3)},
                settings=SETTINGS,
                output_interval=0.01,
                progress=progress,
            )
        errors.append(info.value)
    one, per_piece = errors
    assert str(one) == str(per_piece) and one.time == per_piece.time
    assert 0.3 < one.time < 0.5 and one.state == per_piece.state
    assert one.state["osc.x"] > 1.2
    np.testing.assert_array_equal(one.partial.index, per_piece.partial.index)
    np.testing.assert_array_equal(one.partial["osc.x"], per_piece.partial["osc.x"])
    assert one.partial.index[-1] == pytest.approx(0.3)
    sim = Simulator(m, SETTINGS, t0=0.0)
    sim.step([1e4], 0.05)
    with pytest.raises(SolverError, match="osc.x"):
        sim.advance([1e5], np.linspace(0.1, 1.0, 10))
    assert sim.t == pytest.approx(0.05)  # one piece: nothing of it passed


@pytest.mark.slow  # a compile on a cold cache
def test_a_method_failure_names_the_piece_and_keeps_what_passed():
    """max_steps = 20 fails in the second piece (the step at 0.2 s): the same message, time
    and partial result as the per-piece path."""
    m = model()
    s = SolverSettings("radau", rtol=1e-7, atol=1e-10, max_steps=20)
    errors = []
    for progress in (None, lambda f: None):
        with pytest.raises(SolverError, match="too many steps") as info:
            simulate(
                m,
                1.0,
                {"osc.u": Step(final=1e5, time=0.2)},
                settings=s,
                t_out=[0.0, 1e-6, 2e-6, 0.2, 1.0],
                progress=progress,
            )
        errors.append(info.value)
    one, per_piece = errors
    assert str(one) == str(per_piece) and one.time == per_piece.time
    np.testing.assert_array_equal(one.partial.index, [0.0, 1e-6, 2e-6, 0.2])


def test_threads_never_share_an_integrator_memory():
    """Four threads simulating the same model at once (ctypes releases the GIL during the
    C call): every result equals the one computed alone."""
    m = model()
    inputs = {"osc.u": Sine(amplitude=5e4, offset=1e5, frequency=3.0, unit="Pa")}
    alone = simulate(m, 1.0, inputs, settings=SETTINGS)["osc.x"]
    results = []

    def work():
        for _ in range(5):
            results.append(simulate(m, 1.0, inputs, settings=SETTINGS)["osc.x"])

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 20
    for r in results:
        np.testing.assert_array_equal(r, alone)
