"""Build: takes parsed ``ast.File`` values (and their sources) and returns the checked
:class:`bondc.model.BondGraph` with its warnings, or raises :class:`bondc.errors.ModelError`
with every problem found. Selects the model and experiment, runs the checks of the sibling
modules in order, evaluates the parameters, infers dimensions and assembles the graph.
"""

from __future__ import annotations

import bisect
import dataclasses
from typing import Iterable, Mapping, Sequence

from bondc import ast
from bondc.errors import Diagnostic, ModelError, Related, sort_key
from bondc.flatten import flatten, ports_of
from bondc.kinds import KINDS
from bondc.model import (
    Bond, BondGraph, ElementNode, ExperimentDef, Function, JunctionNode, OutputDef, Parameter, Signal, StateVar,
    WhenDef,
)
from bondc.source import Source, Span
from bondc.semantic.bonds import check_bonds, check_ports, number_bonds
from bondc.semantic.context import (
    FIRST, CheckContext, declare, Definition, did_you_mean, ElementLaws, error_at, file_span, input_value,
    join_hints,
)
from bondc.semantic.experiments import (
    check_defaults, check_experiments, experiment_def, ExperimentPlan, signal_of, with_defaults,
)
from bondc.semantic.laws import check_laws, check_model_states
from bondc.semantic.lints import check_label_names, check_passive_orientation, check_unused
from bondc.semantic.names import check_duplicate_names, check_kinds, check_reserved_names, check_shadowing
from bondc.semantic.parameters import (
    check_bindings, check_constants, check_divisors, check_override, evaluate_parameters, override,
    parameter_definitions, parameters_of, try_evaluate,
)
from bondc.semantic.rules import check_expressions, check_functions, check_signal_cycles
from bondc.semantic.unit_checks import check_units, resolve_unit
from bondc import codes


def _select_model(files: Sequence[ast.File], name: str | None) -> tuple[ast.Model | None, list[Diagnostic]]:
    """The model to build: the only one in the main file, or the one named (also from imports)."""
    main = files[0]
    where = file_span(main.path)
    own = list(main.models)
    every = own + [model for file in files[1:] for model in file.models]
    listing = ", ".join(model.name for model in every) or "none"
    if name is not None:
        for model in own + every:
            if model.name == name:
                return model, []
        return None, [error_at(codes.E309, f"no model '{name}' in '{main.path}'", where,
                               hint=join_hints(did_you_mean(name, [m.name for m in every]),
                                                f"available models: {listing}"))]
    candidates = own or every
    runnable = [model for model in candidates if not ports_of(model)]   # a model with ports is a component
    if len(candidates) > 1 and len(runnable) == 1:
        return runnable[0], []
    if len(candidates) == 1:
        return candidates[0], []
    if not candidates:
        return None, [error_at(codes.E309, f"no model in '{main.path}'", where,
                               hint="a file describes a model in a 'model NAME ... end' block")]
    return None, [error_at(codes.E309, f"'{main.path}' has {len(candidates)} models; choose one with --model", where,
                           hint=f"available models: {', '.join(model.name for model in candidates)}")]


def _select_experiment(m: CheckContext, name: str | None) -> tuple[ast.Experiment | None, list[Diagnostic]]:
    if name is None:
        return None, []
    experiments = m.experiments
    if name == FIRST:
        return (experiments[0] if experiments else None), []
    for experiment in experiments:
        if experiment.name == name:
            return experiment, []
    listing = ", ".join(e.name for e in experiments) or "none"
    return None, [error_at(codes.E318, f"model '{m.model.name}' has no experiment '{name}'", file_span(m.file.path),
                           hint=join_hints(did_you_mean(name, [e.name for e in experiments]),
                                            f"its experiments: {listing}"))]


def check_sets(m: CheckContext, sets: Sequence[ast.SetValue]) -> list[ast.SetValue]:
    """The command line's ``--set`` overrides that name a parameter with a fitting value and unit."""
    good = []
    for item in sets:
        name_span = Span(item.span.file, item.span.line, item.span.column, item.span.line,
                         item.span.column + len(item.name), item.span.start, item.span.start + len(item.name))
        if check_override(m, item.name, name_span, item.value, item.unit, "an override (--set)"):
            good.append(item)
    return good


