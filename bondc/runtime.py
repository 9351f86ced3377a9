"""What bondc-generated modules run on: signals, switching modes, events, integration.

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

This file imports only numpy, scipy and the standard library (and SUNDIALS'
scikit-sundae where CVODE runs, with LSODA as the fallback without it): bondc
copies it verbatim into every generated module, so a generated module runs where bondc
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
   they select. With the native driver the first round is done in C
   (``bondc_driver_restart``, the same modes to the bit); the runtime goes on
   where the modes ahead differ.
5. Sliding. When modes do not agree with themselves at a restart (each side's
   law pushes the state back across the surface, as friction does when it
   sticks), or a ``coulomb`` friction or a switch that slid until now sits on
   its surface, those switches are candidates for a sliding mode, any number
   at once. The segment follows Filippov's combination: the multilinear blend
   of the right-hand sides at the corners of the candidates' modes (``+-1``;
   ``+-2`` for a ``coulomb`` friction, whose frozen law gives its static limit
   there), with weights ``alpha`` solved by Newton's method so that every
   sliding ``g`` stays put (rates by central differences). From three
   switches on, where the right-hand side is affine in the weights (checked:
   ``affine_holds``), the affine blend of k + 1 corners instead of 2**k; the
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

import atexit
import collections as _collections
import csv as _csv
import functools
import importlib
import math
import os
import sys  # noqa: F401  (the generated module's main writes to sys.stdout)
import time as _time_module
from collections.abc import Mapping as _Mapping

import numpy as np


class _LazyModule:
    """A module imported on first use: reading a model's data (``bondc check``) needs no scipy."""

    def __init__(self, name):
        self._name, self._module = name, None

    def __getattr__(self, attribute):
        if self._module is None:
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attribute)


_integrate = _LazyModule("scipy.integrate")
_optimize = _LazyModule("scipy.optimize")


@functools.lru_cache(maxsize=None)
def _scipy_kernel(package, name, probe):
    """scipy's compiled module ``scipy.<package>.<name>``, loaded by itself, or None.

    Importing ``scipy.optimize`` or ``scipy.integrate`` takes 0.3-0.5 s (they import
    scipy.special, scipy.linalg and scipy's array-API layer), about half of a cached
    ``bondc simulate``; the compiled Brent solver and QUADPACK routine they wrap import
    nothing but numpy. The module is loaded from scipy's folder without running its
    package's ``__init__``; ``probe`` (a function of the module) must return True on a
    known problem, so a scipy that moved or changed the routine gives None and the
    caller uses the public function (same routine, slower import)."""
    full = f"scipy.{package}.{name}"
    if full in sys.modules:
        return sys.modules[full]
    try:
        import importlib.machinery
        import importlib.util

        spec = importlib.util.find_spec("scipy")
        for folder in (spec.submodule_search_locations or []) if spec else []:
            for suffix in importlib.machinery.EXTENSION_SUFFIXES:
                path = os.path.join(folder, package, name + suffix)
                if os.path.isfile(path):
                    module_spec = importlib.util.spec_from_file_location(full, path)
                    module = importlib.util.module_from_spec(module_spec)
                    module_spec.loader.exec_module(module)
                    return module if probe(module) else None
    except Exception:           # noqa: BLE001 (any trouble: the public function does the same job)
        return None
    return None


def _zeros_probe(module):
    return module._brentq(lambda x: x - 0.25, 0.0, 1.0, 1e-12, 4 * _EPS, 100, (), False, True) == 0.25


def _quadpack_probe(module):
    value = module._qagse(lambda x: 3.0 * x * x, 0.0, 1.0, (), 0, 1e-14, 1e-12, 50)
    return abs(value[0] - 1.0) < 1e-12 and value[-1] == 0


def brentq(function, a, b, xtol, rtol):
    """``scipy.optimize.brentq(function, a, b, xtol=xtol, rtol=rtol)``: scipy's Brent solver,
    called without importing scipy.optimize (see :func:`_scipy_kernel`). Raises ValueError when
    ``function`` has the same sign at both ends or is nan at a trial point, as scipy's does."""
    kernel = _scipy_kernel("optimize", "_zeros", _zeros_probe)
    if kernel is None:
        return _optimize.brentq(function, a, b, xtol=xtol, rtol=rtol)

    def checked(x):
        value = function(x)
        if np.isnan(value):
            raise ValueError(f"the function value at x={x:.20g} is NaN")
        return value

    return kernel._brentq(checked, a, b, xtol, rtol, 100, (), False, True)


def bracketed_roots(function, a, b, fa, fb, xtol, rtol):
    """Roots of ``function`` in many brackets ``[a[i], b[i]]`` at once, by bisection of every
    bracket together: ``function(times, rows)`` gives the values at ``times`` (one per bracket
    of ``rows``, an index array), ``fa``/``fb`` its values at the ends. As :func:`brentq` (the
    same tolerance ``xtol + rtol*|x|``; an end where the value is 0 is the root; a value that is
    nan inside gives the right end), but one vectorised call per halving for all brackets, not
    ten Python calls per bracket; a jump (a pwm edge) is found like a zero. The root returned is
    the bracket's end on the far side of the change (where ``function`` has the sign of ``fb``).
    """
    a, b = np.array(a, dtype=float), np.array(b, dtype=float)
    fa, fb = np.asarray(fa, dtype=float), np.asarray(fb, dtype=float)
    roots = b.copy()
    roots[fa == 0] = a[fa == 0]
    side = np.sign(fa)
    active = np.flatnonzero((fa != 0) & (fb != 0) & (side * np.sign(fb) < 0))
    lo, hi = a[active], b[active]
    for _ in range(1100):       # halving the widest double interval down to one ulp takes < 1100
        if not active.size:
            break
        middle = lo + 0.5 * (hi - lo)
        done = (hi - lo <= xtol + rtol * np.abs(hi)) | (middle <= lo) | (middle >= hi)
        if done.any():
            roots[active[done]] = hi[done]
            keep = ~done
            active, lo, hi, middle = active[keep], lo[keep], hi[keep], middle[keep]
            if not active.size:
                break
        with np.errstate(all="ignore"):
            value = np.asarray(function(middle, active), dtype=float)
        lost = np.isnan(value)
        if lost.any():                  # brentq's ValueError: its caller takes the right end
            keep = ~lost
            active, lo, hi, middle, value = active[keep], lo[keep], hi[keep], middle[keep], value[keep]
        before = side[active] * value > 0           # still on the side of a: the change is after
        lo = np.where(before, middle, lo)
        hi = np.where(before, hi, middle)
    return roots


#: Cells that may hide a pulse between two samples of a switch of time are sampled this many times
#: finer, up to this many times over, at most this many values at a time (see _hidden_changes).
_HIDDEN_SPLIT, _HIDDEN_LEVELS, _HIDDEN_VALUES = 64, 3, 1 << 22


def _hidden_changes(values, grid, g, changes):
    """Sign changes of ``g`` (a switch of time, sampled on ``grid``) that the grid's samples do not
    show: a pulse narrower than a cell, whose two samples have the same sign. A cell is suspect
    when its samples are no further from zero than the largest slope seen at it (its own and its
    neighbours') could carry ``g`` across it: the V of ``abs(t - t0) < w``, a ramp that turns. A
    suspect cell is sampled ``_HIDDEN_SPLIT`` times finer, and so are its suspect parts, up to
    ``_HIDDEN_LEVELS`` times. Returns the brackets found (lo, hi, g(lo), g(hi)). A narrow smooth
    bump whose slope the samples never see can still hide: a pulse whose times are known is best
    written with ``step(t, t1) - step(t, t2)``.

    A sample where ``g`` is exactly 0 between samples of one sign may be where a pulse narrower
    than a cell begins or ends (a 50 ps ``pwm`` pulse whose edge falls on the grid): the two cells
    around it are sampled finer as one (:func:`_zero_touches`), the zero in its middle again, so
    that at the finest level the edge is the sample itself."""
    lo, hi, g_lo, g_hi = grid[:-1], grid[1:], g[:-1], g[1:]
    ends = (grid[0], grid[-1])
    spans = _zero_touches(grid[None, :], g[None, :], ends)
    forced = np.zeros(lo.size + spans[0].size, dtype=bool)
    forced[lo.size:] = True
    lo, hi, g_lo, g_hi = (np.concatenate(pair) for pair in zip((lo, hi, g_lo, g_hi), spans))
    found = [[], [], [], []]
    fraction = np.linspace(0.0, 1.0, _HIDDEN_SPLIT + 1)
    for _ in range(_HIDDEN_LEVELS):
        with np.errstate(all="ignore"):
            width = hi - lo
            slope = np.abs(g_hi - g_lo) / width
            bound = slope.copy()
            joined = lo[1:] == hi[:-1]          # neighbours: cells that share an end
            bound[1:] = np.where(joined, np.maximum(bound[1:], slope[:-1]), bound[1:])
            bound[:-1] = np.where(joined, np.maximum(bound[:-1], slope[1:]), bound[:-1])
            suspect = np.flatnonzero(((np.sign(g_lo) * np.sign(g_hi) > 0)
                                      & (np.abs(g_lo) + np.abs(g_hi) <= bound * width)) | forced)
        if not suspect.size or suspect.size * fraction.size > _HIDDEN_VALUES:
            break
        times = lo[suspect, None] + width[suspect, None] * fraction[None, :]
        times[:, -1] = hi[suspect]
        samples = values(times.ravel())
        if not np.all(np.isfinite(samples)):
            break
        at = changes(samples)
        at = at[at % fraction.size != fraction.size - 1]        # not across two cells' ends
        flat = times.ravel()
        for part, value in zip(found, (flat[at], flat[at + 1], samples[at], samples[at + 1])):
            part.append(value)
        cells = samples.reshape(times.shape)
        lo, hi = times[:, :-1].ravel(), times[:, 1:].ravel()
        g_lo, g_hi = cells[:, :-1].ravel(), cells[:, 1:].ravel()
        spans = _zero_touches(times, cells, ends)
        forced = np.zeros(lo.size + spans[0].size, dtype=bool)
        forced[lo.size:] = True
        lo, hi, g_lo, g_hi = (np.concatenate(pair) for pair in zip((lo, hi, g_lo, g_hi), spans))
    return tuple(np.concatenate(part) if part else np.zeros(0) for part in found)


def _zero_touches(times, samples, ends):
    """Spans to sample finer around the zeros of ``samples`` (rows of samples of ``g`` at
    ``times``) that a sign change does not count: a 0 inside a row between samples of one sign
    gives the span of its two neighbours (the zero in its middle); a 0 at ``ends`` (the run's
    first or last time) beside a non-zero sample gives the cell it ends. Returns (lo, hi, g(lo),
    g(hi))."""
    rows, columns = np.nonzero(samples == 0)
    spans = []
    last = samples.shape[1] - 1
    for r, j in zip(rows.tolist(), columns.tolist()):
        if 0 < j < last and np.sign(samples[r, j - 1]) * np.sign(samples[r, j + 1]) > 0:
            spans.append((r, j - 1, j + 1))
        elif j == 0 and times[r, 0] == ends[0] and samples[r, 1] != 0:
            spans.append((r, 0, 1))
        elif j == last and times[r, last] == ends[1] and samples[r, last - 1] != 0:
            spans.append((r, last - 1, last))
    if not spans:
        return (np.zeros(0),) * 4
    r, a, b = (np.array(column) for column in zip(*spans))
    return times[r, a], times[r, b], samples[r, a], samples[r, b]


def quad(function, a, b, epsabs, epsrel, limit):
    """The value of ``scipy.integrate.quad(function, a, b, epsabs=..., epsrel=..., limit=...)``
    for finite a and b (QUADPACK's qagse), without importing scipy.integrate. Warnings that
    scipy would give (limit reached, roundoff) are not given: callers judge the value."""
    kernel = _scipy_kernel("integrate", "_quadpack", _quadpack_probe)
    if kernel is None:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", _integrate.IntegrationWarning)
            return float(_integrate.quad(function, a, b, epsabs=epsabs, epsrel=epsrel, limit=limit)[0])
    return float(kernel._qagse(function, a, b, (), 0, epsabs, epsrel, limit)[0])


RUNTIME_VERSION = 1

# ------------------------------------------------------------------ signals


def table(x, breakpoints, values):
    """``table(x, [x0, x1, ...], [v0, v1, ...])``: piecewise linear, held at the ends.

    >>> float(table(0.5, (0.0, 1.0), (0.0, 10.0))), float(table(2.0, (0.0, 1.0), (0.0, 10.0)))
    (5.0, 10.0)
    """
    return np.interp(x, np.asarray(breakpoints, dtype=float), np.asarray(values, dtype=float))


def step(x, x0):
    """``step(x, x0)``: 0 before ``x0``, 1 from it.

    >>> step(0.1, 0.1), step(0.0999, 0.1)
    (1.0, 0.0)
    """
    if np.ndim(x) == 0 and np.ndim(x0) == 0:
        return 1.0 if x >= x0 else 0.0
    return np.where(np.asarray(x) >= x0, 1.0, 0.0)


def as_time(t):
    """``t`` as a numpy float (or float array), so that arithmetic on it follows numpy rules (1/0 is inf)."""
    return np.float64(t) if np.ndim(t) == 0 else np.asarray(t, dtype=float)


def stack(*values):
    """``np.array(values)``, broadcasting scalars against arrays (a constant among time series)."""
    try:
        return np.array(values, dtype=float)
    except ValueError:
        return np.array(np.broadcast_arrays(*values), dtype=float)


class _ModeReader:
    """A mode vector that records which modes a law reads (only the active branches read theirs)."""

    __slots__ = ("values", "read")

    def __init__(self, values):
        self.values = [float(v) for v in values]
        self.read = set()

    def __getitem__(self, k):
        self.read.add(k)
        return self.values[k]


_CSV_CACHE = {}


class CsvError(ValueError):
    """A measured-signal file that cannot be read."""


def csv_rows(handle):
    """The rows of an open csv file as every stage of bondc reads them: blank lines and lines
    starting with ``#`` are skipped; the first remaining row is the header."""
    return [row for row in _csv.reader(handle)
            if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")]


#: The largest data file read (a measured signal is a few MB; /dev/zero is endless).
MAX_DATA_BYTES = 256 * 2**20


def open_data(path, encoding="utf-8"):
    """Open a data file for reading: only a regular file of at most MAX_DATA_BYTES (a device, a
    named pipe or a directory would block or never end), else CsvError saying which."""
    import stat

    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise CsvError(f"{path}: not a regular file (a device, a pipe or a directory cannot be a data file)")
    if info.st_size > MAX_DATA_BYTES:
        raise CsvError(f"{path}: {info.st_size} bytes, more than the {MAX_DATA_BYTES} a data file may have")
    return open(path, newline="", encoding=encoding)


def header_cell(cell):
    """``"omega [rpm]"`` -> ``("omega", "rpm")``; ``"omega"`` -> ``("omega", None)``: a column's name
    and the unit its header gives (the language reference, section 14)."""
    cell = cell.strip()
    if cell.endswith("]") and "[" in cell:
        name, _, unit = cell[:-1].rpartition("[")
        if name.strip():
            return name.strip(), unit.strip() or None
    return cell, None


def csv_header(path):
    """The column names of a csv file, without their units (``[]`` when it has no header line)."""
    return [name for name, _ in csv_columns(path)]


def csv_columns(path):
    """``[(name, unit or None), ...]``: the header of a csv file."""
    with open_data(path) as handle:
        rows = csv_rows(handle)
    return [header_cell(cell) for cell in rows[0]] if rows else []



def first_decrease(times) -> int | None:
    """The index i of the first sample after which ``times`` decreases (times[i + 1] < times[i]),
    or None: a csv signal's and an external input's times must not decrease."""
    drops = np.flatnonzero(np.diff(times) < 0)
    return int(drops[0]) if drops.size else None


def load_csv(path, column):
    """Time and value arrays of ``column`` in a csv file (loaded once per path and column).

    The one reader of measured signals: ``bondc check``, the equations stage
    (``linearize``) and the simulation all read files through it. The time is
    the column named ``t`` or ``time`` (any case), else the first column;
    rows as :func:`csv_rows` gives them. Times must not decrease. Columns are
    matched by name; a unit in the header (``omega [rpm]``) is not applied
    here: the compiler scales the signal (see :func:`bondc.numeric.csv_scales`).
    """
    path = os.path.abspath(path)
    try:
        info = os.stat(path)
        key = (path, column, info.st_mtime_ns, info.st_size)     # a file edited since is read again
    except OSError:
        key = (path, column)
    if key in _CSV_CACHE:
        return _CSV_CACHE[key]
    with open_data(path) as handle:
        rows = csv_rows(handle)
    if not rows:
        raise CsvError(f"{path}: empty csv file")
    header = [header_cell(cell)[0] for cell in rows[0]]
    lowered = [name.lower() for name in header]
    time_index = lowered.index("t") if "t" in lowered else (lowered.index("time") if "time" in lowered else 0)
    if column not in header:
        raise CsvError(f"{path}: no column {column!r} (columns: {', '.join(header)})")
    value_index = header.index(column)
    times, values = [], []
    for number, row in enumerate(rows[1:], start=2):
        # (the row's cells are not quoted: a model may name any file, and only its column names
        # are shown)
        for index, into in ((time_index, times), (value_index, values)):
            try:
                into.append(float(row[index]))
            except (ValueError, IndexError):
                raise CsvError(f"{path}: row {number} has no number in column {header[index]!r}") from None
    times, values = np.array(times), np.array(values)
    if times.size == 0:
        raise CsvError(f"{path}: no data rows")
    i = first_decrease(times)
    if i is not None:
        raise CsvError(f"{path}: the time column must not decrease: row {i + 3} has t = {times[i + 1]:g} "
                       f"after {times[i]:g}")
    _CSV_CACHE[key] = (times, values)
    return times, values


def csv_signal(x, base_dir, path, column, time_scale=1.0, value_scale=1.0):
    """A measured signal: ``column`` of the csv file at ``x``, linearly interpolated, held at the ends.

    ``time_scale``/``value_scale``: the SI factors of the units the file's header gives (the compiler
    reads them), so that ``x`` is in s and the result in SI."""
    times, values = load_csv(os.path.join(base_dir, path), column)
    return value_scale * np.interp(x / time_scale, times, values)


def csv_times(base_dir, path, column, time_scale=1.0):
    return load_csv(os.path.join(base_dir, path), column)[0] * time_scale


# -------------------------------------------------------- external inputs

class InputError(ValueError):
    """A signal given for an external input that cannot be used (not a table or a function of t)."""


def external_signal(x, store, name, default):
    """An external input (``input u [V] external = default``) at ``x``: what the host put in the
    module's ``EXTERNAL_INPUTS`` (``store``) under ``name`` -- a table ``(times, values)``, linearly
    interpolated and held at the ends as a csv signal is, or a function of t -- else ``default``."""
    source = store.get(name)
    if source is None:
        return default if np.ndim(x) == 0 else np.zeros(np.shape(x)) + default
    if callable(source):
        return _call_input(source, x, name)
    times, values = source
    return np.interp(x, times, values)


def _call_input(function, x, name):
    """A host's function of t at a time or at an array of times (called point by point where it
    does not take an array)."""
    if np.ndim(x) == 0:
        return _input_number(function(float(x)), name, x)
    times = np.asarray(x, dtype=float)
    try:
        values = np.asarray(function(times), dtype=float)
        if values.shape == times.shape:
            return values
    except Exception:
        pass
    return np.array([_input_number(function(float(v)), name, v) for v in times.ravel()]).reshape(times.shape)


def _input_number(value, name, t):
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(f"the function given for external input {name!r} returned {value!r} at t={float(t):g}, "
                         "not a number") from None
    return value


def external_times(store, name):
    """The sample times of the table the host gave external input ``name`` (none for a function):
    segment boundaries, as a csv signal's samples are."""
    source = store.get(name)
    if source is None or callable(source):
        return ()
    return source[0]


def external_inputs(inputs, names):
    """``{name: (times, values) or f(t)}`` checked and made ready for ``external_signal``: times and
    values are 1-D float arrays of one length (at least one sample), finite, times not decreasing.
    Raises InputError naming what is wrong."""
    prepared = {}
    for name, source in dict(inputs or {}).items():
        if name not in names:
            known = ", ".join(names) if names else "none"
            raise InputError(f"{name!r} is not an external input of this model (its external inputs: {known})")
        if callable(source):
            prepared[name] = source
            continue
        try:
            times, values = source
            times, values = np.asarray(times, dtype=float), np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"external input {name!r} takes a pair (times, values) of number sequences or a "
                             f"function of t, not {type(source).__name__}") from None
        if times.ndim != 1 or values.ndim != 1 or times.size != values.size or times.size == 0:
            raise InputError(f"external input {name!r}: times and values must be two 1-D sequences of one length "
                             f"(at least one sample), not shapes {times.shape} and {values.shape}")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(values))):
            raise InputError(f"external input {name!r}: times and values must be finite numbers (no nan or inf)")
        i = first_decrease(times)
        if i is not None:
            raise InputError(f"external input {name!r}: times must not decrease: t = {times[i + 1]:g} comes after "
                             f"{times[i]:g} (sample {i + 2})")
        prepared[name] = (times, values)
    return prepared


