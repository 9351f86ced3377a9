"""The grammar: expressions, statements, line rules, comments, units and syntax errors.

Expected trees are built by hand from ``bondc.ast``; spans are not part of AST
equality, so positions are checked separately where they matter.
"""

from __future__ import annotations

from fractions import Fraction

import pytest

from bondc import ast
from bondc.ast import (Binary, BondChain, Call, Element, Endpoint, FnDef, If, Import, Input, Junction,
                       LawAssign, LawCall, LawState, ListExpr, Model, Name, Num, Output, Param, Ref, Setting,
                       StateDecl, Str, Unary, Unit, UnitFactor)
from bondc.errors import BondcError, ParseError
from bondc.parse import KEYWORDS, parse_set_value, parse_text


# ------------------------------------------------------------------ helpers

def expr(text: str) -> ast.Expr:
    """The expression ``text`` as a parameter value inside a model."""
    file = parse_text(f"model M\n  param x = {text}\nend\n", "e.bg")
    return file.models[0].body[0].value


def body(text: str) -> tuple:
    """The statements of a model whose body is ``text``."""
    return parse_text(f"model M\n{text}\nend\n", "m.bg").models[0].body


def errors(text: str) -> list[tuple[str, int, int]]:
    """(code, line, column) of every syntax error in ``text``."""
    with pytest.raises(ParseError) as info:
        parse_text(text, "bad.bg")
    return [(d.code, d.span.line, d.span.column) for d in info.value.diagnostics]


def n(text: str) -> Num:
    return Num(float(text), text)


a, b, c, d, x = (Name(s) for s in "abcdx")


def factors(unit: Unit) -> list[tuple[str, Fraction]]:
    return [(f.name, f.exponent) for f in unit.factors]


# ------------------------------------------------------- precedence and associativity

@pytest.mark.parametrize("text, tree", [
    ("a^b^c", Binary("^", a, Binary("^", b, Name("c")))),
    ("(a^b)^c", Binary("^", Binary("^", a, b), c)),
    ("-x^2", Unary("-", Binary("^", x, n("2")))),
    ("(-x)^2", Binary("^", Unary("-", x), n("2"))),
    ("2^-1", Binary("^", n("2"), Unary("-", n("1")))),
    ("a^-b^c", Binary("^", a, Unary("-", Binary("^", b, c)))),
    ("a - b - c", Binary("-", Binary("-", a, b), c)),
    ("a - (b - c)", Binary("-", a, Binary("-", b, c))),
    ("a/b*c", Binary("*", Binary("/", a, b), c)),
    ("a + b*c", Binary("+", a, Binary("*", b, c))),
    ("-a*b", Binary("*", Unary("-", a), b)),
    ("a*-b", Binary("*", a, Unary("-", b))),
    ("a - -b", Binary("-", a, Unary("-", b))),
    ("+a", Unary("+", a)),
    ("a + b < c*d", Binary("<", Binary("+", a, b), Binary("*", c, d))),
    ("a < b and not c or d", Binary("or", Binary("and", Binary("<", a, b), Unary("not", c)), d)),
    ("not a == b", Unary("not", Binary("==", a, b))),
    ("not not a", Unary("not", Unary("not", a))),
    ("a or b or c", Binary("or", Binary("or", a, b), c)),
    ("a and b or c and d", Binary("or", Binary("and", a, b), Binary("and", c, d))),
    ("a or b and c", Binary("or", a, Binary("and", b, c))),
    ("a <= b", Binary("<=", a, b)),
    ("a >= b", Binary(">=", a, b)),
    ("a != b", Binary("!=", a, b)),
    ("a > -b", Binary(">", a, Unary("-", b))),
    ("if a then b else c", If(a, b, c)),
    ("if a then b else c + 1", If(a, b, Binary("+", c, n("1")))),
    ("(if a then b else c) + 1", Binary("+", If(a, b, c), n("1"))),
    ("2*(if a then b else c)", Binary("*", n("2"), If(a, b, c))),
    ("if a then b else if c then d else x", If(a, b, If(c, d, x))),
    ("if if a then b else c then d else x", If(If(a, b, c), d, x)),
    ("if a < b or c then -x^2 else x", If(Binary("or", Binary("<", a, b), c), Unary("-", Binary("^", x, n("2"))), x)),
    ("f(x)^2", Binary("^", Call("f", (x,)), n("2"))),
    ("mass.f^2", Binary("^", Ref(("mass", "f")), n("2"))),
    ("((a))", a),
])
def test_precedence_and_associativity(text, tree):
    assert expr(text) == tree


