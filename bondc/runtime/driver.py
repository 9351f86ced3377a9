"""bondc's C driver of CVODE (:class:`_NativeDriver`) and the segments a run integrates with it
(:class:`_DriverSegments`, a mixin of ``_Run``): frozen segments, queued pieces between known times,
sliding and unfrozen intervals, handed back to the Python step loop where anything is unusual."""

import collections as _collections
import os

import numpy as np

from bondc.runtime.kernels import _EPS
from bondc.runtime.adapter import pattern_arrays
from bondc.runtime.results import DIVERGED, _Stop
from bondc.runtime.native import compiler_label, load_erk
from bondc.runtime.solvers import CvodeSolver, DOPRI5, IDA, _CREEP, _CREEP_STEPS, _UNFROZEN_STEPS
from bondc.runtime.steppers import register_stepper_driver, stepper_table


class _NativeDriver:
    """bondc's C driver of CVODE (``bondc/native/driver.c``) for one run: the model's C right-hand side
    and Jacobian called by SUNDIALS directly, steps gathered in C, Python only between batches."""

    CAPACITY = 2048
    #: Values of the batch buffer (2 MB): a large model's batches hold fewer steps, so a run
    #: never allocates (and the kernel never clears) a buffer of thousands of steps of every state.
    BUFFER = 1 << 18

    def __init__(self, ffi, lib, handle, n, keep):
        self.ffi, self.lib, self.handle, self.n = ffi, lib, handle, n
        self.keep = keep                # arrays the C side points to
        self.capacity = self.capacity_for(n)
        self.ts = np.empty(self.capacity)
        self.ys = np.empty((self.capacity, n))
        self.count = ffi.new("int *")
        self.entries = 0                # the Jacobian's entries (JACOBIAN_PATTERN)
        self.modes = np.zeros(0)
        self.linear_solver = keep["solver"]

    @classmethod
    def capacity_for(cls, n: int) -> int:
        """Steps per batch for ``n`` states: 2048, fewer where that would exceed ``BUFFER`` values."""
        return max(16, min(cls.CAPACITY, cls.BUFFER // max(n, 1)))

    @classmethod
    def create(cls, model, library, p, adams, explicit=None):
        """The driver, or None where it does not apply (a sparse linear solver, no driver built).
        ``explicit``: the address of the explicit stepper's table (:func:`load_erk`), which then
        integrates instead of CVODE, without a linear solver."""
        ffi, lib = library
        # SUNDIALS logs a failed right-hand side (the driver's signal to hand over) as an error
        os.environ.setdefault("SUNLOGGER_ERROR_FILENAME", os.devnull)
        os.environ.setdefault("SUNLOGGER_WARNING_FILENAME", os.devnull)
        n = len(model.STATE_NAMES)
        pattern = tuple(model.JACOBIAN_PATTERN or ())
        solver, lower, upper = ("none", 0, 0) if explicit else CvodeSolver.linear_solver_for(n, pattern)
        if solver == "sparse":
            return None         # SuperLU: scikit-sundae's solver, stepped from Python
        rows, cols = pattern_arrays(model.JACOBIAN_PATTERN)
        keep = {"rows": rows.astype(np.intc) if rows.size else np.zeros(1, dtype=np.intc),
                "cols": cols.astype(np.intc) if cols.size else np.zeros(1, dtype=np.intc),
                "p": np.array(p, dtype=float), "solver": solver}
        buffer = ffi.from_buffer
        handle = lib.bondc_driver_new(n, len(model.SWITCHES), len(pattern), buffer("int[]", keep["rows"]),
                                      buffer("int[]", keep["cols"]), -1 if explicit else int(solver == "band"),
                                      int(lower), int(upper), int(bool(adams)), buffer("double[]", keep["p"]))
        if handle == ffi.NULL:
            return None
        handle = ffi.gc(handle, lib.bondc_driver_free)
        if explicit and lib.bondc_driver_explicit(handle, ffi.cast("void *", explicit)) != 0:
            return None
        driver = cls(ffi, lib, handle, n, keep)
        driver.entries = len(pattern)
        if explicit:
            register_stepper_driver(int(ffi.cast("uintptr_t", handle)), driver)
        return driver

    def jacobian_entries(self, t, y):
        """The Jacobian's entries (JACOBIAN_PATTERN's order) at (t, y) as the segment integrates
        (frozen modes, or the sliding combination's weighted corners); None where not finite."""
        out = np.empty(max(self.entries, 1))
        y = np.ascontiguousarray(y, dtype=float)
        flag = self.lib.bondc_driver_jac_entries(self.handle, float(t), self.ffi.from_buffer("double[]", y),
                                                 self.ffi.from_buffer("double[]", out))
        return out[:self.entries] if flag == 0 else None

    def start(self, t, y, modes, t_stop, rtol, atol, max_step, first_step) -> bool:
        self.modes = np.array(modes, dtype=float)
        y = np.array(y, dtype=float)
        buffer = self.ffi.from_buffer
        flag = self.lib.bondc_driver_start(self.handle, float(t), buffer("double[]", y),
                                           buffer("double[]", self.modes) if self.modes.size else self.ffi.NULL,
                                           float(t_stop), float(rtol), float(atol), float(max_step),
                                           float(first_step), 100000)
        return flag == 0

    def advance(self, watch, signs, band, g_old):
        """One batch: (code, times, states) — see ``bondc_driver_advance``."""
        return self.advance_reporting(watch, signs, band, g_old, None)[:3]

    def advance_reporting(self, watch, signs, band, g_old, t_eval, eval_next=0):
        """One batch of a run reported at ``t_eval`` (None: every step), from its index ``eval_next``
        on: (code, times, states) of the steps as :meth:`advance` gives them, and (times, states,
        next index) of the report points in the steps kept, or None — see ``bondc_driver_advance``."""
        buffer, null = self.ffi.from_buffer, self.ffi.NULL
        watched = int(watch.size)
        code = self.lib.bondc_driver_advance(
            self.handle, self.capacity, watched, buffer("int[]", watch) if watched else null,
            buffer("double[]", signs) if watched else null, buffer("double[]", band) if watched else null,
            buffer("double[]", g_old) if watched else null, buffer("double[]", self.ts),
            buffer("double[]", self.ys), self.count, *self._report_arguments(t_eval, eval_next))
        count = self.count[0]
        return code, self.ts[:count], self.ys[:count], self._reported(t_eval)

    def check(self, longest):
        """Sliding steps longer than ``longest`` end a batch (see ``bondc_driver_check``)."""
        self.lib.bondc_driver_check(self.handle, float(longest) if np.isfinite(longest) else 0.0)

    def slide(self, k, plus, minus, alpha, probe, others, drift):
        """Make the segment just started a sliding mode on switch ``k`` (see ``bondc_driver_slide``)."""
        buffer = self.ffi.from_buffer
        self.others = np.array(others, dtype=np.intc).reshape(-1)      # the C side keeps pointing to them
        self.drift = np.array(drift, dtype=float).reshape(-1)
        self.alphas = np.empty(self.capacity)
        self.exits = np.empty(2 * (2 + self.others.size))     # its second half: the C side's scratch
        self.lib.bondc_driver_slide(self.handle, int(k), buffer("double[]", np.array(plus, dtype=float)),
                                    buffer("double[]", np.array(minus, dtype=float)), float(alpha), float(probe),
                                    int(self.others.size),
                                    buffer("int[]", self.others) if self.others.size else self.ffi.NULL,
                                    buffer("double[]", self.drift) if self.others.size else self.ffi.NULL)

    def slide_many(self, sliding, corners, affine, alphas, probe, others, drift):
        """Make the segment just started a sliding mode on several switches (see
        ``bondc_driver_slide_many``); False when out of memory."""
        buffer = self.ffi.from_buffer
        self.others = np.array(others, dtype=np.intc).reshape(-1)      # the C side keeps pointing to them
        self.drift = np.array(drift, dtype=float).reshape(-1)
        count = len(sliding)
        self.alphas = np.empty(self.capacity * count)
        self.exits = np.empty(2 * (2 * count + self.others.size))     # its second half: the C side's scratch
        corners = np.ascontiguousarray(corners, dtype=float)
        return self.lib.bondc_driver_slide_many(
            self.handle, count, buffer("int[]", np.array(sliding, dtype=np.intc)), len(corners), int(affine),
            buffer("double[]", corners), buffer("double[]", np.array(alphas, dtype=float)), float(probe),
            int(self.others.size), buffer("int[]", self.others) if self.others.size else self.ffi.NULL,
            buffer("double[]", self.drift) if self.others.size else self.ffi.NULL) == 0

    def exits_at(self, t, y):
        """The sliding mode's exits at (t, y), evaluated in C (as ``exits`` of :meth:`_Run.sliding_segment`)."""
        out = np.empty(self.exits.size // 2)
        self.lib.bondc_driver_exits(self.handle, float(t), self.ffi.from_buffer("double[]", np.ascontiguousarray(
            y, dtype=float)), self.ffi.from_buffer("double[]", out))
        return out

    def crossing(self, index, signs, band, g_old, floors, modes, t_old, t_new, y_new):
        """The earliest crossing in the last step (t_old, t_new] on the interpolant
        (``bondc_driver_crossing``): (time, switch) or None."""
        buffer = self.ffi.from_buffer
        watch = np.ascontiguousarray(index, dtype=np.intc)
        g_new = np.empty(max(modes.size, 1))
        t_event = self.ffi.new("double *")
        k = self.lib.bondc_driver_crossing(
            self.handle, int(watch.size), buffer("int[]", watch), buffer("double[]", np.ascontiguousarray(signs, dtype=float)),
            buffer("double[]", np.ascontiguousarray(band, dtype=float)),
            buffer("double[]", np.ascontiguousarray(g_old, dtype=float)), buffer("int[]", floors),
            buffer("double[]", modes), float(t_old), float(t_new),
            buffer("double[]", np.ascontiguousarray(y_new, dtype=float)), buffer("double[]", g_new), t_event)
        return None if k < 0 else (float(t_event[0]), int(k))

    def slide_end(self, t_old, t_new, old, new, longest):
        """The end of the sliding mode inside its last step (t_old, t_new] on the driver's
        interpolant, or None (``bondc_driver_slide_end``, as :meth:`_Run.sliding_end_within`)."""
        buffer = self.ffi.from_buffer
        t_end = self.ffi.new("double *")
        code = self.lib.bondc_driver_slide_end(self.handle, float(t_old), float(t_new),
                                               buffer("double[]", np.ascontiguousarray(old, dtype=float)),
                                               buffer("double[]", np.ascontiguousarray(new, dtype=float)),
                                               float(longest) if np.isfinite(longest) else 0.0, t_end)
        if code < 0:
            raise MemoryError("the native driver ran out of memory")
        return float(t_end[0]) if code == 0 else None

    def slide_advance(self, old):
        """One batch of a sliding mode: (code, times, states, alphas) — see ``bondc_driver_slide_advance``;
        ``old`` (the exits before the batch) is updated in place, the first half of ``self.exits``
        holds the last step's."""
        return self.slide_advance_reporting(old, None)[:4]

    def slide_advance_reporting(self, old, t_eval, eval_next=0):
        """:meth:`slide_advance` of a run reported at ``t_eval`` from its index ``eval_next`` on, and
        the report points in the steps kept, as :meth:`advance_reporting` gives them."""
        buffer = self.ffi.from_buffer
        code = self.lib.bondc_driver_slide_advance(
            self.handle, self.capacity, buffer("double[]", old), buffer("double[]", self.exits),
            buffer("double[]", self.ts), buffer("double[]", self.ys), buffer("double[]", self.alphas), self.count,
            *self._report_arguments(t_eval, eval_next))
        count = self.count[0]
        held = self.alphas.size // self.capacity
        return (code, self.ts[:count], self.ys[:count], self.alphas[:count * held].reshape(count, held),
                self._reported(t_eval))

    def unfrozen_advance(self, floors, t_eval=None, eval_next=0):
        """One batch of the unfrozen law of the segment just started: (code, times, states, modes of
        each step) and, with ``t_eval``, (times, states, next index) of the report points in it —
        see ``bondc_driver_unfrozen_advance``. ``floors``: the floor switches (kept by the caller)."""
        buffer = self.ffi.from_buffer
        self.floors = floors            # the C side keeps pointing to them
        switches = max(self.modes.size, 1)
        if getattr(self, "ms", None) is None or self.ms.shape[1] != switches:
            self.ms = np.empty((self.capacity, switches))
        code = self.lib.bondc_driver_unfrozen_advance(
            self.handle, self.capacity, buffer("int[]", floors), buffer("double[]", self.ts),
            buffer("double[]", self.ys), buffer("double[]", self.ms), self.count,
            *self._report_arguments(t_eval, eval_next))
        count = self.count[0]
        return code, self.ts[:count], self.ys[:count], self.ms[:count, :self.modes.size], self._reported(t_eval)

    def _report_arguments(self, t_eval, eval_next):
        """The C arguments of a batch's report points (t_eval, its size, the next index, the buffers'
        capacity, times, states, count), NULL where the run reports every step (``t_eval`` None)."""
        null = self.ffi.NULL
        if t_eval is None:
            return null, 0, null, 0, null, null, null
        if getattr(self, "et", None) is None:       # made at the first batch of a reported run
            self.et, self.ey = np.empty(self.capacity), np.empty((self.capacity, self.n))
            self.eval_next, self.eval_count = self.ffi.new("int *"), self.ffi.new("int *")
        self.eval_next[0] = int(eval_next)
        buffer = self.ffi.from_buffer
        return (buffer("double[]", t_eval), int(t_eval.size), self.eval_next, self.capacity,
                buffer("double[]", self.et), buffer("double[]", self.ey), self.eval_count)

    def _reported(self, t_eval):
        """(times, states, next index) of the report points the last batch stored, or None."""
        if t_eval is None:
            return None
        reported = self.eval_count[0]
        return self.et[:reported], self.ey[:reported], self.eval_next[0]

    def interpolate(self, t):
        out = np.empty(self.n)
        self.lib.bondc_driver_dky(self.handle, float(t), 0, self.ffi.from_buffer("double[]", out))
        return out

    def counts(self):
        out = self.ffi.new("long[3]")
        self.lib.bondc_driver_counts(self.handle, out)
        return int(out[0]), int(out[1]), int(out[2])

    def pieces(self, t_stops, t0, y0, m0, floors, watch, held, strict, probe, rtol, atol, max_step, first_step,
               whens=None):
        """Known pieces in one call (``bondc_driver_pieces``): (pieces done, times, states, ends,
        modes, counts, partial, starts, guesses), the arrays of the pieces done (modes, starts and
        guesses, times and states also of the piece begun after them, of ``partial`` = (steps,
        code, values of the watched switches) where there is one), copied. ``whens``: (offsets,
        targets) of the when clauses' targets (clause k sets targets[offsets[k]:offsets[k + 1]]),
        for the restarts where a clause fires; each piece then starts from ``starts[i]``, its
        restart found from the modes ``guesses[i]``."""
        buffer, null = self.ffi.from_buffer, self.ffi.NULL
        count, switches, watched = len(t_stops), m0.size, int(watch.size)
        offsets, targets = whens if whens is not None else (np.zeros(1, dtype=np.intc), np.zeros(1, dtype=np.intc))
        n = np.size(y0)
        starts = np.zeros((count, max(n, 1)))
        guesses = np.zeros((count, max(switches, 1)))
        t_stops = np.ascontiguousarray(t_stops, dtype=float)
        ends = np.zeros(count, dtype=np.intc)
        modes = np.zeros((count, max(switches, 1)))
        counts = np.zeros((count, 3), dtype=np.int_)
        partial = np.zeros(2, dtype=np.intc)
        g_left = np.zeros(max(watched, 1))
        done = self.lib.bondc_driver_pieces(
            self.handle, count, buffer("double[]", t_stops), float(t0), buffer("double[]", np.array(y0, dtype=float)),
            buffer("double[]", np.array(m0, dtype=float)) if switches else null,
            buffer("int[]", floors) if switches else null, watched, buffer("int[]", watch) if watched else null,
            buffer("int[]", held) if watched else null, int(bool(strict)), float(probe), float(rtol), float(atol),
            float(max_step),
            float(first_step), self.capacity, buffer("double[]", self.ts), buffer("double[]", self.ys),
            buffer("int[]", ends), buffer("double[]", modes), buffer("long[]", counts), buffer("int[]", partial),
            buffer("double[]", g_left), int(offsets.size - 1), buffer("int[]", offsets), buffer("int[]", targets),
            buffer("double[]", starts), buffer("double[]", guesses))
        stored = (int(ends[done - 1]) if done else 0) + int(partial[0])
        return (done, self.ts[:stored].copy(), self.ys[:stored].copy(), ends[:done], modes[:done + 1, :switches],
                counts[:done], (int(partial[0]), int(partial[1]), g_left[:watched]), starts[:done + 1, :n],
                guesses[:done + 1, :switches])


#: A piece of a run integrated ahead (:meth:`_Run.queued_piece`): from (t0, y0) to t_stop with
#: ``modes``, found at its start from the modes before (``guess``; None for the first of a call);
#: its steps (``ts``, ``ys`` by rows) and the solver's counts; or, with ``resume`` the driver's code
#: (0 or 1) where the call stopped inside it, its first steps, the driver standing at the last, and
#: ``left`` the values the driver left of each switch it watched (switch -> value).
_Piece = _collections.namedtuple("_Piece", "t0 y0 t_stop modes guess ts ys counts resume left")


class _DriverStep:
    """The driver's last step seen as a solver by :meth:`_Run.crossing` (which locates it in C):
    driver, t_old, t, y, dense_output()."""

    def __init__(self, driver, t_old, t, y):
        self.driver, self.t_old, self.t, self.y = driver, t_old, t, y

    def dense_output(self):
        t_old, t_new, y_new, driver = self.t_old, self.t, self.y, self.driver

        def interpolate(tt):
            tt = float(tt)
            if tt == t_new:
                return y_new.copy()
            return driver.interpolate(min(max(tt, t_old), t_new))

        return interpolate


class _DriverSegments:
    """Segments integrated by bondc's C driver (:class:`_NativeDriver`): frozen segments, queued
    pieces between known times, sliding on one or more switches, unfrozen intervals. A mixin of
    :class:`_Run`: the driver records into the run's blocks and counts, and hands back to the step loop."""

    def driver_for(self, index, signs):
        """The native driver for a segment watching ``index`` in modes ``signs``, or None.

        It serves CVODE, DOPRI5 and scipy's solvers for models whose C code carries the driver
        (DOPRI5 where bondc's explicit stepper is built, :func:`load_erk`; scipy's solvers through
        :func:`stepper_table`), when every watched switch is a sign
        switch (floor switches keep the step-by-step loop); a run reported at ``t_eval`` takes its
        report points from the driver's interpolant of each step (:meth:`record_reported`). It also
        serves sliding modes (:meth:`driver_sliding`)."""
        if self._driver is False:
            return None
        if self._driver is None:
            self._driver = False
            library = getattr(self.model, "native_library", None)
            if library is None or not isinstance(self.method, type):
                return None
            if self.method is DOPRI5:
                table, why = load_erk()
                if table is None:
                    self.stats["code_note"] = f"DOPRI5 runs scipy's RK45 from Python: {why}"
                    return None
                self.stats["compiler_cxx"] = compiler_label("c++")
                driver = _NativeDriver.create(self.model, library, self.p, False, explicit=table)
                if driver is not None and self.auto:
                    # batches no longer than the stiffness checks' spacing (check_stiffness)
                    driver.capacity = min(driver.capacity, self.STIFFNESS_CHECK)
            elif issubclass(self.method, CvodeSolver):
                driver = _NativeDriver.create(self.model, library, self.p, self.method.variant == "Adams")
            elif self.method is not IDA:
                # one of scipy's solvers, stepping the driver's right-hand side through callbacks
                driver = _NativeDriver.create(self.model, library, self.p, False,
                                              explicit=stepper_table(self.method))
            else:
                return None
            if driver is None:
                return None
            self._driver = driver
        if index.size and self.model.floor_switches[index].any():
            return None
        return self._driver

    def driver_steps(self) -> tuple:
        """(first step, largest step) as the native driver takes them: 0 for none (the driver
        leaves out a first step longer than its segment)."""
        options = self.options
        first_step = float(options.get("first_step") or 0.0)
        return first_step, float(options["max_step"]) if np.isfinite(options["max_step"]) else 0.0

    def start_driver(self, driver, t, y, modes, t_stop) -> bool:
        """(Re)start the native driver at (t, y) with ``modes`` towards ``t_stop``, with the run's
        tolerances and step limits; False where CVODE refuses."""
        first_step, max_step = self.driver_steps()
        if first_step > t_stop - t:
            first_step = 0.0
        return driver.start(t, y, modes, t_stop, self.options["rtol"], self.options["atol"], max_step, first_step)

    def collect_driver(self, driver, kind, counts=None):
        """Add the driver's counts since its start (or ``counts``, a piece's) to the run's, and count
        one segment of ``kind``."""
        nfev, njev, nlu = driver.counts() if counts is None else (int(count) for count in counts)
        self.stats["nfev"] += nfev
        self.stats["njev"] += njev
        self.stats["nlu"] += nlu
        self.stats["linear_solver"] = driver.linear_solver
        self.stats[kind] = self.stats.get(kind, 0) + 1

    def report_points(self, driver, whole, t_last, y_last, first, report):
        """(times, states, next index) of the report points of a batch of the driver whose last kept
        step ends at (``t_last``, ``y_last``), the run's report times from index ``first`` on: those
        the driver stored up to that step and, where the batch ended there (``whole``: not at a
        crossing, a failure or a cut), those of that step it had no room for, from CVODE's
        interpolant of the step, which is still the driver's last (a batch ends right after the step
        whose points filled the buffer)."""
        times, states, _ = report
        kept = int(np.searchsorted(times, t_last, side="right"))
        times, states = times[:kept], states[:kept]
        stop = first + kept
        more = int(np.searchsorted(self.t_eval, t_last, side="right")) if whole else stop
        if more > stop:
            extra = self.t_eval[stop:more]
            times = np.concatenate([times, extra])
            states = np.vstack([states] + [np.array(y_last, dtype=float) if te == t_last
                                           else driver.interpolate(float(te)) for te in extra])
        return times, states, max(stop, more)

    def record_reported(self, driver, code, t_last, y_last, first, report, mode):
        """Record the report points (:meth:`report_points`) of a batch that ended with ``code`` as
        one block. ``mode``: the points' mode, or a function of their (times, states) that gives it
        (a sliding mode's weights)."""
        times, states, self.eval_index = self.report_points(driver, code in (0, 2), t_last, y_last, first, report)
        if times.size:
            self.blocks_t.append(times.copy())
            self.blocks_x.append(states.copy().T)
            self.blocks_mode.append(mode(self.blocks_t[-1], self.blocks_x[-1]) if callable(mode) else mode)

    def driver_segment(self, driver, t, y, modes, t_stop, mode, index, signs, values_old, deadband, resumed=None):
        """Integrate one segment with the native driver: (t, y, event) as :meth:`segment` returns,
        or ("handover", t, y) to go on step by step from there. ``resumed``: the piece the driver
        began ahead (:meth:`integrate_pieces`) and stands in, its steps the first batch."""
        if resumed is None and not self.start_driver(driver, t, y, modes, t_stop):
            return "handover", t, np.array(y, dtype=float)
        g_old = np.array(values_old, dtype=float)
        watch = index.astype(np.intc)
        signs = np.asarray(signs, dtype=float)
        band = np.asarray(deadband, dtype=float)
        t_prev, y_prev = float(t), np.array(y, dtype=float)
        creeping = 0
        self.extended = None
        try:
            while True:
                if resumed is not None:
                    # a batch the driver made watching more switches (every one it locates): its last
                    # step stands as a possible crossing (code 1) or not (0), and g_old takes the
                    # values it left of those this segment watches
                    code, ts, ys, left, resumed = resumed.resume, resumed.ts, resumed.ys, resumed.left, None
                    g_old[:] = [left[k] for k in index.tolist()]
                else:
                    first = self.eval_index
                    code, ts, ys, report = driver.advance_reporting(watch, signs, band, g_old, self.t_eval, first)
                done = len(ts) - (1 if code in (1, 4) else 0)
                grown = ()      # the batch's states are finite (code 4 ends it before the first that is not)
                if done and (ys[:done].max() >= DIVERGED or ys[:done].min() <= -DIVERGED):   # no |ys| copy
                    grown = np.flatnonzero(np.max(np.abs(ys[:done]), axis=1) >= DIVERGED)
                if len(grown):
                    done = int(grown[0]) + 1        # keep the step where it happened, then stop
                    code = "diverged"
                if done > 0:
                    self.stats["steps"] += done
                    steps = np.diff(np.concatenate(([t_prev], ts[:done])))
                    tinies = steps <= _CREEP * np.maximum(np.abs(ts[:done]), 1.0)
                    if tinies.any():
                        for tiny in tinies:
                            creeping = creeping + 1 if tiny else 0
                            if creeping >= _CREEP_STEPS:
                                return "handover", t_prev, y_prev    # the step loop diagnoses it
                    else:
                        creeping = 0        # the common batch, at once
                    if self.t_eval is None:
                        self.blocks_t.append(ts[:done].copy())
                        self.blocks_x.append(ys[:done].copy().T)
                        self.blocks_mode.append(mode)
                    else:
                        self.record_reported(driver, code, float(ts[done - 1]), ys[done - 1], first, report, mode)
                    t_prev, y_prev = float(ts[done - 1]), ys[done - 1].copy()
                    if self.progress is not None:
                        self.progress(t_prev)
                if code == "diverged":
                    raise _Stop(self.diagnosis.diverged(t_prev, y_prev))
                if code == 0:
                    if self.check_stiffness(t_prev, y_prev, modes):
                        return t_prev, y_prev, None     # the rest is the stiff solver's
                    continue
                if code == 2:
                    return t_prev, y_prev, None
                if code != 1:       # 3, 4 or a CVODE failure: the step loop takes over and explains
                    return "handover", t_prev, y_prev
                # a possible crossing in the last step: the step loop's own test and location
                t_new, y_new = float(ts[-1]), ys[-1].copy()
                self.stats["steps"] += 1
                step = _DriverStep(driver, t_prev, t_new, y_new)
                values_new = self.switches_at(t_new, y_new, modes, index)
                self._dense = None
                hit = self.crossing(step, modes, index, signs, g_old, values_new, band)
                if hit is not None:
                    t_event, k = hit
                    dense = self._dense or step.dense_output()
                    y_event = dense(t_event)
                    self.record(t_prev, t_event, y_event, dense, mode)
                    return t_event, y_event, k
                self.record(t_prev, t_new, y_new, None if self.t_eval is None else step.dense_output(), mode)
                g_old[:] = values_new
                t_prev, y_prev = t_new, y_new
                if t_new >= t_stop:
                    return t_new, y_new, None
        finally:
            self.collect_driver(driver, "driver_segments")

    #: Pieces integrated ahead in one native call (at most; fewer where the driver's buffer fills)
    PIECES_AHEAD = 512

    def pieces_apply(self) -> bool:
        """Whether the pieces between known breaks can be integrated ahead (:meth:`queued_piece`):
        a run with the native driver, reporting every step, with scalar tolerances (the driver's
        deadbands), of a model without a floor of the state among the switches it locates as events
        (a segment watching one is stepped from Python), and whose when clauses, if any, are in its
        C code (``bondc_when_native``: their statements then run in the C call where a clause fires
        at a break, one round). With a nonlinear algebraic loop, a restart where C's Newton fails
        (numpy then solves the loop) is left to the run."""
        if self._pieces is None:
            model = self.model
            self._pieces = bool(
                self.t_eval is None and not model.floor_switches[self.event_switches].any()
                and np.ndim(self.options["atol"]) == 0 and np.ndim(self.options["rtol"]) == 0
                and self.driver_for(np.zeros(0, dtype=int), np.zeros(0)) is not None
                and (not model.WHEN_LABELS or self.when_targets is not None))
        return self._pieces

    def queued_piece(self, t, y, modes, t_stop, mode):
        """The segment from (t, y) with ``modes`` to ``t_stop`` (a known break or the end), taken
        from the pieces integrated ahead, integrating them first where none is queued: (t, y,
        None) as :meth:`segment` returns, or None (the segment is integrated as any other).

        Where :meth:`pieces_apply`, the segments between the run's known breaks (a pwm's edges) and
        the restarts at those breaks are done in one native call for many breaks
        (``bondc_driver_pieces``): each piece started and stepped as :meth:`driver_segment` starts
        and steps it, each restart as :meth:`restart_modes` and :meth:`sliding_candidates` make it,
        so the run is the same to the bit. The call stops before a restart that is not that simple
        (the modes probed ahead differ, a friction sits on its surface) and inside a piece in which a
        switch of the state may cross or that fills its buffer: that piece is queued as begun
        (``resume``), and :meth:`driver_segment` goes on from where CVODE stands. The run loop takes
        each piece (here) and each restart (in :meth:`restart_modes`) as it reaches them, with all
        its bookkeeping of events; a piece that does not match where the run is (it went another
        way) empties the queue. Where the calls end
        inside their first piece (a switch of the state crossing before the next break, as in most
        segments of the flagship cycle), they are tried again after 2, 4, ... 64 segments only: they
        save nothing there and cost a little."""
        queue = self.queue
        if not queue:
            if not self.pieces_apply():
                return None
            if self.pieces_skip:
                self.pieces_skip -= 1
                return None
            self.integrate_pieces(t, y, modes, t_stop)
        if not queue:
            return None
        piece = queue[0]
        # (their bytes: the run hands back the very modes and state of the queue; anything else,
        # a -0.0 for a 0.0 included, only sends the segment the usual way)
        if not (piece.t0 == t and piece.t_stop == t_stop and piece.modes.tobytes() == modes.tobytes()
                and piece.y0.tobytes() == np.asarray(y, dtype=float).tobytes()):
            queue.clear()
            return None
        queue.popleft()
        self.stats["pieces_ahead"] = self.stats.get("pieces_ahead", 0) + 1
        if piece.resume is not None:
            self.stats["pieces_resumed"] = self.stats.get("pieces_resumed", 0) + 1
            return "resume", piece
        self.extended = None
        ts, ys = piece.ts, piece.ys
        self.stats["steps"] += ts.size
        self.blocks_t.append(ts)
        self.blocks_x.append(ys.T)
        self.blocks_mode.append(mode)
        if self.progress is not None:
            self.progress(float(ts[-1]))
        self.collect_driver(self._driver, "driver_segments", piece.counts)
        return float(ts[-1]), ys[-1].copy(), None

    def integrate_pieces(self, t, y, modes, t_stop):
        """Integrate the pieces from (t, y) with ``modes`` to ``t_stop`` and on, break after break
        (up to PIECES_AHEAD, none shorter than the run loop's sliver), into the queue."""
        times = self.break_times
        stops = times[np.searchsorted(times, t_stop, side="left"):]
        stops = np.concatenate((stops[stops < self.t_end], [self.t_end]))[:self.PIECES_AHEAD]
        if stops[0] != t_stop:
            return
        starts = np.concatenate(([t], stops[:-1]))
        slivers = np.flatnonzero(stops - starts <= 16 * _EPS * np.maximum(np.maximum(np.abs(starts), np.abs(stops)),
                                                                            1.0))
        if slivers.size:
            stops, starts = stops[:slivers[0]], starts[:slivers[0]]
        if not stops.size:
            return
        options = self.options
        first_step, max_step = self.driver_steps()      # (the first step per piece, in C)
        floors = np.ascontiguousarray(self.model.floor_switches, dtype=np.intc)
        watch = np.ascontiguousarray(self.event_switches, dtype=np.intc)
        held = np.ascontiguousarray(np.asarray(self.model.SWITCH_VERTICES, dtype=float)[watch] != 1.0, dtype=np.intc)
        done, ts, ys, ends, piece_modes, counts, (partial, code, g_left), starts, guesses = self._driver.pieces(
            stops, t, y, np.asarray(modes, dtype=float), floors, watch, held, not getattr(self.model, "VECTORIZED", True),
            self.probe, options["rtol"], options["atol"], max_step, first_step, self.when_targets)
        whole = int(ends[done - 1]) if done else 0
        if done:
            self.pieces_backoff = 1
        else:
            self.pieces_backoff = self.pieces_skip = min(2 * self.pieces_backoff, 64)
        # a state growing without bound, or _CREEP_STEPS steps of rounding size in a row in one
        # piece: from that piece on, the driver's own segment diagnoses them
        bad = (ys[:whole].max(axis=1, initial=-np.inf) >= DIVERGED) | (ys[:whole].min(axis=1, initial=np.inf)
                                                                      <= -DIVERGED)
        tiny = np.diff(np.concatenate(([t], ts[:whole]))) <= _CREEP * np.maximum(np.abs(ts[:whole]), 1.0)
        if tiny.any():
            creeping, piece = 0, 0
            for i in np.flatnonzero(tiny):
                while ends[piece] <= i:
                    piece += 1
                start = ends[piece - 1] if piece else 0
                creeping = creeping + 1 if i > start and tiny[i - 1] else 1
                bad[i] |= creeping >= _CREEP_STEPS
        if bad.any():
            done, partial = int(np.searchsorted(ends, np.flatnonzero(bad)[0], side="right")), 0
        # each piece starts where the one before ended (after the statements of a when clause that
        # fired there), its restart found from the modes guesses[i], as in C
        begin, t0, y0 = 0, t, np.array(y, dtype=float)
        for i in range(done):
            end = int(ends[i])
            self.queue.append(_Piece(t0, y0, float(stops[i]), piece_modes[i], guesses[i] if i else None,
                                     ts[begin:end], ys[begin:end], counts[i], None, None))
            begin, t0, y0 = end, float(ts[end - 1]), starts[i + 1] if i + 1 < starts.shape[0] else ys[end - 1]
        if partial:     # the piece begun after them, its first steps: the driver goes on from there
            self.queue.append(_Piece(t0, y0, float(stops[done]), piece_modes[done],
                                     guesses[done] if done else None, ts[begin:begin + partial],
                                     ys[begin:begin + partial], None, code, dict(zip(watch.tolist(), g_left))))

    def driver_sliding(self, driver, t, y, modes, sliding, corners, sides, corner_ids, others, drift, memory,
                       weights_at, labels, t_stop):
        """:meth:`sliding_segment` with the native driver: the combination of the corners, its
        Jacobian and the exits evaluated in C (the same formulas; for several switches, Newton's
        method on the weights with Gaussian elimination), each batch of steps recorded at once.
        Returns (t, y), or ("handover", t, y) to go on with the step loop from there."""
        if not self.start_driver(driver, t, y, modes, t_stop):
            return "handover", t, np.array(y, dtype=float)
        if len(sliding) == 1:
            plus, minus = corners[sides[:, 0] > 0][0], corners[sides[:, 0] < 0][0]
            driver.slide(sliding[0], plus, minus, float(memory["alpha"][0]), self.probe, others, drift)
        elif not driver.slide_many(sliding, corners, sides.shape[0] != 2 ** sides.shape[1], memory["alpha"],
                                   self.probe, others, drift):
            return "handover", t, np.array(y, dtype=float)
        driver.check(self.sliding_check())
        old = np.maximum(driver.exits_at(t, y), 0.0)    # at the edge of the sliding region: leaving counts from here
        t_prev, y_prev = float(t), np.array(y, dtype=float)
        positive = sides[:, 0] > 0
        try:
            while True:
                first = self.eval_index
                if self.t_eval is None:
                    code, ts, ys, alphas = driver.slide_advance(old)
                else:
                    code, ts, ys, alphas, report = driver.slide_advance_reporting(old, self.t_eval, first)
                done = len(ts) - (1 if code == 1 else 0)
                if done > 0:
                    self.stats["steps"] += done
                    if self.t_eval is not None:     # the weights at the report points, as the step loop's
                        self.record_reported(driver, code, float(ts[done - 1]), ys[done - 1], first, report,
                                             lambda times, states: ("slide", tuple(corner_ids),
                                                                    weights_at(times, states)))
                    else:
                        weights = np.clip(alphas[:done], 0.0, 1.0)
                        self.blocks_t.append(ts[:done].copy())
                        self.blocks_x.append(ys[:done].copy().T)
                        if len(sliding) == 1:
                            weights = weights[:, 0]
                            weights = np.where(positive[:, None], weights[None, :], 1.0 - weights[None, :])
                        else:
                            weights = np.array([self.corner_weights(w, sides) for w in weights]).T
                        self.blocks_mode.append(("slide", tuple(corner_ids), weights))
                    t_prev, y_prev = float(ts[done - 1]), ys[done - 1].copy()
                    if np.all(np.isfinite(alphas[done - 1])):
                        memory["alpha"] = alphas[done - 1].copy()
                    if self.progress is not None:
                        self.progress(t_prev)
                if code == 0:
                    continue
                if code == 2:
                    return t_prev, y_prev
                if code != 1:       # 3, 4 or a CVODE failure: the step loop takes over and explains
                    return "handover", t_prev, y_prev
                # a possible end in the last step: located as the step loop does
                t_new, y_new = float(ts[-1]), ys[-1].copy()
                self.stats["steps"] += 1
                dense = _DriverStep(driver, t_prev, t_new, y_new).dense_output()
                new = driver.exits[:driver.exits.size // 2].copy()
                hit = driver.slide_end(t_prev, t_new, old, new, self.sliding_check())
                end = t_new if hit is None else hit
                y_end = y_new if hit is None else dense(hit)
                self.record_sliding(t_prev, end, y_end, dense, corner_ids, weights_at)
                if self.progress is not None:
                    self.progress(end)
                if hit is not None:
                    self.note_event(end, f"sliding on {labels} ends")
                    return end, np.array(y_end)
                old[:] = new
                t_prev, y_prev = t_new, y_new
                if t_new >= t_stop:
                    return t_new, y_new
        finally:
            self.collect_driver(driver, "driver_sliding_segments")

    def driver_unfrozen(self, t, y, modes, t_stop):
        """:meth:`unfrozen_interval` in the C driver (the modes found again at every evaluation, in
        C): (t, y) at its end, or None where the driver does not serve it or gives up (a law not
        finite at a trial point, a failed step: nothing it did is kept, and the step loop integrates
        the interval from its start, explaining or retrying as it does)."""
        if not getattr(self.model, "VECTORIZED", True):
            return None         # (a loop model's modes are found with its loops solved: numpy's)
        driver = self.driver_for(np.zeros(0, dtype=int), np.zeros(0))
        if driver is None or not self.start_driver(driver, t, y, modes, t_stop):
            return None
        floors = np.ascontiguousarray(self.model.floor_switches, dtype=np.intc)
        blocks, eval_index, steps_before = len(self.blocks_t), self.eval_index, self.stats["steps"]
        t_prev, creeping = float(t), 0

        def undo():
            del self.blocks_t[blocks:], self.blocks_x[blocks:], self.blocks_mode[blocks:]
            self.eval_index = eval_index
            self.stats["steps"] = steps_before

        try:
            while True:
                code, ts, ys, ms, report = driver.unfrozen_advance(floors, self.t_eval, self.eval_index)
                done = len(ts)
                if code not in (0, 2):
                    undo()
                    return None
                if done == 0:
                    continue
                # the step loop's stop: the first step that creeps for the _CREEP_STEPS-th time in a
                # row, or the one past _UNFROZEN_STEPS; the steps before it kept, it not
                stalled = None
                steps = np.diff(np.concatenate(([t_prev], ts)))
                for i, tiny in enumerate(steps <= _CREEP * np.maximum(np.abs(ts), 1.0)):
                    creeping = creeping + 1 if tiny else 0
                    if creeping >= _CREEP_STEPS or self.stats["steps"] + i + 1 - steps_before > _UNFROZEN_STEPS:
                        stalled = i
                        break
                if stalled is not None:
                    self.stats["steps"] += stalled + 1
                    done = stalled
                else:
                    self.stats["steps"] += done
                if self.t_eval is None and done:
                    # each run of steps with the same modes, one block
                    changes = np.flatnonzero(np.any(ms[1:done] != ms[:done - 1], axis=1)) + 1
                    bounds = [0, *changes.tolist(), done]
                    for a, b in zip(bounds[:-1], bounds[1:]):
                        self.blocks_t.append(ts[a:b].copy())
                        self.blocks_x.append(ys[a:b].copy().T)
                        self.blocks_mode.append(self.mode_id(ms[a]))
                elif self.t_eval is not None and done:
                    # each report point with the modes of its own state, from those of its step
                    times, states, self.eval_index = self.report_points(
                        driver, stalled is None, float(ts[done - 1]), ys[done - 1], self.eval_index, report)
                    for ti, yi in zip(times, states):
                        guess = ms[min(int(np.searchsorted(ts[:done], ti, side="left")), done - 1)]
                        self.blocks_t.append(np.array([ti]))
                        self.blocks_x.append(np.asarray(yi, dtype=float).reshape(-1, 1).copy())
                        self.blocks_mode.append(self.mode_id(self.modes_at(ti, yi, guess)))
                if stalled is not None:
                    raise self.unfrozen_stalled(float(ts[stalled]), ys[stalled].copy())
                t_prev = float(ts[-1])
                if self.progress is not None:
                    self.progress(t_prev)
                if code == 2:
                    return t_prev, ys[-1].copy()
        finally:
            self.collect_driver(driver, "driver_unfrozen_segments")
