"""The two-way co-simulation study: a muscle and a spring-coupled load mass split into two
participants, against the same system simulated as one model, and the linear analysis
of the coupling's stability.

The system is the co-simulation set-up of :mod:`sarcomere.dynamics.assemblies`: one APS
hanging from the frame, its hook of ``END_KG`` [kg] at its lower end, and a spring ``c``
[N/m] (unstretched ``REST_M``, undamped) from the hook to a mass ``LOAD_KG`` [kg]
(gravity on both). Split:

* ``muscle`` (:func:`muscle_participant_model`, :func:`~sarcomere.dynamics.assemblies.
  force_driven`): input ``pull.f`` (the spring's pull on the hook [N]), output ``end.s``
  (the hook's position [m]);
* ``load`` (:func:`load_participant_model`, :func:`~sarcomere.dynamics.assemblies.
  spring_mass_load`): the spring driven at its top by the input ``drive.s`` [m] and the
  mass; output ``sensor.f``, the spring's tension [N] (it feeds through from the input: a
  real two-way loop, position one way, force the other).

:func:`monolithic_model` (:func:`~sarcomere.dynamics.assemblies.sprung_load`) is the whole
system as one flattened model (the reference). :func:`amplification` is the spectral
radius of the co-simulation's step map for the two participants linearised at the joint
equilibrium, each integrated exactly over a step with its inputs held as the master holds
them: the coupling is stable where it is <= 1.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import scipy.linalg

from sarcomere.dynamics.assemblies import force_driven, spring_mass_load, sprung_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.params.ambient import Ambient
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.signals import Step
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulate import simulate
from sarcomere.fmu.archive import OpenedFmu
from sarcomere.fmu.cosim import INPUT_LAWS, ORDERINGS, Connection, cosimulate
from sarcomere.fmu.participants import FmuParticipant, NativeParticipant

G = Ambient().g
"""Gravity of both participants [m/s^2] (the environment's default)."""

END_KG = 0.02
"""The hook at the muscle's lower end [kg] (hook and clip of the coupling)."""

LOAD_KG = 0.05
"""The load mass below the spring [kg]."""

REST_M = 0.01
"""The spring's unstretched length [m]."""

DAMPING = 0.0
"""The load's damping to the ground [N*s/m]: none, the loop's only damping is the
muscle's own (:func:`relative_mode_damping`)."""

CONNECTIONS = (
    Connection("muscle.end.s", "load.drive.s"),
    Connection("load.sensor.f", "muscle.pull.f"),
)
"""The two-way loop: the hook's position drives the spring, its tension pulls the hook."""


def _check(c: float) -> float:
    if not (np.isfinite(c) and c > 0):
        raise ParameterError("c", c, "(0, inf) N/m")
    return float(c)


def muscle_participant_model() -> Model:
    """The muscle (1 APS) with its hook pulled by the force input ``pull.f`` [N]; output
    ``end.s``, the hook's position [m]."""
    return force_driven(1, hook_kg=END_KG)


def load_participant_model(c: float) -> Model:
    """The spring ``c`` [N/m] driven at its top by the input ``drive.s`` [m] and the load
    mass below it; output ``sensor.f``, the spring's tension [N]."""
    return spring_mass_load(LOAD_KG, _check(c), DAMPING, rest_length=REST_M)


def monolithic_model(c: float) -> Model:
    """The whole system as one model: states ``hook.s``, ``mass.s``, ...; ``sensor.f``."""
    return sprung_load(
        1, mass_kg=LOAD_KG, stiffness=_check(c), damping=DAMPING, hook_kg=END_KG, rest_length=REST_M
    )


@functools.lru_cache(maxsize=32)
def _linearised(c: float, p_cmd: float) -> tuple:
    """``(A, B, C, D)`` of the muscle (input ``pull.f``, output ``end.s``) and of the load
    (``drive.s`` -> ``sensor.f``) at the joint equilibrium of ``p_cmd`` [Pa]."""
    mus, lod = muscle_participant_model(), load_participant_model(c)
    eq_m = solve_equilibrium(mus, {"regulator.p_cmd": p_cmd, "pull.f": start_force()})
    eq_l = solve_equilibrium(lod, {"drive.s": eq_m["end.s"]})
    out = []
    for model, eq, u, y in (
        (mus, eq_m, "pull.f", "end.s"),
        (lod, eq_l, "drive.s", "sensor.f"),
    ):
        A, B, C, D = (np.array(m) for m in model.linearization([y])(eq.x, eq.z, eq.u, eq.p))
        k = model.input_names.index(u)
        out.append((A, B[:, k : k + 1], C, D[:, k : k + 1]))
    return tuple(out)


def _discrete(A, B, C, D, h: float):
    """The exact zero-order-hold step ``x+ = Phi x + Gam u``, ``y = C x + D u``."""
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx], M[:nx, nx:] = A, B
    E = scipy.linalg.expm(M * h)
    return E[:nx, :nx], E[:nx, nx:], C, D


