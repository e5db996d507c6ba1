"""Start values that are expressions of parameters follow a parameter change."""

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.errors import ModelError
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.modeling.ports import FLANGE


class Vessel(Component):
    """A rigid vessel venting to ambient: state m_air starts at the ambient air mass."""

    def build(self, b):
        V0 = b.parameter("V0", 2e-6, "m^3", "volume", low=0.0)
        p_amb = b.parameter("p_amb", 101325.0, "Pa", "ambient pressure", low=0.0)
        R, T = 287.05, 293.15
        m = b.state("m_air", V0 * p_amb / (R * T), "kg", "air mass")
        b.der(m, -(m - V0 * p_amb / (R * T)))
        flange = b.port("flange", FLANGE)
        b.set_start(flange.s, 1e3 * V0)  # a guess shared with the connected flange
        b.equation(flange.f, 0.0)


class Plate(Component):
    def build(self, b):
        f = b.port("flange", FLANGE)
        b.equation(f.s, 0.0)


def vessel_model():
    sys = System("vessel")
    v = sys.add(Vessel("vessel"))
    plate = sys.add(Plate("plate"))
    sys.connect(v.flange, plate.flange)
    return sys.flatten()


def test_state_start_follows_a_parameter_change():
    model = vessel_model()
    R, T = 287.05, 293.15
    assert model.x0() == pytest.approx([2e-6 * 101325.0 / (R * T)], rel=1e-15)
    p = model.parameters({"vessel.V0": 5e-6, "vessel.p_amb": 95000.0})
    assert model.x0(p) == pytest.approx([5e-6 * 95000.0 / (R * T)], rel=1e-15)
    assert model.function("start").name_in() == ["p"]
    assert model.function("start").name_out() == ["x0", "z0", "u0"]


def test_a_connection_set_shares_an_expression_start():
    model = vessel_model()
    shared = model.variables["plate.flange.s"].start
    value = cs.Function("s", [model.p], [shared])(model.parameters({"vessel.V0": 3e-6}))
    assert float(value) == pytest.approx(3e-3, rel=1e-15)


def test_a_start_expression_of_a_non_parameter_is_refused():
    class Bad(Component):
        def build(self, b):
            x = b.state("x", 0.0, "m", "position")
            b.der(x, -x)
            b.state("y", 2 * x, "m", "other")

    sys = System("bad")
    with pytest.raises(ModelError, match=r"start value of 'bad\.y' depends on \['bad\.x'\]"):
        sys.add(Bad("bad"))


def test_float_starts_are_unchanged():
    sys = System("plain")

    class Decay(Component):
        def build(self, b):
            x = b.state("x", 0.25, "m", "position")
            b.der(x, -x)

    sys.add(Decay("d"))
    np.testing.assert_array_equal(sys.flatten().x0(), [0.25])
