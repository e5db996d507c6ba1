"""Straight-line Python source generated from a CasADi SX Function.

The baseline a user would write by hand, a numpy/``math`` right-hand side, without a
second copy of the physics: every instruction of the SX algorithm becomes one line of
plain Python on floats, compiled once with :func:`compile`. :func:`register_baseline`
adds the method ``scipy_radau_numpy`` (scipy's Radau on this Python right-hand side, with
scipy's finite-difference Jacobian) to the method registry, for the studies and the speed
benchmarks that ask for it (importing this module registers nothing); not a fast path, and
the library never imports it.
"""

from __future__ import annotations

import math

import casadi as cs
import numpy as np

from ..errors import ModelError
from ..simulation.scipy_methods import register_scipy_variant

_BINARY = {
    cs.OP_ADD: "{0} + {1}",
    cs.OP_SUB: "{0} - {1}",
    cs.OP_MUL: "{0} * {1}",
    cs.OP_DIV: "_div({0}, {1})",
    cs.OP_POW: "_pow({0}, {1})",
    cs.OP_CONSTPOW: "_pow({0}, {1})",
    cs.OP_LT: "float({0} < {1})",
    cs.OP_LE: "float({0} <= {1})",
    cs.OP_EQ: "float({0} == {1})",
    cs.OP_NE: "float({0} != {1})",
    cs.OP_AND: "float(bool({0}) and bool({1}))",
    cs.OP_OR: "float(bool({0}) or bool({1}))",
    cs.OP_FMIN: "min({0}, {1})",
    cs.OP_FMAX: "max({0}, {1})",
    cs.OP_IF_ELSE_ZERO: "({1} if {0} else 0.0)",
    cs.OP_ATAN2: "math.atan2({0}, {1})",
    cs.OP_COPYSIGN: "math.copysign({0}, {1})",
    cs.OP_FMOD: "math.fmod({0}, {1})",
    cs.OP_HYPOT: "math.hypot({0}, {1})",
}
_UNARY = {
    cs.OP_ASSIGN: "{0}",
    cs.OP_NEG: "-{0}",
    cs.OP_SQ: "{0} * {0}",
    cs.OP_TWICE: "2.0 * {0}",
    cs.OP_INV: "_div(1.0, {0})",
    cs.OP_SQRT: "_ieee(math.sqrt, {0})",
    cs.OP_EXP: "_ieee(math.exp, {0})",
    cs.OP_LOG: "_ieee(math.log, {0})",
    cs.OP_SIN: "math.sin({0})",
    cs.OP_COS: "math.cos({0})",
    cs.OP_TAN: "math.tan({0})",
    cs.OP_ASIN: "_ieee(math.asin, {0})",
    cs.OP_ACOS: "_ieee(math.acos, {0})",
    cs.OP_ATAN: "math.atan({0})",
    cs.OP_SINH: "math.sinh({0})",
    cs.OP_COSH: "math.cosh({0})",
    cs.OP_TANH: "math.tanh({0})",
    cs.OP_ASINH: "math.asinh({0})",
    cs.OP_ACOSH: "math.acosh({0})",
    cs.OP_ATANH: "math.atanh({0})",
    cs.OP_FABS: "abs({0})",
    cs.OP_FLOOR: "float(math.floor({0}))",
    cs.OP_CEIL: "float(math.ceil({0}))",
    cs.OP_SIGN: "_sign({0})",
    cs.OP_NOT: "float(not {0})",
    cs.OP_ERF: "math.erf({0})",
    cs.OP_LOG1P: "math.log1p({0})",
    cs.OP_EXPM1: "math.expm1({0})",
}


def _pow(a: float, b: float) -> float:
    try:
        r = a**b
    except (ZeroDivisionError, OverflowError):
        return math.inf
    return r if isinstance(r, float) else math.nan  # a negative base: complex in Python


def _div(a: float, b: float) -> float:
    """IEEE division: CasADi evaluates both branches of if_else, so 0-divisions occur."""
    try:
        return a / b
    except ZeroDivisionError:
        return math.nan if a == 0 or a != a else math.copysign(math.inf, a) * math.copysign(1.0, b)


def _ieee(fn, a: float) -> float:
    """``fn(a)``, or NaN/inf where Python raises and C would return them."""
    try:
        return fn(a)
    except ValueError:
        return -math.inf if fn is math.log and a == 0 else math.nan
    except OverflowError:
        return math.inf


def _sign(a: float) -> float:
    return float((a > 0) - (a < 0))


def python_source(F: cs.Function) -> str:
    """The source of ``def <name>(i0, i1, ...)`` returning one flat array per output
    (the output nonzeros), for an SX Function ``F``."""
    if not F.is_a("SXFunction"):
        raise ModelError(f"python_source needs an SX Function, got {F.class_name()}")
    args = ", ".join(f"i{k}" for k in range(F.n_in()))
    lines = [f"def {F.name()}({args}):"]
    lines += [f"    o{k} = _zeros({F.nnz_out(k)})" for k in range(F.n_out())]
    for k in range(F.n_instructions()):
        op, ins, outs = F.instruction_id(k), F.instruction_input(k), F.instruction_output(k)
        if op == cs.OP_INPUT:
            lines.append(f"    w{outs[0]} = float(i{ins[0]}[{ins[1]}])")
        elif op == cs.OP_OUTPUT:
            lines.append(f"    o{outs[0]}[{outs[1]}] = w{ins[0]}")
        elif op == cs.OP_CONST:
            lines.append(f"    w{outs[0]} = {float(F.instruction_constant(k))!r}")
        elif op in _BINARY:
            lines.append(f"    w{outs[0]} = " + _BINARY[op].format(f"w{ins[0]}", f"w{ins[1]}"))
        elif op in _UNARY:
            lines.append(f"    w{outs[0]} = " + _UNARY[op].format(f"w{ins[0]}"))
        else:
            raise ModelError(f"python_source: CasADi operation {op} is not translated")
    lines.append("    return " + ", ".join(f"o{k}" for k in range(F.n_out())) + ",")
    return "\n".join(lines) + "\n"


def python_function(F: cs.Function):
    """Compile :func:`python_source` of ``F``; returns the callable."""
    src = python_source(F)
    namespace = {
        "math": math,
        "_pow": _pow,
        "_sign": _sign,
        "_div": _div,
        "_ieee": _ieee,
        "_zeros": np.zeros,
    }
    exec(compile(src, f"<sarcomere.pysource {F.name()}>", "exec"), namespace)  # noqa: S102
    return namespace[F.name()]


class PythonCall:
    """A Function of (t, x, w, p) as generated straight-line Python, called as ``f(t, x)``
    (the scipy methods' call interface; the input law's argument is set as ``call.w``)."""

    def __init__(self, F: cs.Function, p: np.ndarray) -> None:
        self.f, self.p = python_function(F), np.asarray(p, float)
        self.w = np.zeros(F.size1_in(2))

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        return self.f((t,), x, self.w, self.p)[0]


BASELINE = "scipy_radau_numpy"
"""The name of the baseline method :func:`register_baseline` registers."""


def register_baseline() -> str:
    """Register the method :data:`BASELINE` (again: a no-op) and return its name."""
    register_scipy_variant(
        BASELINE, "scipy_radau", "python", PythonCall, {"jacobian": "finite_differences"}
    )
    return BASELINE
