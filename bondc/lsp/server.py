"""The server: the documents' analyses, scheduled on the worker thread, and the LSP's handlers.

An edit (didChange) supersedes the analysis of the document in flight at once, waits
:data:`DEBOUNCE` for more typing, then asks the worker for the new version; a result is
published only if no newer version came meanwhile (``publishDiagnostics`` carries its version).
Requests are answered from the last completed analysis, on the event loop, which analyses never
occupy; rename waits for the analysis of the version the client holds.
"""

from __future__ import annotations

import asyncio
import logging
import sys

from lsprotocol import types as lsp
from pygls.exceptions import JsonRpcException
from pygls.lsp.server import LanguageServer

from bondc.version import __version__
from bondc.errors import BondcError
from bondc.lsp import features
from bondc.lsp.analysis import Analysis, Job, Worker, too_large
from bondc.lsp.positions import path_of
from bondc.lsp.protocol import _NOT_JSON, PARSE_ERROR, _Framed, _Protocol

logger = logging.getLogger(__name__)

DEBOUNCE = 0.05          # seconds after the last change before the buffer is checked (a newer edit
#                          supersedes the check in flight, so a short wait costs only wasted work)
#: How long the analysis thread may hold the GIL while the event loop waits for it [s] (Python's
#: default, 5 ms, made a hover wait several of those while an analysis ran).
SWITCH_INTERVAL = 0.001
REQUEST_FAILED = -32803  # LSP's RequestFailed: a rename that cannot be done
FRESH_WAIT = 30.0        # seconds rename waits for the analysis of the client's version


class BondcServer(LanguageServer):
    def __init__(self):
        super().__init__("bondc", __version__, protocol_cls=_Protocol)
        self.analyses: dict[str, Analysis] = {}      # an open document: its last completed analysis
        self.latest: dict[str, int] = {}             # an open document: the newest version received
        self.jobs: dict[str, list[Job]] = {}         # an open document: its analyses asked and not done
        self.published: dict[str, set] = {}          # an open document -> the imported files' URIs it reported on
        self._waiting: dict[str, list[tuple[int, asyncio.Future]]] = {}
        self._worker: Worker | None = None

    @property
    def worker(self) -> Worker:
        if self._worker is None:
            self._worker = Worker()
        return self._worker

    def report_server_error(self, error: Exception, source) -> None:
        """A body that is not JSON is answered with ParseError (id null: its id cannot be read), as
        JSON-RPC says; pygls only showed the editor a message. A refused rename is its answer.
        Other errors as pygls reports them."""
        if isinstance(error, _NOT_JSON):
            logger.warning("a message from the client is not JSON: %s", error)
            self.protocol.send_error(None, PARSE_ERROR, f"the message is not JSON: {error}")
            return
        if isinstance(error, JsonRpcException) and error.code == REQUEST_FAILED:
            return
        super().report_server_error(error, source)

    def encoding(self) -> str:
        try:
            found = self.workspace.position_encoding
            return str(getattr(found, "value", found))
        except Exception:       # noqa: BLE001  (no workspace before initialisation: the protocol's default)
            return "utf-16"

    # -- analyses

    async def analyse(self, uri: str, text: str, version: int, debounce: float = 0.0) -> None:
        """Analyse ``version`` of ``uri`` and publish its diagnostics, unless a newer version
        comes first (it supersedes this one at once)."""
        self.latest[uri] = version
        self.worker.supersede(self.jobs.pop(uri, []))
        if debounce:
            await asyncio.sleep(debounce)       # typing: only the last change is checked
            if self.latest.get(uri) != version:
                return
        job = Job(asyncio.get_running_loop(), (uri, text, version, self.encoding(), self.analyses.get(uri)))
        self.jobs.setdefault(uri, []).append(self.worker.submit(job))
        result = await job.future
        if job in self.jobs.get(uri, ()):
            self.jobs[uri].remove(job)
        if result is None or self.latest.get(uri) != version:
            return                              # superseded, or closed: never published
        self.analyses[uri] = result
        self.publish(result)
        still = []
        for wanted, future in self._waiting.pop(uri, []):
            if wanted <= version:
                if not future.done():
                    future.set_result(result)
            else:
                still.append((wanted, future))
        if still:
            self._waiting[uri] = still

    def publish(self, analysis: Analysis) -> None:
        uri = analysis.uri
        self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(
            uri=uri, diagnostics=analysis.shown, version=analysis.version))
        for other in self.published.get(uri, set()) - set(analysis.imported):
            if other not in self.analyses:
                self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=other, diagnostics=[]))
        for other, items in analysis.imported.items():
            if other not in self.analyses:
                self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=other, diagnostics=items))
        self.published[uri] = set(analysis.imported)

    def close(self, uri: str) -> None:
        self.latest.pop(uri, None)
        self.worker.supersede(self.jobs.pop(uri, []))
        self.analyses.pop(uri, None)
        for _, future in self._waiting.pop(uri, []):
            if not future.done():
                future.set_result(None)
        for other in {uri} | self.published.pop(uri, set()):
            if other not in self.analyses:
                self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=other, diagnostics=[]))

    async def current(self, uri: str) -> Analysis | None:
        """The analysis of the newest version received (waiting for it), or None."""
        analysis = self.analyses.get(uri)
        wanted = self.latest.get(uri)
        if wanted is None or (analysis is not None and analysis.version >= wanted):
            return analysis
        future = asyncio.get_running_loop().create_future()
        self._waiting.setdefault(uri, []).append((wanted, future))
        try:
            return await asyncio.wait_for(future, FRESH_WAIT)
        except asyncio.TimeoutError:
            return None


