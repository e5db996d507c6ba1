"""Study definitions: parsing, the one-line errors of every bad input (issue 19), the
canonical definition and fingerprint, pickling."""

import pickle
import textwrap

import pytest

from sarcomere.dynamics.errors import SarcomereError
from sarcomere.scenarios.explore.spec import StudyError, load_study, packaged_studies, parse_study

GRID = """
[study]
kind = "grid"
base = "step-50g"
[study.grid]
load = ["0 g", "50 g"]
pressure = {from = "0.05 MPa", to = "0.1 MPa", num = 3}
"""

SAMPLE = """
[study]
kind = "sample"
base = "step-50g"
seed = 3
[study.sample]
method = "lhs"
count = 8
[study.factors."aps.k_s"]
uniform = ["600 N/m", "800 N/m"]
"""


def parse(text: str):
    return parse_study(textwrap.dedent(text), "/nonexistent/study.toml")


def refused(text: str, *fragments: str) -> str:
    """The StudyError's message for ``text``: one line holding every fragment."""
    with pytest.raises(StudyError) as info:
        parse(text)
    message = str(info.value)
    assert "\n" not in message, message
    assert isinstance(info.value, SarcomereError)
    for f in fragments:
        assert f in message, (f, message)
    return message


def test_grid_study_in_si_with_its_axes_in_order():
    s = parse(GRID)
    assert s.kind == "grid" and s.method == "grid" and s.count == 6
    assert s.factor_names == ("load", "pressure")
    assert s.factors[0].values == (0.0, 0.05) and s.factors[0].unit == "kg"
    assert s.factors[1].values == pytest.approx((5e4, 7.5e4, 1e5))
    assert s.factors[1].unit == "Pa"
    assert s.seed is None and s.max_samples == 100_000


def test_scene_overrides_of_the_base_are_applied():
    s = parse(GRID + '[solver]\nmethod = "radau"\n[simulation]\nstop_time = "1 s"\n')
    sc = s.scene()
    assert sc.solver.method == "radau" and sc.simulation.stop_time == 1.0
    assert sc.model.n == 3 and sc.model.options["load"] == "50 g"  # from the base


def test_definition_is_canonical_and_the_fingerprint_follows_it():
    a, b = parse(SAMPLE), parse(SAMPLE.replace("count = 8", "count  =  8"))
    assert a.definition() == b.definition() and a.fingerprint() == b.fingerprint()
    assert parse(SAMPLE.replace("seed = 3", "seed = 4")).fingerprint() != a.fingerprint()
    other_scene = parse(SAMPLE + '[simulation]\nstop_time = "1 s"\n')
    assert other_scene.fingerprint() != a.fingerprint()
    assert len(a.fingerprint()) == 64


def test_study_pickles():
    s = parse(SAMPLE)
    again = pickle.loads(pickle.dumps(s))
    assert again == s and again.fingerprint() == s.fingerprint()


def test_packaged_studies_load_and_stay_out_of_the_scene_list():
    from sarcomere.scenarios.catalog import packaged_scenarios

    names = set(packaged_studies())
    assert {"design-map", "montecarlo-family", "sensitivity-step"} <= names
    assert not names & set(packaged_scenarios())
    assert load_study("design-map").factor_names == ("load", "pressure", "n")
    mc = load_study("montecarlo-family")
    assert mc.method == "montecarlo" and mc.factors[0].values[0] == pytest.approx(4e-3)
    sens = load_study("sensitivity-step")
    assert sens.method == "sobol-saltelli" and len(sens.factors) >= 8


