"""Experiments: takes the model and its parameter values; checks the ``defaults`` block and each
experiment's settings, input replacements and parameter overrides, and returns them as
:class:`bondc.model.ExperimentDef` values.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Mapping, Union

from bondc import ast, units
from bondc.errors import Related
from bondc.model import ExperimentDef, Signal
from bondc.semantic.context import (
    OPERATING_POINTS, SETTINGS, SOLVERS, a_or_an, CheckContext, did_you_mean, error_at, input_value, join_hints,
)
from bondc.semantic.expressions import CONSTANT, SIGNAL, check_expr
from bondc.semantic.parameters import check_override, finite_si, try_evaluate
from bondc.semantic.rules import CONSTANT_RULE, INPUT_RULE, check_signal_cycles, scope_for
from bondc.semantic.unit_checks import COMPUTED_WHY, is_constant, require_coherent, resolve_unit
from bondc import codes


@dataclass
class ExperimentPlan:
    """An experiment's overrides, checked: what :func:`experiment_def` needs."""

    experiment: ast.Experiment
    params: list[ast.Param] = field(default_factory=list)
    inputs: dict[str, ast.Input] = field(default_factory=dict)
    settings: dict[str, ast.Setting] = field(default_factory=dict)


def with_defaults(model: ast.Model) -> ast.Model:
    """Each experiment with the settings of the model's ``defaults`` that it does not set itself."""
    defaults = [item for s in model.body if isinstance(s, ast.Defaults) for item in s.body]
    if not defaults:
        return model
    if not any(isinstance(s, ast.Experiment) for s in model.body):
        # a model without experiments runs with its defaults, as an experiment called "defaults"
        block = next(s for s in model.body if isinstance(s, ast.Defaults))
        experiment = ast.Experiment("defaults", "the model's defaults", tuple(defaults), block.span, block.span)
        return dataclasses.replace(model, body=model.body + (experiment,))
    body = []
    for statement in model.body:
        if isinstance(statement, ast.Experiment):
            own = {item.name for item in statement.body if isinstance(item, ast.Setting)}
            inherited = tuple(item for item in defaults if item.name not in own)
            statement = dataclasses.replace(statement, body=inherited + statement.body)
        body.append(statement)
    return dataclasses.replace(model, body=tuple(body))


def check_defaults(m: CheckContext) -> None:
    """``defaults`` blocks: settings only, each once (checked even where no experiment uses them)."""
    plan = ExperimentPlan(ast.Experiment("defaults", None, ()))
    for block in m.statements(ast.Defaults):
        for item in block.body:
            _check_setting(m, plan, item)


def check_experiments(m: CheckContext) -> list[ExperimentPlan]:
    """E314 unknown setting, E313/E317 bad setting values, overrides of unknown names (E301)."""
    plans = []
    for experiment in m.experiments:
        plan = ExperimentPlan(experiment)
        plans.append(plan)
        where = f"experiment '{experiment.name}'"
        seen_params: dict[str, ast.Param] = {}
        for item in experiment.body:
            if isinstance(item, ast.Param):
                if item.name in seen_params:
                    m.report(error_at(codes.E302, f"{where} sets '{item.name}' twice", item.name_span,
                                      related=[Related(seen_params[item.name].name_span, "first set here")]))
                    continue
                seen_params[item.name] = item
                if check_override(m, item.name, item.name_span, item.value, item.unit, where):
                    plan.params.append(item)
            elif isinstance(item, ast.Input):
                _check_input_replacement(m, plan, item, where)
            else:
                _check_setting(m, plan, item)
        if plan.inputs:
            check_signal_cycles(m, {**{i.name: i for i in m.inputs}, **plan.inputs})
    return plans