def amplification(c: float, h: float, ordering: str, inputs: str, p_cmd: float) -> float:
    """Spectral radius of the co-simulation step map of the linearised loop.

    Both participants are linearised at the joint equilibrium of the command ``p_cmd``
    [Pa] and stepped exactly over ``h`` [s] with their inputs held as
    :func:`~sarcomere.fmu.cosim.cosimulate` holds them (``muscle`` first). The map acts on
    the participants' states and the last two read outputs (the extrapolation uses the
    previous one); it is linear, so it is built column by column. The monolithic system
    is damped, so a radius above 1 is the coupling's own instability.
    """
    if ordering not in ORDERINGS:
        raise ParameterError("ordering", ordering, " or ".join(ORDERINGS))
    if inputs not in INPUT_LAWS:
        raise ParameterError("inputs", inputs, " or ".join(INPUT_LAWS))
    if not (np.isfinite(h) and h > 0):
        raise ParameterError("h", h, "(0, inf) s")
    muscle, load = _linearised(_check(c), float(p_cmd))
    Pm, Gm, Cm, Dm = _discrete(*muscle, h)
    Pl, Gl, Cl, Dl = _discrete(*load, h)
    nm, nl = len(Pm), len(Pl)

    def law(now: float, before: float, new: float | None) -> float:
        if new is not None:  # Gauss-Seidel: the source already stepped
            return new if inputs == "hold" else 0.5 * (now + new)
        return now if inputs == "hold" else now + 0.5 * (now - before)

    def step(s: np.ndarray) -> np.ndarray:
        xm, xl = s[:nm], s[nm : nm + nl]
        ym, yl, ym_old, yl_old = s[nm + nl :]
        um = law(yl, yl_old, None)
        xm_new = Pm @ xm + Gm[:, 0] * um
        ym_new = float(Cm[0] @ xm_new + Dm[0, 0] * um)
        ul = law(ym, ym_old, ym_new if ordering == "gauss-seidel" else None)
        xl_new = Pl @ xl + Gl[:, 0] * ul
        yl_new = float(Cl[0] @ xl_new + Dl[0, 0] * ul)
        return np.concatenate([xm_new, xl_new, [ym_new, yl_new, ym, yl]])

    n = nm + nl + 4
    T = np.column_stack([step(e) for e in np.eye(n)])
    return float(np.max(np.abs(np.linalg.eigvals(T))))


def critical_step(
    c: float, ordering: str, inputs: str, p_cmd: float, bracket: tuple[float, float]
) -> float:
    """The largest stable step [s] of the linearised loop (:func:`amplification` = 1),
    by bisection in log of ``h`` within ``bracket`` [s] to 0.1 %.

    Raises
    ------
    ParameterError
        The bracket does not hold the boundary (stable at its top or unstable at its
        bottom).
    """
    lo, hi = bracket
    if not (
        amplification(c, lo, ordering, inputs, p_cmd)
        <= 1
        < amplification(c, hi, ordering, inputs, p_cmd)
    ):
        raise ParameterError("bracket", bracket, "steps [s] stable at the bottom, not at the top")
    while hi / lo > 1.001:
        mid = float(np.sqrt(lo * hi))
        lo, hi = (lo, mid) if amplification(c, mid, ordering, inputs, p_cmd) > 1 else (mid, hi)
    return lo


def coupled_frequency(c: float) -> float:
    """``sqrt(c (1/m_end + 1/m_load))`` [rad/s]: the two masses' relative mode on the
    spring alone (the muscle's stiffness is far smaller), the scale of ``h``."""
    return float(np.sqrt(_check(c) * (1 / END_KG + 1 / LOAD_KG)))


