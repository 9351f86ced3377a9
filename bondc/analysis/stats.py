"""Statistics of simulated outputs: :class:`~bondc.simulate.SimResult` -> dicts of numbers, SI units.

- :func:`output_statistics`: every output's min, max, time-average, time-RMS
  and final value over the run;
- :func:`power_statistics`: for outputs that are powers (declared in W, kW,
  N*m*rad/s, ...; see :func:`power_outputs`), per cycle: peak ``|p|``, peak
  positive, peak negative, RMS, positive, negative and net energy.

Time integrals use the trapezoid rule on the result's points (with a zero
crossing between two points placed by linear interpolation), second order in
the spacing: accurate to the percent on a run reported at the solver's steps
or on a fine grid. :mod:`bondc.analysis.energy` integrates element powers to
much higher accuracy for the energy balance.

Non-finite samples (a law evaluated outside its domain, warning W821) are
left out of min, max, mean and RMS; ``final`` is the last value as it is.

>>> import numpy as np
>>> from types import SimpleNamespace
>>> t = np.linspace(0.0, 2.0, 20001)
>>> result = SimpleNamespace(t=t, outputs={"p": 10 * np.sin(2 * np.pi * t)})
>>> stats = power_statistics(result, ["p"], cycle=1.0)["p"]
>>> len(stats), round(stats[0]["peak"], 6), round(stats[0]["rms"], 4), round(stats[1]["positive_energy"], 5)
(2, 10.0, 7.0711, 3.1831)
>>> round(output_statistics(result)["p"]["mean"], 9)
0.0
"""

from __future__ import annotations

import re

import math
from typing import Mapping

import numpy as np

from bondc.errors import AnalysisError, Diagnostic
from bondc import codes

STATISTICS_KEYS = ("min", "max", "mean", "rms", "final")
POWER_KEYS = ("cycle", "t_start", "t_end", "peak", "peak_positive", "peak_negative", "rms",
              "positive_energy", "negative_energy", "net_energy")


# ------------------------------------------------------------------ units


_SIMPLE_FACTOR = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?:\^\s*([+-]?\d+))?\s*([*/]|$)")


def _simple_unit(unit_text: str):
    """``N*m/rad``, ``kg*m^2``, ``J/kg/K`` as an :class:`ast.Unit` (as the parser reads them:
    left to right, each ``/`` dividing by the next factor), or None for anything else."""
    from fractions import Fraction

    from bondc import ast

    factors, position, sign = [], 0, 1
    while position < len(unit_text):
        match = _SIMPLE_FACTOR.match(unit_text, position)
        if match is None:
            return None
        name, power, operator = match.groups()
        factors.append(ast.UnitFactor(name, Fraction(sign * int(power or 1))))
        sign = -1 if operator == "/" else 1
        position = match.end()
        if not operator:
            break
    if position < len(unit_text) or not factors or sign == -1 and unit_text.rstrip().endswith("/"):
        return None
    return ast.Unit(tuple(factors), unit_text)


def _si_unit(unit_text: str | None):
    """The resolved :class:`bondc.units.SIUnit` of a unit as written, or None."""
    if not unit_text:
        return None
    from bondc import units
    from bondc.errors import BondcError

    unit = _simple_unit(unit_text)
    if unit is not None:        # names and integer powers: no parser needed (it costs 0.3 s to build)
        si, diagnostics = units.resolve(unit)
        return None if diagnostics else si
    from bondc.parse import parse_set_value

    try:
        unit = parse_set_value(f"_unit = 1 [{unit_text}]").unit
    except BondcError:
        return None
    if unit is None:
        return None
    si, diagnostics = units.resolve(unit)
    return None if diagnostics else si


def is_power_unit(unit_text: str | None) -> bool:
    """Whether a unit as written measures a power (angle ignored: ``N*m*rad/s`` is one).

    >>> is_power_unit("kW"), is_power_unit("N*m*rad/s"), is_power_unit("J"), is_power_unit(None)
    (True, True, False, False)
    """
    from bondc import units

    si = _si_unit(unit_text)
    watt = _si_unit("W")
    return si is not None and units.compatible(si, watt)


def power_outputs(graph) -> tuple[str, ...]:
    """The outputs of a BondGraph (or a StateSpace's graph) whose declared unit is a power."""
    graph = getattr(graph, "graph", None) or graph
    return tuple(name for name, output in graph.outputs.items() if is_power_unit(output.unit_text))


# ---------------------------------------------------------------- helpers


def _finite(t: np.ndarray, y: np.ndarray):
    keep = np.isfinite(y)
    return t[keep], y[keep]


def _trapezoid(t: np.ndarray, y: np.ndarray) -> float:
    if t.size < 2:
        return 0.0
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(t)))


