"""Element laws and model states: takes the model with its bonds; checks the laws each element
kind allows and requires (:data:`bondc.kinds.KINDS`), storage elements' own states, rates and
initial values, and model-level states. Fills ``m.element_laws`` and ``m.model_states``.
"""

from __future__ import annotations

from bondc import ast
from bondc.errors import Related
from bondc.kinds import KINDS
from bondc.semantic.context import a_or_an, CheckContext, did_you_mean, ElementLaws, error_at, join_hints, StateLaws
from bondc import codes


def _kind_takes(kind_name: str) -> str:
    """The laws a kind takes, for hints: "e = ... and q(0) = ... (or its own states: ...)"."""
    kind = KINDS[kind_name]
    if kind.ports == 2:
        return "r = ..."
    laws = " and/or ".join(f"{law} = ..." for law in sorted(kind.laws))
    if kind.storage:
        return f"{laws} and {kind.state}(0) = ..., or its own states: state X, der(X) = ..., X(0) = ..."
    return laws


def check_laws(m: CheckContext) -> None:
    """E501-E505: the laws each element kind takes, needs and may not repeat; states and rates."""
    for element in m.elements:
        if element.kind in KINDS:
            m.element_laws[element.name] = _check_element_laws(m, element)


def _check_element_laws(m: CheckContext, element: ast.Element) -> ElementLaws:
    kind = KINDS[element.kind]
    laws = ElementLaws()
    calls: list[ast.LawCall] = []
    for law in element.laws:
        if isinstance(law, ast.LawState):
            if not kind.storage:
                m.report(error_at(codes.E505, f"{element.kind} '{element.name}' cannot declare states", law.span,
                                  hint=f"only storage elements (C, I) have states; "
                                       f"{a_or_an(element.kind)} takes {_kind_takes(element.kind)}"))
            elif law.name in ("e", "f"):
                m.report(error_at(codes.E505, f"a state cannot be called '{law.name}'", law.name_span,
                                  hint="e and f are the element's effort and flow; choose another name"))
            elif law.name in laws.custom:
                m.report(error_at(codes.E503, f"state '{law.name}' of '{element.name}' is declared twice", law.name_span,
                                  related=[Related(laws.custom[law.name].name_span, "first declared here")]))
            else:
                laws.custom[law.name] = law
        elif isinstance(law, ast.LawAssign):
            if law.target not in kind.laws:
                m.report(error_at(codes.E501, f"{element.kind} '{element.name}' cannot have a law '{law.target} = ...'",
                                  law.target_span, hint=f"{a_or_an(element.kind)} takes {_kind_takes(element.kind)}"))
            elif law.target in laws.assigns:
                m.report(error_at(codes.E503, f"'{element.name}' has two laws for {law.target}", law.target_span,
                                  related=[Related(laws.assigns[law.target].target_span, "first given here")]))
            else:
                laws.assigns[law.target] = law
        else:
            calls.append(law)
    if kind.state is not None:
        laws.state_names = tuple(laws.custom) or (kind.state,)
    for call in calls:
        _check_state_law(m, element, laws, call)
    for required in kind.required:
        if not required & set(laws.assigns):
            needed = " or ".join(f"'{law} = ...'" for law in sorted(required))
            m.report(error_at(codes.E502, f"{element.kind} '{element.name}' has no law {needed}", element.name_span,
                              hint=f"{a_or_an(element.kind)} takes {_kind_takes(element.kind)}"))
    for name, state in laws.custom.items():
        if name not in laws.rates:
            m.report(error_at(codes.E504, f"state '{name}' of '{element.name}' has no rate law", state.name_span,
                              hint=f"add 'der({name}) = ...', driven by the element's "
                                   f"{kind.stored_variable}"))
    return laws


