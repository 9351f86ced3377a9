"""The run loop of bondc's runtime: switching modes, events, integration.

Takes a *model*: a generated module's namespace (its ``globals()``, the module
itself, or any object) with these names, all written by ``bondc.codegen``:

- ``STATE_NAMES``, ``OUTPUT_NAMES``, ``VARIABLE_NAMES`` (every assigned
  variable in causal order), ``VARIABLE_LAWS`` (their laws as text, for
  diagnostics), optionally ``VARIABLE_ROWS`` (the result's row of each variable:
  variables that ``_variables`` returns as one expression share a read-only row),
  ``PARAMETERS`` (name -> SI default, in the order of ``p``),
  ``SWITCHES`` (one label per switching function), ``EVENT_SWITCHES`` (the
  indices of switches located as events; the others only change at known
  times), ``DEFAULTS`` (solver settings of the experiment);
- ``x0(p)``; ``_rhs(t, x, p, m)``, ``_jac(t, x, p, m)``, ``_outputs(t, x, p, m)``,
  ``_variables(t, x, p, m)``: the model with every discontinuous choice frozen
  by the mode vector ``m``; ``_switches(t, x, p, m)``: the switching functions;
  ``_time_breaks(p)``: ``(time, label, kind)`` of switches known in advance.

Returns :class:`Result` from :func:`simulate_model`.

The run loop: :func:`simulate_model` builds one :class:`RunSpec` and a :class:`_Run`, whose
step loop integrates segments between events (see the package docstring for the other modules).

The runtime imports only numpy, scipy and the standard library (and SUNDIALS'
scikit-sundae where CVODE runs, with LSODA as the fallback without it): bondc
copies its modules into every standalone generated module, so a generated module runs where bondc
is not installed, and ``bondc simulate`` runs the same code in-process. Its C and C++
(the CVODE driver, the explicit stepper) are the files of ``bondc/native``, which such a
module carries too (``_NATIVE_FILES``).

The integrator
--------------
By default SUNDIALS CVODE (BDF, Newton, the analytic Jacobian) through
scikit-sundae, driven one internal step at a time by :class:`CvodeSolver`;
scipy's ``solve_ivp`` methods by name. No integrator is written here.

How discontinuities are handled
-------------------------------
Every ``if`` condition, ``sign``, ``step``, ``table`` corner, ``floor`` (and
``ceil``, ``mod``), ``pwm`` and ``coulomb`` of a model is a *switch*: a
continuous switching function ``g`` (``lhs - rhs`` of a condition, the argument
of sign/coulomb/floor, ``x - x_i`` of a table corner) whose sign (for ``floor``:
whose integer part) selects a smooth piece of the law. ``abs``, ``min`` and
``max`` are continuous and evaluated as they are. The integrator never steps
across a switch blindly:

1. A *segment* is integrated with every switch frozen in its mode
   ``m = sign(g)`` (-1, 0 or +1; ``floor(g)`` for a floor switch), so the
   right-hand side and the analytic Jacobian the solver sees are smooth (an
   ``if`` takes one branch, a table one linear piece).
2. The switches the frozen law actually reads (only the active branch of an
   ``if`` reads its modes; ``SWITCH_DEPENDS`` adds what their switching
   functions read) are event functions: after each step, a switch whose
   ``m*g`` fell below ``-deadband`` has crossed (a mode-0 switch, sitting
   exactly on its surface, when ``|g|`` leaves the band; a floor switch when
   ``g`` leaves ``[m, m + 1)``). The crossing time is found with ``brentq`` on
   the solver's dense output (the zero of ``g`` itself when it lies in that
   step), the segment ends there and the mode change is recorded as an event.
   The deadband is how far ``g`` moves when the state moves by its error
   tolerance (``atol + rtol*|x|``): shallower crossings are integration noise
   (a chamber pressure sitting at its regulator's set point), not events.
   Crossings of switches the law does not read change nothing the solver
   sees; outputs still get the right mode at every point.
3. Switches of time only are known in advance: segments simply end at those
   times; nothing is root-found. Linear ones (``step(t, t0)``, table corners in
   ``t``, ``t < t1``) from their parameter expressions; the others
   (``TIME_SWITCHES``: ``pwm(t, f, d)``, ``if sin(2*pi*f*t) > c``, ``floor(t*f)``)
   by sampling ``g`` on a grid refined until its number of sign changes is
   stable, a cell the slope around it could carry across zero sampled finer
   (``_hidden_changes``: a pulse narrower than the grid), all refined at once by
   bisection (``bracketed_roots``, brentq's tolerance): a pulse shorter than a
   solver step is not skipped. csv sample
   times are listed when there are at most 200; a denser measured signal
   instead caps ``max_step`` at its median spacing. With the native driver the
   segments between these times and the simple restarts at them run hundreds
   at a time in one C call (``_Run.queued_piece``), the same to the bit.
4. At every restart the modes are chosen *just after* the restart point: the
   state is advanced by a probe ``h = 1e-8 * span`` along the frozen law and
   ``m = sign(g)`` is taken there, iterated until the modes agree with the law
   they select, or until they cycle (a sliding mode): ``bondc_select_modes``
   (bondc/native/filippov.c), the one implementation the driver, an FMU and
   this loop share.
5. Sliding. When modes do not agree with themselves at a restart (each side's
   law pushes the state back across the surface, as friction does when it
   sticks), or a ``coulomb`` friction or a switch that slid until now sits on
   its surface, those switches are candidates for a sliding mode, any number
   at once. The segment follows Filippov's combination: the multilinear blend
   of the right-hand sides at the corners of the candidates' modes (``+-1``;
   ``+-2`` for a ``coulomb`` friction, whose frozen law gives its static limit
   there), with weights ``alpha`` solved by Newton's method so that every
   sliding ``g`` stays put (rates by central differences). From three
   switches on, where the right-hand side is affine in the weights (checked
   on pairs of switches), the affine blend of k + 1 corners instead of 2**k; the
   multilinear one takes at most ``_MAX_SLIDING`` switches. A switch whose
   sides give the same right-hand side (a free clutch) is not held. A switch
   whose weight leaves [0, 1] cannot be held (the force needed exceeds its
   limit) and leaves on that side; the others are solved
   again (complementarity by active set). The segment ends when a weight
   reaches 0 or 1 (break-away), another switch crosses, or a known time;
   outputs are the same combination (the friction forces that hold). With the
   native CVODE driver, a sliding mode on one switch is integrated in C (the
   weight is then ``rate- / (rate- - rate+)``, the same formula), batches of
   steps at a time; several switches too (Newton's method on their weights
   with Gaussian elimination), handing over to Python where that is singular.
6. Chattering. When events come faster than ``max_event_rate`` per 1/1000 of
   the run, or repeat without time advancing, the next short interval ``tau``
   is integrated with the *unfrozen* law (modes recomputed at every
   evaluation, no events; retried with RK23 if the implicit solver gives up);
   ``tau`` starts at 1e-6 of the run and doubles while this continues (at most
   1/100 of the run). Where that stalls (switching accumulating at a point,
   the motion coming to rest), the switches near their surfaces there are
   held as a sliding mode; if they cannot be, the run stops (E812). Every
   sliding and chattering episode is listed in ``Result.events``.

A non-finite state or derivative ends the run: the result keeps every point
computed before it, ``complete`` is False and ``failure`` names the time, the
variable that first became nan or inf (in causal order) and its law.
"""

