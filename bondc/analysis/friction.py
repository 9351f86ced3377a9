"""Friction identification: steady-velocity test rows to the power law C = a*|v|^b.

Takes measured rows of (velocity [m/s], motor torque [N*m], chamber pressure
[Pa]) -- a CSV file via :func:`load_friction_csv`, or arrays -- and returns a
:class:`FrictionFit`: one power law per direction of motion. This is the
paper's identification (eqs. 17-20): at constant velocity the mass does not
accelerate, so the cylinder friction is what is left of the motor's thrust,
the piston force and the weight::

    F = 2*pi/l * tau + (P - P_atm)*A - M*g     (eq. 17)
    C = F / v                                   (eq. 18)
    C = a * |v|^b, fitted separately for v > 0 (up) and v < 0 (down)   (eqs. 19-20)

Two readings of eq. 17 are fixed here, following MODEL-NOTES.md:

* The paper writes ``P*A_e``, but A_e is the valve's effective area; the
  force is the pressure on the piston's rod-side annulus, so ``area`` is A_r.
* The pressure in the data is **absolute**, and the force the air puts on the
  mass is the gauge part ``(P - P_atm)*A``: the head side is vented and the
  atmosphere also pushes on the rod end (the notes' piston force). ``patm``
  defaults to 101325 Pa; pass ``patm=0`` for data logged as gauge pressure.

Signs: velocity and torque are positive upward (torque > 0 pushes the mass
up), so friction opposes motion and C = F/v is positive in both directions.

The fit is least squares on ln C = ln a + b*ln|v| (exact for exact data and
a good start), refined by nonlinear least squares on C itself, which is the
quantity the model uses; R^2 and the residuals are on C.

Every problem with the data is a :class:`~bondc.errors.DataError` with one
diagnostic per problem (codes E901-E915) that points at the CSV line.

>>> import numpy as np
>>> v = np.array([0.02, 0.05, 0.1, 0.2, -0.02, -0.05, -0.1, -0.2])
>>> C = np.where(v > 0, 706.59 * abs(v) ** -0.73, 435.61 * abs(v) ** -0.66)
>>> P = np.full(v.shape, 224e3)
>>> tau = 5e-3 / (2 * np.pi) * (C * v - (P - 101325) * 2.63e-3 + 31.7 * 9.81)
>>> fit = fit_friction({"v": v, "tau": tau, "P": P}, lead=5e-3, area=2.63e-3, mass=31.7)
>>> round(fit.up.a, 2), round(fit.up.b, 3), round(fit.down.a, 2), round(fit.down.b, 3)
(706.59, -0.73, 435.61, -0.66)
"""

from __future__ import annotations

import csv
import difflib
import json as _json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from bondc import ast, units
from bondc.errors import DataError, Diagnostic, render_all
from bondc.source import NO_SPAN, Source, Span
from bondc import codes

# The flagship's Table 3 values: the defaults of `bondc fit-friction`.
DEFAULT_LEAD = 5.0e-3  # m per revolution
DEFAULT_AREA = 2.63e-3  # m^2, rod-side annulus A_r
DEFAULT_MASS = 31.7  # kg
DEFAULT_GRAVITY = 9.81  # m/s^2
DEFAULT_PATM = 101325.0  # Pa

MIN_ROWS_PER_DIRECTION = 3
# A file with thousands of bad cells should not print thousands of diagnostics.
MAX_DIAGNOSTICS_PER_CODE = 20

EXIT_OK, EXIT_ERRORS, EXIT_USAGE = 0, 1, 2


# ====================================================================== tables
# Shared with bondc.analysis.motors: a CSV file read into cells that know
# where they are, so every data diagnostic can point at its line and column.

@dataclass(frozen=True)
class Cell:
    """One CSV cell: its text (surrounding blanks removed) and where it is."""

    text: str
    span: Span = NO_SPAN


