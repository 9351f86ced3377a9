"""The windows the account is made over: a run (its start and end) and a cycle length -> the
windows ``(start, end, partial)``.
"""

from __future__ import annotations

import math

from bondc.analysis.energy.values import _error
from bondc import codes

#: At most this many cycles are analysed (each is a row of every per-cycle table).
MAX_CYCLES = 10_000


def cycle_windows(t_start: float, t_end: float, cycle: float | None) -> list[tuple[float, float, bool]]:
    """``(start, end, partial)`` of consecutive windows of length ``cycle`` from ``t_start``.

    A last partial window is dropped unless it is the only one; ``cycle`` None
    is the whole run.

    >>> cycle_windows(0.0, 1.0, 0.4)
    [(0.0, 0.4, False), (0.4, 0.8, False)]
    >>> cycle_windows(0.0, 1.0, 2.0)
    [(0.0, 1.0, True)]
    """
    if cycle is None:
        return [(t_start, t_end, False)]
    if not (isinstance(cycle, (int, float)) and math.isfinite(cycle) and cycle > 0):
        raise _error(codes.E932, f"the cycle length must be a positive number of seconds, not {cycle!r}")
    count = (t_end - t_start) / cycle
    if count > MAX_CYCLES:      # before a window is made (cycle = 1e-9 s would be billions of them)
        raise _error(codes.E935, f"the run spans {count:.3g} cycles of {cycle:g} s; at most {MAX_CYCLES} cycles "
                             f"are analysed", hint="check the cycle length (seconds), or analyse a shorter run")
    count = int(math.floor(count * (1 + 1e-9) + 1e-9))
    if count == 0:
        return [(t_start, t_end, True)]
    windows = [(t_start + k * cycle, t_start + (k + 1) * cycle, False) for k in range(count)]
    if abs(windows[-1][1] - t_end) <= 1e-9 * cycle:
        windows[-1] = (windows[-1][0], t_end, False)
    return windows


def experiment_cycle(ss, result) -> float | None:
    """The ``cycle`` of the experiment the result was run with, or None."""
    graph = getattr(ss, "graph", None)
    name = getattr(result, "experiment", None)
    experiments = getattr(graph, "experiments", {}) or {}
    if name is not None and name in experiments:
        return experiments[name].cycle
    return None