import collections as _collections
import dataclasses
import math
import time as _time_module

import numpy as np

from bondc.runtime.kernels import _EPS
from bondc.runtime.signals import _with_inputs, external_inputs
from bondc.runtime.loops import _BLOCK_SOLUTIONS
from bondc.runtime.adapter import _Model, _model_memo, param_array
from bondc.runtime.results import (
    DIVERGED, MAX_VALUES, RunFailure, _CountedBlocks, _Diagnosis, _ResultBuilder, _Stalled, _Stop, max_points
)
from bondc.runtime.native import NativeUnavailable, attach_native, compiler_label
from bondc.runtime.solvers import (
    DEFAULT_SOLVER, IDA, _CREEP, _CREEP_STEPS, _IMPLICIT, _SolverChoice, _UNFROZEN_STEPS, _all_finite, _creeping,
    solver_class, stiff_solver
)
from bondc.runtime.driver import _DriverSegments
from bondc.runtime.events import _EventLocation
from bondc.runtime.sliding import _MAX_HELD, _Sliding


@dataclasses.dataclass(frozen=True, eq=False)
class RunSpec:
    """What one run integrates, settled once by :func:`simulate_model`: the model (the run's own
    :class:`_Model` copy, its C functions attached where they run), the parameter vector, the span
    and the reported times, the solver and its settings, and the guards on events. The run's parts
    read it; nothing changes it.

    ``method``: a solver's name, "auto" or a solver class; ``progress(t)``: called after every
    step; ``inputs``: the external inputs' signals, checked (see :class:`RunFailure` on why the
    types are an explicit ``__annotations__``)."""

    __annotations__ = {"model": object, "parameters": np.ndarray, "t_start": float, "t_end": float,
                       "t_eval": np.ndarray | None, "method": object, "rtol": float, "atol": float,
                       "max_step": float, "first_step": float | None, "progress": object, "max_events": int,
                       "max_event_rate": float, "inputs": dict}
    first_step = None
    progress = None
    max_events = 100000
    max_event_rate = 100
    inputs = dataclasses.field(default_factory=dict)


_STALL_FRACTION = 1e-7  # restarts that advance time by less than this fraction of the run ...
_STALL_RESTARTS = 5000  # ... this many times in a row mean the run is stalled


