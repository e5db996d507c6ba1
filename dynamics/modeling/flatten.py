"""Flattening: connection equations, structural analysis (BLT) and symbolic elimination.

Steps, as a Modelica tool does them:

1. Connection sets (union-find over ports): potentials equal, flows sum to zero;
   an unconnected port gets ``flow == 0``.
2. Structural check: as many equations as algebraic unknowns, and a perfect matching
   between them (scipy's bipartite matching); otherwise a :class:`ModelError` names
   the equations or variables left over.
3. Block-lower-triangular order: strongly connected components of the
   equation-dependency graph (scipy), ordered topologically (graphlib).
4. Each scalar block that is linear in its unknown is solved symbolically and
   substituted forward (aliases, definitions ``v = rhs`` and flow balances, most
   blocks, read off their equation's form without differentiating). Larger blocks
   (algebraic loops) are torn: equations linear in one of the loop's unknowns (aliases,
   force balances) are solved and substituted;
   what remains stays as the algebraic part ``0 = g(x, z, u, p)`` of a semi-explicit
   DAE (a structurally or numerically singular remainder is a ModelError).
5. Velocities asked for with ``Builder.der_of`` (dampers) become ``d expr/dx . f``; a
   linear loop among them (a damper on a viscous node) is solved.

Connection sets also share the start value one member declares (Newton guesses of
algebraic potentials).

Storage components (masses, chambers) alternating with transport components
(springs, threads, orifices) give an explicit ODE with no algebraic part.
"""

from __future__ import annotations

import graphlib
import math
from dataclasses import replace

import casadi as cs
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, maximum_bipartite_matching

from ..errors import ModelError
from .model import Model
from .variables import Collected, Var

Equation = tuple[cs.SX, str, object]
"""Residual, origin, and its form: ``(lhs, rhs)`` for ``lhs - rhs``, a list of flows for
their sum, or None (see :func:`_direct_solutions`)."""


def _connection_equations(c: Collected, variables: dict[str, Var]) -> list[Equation]:
    parent: dict[int, int] = {id(p): id(p) for p in c.ports}

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in c.connections:
        parent[find(id(a))] = find(id(b))
    sets: dict[int, list] = {}
    for p in c.ports:
        sets.setdefault(find(id(p)), []).append(p)
    eqs = []
    for members in sets.values():
        _share_start(variables, [p.potential.name() for p in members])
        where = "connect(" + ", ".join(p.path for p in members) + ")"
        first = members[0]
        for other in members[1:]:
            pair = (other.potential, first.potential)
            eqs.append((pair[0] - pair[1], where, pair))
        flows = [p.flow for p in members]
        eqs.append((_sum(flows), where, flows))
    return eqs


def _sum(terms: list[cs.SX]) -> cs.SX:
    """``0 + t1 + t2 + ...``, the same expression as ``sum(terms, SX(0))`` (CasADi drops
    the ``0 +``) with one operation less."""
    return sum(terms[1:], terms[0]) if terms else cs.SX(0)


def _start_nominals(c: Collected, variables: dict[str, Var]) -> None:
    """Nominal values of the expression starts declared without one: ``|start|`` at the
    parameter defaults (1 where that is 0 or not finite), all in one evaluation."""
    if not c.start_nominals:
        return
    starts = cs.vertcat(*c.start_nominals.values())
    pars = cs.symvar(starts)
    values = cs.DM([variables[s.name()].value for s in pars])
    at_defaults = np.array(cs.evalf(cs.substitute(starts, cs.vertcat(*pars), values)))
    for name, v in zip(c.start_nominals, at_defaults.ravel(), strict=True):
        val = abs(float(v))
        variables[name] = replace(variables[name], nominal=val if 0.0 < val < math.inf else 1.0)


def _share_start(variables: dict[str, Var], names: list[str]) -> None:
    """Give every potential of a connection set the start value (a nonzero float or a
    parameter expression) and nominal value one of them declares."""
    given = [v for v in (variables[n] for n in names) if isinstance(v.start, cs.SX) or v.start]
    if given:
        start, nominal = given[0].start, given[0].nominal
        for n in names:
            v = variables[n]
            if v.start is not start or v.nominal != nominal:  # else it has them already
                variables[n] = replace(v, start=start, nominal=nominal)


