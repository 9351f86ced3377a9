"""Calibration: the parameter values that make a model's outputs match measured data (``bondc fit``).

:func:`run_fit` is ``bondc fit`` without argument parsing. It minimises, with
:func:`scipy.optimize.least_squares` (trust-region reflective, bounds honoured),
the weighted residuals of every compared signal of every data set::

    r = weight * (model - measured) / range(measured)

each data set (a measured CSV, read as ``bondc validate`` reads it: header
units converted to SI, time column ``t``/``time`` or the first) simulated with
its experiment at the measured instants the run covers. Dividing by the
measured range puts signals of different units (a torque in N*m, a pressure
in Pa) on one scale, as the NRMSE does; ``:weight=W`` weighs a signal more
(or less).

**One compiled model, late-bound values.** Each experiment's model is loaded,
derived and compiled once (:func:`bondc.pipeline.derive_file`, the compile
cache); every evaluation only gives the compiled module a new vector of
parameter values (as ``bondc sweep`` runs its points), and the module
recomputes the parameters defined by others (``F_n0 = M*g - ...``). A
parameter that cannot be given that way is refused before the fit (E883, with
the reason): one that sets an experiment setting (``t_end = t9``,
``max_step = h``: fixed before the run starts) or changes the model's
structure (what its equations are derived from besides values).

**Gradients.** The Jacobian is computed by central differences of late-bound
parameters: each column from two runs at ``x ± h``, ``h`` relative to the
parameter (:data:`RELATIVE_STEP`, the cube root of the fit's relative
tolerance, where the truncation error and the solver's noise balance). The
runs of a fit use a tighter tolerance than the experiment's
(:data:`FIT_RTOL`, :data:`FIT_ATOL`, never looser than the experiment's), so
that the solver's error is far below the effect of a step. The tests check
these columns against the closed-form sensitivity of a mass-spring-damper.

**Uncertainty.** At the solution, with ``J`` the Jacobian of the weighted
residuals (m residuals, n parameters) and ``s² = 2 cost / (m - n)`` (cost =
½ Σ r²): ``cov = s² (JᵀJ)⁻¹`` (through the singular value decomposition of J),
the standard errors its diagonal's roots, the 95 % interval
``value ± t(0.975, m - n) stderr`` (Student's t, :mod:`scipy.stats`), the
correlation matrix ``cov_ij / (σ_i σ_j)``. The intervals are those of a model
that is linear near the solution, with independent noise of one variance in
the weighted residuals.

**Warnings** (the fit still reports what it reached): W880 two parameters
whose estimates correlate beyond :data:`CORRELATION_LIMIT` (the data cannot
tell them apart); W881 a Jacobian that is rank-deficient (a direction of the
parameters that changes no residual: the parameters named, their intervals
infinite); W882 an estimate on its bound (its interval is not meaningful);
W883 the optimiser stopped before it converged (exit status 1); W884 runs that
failed at some trial points.

Problems with the request are :class:`~bondc.errors.UsageError` (exit 2) or
:class:`~bondc.errors.DataError` (exit 1) with codes E880-E892 (see
``docs/diagnostics.md``).

>>> parse_compare("x=x_meas:weight=2")
FitCompare(output='x', column='x_meas', weight=2.0, text='x=x_meas:weight=2')
>>> e = parse_estimate("b=5:30")
>>> e.name, e.low, e.high, e.unit
('b', 5.0, 30.0, None)
"""

from __future__ import annotations

import difflib
import math
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from bondc.errors import BondcError, DataError, Diagnostic, UsageError
from bondc.source import NO_SPAN, Span
from bondc import codes

if TYPE_CHECKING:
    from bondc.pipeline import Derived

__all__ = ["FitCompare", "Estimate", "DataSet", "FitResult", "parse_compare", "parse_estimate", "parse_groups",
           "run_fit", "prepare_fit", "FitProblem", "FIT_RTOL", "FIT_ATOL", "RELATIVE_STEP", "CORRELATION_LIMIT"]

#: The relative and absolute tolerance of every run of a fit (the experiment's when tighter).
FIT_RTOL = 1e-9
FIT_ATOL = 1e-11
#: The central-difference step, relative to the parameter: ~ FIT_RTOL^(1/3), where the step's
#: truncation error (~h²) and the solver's noise divided by the step (~rtol/h) balance.
RELATIVE_STEP = 1e-3
#: |correlation| above this: the two estimates cannot be told apart (W880).
CORRELATION_LIMIT = 0.99
#: A singular value of the (scaled) Jacobian below this share of the largest: rank-deficient (W881).
RANK_TOLERANCE = 1e-6
#: Function evaluations of the optimiser by default (each Jacobian costs 2n runs more).
DEFAULT_MAX_EVALUATIONS = 200


def _usage(code: str, message: str, hint: str | None = None) -> UsageError:
    return UsageError(Diagnostic("error", code, message, hint=hint))


def _did_you_mean(name: str, choices, what: str) -> str:
    choices = list(choices)
    close = difflib.get_close_matches(name, choices, n=1)
    listed = ", ".join(choices[:40]) + (", ..." if len(choices) > 40 else "")
    return (f"did you mean '{close[0]}'? " if close else "") + f"{what}: {listed}"


# ------------------------------------------------------------------ the request

@dataclass(frozen=True)
class FitCompare:
    """``--compare OUT=COLUMN[:weight=W]``: a simulated signal against a measured column, weighted."""

    output: str
    column: str
    weight: float = 1.0
    text: str = ""


