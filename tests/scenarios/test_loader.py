"""Scenario TOML -> Scenario: schema, units, error locations, name resolution."""

from __future__ import annotations

import os
import re
import textwrap
import warnings
from pathlib import Path

import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.dynamics.units import to_si
from sarcomere.scenarios.loader import (
    key_lines,
    load_scenario,
    packaged_scenarios,
    parse_scenario,
    resolve_scenario,
    scenario_from_dict,
)
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
        (
            '[sweep.pressure]\nstart = "0 Pa"\nstop = "1 Pa"\nstep = "0.3 Pa"\n',
            "sweep.pressure.step",
            "divide",
        ),
        ('[sweep.pressure]\nvalues = ["2 Pa", "1 Pa"]\n', "sweep.pressure.values", "increasing"),
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


@pytest.mark.parametrize(
    ("make", "what"),
    [
        (lambda p: p.mkdir(), "is a directory"),
        (lambda p: os.mkfifo(p), "is a FIFO (named pipe)"),
        (lambda p: p.symlink_to(p.parent / "gone.toml"), "is a broken symbolic link"),
    ],
)
def test_a_scenario_path_that_is_no_file_says_what_it_is(tmp_path: Path, make, what) -> None:
    """Issue 16: a directory, a FIFO or /dev/null was "no such file"; a FIFO is never
    opened (reading it would block until a writer comes)."""
    path = tmp_path / "scene.toml"
    make(path)
    with pytest.raises(ScenarioError, match=f"{re.escape(what)}; expected a scenario TOML file"):
        load_scenario(path)


def test_dev_null_as_scenario_is_a_character_device() -> None:
    with pytest.raises(ScenarioError, match="is a character device; expected a scenario"):
        load_scenario("/dev/null")


def test_a_folder_named_like_a_packaged_scene_does_not_hide_it(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "step-50g").mkdir()  # e.g. an earlier `--out step-50g`
    assert load_scenario("step-50g").name == "step-50g"


def test_binary_scenario_file_is_named_with_the_problem(tmp_path: Path) -> None:
    path = tmp_path / "b.toml"
    path.write_bytes(b'[scenario]\nkind = "\xff"\n')
    with pytest.raises(ScenarioError, match=r"not UTF-8 text: byte 0xff at offset 19 \(line 2\)"):
        load_scenario(path)


SCENE = """\
[scenario]
kind = "transient"
[model]
n = 1
{body}
[inputs.pressure]
type = "step"
final = "0.1 MPa"
[simulation]
stop_time = "1 s"
"""


@pytest.mark.parametrize(
    ("body", "key", "value"),
    [
        ("[model.options]\nload = 50", "model.options.load", "'50 kg'"),
        ('[model.options]\nregulator_tau = "0.05"', "model.options.regulator_tau", "'0.05 s'"),
        ('[parameters]\n"aps.k_s" = 400', 'parameters."aps.k_s"', "'400 N/m'"),
        ('[parameters]\n"load.m" = 0.05', 'parameters."load.m"', "'0.05 kg'"),
        ('[parameters]\n"regulator.p_max" = 1e6', 'parameters."regulator.p_max"', "'1e+06 Pa'"),
    ],
)
def test_a_bare_number_of_a_dimensioned_key_is_refused(body: str, key: str, value: str) -> None:
    """Issue 16: `load = 50` was 50 kg without a word; a file's quantities need a unit."""
    from sarcomere.scenarios.binding import bind

    sc = parse_scenario(SCENE.format(body=body), "u.toml")
    with pytest.raises(ScenarioError) as info:
        bind(sc).build("full")
    assert info.value.key == key and info.value.line == 6
    assert "a bare number needs a unit here" in str(info.value) and value in str(info.value)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        (
            SCENE.format(body="").replace('stop_time = "1 s"', "stop_time = 2"),
            "simulation.stop_time",
        ),
        (
            SCENE.format(body="").replace('final = "0.1 MPa"', "final = 1e5"),
            "inputs.pressure.final",
        ),
        (
            SCENE.format(body="").replace('final = "0.1 MPa"', 'final = "1e5"'),
            "inputs.pressure.final",
        ),
        (SCENE.format(body="") + '[sweep."load.m"]\nvalues = [0.05]\n', 'sweep."load.m".values'),
    ],
)
def test_a_bare_number_in_a_loaded_section_is_refused(text: str, key: str) -> None:
    with pytest.raises(ScenarioError, match="a bare number needs a unit here") as info:
        parse_scenario(text, "u.toml")
    assert info.value.key == key


def test_zero_and_numbers_in_a_stated_unit_need_none() -> None:
    text = SCENE.format(body="").replace(
        'final = "0.1 MPa"', 'unit = "Pa"\nfinal = 1e5\ninitial = 0'
    )
    text += '[sweep."load.m"]\nunit = "kg"\nvalues = [0, 0.05]\n'
    sc = parse_scenario(text, "u.toml")
    assert sc.inputs["pressure"](2.0) == 1e5 and sc.axis("load.m").values == (0.0, 0.05)


def test_an_unparsable_quantity_gives_a_reason() -> None:
    text = SCENE.format(body="").replace('final = "0.1 MPa"', 'final = "1 +"')
    with pytest.raises(ScenarioError, match=r"cannot parse: not a number followed by a unit\)"):
        parse_scenario(text, "u.toml")


