"""dynamics/units.py: quantities with units to SI floats, with and without pint."""

import random

import pint
import pytest

from sarcomere.dynamics import units
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.units import to_si

UREG = pint.UnitRegistry()
SI = {
    "pressure": "Pa",
    "length": "m",
    "mass": "kg",
    "time": "s",
    "force": "N",
    "frequency": "Hz",
    "area": "m^2",
    "stiffness": "N/m",
}


def _pint(text: str, unit: str) -> float:
    return float(UREG.Quantity(text).to(unit).magnitude)


@pytest.mark.parametrize("symbol", [s for s, (dim, _) in units._UNITS.items() if dim in SI])
def test_the_fast_path_gives_pints_float_exactly(symbol):
    """Every unit converted without pint, in its SI unit: the same float as pint, for
    plain, signed, exponent and leading-dot numbers (pint: magnitude times factor)."""
    target = SI[units._UNITS[symbol][0]]
    rng = random.Random(16)
    values = [rng.uniform(0, 1000) for _ in range(200)] + [0.1, 9.5, 1e5, 7.25e-3]
    texts = [f"{v!r} {symbol}" for v in values]
    texts += [f"-3.5{symbol}", f"1e5 {symbol}", f".5 {symbol}", f"  2E-3   {symbol} "]
    for text in texts:
        assert units._fast(text, target) is not None, text
        assert to_si(text, target) == _pint(text, target), text


@pytest.mark.parametrize("text", ["0.875", "1.07 1", "87.5 %", " -2e-3 ", ".5%"])
def test_dimensionless_values_without_pint(text):
    """A ratio in a fit's data or noise ("0.875", "87.5 %"): pint's float, without pint."""
    assert units._fast(text, "1") is not None
    assert to_si(text, "1") == _pint(text, "dimensionless")


def test_pint_still_decides_what_the_table_does_not_hold():
    assert to_si("2 N*s/m", "N*s/m") == 2.0  # a compound unit: pint
    assert to_si("1 bar", "kPa") == pytest.approx(100.0)  # a target that is not SI: pint
    assert to_si("30 deg", "rad") == pytest.approx(0.5235987755982988)
    assert to_si("0.5 inch", "m") == pytest.approx(0.0127)
    assert units._fast("50 g", "Pa") is None  # a mismatch is worded by pint:
    with pytest.raises(ParameterError, match="wrong dimension"):
        to_si("50 g", "Pa", "load")


def test_a_bare_number_in_a_string_still_needs_its_unit():
    with pytest.raises(ParameterError, match="needs a unit"):
        to_si("50", "kg", "load", bare_ok=False)
    assert to_si("50", "kg", "load") == 50.0
    assert to_si("0", "kg", "load", bare_ok=False) == 0.0
    assert to_si("5 %", "1") == pytest.approx(0.05)
