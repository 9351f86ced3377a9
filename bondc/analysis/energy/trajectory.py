"""A run as solver steps: a :class:`_Model` and a result at its solver's steps -> a
:class:`_Trajectory` (per step its ends, states, rates and modes) whose states at the
Lobatto nodes are the cubic Hermite interpolant refined by deferred correction
(:func:`_corrected_nodes`), a sliding mode's from its recorded combination or a spline.
"""

from __future__ import annotations

import bisect
from typing import Sequence

import numpy as np

from bondc.analysis.energy.model import _Model
from bondc.analysis.energy.quadrature import _FROM_NODES, _INTEGRATION, _LOBATTO_NODES, _LOBATTO_WEIGHTS

def _hermite(tau, h, xa, xb, fa, fb):
    """Cubic Hermite interpolant at fractions ``tau`` of steps of length ``h`` (broadcast)."""
    tau2, tau3 = tau * tau, tau * tau * tau
    return ((2 * tau3 - 3 * tau2 + 1) * xa + (tau3 - 2 * tau2 + tau) * h * fa
            + (-2 * tau3 + 3 * tau2) * xb + (tau3 - tau2) * h * fb)


def _corrected_at(tau, h, xa, xb, rates):
    """The corrected interpolant of steps (:func:`_corrected_nodes`) at the fraction ``tau`` of each
    (length ``h``, ends ``xa``, ``xb``, rates at the Lobatto nodes ``rates`` (..., 5)): the integral
    of the rates' degree-4 interpolant from the start, plus the share ``tau`` of the step's defect."""
    s = 2.0 * tau - 1.0
    weights = np.array([(s ** (m + 1) - (-1.0) ** (m + 1)) / (m + 1) for m in range(5)]) @ _FROM_NODES
    total = 0.5 * h * (rates @ _LOBATTO_WEIGHTS)
    return xa + 0.5 * h * (rates @ weights) + tau * (xb - xa - total)


def _inside(values, increasing, start, end, closed=False):
    """Indices of ``values`` in (start, end) (``closed``: [start, end]), by bisection where the
    values increase (a run with thousands of sliding spans: not a pass over all of them per span)."""
    if increasing:
        return np.arange(np.searchsorted(values, start, "left" if closed else "right"),
                         np.searchsorted(values, end, "right" if closed else "left"))
    inside = (values >= start) & (values <= end) if closed else (values > start) & (values < end)
    return np.flatnonzero(inside)


def _sliding_spans(events, t_end) -> list[tuple[float, float]]:
    """Spans of Filippov sliding modes: from a "sliding on ..." event to the next event (or the end)."""
    spans = []
    ordered = sorted(events, key=lambda item: item[0])
    times = [float(time) for time, _ in ordered]
    for i, (time, label) in enumerate(ordered):
        if label.startswith("sliding on") and not label.endswith(" ends"):
            later = bisect.bisect_right(times, time, i + 1)      # the first later event after it
            spans.append((float(time), times[later] if later < len(times) else float(t_end)))
    return spans


