"""Transient runs honour start_time; pressure commands outside the regulator's range are
refused before solving (the regulator would clamp them)."""

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import parse_scenario, run

STEP = """
[scenario]
kind = "transient"
[model]
fidelity = "symmetric"
n = 3
[model.options]
setup = "hanging"
load = "50 g"
[inputs.pressure]
type = "step"
{step}
time = "0.1 s"
[simulation]
{sim}
output_interval = "2 ms"
"""


def _run(tmp_path, step='final = "0.1 MPa"', sim='start_time = "0.5 s"\nstop_time = "0.8 s"'):
    return run(parse_scenario(STEP.format(step=step, sim=sim), "t.toml"), tmp_path, quiet=True)


def test_start_time_starts_the_run_there_with_the_input_there(tmp_path):
    res = _run(tmp_path).results["main"]
    assert res.index[0] == pytest.approx(0.5) and res.index[-1] == pytest.approx(0.8)
    assert np.all(res["regulator.p_cmd"] == 1e5)
    assert res["regulator.p_out"][0] == pytest.approx(1e5)  # the equilibrium at 0.1 MPa
    first = (tmp_path / "timeseries.csv").read_text().splitlines()[1].split(",")
    assert float(first[0]) == pytest.approx(0.5) and float(first[1]) == 1e5


def test_a_negative_command_is_refused_at_its_time(tmp_path):
    with pytest.raises(ScenarioError) as info:
        _run(tmp_path, 'final = "-0.05 MPa"', 'stop_time = "0.3 s"')
    msg = str(info.value)
    assert "inputs.pressure" in msg and "-0.05 MPa at t = 0.1 s" in msg
    assert "regulator" in msg and "[0, 0.6] MPa" in msg
    assert not tmp_path.joinpath("summary.json").exists()


def test_a_command_above_p_max_is_refused(tmp_path):
    with pytest.raises(ScenarioError, match=r"0.7 MPa at t = 0.1 s.*regulator's range"):
        _run(tmp_path, 'final = "0.7 MPa"', 'stop_time = "0.3 s"')


def test_p_max_override_narrows_the_range(tmp_path):
    text = STEP.format(step='final = "0.35 MPa"', sim='stop_time = "0.3 s"')
    text += '[parameters]\n"regulator.p_max" = "0.3 MPa"\n'
    with pytest.raises(ScenarioError, match=r"\[0, 0.3\] MPa"):
        run(parse_scenario(text, "t.toml"), tmp_path, quiet=True)


def test_an_equilibrium_sweep_above_p_max_is_refused(tmp_path):
    text = """
[scenario]
kind = "equilibrium"
[model]
fidelity = "symmetric"
[sweep.pressure]
values = ["0.1 MPa", "0.7 MPa"]
"""
    with pytest.raises(ScenarioError, match=r"sweep.pressure.*0.7 MPa is outside.*\[0, 0.6\]"):
        run(parse_scenario(text, "e.toml"), tmp_path, quiet=True)


def test_one_input_given_by_alias_and_full_name_is_refused_naming_both(tmp_path):
    """Issue 16 bug 3: [inputs.pressure] and [inputs."regulator.p_cmd"] both drive
    regulator.p_cmd; the first was silently dropped."""
    text = STEP.format(step='final = "0.1 MPa"', sim='stop_time = "0.3 s"')
    text += '[inputs."regulator.p_cmd"]\ntype = "step"\nunit = "Pa"\nfinal = "0.05 MPa"\n'
    with pytest.raises(ScenarioError) as info:
        run(parse_scenario(text, "t.toml"), tmp_path, quiet=True)
    msg = str(info.value)
    line = text.splitlines().index('[inputs."regulator.p_cmd"]') + 1
    assert msg.startswith(f"t.toml:{line}: key 'inputs.\"regulator.p_cmd\"'")
    assert "[inputs.pressure]" in msg and '[inputs."regulator.p_cmd"]' in msg
    assert "regulator.p_cmd" in msg
