"""Component laws built once and replayed: one CasADi call per instance, not one per
operation.

Each arithmetic operation on CasADi symbols from Python costs some 10-20 us of
interpreter and wrapper overhead, against well under a microsecond for CasADi itself. A
component of a chain repeats the same law for every unit; :func:`apply` builds the law
once as an SX Function of fresh symbols and evaluates it symbolically on each
instance's symbols. Evaluating an SX Function on SX arguments replays its operations
(with the same simplifications), so the result is the expression the law would have
built directly.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence

import casadi as cs

_CACHE: dict[tuple, cs.Function] = {}


def apply(law: Callable[..., Sequence[cs.SX]], args: Sequence, **options: Hashable) -> list:
    """``law(*args, **options)``: a sequence of scalar SX expressions of the scalar
    arguments ``args`` (SX or floats), through an SX Function cached per law, options
    and number of arguments.

    ``options`` are what else shapes the law (flags, constants that CasADi should fold);
    the law may not read symbols other than its arguments (CasADi refuses free symbols).
    """
    key = (law, tuple(sorted(options.items())), len(args))
    f = _CACHE.get(key)
    if f is None:
        syms = [cs.SX.sym(f"a{i}") for i in range(len(args))]
        f = _CACHE[key] = cs.Function("law", syms, list(law(*syms, **options)))
    return f.call([a if isinstance(a, cs.SX) else cs.SX(a) for a in args])
