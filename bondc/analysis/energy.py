"""Energy account: :class:`~bondc.statespace.StateSpace` + :class:`~bondc.simulate.SimResult` -> :class:`EnergyAccount`.

For every element the power *into* it is ``e*f`` when its bond points at it and
``-e*f`` when the bond leaves it (a two-port gets one power per port). Per
cycle (the experiment's ``cycle``; windows of that length from the start of the
run, a last partial window dropped unless it is the only one) the account
gives:

- sources (Se, MSe, Sf, MSf): energy *supplied* to the graph and energy
  *returned* into the source (both >= 0);
- resistors: energy *dissipated* (the integral of the power into the R);
- storage elements with a stored-energy function: the *change of stored
  energy*, the function evaluated at the state at both window ends. The
  function is ``StateSpace.energy`` (polynomial laws, analytic) or, for a law
  of the element's own default state alone that is not polynomial (a spring
  with backlash, a tyre that lifts off), ``integral of law dx`` between the two
  end states by adaptive quadrature ("numeric"), in pieces split at the state's
  values at the run's events, where such a law switches (a hard stop's law is
  zero on all but the last 3e-4 of the way: in one piece, every node of the
  quadrature can fall where it is zero);
- a storage element with a state of its own whose rate is proportional to
  its port flow (C) or effort (I), ``der(x) = k(x)*f``, and whose law depends
  on that state alone (a hydraulic chamber ``state p, der(p) = beta/V*f,
  e = p``): the port power is ``e(x)/k(x) * dx/dt``, so its stored energy is
  the integral of ``e/k dx`` ("numeric", like the above);
- storage elements without one (a chamber whose volume changes with a
  piston, laws that depend on other variables): the *net work in*, the
  integral of the power into the element;
- two-ports: the power in at each port and their sum, which must be ~0.

The **balance** per cycle: sources' net energy (supplied - returned) =
dissipated + change of stored energy + net work into storage without an energy
function, and its *residual*. Junctions, transformers and gyrators conserve
power at every instant, so the residual is the sum over the storage elements
with an energy function of ``integral(power in) - change of stored energy``:
it measures how far the simulated states are from integrating their own rates
(the solver's accumulated local error), plus the error of the quadrature
below, which is made far smaller. ``throughput`` is the sum over every element
(two-ports excepted) of ``integral(|power|)``, the energy that moved;
``relative_residual = |residual| / throughput``.

How the powers are integrated: the result must hold the solver's own step
points (a run without ``dt``; otherwise the run is repeated with the same
settings, which reproduces the same steps, and ``resimulated`` says so).
Steps never straddle an event or a known switching time. Each step is
evaluated with its modes frozen (the modes at its midpoint), as the solver
integrated it. The states inside a step start as the cubic Hermite
interpolant of the states and rates at both ends and are refined by
deferred-correction sweeps at the 5 Gauss-Lobatto nodes (see
:func:`_corrected_nodes`; steps where the sweeps would not contract, stiff
modes stepped over, keep the Hermite states); the powers there are
integrated with the 5-point Lobatto rule (exact for degree 7). The
quadrature's own error is then far below the solver's: the residual follows
the solver tolerance down to about 1e-12 of the throughput (see
``tests/test_energy.py``). A window edge inside a step splits the step at the
refined interpolant. Positive and negative parts of a power come from the
degree-4 interpolant of the five samples where they change sign, so
``supplied - returned`` is the net integral exactly. Steps of a Filippov
sliding mode (the law there is a convex combination only the runtime
computes) use the result's recorded values, through a cubic spline over the
points of each sliding span (the motion is smooth there).
``EnergyAccount.quadrature`` counts the steps of each kind.

>>> from pathlib import Path
>>> from bondc import semantic
>>> from bondc.causality import assign_causality
>>> from bondc.equations import derive
>>> path = Path(__file__).parents[2] / "models/series_rlc.bg"
>>> graph, _ = semantic.load(path, experiment=semantic.FIRST)
>>> ss = derive(assign_causality(graph))
>>> from bondc.simulate import simulate
>>> account = energy_account(ss, simulate(ss, graph.experiments["step"], t_end=0.1))
>>> cycle = account.windows[0]
>>> round(cycle.balance.sources_net * 1e3, 6), round(cycle.element("resistor").dissipated * 1e3, 6)
(10.0, 5.0)
>>> account.windows[0].balance.relative_residual < 1e-8
True
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from bondc.errors import AnalysisError, Diagnostic
from bondc.kinds import KINDS
from bondc.runtime import _unique_rows, corner_weights, filippov_alpha, mode_values

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

# The quadrature of a numeric energy function over many pieces at once: Gauss-Legendre rules of 10
# and 21 points on [-1, 1] (numpy's leggauss; exact for polynomials to degree 19 and 41), the
# second the piece's integral, their difference its error estimate.
GAUSS_NODES, GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(10)
FINE_NODES, FINE_WEIGHTS = np.polynomial.legendre.leggauss(21)
_PIECE_NODES = np.concatenate([GAUSS_NODES, FINE_NODES])

#: A residual above this fraction of the throughput gets warning W930.
RESIDUAL_TOLERANCE = 1e-6

ROLES = {name: kind.energy for name, kind in KINDS.items()}     # the energy role of each kind (bondc.kinds)

METHOD = ("5-point Gauss-Lobatto quadrature per solver step, states from the cubic Hermite interpolant refined "
          "by deferred correction (rates with the step's modes frozen); sliding-mode steps: a cubic spline "
          "through the recorded values of each sliding span")


# ------------------------------------------------------------------ values


@dataclass(frozen=True)
class ElementEnergy:
    """One element's energies over one window, in J (None where they do not apply).

    ``work_in`` is the integral of the power into the element (every kind);
    ``gross`` the integral of its absolute value. Storage elements with an
    energy function have ``stored_start``/``stored_end``/``stored_change``;
    those without have ``net_work_in`` (= ``work_in``). Two-ports have
    ``port_work`` (work in at p1, at p2) and ``work_in`` their sum.
    """

    element: str
    kind: str
    role: str                                   # source, dissipator, storage, converter
    work_in: float
    gross: float
    supplied: float | None = None
    returned: float | None = None
    dissipated: float | None = None
    stored_start: float | None = None
    stored_end: float | None = None
    stored_change: float | None = None
    net_work_in: float | None = None
    port_work: tuple[float, float] | None = None
    energy_function: str | None = None          # "analytic", "numeric" or None
    event_change: float | None = None           # stored energy changed by when clauses (reinit) in the window
    unit: str = "J"                             # a pseudo bond graph's own unit (e*f*s), e.g. K*J for heat

    @property
    def storage_defect(self) -> float | None:
        """``work_in - stored_change``: this storage element's share of the balance residual."""
        if self.stored_change is None:
            return None
        return self.work_in - self.stored_change