@pytest.mark.parametrize("text", ["a < b < c", "1 + if a then b else c", "a == b != c", "-not a",
                                  "a^if b then c else d"])
def test_expressions_the_grammar_rejects(text):
    assert errors(f"model M\n  param x = {text}\nend\n")[0][0] == "E100"


@pytest.mark.parametrize("text, tree", [
    ("3", n("3")),
    ("0.5", n("0.5")),
    ("4.06e-5", n("4.06e-5")),
    ("1E+3", n("1E+3")),
    (".5", n(".5")),
    ("1.", n("1.")),
    ('"a\\"b\\\\c"', Str('a"b\\c')),
    ("screw.p1.e", Ref(("screw", "p1", "e"))),
    ("b9.f", Ref(("b9", "f"))),
    ("t", Name("t")),
    ("f()", Call("f", ())),
    ("atan2(a, b)", Call("atan2", (a, b))),
    ("table(t, [0, 1], [a, b])", Call("table", (Name("t"), ListExpr((n("0"), n("1"))), ListExpr((a, b))))),
    ("[]", ListExpr(())),
    ('csv("data/omega.csv", "omega")', Call("csv", (Str("data/omega.csv"), Str("omega")))),
])
def test_atoms(text, tree):
    assert expr(text) == tree


def test_numbers_keep_their_text():
    value = expr("1e-6")
    assert value.text == "1e-6" and value.value == 1e-6


# ------------------------------------------------------------------ line rules

def test_statement_continues_after_trailing_comma():
    (element,) = body("  C spring : e = k*q,\n\n      q(0) = 0.01")
    assert element.laws == (LawAssign("e", Binary("*", Name("k"), Name("q"))), LawCall("q", n("0"), n("0.01")))


def test_statement_continues_inside_parentheses_and_brackets():
    (param, inp) = body("  param x = (a +\n     b)\n  input u = table(t,\n  [0,\n 1],\n\n [2, 3]\n  )")
    assert param.value == Binary("+", a, b)
    assert inp.value == Call("table", (Name("t"), ListExpr((n("0"), n("1"))), ListExpr((n("2"), n("3")))))


def test_junction_names_continue_after_comma():
    assert body("  0 a,\n    b") == (Junction("0", ("a", "b")),)


def test_newline_without_comma_ends_the_statement():
    # the second line is then a statement of its own, and not a valid one
    assert errors("model M\n  param x = a +\n    b\nend\n") == [("E100", 2, 16), ("E100", 3, 6)]


def test_blank_lines_and_missing_final_newline():
    file = parse_text("\n\nmodel M\n\n\n  param a = 1\n\nend", "m.bg")
    assert file.models[0].body == (Param("a", n("1"), None, None),)


# ------------------------------------------------------------------ comments

def test_comments_are_collected_in_order_with_positions():
    text = ('# head\nmodel M  # model\n  param a = 1 # trailing\n  # own line\n'
            '  R r : e = "#not a comment",  # law\n    f = 1\nend # done')
    file = parse_text(text, "m.bg")
    assert [c.text for c in file.comments] == ["# head", "# model", "# trailing", "# own line", "# law", "# done"]
    assert [(c.span.line, c.span.column) for c in file.comments] == [(1, 1), (2, 10), (3, 15), (4, 3), (5, 32), (7, 5)]
    assert file.models[0].body[1].laws[0] == LawAssign("e", Str("#not a comment"))


def test_comment_text_drops_trailing_blanks_and_carriage_returns():
    file = parse_text("model M  # crlf  \r\n  param a = 1\r\nend\r\n", "m.bg")
    assert [c.text for c in file.comments] == ["# crlf"]
    assert file.models[0].body == (Param("a", n("1"), None, None),)


def test_comments_take_part_in_file_equality():
    assert parse_text("model M\nend # a\n") != parse_text("model M\nend # b\n")
    assert parse_text("model M\nend # a\n") == parse_text("model  M\n\nend     # a\n")


# ------------------------------------------------------------------ statements

