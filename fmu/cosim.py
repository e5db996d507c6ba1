"""A co-simulation master: participants (FMUs or native models, see :mod:`.participants`)
stepped at a fixed communication step, their inputs fed by connections and sources.

At the start, the participants are initialised in their listed order, each with its
sources' values and the outputs of the participants started before it (an input driven
by a later participant keeps its start value, or the value given in ``start_inputs``,
until the first step).

Each communication step ``[t_k, t_k + h]``:

1. every source (a function of time) sets its input to its value at ``t_k``;
2. the participants are stepped in their listed order. Each connected input is set just
   before its participant steps, to a value held over the step (FMI Co-Simulation holds
   inputs; no input derivatives are used):

   * **jacobi**: every participant sees the outputs of ``t_k``;
   * **gauss-seidel**: a participant sees the outputs of ``t_k + h`` of those stepped
     before it in this step, and of ``t_k`` of the others;

   ``hold`` (zero-order hold) sets that freshest value itself; ``extrapolate`` sets the
   linear estimate of the source at the step's midpoint ``t_k + h/2``: from ``y(t_k)``
   and ``y(t_k - h)`` (extrapolated; plain hold at the first step), or halfway between
   ``y(t_k)`` and ``y(t_k + h)`` when the source was already stepped (Gauss-Seidel);
3. the recorded signals are read at ``t_k + h``.

A failed participant stops the run with a :class:`CosimError` naming it, the time and
the FMI status; the error keeps the results up to the last completed step.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from sarcomere.dynamics.errors import ParameterError, SarcomereError
from sarcomere.dynamics.results import Result

from .participants import ParticipantError

ORDERINGS = ("jacobi", "gauss-seidel")
INPUT_LAWS = ("hold", "extrapolate")


class CosimError(SarcomereError):
    """A participant failed mid-run.

    Attributes
    ----------
    participant, status : str
        Who failed and the FMI status label.
    time : float
        Start of the communication step that failed [s].
    result : Result
        The recorded signals up to the last completed communication point (no rows when
        a participant failed to start).
    """

    def __init__(self, err: ParticipantError, time: float, result: Result) -> None:
        kept = f"up to t = {result.index[-1]:.6g} s" if len(result.index) else "none"
        super().__init__(f"co-simulation stopped at t = {time:.6g} s: {err} (results kept: {kept})")
        self.participant = err.participant
        self.status = err.status
        self.time = time
        self.result = result


@dataclass(frozen=True)
class Connection:
    """``source`` output feeds ``target`` input, each ``"participant.variable"``."""

    source: str
    target: str


def _split(name: str, parts: Mapping, what: str) -> tuple[str, str]:
    owner, _, var = name.partition(".")
    if owner not in parts or not var:
        raise ParameterError(what, name, f"'participant.variable' with one of {list(parts)}")
    return owner, var


def cosimulate(
    participants: Sequence,
    connections: Sequence[Connection] = (),
    *,
    stop_time: float,
    step: float,
    start_time: float = 0.0,
    ordering: str = "jacobi",
    inputs: str = "hold",
    sources: Mapping[str, Callable[[float], float]] | None = None,
    start_inputs: Mapping[str, float] | None = None,
    record: Sequence[str] | None = None,
    on_step: Callable[[float], None] | None = None,
) -> Result:
    """Co-simulate ``participants`` from ``start_time`` to ``stop_time`` [s].

    Parameters
    ----------
    participants : sequence of participants
        Stepped in this order (it matters for Gauss-Seidel); names must be unique.
    connections : sequence of Connection
        Output -> input, by ``"participant.variable"``; an input has at most one driver.
    stop_time, step, start_time : float
        Times [s]; ``stop_time - start_time`` must be a whole number of steps.
    ordering : {"jacobi", "gauss-seidel"}
    inputs : {"hold", "extrapolate"}
        How a connected input is held over a step (see the module docstring).
    sources : mapping of str to callable, optional
        ``"participant.input"`` -> function of time [SI]; evaluated at each step's start.
    start_inputs : mapping of str to float, optional
        ``"participant.input"`` -> value [SI] at the start, for a connected input whose
        driver starts after its participant (a loop: the value that closes it, e.g. the
        coupling force of the joint equilibrium); default the input's start value.
    record : sequence of str, optional
        ``"participant.variable"`` to record (default every participant's outputs).
    on_step : callable, optional
        Called with the time after each communication step (progress reports).

    Returns
    -------
    Result
        The recorded signals at ``start_time, start_time + step, ..., stop_time``.

    Raises
    ------
    ParameterError
        Bad names, times, ordering or input law.
    CosimError
        A participant failed; ``err.result`` holds the results so far.
    """
    parts = {p.name: p for p in participants}
    if len(parts) != len(participants):
        raise ParameterError("participants", [p.name for p in participants], "unique names")
    if ordering not in ORDERINGS:
        raise ParameterError("ordering", ordering, " or ".join(ORDERINGS))
    if inputs not in INPUT_LAWS:
        raise ParameterError("inputs", inputs, " or ".join(INPUT_LAWS))
    if not (np.isfinite(step) and step > 0):
        raise ParameterError("step", step, "a finite step > 0 s")
    n_float = (stop_time - start_time) / step
    n = int(round(n_float))
    if n < 1 or abs(n - n_float) > 1e-9 * max(1.0, n_float):
        raise ParameterError(
            "stop_time", stop_time, f"start_time + a whole number (>= 1) of steps of {step:g} s"
        )
    sources = dict(sources or {})
    drivers: dict[str, dict[str, tuple[str, str]]] = {p: {} for p in parts}  # target -> source
    for c in connections:
        src, out = _split(c.source, parts, "connection source")
        dst, inp = _split(c.target, parts, "connection target")
        if out not in parts[src].outputs:
            raise ParameterError("connection source", c.source, f"an output of '{src}'")
        if inp not in parts[dst].inputs:
            raise ParameterError("connection target", c.target, f"an input of '{dst}'")
        if inp in drivers[dst] or c.target in sources:
            raise ParameterError("connection target", c.target, "an input with one driver")
        drivers[dst][inp] = (src, out)
    external: dict[str, dict[str, Callable]] = {p: {} for p in parts}
    for target, fn in sources.items():
        dst, inp = _split(target, parts, "source")
        if inp not in parts[dst].inputs:
            raise ParameterError("source", target, f"an input of '{dst}'")
        external[dst][inp] = fn
    given = {}
    order = {name: i for i, name in enumerate(parts)}
    for target, value in (start_inputs or {}).items():
        dst, inp = _split(target, parts, "start_inputs")
        if inp not in drivers[dst] or order[drivers[dst][inp][0]] < order[dst]:
            raise ParameterError(
                "start_inputs", target, "a connected input whose driver starts after it"
            )
        given[target] = float(value)
    if record is None:
        record = [f"{p.name}.{o}" for p in participants for o in p.outputs]
    wanted: dict[str, list[str]] = {p: [] for p in parts}
    for name in record:
        owner, var = _split(name, parts, "record")
        if var not in parts[owner].units:
            raise ParameterError("record", name, f"a variable of '{owner}'")
        wanted[owner].append(var)
    for dst in drivers.values():
        for src, out in dst.values():
            if out not in wanted[src]:
                wanted[src].append(out)

    times = [start_time]
    rows: list[dict[str, dict[str, float]]] = []

    def partial() -> Result:
        signals = {
            name: np.array([row[name.partition(".")[0]][name.partition(".")[2]] for row in rows])
            for name in record
        }
        units = {
            name: parts[_split(name, parts, "record")[0]].units[name.partition(".")[2]]
            for name in record
        }
        return Result(
            "time",
            "s",
            np.array(times[: len(rows)]),
            signals,
            units,
            {"ordering": ordering, "inputs": inputs, "step": step},
        )

    t = start_time
    try:
        current: dict[str, dict[str, float]] = {}
        for p in participants:
            start = {k: float(fn(t)) for k, fn in external[p.name].items()}
            for inp, (src, out) in drivers[p.name].items():
                if src in current:  # started before p: its output at the start time
                    start[inp] = current[src][out]
                elif f"{p.name}.{inp}" in given:
                    start[inp] = given[f"{p.name}.{inp}"]
            p.start(t, start)
            current[p.name] = p.get(wanted[p.name])
        rows.append(current)
        previous: dict[str, dict[str, float]] | None = None
        for k in range(n):
            t = start_time + k * step
            t_next = start_time + (k + 1) * step
            fresh: dict[str, dict[str, float]] = {}
            for p in participants:
                values = {inp: float(fn(t)) for inp, fn in external[p.name].items()}
                for inp, (src, out) in drivers[p.name].items():
                    now = current[src][out]
                    if ordering == "gauss-seidel" and src in fresh:
                        new = fresh[src][out]
                        values[inp] = new if inputs == "hold" else 0.5 * (now + new)
                    elif inputs == "extrapolate" and previous is not None:
                        values[inp] = now + 0.5 * (now - previous[src][out])
                    else:
                        values[inp] = now
                p.set(values)
                p.do_step(t, step)
                if ordering == "gauss-seidel":
                    fresh[p.name] = p.get(wanted[p.name])
            previous = current
            current = fresh or {p: parts[p].get(wanted[p]) for p in parts}
            rows.append(current)
            times.append(t_next)
            if on_step is not None:
                on_step(t_next)
    except ParticipantError as err:
        raise CosimError(err, t, partial()) from None
    finally:
        for p in participants:
            p.close()
    return partial()
