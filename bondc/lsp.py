"""``bondc lsp``: a Language Server Protocol server on stdio (pygls), for editors.

It works on the editor's buffers, saved or not:

- diagnostics as you type (debounced): everything ``bondc check`` reports up to
  causality — syntax, names, units and dimensions, causal conflicts — with the
  same codes, ranges and related locations, every model of the file;
- hover: an element's kind, laws, bonds and causality; a parameter's value in
  SI and as written; a component's ports and description;
- go to definition and find references for parameters, elements, junctions,
  functions, models and components (across imports, ``std:`` included), and
  dotted names (``valve.loss.f``);
- completion of names, element kinds, built-ins, units, and members after a
  dot (``valve.`` lists the instance's ports, elements and outputs);
- document symbols (the outline) and formatting (``bondc fmt``).

A client that sends bad input is answered and served on: a message that cannot be framed (no
Content-Length, one that is not a number, one above :data:`MAX_MESSAGE_BYTES`) or is not JSON gets
a JSON-RPC error with id null and reading goes on at the next message (:class:`_Framed`); a request
with parameters of the wrong shape gets InvalidParams (:class:`_Protocol`); a buffer beyond
:data:`MAX_DOCUMENT_LINES` lines or :data:`MAX_DOCUMENT_CHARS` characters is not analysed (one
diagnostic, E006), so that the server keeps answering.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlparse

from lsprotocol import types as lsp
from pygls.exceptions import JsonRpcException, JsonRpcInvalidParams, JsonRpcInvalidRequest
from pygls.lsp.server import LanguageServer
from pygls.protocol import LanguageServerProtocol

from bondc import __version__, ast
from bondc.builtins import BUILTINS
from bondc.errors import BondcError, Diagnostic
from bondc.model import KINDS

DEBOUNCE = 0.15          # seconds after the last change before the buffer is checked
#: The largest message read from the client [bytes]; a larger one is skipped (a JSON-RPC error says so).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
#: The largest header block of a message [bytes] (a header is a line or two: Content-Length, Content-Type).
MAX_HEADER_BYTES = 8192
#: The largest buffer analysed: a larger one gets one diagnostic, E006, and no index (a check of a
#: buffer runs in the server's only thread, and one of 20 000 lines of a model takes seconds).
MAX_DOCUMENT_LINES = 20_000
MAX_DOCUMENT_CHARS = 1_000_000
KEYWORDS = ("model", "end", "param", "input", "output", "state", "fn", "experiment", "import", "if", "then",
            "else", "and", "or", "not", "port", "defaults", "discrete", "when", "external")
_DOCS = Path(__file__).resolve().parent.parent / "docs" / "diagnostics.md"


def path_of(uri: str) -> Path:
    parsed = urlparse(uri)
    return Path(unquote(parsed.path)) if parsed.scheme in ("file", "") else Path(uri)


# -- positions: bondc counts columns in characters (code points); LSP clients count them in the
# encoding negotiated at initialisation (UTF-16 code units unless the client offers another)

_DISK_LINES: dict[str, tuple[float, list[str]]] = {}


def _encoding() -> str:
    try:
        return str(getattr(server.workspace.position_encoding, "value", server.workspace.position_encoding))
    except Exception:       # noqa: BLE001  (no workspace before initialisation: the protocol's default)
        return "utf-16"


def _units(text: str, encoding: str) -> int:
    """The length of ``text`` in the client's units."""
    if text.isascii() or encoding == "utf-32":
        return len(text)
    if encoding == "utf-8":
        return len(text.encode("utf-8"))
    return len(text.encode("utf-16-le", "surrogatepass")) // 2


def _file_lines(file: str) -> list[str] | None:
    """The lines of a file a span is in: an open document's buffer, else the file on disk."""
    for document in getattr(server, "documents", {}).values():
        if str(document.path) == file:
            return document.text.splitlines()
    try:
        if file.startswith("std:"):
            from bondc.std import path_of as std_path

            file = str(std_path(file[4:]))
        stamp = os.stat(file).st_mtime_ns
        cached = _DISK_LINES.get(file)
        if cached is None or cached[0] != stamp:
            cached = _DISK_LINES[file] = (stamp, Path(file).read_text(encoding="utf-8").splitlines())
        return cached[1]
    except (OSError, UnicodeDecodeError, ValueError):
        return None


def _client_column(lines: list[str] | None, line: int, column: int) -> int:
    if lines is None or line >= len(lines):
        return column
    text = lines[line]
    return _units(text[:column], _encoding()) + max(column - len(text), 0)


def server_character(text: str, line: int, character: int) -> int:
    """A client's column (in its units) on ``line`` of ``text`` as a column in characters."""
    lines = text.splitlines()
    if line >= len(lines) or lines[line].isascii():
        return character
    encoding, count = _encoding(), 0
    for index, char in enumerate(lines[line]):
        if count >= character:
            return index
        count += _units(char, encoding)
    return len(lines[line]) + max(character - count, 0)


def _range(span) -> lsp.Range:
    line, column = max(span.line - 1, 0), max(span.column - 1, 0)
    end_line, end_column = max(span.end_line - 1, 0), max(span.end_column - 1, 0)
    if (end_line, end_column) <= (line, column):
        end_line, end_column = line, column + 1
    lines = _file_lines(span.file) if span.file else None
    return lsp.Range(lsp.Position(line, _client_column(lines, line, column)),
                     lsp.Position(end_line, _client_column(lines, end_line, end_column)))


def _contains(span, line: int, column: int) -> bool:
    """Whether 0-based (line, column) is inside ``span``."""
    start = (span.line - 1, span.column - 1)
    end = (span.end_line - 1, span.end_column - 1)
    return start <= (line, column) <= end


# ------------------------------------------------------------------ diagnostics