@pytest.mark.parametrize(
    ("change", "fragments"),
    [
        # unknown names, with the nearest ones
        (("[study.grid]", '[study.grid]\n"aps.Ap" = ["1 mm^2"]'), ["aps.Ap", "aps.A_p"]),
        (("[study.grid]", '[study.grid]\nloda = ["1 g"]'), ["loda", "nearest: load"]),
        (('kind = "grid"', 'kind = "grid"\nseeds = 1'), ["study.seeds", "did you mean 'seed'"]),
        (('kind = "grid"', 'kind = "gird"'), ["'gird'", "did you mean 'grid'"]),
        # wrong units, bare numbers, out of range
        (('["0 g", "50 g"]', '["0 g", "50 mm"]'), ["study.grid.load", "50 mm", "convertible"]),
        (('["0 g", "50 g"]', '["0 g", 50]'), ["study.grid.load", "needs a unit"]),
        (('["0 g", "50 g"]', '["-10 g"]'), ["study.grid.load", "-0.01 kg", "[0, inf) kg"]),
        (('to = "0.1 MPa"', 'to = "0.7 MPa"'), ["study.grid.pressure", "700000 Pa", "600000"]),
        (
            ('["0 g", "50 g"]', '["0 g", "50 g"]\nn = [0, 1]'),
            ["study.grid.n", "0 is outside whole numbers in [1, 175]"],
        ),
        (('["0 g", "50 g"]', '["0 g", "50 g"]\nn = [1.5]'), ["study.grid.n", "whole numbers"]),
        (('["0 g", "50 g"]', '["0 g", "0 g"]'), ["study.grid.load", "repeat"]),
        (("num = 3", "num = 1"), ["study.grid.pressure.num", "1: expected an integer >= 2"]),
        (('kind = "grid"', 'kind = "grid"\nseed = 3'), ["study.seed", "remove it"]),
        # the size cap, with the numbers
        (('kind = "grid"', 'kind = "grid"\nmax_samples = 5'), ["6 samples", "max_samples = 5"]),
        (('base = "step-50g"', 'base = "step-5g"'), ["step-5g", "did you mean 'step-50g'"]),
        (('base = "step-50g"', 'base = "paper-static"'), ["'static'", "transient"]),
    ],
)
def test_bad_grid_is_one_line_naming_key_value_and_what_is_allowed(change, fragments):
    old, new = change
    assert old in GRID
    refused(GRID.replace(old, new, 1), *fragments)


@pytest.mark.parametrize(
    ("change", "fragments"),
    [
        (('uniform = ["600 N/m", "800 N/m"]', 'uniform = ["800 N/m", "600 N/m"]'), ["low < high"]),
        (
            ('uniform = ["600 N/m", "800 N/m"]', 'uniform = ["-1 N/m", "8 N/m"]'),
            ["(0, inf) N/m", "-1"],
        ),
        (('uniform = ["600 N/m", "800 N/m"]', 'uniform = ["600 mm", "8 N/m"]'), ["600 mm"]),
        (
            ('uniform = ["600 N/m", "800 N/m"]', 'normal = {mean = "700 N/m", std = "0 N/m"}'),
            ['study.factors."aps.k_s".normal.std', "must be > 0"],
        ),
        (
            ('uniform = ["600 N/m", "800 N/m"]', 'lognormal = {median = "700 N/m", sd = 0.1}'),
            ["unknown key 'sd'", "sigma"],
        ),
        (
            ('uniform = ["600 N/m", "800 N/m"]', 'uniform = ["6 N/m", "8 N/m"]\nlevels = [1]'),
            ["exactly one of"],
        ),
        (
            (
                '"aps.k_s"]\nuniform = ["600 N/m", "800 N/m"]',
                '"aps.r_lam"]\nuniform = ["0.9", "1.01"]\nrelative = true',
            ),
            [
                "1.01 is outside [0.500501, 1.001)",
                "multiplier of the scene's aps.r_lam = 0.999 1",
            ],
        ),
        (('method = "lhs"\ncount = 8', 'method = "sobol"\ncount = 12'), ["not a power of two"]),
        (("seed = 3\n", ""), ["study.seed", "missing"]),
        (('method = "lhs"', 'method = "halton"'), ["'halton'", "lhs, sobol, montecarlo"]),
        (('"aps.k_s"', "family"), ["levels"]),
        (
            ("[study.factors", '[study.factors.family]\nlevels = "all"\n[study.factors'),
            ["the family member sets aps.k_s", "relative = true"],
        ),
        (('"aps.k_s"', '"aps.thermal"'), ["aps.thermal", "nearest"]),
        (('"aps.k_s"', '"regulator.p_max"'), ["regulator.p_max", "built into the model"]),
        (
            (
                '"aps.k_s"]\nuniform = ["600 N/m", "800 N/m"]',
                '"aps.h_jz"]\nuniform = ["1 mm", "3 mm"]',
            ),
            ["'aps.h_jz' sets no parameter of this model", "thermal 'isothermal'"],
        ),
        (
            (
                '"aps.k_s"]\nuniform = ["600 N/m", "800 N/m"]',
                '"aps.C3"]\nuniform = ["0 Pa", "1 kPa"]',
            ),
            ["'aps.C3' is not a run-time parameter", "base value 0 Pa", "levels"],
        ),
    ],
)
def test_bad_sample_study_is_one_line(change, fragments):
    old, new = change
    assert old in SAMPLE
    refused(SAMPLE.replace(old, new, 1), *fragments)


