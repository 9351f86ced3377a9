"""Syntax highlighting of ``.bg`` source for reports: text -> HTML.

:class:`BgLexer` is a Pygments ``RegexLexer`` for the language of
``docs/language.md``; :func:`highlight_bg` turns a model's text into an HTML
``<pre>`` block (CSS classes, no inline styles) and :func:`lexer_css` returns
the matching style sheet, scoped to ``.bg-source``, for the report to inline.

Two rules of the language need context a plain keyword list cannot give:

- element kinds (``Se Sf MSe MSf R C I TF GY MTF MGY``) and junction kinds
  (``0``, ``1``) are keywords only at the start of a statement, where they are
  followed by a name, so ``param R = 3`` and ``2*C`` stay names and numbers;
- ``[ ]`` after a value (a number, a name or ``)``) is a unit, but ``[`` after
  ``(``, ``,`` or ``=`` starts a list (``table(t, [0, 1], [0, w])``).

Every character of the input reaches the output escaped, so a ``<script>``
in a string or comment is shown, never run.

>>> from pygments.token import Keyword, Name
>>> [(t, v) for t, v in BgLexer().get_tokens("R damper : e = R*f\\n") if v.strip()][:3]
[(Token.Keyword.Type, 'R'), (Token.Name.Entity, 'damper'), (Token.Punctuation, ':')]
"""

from __future__ import annotations

from markupsafe import Markup
from pygments import highlight
from pygments.formatters import HtmlFormatter
from pygments.lexer import RegexLexer, bygroups, default, words
from pygments.style import Style
from pygments.token import (
    Comment,
    Error,
    Keyword,
    Name,
    Number,
    Operator,
    Punctuation,
    String,
    Token,
    Whitespace,
)

from bondc.builtins import BUILTINS as LANGUAGE_BUILTINS
from bondc.kinds import JUNCTION_KINDS, NAMES_LONGEST_FIRST

__all__ = ["BgLexer", "BgStyle", "UNIT", "highlight_bg", "lexer_css", "CSS_SCOPE"]

KEYWORDS = ("model", "end", "param", "input", "output", "state", "fn", "experiment",
            "import", "if", "then", "else", "port", "defaults", "discrete", "when")
WORD_OPERATORS = ("and", "or", "not")
ELEMENT_KINDS = NAMES_LONGEST_FIRST
# longest first, so that atan2 is not read as atan
BUILTINS = tuple(sorted(LANGUAGE_BUILTINS, key=lambda name: (-len(name), name))) + ("der",)

#: Token type of a unit in brackets, ``[N*m/rad]`` (a subtype of ``Literal``,
#: so any Pygments style still colours it).
UNIT = Token.Literal.Unit

#: The CSS class of the ``<div>`` that :func:`highlight_bg` wraps the code in.
CSS_SCOPE = "bg-source"

_NAME = r"[A-Za-z_][A-Za-z0-9_]*"


