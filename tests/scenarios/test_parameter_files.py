"""Parameter files (``sarcomere fit``'s ``fitted.toml``): ``[parameters] include`` in a
scene, ``--parameters FILE`` on ``run``, ``export-fmu`` and ``study``; precedence, the
sources carried into summary.json, and the errors naming the file and the key."""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import binding, cli
from sarcomere.scenarios.explore.spec import load_study
from sarcomere.scenarios.export_fmu import scenario_setup
from sarcomere.scenarios.loader import load_scenario, read_parameter_file, with_parameter_file

SCENE = """\
[scenario]
name = "t"
kind = "transient"

[model]
name = "myofibril"
n = 1

[model.options]
load = "20 g"
{parameters}
[inputs.pressure]
type = "step"
final = "0.08 MPa"
time = "0.01 s"

[simulation]
stop_time = "0.15 s"
output_interval = "5 ms"

[solver]
rtol = 1e-8
atol = 1e-11
"""

#: Dynamic estimates and their units, as a fit file writes them.
NAMES = {"regulator.tau": "s", "aps.C_tube": "m^3/(s*Pa)", "aps.c_e": "N*s/m", "aps.V0": "m^3"}
DEFAULTS = {"regulator.tau": 0.05, "aps.C_tube": 2e-9, "aps.c_e": 2.0, "aps.V0": 4e-6}


def _fitted(values: dict, sources: dict | None = None) -> str:
    rows = "\n".join(f'"{k}" = "{v!r} {NAMES[k]}"' for k, v in values.items())
    src = "\n".join(f'"{k}" = "{v}"' for k, v in (sources or {}).items())
    return f'[fitted]\nfit = "test"\n\n[parameters]\n{rows}\n\n[sources]\n{src}\n'


def _scene(tmp_path, parameters: str = "", name: str = "s.toml"):
    path = tmp_path / name
    path.write_text(
        SCENE.format(parameters=f"\n[parameters]\n{parameters}\n" if parameters else "")
    )
    return path


def _simulate(sc):
    b = binding.bind(sc)
    return binding.simulate_scene(sc, b, "full")


def test_included_file_equals_explicit_parameters(tmp_path):
    """Random values (fixed seed) 0.5-2x the defaults: the included file gives the result
    the same explicit [parameters] give, to 1e-12, and not the defaults' result."""
    rng = np.random.default_rng(25)
    values = {
        k: float(v * np.exp(rng.uniform(np.log(0.5), np.log(2.0)))) for k, v in DEFAULTS.items()
    }
    (tmp_path / "fitted.toml").write_text(_fitted(values))
    explicit = "\n".join(f'"{k}" = "{v!r} {NAMES[k]}"' for k, v in values.items())
    inc = _simulate(load_scenario(_scene(tmp_path, 'include = "fitted.toml"', "inc.toml")))
    exp = _simulate(load_scenario(_scene(tmp_path, explicit, "exp.toml")))
    base = _simulate(load_scenario(_scene(tmp_path, "", "base.toml")))
    name = "myofibril.length"
    assert np.allclose(inc[name], exp[name], rtol=1e-12, atol=0)
    assert np.allclose(inc["regulator.p_out"], exp["regulator.p_out"], rtol=1e-12, atol=1e-9)
    assert np.max(np.abs(inc[name] - base[name])) > 1e-5  # the file changed the result
    # --parameters FILE on a scene without include: the same result again
    cmd = _simulate(with_parameter_file(load_scenario(_scene(tmp_path)), tmp_path / "fitted.toml"))
    assert np.allclose(cmd[name], exp[name], rtol=1e-12, atol=0)


def test_precedence_and_sources(tmp_path):
    """Later includes override earlier ones, the scene's own entries override all;
    --parameters comes after the scene's includes; sources say where each value is from."""
    (tmp_path / "a.toml").write_text(
        _fitted({"regulator.tau": 0.07, "aps.c_e": 3.0}, {"regulator.tau": "fitted to A"})
    )
    (tmp_path / "b.toml").write_text(_fitted({"regulator.tau": 0.08}, {"regulator.tau": "to B"}))
    (tmp_path / "c.toml").write_text(_fitted({"aps.c_e": 4.0, "aps.V0": 5e-6}))
    scene = _scene(tmp_path, 'include = ["a.toml", "b.toml"]\n"aps.c_e" = "2.5 N*s/m"')
    sc = load_scenario(scene)
    assert dict(sc.parameters) == {
        "regulator.tau": "0.08 s",
        "aps.c_e": "2.5 N*s/m",
    }
    src = sc.parameter_sources()
    assert src["regulator.tau"] == f"{tmp_path / 'b.toml'}: to B"
    assert src["aps.c_e"] == f"[parameters] of {scene}"
    sc2 = with_parameter_file(sc, tmp_path / "c.toml")
    assert sc2.parameters["aps.c_e"] == "2.5 N*s/m"  # the scene's own entry stays
    assert sc2.parameters["aps.V0"] == "5e-06 m^3"
    assert sc2.parameter_sources()["aps.V0"] == f"{tmp_path / 'c.toml'}: no source"
    assert load_scenario(_scene(tmp_path, '"aps.c_e" = "3 N*s/m"')).parameter_sources() == {}


