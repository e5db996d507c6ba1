"""Where explicit fixed-step methods fail: predicted stability limits against observed.

**Prediction.** Along a reference trajectory of the step scenario (CVODES, rtol 1e-10)
the Jacobian ``A = d ode / dx`` is evaluated at every saved point; a scheme with
stability polynomial ``R`` is linearly stable for step ``h`` when every ``h lambda``
lies in ``|R(z)| <= 1``, so ``h_max(t) = min_lambda r(arg lambda) / |lambda|`` with
``r`` the distance to the boundary of the region along the ray
(:func:`~sarcomere.dynamics.simulation.guard.stability_radius`; RK4: 2.785 on the negative
real axis, explicit Euler: ``-2 cos(theta)``). The predicted limit is the minimum
over the trajectory.

**Observation.** Runs at steps around the prediction are classified against a
reference on the same grid (every step saved):

* ``blown_up``: the run raised (non-finite state) or its error exceeds 100 %;
* ``silently_wrong``: finite, but the l2 error (scaled as in
  :mod:`~sarcomere.dynamics.studies.workprecision`) exceeds 1 %, or a spurious pressure
  oscillation persists: in the second half of the run the period-2 content of the
  chamber pressure error, ``max |e_k - (e_{k-1} + e_{k+1}) / 2|``, exceeds 1e-4 of the
  largest reference pressure (10 Pa at 0.1 MPa);
* ``fine``: everything else.

**The Rosenbrock method.** ``rodas`` (Rodas5P) is L-stable: ``|R(z)| <= 1`` on the whole
left half-plane and ``R(inf) = 0``, so no eigenvalue limits its step. It is run held at
fixed steps (first = max step, error control loosened to rtol = atol = 0.5 so that no
step is rejected: ``n_rejected`` is recorded) far beyond RK4's limit and classified
alike: its largest fine step is an accuracy limit, not a stability one.

**Laminar threshold.** The same study is repeated for ``r_lam`` = 0.995, 0.999
(default) and 0.99999, which moves the fastest eigenvalue (the laminar conductance
grows as ``1/sqrt(1 - r_lam)``).
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import SolverError
from ..simulation.guard import SCHEMES, StepStabilityWarning, jacobian_eigenvalues, max_stable_step
from ..simulation.simulate import SolverSettings, simulate
from .workprecision import P_CMD, Reference, Scenario, scenarios, state_errors, states

ERROR_TOL = 1e-2
"""l2 error above which a finite run is silently wrong (1 %)."""
OSC_TOL = 1e-4
"""Persistent period-2 pressure content, relative to the largest reference pressure."""
DIVERGED = 1.0
"""l2 error above which a finite run counts as blown up (100 %)."""
R_LAM = (0.995, 0.999, 0.99999)
REF_RTOL = 1e-10


def with_r_lam(sc: Scenario, r_lam: float) -> Scenario:
    """The scenario with the laminar threshold of every tube set to ``r_lam``."""
    over = tuple((f"myofibril.tube{k}.r_lam", r_lam) for k in range(1, sc.n + 1))
    return dataclasses.replace(sc, params=(*sc.params, *over))


def trajectory_spectrum(sc: Scenario, n_points: int = 401) -> dict:
    """Jacobian eigenvalues along the reference trajectory of ``sc``.

    Returns
    -------
    dict
        ``t_s``, ``max_abs_eig_1_s`` (largest ``|lambda|``), ``min_real_eig_1_s`` and
        ``h_max_<scheme>_s`` per explicit scheme, one value per point.
    """
    model, x0 = sc.setup()
    t = np.linspace(0.0, sc.t_final, n_points)
    res = simulate(
        model,
        sc.t_final,
        inputs={P_CMD: sc.command},
        params=dict(sc.params),
        x0=x0,
        settings=SolverSettings("cvodes", REF_RTOL, REF_RTOL * 1e-3),
        t_out=t,
    )
    X, p = states(res, model), model.parameters(dict(sc.params))
    out: dict[str, list] = {"t_s": t.tolist(), "max_abs_eig_1_s": [], "min_real_eig_1_s": []}
    for name in SCHEMES:
        out[f"h_max_{name}_s"] = []
    for k, tk in enumerate(t):
        lam = jacobian_eigenvalues(model, X[k], np.array([sc.command(tk)], dtype=float), p)
        out["max_abs_eig_1_s"].append(float(np.abs(lam).max()))
        out["min_real_eig_1_s"].append(float(lam.real.min()))
        for name, scheme in SCHEMES.items():
            out[f"h_max_{name}_s"].append(max_stable_step(lam, scheme)[0])
    return out


def predicted(spectrum: dict) -> dict:
    """Per scheme: the limit at t = 0 and the minimum over the trajectory (and when) [s]."""
    t = np.asarray(spectrum["t_s"])
    out = {}
    for name in SCHEMES:
        h = np.asarray(spectrum[f"h_max_{name}_s"])
        k = int(np.argmin(h))
        out[name] = {"initial_s": float(h[0]), "trajectory_s": float(h[k]), "at_t_s": float(t[k])}
    return out


def _step_grid(sc: Scenario, h: float) -> np.ndarray:
    """Every step saved: a grid of spacing ``h`` [s] (the input breakpoint splits one step)."""
    return np.unique(np.append(np.arange(0.0, sc.t_final, h), sc.t_final))


def _pressure_names(sc: Scenario) -> list[str]:
    return [f"myofibril.aps{k}.chamber.p_gauge" for k in range(1, sc.n + 1)]


def oscillation(sc: Scenario, run, ref_run) -> tuple[float, float]:
    """(late, early) period-2 amplitude of the chamber pressure error, relative to max |p_ref|."""
    late = early = 0.0
    half = np.searchsorted(run.index, sc.t_final / 2)
    scale = max(float(np.abs(ref_run[n]).max()) for n in _pressure_names(sc)) or 1.0
    for name in _pressure_names(sc):
        e = run[name] - ref_run[name]
        r = np.abs(e[1:-1] - 0.5 * (e[:-2] + e[2:]))
        late = max(late, float(r[half:].max(initial=0.0)))
        early = max(early, float(r[:half].max(initial=0.0)))
    return late / scale, early / scale


def classify(sc: Scenario, method: str, h: float, settings: SolverSettings | None = None) -> dict:
    """Run ``method`` at step ``h`` [s] (every step saved) and classify the answer
    (``settings``: how an adaptive method is held at ``h``; default the fixed step)."""
    model, x0 = sc.setup()
    t_out = _step_grid(sc, h)
    kw = {"inputs": {P_CMD: sc.command}, "params": dict(sc.params), "x0": x0, "t_out": t_out}
    ref_run = simulate(model, sc.t_final, settings=SolverSettings("cvodes", REF_RTOL, 1e-13), **kw)
    ref_X = states(ref_run, model)
    scale = np.abs(ref_X).max(axis=0)
    ref = Reference(ref_run, ref_X, np.where(scale > 0, scale, 1.0), SolverSettings())
    record = {"method": method, "step_s": h}
    if settings is None:
        settings = SolverSettings(method, step=h, options=(("on_unstable", "warn"),))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", StepStabilityWarning)
        try:
            run = simulate(model, sc.t_final, settings=settings, **kw)
        except SolverError as exc:
            return {
                **record,
                "class": "blown_up",
                "reason": " ".join(str(exc).split())[:200],
                "t_fail_s": exc.time,
                "guard_warned": bool(caught),
            }
    final, l2 = state_errors(states(run, model), ref)
    late, early = oscillation(sc, run, ref_run)
    if not l2 <= DIVERGED:
        cls, why = "blown_up", f"l2 error {l2:.3g} > {DIVERGED:g}"
    elif l2 > ERROR_TOL:
        cls, why = "silently_wrong", f"l2 error {l2:.3g} > {ERROR_TOL:g}"
    elif late > OSC_TOL:
        cls, why = "silently_wrong", f"persistent pressure oscillation {late:.3g} > {OSC_TOL:g}"
    else:
        cls, why = "fine", ""
    return {
        **record,
        "class": cls,
        "reason": why,
        "error_l2": l2,
        "error_final": final,
        "oscillation_late": late,
        "oscillation_early": early,
        "guard_warned": bool(caught),
        "n_steps": run.meta.get("n_steps"),
        "n_rejected": run.meta.get("n_rejected"),
    }


def observed(runs: Sequence[dict]) -> dict:
    """Smallest step that is not fine, and the largest fine step below it [s]."""
    bad = [r["step_s"] for r in runs if r["class"] != "fine"]
    first_bad = min(bad, default=None)
    fine = [
        r["step_s"]
        for r in runs
        if r["class"] == "fine" and (first_bad is None or r["step_s"] < first_bad)
    ]
    return {"largest_fine_s": max(fine, default=None), "first_failure_s": first_bad}


def sweep(sc: Scenario, pred: dict, factors: Sequence[float]) -> dict:
    """For each explicit scheme: runs at ``factor * predicted limit`` and the observed limit."""
    out = {}
    for name in SCHEMES:
        h_pred = pred[name]["trajectory_s"]
        runs = [classify(sc, name, f * h_pred) for f in factors]
        for r, f in zip(runs, factors, strict=True):
            r["factor"] = f
        out[name] = {"predicted": pred[name], "runs": runs, "observed": observed(runs)}
    return out


def held_step(method: str, h: float) -> SolverSettings:
    """An adaptive method held at step ``h``: first = max step, tolerances too loose to
    reject a step (the runs record ``n_rejected``)."""
    return SolverSettings(method, 0.5, 0.5, options=(("first_step", h), ("max_step", h)))


def rosenbrock_steps(sc: Scenario, steps: Sequence[float]) -> dict:
    """``rodas`` held at each of ``steps``: the runs and the observed (accuracy) limit;
    no predicted limit (L-stable)."""
    runs = [classify(sc, "rodas", h, held_step("rodas", h)) for h in steps]
    none = {"initial_s": None, "trajectory_s": None, "at_t_s": None, "why": "L-stable"}
    return {"predicted": none, "runs": runs, "observed": observed(runs)}


# --- charts -----------------------------------------------------------------------------
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_spectrum(spectra: dict, path: Path) -> Path:
    """Fastest eigenvalue and predicted RK4 step limit along the trajectory, per r_lam."""
    plt = _pyplot()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7.0, 5.0), sharex=True)
    for i, (r_lam, sp) in enumerate(spectra.items()):
        a1.semilogy(sp["t_s"], sp["max_abs_eig_1_s"], color=f"C{i}", label=f"r_lam = {r_lam}")
        a2.semilogy(sp["t_s"], np.asarray(sp["h_max_rk4_s"]) * 1e3, color=f"C{i}")
        a2.semilogy(sp["t_s"], np.asarray(sp["h_max_euler_s"]) * 1e3, color=f"C{i}", ls="--")
    a1.set_ylabel("max |lambda| [1/s]")
    a1.legend(fontsize=8)
    a2.set_ylabel("predicted h_max [ms]\n(solid rk4, dashed euler)")
    a2.set_xlabel("time [s] (step 0 -> 0.1 MPa at 0.1 s, 50 g)")
    for ax in (a1, a2):
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


_MARK = {
    "fine": ("o", "tab:green"),
    "silently_wrong": ("s", "tab:orange"),
    "blown_up": ("x", "tab:red"),
}


def plot_steps(studies: dict, path: Path) -> Path:
    """Observed class of each run against its step, with the predicted limit, per r_lam."""
    plt = _pyplot()
    rows = list(studies.items())
    fig, axes = plt.subplots(len(rows), 1, figsize=(7.0, 1.6 + 1.3 * len(rows)), squeeze=False)
    for ax, (r_lam, study) in zip(axes[:, 0], rows, strict=True):
        for y, res in enumerate(study.values()):
            for cls, (marker, color) in _MARK.items():
                hs = [r["step_s"] * 1e3 for r in res["runs"] if r["class"] == cls]
                ax.semilogx(
                    hs, [y] * len(hs), marker, color=color, ls="", label=cls if y == 0 else None
                )
            if res["predicted"]["trajectory_s"] is not None:  # rodas: none (L-stable)
                h_pred = res["predicted"]["trajectory_s"] * 1e3
                ax.plot([h_pred, h_pred], [y - 0.35, y + 0.35], color="k", lw=1.5)
        ax.set_yticks(range(len(study)), list(study))
        ax.set_ylim(-0.6, len(study) - 0.4)
        ax.set_title(f"r_lam = {r_lam} (bar: predicted limit)", fontsize=9)
        ax.grid(True, axis="x", which="both", alpha=0.3)
    axes[-1, 0].set_xlabel("step [ms]")
    axes[0, 0].legend(fontsize=7, ncol=3, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


# --- the whole study --------------------------------------------------------------------
FULL_FACTORS = (0.5, 0.8, 0.9, 0.95, 0.99, 1.01, 1.05, 1.1, 1.2, 1.4, 1.7, 2.0, 3.0, 5.0, 10.0)
QUICK_FACTORS = (0.9, 1.1, 1.5)
FULL_RODAS_STEPS = (1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1)
QUICK_RODAS_STEPS = (1e-3, 1e-2, 1e-1)
"""Steps [s] at which ``rodas`` is held: from RK4's limit (about 1 ms) up 100-fold."""