class _Run(_EventLocation, _Sliding, _DriverSegments, _SolverChoice):
    """One simulation run of a model: segments between events, recorded points."""

    def __init__(self, spec: RunSpec):
        self.spec = spec
        model, p, t_start, t_end, t_eval = spec.model, spec.parameters, spec.t_start, spec.t_end, spec.t_eval
        method, rtol, atol, max_step, first_step = spec.method, spec.rtol, spec.atol, spec.max_step, spec.first_step
        self.model = model
        self.p = p
        self.diagnosis = _Diagnosis(model, p)
        self.t_start, self.t_end = float(t_start), float(t_end)
        self.span = self.t_end - self.t_start
        self.t_eval = None if t_eval is None else np.asarray(t_eval, dtype=float)
        self.eval_index = 0
        # auto: the stiff solver until choose_solver (at the start) finds the model not stiff
        self.auto = isinstance(method, str) and method.strip().lower() == "auto"
        self.method = solver_class(stiff_solver() if self.auto else method)
        self.stiffness_check = self.STIFFNESS_CHECK          # steps of DOPRI5 before auto looks again
        self.options = {"rtol": rtol, "atol": atol, "max_step": max_step}
        if first_step is not None:
            # a first step that the creep guard counts as not advancing (first_step = 1e-300) would
            # stop the run before the step size grows: it starts at the smallest step that advances
            self.options["first_step"] = max(first_step, 10 * _CREEP * max(abs(t_start), 1.0))
        self.implicit = self.method.__name__ in _IMPLICIT
        self.progress = spec.progress
        self.max_events = spec.max_events
        self.max_event_rate = spec.max_event_rate
        self.switch_count = len(model.SWITCHES)
        # the switches of when conditions: their edges are the clauses' own business (a firing is
        # noted as such), not events of the model's laws
        self.condition_switches = frozenset(k for k, owner in enumerate(model.SWITCH_OWNERS)
                                            if owner.startswith("when "))
        self.event_switches = np.asarray(model.EVENT_SWITCHES, dtype=int)
        self.probe = 1e-8 * max(self.span, abs(self.t_end), 1e-300)
        self.tau_min = 1e-6 * self.span
        self.tau = self.tau_min
        self.chattering_since = None
        self.recent_events = []
        self.recent_switches = []      # (time, switch) of the latest located mode changes
        # recorded points: lists of time arrays, state blocks (n, k) and mode ids
        self.blocks_t, self.blocks_x, self.blocks_mode = [], [], _CountedBlocks(self)
        width = len(model.STATE_NAMES) + len(model.OUTPUT_NAMES) + len(model.VARIABLE_NAMES)
        self.max_points = max_points(width)
        self.points = 0
        self.mode_table = {}
        self.events = []
        self.stats = {"nfev": 0, "njev": 0, "nlu": 0, "steps": 0, "segments": 0, "mode_changes": 0,
                      "chattering_intervals": 0}
        self.bad = None
        self.last_relevant = np.ones(self.switch_count, dtype=bool)
        # mode vector -> the switches its law's active branches read: the model's, for every run
        self.relevant_by_modes = _model_memo(model, "relevant")
        self.sliding_now = []          # the switches of the last sliding segment
        self.vertex_override = {}      # coulomb switches held between their sliding forces
        self.affine_sets = set()       # sets of switches held in the affine combination ...
        self.sliding_law = None        # the model's laws as bondc/native/filippov.c calls them (made once)
        self.floors_c = np.ascontiguousarray(model.floor_switches, dtype=np.intc)   # for the native driver
        # the when clauses' targets (offsets, indices) where C runs their statements (attach_native)
        offsets = model.when_offsets if getattr(model, "native_library", None) is not None else None
        self.when_targets = None if offsets is None else (
            offsets, np.ascontiguousarray([i for targets in model.WHEN_TARGETS for i in targets] or [0],
                                          dtype=np.intc))
        self.jumps = []                # (t, state before, state after) of every when clause that fired
        self.when_times = {}           # when clause -> its last firing times (Zeno detection)
        self.extended = None           # modes of the last right-hand side taken beyond a switch
        self._dense = None
        self._driver = None            # the native CVODE driver: None (not tried yet), False (none)
        self.break_times = np.zeros(0)  # the run's known breaks (times), for the pieces between them
        self.queue = _collections.deque()   # pieces integrated ahead (see queued_piece)
        self._pieces = None            # whether pieces can be integrated ahead: None (not decided yet)
        self.pieces_skip, self.pieces_backoff = 0, 1    # segments not to try it for, after calls that
                                                        # ended inside their first piece (see queued_piece)

    def _consistent_blocks(self) -> None:
        """Drop what an interruption (Ctrl-C lands between any two statements) left half recorded:
        a block whose times, states or mode were not all appended, or whose times and states
        differ in length."""
        count = min(len(self.blocks_t), len(self.blocks_x), len(self.blocks_mode))
        del self.blocks_t[count:], self.blocks_x[count:], self.blocks_mode[count:]
        while self.blocks_t and np.shape(self.blocks_x[-1])[-1] != np.size(self.blocks_t[-1]):
            self.blocks_t.pop(), self.blocks_x.pop(), self.blocks_mode.pop()

    # -- failures

    def solver_failure(self, t, message):
        if self.bad is not None and self.bad[0] >= t - 1e-6 * max(self.span, 1e-300):
            failure = self.diagnosis.nonfinite(*self.bad, context=f"the solver could not go past t={t:.6g}: ")
            return failure.replace(time=float(t), solver_message=message)
        method = self.method.__name__
        hint = ("try a stiff solver (solver = \"CVODE\" in the experiment)" if not self.implicit
                else "check the laws near that time for a singularity or a switch bondc cannot see "
                     "(a discontinuity hidden in a smooth-looking function), or loosen rtol/atol")
        return RunFailure(message=f"the solver ({method}) failed at t={t:.6g}: {message}", time=float(t),
                          variable=None, law=None,
                          cause="the step size became too small: the model is stiffer than the method can "
                                "handle, a variable grows without bound, or the right-hand side is discontinuous",
                          hint=hint, kind="solver", solver_message=message)

    def stop_nonfinite(self, solver, derivative, modes_of, mode):
        """The last step produced a nan or inf: bisect its dense output for the first non-finite point,
        record the trajectory up to just before it and stop with a diagnosis there."""
        dense = solver.dense_output()
        lo, hi = solver.t_old, solver.t

        def finite(tt):
            yy = dense(tt)
            return bool(np.all(np.isfinite(yy)) and np.all(np.isfinite(derivative(tt, yy))))

        for _ in range(80):
            if hi - lo <= 4 * _EPS * max(abs(hi), 1.0):
                break
            middle = 0.5 * (lo + hi)
            if finite(middle):
                lo = middle
            else:
                hi = middle
        if lo > solver.t_old:
            y_lo = dense(lo)
            self.record(solver.t_old, lo, y_lo, dense,
                        mode if mode is not None else self.mode_id(modes_of(lo, y_lo)))
        y_hi = dense(hi)
        failure = self.diagnosis.nonfinite(hi, y_hi, modes_of(hi, y_hi), "")
        if failure.variable in self.model.STATE_NAMES and self.bad is not None:
            # the solver's own state went bad: name the law that produced the nan it saw
            cause = self.diagnosis.nonfinite(*self.bad, context="")
            failure = cause.replace(message=f"the solver's state became non-finite at t={hi:.6g} after the "
                                            f"right-hand side was evaluated at a trial point where {cause.message}",
                                    time=float(hi))
        raise _Stop(failure)

    def result(self, complete, failure):
        """The run's :class:`Result` (built by :class:`_ResultBuilder` from what it recorded)."""
        self._consistent_blocks()
        return _ResultBuilder(self.model, self.p, self.t_start).build(
            complete, failure, self.blocks_t, self.blocks_x, self.blocks_mode, self.mode_table, self.events,
            self.jumps, self.stats)

    # -- evaluation helpers

    def rhs(self, t, x, modes):
        self.stats["nfev"] += 1
        value = np.asarray(self.model.rhs(t, x, self.p, modes), dtype=float)
        if not math.isfinite(value.sum()) and math.isfinite(np.asarray(x, dtype=float).sum()):
            # A trial point beyond a switch, where the frozen branch is outside its domain
            # (``if e > 0 then sqrt(e) else 0`` at e < 0): take the branches that hold there. The
            # step that reaches it crosses the switch, which is then located as an event.
            here = self.modes_at(t, x, modes)
            if not np.array_equal(here, modes):
                with np.errstate(all="ignore"):
                    other = np.asarray(self.model.rhs(t, x, self.p, here), dtype=float)
                if np.isfinite(np.sum(other)):
                    self.stats["branch_extensions"] = self.stats.get("branch_extensions", 0) + 1
                    self.extended = here
                    return other
            if self.bad is None or np.isfinite(np.sum(x)):
                # the latest non-finite evaluation at a finite state: where a law left its domain
                self.bad = (t, np.array(x, dtype=float), np.array(modes))
        return value

    def jac(self, t, x, modes):
        return np.asarray(self.model.jac(t, x, self.p, modes), dtype=float)

    def modes_at(self, t, x, guess=None):
        if not self.switch_count:
            return np.zeros(0)
        return self.law().modes_at(t, x, guess, self.floors_c)

    def mode_id(self, modes):
        key = tuple(modes)
        return self.mode_table.setdefault(key, len(self.mode_table))

    # -- recording

    def record(self, t_old, t_new, y_new, dense, mode):
        """Record the points of (t_old, t_new]: solver steps, or the t_eval points there."""
        if self.t_eval is None:
            self.blocks_t.append(np.array([t_new]))
            self.blocks_x.append(np.array(y_new, dtype=float).reshape(-1, 1))
            self.blocks_mode.append(mode)
            return
        start = self.eval_index
        stop = np.searchsorted(self.t_eval, t_new, side="right")
        if stop > start:
            times = self.t_eval[start:stop]
            if dense is None:
                dense = self._dense
            states = np.column_stack([y_new if ti == t_new else dense(ti) for ti in times])
            self.blocks_t.append(times)
            self.blocks_x.append(states)
            self.blocks_mode.append(mode)
            self.eval_index = stop

    def record_start(self, t, y, mode):
        if self.t_eval is None:
            self.record(t, t, y, None, mode)
        elif self.eval_index < self.t_eval.size and self.t_eval[self.eval_index] <= t:
            stop = np.searchsorted(self.t_eval, t, side="right")
            self.blocks_t.append(self.t_eval[self.eval_index:stop])
            self.blocks_x.append(np.repeat(np.asarray(y, dtype=float).reshape(-1, 1), stop - self.eval_index, 1))
            self.blocks_mode.append(mode)
            self.eval_index = stop

    def run(self):
        model = self.model
        started = _time_module.perf_counter()
        t, y = self.t_start, np.asarray(model.x0(self.p), dtype=float).reshape(-1)
        complete, failure = True, None
        breaks = self.breaks()
        self.break_times = np.array([tb for tb, _ in breaks], dtype=float)
        break_index = 0
        if self.switch_count:
            try:        # the engine's C functions locate, select and hold the switches
                self.law()
            except NativeUnavailable as why:
                self.record_start(t, y, self.mode_id(np.ones(self.switch_count)))
                return self.result(False, RunFailure(
                    message=f"the model's switches need bondc's engine in C, which cannot be built here: {why}",
                    time=float(t), kind="solver",
                    cause="no C compiler works on this machine (bondc installs one with its dependencies: zig, "
                          "from the ziglang package)",
                    hint="reinstall bondc with its dependencies (pip install bondc), or set CC to a C compiler"))
        if self.auto:       # before the restart, whose C code would make the stiff solver's driver
            self.choose_solver(t, y, self.modes_at(t, y))
        self.stats["solver"] = self.solver_label()
        modes, chattering = self.restart_modes(t, y, None)
        candidates = self.sliding_candidates(t, y, modes, chattering)
        self.passing = None
        self.record_start(t, y, self.mode_id(modes))
        zero_progress = 0
        # Time must advance: restarts that together move it less than this are a stall.
        stall_time, stall_count, stall_span = t, 0, _STALL_FRACTION * max(self.t_end - self.t_start, 1e-300)
        try:
            if not np.all(np.isfinite(y)):
                raise _Stop(self.diagnosis.nonfinite(t, y, modes, "the initial state is not finite: "))
            with np.errstate(all="ignore"):
                if not np.all(np.isfinite(self.rhs(t, y, modes))):
                    raise _Stop(self.diagnosis.nonfinite(t, y, modes, "at the start, "))
            with np.errstate(all="ignore"):
                while t < self.t_end:
                    while break_index < len(breaks) and breaks[break_index][0] <= t:
                        break_index += 1
                    t_stop = breaks[break_index][0] if break_index < len(breaks) else self.t_end
                    sliding, held_now = None, []
                    if t_stop - t <= 16 * _EPS * max(abs(t), abs(t_stop), 1.0):
                        # a sliver too short for any solver (a switch just before a known time): one Euler step
                        slope = self.rhs(t, y, modes)
                        t_new, y_new = t_stop, y + (t_stop - t) * slope
                        self.record(t, t_new, y_new, lambda tt, t0=t, y0=y, s=slope: y0 + (tt - t0) * s,
                                    self.mode_id(modes))
                    elif candidates and zero_progress <= 8 and len(candidates) <= _MAX_HELD:
                        held, modes, alpha = self.consistent_sliding_set(t, y, modes, candidates)
                        self.note_passing(t, modes, held)
                        if held:
                            sliding = held
                            t_new, y_new = self.sliding_segment(t, y, modes, held, alpha, t_stop)
                            y_new = self.onto_surfaces(t_new, y_new, modes, held, alpha)
                        else:               # every side leaves its surface: a frozen segment
                            t_new, y_new, hit = self.segment(t, y, modes, t_stop)
                        held_now = held
                    elif chattering or zero_progress > 8 or self.too_many_events(t):
                        try:
                            t_new, y_new = self.unfrozen_interval(t, y, modes, min(t_stop, t + self.tau))
                        except _Stalled as stalled:
                            # switches accumulating at a point (a Zeno approach to rest): hold the
                            # ones that sit on their surfaces there, all at once
                            t_new, y_new, held_now = self.hold_at_stall(stalled, t_stop)
                            sliding = held_now
                        zero_progress = 0
                    else:
                        t_new, y_new, hit = self.segment(t, y, modes, t_stop)
                        if hit is None and t_new - t > self.tau:
                            self.tau, self.chattering_since = self.tau_min, None
                    self.sliding_now = held_now
                    progress_made = t_new - t > 64 * _EPS * max(abs(t), 1.0)
                    zero_progress = 0 if progress_made else zero_progress + 1
                    old_modes = modes
                    t, y = t_new, y_new
                    self.check_stiffness(t, y, old_modes)
                    if t - stall_time > stall_span:
                        stall_time, stall_count = t, 0
                    else:
                        stall_count += 1
                        if stall_count > _STALL_RESTARTS:
                            raise _Stop(RunFailure(
                                message=f"the simulation stalled at t={t:.6g}: {_STALL_RESTARTS} restarts "
                                        f"advanced time by less than {stall_span:.3g} s",
                                time=float(t), kind="events",
                                cause="several switches (sign, abs, if) keep changing mode together, e.g. "
                                      "friction laws that make the motion stick",
                                hint="smooth the laws near their switching surfaces (a small linear band "
                                     "around zero velocity, for instance)"))
                    at_break = break_index < len(breaks) and t >= breaks[break_index][0]
                    if t >= self.t_end:
                        if at_break:
                            self.note_break(*breaks[break_index])
                        break
                    modes, chattering = self.restart_modes(t, y, old_modes)
                    if model.WHEN_LABELS:
                        y, modes, chattering = self.fire_when_clauses(t, y, old_modes, modes, chattering)
                    candidates = self.sliding_candidates(t, y, modes, chattering)
                    only_candidates = set(candidates) - set(chattering)
                    chattering = sorted(set(chattering) | set(candidates))
                    relevant_now = self.relevant(t, y, modes) | self.last_relevant
                    self.last_relevant = np.ones(self.switch_count, dtype=bool)
                    changed = [k for k in range(self.switch_count) if modes[k] != old_modes[k]
                               and k not in chattering and relevant_now[k]]
                    # a switch on its surface that does not chatter (a friction whose velocity
                    # reaches 0) is a candidate for sliding, not a change: whether it changed is
                    # known once the candidates are decided (note_passing); one that the segment
                    # before held has its own events (its sliding span ends here)
                    self.passing = (t, old_modes, [k for k in sorted(only_candidates) if relevant_now[k]
                                                   and not (sliding is not None and k in sliding)],
                                    bool(changed), self.chattering_since is None)
                    if at_break:
                        self.note_break(*breaks[break_index], changed)
                    # after a sliding segment, the switches it held are its own business; any other
                    # that changed (a step of time at a break) is an event like any: a sliding span
                    # ends there (the energy account's spans end at the next event). While switches
                    # chatter their flips are not noted, but a break's own switch still is
                    known_here = breaks[break_index][1].split("; ") if at_break else ()
                    for k in changed:
                        if sliding is not None and k in sliding:
                            continue
                        if k in self.condition_switches:
                            continue
                        if self.chattering_since is None or model.SWITCHES[k] in known_here:
                            self.note_event(t, self.mode_label(k, modes[k]))
                    if changed:
                        self.stats["mode_changes"] += 1
                        if not at_break:            # changes at known times are no chattering
                            self.recent_events.append(t)
                            self.recent_switches = self.recent_switches[-200:] + [(t, k) for k in changed]
                    if self.stats["mode_changes"] > self.max_events:
                        raise _Stop(RunFailure(
                            message=f"more than {self.max_events} events by t={t:.6g}",
                            time=float(t), kind="events",
                            cause="a switch keeps changing mode (chattering) faster than the chattering guard "
                                  "can absorb",
                            hint="smooth the law near its switching surface (a small linear band around zero "
                                 "velocity, for instance) or raise max_events"))
        except _Stop as stop:
            complete, failure = False, stop.failure
        except KeyboardInterrupt as interrupt:
            complete = False
            # where the run got to: its last recorded point (t is where the current segment began)
            self._consistent_blocks()
            t = max([float(t)] + [float(block[-1]) for block in self.blocks_t[-1:] if block.size])
            failure = RunFailure(message=f"interrupted at t={t:.6g}", time=float(t), variable=None,
                                 law=None, cause="interrupted by the user", hint="", kind="interrupted",
                                 terminated=type(interrupt).__name__ == "Terminated")   # SIGTERM (bondc.cli)
        self.stats["wall_time"] = _time_module.perf_counter() - started
        return self.result(complete, failure)

    def segment(self, t, y, modes, t_stop):
        """Integrate with frozen ``modes`` until ``t_stop`` or the first event; returns (t, y, event)."""
        self.stats["segments"] += 1
        modes = np.array(modes)
        relevant = self.relevant(t, y, modes)
        mode = ("frozen", self.mode_id(modes), tuple(relevant))
        self.last_relevant = relevant
        fun = lambda tt, yy: self.rhs(tt, yy, modes)
        jac = lambda tt, yy: self.jac(tt, yy, modes)
        index = np.array([k for k in self.event_switches if relevant[k]], dtype=int)
        queued = self.queued_piece(t, y, modes, t_stop, mode)
        resumed = None
        if queued is not None:
            if queued[0] != "resume":
                return queued
            resumed = queued[1]
        signs = modes[index] if index.size else np.zeros(0)
        values_old = self.switches_at(t, y, modes, index)
        # a restart may leave a switch a little on the far side of its surface (a sliding segment
        # drifts by the solver's tolerance): its crossing counts from where it starts
        drift = np.where(self.model.floor_switches[index], 0.0, np.maximum(0.0, -signs * values_old)) \
            if index.size else np.zeros(0)
        deadband = self.deadbands(t, y, modes, index) + drift
        driver = self.driver_for(index, signs)
        if driver is not None:
            outcome = self.driver_segment(driver, t, y, modes, t_stop, mode, index, signs, values_old, deadband,
                                          resumed)
            if outcome[0] != "handover":
                return outcome
            # something the driver leaves to this loop (a law not finite at a trial point, a solver
            # failure to diagnose): go on from its last accepted step, one step at a time
            _, t, y = outcome
            values_old = self.switches_at(t, y, modes, index)
        solver = self.new_solver(fun, jac, t, y, t_stop, modes)
        creeping = 0
        while True:
            # a step whose last stage is the rate at its end (an explicit Runge-Kutta pair's) tells
            # through that evaluation whether its end lies beyond a switch where the frozen branch is
            # not defined (self.rhs then takes the branches that hold there)
            self.extended = None
            message = solver.step()
            self.stats["steps"] += 1
            if solver.status == "failed":
                self.collect(solver)
                raise _Stop(self.solver_failure(solver.t, message))
            # A solver creeping towards a singularity (a law like 1/(t0 - t)) may never fail by
            # itself: it takes ever smaller steps. Give up once steps stay at rounding size.
            creeping = _creeping(solver, creeping)
            if creeping >= _CREEP_STEPS:
                self.collect(solver)
                raise _Stop(self.solver_failure(solver.t, f"{_CREEP_STEPS} steps in a row shorter than "
                                                          f"{_CREEP:g} relative: the solution is not advancing"))
            t_new, y_new = solver.t, solver.y
            derivative = getattr(solver, "f", None)
            if derivative is None or self.method.__name__ == "LSODA":
                self.extended = None
                with np.errstate(all="ignore"):
                    derivative = self.rhs(t_new, y_new, modes)
            if not (_all_finite(y_new) and _all_finite(derivative)):
                self.collect(solver)
                self.stop_nonfinite(solver, lambda tt, yy: self.rhs(tt, yy, modes), lambda tt, yy: modes, mode)
            if not np.max(np.abs(y_new), initial=0.0) < DIVERGED:
                self.collect(solver)
                self.record(solver.t_old, t_new, y_new, None, mode)
                raise _Stop(self.diagnosis.diverged(t_new, y_new))
            self._dense = None
            if index.size:
                values_new = self.switches_at(t_new, y_new, modes, index)
                band = deadband
                if self.extended is not None:
                    # the step ended where the frozen branch is not defined: the switches whose
                    # mode differs there have crossed, however shallow the crossing
                    band = np.where(self.extended[index] != modes[index], 0.0, deadband)
                hit = self.crossing(solver, modes, index, signs, values_old, values_new, band)
                if hit is not None:
                    t_event, k = hit
                    if self._dense is None:
                        self._dense = solver.dense_output()
                    y_event = self._dense(t_event)
                    self.record(solver.t_old, t_event, y_event, self._dense, mode)
                    self.collect(solver)
                    return t_event, y_event, k
                values_old = values_new
            if self.t_eval is not None and self._dense is None:
                self._dense = solver.dense_output()
            self.record(solver.t_old, t_new, y_new, self._dense, mode)
            if self.progress is not None:
                self.progress(t_new)
            if solver.status == "finished" or self.check_stiffness(t_new, y_new, modes):
                self.collect(solver)
                return t_new, np.array(y_new), None

    def unfrozen_interval(self, t, y, modes, t_stop, method=None):
        """Integrate the unfrozen law (modes recomputed at every evaluation) over a short interval.

        If the solver gives up on the discontinuous right-hand side, the
        interval is retried once with the explicit RK23 method.
        """
        self.stats["chattering_intervals"] += 1
        if self.chattering_since is None:
            self.chattering_since = t
            # name the switches that changed most often lately (all of them when none did)
            window = self.span / 1000.0
            counts = {}
            for time, k in self.recent_switches:
                if time > t - 10 * window:
                    counts[k] = counts.get(k, 0) + 1
            order = sorted(counts, key=lambda k: (-counts[k], k)) or list(range(self.switch_count))
            labels = [self.model.SWITCHES[k] for k in order]
            self.chattering_switches = order[:3]
            if order and not self.stats.get("chattering_law"):
                self.stats["chattering_law"] = self.model.SWITCH_OWNERS[order[0]]
            self.note_event(t, "chattering: integrating the unfrozen law (" + "; ".join(labels[:3])
                            + ("; ..." if len(labels) > 3 else "") + ")")
        else:
            self.tau = min(2 * self.tau, self.span / 100.0)
        state = {"modes": np.array(modes)}

        def current(tt, yy):
            state["modes"] = self.modes_at(tt, yy, state["modes"])
            return state["modes"]

        if method is None:
            outcome = self.driver_unfrozen(t, y, modes, t_stop)
            if outcome is not None:
                return outcome
        fun = lambda tt, yy: self.rhs(tt, yy, current(tt, yy))
        jac = lambda tt, yy: self.jac(tt, yy, current(tt, yy))
        if method is None:
            solver = self.new_solver(fun, jac, t, y, t_stop)
        else:
            options = {key: value for key, value in self.options.items() if key != "first_step"}
            solver = solver_class(method)(fun, t, y, t_stop, **options)
        blocks = len(self.blocks_t), self.eval_index
        creeping, steps_before = 0, self.stats["steps"]
        while True:
            message = solver.step()
            self.stats["steps"] += 1
            creeping = _creeping(solver, creeping)
            steps_here = self.stats["steps"] - steps_before
            if creeping >= _CREEP_STEPS or steps_here > _UNFROZEN_STEPS:
                self.collect(solver)
                raise self.unfrozen_stalled(solver.t, solver.y)
            if solver.status == "failed":
                self.collect(solver)
                if method is None:      # forget this attempt's points and retry explicitly
                    del self.blocks_t[blocks[0]:], self.blocks_x[blocks[0]:], self.blocks_mode[blocks[0]:]
                    self.eval_index = blocks[1]
                    return self.unfrozen_interval(t, y, modes, t_stop, method="RK23")
                raise _Stop(self.solver_failure(solver.t, message))
            t_new, y_new = solver.t, solver.y
            derivative = self.rhs(t_new, y_new, current(t_new, y_new))
            if not (np.all(np.isfinite(y_new)) and np.all(np.isfinite(derivative))):
                self.collect(solver)
                self.stop_nonfinite(solver, lambda tt, yy: self.rhs(tt, yy, current(tt, yy)), current, None)
            if self.t_eval is None:
                self.record(solver.t_old, t_new, y_new, None, self.mode_id(state["modes"]))
            else:
                # each point gets the modes of its own state
                dense = solver.dense_output()
                stop = np.searchsorted(self.t_eval, t_new, side="right")
                for ti in self.t_eval[self.eval_index:stop]:
                    yi = y_new if ti == t_new else dense(ti)
                    self.blocks_t.append(np.array([ti]))
                    self.blocks_x.append(np.asarray(yi, dtype=float).reshape(-1, 1))
                    self.blocks_mode.append(self.mode_id(self.modes_at(ti, yi, state["modes"])))
                self.eval_index = stop
            if self.progress is not None:
                self.progress(t_new)
            if solver.status == "finished":
                self.collect(solver)
                return t_new, np.array(y_new)

    def unfrozen_stalled(self, t, y) -> "_Stalled":
        """The stop of an unfrozen interval that makes no headway (the solver creeps, or takes more
        than _UNFROZEN_STEPS steps): the switches that chatter, named."""
        culprits = getattr(self, "chattering_switches", [])
        named = "; ".join(self.model.SWITCHES[k] for k in culprits)
        return _Stalled(RunFailure(message=f"the simulation stalled at t={t:.6g}: "
                                           + (f"{named} keep changing mode at every evaluation and " if named
                                              else "switches keep changing mode at every evaluation and ")
                                           + "the solver makes no headway",
                                   time=float(t), kind="events", law=None,
                                   variable=self.model.SWITCH_OWNERS[culprits[0]] if culprits else None,
                                   cause="several switches (sign, if, coulomb) keep changing mode together "
                                         "where no sliding mode holds them",
                                   hint="smooth the laws near their switching surfaces (a small linear band "
                                        "around zero velocity, for instance)"), t, y)


