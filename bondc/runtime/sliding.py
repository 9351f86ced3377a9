"""Filippov sliding (:class:`_Sliding`, a mixin of ``_Run``): the switches that can be held on
their surfaces, the corners and weights of the combination, affine holds, sliding segments and
their ends, holding at a stall."""

import numpy as np

from bondc.runtime.policy import SlidingLaw, TooManyHeld, corner_weights, filippov_alpha, first_end
from bondc.runtime.results import RunFailure, _Stop
from bondc.runtime.solvers import CvodeSolver, IDA, difference_jacobian


_MAX_SLIDING = 8         # switches sliding at once in the multilinear combination (2**8 corners) ...
_MAX_HELD = 4096         # ... and in the affine one (k + 1 corners), when the laws combine linearly
SLIDING_CHECKS = 1000    # a sliding mode's exits are tested at least this often over the run's span


class _Sliding:
    """Filippov sliding: the candidates on their surfaces, the corners and weights, affine holds,
    sliding segments and their ends, holding at a stall. A mixin of :class:`_Run`."""

    def hold_at_stall(self, stalled, t_stop):
        """After the unfrozen law stalled at (t, y): slide on every switch close to its surface
        there, or stop the run with the stall's diagnosis when they cannot be held."""
        t, y = stalled.t, stalled.y
        modes = self.modes_at(t, y)
        index = np.array([k for k in self.event_switches if not self.model.floor_switches[k]], dtype=int)
        near = []
        if index.size:
            values = np.abs(self.switches_at(t, y, modes, index))
            bands = np.maximum(100 * self.deadbands(t, y, modes, index), 1e-12)
            relevant = self.relevant(t, y, modes)
            near = [int(k) for k, value, band in zip(index, values, bands) if value <= band and relevant[k]]
        # a law continuous across its surface holds nothing there (its two sides' laws agree): it
        # may only be held where the motion keeps to the surface anyway (a valve at rest between
        # equal pressures), not where it crosses (a pressure drop changing sign)
        steep = [k for k in near if self.continuous_across(t, y, modes, k) and not self.keeps_to(t, y, modes, k)]
        near = [k for k in near if k not in steep]
        if steep and not near:
            # a law continuous across its surface but too steep there for the solver (a square
            # root at 0): it is crossed, never held, and cannot be integrated as written
            named = "; ".join(self.model.SWITCHES[k] for k in steep)
            raise _Stop(stalled.failure.replace(
                message=f"the simulation stalled at t={t:.6g}: the law of {named} is continuous there but "
                        f"infinitely steep (a square root at 0), and the solver makes no headway through it",
                variable=self.model.SWITCH_OWNERS[steep[0]],
                cause="a law like sign(dp)*sqrt(abs(dp)) has an infinite slope at dp = 0: near it the time "
                      "constant of what it feeds goes to zero",
                hint="give the law a laminar band around 0, as real orifices have: if abs(dp) < dp_l then "
                     "K*dp/sqrt(dp_l) else K*sign(dp)*sqrt(abs(dp)) (std:hydraulics's LaminarTurbulentOrifice)"))
        if near and len(near) <= _MAX_HELD:
            held, modes, alpha = self.consistent_sliding_set(t, y, modes, near)
            if held:
                t_new, y_new = self.sliding_segment(t, y, modes, held, alpha, t_stop)
                return t_new, y_new, held
        if len(near) > _MAX_HELD:
            raise _Stop(self.too_many_held(t, near, f"more than {_MAX_HELD}"))
        raise _Stop(stalled.failure)

    def law(self) -> SlidingLaw:
        """The model's laws at the run's parameters as the engine's C functions call them (made once)."""
        if self.sliding_law is None:
            self.sliding_law = SlidingLaw(self.model, self.p)
        return self.sliding_law

    def too_many_held(self, t, near, why):
        """The failure of a run whose switches on their surfaces at (t, y) cannot be held together."""
        named = "; ".join(self.model.SWITCHES[k] for k in near[:4]) + ("; ..." if len(near) > 4 else "")
        return RunFailure(message=f"the simulation stalled at t={t:.6g}: {len(near)} switches are on their "
                                  f"surfaces at once ({named}), and {why}",
                          time=float(t), kind="events", variable=self.model.SWITCH_OWNERS[near[0]],
                          cause=f"holding {len(near)} switches at once (dry frictions that stick together) "
                                f"combines 2^{len(near)} laws; beyond {_MAX_SLIDING}, bondc holds them only where "
                                "each one's law enters the motion linearly (a friction force added to sums of "
                                f"forces), at most {_MAX_HELD} at a time",
                          hint="give some of these laws a narrow linear band around zero velocity (for a "
                               "friction, e = if abs(f) < v_band then F_s*f/v_band else coulomb(f, F_c, F_s)), "
                               "or join parts that always move together into one mass")

    def onto_surfaces(self, t, y, modes, held, alpha):
        """The state at the end of a sliding segment, back on the surfaces of the switches it held,
        where they are still held there (the segment ended at another switch's event or a known
        time, not at a break-away).

        In the Filippov motion they stay at g = 0; the integration lets them drift (a stuck mass's
        momentum by 1e-10 over 0.7 s, a hundred times its tolerance). Where that drift is more than
        the switch's deadband, the restart would no longer see the switch on its surface, and a
        friction held by its static limit would slide off at the next unrelated event. The
        smallest correction, each state weighted by its tolerance, that makes every held g zero
        (one Newton step; g is linear in the states for a velocity); only for a drift (at most 1e6
        deadbands) and where every weight of the sliding combination is still inside (0, 1)
        (``bondc_onto_surfaces``, the engine's one implementation)."""
        return self.law().onto_surfaces(t, y, modes, held, self.affine_key(modes, held) in self.affine_sets,
                                        self.vertices_now(), alpha, self.probe, self.scale_at(y), self.floors_c)

    def sliding_candidates(self, t, y, modes, chattering):
        """Switches that may slide at (t, y): those that chatter, and those on their surface that
        either slid until now or are ``coulomb`` frictions (whose static limit can hold them even
        where each side's sliding law alone would move away); none whose law is continuous across
        its surface (``bondc_sliding_candidates``, the engine's one implementation)."""
        if not self.switch_count:
            return []
        located = np.zeros(self.switch_count, dtype=np.intc)
        located[np.asarray(self.event_switches, dtype=int)] = 1
        slid = np.zeros(self.switch_count, dtype=np.intc)
        slid[np.asarray(self.sliding_now, dtype=int)] = 1
        return self.law().candidates(t, y, modes, chattering, self.scale_at(y), located, slid,
                                     self.relevant(t, y, modes), self.vertices_now(), self.floors_c)

    def affine_key(self, modes, sliding):
        """The key of ``affine_sets`` for the switches ``sliding`` held with the others' ``modes``:
        the modes with each held switch on its minus side, and the held switches."""
        base = np.array(modes, dtype=float)
        vertices = self.vertices_now()
        for k in sliding:
            base[k] = -vertices[k]
        return base.tobytes(), tuple(sliding)

    def scale_at(self, y):
        """Each state's error tolerance at y: atol + rtol*|y|."""
        return self.options["atol"] + self.options["rtol"] * np.abs(np.asarray(y, dtype=float))

    def vertices_now(self):
        """Each switch's vertex now: the model's, or 1 for a coulomb friction held between its
        sliding forces (``vertex_override``)."""
        return np.array([self.vertex_override.get(k, vertex) for k, vertex in enumerate(self.model.SWITCH_VERTICES)],
                        dtype=float)

    def keeps_to(self, t, y, modes, k) -> bool:
        """Whether the motion keeps to switch ``k``'s surface near (t, y) (``bondc_keeps_to``): on
        the surface (where a continuous law's two sides agree), g moves by less than its deadband
        over a thousandth of the run."""
        return self.law().near("keeps", t, y, modes, k, self.vertices_now()[k], self.scale_at(y), self.floors_c,
                               self.probe, self.span)

    def continuous_across(self, t, y, modes, k) -> bool:
        """Whether the law is continuous across switch ``k``'s surface near (t, y), as a turbulent
        orifice's sign(dp)*sqrt(abs(dp)) is at dp = 0 (``bondc_continuous_across``): such a switch
        is crossed, never held (each side's law past the surface gives the flow of the other
        direction, and from a state a little off the surface the two seem to push towards it). A
        discontinuity (a friction's) keeps its size as the surface nears; a continuous law's jump
        vanishes there."""
        return self.law().near("continuous", t, y, modes, k, self.vertices_now()[k], self.scale_at(y),
                               self.floors_c)

    def switch_rate(self, t, y, slope, modes, k):
        """d g_k / dt along ``slope`` with the modes frozen (central difference over the probe step);
        ``k`` an index or an array of them."""
        h = self.probe
        ahead = self.model.switches(t + h, y + h * slope, self.p, modes)[k]
        behind = self.model.switches(t - h, y - h * slope, self.p, modes)[k]
        return (ahead - behind) / (2 * h)

    def sliding_corners(self, modes, sliding, affine=None):
        """The mode vectors at the corners of the sliding set and their sides (+1/-1 per switch).

        Each sliding switch takes its vertex value on each side: 1 for a sign or an if, 2 for a
        ``coulomb`` friction (its frozen law gives the static limit there). Either all 2**k corners
        (the multilinear combination) or the k + 1 corners of the affine one: every switch on its
        minus side, then each one alone on its plus side. ``affine`` None: the affine one where
        :meth:`sliding_set` found that the laws combine so (the first corner, all minus, is the
        same in both).
        """
        vertices = self.vertices_now()
        count = len(sliding)
        if affine is None:
            affine = self.affine_key(modes, sliding) in self.affine_sets
        if affine:
            sides = np.vstack([-np.ones((1, count)), 2.0 * np.eye(count) - 1.0])
        else:
            sides = np.array([[1.0 if (c >> i) & 1 else -1.0 for i in range(count)] for c in range(2 ** count)])
        corners = np.repeat(np.asarray(modes, dtype=float)[None, :], len(sides), axis=0)
        for i, k in enumerate(sliding):
            corners[:, k] = sides[:, i] * vertices[k]
        return corners, sides

    corner_weights = staticmethod(corner_weights)

    def sliding_rates(self, t, y, corners, sliding):
        """Right-hand side at each corner and the rate of each sliding switch's g along it."""
        values = np.array([self.rhs(t, y, corner) for corner in corners])
        index = np.asarray(sliding, dtype=int)
        rates = np.array([self.switch_rate(t, y, values[c], corners[c], index) for c in range(len(corners))])
        return values, rates

    solve_alpha = staticmethod(filippov_alpha)

    def consistent_sliding_set(self, t, y, modes, candidates):
        """Which of ``candidates`` slide at (t, y) and the modes of the others
        (``bondc_consistent_sliding_set``, bondc/native/filippov.c, the engine's one implementation):
        complementarity by an active set (a switch whose weight leaves [0, 1] cannot be held and
        takes that side), with the other switches' modes chosen just after (t, y) along the sliding
        motion itself: one that flips there takes its new mode, one that flips back and forth joins
        the sliding set. A coulomb switch held between its sliding forces is noted in
        ``vertex_override``, an affine combination in ``affine_sets`` (for :meth:`sliding_corners`).

        Returns (sliding switches, modes, alpha).
        """
        law = self.law()
        scale = self.options["atol"] + self.options["rtol"] * np.abs(np.asarray(y, dtype=float))
        located = np.zeros(max(self.switch_count, 1), dtype=np.intc)
        located[np.asarray(self.event_switches, dtype=int)] = 1
        try:
            held, modes, alpha, vertices, affine = law.sliding_set(
                t, y, modes, candidates, self.probe, self.span, scale, located,
                relevant=lambda m: self.relevant(t, y, m), floors=self.floors_c)
        except TooManyHeld:
            raise _Stop(self.too_many_held(t, list(candidates), "their laws do not combine linearly")) from None
        given = self.model.SWITCH_VERTICES
        self.vertex_override = {k: float(vertices[k]) for k in range(self.switch_count) if vertices[k] != given[k]}
        if held:
            key = self.affine_key(modes, held)
            if affine:
                self.affine_sets.add(key)
            else:
                self.affine_sets.discard(key)
        return held, modes, alpha

    def sliding_segment(self, t, y, modes, sliding, alpha0, t_stop):
        """Integrate a sliding mode on the switches ``sliding`` (Filippov, any number at once).

        The right-hand side is the multilinear combination of the corners of the sliding set
        whose weights keep every sliding ``g`` constant (for friction: the holding forces), until
        a weight reaches 0 or 1 (a holding force reaches its limit: break-away), another switch
        crosses, or ``t_stop``. Returns (t, y).
        """
        self.stats["segments"] += 1
        self.stats["sliding_segments"] = self.stats.get("sliding_segments", 0) + 1
        corners, sides = self.sliding_corners(modes, sliding)
        corner_ids = [self.mode_id(corner) for corner in corners]
        labels = "; ".join(self.model.SWITCHES[k] for k in sliding)
        ended = f"sliding on {labels} ends"
        again = [i for i in range(len(self.events) - 1, -1, -1)
                 if self.events[i] == (float(t), ended)]
        if again:               # the same switches held again at once (another switch's event between):
            del self.events[again[0]]       # one sliding span goes on, not an end and a start
        else:
            self.note_event(t, f"sliding on {labels}")
        others = np.array([j for j in self.event_switches if j not in sliding and modes[j] != 0], dtype=int)
        # a switch that starts a little on the far side of its surface (a sliding mode drifts by the
        # solver's tolerance, and a friction may leave from there): it exits from where it starts
        drift = np.zeros(others.size)
        if others.size:
            start = modes[others] * self.model.switches(t, y, self.p, modes)[others]
            drift = np.where(self.model.floor_switches[others], 0.0, np.maximum(0.0, -start))
        memory = {"alpha": np.array(alpha0, dtype=float)}
        sundials = self.method is IDA or issubclass(self.method, CvodeSolver)
        # scipy's implicit solvers declare their Newton iteration diverging where one correction is
        # not smaller than the one before, even at the level of rounding: the combination must be a
        # function of (t, y) alone. Solved from the last weights, the weights of two held frictions
        # came out an ulp apart from call to call, a held mass's rate flipped between +-2e-16, and
        # BDF stopped at t = 0.2 ms. The weights are solved from those at the mode's start there;
        # SUNDIALS, whose convergence test is absolute, keeps solving from the last ones (as C does)
        start = None if sundials else np.array(alpha0, dtype=float)

        def combination(tt, yy):
            values, rates = self.sliding_rates(tt, yy, corners, sliding)
            alpha = self.solve_alpha(rates, sides, memory["alpha"] if start is None else start)
            if np.all(np.isfinite(alpha)):
                memory["alpha"] = alpha
            return values, alpha

        def fun(tt, yy):
            values, alpha = combination(tt, yy)
            return self.corner_weights(np.clip(alpha, 0.0, 1.0), sides) @ values

        def jac(tt, yy):
            _, alpha = combination(tt, yy)
            weights = self.corner_weights(np.clip(alpha, 0.0, 1.0), sides)
            return sum(w * self.jac(tt, yy, corner) for w, corner in zip(weights, corners) if w != 0)

        def differences(tt, yy):
            # scipy's implicit solvers: the combination's own Jacobian, the weights' dependence on the
            # state included. The corners' weighted Jacobians leave it out, and Radau's Newton iteration
            # then fails step after step (a held mass pulled through a spring: 5 201 steps in 20 s
            # where 412 do). The SUNDIALS solvers cope with the weighted ones.
            with np.errstate(all="ignore"):
                return difference_jacobian(fun, tt, yy, np.asarray(fun(tt, yy), dtype=float))

        def exits(tt, yy):      # every entry stays positive while sliding lasts
            _, alpha = combination(tt, yy)
            values = list(alpha) + list(1.0 - alpha)
            if others.size:
                values += list(modes[others] * self.model.switches(tt, yy, self.p, modes)[others] + drift)
            return np.array(values, dtype=float)

        def weights_at(times, states):
            return np.array([self.corner_weights(np.clip(combination(ti, states[:, i])[1], 0.0, 1.0), sides)
                             for i, ti in enumerate(times)]).T

        if (len(self.blocks_t) == 1 and self.blocks_t[0].size == 1 and self.blocks_t[0][0] == t
                and t == self.t_start):
            # the initial point: its outputs are those of the sliding combination too
            self.blocks_mode[0] = ("slide", tuple(corner_ids), weights_at(self.blocks_t[0], self.blocks_x[0]))
        driver = None
        if not any(self.model.floor_switches[k] for k in sliding):
            driver = self.driver_for(others, ())
        if driver is not None:
            outcome = self.driver_sliding(driver, t, y, modes, sliding, corners, sides, corner_ids, others,
                                          drift, memory, weights_at, labels, t_stop)
            if outcome[0] != "handover":
                return outcome
            _, t, y = outcome       # a law not finite at a trial point: the step loop goes on and explains
        solver = self.new_solver(fun, jac if sundials else differences, t, y, t_stop)
        old = np.maximum(exits(t, y), 0.0)      # at the edge of the sliding region: leaving counts from here
        while True:
            message = solver.step()
            self.stats["steps"] += 1
            if solver.status == "failed":
                self.collect(solver)
                raise _Stop(self.solver_failure(solver.t, message))
            t_new, y_new = solver.t, solver.y
            if not (np.all(np.isfinite(y_new)) and np.all(np.isfinite(fun(t_new, y_new)))):
                self.collect(solver)
                self.stop_nonfinite(solver, fun, lambda tt, yy: corners[-1], corner_ids[-1])
            new = exits(t_new, y_new)
            dense = solver.dense_output()
            hit = self.sliding_end_within(old, new, lambda tt: exits(tt, dense(tt)), solver.t_old, t_new)
            end = t_new if hit is None else hit
            y_end = y_new if hit is None else dense(hit)
            self.record_sliding(solver.t_old, end, y_end, dense, corner_ids, weights_at)
            if self.progress is not None:
                self.progress(end)
            if hit is not None or solver.status == "finished":
                self.collect(solver)
                if hit is not None:
                    self.note_event(end, f"sliding on {labels} ends")
                return end, np.array(y_end)
            old = new

    def sliding_end_within(self, old, new, exits_at, t_old, t_new):
        """The end of a sliding mode inside the step (t_old, t_new] (``bondc_first_end``, the
        engine's one implementation): its exits tested at the step's ends, every
        :meth:`sliding_check` inside it (a mode whose states stand still gives the solver nothing to
        limit its steps by, while the force that holds it may pass the limit and come back within
        one step), and for a dip between two tests; or None."""
        return first_end(exits_at, t_old, t_new, old, new, self.sliding_check())

    def sliding_check(self) -> float:
        """The longest stretch of a sliding mode whose exits are tested only at its ends: the run's
        span over SLIDING_CHECKS, or its max_step where that is shorter."""
        return min(self.span / SLIDING_CHECKS, float(self.options.get("max_step", np.inf)))

    def record_sliding(self, t_old, t_new, y_new, dense, corner_ids, weights_at):
        if self.t_eval is None:
            times = np.array([t_new])
            states = np.asarray(y_new, dtype=float).reshape(-1, 1)
        else:
            stop = np.searchsorted(self.t_eval, t_new, side="right")
            times = self.t_eval[self.eval_index:stop]
            self.eval_index = stop
            if times.size == 0:
                return
            states = np.column_stack([y_new if ti == t_new else dense(ti) for ti in times])
        self.blocks_t.append(times)
        self.blocks_x.append(states)
        self.blocks_mode.append(("slide", tuple(corner_ids), weights_at(times, states)))
