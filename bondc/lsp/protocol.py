"""The JSON-RPC layer of ``bondc lsp``: the client's byte stream framed with bounded memory
(:class:`_Framed`), and a protocol that answers every request, even one it cannot read
(:class:`_Protocol`)."""

from __future__ import annotations

import json
import logging
import re

from pygls.exceptions import JsonRpcException, JsonRpcInvalidParams, JsonRpcInvalidRequest
from pygls.protocol import LanguageServerProtocol

#: The largest message read from the client [bytes]; a larger one is skipped (a JSON-RPC error says so).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
#: The largest header block of a message [bytes] (a header is a line or two: Content-Length, Content-Type).
MAX_HEADER_BYTES = 8192

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

