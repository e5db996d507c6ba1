"""Designs: counts, bounds, grid order, reproducibility with the seed, the distributions'
moments, SALib's designs, and the calibration family's members."""

import textwrap
from dataclasses import replace

import numpy as np
import pytest

from sarcomere.scenarios.explore import designs
from sarcomere.scenarios.explore.spec import Factor, parse_study


def study(kind: str, body: str, seed: int | None = 7):
    head = f'[study]\nkind = "{kind}"\nbase = "step-50g"\n'
    if seed is not None:
        head += f"seed = {seed}\n"
    return parse_study(head + textwrap.dedent(body), "/nonexistent/s.toml")


FACTORS = """
[study.factors.load]
uniform = ["40 g", "60 g"]
[study.factors."aps.c_s"]
normal = {mean = "0.5 N*s/m", std = "0.02 N*s/m"}
[study.factors."aps.V0"]
lognormal = {median = "4 cm^3", sigma = 0.05}
[study.factors.family]
levels = ["8 mm", "20 mm", "34 mm"]
"""


def test_grid_is_the_full_factorial_in_c_order():
    pts = designs.grid_points([[1, 2], [10, 20, 30]])
    expected = [[1, 10], [1, 20], [1, 30], [2, 10], [2, 20], [2, 30]]
    np.testing.assert_array_equal(pts, expected)
    s = study(
        "grid",
        '[study.grid]\nn = [1, 2]\nload = ["0 g", "50 g"]\n'
        'pressure = {from = "0.05 MPa", to = "0.1 MPa", num = 3}\n',
        seed=None,
    )
    d = s.design()
    assert d.grid_shape == (2, 2, 3) and d.points.shape == (12, 3) and d.method == "grid"
    assert d.factor_names == ("n", "load", "pressure")
    # C order: the last factor varies fastest; reshaping gives the axes back
    cube = d.points.reshape(2, 2, 3, 3)
    np.testing.assert_array_equal(cube[:, 0, 0, 0], [1, 2])
    np.testing.assert_allclose(cube[0, 0, :, 2], [5e4, 7.5e4, 1e5])
    np.testing.assert_allclose(cube[0, :, 0, 1], [0.0, 0.05])


@pytest.mark.parametrize(("method", "count"), [("lhs", 64), ("sobol", 64), ("montecarlo", 64)])
def test_samples_are_seeded_within_bounds_and_on_the_levels(method, count):
    body = f'[study.sample]\nmethod = "{method}"\ncount = {count}\n' + FACTORS
    a, b = study("sample", body).design(), study("sample", body).design()
    np.testing.assert_array_equal(a.points, b.points)  # reproducible
    other = study("sample", body, seed=8).design()
    assert not np.array_equal(a.points, other.points)
    assert a.points.shape == (count, 4) and a.method == method
    load = a.points[:, 0]
    assert load.min() >= 0.04 and load.max() <= 0.06
    assert set(np.round(a.points[:, 3], 6)) <= {0.008, 0.02, 0.034}
    assert np.all(a.points[:, 2] > 0)


def test_latin_hypercube_has_one_point_per_stratum():
    d = study("sample", '[study.sample]\nmethod = "lhs"\ncount = 16\n' + FACTORS).design()
    strata = np.floor((d.points[:, 0] - 0.04) / 0.02 * 16).astype(int)
    assert sorted(strata) == list(range(16))


def test_distributions_have_their_moments():
    u = designs.unit_cube("montecarlo", 3, 20000, 1)
    factors = (
        Factor("a", "m", "continuous", dist="normal", args=(2.0, 0.5)),
        Factor("b", "m", "continuous", dist="lognormal", args=(3.0, 0.2)),
        Factor("c", "1", "discrete", values=(1.0, 2.0, 4.0)),
    )
    x = designs.to_factors(u, factors)
    assert abs(x[:, 0].mean() - 2.0) < 0.02 and abs(x[:, 0].std() - 0.5) < 0.02
    assert abs(np.median(x[:, 1]) - 3.0) < 0.03 and abs(np.log(x[:, 1]).std() - 0.2) < 0.01
    counts = np.array([np.sum(x[:, 2] == v) for v in (1.0, 2.0, 4.0)]) / len(x)
    np.testing.assert_allclose(counts, 1 / 3, atol=0.02)


SENS = """
[study.sensitivity]
method = "{method}"
base_count = 16
metrics = ["stroke"]
[study.factors.load]
uniform = ["40 g", "60 g"]
[study.factors."aps.k_s"]
uniform = ["0.9", "1.1"]
relative = true
[study.factors."aps.C_tube"]
uniform = ["0.9", "1.1"]
relative = true
"""


def test_saltelli_design_matches_salib_and_its_count():
    from SALib.sample import sobol

    s = study("sensitivity", SENS.format(method="sobol"))
    d = s.design()
    assert d.method == "sobol-saltelli" and d.points.shape == (16 * (3 + 2), 3) == (s.count, 3)
    assert d.salib_problem["names"] == ["load", "aps.k_s", "aps.C_tube"]
    assert d.salib_problem["bounds"] == [[0.04, 0.06], [0.9, 1.1], [0.9, 1.1]]
    assert d.salib_options == {"calc_second_order": False}
    again = sobol.sample(d.salib_problem, 16, calc_second_order=False, seed=7)
    np.testing.assert_array_equal(d.points, again)
    assert d.points[:, 0].min() >= 0.04 and d.points[:, 0].max() <= 0.06


def test_morris_design_is_on_its_level_grid():
    s = study("sensitivity", SENS.format(method="morris"))
    d = s.design()
    assert d.method == "morris" and d.points.shape == (16 * 4, 3) == (s.count, 3)
    assert d.salib_options == {"num_levels": 4}
    levels = np.round((d.points[:, 1] - 0.9) / 0.2 * 3, 9)  # 4 levels: 0, 1/3, 2/3, 1
    assert set(levels) <= {0.0, 1.0, 2.0, 3.0}


def test_family_members_meet_the_calibration_targets():
    from sarcomere.dynamics.calibration import FAMILY_L_R, TARGETS, evaluate
    from sarcomere.dynamics.components.aps import APSParams

    assert tuple(m.L_r for m in designs.FAMILY) == FAMILY_L_R
    base = APSParams.from_paper()
    for m in designs.FAMILY:
        got = evaluate(replace(base, **designs.family_member(m.L_r)))
        for key, target in TARGETS.items():
            assert got[key] == pytest.approx(target, rel=1e-6), (m.L_r, key)
    with pytest.raises(KeyError, match="no calibration family member"):
        designs.family_member(5e-3)


def test_normal_draws_outside_the_range_are_refused_before_work():
    from sarcomere.scenarios.explore.spec import StudyError

    body = '[study.sample]\nmethod = "montecarlo"\ncount = 64\n'
    body += '[study.factors."aps.k_s"]\nnormal = {mean = "700 N/m", std = "500 N/m"}\n'
    s = study("sample", body)
    with pytest.raises(StudyError, match=r'factors."aps.k_s".normal\': sample \d+ draws -?\d'):
        s.design()
    narrow = study("sample", body.replace("500 N/m", "50 N/m"))
    assert narrow.design().points.min() > 0
