"""The analysis of a buffer, off the server's event loop.

:func:`analyse` parses the buffer once and checks each of its models from that parse, assigning
causality (:func:`bondc.pipeline.diagnose_file`, as ``bondc check`` but the equations), builds the index and
turns the diagnostics into the LSP's, with ranges mapped through one line table of that version
(:class:`~bondc.lsp.positions.Lines`). The result (:class:`Analysis`) is what hover, completion,
definition and rename answer from, so that they answer at once whatever is being analysed.

:class:`Worker` runs analyses one at a time in a thread of its own. A newer edit supersedes the
analysis in flight (:meth:`Worker.supersede`): the analysis stops at its next checkpoint (between
stages and models) or, inside a stage (lark's parse of 5 000 lines takes 0.3-0.5 s), at once by an
exception raised in the worker thread; its result is never published.
"""

from __future__ import annotations

import ctypes
import logging
import threading
from dataclasses import dataclass, field
from difflib import SequenceMatcher
from pathlib import Path
from typing import TYPE_CHECKING

from lsprotocol import types as lsp

from bondc.errors import Diagnostic
from bondc.lsp.index import Index, build_index
from bondc.lsp.positions import Lines, Positions, path_of
from bondc import codes

if TYPE_CHECKING:
    from bondc.causality import CausalGraph
    from bondc.model import BondGraph

logger = logging.getLogger(__name__)

#: The largest buffer analysed: a larger one gets one diagnostic, E006, and no index.
MAX_DOCUMENT_LINES = 20_000
MAX_DOCUMENT_CHARS = 1_000_000
DOCS = Path(__file__).resolve().parent.parent.parent / "docs" / "diagnostics.md"


def code_link(code: str) -> str:
    """The link of a diagnostic code: its section of docs/diagnostics.md (the registry's anchor)."""
    from bondc.codes import anchor

    return DOCS.as_uri() + "#" + anchor(code)


class Superseded(BaseException):
    """An analysis stopped because a newer version of its buffer came (a BaseException, so that no
    ``except Exception`` of a stage takes it for the stage's own failure)."""


@dataclass
class Analysis:
    """A version of a buffer as analysed: what every request is answered from."""

    uri: str
    text: str
    version: int
    path: Path
    lines: Lines
    files: list = field(default_factory=list)
    index: Index | None = None
    graph: BondGraph | None = None
    causal: CausalGraph | None = None     # the graph's causality (hover shows it)
    too_large: bool = False          # beyond MAX_DOCUMENT_LINES or MAX_DOCUMENT_CHARS: not analysed (E006)
    shown: list = field(default_factory=list)                 # its own diagnostics, as published
    imported: dict[str, list] = field(default_factory=dict)   # an imported file's URI: its diagnostics

    @property
    def positions(self) -> Positions:
        return Positions(str(self.path), self.lines)


def _nothing() -> None:
    return None


def check(path: Path, text: str, checkpoint=_nothing):
    """Every diagnostic of the buffer (all its models), the graph of its runnable model (or None),
    its causality, and the parsed files (None where the buffer does not parse). One parse, and
    the stages of ``bondc check`` but the equations (:func:`bondc.pipeline.diagnose_file`, editing)."""
    from bondc.pipeline import diagnose_file

    checks = diagnose_file(path, text=text, editing=True, checkpoint=checkpoint)
    runnable = next((d for d in checks.models if d.causal is not None and d.checked is not None), None)
    graph = runnable.checked.graph if runnable is not None and runnable.checked is not None else None
    causal = runnable.causal if runnable is not None else None
    files = checks.loaded[0] if checks.loaded is not None else None
    return list(checks.diagnostics), graph, causal, files


def check_text(path: Path, text: str) -> tuple[list[Diagnostic], BondGraph | None]:
    """Every diagnostic of the buffer (all its models), and the graph of its runnable model (or None)."""
    found, graph, _, _ = check(path, text)
    return found, graph


# ------------------------------------------------------------------ diagnostics as the LSP has them

