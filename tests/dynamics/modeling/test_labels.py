"""python-control labels: a reversible mapping of variable names that python-control accepts."""

import control as ct
import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ModelError, ParameterError
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.modeling.labels import from_label, to_label

OUTPUTS = ["myofibril.length", "load.s", "myofibril.aps2.chamber.p_gauge"]


@pytest.fixture(scope="module")
def model():
    return hanging_load(n=3, load_kg=0.05)


def test_every_name_round_trips_and_labels_have_no_dot(model):
    names = list(model.signal_names) + model.param_names
    labels = [to_label(n) for n in names]
    assert all("." not in label for label in labels)
    assert len(set(labels)) == len(names)
    assert [from_label(label) for label in labels] == names


def plant(model):
    eq = solve_equilibrium(model, {"regulator.p_cmd": 3e4})
    lin = model.linearization(OUTPUTS)(x=eq.x, z=eq.z, u=eq.u, p=eq.p)
    A, B, C, D = (np.array(lin[k]) for k in "ABCD")
    return ct.ss(
        A,
        B,
        C,
        D,
        states=[to_label(n) for n in model.state_names],
        inputs=[to_label(n) for n in model.input_names],
        outputs=[to_label(n) for n in OUTPUTS],
        name="plant",
    )


def test_control_ss_accepts_the_labels_and_they_map_back(model):
    P = plant(model)
    assert [from_label(s) for s in P.state_labels] == model.state_names
    assert [from_label(s) for s in P.input_labels] == model.input_names
    assert [from_label(s) for s in P.output_labels] == OUTPUTS


def test_control_interconnect_connects_by_label(model):
    """A proportional length controller closed around the plant by signal name."""
    P, k = plant(model), 1e5
    u, y = to_label("regulator.p_cmd"), to_label("myofibril.length")
    K = ct.ss([], [], [], [[k, -k]], inputs=["ref", y], outputs=[u], name="gain")
    loop = ct.interconnect([P, K], inputs=["ref"], outputs=[y], check_unused=False)
    C_y = P.C[[P.output_labels.index(y)], :]
    np.testing.assert_allclose(loop.A, P.A - k * P.B @ C_y, rtol=1e-12, atol=0)
    assert loop.output_labels == [y] and loop.input_labels == ["ref"]
    assert [from_label(s.removeprefix("plant_")) for s in loop.state_labels] == model.state_names


@pytest.mark.parametrize("bad", ["a__b.c", "a._b", "a_.b", "a..b", "1a.b", ""])
def test_names_that_would_not_map_back_are_refused(bad):
    with pytest.raises(ParameterError, match="parameter 'name'"):
        to_label(bad)


@pytest.mark.parametrize("bad", ["a___b", "a__", "__a", "a.b"])
def test_labels_not_made_by_to_label_are_refused(bad):
    with pytest.raises(ParameterError, match="parameter 'label'"):
        from_label(bad)


@pytest.mark.parametrize("bad", ["p__in", "p_", "_p"])
def test_declaring_a_name_with_the_separator_is_refused(bad):
    class Bad(Component):
        def build(self, b):
            b.state(bad, 0.0, "m", "bad name")

    with pytest.raises(ModelError, match=f"variable name '{bad}' in 'c' must be letters"):
        System("s").add(Bad("c"))
    with pytest.raises(ModelError, match=f"component name '{bad}' must be letters"):
        Bad(bad)
