"""scipy's solvers as steppers of bondc's native driver: one implementation of the events.

bondc's C driver (``bondc/native/driver.c``) locates switch crossings, integrates Filippov sliding
modes, restarts and reports points; it steps with CVODE or with any stepper that fills the table of
``bondc/native/erk_api.h`` (the explicit Runge-Kutta stepper of ``erk.cpp`` is one). This module
fills that table with callbacks into one of scipy's ``OdeSolver`` classes (``Radau``, ``BDF``,
``LSODA``, ``RK45``, ...), so that a run with a scipy solver takes its crossings, sliding modes and
restarts from the same C functions as a CVODE run: the solver integrates the driver's own right-hand
side (the model's C rates in the frozen modes, or the sliding combination), called through cffi.

The table's contract (erk_api.h, as erk.cpp keeps it):

* ``start``: 0 (the solver is made at the first step, after the driver has set the segment's
  sliding mode, if any);
* ``step``: one accepted step, never past ``t_stop``: 0; -1 a rate that is not finite (or a
  right-hand side that failed) at a trial point; -2 the step size fell to rounding (scipy's
  "failed"); -3 too many steps; -4 at ``t_stop`` already;
* ``dky``: the state at ``t`` inside the last step (the solver's dense output);
* ``counts``: right-hand side evaluations, steps and rejected steps since the last start (scipy
  counts no rejections: 0).
"""

import weakref

import numpy as np

from bondc.runtime.native import native_file

_STEPPER_TABLES: dict = {}  # (solver class, options) -> _StepperTable: made once per process, never freed
_STEPPER_DRIVERS = weakref.WeakValueDictionary()  # a C driver's address -> its _NativeDriver (its Jacobian)
#: scipy's solvers that take a Jacobian (``jac``): given the driver's, the model's compiled entries
_TAKE_JACOBIAN = ("Radau", "BDF", "LSODA")
#: above this many states the Jacobian goes to scipy as a sparse matrix (its solvers then use SuperLU)
_DENSE_UP_TO = 64


class _RatesFailed(Exception):
    """The driver's right-hand side failed or gave a rate that is not finite."""


class _StepperRun:
    """One stepper: the solver of the current segment and its counts."""

    def __init__(self, n: int):
        self.n = n
        self.solver = None
        self.dense = None
        self.make = None        # makes the solver (at the first step)
        self.t0, self.y0 = 0.0, None
        self.steps = 0
        self.evaluations = 0
        self.max_steps = 0
        self.t_stop = 0.0


