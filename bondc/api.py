"""The Python API of bondc, for scripts and notebooks (``docs/api.md``).

Every function takes a model file (``path``), or its text with ``text=`` (the
path then only names it and anchors its imports and data files). Parameter
``overrides`` is a dict ``{name: value}``: a number in the parameter's
declared unit (as ``--set``), a string with a unit (``"5 [mm]"``), or a pair
``(5, "mm")``. Model errors raise :class:`bondc.errors.BondcError` (its
``diagnostics`` say what and where), except in :func:`check`, which returns
them.
"""

from __future__ import annotations

import html
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence, Union

import numpy as np

from bondc.errors import BondcError, Diagnostic, UsageError
from bondc import codes

if TYPE_CHECKING:
    import pandas
    from matplotlib.figure import Figure

    from bondc.analysis.bode import Bode
    from bondc.analysis.fit import DataSet, FitResult
    from bondc.analysis.linearize import Linearization
    from bondc.model import BondGraph
    from bondc.pipeline import Derived
    from bondc.simulate import SimResult

#: A model file: a path as a string or a :class:`pathlib.Path`.
PathLike = Union[str, os.PathLike[str]]

__all__ = ["load", "check", "equations", "linearize", "bode", "compile", "simulate", "fit", "Model", "CheckResult",
           "Simulation", "PathLike"]


def _usage(message: str, hint: str | None = None) -> UsageError:
    """A misused argument of the API: a bondc error naming it (E001), not Python's own."""
    return UsageError(Diagnostic("error", codes.E001, message, hint=hint))


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))


def _number(value, what: str) -> float:
    """``value`` as a finite float; a bool, a non-number or nan/inf is an error naming ``what``."""
    if not _is_number(value):
        raise _usage(f"{what} must be a number, not {type(value).__name__} ({value!r})")
    if not math.isfinite(float(value)):
        raise _usage(f"{what} must be a finite number, not {float(value)!r}")
    return float(value)


def _sets(overrides: Mapping[str, Any] | None) -> list[str]:
    if overrides is None:
        return []
    if not isinstance(overrides, Mapping):
        raise _usage(f"overrides must be a dict {{name: value}}, not {type(overrides).__name__}",
                     hint='e.g. overrides={"k": 1600, "m": "2 [kg]", "lead": (5, "mm")}')
    texts = []
    for name, value in overrides.items():
        if not isinstance(name, str):
            raise _usage(f"an override's name must be a string, not {type(name).__name__} ({name!r})")
        what = f"overrides[{name!r}]"
        if isinstance(value, tuple):
            if len(value) != 2 or not isinstance(value[1], str):
                raise _usage(f"{what} must be a (number, unit) pair, not {value!r}", hint='e.g. (5, "mm")')
            texts.append(f"{name}={_number(value[0], what)!r} [{value[1]}]")
        elif isinstance(value, str):
            texts.append(f"{name}={value}")
        elif _is_number(value):
            texts.append(f"{name}={_number(value, what)!r}")
        else:
            raise _usage(f"{what} must be a number, a string with a unit or a (number, unit) pair, not "
                         f"{type(value).__name__} ({value!r})", hint='e.g. 1600, "1.6 [kN/m]" or (1.6, "kN/m")')
    return texts


def _text(text):
    if text is not None and not isinstance(text, str):
        raise _usage(f"text must be a str (the model's text), not {type(text).__name__}",
                     hint="decode bytes first: text=data.decode('utf-8')")
    return text


def _source(path: PathLike | None, text: str | None) -> tuple[Path, str | None]:
    """The path to load and, for an in-memory text, the text."""
    return Path(path) if path is not None else Path("<text>.bg"), text


