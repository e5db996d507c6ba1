"""evaluate_batch: metrics against a direct run of the equivalent scene, a failing sample
recorded without stopping the batch, the model flattened once per structure."""

import pickle
import textwrap

import numpy as np
import pytest

from sarcomere.scenarios import binding, step_metrics
from sarcomere.scenarios.catalog import packaged_scenarios
from sarcomere.scenarios.explore import evaluate, factors, metrics, spec
from sarcomere.scenarios.explore.evaluate import evaluate_batch
from sarcomere.scenarios.loader import parse_scenario

HEAD = '[study]\nkind = "grid"\nbase = "step-50g"\n'


def study(body: str):
    return spec.parse_study(HEAD + textwrap.dedent(body), "/nonexistent/s.toml")


@pytest.fixture
def fresh_caches():
    """Forget the models, probes and bound scenes of this process."""
    for cache in (factors.model_for, factors.aps_map, factors._bound, evaluate._context):
        cache.cache_clear()
    yield


def test_sample_equals_the_scene_run_with_the_same_values():
    s = study(
        """
        [study.grid]
        load = ["20 g"]
        pressure = ["0.08 MPa"]
        "aps.k_s" = ["760 N/m"]
        "myofibril.tube2.C" = ["2.5e-9 m^3/(s*Pa)"]
        [study.metrics]
        value_at = {mid = {signal = "myofibril.aps2.chamber.p_gauge", time = "0.15 s"}}
        [study.series]
        signals = ["myofibril.length"]
        grid = {from = "0 s", to = "2 s", num = 11}
        """
    )
    got = evaluate_batch(s, [0])
    assert got.status.tolist() == [0] and got.error == [""]
    # the same point written as a scene: APSParams rebuilt, load as an option
    text = (
        packaged_scenarios()["step-50g"]
        .read_text(encoding="utf-8")
        .replace('load = "50 g"', 'load = "20 g"')
        .replace('final = "0.1 MPa"', 'final = "0.08 MPa"')
    )
    text += '\n[parameters]\n"aps.k_s" = "760 N/m"\n"myofibril.tube2.C" = "2.5e-9 m^3/(s*Pa)"\n'
    sc = parse_scenario(text, "scene.toml")
    res = binding.simulate_scene(sc, binding.bind(sc), "full")
    L = res["myofibril.length"]
    assert got.metrics["length_final"][0] == pytest.approx(L[-1], abs=1e-8)  # atol 1e-9 m
    assert got.metrics["stroke"][0] == pytest.approx(L[0] - L[-1], rel=1e-6)
    rise, _ = step_metrics.rise_time(res.index, L, step_metrics.RISE_MIN_STROKE_M)
    assert got.metrics["rise_time"][0] == pytest.approx(rise, rel=1e-6)
    T = np.array([res[n] for n in metrics.tensions(res.names)])
    assert got.metrics["peak_tension"][0] == pytest.approx(T.max(), rel=1e-7)
    assert got.metrics["min_tension"][0] == pytest.approx(T.min(), rel=1e-7)
    p = np.array([res[n] for n in metrics.pressures(res.names)])
    assert got.metrics["peak_pressure"][0] == pytest.approx(p.max(), rel=1e-7)
    mid = np.interp(0.15, res.index, res["myofibril.aps2.chamber.p_gauge"])
    assert got.metrics["mid"][0] == pytest.approx(mid, rel=1e-7)
    np.testing.assert_allclose(
        got.series["myofibril.length"][0], np.interp(got.series_time, res.index, L), rtol=1e-9
    )
    assert got.series_time.tolist() == pytest.approx(np.linspace(0, 2, 11).tolist())


def test_air_mass_is_the_chambers_gain_about_p_v_over_r_t():
    s = study('[study.grid]\npressure = ["0.1 MPa"]\n[study.metrics]\nnames = ["air_mass"]\n')
    air = evaluate_batch(s, [0]).metrics["air_mass"][0]
    # isothermal chambers: about p V / (R T) each at 0.1 MPa gauge, V about V0 = 4 cm^3
    assert 3 * 1e5 * 4e-6 / (287.0 * 293.15) == pytest.approx(air, rel=0.15)


def test_a_failing_sample_is_recorded_and_the_batch_goes_on():
    s = study(
        """
        [study.grid]
        pressure = ["0 MPa", "0.1 MPa", "0.05 MPa"]
        [study.metrics]
        names = ["stroke", "rise_time"]
        [solver]
        max_steps = 50
        """
    )
    got = evaluate_batch(s, np.array([0, 1]))
    assert got.indices.tolist() == [0, 1]
    assert got.status.tolist() == [0, 1] and got.status.dtype == np.int8
    assert (
        got.error[1].startswith("SolverError: cvodes: too many steps") and "\n" not in got.error[1]
    )
    assert np.isnan(got.metrics["stroke"][1]) and np.isnan(got.metrics["rise_time"][1])
    # the sample that ran: no stroke at 0 MPa, so no rise time, and the note says why
    assert abs(got.metrics["stroke"][0]) < 1e-12 and np.isnan(got.metrics["rise_time"][0])
    assert got.error[0].startswith("rise_time: the net stroke")
    again = pickle.loads(pickle.dumps(got))
    assert again.error == got.error and np.array_equal(again.status, got.status)