def output_grid(t_start, t_end, dt):
    """``t_start, t_start + dt, ...`` up to ``t_end`` (included, even when not a multiple of dt)."""
    count = int(math.floor((t_end - t_start) / dt * (1 + 1e-12) + 1e-9))
    grid = t_start + dt * np.arange(count + 1)
    if grid[-1] < t_end - 1e-9 * dt:
        grid = np.append(grid, t_end)
    grid[-1] = min(grid[-1], t_end)
    return grid


def simulate_model(model, t_end=None, p=None, t_eval=None, *, method=None, rtol=None, atol=None,
                   max_step=None, first_step=None, dt=None, t_start=0.0, progress=None,
                   max_events=100000, max_event_rate=100, native=None, inputs=None):
    """Simulate a generated model from ``t_start`` to ``t_end``; see the module docstring.

    ``p``: None, a dict of parameter overrides or a full parameter array.
    ``t_eval``: the times to report; ``dt``: report on a regular grid instead;
    neither: every solver step (and every event). Missing solver settings come
    from the model's ``DEFAULTS`` (its experiment), then LSODA (stiff/non-stiff
    switching, with the analytic Jacobian when stiff), rtol 1e-6, atol 1e-9.
    ``atol`` is absolute, in the SI unit of each state: a charge in microcoulombs
    needs a smaller one. ``progress(t)`` is called after every step. ``native``: None runs the
    model's compiled C code where it can (else numpy), False always numpy; ``stats["code"]``
    says which ran and ``stats["code_note"]`` why not C. ``inputs``: ``{name: (times, values) or
    f(t)}`` for the model's external inputs (EXTERNAL_INPUT_NAMES, SI); one not given takes its default.
    """
    model = _Model(model)       # a copy: the native functions are attached to this run's only
    store = model.EXTERNAL_INPUTS
    supplied = external_inputs(inputs, model.EXTERNAL_INPUT_NAMES)
    if store is not None:       # a run never depends on the signals given to the runs before it
        store.clear()
        store.update(supplied)
    _BLOCK_SOLUTIONS.clear()    # algebraic loops start from their guesses: a run never depends on the runs before it
    padded = not model.STATE_NAMES
    if padded:
        model = _padded(model)
    defaults = model.DEFAULTS
    chosen = method or defaults.get("method") or DEFAULT_SOLVER
    if model.dae is not None and (chosen is IDA or str(chosen).lower() == "ida") and native is not False:
        # IDA integrates the loops' unknowns as algebraic variables of the numpy module's _dae
        native_used, native_note = False, "IDA integrates the algebraic loops with the numpy module's DAE"
    else:
        native_used, native_note = attach_native(model, native)
    t_end = defaults.get("t_end") if t_end is None else t_end
    if t_end is None:
        raise ValueError("t_end is needed (the experiment does not set it)")
    t_end = float(t_end)
    if not t_end > t_start:
        raise ValueError(f"t_end ({t_end}) must be after the start time ({t_start})")
    dt = defaults.get("dt") if (dt is None and t_eval is None) else dt
    if t_eval is None and dt is not None:
        width = len(model.STATE_NAMES) + len(model.OUTPUT_NAMES) + len(model.VARIABLE_NAMES)
        count = (t_end - t_start) / float(dt)
        if count > max_points(width):       # before the grid is allocated
            raise ValueError(f"dt = {float(dt):g} s over {t_end - t_start:g} s gives {count:.3g} points, more than "
                             f"the {max_points(width)} a run of this model records ({width} numbers per point, "
                             f"at most {MAX_VALUES:.0e} numbers: about 1 GB with its analyses); give a larger "
                             "dt or a shorter t_end")
        t_eval = output_grid(t_start, t_end, float(dt))
    if t_eval is not None:
        t_eval = np.asarray(t_eval, dtype=float)
        if np.any(np.diff(t_eval) < 0):
            raise ValueError("t_eval must be increasing")
        t_eval = t_eval[(t_eval >= t_start) & (t_eval <= t_end)]
    method = chosen
    rtol = float(rtol if rtol is not None else defaults.get("rtol") or 1e-6)
    atol = float(atol if atol is not None else defaults.get("atol") or 1e-9)
    max_step = float(max_step if max_step is not None else defaults.get("max_step") or np.inf)
    parameters = param_array(model.PARAMETERS, p, model.derive_parameters)
    run = _Run(RunSpec(model=model, parameters=parameters, t_start=float(t_start), t_end=t_end, t_eval=t_eval,
                       method=method, rtol=rtol, atol=atol, max_step=max_step, first_step=first_step,
                       progress=progress, max_events=max_events, max_event_rate=max_event_rate, inputs=supplied))
    run.stats["code"] = "native" if native_used else "numpy"
    if not native_used:
        run.stats["code_note"] = native_note
    else:
        run.stats["compiler"] = compiler_label("c")
    result = run.run()
    if store is not None and model.EXTERNAL_INPUT_NAMES:
        # which signal each external input took ("u: table, F_ext: default")
        result.stats["external_inputs"] = ", ".join(
            f"{name}: " + (("function" if callable(supplied[name]) else "table") if name in supplied else "default")
            for name in model.EXTERNAL_INPUT_NAMES)
        deferred = getattr(result.variables, "_deferred", None)
        if deferred is not None and deferred.tasks:
            deferred.tasks = [_with_inputs(store, supplied, task) for task in deferred.tasks]
    if padded:
        result.states.pop(_PADDING, None)
        result.jumps = [(time, {}, {}) for time, _, _ in result.jumps]
    return result


_PADDING = "<no state>"


def _padded(model):
    """A model without states, given one state that stays 0: the step loop, the located switches
    and the output grid of a purely algebraic model (a rectifier of R elements) need something to
    integrate. Every function sees the model's own (empty) state vector."""
    padded = _Model(model)
    padded.STATE_NAMES = (_PADDING,)
    original = {name: getattr(model, name) for name in ("outputs", "variables", "switches")}
    padded.x0 = lambda p=None: np.zeros(1)
    padded.rhs = lambda t, x, p, m: np.zeros_like(np.asarray(x, dtype=float))
    padded.jac = lambda t, x, p, m: np.zeros((1, 1))
    for name, function in original.items():
        setattr(padded, name, lambda t, x, p, m, f=function: f(t, np.asarray(x, dtype=float)[:0], p, m))
    padded.JACOBIAN_PATTERN = None
    padded.NATIVE_SOURCE = ""
    padded.NATIVE_UNAVAILABLE = "the model has no states: nothing to integrate in C"
    return padded
