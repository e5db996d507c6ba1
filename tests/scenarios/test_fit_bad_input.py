"""Every bad input of a fit file or its data: a one-line FitError naming the file, the
line, the key, the value and what is allowed, before any solve (issue 25, "Bad input")."""

from __future__ import annotations

import numpy as np
import pytest

from sarcomere.dynamics.errors import SarcomereError
from sarcomere.scenarios.cli import main
from sarcomere.scenarios.fit.build import build
from sarcomere.scenarios.fit.data import sampling_note
from sarcomere.scenarios.fit.spec import FitError, load_fit

FIT = """\
[fit]
name = "bad"

[parameters."regulator.tau"]
start = "{start}"
bounds = ["10 ms", "200 ms"]
per_experiment = {per}

[noise."myofibril.length"]
sigma = "10 um"

[[experiments]]
name = "step"
kind = "time-series"
data = "step.csv"
inputs = ["pressure"]
outputs = ["{signal}"]
[experiments.model]
name = "myofibril"
n = 1
[experiments.model.options]
load = "50 g"
"""

GOOD_CSV = "time [ms],pressure [kPa],myofibril.length [mm]\n" + "".join(
    f"{t},{0 if t < 5 else 50},{59.2 + 0.01 * t}\n" for t in range(10)
)


def _write(tmp_path, csv=GOOD_CSV, start="50 ms", per="false", signal="myofibril.length"):
    (tmp_path / "step.csv").write_text(csv)
    path = tmp_path / "fit.toml"
    text = FIT.format(start=start, per=per, signal=signal)
    if signal != "myofibril.length":
        text = text.replace('[noise."myofibril.length"]', f'[noise."{signal}"]')
    path.write_text(text)
    return path


def _error(path) -> FitError:
    with pytest.raises(FitError) as info:
        build(load_fit(path))
    message = str(info.value)
    assert "\n" not in message
    return info.value


def test_good_file_builds(tmp_path):
    built = build(load_fit(_write(tmp_path)))
    assert [e.name for e in built.params] == ["regulator.tau"]
    assert built.problem.series[0].data.shape == (10, 1)
    # units taken to SI: mm -> m, kPa -> Pa, ms -> s
    assert built.problem.series[0].data[0, 0] == pytest.approx(0.0592)
    assert built.problem.series[0].u[9, 0] == pytest.approx(5e4)
    assert built.problem.series[0].t[1] == pytest.approx(1e-3)


@pytest.mark.parametrize(
    ("csv", "line", "key", "words"),
    [
        (
            "\n".join(ln.rsplit(",", 1)[0] for ln in GOOD_CSV.splitlines()),
            1,
            "myofibril.length",
            "no column",
        ),
        (
            GOOD_CSV.replace("myofibril.length [mm]", "myofibril.length"),
            1,
            "myofibril.length",
            "no unit",
        ),
        (GOOD_CSV.replace("\n3,", "\n1.5,"), 5, "time", "not increasing"),
        (GOOD_CSV.replace("\n3,", "\n2,"), 5, "time", "duplicate time"),
        (
            "\n".join(ln if not ln.startswith("3,") else "3,0,nan" for ln in GOOD_CSV.splitlines()),
            5,
            "myofibril.length",
            "NaN",
        ),
        (GOOD_CSV.replace("\n7,50,", "\n7,5000,"), 9, "pressure", "outside the input's range"),
        (GOOD_CSV.replace("pressure [kPa]", "pressure [mm]"), 1, "pressure", "is not a unit of Pa"),
    ],
    ids=[
        "missing-column",
        "unitless",
        "time-decreasing",
        "duplicate-time",
        "nan",
        "input-range",
        "wrong-unit",
    ],
)
def test_bad_csv(tmp_path, csv, line, key, words):
    err = _error(_write(tmp_path, csv=csv))
    assert err.file.endswith("step.csv") and err.line == line and err.key == key
    assert words in str(err)