def to_lsp(diagnostic: Diagnostic, path: Path) -> lsp.Diagnostic:
    severity = {"error": lsp.DiagnosticSeverity.Error, "warning": lsp.DiagnosticSeverity.Warning}.get(
        diagnostic.severity, lsp.DiagnosticSeverity.Information)
    message = diagnostic.message + (f"\n{diagnostic.hint}" if diagnostic.hint else "")
    if diagnostic.span.instance:
        message += f"\n(in {diagnostic.span.instance})"
    related = [lsp.DiagnosticRelatedInformation(lsp.Location(Path(r.span.file).resolve().as_uri()
                                                             if r.span.file and r.span.line > 0 else path.as_uri(),
                                                             _range(r.span)), r.label)
               for r in diagnostic.related if r.span.line > 0 and not r.span.file.startswith("std:")]
    description = (lsp.CodeDescription(href=_DOCS.as_uri() + f"#{diagnostic.code.lower()}")
                   if _DOCS.exists() else None)
    return lsp.Diagnostic(range=_range(diagnostic.span), message=message, severity=severity,
                          code=diagnostic.code, code_description=description, source="bondc",
                          related_information=related or None)


def _resolved(file: str, document: Path) -> Path:
    """The path of a diagnostic's file (as the loader names it: relative to the working directory, or
    absolute)."""
    path = Path(file)
    return path.resolve() if path.is_absolute() or path.exists() else (document.parent / path).resolve()


def _at_import(diagnostic: Diagnostic, document: "Document") -> lsp.Diagnostic:
    """A diagnostic of an imported file, shown on the open document: on the import that brings that
    file in (the first import where it comes through another), its own place as related information."""
    target = _resolved(diagnostic.span.file, document.path)
    imports = [item for file in document.files[:1] for item in file.imports if not item.path.startswith("std:")]
    anchor = next((item.span for item in imports if (document.path.parent / item.path).resolve() == target),
                  imports[0].span if imports else None)
    shown = to_lsp(diagnostic, target)
    where = f"{diagnostic.span.file}:{diagnostic.span.line}:{diagnostic.span.column}"
    shown.message = f"{where}: {shown.message}"
    shown.related_information = [lsp.DiagnosticRelatedInformation(lsp.Location(target.as_uri(), shown.range),
                                                                   "here")] + list(shown.related_information or [])
    shown.range = _range(anchor) if anchor is not None else lsp.Range(lsp.Position(0, 0), lsp.Position(0, 0))
    return shown


def check_text(path: Path, text: str) -> tuple[list[Diagnostic], object]:
    """Every diagnostic of the buffer (all its models), and the graph of its runnable model (or None)."""
    from bondc import semantic
    from bondc.causality import assign_causality
    from bondc.flatten import ports_of

    found: list[Diagnostic] = []
    graph = None
    try:
        files, _, _ = semantic.load_files(path, text)
        own = files[0].models
    except BondcError as error:
        return list(error.diagnostics), None
    names = [None] if len(own) <= 1 else [m.name for m in own]
    for name in names:
        try:
            loaded, warnings = semantic.load(path, model=name, text=text)
            found += [d for d in warnings if d not in found]
            component = any(m.name == loaded.name and ports_of(m) for m in own)
            if not component:
                causal = assign_causality(loaded)
                found += [d for d in causal.diagnostics if d not in found]
                graph = graph or loaded
        except BondcError as error:
            found += [d for d in error.diagnostics if d not in found]
    return found, graph


# ------------------------------------------------------------------ the index

@dataclass
class Symbol:
    name: str
    category: str             # parameter element junction input output state function model port ...
    span: object              # the name as written
    statement: object         # its AST statement (for hover)
    model: str | None         # the model it belongs to (None: file level)
    file: str


@dataclass
class Use:
    name: str                 # the name used (its first part for dotted references)
    span: object
    model: str | None
    parts: tuple[str, ...] = ()
    part_spans: tuple = ()
    call: bool = False        # a function called by this name: an fn (or a built-in), nothing else


@dataclass
class Index:
    symbols: list[Symbol] = field(default_factory=list)
    uses: list[Use] = field(default_factory=list)
    models: dict[str, tuple[ast.Model, str]] = field(default_factory=dict)   # every model: (model, file)

    def declared(self, name: str, model: str | None) -> Symbol | None:
        for symbol in self.symbols:
            if symbol.name == name and symbol.model == model:
                return symbol
        for symbol in self.symbols:
            if symbol.name == name and symbol.model is None:
                return symbol
        return None


def _ref_parts(node: ast.Ref) -> tuple:
    """Spans of each part of a dotted reference (``valve.loss.f``)."""
    spans, column, offset = [], node.span.column, node.span.start
    for part in node.parts:
        spans.append(type(node.span)(node.span.file, node.span.line, column, node.span.line, column + len(part),
                                     offset, offset + len(part)))
        column += len(part) + 1
        offset += len(part) + 1
    return tuple(spans)


def build_index(files) -> Index:
    index = Index()
    for file in files:
        for item in file.items:
            if isinstance(item, ast.FnDef):
                index.symbols.append(Symbol(item.name, "function", item.name_span, item, None, file.path))
            elif isinstance(item, ast.Model):
                index.models[item.name] = (item, file.path)
                index.symbols.append(Symbol(item.name, "model", item.name_span, item, None, file.path))
                _index_model(index, item, file.path)
    return index