server = BondcServer()


@server.feature(lsp.TEXT_DOCUMENT_DID_OPEN)
async def did_open(ls: BondcServer, params: lsp.DidOpenTextDocumentParams):
    document = params.text_document
    await ls.analyse(document.uri, document.text, document.version)


@server.feature(lsp.TEXT_DOCUMENT_DID_CHANGE)
async def did_change(ls: BondcServer, params: lsp.DidChangeTextDocumentParams):
    uri, version = params.text_document.uri, params.text_document.version
    document = ls.workspace.get_text_document(uri)
    await ls.analyse(uri, document.source, version, DEBOUNCE)


@server.feature(lsp.TEXT_DOCUMENT_DID_CLOSE)
def did_close(ls: BondcServer, params: lsp.DidCloseTextDocumentParams):
    """A closed file's problems leave the editor's list (a file not open is not checked), with
    those it reported in the files it imports."""
    ls.close(params.text_document.uri)


@server.feature(lsp.TEXT_DOCUMENT_DID_SAVE)
async def did_save(ls: BondcServer, params: lsp.DidSaveTextDocumentParams):
    document = ls.workspace.get_text_document(params.text_document.uri)
    await ls.analyse(document.uri, document.source, document.version or 0)


def _analysis(ls: BondcServer, uri: str) -> Analysis | None:
    analysis = ls.analyses.get(uri)
    return None if analysis is None or analysis.too_large else analysis


@server.feature(lsp.TEXT_DOCUMENT_DEFINITION)
def definition(ls: BondcServer, params: lsp.DefinitionParams):
    analysis = _analysis(ls, params.text_document.uri)
    return features.definition(analysis, params.position) if analysis is not None else None


@server.feature(lsp.TEXT_DOCUMENT_REFERENCES)
def references(ls: BondcServer, params: lsp.ReferenceParams):
    analysis = _analysis(ls, params.text_document.uri)
    if analysis is None:
        return []
    return features.references(analysis, params.position, params.context.include_declaration)


@server.feature(lsp.TEXT_DOCUMENT_HOVER)
def hover(ls: BondcServer, params: lsp.HoverParams):
    analysis = _analysis(ls, params.text_document.uri)
    return features.hover(analysis, params.position) if analysis is not None else None


