"""Parameter sweeps: a ``.bg`` file + ``--vary`` specs -> :class:`SweepResult` (one row per grid point).

:func:`run_sweep` is ``bondc sweep`` without argument parsing. Each ``vary``
text names a parameter and its values::

    "k=400,800,1600"          a list, in the parameter's declared unit (as --set)
    "lead=5,10 [mm]"          a list in the given unit (converted by bondc.units)
    "M=20:40:5 [kg]"          start:stop:count, count values from start to stop inclusive
    "k=100, 200:400:3"        items mix: 100, 200, 300, 400

Several specs make a full grid (the cartesian product, the first spec
varying slowest, rows ordered by grid index), at most :data:`MAX_RUNS` runs.

**How a point is run.** The model is loaded, checked, derived and compiled
once, with the base ``sets``. A point is then a vector of values (late
binding, ``path`` "bound"): the varied parameters in SI go to the compiled
module, which recomputes every parameter defined by others (the flagship's
``F_n0 = M*g - ...``, ``delta0``, ``theta0``); the file is not read again, so
editing it during a study changes nothing. When a varied parameter also sets
something the check fixes outside the compiled module (an experiment setting
such as ``max_step = h``, seen by loading the first and the last point), every
point loads the file again with its values as ``--set`` overrides ("fast"), so
units and validation follow exactly the ``--set`` rules; ``rederive=True``
also derives and compiles again for every point ("rederived"), for a model
whose derivation depends on parameter values (a nonlinear law inverted with
``sympy.solve`` keeps the branch that reproduces the law at the parameters'
values).

**What each point gives** (SI in :meth:`SweepResult.to_json` and the csv;
the text table shows the outputs' declared units):

* for every output: ``NAME.min``, ``NAME.max``, ``NAME.rms``, ``NAME.final``
  (and ``NAME.mean`` on request), from :func:`~bondc.analysis.stats.output_statistics`;
* for every output declared in a unit of power, over the experiment's first
  cycle: ``NAME.cycle_peak``, ``NAME.cycle_rms`` [W], ``NAME.cycle_energy``
  (net), ``NAME.cycle_energy_positive``, ``NAME.cycle_energy_negative`` [J]
  (:func:`~bondc.analysis.stats.power_statistics`);
* ``energy.residual``: the energy balance residual summed over the cycles
  [J], and ``energy.relative_residual``: its largest share of a cycle's
  throughput (:func:`~bondc.analysis.energy.energy_account`);
* when the model has an output ``torque`` and an output or input ``omega``
  or ``speed`` (:mod:`bondc.analysis.motor_report`), the motor
  requirements over the experiment's cycle: ``motor.peak_torque``,
  ``motor.rms_torque`` [N*m], ``motor.peak_speed`` [rad/s],
  ``motor.peak_power`` [W], ``motor.energy`` (net energy per cycle) [J].

``metrics`` selects columns (``torque.max``, ``x.final``,
``energy.residual``, ``x.*``, ``motor.*``); None takes them all (without
the means). Only what is selected is computed.

**Failures.** A point that cannot be loaded or whose run stops early (a law
that gives nan, a solver failure) gets ``status`` "failed", its message and
diagnostics, and the sweep goes on; :attr:`SweepResult.exit_code` is then 1.
A metric that cannot be computed for a point that ran (energy account, motor
profile) is nan with a warning, and the point is "incomplete".

**Running the points.** Points run in ``jobs`` worker processes (forked with
the base model compiled), each with a time limit (``point_timeout``, default
20 times the median point time, at least 60 s): a point over its limit is
killed with its worker and recorded as "timed out". ``point_timeout=0`` runs
them one after the other in this process. ``executor="dask"`` runs them on a
``dask.distributed`` cluster instead. Every point is computed the same way in
whichever process, so the result does not depend on ``jobs`` or the executor.
Rows are appended to the csv as points finish (flushed), Ctrl-C and SIGTERM
keep them, and running the same sweep again resumes: the points already in the
file (matched by their parameter values) are not run again. What they were
computed from (the text of the model file and its imports, the model,
experiment, --set values, t_end, dt and motor catalogue) is recorded beside a
csv table in ``<table>.csv.study`` and inside a json one; a resume with any of
these changed is E970, not a table mixing two studies. A sweep never rewrites
its file without the finished points it holds: a grid (or Latin hypercube)
that leaves out some of them is E970 too, and the file is left as it is; a
grid that holds them all extends the study. A row cut short by a killed run
is not a point, and runs again.

**Statuses.** "ok"; "failed" (it did not load, or its run stopped early);
"timed out"; "incomplete" (it ran, but a metric or the motor selection could
not be computed: never "ok" with nan).

Problems with the request are :class:`~bondc.errors.UsageError` with codes
E960 (a vary text that is not ``NAME=VALUES [unit]``, or an empty list),
E961 (not a parameter), E962 (a value that is not a finite number, a bad
``start:stop:count``), E963 (a unit bondc does not know, or of another
quantity than the parameter's), E964 (more than :data:`MAX_RUNS` runs),
E965 (an unknown metric), E966 (a parameter varied twice, or varied and
``--set``), E967 (jobs < 1, a negative time limit), E969 (an output file
that is not .csv or .json), E970 (an output file holding another sweep's
table, points this sweep would drop, or a file bondc did not write), E971 (Dask not installed, an unknown executor, an unreachable
scheduler). E968 is a failed point's diagnostic when it has none of its own
(the model file changed during the sweep, a worker process died, an
internal error).

>>> axis = parse_vary("M=20:40:5 [kg]")
>>> axis.name, axis.values, axis.unit
('M', (20.0, 25.0, 30.0, 35.0, 40.0), 'kg')
>>> parse_vary("k=100, 200:400:3").values
(100.0, 200.0, 300.0, 400.0)
>>> parse_vary("k=abc")
Traceback (most recent call last):
...
bondc.errors.UsageError: --vary 'k=abc': 'abc' is not a number
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import io
import itertools
import json
import logging
import math
import os
import re
import statistics
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from bondc.errors import BondcError, Diagnostic, UsageError
from bondc.io import json_safe
from bondc.pipeline import chosen_experiment

#: The most runs one sweep may ask for (checked before the grid is made).
MAX_RUNS = 100_000

#: Without --point-timeout: a point may take 20 times the median time of the points done so far,
#: at least this long [s]; before any point is done, FIRST_POINT_LIMIT.
MIN_POINT_LIMIT = 60.0
FIRST_POINT_LIMIT = 600.0
#: Not on a terminal, a progress line at most this often [s].
PLAIN_PROGRESS_EVERY = 10.0

STATUSES = ("ok", "failed", "timed out", "incomplete")

OUTPUT_STATISTICS = ("min", "max", "mean", "rms", "final")
DEFAULT_OUTPUT_STATISTICS = ("min", "max", "rms", "final")
ENERGY_METRICS = {"energy.residual": "J", "energy.relative_residual": None}
#: Of every power output, over the experiment's first cycle (stats.power_statistics): SI units.
CYCLE_STATISTICS = {"cycle_peak": "W", "cycle_rms": "W", "cycle_energy": "J", "cycle_energy_positive": "J",
                    "cycle_energy_negative": "J"}
_CYCLE_KEYS = {"cycle_peak": "peak", "cycle_rms": "rms", "cycle_energy": "net_energy",
               "cycle_energy_positive": "positive_energy", "cycle_energy_negative": "negative_energy"}
MOTOR_METRICS = {"motor.peak_torque": "N*m", "motor.rms_torque": "N*m", "motor.peak_speed": "rad/s",
                 "motor.peak_power": "W", "motor.energy": "J"}
_MOTOR_FIELDS = {"motor.peak_torque": "peak_torque", "motor.rms_torque": "rms_torque",
                 "motor.peak_speed": "peak_speed", "motor.peak_power": "peak_power", "motor.energy": "energy_net"}


def _usage(code: str, message: str, hint: str | None = None) -> UsageError:
    return UsageError(Diagnostic("error", code, message, hint=hint))


# ------------------------------------------------------------------ the request


@dataclass(frozen=True)
class Axis:
    """One varied parameter: its values as given, in ``unit`` (None: the parameter's declared unit)."""

    name: str
    values: tuple[float, ...]
    unit: str | None
    text: str


_VARY = re.compile(r"^\s*(?P<name>[^=\[\]]*?)\s*=\s*(?P<values>[^\[\]]*?)\s*(?:\[(?P<unit>[^\[\]]*)\])?\s*$")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*$")      # dotted: a component's parameter


def _number(text: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _usage("E962", f"--vary '{spec}': '{text}' is not a number",
                     hint="values are numbers separated by commas, or start:stop:count") from None
    if not math.isfinite(value):
        raise _usage("E962", f"--vary '{spec}': '{text}' is not a finite number")
    return value


def _range(item: str, spec: str) -> list[float]:
    parts = [part.strip() for part in item.split(":")]
    if len(parts) != 3:
        raise _usage("E962", f"--vary '{spec}': '{item}' is not start:stop:count",
                     hint="e.g. M=20:40:5 gives 20, 25, 30, 35, 40")
    start, stop = _number(parts[0], spec), _number(parts[1], spec)
    try:
        count = int(parts[2])
    except ValueError:
        count = 0
    if count < 2 or str(count) != parts[2].lstrip("+"):
        raise _usage("E962", f"--vary '{spec}': the count in '{item}' must be a whole number >= 2, "
                             f"got '{parts[2]}'", hint="start:stop:count includes both ends")
    if count > MAX_RUNS:        # before anything is allocated (a count of 10^8 is 800 MB of values)
        raise _usage("E964", f"--vary '{spec}' asks for {count} values; a sweep has at most {MAX_RUNS} runs",
                     hint="use fewer points (a coarse grid first, then a finer one where it matters)")
    values = np.linspace(start, stop, count)
    values[0], values[-1] = start, stop
    return [float(v) for v in values]


def parse_vary(text: str) -> Axis:
    """``"NAME=v1,v2 [unit]"`` or ``"NAME=start:stop:count [unit]"`` -> :class:`Axis` (E960, E962)."""
    match = _VARY.match(text)
    if match is None or "=" not in text:
        raise _usage("E960", f"--vary '{text}' is not NAME=VALUES [unit]",
                     hint='e.g. --vary "k=400,800,1600" or --vary "M=20:40:5 [kg]"')
    name = match["name"]
    if not _NAME.match(name):
        raise _usage("E960", f"--vary '{text}': '{name}' is not a parameter name",
                     hint='e.g. --vary "k=400,800,1600"')
    unit = match["unit"].strip() if match["unit"] is not None else None
    if unit == "":
        raise _usage("E963", f"--vary '{text}': the unit between [ ] is empty",
                     hint="leave out [ ] to use the parameter's declared unit")
    items = [item.strip() for item in match["values"].split(",")]
    if not any(items):
        raise _usage("E960", f"--vary '{text}' gives no values for '{name}'",
                     hint="give values separated by commas, or start:stop:count")
    values: list[float] = []
    for item in items:
        if not item:
            raise _usage("E960", f"--vary '{text}' has an empty value between commas")
        values += _range(item, text) if ":" in item else [_number(item, text)]
    return Axis(name, tuple(values), unit, text)


def _resolve_unit(text: str, where: str = ""):
    """The :class:`bondc.units.SIUnit` of a unit as written; raises UsageError E963 (``where`` starts
    its message)."""
    from bondc import units
    from bondc.parse import parse_set_value

    try:
        unit = parse_set_value(f"_unit = 1 [{text}]").unit
    except BondcError:
        raise _usage("E963", f"{where}[{text}] is not a unit") from None
    si, diagnostics = units.resolve(unit)
    if si is None:
        hint = next((d.hint for d in diagnostics if d.hint), None)
        message = "; ".join(d.message for d in diagnostics) or f"[{text}] is not a unit"
        raise _usage("E963", where + message, hint=hint)
    return si


def _si_unit_text(unit_text: str | None) -> str | None:
    """The SI unit of a unit as written: itself when coherent (``N``), else its dimensions (``mm`` -> ``m``)."""
    if not unit_text:
        return None
    try:
        si = _resolve_unit(unit_text)
    except UsageError:
        return unit_text
    if si.is_coherent:
        return unit_text
    text = si.dimension_text()
    return None if text == "1" else text


@dataclass(frozen=True)
class Metric:
    """A column: its name, the unit of its SI value and how the text table shows it."""

    name: str
    si_unit: str | None
    unit: str | None = None          # the display unit (an output's declared unit)
    display_factor: float = 1.0      # display value = SI value / display_factor


def _available_metrics(graph, motor: bool) -> dict[str, Metric]:
    found: dict[str, Metric] = {}
    for name, output in graph.outputs.items():
        for statistic in OUTPUT_STATISTICS:
            found[f"{name}.{statistic}"] = Metric(f"{name}.{statistic}", _si_unit_text(output.unit_text),
                                                  output.unit_text, output.display_factor or 1.0)
    from bondc.analysis.stats import power_outputs

    for name in power_outputs(graph):          # per cycle (the experiment's first): peak, RMS, energies
        for statistic, unit in CYCLE_STATISTICS.items():
            shown = graph.outputs[name].unit_text if unit == "W" else "J"
            factor = (graph.outputs[name].display_factor or 1.0) if unit == "W" else 1.0
            found[f"{name}.{statistic}"] = Metric(f"{name}.{statistic}", unit, shown, factor)
    for name, unit in ENERGY_METRICS.items():
        found[name] = Metric(name, unit, unit)
    if motor:
        for name, unit in MOTOR_METRICS.items():
            found[name] = Metric(name, unit, unit)
    return found


def _has_motor(graph) -> bool:
    from bondc.analysis.motor_report import SPEED_NAMES, TORQUE_NAMES

    torque = any(name in graph.outputs for name in TORQUE_NAMES)
    speed = any(name in graph.outputs or name in graph.inputs for name in SPEED_NAMES)
    return torque and speed


def select_metrics(graph, metrics: Sequence[str] | None) -> tuple[Metric, ...]:
    """The columns ``metrics`` asks for (None: every default column), in the order asked; E965."""
    motor = _has_motor(graph)
    available = _available_metrics(graph, motor)
    if metrics is None:
        return tuple(m for name, m in available.items() if _default(name))
    chosen: dict[str, Metric] = {}
    for requested in metrics:
        for text in (part.strip() for part in requested.split(",")):
            if not text:
                continue
            if text.endswith(".*"):
                head = text[:-2]
                group = [m for name, m in available.items() if name.rpartition(".")[0] == head and _default(name)]
                if group:
                    chosen.update((m.name, m) for m in group)
                    continue
            elif text in available:
                chosen[text] = available[text]
                continue
            raise _unknown_metric(text, available, graph, motor)
    if not chosen:
        raise _usage("E965", "no metrics selected", hint="e.g. --metric x.max --metric energy.residual")
    return tuple(chosen.values())


def _default(name: str) -> bool:
    """Whether a metric is a column when none are asked for (every one but the means)."""
    return (name in ENERGY_METRICS or name in MOTOR_METRICS
            or name.rpartition(".")[2] in DEFAULT_OUTPUT_STATISTICS or name.rpartition(".")[2] in CYCLE_STATISTICS)


def _unknown_metric(text: str, available: dict, graph, motor: bool) -> UsageError:
    if text.startswith("motor.") and not motor:
        return _usage("E965", f"unknown metric '{text}': motor requirements need an output 'torque' and an "
                              "output or input 'omega' or 'speed'",
                      hint=f"outputs: {', '.join(graph.outputs) or 'none'}")
    head, dot, _ = text.rpartition(".")
    listing = (f"outputs: {', '.join(graph.outputs) or 'none'}, each with .min .max .mean .rms .final; "
               "also energy.residual, energy.relative_residual" + (", motor.*" if motor else ""))
    if dot and head not in graph.outputs and head not in ("energy", "motor"):
        close = difflib.get_close_matches(head, list(graph.outputs), n=1)
        return _usage("E965", f"unknown metric '{text}': the model has no output '{head}'",
                      hint=f"did you mean '{close[0]}'?" if close else listing)
    close = difflib.get_close_matches(text, list(available), n=1)
    return _usage("E965", f"unknown metric '{text}'", hint=f"did you mean '{close[0]}'?" if close else listing)


# ------------------------------------------------------------------ results


@dataclass(frozen=True)
class SweepPoint:
    """One grid point: the values as given, every parameter it ran with (SI) and its metrics (SI)."""

    index: int
    values: tuple[float, ...]                    # per axis, as given
    status: str                                  # "ok", "failed", "timed out" or "incomplete" (a metric is nan)
    message: str | None = None
    path: str | None = None                      # "fast", "rederived" or None (not run)
    parameters: dict = field(default_factory=dict)   # varied parameter -> SI value
    metrics: dict = field(default_factory=dict)      # metric -> SI value (nan: not computed)
    t_reached: float | None = None
    diagnostics: tuple[Diagnostic, ...] = ()     # why it failed
    warnings: tuple[Diagnostic, ...] = ()
    traceback: str | None = None                 # an internal error's traceback
    wall_time: float | None = None               # seconds this point took (in its worker)
    motors: tuple[str, ...] | None = None        # with --motors: the catalogue motors that qualify

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def chosen_motor(self) -> str | None:
        """With --motors: the point's answer, the smallest motor that qualifies (None if none does)."""
        return self.motors[0] if self.motors else None

    @property
    def ran(self) -> bool:
        """The simulation completed (its metrics are there, maybe not all of them)."""
        return self.status in ("ok", "incomplete")


@dataclass(frozen=True)
class SweepResult:
    """Every point of a sweep, ordered by grid index; see the module docstring."""

    model: str
    experiment: str | None
    file: str
    axes: tuple[Axis, ...]
    axis_units: tuple[str | None, ...]           # each axis's unit as shown (given, else declared)
    axis_si_units: tuple[str | None, ...]
    metrics: tuple[Metric, ...]
    points: tuple[SweepPoint, ...]
    settings: dict = field(default_factory=dict)     # t_end, dt, rederive, samples, seed, point_timeout
    warnings: tuple[Diagnostic, ...] = ()        # from loading and deriving the base model
    total: int | None = None                     # the points asked for (more than ``points`` if interrupted)
    motors: bool = False                         # a motors column (--motors)

    @property
    def failed(self) -> tuple[SweepPoint, ...]:
        return tuple(point for point in self.points if not point.ok)

    @property
    def exit_code(self) -> int:
        """0 when every point ran with all its metrics, 1 otherwise."""
        return 1 if self.failed or self.interrupted else 0

    @property
    def interrupted(self) -> bool:
        return self.total is not None and len(self.points) < self.total

    def counts(self) -> dict[str, int]:
        return {status: sum(p.status == status for p in self.points) for status in STATUSES}

    def motors_for_all(self) -> list[str] | None:
        """With --motors: the motors that qualify at every point that ran, smallest first (the
        catalogue order of each point's selection); None without --motors."""
        if not self.motors:
            return None
        selections = [p.motors for p in self.points if p.motors is not None]
        if not selections:
            return []
        common = set(selections[0]).intersection(*map(set, selections[1:]))
        return [name for name in selections[0] if name in common]

    def describe(self, point: SweepPoint) -> str:
        """``k=400 N/m, b=12`` for a point, in the units as given."""
        parts = []
        for axis, unit, value in zip(self.axes, self.axis_units, point.values):
            parts.append(f"{axis.name}={value:.6g}" + (f" {unit}" if unit else ""))
        return ", ".join(parts)

    def diagnostics(self) -> list[Diagnostic]:
        """Every failed point's diagnostics, each message prefixed with the point, then E968 per point
        without one."""
        out = []
        for point in self.failed:
            where = f"point {point.index} ({self.describe(point)}): "
            if point.diagnostics:
                out += [Diagnostic(d.severity, d.code, where + d.message, d.span, d.hint, d.related)
                        for d in point.diagnostics]
            else:
                out.append(Diagnostic("error", "E968", where + (point.message or "failed")))
        return out

    def column(self, metric: str) -> list[float]:
        """One metric over the points, SI (nan where it was not computed)."""
        return [point.metrics.get(metric, math.nan) for point in self.points]

    # ---------------------------------------------------------------- json

    def to_json(self) -> dict:
        """A JSON-ready dict (nan/inf as the strings "nan", "inf"); values SI."""
        data = {
            "model": self.model,
            "experiment": self.experiment,
            "file": self.file,
            "settings": dict(self.settings),
            "parameters": [{"name": axis.name, "vary": axis.text, "unit": unit, "si_unit": si_unit,
                            "values": list(axis.values)}
                           for axis, unit, si_unit in zip(self.axes, self.axis_units, self.axis_si_units)],
            "metrics": [{"name": m.name, "si_unit": m.si_unit} for m in self.metrics],
            "runs": len(self.points),
            "total": self.total if self.total is not None else len(self.points),
            **({"motors_for_all": self.motors_for_all()} if self.motors else {}),
            "failed": len(self.failed),
            "counts": self.counts(),
            "points": [{
                "index": point.index,
                "values": list(point.values),
                "parameters": dict(point.parameters),
                "status": point.status,
                "message": point.message,
                "path": point.path,
                "t_reached": point.t_reached,
                "metrics": {m.name: point.metrics.get(m.name) for m in self.metrics} if point.ran else {},
                "wall_time": point.wall_time,
                **({"motors": list(point.motors)} if point.motors is not None else {}),
                "diagnostics": [d.to_json() for d in point.diagnostics],
                "warnings": [d.to_json() for d in point.warnings],
                **({"traceback": point.traceback} if point.traceback else {}),
            } for point in self.points],
        }
        return json_safe(data)

    def to_json_text(self) -> str:
        return json.dumps(self.to_json(), indent=2, allow_nan=False) + "\n"

    # ---------------------------------------------------------------- csv

    def csv_text(self) -> str:
        """Columns ``index``, each varied parameter, each metric (SI, the unit in the header), ``motors``
        (with --motors), ``status``, ``message``, ``wall_time``; one row per point; values are the
        shortest text that reads back to the same float."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(self.csv_header())
        for point in self.points:
            writer.writerow(self.csv_row(point))
        return out.getvalue()

    def csv_header(self) -> list[str]:
        header = ["index"]
        header += [_with_unit(axis.name, unit) for axis, unit in zip(self.axes, self.axis_si_units)]
        header += [_with_unit(m.name, m.si_unit) for m in self.metrics]
        return header + (["motors"] if self.motors else []) + ["status", "message", "wall_time [s]"]

    def csv_row(self, point: SweepPoint) -> list:
        row = [point.index]
        row += [_csv_number(point.parameters.get(axis.name)) for axis in self.axes]
        row += [_csv_number(point.metrics.get(m.name)) if point.ran else "" for m in self.metrics]
        if self.motors:
            row.append(";".join(point.motors or ()))
        return row + [point.status, point.message or "", _csv_number(point.wall_time)]

    def write_csv(self, path) -> None:
        """Write :meth:`csv_text` atomically."""
        from bondc.io import atomic_write_text

        atomic_write_text(Path(path), self.csv_text())

    def write(self, path) -> None:
        """``.json`` -> :meth:`to_json`, ``.csv`` -> :meth:`write_csv` (atomic); E969 otherwise."""
        from bondc.io import atomic_write_text

        suffix = Path(path).suffix.lower()
        if suffix == ".json":
            atomic_write_text(Path(path), self.to_json_text())
        elif suffix == ".csv":
            self.write_csv(path)
        else:
            raise _usage("E969", f"cannot write '{path}': give a .csv or .json file")

    # ---------------------------------------------------------------- text

    def to_text(self, width: int = 110) -> str:
        """A table: the varied parameters, then the metrics in display units, then the status.

        Metric columns that do not fit in ``width`` go to further tables that repeat the parameters.
        """
        shape = " x ".join(str(len(axis.values)) for axis in self.axes)
        counts = self.counts()
        states = ", ".join(f"{n} {status}" for status, n in counts.items() if n and status != "ok")
        head = [f"sweep of {self.model}" + (f" ({self.experiment})" if self.experiment else "")
                + f": {len(self.points)} run{'s' if len(self.points) != 1 else ''}"
                + (f" ({shape})" if len(self.axes) > 1 and not self.settings.get("samples") else "")
                + (f" (Latin hypercube, seed {self.settings.get('seed')})" if self.settings.get("samples") else "")
                + ", " + (f"{counts['ok']} ok, {states}" if states else "all complete")
                + (f"; interrupted after {len(self.points)} of {self.total} points" if self.interrupted else "")]
        keys = [_with_unit(axis.name, unit) for axis, unit in zip(self.axes, self.axis_units)]
        fixed = [[key] + [f"{value:.6g}" for value in (p.values[i] for p in self.points)]
                 for i, key in enumerate(keys)]
        status = ["status"] + [point.status for point in self.points]
        if self.motors:         # the smallest qualifying motor and how many more
            fixed.append(["motors"] + ["-" if not p.motors else
                                       p.motors[0] + (f" +{len(p.motors) - 1}" if len(p.motors) > 1 else "")
                                       for p in self.points])
        columns = []
        for metric in self.metrics:
            cells = [_with_unit(metric.name, metric.unit)]
            for point in self.points:
                value = point.metrics.get(metric.name) if point.ran else None
                cells.append("-" if value is None else _format(value / metric.display_factor))
            columns.append(cells)
        blocks, block, used = [], [], sum(_width(c) + 2 for c in fixed) + _width(status)
        for cells in columns:
            if block and used + _width(cells) + 2 > width:
                blocks.append(block)
                block, used = [], sum(_width(c) + 2 for c in fixed) + _width(status)
            block.append(cells)
            used += _width(cells) + 2
        blocks.append(block)
        lines = list(head)
        for block in blocks:
            table = fixed + block + [status]
            widths = [_width(c) for c in table]
            lines.append("")
            for row in range(len(self.points) + 1):
                cells = []
                for number, (cells_of, w) in enumerate(zip(table, widths)):
                    text = cells_of[row]
                    left = number >= len(table) - 1      # status is text
                    cells.append(text.ljust(w) if left else text.rjust(w))
                lines.append("  ".join(cells).rstrip())
        notes = []
        for point in self.points:
            if not point.ran:
                # its warnings (outputs not finite, ...) follow from the failure: see to_json()
                notes.append(f"  point {point.index} ({self.describe(point)}) {point.status}: {point.message}")
                continue
            if point.status == "incomplete":
                notes.append(f"  point {point.index} ({self.describe(point)}) incomplete: {point.message}")
            for warning in point.warnings:
                notes.append(f"  point {point.index}: {warning.severity}[{warning.code}]: {warning.message}")
        if notes:
            lines += [""] + notes
        common = self.motors_for_all()
        if common is not None:
            lines += ["", "motors that qualify at every point: " + (", ".join(common) + f" (smallest: {common[0]})"
                                                                    if common else "none")]
        return "\n".join(lines)


def _with_unit(name: str, unit: str | None) -> str:
    return f"{name} [{unit}]" if unit and unit != "1" else name


def _width(cells: list[str]) -> int:
    return max(len(cell) for cell in cells)


def _format(value: float) -> str:
    return f"{value:.5g}" if math.isfinite(value) else str(value)


def _csv_number(value) -> str:
    if value is None:
        return ""
    value = float(value)
    return repr(value) if math.isfinite(value) else str(value)


# ------------------------------------------------------------------ running a point


@dataclass(frozen=True)
class _Setup:
    """What every point needs, picklable for worker processes. ``key`` finds the compiled base model."""

    key: tuple
    path: str
    model: str | None
    experiment: str | None
    sets: tuple                  # parsed ast.SetValue, the base --set values
    names: tuple[str, ...]       # the varied parameters, per axis
    units: tuple[str | None, ...]            # as given (None: the declared unit)
    converters: tuple                        # per axis, the SIUnit its values are in (for a point not loaded)
    metrics: tuple[str, ...]
    t_end: float | None
    dt: float | None
    rederive: bool
    motors: str | None = None                # a motor catalogue (csv): which motors qualify per point
    inertia_ratio: float | None = None       # --inertia-ratio: every motor's load/rotor inertia limit
    bound: bool = False                      # late binding: points are vectors of values (see _measure_point)


@dataclass
class _Base:
    graph: object
    state_space: object
    structure: tuple
    files: dict                  # file name -> text the base model was read from
    warnings: list


def _file_texts(graph) -> dict:
    return {name: source.text for name, source in graph.sources.items() if source.path is not None}


_BASES: dict[tuple, _Base] = {}
_COUNTER = itertools.count()


def _experiment_selector(setup: _Setup):
    from bondc import semantic

    return setup.experiment if setup.experiment is not None else semantic.FIRST


def _structure(graph) -> tuple:
    from bondc.pipeline import structure

    return structure(graph)


def _derive(graph):
    from bondc.causality import assign_causality
    from bondc.equations import derive

    causal = assign_causality(graph)
    state_space = derive(causal)
    return causal, state_space


def _base(setup: _Setup, loaded: tuple | None = None) -> _Base:
    """The base model of ``setup``, derived and compiled once per process; ``loaded`` is
    ``semantic.load``'s (graph, warnings) when the caller has them."""
    base = _BASES.get(setup.key)
    if base is not None:
        return base
    from bondc import semantic
    from bondc.simulate import compile_model

    graph, warnings = loaded or semantic.load(Path(setup.path), model=setup.model,
                                              experiment=_experiment_selector(setup), sets=list(setup.sets))
    causal, state_space = _derive(graph)
    namespace = compile_model(state_space)
    if namespace.get("NATIVE_SOURCE"):
        from bondc.runtime import load_native

        load_native(namespace["NATIVE_SOURCE"])     # built once here, before workers fork: they load it
    notes = list(warnings)
    notes += [d for d in list(causal.diagnostics) + list(state_space.diagnostics) if d not in notes]
    base = _Base(graph, state_space, _structure(graph), _file_texts(graph), notes)
    _BASES[setup.key] = base
    return base


def _set_text(name: str, value: float, unit: str | None) -> str:
    return f"{name}={value!r}" + (f" [{unit}]" if unit else "")


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
    from bondc import semantic
    from bondc.parse import parse_set_value
    from bondc.simulate import simulate

    base = _base(setup)
    parameters = {name: unit.to_si(value) for name, unit, value in zip(setup.names, setup.converters, values)}
    try:
        if setup.bound:
            graph, experiment = base.graph, chosen_experiment(base.graph, setup.experiment)
            state_space, path = base.state_space, "bound"
            result = simulate(state_space, experiment, t_end=setup.t_end, dt=setup.dt, overrides=dict(parameters))
            return _finish_point(setup, index, values, path, parameters, state_space, graph, experiment, result)
        sets = list(setup.sets) + [parse_set_value(_set_text(name, value, unit), f"--vary {name}")
                                   for name, unit, value in zip(setup.names, setup.units, values)]
        graph, _ = semantic.load(Path(setup.path), model=setup.model, experiment=_experiment_selector(setup),
                                 sets=sets)
        parameters = {name: graph.parameters[name].value for name in setup.names}
        if _file_texts(graph) != base.files:
            return SweepPoint(index, values, "failed", "E968: the model file changed during the sweep",
                              None, parameters, diagnostics=(Diagnostic(
                                  "error", "E968", "the model file changed during the sweep",
                                  hint="run the sweep again"),))
        experiment = chosen_experiment(graph, setup.experiment)
        if not setup.rederive and _structure(graph) == base.structure:
            state_space, path = base.state_space, "fast"
            # every parameter given: the compiled module recomputes none of them
            overrides = {name: graph.parameters[name].value for name in state_space.parameters}
        else:
            _, state_space = _derive(graph)
            path, overrides = "rederived", None
        result = simulate(state_space, experiment, t_end=setup.t_end, dt=setup.dt, overrides=overrides)
    except BondcError as error:
        message = "; ".join(f"{d.code}: {d.message}" for d in error.diagnostics) or str(error)
        return SweepPoint(index, values, "failed", message, None, parameters, diagnostics=tuple(error.diagnostics))
    return _finish_point(setup, index, values, path, parameters, state_space, graph, experiment, result)


def _can_bind(setup: _Setup, base: _Base, grid: list) -> bool:
    """Whether the points can be bound late: the varied parameters change nothing the check fixes
    outside the compiled module (the experiment's settings: t_end, max_step, cycle, ...). Loaded at
    the first and the last point and compared with the base model."""
    from bondc import semantic
    from bondc.parse import parse_set_value

    if setup.rederive:
        return False
    reference = chosen_experiment(base.graph, setup.experiment)
    for values in (grid[0], grid[-1]):
        sets = list(setup.sets) + [parse_set_value(_set_text(name, value, unit), f"--vary {name}")
                                   for name, unit, value in zip(setup.names, setup.units, values)]
        try:
            graph, _ = semantic.load(Path(setup.path), model=setup.model, experiment=_experiment_selector(setup),
                                     sets=sets)
        except BondcError:
            return False            # the points say why, one by one
        experiment = chosen_experiment(graph, setup.experiment)
        if _structure(graph) != base.structure or _settings(experiment) != _settings(reference):
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
        diagnostics = tuple(result.diagnostics) or (Diagnostic("error", "E968", result.message),)
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


_CATALOGUES: dict[str, list] = {}
#: The version of the sizing rules a study's motors column was made with (part of its identity).
MOTOR_RULES = "peak envelope, RMS at RMS speed, top speed, inertia ratio (2)"


def _qualifying_motors(setup: _Setup, result, graph, warnings: list) -> tuple[str, ...] | None:
    """The catalogue motors that pass every sizing rule at this point, smallest first (the first is the
    point's choice); None: no selection possible. The same call as ``bondc simulate --motors``
    (:func:`bondc.analysis.motor_report.size_motors`): rotor inertia added, the load inertia
    estimated from the point's run, the inertia-ratio rule applied."""
    from bondc.analysis.motor_report import size_motors
    from bondc.analysis.motors import load_catalogue

    try:
        catalogue = _CATALOGUES.get(setup.motors)
        if catalogue is None:
            catalogue = _CATALOGUES[setup.motors] = load_catalogue(setup.motors)
        selection = size_motors(result, graph, catalogue, inertia_limit=setup.inertia_ratio)
        return tuple(candidate.motor.name for candidate in selection.qualified)
    except BondcError as error:
        warnings += [Diagnostic("warning", d.code, f"no motor selection: {d.message}", d.span, d.hint)
                     for d in error.diagnostics]
        return None


def _measure(setup: _Setup, state_space, graph, experiment, result, warnings: list) -> dict:
    from bondc.analysis.stats import output_statistics

    wanted = setup.metrics
    metrics: dict[str, float] = {}
    statistics = output_statistics(result) if result.t.size else {}
    for name in wanted:
        output, _, statistic = name.rpartition(".")
        if output in statistics and statistic in OUTPUT_STATISTICS:
            metrics[name] = float(statistics[output][statistic])
    cycled = [name for name in wanted if name.rpartition(".")[2] in CYCLE_STATISTICS]
    if cycled and result.t.size > 1:
        from bondc.analysis.stats import power_statistics

        outputs = sorted({name.rpartition(".")[0] for name in cycled})
        per_cycle = power_statistics(result, outputs, getattr(experiment, "cycle", None))
        for name in cycled:
            output, _, statistic = name.rpartition(".")
            first = (per_cycle.get(output) or [None])[0]
            if first is not None:
                metrics[name] = float(first[_CYCLE_KEYS[statistic]])
    if any(name in ENERGY_METRICS for name in wanted):
        metrics.update(_energy_metrics(state_space, result, experiment, warnings))
    if any(name in MOTOR_METRICS for name in wanted):
        metrics.update(_motor_metrics(result, graph, warnings))
    return {name: metrics.get(name, math.nan) for name in wanted}


def _energy_metrics(state_space, result, experiment, warnings: list) -> dict:
    from bondc.analysis.energy import energy_account

    cycle = getattr(experiment, "cycle", None)
    try:
        account = energy_account(state_space, result, cycle=cycle)
    except BondcError as error:
        warnings += [Diagnostic("warning", d.code, f"no energy balance: {d.message}", d.span, d.hint)
                     for d in error.diagnostics]
        return {}
    warnings += [d for d in account.diagnostics if d not in warnings]
    return {"energy.residual": float(sum(window.balance.residual for window in account.windows)),
            "energy.relative_residual": float(account.max_relative_residual)}


def _motor_metrics(result, graph, warnings: list) -> dict:
    from bondc.analysis.motor_report import SPEED_NAMES, TORQUE_NAMES, cycle_window, find_signal
    from bondc.analysis.motors import requirements

    try:
        _, _, torque = find_signal(result, TORQUE_NAMES, "torque")
        _, _, speed = find_signal(result, SPEED_NAMES, "speed")
        need = requirements(result.t, torque, speed, cycle=cycle_window(result, graph))
    except BondcError as error:
        warnings += [Diagnostic("warning", d.code, f"no motor requirements: {d.message}", d.span, d.hint)
                     for d in error.diagnostics]
        return {}
    return {name: float(getattr(need, attribute)) for name, attribute in _MOTOR_FIELDS.items()}


# ------------------------------------------------------------------ the sweep


def _check_axes(graph, axes: Sequence[Axis], sets: Sequence) -> tuple[list, list, list]:
    """E961 unknown parameter, E963 unit, E966 duplicates.

    Returns per axis the unit its values are shown in, the SI unit text, and the
    :class:`bondc.units.SIUnit` its values are in.
    """
    from bondc import units

    names = list(graph.parameters)
    seen: set[str] = set()
    fixed = {item.name for item in sets}
    shown, si_units, converters = [], [], []
    for axis in axes:
        if axis.name not in graph.parameters:
            close = difflib.get_close_matches(axis.name, names, n=1)
            hint = f"did you mean '{close[0]}'?" if close else "parameters: " + ", ".join(names)
            raise _usage("E961", f"--vary '{axis.text}': '{axis.name}' is not a parameter of {graph.name}",
                         hint=hint)
        if axis.name in seen:
            raise _usage("E966", f"'{axis.name}' is varied twice", hint="give all its values in one --vary")
        if axis.name in fixed:
            raise _usage("E966", f"'{axis.name}' is both varied and set with --set", hint="drop one of them")
        seen.add(axis.name)
        declared_text = graph.parameters[axis.name].unit_text
        declared = _resolve_unit(declared_text) if declared_text else units.DIMENSIONLESS
        converter = declared
        if axis.unit is not None:
            converter = _resolve_unit(axis.unit, f"--vary '{axis.text}': ")
            # the same test as --set (semantic's E204): angle counts, rpm is not 1/s
            if converter.dims != declared.dims:
                raise _usage("E963", f"--vary '{axis.text}': [{axis.unit}] does not measure the same quantity "
                                     f"as [{declared_text or '1'}], the unit of '{axis.name}'",
                             hint=f"give the values in [{declared_text or '1'}] or a unit of the same kind "
                                  f"({declared.dimension_text()})")
        shown.append(axis.unit if axis.unit is not None else declared_text)
        si_units.append(_si_unit_text(declared_text))
        converters.append(converter)
    return shown, si_units, converters


def parse_range(text: str) -> Axis:
    """``--range NAME=lo:hi [unit]`` for Latin-hypercube samples: an axis whose values are its bounds.

    >>> axis = parse_range("M=20:45 [kg]")
    >>> axis.name, axis.values, axis.unit
    ('M', (20.0, 45.0), 'kg')
    """
    match = _VARY.fullmatch(text.strip())
    if match is None or ":" not in match.group("values") or match.group("values").count(":") != 1:
        raise _usage("E960", f"--range '{text}': write NAME=LOW:HIGH, optionally with a unit: \"M=20:45 [kg]\"")
    low_text, high_text = match.group("values").split(":")
    low, high = _number(low_text, text), _number(high_text, text)
    if not high > low:
        raise _usage("E962", f"--range '{text}': the upper bound must be above the lower one")
    return Axis(match.group("name"), (low, high), match.group("unit"), text)


def latin_hypercube(axes: Sequence[Axis], samples: int, seed: int | None) -> list[tuple[float, ...]]:
    """``samples`` points of a Latin hypercube over the axes' [low, high] (scipy.stats.qmc), the same
    for the same seed."""
    from scipy.stats import qmc

    unit = qmc.LatinHypercube(d=len(axes), seed=seed).random(samples)
    lows = np.array([axis.values[0] for axis in axes])
    highs = np.array([axis.values[1] for axis in axes])
    return [tuple(float(v) for v in row) for row in qmc.scale(unit, lows, highs)]


def run_sweep(path, *, model: str | None = None, experiment: str | None = None, sets: Sequence = (),
              vary: Sequence[str] = (), samples: int | None = None, ranges: Sequence[str] = (),
              seed: int | None = None, metrics: Sequence[str] | None = None, output=None, jobs: int = 1,
              t_end: float | None = None, dt: float | None = None, rederive: bool = False,
              progress: bool | Callable[[SweepPoint, int, int], None] = False,
              point_timeout: float | None = None, motors=None, executor: str = "local",
              scheduler: str | None = None, inertia_ratio: float | None = None) -> SweepResult:
    """``bondc sweep``: run the model at every point of the grid of ``vary`` (or at ``samples``
    Latin-hypercube points over ``ranges``, reproducible with ``seed``); see the module docstring.

    ``sets`` are ``--set`` texts or parsed ``ast.SetValue`` applied to every
    point; ``experiment`` None takes the first; ``t_end``/``dt`` override the
    experiment's; ``output`` a ``.csv`` (rows appended as points finish) or
    ``.json`` path. When ``output`` already holds points of the same sweep,
    they are kept and only the others run (resuming). ``point_timeout``:
    seconds a point may take (None: 20 times the median, at least 60 s; 0: no
    limit, points run in this process). ``motors``: a motor catalogue (csv);
    each point lists the motors that pass the sizing rules of ``bondc simulate --motors``,
    smallest (the point's choice) first; ``inertia_ratio`` is every motor's load/rotor
    inertia-ratio limit (default: the catalogue's, else 10). ``progress`` True shows progress
    on stderr, or is called as ``progress(point, done, total)``. ``executor``
    "local" runs ``jobs`` worker processes here; "dask" runs the points on a
    ``dask.distributed`` cluster: ``scheduler`` (``tcp://host:8786``) or a
    ``LocalCluster`` of ``jobs`` workers (the model file must be readable at
    the same path on every worker).

    Raises UsageError (E960-E967, E969, E970) for a bad request and the stage
    errors of loading or deriving the base model; a point that fails is
    recorded, not raised (:attr:`SweepResult.exit_code`). Ctrl-C and SIGTERM
    stop the sweep after writing every finished point; the exception raised
    carries the partial result as ``sweep_result``.
    """
    from bondc import semantic

    if not vary and not samples:
        raise _usage("E960", "nothing to vary", hint='give --vary, e.g. --vary "k=400,800,1600", or --samples N '
                                                    'with --range NAME=LOW:HIGH')
    if vary and (samples or ranges):
        raise _usage("E960", "give either --vary (a grid) or --samples with --range (a Latin hypercube)")
    if samples is not None and (not isinstance(samples, int) or samples < 1 or not ranges):
        raise _usage("E960", "--samples needs a whole number >= 1 and at least one --range NAME=LOW:HIGH")
    if not isinstance(jobs, int) or jobs < 1:
        raise _usage("E967", f"jobs must be a whole number >= 1, got {jobs!r}")
    if executor not in ("local", "dask"):
        raise _usage("E971", f"unknown executor {executor!r}", hint="choose local or dask")
    if scheduler and executor != "dask":
        executor = "dask"           # --scheduler means a Dask cluster
    if point_timeout is not None and not point_timeout >= 0:
        raise _usage("E967", f"--point-timeout must be a number of seconds >= 0 (0: no limit), got {point_timeout!r}")
    if output is not None and Path(output).suffix.lower() not in (".csv", ".json"):
        raise _usage("E969", f"cannot write '{output}': give a .csv or .json file")
    if output is not None:
        from bondc.io import check_output

        check_output(output, "the sweep table")
    axes = [parse_range(text) for text in ranges] if samples else [parse_vary(text) for text in vary]
    runs = samples if samples else math.prod(len(axis.values) for axis in axes)
    if runs > MAX_RUNS:
        shape = f" ({' x '.join(str(len(axis.values)) for axis in axes)})" if len(axes) > 1 and not samples else ""
        raise _usage("E964", f"the sweep has {runs} runs{shape}; at most {MAX_RUNS} are allowed",
                     hint="use fewer values, or split the sweep")
    from bondc.pipeline import parse_sets

    parsed_sets = tuple(parse_sets(sets))

    # load to check the request before deriving anything
    graph, warnings = semantic.load(Path(path), model=model,
                                    experiment=experiment if experiment is not None else semantic.FIRST,
                                    sets=list(parsed_sets))
    shown_units, si_units, converters = _check_axes(graph, axes, parsed_sets)
    chosen_metrics = select_metrics(graph, metrics)
    chosen = chosen_experiment(graph, experiment)
    if t_end is None and getattr(chosen, "t_end", None) is None:
        raise _usage("E801", "no end time for the simulation", hint="give --t-end, or set t_end in the experiment")
    if motors is not None:
        from bondc.analysis.motors import load_catalogue

        load_catalogue(motors)          # a bad catalogue is an error now, not at every point
    from bondc.analysis.motors import check_inertia_limit

    inertia_ratio = check_inertia_limit(inertia_ratio)

    setup = _Setup(key=(os.getpid(), next(_COUNTER)), path=str(path), model=model, experiment=experiment,
                   sets=parsed_sets, names=tuple(axis.name for axis in axes),
                   units=tuple(axis.unit for axis in axes), converters=tuple(converters),
                   metrics=tuple(m.name for m in chosen_metrics), t_end=t_end, dt=dt, rederive=rederive,
                   motors=str(motors) if motors is not None else None,
                   inertia_ratio=inertia_ratio)
    grid = latin_hypercube(axes, samples, seed) if samples else list(itertools.product(*(axis.values for axis in axes)))
    settings = {"t_end": t_end if t_end is not None else chosen.t_end, "dt": dt, "rederive": rederive,
                "point_timeout": point_timeout, "executor": executor}
    if samples:
        settings.update(samples=samples, seed=seed)
    settings["study"] = _study(graph, model, experiment, sets, settings["t_end"], dt, motors, inertia_ratio)

    def result_of(points) -> SweepResult:
        return SweepResult(
            model=graph.name, experiment=getattr(chosen, "name", None), file=str(path), axes=tuple(axes),
            axis_units=tuple(shown_units), axis_si_units=tuple(si_units), metrics=chosen_metrics,
            points=tuple(sorted(points, key=lambda p: p.index)), settings=settings, warnings=tuple(base.warnings),
            total=len(grid), motors=motors is not None)

    names = [axis.name for axis in axes]
    keys = [_key({n: c.to_si(v) for n, c, v in zip(names, converters, values)}, names) for values in grid]
    previous: dict[tuple, SweepPoint] = {}
    if output is not None:
        template = SweepResult(graph.name, None, str(path), tuple(axes), tuple(shown_units), tuple(si_units),
                               chosen_metrics, (), motors=motors is not None)
        previous = _previous_points(output, template.csv_header(), axes, chosen_metrics, motors is not None)
        if previous:
            _check_study(output, settings["study"])
            _check_grid(output, previous, keys, axes, samples, seed)
    done: dict[int, SweepPoint] = {}
    for index, (key, values) in enumerate(zip(keys, grid)):
        if key in previous:
            done[index] = dataclasses.replace(previous[key], index=index, values=values)
    tasks = [(index, values) for index, values in enumerate(grid) if index not in done]

    base = _base(setup, (graph, warnings))     # before any worker starts: forked workers inherit it
    if tasks and _can_bind(setup, base, grid):
        setup = dataclasses.replace(setup, bound=True)
    journal = None
    if output is not None and Path(output).suffix.lower() == ".csv":
        journal = _Journal(output, result_of(()).csv_header())
        _write_study(output, settings["study"], _described(graph, path, chosen, axes, shown_units, converters,
                                                            chosen_metrics))
    report = _progress_reporter(progress, len(tasks))

    def on_done(point: SweepPoint) -> None:
        if not point.parameters:        # stopped before it loaded (timed out): its values in SI all the same
            point = dataclasses.replace(point, parameters={
                name: converter.to_si(value) for name, converter, value in zip(names, converters, point.values)})
        done[point.index] = point
        if journal is not None:
            journal.add(result_of(()).csv_row(point))

    try:
        if tasks:
            _run_all(setup, tasks, jobs, report, point_timeout, on_done, executor, scheduler)
    except KeyboardInterrupt as interrupt:
        result = result_of(done.values())
        _finish(result, output, journal)
        interrupt.sweep_result = result
        raise
    finally:
        _BASES.pop(setup.key, None)
        if report is not None and hasattr(report, "close"):
            report.close()
    result = result_of(done.values())
    _finish(result, output, journal)
    return result


def _finish(result: SweepResult, output, journal) -> None:
    """Close the journal and write the whole table in grid order (atomically)."""
    if journal is not None:
        journal.close()
    if output is not None:
        result.write(output)


def _run_all(setup: _Setup, tasks: list, jobs: int, report, point_timeout: float | None,
             on_done: Callable[[SweepPoint], None], executor: str = "local", scheduler: str | None = None) -> None:
    """Run every ``(index, values)`` task; ``on_done(point)`` in the main process as each finishes.

    ``point_timeout`` 0 runs the points one after the other in this process (no time limit);
    otherwise they run in ``jobs`` worker processes, and a point that takes longer than its limit
    (``point_timeout`` seconds, or None: 20 times the median of the points done so far, at least
    :data:`MIN_POINT_LIMIT`) is stopped and recorded as timed out. Ctrl-C and SIGTERM stop the
    workers at once; what finished has been handed to ``on_done``.
    """
    total = len(tasks)
    if executor == "dask":
        _run_dask(setup, tasks, jobs, report, point_timeout, on_done, scheduler)
        return
    if point_timeout == 0:
        for count, (index, values) in enumerate(tasks, 1):
            started = time.perf_counter()
            point = _run_point(setup, index, values)
            if any(d.code == "E813" for d in point.diagnostics):
                raise KeyboardInterrupt     # Ctrl-C stopped this point's run: stop the sweep, keep the rest
            point = dataclasses.replace(point, wall_time=time.perf_counter() - started)
            on_done(point)
            if report is not None:
                report(point, count, total)
        return
    workers = _Workers(setup, min(jobs, total))
    try:
        workers.run(tasks, point_timeout, on_done, report)
    finally:
        workers.stop()


def _timed_point(setup: _Setup, index: int, values: tuple) -> SweepPoint:
    """One point with its wall time (what a Dask worker runs)."""
    started = time.perf_counter()
    point = _run_point(setup, index, values)
    return dataclasses.replace(point, wall_time=time.perf_counter() - started)


def _run_dask(setup: _Setup, tasks: list, jobs: int, report, point_timeout: float | None, on_done,
              scheduler: str | None) -> None:
    """The points on a Dask cluster: an existing one (``scheduler``, ``tcp://host:8786``) or a
    ``LocalCluster`` of ``jobs`` worker processes. As many points are in flight as there are
    workers, so a point's time runs from when it was sent; one over its limit is recorded as timed
    out and released (on a cluster of its own the sweep closes it at the end, stopping such a point;
    on an existing cluster the worker finishes it in the background)."""
    try:
        from distributed import Client, LocalCluster, wait
    except ImportError:
        raise _usage("E971", "--executor dask needs dask.distributed, which is not installed",
                     hint='pip install "dask[distributed]"') from None
    cluster = None
    try:
        if scheduler:
            client = Client(scheduler, timeout="10s")
        else:
            cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
            client = Client(cluster)
    except (OSError, TimeoutError) as error:
        raise _usage("E971", f"cannot reach the Dask scheduler {scheduler!r}: {error}",
                     hint="start one with 'dask scheduler' and workers with 'dask worker ADDRESS'") from None
    try:
        slots = max(1, len(client.scheduler_info().get("workers", {})) or jobs)
        pending = list(reversed(tasks))
        flying: dict = {}                 # future -> (index, values, sent)
        times: list[float] = []
        done, total = 0, len(tasks)
        while pending or flying:
            while pending and len(flying) < slots:
                index, values = pending.pop()
                flying[client.submit(_timed_point, setup, index, values, pure=False)] = (index, values,
                                                                                           time.monotonic())
            limit = point_timeout if point_timeout is not None else (
                FIRST_POINT_LIMIT if not times else max(MIN_POINT_LIMIT, 20.0 * statistics.median(times)))
            oldest = min(sent for _, _, sent in flying.values())
            try:
                finished_set, _ = wait(list(flying), timeout=max(0.05, min(oldest + limit - time.monotonic(), 1.0)),
                                       return_when="FIRST_COMPLETED")
            except TimeoutError:        # nothing finished within the wait
                finished_set = set()
            finished = []
            for future in finished_set:
                index, values, sent = flying.pop(future)
                try:
                    point = future.result()
                    times.append(point.wall_time or time.monotonic() - sent)
                except Exception as error:     # a worker lost, a value that does not pickle
                    point = SweepPoint(index, values, "failed", f"E968: the Dask task failed: "
                                                                f"{type(error).__name__}: {error}")
                finished.append(point)
            now = time.monotonic()
            for future, (index, values, sent) in list(flying.items()):
                if now - sent > limit:
                    del flying[future]
                    future.cancel()
                    finished.append(SweepPoint(index, values, "timed out",
                                               f"stopped after {limit:.3g} s (the limit per point; "
                                               "--point-timeout sets it)", wall_time=now - sent))
            for point in finished:
                done += 1
                on_done(point)
                if report is not None:
                    report(point, done, total)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _worker_main(setup: _Setup, connection) -> None:
    """A worker process: run the points it is sent, one at a time, until it is sent None."""
    _worker_signals()
    while True:
        try:
            task = connection.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        index, values = task
        started = time.perf_counter()
        point = _run_point(setup, index, values)
        point = dataclasses.replace(point, wall_time=time.perf_counter() - started)
        try:
            connection.send(point)
        except Exception as error:      # a value that does not pickle: send what can be sent
            connection.send(SweepPoint(index, values, "failed", f"E968: internal error: cannot send the result "
                                                                f"({type(error).__name__}: {error})",
                                       wall_time=point.wall_time))


class _Workers:
    """Worker processes with a time limit per point: a point over its limit is killed with its
    worker, recorded as timed out, and a new worker takes the next point."""

    def __init__(self, setup: _Setup, count: int):
        import multiprocessing

        methods = multiprocessing.get_all_start_methods()
        # fork: a worker starts with the base model already compiled in this process
        self.context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
        self.setup = setup
        self.count = max(count, 1)
        self.idle: list = []
        self.busy: dict = {}            # connection -> (process, index, values, started)
        self.times: list[float] = []

    def _start(self):
        parent, child = self.context.Pipe()
        process = self.context.Process(target=_worker_main, args=(self.setup, child), daemon=True)
        process.start()
        child.close()
        return process, parent

    def limit(self, point_timeout: float | None) -> float:
        if point_timeout is not None:
            return point_timeout
        if not self.times:
            return FIRST_POINT_LIMIT
        return max(MIN_POINT_LIMIT, 20.0 * statistics.median(self.times))

    def run(self, tasks: list, point_timeout, on_done, report) -> None:
        from multiprocessing.connection import wait

        pending = list(reversed(tasks))
        total, done = len(tasks), 0
        self.idle = [self._start() for _ in range(min(self.count, total))]
        while pending or self.busy:
            while self.idle and pending:
                process, connection = self.idle.pop()
                index, values = pending.pop()
                connection.send((index, values))
                self.busy[connection] = (process, index, values, time.monotonic())
            limit = self.limit(point_timeout)
            now = time.monotonic()
            next_deadline = min(started + limit for _, _, _, started in self.busy.values())
            ready = wait(list(self.busy), timeout=max(0.0, min(next_deadline - now, 1.0)))
            finished = []
            for connection in ready:
                process, index, values, started = self.busy.pop(connection)
                try:
                    point = connection.recv()
                    self.idle.append((process, connection))
                    self.times.append(point.wall_time or (time.monotonic() - started))
                except (EOFError, OSError):
                    code = process.exitcode
                    process.join(timeout=1)
                    point = SweepPoint(index, values, "failed",
                                       f"E968: the worker process running this point died (exit code {code})",
                                       wall_time=time.monotonic() - started)
                    self.idle.append(self._start())
                finished.append(point)
            now = time.monotonic()
            for connection, (process, index, values, started) in list(self.busy.items()):
                if now - started > limit:
                    del self.busy[connection]
                    process.kill()
                    process.join(timeout=5)
                    connection.close()
                    finished.append(SweepPoint(
                        index, values, "timed out", f"stopped after {limit:.3g} s (the limit per point; "
                                                    "--point-timeout sets it)", wall_time=now - started))
                    if pending:
                        self.idle.append(self._start())
            for point in finished:
                done += 1
                on_done(point)
                if report is not None:
                    report(point, done, total)

    def stop(self) -> None:
        """Stop every worker now (Ctrl-C, SIGTERM, an error, or the end)."""
        for process, connection in self.idle:
            try:
                connection.send(None)
            except (OSError, ValueError):
                pass
        for process, *_ in list(self.busy.values()):
            process.kill()
        for process, connection in self.idle + [(v[0], k) for k, v in self.busy.items()]:
            process.join(timeout=2)
            if process.is_alive():
                process.kill()
                process.join(timeout=2)
            connection.close()
        self.idle, self.busy = [], {}


def _worker_signals() -> None:
    """In a worker: Ctrl-C (sent to the whole process group) is the parent's to handle, and
    SIGTERM ends the worker at once (the parent kills its workers when it stops)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


class _Progress:
    """Progress on stderr: a tqdm bar on a terminal (points done and failed, rate, ETA); elsewhere
    (CI logs) a plain line at most every :data:`PLAIN_PROGRESS_EVERY` seconds and at the end."""

    def __init__(self, total: int, stream=None, terminal: bool | None = None):
        self.stream = stream or sys.stderr
        self.total = total
        self.counts = {status: 0 for status in STATUSES}
        self.started = time.monotonic()
        self.last = self.started
        if terminal is None:
            try:
                terminal = self.stream.isatty()
            except (AttributeError, ValueError):
                terminal = False
        self.bar = None
        if terminal:
            from tqdm import tqdm

            self.bar = tqdm(total=total, file=self.stream, unit="point", desc="sweep", leave=False,
                            dynamic_ncols=True)

    def _states(self) -> str:
        return ", ".join(f"{n} {status}" for status, n in self.counts.items() if n and status != "ok")

    def __call__(self, point: SweepPoint, done: int, total: int) -> None:
        self.counts[point.status] = self.counts.get(point.status, 0) + 1
        if self.bar is not None:
            self.bar.update(1)
            states = self._states()
            if states:
                self.bar.set_postfix_str(states, refresh=False)
            return
        now = time.monotonic()
        if now - self.last >= PLAIN_PROGRESS_EVERY or done == total:
            self.last = now
            rate = done / max(now - self.started, 1e-9)
            left = (total - done) / rate if rate > 0 else float("nan")
            states = self._states()
            print(f"sweep: {done}/{total} points" + (f" ({states})" if states else "")
                  + f", {rate:.3g} points/s" + (f", about {left:.0f} s left" if done < total else ""),
                  file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _progress_reporter(progress, total: int):
    if callable(progress):
        return progress
    if not progress:
        return None
    return _Progress(total)


# ------------------------------------------------------------------ resuming


def _key(parameters: Mapping, names: Sequence[str]) -> tuple:
    """A point's identity in a results file: its varied parameters' SI values (12 digits)."""
    return tuple(f"{float(parameters[name]):.12g}" for name in names)


def _not_resumable(path, why: str) -> UsageError:
    return _usage("E970", f"cannot resume from '{path}': {why}",
                  hint="it is not the table of this sweep, and bondc leaves it as it is; write to another file "
                       "(-o), or delete it to start again")


def _previous_points(path, result_header: list[str], axes, metrics, motors: bool) -> dict[tuple, SweepPoint]:
    """The points an earlier run of the same sweep wrote to ``path`` (a .csv or .json), by key.

    A file of another sweep (other columns), or one that bondc did not write (a row it would not
    write, a json that is not a sweep's), is not resumed: E970 says so rather than mixing them or
    replacing the file. A csv row cut short (an interruption) is not a point: that point runs again."""
    path = Path(path)
    if not path.exists() or path.stat().st_size == 0:
        return {}
    names = [axis.name for axis in axes]
    found: dict[tuple, SweepPoint] = {}
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or not isinstance(data.get("points", []), list):
                raise ValueError("not the json table of a sweep")
            if [p["name"] for p in data.get("parameters", [])] != names or \
                    [m["name"] for m in data.get("metrics", [])] != [m.name for m in metrics]:
                raise ValueError("other columns")
            for item in data.get("points", []):
                point = SweepPoint(int(item["index"]), tuple(item["values"]), item["status"], item.get("message"),
                                   item.get("path"), dict(item["parameters"]),
                                   {k: _from_json_number(v) for k, v in (item.get("metrics") or {}).items()},
                                   item.get("t_reached"), wall_time=item.get("wall_time"),
                                   motors=tuple(item["motors"]) if "motors" in item else None)
                if point.status not in STATUSES:
                    raise ValueError(f"a point with the status {point.status!r}")
                found[_key(point.parameters, names)] = point
            return found
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError, csv.Error) as error:
        raise _not_resumable(path, str(error) or type(error).__name__) from None
    if not rows:
        return {}
    if rows[0] != result_header:
        raise _usage("E970", f"'{path}' holds the table of another sweep (other columns)",
                     hint="bondc leaves it as it is; write to another file (-o), or delete it to start again")
    width = len(result_header)
    columns = {name: number for number, name in enumerate(result_header)}
    for line, row in enumerate(rows[1:], 2):
        if len(row) < width:
            continue            # a row cut short by an interruption: that point runs again
        if len(row) > width or row[columns["status"]] not in STATUSES or not row[0].isdigit():
            raise _not_resumable(path, f"row {line} is not a row bondc writes")
        try:
            parameters = {axis.name: float(row[1 + i]) for i, axis in enumerate(axes)}
        except ValueError:
            continue            # a row without its values (written by an older bondc): that point runs again
        try:
            metrics_values = {m.name: _from_csv(row[1 + len(axes) + i]) for i, m in enumerate(metrics)}
            wall_time = _from_csv(row[columns["wall_time [s]"]])
        except ValueError:
            raise _not_resumable(path, f"row {line} is not a row bondc writes") from None
        status = row[columns["status"]]
        point = SweepPoint(int(row[0]), (), status, row[columns["message"]] or None, None, parameters,
                           metrics_values if status in ("ok", "incomplete") else {},
                           wall_time=wall_time,
                           motors=tuple(m for m in row[columns["motors"]].split(";") if m) if motors else None)
        found[_key(parameters, names)] = point
    return found


def _check_grid(output, previous: dict[tuple, SweepPoint], keys: Sequence[tuple], axes, samples, seed) -> None:
    """E970 where ``output`` holds finished points that are not points of this sweep: running it
    would rewrite the table without them. A grid that holds every one of them resumes or extends
    the study."""
    grid = set(keys)
    strays = [point for key, point in previous.items() if key not in grid]
    if not strays:
        return
    example = ", ".join(f"{name}={value:.6g}" for name, value in strays[0].parameters.items())
    how = ("the same --samples, --range and --seed" if samples else "the same --vary values, or a grid that "
           "holds them,")
    hint = (f"bondc leaves '{output}' as it is. To resume it give {how} as the run that wrote it; otherwise "
            "write to another file (-o), or delete it to start again")
    if samples and seed is None:
        hint += " (a Latin hypercube without --seed draws other points every run: give --seed)"
    raise _usage("E970", f"'{output}' holds {len(strays)} finished point{'s' if len(strays) != 1 else ''} "
                         f"that {'are' if len(strays) != 1 else 'is'} not in this sweep (e.g. {example}): "
                         "running it would drop them", hint=hint)


def _study(graph, model, experiment, sets, t_end, dt, motors, inertia_ratio=None) -> dict:
    """What the points of a sweep were computed from besides their own values: the text of every
    file the model read, the model and experiment chosen, the --set values, t_end, dt and the motor
    catalogue. A resumed sweep keeps the points of an earlier run only where these are the same."""
    import hashlib

    texts = sorted((name, source.text) for name, source in graph.sources.items()
                   if getattr(source, "path", None) is not None)
    digest = lambda data: hashlib.sha256(data).hexdigest()      # noqa: E731
    catalogue = None
    if motors is not None:
        try:
            catalogue = digest(Path(motors).read_bytes())
        except OSError:
            catalogue = str(motors)
    study = {"model files": digest(json.dumps(texts).encode("utf-8")), "model": model, "experiment": experiment,
             "--set": [item if isinstance(item, str) else getattr(getattr(item, "source", None), "text", repr(item))
                       for item in sets or ()],
             "t_end": t_end, "dt": dt, "motor catalogue": catalogue}
    if motors is not None:
        # the motors column depends on the sizing rules and the inertia-ratio limit: a study made
        # with other rules (before the inertia ratio was one) is not resumed with these
        study["motor rules"] = MOTOR_RULES
        study["--inertia-ratio"] = inertia_ratio
    return study


def study_file(output) -> Path:
    """Beside a sweep's csv table, what its points were computed from (:func:`_study`): ``x.csv.study``."""
    return Path(str(output) + ".study")


def _described(graph, path, experiment, axes, shown_units, converters, metrics) -> dict:
    """What a study's report shows that its csv does not hold: the model's name and file, the
    experiment, and the unit each varied parameter and metric is shown in (``shown = (si - offset) /
    factor``; a metric's is its output's declared unit, ``P_kPa.min`` in kPa). Not part of the study's
    identity: a resume does not compare it."""
    parameters = []
    for axis, unit, converter in zip(axes, shown_units, converters):
        offset = float(converter.to_si(0.0))
        parameters.append({"name": axis.name, "unit": unit, "factor": float(converter.to_si(1.0)) - offset,
                           "offset": offset})
    return {"model name": graph.name, "model file": str(path), "experiment": getattr(experiment, "name", None),
            "parameters": parameters,
            "metrics": [{"name": m.name, "si_unit": m.si_unit, "unit": m.unit, "factor": m.display_factor}
                        for m in metrics]}


def _write_study(output, study: dict, described: dict | None = None) -> None:
    """The record of ``study`` beside the csv; ``described`` under "report" (see :func:`_described`)."""
    from bondc.io import atomic_write_text

    record = dict(study)
    if described is not None:
        record["report"] = described
    atomic_write_text(study_file(output), json.dumps(record, indent=1) + "\n")


def _check_study(output, study: dict) -> None:
    """E970 where the points in ``output`` were computed from another model or other options
    (a table written without the record of its study is resumed as before)."""
    path = Path(output)
    try:
        if path.suffix.lower() == ".json":
            recorded = json.loads(path.read_text(encoding="utf-8")).get("settings", {}).get("study")
        else:
            recorded = json.loads(study_file(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        recorded = None
    if not isinstance(recorded, dict):
        return
    labels = {"model files": "a different text of the model file or its imports", "model": "another --model",
              "experiment": "another --experiment", "--set": "other --set values", "t_end": "another t_end",
              "dt": "another dt", "motor catalogue": "another motor catalogue"}
    changed = [labels.get(key, key) for key in study if json.dumps(recorded.get(key)) != json.dumps(study[key])]
    if changed:
        raise _usage("E970", f"'{output}' holds points of this sweep computed with {', '.join(changed)}: "
                             "resuming would mix them with points of this one",
                     hint="write to another file, or delete it to start again")


def _from_csv(text: str) -> float | None:
    return None if text == "" else float(text)


def _from_json_number(value):
    return float(value) if isinstance(value, str) else value


class _Journal:
    """The csv results file, one row appended and flushed as each point finishes, so that nothing
    finished is lost whatever stops the sweep; at the end the file is rewritten in grid order.

    A file that exists is only appended to (its header and rows were checked by
    :func:`_previous_points` and :func:`_check_grid`): a new file, or an empty one, gets the header."""

    def __init__(self, path, header: list[str]):
        self.path = Path(path)
        fresh = not self.path.exists() or self.path.stat().st_size == 0
        if fresh:
            from bondc.io import atomic_write_text

            buffer = io.StringIO()
            csv.writer(buffer, lineterminator="\n").writerow(header)
            atomic_write_text(self.path, buffer.getvalue())
        self.handle = open(self.path, "a", newline="", encoding="utf-8")
        if not fresh:
            self._end_line()
        self.writer = csv.writer(self.handle, lineterminator="\n")

    def _end_line(self) -> None:
        """A row an interruption cut short stays a separate (ignored) line."""
        with open(self.path, "rb") as check:
            check.seek(0, os.SEEK_END)
            if check.tell():
                check.seek(-1, os.SEEK_END)
                if check.read(1) != b"\n":
                    self.handle.write("\n")

    def add(self, row: list) -> None:
        self.writer.writerow(row)
        self.handle.flush()
        os.fsync(self.handle.fileno())

    def close(self) -> None:
        self.handle.close()
