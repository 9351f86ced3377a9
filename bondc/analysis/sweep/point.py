"""One point of a sweep: a vector of parameter values -> :class:`~bondc.analysis.sweep.table.SweepPoint`.

The base model is checked, derived and compiled once per process (:func:`_base`, through
:mod:`bondc.pipeline`); a point binds its values to it (late binding), or loads the file again
with them as ``--set`` values when they change what the check fixes (see the package's docstring)."""

from __future__ import annotations

import itertools
import math
import traceback
from dataclasses import dataclass
from typing import TYPE_CHECKING

from bondc.analysis.sweep.metrics import _measure, _qualifying_motors
from bondc.analysis.sweep.table import SweepPoint
from bondc.errors import BondcError, Diagnostic
from bondc.pipeline import Checked, Derived, check_file, derive, file_texts, structure
from bondc import codes

if TYPE_CHECKING:
    from bondc.ast import SetValue
    from bondc.units import SIUnit


@dataclass(frozen=True)
class _Setup:
    """What every point needs, picklable for worker processes. ``key`` finds the compiled base model."""

    key: tuple[int, int]                     # (process id, sweep number)
    path: str
    model: str | None
    experiment: str | None
    sets: tuple[SetValue, ...]               # the base --set values, parsed
    names: tuple[str, ...]                   # the varied parameters, per axis
    units: tuple[str | None, ...]            # as given (None: the declared unit)
    converters: tuple[SIUnit, ...]           # per axis, the SIUnit its values are in (for a point not loaded)
    metrics: tuple[str, ...]
    t_end: float | None
    dt: float | None
    rederive: bool
    motors: str | None = None                # a motor catalogue (csv): which motors qualify per point
    inertia_ratio: float | None = None       # --inertia-ratio: every motor's load/rotor inertia limit
    bound: bool = False                      # late binding: points are vectors of values (see _measure_point)


#: The base model of each sweep in this process, derived and compiled (by ``_Setup.key``).
_BASES: dict[tuple[int, int], Derived] = {}
_COUNTER = itertools.count()


def _base(setup: _Setup, checked: Checked | None = None) -> Derived:
    """The base model of ``setup``, derived and compiled once per process; ``checked`` is the
    caller's check of it, when it has one."""
    base = _BASES.get(setup.key)
    if base is not None:
        return base
    from bondc.simulate import compile_model

    base = derive(checked or check_file(setup.path, model=setup.model, experiment=setup.experiment,
                                        sets=setup.sets))
    namespace = compile_model(base.state_space)
    if namespace.get("NATIVE_SOURCE"):
        from bondc.runtime import load_native

        load_native(namespace["NATIVE_SOURCE"])     # built once here, before workers fork: they load it
    _BASES[setup.key] = base
    return base


def _set_text(name: str, value: float, unit: str | None) -> str:
    return f"{name}={value!r}" + (f" [{unit}]" if unit else "")


def _point_check(setup: _Setup, values: tuple[float, ...]) -> Checked:
    """The model checked again with the point's values as ``--set`` values (after the base's)."""
    from bondc.parse import parse_set_value

    sets = list(setup.sets) + [parse_set_value(_set_text(name, value, unit), f"--vary {name}")
                               for name, unit, value in zip(setup.names, setup.units, values)]
    return check_file(setup.path, model=setup.model, experiment=setup.experiment, sets=sets)


def _run_point(setup: _Setup, index: int, values: tuple[float, ...]) -> SweepPoint:
    """One grid point. Any error becomes a failed point, so that one point cannot stop the others and
    the result is the same with or without worker processes; an internal error (a bug in bondc) keeps
    its traceback in the point's ``traceback``."""
    try:
        return _measure_point(setup, index, values)
    except Exception as error:
        return SweepPoint(index, values, "failed", f"E968: internal error: {type(error).__name__}: {error} "
                                                   "(a bug in bondc; please report it with the model file)",
                          traceback=traceback.format_exc())


