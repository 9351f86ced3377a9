"""The integrators: SUNDIALS CVODE and IDA (scikit-sundae), bondc's explicit Dormand-Prince
stepper, scipy's ``solve_ivp`` methods by name (:func:`solver_class`), finite-difference
Jacobians, and the run's choice among them (:class:`_SolverChoice`, a mixin of ``_Run``)."""

import math
import os

import numpy as np

from bondc.runtime.kernels import _integrate
from bondc.runtime.signals import step
from bondc.runtime.adapter import pattern_arrays
from bondc.runtime.native import load_erk


# --------------------------------------------------------------- integrator

_METHODS = {"rk45": "RK45", "rk23": "RK23", "dop853": "DOP853", "radau": "Radau", "bdf": "BDF",
            "lsoda": "LSODA"}
_IMPLICIT = ("Radau", "BDF", "LSODA", "CVODE", "IDA")
_CREEP = 1e-12          # a step this small relative to t does not advance the solution ...
_CREEP_STEPS = 200      # ... and this many of them in a row mean the run is stuck
_UNFROZEN_STEPS = 3000   # steps in one short unfrozen interval: the solver is fighting a discontinuity


def _all_finite(values) -> bool:
    """Whether every value is finite (one sum in the common case; the exact test when it is not)."""
    values = np.asarray(values, dtype=float)
    return math.isfinite(values.sum()) or bool(np.isfinite(values).all())


def _creeping(solver, count: int) -> int:
    """``count`` + 1 if the solver's last step was of rounding size (it is not advancing), else 0."""
    step = abs(solver.t - solver.t_old) if solver.t_old is not None else np.inf
    return count + 1 if step <= _CREEP * max(abs(solver.t), 1.0) else 0


_CVODE_METHODS = {"cvode": "BDF", "cvode-bdf": "BDF", "cvode-adams": "Adams"}
#: Every solver name an experiment may give: the choice by stiffness, SUNDIALS CVODE and IDA,
#: bondc's explicit Dormand-Prince, then scipy's ``solve_ivp`` methods.
SOLVER_NAMES = ("auto", "CVODE", "CVODE-BDF", "CVODE-Adams", "IDA", "DOPRI5") + tuple(_METHODS.values())
#: ``auto``: DOPRI5 where the model is not stiff (:meth:`_Run.choose_solver`), else CVODE
DEFAULT_SOLVER = "auto"


def sundials_available() -> bool:
    """Whether SUNDIALS (scikit-sundae) is installed here. Found, not imported: importing it costs
    0.4 s (it imports scipy.optimize), and a run on bondc's C driver never needs the Python side.
    Looked up once per process (0.1 ms a run otherwise, a run of a small model's)."""
    global _SUNDIALS_FOUND
    if _SUNDIALS_FOUND is None:
        try:
            import importlib.util

            _SUNDIALS_FOUND = importlib.util.find_spec("sksundae") is not None
        except (ImportError, ValueError):
            _SUNDIALS_FOUND = False
    return _SUNDIALS_FOUND


_SUNDIALS_FOUND = None


class _NotFinite(Exception):
    """CVODE asked for the derivative at a time that is not finite: its step size overflowed (a
    derivative near the largest float makes the error estimate inf). SUNDIALS would go on with
    nan forever; raised from the right-hand side, it ends the step. (A state that is not finite
    is CVODE's to handle: a trial that failed, retried with a shorter step.)"""


