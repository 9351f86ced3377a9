"""The bond-graph SVG: bonds, half-arrows, causal strokes, escaping, layout, determinism."""

from __future__ import annotations

import itertools
import math
import xml.etree.ElementTree as ET

from pathlib import Path

import pytest

from bondc.causality import assign_causality
from bondc.model import BondGraph, Bond, ElementNode, JunctionNode
from bondc.parse import parse_text
from bondc.report.diagram import _layout, bond_graph_svg, effort_setters
from bondc.semantic import build

NS = {"svg": "http://www.w3.org/2000/svg"}

# The complete model of LANGUAGE.md section 10, shared with the language-example tests.
MSD = (Path(__file__).parent / "fixtures" / "language" / "s10_complete_model.bg").read_text(encoding="utf-8")

# About twenty elements and junctions, after the flagship's structure (MODEL-NOTES.md).
HYBRID = """\
model Hybrid "electro-pneumatic hybrid positioning"
  param w = 10 [rad/s]
  Sf  servomotor : f = w
  C   coupling   : e = 120*q
  I   shaft      : f = p/4e-5
  TF  screw      : r = 8e-4
  C   nut        : e = 1e8*q
  R   nut_damper : e = 1e5*f
  I   mass       : f = p/31.7
  R   friction   : e = 50*f
  Se  gravity    : e = -311
  Se  supply     : e = 224000
  R   valve      : e = 1e9*f
  C   chamber    : e = q/1e-9
  TF  piston     : r = 2.63e-3
  0   j_motor, j_nut, j_chamber
  1   j_shaft, j_delta, j_mass, j_valve
  servomotor -> j_motor -> coupling
  j_motor -> j_shaft -> shaft
  j_shaft -> screw -> j_nut -> j_delta
  j_delta -> nut
  j_delta -> nut_damper
  j_nut -> j_mass -> mass
  j_mass -> friction
  j_mass -> gravity
  supply -> j_valve -> valve
  j_valve -> j_chamber -> chamber
  j_chamber -> piston
  b_rod: piston -> j_mass
end
"""

# A loop of junctions, parallel bonds between two junctions, a gyrator with named ports.
LOOP = """\
model Loop "loop"
  Se src : e = 1
  C  k1  : e = q
  I  m1  : f = p
  I  m2  : f = p
  R  r1  : e = f
  R  r2  : e = f
  GY gy  : r = 2
  1 a, b
  0 c
  src -> a -> c -> b
  a -> b
  b -> c
  c -> k1
  b -> m1
  a -> r1
  a -> r2
  c -> gy.p1
  m2 -> gy.p2
end
"""


def graph_of(text: str) -> BondGraph:
    graph, _ = build(parse_text(text, "m.bg"))
    return graph


def parse_svg(svg: str) -> ET.Element:
    return ET.fromstring(svg)


def by_class(root: ET.Element, tag: str, cls: str) -> list[ET.Element]:
    return [e for e in root.iter(f"{{{NS['svg']}}}{tag}") if cls in (e.get("class") or "").split()]


@pytest.fixture(scope="module", params=["MSD", "HYBRID", "LOOP"])
def graph(request) -> BondGraph:
    return graph_of(globals()[request.param])


@pytest.mark.parametrize("orientation", ["auto", "horizontal", "vertical"])
def test_every_bond_is_drawn_with_number_and_half_arrow(graph, orientation):
    root = parse_svg(bond_graph_svg(graph, orientation=orientation))
    bonds = by_class(root, "g", "bond")
    assert [g.get("id") for g in bonds] == [f"bond-{b.number}" for b in graph.bonds]
    numbers = [t.text for t in by_class(root, "text", "bond-number")]
    assert numbers == [str(b.number) + (f" {b.label}" if b.label else "") for b in graph.bonds]
    assert len(by_class(root, "path", "half-arrow")) == len(graph.bonds)
    assert len(by_class(root, "line", "bond-line")) == len(graph.bonds)
    assert by_class(root, "line", "causal-stroke") == []


def test_labelled_bond_shows_number_and_label():
    root = parse_svg(bond_graph_svg(graph_of(HYBRID)))
    assert "19 b_rod" in [t.text for t in by_class(root, "text", "bond-number")]


