"""The state equations as ``bondc equations`` prints them: text in ``.bg`` syntax
(:class:`BgPrinter`), LaTeX or JSON (:func:`format_equations`).
"""

from __future__ import annotations

import json
import math
import re

import sympy
from sympy.printing.str import StrPrinter

from bondc.statespace import StateSpace
from bondc.symbolic import External, as_sympy

FORMATS = ("text", "latex", "json")


def _display(ss: StateSpace):
    """Expansions shown by ``bondc equations``: in states, inputs, parameters and t."""
    keep = ss.input_symbols
    mapping = ss.substitution(keep)
    return lambda expr: as_sympy(expr).xreplace(mapping)


def _latex_symbol(name: str) -> str:
    r"""A name as LaTeX: Greek letters as symbols, a multi-letter name upright as one word
    (``Iz`` -> ``\mathit{Iz}``, not I times z), the part after ``_`` a subscript."""
    base, _, sub = name.partition("_")
    shown = sympy.latex(sympy.Symbol(base)) if base else ""
    leading = re.match(r"[A-Za-z]*", base)
    letters = leading.group(0) if leading else ""
    if len(letters) > 1 and not shown.startswith("\\"):       # (t1 stays t_1, as sympy writes it)
        shown = r"\mathit{%s}" % base
    return shown + (r"_{\mathrm{%s}}" % sub.replace("_", r"\_") if sub else "")


def _latex_name(name: str) -> str:
    def mathrm(text):
        return r"\mathrm{%s}" % text.replace("_", r"\_")

    if name.startswith("der(") and name.endswith(")"):
        inner = name[4:-1]
        if "." in inner:
            owner, variable = inner.rsplit(".", 1)
            return r"\dot{%s}_{%s}" % (_latex_symbol(variable), mathrm(owner))
        return r"\dot{%s}" % _latex_name(inner)
    if "." in name:
        owner, variable = name.rsplit(".", 1)
        return "%s_{%s}" % (_latex_symbol(variable), mathrm(owner))
    return _latex_symbol(name)