def _index_model(index: Index, model: ast.Model, path: str) -> None:
    name = model.name

    def add(symbol_name, category, span, statement):
        index.symbols.append(Symbol(symbol_name, category, span, statement, name, path))

    def uses_in(expr):
        for node in ast.walk(expr):
            if isinstance(node, ast.Name):
                index.uses.append(Use(node.name, node.span, name))
            elif isinstance(node, ast.Ref):
                index.uses.append(Use(node.parts[0], node.span, name, node.parts, _ref_parts(node)))
            elif isinstance(node, ast.Call):
                index.uses.append(Use(node.func, node.func_span, name, call=True))

    for statement in model.body:
        if isinstance(statement, (ast.Param, ast.Input, ast.Output, ast.Discrete)):
            category = {ast.Param: "parameter", ast.Input: "input", ast.Output: "output",
                        ast.Discrete: "discrete"}[type(statement)]
            add(statement.name, category, statement.name_span, statement)
            if statement.value is not None:
                uses_in(statement.value)
        elif isinstance(statement, ast.StateDecl):
            add(statement.name, "state", statement.name_span, statement)
            for law in statement.laws:
                for expr in (getattr(law, "value", None), getattr(law, "arg", None)):
                    if expr is not None:
                        uses_in(expr)
        elif isinstance(statement, ast.FnDef):
            add(statement.name, "function", statement.name_span, statement)
            uses_in(statement.body)
        elif isinstance(statement, ast.Element):
            category = "element" if statement.kind in KINDS else "instance"
            add(statement.name, category, statement.name_span, statement)
            if category == "instance":
                index.uses.append(Use(statement.kind.rpartition(".")[2], statement.kind_span, None))
            for law in statement.laws:
                for expr in (getattr(law, "value", None), getattr(law, "arg", None)):
                    if expr is not None:
                        uses_in(expr)
        elif isinstance(statement, ast.Junction):
            spans = statement.name_spans or (statement.span,) * len(statement.names)
            for junction, span in zip(statement.names, spans):
                add(junction, "junction", span, statement)
        elif isinstance(statement, ast.PortDecl):
            spans = statement.name_spans or (statement.span,) * len(statement.names)
            for port, span in zip(statement.names, spans):
                add(port, "port", span, statement)
        elif isinstance(statement, ast.BondChain):
            if statement.label:
                add(statement.label, "bond label", statement.label_span, statement)
            for end in statement.endpoints:
                span = end.span
                width = len(end.name)
                name_span = type(span)(span.file, span.line, span.column, span.line, span.column + width,
                                       span.start, span.start + width)
                index.uses.append(Use(end.name, name_span, name, (end.name,) + ((end.port,) if end.port else ()),
                                      (name_span,)))
        elif isinstance(statement, ast.When):
            uses_in(statement.condition)
            for action in statement.actions:
                for expr in ([action.value] if isinstance(action, ast.WhenAssign) else list(action.args)):
                    uses_in(expr)
        elif isinstance(statement, ast.Experiment):
            add(statement.name, "experiment", statement.name_span, statement)
            for item in statement.body:
                if isinstance(item, (ast.Param, ast.Input)):
                    index.uses.append(Use(item.name, item.name_span, name))
                    uses_in(item.value)


# ------------------------------------------------------------------ the server

@dataclass
class Document:
    uri: str
    text: str
    version: int
    path: Path
    files: list = field(default_factory=list)
    index: Index | None = None
    graph: object = None
    too_large: bool = False          # beyond MAX_DOCUMENT_LINES or MAX_DOCUMENT_CHARS: not analysed (E006)


logger = logging.getLogger(__name__)

PARSE_ERROR, INVALID_REQUEST = -32700, -32600      # JSON-RPC's error codes

# a header line: a name (an HTTP token), ':', a value; the start of one (what a partial line may be)
_HEADER = re.compile(rb"([!#$%&'*+.^_`|~0-9A-Za-z-]+)[ \t]*:[ \t]*([^\r\n]*?)[ \t]*\r?\n")
_HEADER_START = re.compile(rb"[!#$%&'*+.^_`|~0-9A-Za-z-]*(?:[ \t]*:[^\r\n]*)?\r?")
# where a message starts: its Content-Length line (which valid JSON cannot hold: no raw line breaks)
_MARKER = re.compile(rb"content-length[ \t]{0,8}:[ \t]{0,8}[0-9]{1,20}[ \t]{0,8}\r?\n", re.IGNORECASE)
_MARKER_TAIL = 64       # bytes kept while looking for a marker: a marker is shorter


def _shown(data: bytes, width: int = 40) -> str:
    text = bytes(data[:width]).decode("ascii", "backslashreplace")
    return repr(text + ("..." if len(data) > width else ""))


