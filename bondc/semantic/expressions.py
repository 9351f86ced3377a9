"""Expressions against a scope: the categories of name each kind of expression may use
(:class:`ExprScope`), :class:`_ExpressionChecker` that walks one ``ast`` expression and reports
undefined or misplaced names, wrong calls, graph variables and ``csv(...)`` files and columns,
and the name and dependency-cycle helpers the other checks share. Takes an expression and a
scope, returns whether the expression is sound (diagnostics go to the model).
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

from bondc import ast
from bondc.errors import Diagnostic, Related
from bondc.kinds import JUNCTIONS, KINDS
from bondc.model import PORT_NAMES
from bondc.semantic.context import (
    BOND_NUMBER, BUILTINS, SET_HINT, a_or_an, CheckContext, did_you_mean, error_at, join_hints,
)
from bondc import codes


GENERAL = frozenset({"parameter", "input", "output", "state", "discrete", "graph", "time", "csv"})
DISCRETE_START = frozenset({"parameter", "input", "state", "discrete", "graph"})
DISCRETE_RULE = ("a discrete variable's initial value is an expression of parameters, and of inputs and initial "
                  "states at t = 0")
SIGNAL = frozenset({"parameter", "input", "time", "csv"})
CONSTANT = frozenset({"parameter"})

_CATEGORY_PHRASE = {"state": "model state", "time": "time", "discrete": "discrete variable"}


@dataclass(frozen=True)
class ExprScope:
    """Where an expression is written: which names it may use, and how to explain it."""

    what: str                               # "a parameter", "an input", "the law e = ... of C 'spring'", ...
    allowed: frozenset[str]                 # categories of model names, and "graph", "time", "csv"
    rule: str                               # the hint that says what this place may use
    functions: Mapping[str, ast.FnDef]
    local: Mapping[str, str] = field(default_factory=dict)       # name -> what it is here
    forbidden: Mapping[str, str] = field(default_factory=dict)   # own names this law may not use -> why
    owner: str | None = None                # the element whose law this is
    params_before: "ParamsAbove | frozenset[str] | None" = None   # in a parameter declaration: those above it
    current: str | None = None              # the name being defined (a parameter's self-reference)
    constant_locals: bool = False           # locals are constants (function arguments)
    code: str = codes.E316                      # the code of a name this place may not use

    def constant(self, what: str) -> "ExprScope":
        """The scope of a table's breakpoints inside this one: constants only."""
        return dataclasses.replace(
            self, what=what, allowed=self.allowed & CONSTANT,
            rule="table breakpoints are constants: numbers, parameters and pi",
            local=self.local if self.constant_locals else {}, forbidden={})


