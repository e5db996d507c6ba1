"""Scenario TOML -> Scenario: schema, units, error locations, name resolution."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios.loader import key_lines, load_scenario, parse_scenario, resolve_scenario
from sarcomere.scenarios.signals import Staircase, Step, Table

FULL = """\
[scenario]
name = "concentric"
kind = "transient"
description = "Three APS lifting loads"

[model]
fidelity = "quasi_static"
n = 3
material = "dragonskin_30"
geometry = "experimental"
options = { smooth_orifice = true }

[parameters]
"load.m" = "50 g"
[parameters.regulator]
tau = "80 ms"

[inputs.pressure]
type = "staircase"
levels = ["0 MPa", "0.05 MPa", "0.1 MPa"]
dwell = "2 s"

[inputs.disturbance]
type = "step"
unit = "N"
final = "10 mN"
time = "500 ms"

[inputs.recorded]
type = "table"
unit = "Pa"
file = "data/p.csv"

[sweep.pressure]
start = "0 MPa"
stop = "0.1 MPa"
step = "0.01 MPa"

[sweep."load.m"]
values = [
    "0 g",
    "10 g",
    "100 g",
]

[simulation]
stop_time = "6 s"
output_interval = "10 ms"

[solver]
method = "idas"
rtol = 1e-6
step = "1 ms"
max_num_steps = 10000

[outputs]
signals = ["load.s", "chamber.p"]
tolerance = "1 %"
[outputs.plots]
position = ["load.s"]

