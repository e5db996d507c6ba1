"""Model Exchange FMUs as CasADi Functions, and their composition with a flattened Model.

:func:`import_me` opens an FMU through :func:`~sarcomere.fmu.archive.open_fmu` (the safety
checks, Model Exchange interface) and builds ``ode(x, u) -> (ode, y)`` with CasADi's
``DaeBuilder``. Its derivatives use the FMU's directional derivatives when the FMU provides
them (``providesDirectionalDerivative="true"``). When it does not, CasADi differentiates the
FMU by finite differences instead, silently: on the muscle's FMU that gave Jacobian entries
wrong by more than 100 % (badly scaled states), so check such an FMU's linearisation before
using it (docs/cosim.md). CasADi's option ``uses_directional_derivatives=False`` does not
reach the Jacobian here (casadi 3.8.2: still exact), so it is not offered. Parameters are
set on the DaeBuilder, never passed as inputs (with FMI 3.0 that gave wrong Jacobians).
An FMI 3.0 FMU must state the ``dependencies`` of its ``InitialUnknown`` elements (the
DaeBuilder does not implement their default); one that does not is refused.

:func:`compose` couples imported FMUs to a flattened
:class:`~sarcomere.dynamics.modeling.model.Model` by connections by name and returns plain
CasADi Functions of the joint state: simulate them with ``cs.integrator``; linearise with
:meth:`Composed.linearization` (by parts: CasADi's Jacobian of two chained FMU Functions
was wrong).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree

import casadi as cs
import numpy as np
import scipy.linalg

from sarcomere.dynamics.errors import ModelError, ParameterError
from sarcomere.dynamics.modeling.model import Model

from .archive import open_fmu


@dataclass(frozen=True)
class ImportedFMU:
    """A Model Exchange FMU as a CasADi Function.

    Attributes
    ----------
    name : str
        The FMU's model name.
    ode : casadi.Function
        ``(x, u) -> (ode, y)``: the state derivatives and outputs, in the orders below.
    state_names, input_names, output_names : list of str
        The FMU's variable names.
    x0 : numpy.ndarray
        The states' start values from the model description.
    """

    name: str
    ode: cs.Function
    state_names: list[str]
    input_names: list[str]
    output_names: list[str]
    x0: np.ndarray


def import_me(path, params: Mapping[str, float] | None = None) -> ImportedFMU:
    """Import the Model Exchange interface of the FMU at ``path`` as a CasADi Function.

    ``params``: parameter values by name, set on the DaeBuilder.

    Raises
    ------
    FmuArchiveError
        The archive fails a safety check or has no Model Exchange interface.
    ModelError
        An FMI 3.0 FMU with an ``InitialUnknown`` without ``dependencies``, or another
        description or binary CasADi's DaeBuilder cannot load (its cause named).
    ParameterError
        A name in ``params`` is not a parameter of the FMU.

    Examples
    --------
    >>> fmu = import_me("hanging.fmu", {"load.m": 0.06})  # doctest: +SKIP
    >>> xdot, y = fmu.ode(fmu.x0, 0.3e6)  # doctest: +SKIP
    """
    with open_fmu(path, interface="modelExchange") as opened:
        if opened.fmi_version == 3:
            _check_initial_unknowns(opened.folder / "modelDescription.xml", path)
        try:
            dae = cs.DaeBuilder(opened.description.modelName, str(opened.folder))
        except RuntimeError as err:
            raise ModelError(
                f"FMU '{path}': CasADi's DaeBuilder could not load it: {_last_line(err)}"
            ) from None
        for name, value in (params or {}).items():
            if name not in dae.p():
                raise ParameterError("params", name, f"a parameter of FMU '{path}'")
            dae.set(name, float(value))
        # one name per FMU: CasADi caches derivative Functions by name, so two FMUs whose
        # Functions shared a name had their Jacobians mixed up in one expression
        ode = dae.create(f"ode_{_identifier(dae.name())}", ["x", "u"], ["ode", "y"])
        x0 = np.array(dae.start(dae.x()), dtype=float)
        return ImportedFMU(dae.name(), ode, dae.x(), dae.u(), dae.y(), x0)


def _identifier(name: str) -> str:
    """``name`` with every character that is not a letter, digit or ``_`` replaced."""
    return re.sub(r"\W", "_", name)


def _last_line(err: Exception) -> str:
    """The cause of a CasADi error (its last line; the ones above are source locations)."""
    return str(err).strip().splitlines()[-1]


def _check_initial_unknowns(description: Path, path) -> None:
    """Refuse an FMI 3.0 FMU with an ``InitialUnknown`` that omits ``dependencies``.

    The attribute is optional in FMI 3.0 (absent: depends on every input and
    parameter), but CasADi's DaeBuilder (3.8.2) does not implement that default
    ("Default 'dependencies' not implemented") and fails on such an FMU; with the
    attribute written out it imports FMI 3.0 Model Exchange FMUs exactly.
    """
    structure = ElementTree.parse(description).getroot().find("ModelStructure")
    missing = [
        e.get("valueReference")
        for e in (structure if structure is not None else [])
        if e.tag == "InitialUnknown" and e.get("dependencies") is None
    ]
    if missing:
        raise ModelError(
            f"FMU '{path}': FMI 3.0 Model Exchange import needs the dependencies of every "
            f"InitialUnknown (CasADi's DaeBuilder does not implement their default); "
            f"{len(missing)} have none (valueReference {', '.join(missing[:5])})"
        )


@dataclass(frozen=True)
class Composed:
    """A Model and imported FMUs joined at the Function level.

    Attributes
    ----------
    rhs : casadi.Function
        ``(x, u) -> xdot`` of the joint state ``x = [model states, each FMU's states]`` and
        the inputs left unconnected ``u`` (the model's, then each FMU's).
    outputs : casadi.Function
        ``(x, u) -> (signals, y)``: the model's signals and the FMUs' outputs (in order).
    state_names, input_names, output_names : list of str
        The joint states, free inputs and FMU outputs; FMU names prefixed with
        ``"<fmu name>."``.
    signal_names : list of str
        The model's signals (``outputs``' first result), then ``output_names``.
    """

    rhs: cs.Function
    outputs: cs.Function
    state_names: list[str]
    input_names: list[str]
    output_names: list[str]
    signal_names: list[str]

    parts: tuple = field(repr=False)
    """Per part (the model, then each FMU): ``(jacobians, states slice)``, ``jacobians`` a
    Function ``(x_part, u_part) -> (A, B, C, D)`` of that part alone."""
    part_inputs: cs.Function = field(repr=False)
    """``(x, u) -> (u_model, u_fmu_1, ...)``: every part's full input vector."""
    wiring: tuple = field(repr=False)
    """``(S, R)``: the stacked inputs are ``S @ outputs + R @ u`` (0/1 matrices)."""

    def linearization(self, outputs: list[str]):
        """``(x, u) -> (A, B, C, D)`` (numpy): the exact linearisation of ``rhs`` and of the
        signals ``outputs`` (names of :attr:`signal_names`), as :meth:`Model.linearization`.

        Each part is differentiated alone (the model's Jacobians, each FMU's directional
        derivatives) and the parts are joined by the connections, ``w = S y + R u``:
        ``w = (I - S D)^-1 (S C x + R u)``. CasADi's own Jacobian of an expression holding
        two FMU Functions, one feeding the other, came out wrong (casadi 3.8.2: entries of
        one FMU's derivatives added in another's column, in forward mode), while each FMU
        alone is exact; the block form needs only the latter.

        Raises
        ------
        ParameterError
            For a name that is not a signal of the composition.
        """
        rows = []
        for n in outputs:
            if n not in self.signal_names:
                raise ParameterError("outputs", n, "a signal of the composition")
            rows.append(self.signal_names.index(n))
        S, R = self.wiring

        def evaluate(x, u):
            x = np.asarray(x, dtype=float).ravel()
            ws = [np.array(w, dtype=float).ravel() for w in self.part_inputs(x, u)]
            blocks = [
                [np.array(m, dtype=float) for m in jac(x[sl], w)]
                for (jac, sl), w in zip(self.parts, ws, strict=True)
            ]
            A, B, C, D = (scipy.linalg.block_diag(*[b[k] for b in blocks]) for k in range(4))
            M = np.linalg.inv(np.eye(S.shape[0]) - S @ D)  # no algebraic loop: invertible
            Aw, Bw = M @ S @ C, M @ R  # the stacked inputs against x and u
            Cy, Dy = C + D @ Aw, D @ Bw
            return A + B @ Aw, B @ Bw, Cy[rows], Dy[rows]

        return evaluate


