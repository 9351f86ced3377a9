"""``bondc fmt``: canonical layout, round trip and idempotence on every model we have.

For every ``.bg`` file under ``models/`` and ``tests/``: ``parse(fmt(x)) == parse(x)``
(AST equality ignores spans but compares comments, in order) and
``fmt(fmt(x)) == fmt(x)``. Every one of them must parse: the golden cases of
semantic and later-stage errors are syntactically valid.

The golden test formats ``tests/golden/fmt/<name>.bg`` and compares with the
reviewed ``<name>.formatted.bg``; run with ``BONDC_UPDATE_GOLDEN=1`` (or
``--update-golden`` where conftest.py provides it) to rewrite the expected file.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

import pytest

from bondc import ast
from bondc.errors import ParseError
from bondc.fmt import MAX_WIDTH, fmt, format_expr, format_file, format_path
from bondc.io import atomic_write_text
from bondc.parse import parse_set_value, parse_text

ROOT = Path(__file__).resolve().parent.parent


def _bg_files(folder: Path) -> list[Path]:
    return sorted(folder.rglob("*.bg"))


MODELS = _bg_files(ROOT / "models")
TEST_FILES = _bg_files(ROOT / "tests")
GOLDEN = ROOT / "tests" / "golden" / "fmt"
GOLDEN_INPUTS = sorted(p for p in GOLDEN.glob("*.bg") if not p.name.endswith(".formatted.bg"))


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def assert_round_trip(text: str, name: str = "<text>") -> str:
    """fmt keeps the meaning and the comments, and is a fixed point; returns fmt(text)."""
    original = parse_text(text, name)
    formatted = format_file(original, text)
    again = parse_text(formatted, name)
    assert again == original, f"{name}: formatting changed the AST"
    assert [c.text for c in again.comments] == [c.text for c in original.comments]
    assert format_file(again, formatted) == formatted, f"{name}: fmt is not idempotent"
    return formatted


def _update_golden(request) -> bool:
    return bool(os.environ.get("BONDC_UPDATE_GOLDEN")) or bool(
        request.config.getoption("--update-golden", default=False))


# ------------------------------------------------------------------ corpus

@pytest.mark.parametrize("path", MODELS, ids=_id)
def test_models_round_trip(path):
    # Every shipped model must parse: a ParseError here is a real failure.
    assert_round_trip(path.read_text(encoding="utf-8"), str(path))


@pytest.mark.parametrize("path", TEST_FILES, ids=_id)
def test_test_files_round_trip(path):
    # Every .bg under tests/ parses, the semantic and stage goldens included (their errors come later).
    assert_round_trip(path.read_text(encoding="utf-8"), str(path))


def _language_examples() -> list[tuple[str, str]]:
    """The code blocks of docs/language.md, fragments wrapped in a model so they parse."""
    examples = []
    doc = ROOT / "docs" / "language.md"
    if not doc.exists():
        return examples
    blocks = re.findall(r"```[a-z]*\n(.*?)```", doc.read_text(encoding="utf-8"), re.S)
    for index, block in enumerate(blocks):
        for candidate in (block, f"model Example\n{block}end\n", f"model Example\n{block.replace('...', 'x')}end\n"):
            try:
                parse_text(candidate)
            except ParseError:
                continue
            examples.append((f"block{index}", candidate))
            break
    return examples


@pytest.mark.parametrize("name, text", _language_examples())
def test_language_reference_examples_round_trip(name, text):
    assert_round_trip(text, name)


# ------------------------------------------------------------------ golden

@pytest.mark.parametrize("path", GOLDEN_INPUTS, ids=_id)
def test_golden(path, request):
    expected_path = path.with_name(path.name[: -len(".bg")] + ".formatted.bg")
    formatted = assert_round_trip(path.read_text(encoding="utf-8"), str(path))
    if _update_golden(request):
        expected_path.write_text(formatted, encoding="utf-8")
    assert expected_path.exists(), f"{_id(expected_path)} is missing: run with BONDC_UPDATE_GOLDEN=1 and review it"
    assert formatted == expected_path.read_text(encoding="utf-8")


def test_golden_inputs_exist():
    assert GOLDEN_INPUTS, "tests/golden/fmt/ has no input model"


# ------------------------------------------------------------------ expressions

@pytest.mark.parametrize("text, canonical", [
    ("a^b^c", "a^b^c"),
    ("a^(b^c)", "a^b^c"),
    ("(a^b)^c", "(a^b)^c"),
    ("-x^2", "-x^2"),
    ("-(x^2)", "-x^2"),
    ("(-x)^2", "(-x)^2"),
    ("2^-1", "2^-1"),
    ("2^(-1)", "2^-1"),
    ("a^-b^c", "a^-b^c"),
    ("a - (b - c)", "a - (b - c)"),
    ("(a - b) - c", "a - b - c"),
    ("a + (b + c)", "a + (b + c)"),
    ("a / (b * c)", "a/(b*c)"),
    ("(a * b) / c", "a*b/c"),
    ("a * (b + c)", "a*(b + c)"),
    ("-(a + b)", "-(a + b)"),
    ("-(-x)", "-(-x)"),
    ("- -x", "-(-x)"),
    ("a - -b", "a - -b"),
    ("a*(-b)", "a*-b"),
    ("(a < b) == (c < d)", "(a < b) == (c < d)"),
    ("(a + b) < c", "a + b < c"),
    ("a < b and not c or d", "a < b and not c or d"),
    ("(a and b) or c", "a and b or c"),
    ("a and (b or c)", "a and (b or c)"),
    ("not (a and b)", "not (a and b)"),
    ("(not a) and b", "not a and b"),
    ("not (a < b)", "not a < b"),
    ("-(not a)", "-(not a)"),
    ("(not a) < b", "(not a) < b"),
    ("if a then b else c", "if a then b else c"),
    ("(if a then b else c) + 1", "(if a then b else c) + 1"),
    ("1 + (if a then b else c)", "1 + (if a then b else c)"),
    ("2*(if a then b else c)", "2*(if a then b else c)"),
    ("-(if a then b else c)", "-(if a then b else c)"),
    ("if a then b else (if c then d else e)", "if a then b else if c then d else e"),
    ("f((a), [(b), (c + d)])", "f(a, [b, c + d])"),
    ("f(if a then b else c, d)", "f(if a then b else c, d)"),
    ("(mass.f)^2", "mass.f^2"),
    ("1.50e-3*x", "1.50e-3*x"),
    (".5 + 1.", ".5 + 1."),
    ('"a\\"b\\\\c"', '"a\\"b\\\\c"'),
])
def test_expressions_print_with_minimal_parentheses(text, canonical):
    tree = parse_set_value(f"x = {text}").value
    assert format_expr(tree) == canonical
    assert parse_set_value(f"x = {canonical}").value == tree


def test_format_expr_rejects_unknown_nodes():
    with pytest.raises(TypeError, match="unsupported"):
        format_expr(object())


# ------------------------------------------------------------------ layout

# The complete model of LANGUAGE.md section 10, shared with the language-example tests.
SMALL = (Path(__file__).parent / "fixtures" / "language" / "s10_complete_model.bg").read_text(encoding="utf-8")


def test_reference_model_is_nearly_canonical():
    # LANGUAGE.md section 10, as written there, only differs in one product's spacing
    assert fmt(SMALL) == SMALL.replace("step(t, 0.1) * 10", "step(t, 0.1)*10")


def test_messy_layout_is_normalised():
    text = ("model  M\n"
            "      param  a=1   [ N * m / rad ]\n"
            "  param long_name = (2)\n"
            "\tR r:e=b*f\n"
            "  MSe   src \"a source\"   :  e=1\n"
            "  0 j1 ,j2\n"
            "  b1 : src->j1 -> r.p1\n"
            "end")
    assert fmt(text) == ("model M\n"
                         "  param a         = 1 [N*m/rad]\n"
                         "  param long_name = 2\n"
                         "  R   r              : e = b*f\n"
                         '  MSe src "a source" : e = 1\n'
                         "  0   j1, j2\n"
                         "  b1: src -> j1 -> r.p1\n"
                         "end\n")


def test_blank_lines_are_kept_as_at_most_one():
    text = "\n\nmodel M\n\n\n  param a = 1\n\n\n\n  param b = 2\n  param c = 3\n\n\nend\n\n\nmodel N\nend\n\n\n"
    assert fmt(text) == "model M\n  param a = 1\n\n  param b = 2\n  param c = 3\nend\n\nmodel N\nend\n"


def test_a_blank_line_separates_alignment_runs():
    text = "model M\n  param a = 1\n  param bb = 2\n\n  param ccc = 3\nend\n"
    assert fmt(text) == "model M\n  param a  = 1\n  param bb = 2\n\n  param ccc = 3\nend\n"


def test_inputs_outputs_and_settings_align():
    text = ('model M\n  input omega [rad/s] = w\n  output torque [N*m] = c.e "torque"\n  output x = s.q\n'
            '  experiment e\n    t_end = 2 [s]\n    max_step = 1 [ms]\n  end\nend\n')
    assert fmt(text) == ("model M\n"
                         "  input  omega  [rad/s] = w\n"
                         '  output torque [N*m]   = c.e "torque"\n'
                         "  output x              = s.q\n"
                         "  experiment e\n"
                         "    t_end    = 2 [s]\n"
                         "    max_step = 1 [ms]\n"
                         "  end\n"
                         "end\n")


def test_bond_chains_stay_chains_one_per_line():
    text = "model M\n  a->b->c.p1\n  lbl:c.p2->d\nend\n"
    assert fmt(text) == "model M\n  a -> b -> c.p1\n  lbl: c.p2 -> d\nend\n"


def test_strings_and_numbers_are_kept():
    text = 'model M "say \\"hi\\" \\\\ bye"\n  param a = 1.50E+03 "t\\tab"\nend\n'
    formatted = assert_round_trip(text)
    assert 'model M "say \\"hi\\" \\\\ bye"' in formatted and "1.50E+03" in formatted
    assert parse_text(formatted).models[0].body[0].description == "t\tab"


def test_long_laws_continue_after_a_comma():
    laws = ", ".join(f"der(x{i}) = alpha_{i}*x{i} + beta_{i}" for i in range(8))
    text = f"model M\n  state x \"many laws\" : {laws}\nend\n"
    formatted = assert_round_trip(text)
    lines = formatted.splitlines()
    assert len(lines) > 3
    assert all(len(line) <= MAX_WIDTH for line in lines)
    assert all(line.endswith(",") for line in lines[1:-2])
    assert all(line.startswith("      der(") for line in lines[2:-1])  # statement indent + 4


def test_long_expressions_continue_inside_brackets():
    points = ", ".join(str(i / 10) for i in range(60))
    text = f"model M\n  input u = table(t, [{points}], [{points}]) \"a long table\"\nend\n"
    formatted = assert_round_trip(text)
    assert all(len(line) <= MAX_WIDTH for line in formatted.splitlines())


def test_a_line_that_cannot_be_broken_is_left_long():
    name = "x" * 120
    formatted = assert_round_trip(f"model M\n  param {name} = 1\nend\n")
    assert f"param {name} = 1" in formatted


# ------------------------------------------------------------------ comments

def test_comments_keep_their_places():
    text = ("# file header\n"
            "\n"
            "model M # the model\n"
            "  # before a\n"
            "  param a = 1 # after a\n"
            "  param b = 2\n"
            "\n"
            "  # before end\n"
            "end # after end\n"
            "# trailing\n")
    assert fmt(text) == ("# file header\n"
                         "\n"
                         "model M  # the model\n"
                         "  # before a\n"
                         "  param a = 1  # after a\n"
                         "  param b = 2\n"
                         "\n"
                         "  # before end\n"
                         "end  # after end\n"
                         "# trailing\n")


def test_trailing_comments_align_in_a_run():
    text = "model M\n  param a = 1 # one\n  param bbb = 22 # two\n  param c = 3\n  param d = 4   # four\nend\n"
    assert fmt(text) == ("model M\n"
                         "  param a   = 1   # one\n"
                         "  param bbb = 22  # two\n"
                         "  param c   = 3\n"
                         "  param d   = 4   # four\n"
                         "end\n")


def test_comments_between_laws_stay_between_laws():
    text = ("model M\n"
            "  C spring : e = k*q,   # linear\n"
            "     # the preload\n"
            "     q(0) = 0.01 # metres\n"
            "end\n")
    assert fmt(text) == ("model M\n"
                         "  C spring : e = k*q,  # linear\n"
                         "      # the preload\n"
                         "      q(0) = 0.01  # metres\n"
                         "end\n")


def test_comments_inside_an_expression_move_before_the_statement():
    text = ("model M\n"
            "  param x = 1\n"
            "\n"
            "  input u = table(t, [0,   # times\n"
            "                      1], [a, b]) # values\n"
            "  R r : e = f(a,  # inside a law\n"
            "     b),  # after it\n"
            "     f = 1\n"
            "end\n")
    formatted = assert_round_trip(text)
    assert formatted == ("model M\n"
                         "  param x = 1\n"
                         "\n"
                         "  # times\n"
                         "  input u = table(t, [0, 1], [a, b])  # values\n"
                         "  # inside a law\n"
                         "  # after it\n"
                         "  R r : e = f(a, b), f = 1\n"
                         "end\n")


def test_comments_in_units_and_experiments_are_kept():
    text = ("model M\n"
            "  param k = 1 [N *  # newton\n"
            "   m]\n"
            "  experiment e  # exp\n"
            "    # settings\n"
            "    t_end = 1 [s]  # one second\n"
            "    # nothing more\n"
            "  end  # exp end\n"
            "end\n")
    formatted = assert_round_trip(text)
    assert formatted == ("model M\n"
                         "  # newton\n"
                         "  param k = 1 [N*m]\n"
                         "  experiment e  # exp\n"
                         "    # settings\n"
                         "    t_end = 1 [s]  # one second\n"
                         "    # nothing more\n"
                         "  end  # exp end\n"
                         "end\n")


@pytest.mark.parametrize("text", [
    "",
    "\n\n",
    "# only a comment",
    "# a\n\n\n# b\n",
    "model M\nend",
    "model M\r\n  param a = 1  # crlf\r\nend\r\n",
    "model A\nend\nmodel B\nend\n",
    "fn f(x) = x\nfn g() = 1 # g\n",
    "model M\n  fn h(u, v) = u*v \"product\"\n  state y\n  R r\nend\n",
])
def test_edge_cases_round_trip(text):
    assert_round_trip(text)


def test_format_file_needs_no_source_text():
    text = SMALL.replace("  j -> mass\n", "  j -> mass  # inertia\n")
    assert format_file(parse_text(text)) == format_file(parse_text(text), text) == fmt(text)


def test_format_file_on_a_tree_built_by_hand():
    model = ast.Model("M", None, (ast.Param("a", ast.Num(1.0, "1"), None, None),))
    assert format_file(ast.File((model,))) == "model M\n  param a = 1\nend\n"


def test_fmt_reports_syntax_errors():
    with pytest.raises(ParseError):
        fmt("model M\n  param = 1\nend\n")


# ------------------------------------------------------------------ files

def test_format_path_and_atomic_write(tmp_path):
    path = tmp_path / "m.bg"
    path.write_text("model M\n  param a=1\nend\n", encoding="utf-8")
    path.chmod(0o640)
    original, formatted = format_path(path)
    assert original == "model M\n  param a=1\nend\n"
    assert formatted == "model M\n  param a = 1\nend\n"
    atomic_write_text(path, formatted)
    assert path.read_text(encoding="utf-8") == formatted
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.bg"]  # no temporary file left
    assert format_path(path) == (formatted, formatted)


def test_atomic_write_creates_a_new_file(tmp_path):
    path = tmp_path / "new.bg"
    atomic_write_text(path, "model N\nend\n")
    assert path.read_text(encoding="utf-8") == "model N\nend\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.bg"]


def test_atomic_write_leaves_no_temporary_file_on_failure(tmp_path):
    path = tmp_path / "m.bg"
    path.write_text("old", encoding="utf-8")
    with pytest.raises(TypeError):
        atomic_write_text(path, None)
    assert path.read_text(encoding="utf-8") == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.bg"]


def test_format_path_reports_syntax_errors_with_the_path(tmp_path):
    path = tmp_path / "bad.bg"
    path.write_text("model M\n  param = 1\nend\n", encoding="utf-8")
    with pytest.raises(ParseError) as info:
        format_path(path)
    assert info.value.diagnostics[0].span.file == str(path)


def test_long_if_chains_break_before_else():
    text = ("model M\n"
            "  R friction : e = if abs(f) < v_threshold then c0*f else if f > 0 then a_up*abs(f)^(1 + n_up)*sign(f)"
            " else a_down*abs(f)^(1 + n_down)*sign(f)\n"
            "end\n")
    assert assert_round_trip(text) == (
        "model M\n"
        "  R friction : e = (if abs(f) < v_threshold then c0*f\n"
        "      else if f > 0 then a_up*abs(f)^(1 + n_up)*sign(f)\n"
        "      else a_down*abs(f)^(1 + n_down)*sign(f))\n"
        "end\n")


def test_function_parameters_are_not_broken():
    text = ("fn valve(ps, pc, area, kappa, gas_constant, temperature) = orifice(ps, pc, area, kappa, "
            "gas_constant, temperature)*correction(ps, pc)\n")
    formatted = assert_round_trip(text)
    assert formatted.splitlines()[0].startswith("fn valve(ps, pc, area, kappa, gas_constant, temperature) = ")
    assert all(len(line) <= MAX_WIDTH for line in formatted.splitlines())


def test_short_if_laws_stay_on_one_line():
    text = "model M\n  R r : e = 1, f = if a then b else c\nend\n"
    assert assert_round_trip(text) == text


def test_doctests():
    import doctest

    import bondc.fmt
    import bondc.io

    for module in (bondc.fmt, bondc.io):
        result = doctest.testmod(module)
        assert result.attempted and not result.failed, module.__name__


@pytest.mark.parametrize("path", sorted((Path(__file__).parent.parent / "models").glob("*.bg"))
                         + sorted((Path(__file__).parent.parent / "bondc" / "std").glob("*.bg")), ids=_id)
def test_shipped_models_and_libraries_are_formatted(path):
    # `bondc fmt --check` passes on every model in models/ and every std: library
    text = path.read_text(encoding="utf-8")
    assert fmt(text, str(path)) == text