class BgLexer(RegexLexer):
    """Pygments lexer for bondc's ``.bg`` bond-graph models."""

    name = "bondc bond graph"
    aliases = ["bg", "bondc"]
    filenames = ["*.bg"]
    mimetypes = ["text/x-bondc"]

    tokens = {
        "root": [
            # Statement starts come first: they must see the line's indentation,
            # which the whitespace rule below would otherwise swallow.
            (r"^([ \t]*)(%s)([ \t]+)(%s)" % ("|".join(ELEMENT_KINDS), _NAME),
             bygroups(Whitespace, Keyword.Type, Whitespace, Name.Entity)),
            (r"^([ \t]*)([01])([ \t]+)(%s)" % _NAME,
             bygroups(Whitespace, Keyword.Type, Whitespace, Name.Entity), "junction"),
            (r"^([ \t]*)(model|experiment)([ \t]+)(%s)" % _NAME,
             bygroups(Whitespace, Keyword.Declaration, Whitespace, Name.Class)),
            (r"^([ \t]*)(fn)([ \t]+)(%s)" % _NAME,
             bygroups(Whitespace, Keyword.Declaration, Whitespace, Name.Function)),
            (r"^([ \t]*)(%s)([ \t]*)(:)" % _NAME,
             bygroups(Whitespace, Name.Label, Whitespace, Punctuation)),
            (r"\n", Whitespace),
            (r"[ \t\f\r]+", Whitespace),
            (r"#.*?$", Comment.Single),
            (r'"', String.Double, "string"),
            (r"->", Operator),
            (r"<=|>=|==|!=|<|>|=|\+|-|\*|/|\^", Operator),
            (words(WORD_OPERATORS, suffix=r"\b"), Operator.Word),
            (words(KEYWORDS, suffix=r"\b"), Keyword),
            # A built-in is a built-in where it is called; a parameter may share its name.
            (r"(%s)(?=[ \t]*\()" % "|".join(BUILTINS), Name.Builtin),
            (r"pi\b", Name.Builtin.Pseudo, "after_value"),
            (_NAME, Name, "after_value"),
            (r"(?:\d+\.\d*|\.\d+)(?:[eE][+-]?\d+)?|\d+[eE][+-]?\d+", Number.Float, "after_value"),
            (r"\d+", Number.Integer, "after_value"),
            (r"\)", Punctuation, "after_value"),
            (r"[(\[\],:.]", Punctuation),
        ],
        # After a value, a bracket is a unit: `31.7 [kg]`, `omega [rad/s]`, `(...) [m^2]`.
        # Units never hold commas, so `[0, t1]` can never be taken for one.
        "after_value": [
            (r"([ \t]*)(\[[^\]\[,\n#\"]*\])", bygroups(Whitespace, UNIT), "#pop"),
            default("#pop"),
        ],
        # `0 j_a, j_b`: further junction names on the same line.
        "junction": [
            (r"([ \t]*)(,)([ \t]*)(%s)" % _NAME,
             bygroups(Whitespace, Punctuation, Whitespace, Name.Entity)),
            default("#pop"),
        ],
        "string": [
            (r'\\.', String.Escape),
            (r'[^"\\\n]+', String.Double),
            (r'"', String.Double, "#pop"),
            # An unterminated string ends at the end of its line, as the parser says.
            (r"\n", Whitespace, "#pop"),
        ],
    }


class BgStyle(Style):
    """A light, print-friendly colour scheme for model listings."""

    name = "bondc"
    background_color = "#fbfbfa"
    highlight_color = "#fff3c4"
    line_number_color = "#9a9a9a"
    line_number_background_color = "transparent"

    styles = {
        Token: "#1f2328",
        Whitespace: "",
        Comment: "italic #6a737d",
        Keyword: "bold #8250df",
        Keyword.Declaration: "bold #8250df",
        Keyword.Type: "bold #0550ae",
        Operator: "#57606a",
        Operator.Word: "bold #8250df",
        Punctuation: "#57606a",
        Name: "#1f2328",
        Name.Builtin: "#953800",
        Name.Builtin.Pseudo: "#953800",
        Name.Entity: "bold #116329",
        Name.Class: "bold #1f2328",
        Name.Function: "bold #1f2328",
        Name.Label: "#6639ba",
        Number: "#0a3069",
        String: "#0a6e62",
        String.Escape: "bold #0a6e62",
        UNIT: "#9a6700",
        Error: "#cf222e underline",
    }


def _formatter(linenos: bool = True) -> HtmlFormatter:
    return HtmlFormatter(style=BgStyle, cssclass=CSS_SCOPE, noclasses=False,
                         linenos="inline" if linenos else False, wrapcode=True)


def highlight_bg(text: str, linenos: bool = True) -> Markup:
    """The HTML of a ``.bg`` listing: ``<div class="bg-source"><pre>...</pre></div>``.

    Every source character is HTML-escaped by Pygments, so the result is safe
    to insert into a report as it is (it is returned as ``Markup``).

    >>> html = highlight_bg('model M "<b>"\\nend\\n', linenos=False)
    >>> "&lt;b&gt;" in html and "<b>" not in html
    True
    """
    return Markup(highlight(text, BgLexer(), _formatter(linenos)))


def lexer_css() -> str:
    """The CSS rules for :func:`highlight_bg` output, scoped to ``.bg-source``.

    Pygments leaves its ``pre`` and line-number rules unscoped; they are scoped
    here so they cannot restyle the rest of a report.
    """
    scope = "." + CSS_SCOPE
    lines = []
    for line in _formatter().get_style_defs(scope).splitlines():
        if not line.startswith(scope):
            line = f"{scope} {line}"
        lines.append(line)
    lines.append(f"{scope} .linenos {{ user-select: none; }}")
    return "\n".join(lines) + "\n"
