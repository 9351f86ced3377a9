"""Code generation: :class:`~bondc.statespace.StateSpace` -> standalone Python module source.

:func:`emit` freezes the model's discontinuities (:mod:`bondc.codegen.freeze`),
differentiates the frozen assignments in forward mode for the analytic
Jacobian, runs common-subexpression elimination, prints every expression
through :class:`~bondc.codegen.printer.BondcPrinter`, and appends the model
code to a verbatim copy of :mod:`bondc.runtime`. The result imports only
numpy, scipy and the standard library, runs where bondc is not installed and
is byte-identical for the same input (no hashes, dates or absolute paths).

The module provides ``STATE_NAMES``, ``OUTPUT_NAMES``, ``PARAMETERS``,
``x0(p)``, ``rhs(t, x, p)``, ``jacobian(t, x, p)``, ``outputs(t, x, p)``,
``modes(t, x, p)``, ``event_functions(p)`` (one continuous g(t, x) per switch,
zero where that law switches, for ``solve_ivp(events=...)``),
``simulate(t_end, p=None, t_eval=None, **solver_options)`` and a ``__main__``
that writes csv. ``p`` is None (the defaults), a dict of
overrides (parameters defined by others, ``DERIVED_PARAMETERS``, are then
recomputed unless given too) or an array in the order of ``PARAMETERS``
(taken as it is). Names like ``mass.p`` become the identifiers ``mass_p``
(``.`` and other non-identifier characters
-> ``_``; a name that starts with ``_`` gets a ``u`` in front; a clash with a
keyword, a runtime name or an earlier identifier gets ``_`` appended);
``STATE_NAMES`` and the other name tuples keep the qualified names.

Jacobian, forward mode: each assignment ``a_i = E_i(...)`` gets the row
``da_i/dx = sum_s dE_i/ds * ds/dx`` over the assigned symbols and states ``s``
it uses, kept sparse (one symbol per non-zero entry), so its size grows
linearly with the model. An algebraic block ``R(z) = 0`` contributes
``dz/dx = -(dR/dz)^-1 dR/dx`` (implicit function theorem), solved numerically.

>>> import sympy
>>> from bondc.statespace import StateInfo, StateSpace
>>> t, q, C = sympy.symbols("t spring.q C", real=True)
>>> ss = StateSpace(graph=None, causal=None, states=(StateInfo("spring.q", q, None, sympy.Integer(1)),),
...                 parameters={"C": (C, 2.0)}, inputs={}, time=t, assignments=(), derivatives={"spring.q": -q/C})
>>> namespace = {}
>>> exec(emit(ss, source="decay.bg"), namespace)
>>> namespace["STATE_NAMES"], float(namespace["rhs"](0.0, [1.0])[0])
(('spring.q',), -0.5)
"""

from __future__ import annotations

import ast as _python_ast
import builtins
import functools
import keyword
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import sympy

from bondc import __version__
from bondc.codegen.freeze import Freezer
from bondc.codegen.printer import BondcPrinter, relative_data_path
from bondc.symbolic import Csv, Table

RUNTIME_PATH = Path(__file__).resolve().parent.parent / "runtime.py"
ARGUMENTS = ("t", "x", "p", "m")
#: Module-level names of the generated model code (besides the runtime's).
MODULE_NAMES = (
    "STATE_NAMES", "STATE_UNITS", "OUTPUT_NAMES", "VARIABLE_NAMES", "VARIABLE_LAWS", "BOND_VARIABLES",
    "PARAMETERS", "DERIVED_PARAMETERS", "SWITCHES", "EVENT_SWITCHES", "SWITCH_DEPENDS", "DEFAULTS",
    "MODEL_NAME", "SOURCE_FILE", "DATA_DIR", "VECTORIZED", "x0", "rhs", "jacobian", "outputs", "variables",
    "modes", "event_functions", "simulate", "main", "_derive_parameters", "_rhs", "_jac", "_outputs", "_variables", "_switches",
    "_time_breaks", "_MODEL",
)
_INDENT = "    "
_LAW_LIMIT = 200


def runtime_source() -> str:
    """The text of ``bondc/runtime.py``, which every generated module carries verbatim."""
    return RUNTIME_PATH.read_text(encoding="utf-8")