def _with_inputs(store, inputs, task):
    """``task`` run with ``store`` holding ``inputs`` (a run's lazily evaluated variables read the
    signals of their run, whatever later runs of the model set)."""
    def run(*args):
        saved = dict(store)
        store.clear()
        store.update(inputs)
        try:
            return task(*args)
        finally:
            store.clear()
            store.update(saved)
    return run


# -------------------------------------------------------- algebraic loops

_BLOCK_SOLUTIONS = {}
#: True while a law is evaluated with a :class:`_ModeReader` (see :func:`solve_block`)
_READING_MODES = False

#: Where a loop's residual is not finite at its guesses, :func:`newton_search` (and the C loop's
#: second attempt) starts from the first of the guesses plus one of these (added to every
#: unknown) where it is finite.
LOOP_START_OFFSETS = (0.0, 1.0, -1.0, 10.0, -10.0, 100.0, -100.0, 1e3, -1e3)


def solve_block(residual, number, guess):
    """Solve ``residual(z) = 0`` (a nonlinear algebraic loop), warm-started from its last solution.

    Returns nan for every unknown when it does not converge, so the caller's
    non-finite check names the loop's unknowns.
    """
    if _READING_MODES:
        # only which modes the law reads is wanted (``_Run.relevant``): the residual's branches
        # depend on the modes alone, so one evaluation reads them all, whatever the unknowns
        residual(np.asarray(guess, dtype=float))
        return tuple(np.asarray(guess, dtype=float))
    key = (residual.__code__, number)       # per model: modules importing this runtime share it
    start = _BLOCK_SOLUTIONS.get(key)
    if start is None or not np.all(np.isfinite(start)):
        start = np.asarray(guess, dtype=float)
    x = solve_loop(lambda z: np.asarray(residual(z), dtype=float), start, guess)
    if x is None:
        return tuple(np.full(len(start), np.nan))
    _BLOCK_SOLUTIONS[key] = x
    return tuple(x)


def solve_loop(function, start, guess):
    """A root of a nonlinear algebraic loop's residual ``function``, or None: MINPACK's hybr from
    ``start`` (a warm start), then from ``guess``, then :func:`newton_search` from ``guess``."""
    def solved(x):
        # hybr's own verdict is not enough: "not making good progress" where the residual is
        # already at rounding level, and "converged" where its trust region collapsed far from
        # the root (a diode switched off at the warm start). Judge by the residual itself, or,
        # since its units are the equations' own, by the Newton step it leaves.
        if x is None or not np.all(np.isfinite(x)):
            return False
        with np.errstate(all="ignore"):
            left = function(x)
            if not np.all(np.isfinite(left)):
                return False
            if _at_rounding(left, x):
                return True
            step = _newton_step(function, x, left)
        return step is not None and float(np.max(np.abs(step))) <= 1e-9 * max(1.0, float(np.max(np.abs(x))))

    for attempt in (np.asarray(start, dtype=float), np.asarray(guess, dtype=float)):
        with np.errstate(all="ignore"):     # an overflow at a trial point: hybr steps back
            x = _optimize.root(function, attempt, method="hybr", options={"xtol": 1e-12}).x
        if solved(x):
            return x
    # MINPACK's hybr does not converge: Newton's method with a line search, from the guesses
    x = newton_search(function, guess)
    return x if solved(x) else None


def _at_rounding(r, z) -> bool:
    """Whether the residual ``r`` at ``z`` is at rounding level: max |r| below 1e-10 of the
    unknowns' size (at least 1). The C loop's second attempt uses the same test."""
    return bool(np.max(np.abs(r)) <= 1e-10 * max(1.0, float(np.max(np.abs(z)))))


def _newton_step(function, z, r):
    """The Newton step J^-1 R at ``z`` (``r``: the residual there), J by forward differences;
    None where J is singular or a value is not finite."""
    jacobian = np.empty((z.size, z.size))
    for j in range(z.size):
        h = 1.5e-8 * max(abs(z[j]), 1.0)
        shifted = np.array(z, dtype=float)
        shifted[j] += h
        jacobian[:, j] = (np.asarray(function(shifted), dtype=float) - r) / h
    if not np.all(np.isfinite(jacobian)):
        return None
    try:
        d = np.linalg.solve(jacobian, r)
    except np.linalg.LinAlgError:
        return None
    return d if np.all(np.isfinite(d)) else None


def newton_search(function, guess, iterations=100):
    """A root of ``function`` by Newton's method with a line search on max |R|, from ``guess``;
    None where it fails (a singular or non-finite Jacobian, no step lowers the residual,
    ``iterations`` steps). The Jacobian is taken by forward differences.

    The second attempt of a nonlinear algebraic loop, where MINPACK's hybr (or, in C, plain
    Newton) does not converge: an exponential law far from its root (a diode's
    ``exp(e/0.025)`` at e = 10 V) moves by one e-fold per Newton step, hundreds of steps. A step
    that does not lower max |R| is halved; one that lowers it to more than a tenth is doubled while
    it keeps lowering it. Where the residual is not finite at the guesses (an exponential that
    overflows there), the search starts from the first of the guesses plus ``LOOP_START_OFFSETS``
    where it is finite. The C loop's second attempt is the same method with the analytic
    Jacobian (``codegen.emit._NativeEmitter.loop_lines``). Converged: the Newton step is below
    1e-12 of the unknowns' size, or the Jacobian is singular or no step lowers the residual where
    that is below 1e-10 of their size (a node that floats between reverse-biased diodes: the
    Jacobian is singular along it to rounding, and the residual flat at rounding level)."""
    with np.errstate(all="ignore"):
        for offset in LOOP_START_OFFSETS:
            z = np.asarray(guess, dtype=float) + offset
            r = np.asarray(function(z), dtype=float)
            norm = float(np.max(np.abs(r))) if r.size else 0.0
            if math.isfinite(norm):
                break
        for _ in range(iterations):
            if not math.isfinite(norm):
                return None
            d = _newton_step(function, z, r)
            if d is None:       # singular: a root if the residual is at rounding level
                return z if _at_rounding(r, z) else None
            step = float(np.max(np.abs(d)))
            if step <= 1e-12 * (1.0 + float(np.max(np.abs(z - d)))):
                return z - d
            alpha, best, least, shrunk, kept = 1.0, 0.0, norm, False, r
            for _ in range(60):
                tried_r = np.asarray(function(z - alpha * d), dtype=float)
                tried = float(np.max(np.abs(tried_r)))
                if tried < least:           # false for nan
                    best, least, kept = alpha, tried, tried_r
                    if not shrunk and (alpha > 1.0 or tried > 0.1 * norm):
                        alpha *= 2.0
                        continue
                    break
                if best > 0.0:
                    break
                alpha *= 0.5
                shrunk = True
            if not best > 0.0:      # no step lowers the residual: a root if it is at rounding level
                return z if _at_rounding(r, z) else None
            z, r, norm = z - best * d, kept, least
    return None


# ------------------------------------------------------------ model access

_MODEL_NAMES = ("STATE_NAMES", "OUTPUT_NAMES", "VARIABLE_NAMES", "VARIABLE_LAWS", "PARAMETERS",
                "SWITCHES", "EVENT_SWITCHES", "x0", "_rhs", "_jac", "_outputs", "_variables",
                "_switches", "_time_breaks")


class _Model:
    """The names :func:`simulate_model` needs, from a namespace dict or any object."""

    def __init__(self, source):
        if isinstance(source, _Model):
            self.__dict__.update(source.__dict__)
            return
        get = source.__getitem__ if isinstance(source, dict) else (lambda name: getattr(source, name))
        for name in _MODEL_NAMES:
            setattr(self, name.lstrip("_"), get(name))
        count = len(self.SWITCHES)

        def optional(name, convert, default):
            """A name modules from older bondc versions (or hand-made models) may lack."""
            try:
                return convert(get(name))
            except (KeyError, AttributeError):
                return default

        self.derive_parameters = optional("_derive_parameters", lambda f: f, None)
        self.DEFAULTS = optional("DEFAULTS", dict, {})
        self.VECTORIZED = optional("VECTORIZED", bool, True)
        self.SWITCH_DEPENDS = optional("SWITCH_DEPENDS", lambda d: tuple(map(tuple, d)), None)
        self.SWITCH_VERTICES = optional("SWITCH_VERTICES", lambda v: tuple(map(float, v)), (1.0,) * count)
        self.SWITCH_KINDS = optional("SWITCH_KINDS", tuple, ("sign",) * count)
        self.SWITCH_TRUTH = optional("SWITCH_TRUTH", lambda v: tuple(map(int, v)), (0,) * count)
        self.SWITCH_OWNERS = optional("SWITCH_OWNERS", tuple, ("",) * count)
        self.TIME_SWITCHES = optional("TIME_SWITCHES", lambda k: tuple(map(int, k)), ())
        # a model with an algebraic loop: its switches of time alone, over arrays of times
        self.time_switches = optional("_time_switches", lambda f: f, None)
        # variables that are one quantity share a row of the result (VARIABLE_ROWS[i]: variable
        # i's row, rows numbered in order of first use); ``row_variables``: each row's first variable
        rows = optional("VARIABLE_ROWS", lambda r: tuple(map(int, r)), None)
        firsts: dict = {}
        for i, row in enumerate(rows or ()):
            firsts.setdefault(row, i)
        if rows is None or len(rows) != len(self.VARIABLE_NAMES) or list(firsts) != list(range(len(firsts))):
            rows, firsts = tuple(range(len(self.VARIABLE_NAMES))), dict(enumerate(range(len(self.VARIABLE_NAMES))))
        self.VARIABLE_ROWS, self.row_variables = rows, tuple(firsts.values())
        self.JACOBIAN_PATTERN = optional("JACOBIAN_PATTERN", tuple, None)
        self.WHEN_LABELS = optional("WHEN_LABELS", tuple, ())
        self.WHEN_TARGETS = optional("WHEN_TARGETS", lambda w: tuple(map(tuple, w)), ())
        self.WHEN_SWITCHES = optional("WHEN_SWITCHES", tuple, ())
        self.WHEN_ACTIONS = optional("WHEN_ACTIONS", tuple, ())
        self.when_conditions = optional("_when_conditions", lambda f: f, None)
        self.dae = optional("_dae", lambda f: f, None)
        self.loop_values = optional("_loop_values", lambda f: f, None)
        self.NATIVE_SOURCE = optional("NATIVE_SOURCE", lambda text: "".join(text), "")
        self.NATIVE_UNAVAILABLE = optional("NATIVE_UNAVAILABLE", str, "")
        # the external inputs the host supplies: the module's own dict, which its functions read
        self.EXTERNAL_INPUT_NAMES = optional("EXTERNAL_INPUT_NAMES", tuple, ())
        self.EXTERNAL_INPUTS = optional("EXTERNAL_INPUTS", lambda store: store, None)
        self.native_library = None      # (ffi, lib) when the model's C code carries the CVODE driver
        self.when_offsets = None        # clause k sets targets offsets[k]:offsets[k + 1], where C runs them
        self.floor_switches = np.array([kind == "floor" for kind in self.SWITCH_KINDS], dtype=bool)
        # the modes some switching function reads (a nested switch's); None: not known
        self.modes_read_by_switches = None if self.SWITCH_DEPENDS is None else np.array(
            [any(k in read for read in self.SWITCH_DEPENDS) for k in range(count)], dtype=bool)
        self.parameter_names = tuple(self.PARAMETERS)


