"""Which names each statement may use: takes the model with its laws; checks functions
(recursion, arity), parameters, inputs, outputs, states, ``when`` clauses and element laws
against their scope (:mod:`bondc.semantic.expressions`) and the inputs' dependency cycles.
Returns nothing: diagnostics go to the model.
"""

from __future__ import annotations

from typing import Mapping, Sequence

from bondc import ast
from bondc.errors import Related
from bondc.kinds import KINDS
from bondc.semantic.context import a_or_an, CheckContext, did_you_mean, ElementLaws, error_at, input_value, quoted
from bondc.semantic.expressions import (
    CONSTANT, DISCRETE_RULE, DISCRETE_START, GENERAL, SIGNAL, calls_in, check_expr, cycles, ExprScope, names_in,
    ParamsAbove,
)
from bondc import codes


_PARAMETER_RULE = "a parameter is a constant: numbers, parameters defined above it, pi and functions"
OVERRIDE_RULE = "an override is a constant: numbers, parameters, pi and functions"
BINDING_RULE = ("a parameter is a constant: numbers, parameters, pi and functions; a value that varies "
                 "needs an input of the component (bind it to any signal) or an element of your own")
CONSTANT_RULE = "{} is a constant: numbers, parameters, pi and functions"
INPUT_RULE = ("an input is a signal of t, parameters and other inputs (table, step, csv, functions); "
               "feedback from the states goes into an element's law, a modulated source's for a controller "
               "(MSe drive : e = Kp*(x_ref - mass.q))")
_EXTERNAL_RULE = ("an external input's default is a constant: numbers, parameters, pi and functions; the host "
                  "supplies the signal itself (a table of times and values, a function of t or a CSV file)")
_GENERAL_RULE = ("an expression may use parameters, inputs, outputs, model states, t, functions and graph "
                 "variables (X.e, X.f, X.q, J.e, b3.f)")


def scope_for(m: CheckContext, what: str, allowed: frozenset[str], rule: str, **extra) -> ExprScope:
    return ExprScope(what=what, allowed=allowed, rule=rule, functions=m.functions, **extra)


def check_functions(m: CheckContext) -> None:
    """Names in function bodies (their arguments only) and E304 recursion."""
    for decl in m.all_decls:
        function = decl.node
        if not isinstance(function, ast.FnDef) or m.decls[decl.name] is not decl:
            continue
        file_level = function.name in m.file_functions and m.file_functions[function.name] is function
        callable_ = m.file_functions if file_level else m.functions
        arguments = ", ".join(function.params) or "none"
        allowed: frozenset[str]
        if file_level:
            allowed, rule = frozenset(), (f"a file-level function uses only its arguments ({arguments}), pi, "
                                          f"numbers and functions; pass other values as arguments")
        else:       # a function inside a model may also use the model's parameters (constants)
            allowed, rule = frozenset({"parameter"}), (f"a function uses its arguments ({arguments}), the "
                                                       f"model's parameters, pi, numbers and functions; pass "
                                                       f"signals and graph variables as arguments")
        scope = ExprScope(what=f"function '{function.name}'", allowed=allowed, functions=callable_, rule=rule,
                       local={p: "argument" for p in function.params}, constant_locals=True)
        check_expr(m, function.body, scope)
    calls = {name: [c for c in calls_in(f.body) if c in m.functions] for name, f in m.functions.items()}
    for cycle in cycles(list(m.functions), calls):
        m.bad_functions.update(cycle)
        first = m.functions[cycle[0]]
        path = " -> ".join(cycle + [cycle[0]])
        message = (f"function '{cycle[0]}' calls itself" if len(cycle) == 1
                   else f"functions {quoted(cycle)} call each other")
        m.report(error_at(codes.E304, f"{message}: {path}", first.name_span,
                          hint="functions cannot be recursive; write the repetition out",
                          related=[Related(m.functions[name].name_span, f"'{name}' is defined here")
                                   for name in cycle[1:]]))


