"""Bond-graph diagram for reports: BondGraph (+ causality) -> SVG text.

:func:`bond_graph_svg` draws a :class:`~bondc.model.BondGraph` the way a
textbook does: elements as ``KIND:name``, junctions as ``0``/``1`` with their
name small beside the symbol, each bond a line with a power half-arrow at its
head and its number (and label) beside it, and, when a causal assignment is
given, a causal stroke on every bond.

Causal stroke convention (Karnopp, Margolis & Rosenberg, *System Dynamics*,
ch. 5; the same as :meth:`bondc.causality.CausalGraph.stroke_end`): the stroke
is drawn across the end of the bond *toward which the effort is directed*,
i.e. at the node that RECEIVES the effort; the node at the other end sets the
effort and receives the flow. So an effort source's stroke is at the far end
(``Se ——|``), a flow source's at its own end (``Sf |——``), an I in integral
causality has the stroke at its own end, a C in integral causality at the far
end. Stroke and half-arrow are independent: the half-arrow shows the positive
power direction, the stroke the causality.

Layout (deterministic, no external program or library):

- *backbone* nodes are junctions, two-ports and anything not a one-port with a
  single bond; every other one-port element is a *leaf* hung on its neighbour;
- backbone columns are breadth-first layers over the bonds (ignoring power
  direction, which may point either way along a chain) from a root: the
  backbone node next to the first source, else the first node;
- within a column, nodes are ordered by the barycentre of their neighbours in
  the previous column and placed on the row nearest to it, so chains run
  straight and branches step aside;
- a node's leaves go before it along the flow (a source, when nothing else is
  there), after it (when nothing else is), then on its sides, preferring the
  side no backbone bond arrives from; columns and rows are sized from the
  estimated text widths, so labels never overlap;
- the flow runs left to right, or downwards when a long chain would otherwise
  not fit a report column (``orientation="auto"``);
- bond numbers sit on the right of the power direction (away from the
  half-arrow's barb), on the outer side for parallel bonds and fans of leaves.

>>> from bondc.parse import parse_text
>>> from bondc.semantic import build
>>> text = "model M\\n Se force : e = 1\\n I mass : f = p\\n 1 j\\n force -> j -> mass\\nend\\n"
>>> graph, _ = build(parse_text(text, "m.bg"))
>>> svg = bond_graph_svg(graph, causal={1: "force", 2: "j"})
>>> svg.startswith("<svg"), svg.count('class="half-arrow"'), svg.count('class="causal-stroke"')
(True, 2, 2)
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Mapping

from markupsafe import Markup

from bondc.model import KINDS, BondGraph

__all__ = ["bond_graph_svg", "collapsed_graph", "collapsed_setters", "effort_setters"]

SVG_NS = "http://www.w3.org/2000/svg"

# Geometry, in px (user units). Text widths are estimated, not measured: the
# factors over-estimate a sans-serif face so labels never touch.
FONT_FAMILY = "Helvetica, Arial, 'Liberation Sans', sans-serif"
LABEL_SIZE = 13.0            # element labels
JUNCTION_SIZE = 17.0         # the 0 / 1 symbol
NAME_SIZE = 9.5              # a junction's name
BOND_LABEL_SIZE = 10.5       # bond numbers
CHAR_WIDTH = 0.62            # em per character, generous for sans-serif
NODE_HEIGHT = 22.0
NODE_PAD = 5.0               # around a label's text
MARGIN = 24.0
COLUMN_GAP = 52.0            # between the boxes of neighbouring columns
ROW_GAP = 34.0
LEAF_DY = 62.0               # vertical distance from a node to its leaves above / below
LEAF_GAP_X = 18.0            # between leaves sharing a row
SIDE_GAP = 50.0              # between a node and a leaf beside it
STACK_DY = 46.0              # between leaves stacked on one side (vertical layout)
SIDE_GAP_V = 62.0            # between a node and a leaf beside it (vertical layout)
LAYER_GAP = 46.0             # between the boxes of neighbouring layers (vertical layout)
FIT_WIDTH = 880.0            # "auto" orientation: the width a drawing should fit (a report column)
FIT_HEIGHT = 1000.0          # ... and the height
BOND_CLEARANCE = 3.0         # between a node's box and the end of a bond line
HALF_ARROW_LENGTH = 10.0
HALF_ARROW_WIDTH = 6.0
STROKE_HALF = 7.0            # half the length of a causal stroke
PARALLEL_OFFSET = 10.0       # between parallel bonds joining the same two nodes
INK = "#1f2328"
BOND_LABEL_INK = "#0550ae"

SOURCE_KINDS = frozenset(k for k, info in KINDS.items() if info.source)


# Where a leaf hangs, in the frame of the layout's flow (columns follow the flow):
# "before"/"after" the node along the flow, or on its first/second side.
SLOTS = ("before", "after", "side1", "side2")
ORIENTATIONS = ("horizontal", "vertical")


@dataclass
class _Node:
    name: str
    kind: str
    is_junction: bool
    description: str | None
    left: float = 0.0                # box extent left of x (a junction's x is its symbol's centre)
    right: float = 0.0               # box extent right of x (a junction's name is on the right)
    height: float = NODE_HEIGHT
    x: float = 0.0
    y: float = 0.0
    column: int = 0                  # layer along the flow
    row: int = 0                     # lane across the flow
    leaves: dict[str, list[str]] = field(default_factory=lambda: {slot: [] for slot in SLOTS})

    @property
    def width(self) -> float:
        return self.left + self.right

    @property
    def label(self) -> str:
        return self.kind if self.is_junction else f"{self.kind}:{self.name}"


def _text_width(text: str, size: float) -> float:
    return len(text) * size * CHAR_WIDTH


def _make_nodes(graph: BondGraph) -> dict[str, _Node]:
    """Every node, in the order it first appears in a bond (then unbonded ones)."""
    order: list[str] = []
    for bond in graph.bonds:
        for name in (bond.tail, bond.head):
            if name not in order:
                order.append(name)
    for name in list(graph.elements) + list(graph.junctions):
        if name not in order:
            order.append(name)
    nodes: dict[str, _Node] = {}
    for name in order:
        if name in graph.junctions:
            node = _Node(name, graph.junctions[name].kind, True, None)
            symbol = _text_width(node.kind, JUNCTION_SIZE)
            node.left = symbol / 2 + NODE_PAD
            node.right = symbol / 2 + 3 + _text_width(name, NAME_SIZE) + NODE_PAD
        elif name in graph.elements:
            element = graph.elements[name]
            node = _Node(name, element.kind, False, element.description)
            node.left = node.right = _text_width(node.label, LABEL_SIZE) / 2 + NODE_PAD
        else:
            raise ValueError(f"bond endpoint {name!r} is neither an element nor a junction")
        nodes[name] = node
    return nodes


def _neighbours(graph: BondGraph, nodes: Mapping[str, _Node]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {name: [] for name in nodes}
    for bond in graph.bonds:
        if bond.tail != bond.head:
            out[bond.tail].append(bond.head)
            out[bond.head].append(bond.tail)
    return out


def _is_one_port(graph: BondGraph, name: str) -> bool:
    if name not in graph.elements:
        return False
    kind = KINDS.get(graph.elements[name].kind)
    return (kind.ports if kind is not None else len(graph.elements[name].bonds)) == 1   # a component box


def collapsed_setters(causal: Any, graph: BondGraph, collapsed: BondGraph) -> dict[int, str]:
    """The effort setters of :func:`collapsed_graph`'s bonds: a setter inside an instance is its box."""
    setters = effort_setters(causal, graph)
    kept = {bond.number: bond for bond in collapsed.bonds}
    out = {}
    for number, setter in setters.items():
        bond = kept.get(number)
        if bond is None:
            continue
        original = graph.bond(number)
        out[number] = bond.tail if setter == original.tail else bond.head
    return out