@dataclass(frozen=True)
class Table:
    """A CSV file: the header row and the data rows; comments and blank lines dropped.

    ``header_span`` and ``row_spans`` cover whole lines, for problems that
    are about a row rather than one cell.
    """

    source: Source
    header: tuple[Cell, ...]
    rows: tuple[tuple[Cell, ...], ...]
    header_span: Span = NO_SPAN
    row_spans: tuple[Span, ...] = ()


def _cell_bounds(line: str) -> list[tuple[int, int]]:
    """(start, end) of each comma-separated field, commas inside quotes ignored."""
    bounds, start, quoted = [], 0, False
    for index, char in enumerate(line):
        if char == '"':
            quoted = not quoted
        elif char == "," and not quoted:
            bounds.append((start, index))
            start = index + 1
    bounds.append((start, len(line)))
    return bounds


def _row_cells(source: Source, line_start: int, line: str) -> tuple[Cell, ...]:
    try:
        values = next(csv.reader([line], skipinitialspace=True), [])
    except csv.Error:  # e.g. a NUL byte: keep the raw fields, the number check reports them
        values = line.split(",")
    bounds = _cell_bounds(line)
    if len(bounds) != len(values):  # odd quoting: point at the whole line
        bounds = [(0, len(line))] * len(values)
    cells = []
    for value, (start, end) in zip(values, bounds):
        raw = line[start:end]
        lead = len(raw) - len(raw.lstrip())
        trail = len(raw) - len(raw.rstrip())
        span = source.span(line_start + start + lead, line_start + max(end - trail, start + lead))
        cells.append(Cell(value.strip(), span))
    return tuple(cells)


def read_csv_table(path: str | Path) -> Table:
    """Read a CSV file into a :class:`Table`; lines starting with ``#`` are comments.

    Raises DataError E905 if the file cannot be read and E901 if it has no
    header or no data rows.
    """
    path = Path(path)
    from bondc.runtime import CsvError, open_data

    try:
        with open_data(path, encoding="utf-8-sig") as handle:
            text = handle.read()
    except CsvError as error:
        raise DataError(Diagnostic("error", codes.E905, f"cannot read '{path}': "
                                                    f"{str(error).rpartition(': ')[2]}")) from None
    except (OSError, UnicodeDecodeError) as error:
        reason = error.strerror if isinstance(error, OSError) and error.strerror else str(error)
        raise DataError(Diagnostic("error", codes.E905, f"cannot read '{path}': {reason}")) from None
    source = Source(str(path), text, path)
    header: tuple[Cell, ...] = ()
    header_span = NO_SPAN
    rows: list[tuple[Cell, ...]] = []
    row_spans: list[Span] = []
    offset = 0
    for raw_line in text.split("\n"):
        line = raw_line.rstrip("\r")
        line_start = offset
        offset += len(raw_line) + 1
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        cells = _row_cells(source, line_start, line)
        span = source.span(line_start, line_start + len(line))
        if not header:
            header, header_span = cells, span
        else:
            rows.append(cells)
            row_spans.append(span)
    if not header:
        raise DataError(Diagnostic("error", codes.E901, "the file is empty: no header row and no data",
                                   Span(str(path), 0, 0, 0, 0),
                                   hint="the first line that is not a '#' comment names the columns"))
    if not rows:
        raise DataError(Diagnostic("error", codes.E901, "the file has a header but no data rows", header_span))
    return Table(source, header, tuple(rows), header_span, tuple(row_spans))


# ------------------------------------------------------------ header units

_UNIT_TOKEN = re.compile(r"\s*([*/])?\s*([^\s*/^]+)\s*(?:\^\s*\(?\s*(-?\d+(?:/\d+)?)\s*\)?)?\s*")


def parse_unit_text(text: str) -> ast.Unit | None:
    """``"N*m/rad"`` -> an ast.Unit with factors N^1 m^1 rad^-1; None if malformed.

    Only products, quotients and integer or fraction powers: enough for a CSV
    header such as ``velocity [mm/s]``.
    """
    from fractions import Fraction

    text = text.replace("·", "*").strip()
    factors, position = [], 0
    while position < len(text):
        match = _UNIT_TOKEN.match(text, position)
        if not match or match.end() == position:
            return None
        operator, name, exponent = match.groups()
        if (operator is None) != (position == 0):
            return None
        power = Fraction(exponent) if exponent else Fraction(1)
        factors.append(ast.UnitFactor(name, -power if operator == "/" else power))
        position = match.end()
    return ast.Unit(factors=tuple(factors), text=text) if factors else None


