"""Parameters: takes the model and the command line's ``--set`` values; gathers each parameter's
definition (declaration, experiment or ``--set`` override), evaluates them in dependency order
to SI values and checks what needs the values (constants, divisions by parameters). Returns the
definitions and the values.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

from bondc import ast
from bondc.errors import Diagnostic, Related
from bondc.evaluate import EvaluationError, evaluate
from bondc.model import Parameter
from bondc.source import Span
from bondc.semantic.context import a_or_an, CheckContext, Definition, did_you_mean, error_at, input_value
from bondc.semantic.expressions import CONSTANT, calls_in, check_expr, cycles, names_in
from bondc.semantic.rules import BINDING_RULE, OVERRIDE_RULE, scope_for
from bondc.semantic.unit_checks import COMPUTED_WHY, is_constant, require_coherent, resolve_unit
from bondc import codes


def parameter_definitions(m: CheckContext) -> dict[str, Definition]:
    """Every parameter's declaration, with the values its instance binds (section 11)."""
    definitions = {p.name: Definition(p.name, p.value, p.unit, p.span, p.unit, "declaration") for p in m.params
                   if m.decls.get(p.name) is not None and m.decls[p.name].node is p}
    for binding in m.good_bindings:
        override(binding.name, binding.value, binding.unit, binding.span, binding.origin, definitions)
    return definitions


def check_bindings(m: CheckContext) -> None:
    """An instance's parameter bindings: the value fits the parameter as an override would."""
    m.good_bindings = [b for b in m.bindings
                       if check_override(m, b.name, b.name_span, b.value, b.unit, b.origin)]


def override(name: str, expr: ast.Expr, unit: ast.Unit | None, span: Span, origin: str,
              definitions: dict[str, Definition]) -> None:
    """Replace the definition of parameter ``name`` (if it is one) by an override."""
    base = definitions.get(name)
    if base is not None:
        definitions[name] = Definition(name, expr, unit, span, base.declared_unit, origin)


def check_override(m: CheckContext, name: str, name_span: Span, expr: ast.Expr, unit: ast.Unit | None,
                    where: str) -> bool:
    """An experiment's ``param`` or a ``--set``: the name is a parameter, the value and unit fit it."""
    decl = m.decls.get(name)
    if decl is None or not isinstance(decl.node, ast.Param):
        what = f"; '{name}' is {a_or_an(decl.category)}" if decl is not None else ""
        m.report(error_at(codes.E301, f"{where} sets '{name}', which is not a parameter{what}", name_span,
                          hint=did_you_mean(name, m.names("parameter"))))
        return False
    m.used.add(name)
    if where.startswith("instance "):       # a component's parameter bound in an instance
        scope = scope_for(m, f"the value of parameter '{name.rsplit('.', 1)[-1]}' in {where}", CONSTANT,
                       BINDING_RULE)
    else:
        scope = scope_for(m, "an override", CONSTANT, OVERRIDE_RULE)
    ok = check_expr(m, expr, scope)
    if is_constant(expr):
        resolved = resolve_unit(m, unit)
    else:
        resolved = require_coherent(m, unit, f"the value of '{name}'", COMPUTED_WHY.format("the value"))
    declared_unit = decl.node.unit
    declared = resolve_unit(m, declared_unit)
    if (unit is not None and declared_unit is not None and resolved is not None and declared is not None
            and resolved.dims != declared.dims):
        m.report(error_at(codes.E204, f"[{unit.text}] does not measure the same quantity as [{declared.text}], the unit "
                                  f"of '{name}'", unit.span,
                          hint=f"give the value in [{declared.text}] or a unit of the same kind "
                               f"({declared.dimension_text()})",
                          related=[Related(declared_unit.span, f"'{name}' is declared in [{declared.text}] here")]))
        ok = False
    return ok