def _measure_point(setup: _Setup, index: int, values: tuple[float, ...]) -> SweepPoint:
    """Simulate and measure one grid point; every bondc error becomes a failed point.

    Late binding (``setup.bound``): the model checked and compiled once, the point only its vector
    of values; the compiled module recomputes every parameter defined by others (the flagship's
    ``F_n0 = M*g - ...``). Otherwise (a varied parameter sets an experiment setting, or
    ``rederive``) the file is loaded again with the point's values as ``--set`` overrides."""
    from bondc.simulate import simulate

    base = _base(setup)
    parameters = {name: unit.to_si(value) for name, unit, value in zip(setup.names, setup.converters, values)}
    try:
        if setup.bound:
            graph, experiment = base.graph, base.experiment
            state_space, path = base.state_space, "bound"
            result = simulate(state_space, experiment, t_end=setup.t_end, dt=setup.dt, overrides=dict(parameters))
            return _finish_point(setup, index, values, path, parameters, state_space, graph, experiment, result)
        checked = _point_check(setup, values)
        graph = checked.graph
        parameters = {name: graph.parameters[name].value for name in setup.names}
        if file_texts(graph) != file_texts(base.graph):
            return SweepPoint(index, values, "failed", "E968: the model file changed during the sweep",
                              None, parameters, diagnostics=(Diagnostic(
                                  "error", codes.E968, "the model file changed during the sweep",
                                  hint="run the sweep again"),))
        experiment = checked.experiment
        if not setup.rederive and structure(graph) == structure(base.graph):
            state_space, path = base.state_space, "fast"
            # every parameter given: the compiled module recomputes none of them
            overrides = {name: graph.parameters[name].value for name in state_space.parameters}
        else:
            state_space, path, overrides = derive(checked).state_space, "rederived", None
        result = simulate(state_space, experiment, t_end=setup.t_end, dt=setup.dt, overrides=overrides)
    except BondcError as error:
        message = "; ".join(f"{d.code}: {d.message}" for d in error.diagnostics) or str(error)
        return SweepPoint(index, values, "failed", message, None, parameters, diagnostics=tuple(error.diagnostics))
    return _finish_point(setup, index, values, path, parameters, state_space, graph, experiment, result)


def _can_bind(setup: _Setup, base: Derived, grid: list[tuple[float, ...]]) -> bool:
    """Whether the points can be bound late: the varied parameters change nothing the check fixes
    outside the compiled module (the experiment's settings: t_end, max_step, cycle, ...). Loaded at
    the first and the last point and compared with the base model."""
    if setup.rederive:
        return False
    for values in (grid[0], grid[-1]):
        try:
            checked = _point_check(setup, values)
        except BondcError:
            return False            # the points say why, one by one
        if structure(checked.graph) != structure(base.graph) or \
                _settings(checked.experiment) != _settings(base.experiment):
            return False
    return True


def _settings(experiment) -> tuple:
    if experiment is None:
        return ()
    return (experiment.t_end, experiment.solver, experiment.rtol, experiment.atol, experiment.max_step,
            experiment.cycle, tuple(sorted(experiment.settings.items())))


def _finish_point(setup: _Setup, index: int, values, path, parameters, state_space, graph, experiment,
                  result) -> SweepPoint:
    """A point that ran (or stopped early): its status, metrics and motors."""
    warnings = list(result.warnings)
    if not result.complete:
        diagnostics = tuple(result.diagnostics) or (Diagnostic("error", codes.E968, result.message),)
        message = "; ".join(f"{d.code}: {d.message}" for d in diagnostics)
        return SweepPoint(index, values, "failed", message, path, parameters, {}, result.t_reached,
                          diagnostics, tuple(warnings))
    from bondc.analysis.energy import dense_steps

    steps = dense_steps(state_space, result)   # the metrics from the solver's steps and between them, not a grid's
    metrics = _measure(setup, state_space, graph, experiment, steps, warnings)
    motors = _qualifying_motors(setup, steps, graph, warnings) if setup.motors else None
    missing = [name for name, value in metrics.items() if not math.isfinite(value)]
    if missing or (setup.motors and motors is None):
        why = (f"not computed: {', '.join(missing)}" if missing else "") + \
              ("; " if missing and setup.motors and motors is None else "") + \
              ("no motor selection" if setup.motors and motors is None else "")
        reasons = "; ".join(f"{w.code}: {w.message}" for w in warnings if w.code.startswith(("W9", "E9")))
        return SweepPoint(index, values, "incomplete", why + (f" ({reasons})" if reasons else ""), path,
                          parameters, metrics, result.t_reached, (), tuple(warnings), motors=motors)
    return SweepPoint(index, values, "ok", None, path, parameters, metrics, result.t_reached, (), tuple(warnings),
                      motors=motors)
