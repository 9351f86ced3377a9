"""The Python module's text: a :class:`~bondc.codegen.plan._Plan` -> the generated module's
source (:class:`_Emitter`): its header, constants, functions (right-hand side, Jacobian,
switches, outputs, variables, algebraic loops, when clauses, time breaks) printed by
:class:`~bondc.codegen.printer.BondcPrinter` after one common-subexpression pass, around the
runtime (a copy or an import) and the C source its C emitter gives.
"""

from __future__ import annotations

import builtins
from pathlib import Path
from typing import TYPE_CHECKING

from bondc.codegen.naming import ARGUMENTS, MODULE_NAMES, Namer, _top_level_names
from bondc.codegen.plan import _switch_depends
from bondc.codegen.printer import BondcPrinter, relative_data_path
from bondc.codegen.sources import native_files_source, runtime_source
from bondc.codegen.statements import _copied, _cse, _hide_piecewise
from bondc.model import readable, readable_names, result_units
from bondc.symbolic import as_sympy
from bondc.version import __version__

if TYPE_CHECKING:
    from bondc.codegen.plan import _Plan


_INDENT = "    "


#: Names the runtime defines that a generated module importing it needs not (it imports its own modules).
_RUNTIME_MODULES = frozenset({"_integrate", "_optimize"})