class CvodeSolver:
    """SUNDIALS CVODE (through scikit-sundae) behind the stepping interface of scipy's ``OdeSolver``.

    ``step()`` takes one internal CVODE step, never past ``t_bound`` (CVODE's
    stop time); ``dense_output()`` interpolates within the last step with
    CVODE's own Nordsieck history (``CVode`` in normal mode with an output time
    inside that step). The event logic of :class:`_Run` therefore drives CVODE
    exactly as it drives scipy's solvers. ``jac`` is the analytic Jacobian;
    where it is not finite (``sqrt`` at 0, a law's kink) a forward-difference
    Jacobian of ``fun`` replaces it for that evaluation and ``jacobian_fallbacks``
    counts how often.

    >>> solver = CvodeSolver(lambda t, y: -y, 0.0, np.array([1.0]), 1.0, rtol=1e-10, atol=1e-12)
    >>> while solver.status == "running":
    ...     _ = solver.step()
    >>> round(float(solver.y[0]), 8), solver.t
    (0.36787944, 1.0)
    """

    variant = "BDF"
    label = "CVODE"

    #: From this many states on, a model with a known Jacobian pattern uses a structured linear
    #: solver: banded where the pattern's band is narrow (a chain), else from SPARSE_FROM states
    #: sparse (SuperLU_MT). Below, dense LU is faster than either (measured: 200 states, 3x).
    STRUCTURED_FROM = 40
    SPARSE_FROM = 400

    def __init__(self, fun, t0, y0, t_bound, *, rtol=1e-6, atol=1e-9, max_step=np.inf, first_step=None,
                 jac=None, pattern=None):
        # SUNDIALS warns on stderr when a step is at rounding size; the run's own guards report that
        os.environ.setdefault("SUNLOGGER_WARNING_FILENAME", os.devnull)
        try:
            from sksundae.cvode import CVODE as SundialsCvode
        except ImportError as error:
            raise ValueError(f"SUNDIALS (scikit-sundae) cannot be imported: {error}; reinstall scikit-sundae "
                             f"or choose a scipy solver (solver = \"LSODA\")") from None

        self.fun, self.jac_function = fun, jac
        self.t_bound = float(t_bound)
        self.t, self.t_old = float(t0), None
        self.y = np.array(y0, dtype=float)
        self.n = self.y.size
        self.status = "running" if self.t < self.t_bound else "finished"
        self.nfev = self.njev = self.nlu = 0
        self.jacobian_fallbacks, self.first_fallback = 0, None
        method = self.variant
        options = {"method": method, "rtol": float(rtol), "atol": float(atol),
                   "max_step": 0.0 if not np.isfinite(max_step) else float(max_step),
                   "first_step": float(first_step or 0.0), "max_num_steps": 100000}
        self.pattern = None
        if jac is not None and method == "BDF":
            options["jacfn"] = self._jacobian
            solver, lower, upper = self.linear_solver_for(self.n, pattern)
            if solver == "band":
                # banded LU: O(n b^2) work on the band only (a chain of sections)
                options.update(linsolver="band", lband=lower, uband=upper)
            elif solver == "sparse":
                    # SuperLU on the structural non-zeros (with the diagonal, which Newton's matrix has)
                    entries = sorted(set(map(tuple, pattern)) | {(i, i) for i in range(self.n)},
                                     key=lambda key: (key[1], key[0]))
                    self.pattern = (np.array([i for i, _ in entries]), np.array([j for _, j in entries]))
                    sparsity = np.zeros((self.n, self.n), dtype=int)
                    sparsity[self.pattern] = 1
                    options.update(linsolver="sparse", sparsity=sparsity)
        self.linear_solver = options.get("linsolver", "dense")
        import warnings

        with warnings.catch_warnings():
            # with a sparsity pattern and our own Jacobian, scikit-sundae says it will not approximate one
            warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
            self._sundials = SundialsCvode(self._rhs, **options)
        self._sundials.init_step(self.t, self.y)

    @classmethod
    def linear_solver_for(cls, n, pattern) -> tuple:
        """("dense" | "band" | "sparse", lower bandwidth, upper bandwidth) for ``n`` states whose
        Jacobian has the structural non-zeros ``pattern`` (None: unknown)."""
        rows, cols = pattern_arrays(pattern)
        if not rows.size or n < cls.STRUCTURED_FROM:
            return "dense", 0, 0
        lower = int(max(0, np.max(rows - cols)))
        upper = int(max(0, np.max(cols - rows)))
        if 4 * (lower + upper + 1) <= n:
            return "band", lower, upper
        return ("sparse" if n >= cls.SPARSE_FROM else "dense"), lower, upper

    def _rhs(self, t, y, yp):
        self.nfev += 1
        if not math.isfinite(t):
            raise _NotFinite(t)
        yp[:] = self.fun(t, y)

    def _jacobian(self, t, y, yp, JJ):
        self.njev += 1
        if not math.isfinite(t):
            raise _NotFinite(t)
        matrix = np.asarray(self.jac_function(t, y), dtype=float)
        if not np.all(np.isfinite(matrix)):
            matrix = self.difference_jacobian(t, np.array(y), np.array(yp))
            if not self.jacobian_fallbacks:
                self.first_fallback = float(t)
            self.jacobian_fallbacks += 1
        if self.pattern is None:
            JJ[:, :] = matrix
        else:
            JJ[:] = matrix[self.pattern]        # compressed sparse columns, in the pattern's order

    def difference_jacobian(self, t, y, f0):
        """Forward differences of ``fun``; a column that is not finite is taken as zero."""
        self.nfev += self.n
        return difference_jacobian(self.fun, t, y, f0)

    def step(self):
        """One internal step towards ``t_bound``; None, or the solver's message when it failed."""
        if self.status != "running":
            raise RuntimeError("the solver is not running")
        for _ in range(2):      # after an interpolation SUNDIALS first returns the step it had already taken
            try:
                result = self._sundials.step(self.t_bound, "onestep", self.t_bound)
            except _NotFinite:
                self.status = "failed"
                return (f"{self.label}: the step size became nan (a derivative near the largest float "
                        f"overflows the error estimate)")
            if not result.success:
                self.status = "failed"
                return f"{self.label}: {result.message}"
            if result.t != self.t:
                break
        self.t_old, self.t = self.t, float(result.t)
        self.y = np.array(result.y[:self.n], dtype=float)
        if self.t >= self.t_bound:
            self.status = "finished"
        return None

    def dense_output(self):
        """``y(t)`` (the states) for ``t`` inside the last step, from the solver's interpolating polynomial."""
        t_old, t_new, y_new = self.t_old, self.t, self.y.copy()

        def interpolate(tt):
            tt = float(tt)
            if tt == t_new:
                return y_new.copy()
            tt = min(max(tt, t_old), t_new)
            return np.array(self._sundials.step(tt, "normal").y[:self.n], dtype=float)

        return interpolate


