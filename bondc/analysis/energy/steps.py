"""A run at its solver's own steps: a result -> itself or the same run repeated at its steps
(:func:`steps_of`, :func:`repeat_run`); the model evaluated at the Lobatto nodes of every
step (:func:`_run_nodes`), and the run with those nodes as points (:func:`dense_steps`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from bondc.analysis.energy.cycles import cycle_windows, experiment_cycle
from bondc.analysis.energy.model import _Model
from bondc.analysis.energy.quadrature import (BUDGET_FLOOR, BUDGET_SHARE, HALVINGS, resolution_totals,
                                              under_resolved)
from bondc.analysis.energy.trajectory import _Trajectory
from bondc.errors import AnalysisError

def _at_solver_steps(result) -> bool:
    """Whether the result's points are the solver's steps (a run without ``dt`` or ``t_eval``)."""
    settings = getattr(result, "settings", {}) or {}
    if settings.get("dt") is not None:
        return False
    stats = getattr(result, "stats", {}) or {}
    steps = stats.get("steps")
    t = np.asarray(result.t, dtype=float)
    if steps is None or not (steps + 1 <= t.size <= steps + 1 + len(result.events) + 1):
        return False
    if not result.events or not t.size:
        return True
    scale = max(abs(float(t[-1])), 1.0)
    times = np.array([time for time, _ in result.events], dtype=float)
    if t.size > 1 and np.all(t[1:] >= t[:-1]):
        # each event's nearest point among the sorted times: the one at or after it, or the one before
        after = np.minimum(np.searchsorted(t, times), t.size - 1)
        nearest = np.minimum(np.abs(t[after] - times), np.abs(t[np.maximum(after - 1, 0)] - times))
    else:
        nearest = np.array([np.min(np.abs(t - time)) for time in times])
    return bool(np.all(nearest <= 1e-9 * scale))


def steps_of(ss, result):
    """``result`` at the solver's own steps: itself, or for a run on a grid (``dt``, ``t_eval``) the
    same run repeated without it (the same steps), once per result. What is computed from a run
    rather than shown of it (the energy account, statistics, motor requirements) takes these: a
    peak between two report points is not missed."""
    if _at_solver_steps(result):
        return result
    steps = getattr(result, "_solver_steps", None)
    if steps is None:
        steps = repeat_run(ss, result)
        try:
            result._solver_steps = steps
        except AttributeError:      # (a result that takes no attributes: repeated each time)
            pass
    return steps


def _run_nodes(ss, steps, boundaries):
    """(model, trajectory, node times (steps, 5), every variable at the nodes) of a run at its
    solver's steps, its steps split at ``boundaries``: made once per run and boundaries, for the
    energy account and the statistics (:func:`dense_steps`) alike."""
    from bondc.simulate import compile_model

    key = tuple(float(edge) for edge in boundaries)
    memo = steps.__dict__.setdefault("_nodes", {})
    if key not in memo:
        # values bound late (--set, an edit of values only): the base's module, given the run's values
        namespace = compile_model(getattr(ss, "bound_base", None) or ss)
        model = _Model(namespace, steps.parameters)
        trajectory = _Trajectory(model, steps, boundaries)
        times, values = trajectory.samples()
        totals = resolution_totals(times, values)
        budget = max(BUDGET_FLOOR, int(BUDGET_SHARE * times.shape[0]))
        # a step whose interpolant is not the corrected one (a stiff mode the solver stepped over, in
        # equilibrium there: the law's rate at a state between its ends is far off) is not halved
        coarse = under_resolved(times, values, totals, ~trajectory.corrected, budget)
        for _ in range(HALVINGS):       # steps too long for their quadrature, halved (only theirs evaluated)
            if coarse.size == 0:
                break
            budget -= coarse.size
            halves = trajectory.bisect(coarse)
            new = trajectory.samples_of(halves)
            times = trajectory.node_times()
            values = {name: np.insert(v, coarse + 1, 0.0, axis=0) for name, v in values.items()}
            for name, v in values.items():
                v[halves] = new[name]
            coarse = halves[under_resolved(times[halves], new, totals, ~trajectory.corrected[halves], budget)]
        memo[key] = (model, trajectory, times, values)
    return memo[key]


def _flat_nodes(values):
    """Values at the nodes (steps, 5) as one row: the first step's start, then each step's nodes
    after its start (a step's start is the step before's end).

    >>> _flat_nodes(np.array([[0.0, 1, 2, 3, 4], [4, 5, 6, 7, 8]])).tolist()
    [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    """
    return np.concatenate([values[:1, 0], values[:, 1:].ravel()])


class _NodeRows(Mapping):
    """Node values (name -> (steps, 5)) as the rows of :func:`dense_steps` (each step's nodes after
    its start, the first step's start too), flattened when first read."""

    def __init__(self, values: Mapping, names):
        self._values, self._names = values, tuple(names)
        self._made: dict[str, np.ndarray] = {}

    def __getitem__(self, name):
        if name not in self._made:
            self._made[name] = _flat_nodes(np.asarray(self._values[name]))
        return self._made[name]

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)


def dense_steps(ss, result):
    """``result`` at its solver's steps (:func:`steps_of`) and at the three interior Lobatto nodes of
    every step, where its states are the energy account's corrected interpolant between the steps
    (a sliding mode's, the cubic Hermite of its combination's rates) and its outputs and variables are
    evaluated there as the energy account evaluates its powers. What is computed from a run's outputs
    rather than shown of it (statistics, power per cycle, motor requirements) takes these: a peak
    between two steps is not missed (a 4 ms torque pulse inside a step of an explicit method, whose
    steps are long: 2.40 N m at the steps for its 2.5 N m), and the time integrals are of the solution
    between the steps, not of straight lines through them. Made once per result; a run whose steps
    cannot be interpolated so (fewer than two points, a law not finite there) gives its steps."""
    dense = getattr(result, "_dense_steps", None)
    if dense is not None:
        return dense
    steps = steps_of(ss, result)
    dense = steps
    if steps.t.size >= 2 and np.any(np.diff(steps.t) > 0):
        try:
            with np.errstate(all="ignore"):
                dense = _dense_view(ss, steps)
        except (AnalysisError, ValueError, FloatingPointError):
            dense = steps
    try:
        result._dense_steps = dense
    except AttributeError:
        pass
    return dense


def _dense_view(ss, steps):
    import dataclasses

    boundaries = sorted({edge for start, end, _ in cycle_windows(float(steps.t[0]), float(steps.t[-1]),
                                                                 experiment_cycle(ss, steps))
                         for edge in (start, end)})
    model, trajectory, times, variables = _run_nodes(ss, steps, boundaries)
    _, outputs = trajectory.samples("outputs")
    states = trajectory.interpolated_states()
    t = _flat_nodes(times)
    if not np.all(np.diff(t) > 0):
        raise ValueError("the nodes do not increase")
    bond_names = list(steps.bonds)
    return dataclasses.replace(
        steps, t=t, states={name: _flat_nodes(states[i]) for i, name in enumerate(model.state_names)},
        outputs={name: _flat_nodes(values) for name, values in outputs.items()},
        variables=_NodeRows(variables, model.variable_names),
        bonds=_NodeRows({name: variables[name] for name in bond_names if name in variables},
                        [name for name in bond_names if name in variables]))


def repeat_run(ss, result, t_eval=None):
    """``result``'s run again, with its settings and parameter values (the same solver steps),
    reported at its steps or at ``t_eval``; an incomplete run is cut where it stopped."""
    from bondc.simulate import simulate

    settings = dict(result.settings)
    rerun = simulate(ss, None, t_end=settings.get("t_end", float(result.t[-1])), method=settings.get("method"),
                     rtol=settings.get("rtol"), atol=settings.get("atol"), max_step=settings.get("max_step"),
                     first_step=settings.get("first_step"), overrides=dict(result.parameters), t_eval=t_eval)
    if not result.complete:         # (a SimResult is frozen: the cut run is a new one)
        import dataclasses

        keep = rerun.t <= result.t[-1]
        rerun = dataclasses.replace(rerun, t=rerun.t[keep], **{
            group: {name: values[keep] for name, values in getattr(rerun, group).items()}
            for group in ("states", "outputs", "bonds", "variables")})
    return rerun
