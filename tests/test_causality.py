"""Tests of the causality stage (SCAP): assignments, conflicts, derivative causality, loops."""

from __future__ import annotations

from pathlib import Path

import pytest

from bondc import semantic
from bondc.causality import CausalGraph, assign_causality, format_table
from bondc.errors import CausalityError, render
from bondc.model import BondGraph

FIXTURES = Path(__file__).parent / "fixtures" / "textbook"


# ----------------------------------------------------------------- loading

def load(path) -> BondGraph:
    graph, _warnings = semantic.load(Path(path))
    return graph


def load_text(tmp_path, text: str, name: str = "model.bg") -> BondGraph:
    path = tmp_path / name
    path.write_text(text)
    return load(path)


def causal_of(name: str) -> CausalGraph:
    return assign_causality(load(FIXTURES / f"{name}.bg"))


def codes(diagnostics) -> list[str]:
    return [d.code for d in diagnostics]


# ---------------------------------------------------------- integral causality

def test_mass_spring_damper_is_all_integral():
    causal = causal_of("mass_spring_damper")
    assert dict(causal.storage) == {"mass": "integral", "spring": "integral"}
    assert dict(causal.resistors) == {"damper": "resistance"}
    graph = causal.graph
    # The force sets the effort of its bond; the 1-junction sets the mass's effort
    # (I in integral causality receives effort) and receives the spring's and damper's.
    by_head = {graph.bond(n).head: n for n in causal.effort_setter}
    assert causal.effort_from(by_head["j"]) == "force"
    assert causal.effort_from(by_head["mass"]) == "j"
    assert causal.effort_from(by_head["spring"]) == "spring"
    assert causal.effort_from(by_head["damper"]) == "damper"
    assert causal.stroke_end(by_head["mass"]) == "mass"
    assert causal.strong_bond("j") == by_head["mass"]
    assert causal.diagnostics == ()
    assert causal.summary()["integral"] == 2 and causal.summary()["derivative"] == 0


def test_every_junction_has_exactly_one_strong_bond_in_every_fixture():
    for path in sorted(FIXTURES.glob("*.bg")):
        causal = assign_causality(load(path))
        graph = causal.graph
        for junction in graph.junctions.values():
            if junction.kind == "0":
                strong = [b for b in junction.bonds if not causal.sets_effort(b, junction.name)]
            else:
                strong = [b for b in junction.bonds if causal.sets_effort(b, junction.name)]
            assert len(strong) == 1, (path.name, junction.name)
        for element in graph.elements.values():
            if element.kind in ("TF", "MTF"):
                first, second = element.bonds
                assert causal.sets_effort(first, element.name) != causal.sets_effort(second, element.name)
            if element.kind in ("GY", "MGY"):
                first, second = element.bonds
                assert causal.sets_effort(first, element.name) == causal.sets_effort(second, element.name)


def test_assignment_is_deterministic():
    first = causal_of("quarter_car")
    second = causal_of("quarter_car")
    assert dict(first.effort_setter) == dict(second.effort_setter)
    assert format_table(first) == format_table(second)


def test_format_table_lists_bonds_and_storage():
    table = format_table(causal_of("mass_spring_damper"))
    lines = table.splitlines()
    assert lines[0].split() == ["bond", "name", "from", "->", "to", "effort", "set", "by", "stroke", "at"]
    assert lines[1].split() == ["1", "b1", "force", "->", "j", "force", "j"]
    assert "  mass    I  integral" in table
    assert "  spring  C  integral" in table
    assert "damper  R  resistance" in table


def test_resistor_prefers_the_form_its_law_is_written_in(tmp_path):
    # A 1-junction driven by an effort source needs exactly one resistor to set
    # its flow: the one written f = ... (conductance), whatever the order.
    text = """model M
  param Ra = 2
  param Rb = 3
  Se source : e = 1
  R  ra : e = Ra*f
  R  rb : f = e/Rb
  1  j
  source -> j
  j -> ra
  j -> rb
end
"""
    causal = assign_causality(load_text(tmp_path, text))
    assert dict(causal.resistors) == {"ra": "resistance", "rb": "conductance"}


# ------------------------------------------------------------------ conflicts

TWO_FLOW_SOURCES = """model TwoFlowSources
  Sf pump_a : f = 1
  Sf pump_b : f = 2
  R  pipe   : e = 3*f
  1  j
  pump_a -> j
  pump_b -> j
  j -> pipe
end
"""

TWO_EFFORT_SOURCES = """model TwoEffortSources
  Se battery_a : e = 12
  Se battery_b : e = 9
  C  cap       : e = q/1e-3
  0  node
  battery_a -> node
  battery_b -> node
  node -> cap
end
"""