_SIGNAL = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
_COMPARE_HINT = "write OUT=COLUMN, optionally weighted: --compare torque=tau_meas:weight=2"


def parse_compare(text: str) -> FitCompare:
    """``OUT=COLUMN[:weight=W]`` -> :class:`FitCompare` (E880 when it is not that)."""
    head, colon, tail = text.strip().partition(":")
    output, equals, column = head.partition("=")
    output, column = output.strip(), column.strip()
    if not equals or not _SIGNAL.fullmatch(output) or not column or "=" in column:
        raise _usage(codes.E880, f"--compare '{text}' is not OUT=COLUMN[:weight=W]", hint=_COMPARE_HINT)
    weight = 1.0
    if colon:
        key, eq, value = tail.partition("=")
        if key.strip().lower() != "weight" or not eq:
            raise _usage(codes.E880, f"--compare '{text}': '{tail.strip()}' is not weight=W",
                         hint=_COMPARE_HINT + " (a fit takes no tolerances; bondc validate does)")
        try:
            weight = float(value)
        except ValueError:
            weight = math.nan
        if not (math.isfinite(weight) and weight > 0):
            raise _usage(codes.E880, f"--compare '{text}': the weight '{value.strip()}' is not a positive number",
                         hint=_COMPARE_HINT)
    return FitCompare(output, column, weight, text.strip())


@dataclass(frozen=True)
class Estimate:
    """``--estimate NAME[=LOW:HIGH] [unit]``: a parameter to estimate, its bounds (None: open) in
    ``unit`` (None: the parameter's declared unit)."""

    name: str
    low: float | None = None
    high: float | None = None
    unit: str | None = None
    text: str = ""


_ESTIMATE = re.compile(r"^\s*(?P<name>[^=\[\]]*?)\s*(?:=\s*(?P<bounds>[^\[\]]*?))?\s*"
                       r"(?:\[(?P<unit>[^\[\]]*)\])?\s*$")
_ESTIMATE_HINT = 'write NAME, or NAME=LOW:HIGH with bounds in its declared unit (or a unit in [ ]): ' \
                 '--estimate b=5:30, --estimate "Ae=5:50 [mm^2]"; an empty bound is open (b=0:)'


def _bound(text: str, spec: str) -> float | None:
    text = text.strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise _usage(codes.E881, f"--estimate '{spec}': the bound '{text}' is not a finite number", hint=_ESTIMATE_HINT)
    return value


def parse_estimate(text: str) -> Estimate:
    """``NAME[=LOW:HIGH] [unit]`` -> :class:`Estimate` (E881 syntax, E884 LOW >= HIGH)."""
    match = _ESTIMATE.match(text)
    if match is None or not _SIGNAL.fullmatch(match["name"] or ""):
        raise _usage(codes.E881, f"--estimate '{text}' is not NAME[=LOW:HIGH] [unit]", hint=_ESTIMATE_HINT)
    unit = match["unit"].strip() if match["unit"] is not None else None
    if unit == "":
        raise _usage(codes.E881, f"--estimate '{text}': the unit between [ ] is empty", hint=_ESTIMATE_HINT)
    low = high = None
    if match["bounds"] is not None:
        parts = match["bounds"].split(":")
        if len(parts) != 2:
            raise _usage(codes.E881, f"--estimate '{text}': the bounds '{match['bounds']}' are not LOW:HIGH",
                         hint=_ESTIMATE_HINT)
        low, high = _bound(parts[0], text), _bound(parts[1], text)
        if low is not None and high is not None and not low < high:
            raise _usage(codes.E884, f"--estimate '{text}': the lower bound {low:g} is not below the upper bound "
                                 f"{high:g}", hint="give LOW:HIGH with LOW < HIGH")
    elif unit is not None:
        raise _usage(codes.E881, f"--estimate '{text}': a unit without bounds", hint=_ESTIMATE_HINT)
    return Estimate(match["name"], low, high, unit, text.strip())


@dataclass(frozen=True)
class DataSet:
    """One measured data set: its CSV, the comparisons in it, and the experiment it was measured in
    (None: the model's first)."""

    data: str
    compare: tuple = ()
    experiment: str | None = None


def parse_groups(items: Sequence[tuple[str, str]], experiment: str | None = None) -> list[DataSet]:
    """The data sets of ``bondc fit``'s ``--data``, ``--experiment`` and ``--compare`` in command-line
    order (``("data", FILE)``, ...): each ``--data`` starts a data set, the ``--experiment`` and
    ``--compare`` after it belong to it; an ``--experiment`` before the first ``--data`` is every
    data set's default (E889 for a --compare before any --data, a data set without a comparison, or
    two experiments in one data set)."""
    groups: list[dict] = []
    for kind, value in items:
        if kind == "data":
            groups.append({"data": value, "compare": [], "experiment": None})
        elif not groups:
            if kind == "compare":
                raise _usage(codes.E889, f"--compare '{value}' comes before any --data",
                             hint="each --data starts a data set; give its --compare (and --experiment) after it")
            if experiment is not None and experiment != value:
                raise _usage(codes.E889, "two --experiment before the first --data",
                             hint="give one default --experiment, or one after each --data")
            experiment = value
        elif kind == "compare":
            groups[-1]["compare"].append(parse_compare(value) if isinstance(value, str) else value)
        else:
            if groups[-1]["experiment"] is not None:
                raise _usage(codes.E889, f"data set '{groups[-1]['data']}' has two --experiment",
                             hint="one experiment per --data: repeat --data for another experiment")
            groups[-1]["experiment"] = value
    if not groups:
        raise _usage(codes.E889, "bondc fit needs measured data: --data FILE --compare OUT=COLUMN",
                     hint="e.g. bondc fit m.bg --data measured.csv --compare x=x_meas --estimate b")
    for group in groups:
        if not group["compare"]:
            raise _usage(codes.E889, f"data set '{group['data']}' has no --compare",
                         hint="say which simulated signal each measured column is: --data FILE --compare OUT=COLUMN")
    return [DataSet(g["data"], tuple(g["compare"]), g["experiment"] if g["experiment"] is not None else experiment)
            for g in groups]


