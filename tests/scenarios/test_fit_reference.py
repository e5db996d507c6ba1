"""A static experiment measured against a reference equilibrium (``[experiments.reference]``,
ratio or tared difference) and the isometric fixture linked to the chain's rest position:
the targets checked against independent equilibrium solves, and every bad entry refused
with a one-line FitError naming the file, line and key."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load, isometric
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.scenarios.fit.build import build
from sarcomere.scenarios.fit.spec import FitError, load_fit

FIT = """\
[fit]
name = "ref"

[parameters."aps.A_r"]
start = "7.3706e-7 m^2"
bounds = ["1e-7 m^2", "1e-5 m^2"]

[noise."myofibril.length"]
sigma = "{sigma}"

[noise."sensor.f"]
sigma = "1 mN"

[[experiments]]
name = "hang"
kind = "static"
data = "hang.csv"
inputs = ["pressure"]
outputs = ["myofibril.length"]
reference = {{ form = "{form}", inputs = {{ pressure = "{p_ref}" }} }}
[experiments.model]
name = "myofibril"
n = 1
[experiments.model.options]
load = "{load}"

[[experiments]]
name = "iso"
kind = "static"
data = "iso.csv"
inputs = ["pressure"]
outputs = ["sensor.f"]
reference = {{ form = "difference", inputs = {{ pressure = "0 kPa" }} }}
[experiments.model]
name = "myofibril"
n = 1
[experiments.model.options]
setup = "isometric"
"""

HANG = "pressure [kPa],myofibril.length [{unit}]\n" + "".join(
    f"{p},{v}\n" for p, v in ((40, 0.98), (80, 0.95))
)
ISO = "pressure [kPa],sensor.f [N]\n40,0.1\n80,0.2\n"


REF = 'reference = { form = "ratio", inputs = { pressure = "0 kPa" } }'


def _write(tmp_path, unit="1", sigma="0.005", p_ref="0 kPa", load="20 g", ref=None):
    """The fit file and its data; ``ref``: the first experiment's reference line instead."""
    (tmp_path / "hang.csv").write_text(HANG.format(unit=unit))
    (tmp_path / "iso.csv").write_text(ISO)
    text = FIT.format(form="ratio", sigma=sigma, p_ref=p_ref, load=load)
    if ref is not None:
        assert REF in text
        text = text.replace(REF, ref)
    path = tmp_path / "fit.toml"
    path.write_text(text)
    return path


def _first_experiment(text: str) -> str:
    first = text.index("[[experiments]]")
    return text[first : text.index("[[experiments]]", first + 1)]


def _error(path) -> FitError:
    with pytest.raises(FitError) as info:
        build(load_fit(path))
    assert "\n" not in str(info.value)
    return info.value


def _predictions(built, factor: float) -> np.ndarray:
    prob = built.problem
    theta = np.array([e.start * factor for e in prob.params])
    sol = prob.evaluate(prob.initial_guess(theta), prob.weights())
    return prob.predictions(sol)


@pytest.mark.parametrize("seed", [0, 1])
def test_ratio_and_tare_match_independent_equilibria(tmp_path, seed):
    """Generated loads, reference pressures and estimated values (fixed seeds): each
    prediction equals the same quantity from equilibria solved from scratch on set-ups
    built with the estimated value, the isometric fixture at that set-up's own rest
    position (a fixture left at the start's position fails this)."""
    rng = np.random.default_rng(seed)
    load_g, p_ref_kpa, factor = rng.uniform(5, 80), rng.uniform(0, 30), rng.uniform(1.2, 1.6)
    built = build(load_fit(_write(tmp_path, p_ref=f"{p_ref_kpa} kPa", load=f"{load_g} g")))
    pred = _predictions(built, factor)
    aps = APSParams.from_paper()
    aps = dataclasses.replace(aps, A_r=aps.A_r * factor)
    hang, iso = hanging_load(1, aps, load_g * 1e-3), isometric(1, aps)

    def solve(model, kpa, signal):
        return solve_equilibrium(model, {"regulator.p_cmd": kpa * 1e3})[signal]

    L_ref = solve(hang, p_ref_kpa, "myofibril.length")
    F_0 = solve(iso, 0.0, "sensor.f")
    expected = [solve(hang, p, "myofibril.length") / L_ref for p in (40, 80)]
    expected += [solve(iso, p, "sensor.f") - F_0 for p in (40, 80)]
    np.testing.assert_allclose(pred, expected, rtol=1e-9)
    # the data entered as written: ratios dimensionless, forces in N
    np.testing.assert_allclose(built.problem.rows.data, [0.98, 0.95, 0.1, 0.2])
    names = [pt.name for pt in built.problem.points]
    assert names == [
        "hang#reference1",
        "hang#1",
        "hang#2",
        "iso#rest",
        "iso#reference1",
        "iso#1",
        "iso#2",
    ]