def _check_input_replacement(m: CheckContext, plan: ExperimentPlan, item: ast.Input, where: str) -> None:
    decl = m.decls.get(item.name)
    if decl is None or decl.category != "input":
        what = f"; '{item.name}' is {a_or_an(decl.category)}" if decl is not None else ""
        m.report(error_at(codes.E301, f"{where} replaces '{item.name}', which is not an input{what}", item.name_span,
                          hint=did_you_mean(item.name, m.names("input"))))
        return
    if item.name in plan.inputs:
        m.report(error_at(codes.E302, f"{where} replaces input '{item.name}' twice", item.name_span,
                          related=[Related(plan.inputs[item.name].name_span, "first replaced here")]))
        return
    m.used.add(item.name)
    if item.external:
        m.report(error_at(codes.E345, f"{where} declares input '{item.name}' external", item.name_span,
                          hint=f"'external' belongs on the model's input ('input {item.name} [UNIT] external = ...'); "
                               f"an experiment replaces an input with a signal ('input {item.name} = ...')"))
        return
    if item.value is None:      # (was an internal error)
        m.report(error_at(codes.E334, f"{where} replaces input '{item.name}' without a value", item.name_span,
                          hint=f"give it its signal: 'input {item.name} = ...'"))
        return
    require_coherent(m, item.unit, f"input '{item.name}'", "an input is computed in SI")
    check_expr(m, item.value, scope_for(m, "an input", SIGNAL, INPUT_RULE))
    plan.inputs[item.name] = item


def _check_setting(m: CheckContext, plan: ExperimentPlan, item: ast.Setting) -> None:
    kind = SETTINGS.get(item.name)
    if kind is None:
        m.report(error_at(codes.E314, f"unknown experiment setting '{item.name}'", item.name_span,
                          hint=join_hints(did_you_mean(item.name, SETTINGS), "settings: " + " ".join(SETTINGS))))
        return
    if item.name in plan.settings:
        m.report(error_at(codes.E302, f"setting '{item.name}' is given twice", item.name_span,
                          related=[Related(plan.settings[item.name].name_span, "first given here")]))
        return
    if kind == "solver":
        if not isinstance(item.value, ast.Str):
            written = item.value.name if isinstance(item.value, ast.Name) else "Radau"
            m.report(error_at(codes.E313, "solver must be a string", item.value.span,
                              hint=f'write solver = "{written}"; solvers: {", ".join(SOLVERS)}'))
            return
        if item.unit is not None:
            m.report(error_at(codes.E313, "solver takes no unit", item.unit.span))
            return
        if item.value.value not in SOLVERS:
            m.report(error_at(codes.E317, f"unknown solver '{item.value.value}'", item.value.span,
                              hint=join_hints(did_you_mean(item.value.value, SOLVERS),
                                               "solvers (auto: chosen for stiffness; SUNDIALS CVODE and IDA; bondc's DOPRI5; scipy.integrate.solve_ivp methods): " + ", ".join(SOLVERS))))
            return
    elif kind in _LISTS:
        if not _list_setting_ok(m, item, kind):
            return
    elif kind == "operating point":
        if not isinstance(item.value, ast.Str) or item.value.value not in OPERATING_POINTS or item.unit is not None:
            m.report(error_at(codes.E313, f"{item.name} is \"initial\" or \"equilibrium\"", item.value.span,
                              hint=f'write {item.name} = "equilibrium" to linearise at the equilibrium found from the '
                                   "initial state"))
            return
    else:
        if isinstance(item.value, (ast.Str, ast.ListExpr)):
            m.report(error_at(codes.E313, f"{item.name} must be a number", item.value.span))
            return
        if not check_expr(m, item.value, scope_for(m, "a setting", CONSTANT, CONSTANT_RULE.format("a setting"))):
            return
        if is_constant(item.value):
            resolved = resolve_unit(m, item.unit)
        else:
            resolved = require_coherent(m, item.unit, f"setting '{item.name}'", COMPUTED_WHY.format("it"))
        if resolved is not None and item.unit is not None and kind == "time" and resolved.dims != _TIME:
            m.report(error_at(codes.E204, f"{item.name} is a time, but [{item.unit.text}] is not a unit of time",
                              item.unit.span, hint="write it in s, ms, min or h"))
            return
        if item.unit is not None and resolved is None:
            return
    plan.settings[item.name] = item


#: The dimensions of a time (the second's).
_TIME = tuple(int(base == "s") for base in units.BASE_DIMENSIONS)


#: Settings that list names: the node each entry must be, and the E313 message and hint for another.
_LISTS = {"outputs": (ast.Name, "outputs lists output names", "write outputs = [name1, name2]"),
          "transfers": (ast.Transfer, "bode lists pairs INPUT -> OUTPUT",
                        "write bode = [F -> x, F -> v]: the input excited and the output measured")}