def _corrected_nodes(model: _Model, ta, tb, xa, xb, fa, fb, modes, scale, *, with_rates=False, sweeps=6):
    """States at the Lobatto nodes of steps: (states (n, k, 5), rates (n, k, 5) or None, corrected (k,)).

    Starts from the cubic Hermite interpolant; a deferred-correction sweep then
    replaces the interior states by ``x_a + integral of the interpolated rates``
    plus the share ``tau * d`` of the step's defect ``d = x_b - x_a - integral
    over the step``, so the curve still ends at ``x_b``; each sweep gains an
    order in the step size. The sweeps are a fixed-point iteration that
    contracts only where ``h*|J|`` is small: a step where they stop contracting
    (a stiff mode the solver stepped over) keeps its Hermite states
    (``corrected`` False), accurate there because the stiff part is in
    equilibrium. ``scale`` (n,) is the size of each state, for the
    convergence test; ``with_rates`` also returns the rates at the final
    states.
    """
    n, count = xa.shape
    tau = (_LOBATTO_NODES + 1.0) / 2.0
    h = tb - ta
    times = ta[:, None] + h[:, None] * tau[None, :]
    hermite = _hermite(tau[None, None, :], h[None, :, None], xa[:, :, None], xb[:, :, None],
                       fa[:, :, None], fb[:, :, None])
    hermite[:, :, 0], hermite[:, :, -1] = xa, xb
    rates = np.empty_like(hermite)
    rates[:, :, 0], rates[:, :, -1] = fa, fb
    corrected = np.ones(count, dtype=bool)
    if n == 0 or count == 0:
        return hermite, rates, corrected
    half = 0.5 * h
    groups = model.groups(modes)        # the steps' distinct modes, found once for every sweep

    def node_groups(steps):
        """:meth:`_Model.groups` of the modes of ``steps``' three interior nodes."""
        return None if groups is None else (groups[0], np.repeat(groups[1][steps], 3))

    current = hermite.copy()
    previous = np.full(count, np.inf)
    active = np.ones(count, dtype=bool)
    for _ in range(sweeps):
        index = np.flatnonzero(active)
        if index.size == 0:
            break
        rates[:, index, 1:4] = model.rhs(
            times[index, 1:4].ravel(), current[:, index, 1:4].reshape(n, -1), np.repeat(modes[index], 3, axis=0),
            node_groups(index)).reshape(n, index.size, 3)
        integral = np.einsum("ij,nkj->nki", _INTEGRATION, rates[:, index, :]) * half[index][None, :, None]
        defect = xb[:, index] - xa[:, index] - integral[:, :, -1]
        new = xa[:, index, None] + integral + tau[None, None, :] * defect[:, :, None]
        new[:, :, 0], new[:, :, -1] = xa[:, index], xb[:, index]
        with np.errstate(all="ignore"):
            change = np.max(np.abs(new - current[:, index]) / scale[:, None, None], axis=(0, 2))
        settled = change <= 1e-14
        diverging = ~np.isfinite(change) | ((change > 0.5 * previous[index]) & ~settled)
        good, bad = index[~diverging], index[diverging]
        current[:, good] = new[:, ~diverging]
        previous[good] = change[~diverging]
        current[:, bad] = hermite[:, bad]
        corrected[bad] = False
        active[bad] = False
        active[index[settled]] = False
    if not with_rates:
        return current, None, corrected
    rates[:, :, 1:4] = model.rhs(times[:, 1:4].ravel(), current[:, :, 1:4].reshape(n, -1),
                                 np.repeat(modes, 3, axis=0), node_groups(slice(None))).reshape(n, count, 3)
    return current, rates, corrected


