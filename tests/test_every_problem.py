"""One run reports every problem: a model's law errors and the causal conflicts of its structure.

A law error (an undefined name, a missing law, a dimension error) leaves the graph's structure --
its elements, junctions, bonds and ports -- known, and its causality depends on that structure only:
``bondc check`` and the language server report the conflicts (E601) beside the law errors. Where
the structure itself is wrong (an unknown kind, a bond to nothing, a duplicate name, a syntax error)
only that is reported: no conflict that a fix could make disappear or appear.
"""

from __future__ import annotations

import dataclasses
import json

import pytest

from bondc import semantic
from bondc.causality import structural_conflicts
from bondc.cli import main
from bondc.errors import BondcError, ModelError, ParseError
from bondc.lsp import check_text

# The issue's model: an undefined name on one line, two flow sources on one 1-junction.
ISSUE = """\
model Issue
  param m = 2 [kg]
  Sf pump : f = 1
  Sf fan : f = 2
  I mass : f = p/mm
  1 j
  pump -> j
  fan -> j
  j -> mass
end
"""


def errors(text: str, tmp_path, name: str = "m.bg") -> list[tuple[str, int, int]]:
    """(code, line, column) of every error ``semantic.load`` reports."""
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(BondcError) as info:
        semantic.load(path)
    return [(d.code, d.span.line, d.span.column) for d in info.value.diagnostics]


def test_the_issue_model_reports_the_undefined_name_and_the_causal_conflict(tmp_path):
    assert errors(ISSUE, tmp_path) == [("E601", 4, 6), ("E301", 5, 18)]


def test_check_prints_both_with_their_codes_and_positions(tmp_path, capsys):
    path = tmp_path / "issue.bg"
    path.write_text(ISSUE)
    assert main(["check", str(path)]) == 1
    captured = capsys.readouterr()      # (diagnostics go to stderr)
    assert f"{path}:4:6: error[E601]: causal conflict: flow source 'pump' and flow source 'fan' both set the " \
           "flow of 1-junction 'j'" in captured.err
    assert f"{path}:5:18: error[E301]: undefined name 'mm'" in captured.err
    assert captured.err.index("E601") < captured.err.index("E301") and f"{path}: 2 errors" in captured.err


def test_check_json_lists_both(tmp_path, capsys):
    path = tmp_path / "issue.bg"
    path.write_text(ISSUE)
    assert main(["check", "--json", str(path)]) == 1
    data = json.loads(capsys.readouterr().out)
    assert data["ok"] is False and data["model"] is None
    assert [(d["code"], d["line"], d["column"]) for d in data["diagnostics"]] == [("E601", 4, 6), ("E301", 5, 18)]


def test_the_language_servers_analysis_reports_both(tmp_path):
    found, graph = check_text(tmp_path / "issue.bg", ISSUE)
    assert [(d.code, d.span.line, d.span.column) for d in found] == [("E601", 4, 6), ("E301", 5, 18)]
    assert graph is None


def test_without_the_law_error_the_conflict_is_the_same_one(tmp_path, capsys):
    """What the structural stage reports is what causality reports once the laws are right."""
    path = tmp_path / "fixed.bg"
    path.write_text(ISSUE.replace("p/mm", "p/m"))
    assert main(["check", "--json", str(path)]) == 1
    fixed = json.loads(capsys.readouterr().out)["diagnostics"]
    path.write_text(ISSUE)
    assert main(["check", "--json", str(path)]) == 1
    broken = json.loads(capsys.readouterr().out)["diagnostics"]
    assert [d for d in broken if d["code"] == "E601"] == fixed


@pytest.mark.parametrize("law, code", [
    ("R drag : e = bb*f", "E301"),          # an undefined name in a resistor's law
    ("R drag : f = e/bb", "E301"),          # the same, written as a conductance
    ("R drag", "E502"),                     # no law at all
    ("R drag : e = 2*f, e = 3*f", "E503"),  # two laws
    ("R drag : x = 2*f", "E501"),           # a law it cannot have (and so none it needs, E502)
    ("R drag : e = b*f\n  param L = 1 [m]\n  output w = b + L", "E210"),  # dimensions that differ (on the built graph)
])
def test_a_law_error_of_any_kind_beside_a_conflict(tmp_path, law, code):
    text = ("model M\n  param b = 2 [N*s/m]\n  Se a : e = 1\n  Se c : e = 2\n  " + law + "\n  0 z\n"
            "  a -> z\n  c -> z\n  z -> drag\n  output k = b\nend\n")
    found = errors(text, tmp_path)
    assert ("E601", 4, 6) in found and code in {c for c, _, _ in found}
    assert {c for c, _, _ in found} <= {"E601", code, "E502"}


