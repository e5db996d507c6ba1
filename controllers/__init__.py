"""Controllers on the flattened model: exact linearisation to python-control, PID, LQI
(full state or on an extended Kalman filter), linear and nonlinear MPC, the sampled
closed loop and its metrics.

Every controller implements :class:`~.base.Controller` (``update(t, y, r) -> u`` by name,
checked by :meth:`~.base.Controller.checked`) and is built by a factory registered by slug
(:mod:`.registry`)::

    factory(model, operating_point, dt, settings: dict) -> Controller
    register_controller("lmpc", make_lmpc)

``settings`` holds the common keys the scene sets (:data:`~.registry.COMMON_KEYS`:
``output``, ``input``, ``u_min``, ``u_max``, ``measured``, ``noise_std``,
``tension_min``, ``build_model``, ``overrides``) and the controller's own keys (the scene's
``[control.controllers.<key>]`` table, SI numbers or text), checked with
:func:`~.registry.own_settings`. A module that registers a controller is imported here, so
``import sarcomere.controllers`` makes every slug available to the loop
(:func:`~.loop.run_closed_loop`) and to the ``closed_loop`` scene kind.
"""

from . import lmpc, lqi, nmpc, pid  # noqa: F401  (register the controllers)
from .base import Controller, ControllerStats
from .linearize import classify_poles, linearize, operating_point
from .registry import CONTROLLERS, make_controller, register_controller

__all__ = [
    "CONTROLLERS",
    "Controller",
    "ControllerStats",
    "classify_poles",
    "linearize",
    "make_controller",
    "operating_point",
    "register_controller",
]