def collapsed_graph(graph: BondGraph) -> BondGraph | None:
    """``graph`` with each top-level submodel instance drawn as one box (``Orifice:valve``), bonded
    by the bonds that cross its boundary; None when the model has no instances. The bonds inside
    an instance are left out; the expanded drawing is the flat graph itself."""
    import dataclasses

    from bondc.model import ElementNode

    top = {i.path: i for i in getattr(graph, "instances", ()) if "." not in i.path}
    if not top:
        return None

    def owner(name: str) -> str:
        head = name.split(".", 1)[0]
        return head if "." in name and head in top else name

    bonds = []
    for bond in graph.bonds:
        tail, head = owner(bond.tail), owner(bond.head)
        if tail == head and tail in top:
            continue
        bonds.append(dataclasses.replace(bond, tail=tail, head=head,
                                         tail_port=None if tail in top else bond.tail_port,
                                         head_port=None if head in top else bond.head_port))
    elements = {name: e for name, e in graph.elements.items() if owner(name) == name}
    for path, instance in top.items():
        numbers = tuple(b.number for b in bonds if path in (b.tail, b.head))
        elements[path] = ElementNode(instance.model, path, instance.description, {}, {}, (), numbers,
                                     (1,) * len(numbers))
    junctions = {name: j for name, j in graph.junctions.items() if owner(name) == name}
    return dataclasses.replace(graph, elements=elements, junctions=junctions, bonds=tuple(bonds))


