"""Input signals: values, breakpoints, CasADi expressions, CSV tables, spec factory."""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from sarcomere.dynamics.errors import ParameterError, ScenarioError
from sarcomere.scenarios.signals import (
    Chirp,
    Ramp,
    Signal,
    Sine,
    Staircase,
    Step,
    Table,
    signal_from_spec,
)

SIGNALS = [
    Step(final=1e5, initial=2e4, time=1.0, unit="Pa"),
    Ramp(final=1e5, duration=2.0, initial=1e4, start=0.5, unit="Pa"),
    Staircase(levels=(0.0, 1e4, 3e4, 2e4), dwell=0.7, start=0.2, unit="Pa"),
    Sine(amplitude=2.0, frequency=1.5, offset=1.0, phase=0.3, start=0.4),
    Chirp(amplitude=3e4, f0=0.5, f1=10.0, duration=2.0, offset=5e4, start=0.3, unit="Pa"),
    Table(times=(0.0, 0.5, 2.0, 3.0), values=(0.0, 4.0, -1.0, 2.0)),
]


def test_step_values_and_breakpoints() -> None:
    s = Step(final=5.0, initial=1.0, time=2.0)
    assert s(np.array([0.0, 1.999, 2.0, 9.0])).tolist() == [1.0, 1.0, 5.0, 5.0]
    assert s(3.0) == 5.0 and isinstance(s(3.0), float)
    assert s.breakpoints(0.0, 10.0) == [2.0]
    assert s.breakpoints(2.0, 10.0) == []  # only strictly inside


def test_ramp_values_and_breakpoints() -> None:
    r = Ramp(final=3.0, duration=2.0, initial=1.0, start=1.0)
    assert r(np.array([0.0, 1.0, 2.0, 3.0, 4.0])).tolist() == [1.0, 1.0, 2.0, 3.0, 3.0]
    assert r.breakpoints(0.0, 10.0) == [1.0, 3.0]
    assert r.breakpoints(0.0, 2.0) == [1.0]
    with pytest.raises(ParameterError, match="duration"):
        Ramp(final=1.0, duration=0.0)


def test_staircase_values_and_breakpoints() -> None:
    s = Staircase(levels=(0.0, 10.0, 20.0), dwell=2.0, start=1.0)
    assert s(np.array([0.0, 2.9, 3.0, 5.0, 100.0])).tolist() == [0.0, 0.0, 10.0, 20.0, 20.0]
    assert s.breakpoints(0.0, 4.0) == [3.0]
    assert s.breakpoints(0.0, 10.0) == [3.0, 5.0]


def test_sine_values_and_breakpoints() -> None:
    s = Sine(amplitude=2.0, frequency=0.5, offset=1.0, start=1.0)
    assert s(np.array([0.0, 1.0, 1.5, 2.0])) == pytest.approx([1.0, 1.0, 3.0, 1.0])
    assert s.breakpoints(0.0, 5.0) == [1.0]


def test_table_interpolates_and_holds_ends() -> None:
    t = Table(times=(1.0, 2.0, 4.0), values=(0.0, 10.0, 0.0))
    assert t(np.array([0.0, 1.5, 3.0, 5.0])).tolist() == [0.0, 5.0, 5.0, 0.0]
    assert t.breakpoints(0.0, 3.0) == [1.0, 2.0]
    with pytest.raises(ParameterError, match="increasing"):
        Table(times=(0.0, 0.0), values=(1.0, 2.0))


@pytest.mark.parametrize("signal", SIGNALS, ids=lambda s: type(s).__name__)
@pytest.mark.parametrize("symbol", [ca.SX, ca.MX])
def test_casadi_expression_equals_numpy(signal: Signal, symbol: type) -> None:
    t = symbol.sym("t")
    f = ca.Function("f", [t], [signal.casadi(t)])
    grid = np.concatenate([np.linspace(-1.0, 4.0, 101), signal.breakpoints(-1.0, 4.0)])
    got = np.array([float(f(x)) for x in grid])
    assert got == pytest.approx(signal(grid), abs=1e-12)


def test_breakpoints_are_where_numpy_jumps() -> None:
    s = SIGNALS[2]
    for tb in s.breakpoints(0.0, 10.0):
        assert s(tb - 1e-9) != s(tb)


def test_from_spec_converts_units() -> None:
    spec = {"type": "ramp", "initial": "20 kPa", "final": "0.1 MPa", "duration": "500 ms"}
    r = signal_from_spec(spec, "Pa", "inputs.pressure")
    assert (r.initial, r.final, r.duration, r.start, r.unit) == (2e4, 1e5, 0.5, 0.0, "Pa")
    s = signal_from_spec({"type": "sine", "amplitude": 1, "frequency": "2 Hz"}, "N", "f")
    assert s.frequency == 2.0
    st = signal_from_spec({"type": "staircase", "levels": ["0 g", "50 g"], "dwell": 1}, "kg", "m")
    assert st.levels == pytest.approx((0.0, 0.05))


@pytest.mark.parametrize(
    ("spec", "name"),
    [
        ({"type": "pulse"}, "p.type"),
        ({"type": "step", "final": 1, "tim": 2}, "p.tim"),
        ({"type": "step"}, "p.final"),
        ({"type": "step", "final": "3 kg"}, "p.final"),
        ({"type": "ramp", "final": 1, "duration": "-1 s"}, "p.duration"),
        ({"type": "staircase", "levels": [1, "2 m"], "dwell": 1}, "p.levels[1]"),
    ],
)
def test_from_spec_errors_name_the_key(spec: dict, name: str) -> None:
    with pytest.raises(ParameterError) as info:
        signal_from_spec(spec, "Pa", "p")
    assert info.value.name == name