@dataclass(frozen=True)
class Model:
    """A checked model: its graph and the warnings of checking it."""

    graph: BondGraph
    warnings: tuple[Diagnostic, ...]

    @property
    def name(self) -> str:
        return self.graph.name

    @property
    def parameters(self) -> dict[str, float]:
        """Every parameter's value, SI."""
        return {name: p.value for name, p in self.graph.parameters.items()}

    @property
    def states(self) -> list[str]:
        return [s.qualified for s in self.graph.states]

    @property
    def outputs(self) -> dict[str, str | None]:
        """Each output's declared unit."""
        return {name: o.unit_text for name, o in self.graph.outputs.items()}

    @property
    def experiments(self) -> list[str]:
        return list(self.graph.experiments)

    def _repr_html_(self) -> str:
        rows = "".join(f"<tr><td>{html.escape(n)}</td><td>{v:.6g}</td></tr>" for n, v in self.parameters.items())
        return (f"<p><b>{html.escape(self.name)}</b>: {len(self.graph.elements)} elements, "
                f"{len(self.graph.bonds)} bonds, {len(self.states)} states</p>"
                f"<table><tr><th>parameter</th><th>SI value</th></tr>{rows}</table>")


def load(path: PathLike | None = None, *, text: str | None = None, model: str | None = None, experiment: str | None = None,
         overrides: Mapping[str, Any] | None = None) -> Model:
    """Read and check a model; raises :class:`BondcError` with every problem.

    >>> m = load("models/mass_spring_damper.bg")
    >>> m.name, m.states, m.parameters["k"]
    ('MassSpringDamper', ['mass.p', 'spring.q'], 800.0)
    """
    from bondc.pipeline import check_file

    path, text = _source(path, text)
    checked = check_file(path, model=model, experiment=experiment, sets=_sets(overrides), text=text,
                         first_experiment=False)
    return Model(checked.graph, checked.warnings)


@dataclass(frozen=True)
class CheckResult:
    """What ``bondc check`` says: ``ok`` and every diagnostic (errors and warnings)."""

    ok: bool
    diagnostics: tuple[Diagnostic, ...]
    model: Model | None = None

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.diagnostics if d.is_error]

    def __str__(self) -> str:
        from bondc.errors import render_all

        return render_all(self.diagnostics) if self.diagnostics else "ok"

    def _repr_html_(self) -> str:
        if not self.diagnostics:
            return "<p>ok: no problems</p>"
        rows = "".join(f"<tr><td>{html.escape(d.severity)}</td><td>{html.escape(d.code)}</td>"
                       f"<td>{d.span.line}:{d.span.column}</td><td>{html.escape(d.message)}</td></tr>"
                       for d in self.diagnostics)
        return f"<table><tr><th></th><th>code</th><th>where</th><th>message</th></tr>{rows}</table>"


def check(path: PathLike | None = None, *, text: str | None = None, model: str | None = None) -> CheckResult:
    """Check a model (names, units, dimensions, causality, equations); never raises for the model.

    >>> result = check(text="model M\\n  C c : e = q\\n  Se s : e = 1\\n  s -> c\\n  output y [m/s] = s.e\\nend\\n")
    >>> result.ok
    True
    >>> check(text="model M\\n  R r : e = f\\n  r -> nowhere\\nend\\n").errors[0].code
    'E404'
    """
    from bondc.pipeline import diagnose

    path, text = _source(path, text)
    diagnosis = diagnose(path, model=model, text=text, cache=False)
    if diagnosis.failure is not None or diagnosis.checked is None:     # the failed stage's diagnostics alone
        return CheckResult(False, diagnosis.failure or ())
    return CheckResult(diagnosis.ok, diagnosis.diagnostics, Model(diagnosis.checked.graph, diagnosis.checked.warnings))


def _derived(path: PathLike | None, text: str | None, model: str | None, experiment: str | None,
             overrides: Mapping[str, Any] | None) -> Derived:
    from bondc.pipeline import derive_file

    path, text = _given(path, text)
    return derive_file(path, model=model, experiment=experiment, sets=_sets(overrides), text=text)


def _given(path: PathLike | None, text: str | None) -> tuple[Path, str | None]:
    """:func:`_source` of a model that must be given, as a file or as its text."""
    text = _text(text)
    if path is None and text is None:
        raise _usage("give the model: a file (path) or its text (text=...)")
    return _source(path, text)


