"""Validation against measured data: simulated signals + a CSV -> metrics, pass/fail, JUnit XML.

- :func:`load_measured_csv` reads a measured-data CSV into ``{"t": time,
  column: values, ...}`` (the time column is the one named ``t`` or ``time``,
  else the first; the same rule as the language's ``csv()``);
- :func:`parse_compare_spec` reads ``OUT=COLUMN[:nrmse=0.05,r2=0.9]``;
- :func:`compare` interpolates each measured column onto the simulated time
  points inside the time range both cover, and computes RMSE, NRMSE (RMSE over
  the range max-min of the measured values compared), the largest absolute
  error and R² (coefficient of determination of the measured values by the
  simulated ones), each checked against the spec's tolerances;
- :func:`junit_xml` / :func:`write_junit` report one test case per signal.

Data problems raise :class:`~bondc.errors.DataError` with these codes:

====== ==============================================================
E950   the CSV file is missing/unreadable, empty, or has no data rows
E951   a cell is not a finite number (line and column given)
E952   time is not strictly increasing (line given)
E953   a column named in a comparison is not in the CSV (did-you-mean)
E954   a signal named in a comparison was not simulated (did-you-mean)
E955   a comparison spec is not ``OUT=COLUMN[:metric=value,...]``
E956   simulated and measured times do not overlap (in >= 2 samples)
E957   a CSV row has the wrong number of cells, or the header repeats a name
E958   a measured column's unit measures another quantity than its signal
====== ==============================================================

>>> spec = parse_compare_spec("x=x_meas:rmse=0.1")
>>> import numpy as np
>>> t = np.linspace(0, 1, 11)
>>> [r] = compare(t, {"x": t}, {"t": t, "x_meas": t + 0.01}, [spec])
>>> r.passed, round(r.rmse, 6)
(True, 0.01)
"""

from __future__ import annotations

import csv
import difflib
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Mapping, Sequence

import numpy as np
import numpy.typing as npt

from bondc.errors import DataError, Diagnostic, UsageError
from bondc.io import atomic_write_text
from bondc.runtime import CsvError, header_cell, open_data
from bondc.source import NO_SPAN, Span
from bondc.numeric import unit_scale
from bondc import codes


if TYPE_CHECKING:
    from bondc.pipeline import PipelineRun

__all__ = [
    "TIME_KEY", "METRICS", "DEFAULT_TOLERANCES", "CompareSpec", "Check", "SignalResult",
    "load_measured_csv", "parse_compare_spec", "compare", "metrics", "junit_xml", "write_junit",
]

#: The key of the time column in what :func:`load_measured_csv` returns.
TIME_KEY = "t"
TIME_NAMES = ("t", "time")

#: Metric -> "max" (the value must not exceed the tolerance) or "min" (must reach it).
METRICS: Mapping[str, str] = {"nrmse": "max", "rmse": "max", "maxabs": "max", "r2": "min"}
DEFAULT_TOLERANCES: Mapping[str, float] = {"nrmse": 0.05}


def _error(code: str, message: str, span: Span = NO_SPAN, hint: str | None = None) -> DataError:
    return DataError(Diagnostic("error", code, message, span, hint=hint))


def _io_error(message: str) -> DataError:
    """E950 for a data file that cannot be read at all: an I/O error (the command exits 2, as for a
    model file that cannot be read), where an empty file or a bad cell is an error of the data (1)."""
    error = _error(codes.E950, message)
    error.io = True
    return error


def _did_you_mean(name: str, choices: Iterable[str]) -> str | None:
    choices = list(choices)
    close = difflib.get_close_matches(name, choices, n=1, cutoff=0.6)
    if not close:
        lowered = {c.lower(): c for c in choices}
        if name.lower() in lowered:
            close = [lowered[name.lower()]]
    if close:
        return f"did you mean '{close[0]}'?"
    if choices:
        return "available: " + ", ".join(f"'{c}'" for c in choices)
    return None


# ---------------------------------------------------------------- measured data

