"""Nonlinear algebraic loops: MINPACK's hybr warm-started from the last solution, then Newton's
method from the guesses (:func:`solve_block`, :func:`solve_loop`, :func:`newton_search`)."""

import math

import numpy as np

from bondc.runtime.kernels import _optimize


class _ModeReader:
    """A mode vector that records which modes a law reads (only the active branches read theirs)."""

    __slots__ = ("values", "read")

    def __init__(self, values):
        self.values = [float(v) for v in values]
        self.read = set()

    def __getitem__(self, k):
        self.read.add(k)
        return self.values[k]


# -------------------------------------------------------- algebraic loops

_BLOCK_SOLUTIONS = {}
#: True while a law is evaluated with a :class:`_ModeReader` (see :func:`solve_block`)
_READING_MODES = False


class _ReadingModes:
    """``with _ReadingModes():`` a law is evaluated only to see which modes it reads (see
    :func:`solve_block`): sets this module's ``_READING_MODES`` for the block."""

    def __enter__(self):
        global _READING_MODES
        _READING_MODES = True

    def __exit__(self, *exc_info):
        global _READING_MODES
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
