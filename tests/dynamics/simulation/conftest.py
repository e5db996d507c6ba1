"""A damped oscillator ``m x'' + d x' + c x = 0`` built from the mechanical components,
and its closed-form solution: the reference of the integrator tests."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sarcomere.dynamics.components.mechanical import Damper, Fixed, Mass, Spring
from sarcomere.dynamics.modeling.component import System

M_KG, C_N_M, D_NS_M, X0_M = 1.0, 100.0, 2.0, 0.1


@pytest.fixture(scope="module")
def oscillator():
    """The oscillator as a flattened model: ``mass.s`` [m] released from X0_M at rest."""
    sys = System("oscillator")
    fix = sys.add(Fixed("fix"))
    spring = sys.add(Spring("spring", c=C_N_M))
    damper = sys.add(Damper("damper", d=D_NS_M))
    mass = sys.add(Mass("mass", m=M_KG, g=0.0, s_start=X0_M))
    sys.connect(fix.flange, spring.flange_a)
    sys.connect(spring.flange_b, mass.flange_a)
    sys.connect(fix.flange, damper.flange_a)
    sys.connect(damper.flange_b, mass.flange_b)
    return sys.flatten()


def _exact(t: np.ndarray) -> np.ndarray:
    """Position [m] of the underdamped oscillator released from X0_M at rest."""
    w0 = math.sqrt(C_N_M / M_KG)
    zeta = D_NS_M / (2 * math.sqrt(C_N_M * M_KG))
    wd = w0 * math.sqrt(1 - zeta**2)
    return X0_M * np.exp(-zeta * w0 * t) * (np.cos(wd * t) + zeta * w0 / wd * np.sin(wd * t))


@pytest.fixture(scope="session")
def oscillator_error():
    """``error(result)``: max |x - x_exact| / X0_M over the result's points."""
    return lambda res: float(np.max(np.abs(res["mass.s"] - _exact(res["time"])))) / X0_M