def _cell_span(path: str, line_number: int, line: str, index: int) -> Span:
    """The span of cell ``index`` of a CSV line (exact when the line has no quotes)."""
    if '"' in line:
        return Span(path, line_number, 1, line_number, len(line) + 1)
    column = 1
    for i, cell in enumerate(line.split(",")):
        if i == index:
            return Span(path, line_number, column, line_number, column + max(len(cell), 1))
        column += len(cell) + 1
    return Span(path, line_number, 1, line_number, len(line) + 1)


class MeasuredData(dict):
    """``{"t": time, column: values}`` in SI, and ``units``: the unit each column's header gave (or None)."""

    def __init__(self, *args):
        super().__init__(*args)
        self.units: dict[str, str | None] = {}


def load_measured_csv(path: str | Path, columns: Iterable[str] = ()) -> dict[str, np.ndarray]:
    """Measured data: ``{"t": time, column: values, ...}``, every array float and the same length.

    A header cell may give the column's unit in brackets (``t [ms]``, ``P [bar]``): its values are
    converted to SI, as every simulated signal is; a column without a unit is taken as SI.

    The first line is the header. The time column is the one named ``t`` or
    ``time`` (any case), else the first; it must increase strictly. Blank lines
    and lines starting with ``#`` are skipped. ``columns`` names columns that
    must be present. Raises :class:`DataError` (E950-E953, E957) on bad data.
    """
    path = Path(path)
    name = str(path)
    try:
        with open_data(path, encoding="utf-8-sig") as handle:
            text = handle.read()
    except FileNotFoundError:
        raise _io_error(f"measured data file '{name}' does not exist") from None
    except CsvError as exc:
        raise _io_error(f"cannot read measured data file '{name}': {str(exc).rpartition(': ')[2]}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _io_error(f"cannot read measured data file '{name}': {exc}") from None

    lines = [(number, line) for number, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise _error(codes.E950, f"measured data file '{name}' is empty",
                     hint="expected a header line such as 't,omega' and then rows of numbers")
    header_number, header_line = lines[0]
    header_cells = [header_cell(cell) for cell in next(csv.reader([header_line]))]
    header = [cell_name for cell_name, _ in header_cells]
    scales = []
    for index, (cell, unit) in enumerate(header_cells):
        try:
            scales.append(unit_scale(unit))
        except ValueError:
            raise _error(codes.E957, f"column '{cell}' of '{name}' names an unknown unit [{unit}]",
                         _cell_span(name, header_number, header_line, index),
                         hint="a header gives a column's unit in brackets, e.g. 'P [bar]'; a column without one "
                              "is SI") from None
    for index, cell in enumerate(header):
        if not cell:
            raise _error(codes.E957, f"column {index + 1} of the header of '{name}' has no name",
                         _cell_span(name, header_number, header_line, index))
        if cell in header[:index]:
            raise _error(codes.E957, f"the header of '{name}' names column '{cell}' twice",
                         _cell_span(name, header_number, header_line, index))
    if len(lines) == 1:
        raise _error(codes.E950, f"measured data file '{name}' has a header but no data rows",
                     Span(name, header_number, 1, header_number, len(header_line) + 1))

    time_index = 0
    for candidate in TIME_NAMES:
        matches = [i for i, cell in enumerate(header) if cell.lower() == candidate]
        if matches:
            time_index = matches[0]
            break

    values = np.empty((len(lines) - 1, len(header)))
    for row, (number, line) in enumerate(lines[1:]):
        cells = next(csv.reader([line]))
        if len(cells) != len(header):
            raise _error(codes.E957, f"line {number} of '{name}' has {len(cells)} cells; the header has {len(header)}",
                         Span(name, number, 1, number, len(line) + 1))
        for index, cell in enumerate(cells):
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                shown = cell.strip()
                what = f"'{shown}' is not a number" if shown else "the cell is empty"
                raise _error(codes.E951, f"line {number} of '{name}', column '{header[index]}': {what}",
                             _cell_span(name, number, line, index))
            values[row, index] = value

    values = values * np.asarray(scales)       # every column in SI, as the simulation
    time = values[:, time_index]
    steps = np.diff(time)
    if np.any(steps <= 0):
        row = int(np.argmax(steps <= 0)) + 1
        number, line = lines[1 + row]
        previous = lines[row][0]
        raise _error(
            codes.E952,
            f"time must increase strictly: line {number} of '{name}' has {header[time_index]} = "
            f"{time[row]:g}, not after {time[row - 1]:g} on line {previous}",
            _cell_span(name, number, line, time_index),
            hint=f"the time column is '{header[time_index]}'"
                 + ("" if header[time_index].lower() in TIME_NAMES else
                    " (the first column, as no column is named 't' or 'time')"))

    data = MeasuredData({TIME_KEY: time.copy()})
    for index, cell in enumerate(header):
        if index != time_index:
            data[cell] = values[:, index].copy()
            data.units[cell] = header_cells[index][1]
    for column in columns:
        if column not in data:
            raise _error(codes.E953, f"measured data file '{name}' has no column '{column}'",
                         hint=_did_you_mean(column, [c for c in data if c != TIME_KEY]))
    return data


# ---------------------------------------------------------------- comparison specs

@dataclass(frozen=True)
class CompareSpec:
    """One comparison: simulated signal ``output`` against measured ``column``, within ``tolerances``."""

    output: str
    column: str
    tolerances: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_TOLERANCES))
    text: str = ""

    def __str__(self) -> str:
        return self.text or f"{self.output}={self.column}"