@dataclass(frozen=True)
class Balance:
    """sources' net energy = dissipated + stored_change + net_work_in (+ residual)."""

    supplied: float
    returned: float
    dissipated: float
    stored_change: float
    net_work_in: float
    converter_work: float                       # sum over two-ports of the work in at both ports (~0)
    throughput: float
    event_change: float = 0.0                   # stored energy changed at when clauses (an impact's loss < 0)

    @property
    def sources_net(self) -> float:
        return self.supplied - self.returned

    @property
    def residual(self) -> float:
        # what the ports delivered plus what the events changed is what is stored or dissipated
        return self.sources_net + self.event_change - (self.dissipated + self.stored_change + self.net_work_in)

    @property
    def relative_residual(self) -> float | None:
        return abs(self.residual) / self.throughput if self.throughput > 0 else None

    def to_json(self) -> dict:
        return {
            "supplied": self.supplied, "returned": self.returned, "sources_net": self.sources_net,
            "dissipated": self.dissipated, "stored_change": self.stored_change,
            "net_work_in": self.net_work_in, "converter_work": self.converter_work,
            "event_change": self.event_change, "residual": self.residual, "throughput": self.throughput,
            "relative_residual": self.relative_residual,
        }


@dataclass(frozen=True)
class Window:
    """One cycle (or the whole run): its span, every element's energies and the balance."""

    index: int
    t_start: float
    t_end: float
    partial: bool
    elements: tuple[ElementEnergy, ...]
    balance: Balance

    def element(self, name: str) -> ElementEnergy:
        for entry in self.elements:
            if entry.element == name:
                return entry
        raise KeyError(name)


ROW_KEYS = ("cycle", "t_start", "t_end", "element", "kind", "role", "supplied", "returned", "dissipated",
            "stored_change", "net_work_in", "work_in", "energy_function")
BALANCE_KEYS = ("cycle", "t_start", "t_end", "supplied", "returned", "sources_net", "dissipated",
                "stored_change", "net_work_in", "converter_work", "residual", "throughput", "relative_residual")


@dataclass(frozen=True)
class EnergyAccount:
    """Energies per element and cycle, and the energy balance of each cycle (see the module docstring)."""

    model: str
    experiment: str | None
    cycle: float | None
    windows: tuple[Window, ...]
    complete: bool                              # False: the run stopped early; the account covers what ran
    resimulated: bool                           # True: the run was repeated to get the solver's steps
    method: str = METHOD
    quadrature: Mapping[str, int] = field(default_factory=dict)   # steps: all, corrected, hermite, sliding
    diagnostics: tuple[Diagnostic, ...] = ()
    #: the stored-energy functions' recipes (for the compile cache's light entry); None if one has none
    energy_recipes: Mapping | None = field(default=None, repr=False, compare=False)

    @property
    def unit(self) -> str:
        """The unit of every energy: J, a pseudo bond graph's own (``kg*m^2*K/s^2`` for temperature and
        heat flow), or "mixed" when elements differ (then the balance adds unlike quantities)."""
        found = {e.unit for w in self.windows for e in w.elements}
        return found.pop() if len(found) == 1 else ("J" if not found else "mixed")

    @property
    def max_relative_residual(self) -> float:
        values = [w.balance.relative_residual for w in self.windows if w.balance.relative_residual is not None]
        return max(values) if values else 0.0

    def rows(self) -> list[dict]:
        """One dict per (cycle, element), keys :data:`ROW_KEYS`, energies in J."""
        rows = []
        for window in self.windows:
            for entry in window.elements:
                rows.append({
                    "cycle": window.index, "t_start": window.t_start, "t_end": window.t_end,
                    "element": entry.element, "kind": entry.kind, "role": entry.role,
                    "supplied": entry.supplied, "returned": entry.returned, "dissipated": entry.dissipated,
                    "stored_change": entry.stored_change, "net_work_in": entry.net_work_in,
                    "work_in": entry.work_in, "energy_function": entry.energy_function,
                })
        return rows

    def balance_rows(self) -> list[dict]:
        """One dict per cycle, keys :data:`BALANCE_KEYS`, energies in J."""
        rows = []
        for window in self.windows:
            row = {"cycle": window.index, "t_start": window.t_start, "t_end": window.t_end}
            row.update(window.balance.to_json())
            rows.append({key: row[key] for key in BALANCE_KEYS})
        return rows

    def to_json(self) -> dict:
        return {
            "model": self.model,
            "experiment": self.experiment,
            "cycle": self.cycle,
            "complete": self.complete,
            "resimulated": self.resimulated,
            "method": self.method,
            "quadrature": dict(self.quadrature),
            "max_relative_residual": self.max_relative_residual,
            "unit": self.unit,
            "cycles": [
                {
                    "index": window.index, "t_start": window.t_start, "t_end": window.t_end,
                    "partial": window.partial,
                    "balance": window.balance.to_json(),
                    "elements": [_element_json(entry) for entry in window.elements],
                }
                for window in self.windows
            ],
            "diagnostics": [d.to_json() for d in self.diagnostics],
        }

    def to_text(self) -> str:
        """Readable tables, one per cycle: element, kind, supplied, returned, dissipated, change of
        stored energy and net work in, in J; then the balance."""
        out = [f"Energy account of {self.model}" + (f" ({self.experiment})" if self.experiment else "")]
        unit = self.unit
        if unit != "J":
            pseudo = sorted({e.element for w in self.windows for e in w.elements if e.unit != "J"})
            out.append(f"(a pseudo bond graph: effort times flow is not a power for {', '.join(pseudo)}; "
                       + (f"its integrals are in {unit}, not joules)" if unit != "mixed" else
                          "each element's integrals are in its own unit, so the balance adds unlike quantities)"))
        J = "J" if unit == "J" else ("" if unit == "mixed" else unit)
        if not self.complete:
            out.append("(the run stopped early: the account covers what was simulated)")
        for window in self.windows:
            head = (f"cycle {window.index + 1}: t = {window.t_start:g} .. {window.t_end:g} s"
                    + (" (partial)" if window.partial else ""))
            out += ["", head]
            out += _table(window)
            b = window.balance
            relative = "-" if b.relative_residual is None else f"{b.relative_residual:.2e}"
            events = f" - changed at events {_j(b.event_change)} {J}" if b.event_change else ""
            out.append(f"balance: sources net {_j(b.sources_net)} {J} = dissipated {_j(b.dissipated)} {J}"
                       f" + stored {_j(b.stored_change)} {J} + net work in {_j(b.net_work_in)} {J}{events}"
                       f"; residual {b.residual:.3e} {J} ({relative} of throughput {_j(b.throughput)} {J})")
            if any(e.role == "converter" for e in window.elements):
                out.append(f"two-ports: work in at both ports {b.converter_work:.3e} {J} (ideally 0)")
        for diagnostic in self.diagnostics:
            out.append(f"{diagnostic.severity}[{diagnostic.code}]: {diagnostic.message}")
            if diagnostic.hint:
                out.append(f" = hint: {diagnostic.hint}")
        return "\n".join(out)


