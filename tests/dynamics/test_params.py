"""Tests of sarcomere.dynamics.params: Param, ParameterSet, geometry, materials, ambient."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.params import (
    FEM_H_CH_ESTIMATE_M,
    MATERIALS,
    Ambient,
    Param,
    ParameterSet,
    YeohMaterial,
    cauchy_stress,
    cauchy_stress_inverse,
    experimental_geometry,
    fem_geometry,
    get_material,
    monotone_branch,
    strain_energy,
    stress_slope,
    true_cauchy_stress,
)

MM = 1e-3


# --- Param ------------------------------------------------------------------------------
def test_param_rejects_value_outside_range_and_names_range():
    with pytest.raises(ParameterError) as err:
        Param("t_w", 0.0, unit="m", low=0.0, low_open=True, source="test")
    msg = str(err.value)
    assert "t_w" in msg and "0.0" in msg and "(0, inf) m" in msg


def test_param_rejects_nan_and_bool():
    with pytest.raises(ParameterError):
        Param("x", float("nan"))
    with pytest.raises(ParameterError):
        Param("x", True)


def test_param_closed_and_open_bounds():
    p = Param("r", 1.0, low=0.0, high=1.0)
    assert p.range_str == "[0, 1]"  # closed by default; no unit when dimensionless
    with pytest.raises(ParameterError, match=r"'r' = 1.0 .*allowed: \(0, 1\)$"):
        Param("r", 1.0, low=0.0, high=1.0, low_open=True, high_open=True)


# --- ParameterSet ------------------------------------------------------------------------
def test_getitem_returns_float_and_param_returns_param():
    g = experimental_geometry()
    assert g["a_ch"] == pytest.approx(9.5 * MM)
    assert isinstance(g.param("a_ch"), Param)
    assert g.param("a_ch").unit == "m"
    assert g.values()["l"] == pytest.approx(32 * MM)
    assert list(g) == g.keys()


def test_experimental_geometry_values_in_si():
    g = experimental_geometry()
    expected_mm = dict(
        A=30, h_m=28, a_ch=9.5, b_ch=10, a_hz=6, b_hz=15, h_jz=2, t_w=1.5, h_ch=5, l=32
    )
    for name, mm in expected_mm.items():
        assert g[name] == pytest.approx(mm * MM, rel=1e-12), name
        assert "Experimental Setup" in g.param(name).source


def test_h_m_is_derived_28_mm_and_follows_overrides():
    g = experimental_geometry()
    assert g["h_m"] == pytest.approx(28 * MM, rel=1e-12)
    g2 = g.with_overrides({"t_w": "1.0 mm"})
    assert g2["h_m"] == pytest.approx(3 * (2 * 1.0 + 5) * MM + 2 * 2 * MM)
    with pytest.raises(ParameterError, match="derived"):
        g.with_overrides({"h_m": 0.03})


def test_overrides_with_units_and_si_floats():
    g = experimental_geometry().with_overrides({"a_ch": "9.5 mm", "b_ch": 0.011, "l": "3.3 cm"})
    assert g["a_ch"] == pytest.approx(9.5 * MM)
    assert g["b_ch"] == pytest.approx(11 * MM)
    assert g["l"] == pytest.approx(33 * MM)
    # the original is unchanged (immutability)
    assert experimental_geometry()["b_ch"] == pytest.approx(10 * MM)


def test_unknown_key_lists_valid_keys_and_suggests():
    with pytest.raises(ParameterError) as err:
        experimental_geometry().with_overrides({"h_chh": 0.005})
    msg = str(err.value)
    assert "h_chh" in msg and "did you mean 'h_ch'" in msg and "a_ch" in msg
    with pytest.raises(ParameterError):
        experimental_geometry()["nope"]


def test_wrong_dimension_is_rejected():
    with pytest.raises(ParameterError, match="wrong dimension"):
        experimental_geometry().with_overrides({"a_ch": "3 kg"})


@pytest.mark.parametrize("value", [0.0, -1e-3, "-2 mm"])
def test_non_positive_length_is_rejected(value):
    with pytest.raises(ParameterError, match=r"\(0, inf\) m"):
        experimental_geometry().with_overrides({"h_jz": value})


def test_anchors_wider_than_thread_rejected():
    # 2 r2' = h_m - 2 t_w - h_ch = 20 mm at rest; a 20 mm thread cannot span it
    with pytest.raises(ParameterError) as err:
        experimental_geometry().with_overrides({"l": "20 mm"})
    msg = str(err.value)
    assert "2 r2'" in msg and "20 mm" in msg and "l = 20 mm" in msg
    # thicker walls push the anchors apart: 2 r2' = 2 (2 t_w + h_ch) + 2 h_jz = 34 mm
    with pytest.raises(ParameterError, match="34 mm"):
        experimental_geometry().with_overrides({"t_w": "5 mm"})
    # just inside is fine
    assert experimental_geometry().with_overrides({"l": "20.5 mm"})["l"] == pytest.approx(0.0205)


def test_derived_value_must_match_rule():
    from sarcomere.dynamics.params import Derived

    rule = Derived(lambda v: 2 * v["a"], "2 a", ("a",))
    with pytest.raises(ParameterError, match="disagrees"):
        ParameterSet([Param("a", 1.0), Param("b", 3.0)], derived={"b": rule})
    ps = ParameterSet([Param("a", 1.0), Param("b", 2.0)], derived={"b": rule})
    assert ps.with_overrides({"a": 4.0})["b"] == 8.0


def test_fem_geometry():
    f = fem_geometry(0.5)
    assert f["h_ch"] == pytest.approx(FEM_H_CH_ESTIMATE_M)
    assert f["t_w"] == pytest.approx(0.5 * FEM_H_CH_ESTIMATE_M)
    assert f["a_ch"] == f["b_ch"] == pytest.approx(14 * MM)
    assert f["b_hz"] == pytest.approx(20 * MM) and f["h_jz"] == pytest.approx(3 * MM)
    assert "l" not in f and "A" not in f
    assert "estimated" in f.param("h_ch").source
    assert fem_geometry(1.0, "7 mm")["t_w"] == pytest.approx(7 * MM)
    with pytest.raises(ParameterError):
        fem_geometry(0.0)
    with pytest.raises(ParameterError):
        fem_geometry(0.5, "7 kg")


# --- materials ---------------------------------------------------------------------------
def test_material_catalogue():
    ds = get_material("dragonskin_30")
    assert (ds.C1, ds.C2, ds.density) == (0.096e6, 0.0095e6, 1080.0)
    alt = get_material("dragonskin_30_alt")
    assert (alt.C1, alt.C2) == pytest.approx((0.1536e6, 0.0016e6))
    eco = get_material("ecoflex_00_30")
    assert (eco.C1, eco.C2, eco.C3, eco.density) == pytest.approx(
        (0.017e6, -0.0002e6, 0.000023e6, 1070.0)
    )
    assert get_material("elastosil_m4601").C2 == pytest.approx(0.02e6)
    assert get_material("smooth_sil_950").density == 1240.0
    assert set(MATERIALS) == {
        "dragonskin_30",
        "dragonskin_30_alt",
        "ecoflex_00_30",
        "elastosil_m4601",
        "smooth_sil_950",
    }


def test_unknown_material_lists_slugs():
    with pytest.raises(ParameterError) as err:
        get_material("dragon_skin_30")
    assert "dragonskin_30" in str(err.value) and "smooth_sil_950" in str(err.value)


def test_material_validation():
    with pytest.raises(ParameterError):
        YeohMaterial("x", "x", -1.0, 0.0, 0.0, 1000.0, "test")
    with pytest.raises(ParameterError):
        YeohMaterial("x", "x", 1.0, 0.0, 0.0, 0.0, "test")


@pytest.mark.parametrize("slug", sorted(MATERIALS))
@pytest.mark.parametrize("include_c3", [False, True])
def test_printed_stress_is_dW_dlambda(slug, include_c3):
    """The paper's 'cauchyStress' is dW/dlambda of the plane-strain Yeoh energy."""
    m = get_material(slug)
    lam = np.linspace(0.6, 3.0, 25)
    h = 1e-6
    dW = (
        strain_energy(lam + h, m, include_c3=include_c3)
        - strain_energy(lam - h, m, include_c3=include_c3)
    ) / (2 * h)
    sig = cauchy_stress(lam, m, include_c3=include_c3)
    np.testing.assert_allclose(sig, dW, rtol=1e-6, atol=1e-6 * m.C1)
    ds = (
        cauchy_stress(lam + h, m, include_c3=include_c3)
        - cauchy_stress(lam - h, m, include_c3=include_c3)
    ) / (2 * h)
    np.testing.assert_allclose(stress_slope(lam, m, include_c3=include_c3), ds, rtol=1e-5)


