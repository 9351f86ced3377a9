"""The generated module's functions evaluated over columns of points: a compiled model's
namespace and parameter values -> :class:`_Model` (right-hand side, variables, outputs,
switches, modes and Filippov combinations at many points at once, grouped by mode).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from bondc.runtime import _unique_rows, corner_weights, filippov_alpha, mode_values

class _Model:
    """The generated module's functions (see :mod:`bondc.runtime`), evaluated over columns."""

    def __init__(self, namespace: Mapping, parameters: Mapping[str, float]):
        self.state_names = tuple(namespace["STATE_NAMES"])
        self.variable_names = tuple(namespace["VARIABLE_NAMES"])
        self.output_names = tuple(namespace["OUTPUT_NAMES"])
        self.switch_count = len(namespace["SWITCHES"])
        self.vectorized = bool(namespace.get("VECTORIZED", False))
        self._rhs, self._variables, self._outputs = namespace["_rhs"], namespace["_variables"], namespace["_outputs"]
        self._switches = namespace["_switches"]
        if not self.vectorized:
            self._native_point_functions(namespace)
        kinds = tuple(namespace.get("SWITCH_KINDS", ())) or ("sign",) * self.switch_count
        self.floors = np.array([kind == "floor" for kind in kinds], dtype=bool)
        names = tuple(namespace["PARAMETERS"])
        self.p = np.array([float(parameters.get(name, namespace["PARAMETERS"][name])) for name in names])

    def _native_point_functions(self, namespace: Mapping) -> None:
        """A model evaluated point by point (its algebraic loops are solved at every point: numpy's
        MINPACK from Python) has its right-hand side, switching functions and variables evaluated
        by its C code where that is built (the loops solved there by Newton's method; numpy's where
        that fails)."""
        make, attach = namespace.get("_Model"), namespace.get("attach_native")
        if make is None or attach is None or "_MODEL" not in namespace:
            return
        model = make(namespace["_MODEL"])
        if attach(model, None)[0]:
            self._rhs, self._switches, self._variables = model.rhs, model.switches, model.variables
            self._outputs = model.outputs

    def _columns(self, function, t, x, modes, rows):
        out = np.empty((rows, t.size))
        if t.size == 0:
            return out
        with np.errstate(all="ignore"):
            if self.vectorized:
                # a quantity of parameters alone (a pump's flow with its drive's step frozen) is a
                # number where the others are rows, and numpy cannot stack the two: the parameters
                # given as rows too make it one; a literal constant in the list still cannot be
                # stacked, and that model is evaluated point by point
                rows_of_p = np.broadcast_to(self.p[:, None], (self.p.size, t.size))
                for p in (self.p, rows_of_p):
                    try:
                        values = function(t, x, p, modes)
                        for row, value in enumerate(values):
                            out[row] = value
                        return out
                    except (ValueError, TypeError, IndexError):
                        continue
            elif getattr(function, "at_points", None) is not None:     # C, every point in one call
                out[:] = function.at_points(t, x, self.p, modes)
                return out
            for j in range(t.size):
                out[:, j] = np.asarray(function(t[j], x[:, j], self.p, modes), dtype=float)
        return out

    def groups(self, modes):
        """(the distinct rows of ``modes``, each row's index among them), for :meth:`by_modes`."""
        if self.switch_count == 0:
            return None
        unique, inverse = _unique_rows(np.ascontiguousarray(modes, dtype=float))
        return unique, np.ravel(inverse)

    def by_modes(self, function, t, x, modes, rows, groups=None):
        """``function`` at every column with that column's mode vector (rows of ``modes``);
        ``groups``: :meth:`groups` of ``modes`` where the caller has it already."""
        out = np.empty((rows, t.size))
        if self.switch_count == 0:
            return self._columns(function, t, x, np.zeros(0), rows)
        unique, inverse = groups if groups is not None else self.groups(modes)
        if len(unique) == 1:
            return self._columns(function, t, x, unique[0], rows)
        # each mode's columns, in order: one stable sort instead of a comparison per mode
        order = np.argsort(inverse, kind="stable")
        bounds = np.cumsum(np.bincount(inverse, minlength=len(unique)))[:-1]
        for row, columns in zip(unique, np.split(order, bounds)):
            if columns.size:
                out[:, columns] = self._columns(function, t[columns], x[:, columns], row, rows)
        return out

    def modes(self, t, x):
        """The mode vector of the unfrozen law at every column: ``m = sign(g(t, x, m))`` (fixed point)."""
        rows = np.ones((t.size, self.switch_count))
        if self.switch_count == 0:
            return rows
        for _ in range(self.switch_count + 1):
            new = mode_values(self.by_modes(self._switches, t, x, rows, self.switch_count), self.floors).T
            if np.array_equal(new, rows):
                break
            rows = new
        return rows

    def rhs(self, t, x, modes, groups=None):
        return self.by_modes(self._rhs, t, x, modes, len(self.state_names), groups)

    def variables(self, t, x, modes):
        return self.by_modes(self._variables, t, x, modes, len(self.variable_names))

    def outputs(self, t, x, modes):
        return self.by_modes(self._outputs, t, x, modes, len(self.output_names))

    def switches(self, t, x, modes):
        return self.by_modes(self._switches, t, x, modes, self.switch_count)

    def filippov(self, corners, t, x, guess, probe):
        """The Filippov combination of a sliding mode at the columns (t, x): (its rate (n, k), the
        corners' weights (corners, k)), as the run computes it (``bondc.runtime.filippov_alpha``): the
        weights that hold every sliding switch's rate along the combination at zero, the rates by a
        central difference over ``probe``. ``corners``: the mode vectors (rows); the sliding switches
        are those in which they differ, each corner's side of one its sign there. ``guess``: the
        sliding switches' weights (switches, k) where a rate does not depend on them."""
        sliding = np.flatnonzero(np.any(corners != corners[0], axis=0))
        sides = np.sign(corners[:, sliding])
        count = t.size
        values = np.empty((len(corners), len(self.state_names), count))
        rates = np.empty((len(corners), sliding.size, count))
        with np.errstate(all="ignore"):
            for c, corner in enumerate(corners):
                modes = np.broadcast_to(corner, (count, corner.size))
                values[c] = self.rhs(t, x, modes)
                ahead = self.switches(t + probe, x + probe * values[c], modes)[sliding]
                behind = self.switches(t - probe, x - probe * values[c], modes)[sliding]
                rates[c] = (ahead - behind) / (2 * probe)
            if sliding.size == 1:       # one switch: alpha*rate+ + (1 - alpha)*rate- = 0
                plus, minus = rates[sides[:, 0] > 0, 0][0], rates[sides[:, 0] < 0, 0][0]
                alpha = np.where(minus == plus, guess[0], minus / (minus - plus))[None, :]
            else:
                alpha = np.array([filippov_alpha(rates[:, :, j], sides, guess[:, j]) for j in range(count)]).T
            alpha = np.where(np.isfinite(alpha), np.clip(alpha, 0.0, 1.0), guess)
            weights = np.array([corner_weights(alpha[:, j], sides) for j in range(count)]).T \
                if sliding.size > 1 else np.where(sides[:, :1] > 0, alpha, 1.0 - alpha)
            rate = np.einsum("ck,cnk->nk", weights, np.where(weights[:, None, :] != 0, values, 0.0))
        return rate, weights