_HEADER = re.compile(r"^\s*(.*?)\s*(?:[\[(]\s*(.*?)\s*[\])])?\s*$")


def split_header(text: str) -> tuple[str, str | None]:
    """``"Velocity [m/s]"`` -> ``("velocity", "m/s")``; the name is lower-cased."""
    match = _HEADER.match(text)         # (every text matches: both parts are optional)
    name, unit_text = (match.group(1), match.group(2)) if match else (text, None)
    return name.strip().lower(), (unit_text or None)


@dataclass(frozen=True)
class Quantity:
    """A column a reader needs: its names, and the SI unit its values must be in."""

    name: str
    aliases: tuple[str, ...]
    si_unit: str


def _unit_scale(quantity: Quantity, unit_text: str | None, span: Span) -> tuple[float, list[Diagnostic]]:
    """The factor that takes a column's values to SI, from the unit in its header."""
    if unit_text is None:
        return 1.0, []
    unit = parse_unit_text(unit_text)
    if unit is None:
        return 1.0, [Diagnostic("error", codes.E906, f"cannot read the unit '{unit_text}' of the {quantity.name} column",
                                span, hint=f"write it like '{quantity.si_unit}'")]
    si, problems = units.resolve(unit)
    if si is None:
        hints = [d.hint for d in problems if d.hint]
        return 1.0, [Diagnostic("error", codes.E906, f"unknown unit '{unit_text}' in the {quantity.name} column",
                                span, hint=hints[0] if hints else f"write it like '{quantity.si_unit}'")]
    si_unit = parse_unit_text(quantity.si_unit)
    expected = units.resolve(si_unit)[0] if si_unit is not None else None
    if expected is None:
        raise ValueError(f"a quantity's SI unit that bondc cannot read: '{quantity.si_unit}'")
    if not units.compatible(si, expected):
        return 1.0, [Diagnostic("error", codes.E906,
                                f"the {quantity.name} column is in '{unit_text}' ({si.dimension_text()}), "
                                f"which is not a {quantity.name}", span,
                                hint=f"expected a unit like '{quantity.si_unit}' ({expected.dimension_text()})")]
    return si.to_si(1.0), []


def _suggestion(aliases: Sequence[str], names: Sequence[str]) -> tuple[int, str] | None:
    """(index into ``names``, alias) of the header name that most looks like an alias, if any does."""
    best, best_score = None, 0.0
    for index, name in enumerate(names):
        if not name:
            continue
        for alias in aliases:
            lower = alias.lower()
            score = difflib.SequenceMatcher(None, name, lower).ratio()
            if len(name) >= 2 and lower.startswith(name) or len(lower) >= 2 and name.startswith(lower):
                score = max(score, 0.8)
            if score > best_score:
                best, best_score = (index, alias), score
    return best if best_score >= 0.5 else None