class _Trajectory:
    """The run as steps: ends, states, rates and modes per step; samples at the Lobatto nodes."""

    def __init__(self, model: _Model, result, boundaries: Sequence[float]):
        self.model = model
        self.result = result
        t = np.asarray(result.t, dtype=float)
        x = np.array([result.states[name] for name in model.state_names], dtype=float).reshape(-1, t.size)
        keep = np.flatnonzero(np.diff(t) > 0)          # zero-length steps carry no energy
        ta, tb = t[keep], t[keep + 1]
        xa, xb = x[:, keep], x[:, keep + 1]
        self._after_jumps(ta, xa, getattr(result, "jumps", ()), model.state_names)
        mid = 0.5 * (ta + tb)
        # a step's modes: those at both its ends where they agree (modes change at events only, and
        # events end steps), else those at its middle (an event at one end: its switch at 0 there).
        # The middle alone, from the ends' mean state, is off by the curvature of the states: an
        # orifice's pressure drop of -500 Pa near the supply's peak came out +100 Pa there, the
        # flow's sign flipped for the whole step, and a swinging supply's net energy was 5 times
        # the orifice's loss
        modes = model.modes(mid, 0.5 * (xa + xb))
        at_start, at_end = model.modes(ta, xa), model.modes(tb, xb)
        agree = np.all(at_start == at_end, axis=1)
        modes[agree] = at_start[agree]
        groups = model.groups(modes)
        fa = model.rhs(ta, xa, modes, groups)
        fb = model.rhs(tb, xb, modes, groups)
        sliding = np.zeros(ta.size, dtype=bool)
        increasing = bool(np.all(np.diff(mid) > 0))
        for start, end in _sliding_spans(result.events, t[-1]):
            sliding[_inside(mid, increasing, start, end)] = True
        self.ta, self.tb, self.xa, self.xb, self.fa, self.fb = ta, tb, xa, xb, fa, fb
        self.modes, self.sliding = modes, sliding
        # a sliding step whose mode the run recorded (result.sliding): its rates are the Filippov
        # combination's, evaluated between its points as the run does (not a spline through them)
        self.blocks = list(getattr(result, "sliding", ()) or ())
        settings = getattr(result, "settings", {}) or {}
        t_end = settings.get("t_end", float(t[-1]) if t.size else 1.0)
        self.probe = 1e-8 * max(float(t[-1] - t[0]) if t.size else 0.0, abs(float(t_end)), 1e-300)
        self.block = self._blocks_of(mid)
        if self.blocks:     # the run's record of its sliding modes, whatever events fell inside them
            self.sliding = sliding = self.block >= 0
        for b in np.unique(self.block[self.block >= 0]):
            rows = np.flatnonzero(self.block == b)
            self.fa[:, rows] = self.combination(int(b), ta[rows], xa[:, rows])[0]
            self.fb[:, rows] = self.combination(int(b), tb[rows], xb[:, rows])[0]
        self.scale = np.max(np.abs(x), axis=1) + 1e-300 if x.size else np.ones(x.shape[0])
        for boundary in boundaries:
            self._split(boundary)

    def _blocks_of(self, mid) -> np.ndarray:
        """Per step, the index of the recorded sliding mode (``self.blocks``) that holds it (its middle
        in the mode's (t0, t1]), or -1: a step that is not sliding, or a result without the record."""
        block = np.full(mid.size, -1, dtype=int)
        if not self.blocks:
            return block
        order = sorted(range(len(self.blocks)), key=lambda b: self.blocks[b][1])
        ends = np.array([self.blocks[b][1] for b in order])
        starts = np.array([self.blocks[b][0] for b in order])
        at = np.searchsorted(ends, mid, side="left")
        inside = at < ends.size
        inside[inside] &= starts[at[inside]] < mid[inside]
        block[inside] = np.array(order, dtype=int)[at[inside]]
        return block

    def combination(self, b: int, times: np.ndarray, states: np.ndarray):
        """(rate, corner weights) of the recorded sliding mode ``b`` at the columns (times, states):
        :meth:`_Model.filippov`, from the weights the run recorded (interpolated) where a sliding
        switch's rate does not depend on its own."""
        _, _, corners, recorded_t, recorded_w = self.blocks[b]
        sliding = np.flatnonzero(np.any(corners != corners[0], axis=0))
        plus = np.asarray(recorded_w, dtype=float).T @ (corners[:, sliding] > 0)     # (points, switches)
        guess = np.array([np.interp(times, recorded_t, plus[:, i]) for i in range(sliding.size)])
        return self.model.filippov(corners, times, states, guess, self.probe)

    @staticmethod
    def _after_jumps(ta, xa, jumps, state_names) -> None:
        """Start each step that begins where when clauses fired from the states they left: the run
        records one point there, with the states from before (a current limit's ``enabled = 0``
        would otherwise be interpolated from 1 to 0 across the next step, and the source it gates
        counted as on)."""
        if not len(jumps) or not ta.size:
            return
        rows = {name: i for i, name in enumerate(state_names)}
        tolerance = 1e-12 * max(abs(float(ta[-1])), abs(float(ta[0])), 1.0)
        for time, _, after in jumps:            # in firing order: the last round's states stand
            k = int(np.searchsorted(ta, time - tolerance))
            if k < ta.size and abs(ta[k] - time) <= tolerance:
                for name, value in after.items():
                    if name in rows:
                        xa[rows[name], k] = value

    def state_at(self, k: int, time: float) -> np.ndarray:
        """The state inside step ``k`` at ``time``, from the corrected interpolant of that step."""
        h = self.tb[k] - self.ta[k]
        tau = (time - self.ta[k]) / h
        xa, xb = self.xa[:, k], self.xb[:, k]
        if self.sliding[k]:
            if self.block[k] >= 0:      # the combination's rates at its ends
                return _hermite(tau, h, xa, xb, self.fa[:, k], self.fb[:, k])
            return (1 - tau) * xa + tau * xb
        one = slice(k, k + 1)
        _, rates, corrected = _corrected_nodes(self.model, self.ta[one], self.tb[one], self.xa[:, one],
                                               self.xb[:, one], self.fa[:, one], self.fb[:, one], self.modes[one],
                                               self.scale, with_rates=True)
        if not corrected[0]:
            return _hermite(tau, h, xa, xb, self.fa[:, k], self.fb[:, k])
        return _corrected_at(tau, h, xa, xb, rates[:, 0, :])

    def _split(self, time: float) -> None:
        span = max(abs(self.tb[-1]), abs(self.ta[0]), 1.0) if self.ta.size else 1.0
        tolerance = 1e-12 * span
        inside = np.flatnonzero((self.ta < time - tolerance) & (self.tb > time + tolerance))
        if inside.size == 0:
            return
        k = int(inside[0])
        x_mid = self.state_at(k, time)
        if self.block[k] >= 0:
            f_mid = self.combination(int(self.block[k]), np.array([time]), x_mid.reshape(-1, 1))[0][:, 0]
        else:
            f_mid = self.model.rhs(np.array([time]), x_mid.reshape(-1, 1), self.modes[k:k + 1])[:, 0]
        insert = lambda array, left, right: np.concatenate(
            [array[..., :k], left[..., None], right[..., None], array[..., k + 1:]], axis=-1)
        self.ta = np.concatenate([self.ta[:k], [self.ta[k], time], self.ta[k + 1:]])
        self.tb = np.concatenate([self.tb[:k], [time, self.tb[k]], self.tb[k + 1:]])
        self.xa = insert(self.xa, self.xa[:, k], x_mid)
        self.xb = insert(self.xb, x_mid, self.xb[:, k])
        self.fa = insert(self.fa, self.fa[:, k], f_mid)
        self.fb = insert(self.fb, f_mid, self.fb[:, k])
        self.modes = np.concatenate([self.modes[:k], self.modes[k:k + 1], self.modes[k:k + 1],
                                     self.modes[k + 1:]], axis=0)
        self.sliding = np.concatenate([self.sliding[:k], [self.sliding[k]] * 2, self.sliding[k + 1:]])
        self.block = np.concatenate([self.block[:k], [self.block[k]] * 2, self.block[k + 1:]])

    def bisect(self, steps: np.ndarray) -> np.ndarray:
        """Split each of ``steps`` (sorted indices of steps that do not slide) at its middle, where its
        state is the step's corrected interpolant (:meth:`state_at`, for all of them at once) and its
        rate the law's in the step's modes: for a step too long for its quadrature
        (:func:`under_resolved`). Returns the indices of the halves among the steps now."""
        k = np.asarray(steps, dtype=int)
        if k.size == 0:
            return k
        ta, tb = self.ta[k], self.tb[k]
        h, mid = tb - ta, 0.5 * (self.ta[k] + self.tb[k])
        xa, xb, fa, fb = self.xa[:, k], self.xb[:, k], self.fa[:, k], self.fb[:, k]
        _, rates, corrected = _corrected_nodes(self.model, ta, tb, xa, xb, fa, fb, self.modes[k], self.scale,
                                               with_rates=True)
        x_mid = np.where(corrected, _corrected_at(0.5, h, xa, xb, rates), _hermite(0.5, h, xa, xb, fa, fb))
        f_mid = self.model.rhs(mid, x_mid, self.modes[k])
        after = k + 1
        self.ta = np.insert(self.ta, after, mid)
        self.tb[k] = mid
        self.tb = np.insert(self.tb, after, tb)
        self.xa = np.insert(self.xa, after, x_mid, axis=1)
        self.xb[:, k] = x_mid
        self.xb = np.insert(self.xb, after, xb, axis=1)
        self.fa = np.insert(self.fa, after, f_mid, axis=1)
        self.fb[:, k] = f_mid
        self.fb = np.insert(self.fb, after, fb, axis=1)
        self.modes = np.insert(self.modes, after, self.modes[k], axis=0)
        self.sliding = np.insert(self.sliding, after, self.sliding[k])
        self.block = np.insert(self.block, after, self.block[k])
        halves = np.sort(np.concatenate([k + np.arange(k.size), k + np.arange(k.size) + 1]))
        # each half's modes as a step's are chosen (__init__): a kink inside the step lies in one half
        modes = self.model.modes(0.5 * (self.ta[halves] + self.tb[halves]), 0.5 * (self.xa[:, halves] + self.xb[:, halves]))
        at_start, at_end = self.model.modes(self.ta[halves], self.xa[:, halves]), self.model.modes(self.tb[halves],
                                                                                               self.xb[:, halves])
        agree = np.all(at_start == at_end, axis=1)
        modes[agree] = at_start[agree]
        changed = np.flatnonzero(np.any(modes != self.modes[halves], axis=1))
        if changed.size:
            rows = halves[changed]
            self.modes[rows] = modes[changed]
            self.fa[:, rows] = self.model.rhs(self.ta[rows], self.xa[:, rows], self.modes[rows])
            self.fb[:, rows] = self.model.rhs(self.tb[rows], self.xb[:, rows], self.modes[rows])
        if getattr(self, "_node_states", None) is not None:     # the halves' nodes, the others' kept
            states, _, corrected = _corrected_nodes(self.model, self.ta[halves], self.tb[halves], self.xa[:, halves],
                                                    self.xb[:, halves], self.fa[:, halves], self.fb[:, halves],
                                                    self.modes[halves], self.scale)
            self._node_states = np.insert(self._node_states, after, 0.0, axis=1)
            self._node_states[:, halves] = states
            self.corrected = np.insert(self.corrected, after, False)
            self.corrected[halves] = corrected & ~self.sliding[halves]
        return halves

    def node_times(self) -> np.ndarray:
        """The times (steps, 5) of each step's Lobatto nodes, its ends exactly."""
        tau = (_LOBATTO_NODES + 1.0) / 2.0
        times = self.ta[:, None] + (self.tb - self.ta)[:, None] * tau[None, :]
        times[:, 0], times[:, -1] = self.ta, self.tb
        return times

    def node_states(self) -> np.ndarray:
        """The states (n, steps, 5) at each step's Lobatto nodes (:func:`_corrected_nodes`), found
        once; ``self.corrected`` then says which steps the correction converged in."""
        if getattr(self, "_node_states", None) is None:
            states, _, corrected = _corrected_nodes(self.model, self.ta, self.tb, self.xa, self.xb, self.fa, self.fb,
                                                    self.modes, self.scale)
            self.corrected = corrected & ~self.sliding
            self._node_states = states
        return self._node_states

    def interpolated_states(self) -> np.ndarray:
        """The states (n, steps, 5) at each step's Lobatto nodes as :meth:`samples` takes them: the
        corrected interpolant (:meth:`node_states`), and in a sliding step the cubic Hermite
        interpolant of its combination's rates."""
        states = np.array(self.node_states(), dtype=float)
        sliding = np.flatnonzero(self.sliding)
        if sliding.size:
            tau = (_LOBATTO_NODES + 1.0) / 2.0
            h = (self.tb - self.ta)[sliding]
            states[:, sliding, :] = _hermite(tau[None, None, :], h[None, :, None], self.xa[:, sliding, None],
                                             self.xb[:, sliding, None], self.fa[:, sliding, None],
                                             self.fb[:, sliding, None])
            states[:, sliding, 0], states[:, sliding, -1] = self.xa[:, sliding], self.xb[:, sliding]
        return states

    def _at_nodes(self, evaluate, rows: int, times: np.ndarray, states: np.ndarray, modes: np.ndarray) -> np.ndarray:
        """``evaluate`` (outputs or variables, ``rows`` of them) at the nodes ``times`` (steps, 5) with
        the ``states`` (n, steps, 5) there and each step's ``modes``: (rows, steps, 5)."""
        n, steps = states.shape[0], times.shape[0]
        values = evaluate(times.ravel(), states.reshape(n, steps * 5), np.repeat(modes, 5, axis=0))
        values = values.reshape(rows, steps, 5)
        outside = ~np.all(np.isfinite(values), axis=0)
        if np.any(outside):
            # a node whose interpolated state is a little outside its step's branch (a level that
            # reaches 0 with zero slope, interpolated to -1e-20 under its law's sqrt): the laws'
            # own branches at that node, as the unfrozen law evaluates them
            at, columns = np.nonzero(outside)
            node_t, node_x = times[at, columns], states[:, at, columns]
            with np.errstate(all="ignore"):
                again = evaluate(node_t, node_x, self.model.modes(node_t, node_x))
            values[:, at, columns] = np.where(np.isfinite(again), again, values[:, at, columns])
        return values

    def samples_of(self, steps: np.ndarray) -> dict:
        """Every variable at the Lobatto nodes of ``steps`` (indices of steps that do not slide):
        name -> (len(steps), 5), as :meth:`samples` evaluates them."""
        names = self.model.variable_names
        values = self._at_nodes(self.model.variables, len(names), self.node_times()[steps],
                                self.node_states()[:, steps], self.modes[steps])
        return {name: values[i] for i, name in enumerate(names)}

    def samples(self, kind: str = "variables") -> tuple[np.ndarray, dict]:
        """Times (steps, 5) of the Lobatto nodes and every variable there (``kind`` "outputs": every
        output): name -> (steps, 5)."""
        evaluate = self.model.outputs if kind == "outputs" else self.model.variables
        names = self.model.output_names if kind == "outputs" else self.model.variable_names
        tau = (_LOBATTO_NODES + 1.0) / 2.0
        h = self.tb - self.ta
        times = self.node_times()
        values = self._at_nodes(evaluate, len(names), times, self.node_states(), self.modes)
        for b in np.unique(self.block[self.block >= 0]):
            # a recorded sliding mode: its combination at the nodes, the states there from the cubic
            # Hermite interpolant of its rates
            rows = np.flatnonzero(self.block == b)
            inner = times[rows, 1:4].ravel()
            nodes = _hermite(np.tile(tau[1:4], rows.size)[None, :], np.repeat(h[rows], 3)[None, :],
                             np.repeat(self.xa[:, rows], 3, axis=1), np.repeat(self.xb[:, rows], 3, axis=1),
                             np.repeat(self.fa[:, rows], 3, axis=1), np.repeat(self.fb[:, rows], 3, axis=1))
            node_t = np.concatenate([self.ta[rows], inner, self.tb[rows]])
            node_x = np.concatenate([self.xa[:, rows], nodes, self.xb[:, rows]], axis=1)
            _, weights = self.combination(int(b), node_t, node_x)
            corners = self.blocks[int(b)][2]
            blended = np.zeros((len(names), node_t.size))
            with np.errstate(all="ignore"):
                for c, corner in enumerate(corners):
                    if np.any(weights[c] != 0):
                        corner_values = evaluate(node_t, node_x, np.broadcast_to(corner, (node_t.size,
                                                                                                     corner.size)))
                        blended += weights[c] * np.where(weights[c] != 0, corner_values, 0.0)
            m = rows.size
            values[:, rows, 0] = blended[:, :m]
            values[:, rows, 1:4] = blended[:, m:4 * m].reshape(-1, m, 3)
            values[:, rows, 4] = blended[:, 4 * m:]
        if np.any(self.sliding & (self.block < 0)):
            # the Filippov combination is the runtime's: interpolate its recorded values, by a cubic
            # spline through the points of each sliding span (the motion is smooth there)
            recorded_t = np.asarray(self.result.t, dtype=float)
            mid = 0.5 * (self.ta + self.tb)
            kept = self.result.outputs if kind == "outputs" else self.result.variables
            recorded = np.array([np.asarray(kept[name], dtype=float) for name in names]).reshape(len(names), -1)
            increasing = (bool(np.all(np.diff(mid) > 0)), bool(np.all(np.diff(recorded_t) > 0)))
            for start, end in _sliding_spans(self.result.events, float(recorded_t[-1])):
                rows = _inside(mid, increasing[0], start, end)
                rows = rows[self.sliding[rows] & (self.block[rows] < 0)]
                # the points of (start, end]: the one recorded at the span's start holds the values
                # from before its event (a restart keeps a repeated time's first record), which a
                # pwm source's effort, for one, does not share with the span
                points = _inside(recorded_t, increasing[1], start, end, closed=True)
                points = points[recorded_t[points] > start] if start > recorded_t[0] else points
                if rows.size == 0:
                    continue
                # one spline through every variable that is finite there (column by column, as
                # many splines would be), linear interpolation for the others
                splined = np.all(np.isfinite(recorded[:, points]), axis=1) if points.size >= 4 else \
                    np.zeros(len(names), dtype=bool)
                if np.any(splined):
                    from scipy.interpolate import CubicSpline

                    spline = CubicSpline(recorded_t[points], recorded[splined][:, points].T, axis=0)(times[rows])
                    values[np.flatnonzero(splined)[:, None], rows[None, :], :] = np.moveaxis(spline, -1, 0)
                for i in np.flatnonzero(~splined):
                    values[i, rows, :] = np.interp(times[rows], recorded_t[points], recorded[i, points]) \
                        if points.size else np.interp(times[rows], recorded_t, recorded[i])
        return times, {name: values[i] for i, name in enumerate(names)}

    def states_at_bounds(self) -> dict:
        """State name -> (value at the start of each step, value at its end)."""
        return {name: (self.xa[i], self.xb[i]) for i, name in enumerate(self.model.state_names)}
