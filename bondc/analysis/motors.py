"""Motor selection: a torque and speed profile to the servomotors of a catalogue that can drive it.

Two steps, each one function:

* :func:`requirements` takes a sampled cycle -- time [s], motor torque
  [N*m], motor speed [rad/s] -- and returns :class:`MotorRequirements`:
  peak and RMS torque, peak speed, peak motoring and regenerative power and
  the energy per cycle.
* :func:`select` takes those requirements and a catalogue
  (:func:`load_catalogue`, e.g. ``models/data/motors.csv``) and returns a
  :class:`Selection`: every motor as a :class:`Candidate` with its margins,
  the ones that qualify first, smallest first.

Sizing rules (the usual servo checks, each a margin = available/required,
a motor qualifies when every margin is >= 1):

1. **peak torque**: catalogue peak (intermittent) torque >= the cycle's peak |tau|;
2. **RMS torque**: rated (continuous) torque >= the cycle's RMS torque --
   the thermal check, since winding losses go with tau^2;
3. **speed**: rated speed >= the cycle's peak |omega|; the catalogue gives
   no maximum speed, so the rated speed is used (conservative);
4. **power**: rated power >= the cycle's peak |tau*omega| (motoring or
   regenerating). Conservative: a servo may exceed its rated power briefly,
   but a motor that never has to is a safe pick; the margin shows how much.
5. **inertia ratio** (only with ``load_inertia``): load inertia reflected to
   the motor shaft / rotor inertia <= 10 for good servo tuning. A larger
   ratio is a *warning*, not a disqualification.

With ``include_rotor_inertia=True`` each motor's own rotor inertia is added
to the torque profile (tau + J_rotor*d(omega)/dt) before checks 1, 2 and 4:
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
    time: np.ndarray = field(repr=False, default=None)
    torque: np.ndarray = field(repr=False, default=None)
    speed: np.ndarray = field(repr=False, default=None)

    @property
    def duration(self) -> float:
        return self.t_end - self.t_start

    @property
    def peak_speed_rpm(self) -> float:
        return self.peak_speed / RPM

    def to_json(self) -> dict:
        return {
            "t_start": self.t_start, "t_end": self.t_end, "duration": self.duration,
            "peak_torque": self.peak_torque,
            "peak_torque_positive": self.peak_torque_positive,
            "peak_torque_negative": self.peak_torque_negative,
            "rms_torque": self.rms_torque,
            "peak_speed": self.peak_speed, "peak_speed_rpm": self.peak_speed_rpm,
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
            f"  peak power       {self.peak_power:10.4g} W     (motoring {self.peak_power_motoring:.4g}, "
            f"regenerative {self.peak_power_regenerative:.4g})",
            f"  energy per cycle {self.energy_net:10.4g} J     net (positive {self.energy_positive:.4g}, "
            f"regenerative {self.energy_regenerative:.4g})",
        ])


def _trapezoid(values: np.ndarray, time: np.ndarray) -> float:
    # Written out: np.trapz is gone in NumPy 2 and np.trapezoid is new in it.
    return float(np.sum(np.diff(time) * (values[1:] + values[:-1]) / 2))


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
        return None, [Diagnostic("error", "E923", f"{name} is not an array of numbers")]
    if array.ndim != 1:
        return None, [Diagnostic("error", "E923", f"{name} must be one-dimensional, got shape {array.shape}")]
    problems = []
    if length is not None and len(array) != length:
        problems.append(Diagnostic("error", "E923", f"{name} has {len(array)} samples; time has {length}",
                                   hint="sample time, torque and speed at the same instants"))
    bad = np.flatnonzero(~np.isfinite(array))
    if len(bad):
        problems.append(Diagnostic("error", "E923",
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
        raise DataError(Diagnostic("error", "E923", f"a cycle needs at least 2 samples, got {len(time)}"))
    steps = np.diff(time)
    if np.any(steps <= 0):
        index = int(np.flatnonzero(steps <= 0)[0])
        raise DataError(Diagnostic("error", "E924",
                                   f"time is not strictly increasing: t[{index}] = {time[index]:g} s, "
                                   f"t[{index + 1}] = {time[index + 1]:g} s",
                                   hint="sort the samples and drop repeated instants"))
    if cycle is not None:
        try:
            start, end = (float(x) for x in cycle)
        except (TypeError, ValueError):
            raise DataError(Diagnostic("error", "E925", f"cycle must be (t_start, t_end), got {cycle!r}")) from None
        if not (math.isfinite(start) and math.isfinite(end)) or not start < end:
            raise DataError(Diagnostic("error", "E925", f"the cycle window {start:g}..{end:g} s is empty",
                                       hint="give t_start < t_end"))
        if start < time[0] or end > time[-1]:
            raise DataError(Diagnostic("error", "E925",
                                       f"the cycle window {start:g}..{end:g} s is outside the record "
                                       f"{time[0]:g}..{time[-1]:g} s"))
        time, torque, speed = _window(time, torque, speed, (start, end))
    power = torque * speed
    duration = float(time[-1] - time[0])
    energy_positive, energy_regenerative = _trapezoid_split(time, power)
    rms = math.sqrt(_trapezoid(torque ** 2, time) / duration)
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
        time=time, torque=torque, speed=speed)


def reflected_inertia(mass: float, lead: float, *, shaft_inertia: float = 0.0) -> float:
    """A mass on a ball screw seen from the motor shaft: M*(lead/2pi)^2 + J_shaft [kg*m^2].

    >>> round(reflected_inertia(31.7, 5e-3, shaft_inertia=4.06e-5), 9)
    6.0674e-05
    """
    return mass * (lead / (2 * math.pi)) ** 2 + shaft_inertia


# ================================================================= catalogue

@dataclass(frozen=True)
class Motor:
    """One catalogue entry: torques N*m, rated speed in rpm (as catalogues give it), power W, inertia kg*m^2."""

    name: str
    rated_torque: float
    peak_torque: float
    rated_speed: float
    rated_power: float
    rotor_inertia: float

    @property
    def rated_speed_rad_s(self) -> float:
        return self.rated_speed * RPM

    def to_json(self) -> dict:
        return {column: getattr(self, column) for column in CATALOGUE_COLUMNS}


def load_catalogue(path: str | Path) -> list[Motor]:
    """Read a motor catalogue CSV (``#`` comments allowed) in file order.

    The header must be exactly ``name,rated_torque,peak_torque,rated_speed,
    rated_power,rotor_inertia`` (units N*m, N*m, rpm, W, kg*m^2). Raises
    DataError: E901 empty, E905 unreadable, E920 wrong header, E904 wrong
    number of cells, E903 a value that is not a number, E921 a value out of
    range (not positive, peak torque below rated torque, empty name), E922
    the same name twice.
    """
    table = read_csv_table(path)
    names = tuple(cell.text for cell in table.header)
    if names != CATALOGUE_COLUMNS:
        missing = [column for column in CATALOGUE_COLUMNS if column not in names]
        extra = [name for name in names if name not in CATALOGUE_COLUMNS]
        details = []
        if missing:
            details.append("missing " + ", ".join(f"'{m}'" for m in missing))
        if extra:
            guesses = []
            for name in extra:
                close = difflib.get_close_matches(name.lower(), missing or CATALOGUE_COLUMNS, n=1, cutoff=0.5)
                guesses.append(f"'{name}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
            details.append("unexpected " + ", ".join(guesses))
        if not details:
            details.append("the columns are in a different order")
        raise DataError(Diagnostic("error", "E920",
                                   f"the catalogue header is {','.join(names)}: {'; '.join(details)}",
                                   table.header_span, hint="the header must be exactly " + ",".join(CATALOGUE_COLUMNS)))
    diagnostics: list[Diagnostic] = []
    motors: list[Motor] = []
    seen: dict[str, int] = {}
    for cells, span in zip(table.rows, table.row_spans):
        label = f"line {span.line}"
        if len(cells) != len(CATALOGUE_COLUMNS):
            diagnostics.append(Diagnostic("error", "E904",
                                          f"{label} has {len(cells)} cells; the header has {len(CATALOGUE_COLUMNS)}",
                                          span, hint="check for a missing or extra comma"))
            continue
        name = cells[0].text
        values: dict[str, float] = {}
        row_ok = True
        if not name:
            diagnostics.append(Diagnostic("error", "E921", f"{label}: the motor has no name", cells[0].span))
            row_ok = False
        for column, cell in zip(CATALOGUE_COLUMNS[1:], cells[1:]):
            value, problem = parse_number(cell, column, label)
            if problem is not None:
                diagnostics.append(problem)
                row_ok = False
            elif value <= 0:
                diagnostics.append(Diagnostic("error", "E921",
                                              f"{label}, column '{column}': {cell.text} must be positive "
                                              f"({_CATALOGUE_UNITS[column]})", cell.span))
                row_ok = False
            else:
                values[column] = value
        if "rated_torque" in values and "peak_torque" in values and values["peak_torque"] < values["rated_torque"]:
            diagnostics.append(Diagnostic("error", "E921",
                                          f"{label}: peak torque {values['peak_torque']:g} N*m is below the rated "
                                          f"torque {values['rated_torque']:g} N*m", cells[2].span,
                                          hint="are the two torque columns swapped?"))
            row_ok = False
        if name and name in seen:
            diagnostics.append(Diagnostic("error", "E922",
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


# ================================================================= selection

@dataclass(frozen=True)
class Candidate:
    """One motor judged against the requirements.

    ``margins`` maps each check to available/required (None when nothing is
    required, e.g. zero speed); ``reasons`` says why a motor fails;
    ``warnings`` are advisory (inertia ratio). ``inertia_ratio`` is load/rotor
    when a load inertia was given.
    """

    motor: Motor
    qualifies: bool
    margins: dict[str, float | None]
    reasons: tuple[str, ...] = ()
    warnings: tuple[Diagnostic, ...] = ()
    inertia_ratio: float | None = None

    def to_json(self) -> dict:
        return {
            "motor": self.motor.to_json(),
            "qualifies": self.qualifies,
            "margins": self.margins,
            "reasons": list(self.reasons),
            "inertia_ratio": self.inertia_ratio,
            "warnings": [d.to_json() for d in self.warnings],
        }

    def to_text(self) -> str:
        margins = "  ".join(f"{_MARGIN_LABELS[key]} {_ratio_text(value)}" for key, value in self.margins.items())
        verdict = "ok " if self.qualifies else "no "
        line = f"{verdict} {self.motor.name:<12} {margins}"
        if self.inertia_ratio is not None:
            line += f"  J_load/J_rotor {self.inertia_ratio:.3g}"
        details = [f"      - {reason}" for reason in self.reasons]
        details += [f"      ! {warning.message}" for warning in self.warnings]
        return "\n".join([line] + details)


_MARGIN_LABELS = {"peak_torque": "peak tau", "rms_torque": "rms tau", "speed": "speed", "power": "power"}


def _ratio_text(value: float | None) -> str:
    return "   -  " if value is None else f"{value:6.2f}"


class Selection(list):
    """``list[Candidate]``: the qualifying motors first, each group smallest first.

    Also carries the ``requirements`` it was judged against, and renders the
    whole selection with :meth:`to_text` / :meth:`to_json`.
    """

    def __init__(self, candidates: Sequence[Candidate], requirements: MotorRequirements,
                 load_inertia: float | None = None, include_rotor_inertia: bool = False):
        super().__init__(candidates)
        self.requirements = requirements
        self.load_inertia = load_inertia
        self.include_rotor_inertia = include_rotor_inertia

    @property
    def qualified(self) -> list[Candidate]:
        return [candidate for candidate in self if candidate.qualifies]

    @property
    def rejected(self) -> list[Candidate]:
        return [candidate for candidate in self if not candidate.qualifies]

    @property
    def best(self) -> Candidate | None:
        """The smallest qualifying motor, or None if none qualifies."""
        return self.qualified[0] if self.qualified else None

    @property
    def recommended(self) -> Candidate | None:
        """The smallest qualifying motor without a warning (the load/rotor inertia ratio), else the
        smallest qualifying one."""
        clean = [candidate for candidate in self.qualified if not candidate.warnings]
        return (clean or self.qualified or [None])[0]

    def recommendation(self) -> str:
        """Why the recommended motor: the smallest one, or the first after the inertia-ratio check."""
        best, chosen = self.best, self.recommended
        if best is None:
            return "no motor of the catalogue qualifies"
        if chosen is best:
            ratio = "" if best.inertia_ratio is None else f" and its load/rotor inertia ratio {best.inertia_ratio:.3g}"
            return f"{best.motor.name}: the smallest that qualifies{ratio} is within the limit"
        why = (f"a load/rotor inertia ratio of {best.inertia_ratio:.3g}, above {MAX_INERTIA_RATIO:g}"
               if best.inertia_ratio is not None else "; ".join(w.message for w in best.warnings))
        if chosen.warnings:
            return f"{best.motor.name}: the smallest that qualifies; every qualifying motor has {why}"
        return (f"{chosen.motor.name}: the smallest that qualifies, {best.motor.name}, has {why}; "
                f"{chosen.motor.name} is the smallest without")

    def to_json(self) -> dict:
        return {
            "requirements": self.requirements.to_json(),
            "load_inertia": self.load_inertia,
            "include_rotor_inertia": self.include_rotor_inertia,
            "best": self.best.motor.name if self.best else None,
            "recommended": self.recommended.motor.name if self.recommended else None,
            "recommendation": self.recommendation(),
            "candidates": [candidate.to_json() for candidate in self],
        }

    def to_text(self) -> str:
        lines = [self.requirements.to_text(), ""]
        if self.include_rotor_inertia:
            lines += ["each motor is judged with its own rotor inertia added: tau + J_rotor*d(omega)/dt", ""]
        lines += [f"motors that qualify ({len(self.qualified)} of {len(self)}), smallest first; "
                 "margins are available/required:"]
        lines += [candidate.to_text() for candidate in self.qualified] or ["    (none)"]
        if self.rejected:
            lines += ["", "motors that do not qualify:"]
            lines += [candidate.to_text() for candidate in self.rejected]
        lines += ["", f"smallest qualifying motor: {self.best.motor.name if self.best else 'none'}",
                  f"recommended: {self.recommendation()}"]
        return "\n".join(lines)


def _margin(available: float, required: float) -> float | None:
    return available / required if required > 0 else None


def _judge(motor: Motor, need: MotorRequirements, load_inertia: float | None) -> Candidate:
    checks = (
        ("peak_torque", motor.peak_torque, need.peak_torque, "peak torque", "N*m"),
        ("rms_torque", motor.rated_torque, need.rms_torque, "rated torque", "N*m"),
        ("speed", motor.rated_speed, need.peak_speed_rpm, "rated speed", "rpm"),
        ("power", motor.rated_power, need.peak_power, "rated power", "W"),
    )
    required_name = {"peak_torque": "peak torque", "rms_torque": "RMS torque", "speed": "peak speed",
                     "power": "peak power"}
    margins: dict[str, float | None] = {}
    reasons = []
    for key, available, required, what, unit in checks:
        margins[key] = _margin(available, required)
        if available < required:
            reasons.append(f"{what} {available:.4g} {unit} < required {required_name[key]} {required:.4g} {unit}")
    warnings = []
    ratio = None
    if load_inertia is not None:
        ratio = load_inertia / motor.rotor_inertia
        if ratio > MAX_INERTIA_RATIO:
            warnings.append(Diagnostic(
                "warning", "E926",
                f"{motor.name}: load/rotor inertia ratio {ratio:.3g} is above {MAX_INERTIA_RATIO:g}",
                hint="the servo loop will be hard to tune; consider a higher-inertia motor or a gearbox"))
    return Candidate(motor, not reasons, margins, tuple(reasons), tuple(warnings), ratio)


def select(need: MotorRequirements, catalogue: Sequence[Motor], *, load_inertia: float | None = None,
           include_rotor_inertia: bool = False) -> Selection:
    """Judge every catalogue motor against ``need`` (the rules in the module docstring).

    ``load_inertia`` [kg*m^2] is the load reflected to the motor shaft (see
    :func:`reflected_inertia`); it only adds the inertia-ratio warning (E926).
    ``include_rotor_inertia`` adds J_rotor*d(omega)/dt to the torque profile
    of each motor before judging it. Returns a :class:`Selection` (a list of
    :class:`Candidate`): qualifying motors first, each group sorted by rated
    power, then rated torque, then name.
    """
    problems = check_parameters(load_inertia=load_inertia)
    if problems:
        raise DataError(problems)
    if include_rotor_inertia and need.time is None:
        raise DataError(Diagnostic("error", "E923", "these requirements carry no profile to add rotor inertia to",
                                   hint="make them with requirements(t, torque, speed)"))
    candidates = []
    for motor in catalogue:
        motor_need = need
        if include_rotor_inertia:
            acceleration = np.gradient(need.speed, need.time)
            motor_need = requirements(need.time, need.torque + motor.rotor_inertia * acceleration, need.speed)
        candidates.append(_judge(motor, motor_need, load_inertia))
    candidates.sort(key=lambda c: (not c.qualifies, c.motor.rated_power, c.motor.rated_torque, c.motor.name))
    return Selection(candidates, need, load_inertia, include_rotor_inertia)