def _element_json(entry: ElementEnergy) -> dict:
    data = {
        "element": entry.element, "kind": entry.kind, "role": entry.role,
        "work_in": entry.work_in, "gross": entry.gross,
    }
    for key in ("supplied", "returned", "dissipated", "stored_start", "stored_end", "stored_change",
                "net_work_in", "energy_function"):
        value = getattr(entry, key)
        if value is not None:
            data[key] = value
    if entry.port_work is not None:
        data["port_work"] = {"p1": entry.port_work[0], "p2": entry.port_work[1]}
    if entry.unit != "J":
        data["unit"] = entry.unit
    if entry.storage_defect is not None:
        data["storage_defect"] = entry.storage_defect
    return data


def _j(value: float) -> str:
    return f"{value:.6g}"


def _table(window: Window) -> list[str]:
    columns = ("supplied", "returned", "dissipated", "stored_change", "net_work_in")
    titles = ("element", "kind", "supplied", "returned", "dissipated", "Δstored", "net work in")
    largest = max([abs(getattr(e, c)) for e in window.elements for c in columns
                   if getattr(e, c) is not None] + [0.0])
    # six significant digits for the largest entry of the table, at most nine decimals
    decimals = 3 if largest == 0 else min(max(5 - int(math.floor(math.log10(largest))), 0), 9)
    rows = []
    for entry in window.elements:
        cells = [entry.element, entry.kind]
        for column in columns:
            value = getattr(entry, column)
            cells.append("-" if value is None else f"{value:.{decimals}f}")
        rows.append(cells)
    widths = [max(len(titles[i]), *(len(r[i]) for r in rows)) if rows else len(titles[i])
              for i in range(len(titles))]
    line = lambda cells: "  ".join(c.ljust(w) if i < 2 else c.rjust(w)
                                   for i, (c, w) in enumerate(zip(cells, widths))).rstrip()
    return [line(titles), line(["-" * w for w in widths])] + [line(r) for r in rows]


# ------------------------------------------------------------------ errors


def _error(code: str, message: str, hint: str | None = None) -> AnalysisError:
    return AnalysisError(Diagnostic("error", code, message, hint=hint))


# ---------------------------------------------------------------- windows


#: At most this many cycles are analysed (each is a row of every per-cycle table).
MAX_CYCLES = 10_000


def cycle_windows(t_start: float, t_end: float, cycle: float | None) -> list[tuple[float, float, bool]]:
    """``(start, end, partial)`` of consecutive windows of length ``cycle`` from ``t_start``.

    A last partial window is dropped unless it is the only one; ``cycle`` None
    is the whole run.

    >>> cycle_windows(0.0, 1.0, 0.4)
    [(0.0, 0.4, False), (0.4, 0.8, False)]
    >>> cycle_windows(0.0, 1.0, 2.0)
    [(0.0, 1.0, True)]
    """
    if cycle is None:
        return [(t_start, t_end, False)]
    if not (isinstance(cycle, (int, float)) and math.isfinite(cycle) and cycle > 0):
        raise _error("E932", f"the cycle length must be a positive number of seconds, not {cycle!r}")
    count = (t_end - t_start) / cycle
    if count > MAX_CYCLES:      # before a window is made (cycle = 1e-9 s would be billions of them)
        raise _error("E935", f"the run spans {count:.3g} cycles of {cycle:g} s; at most {MAX_CYCLES} cycles "
                             f"are analysed", hint="check the cycle length (seconds), or analyse a shorter run")
    count = int(math.floor(count * (1 + 1e-9) + 1e-9))
    if count == 0:
        return [(t_start, t_end, True)]
    windows = [(t_start + k * cycle, t_start + (k + 1) * cycle, False) for k in range(count)]
    if abs(windows[-1][1] - t_end) <= 1e-9 * cycle:
        windows[-1] = (windows[-1][0], t_end, False)
    return windows


def experiment_cycle(ss, result) -> float | None:
    """The ``cycle`` of the experiment the result was run with, or None."""
    graph = getattr(ss, "graph", None)
    name = getattr(result, "experiment", None)
    experiments = getattr(graph, "experiments", {}) or {}
    if name is not None and name in experiments:
        return experiments[name].cycle
    return None


# ------------------------------------------------------------ trajectory


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


