"""Stored-energy functions: a :class:`~bondc.statespace.StateSpace` and parameter values ->
storage element -> :class:`_StoredEnergy` (analytic from ``StateSpace.energy``, or numeric: the
law integrated over the state by Gauss-Legendre rules and scipy's ``quad``), and their
recipes, rebuilt without sympy for the compile cache (:func:`energy_from_recipe`).
"""

from __future__ import annotations

import functools
from typing import Any, Callable, Mapping

import numpy as np

# The quadrature of a numeric energy function over many pieces at once: Gauss-Legendre rules of 10
# and 21 points on [-1, 1] (numpy's leggauss; exact for polynomials to degree 19 and 41), the
# second the piece's integral, their difference its error estimate.
GAUSS_NODES, GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(10)
FINE_NODES, FINE_WEIGHTS = np.polynomial.legendre.leggauss(21)
_PIECE_NODES = np.concatenate([GAUSS_NODES, FINE_NODES])


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
    namespace: dict[str, object] = {"__builtins__": {}}
    for name, (origin, attribute) in names.items():
        namespace[name] = (NUMERIC_FUNCTIONS[attribute] if origin == "bondc"
                           else functools.reduce if origin == "functools"
                           else getattr(np, attribute) if attribute else np)
    exec(compile(text, "<bondc energy function>", "exec"), namespace)  # safe: sympy's printing of an AST-built law, no model text
    made: list[Callable[..., Any]] = [value for name, value in namespace.items()
                                      if name not in names and callable(value)]
    function = made[0]
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
