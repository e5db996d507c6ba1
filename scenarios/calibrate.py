"""``sarcomere calibrate``: fit the effective APS parameters to the paper's targets.

The fit is the packaged fit file ``fits/fit-paper.toml`` (:data:`FIT_PAPER`: the paper's
three numbers as data, through the fit engine: one home for fitting), its result verified
and assessed by :mod:`sarcomere.dynamics.calibration` (the targets re-solved from scratch,
the candidates' sensitivities, the compliance split); the same parameters as
``calibration.calibrate()`` to 1e-8 (tests/scenarios/test_fit_paper.py).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from .outdir import check_out_dir, staged
from .progress import progress

FIT_PAPER = Path(__file__).parent / "fits" / "fit-paper.toml"
"""The packaged fit of the calibration (docs/fitting.md, "fit-paper")."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--out DIR`` (default out/calibration), ``--verbose`` (the fit's and its
    continuation's log) and
    ``--family`` (also calibrate the L_r family and draw its concentric band)."""
    parser.add_argument(
        "--out",
        default="out/calibration",
        metavar="DIR",
        help="output folder for calibration.json (default: out/calibration)",
    )
    parser.add_argument("--verbose", action="store_true", help="print the fit's steps")
    parser.add_argument(
        "--family",
        action="store_true",
        help="also calibrate one member per restoring length L_r "
        "of the family (calibration.FAMILY_L_R; docs/paper.md) and write family.json, "
        "family.csv and concentric-family.png (the concentric strain band)",
    )


def handler(args: argparse.Namespace) -> int:
    """Run the calibration, write ``DIR/calibration.json`` and print a summary.

    ``--out`` is checked before the fit starts; the folder is replaced only on success.
    """
    # imported here, not at the top: `sarcomere calibrate --help` and argument errors
    # stay light (no CasADi)
    from sarcomere.dynamics.calibration import TARGETS, family

    out = check_out_dir(args.out, "--out")
    tic = time.perf_counter()
    with progress("calibrate", enabled=not args.verbose):
        res = calibrate_file(FIT_PAPER, verbose=args.verbose)
        members = family() if args.family else None
    wall = time.perf_counter() - tic
    record = {**res.to_dict(), "wall_time_s": wall}
    with staged(out) as tmp:  # every file of this run, or none
        (tmp / "calibration.json").write_text(json.dumps(record, indent=2) + "\n")
        if members is not None:
            _write_family(members, tmp)
    print(f"calibration {res.status}; {wall:.1f} s")
    for name, value in res.fitted.items():
        print(f"  {name:<4} = {value:.6g} {record['fitted'][name]['unit']}")
    for key, target in TARGETS.items():
        print(
            f"  {key:<24} {res.achieved[key]:.6g}  (target {target}, "
            f"residual {100 * res.residuals[key]:+.2e} %)"
        )
    print(
        f"  singular values of d log(targets)/d log(A_p, A_r, k_s): "
        f"{', '.join(f'{s:.3g}' for s in res.singular_values)}"
    )
    print(f"  no influence on these targets: {', '.join(res.not_identifiable)}")
    split = res.compliance_split["verdicts"]["L_r"]
    print(f"  compliance split (L_r fitted too): {split['verdict']}: {split['why']}")
    print(
        f"  3-APS rest length: L' = {1e3 * record['rest_length_hanging_n3_m']:.1f} mm hanging "
        f"(the ratios' L'), {1e3 * record['rest_length_undeformed_n3_m']:.2f} mm undeformed; "
        "measured 165 mm (docs/paper.md, 'Rest length')"
    )
    written = "calibration.json" + (
        ", family.json, family.csv, concentric-family.png" if members else ""
    )
    print(f"wrote {out}/: {written}")
    return 0


def calibrate_file(path: str | Path = FIT_PAPER, verbose: bool = False):
    """The calibration of fit file ``path`` (default :data:`FIT_PAPER`) through the fit
    engine (one start, no profiles), verified and assessed as
    :func:`~sarcomere.dynamics.calibration.calibrate`'s: a
    :class:`~sarcomere.dynamics.calibration.CalibrationResult`. The file must estimate
    exactly ``aps.A_p``, ``aps.A_r`` and ``aps.k_s`` (calibration.FITTED)."""
    from sarcomere.dynamics.calibration import FITTED, assessed, verified
    from sarcomere.dynamics.components.aps import APSParams
    from sarcomere.dynamics.errors import ParameterError

    from .fit.run import Fit

    fit = Fit.from_file(path)
    names = sorted(e.name for e in fit.built.params)
    if names != sorted(f"aps.{k}" for k in FITTED):
        raise ParameterError(
            "calibration fit file", f"{path}: {names}", f"estimates of aps.{', aps.'.join(FITTED)}"
        )
    run = fit.run(None, plots=False, profiles=False)
    sol = run.solution
    if verbose:
        print(f"calibration: fit file {path}: {sol.status}, {sol.iterations} iterations")
    values = {name.removeprefix("aps."): value for name, (value, _) in run.estimates.items()}
    how = (
        f"fit file '{fit.built.spec.name}', least squares (constrained Gauss-Newton) in "
        f"{sol.iterations} iterations"
    )
    return assessed(verified(APSParams.from_paper(), values, how, sol.iterations))


def _write_family(members, out: Path) -> None:
    """Write the L_r family's fits, its concentric strains and the band plot into ``out``."""
    from sarcomere.dynamics.calibration import CONCENTRIC_LOADS_KG, CONCENTRIC_PRESSURES_PA
    from sarcomere.dynamics.components.aps import APSParams

    default_L_r = APSParams.from_paper().L_r
    record = [
        {
            "L_r_m": m.L_r,
            "fitted": m.result.fitted,
            "achieved": m.result.achieved,
            "stretch_range": [m.concentric.stretch_min, m.concentric.stretch_max],
            "strain_0p1MPa": dict(
                zip(
                    (f"{1e3 * x:g} g" for x in CONCENTRIC_LOADS_KG),
                    m.concentric.strain[:, -1].tolist(),
                    strict=True,
                )
            ),
        }
        for m in members
    ]
    (out / "family.json").write_text(json.dumps(record, indent=2) + "\n")
    rows = ["L_r_m,load_kg,pressure_Pa,strain"]
    for m in members:
        for i, load in enumerate(CONCENTRIC_LOADS_KG):
            for j, pc in enumerate(CONCENTRIC_PRESSURES_PA):
                rows.append(f"{m.L_r:g},{load:g},{pc:g},{m.concentric.strain[i, j]:.9g}")
    (out / "family.csv").write_text("\n".join(rows) + "\n")
    print("calibration family (each meets the three targets):")
    for r in record:
        s = r["strain_0p1MPa"]
        print(
            f"  L_r = {1e3 * r['L_r_m']:4g} mm: stretch {r['stretch_range'][0]:.2f}.."
            f"{r['stretch_range'][1]:.2f}, strain at 0.1 MPa 50 g {100 * s['50 g']:+.2f} %, "
            f"100 g {100 * s['100 g']:+.2f} %"
        )
    _plot_family(members, default_L_r, out / "concentric-family.png")