def _hermite(tau, h, xa, xb, fa, fb):
    """Cubic Hermite interpolant at fractions ``tau`` of steps of length ``h`` (broadcast)."""
    tau2, tau3 = tau * tau, tau * tau * tau
    return ((2 * tau3 - 3 * tau2 + 1) * xa + (tau3 - 2 * tau2 + tau) * h * fa
            + (-2 * tau3 + 3 * tau2) * xb + (tau3 - tau2) * h * fb)


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
        s = 2.0 * tau - 1.0
        weights = np.array([(s ** (m + 1) - (-1.0) ** (m + 1)) / (m + 1) for m in range(5)]) @ _FROM_NODES
        total = 0.5 * h * (rates[:, 0, :] @ _LOBATTO_WEIGHTS)
        return xa + 0.5 * h * (rates[:, 0, :] @ weights) + tau * (xb - xa - total)

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

    def samples(self, kind: str = "variables") -> tuple[np.ndarray, dict]:
        """Times (steps, 5) of the Lobatto nodes and every variable there (``kind`` "outputs": every
        output): name -> (steps, 5)."""
        evaluate = self.model.outputs if kind == "outputs" else self.model.variables
        names = self.model.output_names if kind == "outputs" else self.model.variable_names
        tau = (_LOBATTO_NODES + 1.0) / 2.0
        h = self.tb - self.ta
        times = self.node_times()
        states = self.node_states()
        n, steps = states.shape[0], times.shape[0]
        flat_modes = np.repeat(self.modes, 5, axis=0)
        values = evaluate(times.ravel(), states.reshape(n, steps * 5), flat_modes)
        values = values.reshape(len(names), steps, 5)
        outside = ~np.all(np.isfinite(values), axis=0)
        if np.any(outside):
            # a node whose interpolated state is a little outside its step's branch (a level that
            # reaches 0 with zero slope, interpolated to -1e-20 under its law's sqrt): the laws'
            # own branches at that node, as the unfrozen law evaluates them
            rows, columns = np.nonzero(outside)
            node_t, node_x = times[rows, columns], states[:, rows, columns]
            with np.errstate(all="ignore"):
                again = evaluate(node_t, node_x, self.model.modes(node_t, node_x))
            values[:, rows, columns] = np.where(np.isfinite(again), again, values[:, rows, columns])
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


# ------------------------------------------------------------- integrals


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


# ---------------------------------------------------------------- energy