class CVODE(CvodeSolver):
    """CVODE with variable-order BDF and Newton iteration: the default, for stiff and non-stiff models."""

    variant = "BDF"


class CVODE_Adams(CvodeSolver):  # noqa: N801  (named like the solver name users write)
    """CVODE with Adams-Moulton: cheaper per step for smooth, non-stiff models."""

    variant = "Adams"


class DOPRI5:
    """Dormand-Prince 5(4), explicit, for non-stiff models: six evaluations of the right-hand side a
    step and no linear algebra, where CVODE's BDF solves a linear system at every step and its
    low order takes more steps on a model whose fast modes must be followed anyway (a lightly
    damped chain of masses pushed by a step: 330 steps against 950 for 2 000 states). With compiled
    code the driver steps with bondc's explicit stepper (Boost.Odeint's pair, :func:`load_erk`); with
    the numpy code this is scipy's RK45, the same pair and continuous extension.

    >>> solver = DOPRI5(lambda t, y: -y, 0.0, np.array([1.0]), 1.0, rtol=1e-10, atol=1e-12)
    >>> while solver.status == "running":
    ...     _ = solver.step()
    >>> round(float(solver.y[0]), 8), solver.t
    (0.36787944, 1.0)
    """

    label = "DOPRI5"
    #: The pair's stability boundary on the negative real axis, h*|lambda| (3.31; on the imaginary
    #: axis it is near 1, 2.2-2.5 for a mode damped by 3-6 %): a step longer than this over the
    #: spectral radius is unstable, so a run needs at least span * radius / STABILITY steps.
    STABILITY = 3.3

    def __new__(cls, fun, t0, y0, t_bound, **options):
        options.pop("pattern", None)
        return _integrate.RK45(fun, t0, y0, t_bound, **options)


