"""Simulation stage: :class:`~bondc.statespace.StateSpace` (+ experiment) -> :class:`SimResult`.

:func:`simulate` generates the model's module with :func:`bondc.codegen.emit`,
executes it in-process (the very code ``bondc compile`` writes, runtime
included) and runs :func:`bondc.runtime.simulate_model`: the experiment's
solver, by default SUNDIALS CVODE (variable-order BDF with Newton iteration and
the analytic Jacobian, through scikit-sundae), every discontinuity located as
an event or a known time (see :mod:`bondc.runtime`), every state and
derivative checked for nan/inf.

Why CVODE by default: it is the reference implementation of variable-order BDF
(compiled, with CVODE's own step-size and order control and its convergence
tests), it handles stiff and non-stiff models alike, and a non-finite
right-hand side at a trial point is a convergence failure that makes it retry
with a shorter step instead of failing the run. scipy's Python Radau and BDF
test Newton convergence on the ratio of successive corrections, which fails
when a model sits at an equilibrium whose right-hand side is rounding noise (a
car at rest on its springs); they then creep with thousands of Jacobian
updates. The scipy methods (``solver = "LSODA"``, ``"Radau"``, ...) stay
available for comparison; without scikit-sundae the default falls back to
LSODA.

A run that fails (solver failure, a nan or inf, too many events) still
returns what it computed: ``complete`` is False, ``message`` says what
happened and ``diagnostics`` holds a :class:`~bondc.errors.Diagnostic`
pointing, when it can, at the law of the variable that went wrong.
:meth:`SimResult.error` turns that into a :class:`~bondc.errors.SimulationError`.

Files: :func:`write_csv` writes the columns ``t``, every output (SI), every
state by qualified name, then every dependent state (a storage element's in
derivative causality, e.g. ``load.p`` behind a rigid gear, computed from the
independent states) and, with ``all_bonds``, every bond's effort and flow
(``b3.e``, ``b3.f`` or the bond's label); values are the shortest text that
reads back to the same float. An incomplete run's csv is written the same way
(no comment line, so every csv reader reads it); the command line says that it
is incomplete and exits with status 1. :func:`write_npz` writes the same
arrays plus ``complete``, ``message``, events and parameters. Both write a
temporary file in the target's directory and rename it over the target.

The whole ``bondc simulate`` command (load, check, derive, simulate, write) is
:func:`bondc.pipeline.simulate_file`; this module is its simulation stage and its files.
"""

from __future__ import annotations

import difflib
import math
import os
import sys
import time
import weakref
from dataclasses import dataclass, field, fields
from pathlib import Path
from types import CodeType
from typing import TYPE_CHECKING, Any, BinaryIO, Callable, Iterable, Mapping, NoReturn, Sequence, TextIO, TypeVar

import numpy as np

from bondc.errors import DataError, Diagnostic, SimulationError, UsageError
from bondc.io import atomic_write
from bondc.model import ExperimentDef, bond_alias, law_span, readable, readable_names, result_units
from bondc import codes

if TYPE_CHECKING:
    from bondc.source import Span
    from bondc.statespace import StateSpace

_COMPILED: dict[int, tuple[weakref.ref[Any], dict[str, Any]]] = {}


_K = TypeVar("_K")
_V = TypeVar("_V")


class ReadOnlyDict(dict[_K, _V]):
    """A dict that cannot be changed once made: the mappings a frozen :class:`SimResult` holds.

    Every reader takes it for the dict it is (``json``, pandas, ``isinstance(x, dict)``, pickle,
    ``==``); a write (``d[k] = v``, ``del``, ``update``, ``pop``, ...) raises TypeError. A changed
    copy is ``dict(d)`` changed, or ``{**d, k: v}``.
    """

    __slots__ = ()

    def _refuse(self) -> NoReturn:
        raise TypeError(f"{type(self).__name__} cannot be changed: make a changed copy (dict(it), or {{**it, key: value}})")

    def __setitem__(self, *args: Any) -> NoReturn:
        self._refuse()

    def __delitem__(self, *args: Any) -> NoReturn:
        self._refuse()

    # (mypy holds an in-place operator to the signature of its binary one, dict's | that returns a
    # new dict; this one only refuses)
    def __ior__(self, other: Any) -> NoReturn:  # type: ignore[misc]
        self._refuse()

    def update(self, *args: Any, **kwargs: Any) -> NoReturn:
        self._refuse()

    def setdefault(self, *args: Any) -> NoReturn:
        self._refuse()

    def pop(self, *args: Any) -> NoReturn:
        self._refuse()

    def popitem(self) -> NoReturn:
        self._refuse()

    def clear(self) -> NoReturn:
        self._refuse()

    def __reduce__(self) -> tuple[type[ReadOnlyDict[_K, _V]], tuple[dict[_K, _V]]]:
        # (pickle and copy would otherwise fill the new one item by item, through __setitem__)
        return type(self), (dict(self),)