def test_unknown_signal_names_the_nearest(tmp_path):
    err = _error(_write(tmp_path, signal="myofibril.lenght"))
    assert err.file.endswith("fit.toml") and err.line == 17 and "outputs" in err.key
    assert "myofibril.length" in str(err) and "lenght" in str(err)


def test_unknown_parameter_names_the_nearest(tmp_path):
    path = _write(tmp_path)
    path.write_text(path.read_text().replace('"regulator.tau"]', '"regulator.taux"]'))
    err = _error(path)
    assert err.line == 4 and "regulator.tau" in str(err) and "taux" in str(err)


def test_bounds_excluding_the_start(tmp_path):
    err = _error(_write(tmp_path, start="300 ms"))
    assert err.line == 5 and err.key == 'parameters."regulator.tau".start'
    assert "'300 ms' is outside the bounds [10 ms, 200 ms]" in str(err)


def test_bare_number_start_refused(tmp_path):
    err = _error(_write(tmp_path, start="0.05"))
    assert err.line == 5 and "unit" in str(err)


def test_per_experiment_parameter_in_a_single_experiment(tmp_path):
    err = _error(_write(tmp_path, per="true"))
    assert err.line == 7 and "per_experiment" in err.key and "single fitted experiment" in str(err)


def test_missing_noise_and_unknown_key(tmp_path):
    path = _write(tmp_path)
    path.write_text(path.read_text().replace('[noise."myofibril.length"]\nsigma = "10 um"\n', ""))
    assert "has no [noise" in str(_error(path))
    path.write_text(_write(tmp_path).read_text().replace('name = "bad"', 'name = "bad"\nstart = 3'))
    err = _error(path)
    assert err.line == 3 and "unknown key 'start'" in str(err)


def test_model_error_placed_in_its_experiment(tmp_path):
    path = _write(tmp_path)
    path.write_text(path.read_text().replace('load = "50 g"', 'load = "-5 g"'))
    err = _error(path)
    assert err.key == "experiments[1].model.options.load" and err.line == 22


def test_different_sampling_rates_allowed_and_stated(tmp_path):
    csv2 = "time [s],pressure [kPa],myofibril.length [mm]\n" + "".join(
        f"{t * 0.002},{0 if t < 3 else 50},{59.2}\n" for t in range(6)
    )
    path = _write(tmp_path)
    (tmp_path / "slow.csv").write_text(csv2)
    text = path.read_text()
    block = text[text.index("[[experiments]]") :]
    path.write_text(text + "\n" + block.replace('"step"', '"slow"').replace("step.csv", "slow.csv"))
    built = build(load_fit(path))
    note = sampling_note({b.spec.name: b.table for b in built.experiments})
    assert "different sampling intervals (allowed)" in note and "2 ms" in note and "1 ms" in note
    assert np.diff(built.problem.series[1].t)[0] == pytest.approx(2e-3)


@pytest.mark.slow
def test_cli_prints_one_line_and_exits_2(tmp_path, capsys):
    path = _write(tmp_path, start="300 ms")
    assert main(["fit", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "fit.toml:5" in err and "300 ms" in err
    assert not (tmp_path / "out").exists()


def test_fit_error_is_a_sarcomere_error():
    assert issubclass(FitError, SarcomereError)


@pytest.mark.parametrize(
    ("value", "words"), [("0", "expected an integer >= 1"), ("65", "at most 64"), ('"8"', "'8'")]
)
def test_a_bad_step_names_the_key(tmp_path, value, words):
    path = _write(tmp_path)
    path.write_text(path.read_text().replace('name = "bad"', f'name = "bad"\nstep = {value}'))
    err = _error(path)
    assert err.file.endswith("fit.toml") and err.line == 3 and err.key.endswith("step")
    assert words in str(err)


def test_a_step_the_file_sets_is_the_grid(tmp_path):
    path = _write(tmp_path)
    path.write_text(path.read_text().replace('name = "bad"', 'name = "bad"\nstep = 2'))
    built = build(load_fit(path))
    assert built.problem.shootings[0].step == 2