class _Framed:
    """The client's byte stream as pygls's reader reads it: well-formed messages only.

    pygls (2.1) reads a header block, takes the number after ``Content-Length: `` and reads that many
    bytes at once; it skips a header it does not understand without telling anyone. A length of
    10^15 bytes made it allocate them (MemoryError: the server died), and after a length that was
    not a number it read the following messages as header lines, so valid requests went unanswered.

    This reads the stream itself, with bounded memory (a header block of at most
    :data:`MAX_HEADER_BYTES`, a body of at most :data:`MAX_MESSAGE_BYTES`), and gives pygls each
    message it can frame, as ``Content-Length: N`` and the body. A message it cannot frame (no
    length, a length that is not a number or is above the limit, a line that is not a header, a
    body cut short by the next message's header) is answered with a JSON-RPC error of id null (its
    id cannot be known) and logged, and reading goes on at the next ``Content-Length`` line: that
    line cannot occur inside a JSON body, so a message is never taken for another's body.
    ``reply(code, message)`` sends the error; it is called from the reader's thread.
    """

    CHUNK = 65536

    def __init__(self, stream, reply):
        self.read_some = stream.read1 if hasattr(stream, "read1") else stream.readline
        self.reply = reply
        self.buffer = bytearray()       # bytes read from the client and not yet handled
        self.frame = b""                # what pygls reads next
        self.position = 0

    # -- what pygls's reader calls (StdinAsyncReader: from a worker thread, one call at a time)

    def readline(self) -> bytes:
        if not self._ready():
            return b""
        end = self.frame.find(b"\n", self.position)
        end = len(self.frame) if end < 0 else end + 1
        line, self.position = self.frame[self.position:end], end
        return line

    def read(self, size: int = -1) -> bytes:
        if not self._ready():
            return b""
        end = len(self.frame) if size < 0 else self.position + size
        data, self.position = self.frame[self.position:end], min(end, len(self.frame))
        return data

    def _ready(self) -> bool:
        while self.position >= len(self.frame):
            body = self._next_body()
            if body is None:
                return False
            self.frame, self.position = b"Content-Length: %d\r\n\r\n" % len(body) + body, 0
        return True

    # -- reading the client's stream

    def _fill(self) -> bool:
        """More bytes from the client; False at the end of the stream."""
        data = self.read_some(self.CHUNK)
        if not data:
            return False
        self.buffer += data
        return True

    def _next_body(self) -> bytes | None:
        """The body of the next message that is well framed; None at the end of the stream."""
        while True:
            outcome = self._message()
            if outcome is None:
                return None
            if isinstance(outcome, bytes):
                return outcome
            code, problem = outcome
            logger.warning("skipped a message from the client: %s", problem)
            try:
                self.reply(code, problem)
            except Exception:       # noqa: BLE001  (the client's end is gone: the next read ends the stream)
                logger.exception("could not tell the client")
            if not self._resync():
                return None

    def _message(self):
        """The next message: its body (bytes), a problem ``(code, text)``, or None at the end."""
        length, offset, lines = None, 0, 0
        while True:                                     # the header block, up to an empty line
            newline = self.buffer.find(b"\n", offset)
            if newline < 0:
                if len(self.buffer) > MAX_HEADER_BYTES:
                    return PARSE_ERROR, f"a header of more than {MAX_HEADER_BYTES} bytes"
                partial = bytes(self.buffer[offset:])
                if partial.strip() and not _HEADER_START.fullmatch(partial):
                    return PARSE_ERROR, f"{_shown(partial)} is not a header line (Content-Length: N)"
                if not self._fill():
                    if self.buffer.strip():
                        logger.warning("the client's stream ended inside a message header")
                    return None
                continue
            line, offset = bytes(self.buffer[offset:newline + 1]), newline + 1
            if not line.strip():
                if lines == 0:                          # blank lines between messages
                    del self.buffer[:offset]
                    offset = 0
                    continue
                break
            lines += 1
            if offset > MAX_HEADER_BYTES:
                return PARSE_ERROR, f"a header of more than {MAX_HEADER_BYTES} bytes"
            match = _HEADER.fullmatch(line)
            if match is None:
                return PARSE_ERROR, f"{_shown(line)} is not a header line (Content-Length: N)"
            if match[1].lower() == b"content-length":
                value = match[2]
                if not value.isdigit() or len(value) > 20:
                    return PARSE_ERROR, f"the Content-Length {_shown(value)} is not a number of bytes"
                length = int(value)
        if length is None:
            return PARSE_ERROR, "a message without Content-Length"
        if length == 0:
            return PARSE_ERROR, "an empty message (Content-Length: 0)"
        if length > MAX_MESSAGE_BYTES:
            return INVALID_REQUEST, (f"a message of {length} bytes: the server reads messages of at most "
                                     f"{MAX_MESSAGE_BYTES} bytes")
        scanned = offset
        while True:                                     # the body: a header in it means it was cut short
            end = min(len(self.buffer), offset + length)
            marker = _MARKER.search(self.buffer, max(offset, scanned - _MARKER_TAIL), end)
            if marker is not None:
                return PARSE_ERROR, (f"a message shorter than its Content-Length ({length} bytes): the next "
                                     "message's header came inside it")
            if len(self.buffer) >= offset + length:
                body = bytes(self.buffer[offset:offset + length])
                del self.buffer[:offset + length]
                return body
            scanned = len(self.buffer)
            if not self._fill():
                logger.warning("the client's stream ended inside a message (%d of %d bytes)",
                               len(self.buffer) - offset, length)
                return None

    def _resync(self) -> bool:
        """Drop the message that could not be framed: up to the next Content-Length line after its
        first byte. False at the end of the stream."""
        del self.buffer[:1]
        while True:
            marker = _MARKER.search(self.buffer)
            if marker is not None:
                del self.buffer[:marker.start()]
                return True
            del self.buffer[:max(len(self.buffer) - _MARKER_TAIL, 0)]
            if not self._fill():
                return False


class _Unreadable:
    """A message pygls could not read into its types (its parameters' types, for a request): a
    request (``answer``) is answered with ``error`` all the same; a notification or a response is
    logged and dropped."""

    def __init__(self, msg_id, error: JsonRpcException, answer: bool):
        self.id = msg_id
        self.error = error
        self.answer = answer


class _Answered(logging.Filter):
    """pygls logs a traceback for every message it cannot read, or that is not JSON; bondc answers
    (or logs) those itself, in one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = str(record.msg)
        if text.startswith("Unable to deserialize message"):
            return False
        error = record.exc_info[1] if record.exc_info else None
        return not (text.startswith("Unable to handle message") and isinstance(error, _NOT_JSON))


_NOT_JSON = (json.JSONDecodeError, UnicodeDecodeError, RecursionError)
for _name in ("pygls.protocol.json_rpc", "pygls.server"):
    logging.getLogger(_name).addFilter(_Answered())


def _valid_id(value):
    """A request's id as it may be answered: a string or an integer, else None (JSON-RPC: null)."""
    return value if isinstance(value, str) or (isinstance(value, int) and not isinstance(value, bool)) else None