def _quick_fix(diagnostic: Diagnostic, positions: Positions):
    """The edit a "did you mean" offers: the span's text, or the dotted part of it closest to the
    suggestion, replaced by the suggestion (``data`` of the LSP diagnostic, which a code action
    request sends back)."""
    if not diagnostic.suggestions or diagnostic.span.line != diagnostic.span.end_line or diagnostic.span.line < 1:
        return None
    lines = positions.lines_of(diagnostic.span.file)
    if lines is None:
        return None
    line = diagnostic.span.line - 1
    start, end = diagnostic.span.column - 1, diagnostic.span.end_column - 1
    written = lines.line(line)[start:end]
    suggestion = diagnostic.suggestions[0]
    parts, wanted = written.split("."), suggestion.count(".") + 1
    if written and len(parts) > wanted:         # 'sprung.e' with 'spring': the closest run of parts
        runs = [(".".join(parts[i:i + wanted]), sum(len(p) + 1 for p in parts[:i])) for i in
                range(len(parts) - wanted + 1)]
        text, offset = max(runs, key=lambda run: SequenceMatcher(None, run[0], suggestion).ratio())
        start, end = start + offset, start + offset + len(text)
    if not written:
        return None
    replaced = lsp.Range(lsp.Position(line, lines.client_column(line, start)),
                         lsp.Position(line, lines.client_column(line, end)))
    return {"replace": replaced, "with": list(diagnostic.suggestions)}


def to_lsp(diagnostic: Diagnostic, path: Path, positions: Positions) -> lsp.Diagnostic:
    severity = {"error": lsp.DiagnosticSeverity.Error, "warning": lsp.DiagnosticSeverity.Warning}.get(
        diagnostic.severity, lsp.DiagnosticSeverity.Information)
    message = diagnostic.message + (f"\n{diagnostic.hint}" if diagnostic.hint else "")
    if diagnostic.span.instance:
        message += f"\n(in {diagnostic.span.instance})"
    related = [lsp.DiagnosticRelatedInformation(lsp.Location(Path(r.span.file).resolve().as_uri()
                                                             if r.span.file and r.span.line > 0 else path.as_uri(),
                                                             positions.range(r.span)), r.label)
               for r in diagnostic.related if r.span.line > 0 and not r.span.file.startswith("std:")]
    description = lsp.CodeDescription(href=code_link(diagnostic.code)) if DOCS.exists() else None
    fix = _quick_fix(diagnostic, positions) if diagnostic.span.file == str(path) else None
    return lsp.Diagnostic(range=positions.range(diagnostic.span), message=message, severity=severity,
                          code=diagnostic.code, code_description=description, source="bondc",
                          related_information=related or None, data=fix)


def _resolved(file: str, document: Path) -> Path:
    """The path of a diagnostic's file (as the loader names it: relative to the working directory, or
    absolute)."""
    path = Path(file)
    return path.resolve() if path.is_absolute() or path.exists() else (document.parent / path).resolve()


def _at_import(diagnostic: Diagnostic, analysis: Analysis) -> lsp.Diagnostic:
    """A diagnostic of an imported file, shown on the open document: on the import that brings that
    file in (the first import where it comes through another), its own place as related information."""
    positions = analysis.positions
    target = _resolved(diagnostic.span.file, analysis.path)
    imports = [item for file in analysis.files[:1] for item in file.imports if not item.path.startswith("std:")]
    anchor = next((item.span for item in imports if (analysis.path.parent / item.path).resolve() == target),
                  imports[0].span if imports else None)
    shown = to_lsp(diagnostic, target, positions)
    where = f"{diagnostic.span.file}:{diagnostic.span.line}:{diagnostic.span.column}"
    shown.message = f"{where}: {shown.message}"
    shown.related_information = [lsp.DiagnosticRelatedInformation(lsp.Location(target.as_uri(), shown.range),
                                                                   "here")] + list(shown.related_information or [])
    shown.range = positions.range(anchor) if anchor is not None else lsp.Range(lsp.Position(0, 0),
                                                                                lsp.Position(0, 0))
    return shown


def too_large(text: str) -> lsp.Diagnostic | None:
    """E006 for a buffer beyond :data:`MAX_DOCUMENT_LINES` or :data:`MAX_DOCUMENT_CHARS`, else None."""
    lines = text.count("\n") + (1 if text and not text.endswith("\n") else 0)
    if lines <= MAX_DOCUMENT_LINES and len(text) <= MAX_DOCUMENT_CHARS:
        return None
    return lsp.Diagnostic(
        range=lsp.Range(lsp.Position(0, 0), lsp.Position(0, 0)), severity=lsp.DiagnosticSeverity.Error,
        code=codes.E006, source="bondc",
        message=(f"the document is too large to analyse as you type: {lines} lines, {len(text)} characters "
                 f"(at most {MAX_DOCUMENT_LINES} lines and {MAX_DOCUMENT_CHARS} characters)\n"
                 "run 'bondc check FILE' on it, or split it into files that import each other"),
        code_description=(lsp.CodeDescription(href=code_link(codes.E006)) if DOCS.exists() else None))