class _ExpressionChecker:
    """Checks one expression's names, references and calls; one ``_check_<Class>`` per node class."""

    def __init__(self, m: CheckContext, scope: ExprScope):
        self.m = m
        self.scope = scope
        self.errors = 0

    def report(self, diagnostic: Diagnostic) -> None:
        self.errors += diagnostic.is_error
        self.m.report(diagnostic)

    def check(self, node, scope: ExprScope | None = None) -> None:
        saved = self.scope
        self.scope = scope or self.scope
        try:
            method = getattr(self, f"_check_{type(node).__name__}", None)
            if method is None:
                raise TypeError(f"unsupported expression node {type(node).__name__}")
            method(node)
        finally:
            self.scope = saved

    # leaves ------------------------------------------------------------------
    def _check_Num(self, node: ast.Num) -> None:
        pass

    def _check_Str(self, node: ast.Str) -> None:
        self.report(error_at(codes.E313, "a string where a number is expected", node.span,
                             hint="strings are descriptions, or the file and column of csv(...)"))

    def _check_ListExpr(self, node: ast.ListExpr) -> None:
        self.report(error_at(codes.E313, "a list where a number is expected", node.span,
                             hint="lists are the breakpoints of table(t, [t0, t1, ...], [v0, v1, ...])"))

    def _check_Unary(self, node: ast.Unary) -> None:
        self.check(node.operand)

    def _check_Binary(self, node: ast.Binary) -> None:
        self.check(node.left)
        self.check(node.right)

    def _check_If(self, node: ast.If) -> None:
        self.check(node.cond)
        self.check(node.then)
        self.check(node.orelse)

    # names -------------------------------------------------------------------
    def _not_allowed(self, node, phrase: str) -> None:
        self.report(error_at(self.scope.code, f"{self.scope.what} cannot use {phrase}", node.span,
                             hint=self.scope.rule))

    def _check_Name(self, node: ast.Name) -> None:
        scope, name = self.scope, node.name
        if name in scope.forbidden:
            self.report(error_at(codes.E506, scope.forbidden[name], node.span, hint=scope.rule))
            return
        if name in scope.local or name == "pi":
            return
        if name == "t":
            if "time" not in scope.allowed:
                self._not_allowed(node, "time 't'")
            return
        decl = self.m.decls.get(name)
        if decl is None:
            self._undefined(node)
            return
        self.m.used.add(name)
        if decl.category in ("element", "junction", "bond label"):
            variables = self._variables_of(name)
            self.report(error_at(codes.E316, f"'{name}' is {a_or_an(decl.category)}, not a value", node.span,
                                 hint=f"use one of its variables: {', '.join(variables)}" if variables else None))
        elif isinstance(decl.node, ast.FnDef):
            params = ", ".join(decl.node.params)
            self.report(error_at(codes.E316, f"'{name}' is a function, not a value", node.span,
                                 hint=f"call it: {name}({params})"))
        elif decl.category not in scope.allowed:
            self._not_allowed(node, f"{_CATEGORY_PHRASE.get(decl.category, decl.category)} '{name}'")
        elif decl.category == "parameter" and scope.params_before is not None:
            if name == scope.current:
                self.report(error_at(codes.E305, f"parameter '{name}' is defined in terms of itself", node.span))
            elif name not in scope.params_before:
                self.report(error_at(codes.E305, f"parameter '{name}' is used before it is defined", node.span,
                                     hint=f"a parameter may use only parameters defined above it: move "
                                          f"'param {name}' above this line",
                                     related=[Related(decl.span, f"'{name}' is defined here")]))

    def _undefined(self, node: ast.Name) -> None:
        name, scope = node.name, self.scope
        visible = [n for n, d in self.m.decls.items()
                   if d.category in scope.allowed or d.category == "function"] + list(scope.local) + ["pi"]
        if "time" in scope.allowed:
            visible.append("t")
        hint = did_you_mean(name, visible)
        if hint is None and name in ("e", "f"):
            hint = (f"'{name}' alone is an element's own {'effort' if name == 'e' else 'flow'}, usable in its laws; "
                    f"elsewhere write X.{name} for element X")
        if hint is None:
            owners = [o for o, laws in self.m.element_laws.items() if name in laws.state_names]
            if owners:
                hint = f"'{name}' is a state of '{owners[0]}': write {owners[0]}.{name}"
        if node.span.file.startswith("--set #"):     # --set k=abc

            hint = f"{hint}; {SET_HINT}" if hint else SET_HINT
        self.report(error_at(codes.E301, f"undefined name '{name}'", node.span, hint=hint))

    def _variables_of(self, name: str) -> list[str]:
        """The variables an element, junction or bond exposes, as written in expressions."""
        decl = self.m.decls.get(name)
        if decl is None or decl.category == "bond label":
            return [f"{name}.e", f"{name}.f"]
        if decl.category == "junction":
            kind = self.m.junction_kind(name)
            return [f"{name}.{JUNCTIONS[kind].common}"] if kind is not None else []
        kind = self.m.known_kind(name)
        if kind is None:
            return []
        if KINDS[kind].ports == 2:
            return [f"{name}.{port}.{var}" for port in PORT_NAMES for var in "ef"]
        laws = self.m.element_laws.get(name)
        states = laws.state_names if laws else ()
        return [f"{name}.e", f"{name}.f"] + [f"{name}.{s}" for s in states]

    # graph references ------------------------------------------------------
    def _check_Ref(self, node: ast.Ref) -> None:
        if not self._valid_ref(node):
            return
        head = node.parts[0]
        if head == self.scope.owner and len(node.parts) == 2 and node.parts[1] in self.scope.forbidden:
            self.report(error_at(codes.E506, self.scope.forbidden[node.parts[1]], node.span, hint=self.scope.rule))
        elif "graph" not in self.scope.allowed:
            self._not_allowed(node, f"the graph variable '{node.dotted}'")

    def _valid_ref(self, node: ast.Ref) -> bool:
        head, rest = node.parts[0], node.parts[1:]
        decl = self.m.decls.get(head)
        if decl is not None and decl.category not in ("element", "junction", "bond label") \
                and BOND_NUMBER.fullmatch(head):
            decl = None  # bN names bond N unless an element, junction or label is called bN
        if decl is None:
            match = BOND_NUMBER.fullmatch(head)
            if match is None:
                self.report(error_at(codes.E301, f"undefined name '{head}' in '{node.dotted}'", node.span,
                                     hint=did_you_mean(head, self.m.names("element", "junction", "bond label"))))
                return False
            number = int(match.group(1))
            if not 1 <= number <= len(self.m.bonds):
                self.report(error_at(codes.E312, f"there is no bond {number}", node.span,
                                     hint=f"bonds are numbered 1 to {len(self.m.bonds)} in order of appearance"))
                return False
            return self._bond_variable(node, rest, f"bond {number}")
        self.m.used.add(head)
        if decl.category == "bond label":
            return self._bond_variable(node, rest, f"bond '{head}'")
        if decl.category == "junction":
            return self._junction_variable(node, head, rest)
        if decl.category == "element":
            return self._element_variable(node, head, rest)
        self.report(error_at(codes.E312, f"'{head}' is {a_or_an(decl.category)}; only elements, junctions and bonds have "
                                     f"variables", node.span, hint=f"write just '{head}'"))
        return False

    def _unknown_variable(self, node: ast.Ref, owner: str, variables: list[str], extra: str | None = None) -> bool:
        hint = None if extra else did_you_mean(node.dotted, variables)
        listing = f"its variables: {', '.join(variables)}" if variables else None
        self.report(error_at(codes.E312, f"{owner} has no variable '{'.'.join(node.parts[1:])}'", node.span,
                             hint=join_hints(extra, hint, listing)))
        return False

    def _bond_variable(self, node: ast.Ref, rest: tuple[str, ...], owner: str) -> bool:
        if rest in (("e",), ("f",)):
            return True
        return self._unknown_variable(node, owner, [f"{node.parts[0]}.e", f"{node.parts[0]}.f"])

    def _junction_variable(self, node: ast.Ref, name: str, rest: tuple[str, ...]) -> bool:
        kind = self.m.junction_kind(name)
        if kind is None:
            return True  # unknown junction kind, reported by check_kinds
        common = JUNCTIONS[kind].common
        if rest == (common,):
            return True
        if rest in (("e",), ("f",)):
            has, lacks = JUNCTIONS[kind].common_word, JUNCTIONS[kind].summed_word
            bonds = [f"b{end.bond}" if self.m.bonds[end.bond - 1].label is None else self.m.bonds[end.bond - 1].label
                     for end in self.m.ends.get(name, [])]
            example = f", e.g. {bonds[0]}.{rest[0]}" if bonds else ""
            self.report(error_at(codes.E312, f"'{name}' is a {kind}-junction: it has a common {has} ({name}.{common}) but "
                                         f"no common {lacks}", node.span,
                                 hint=f"each bond at a {kind}-junction has its own {lacks}: use a bond's variable"
                                      f"{example}"))
            return False
        return self._unknown_variable(node, f"junction '{name}'", [f"{name}.{common}"])

    def _element_variable(self, node: ast.Ref, name: str, rest: tuple[str, ...]) -> bool:
        kind = self.m.known_kind(name)
        if kind is None:
            return True  # unknown kind, reported by check_kinds
        variables = self._variables_of(name)
        owner = f"{kind} '{name}'"
        if ".".join((name,) + rest) in variables:
            return True
        if KINDS[kind].ports == 1 and rest and rest[0] in PORT_NAMES:
            variable = rest[-1] if rest[-1] in ("e", "f") else "e"
            return self._unknown_variable(node, owner, variables, f"'{name}' is a one-port: write {name}.{variable}")
        if KINDS[kind].ports == 2 and rest in (("e",), ("f",)):
            return self._unknown_variable(node, owner, variables,
                                          f"'{name}' is a two-port: name the port, e.g. {name}.p1.{rest[0]}")
        return self._unknown_variable(node, owner, variables)

    # calls -------------------------------------------------------------------
    def _check_Call(self, node: ast.Call) -> None:
        scope, func = self.scope, node.func
        if func in scope.functions:
            self.m.used.add(func)
            function = scope.functions[func]
            if len(node.args) != len(function.params):
                self.report(error_at(codes.E306, f"'{func}' takes {len(function.params)} argument"
                                             f"{'' if len(function.params) == 1 else 's'} "
                                             f"({', '.join(function.params)}), {len(node.args)} given", node.span,
                                     related=[Related(function.name_span, f"'{func}' is defined here")]))
            for arg in node.args:
                self.check(arg)
            return
        if func in BUILTINS:
            getattr(self, f"_call_{func}", self._call_builtin)(node)
            return
        decl = self.m.decls.get(func)
        if decl is not None and decl.category != "function":
            self.report(error_at(codes.E316, f"'{func}' is {a_or_an(decl.category)}, not a function", node.func_span))
        else:
            hint = did_you_mean(func, list(BUILTINS) + list(scope.functions))
            if decl is not None:
                hint = f"'{func}' is defined inside the model; a function outside it cannot call it"
            self.report(error_at(codes.E301, f"unknown function '{func}'", node.func_span,
                                 hint=hint or "built-in functions: " + " ".join(BUILTINS)))
        for arg in node.args:
            self.check(arg)

    def _arity(self, node: ast.Call) -> bool:
        least, most = BUILTINS[node.func]
        given = len(node.args)
        if least <= given and (most is None or given <= most):
            return True
        if most is None:
            wanted = f"at least {least} arguments"
        else:
            wanted = f"{least} argument{'' if least == 1 else 's'}"
        usage = {"table": "table(t, [t0, t1, ...], [v0, v1, ...])", "step": "step(t, t0)",
                 "csv": 'csv("file.csv", "column")', "atan2": "atan2(y, x)"}.get(node.func)
        self.report(error_at(codes.E306, f"{node.func}() takes {wanted}, {given} given", node.span,
                             hint=f"write {usage}" if usage else None))
        return False

    def _call_builtin(self, node: ast.Call) -> None:
        self._arity(node)
        for arg in node.args:
            self.check(arg)

    def _call_table(self, node: ast.Call) -> None:
        if not self._arity(node):
            for arg in node.args:
                if not isinstance(arg, ast.ListExpr):
                    self.check(arg)
            return
        x, xs, ys = node.args
        self.check(x)
        lists = []
        for position, arg in (("second", xs), ("third", ys)):
            if isinstance(arg, ast.ListExpr):
                lists.append(arg)
            else:
                self.report(error_at(codes.E306, f"the {position} argument of table() must be a list [...]", arg.span,
                                     hint="write table(t, [t0, t1, ...], [v0, v1, ...])"))
        entries = self.scope.constant("a table breakpoint")
        for lst in lists:
            for item in lst.items:
                self.check(item, entries)
        if len(lists) == 2:
            breakpoints, values = lists
            if len(breakpoints.items) != len(values.items):
                self.report(error_at(codes.E306, f"table() has {len(breakpoints.items)} breakpoints but "
                                             f"{len(values.items)} values", node.span,
                                     hint="give one value per breakpoint"))
            elif len(breakpoints.items) < 2:
                self.report(error_at(codes.E306, "table() needs at least two points", node.span,
                                     hint="for a constant, write the value itself"))

    def _call_mod(self, node: ast.Call) -> None:
        self._call_builtin(node)
        if len(node.args) == 2:
            divisor = node.args[1]
            while isinstance(divisor, ast.Unary) and divisor.op in "+-":
                divisor = divisor.operand
            if isinstance(divisor, ast.Num) and divisor.value == 0:
                self.report(error_at(codes.E306, "mod(x, 0): the divisor is zero", node.args[1].span,
                                     hint="the remainder of a division by zero is undefined; give a non-zero divisor"))

    def _call_csv(self, node: ast.Call) -> None:
        if "csv" not in self.scope.allowed:
            self._not_allowed(node, "csv(...)")
            return
        if not self._arity(node):
            return
        strings = []
        for position, arg in zip(("file name", "column name"), node.args):
            if isinstance(arg, ast.Str):
                strings.append(arg)
            else:
                self.report(error_at(codes.E313, f"the {position} of csv() must be a string", arg.span,
                                     hint='write csv("data/file.csv", "column")'))
        if len(strings) == 2:
            path_arg, column_arg = strings
            _check_csv(self.m, node, path_arg, column_arg, report=self.report)


