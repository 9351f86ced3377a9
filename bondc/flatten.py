"""Submodels and ports (LANGUAGE.md section 11): one model with instances -> one flat model.

An instance statement (``Orifice valve "..." : A = 2e-5 [m^2]``) has the shape of an element
whose kind names a model. :func:`flatten` expands every instance, to any depth, into the
statements of the model that uses it, with dotted names: the instance's element ``loss`` becomes
``valve.loss``, its parameter ``A`` becomes ``valve.A``, its bonds are labelled ``valve.b1``,
``valve.b2``, ... (or ``valve.LABEL``). A port bond inside and the bond at ``valve.a`` outside
become one bond of the flat graph, which keeps the outside bond's place, number and label.

The flat model is plain version-1 AST: every later stage (checks, causality, equations, code,
reports) sees dotted names and nothing else. What cannot be written as AST comes back beside it:

- ``bindings``: an instance's parameter values (``valve.A = 2e-5 [m^2]``), applied by the
  semantic stage exactly like an experiment's override, so units convert as in section 3;
- ``instances``: the instance tree (path, model, description, ports) for reports and diagrams.

Spans inside an instance keep pointing into the component's own source and carry the instance
path (``Span.instance``), so a diagnostic there also says ``in plant.valve``.

>>> from bondc.parse import parse_text
>>> text = '''
... model Pipe
...   port a, b
...   param k = 2
...   R loss : e = k*f
...   1 j
...   a -> j -> b
...   j -> loss
... end
... model Top
...   Se s : e = 1
...   Pipe pipe : k = 3
...   R sink : e = f
...   s -> pipe.a
...   pipe.b -> sink
... end
... '''
>>> file = parse_text(text, "m.bg")
>>> flat = flatten(file.models[1], [file])
>>> [(type(s).__name__, getattr(s, "name", None)) for s in flat.model.body][:4]
[('Element', 's'), ('Param', 'pipe.k'), ('Element', 'pipe.loss'), ('Junction', None)]
>>> [(b.endpoints[0].name, b.endpoints[1].name) for b in flat.model.body if isinstance(b, ast.BondChain)]
[('s', 'pipe.j'), ('pipe.j', 'sink'), ('pipe.j', 'pipe.loss')]
>>> [(b.name, b.origin) for b in flat.bindings]
[('pipe.k', "instance 'pipe'")]
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from dataclasses import dataclass, field
from pathlib import PurePosixPath
from typing import Iterable, Mapping, Sequence

from bondc import ast
from bondc.errors import Diagnostic, Hint, Related
from bondc.kinds import JUNCTION_KINDS, KINDS
from bondc.source import Span
from bondc import codes

_BOND_NUMBER = re.compile(r"b([0-9]+)")
#: The codes of an instance's kind that names no model (E330) or two (E331): no E303 for it after them.
KIND_CODES = (codes.E330, codes.E331)
_ELEMENT_LOCALS = frozenset({"e", "f"})   # an element's own variables inside its laws (and its states)
#: The statements a model may expand to through its instances (E319 beyond), or twenty per
#: statement written in its files where that is more: components that instantiate two of the
#: one before, 40 deep, would expand to 2^40 copies (the flattening of 20 000 takes seconds).
MAX_FLAT_STATEMENTS = 20_000


class _TooLarge(Exception):
    """The expansion went beyond the limit; the top model's instance turns it into E319."""


def _error(code: str, message: str, span: Span, hint: str | None = None, related=()) -> Diagnostic:
    return Diagnostic("error", code, message, span, hint, tuple(related),
                      suggestions=getattr(hint, "suggestions", ()))


def _did_you_mean(name: str, candidates: Iterable[str]) -> str | None:
    close = difflib.get_close_matches(name, list(candidates), n=1)
    return Hint(f"did you mean '{close[0]}'?", (close[0],)) if close else None


def _hints(*hints: str | None) -> str | None:
    return Hint.join(h for h in hints if h) or None


def library_name(file: ast.File) -> str:
    """The name a file's models may be qualified with: ``std:hydraulics`` -> ``hydraulics``,
    ``lib/pneumatics.bg`` -> ``pneumatics``."""
    path = file.path
    if path.startswith("std:"):
        return path[4:]
    return PurePosixPath(path.replace("\\", "/")).stem


