"""Make the data of the packaged fits: ``python -m sarcomere.scenarios.fits.generate``.

Writes ``scenarios/fits/data/*.csv`` (or ``--out DIR``) from a stated "true" model, with
fixed-seed noise; ``--check`` regenerates into memory and compares with the packaged
files instead (exit 1 on a difference). tests/scenarios/test_fit_data.py runs the same
comparison, so the data and this script cannot drift. docs/fitting.md, "The packaged
data", states everything below.

**Synthetic** (``fit-synthetic``): the library's own model (3 APS, fidelity ``full``,
isothermal chambers) at :data:`TRUTH`, a parameter set 30-50 % away from the defaults in
the dynamic estimates of docs/model.md; the hook is 1.4 g instead of 1 g, so each
experiment's end mass ``load.m`` is its payload + 1.4 g. Time series at :data:`RATE_HZ`
(1 kHz) of the commanded pressure (an input, exact: piecewise linear between its
samples, as the fit applies a CSV input) and the measured length and first chamber's
gauge pressure, with Gaussian noise :data:`NOISE` (standard deviations). Static curves:
the concentric length of 3 APS at 50 g against pressure
levels (equilibria), with the same noise per signal. (No isometric curve: a fit that
estimates ``load.m`` per experiment cannot hold an isometric experiment, whose model has
no ``load.m``.)

**Mismatch** (``fit-mismatch``): a richer model than the one fitted: the units' areas
spread (:data:`SPREAD`: per unit, the pneumatic area ``A_p`` and the restoring
cross-section ``A_r`` times the factors given) and adiabatic chambers with wall heat
exchange (``aps.thermal = "adiabatic"``, ``aps.tau_heat = 0.6 s``), at the same
:data:`TRUTH` otherwise. The regulator's hysteresis (0.03 bar on its data sheet) is not
expressible in the library and is left out.

Everything is simulated through the public scene binding (:func:`..binding.bind`,
:func:`..binding.run`) and :func:`~sarcomere.dynamics.equilibrium.solve_equilibrium` at
tight tolerances (``rtol`` 1e-10); values are written rounded to well below the noise
(1 nm, 0.1 mPa... see :data:`SIGNALS`).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Seed of the noise; experiment ``i`` of :data:`EXPERIMENTS` draws from
#: ``SeedSequence([SEED, i])`` (one experiment regenerates alone to the same values).
SEED = 20261128

#: Sampling rate of the time series, Hz.
RATE_HZ = 1000

#: The "true" dynamic parameters of the synthetic data (defaults in docs/model.md), as a
#: scene's [parameters] writes them.
TRUTH = {
    "regulator.tau": "0.075 s",  # default 0.05 s: +50 %
    "aps.C_tube": "1.4e-9 m^3/(s*Pa)",  # default 2e-9: -30 %
    "aps.V0": "5.2e-6 m^3",  # default 4e-6 (4 cm^3): +30 %
    "aps.c_e": "2.8 N*s/m",  # default 2 N s/m: +40 %
    "aps.c_s": "0.3 N*s/m",  # default 0.5 N s/m: -40 %
}

#: The true hook mass, kg (default 1 g: +40 %); ``load.m`` = payload + hook.
HOOK_KG = 1.4e-3

#: Mismatch model: per-unit factors on ``A_p`` and ``A_r`` (3 units) and the thermal
#: model (adiabatic chambers with wall heat exchange).
SPREAD = {"A_p": (1.08, 0.95, 0.97), "A_r": (0.93, 1.06, 1.01)}
MISMATCH_THERMAL = {"aps.thermal": "adiabatic", "aps.tau_heat": "0.6 s"}

#: Written signals: column unit, its factor from SI, decimals written, noise sigma (SI).
SIGNALS = {
    "pressure": ("kPa", 1e-3, 4, 0.0),  # the command: exact (factor: SI to the unit)
    "myofibril.length": ("mm", 1e3, 6, 20e-6),  # camera / laser: 20 um
    "myofibril.aps1.chamber.p_gauge": ("kPa", 1e-3, 4, 500.0),  # sensor: 0.5 kPa
}
#: The noise standard deviations by measured signal, SI.
NOISE = {k: v[3] for k, v in SIGNALS.items() if v[3] > 0}

P_CMD = "regulator.p_cmd"


@dataclass(frozen=True)
class Experiment:
    """One data file: ``name`` (the CSV's stem), ``kind`` ("time-series" or "static"),
    ``setup`` ("hanging"), ``n``, ``payload_kg``, ``command``
    (time series: corners ``(t [s], p [Pa])`` of the piecewise-linear command, on the
    sampling grid; static: the pressure levels, Pa), ``duration`` [s], ``outputs`` and
    ``mismatch`` (the richer model)."""

    name: str
    kind: str
    setup: str
    n: int
    payload_kg: float
    command: tuple
    outputs: tuple[str, ...]
    duration: float = 0.0
    mismatch: bool = False


def _step(level: float, at: float = 0.05) -> tuple:
    dt = 1.0 / RATE_HZ
    return ((0.0, 0.0), (at - dt, 0.0), (at, level))


def _staircase(levels: tuple, start: float = 0.05, every: float = 0.25) -> tuple:
    dt, corners, last = 1.0 / RATE_HZ, [(0.0, 0.0)], 0.0
    for k, level in enumerate(levels):
        t = round(start + k * every, 6)
        corners += [(t - dt, last), (t, level)]
        last = level
    return tuple(corners)


TS_OUT = ("myofibril.length", "myofibril.aps1.chamber.p_gauge")
STAIRS = (3e4, 6e4, 9e4, 12e4)
LEVELS = tuple(k * 2e4 for k in range(7))  # 0 to 0.12 MPa

EXPERIMENTS = (
    Experiment("step-50g", "time-series", "hanging", 3, 0.05, _step(1e5), TS_OUT, 1.0),
    Experiment("staircase-100g", "time-series", "hanging", 3, 0.1, _staircase(STAIRS), TS_OUT, 1.0),
    Experiment("step-100g", "time-series", "hanging", 3, 0.1, _step(1.2e5), TS_OUT, 1.0),
    Experiment("concentric-50g", "static", "hanging", 3, 0.05, LEVELS, ("myofibril.length",)),
    Experiment(
        "mismatch-step-50g", "time-series", "hanging", 3, 0.05, _step(1e5), TS_OUT, 1.0, True
    ),
    Experiment(
        "mismatch-staircase-100g",
        "time-series",
        "hanging",
        3,
        0.1,
        _staircase(STAIRS),
        TS_OUT,
        1.0,
        True,
    ),
    Experiment(
        "mismatch-concentric-50g", "static", "hanging", 3, 0.05, LEVELS, TS_OUT[:1], 0.0, True
    ),
)


def true_parameters(exp: Experiment) -> dict[str, object]:
    """The scene ``[parameters]`` of ``exp``'s true model."""
    params: dict[str, object] = dict(TRUTH)
    params["load.m"] = f"{exp.payload_kg + HOOK_KG!r} kg"
    if exp.mismatch:
        from sarcomere.dynamics.components.aps import APSParams

        base = APSParams.from_paper("dragonskin_30")
        params.update(MISMATCH_THERMAL)
        for i in range(exp.n):
            params[f"myofibril.aps{i + 1}.chamber.A"] = f"{base.A_p * SPREAD['A_p'][i]!r} m^2"
            params[f"myofibril.aps{i + 1}.yeoh.A_r"] = f"{base.A_r * SPREAD['A_r'][i]!r} m^2"
    return params


def _bound(exp: Experiment):
    """The true model of ``exp`` and its parameter overrides, bound as a scene."""
    from ..binding import bind
    from ..loader import scenario_from_dict

    scene = {
        "scenario": {"name": exp.name, "kind": "transient"},
        "model": {"name": "myofibril", "n": exp.n, "options": {"setup": exp.setup}},
        "parameters": true_parameters(exp),
    }
    b = bind(scenario_from_dict(scene, f"<{exp.name}>"))
    return b.build("full"), b.overrides


def clean(exp: Experiment) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The noise-free data of ``exp``: the rows' index (time [s], or the pressure level
    [Pa] of a static curve) and each column in SI (``pressure`` the command)."""
    from sarcomere.dynamics.equilibrium import solve_equilibrium
    from sarcomere.dynamics.signals import Table
    from sarcomere.dynamics.simulation.settings import SolverSettings

    from ..binding import run

    model, params = _bound(exp)
    if exp.kind == "static":
        cols: dict[str, list] = {"pressure": [], **{s: [] for s in exp.outputs}}
        guess = None
        for level in exp.command:
            guess = solve_equilibrium(model, {P_CMD: level}, params, guess=guess, tol=1e-12)
            cols["pressure"].append(level)
            for s in exp.outputs:
                cols[s].append(guess[s])
        return np.asarray(exp.command), {k: np.asarray(v) for k, v in cols.items()}
    t = np.arange(round(exp.duration * RATE_HZ) + 1) / RATE_HZ
    times, values = zip(*exp.command, strict=True)
    command = Table(times=(*times, t[-1]), values=(*values, values[-1]), unit="Pa")
    settings = SolverSettings(method="cvodes", rtol=1e-10, atol=1e-12)
    result = run(model, {P_CMD: command}, params, t, settings, list(exp.outputs))
    return t, {"pressure": command(t), **{s: np.asarray(result[s]) for s in exp.outputs}}


def noisy(
    exp: Experiment, columns: dict[str, np.ndarray], replicate: int | None = None
) -> dict[str, np.ndarray]:
    """``columns`` with the measured signals' Gaussian noise (:data:`NOISE`), drawn from
    this experiment's own stream; ``replicate``: another draw (``SeedSequence([SEED, i,
    replicate])``, the coverage benchmark's), None the packaged one."""
    extra = [] if replicate is None else [replicate]
    rng = np.random.default_rng(np.random.SeedSequence([SEED, EXPERIMENTS.index(exp), *extra]))
    return {
        k: v + rng.normal(0.0, NOISE[k], v.shape) if k in NOISE else v for k, v in columns.items()
    }