def _list_setting_ok(m: CheckContext, item: ast.Setting, kind: str) -> bool:
    """Check a setting that lists outputs (``outputs = [a, b]``) or input-output pairs (``bode =
    [F -> x]``): E313 for an entry of another form, E301 for a name that is not an output (input)."""
    node, message, hint = _LISTS[kind]
    items = item.value.items if isinstance(item.value, ast.ListExpr) else (item.value,)
    ok = True
    for entry in items:
        if not isinstance(entry, node):
            m.report(error_at(codes.E313, message, entry.span, hint=hint))
            ok = False
        elif isinstance(entry, ast.Name):
            ok = _declared_as(m, entry, "output", f"declare it with 'output {entry.name} = ...'") and ok
        elif isinstance(entry, ast.Transfer):
            for name, category in ((entry.source, "input"), (entry.target, "output")):
                if _declared_as(m, name, category, f"bode = [INPUT -> OUTPUT]: declare it with "
                                                   f"'{category} {name.name} [UNIT] = ...'"):
                    m.used.add(name.name)
                else:
                    ok = False
    return ok


def _declared_as(m: CheckContext, entry: ast.Name, category: str, how: str) -> bool:
    """Whether a setting's name ``entry`` is a declared ``category`` ("output", "input"); else E301
    with the closest such name, what the name is instead, and ``how`` to declare it."""
    if entry.name in m.names(category):
        return True
    decl = m.decls.get(entry.name)
    what = f"'{entry.name}' is {a_or_an(decl.category)}; " if decl is not None else ""
    m.report(error_at(codes.E301, f"no {category} named '{entry.name}'", entry.span,
                      hint=join_hints(did_you_mean(entry.name, m.names(category)), what + how)))
    return False


#: A checked setting's value: SI float, solver or operating point name, output names, transfers.
SettingValue = Union[float, str, tuple[str, ...], tuple[tuple[str, str], ...]]


def _setting_value(m: CheckContext, item: ast.Setting, values: Mapping[str, float]) -> SettingValue | None:
    """A checked setting's value: SI float, solver string or output names."""
    kind = SETTINGS[item.name]
    node = item.value
    items = node.items if isinstance(node, ast.ListExpr) else (node,)
    if kind in ("solver", "operating point"):
        return node.value if isinstance(node, ast.Str) else None    # (checked: a string)
    if kind == "outputs":
        return tuple(entry.name for entry in items if isinstance(entry, ast.Name))
    if kind == "transfers":
        return tuple((entry.source.name, entry.target.name) for entry in items if isinstance(entry, ast.Transfer))
    value = try_evaluate(m, node, values)
    if value is None:
        return None
    unit = m.units.get(id(item.unit)) if item.unit is not None else None
    if is_constant(node) and item.unit is not None and unit is not None:
        value = finite_si(m, unit.to_si(value), value, item.unit, node.span)
        if value is None:
            return None
    if value <= 0:
        m.report(error_at(codes.E317, f"{item.name} must be positive, not {value:g}", item.value.span))
        return None
    return value


def _number(value: SettingValue | None) -> float | None:
    return value if isinstance(value, (int, float)) else None


def signal_of(item: ast.Input, description: str | None = None) -> Signal:
    return Signal(item.name, input_value(item), item.unit.text if item.unit else None,
                  item.description or description, item.span, external=item.external, name_span=item.name_span)


def experiment_def(m: CheckContext, plan: ExperimentPlan, base_values: Mapping[str, float],
                    values: Mapping[str, float]) -> ExperimentDef:
    settings = {}
    for name, item in plan.settings.items():
        value = _setting_value(m, item, values)
        if value is not None:
            settings[name] = value
    t_end, rtol, atol, max_step, cycle = (_number(settings.pop(k, None)) for k in ("t_end", "rtol", "atol",
                                                                                   "max_step", "cycle"))
    solver, outputs = settings.pop("solver", None), settings.pop("outputs", ())
    descriptions = {i.name: i.description for i in m.inputs}
    changed = {name: value for name, value in values.items() if base_values.get(name) != value}
    experiment = plan.experiment
    return ExperimentDef(experiment.name, experiment.description, t_end=t_end,
                         solver=solver if isinstance(solver, str) else None, rtol=rtol, atol=atol,
                         max_step=max_step, cycle=cycle,
                         outputs=tuple(name for name in outputs if isinstance(name, str)) if isinstance(outputs, tuple)
                         else (),
                         parameters=changed,
                         inputs={name: signal_of(item, descriptions.get(name)) for name, item in plan.inputs.items()},
                         settings=settings, span=experiment.span)