def evaluate_parameters(m: CheckContext, definitions: Mapping[str, Definition]) -> dict[str, float]:
    """Every parameter's SI value, in dependency order; problems reported, failed ones left out."""
    order = list(definitions)
    edges = {name: [n for n in names_in(d.expr) + _names_in_functions(m, d.expr) if n in definitions]
             for name, d in definitions.items()}
    in_cycle: set[str] = set()
    for cycle in cycles(order, edges):
        in_cycle.update(cycle)
        overridden = [n for n in cycle if definitions[n].origin != "declaration"]
        if not overridden:
            continue  # a cycle of declarations always has a forward reference, reported as such
        culprit = definitions[overridden[0]]
        path = " -> ".join(cycle + [cycle[0]])
        m.report(error_at(codes.E305, f"parameter dependency cycle: {path}", culprit.span,
                          hint=f"the value from {culprit.origin} makes '{culprit.name}' depend on itself",
                          related=[Related(definitions[n].span, f"'{n}' is defined here") for n in cycle
                                   if n != culprit.name]))
    values: dict[str, float] = {}
    failed: set[str] = set(in_cycle)
    done: set[str] = set()

    def visit(name: str) -> None:
        if name in done:
            return
        done.add(name)
        for dependency in edges[name]:
            if dependency not in in_cycle:
                visit(dependency)
        definition = definitions[name]
        if name in failed or any(d in failed for d in edges[name]) or not m.expr_ok.get(id(definition.expr), True) \
                or _function_closure(m, calls_in(definition.expr)) & m.bad_functions:
            failed.add(name)
            return
        value = _definition_value(m, definition, values)
        if value is None:
            failed.add(name)
        else:
            values[name] = value

    for name in order:
        visit(name)
    return values


def _names_in_functions(m: CheckContext, expr: ast.Expr) -> list[str]:
    """The names the bodies of the functions ``expr`` calls use (a model's function may use its
    parameters), arguments left out."""
    found: list[str] = []
    for name in sorted(_function_closure(m, calls_in(expr))):
        function = m.functions.get(name)
        if function is not None:
            found += [n for n in names_in(function.body) if n not in function.params]
    return found


def _function_closure(m: CheckContext, names: Iterable[str]) -> set[str]:
    found: set[str] = set()
    todo = [n for n in names if n in m.functions]
    while todo:
        name = todo.pop()
        if name in found:
            continue
        found.add(name)
        todo += [c for c in calls_in(m.functions[name].body) if c in m.functions]
    return found


def _definition_value(m: CheckContext, definition: Definition, values: Mapping[str, float]) -> float | None:
    """A parameter's SI value: a constant is converted by its unit (or the declared one), an expression is SI."""
    try:
        value = evaluate(definition.expr, values, m.functions, m.budget)
    except EvaluationError as error:
        if not error.repeated:
            m.report(error.diagnostic)
        return None
    if not is_constant(definition.expr):
        return value
    unit = definition.unit if definition.unit is not None else definition.declared_unit
    resolved = m.units.get(id(unit)) if unit is not None else None
    if unit is not None and resolved is None:
        return None
    if resolved is None or unit is None:
        return value
    return finite_si(m, resolved.to_si(value), value, unit, definition.expr.span)


def finite_si(m: CheckContext, si: float, value: float, unit: ast.Unit, span: Span) -> float | None:
    """A number converted to SI, or None with E311 where the conversion leaves a double's range
    (``1e308 [kN/m]`` is 1e311 N/m: inf, which no law and no generated module can use)."""
    if math.isfinite(si):
        return si
    m.report(error_at(codes.E311, f"cannot evaluate: {value:g} [{unit.text}] is {'an infinite' if si == si else 'no'} "
                              f"number in SI units (beyond a double's range, about 1.8e308)", span,
                      hint="write the value in a unit closer to SI, or a smaller value"))
    return None


def parameters_of(m: CheckContext, definitions: Mapping[str, Definition],
                values: Mapping[str, float]) -> dict[str, Parameter]:
    out = {}
    for name, definition in definitions.items():
        declared = m.decls[name].node
        unit = definition.unit if definition.unit is not None else definition.declared_unit
        resolved = m.units.get(id(unit)) if unit is not None else None
        out[name] = Parameter(name, values[name], definition.expr, unit.text if unit is not None else None,
                              declared.description if isinstance(declared, ast.Param) else None, declared.span,
                              resolved.factor if resolved is not None else 1.0)
    return out


def check_constants(m: CheckContext, values: Mapping[str, float]) -> None:
    """E311/E306 for constants outside parameters: initial values and table breakpoints."""
    constants: list[ast.Expr] = []
    for laws in m.element_laws.values():
        constants += [law.value for law in laws.initials.values()]
    constants += [laws.initial.value for laws in m.model_states.values() if laws.initial is not None]
    constants += [input_value(signal) for signal in m.inputs if signal.external]      # external inputs' defaults
    for expr in constants:
        try_evaluate(m, expr, values)
    for expr in _all_expressions(m):
        if not m.expr_ok.get(id(expr), False):
            continue
        for node in ast.walk(expr):
            if isinstance(node, ast.Call) and node.func == "table" and len(node.args) == 3 \
                    and isinstance(node.args[1], ast.ListExpr):
                _check_breakpoints(m, node.args[1], values)