def test_run_cli_writes_sources(tmp_path, monkeypatch):
    """``run --parameters FILE``: the file's values reach the run and summary.json says
    what each was fitted to."""
    (tmp_path / "f.toml").write_text(_fitted({"regulator.tau": 0.065}, {"regulator.tau": "step"}))
    scene = _scene(tmp_path)
    out = tmp_path / "out"
    argv = [
        "run",
        str(scene),
        "--out",
        str(out),
        "--quiet",
        "--parameters",
        str(tmp_path / "f.toml"),
    ]
    assert cli.main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["parameters"] == {"regulator.tau": "0.065 s"}
    assert summary["parameter_sources"] == {"regulator.tau": f"{tmp_path / 'f.toml'}: step"}
    assert cli.main([*argv[:4], "--parameters", str(tmp_path / "none.toml")]) == 2


def test_export_fmu_and_study_take_the_file(tmp_path):
    """export-fmu's set-up and a study's scene carry the file's values; a study's
    fingerprint follows the file's content."""
    f = tmp_path / "f.toml"
    f.write_text(_fitted({"aps.C_tube": 3e-9}))
    scene = _scene(tmp_path)
    model, params, _, _ = scenario_setup(with_parameter_file(load_scenario(scene), f))
    assert np.isclose(model.parameters(params)[model.index("myofibril.tube1.C")[1]], 3e-9)
    args = cli.build_parser(argv=["export-fmu"]).parse_args(
        ["export-fmu", "x", "--parameters", "f"]
    )
    assert args.parameters == "f"
    study = tmp_path / "st.toml"
    study.write_text(
        textwrap.dedent(
            f"""\
            [study]
            base = "{scene.name}"
            kind = "grid"
            [study.grid]
            load = ["10 g", "20 g"]
            [study.metrics]
            names = ["stroke"]
            """
        )
    )
    s1 = load_study(study, f)
    assert s1.scene().parameters["aps.C_tube"] == "3e-09 m^3/(s*Pa)"
    assert s1.scene().parameter_sources()
    fingerprint = s1.fingerprint()
    assert load_study(study).fingerprint() != fingerprint
    f.write_text(_fitted({"aps.C_tube": 4e-9}))  # a resumed store refuses changed values
    assert load_study(study, f).fingerprint() != fingerprint


@pytest.mark.parametrize(
    ("content", "key", "line", "why"),
    [
        (
            '[parameters]\n"regulator.tauu" = "60 ms"\n',
            "regulator.tauu",
            2,
            "did you mean 'regulator.tau'",
        ),
        ('[parameters]\nx = 1\n"regulator.tau" = "fast"\n', "x", 2, "unknown key 'x'"),
        ('[parameters]\n"regulator.tau" = "fast"\n', "regulator.tau", 2, "'fast' is invalid"),
        ('[parameters]\n"regulator.tau" = 60\n', "regulator.tau", 2, "bare number"),
        ('[parameters]\n\n"aps.V0" = "3 kg"\n', "aps.V0", 3, "wrong dimension"),
        ('[parameters.aps]\nc_e = "-1 N*s/m"\n', "aps.c_e", 2, "c_e"),
    ],
)
def test_bad_value_names_the_included_file(tmp_path, content, key, line, why):
    (tmp_path / "fitted.toml").write_text(content)
    sc = load_scenario(_scene(tmp_path, 'include = "fitted.toml"'))
    with pytest.raises(ScenarioError, match=why) as info:
        binding.bind(sc).build("full")
    assert info.value.file == str(tmp_path / "fitted.toml")
    assert info.value.line == line
    assert key in info.value.key


@pytest.mark.parametrize(
    ("content", "key", "why"),
    [
        ('[parameters]\ninclude = "x.toml"\n', "parameters.include", "cannot include"),
        ('[parameter]\n"regulator.tau" = "1 s"\n', "parameter", "unknown key 'parameter'"),
        ('[fitted]\nfit = "x"\n', "", "missing required key 'parameters'"),
        ('[parameters]\n"a.b" = [1]\n', 'parameters."a.b"', "expected a number or a string"),
        ('[parameters]\n"aps.c_e" = "1 N*s/m"\n[sources]\n"aps.ce" = "x"\n', "sources", "aps.ce"),
        ('[parameters]\n"aps.c_e" = "1 N*s/m"\n[sources]\n"aps.c_e" = 3\n', "sources", "string"),
        ('[parameters\n"aps.c_e" = "1 N*s/m"\n', "", "TOML syntax error"),
    ],
)
def test_malformed_parameter_file(tmp_path, content, key, why):
    path = tmp_path / "fitted.toml"
    path.write_text(content)
    with pytest.raises(ScenarioError, match=why) as info:
        read_parameter_file(path)
    assert info.value.file == str(path)
    assert key in info.value.key
    with pytest.raises(ScenarioError, match=why):  # the same through a scene
        load_scenario(_scene(tmp_path, 'include = "fitted.toml"'))


@pytest.mark.parametrize(
    ("include", "why"),
    [('"none.toml"', "'none.toml': no such file"), ('"."', "is a directory"), ("3", "file name")],
)
def test_missing_include_names_the_scene_key(tmp_path, include, why):
    scene = _scene(tmp_path, f"include = {include}")
    with pytest.raises(ScenarioError, match=why) as info:
        load_scenario(scene)
    assert info.value.file == str(scene)
    assert info.value.key == "parameters.include"
    assert info.value.line == scene.read_text().splitlines().index(f"include = {include}") + 1