def resolve_columns(header: Sequence[Cell], quantities: Sequence[Quantity], where: Span
                    ) -> tuple[dict[str, tuple[int, float]], list[Diagnostic]]:
    """Find each quantity's column (case-insensitive, unit in brackets allowed).

    Returns ``{quantity name: (column index, scale to SI)}`` and E902 / E906
    diagnostics for missing, ambiguous or wrongly-united columns.
    """
    names = [split_header(cell.text) for cell in header]
    found: dict[str, tuple[int, float]] = {}
    diagnostics: list[Diagnostic] = []
    claimed = set()
    for quantity in quantities:
        lowered = {alias.lower() for alias in quantity.aliases}
        matches = [index for index, (name, _) in enumerate(names) if name in lowered]
        if len(matches) > 1:
            shown = " and ".join(f"'{header[i].text}'" for i in matches)
            diagnostics.append(Diagnostic(
                "error", codes.E902, f"two columns hold the {quantity.name}: {shown}", header[matches[1]].span,
                hint="keep one of them, or rename the other"))
            continue
        if matches:
            index = matches[0]
            claimed.add(index)
            scale, problems = _unit_scale(quantity, names[index][1], header[index].span)
            diagnostics += problems
            found[quantity.name] = (index, scale)
    for quantity in quantities:
        if quantity.name in found or any(d.message.startswith(f"two columns hold the {quantity.name}")
                                         for d in diagnostics):
            continue
        present = ", ".join(f"'{cell.text}'" for cell in header) or "no columns"
        free = [i for i in range(len(names)) if i not in claimed]
        guess = _suggestion(quantity.aliases, [names[i][0] for i in free])
        accepted = " or ".join(f"'{alias}'" for alias in quantity.aliases)
        rule = (f"name the {quantity.name} column {accepted} (any case, unit optional: "
                f"'{quantity.aliases[-1]} [{quantity.si_unit}]')")
        span, hint = where, rule
        if len(header) == 1 and any(sep in header[0].text for sep in ";\t|"):
            hint = f"the header is one cell, '{header[0].text}': separate the columns with commas; {rule}"
        elif guess is not None:
            cell = header[free[guess[0]]]
            span, hint = cell.span, f"did you mean '{guess[1]}' for '{cell.text}'? {rule}"
        diagnostics.append(Diagnostic("error", codes.E902,
                                      f"no {quantity.name} column; the header has {present}", span, hint=hint))
    return found, diagnostics


def parse_number(cell: Cell | Any, column: str, row_label: str) -> tuple[float | None, Diagnostic | None]:
    """A cell's value as a finite float, or an E903 diagnostic naming row and column."""
    text = cell.text if isinstance(cell, Cell) else cell
    span = cell.span if isinstance(cell, Cell) else NO_SPAN
    if text is None or (isinstance(text, str) and not text.strip()):
        return None, Diagnostic("error", codes.E903, f"{row_label}, column '{column}': empty cell", span,
                                hint="every row needs a number in every column it uses")
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None, Diagnostic("error", codes.E903, f"{row_label}, column '{column}': '{text}' is not a number",
                                span, hint="write plain numbers such as 0.05 or 2.24e5; units go in the header")
    if not math.isfinite(value):
        return None, Diagnostic("error", codes.E903, f"{row_label}, column '{column}': '{text}' is not a finite number",
                                span)
    return value, None


def cap_diagnostics(diagnostics: list[Diagnostic]) -> list[Diagnostic]:
    """At most MAX_DIAGNOSTICS_PER_CODE of each code, then one 'and N more'."""
    kept: list[Diagnostic] = []
    counts: dict[str, int] = {}
    for diagnostic in diagnostics:
        counts[diagnostic.code] = counts.get(diagnostic.code, 0) + 1
        if counts[diagnostic.code] <= MAX_DIAGNOSTICS_PER_CODE:
            kept.append(diagnostic)
    for code, count in counts.items():
        if count > MAX_DIAGNOSTICS_PER_CODE:
            kept.append(Diagnostic("error", code, f"... and {count - MAX_DIAGNOSTICS_PER_CODE} more like this"))
    return kept


def check_parameters(**values: float | None) -> list[Diagnostic]:
    """E914 for a parameter that is not a finite number of the right sign.

    A name ending in ``_positive`` must be > 0; any other must be >= 0. None is skipped.
    """
    diagnostics = []
    for key, value in values.items():
        name, positive = (key[: -len("_positive")], True) if key.endswith("_positive") else (key, False)
        if value is None:
            continue
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if not math.isfinite(number) or number < 0 or (positive and number == 0):
            need = "a positive number" if positive else "a number >= 0"
            diagnostics.append(Diagnostic("error", codes.E914, f"{name} must be {need}, got {value!r}"))
    return diagnostics


# ================================================================= the data

QUANTITIES = (
    Quantity("velocity", ("v", "velocity"), "m/s"),
    Quantity("torque", ("tau", "τ", "torque"), "N*m"),
    Quantity("pressure", ("P", "pressure"), "Pa"),
)