def ports_of(model: ast.Model) -> list[str]:
    return [name for statement in model.body if isinstance(statement, ast.PortDecl) for name in statement.names]


# ------------------------------------------------------------------ results

@dataclass(frozen=True)
class Binding:
    """``valve.A = 2e-5 [m^2]``: an instance sets one of its model's parameters."""

    name: str                 # the flat parameter name
    value: ast.Expr           # in the flat namespace of the model that binds it
    unit: ast.Unit | None
    span: Span                # the binding as written
    name_span: Span
    origin: str               # "instance 'valve'"


@dataclass(frozen=True)
class Instance:
    """One instance of the tree, for reports and diagrams."""

    path: str                 # "plant.valve"
    model: str                # the model's name as defined
    description: str | None
    ports: tuple[str, ...]
    span: Span


@dataclass
class Flat:
    model: ast.Model
    bindings: list[Binding] = field(default_factory=list)
    instances: list[Instance] = field(default_factory=list)
    diagnostics: list[Diagnostic] = field(default_factory=list)
    too_large: bool = False         # its instances expand beyond MAX_FLAT_STATEMENTS (E319)


@dataclass
class _Port:
    name: str
    span: Span                        # its declaration
    end: ast.Endpoint | None = None   # the flat endpoint on the inside of its bond
    inward: bool = True               # inside, power flows from the port inward
    bond_span: Span | None = None
    names: tuple[str, ...] = ()       # the flat names the inside bond had (for references to it)
    used: Span | None = None          # where it is bonded outside


@dataclass
class _Expansion:
    """A model expanded at one prefix: its names, its flat statements and bonds, its ports."""

    model: ast.Model
    prefix: str
    values: set[str] = field(default_factory=set)      # parameters, inputs, outputs, states, discretes
    params: set[str] = field(default_factory=set)
    inputs: dict[str, ast.Input] = field(default_factory=dict)
    functions: set[str] = field(default_factory=set)
    nodes: set[str] = field(default_factory=set)       # elements, junctions, bond labels
    instances: dict[str, "_Expansion"] = field(default_factory=dict)
    ports: dict[str, _Port] = field(default_factory=dict)
    statements: list = field(default_factory=list)
    bonds: list[ast.BondChain] = field(default_factory=list)


def _signal(x: _Expansion, node) -> bool:
    """Whether an expression of model ``x`` is a signal of time: it names only time, ``x``'s parameters
    and inputs (and functions); not its states, discrete variables, outputs or graph variables."""
    return not any(isinstance(n, ast.Ref) or isinstance(n, ast.Name) and n.name in x.values
                   and n.name not in x.params and n.name not in x.inputs for n in ast.walk(node))


# ------------------------------------------------------------------- spans

def _relocate(node, instance: str):
    """``node`` with every span inside it marked as inside ``instance``."""
    if isinstance(node, Span):
        return dataclasses.replace(node, instance=instance) if node.line > 0 else node
    if isinstance(node, tuple):
        return tuple(_relocate(item, instance) for item in node)
    if dataclasses.is_dataclass(node) and not isinstance(node, type):
        changes = {}
        for f in dataclasses.fields(node):
            value = getattr(node, f.name)
            if isinstance(value, (Span, tuple)) or (dataclasses.is_dataclass(value) and not isinstance(value, type)):
                new = _relocate(value, instance)
                if new is not value:
                    changes[f.name] = new
        return dataclasses.replace(node, **changes) if changes else node
    return node


# --------------------------------------------------------------- flattening