def check_expressions(m: CheckContext) -> None:
    """Every expression of the model: E301, E305, E306, E310, E312, E313, E316, E506."""
    order: dict[str, int] = {}
    for index, param in enumerate(m.params):
        order.setdefault(param.name, index)         # (a name defined twice: from its first line on)
    for index, param in enumerate(m.params):
        # (the parameters above it as a view, not a copy: a copy per parameter was quadratic, 39 s
        # for 60 000 parameters)
        scope = scope_for(m, "a parameter", CONSTANT, _PARAMETER_RULE,
                       params_before=ParamsAbove(order, index), current=param.name)
        check_expr(m, param.value, scope)
    for signal in m.inputs:
        if signal.external:
            check_expr(m, input_value(signal), scope_for(m, f"the default of external input '{signal.name}'", CONSTANT,
                                                _EXTERNAL_RULE, code=codes.E344))
        else:
            check_expr(m, input_value(signal), scope_for(m, "an input", SIGNAL, INPUT_RULE))
    for output in m.outputs:
        check_expr(m, output.value, scope_for(m, "an output", GENERAL, _GENERAL_RULE))
    for element in m.elements:
        if element.name in m.element_laws:
            _check_element_expressions(m, element, m.element_laws[element.name])
    for state in m.statements(ast.StateDecl):
        laws = m.model_states[state.name]
        if laws.rate is not None:
            check_expr(m, laws.rate.value, scope_for(m, f"the rate of state '{state.name}'", GENERAL, _GENERAL_RULE))
        if laws.initial is not None:
            check_expr(m, laws.initial.value, scope_for(m, "an initial value", CONSTANT,
                                                      CONSTANT_RULE.format("an initial value")))
    for discrete in m.statements(ast.Discrete):     # parameters, and inputs and initial states at t = 0
        check_expr(m, discrete.value, scope_for(m, f"the initial value of discrete variable '{discrete.name}'",
                                              DISCRETE_START, DISCRETE_RULE))
    for when in m.statements(ast.When):
        _check_when(m, when)


_WHEN_RULE = ("a when clause's statements are NAME = EXPR, for a discrete variable, and reinit(STATE, EXPR), "
              "for a state (X.q, X.p, a custom or a model state)")


def _check_when(m: CheckContext, when: ast.When) -> None:
    """The condition and the statements of a ``when`` clause: targets are discrete variables
    (``NAME = ...``) or states (``reinit(STATE, ...)``), E301/E306/E316 otherwise."""
    scope = scope_for(m, "a when clause", GENERAL, _GENERAL_RULE)
    check_expr(m, when.condition, scope)
    for action in when.actions:
        if isinstance(action, ast.WhenAssign):
            decl = m.decls.get(action.name)
            if decl is None:
                m.report(error_at(codes.E301, f"undefined name '{action.name}'", action.name_span,
                                  hint=did_you_mean(action.name, m.names("discrete")) or _WHEN_RULE))
            elif decl.category != "discrete":
                m.report(error_at(codes.E316, f"a when clause cannot assign {a_or_an(decl.category)} ('{action.name}')",
                                  action.name_span, hint=_WHEN_RULE))
            else:
                m.used.add(action.name)
            check_expr(m, action.value, scope)
            continue
        if action.func != "reinit":
            m.report(error_at(codes.E301, f"unknown statement '{action.func}(...)' in a when clause", action.func_span,
                              hint=_WHEN_RULE))
            continue
        if len(action.args) != 2:
            m.report(error_at(codes.E306, f"reinit() takes 2 arguments, {len(action.args)} given", action.span,
                              hint="write reinit(STATE, new value)"))
            continue
        target, value = action.args
        if check_expr(m, target, scope) and _reinit_target(m, target) is None:
            m.report(error_at(codes.E316, "reinit() sets a state: X.q, X.p, a custom state X.NAME or a model state",
                              target.span, hint=_WHEN_RULE))
        check_expr(m, value, scope)


