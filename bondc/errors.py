"""Diagnostics, typed errors per stage, and the one renderer of source context.

Every stage reports problems as :class:`Diagnostic` values (a stable code, a
message, the span it is about, related spans and a hint) and collects them, so
one run reports every problem it can. A stage that cannot go on raises the
:class:`BondcError` subclass named after it, carrying all its diagnostics.

>>> from bondc.source import Source
>>> src = Source("m.bg", "param M = 31.7 [kgg]\\n")
>>> d = Diagnostic("error", "E201", "unknown unit 'kgg'", src.span(16, 19), hint="did you mean 'kg'?")
>>> print(render(d, {"m.bg": src}))
m.bg:1:17: error[E201]: unknown unit 'kgg'
  |
1 | param M = 31.7 [kgg]
  |                 ^^^
  = hint: did you mean 'kg'?
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping

from bondc.source import NO_SPAN, Source, Span
from bondc import codes

if TYPE_CHECKING:
    from bondc.simulate import SimResult

SEVERITIES = ("error", "warning", "info")


@dataclass(frozen=True)
class Related:
    """A second location a diagnostic is about, with a short label."""

    span: Span
    label: str


class Hint(str):
    """A hint's text with the names its "did you mean" offers (:attr:`Diagnostic.suggestions`):
    a string everywhere a hint is, that keeps them through :meth:`join`."""

    suggestions: tuple[str, ...]

    def __new__(cls, text: str, suggestions: tuple[str, ...] = ()) -> "Hint":
        made = super().__new__(cls, text)
        made.suggestions = tuple(suggestions)
        return made

    @classmethod
    def join(cls, parts: Iterable[str], separator: str = "; ") -> "Hint":
        """The parts joined, with the suggestions of the first part that offers any."""
        parts = list(parts)
        offered = next((p.suggestions for p in parts if isinstance(p, Hint) and p.suggestions), ())
        return cls(separator.join(parts), offered)


@dataclass(frozen=True)
class Diagnostic:
    severity: str
    code: str
    message: str
    span: Span = NO_SPAN
    hint: str | None = None
    related: tuple[Related, ...] = ()
    #: The names the hint's "did you mean" offers for what the span names, as data (the language
    #: server's quick fix replaces the span's text, or its closest dotted part, with one of them).
    suggestions: tuple[str, ...] = field(default=(), compare=False)

    @property
    def is_error(self) -> bool:
        return self.severity == "error"

    def to_json(self) -> dict[str, Any]:
        data = {
            "severity": self.severity,
            "code": self.code,
            "message": self.message,
            "file": self.span.file,
            "line": self.span.line,
            "column": self.span.column,
            "end_line": self.span.end_line,
            "end_column": self.span.end_column,
            "hint": self.hint,
            "related": [
                {
                    "message": rel.label,
                    "file": rel.span.file,
                    "line": rel.span.line,
                    "column": rel.span.column,
                    "end_line": rel.span.end_line,
                    "end_column": rel.span.end_column,
                }
                for rel in self.related
            ],
        }
        if self.span.instance:
            data["instance"] = self.span.instance    # inside a component: the instance path
        return data


class BondcError(Exception):
    """Base of every error bondc reports to a user; carries its diagnostics."""

    stage = "bondc"

    def __init__(self, diagnostics: Iterable[Diagnostic] | Diagnostic | str,
                 sources: Mapping[str, Source] | None = None):
        if isinstance(diagnostics, str):
            diagnostics = [Diagnostic("error", codes.E000, diagnostics)]
        elif isinstance(diagnostics, Diagnostic):
            diagnostics = [diagnostics]
        self.diagnostics: list[Diagnostic] = list(diagnostics)
        # The texts the diagnostics point into, for rendering (files are re-read otherwise).
        self.sources: dict[str, Source] = dict(sources or {})
        super().__init__(_message(self.diagnostics))


def _message(diagnostics: list[Diagnostic]) -> str:
    """``str(error)``: where the first diagnostic is (``file:line:col``), then every message."""
    text = "; ".join(d.message for d in diagnostics)
    span = diagnostics[0].span if diagnostics else NO_SPAN
    if span.line > 0:
        return f"{span.file}:{span.line}:{span.column}: {text}"
    if span.file and span.file != NO_SPAN.file:
        return f"{span.file}: {text}"
    return text


class UsageError(BondcError):
    stage = "usage"


class ParseError(BondcError):
    stage = "parse"


class ModelError(BondcError):
    stage = "model"


class CausalityError(BondcError):
    stage = "causality"


class EquationError(BondcError):
    stage = "equations"


class SimulationError(BondcError):
    """A run that stopped early; ``result`` is what it computed up to there (every SimulationError
    bondc raises carries it)."""

    stage = "simulation"
    #: the incomplete run (``result.t``, ``result.outputs``, ... up to the failure)
    result: SimResult | None = None


class AnalysisError(BondcError):
    stage = "analysis"


class DataError(BondcError):
    stage = "data"
    #: a file that cannot be read at all (the command exits 2), not an error of its data (1)
    io = False


def sort_key(diagnostic: Diagnostic) -> tuple[str, int, int, str, str, str]:
    span = diagnostic.span
    return (span.file, span.line, span.column, diagnostic.code, diagnostic.message, span.instance)


def has_errors(diagnostics: Iterable[Diagnostic]) -> bool:
    return any(d.is_error for d in diagnostics)


def _source_for(name: str, sources: Mapping[str, Source]) -> Source | None:
    if name in sources:
        return sources[name]
    try:
        return Source.from_path(Path(name))
    except (OSError, UnicodeDecodeError, ValueError):
        return None


#: The characters a terminal acts on instead of showing them: the C0 controls but tab (ESC starts
#: escape sequences that recolour, move the cursor or retitle the window; BEL rings), DEL and the
#: C1 controls.
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """``text`` with every control character written as an escape (``\\x1b``), so that a model
    line or a data file's header is shown, never acted on by the terminal.

    >>> print(printable("e = 1" + chr(27) + "[31m" + chr(7)))
    e = 1\\x1b[31m\\x07
    """
    return _CONTROL.sub(lambda found: f"\\x{ord(found.group()):02x}", text)


def _excerpt(span: Span, source: Source | None, label: str = "") -> list[str]:
    """The source line of a span with a caret line under it (control characters escaped, the
    caret under what they became)."""
    if source is None or span.line < 1:
        return []
    raw = source.line_text(span.line).rstrip("\r").expandtabs(1)
    text = printable(raw)
    gutter = " " * len(str(span.line))
    start = max(span.column, 1)
    if span.end_line == span.line and span.end_column > span.column:
        width = span.end_column - span.column
    elif span.end_line > span.line:
        width = max(len(raw) - start + 1, 1)
    else:
        width = 1
    # the columns of the escaped line: what precedes the span, and the span itself, as shown
    before = len(printable(raw[:start - 1])) + max(start - 1 - len(raw), 0)
    width = max(len(printable(raw[start - 1:start - 1 + width])), 1) if start - 1 < len(raw) else width
    caret = " " * before + "^" * width
    if label:
        caret += " " + label
    return [f"{gutter} |", f"{span.line} | {text}", f"{gutter} | {caret}"]


def render(diagnostic: Diagnostic, sources: Mapping[str, Source] | None = None) -> str:
    """Render one diagnostic as ``file:line:col: severity[code]: message`` with context."""
    sources = sources or {}
    span = diagnostic.span
    if span.line > 0:
        head = f"{span.file}:{span.line}:{span.column}: "
    elif span.file and span.file != NO_SPAN.file:
        head = f"{span.file}: "
    else:
        head = ""
    lines = [f"{head}{diagnostic.severity}[{diagnostic.code}]: {printable(diagnostic.message)}"]
    lines += _excerpt(span, _source_for(span.file, sources))
    if span.instance:
        lines.append(f"  note: in {span.instance}")
    for rel in diagnostic.related:
        where = f"{rel.span.file}:{rel.span.line}:{rel.span.column}"
        lines.append(f"  note: {printable(rel.label)} ({where})")
        lines += ["  " + row for row in _excerpt(rel.span, _source_for(rel.span.file, sources))]
    if diagnostic.hint:
        gutter = " " * len(str(span.line)) if span.line > 0 else ""
        lines.append(f"{gutter} = hint: {printable(diagnostic.hint)}")
    return "\n".join(lines)


def render_all(diagnostics: Iterable[Diagnostic], sources: Mapping[str, Source] | None = None) -> str:
    return "\n\n".join(render(d, sources) for d in diagnostics)