def _layout(graph: BondGraph, orientation: str) -> tuple[dict[str, _Node], float, float]:
    """Place every node; returns the nodes and the drawing's width and height."""
    nodes = _make_nodes(graph)
    neighbours = _neighbours(graph, nodes)
    order = list(nodes)

    def hangs(name: str) -> bool:
        """A one-port with one bond to a node that is not itself such a one-port."""
        if not _is_one_port(graph, name) or len(neighbours[name]) != 1:
            return False
        other = neighbours[name][0]
        return not (_is_one_port(graph, other) and len(neighbours[other]) == 1)

    backbone = [name for name in order if not hangs(name)]
    backbone_set = set(backbone)
    parent = {name: neighbours[name][0] for name in order if name not in backbone_set}
    spine = {name: [n for n in neighbours[name] if n in backbone_set] for name in backbone}

    # Connected components of the backbone, each with its root and BFS columns.
    components: list[list[str]] = []
    seen: set[str] = set()
    for start in backbone:
        if start in seen:
            continue
        members = []
        queue = deque([start])
        seen.add(start)
        while queue:
            name = queue.popleft()
            members.append(name)
            for other in spine[name]:
                if other not in seen:
                    seen.add(other)
                    queue.append(other)
        members.sort(key=order.index)
        components.append(members)

    place = _place_horizontal if orientation == "horizontal" else _place_vertical
    width = height = 0.0
    for members in components:
        root = _root(graph, members, neighbours, parent)
        discovery = _columns(root, spine, nodes)
        _rows(members, spine, nodes, discovery)
        _assign_leaves(members, spine, nodes, parent, graph, order)
        # Components are stacked across the flow: below each other when it runs
        # left to right, side by side when it runs downwards.
        if orientation == "horizontal":
            w, h = place(members, nodes, MARGIN, MARGIN + height + (ROW_GAP if height else 0.0))
            width, height = max(width, w), height + (ROW_GAP if height else 0.0) + h
        else:
            w, h = place(members, nodes, MARGIN + width + (COLUMN_GAP if width else 0.0), MARGIN)
            width, height = width + (COLUMN_GAP if width else 0.0) + w, max(height, h)
    return nodes, max(width, MARGIN) + 2 * MARGIN, max(height, MARGIN) + 2 * MARGIN


def _root(graph: BondGraph, members: list[str], neighbours, parent) -> str:
    """The backbone node next to the first source leaf, else the first source, else the first node."""
    for name in members:
        for other in neighbours[name]:
            if parent.get(other) == name and graph.elements[other].kind in SOURCE_KINDS:
                return name
    for name in members:
        if name in graph.elements and graph.elements[name].kind in SOURCE_KINDS:
            return name
    return members[0]