def test_table_from_csv_with_units_and_named_column(tmp_path: Path) -> None:
    (tmp_path / "p.csv").write_text(
        "# recorded command\ntime [ms],other,pressure [MPa]\n0,9,0\n\n500,9,0.05\n1000,9,0.1\n"
    )
    t = signal_from_spec(
        {"type": "table", "file": "p.csv", "column": "pressure"}, "Pa", "p", tmp_path
    )
    assert t.times == pytest.approx((0.0, 0.5, 1.0))
    assert t.values == pytest.approx((0.0, 5e4, 1e5))
    assert t(0.75) == pytest.approx(7.5e4)


def test_table_reads_a_run_timeseries(tmp_path: Path) -> None:
    (tmp_path / "ts.csv").write_text("time [s],load.s [m]\n0.0,0.01\n1.0,0.02\n")
    t = Table.from_csv(tmp_path / "ts.csv", "m")
    assert t(0.5) == pytest.approx(0.015)


@pytest.mark.parametrize(
    ("text", "line", "needle"),
    [
        ("time,p [Pa]\n0,1\n2,2\n1,3\n", 4, "increasing"),
        ("time,p [Pa]\n0,1\n1,abc\n", 3, "numbers"),
        ("time,p [Pa]\n0,1\n1,nan\n", 3, "non-finite"),
        ("time,p\n0,1\n", None, "two data rows"),
        ("time [kg],p [Pa]\n0,1\n1,2\n", None, "wrong dimension"),
        ("time,p\n0,0.1\n1,0.2\n", 1, "column 'p' states no unit"),
    ],
)
def test_table_csv_errors(tmp_path: Path, text: str, line: int | None, needle: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=needle) as info:
        Table.from_csv(path, "Pa", key="inputs.p.file")
    assert (info.value.file, info.value.line, info.value.key) == (str(path), line, "inputs.p.file")


def test_table_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="readable CSV") as info:
        signal_from_spec({"type": "table", "file": "none.csv"}, "Pa", "inputs.p", tmp_path)
    assert info.value.name == "inputs.p.file"


def test_signals_are_frozen() -> None:
    with pytest.raises(AttributeError):
        SIGNALS[0].final = 0.0  # type: ignore[misc]


def test_chirp_sweeps_its_frequency_and_holds_after() -> None:
    c = Chirp(amplitude=1.0, f0=1.0, f1=3.0, duration=1.0)
    # instantaneous frequency f0 + (f1 - f0) t / T: zero crossings get closer
    t = np.linspace(0.0, 1.0, 20001)
    crossings = t[1:][np.diff(np.sign(c(t))) != 0]
    assert np.all(np.diff(np.diff(crossings)) < 1e-3)
    assert c(1.5) == pytest.approx(c(1.0))
    assert c.breakpoints(0.0, 2.0) == [1.0]


def test_binary_table_file_names_the_file_and_the_problem(tmp_path: Path) -> None:
    """Issue 16 bug 4: binary bytes gave a raw UnicodeDecodeError traceback."""
    (tmp_path / "p.csv").write_bytes(b"time [s],p [Pa]\n0,1\n\xff\xfe\x00,2\n")
    spec = {"type": "table", "file": "p.csv"}
    with pytest.raises(ParameterError) as info:
        signal_from_spec(spec, "Pa", "inputs.pressure", tmp_path)
    assert info.value.name == "inputs.pressure.file"
    msg = str(info.value)
    assert "p.csv" in msg and "not UTF-8 text: byte 0xff at offset 20 (line 3)" in msg


@pytest.mark.parametrize("kind", ["directory", "fifo"])
def test_table_file_that_is_no_file_says_what_it_is(tmp_path: Path, kind: str) -> None:
    path = tmp_path / "p.csv"
    path.mkdir() if kind == "directory" else __import__("os").mkfifo(path)
    with pytest.raises(ParameterError, match="is a (directory|FIFO .named pipe.), not a file"):
        Table.from_csv(path, "Pa")  # a FIFO is never opened: it would block


def test_a_dense_table_is_read_whole_and_integrated_without_a_restart_per_row(
    tmp_path: Path,
) -> None:
    """A 500 k-row recording ran for over 10 minutes: every row was an integrator restart.
    Up to TABLE_MAX_BREAKPOINTS rows inside the run stay restarts; beyond, none."""
    from sarcomere.dynamics import signals

    rows = signals.TABLE_MAX_BREAKPOINTS + 1
    t = np.linspace(0.0, 1.0, rows + 2)
    lines = "\n".join(f"{a!r},{float(np.sin(a))!r}" for a in t.tolist())
    (tmp_path / "d.csv").write_text("time [s],y [1]\n" + lines + "\n")
    table = Table.from_csv(tmp_path / "d.csv", "1")
    assert table.times == tuple(t.tolist()) and table(0.3) == pytest.approx(np.sin(0.3), 1e-6)
    assert table.breakpoints(0.0, 1.0) == []
    assert table.breakpoints(0.0, 0.5) == [x for x in t.tolist() if 0 < x < 0.5]


def test_a_table_above_the_row_limit_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    from sarcomere.dynamics import signals

    monkeypatch.setattr(signals, "TABLE_MAX_ROWS", 4)
    with pytest.raises(ParameterError, match="'5 rows'.*resample it.*at most 4 rows"):
        Table(times=(0.0, 1.0, 2.0, 3.0, 4.0), values=(0.0,) * 5)