_SPEC_SYNTAX = "write OUT=COLUMN, optionally with tolerances: OUT=COLUMN:nrmse=0.05,r2=0.95"


def parse_compare_spec(text: str) -> CompareSpec:
    """``OUT=COLUMN[:metric=value,...]`` -> :class:`CompareSpec` (default ``nrmse=0.05``).

    Metrics: ``nrmse``, ``rmse``, ``maxabs`` (upper bounds, in the signal's
    units for rmse/maxabs) and ``r2`` (a lower bound).

    >>> parse_compare_spec("torque = tau_meas : rmse=0.2, r2=0.9").tolerances
    {'rmse': 0.2, 'r2': 0.9}
    """
    raw = text
    text = text.strip()
    head, colon, tail = text.partition(":")
    output, equals, column = head.partition("=")
    output, column = output.strip(), column.strip()
    if not equals or not output or not column:
        raise _error(codes.E955, f"cannot read the comparison '{raw}'", hint=_SPEC_SYNTAX)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*", output):
        raise _error(codes.E955, f"'{output}' in the comparison '{raw}' is not a signal name", hint=_SPEC_SYNTAX)
    if "=" in column:
        raise _error(codes.E955, f"the comparison '{raw}' has more than one '=' before its tolerances",
                     hint=_SPEC_SYNTAX)
    tolerances: dict[str, float] = {}
    if colon:
        if not tail.strip():
            raise _error(codes.E955, f"the comparison '{raw}' has ':' but no tolerances", hint=_SPEC_SYNTAX)
        for item in tail.split(","):
            metric, eq, value_text = item.partition("=")
            metric, value_text = metric.strip().lower(), value_text.strip()
            if not eq or not metric or not value_text:
                raise _error(codes.E955, f"cannot read the tolerance '{item.strip()}' in '{raw}'",
                             hint="a tolerance is METRIC=NUMBER, e.g. nrmse=0.05")
            if metric not in METRICS:
                raise _error(codes.E955, f"unknown metric '{metric}' in '{raw}'",
                             hint=_did_you_mean(metric, METRICS) or "metrics: " + ", ".join(METRICS))
            if metric in tolerances:
                raise _error(codes.E955, f"the comparison '{raw}' gives '{metric}' twice")
            try:
                value = float(value_text)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise _error(codes.E955, f"tolerance {metric}='{value_text}' in '{raw}' is not a number")
            if METRICS[metric] == "max" and value < 0:
                raise _error(codes.E955, f"tolerance {metric}={value_text} in '{raw}' is negative",
                             hint=f"{metric} is an upper bound on an error, so it is >= 0")
            if metric == "r2" and value > 1:
                raise _error(codes.E955, f"tolerance r2={value_text} in '{raw}' is above 1, which no fit reaches")
            tolerances[metric] = value
    return CompareSpec(output, column, tolerances or dict(DEFAULT_TOLERANCES), text)