def test_counts_that_are_allowed():
    assert parse(SAMPLE.replace("count = 8", "count = 12")).count == 12  # lhs: any count
    assert parse(SAMPLE.replace('"lhs"', '"sobol"')).count == 8  # a power of two


SENS = """
[study]
kind = "sensitivity"
base = "step-50g"
seed = 1
[study.sensitivity]
method = "sobol"
base_count = 8
metrics = ["stroke"]
[study.factors.load]
uniform = ["40 g", "60 g"]
[study.factors."aps.A_p"]
uniform = ["0.9", "1.1"]
relative = true
"""


def test_sensitivity_counts_and_its_metrics_are_added():
    s = parse(SENS)
    assert s.count == 8 * (2 + 2)  # Saltelli without second order: N (D + 2)
    assert "stroke" in [m.name for m in s.metrics]
    assert parse(SENS.replace('"sobol"', '"morris"')).count == 8 * 3  # N (D + 1)
    second = parse(SENS.replace("metrics = [", "second_order = true\nmetrics = ["))
    assert second.count == 8 * (2 * 2 + 2)


@pytest.mark.parametrize(
    ("old", "new", "fragments"),
    [
        ("base_count = 8", "base_count = 12", ["study.sensitivity.base_count", "12", "8 or 16"]),
        ('metrics = ["stroke"]', 'metrics = ["strok"]', ["strok", "did you mean 'stroke'"]),
        ('"sobol"', '"morris"\nlevels = 3', ["study.sensitivity.levels", "even"]),
        ("[study.factors.load]", "[study.factors.n]\nlevels = [1, 2]\n[study.factors.load]", []),
        ('kind = "sensitivity"', 'kind = "sensitivity"\nmax_samples = 10', ["32 samples"]),
    ],
)
def test_bad_sensitivity_is_one_line(old, new, fragments):
    assert old in SENS
    refused(SENS.replace(old, new, 1), *(fragments or ["continuous factors"]))


def test_metrics_and_series_checked_against_the_model():
    at = '{x = {signal = "myofibril.lenght", time = "1 s"}}'
    extra = f'[study.metrics]\nnames = ["stroke"]\nvalue_at = {at}\n'
    refused(GRID + extra, "myofibril.lenght", "did you mean 'myofibril.length'")
    late = '[study.metrics]\nvalue_at = {x = {signal = "myofibril.length", time = "3 s"}}\n'
    refused(GRID + late, "3 s is outside the simulation [0, 2] s")
    grid = '{from = "0 s", to = "2 s", num = 5}'
    series = f'[study.series]\nsignals = ["myofibril.length"]\ngrid = {grid}\n'
    s = parse(GRID + series)
    assert s.series.time == pytest.approx((0, 0.5, 1, 1.5, 2))
    refused(GRID + series.replace('"2 s"', '"5 s"'), "study.series.grid", "[0, 2] s")
    refused(GRID + '[study.metrics]\nnames = ["peak"]\n', "unknown metric 'peak'")


def test_scene_error_is_placed_in_the_study_or_the_base():
    message = refused(GRID + '[model]\nfidelity = "ful"\n', "study.toml", "model.fidelity")
    assert ":" in message.split("key")[0]
    auto = '[model]\nfidelity = "auto"\nn = 30\n'  # auto predicts each run's level
    refused(GRID + auto, "study.toml", "model.fidelity", "set it in the study file")
    assert parse(GRID + '[model]\nfidelity = "auto"\n').fidelity.startswith("auto: full")


def test_missing_file_is_a_study_error(tmp_path):
    with pytest.raises(StudyError, match="no such file or packaged study or scene"):
        load_study("no-such-study")
    with pytest.raises(StudyError, match="missing"):
        load_study(str(tmp_path / "x.toml"))