def analyse(uri: str, text: str, version: int, encoding: str, previous: Analysis | None = None,
            checkpoint=_nothing) -> Analysis:
    """The analysis of one version of a buffer (``previous``: the last one, whose index is kept
    while the buffer does not parse)."""
    path = path_of(uri)
    analysis = Analysis(uri, text, version, path, Lines("" if too_large(text) else text, encoding))
    problem = too_large(text)
    if problem is not None:         # one diagnostic, no index: every feature answers at once
        analysis.too_large = True
        analysis.shown = [problem]
        return analysis
    diagnostics, analysis.graph, analysis.causal, files = check(path, text, checkpoint)
    checkpoint()
    if files is not None:
        analysis.files, analysis.index = files, build_index(files)
    elif previous is not None and not previous.too_large:
        analysis.files, analysis.index = previous.files, previous.index
    checkpoint()
    positions = analysis.positions
    mine = [d for d in diagnostics if not d.span.file or Path(d.span.file) == path
            or d.span.file == str(path) or d.span.line == 0]
    others = [d for d in diagnostics if d not in mine and not d.span.file.startswith("std:")]
    analysis.shown = [to_lsp(d, path, positions) for d in mine] + [_at_import(d, analysis) for d in others]
    for diagnostic in others:       # and in the imported files themselves (cleared there once they are fixed)
        target = _resolved(diagnostic.span.file, path)
        analysis.imported.setdefault(target.as_uri(), []).append(to_lsp(diagnostic, target, positions))
    return analysis


# ------------------------------------------------------------------ the worker thread

_SET_ASYNC_EXC = ctypes.pythonapi.PyThreadState_SetAsyncExc
_SET_ASYNC_EXC.argtypes = (ctypes.c_ulong, ctypes.c_void_p)


def _set_async_exc(thread: int, exception: type[BaseException] | None) -> None:
    """Raise ``exception`` in ``thread`` at its next bytecode (None: drop one not raised yet).
    The class is kept alive by this module, so passing its address is safe (CPython's id)."""
    _SET_ASYNC_EXC(thread, None if exception is None else id(exception))


class Job:
    """One analysis asked of the worker; ``future`` (an asyncio future of the server's loop) gets
    its :class:`Analysis`, or None when it was superseded."""

    def __init__(self, loop, arguments: tuple):
        self.loop = loop
        self.arguments = arguments
        self.future = loop.create_future()
        self.cancelled = threading.Event()

    def checkpoint(self) -> None:
        if self.cancelled.is_set():
            raise Superseded

    def settle(self, result) -> None:
        def done():
            if not self.future.done():
                self.future.set_result(result)
        try:
            self.loop.call_soon_threadsafe(done)
        except RuntimeError:        # the loop is closed: the server is exiting
            pass


class Worker:
    """A thread that runs the analyses one after another (in the order asked, skipping the
    superseded); see the module's docstring."""

    def __init__(self):
        self._lock = threading.Lock()
        self._queue: list[Job] = []
        self._ready = threading.Condition(self._lock)
        self._running: Job | None = None
        self._thread = threading.Thread(target=self._loop, name="bondc-analysis", daemon=True)
        self._thread.start()

    def submit(self, job: Job) -> Job:
        with self._lock:
            self._queue.append(job)
            self._ready.notify()
        return job

    def supersede(self, jobs) -> None:
        """Stop ``jobs`` (waiting or running): a running one at once."""
        with self._lock:
            for job in jobs:
                job.cancelled.set()
                if job is self._running and self._thread.ident is not None:
                    _set_async_exc(self._thread.ident, Superseded)

    def _next(self) -> Job:
        with self._lock:
            while not self._queue:
                self._ready.wait()
            job = self._queue.pop(0)
            self._running = job
            return job

    def _finish(self) -> None:
        with self._lock:
            self._running = None
            _set_async_exc(self._thread.ident, None)        # one raised too late is dropped here

    def _loop(self) -> None:
        self._warm()
        while True:
            job = None
            try:
                job = self._next()
                if job.cancelled.is_set():
                    result = None
                else:
                    try:
                        result = analyse(*job.arguments, checkpoint=job.checkpoint)
                    except Superseded:
                        result = None
                    except Exception:       # noqa: BLE001  (a bug in a stage: logged, the server goes on)
                        logger.exception("the analysis of %s failed", job.arguments[0])
                        result = None
                self._finish()
                job.settle(result)
            except Superseded:              # raised between the analysis and _finish
                self._finish()
                if job is not None:
                    job.settle(None)

    @staticmethod
    def _warm() -> None:
        """The modules an analysis imports, imported before any analysis can be interrupted."""
        try:
            from bondc import causality, fmt, pipeline, scope, semantic, units  # noqa: F401
        except Exception:       # noqa: BLE001
            logger.exception("importing the checker failed")