[metrics]
length_ratio_0g_0p1MPa_ratio = 0.875
force_N = { reference = 0.315, rtol = 0.05, source = "paper" }
"""


def write(tmp_path: Path, text: str, name: str = "case.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


@pytest.fixture
def full(tmp_path: Path) -> Path:
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "p.csv").write_text("time [s],p [kPa]\n0,0\n1,100\n")
    return write(tmp_path, FULL)


def test_full_file_round_trip(full: Path) -> None:
    sc = load_scenario(full)
    assert (sc.name, sc.kind, sc.description) == ("concentric", "transient", sc.description)
    assert sc.file == str(full) and sc.base_dir == full.parent
    assert (sc.model.name, sc.model.fidelity, sc.model.n) == ("myofibril", "quasi_static", 3)
    assert dict(sc.model.options) == {"smooth_orifice": True}
    assert dict(sc.parameters) == {"load.m": "50 g", "regulator.tau": "80 ms"}
    p = sc.inputs["pressure"]
    assert isinstance(p, Staircase) and p.unit == "Pa" and p.dwell == 2.0
    assert p.levels == pytest.approx((0.0, 5e4, 1e5))
    d = sc.inputs["disturbance"]
    assert isinstance(d, Step) and d.unit == "N"
    assert (d.final, d.time) == pytest.approx((0.01, 0.5))
    rec = sc.inputs["recorded"]
    assert isinstance(rec, Table) and rec.values == pytest.approx((0.0, 1e5))
    assert [a.name for a in sc.sweep] == ["pressure", "load.m"]
    assert sc.axis("pressure").values == pytest.approx([k * 1e4 for k in range(11)])
    assert sc.axis("load.m").unit == "kg"
    assert sc.axis("load.m").values == pytest.approx((0.0, 0.01, 0.1))
    assert (sc.simulation.stop_time, sc.simulation.output_interval) == pytest.approx((6, 0.01))
    assert (sc.solver.method, sc.solver.rtol, sc.solver.atol, sc.solver.step) == (
        "idas",
        1e-6,
        None,
        pytest.approx(1e-3),
    )
    assert dict(sc.solver.options) == {"max_num_steps": 10000}
    assert sc.outputs.signals == ("load.s", "chamber.p")
    assert sc.outputs.tolerance == pytest.approx(0.01)
    assert dict(sc.outputs.plots) == {"position": ("load.s",)}
    ratio, force = sc.metrics
    assert (ratio.name, ratio.reference, ratio.rtol) == (
        "length_ratio_0g_0p1MPa_ratio",
        0.875,
        0.01,
    )
    assert (force.reference, force.rtol, force.source) == (0.315, 0.05, "paper")
    assert force.passes(0.33) and not force.passes(0.34)


def test_defaults_and_name_from_file(tmp_path: Path) -> None:
    sc = load_scenario(write(tmp_path, '[scenario]\nkind = "static"\n', "my-case.toml"))
    assert sc.name == "my-case"
    assert (sc.model.fidelity, sc.model.n, sc.sweep, sc.simulation) == ("full", 1, (), None)


def error_of(text: str, tmp_path: Path) -> ScenarioError:
    path = write(tmp_path, text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert info.value.file == str(path)
    return info.value


def test_unknown_key_names_line_valid_keys_and_close_match(tmp_path: Path) -> None:
    err = error_of('[scenario]\nkind = "static"\n\n[model]\nn = 1\nmaterail = "x"\n', tmp_path)
    assert (err.key, err.line) == ("model.materail", 6)
    assert "did you mean 'material'?" in str(err)
    assert "valid keys: name, fidelity, n, material, geometry, options" in str(err)


def test_unknown_section(tmp_path: Path) -> None:
    err = error_of('[scenario]\nkind = "static"\n[sweeps.pressure]\nvalues = [1]\n', tmp_path)
    assert (err.key, err.line) == ("sweeps", 3)
    assert "did you mean 'sweep'?" in str(err)


def test_unknown_signal_key_inside_input(tmp_path: Path) -> None:
    text = '[scenario]\nkind = "x"\n[inputs.pressure]\ntype = "sine"\namplitud = 1\n'
    err = error_of(text, tmp_path)
    assert (err.key, err.line) == ("inputs.pressure.amplitud", 5)
    assert "did you mean 'amplitude'?" in str(err)


def test_wrong_dimension(tmp_path: Path) -> None:
    text = """\
    [scenario]
    kind = "static"

    [sweep.pressure]
    start = "0 MPa"
    stop = "5 kg"
    step = "0.01 MPa"
    """
    err = error_of(text, tmp_path)
    assert (err.key, err.line) == ("sweep.pressure.stop", 6)
    assert "wrong dimension" in str(err) and "Pa" in str(err)


def test_wrong_dimension_in_list_and_quoted_key(tmp_path: Path) -> None:
    text = '[scenario]\nkind = "x"\n[sweep."load.m"]\nvalues = ["0 g",\n  "5 mm"]\n'
    err = error_of(text, tmp_path)
    assert (err.key, err.line) == ('sweep."load.m".values', 4)


@pytest.mark.parametrize(
    ("body", "key", "needle"),
    [
        ("[model]\nn = 0\n", "model.n", "integer >= 1"),
        ('[model]\nfidelity = "fast"\n', "model.fidelity", "not one of paper"),
        ("[sweep.pressure]\nstart = 0\nstop = 1\nstep = 0.3\n", "sweep.pressure.step", "divide"),
        ("[sweep.pressure]\nvalues = [2, 1]\n", "sweep.pressure.values", "increasing"),
        ("[sweep.angle]\nvalues = [1]\n", "sweep.angle", "missing required key 'unit'"),
        ('[sweep.x]\nunit = "mm"\nvalues = [1]\n', "sweep.x.unit", "not an SI unit"),
        ('[simulation]\nstop_time = "-1 s"\n', "simulation.stop_time", "later than"),
        ('[inputs.pressure]\ntype = "pulse"\n', "inputs.pressure.type", "one of step, ramp"),
        ('[inputs.pressure]\ntype = "ramp"\nfinal = 1\n', "inputs.pressure", "key 'duration'"),
        ('[inputs.x]\ntype = "step"\nfinal = 1\n', "inputs.x", "missing required key 'unit'"),
        ('[metrics]\nx_N = "big"\n', "metrics.x_N", "expected a number"),
    ],
)
def test_bad_values(tmp_path: Path, body: str, key: str, needle: str) -> None:
    err = error_of('[scenario]\nkind = "x"\n' + body, tmp_path)
    assert err.key == key and err.line is not None
    assert needle in str(err)


def test_toml_syntax_error_reports_tomllib_line(tmp_path: Path) -> None:
    err = error_of('[scenario]\nkind = "static"\n\n[model]\nn = = 2\n', tmp_path)
    assert err.line == 5
    assert "TOML syntax error" in str(err) and f"{err.file}:5:" in str(err)


def test_key_lines_scanner() -> None:
    text = '[a]\nx = [\n  "y = 1",\n]\n"q.r" = 2 # c\n[a.b]\n  z = """\nw = 3\n"""\nv = 1\n'
    assert key_lines(text) == {
        ("a",): 1,
        ("a", "x"): 2,
        ("a", "q.r"): 5,
        ("a", "b"): 6,
        ("a", "b", "z"): 7,
        ("a", "b", "v"): 10,
    }


def test_parameter_error_finds_quoted_and_nested_keys() -> None:
    text = '[scenario]\nkind = "x"\n[parameters]\n"load.m" = 1\n[parameters.geometry]\nh_ch = 2\n'
    sc = parse_scenario(text, "f.toml")
    assert sc.parameter_error("load.m", "bad").line == 4
    assert sc.parameter_error("geometry.h_ch", "bad").line == 6
    assert sc.parameter_error("nope", "bad").line == 3


def test_bare_name_resolves_to_packaged_file() -> None:
    res = resolve_scenario("paper-static")
    assert res.name == "paper-static.toml"
    sc = load_scenario("paper-static")
    assert (sc.name, sc.kind, sc.model.fidelity) == ("paper-static", "static", "paper")
    assert sc.axis("pressure").values[0] == pytest.approx(1e4)


def test_unknown_name_suggests_packaged(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="did you mean 'paper-static'"):
        load_scenario("paper-statc")
    with pytest.raises(ScenarioError, match="no such file"):
        load_scenario(tmp_path / "missing.toml")