# ---------------------------------------------------------------- metrics

@dataclass(frozen=True)
class Check:
    """One tolerance check of one signal."""

    metric: str
    value: float
    limit: float
    passed: bool

    def describe(self) -> str:
        relation = "<=" if METRICS[self.metric] == "max" else ">="
        verdict = "ok" if self.passed else "FAILED"
        return f"{self.metric} = {self.value:.6g} (required {relation} {self.limit:g}): {verdict}"


@dataclass(frozen=True)
class SignalResult:
    """The comparison of one simulated signal with one measured column."""

    spec: CompareSpec
    n_samples: int
    t_start: float
    t_end: float
    rmse: float
    nrmse: float
    maxabs: float
    r2: float
    checks: tuple[Check, ...]
    t: np.ndarray = field(repr=False, compare=False)
    simulated: np.ndarray = field(repr=False, compare=False)
    measured: np.ndarray = field(repr=False, compare=False)

    @property
    def output(self) -> str:
        return self.spec.output

    @property
    def column(self) -> str:
        return self.spec.column

    @property
    def name(self) -> str:
        return f"{self.spec.output}={self.spec.column}"

    @property
    def passed(self) -> bool:
        return all(check.passed for check in self.checks)

    @property
    def metrics(self) -> dict[str, float]:
        return {"rmse": self.rmse, "nrmse": self.nrmse, "maxabs": self.maxabs, "r2": self.r2}

    def summary(self) -> str:
        lines = [f"{self.name}: {'passed' if self.passed else 'FAILED'} "
                 f"({self.n_samples} samples, t = {self.t_start:g} .. {self.t_end:g} s)"]
        lines += [f"  rmse = {self.rmse:.6g}, nrmse = {self.nrmse:.6g}, "
                  f"maxabs = {self.maxabs:.6g}, r2 = {self.r2:.6g}"]
        lines += ["  " + check.describe() for check in self.checks]
        return "\n".join(lines)


def metrics(simulated: np.ndarray, measured: np.ndarray) -> dict[str, float]:
    """RMSE, NRMSE, max abs error and R² of ``simulated`` against ``measured`` (same points).

    NRMSE divides by the measured range (max - min); for a constant measured
    signal it is 0 when the error is 0, else infinite. R² is
    1 - SS_res/SS_tot; for a constant measured signal it is 1 when the error
    is 0, else nan (undefined, so an r2 tolerance fails).

    >>> m = metrics(np.array([1.0, 2.0, 4.0]), np.array([1.0, 3.0, 3.0]))
    >>> round(m["rmse"], 6), round(m["nrmse"], 6), m["maxabs"], m["r2"]
    (0.816497, 0.408248, 1.0, 0.25)
    """
    simulated = np.asarray(simulated, dtype=float)
    measured = np.asarray(measured, dtype=float)
    error = simulated - measured
    rmse = float(np.sqrt(np.mean(error ** 2)))
    span = float(np.max(measured) - np.min(measured))
    if span > 0:
        nrmse = rmse / span
    else:
        nrmse = 0.0 if rmse == 0 else math.inf
    ss_res = float(np.sum(error ** 2))
    ss_tot = float(np.sum((measured - np.mean(measured)) ** 2))
    if ss_tot > 0:
        r2 = 1.0 - ss_res / ss_tot
    else:
        r2 = 1.0 if ss_res == 0 else math.nan
    return {"rmse": rmse, "nrmse": nrmse, "maxabs": float(np.max(np.abs(error))), "r2": r2}


def _passes(metric: str, value: float, limit: float) -> bool:
    if math.isnan(value):
        return False
    return value <= limit if METRICS[metric] == "max" else value >= limit