def _columns(root: str, spine, nodes) -> dict[str, int]:
    """Breadth-first columns from the root; returns each node's discovery index."""
    discovery = {root: 0}
    nodes[root].column = 0
    queue = deque([root])
    while queue:
        name = queue.popleft()
        for other in spine[name]:
            if other not in discovery:
                discovery[other] = len(discovery)
                nodes[other].column = nodes[name].column + 1
                queue.append(other)
    return discovery


def _rows(members, spine, nodes, discovery) -> None:
    """Rows per column: barycentre of the previous column's neighbours, pushed on by collisions."""
    columns: dict[int, list[str]] = {}
    for name in members:
        columns.setdefault(nodes[name].column, []).append(name)
    for column in sorted(columns):
        def barycentre(name: str) -> float:
            rows = [nodes[o].row for o in spine[name] if nodes[o].column == column - 1]
            return sum(rows) / len(rows) if rows else 0.0

        ranked = sorted(columns[column], key=lambda n: (barycentre(n), discovery[n]))
        last = -1
        for name in ranked:
            nodes[name].row = max(math.floor(barycentre(name) + 0.5), last + 1)
            last = nodes[name].row


def _assign_leaves(members, spine, nodes, parent, graph, order) -> None:
    """A source goes before a node with nothing before it, one leaf after a node with
    nothing after it, the rest alternately on its two sides."""
    for name in members:
        node = nodes[name]
        leaves = [leaf for leaf in order if parent.get(leaf) == name]
        before_free = all(nodes[o].column >= node.column for o in spine[name])
        after_free = all(nodes[o].column <= node.column for o in spine[name])
        sources = [leaf for leaf in leaves if graph.elements[leaf].kind in SOURCE_KINDS]
        if before_free and sources:
            node.leaves["before"].append(sources[0])
            leaves.remove(sources[0])
        if after_free and leaves:
            node.leaves["after"].append(leaves.pop(0))
        if before_free and not node.leaves["before"] and len(leaves) >= 3:
            node.leaves["before"].append(leaves.pop(0))
        # Keep side leaves clear of backbone bonds that arrive from a side (from
        # another row): up to three go on the free side, more alternate from it.
        from_side1 = any(nodes[o].row < node.row for o in spine[name])
        from_side2 = any(nodes[o].row > node.row for o in spine[name])
        sides = ("side1", "side2")
        if from_side1 and not from_side2:
            sides = ("side2", "side1")
        if from_side1 != from_side2 and len(leaves) <= 3:
            sides = (sides[0], sides[0])
        for i, leaf in enumerate(leaves):
            node.leaves[sides[i % 2]].append(leaf)


def _spread(names: list[str], nodes) -> float:
    """The width of leaves side by side in one row."""
    if not names:
        return 0.0
    return sum(nodes[n].width for n in names) + LEAF_GAP_X * (len(names) - 1)


def _widest(names: list[str], nodes) -> float:
    return max((nodes[n].width for n in names), default=0.0)


def _place_horizontal(members, nodes, x0: float, y0: float) -> tuple[float, float]:
    """Flow left to right: columns are x, rows y; side leaves above and below in a row."""
    columns = sorted({nodes[n].column for n in members})
    rows = sorted({nodes[n].row for n in members})
    by_column = {c: [n for n in members if nodes[n].column == c] for c in columns}
    by_row = {r: [n for n in members if nodes[n].row == r] for r in rows}

    x_center: dict[int, float] = {}
    cursor = x0
    for c in columns:
        reach_left = reach_right = 0.0
        for n in by_column[c]:
            node = nodes[n]
            rows_half = max(_spread(node.leaves["side1"], nodes), _spread(node.leaves["side2"], nodes)) / 2
            before = node.left + SIDE_GAP + _widest(node.leaves["before"], nodes) if node.leaves["before"] else 0.0
            after = node.right + SIDE_GAP + _widest(node.leaves["after"], nodes) if node.leaves["after"] else 0.0
            reach_left = max(reach_left, node.left, rows_half, before)
            reach_right = max(reach_right, node.right, rows_half, after)
        x_center[c] = cursor + reach_left
        cursor += reach_left + reach_right + COLUMN_GAP
    width = cursor - COLUMN_GAP - x0

    y_center: dict[int, float] = {}
    cursor = y0
    for r in rows:
        above = LEAF_DY if any(nodes[n].leaves["side1"] for n in by_row[r]) else 0.0
        below = LEAF_DY if any(nodes[n].leaves["side2"] for n in by_row[r]) else 0.0
        y_center[r] = cursor + above + NODE_HEIGHT / 2
        cursor += above + NODE_HEIGHT + below + ROW_GAP
    height = cursor - ROW_GAP - y0

    for name in members:
        node = nodes[name]
        node.x, node.y = x_center[node.column], y_center[node.row]
        for leaf in node.leaves["before"]:
            nodes[leaf].x, nodes[leaf].y = node.x - node.left - SIDE_GAP - nodes[leaf].right, node.y
        for leaf in node.leaves["after"]:
            nodes[leaf].x, nodes[leaf].y = node.x + node.right + SIDE_GAP + nodes[leaf].left, node.y
        for slot, dy in (("side1", -LEAF_DY), ("side2", LEAF_DY)):
            x = node.x - _spread(node.leaves[slot], nodes) / 2
            for leaf in node.leaves[slot]:
                nodes[leaf].x, nodes[leaf].y = x + nodes[leaf].left, node.y + dy
                x += nodes[leaf].width + LEAF_GAP_X
    return width, height