class _Protocol(LanguageServerProtocol):
    """pygls's protocol, except that every request gets an answer:

    - a request after ``shutdown`` is answered with InvalidRequest, as the LSP specification says
      (pygls drops it and the client waits for ever);
    - a request whose parameters do not have their types (a negative position, a string for a
      number, a field missing) is answered with InvalidParams: pygls logged it and sent nothing;
    - a message that is not a JSON-RPC request (no ``jsonrpc``, a method that is no name, a batch)
      is answered with InvalidRequest.
    """

    def structure_message(self, data):
        try:
            return super().structure_message(data)
        except JsonRpcException as error:
            method, cause = data.get("method"), error.__cause__
            detail = ""
            if cause is not None:
                try:
                    import cattrs

                    # "... @ $.params.text_document": the field as the client spells it (textDocument)
                    detail = "; ".join(re.sub(r"_([a-z])", lambda m: m[1].upper(), line)
                                       for line in cattrs.transform_error(cause))
                except Exception:   # noqa: BLE001  (not a cattrs error: its own text)
                    detail = str(cause)
            if "id" not in data or "method" not in data:        # a notification or a response
                what = f"the notification {method!r} with invalid params" if "method" in data else \
                    "a response that cannot be read"
                return _Unreadable(None, JsonRpcInvalidParams(what + (f": {detail}" if detail else "")),
                                   answer=False)
            if not isinstance(method, str) or _valid_id(data["id"]) is None:
                return _Unreadable(_valid_id(data["id"]), JsonRpcInvalidRequest(
                    "a request needs a method name (a string) and an id (a string or an integer)"), answer=True)
            return _Unreadable(data["id"], JsonRpcInvalidParams(
                f"invalid params for {method}" + (f": {detail}" if detail else "")), answer=True)

    def send_error(self, msg_id, code: int, message: str) -> None:
        """A JSON-RPC error response; ``msg_id`` None is sent as null (pygls would leave it out)."""
        self._send_data({"jsonrpc": "2.0", "id": msg_id, "error": {"code": code, "message": message}})

    def handle_message(self, message):
        if isinstance(message, _Unreadable):
            if message.answer:
                logger.warning("answered a request with an error: %s", message.error.message)
                self.send_error(message.id, message.error.code, message.error.message)
            else:
                logger.warning("ignored %s", message.error.message)
            return
        if not hasattr(message, "jsonrpc"):            # json that is not a JSON-RPC message
            msg_id = _valid_id(message.get("id")) if isinstance(message, dict) else None
            self.send_error(msg_id, INVALID_REQUEST, "not a JSON-RPC 2.0 message (an object with "
                                                     "\"jsonrpc\": \"2.0\" and a method)")
            return
        msg_id, method = getattr(message, "id", None), getattr(message, "method", None)
        if method is not None and msg_id is not None and (message.jsonrpc != self.VERSION
                                                          or not isinstance(method, str)):
            self.send_error(_valid_id(msg_id), INVALID_REQUEST,
                            f"jsonrpc must be \"2.0\", not {message.jsonrpc!r}" if message.jsonrpc != self.VERSION
                            else "a request needs a method name (a string)")
            return
        if self._shutdown and getattr(message, "method", "exit") != "exit" and msg_id is not None:
            error = JsonRpcInvalidRequest("the server is shut down: only 'exit' is accepted")
            self._send_response(message.id, None, error.to_response_error())
            return
        super().handle_message(message)


class BondcServer(LanguageServer):
    def __init__(self):
        super().__init__("bondc", __version__, protocol_cls=_Protocol)
        self.documents: dict[str, Document] = {}
        self.published: dict[str, set] = {}     # an open document -> the imported files' URIs it reported on

    def report_server_error(self, error: Exception, source) -> None:
        """A body that is not JSON is answered with ParseError (id null: its id cannot be read), as
        JSON-RPC says; pygls only showed the editor a message. Other errors as pygls reports them."""
        if isinstance(error, _NOT_JSON):
            logger.warning("a message from the client is not JSON: %s", error)
            self.protocol.send_error(None, PARSE_ERROR, f"the message is not JSON: {error}")
            return
        super().report_server_error(error, source)

    def analyse(self, uri: str, text: str, version: int) -> None:
        from bondc import semantic

        document = Document(uri, text, version, path_of(uri))
        too_large = _too_large(text)
        if too_large is not None:       # one diagnostic, no index: every feature answers at once
            document.too_large = True
            self.documents[uri] = document
            self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(
                uri=uri, diagnostics=[too_large], version=version))
            for other_uri in self.published.pop(uri, set()):
                if other_uri not in self.documents:
                    self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=other_uri,
                                                                                        diagnostics=[]))
            return
        diagnostics, document.graph = check_text(document.path, text)
        try:
            document.files, _, _ = semantic.load_files(document.path, text)
            document.index = build_index(document.files)
        except BondcError:
            previous = self.documents.get(uri)
            document.files, document.index = (previous.files, previous.index) if previous else ([], None)
        self.documents[uri] = document
        mine = [d for d in diagnostics if not d.span.file or Path(d.span.file) == document.path
                or d.span.file == str(document.path) or d.span.line == 0]
        others = [d for d in diagnostics if d not in mine and not d.span.file.startswith("std:")]
        shown = [to_lsp(d, document.path) for d in mine] + [_at_import(d, document) for d in others]
        self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(
            uri=uri, diagnostics=shown, version=version))
        # and in the imported files themselves (cleared there once they are fixed)
        by_file: dict[str, list] = {}
        for diagnostic in others:
            target = _resolved(diagnostic.span.file, document.path)
            by_file.setdefault(target.as_uri(), []).append(to_lsp(diagnostic, target))
        for other_uri in self.published.get(uri, set()) - set(by_file):
            if other_uri not in self.documents:
                self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=other_uri, diagnostics=[]))
        for other_uri, items in by_file.items():
            if other_uri not in self.documents:
                self.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=other_uri, diagnostics=items))
        self.published[uri] = set(by_file)