def _is_table(path: Path, header: list[str]) -> bool:
    """Whether a file whose first line is ``header`` is a CSV table, whose column names may be
    shown: two columns or more, named in printable text, and a first data row (if any) of as many
    numbers."""
    if len(header) < 2 or any(_CONTROL.search(cell) for cell in header):
        return False
    from bondc.runtime import csv_rows, open_data

    try:
        with open_data(path) as handle:
            rows = csv_rows(handle)
    except (OSError, UnicodeDecodeError, ValueError, csv.Error):
        return False
    if len(rows) < 2:
        return True
    try:
        numbers = [float(cell) for cell in rows[1]]
    except ValueError:
        return False
    return len(numbers) == len(header)


#: Characters no column name (or line of a model) holds: the C0 controls but tab, and DEL.
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")


def _check_csv(m: CheckContext, node: ast.Call, path_arg: ast.Str, column_arg: ast.Str, report) -> None:
    """E310: the CSV file exists (relative to the model file) and has the column."""
    source = m.sources.get(node.span.file)
    base = source.path.parent if source is not None and source.path is not None else Path(node.span.file).parent
    path = base / path_arg.value
    shown = os.path.normpath(os.path.join(os.path.dirname(node.span.file), path_arg.value))
    key = str(path)
    if key not in m.csv_headers:
        from bondc.runtime import CsvError, csv_header      # (numpy: only for a model that reads a csv file)

        try:
            m.csv_headers[key] = csv_header(path)      # the simulator's own reader
        except CsvError as problem:
            m.csv_headers[key] = str(problem).rpartition(": ")[2]
        except (OSError, UnicodeDecodeError, csv.Error):
            m.csv_headers[key] = None
    header = m.csv_headers[key]
    if isinstance(header, str):
        report(error_at(codes.E310, f"cannot read CSV file '{path_arg.value}': {header}", path_arg.span,
                        hint="a data file is a regular text file with a header line"))
    elif header is None:
        report(error_at(codes.E310, f"cannot read CSV file '{path_arg.value}'", path_arg.span,
                        hint=f"the path is relative to the model file: looked for '{shown}'"))
    elif not header or not any(header):
        report(error_at(codes.E310, f"CSV file '{path_arg.value}' has no header line", path_arg.span,
                        hint="the first line names the columns, e.g. t,omega"))
    elif column_arg.value not in header and not _is_table(path, header):
        # a model may name any file (/etc/passwd, /proc/self/environ): what is not a table is not quoted
        report(error_at(codes.E310, f"'{path_arg.value}' is not a CSV table", path_arg.span,
                        hint="a data file is a header line of column names separated by commas (time first), "
                             "then rows of numbers"))
    elif column_arg.value not in header:
        columns = [c for c in header if c]
        report(error_at(codes.E310, f"CSV file '{path_arg.value}' has no column '{column_arg.value}'", column_arg.span,
                        hint=join_hints(did_you_mean(column_arg.value, columns), f"its columns: {', '.join(columns)}")))
    elif len(header) < 2:
        report(error_at(codes.E310, f"CSV file '{path_arg.value}' needs a time column and a value column",
                        path_arg.span, hint="the first column (or the column t or time) is time"))
    else:
        from bondc.numeric import csv_scales

        try:
            csv_scales(str(path), column_arg.value)
        except ValueError as problem:
            report(error_at(codes.E310, f"CSV file '{path_arg.value}': {problem} in its header", column_arg.span,
                            hint="a header names a column's unit in brackets, e.g. 'omega [rpm]', 't [ms]'; "
                                 "a column without one is SI"))
            return
        from bondc.runtime import CsvError, load_csv

        try:
            load_csv(path, column_arg.value)        # the data rows, as the simulation reads them
        except CsvError as problem:
            report(error_at(codes.E310, f"CSV file '{path_arg.value}': {str(problem).partition(': ')[2]}",
                            path_arg.span, hint="rows (after the header, not counting blank lines and # comments) "
                                                "are numbers, times in increasing order"))
        except (OSError, UnicodeDecodeError, csv.Error):
            report(error_at(codes.E310, f"cannot read CSV file '{path_arg.value}'", path_arg.span))