def test_nodes_are_labelled_kind_colon_name_and_junctions_by_symbol(graph):
    root = parse_svg(bond_graph_svg(graph))
    texts = [t.text for t in root.iter(f"{{{NS['svg']}}}text")]
    for element in graph.elements.values():
        assert f"{element.kind}:{element.name}" in texts
    for junction in graph.junctions.values():
        assert junction.name in texts
    symbols = [t.text for g in by_class(root, "g", "junction") for t in g.iter(f"{{{NS['svg']}}}text")]
    assert sorted(s for s in symbols if s in ("0", "1")) == sorted(j.kind for j in graph.junctions.values())


def test_one_causal_stroke_per_bond(graph):
    causal = assign_causality(graph)
    root = parse_svg(bond_graph_svg(graph, causal))
    assert len(by_class(root, "line", "causal-stroke")) == len(graph.bonds)
    # The same drawing from the plain mapping the causal graph exposes.
    assert bond_graph_svg(graph, causal) == bond_graph_svg(graph, dict(causal.effort_setter))


def _stroke_end(group: ET.Element) -> str:
    """'head' or 'tail': which end of the bond line the stroke crosses."""
    line = by_class(group, "line", "bond-line")[0]
    stroke = by_class(group, "line", "causal-stroke")[0]
    mid = ((float(stroke.get("x1")) + float(stroke.get("x2"))) / 2,
           (float(stroke.get("y1")) + float(stroke.get("y2"))) / 2)
    tail = (float(line.get("x1")), float(line.get("y1")))
    head = (float(line.get("x2")), float(line.get("y2")))
    return "head" if math.dist(mid, head) < math.dist(mid, tail) else "tail"


def test_stroke_sits_at_the_end_that_receives_the_effort():
    # Karnopp: the stroke is at the end toward which the effort is directed.
    graph = graph_of(MSD)
    causal = assign_causality(graph)
    root = parse_svg(bond_graph_svg(graph, causal))
    ends = {int(g.get("id").split("-")[1]): _stroke_end(g) for g in by_class(root, "g", "bond")}
    # 1 force -> j: MSe sets the effort, which goes to j (head).  2 j -> mass: j sets the
    # effort on the I in integral causality (head).  3 j -> spring and 4 j -> damper: C and R
    # set the effort, which goes to j (tail).
    assert causal.effort_setter == {1: "force", 2: "j", 3: "spring", 4: "damper"}
    assert ends == {1: "head", 2: "head", 3: "tail", 4: "tail"}


def test_stroke_is_perpendicular_to_its_bond():
    graph = graph_of(HYBRID)
    root = parse_svg(bond_graph_svg(graph, assign_causality(graph)))
    for group in by_class(root, "g", "bond"):
        line = by_class(group, "line", "bond-line")[0]
        stroke = by_class(group, "line", "causal-stroke")[0]
        bond = (float(line.get("x2")) - float(line.get("x1")), float(line.get("y2")) - float(line.get("y1")))
        cross = (float(stroke.get("x2")) - float(stroke.get("x1")), float(stroke.get("y2")) - float(stroke.get("y1")))
        assert abs(bond[0] * cross[0] + bond[1] * cross[1]) < 0.05 * math.hypot(*bond) * math.hypot(*cross)


def test_half_arrow_is_at_the_head():
    graph = graph_of(MSD)
    root = parse_svg(bond_graph_svg(graph))
    for group in by_class(root, "g", "bond"):
        line = by_class(group, "line", "bond-line")[0]
        start = by_class(group, "path", "half-arrow")[0].get("d").split()[0][1:]
        assert start == f"{line.get('x2')},{line.get('y2')}"


def test_partial_causality_draws_only_the_given_strokes():
    graph = graph_of(MSD)
    root = parse_svg(bond_graph_svg(graph, {1: "force"}))
    assert len(by_class(root, "line", "causal-stroke")) == 1