def compare(sim_t: npt.ArrayLike, sim_values: Mapping[str, npt.ArrayLike],
            measured: Mapping[str, np.ndarray], specs: Iterable[CompareSpec]) -> list[SignalResult]:
    """Compare simulated signals with measured columns; one :class:`SignalResult` per spec.

    The measured column is linearly interpolated onto the simulated time points
    that lie inside the time range both cover (``measured["t"]`` is its time).
    Raises :class:`DataError`: E953/E954 for unknown names, E956 when fewer
    than two simulated points fall in the common time range.
    """
    times = np.asarray(sim_t, dtype=float)
    if TIME_KEY not in measured:
        raise _error(codes.E953, "the measured data has no time column 't'")
    meas_t = np.asarray(measured[TIME_KEY], dtype=float)
    results = []
    for spec in specs:
        if spec.output not in sim_values:
            raise _error(codes.E954, f"'{spec.output}' in the comparison '{spec}' is not a simulated signal",
                         hint=_did_you_mean(spec.output, sim_values))
        if spec.column not in measured or spec.column == TIME_KEY:
            raise _error(codes.E953, f"the measured data has no column '{spec.column}' (comparison '{spec}')",
                         hint=_did_you_mean(spec.column, [c for c in measured if c != TIME_KEY]))
        simulated = np.asarray(sim_values[spec.output], dtype=float)
        if simulated.shape != times.shape:
            raise ValueError(f"signal '{spec.output}' has {simulated.size} values for {times.size} time points")
        low, high = max(times[0], meas_t[0]), min(times[-1], meas_t[-1])
        inside = (times >= low) & (times <= high)
        if high < low or np.count_nonzero(inside) < 2:
            raise _error(
                codes.E956,
                f"comparison '{spec}': the simulation covers t = {times[0]:g} .. {times[-1]:g} s and the "
                f"measurement t = {meas_t[0]:g} .. {meas_t[-1]:g} s; they share "
                f"{'no time' if high < low else 'fewer than two simulated samples'}",
                hint="check the experiment's t_end and the time column (seconds) of the data")
        t = times[inside]
        sim = simulated[inside]
        meas = np.interp(t, meas_t, np.asarray(measured[spec.column], dtype=float))
        values = metrics(sim, meas)
        checks = tuple(Check(metric, values[metric], limit, _passes(metric, values[metric], limit))
                       for metric, limit in spec.tolerances.items())
        results.append(SignalResult(spec, int(t.size), float(t[0]), float(t[-1]),
                                    values["rmse"], values["nrmse"], values["maxabs"], values["r2"],
                                    checks, t, sim, meas))
    return results


# ---------------------------------------------------------------- JUnit

_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def _xml_safe(element: ET.Element) -> ET.Element:
    """Characters XML 1.0 cannot hold (control characters from a column name, say), in every
    attribute and text of ``element``'s tree, written as visible escapes (``\\x01``)."""
    clean = lambda text: _NOT_XML.sub(lambda match: f"\\x{ord(match.group()):02x}", text)
    for node in element.iter():
        node.attrib.update({key: clean(value) for key, value in node.attrib.items()})
        if node.text:
            node.text = clean(node.text)
    return element


def junit_xml(results: Sequence[SignalResult], suite_name: str) -> str:
    """A JUnit XML report: one ``<testcase>`` per signal, ``<failure>`` with the numbers when it fails.

    Every name and message is XML-safe (:func:`_xml_safe`), so any CI can parse it.
    """
    failures = sum(1 for r in results if not r.passed)
    suites = ET.Element("testsuites", {"name": suite_name, "tests": str(len(results)),
                                       "failures": str(failures), "errors": "0"})
    suite = ET.SubElement(suites, "testsuite", {
        "name": suite_name, "tests": str(len(results)), "failures": str(failures),
        "errors": "0", "skipped": "0", "time": "0"})
    for result in results:
        case = ET.SubElement(suite, "testcase", {"classname": suite_name, "name": result.name, "time": "0"})
        properties = ET.SubElement(case, "properties")
        for key, value in result.metrics.items():
            ET.SubElement(properties, "property", {"name": key, "value": f"{value:.6g}"})
        if not result.passed:
            failed = [c for c in result.checks if not c.passed]
            failure = ET.SubElement(case, "failure", {
                "type": "ToleranceExceeded",
                "message": "; ".join(c.describe() for c in failed)})
            failure.text = result.summary()
        output = ET.SubElement(case, "system-out")
        output.text = result.summary()
    ET.indent(_xml_safe(suites))
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(suites, encoding="unicode") + "\n"


