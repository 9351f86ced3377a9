"""Linearisation: :class:`~bondc.statespace.StateSpace` -> :class:`Linearization`.

``dx/dt = f(x, u, t)``, ``y = g(x, u, t)`` are linearised at an operating
point: ``A = df/dx``, ``B = df/du``, ``C = dg/dx``, ``D = dg/du``. The inputs
``u`` are the model's ``input`` signals, treated as independent variables and
held at their value at time ``time``; ``t`` itself is held at ``time``.

Operating point (``at``):

- ``"initial"``: the initial state;
- ``"equilibrium"``: ``f(x, u(time), time) = 0`` solved from the initial state
  with ``scipy.optimize.least_squares`` (Levenberg-Marquardt). A rate counts as
  zero when it is negligible (1e-8) next to the terms it balances,
  ``sum_j |A_ij x_j| + sum_k |B_ik u_k|``; an initial state that already
  satisfies this is taken as it is. States on which no derivative depends
  (a zero column of ``A``: pure integrators such as a position ``x`` with
  ``der(x) = mass.f``) make ``A`` singular and leave the equilibrium
  undetermined along them; they are *held* at their initial value (listed in
  ``held``) and the other states are solved for, with every state equation
  (theirs included, e.g. ``mass.f = 0``) as a residual. They stay in A, B, C,
  D and contribute zero eigenvalues. Where Newton's method cannot leave a
  region in which a law is flat (a relief valve closed at the start, a spring
  inside its backlash gap, whose Jacobian column is zero only there), the
  states the derivatives depend on near the start are followed along the
  state equations, with the inputs held (scipy's LSODA), to where they settle,
  and solved again from there. If the residual cannot be driven to zero
  (a constant force on a free mass) :class:`~bondc.errors.AnalysisError`
  ``E940`` is raised.

Discrete variables (set only by ``when`` clauses) are constants between
events: both operating points hold them at their initial value (a note says
which), and they are not states of the linear model: A, B, C, D and the
eigenvalues are those of the continuous states.

A, B, C and D are in SI units, outputs declared in other units included (a
note names them with their factor).

The Jacobians are computed in forward mode over the assignment sequence: each
assignment's symbolic partial derivatives (sympy), evaluated numerically at
the operating point and chained, so sizes stay linear in the model; algebraic
blocks are differentiated implicitly (the chain rule of :mod:`bondc.jacobian`, which the
generated module's analytic Jacobian uses too). Dirac impulses of derivatives of
``sign``/``step`` are dropped (a kink's derivative is taken from one side).

>>> from bondc.causality import assign_causality
>>> from bondc.equations import derive
>>> from bondc.parse import parse_text
>>> from bondc.semantic import build
>>> text = "model M\\n param m = 2\\n param k = 800\\n param b = 12\\n Se force : e = 10\\n" \\
...        " I mass : f = p/m\\n C spring : e = k*q\\n R damper : e = b*f\\n 1 j\\n" \\
...        " force -> j\\n j -> mass\\n j -> spring\\n j -> damper\\nend\\n"
>>> lin = linearize(derive(assign_causality(build(parse_text(text, "m.bg"))[0])), at="equilibrium")
>>> lin.natural_frequencies.round(6).tolist(), lin.damping_ratios.round(6).tolist()
([20.0, 20.0], [0.15, 0.15])
>>> lin.x0.tolist()
[0.0, 0.0125]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import sympy

from bondc.errors import AnalysisError, Diagnostic
from bondc.jacobian import NUMERIC, Sensitivities
from bondc.statespace import StateSpace
from bondc.symbolic import as_sympy, partial_derivative, strip_impulses
from bondc import codes

AT = ("initial", "equilibrium")


@dataclass(frozen=True)
class Linearization:
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    eigenvalues: np.ndarray             # complex, sorted by real part, then imaginary part;
                                        # parts below 1e-12 of the spectral radius are set to 0
    natural_frequencies: np.ndarray     # |lambda| [rad/s]
    damping_ratios: np.ndarray          # -Re(lambda)/|lambda|; nan for lambda = 0
    time: float
    at: str
    x0: np.ndarray                      # operating point: states
    u0: np.ndarray                      # operating point: inputs
    held: tuple[str, ...] = ()          # states held at their initial value (equilibrium)
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_json(self) -> dict:
        def number(value):
            value = float(value)
            return value if math.isfinite(value) else None

        def matrix(m):
            return [[number(v) for v in row] for row in np.asarray(m)]

        return {
            "states": list(self.states),
            "inputs": list(self.inputs),
            "outputs": list(self.outputs),
            "A": matrix(self.A),
            "B": matrix(self.B),
            "C": matrix(self.C),
            "D": matrix(self.D),
            "eigenvalues": [[number(v.real), number(v.imag)] for v in self.eigenvalues],
            "natural_frequencies": [number(v) for v in self.natural_frequencies],
            "damping_ratios": [number(v) for v in self.damping_ratios],
            "time": self.time,
            "at": self.at,
            "operating_point": {
                "states": {name: number(v) for name, v in zip(self.states, self.x0)},
                "inputs": {name: number(v) for name, v in zip(self.inputs, self.u0)},
            },
            "held": list(self.held),
            "notes": list(self.notes),
        }

    def to_text(self) -> str:
        lines = [f"linearised at {self.at} point, t = {self.time:g} s"]
        lines += ["", "operating point"]
        lines += [f"  {name} = {value:.6g}" for name, value in zip(self.states, self.x0)]
        lines += [f"  {name} = {value:.6g}  (input)" for name, value in zip(self.inputs, self.u0)]
        if self.held:
            lines.append(f"  held at initial value: {', '.join(self.held)}")
        for title, m, rows, cols in (("A", self.A, self.states, self.states), ("B", self.B, self.states, self.inputs),
                                     ("C", self.C, self.outputs, self.states), ("D", self.D, self.outputs, self.inputs)):
            lines += ["", f"{title} ({len(rows)} x {len(cols)})"]
            if not rows or not cols:
                lines.append("  (empty)")
                continue
            if len(cols) > _TABLE_COLUMNS:
                # a large model: its non-zero entries, row by row (a dense table would be N^2 cells)
                matrix = np.asarray(m)
                entries = list(zip(*np.nonzero(matrix)))
                lines.append(f"  {len(entries)} non-zero entries (row, column, value)")
                lines += [f"  {rows[i]}  {cols[j]}  {matrix[i, j]:.6g}" for i, j in entries]
                continue
            width = max(12, *(len(c) for c in cols))
            rwidth = max(len(r) for r in rows)
            lines.append(" " * (rwidth + 2) + "".join(c.rjust(width + 2) for c in cols))
            for name, row in zip(rows, np.asarray(m)):
                lines.append(f"  {name.ljust(rwidth)}" + "".join(f"{v:.6g}".rjust(width + 2) for v in row))
        lines += ["", "eigenvalues            natural frequency  damping ratio"]
        for value, wn, zeta in zip(self.eigenvalues, self.natural_frequencies, self.damping_ratios):
            text = f"{value.real:.6g}" + (f" {'+' if value.imag >= 0 else '-'} {abs(value.imag):.6g}j"
                                          if value.imag else "")
            zeta_text = f"{zeta:.4g}" if math.isfinite(zeta) else "-"
            lines.append(f"  {text.ljust(22)} {wn:.6g} rad/s".ljust(45) + f"  {zeta_text}")
        lines += [f"note: {note}" for note in self.notes]
        return "\n".join(lines) + "\n"


#: Matrices with more columns than this print as their non-zero entries.
_TABLE_COLUMNS = 12


# ----------------------------------------------------------------- jacobians

class _Jacobian:
    """Forward-mode derivatives of the assignments w.r.t. states and inputs."""

    def __init__(self, ss: StateSpace, parameter_values: Mapping):
        self.ss = ss
        self.parameter_values = {s: sympy.Float(v) for s, v in parameter_values.items()}
        self.state_symbols = ss.state_symbols
        self.input_symbols = ss.input_symbols
        self.partials: list = []
        for symbol, rhs in ss.assignments:
            self.partials.append(self._partials(rhs) if symbol not in self.input_symbols else ())
        self.block_partials = [
            [self._partials(r) for r in block.residuals] for block in ss.algebraic_blocks]
        self.derivative_partials = [self._partials(ss.derivatives[name]) for name in ss.state_names]
        self.output_partials = [self._partials(expr) for expr in ss.outputs.values()]

    def _partials(self, expr):
        """``(symbol, partial, value)`` per variable ``expr`` depends on; ``value`` is the partial's
        number when it depends on parameters only (most of a large model's), else None."""
        expr = as_sympy(expr)
        symbols = sorted((s for s in expr.free_symbols if s not in self.parameter_values and s != self.ss.time),
                         key=lambda s: s.name)
        out = []
        for s in symbols:
            partial = _staircases_flat(strip_impulses(partial_derivative(expr, s, sympy.diff)))
            constant = None
            if not (partial.free_symbols - set(self.parameter_values)):
                constant = self._value(partial, {})
            out.append((s, partial, constant))
        return tuple(out)

    def _value(self, expr, values) -> float:
        number = None
        try:
            number = as_sympy(expr).xreplace(values).xreplace(self.parameter_values)
            number = as_sympy(number).evalf()
            return float(number)
        except (TypeError, ValueError) as error:
            # zoo; a comparison of a complex value (sqrt of a tiny negative number)
            text = str(expr)
            text = text if len(text) <= 160 else text[:150] + " ..."
            value = f" ({number})" if number is not None and len(str(number)) <= 40 else ""
            raise AnalysisError(Diagnostic("error", codes.E941, f"cannot evaluate the derivative {text} at the "
                                                            f"operating point{value}",
                                           hint="linearise at another point (another initial value, or --at "
                                                "equilibrium), or make the law smooth at the operating "
                                                "point")) from error

    def __call__(self, values: Mapping) -> tuple[np.ndarray, np.ndarray]:
        """[A B] and [C D] at a point given by ``values`` (symbol -> float, incl. t).

        Each variable's gradient is kept sparse ({column: value}): a chain of N sections has
        gradients of a few entries each, where dense rows would take N^2 memory."""
        ss = self.ss
        n, m = len(self.state_symbols), len(self.input_symbols)
        seeds = {symbol: i for i, symbol in enumerate(self.state_symbols)}
        seeds.update({symbol: n + j for j, symbol in enumerate(self.input_symbols)})
        sensitivities = Sensitivities(seeds, NUMERIC)
        gradient = sensitivities.rows
        numeric = {s: sympy.Float(v) for s, v in values.items()}

        def value(partial, constant):
            return constant if constant is not None else self._value(partial, numeric)

        def chain(partials):
            return sensitivities.chain((symbol, lambda partial=partial, constant=constant: value(partial, constant))
                                       for symbol, partial, constant in partials)

        blocks: dict[int, list[int]] = {}
        for number, block in enumerate(ss.algebraic_blocks):
            blocks.setdefault(block.index, []).append(number)

        def solve_blocks(position):
            for number in blocks.get(position, ()):
                block = ss.algebraic_blocks[number]
                unknowns = list(block.unknowns)
                jac_u = np.zeros((len(unknowns), len(unknowns)))
                rhs = np.zeros((len(unknowns), n + m))
                for row, partials in enumerate(self.block_partials[number]):
                    def others(partials=partials, row=row):
                        """The partials by the block's other symbols; dR/dz into jac_u on the way (in
                        the partials' order: the first that cannot be evaluated is the one reported)."""
                        for symbol, partial, constant in partials:
                            if symbol in unknowns:
                                jac_u[row, unknowns.index(symbol)] = value(partial, constant)
                            else:
                                yield symbol, partial, constant

                    for column, entry in chain(others()).items():
                        rhs[row, column] = 0.0 - entry      # (0.0 -: no -0.0, as 0.0 - a - b gave)
                solution = np.linalg.solve(jac_u, rhs)
                for k, unknown in enumerate(unknowns):
                    gradient[unknown] = {int(c): float(solution[k, c]) for c in np.flatnonzero(solution[k])}

        for position, ((symbol, _), partials) in enumerate(zip(ss.assignments, self.partials)):
            solve_blocks(position)
            if symbol in gradient:      # an input, held as an independent variable
                continue
            gradient[symbol] = chain(partials)
        solve_blocks(len(ss.assignments))

        def rows(all_partials):
            matrix = np.zeros((len(all_partials), n + m))
            for row, partials in enumerate(all_partials):
                for column, entry in chain(partials).items():
                    matrix[row, column] = entry
            return matrix

        return rows(self.derivative_partials), rows(self.output_partials)


# --------------------------------------------------------------------- stage

def linearize(ss: StateSpace, *, time: float = 0.0, at: str = "initial",
              parameters: Mapping[str, float] | None = None) -> Linearization:
    """Linearise ``ss`` at its initial state or an equilibrium, inputs held at their value at ``time``."""
    if at not in AT:
        raise ValueError(f"at must be one of {', '.join(AT)}, not {at!r}")
    numeric = ss.numeric(parameters)
    parameter_values = ss.parameter_values(parameters)
    jacobian = _Jacobian(ss, parameter_values)
    n, m = len(ss.states), len(ss.inputs)
    x0 = numeric.initial_state()
    first = numeric.values(time, x0)
    inputs = {name: first[name] for name in ss.inputs}
    u0 = np.array([inputs[name] for name in ss.inputs], dtype=float)

    def point(x):
        values = numeric.values(time, x, inputs)
        out = {ss.symbols[name]: value for name, value in values.items() if name in ss.symbols}
        for block in ss.algebraic_blocks:
            for unknown in block.unknowns:
                out[unknown] = values[unknown.name]
        out.update({symbol: float(v) for symbol, v in zip(ss.state_symbols, x)})
        out[ss.time] = float(time)
        return out

    held: tuple[str, ...] = ()
    notes: list[str] = []
    x = x0
    # discrete variables are constants between the events that set them: held at their initial
    # value, not unknowns of the equilibrium (der = 0 holds for any value), and not states of the
    # linear model (each would add an eigenvalue 0, a pure integrator that is not there)
    names = set(getattr(ss.graph, "discrete", None) or ())
    discrete = [i for i, name in enumerate(ss.state_names) if name in names]
    if at == "equilibrium" and n:
        x, held = _equilibrium(ss, numeric, jacobian, point, x0, time, inputs, fixed=discrete)
        held = tuple(name for name in held if name not in names)
        if held:
            notes.append(f"no state equation depends on {', '.join(held)}: held at the initial value")
    if discrete:
        notes.append("discrete variables held at their initial value, not states of the linear model: "
                     + ", ".join(f"{name} = {x[i]:.6g}" for i, name in enumerate(ss.state_names) if name in names))
    outputs = getattr(ss.graph, "outputs", None) or {}
    scaled = [(name, outputs[name]) for name in ss.outputs
              if name in outputs and abs((outputs[name].display_factor or 1.0) - 1.0) > 1e-12]
    if scaled:
        notes.append("A, B, C, D are in SI units; the rows of C and D of outputs declared in other units are "
                     "SI values too: " + ", ".join(f"{name} (declared in {out.unit_text}: 1 {out.unit_text} = "
                                                   f"{out.display_factor:.6g} SI)" for name, out in scaled))
    f_rows, g_rows = jacobian(point(x))
    _require_finite(f_rows, [f"der({name})" for name in ss.state_names], g_rows, list(ss.outputs),
                    list(ss.state_names) + list(ss.inputs), time)
    state_names = ss.state_names        # a property that builds the tuple: once, not per state
    held_discrete = set(discrete)
    keep = [i for i in range(n) if i not in held_discrete]
    A, B = f_rows[keep][:, keep], f_rows[keep, n:]
    C, D = g_rows[:, keep], g_rows[:, n:]
    n = len(keep)
    eigenvalues = np.linalg.eigvals(A) if n else np.zeros(0, dtype=complex)
    if n:
        # Round-off-sized parts (a pure integrator's 1e-26) are zero: no spurious instability.
        tiny = 1e-12 * float(np.max(np.abs(eigenvalues)))
        eigenvalues = np.where(np.abs(eigenvalues.real) <= tiny, 0.0, eigenvalues.real) + 1j * np.where(
            np.abs(eigenvalues.imag) <= tiny, 0.0, eigenvalues.imag)
        eigenvalues = np.sort_complex(eigenvalues)
    magnitude = np.abs(eigenvalues)
    with np.errstate(divide="ignore", invalid="ignore"):
        damping = np.where(magnitude > 0, -eigenvalues.real / np.where(magnitude > 0, magnitude, 1), np.nan)
    return Linearization(
        states=tuple(state_names[i] for i in keep), inputs=tuple(ss.inputs), outputs=tuple(ss.outputs),
        A=A, B=B.reshape(n, m), C=C, D=D.reshape(len(ss.outputs), m),
        eigenvalues=eigenvalues, natural_frequencies=magnitude, damping_ratios=damping,
        time=float(time), at=at, x0=np.asarray(x, dtype=float)[keep], u0=u0, held=held, notes=tuple(notes))


def _staircases_flat(partial):
    """``floor`` and ``ceil`` are constant between their jumps (whose impulses no linear model
    carries, as a step's): their derivatives, which sympy keeps unevaluated, are 0."""
    if not partial.has(sympy.Derivative):
        return partial
    flat = partial.replace(lambda e: isinstance(e, sympy.Derivative) and isinstance(e.expr, (sympy.floor,
                                                                                            sympy.ceiling)),
                           lambda e: sympy.Integer(0))
    # the chain rule through an argument (floor(q/0.3) of a mod) leaves Subs(0, ...): 0 too
    return flat.replace(lambda e: isinstance(e, sympy.Subs) and e.expr.is_number, lambda e: e.expr)


def _require_finite(f_rows, f_names, g_rows, g_names, columns, time) -> None:
    """E941 for the first partial derivative that is not a finite number at the operating point
    (a law with an infinite slope there: d/dp sqrt(abs(p)) at p = 0), naming it."""
    for rows, names in ((f_rows, f_names), (g_rows, g_names)):
        bad = np.argwhere(~np.isfinite(rows))
        if bad.size:
            row, column = (int(i) for i in bad[0])
            raise AnalysisError(Diagnostic(
                "error", codes.E941, f"the partial derivative of {names[row]} with respect to {columns[column]} is "
                                 f"{rows[row, column]} at the operating point (t = {time:g}): a law with an infinite "
                                 "slope there, or a parameter that is zero or tiny",
                hint="linearise at another point (another initial value, or --at equilibrium), or make the law "
                     "smooth at the operating point (a linear band around zero flow)"))


def _settle(rates, start):
    """Integrate ``dz/dtau = rates(z)`` (scipy's LSODA) until the rates vanish; the state there, or
    None when it does not settle (or runs away) within 1e6 of the slowest time scale tried."""
    from scipy.integrate import solve_ivp

    z = np.array(start, dtype=float)
    origin = z.copy()
    limit = 1e9 * (1.0 + float(np.max(np.abs(z), initial=0.0)))

    def runaway(tau, y):
        """Positive while the state stays within ``limit`` of the start (the runaway test of
        ``_equilibrium``'s solve); a terminal event where it leaves: a blow-up in finite time (a
        plate snapping through its gap past pull-in), which LSODA would otherwise follow with ever
        shorter steps, through inf and nan, without end."""
        size = float(np.max(np.abs(y - origin)))
        return limit - size if np.isfinite(size) else -1.0

    runaway.terminal = True
    horizon = 1.0
    for _ in range(7):
        with np.errstate(all="ignore"):
            solution = solve_ivp(lambda tau, y: rates(y), (0.0, horizon), z, method="LSODA", rtol=1e-10,
                                 atol=1e-14 * (1.0 + np.abs(z)), events=runaway)
        if solution.status != 0 or not np.all(np.isfinite(solution.y[:, -1])):
            return None
        end = solution.y[:, -1]
        if np.max(np.abs(end - z)) <= 1e-12 * (1.0 + np.max(np.abs(end))):
            return end
        z, horizon = end, 10.0 * horizon
    return z


def _equilibrium(ss, numeric, jacobian, point, x0, time, inputs, fixed=()):
    """The equilibrium near ``x0`` and the states held there; the states ``fixed`` (discrete
    variables) are never solved for."""
    from scipy.optimize import least_squares

    n = len(x0)
    x_start = np.asarray(x0, dtype=float)
    u = np.array(list(inputs.values()), dtype=float)

    def unbalanced(x):
        """Rates that are not negligible next to the terms they balance:
        |f_i| > 1e-8 * (sum_j |A_ij x_j| + sum_k |B_ik u_k|) + 1e-12."""
        rates = numeric.derivatives(time, x, inputs)
        rows = jacobian(point(x))[0]
        scale = np.abs(rows[:, :n]) @ np.abs(x) + np.abs(rows[:, n:]) @ np.abs(u)
        return np.abs(rates) > 1e-8 * scale + 1e-12, rates

    def attempt(free, settle):
        """Solve for the states ``free`` (the others held); (x, runaway, bad, rates)."""
        def full(z):
            x = np.array(x_start)
            x[free] = z
            return x

        def residual(z):
            return numeric.derivatives(time, full(z), inputs)

        def jac(z):
            return jacobian(point(full(z)))[0][:, :n][:, free]

        def solve(initial):
            z = least_squares(residual, initial, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                              max_nfev=2000).x if free else initial
            return z, not np.all(np.isfinite(z)) or (
                bool(free) and np.max(np.abs(z - initial)) > 1e9 * (1.0 + float(np.max(np.abs(initial)))))

        start = x_start[free]
        if settle:
            # Newton's method cannot leave a region where the law is flat (a closed relief valve, a
            # backlash gap): follow the motion the state equations give, with the inputs held, to
            # where it settles, and solve from there
            start = _settle(lambda z: residual(z)[free], start)
            if start is None:
                return None
        z, runaway = solve(start)
        bad, rates = unbalanced(full(z)) if not runaway else (None, None)
        return full(z), runaway, bad, rates

    def columns_at(x):
        return np.any(jacobian(point(x))[0][:, :n] != 0, axis=0)

    # States on which no derivative depends at the start (pure integrators) are held.
    columns = columns_at(x_start)
    columns[list(fixed)] = False
    free = [i for i in range(n) if columns[i]]
    state_names = ss.state_names        # a property that builds the tuple: once, not per state
    held = tuple(state_names[i] for i in range(n) if not columns[i])
    bad, rates = unbalanced(x_start)
    if not bad.any():
        return x_start, held          # already at rest: do not wander along flat directions
    x, runaway, bad, rates = attempt(free, settle=False)
    if runaway or bad.any():
        # A column that is zero only at the start (a spring inside its backlash gap): sample around
        # the start for the states the derivatives do depend on, and follow the motion to rest.
        rng = np.random.default_rng(0)
        spread = np.maximum(np.abs(x_start), 1.0)
        wider = columns.copy()
        for _ in range(8):
            with np.errstate(all="ignore"):
                sample = jacobian(point(x_start + spread * rng.uniform(-1.0, 1.0, n)))[0][:, :n]
            wider |= np.any(np.nan_to_num(sample) != 0, axis=0)
        wider[list(fixed)] = False
        retry = attempt([i for i in range(n) if wider[i]], settle=True) if wider.any() else None
        if retry is not None and not retry[1] and not retry[2].any():
            x, runaway, bad, rates = retry
            at_rest = columns_at(x)
            held = tuple(state_names[i] for i in range(n) if not at_rest[i] and not wider[i])
    if runaway or bad.any():
        detail = ": the solver ran away" if runaway else ", ".join(
            f"der({state_names[i]}) stays {rates[i]:.3g}" for i in np.flatnonzero(bad))
        raise AnalysisError(Diagnostic(
            "error", codes.E940,
            f"no equilibrium found near the initial state with the inputs held at t = {time:g} s"
            + (detail if runaway else f" ({detail})"),
            hint="the system may have no equilibrium (e.g. a constant force on a free mass); "
                 "linearise at the initial point instead"))
    return x, held