class ReadOnlyList(list[_V]):
    """A list that cannot be changed once made: the event, jump and sliding lists a frozen
    :class:`SimResult` holds. Every reader takes it for the list it is (``==``, ``+``, json, pickle);
    a write (``append``, ``l[i] = v``, ``sort``, ...) raises TypeError."""

    __slots__ = ()

    def _refuse(self, *args: Any, **kwargs: Any) -> NoReturn:
        raise TypeError(f"{type(self).__name__} cannot be changed: make a changed copy (list(it))")

    __setitem__ = __delitem__ = append = extend = insert = remove = pop = clear = sort = reverse = _refuse
    __iadd__ = __imul__ = _refuse

    def __reduce__(self) -> tuple[type[ReadOnlyList[_V]], tuple[list[_V]]]:
        # (pickle and copy would otherwise fill the new one item by item, through append)
        return type(self), (list(self),)


@dataclass(frozen=True)
class SimResult:
    """The trajectories of one simulation run, arrays by name, SI units.

    ``states`` holds the independent states (what the solver integrates);
    ``dependent`` the states of storage elements in derivative causality
    (``load.p`` of an inertia rigidly geared to another), computed at every
    point from the independent ones by the equations stage's assignment;
    ``bonds`` holds every bond's effort and flow (``b3.e``, ``label.f``);
    ``variables`` every assigned variable (inputs, bond variables, eliminated
    states); ``events`` is a list of ``(time, label)``; ``stats`` the solver's
    counts (nfev, njev, nlu, steps, segments, events, wall_time, ...).

    A result is made once, complete, and not changed (a variant is ``dataclasses.replace``'s): its
    mappings are :class:`ReadOnlyDict` (those given as plain dicts are copied into one).
    """

    t: np.ndarray
    states: ReadOnlyDict[str, np.ndarray]
    outputs: ReadOnlyDict[str, np.ndarray]
    bonds: ReadOnlyDict[str, np.ndarray]
    variables: ReadOnlyDict[str, np.ndarray]
    complete: bool
    message: str
    events: Sequence[tuple[float, str]]
    stats: ReadOnlyDict[str, Any]
    parameters: ReadOnlyDict[str, float]
    failure: ReadOnlyDict[str, Any] | None = None
    model: str = ""
    experiment: str | None = None
    diagnostics: tuple[Diagnostic, ...] = ()
    warnings: tuple[Diagnostic, ...] = ()
    settings: ReadOnlyDict[str, Any] = field(default_factory=ReadOnlyDict)
    # (t, states before, states after) of when clauses
    jumps: Sequence[tuple[float, Any, Any]] = field(default_factory=ReadOnlyList)
    # (t0, t1, corners, times, weights) of each Filippov sliding mode (see bondc.runtime.Result): the
    # energy account evaluates the combination between the points from them
    sliding: Sequence[tuple[Any, ...]] = field(default_factory=ReadOnlyList)
    # the unit of a column as result files show it: name -> (unit text, scale); shown = SI value / scale.
    # Outputs in their declared unit, states and bond variables in SI (as dimensions), t in s.
    units: ReadOnlyDict[str, tuple[str, float]] = field(default_factory=ReadOnlyDict)
    # dependent states (storage in derivative causality), name -> values at every point (SI); they
    # are also in ``variables``, and are not in ``states`` (which the solver integrates)
    dependent: ReadOnlyDict[str, np.ndarray] = field(default_factory=ReadOnlyDict)

    def __post_init__(self) -> None:
        for name in _MAPPINGS:
            value = getattr(self, name)
            if value is not None and not isinstance(value, ReadOnlyDict):
                object.__setattr__(self, name, ReadOnlyDict(value))
        for name in _LISTS:
            value = getattr(self, name)
            if not isinstance(value, ReadOnlyList):
                object.__setattr__(self, name, ReadOnlyList(value))

    @property
    def t_reached(self) -> float:
        return float(self.t[-1]) if self.t.size else float("nan")

    @property
    def exit_status(self) -> int | None:
        """130 for a run stopped by Ctrl-C, 143 by SIGTERM (the shell's statuses), else None."""
        failure: Mapping[str, Any] = self.failure or {}
        if failure.get("kind") != "interrupted":
            return None
        return 143 if failure.get("terminated") else 130

    def error(self) -> SimulationError | None:
        """The failure as a :class:`SimulationError` (carrying this result as ``.result``), or None."""
        if self.complete:
            return None
        error = SimulationError(self.diagnostics or self.message)
        error.result = self
        return error

    def summary(self) -> dict[str, Any]:
        """A JSON-ready summary (what ``bondc simulate --json`` prints)."""
        return {
            "model": self.model,
            "experiment": self.experiment,
            "complete": self.complete,
            "message": self.message,
            "t_reached": self.t_reached,
            "points": int(self.t.size),
            "states": list(self.states),
            "outputs": list(self.outputs),
            "dependent_states": list(self.dependent),
            "final": {name: _json_float(values[-1]) for name, values in
                      {**self.outputs, **self.states, **self.dependent}.items()} if self.t.size else {},
            "events": [{"time": time_, "what": label} for time_, label in self.events],
            "stats": {k: (round(v, 6) if isinstance(v, float) else v) for k, v in self.stats.items()},
            "settings": self.settings,
            "parameters": self.parameters,
            "failure": self.failure,
            "diagnostics": [d.to_json() for d in self.diagnostics],
        }


