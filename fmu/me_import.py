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

:func:`compose` couples an imported FMU to a flattened
:class:`~sarcomere.dynamics.modeling.model.Model` by connections by name and returns plain
CasADi Functions of the joint state: simulate them with ``cs.integrator`` and linearise them
with ``cs.jacobian``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import casadi as cs
import numpy as np

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
    ParameterError
        A name in ``params`` is not a parameter of the FMU.

    Examples
    --------
    >>> fmu = import_me("hanging.fmu", {"load.m": 0.06})  # doctest: +SKIP
    >>> xdot, y = fmu.ode(fmu.x0, 0.3e6)  # doctest: +SKIP
    """
    with open_fmu(path, interface="modelExchange") as opened:
        dae = cs.DaeBuilder(opened.description.modelName, str(opened.folder))
        for name, value in (params or {}).items():
            if name not in dae.p():
                raise ParameterError("params", name, f"a parameter of FMU '{path}'")
            dae.set(name, float(value))
        ode = dae.create("ode", ["x", "u"], ["ode", "y"])
        x0 = np.array(dae.start(dae.x()), dtype=float)
        return ImportedFMU(dae.name(), ode, dae.x(), dae.u(), dae.y(), x0)


@dataclass(frozen=True)
class Composed:
    """A Model and an imported FMU joined at the Function level.

    Attributes
    ----------
    rhs : casadi.Function
        ``(x, u) -> xdot`` of the joint state ``x = [model states, FMU states]`` and the
        inputs left unconnected ``u`` (the model's, then the FMU's).
    outputs : casadi.Function
        ``(x, u) -> (signals, y)``: the model's signals and the FMU's outputs.
    state_names, input_names : list of str
        The joint states and free inputs, FMU names prefixed with ``"<fmu name>."``.
    """

    rhs: cs.Function
    outputs: cs.Function
    state_names: list[str]
    input_names: list[str]


def compose(
    model: Model,
    fmu: ImportedFMU,
    connections: Mapping[str, str],
    params: Mapping[str, object] | None = None,
) -> Composed:
    """Couple ``model`` (``nz = 0``) and ``fmu`` by name: ``connections`` maps each input
    that is driven (of the model or the FMU) to the output that drives it (a signal of the
    model, see ``model.signal_names``, or an output of the FMU).

    The model signals that feed the FMU must not depend on the model inputs the FMU feeds
    (an algebraic loop); FMU outputs may depend on FMU inputs directly.

    Raises
    ------
    ModelError
        A connection names an unknown variable, or the coupling has an algebraic loop.
    """
    if model.nz:
        raise ModelError(f"model '{model.name}' has {model.nz} algebraic unknowns; need 0")
    signals = model.signal_names
    to_fmu, to_model = {}, {}
    for target, source in connections.items():
        if target in fmu.input_names and source in signals:
            to_fmu[target] = signals.index(source)
        elif target in model.input_names and source in fmu.output_names:
            to_model[target] = fmu.output_names.index(source)
        else:
            raise ModelError(
                f"connection {source} -> {target} joins no model signal to an FMU input "
                f"and no FMU output to a model input"
            )
    p = model.parameters(params)
    free_m = [n for n in model.input_names if n not in to_model]
    free_f = [n for n in fmu.input_names if n not in to_fmu]
    xm, xf = cs.MX.sym("x_model", model.nx), cs.MX.sym("x_fmu", len(fmu.state_names))
    um, uf = cs.MX.sym("u_model", len(free_m)), cs.MX.sym("u_fmu", len(free_f))
    fed = cs.MX.sym("fed", len(to_model))  # the model inputs the FMU drives
    z = cs.MX(0, 1)

    def model_inputs(fed_values):
        parts = {n: um[free_m.index(n)] for n in free_m}
        parts.update({n: fed_values[i] for i, n in enumerate(to_model)})
        return cs.vertcat(*[parts[n] for n in model.input_names])

    sig = model.function("signals")(xm, z, model_inputs(fed), p)
    feed = cs.vertcat(*[sig[i] for i in to_fmu.values()])
    if to_model and to_fmu and cs.depends_on(feed, fed):
        raise ModelError(
            f"algebraic loop: the model signals {[connections[t] for t in to_fmu]} feeding FMU "
            f"'{fmu.name}' depend on the model inputs {list(to_model)} it drives"
        )
    sig = cs.substitute(sig, fed, cs.DM.zeros(fed.shape))  # it does not depend on them
    parts = {n: uf[free_f.index(n)] for n in free_f}
    parts.update({n: sig[i] for n, i in to_fmu.items()})
    xf_dot, y = fmu.ode(xf, cs.vertcat(*[parts[n] for n in fmu.input_names]))
    u_full = model_inputs(cs.vertcat(*[y[i] for i in to_model.values()]))
    xm_dot = model.function("ode")(xm, z, u_full, p)
    signals_out = model.function("signals")(xm, z, u_full, p)
    x, u = cs.vertcat(xm, xf), cs.vertcat(um, uf)
    prefix = f"{fmu.name}."
    return Composed(
        rhs=cs.Function("rhs", [x, u], [cs.vertcat(xm_dot, xf_dot)], ["x", "u"], ["xdot"]),
        outputs=cs.Function("outputs", [x, u], [signals_out, y], ["x", "u"], ["signals", "y"]),
        state_names=model.state_names + [prefix + n for n in fmu.state_names],
        input_names=free_m + [prefix + n for n in free_f],
    )
