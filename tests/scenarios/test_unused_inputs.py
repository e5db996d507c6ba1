"""Inputs a run would ignore are refused, naming the key; signal fields are checked early."""

import pytest

from sarcomere.dynamics.errors import ParameterError, ScenarioError
from sarcomere.dynamics.signals import Ramp, Staircase, Step, Table
from sarcomere.scenarios import parse_scenario, run

TRANSIENT = """
[scenario]
kind = "transient"
[model]
fidelity = "symmetric"
{model}
[model.options]
setup = "{setup}"
{option}
[inputs.pressure]
type = "step"
{unit}
[simulation]
stop_time = "0.2 s"
{extra}
"""


def _refused(
    tmp_path, match, model="", setup="hanging", option="", unit='final = "0.1 MPa"', extra=""
):
    text = TRANSIENT.format(model=model, setup=setup, option=option, unit=unit, extra=extra)
    sc = parse_scenario(text, "t.toml")
    with pytest.raises(ScenarioError, match=match):
        run(sc, tmp_path / "o", quiet=True)
    assert not (tmp_path / "o").exists()


def test_geometry_in_a_dynamic_kind_is_refused(tmp_path):
    _refused(tmp_path, r"model.geometry.*does not use a geometry", model='geometry = "fem"')


def test_load_with_the_isometric_setup_is_refused(tmp_path):
    _refused(tmp_path, r"options.load.*'isometric' does not use", "", "isometric", 'load = "50 g"')


def test_fixture_with_the_hanging_setup_is_refused(tmp_path):
    _refused(tmp_path, r"fixture_gap", option='fixture_gap = "1 mm"')


def test_sweep_in_a_transient_is_refused(tmp_path):
    _refused(tmp_path, r"t.toml:\d+: key 'sweep'.*does not use \[sweep\]", extra=SWEEP)


def test_cosim_settings_in_a_transient_are_refused(tmp_path):
    _refused(tmp_path, r"key 'cosim'.*does not use \[cosim\]", extra="[cosim]\nfmi = 2")


def test_tolerance_without_auto_is_refused(tmp_path):
    _refused(tmp_path, r"outputs.tolerance", extra='[outputs]\ntolerance = "1 %"')


def test_a_signal_unit_must_match_its_input(tmp_path):
    _refused(tmp_path, r"inputs.pressure.unit.*'N'.*'Pa'", unit='unit = "N"\nfinal = 1.0')


SWEEP = '[sweep.pressure]\nvalues = ["0.1 MPa"]'
STATIC = '[scenario]\nkind = "static"\n[model]\nfidelity = "paper"\n' + SWEEP + "\n"


@pytest.mark.parametrize(
    ("extra", "key"),
    [
        ('[simulation]\nstop_time = "1 s"', "simulation"),
        ('[solver]\nmethod = "idas"', "solver"),
        ('[inputs.pressure]\ntype = "step"\nfinal = "0.1 MPa"', "inputs"),
    ],
)
def test_static_refuses_what_it_does_not_use(tmp_path, extra, key):
    sc = parse_scenario(STATIC + extra, "s.toml")
    with pytest.raises(ScenarioError, match=rf"key '{key}'.*does not use \[{key}\]"):
        run(sc, tmp_path, quiet=True)


def test_equilibrium_refuses_a_simulation(tmp_path):
    text = STATIC.replace('"static"', '"equilibrium"').replace('"paper"', '"symmetric"')
    sc = parse_scenario(text + '[simulation]\nstop_time = "1 s"', "e.toml")
    with pytest.raises(ScenarioError, match=r"key 'simulation'"):
        run(sc, tmp_path, quiet=True)


@pytest.mark.parametrize(
    ("make", "name"),
    [
        (lambda: Step(final="abc", unit="Pa"), "final"),
        (lambda: Step(final="5 kg", unit="Pa"), "final"),
        (lambda: Ramp(final=1.0, duration="2 m"), "duration"),
        (lambda: Staircase(levels=(0.0, "x"), dwell=1.0), "levels[1]"),
        (lambda: Table(times=(0.0, "x"), values=(1.0, 2.0)), "times[1]"),
    ],
)
def test_signal_fields_are_checked_at_construction(make, name):
    with pytest.raises(ParameterError) as info:
        make()
    assert info.value.name == name


def test_signal_fields_take_quantity_strings():
    s = Step(final="0.1 MPa", time="100 ms", unit="Pa")
    assert (s.final, s.time) == (1e5, 0.1)
