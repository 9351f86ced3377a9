"""Bonds and ports: takes the declared model; numbers and orients its bonds (``m.bonds``,
``m.ends``), checks each bond's endpoints, each junction's bonds and each element's ports
(one-port or two-port, from :data:`bondc.kinds.KINDS`). Returns nothing: diagnostics and the
numbered bonds go to the model.
"""

from __future__ import annotations

from typing import Sequence

from bondc import ast
from bondc.errors import Related
from bondc.kinds import KINDS
from bondc.model import Bond, PORT_NAMES
from bondc.source import Span
from bondc.semantic.context import a_or_an, BondEnd, CheckContext, did_you_mean, error_at
from bondc import codes


def number_bonds(m: CheckContext) -> None:
    """Bonds 1, 2, 3, ... in order of appearance, chains left to right."""
    for chain in m.statements(ast.BondChain):
        single = len(chain.endpoints) == 2
        for tail, head in zip(chain.endpoints, chain.endpoints[1:]):
            number = len(m.bonds) + 1
            label = chain.label if single else None
            start = chain.label_span if label is not None else tail.span
            m.bonds.append(Bond(number, tail.name, head.name, label=label, span=start.to(head.span)))
            m.ends.setdefault(tail.name, []).append(BondEnd(number, "tail", tail.port, tail.span))
            m.ends.setdefault(head.name, []).append(BondEnd(number, "head", head.port, head.span))


def check_bonds(m: CheckContext) -> None:
    """E404 endpoint not an element or junction, E405 bond to itself, E406 label on a chain."""
    nodes = {d.name for d in m.all_decls if d.category in ("element", "junction")}
    for chain in m.statements(ast.BondChain):
        for endpoint in chain.endpoints:
            decl = m.decls.get(endpoint.name)
            if endpoint.name in nodes:
                continue
            if decl is None:
                hint = did_you_mean(endpoint.name, nodes)
                if hint is not None:
                    m.misspelt.add(hint.split("'")[1])
                m.report(error_at(codes.E404, f"unknown element or junction '{endpoint.name}'", _name_part(endpoint),
                                  hint=hint))
            elif decl.category not in ("element", "junction"):
                m.report(error_at(codes.E404, f"'{endpoint.name}' is {a_or_an(decl.category)}, not an element or junction",
                                  _name_part(endpoint), hint="bonds connect elements and junctions",
                                  related=[Related(decl.span, f"'{endpoint.name}' is defined here")]))
        if chain.label is not None and len(chain.endpoints) > 2:
            m.report(error_at(codes.E406, f"the label '{chain.label}' is on a chain of {len(chain.endpoints) - 1} bonds",
                              chain.label_span,
                              hint=f"a label names one bond: write '{chain.label}: {chain.endpoints[0].name} -> "
                                   f"{chain.endpoints[1].name}' on its own line"))
    for bond in m.bonds:
        if bond.tail == bond.head:
            m.report(error_at(codes.E405, f"bond {bond.number} connects '{bond.tail}' to itself", bond.span,
                              hint="a bond joins two different elements or junctions"))


def _name_part(endpoint: ast.Endpoint) -> Span:
    """The span of an endpoint's node name, without ``.port``."""
    span = endpoint.span
    if endpoint.port is None:
        return span
    width = span.end - span.start - len(endpoint.port) - 1   # the name as written (a component's is not dotted)
    if width <= 0 or span.end_line != span.line:
        return span
    return Span(span.file, span.line, span.column, span.line, span.column + width,
                span.start, span.start + width, span.instance)


def _bond_notes(m: CheckContext, ends: Sequence[BondEnd]) -> list[Related]:
    return [Related(m.bonds[end.bond - 1].span, f"bond {end.bond}") for end in ends]


