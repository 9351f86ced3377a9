"""Motor selection: a torque and speed profile to the servomotors of a catalogue that can drive it.

Two steps:

* :func:`requirements` takes a sampled cycle -- time [s], motor torque
  [N*m], motor speed [rad/s] -- and returns :class:`MotorRequirements`:
  peak and RMS torque, peak speed, peak motoring and regenerative power and
  the energy per cycle.
* :func:`select` takes those requirements and a catalogue
  (:func:`load_catalogue`, e.g. ``models/data/motors.csv``) and returns a
  :class:`Selection`: every motor as a :class:`Candidate` judged by
  :func:`judge`, the ones that qualify first, smallest first, and the
  verdict (:meth:`Selection.verdict`) in complete sentences.

Sizing rules -- one set, in :func:`judge`, used by ``bondc simulate --motors``,
``bondc report --motors`` and ``bondc sweep --motors`` alike. They are the checks of
the servo manufacturers' sizing guides and of the motor-sizing chapters of
mechatronics texts: a motor qualifies when it passes every rule, and each rule
records its margin (available/required, and the headroom 1 - required/available
the verdict quotes in per cent):

1. **peak torque**: at every instant of the cycle |tau| is inside the peak
   (intermittent) torque envelope at that instant's speed -- the catalogue's peak
   torque up to the rated speed, constant power above it;
2. **RMS torque** (thermal): the cycle's RMS torque is inside the continuous
   envelope at the cycle's RMS speed -- the rated torque up to the rated speed,
   constant power above it; winding losses go with tau^2, so the RMS torque is
   what heats the motor;
3. **speed**: the cycle's peak |omega| is at most the motor's top speed (the
   optional catalogue column ``max_speed``, else the rated speed);
4. **inertia ratio**: load inertia reflected to the motor shaft / rotor inertia
   is at most the limit (``--inertia-ratio``, else the catalogue column
   ``max_inertia_ratio``, else 10): above it the servo loop is hard to tune.
   When the load inertia is unknown the rule is not applied, and the verdict
   says so and why.

Power (the cycle's peak |tau*omega| against the rated power) is information, not
a rule: a servo delivers its peak torque at speed briefly, which is what rules 1
and 2 check.

With ``include_rotor_inertia=True`` each motor's own rotor inertia is added
to the torque profile (tau + J_rotor*d(omega)/dt) before the torque rules:
use it when the profile is the torque at the coupling (the flagship's
``tau = K*theta``), not when it was measured at the motor.

Energies integrate the sampled power tau*omega with the trapezoidal rule,
split exactly at its zero crossings, so positive - regenerative = net.
Regenerative power and energy are reported as magnitudes (>= 0).

>>> import numpy as np
>>> t = np.linspace(0.0, 1.0, 2001)
>>> req = requirements(t, 0.5 * np.sin(2 * np.pi * t), np.full(t.shape, 100.0))
>>> round(req.peak_torque, 3), round(req.rms_torque, 4), round(req.energy_positive, 3)
(0.5, 0.3536, 15.915)
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from bondc.analysis.friction import (
    cap_diagnostics,
    check_parameters,
    parse_number,
    read_csv_table,
)
from bondc.errors import DataError, Diagnostic
from bondc import codes

RPM = 2 * math.pi / 60  # rad/s per rpm
MAX_INERTIA_RATIO = 10.0

CATALOGUE_COLUMNS = ("name", "rated_torque", "peak_torque", "rated_speed", "rated_power", "rotor_inertia")
_CATALOGUE_UNITS = {"rated_torque": "N*m", "peak_torque": "N*m", "rated_speed": "rpm",
                    "rated_power": "W", "rotor_inertia": "kg*m^2"}


# =============================================================== requirements

@dataclass(frozen=True, eq=False)
class MotorRequirements:
    """What one cycle asks of the motor. Torques N*m, speeds rad/s, powers W, energies J.

    ``time``, ``torque`` and ``speed`` keep the profile over the window
    (end points interpolated), so :func:`select` can add a rotor's inertia.
    """

    t_start: float
    t_end: float
    peak_torque: float
    peak_torque_positive: float
    peak_torque_negative: float
    rms_torque: float
    peak_speed: float
    peak_power: float
    peak_power_motoring: float
    peak_power_regenerative: float
    energy_positive: float
    energy_regenerative: float
    energy_net: float
    rms_speed: float = 0.0
    time: np.ndarray | None = field(repr=False, default=None)
    torque: np.ndarray | None = field(repr=False, default=None)
    speed: np.ndarray | None = field(repr=False, default=None)

    @property
    def duration(self) -> float:
        return self.t_end - self.t_start

    @property
    def peak_speed_rpm(self) -> float:
        return self.peak_speed / RPM

    @property
    def rms_speed_rpm(self) -> float:
        return self.rms_speed / RPM

    def to_json(self) -> dict:
        return {
            "t_start": self.t_start, "t_end": self.t_end, "duration": self.duration,
            "peak_torque": self.peak_torque,
            "peak_torque_positive": self.peak_torque_positive,
            "peak_torque_negative": self.peak_torque_negative,
            "rms_torque": self.rms_torque,
            "peak_speed": self.peak_speed, "peak_speed_rpm": self.peak_speed_rpm,
            "rms_speed": self.rms_speed, "rms_speed_rpm": self.rms_speed_rpm,
            "peak_power": self.peak_power,
            "peak_power_motoring": self.peak_power_motoring,
            "peak_power_regenerative": self.peak_power_regenerative,
            "energy_positive": self.energy_positive,
            "energy_regenerative": self.energy_regenerative,
            "energy_net": self.energy_net,
            "units": {"torque": "N*m", "speed": "rad/s", "power": "W", "energy": "J", "time": "s"},
        }

    def to_text(self) -> str:
        return "\n".join([
            f"motor requirements over t = {self.t_start:g}..{self.t_end:g} s ({self.duration:g} s)",
            f"  peak torque      {self.peak_torque:10.4g} N*m   (max {self.peak_torque_positive:.4g}, "
            f"min {self.peak_torque_negative:.4g})",
            f"  RMS torque       {self.rms_torque:10.4g} N*m",
            f"  peak speed       {self.peak_speed:10.4g} rad/s ({self.peak_speed_rpm:.4g} rpm)",
            f"  RMS speed        {self.rms_speed:10.4g} rad/s ({self.rms_speed_rpm:.4g} rpm)",
            f"  peak power       {self.peak_power:10.4g} W     (motoring {self.peak_power_motoring:.4g}, "
            f"regenerative {self.peak_power_regenerative:.4g})",
            f"  energy per cycle {self.energy_net:10.4g} J     net (positive {self.energy_positive:.4g}, "
            f"regenerative {self.energy_regenerative:.4g})",
        ])


def _trapezoid_split(time: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """(integral of the positive part, magnitude of the negative part) of the sampled values.

    The samples are joined linearly; an interval whose ends differ in sign is
    split at its zero crossing, so the two parts add up to the trapezoid rule.
    """
    dt = np.diff(time)
    left, right = values[:-1], values[1:]
    same_sign = left * right >= 0
    positive = np.where(same_sign, np.maximum(left + right, 0) / 2 * dt, 0.0)
    negative = np.where(same_sign, np.maximum(-(left + right), 0) / 2 * dt, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = np.where(same_sign, 0.0, left / (left - right))  # fraction of dt before the zero
    high_left = ~same_sign & (left > 0)
    high_right = ~same_sign & (right > 0)
    positive += np.where(high_left, left * crossing * dt / 2, 0.0)
    positive += np.where(high_right, right * (1 - crossing) * dt / 2, 0.0)
    negative += np.where(high_left, -right * (1 - crossing) * dt / 2, 0.0)
    negative += np.where(high_right, -left * crossing * dt / 2, 0.0)
    return float(positive.sum()), float(negative.sum())


def _as_profile(name: str, values, length: int | None) -> tuple[np.ndarray | None, list[Diagnostic]]:
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        return None, [Diagnostic("error", codes.E923, f"{name} is not an array of numbers")]
    if array.ndim != 1:
        return None, [Diagnostic("error", codes.E923, f"{name} must be one-dimensional, got shape {array.shape}")]
    problems = []
    if length is not None and len(array) != length:
        problems.append(Diagnostic("error", codes.E923, f"{name} has {len(array)} samples; time has {length}",
                                   hint="sample time, torque and speed at the same instants"))
    bad = np.flatnonzero(~np.isfinite(array))
    if len(bad):
        problems.append(Diagnostic("error", codes.E923,
                                   f"{name} has {len(bad)} non-finite sample{'s' if len(bad) != 1 else ''} "
                                   f"(first at index {bad[0]}: {array[bad[0]]})"))
    return array, problems


def _window(time, torque, speed, cycle):
    """The profile restricted to ``cycle`` = (start, end), end points interpolated."""
    if cycle is None:
        return time, torque, speed
    start, end = cycle
    inside = (time > start) & (time < end)
    new_time = np.concatenate([[start], time[inside], [end]])
    return (new_time, np.interp(new_time, time, torque), np.interp(new_time, time, speed))


def requirements(t, torque, speed, *, cycle: tuple[float, float] | None = None) -> MotorRequirements:
    """Peak/RMS torque, peak speed and power, and energies of a sampled cycle.

    ``t`` [s] strictly increasing; ``torque`` [N*m] and ``speed`` [rad/s] at
    the same instants, signed (torque*speed > 0 is motoring). ``cycle`` =
    (t_start, t_end) restricts everything to that window (default: the whole
    record); RMS torque is sqrt(integral of tau^2 dt / window length) by the
    trapezoidal rule.

    Raises DataError E923 (arrays of different lengths, fewer than 2 samples,
    non-finite values), E924 (time not strictly increasing), E925 (a window
    outside the record or of zero length).
    """
    from scipy.integrate import trapezoid

    time, diagnostics = _as_profile("time", t, None)
    if time is None:
        raise DataError(diagnostics)
    torque, problems = _as_profile("torque", torque, len(time))
    diagnostics += problems
    speed, problems = _as_profile("speed", speed, len(time))
    diagnostics += problems
    if diagnostics:
        raise DataError(diagnostics)
    if len(time) < 2:
        raise DataError(Diagnostic("error", codes.E923, f"a cycle needs at least 2 samples, got {len(time)}"))
    steps = np.diff(time)
    if np.any(steps <= 0):
        index = int(np.flatnonzero(steps <= 0)[0])
        raise DataError(Diagnostic("error", codes.E924,
                                   f"time is not strictly increasing: t[{index}] = {time[index]:g} s, "
                                   f"t[{index + 1}] = {time[index + 1]:g} s",
                                   hint="sort the samples and drop repeated instants"))
    if cycle is not None:
        try:
            start, end = (float(x) for x in cycle)
        except (TypeError, ValueError):
            raise DataError(Diagnostic("error", codes.E925, f"cycle must be (t_start, t_end), got {cycle!r}")) from None
        if not (math.isfinite(start) and math.isfinite(end)) or not start < end:
            raise DataError(Diagnostic("error", codes.E925, f"the cycle window {start:g}..{end:g} s is empty",
                                       hint="give t_start < t_end"))
        if start < time[0] or end > time[-1]:
            raise DataError(Diagnostic("error", codes.E925,
                                       f"the cycle window {start:g}..{end:g} s is outside the record "
                                       f"{time[0]:g}..{time[-1]:g} s"))
        time, torque, speed = _window(time, torque, speed, (start, end))
    power = torque * speed
    duration = float(time[-1] - time[0])
    energy_positive, energy_regenerative = _trapezoid_split(time, power)
    rms = math.sqrt(float(trapezoid(torque ** 2, time)) / duration)
    rms_speed = math.sqrt(float(trapezoid(speed ** 2, time)) / duration)
    return MotorRequirements(
        t_start=float(time[0]), t_end=float(time[-1]),
        peak_torque=float(np.max(np.abs(torque))),
        peak_torque_positive=float(np.max(torque)), peak_torque_negative=float(np.min(torque)),
        rms_torque=rms,
        peak_speed=float(np.max(np.abs(speed))),
        peak_power=float(np.max(np.abs(power))),
        peak_power_motoring=max(0.0, float(np.max(power))),
        peak_power_regenerative=max(0.0, -float(np.min(power))),
        energy_positive=energy_positive, energy_regenerative=energy_regenerative,
        energy_net=energy_positive - energy_regenerative,
        rms_speed=rms_speed, time=time, torque=torque, speed=speed)


def reflected_inertia(mass: float, lead: float, *, shaft_inertia: float = 0.0) -> float:
    """A mass on a ball screw seen from the motor shaft: M*(lead/2pi)^2 + J_shaft [kg*m^2].

    >>> round(reflected_inertia(31.7, 5e-3, shaft_inertia=4.06e-5), 9)
    6.0674e-05
    """
    return mass * (lead / (2 * math.pi)) ** 2 + shaft_inertia


# ================================================================= catalogue

@dataclass(frozen=True)
class Motor:
    """One catalogue entry: torques N*m, speeds in rpm (as catalogues give them), power W, inertia kg*m^2.

    ``max_speed`` (rpm) and ``max_inertia_ratio`` come from the optional catalogue columns of those
    names; None where the catalogue gives none (then the rated speed is the top speed, and the
    inertia-ratio limit is the command line's or :data:`MAX_INERTIA_RATIO`).
    """

    name: str
    rated_torque: float
    peak_torque: float
    rated_speed: float
    rated_power: float
    rotor_inertia: float
    max_speed: float | None = None
    max_inertia_ratio: float | None = None

    @property
    def rated_speed_rad_s(self) -> float:
        return self.rated_speed * RPM

    @property
    def top_speed(self) -> float:
        """The highest speed the motor may run at [rpm]: ``max_speed``, else the rated speed."""
        return self.max_speed if self.max_speed is not None else self.rated_speed

    def continuous_torque_at(self, speed_rpm):
        """The continuous (S1) envelope [N*m] at ``speed_rpm`` (a number or an array of |speed|).

        The rated torque up to the rated speed; above it, constant power (rated torque *
        rated speed / speed) up to the top speed -- the usual shape when a catalogue gives only
        the rated point. Beyond the top speed the speed rule rejects the motor.
        """
        return self._envelope(self.rated_torque, speed_rpm)

    def peak_torque_at(self, speed_rpm):
        """The peak (intermittent) envelope [N*m]: the peak torque up to the rated speed, then constant power."""
        return self._envelope(self.peak_torque, speed_rpm)

    def _envelope(self, torque: float, speed_rpm):
        speed = np.abs(np.asarray(speed_rpm, dtype=float))
        with np.errstate(divide="ignore", invalid="ignore"):
            value = np.where(speed <= self.rated_speed, torque, torque * self.rated_speed / speed)
        return float(value) if value.ndim == 0 else value

    @property
    def size(self) -> tuple:
        """The order "smallest first": rated power, then rated torque, then name."""
        return (self.rated_power, self.rated_torque, self.name)

    def to_json(self) -> dict:
        return {column: getattr(self, column) for column in CATALOGUE_COLUMNS + OPTIONAL_COLUMNS}


OPTIONAL_COLUMNS = ("max_speed", "max_inertia_ratio")
_CATALOGUE_UNITS.update({"max_speed": "rpm", "max_inertia_ratio": "1"})


def _header_problem(names: tuple[str, ...]) -> str | None:
    """What is wrong with a catalogue header, or None: the six columns in order, then optional ones."""
    known = CATALOGUE_COLUMNS + OPTIONAL_COLUMNS
    missing = [column for column in CATALOGUE_COLUMNS if column not in names]
    extra = [name for name in names if name not in known]
    repeated = sorted({name for name in names if names.count(name) > 1})
    details = []
    if missing:
        details.append("missing " + ", ".join(f"'{m}'" for m in missing))
    if extra:
        guesses = []
        for name in extra:
            close = difflib.get_close_matches(name.lower(), missing or known, n=1, cutoff=0.5)
            guesses.append(f"'{name}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
        details.append("unexpected " + ", ".join(guesses))
    if repeated:
        details.append("repeated " + ", ".join(f"'{r}'" for r in repeated))
    if not details and names[:len(CATALOGUE_COLUMNS)] != CATALOGUE_COLUMNS:
        details.append("the columns are in a different order")
    return "; ".join(details) if details else None


def load_catalogue(path: str | Path) -> list[Motor]:
    """Read a motor catalogue CSV (``#`` comments allowed) in file order.

    The header starts with exactly ``name,rated_torque,peak_torque,rated_speed,
    rated_power,rotor_inertia`` (units N*m, N*m, rpm, W, kg*m^2); the optional
    columns ``max_speed`` (rpm, at least the rated speed) and ``max_inertia_ratio``
    (the largest load/rotor inertia ratio the maker allows for that motor) may
    follow, in any order, with an empty cell where a motor has no value. Raises
    DataError: E901 empty, E905 unreadable, E920 wrong header, E904 wrong number
    of cells, E903 a value that is not a number, E921 a value out of range (not
    positive, peak torque below rated torque, maximum speed below rated speed,
    empty name), E922 the same name twice.
    """
    table = read_csv_table(path)
    names = tuple(cell.text for cell in table.header)
    problem = _header_problem(names)
    if problem is not None:
        raise DataError(Diagnostic("error", codes.E920, f"the catalogue header is {','.join(names)}: {problem}",
                                   table.header_span,
                                   hint="the header must start with " + ",".join(CATALOGUE_COLUMNS)
                                        + "; optional columns after them: " + ", ".join(OPTIONAL_COLUMNS)))
    diagnostics: list[Diagnostic] = []
    motors: list[Motor] = []
    seen: dict[str, int] = {}
    for cells, span in zip(table.rows, table.row_spans):
        label = f"line {span.line}"
        if len(cells) != len(names):
            diagnostics.append(Diagnostic("error", codes.E904,
                                          f"{label} has {len(cells)} cells; the header has {len(names)}",
                                          span, hint="check for a missing or extra comma"))
            continue
        name = cells[0].text
        values: dict[str, float] = {}
        row_ok = True
        if not name:
            diagnostics.append(Diagnostic("error", codes.E921, f"{label}: the motor has no name", cells[0].span))
            row_ok = False
        for column, cell in zip(names[1:], cells[1:]):
            if column in OPTIONAL_COLUMNS and not cell.text.strip():
                continue                    # no value for this motor
            value, bad_number = parse_number(cell, column, label)
            if bad_number is not None:
                diagnostics.append(bad_number)
                row_ok = False
            elif value is None or value <= 0:
                diagnostics.append(Diagnostic("error", codes.E921,
                                              f"{label}, column '{column}': {cell.text} must be positive "
                                              f"({_CATALOGUE_UNITS[column]})", cell.span))
                row_ok = False
            else:
                values[column] = value
        cell_of = dict(zip(names, cells))
        if "rated_torque" in values and "peak_torque" in values and values["peak_torque"] < values["rated_torque"]:
            diagnostics.append(Diagnostic("error", codes.E921,
                                          f"{label}: peak torque {values['peak_torque']:g} N*m is below the rated "
                                          f"torque {values['rated_torque']:g} N*m", cell_of["peak_torque"].span,
                                          hint="are the two torque columns swapped?"))
            row_ok = False
        if "rated_speed" in values and "max_speed" in values and values["max_speed"] < values["rated_speed"]:
            diagnostics.append(Diagnostic("error", codes.E921,
                                          f"{label}: maximum speed {values['max_speed']:g} rpm is below the rated "
                                          f"speed {values['rated_speed']:g} rpm", cell_of["max_speed"].span,
                                          hint="leave the cell empty if the catalogue gives no maximum speed"))
            row_ok = False
        if name and name in seen:
            diagnostics.append(Diagnostic("error", codes.E922,
                                          f"{label}: motor '{name}' is already listed on line {seen[name]}",
                                          cells[0].span))
            row_ok = False
        elif name:
            seen[name] = span.line
        if row_ok:
            motors.append(Motor(name=name, **values))
    if diagnostics:
        raise DataError(cap_diagnostics(diagnostics))
    return motors


# ================================================================= the rules

#: The rules a motor must pass, in the order the verdict names them; ``power`` is information only.
RULES = ("peak_torque", "rms_torque", "speed", "inertia_ratio")


@dataclass(frozen=True)
class Check:
    """One rule applied to one motor: what the cycle requires, what the motor offers, and whether it passes.

    ``required`` and ``available`` are in ``unit`` (N*m, rpm, or 1 for the inertia ratio, where
    ``available`` is the limit); ``speed`` [rpm] is where an envelope was read (the peak-torque
    and RMS-torque rules). ``passed`` is None when the rule was not applied (``note`` says why: an
    unknown load inertia) and for ``power``, which is information, not a rule.
    """

    rule: str
    required: float | None
    available: float | None
    unit: str
    passed: bool | None
    speed: float | None = None
    note: str | None = None

    @property
    def margin(self) -> float | None:
        """available / required (>= 1 passes); None when nothing is required or the rule was not applied."""
        if self.required is None or self.available is None or not self.required > 0:
            return None
        return self.available / self.required

    @property
    def headroom(self) -> float | None:
        """The share of the motor's capability the cycle leaves unused: 1 - required/available."""
        if self.required is None or self.available is None or not self.available > 0:
            return None
        return 1.0 - self.required / self.available

    def to_json(self) -> dict:
        return {"rule": self.rule, "required": self.required, "available": self.available, "unit": self.unit,
                "speed_rpm": self.speed, "passed": self.passed, "margin": self.margin, "headroom": self.headroom,
                "note": self.note}


@dataclass(frozen=True)
class Candidate:
    """One motor judged against the requirements by :func:`judge`.

    ``checks`` holds one :class:`Check` per rule of :data:`RULES` and one for ``power``
    (information); ``qualifies`` when every applied rule passes. ``margins`` maps each to
    available/required; ``reasons`` are the failed rules as clauses ("its load/rotor inertia
    ratio is 11.9, above 10"); ``inertia_ratio`` is load/rotor when the load inertia is known.
    """

    motor: Motor
    qualifies: bool
    checks: tuple[Check, ...]
    inertia_ratio: float | None = None

    def check(self, rule: str) -> Check:
        return next(check for check in self.checks if check.rule == rule)

    @property
    def margins(self) -> dict[str, float | None]:
        return {check.rule: check.margin for check in self.checks}

    @property
    def failed(self) -> tuple[Check, ...]:
        return tuple(check for check in self.checks if check.passed is False)

    @property
    def reasons(self) -> tuple[str, ...]:
        return tuple(failure_clause(check) for check in self.failed)

    def to_json(self) -> dict:
        return {
            "motor": self.motor.to_json(),
            "qualifies": self.qualifies,
            "margins": self.margins,
            "checks": {check.rule: check.to_json() for check in self.checks},
            "reasons": list(self.reasons),
            "inertia_ratio": self.inertia_ratio,
        }

    def to_text(self) -> str:
        margins = "  ".join(f"{_MARGIN_LABELS[check.rule]} {_ratio_text(check.margin)}" for check in self.checks)
        verdict = "ok " if self.qualifies else "no "
        line = f"{verdict} {self.motor.name:<12} {margins}"
        if self.inertia_ratio is not None:
            line += f"  J_load/J_rotor {self.inertia_ratio:.3g}"
        details = [f"      - {reason}" for reason in self.reasons]
        return "\n".join([line] + details)


_MARGIN_LABELS = {"peak_torque": "peak tau", "rms_torque": "rms tau", "speed": "speed",
                  "inertia_ratio": "J limit", "power": "(power)"}


def _ratio_text(value: float | None) -> str:
    return "   -  " if value is None else f"{value:6.2f}"


def figure(value: float | None) -> str:
    """A number as the verdict shows it: three significant digits, whole numbers from 100 up
    ("n/a" for a figure a rule that was not applied has not).

    >>> figure(0.40129), figure(11.93), figure(2999.6), figure(1.0), figure(None)
    ('0.401', '11.9', '3000', '1', 'n/a')
    """
    if value is None:
        return "n/a"
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    if abs(value) >= 100:
        return f"{value:.0f}"
    return f"{value:.3g}"


def _percent(fraction: float | None) -> str:
    return "" if fraction is None else f" ({100 * fraction:.0f} % margin)"


def pass_clause(check: Check) -> str:
    """A passed (or not applied) rule as the verdict states it: "peak torque 0.41 of 0.95 N·m (57 % margin)"."""
    if check.rule == "peak_torque":
        return (f"peak torque {figure(check.required)} of {figure(check.available)} N·m"
                + (f" at {figure(check.speed)} rpm" if check.speed is not None and check.speed > 0 else "")
                + _percent(check.headroom))
    if check.rule == "rms_torque":
        return (f"RMS torque {figure(check.required)} of {figure(check.available)} N·m at "
                f"{figure(check.speed or 0.0)} rpm RMS speed" + _percent(check.headroom))
    if check.rule == "speed":
        return f"top speed {figure(check.required)} of {figure(check.available)} rpm" + _percent(check.headroom)
    if check.rule == "inertia_ratio":
        if check.passed is None:
            return f"no inertia-ratio check ({check.note})"
        return (f"load/rotor inertia ratio {figure(check.required)} of {figure(check.available)}"
                + _percent(check.headroom))
    return f"peak power {figure(check.required or 0.0)} W against {figure(check.available)} W rated (information)"


def failure_clause(check: Check) -> str:
    """A failed rule as a clause about the motor: "its load/rotor inertia ratio is 11.9, above 10"."""
    if check.rule == "peak_torque":
        return (f"its peak torque at {figure(check.speed or 0.0)} rpm is {figure(check.available)} N·m, "
                f"below the cycle's {figure(check.required)} N·m")
    if check.rule == "rms_torque":
        return (f"its continuous torque at the RMS speed {figure(check.speed or 0.0)} rpm is "
                f"{figure(check.available)} N·m, below the cycle's RMS torque {figure(check.required)} N·m")
    if check.rule == "speed":
        return f"its top speed {figure(check.available)} rpm is below the cycle's {figure(check.required)} rpm"
    return f"its load/rotor inertia ratio is {figure(check.required)}, above {figure(check.available)}"


def _peak_torque_check(motor: Motor, need: MotorRequirements) -> Check:
    """The cycle's torque against the peak envelope at the speed of each instant; the worst instant counts.

    With a flat envelope (every speed at or below the rated speed) that instant is the peak
    torque's. Without a profile, the peak torque at the peak speed.
    """
    if need.time is None or need.torque is None or need.speed is None:        # (the three come together)
        torque, speed = np.array([need.peak_torque]), np.array([need.peak_speed_rpm])
    else:
        torque, speed = np.abs(need.torque), np.abs(need.speed) / RPM
    speed = np.minimum(speed, motor.top_speed)          # beyond the top speed is the speed rule's
    available = np.broadcast_to(motor.peak_torque_at(speed), torque.shape)
    loaded = torque > 0
    if not np.any(loaded):
        return Check("peak_torque", 0.0, float(motor.peak_torque), "N*m", True, 0.0)
    ratios = np.where(loaded, available / np.where(loaded, torque, 1.0), np.inf)
    worst = int(np.argmin(ratios))
    required, offered = float(torque[worst]), float(available[worst])
    return Check("peak_torque", required, offered, "N*m", offered >= required, float(speed[worst]))


def motor_torque(motor: Motor, need: MotorRequirements) -> np.ndarray:
    """The torque ``motor`` delivers over the cycle when it also accelerates its own rotor:
    tau + J_rotor*d(omega)/dt at ``need.time`` (what :func:`judge` checks with
    ``include_rotor_inertia``; the report plots it against the motor's limits).

    Raises DataError E923 when ``need`` carries no profile.
    """
    if need.time is None or need.torque is None or need.speed is None:        # (the three come together)
        raise DataError(Diagnostic("error", codes.E923, "these requirements carry no profile to add rotor inertia to",
                                   hint="make them with requirements(t, torque, speed)"))
    return need.torque + motor.rotor_inertia * np.gradient(need.speed, need.time)


def judge(motor: Motor, need: MotorRequirements, *, load_inertia: float | None = None,
          inertia_limit: float | None = None, include_rotor_inertia: bool = False,
          unknown_inertia: str | None = None) -> Candidate:
    """Judge one motor against a cycle's requirements: THE sizing rules, used by every command.

    1. **peak torque**: at every instant, |tau| <= the peak (intermittent) envelope at that
       instant's speed (:meth:`Motor.peak_torque_at`; flat at the catalogue's peak torque up to
       the rated speed); the worst instant is reported;
    2. **RMS torque** (thermal): the cycle's RMS torque <= the continuous envelope at the
       cycle's RMS speed (:meth:`Motor.continuous_torque_at`);
    3. **speed**: the cycle's peak |omega| <= the motor's top speed (``max_speed``, else the
       rated speed);
    4. **inertia ratio**: load inertia at the motor shaft / rotor inertia <= the limit:
       ``inertia_limit`` when given (``--inertia-ratio``), else the motor's catalogue
       ``max_inertia_ratio``, else :data:`MAX_INERTIA_RATIO` (10). With ``load_inertia`` None
       the rule is not applied and its check says why (``unknown_inertia``).

    Peak power against the rated power is recorded as information, never a rule. With
    ``include_rotor_inertia`` the motor's own rotor is added to the profile first:
    tau + J_rotor*d(omega)/dt (the profile is the torque delivered to the load).
    """
    if include_rotor_inertia:
        need = requirements(need.time, motor_torque(motor, need), need.speed)
    continuous = float(motor.continuous_torque_at(need.rms_speed_rpm))
    checks = [
        _peak_torque_check(motor, need),
        Check("rms_torque", need.rms_torque, continuous, "N*m", continuous >= need.rms_torque, need.rms_speed_rpm),
        Check("speed", need.peak_speed_rpm, motor.top_speed, "rpm", motor.top_speed >= need.peak_speed_rpm),
    ]
    limit = inertia_limit if inertia_limit is not None else (motor.max_inertia_ratio or MAX_INERTIA_RATIO)
    ratio = None
    if load_inertia is not None:
        ratio = load_inertia / motor.rotor_inertia
        checks.append(Check("inertia_ratio", ratio, limit, "1", ratio <= limit))
    else:
        checks.append(Check("inertia_ratio", None, limit, "1", None,
                            note=unknown_inertia or "the load inertia is unknown"))
    checks.append(Check("power", need.peak_power, motor.rated_power, "W", None))
    qualifies = all(check.passed is not False for check in checks)
    return Candidate(motor, qualifies, tuple(checks), ratio)


def check_inertia_limit(value, what: str = "--inertia-ratio") -> float | None:
    """``value`` as a positive finite inertia-ratio limit (None stays None); DataError E928 otherwise."""
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        raise DataError(Diagnostic("error", codes.E928, f"{what}: the inertia-ratio limit must be a positive number, "
                                                    f"got {value!r}",
                                   hint="e.g. --inertia-ratio 10 (load inertia up to 10 times the rotor's)"))
    return number


# ================================================================= selection

class Selection(list):
    """``list[Candidate]``: the qualifying motors first, each group smallest first.

    Also carries the ``requirements`` it was judged against, the load inertia (or why it is
    unknown), and renders the verdict (:meth:`verdict`) and the whole selection
    (:meth:`to_text`, :meth:`to_json`).
    """

    def __init__(self, candidates: Sequence[Candidate], requirements: MotorRequirements,
                 load_inertia: float | None = None, include_rotor_inertia: bool = False,
                 inertia_limit: float | None = None, unknown_inertia: str | None = None,
                 catalogue_name: str | None = None):
        super().__init__(candidates)
        self.requirements = requirements
        self.load_inertia = load_inertia
        self.include_rotor_inertia = include_rotor_inertia
        self.inertia_limit = inertia_limit
        self.unknown_inertia = unknown_inertia if load_inertia is None else None
        self.catalogue_name = catalogue_name
        # of a selection for a run (bondc.analysis.motor_report): (name, where) of the torque and of
        # the speed, the cycle's (t_start, t_end), and "given" or "estimated" for the load inertia
        self.signals: tuple[tuple[str, str], tuple[str, str]] | None = None
        self.cycle: tuple[float, float] | None = None
        self.load_inertia_source: str | None = None

    @property
    def qualified(self) -> list[Candidate]:
        return [candidate for candidate in self if candidate.qualifies]

    @property
    def rejected(self) -> list[Candidate]:
        return [candidate for candidate in self if not candidate.qualifies]

    @property
    def best(self) -> Candidate | None:
        """The smallest motor that passes every rule, or None if none does."""
        return self.qualified[0] if self.qualified else None

    recommended = best      # one set of rules: the smallest that qualifies is the answer

    def verdict(self) -> str:
        """The answer in complete sentences, written from the rules' results.

        "SV-200 is the smallest motor that qualifies: peak torque ... of ... N·m (..% margin),
        RMS torque ..., top speed ..., load/rotor inertia ratio ... of 10. SV-100 is smaller but
        its load/rotor inertia ratio is 11.9, above 10." With an unknown load inertia the first
        sentence ends "...; the load inertia is unknown (why), so no inertia-ratio check was made."
        """
        chosen = self.best
        by_size = sorted(self, key=lambda candidate: candidate.motor.size)
        if chosen is None:
            if not by_size:
                return "The catalogue has no motors, so none can be chosen."
            largest = by_size[-1]
            text = (f"No motor of the catalogue qualifies: the largest, {largest.motor.name}, fails because "
                    f"{_joined(largest.reasons)}.")
            return text + self._inertia_sentence(" ")
        passed = [chosen.check(rule) for rule in RULES if chosen.check(rule).passed is not None]
        text = f"{chosen.motor.name} is the smallest motor that qualifies: " + ", ".join(map(pass_clause, passed))
        inertia = chosen.check("inertia_ratio")
        if inertia.passed is None:
            text += f"; the load inertia is unknown ({inertia.note}), so no inertia-ratio check was made."
        else:
            text += "."
        smaller = [c for c in by_size if c.motor.size < chosen.motor.size and not c.qualifies]
        shown = smaller[::-1][:3]           # the nearest smaller ones first
        for candidate in shown:
            same = candidate.motor.size[:2] == chosen.motor.size[:2]
            text += (f" {candidate.motor.name}" + (", of the same size," if same else " is smaller") + " but "
                     + _joined(candidate.reasons) + ".")
        if len(smaller) > len(shown):
            rest = len(smaller) - len(shown)
            text += f" The {rest} smaller motor{'s' if rest > 1 else ''} of the catalogue fail{'' if rest > 1 else 's'} too."
        return text

    def _inertia_sentence(self, sep: str) -> str:
        if self.load_inertia is None:
            why = self.unknown_inertia or "the load inertia is unknown"
            return f"{sep}The load inertia is unknown ({why}), so no inertia-ratio check was made."
        return ""

    def recommendation(self) -> str:
        """The verdict (kept under its old name)."""
        return self.verdict()

    def to_json(self) -> dict:
        return {
            "requirements": self.requirements.to_json(),
            "load_inertia": self.load_inertia,
            "load_inertia_unknown_because": self.unknown_inertia,
            "inertia_limit": self.inertia_limit,
            "include_rotor_inertia": self.include_rotor_inertia,
            "best": self.best.motor.name if self.best else None,
            "recommended": self.best.motor.name if self.best else None,
            "verdict": self.verdict(),
            "recommendation": self.verdict(),
            "candidates": [candidate.to_json() for candidate in self],
        }

    def to_text(self, width: int = 88) -> str:
        import textwrap

        lines = [self.requirements.to_text(), ""]
        if self.include_rotor_inertia:
            lines += ["each motor is judged with its own rotor inertia added: tau + J_rotor*d(omega)/dt", ""]
        lines += [f"motors that qualify ({len(self.qualified)} of {len(self)}), smallest first; "
                  "margins are available/required (power: information, not a rule):"]
        lines += [candidate.to_text() for candidate in self.qualified] or ["    (none)"]
        if self.rejected:
            lines += ["", "motors that do not qualify:"]
            lines += [candidate.to_text() for candidate in self.rejected]
        # a figure and its unit stay on one line: "77 %" is not broken
        wrapped = textwrap.wrap(self.verdict().replace(" %", "\u00a0%"), width=width, break_on_hyphens=False)
        lines += [""] + [line.replace("\u00a0", " ") for line in wrapped]
        return "\n".join(lines)


def _joined(clauses: Sequence[str]) -> str:
    clauses = list(clauses)
    if len(clauses) <= 1:
        return "".join(clauses)
    return ", ".join(clauses[:-1]) + ", and " + clauses[-1]


def select(need: MotorRequirements, catalogue: Sequence[Motor], *, load_inertia: float | None = None,
           include_rotor_inertia: bool = False, inertia_limit: float | None = None,
           unknown_inertia: str | None = None, catalogue_name: str | None = None) -> Selection:
    """Judge every catalogue motor against ``need`` with :func:`judge` (the rules are there).

    ``load_inertia`` [kg*m^2] is the load reflected to the motor shaft (see
    :func:`reflected_inertia`); None skips the inertia-ratio rule, and ``unknown_inertia``
    says why in the verdict. ``inertia_limit`` overrides every motor's limit (E928 if not
    positive). Returns a :class:`Selection` (a list of :class:`Candidate`): qualifying motors
    first, each group sorted by rated power, then rated torque, then name.
    """
    problems = check_parameters(load_inertia=load_inertia)
    if problems:
        raise DataError(problems)
    inertia_limit = check_inertia_limit(inertia_limit, "inertia_limit")
    candidates = [judge(motor, need, load_inertia=load_inertia, inertia_limit=inertia_limit,
                        include_rotor_inertia=include_rotor_inertia, unknown_inertia=unknown_inertia)
                  for motor in catalogue]
    candidates.sort(key=lambda c: (not c.qualifies,) + c.motor.size)
    return Selection(candidates, need, load_inertia, include_rotor_inertia, inertia_limit, unknown_inertia,
                     catalogue_name)