def relative_mode_damping(c: float, p_cmd: float) -> float:
    """The physical damping of the masses' relative mode [N s/m], ``2 sigma m_red``: its
    decay rate ``sigma`` [1/s] from the monolithic linearisation at ``p_cmd`` [Pa] (the
    eigenvalue whose frequency is nearest :func:`coupled_frequency`; a real pole, e.g. a
    chamber's, can be nearer in modulus), ``m_red`` the reduced mass.

    A coupling force held with an effective delay ``tau`` is ``c e(t - tau) ~ c e - c tau
    de/dt``: a negative damping ``c tau``; the loop is stable while it is below this one.
    """
    model = monolithic_model(c)
    eq = solve_equilibrium(model, {"regulator.p_cmd": p_cmd})
    lam = np.linalg.eigvals(np.array(model.function("jac")(eq.x, eq.z, eq.u, eq.p)[0]))
    mode = lam[np.argmin(np.abs(lam.imag - coupled_frequency(c)))]
    return float(-2 * mode.real * END_KG * LOAD_KG / (END_KG + LOAD_KG))


def command(p_low: float, p_high: float, t_step: float) -> Callable[[float], float]:
    """The regulator command [Pa]: ``p_low`` before ``t_step`` [s], ``p_high`` after."""
    return lambda t: p_high if t >= t_step else p_low


def start_force() -> float:
    """The spring's tension at the joint equilibrium [N]: the load's weight, the value that
    closes the loop at the start (``start_inputs`` of the muscle's ``pull.f``)."""
    return LOAD_KG * G


def cosimulate_split(
    c: float,
    step: float,
    ordering: str,
    inputs: str,
    p: tuple[float, float, float],
    stop_time: float,
    record: tuple[str, ...] = ("load.mass.s", "load.sensor.f"),
    settings: SolverSettings | None = None,
    load_fmu: OpenedFmu | None = None,
) -> Result:
    """The split system co-simulated (muscle first), the command ``p = (p_low, p_high,
    t_step)`` [Pa, Pa, s], from the joint equilibrium of ``p_low``. Both participants are
    native (CVODES with ``settings``), or the load is ``load_fmu``, an FMU of
    :func:`load_participant_model` (any ``c``: its ``spring.c`` is set to ``c``).

    Raises
    ------
    CosimError
        A participant failed (a diverging coupling leaves the physical domain).
    """
    load = (
        NativeParticipant(load_participant_model(c), "load", settings=settings)
        if load_fmu is None
        else FmuParticipant(load_fmu, "load", {"spring.c": _check(c)})
    )
    parts = [NativeParticipant(muscle_participant_model(), "muscle", settings=settings), load]
    return cosimulate(
        parts,
        CONNECTIONS,
        stop_time=stop_time,
        step=step,
        ordering=ordering,
        inputs=inputs,
        sources={"muscle.regulator.p_cmd": command(*p)},
        start_inputs={"muscle.pull.f": start_force()},
        record=list(record),
    )


def monolithic_run(
    c: float, p: tuple[float, float, float], stop_time: float, t_out: np.ndarray
) -> Result:
    """The reference: :func:`monolithic_model` from its equilibrium of ``p_low``, the same
    command, CVODES at rtol 1e-10, on ``t_out`` [s]; signals ``mass.s``, ``sensor.f``."""
    model = monolithic_model(c)
    eq = solve_equilibrium(model, {"regulator.p_cmd": p[0]})
    return simulate(
        model,
        stop_time,
        {"regulator.p_cmd": Step(final=p[1], initial=p[0], time=p[2], unit="Pa")},
        x0=eq.x,
        settings=SolverSettings(rtol=1e-10, atol=1e-13),
        t_out=t_out,
        signals=["mass.s", "sensor.f"],
    )


def diverges(error: np.ndarray) -> bool:
    """Whether a run's error against the reference grows: its largest value over the last
    quarter of the run above that over the second quarter (the reference's transient
    decays, a stable coupling's error with it)."""
    n = len(error)
    return bool(np.max(error[3 * n // 4 :]) > np.max(error[n // 4 : n // 2]))