def format_equations(ss: StateSpace, fmt: str = "text") -> str:
    """The state and output equations for ``bondc equations`` (text, latex or json).

    Deterministic: the same model prints byte-identical text in every run.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    show = _display(ss)
    return {"text": _format_text, "latex": _format_latex, "json": _format_json}[fmt](ss, show)


def _format_json(ss: StateSpace, show) -> str:
    values = ss.initial_values()       # once: it evaluates every state's initial value
    graph = ss.graph
    data = {
        "model": graph.name,
        "states": [{"name": s.name, "unit": s.unit_text, "initial": values[s.name]} for s in ss.states],
        "inputs": [{"name": name, "unit": graph.inputs[name].unit_text, "expr": sympy.sstr(expr)}
                   for name, (_, expr) in ss.inputs.items()],
        "parameters": {name: value for name, (_, value) in ss.parameters.items()},
        "derivatives": {name: sympy.sstr(show(expr)) for name, expr in ss.derivatives.items()},
        "outputs": {name: sympy.sstr(show(expr)) for name, expr in ss.outputs.items()},
        "eliminated": {name: sympy.sstr(show(symbol)) for name, symbol in ss.eliminated.items()},
        "algebraic_blocks": [{"unknowns": [u.name for u in block.unknowns],
                              "residuals": [sympy.sstr(show(r)) for r in block.residuals]}
                             for block in ss.algebraic_blocks],
    }
    if ss.events:
        data["when"] = [{"condition": label, "condition_sympy": sympy.sstr(condition),
                         "set": {name: sympy.sstr(value) for name, value in actions}}
                        for label, condition, actions in ss.events]
    return json.dumps(data, indent=2) + "\n"


class BgPrinter(StrPrinter):
    """Expressions in ``.bg`` syntax for ``bondc equations --format text``: ``abs``, ``^``,
    ``if ... then ... else``, ``min``/``max``, ``and``/``or``/``not``, ``==``/``!=``.

    >>> x, y = sympy.symbols("x y", real=True)
    >>> bg_text(sympy.Piecewise((sympy.Abs(x - y)**sympy.Rational(3, 2), x < y), (sympy.Max(x, 1), True)))
    '(if x < y then abs(x - y)^(3/2) else max(1, x))'
    >>> bg_text(sympy.Float("0.1") * x + sympy.Float("2.5e-7"))
    '0.1*x + 2.5e-7'
    """

    def _print_Pow(self, expr, rational=False):
        return super()._print_Pow(expr, rational).replace("**", "^")

    def _call(self, name, expr):
        """``name(arguments)`` in the language's own names for sympy's functions."""
        return f"{name}({', '.join(self._print(a) for a in expr.args)})"

    def _print_Exp1(self, expr):
        return "exp(1)"

    def _print_Float(self, expr):
        # the shortest text that reads back as the same double (0.1, not sympy's 0.100000000000000)
        value = float(expr)
        if not math.isfinite(value):
            return super()._print_Float(expr)
        mantissa, _, exponent = repr(value).partition("e")
        return f"{mantissa}e{int(exponent)}" if exponent else mantissa

    def _print_Table(self, expr):
        x, breakpoints, values = expr.args
        return (f"table({self._print(x)}, [{', '.join(self._print(v) for v in breakpoints)}], "
                f"[{', '.join(self._print(v) for v in values)}])")

    def _print_Piecewise(self, expr):
        parts = []
        for value, condition in expr.args[:-1]:
            parts.append(f"if {self._print(condition)} then {self._print(value)}")
        last_value, last_condition = expr.args[-1]
        tail = self._print(last_value) if last_condition == sympy.true else \
            f"if {self._print(last_condition)} then {self._print(last_value)} else nan"
        return "(" + " else ".join(parts + [tail]) + ")" if parts else tail

    def _print_Equality(self, expr):
        return f"{self._print(expr.lhs)} == {self._print(expr.rhs)}"

    def _print_Unequality(self, expr):
        return f"{self._print(expr.lhs)} != {self._print(expr.rhs)}"

    def _print_And(self, expr):
        return " and ".join(f"({self._print(a)})" for a in expr.args)

    def _print_Or(self, expr):
        return " or ".join(f"({self._print(a)})" for a in expr.args)

    def _print_Not(self, expr):
        return f"not ({self._print(expr.args[0])})"

    def _print_BooleanTrue(self, expr):
        return "1"

    def _print_BooleanFalse(self, expr):
        return "0"


#: sympy's function -> the language's name for it, printed as ``name(arguments)``
_BG_CALLS = {"Abs": "abs", "Min": "min", "Max": "max", "ceiling": "ceil", "floor": "floor", "Mod": "mod",
             "Coulomb": "coulomb", "Step": "step", "Pwm": "pwm"}
for _function, _name in _BG_CALLS.items():
    setattr(BgPrinter, f"_print_{_function}", lambda self, expr, name=_name: self._call(name, expr))


def bg_text(expr) -> str:
    """An expression in ``.bg`` syntax (see :class:`BgPrinter`)."""
    return BgPrinter().doprint(as_sympy(expr))


def _format_text(ss: StateSpace, show) -> str:
    values = ss.initial_values()       # once: it evaluates every state's initial value
    graph = ss.graph
    head = f"model {graph.name}" + (f' "{graph.description}"' if graph.description else "")
    lines = [head]

    def section(title, rows):
        lines.append("")
        lines.append(title)
        lines.extend(f"  {row}" for row in rows or ["(none)"])

    width = max([len(s.name) for s in ss.states] + [1])
    units = [f"[{s.unit_text}]" if s.unit_text else "" for s in ss.states]
    unit_width = max([len(u) for u in units] + [0])
    rows = []
    for s, unit in zip(ss.states, units):
        initial = as_sympy(s.initial)
        value = repr(values[s.name])
        shown = value if initial.is_number else f"{bg_text(initial)} = {value}"
        cells = [s.name.ljust(width)] + ([unit.ljust(unit_width)] if unit_width else []) + [f"initial {shown}"]
        rows.append("  ".join(cells))
    section("states", rows)
    section("inputs", [f"{name} = external (default {bg_text(expr.default)})" if isinstance(expr, External)
                       else f"{name} = {bg_text(expr)}" for name, (_, expr) in ss.inputs.items()])
    section("parameters (SI)", [f"{name} = {value!r}" for name, (_, value) in ss.parameters.items()])
    section("state equations", [f"der({name}) = {bg_text(show(expr))}" for name, expr in ss.derivatives.items()])
    section("outputs", [f"{name} = {bg_text(show(expr))}" for name, expr in ss.outputs.items()])
    if ss.eliminated:
        section("eliminated states (derivative causality)",
                [f"{symbol.name} = {bg_text(show(symbol))}" for symbol in ss.eliminated.values()])
    if ss.algebraic_blocks:
        rows = []
        for block in ss.algebraic_blocks:
            rows.append(f"solve for {', '.join(u.name for u in block.unknowns)}:")
            rows += [f"  0 = {bg_text(show(r))}" for r in block.residuals]
        section("algebraic loops (solved numerically)", rows)
    if ss.events:
        section("when clauses (at the instant the condition becomes true)",
                [f"{label} then " + ", ".join(f"{name} = {bg_text(value)}" for name, value in actions)
                 for label, _, actions in ss.events])
    return "\n".join(lines) + "\n"


def _format_latex(ss: StateSpace, show) -> str:
    values = ss.initial_values()       # once: it evaluates every state's initial value
    names = {symbol: _latex_name(name) for name, symbol in ss.symbols.items()}

    def tex(expr):
        return sympy.latex(show(expr), symbol_names=names)

    lines = [f"% bondc equations of model {ss.graph.name}", "% states (initial values, SI):"]
    lines += [f"%   {s.name} = {values[s.name]!r}" for s in ss.states]
    lines += ["% parameters (SI):"] + [f"%   {name} = {value!r}" for name, (_, value) in ss.parameters.items()]
    rows = []
    for name, (symbol, expr) in ss.inputs.items():
        rows.append(f"{names[symbol]} &= {sympy.latex(expr, symbol_names=names)}")
    rows += [f"{_latex_name(f'der({name})')} &= {tex(expr)}" for name, expr in ss.derivatives.items()]
    rows += [f"{_latex_name(name)} &= {tex(expr)}" for name, expr in ss.outputs.items()]
    lines.append(r"\begin{align*}")
    lines.append(" \\\\\n".join(f"  {row}" for row in rows))
    lines.append(r"\end{align*}")
    return "\n".join(lines) + "\n"