@dataclass(frozen=True, eq=False)
class FrictionData:
    """Test rows in SI: velocity [m/s], motor torque [N*m], absolute chamber pressure [Pa].

    ``labels`` names each row for messages ("line 7" of a file, "row 3" of
    arrays); ``spans`` point at the rows in ``source`` when there is one.
    """

    velocity: np.ndarray
    torque: np.ndarray
    pressure: np.ndarray
    labels: tuple[str, ...]
    spans: tuple[Span, ...]
    source: Source | None = None
    name: str = "<data>"

    def __len__(self) -> int:
        return len(self.velocity)


def _rows_to_data(header: Sequence[Cell], rows: Sequence[Sequence[Any]], labels: Sequence[str],
                  row_spans: Sequence[Span], where: Span, source: Source | None, name: str) -> FrictionData:
    columns, diagnostics = resolve_columns(header, QUANTITIES, where)
    if diagnostics:
        raise DataError(diagnostics)
    values: dict[str, list[float]] = {quantity.name: [] for quantity in QUANTITIES}
    for row, label, span in zip(rows, labels, row_spans):
        if len(row) != len(header):
            diagnostics.append(Diagnostic("error", codes.E904,
                                          f"{label} has {len(row)} cells; the header has {len(header)}", span,
                                          hint="check for a missing or extra comma"))
            continue
        for quantity in QUANTITIES:
            index, scale = columns[quantity.name]
            value, problem = parse_number(row[index], header[index].text, label)
            if problem is not None:
                diagnostics.append(problem)
            elif value is not None:         # (parse_number gives a value or a problem)
                values[quantity.name].append(value * scale)
    if diagnostics:
        raise DataError(cap_diagnostics(diagnostics))
    return FrictionData(np.asarray(values["velocity"], float), np.asarray(values["torque"], float),
                        np.asarray(values["pressure"], float), tuple(labels), tuple(row_spans), source, name)


def load_friction_csv(path: str | Path) -> FrictionData:
    """Read friction test rows from a CSV file (``#`` comment lines allowed).

    Columns are found by name, in any order and case: ``v``/``velocity``,
    ``tau``/``torque``, ``P``/``pressure``, each optionally with a unit in
    brackets (``velocity [mm/s]``, ``pressure [MPa]``) that is converted to
    SI; without a unit the values are taken as m/s, N*m and Pa. Other columns
    are ignored.
    """
    table = read_csv_table(path)
    labels = [f"line {span.line}" for span in table.row_spans]
    return _rows_to_data(table.header, table.rows, labels, table.row_spans, table.header_span, table.source,
                         table.source.name)


def as_friction_data(data: Any) -> FrictionData:
    """Accept FrictionData, a mapping of columns, a sequence of row mappings, or an (n, 3) array.

    An (n, 3) array or a sequence of 3-sequences is read as columns
    velocity, torque, pressure in that order.
    """
    if isinstance(data, FrictionData):
        return data
    if isinstance(data, (str, Path)):
        return load_friction_csv(data)
    if isinstance(data, Mapping):
        header = [Cell(str(key)) for key in data]
        columns = [np.atleast_1d(np.asarray(column, dtype=object)) for column in data.values()]
        lengths = {len(column) for column in columns}
        if len(lengths) > 1:
            shown = ", ".join(f"'{cell.text}': {len(column)}" for cell, column in zip(header, columns))
            raise DataError(Diagnostic("error", codes.E904, f"the columns have different lengths ({shown})"))
        count = lengths.pop() if lengths else 0
        rows = [[column[i] for column in columns] for i in range(count)]
    else:
        data = list(data) if data is not None else []
        if data and isinstance(data[0], Mapping):
            keys = list(dict.fromkeys(key for row in data for key in row))
            header = [Cell(str(key)) for key in keys]
            rows = [[row.get(key) if isinstance(row, Mapping) else None for key in keys] for row in data]
        else:
            header = [Cell(quantity.name) for quantity in QUANTITIES]
            rows = [list(np.atleast_1d(np.asarray(row, object))) for row in data]
        count = len(rows)
    if count == 0:
        raise DataError(Diagnostic("error", codes.E901, "no friction test rows were given"))
    labels = [f"row {i + 1}" for i in range(count)]
    return _rows_to_data(header, rows, labels, [NO_SPAN] * count, NO_SPAN, None, "<data>")