def _check_state_law(m: CheckContext, element: ast.Element, laws: ElementLaws, call: ast.LawCall) -> None:
    kind = KINDS[element.kind]
    states = laws.state_names
    if not kind.storage:
        written = call.arg.name if call.func == "der" and isinstance(call.arg, ast.Name) else call.func
        if any(isinstance(law, ast.LawState) and law.name == written for law in element.laws):
            return  # the state itself is reported (E505)
        m.report(error_at(codes.E504, f"{element.kind} '{element.name}' has no states, so '{call.func}(...)' means nothing "
                                  f"here", call.func_span,
                          hint=f"{a_or_an(element.kind)} takes {_kind_takes(element.kind)}"))
        return
    listing = f"its states: {', '.join(states)}"
    if call.func == "der":
        target = call.arg.name if isinstance(call.arg, ast.Name) else None
        if target in laws.custom:
            _store_once(m, laws.rates, target, call, f"'{element.name}' has two rate laws for {target}")
        elif target is not None and target == kind.state and not laws.custom:
            port = kind.stored_variable or ""
            m.report(error_at(codes.E504, f"the rate of {target} is the {port} of '{element.name}' and cannot be given",
                              call.span,
                              hint=f"der({target}) = {port[-1]} always; to integrate something else, declare "
                                   f"a state: 'state X [unit], der(X) = ..., X(0) = ...'"))
        elif target is None:
            m.report(error_at(codes.E504, "der(...) takes the name of a state", call.arg.span,
                              hint=f"write der(X) = ... for a state X; {listing}"))
        else:
            m.report(error_at(codes.E504, f"der({target}): '{element.name}' has no state '{target}'", call.arg.span,
                              hint=join_hints(did_you_mean(target, states), listing)))
        return
    if call.func in states:
        if not (isinstance(call.arg, ast.Num) and call.arg.value == 0):
            m.report(error_at(codes.E504, f"an initial value is written {call.func}(0) = ...", call.arg.span))
        else:
            _store_once(m, laws.initials, call.func, call, f"'{element.name}' has two initial values for {call.func}")
        return
    m.report(error_at(codes.E504, f"'{call.func}(...)' on '{element.name}' is neither an initial value nor a rate law",
                      call.func_span,
                      hint=join_hints(did_you_mean(call.func, states + ("der",)),
                                       f"write STATE(0) = ... or der(STATE) = ...; {listing}")))


def _store_once(m: CheckContext, store: dict, key: str, law: ast.LawCall, message: str) -> None:
    if key in store:
        m.report(error_at(codes.E503, message, law.span, related=[Related(store[key].span, "first given here")]))
    else:
        store[key] = law


def check_model_states(m: CheckContext) -> None:
    """E501/E503/E504/E505 for model-level ``state x : der(x) = ..., x(0) = ...``."""
    for state in m.statements(ast.StateDecl):
        laws = StateLaws()
        m.model_states[state.name] = laws
        for law in state.laws:
            if isinstance(law, ast.LawAssign):
                m.report(error_at(codes.E501, f"state '{state.name}' has no law '{law.target} = ...'", law.target_span,
                                  hint=f"a model state takes der({state.name}) = ... and {state.name}(0) = ..."))
            elif isinstance(law, ast.LawState):
                m.report(error_at(codes.E505, f"state '{state.name}' cannot declare further states", law.span,
                                  hint="declare each model state with its own 'state' statement"))
            elif law.func == "der":
                if isinstance(law.arg, ast.Name) and law.arg.name == state.name:
                    if laws.rate is not None:
                        m.report(error_at(codes.E503, f"state '{state.name}' has two rate laws", law.span,
                                          related=[Related(laws.rate.span, "first given here")]))
                    laws.rate = laws.rate or law
                else:
                    m.report(error_at(codes.E504, f"the rate law of state '{state.name}' is written "
                                              f"der({state.name}) = ...",
                                      law.arg.span))
            elif law.func == state.name:
                if not (isinstance(law.arg, ast.Num) and law.arg.value == 0):
                    m.report(error_at(codes.E504, f"an initial value is written {state.name}(0) = ...", law.arg.span))
                elif laws.initial is not None:
                    m.report(error_at(codes.E503, f"state '{state.name}' has two initial values", law.span,
                                      related=[Related(laws.initial.span, "first given here")]))
                else:
                    laws.initial = law
            else:
                m.report(error_at(codes.E504, f"'{law.func}(...)' is neither an initial value nor a rate law of state "
                                          f"'{state.name}'", law.func_span,
                                  hint=f"write der({state.name}) = ... and {state.name}(0) = ..."))
        if laws.rate is None:
            m.report(error_at(codes.E504, f"state '{state.name}' has no rate law", state.name_span,
                              hint=f"add ': der({state.name}) = ...' (and '{state.name}(0) = ...' if not 0)"))