def test_bad_causal_assignment_is_rejected():
    graph = graph_of(MSD)
    with pytest.raises(ValueError, match="cannot set its effort"):
        bond_graph_svg(graph, {1: "mass"})
    with pytest.raises(ValueError, match="bond 9"):
        bond_graph_svg(graph, {9: "j"})
    with pytest.raises(TypeError):
        effort_setters(object(), graph)
    with pytest.raises(ValueError, match="orientation"):
        bond_graph_svg(graph, orientation="diagonal")


def _element(kind, name, bond, description=None):
    return ElementNode(kind, name, description, {}, {}, (), (bond,), (1,))


def test_names_and_descriptions_are_escaped():
    # The parser never lets such names through, but the drawing must not trust that.
    nasty = 'a<b&c>"'
    graph = BondGraph(
        name="<script>", description=None, file="x.bg", parameters={}, functions={}, inputs={}, outputs={},
        elements={nasty: _element("Se", nasty, 1, "desc </svg><script>alert(1)</script>"),
                  "m": _element("I", "m", 2)},
        junctions={"j&<": JunctionNode("1", "j&<", (1, 2))},
        bonds=(Bond(1, nasty, "j&<", label="l<1>"), Bond(2, "j&<", "m")),
        model_states=(), experiments={})
    svg = bond_graph_svg(graph, {1: nasty, 2: "j&<"})
    assert "<script" not in svg and svg.count("</svg>") == 1 and svg.endswith("</svg>")
    assert "a&lt;b&amp;c&gt;" in svg
    root = parse_svg(svg)                          # well-formed XML
    texts = [t.text for t in root.iter(f"{{{NS['svg']}}}text")]
    assert f"Se:{nasty}" in texts and "j&<" in texts and "1 l<1>" in texts


def test_svg_has_a_size_and_everything_inside_it(graph):
    svg = bond_graph_svg(graph, assign_causality(graph))
    root = parse_svg(svg)
    width, height = float(root.get("width")), float(root.get("height"))
    assert width > 50 and height > 50
    assert root.get("viewBox") == f"0 0 {root.get('width')} {root.get('height')}"
    for element in root.iter():
        for attribute in ("x", "x1", "x2"):
            if element.get(attribute) is not None:
                assert 0 <= float(element.get(attribute)) <= width
        for attribute in ("y", "y1", "y2"):
            if element.get(attribute) is not None:
                assert 0 <= float(element.get(attribute)) <= height


@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
def test_node_boxes_do_not_overlap(graph, orientation):
    nodes, width, height = _layout(graph, orientation)
    assert set(nodes) == set(graph.elements) | set(graph.junctions)
    boxes = {n.name: (n.x - n.left, n.y - n.height / 2, n.x + n.right, n.y + n.height / 2) for n in nodes.values()}
    for (a, box_a), (b, box_b) in itertools.combinations(boxes.items(), 2):
        separate = (box_a[2] <= box_b[0] or box_b[2] <= box_a[0] or box_a[3] <= box_b[1] or box_b[3] <= box_a[1])
        assert separate, (a, b)
    for box in boxes.values():
        assert 0 <= box[0] and box[2] <= width and 0 <= box[1] and box[3] <= height


def test_twenty_element_model_fits_a_report_column():
    graph = graph_of(HYBRID)
    assert len(graph.elements) + len(graph.junctions) == 20
    root = parse_svg(bond_graph_svg(graph))
    assert float(root.get("width")) <= 880 and float(root.get("height")) <= 1000
    assert bond_graph_svg(graph) == bond_graph_svg(graph, orientation="vertical")
    # Short chains keep the textbook left-to-right drawing.
    small = graph_of(MSD)
    assert bond_graph_svg(small) == bond_graph_svg(small, orientation="horizontal")


def test_output_is_deterministic(graph):
    causal = assign_causality(graph)
    first = bond_graph_svg(graph, causal)
    assert first == bond_graph_svg(graph, causal)
    assert first == bond_graph_svg(graph_of({"Hybrid": HYBRID, "Loop": LOOP}.get(graph.name, MSD)),
                                   assign_causality(graph))


def test_empty_graph_still_has_a_size():
    graph = BondGraph("E", None, "e.bg", {}, {}, {}, {}, {}, {}, (), (), {})
    root = parse_svg(bond_graph_svg(graph))
    assert float(root.get("width")) > 0 and float(root.get("height")) > 0
