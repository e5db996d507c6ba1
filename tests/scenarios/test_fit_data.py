"""The packaged fits' data (scenarios/fits/data) and the script that makes it
(``python -m sarcomere.scenarios.fits.generate``): regenerated data equals the packaged
CSV files, the stated truth is what the fit files' comments say and 20-60 % off the
defaults, the noise is as stated, and the data agree with an independent equilibrium."""

from __future__ import annotations

import re
import tomllib
from importlib import resources

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.units import to_si
from sarcomere.scenarios.fits import generate as gen

FITS = resources.files("sarcomere.scenarios.fits")


def _read(name: str) -> tuple[list[str], np.ndarray]:
    text = (FITS / "data" / f"{name}.csv").read_text()
    lines = [line for line in text.splitlines() if not line.startswith("#")]
    return lines[0].split(","), np.array([[float(v) for v in r.split(",")] for r in lines[1:]])


def _experiment(name: str) -> gen.Experiment:
    return next(e for e in gen.EXPERIMENTS if e.name == name)


@pytest.mark.slow
def test_regenerated_data_equal_the_packaged_files():
    """Every packaged CSV is what the script makes (to the last written digit), and every
    CSV of the folder is made by it, but fit-paper's three numbers typed from the paper
    (``paper-*.csv``; tests/scenarios/test_fit_paper.py holds them to calibration.TARGETS)."""
    for exp in gen.EXPERIMENTS:
        packaged = (FITS / "data" / f"{exp.name}.csv").read_text()
        assert gen.difference(gen.csv_text(exp), packaged) is None, exp.name
    made = {f"{e.name}.csv" for e in gen.EXPERIMENTS}
    typed = {"paper-isometric-1aps.csv", "paper-contraction-0g.csv", "paper-contraction-100g.csv"}
    assert {p.name for p in (FITS / "data").iterdir()} == made | typed


def test_one_static_curve_regenerates():
    """The concentric curve (fast: 7 equilibria) regenerates to the file."""
    text = (FITS / "data" / "concentric-50g.csv").read_text()
    assert gen.difference(gen.csv_text(_experiment("concentric-50g")), text) is None


def test_difference_sees_a_changed_value():
    text = (FITS / "data" / "concentric-50g.csv").read_text()
    lines = text.splitlines()
    cells = lines[4].split(",")
    cells[1] = f"{float(cells[1]) + 3e-6:.6f}"  # 3 nm: three units of the last digit
    changed = "\n".join([*lines[:4], ",".join(cells), *lines[5:]]) + "\n"
    assert "line 5" in gen.difference(text, changed)
    assert gen.difference(text, text) is None
    assert "length" in gen.difference(text, "\n".join(lines[:-1]) + "\n")


def test_truth_is_20_to_60_percent_off_the_defaults():
    aps = APSParams.from_paper("dragonskin_30")
    model = hanging_load(1)
    tau = model.parameters()[model.index("regulator.tau")[1]]
    for key, value in gen.TRUTH.items():
        name = key.removeprefix("aps.")
        default = tau if key == "regulator.tau" else getattr(aps, name)
        unit = "s" if key == "regulator.tau" else APSParams.unit(name)
        ratio = to_si(value, unit) / default
        assert 0.2 <= abs(ratio - 1) <= 0.6, (key, ratio)
    assert abs(gen.HOOK_KG / 1e-3 - 1) == pytest.approx(0.4)


@pytest.mark.parametrize("fit", ["fit-synthetic.toml", "fit-mismatch.toml"])
def test_fit_files_state_the_truth_and_point_at_the_data(fit):
    """The comments give the script's true values; every data file exists; the noise
    is the script's."""
    text = (FITS / fit).read_text()
    comments = "\n".join(line for line in text.splitlines() if line.startswith("#"))
    for key, value in gen.TRUTH.items():
        match = re.search(rf"{re.escape(key)}\s*=\s*([0-9.e-]+ [^\s,]+)", comments)
        assert match, key
        unit = "s" if key == "regulator.tau" else APSParams.unit(key.removeprefix("aps."))
        assert to_si(match[1], unit) == pytest.approx(to_si(value, unit), rel=1e-12)
    assert f"{gen.HOOK_KG * 1e3:g} g" in comments
    data = tomllib.loads(text)
    for exp in data["experiments"]:
        assert (FITS / exp["data"]).is_file()
        assert ("mismatch" in exp["name"]) == (fit == "fit-mismatch.toml")
        _experiment(exp["name"])  # made by the script
    for signal, spec in data["noise"].items():
        unit = "m" if "length" in signal else "Pa"
        assert to_si(spec["sigma"], unit) == pytest.approx(gen.NOISE[signal], rel=1e-12)


def test_noise_is_as_stated_and_the_steps_settle_on_the_equilibrium():
    """The step's tail (0.8-1 s, settled) scatters like the stated noise around the
    concentric curve's 100 kPa point, an equilibrium solved independently; the number
    of time-series points is about 6000."""
    head, step = _read("step-50g")
    assert head == [
        "time [s]",
        "pressure [kPa]",
        "myofibril.length [mm]",
        "myofibril.aps1.chamber.p_gauge [kPa]",
    ]
    assert np.allclose(np.diff(step[:, 0]), 1e-3)
    _, clean = gen.clean(_experiment("concentric-50g"))
    tail = step[step[:, 0] >= 0.8]
    residual = tail[:, 2] - clean["myofibril.length"][5] * 1e3  # mm, at 100 kPa
    assert abs(residual.mean()) < 4 * 0.020 / np.sqrt(len(tail))
    assert residual.std() == pytest.approx(0.020, rel=0.15)
    assert (tail[:, 3] - 100.0).std() == pytest.approx(0.5, rel=0.15)
    total = sum(_read(e.name)[1].shape[0] * 2 for e in gen.EXPERIMENTS[:3])
    assert 5500 <= total <= 6500