def _resolve(name: str, model_names: list[str], fmus, fmu_names) -> tuple[int, str]:
    """Who owns ``name``: ``(-1, name)`` for the model, ``(i, var)`` for FMU ``i``; an FMU
    variable is ``"<fmu name>.<var>"`` or, if no other owner has it, ``"<var>"``."""
    owners = [(-1, name)] if name in model_names else []
    for i, fmu in enumerate(fmus):
        prefix = f"{fmu.name}."
        if name.startswith(prefix) and name[len(prefix) :] in fmu_names(fmu):
            return i, name[len(prefix) :]
        if name in fmu_names(fmu):
            owners.append((i, name))
    if len(owners) > 1:
        raise ModelError(f"'{name}' is ambiguous: prefix it with its FMU's name")
    return owners[0] if owners else (None, name)


def compose(
    model: Model,
    fmus: ImportedFMU | Sequence[ImportedFMU],
    connections: Mapping[str, str],
    params: Mapping[str, object] | None = None,
) -> Composed:
    """Couple ``model`` (``nz = 0``) and one or several ``fmus`` by name: ``connections``
    maps each input that is driven (of the model or an FMU) to the output that drives it
    (a signal of the model, see ``model.signal_names``, or an output of an FMU). An FMU's
    variable is named ``"<fmu name>.<var>"``, or ``"<var>"`` where that is unambiguous.

    Outputs may feed through from inputs (the model's signals from its inputs, an FMU's
    outputs from its inputs), as long as the connections form no cycle through them (an
    algebraic loop, refused).

    Raises
    ------
    ModelError
        A connection names an unknown or ambiguous variable, joins two variables of one
        side, or the coupling has an algebraic loop; FMU names are not unique.
    """
    if model.nz:
        raise ModelError(f"model '{model.name}' has {model.nz} algebraic unknowns; need 0")
    fmus = [fmus] if isinstance(fmus, ImportedFMU) else list(fmus)
    if len({f.name for f in fmus}) != len(fmus):
        raise ModelError(f"FMU names must be unique: {[f.name for f in fmus]}")
    signals = model.signal_names
    driven: dict[tuple[int, str], tuple[int, str]] = {}  # (owner, input) -> (owner, output)
    for target, source in connections.items():
        dst = _resolve(target, model.input_names, fmus, lambda f: f.input_names)
        src = _resolve(source, signals, fmus, lambda f: f.output_names)
        if dst[0] is None or src[0] is None or dst[0] == src[0]:
            raise ModelError(
                f"connection {source} -> {target} joins no model signal to an FMU input "
                f"and no FMU output to a model input or another FMU's input"
            )
        driven[dst] = src
    p = model.parameters(params)
    free_m = [n for n in model.input_names if (-1, n) not in driven]
    free_f = [[n for n in f.input_names if (i, n) not in driven] for i, f in enumerate(fmus)]
    xm = cs.MX.sym("x_model", model.nx)
    xf = [cs.MX.sym(f"x_{i}", len(f.state_names)) for i, f in enumerate(fmus)]
    um = cs.MX.sym("u_model", len(free_m))
    uf = [cs.MX.sym(f"u_{i}", len(n)) for i, n in enumerate(free_f)]
    targets = list(driven)  # the driven inputs stand in as placeholders, then are solved
    placeholder = cs.MX.sym("driven", len(targets))
    value = {t: placeholder[k] for k, t in enumerate(targets)}

    def label(key: tuple[int, str]) -> str:
        return key[1] if key[0] == -1 else f"{fmus[key[0]].name}.{key[1]}"

    def inputs_of(owner: int, names: list[str], free: list[str], u) -> cs.MX:
        parts = {n: u[free.index(n)] for n in free}
        parts.update({n: value[(owner, n)] for n in names if (owner, n) in value})
        return cs.vertcat(*[parts[n] for n in names])

    z = cs.MX(0, 1)
    sig = model.function("signals")(xm, z, inputs_of(-1, model.input_names, free_m, um), p)
    ys = [
        f.ode(xf[i], inputs_of(i, f.input_names, free_f[i], uf[i]))[1] for i, f in enumerate(fmus)
    ]

    def source_value(owner: int, var: str) -> cs.MX:
        if owner == -1:
            return sig[signals.index(var)]
        return ys[owner][fmus[owner].output_names.index(var)]

    definition = cs.vertcat(*[source_value(*driven[t]) for t in targets])
    solved = definition
    for _ in range(len(targets) + 1):  # an acyclic chain resolves in at most len(targets)
        if not cs.depends_on(solved, placeholder):
            break
        solved = cs.substitute(definition, placeholder, solved)
    else:
        loop = [
            f"{label(driven[t])} -> {label(t)}"
            for k, t in enumerate(targets)
            if cs.depends_on(solved[k], placeholder)
        ]
        raise ModelError(f"algebraic loop through the connections {loop}")
    # the placeholders still appear as arguments that nothing depends on: drop them
    solved = cs.substitute(solved, placeholder, cs.DM.zeros(placeholder.shape))
    value = {t: solved[k] for k, t in enumerate(targets)}  # inputs_of now uses these

    u_model = inputs_of(-1, model.input_names, free_m, um)
    xm_dot = model.function("ode")(xm, z, u_model, p)
    signals_out = model.function("signals")(xm, z, u_model, p)
    xf_dot, y_out = [], []
    for i, f in enumerate(fmus):
        d, y = f.ode(xf[i], inputs_of(i, f.input_names, free_f[i], uf[i]))
        xf_dot.append(d)
        y_out.append(y)
    x, u = cs.vertcat(xm, *xf), cs.vertcat(um, *uf)
    y_all = cs.vertcat(*y_out)
    out_names = [f"{f.name}.{n}" for f in fmus for n in f.output_names]
    # the block linearisation: each part alone, and the wiring between stacked outputs
    # (model signals, then each FMU's outputs) and stacked inputs (each part's full vector)
    xs, us = cs.SX.sym("x", model.nx), cs.SX.sym("u", len(model.input_names))
    zs = cs.SX(0, 1)
    ode_s = model.function("ode")(xs, zs, us, p)
    sig_s = model.function("signals")(xs, zs, us, p)
    jacs = [_jacobians(xs, us, ode_s, sig_s)]
    for f in fmus:
        xi, ui = cs.MX.sym("x", len(f.state_names)), cs.MX.sym("u", len(f.input_names))
        jacs.append(_jacobians(xi, ui, *f.ode(xi, ui)))
    owners = [(-1, model.input_names, signals)] + [
        (i, f.input_names, f.output_names) for i, f in enumerate(fmus)
    ]
    y_keys = [(owner, n) for owner, _, outs in owners for n in outs]
    y_at = {key: k for k, key in enumerate(y_keys)}  # row of the stacked outputs
    free_keys = [(-1, n) for n in free_m] + [(i, n) for i in range(len(fmus)) for n in free_f[i]]
    free_at = {key: k for k, key in enumerate(free_keys)}  # the order of u
    w_keys = [(owner, n) for owner, ins, _ in owners for n in ins]
    S, R = np.zeros((len(w_keys), len(y_at))), np.zeros((len(w_keys), len(free_at)))
    for k, key in enumerate(w_keys):
        if key in driven:
            S[k, y_at[driven[key]]] = 1.0
        else:
            R[k, free_at[key]] = 1.0
    sizes = np.cumsum([0, model.nx, *[len(f.state_names) for f in fmus]])
    part_inputs = [u_model] + [
        inputs_of(i, f.input_names, free_f[i], uf[i]) for i, f in enumerate(fmus)
    ]
    return Composed(
        rhs=cs.Function("rhs", [x, u], [cs.vertcat(xm_dot, *xf_dot)], ["x", "u"], ["xdot"]),
        outputs=cs.Function("outputs", [x, u], [signals_out, y_all], ["x", "u"], ["signals", "y"]),
        state_names=model.state_names + [f"{f.name}.{n}" for f in fmus for n in f.state_names],
        input_names=free_m + [f"{f.name}.{n}" for i, f in enumerate(fmus) for n in free_f[i]],
        output_names=out_names,
        signal_names=list(signals) + out_names,
        parts=tuple(
            (jac, slice(int(lo), int(hi)))
            for jac, lo, hi in zip(jacs, sizes[:-1], sizes[1:], strict=True)
        ),
        part_inputs=cs.Function("part_inputs", [x, u], part_inputs),
        wiring=(S, R),
    )


def _jacobians(x, u, xdot, y) -> cs.Function:
    """``(x, u) -> (A, B, C, D)`` of one part's ``xdot`` and outputs ``y``."""
    jac = [cs.jacobian(xdot, x), cs.jacobian(xdot, u), cs.jacobian(y, x), cs.jacobian(y, u)]
    return cs.Function("jacobians", [x, u], jac, ["x", "u"], ["A", "B", "C", "D"])