_FIELDS = frozenset(f.name for f in fields(SimResult))
#: The fields that are mappings (read-only once made).
_LISTS = ("events", "jumps", "sliding")
_MAPPINGS = ("states", "outputs", "bonds", "variables", "stats", "parameters", "failure", "settings", "units",
             "dependent")
_frozen_setattr = SimResult.__setattr__


def _keep_memo(self: SimResult, name: str, value: Any) -> None:
    """A field cannot change (FrozenInstanceError); what an analysis computes once from the run (the
    energy account's run at the solver's steps, ``_solver_steps``, ``_dense_steps``) may be kept on it
    under a private name that is no field."""
    if name.startswith("_") and name not in _FIELDS:
        object.__setattr__(self, name, value)
        return
    _frozen_setattr(self, name, value)


SimResult.__setattr__ = _keep_memo      # type: ignore[method-assign, assignment]


def _json_float(value: Any) -> float | str:
    value = float(value)
    return value if np.isfinite(value) else str(value)


# ------------------------------------------------------------------ compile


def compile_model(ss: StateSpace) -> dict[str, Any]:
    """The generated module of ``ss``, executed in a fresh namespace (cached per StateSpace object)."""
    key = id(ss)
    cached = _COMPILED.get(key)
    if cached is not None and cached[0]() is ss:
        return cached[1]
    from bondc.cache import entry_of

    graph = getattr(ss, "graph", None)
    graph_file = getattr(graph, "file", None)
    module_dir = Path(graph_file).resolve().parent if graph_file else Path.cwd()
    entry = entry_of(ss)        # loaded from (or stored in) the compile cache: its module is there too
    source = entry.read_module() if entry is not None else None
    if source is None:
        from bondc.codegen import emit

        source = emit(ss, None, module_dir=module_dir)
        if entry is not None:
            entry.write_module(source)
    from bondc.runtime.native import native_text, start_native

    # a large model's C library compiles (in parallel units) while Python compiles its module
    start_native(native_text(source))
    name = getattr(graph, "name", "model")
    namespace = {"__name__": f"bondc_generated_{name}", "__file__": str(module_dir / f"__bondc_{name}__.py")}
    # the text is bondc's own output (printed from sympy), never user text; a cached entry keeps
    # it compiled, with the text's hash
    filename = f"<bondc generated module of {name}>"
    compiled = (entry.module_code(source, filename),) if entry is not None else _module_codes(source, filename)
    for code in compiled:
        exec(code, namespace)  # safe: generated by codegen, not model text
    namespace["__bondc_source__"] = source
    try:
        _COMPILED[key] = (weakref.ref(ss), namespace)
    except TypeError:       # not weak-referenceable: do not cache
        pass
    return namespace


def _module_codes(source: str, filename: str) -> tuple[CodeType, ...]:
    """The code of a generated module, as the code objects to execute in turn. The copy of the
    runtime's modules that a module carries (300 kB: 0.1 s of compiling, 30 times its model's
    part for a small model) is compiled once per process, each module under its own file name, so
    that a traceback shows its lines; the text before it and the model after it are compiled
    with their lines numbered as in the whole text. The runtime runs first: the text before it
    (comments and the module's docstring) then sets ``__doc__``, which the runtime modules'
    docstrings, compiled alone, would set too. A text without the copy is compiled whole."""
    from bondc.codegen.emit import runtime_parts, runtime_source

    runtime = runtime_source().rstrip("\n")
    at = source.find(runtime)
    if at < 0:
        return (compile(source, filename, "exec"),)
    if _RUNTIME_CODE.get("text") != runtime:
        _RUNTIME_CODE.update(text=runtime, codes=tuple(compile(text, path, "exec") for path, text in runtime_parts()))
    head, model = source[:at], source[at + len(runtime):]
    return (*_RUNTIME_CODE["codes"], compile(head, filename, "exec"),
            compile("\n" * (head.count("\n") + runtime.count("\n")) + model, filename, "exec"))


_RUNTIME_CODE: dict[str, Any] = {}


# ------------------------------------------------------------------ simulate


def _first(*values: Any) -> Any:
    """The first of ``values`` that is not None (None if all are)."""
    return next((value for value in values if value is not None), None)


#: What a run without an experiment takes its settings from: none declared.
_NO_EXPERIMENT = ExperimentDef("", None)


def _settings(experiment: ExperimentDef | None, t_end: float | None, dt: float | None, method: str | None,
              rtol: float | None, atol: float | None, max_step: float | None,
              first_step: float | None = None) -> dict[str, Any]:
    """The run's settings: each one given here, else the experiment's, else the default."""
    declared = experiment if experiment is not None else _NO_EXPERIMENT
    extra = declared.settings
    settings = {
        "t_end": _first(t_end, declared.t_end),
        "method": _first(method, declared.solver),
        "rtol": float(_first(rtol, declared.rtol, 1e-6)),
        "atol": float(_first(atol, declared.atol, 1e-9)),
        "max_step": _first(max_step, declared.max_step),
        "dt": _first(dt, extra.get("dt")),
        "first_step": _first(first_step, extra.get("first_step")),
    }
    # Settings from the model are checked by the semantic stage; these can come from the command line.
    for name in ("t_end", "dt", "max_step", "rtol", "atol", "first_step"):
        value = settings[name]
        if value is not None and not (np.isfinite(float(value)) and float(value) > 0):
            raise UsageError(Diagnostic("error", codes.E803, f"cannot simulate: {name} must be a positive number, "
                                                         f"not {value:g}",
                                        hint=f"give a positive {name} (seconds for times)"))
    return settings


