"""Names and kinds: takes the declared :class:`~bondc.semantic.context._Model` and reports
reserved and duplicate names, unknown element and junction kinds (read from
:data:`bondc.kinds.KINDS`) and parameters hidden by an element's own variables. Returns
nothing: diagnostics go to the model.
"""

from __future__ import annotations

from bondc import ast
from bondc.errors import Related
from bondc.flatten import KIND_CODES
from bondc.kinds import JUNCTION_KINDS, KINDS
from bondc.semantic.context import (
    BUILTINS, RESERVED, a_or_an, CheckContext, Decl, did_you_mean, error_at, join_hints, quoted, warning_at,
)
from bondc import codes


def check_reserved_names(m: CheckContext) -> None:
    """E315: ``t`` and ``pi`` cannot be defined; a function cannot take a built-in's name."""
    for decl in m.all_decls:
        if decl.name in RESERVED:
            m.report(error_at(codes.E315, f"'{decl.name}' is reserved for {RESERVED[decl.name]} and cannot name "
                                      f"{a_or_an(decl.category)}", decl.span,
                              hint=f"choose another name, e.g. '{decl.name}_'"))
        elif decl.category == "function" and decl.name in BUILTINS:
            m.report(error_at(codes.E315, f"'{decl.name}' is a built-in function and cannot be redefined", decl.span,
                              hint=f"choose another name, e.g. 'my_{decl.name}'"))


def check_duplicate_names(m: CheckContext) -> None:
    """E302: one namespace per model; experiments, function arguments, settings each their own."""
    first: dict[str, Decl] = {}
    for decl in m.all_decls:
        earlier = first.setdefault(decl.name, decl)
        if earlier is not decl:
            m.report(error_at(
                codes.E302, f"'{decl.name}' is defined twice", decl.span,
                hint="elements, junctions, parameters, inputs, outputs, states, functions and bond labels "
                     "share one namespace; rename one of them",
                related=[Related(earlier.span, f"first defined here, as {a_or_an(earlier.category)}")]))
    seen_experiments: dict[str, ast.Experiment] = {}
    for experiment in m.experiments:
        first_experiment = seen_experiments.setdefault(experiment.name, experiment)
        if first_experiment is not experiment:
            m.report(error_at(codes.E302, f"experiment '{experiment.name}' is defined twice", experiment.name_span,
                              related=[Related(first_experiment.name_span, "first defined here")]))
    for function in m.functions.values():
        seen: set[str] = set()
        for name in function.params:
            if name in seen:
                m.report(error_at(codes.E302, f"function '{function.name}' has two arguments named '{name}'",
                                  function.name_span))
            seen.add(name)


def check_kinds(m: CheckContext) -> None:
    """E303 unknown element kind, E407 junction kind other than 0 or 1."""
    nodes = {d.name for d in m.all_decls if d.category in ("element", "junction")}
    # a kind the flattener already reported (E330 no such model in a library, E331 defined twice)
    reported = {(d.span.file, d.span.start) for d in m.diagnostics if d.code in KIND_CODES and d.span}
    models = {model.name for file in m.files for model in file.models} - {m.model.name}
    for element in m.statements(ast.Element):
        if element.kind in KINDS or (element.kind_span.file, element.kind_span.start) in reported:
            continue
        hint = join_hints(did_you_mean(element.kind, set(KINDS) | models),
                           f"element kinds are: {' '.join(KINDS)}"
                           + (", or a model defined or imported here" if models else ""))
        if element.kind in nodes:
            hint = f"to connect '{element.kind}' and '{element.name}' with a bond, write " \
                   f"'{element.kind} -> {element.name}'"
        m.report(error_at(codes.E303, f"unknown element kind '{element.kind}'", element.kind_span, hint=hint))
    for junction in m.statements(ast.Junction):
        if junction.kind not in JUNCTION_KINDS:
            m.report(error_at(codes.E407, f"unknown junction kind '{junction.kind}'", junction.kind_span,
                              hint="a junction is 0 (common effort, flows sum to zero) or "
                                   "1 (common flow, efforts sum to zero)"))


def check_shadowing(m: CheckContext) -> None:
    """W303: a model name hidden inside element laws by an element's own e, f or state."""
    one_ports = [e for e in m.elements if m.known_kind(e.name) and KINDS[e.kind].ports == 1]
    for decl in m.decls.values():
        if decl.category in ("element", "junction", "bond label", "function"):
            continue
        if decl.name in ("e", "f") and one_ports:
            meaning = "effort" if decl.name == "e" else "flow"
            m.report(warning_at(codes.W303, f"{decl.category} '{decl.name}' is hidden inside element laws", decl.span,
                                hint=f"in an element's laws '{decl.name}' is the element's own {meaning}; "
                                     f"rename the {decl.category} to use it there"))
            continue
        if decl.category not in ("parameter", "input"):
            continue  # an output or state of the same name as an element's state is usually that state
        owners = [name for name, laws in m.element_laws.items() if decl.name in laws.state_names]
        if owners:
            m.report(warning_at(codes.W303, f"{decl.category} '{decl.name}' is hidden inside the laws of "
                                        f"{quoted(owners)}", decl.span,
                                hint=f"there '{decl.name}' is the element's own state; rename one of them"))
