"""The state-space form of a model: what ``equations.derive`` returns.

A :class:`StateSpace` is the contract between the equations stage and its
consumers (code generator, simulator, reports, linearisation). Its expressions
are sympy, in the symbols listed below; every symbol is ``real=True``.

Fields (names are stable):

``graph``, ``causal``
    The :class:`~bondc.model.BondGraph` and :class:`~bondc.causality.CausalGraph`
    it was derived from.
``states``
    ``tuple[StateInfo]``: the independent states, in declaration order
    (storage elements' first, then model-level). Each has ``name``
    (qualified: ``mass.p``, ``spring.q``, ``chamber.P``, model-level ``x``),
    ``symbol``, ``unit_text``, ``initial`` (sympy expression in parameter
    symbols), ``description``, ``element`` (owner or None). States of storage
    elements in derivative causality are not here: they are assigned (see
    ``eliminated``).
``parameters``
    ``dict[name, (Symbol, float)]``: every parameter, with its SI value.
``inputs``
    ``dict[name, (Symbol, Expr)]``: every ``input`` signal, as an expression
    of ``t`` and parameters (other inputs substituted).
``time``
    The symbol ``t``.
``assignments``
    ``tuple[(Symbol, Expr)]`` in causal order: evaluating them one after the
    other computes the inputs, every bond's effort and flow (symbols named
    ``b3.e``/``b3.f`` or ``label.e``), the states of eliminated storage
    elements, and the outputs other expressions use. Each right-hand side
    uses only states, parameters, ``t``, symbols assigned before it, and the
    unknowns of algebraic blocks solved before it.
``algebraic_blocks``
    ``tuple[AlgebraicBlock]``: nonlinear algebraic loops the runtime solves
    numerically: ``unknowns`` (symbols), ``residuals`` (expressions that must
    be 0), ``guesses`` (initial guesses), and ``index``: the block is solved
    after ``assignments[:index]`` and before ``assignments[index]``. Linear
    loops are solved symbolically and appear as ordinary assignments.
``derivatives``
    ``dict[state name, Expr]``: the time derivative of every state, in terms
    of states, parameters, ``t`` and assigned symbols.
``outputs``
    ``dict[name, Expr]``: every ``output``, likewise.
``discontinuities``
    ``tuple[Expr]``: expressions whose zero crossings are potential
    discontinuities (if/Piecewise conditions as ``lhs - rhs``, arguments of
    Abs/sign, differences of Min/Max arguments, ``x - x_i`` for table
    breakpoints, ``x - x0`` for steps), in terms of the same symbols.
``energy``
    ``dict[element, Expr | None]``: for each storage element, the stored
    energy as a function of its state when its law is a polynomial in its
    default ``q``/``p`` state alone (``∫ e dq`` for a C, ``∫ f dp`` for an I,
    from 0); None otherwise (custom states, laws with other variables or
    non-polynomial laws).
``eliminated``
    ``dict[element, Symbol]``: storage elements in derivative causality and
    the symbol of their (assigned) state.
``symbols``
    ``dict[name, Symbol]``: every named symbol (parameters, inputs, outputs,
    states, bond variables, ``t``).
``bond_symbols``
    ``dict[bond number, (effort symbol, flow symbol)]``.
``diagnostics``
    Warnings of the equations stage (W604, W704).

>>> import sympy
>>> x = sympy.Symbol("x", real=True)
>>> a = sympy.Symbol("a", real=True)
>>> ss = StateSpace(graph=None, causal=None, states=(), parameters={}, inputs={}, time=sympy.Symbol("t", real=True),
...                 assignments=((a, 2*x),), derivatives={"x": -a})
>>> ss.substituted(ss.derivatives["x"])
-2*x
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping, Sequence

import sympy

from bondc.symbolic import as_sympy
from bondc import codes

if TYPE_CHECKING:
    import numpy as np

    from bondc.causality import CausalGraph
    from bondc.errors import Diagnostic
    from bondc.model import BondGraph


@dataclass(frozen=True)
class StateInfo:
    name: str                       # qualified: "mass.p", "chamber.P", "x"
    symbol: sympy.Symbol
    unit_text: str | None
    initial: sympy.Expr             # in parameter symbols
    description: str | None = None
    element: str | None = None      # owning storage element; None for a model-level state


@dataclass(frozen=True)
class AlgebraicBlock:
    """Equations solved numerically: find ``unknowns`` with every residual 0."""

    unknowns: tuple[sympy.Symbol, ...]
    residuals: tuple[sympy.Expr, ...]
    guesses: tuple[sympy.Expr, ...]
    index: int                      # solved after assignments[:index]
    nodes: tuple[str, ...] = ()     # elements and junctions of the loop


@dataclass(frozen=True)
class StateSpace:
    graph: BondGraph
    causal: CausalGraph
    states: tuple[StateInfo, ...]
    parameters: Mapping[str, tuple[sympy.Symbol, float]]
    inputs: Mapping[str, tuple[sympy.Symbol, sympy.Expr]]
    time: sympy.Symbol
    assignments: tuple[tuple[sympy.Symbol, sympy.Expr], ...]
    derivatives: Mapping[str, sympy.Expr]
    outputs: Mapping[str, sympy.Expr] = field(default_factory=dict)
    algebraic_blocks: tuple[AlgebraicBlock, ...] = ()
    discontinuities: tuple[sympy.Expr, ...] = ()
    energy: Mapping[str, sympy.Expr | None] = field(default_factory=dict)
    eliminated: Mapping[str, sympy.Symbol] = field(default_factory=dict)
    symbols: Mapping[str, sympy.Symbol] = field(default_factory=dict)
    bond_symbols: Mapping[int, tuple[sympy.Symbol, sympy.Symbol]] = field(default_factory=dict)
    diagnostics: tuple[Diagnostic, ...] = ()
    # when clauses: (label, condition, ((state name, new value), ...)); discrete variables are
    # states whose derivative is 0, set only here
    events: tuple[tuple[str, sympy.Expr, tuple[tuple[str, sympy.Expr], ...]], ...] = ()
    # whether a parameter's value decided anything here (which solution of a law to keep): when
    # not, the equations are those of any other values of the parameters
    values_consulted: bool = False
    # values bound late (pipeline.rebind: --set, a sweep's point): the state space derived without
    # them, whose compiled module this one runs with its parameter values
    bound_base: StateSpace | None = field(default=None, compare=False, repr=False)

    # -- lookups

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.states)

    @property
    def eliminated_names(self) -> tuple[str, ...]:
        """The states of storage elements in derivative causality (``eliminated``), by name."""
        return tuple(symbol.name for symbol in self.eliminated.values())

    @property
    def state_symbols(self) -> tuple[sympy.Symbol, ...]:
        return tuple(s.symbol for s in self.states)

    @property
    def input_symbols(self) -> tuple[sympy.Symbol, ...]:
        return tuple(symbol for symbol, _ in self.inputs.values())

    def symbol(self, name: str) -> sympy.Symbol:
        return self.symbols[name]

    def parameter_values(self, overrides: Mapping[str, float] | None = None) -> dict[sympy.Symbol, float]:
        """Parameter symbol -> SI value, with ``overrides`` (name -> SI value) applied."""
        overrides = dict(overrides or {})
        unknown = sorted(set(overrides) - set(self.parameters))
        if unknown:
            raise KeyError(f"unknown parameter(s): {', '.join(unknown)}")
        return {symbol: float(overrides.get(name, value)) for name, (symbol, value) in self.parameters.items()}

    def initial_values(self, overrides: Mapping[str, float] | None = None) -> dict[str, float]:
        """State name -> initial value (SI), with parameter ``overrides`` applied."""
        numbers = {symbol: sympy.Float(value) for symbol, value in self.parameter_values(overrides).items()}
        return {s.name: float(as_sympy(as_sympy(s.initial).xreplace(numbers)).evalf())
                for s in self.states}

    # -- expansion (linearisation and tests only: the runtime evaluates the assignments)

    def substitution(self, keep: Iterable[sympy.Symbol] = ()) -> dict[sympy.Symbol, sympy.Expr]:
        """Assigned symbol -> its expression in states, parameters, ``t`` (and kept symbols).

        Symbols in ``keep`` (e.g. the input symbols, for linearisation) are not
        expanded. Unknowns of algebraic blocks stay symbols.
        """
        kept = frozenset(keep)
        mapping: dict[sympy.Symbol, sympy.Expr] = {}
        for symbol, rhs in self.assignments:
            if symbol in kept:
                continue
            mapping[symbol] = rhs.xreplace(mapping)
        return mapping

    def substituted(self, expr: object, keep: Iterable[sympy.Symbol] = ()) -> sympy.Expr:
        """``expr`` with every assignment expanded (see :meth:`substitution`)."""
        return as_sympy(expr).xreplace(self.substitution(keep))

    # -- numeric evaluation (analysis and tests; the simulator runs generated code)

    def numeric(self, parameters: Mapping[str, float] | None = None) -> "NumericModel":
        """A compiled numeric evaluator of this state space (see :class:`NumericModel`)."""
        return NumericModel(self, parameters)


class NumericModel:
    """Evaluates a :class:`StateSpace` numerically, in SI, with fixed parameters.

    ``inputs`` (name -> value) given to the methods replace the input signals,
    which is how linearisation holds them as independent variables. Algebraic
    blocks are solved with ``scipy.optimize.root``, warm-started from the last
    solution.
    """

    def __init__(self, ss: StateSpace, parameters: Mapping[str, float] | None = None):
        import numpy
        from sympy.printing.numpy import NumPyPrinter

        from bondc.numeric import NUMERIC_FUNCTIONS

        self.ss = ss
        values = ss.parameter_values(parameters)
        self.parameter_values = values
        numbers = {symbol: sympy.Float(value) for symbol, value in values.items()}
        names: dict[sympy.Symbol, str] = {}     # symbol -> its variable in the code: _v0, _v1, ... and _p0, _p1, ...

        def ident(symbol: sympy.Symbol) -> str:
            if symbol not in names:
                names[symbol] = f"_v{len(names)}"
            return names[symbol]

        for symbol in ss.state_symbols:
            ident(symbol)
        ident(ss.time)
        for symbol, _ in ss.assignments:
            ident(symbol)
        for block in ss.algebraic_blocks:
            for unknown in block.unknowns:
                ident(unknown)
        # parameters are variables of the code (numpy numbers, bound in its namespace): printing
        # through the name table instead of substituting numbers into every expression (each
        # substitution rebuilds the expression: 5 s for a 2000-state model)
        parameter_names = {symbol: f"_p{index}" for index, symbol in enumerate(values)}
        names.update((symbol, name) for symbol, name in parameter_names.items() if symbol not in names)

        # sympy's printers are not annotated: the base class is Any to mypy, nothing to check against
        class _Printer(NumPyPrinter):  # type: ignore[misc]
            def _print_Symbol(self, symbol: sympy.Symbol) -> str:
                return names[symbol]

            def _print_Integer(self, expr: sympy.Integer) -> str:
                # beyond a double's exact integers, numpy would take Python's int as an object
                return str(int(expr)) if abs(int(expr)) < 2 ** 53 else repr(float(expr))

            _print_Dummy = _print_Symbol

        # sums in sympy's own argument order: this code is only run, and sorting every sum is slow
        printer = _Printer({"allow_unknown_functions": True, "fully_qualified_modules": True, "order": "none"})

        def code(value: object) -> str:
            expr = as_sympy(value)
            free = [s for s in expr.free_symbols if s not in names]
            if free:
                raise ValueError(f"unbound symbols {sorted(str(s) for s in free)} in {expr}")
            return str(printer.doprint(expr))

        inputs = {symbol: index for index, (symbol, _) in enumerate(ss.inputs.values())}
        lines = ["def _run(_t, _x, _fixed):"]
        lines.append(f"    {ident(ss.time)} = _t")
        for index, symbol in enumerate(ss.state_symbols):
            lines.append(f"    {ident(symbol)} = _x[{index}]")
        blocks: dict[int, list[tuple[int, AlgebraicBlock]]] = {}
        for number, block in enumerate(ss.algebraic_blocks):
            blocks.setdefault(block.index, []).append((number, block))

        def emit_blocks(position: int) -> None:
            for number, block in blocks.get(position, ()):
                unknowns = ", ".join(ident(u) for u in block.unknowns) + ","
                lines.append(f"    def _residual{number}(_z):")
                lines.append(f"        {unknowns} = _z")
                lines.append(f"        return [{', '.join(code(r) for r in block.residuals)}]")
                lines.append(f"    {unknowns} = _solve({number}, _residual{number})")

        for position, (symbol, rhs) in enumerate(ss.assignments):
            emit_blocks(position)
            target = ident(symbol)
            if symbol in inputs:
                lines.append(f"    {target} = _fixed[{inputs[symbol]}] if _fixed[{inputs[symbol]}] is not None "
                             f"else ({code(rhs)})")
            else:
                lines.append(f"    {target} = {code(rhs)}")
        emit_blocks(len(ss.assignments))
        assigned = [ident(symbol) for symbol, _ in ss.assignments] + [
            ident(u) for block in ss.algebraic_blocks for u in block.unknowns]
        lines.append(f"    _values = [{', '.join(assigned)}]")
        lines.append(f"    _der = [{', '.join(code(ss.derivatives[s.name]) for s in ss.states)}]")
        lines.append(f"    _out = [{', '.join(code(expr) for expr in ss.outputs.values())}]")
        lines.append("    return _values, _der, _out")
        self.source = "\n".join(lines)
        self._guesses = {n: numpy.array([float(as_sympy(g).xreplace(numbers)) for g in b.guesses], dtype=float)
                         for n, b in enumerate(ss.algebraic_blocks)}
        self._first_guesses = {n: guess.copy() for n, guess in self._guesses.items()}
        namespace: dict[str, Any] = {"numpy": numpy, "functools": __import__("functools"), "_solve": self._solve_block}
        namespace.update(NUMERIC_FUNCTIONS)
        namespace.update({name: numpy.float64(values[symbol]) for symbol, name in parameter_names.items()})
        exec(compile(self.source, "<bondc numeric model>", "exec"), namespace)  # safe: generated from sympy, not model text
        self._run: Callable[[float, list[float], tuple[float | None, ...]], tuple[Any, Any, Any]] = namespace["_run"]
        self._assigned_names = [symbol.name for symbol, _ in ss.assignments] + [
            u.name for block in ss.algebraic_blocks for u in block.unknowns]
        self._input_names = list(ss.inputs)

    def _solve_block(self, number: int, residual: Callable[[np.ndarray], Sequence[float]]) -> tuple[float, ...]:
        import numpy

        from bondc.runtime.loops import solve_loop

        # (the engine's loop solver is not annotated: its contract, as this model calls it)
        solve: Callable[[Callable[[np.ndarray], np.ndarray], np.ndarray, np.ndarray], np.ndarray | None] = solve_loop
        x = solve(lambda z: numpy.asarray(residual(z), dtype=float), self._guesses[number],
                       self._first_guesses[number])
        if x is None:
            from bondc.errors import AnalysisError, Diagnostic

            block = self.ss.algebraic_blocks[number]
            through = ", ".join(block.nodes) or ", ".join(u.name for u in block.unknowns)
            raise AnalysisError(Diagnostic(
                "error", codes.E941, f"cannot evaluate the state equations at the operating point: the algebraic loop "
                                 f"through {through} has no solution found there",
                hint="linearise at another point (another initial value, or --at equilibrium), or break the loop "
                     "with a small storage element"))
        self._guesses[number] = x
        return tuple(float(v) for v in x)

    def _call(self, t: float, x: Sequence[float] | np.ndarray, inputs: Mapping[str, float] | None) -> tuple[Any, Any, Any]:
        import numpy

        from bondc.errors import AnalysisError, DataError, Diagnostic
        from bondc.runtime.signals import CsvError

        # numpy evaluates every branch of a Piecewise: the unused ones may warn.
        with numpy.errstate(all="ignore"):
            try:
                return self._run(float(t), list(x), self._fixed(inputs))
            except CsvError as error:           # as a simulation says it (E804)
                raise DataError(Diagnostic("error", codes.E804, f"cannot read a measured signal: {error}")) from None
            except (ArithmeticError, ValueError, TypeError) as error:   # a division by zero, a domain error
                raise AnalysisError(Diagnostic(
                    "error", codes.E941, f"cannot evaluate the state equations at the operating point (t = {float(t):g}): "
                                     f"{error}",
                    hint="linearise at another point (another initial value, or --at equilibrium), or check the "
                         "parameters a law divides by")) from None

    def _fixed(self, inputs: Mapping[str, float] | None) -> tuple[float | None, ...]:
        given = inputs or {}
        unknown = set(given) - set(self._input_names)
        if unknown:
            raise KeyError(f"unknown input(s): {', '.join(sorted(unknown))}")
        return tuple(None if name not in given else float(given[name]) for name in self._input_names)

    def initial_state(self) -> np.ndarray:
        import numpy

        overrides = {name: self.parameter_values[symbol] for name, (symbol, _) in self.ss.parameters.items()}
        return numpy.array(list(self.ss.initial_values(overrides).values()), dtype=float)

    def derivatives(self, t: float, x: Sequence[float] | np.ndarray, inputs: Mapping[str, float] | None = None) -> np.ndarray:
        import numpy

        return numpy.array([float(v) for v in self._call(t, x, inputs)[1]], dtype=float)

    def outputs(self, t: float, x: Sequence[float] | np.ndarray, inputs: Mapping[str, float] | None = None) -> dict[str, float]:
        out = self._call(t, x, inputs)[2]
        return {name: float(v) for name, v in zip(self.ss.outputs, out)}

    def values(self, t: float, x: Sequence[float] | np.ndarray, inputs: Mapping[str, float] | None = None) -> dict[str, float]:
        """Every assigned symbol (by name), ``der(state)`` and output at one point."""
        assigned, der, out = self._call(t, x, inputs)
        result = {name: float(v) for name, v in zip(self._assigned_names, assigned)}
        result.update({f"der({s.name})": float(v) for s, v in zip(self.ss.states, der)})
        result.update({name: float(v) for name, v in zip(self.ss.outputs, out)})
        return result