class _StoredEnergy:
    """A storage element's stored-energy function: analytic (``StateSpace.energy``) or numeric.

    ``recipe``: how to rebuild it without sympy (:func:`energy_from_recipe`): the printed function
    of one state ``x`` and the global names it reads, or None when it cannot be rebuilt.
    """

    def __init__(self, kind: str, state_name: str, function=None, law=None, recipe=None, law_of_arrays=None):
        self.kind = kind                    # "analytic" or "numeric"
        self.state_name = state_name
        self.function = function            # H(x), analytic
        self.law = law                      # e(q) or f(p): dH/dx, numeric
        self.law_of_arrays = law_of_arrays  # the same law of an array of states, where it has one
        self.recipe = recipe

    def change(self, start: float, end: float, breaks=()) -> tuple[float, float, float]:
        """(H at start, H at end, change); a numeric H is the law integrated from a zero state,
        in pieces between the ``breaks`` (state values where the law may switch: quadrature that
        straddles a switch can miss it, as 31 Gauss nodes over [0, 0.050015] all miss a hard
        stop's law, zero below 0.05)."""
        if self.kind == "analytic":
            h0, h1 = float(self.function(start)), float(self.function(end))
            return h0, h1, h1 - h0
        # the change is integrated directly (not as a difference of two large integrals)
        return (self._integral(0.0, start, breaks), self._integral(0.0, end, breaks),
                self._integral(start, end, breaks))

    def _integral(self, a: float, b: float, breaks=()) -> float:
        if a == b:
            return 0.0
        low, high = min(a, b), max(a, b)
        inner = sorted({float(x) for x in breaks if low < x < high})
        edges = np.array([low, *inner, high])
        total = float(np.sum(self._pieces(edges[:-1], edges[1:])))
        return total if b > a else -total

    def _pieces(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """The law's integral over each piece [starts[i], ends[i]]: the 21-point Gauss rule on every
        piece in one evaluation of the law (at the 10-point rule's nodes too), where the 10-point
        rule agrees with it to the tolerance of :meth:`_piece` (a run with thousands of events has
        as many pieces); :meth:`_piece`, quad's adaptive rule, for the others (a kink inside, a
        steep law) and for a law that has no form for arrays."""
        results = np.full(starts.size, np.nan)
        if self.law_of_arrays is not None and starts.size > 1:
            half, middle = 0.5 * (ends - starts), 0.5 * (ends + starts)
            with np.errstate(all="ignore"):
                try:
                    values = np.broadcast_to(np.asarray(self.law_of_arrays(middle[:, None] + half[:, None] * _PIECE_NODES),
                                                        dtype=float), (starts.size, _PIECE_NODES.size))
                except (ValueError, TypeError, IndexError):
                    values = None
                if values is not None:
                    coarse = half * (values[:, :GAUSS_NODES.size] @ GAUSS_WEIGHTS)
                    fine = half * (values[:, GAUSS_NODES.size:] @ FINE_WEIGHTS)
                    size = np.max(np.abs(values), axis=1) * np.abs(ends - starts)
                    good = (np.all(np.isfinite(values), axis=1)
                            & (np.abs(fine - coarse) <= np.maximum(1e-15 * size, 1e-12 * np.abs(fine))))
                    results[good] = fine[good]
        for i in np.flatnonzero(np.isnan(results)):
            results[i] = self._piece(float(starts[i]), float(ends[i]))
        return results

    def _piece(self, a: float, b: float) -> float:
        from bondc.runtime import quad

        with np.errstate(all="ignore"):
            # a law that is not finite on the way (outside its domain) gives nan: no energy function
            size = max(abs(self.law(a)), abs(self.law(b)), abs(self.law(0.5 * (a + b)))) * abs(b - a)
            return quad(self.law, a, b, epsabs=1e-15 * size, epsrel=1e-12, limit=500)


def _numbers(ss, parameters: Mapping[str, float]) -> dict:
    import sympy

    return {symbol: sympy.Float(float(parameters.get(name, value)))
            for name, (symbol, value) in ss.parameters.items()}


def _lambdify(symbol, expr) -> tuple:
    """(the numpy function of ``symbol``, its recipe). The recipe is the function's text, printed
    by sympy from ``expr`` with its one symbol renamed ``x`` (so no name from the model is in it,
    and its numbers are the parameters' values), and where each global name it reads comes from."""
    import inspect

    import sympy

    from bondc.numeric import NUMERIC_FUNCTIONS

    x = sympy.Symbol("x", real=True)
    function = sympy.lambdify(x, expr.xreplace({symbol: x}), modules=[dict(NUMERIC_FUNCTIONS), "numpy"])
    try:
        text = inspect.getsource(function)
    except (OSError, TypeError):
        return function, None
    names = {}
    for name in function.__code__.co_names:
        value = function.__globals__.get(name)
        if name in NUMERIC_FUNCTIONS and NUMERIC_FUNCTIONS[name] is value:
            names[name] = ("bondc", name)
        elif value is np:
            names[name] = ("numpy", "")
        elif value is functools.reduce:         # sympy prints Max/Min as reduce(maximum, [...])
            names[name] = ("functools", "reduce")
        elif value is not None and getattr(np, name, None) is value:
            names[name] = ("numpy", name)
        else:
            return function, None      # anything else: no recipe (the cache then keeps sympy)
    return function, (text, names)


def energy_from_recipe(kind: str, state_name: str, recipe) -> _StoredEnergy:
    """A stored-energy function rebuilt from its recipe (see :func:`_lambdify`), without sympy.

    The text is sympy's printing of the energy law, made by bondc when the model was compiled
    (as the generated module is): its one argument is ``x`` and its only names are numpy's and
    bondc's numeric functions, so nothing of the model's text is executed.
    """
    from bondc.numeric import NUMERIC_FUNCTIONS

    if kind == "constant":
        return _StoredEnergy("analytic", state_name, function=lambda x, c=float(recipe): c)
    text, names = recipe
    namespace = {"__builtins__": {}}
    for name, (origin, attribute) in names.items():
        namespace[name] = (NUMERIC_FUNCTIONS[attribute] if origin == "bondc"
                           else functools.reduce if origin == "functools"
                           else getattr(np, attribute) if attribute else np)
    exec(compile(text, "<bondc energy function>", "exec"), namespace)  # safe: sympy's printing of an AST-built law, no model text
    function = next(value for name, value in namespace.items() if name not in names and callable(value))
    if kind == "analytic":
        return _StoredEnergy("analytic", state_name, function=function, recipe=recipe)
    return _StoredEnergy("numeric", state_name, law=lambda x, f=function: float(f(x)), recipe=recipe,
                         law_of_arrays=function)


def stored_energy_functions(ss, parameters: Mapping[str, float] | None = None) -> dict:
    """Storage element -> its :class:`_StoredEnergy`, for those that have one.

    Analytic from ``ss.energy``; numeric (``integral of law dx``) for an element
    in integral causality whose law depends on its own default state alone.
    A state space read from the compile cache without its sympy part
    (:class:`bondc.cache.LightStateSpace`) gives them from its recipes.
    """
    light = getattr(ss, "light_recipes", None)
    if light is not None:
        recipes = light(parameters or {})
        if recipes is not None:
            return {name: energy_from_recipe(kind, state, recipe) for name, (kind, state, recipe) in recipes.items()}
        ss = ss.full()
    import sympy

    from bondc.symbolic import as_sympy

    graph = ss.graph
    numbers = _numbers(ss, parameters or {})
    found = {}
    for element in graph.storage_elements:
        expr = (ss.energy or {}).get(element.name)
        if expr is not None:
            expr = as_sympy(expr).xreplace(numbers)
            if expr.has(sympy.zoo, sympy.nan, sympy.oo, -sympy.oo):
                continue        # a parameter of 0 where it divides (m = 0): count the work in instead
            free = list(expr.free_symbols)
            if len(free) == 1:
                function, recipe = _lambdify(free[0], expr)
                found[element.name] = _StoredEnergy("analytic", free[0].name, function=function, recipe=recipe)
            elif not free:
                constant = float(expr)
                found[element.name] = _StoredEnergy("analytic", "", function=lambda x, c=constant: c,
                                                    recipe=constant)
            continue
        kind = element.kind_info
        if element.name in ss.eliminated or len(element.states) != 1:
            continue
        state = element.states[0]
        state_name = state.qualified
        state_symbol = ss.symbols.get(state_name)
        if state_symbol is None:
            continue
        effort, flow = ss.bond_symbols[element.bond]
        law = ss.substituted(effort if kind.storage == "C" else flow).xreplace(numbers)
        if not law.free_symbols <= {state_symbol} or law.has(sympy.zoo, sympy.nan):
            continue
        if state.name == kind.state and state.rate is None:
            density = law                       # dH/dq = e(q), dH/dp = f(p)
        else:
            # a state of its own, der(x) = k(x)*f (C) or k(x)*e (I): the port power e*f is
            # law(x)/k(x) * dx/dt, so H(x) is the integral of law/k
            port = flow if kind.storage == "C" else effort
            rate = as_sympy(ss.derivatives.get(state_name, sympy.nan)).xreplace(numbers)
            gain = sympy.diff(rate, port)
            if (gain.free_symbols - {state_symbol} or gain == 0
                    or sympy.simplify(rate - gain * port) != 0):
                continue
            density = law / gain
        function, recipe = _lambdify(state_symbol, density)
        found[element.name] = _StoredEnergy("numeric", state_name, law=lambda x, f=function: float(f(x)),
                                            recipe=recipe, law_of_arrays=function)
    return found


def energy_recipes(functions: Mapping[str, _StoredEnergy]) -> dict | None:
    """element -> (kind, state name, recipe) of every function, or None if one has no recipe."""
    recipes = {}
    for name, energy in functions.items():
        if energy.recipe is None:
            return None
        kind = "constant" if not isinstance(energy.recipe, tuple) else energy.kind
        recipes[name] = (kind, energy.state_name, energy.recipe)
    return recipes


# ----------------------------------------------------------- the account


def _at_solver_steps(result) -> bool:
    """Whether the result's points are the solver's steps (a run without ``dt`` or ``t_eval``)."""
    settings = getattr(result, "settings", {}) or {}
    if settings.get("dt") is not None:
        return False
    stats = getattr(result, "stats", {}) or {}
    steps = stats.get("steps")
    t = np.asarray(result.t, dtype=float)
    if steps is None or not (steps + 1 <= t.size <= steps + 1 + len(result.events) + 1):
        return False
    if not result.events or not t.size:
        return True
    scale = max(abs(float(t[-1])), 1.0)
    times = np.array([time for time, _ in result.events], dtype=float)
    if t.size > 1 and np.all(t[1:] >= t[:-1]):
        # each event's nearest point among the sorted times: the one at or after it, or the one before
        after = np.minimum(np.searchsorted(t, times), t.size - 1)
        nearest = np.minimum(np.abs(t[after] - times), np.abs(t[np.maximum(after - 1, 0)] - times))
    else:
        nearest = np.array([np.min(np.abs(t - time)) for time in times])
    return bool(np.all(nearest <= 1e-9 * scale))


def steps_of(ss, result):
    """``result`` at the solver's own steps: itself, or for a run on a grid (``dt``, ``t_eval``) the
    same run repeated without it (the same steps), once per result. What is computed from a run
    rather than shown of it (the energy account, statistics, motor requirements) takes these: a
    peak between two report points is not missed."""
    if _at_solver_steps(result):
        return result
    steps = getattr(result, "_solver_steps", None)
    if steps is None:
        steps = repeat_run(ss, result)
        try:
            result._solver_steps = steps
        except AttributeError:      # (a result that takes no attributes: repeated each time)
            pass
    return steps


def _run_nodes(ss, steps, boundaries):
    """(model, trajectory, node times (steps, 5), every variable at the nodes) of a run at its
    solver's steps, its steps split at ``boundaries``: made once per run and boundaries, for the
    energy account and the statistics (:func:`dense_steps`) alike."""
    from bondc.simulate import compile_model

    key = tuple(float(edge) for edge in boundaries)
    memo = steps.__dict__.setdefault("_nodes", {})
    if key not in memo:
        # values bound late (--set, an edit of values only): the base's module, given the run's values
        namespace = compile_model(getattr(ss, "bound_base", None) or ss)
        model = _Model(namespace, steps.parameters)
        trajectory = _Trajectory(model, steps, boundaries)
        times, values = trajectory.samples()
        memo[key] = (model, trajectory, times, values)
    return memo[key]


def _flat_nodes(values):
    """Values at the nodes (steps, 5) as one row: the first step's start, then each step's nodes
    after its start (a step's start is the step before's end).

    >>> _flat_nodes(np.array([[0.0, 1, 2, 3, 4], [4, 5, 6, 7, 8]])).tolist()
    [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    """
    return np.concatenate([values[:1, 0], values[:, 1:].ravel()])


class _NodeRows(Mapping):
    """Node values (name -> (steps, 5)) as the rows of :func:`dense_steps` (each step's nodes after
    its start, the first step's start too), flattened when first read."""

    def __init__(self, values: Mapping, names):
        self._values, self._names, self._made = values, tuple(names), {}

    def __getitem__(self, name):
        if name not in self._made:
            self._made[name] = _flat_nodes(np.asarray(self._values[name]))
        return self._made[name]

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)