def _place_vertical(members, nodes, x0: float, y0: float) -> tuple[float, float]:
    """Flow downwards: columns are y, rows x; side leaves left and right, stacked."""
    columns = sorted({nodes[n].column for n in members})
    rows = sorted({nodes[n].row for n in members})
    by_column = {c: [n for n in members if nodes[n].column == c] for c in columns}
    by_row = {r: [n for n in members if nodes[n].row == r] for r in rows}

    def stack_half(names: list[str]) -> float:
        return (len(names) - 1) * STACK_DY / 2 if names else 0.0

    x_center: dict[int, float] = {}
    cursor = x0
    for r in rows:
        reach_left = reach_right = 0.0
        for n in by_row[r]:
            node = nodes[n]
            ends_half = max(_widest(node.leaves["before"], nodes), _widest(node.leaves["after"], nodes)) / 2
            left = node.left + SIDE_GAP_V + _widest(node.leaves["side1"], nodes) if node.leaves["side1"] else 0.0
            right = node.right + SIDE_GAP_V + _widest(node.leaves["side2"], nodes) if node.leaves["side2"] else 0.0
            reach_left = max(reach_left, node.left, ends_half, left)
            reach_right = max(reach_right, node.right, ends_half, right)
        x_center[r] = cursor + reach_left
        cursor += reach_left + reach_right + COLUMN_GAP
    width = cursor - COLUMN_GAP - x0

    y_center: dict[int, float] = {}
    cursor = y0
    for c in columns:
        top = bottom = NODE_HEIGHT / 2
        for n in by_column[c]:
            node = nodes[n]
            stacks = max(stack_half(node.leaves["side1"]), stack_half(node.leaves["side2"])) + NODE_HEIGHT / 2
            top = max(top, stacks, LEAF_DY + NODE_HEIGHT / 2 if node.leaves["before"] else 0.0)
            bottom = max(bottom, stacks, LEAF_DY + NODE_HEIGHT / 2 if node.leaves["after"] else 0.0)
        y_center[c] = cursor + top
        cursor += top + bottom + LAYER_GAP
    height = cursor - LAYER_GAP - y0

    for name in members:
        node = nodes[name]
        node.x, node.y = x_center[node.row], y_center[node.column]
        for leaf in node.leaves["before"]:
            nodes[leaf].x, nodes[leaf].y = node.x, node.y - LEAF_DY
        for leaf in node.leaves["after"]:
            nodes[leaf].x, nodes[leaf].y = node.x, node.y + LEAF_DY
        for slot, sign in (("side1", -1), ("side2", 1)):
            names = node.leaves[slot]
            for i, leaf in enumerate(names):
                reach = (node.left + SIDE_GAP_V + nodes[leaf].right if sign < 0
                         else node.right + SIDE_GAP_V + nodes[leaf].left)
                nodes[leaf].x = node.x + sign * reach
                nodes[leaf].y = node.y - stack_half(names) + i * STACK_DY
    return width, height


