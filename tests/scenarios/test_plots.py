"""Default figures a person can read: few curves, one magnitude per axis, distinct styles."""

import subprocess
import sys
from pathlib import Path

import numpy as np

from sarcomere.dynamics.results import Result
from sarcomere.scenarios import load_scenario
from sarcomere.scenarios.cli import main
from sarcomere.scenarios.plots import MAX_CURVES, groups_by_unit, plot_groups

T = np.linspace(0.0, 1.0, 50)


def _many(count: int) -> Result:
    signals = {f"u{k}.s": 1e-3 * (1 + 0 * T) for k in range(count)}
    signals["length"] = 0.11 + 0 * T
    return Result("time", "s", T, signals, dict.fromkeys(signals, "m"))


def test_a_110_mm_and_a_1_mm_signal_do_not_share_an_axis():
    groups = groups_by_unit(_many(2), ["length", "u0.s", "u1.s"])
    assert groups == {"length": ("length",), "length_2": ("u0.s", "u1.s")}


def test_a_default_figure_draws_at_most_max_curves_and_says_so(tmp_path, monkeypatch):
    drawn = []
    from matplotlib.axes import Axes

    plot, title = Axes.plot, Axes.set_title
    monkeypatch.setattr(Axes, "plot", lambda ax, *a, **k: drawn.append(k) or plot(ax, *a, **k))
    titles = []
    monkeypatch.setattr(Axes, "set_title", lambda ax, t: titles.append(t) or title(ax, t))
    names = [f"u{k}.s" for k in range(200)]
    plot_groups({"main": _many(200)}, {"length_2": names}, tmp_path, "n100")
    assert len(drawn) == MAX_CURVES
    labels = [k["label"] for k in drawn]
    assert labels[0] == "u0.s" and labels[-1] == "u199.s"
    assert titles == [f"n100: length 2 ({MAX_CURVES} of 200 curves)"]
    styles = {(k["linestyle"], k["marker"]) for k in drawn}
    assert len(styles) == len(drawn)  # identical curves stay distinguishable


def test_the_step_scene_plots_the_command_with_the_pressures():
    plots = load_scenario("step-50g").outputs.plots
    assert "regulator.p_cmd" in plots["pressure"] and "regulator.p_out" in plots["pressure"]


def test_version(capsys):
    try:
        main(["--version"])
    except SystemExit as stop:
        assert stop.code == 0
    assert capsys.readouterr().out.startswith("sarcomere 0.")
    script = Path(sys.executable).parent / "sarcomere"
    done = subprocess.run([str(script), "--version"], capture_output=True, text=True, check=True)
    assert done.stdout.startswith("sarcomere ")


def test_a_signal_shared_by_every_result_is_one_curve():
    """Six controllers tracking one reference: the reference is drawn once ("all"), so the
    cap of 8 curves keeps every controller's output."""
    import numpy as np

    from sarcomere.dynamics.results import Result
    from sarcomere.scenarios.plots import _distinct_curves

    t = np.linspace(0.0, 1.0, 11)
    results = {
        f"c{k}": Result("time", "s", t, {"ref": t, "y": t + k}, {"ref": "m", "y": "m"})
        for k in range(6)
    }
    curves = _distinct_curves(results, ["ref", "y"])
    assert curves[0] == (list(results), "ref")
    assert [c for c in curves[1:]] == [([k], "y") for k in results]