def equations(path: PathLike | None = None, *, text: str | None = None, model: str | None = None, experiment: str | None = None,
              overrides: Mapping[str, Any] | None = None, format: str = "text") -> str:
    """The state and output equations as ``bondc equations`` prints them (text, latex or json).

    >>> text = equations("models/mass_spring_damper.bg")
    >>> [line.strip() for line in text.split("state equations")[1].split("outputs")[0].strip().splitlines()]
    ['der(mass.p) = F - b*mass.p/m - k*spring.q', 'der(spring.q) = mass.p/m']
    """
    from bondc.equations import FORMATS, format_equations

    if format not in FORMATS:
        raise _usage(f"format must be one of {', '.join(FORMATS)}, not {format!r}")
    return format_equations(_derived(path, text, model, experiment, overrides).state_space, format)


def linearize(path: PathLike | None = None, *, text: str | None = None, model: str | None = None, experiment: str | None = None,
              overrides: Mapping[str, Any] | None = None, at: str = "initial", time: float = 0.0) -> Linearization:
    """A, B, C, D and the eigenvalues (:class:`bondc.analysis.linearize.Linearization`).

    >>> lin = linearize("models/mass_spring_damper.bg")
    >>> [round(float(abs(e)), 6) for e in lin.eigenvalues]    # sqrt(k/m) = 20 rad/s
    [20.0, 20.0]
    """
    from bondc.analysis.linearize import AT, linearize as linearise

    if at not in AT:
        raise _usage(f"at must be one of {', '.join(AT)}, not {at!r}")
    time = _number(time, "time")
    return linearise(_derived(path, text, model, experiment, overrides).state_space, time=time, at=at)


def bode(path: PathLike | None = None, *, text: str | None = None, model: str | None = None,
         experiment: str | None = None, overrides: Mapping[str, Any] | None = None,
         inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None, at: str = "initial",
         time: float = 0.0, low: float | str | None = None, high: float | str | None = None, points: int = 400,
         verify: bool = False, amplitude: float | str | None = None) -> Bode:
    """The frequency response of ``outputs`` to ``inputs`` (``bondc bode``): a
    :class:`bondc.analysis.bode.Bode` with one ``Response`` per pair (frequencies in Hz, magnitude
    in dB, phase in degrees, margins) and, with ``verify``, the nonlinear model against it.
    ``low``/``high``: the range in Hz, or texts with a unit (``"10 [rad/s]"``).

    >>> result = bode("models/mass_spring_damper.bg", outputs=["x"], points=3, low=0.1, high=10)
    >>> [round(float(v), 2) for v in result.responses[0].magnitude_db]      # 1/(m s^2 + b s + k)
    [-58.05, -57.21, -77.07]
    """
    from bondc.analysis.bode import bode as frequency_response
    from bondc.analysis.linearize import AT

    if at not in AT:
        raise _usage(f"at must be one of {', '.join(AT)}, not {at!r}")
    for name, names in (("inputs", inputs), ("outputs", outputs)):
        if names is not None and (isinstance(names, str) or not all(isinstance(n, str) for n in names)):
            raise _usage(f"{name} must be a list of names, not {names!r}", hint=f'e.g. {name}=["x"]')
    time = _number(time, "time")
    return frequency_response(_derived(path, text, model, experiment, overrides).state_space, inputs=inputs,
                              outputs=outputs, at=at, time=time, low=low, high=high, points=points,
                              verify_model=verify, amplitude=amplitude)


def compile(path: PathLike, output: PathLike | None = None, *, model: str | None = None, experiment: str | None = None,
            overrides: Mapping[str, Any] | None = None, standalone: bool = False) -> Path:
    """Write the model's Python module (``bondc compile``); returns its path. ``standalone``: the
    module carries bondc's runtime (it runs where bondc is not installed)."""
    from bondc.pipeline import compile_file, default_output

    output = Path(output) if output is not None else default_output(path)
    compile_file(Path(path), output, model=model, experiment=experiment, sets=_sets(overrides),
                 standalone=standalone)
    return output