def check_ports(m: CheckContext) -> None:
    """E401 one-port bonds, E402 two-port ports, E403 junction with fewer than two bonds."""
    for element in m.elements:
        kind = m.known_kind(element.name)
        if kind is None:
            continue
        ends = m.ends.get(element.name, [])
        if KINDS[kind].ports == 1:
            _check_one_port(m, element, ends)
        else:
            _check_two_port(m, element, ends)
    for junction in m.statements(ast.Junction):
        for name, span in zip(junction.names, junction.name_spans or (junction.span,) * len(junction.names)):
            ends = m.ends.get(name, [])
            for end in ends:
                if end.port is not None:
                    m.report(error_at(codes.E402, f"junction '{name}' has no port '{end.port}'", end.span,
                                      hint=f"ports belong to two-ports (TF, GY); write just '{name}'"))
            if len(ends) < 2 and not (not ends and name in m.misspelt):
                count = "no bond" if not ends else "only one bond"
                m.report(error_at(codes.E403, f"junction '{name}' has {count}", span,
                                  hint="a junction joins two or more bonds; connect it or remove it",
                                  related=_bond_notes(m, ends)))


def _check_one_port(m: CheckContext, element: ast.Element, ends: list[BondEnd]) -> None:
    for end in ends:
        if end.port is not None:
            m.report(error_at(codes.E402, f"'{element.name}' is a one-port {element.kind} and has no port '{end.port}'",
                              end.span, hint=f"write just '{element.name}'"))
    if len(ends) == 1:
        return
    if not ends:
        if element.name in m.misspelt:
            return  # its bond names it misspelt (E404)
        m.report(error_at(codes.E401, f"{element.kind} '{element.name}' has no bond", element.name_span,
                          hint=f"connect it to a junction, e.g. 'j -> {element.name}'"))
        return
    m.report(error_at(codes.E401, f"{element.kind} '{element.name}' has {len(ends)} bonds; a one-port element has "
                              f"exactly one", element.name_span,
                      hint="join the bonds at a 0- or 1-junction and connect the element to it",
                      related=_bond_notes(m, ends)))


def _check_two_port(m: CheckContext, element: ast.Element, ends: list[BondEnd]) -> None:
    name = element.name
    if len(ends) != 2:
        count = "no bond" if not ends else f"{len(ends)} bond" + ("s" if len(ends) > 1 else "")
        m.report(error_at(codes.E402, f"{element.kind} '{name}' has {count}; a two-port has exactly two", element.name_span,
                          hint=f"connect one bond to each port: 'a -> {name}.p1' and '{name}.p2 -> b'",
                          related=_bond_notes(m, ends)))
        return
    problems = False
    for end in ends:
        if end.port is not None and end.port not in PORT_NAMES:
            m.report(error_at(codes.E402, f"{element.kind} '{name}' has no port '{end.port}'", end.span,
                              hint=f"the ports of a two-port are p1 and p2{_port_suggestion(end.port)}"))
            problems = True
    if problems:
        return
    first, second = ends
    if first.port is not None and first.port == second.port:
        m.report(error_at(codes.E402, f"port {first.port} of '{name}' is used by two bonds ({first.bond} and "
                                  f"{second.bond})",
                          second.span, hint="each port of a two-port takes one bond: use p1 and p2",
                          related=[Related(first.span, f"bond {first.bond} uses {first.port} here")]))
        return
    if first.port is None and second.port is None:
        if first.side == second.side:
            direction = "into" if first.side == "head" else "out of"
            m.report(error_at(codes.E402, f"both bonds of {element.kind} '{name}' point {direction} it, so its ports "
                                      f"must be named", element.name_span,
                              hint=f"write {name}.p1 at one bond and {name}.p2 at the other",
                              related=_bond_notes(m, ends)))
            return
        p1, p2 = (first, second) if first.side == "head" else (second, first)
    elif first.port is not None:
        p1, p2 = (first, second) if first.port == "p1" else (second, first)
    else:
        p1, p2 = (second, first) if second.port == "p1" else (first, second)
    signs = (1 if p1.side == "head" else -1, 1 if p2.side == "tail" else -1)
    m.ports[name] = ((p1.bond, p2.bond), signs)


def _port_suggestion(port: str) -> str:
    hint = did_you_mean(port, PORT_NAMES)
    return f" ({hint})" if hint else ""