# ---------------------------------------------------------------- causality

def effort_setters(causal: Any, graph: BondGraph) -> dict[int, str]:
    """``{bond number: name of the node that sets the bond's effort}`` from a causal assignment.

    ``causal`` is ``None`` (no causality), a :class:`bondc.causality.CausalGraph`
    (its ``effort_setter`` mapping), or such a mapping itself. A bond missing
    from it is drawn without a stroke.
    """
    if causal is None:
        return {}
    mapping = causal if isinstance(causal, Mapping) else getattr(causal, "effort_setter", None)
    if not isinstance(mapping, Mapping):
        raise TypeError(f"cannot read a causal assignment from {type(causal).__name__}: expected a "
                        "CausalGraph or a mapping {bond number: node that sets the effort}")
    out: dict[int, str] = {}
    bonds = {bond.number: bond for bond in graph.bonds}
    for number, setter in mapping.items():
        number = int(number)
        if number not in bonds:
            raise ValueError(f"causal assignment names bond {number}, which the graph does not have")
        bond = bonds[number]
        if setter not in (bond.tail, bond.head):
            raise ValueError(f"bond {number} joins {bond.tail!r} and {bond.head!r}; "
                             f"{setter!r} cannot set its effort")
        out[number] = setter
    return out


# ---------------------------------------------------------------- drawing

def _fan_offset(nodes: Mapping[str, _Node], tail: str, head: str) -> tuple[float, float] | None:
    """For a bond to a leaf sharing its slot with others: the leaf's offset from the slot's centre."""
    for parent, leaf in ((tail, head), (head, tail)):
        for slot in SLOTS:
            names = nodes[parent].leaves[slot]
            if leaf in names and len(names) > 1:
                cx = sum(nodes[n].x for n in names) / len(names)
                cy = sum(nodes[n].y for n in names) / len(names)
                return nodes[leaf].x - cx, nodes[leaf].y - cy
    return None


def _fmt(value: float) -> str:
    text = f"{value:.1f}"
    return "0.0" if text == "-0.0" else text


def _clip(node: _Node, dx: float, dy: float, ox: float, oy: float) -> tuple[float, float]:
    """Where the ray from the node's centre (shifted by ox, oy) along (dx, dy) leaves its box."""
    half_w = (node.right if dx > 0 else node.left) + BOND_CLEARANCE
    half_h = node.height / 2 + BOND_CLEARANCE
    candidates = []
    if abs(dx) > 1e-9:
        candidates.append(half_w / abs(dx))
    if abs(dy) > 1e-9:
        candidates.append(half_h / abs(dy))
    t = min(candidates) if candidates else 0.0
    return node.x + ox + t * dx, node.y + oy + t * dy


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attributes: str) -> ET.Element:
    element = ET.SubElement(parent, tag, {k.rstrip("_").replace("_", "-"): v for k, v in attributes.items()})
    if text is not None:
        element.text = text
    return element


def _draw_node(parent: ET.Element, node: _Node, graph: BondGraph, id_prefix: str = "") -> None:
    group = _sub(parent, "g", class_="junction" if node.is_junction else "element",
                 id_=f"{id_prefix}node-{_css_id(node.name)}")
    if node.is_junction:
        _sub(group, "title", f"{node.kind}-junction {node.name}")
        symbol_width = _text_width(node.kind, JUNCTION_SIZE)
        _sub(group, "text", node.kind, x=_fmt(node.x), y=_fmt(node.y + JUNCTION_SIZE * 0.35),
             text_anchor="middle", font_size=_fmt(JUNCTION_SIZE), font_weight="bold")
        _sub(group, "text", node.name, x=_fmt(node.x + symbol_width / 2 + 3), y=_fmt(node.y + JUNCTION_SIZE * 0.35),
             font_size=_fmt(NAME_SIZE), fill="#57606a", class_="junction-name")
    else:
        info = KINDS.get(node.kind)
        if info is None:        # a submodel instance drawn as a box
            group.set("class", "component")
            title = f"component {node.name}, an instance of model {node.kind}"
            width = node.width - 2 * NODE_PAD + 8
            _sub(group, "rect", x=_fmt(node.x - width / 2), y=_fmt(node.y - LABEL_SIZE * 0.9),
                 width=_fmt(width), height=_fmt(LABEL_SIZE * 1.8), rx="3", fill="none", stroke=INK,
                 stroke_width="1")
        else:
            title = f"{node.kind} {node.name} ({info.description})"
        if node.description:
            title += f": {node.description}"
        _sub(group, "title", title)
        _sub(group, "text", node.label, x=_fmt(node.x), y=_fmt(node.y + LABEL_SIZE * 0.35),
             text_anchor="middle", font_size=_fmt(LABEL_SIZE))