def test_a_setting_the_build_refuses_is_blamed_on_its_option_and_line() -> None:
    """Issue 16: regulator_tau was reported as `regulator.tau`, with no file and line."""
    from sarcomere.scenarios.binding import bind

    sc = parse_scenario(SCENE.format(body='[model.options]\nregulator_tau = "0.1 us"'), "u.toml")
    with pytest.raises(ScenarioError) as info:
        bind(sc).build("full")
    assert str(info.value).startswith("u.toml:6: key 'model.options.regulator_tau': 1e-07")


def test_load_m_against_the_load_option_is_refused_naming_both() -> None:
    from sarcomere.scenarios.binding import bind

    body = '[model.options]\nload = "50 g"\n[parameters]\n"load.m" = "60 g"'
    with pytest.raises(ScenarioError) as info:
        bind(parse_scenario(SCENE.format(body=body), "u.toml"))
    msg = str(info.value)
    assert msg.startswith("u.toml:8: key 'parameters.\"load.m\"'")
    assert "[parameters] load.m and [model.options] load" in msg


def test_aps_thermal_is_a_parameter_and_aps_material_points_to_model_material() -> None:
    from sarcomere.scenarios.binding import bind

    body = '[parameters]\n"aps.thermal" = "adiabatic"'
    assert bind(parse_scenario(SCENE.format(body=body), "u.toml")).aps.thermal == "adiabatic"
    body = '[parameters]\n"aps.thermal" = "hot"'
    with pytest.raises(ScenarioError, match="aps.thermal.*'hot'.*isothermal"):
        bind(parse_scenario(SCENE.format(body=body), "u.toml"))
    body = '[parameters]\n"aps.material" = "ecoflex_00_30"'
    with pytest.raises(ScenarioError, match=r"aps.material.*\[model\] material"):
        bind(parse_scenario(SCENE.format(body=body), "u.toml"))


@pytest.mark.parametrize(
    ("body", "key", "needle"),
    [
        (
            '[model.options]\nload = "50 kg"',
            "model.options.load",
            "50 kg is outside the plausible 0 to 1 kg",
        ),
        ('[parameters]\n"load.m" = "2 kg"', 'parameters."load.m"', "2 kg is outside the plausible"),
        ('[parameters]\n"aps.l" = "0.5 m"', 'parameters."aps.l"', "0.5 m is more than 10 times"),
        (
            '[parameters]\n"aps.A_p" = "10 cm^2"',
            'parameters."aps.A_p"',
            "0.001 m^2 is more than 100 times",
        ),
        (
            '[parameters]\n"aps.k_s" = "2e-12 N/m"',
            'parameters."aps.k_s"',
            "2e-12 N/m is more than 1000 times",
        ),
    ],
)
def test_an_implausible_load_or_geometry_warns_naming_the_value(body, key, needle) -> None:
    from sarcomere.scenarios.binding import bind
    from sarcomere.scenarios.spec import ScenarioWarning

    with pytest.warns(ScenarioWarning) as caught:
        bind(parse_scenario(SCENE.format(body=body), "u.toml"))
    (warning,) = caught
    assert (warning.filename, warning.lineno) == ("u.toml", 6)
    assert str(warning.message).startswith(f"key '{key}': {needle}")


def test_a_scene_warns_once_at_its_key_not_again_from_the_set_up() -> None:
    """The scene and the Python set-ups share one plausibility rule; a scene's model
    build does not repeat the warning bind gave at the scene's key."""
    from sarcomere.scenarios.binding import bind

    body = '[model.options]\nload = "2 kg"'
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bind(parse_scenario(SCENE.format(body=body), "u.toml")).build("full")
    assert [w.filename for w in caught] == ["u.toml"]


@pytest.mark.parametrize("name", list(packaged_scenarios()))
def test_every_packaged_scene_loads_and_binds_without_warnings(name: str) -> None:
    from sarcomere.scenarios.binding import bind

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sc = load_scenario(name)
        if sc.kind != "static":
            bind(sc)


@pytest.mark.parametrize("unit", ["kPa", "bar", "psi"])
def test_an_input_in_any_pressure_unit_is_taken_to_pa(tmp_path: Path, unit: str) -> None:
    """Issue 24: ``unit = "kPa"`` on an input was refused ("not an SI unit")."""
    text = SCENE.format(body="").replace('final = "0.1 MPa"', f'final = 2\nunit = "{unit}"')
    sc = load_scenario(write(tmp_path, text))
    step = sc.inputs["pressure"]
    assert step.unit == "Pa"
    assert step.final == pytest.approx(to_si(f"2 {unit}", "Pa"), rel=1e-12)


def test_a_parsed_dict_is_checked_as_its_text_is():
    """A study merges its base with its own tables as dicts and hands the result over (no
    TOML text written and parsed again)."""
    import tomllib

    text = packaged_scenarios()["step-50g"].read_text(encoding="utf-8")
    data = tomllib.loads(text)
    assert scenario_from_dict(data, "s.toml") == parse_scenario(text, "s.toml")
    data["model"]["fidelity"] = "ful"
    with pytest.raises(ScenarioError, match="s.toml: key 'model.fidelity': 'ful' is not one"):
        scenario_from_dict(data, "s.toml")