def dense_steps(ss, result):
    """``result`` at its solver's steps (:func:`steps_of`) and at the three interior Lobatto nodes of
    every step, where its states are the energy account's corrected interpolant between the steps
    (a sliding mode's, the cubic Hermite of its combination's rates) and its outputs and variables are
    evaluated there as the energy account evaluates its powers. What is computed from a run's outputs
    rather than shown of it (statistics, power per cycle, motor requirements) takes these: a peak
    between two steps is not missed (a 4 ms torque pulse inside a step of an explicit method, whose
    steps are long: 2.40 N m at the steps for its 2.5 N m), and the time integrals are of the solution
    between the steps, not of straight lines through them. Made once per result; a run whose steps
    cannot be interpolated so (fewer than two points, a law not finite there) gives its steps."""
    dense = getattr(result, "_dense_steps", None)
    if dense is not None:
        return dense
    steps = steps_of(ss, result)
    dense = steps
    if steps.t.size >= 2 and np.any(np.diff(steps.t) > 0):
        try:
            with np.errstate(all="ignore"):
                dense = _dense_view(ss, steps)
        except (AnalysisError, ValueError, FloatingPointError):
            dense = steps
    try:
        result._dense_steps = dense
    except AttributeError:
        pass
    return dense


def _dense_view(ss, steps):
    import dataclasses

    boundaries = sorted({edge for start, end, _ in cycle_windows(float(steps.t[0]), float(steps.t[-1]),
                                                                 experiment_cycle(ss, steps))
                         for edge in (start, end)})
    model, trajectory, times, variables = _run_nodes(ss, steps, boundaries)
    _, outputs = trajectory.samples("outputs")
    states = trajectory.interpolated_states()
    t = _flat_nodes(times)
    if not np.all(np.diff(t) > 0):
        raise ValueError("the nodes do not increase")
    bond_names = list(steps.bonds)
    return dataclasses.replace(
        steps, t=t, states={name: _flat_nodes(states[i]) for i, name in enumerate(model.state_names)},
        outputs={name: _flat_nodes(values) for name, values in outputs.items()},
        variables=_NodeRows(variables, model.variable_names),
        bonds=_NodeRows({name: variables[name] for name in bond_names if name in variables},
                        [name for name in bond_names if name in variables]))


def repeat_run(ss, result, t_eval=None):
    """``result``'s run again, with its settings and parameter values (the same solver steps),
    reported at its steps or at ``t_eval``; an incomplete run is cut where it stopped."""
    from bondc.simulate import simulate

    settings = dict(result.settings)
    rerun = simulate(ss, None, t_end=settings.get("t_end", float(result.t[-1])), method=settings.get("method"),
                     rtol=settings.get("rtol"), atol=settings.get("atol"), max_step=settings.get("max_step"),
                     first_step=settings.get("first_step"), overrides=dict(result.parameters), t_eval=t_eval)
    if not result.complete:         # (a SimResult is frozen: the cut run is a new one)
        import dataclasses

        keep = rerun.t <= result.t[-1]
        rerun = dataclasses.replace(rerun, t=rerun.t[keep], **{
            group: {name: values[keep] for name, values in getattr(rerun, group).items()}
            for group in ("states", "outputs", "bonds", "variables")})
    return rerun