# ------------------------------------------------------------------ the problem

@dataclass
class _Signal:
    spec: FitCompare
    measured: np.ndarray            # SI, at the group's times
    scale: float                    # the measured range: residuals are divided by it
    unit: str | None                # the output's display unit
    factor: float                   # SI value / display value


@dataclass
class _Group:
    dataset: DataSet
    derived: Derived                # of its experiment
    times: np.ndarray
    signals: list[_Signal]


@dataclass
class _Parameter:
    name: str
    unit: str | None                # declared
    factor: float                   # SI value / declared value
    initial: float                  # SI
    low: float                      # SI (-inf: open)
    high: float                     # SI (inf: open)
    span: Span = NO_SPAN


@dataclass
class SignalFit:
    """One compared signal, before and after the fit (RMSE in the signal's display unit)."""

    data: str
    output: str
    column: str
    unit: str | None
    t: np.ndarray
    measured: np.ndarray            # display unit
    before: np.ndarray
    after: np.ndarray
    rmse_before: float
    rmse: float
    nrmse_before: float
    nrmse: float

    def to_json(self) -> dict:
        return {"output": self.output, "column": self.column, "data": self.data, "rmse": self.rmse,
                "nrmse": self.nrmse}


@dataclass
class ParameterFit:
    """One estimate, in the parameter's declared unit."""

    name: str
    unit: str | None
    initial: float
    value: float
    stderr: float
    ci95: tuple[float, float]
    low: float | None
    high: float | None

    def to_json(self) -> dict:
        return {"name": self.name, "value": self.value, "unit": self.unit, "initial": self.initial,
                "stderr": self.stderr, "ci95": list(self.ci95)}


@dataclass
class FitResult:
    """What ``bondc fit`` found (see the module docstring); :meth:`to_json` is ``--json``."""

    model: str
    file: str
    converged: bool
    message: str
    parameters: list[ParameterFit]
    correlation: np.ndarray
    cost_initial: float
    cost: float
    signals: list[SignalFit]
    diagnostics: list[Diagnostic]
    evaluations: int
    runs: int
    residuals: int
    datasets: list[DataSet] = field(default_factory=list)
    written: list[str] = field(default_factory=list)

    @property
    def exit_status(self) -> int:
        return 0 if self.converged else 1

    @property
    def values(self) -> dict[str, float]:
        """Each estimate in its declared unit."""
        return {p.name: p.value for p in self.parameters}

    def to_json(self) -> dict:
        return {"converged": self.converged, "parameters": [p.to_json() for p in self.parameters],
                "correlation": [[float(v) for v in row] for row in self.correlation],
                "cost": {"initial": self.cost_initial, "final": self.cost},
                "signals": [s.to_json() for s in self.signals],
                "diagnostics": [d.to_json() for d in self.diagnostics]}

    def to_text(self) -> str:
        state = "converged" if self.converged else "NOT converged"
        lines = [f"{self.model}: fit {state} after {self.evaluations} evaluations ({self.runs} runs), "
                 f"{self.residuals} residuals; cost {self.cost_initial:.6g} -> {self.cost:.6g}", ""]
        header: tuple[str, ...] = ("parameter", "unit", "initial", "estimate", "std. error", "95% interval")
        rows: list[tuple[str, ...]] = [(p.name, p.unit or "1", f"{p.initial:.6g}", f"{p.value:.6g}", f"{p.stderr:.3g}",
                 f"[{p.ci95[0]:.6g}, {p.ci95[1]:.6g}]") for p in self.parameters]
        lines += _table(header, rows, numeric={2, 3, 4})
        if len(self.parameters) > 1:
            lines += ["", "correlation"]
            names = [p.name for p in self.parameters]
            lines += _table(("",) + tuple(names), [(name,) + tuple(f"{v:+.3f}" for v in row)
                                                   for name, row in zip(names, self.correlation)],
                            numeric=set(range(1, len(names) + 1)))
        lines += [""]
        header = ("signal", "measured", "data", "unit", "RMSE before", "RMSE after", "NRMSE after")
        rows = [(s.output, s.column, s.data, s.unit or "SI", f"{s.rmse_before:.4g}", f"{s.rmse:.4g}",
                 f"{s.nrmse:.4g}") for s in self.signals]
        lines += _table(header, rows, numeric={4, 5, 6})
        return "\n".join(lines)