def test_file_items_imports_functions_and_models():
    file = parse_text('import "lib/pneumatics.bg"\nfn sq(x) = x^2 "square"\nfn zero() = 0\n'
                      'model A "first"\nend\nmodel B\nend\n', "f.bg")
    assert file.items == (
        Import("lib/pneumatics.bg"),
        FnDef("sq", ("x",), Binary("^", x, n("2")), "square"),
        FnDef("zero", (), n("0")),
        Model("A", "first", ()),
        Model("B", None, ()),
    )
    assert [m.name for m in file.models] == ["A", "B"] and len(file.functions) == 2 and len(file.imports) == 1


def test_element_kinds_are_usable_as_parameter_names():
    statements = body("  param R = 5\n  param C = 1e-6\n  param I = 2\n  R R : e = R*f\n  C C : e = q/C")
    assert statements == (
        Param("R", n("5"), None, None),
        Param("C", n("1e-6"), None, None),
        Param("I", n("2"), None, None),
        Element("R", "R", None, (LawAssign("e", Binary("*", Name("R"), Name("f"))),)),
        Element("C", "C", None, (LawAssign("e", Binary("/", Name("q"), Name("C"))),)),
    )


def test_element_forms():
    statements = body('  C chamber "rod-side air" : state P [Pa] "pressure", P(0) = P0,\n'
                      '      der(P) = k*f,\n      e = P\n  R r\n  TF screw "ball screw" : r = lead/(2*pi)')
    chamber, resistor, screw = statements
    assert chamber == Element("C", "chamber", "rod-side air", (
        LawState("P", Unit((UnitFactor("Pa", Fraction(1)),), "Pa"), "pressure"),
        LawCall("P", n("0"), Name("P0")),
        LawCall("der", Name("P"), Binary("*", Name("k"), Name("f"))),
        LawAssign("e", Name("P")),
    ))
    assert resistor == Element("R", "r", None, ())
    assert screw.laws == (LawAssign("r", Binary("/", Name("lead"), Binary("*", n("2"), Name("pi")))),)
    assert (chamber.kind_span.line, chamber.kind_span.column, chamber.name_span.column) == (2, 3, 5)


def test_junctions():
    assert body("  0 a, b\n  1 j") == (Junction("0", ("a", "b")), Junction("1", ("j",)))


def test_bond_chains_labels_and_ports():
    statements = body("  A -> B\n  A -> B -> C\n  b9: motor -> j_motor\n  j_shaft -> screw.p1\n  screw.p2 -> x.p1 -> y")
    assert statements == (
        BondChain(None, (Endpoint("A", None), Endpoint("B", None))),
        BondChain(None, (Endpoint("A", None), Endpoint("B", None), Endpoint("C", None))),
        BondChain("b9", (Endpoint("motor", None), Endpoint("j_motor", None))),
        BondChain(None, (Endpoint("j_shaft", None), Endpoint("screw", "p1"))),
        BondChain(None, (Endpoint("screw", "p2"), Endpoint("x", "p1"), Endpoint("y", None))),
    )
    assert statements[2].label_span.column == 3


def test_inputs_outputs_states_and_functions_in_models():
    statements = body('  input omega [rad/s] = table(t, [0, 1], [0, w]) "servo speed"\n'
                      '  output torque [N*m] = coupling.e "servomotor torque"\n'
                      '  output P = chamber.e\n'
                      '  state x [m] "piston travel" : der(x) = mass.f, x(0) = 0\n'
                      '  state y\n'
                      '  fn g(u) = 2*u')
    inp, torque, pressure, travel, y, g = statements
    assert inp == Input("omega", Unit((UnitFactor("rad", Fraction(1)), UnitFactor("s", Fraction(-1))), "rad/s"),
                        Call("table", (Name("t"), ListExpr((n("0"), n("1"))), ListExpr((n("0"), Name("w"))))),
                        "servo speed")
    assert torque == Output("torque", Unit((UnitFactor("N", Fraction(1)), UnitFactor("m", Fraction(1))), "N*m"),
                            Ref(("coupling", "e")), "servomotor torque")
    assert pressure == Output("P", None, Ref(("chamber", "e")), None)
    assert travel == StateDecl("x", Unit((UnitFactor("m", Fraction(1)),), "m"), "piston travel",
                               (LawCall("der", x, Ref(("mass", "f"))), LawCall("x", n("0"), n("0"))))
    assert y == StateDecl("y", None, None, ())
    assert g == FnDef("g", ("u",), Binary("*", n("2"), Name("u")))


