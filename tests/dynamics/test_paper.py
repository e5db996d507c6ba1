"""Tests of sarcomere.dynamics.paper: the paper's static model and its reported numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.paper import (
    PaperOptions,
    max_length_ratio,
    myofibril_length,
    paper_static,
    rest_length,
    theta_rest,
    wall_factor,
)
from sarcomere.dynamics.paper_reported import (
    REPORTED,
    TABLE1,
    comparison_table,
    implied_gains,
    table1_mean_max_force,
)
from sarcomere.dynamics.params import experimental_geometry, fem_geometry, get_material

MPA = 1e6
FIXED = PaperOptions(force_scale=1e-3)


@pytest.fixture(scope="module")
def geo():
    return experimental_geometry()


# --- geometry and kinematics -------------------------------------------------------------
def test_theta_rest_corrected_and_printed(geo):
    assert math.degrees(theta_rest(geo, PaperOptions(theta="corrected"))) == pytest.approx(
        51.32, abs=0.005
    )
    assert math.degrees(theta_rest(geo)) == pytest.approx(67.98, abs=0.005)


def test_rest_length_three_aps(geo):
    L = rest_length(3, geo)
    assert L == pytest.approx(164.94e-3, abs=0.1e-3)
    assert L == pytest.approx(REPORTED["rest_length_3aps_m"], abs=0.1e-3)
    assert rest_length(3, geo, "band_ratio") == pytest.approx(150e-3)
    assert rest_length(3, geo, "ellipse_corrected") == pytest.approx(152.2e-3, abs=0.1e-3)
    with pytest.raises(ParameterError, match="no real solution"):
        rest_length(3, geo, "ellipse")
    with pytest.raises(ParameterError):
        rest_length(0, geo)


def test_stretch_bound_unreachable(geo):
    assert max_length_ratio(geo) == pytest.approx(1.128, abs=1e-3)
    assert max_length_ratio(geo) < REPORTED["length_ratio_bounds"][1]


def test_myofibril_shortens_with_pressure(geo):
    L = myofibril_length(3, np.array([0.0, 0.05, 0.1]) * MPA, geo, "dragonskin_30", FIXED)
    assert L[0] == pytest.approx(rest_length(3, geo))
    assert np.all(np.diff(L) < 0)
    assert L[-1] / L[0] == pytest.approx(0.936, abs=1e-3)  # measured 0.875


def test_triangle_kinematics_closes(geo):
    r = paper_static(np.linspace(0, 0.1, 5) * MPA, geo, "dragonskin_30", FIXED)
    np.testing.assert_allclose(r.r1_m**2 + r.r2_m**2, (geo["l"] / 2) ** 2, rtol=1e-12)
    # with the corrected theta, cos(theta) = 2 r2 / l and F_contr = F_SPA r1/r2
    rc = paper_static(np.linspace(0, 0.1, 5) * MPA, geo, "dragonskin_30", PaperOptions.corrected())
    np.testing.assert_allclose(np.cos(rc.theta_rad), 2 * rc.r2_m / geo["l"], rtol=1e-12)


def test_printed_ellipse_raises_with_reason(geo):
    with pytest.raises(ParameterError) as err:
        paper_static(0.0, geo, "dragonskin_30", PaperOptions(kinematics="ellipse"))
    assert "h_m/2 = 14 mm" in str(err.value) and "l = 32 mm" in str(err.value)


def test_corrected_ellipse_arc_length(geo):
    from scipy.integrate import quad

    r = paper_static(0.05 * MPA, geo, "dragonskin_30", PaperOptions(kinematics="ellipse_corrected"))
    a, b = float(r.r1_m), float(r.r2_m)
    arc = quad(lambda t: math.hypot(b * math.sin(t), a * math.cos(t)), 0, math.pi)[0]
    assert arc == pytest.approx(geo["l"], rel=1e-9)


# --- the K rule --------------------------------------------------------------------------
def test_wall_factor_both_sides_of_quarter():
    h = 8e-3
    thin = wall_factor(0.99 * h / 4, h)
    assert thin == pytest.approx(h / (2 * 0.99 * h / 4))
    at = wall_factor(h / 4, h)  # t_w = h_ch/4 is thick-walled (strict '<')
    assert at == pytest.approx(1 + h**2 / (2 * (h / 4) * (h / 4 + h)))
    assert at == pytest.approx(2.6)
    thick = wall_factor(1.5e-3, 5e-3)  # experimental APS
    assert thick == pytest.approx(1 + 25 / (2 * 1.5 * 6.5))


# --- forces ------------------------------------------------------------------------------
def test_printed_force_is_about_1000x(geo):
    r = paper_static(0.1 * MPA, geo, "dragonskin_30", PaperOptions())
    assert float(r.F_spa_N) == pytest.approx(314.4, rel=1e-3)


def test_measured_isometric_force_one_aps(geo):
    r = paper_static(0.1 * MPA, geo, "dragonskin_30", PaperOptions(force_scale=1e-3))
    assert float(r.F_spa_N) == pytest.approx(0.315, rel=0.05)
    assert float(r.lambda_jz) == pytest.approx(1.934, abs=1e-3)
    assert float(r.c_m) == pytest.approx(10.0999, abs=1e-4)
    # with use_tan=False the contraction force is F_SPA
    r2 = paper_static(
        0.1 * MPA, geo, "dragonskin_30", PaperOptions(force_scale=1e-3, use_tan=False)
    )
    assert float(r2.F_contr_N) == pytest.approx(float(r.F_spa_N))


def test_restoring_force_equals_wall_force_by_construction(geo):
    r = paper_static(np.linspace(-0.05, 0.1, 7) * MPA, geo, "dragonskin_30", FIXED)
    np.testing.assert_allclose(r.F_r_N, r.F_e_wall_N, rtol=1e-9, atol=1e-15)


def test_force_scale_scales_forces_only(geo):
    p = np.array([0.02, 0.1]) * MPA
    a = paper_static(p, geo, "dragonskin_30", PaperOptions())
    b = paper_static(p, geo, "dragonskin_30", FIXED)
    np.testing.assert_allclose(b.F_spa_N, 1e-3 * a.F_spa_N)
    np.testing.assert_allclose(b.F_contr_N, 1e-3 * a.F_contr_N)
    np.testing.assert_array_equal(a.lambda_jz, b.lambda_jz)
    np.testing.assert_array_equal(a.theta_rad, b.theta_rad)


def test_cm_pressure_in_kpa_gives_negative_force(geo):
    r = paper_static(0.1 * MPA, geo, "dragonskin_30", PaperOptions(cm_pressure_unit="kPa"))
    assert float(r.F_spa_N) < 0


def test_result_shapes_and_names(geo):
    r = paper_static(np.zeros((2, 3)), geo, "dragonskin_30")
    for name in (
        "lambda_jz",
        "sigma_w_Pa",
        "K",
        "c_m",
        "F_e_N",
        "F_r_N",
        "F_spa_N",
        "theta_rad",
        "F_contr_N",
        "r1_m",
        "r2_m",
    ):
        assert r[name].shape == (2, 3), name
    assert np.all(r.lambda_jz == 1.0) and np.all(r.F_spa_N == 0.0)
    with pytest.raises(ParameterError):
        r["F_spa"]


def test_fem_geometry_has_no_thread_outputs():
    r = paper_static(0.04 * MPA, fem_geometry(0.5), "elastosil_m4601", FIXED)
    assert r.theta_rad is None and r.F_contr_N is None and float(r.F_spa_N) > 0


# --- Table 1 -----------------------------------------------------------------------------
@pytest.mark.parametrize("slug", sorted(TABLE1))
def test_table1_mean_max_force(slug):
    ours = table1_mean_max_force(slug, FIXED)
    assert ours == pytest.approx(TABLE1[slug].analytical_force_N, rel=0.05)
    assert ours == pytest.approx(TABLE1[slug].analytical_force_N, rel=0.025)


def test_table1_other_readings_do_not_match():
    f = table1_mean_max_force("smooth_sil_950", FIXED, pressure_reading="sweep_max")
    assert f / TABLE1["smooth_sil_950"].analytical_force_N > 2.0
    with pytest.raises(ParameterError, match="no stretch"):
        table1_mean_max_force("ecoflex_00_30", FIXED, pressure_reading="sweep_max")
    with pytest.raises(ParameterError):
        table1_mean_max_force("dragonskin_30", FIXED)


# --- reported numbers that contradict each other -----------------------------------------
def test_implied_gains_contradict_reported():
    g = implied_gains()
    assert g[2] == pytest.approx(0.176, abs=1e-3) and g[3] == pytest.approx(0.093, abs=1e-3)
    assert REPORTED["gain_over_n_single"] == {2: 0.1345, 3: 0.1939}


def test_comparison_table_rows():
    rows = comparison_table()
    assert all({"quantity", "reported", "ours", "option", "status"} <= set(r) for r in rows)
    statuses = {r["quantity"]: r["status"] for r in rows}
    assert statuses["3-APS rest length, mm"] == "reproduced"
    assert statuses["F (1 APS, 0.1 MPa), N: F_SPA as printed"] == "inconsistent in the paper"


# --- bad input ---------------------------------------------------------------------------
@pytest.mark.parametrize("p", [-2e5, float("nan"), float("inf"), [0.0, -1.1e5]])
def test_bad_pressure(geo, p):
    with pytest.raises(ParameterError) as err:
        paper_static(p, geo)
    assert "pressure_Pa" in str(err.value) and "-101325" in str(err.value)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"theta": "exact"},
        {"kinematics": "circle"},
        {"force_scale": 0.0},
        {"force_scale": float("nan")},
        {"use_tan": "yes"},
        {"cm_pressure_unit": "psi"},
    ],
)
def test_bad_options(kwargs):
    with pytest.raises(ParameterError) as err:
        PaperOptions(**kwargs)
    assert next(iter(kwargs)) in str(err.value)


def test_span_beyond_thread_is_an_error(geo):
    # 2 r2 = 20 mm + 4 (lambda - 1) mm reaches l = 32 mm near lambda = 4 (about 0.6 MPa)
    with pytest.raises(ParameterError, match="pressure_Pa"):
        paper_static(1.0 * MPA, geo, "dragonskin_30", PaperOptions.corrected())


def test_material_objects_and_slugs_agree(geo):
    a = paper_static(0.05 * MPA, geo, "dragonskin_30_alt", FIXED)
    b = paper_static(0.05 * MPA, geo, get_material("dragonskin_30_alt"), FIXED)
    assert float(a.F_spa_N) == float(b.F_spa_N)