def _table(header, rows, numeric=frozenset()) -> list[str]:
    widths = [max(len(str(cell)) for cell in column) for column in zip(header, *rows)]

    def line(cells):
        return "  ".join(str(c).rjust(w) if i in numeric else str(c).ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return [line(header), line(["-" * w for w in widths])] + [line(row) for row in rows]


# ------------------------------------------------------------------ setting up

def _derive(path, model, experiment, sets, cache):
    from bondc.pipeline import derive_file

    return derive_file(Path(path), model=model, experiment=experiment, sets=sets, cache=cache)


def _declared_unit(parameter):
    """(declared unit text, SI value / declared value) of a model.Parameter."""
    return parameter.unit_text, float(parameter.display_factor or 1.0)


def _resolve_estimates(estimates: Sequence[Estimate], derived, sets) -> list[_Parameter]:
    """E882 unknown, E888 twice, E885 a start outside its bounds; bounds to SI."""
    from bondc.analysis.sweep import _resolve_unit

    graph, state_space = derived.graph, derived.state_space
    seen: set[str] = set()
    found = []
    for estimate in estimates:
        if estimate.name not in graph.parameters:
            raise _usage(codes.E882, f"--estimate '{estimate.text}': '{estimate.name}' is not a parameter of {graph.name}",
                         hint=_did_you_mean(estimate.name, graph.parameters, "parameters"))
        if estimate.name in seen:
            raise _usage(codes.E888, f"'{estimate.name}' is estimated twice", hint="give it once, with its bounds")
        seen.add(estimate.name)
        parameter = graph.parameters[estimate.name]
        unit, factor = _declared_unit(parameter)
        if estimate.unit is not None:
            converter = _resolve_unit(estimate.unit, f"--estimate '{estimate.text}': ")
            declared = _resolve_unit(unit) if unit else None
            if declared is not None and converter.dims != declared.dims or declared is None and \
                    not converter.is_dimensionless:
                raise _usage(codes.E881, f"--estimate '{estimate.text}': [{estimate.unit}] does not measure the same "
                                     f"quantity as [{unit or '1'}], the unit of '{estimate.name}'",
                             hint=f"give the bounds in [{unit or '1'}] or a unit of the same kind")
            to_si = converter.to_si
        else:
            to_si = lambda value, factor=factor: value * factor
        low = -math.inf if estimate.low is None else to_si(estimate.low)
        high = math.inf if estimate.high is None else to_si(estimate.high)
        if estimate.name not in state_space.parameters:
            raise _not_late(estimate, graph, "the compiled model has no such value (it was folded into the equations)")
        initial = float(state_space.parameters[estimate.name][1])
        if not low <= initial <= high:
            shown = initial / factor
            raise _usage(codes.E885, f"--estimate '{estimate.text}': the start value {shown:.6g}"
                                 f"{' ' + unit if unit else ''} of '{estimate.name}' is outside its bounds",
                         hint=f"widen the bounds, or start inside them: --set \"{estimate.name}=VALUE\" gives the "
                              "start value")
        found.append(_Parameter(estimate.name, unit, factor, initial, low, high, parameter.span))
    return found


def _not_late(estimate: Estimate, graph, why: str, span=None) -> UsageError:
    from bondc.source import NO_SPAN

    parameter = graph.parameters.get(estimate.name)
    return UsageError(Diagnostic(
        "error", codes.E883, f"'{estimate.name}' cannot be estimated: {why}",
        span if span is not None else (parameter.span if parameter is not None else NO_SPAN),
        hint="a fit gives the compiled model new values of its parameters at each evaluation; estimate a "
             "parameter that only enters the model's equations, and fix this one with --set"))


def _settings(experiment) -> dict:
    if experiment is None:
        return {}
    found = {"t_end": experiment.t_end, "solver": experiment.solver, "rtol": experiment.rtol,
             "atol": experiment.atol, "max_step": experiment.max_step, "cycle": experiment.cycle}
    found.update(experiment.settings)
    return found


def _check_late(parameters: list[_Parameter], estimates, derived, path, model, experiment_name, sets) -> None:
    """E883 for a parameter whose value sets something fixed before a run: an experiment setting
    (t_end, max_step, cycle, ...) or the model's structure. The model is loaded with each estimated
    parameter moved (to its bounds, or by 10 % when open) and compared with the base, as ``bondc
    sweep`` decides whether its points can be bound late. A value the model rejects (a divisor that
    becomes 0 at a bound) is E892."""
    from bondc.parse import parse_set_value
    from bondc.pipeline import check_file, chosen_experiment, parse_sets, structure

    base_graph = derived.graph
    base_structure = structure(base_graph)
    base_settings = _settings(chosen_experiment(base_graph, experiment_name))
    by_name = {e.name: e for e in estimates}
    for parameter in parameters:
        trials = [v for v in (parameter.low, parameter.high) if math.isfinite(v)]
        trials += [parameter.initial * 1.1 if parameter.initial else 1.0] if len(trials) < 2 else []
        for value in trials:
            # in its declared unit, as --set reads a number without a unit
            moved = [s for s in parse_sets(sets) if s.name != parameter.name] + [parse_set_value(f"{parameter.name}={value / parameter.factor!r}",
                                                              f"--estimate {parameter.name}")]
            try:
                graph = check_file(path, model=model, experiment=experiment_name, sets=moved).graph
            except BondcError as error:
                first = error.diagnostics[0] if error.diagnostics else None
                detail = f"{first.code}: {first.message}" if first is not None else str(error)
                raise UsageError(Diagnostic(
                    "error", codes.E892, f"--estimate '{by_name[parameter.name].text}': the model does not accept "
                                     f"{parameter.name} = {value / parameter.factor:.6g}"
                                     f"{' ' + parameter.unit if parameter.unit else ''} ({detail})",
                    parameter.span, hint="give bounds inside the values the model accepts")) from None
            settings = _settings(chosen_experiment(graph, experiment_name))
            changed = [key for key in sorted(set(settings) | set(base_settings))
                       if settings.get(key) != base_settings.get(key)]
            if changed:
                raise _not_late(by_name[parameter.name], base_graph,
                                f"its value sets the experiment's {', '.join(changed)}, which is fixed before a "
                                "run starts (not a value the compiled model takes)")
            if structure(graph) != base_structure:
                raise _not_late(by_name[parameter.name], base_graph,
                                "its value changes the model's structure (its inputs or parameters), which the "
                                "equations are derived from")


def _load_group(dataset: DataSet, derived) -> _Group:
    """The measured data of a data set at the instants its run covers (E886 missing column, E887 not
    a signal, E889 no overlap)."""
    from bondc.analysis.validate import TIME_KEY, CompareSpec, check_quantity, load_measured_csv, signal_unit

    measured = load_measured_csv(dataset.data)
    columns = [c for c in measured if c != TIME_KEY]
    graph = derived.graph
    experiment = derived.experiment
    t_end = getattr(experiment, "t_end", None)
    if t_end is None:
        raise _usage(codes.E801, "no end time for the simulation", hint="set t_end in the experiment")
    times = np.asarray(measured[TIME_KEY], dtype=float)
    inside = (times >= 0.0) & (times <= t_end)
    if np.count_nonzero(inside) < 2:
        raise DataError(Diagnostic(
            "error", codes.E889, f"the measured data '{dataset.data}' (t = {times[0]:g} .. {times[-1]:g} s) and the "
                             f"run (t = 0 .. {t_end:g} s) share fewer than two samples",
            hint="check the experiment's t_end and the time column (seconds) of the data"))
    signals = []
    for spec in dataset.compare:
        if spec.column not in measured or spec.column == TIME_KEY:
            raise DataError(Diagnostic("error", codes.E886, f"--compare '{spec.text}': the measured data "
                                                        f"'{dataset.data}' has no column '{spec.column}'",
                                       hint=_did_you_mean(spec.column, columns, "its columns")))
        check_quantity(graph, CompareSpec(spec.output, spec.column, text=spec.text),
                        getattr(measured, "units", {}).get(spec.column))
        values = np.asarray(measured[spec.column], dtype=float)[inside]
        scale = float(np.max(values) - np.min(values))
        if not scale > 0:
            scale = float(np.max(np.abs(values))) or 1.0
        unit, factor = signal_unit(graph, spec.output)
        signals.append(_Signal(spec, values, scale, unit, factor))
    return _Group(dataset, derived, times[inside], signals)


# ------------------------------------------------------------------ evaluating

class _Evaluator:
    """Residuals of the weighted comparisons for a vector of parameter values (SI), each run the
    compiled model of its experiment with the values bound late."""

    def __init__(self, groups: list[_Group], names: list[str], progress=None):
        self.groups = groups
        self.names = names
        self.runs = 0
        self.failures = 0
        self.progress = progress

    def simulate(self, group: _Group, x: np.ndarray):
        from bondc.analysis.validate import simulated_signals
        from bondc.simulate import simulate

        experiment = group.derived.experiment
        rtol = min(FIT_RTOL, float(getattr(experiment, "rtol", None) or 1e-6))
        atol = min(FIT_ATOL, float(getattr(experiment, "atol", None) or 1e-9))
        self.runs += 1
        result = simulate(group.derived.state_space, experiment, overrides=dict(zip(self.names, map(float, x))),
                          t_eval=group.times, rtol=rtol, atol=atol)
        return result, simulated_signals(result)

    def model_values(self, group: _Group, x: np.ndarray) -> list[np.ndarray] | None:
        """Each compared signal of ``group`` at its times (SI), or None when the run fails."""
        result, signals = self.simulate(group, x)
        if not result.complete or result.t.size < 1:
            return None
        t = np.asarray(result.t, dtype=float)
        values = []
        for signal in group.signals:
            series = np.asarray(signals[signal.spec.output], dtype=float)
            if t.size != group.times.size or not np.array_equal(t, group.times):
                series = np.interp(group.times, t, series)
            values.append(series)
        if not all(np.all(np.isfinite(v)) for v in values):
            return None
        return values

    def residuals(self, x: np.ndarray) -> np.ndarray | None:
        parts = []
        for group in self.groups:
            values = self.model_values(group, x)
            if values is None:
                return None
            for signal, series in zip(group.signals, values):
                parts.append(signal.spec.weight * (series - signal.measured) / signal.scale)
        return np.concatenate(parts)


def finite_difference_jacobian(residuals: Callable[[np.ndarray], np.ndarray | None], x: np.ndarray,
                               steps: np.ndarray, low: np.ndarray, high: np.ndarray,
                               at_x: np.ndarray | None = None) -> np.ndarray | None:
    """The Jacobian of ``residuals`` at ``x`` by central differences with ``steps`` (one-sided at a
    bound, from ``at_x`` = residuals(x)); None when a run fails."""
    columns = []
    for i in range(x.size):
        h = steps[i]
        up, down = x.copy(), x.copy()
        up[i], down[i] = x[i] + h, x[i] - h
        if up[i] > high[i]:
            up[i] = x[i]
        if down[i] < low[i]:
            down[i] = x[i]
        r_up = at_x if up[i] == x[i] else residuals(up)
        r_down = at_x if down[i] == x[i] else residuals(down)
        if r_up is None or r_down is None:
            if r_up is None and at_x is not None and r_down is not None and down[i] != x[i]:
                r_up, up[i] = at_x, x[i]
            elif r_down is None and at_x is not None and r_up is not None and up[i] != x[i]:
                r_down, down[i] = at_x, x[i]
            else:
                return None
        columns.append((r_up - r_down) / (up[i] - down[i]))
    return np.column_stack(columns)


# ------------------------------------------------------------------ the fit

class _Progress:
    """A line per optimiser evaluation on stderr (rewritten in place on a terminal, at most one a
    second otherwise)."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.terminal = bool(getattr(self.stream, "isatty", lambda: False)())
        self.last = 0.0
        self.started = time.perf_counter()
        self.shown = False

    def __call__(self, evaluation: int, cost: float, runs: int) -> None:
        now = time.perf_counter()
        if now - self.started < 1.0 or (not self.terminal and now - self.last < 1.0):
            return
        self.last = now
        text = f"fit: evaluation {evaluation}, cost {cost:.6g}, {runs} runs, {now - self.started:.0f} s"
        if self.terminal:
            self.stream.write("\r" + text + "\033[K")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown and self.terminal:
            self.stream.write("\n")
            self.stream.flush()


@dataclass
class FitProblem:
    """A fit made ready (:func:`prepare_fit`): the compiled models, the measured data, the
    estimated parameters (SI), and the residuals at the start."""

    path: str
    datasets: list[DataSet]
    first: Derived                  # of the first data set's experiment
    parameters: list[_Parameter]
    groups: list[_Group]
    evaluator: _Evaluator
    diagnostics: list[Diagnostic]
    r0: np.ndarray

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def x0(self) -> np.ndarray:
        return np.array([p.initial for p in self.parameters], dtype=float)

    @property
    def scale(self) -> np.ndarray:
        """The magnitude of each parameter: the optimiser works on x / scale."""
        return np.array([abs(p.initial) if p.initial != 0 else
                         (p.high - p.low if math.isfinite(p.high - p.low) else 1.0) for p in self.parameters])

    def residuals(self, x) -> np.ndarray | None:
        """The weighted residuals at parameter values ``x`` (SI), None where a run fails."""
        return self.evaluator.residuals(np.asarray(x, dtype=float))

    def jacobian(self, x, at_x: np.ndarray | None = None) -> np.ndarray | None:
        """d residuals / d x (SI) at ``x`` by central differences (:data:`RELATIVE_STEP` times each
        parameter's magnitude, one-sided at a bound); None where a run fails."""
        x = np.asarray(x, dtype=float)
        scale = self.scale
        z = x / scale
        low = np.array([p.low for p in self.parameters]) / scale
        high = np.array([p.high for p in self.parameters]) / scale
        found = finite_difference_jacobian(lambda zz: self.evaluator.residuals(zz * scale), z,
                                           RELATIVE_STEP * np.maximum(np.abs(z), 1e-3), low, high, at_x=at_x)
        return None if found is None else found / scale


def prepare_fit(path, *, datasets: Sequence[DataSet], estimates: Sequence[str | Estimate], model: str | None = None,
                sets: Sequence = (), cache: bool | None = None, write=None) -> FitProblem:
    """Everything a fit checks and builds before it starts (E880-E892 for a bad request): the models
    derived and compiled once per experiment, the estimates resolved and checked to be late-bound,
    the measured data read, a first run of every data set at the start values."""
    wanted = [e if isinstance(e, Estimate) else parse_estimate(e) for e in estimates]
    if not wanted:
        raise _usage(codes.E889, "bondc fit needs at least one --estimate NAME[=LOW:HIGH]",
                     hint="name the parameters to estimate: --estimate b=5:30")
    datasets = [d if all(isinstance(c, FitCompare) for c in d.compare)
                else DataSet(d.data, tuple(c if isinstance(c, FitCompare) else parse_compare(c) for c in d.compare),
                             d.experiment) for d in datasets]
    if not datasets:
        raise _usage(codes.E889, "bondc fit needs measured data: --data FILE --compare OUT=COLUMN")
    # one derived (and compiled) model per experiment
    derived_of: dict = {}
    for dataset in datasets:
        if dataset.experiment not in derived_of:
            derived_of[dataset.experiment] = _derive(path, model, dataset.experiment, sets, cache)
    first = derived_of[datasets[0].experiment]
    for derived in derived_of.values():
        if derived.experiment is None:
            raise _usage(codes.E801, f"{derived.graph.name} has no experiment to run",
                         hint="add an experiment with t_end to the model")
    # the estimates and the data sets are checked independently: one run reports the problems of both
    problems: list[BondcError] = []
    try:
        parameters = _resolve_estimates(wanted, first, sets)
        for experiment_name, derived in derived_of.items():
            others = _resolve_estimates(wanted, derived, sets) if derived is not first else parameters
            _check_late(others, wanted, derived, path, model, experiment_name, sets)
        if write is not None:
            from bondc.analysis.fit_write import check_writable

            check_writable(path, first.graph, [p.name for p in parameters])
    except BondcError as error:
        problems.append(error)
    groups = []
    for dataset in datasets:
        try:
            groups.append(_load_group(dataset, derived_of[dataset.experiment]))
        except BondcError as error:
            problems.append(error)
    if problems:
        sources: dict = {}
        for failure in problems:
            sources.update(failure.sources)
        raise type(problems[0])([d for failure in problems for d in failure.diagnostics], sources)
    names = [p.name for p in parameters]
    diagnostics: list[Diagnostic] = []
    for derived in derived_of.values():
        diagnostics += [d for d in derived.notes if d not in diagnostics and d.severity == "warning"]
    evaluator = _Evaluator(groups, names)
    x0 = np.array([p.initial for p in parameters], dtype=float)
    # the start: every name checked against what the runs record, and a run that fails is an error
    for group in groups:
        result, signals = evaluator.simulate(group, x0)
        for signal in group.signals:
            if signal.spec.output not in signals:
                outputs = list(group.derived.graph.outputs)
                close = difflib.get_close_matches(signal.spec.output, list(signals), n=1)
                raise DataError(Diagnostic(
                    "error", codes.E887, f"--compare '{signal.spec.text}': '{signal.spec.output}' is not a signal of "
                                     f"{group.derived.graph.name}",
                    hint=(f"did you mean '{close[0]}'? " if close else "") + "outputs: " + ", ".join(outputs)
                         + " (states and bond variables such as b3.e too)"))
        if not result.complete:
            cause = result.diagnostics[0] if result.diagnostics else None
            raise DataError(Diagnostic(
                "error", codes.E891, f"the run of '{group.dataset.data}' fails at the start values: "
                                 + (f"{cause.code}: {cause.message}" if cause else result.message),
                cause.span if cause is not None else _no_span(),
                hint="start from values with which the model runs (bondc simulate), e.g. with --set"))
    r0 = evaluator.residuals(x0)
    if r0 is None:
        raise DataError(Diagnostic("error", codes.E891, "the model gives no finite values at the start values",
                                   hint="start from values with which the model runs (bondc simulate)"))
    if r0.size <= len(names):
        raise DataError(Diagnostic("error", codes.E889, f"{r0.size} measured samples cannot determine {len(names)} "
                                                    "parameters",
                                   hint="give more samples or estimate fewer parameters"))
    return FitProblem(str(path), list(datasets), first, parameters, groups, evaluator, diagnostics, r0)


def run_fit(path, *, datasets: Sequence[DataSet], estimates: Sequence[str | Estimate], model: str | None = None,
            sets: Sequence = (), max_evaluations: int | None = None, output=None, write=None,
            progress: bool | Callable = False, cache: bool | None = None,
            report: Callable | None = None) -> FitResult:
    """``bondc fit``: estimate ``estimates`` from ``datasets`` (see the module docstring).

    ``sets`` (``--set`` texts) fix other parameters and give the start value of an estimated one;
    ``output``: the HTML report to write, by ``report(result, output)`` (the caller's: the
    command line and the API give :func:`bondc.report.fit_report.write_fit_report`; analysis does not
    import the report layer); ``write``: a copy of the model with the fitted values
    (:func:`bondc.analysis.fit_write.write_fitted`). Raises UsageError/DataError for a bad request
    (E880-E892); a fit that does not converge is a result with ``converged`` False."""
    from scipy.optimize import least_squares

    from bondc.io import check_output

    if max_evaluations is not None and max_evaluations < 1:
        raise _usage(codes.E889, f"--max-evaluations must be at least 1, not {max_evaluations}")
    if output is not None:
        if report is None:
            raise TypeError("run_fit: an output needs report, the function that writes it")
        check_output(output, "the report", make_folder=True)
    if write is not None:
        from bondc.analysis.fit_write import check_write_target

        check_write_target(write, path, [d.data for d in datasets])
    problem = prepare_fit(path, datasets=datasets, estimates=estimates, model=model, sets=sets, cache=cache,
                          write=write)
    names, parameters, r0 = problem.names, problem.parameters, problem.r0
    m, n = r0.size, len(names)
    x0, scale = problem.x0, problem.scale
    low = np.array([p.low for p in parameters]) / scale
    high = np.array([p.high for p in parameters]) / scale
    bar = _Progress() if progress is True else (progress or None)
    penalty = max(float(np.sqrt(np.mean(r0 ** 2))), 1.0) * 10.0
    failed = [0]
    evaluations = [0]
    cache_r: dict = {}

    def fun(z):
        key = z.tobytes()
        if key in cache_r:
            return cache_r[key]
        r = problem.residuals(z * scale)
        evaluations[0] += 1
        if r is None:
            failed[0] += 1
            r = np.full(m, penalty)
        cache_r.clear()
        cache_r[key] = r
        if bar is not None:
            bar(evaluations[0], 0.5 * float(r @ r), problem.evaluator.runs)
        return r

    def jac(z):
        found = problem.jacobian(z * scale, at_x=fun(z))
        if found is None:
            failed[0] += 1
            return np.zeros((m, n))
        return found * scale

    try:
        solution = least_squares(fun, x0 / scale, jac=jac, bounds=(low, high), method="trf", x_scale="jac",
                                 max_nfev=max_evaluations or DEFAULT_MAX_EVALUATIONS)
    finally:
        if bar is not None and hasattr(bar, "close"):
            bar.close()
    x = solution.x * scale
    r = fun(solution.x)
    result = _summarise(problem, x, r, jac(solution.x), solution, evaluations[0], failed[0])
    if output is not None and report is not None:       # (an output without report: TypeError above)
        report(result, output)
        result.written.append(str(output))
    if write is not None:
        from bondc.analysis.fit_write import write_fitted

        write_fitted(write, path, problem.first.graph, result, [d.experiment for d in problem.datasets], sets)
        result.written.append(str(write))
    return result


def _summarise(problem: FitProblem, x, r, Jz, solution, evaluations: int, failed: int) -> FitResult:
    """The result at the solution ``x`` (SI): intervals and correlations from ``Jz`` (the Jacobian
    with respect to x / scale), warnings, each signal before and after."""
    from scipy import stats

    names, parameters, r0 = problem.names, problem.parameters, problem.r0
    diagnostics = list(problem.diagnostics)
    m, n = r0.size, len(names)
    scale, x0 = problem.scale, problem.x0
    cost = 0.5 * float(r @ r)
    cost0 = 0.5 * float(r0 @ r0)
    converged = bool(solution.status > 0)
    dof = m - n
    s2 = 2.0 * cost / dof
    U, S, Vt = np.linalg.svd(Jz, full_matrices=False)
    tiny = S <= RANK_TOLERANCE * (S[0] if S.size and S[0] > 0 else 1.0)
    inverse = np.where(tiny, 0.0, 1.0 / np.where(S > 0, S, 1.0) ** 2)
    cov_z = (Vt.T * inverse) @ Vt * s2
    cov = cov_z * np.outer(scale, scale)
    stderr = np.sqrt(np.maximum(np.diag(cov), 0.0))
    undetermined = set()
    for k in np.nonzero(tiny)[0].tolist():
        direction = Vt[k]
        involved = [i for i in range(n) if abs(direction[i]) > 0.1]
        undetermined.update(involved)
        diagnostics.append(Diagnostic(
            "warning", codes.W881, "the Jacobian is singular: " + _names([names[i] for i in involved])
                               + " cannot be determined from this data (changing "
                               + ("them together" if len(involved) > 1 else "it") + " along "
                               + ", ".join(f"{direction[i]:+.2f} {names[i]}" for i in involved)
                               + ", relative to their values, changes no residual)",
            hint="fix all but one of them with --set, or add data that tells them apart"))
    for i in undetermined:
        stderr[i] = math.inf
    # the correlations: singular values floored at the rank tolerance, so that a direction the
    # data does not determine dominates (a product a*b: a and b correlate at -1, as they trade off)
    floored = np.maximum(S, RANK_TOLERANCE * (S[0] if S.size and S[0] > 0 else 1.0))
    spread = (Vt.T / floored ** 2) @ Vt
    with np.errstate(invalid="ignore", divide="ignore"):
        sd = np.sqrt(np.maximum(np.diag(spread), 0.0))
        correlation = spread / np.outer(sd, sd)
    correlation = np.where(np.isfinite(correlation), correlation, 0.0)
    for i in range(n):
        correlation[i, i] = 1.0
    for i in range(n):
        for j in range(i + 1, n):
            if abs(correlation[i, j]) > CORRELATION_LIMIT:
                diagnostics.append(Diagnostic(
                    "warning", codes.W880, f"'{names[i]}' and '{names[j]}' cannot be told apart: their estimates "
                                       f"correlate at {correlation[i, j]:+.4f}",
                    hint="the data determines only a combination of them: fix one with --set, or add data "
                         "(another signal, another experiment) that separates them"))
    quantile = float(stats.t.ppf(0.975, dof))
    fitted = []
    for i, p in enumerate(parameters):
        value = x[i] / p.factor
        err = stderr[i] / p.factor
        at_bound = (math.isfinite(p.low) and abs(x[i] - p.low) <= 1e-9 * max(abs(p.low), scale[i])) or \
                   (math.isfinite(p.high) and abs(x[i] - p.high) <= 1e-9 * max(abs(p.high), scale[i]))
        if at_bound or solution.active_mask[i] != 0:
            diagnostics.append(Diagnostic(
                "warning", codes.W882, f"the estimate of '{p.name}' is on its bound ({value:.6g}"
                                   f"{' ' + p.unit if p.unit else ''}): its interval is not meaningful",
                hint="widen the bounds, or check the model and the data"))
        fitted.append(ParameterFit(p.name, p.unit, p.initial / p.factor, float(value), float(err),
                                   (float(value - quantile * err), float(value + quantile * err)),
                                   None if not math.isfinite(p.low) else p.low / p.factor,
                                   None if not math.isfinite(p.high) else p.high / p.factor))
    if failed:
        diagnostics.append(Diagnostic(
            "warning", codes.W884, f"the model failed to run at {failed} trial point"
                               f"{'s' if failed != 1 else ''} of the fit; the optimiser stepped back",
            hint="bounds that keep the parameters where the model runs make the fit faster"))
    if not converged:
        diagnostics.append(Diagnostic(
            "warning", codes.W883, f"the fit did not converge after {evaluations} evaluations: {solution.message}",
            hint="the values reached are reported; raise --max-evaluations, or start nearer (--set)"))

    signals = []
    for group in problem.groups:
        before = problem.evaluator.model_values(group, x0)
        after = problem.evaluator.model_values(group, x)
        for k, signal in enumerate(group.signals):
            b = before[k] if before is not None else np.full(group.times.size, math.nan)
            a = after[k] if after is not None else np.full(group.times.size, math.nan)
            shown = lambda v: v / signal.factor
            rmse_b = float(np.sqrt(np.mean((b - signal.measured) ** 2))) / signal.factor
            rmse_a = float(np.sqrt(np.mean((a - signal.measured) ** 2))) / signal.factor
            span = float(np.max(signal.measured) - np.min(signal.measured)) / signal.factor
            nrmse = lambda value: value / span if span > 0 else (0.0 if value == 0 else math.inf)
            signals.append(SignalFit(str(group.dataset.data), signal.spec.output, signal.spec.column, signal.unit,
                                     group.times, shown(signal.measured), shown(b), shown(a), rmse_b, rmse_a,
                                     nrmse(rmse_b), nrmse(rmse_a)))
    return FitResult(problem.first.graph.name, problem.path, converged, str(solution.message), fitted, correlation,
                     cost0, cost, signals, diagnostics, evaluations, problem.evaluator.runs, m, list(problem.datasets))


def _names(names: list[str]) -> str:
    quoted = [f"'{n}'" for n in names]
    return quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " and " + quoted[-1]


def _no_span():
    from bondc.source import NO_SPAN

    return NO_SPAN