def test_experiments_with_settings_and_overrides():
    (experiment,) = body('  experiment cycle "up and down"\n    t_end = 3.6 [s]\n    solver = "Radau"\n'
                         '    outputs = [torque, power]\n    param Ae = 6.0e-5 [m^2]\n'
                         '    input omega = csv("data/omega.csv", "omega")\n  end')
    assert experiment.name == "cycle" and experiment.description == "up and down"
    t_end, solver, outputs, param, inp = experiment.body
    assert t_end == Setting("t_end", n("3.6"), Unit((UnitFactor("s", Fraction(1)),), "s"))
    assert solver == Setting("solver", Str("Radau"), None)
    assert outputs == Setting("outputs", ListExpr((Name("torque"), Name("power"))), None)
    assert param == Param("Ae", n("6.0e-5"), Unit((UnitFactor("m", Fraction(2)),), "m^2"), None)
    assert inp == Input("omega", None, Call("csv", (Str("data/omega.csv"), Str("omega"))), None)


def test_statement_spans():
    (param,) = body("  param lead = 5.0 [mm]")
    assert (param.span.line, param.span.column) == (2, 3)
    assert (param.name_span.line, param.name_span.column, param.name_span.end_column) == (2, 9, 13)
    assert (param.unit.span.column, param.unit.factors[0].span.column) == (20, 21)


# ------------------------------------------------------------------ units

@pytest.mark.parametrize("text, expected, canonical", [
    ("kg*m^2", [("kg", 1), ("m", 2)], "kg*m^2"),
    ("N*m/rad", [("N", 1), ("m", 1), ("rad", -1)], "N*m/rad"),
    ("1/s", [("1", 1), ("s", -1)], "1/s"),
    ("m/s^2", [("m", 1), ("s", -2)], "m/s^2"),
    ("m^-1", [("m", -1)], "m^-1"),
    ("m^+2", [("m", 2)], "m^+2"),
    ("N/m*s", [("N", 1), ("m", -1), ("s", 1)], "N/m*s"),
    ("kg/(m*s^2)", [("kg", 1), ("m", -1), ("s", -2)], "kg/(m*s^2)"),
    ("m^(1/2)", [("m", Fraction(1, 2))], "m^(1/2)"),
    ("Hz^(-3/2)", [("Hz", Fraction(-3, 2))], "Hz^(-3/2)"),
    ("(N*m)^2", [("N", 2), ("m", 2)], "(N*m)^2"),
    ("1", [("1", 1)], "1"),
    (" N * m\n / rad ", [("N", 1), ("m", 1), ("rad", -1)], "N*m/rad"),
    ("N *  # newton\n m", [("N", 1), ("m", 1)], "N*m"),
])
def test_units_are_flattened(text, expected, canonical):
    (param,) = body(f"  param k = 1 [{text}]")
    assert factors(param.unit) == [(name, Fraction(exponent)) for name, exponent in expected]
    # the text is layout-free, so differently spaced units compare equal
    assert param.unit.text == canonical


# ------------------------------------------------------------------ keywords

@pytest.mark.parametrize("text, line, column", [
    ("model M\n  param end = 5\nend\n", 2, 9),
    ("model M\n  param if = 5\nend\n", 2, 9),
    ("model M\n  R then : e = 1\nend\n", 2, 5),
    ("model M\n  output y = a.end\nend\n", 2, 16),
    ("model M\n  input state = 1\nend\n", 2, 9),
    ("fn model(x) = x\n", 1, 4),
    ("fn g(import) = 1\n", 1, 6),
    ("model M\n  a -> else\nend\n", 2, 8),
    ("model M\n  0 j, or\nend\n", 2, 8),
    ("model M\n  param x = 2*and\nend\n", 2, 15),
    ("model fn\nend\n", 1, 7),
    ("model M\n  experiment e\n    not = 1\n  end\nend\n", 3, 5),
])
def test_keywords_are_rejected_as_names(text, line, column):
    with pytest.raises(ParseError) as info:
        parse_text(text, "kw.bg")
    (diagnostic,) = info.value.diagnostics
    assert (diagnostic.code, diagnostic.span.line, diagnostic.span.column) == ("E104", line, column)
    assert "keyword" in diagnostic.message