@pytest.mark.parametrize("mistake, code", [
    ("  Rx spare : e = 1\n", "E303"),         # an unknown kind
    ("  j -> nowhere\n", "E404"),          # a bond to nothing
    ("  R pump : e = f\n", "E302"),           # a name defined twice
    ("  0 lonely\n", "E403"),                 # a junction with no bond
])
def test_a_wrong_structure_reports_only_itself_and_the_law_errors(tmp_path, mistake, code):
    """The conflict is not reported: with the structure wrong, a fix may change it."""
    text = ISSUE.replace("end\n", mistake + "end\n")
    assert {c for c, _, _ in errors(text, tmp_path)} == {code, "E301"}


def test_a_syntax_error_in_a_law_reports_only_the_syntax_error(tmp_path, capsys):
    """The statement with a syntax error is not read, so its element is unknown: the semantic stage
    does not run (no bond to 'mass' called unknown, no law error of the rest), nor causality."""
    text = ISSUE.replace("f = p/mm", "f = p/*m")
    with pytest.raises(ParseError):
        semantic.load_files(tmp_path / "x.bg", text)
    assert errors(text, tmp_path) == [("E100", 5, 18)]
    path = tmp_path / "m.bg"
    assert main(["check", "--json", str(path)]) == 1
    assert [d["code"] for d in json.loads(capsys.readouterr().out)["diagnostics"]] == ["E100"]
    assert [d.code for d in check_text(path, text)[0]] == ["E100"]


def test_a_component_with_law_errors_is_not_given_a_causality(tmp_path):
    """A component's causality is checked where it is used (its ports are open)."""
    text = ("model Part\n  port a\n  Sf pump : f = 1\n  Sf fan : f = 2\n  R r : e = bb*f\n  1 j\n"
            "  pump -> j\n  fan -> j\n  j -> r\n  j -> a\nend\n")
    path = tmp_path / "part.bg"
    path.write_text(text)
    with pytest.raises(ModelError) as info:
        semantic.load(path, model="Part")
    assert [d.code for d in info.value.diagnostics] == ["E301"]


def test_a_conflict_that_depends_on_a_broken_resistors_law_is_not_reported(tmp_path, monkeypatch):
    """One run per causality the resistor of unknown law could prefer: only what every run meets."""
    import bondc.causality as causality

    text = ("model M\n  Sf pump : f = 1\n  Sf fan : f = 2\n  R r : e = 3*f\n  1 j\n"
            "  pump -> j\n  fan -> j\n  j -> r\nend\n")
    path = tmp_path / "m.bg"
    path.write_text(text)
    graph, _ = semantic.load(path)
    conflict = structural_conflicts(graph, ["r"])
    assert [(d.code, d.span.line) for d in conflict] == [("E601", 3)]

    real = causality._Procedure.run
    preferred = []

    def run(self):      # as if a conflict were met only when the resistor prefers conductance
        state = real(self)
        preferred.append(self.conductance.get("r"))
        if self.conductance.get("r"):
            self.errors.append(dataclasses.replace(self.errors[0], message="only one way"))
        return state

    monkeypatch.setattr(causality._Procedure, "run", run)
    assert structural_conflicts(graph, ["r"]) == conflict and preferred == [False, True]
    preferred.clear()
    assert structural_conflicts(graph) == conflict and preferred == [None]


def test_with_many_resistors_of_unknown_law_the_sources_conflicts_are_still_reported(tmp_path):
    """Past MAX_UNKNOWN_RESISTORS, not every preference is tried: the conflicts met before any
    resistor is decided (sources, storage elements) hold whatever the resistors' laws."""
    from bondc.causality import MAX_UNKNOWN_RESISTORS

    count = MAX_UNKNOWN_RESISTORS + 1
    resistors = "".join(f"  R r{i} : e = bb*f\n" for i in range(count))
    bonds = "".join(f"  j -> r{i}\n" for i in range(count))
    text = f"model M\n  Sf pump : f = 1\n  Sf fan : f = 2\n{resistors}  1 j\n  pump -> j\n  fan -> j\n{bonds}end\n"
    found = errors(text, tmp_path)
    assert found[0] == ("E601", 3, 6) and [c for c, _, _ in found[1:]] == ["E301"] * count
