"""The quadrature of a power over one solver step: the 5-point Gauss-Lobatto rule, and the split
of a power that changes sign into its positive and negative parts (:func:`_integrals`).

Takes the powers at the Lobatto nodes of each step (steps, 5); returns per step the net
integral and its positive and negative parts.

>>> times = 1.0 + _LOBATTO_NODES[None, :]              # one step, from t = 0 to 2 s
>>> [round(float(value[0]), 12) for value in _integrals(times, times ** 2)]    # t^2 W: exact
[2.666666666667, 2.666666666667, 0.0]
>>> [round(float(value[0]), 3) + 0.0 for value in _integrals(times, times - 1.0)]  # t - 1 W
[0.0, 0.5, -0.5]
"""

from __future__ import annotations

import math

import numpy as np

# Gauss-Lobatto, 5 points on [-1, 1]: exact for polynomials of degree 7.
_LOBATTO_NODES = np.array([-1.0, -math.sqrt(3.0 / 7.0), 0.0, math.sqrt(3.0 / 7.0), 1.0])
_LOBATTO_WEIGHTS = np.array([0.1, 49.0 / 90.0, 32.0 / 45.0, 49.0 / 90.0, 0.1])
# Samples at the nodes -> monomial coefficients of their degree-4 interpolant.
_FROM_NODES = np.linalg.inv(np.vander(_LOBATTO_NODES, 5, increasing=True))
# _INTEGRATION[i, j]: integral from -1 to node i of the Lagrange basis polynomial of node j.
_INTEGRATION = np.array([[(s ** (m + 1) - (-1.0) ** (m + 1)) / (m + 1) for m in range(5)]
                         for s in _LOBATTO_NODES]) @ _FROM_NODES
# The interpolant evaluated on a fine grid (to split a power into its positive and negative parts).
_FINE_GRID = np.linspace(-1.0, 1.0, 65)
_FINE_FROM_NODES = np.vander(_FINE_GRID, 5, increasing=True) @ _FROM_NODES


METHOD = ("5-point Gauss-Lobatto quadrature per solver step, a step halved where the rule and Simpson's on its "
          "ends and middle disagree, states from the cubic Hermite interpolant refined "
          "by deferred correction (rates with the step's modes frozen); sliding-mode steps: a cubic spline "
          "through the recorded values of each sliding span")
# Simpson's rule on the nodes -1, 0, 1 (the first, middle and last Lobatto nodes): exact to degree 3
_SIMPSON_WEIGHTS = np.array([1.0 / 3.0, 0.0, 4.0 / 3.0, 0.0, 1.0 / 3.0])
#: a step is halved where the two rules differ by more than this share of the run's integral of |v|
RESOLUTION = 1e-6
#: ... at most this many times over (a kink inside a step: each halving quarters its difference) ...
HALVINGS = 8
#: ... adding at most this share of the run's steps (or BUDGET_FLOOR steps), the worst steps first:
#: a kink that the solver's noise crosses in step after step (a turbulent orifice at rest) stays within it
BUDGET_SHARE, BUDGET_FLOOR = 0.1, 64


def resolution_totals(times: np.ndarray, values) -> dict:
    """Per variable, the run's integrals of its magnitude and its square's (the 5-point Lobatto rule
    over every step): the scales :func:`under_resolved` measures a step's quadrature against."""
    half = 0.5 * (times[:, -1] - times[:, 0])
    totals = {}
    with np.errstate(all="ignore"):
        for name, samples in values.items():
            samples = np.asarray(samples, dtype=float)
            totals[name] = tuple(float(np.sum(np.abs(lobatto)[np.isfinite(lobatto)])) for lobatto in
                                 (half * (samples @ _LOBATTO_WEIGHTS), half * ((samples * samples) @ _LOBATTO_WEIGHTS)))
    return totals


