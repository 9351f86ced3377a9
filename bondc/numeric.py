"""bondc's numeric functions, without sympy: ``table``, ``step`` and ``csv`` as numbers, the SI
scales of a measured file's header units, and :data:`NUMERIC_FUNCTIONS`, the names sympy's
``lambdify`` (and the energy functions of a cached run) use for them.
"""

from __future__ import annotations

import math
from typing import Callable, Mapping

import numpy as np


def table_value(x, breakpoints, values):
    """Numeric ``table``: ``numpy.interp`` holds the end values."""
    return float(np.interp(x, np.asarray(breakpoints, dtype=float), np.asarray(values, dtype=float)))


def step_value(x, x0):
    return 1.0 if x >= x0 else 0.0


def pwm_value(x, f, d):
    """``pwm(x, f, d)`` at numbers.

    >>> pwm_value(0.0, 10.0, 0.3), pwm_value(0.029, 10.0, 0.3), pwm_value(0.03, 10.0, 0.3)
    (1.0, 1.0, 0.0)
    """
    phase = x * f - math.floor(x * f)
    return 1.0 if phase < d else 0.0


def coulomb_value(v, slide, static=None):
    """``coulomb(v, F_slide, F_static)`` away from sticking: ``F_slide*sign(v)`` (0 at v = 0, where
    only a simulation finds the holding force); a negative limit acts as 0."""
    return max(float(slide), 0.0) * float(np.sign(v))


def read_csv_column(path: str, column: str) -> tuple[np.ndarray, np.ndarray]:
    """Time and value columns of a csv file, read by the one reader of every stage
    (:func:`bondc.runtime.load_csv`)."""
    from bondc.runtime import load_csv

    return load_csv(str(path), str(column))


def csv_value(x, path, column, time_scale=1.0, value_scale=1.0):
    times, values = read_csv_column(str(path), str(column))
    return float(value_scale * np.interp(x / time_scale, times, values))


def csv_scales(path: str, column: str) -> tuple[float, float]:
    """The SI scales of a csv file's time column and of ``column`` from the units in its header
    (``t [ms]`` -> 0.001, ``omega [rpm]`` -> 0.1047...); 1.0 where the header gives none (SI).

    Raises ValueError naming a unit it does not know."""
    from bondc.runtime import csv_columns

    columns = csv_columns(path)
    names = [name.lower() for name, _ in columns]
    time_index = names.index("t") if "t" in names else (names.index("time") if "time" in names else 0)
    units = dict(columns)
    return (unit_scale(columns[time_index][1]) if columns else 1.0), unit_scale(units.get(column))


def unit_scale(text: str | None) -> float:
    """The SI factor of a unit written as text (``"kPa"`` -> 1000.0); None -> 1.0."""
    if text is None:
        return 1.0
    from bondc.units import unit_of

    resolved = unit_of(text)
    if resolved is None:
        raise ValueError(f"unknown unit [{text}]")
    return float(resolved.factor)


#: What ``lambdify``/generated numpy code needs besides numpy for bondc's functions.
NUMERIC_FUNCTIONS: Mapping[str, Callable] = {
    "Table": lambda x, xs, vs: table_value(x, xs, vs),
    "Step": step_value,
    "Csv": csv_value,
    "External": lambda x, name, default: float(default),     # an external input at its default
    "Pwm": pwm_value,
    "Coulomb": coulomb_value,
}
