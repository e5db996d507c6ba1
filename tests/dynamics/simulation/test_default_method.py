"""The method a run gets when it names none (``radau.default_method``): the compiled
``radau`` iff its library for the model and input law is in the disk cache, else CVODES
(IDAS with algebraic unknowns), never a compile, always with the reason."""

from __future__ import annotations

import pytest

from sarcomere.dynamics import hanging_load
from sarcomere.dynamics.signals import Sine, Step
from sarcomere.dynamics.simulation import radau
from sarcomere.dynamics.simulation.settings import HELD
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate
from sarcomere.dynamics.simulation.simulator import Simulator


@pytest.fixture
def empty_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SARCOMERE_CACHE_DIR", str(tmp_path))
    return tmp_path


def test_an_empty_cache_gives_cvodes_and_compiles_nothing(oscillator, empty_cache):
    method, reason = radau.default_method(oscillator, HELD)
    assert method == "cvodes" and "not in" in reason and str(empty_cache) in reason
    assert radau.cached(oscillator, HELD) is None
    assert not any(empty_cache.rglob("*.so"))  # a lookup, no compile


def test_algebraic_unknowns_give_idas():
    model = hanging_load(n=1, load_kg=0.05, fidelity="static_chain")
    method, reason = radau.default_method(model, HELD)
    assert method == "idas" and "algebraic unknowns" in reason


def test_without_a_compiler_cvodes_says_why(oscillator, monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    method, reason = radau.default_method(oscillator, HELD)
    assert method == "cvodes" and "no C compiler" in reason


def test_input_law_is_the_one_advance_uses(oscillator):
    sim = Simulator(oscillator, t0=0.0)
    assert sim.input_law() is HELD  # the inputs' start values: held
    model = hanging_load(n=1, load_kg=0.05)
    sim = Simulator(model, t0=0.0)
    assert sim.input_law({"regulator.p_cmd": Step(final=1e5, time=0.1)}) is HELD
    sine = Sine(amplitude=1e4, frequency=1.0, offset=5e4)
    law = sim.input_law({"regulator.p_cmd": sine})
    assert law is not HELD and sine in law.signals


@pytest.mark.slow  # compiles radau once
def test_radau_iff_its_library_for_this_law_is_cached(empty_cache):
    model = hanging_load(n=1, load_kg=0.05)
    step = {"regulator.p_cmd": Step(final=1e5, time=0.1)}
    sine = {"regulator.p_cmd": Sine(amplitude=1e4, frequency=1.0, offset=5e4)}
    held = Simulator(model, t0=0.0).input_law(step)
    assert radau.default_method(model, held)[0] == "cvodes"
    simulate(model, 0.2, step, settings=SolverSettings("radau"))  # builds the held library
    method, reason = radau.default_method(model, held)
    assert method == "radau" and radau.cached(model, held).name in reason
    # a sine is another input law: its own library, not built, so CVODES
    law = Simulator(model, t0=0.0).input_law(sine)
    assert radau.default_method(model, law)[0] == "cvodes"