def _too_large(text: str) -> lsp.Diagnostic | None:
    """E006 for a buffer beyond :data:`MAX_DOCUMENT_LINES` or :data:`MAX_DOCUMENT_CHARS`, else None."""
    lines = text.count("\n") + (1 if text and not text.endswith("\n") else 0)
    if lines <= MAX_DOCUMENT_LINES and len(text) <= MAX_DOCUMENT_CHARS:
        return None
    return lsp.Diagnostic(
        range=lsp.Range(lsp.Position(0, 0), lsp.Position(0, 0)), severity=lsp.DiagnosticSeverity.Error,
        code="E006", source="bondc",
        message=(f"the document is too large to analyse as you type: {lines} lines, {len(text)} characters "
                 f"(at most {MAX_DOCUMENT_LINES} lines and {MAX_DOCUMENT_CHARS} characters)\n"
                 "run 'bondc check FILE' on it, or split it into files that import each other"),
        code_description=(lsp.CodeDescription(href=_DOCS.as_uri() + "#e006") if _DOCS.exists() else None))


server = BondcServer()


@server.feature(lsp.TEXT_DOCUMENT_DID_OPEN)
def did_open(ls: BondcServer, params: lsp.DidOpenTextDocumentParams):
    document = params.text_document
    ls.analyse(document.uri, document.text, document.version)


@server.feature(lsp.TEXT_DOCUMENT_DID_CHANGE)
async def did_change(ls: BondcServer, params: lsp.DidChangeTextDocumentParams):
    uri, version = params.text_document.uri, params.text_document.version
    await asyncio.sleep(DEBOUNCE)                       # typing: only the last change is checked
    document = ls.workspace.get_text_document(uri)
    if document.version != version:
        return
    ls.analyse(uri, document.source, version)


@server.feature(lsp.TEXT_DOCUMENT_DID_CLOSE)
def did_close(ls: BondcServer, params: lsp.DidCloseTextDocumentParams):
    """A closed file's problems leave the editor's list (a file not open is not checked), with
    those it reported in the files it imports."""
    uri = params.text_document.uri
    ls.documents.pop(uri, None)
    for other in {uri} | ls.published.pop(uri, set()):
        if other not in ls.documents:
            ls.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=other, diagnostics=[]))


@server.feature(lsp.TEXT_DOCUMENT_DID_SAVE)
def did_save(ls: BondcServer, params: lsp.DidSaveTextDocumentParams):
    document = ls.workspace.get_text_document(params.text_document.uri)
    ls.analyse(document.uri, document.source, document.version or 0)


def _at(document: Document, position: lsp.Position):
    """The use or declaration under the cursor: (Symbol or None, Use or None, part index)."""
    index = document.index
    if index is None:
        return None, None, 0
    position = lsp.Position(position.line, server_character(document.text, position.line, position.character))
    here = str(document.path)
    for use in index.uses:
        if use.span.file != here:
            continue
        if use.part_spans:
            for number, span in enumerate(use.part_spans):
                if _contains(span, position.line, position.character):
                    return None, use, number
        elif _contains(use.span, position.line, position.character):
            return None, use, 0
    for symbol in index.symbols:
        if symbol.file == here and _contains(symbol.span, position.line, position.character):
            return symbol, None, 0
    return None, None, 0


def resolve(document: Document, use: Use, part: int = 0) -> Symbol | None:
    """The declaration a use names; through instances for a dotted name."""
    index = document.index
    model = use.model
    if use.call:        # step(...) is the built-in even where an experiment or a parameter is named step
        return next((symbol for owner in (model, None) for symbol in index.symbols
                     if symbol.name == use.name and symbol.model == owner and symbol.category == "function"), None)
    if part == 0 or not use.parts:
        found = index.declared(use.name, model)
        if found is None and use.model is None:
            found = index.declared(use.name, None)
        return found
    symbol = index.declared(use.parts[0], model)
    for number in range(1, part + 1):
        if symbol is None or symbol.category != "instance":
            return None
        kind = symbol.statement.kind.rpartition(".")[2]
        symbol = index.declared(use.parts[number], kind)
    return symbol


def _symbol_at(ls: BondcServer, uri: str, position: lsp.Position) -> Symbol | None:
    document = ls.documents.get(uri)
    if document is None:
        return None
    symbol, use, part = _at(document, position)
    if symbol is not None:
        return symbol
    return resolve(document, use, part) if use is not None else None


def _location(symbol: Symbol) -> lsp.Location | None:
    if symbol.file.startswith("std:"):
        from bondc.std import path_of as std_path

        path = Path(str(std_path(symbol.file[4:])))
    else:
        path = Path(symbol.file).resolve()
    return lsp.Location(path.as_uri(), _range(symbol.span))


def _scoped(ls: BondcServer, uri: str, position: lsp.Position):
    """The declaration at the cursor from the checked model's own scope (bondc.scope), or None."""
    document = ls.documents.get(uri)
    scope = getattr(document.graph, "scope", None) if document is not None else None
    if scope is None:
        return None, None
    character = server_character(document.text, position.line, position.character)
    return scope, scope.at(str(document.path), position.line + 1, character + 1)


def _span_location(span) -> lsp.Location:
    if span.file.startswith("std:"):
        from bondc.std import path_of as std_path

        return lsp.Location(Path(str(std_path(span.file[4:]))).as_uri(), _range(span))
    return lsp.Location(Path(span.file).resolve().as_uri(), _range(span))


