"""The landing page's figure, drawn at every build from the library as it is (a figure
in the repository would show an older model): the 50 g step of ``step-50g``."""

from __future__ import annotations

from pathlib import Path


def draw(path: Path) -> Path:
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from sarcomere.dynamics import Step, hanging_load, simulate, solve_equilibrium

    model = hanging_load(n=3, load_kg=0.05)
    rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
    step = {"regulator.p_cmd": Step(final=0.1, time=0.1, unit="MPa")}
    res = simulate(model, 1.5, inputs=step, x0=rest.x, output_interval=2e-3)
    fig, (ax_p, ax_l) = plt.subplots(1, 2, figsize=(9, 2.8))
    ax_p.plot(res.index, res["regulator.p_out"] / 1e3, label="regulator")
    ax_p.plot(res.index, res["myofibril.aps3.chamber.p_gauge"] / 1e3, label="lowest chamber")
    ax_p.set(xlabel="time [s]", ylabel="gauge pressure [kPa]")
    ax_p.legend()
    ax_l.plot(res.index, res["myofibril.length"] * 1e3, color="C3")
    ax_l.set(xlabel="time [s]", ylabel="chain length [mm]", title="3 units lift 50 g")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