def csv_text(exp: Experiment) -> str:
    """The CSV file of ``exp`` (header ``signal [unit]``, a comment line first)."""
    index, columns = clean(exp)
    columns = noisy(exp, columns)
    what = "mismatch model" if exp.mismatch else "synthetic truth"
    head = [f"# {exp.name}: {what}, made by python -m sarcomere.scenarios.fits.generate"]
    names = ([] if exp.kind == "static" else ["time"]) + list(columns)
    cells = [f"{n} [{SIGNALS[n][0]}]" if n in SIGNALS else "time [s]" for n in names]
    rows = [",".join(cells)]
    data = ([index] if exp.kind != "static" else []) + list(columns.values())
    formats = ["{:.3f}"] * (exp.kind != "static") + [f"{{:.{SIGNALS[n][2]}f}}" for n in columns]
    scales = [1.0] * (exp.kind != "static") + [SIGNALS[n][1] for n in columns]
    for i in range(len(index)):
        rows.append(
            ",".join(f.format(c[i] * s) for f, c, s in zip(formats, data, scales, strict=True))
        )
    return "\n".join(head + rows) + "\n"


def difference(new: str, old: str) -> str | None:
    """Why CSV text ``old`` is not ``new`` (None if it is): the comment and header lines
    must be equal, and every value within one unit of its last written digit (a value
    computed on another machine may round the other way)."""
    a, b = new.splitlines(), old.splitlines()
    if a[:2] != b[:2] or len(a) != len(b):
        return f"header or length differs ({len(a)} against {len(b)} lines)"
    for i, (x, y) in enumerate(zip(a[2:], b[2:], strict=True), start=3):
        if x.count(",") != y.count(","):
            return f"line {i}: {y!r}, the script gives {x!r}"
        for u, v in zip(x.split(","), y.split(","), strict=True):
            digits = len(u.partition(".")[2])
            if abs(float(u) - float(v)) > 1.01 * 10.0**-digits:
                return f"line {i}: {y!r}, the script gives {x!r}"
    return None


def data_dir() -> Path:
    """The packaged data folder (``scenarios/fits/data``)."""
    return Path(__file__).parent / "data"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sarcomere.scenarios.fits.generate")
    parser.add_argument("--out", type=Path, default=data_dir(), help="folder of the CSV files")
    parser.add_argument("--check", action="store_true", help="compare with --out, write nothing")
    parser.add_argument("names", nargs="*", help="experiments (default: all)")
    args = parser.parse_args(argv)
    chosen = [e for e in EXPERIMENTS if not args.names or e.name in args.names]
    different = []
    for exp in chosen:
        text, path = csv_text(exp), args.out / f"{exp.name}.csv"
        if args.check:
            why = difference(text, path.read_text()) if path.is_file() else "missing"
            if why:
                different.append(f"{path.name} ({why})")
        else:
            args.out.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            print(f"wrote {path}")
    if different:
        print(f"differ from the script: {', '.join(different)}", file=sys.stderr)
    return 1 if different else 0


if __name__ == "__main__":
    sys.exit(main())