def build_files(files: Sequence[ast.File], sources: Mapping[str, Source], model: str | None, experiment: str | None,
           sets: Sequence[ast.SetValue]) -> tuple[BondGraph | None, list[Diagnostic]]:
    chosen, problems = _select_model(files, model)
    if chosen is None:
        return None, problems
    component = bool(ports_of(chosen))     # (its causality is checked where it is used)
    flat = flatten(chosen, files, standalone=component)
    if flat.too_large:
        return None, list(flat.diagnostics)
    m = CheckContext(files[0], sources, with_defaults(flat.model), tuple(files))
    m.diagnostics += flat.diagnostics
    m.bindings, m.instances = flat.bindings, flat.instances
    selected, problems = _select_experiment(m, experiment)
    m.diagnostics += problems
    declare(m)
    number_bonds(m)
    check_reserved_names(m)
    check_duplicate_names(m)
    check_kinds(m)
    check_bonds(m)
    check_ports(m)
    # what the structural checks found: with no error there, the causality of the graph's
    # structure is known whatever the laws' errors (_structural_conflicts)
    structure_known = not any(d.is_error for d in m.diagnostics)
    check_laws(m)
    check_model_states(m)
    check_shadowing(m)
    check_functions(m)
    check_expressions(m)
    check_signal_cycles(m)
    check_units(m)
    check_bindings(m)
    check_defaults(m)
    plans = check_experiments(m)
    good_sets = check_sets(m, sets)
    base, base_values = check_parameters(m, good_sets)
    check_constants(m, base_values)
    experiment_defs, chosen = check_experiment_values(m, plans, good_sets, base_values, selected)
    chosen_definitions, chosen_values = chosen or (base, base_values)
    check_divisors(m, chosen_values)
    check_passive_orientation(m)
    check_label_names(m)
    check_unused(m)

    diagnostics = sorted_unique(m.diagnostics)
    if any(d.is_error for d in diagnostics):
        if structure_known and not component:
            diagnostics = sorted_unique(diagnostics + _structural_conflicts(m, diagnostics))
        return None, diagnostics
    inputs = {i.name: signal_of(i) for i in m.inputs}
    for i in m.inputs:
        if i.external:          # its default's value (SI), for the note that says it is used
            default = try_evaluate(m, input_value(i), chosen_values)
            inputs[i.name] = dataclasses.replace(inputs[i.name], default=default)
    if selected is not None:
        inputs.update(experiment_defs[selected.name].inputs)
    graph = _graph(m, parameters_of(m, chosen_definitions, chosen_values), inputs, experiment_defs)
    dimension_errors, si_units = check_dimensions(m, graph, chosen_values)
    if dimension_errors:
        if not component:    # (the laws' targets are right: only their dimensions are not)
            from bondc.causality import structural_conflicts

            dimension_errors += structural_conflicts(graph)
        return None, sorted_unique(diagnostics + dimension_errors)
    from bondc.scope import build_scope

    return dataclasses.replace(graph, si_units=si_units, instances=tuple(m.instances),
                               scope=build_scope(m.model, m.all_decls)), diagnostics


def _structural_conflicts(m: CheckContext, diagnostics: Sequence[Diagnostic]) -> list[Diagnostic]:
    """E601: the causal conflicts of a model whose structure (elements, junctions, bonds, ports) is
    right and whose laws, parameters or experiments have errors, so that one run reports both.

    The graph is built from the structure only: no parameter, input or experiment is evaluated and
    no law is read but for which of ``e``/``f`` a resistor gives; an element with an error in its
    statement (its laws) is of unknown law, a resistor among them either way
    (:func:`bondc.causality.structural_conflicts`)."""
    from bondc.causality import structural_conflicts

    starts: dict[tuple[str, str], list[int]] = {}      # where the errors are, by file and instance
    for d in diagnostics:
        if d.is_error:
            starts.setdefault((d.span.file, d.span.instance), []).append(d.span.start)
    for offsets in starts.values():
        offsets.sort()

    def has_error(span: Span) -> bool:
        offsets = starts.get((span.file, span.instance), [])
        index = bisect.bisect_left(offsets, span.start)
        return index < len(offsets) and offsets[index] < max(span.end, span.start + 1)

    unknown = [element.name for element in m.elements if has_error(element.span)]
    elements, junctions, bonds = _structure(m, states=False)
    graph = BondGraph(m.model.name, m.model.description, m.file.path, {}, {}, {}, {}, elements, junctions, bonds,
                      (), {}, sources=dict(m.sources), span=m.model.span)
    return structural_conflicts(graph, unknown)