class _Emitter:
    def __init__(self, plan: _Plan, source: str, experiment, module_dir, standalone=True, native=None):
        self.standalone = standalone
        # the emitter's C code: a function of this emitter giving (C source, why there is none)
        # (bondc.codegen.native_code.native_source, which subclasses this emitter)
        self.native = native
        self.plan = plan
        self.dae_offsets: dict[int, int] | None = None     # block number -> offset in _dae's unknowns, while _dae is printed
        self.source = source
        self.experiment = experiment
        ss = plan.ss
        # a switch's label names bond variables by the elements they are (coulomb(fr1.f) in fr1.e),
        # as the results of bondc simulate do, so that a module run on its own says the same
        names_of = readable_names(getattr(ss, "graph", None))
        self.label = lambda text: readable(names_of, text)
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
        # a statement that only copies another symbol (b3_f = b2_f: 45 % of a chain's statements)
        # is not printed; the copy is printed by its source's name (copy propagation, at printing)
        self.aliases: dict = {}
        for statement in plan.statements:
            source = _copied(statement)
            if source is not None and source in names and source not in self.modes:
                self.aliases[statement.defines[0]] = self.aliases.get(source, source)
        for symbol, source in self.aliases.items():
            names[symbol] = names[source]
        self.parameter_index = {symbol: i for i, (_, symbol, _) in enumerate(plan.parameters)}
        self.state_index = {s.symbol: i for i, s in enumerate(plan.states)}
        data_paths = {}
        module_dir = Path(module_dir) if module_dir is not None else None
        for item in plan.time_breaks:
            if item.csv is not None and item.csv.path not in data_paths:
                path = item.csv.path
                data_paths[path] = relative_data_path(path, module_dir) if module_dir else Path(path).name
        self.data_paths = data_paths
        self.reduced: dict = {}        # body() memo, shared with the C emitter (a shallow copy of this one)
        self.shared = None             # share(): one cse of every function's statements and results
        self.free_memo: dict = {}      # free(): expr -> its free symbols
        self.reads_memo: dict = {}     # reads(): id(statement) -> the symbols it reads
        self.printed: dict = {}        # text() memo (keyed by the printer's class: numpy and C differ)

    def printer(self, extra_frozen=()):
        return BondcPrinter(self.names, mode_symbols=self.modes | set(extra_frozen), data_paths=self.data_paths)

    # -- function bodies

    def body(self, statements, finals):
        """Lines computing ``finals`` from (t, x, p, m) and the printed finals."""
        key = (id(statements), tuple(finals))
        if key not in self.reduced:     # the same body printed as numpy and as C: reduce it once
            self.reduced[key] = self.reduce(statements, finals)
        kept, replacements, reduced, frozen = self.reduced[key]
        return self.print_body(kept, replacements, reduced, frozen)

    def share(self):
        """One common-subexpression pass over every statement and the results of every function
        that reads them (the right-hand side, the Jacobian, the switches, outputs, variables, when
        clauses and loop unknowns). A subexpression two functions share is one temporary; each
        function prints the temporaries it reads (:meth:`print_body`). One pass instead of one per
        function: on a large model each pass costs about as much as printing its function."""
        plan = self.plan
        finals = list(plan.derivatives) + list(plan.jacobian_entries.values()) + [s.g for s in plan.switches]
        finals += [expr for _, expr in plan.outputs] + [symbol for _, symbol, _ in plan.variables]
        for _, condition, actions in plan.events:
            finals += [condition] + [value for _, value in actions]
        finals = list(dict.fromkeys(as_sympy(f) for f in finals))
        statements = plan.jacobian_statements        # every statement of plan.statements, and the Jacobian's
        exprs = [expr for statement in statements for expr in statement.exprs] + finals
        replacements, reduced, frozen = self.common(exprs)
        by_statement, position = {}, 0
        for statement in statements:
            by_statement[id(statement)] = reduced[position:position + len(statement.exprs)]
            position += len(statement.exprs)
        self.shared = (by_statement, dict(zip(finals, reduced[position:])), replacements, frozen)

    def free(self, expr) -> frozenset:
        """``expr.free_symbols``, once per expression (sympy walks the tree on every call)."""
        found = self.free_memo.get(expr)
        if found is None:
            found = self.free_memo[expr] = frozenset(expr.free_symbols)
        return found

    def reads(self, statement) -> frozenset:
        """Every symbol a statement reads."""
        found = self.reads_memo.get(id(statement))
        if found is None:
            found = statement.uses.union(*(self.free(expr) for expr in statement.exprs))
            self.reads_memo[id(statement)] = found
        return found

    def reduce(self, statements, finals):
        """The statements ``finals`` need, and their common subexpressions (sympy, not printed)."""
        finals = [as_sympy(f) for f in finals]
        needed = set().union(*(self.free(f) for f in finals)) if finals else set()
        kept = []
        for statement in reversed(statements):
            if not needed.isdisjoint(statement.defines):
                kept.append(statement)
                needed |= self.reads(statement)
        kept.reverse()
        if self.shared is not None:
            by_statement, by_final, replacements, frozen = self.shared
            if all(id(s) in by_statement for s in kept) and all(f in by_final for f in finals):
                reduced = [expr for s in kept for expr in by_statement[id(s)]] + [by_final[f] for f in finals]
                return kept, replacements, reduced, frozen
        exprs = [expr for statement in kept for expr in statement.exprs] + finals
        replacements, reduced, frozen = self.common(exprs)
        return kept, replacements, reduced, frozen

    def common(self, exprs):
        """(replacements, reduced exprs, the temporaries that are conditions on modes only)."""
        # cse must not hoist work out of an if's branches (only the active one is evaluated, so its
        # modes are the only ones read): every Piecewise is hidden behind a placeholder first
        pieces: dict = {}
        exprs = [_hide_piecewise(expr, pieces) for expr in exprs]
        replacements, reduced = _cse(exprs) if exprs else ([], [])
        placeholders = {symbol: piecewise for piecewise, symbol in pieces.items()}
        placeholder_set = set(placeholders)
        uses: dict = {}
        for expr in [e for _, e in replacements] + list(reduced):
            for symbol in expr.free_symbols & placeholder_set:
                uses[symbol] = uses.get(symbol, 0) + 1
        once = {symbol: placeholders[symbol] for symbol, count in uses.items() if count == 1}
        replacements = [(symbol, expr.xreplace(once)) for symbol, expr in replacements]
        reduced = [expr.xreplace(once) for expr in reduced]
        shared = [(symbol, placeholders[symbol]) for symbol in sorted(set(uses) - set(once), key=lambda s: s.name)]
        replacements = replacements + shared
        frozen = set()
        for symbol, expr in replacements:       # cse temps that are conditions on modes only
            if expr.free_symbols <= (self.modes | frozen):
                frozen.add(symbol)
        return replacements, reduced, frozen

    def print_body(self, kept, replacements, reduced, frozen):
        substitutes = dict(replacements)
        order = {symbol: i for i, (symbol, _) in enumerate(replacements)}
        for symbol, _ in replacements:
            self.names.setdefault(symbol, symbol.name)
        printer = self.printer(frozen)
        lines, emitted, used = [], set(), set()

        def emit_replacements(free):
            pending = free & substitutes.keys()
            if not pending:
                return
            for symbol in sorted(pending - emitted, key=order.get):
                if symbol in emitted:
                    continue
                expr = substitutes[symbol]
                inner = self.free(expr)
                emit_replacements(inner)
                emitted.add(symbol)
                used.update(inner)
                lines.append(self.assign_line(self.names[symbol], self.text(printer, expr)))

        position = 0
        for statement in kept:
            used |= statement.uses
            count = len(statement.exprs)
            statement_exprs = reduced[position:position + count]
            position += count
            frees = [self.free(expr) for expr in statement_exprs]
            for free in frees:
                used |= free
            if statement.kind == "assign" and statement.defines[0] in self.aliases:
                continue        # a copy: printed by its source's name
            for free in frees:
                emit_replacements(free)
            lines += self.statement_lines(statement, statement_exprs, printer)
        final_texts = []
        for expr in reduced[position:]:
            free = self.free(expr)
            used |= free
            emit_replacements(free)
            final_texts.append(self.text(printer, expr))
        return lines, final_texts, used

    #: how a function body makes t a number with numpy's arithmetic (None: it already is one)
    time_line = "t = as_time(t)"

    @staticmethod
    def assign_line(name: str, text: str) -> str:
        return f"{name} = {text}"

    def text(self, printer, expr) -> str:
        """``printer.doprint(expr)``, once per expression and printer setting: most statements are
        printed in several functions (the right-hand side, the variables, the outputs)."""
        key = (type(printer), getattr(printer, "mode_symbols", None), expr)
        text = self.printed.get(key)
        if text is None:
            # the common shapes (names, products, sums) by the printer's quick path, the same text
            # without sympy's per-call setup and dispatch (see BondcPrinting.quick)
            text = printer.quick(expr)
            if text is None:
                text = printer.doprint(expr)
            self.printed[key] = text
        return text

    def statement_lines(self, statement, exprs, printer):
        if statement.kind == "assign":
            return [self.assign_line(self.names[statement.defines[0]], self.text(printer, exprs[0]))]
        if statement.kind == "block":
            number = statement.data["number"]
            unknowns = ", ".join(self.names[u] for u in statement.defines) + ","
            raw = self.printer()
            residuals = ", ".join(raw.doprint(r) for r in statement.data["residuals"])
            guesses = ", ".join(raw.doprint(g) for g in statement.data["guesses"])
            lines = [f"def _residual{number}(_z):",
                     f"{_INDENT}{unknowns} = _z",
                     f"{_INDENT}return ({residuals},)"]
            if self.dae_offsets is not None:        # _dae: the unknowns are the DAE's algebraic variables
                start, size = self.dae_offsets[number], len(statement.defines)
                return lines + [f"{unknowns} = _za[{start}:{start + size}]",
                                f"_ra.extend(_residual{number}(({unknowns})))"]
            return lines + [f"{unknowns} = solve_block(_residual{number}, {number}, ({guesses},))"]
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
        if self.plan.ss.time in used and self.time_line:
            lines.append(self.time_line)
        for symbol, i in sorted(self.parameter_index.items(), key=lambda item: item[1]):
            if symbol in used:
                lines.append(self.assign_line(self.names[symbol], f"p[{i}]"))
        for symbol, i in sorted(self.state_index.items(), key=lambda item: item[1]):
            if symbol in used:
                lines.append(self.assign_line(self.names[symbol], f"x[{i}]"))
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
        if self.standalone:
            parts = [self.header(model_name), self.runtime_banner(), runtime_source().rstrip("\n"),
                     native_files_source(), self.model_banner()]
        else:
            parts = [self.header(model_name), self.runtime_import(), self.model_banner()]
        self.share()
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
        parts += self.dae_functions()
        entries = plan.jacobian_entries
        keys = sorted(entries, key=lambda key: (key[1], key[0]))     # JACOBIAN_PATTERN's order, as in C

        def jac_tail(texts):
            lines = [f"J = np.zeros(({n}, {n}))"]
            lines += [f"J[{i}, {j}] = {text}" for (i, j), text in zip(keys, texts)]
            return lines + ["return J"]

        parts.append(self.function(
            "def _jac(t, x, p, m):", "Analytic Jacobian d rhs / d x with the modes m frozen.",
            plan.jacobian_statements, [entries[k] for k in keys], jac_tail))
        def stacked(texts):
            return ["return stack(" + "".join(text + ", " for text in texts).rstrip(", ") + ")"]

        parts.append(self.function(
            "def _switches(t, x, p, m):", "Switching functions: the sign of each is its mode.",
            statements, [s.g for s in plan.switches], stacked))
        timed = [sw for sw in plan.switches if sw.event and sw.time_only]
        if plan.blocks and timed:
            # a model with an algebraic loop is evaluated point by point, but its switches of time
            # alone are not in the loop: over many times at once, to find their zeros before the run
            parts.append(self.function(
                "def _time_switches(t, x, p, m):", "The switches of time alone (TIME_SWITCHES), over arrays of times.",
                statements, [sw.g for sw in timed], stacked))
        parts.append(self.function(
            "def _outputs(t, x, p, m):", "Outputs with the modes m frozen.",
            statements, [expr for _, expr in plan.outputs],
            lambda texts: ["return (" + "".join(text + ", " for text in texts).rstrip() + ")"]))
        returned = []

        def variables_tail(texts):
            returned.extend(texts)
            return ["return (" + "".join(text + ", " for text in texts).rstrip() + ")"]

        parts.append(self.function(
            "def _variables(t, x, p, m):", "Every assigned variable (VARIABLE_NAMES) with the modes m frozen.",
            statements, [symbol for _, symbol, _ in plan.variables], variables_tail))
        # variables that _variables returns as one expression (a junction's common effort or flow,
        # an input and its source's effort) are one quantity: one row of the result, shared
        first: dict = {}
        parts.append("#: The result's row of each variable (VARIABLE_NAMES order): one row per distinct\n"
                     "#: expression that _variables returns, in order of first use.\n"
                     "VARIABLE_ROWS = " + _numbers([first.setdefault(text, len(first)) for text in returned]))
        parts.append(self.time_breaks())
        parts.append(self.when_functions())
        parts.append(_WRAPPERS)
        return "\n\n\n".join(parts) + "\n"

    def dae_functions(self) -> list[str]:
        """For a model whose derivatives go through algebraic loops: the same equations as a DAE
        for IDA, ``_dae(t, x, _za, p, m)`` -> (derivatives, loop residuals) with the loops'
        unknowns given (``_za``, in block order) instead of solved, and ``_loop_values(t, x, p, m)``
        (the unknowns solved, for consistent initial values). None of this without a loop."""
        plan = self.plan
        kept = self.reduced.get((id(plan.statements), tuple(plan.derivatives)), ([],))[0]
        blocks = [statement for statement in kept if statement.kind == "block"]
        if not blocks:
            return []
        self.dae_offsets, start = {}, 0
        for statement in blocks:
            self.dae_offsets[statement.data["number"]] = start
            start += len(statement.defines)
        try:
            dae = self.function(
                "def _dae(t, x, _za, p, m):",
                "The state equations as a DAE: (derivatives, residuals of the algebraic loops) with the "
                "loops' unknowns _za.",
                plan.statements, plan.derivatives,
                lambda texts: ["return np.array([" + ", ".join(texts) + "], dtype=float), np.array(_ra, "
                               "dtype=float)"],
                prologue=["_ra = []"])
        finally:
            self.dae_offsets = None
        unknowns = [symbol for statement in blocks for symbol in statement.defines]
        values = self.function(
            "def _loop_values(t, x, p, m):", "The unknowns of the algebraic loops (_dae's _za), solved.",
            plan.statements, unknowns,
            lambda texts: ["return np.array([" + ", ".join(texts) + "], dtype=float)"])
        return [dae, values, f"DAE_SIZE = {start}"]

    def when_functions(self) -> str:
        """``_when_conditions`` (each clause's condition with the modes m) and one function per
        clause giving the new values of its targets from the values just before the event."""
        plan = self.plan
        conditions = [condition for _, condition, _ in plan.events]
        out = [self.function(
            "def _when_conditions(t, x, p, m):", "Whether each when clause's condition holds, with the modes m.",
            plan.statements, conditions,
            lambda texts: ["return (" + "".join(f"bool({text}), " for text in texts).rstrip() + ")"])]
        for k, (_, _, actions) in enumerate(plan.events):
            out.append(self.function(
                f"def _when_action_{k}(t, x, p, m):", f"The new values of when clause {k + 1}'s targets.",
                plan.statements, [value for _, value in actions],
                lambda texts: ["return (" + "".join(text + ", " for text in texts).rstrip() + ")"]))
        out.append("WHEN_ACTIONS = (" + "".join(f"_when_action_{k}, " for k in range(len(plan.events))).rstrip()
                   + ")")
        return "\n\n\n".join(out)

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
        needs = ("Standalone: it needs numpy and scipy (and scikit-sundae for CVODE), not bondc." if self.standalone
                 else "It imports bondc.runtime; `bondc compile --standalone` writes one that does not.")
        doc = (f"{model_name}: simulation module generated by bondc from the model file SOURCE_FILE.\n\n"
               f"{needs} Run it to simulate and print csv\n"
               "(``python THIS.py --help``), or import it::\n\n"
               "    result = simulate(t_end, p={'name': value})\n"
               "    result.t, result.states['mass.p'], result.outputs['x']\n\n"
               "rhs(t, x, p), jacobian(t, x, p), outputs(t, x, p) and x0(p) evaluate the model;\n"
               "p is None (PARAMETERS), a dict of overrides or an array in PARAMETERS order.\n")
        # the file name comes from the user: only as an ASCII literal in the comment (no line break
        # can end the comment); the docstring holds the model's name, an identifier, and fixed text
        return (f"# generated by bondc {__version__} from {ascii(self.source)} ({what}) — do not edit\n"
                f'"""{doc}"""')

    @staticmethod
    def runtime_import() -> str:
        names = sorted(name for name in _top_level_names(runtime_source(), imports=False)
                       if not name.startswith("__") and name not in _RUNTIME_MODULES)
        lines = ["import math", "import os", "import sys", "", "import numpy as np", "",
                 "from bondc.runtime import ("]
        lines += [f"    {name}," for name in names]
        return "\n".join(lines + [")"])

    @staticmethod
    def runtime_banner() -> str:
        rule = "# " + "=" * 76
        return (f"{rule}\n# bondc runtime: verbatim copies of the modules of bondc/runtime (their imports of\n"
                f"# each other commented out), so that this module runs without bondc. Model-specific\n"
                f"# code follows the runtime.\n{rule}")

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
        # each result column's unit and factor (SI value / factor = value in that unit), as bondc's
        # own result files record them (bondc.model.result_units)
        units = result_units(getattr(plan.ss, "graph", None))
        lines.append("RESULT_UNITS = {" + "".join(f"\n    {name!r}: ({unit!r}, {float(factor)!r}),"
                                                  for name, (unit, factor) in units.items()) + "\n}")
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
        lines.append("SWITCHES = " + _tuple((self.label(s.label) for s in plan.switches), multiline=True))
        lines.append("EVENT_SWITCHES = " + _tuple(s.index for s in plan.switches if s.event))
        lines.append("SWITCH_DEPENDS = " + _tuple((tuple(d) for d in _switch_depends(plan)),
                                                  multiline=len(plan.switches) > 8))
        lines.append("SWITCH_VERTICES = " + _tuple(float(s.vertex) for s in plan.switches))
        lines.append("SWITCH_KINDS = " + _tuple(s.kind for s in plan.switches))
        lines.append("SWITCH_TRUTH = " + _tuple(s.truth for s in plan.switches))
        # the Jacobian's structural non-zeros, column by column (the order of a CSC matrix)
        pattern = sorted(plan.jacobian_entries, key=lambda key: (key[1], key[0]))
        lines.append("JACOBIAN_PATTERN = (" + "".join(f"({i}, {j}), " for i, j in pattern).rstrip() + ")")
        lines.append("SWITCH_OWNERS = " + _tuple((s.owner for s in plan.switches), multiline=len(plan.switches) > 8))
        modes = {s.mode: s.index for s in plan.switches}
        when_switches = sorted({modes[symbol] for _, condition, _ in plan.events
                                for symbol in as_sympy(condition).free_symbols if symbol in modes})
        lines.append("WHEN_LABELS = " + _tuple(label for label, _, _ in plan.events))
        lines.append("WHEN_TARGETS = " + _tuple(tuple(index for index, _ in actions) for _, _, actions in plan.events))
        lines.append("WHEN_SWITCHES = " + _tuple(when_switches))
        lines.append("TIME_SWITCHES = " + _tuple(s.index for s in plan.switches if s.event and s.time_only))
        lines.append(f"VECTORIZED = {plan.blocks == 0}")
        # the top model's external inputs: the host sets {name: (times, values) or f(t)} here (see
        # runtime.simulate_model's inputs); an input nothing supplies takes its default. (A model
        # without them has neither name: its module stays as it was.)
        external = [name for name, (_, expr) in (plan.ss.inputs or {}).items() if type(expr).__name__ == "External"]
        if external:
            lines.append("EXTERNAL_INPUT_NAMES = " + _tuple(external))
            lines.append("EXTERNAL_INPUTS = {}")
        native, reason = self.native(self) if self.native is not None else ("", "no C emitter was given")
        lines.append(f"NATIVE_SOURCE = {_text_literal(native)}")
        lines.append(f"NATIVE_UNAVAILABLE = {reason!r}")
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
            if item.external is not None:
                text = (f"[(time, {self.label(item.label)!r}, 'csv') for time in external_times(EXTERNAL_INPUTS, "
                        f"{item.external!r})]")
                if text not in csvs:
                    csvs.append(text)
            elif item.csv is not None:
                csv = item.csv
                path = self.data_paths.get(csv.path, csv.path)
                scale = f", {csv.time_scale!r}" if csv.time_scale != 1.0 else ""
                text = (f"[(time, {self.label(item.label)!r}, 'csv') for time in csv_times(DATA_DIR, {path!r}, "
                        f"{csv.column!r}{scale})]")
                if text not in csvs:
                    csvs.append(text)
            else:
                used |= item.time.free_symbols
                entry = f"({printer.doprint(item.time)}, {self.label(item.label)!r}, {item.kind!r})"
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