@pytest.mark.parametrize("text, sources, junction, what", [
    (TWO_FLOW_SOURCES, ("pump_a", "pump_b"), "1-junction 'j'", "flow"),
    (TWO_EFFORT_SOURCES, ("battery_a", "battery_b"), "0-junction 'node'", "effort"),
])
def test_two_sources_on_one_junction_conflict(tmp_path, text, sources, junction, what):
    graph = load_text(tmp_path, text)
    with pytest.raises(CausalityError) as info:
        assign_causality(graph)
    errors = info.value.diagnostics
    assert codes(errors) == ["E601"]
    error = errors[0]
    for source in sources:
        assert f"'{source}'" in error.message
    assert junction in error.message and f"the {what} of" in error.message
    # Primary location: the second source; notes: the first source, the junction and both bonds.
    assert error.span.line == 3 and error.span.column == 6
    labels = [rel.label for rel in error.related]
    assert any(sources[0] in label for label in labels)
    assert any(junction in label for label in labels)
    assert any(label.startswith("bond 1:") for label in labels)
    assert any(label.startswith("bond 2:") for label in labels)
    assert error.hint
    rendered = render(error, graph.sources)
    assert "error[E601]" in rendered and "model.bg:3:6" in rendered and "^" in rendered


def test_every_conflict_is_reported(tmp_path):
    text = """model Two
  Sf a : f = 1
  Sf b : f = 2
  Se c : e = 1
  Se d : e = 2
  1  j1
  0  j0
  a -> j1
  b -> j1
  c -> j0
  d -> j0
end
"""
    with pytest.raises(CausalityError) as info:
        assign_causality(load_text(tmp_path, text))
    messages = [d.message for d in info.value.diagnostics]
    assert codes(info.value.diagnostics) == ["E601", "E601"]
    assert "'a'" in messages[0] and "'b'" in messages[0]
    assert "'c'" in messages[1] and "'d'" in messages[1]


def test_effort_sources_on_both_sides_of_a_transformer_conflict(tmp_path):
    text = """model Lever
  Se left  : e = 1
  Se right : e = 2
  TF lever : r = 2
  left -> lever -> right
end
"""
    with pytest.raises(CausalityError) as info:
        assign_causality(load_text(tmp_path, text))
    (error,) = info.value.diagnostics
    assert error.code == "E601" and "'left'" in error.message and "'right'" in error.message


# ------------------------------------------------------- derivative causality

def test_rigidly_geared_inertias_give_derivative_causality():
    causal = causal_of("two_inertias_gear")
    assert dict(causal.storage) == {"motor": "integral", "load": "derivative"}
    assert causal.dependencies["load"] == ("motor",)
    (warning,) = [d for d in causal.diagnostics if d.code == "W602"]
    assert "'load'" in warning.message and "'motor'" in warning.message
    assert warning.severity == "warning"
    assert [rel.label for rel in warning.related] == ["inertia (flow store) 'motor' fixes it"]
    assert "derivative" in format_table(causal) and "(fixed by motor)" in format_table(causal)


def test_capacitor_across_an_effort_source_depends_on_the_source(tmp_path):
    text = """model Stiff
  param Cap = 1e-3
  input V = 5*sin(t)
  MSe supply : e = V
  C   cap    : e = q/Cap
  R   leak   : f = e/100
  0   node
  supply -> node
  node -> cap
  node -> leak
end
"""
    causal = assign_causality(load_text(tmp_path, text))
    assert causal.storage["cap"] == "derivative"
    assert causal.dependencies["cap"] == ("supply",)
    assert codes(causal.diagnostics) == ["W602"]


# ------------------------------------------------------------ algebraic loops

def test_resistor_loop_is_reported_with_its_resistors_and_junctions():
    causal = causal_of("rr_loop")
    assert causal.resistors["r1"] == "resistance"
    (loop,) = causal.algebraic_loops
    assert loop.resistors == ("r1", "r2", "r3")
    assert set(loop.junctions) == {"series", "node", "branch"}
    (info,) = [d for d in causal.diagnostics if d.code == "I603"]
    assert info.severity == "info"
    for name in ("r1", "r2", "series", "node"):
        assert f"'{name}'" in info.message
    assert causal.summary()["algebraic_loops"] == 1


def test_no_loop_without_a_resistor_choice():
    for name in ("mass_spring_damper", "series_rlc", "quarter_car", "dc_motor_gear", "pneumatic_piston"):
        assert causal_of(name).algebraic_loops == (), name


def test_summary_is_json_ready():
    import json

    summary = causal_of("two_inertias_gear").summary()
    assert json.loads(json.dumps(summary)) == summary
    assert summary["derivative_storage"] == ["load"]