def study(out_dir: Path, quick: bool = False, n: int = 3) -> dict:
    """Spectrum, predicted and observed limits for each r_lam; writes stability.json and plots.

    Returns
    -------
    dict
        ``result`` (what stability.json holds), ``metrics`` (named numbers) and
        ``files`` (paths written).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    base = scenarios(n)["step"]
    factors = QUICK_FACTORS if quick else FULL_FACTORS
    spectra, studies, summary = {}, {}, {}
    tic = time.perf_counter()
    for r_lam in R_LAM:
        sc = with_r_lam(base, r_lam)
        sp = trajectory_spectrum(sc, 101 if quick else 401)
        pred = predicted(sp)
        spectra[r_lam] = sp
        studies[r_lam] = sweep(sc, pred, factors)
        studies[r_lam]["rodas"] = rosenbrock_steps(
            sc, QUICK_RODAS_STEPS if quick else FULL_RODAS_STEPS
        )
        summary[r_lam] = {
            "max_abs_eig_1_s": max(sp["max_abs_eig_1_s"]),
            **{
                k: {"predicted": v["predicted"], "observed": v["observed"]}
                for k, v in studies[r_lam].items()
            },
        }
    result = {
        "scenario": base.description,
        "n": n,
        "criteria": {"error_tol": ERROR_TOL, "oscillation_tol": OSC_TOL, "diverged": DIVERGED},
        "factors": list(factors),
        "summary": {str(k): v for k, v in summary.items()},
        "spectra": {str(k): v for k, v in spectra.items()},
        "runs": {str(k): {m: v["runs"] for m, v in s.items()} for k, s in studies.items()},
        "wall_time_s": time.perf_counter() - tic,
    }
    path = out_dir / "stability.json"
    path.write_text(json.dumps(result, indent=1))
    files = [
        path,
        plot_spectrum(spectra, out_dir / "stability_spectrum.png"),
        plot_steps(studies, out_dir / "stability_steps.png"),
    ]
    return {"result": result, "metrics": _metrics(summary), "files": files}


def _metrics(summary: dict) -> dict:
    """Named numbers for summary.json: limits in s, eigenvalues in 1/s, ratios."""
    out: dict[str, float | None] = {}
    for r_lam, s in summary.items():
        tag = f"{r_lam:g}".replace(".", "p")
        out[f"max_abs_eig_rlam{tag}_1_s"] = s["max_abs_eig_1_s"]
        for name in SCHEMES:
            pred, obs = s[name]["predicted"]["trajectory_s"], s[name]["observed"]
            out[f"{name}_predicted_limit_rlam{tag}_s"] = pred
            out[f"{name}_observed_first_failure_rlam{tag}_s"] = obs["first_failure_s"]
            ff = obs["first_failure_s"]
            out[f"{name}_observed_over_predicted_rlam{tag}_ratio"] = ff / pred if ff else None
        obs = s["rodas"]["observed"]
        out[f"rodas_largest_fine_step_rlam{tag}_s"] = obs["largest_fine_s"]
        out[f"rodas_first_failure_rlam{tag}_s"] = obs["first_failure_s"]
    return out