def _plot_family(members, default_L_r: float, path: Path) -> None:
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from sarcomere.dynamics.calibration import CONCENTRIC_LOADS_KG, CONCENTRIC_PRESSURES_PA

    fig = Figure(figsize=(7, 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    p_kpa = np.array(CONCENTRIC_PRESSURES_PA) * 1e-3
    strains = np.array([m.concentric.strain for m in members]) * 100  # member, load, pressure
    for i, load in enumerate(CONCENTRIC_LOADS_KG):
        color = f"C{i}"
        ax.fill_between(
            p_kpa, strains[:, i].min(axis=0), strains[:, i].max(axis=0), color=color, alpha=0.25
        )
        k = min(range(len(members)), key=lambda j: abs(members[j].L_r - default_L_r))
        ax.plot(p_kpa, strains[k, i], color=color, label=f"{1e3 * load:g} g")
    lo, hi = min(m.L_r for m in members), max(m.L_r for m in members)
    ax.set_title(
        f"Concentric strain, 3 APS: default L_r = {1e3 * default_L_r:g} mm (lines), "
        f"band: L_r = {1e3 * lo:g}..{1e3 * hi:g} mm",
        fontsize=9,
    )
    ax.set_xlabel("pressure [kPa]")
    ax.set_ylabel("actuation strain [%]")
    ax.grid(True, alpha=0.3)
    ax.legend(title="load", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
