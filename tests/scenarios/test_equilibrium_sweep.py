"""Equilibrium sweeps keep one result per combination of the swept axes."""

import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import parse_scenario, run

HANGING_N = """
[scenario]
name = "hang-n"
kind = "equilibrium"
[model]
fidelity = "symmetric"
[model.options]
setup = "hanging"
load = "50 g"
[sweep.pressure]
values = ["0 MPa", "0.05 MPa", "0.1 MPa"]
[sweep.n]
unit = "1"
values = {ns}
"""


def test_a_hanging_sweep_over_n_keeps_every_n(tmp_path):
    out = run(parse_scenario(HANGING_N.format(ns="[1, 2, 3]"), "h.toml"), tmp_path, quiet=True)
    assert sorted(out.results) == ["n1_load_50g", "n2_load_50g", "n3_load_50g"]
    lengths = [out.results[f"n{n}_load_50g"]["length"][0] for n in (1, 2, 3)]
    assert lengths[0] < lengths[1] < lengths[2]  # three different chains, not n = 3 thrice
    for n in (1, 2, 3):
        assert f"strain_n{n}_50g_0p1MPa" in out.metrics
        assert f"length_ratio_n{n}_50g_0p1MPa" in out.metrics
        assert (tmp_path / f"timeseries_n{n}_load_50g.csv").exists()


def test_a_fractional_n_is_refused(tmp_path):
    sc = parse_scenario(HANGING_N.format(ns="[1, 2.5]"), "h.toml")
    with pytest.raises(ScenarioError, match=r"sweep.n.values.*2.5 is not a whole number"):
        run(sc, tmp_path, quiet=True)


def test_a_load_sweep_refuses_the_load_option_and_negative_loads(tmp_path):
    sweep = '[sweep.load]\nunit = "kg"\nvalues = ["-5 g", "10 g"]\n'
    text = HANGING_N.split("[sweep.n]")[0] + sweep
    with pytest.raises(ScenarioError, match=r"options.load.*\[sweep.load\] sets the load"):
        run(parse_scenario(text, "h.toml"), tmp_path, quiet=True)
    text = text.replace('load = "50 g"\n', "")
    with pytest.raises(ScenarioError, match=r"sweep.load.values.*-5 g: a load is >= 0 kg"):
        run(parse_scenario(text, "h.toml"), tmp_path, quiet=True)


def test_a_sweep_over_n_refuses_model_n(tmp_path):
    text = HANGING_N.format(ns="[1, 2]").replace(
        'fidelity = "symmetric"', 'fidelity = "symmetric"\nn = 3'
    )
    with pytest.raises(ScenarioError, match=r"key 'model.n': \[sweep.n\] sets n"):
        run(parse_scenario(text, "h.toml"), tmp_path, quiet=True)
