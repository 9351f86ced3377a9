"""The points of a sweep: ``--vary`` and ``--range`` texts -> :class:`Axis` (values in a unit),
checked against the model's parameters; a full grid or a Latin hypercube over the axes.

>>> parse_range("M=20:40 [kg]").values
(20.0, 40.0)
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bondc.errors import BondcError, Diagnostic, UsageError
from bondc import codes


#: The most runs one sweep may ask for (checked before the grid is made).
MAX_RUNS = 100_000


def _usage(code: str, message: str, hint: str | None = None) -> UsageError:
    return UsageError(Diagnostic("error", code, message, hint=hint))


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
        raise _usage(codes.E962, f"--vary '{spec}': '{text}' is not a number",
                     hint="values are numbers separated by commas, or start:stop:count") from None
    if not math.isfinite(value):
        raise _usage(codes.E962, f"--vary '{spec}': '{text}' is not a finite number")
    return value


def _range(item: str, spec: str) -> list[float]:
    parts = [part.strip() for part in item.split(":")]
    if len(parts) != 3:
        raise _usage(codes.E962, f"--vary '{spec}': '{item}' is not start:stop:count",
                     hint="e.g. M=20:40:5 gives 20, 25, 30, 35, 40")
    start, stop = _number(parts[0], spec), _number(parts[1], spec)
    try:
        count = int(parts[2])
    except ValueError:
        count = 0
    if count < 2 or str(count) != parts[2].lstrip("+"):
        raise _usage(codes.E962, f"--vary '{spec}': the count in '{item}' must be a whole number >= 2, "
                             f"got '{parts[2]}'", hint="start:stop:count includes both ends")
    if count > MAX_RUNS:        # before anything is allocated (a count of 10^8 is 800 MB of values)
        raise _usage(codes.E964, f"--vary '{spec}' asks for {count} values; a sweep has at most {MAX_RUNS} runs",
                     hint="use fewer points (a coarse grid first, then a finer one where it matters)")
    values = np.linspace(start, stop, count)
    values[0], values[-1] = start, stop
    return [float(v) for v in values]


def parse_vary(text: str) -> Axis:
    """``"NAME=v1,v2 [unit]"`` or ``"NAME=start:stop:count [unit]"`` -> :class:`Axis` (E960, E962)."""
    match = _VARY.match(text)
    if match is None or "=" not in text:
        raise _usage(codes.E960, f"--vary '{text}' is not NAME=VALUES [unit]",
                     hint='e.g. --vary "k=400,800,1600" or --vary "M=20:40:5 [kg]"')
    name = match["name"]
    if not _NAME.match(name):
        raise _usage(codes.E960, f"--vary '{text}': '{name}' is not a parameter name",
                     hint='e.g. --vary "k=400,800,1600"')
    unit = match["unit"].strip() if match["unit"] is not None else None
    if unit == "":
        raise _usage(codes.E963, f"--vary '{text}': the unit between [ ] is empty",
                     hint="leave out [ ] to use the parameter's declared unit")
    items = [item.strip() for item in match["values"].split(",")]
    if not any(items):
        raise _usage(codes.E960, f"--vary '{text}' gives no values for '{name}'",
                     hint="give values separated by commas, or start:stop:count")
    values: list[float] = []
    for item in items:
        if not item:
            raise _usage(codes.E960, f"--vary '{text}' has an empty value between commas")
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
        raise _usage(codes.E963, f"{where}[{text}] is not a unit") from None
    si, diagnostics = units.resolve(unit)
    if si is None:
        hint = next((d.hint for d in diagnostics if d.hint), None)
        message = "; ".join(d.message for d in diagnostics) or f"[{text}] is not a unit"
        raise _usage(codes.E963, where + message, hint=hint)
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
            raise _usage(codes.E961, f"--vary '{axis.text}': '{axis.name}' is not a parameter of {graph.name}",
                         hint=hint)
        if axis.name in seen:
            raise _usage(codes.E966, f"'{axis.name}' is varied twice", hint="give all its values in one --vary")
        if axis.name in fixed:
            raise _usage(codes.E966, f"'{axis.name}' is both varied and set with --set", hint="drop one of them")
        seen.add(axis.name)
        declared_text = graph.parameters[axis.name].unit_text
        declared = _resolve_unit(declared_text) if declared_text else units.DIMENSIONLESS
        converter = declared
        if axis.unit is not None:
            converter = _resolve_unit(axis.unit, f"--vary '{axis.text}': ")
            # the same test as --set (semantic's E204): angle counts, rpm is not 1/s
            if converter.dims != declared.dims:
                raise _usage(codes.E963, f"--vary '{axis.text}': [{axis.unit}] does not measure the same quantity "
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
        raise _usage(codes.E960, f"--range '{text}': write NAME=LOW:HIGH, optionally with a unit: \"M=20:45 [kg]\"")
    low_text, high_text = match.group("values").split(":")
    low, high = _number(low_text, text), _number(high_text, text)
    if not high > low:
        raise _usage(codes.E962, f"--range '{text}': the upper bound must be above the lower one")
    return Axis(match.group("name"), (low, high), match.group("unit"), text)


def latin_hypercube(axes: Sequence[Axis], samples: int, seed: int | None) -> list[tuple[float, ...]]:
    """``samples`` points of a Latin hypercube over the axes' [low, high] (scipy.stats.qmc), the same
    for the same seed."""
    from scipy.stats import qmc

    unit = qmc.LatinHypercube(d=len(axes), seed=seed).random(samples)
    lows = np.array([axis.values[0] for axis in axes])
    highs = np.array([axis.values[1] for axis in axes])
    return [tuple(float(v) for v in row) for row in qmc.scale(unit, lows, highs)]