# ==================================================================== the fit

@dataclass(frozen=True, eq=False)
class DirectionFit:
    """C = a*|v|^b for one direction, with the rows it was fitted to.

    ``a_log, b_log`` are the log-space estimate; ``a, b`` the nonlinear
    least-squares refinement on C, which ``r_squared`` and ``residuals``
    (measured C minus fitted C, N*s/m) describe.
    """

    direction: str
    a: float
    b: float
    r_squared: float
    a_log: float
    b_log: float
    speed: np.ndarray
    force: np.ndarray
    coefficient: np.ndarray
    residuals: np.ndarray
    labels: tuple[str, ...]

    @property
    def n(self) -> int:
        return len(self.speed)

    @property
    def rms_residual(self) -> float:
        return float(np.sqrt(np.mean(self.residuals ** 2)))

    def predict(self, velocity) -> np.ndarray:
        """The fitted C [N*s/m] at ``velocity`` (its magnitude is used)."""
        return self.a * np.abs(np.asarray(velocity, float)) ** self.b

    def law_text(self) -> str:
        return f"C = {self.a:.6g}*|v|^{self.b:.4g}"

    def to_json(self) -> dict:
        return {
            "direction": self.direction,
            "a": self.a,
            "b": self.b,
            "r_squared": _json_float(self.r_squared),
            "n": self.n,
            "log_fit": {"a": self.a_log, "b": self.b_log},
            "rms_residual": self.rms_residual,
            "rows": [
                {"row": label, "speed": float(s), "force": float(f), "coefficient": float(c), "residual": float(r)}
                for label, s, f, c, r in zip(self.labels, self.speed, self.force, self.coefficient, self.residuals)
            ],
        }


@dataclass(frozen=True, eq=False)
class FrictionFit:
    """The friction law identified from one data set: ``up`` (v > 0) and ``down`` (v < 0)."""

    up: DirectionFit
    down: DirectionFit
    lead: float
    area: float
    mass: float
    gravity: float
    patm: float
    name: str = "<data>"
    warnings: tuple[Diagnostic, ...] = ()

    def coefficient(self, velocity) -> np.ndarray:
        """The fitted C [N*s/m] at signed ``velocity``: the up law for v > 0, down for v < 0."""
        v = np.asarray(velocity, float)
        return np.where(v >= 0, self.up.predict(v), self.down.predict(v))

    def to_json(self) -> dict:
        return {
            "data": self.name,
            "model": "C = a*|v|^b; F = 2*pi/lead*tau + (P - patm)*area - mass*gravity; C = F/v",
            "parameters": {"lead": self.lead, "area": self.area, "mass": self.mass,
                           "gravity": self.gravity, "patm": self.patm},
            "up": self.up.to_json(),
            "down": self.down.to_json(),
            "warnings": [d.to_json() for d in self.warnings],
        }

    def to_text(self) -> str:
        lines = [
            f"friction fit: {self.name} ({self.up.n + self.down.n} rows)",
            "  F = 2*pi/l*tau + (P - P_atm)*A - M*g (eq. 17),  C = F/v (eq. 18),  C = a*|v|^b",
            f"  l = {self.lead:g} m, A = {self.area:g} m^2, M = {self.mass:g} kg, "
            f"g = {self.gravity:g} m/s^2, P_atm = {self.patm:g} Pa",
            "",
            "  direction  rows  |v| [m/s]      a [N*s/m]        b     R^2 (C)  rms residual [N*s/m]",
        ]
        for fit in (self.up, self.down):
            speeds = f"{fit.speed.min():.4g}..{fit.speed.max():.4g}"
            lines.append(f"  {fit.direction:<9}  {fit.n:>4}  {speeds:<13}  {fit.a:>9.5g}  {fit.b:>8.4f}  "
                         f"{fit.r_squared:>9.5f}  {fit.rms_residual:>10.4g}")
        lines += ["", f"  up:   {self.up.law_text()}", f"  down: {self.down.law_text()}"]
        if self.warnings:
            lines += ["", render_all(self.warnings)]
        return "\n".join(lines)