class IDA:
    """SUNDIALS IDA (through scikit-sundae) behind the same stepping interface as :class:`CvodeSolver`
    (whose ``step`` and ``dense_output`` it shares).

    Given ``dae`` (the model's ``_dae`` with the modes frozen: (t, x, z) -> (dx/dt, loop residuals))
    and ``loops`` ((t, x) -> z, the loops solved), it integrates the DAE form: the unknowns of the
    algebraic loops are IDA's algebraic variables, solved together with the states at every step
    instead of by a Newton iteration of their own inside every right-hand side evaluation. Without
    them (a model with no loop, a sliding or unfrozen interval, whose right-hand side is a
    combination) it integrates ``dx/dt = fun(t, x)`` as the implicit ODE ``x' - fun(t, x) = 0``.
    ``y`` and ``dense_output`` are the states alone.

    >>> solver = IDA(lambda t, y: -y, 0.0, np.array([1.0]), 1.0, rtol=1e-10, atol=1e-12)
    >>> while solver.status == "running":
    ...     _ = solver.step()
    >>> round(float(solver.y[0]), 8), solver.t
    (0.36787944, 1.0)
    """

    variant = label = "IDA"
    step = CvodeSolver.step
    dense_output = CvodeSolver.dense_output

    def __init__(self, fun, t0, y0, t_bound, *, rtol=1e-6, atol=1e-9, max_step=np.inf, first_step=None,
                 jac=None, pattern=None, dae=None, loops=None):
        os.environ.setdefault("SUNLOGGER_WARNING_FILENAME", os.devnull)
        os.environ.setdefault("SUNLOGGER_ERROR_FILENAME", os.devnull)
        try:
            from sksundae.ida import IDA as SundialsIda
        except ImportError as error:
            raise ValueError(f"SUNDIALS (scikit-sundae) cannot be imported: {error}; reinstall scikit-sundae "
                             f"or choose a scipy solver (solver = \"Radau\")") from None
        self.fun, self.jac_function = fun, jac
        self.t_bound = float(t_bound)
        self.t, self.t_old = float(t0), None
        x0 = np.array(y0, dtype=float)
        self.n = x0.size
        self.nfev = self.njev = self.nlu = 0
        self.jacobian_fallbacks, self.first_fallback = 0, None
        self.linear_solver = "dense"
        z0 = np.zeros(0)
        if dae is not None:
            with np.errstate(all="ignore"):
                z0 = np.asarray(loops(t0, x0), dtype=float)
            if not np.all(np.isfinite(z0)):
                dae, z0 = None, np.zeros(0)         # no consistent start: the loops solved per evaluation
        self.dae, self.size = dae, self.n + z0.size
        with np.errstate(all="ignore"):
            rate = np.asarray(dae(t0, x0, z0)[0] if dae is not None else fun(t0, x0), dtype=float)
            # the loops' unknowns change too (an algebraic variable follows the inputs and states):
            # IDA's first error test needs their rates, which the residual does not give; central
            # differences of the solved loops along the states' rates
            z_rate = np.zeros(z0.size)
            if z0.size:
                h = 1e-6 * max(abs(self.t_bound - float(t0)), 1e-300)
                ahead = np.asarray(loops(t0 + h, x0 + h * rate), dtype=float)
                behind = np.asarray(loops(t0 - h, x0 - h * rate), dtype=float)
                z_rate = np.where(np.isfinite(ahead - behind), (ahead - behind) / (2 * h), 0.0)
        self.y = x0
        self.status = "running" if self.t < self.t_bound else "finished"
        options = {"rtol": float(rtol), "atol": float(atol),
                   "max_step": 0.0 if not np.isfinite(max_step) else float(max_step),
                   "first_step": float(first_step or 0.0), "max_num_steps": 100000}
        if z0.size:
            options["algebraic_idx"] = np.arange(self.n, self.size)
            # the loops' unknowns made consistent to IDA's own Newton tolerance first (IDACalcIC)
            options.update(calc_initcond="yp0", calc_init_dt=1e-3 * (self.t_bound - self.t))
        elif jac is not None:
            options["jacfn"] = self._jacobian
        self._sundials = SundialsIda(self._residual, **options)
        self._sundials.init_step(self.t, np.concatenate([x0, z0]),
                            np.concatenate([rate, z_rate]))

    def _residual(self, t, y, yp, res):
        self.nfev += 1
        if self.dae is not None:
            rate, loops = self.dae(t, y[:self.n], y[self.n:])
            res[:self.n] = yp[:self.n] - rate
            res[self.n:] = loops
        else:
            res[:] = yp - self.fun(t, y)

    def _jacobian(self, t, y, yp, res, cj, JJ):
        """dF/dy + cj dF/dy' = cj I - d fun/dx (the ODE form); finite differences where not finite."""
        self.njev += 1
        matrix = np.asarray(self.jac_function(t, y), dtype=float)
        if not np.all(np.isfinite(matrix)):
            matrix = CvodeSolver.difference_jacobian(self, t, np.array(y), np.asarray(self.fun(t, y)))
            if not self.jacobian_fallbacks:
                self.first_fallback = float(t)
            self.jacobian_fallbacks += 1
        JJ[:, :] = cj * np.eye(self.n) - matrix


def difference_jacobian(fun, t, y, f0):
    """Forward differences of ``fun`` at (t, y), whose value there is ``f0``; a column that is not
    finite is taken as zero."""
    y = np.asarray(y, dtype=float)
    matrix = np.empty((y.size, y.size))
    for j in range(y.size):
        h = 1.5e-8 * max(abs(y[j]), 1e-6)
        shifted = y.copy()
        shifted[j] += h
        with np.errstate(all="ignore"):
            column = (np.asarray(fun(t, shifted), dtype=float) - f0) / h
        matrix[:, j] = np.where(np.isfinite(column), column, 0.0)
    return matrix