@dataclass
class Simulation:
    """A simulation: arrays by name (SI), the units result files use, and helpers for notebooks.

    ``sim["x"]`` is an output, state or bond variable (SI); ``sim.t`` the times.
    """

    result: SimResult
    warnings: tuple[Diagnostic, ...] = field(default_factory=tuple)

    @property
    def t(self) -> np.ndarray:
        return self.result.t

    @property
    def complete(self) -> bool:
        return self.result.complete

    @property
    def outputs(self) -> dict[str, np.ndarray]:
        return self.result.outputs

    @property
    def states(self) -> dict[str, np.ndarray]:
        return self.result.states

    @property
    def dependent_states(self) -> dict[str, np.ndarray]:
        """States of storage elements in derivative causality (``load.p`` behind a rigid gear), SI:
        computed from the independent :attr:`states` at every point."""
        return self.result.dependent

    @property
    def units(self) -> dict[str, tuple[str, float]]:
        """``{name: (unit, scale)}``: a column's value in its unit is the SI value / scale."""
        return self.result.units

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "t":
            return self.result.t
        groups = (self.result.outputs, self.result.states, self.result.dependent, self.result.bonds,
                  self.result.variables)
        for group in groups:
            if name in group:
                return group[name]
        import difflib

        shown = [*self.result.outputs, *self.result.states, *self.result.dependent]
        close = difflib.get_close_matches(str(name), [n for group in groups for n in group], n=1)
        raise KeyError(f"{name!r} is not a signal of this run" + (f"; did you mean {close[0]!r}?" if close else "")
                       + f" (outputs and states: {', '.join(shown)}; bond variables too, as b3.e or element.f)")

    def in_unit(self, name: str) -> np.ndarray:
        """A column in the unit result files show it in (an output in its declared unit)."""
        _, scale = self.result.units.get(name, (None, 1.0))
        return np.asarray(self[name]) / scale

    def to_dataframe(self, all_bonds: bool = False) -> pandas.DataFrame:
        """A pandas DataFrame indexed by time, one column per output and state (dependent states, those in
        derivative causality, after the others), named with their units
        (``P_kPa [kPa]``) and in those units, as the csv; needs pandas."""
        try:
            import pandas
        except ImportError:
            raise ImportError("to_dataframe needs pandas: pip install pandas") from None
        from bondc.runtime import column_name, shown_columns
        from bondc.simulate import _columns

        names, columns = _columns(self.result, all_bonds)
        units = self.result.units
        data = {column_name(n, units): c for n, c in zip(names[1:], shown_columns(columns[1:], names[1:], units))}
        return pandas.DataFrame(data, index=pandas.Index(self.result.t, name="t [s]"))

    def plot(self, names: Sequence[str] | None = None) -> Figure:
        """A matplotlib Figure of the outputs ``names`` (default: every output) against time, each in
        its declared unit, one axis per unit. It is not pyplot's (``figure.savefig(...)`` to write
        it); a notebook shows it as a picture, without ``%matplotlib``."""
        from bondc.figure import SimulationFigure

        names = list(names) if names is not None else list(self.result.outputs)
        by_unit: dict[str, list[str]] = {}
        for name in names:
            by_unit.setdefault(self.result.units.get(name, ("", 1.0))[0] or "", []).append(name)
        figure = SimulationFigure(figsize=(7, 2.4 * max(len(by_unit), 1)), layout="constrained")
        axes_list = figure.subplots(max(len(by_unit), 1), 1, sharex=True, squeeze=False)[:, 0]
        for axes, (unit, group) in zip(axes_list, by_unit.items()):
            for name in group:
                axes.plot(self.t, self.in_unit(name), label=name)
            axes.set_ylabel(f"[{unit}]" if unit else "")
            axes.legend(loc="best")
            axes.grid(True, alpha=0.3)
        axes_list[-1].set_xlabel("t [s]")
        return figure

    def summary(self) -> list[dict[str, Any]]:
        """Per output: unit, min, max, final (in its unit)."""
        rows = []
        for name in self.result.outputs:
            values = self.in_unit(name)
            finite = values[np.isfinite(values)]
            rows.append({"output": name, "unit": self.result.units.get(name, ("", 1.0))[0],
                         "min": float(finite.min()) if finite.size else math.nan,
                         "max": float(finite.max()) if finite.size else math.nan,
                         "final": float(values[-1]) if values.size else math.nan})
        return rows

    def _repr_html_(self) -> str:
        state = "complete" if self.complete else f"INCOMPLETE: {html.escape(self.result.message)}"
        rows = "".join(f"<tr><td>{html.escape(r['output'])}</td><td>{html.escape(r['unit'] or '')}</td>"
                       f"<td>{r['min']:.5g}</td><td>{r['max']:.5g}</td><td>{r['final']:.5g}</td></tr>"
                       for r in self.summary())
        return (f"<p><b>{html.escape(self.result.model)}</b>: {self.t.size} points to t = {self.result.t_reached:g} s, "
                f"{state}, {len(self.result.events)} events</p><table><tr><th>output</th><th>unit</th><th>min</th>"
                f"<th>max</th><th>final</th></tr>{rows}</table>")