def test_parameters_and_signals_must_exist_at_every_n():
    n = "[study.grid]\nn = [2, 3]\n"
    refused(
        GRID.replace("[study.grid]", n.strip()) + "[study.metrics]\nvalue_at = {p3 = "
        '{signal = "myofibril.aps3.chamber.p_gauge", time = "1 s"}}\n',
        "study.grid.n",
        "n = 2 has no signal 'myofibril.aps3.chamber.p_gauge'",
    )
    refused(
        GRID.replace("[study.grid]", n.strip() + '\n"myofibril.tube3.C" = ["2e-9 m^3/(s*Pa)"]'),
        "no parameter 'myofibril.tube3.C' at n = 2",
    )


def test_base_is_a_scene_relative_to_the_study_file(tmp_path):
    scene = tmp_path / "scenes" / "mine.toml"
    scene.parent.mkdir()
    from sarcomere.scenarios.catalog import packaged_scenarios

    scene.write_text(packaged_scenarios()["step-50g"].read_text(encoding="utf-8"))
    study = tmp_path / "s.toml"
    study.write_text(GRID.replace('"step-50g"', '"scenes/mine.toml"'))
    assert load_study(study).scene_file == str(scene)
    study.write_text(GRID.replace('"step-50g"', '"design-map"'))  # a study is not a scene
    with pytest.raises(
        StudyError, match="s.toml: key 'study.base': 'design-map': no such file or packaged scene"
    ):
        load_study(study)
    scene.write_text("[scenario\n")
    study.write_text(GRID.replace('"step-50g"', '"scenes/mine.toml"'))
    with pytest.raises(StudyError, match="mine.toml: key '\\(toml syntax\\)': TOML syntax"):
        load_study(study)


def test_a_study_section_in_a_scene_file(tmp_path):
    from sarcomere.scenarios.catalog import packaged_scenarios

    scene = packaged_scenarios()["step-50g"].read_text(encoding="utf-8")
    path = tmp_path / "scene-study.toml"
    path.write_text(scene + '\n[study]\nkind = "grid"\n[study.grid]\nload = ["10 g", "30 g"]\n')
    s = load_study(path)
    assert s.base == "step-50g" and s.scene_file == str(path) and s.count == 2
    assert s.scene().name == "step-50g" and "study" not in s.definition()["scene"]
    path.write_text(scene.replace('kind = "transient"', 'kind = "transient"\nbogus = 1'))
    with pytest.raises(StudyError, match="missing the \\[study\\] table"):
        load_study(path)


@pytest.mark.parametrize(
    ("factors", "fragments"),
    [
        (
            '[study.factors.load]\nuniform = ["40 g", "60 g"]\n'
            '[study.factors."load.m"]\nuniform = ["40 g", "60 g"]\n',
            ["'load.m' and 'load' both set load.m", "keep one"],
        ),
        (
            '[study.factors."aps.A_p"]\nuniform = ["0.9", "1.1"]\nrelative = true\n'
            '[study.factors."myofibril.aps1.chamber.A"]\nuniform = ["10 mm^2", "20 mm^2"]\n',
            ["'myofibril.aps1.chamber.A' and 'aps.A_p' both set myofibril.aps1.chamber.A"],
        ),
        (
            '[study.factors.pressure]\nuniform = ["0.05 MPa", "0.1 MPa"]\n'
            '[study.factors."regulator.p_cmd"]\nuniform = ["0.05 MPa", "0.1 MPa"]\n',
            ["'regulator.p_cmd' and 'pressure' both set regulator.p_cmd"],
        ),
    ],
)
def test_two_factors_setting_the_same_parameter_are_refused_naming_both(factors, fragments):
    """Issue 24, bug 1: one of the two silently did nothing."""
    head = SAMPLE.split("[study.factors")[0]
    refused(head + factors, *fragments)


def test_the_regulator_command_is_a_factor_by_either_name():
    """``pressure`` is the scene's alias of the input ``regulator.p_cmd``: one kind of
    factor (an input's step or ramp level), by either name."""
    by_alias = parse(GRID)
    by_name = parse(GRID.replace("pressure = ", '"regulator.p_cmd" = '))
    assert by_name.factors[1].values == by_alias.factors[1].values
    assert by_name.factors[1].unit == "Pa"


def test_a_series_signal_given_twice_is_refused():
    """Issue 24, bug 3: a repeated signal crashed with zarr's ContainsArrayError."""
    grid = '{from = "0 s", to = "2 s", num = 5}'
    twice = '["myofibril.length", "myofibril.length"]'
    refused(
        GRID + f"[study.series]\nsignals = {twice}\ngrid = {grid}\n",
        "study.series.signals",
        "'myofibril.length' is given twice",
    )