@server.feature(lsp.TEXT_DOCUMENT_DEFINITION)
def definition(ls: BondcServer, params: lsp.DefinitionParams):
    document = ls.documents.get(params.text_document.uri)
    if document is not None and document.index is not None:
        _, use, _ = _at(document, params.position)
        if use is not None and use.call:        # a call: an fn, or a built-in (no definition to go to)
            symbol = resolve(document, use)
            return _location(symbol) if symbol is not None else None
    _, declaration = _scoped(ls, params.text_document.uri, params.position)
    if declaration is not None:
        return _span_location(declaration.span)
    symbol = _symbol_at(ls, params.text_document.uri, params.position)
    return _location(symbol) if symbol is not None else None


@server.feature(lsp.TEXT_DOCUMENT_REFERENCES)
def references(ls: BondcServer, params: lsp.ReferenceParams):
    scope, declaration = _scoped(ls, params.text_document.uri, params.position)
    if declaration is not None:
        found = [_span_location(declaration.span)] if params.context.include_declaration else []
        return found + [_span_location(use.span) for use in scope.uses_of(declaration.name)]
    document = ls.documents.get(params.text_document.uri)
    symbol = _symbol_at(ls, params.text_document.uri, params.position)
    if document is None or symbol is None:
        return []
    found = [_location(symbol)] if params.context.include_declaration else []
    for use in document.index.uses:
        for part in range(max(len(use.parts), 1)):
            if resolve(document, use, part) is symbol:
                span = use.part_spans[part] if use.part_spans else use.span
                found.append(lsp.Location(Path(span.file).resolve().as_uri(), _range(span)))
    return found


def hover_text(document: Document, symbol: Symbol) -> str:
    from bondc.fmt import format_law, unit_text

    statement = symbol.statement
    graph = document.graph
    lines = []
    if symbol.category == "parameter":
        written = f"{_expr(statement.value)}" + (f" {unit_text(statement.unit)}" if statement.unit else "")
        lines.append(f"**param {symbol.name}** = {written}")
        if graph is not None and symbol.name in graph.parameters:
            lines.append(f"SI value: `{graph.parameters[symbol.name].value:.6g}`")
        if statement.description:
            lines.append(statement.description)
    elif symbol.category == "element":
        kind = KINDS[statement.kind]
        lines.append(f"**{statement.kind} {symbol.name}** — {kind.description}")
        if statement.description:
            lines.append(statement.description)
        lines += [f"`{format_law(law)}`" for law in statement.laws]
        if graph is not None and symbol.name in graph.elements:
            element = graph.elements[symbol.name]
            bonds = ", ".join(str(b) for b in element.bonds)
            lines.append(f"bonds: {bonds}" + (f"; states: {', '.join(s.qualified for s in element.states)}"
                                              if element.states else ""))
            causality = _causality(document, symbol.name)
            if causality:
                lines.append(causality)
    elif symbol.category in ("instance", "model"):
        model_name = statement.kind.rpartition(".")[2] if symbol.category == "instance" else symbol.name
        found = document.index.models.get(model_name)
        if found is not None:
            model, path = found
            from bondc.flatten import ports_of

            ports = ports_of(model)
            lines.append(f"**{model.name}**" + (f" — {model.description}" if model.description else ""))
            if ports:
                lines.append(f"ports: {', '.join(ports)}")
            params = [s for s in model.body if isinstance(s, ast.Param)]
            if params:
                lines.append("parameters: " + ", ".join(f"{p.name}" + (f" [{p.unit.text}]" if p.unit else "")
                                                        for p in params))
            if symbol.category == "instance" and statement.laws:
                lines.append("bound: " + ", ".join(format_law(law) for law in statement.laws))
    else:
        text = getattr(statement, "description", None)
        lines.append(f"**{symbol.category} {symbol.name}**" + (f" — {text}" if text else ""))
        value = getattr(statement, "value", None)
        if isinstance(value, (ast.Num, ast.Binary, ast.Call, ast.Name, ast.Ref, ast.If, ast.Unary)):
            lines.append(f"`{_expr(value)}`")
    return "\n\n".join(lines)


def _expr(expr) -> str:
    from bondc.fmt import format_expr

    return format_expr(expr)


def _causality(document: Document, name: str) -> str | None:
    try:
        from bondc.causality import assign_causality

        causal = assign_causality(document.graph)
        row = [r for r in causal.summary().get("derivative_storage", []) if r == name]
        setter = causal.effort_setter
        element = document.graph.elements[name]
        parts = []
        for bond in element.bonds:
            parts.append(f"bond {bond}: effort set by {setter.get(bond, '?')}")
        return "; ".join(parts) + (" (derivative causality)" if row else "")
    except BondcError:
        return None


@server.feature(lsp.TEXT_DOCUMENT_HOVER)
def hover(ls: BondcServer, params: lsp.HoverParams):
    document = ls.documents.get(params.text_document.uri)
    symbol = _symbol_at(ls, params.text_document.uri, params.position)
    if document is None:
        return None
    if symbol is None:
        _, use, _ = _at(document, params.position) if document.index is not None else (None, None, 0)
        if use is not None and use.call and use.name in BUILTINS:
            return lsp.Hover(contents=lsp.MarkupContent(
                kind=lsp.MarkupKind.Markdown, value=f"**{use.name}** (built-in): {BUILTINS[use.name].summary}"))
        return None
    return lsp.Hover(contents=lsp.MarkupContent(kind=lsp.MarkupKind.Markdown, value=hover_text(document, symbol)))


_MEMBER = re.compile(r"([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)\.[A-Za-z0-9_]*$")