def check_divisors(m: CheckContext, values: Mapping[str, float]) -> None:
    """E311: a law, output, input or rate that divides by parameters whose value is 0 (``p/m`` with
    ``m = 0``): every evaluation of it would be inf or nan. The divisions are kept on the graph
    (``BondGraph.divisors``) so that values bound later (a sweep's points) are checked the same way
    (:func:`zero_divisors`)."""
    exprs = [input_value(i) for i in m.inputs] + [o.value for o in m.outputs]
    for element in m.elements:
        exprs += [law.value for law in element.laws if isinstance(law, (ast.LawAssign, ast.LawCall))]
    for state in m.statements(ast.StateDecl):
        exprs += [law.value for law in state.laws if isinstance(law, (ast.LawAssign, ast.LawCall))]
    def unguarded(node):
        """The sub-expressions outside every if-branch (a guarded division may well be by 0)."""
        yield node
        if isinstance(node, ast.If):
            return
        for child in (getattr(node, "args", None) or getattr(node, "items", None) or
                      [getattr(node, k) for k in ("operand", "left", "right") if hasattr(node, k)]):
            yield from unguarded(child)

    divisors: list[tuple[ast.Expr, tuple[str, ...]]] = []
    for expr in exprs:
        if not m.expr_ok.get(id(expr), False):
            continue
        for node in unguarded(expr):
            if not (isinstance(node, ast.Binary) and node.op == "/"):
                continue
            names = [n for n in ast.walk(node.right) if isinstance(n, (ast.Name, ast.Ref, ast.Call))]
            parameters = [n.name for n in names if isinstance(n, ast.Name) and n.name in values]
            if names and len(parameters) == len(names):
                divisors.append((node.right, tuple(dict.fromkeys(parameters))))
    m.divisors = tuple(divisors)
    for diagnostic in zero_divisors(m.divisors, values):
        m.report(diagnostic)


def zero_divisors(divisors, values: Mapping[str, float]) -> list[Diagnostic]:
    """E311 for each division of ``divisors`` (``BondGraph.divisors``: divisor and the parameters it
    uses) whose divisor is 0 with the parameter values ``values`` (name -> SI value)."""
    found = []
    for divisor, names in divisors:
        if not all(name in values for name in names):
            continue
        try:
            value = evaluate(divisor, values, {})
        except EvaluationError:
            continue
        if value == 0:
            used = ", ".join(f"{name} = {values[name]:g}" for name in names)
            found.append(error_at(codes.E311, f"a division by zero: the divisor is 0 with {used}", divisor.span,
                                  hint="a parameter that divides must not be 0; check its value and the "
                                       "experiment's and --set overrides"))
    return found


def try_evaluate(m: CheckContext, expr: ast.Expr, values: Mapping[str, float], checked: bool = False) -> float | None:
    """The value of a checked constant expression, or None (with E311 reported if it has none)."""
    if not (checked or m.expr_ok.get(id(expr), False)) or _function_closure(m, calls_in(expr)) & m.bad_functions:
        return None
    if any(name not in values and name != "pi" for name in names_in(expr)):
        return None  # uses a parameter that failed (already reported), or a function argument
    try:
        return evaluate(expr, values, m.functions, m.budget)
    except EvaluationError as error:
        if not error.repeated:
            m.report(error.diagnostic)
        return None


def _check_breakpoints(m: CheckContext, breakpoints: ast.ListExpr, values: Mapping[str, float]) -> None:
    points = []
    for item in breakpoints.items:
        value = try_evaluate(m, item, values, checked=True)
        if value is None:
            return
        points.append((value, item))
    for (previous, _), (value, item) in zip(points, points[1:]):
        if value < previous:
            m.report(error_at(codes.E306, f"table breakpoints must not decrease: {value:g} comes after {previous:g}",
                              item.span, hint="list the breakpoints in increasing order"))
            return


def _all_expressions(m: CheckContext) -> list[ast.Expr]:
    exprs = [p.value for p in m.params] + [input_value(i) for i in m.inputs] + [o.value for o in m.outputs]
    for element in m.elements:
        for law in element.laws:
            if isinstance(law, (ast.LawAssign, ast.LawCall)):
                exprs.append(law.value)
    for state in m.statements(ast.StateDecl):
        exprs += [law.value for law in state.laws if isinstance(law, (ast.LawAssign, ast.LawCall))]
    exprs += [discrete.value for discrete in m.statements(ast.Discrete)]
    for when in m.statements(ast.When):
        exprs.append(when.condition)
        for action in when.actions:
            exprs += [action.value] if isinstance(action, ast.WhenAssign) else list(action.args)
    for experiment in m.experiments:
        exprs += [input_value(item) if isinstance(item, ast.Input) else item.value for item in experiment.body]
    exprs += [f.body for f in m.functions.values()]
    return exprs