def test_percent_column_and_shared_reference(tmp_path):
    """A ratio in %; a second experiment referring to the first one's set-up at the same
    inputs shares its reference point."""
    path = _write(tmp_path, unit="%")
    (tmp_path / "hang.csv").write_text(HANG.format(unit="%").replace("0.98", "98"))
    text = path.read_text()
    block = _first_experiment(text)
    extra = block.replace('name = "hang"', 'name = "hang2"').replace(
        'form = "ratio",', 'form = "ratio", experiment = "hang",'
    )
    path.write_text(text + "\n" + extra)
    built = build(load_fit(path))
    assert built.problem.rows.data[0] == pytest.approx(0.98)
    refs = [pt.name for pt in built.problem.points if "reference" in pt.name]
    assert refs == ["hang#reference1", "iso#reference1"]


@pytest.mark.parametrize(
    ("ref", "key", "words"),
    [
        (REF.replace('"ratio"', '"ratios"'), "experiments[1].reference.form", "did you mean"),
        (
            REF.replace("ratio", 'ratio", experiment = "hung'),
            "experiments[1].reference.experiment",
            "'hung' is not an experiment of this file; did you mean 'hang'",
        ),
        (REF.replace(" } }", " }, tare = 1 }"), "experiments[1].reference.tare", "unknown key"),
        (
            'reference = { form = "ratio" }',
            "experiments[1].reference",
            "missing required key 'inputs'",
        ),
        (
            'reference = { form = "ratio", inputs = {} }',
            "experiments[1].reference.inputs",
            "give the reference's inputs",
        ),
        (
            REF.replace("pressure", "presure"),
            "experiments[1].reference.inputs.presure",
            "not an input of model 'hanging_n1_full'; did you mean 'pressure'",
        ),
        (
            REF.replace('"ratio",', '"ratio", experiment = 3,'),
            "experiments[1].reference.experiment",
            "expected an experiment's name, got 3",
        ),
        (
            'reference = { form = "ratio", inputs = "0 MPa" }',
            "experiments[1].reference.inputs",
            "expected a table, got '0 MPa'",
        ),
    ],
    ids=[
        "form",
        "experiment",
        "unknown-key",
        "no-inputs",
        "empty-inputs",
        "not-an-input",
        "experiment-not-a-name",
        "inputs-not-a-table",
    ],
)
def test_bad_reference_entries(tmp_path, ref, key, words):
    err = _error(_write(tmp_path, ref=ref))
    assert err.file.endswith("fit.toml") and err.line == 20 and err.key == key
    assert words in str(err)


@pytest.mark.parametrize(
    ("p_ref", "words"),
    [
        ("0 mm", "convertible to Pa"),
        ("0", None),  # 0 is the same in every unit: accepted
        ("-50 kPa", "outside the input's range"),
        ("1 GPa", "outside the input's range"),
    ],
)
def test_reference_input_values(tmp_path, p_ref, words):
    path = _write(tmp_path, p_ref=p_ref)
    if words is None:
        build(load_fit(path))
        return
    err = _error(path)
    assert err.line == 20 and err.key == "experiments[1].reference.inputs.pressure"
    assert words in str(err) and p_ref in str(err)


def test_reference_on_a_time_series_refused(tmp_path):
    path = _write(tmp_path)
    csv = "time [s],pressure [kPa],myofibril.length [1]\n0,0,1\n1,40,0.98\n"
    (tmp_path / "hang.csv").write_text(csv)
    static = 'kind = "static"\ndata = "hang.csv"'
    path.write_text(path.read_text().replace(static, static.replace("static", "time-series")))
    err = _error(path)
    assert err.line == 20 and err.key == "experiments[1].reference"
    assert "a reference is for static experiments" in str(err)


def test_ratio_column_with_a_unit_of_the_signal(tmp_path):
    err = _error(_write(tmp_path, unit="mm"))
    assert err.file.endswith("hang.csv") and err.line == 1 and err.key == "myofibril.length"
    assert "'mm' is not a unit of 1 (a ratio to the reference: write [1] or [%])" in str(err)


def test_difference_column_in_the_signal_unit(tmp_path):
    path = _write(tmp_path)
    (tmp_path / "iso.csv").write_text(ISO.replace("[N]", "[1]"))
    err = _error(path)
    assert err.file.endswith("iso.csv") and err.key == "sensor.f" and "not a unit of N" in str(err)


def test_ratio_noise_is_dimensionless(tmp_path):
    err = _error(_write(tmp_path, sigma="10 um"))
    assert err.line == 9 and err.key == 'noise."myofibril.length".sigma' and "(1)" in str(err)


def test_one_form_per_signal(tmp_path):
    path = _write(tmp_path)
    text = path.read_text()
    block = _first_experiment(text)
    (tmp_path / "abs.csv").write_text("pressure [kPa],myofibril.length [mm]\n40,60\n")
    extra = block.replace('name = "hang"', 'name = "abs"').replace("hang.csv", "abs.csv")
    extra = extra.replace(REF + "\n", "")
    path.write_text(text + "\n" + extra)
    err = _error(path)
    assert err.key == "experiments[3].outputs" and "one noise per signal needs one form" in str(err)