def _signed_parts(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(positive, negative) parts of the trapezoid integral, zero crossings placed linearly."""
    if t.size < 2:
        return 0.0, 0.0
    left, right, width = y[:-1], y[1:], np.diff(t)
    crossing = (left > 0) != (right > 0)
    with np.errstate(all="ignore"):
        theta = np.where(crossing, left / (left - right), 0.5)
    up = np.where(crossing, np.where(left > 0, theta * left, (1 - theta) * right),
                  np.maximum(left, 0) + np.maximum(right, 0))
    down = np.where(crossing, np.where(left < 0, theta * left, (1 - theta) * right),
                    np.minimum(left, 0) + np.minimum(right, 0))
    return float(np.sum(0.5 * width * up)), float(np.sum(0.5 * width * down))


def _window(t: np.ndarray, y: np.ndarray, start: float, end: float):
    """The points of [start, end], with the values at both ends interpolated when they fall between points."""
    inside = (t > start) & (t < end)
    ends_t = np.array([start, end])
    ends_y = np.interp(ends_t, t, y)
    return (np.concatenate([[start], t[inside], [end]]), np.concatenate([[ends_y[0]], y[inside], [ends_y[1]]]))


# ------------------------------------------------------------- statistics


def output_statistics(result) -> dict[str, dict[str, float]]:
    """``{output: {min, max, mean, rms, final}}`` over the whole run, SI units.

    ``mean`` and ``rms`` are time averages (trapezoid rule over the result's
    points), not averages of the samples.
    """
    t_all = np.asarray(result.t, dtype=float)
    statistics = {}
    for name, values in result.outputs.items():
        values = np.asarray(values, dtype=float)
        t, y = _finite(t_all, values)
        final = float(values[-1]) if values.size else math.nan
        if y.size == 0:
            statistics[name] = {"min": math.nan, "max": math.nan, "mean": math.nan, "rms": math.nan,
                                "final": final}
            continue
        span = float(t[-1] - t[0])
        if span > 0:
            mean = _trapezoid(t, y) / span
            rms = math.sqrt(max(_trapezoid(t, y * y) / span, 0.0))
        else:
            mean, rms = float(y[0]), abs(float(y[0]))
        statistics[name] = {"min": float(np.min(y)), "max": float(np.max(y)), "mean": mean, "rms": rms,
                            "final": final}
    return statistics


def power_statistics(result, names, cycle: float | None = None) -> dict[str, list[dict]]:
    """``{output: [per cycle {cycle, t_start, t_end, peak, peak_positive, peak_negative, rms,
    positive_energy, negative_energy, net_energy}]}``, W and J.

    ``names``: the power outputs to analyse, or a BondGraph/StateSpace whose
    power outputs (:func:`power_outputs`) are taken. ``cycle`` [s]: windows
    of that length from the start of the run (a last partial window dropped
    unless it is the only one); None for the whole run. ``peak`` is the
    largest ``|p|``; ``peak_positive`` the largest ``p`` (0 if ``p`` is never
    positive), ``peak_negative`` the most negative (0 if never negative);
    ``negative_energy`` <= 0. Raises :class:`AnalysisError` E933 for a name
    that is not an output of the result.
    """
    from bondc.analysis.energy import cycle_windows

    if hasattr(names, "outputs") and not isinstance(names, (str, Mapping)):
        names = power_outputs(names)
    names = [names] if isinstance(names, str) else list(names)
    unknown = [name for name in names if name not in result.outputs]
    if unknown:
        raise AnalysisError(Diagnostic(
            "error", codes.E933, f"no output named {', '.join(repr(n) for n in unknown)} in the simulation result",
            hint="outputs: " + (", ".join(result.outputs) or "none")))
    t_all = np.asarray(result.t, dtype=float)
    statistics: dict[str, list[dict]] = {}
    if t_all.size == 0:
        return {name: [] for name in names}
    windows = cycle_windows(float(t_all[0]), float(t_all[-1]), cycle)
    for name in names:
        t_finite, y_finite = _finite(t_all, np.asarray(result.outputs[name], dtype=float))
        rows = []
        for index, (start, end, _) in enumerate(windows):
            if t_finite.size == 0:
                rows.append({"cycle": index, "t_start": start, "t_end": end,
                             **{key: math.nan for key in POWER_KEYS[3:]}})
                continue
            t, y = _window(t_finite, y_finite, start, end)
            positive, negative = _signed_parts(t, y)
            span = end - start
            rms = math.sqrt(max(_trapezoid(t, y * y) / span, 0.0)) if span > 0 else abs(float(y[0]))
            rows.append({
                "cycle": index, "t_start": float(start), "t_end": float(end),
                "peak": float(np.max(np.abs(y))),
                "peak_positive": max(float(np.max(y)), 0.0),
                "peak_negative": min(float(np.min(y)), 0.0),
                "rms": rms,
                "positive_energy": positive,
                "negative_energy": negative,
                "net_energy": positive + negative,
            })
        statistics[name] = rows
    return statistics


def statistics_rows(statistics: Mapping[str, Mapping[str, float]]) -> list[dict]:
    """:func:`output_statistics` as table rows: ``{"output", "min", "max", "mean", "rms", "final"}``."""
    return [{"output": name, **{key: values[key] for key in STATISTICS_KEYS}}
            for name, values in statistics.items()]


def power_rows(statistics: Mapping[str, list[dict]]) -> list[dict]:
    """:func:`power_statistics` as table rows: ``{"output", "cycle", ..., "net_energy"}``."""
    return [{"output": name, **{key: row[key] for key in POWER_KEYS}}
            for name, rows in statistics.items() for row in rows]