def _check_overrides(ss: StateSpace, overrides: Mapping[str, float] | None) -> dict[str, float]:
    overrides = dict(overrides or {})
    names = list(ss.parameters)
    for name in overrides:
        if name not in ss.parameters:
            close = difflib.get_close_matches(name, names, n=1)
            hint = f"did you mean '{close[0]}'?" if close else "parameters: " + ", ".join(names)
            raise UsageError(Diagnostic("error", codes.E802, f"unknown parameter '{name}'", hint=hint))
    return {name: float(value) for name, value in overrides.items()}


def _check_bound_divisors(ss: StateSpace, namespace: Mapping[str, Any], overrides: Mapping[str, float]) -> None:
    """E311 (raised as a ModelError) when parameter values given after the check (a sweep's point)
    make a divisor 0, as the check says for the same values given with ``--set``."""
    from bondc.errors import ModelError
    from bondc.semantic import zero_divisors

    divisors = getattr(getattr(ss, "graph", None), "divisors", ())
    if not divisors:
        return
    names = tuple(namespace["PARAMETERS"])
    values = namespace["param_array"](namespace["PARAMETERS"], dict(overrides), namespace["_derive_parameters"])
    found = zero_divisors(divisors, dict(zip(names, (float(v) for v in values))))
    if found:
        raise ModelError(found, getattr(ss.graph, "sources", None))


# ------------------------------------------------------------ external inputs


def _input_error(code: str, message: str, hint: str | None = None) -> UsageError:
    return UsageError(Diagnostic("error", code, message, hint=hint))


def external_inputs(ss: StateSpace, inputs: Any) -> dict[str, Any]:
    """The signals a host gives the external inputs of ``ss`` (``input u [V] external``), checked:
    ``{name: (times, values) or f(t)}``, SI. E805 for a name that is no input, E806 for an input
    the model computes itself, E807 for a signal that is not a table of numbers or a function."""
    if inputs is None:
        return {}
    if not isinstance(inputs, Mapping):
        raise _input_error(codes.E807, f"inputs must be a dict {{name: (times, values) or f(t)}}, not "
                                   f"{type(inputs).__name__}", hint='e.g. inputs={"u": ([0, 1], [0, 10])}')
    graph = getattr(ss, "graph", None)
    signals = dict(getattr(graph, "inputs", None) or {})
    external = [name for name, signal in signals.items() if getattr(signal, "external", False)]
    listed = ", ".join(external) if external else "none"
    from bondc.runtime.signals import InputError, external_inputs as untyped

    # (the engine is not annotated: its function's contract, as it is called here)
    prepare: Callable[[Mapping[str, Any], tuple[str, ...]], dict[str, Any]] = untyped

    for name in inputs:
        if name not in signals:
            close = difflib.get_close_matches(str(name), external, n=1)
            raise _input_error(codes.E805, f"the model has no input '{name}' to supply",
                               hint=(f"did you mean '{close[0]}'? " if close else "") + f"its external inputs: {listed}")
        if name not in external:
            raise _input_error(codes.E806, f"input '{name}' is not external: the model computes it",
                               hint=f"declare it 'input {name} [UNIT] external' to supply it from outside; "
                                    f"the external inputs: {listed}")
    try:
        return prepare(inputs, tuple(external))
    except InputError as error:
        raise _input_error(codes.E807, f"cannot use the signal given for an external input: {error}",
                           hint="give (times, values): two sequences of numbers of one length, times not "
                                "decreasing, in SI; or a function of t") from None