def test_every_keyword_is_reserved():
    for keyword in sorted(KEYWORDS):
        assert errors(f"model M\n  param {keyword} = 1\nend\n") == [("E104", 2, 9)], keyword


# ------------------------------------------------------------------ syntax errors

@pytest.mark.parametrize("text, code, line, column", [
    ("model M\n  param a = 1 +\nend\n", "E100", 2, 16),
    ("model M\n  R r e = f\nend\n", "E100", 2, 7),
    ("model M\n  x ->\nend\n", "E100", 2, 7),
    ("model M\n  param a = 1 @ 2\nend\n", "E101", 2, 15),
    ("model M\n  param a = 1 $\nend\n", "E101", 2, 15),
    ('model M\n  param a = "abc\nend\n', "E102", 2, 13),
    ("model M\n  param a = 1\n", "E103", 2, 14),
    ("model M\n  experiment e\n    t_end = 1\nend\n", "E103", 4, 4),
    ("model M\n  param end = 1\nend\n", "E104", 2, 9),
])
def test_each_syntax_error_code(text, code, line, column):
    assert errors(text) == [(code, line, column)]


def test_syntax_error_diagnostics_carry_message_and_hint():
    with pytest.raises(ParseError) as info:
        parse_text("model M\n  R r = b*f\nend\n", "bad.bg")
    (diagnostic,) = info.value.diagnostics
    assert diagnostic.code == "E100" and diagnostic.severity == "error"
    assert "unexpected '='" in diagnostic.message and "':'" in diagnostic.message
    assert diagnostic.hint and "':'" in diagnostic.hint
    assert diagnostic.span.file == "bad.bg"
    assert isinstance(info.value, BondcError) and info.value.stage == "parse"


def test_every_syntax_error_is_reported_in_one_run():
    text = ("model M\n"
            "  param a = = 1\n"       # E100 at '='
            "  R r e = f\n"           # E100 at 'e'
            "  param b = 2 $\n"       # E101 at '$'
            "  C c : e = q\n"         # fine
            "  param if = 3\n"        # E104 at 'if'
            '  param s = "open\n'     # E102 at '"'
            "  I i : f = p/m\n"       # fine
            "end\n")
    assert errors(text) == [("E100", 2, 13), ("E100", 3, 7), ("E101", 4, 15), ("E104", 6, 9), ("E102", 7, 13)]


def test_errors_in_two_models_are_all_reported():
    text = "model A\n  param = 1\nend\n\nmodel B\n  R r : e = (f\nend\n"
    found = errors(text)
    assert found[0] == ("E100", 2, 9)
    assert ("E100", 2, 9) in found and any(line >= 6 for _, line, _ in found)


# ------------------------------------------------------------------ --set values

@pytest.mark.parametrize("text, name, value, unit", [
    ("M=40", "M", n("40"), None),
    ("M=40 [kg]", "M", n("40"), [("kg", 1)]),
    ("M = -1e3 [N*m/rad]", "M", Unary("-", n("1e3")), [("N", 1), ("m", 1), ("rad", -1)]),
    ("n=1000 [rpm]", "n", n("1000"), [("rpm", 1)]),
    ("R=2*pi", "R", Binary("*", n("2"), Name("pi")), None),
    ('solver="RK45"', "solver", Str("RK45"), None),
])
def test_parse_set_value(text, name, value, unit):
    parsed = parse_set_value(text)
    assert (parsed.name, parsed.value) == (name, value)
    if unit is None:
        assert parsed.unit is None
    else:
        assert factors(parsed.unit) == [(u, Fraction(e)) for u, e in unit]


@pytest.mark.parametrize("text, code", [("M=", "E100"), ("M=40 kg", "E100"), ("end=3", "E104"),
                                        ("=3", "E100"), ("M=4 @", "E101"), ('M="x', "E102")])
def test_parse_set_value_errors(text, code):
    with pytest.raises(ParseError) as info:
        parse_set_value(text)
    assert [d.code for d in info.value.diagnostics] == [code]
    assert info.value.diagnostics[0].span.file == "--set"


def test_doctests():
    import doctest

    import bondc.ast
    import bondc.parse

    for module in (bondc.parse, bondc.ast):
        result = doctest.testmod(module)
        assert result.attempted and not result.failed, module.__name__