def write_junit(results: Sequence[SignalResult], suite_name: str, path: str | Path) -> None:
    """Write :func:`junit_xml` to ``path`` atomically."""
    atomic_write_text(path, junit_xml(results, suite_name))


# ---------------------------------------------------------------- a model's signals against the data

def simulated_signals(result) -> dict[str, np.ndarray]:
    """Every simulated signal by name: bond variables, inputs and other variables, states, outputs (SI)."""
    signals: dict[str, np.ndarray] = {}
    for group in (result.bonds, result.variables, result.states, result.outputs):
        signals.update(group)
    return signals


def check_quantity(graph, spec: CompareSpec, unit: str | None) -> None:
    """E958 where the measured column's unit and the signal's measure different quantities (a force
    compared with a column in kg); nothing where either is unknown."""
    from bondc.units import compatible, unit_of

    output = graph.outputs.get(spec.output)
    declared = output.unit_text if output is not None and output.unit_text else \
        (getattr(graph, "si_units", None) or {}).get(spec.output)
    if unit is None or declared is None:
        return
    measured, simulated = unit_of(unit), unit_of(declared)
    if measured is None or simulated is None or compatible(measured, simulated):
        return
    raise DataError(Diagnostic(
        "error", codes.E958, f"comparison '{spec}': column '{spec.column}' is in [{unit}] and '{spec.output}' in "
                         f"[{declared}]: they measure different quantities ({measured.dimension_text()} and "
                         f"{simulated.dimension_text()})",
        hint="compare the signal with the column that measures it, or fix the unit in the column's header"))


def signal_unit(graph, name: str) -> tuple[str | None, float]:
    """The display unit of a signal and the factor SI value / display value (outputs only)."""
    output = graph.outputs.get(name)
    if output is not None and output.unit_text:
        return output.unit_text, output.display_factor
    return None, 1.0


# ---------------------------------------------------------------- a run against measured data

def signal_json(result: SignalResult, unit: str | None = None) -> dict:
    """One compared signal for ``--json``: its output and column, pass or fail, each metric and each
    check (metric, value, limit, passed); RMSE and the largest error in ``unit`` (the output's)."""
    return {"name": result.name, "output": result.output, "column": result.column, "passed": result.passed,
            "unit": unit, "samples": result.n_samples, "t_start": result.t_start, "t_end": result.t_end,
            "rmse": result.rmse, "nrmse": result.nrmse, "maxabs": result.maxabs, "r2": result.r2,
            "checks": [{"metric": check.metric, "value": check.value, "limit": check.limit,
                        "passed": check.passed} for check in result.checks]}


def measured_data(data, compare_specs) -> tuple[list[CompareSpec], dict[str, np.ndarray] | None]:
    specs = [spec if isinstance(spec, CompareSpec) else parse_compare_spec(spec) for spec in compare_specs or ()]
    if data is None and specs:
        raise UsageError(Diagnostic("error", codes.E001, "--compare needs measured data",
                                    hint="give the measured CSV with --data FILE"))
    if data is not None and not specs:
        raise UsageError(Diagnostic("error", codes.E001, "--data needs at least one comparison",
                                    hint="say which simulated signal each measured column is: --compare OUT=COLUMN"))
    if data is None:
        return [], None
    return specs, load_measured_csv(data, columns=[spec.column for spec in specs])


def unit_warnings(run: PipelineRun, measured, specs: Iterable[CompareSpec]) -> list[Diagnostic]:
    """W954: a measured column without a unit compared with an output declared in a non-SI unit —
    the column is taken as SI, which the engineer may not have meant."""
    units = getattr(measured, "units", {})
    found = []
    for spec in specs:
        output = run.graph.outputs.get(spec.output)
        if output is None or not output.unit_text or units.get(spec.column) is not None:
            continue
        if abs((output.display_factor or 1.0) - 1.0) > 1e-12:
            found.append(Diagnostic(
                "warning", codes.W954, f"measured column '{spec.column}' has no unit: it is taken as SI, while output "
                                   f"'{spec.output}' is declared in [{output.unit_text}]",
                hint=f"if the data is in {output.unit_text}, write the header as '{spec.column} "
                     f"[{output.unit_text}]'"))
    return found