def read_input_files(ss: StateSpace, specs: Sequence[str] | None) -> dict[str, Any]:
    """``bondc simulate --input u=FILE.csv[:COLUMN]``: each external input's table from a CSV file,
    read by the reader of ``csv()`` (time column ``t`` or ``time``, else the first; units in the
    header applied; rows as csv() reads them). COLUMN defaults to the input's name, or to the only
    column besides time. Names are checked as :func:`external_inputs` does (E805, E806); a file
    or column that cannot be read is E807."""
    from bondc.numeric import csv_scales
    from bondc.runtime.signals import CsvError

    columns_of, load_csv = _csv_readers()

    graph = getattr(ss, "graph", None)
    signals = dict(getattr(graph, "inputs", None) or {})
    tables: dict[str, Any] = {}
    for spec in specs or ():
        name, equals, target = spec.partition("=")
        name = name.strip()
        if not equals or not name or not target:
            raise _input_error(codes.E807, f"--input takes NAME=FILE.csv[:COLUMN], not '{spec}'",
                               hint="e.g. --input u=drive.csv:voltage")
        if name in tables:
            raise _input_error(codes.E807, f"--input gives input '{name}' twice")
        external_inputs(ss, {name: lambda t: 0.0})          # the name: E805, E806
        path, column = target, None
        if not Path(target).is_file() and ":" in target:
            path, _, column = target.rpartition(":")
        if not Path(path).is_file():
            raise _input_error(codes.E807, f"--input {name}: no file '{path}'",
                               hint="the file is read relative to the current directory")
        try:
            columns = [c for c, _ in columns_of(path)]
        except (OSError, UnicodeDecodeError, ValueError) as error:
            raise _input_error(codes.E807, f"--input {name}: cannot read '{path}': {error}") from None
        if column is None:
            lowered = [c.lower() for c in columns]
            time_index = lowered.index("t") if "t" in lowered else (lowered.index("time") if "time" in lowered else 0)
            others = [c for i, c in enumerate(columns) if i != time_index]
            column = name if name in columns else (others[0] if len(others) == 1 else None)
            if column is None:
                raise _input_error(codes.E807, f"--input {name}: '{path}' has no column '{name}'",
                                   hint=f"name the column: --input {name}={path}:COLUMN (its columns: "
                                        f"{', '.join(columns)})")
        elif column not in columns:
            close = difflib.get_close_matches(column, columns, n=1)
            raise _input_error(codes.E807, f"--input {name}: '{path}' has no column '{column}'",
                               hint=(f"did you mean '{close[0]}'? " if close else "") + f"its columns: "
                                    f"{', '.join(columns)}")
        try:
            time_scale, value_scale = csv_scales(path, column)
            times, values = load_csv(path, column)
        except (CsvError, ValueError, OSError) as error:
            raise _input_error(codes.E807, f"--input {name}: {error}",
                               hint="a header line (time first, units in brackets as 't [ms]'), then rows of "
                                    "numbers; times must not decrease") from None
        _check_header_unit(name, signals.get(name), path, column)
        tables[name] = (times * time_scale, values * value_scale)
    return external_inputs(ss, tables)


def _csv_readers() -> tuple[Callable[[str], list[tuple[str, str | None]]],
                             Callable[[str, str], tuple[np.ndarray, np.ndarray]]]:
    """The engine's readers of a csv file (not annotated there), with their contracts: its header's
    ``[(name, unit or None), ...]``, and a column's (times, values)."""
    from bondc.runtime.signals import csv_columns, load_csv

    return csv_columns, load_csv


def _check_header_unit(name: str, signal: Any, path: str, column: str) -> None:
    """E807 when the unit a file's header gives a column is not of the input's declared dimension."""
    from bondc.units import unit_of

    columns_of, _ = _csv_readers()
    declared = getattr(signal, "unit_text", None)
    written = dict(columns_of(path)).get(column)
    if not declared or not written:
        return
    have, want = unit_of(written), unit_of(declared)
    if have is not None and want is not None and tuple(have.dims) != tuple(want.dims):
        raise _input_error(codes.E807, f"--input {name}: column '{column}' of '{path}' is in [{written}], which is not "
                                   f"a unit of input '{name}' [{declared}]",
                           hint="give the column's unit in its header in a unit of the input's dimension")


def simulate(ss: StateSpace, experiment: ExperimentDef | None = None, *, t_end: float | None = None,
             dt: float | None = None, overrides: Mapping[str, float] | None = None, progress: bool = False,
             t_eval: Any = None,
             method: str | None = None, rtol: float | None = None, atol: float | None = None,
             max_step: float | None = None, first_step: float | None = None, inputs: Any = None) -> SimResult:
    """Simulate ``ss`` with the settings of ``experiment`` (an ExperimentDef or None).

    Keyword arguments override the experiment: ``t_end`` [s], ``dt`` (report
    on a regular grid instead of at every solver step), ``overrides``
    (parameter name -> SI value), ``t_eval`` (report at these times),
    ``method``/``rtol``/``atol``/``max_step``/``first_step``. ``progress``: draw a progress
    bar on stderr when the run takes more than 2 s and stderr is a terminal. ``inputs``: the
    signals of the model's external inputs, ``{name: (times, values) or f(t)}`` in SI (see
    :func:`external_inputs`); one not given takes its default, and the result's warnings say so
    (I346). Never raises for a failed run: see ``SimResult.complete``.
    """
    supplied = external_inputs(ss, inputs)
    settings = _settings(experiment, t_end, dt, method, rtol, atol, max_step, first_step)
    if settings["t_end"] is None:
        raise UsageError(Diagnostic("error", codes.E801, "no end time for the simulation",
                                    hint="give --t-end, or set t_end in the experiment"))
    p = _check_overrides(ss, overrides)
    base = ss.bound_base                            # values bound late (--set): the base's module
    namespace = compile_model(base if base is not None else ss)
    if base is not None:
        p = {**{name: value for name, (_, value) in ss.parameters.items()}, **p}
    if p:
        _check_bound_divisors(ss, namespace, p)
    bar = ProgressBar(0.0, float(settings["t_end"]), note=_solver_note(settings["method"])) if progress else None
    try:
        raw = namespace["simulate_model"](
            namespace["_MODEL"], float(settings["t_end"]), p or None, t_eval, method=settings["method"],
            rtol=settings["rtol"], atol=settings["atol"], max_step=settings["max_step"],
            first_step=settings["first_step"], dt=settings["dt"], progress=bar,
            **({"inputs": supplied} if supplied else {}))
    except ValueError as error:
        if type(error).__name__ == "CsvError":      # the generated module's own class
            raise DataError(Diagnostic("error", codes.E804, f"cannot read a measured signal: {error}")) from None
        if type(error).__name__ == "InputError":    # a host's function of t that returned no number
            raise UsageError(Diagnostic("error", codes.E807, f"cannot use the signal given for an external input: "
                                                         f"{error}")) from None
        raise UsageError(Diagnostic("error", codes.E803, f"cannot simulate: {error}")) from None
    finally:
        if bar is not None:
            bar.close()
    from bondc.model import external_input_notes

    return _result(ss, experiment, namespace, raw, settings,
                   notes=external_input_notes(getattr(ss, "graph", None), supplied))


