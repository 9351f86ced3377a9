"""Causality stage: :class:`~bondc.model.BondGraph` -> :class:`CausalGraph`.

The sequential causality assignment procedure (SCAP, Karnopp, Margolis &
Rosenberg ch. 5), deterministic: elements and bonds are taken in declaration
order, so the same file always gets the same assignment.

1. Every source gets its fixed causality (``Se``/``MSe`` set the effort of
   their bond, ``Sf``/``MSf`` its flow); the consequences are propagated
   through 0- and 1-junctions, transformers and gyrators after each choice.
   Two sources that cannot both hold (two ``Sf`` on one 1-junction, two ``Se``
   on one 0-junction, ...) are a causal conflict, ``E601``.
2. Every storage element not yet constrained gets integral causality (a ``C``
   sets the effort of its bond, an ``I`` the flow) and is propagated. A storage
   element whose causality was forced the other way, or whose integral
   causality would conflict, is in derivative causality (``W602``): its state
   depends on the others' and the equations stage eliminates it.
3. Every resistor not yet constrained gets the causality in which its law is
   written (``e = expr(f)`` -> resistance, ``f = expr(e)`` -> conductance;
   resistance when both are given), falling back to the other if that
   conflicts.
4. Bonds still without causality (loops of junctions only) are given one
   arbitrarily but deterministically (the tail sets the effort), in bond order.

Afterwards the algebraic loops (cycles of the causal dependencies that pass
through no storage element, e.g. two resistors closing a loop) are reported as
``I603``.

``effort_setter[bond]`` names the node (element or junction) that sets the
effort of a bond; the other end sets its flow. The causal stroke is drawn at
the end that receives the effort (:meth:`CausalGraph.stroke_end`).

Diagnostics: ``E601`` causal conflict (raised as
:class:`~bondc.errors.CausalityError` with every conflict found), ``W602``
derivative causality, ``I603`` algebraic loop. :func:`structural_conflicts`
gives the ``E601`` of a model whose laws have errors (the semantic stage reports
them with those errors).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Hashable, Iterable, Mapping, Sequence, TypeVar

from bondc import ast
from bondc.kinds import GYRATOR, KINDS, RESISTOR, SOURCE, STORAGE, TRANSFORMER, WORDS
from bondc.errors import CausalityError, Diagnostic, Related, sort_key
from bondc.model import BondGraph, ElementNode, JunctionNode, readable_names
from bondc.source import Span
from bondc import codes

# ---------------------------------------------------------------- kinds as data (bondc.kinds)

#: Causal role of each element kind.
ROLES: Mapping[str, str] = {name: kind.role for name, kind in KINDS.items()}

#: One-port causalities: name -> whether the element sets the effort of its bond,
#: in order of preference.
ONE_PORT_CAUSALITIES: Mapping[str, tuple[tuple[str, bool], ...]] = {
    name: tuple((c.name, c.sets_effort) for c in kind.causalities) for name, kind in KINDS.items() if kind.causalities}

INTEGRAL, DERIVATIVE = "integral", "derivative"
RESISTANCE, CONDUCTANCE = "resistance", "conductance"

#: What a dotted reference names: ``("e" | "f", bond number)`` or ``("state", qualified name)``.
Reference = tuple[str, int] | tuple[str, str]
#: A causal relation: (node, the variable it computes, the variables it reads); see causal_relations.
Relation = tuple[str, str, tuple[str, ...]]
_Node = TypeVar("_Node", bound=Hashable)


# ------------------------------------------------------------------ results

@dataclass(frozen=True)
class AlgebraicLoop:
    """A cycle of causal dependencies through no storage element."""

    resistors: tuple[str, ...]      # R elements on the loop, declaration order
    junctions: tuple[str, ...]      # junctions on the loop
    nodes: tuple[str, ...]          # every element and junction on the loop
    variables: tuple[str, ...]      # bond variables on the loop ("b3.e", "b4.f", ...)


@dataclass(frozen=True)
class CausalGraph:
    """A bond graph with a causality on every bond.

    - ``effort_setter``: bond number -> name of the node that sets the bond's
      effort (the other end sets its flow);
    - ``storage``: storage element -> ``"integral"`` or ``"derivative"``;
    - ``resistors``: R element -> ``"resistance"`` (sets its effort: ``e = law(f)``)
      or ``"conductance"`` (sets its flow);
    - ``dependencies``: storage element in derivative causality -> the
      elements (integral storage and sources) its port variable is fixed by;
    - ``algebraic_loops``: the loops found (each also reported as I603);
    - ``diagnostics``: warnings and infos (W602, I603), sorted by position.
    """

    graph: BondGraph
    effort_setter: Mapping[int, str]
    storage: Mapping[str, str]
    resistors: Mapping[str, str]
    dependencies: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    algebraic_loops: tuple[AlgebraicLoop, ...] = ()
    diagnostics: tuple[Diagnostic, ...] = ()

    # -- per bond

    def effort_from(self, bond: int) -> str:
        """The node that sets the effort of ``bond``."""
        return self.effort_setter[bond]

    def flow_from(self, bond: int) -> str:
        """The node that sets the flow of ``bond`` (the other end)."""
        return _other_end(self.graph, bond, self.effort_setter[bond])

    def stroke_end(self, bond: int) -> str:
        """The end where the causal stroke is drawn: the node receiving the effort."""
        return self.flow_from(bond)

    def sets_effort(self, bond: int, node: str) -> bool:
        return self.effort_setter[bond] == node

    def strong_bond(self, junction: str) -> int:
        """The bond that sets a junction's common variable.

        For a 0-junction the one bond whose other end sets the effort; for a
        1-junction the one bond whose other end sets the flow.
        """
        node = self.graph.junctions[junction]
        for bond in node.bonds:
            if node.kind_info.strong(self.sets_effort(bond, junction)):
                return bond
        raise KeyError(f"junction {junction!r} has no strong bond")

    # -- per element

    @property
    def integral_storage(self) -> tuple[str, ...]:
        return tuple(name for name, c in self.storage.items() if c == INTEGRAL)

    @property
    def derivative_storage(self) -> tuple[str, ...]:
        return tuple(name for name, c in self.storage.items() if c == DERIVATIVE)

    def reference(self, parts: tuple[str, ...], owner: str | None = None) -> Reference | None:
        """What a dotted reference names: ``("e"|"f", bond)`` or ``("state", qualified)``.

        ``owner`` is the element whose law holds the reference (a two-port may
        write ``p1.e``). Returns None for a reference to nothing.
        """
        return resolve_reference(self.graph, self.effort_setter, parts, owner)

    # -- summaries

    def summary(self) -> dict[str, Any]:
        return {
            "integral": len(self.integral_storage),
            "derivative": len(self.derivative_storage),
            "derivative_storage": list(self.derivative_storage),
            "resistance": sum(c == RESISTANCE for c in self.resistors.values()),
            "conductance": sum(c == CONDUCTANCE for c in self.resistors.values()),
            "algebraic_loops": len(self.algebraic_loops),
        }

    def summary_text(self) -> str:
        n_int, n_der = len(self.integral_storage), len(self.derivative_storage)
        loops = len(self.algebraic_loops)
        text = f"causality: {n_int} integral"
        if n_der:
            text += f", {n_der} derivative ({', '.join(self.derivative_storage)})"
        text += f", {loops} algebraic loop{'s' if loops != 1 else ''}"
        return text


# ----------------------------------------------------------------- helpers

def _other_end(graph: BondGraph, bond: int, node: str) -> str:
    b = graph.bond(bond)
    return b.head if b.tail == node else b.tail


def element_span(element: ElementNode) -> Span:
    """Where a diagnostic about an element points: its name."""
    return element.name_span if element.name_span.line > 0 else element.span


def resolve_reference(graph: BondGraph, effort_setter: Mapping[int, str], parts: tuple[str, ...],
                      owner: str | None = None) -> Reference | None:
    """See :meth:`CausalGraph.reference`."""
    parts = tuple(parts)
    if owner is not None and owner in graph.elements and len(parts) == 2 and parts[0] in ("p1", "p2"):
        element = graph.elements[owner]
        if len(element.bonds) == 2 and parts[1] in ("e", "f"):
            return (parts[1], element.bonds[int(parts[0][1]) - 1])
    head = parts[0]
    if head in graph.elements:
        element = graph.elements[head]
        if len(parts) == 2 and parts[1] in ("e", "f") and len(element.bonds) == 1:
            return (parts[1], element.bonds[0])
        if len(parts) == 2:
            for state in element.states:
                if state.name == parts[1]:
                    return ("state", state.qualified)
        if len(parts) == 3 and parts[1] in ("p1", "p2") and parts[2] in ("e", "f") and len(element.bonds) == 2:
            return (parts[2], element.bonds[int(parts[1][1]) - 1])
        return None
    if head in graph.junctions and len(parts) == 2:
        junction = graph.junctions[head]
        wanted = junction.kind_info.common
        if parts[1] != wanted:
            return None
        for bond in junction.bonds:
            if junction.kind_info.strong(effort_setter.get(bond) == head):
                return (wanted, bond)
        return (wanted, junction.bonds[0]) if junction.bonds else None
    if len(parts) == 2 and parts[1] in ("e", "f"):
        for labelled in graph.bonds:
            if labelled.label == head:
                return (parts[1], labelled.number)
        if head.startswith("b") and head[1:].isdigit() and 1 <= int(head[1:]) <= len(graph.bonds):
            return (parts[1], int(head[1:]))
    return None


# ------------------------------------------------------------------- SCAP

@dataclass(frozen=True)
class _Conflict:
    node: str | None            # junction or two-port where it shows, or None for one bond
    bonds: tuple[int, ...]
    what: str                   # "effort" | "flow" | "bond" | "none" | "two-port"
    setter: str | None = None   # for a bond: the end the failing choice wanted to set its effort


class _Assignment:
    """Effort setters chosen so far, with the decision each one came from."""

    def __init__(self, graph: BondGraph):
        self.graph = graph
        self.setter: dict[int, str] = {}
        self.origin: dict[int, str] = {}
        self.journal: list[int] = []      # bonds in the order they were set (to undo a failed trial)

    def copy(self) -> "_Assignment":
        other = _Assignment(self.graph)
        other.setter = dict(self.setter)
        other.origin = dict(self.origin)
        return other

    def undo(self, mark: int) -> None:
        """Forget every bond set after ``len(journal) == mark`` (a trial that conflicted)."""
        while len(self.journal) > mark:
            bond = self.journal.pop()
            del self.setter[bond]
            del self.origin[bond]

    def decide(self, bond: int, setter: str, origin: str) -> _Conflict | None:
        queue: list[str] = []
        conflict = self._set(bond, setter, origin, queue)
        return conflict or self._propagate(queue, origin)

    def _set(self, bond: int, setter: str, origin: str, queue: list[str]) -> _Conflict | None:
        current = self.setter.get(bond)
        if current is not None:
            if current == setter:
                return None
            return _Conflict(None, (bond,), "bond", setter)
        self.setter[bond] = setter
        self.origin[bond] = origin
        self.journal.append(bond)
        b = self.graph.bond(bond)
        queue.extend((b.tail, b.head))
        return None

    def _propagate(self, queue: list[str], origin: str) -> _Conflict | None:
        while queue:
            node = queue.pop(0)
            result = self._constrain(node)
            if isinstance(result, _Conflict):
                return result
            for bond, setter in result:
                conflict = self._set(bond, setter, origin, queue)
                if conflict:
                    return conflict
        return None

    def _constrain(self, node: str) -> _Conflict | list[tuple[int, str]]:
        if node in self.graph.junctions:
            junction = self.graph.junctions[node]
            return self._junction(junction)
        element = self.graph.elements.get(node)
        if element is not None and element.kind_info.two_port:
            return self._two_port(element)
        return []

    def _junction(self, junction: JunctionNode) -> _Conflict | list[tuple[int, str]]:
        name = junction.name
        # "marked": bonds on which the junction's single-source variable enters it.
        # 0-junction: the effort comes in on exactly one bond (its other end sets it).
        # 1-junction: the flow comes in on exactly one bond (the junction sets its effort).
        marked, unmarked, free = [], [], []
        for bond in junction.bonds:
            setter = self.setter.get(bond)
            if setter is None:
                free.append(bond)
            elif junction.kind_info.strong(setter == name):
                marked.append(bond)
            else:
                unmarked.append(bond)
        variable = junction.kind_info.common_word
        if len(marked) > 1:
            return _Conflict(name, tuple(marked), variable)
        if len(marked) == 1:
            return [(bond, self._unmarked_setter(junction, bond)) for bond in free]
        if not free:
            return _Conflict(name, tuple(unmarked), "none")
        if len(free) == 1:
            bond = free[0]
            return [(bond, self._marked_setter(junction, bond))]
        return []

    def _marked_setter(self, junction: JunctionNode, bond: int) -> str:
        # the bond bringing the common variable in: a 1-junction sets its effort, a 0-junction does not
        return _setter_at(self.graph, junction, bond, junction.kind_info.common == "f")

    def _unmarked_setter(self, junction: JunctionNode, bond: int) -> str:
        return _setter_at(self.graph, junction, bond, junction.kind_info.common == "e")

    def _two_port(self, element: ElementNode) -> _Conflict | list[tuple[int, str]]:
        name = element.name
        first, second = element.bonds
        gyrator = element.kind_info.role == GYRATOR
        s1, s2 = self.setter.get(first), self.setter.get(second)
        if s1 is None and s2 is None:
            return []
        if s1 is not None and s2 is not None:
            same = (s1 == name) == (s2 == name)
            return [] if same == gyrator else _Conflict(name, (first, second), "two-port")
        known, other = (first, second) if s1 is not None else (second, first)
        element_sets = self.setter[known] == name
        if gyrator:
            other_setter = name if element_sets else _other_end(self.graph, other, name)
        else:
            other_setter = _other_end(self.graph, other, name) if element_sets else name
        return [(other, other_setter)]


def _one_port_options(element: ElementNode, conductance: bool | None = None) -> tuple[tuple[str, bool], ...]:
    """The causalities of a one-port, preferred first; ``conductance`` (an R): prefer conductance
    (True) or resistance (False) whatever its laws say (:func:`structural_conflicts`)."""
    options = ONE_PORT_CAUSALITIES[element.kind]
    # a resistor given only as f = expr(e) prefers the causality its law computes
    resistor = element.kind_info.role == RESISTOR
    if conductance is None:
        conductance = resistor and "e" not in element.laws and "f" in element.laws
    if resistor and conductance:
        options = tuple(reversed(options))
    return options


def _setter_at(graph: BondGraph, junction: JunctionNode, bond: int, junction_sets: bool) -> str:
    return junction.name if junction_sets else _other_end(graph, bond, junction.name)


def _setter_for(graph: BondGraph, element: ElementNode, sets_effort: bool) -> str:
    return element.name if sets_effort else _other_end(graph, element.bond, element.name)


class _Procedure:
    def __init__(self, graph: BondGraph, conductance: Mapping[str, bool] | None = None):
        self.graph = graph
        self.state = _Assignment(graph)
        self.errors: list[Diagnostic] = []
        self.conductance = conductance or {}    # R name -> preferred causality, over its laws
        self.fixed_errors = 0       # how many of the errors the sources and storage elements met

    def run(self) -> _Assignment:
        graph = self.graph
        elements = list(graph.elements.values())
        for element in elements:
            if element.kind_info.role == SOURCE:
                self._decide_element(element)
        for element in elements:
            if element.kind_info.role == STORAGE:
                self._decide_element(element)
        self.fixed_errors = len(self.errors)
        for element in elements:
            if element.kind_info.role == RESISTOR:
                self._decide_element(element)
        for bond in graph.bonds:
            if bond.number not in self.state.setter:
                self._decide(bond.number, ((bond.tail, f"bond {bond.number}"), (bond.head, f"bond {bond.number}")),
                             subject=None)
        return self.state

    def _decide_element(self, element: ElementNode) -> None:
        if len(element.bonds) != 1:
            return
        if element.bond in self.state.setter and element.kind_info.role != SOURCE:
            return      # forced by an earlier choice: storage in derivative causality, or an R either way
        options = tuple((_setter_for(self.graph, element, sets), element.name)
                        for _, sets in _one_port_options(element, self.conductance.get(element.name)))
        self._decide(element.bond, options, subject=element)

    def _decide(self, bond: int, options: Iterable[tuple[str, str]], subject: ElementNode | None) -> None:
        first_conflict: tuple[_Conflict, _Assignment, str] | None = None
        for setter, origin in options:
            # try the option in place; undo it on a conflict (a copy of the whole assignment per
            # decision made causality quadratic in the number of bonds)
            mark = len(self.state.journal)
            conflict = self.state.decide(bond, setter, origin)
            if conflict is None:
                return
            if first_conflict is None:
                first_conflict = (conflict, self.state.copy(), origin)
            self.state.undo(mark)
        assert first_conflict is not None, "a decision has at least one option"
        conflict, trial, origin = first_conflict
        self.errors.append(_conflict_diagnostic(self.graph, conflict, trial, origin, subject))


# --------------------------------------------------------------- diagnostics

def describe_node(graph: BondGraph, name: str) -> str:
    """``resistor 'damper'``, ``1-junction 'j'``: a node as diagnostics name it."""
    if name in graph.elements:
        element = graph.elements[name]
        return f"{element.kind_info.description} '{name}'"
    if name in graph.junctions:
        return f"{graph.junctions[name].kind}-junction '{name}'"
    return name


def join_words(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def _bond_text(graph: BondGraph, number: int) -> str:
    bond = graph.bond(number)
    label = f" ({bond.label})" if bond.label else ""
    return f"bond {number}{label}: {bond.tail} -> {bond.head}"


def _at_node(graph: BondGraph, conflict: _Conflict, trial: _Assignment, subject: ElementNode | None) -> _Conflict:
    """A conflict on one bond, described at the junction or two-port that propagated it there."""
    number = conflict.bonds[0]
    bond = graph.bond(number)
    for end in (bond.head, bond.tail):
        if subject is not None and end == subject.name:
            continue
        if end in graph.junctions:
            junction = graph.junctions[end]
            marked = [b for b in junction.bonds if b in trial.setter and b != number
                      and junction.kind_info.strong(trial.setter[b] == end)]
            return _Conflict(end, tuple(marked) + (number,), junction.kind_info.common_word)
        if end in graph.elements and graph.elements[end].kind_info.two_port:
            return _Conflict(end, graph.elements[end].bonds, "two-port")
    return conflict


def _conflict_diagnostic(graph: BondGraph, conflict: _Conflict, trial: _Assignment, origin: str,
                         subject: ElementNode | None) -> Diagnostic:
    if conflict.node is None:
        conflict = _at_node(graph, conflict, trial, subject)
    origins: list[str] = []
    for bond in conflict.bonds:
        who = trial.origin.get(bond)
        if who and who not in origins and who != origin:
            origins.append(who)
    origins.append(origin)
    culprits = [name for name in origins if name in graph.elements]
    where = conflict.node
    described = join_words([describe_node(graph, name) for name in culprits]) or "the bonds"
    if where is not None and where in graph.junctions:
        junction = graph.junctions[where].kind_info
        kind = junction.name
        if conflict.what == "none":
            message = (f"causal conflict: every bond of {kind}-junction '{where}' imposes its {junction.summed_word} "
                       f"({described}), so nothing sets its common {junction.common_word}")
        else:
            verb = "both set" if len(culprits) == 2 else "all set"
            message = f"causal conflict: {described} {verb} the {conflict.what} of {kind}-junction '{where}'"
        hint = (f"a {kind}-junction takes its common {junction.common_word} from exactly one bond; "
                "remove one of them, or put a resistor or storage element between them")
    elif where is not None and where in graph.elements:
        message = (f"causal conflict at {describe_node(graph, where)}: {described} impose incompatible causality "
                   f"on its two ports")
        hint = "a transformer passes an effort through in one direction only; a gyrator turns flow into effort"
    else:
        bond = conflict.bonds[0]
        wanted = "effort"
        if subject is not None and conflict.setter is not None and subject.bonds == (bond,):
            wanted = "effort" if conflict.setter == subject.name else "flow"
        message = f"causal conflict on bond {bond}: {described} both set its {wanted}"
        hint = "one end of a bond sets the effort and the other the flow"
    if subject is not None and subject.kind_info.role == STORAGE:
        message += f" (no causality of '{subject.name}' is consistent)"
    primary = element_span(subject) if subject is not None else graph.bond(conflict.bonds[0]).span
    related: list[Related] = []
    for name in culprits:
        if subject is not None and name == subject.name:
            continue
        related.append(Related(element_span(graph.elements[name]), f"{describe_node(graph, name)} is declared here"))
    if where is not None and where in graph.junctions:
        related.append(Related(graph.junctions[where].span, f"{describe_node(graph, where)}"))
    elif where is not None and where in graph.elements and (subject is None or where != subject.name):
        related.append(Related(element_span(graph.elements[where]), describe_node(graph, where)))
    for bond in conflict.bonds:
        related.append(Related(graph.bond(bond).span, _bond_text(graph, bond)))
    if subject is not None and subject.kind_info.role == SOURCE:
        related.append(Related(graph.bond(subject.bond).span, _bond_text(graph, subject.bond)))
    return Diagnostic("error", codes.E601, message, primary, hint=hint, related=_unique(related))


def _unique(related: Iterable[Related]) -> tuple[Related, ...]:
    out: list[Related] = []
    for item in related:
        if item not in out:
            out.append(item)
    return tuple(out)


# --------------------------------------------- causal dependencies (structure)

def _law_references(graph: BondGraph, setter: Mapping[int, str], expr: ast.Expr, owner: str | None) -> list[str]:
    """Graph variables an expression reads, as dependency keys (``e3``, ``f3``, ``s:mass.p``, ``o:x``)."""
    out: list[str] = []
    element = graph.elements.get(owner) if owner else None
    local_states = {s.name: s.qualified for s in element.states} if element else {}
    model_states = {s.name: s.qualified for s in graph.model_states}
    for node in ast.walk(expr):
        key = None
        if isinstance(node, ast.Ref):
            target = resolve_reference(graph, setter, node.parts, owner)
            if target is not None:
                key = f"s:{target[1]}" if target[0] == "state" else f"{target[0]}{target[1]}"
        elif isinstance(node, ast.Name):
            if element is not None and len(element.bonds) == 1 and node.name in ("e", "f"):
                key = f"{node.name}{element.bond}"
            elif node.name in local_states:
                key = f"s:{local_states[node.name]}"
            elif node.name in model_states:
                key = f"s:{model_states[node.name]}"
            elif node.name in graph.outputs:
                key = f"o:{node.name}"
        if key is not None and key not in out:
            out.append(key)
    return out


def causal_relations(graph: BondGraph, setter: Mapping[int, str], storage: Mapping[str, str]) -> tuple[Relation, ...]:
    """Structural causal dependencies: ``(node, computed variable, variables it reads)``.

    Variables are keys ``e3``/``f3`` (bond 3), ``s:mass.p`` (a state), ``o:x``
    (an output). A storage element in derivative causality reads nothing here:
    its output is a time derivative, handled by the equations stage.
    """
    relations: list[tuple[str, str, tuple[str, ...]]] = []

    def refs(element: ElementNode, targets: Iterable[str]) -> list[str]:
        out: list[str] = []
        for target in targets:
            if target in element.laws:
                out += _law_references(graph, setter, element.laws[target], element.name)
        return out

    for element in graph.elements.values():
        role = element.kind_info.role
        if role in (SOURCE, STORAGE, RESISTOR):
            bond = element.bond
            element_sets = setter[bond] == element.name
            output = f"e{bond}" if element_sets else f"f{bond}"
            if role == SOURCE:
                inputs = refs(element, ("e", "f"))
            elif role == STORAGE:
                if storage.get(element.name) == DERIVATIVE:
                    inputs = []
                else:
                    inputs = [f"s:{s.qualified}" for s in element.states] + refs(element, ("e", "f"))
            else:
                inputs = [f"f{bond}" if element_sets else f"e{bond}"] + refs(element, ("e", "f"))
            relations.append((element.name, output, tuple(dict.fromkeys(k for k in inputs if k != output))))
        elif role in (TRANSFORMER, GYRATOR):
            first, second = element.bonds
            modulation = refs(element, ("r",))
            sets_first = setter[first] == element.name
            if role == TRANSFORMER:
                if sets_first:
                    pairs = ((f"e{first}", f"e{second}"), (f"f{second}", f"f{first}"))
                else:
                    pairs = ((f"e{second}", f"e{first}"), (f"f{first}", f"f{second}"))
            elif sets_first:
                pairs = ((f"e{first}", f"f{second}"), (f"e{second}", f"f{first}"))
            else:
                pairs = ((f"f{second}", f"e{first}"), (f"f{first}", f"e{second}"))
            for output, source in pairs:
                relations.append((element.name, output, tuple(dict.fromkeys([source] + modulation))))
    for junction in graph.junctions.values():
        bonds = junction.bonds
        if not bonds:
            continue
        strong = None
        for bond in bonds:
            if junction.kind_info.strong(setter[bond] == junction.name):
                strong = bond
        if strong is None:
            continue
        common, summed = junction.kind_info.common, junction.kind_info.summed
        others = [b for b in bonds if b != strong]
        for bond in others:
            relations.append((junction.name, f"{common}{bond}", (f"{common}{strong}",)))
        relations.append((junction.name, f"{summed}{strong}", tuple(f"{summed}{b}" for b in others)))
    for declared in graph.outputs.values():
        relations.append((declared.name, f"o:{declared.name}",
                          tuple(_law_references(graph, setter, declared.expr, None))))
    return tuple(relations)


def strongly_connected(nodes: Sequence[_Node], edges: Mapping[_Node, Iterable[_Node]]) -> list[list[_Node]]:
    """Tarjan's algorithm, iterative and deterministic (follows the given orders).

    Returns the components with every component after the ones it depends on
    (edges point from a node to what it depends on).
    """
    index: dict[_Node, int] = {}
    low: dict[_Node, int] = {}
    on_stack: set[_Node] = set()
    stack: list[_Node] = []
    components: list[list[_Node]] = []
    order = {n: i for i, n in enumerate(nodes)}
    counter = 0
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(edges.get(root, ())))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(edges.get(child, ()))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                component.sort(key=lambda n: order.get(n, len(order)))
                components.append(component)
    return components


def _variable_name(graph: BondGraph, key: str) -> str:
    if key[0] in "ef" and key[1:].isdigit():
        return f"{graph.bond(int(key[1:])).name}.{key[0]}"
    return key.split(":", 1)[1]


def _variable_order(key: str) -> tuple[int, int, str]:
    if key[0] in "ef" and key[1:].isdigit():
        return (0, int(key[1:]), key[0])
    return (1, 0, key)


def _find_loops(graph: BondGraph, relations: Sequence[Relation]) -> tuple[AlgebraicLoop, ...]:
    computed_by = {output: node for node, output, _ in relations}
    edges = {output: [k for k in inputs if k in computed_by] for _, output, inputs in relations}
    nodes = [output for _, output, _ in relations]
    loops = []
    positions = {n: i for i, n in enumerate((*graph.elements, *graph.junctions, *graph.outputs))}
    for component in strongly_connected(nodes, edges):
        cyclic = len(component) > 1 or component[0] in edges.get(component[0], ())
        if not cyclic:
            continue
        members = {computed_by[k] for k in component}
        ordered = sorted(members, key=positions.__getitem__)
        loops.append(AlgebraicLoop(
            resistors=tuple(n for n in ordered if n in graph.elements and graph.elements[n].kind_info.role == RESISTOR),
            junctions=tuple(n for n in ordered if n in graph.junctions),
            nodes=tuple(ordered),
            variables=tuple(_variable_name(graph, k) for k in sorted(component, key=_variable_order)),
        ))
    return tuple(loops)


def _loop_diagnostic(graph: BondGraph, loop: AlgebraicLoop, element_names: Mapping[str, str]) -> Diagnostic:
    """I603 for ``loop``, its variables named by their elements (``element_names``: readable_names)."""
    parts = []
    if loop.resistors:
        parts.append(f"resistor{'s' if len(loop.resistors) > 1 else ''} "
                     + join_words([f"'{n}'" for n in loop.resistors]))
    if loop.junctions:
        parts.append(f"junction{'s' if len(loop.junctions) > 1 else ''} "
                     + join_words([f"'{n}'" for n in loop.junctions]))
    rest = [n for n in loop.nodes if n not in loop.resistors and n not in loop.junctions]
    if rest:
        parts.append(join_words([f"'{n}'" for n in rest]))
    first = loop.nodes[0]
    span = (element_span(graph.elements[first]) if first in graph.elements
            else graph.junctions[first].span if first in graph.junctions else graph.outputs[first].span)
    related = []
    for name in loop.nodes[1:]:
        if name in graph.elements:
            related.append(Related(element_span(graph.elements[name]), f"{describe_node(graph, name)} is on the loop"))
        elif name in graph.junctions:
            related.append(Related(graph.junctions[name].span, f"{describe_node(graph, name)} is on the loop"))
    return Diagnostic(
        "info", codes.I603,
        f"algebraic loop through {join_words(parts)}: "
        f"{', '.join(element_names.get(v, v) for v in loop.variables)} depend on each other "
        "with no storage element in between; the equations stage solves the loop",
        span, related=tuple(related),
        hint="a small storage element (or a resistor in the other causality) would break the loop")


def _dependencies(graph: BondGraph, relations: Sequence[Relation], storage: Mapping[str, str]) -> dict[str, tuple[str, ...]]:
    """For each storage element in derivative causality: the integral storage
    elements and sources its port input is computed from."""
    computed = {output: (node, inputs) for node, output, inputs in relations}
    owners = {f"s:{s.qualified}": s.owner for s in graph.states if s.owner}
    result: dict[str, tuple[str, ...]] = {}
    positions = {n: i for i, n in enumerate(graph.elements)}
    for name, causality in storage.items():
        if causality != DERIVATIVE:
            continue
        element = graph.elements[name]
        start = f"{element.kind_info.law_variable}{element.bond}"
        seen, queue, found = {start}, [start], []
        while queue:
            key = queue.pop(0)
            if key in owners:
                found.append(owners[key])
                continue
            if key not in computed:
                continue
            node, inputs = computed[key]
            if node in graph.elements and graph.elements[node].kind_info.role == SOURCE and node not in found:
                found.append(node)
            for item in inputs:
                if item not in seen:
                    seen.add(item)
                    queue.append(item)
        result[name] = tuple(sorted(dict.fromkeys(found), key=positions.__getitem__))
    return result


def _derivative_diagnostic(graph: BondGraph, name: str, depends_on: tuple[str, ...]) -> Diagnostic:
    element = graph.elements[name]
    variable = WORDS[element.kind_info.law_variable or "e"]
    if depends_on:
        by = f"is fixed by {join_words([describe_node(graph, n) for n in depends_on])}"
    else:
        by = "is fixed by the rest of the graph"
    message = (f"{describe_node(graph, name)} is in derivative causality: its {variable} {by}, "
               f"so its state is not independent and is eliminated from the state equations")
    related = tuple(Related(element_span(graph.elements[n]), f"{describe_node(graph, n)} fixes it")
                    for n in depends_on)
    return Diagnostic("warning", codes.W602, message, element_span(element), related=related,
                      hint="intended for rigidly coupled parts; otherwise put a compliance (C) or "
                           "inertia (I) between the storage elements")


# ------------------------------------------------------------------- stage

def assign_causality(graph: BondGraph) -> CausalGraph:
    """Assign a causality to every bond of ``graph`` (SCAP), or raise CausalityError.

    >>> from bondc.parse import parse_text
    >>> from bondc.semantic import build
    >>> text = "model M\\n Se force : e = 10\\n I mass : f = p/2\\n R damper : e = 3*f\\n 1 j\\n" \\
    ...        " force -> j\\n j -> mass\\n j -> damper\\nend\\n"
    >>> causal = assign_causality(build(parse_text(text, "m.bg"))[0])
    >>> dict(causal.storage), dict(causal.resistors), causal.effort_from(2)
    ({'mass': 'integral'}, {'damper': 'resistance'}, 'j')
    """
    procedure = _Procedure(graph)
    state = procedure.run()
    if procedure.errors:
        raise CausalityError(sorted(procedure.errors, key=sort_key))
    setter = {bond.number: state.setter[bond.number] for bond in graph.bonds}
    storage: dict[str, str] = {}
    resistors: dict[str, str] = {}
    for element in graph.elements.values():
        role = element.kind_info.role
        if role not in (STORAGE, RESISTOR):
            continue
        sets = setter[element.bond] == element.name
        names = dict((s, c) for c, s in ONE_PORT_CAUSALITIES[element.kind])
        if role == STORAGE:
            storage[element.name] = names[sets]
        else:
            resistors[element.name] = names[sets]
    relations = causal_relations(graph, setter, storage)
    loops = _find_loops(graph, relations)
    dependencies = _dependencies(graph, relations, storage)
    diagnostics = [_derivative_diagnostic(graph, name, deps) for name, deps in dependencies.items()]
    element_names = readable_names(graph) if loops else {}     # b2.e -> r1.e
    diagnostics += [_loop_diagnostic(graph, loop, element_names) for loop in loops]
    return CausalGraph(graph=graph, effort_setter=setter, storage=storage, resistors=resistors,
                       dependencies=dependencies, algebraic_loops=loops,
                       diagnostics=tuple(sorted(diagnostics, key=sort_key)))


#: At most this many resistors of unknown law are tried both ways by :func:`structural_conflicts`.
MAX_UNKNOWN_RESISTORS = 4


def structural_conflicts(graph: BondGraph, unknown: Iterable[str] = ()) -> list[Diagnostic]:
    """The causal conflicts (``E601``) of ``graph``'s structure, for a model whose laws have errors.

    Only what is certain whatever the laws will say: ``unknown`` are the elements whose laws have
    an error, so a resistor among them may be written either way (``e = ...`` or ``f = ...``) and
    prefer either causality. The procedure runs for each preference of those resistors and keeps the
    conflicts met in every run; beyond :data:`MAX_UNKNOWN_RESISTORS` of them, only the conflicts met
    before any resistor is decided (those of the sources and storage elements). Nothing here reads
    an expression: the derivative causality (``W602``) and algebraic loops (``I603``) depend on what
    the laws read and are left to :func:`assign_causality` once the laws are right.

    >>> from bondc.parse import parse_text
    >>> from bondc.semantic import build
    >>> text = "model M\\n Sf a : f = 1\\n Sf b : f = 2\\n R r : e = f\\n 1 j\\n" \\
    ...        " a -> j\\n b -> j\\n j -> r\\nend\\n"
    >>> [(d.code, d.span.line) for d in structural_conflicts(build(parse_text(text, "m.bg"))[0], ["r"])]
    [('E601', 3)]
    """
    resistors = [name for name in dict.fromkeys(unknown)
                 if name in graph.elements and graph.elements[name].kind_info.role == RESISTOR]
    if len(resistors) > MAX_UNKNOWN_RESISTORS:
        procedure = _Procedure(graph)
        procedure.run()
        return sorted(procedure.errors[:procedure.fixed_errors], key=sort_key)
    common: list[Diagnostic] | None = None
    for choice in range(2 ** len(resistors)):
        conductance = {name: bool(choice >> i & 1) for i, name in enumerate(resistors)}
        procedure = _Procedure(graph, conductance)
        procedure.run()
        common = procedure.errors if common is None else [d for d in common if d in procedure.errors]
    return sorted(dict.fromkeys(common or ()), key=sort_key)


# ------------------------------------------------------------------ display

def format_table(causal: CausalGraph) -> str:
    """The causality table printed by ``bondc check --causality``."""
    graph = causal.graph
    rows = [("bond", "name", "from -> to", "effort set by", "stroke at")]
    for bond in graph.bonds:
        tail = bond.tail + (f".{bond.tail_port}" if bond.tail_port else "")
        head = bond.head + (f".{bond.head_port}" if bond.head_port else "")
        setter = causal.effort_from(bond.number)
        rows.append((str(bond.number), bond.name, f"{tail} -> {head}", setter, causal.stroke_end(bond.number)))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.rjust(widths[i]) if i == 0 else cell.ljust(widths[i]) for i, cell in enumerate(row)).rstrip()
             for row in rows]
    if causal.storage:
        lines += ["", "storage elements"]
        width = max(len(n) for n in causal.storage)
        for name, causality in causal.storage.items():
            element = graph.elements[name]
            extra = ""
            if causality == DERIVATIVE:
                deps = causal.dependencies.get(name, ())
                extra = f"  (fixed by {', '.join(deps)})" if deps else ""
            lines.append(f"  {name.ljust(width)}  {element.kind}  {causality}{extra}")
    if causal.resistors:
        lines += ["", "resistors"]
        width = max(len(n) for n in causal.resistors)
        for name, causality in causal.resistors.items():
            law = "e = law(f)" if causality == RESISTANCE else "f = law(e)"
            lines.append(f"  {name.ljust(width)}  R  {causality} ({law})")
    lines += ["", "algebraic loops: " + ("none" if not causal.algebraic_loops else "")]
    for loop in causal.algebraic_loops:
        lines.append(f"  {', '.join(loop.nodes)}: {', '.join(loop.variables)}")
    return "\n".join(lines)