class _Flattener:
    def __init__(self, files: Sequence[ast.File], flat: Flat, standalone: bool):
        self.files = files
        self.flat = flat
        self.standalone = standalone
        self.aliases: dict[str, str] = {}      # a port bond's inner name -> the fused bond's name
        written = sum(len(model.body) for file in files for model in file.models)
        self.limit = max(MAX_FLAT_STATEMENTS, 20 * written)
        self.expanded = 0                       # statements of the models expanded so far
        self.by_file: dict[int, ast.File] = {}
        for file in files:
            for model in file.models:
                self.by_file[id(model)] = file

    def report(self, diagnostic: Diagnostic) -> None:
        self.flat.diagnostics.append(diagnostic)

    # -- which model an element kind names

    def component(self, kind: str, where: ast.Model, span: Span) -> ast.Model | None:
        """The model an instance statement's kind names, or None for an element kind."""
        if kind in KINDS or kind in JUNCTION_KINDS:
            return None
        if "." in kind:
            library, name = kind.split(".", 1)
            found = [m for f in self.files if library_name(f) == library for m in f.models if m.name == name]
            if not found:
                known = sorted({library_name(f) for f in self.files if f is not self.files[0]})
                if library in known:
                    models = sorted({m.name for f in self.files if library_name(f) == library for m in f.models})
                    close = difflib.get_close_matches(name, models, n=1)
                    hint = _hints(Hint(f"did you mean '{library}.{close[0]}'?", (f"{library}.{close[0]}",))
                                  if close else None,
                                  f"'{library}' has: {', '.join(models[:12])}"
                                  + (", ..." if len(models) > 12 else ""))
                    self.report(_error(codes.E330, f"no model '{name}' in the imported library '{library}'", span,
                                       hint=hint))
                else:
                    self.report(_error(codes.E330, f"no model '{name}' in an imported library '{library}'", span,
                                       hint=f"imported libraries: {', '.join(known) or 'none'}; import the file "
                                            f"or 'std:{library}' at file level"))
            return found[0] if found else None
        home = self.by_file.get(id(where))
        own = [m for m in (home.models if home is not None else ()) if m.name == kind]
        if own:
            return own[0]
        defined = [(f, m) for f in self.files for m in f.models if m.name == kind]
        if len({id(f) for f, _ in defined}) > 1:
            names = [library_name(f) for f, _ in defined]
            files = " and ".join(f.path for f, _ in defined)
            self.report(_error(codes.E331, f"'{kind}' is defined by two imports: {files}",
                               span, hint=f"qualify it with its library, e.g. '{names[0]}.{kind}'"))
            return None
        return defined[0][1] if defined else None

    # -- one model at one prefix

    def expand(self, model: ast.Model, prefix: str, stack: tuple) -> _Expansion:
        self.expanded += len(model.body)
        if self.expanded > self.limit:
            raise _TooLarge()
        x = _Expansion(model, prefix)
        kinds: dict[int, ast.Model] = {}
        for statement in model.body:
            if isinstance(statement, (ast.Param, ast.Input, ast.Output, ast.StateDecl, ast.Discrete)):
                x.values.add(statement.name)
                if isinstance(statement, ast.Param):
                    x.params.add(statement.name)
                if isinstance(statement, ast.Input):
                    x.inputs[statement.name] = statement
            elif isinstance(statement, ast.FnDef):
                x.functions.add(statement.name)
            elif isinstance(statement, ast.Junction):
                x.nodes.update(statement.names)
            elif isinstance(statement, ast.BondChain) and statement.label is not None:
                x.nodes.add(statement.label)
            elif isinstance(statement, ast.PortDecl):
                spans = statement.name_spans or (statement.span,) * len(statement.names)
                for name, span in zip(statement.names, spans):
                    if self.standalone and not prefix:
                        x.nodes.add(name)
                    elif name not in x.ports:
                        x.ports[name] = _Port(name, span)
            elif isinstance(statement, ast.Element):
                sub = self.component(statement.kind, model, statement.kind_span)
                if sub is not None:
                    kinds[id(statement)] = sub
                else:       # an element (an unknown library model was reported by component())
                    x.nodes.add(statement.name)
        for port in x.ports.values():
            if port.name in x.values | x.nodes | x.functions or any(
                    isinstance(s, ast.Element) and s.name == port.name for s in model.body):
                self.report(_error(codes.E302, f"'{port.name}' is defined twice: as a port and as another name "
                                           f"of model '{model.name}'", port.span,
                                   hint="ports share the model's namespace; rename the port or the other name"))
        # Instances first, so that references into them resolve.
        for statement in model.body:
            sub = kinds.get(id(statement))
            if sub is None or not isinstance(statement, ast.Element):
                continue
            path = prefix + statement.name
            if any(sub is seen for seen, _ in stack):
                cycle = " -> ".join([name for _, name in stack] + [sub.name])
                self.report(_error(codes.E332, f"model '{sub.name}' instantiates itself: {cycle}", statement.kind_span,
                                   hint="a component cannot contain itself, directly or through others"))
                continue
            relocated = _relocate(sub, path)
            try:
                x.instances[statement.name] = self.expand(relocated, path + ".", stack + ((sub, sub.name),))
            except _TooLarge:
                if prefix:
                    raise
                # reported at the instance in the model itself, with the component it starts from
                self.report(_error(codes.E319, f"instance '{statement.name}' of '{sub.name}' expands to more than "
                                           f"{self.limit} statements (its components instantiate others at "
                                           f"every level)", statement.kind_span.to(statement.name_span),
                                   hint="instantiate fewer components in each other, or write the repeated "
                                        "part once"))
                raise
            self.flat.instances.append(Instance(path, sub.name, statement.description,
                                                tuple(ports_of(sub)), statement.name_span))
        renamer = _Renamer(self, x)
        number = 0
        for statement in model.body:
            if isinstance(statement, ast.Element) and id(statement) in kinds:
                if statement.name in x.instances:
                    self.instantiate(x, statement, renamer)
            elif isinstance(statement, ast.BondChain):
                number = self.bonds(x, statement, number, renamer)
            elif isinstance(statement, ast.PortDecl):
                if self.standalone and not prefix:
                    x.statements.extend(self.boundary(statement))
            elif isinstance(statement, (ast.Experiment, ast.Defaults)):
                if not prefix:
                    x.statements.append(statement)
            else:
                x.statements.append(renamer.statement(statement))
        for statement in model.body:
            if isinstance(statement, ast.Element) and id(statement) in kinds:
                expansion = x.instances.get(statement.name)
                if expansion is not None:
                    self.unbonded_ports(x, expansion, statement)
        for port in x.ports.values():
            if port.end is None:
                self.report(_error(codes.E333, f"port '{port.name}' is not bonded inside model '{model.name}'",
                                   port.span, hint="bond each port exactly once inside its model, e.g. "
                                                   f"'{port.name} -> j'"))
        if not prefix:
            for name, item in x.inputs.items():
                if item.value is None and not item.external and not self.standalone:
                    self.report(_error(codes.E334, f"input '{name}' has no value", item.name_span,
                                       hint=f"give it one ('input {name} = ...') or use model '{model.name}' as "
                                            f"a component whose instances bind it"))
        return x

    def unbonded_ports(self, x: _Expansion, sub: _Expansion, statement: ast.Element) -> None:
        """E343 for each port of instance ``sub`` that no bond outside reaches. Inside, the port
        becomes a boundary of zero effort (as a component checked on its own), so that its
        elements are not reported as unbonded too."""
        path = sub.prefix[:-1]
        for port in sub.ports.values():
            if port.used is not None or port.end is None:
                continue
            self.report(_error(codes.E343, f"port '{port.name}' of instance '{path}' is not bonded",
                               statement.name_span,
                               hint=f"bond it once outside, e.g. '{path}.{port.name} -> j' or 'j -> "
                                    f"{path}.{port.name}' (every port of a component carries one bond)"))
            name = f"{path}.{port.name}"
            end = ast.Endpoint(name, None, statement.name_span)
            x.statements.append(ast.Element("Se", name, "unbonded port (checked as a boundary)",
                                            (ast.LawAssign("e", ast.Num(0.0, "0")),), statement.name_span,
                                            statement.name_span, statement.name_span))
            x.bonds.append(ast.BondChain(None, (end, port.end) if port.inward else (port.end, end),
                                         statement.name_span, statement.name_span))

    def boundary(self, statement: ast.PortDecl) -> list[ast.Element]:
        """A component checked on its own: each port becomes a source of zero effort, so that every
        name, law and unit inside can be checked (``bondc check`` on a library)."""
        spans = statement.name_spans or (statement.span,) * len(statement.names)
        return [ast.Element("Se", name, "port (checked as a boundary)", (ast.LawAssign("e", ast.Num(0.0, "0")),),
                            span, span, span) for name, span in zip(statement.names, spans)]

    def instantiate(self, x: _Expansion, statement: ast.Element, renamer: "_Renamer") -> None:
        sub = x.instances[statement.name]
        path = sub.prefix[:-1]
        bound: dict[str, Span] = {}
        for law in statement.laws:
            if not isinstance(law, ast.LawAssign):
                written = law.func if isinstance(law, ast.LawCall) else "state"
                self.report(_error(codes.E335, f"an instance takes bindings 'NAME = value', not '{written} ...'",
                                   law.span, hint=f"bind a parameter or input of '{sub.model.name}', e.g. "
                                                  f"'{next(iter(sorted(sub.params)), 'k')} = 2'"))
                continue
            name = law.target
            if name in bound:
                self.report(_error(codes.E302, f"'{name}' is bound twice in instance '{path}'", law.target_span,
                                   related=[Related(bound[name], "first bound here")]))
                continue
            bound[name] = law.target_span
            value = renamer.expr(law.value)
            if name in sub.params:
                self.flat.bindings.append(Binding(sub.prefix + name, value, law.unit, law.span, law.target_span,
                                                  f"instance '{path}'"))
            elif name in sub.inputs:
                if law.unit is not None:
                    self.report(_error(codes.E336, f"input '{name}' is bound to a signal, which takes no unit",
                                       law.unit.span, hint="inputs are computed in SI: write the expression "
                                                           "in SI units"))
                flat_name = sub.prefix + name
                if _signal(x, law.value):
                    sub.statements = [dataclasses.replace(s, value=value) if isinstance(s, ast.Input)
                                      and s.name == flat_name else s for s in sub.statements]
                else:
                    # a signal of the outer model's states, discrete variables, outputs or graph
                    # variables (a controller's held output driving a voltage source): no function of
                    # time alone, so the instance's input is a named expression, as an output is, and
                    # so is every input inside it bound to that one (a source in a nested component)
                    named = {flat_name}
                    changed = True
                    while changed:
                        changed = False
                        for i, s in enumerate(sub.statements):
                            if isinstance(s, ast.Input) and (s.name in named or s.value is not None and any(
                                    isinstance(n, ast.Name) and n.name in named for n in ast.walk(s.value))):
                                expr = value if s.name == flat_name else s.value
                                if expr is None:        # (a second input of the same name: E302)
                                    continue
                                sub.statements[i] = ast.Output(s.name, s.unit, expr, s.description, s.span,
                                                               s.name_span)
                                named.add(s.name)
                                changed = True
            else:
                kinds = sorted(sub.params | set(sub.inputs))
                self.report(_error(codes.E337, f"model '{sub.model.name}' has no parameter or input '{name}'",
                                   law.target_span,
                                   hint=_hints(_did_you_mean(name, kinds),
                                               f"it can bind: {', '.join(kinds)}" if kinds else
                                               "it has no parameters or inputs")))
        for name, item in sub.inputs.items():
            if item.value is None and not item.external and name not in bound:
                self.report(_error(codes.E334, f"instance '{path}' must bind input '{name}' of '{sub.model.name}' "
                                           f"(it has no default)", statement.name_span,
                                   hint=f"add '{name} = ...' to the instance's bindings",
                                   related=[Related(item.name_span, "declared here")]))
        x.statements.append(_InstanceMark(path))
        x.statements.extend(sub.statements)
        x.bonds.extend(sub.bonds)

    # -- bonds

    def bonds(self, x: _Expansion, chain: ast.BondChain, number: int, renamer: "_Renamer") -> int:
        """The bonds of one chain: port bonds fused, the rest renamed. Returns the last bond number."""
        top = not x.prefix
        ends = [self.endpoint(x, end) for end in chain.endpoints]
        pairs = list(zip(range(len(ends) - 1), ends, ends[1:]))
        kept: list[tuple] = []
        for index, tail, head in pairs:
            number += 1
            label = chain.label if len(ends) == 2 else None
            local = label if label is not None else f"b{number}"
            span = (chain.label_span if label is not None else chain.endpoints[index].span).to(
                chain.endpoints[index + 1].span)
            own = [(end, side) for end, side in ((tail, "tail"), (head, "head")) if end[0] == "port"]
            if own:
                if len(own) == 2:
                    self.report(_error(codes.E338, "a bond cannot join two ports of the same model", span,
                                       hint="put a junction between them: 'a -> j -> b'"))
                    continue
                (kind, port), side = own[0]
                other = head if side == "tail" else tail
                if port.end is not None:
                    self.report(_error(codes.E339, f"port '{port.name}' is bonded twice inside its model", span,
                                       hint="a port is one bond through the boundary; join more bonds at a "
                                            "junction inside",
                                       related=[Related(port.bond_span, "first bonded here")]))
                    continue
                port.end = self.fuse(x, other, side == "tail", span, x.prefix + local)
                port.inward = side == "tail"
                port.bond_span = span
                port.names = (x.prefix + local,)
                continue
            name = x.prefix + local if x.prefix else local
            new_tail = self.fuse(x, tail, False, span, name)
            new_head = self.fuse(x, head, True, span, name)
            if new_tail is None or new_head is None:
                continue
            kept.append((index, new_tail, new_head, local, span, label))
        if top:
            # The top model keeps its chains, so its bonds keep their numbers, labels and spans.
            if len(kept) == len(pairs):
                endpoints = [kept[0][1]] + [k[2] for k in kept]
                x.statements.append(dataclasses.replace(chain, endpoints=tuple(endpoints)))
            else:
                for index, tail, head, local, span, label in kept:
                    x.statements.append(ast.BondChain(label, (tail, head), span,
                                                      chain.label_span if label is not None else span))
            return number
        for index, tail, head, local, span, label in kept:
            label_span = chain.label_span if label is not None else span
            x.bonds.append(ast.BondChain(x.prefix + local, (tail, head), span, label_span))
        return number

    def endpoint(self, x: _Expansion, end: ast.Endpoint):
        """("port", _Port) for the model's own port, ("instance", (expansion, port name, end)) for
        ``inst.port``, ("node", Endpoint) otherwise (renamed)."""
        if end.port is None and end.name in x.ports:
            return ("port", x.ports[end.name])
        if end.name in x.instances:
            return ("instance", (x.instances[end.name], end.port, end))
        return ("node", dataclasses.replace(end, name=x.prefix + end.name) if x.prefix else end)

    def fuse(self, x: _Expansion, end, into: bool, bond_span: Span, bond_name: str) -> ast.Endpoint | None:
        """The flat endpoint for one end of a bond; ``into``: the bond's power flows into this end."""
        kind, what = end
        if kind == "node":
            return what
        if kind == "port":
            return None
        sub, port_name, written = what
        if port_name is None:
            ports = list(sub.ports)
            self.report(_error(codes.E340, f"'{written.name}' is an instance of '{sub.model.name}': bond one of its "
                                       f"ports", written.span,
                               hint=f"write {' or '.join(f'{written.name}.{p}' for p in ports[:3]) or 'a port'}"
                               if ports else f"model '{sub.model.name}' declares no ports"))
            return None
        port = sub.ports.get(port_name)
        if port is None:
            self.report(_error(codes.E341, f"model '{sub.model.name}' has no port '{port_name}'", written.span,
                               hint=_hints(_did_you_mean(port_name, sub.ports),
                                           f"its ports: {', '.join(sub.ports) or 'none'}")))
            return None
        if port.used is not None:
            self.report(_error(codes.E339, f"port '{written.name}.{port_name}' is bonded twice", written.span,
                               hint="a port is one bond through the boundary; join more bonds at a junction "
                                    "outside",
                               related=[Related(port.used, "first bonded here")]))
            return None
        port.used = written.span
        if port.end is None:
            return None    # reported inside (E333)
        if into != port.inward:
            outside = "into" if into else "out of"
            inside = "from the port inward" if port.inward else "toward the port"
            self.report(_error(codes.E342, f"the bonds at port '{written.name}.{port_name}' disagree on the power "
                                       f"direction: outside it points {outside} the component, inside it points "
                                       f"{inside}", bond_span,
                               hint="reverse one of the two bonds (a port's power goes in on both sides or out "
                                    "on both)",
                               related=[Related(port.bond_span, f"the bond at port '{port_name}' inside "
                                                                f"'{sub.model.name}'")]))
            # joined all the same, as the outside bond draws it: the element inside is bonded, and
            # is not reported again as having no bond (the model does not compile either way)
        for name in port.names:
            self.aliases[name] = bond_name
        return dataclasses.replace(port.end, span=written.span)   # where it is written at this level