def compare_run(run: PipelineRun, measured: Mapping[str, np.ndarray],
                specs: Iterable[CompareSpec]) -> list[SignalResult]:
    """:func:`~bondc.analysis.validate.compare` the run's signals with the measured columns, each pair
    in the signal's display unit (an output declared ``[mm]`` is compared in millimetres): its RMSE,
    largest error and the ``rmse``/``maxabs`` tolerances are in that unit, as the terminal table,
    the JUnit file and the report show them (NRMSE and R² do not depend on the unit). The
    comparison is at the measured samples the run covers (:func:`_at_measured_times`)."""
    if run.result is None:
        raise UsageError(Diagnostic("error", codes.E801, "no end time for the simulation",
                                    hint="give --t-end, or set t_end in the experiment"))
    t, signals = _at_measured_times(run, measured)
    results = []
    for spec in specs:
        check_quantity(run.graph, spec, getattr(measured, "units", {}).get(spec.column))
        _, factor = signal_unit(run.graph, spec.output)
        if spec.output not in signals or spec.column not in measured or factor == 1.0:
            results += compare(t, signals, measured, [spec])     # (its own errors, if any)
            continue
        shown = {spec.output: np.asarray(signals[spec.output], dtype=float) / factor}
        columns = {TIME_KEY: measured[TIME_KEY], spec.column: np.asarray(measured[spec.column], dtype=float) / factor}
        results += compare(t, shown, columns, [spec])
    return results


def _at_measured_times(run: PipelineRun, measured: Mapping[str, np.ndarray]) -> tuple[np.ndarray, dict]:
    """(times, signals) to compare at: the measured samples the run covers, the model evaluated there
    (the run repeated with those report times, from the solver's own interpolant), so that a
    measurement sampled more coarsely than the solver steps is compared sample by sample and not
    interpolated between them. The run's own points where that is not possible (fewer than two
    samples inside the run, more than a run may record, or a repeat that does not reach as far)."""
    from bondc.analysis.energy import repeat_run
    from bondc.runtime import MAX_POINTS

    result = run.result
    own = (np.asarray(result.t, dtype=float), simulated_signals(result))
    times = np.asarray(measured.get(TIME_KEY, ()), dtype=float)
    if not len(own[0]) or times.size < 2:
        return own
    inside = times[(times >= own[0][0]) & (times <= own[0][-1])]
    if inside.size < 2 or inside.size > MAX_POINTS:
        return own
    again = repeat_run(run.state_space, result, t_eval=inside)
    reached = np.asarray(again.t, dtype=float)
    if reached.size != inside.size or not np.array_equal(reached, inside):
        return own
    return reached, simulated_signals(again)


def validation_table(results: Sequence[SignalResult], units: Mapping[str, str | None] | None = None) -> str:
    """The metrics of every compared signal as a text table, then what failed; ``units``: each
    signal's display unit (RMSE and max |err| are in it; "SI" where it has none)."""
    units = units or {}
    header = ("signal", "measured", "unit", "samples", "RMSE", "NRMSE", "max |err|", "R²", "result")
    rows = [(r.output, r.column, units.get(r.output) or "SI", str(r.n_samples), f"{r.rmse:.4g}", f"{r.nrmse:.4g}",
             f"{r.maxabs:.4g}", f"{r.r2:.4g}", "pass" if r.passed else "FAIL") for r in results]
    widths = [max(len(cell) for cell in column) for column in zip(header, *rows)]
    numeric = {3, 4, 5, 6, 7}

    def line(cells):
        return "  ".join(cell.rjust(w) if i in numeric else cell.ljust(w)
                         for i, (cell, w) in enumerate(zip(cells, widths))).rstrip()

    lines = [line(header), line(["-" * w for w in widths])] + [line(row) for row in rows]
    for result in results:
        for check in result.checks:
            if not check.passed:
                lines.append(f"{result.name}: {check.describe()}")
    failed = sum(not r.passed for r in results)
    lines.append(f"{len(results) - failed} of {len(results)} signal{'s' if len(results) != 1 else ''} passed")
    return "\n".join(lines)