def check_expr(m: CheckContext, expr: ast.Expr, scope: ExprScope) -> bool:
    """Check one expression in its scope; remember and return whether it had no errors."""
    checker = _ExpressionChecker(m, scope)
    checker.check(expr)
    m.expr_ok[id(expr)] = checker.errors == 0
    return checker.errors == 0


def calls_in(expr: ast.Expr) -> list[str]:
    return [node.func for node in ast.walk(expr) if isinstance(node, ast.Call)]


def names_in(expr: ast.Expr) -> list[str]:
    return [node.name for node in ast.walk(expr) if isinstance(node, ast.Name)]


def cycles(order: Sequence[str], edges: Mapping[str, Sequence[str]]) -> list[list[str]]:
    """Each dependency cycle once, as the list of its members starting at the earliest in ``order``."""
    rank = {name: index for index, name in enumerate(order)}
    state: dict[str, str] = {}
    found: list[list[str]] = []
    seen: set[frozenset[str]] = set()

    def visit(name: str, stack: list[str]) -> None:
        state[name] = "visiting"
        stack.append(name)
        for target in edges.get(name, ()):
            if target not in rank:
                continue
            if state.get(target) == "visiting":
                cycle = stack[stack.index(target):]
                start = min(range(len(cycle)), key=lambda i: rank[cycle[i]])
                cycle = cycle[start:] + cycle[:start]
                if frozenset(cycle) not in seen:
                    seen.add(frozenset(cycle))
                    found.append(cycle)
            elif target not in state:
                visit(target, stack)
        stack.pop()
        state[name] = "done"

    for name in order:
        if name not in state:
            visit(name, [])
    return found


class ParamsAbove:
    """The parameters declared above the one at ``index`` (``name in above``), without a copy."""

    __slots__ = ("order", "index")

    def __init__(self, order: Mapping[str, int], index: int):
        self.order, self.index = order, index

    def __contains__(self, name) -> bool:
        return self.order.get(name, self.index) < self.index