def test_printed_stress_formula_value():
    m = get_material("dragonskin_30")
    lam = 2.0
    expected = (lam - lam**-3) * (2 * 0.096e6 + 4 * 0.0095e6 * (lam - 1 / lam) ** 2)
    assert cauchy_stress(lam, m) == pytest.approx(expected, rel=1e-14)
    assert true_cauchy_stress(lam, m) == pytest.approx(lam * expected, rel=1e-14)
    assert cauchy_stress(1.0, m) == 0.0


@pytest.mark.parametrize("slug", ["dragonskin_30", "elastosil_m4601", "smooth_sil_950"])
def test_inverse_stress_round_trip(slug):
    m = get_material(slug)
    lam = np.array([0.3, 0.7, 0.999, 1.0, 1.001, 1.5, 2.5, 8.0])
    back = cauchy_stress_inverse(cauchy_stress(lam, m), m)
    np.testing.assert_allclose(back, lam, rtol=1e-12)
    assert isinstance(cauchy_stress_inverse(1e4, m), float)
    assert cauchy_stress_inverse(np.zeros((2, 3)), m).shape == (2, 3)


def test_ecoflex_without_c3_is_not_monotone():
    eco = get_material("ecoflex_00_30")
    lam_lo, lam_hi, _, s_hi = monotone_branch(eco)
    assert lam_hi == pytest.approx(3.877, abs=1e-3)
    assert s_hi == pytest.approx(0.0908e6, rel=1e-3)
    lam = np.array([1.2, 2.0, 3.5])
    np.testing.assert_allclose(cauchy_stress_inverse(cauchy_stress(lam, eco), eco), lam, 1e-10)
    with pytest.raises(ParameterError, match="no stretch gives this stress"):
        cauchy_stress_inverse(0.1e6, eco)
    # with C3 the law is monotone again
    assert monotone_branch(eco, include_c3=True)[1] == math.inf
    lam_c3 = cauchy_stress_inverse(0.1e6, eco, include_c3=True)
    assert cauchy_stress(lam_c3, eco, include_c3=True) == pytest.approx(0.1e6, rel=1e-12)