def test_the_model_is_built_once_per_structure(fresh_caches):
    before = dict(factors.BUILDS)
    s = study(
        """
        [study.grid]
        load = ["30 g", "60 g"]
        pressure = ["0.09 MPa", "0.11 MPa"]
        "aps.A_p" = ["2.5 mm^2", "2.7 mm^2"]
        [study.metrics]
        names = ["stroke"]
        """
    )
    assert factors.BUILDS["models"] - before["models"] == 1  # the base model, to check
    got = evaluate_batch(s, np.arange(8))
    assert got.status.tolist() == [0] * 8
    assert factors.BUILDS["models"] - before["models"] == 1  # reused for all eight
    assert factors.BUILDS["probes"] - before["probes"] == 1  # aps.A_p's parameters, once
    evaluate_batch(s, np.arange(8))
    assert factors.BUILDS["models"] - before["models"] == 1
    strokes = got.metrics["stroke"]
    assert len(set(np.round(strokes, 12))) == 8  # every sample differs
    n = study('[study.grid]\nn = [1, 2, 3]\n[study.metrics]\nnames = ["stroke"]\n')
    evaluate_batch(n, np.arange(3))
    assert factors.BUILDS["models"] - before["models"] == 3  # n = 1 and 2 are new


def test_family_member_with_a_relative_tolerance_equals_the_scene_run():
    from sarcomere.scenarios.explore.designs import family_member

    rel = spec.parse_study(
        HEAD.replace('"grid"', '"sample"')
        + "seed = 1\n"
        + textwrap.dedent(
            """
            [study.sample]
            method = "montecarlo"
            count = 1
            [study.factors.family]
            levels = ["8 mm"]
            [study.factors."aps.A_p"]
            levels = [1.05]
            relative = true
            [study.factors."aps.C_tube"]
            levels = [0.9]
            relative = true
            [study.metrics]
            names = ["length_final", "stroke"]
            """
        ),
        "/nonexistent/s.toml",
    )
    got = evaluate_batch(rel, [0])
    assert got.status.tolist() == [0]
    member = family_member(8e-3)
    values = {**member, "A_p": member["A_p"] * 1.05, "C_tube": 2.0e-9 * 0.9}
    text = packaged_scenarios()["step-50g"].read_text(encoding="utf-8") + "\n[parameters]\n"
    text += "".join(f'"aps.{k}" = "{v!r} {unit}"\n' for k, v, unit in _units(values))
    sc = parse_scenario(text, "scene.toml")
    res = binding.simulate_scene(sc, binding.bind(sc), "full")
    L = res["myofibril.length"]
    # the same parameters to an ulp; the runs agree within the solver's atol (1e-9 m)
    model, over, _ = factors.scene_context(rel.scene()).apply(rel.factors, rel.design().points[0])
    direct = binding.bind(sc).build("full")
    np.testing.assert_allclose(model.parameters(over), direct.parameters(), rtol=1e-15)
    assert got.metrics["length_final"][0] == pytest.approx(L[-1], abs=1e-8)
    assert got.metrics["stroke"][0] == pytest.approx(L[0] - L[-1], rel=1e-6)


def _units(values: dict):
    from sarcomere.dynamics.components.aps import APSParams

    return [(k, v, APSParams.unit(k)) for k, v in values.items()]


def test_points_given_by_the_caller_skip_the_design(fresh_caches):
    s = study(
        '[study.grid]\npressure = ["0.09 MPa", "0.1 MPa"]\n[study.metrics]\nnames = ["stroke"]\n'
    )
    rows = np.array([[1e5]])
    given = evaluate_batch(s, [1], points=rows)
    assert evaluate.context(s)._design is None  # never made here
    assert given.metrics["stroke"].tolist() == evaluate_batch(s, [1]).metrics["stroke"].tolist()


def test_a_structural_aps_field_builds_one_model_per_level(fresh_caches):
    s = study(
        '[study.grid]\n"aps.C3" = ["0 Pa", "2 kPa"]\n[study.metrics]\nnames = ["length_final"]\n'
    )
    before = factors.BUILDS["models"]
    got = evaluate_batch(s, [0, 1])
    assert factors.BUILDS["models"] - before == 1  # C3 = 0 is the base model
    text = packaged_scenarios()["step-50g"].read_text(encoding="utf-8")
    sc = parse_scenario(text + '\n[parameters]\n"aps.C3" = "2 kPa"\n', "scene.toml")
    L = binding.simulate_scene(sc, binding.bind(sc), "full")["myofibril.length"]
    assert got.metrics["length_final"][1] == pytest.approx(L[-1], abs=1e-8)
    assert abs(got.metrics["length_final"][1] - got.metrics["length_final"][0]) > 1e-6


def test_a_sample_does_not_depend_on_the_samples_run_before_it():
    s = study(
        '[study.grid]\nload = ["20 g", "50 g", "80 g"]\n[study.metrics]\nnames = ["stroke"]\n'
    )
    alone = evaluate_batch(s, [1]).metrics["stroke"][0]
    batch = evaluate_batch(s, [2, 0, 1]).metrics["stroke"]
    assert batch[2] == alone  # bitwise: a resumed study equals an uninterrupted one
