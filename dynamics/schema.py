"""What a scene file is checked against when it is parsed, without the model code (no
CasADi is loaded to read a scene): the level names and the default output size."""

FIDELITIES = (
    "full",
    "quasi_static",
    "static_chain",
    "grouped",
    "symmetric",
    "instant_pneumatics",
    "instant_quasi_static",
)
"""Dynamic fidelity levels, each a flattened model (the chain levels of
:data:`~.components.chains.CHAIN_LEVELS`, then the reduced chains, then
:data:`~.components.chains.INSTANT_LEVELS`; docs/model.md); "grouped" is
:data:`~.assemblies.GROUPS` groups of units in series, two representative half-groups
each, with the bodies' inertia and the weight gradient
(:class:`~.components.chains.GroupedMyofibril`, all n units when n <= GROUPS), "symmetric"
one representative unit for n identical units; "instant_pneumatics" and
"instant_quasi_static" the mechanics of "full" and "quasi_static" with every chamber at
the regulator's outlet pressure (no air masses, no tubes)."""

WITHOUT_MODEL = ("linear", "equilibrium_path")
"""The levels without a flattened model of their own (:mod:`.fidelity.levels`): the full
model linearised at the middle of the input's range, and its equilibrium path with the
linearised deviation from it; transients only, one input."""

MAX_VALUES = 2e7
"""Default limit on output points x signals of one simulation (160 MB of float64);
``simulate(..., max_values=...)`` and ``[outputs] max_values`` raise it."""