def _css_id(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def bond_graph_svg(graph: BondGraph, causal: Any = None, orientation: str = "auto",
                   id_prefix: str = "") -> Markup:
    """An SVG drawing of ``graph``; with ``causal``, causal strokes on the bonds.

    ``causal`` is anything :func:`effort_setters` accepts, e.g.
    ``{1: "force", 2: "j"}`` (bond 1's effort is set by ``force``, so its
    stroke is at the other end). ``orientation`` is ``"horizontal"`` (power
    flows left to right, the textbook way), ``"vertical"`` (downwards), or
    ``"auto"``: horizontal unless the vertical drawing fits a report column
    (:data:`FIT_WIDTH` x :data:`FIT_HEIGHT`) at a larger scale, as long chains
    do. The result is a standalone ``<svg>`` element with
    ``width``/``height``/``viewBox``, every text XML-escaped, returned as
    ``Markup`` so a report template inserts it as it is. ``id_prefix`` starts every element id,
    so that two drawings in one page (a model and its expanded components) have distinct ids.
    """
    if orientation not in ORIENTATIONS + ("auto",):
        raise ValueError(f"orientation must be 'auto', 'horizontal' or 'vertical', not {orientation!r}")
    setters = effort_setters(causal, graph)
    if orientation == "auto":
        nodes, width, height = _layout(graph, "horizontal")
        if width > FIT_WIDTH or height > FIT_HEIGHT:
            def fit(w: float, h: float) -> float:
                return min(1.0, FIT_WIDTH / w, FIT_HEIGHT / h)

            candidate = _layout(graph, "vertical")
            if fit(*candidate[1:]) > 1.1 * fit(width, height):
                nodes, width, height = candidate
    else:
        nodes, width, height = _layout(graph, orientation)

    root = ET.Element("svg", {
        "xmlns": SVG_NS,
        "class": "bond-graph",
        "width": _fmt(width),
        "height": _fmt(height),
        "viewBox": f"0 0 {_fmt(width)} {_fmt(height)}",
        "role": "img",
        "aria-label": f"bond graph of {graph.name}",
    })
    _sub(root, "title", f"Bond graph of {graph.name}")
    bonds_group = _sub(root, "g", class_="bonds", stroke=INK, stroke_width="1.4", fill="none",
                       stroke_linecap="round")
    labels_group = _sub(root, "g", class_="bond-labels", fill=BOND_LABEL_INK, font_family=FONT_FAMILY,
                        font_size=_fmt(BOND_LABEL_SIZE))
    nodes_group = _sub(root, "g", class_="nodes", fill=INK, font_family=FONT_FAMILY)

    fans = {leaf for node in nodes.values() for slot in SLOTS if len(node.leaves[slot]) > 1
            for leaf in node.leaves[slot]}

    # Parallel bonds between the same two nodes are drawn side by side.
    pairs: dict[frozenset, list[int]] = {}
    for bond in graph.bonds:
        pairs.setdefault(frozenset((bond.tail, bond.head)), []).append(bond.number)

    for bond in graph.bonds:
        tail, head = nodes[bond.tail], nodes[bond.head]
        dx, dy = head.x - tail.x, head.y - tail.y
        length = math.hypot(dx, dy) or 1.0
        ux, uy = dx / length, dy / length
        left_x, left_y = uy, -ux            # left of the direction of power, on screen (y down)
        siblings = pairs[frozenset((bond.tail, bond.head))]
        # offset measured in a frame fixed by the node order, so siblings drawn opposite ways still separate
        sign = 1.0 if (bond.tail, bond.head) == tuple(sorted((bond.tail, bond.head))) else -1.0
        offset = (siblings.index(bond.number) - (len(siblings) - 1) / 2) * PARALLEL_OFFSET * sign
        ox, oy = left_x * offset, left_y * offset
        x1, y1 = _clip(tail, ux, uy, ox, oy)
        x2, y2 = _clip(head, -ux, -uy, ox, oy)

        group = _sub(bonds_group, "g", class_="bond", id_=f"{id_prefix}bond-{bond.number}")
        tail_text = f"{bond.tail}.{bond.tail_port}" if bond.tail_port else bond.tail
        head_text = f"{bond.head}.{bond.head_port}" if bond.head_port else bond.head
        caption = f"bond {bond.number}" + (f" ({bond.label})" if bond.label else "")
        title = f"{caption}: power from {tail_text} to {head_text}"
        if bond.number in setters:
            title += f"; effort set by {setters[bond.number]}"
        _sub(group, "title", title)
        _sub(group, "line", class_="bond-line", x1=_fmt(x1), y1=_fmt(y1), x2=_fmt(x2), y2=_fmt(y2))
        # The half-arrow: one barb on the left of the power direction (⇀ for a bond drawn left to right).
        bx = x2 - ux * HALF_ARROW_LENGTH + left_x * HALF_ARROW_WIDTH
        by = y2 - uy * HALF_ARROW_LENGTH + left_y * HALF_ARROW_WIDTH
        _sub(group, "path", class_="half-arrow", d=f"M{_fmt(x2)},{_fmt(y2)} L{_fmt(bx)},{_fmt(by)}")
        if bond.number in setters:
            # The stroke sits at the end that receives the effort: the end away from its setter.
            sx, sy = (x2, y2) if setters[bond.number] == bond.tail else (x1, y1)
            _sub(group, "line", class_="causal-stroke",
                 x1=_fmt(sx + left_x * STROKE_HALF), y1=_fmt(sy + left_y * STROKE_HALF),
                 x2=_fmt(sx - left_x * STROKE_HALF), y2=_fmt(sy - left_y * STROKE_HALF))

        # The number goes on the right of the bond, away from the barb; a parallel
        # bond's number goes on its outer side, so siblings' numbers do not collide.
        # Bonds fanning out to leaves that share a slot get their numbers on the
        # fan's outer side, nearer the leaves, where the fan is widest.
        text = str(bond.number) + (f" {bond.label}" if bond.label else "")
        nx, ny = -left_x, -left_y
        fraction = 0.5
        if offset:
            nx, ny = (left_x, left_y) if offset > 0 else (-left_x, -left_y)
        else:
            spread = _fan_offset(nodes, bond.tail, bond.head)
            if spread is not None:
                fraction = 0.62 if bond.head in fans else 0.38
                if spread[0] * left_x + spread[1] * left_y > 1e-6:
                    nx, ny = left_x, left_y
                elif spread[0] * left_x + spread[1] * left_y < -1e-6:
                    nx, ny = -left_x, -left_y
        mx = x1 + (x2 - x1) * fraction + nx * 9
        my = y1 + (y2 - y1) * fraction + ny * 9
        anchor = "start" if nx > 0.35 else "end" if nx < -0.35 else "middle"
        if ny > 0.35:
            my += BOND_LABEL_SIZE * 0.8
        elif ny >= -0.35:
            my += BOND_LABEL_SIZE * 0.35
        _sub(labels_group, "text", text, class_="bond-number", x=_fmt(mx), y=_fmt(my), text_anchor=anchor)

    for node in nodes.values():
        _draw_node(nodes_group, node, graph, id_prefix)

    if not nodes:
        _sub(nodes_group, "text", "(empty bond graph)", x=_fmt(MARGIN), y=_fmt(MARGIN + 4),
             font_size=_fmt(LABEL_SIZE))
    return Markup(ET.tostring(root, encoding="unicode", short_empty_elements=True))
