"""A scene's mistakes are named by the key the user wrote (issue 24): an unknown key says
"unknown key, did you mean", never "invalid value" of another key."""

from __future__ import annotations

import re

import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import parse_scenario, resolve_scenario, run


def _text(name: str) -> str:
    return resolve_scenario(name).read_text(encoding="utf-8")


def test_an_unknown_model_parameter_is_an_unknown_key_of_the_file(tmp_path):
    """Was ``parameter 'load.mm' = '3 g' is invalid``, without the file or line."""
    text = _text("step-50g").replace(
        "[inputs.pressure]", '[parameters]\n"load.mm" = "3 g"\n\n[inputs.pressure]'
    )
    with pytest.raises(ScenarioError) as info:
        run(parse_scenario(text, "x.toml"), tmp_path / "o", quiet=True)
    assert re.match(r"x\.toml:\d+: key 'parameters\.\"load\.mm\"': ", str(info.value))
    count = len(hanging_load(3).param_names)  # the model's own count, not a number kept here
    assert str(info.value).endswith(
        f"unknown key 'load.mm'; did you mean 'load.m'? ({count} parameters of model "
        "'hanging_n3_full')"
    )
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("name", "old", "new"),
    [
        ("step-50g", "[inputs.pressure]", "[inputs.presure]"),
        ("paper-static", "[sweep.pressure]", "[sweep.presure]"),
    ],
)
def test_a_misspelt_signal_or_axis_is_unknown_not_missing_its_unit(name, old, new):
    """Was ``key 'inputs.presure': missing required key 'unit'``."""
    text = _text(name).replace(old, new)
    section = new.strip("[]")
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text, "x.toml")
    assert f"key '{section}': unknown key 'presure'; did you mean 'pressure'?" in str(info.value)


def test_a_named_signal_with_its_unit_is_still_accepted():
    text = _text("step-50g").replace("[inputs.pressure]", '[inputs.pressure]\nunit = "Pa"')
    text = text.replace('final = "0.1 MPa"', "final = 1e5")
    assert parse_scenario(text, "x.toml").inputs["pressure"](1.0) == pytest.approx(1e5)


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        # was blamed on pressure_max
        ('operating_pressure = "50 kPa"', 'operating_pressure = "5 MPa"', "operating_pressure"),
        ('pressure_min = "0 MPa"', 'pressure_min = "0.06 MPa"', "operating_pressure"),
        ('pressure_max = "0.3 MPa"', 'pressure_max = "0.7 MPa"', "pressure_max"),
        ('pressure_min = "0 MPa"', 'pressure_min = "0.4 MPa"', "pressure_max"),
    ],
)
def test_the_pressure_limits_blame_the_key_out_of_place(tmp_path, old, new, key):
    text = _text("control-length").replace(old, new)
    line = 1 + next(i for i, row in enumerate(text.splitlines()) if row.startswith(f"{key} ="))
    with pytest.raises(ScenarioError, match=rf"^x\.toml:{line}: key 'control\.{key}': need"):
        run(parse_scenario(text, "x.toml"), tmp_path / "o", quiet=True)