def test_an_if_operand_needs_parentheses():
    with pytest.raises(ParseError) as info:
        parse_text("model M\n  param x = 1 + if a then b else c\nend\n", "m.bg")
    (diagnostic,) = info.value.diagnostics
    assert (diagnostic.code, diagnostic.span.line, diagnostic.span.column) == ("E100", 2, 17)
    assert "parentheses" in diagnostic.hint


def test_the_parser_tables_are_kept_in_the_cache_folder_and_a_damaged_file_is_rebuilt(tmp_path, monkeypatch):
    """The LALR tables are built once and loaded from bondc's cache folder afterwards; a damaged
    or unwritable cache never stops a parse."""
    from bondc import parse as parse_module

    text = "model M\n  I mass : f = p/m\nend\n"
    expected = parse_module.parse_text(text, "m.bg")
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path / "cache"))
    try:
        parse_module._parser.cache_clear()
        assert parse_module.parse_text(text, "m.bg") == expected
        (kept,) = (tmp_path / "cache" / "parser").iterdir()
        assert kept.suffix == ".lark" and kept.stat().st_size > 1000
        written, stamp = kept.read_bytes(), kept.stat().st_mtime_ns
        parse_module._parser.cache_clear()
        assert parse_module.parse_text(text, "m.bg") == expected            # loaded
        # loaded, not built and written again (lark rewrites a file whose check fails: one written
        # under another name and renamed into place was never loaded)
        assert kept.read_bytes() == written and kept.stat().st_mtime_ns == stamp
        kept.write_bytes(b"not a parser")
        parse_module._parser.cache_clear()
        assert parse_module.parse_text(text, "m.bg") == expected            # rebuilt
        monkeypatch.setenv("BONDC_CACHE_DIR", str(kept))                    # a file, not a folder
        parse_module._parser.cache_clear()
        assert parse_module.parse_text(text, "m.bg") == expected
    finally:
        parse_module._parser.cache_clear()


def test_spans_are_the_positions_of_their_ends():
    """Source.span (which looks the end's line up only when it differs from the start's) gives each
    end's 1-based line and column, offsets outside the text clamped to it, as position() does."""
    import random

    from bondc.source import Source

    rng = random.Random(11)
    for _ in range(50):
        text = "".join(rng.choice("ab \n\n") for _ in range(rng.randrange(0, 60)))
        source = Source("t.bg", text)
        lines = text.split("\n")
        for _ in range(40):
            start, end = sorted(rng.randrange(-3, len(text) + 4) for _ in range(2))
            span = source.span(start, end)
            for offset, (line, column) in ((start, (span.line, span.column)), (end, (span.end_line, span.end_column))):
                clamped = max(0, min(offset, len(text)))
                before = text[:clamped].split("\n")
                assert (line, column) == (len(before), len(before[-1]) + 1) == source.position(offset)
            assert (span.start, span.end) == (start, end) and len(lines) == len(source._line_starts)


def test_an_unclosed_bracket_is_named_where_it_opened_and_nothing_after_it_is_reported():
    # inside [ ] the statement goes on over the line break: the error is at the next line's first
    # token, and every line after would be reported again
    text = "model U\n  param m = 2 [kg\n  param k = 3\n  Se s : e = k\n  R r : e = m*f\n  s -> r\nend\n"
    with pytest.raises(ParseError) as caught:
        parse_text(text, "u.bg")
    (diagnostic,) = caught.value.diagnostics
    assert (diagnostic.code, diagnostic.span.line, diagnostic.span.column) == ("E100", 3, 3)
    assert "the '[' on line 2 is not closed" in diagnostic.hint and "']'" in diagnostic.hint
    (related,) = diagnostic.related
    assert (related.span.line, related.span.column) == (2, 15)
    # a bracket closed on its own line is not blamed
    with pytest.raises(ParseError) as caught:
        parse_text("model U\n  param m = (2 + 3]\nend\n", "u.bg")
    assert all(not d.related for d in caught.value.diagnostics)