def _json_float(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _r_squared(measured: np.ndarray, fitted: np.ndarray) -> float:
    residual = float(np.sum((measured - fitted) ** 2))
    total = float(np.sum((measured - measured.mean()) ** 2))
    if residual == 0.0:
        return 1.0
    return 1.0 - residual / total if total > 0 else math.nan


def _fit_power_law(speed: np.ndarray, coefficient: np.ndarray) -> tuple[float, float, float, float, bool]:
    """(a, b, a_log, b_log, converged) for coefficient = a*speed^b."""
    from scipy.optimize import least_squares

    b_log, log_a = np.polyfit(np.log(speed), np.log(coefficient), 1)
    a_log = float(np.exp(log_a))
    start = np.array([a_log, float(b_log)])

    def residual(params):
        return params[0] * speed ** params[1] - coefficient

    def jacobian(params):
        power = speed ** params[1]
        return np.column_stack([power, params[0] * power * np.log(speed)])

    result = least_squares(residual, start, jac=jacobian, method="lm", x_scale="jac",
                           xtol=1e-14, ftol=1e-14, gtol=1e-14)
    a, b = (float(x) for x in result.x)
    converged = bool(result.success) and a > 0 and all(map(math.isfinite, (a, b)))
    return a, b, a_log, float(b_log), converged


def fit_friction(data: Any, *, lead: float = DEFAULT_LEAD, area: float = DEFAULT_AREA,
                 mass: float = DEFAULT_MASS, gravity: float = DEFAULT_GRAVITY,
                 patm: float = DEFAULT_PATM) -> FrictionFit:
    """Identify C = a*|v|^b for upward and downward motion from steady-velocity rows.

    ``data``: a :class:`FrictionData` (from :func:`load_friction_csv`), a
    path, a mapping of columns (``{"v": ..., "tau": ..., "P": ...}``), a
    sequence of row mappings, or an (n, 3) array of (velocity, torque,
    pressure). ``lead`` [m/rev], ``area`` (the rod-side A_r) [m^2], ``mass``
    [kg], ``gravity`` [m/s^2], ``patm`` [Pa]: the pressure is absolute and
    (P - patm)*area is the piston force; give ``patm=0`` for gauge data.

    Raises DataError (every problem found, not just the first): E910 rows at
    zero velocity, E911 fewer than 3 rows in a direction, E912 rows whose C is
    not positive (so the log fit is impossible), E913 a direction with one
    distinct speed or a failed fit, E914 a bad parameter, and the reading
    errors E901-E906.
    """
    problems = check_parameters(lead_positive=lead, area_positive=area, mass=mass, gravity=gravity, patm=patm)
    if problems:
        raise DataError(problems)
    rows = as_friction_data(data)
    lead, area, mass, gravity, patm = (float(x) for x in (lead, area, mass, gravity, patm))
    force = 2 * math.pi / lead * rows.torque + (rows.pressure - patm) * area - mass * gravity

    diagnostics: list[Diagnostic] = []
    zero = np.flatnonzero(rows.velocity == 0)
    for i in zero:
        diagnostics.append(Diagnostic(
            "error", codes.E910, f"{rows.labels[i]}: velocity is zero, so C = F/v is undefined", rows.spans[i],
            hint="friction is identified from steady motion; drop standstill rows"))

    warnings: list[Diagnostic] = []
    if len(rows) and np.median(rows.pressure) <= patm:
        warnings.append(Diagnostic(
            "warning", codes.E915,
            f"the chamber pressure (median {np.median(rows.pressure):g} Pa) is not above P_atm = {patm:g} Pa",
            hint="bondc reads pressure as absolute and uses (P - P_atm)*A; for gauge data pass --patm 0"))

    fits: dict[str, DirectionFit] = {}
    for direction, mask in (("up", rows.velocity > 0), ("down", rows.velocity < 0)):
        indices = np.flatnonzero(mask)
        sign = "v > 0" if direction == "up" else "v < 0"
        if len(indices) < MIN_ROWS_PER_DIRECTION:
            diagnostics.append(Diagnostic(
                "error", codes.E911,
                f"{len(indices)} row{'s' if len(indices) != 1 else ''} for {direction}ward motion ({sign}); "
                f"the fit needs at least {MIN_ROWS_PER_DIRECTION}",
                hint="measure at three or more steady speeds in each direction"))
            continue
        speed = np.abs(rows.velocity[indices])
        coefficient = force[indices] / rows.velocity[indices]
        bad = indices[coefficient <= 0]
        for i in bad:
            diagnostics.append(Diagnostic(
                "error", codes.E912,
                f"{rows.labels[i]}: friction coefficient C = F/v = {force[i] / rows.velocity[i]:.4g} N*s/m "
                f"is not positive (v = {rows.velocity[i]:g} m/s, tau = {rows.torque[i]:g} N*m, "
                f"P = {rows.pressure[i]:g} Pa give F = {force[i]:.4g} N)", rows.spans[i],
                hint="friction must oppose motion: check the signs (v and tau positive upward), that the "
                     "pressure is absolute (else --patm 0), and --lead/--area/--mass"))
        if len(bad):
            continue
        if np.ptp(np.log(speed)) < 1e-12:
            diagnostics.append(Diagnostic(
                "error", codes.E913,
                f"all {direction}ward rows are at the same speed {speed[0]:g} m/s: the exponent b cannot be fitted",
                hint="measure at two or more different speeds in each direction"))
            continue
        a, b, a_log, b_log, converged = _fit_power_law(speed, coefficient)
        if not converged:
            diagnostics.append(Diagnostic("error", codes.E913,
                                          f"the {direction}ward power-law fit did not converge"))
            continue
        fitted = a * speed ** b
        fits[direction] = DirectionFit(direction, a, b, _r_squared(coefficient, fitted), a_log, b_log,
                                       speed, force[indices], coefficient, coefficient - fitted,
                                       tuple(rows.labels[i] for i in indices))
    if diagnostics:
        raise DataError(cap_diagnostics(diagnostics))
    return FrictionFit(fits["up"], fits["down"], lead, area, mass, gravity, patm, rows.name, tuple(warnings))


# ================================================================ CLI helper

def run_fit_friction(path: str | Path, *, lead: float = DEFAULT_LEAD, area: float = DEFAULT_AREA,
                     mass: float = DEFAULT_MASS, gravity: float = DEFAULT_GRAVITY, patm: float = DEFAULT_PATM,
                     json: bool = False) -> tuple[str, int]:
    """``bondc fit-friction DATA.csv``: the text to print and the exit status.

    Exit 0 with the fit (a table, or JSON with ``json=True``) -- warnings
    included; 1 with the rendered diagnostics when the data has errors; 2 when
    the file cannot be read. Print the text on stdout when the status is 0,
    on stderr otherwise (in JSON mode always stdout).
    """
    try:
        data = load_friction_csv(path)
        fit = fit_friction(data, lead=lead, area=area, mass=mass, gravity=gravity, patm=patm)
    except DataError as error:
        status = EXIT_USAGE if any(d.code == codes.E905 for d in error.diagnostics) else EXIT_ERRORS
        if json:
            return _json.dumps({"ok": False, "diagnostics": [d.to_json() for d in error.diagnostics]},
                               indent=2), status
        sources = {}
        if status == EXIT_ERRORS:  # the file was read, so it can be shown (BOM dropped as the reader did)
            sources = {str(path): Source(str(path), Path(path).read_text(encoding="utf-8-sig"), Path(path))}
        return render_all(error.diagnostics, sources), status
    if json:
        return _json.dumps({"ok": True, "fit": fit.to_json()}, indent=2), EXIT_OK
    return fit.to_text(), EXIT_OK
