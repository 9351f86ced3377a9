"""A kind missing anywhere fails: every element kind of ``bondc.kinds.KINDS`` checks, gets its
causality and simulates in a small model against its closed-form solution, and every place
that cannot import the table (the editor grammar, the language reference, the README) and the
places that read it (report highlighter, language server) list it."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from types import SimpleNamespace

import pytest
from pygments.token import Keyword

import bondc
from bondc import causality
from bondc.analysis import energy
from bondc.kinds import JUNCTIONS, KINDS
from bondc.lsp.features import completions
from bondc.report.lexer import BgLexer

ROOT = Path(__file__).resolve().parent.parent

# Each kind in a first-order circuit with a known solution at t = 1 s. ``y`` is a state with
# y(0) = 0 and dy/dt = a*(b - y): y(1) = b*(1 - exp(-a)), or with a ramp drive dy/dt = t - y:
# y(1) = exp(-1). Written by hand from the kinds' laws (docs/language.md), not from the table.
RC = "  1 j\n  R r : e = f\n  C c : e = q\n  j -> r\n  j -> c\n  output y = c.q\n"
FIRST = 1 - math.exp(-1)
CASES = {
    # Se 1 V on R = 1, C = 1 in series: q' = 1 - q
    "Se": ("  Se s : e = 1\n  s -> j\n" + RC, FIRST),
    # a ramp effort t: q' = t - q, q(1) = exp(-1)
    "MSe": ("  input u = t\n  MSe s : e = 1*u\n  s -> j\n" + RC, math.exp(-1)),
    # Sf 1 A into C = 1 parallel with R = 1 (a 0-junction): q' = 1 - q
    "Sf": ("  Sf s : f = 1\n  0 j\n  R r : e = f\n  C c : e = q\n  s -> j\n  j -> r\n  j -> c\n  output y = c.q\n",
           FIRST),
    "MSf": ("  input u = t\n  MSf s : f = 1*u\n  0 j\n  R r : e = f\n  C c : e = q\n  s -> j\n  j -> r\n  j -> c\n"
            "  output y = c.q\n", math.exp(-1)),
    # R given as a conductance f = 2 e: q' = 2 (1 - q)
    "R": ("  Se s : e = 1\n  1 j\n  R r : f = 2*e\n  C c : e = q\n  s -> j\n  j -> r\n  j -> c\n"
          "  output y = c.q\n", 1 - math.exp(-2)),
    # C of capacitance 1/2: e = 2 q, q' = 1 - 2 q: q(1) = (1 - exp(-2))/2
    "C": ("  Se s : e = 1\n  1 j\n  R r : e = f\n  C c : e = 2*q\n  s -> j\n  j -> r\n  j -> c\n"
          "  output y = c.q\n", (1 - math.exp(-2)) / 2),
    # I of inertance 1: f = p, p' = 1 - p
    "I": ("  Se s : e = 1\n  1 j\n  R r : e = f\n  I m : f = p\n  s -> j\n  j -> r\n  j -> m\n  output y = m.p\n",
          FIRST),
    # TF p1.e = r p2.e with r = 2: 1/2 V behind it, q' = 1/2 - q
    "TF": ("  Se s : e = 1\n  TF tf : r = 2\n  s -> tf.p1\n  tf.p2 -> j\n" + RC, FIRST / 2),
    "MTF": ("  input u = 2\n  Se s : e = 1\n  MTF tf : r = u\n  s -> tf.p1\n  tf.p2 -> j\n" + RC, FIRST / 2),
    # GY p1.e = r p2.f with r = 2: a 1/2 A flow source into C parallel with R, q' = 1/2 - q
    "GY": ("  Se s : e = 1\n  GY g : r = 2\n  0 j\n  R r : e = f\n  C c : e = q\n  s -> g.p1\n  g.p2 -> j\n"
           "  j -> r\n  j -> c\n  output y = c.q\n", FIRST / 2),
    "MGY": ("  input u = 2\n  Se s : e = 1\n  MGY g : r = u\n  0 j\n  R r : e = f\n  C c : e = q\n  s -> g.p1\n"
            "  g.p2 -> j\n  j -> r\n  j -> c\n  output y = c.q\n", FIRST / 2),
}


def test_every_kind_has_a_case():
    assert set(CASES) == set(KINDS)


@pytest.mark.parametrize("name", sorted(KINDS))
def test_every_kind_checks_gets_causality_and_simulates(name):
    text, expected = CASES[name]
    text = f"model K\n{text}end\n"
    assert re.search(rf"^  {name} ", text, re.M)
    checked = bondc.check(text=text)
    assert checked.ok, checked
    graph = bondc.load(text=text).graph
    assert any(element.kind == name for element in graph.elements.values())
    causal = causality.assign_causality(graph)
    assert not [d for d in causal.diagnostics if d.severity == "error"]
    sim = bondc.simulate(text=text, t_end=1.0, dt=0.01)
    assert sim["y"][-1] == pytest.approx(expected, rel=1e-4)


def test_the_tables_derived_from_kinds_cover_every_kind():
    assert set(causality.ROLES) == set(energy.ROLES) == set(KINDS)
    for name, kind in KINDS.items():
        assert kind.ports in (1, 2) and kind.laws and kind.description
        if kind.ports == 1:
            assert name in causality.ONE_PORT_CAUSALITIES and kind.causalities
        else:
            assert len(kind.ratios) == 2 and not kind.causalities
        if kind.stores:
            assert kind.state in ("q", "p") and kind.integrates in ("e", "f")


@pytest.mark.parametrize("name", sorted(KINDS))
def test_the_report_highlighter_marks_every_kind(name):
    tokens = [(token, value) for token, value in BgLexer().get_tokens(f"model M\n  {name} x : r = 1\nend\n")]
    assert (Keyword.Type, name) in tokens


def test_the_language_server_completes_every_kind_with_its_description():
    items = {item.label: item.detail for item in completions(SimpleNamespace(index=None), "", "  ", None)}
    for name, kind in KINDS.items():
        assert items.get(name) == kind.description


def test_the_editor_grammar_lists_every_kind():
    grammar = json.loads((ROOT / "editors/vscode/syntaxes/bondgraph.tmLanguage.json").read_text(encoding="utf-8"))
    match = re.match(r"\^\\s\*\(([A-Za-z|]+)\)", grammar["repository"]["element"]["match"])
    assert match, grammar["repository"]["element"]["match"]
    assert set(match.group(1).split("|")) == set(KINDS)


def test_the_language_reference_and_readme_list_every_kind():
    language = (ROOT / "docs/language.md").read_text(encoding="utf-8")
    listed = re.search(r"Element kinds \(`([^`]*)`\)", language)
    assert listed and set(listed.group(1).split()) == set(KINDS)
    in_table = set()
    for line in language.splitlines():
        if line.startswith("| `") and "|" in line[1:]:
            first = line.split("|")[1]
            in_table |= set(re.findall(r"`([A-Za-z]+)`", first)) & set(KINDS)
    assert in_table == set(KINDS)
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    listed = re.search(r"with kinds `([^`]*)`", readme)
    assert listed and set(listed.group(1).split()) == set(KINDS)
    for junction in JUNCTIONS:
        assert f"{junction}-junction" in language