def _text_literal(text: str) -> str:
    """A Python literal of ``text``, one line of source per line of text."""
    if not text:
        return "''"
    return "(\n" + "".join(f"    {line!r}\n" for line in text.splitlines(keepends=True)) + ")"


def _numbers(values) -> str:
    """A tuple of integers, 20 to a line."""
    if not values:
        return "()"
    rows = [", ".join(map(str, values[i:i + 20])) for i in range(0, len(values), 20)]
    return "(" + "".join(f"\n    {row}," for row in rows) + "\n)"


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
    parser.add_argument("--method", help="solver: CVODE (needs scikit-sundae), LSODA, BDF, Radau, ... "
                                         "(default: the experiment's)")
    parser.add_argument("-o", "--output", help="file to write: .csv (units in the header), .npz or .parquet "
                                               "(default: csv on standard output)")
    args = parser.parse_args(argv)
    overrides = {}
    for item in args.set:
        name, _, value = item.partition("=")
        try:
            overrides[name.strip()] = float(value)
        except ValueError:
            parser.error(f"--set {item!r}: write NAME=VALUE with VALUE a number in SI")
    options = {"dt": args.dt, **({"method": args.method} if args.method else {})}
    try:
        result = simulate(args.t_end, overrides or None, **options)
    except ImportError as error:
        print(f"{MODEL_NAME}: cannot simulate: {error}", file=sys.stderr)
        print("hint: install scikit-sundae (pip install scikit-sundae), or run with --method LSODA",
              file=sys.stderr)
        return 2
    except (ValueError, OSError) as error:
        print(f"{MODEL_NAME}: cannot simulate: {error}", file=sys.stderr)
        if isinstance(error, (CsvError, OSError)):
            print("hint: a measured signal's path is relative to the folder the module was compiled for; "
                  "set BONDC_DATA_DIR to the folder it is relative to now", file=sys.stderr)
        return 2
    write_result(result, args.output or sys.stdout, variables=args.all)
    if not result.complete:
        print(f"{MODEL_NAME}: INCOMPLETE: {result.message}", file=sys.stderr)
        if result.failure and result.failure.get("hint"):
            print(f"hint: {result.failure['hint']}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())'''