def test_stretch_must_be_positive():
    with pytest.raises(ParameterError):
        cauchy_stress(0.0, get_material("dragonskin_30"))
    with pytest.raises(ParameterError):
        cauchy_stress_inverse(float("nan"), get_material("dragonskin_30"))


# --- ambient -----------------------------------------------------------------------------
def test_ambient_defaults_and_params():
    a = Ambient()
    assert a.p_amb == 101325.0 and a.T_amb == 293.15 and a.g == 9.80665
    assert a.R_air == 287.05 and a.rho0 == 1.185 and a.kappa == 1.4
    ps = a.params()
    assert ps.param("rho0").unit == "kg/m^3" and "6358" in ps.param("rho0").source
    with pytest.raises(ParameterError):
        Ambient(p_amb=-1.0)


def test_one_quantity_record_and_one_refusal_text():
    """Param, the model's Var, the APSParams fields and a study factor's target are one
    record (Quantity): an APS field, the model parameter it sets and a Param with the
    same range refuse a value in the same words, the bracket open at 0."""
    from sarcomere.dynamics.assemblies import hanging_load
    from sarcomere.dynamics.components.aps import APSParams
    from sarcomere.dynamics.modeling.variables import Var
    from sarcomere.dynamics.params import Quantity
    from sarcomere.scenarios.explore.factors import Target

    assert all(issubclass(c, Quantity) for c in (Param, Var, Target))
    tail = r" = 0.0 is invalid; allowed: \(0, inf\) N/m$"
    with pytest.raises(ParameterError, match=r"^parameter 'k_s'" + tail):
        APSParams(k_s=0.0)
    with pytest.raises(ParameterError, match=r"^parameter 'myofibril.actin0.k_s'" + tail):
        hanging_load(1).parameters({"myofibril.actin0.k_s": 0.0})
    q = APSParams.quantity("k_s")
    with pytest.raises(ParameterError, match=r"^parameter 'k'" + tail):
        raise q.refuse("k", 0.0)
    assert Param("k", 1.0, **vars(q)).range_str == q.range_str == "(0, inf) N/m"
