"""Source text and spans: where every AST node and diagnostic points.

A :class:`Source` is one file's text; a :class:`Span` is a range in it with
1-based line and column numbers (columns count characters, as editors do) and
0-based character offsets.

>>> src = Source("m.bg", "param M = 31.7 [kg]\\n")
>>> span = src.span(6, 7)
>>> (span.line, span.column, span.end_line, span.end_column)
(1, 7, 1, 8)
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Span:
    """A range of one source file: 1-based line/column, end column exclusive."""

    file: str
    line: int
    column: int
    end_line: int
    end_column: int
    start: int = 0
    end: int = 0
    instance: str = ""      # inside a component: the instance path from the top model (``plant.valve``)

    def to(self, other: "Span") -> "Span":
        """The span from the start of ``self`` to the end of ``other``."""
        return Span(self.file, self.line, self.column, other.end_line, other.end_column,
                    self.start, other.end, self.instance)

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


NO_SPAN = Span("<unknown>", 0, 0, 0, 0)


@dataclass(frozen=True)
class Source:
    """One source file: its display name and full text."""

    name: str
    text: str
    path: Path | None = field(default=None, compare=False)
    _line_starts: tuple[int, ...] = field(default=(), compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.text.startswith("\ufeff"):     # a byte-order mark (Windows editors write one) is not text
            object.__setattr__(self, "text", self.text[1:])
        starts = [0]
        find, index = self.text.find, self.text.find("\n")
        while index >= 0:
            starts.append(index + 1)
            index = find("\n", index + 1)
        object.__setattr__(self, "_line_starts", tuple(starts))

    @classmethod
    def from_path(cls, path: str | Path) -> "Source":
        path = Path(path)
        text = path.read_text(encoding="utf-8")
        return cls(str(path), text, path)

    def position(self, offset: int) -> tuple[int, int]:
        """1-based (line, column) of a character offset."""
        offset = max(0, min(offset, len(self.text)))
        line_index = bisect.bisect_right(self._line_starts, offset) - 1
        return line_index + 1, offset - self._line_starts[line_index] + 1

    def span(self, start: int, end: int) -> Span:
        """The span of offsets ``start`` to ``end`` (every AST node has one: a large model makes a
        million, so the end's line is looked up only when it is not the start's)."""
        starts, size = self._line_starts, len(self.text)
        first = 0 if start < 0 else size if start > size else start
        last = 0 if end < 0 else size if end > size else end
        line = bisect.bisect_right(starts, first)
        end_line = line if line == len(starts) or last < starts[line] else bisect.bisect_right(starts, last)
        return Span(self.name, line, first - starts[line - 1] + 1, end_line, last - starts[end_line - 1] + 1,
                    start, end)

    def line_text(self, line: int) -> str:
        """The text of a 1-based line, without its newline."""
        if line < 1 or line > len(self._line_starts):
            return ""
        start = self._line_starts[line - 1]
        end = self.text.find("\n", start)
        return self.text[start:] if end < 0 else self.text[start:end]