def simulate(path: PathLike | None = None, *, text: str | None = None, model: str | None = None, experiment: str | None = None,
             overrides: Mapping[str, Any] | None = None, t_end: float | None = None,
             dt: float | None = None, inputs: Mapping[str, Any] | None = None) -> Simulation:
    """Simulate (``bondc simulate``); a run that stops early raises SimulationError with the partial
    result as ``.result``.

    ``inputs`` supplies the model's external inputs (``input u [V] external``): ``{name: (times,
    values)}`` (linearly interpolated, held at the ends, SI) or ``{name: f}`` with ``f(t)`` a number;
    one not given takes its default (the warnings say so, I346).

    >>> sim = simulate("models/mass_spring_damper.bg", overrides={"k": (1.6, "kN/m")}, dt=0.5)
    >>> sim.complete, abs(float(sim["x"][-1]) - 10/1600) < 1e-4    # x settles at F0/k
    (True, True)
    >>> sim.units["x"]
    ('m', 1.0)
    """
    from bondc.pipeline import simulate_file

    t_end = None if t_end is None else _number(t_end, "t_end")
    dt = None if dt is None else _number(dt, "dt")
    path, text = _given(path, text)
    result = simulate_file(path, text=text, model=model, experiment=experiment, sets=_sets(overrides), t_end=t_end,
                           dt=dt, inputs=inputs)
    return Simulation(result, tuple(result.warnings))


def fit(path: PathLike, *, data: PathLike | Sequence[DataSet], estimate: Sequence[str],
        compare: Sequence[str] | None = None, model: str | None = None, experiment: str | None = None,
        overrides: Mapping[str, Any] | None = None, max_evaluations: int | None = None,
        output: PathLike | None = None, write: PathLike | None = None) -> FitResult:
    """Estimate parameters from measured data (``bondc fit``); returns a
    :class:`bondc.analysis.fit.FitResult` (``converged``, ``parameters`` with ``value``,
    ``stderr``, ``ci95`` in each parameter's declared unit, ``correlation``, ``signals``,
    ``diagnostics``; ``to_json()`` is ``--json``).

    ``data``: one measured CSV with its ``compare`` list (``"OUT=COLUMN[:weight=W]"``) and
    ``experiment``, or several :class:`bondc.analysis.fit.DataSet` (each its own CSV, comparisons and
    experiment; one parameter set fits them all). ``estimate``: ``"NAME"`` or ``"NAME=LOW:HIGH"``
    (bounds in the declared unit, or a unit in brackets). ``overrides`` fix other parameters and
    give an estimated one its start value. ``output``: the HTML report; ``write``: a copy of the
    model with the fitted values. A fit that does not converge is returned with ``converged``
    False; a bad request raises (E880-E892).
    """
    from bondc.analysis.fit import DataSet, run_fit
    from bondc.report.fit_report import write_fit_report

    if isinstance(data, (str, os.PathLike)):
        if not compare:
            raise _usage("compare must list at least one 'OUT=COLUMN' when data is one file",
                         hint='e.g. compare=["x=x_meas"]')
        if isinstance(compare, str):
            compare = [compare]
        datasets = [DataSet(str(data), tuple(compare), experiment)]
    else:
        if compare is not None:
            raise _usage("give compare inside each DataSet when data is a list of them")
        datasets = [d if d.experiment is not None or experiment is None else DataSet(d.data, d.compare, experiment)
                    for d in data]
    if isinstance(estimate, str):
        estimate = [estimate]
    return run_fit(Path(path), datasets=datasets, estimates=list(estimate), model=model, sets=_sets(overrides),
                   max_evaluations=max_evaluations, output=output, write=write, report=write_fit_report)