class _Solved:
    """Solved unknowns as vectors of their symbols and definitions, built once (CasADi
    converts a list element by element, several times slower than a vector)."""

    def __init__(self, names: list[str], syms: cs.SX, defs: cs.SX) -> None:
        self.names, self.syms, self.defs = names, syms, defs

    def as_dict(self) -> dict[str, cs.SX]:
        """Name -> definition."""
        return dict(zip(self.names, cs.vertsplit(self.defs), strict=True)) if self.names else {}

    def substitute(self, exprs: dict) -> dict:
        """``exprs`` with every solved unknown replaced (the definitions are free of
        them), in one pass over the shared expression graph."""
        if not exprs or not self.names:
            return dict(exprs)
        out = cs.substitute(cs.vertcat(*exprs.values()), self.syms, self.defs)
        return dict(zip(exprs, cs.vertsplit(out), strict=True))


def _resolve(known: dict[str, cs.SX], symbols: dict[str, cs.SX]) -> _Solved:
    """Definitions in solve (BLT) order, each in terms of earlier ones, rewritten in terms
    of the states, the algebraic unknowns kept, inputs and parameters (one ordered pass)."""
    if not known:
        return _Solved([], cs.SX(0, 1), cs.SX(0, 1))
    syms, defs = cs.vertcat(*[symbols[n] for n in known]), cs.vertcat(*known.values())
    (defs,), _ = cs.substitute_inplace([syms], [defs], [], False)
    return _Solved(list(known), syms, defs)


def _linear_solution(e: cs.SX, v: cs.SX, others: cs.SX) -> cs.SX | None:
    """``v`` solved from ``e = 0``, ``-e(v = 0) / (de/dv)``, if ``e`` is linear in ``v`` with
    a coefficient free of ``others``; else None."""
    slope = cs.jacobian(e, v)
    if slope.is_zero() or cs.depends_on(slope, cs.vertcat(v, others)):
        return None
    return -cs.substitute(e, v, cs.SX(0)) / slope


def _tear(
    eqs: list[cs.SX], unknowns: list[cs.SX], known: dict[str, cs.SX]
) -> tuple[list[cs.SX], list[cs.SX]]:
    """Greedy tearing of an algebraic loop: solve equations that are linear in one of the
    loop's unknowns (aliases, flow balances) and substitute, keeping the rest as residuals.

    Solved unknowns go into ``known``. If the torn residual system is structurally
    singular, the untorn block is returned unchanged.
    """
    original = (list(eqs), list(unknowns))
    eqs, unknowns = list(eqs), list(unknowns)
    solved: dict[str, cs.SX] = {}
    progress = True
    while progress and len(eqs) > 1:
        progress = False
        order = sorted(range(len(eqs)), key=lambda i: len(cs.symvar(eqs[i])))
        for i in order:
            e = eqs[i]
            present = [v for v in unknowns if cs.depends_on(e, v)]
            for v in present:
                rest = cs.vertcat(*[u for u in unknowns if u is not v])
                sol = _linear_solution(e, v, rest)
                if sol is None:
                    continue
                eqs = [cs.substitute(x, v, sol) for j, x in enumerate(eqs) if j != i]
                solved = {k: cs.substitute(x, v, sol) for k, x in solved.items()}
                solved[v.name()] = sol
                unknowns = [u for u in unknowns if u is not v]
                progress = True
                break
            if progress:
                break
    if len(eqs) != len(unknowns) or not _structurally_regular(eqs, unknowns):
        return original
    known.update(solved)
    return eqs, unknowns


def _structurally_regular(eqs: list[cs.SX], unknowns: list[cs.SX]) -> bool:
    if not eqs:
        return True
    jac = cs.jacobian_sparsity(cs.vertcat(*eqs), cs.vertcat(*unknowns))
    rows, cols = jac.get_triplet()
    n = len(eqs)
    inc = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    return bool(np.all(maximum_bipartite_matching(inc, perm_type="column") >= 0))