class _InstanceMark:
    """Where an instance's statements start in the flat body (dropped before the model is built)."""

    def __init__(self, path: str):
        self.path = path


# ----------------------------------------------------------------- renaming

class _Renamer:
    """Expressions and statements of one model, renamed into the flat namespace."""

    def __init__(self, flattener: _Flattener, x: _Expansion):
        self.flattener = flattener
        self.x = x
        self.exempt: frozenset[str] = frozenset()

    def name(self, name: str) -> str:
        if name in self.exempt or not self.x.prefix:
            return name
        return self.x.prefix + name if name in self.x.values else name

    def function(self, name: str) -> str:
        return self.x.prefix + name if self.x.prefix and name in self.x.functions else name

    def expr(self, node):
        if isinstance(node, ast.Name):
            return dataclasses.replace(node, name=self.name(node.name)) if node.name not in self.exempt else node
        if isinstance(node, ast.Ref):
            return self.ref(node)
        if isinstance(node, ast.Call):
            return dataclasses.replace(node, func=self.function(node.func), args=tuple(self.expr(a) for a in node.args))
        if isinstance(node, ast.ListExpr):
            return dataclasses.replace(node, items=tuple(self.expr(i) for i in node.items))
        if isinstance(node, ast.Unary):
            return dataclasses.replace(node, operand=self.expr(node.operand))
        if isinstance(node, ast.Binary):
            return dataclasses.replace(node, left=self.expr(node.left), right=self.expr(node.right))
        if isinstance(node, ast.If):
            return dataclasses.replace(node, cond=self.expr(node.cond), then=self.expr(node.then),
                                       orelse=self.expr(node.orelse))
        return node

    def ref(self, node: ast.Ref):
        head, rest = node.parts[0], node.parts[1:]
        x = self.x
        if head in self.exempt:
            return node
        if head in x.instances:
            return self.member(x.instances[head], rest, node, head)
        if not x.prefix:
            return node
        if head in x.nodes or _BOND_NUMBER.fullmatch(head):
            return dataclasses.replace(node, parts=(x.prefix + head,) + rest)
        return node

    def member(self, sub: _Expansion, parts: tuple[str, ...], node: ast.Ref, written: str):
        """``valve.loss.f``, ``valve.Q``, ``plant.valve.A``: a name inside an instance."""
        if not parts:
            return node
        head, rest = parts[0], parts[1:]
        if head in sub.instances:
            return self.member(sub.instances[head], rest, node, f"{written}.{head}")
        if head in sub.nodes or _BOND_NUMBER.fullmatch(head):
            return dataclasses.replace(node, parts=(sub.prefix + head,) + rest)
        if head in sub.values and not rest:
            return ast.Name(sub.prefix + head, node.span)
        hint: str | None
        if head in sub.ports:
            message = f"'{written}.{head}' is a port of '{sub.model.name}'; a port has no variables"
            hint = "use a variable of the element or junction the port is bonded to inside"
        elif head in sub.values:
            message = f"'{written}.{head}' is a value, not an element: '{'.'.join(rest)}' cannot follow it"
            hint = f"write {written}.{head}"
        else:
            members = sorted(sub.nodes | sub.values | set(sub.instances))
            message = f"instance '{written}' of '{sub.model.name}' has no '{head}'"
            hint = _hints(_did_you_mean(head, members), f"it has: {', '.join(members[:12])}"
                          + (", ..." if len(members) > 12 else ""))
        self.flattener.report(_error(codes.E312, message, node.span, hint=hint))
        return ast.Num(0.0, "0", node.span)

    # -- statements

    def laws(self, laws: tuple, exempt: frozenset[str]) -> tuple:
        saved, self.exempt = self.exempt, exempt
        try:
            out: list[ast.Law] = []
            for law in laws:
                if isinstance(law, ast.LawAssign):
                    out.append(dataclasses.replace(law, value=self.expr(law.value)))
                elif isinstance(law, ast.LawCall):
                    func = law.func if law.func in ("der",) or law.func in exempt else self.name(law.func)
                    out.append(dataclasses.replace(law, func=func, arg=self.expr(law.arg), value=self.expr(law.value)))
                else:
                    out.append(law)
            return tuple(out)
        finally:
            self.exempt = saved

    def statement(self, s):
        p = self.x.prefix
        if isinstance(s, ast.Param):
            return dataclasses.replace(s, name=self.name(s.name), value=self.expr(s.value))
        if isinstance(s, (ast.Output, ast.Discrete)):
            return dataclasses.replace(s, name=self.name(s.name), value=self.expr(s.value))
        if isinstance(s, ast.Input):
            value = None if s.value is None else self.expr(s.value)
            if s.external and p:
                # a component's external input is an input with a default, which its instance may
                # bind: only the top model's external inputs are supplied by the host (section 15)
                value = value if value is not None else ast.Num(0.0, "0", s.name_span)
                return dataclasses.replace(s, name=self.name(s.name), value=value, external=False)
            return dataclasses.replace(s, name=self.name(s.name), value=value)
        if isinstance(s, ast.StateDecl):
            return dataclasses.replace(s, name=self.name(s.name), laws=self.laws(s.laws, frozenset()))
        if isinstance(s, ast.FnDef):
            saved, self.exempt = self.exempt, frozenset(s.params)
            try:
                return dataclasses.replace(s, name=self.function(s.name), body=self.expr(s.body))
            finally:
                self.exempt = saved
        if isinstance(s, ast.Element):
            kind = KINDS.get(s.kind)
            own = {law.name for law in s.laws if isinstance(law, ast.LawState)}
            if kind is not None and kind.state:
                own.add(kind.state)          # q of a C, p of an I
            return dataclasses.replace(s, name=p + s.name, laws=self.laws(s.laws, _ELEMENT_LOCALS | own))
        if isinstance(s, ast.Junction):
            return dataclasses.replace(s, names=tuple(p + n for n in s.names))
        if isinstance(s, ast.When):
            actions = []
            for action in s.actions:
                if isinstance(action, ast.WhenAssign):
                    actions.append(dataclasses.replace(action, name=self.name(action.name),
                                                       value=self.expr(action.value)))
                else:
                    actions.append(dataclasses.replace(action, args=tuple(self.expr(a) for a in action.args)))
            return dataclasses.replace(s, condition=self.expr(s.condition), actions=tuple(actions))
        return s