def under_resolved(times: np.ndarray, values, totals: dict, skip: np.ndarray, budget: int) -> np.ndarray:
    """The steps (sorted indices, at most ``budget`` of them, the worst first) over which some
    variable's or its square's 5-point Lobatto integral and Simpson's differ by more than
    ``RESOLUTION`` of the run's integral of its magnitude (``totals``, :func:`resolution_totals`): a
    step long for the curvature of a law of its states (an explicit solver's step over a constant flow
    into a gas spring, whose pressure is p0 (V0/V)^n: exact for the states and 4 s long) or with a
    kink inside. ``values``: name -> (steps, 5) at the nodes ``times``; ``skip`` marks steps not to
    split (sliding).

    >>> times = np.array([[0.0, 0.17, 0.5, 0.83, 1.0], [1.0, 1.17, 1.5, 1.83, 2.0]])
    >>> values = {"v": np.array([[1.0, 1.0, 1.0, 1.0, 1.0], [0.0, 0.1, 4.0, 0.1, 0.0]])}
    >>> under_resolved(times, values, resolution_totals(times, values), np.zeros(2, dtype=bool), 10).tolist()
    [1]
    """
    half = 0.5 * (times[:, -1] - times[:, 0])
    worst = np.zeros(times.shape[0])
    with np.errstate(all="ignore"):
        for name, samples in values.items():
            samples = np.asarray(samples, dtype=float)
            for v, total in zip((samples, samples * samples), totals[name]):
                share = np.abs(half * (v @ _LOBATTO_WEIGHTS) - half * (v @ _SIMPSON_WEIGHTS)) / max(total, 1e-300)
                worst = np.fmax(worst, share)
    worst[skip] = 0.0
    coarse = np.flatnonzero(worst > RESOLUTION)
    if coarse.size > budget:
        coarse = coarse[np.argsort(-worst[coarse], kind="stable")[:max(budget, 0)]]
    return np.sort(coarse)


def _integrals(times: np.ndarray, power: np.ndarray):
    """Per step: (net, positive part, negative part) of the integral of ``power`` (steps, 5).

    The net integral is the Lobatto rule. Where the samples change sign, the
    parts come from the degree-4 interpolant of the five samples (whose exact
    integral is the Lobatto rule) on a fine grid, with linear zero crossings,
    scaled so that positive + negative is the net integral.
    """
    half = 0.5 * (times[:, -1] - times[:, 0])
    net = half * (power @ _LOBATTO_WEIGHTS)
    positive = np.where(np.all(power >= 0, axis=1), net, 0.0)
    negative = np.where(np.all(power <= 0, axis=1), net, 0.0)
    mixed = np.flatnonzero(np.any(power > 0, axis=1) & np.any(power < 0, axis=1))
    if mixed.size:
        values = power[mixed] @ _FINE_FROM_NODES.T                      # (k, fine points)
        left, right = values[:, :-1], values[:, 1:]
        width = 2.0 / (_FINE_GRID.size - 1)
        crossing = (left > 0) != (right > 0)
        with np.errstate(all="ignore"):
            theta = np.where(crossing, left / (left - right), 0.5)      # where the chord crosses zero
        up = np.where(crossing, np.where(left > 0, theta * left, (1 - theta) * right),
                      np.maximum(left, 0) + np.maximum(right, 0))
        down = np.where(crossing, np.where(left < 0, theta * left, (1 - theta) * right),
                        np.minimum(left, 0) + np.minimum(right, 0))
        pos = 0.5 * width * np.sum(up, axis=1)
        neg = 0.5 * width * np.sum(down, axis=1)
        total = net[mixed] / half[mixed]
        gross = pos - neg
        with np.errstate(all="ignore"):
            excess = np.where(gross > 0, (total - (pos + neg)) / gross, 0.0)
        positive[mixed] = half[mixed] * pos * (1 + excess)
        negative[mixed] = half[mixed] * neg * (1 - excess)
    return net, positive, negative