class _StepperTable:
    """The table of functions (a ``bondc_erk_api``) over ``method`` with fixed ``options``."""

    def __init__(self, method, options: dict):
        import cffi

        self.method, self.options = method, dict(options)
        ffi = self.ffi = cffi.FFI()
        ffi.cdef("\n".join(line for line in native_file("erk_api.h").splitlines() if not line.startswith("#")))
        self.runs: dict = {}
        self._next = 1
        self.callbacks = [
            ffi.callback("void *(int)", self._create),
            ffi.callback("void (void *)", self._destroy),
            ffi.callback("int (void *, bondc_erk_rhs, void *, double, const double *, double, double, double, "
                         "double, double, long)", self._start, onerror=self._start_failed),
            ffi.callback("int (void *, double *, double *)", self._step, onerror=self._step_failed),
            ffi.callback("int (void *, double, double *)", self._dky, onerror=lambda *_: -1),
            ffi.callback("double (void *)", self._last_step, onerror=lambda *_: 0.0),
            ffi.callback("void (void *, long *)", self._counts),
        ]
        self.table = ffi.new("bondc_erk_api *", [1, *self.callbacks])
        self.address = int(ffi.cast("uintptr_t", self.table))

    # -- the table's functions (called from C)

    def _run(self, memory) -> _StepperRun:
        return self.runs[int(self.ffi.cast("uintptr_t", memory))]

    def _create(self, n):
        key, self._next = self._next, self._next + 1
        self.runs[key] = _StepperRun(int(n))
        return self.ffi.cast("void *", key)

    def _destroy(self, memory):
        self.runs.pop(int(self.ffi.cast("uintptr_t", memory)), None)

    def _start(self, memory, rhs, data, t0, y0, t_stop, rtol, atol, max_step, first_step, max_steps):
        run = self._run(memory)
        ffi, n = self.ffi, run.n
        y = np.frombuffer(ffi.buffer(y0, 8 * n), dtype=float).copy()

        def fun(t, x):
            x = np.ascontiguousarray(x, dtype=float)
            out = np.empty(n)
            run.evaluations += 1
            flag = rhs(float(t), ffi.from_buffer("double[]", x), ffi.from_buffer("double[]", out), data)
            if flag != 0 or not np.all(np.isfinite(out)):
                raise _RatesFailed
            return out

        options = dict(self.options, rtol=rtol, atol=atol)
        if max_step > 0 and np.isfinite(max_step):
            options["max_step"] = max_step
        if 0 < first_step <= t_stop - t0:
            options["first_step"] = first_step
        run.steps = run.evaluations = 0
        run.max_steps, run.t_stop, run.dense = int(max_steps), float(t_stop), None
        # made at the first step: the driver sets a sliding mode after its start, and scipy's
        # solvers evaluate the rates (and BDF its first differences) when they are made
        run.solver = None
        run.make = lambda: self.method(fun, float(t0), y, float(t_stop), **options, **self._jacobian(data, n))
        run.t0, run.y0 = float(t0), y
        return 0

    def _start_failed(self, exception, value, traceback):
        return -2

    def _step(self, memory, t_out, y_out):
        run = self._run(memory)
        if run.solver is None:
            if run.make is None:
                return -2
            try:
                run.solver = run.make()
            except _RatesFailed:
                return -1
        solver = run.solver
        if solver.status != "running":
            return -4 if solver.status == "finished" else -2
        if run.max_steps > 0 and run.steps >= run.max_steps:
            return -3
        try:
            solver.step()
        except _RatesFailed:
            return -1
        if solver.status == "failed":
            return -2
        run.steps += 1
        run.dense = None
        t_out[0] = solver.t
        self.ffi.memmove(y_out, np.ascontiguousarray(solver.y, dtype=float), 8 * run.n)
        return 0

    def _jacobian(self, data, n) -> dict:
        """``{"jac": ...}`` for an implicit method in a frozen segment: the driver's compiled Jacobian;
        nothing (scipy's differences of the rates) in a sliding mode, whose weights change with the
        state (the corners' Jacobians weighted leave that out: Radau's Newton iteration failed on them
        step after step) or where the model has none."""
        if self.method.__name__ not in _TAKE_JACOBIAN:
            return {}
        jacobian = _driver_jacobian(data, self.ffi, n)
        return {} if jacobian is None else {"jac": jacobian}

    def _step_failed(self, exception, value, traceback):
        return -2

    def _dky(self, memory, t, out):
        run = self._run(memory)
        solver = run.solver
        if solver is None:
            values = run.y0
        elif t == solver.t or solver.t_old is None:
            values = solver.y
        else:
            if run.dense is None:
                run.dense = solver.dense_output()
            values = run.dense(float(t))
        self.ffi.memmove(out, np.ascontiguousarray(values, dtype=float), 8 * run.n)
        return 0

    def _last_step(self, memory):
        solver = self._run(memory).solver
        return 0.0 if solver is None or solver.t_old is None else float(solver.t - solver.t_old)

    def _counts(self, memory, out):
        run = self._run(memory)
        out[0], out[1], out[2] = run.evaluations, run.steps, 0


def register_stepper_driver(address: int, driver) -> None:
    """Make the Jacobian of the C driver at ``address`` (a :class:`_NativeDriver` with
    ``jacobian_entries``) the one scipy's implicit solvers use when that driver steps with them."""
    _STEPPER_DRIVERS[address] = driver


def _driver_jacobian(data, ffi, n):
    """``jac(t, y)`` for scipy from the driver whose address is ``data`` (the model's compiled
    Jacobian in the segment's modes): a dense array, sparse above ``_DENSE_UP_TO`` states; None
    where the driver or the model has none, or the segment slides."""
    driver = _STEPPER_DRIVERS.get(int(ffi.cast("uintptr_t", data)))
    if driver is None or not driver.entries or driver.lib.bondc_driver_sliding(driver.handle):
        return None
    rows, cols = driver.keep["rows"][:driver.entries], driver.keep["cols"][:driver.entries]

    def jac(t, y):
        values = driver.jacobian_entries(t, y)
        if values is None:
            raise _RatesFailed
        if n > _DENSE_UP_TO:
            from scipy.sparse import csc_matrix

            return csc_matrix((values, (rows, cols)), shape=(n, n))
        matrix = np.zeros((n, n))
        matrix[rows, cols] = values
        return matrix

    return jac


def stepper_table(method, **options) -> int:
    """The address of a ``bondc_erk_api`` table that steps with scipy's ``method`` (an ``OdeSolver``
    class) given ``options`` (e.g. ``jac_sparsity``); the table lives as long as the process."""
    key = (method, tuple(sorted(options.items())))
    table = _STEPPER_TABLES.get(key)
    if table is None:
        table = _STEPPER_TABLES[key] = _StepperTable(method, options)
    return table.address