# ---------------------------------------------------------------- the entry

def flatten(model: ast.Model, files: Sequence[ast.File], *, standalone: bool = False) -> Flat:
    """``model`` with every instance expanded (see the module docstring).

    ``standalone``: ``model`` is checked on its own although it declares ports (``bondc check`` on
    a component): each port becomes a zero-effort source so that everything inside can be checked.
    """
    flat = Flat(model)
    plain = not any(isinstance(s, ast.PortDecl) or (isinstance(s, ast.Input) and s.value is None)
                    for s in model.body)
    if plain and not _has_instances(model, files):
        return flat         # a version-1 model: nothing to expand
    flattener = _Flattener(files, flat, standalone)
    try:
        x = flattener.expand(model, "", ((model, model.name),))
    except _TooLarge:
        flat.too_large = True       # (reported; nothing of the model is checked further)
        return flat
    body = [s for s in x.statements if not isinstance(s, _InstanceMark)] + x.bonds
    if flattener.aliases:
        body = [_realias(s, flattener.aliases) for s in body]
    body = [dataclasses.replace(s, value=ast.Num(0.0, "0", s.name_span if s.external else s.span))
            if isinstance(s, ast.Input) and s.value is None else s for s in body]
    flat.model = dataclasses.replace(model, body=tuple(body))
    return flat


def _has_instances(model: ast.Model, files: Sequence[ast.File]) -> bool:
    names = {m.name for f in files for m in f.models}
    return any(isinstance(s, ast.Element) and (s.kind in names or "." in s.kind) and s.kind not in KINDS
               for s in model.body)


def _realias(statement, aliases: Mapping[str, str]):
    """References to a port bond by its inner name point to the fused bond."""
    def final(name: str) -> str:
        seen = set()
        while name in aliases and name not in seen:
            seen.add(name)
            name = aliases[name]
        return name

    def fix(node):
        if isinstance(node, ast.Ref) and node.parts[0] in aliases:
            return dataclasses.replace(node, parts=(final(node.parts[0]),) + node.parts[1:])
        if isinstance(node, tuple):
            return tuple(fix(item) for item in node)
        if dataclasses.is_dataclass(node) and not isinstance(node, (type, Span)):
            changes = {f.name: fix(getattr(node, f.name)) for f in dataclasses.fields(node)
                       if not isinstance(getattr(node, f.name), (str, float, int, Span, type(None)))}
            return dataclasses.replace(node, **changes) if changes else node
        return node

    return fix(statement)