def _blocks(residuals: cs.SX, unknowns: cs.SX, origins: list[str], names: list[str]):
    """Matching + SCCs: a list of blocks (equation indices, unknown indices) in solve order."""
    n = unknowns.numel()
    jac = cs.jacobian_sparsity(residuals, unknowns)
    rows, cols = jac.get_triplet()
    inc = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    match = maximum_bipartite_matching(inc, perm_type="column")  # eq -> unknown
    if np.any(match < 0):
        bad_eq = [origins[i] for i in np.flatnonzero(match < 0)][:8]
        used = set(match[match >= 0].tolist())
        bad_var = [names[j] for j in range(n) if j not in used][:8]
        raise ModelError(
            "structurally singular system: equations from "
            f"{sorted(set(bad_eq))} have no unknown left to determine, and unknowns "
            f"{bad_var} are not determined by any equation (check connections and causality)"
        )
    var_to_eq = np.empty(n, dtype=int)
    var_to_eq[match] = np.arange(n)
    # eq i depends on eq j when eq i uses the unknown matched to eq j
    dep = sp.csr_matrix((np.ones(len(rows)), (rows, var_to_eq[cols])), shape=(n, n))
    ncomp, labels = connected_components(dep, directed=True, connection="strong")
    comp_deps: dict[int, set[int]] = {k: set() for k in range(ncomp)}
    d = dep.tocoo()
    # Python ints, not numpy scalars (the same sets, in the same order, built faster)
    for a, b in zip(labels[d.row].tolist(), labels[d.col].tolist(), strict=True):
        if a != b:
            comp_deps[a].add(b)
    members: dict[int, list[int]] = {}
    for i, lab in enumerate(labels.tolist()):
        members.setdefault(lab, []).append(i)
    order = graphlib.TopologicalSorter(comp_deps).static_order()
    matched = match.tolist()
    return [(members[k], [matched[i] for i in members[k]]) for k in order]


def _is(e: cs.SX, v: int) -> bool:
    """``e`` is the scalar symbol whose element hash is ``v``."""
    return e.is_symbolic() and e.is_scalar() and e.element_hash() == v


def _direct_solutions(
    eqs: list[Equation], blocks: list, unknowns: cs.SX, names: list[str], symbols
) -> dict[int, cs.SX]:
    """Solutions of the scalar blocks that need no differentiation: ``v - rhs`` or
    ``lhs - v`` with the other side free of ``v`` (and not a constant) gives that side,
    a flow sum with ``v`` in it minus the sum of the other flows. Block index -> solution:
    the expression the general path (``-e(v = 0) / (de/dv)``) simplifies to."""
    out: dict[int, cs.SX] = {}
    sides: dict[int, tuple[cs.SX, int]] = {}
    for k, (eq_idx, var_idx) in enumerate(blocks):
        form = eqs[eq_idx[0]][2] if len(eq_idx) == 1 else None
        if form is None:
            continue
        v = symbols[names[var_idx[0]]].element_hash()
        if isinstance(form, list):  # a flow sum: distinct flow symbols
            mine = [f.element_hash() == v for f in form]
            if sum(mine) == 1:
                out[k] = -_sum([f for f, m in zip(form, mine, strict=True) if not m])
            continue
        lhs, rhs = form
        for mine, other in ((lhs, rhs), (rhs, lhs)):
            if _is(mine, v) and not other.is_constant():
                sides[k] = (other, var_idx[0])
                break
    if sides:
        dep = cs.jacobian_sparsity(cs.vertcat(*[o for o, _ in sides.values()]), unknowns)
        uses = set(zip(*dep.get_triplet(), strict=True))
        for row, (k, (other, col)) in enumerate(sides.items()):
            if (row, col) not in uses:
                out[k] = other
    return out


MAX_RATE_LOOP = 64
"""Largest linear loop of ``der_of`` rates solved symbolically (a dense solve)."""


def _resolve_time_derivatives(c: Collected, solved: _Solved, ders: dict[str, cs.SX]) -> _Solved:
    """Replace each ``der_of`` variable ``w = d expr/dt`` by ``d expr/dx . f(x, w, ...)``.

    ``expr`` must be a function of the states. Where the rates depend on each other
    through the dynamics (a damper on a first-order viscous node), the loop is linear
    in the rates and is solved: ``(I - dR/dw) w = R(w = 0)``.
    """
    x = cs.vertcat(*[c.symbols[n] for n in ders])
    f = cs.vertcat(*ders.values())
    params = {n for n, v in c.variables.items() if v.kind in ("parameter", "input")}
    exprs = solved.substitute(c.time_derivatives)
    names = list(exprs)
    allowed = params.union(ders)
    if any(s.name() not in allowed for s in cs.symvar(cs.vertcat(*exprs.values()))):
        for name, e in exprs.items():
            others = {s.name() for s in cs.symvar(e)} - allowed
            if others:
                raise ModelError(
                    f"'{name}' needs the time derivative of an expression of {sorted(others)}, "
                    "which are not states: attach the element to masses or viscous nodes"
                )
    rates = [cs.mtimes(cs.jacobian(exprs[name], x), f) for name in names]
    w = cs.vertcat(*[c.symbols[n] for n in names])
    R = cs.vertcat(*rates)
    if cs.depends_on(R, w):
        J = cs.jacobian(R, w)
        if cs.depends_on(J, w) or len(names) > MAX_RATE_LOOP:
            raise ModelError(
                f"the rates {names[:6]} depend on each other nonlinearly or in a loop larger "
                f"than {MAX_RATE_LOOP}: give the elements inertia (choose another level)"
            )
        R = cs.solve(cs.SX.eye(len(names)) - J, cs.substitute(R, w, cs.SX.zeros(w.shape)))
    defs = cs.substitute(cs.vertcat(solved.defs, R), w, R)
    return _Solved(solved.names + names, cs.vertcat(solved.syms, w), defs)