@server.feature(lsp.TEXT_DOCUMENT_COMPLETION, lsp.CompletionOptions(trigger_characters=[".", "["]))
def completion(ls: BondcServer, params: lsp.CompletionParams):
    analysis = _analysis(ls, params.text_document.uri)
    if analysis is None:
        return []
    buffer = ls.workspace.get_text_document(params.text_document.uri)
    text, line = buffer.source, params.position.line
    start = 0
    for _ in range(line):                 # the cursor's line of the buffer as it is now
        start = text.find("\n", start) + 1
        if start == 0:
            return []
    end = text.find("\n", start)
    line_text = text[start:end if end >= 0 else len(text)].rstrip("\r")
    from bondc.lsp.positions import Lines

    character = Lines(line_text, analysis.lines.encoding).character(0, params.position.character)
    items = features.completions(analysis, text, line_text[:character], features.model_at(analysis, line))
    return lsp.CompletionList(is_incomplete=False, items=items)


@server.feature(lsp.TEXT_DOCUMENT_DOCUMENT_SYMBOL)
def document_symbols(ls: BondcServer, params: lsp.DocumentSymbolParams):
    analysis = _analysis(ls, params.text_document.uri)
    return features.outline(analysis) if analysis is not None else []


@server.feature(lsp.TEXT_DOCUMENT_PREPARE_RENAME)
async def prepare_rename(ls: BondcServer, params: lsp.PrepareRenameParams):
    analysis = await ls.current(params.text_document.uri)
    if analysis is None or analysis.too_large:
        return None
    try:
        symbol, where = features.renamed_symbol(analysis, params.position)
    except features.RenameRefused as refused:
        raise JsonRpcException(str(refused), code=REQUEST_FAILED) from None
    return lsp.PrepareRenamePlaceholder(range=where, placeholder=symbol.name)


@server.feature(lsp.TEXT_DOCUMENT_RENAME, lsp.RenameOptions(prepare_provider=True))
async def rename(ls: BondcServer, params: lsp.RenameParams):
    analysis = await ls.current(params.text_document.uri)
    if analysis is None or analysis.too_large:
        raise JsonRpcException("the document is not analysed (too large, or not open)", code=REQUEST_FAILED)
    try:
        return features.rename(analysis, params.position, params.new_name)
    except features.RenameRefused as refused:
        raise JsonRpcException(str(refused), code=REQUEST_FAILED) from None


@server.feature(lsp.TEXT_DOCUMENT_CODE_ACTION,
                lsp.CodeActionOptions(code_action_kinds=[lsp.CodeActionKind.QuickFix]))
def code_action(ls: BondcServer, params: lsp.CodeActionParams):
    return features.quick_fixes(params.text_document.uri, params.context.diagnostics) or None


def _formatted(source: str, path: str) -> str | None:
    from bondc.fmt import fmt

    try:
        return fmt(source, path)
    except (BondcError, OSError):
        return None                     # a syntax error (diagnostics say where), or a file never opened


@server.feature(lsp.TEXT_DOCUMENT_FORMATTING)
async def formatting(ls: BondcServer, params: lsp.DocumentFormattingParams):
    document = ls.workspace.get_text_document(params.text_document.uri)
    source = document.source
    if too_large(source) is not None:
        return None                     # E006 says so
    formatted = await asyncio.get_running_loop().run_in_executor(None, _formatted, source,
                                                                 str(path_of(document.uri)))
    if formatted is None:
        return None
    if formatted == source:
        return []
    end = lsp.Position(len(source.splitlines()), 0)
    return [lsp.TextEdit(range=lsp.Range(lsp.Position(0, 0), end), new_text=formatted)]


def main() -> int:
    """Serve on stdio until the client sends ``exit`` or closes the stream; what the client sends is
    framed by :class:`_Framed` before pygls reads it."""
    sys.setswitchinterval(SWITCH_INTERVAL)
    stream = _Framed(sys.stdin.buffer, lambda code, message: server.protocol.send_error(None, code, message))
    server.start_io(stdin=stream)
    return 0