def atol_limited(result, rtol, atol) -> list:
    """(state, its span over the run) of each state that ``atol`` resolves more than ten times
    more coarsely than ``rtol`` asks (atol > 10 rtol span) while it moves by 10 atol at least: a
    hydraulic chamber's volume in m^3 (1e-6) at the default atol of 1e-9 is resolved to 1e-3 of
    its span, whatever rtol is."""
    try:
        rtol, atol = float(rtol), float(atol)
    except (TypeError, ValueError):
        return []
    limited = []
    for name, values in result.states.items():
        values = np.asarray(values, dtype=float)
        finite = values[np.isfinite(values)]
        span = float(np.ptp(finite)) if finite.size else 0.0
        # (a state that never moves by more than a few atol is at the solver's noise level: tightening
        # atol for it is no remedy, as for the springs of a run stopped after 2 us)
        if 10.0 * atol <= span and atol > 10.0 * rtol * span:
            limited.append((name, span))
    return limited


def _drawn_outward(graph) -> list[str]:
    """The R, C and I elements whose bond leaves them (W304): their laws deliver the power they
    should dissipate or store, so no tolerance closes the balance."""
    names = []
    for element in graph.elements.values():
        if element.kind in ("R", "C", "I") and len(element.bonds) == 1:
            if graph.bond(element.bonds[0]).head != element.name:
                names.append(f"{element.kind} '{element.name}'")
    return names


def _residual_hint(result, settings, graph=None) -> str:
    rtol, atol = settings.get("rtol"), settings.get("atol")
    outward = _drawn_outward(graph) if graph is not None else []
    if outward:
        return (f"{', '.join(outward[:3])}{' and more' if len(outward) > 3 else ''} "
                f"{'is' if len(outward) == 1 else 'are'} drawn with the bond leaving "
                f"{'it' if len(outward) == 1 else 'them'} (W304): a law written for power in then delivers "
                "the power it should dissipate or store, which no tolerance closes; draw the bond towards "
                "the element")
    limited = atol_limited(result, rtol, atol)
    if not limited:
        return (f"the residual is the simulation's accumulated error (rtol={rtol}, atol={atol}); tighten the "
                "tolerances to shrink it")
    name, span = min(limited, key=lambda item: item[1])
    wanted = 10.0 ** math.floor(math.log10(float(rtol) * span))
    others = f" (and {len(limited) - 1} more)" if len(limited) > 1 else ""
    return (f"the residual is the simulation's accumulated error, here set by atol={atol}: '{name}'{others} "
            f"spans only {span:.3g} over the run, which atol resolves to {float(atol) / span:.1e} of that "
            f"whatever rtol ({rtol}) is; set atol = {wanted:.0e} (rtol times its span) in the experiment")