def _reinit_target(m: CheckContext, target) -> str | None:
    """The qualified state ``target`` names (``ball.p``, ``x``), or None."""
    if isinstance(target, ast.Name):
        decl = m.decls.get(target.name)
        return target.name if decl is not None and decl.category == "state" else None
    if isinstance(target, ast.Ref) and len(target.parts) == 2:
        head, name = target.parts
        kind = m.known_kind(head)
        laws = m.element_laws.get(head)
        if kind is None or laws is None or not KINDS[kind].storage:
            return None
        states = set(laws.state_names) | {KINDS[kind].state}
        return f"{head}.{name}" if name in states else None
    return None


def _own_variable_rules(kind_name: str, target: str, name: str,
                        states: Sequence[str]) -> tuple[dict[str, str], str]:
    """Which of its own variables an element's ``target = ...`` law may not use and why (E506), and its rule."""
    kind = KINDS[kind_name]
    own = f"{kind_name} '{name}'"
    itself = f"the law {target} = ... of {own} cannot use {target} itself"
    other = "f" if target == "e" else "e"
    other_word = "flow" if other == "f" else "effort"
    if kind.source:
        return ({target: itself,
                 other: f"the law {target} = ... of source {own} cannot use its own {other_word} {other}: a "
                        f"source is independent of its load"},
                "a source's law may use parameters, inputs, t and other elements' variables, not its own e or f "
                "(for a load-dependent source use an R)")
    if kind.storage:
        listing = ", ".join(states)
        return ({target: itself,
                 other: f"the law {target} = ... of {own} is a function of its state, not of its {other_word} "
                        f"{other}"},
                f"the law {target} = ... of {a_or_an(kind_name)} may use its states ({listing}), parameters, inputs, t "
                f"and other elements' variables, not its own e or f")
    if kind.ports == 1:
        return ({target: itself},
                f"the law {target} = ... of {a_or_an(kind_name)} may use its {other_word} {other}, not {target} itself")
    return {}, "a two-port's law may use parameters, inputs, t and other elements' variables"


def _check_element_expressions(m: CheckContext, element: ast.Element, laws: ElementLaws) -> None:
    kind = KINDS[element.kind]
    local: dict[str, str] = {}
    if kind.ports == 1:
        local = {"e": "effort", "f": "flow", **{s: "state" for s in laws.state_names}}
    for target, law in laws.assigns.items():
        forbidden, rule = _own_variable_rules(element.kind, target, element.name, laws.state_names)
        scope = scope_for(m, f"the law {target} = ... of {element.kind} '{element.name}'", GENERAL, rule,
                       local=local, forbidden=forbidden, owner=element.name)
        check_expr(m, law.value, scope)
    for name, rate in laws.rates.items():
        scope = scope_for(m, f"the rate of state '{name}' of '{element.name}'", GENERAL,
                       "a rate law may use the element's e, f and states, parameters, inputs, t and other "
                       "elements' variables", local=local, owner=element.name)
        check_expr(m, rate.value, scope)
    not_constant = {n: f"an initial value is a constant and cannot use the {what} '{n}' of '{element.name}'"
                    for n, what in local.items() if n not in m.decls}
    for name, initial in laws.initials.items():
        scope = scope_for(m, "an initial value", CONSTANT, CONSTANT_RULE.format("an initial value"),
                       forbidden=not_constant)
        check_expr(m, initial.value, scope)


def check_signal_cycles(m: CheckContext, inputs: Mapping[str, ast.Input] | None = None) -> None:
    """E305: inputs defined in terms of each other, outputs defined in terms of each other."""
    groups = (("input", inputs if inputs is not None else {i.name: i for i in m.inputs}),
              ("output", {o.name: o for o in m.outputs}))
    for category, defs in groups:
        edges = {name: names_in(input_value(d) if isinstance(d, ast.Input) else d.value)
                 for name, d in defs.items()}
        for cycle in cycles(list(defs), edges):
            path = " -> ".join(cycle + [cycle[0]])
            m.report(error_at(codes.E305, f"{category}s defined in terms of each other: {path}",
                              defs[cycle[0]].name_span,
                              related=[Related(defs[n].name_span, f"'{n}' is defined here") for n in cycle[1:]],
                              hint=f"an {category} cannot depend on itself, directly or through other {category}s"))