def check_dimensions(m: CheckContext, graph: BondGraph, values: Mapping[str, float]) -> tuple[list[Diagnostic], dict]:
    """E210: laws, outputs and inputs dimensionally consistent (LANGUAGE.md section 14); and the SI
    unit of every state and bond variable whose dimension is known."""
    from bondc import dimensions

    state_units: dict[str, ast.Unit | None] = {}
    for element in m.elements:
        for law in element.laws:
            if isinstance(law, ast.LawState):
                state_units[f"{element.name}.{law.name}"] = law.unit
    for declared in m.statements(ast.StateDecl):
        state_units[declared.name] = declared.unit
    for discrete in m.statements(ast.Discrete):
        state_units[discrete.name] = discrete.unit
    context = dimensions.Context(
        graph=graph, unit_of=lambda unit: resolve_unit(m, unit),
        params={p.name: p for p in m.params if m.decls.get(p.name) is not None and m.decls[p.name].node is p},
        inputs={i.name: i for i in m.inputs}, outputs={o.name: o for o in m.outputs},
        discretes={d.name: d for d in m.statements(ast.Discrete)}, state_units=state_units,
        functions=graph.functions, values=values)
    return dimensions.analyse(context)


def check_parameters(m: CheckContext, sets: Sequence[ast.SetValue]) -> tuple[dict[str, Definition], dict[str, float]]:
    """E305 override cycles and E311: every parameter's SI value with the ``--set`` overrides."""
    definitions = parameter_definitions(m)
    for item in sets:
        override(item.name, item.value, item.unit, item.span, "--set", definitions)
    return definitions, evaluate_parameters(m, definitions)


def check_experiment_values(m: CheckContext, plans: Sequence[ExperimentPlan], sets: Sequence[ast.SetValue],
                            base_values: Mapping[str, float], selected: ast.Experiment | None):
    """Each experiment's parameters (its overrides, then ``--set``) and settings, evaluated.

    Returns the experiments by name and, for the selected one, its parameter definitions and values.
    """
    experiment_defs: dict[str, ExperimentDef] = {}
    chosen = None
    for plan in plans:
        experiment = plan.experiment
        if experiment.name in experiment_defs:
            continue  # a duplicate name, reported by check_duplicate_names
        definitions = parameter_definitions(m)
        for item in plan.params:
            override(item.name, item.value, item.unit, item.span, f"experiment '{experiment.name}'", definitions)
        for assignment in sets:
            override(assignment.name, assignment.value, assignment.unit, assignment.span, "--set", definitions)
        values = _in_experiment(m, experiment, lambda: evaluate_parameters(m, definitions))
        experiment_defs[experiment.name] = experiment_def(m, plan, base_values, values)
        if experiment is selected:
            chosen = (definitions, values)
    return experiment_defs, chosen


def _in_experiment(m: CheckContext, experiment: ast.Experiment, run):
    """Run ``run`` and add, to each problem it reports outside the experiment, a note naming the experiment."""
    start = len(m.diagnostics)
    result = run()
    inside = experiment.span
    before = m.diagnostics[:start]
    kept: list[Diagnostic] = []
    for d in m.diagnostics[start:]:
        if d.span.file == inside.file and inside.start <= d.span.start <= inside.end:
            kept.append(d)
        elif not any(d == earlier for earlier in before):
            note = Related(experiment.name_span, f"with the overrides of experiment '{experiment.name}'")
            kept.append(dataclasses.replace(d, related=d.related + (note,)))
    m.diagnostics[start:] = kept
    return result


def sorted_unique(diagnostics: Iterable[Diagnostic]) -> list[Diagnostic]:
    return sorted(dict.fromkeys(diagnostics), key=sort_key)


def _graph(m: CheckContext, parameters: Mapping[str, Parameter], inputs: Mapping[str, Signal],
           experiments: Mapping[str, ExperimentDef]) -> BondGraph:
    elements, junctions, bonds = _structure(m)
    model_states = []
    for state in m.statements(ast.StateDecl):
        laws = m.model_states[state.name]
        model_states.append(StateVar(state.name, state.name, None, state.unit.text if state.unit else None,
                                     laws.initial.value if laws.initial else None,
                                     laws.rate.value if laws.rate else None,
                                     state.description, state.span))
    discrete = []
    for variable in m.statements(ast.Discrete):
        zero = ast.Num(0.0, "0", variable.span)
        model_states.append(StateVar(variable.name, variable.name, None,
                                     variable.unit.text if variable.unit else None, variable.value, zero,
                                     variable.description, variable.span))
        discrete.append(variable.name)
    whens = []
    for when in m.statements(ast.When):
        actions = tuple(("assign", ast.Name(a.name, a.name_span), a.value) if isinstance(a, ast.WhenAssign)
                        else ("reinit", a.args[0], a.args[1]) for a in when.actions)
        whens.append(WhenDef(when.condition, actions, _when_text(m, when), when.span))
    functions = {name: Function(name, f.params, f.body, f.description, f.span) for name, f in m.functions.items()}
    outputs = {}
    for output in m.outputs:
        resolved = m.units.get(id(output.unit)) if output.unit is not None else None
        outputs[output.name] = OutputDef(output.name, output.value, output.unit.text if output.unit else None,
                                         output.description, output.span,
                                         resolved.factor if resolved is not None else 1.0)
    return BondGraph(m.model.name, m.model.description, m.file.path, parameters, functions, inputs, outputs,
                     elements, junctions, bonds, tuple(model_states), experiments,
                     sources=dict(m.sources), span=m.model.span, discrete=tuple(discrete), whens=tuple(whens),
                     divisors=m.divisors)