def dependent_states(ss: StateSpace, variables: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The states of storage elements in derivative causality (``ss.eliminated_names``), name ->
    values: the runtime evaluates their assignment (in the independent states) at every point, as
    it does every bond variable; the energy account uses the same values. (The names only: a
    cached run's light state space has them without sympy.)"""
    found = {}
    for name in getattr(ss, "eliminated_names", ()):
        values = variables.get(name)
        if values is not None:
            found[name] = values
    return found


def _all_finite(series: Iterable[np.ndarray]) -> bool:
    """Whether every value of every series is finite, checked per matrix the series are rows of
    (the runtime's results are rows of one matrix: one sum instead of thousands). False when unsure."""
    bases = {}
    for values in series:
        base = values.base if isinstance(values, np.ndarray) else None
        if base is None or getattr(base, "ndim", 0) != 2:
            return False
        bases[id(base)] = base
    return all(math.isfinite(np.sum(base)) for base in bases.values())


def _result(ss: Any, experiment: ExperimentDef | None, namespace: Mapping[str, Any], raw: Any, settings: Mapping[str, Any],
            notes: Sequence[Diagnostic] = ()) -> SimResult:
    """What :func:`simulate` makes of the engine's raw run: readable names, units, the failure's
    diagnostic and the warnings (``notes`` first) about values that are not finite and chattering."""
    graph = getattr(ss, "graph", None)
    names = readable_names(graph)
    t = raw.t
    outputs = dict(raw.outputs)
    bonds = {name: raw.variables[name] for name in namespace["BOND_VARIABLES"]}
    events = [(time_, readable(names, label)) for time_, label in raw.events]
    diagnostics = (_failure_diagnostic(graph, raw.failure, raw, names),) if raw.failure is not None else ()
    warnings = [*notes, *_nonfinite_warnings(graph, t, outputs, bonds, raw.complete),
                *_chattering_warnings(graph, events, raw.stats)]
    return SimResult(
        t=t, states=ReadOnlyDict(raw.states), outputs=ReadOnlyDict(outputs), bonds=ReadOnlyDict(bonds),
        variables=ReadOnlyDict(raw.variables), complete=raw.complete, message=readable(names, raw.message),
        events=events, stats=ReadOnlyDict(raw.stats), parameters=ReadOnlyDict(raw.parameters),
        failure=ReadOnlyDict(raw.failure) if raw.failure is not None else None,
        model=getattr(graph, "name", "") or "", experiment=experiment.name if experiment is not None else None,
        diagnostics=diagnostics, warnings=tuple(warnings),
        settings=ReadOnlyDict({k: v for k, v in settings.items() if v is not None}),
        jumps=list(getattr(raw, "jumps", ())), sliding=list(getattr(raw, "sliding", ())),
        units=ReadOnlyDict(result_units(graph)), dependent=ReadOnlyDict(dependent_states(ss, raw.variables)),
    )


def _nonfinite_warnings(graph: Any, t: np.ndarray, outputs: Mapping[str, np.ndarray],
                        bonds: Mapping[str, np.ndarray], complete: bool) -> list[Diagnostic]:
    """W821: the first output, and the first bond variable, that is not finite at some point."""
    found = []
    for group, values in (("output", outputs), ("bond variable", bonds)):
        if _all_finite(values.values()):
            continue
        for name, series in values.items():
            if math.isfinite(np.sum(series)):     # the common case, at once (a sum is nan/inf when any is)
                continue
            bad = np.flatnonzero(~np.isfinite(series))
            if bad.size:
                alias = bond_alias(graph, name) if group == "bond variable" else None
                shown = f"{name} ({alias})" if alias else name
                first = int(bad[0])
                # the recorded points bracket where it stops being finite, not the instant itself
                before = f" (the point before it, at t={t[first - 1]:.6g} s, is finite)" if first > 0 else ""
                found.append(Diagnostic(
                    "warning", codes.W821, f"{group} '{shown}' is not finite at {bad.size} of {series.size} recorded "
                                       f"points, the first at t={t[first]:.6g} s{before}",
                    law_span(graph, name) or _no_span(),
                    hint="its law is evaluated outside its domain there; " + (
                        "the states are unaffected (none of their rates reads it)" if complete else
                        "the run stopped (the error says where and why)")))
                break
    return found


def _chattering_warnings(graph: Any, events: Sequence[tuple[float, str]], stats: Mapping[str, Any]
                         ) -> list[Diagnostic]:
    """W820: switching faster than events can be located, at its first episode."""
    chattering = [(time, label) for time, label in events if label.startswith("chattering")]
    if not chattering:
        return []
    first_time, first_label = chattering[0]
    switches = first_label.partition("(")[2].rstrip(")")
    more = f" (and {len(chattering) - 1} more episode{'s' if len(chattering) > 2 else ''})" \
        if len(chattering) > 1 else ""
    return [Diagnostic(
        "warning", codes.W820,
        f"chattering from t={first_time:.6g} s{more}: {switches} kept changing mode faster than events can "
        "be located; integrated with the unfrozen law there",
        law_span(graph, stats.get("chattering_law")) or _no_span(),
        hint="switching that accumulates (a Zeno approach to rest) or that no sliding mode resolves; the "
             "switching instants there are not located, so results there are only as good as the solver's "
             "steps (lower rtol for a tighter result)")]


_CODES = {"nonfinite": codes.E810, "solver": codes.E811, "events": codes.E812, "interrupted": codes.E813, "points": codes.E814,
          "diverged": codes.E815}


def _failure_diagnostic(graph: Any, failure: Mapping[str, Any], raw: Any, names: Any = None) -> Diagnostic:
    reached = float(raw.t[-1]) if raw.t.size else failure.get("time", 0.0)
    text = failure["message"]
    variable = failure.get("variable")
    alias = bond_alias(graph, variable)
    if alias:
        text = text.replace(f"'{variable}'", f"'{variable}' ({alias})", 1)
    text = readable(names, text)
    message = f"simulation stopped: {text.rstrip('. ')}; results up to t={reached:.6g} s were kept (incomplete)"
    if failure.get("cause"):
        message += f". Likely cause: {failure['cause']}"
    from bondc.source import NO_SPAN

    span = law_span(graph, failure.get("variable")) or _when_span(graph, failure.get("when")) or NO_SPAN
    return Diagnostic("error", _CODES.get(str(failure.get("kind")), codes.E811), message, span, hint=failure.get("hint"))


def _when_span(graph: Any, label: str | None) -> Span | None:
    """The span of the when clause whose condition reads ``label``."""
    for when in getattr(graph, "whens", ()) if label else ():
        if when.text == label:
            span: Span = when.span
            return span
    return None


def _no_span() -> Span:
    from bondc.source import NO_SPAN

    return NO_SPAN


# --------------------------------------------------------------- progress


def _solver_note(method: str | None) -> str | None:
    """Why a run on one of scipy's solvers may be slow, for the progress bar: None for the others.

    >>> _solver_note("Radau")[:45]
    "solver 'Radau' is scipy's: it takes its steps"
    >>> _solver_note("CVODE") is None and _solver_note(None) is None
    True
    """
    from bondc.runtime.solvers import SOLVER_NAMES

    scipy_solvers = SOLVER_NAMES[SOLVER_NAMES.index("DOPRI5") + 1:]
    name = next((known for known in scipy_solvers if str(method or "").lower() == known.lower()), None)
    if name is None:
        return None
    return (f"solver '{name}' is scipy's: it takes its steps in Python, one call per step; CVODE (solver = "
            f"\"auto\", the default, or \"CVODE\") takes them in C, often 10 to 100 times faster")


class ProgressBar:
    """A one-line progress bar on stderr, drawn only after 2 s and only on a terminal; ``note``
    (why the run may be slow) is written on its own line above the bar when it is first drawn."""

    def __init__(self, t_start: float, t_end: float, stream: TextIO | None = None, delay: float = 2.0,
                 note: str | None = None) -> None:
        self.t_start, self.t_end = t_start, t_end
        self.stream = stream or sys.stderr
        self.note = note
        self.delay = delay
        self.started = time.monotonic()
        self.last = 0.0
        self.drawn = False
        try:
            self.enabled = self.stream.isatty()
        except (AttributeError, ValueError):
            self.enabled = False

    def __call__(self, t: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.started < self.delay or now - self.last < 0.1:
            return
        self.last = now
        if self.note and not self.drawn:
            self.stream.write(f"note: {self.note}\n")
        fraction = min(max((t - self.t_start) / (self.t_end - self.t_start), 0.0), 1.0)
        width = 30
        filled = int(round(fraction * width))
        elapsed = now - self.started
        remaining = elapsed * (1 - fraction) / fraction if fraction > 0 else float("nan")
        self.stream.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {100 * fraction:5.1f}%  t={t:.4g} s  "
                          f"elapsed {elapsed:.0f} s, about {remaining:.0f} s left ")
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\r" + " " * 79 + "\r")
            self.stream.flush()


# ------------------------------------------------------------------ files


def _columns(result: SimResult, all_bonds: bool) -> tuple[list[str], list[np.ndarray]]:
    """t, the outputs, the states, the dependent states (derivative causality), and with
    ``all_bonds`` every bond variable."""
    states = {**result.states, **{n: v for n, v in result.dependent.items() if n not in result.states}}
    names = ["t"] + list(result.outputs) + [n for n in states if n not in result.outputs]
    columns = [result.t] + list(result.outputs.values()) + [v for n, v in states.items()
                                                             if n not in result.outputs]
    if all_bonds:
        for name, values in result.bonds.items():
            if name not in names:
                names.append(name)
                columns.append(values)
    return names, columns


def csv_text(result: SimResult, all_bonds: bool = False) -> str:
    """The result as csv: a header of names with units (``t [s]``, ``P_kPa [kPa]``), then one row per
    point; each output in its declared unit, states and bond variables in SI."""
    from bondc.runtime.results import result_bytes

    names, columns = _columns(result, all_bonds)
    return result_bytes("csv", names, columns, result.units).decode("utf-8")


def _write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """``data`` as the file ``path``, atomically."""
    def write(handle: BinaryIO) -> None:
        handle.write(data)

    atomic_write(Path(path), write)


def _metadata(result: SimResult) -> dict[str, Any]:
    return {"model": result.model or "", "experiment": result.experiment or "", "complete": result.complete,
            "message": result.message}


def write_csv(result: SimResult, path: str | os.PathLike[str], all_bonds: bool = False) -> None:
    """Write ``t``, outputs, states (and bonds) as csv, atomically (see the module docstring)."""
    text = csv_text(result, all_bonds)
    _write_bytes(path, text.encode("utf-8"))


def write_parquet(result: SimResult, path: str | os.PathLike[str], all_bonds: bool = False) -> None:
    """The csv's table as Parquet (needs pyarrow), atomically: each column in the csv's unit, with
    its ``unit`` and ``si_factor`` in the field's metadata; the model, experiment and status in the
    file's."""
    from bondc.runtime.results import result_bytes

    names, columns = _columns(result, all_bonds)
    try:
        data = result_bytes("parquet", names, columns, result.units, metadata=_metadata(result))
    except ImportError as error:
        raise UsageError(Diagnostic("error", codes.E001, f"cannot write '{path}': {error}",
                                    hint="pip install pyarrow, or give -o run.csv (or run.npz)")) from None
    _write_bytes(path, data)


def write_npz(result: SimResult, path: str | os.PathLike[str], all_bonds: bool = True) -> None:
    """Write the arrays as a compressed ``.npz``, atomically: ``t``, ``states/NAME``, ``dependent/NAME``
    (states in derivative causality), ``outputs/NAME``, ``bonds/NAME`` (SI), with ``unit/KEY`` and
    ``si_factor/KEY`` of each (KEY / si_factor is in unit: an output's declared unit), then
    ``complete``, ``message``, ``event_times``, ``event_labels``, ``parameter_names``,
    ``parameter_values``."""
    from bondc.runtime.results import result_bytes

    arrays = {"t": result.t}
    arrays.update({f"states/{k}": v for k, v in result.states.items()})
    arrays.update({f"dependent/{k}": v for k, v in result.dependent.items()})
    arrays.update({f"outputs/{k}": v for k, v in result.outputs.items()})
    if all_bonds:
        arrays.update({f"bonds/{k}": v for k, v in result.bonds.items()})
    metadata = {"complete": np.array(result.complete), "message": np.array(result.message),
                "event_times": np.array([e[0] for e in result.events], dtype=float),
                "event_labels": np.array([e[1] for e in result.events], dtype=str),
                "parameter_names": np.array(list(result.parameters), dtype=str),
                "parameter_values": np.array(list(result.parameters.values()), dtype=float)}
    data = result_bytes("npz", [], [], result.units, arrays=arrays, metadata=metadata)
    _write_bytes(path, data)


#: Suffixes of formats a result is not written in: a .json would otherwise get csv text.
OTHER_FORMATS = (".json", ".xlsx", ".xls", ".mat", ".h5", ".hdf5", ".html", ".txt.gz", ".pkl")


def check_result_path(path: str | os.PathLike[str]) -> None:
    """E001 for an output file whose suffix names a format other than csv, npz and parquet (before any
    work)."""
    name = str(path).lower()
    other = next((suffix for suffix in OTHER_FORMATS if name.endswith(suffix)), None)
    if other is not None:
        raise UsageError(Diagnostic("error", codes.E001, f"cannot write '{path}' as {other[1:]}: a simulation "
                                                     "is written as .csv (or .npz, numpy's arrays, or "
                                                     ".parquet)",
                                    hint="give -o run.csv (or run.npz, run.parquet); bondc simulate --json prints a "
                                         "JSON summary on stdout"))


def write(result: SimResult, path: str | os.PathLike[str], all_bonds: bool = False) -> None:
    """``.npz`` -> :func:`write_npz`, ``.parquet`` -> :func:`write_parquet`, anything else ->
    :func:`write_csv` (see :func:`check_result_path`); every format records each column's unit."""
    from bondc.runtime.results import result_format

    check_result_path(path)
    kind = result_format(path)
    if kind == "npz":
        write_npz(result, path)
    elif kind == "parquet":
        write_parquet(result, path, all_bonds)
    else:
        write_csv(result, path, all_bonds)