class _FiniteJacobian:
    """The analytic Jacobian for scipy's implicit solvers, replaced by forward differences where it
    is not finite (a law with an infinite slope, like sqrt at 0), as the SUNDIALS solvers do: scipy
    would stop with its own 'array must not contain infs or NaNs'. Counts the replacements
    (``jacobian_fallbacks``, from ``first_fallback`` on), as the SUNDIALS solvers do."""

    def __init__(self, fun, jac):
        self.fun, self.jac = fun, jac
        self.jacobian_fallbacks, self.first_fallback = 0, None

    def __call__(self, t, y):
        matrix = np.asarray(self.jac(t, y), dtype=float)
        if np.all(np.isfinite(matrix)):
            return matrix
        if not self.jacobian_fallbacks:
            self.first_fallback = float(t)
        self.jacobian_fallbacks += 1
        with np.errstate(all="ignore"):
            return difference_jacobian(self.fun, t, y, np.asarray(self.fun(t, y), dtype=float))


def stiff_solver() -> str:
    """The solver ``auto`` takes for a stiff model: CVODE, LSODA where scikit-sundae is missing."""
    return "CVODE" if sundials_available() else "LSODA"


def solver_class(method):
    """The ``OdeSolver``-like class for a solver name (any case): CVODE, IDA, or a ``solve_ivp`` method."""
    if isinstance(method, type):
        return method
    lowered = str(method).lower()
    if lowered == "ida":
        return IDA
    if lowered == "dopri5":
        return DOPRI5
    if lowered in _CVODE_METHODS:
        return CVODE_Adams if _CVODE_METHODS[lowered] == "Adams" else CVODE
    name = _METHODS.get(lowered)
    if name is None:
        raise ValueError(f"unknown solver {method!r}; use one of {', '.join(SOLVER_NAMES)}")
    return getattr(_integrate, name)