def param_array(parameters, p=None, derive=None):
    """Parameter vector from ``None`` (the defaults), a dict of overrides or an array.

    With a dict, ``derive(array, given_names)`` recomputes the parameters
    defined by others that were not given (the generated ``_derive_parameters``).

    >>> param_array({"m": 2.0, "k": 800.0}, {"k": 100})
    array([  2., 100.])
    """
    names = tuple(parameters)
    if p is None:
        return np.array([float(parameters[name]) for name in names], dtype=float)
    if isinstance(p, dict):
        unknown = sorted(set(p) - set(names))
        if unknown:
            raise KeyError(f"unknown parameter{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                           f"the parameters are: {', '.join(names)}")
        array = np.array([float(p.get(name, parameters[name])) for name in names], dtype=float)
        return derive(array, frozenset(p)) if derive is not None and p else array
    array = np.asarray(p, dtype=float)
    if array.shape != (len(names),):
        raise ValueError(f"p must have {len(names)} entries ({', '.join(names)}), got shape {array.shape}")
    return array


def mode_values(values, floors=None):
    """Modes from switching-function values: their signs, and for ``floor`` switches their floors
    (``floors`` a boolean mask over the first axis); nan gives 0."""
    values = np.asarray(values, dtype=float)
    modes = np.sign(values)
    if floors is not None and np.any(floors):
        modes[floors] = np.floor(values[floors])
    modes[np.isnan(modes)] = 0.0
    return modes


def corner_weights(alpha, sides):
    """Weights of the corners. Multilinear (2**k corners): prod_i alpha_i (side +) or
    1 - alpha_i (side -). Affine (k + 1 corners): 1 - sum(alpha) for the all-minus corner and
    alpha_i for the corner with switch i alone on its plus side (the same combination where the
    right-hand side is affine in each switch's weight, as a friction force is)."""
    if sides.shape[0] != 2 ** sides.shape[1]:
        return np.concatenate(([1.0 - np.sum(alpha)], alpha))
    factors = np.where(sides > 0, alpha[None, :], 1.0 - alpha[None, :])
    return np.prod(factors, axis=1)


def filippov_alpha(rates, sides, guess=None):
    """The weights alpha (one per sliding switch) that make every sliding switch's rate zero.

    The rate is multilinear in alpha (exactly the Filippov / equivalent-control combination;
    linear in the affine one); Newton's method with least squares, so a switch whose rate does not depend on its own
    weight (a free clutch) keeps its guess. The result is not clipped: a weight outside
    [0, 1] means that switch cannot be held on its surface.
    """
    count = sides.shape[1]
    alpha = np.full(count, 0.5) if guess is None else np.clip(np.array(guess, dtype=float), 0.0, 1.0)
    affine = sides.shape[0] != 2 ** count      # the rate is linear in alpha: Newton converges at once
    if count == 1:      # one switch: the rate is linear in alpha, alpha*r+ + (1 - alpha)*r- = 0
        plus, minus = rates[sides[:, 0] > 0, 0][0], rates[sides[:, 0] < 0, 0][0]
        if not (math.isfinite(plus) and math.isfinite(minus)):
            return np.full(1, np.nan)
        return alpha if minus == plus else np.array([minus / (minus - plus)])
    for _ in range(3 if affine else 20):
        residual = corner_weights(alpha, sides) @ rates
        if affine:
            jacobian = (rates[1:] - rates[0]).T
        else:
            jacobian = np.empty((count, count))
            for j in range(count):
                others = np.where(sides > 0, alpha[None, :], 1.0 - alpha[None, :])
                others[:, j] = sides[:, j]          # d/d alpha_j of alpha_j or 1 - alpha_j
                jacobian[:, j] = np.prod(others, axis=1) @ rates
        if not (np.all(np.isfinite(jacobian)) and np.all(np.isfinite(residual))):
            return np.full(count, np.nan)
        delta = np.linalg.lstsq(jacobian, -residual, rcond=1e-12)[0]
        alpha = alpha + delta
        if np.max(np.abs(delta)) <= 1e-13:
            break
    return alpha


def modes_at(model, t, x, p, guess=None):
    """The mode vector of the unfrozen law at one point: ``m = sign(g(t, x, m))``.

    Switching functions of nested switches depend on inner modes only, so the
    fixed point is reached in at most depth + 1 evaluations.
    """
    count = len(model.SWITCHES)
    if count == 0:
        return np.zeros(0)
    modes = np.ones(count) if guess is None else np.array(guess, dtype=float)
    read = getattr(model, "modes_read_by_switches", None)
    for _ in range(count + 1):
        new = mode_values(model.switches(t, x, p, modes), getattr(model, "floor_switches", None))
        if np.array_equal(new, modes):
            break
        if read is not None and not read[new != modes].any():
            return new      # no switching function reads a mode that changed: the next pass gives new again
        modes = new
    return modes


def _columns_by_mode(model, t, x, p):
    """Group the columns of a trajectory by their modes: {modes tuple: column indices}."""
    groups = {}
    guess = None
    for j in range(t.size):
        guess = modes_at(model, t[j], x[:, j], p, guess)
        groups.setdefault(tuple(guess), []).append(j)
    return groups


def evaluate(model, what, t, x, p=None):
    """Evaluate ``outputs``/``variables``/``rhs``/``jacobian`` with the unfrozen law.

    ``t`` a number and ``x`` a state vector, or ``t`` of shape (N,) and ``x``
    of shape (n, N) for ``outputs`` and ``variables``.
    """
    model = model if isinstance(model, _Model) else _Model(model)
    p = param_array(model.PARAMETERS, p, model.derive_parameters)
    function = {"outputs": model.outputs, "variables": model.variables,
                "rhs": model.rhs, "jacobian": model.jac, "switches": model.switches}[what]
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        modes = modes_at(model, t, x, p)
        value = function(t, x, p, modes)
        return np.asarray(value, dtype=float) if what in ("rhs", "jacobian", "switches") else \
            tuple(float(v) for v in value)
    t = np.broadcast_to(np.asarray(t, dtype=float), x.shape[1:])
    names = model.OUTPUT_NAMES if what == "outputs" else model.VARIABLE_NAMES
    out = np.full((len(names), t.size), np.nan)
    for modes, columns in _columns_by_mode(model, t, x, p).items():
        columns = np.asarray(columns)
        values = function(t[columns], x[:, columns], p, np.array(modes))
        for i, value in enumerate(values):
            out[i, columns] = value
    return tuple(out)


# ------------------------------------------------------------------ result


class _Deferred:
    """A matrix of ``shape`` whose columns the ``tasks`` fill (each called with the matrix), on
    the first call only; read-only afterwards. The tasks hold the model, the parameters and the
    points they need, never the run."""

    __slots__ = ("shape", "tasks", "matrix")

    def __init__(self, shape, tasks):
        self.shape, self.tasks, self.matrix = shape, list(tasks), None

    def __call__(self):
        if self.matrix is None:
            matrix = np.empty(self.shape)
            with np.errstate(all="ignore"):
                for task in self.tasks:
                    task(matrix)
            # a row is shared by the variables that are one quantity: read-only, so that changing
            # one in place cannot silently change the others
            matrix.flags.writeable = False
            self.matrix, self.tasks = matrix, None
        return self.matrix


class LazyRows(_Mapping):
    """``name -> array``: the rows of a matrix that is evaluated when a value is first read
    (``rows``: name -> row index; names sharing a row share one read-only array).

    A run's variables are this: the integration stores the states, and every bond variable at
    every point is evaluated only by a caller that reads one (``bondc simulate`` reads them all,
    for the CSV, the energy account and the check that each is finite). Names, their number
    and ``in`` need no evaluation; a copy (``dict(...)``) or a pickle holds plain arrays.

    >>> lazy = LazyRows({"a": 0, "b": 1, "c": 0}, _Deferred((2, 3), [lambda m: m.__setitem__(
    ...     slice(None), [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])]))
    >>> list(lazy), "b" in lazy, lazy.evaluated
    (['a', 'b', 'c'], True, False)
    >>> lazy["b"].tolist(), lazy["a"] is lazy["c"], lazy.evaluated
    ([4.0, 5.0, 6.0], True, True)
    """

    __slots__ = ("_rows", "_deferred", "_views")

    def __init__(self, rows, deferred):
        # a dict is kept as given, never changed: the results of a model's runs share their rows
        self._rows = rows if isinstance(rows, dict) else dict(rows)
        self._deferred, self._views = deferred, None

    @property
    def evaluated(self) -> bool:
        return self._views is not None

    def _values(self) -> dict:
        if self._views is None:
            matrix = self._deferred()
            by_row = {}
            self._views = {name: by_row.setdefault(row, matrix[row]) for name, row in self._rows.items()}
            self._deferred = None
        return self._views

    def __getitem__(self, name):
        return self._values()[name]

    def __iter__(self):
        return iter(self._rows)

    def __len__(self):
        return len(self._rows)

    def __contains__(self, name):
        return name in self._rows

    def __reduce__(self):
        return dict, (dict(self._values()),)

    def __repr__(self):
        shown = ", ".join(list(self._rows)[:4]) + (", ..." if len(self._rows) > 4 else "")
        return f"<LazyRows of {len(self._rows)} ({shown}){'' if self.evaluated else ', not evaluated yet'}>"


class Result:
    """A simulation: ``t``, dicts ``states``, ``outputs``, ``variables`` of arrays by name
    (``variables`` a :class:`LazyRows`: evaluated when one is first read).

    ``complete`` is False when the run stopped early; ``message`` says why and
    ``failure`` (a dict: time, variable, law, cause, hint) gives the details.
    ``events`` lists ``(time, label)`` of every mode change, known-time break
    and chattering episode; ``stats`` the solver's counts.
    """

    def __init__(self, t, states, outputs, variables, events, complete, message, failure, stats,
                 parameters, jumps=(), sliding=()):
        self.t = t
        self.states = states
        self.outputs = outputs
        self.variables = variables
        self.events = events
        self.complete = complete
        self.message = message
        self.failure = failure
        self.stats = stats
        self.parameters = parameters
        self.jumps = list(jumps)        # (t, states before, states after) where a when clause fired
        # (t0, t1, corners, times, weights) of each Filippov sliding mode: its points are those of
        # (t0, t1], at `times`, each the combination of the right-hand sides at the corners (mode
        # vectors, one per row) with the corners' `weights` there (one row per corner)
        self.sliding = list(sliding)

    def __repr__(self):
        end = f"{self.t[-1]:.6g}" if self.t.size else "-"
        return (f"<Result {'complete' if self.complete else 'INCOMPLETE'}: {self.t.size} points to t={end}, "
                f"{len(self.events)} events>")


def write_csv(result, path, variables=False):
    """Write ``t``, the outputs, the states (and with ``variables`` every variable) as csv.

    ``path`` may be a file name or an open text file; each value is the shortest text that
    reads back to the same float.
    """
    names = ["t"] + list(result.outputs) + list(result.states)
    columns = [result.t] + list(result.outputs.values()) + list(result.states.values())
    if variables:
        extra = [name for name in result.variables if name not in names]
        names += extra
        columns += [result.variables[name] for name in extra]
    data = np.column_stack(columns).tolist() if columns[0].size else []
    close = False
    if isinstance(path, (str, os.PathLike)):
        handle, close = open(path, "w", encoding="utf-8", newline=""), True
    else:
        handle = path
    try:
        handle.write(",".join(names) + "\n")
        for row in data:
            handle.write(",".join(map(repr, row)) + "\n")
    finally:
        if close:
            handle.close()


# --------------------------------------------------------------- integrator

_METHODS = {"rk45": "RK45", "rk23": "RK23", "dop853": "DOP853", "radau": "Radau", "bdf": "BDF",
            "lsoda": "LSODA"}
_IMPLICIT = ("Radau", "BDF", "LSODA", "CVODE", "IDA")
_EPS = np.finfo(float).eps
_CREEP = 1e-12          # a step this small relative to t does not advance the solution ...
_CREEP_STEPS = 200      # ... and this many of them in a row mean the run is stuck
_STALL_FRACTION = 1e-7  # restarts that advance time by less than this fraction of the run ...
_STALL_RESTARTS = 5000  # ... this many times in a row mean the run is stalled
_UNFROZEN_STEPS = 3000   # steps in one short unfrozen interval: the solver is fighting a discontinuity
_MAX_SLIDING = 8         # switches sliding at once in the multilinear combination (2**8 corners) ...
_MAX_HELD = 4096         # ... and in the affine one (k + 1 corners), when the laws combine linearly
SLIDING_CHECKS = 1000    # a sliding mode's exits are tested at least this often over the run's span
_EVENT_ROUNDS = 10       # rounds of when clauses firing at one instant
_ZENO_FIRINGS = 16       # a when clause firing this often with ever shorter intervals ...
_ZENO_INTERVAL = 1e-4    # ... the last shorter than this fraction of the run, accumulates (Zeno)
_ZENO_RATIO = 0.98       # ... each at most this times the one before (a frequency sweep's shrink slower)


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


_PATTERNS: dict = {}        # id of a Jacobian pattern -> (it, rows, columns)
_MEMOS: dict = {}           # id of a model's x0 function -> (it, {what: memo})


def _model_memo(model, what) -> dict:
    """A dict kept for ``what`` of a model across its runs in this process (a run works on a copy
    of the model, :class:`_Model`; the generated module's own ``x0`` function names it)."""
    key = model.x0
    known = _MEMOS.get(id(key))
    if known is None or known[0] is not key:
        known = _MEMOS[id(key)] = (key, {})
    return known[1].setdefault(what, {})


def pattern_arrays(pattern):
    """(rows, columns) of a Jacobian pattern (``(row, column)`` pairs; None: none) as arrays, made
    once per pattern object: a model's every run asks (6 000 entries for a 1000-section chain).

    >>> rows, cols = pattern_arrays(((0, 1), (1, 0)))
    >>> rows.tolist(), cols.tolist()
    ([0, 1], [1, 0])
    """
    known = _PATTERNS.get(id(pattern))
    if known is None or known[0] is not pattern:
        entries = np.array(pattern or (), dtype=np.intp).reshape(-1, 2)
        known = _PATTERNS[id(pattern)] = (pattern, entries[:, 0].copy(), entries[:, 1].copy())
    return known[1], known[2]


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
        return cls(ffi, lib, handle, n, keep)

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

    def restart(self, t, y, guess, floors, probe, strict):
        """``_Run.restart_modes`` in C where the restart is simple (``bondc_driver_restart``): the
        modes, or None where the runtime decides."""
        buffer = self.ffi.from_buffer
        out = np.empty(max(guess.size, 1))
        code = self.lib.bondc_driver_restart(self.handle, float(t), buffer("double[]", np.ascontiguousarray(y, dtype=float)),
                                             buffer("double[]", np.ascontiguousarray(guess, dtype=float)),
                                             buffer("int[]", floors), float(probe), int(bool(strict)),
                                             buffer("double[]", out))
        return out[:guess.size] if code == 1 else None

    def exits_at(self, t, y):
        """The sliding mode's exits at (t, y), evaluated in C (as ``exits`` of :meth:`_Run.sliding_segment`)."""
        out = np.empty(self.exits.size // 2)
        self.lib.bondc_driver_exits(self.handle, float(t), self.ffi.from_buffer("double[]", np.ascontiguousarray(
            y, dtype=float)), self.ffi.from_buffer("double[]", out))
        return out

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

    def deadbands(self, t, y, modes, index, rtol, atol):
        """:meth:`_Run.deadbands` in C (the same sums in the same order), or None where it cannot run."""
        buffer = self.ffi.from_buffer
        y = np.ascontiguousarray(y, dtype=float)
        modes = np.ascontiguousarray(modes, dtype=float)
        index = np.ascontiguousarray(index, dtype=np.intc)
        out = np.empty(index.size)
        if y.size != self.n or self.lib.bondc_deadbands(
                self.handle, float(t), buffer("double[]", y), buffer("double[]", modes) if modes.size else self.ffi.NULL,
                float(rtol), float(atol), int(index.size), buffer("int[]", index), buffer("double[]", out)) != 0:
            return None
        return out

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
    """The driver's last step seen as a solver by :meth:`_Run.crossing`: t_old, t, y, dense_output()."""

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

    def switch_value(self, modes, tt, k):
        """Switching function ``k`` with ``modes`` at ``tt``, on the state ``dense_output()`` gives
        there: one call into C (the crossing's root finding calls it a few times per event)."""
        driver = self.driver
        return driver.lib.bondc_driver_switch(driver.handle, float(tt), self.t_old, self.t,
                                              driver.ffi.from_buffer("double[]", self.y),
                                              driver.ffi.from_buffer("double[]", modes), int(k))


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


def _may_dip(left, middle, right) -> bool:
    """Whether an exit sampled at the ends and the middle of an interval, positive at all three,
    may dip below 0 between them: the parabola through the three comes within its own curvature
    (the second difference, the size of what the parabola leaves out where the interval is long
    against the exit's time scale) of 0 inside the interval. A 40 ms peak of a push past a static
    limit, every 0.9 s, between tests 0.3 s apart: the parabola's lowest point is 0.5 N above 0,
    its second difference 1.1 N, and the halves are searched until the peak is found."""
    with np.errstate(all="ignore"):
        curve = 2 * left + 2 * right - 4 * middle      # p(u) = left + slope*u + curve*u^2, u in [0, 1]
        slope = 4 * middle - 3 * left - right
        vertex = np.where(curve > 0, -slope / (2 * curve), 0.0)
        inside = (vertex > 0) & (vertex < 1)
        lowest = np.where(inside, left + slope * vertex + curve * vertex * vertex, np.minimum(left, right))
        # an exit at 0 at an end (where the mode began) leaves through the sign test, not here
        return bool(np.any((left > 0) & (right > 0) & (lowest - 0.5 * np.abs(curve) < 0)))


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


#: A state beyond this magnitude (in SI units) has left every physical range: the run has diverged.
DIVERGED = 1e30

#: At most this many numbers in a run's result, points x (states + outputs + variables), and at
#: most MAX_POINTS points: recording, the result and its analyses take about 1.2 kB per point of a
#: small model (measured: 17 GB for 14 million points), so a run stays near 1 GB.
MAX_VALUES = 20_000_000
MAX_POINTS = 1_000_000


def max_points(width: int) -> int:
    """How many points a result of ``width`` numbers per point may hold."""
    return max(1000, min(MAX_POINTS, MAX_VALUES // max(1, width)))


class _CountedBlocks(list):
    """A run's ``blocks_mode``: a block's mode is appended last (after its times and states), and
    then its points count against the run's limit; past it the run stops with what it has."""

    def __init__(self, run):
        super().__init__()
        self.run = run

    def append(self, mode):
        super().append(mode)
        run = self.run
        run.points += int(run.blocks_t[-1].size)
        if run.points > run.max_points:
            t = float(run.blocks_t[-1][-1])
            raise _Stop({"message": f"the result reached {run.points} points at t={t:.6g}, more than the "
                                    f"{run.max_points} a run of this model records (at most {MAX_VALUES:.0e} "
                                    "numbers, about 1 GB with its analyses)",
                         "time": t, "variable": None, "law": None, "kind": "points",
                         "cause": "every point keeps every state, output and bond variable",
                         "hint": "report on a coarser grid (--dt or dt in the experiment) or simulate a "
                                 "shorter time"})


class _Stop(Exception):
    """Ends the run early; carries the failure dict."""

    def __init__(self, failure):
        super().__init__(failure["message"])
        self.failure = failure


class _Stalled(_Stop):
    """The unfrozen law stalled at (t, y): the switches there may be held on their surfaces."""

    def __init__(self, failure, t, y):
        super().__init__(failure)
        self.t, self.y = float(t), np.array(y, dtype=float)


class _Run:
    """One simulation run of a model: segments between events, recorded points."""

    def __init__(self, model, p, t_start, t_end, t_eval, method, rtol, atol, max_step, first_step,
                 progress, max_events, max_event_rate):
        self.model = model
        self.p = p
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
        self.progress = progress
        self.max_events = max_events
        self.max_event_rate = max_event_rate
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
        self.affine_checked = set()    # ... and those whose every pair of corners was checked once
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
        return modes_at(self.model, t, x, self.p, guess)

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

    # -- failures

    def diagnose(self, t, x, modes, context):
        """Name the first non-finite quantity at (t, x): a state, a variable in causal order, a derivative."""
        model = self.model
        variable, law, value = None, None, None
        for name, xi in zip(model.STATE_NAMES, x):
            if not np.isfinite(xi):
                variable, value = name, xi
                break
        if variable is None:
            with np.errstate(all="ignore"):
                values = model.variables(t, x, self.p, modes)
            for name, text, vi in zip(model.VARIABLE_NAMES, model.VARIABLE_LAWS, values):
                if not np.all(np.isfinite(vi)):
                    variable, law, value = name, text, float(np.asarray(vi).ravel()[0])
                    break
        if variable is None:
            with np.errstate(all="ignore"):
                derivatives = np.asarray(model.rhs(t, x, self.p, modes), dtype=float)
            for name, di in zip(model.STATE_NAMES, derivatives):
                if not np.isfinite(di):
                    variable, value = f"der({name})", di
                    break
        what = "nan" if value is None or np.isnan(value) else "inf"
        where = f"'{variable}' became {what} at t={t:.6g}" if variable else f"a {what} appeared at t={t:.6g}"
        if law:
            where += f" (its law: {variable} = {law})"
        states = ", ".join(f"{name}={float(xi):.6g}" for name, xi in zip(model.STATE_NAMES, x))
        if what == "nan" and law and law.startswith("root of the algebraic loop"):
            cause = ("the nonlinear algebraic loop was not solved at this state (Newton's method with a line "
                     "search from its guesses, then MINPACK's hybr): a law in the loop with an infinite slope "
                     "(sign(e)*sqrt(abs(e)) at e = 0) or that leaves its domain on the way, unknowns of very "
                     "different sizes (flows of 1e-8 m^3/s beside pressures of 1e5 Pa), or no solution there")
            hint = (f"the states at t={t:.6g}: {states}. A small storage element in the loop (a node volume, "
                    "a line capacitance, a mass) removes the loop and its solve; a law with a finite slope at "
                    "zero (a laminar band around zero flow) lets Newton's method through")
        else:
            if what == "nan":
                cause = ("a law was evaluated outside its domain: the square root or logarithm of a negative "
                         "number, 0/0 or inf - inf")
            else:
                cause = "a division by zero or an overflow (a quantity growing without bound)"
            hint = (f"check the law of '{variable or '?'}' for the states at t={t:.6g} ({states}); a state that "
                    "left its physical range (a negative pressure, a closed gap) is the usual reason")
        return {"message": f"{context}{where}", "time": float(t), "variable": variable,
                "law": law, "cause": cause, "hint": hint, "kind": "nonfinite"}

    def diverged(self, t, y):
        """The failure of a run whose state left every physical range (DIVERGED)."""
        k = int(np.argmax(np.abs(y)))
        name = self.model.STATE_NAMES[k]
        return {"message": f"the state '{name}' grew beyond {DIVERGED:g} (to {float(y[k]):.3g}) at t={t:.6g}",
                "time": float(t), "variable": name, "law": None, "kind": "diverged",
                "cause": "the model is unstable (a negative damping or resistance, a positive feedback) or a "
                         "law grows without bound",
                "hint": "check the signs and values of the parameters that damp this state"}

    def solver_failure(self, t, message):
        failure = None
        if self.bad is not None and self.bad[0] >= t - 1e-6 * max(self.span, 1e-300):
            failure = self.diagnose(*self.bad, context=f"the solver could not go past t={t:.6g}: ")
            failure["time"] = float(t)
            failure["solver_message"] = message
            return failure
        method = self.method.__name__
        hint = ("try a stiff solver (solver = \"CVODE\" in the experiment)" if not self.implicit
                else "check the laws near that time for a singularity or a switch bondc cannot see "
                     "(a discontinuity hidden in a smooth-looking function), or loosen rtol/atol")
        return {"message": f"the solver ({method}) failed at t={t:.6g}: {message}", "time": float(t),
                "variable": None, "law": None,
                "cause": "the step size became too small: the model is stiffer than the method can "
                         "handle, a variable grows without bound, or the right-hand side is discontinuous",
                "hint": hint, "kind": "solver", "solver_message": message}

    # -- the run

    def breaks(self):
        """Known switching times inside (t_start, t_end) with their labels, merged when equal."""
        listed = [(float(tb), label, kind) for tb, label, kind in self.model.time_breaks(self.p)]
        inside = lambda items: [(tb, label) for tb, label in items
                                if np.isfinite(tb) and self.t_start < tb < self.t_end]
        csv = inside((tb, label) for tb, label, kind in listed if kind == "csv")
        other = [(tb, label) for tb, label, kind in listed if kind != "csv"]
        if len(csv) > 200:
            # a dense measured signal: no segment per sample, but no step longer than its typical spacing
            times = np.unique([tb for tb, _ in csv])
            spacing = float(np.median(np.diff(times))) if times.size > 1 else np.inf
            if spacing > 0 and spacing < self.options["max_step"]:
                self.options["max_step"] = spacing
            csv = []
        found = sorted(inside(other) + csv + self.time_switch_roots())
        merged = []
        tolerance = 4 * _EPS * max(abs(self.t_end), abs(self.t_start), 1.0)
        for tb, label in found:
            if merged and tb - merged[-1][0] <= tolerance:
                if label not in merged[-1][1]:
                    merged[-1][1].append(label)
            else:
                merged.append((tb, [label]))
        return [(tb, "; ".join(labels)) for tb, labels in merged]

    def time_switch_roots(self):
        """The zeros inside the run of the switches of time alone (``if sin(2*pi*f*t) > c``, ``pwm``,
        ``floor(t*f)``), found before integrating: such a switch can change twice within one solver
        step, so it is not left to event location. ``g`` is sampled on a grid refined until the
        number of sign changes (level crossings for ``floor``) stops changing, and every change
        is refined by ``brentq``. Those switches then end segments at known times.

        A switch of time may read the modes of other switches of time (``pwm(t, f, d)`` with a
        duty ``d`` that steps at 50 ms): its ``g`` is evaluated with those modes as they are at
        each time, piece by piece between their own changes (known breaks, or the roots found
        for them first), not with every mode +1."""
        model = self.model
        if not model.TIME_SWITCHES:
            return []
        n = len(model.STATE_NAMES)
        ones = np.ones(self.switch_count)
        vectorized = getattr(model, "VECTORIZED", True)
        if vectorized:
            switches, row_of, rows_count = model.switches, {k: k for k in model.TIME_SWITCHES}, self.switch_count
        elif getattr(model, "time_switches", None) is not None:
            # a model with an algebraic loop: its switches of time alone, without the loop
            switches, row_of = model.time_switches, {k: i for i, k in enumerate(model.TIME_SWITCHES)}
            rows_count = len(row_of)
        else:
            return []
        inner_of = self._inner_time_modes()
        known = {}
        for tb, label, kind in model.time_breaks(self.p):
            if kind != "csv" and np.isfinite(float(tb)):
                known.setdefault(label, []).append(float(tb))

        def changes(g, k):
            if model.floor_switches[k]:
                return np.flatnonzero(np.diff(np.floor(g)) != 0)
            signs = np.sign(g)
            zero = signs == 0
            if zero.any():
                # g exactly 0 at a sample (pwm's edge at t = 0.1 s on a grid through 0.1 s) takes the
                # sign after it: the change then falls in the interval ending there, and brentq
                # returns that sample (g(b) = 0); a product of signs through the zero saw none
                after = np.where(zero, signs.size, np.arange(signs.size))
                after = np.minimum.accumulate(after[::-1])[::-1]
                signs = np.where(after < signs.size, signs[np.minimum(after, signs.size - 1)], 0.0)
            return np.flatnonzero(signs[:-1] * signs[1:] < 0)

        roots, located, found = [], set(), {}
        for k in sorted(model.TIME_SWITCHES, key=lambda k: len(inner_of[k])):
            inner = inner_of[k]
            cuts, resolvable = [], True
            for j in inner:
                if j in found:
                    cuts += found[j]
                elif j in model.TIME_SWITCHES:
                    resolvable = False          # its own roots were not found: left to event location
                else:
                    cuts += known.get(model.SWITCHES[j], [])
            if not resolvable:
                continue
            cuts = np.unique([c for c in cuts if self.t_start < c < self.t_end])
            modes_of = self._piece_modes(inner, cuts, n, ones)
            if modes_of is None:
                continue                    # an inner switch without a value: left to event location

            def values(times, k=k, cuts=cuts, modes_of=modes_of):
                out = np.empty(times.size)
                piece = np.searchsorted(cuts, times, side="right")
                for index in np.unique(piece):
                    chosen = np.flatnonzero(piece == index)
                    for start in range(0, chosen.size, 65536):
                        columns = chosen[start:start + 65536]
                        with np.errstate(all="ignore"):
                            rows = np.broadcast_to(switches(times[columns], np.zeros((n, columns.size)), self.p,
                                                            modes_of[index]), (rows_count, columns.size))
                        out[columns] = rows[row_of[k]]
                return out

            count, previous, size, settled = None, None, 4096, False
            while size <= 2 ** 22:
                grid = np.linspace(self.t_start, self.t_end, size + 1)
                g = values(grid)
                if not np.all(np.isfinite(g)):
                    break
                count = changes(g, k).size
                if count == previous:
                    settled = True
                    break
                previous, size = count, 2 * size
            if not settled:
                continue            # not resolvable by sampling: left to event location
            label = model.SWITCHES[k]

            at = changes(g, k)
            lo, hi, g_lo, g_hi = grid[at], grid[at + 1], g[at], g[at + 1]
            levels = np.zeros(at.size)
            if model.floor_switches[k]:     # the level crossed: g - level changes sign there
                levels = np.where(g[at + 1] > g[at], np.floor(g[at + 1]), np.floor(g[at]))
            else:
                hidden = _hidden_changes(values, grid, g, lambda samples, k=k: changes(samples, k))
                if hidden[0].size:
                    order = np.argsort(np.concatenate((lo, hidden[0])), kind="stable")
                    lo, hi, g_lo, g_hi = (np.concatenate(pair)[order] for pair in zip((lo, hi, g_lo, g_hi), hidden))
                    levels = np.zeros(lo.size)
            found[k] = [float(root) for root in bracketed_roots(
                lambda times, rows, values=values, levels=levels: values(times) - levels[rows],
                lo, hi, g_lo - levels, g_hi - levels, 4 * _EPS, 4 * _EPS)]
            roots += [(root, label) for root in found[k]]
            located.add(k)
        if located:
            self.event_switches = np.array([k for k in self.event_switches if k not in located], dtype=int)
            self.stats["switches_found_ahead"] = len(located)
        return roots

    def _inner_time_modes(self) -> dict:
        """Switch of time -> the switches whose modes its ``g`` reads, directly or through them
        (SWITCH_DEPENDS; none where the module does not say)."""
        depends = self.model.SWITCH_DEPENDS
        inner = {}
        for k in self.model.TIME_SWITCHES:
            seen, stack_ = set(), list(depends[k]) if depends is not None else []
            while stack_:
                j = stack_.pop()
                if j not in seen and j != k:
                    seen.add(j)
                    stack_.extend(depends[j])
            inner[k] = sorted(seen)
        return inner

    def _piece_modes(self, inner, cuts, n, ones) -> list | None:
        """The mode vector on each piece between ``cuts``: +1 everywhere but for the ``inner``
        switches, whose modes are taken at the piece's middle (a fixed point, as nested switches
        read one another; every switching function at one point, the state's value irrelevant to
        these: a loop model's loop is solved there). None where one of them has no value."""
        edges = np.concatenate(([self.t_start], cuts, [self.t_end]))
        pieces = []
        for a, b in zip(edges[:-1], edges[1:]):
            modes = ones.copy()
            if inner:
                middle = 0.5 * (a + b)
                for _ in range(len(inner) + 1):
                    with np.errstate(all="ignore"):
                        g = np.ravel(self.model.switches(middle, np.zeros(n), self.p, modes))
                    if not np.all(np.isfinite(g[inner])):
                        return None
                    new = modes.copy()
                    new[inner] = mode_values(g[inner], self.model.floor_switches[inner])
                    if np.array_equal(new, modes):
                        break
                    modes = new
            pieces.append(modes)
        return pieces

    def restart_modes(self, t, y, guess):
        """Modes just after (t, y), and the switches that chatter there.

        The modes are probed a step ``h`` ahead along the law they select and
        re-chosen until they agree with it. When they cycle instead (each law
        pushes the state back across the surface of the other), the switches
        that flip within the cycle are returned: a sliding mode.
        """
        if self.switch_count == 0:
            return np.zeros(0), []
        if self.queue and guess is not None:
            piece = self.queue[0]       # a restart found with the pieces integrated ahead
            if (piece.t0 == t and piece.guess is not None
                    and piece.guess.tobytes() == np.asarray(guess, dtype=float).tobytes()
                    and piece.y0.tobytes() == np.asarray(y, dtype=float).tobytes()):
                return piece.modes.copy(), []
        driver = self.driver_for(np.zeros(0, dtype=int), np.zeros(0))
        if driver is not None:      # the same modes from C, where the restart is simple
            modes = driver.restart(t, y, np.ones(self.switch_count) if guess is None else guess, self.floors_c,
                                   self.probe, not getattr(self.model, "VECTORIZED", True))
            if modes is not None:
                self.stats["restarts_in_c"] = self.stats.get("restarts_in_c", 0) + 1
                return modes, []
        modes = self.modes_at(t, y, guess)
        seen = [tuple(modes)]
        for _ in range(8):
            with np.errstate(all="ignore"):
                slope = np.asarray(self.model.rhs(t, y, self.p, modes), dtype=float)
                ahead = self.modes_at(t + self.probe, y + self.probe * slope, modes)
            if np.array_equal(ahead, modes) or not np.all(np.isfinite(slope)):
                return modes, []
            if tuple(ahead) in seen:
                cycle = np.array(seen[seen.index(tuple(ahead)):])
                flipping = [k for k in range(self.switch_count) if np.any(cycle[:, k] != cycle[0, k])]
                return ahead, self.only_relevant(t, y, cycle, flipping)
            seen.append(tuple(ahead))
            modes = ahead
        flipping = [k for k in range(self.switch_count) if len({row[k] for row in seen}) > 1]
        return modes, self.only_relevant(t, y, np.array(seen), flipping)

    def only_relevant(self, t, y, rows, switches):
        """The switches among ``switches`` that matter for the law of any of the mode vectors ``rows``."""
        relevant = np.zeros(self.switch_count, dtype=bool)
        for row in rows:
            relevant |= self.relevant(t, y, np.asarray(row, dtype=float))
        return [k for k in switches if relevant[k]]

    def mode_label(self, k, mode) -> str:
        """What an event says of switch ``k`` entering ``mode``: an ``if``'s condition becoming true
        or false (``if h < 0.4 in pump.f -> false``), else the mode (``sign(v) in friction.e -> -1``)."""
        truth = self.model.SWITCH_TRUTH[k]
        if truth in (3, -3):            # == and !=: the condition holds at g = 0 and off it
            holds = (mode == 0) == (truth == 3)
        elif truth:                     # > >= < <=: on the side of its sign, and at g = 0 where not strict
            holds = mode * truth > 0 if mode != 0 else abs(truth) == 2
        else:
            return f"{self.model.SWITCHES[k]} -> {int(mode):+d}"
        return f"{self.model.SWITCHES[k]} -> {'true' if holds else 'false'}"

    def note_event(self, t, label):
        self.events.append((float(t), label))

    def note_break(self, t_break, label, changed=()):
        """Note a known switching time, but of its labels only those not noted otherwise: neither
        switches that changed there (``changed``, noted with their modes) nor switches of when
        conditions."""
        quiet = {self.model.SWITCHES[k] for k in (*changed, *self.condition_switches)}
        rest = [part for part in label.split("; ") if part not in quiet]
        if rest:
            self.note_event(t_break, "; ".join(rest))

    def run(self):
        model = self.model
        started = _time_module.perf_counter()
        t, y = self.t_start, np.asarray(model.x0(self.p), dtype=float).reshape(-1)
        complete, failure = True, None
        breaks = self.breaks()
        self.break_times = np.array([tb for tb, _ in breaks], dtype=float)
        break_index = 0
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
                raise _Stop(self.diagnose(t, y, modes, "the initial state is not finite: "))
            with np.errstate(all="ignore"):
                if not np.all(np.isfinite(self.rhs(t, y, modes))):
                    raise _Stop(self.diagnose(t, y, modes, "at the start, "))
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
                            raise _Stop({"message": f"the simulation stalled at t={t:.6g}: {_STALL_RESTARTS} "
                                                    f"restarts advanced time by less than {stall_span:.3g} s",
                                         "time": float(t), "variable": None, "law": None, "kind": "events",
                                         "cause": "several switches (sign, abs, if) keep changing mode together, "
                                                  "e.g. friction laws that make the motion stick",
                                         "hint": "smooth the laws near their switching surfaces (a small "
                                                 "linear band around zero velocity, for instance)"})
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
                        raise _Stop({"message": f"more than {self.max_events} events by t={t:.6g}",
                                     "time": float(t), "variable": None, "law": None, "kind": "events",
                                     "cause": "a switch keeps changing mode (chattering) faster than the "
                                              "chattering guard can absorb",
                                     "hint": "smooth the law near its switching surface (a small linear band "
                                             "around zero velocity, for instance) or raise max_events"})
        except _Stop as stop:
            complete, failure = False, stop.failure
        except KeyboardInterrupt as interrupt:
            complete = False
            # where the run got to: its last recorded point (t is where the current segment began)
            self._consistent_blocks()
            t = max([float(t)] + [float(block[-1]) for block in self.blocks_t[-1:] if block.size])
            failure = {"message": f"interrupted at t={t:.6g}", "time": float(t), "variable": None,
                       "law": None, "cause": "interrupted by the user", "hint": "", "kind": "interrupted",
                       "terminated": type(interrupt).__name__ == "Terminated"}     # SIGTERM (bondc.cli)
        self.stats["wall_time"] = _time_module.perf_counter() - started
        return self.result(complete, failure)

    def fire_when_clauses(self, t, y, before_modes, modes, chattering):
        """Run the ``when`` clauses whose condition became true at this restart (false with the modes
        before it, true with those just after), in the order written, every right-hand side with the
        values just before; then evaluate the conditions again, up to ``_EVENT_ROUNDS`` times."""
        model = self.model
        before = model.when_conditions(t, y, self.p, before_modes)
        after = model.when_conditions(t, y, self.p, modes)
        for _ in range(_EVENT_ROUNDS):
            firing = [k for k in range(len(after)) if after[k] and not before[k]]
            if not firing:
                return y, modes, chattering
            new = np.array(y, dtype=float)
            for k in firing:
                values = model.WHEN_ACTIONS[k](t, y, self.p, modes)
                for index, value in zip(model.WHEN_TARGETS[k], values):
                    new[index] = float(value)
                self.note_event(t, model.WHEN_LABELS[k])
                self.stats["when_fired"] = self.stats.get("when_fired", 0) + 1
                self.check_zeno(k, t)
            if not np.all(np.isfinite(new)):
                raise _Stop(self.diagnose(t, new, modes, f"after {model.WHEN_LABELS[firing[0]]} at t={t:.6g}, "))
            self.jumps.append((float(t), np.array(y, dtype=float), new.copy()))
            y = new
            modes, chattering = self.restart_modes(t, y, modes)
            before, after = after, model.when_conditions(t, y, self.p, modes)
        labels = "; ".join(model.WHEN_LABELS[k] for k in range(len(after)) if after[k] and not before[k])
        raise _Stop({"message": f"when clauses kept firing at t={t:.6g}: after {_EVENT_ROUNDS} rounds at the same "
                                f"instant, {labels} became true again",
                     "time": float(t), "variable": None, "law": None, "kind": "events",
                     "cause": "the statements of a when clause make another (or its own) condition true again",
                     "hint": "make the conditions exclusive (a hysteresis band), or the statements move the state "
                             "out of the condition"})

    def check_zeno(self, k, t):
        """Stop the run where the firings of when clause ``k`` accumulate (Zeno behaviour, a bouncing
        ball coming to rest): the model says nothing about what follows the accumulation point, and
        past it the events can no longer be told apart at the solver's precision (the ball would fall
        through the floor). Detected when the clause fired ``_ZENO_FIRINGS`` times, each interval at
        most ``_ZENO_RATIO`` times the one before (geometric: the cycles of a frequency sweep shorten
        far more slowly), the last shorter than ``_ZENO_INTERVAL`` of the run, with the geometric
        limit of the intervals before the end of the run."""
        times = self.when_times.setdefault(k, [])
        times.append(float(t))
        del times[:-_ZENO_FIRINGS]
        if len(times) < _ZENO_FIRINGS:
            return
        gaps = np.diff(times)
        if not (np.all(gaps > 0) and np.all(gaps[1:] <= _ZENO_RATIO * gaps[:-1])) \
                or gaps[-1] > _ZENO_INTERVAL * self.span:
            return
        ratio = (gaps[-1] / gaps[0]) ** (1.0 / (len(gaps) - 1))
        limit = t + gaps[-1] * ratio / (1.0 - ratio)
        if limit >= self.t_end:
            return
        label = self.model.WHEN_LABELS[k]
        raise _Stop({"message": f"the events of '{label}' accumulate at t={limit:.6g} (Zeno behaviour): "
                                f"{len(times)} firings, each interval about {ratio:.3g} times the one before, "
                                f"the last {gaps[-1]:.3g} s",
                     "time": float(t), "variable": None, "law": None, "kind": "events", "when": label,
                     "cause": "infinitely many events before a finite time, as a bouncing ball coming to rest; "
                              "the model does not say what happens after that time",
                     "hint": "give the model a law for what follows: e.g. a discrete variable that a when clause "
                             "sets when the rebound is too small to matter, and that switches the motion off"})

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
            raise _Stop({**stalled.failure,
                         "message": f"the simulation stalled at t={t:.6g}: the law of {named} is continuous "
                                    f"there but infinitely steep (a square root at 0), and the solver makes "
                                    f"no headway through it",
                         "variable": self.model.SWITCH_OWNERS[steep[0]],
                         "cause": "a law like sign(dp)*sqrt(abs(dp)) has an infinite slope at dp = 0: near it "
                                  "the time constant of what it feeds goes to zero",
                         "hint": "give the law a laminar band around 0, as real orifices have: "
                                 "if abs(dp) < dp_l then K*dp/sqrt(dp_l) else K*sign(dp)*sqrt(abs(dp)) "
                                 "(std:hydraulics's LaminarTurbulentOrifice)"})
        if near and len(near) <= _MAX_HELD:
            held, modes, alpha = self.consistent_sliding_set(t, y, modes, near)
            if held:
                t_new, y_new = self.sliding_segment(t, y, modes, held, alpha, t_stop)
                return t_new, y_new, held
        if len(near) > _MAX_HELD:
            raise _Stop({**stalled.failure, **self.too_many_held(t, near, f"more than {_MAX_HELD}")})
        raise _Stop(stalled.failure)

    def too_many_held(self, t, near, why):
        """The failure of a run whose switches on their surfaces at (t, y) cannot be held together."""
        named = "; ".join(self.model.SWITCHES[k] for k in near[:4]) + ("; ..." if len(near) > 4 else "")
        return {"message": f"the simulation stalled at t={t:.6g}: {len(near)} switches are on their surfaces at "
                           f"once ({named}), and {why}",
                "time": float(t), "kind": "events", "law": None, "variable": self.model.SWITCH_OWNERS[near[0]],
                "cause": f"holding {len(near)} switches at once (dry frictions that stick together) combines "
                         f"2^{len(near)} laws; beyond {_MAX_SLIDING}, bondc holds them only where each one's law "
                         "enters the motion linearly (a friction force added to sums of forces), at most "
                         f"{_MAX_HELD} at a time",
                "hint": "give some of these laws a narrow linear band around zero velocity (for a friction, "
                        "e = if abs(f) < v_band then F_s*f/v_band else coulomb(f, F_c, F_s)), or join parts "
                        "that always move together into one mass"}

    def note_passing(self, t, modes, held):
        """Note the switches that were candidates for sliding at the restart at ``t`` and are not
        held, where their mode changed there: a friction whose velocity passes through 0 (the force
        to hold it beyond its static limit) is an event like any switch's crossing. Only the event
        list and its count: the run goes on as it would."""
        if self.passing is None or self.passing[0] != t:
            return
        _, before, switches, counted, noting = self.passing
        self.passing = None
        flipped = [k for k in switches if k not in held and modes[k] != before[k]]
        if not flipped or not noting:
            return
        for k in flipped:
            self.note_event(t, self.mode_label(k, modes[k]))
        if not counted:
            self.stats["mode_changes"] += 1

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
        deadbands) and where every weight of the sliding combination is still inside (0, 1)."""
        index = np.array([k for k in held if not self.model.floor_switches[k]], dtype=int)
        if index.size == 0 or len(index) != len(held):
            return y
        g = self.switches_at(t, y, modes, index)
        band = self.deadbands(t, y, modes, index)
        if not np.all(np.isfinite(g)) or np.all(np.abs(g) <= band) or np.any(np.abs(g) > 1e6 * band):
            return y
        corners, sides = self.sliding_corners(modes, held)
        _, rates = self.sliding_rates(t, y, corners, held)
        weights_now = self.solve_alpha(rates, sides, alpha)
        if not np.all(np.isfinite(weights_now)) or np.any(np.minimum(weights_now, 1.0 - weights_now) <= 1e-6):
            return y            # at a break-away: the switch leaves its surface here
        scale = self.options["atol"] + self.options["rtol"] * np.abs(y)
        jacobian = self.switch_differences(t, y, modes, index) / scale
        weights = scale ** 2
        try:
            multipliers = np.linalg.solve((jacobian * weights) @ jacobian.T, -g)
        except np.linalg.LinAlgError:
            return y
        corrected = y + weights * (jacobian.T @ multipliers)
        return corrected if np.all(np.isfinite(corrected)) else y

    def sliding_candidates(self, t, y, modes, chattering):
        """Switches that may slide at (t, y): those that chatter, and those on their surface that
        either slid until now or are ``coulomb`` frictions (whose static limit can hold them even
        where each side's sliding law alone would move away)."""
        floors = self.model.floor_switches
        candidates = {k for k in chattering if not floors[k]}       # an integer mode cannot slide
        vertices = self.model.SWITCH_VERTICES
        keep = [k for k in self.event_switches
                if k not in candidates and (vertices[k] != 1.0 or k in self.sliding_now)]
        if keep:
            relevant = self.relevant(t, y, modes)
            index = np.array([k for k in keep if relevant[k]], dtype=int)
            if index.size:
                # on the surface: |g| within its deadband (the integration noise of the state)
                on_surface = np.abs(self.switches_at(t, y, modes, index)) <= self.deadbands(t, y, modes, index)
                candidates.update(int(k) for k in index[on_surface])
        return sorted(k for k in candidates if not self.continuous_across(t, y, modes, k))

    def keeps_to(self, t, y, modes, k) -> bool:
        """Whether the motion keeps to switch ``k``'s surface near (t, y): on the surface (where a
        continuous law's two sides agree), g moves by less than its deadband over a thousandth of
        the run."""
        near = self.near_surface(t, y, modes, k)
        if near is None:
            return False
        on, band, plus, minus, _ = near
        with np.errstate(all="ignore"):
            at = on(0.0)
            rate = float(self.switch_rate(t, at, self.rhs(t, at, plus), plus, k))
        return bool(np.isfinite(rate) and abs(rate) * 1e-3 * self.span <= band)

    def continuous_across(self, t, y, modes, k) -> bool:
        """Whether the law is continuous across switch ``k``'s surface near (t, y), as a turbulent
        orifice's sign(dp)*sqrt(abs(dp)) is at dp = 0: such a switch is crossed, never held, whatever
        its frozen laws extended past the surface say (each side's law there gives the flow of the
        other direction, and from a state a little off the surface the two seemed to push towards
        it: a false sliding mode held the pressure drop away from 0 at a flow near none).

        The jump between the two sides' right-hand sides (each state by its error tolerance), on
        the side g > 0 at the distance of the switch's deadband (the integration noise of g) and at
        100 times it: a discontinuity (a friction's) keeps its size as the surface nears, a
        continuous law's jump vanishes there (as the square root of the distance for the orifice,
        linearly for a kink). A switch whose modes give one right-hand side is left as it was."""
        near = self.near_surface(t, y, modes, k)
        if near is None:
            return False
        on, band, plus, minus, scale = near
        with np.errstate(all="ignore"):
            def jump(level):
                at = on(level)
                return float(np.max(np.abs(self.rhs(t, at, plus) - self.rhs(t, at, minus)) / scale))

            near_jump, far_jump = jump(band), jump(100.0 * band)
        return bool(np.isfinite(near_jump) and np.isfinite(far_jump) and far_jump > 0
                    and near_jump <= 0.3 * far_jump)

    def near_surface(self, t, y, modes, k):
        """For a sign switch ``k`` whose g moves with the state: (the state moved along g's gradient
        to where g has a given value, g's deadband there, the modes with k on its plus side, on its
        minus side, each state's error tolerance), or None."""
        vertex = self.vertex_override.get(k, self.model.SWITCH_VERTICES[k])
        if vertex != 1.0 or self.model.floor_switches[k]:
            return None
        index = np.array([k])
        scale = self.options["atol"] + self.options["rtol"] * np.abs(y)
        with np.errstate(all="ignore"):
            gradient = self.switch_differences(t, y, modes, index)[0] / scale
            norm = float(gradient @ gradient)
            g0 = float(self.switches_at(t, y, modes, index)[0])
            band = float(self.deadbands(t, y, modes, index)[0])
        if not (np.isfinite(norm) and norm > 0 and np.isfinite(g0) and np.isfinite(band) and band > 0):
            return None
        plus, minus = np.array(modes, dtype=float), np.array(modes, dtype=float)
        plus[k], minus[k] = 1.0, -1.0
        return (lambda level: y + (level - g0) * gradient / norm), band, plus, minus, scale

    def too_many_events(self, t):
        window = self.span / 1000.0
        self.recent_events = [te for te in self.recent_events if te > t - window]
        return len(self.recent_events) > self.max_event_rate

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

    def driver_for(self, index, signs):
        """The native driver for a segment watching ``index`` in modes ``signs``, or None.

        It serves CVODE and DOPRI5 runs of models whose C code carries the driver (DOPRI5 where
        bondc's explicit stepper is built, :func:`load_erk`), when every watched switch is a sign
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
            else:
                return None
            if driver is None:
                return None
            self._driver = driver
        if index.size and self.model.floor_switches[index].any():
            return None
        return self._driver

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

        >>> run = _Run.__new__(_Run)
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
                    raise _Stop(self.diverged(t_prev, y_prev))
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
                raise _Stop(self.diverged(t_new, y_new))
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
        failure = self.diagnose(hi, y_hi, modes_of(hi, y_hi), "")
        if failure["variable"] in self.model.STATE_NAMES and self.bad is not None:
            # the solver's own state went bad: name the law that produced the nan it saw
            cause = self.diagnose(*self.bad, context="")
            cause["message"] = (f"the solver's state became non-finite at t={hi:.6g} after the right-hand side "
                                f"was evaluated at a trial point where {cause['message']}")
            cause["time"] = float(hi)
            failure = cause
        raise _Stop(failure)

    def relevant(self, t, y, modes):
        """Which switches matter for the law selected by ``modes``: those whose modes the right-hand
        side reads (only the active branch of an if reads its modes), and, through SWITCH_DEPENDS,
        the modes their switching functions read. A crossing of any other switch changes nothing the
        solver sees, so it is not located (outputs still get the right mode at every point)."""
        relevant = np.ones(self.switch_count, dtype=bool)
        depends = self.model.SWITCH_DEPENDS
        if depends is None or self.switch_count == 0:
            return relevant
        # which branches are active, so which modes are read, depends on the modes alone (every
        # condition of a law is a switch): once per mode vector and model
        key = tuple(modes)
        known = self.relevant_by_modes.get(key)
        if known is not None:
            return known.copy()
        reader = _ModeReader(modes)
        global _READING_MODES
        _READING_MODES = True
        try:
            with np.errstate(all="ignore"):
                self.model.rhs(t, y, self.p, reader)
        except Exception:       # a law that needs a real array of modes: keep every switch
            return relevant
        finally:
            _READING_MODES = False
        # a when clause's condition is always watched
        needed, stack_ = set(), list(reader.read) + list(self.model.WHEN_SWITCHES)
        while stack_:
            k = stack_.pop()
            if k not in needed:
                needed.add(k)
                stack_.extend(depends[k])
        relevant[:] = False
        relevant[sorted(needed)] = True
        self.relevant_by_modes[key] = relevant.copy()
        return relevant

    def switches_at(self, t, y, modes, index):
        with np.errstate(all="ignore"):
            return np.asarray(self.model.switches(t, y, self.p, modes), dtype=float)[index]

    def deadbands(self, t, y, modes, index):
        """How far each switching function moves when the state moves by its error tolerance
        (``atol + rtol*|x|``, state by state): crossings shallower than that are integration noise
        (a chamber pressure sitting at its regulator's set point) and are not events."""
        if index.size == 0:
            return np.zeros(0)
        driver = self._driver
        if driver and np.ndim(self.options["atol"]) == 0 and np.ndim(self.options["rtol"]) == 0:
            total = driver.deadbands(t, y, modes, index, self.options["rtol"], self.options["atol"])
            if total is not None:
                return total
        differences = self.switch_differences(t, y, modes, index)
        total = np.zeros(index.size)
        for j in range(y.size):
            total += np.abs(differences[:, j])
        total[~np.isfinite(total)] = 0.0
        return total

    def switch_differences(self, t, y, modes, index):
        """How each switching function of ``index`` changes when state j alone moves by its error
        tolerance ``atol + rtol*|x_j|``: a matrix (switches, states)."""
        scale = self.options["atol"] + self.options["rtol"] * np.abs(y)
        base = self.switches_at(t, y, modes, index)
        differences = np.empty((index.size, y.size))
        for j in range(y.size):
            shifted = np.array(y, dtype=float)
            shifted[j] += scale[j]
            differences[:, j] = self.switches_at(t, shifted, modes, index) - base
        return differences

    def crossing_inside(self, solver, modes, index, signs, before, after, deadband, fused):
        """A switch that crosses and comes back inside the last step, on its side at both ends
        (``before``, ``after``: ``m*g + deadband``), as (time, switch index), or None: the sign test
        at the step's ends sees nothing where a hump of a state passes a threshold and returns
        within one step. Its values at the step's middle, and where their parabola comes within its
        curvature of the band, the halves in turn (:meth:`sliding_dip`), as for a sliding mode's
        exits."""
        t_old, t_new = solver.t_old, solver.t
        if not t_old < t_new:
            return None
        if fused is not None:
            frozen = np.ascontiguousarray(modes, dtype=float)
            values = lambda tt: signs * np.array([fused(frozen, tt, k) for k in index]) + deadband
        else:
            dense = solver.dense_output()
            values = lambda tt: signs * self.model.switches(tt, dense(tt), self.p, modes)[index] + deadband
        with np.errstate(all="ignore"):
            hit = self.sliding_dip(np.asarray(before, dtype=float), np.asarray(after, dtype=float), values,
                                   t_old, t_new)
        if hit is None:
            return None
        self._dense = None if fused is not None else dense
        j = int(np.argmin(values(hit)))
        # as a crossing at a step's end: the zero itself (no bias by the band) where it lies before
        surface = lambda tt: values(tt)[j] - deadband[j]
        if deadband[j] > 0 and t_old < hit and surface(t_old) > 0 >= surface(hit):
            with np.errstate(all="ignore"):
                try:
                    hit = brentq(surface, t_old, hit, 4 * _EPS, 4 * _EPS)
                except ValueError:
                    pass
        return hit, int(index[j])

    def crossing(self, solver, modes, index, signs, old, new, deadband):
        """The earliest switch crossing in the last step: (time, switch index), or None.

        A switch in mode +-1 crosses when ``m*g`` falls below ``-deadband`` (located where it does:
        at most a tolerance-sized shift of the event); a switch in mode 0 when ``|g|`` exceeds it.
        """
        t_old, t_new = solver.t_old, solver.t
        found = []
        floors = self.model.floor_switches
        fused = getattr(solver, "switch_value", None)
        if fused is not None:       # the driver's step: g_k at tt in one call
            g = functools.partial(fused, np.ascontiguousarray(modes, dtype=float))
        else:
            g = lambda tt, k: self.model.switches(tt, self._dense(tt), self.p, modes)[k]
        if not floors[index].any() and signs.all():
            # the common step: no switch in mode +-1 went below its band (the loop's first test, at once)
            before, after = signs * old + deadband, signs * new + deadband
            if not ((after < 0) | ((after == 0) & (before > 0))).any():
                # an algebraic loop's switches, evaluated between the steps, would move the warm starts
                # of its Newton iteration (its last solutions) that the run's next points start from
                kept = dict(_BLOCK_SOLUTIONS)
                try:
                    return self.crossing_inside(solver, modes, index, signs, before, after, deadband, fused)
                finally:
                    _BLOCK_SOLUTIONS.clear()
                    _BLOCK_SOLUTIONS.update(kept)
        for j, k in enumerate(index):
            sign, band = signs[j], deadband[j]
            if floors[k]:
                # m = floor(g) holds while g stays in [m, m + 1): the distance to the nearer end
                level = sign
                inside = lambda g, lv=level: min(g - lv, lv + 1.0 - g)
                before, after = inside(old[j]) + band, inside(new[j]) + band
                if not after < 0:
                    continue
                if before <= 0:
                    found.append((t_old, k))
                    continue
                if self._dense is None:
                    self._dense = solver.dense_output()
                function = lambda tt, k=k, f=inside: f(self.model.switches(tt, self._dense(tt), self.p, modes)[k])
                with np.errstate(all="ignore"):
                    try:
                        root = brentq(function, t_old, t_new, 4 * _EPS, 4 * _EPS)
                    except ValueError:
                        root = t_new
                found.append((root, k))
                continue
            if sign != 0:
                before, after = sign * old[j] + band, sign * new[j] + band
                if not (after < 0 or (after == 0 and before > 0)):
                    continue
                if before <= 0:
                    found.append((t_old, k))
                    continue
                if after == 0:
                    found.append((t_new, k))
                    continue
                # the deadband only decides *whether* it crossed; when the zero itself lies in this
                # step, locate the zero (no bias), else where it left the band
                band = 0.0 if sign * old[j] > 0 else band
                function = lambda tt, k=k, s=sign, b=band: s * g(tt, k) + b
            else:
                if not (np.isfinite(new[j]) and abs(new[j]) > band and new[j] != 0):
                    continue
                level = band if band > 0 else 1e-6 * abs(new[j])   # leaving the surface
                function = lambda tt, k=k, lv=level: lv - abs(g(tt, k))
            if self._dense is None:
                self._dense = solver.dense_output()
            with np.errstate(all="ignore"):
                try:
                    root = brentq(function, t_old, t_new, 4 * _EPS, 4 * _EPS)
                except ValueError:      # no sign change on the interpolant: take the step end
                    root = t_new
            found.append((root, k))
        if not found:
            return None
        return min(found)

    def collect(self, solver):
        self.stats["njev"] += int(getattr(solver, "njev", 0) or 0)
        self.stats["nlu"] += int(getattr(solver, "nlu", 0) or 0)
        if getattr(solver, "linear_solver", None):
            self.stats["linear_solver"] = solver.linear_solver
        solver = getattr(solver, "finite_jacobian", solver)     # (scipy's: counted by its Jacobian)
        fallbacks = int(getattr(solver, "jacobian_fallbacks", 0) or 0)
        if fallbacks:
            if not self.stats.get("jacobian_fallbacks"):
                self.note_event(solver.first_fallback, "the analytic Jacobian is not finite here (a law with an infinite "
                                          "slope, like sqrt at 0): finite differences replace it where needed")
            self.stats["jacobian_fallbacks"] = self.stats.get("jacobian_fallbacks", 0) + fallbacks

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
        :meth:`affine_holds` found that the laws combine so (the first corner, all minus, is the
        same in both).
        """
        vertices = self.model.SWITCH_VERTICES
        vertices = [self.vertex_override.get(k, vertices[k]) for k in range(len(vertices))]
        count = len(sliding)
        base = np.array(modes, dtype=float)
        for k in sliding:
            base[k] = -vertices[k]
        if affine is None:
            affine = (base.tobytes(), tuple(sliding)) in self.affine_sets
        if affine:
            sides = np.vstack([-np.ones((1, count)), 2.0 * np.eye(count) - 1.0])
        else:
            sides = np.array([[1.0 if (c >> i) & 1 else -1.0 for i in range(count)] for c in range(2 ** count)])
        corners = np.repeat(np.asarray(modes, dtype=float)[None, :], len(sides), axis=0)
        for i, k in enumerate(sliding):
            corners[:, k] = sides[:, i] * vertices[k]
        return corners, sides

    def held_corners(self, t, y, modes, sliding):
        """The corners of the sliding set at (t, y) (:meth:`sliding_corners`), the right-hand side
        and the sliding switches' rates at each: the affine combination for three switches or more
        where the laws combine linearly (k + 1 corners instead of 2**k), else the multilinear one,
        which holds at most ``_MAX_SLIDING`` switches."""
        if len(sliding) > 2:
            corners, sides = self.sliding_corners(modes, sliding, affine=True)
            values, rates = self.sliding_rates(t, y, corners, sliding)
            if self.affine_holds(t, y, corners, sides, values, sliding):
                return corners, sides, values, rates
            if len(sliding) > _MAX_SLIDING:
                raise _Stop(self.too_many_held(t, sliding, "their laws do not combine linearly"))
        corners, sides = self.sliding_corners(modes, sliding, affine=False)
        values, rates = self.sliding_rates(t, y, corners, sliding)
        return corners, sides, values, rates

    corner_weights = staticmethod(corner_weights)

    def affine_holds(self, t, y, corners, sides, values, sliding):
        """Whether the right-hand side at (t, y) is affine in the sliding switches' weights, as the
        affine combination of :meth:`sliding_corners` takes it: the corners with every pair of
        switches (at most 512 pairs, spread over all) and with every switch on its plus side give
        what the k + 1 corners predict, to rounding. A friction force that only enters sums of
        forces is affine; one that feeds a nonlinear law (a normal force, a product) is not. Once
        a set of switches and the others' modes passed, only the all-plus corner is tested again.
        Records the set in ``affine_sets`` (for :meth:`sliding_corners`) when it holds."""
        count = sides.shape[1]
        checked = self.affine_checked
        base, delta = values[0], values[1:] - values[0]
        key = (corners[0].tobytes(), tuple(sliding))
        tests = [list(range(count))]
        self.affine_sets.discard(key)
        if key not in checked:
            pairs = [(i, j) for i in range(count) for j in range(i + 1, count)]
            if len(pairs) > 512:
                pairs = pairs[:: -(-len(pairs) // 512)]
            tests = [list(pair) for pair in pairs] + tests
        scale = np.max(np.abs(values), axis=0) + np.max(np.abs(delta), axis=0) * count
        for plus in tests:
            corner = corners[0].copy()
            corner[[sliding[i] for i in plus]] = corners[[i + 1 for i in plus], [sliding[i] for i in plus]]
            predicted = base + delta[plus].sum(axis=0)
            actual = self.rhs(t, y, corner)
            if not np.all(np.abs(actual - predicted) <= 1e-9 * scale + 1e-300):
                checked.discard(key)
                return False
        checked.add(key)
        self.affine_sets.add(key)
        return True

    def sliding_rates(self, t, y, corners, sliding):
        """Right-hand side at each corner and the rate of each sliding switch's g along it."""
        values = np.array([self.rhs(t, y, corner) for corner in corners])
        index = np.asarray(sliding, dtype=int)
        rates = np.array([self.switch_rate(t, y, values[c], corners[c], index) for c in range(len(corners))])
        return values, rates

    solve_alpha = staticmethod(filippov_alpha)

    def sliding_set(self, t, y, modes, candidates):
        """Which of ``candidates`` slide at (t, y) (complementarity by active set) and the modes of
        the others: a switch whose weight leaves [0, 1] cannot be held and takes that side.

        Returns (sliding switches, modes, alpha).
        """
        modes = np.array(modes, dtype=float)
        sliding = list(candidates)
        tolerance = 1e-9
        self.vertex_override = {}
        while sliding:
            corners, sides, values, rates = self.held_corners(t, y, modes, sliding)
            if len(sliding) > 1:
                # a switch whose sides give the same right-hand side (a free clutch: both its limits
                # 0) holds nothing; among others it would only bend their weights' least squares
                affine = sides.shape[0] != 2 ** sides.shape[1]
                free = [i for i in range(len(sliding))
                        if (np.array_equal(values[1 + i], values[0]) if affine else
                            all(np.array_equal(values[c], values[c | (1 << i)])
                                for c in range(len(values)) if not (c >> i) & 1))]
                if free:
                    k = sliding[free[0]]
                    g = self.model.switches(t, y, self.p, modes)[k]
                    modes[k] = 1.0 if g >= 0 else -1.0
                    del sliding[free[0]]
                    continue
            alpha = self.solve_alpha(rates, sides)
            if not np.all(np.isfinite(alpha)):
                return [], modes, None
            if np.any(np.minimum(alpha, 1.0 - alpha) < 1e-6):
                # at the edge (a holding force at its limit, as at the instant a sliding segment ended):
                # decide by where the weights go just after t
                h = self.probe
                slope = self.corner_weights(np.clip(alpha, 0.0, 1.0), sides) @ values
                _, rates_ahead = self.sliding_rates(t + h, y + h * slope, corners, sliding)
                ahead = self.solve_alpha(rates_ahead, sides, alpha)
                if np.all(np.isfinite(ahead)):
                    alpha = np.where(np.minimum(alpha, 1.0 - alpha) < 1e-6, ahead, alpha)
            residual = self.corner_weights(np.clip(alpha, 0.0, 1.0), sides) @ rates
            scale = np.max(np.abs(rates), axis=0)
            # a rate that would move g by less than its deadband over a millionth of the run is nil
            # (a surface whose own rate is a state held at zero by the others: second-order sliding)
            nil = self.deadbands(t, y, modes, np.asarray(sliding, dtype=int)) / (1e-6 * self.span)
            unheld = np.flatnonzero(np.abs(residual) > np.maximum(1e-8 * scale, np.maximum(nil, 1e-300)))
            if unheld.size:
                # no weight stops it (its own law does not act on it: a free clutch): it moves on
                worst = int(unheld[np.argmax(np.abs(residual[unheld]) / scale[unheld])])
                if self.relax_static_limit(sliding[worst]):
                    continue
                modes[sliding[worst]] = 1.0 if residual[worst] > 0 else -1.0
                del sliding[worst]
                continue
            violation = np.maximum(alpha - 1.0, -alpha)
            worst = int(np.argmax(violation))
            if violation[worst] <= tolerance:
                return sliding, modes, np.clip(alpha, 0.0, 1.0)
            # the force needed to hold it exceeds its limit: it leaves towards that side
            if self.relax_static_limit(sliding[worst]):
                continue
            modes[sliding[worst]] = 1.0 if alpha[worst] > 1.0 else -1.0
            del sliding[worst]
        return [], modes, None

    def relax_static_limit(self, k):
        """A ``coulomb`` friction that its static limit cannot hold may still be held between its
        sliding forces (a static limit below the sliding force: each side's sliding law pushes
        back across v = 0, which is a Filippov sliding mode): try those as the corners."""
        if self.model.SWITCH_VERTICES[k] != 1.0 and self.vertex_override.get(k) is None:
            self.vertex_override[k] = 1.0
            return True
        return False

    def consistent_sliding_set(self, t, y, modes, candidates):
        """:meth:`sliding_set`, with the modes of the other switches chosen just after (t, y) along the
        sliding motion itself (not along either side's law): a switch that flips there takes its new
        mode; one that flips back and forth joins the sliding set. A candidate that is not held
        keeps the side :meth:`sliding_set` found for it (it leaves its surface on that side, even
        from a state a rounding error on the other)."""
        candidates, flipped = list(candidates), set()
        for _ in range(2 * _MAX_SLIDING):
            held, modes, alpha = self.sliding_set(t, y, modes, candidates)
            if not held:
                return held, modes, alpha
            corners, sides = self.sliding_corners(modes, held)
            values, _ = self.sliding_rates(t, y, corners, held)
            slope = self.corner_weights(alpha, sides) @ values
            ahead = self.modes_at(t + self.probe, y + self.probe * slope, modes)
            relevant = self.relevant(t, y, modes)
            changed = [j for j in self.event_switches
                       if j not in candidates and relevant[j] and ahead[j] != modes[j]]
            if not changed:
                return held, modes, alpha
            for j in changed:
                if j in flipped and len(candidates) < _MAX_HELD:
                    candidates.append(j)
                else:
                    modes[j] = ahead[j]
                    flipped.add(j)
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
        """:meth:`sliding_end` of a step, its exits also tested inside it every
        :meth:`sliding_check`: a mode whose states stand still (a mass held at rest or at a speed)
        gives the solver nothing to limit its steps by, while the force that holds it follows an input
        that may pass the holding limit and come back within one step. Between two tests, an exit
        that dips below 0 and comes back is looked for too (:meth:`sliding_dip`): a step whose
        states move is as long as their motion allows, which may be longer than the push is past
        the limit."""
        longest = self.sliding_check()
        count = int(min(math.ceil((t_new - t_old) / longest), 1e6)) if longest > 0 else 1
        times = np.linspace(t_old, t_new, max(count, 1) + 1)
        before = old
        for a, b in zip(times[:-1], times[1:]):
            after = new if b == t_new else np.asarray(exits_at(b), dtype=float)
            hit = self.sliding_end(before, after, exits_at, a, b)
            if hit is None:
                hit = self.sliding_dip(before, after, exits_at, a, b)
            if hit is not None:
                return hit
            before = after
        return None

    def sliding_dip(self, left, right, exits_at, a, b, budget=None):
        """The end of a sliding mode inside (a, b) where its exits are positive at both ends, or None:
        an exit that dips below 0 and comes back between them (a push passing a static limit for less
        than the spacing of the tests). Each exit's parabola through a, the middle and b is looked at
        (:func:`_may_dip`): where it comes within its own curvature of 0 inside, the halves are
        searched in turn, at most 60 evaluations in all."""
        budget = [60] if budget is None else budget
        middle_t = 0.5 * (a + b)
        if budget[0] <= 0 or not a < middle_t < b:
            return None
        budget[0] -= 1
        middle = np.asarray(exits_at(middle_t), dtype=float)
        hit = self.sliding_end(left, middle, exits_at, a, middle_t)
        if hit is not None:
            return hit
        hit = self.sliding_end(middle, right, exits_at, middle_t, b)
        if hit is not None:
            return hit
        if not _may_dip(left, middle, right):
            return None
        hit = self.sliding_dip(left, middle, exits_at, a, middle_t, budget)
        if hit is not None:
            return hit
        return self.sliding_dip(middle, right, exits_at, middle_t, b, budget)

    def sliding_check(self) -> float:
        """The longest stretch of a sliding mode whose exits are tested only at its ends: the run's
        span over SLIDING_CHECKS, or its max_step where that is shorter."""
        return min(self.span / SLIDING_CHECKS, float(self.options.get("max_step", np.inf)))

    @staticmethod
    def sliding_end(old, new, exits_at, t_old, t_new):
        """The earliest end of a sliding mode in the step (t_old, t_new], or None: where an exit (an
        entry of ``exits_at(tt)``, positive while the mode lasts) went from > 0 to <= 0 or from >= 0
        to < 0 (``old``, ``new``: the exits at the step's ends), located by brentq."""
        hit = None
        for j in range(new.size):
            if not (old[j] > 0 >= new[j] or old[j] >= 0 > new[j]):
                continue
            if old[j] <= 0:
                root = t_old
            else:
                try:
                    root = brentq(lambda tt, j=j: exits_at(tt)[j], t_old, t_new, 4 * _EPS, 4 * _EPS)
                except ValueError:
                    root = t_new
            hit = root if hit is None else min(hit, root)
        return hit

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
                hit = self.sliding_end_within(old, new, lambda tt: driver.exits_at(tt, dense(tt)), t_prev, t_new)
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
        return _Stalled({"message": f"the simulation stalled at t={t:.6g}: "
                                    + (f"{named} keep changing mode at every evaluation and " if named
                                       else "switches keep changing mode at every evaluation and ")
                                    + "the solver makes no headway",
                         "time": float(t), "kind": "events", "law": None,
                         "variable": self.model.SWITCH_OWNERS[culprits[0]] if culprits else None,
                         "cause": "several switches (sign, if, coulomb) keep changing mode together "
                                  "where no sliding mode holds them",
                         "hint": "smooth the laws near their switching surfaces (a small linear band "
                                 "around zero velocity, for instance)"}, t, y)

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

    def switch_columns(self, t, x, modes):
        """Switching functions at many points with one mode vector: shape (switches, points)."""
        if getattr(self.model, "VECTORIZED", True):
            return np.asarray(np.broadcast_to(self.model.switches(t, x, self.p, modes),
                                              (self.switch_count, t.size)), dtype=float)
        return _evaluate_columns(self.model, self.p, self.model.switches, t, x, modes, self.switch_count)

    def point_modes(self, t, x, modes, relevant):
        """Modes at every point of a frozen segment: the segment's for the switches that were located,
        ``sign(g)`` at the point for the others (those whose crossings were not events)."""
        rows = np.repeat(np.asarray(modes, dtype=float)[None, :], t.size, axis=0)
        free = np.flatnonzero(~np.asarray(relevant, dtype=bool))
        if free.size == 0 or t.size == 0:
            return rows
        read = self.model.modes_read_by_switches
        # when no switching function reads a free mode, one pass is the fixed point
        passes = 1 if read is not None and not read[free].any() else self.switch_count + 1
        for _ in range(passes):
            changed = False
            unique, inverse = _unique_rows(rows)
            for r, row in enumerate(unique):
                columns = np.flatnonzero(inverse.ravel() == r)
                new = mode_values(self.switch_columns(t[columns], x[:, columns], row)[free],
                            self.model.floor_switches[free]).T
                if not np.array_equal(new, rows[np.ix_(columns, free)]):
                    rows[np.ix_(columns, free)] = new
                    changed = True
            if not changed:
                break
        return rows

    def evaluate_columns(self, function, t, x, modes, rows, out=None, columns=slice(None)):
        """``function(t, x, p, modes)`` over columns: see :func:`_evaluate_columns`."""
        return _evaluate_columns(self.model, self.p, function, t, x, modes, rows, out, columns)

    def _blend(self, function, p, times, x, corner_ids, weights, modes_by_id, rows, columns):
        """The function that writes into ``out[:, columns]`` ``function`` on a Filippov sliding
        mode's points: its corners' values weighted (a corner of weight 0 counts 0, even where its
        value is not finite)."""
        model = self.model
        corners = [(modes_by_id[corner_id], weight) for corner_id, weight in zip(corner_ids, weights)]

        def blend(out):
            total = np.zeros((rows, times.size))
            for modes, weight in corners:
                if np.any(weight != 0):
                    corner = _evaluate_columns(model, p, function, times, x, modes, rows)
                    total += weight * np.where(weight != 0, corner, 0.0)
            out[:, columns] = total
        return blend

    def _consistent_blocks(self) -> None:
        """Drop what an interruption (Ctrl-C lands between any two statements) left half recorded:
        a block whose times, states or mode were not all appended, or whose times and states
        differ in length."""
        count = min(len(self.blocks_t), len(self.blocks_x), len(self.blocks_mode))
        del self.blocks_t[count:], self.blocks_x[count:], self.blocks_mode[count:]
        while self.blocks_t and np.shape(self.blocks_x[-1])[-1] != np.size(self.blocks_t[-1]):
            self.blocks_t.pop(), self.blocks_x.pop(), self.blocks_mode.pop()

    def variable_rows(self) -> dict:
        """Each variable's row of the result's matrix of variables, made once per model (a
        1000-section chain has 6 000 variables); the results share it and never change it."""
        memo = _model_memo(self.model, "variable rows")
        if not memo:
            memo.update(zip(self.model.VARIABLE_NAMES, self.model.VARIABLE_ROWS))
        return memo

    def result(self, complete, failure):
        self._consistent_blocks()
        model = self.model
        n = len(model.STATE_NAMES)
        n_out, n_var = len(model.OUTPUT_NAMES), len(model.VARIABLE_NAMES)
        modes_by_id = {index: np.array(key) for key, index in self.mode_table.items()}
        if self.blocks_t:
            t = np.concatenate(self.blocks_t)
            # point by point in memory (the driver's batches are stored so, as (points, states) copies
            # seen transposed): the batches are copied whole, not state by state (2 ms of a 10 s run
            # of the 1000-section chain), and a point's states are together, as a CSV row takes them
            x = np.empty((n, t.size), order="F")
            np.concatenate(self.blocks_x, axis=1, out=x)
        else:
            t, x = np.zeros(0), np.zeros((n, 0))
        # restarts that made no progress (a switch re-decided at the same instant) repeat a point:
        # keep its first record, so the time of the result strictly increases. Dropped before the
        # outputs and variables are evaluated (not a copy of every variable at every point after)
        keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.ones(0, dtype=bool)
        kept_blocks = list(zip(self.blocks_t, self.blocks_mode))
        if not keep.all():
            t, x, start, kept_blocks = t[keep], x[:, keep], 0, []
            for times, mode in zip(self.blocks_t, self.blocks_mode):
                kept = keep[start:start + times.size]
                start += times.size
                if kept.all():
                    kept_blocks.append((times, mode))
                elif kept.any():
                    if isinstance(mode, tuple) and mode[0] == "slide":
                        mode = ("slide", mode[1], np.asarray(mode[2])[:, kept])
                    kept_blocks.append((times[kept], mode))
        # every column is written below, by the sliding blend or by its mode's group; variables that
        # are one quantity (a junction's common effort or flow) are one row, evaluated once
        outputs = np.empty((n_out, t.size))
        picked = model.row_variables
        n_rows = len(picked)
        variable_tasks = []     # each fills its columns of the variables' matrix, when one is read
        # the parameters as they are now (the caller's array may be changed after the run)
        parameters = np.array(self.p, dtype=float)
        if n_rows == n_var:
            variables_of = model.variables
        else:
            def variables_of(tt, xx, p, m, evaluate=model.variables):
                values = evaluate(tt, xx, p, m)
                return [values[i] for i in picked]
            if getattr(model.variables, "at_points", None) is not None:
                variables_of.at_points = (lambda tt, xx, p, m, at=model.variables.at_points, rows=list(picked):
                                          at(tt, xx, p, m)[rows])
        groups = {}             # (mode id, relevant mask) -> column indices
        all_relevant = (True,) * self.switch_count
        sliding = []            # (time before, last time, corners) of each sliding block
        start = 0
        with np.errstate(all="ignore"):
            blocks = []         # consecutive blocks of one sliding mode merged: one evaluation per corner
            for times, mode in kept_blocks:
                if (blocks and isinstance(mode, tuple) and mode[0] == "slide" and isinstance(blocks[-1][1], tuple)
                        and blocks[-1][1][0] == "slide" and blocks[-1][1][1] == mode[1]):
                    last_times, last = blocks[-1]
                    blocks[-1] = (np.concatenate([last_times, times]),
                                  ("slide", mode[1], np.concatenate([last[2], mode[2]], axis=1)))
                else:
                    blocks.append((times, mode))
            for times, mode in blocks:
                columns = np.arange(start, start + times.size)
                start += times.size
                if isinstance(mode, tuple) and mode[0] == "slide":     # the Filippov combination
                    _, corner_ids, weights = mode
                    before = t[columns[0] - 1] if columns[0] > 0 else times[0]
                    sliding.append((float(before), float(times[-1]),
                                    np.array([modes_by_id[c] for c in corner_ids], dtype=float), times, weights))
                    xx = x[:, start - times.size:start]
                    self._blend(model.outputs, self.p, times, xx, corner_ids, weights, modes_by_id, n_out,
                                columns)(outputs)
                    variable_tasks.append(self._blend(variables_of, parameters, times, xx, corner_ids, weights,
                                                      modes_by_id, n_rows, columns))
                    continue
                key = (mode[1], mode[2]) if isinstance(mode, tuple) else (mode, all_relevant)
                groups.setdefault(key, []).append(columns)
            for (mode, relevant), parts in groups.items():
                columns = np.concatenate(parts)
                # contiguous (a run without mode changes): views of the states, not copies
                whole = slice(int(columns[0]), int(columns[-1]) + 1) \
                    if columns.size and columns[-1] - columns[0] + 1 == columns.size else columns
                tt, xx = t[whole], x[:, whole]
                per_point = self.point_modes(tt, xx, modes_by_id[int(mode)], relevant)
                unique, inverse = _unique_rows(per_point)
                for r, row in enumerate(unique):
                    if len(unique) == 1:
                        chosen, cols = slice(None), columns
                    else:
                        chosen = np.flatnonzero(inverse.ravel() == r)
                        cols = columns[chosen]
                    if cols.size and cols[-1] - cols[0] + 1 == cols.size:     # contiguous: a view, no scatter
                        cols = slice(int(cols[0]), int(cols[-1]) + 1)
                    points, states = (tt, xx) if len(unique) == 1 else (tt[chosen], xx[:, chosen])
                    self.evaluate_columns(model.outputs, points, states, row, n_out, outputs, cols)
                    variable_tasks.append(functools.partial(_evaluate_columns, model, parameters, variables_of,
                                                            points, states, row, n_rows, columns=cols))
        # the variables are evaluated from these when first read: read-only, like the variables
        t.flags.writeable = x.flags.writeable = False
        reached = float(t[-1]) if t.size else self.t_start
        if complete:
            message = f"completed: {t.size} points to t={reached:.6g}, {len(self.events)} events"
        else:
            message = failure["message"]
        self.stats["points"] = int(t.size)
        return Result(
            t=t,
            states=dict(zip(model.STATE_NAMES, x)),
            outputs=dict(zip(model.OUTPUT_NAMES, outputs)),
            variables=LazyRows(self.variable_rows(), _Deferred((n_rows, t.size), variable_tasks)),
            events=list(self.events),
            complete=complete,
            message=message,
            failure=failure,
            stats=dict(self.stats),
            parameters={name: float(v) for name, v in zip(model.parameter_names, self.p)},
            jumps=[(time, dict(zip(model.STATE_NAMES, before)), dict(zip(model.STATE_NAMES, after)))
                   for time, before, after in self.jumps],
            sliding=sliding,
        )


def _evaluate_columns(model, p, function, t, x, modes, rows, out=None, columns=slice(None)):
    """``function(t, x, p, modes)`` over columns: at once when the model is vectorized, else one by one.

    Written into ``out[:, columns]`` when given (no matrix of its own: the result's matrices
    of every variable at every point are filled in place), else into a new matrix."""
    if out is None:
        out = np.full((rows, t.size), np.nan)
    if getattr(model, "VECTORIZED", True):
        values = function(t, x, p, modes)
        # rows written into a view (or a block scattered once): not a fancy index per row
        target = out[:, columns] if isinstance(columns, slice) else np.empty((rows, t.size))
        for row, value in enumerate(values):
            target[row] = value
        if not isinstance(columns, slice):
            out[:, columns] = target
    elif getattr(function, "at_points", None) is not None and t.size > 1:
        out[:, columns] = function.at_points(t, x, p, modes)
    else:
        indices = np.arange(out.shape[1])[columns]
        for j in range(t.size):
            out[:, indices[j]] = np.asarray(function(t[j], x[:, j], p, modes), dtype=float)
    return out


def _unique_rows(rows):
    """``np.unique(rows, axis=0, return_inverse=True)``, at once for the common case of a segment
    whose points are all in one mode (numpy sorts the rows as bytes, slow for long segments)."""
    if len(rows) and (rows == rows[0]).all():
        return rows[:1], np.zeros(len(rows), dtype=np.intp)
    if rows.ndim == 2 and rows.size and np.isfinite(rows).all() and (rows == np.round(rows)).all():
        low = rows.min(axis=0)
        base = rows.max(axis=0) - low + 1
        if np.sum(np.log2(base)) < 52:         # each row as one exact integer: a 1-d unique
            weights = np.concatenate(([1.0], np.cumprod(base[:-1])))
            keys = (rows - low) @ weights
            _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
            return rows[first], inverse.ravel()
    return np.unique(rows, axis=0, return_inverse=True)


def output_grid(t_start, t_end, dt):
    """``t_start, t_start + dt, ...`` up to ``t_end`` (included, even when not a multiple of dt)."""
    count = int(math.floor((t_end - t_start) / dt * (1 + 1e-12) + 1e-9))
    grid = t_start + dt * np.arange(count + 1)
    if grid[-1] < t_end - 1e-9 * dt:
        grid = np.append(grid, t_end)
    grid[-1] = min(grid[-1], t_end)
    return grid


# ------------------------------------------------------------ native code

#: The three C functions of ``NATIVE_SOURCE`` (see ``bondc.codegen.emit._NativeEmitter``).
_NATIVE_FUNCTIONS = ("bondc_rhs", "bondc_jac", "bondc_switches", "bondc_when_conditions", "bondc_when_actions")
#: a model with a nonlinear algebraic loop also has its outputs and variables in C (where C can print them)
_NATIVE_POINT_FUNCTIONS = ("bondc_outputs", "bondc_variables")
#: ... and each of its functions but the Jacobian over many points in one call (``<name>_at``)
_NATIVE_AT_FUNCTIONS = ("bondc_rhs", "bondc_switches") + _NATIVE_POINT_FUNCTIONS
#: Compiler flags: no contraction into fused multiply-adds, so C rounds like numpy.
_NATIVE_FLAGS = ("-fPIC", "-shared", "-ffp-contract=off")
#: Optimisation by the size of each translation unit's text: gcc's -O2 (and -O1) grow much faster
#: than linearly on one function of thousands of statements (measured: the 100-section chain's
#: 73 kB, 1.0 s; the 300-section chain's 186 kB, 5 s; the 1000-section chain's Jacobian, 160 kB of
#: stores into its output, 11 s, against 0.35 s at -O0). Hand-written models are far below the limit
#: (the flagship: 11 kB). A large model's own small units (its switching functions, the CVODE
#: driver) are still -O2: the driver's loops over every state at every step (the finiteness checks,
#: the stored steps) took 10 % of the 1000-section chain's run at -O0.
_NATIVE_OPTIMIZE = ((100_000, "-O2"), (float("inf"), "-O0"))
#: From this size of C text on, each function of the model (and the driver) is compiled as a
#: translation unit of its own, all at once, and the objects are linked: on a 2-core machine the
#: 10000-section chain's build takes 11 s instead of 17 s. A model's C text marks where its units
#: begin (``UNIT_MARK``, written by bondc's code generation); the part before the first is the
#: prelude every unit starts with. The limit is -O2's: a text above it in one unit was all -O0, and the
#: 100-section chain's (56 kB) with the driver (50 kB) ran its right-hand side and the driver's loops
#: unoptimised (the explicit stepper's run 2.4 times as long).
_NATIVE_SPLIT_FROM = _NATIVE_OPTIMIZE[0][0]
UNIT_MARK = "/* ---- bondc: a translation unit of its own ---- */\n"
_NATIVE_LIBRARIES: dict = {}        # digest -> (ffi, lib) loaded in this process
_NATIVE_BY_TEXT: dict = {}          # (id of a model's C text object, SUNDIALS link) -> (it, digest, (ffi, lib))
_NATIVE_NOTES: set = set()          # reasons already printed (each once per process)


def cache_dir() -> str:
    """bondc's cache folder: ``$BONDC_CACHE_DIR``, else the user cache directory (platformdirs)."""
    given = os.environ.get("BONDC_CACHE_DIR")
    if given:
        return given
    try:
        import platformdirs
    except ImportError:         # a standalone module where platformdirs is not installed
        return os.path.join(os.path.expanduser("~"), ".cache", "bondc")
    return platformdirs.user_cache_dir("bondc", appauthor=False)


#: bondc's native sources, by file name: the C and C++ files of the folder ``bondc/native`` (package
#: data). ``driver.c``, bondc's CVODE driver, is built into a model's library where scikit-sundae's
#: SUNDIALS libraries can be linked: it integrates a segment with the model's C functions and
#: watches its switching functions, returning to Python only at a possible crossing, the segment's
#: end, or anything unusual; ``driver.h`` declares what Python calls of it (cffi's cdef reads it),
#: ``sundials.h`` what it calls of SUNDIALS, ``model.h`` the model's functions it calls.
#: ``erk.cpp`` is bondc's explicit stepper (C++, a library of its own, built once per machine and
#: shared by every model): Boost.Odeint's Dormand-Prince 5(4) pair and its continuous extension,
#: whose steps are controlled as scipy's RK45 controls them (its error norm, step factors, first step
#: and smallest step), so the C code and the numpy code (scipy's RK45) take the same steps to
#: rounding; the driver calls it through its table of functions (``erk_api.h``,
#: ``bondc_driver_explicit``) instead of CVODE, for the solver DOPRI5 (and ``auto`` on a model that
#: is not stiff). The integration formulas, the error estimate and the interpolant are odeint's; the
#: file adds the controller's policy and the stop at a segment's end.
#: None: read from the package. A generated module that carries this runtime (``bondc compile
#: --standalone``) sets it after its copy to the files' text (``{name: text}``), so that it builds
#: them where bondc is not installed.
_NATIVE_FILES = None
_NATIVE_READ: dict = {}         # file name -> its text, read from the package once per process


def native_file(name: str) -> str:
    """The text of bondc's native source ``name`` (``driver.c``, ...): the generated module's own copy
    (``_NATIVE_FILES``), else the package's file ``bondc/native/<name>``. Raises OSError (KeyError
    for a module's copy) where it is missing."""
    if _NATIVE_FILES is not None:
        return _NATIVE_FILES[name]
    text = _NATIVE_READ.get(name)
    if text is None:
        folder = os.path.join(os.path.dirname(os.path.abspath(__file__)), "native")
        with open(os.path.join(folder, name), encoding="utf-8") as stream:
            text = _NATIVE_READ[name] = stream.read()
    return text


def native_build_text(name: str, within=()) -> str:
    """The text of bondc's native source ``name`` as it is compiled: each ``#include "file"`` line of
    it replaced by that file's text (of the same folder, its own includes replaced in turn), so that
    the compiler needs no include folder and the cache key (a hash of the compiled text) covers the
    headers too."""
    parts = []
    for line in native_file(name).splitlines(keepends=True):
        if line.startswith('#include "'):
            included = line.split('"')[1]
            if included in within + (name,):
                raise OSError(f"bondc's native source {name} includes {included} again")
            parts.append(native_build_text(included, within + (name,)))
        else:
            parts.append(line)
    return "".join(parts)


_ERK_FLAGS = ("-O3", "-fPIC", "-shared", "-ffp-contract=off", "-std=c++17")
_ERK_LOADED: dict = {}          # (cache folder, $CXX, $PATH) -> (ffi, lib, table address) or (None, None, why)


#: The compilers bondc builds its native code with, per language: ``$CC`` (``$CXX``) where it names a
#: program, then the system's on PATH, then zig's (the ``ziglang`` package, one of bondc's
#: dependencies: a C and C++ compiler wherever pip installs bondc). Each candidate builds a small
#: shared library once per machine (a compiler without its C library's headers fails there) and the
#: outcome is recorded in ``cache_dir()/native``; the first that builds is the one, and its name and
#: version are part of the cache key of every library it builds.
_SYSTEM_COMPILERS = {"c": ("CC", ("cc", "gcc", "clang")), "c++": ("CXX", ("c++", "g++", "clang++"))}
#: zig's flags on top of bondc's: code for the architecture's baseline processor, as a system
#: compiler makes it (zig's default is this machine's processor), and no UndefinedBehaviorSanitizer
#: (zig's default below -O2: large models' units are compiled at -O0, and a signed overflow would
#: abort the process)
_ZIG_FLAGS = ("-mcpu=baseline", "-fno-sanitize=undefined")
#: (file name, text, flags) of the library each language's candidates build once
_COMPILER_PROBES = {
    "c": ("probe.c", "#include <math.h>\ndouble bondc_probe(double x) { return sin(x); }\n", ("-lm",)),
    "c++": ("probe.cpp", "#include <algorithm>\n#include <vector>\nextern \"C\" double bondc_probe(double x)\n"
            "{ std::vector<double> v{x, 1.0}; return *std::max_element(v.begin(), v.end()); }\n",
            ("-std=c++17",)),
}
_COMPILERS: dict = {}       # (language, $CC or $CXX, $PATH) -> (Compiler or None, why)


#: A compiler bondc builds with: ``command`` (the program and the flags it always gets), ``label``
#: (its version and where it is, as ``stats["compiler"]`` shows it) and ``identity`` (what the cache
#: keys of its builds carry)
Compiler = _collections.namedtuple("Compiler", "command label identity")


def find_compiler(language="c"):
    """``(Compiler, "")`` for ``language`` ("c" or "c++"), or ``(None, why none)``; chosen once per
    process (for the same ``$CC``/``$CXX`` and PATH) from the outcomes recorded for this machine."""
    variable = _SYSTEM_COMPILERS[language][0]
    key = (language, os.environ.get(variable, ""), os.environ.get("PATH", ""))
    known = _COMPILERS.get(key)
    if known is None:
        known = _COMPILERS[key] = _choose_compiler(language)
    return known


def _zig():
    """The zig program the ``ziglang`` package ships, or None."""
    import importlib.util

    try:
        spec = importlib.util.find_spec("ziglang")
    except (ImportError, ValueError):
        return None
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        program = os.path.join(folder, "zig.exe" if os.name == "nt" else "zig")
        if os.access(program, os.X_OK):
            return program
    return None


def _choose_compiler(language):
    import shlex
    import shutil

    variable, names = _SYSTEM_COMPILERS[language]
    kind = "C" if language == "c" else "C++"
    given = os.environ.get(variable, "").strip()
    try:
        words = shlex.split(given)
    except ValueError:
        words = []
    candidates = ([(f"${variable}", words)] if given else []) + [(name, [name]) for name in names]
    failures, seen = [], set()
    if given and not (words and shutil.which(words[0])):
        failures.append(f"${variable} ({given}) was not found")
    for origin, words in candidates:
        program = shutil.which(words[0]) if words else None
        if program is None or os.path.realpath(program) in seen:
            continue
        seen.add(os.path.realpath(program))
        command = (program, *words[1:])
        built, text = _probe_compiler(language, command, (*command, "--version"))
        if built:
            where = "; ".join((" ".join(command), *failures))
            return Compiler(command, f"{text} ({where})", f"{os.path.realpath(program)} {text}"), ""
        failures.append(f"{origin} ({program}) failed ({text})")
    zig = _zig()
    if zig is None:
        failures.append("the ziglang package is not installed")
        return None, f"no {kind} compiler works here ({'; '.join(failures)}; set {variable})"
    command = (zig, "cc" if language == "c" else "c++", *_ZIG_FLAGS)
    built, text = _probe_compiler(language, command, (zig, "version"))
    if not built:
        failures.append(f"zig (the ziglang package) failed ({text})")
        return None, f"no {kind} compiler works here ({'; '.join(failures)}; set {variable})"
    why = "; ".join(failures) or f"no {kind} compiler on PATH"
    return Compiler(command, f"zig {command[1]} {text} (the ziglang package: {why})",
                    f"{os.path.realpath(zig)} zig {text} {' '.join(_ZIG_FLAGS)}"), ""


def _probe_compiler(language, command, version):
    """``(True, its version)`` where ``command`` builds the language's small shared library, else
    ``(False, its first complaint)``: found in this machine's record of the program (by its path,
    size and time), else tried and recorded. A failure is tried again after a day (the C library's
    headers may have been installed since)."""
    import hashlib
    import json
    import shutil
    import subprocess
    import tempfile

    try:
        status = os.stat(command[0])
    except OSError as error:
        return False, str(error)
    name, code, flags = _COMPILER_PROBES[language]
    digest = hashlib.sha256(repr((language, command, os.path.realpath(command[0]), status.st_size,
                                  status.st_mtime_ns, code, flags)).encode("utf-8")).hexdigest()[:24]
    folder = os.path.join(cache_dir(), "native")
    record = os.path.join(folder, f"compiler_{digest}.json")
    try:
        with open(record, encoding="utf-8") as stream:
            known = json.load(stream)
        if known["built"] or _time_module.time() - os.path.getmtime(record) < 86400:
            return bool(known["built"]), str(known["text"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    work = None
    try:
        os.makedirs(folder, exist_ok=True)
        work = tempfile.mkdtemp(dir=folder, prefix="build-")
        source = os.path.join(work, name)
        with open(source, "w", encoding="utf-8") as stream:
            stream.write(code)
        done = subprocess.run([*command, "-O2", "-fPIC", "-shared", "-o", os.path.join(work, "probe.so"), source,
                               *flags], capture_output=True, text=True, timeout=900, cwd=work)
        if done.returncode != 0:
            lines = done.stderr.strip().splitlines() or ["no message"]
            built, text = False, next((line for line in lines if "error" in line), lines[0]).strip()
        else:
            told = subprocess.run(version, capture_output=True, text=True, timeout=60)
            built, text = True, ((told.stdout.strip().splitlines() or ["unknown version"])[0]).strip()
    except (OSError, subprocess.SubprocessError) as error:
        return False, f"could not run: {error}"       # not recorded: it may run another time
    finally:
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)
    try:
        fd, temporary = tempfile.mkstemp(dir=folder, prefix="build-", suffix=".json")
        with os.fdopen(fd, "w", encoding="utf-8") as stream:
            json.dump({"built": built, "text": text, "command": list(command)}, stream)
        os.replace(temporary, record)
    except OSError:
        pass
    return built, text


def compiler_label(language="c") -> str:
    """What ``stats["compiler"]`` (``stats["compiler_cxx"]``) says: the compiler :func:`find_compiler`
    chose for ``language``, its version and why (zig's: why no system compiler), or ""."""
    compiler = find_compiler(language)[0]
    return compiler.label if compiler is not None else ""


def native_turned_off() -> bool:
    """Whether ``BONDC_NATIVE`` turns compiled code off (0, no, off, false)."""
    return os.environ.get("BONDC_NATIVE", "1").strip() in ("0", "no", "off", "false")


def load_erk():
    """``(address of the table, "")`` of bondc's explicit stepper library (``bondc/native/erk.cpp``), or
    ``(None, why not)``: native code turned off, the Boost headers (package boost-headers) or a C++
    compiler missing, a failed build. Built once per machine into ``cache_dir()/native`` (in a
    private folder, then renamed into place) and loaded once per process."""
    if native_turned_off():
        return None, "native code is turned off (BONDC_NATIVE=0)"
    key = (cache_dir(), os.environ.get("CXX", ""), os.environ.get("PATH", ""))
    known = _ERK_LOADED.get(key)
    if known is None:
        known = _ERK_LOADED[key] = _build_erk()
    return (known[2], "") if known[0] is not None else (None, known[2])


def _build_erk():
    """(ffi, lib, table address) of the stepper library, built first where the cache lacks it;
    (None, None, why not) where it cannot be had."""
    try:
        import boost_headers
    except ImportError:
        return None, None, "the Boost headers (the package boost-headers) are not installed"
    import hashlib

    try:
        import cffi
    except ImportError:
        return None, None, "cffi is not installed"
    include = str(boost_headers.get_include())
    compiler, why = find_compiler("c++")
    if compiler is None:
        return None, None, why
    try:
        text = native_build_text("erk.cpp")
    except (OSError, KeyError) as error:
        return None, None, f"bondc's explicit stepper's source is missing ({error})"
    digest = hashlib.sha256("\n".join((*_ERK_FLAGS, compiler.identity, getattr(boost_headers, "__version__", ""),
                                       text)).encode("utf-8")).hexdigest()[:40]
    path = os.path.join(cache_dir(), "native", f"erk_{digest}.so")
    if not os.path.exists(path):
        import shutil
        import subprocess
        import tempfile

        work = None
        try:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            work = tempfile.mkdtemp(dir=os.path.dirname(path), prefix="build-")
            source = os.path.join(work, "erk.cpp")
            with open(source, "w", encoding="utf-8") as stream:
                stream.write(text)
            library = os.path.join(work, "erk.so")
            done = subprocess.run([*compiler.command, *_ERK_FLAGS, "-I", include, "-o", library, source],
                                  capture_output=True, text=True, timeout=900)
            if done.returncode != 0:
                lines = done.stderr.strip().splitlines() or ["no message"]
                first = next((line for line in lines if "error" in line), lines[0])
                return None, None, f"the C++ compiler failed on bondc's explicit stepper ({first})"
            os.replace(library, path)
        except (OSError, subprocess.SubprocessError) as error:
            return None, None, f"the C++ compiler could not run ({error})"
        finally:
            if work is not None:
                shutil.rmtree(work, ignore_errors=True)
    ffi = cffi.FFI()
    ffi.cdef("const void *bondc_erk_table(void);")
    try:
        lib = ffi.dlopen(path)
    except OSError as error:
        return None, None, f"bondc's explicit stepper could not be loaded ({error})"
    return ffi, lib, int(ffi.cast("uintptr_t", lib.bondc_erk_table()))


_SUNDIALS_PARTS = ("core", "cvode", "nvecserial", "sunmatrixdense", "sunmatrixband", "sunlinsoldense",
                   "sunlinsolband")


@functools.lru_cache(maxsize=None)
def _sundials_link():
    """``(C index type, library paths)`` of the SUNDIALS 7 that scikit-sundae ships (Linux wheels),
    or None: then the driver is not built and the model's C functions run under scikit-sundae.
    Looked up once per process."""
    import glob
    import importlib.util

    try:
        spec = importlib.util.find_spec("sksundae")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    package = os.path.dirname(spec.origin)
    try:
        with open(os.path.join(package, "py_config.pxi"), encoding="utf-8") as stream:
            config = dict(line.replace('"', "").split(" = ", 1) for line in stream.read().splitlines()
                          if " = " in line)
    except (OSError, ValueError):
        return None
    index = {"int": "int", "int32_t": "int", "long": "long", "int64_t": "long long",
             "long int": "long", "long long": "long long"}.get(config.get("SUNDIALS_INT_TYPE", "").strip())
    if not config.get("SUNDIALS_VERSION", "").startswith("7.") or index is None \
            or config.get("SUNDIALS_FLOAT_TYPE", "").strip() != "double":
        return None
    folder = os.path.join(os.path.dirname(package), "scikit_sundae.libs")
    libraries = []
    for part in _SUNDIALS_PARTS:
        found = sorted(glob.glob(os.path.join(folder, f"libsundials_{part}-*.so*")))
        if not found:
            return None
        libraries.append(found[0])
    return index, tuple(libraries)


def load_native(source, driver=True):
    """``(ffi, lib)`` for the C text ``source``, or ``(None, why not)``.

    The shared library is built once per distinct text and compiler (:func:`find_compiler`:
    ``$CC``, else ``cc``/``gcc``/``clang``, else zig's from the ziglang package) into
    ``cache_dir()/native`` (built in a private folder, then renamed into place, so concurrent
    runs never see half a file)
    and loaded with cffi. ``BONDC_NATIVE=0`` turns native code off. With ``driver`` and
    scikit-sundae's SUNDIALS libraries at hand, bondc's CVODE driver is built in too
    (``hasattr(lib, "bondc_driver_new")``); if that build fails, the model alone is built.
    A large model's functions are compiled as separate units at once (``_NATIVE_SPLIT_FROM``),
    and :func:`start_native` may have started that build already: it is then waited for.
    """
    if native_turned_off():
        return None, "native code is turned off (BONDC_NATIVE=0)"
    # a model's text object seen before in this process (every run of a loaded model): its
    # library without joining and hashing the text again (2 ms for a 1000-section chain)
    key = (id(source), _sundials_link() if driver else None)
    known = _NATIVE_BY_TEXT.get(key)
    if known is not None and known[0] is source and _NATIVE_LIBRARIES.get(known[1]) is known[2]:
        return known[2]
    given = source
    if isinstance(source, (tuple, list)):
        source = "".join(source)
    if not source:
        return None, "the model has no native code"
    why = ""
    for text, libraries in _native_variants(source, driver):
        ffi, lib = _build_native(text, libraries)
        if ffi is not None:
            digest = next((d for d, loaded in _NATIVE_LIBRARIES.items() if loaded[1] is lib), None)
            if digest is not None:
                _NATIVE_BY_TEXT[key] = (given, digest, _NATIVE_LIBRARIES[digest])
            return ffi, lib
        why = why or lib
    return None, why


def _native_variants(source, driver):
    """[(C text, libraries)] to try in order: with bondc's CVODE driver where SUNDIALS can be
    linked, then the model alone."""
    link = _sundials_link() if driver else None
    variants = []
    if link is not None:
        try:        # SUNDIALS' index type, then the driver with its headers (bondc/native/driver.c)
            text = f"#define BONDC_INDEX_TYPE {link[0]}\n" + native_build_text("driver.c")
        except (OSError, KeyError):     # not there (a damaged installation): the model alone
            text = None
        if text is not None:
            variants.append((source + "\n" + UNIT_MARK + text, link[1]))
    variants.append((source, ()))
    return variants


def _native_plan(source, libraries, compiler):
    """(compiler flags, translation units, digest, library path) of a C text built by ``compiler``
    (a :class:`Compiler`)."""
    import hashlib

    def level(text):
        return next(flag for limit, flag in _NATIVE_OPTIMIZE if len(text) < limit)

    flags = (level(source), *_NATIVE_FLAGS)
    texts = _native_units(source)
    # several units: each optimised by its own size; one: by the whole text's
    units = [(text, level(text) if len(texts) > 1 else flags[0]) for text in texts]
    levels = " ".join(level for _, level in units)
    digest = hashlib.sha256("\n".join((*flags, compiler.identity, *libraries, f"units {len(units)} {levels}",
                                       source)).encode("utf-8")).hexdigest()[:40]
    return flags, units, digest, os.path.join(cache_dir(), "native", f"model_{digest}.so")


def _link_flags(libraries):
    return [*libraries, f"-Wl,-rpath,{os.path.dirname(os.path.realpath(libraries[0]))}"] if libraries else []


def _build_native(source, libraries):
    try:
        import cffi
    except ImportError:
        return None, "cffi is not installed"
    compiler, why = find_compiler("c")
    if compiler is None:
        return None, why
    flags, units, digest, path = _native_plan(source, libraries, compiler)
    if digest in _NATIVE_LIBRARIES:
        return _NATIVE_LIBRARIES[digest]
    build = _NATIVE_PENDING.pop(digest, None)        # started ahead by start_native
    if build is not None and build.owner != os.getpid():
        build = None        # a forked process's copy of its parent's build: the parent finishes it
    if not os.path.exists(path):
        import subprocess

        try:
            if build is None:
                os.makedirs(os.path.dirname(path), exist_ok=True)
                build = _NativeBuild(compiler, flags, units, os.path.dirname(path), _link_flags(libraries))
            failure = build.finish()
            if failure:
                return None, f"the C compiler failed ({failure})"
            os.replace(build.library, path)
        except (OSError, subprocess.SubprocessError) as error:
            return None, f"the C compiler could not run ({error})"
        finally:
            if build is not None:
                build.discard()
    elif build is not None:
        build.discard()
    ffi = cffi.FFI()
    ffi.cdef("".join(f"void {name}(double t, const double *x, const double *p, const double *m, double *out);\n"
                     for name in _NATIVE_FUNCTIONS + _NATIVE_POINT_FUNCTIONS)
             + "".join(f"void {name}_at(int count, const double *t, const double *x, const double *p, "
                       "const double *m, double *out);\n" for name in _NATIVE_AT_FUNCTIONS)
             + (native_file("driver.h") if libraries else ""))
    try:
        lib = ffi.dlopen(path)
    except OSError as error:
        return None, f"the compiled model could not be loaded ({error})"
    _NATIVE_LIBRARIES[digest] = (ffi, lib)
    return ffi, lib


def start_native(source, driver=True) -> None:
    """Start building, in the background, the library ``load_native(source, driver)`` will load,
    when it is a large model's (compiled as several units) and not built yet: its compilers then
    run while the caller goes on (Python compiling the generated module), and ``load_native``
    waits for them. Does nothing otherwise, or where anything is missing (it is only a head start)."""
    if native_turned_off() or not source:
        return
    if isinstance(source, (tuple, list)):
        source = "".join(source)
    text, libraries = _native_variants(source, driver)[0]
    try:
        compiler = find_compiler("c")[0]
        if compiler is None:
            return
        flags, units, digest, path = _native_plan(text, libraries, compiler)
        if (len(units) == 1 or digest in _NATIVE_LIBRARIES or digest in _NATIVE_PENDING
                or os.path.exists(path)):
            return
        os.makedirs(os.path.dirname(path), exist_ok=True)
        _NATIVE_PENDING[digest] = _NativeBuild(compiler, flags, units, os.path.dirname(path),
                                               _link_flags(libraries))
    except Exception:       # noqa: BLE001  (load_native builds it, and says why not)
        return


def native_text(module_source: str) -> str:
    """The C text of a generated module (its ``NATIVE_SOURCE`` literal), read without running it."""
    import ast as python_ast

    marker = "\nNATIVE_SOURCE = "
    start = module_source.rfind(marker)
    end = module_source.find("\nNATIVE_UNAVAILABLE = ", start)
    if start < 0 or end < 0:
        return ""
    try:
        value = python_ast.literal_eval(module_source[start + len(marker):end])
    except (ValueError, SyntaxError):
        return ""
    return "".join(value) if isinstance(value, tuple) else str(value)


class _NativeBuild:
    """A shared library being compiled: every translation unit's compiler started at once (``-c``
    for several, then a link in :meth:`finish`), in a private folder of the native cache."""

    def __init__(self, compiler, flags, units, directory, link):
        import subprocess
        import tempfile

        self.owner = os.getpid()        # only this process waits for the compilers it started
        self.work = tempfile.mkdtemp(dir=directory, prefix="build-")
        self.library = os.path.join(self.work, "model.so")
        self.compiler, self.flags, self.link = compiler, flags, link
        files = []
        for k, (text, _) in enumerate(units):
            files.append(os.path.join(self.work, f"unit{k}.c"))
            with open(files[-1], "w", encoding="utf-8") as stream:
                stream.write(text)
        if len(files) == 1:
            self.objects = None
            commands = [[*compiler.command, *flags, "-o", self.library, files[0], *link, "-lm"]]
        else:
            self.objects = [name[:-2] + ".o" for name in files]
            compile_flags = [flag for flag in flags[1:] if flag != "-shared"]
            commands = [[*compiler.command, level, *compile_flags, "-c", "-o", obj, name]
                        for (_, level), name, obj in zip(units, files, self.objects)]
        self.runs = [subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                     for command in commands]

    def finish(self) -> str:
        """Wait for the compilers (and link): "" or the compiler's first line of complaint."""
        import subprocess

        def first_line(stderr):
            return (stderr.strip().splitlines() or ["no message"])[0]

        failure = ""
        for run in self.runs:
            _, stderr = run.communicate(timeout=900)
            if run.returncode != 0 and not failure:
                failure = first_line(stderr)
        if failure or self.objects is None:
            return failure
        done = subprocess.run([*self.compiler.command, *self.flags, "-o", self.library, *self.objects, *self.link,
                               "-lm"],
                              capture_output=True, text=True, timeout=900)
        return first_line(done.stderr) if done.returncode != 0 else ""

    def discard(self) -> None:
        """Stop any compiler still running and remove the private folder."""
        import shutil

        for run in self.runs:
            if run.poll() is None:
                run.kill()
                run.wait()
        shutil.rmtree(self.work, ignore_errors=True)


_NATIVE_PENDING: dict = {}          # digest -> _NativeBuild started by start_native


def _discard_pending() -> None:
    while _NATIVE_PENDING:
        build = _NATIVE_PENDING.popitem()[1]
        if build.owner == os.getpid():
            build.discard()


atexit.register(_discard_pending)


def _native_units(source):
    """The C text as the translation units to compile: one, or (from ``_NATIVE_SPLIT_FROM`` on,
    where the text is marked) the prelude followed by each marked part, with the prototypes of the
    model's functions (the driver calls them)."""
    if len(source) < _NATIVE_SPLIT_FROM or UNIT_MARK not in source:
        return [source.replace(UNIT_MARK, "")]
    prelude, *parts = source.split(UNIT_MARK)
    prototypes = "".join(f"void {name}(double t, const double *x, const double *p, const double *m, double *out);\n"
                         for name in _NATIVE_FUNCTIONS)
    return [prelude + prototypes + part for part in parts]


def attach_native(model, native=None):
    """Make ``model`` (a :class:`_Model`) evaluate its right-hand side, Jacobian and switching
    functions (and, with an algebraic loop, its outputs and variables) with its compiled C code;
    returns ``(True, "")`` or ``(False, why not)``.

    ``native`` False keeps the numpy code; None (the default) uses C where it can. Calls the
    C code cannot serve (arrays of times, the mode reader that records which modes a law reads)
    go to the numpy functions, which compute the same values.
    """
    if native is False:
        return False, "numpy code requested"
    source = getattr(model, "NATIVE_SOURCE", "")
    if not source:
        return False, getattr(model, "NATIVE_UNAVAILABLE", "") or "the model has no native code"
    ffi, lib = load_native(source)
    if ffi is None:
        return False, lib
    n, count = len(model.STATE_NAMES), len(model.SWITCHES)
    rows, cols = pattern_arrays(model.JACOBIAN_PATTERN)
    buffer, empty, ndarray, contiguous = ffi.from_buffer, np.empty, np.ndarray, np.ascontiguousarray
    doubles = ffi.typeof("double[]")        # resolved once: these wrappers run thousands of times a run
    c_rhs, c_jac, c_switches = lib.bondc_rhs, lib.bondc_jac, lib.bondc_switches
    numpy_rhs, numpy_jac, numpy_switches = model.rhs, model.jac, model.switches
    held = {}       # "p"/"m" -> (the array given, its C buffer): both are the same for many calls

    def pointer(key, value):
        last = held.get(key)
        if last is not None and last[0] is value:
            return last[1]
        made = buffer(doubles, contiguous(value, dtype=float))
        held[key] = (value, made)
        return made

    def arrays(t, x, p, m):
        """The C arguments, or None for a call the C code cannot serve."""
        if not isinstance(t, float) or type(x) is not ndarray or x.ndim != 1:
            return None
        if count and type(m) is not ndarray:
            return None
        return (float(t), buffer(doubles, contiguous(x, dtype=float)), pointer("p", p),
                pointer("m", m) if count else ffi.NULL)

    # a nonlinear algebraic loop is solved in C by Newton's method; where that fails (its unknowns
    # nan), the numpy module solves it as without C (MINPACK's hybr), so that C never makes a
    # point fail that numpy would have solved
    loops = not getattr(model, "VECTORIZED", True)

    def vector(c_function, numpy_function, size, checked):
        """``c_function`` writing ``size`` values; ``numpy_function`` for a call C cannot serve, or
        (``checked``) where C gives a value that is not finite."""
        def evaluate(t, x, p, m):
            arguments = arrays(t, x, p, m)
            if arguments is None:
                return numpy_function(t, x, p, m)
            out = empty(size)
            if size:
                c_function(*arguments, buffer(doubles, out))
                if checked and not math.isfinite(out.sum()):
                    return numpy_function(t, x, p, m)
            return out
        return evaluate

    def jac(t, x, p, m):
        arguments = arrays(t, x, p, m)
        if arguments is None:
            return numpy_jac(t, x, p, m)
        matrix = np.zeros((n, n))
        if rows.size:
            entries = empty(rows.size)      # in JACOBIAN_PATTERN order
            c_jac(*arguments, buffer(doubles, entries))
            if loops and not math.isfinite(entries.sum()):
                return numpy_jac(t, x, p, m)
            matrix[rows, cols] = entries
        return matrix

    def at_points(c_function, numpy_function, size):
        """``c_function`` (a ``<name>_at``) over the columns of ``x`` in one call: values by
        columns, each exactly the point's call; numpy's where C's is not finite."""
        def evaluate(t, x, p, m):
            t = np.ascontiguousarray(t, dtype=float)
            rows = np.ascontiguousarray(np.asarray(x, dtype=float).T)      # a point's states in a row
            out = empty((t.size, size))
            if size and t.size:
                c_function(t.size, buffer(doubles, t), buffer(doubles, rows), pointer("p", p),
                           pointer("m", m) if count else ffi.NULL, buffer(doubles, out))
                for j in np.flatnonzero(~np.isfinite(out).all(axis=1)):
                    out[j] = numpy_function(float(t[j]), rows[j].copy(), p, m)
            return out.T
        return evaluate

    model.rhs, model.jac = vector(c_rhs, numpy_rhs, n, loops), jac
    model.switches = vector(c_switches, numpy_switches, count, loops)
    try:
        when_native = bool(model.WHEN_LABELS) and lib.bondc_when_native() == 1
    except AttributeError:      # a library built before C had the when clauses
        when_native = False
    if when_native:
        # the when clauses' statements from C too: the pieces integrated ahead run them in C, and
        # the run takes those pieces only where its own values are theirs to the bit (numpy's
        # where C's are not finite)
        offsets = np.ascontiguousarray(np.concatenate(([0], np.cumsum([len(targets) for targets in
                                                                        model.WHEN_TARGETS]))), dtype=np.intc)
        c_actions, numpy_actions = lib.bondc_when_actions, model.WHEN_ACTIONS

        def clause(k):
            def action(t, x, p, m):
                arguments = arrays(t, x, p, m)
                if arguments is None:
                    return numpy_actions[k](t, x, p, m)
                out = empty(max(int(offsets[-1]), 1))
                c_actions(*arguments, buffer(doubles, out))
                values = out[offsets[k]:offsets[k + 1]]
                if not math.isfinite(values.sum()):
                    return numpy_actions[k](t, x, p, m)
                return tuple(values)
            return action
        model.WHEN_ACTIONS = tuple(clause(k) for k in range(len(numpy_actions)))
        model.when_offsets = offsets
    if loops:
        # a model with a loop is evaluated point by point: its outputs and variables from C too,
        # where the library has them (C could not print them otherwise); where the library has
        # them, each function also over many points at once (its attribute ``at_points``)
        numpy_functions = {"rhs": numpy_rhs, "switches": numpy_switches}
        for name, size in (("rhs", n), ("switches", count), ("outputs", len(model.OUTPUT_NAMES)),
                           ("variables", len(model.VARIABLE_NAMES))):
            if name not in numpy_functions:
                if not hasattr(lib, f"bondc_{name}"):
                    continue
                numpy_functions[name] = getattr(model, name)
                setattr(model, name, vector(getattr(lib, f"bondc_{name}"), numpy_functions[name], size, True))
            if hasattr(lib, f"bondc_{name}_at"):
                getattr(model, name).at_points = at_points(getattr(lib, f"bondc_{name}_at"), numpy_functions[name],
                                                           size)
    if hasattr(lib, "bondc_driver_new"):
        model.native_library = (ffi, lib)
    return True, ""


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
    run = _Run(model, parameters, t_start, t_end, t_eval, method, rtol, atol, max_step, first_step, progress,
               max_events, max_event_rate)
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
