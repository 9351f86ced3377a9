"""The transmission ratio as a sizing variable: ``--ratio NAME=VALUES`` on ``simulate`` and ``report``.

The motor a cycle needs depends on the transmission between motor and load
(a gear ratio, a ball screw's lead): more reduction lowers the torque and
raises the speed. ``--ratio lead=2,5,10,20 [mm]`` names the model parameter
that sets the transmission and the values to try; every value is run as one
point of a sweep (:func:`bondc.analysis.sweep.run_sweep`, the same compiled
model, the same sizing rules as ``--motors`` on one run), so each row's motor
is the one a single ``bondc simulate --set lead=... --motors ...`` names.
The model's own value is always one of the rows, so the table shows the
design as it is beside the alternatives.

:class:`RatioStudy` is the result: per value the smallest qualifying motor
and the cycle's peak and RMS torque and peak speed, and the value whose motor
is the smallest of the catalogue (``best``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from bondc.errors import Diagnostic, UsageError
from bondc import codes

#: The sweep metrics a ratio study shows (SI: N*m, N*m, rad/s).
METRICS = ("motor.peak_torque", "motor.rms_torque", "motor.peak_speed")
_RPM = 60.0 / (2.0 * math.pi)


@dataclass(frozen=True)
class RatioRow:
    """One value of the ratio parameter: its sizing (torques N*m and speed rad/s in SI)."""

    value: float                      # in the study's unit (as given, else the parameter's declared unit)
    status: str                       # the sweep point's status: "ok", "failed", "timed out", "incomplete"
    motor: str | None                 # the smallest motor that qualifies (None: none does, or no selection)
    qualifying: int                   # how many motors qualify
    peak_torque: float
    rms_torque: float
    peak_speed: float
    own: bool = False                 # the model's own value
    message: str | None = None        # why a point did not run

    @property
    def peak_speed_rpm(self) -> float:
        return self.peak_speed * _RPM


@dataclass(frozen=True)
class RatioStudy:
    """How the smallest qualifying motor changes with the transmission ratio; see the module docstring."""

    name: str
    unit: str | None
    rows: tuple[RatioRow, ...]
    order: tuple[str, ...]            # the catalogue's motors, smallest first

    def _rank(self, row: RatioRow) -> int:
        return self.order.index(row.motor) if row.motor in self.order else len(self.order)

    @property
    def best(self) -> RatioRow | None:
        """The value whose motor is the smallest of the catalogue (of equals, the lowest RMS torque:
        the most thermal margin); None when no value has a qualifying motor."""
        ranked = [row for row in self.rows if row.motor is not None]
        return min(ranked, key=lambda row: (self._rank(row), row.rms_torque)) if ranked else None

    @property
    def own(self) -> RatioRow | None:
        return next((row for row in self.rows if row.own), None)

    def value_text(self, row: RatioRow) -> str:
        return f"{self.name} = {row.value:g}" + (f" {self.unit}" if self.unit else "")

    def sentence(self) -> str:
        """The study's answer as one or two complete sentences."""
        span = f"{self.rows[0].value:g} to {self.rows[-1].value:g}" + (f" {self.unit}" if self.unit else "")
        best, own = self.best, self.own
        if best is None:
            return f"No motor of the catalogue qualifies at any {self.name} from {span}."
        text = (f"Over {self.name} from {span}, the smallest motor that qualifies is {best.motor}, "
                f"at {self.value_text(best)}.")
        if own is not None and own is not best:
            if own.motor == best.motor:
                text += f" The model's {self.value_text(own)} needs the same motor."
            elif own.motor is None:
                text += f" At the model's {self.value_text(own)} no motor qualifies."
            else:
                text += f" At the model's {self.value_text(own)} it is {own.motor}."
        return text

    def to_text(self) -> str:
        """The table the terminal prints: one line per value, the best marked."""
        unit = f" [{self.unit}]" if self.unit else ""
        head = f"{self.name + unit:>16} {'motor':<12} {'peak torque':>12} {'RMS torque':>12} {'peak speed':>12}"
        lines = [f"How the smallest qualifying motor changes with {self.name}:", "",
                 head, f"{'':>16} {'':<12} {'[N*m]':>12} {'[N*m]':>12} {'[rpm]':>12}"]
        best = self.best
        for row in self.rows:
            motor = row.motor or ("none" if row.status in ("ok", "incomplete") else row.status)
            mark = (" <- best" if row is best else "") + (" (model)" if row.own else "")
            lines.append(f"{row.value:>16.6g} {motor:<12} {row.peak_torque:>12.4g} {row.rms_torque:>12.4g} "
                         f"{row.peak_speed_rpm:>12.5g}{mark}")
        return "\n".join(lines + ["", self.sentence()])

    def to_json(self) -> dict:
        best = self.best
        return {"parameter": self.name, "unit": self.unit, "sentence": self.sentence(),
                "best": None if best is None else {"value": best.value, "motor": best.motor},
                "rows": [{"value": row.value, "status": row.status, "motor": row.motor,
                          "qualifying": row.qualifying, "peak_torque": _json(row.peak_torque),
                          "rms_torque": _json(row.rms_torque), "peak_speed": _json(row.peak_speed),
                          "own": row.own, "message": row.message} for row in self.rows]}