class _SolverChoice:
    """The run's choice of integrator: a solver for a segment, the explicit stepper or CVODE
    (``auto``), the stiffness check. A mixin of :class:`_Run` (it reads the run's settings and counts)."""

    def new_solver(self, fun, jac, t, y, t_stop, modes=None):
        """The solver for one segment; with IDA and ``modes`` (a frozen segment) of a model with
        algebraic loops, the DAE form (:class:`IDA`)."""
        options = dict(self.options)
        if self.implicit:
            options["jac"] = jac
        if self.method is IDA and modes is not None and self.model.dae is not None:
            frozen = np.array(modes)
            options["dae"] = lambda tt, xx, zz: self.model.dae(tt, xx, zz, self.p, frozen)
            options["loops"] = lambda tt, xx: self.model.loop_values(tt, xx, self.p, frozen)
            self.stats["dae"] = True
        if issubclass(self.method, CvodeSolver) and self.model.JACOBIAN_PATTERN is not None:
            options["pattern"] = self.model.JACOBIAN_PATTERN
        if "first_step" in options and options["first_step"] > t_stop - t:
            del options["first_step"]
        finite = None
        if self.implicit and not (self.method is IDA or issubclass(self.method, CvodeSolver)):
            options["jac"] = finite = _FiniteJacobian(fun, jac)
        solver = self.method(fun, t, y, t_stop, **options)
        if finite is not None:
            solver.finite_jacobian = finite
        return solver

    #: ``auto`` takes DOPRI5 where the explicit pair would need at most this many steps for its
    #: stability alone (the span left times the spectral radius over ``DOPRI5.STABILITY``): then
    #: the stiff solver's larger steps cannot save much, and the fast modes are mostly ones every
    #: method must follow (the 1000-section chain: 190 such steps; the flagship: 3 300, stiff)
    EXPLICIT_STEPS = 2000

    def explicit_suits(self, t, radius) -> bool:
        """Whether DOPRI5's steps for its stability alone over the rest of the run from ``t``, at the
        spectral radius ``radius``, are at most ``EXPLICIT_STEPS``."""
        return (self.t_end - t) * radius / DOPRI5.STABILITY <= self.EXPLICIT_STEPS

    def solver_label(self) -> str:
        return getattr(self.method, "label", None) or self.method.__name__

    def choose_solver(self, t, y, modes) -> None:
        """``auto`` at the run's start: DOPRI5 for a smooth model (no switch of the state: its only
        breaks are known times) that is not stiff at (t, y) with ``modes`` (``EXPLICIT_STEPS``),
        where bondc's explicit stepper is built; else the stiff solver. A model with switches of
        the state (a friction, a valve, a diode, a when clause on a state) keeps CVODE: its sliding
        modes sit still on their surfaces, where an explicit method's steps grow to their stability
        bound (two masses held by their frictions crept 1.6e-8 m in 1 s), and its steep laws near
        their switches (an orifice's square root at zero drop) are crossed back and forth by
        explicit steps (three flow reversals for one). The choice does not depend on whether this
        run's code is C or numpy, so both take the same method."""
        if set(self.model.EVENT_SWITCHES) - set(self.model.TIME_SWITCHES):
            return          # switches of the state
        table, why = load_erk()
        if table is None:
            self.stats["solver_note"] = f"auto takes {self.solver_label()}: {why}"
            return
        radius = self.spectral_radius(t, y, modes)
        self.stats["spectral_radius"] = radius
        if self.explicit_suits(t, radius):
            self.method, self.implicit = DOPRI5, False
            self._driver, self._pieces = None, None

    #: ``auto`` running DOPRI5 looks again at the model's stiffness after this many steps, and so on
    STIFFNESS_CHECK = 500

    def check_stiffness(self, t, y, modes) -> bool:
        """``auto`` running DOPRI5: whether the model has become stiff at (t, y) (the explicit pair
        would need more than ``EXPLICIT_STEPS`` steps for its stability over what is left of the
        run), looked at every ``STIFFNESS_CHECK`` steps; then the rest of the run is the stiff
        solver's (True: the caller ends its segment here, and the run restarts from it)."""
        if not self.auto or self.method is not DOPRI5 or self.stats["steps"] < self.stiffness_check:
            return False
        self.stiffness_check = self.stats["steps"] + self.STIFFNESS_CHECK
        radius = self.spectral_radius(t, y, modes)
        if self.explicit_suits(t, radius):
            return False
        self.method = solver_class(stiff_solver())
        self.implicit = self.method.__name__ in _IMPLICIT
        self._driver, self._pieces = None, None
        self.queue.clear()
        self.stats["solver_note"] = (f"auto: DOPRI5 until t={t:.6g} s, then {self.solver_label()} (stiff there: "
                                     f"spectral radius {radius:.3g} 1/s)")
        return True

    def spectral_radius(self, t, y, modes, iterations=20) -> float:
        """An estimate of the spectral radius of the right-hand side's Jacobian at (t, y) with
        ``modes`` (inf where the rates are not finite there): power iteration on difference
        quotients of the right-hand side, as RKC estimates it (Sommeijer, Shampine and Verwer
        1997), in states scaled by their size (|y| + atol/rtol), the geometric mean of the growth
        over the last half of the iterations (a complex pair makes the growth swing). A factor of
        two either way changes nothing the estimate decides.

        >>> run = _SolverChoice.__new__(_SolverChoice)
        >>> run.model, run.p, run.options = type("M", (), {"rhs": staticmethod(
        ...     lambda t, x, p, m: np.array([x[1], -400.0 * x[0] - 4.0 * x[1]]))}), None, {"rtol": 1e-6, "atol": 1e-9}
        >>> round(run.spectral_radius(0.0, np.zeros(2), ()))     # eigenvalues -2 +- 19.9i
        20
        """
        y = np.asarray(y, dtype=float)
        if y.size == 0:
            return 0.0
        rtol, atol = self.options["rtol"], self.options["atol"]
        # the probe's step in each state: 1e-7 of the state's size
        scale = 1e-7 * (np.abs(y) + np.asarray(atol, dtype=float) / np.asarray(rtol, dtype=float))
        rhs, p, sqrt, dot = self.model.rhs, self.p, math.sqrt, np.dot
        with np.errstate(all="ignore"):
            f0 = np.asarray(rhs(t, y, p, modes), dtype=float)
            if not np.all(np.isfinite(f0)):
                return math.inf
            u = np.cos(2.399963229728653 * np.arange(1, y.size + 1))     # golden angle: every sign
            u *= 1.0 / sqrt(float(dot(u, u)))
            probe = np.empty_like(y)
            growth = []
            for _ in range(iterations):
                np.multiply(scale, u, out=probe)
                probe += y
                u = np.asarray(rhs(t, probe, p, modes), dtype=float) - f0
                u /= scale
                norm = sqrt(float(dot(u, u)))
                if not math.isfinite(norm):
                    return math.inf
                if norm == 0.0:
                    return 0.0
                growth.append(norm)
                u *= 1.0 / norm
        return float(np.exp(np.mean(np.log(growth[len(growth) // 2:]))))