@functools.lru_cache(maxsize=4)
def _top_level_names(source: str) -> frozenset[str]:
    names = set()
    for node in _python_ast.parse(source).body:
        if isinstance(node, (_python_ast.FunctionDef, _python_ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, _python_ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, _python_ast.Name))
        elif isinstance(node, (_python_ast.Import, _python_ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return frozenset(names)


class Namer:
    """Deterministic Python identifiers for qualified names (see the module docstring).

    >>> namer = Namer({"m"})
    >>> namer("mass.p"), namer("m"), namer("mass_p"), namer("_x")
    ('mass_p', 'm_', 'mass_p_', 'u_x')
    """

    def __init__(self, reserved=()):
        self.used = set(reserved)

    def __call__(self, name: str) -> str:
        ident = re.sub(r"\W", "_", name, flags=re.ASCII) or "v"
        if ident[0].isdigit() or ident[0] == "_":
            ident = ("v" if ident[0].isdigit() else "u") + ident
        while ident in self.used or keyword.iskeyword(ident):
            ident += "_"
        self.used.add(ident)
        return ident


# ----------------------------------------------------------------- statements


@dataclass
class _Statement:
    """One step of a generated function body, in causal order."""

    kind: str                        # "assign", "block", "block_jac"
    defines: tuple                   # symbols it defines
    exprs: list                      # expressions that go through cse (reduced in place)
    uses: frozenset = frozenset()    # further symbols it reads outside exprs
    data: dict = field(default_factory=dict)


def _assign(symbol, expr) -> _Statement:
    return _Statement("assign", (symbol,), [expr])


def _hide_piecewise(expr, pieces: dict):
    """``expr`` with every outermost Piecewise replaced by a placeholder symbol (recorded in ``pieces``)."""
    if isinstance(expr, sympy.Piecewise):
        if expr not in pieces:
            pieces[expr] = sympy.Symbol(f"_pw{len(pieces)}", real=True)
        return pieces[expr]
    if expr.is_Atom or not expr.args:
        return expr
    args = [_hide_piecewise(arg, pieces) if isinstance(arg, sympy.Basic) else arg for arg in expr.args]
    if all(a is b for a, b in zip(args, expr.args)):
        return expr
    return expr.func(*args)


def _safe_diff(expr, symbol):
    """``d expr / d symbol`` with bondc's opaque signals (free of ``symbol``) held as constants."""
    if symbol not in expr.free_symbols:
        return sympy.Integer(0)
    opaque = sorted(expr.atoms(Table, Csv), key=sympy.default_sort_key)
    if not opaque:
        return sympy.diff(expr, symbol)
    held = {f: sympy.Symbol(f"_held{i}", real=True) for i, f in enumerate(opaque)}
    if any(symbol in f.free_symbols for f in opaque):
        raise ValueError(f"cannot differentiate a signal of {symbol}")
    derivative = sympy.diff(expr.xreplace(held), symbol)
    return derivative.xreplace({v: k for k, v in held.items()})


# --------------------------------------------------------------------- plan


@dataclass
class _Plan:
    """Everything :func:`emit` prints, decided before printing."""

    ss: object
    states: list
    parameters: list                 # [(name, symbol, value)]
    statements: list                 # frozen assignments and blocks, causal order
    variables: list                  # [(name, symbol, law text)] every assigned symbol and block unknown
    derivatives: list                # frozen, in state order
    outputs: list                    # [(name, frozen expr)]
    switches: list
    time_breaks: list
    derived: list = field(default_factory=list)    # [(name, expr of other parameters)] in declaration order
    jacobian_statements: list = field(default_factory=list)
    jacobian_entries: dict = field(default_factory=dict)   # (row, column) -> expr
    blocks: int = 0


def _derived_parameters(ss) -> list:
    """Parameters defined by other parameters (``Ar = pi/4*(D^2 - d^2)``), as sympy, in declaration order.

    The generated module recomputes them when ``p`` overrides what they depend on.
    """
    from bondc.errors import EquationError
    from bondc.symbolic import Translator

    graph = getattr(ss, "graph", None)
    declared = getattr(graph, "parameters", None)
    if not declared:
        return []
    symbols = {name: symbol for name, (symbol, _) in ss.parameters.items()}

    def resolve(name, node):
        if name in symbols:
            return symbols[name]
        raise EquationError(f"'{name}' is not a parameter")     # the translator falls back for pi

    translator = Translator(resolve, functions=getattr(graph, "functions", {}), time=ss.time)
    derived = []
    for name, parameter in declared.items():
        if name not in symbols:
            continue
        try:
            expr = translator(parameter.expr)
        except Exception:       # not expressible here (a csv value, ...): keep its number
            continue
        if expr.free_symbols and expr.free_symbols <= set(symbols.values()):
            derived.append((name, expr))
    return derived


def _switch_depends(plan: _Plan) -> list:
    """For each switch, the modes its frozen switching function reads (through the laws it uses)."""
    index = {s.mode: s.index for s in plan.switches}
    closure: dict = {}

    def modes_of(exprs):
        found = set()
        for expr in exprs:
            for symbol in expr.free_symbols:
                if symbol in index:
                    found.add(index[symbol])
                elif symbol in closure:
                    found |= closure[symbol]
        return found

    for statement in plan.statements:
        exprs = statement.exprs if statement.kind == "assign" else statement.data["residuals"]
        found = modes_of(exprs)
        for symbol in statement.defines:
            closure[symbol] = found
    return [sorted(modes_of([s.g]) - {s.index}) for s in plan.switches]


def _law_text(expr) -> str:
    text = sympy.sstr(expr)
    return text if len(text) <= _LAW_LIMIT else text[: _LAW_LIMIT - 3] + "..."


def _plan(ss) -> _Plan:
    states = list(ss.states)
    state_symbols = [s.symbol for s in states]
    parameters = [(name, symbol, float(value)) for name, (symbol, value) in ss.parameters.items()]
    freezer = Freezer(ss.time, state_symbols, [symbol for _, symbol, _ in parameters])
    blocks_at: dict[int, list] = {}
    for number, block in enumerate(ss.algebraic_blocks):
        blocks_at.setdefault(block.index, []).append((number, block))
    statements, variables = [], []

    def add_blocks(position):
        for number, block in blocks_at.get(position, ()):
            owner = "algebraic loop " + ", ".join(block.nodes or (str(u) for u in block.unknowns))
            residuals = [freezer.freeze(r, owner) for r in block.residuals]
            unknowns = tuple(block.unknowns)
            uses = frozenset().union(*(r.free_symbols for r in residuals), *(g.free_symbols for g in block.guesses))
            statements.append(_Statement("block", unknowns, [], uses - set(unknowns),
                                         {"number": number, "residuals": residuals, "guesses": list(block.guesses)}))
            for unknown in unknowns:    # not defined to the freezer: never of time only
                variables.append((unknown.name, unknown, f"root of the {owner}"))

    for position, (symbol, expr) in enumerate(ss.assignments):
        add_blocks(position)
        frozen = freezer.freeze(expr, symbol.name)
        freezer.define(symbol, frozen)
        statements.append(_assign(symbol, frozen))
        variables.append((symbol.name, symbol, _law_text(expr)))
    add_blocks(len(ss.assignments))
    derivatives = [freezer.freeze(ss.derivatives[s.name], f"der({s.name})") for s in states]
    outputs = [(name, freezer.freeze(expr, f"output {name}")) for name, expr in ss.outputs.items()]
    plan = _Plan(ss, states, parameters, statements, variables, derivatives, outputs, freezer.switches,
                 freezer.time_breaks, blocks=len(ss.algebraic_blocks), derived=_derived_parameters(ss))
    _forward_jacobian(plan, state_symbols)
    return plan


def _forward_jacobian(plan: _Plan, state_symbols) -> None:
    """Sparse forward-mode derivatives of the frozen statements (see the module docstring)."""
    column = {s: j for j, s in enumerate(state_symbols)}
    rows: dict = {}                  # symbol -> {column: expr}
    statements = []
    counter = [0]

    def sensitivity(symbol):
        if symbol in column:
            return {column[symbol]: sympy.Integer(1)}
        return rows.get(symbol, {})

    def row_of(expr, exclude=()):
        accumulated: dict = {}
        for symbol in sorted(expr.free_symbols - set(exclude), key=sympy.default_sort_key):
            ds = sensitivity(symbol)
            if not ds:
                continue
            partial = _safe_diff(expr, symbol)
            if partial == 0:
                continue
            for j, dsj in ds.items():
                accumulated[j] = accumulated.get(j, sympy.Integer(0)) + partial * dsj
        return {j: v for j, v in sorted(accumulated.items()) if v != 0}

    def name_entries(entries):
        named = {}
        for j, value in entries.items():
            if value.is_Number or value.is_Symbol:
                named[j] = value
            else:
                symbol = sympy.Symbol(f"_d{counter[0]}", real=True)
                counter[0] += 1
                statements.append(_assign(symbol, value))
                named[j] = symbol
        return named

    for statement in plan.statements:
        statements.append(statement)
        if statement.kind == "assign":
            (symbol,), (expr,) = statement.defines, statement.exprs
            rows[symbol] = name_entries(row_of(expr))
        else:   # an algebraic block: dz/dx = -(dR/dz)^-1 dR/dx
            number = statement.data["number"]
            unknowns = statement.defines
            residuals = statement.data["residuals"]
            rz = [[_safe_diff(r, z) for z in unknowns] for r in residuals]
            rx = {}
            for i, r in enumerate(residuals):
                for j, value in row_of(r, exclude=unknowns).items():
                    rx[(i, j)] = value
            columns = sorted({j for _, j in rx})
            outputs = {}
            for l, z in enumerate(unknowns):
                rows[z] = {}
                for j in columns:
                    symbol = sympy.Symbol(f"_Dz{number}_{l}_{j}", real=True)
                    outputs[symbol] = f"_Dz{number}[{l}, {j}]"
                    rows[z][j] = symbol
            exprs = [v for row in rz for v in row] + [rx[key] for key in sorted(rx)]
            statements.append(_Statement("block_jac", tuple(outputs), exprs, frozenset(),
                                         {"number": number, "size": len(unknowns), "rx_keys": sorted(rx),
                                          "texts": outputs, "states": len(column)}))
    entries = {}
    for k, expr in enumerate(plan.derivatives):
        for j, value in row_of(expr).items():
            entries[(k, j)] = value
    plan.jacobian_statements = statements
    plan.jacobian_entries = entries


# ------------------------------------------------------------------ printing


class _Emitter:
    def __init__(self, plan: _Plan, source: str, experiment, module_dir):
        self.plan = plan
        self.source = source
        self.experiment = experiment
        ss = plan.ss
        reserved = set(ARGUMENTS) | set(MODULE_NAMES) | _top_level_names(runtime_source()) | set(dir(builtins))
        namer = Namer(reserved)
        names: dict = {ss.time: "t"}
        for name, symbol, _ in plan.parameters:
            names[symbol] = namer(name)
        for state in plan.states:
            names[state.symbol] = namer(state.name)
        for name, symbol, _ in plan.variables:
            if symbol not in names:
                names[symbol] = namer(name)
        for switch in plan.switches:
            names[switch.mode] = f"m[{switch.index}]"
        for statement in plan.jacobian_statements:
            if statement.kind == "block_jac":
                names.update(statement.data["texts"])
            else:
                for symbol in statement.defines:
                    names.setdefault(symbol, symbol.name)
        self.names = names
        self.modes = frozenset(s.mode for s in plan.switches)
        self.parameter_index = {symbol: i for i, (_, symbol, _) in enumerate(plan.parameters)}
        self.state_index = {s.symbol: i for i, s in enumerate(plan.states)}
        data_paths = {}
        module_dir = Path(module_dir) if module_dir is not None else None
        for item in plan.time_breaks:
            if item.csv is not None and item.csv.path not in data_paths:
                path = item.csv.path
                data_paths[path] = relative_data_path(path, module_dir) if module_dir else Path(path).name
        self.data_paths = data_paths

    def printer(self, extra_frozen=()):
        return BondcPrinter(self.names, mode_symbols=self.modes | set(extra_frozen), data_paths=self.data_paths)

    # -- function bodies

    def body(self, statements, finals):
        """Lines computing ``finals`` from (t, x, p, m) and the printed finals."""
        needed = set().union(*(sympy.sympify(f).free_symbols for f in finals)) if finals else set()
        kept = []
        for statement in reversed(statements):
            if needed & set(statement.defines):
                kept.append(statement)
                needed |= statement.uses
                for expr in statement.exprs:
                    needed |= expr.free_symbols
        kept.reverse()
        exprs = [expr for statement in kept for expr in statement.exprs] + [sympy.sympify(f) for f in finals]
        # cse must not hoist work out of an if's branches (only the active one is evaluated, so its
        # modes are the only ones read): every Piecewise is hidden behind a placeholder first
        pieces: dict = {}
        exprs = [_hide_piecewise(expr, pieces) for expr in exprs]
        replacements, reduced = sympy.cse(exprs, symbols=sympy.numbered_symbols("_c", real=True),
                                          order="canonical", list=True) if exprs else ([], [])
        placeholders = {symbol: piecewise for piecewise, symbol in pieces.items()}
        uses: dict = {}
        for expr in [e for _, e in replacements] + list(reduced):
            for symbol in expr.free_symbols & set(placeholders):
                uses[symbol] = uses.get(symbol, 0) + 1
        once = {symbol: placeholders[symbol] for symbol, count in uses.items() if count == 1}
        replacements = [(symbol, expr.xreplace(once)) for symbol, expr in replacements]
        reduced = [expr.xreplace(once) for expr in reduced]
        shared = [(symbol, placeholders[symbol]) for symbol in sorted(set(uses) - set(once), key=lambda s: s.name)]
        replacements = replacements + shared
        substitutes = dict(replacements)
        order = {symbol: i for i, (symbol, _) in enumerate(replacements)}
        frozen = set()
        for symbol, expr in replacements:       # cse temps that are conditions on modes only
            if expr.free_symbols <= (self.modes | frozen):
                frozen.add(symbol)
        for symbol, _ in replacements:
            self.names.setdefault(symbol, symbol.name)
        printer = self.printer(frozen)
        lines, emitted = [], set()

        def emit_replacements(expr):
            for symbol in sorted(expr.free_symbols & set(substitutes) - emitted, key=order.get):
                if symbol in emitted:
                    continue
                emit_replacements(substitutes[symbol])
                emitted.add(symbol)
                lines.append(f"{self.names[symbol]} = {printer.doprint(substitutes[symbol])}")

        position = 0
        for statement in kept:
            count = len(statement.exprs)
            statement_exprs = reduced[position:position + count]
            position += count
            for expr in statement_exprs:
                emit_replacements(expr)
            lines += self.statement_lines(statement, statement_exprs, printer)
        final_texts = []
        for expr in reduced[position:]:
            emit_replacements(expr)
            final_texts.append(printer.doprint(expr))
        used = set()
        for _, expr in replacements:
            used |= expr.free_symbols
        for expr in reduced:
            used |= expr.free_symbols
        for statement in kept:
            used |= statement.uses
        return lines, final_texts, used

    def statement_lines(self, statement, exprs, printer):
        if statement.kind == "assign":
            return [f"{self.names[statement.defines[0]]} = {printer.doprint(exprs[0])}"]
        if statement.kind == "block":
            number = statement.data["number"]
            unknowns = ", ".join(self.names[u] for u in statement.defines) + ","
            raw = self.printer()
            residuals = ", ".join(raw.doprint(r) for r in statement.data["residuals"])
            guesses = ", ".join(raw.doprint(g) for g in statement.data["guesses"])
            return [f"def _residual{number}(_z):",
                    f"{_INDENT}{unknowns} = _z",
                    f"{_INDENT}return ({residuals},)",
                    f"{unknowns} = solve_block(_residual{number}, {number}, ({guesses},))"]
        # block_jac
        number, size, columns = statement.data["number"], statement.data["size"], statement.data["states"]
        rz = exprs[: size * size]
        rx = exprs[size * size:]
        rows = ", ".join("[" + ", ".join(printer.doprint(v) for v in rz[i * size:(i + 1) * size]) + "]"
                         for i in range(size))
        lines = [f"_Rz{number} = np.array([{rows}], dtype=float)",
                 f"_Rx{number} = np.zeros(({size}, {columns}))"]
        for (i, j), value in zip(statement.data["rx_keys"], rx):
            lines.append(f"_Rx{number}[{i}, {j}] = {printer.doprint(value)}")
        lines.append(f"_Dz{number} = -np.linalg.solve(_Rz{number}, _Rx{number})")
        return lines

    def unpack(self, used, with_modes=True):
        lines = []
        if self.plan.ss.time in used:
            lines.append("t = as_time(t)")
        for symbol, i in sorted(self.parameter_index.items(), key=lambda item: item[1]):
            if symbol in used:
                lines.append(f"{self.names[symbol]} = p[{i}]")
        for symbol, i in sorted(self.state_index.items(), key=lambda item: item[1]):
            if symbol in used:
                lines.append(f"{self.names[symbol]} = x[{i}]")
        return lines

    def function(self, header, doc, statements, finals, tail, prologue=()):
        lines, texts, used = self.body(statements, finals)
        out = [header, f'{_INDENT}"""{doc}"""']
        out += [_INDENT + line for line in list(prologue) + self.unpack(used) + lines]
        out += [_INDENT + line for line in tail(texts)]
        return "\n".join(out)

    # -- the module

    def module(self) -> str:
        plan, ss = self.plan, self.plan.ss
        n = len(plan.states)
        graph = getattr(ss, "graph", None)
        model_name = getattr(graph, "name", None) or "model"
        experiment = self.experiment
        parts = [self.header(model_name), self.runtime_banner(), runtime_source().rstrip("\n"),
                 self.model_banner()]
        parts.append(self.constants(model_name))
        statements = plan.statements
        parts.append(self.derive_parameters())
        parts.append(self.function(
            "def x0(p=None):", "Initial state vector from the parameters (SI).",
            [], [s.initial for s in plan.states],
            lambda texts: ["return np.array([" + ", ".join(texts) + "], dtype=float)"],
            prologue=["p = param_array(PARAMETERS, p, _derive_parameters)"]))
        parts.append(self.function(
            "def _rhs(t, x, p, m):", "State derivatives with the modes m frozen.",
            statements, plan.derivatives,
            lambda texts: ["return np.array([" + ", ".join(texts) + "], dtype=float)"]))
        entries = plan.jacobian_entries
        keys = sorted(entries)

        def jac_tail(texts):
            lines = [f"J = np.zeros(({n}, {n}))"]
            lines += [f"J[{i}, {j}] = {text}" for (i, j), text in zip(keys, texts)]
            return lines + ["return J"]

        parts.append(self.function(
            "def _jac(t, x, p, m):", "Analytic Jacobian d rhs / d x with the modes m frozen.",
            plan.jacobian_statements, [entries[k] for k in keys], jac_tail))
        parts.append(self.function(
            "def _switches(t, x, p, m):", "Switching functions: the sign of each is its mode.",
            statements, [s.g for s in plan.switches],
            lambda texts: ["return stack(" + "".join(text + ", " for text in texts).rstrip(", ") + ")"]))
        parts.append(self.function(
            "def _outputs(t, x, p, m):", "Outputs with the modes m frozen.",
            statements, [expr for _, expr in plan.outputs],
            lambda texts: ["return (" + "".join(text + ", " for text in texts).rstrip() + ")"]))
        parts.append(self.function(
            "def _variables(t, x, p, m):", "Every assigned variable (VARIABLE_NAMES) with the modes m frozen.",
            statements, [symbol for _, symbol, _ in plan.variables],
            lambda texts: ["return (" + "".join(text + ", " for text in texts).rstrip() + ")"]))
        parts.append(self.time_breaks())
        parts.append(_WRAPPERS)
        return "\n\n\n".join(parts) + "\n"

    def derive_parameters(self) -> str:
        plan = self.plan
        index = {symbol: i for i, (_, symbol, _) in enumerate(plan.parameters)}
        position = {name: i for i, (name, _, _) in enumerate(plan.parameters)}
        printer = BondcPrinter({symbol: f"p[{i}]" for symbol, i in index.items()}, data_paths=self.data_paths)
        lines = ["def _derive_parameters(p, given=()):",
                 f'{_INDENT}"""Recompute the parameters defined by others (DERIVED_PARAMETERS), except those in'
                 " ``given``.",
                 "",
                 f"{_INDENT}Called when ``p`` is a dict of overrides: overriding D updates Ar = pi/4*(D^2 - d^2).",
                 f'{_INDENT}"""',
                 f"{_INDENT}p = np.array(p, dtype=float)"]
        for name, expr in plan.derived:
            lines.append(f"{_INDENT}if {name!r} not in given:")
            lines.append(f"{_INDENT * 2}p[{position[name]}] = {printer.doprint(expr)}")
        lines.append(f"{_INDENT}return p")
        return "\n".join(lines)

    def header(self, model_name) -> str:
        experiment = self.experiment
        what = f"model {model_name}" + (f", experiment {experiment.name}" if experiment is not None else "")
        return (f"# generated by bondc {__version__} from {self.source} ({what}) — do not edit\n"
                f'"""{model_name}: simulation module generated by bondc from {self.source}.\n\n'
                "Standalone: it needs numpy and scipy, not bondc. Run it to simulate and print csv\n"
                "(``python THIS.py --help``), or import it::\n\n"
                "    result = simulate(t_end, p={'name': value})\n"
                "    result.t, result.states['mass.p'], result.outputs['x']\n\n"
                "rhs(t, x, p), jacobian(t, x, p), outputs(t, x, p) and x0(p) evaluate the model;\n"
                "p is None (PARAMETERS), a dict of overrides or an array in PARAMETERS order.\n"
                '"""')

    @staticmethod
    def runtime_banner() -> str:
        rule = "# " + "=" * 76
        return (f"{rule}\n# bondc runtime: a verbatim copy of bondc/runtime.py, so that this module runs\n"
                f"# without bondc. Model-specific code follows the runtime.\n{rule}")

    @staticmethod
    def model_banner() -> str:
        rule = "# " + "=" * 76
        return f"{rule}\n# the model\n{rule}"

    def constants(self, model_name) -> str:
        plan, experiment = self.plan, self.experiment
        lines = [f"MODEL_NAME = {model_name!r}", f"SOURCE_FILE = {self.source!r}"]
        lines.append("STATE_NAMES = " + _tuple(s.name for s in plan.states))
        lines.append("STATE_UNITS = " + _tuple(s.unit_text for s in plan.states))
        lines.append("OUTPUT_NAMES = " + _tuple(name for name, _ in plan.outputs))
        lines.append("VARIABLE_NAMES = " + _tuple(name for name, _, _ in plan.variables))
        lines.append("VARIABLE_LAWS = " + _tuple((law for _, _, law in plan.variables), multiline=True))
        bonds = []
        for number in sorted(getattr(plan.ss, "bond_symbols", {}) or {}):
            for symbol in plan.ss.bond_symbols[number]:
                bonds.append(symbol.name)
        known = {name for name, _, _ in plan.variables}
        lines.append("BOND_VARIABLES = " + _tuple(name for name in bonds if name in known))
        lines.append("DERIVED_PARAMETERS = " + _tuple(name for name, _ in plan.derived))
        lines.append("PARAMETERS = {" + "".join(f"\n    {name!r}: {value!r}," for name, _, value in plan.parameters)
                     + ("\n}" if plan.parameters else "}"))
        lines.append("SWITCHES = " + _tuple((s.label for s in plan.switches), multiline=True))
        lines.append("EVENT_SWITCHES = " + _tuple(s.index for s in plan.switches if s.event))
        lines.append("SWITCH_DEPENDS = " + _tuple((tuple(d) for d in _switch_depends(plan)),
                                                  multiline=len(plan.switches) > 8))
        lines.append(f"VECTORIZED = {plan.blocks == 0}")
        defaults = {}
        if experiment is not None:
            for key, attribute in (("t_end", "t_end"), ("method", "solver"), ("rtol", "rtol"), ("atol", "atol"),
                                   ("max_step", "max_step")):
                value = getattr(experiment, attribute, None)
                if value is not None:
                    defaults[key] = value
            settings = getattr(experiment, "settings", {}) or {}
            for key in ("dt", "first_step"):
                if settings.get(key) is not None:
                    defaults[key] = float(settings[key])
        lines.append("DEFAULTS = {" + ", ".join(f"{k!r}: {v!r}" for k, v in defaults.items()) + "}")
        if self.data_paths:
            lines.append('DATA_DIR = os.environ.get("BONDC_DATA_DIR") or '
                         "os.path.dirname(os.path.abspath(__file__))")
        else:
            lines.append('DATA_DIR = "."')
        return "\n".join(lines)

    def time_breaks(self) -> str:
        printer = self.printer()
        items, csvs, used = [], [], set()
        for item in self.plan.time_breaks:
            if item.csv is not None:
                csv = item.csv
                path = self.data_paths.get(csv.path, csv.path)
                text = (f"[(time, {item.label!r}, 'csv') for time in csv_times(DATA_DIR, {path!r}, "
                        f"{csv.column!r})]")
                if text not in csvs:
                    csvs.append(text)
            else:
                used |= item.time.free_symbols
                entry = f"({printer.doprint(item.time)}, {item.label!r}, {item.kind!r})"
                if entry not in items:
                    items.append(entry)
        lines = ["def _time_breaks(p):",
                 f'{_INDENT}"""Times known in advance where a law switches: (time, label, kind)."""']
        lines += [_INDENT + line for line in self.unpack(used)]
        body = "[" + "".join(f"\n{_INDENT * 2}{entry}," for entry in items) + (f"\n{_INDENT}]" if items else "]")
        for text in csvs:
            body += f" + {text}"
        lines.append(f"{_INDENT}return {body}")
        return "\n".join(lines)


def _tuple(values, multiline=False) -> str:
    values = [repr(v) for v in values]
    if not values:
        return "()"
    if multiline or sum(len(v) + 2 for v in values) > 90:
        return "(" + "".join(f"\n    {v}," for v in values) + "\n)"
    return "(" + ", ".join(values) + ("," if len(values) == 1 else "") + ")"


_WRAPPERS = '''\
def modes(t, x, p=None):
    """The modes (sign of every switching function, SWITCHES) of the unfrozen law at (t, x)."""
    return modes_at(_MODEL, t, np.asarray(x, dtype=float), param_array(PARAMETERS, p, _derive_parameters))


def rhs(t, x, p=None):
    """State derivatives dx/dt at (t, x), in STATE_NAMES order."""
    return evaluate(_MODEL, "rhs", t, x, p)


def jacobian(t, x, p=None):
    """Analytic Jacobian d rhs / d x at (t, x)."""
    return evaluate(_MODEL, "jacobian", t, x, p)


def outputs(t, x, p=None):
    """Outputs (OUTPUT_NAMES order) at (t, x); x of shape (n,) or (n, N) with t of shape (N,)."""
    return evaluate(_MODEL, "outputs", t, x, p)


def variables(t, x, p=None):
    """Every assigned variable (VARIABLE_NAMES order): inputs, bond efforts and flows, ..."""
    return evaluate(_MODEL, "variables", t, x, p)


def event_functions(p=None):
    """One function g(t, x) per switch (SWITCHES): continuous, zero where that law switches.

    For scipy.integrate.solve_ivp(rhs, ..., events=event_functions()); each is terminal.
    simulate() does not need them: it locates switches itself.
    """
    p = param_array(PARAMETERS, p, _derive_parameters)

    def make(k):
        def g(t, x):
            x = np.asarray(x, dtype=float)
            return float(_switches(t, x, p, modes_at(_MODEL, t, x, p))[k])
        g.terminal = True
        g.__name__ = f"switch_{k}"
        return g

    return [make(k) for k in range(len(SWITCHES))]


def simulate(t_end=None, p=None, t_eval=None, **solver_options):
    """Simulate to t_end (default: the experiment's); returns a Result with t, states, outputs.

    solver_options: method, rtol, atol, max_step, first_step, dt, progress, ...
    (see simulate_model); missing ones come from DEFAULTS.
    """
    return simulate_model(_MODEL, t_end, p, t_eval, **solver_options)


_MODEL = _Model(globals())


def main(argv=None):
    import argparse

    parser = argparse.ArgumentParser(description=f"Simulate {MODEL_NAME} (generated by bondc from {SOURCE_FILE}).")
    parser.add_argument("--t-end", type=float, help="end time [s] (default: the experiment's)")
    parser.add_argument("--dt", type=float, help="output interval [s] (default: every solver step)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter, in SI (repeatable)")
    parser.add_argument("--all", action="store_true", help="also write every assigned variable")
    parser.add_argument("-o", "--output", help="csv file to write (default: standard output)")
    args = parser.parse_args(argv)
    overrides = {}
    for item in args.set:
        name, _, value = item.partition("=")
        overrides[name.strip()] = float(value)
    result = simulate(args.t_end, overrides or None, dt=args.dt)
    write_csv(result, args.output or sys.stdout, variables=args.all)
    if not result.complete:
        print(f"{MODEL_NAME}: INCOMPLETE: {result.message}", file=sys.stderr)
        if result.failure and result.failure.get("hint"):
            print(f"hint: {result.failure['hint']}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())'''


def emit(ss, experiment=None, *, source: str | None = None, module_dir: str | os.PathLike | None = None) -> str:
    """Python source of a standalone simulation module for ``ss`` (see the module docstring).

    ``experiment`` (an :class:`~bondc.model.ExperimentDef`) gives the default
    solver settings; ``source`` names the model file in the header (its name
    only; default: the graph's file); ``module_dir`` is where the module will
    live, so that csv data paths are written relative to it (default: the
    model file's directory).
    """
    graph = getattr(ss, "graph", None)
    graph_file = getattr(graph, "file", None)
    if source is None:
        source = Path(graph_file).name if graph_file else "<model>"
    else:
        source = Path(source).name
    if module_dir is None and graph_file:
        module_dir = Path(graph_file).resolve().parent
    plan = _plan(ss)
    return _Emitter(plan, source, experiment, module_dir).module()