def _json(value: float) -> float | None:
    return value if math.isfinite(value) else None


def check_ratio(ratio: str | None, motors) -> None:
    """``--ratio`` without ``--motors`` is a usage error (E973) before any work."""
    if ratio is not None and not motors:
        raise UsageError(Diagnostic("error", codes.E973, f"--ratio '{ratio}' needs a motor catalogue: the study "
                                    "shows how the smallest qualifying motor changes with the ratio",
                                    hint="add --motors CATALOGUE.csv, or vary the parameter with "
                                         "'bondc sweep --vary'"))


def ratio_study(path: str | Path, spec: str, *, motors: str | Path, model: str | None = None,
                experiment: str | None = None, sets: Sequence = (), t_end: float | None = None,
                inertia_ratio: float | None = None, jobs: int = 1, progress: bool = False) -> RatioStudy:
    """Run the model at every value of ``spec`` (``"NAME=VALUES [unit]"``, as ``sweep --vary``) and at
    its own value, and size the motor of ``motors`` at each; see the module docstring.

    A bad ``spec`` raises the sweep's usage errors (E960-E966); points that fail are rows with
    their status and message, not errors.
    """
    from bondc.analysis.motors import load_catalogue
    from bondc.analysis.sweep import parse_vary, run_sweep

    axis = parse_vary(spec)
    own = _own_value(path, model, experiment, axis.name, sets, axis.unit)
    values = list(axis.values)
    if own is not None and not any(math.isclose(own, value, rel_tol=1e-9) for value in values):
        values.append(own)          # the model's own value: one more point of the same sweep
    vary = f"{axis.name}=" + ",".join(repr(value) for value in values) + (f" [{axis.unit}]" if axis.unit else "")
    result = run_sweep(path, model=model, experiment=experiment, sets=sets, vary=[vary], metrics=list(METRICS),
                       jobs=jobs, t_end=t_end, progress=progress, motors=str(motors), inertia_ratio=inertia_ratio)
    unit = result.axis_units[0]
    rows = {point.values[0]: point for point in result.points}
    order = tuple(motor.name for motor in sorted(load_catalogue(motors), key=lambda motor: motor.size))
    table = []
    for value in sorted(values):
        point = rows[value]
        metric = point.metrics
        table.append(RatioRow(value, point.status, point.chosen_motor, len(point.motors or ()),
                              float(metric.get("motor.peak_torque", math.nan)),
                              float(metric.get("motor.rms_torque", math.nan)),
                              float(metric.get("motor.peak_speed", math.nan)),
                              own is not None and math.isclose(value, own, rel_tol=1e-9), point.message))
    return RatioStudy(axis.name, unit, tuple(table), order)


def _own_value(path, model, experiment, name: str, sets: Sequence, unit: str | None) -> float | None:
    """The parameter's value as the model (its experiment, ``--set``) gives it, in ``unit`` (None:
    its declared unit); None where it is not a parameter (the sweep says so: E961)."""
    from bondc import semantic
    from bondc.analysis.sweep import _resolve_unit
    from bondc.pipeline import parse_sets

    graph, _ = semantic.load(Path(path), model=model, experiment=experiment, sets=parse_sets(sets))
    parameter = graph.parameters.get(name)
    if parameter is None:
        return None
    shown = unit or parameter.unit_text
    value = _resolve_unit(shown).from_si(parameter.value) if shown else parameter.value
    return float(value) if math.isfinite(value) else None