def test_a_byte_order_mark_at_the_start_of_a_file_is_not_text(tmp_path):
    """Windows editors save UTF-8 with a byte-order mark; it was E101 'unexpected character' and four
    E100 on valid lines after it. The file is the same model as without it, its columns too."""
    from bondc.cli import main

    text = "model M\n  Se s : e = 1\n  I m : f = p\n  s -> m\nend\n"
    marked, plain = tmp_path / "marked.bg", tmp_path / "plain.bg"
    marked.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    plain.write_text(text, encoding="utf-8")
    assert main(["check", str(marked)]) == 0
    broken = text.replace("= 1", "= 1 +")
    spans = []
    for version in ("\ufeff" + broken, broken):
        with pytest.raises(ParseError) as excinfo:
            parse_text(version, "marked.bg")
        [diagnostic] = excinfo.value.diagnostics
        spans.append((diagnostic.code, diagnostic.span.line, diagnostic.span.column))
    assert spans[0] == spans[1] == ("E100", 2, 17)


WHEN_BLOCK = """model M
  discrete u [1] = 0
  Se s : e = u
  I m : f = p
  s -> m
  HEADER
    u = 1,
    BODY
  end
  experiment run
    t_end = 1 [s]
  end
end
"""


@pytest.mark.parametrize("header, body, line, column, words", [
    ("when t = 0.5 then", "u = 2", 6, 10, "'=='"),            # = for == in the condition
    ("when t > 0.5", "u = 2", 6, 15, "expected 'then'"),      # no then
    ("when t > 0.5 then", "u = if t > 1 then 2", 8, 24, "expected 'else'"),
    ("when t > 0.5 then", "u = 5 [V]", 8, 11, "unexpected '['"),
    ("when t > 0.5 then", "u + 1", 8, 7, "unexpected '+'"),
])
def test_one_slip_in_a_when_block_is_one_error(header, body, line, column, words):
    """An error in a when block's header or statements was followed by three more: its statements
    read as elements, its 'end' closing the model, then 'experiment' outside any model, twice."""
    with pytest.raises(ParseError) as excinfo:
        parse_text(WHEN_BLOCK.replace("HEADER", header).replace("BODY", body), "when.bg")
    (diagnostic,) = excinfo.value.diagnostics
    assert (diagnostic.span.line, diagnostic.span.column) == (line, column)
    assert words in diagnostic.message + (diagnostic.hint or "")


FORGOTTEN_END = """model W
  discrete d = 0
  C s : e = 10*q, q(0) = 1
  I m : f = p
  1 j
  j -> s
  j -> m
  BLOCK
  NEXT
  output x = s.q
  experiment e1
    t_end = 1
  end
end
"""


@pytest.mark.parametrize("block, next_line", [
    ("when s.q > 0.5 then\n    d = 1", "when s.q < 0.2 then d = 0 end"),      # a block without its end
    ("when s.q > 0.5 then d = 1", "output y = 2*s.q"),                       # a one-line block without it
    ("when s.q > 0.5 then\n    d = 1", "R r : e = 2*f"),                     # an element after it
    ("when s.q > 0.5 then\n    d = 1", "j -> r"),                            # a bond after it
])
def test_a_when_block_without_its_end_is_one_error_at_the_statement_it_runs_into(block, next_line):
    """A forgotten 'end' gave two or three errors (the next 'when' unexpected, then 'output' and
    'experiment' read as names in the block): it is one, naming the block's line."""
    text = FORGOTTEN_END.replace("BLOCK", block).replace("NEXT", next_line)
    with pytest.raises(ParseError) as excinfo:
        parse_text(text, "w.bg")
    (diagnostic,) = excinfo.value.diagnostics
    line = text.split("\n").index("  " + next_line) + 1
    assert (diagnostic.code, diagnostic.span.line, diagnostic.span.column) == ("E100", line, 3)
    assert "the 'when' block of line 8 is not closed" in diagnostic.message and "'end'" in diagnostic.hint
    (related,) = diagnostic.related
    assert (related.span.line, related.span.column) == (8, 3)


def test_a_bracket_left_open_on_its_own_line_is_named_in_the_one_error():
    # the statement's later 'then' was reported, then the end of the file (the bracket joined every line)
    text = FORGOTTEN_END.replace("BLOCK", "when (s.q > 0.5 then d = 1 end").replace("NEXT", "")
    with pytest.raises(ParseError) as excinfo:
        parse_text(text, "w.bg")
    (diagnostic,) = excinfo.value.diagnostics
    assert (diagnostic.span.line, diagnostic.span.column) == (8, 19)
    assert "the '(' at column 8 is not closed" in diagnostic.hint
    assert [(r.span.line, r.span.column) for r in diagnostic.related] == [(8, 8)]