def flatten(name: str, c: Collected) -> Model:
    """Turn collected declarations into a :class:`Model` (see module docstring)."""
    missing = [v for v, var in c.variables.items() if var.kind == "state" and v not in c.ders]
    if missing:
        raise ModelError(f"states without a derivative equation: {missing}")
    variables = dict(c.variables)  # the Model's own copy: the System stays as declared
    _start_nominals(c, variables)
    eqs = list(c.equations) + _connection_equations(c, variables)
    unknown_names = [v for v, var in c.variables.items() if var.kind == "algebraic"]
    if len(eqs) != len(unknown_names):
        raise ModelError(
            f"system '{name}' has {len(eqs)} equations for {len(unknown_names)} unknowns"
        )
    known: dict[str, cs.SX] = {}
    kept_eqs: list[cs.SX] = []
    kept_vars: list[str] = []
    if eqs:
        residuals = cs.vertcat(*[e[0] for e in eqs])
        unknowns = cs.vertcat(*[c.symbols[v] for v in unknown_names])
        origins = [e[1] for e in eqs]
        blocks = _blocks(residuals, unknowns, origins, unknown_names)
        direct = _direct_solutions(eqs, blocks, unknowns, unknown_names, c.symbols)
        # Block equations keep the unknowns of earlier blocks as symbols (known, in BLT
        # order); one ordered pass resolves the definitions afterwards.
        for k, (eq_idx, var_idx) in enumerate(blocks):
            block = [eqs[i][0] for i in eq_idx]
            if k in direct:
                known[unknown_names[var_idx[0]]] = direct[k]
                continue
            if len(block) == 1:
                v = c.symbols[unknown_names[var_idx[0]]]
                if (sol := _linear_solution(block[0], v, cs.SX(0, 1))) is not None:
                    known[v.name()] = sol
                    continue
            block_vars = [c.symbols[unknown_names[j]] for j in var_idx]
            block, block_vars = _tear(block, block_vars, known)
            if not _structurally_regular(block, block_vars):
                raise ModelError(
                    "singular system: after elimination, the equations from "
                    f"{sorted({origins[i] for i in eq_idx})} do not determine "
                    f"{[v.name() for v in block_vars]} (a free body or an unconstrained port?)"
                )
            kept_eqs.extend(block)
            kept_vars.extend(v.name() for v in block_vars)
    solved = _resolve(known, c.symbols)
    ders = c.ders
    if c.time_derivatives:
        solved = _resolve_time_derivatives(c, solved, solved.substitute(ders))
    # Equations kept for the algebraic part may use unknowns solved later in BLT order.
    parts = (ders, c.outputs, c.energies, c.dissipations, dict(enumerate(kept_eqs)))
    joint = {(i, k): e for i, part in enumerate(parts) for k, e in part.items()}
    joint = solved.substitute(joint)  # one pass for all of them
    ders, outputs, energies, dissip, kept = (
        {k: joint[i, k] for k in part} for i, part in enumerate(parts)
    )
    kept_eqs = list(kept.values())
    model = Model(
        name=name,
        variables=variables,
        symbols=c.symbols,
        ders=ders,
        alg=kept_eqs,
        alg_vars=kept_vars,
        solved=solved.as_dict(),
        outputs=outputs,
        energies=energies,
        dissipations=dissip,
    )
    _check_numerically_regular(model)
    return model


def _check_numerically_regular(model: Model) -> None:
    """Refuse an algebraic part whose Jacobian is exactly singular at the start values
    (a residual that cancels symbolically, e.g. a spring with both ends free)."""
    if not model.nz:
        return
    J = model.function("dae_jac")(x=model.x0(), z=model.z0(), u=model.u0(), p=model.parameters())[
        "alg_z"
    ]
    sv = np.linalg.svd(np.array(J), compute_uv=False)
    if sv[-1] <= 1e-14 * max(sv[0], 1e-300):
        raise ModelError(
            f"singular system '{model.name}': the algebraic equations do not determine "
            f"{model.alg_names} (their Jacobian is singular: a free body or an "
            "unconstrained port?)"
        )