def completions(document: Document, line_text: str, model: str | None) -> list[lsp.CompletionItem]:
    from bondc.units import unit_names

    index = document.index
    if re.search(r"\[[^\]]*$", line_text):                        # inside a unit
        return [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Unit) for name in unit_names()]
    if index is None:       # a file that never parsed (a new one being written): what needs no index
        words = set(re.findall(r"\b(?:param|input|output|state|discrete)\s+([A-Za-z_]\w*)", document.text))
        return ([lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Variable) for name in sorted(words)]
                + [lsp.CompletionItem(label=kind, kind=lsp.CompletionItemKind.Class, detail=KINDS[kind].description)
                   for kind in KINDS]
                + [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Function, detail=b.summary)
                   for name, b in BUILTINS.items()]
                + [lsp.CompletionItem(label=word, kind=lsp.CompletionItemKind.Keyword) for word in KEYWORDS])
    member = _MEMBER.search(line_text)
    if member:
        parts = member.group(1).split(".")
        symbol = index.declared(parts[0], model)
        for part in parts[1:]:
            if symbol is None or symbol.category != "instance":
                symbol = None
                break
            symbol = index.declared(part, symbol.statement.kind.rpartition(".")[2])
        if symbol is None:
            return []
        if symbol.category == "instance":
            inner = symbol.statement.kind.rpartition(".")[2]
            return [lsp.CompletionItem(label=s.name, kind=lsp.CompletionItemKind.Field, detail=s.category)
                    for s in index.symbols if s.model == inner and s.category in
                    ("port", "element", "junction", "output", "parameter", "instance", "state", "input")]
        if symbol.category == "element":
            kind = KINDS[symbol.statement.kind]
            names = ["p1.e", "p1.f", "p2.e", "p2.f"] if kind.ports == 2 else ["e", "f"]
            names += [kind.state] if kind.state else []
            return [lsp.CompletionItem(label=n, kind=lsp.CompletionItemKind.Field) for n in names]
        if symbol.category == "junction":
            return [lsp.CompletionItem(label="e" if symbol.statement.kind == "0" else "f",
                                       kind=lsp.CompletionItemKind.Field)]
        return []
    items = [lsp.CompletionItem(label=s.name, kind=lsp.CompletionItemKind.Variable, detail=s.category)
             for s in index.symbols if s.model in (model, None) and s.category != "experiment"]
    items += [lsp.CompletionItem(label=kind, kind=lsp.CompletionItemKind.Class, detail=KINDS[kind].description)
              for kind in KINDS]
    items += [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Class, detail="model")
              for name in index.models]
    items += [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Function, detail=b.summary)
              for name, b in BUILTINS.items()]
    items += [lsp.CompletionItem(label=word, kind=lsp.CompletionItemKind.Keyword) for word in KEYWORDS]
    return items


def _model_at(document: Document, line: int) -> str | None:
    if not document.files:
        return None
    for model in document.files[0].models:
        if model.span.line - 1 <= line <= model.span.end_line - 1:
            return model.name
    return None


@server.feature(lsp.TEXT_DOCUMENT_COMPLETION, lsp.CompletionOptions(trigger_characters=[".", "["]))
def completion(ls: BondcServer, params: lsp.CompletionParams):
    document = ls.documents.get(params.text_document.uri)
    if document is None or document.too_large:
        return []
    buffer = ls.workspace.get_text_document(params.text_document.uri)
    lines = buffer.lines
    character = server_character(buffer.source, params.position.line, params.position.character)
    line_text = lines[params.position.line][:character] if params.position.line < len(lines) else ""
    return lsp.CompletionList(is_incomplete=False,
                              items=completions(document, line_text, _model_at(document, params.position.line)))


@server.feature(lsp.TEXT_DOCUMENT_DOCUMENT_SYMBOL)
def document_symbols(ls: BondcServer, params: lsp.DocumentSymbolParams):
    document = ls.documents.get(params.text_document.uri)
    if document is None or document.index is None:
        return []
    kinds = {"parameter": lsp.SymbolKind.Constant, "element": lsp.SymbolKind.Object,
             "instance": lsp.SymbolKind.Module, "junction": lsp.SymbolKind.Struct, "input": lsp.SymbolKind.Variable,
             "output": lsp.SymbolKind.Variable, "state": lsp.SymbolKind.Variable, "function": lsp.SymbolKind.Function,
             "port": lsp.SymbolKind.Interface, "experiment": lsp.SymbolKind.Event,
             "discrete": lsp.SymbolKind.Variable, "bond label": lsp.SymbolKind.Field}
    here = str(document.path)
    out = []
    for model in (document.files[0].models if document.files else ()):
        children = [lsp.DocumentSymbol(name=s.name, detail=s.category, kind=kinds.get(s.category, lsp.SymbolKind.Field),
                                       range=_range(s.span), selection_range=_range(s.span))
                    for s in document.index.symbols if s.model == model.name and s.file == here]
        out.append(lsp.DocumentSymbol(name=model.name, detail=model.description or "model", kind=lsp.SymbolKind.Class,
                                      range=_range(model.span), selection_range=_range(model.name_span),
                                      children=children))
    return out


@server.feature(lsp.TEXT_DOCUMENT_FORMATTING)
def formatting(ls: BondcServer, params: lsp.DocumentFormattingParams):
    from bondc.fmt import fmt

    document = ls.workspace.get_text_document(params.text_document.uri)
    if _too_large(document.source) is not None:
        return None                     # E006 says so
    try:
        formatted = fmt(document.source, str(path_of(document.uri)))
    except (BondcError, OSError):
        return None                     # a syntax error (diagnostics say where), or a file never opened
    if formatted == document.source:
        return []
    lines = document.source.splitlines()
    end = lsp.Position(len(lines), 0)
    return [lsp.TextEdit(range=lsp.Range(lsp.Position(0, 0), end), new_text=formatted)]


def main() -> int:
    """Serve on stdio until the client sends ``exit`` or closes the stream; what the client sends is
    framed by :class:`_Framed` before pygls reads it."""
    stream = _Framed(sys.stdin.buffer, lambda code, message: server.protocol.send_error(None, code, message))
    server.start_io(stdin=stream)
    return 0
