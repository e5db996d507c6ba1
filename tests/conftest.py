"""Tests write only under tmp_path: the checkout is left as it was found (checked for the
whole session)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `benchmarks.studies`: the studies only benchmarks run
    sys.path.append(str(ROOT))


def _status() -> str:
    done = subprocess.run(
        ["git", "status", "--porcelain", "--ignored", "--untracked-files=all"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    lines = done.stdout.splitlines()
    noise = ("__pycache__", ".pytest_cache", ".ruff_cache", ".venv", ".egg-info", ".pyc")
    return "\n".join(ln for ln in lines if not any(n in ln for n in noise))


@pytest.fixture(scope="session", autouse=True)
def checkout_untouched():
    """Fail the session if the tests left files in (or removed files from) the checkout."""
    before = _status()
    yield
    after = _status()
    assert after == before, f"the tests changed the checkout:\n{after}"


@pytest.fixture(scope="session")
def drawn_png():
    """``check(path)``: the file is a PNG plot with something drawn on it (decoded, at least
    200 x 200 pixels, 1-90 % of them not the white background, more than a handful of
    colours: an empty or blank figure fails)."""
    from matplotlib import image

    def check(path: Path) -> None:
        img = image.imread(path)  # raises on a file that is not an image
        assert img.ndim == 3 and min(img.shape[:2]) >= 200, img.shape
        rgb = img[..., :3].reshape(-1, 3)
        inked = (rgb < 0.98).any(axis=1).mean()
        assert 0.01 < inked < 0.9, f"{path.name}: {inked:.3%} of the pixels drawn"
        assert len(set(map(tuple, (rgb * 255).round().astype(int)))) > 8, path.name

    return check


@pytest.fixture(scope="session")
def tight_record():
    """``record(model, t, u, params, outputs) -> (n, len(outputs)) array``: the response of
    ``model`` to the supply command ``u`` (Pa at the samples ``t``, linear between them)
    from its equilibrium at ``u[0]``, simulated by CVODES at rtol 1e-10: the independent
    reference a fit must reproduce (not the fit's own Radau steps)."""
    import numpy as np

    from sarcomere.dynamics.equilibrium import solve_equilibrium
    from sarcomere.dynamics.signals import Table
    from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

    def record(model, t, u, params, outputs):
        eq = solve_equilibrium(model, {"regulator.p_cmd": float(u[0])}, params)
        res = simulate(
            model,
            t[-1],
            x0=eq.x,
            inputs={"regulator.p_cmd": Table(times=tuple(t), values=tuple(u), unit="Pa")},
            params=params,
            t_out=t,
            settings=SolverSettings(rtol=1e-10, atol=1e-12),
        )
        return np.column_stack([res[o] for o in outputs])

    return record


@pytest.fixture(scope="session", autouse=True)
def compile_cache(tmp_path_factory):
    """Compiled libraries (``radau``) go to a session folder, never the user's cache."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SARCOMERE_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    yield
    mp.undo()


@pytest.fixture(scope="session")
def velocity_law_moves():
    """``moves(qp, xi0, u_prev, u_lo, u_hi, du_max, soft_gap, ahead=None, solver="daqp")``:
    the moves ``du`` (horizon x nu, SI) and ``ok`` of the condensed velocity-form QP
    ``qp`` (:class:`~sarcomere.controllers.qp.VelocityQP`) as the LMPC runs it: one call
    of :func:`~sarcomere.controllers.qp.velocity_law` at ``xi0 = [dx; e]`` (the reference
    0, the soft signals 0 with their bounds ``soft_gap``), ``ahead`` the reference at the
    nodes (default 0)."""
    import numpy as np

    from sarcomere.controllers.qp import velocity_law

    def moves(qp, xi0, u_prev, u_lo, u_hi, du_max, soft_gap, ahead=None, solver="daqp"):
        nu, ns, N = qp.nu, qp.ns, qp.horizon
        nx = len(xi0) - 1
        law = velocity_law(nx, nu, ns, N, solver)
        memory = np.concatenate([np.zeros(nx), [1.0], np.tile(u_prev, N)])
        x = np.concatenate([xi0, np.zeros(ns)])
        ref = np.concatenate([[0.0], np.zeros(N) if ahead is None else np.ravel(ahead)])
        p = np.concatenate([qp.data(), u_lo, u_hi, du_max, soft_gap])
        mem, _, ok = (np.array(v).ravel() for v in law(memory, x, u_prev, ref, p))
        plan = mem[nx + 1 :].reshape(N, nu)
        return np.diff(np.vstack([u_prev, plan]), axis=0), bool(ok[0])

    return moves