def energy_account(ss, result, *, cycle: float | None = None) -> EnergyAccount:
    """Energies of every element per cycle and the energy balance; see the module docstring.

    ``cycle`` [s]: the window length; None takes the experiment's ``cycle``
    (the whole run if it has none). Raises :class:`AnalysisError` E930 (the
    result is not a run of ``ss``), E931 (fewer than two points), E932 (a
    cycle that is not a positive number).
    """
    graph = ss.graph
    if set(result.states) != set(ss.state_names):
        raise _error("E930", "the simulation result is not a run of this model: its states are "
                             f"{', '.join(result.states) or 'none'}, the model's {', '.join(ss.state_names)}",
                     hint="pass the StateSpace the result was simulated from")
    t = np.asarray(result.t, dtype=float)
    if t.size < 2 or not t[-1] > t[0]:
        raise _error("E931", "the simulation result has no time span to account energy over",
                     hint="simulate past the start time")
    if cycle is None:
        cycle = experiment_cycle(ss, result)
    resimulated = not _at_solver_steps(result)
    steps = steps_of(ss, result)
    # a run on a grid is accounted from the same run at its solver's steps, which may have stopped
    # earlier (over a million steps, E814): the account then covers only that, and says so
    covered = float(np.asarray(steps.t, dtype=float)[-1]) if len(steps.t) else float(t[0])
    truncated = covered < float(t[-1]) - 1e-9 * max(abs(float(t[-1])), 1.0)
    windows = cycle_windows(float(t[0]), covered if truncated else float(t[-1]), cycle)
    if truncated and windows and windows[-1][1] == covered:
        windows[-1] = (windows[-1][0], windows[-1][1], True)

    units = getattr(graph, "si_units", {}) or {}
    # values bound late (--set, an edit of values only): the base's module, given the run's values
    boundaries = sorted({edge for start, end, _ in windows for edge in (start, end)})
    model, trajectory, times, values = _run_nodes(ss, steps, boundaries)
    quadrature = {"steps": int(times.shape[0]), "corrected": int(np.sum(trajectory.corrected)),
                  "hermite": int(np.sum(~trajectory.corrected & ~trajectory.sliding)),
                  "sliding": int(np.sum(trajectory.sliding))}

    # power into each element (per port for two-ports), at the Lobatto nodes
    def power_into(element, port_index):
        bond = graph.bond(element.bonds[port_index])
        product = values[f"{bond.name}.e"] * values[f"{bond.name}.f"]
        return product if bond.head == element.name else -product

    functions = stored_energy_functions(ss, steps.parameters)
    energies = {name: energy for name, energy in functions.items()
                if energy.state_name in model.state_names or energy.state_name in values}
    step_start, step_end = trajectory.ta, trajectory.tb
    if not step_start.size:     # (a run again at its steps that stopped before its first step)
        raise _error("E931", "the simulation result has no solver step to account energy over",
                     hint="simulate past the start time")
    state_bounds = trajectory.states_at_bounds()
    scale = max(abs(windows[-1][1]), 1.0)
    masks = [(step_start >= start - 1e-12 * scale) & (step_end <= end + 1e-12 * scale)
             for start, end, _ in windows]

    def value_at(name, time, at_end):
        """A state (or eliminated state) at a window edge: the end of the step ending there, or the
        start of the step starting there."""
        index = np.argmin(np.abs((step_end if at_end else step_start) - time))
        if name in state_bounds:
            return float(state_bounds[name][1 if at_end else 0][index])
        return float(values[name][index, -1 if at_end else 0])

    event_times = np.array(sorted({float(time) for time, _ in getattr(result, "events", ())}))

    def switch_values(name):
        """The state's values at the run's events: where a law may switch (a hard stop's
        ``if q > gap``), breakpoints of its numeric energy function's quadrature."""
        if not event_times.size or name not in state_bounds:
            return ()
        index = np.clip(np.searchsorted(step_end, event_times), 0, step_end.size - 1)
        return tuple(float(v) for v in np.asarray(state_bounds[name][1])[index] if math.isfinite(v))

    per_element: dict[str, list[ElementEnergy]] = {}
    diagnostics: list[Diagnostic] = []
    if truncated:
        diagnostics.append(Diagnostic(
            "warning", "W932",
            f"the energy account covers t = {float(t[0]):.6g} to {covered:.6g} s of the run's {float(t[0]):.6g} to "
            f"{float(t[-1]):.6g} s: the run at the solver's own steps that it is computed from stopped there "
            f"({getattr(steps, 'message', '') or 'incomplete'})",
            hint="the figures after that time are missing, not zero: shorten the run or loosen its tolerances "
                 "so that it takes fewer steps"))
    for element in graph.elements.values():
        role = ROLES[element.kind]
        ports = [power_into(element, i) for i in range(len(element.bonds))]
        for power in ports:
            bad = ~np.isfinite(power)
            if np.any(bad):
                first = float(np.min(times[bad]))
                raise _error("E934", f"the power into '{element.name}' is not finite from t={first:.6g} s: "
                                     "no energy account for this run",
                             hint="a law gives inf or nan there (W821 names the variable): a division by a "
                                  "parameter that is zero or tiny, or a state out of its range")
        integrals = [_integrals(times, p) for p in ports]
        entries = []
        for mask, (start, end, _) in zip(masks, windows):
            net = [float(np.sum(i[0][mask])) for i in integrals]
            positive = [float(np.sum(i[1][mask])) for i in integrals]
            negative = [float(np.sum(i[2][mask])) for i in integrals]
            work_in = sum(net)
            gross = sum(positive) - sum(negative)
            common = dict(element=element.name, kind=element.kind, role=role, work_in=work_in, gross=gross,
                          unit=units.get(f"energy:{element.name}", "J"))
            if role == "source":
                entries.append(ElementEnergy(**common, supplied=-negative[0], returned=positive[0]))
            elif role == "dissipator":
                entries.append(ElementEnergy(**common, dissipated=work_in))
            elif role == "converter":
                entries.append(ElementEnergy(**common, port_work=(net[0], net[1])))
            elif element.name in energies:
                energy = energies[element.name]
                breaks = switch_values(energy.state_name) if energy.kind == "numeric" else ()
                h0, h1, change = energy.change(value_at(energy.state_name, start, False),
                                               value_at(energy.state_name, end, True), breaks)
                jumps = [energy.change(before[energy.state_name], after[energy.state_name], breaks)[2]
                         for time, before, after in getattr(result, "jumps", ())
                         if start < time <= end and energy.state_name in before]
                if math.isfinite(change):
                    entries.append(ElementEnergy(**common, stored_start=h0, stored_end=h1, stored_change=change,
                                                 energy_function=energy.kind,
                                                 event_change=float(sum(jumps)) if jumps else None))
                else:       # its law left its domain on the way: count the work in instead
                    entries.append(ElementEnergy(**common, net_work_in=work_in))
            else:
                entries.append(ElementEnergy(**common, net_work_in=work_in))
        per_element[element.name] = entries

    result_windows = []
    for index, (start, end, partial) in enumerate(windows):
        entries = tuple(per_element[name][index] for name in graph.elements)
        total = lambda attribute: float(sum(getattr(e, attribute) or 0.0 for e in entries))
        converters = [e for e in entries if e.role == "converter"]
        balance = Balance(
            supplied=total("supplied"), returned=total("returned"), dissipated=total("dissipated"),
            stored_change=total("stored_change"), net_work_in=total("net_work_in"),
            converter_work=float(sum(e.work_in for e in converters)),
            throughput=float(sum(e.gross for e in entries if e.role != "converter")),
            event_change=total("event_change"))
        result_windows.append(Window(index, float(start), float(end), partial, entries, balance))
        for entry in converters:
            if abs(entry.work_in) > 1e-9 * max(entry.gross, 1e-300):
                diagnostics.append(Diagnostic(
                    "warning", "W931", f"two-port '{entry.element}' does not conserve power in cycle {index + 1}: "
                                       f"the work in at its ports sums to {entry.work_in:.3e} J",
                    hint="a transformer's or gyrator's port laws must give p1.e*p1.f = p2.e*p2.f"))
        relative = balance.relative_residual
        if relative is not None and relative > RESIDUAL_TOLERANCE:
            settings = getattr(result, "settings", {}) or {}
            units_of = {e.unit for e in entries}        # a pseudo bond graph's own (K*J), as the table says
            unit = " " + units_of.pop() if len(units_of) == 1 else ""
            diagnostics.append(Diagnostic(
                "warning", "W930",
                f"the energy balance of cycle {index + 1} does not close: residual {balance.residual:.3e}{unit}, "
                f"{relative:.2e} of the throughput {balance.throughput:.6g}{unit}",
                hint=_residual_hint(result, settings, graph)))
    return EnergyAccount(
        model=getattr(graph, "name", ""), experiment=getattr(result, "experiment", None),
        cycle=cycle, windows=tuple(result_windows), complete=bool(result.complete) and not truncated,
        resimulated=resimulated,
        quadrature=quadrature, diagnostics=tuple(diagnostics), energy_recipes=energy_recipes(functions))