def _structure(m: CheckContext, states: bool = True) -> tuple[dict[str, ElementNode], dict[str, JunctionNode],
                                                          tuple[Bond, ...]]:
    """The graph's elements, junctions and bonds; ``states``: with the storage elements' states
    (False: a model whose laws have errors, where they may be incomplete)."""
    labels = {bond.label for bond in m.bonds if bond.label}
    # A label "b9" on another bond takes the name bond 9 would have (W305 says so).
    bonds = [dataclasses.replace(bond, default_name=f"bond{bond.number}")
             if bond.label is None and f"b{bond.number}" in labels else bond for bond in m.bonds]
    elements = {}
    for element in m.elements:
        laws = m.element_laws[element.name]
        bond_numbers: tuple[int, ...]
        signs: tuple[int, ...]
        if KINDS[element.kind].ports == 2:
            (p1, p2), signs = m.ports[element.name]
            for number, port in ((p1, "p1"), (p2, "p2")):
                bond = bonds[number - 1]
                if bond.tail == element.name:
                    bonds[number - 1] = dataclasses.replace(bond, tail_port=port)
                else:
                    bonds[number - 1] = dataclasses.replace(bond, head_port=port)
            bond_numbers = (p1, p2)
        else:
            (end,) = m.ends[element.name]
            bond_numbers, signs = (end.bond,), (1 if end.side == "head" else -1,)
        elements[element.name] = ElementNode(
            element.kind, element.name, element.description,
            laws={target: law.value for target, law in laws.assigns.items()},
            law_spans={target: law.span for target, law in laws.assigns.items()},
            states=_element_states(element, laws) if states else (), bonds=bond_numbers, port_signs=signs,
            span=element.span, name_span=element.name_span)
    junctions = {}
    for junction in m.statements(ast.Junction):
        spans = junction.name_spans or (junction.span,) * len(junction.names)
        for name, span in zip(junction.names, spans):
            junctions[name] = JunctionNode(junction.kind, name, tuple(end.bond for end in m.ends[name]), span)
    return elements, junctions, tuple(bonds)


def _when_text(m: CheckContext, when: ast.When) -> str:
    """``when CONDITION`` as written (one line), for event lists; inside a component, with the
    names as the flat model has them (``when r2.air.e > r2.T_set + r2.hyst``), so that the firings
    of two instances are told apart."""
    if when.span is not None and when.span.instance:
        from bondc.fmt import format_expr

        head = "when " + " ".join(format_expr(when.condition).split())
    else:
        source = m.sources.get(when.span.file) if when.span is not None else None
        text = source.text[when.span.start:when.span.end] if source is not None else "when ..."
        head = " ".join(text.split(" then")[0].split())
    return head if len(head) <= 120 else head[:117] + "..."


def _element_states(element: ast.Element, laws: ElementLaws) -> tuple[StateVar, ...]:
    kind = KINDS[element.kind]
    if kind.state is None:      # (not a storage element)
        return ()
    if not laws.custom:
        initial = laws.initials.get(kind.state)
        return (StateVar(kind.state, f"{element.name}.{kind.state}", element.name, None,
                         initial.value if initial else None, None, None, element.name_span),)
    states = []
    for name, declared in laws.custom.items():
        initial = laws.initials.get(name)
        states.append(StateVar(name, f"{element.name}.{name}", element.name,
                               declared.unit.text if declared.unit else None,
                               initial.value if initial else None, laws.rates[name].value,
                               declared.description, declared.span))
    return tuple(states)


def build(file: ast.File, sources: Mapping[str, Source] | None = None, *, model: str | None = None,
          experiment: str | None = None, overrides: Sequence[ast.SetValue] = (),
          imported: Sequence[ast.File] = ()) -> tuple[BondGraph, list[Diagnostic]]:
    """Check one model of a parsed file and build its graph; raise ModelError with every error.

    ``imported`` are the files ``file`` imports (parsed); ``overrides`` are ``--set`` values, applied
    after the experiment's. Returns the graph and the warnings.
    """
    graph, diagnostics = build_files([file, *imported], sources or {}, model, experiment, overrides)
    if graph is None:
        raise ModelError([d for d in diagnostics if d.is_error])
    return graph, diagnostics
