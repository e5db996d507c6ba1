"""``[solver]`` keys are checked before running: one line, exit 2, never a traceback."""

import json

import pytest

from sarcomere.scenarios.cli import main

SCENE = """
[scenario]
kind = "transient"
[model]
fidelity = "symmetric"
[inputs.pressure]
type = "step"
final = "0.1 MPa"
[simulation]
stop_time = "0.05 s"
output_interval = "0.05 s"
[solver]
method = "{method}"
{key}
"""


def _cli(tmp_path, capsys, method, key):
    path = tmp_path / "s.toml"
    path.write_text(SCENE.format(method=method, key=key))
    status = main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet"])
    return status, capsys.readouterr().err


@pytest.mark.parametrize(
    ("method", "key", "needle"),
    [
        ("cvodes", "max_step = 10", "did you mean 'max_steps'?"),
        ("idas", "max_stepz = 10", "did you mean"),
        ("cvodes", 'max_order = "abc"', "refused by cvodes"),
        ("cvodes", "abstol = 1e-9", "set it as [solver] atol"),
        ("idas", "max_steps = 2.5", "expected an integer >= 1"),
    ],
)
def test_a_bad_solver_key_is_one_line(tmp_path, capsys, method, key, needle):
    status, err = _cli(tmp_path, capsys, method, key)
    assert status == 2 and err.count("\n") == 1 and err.startswith("error: "), err
    assert f"key 'solver.{key.split()[0]}'" in err and needle in err


def test_max_steps_is_the_settings_field(tmp_path, capsys):
    status, err = _cli(tmp_path, capsys, "cvodes", "max_steps = 1")
    assert status == 2 and "too many steps" in err  # honoured: one step is not enough
    status, err = _cli(tmp_path, capsys, "cvodes", "max_steps = 50000")
    assert status == 0, err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["solver"] == "cvodes"


@pytest.mark.parametrize("method", ["rk4", "euler"])
def test_a_fixed_step_method_without_its_step_names_the_key(tmp_path, capsys, method):
    """Issue 24 (poor): it was "parameter 'solver.step' = None is invalid", no file or line
    (line 12: the [solver] table that lacks the key)."""
    status, err = _cli(tmp_path, capsys, method, "")
    assert status == 2
    assert "s.toml:12: key 'solver.step'" in err and f"method '{method}' is fixed-step" in err
    assert len(err.strip().splitlines()) == 1
