"""A flattened Model owns its data: later changes to the System do not reach it."""

import pytest

from sarcomere.dynamics.components.mechanical import Fixed, Mass, Node, Spring
from sarcomere.dynamics.modeling.component import System


def oscillator_system():
    sys = System("osc")
    fix = sys.add(Fixed("fix"))
    spring = sys.add(Spring("spring", c=100.0))
    mass = sys.add(Mass("mass", m=1.0, g=0.0, s_start=0.1))
    sys.connect(fix.flange, spring.flange_a)
    sys.connect(spring.flange_b, mass.flange_a)
    return sys


def test_adding_a_component_after_flattening_leaves_the_model_unchanged():
    sys = oscillator_system()
    model = sys.flatten()
    before = dict(model.variables)
    sys.add(Mass("extra", m=2.0, g=0.0))
    assert dict(model.variables) == before
    assert not any(n.startswith("extra.") for n in model.variables)


def test_variables_are_read_only():
    model = oscillator_system().flatten()
    with pytest.raises(TypeError):
        model.variables["mass.s"] = model.variables["mass.v"]


def test_flattening_does_not_rewrite_the_system():
    """Connection sets share a start value in the Model's copy, not in the System."""
    sys = System("hanging_node")
    fix = sys.add(Fixed("fix"))
    spring = sys.add(Spring("spring", c=100.0))
    node = sys.add(Node("node", weight=1.0, s_start=0.01))
    sys.connect(fix.flange, spring.flange_a)
    sys.connect(spring.flange_b, node.flange_a)
    declared = dict(sys._c.variables)
    model = sys.flatten()
    assert sys._c.variables == declared
    assert model.variables["spring.flange_b.s"].start == 0.01
    assert model.variables["spring.flange_b.s"].nominal == 0.01  # shared with the start
