"""The results table of a sweep: :class:`SweepPoint` (one row: status, metrics, motors) and
:class:`SweepResult` (every row, with the axes and metrics) as JSON, csv and a text table."""

from __future__ import annotations

import csv
import io
import json
import math
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from bondc.analysis.sweep.grid import _usage, Axis
from bondc.analysis.sweep.metrics import Metric
from bondc.errors import Diagnostic
from bondc.io import json_safe
from bondc import codes


STATUSES = ("ok", "failed", "timed out", "incomplete")


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
                out.append(Diagnostic("error", codes.E968, where + (point.message or "failed")))
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

    def csv_row(self, point: SweepPoint) -> list[int | str]:
        row: list[int | str] = [point.index]
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
            raise _usage(codes.E969, f"cannot write '{path}': give a .csv or .json file")

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
        blocks: list[list[list[str]]] = []
        block: list[list[str]] = []
        used = sum(_width(c) + 2 for c in fixed) + _width(status)
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
