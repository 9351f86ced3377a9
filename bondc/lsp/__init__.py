"""``bondc lsp``: a Language Server Protocol server on stdio (pygls), for editors.

It works on the editor's buffers, saved or not:

- diagnostics as you type (debounced): everything ``bondc check`` reports up to
  causality — syntax, names, units and dimensions, causal conflicts — with the
  same codes, ranges and related locations, every model of the file; a quick fix
  for each "did you mean" (code action);
- hover: an element's kind, laws, bonds and causality; a parameter's value in
  SI and as written; a component's ports and description; a function's
  signature and body; what an ``import`` brings;
- go to definition and find references for parameters, elements, junctions,
  functions, models and components (across imports, ``std:`` included), and
  dotted names (``valve.loss.f``); rename of what the document declares;
- completion of names, element kinds, built-ins, units, and members after a
  dot (``valve.`` lists what the instance has; ``chamber.`` the element's effort,
  flow and states);
- document symbols (the outline) and formatting (``bondc fmt``).

The modules: :mod:`~bondc.lsp.protocol` (framing and JSON-RPC answers),
:mod:`~bondc.lsp.positions` (columns in the client's encoding, one line table per
version), :mod:`~bondc.lsp.analysis` (the check of a buffer on a worker thread,
superseded by a newer edit), :mod:`~bondc.lsp.index` (declarations and uses),
:mod:`~bondc.lsp.features` (the answers) and :mod:`~bondc.lsp.server` (the handlers).

A client that sends bad input is answered and served on: a message that cannot be framed (no
Content-Length, one that is not a number, one above :data:`MAX_MESSAGE_BYTES`) or is not JSON gets
a JSON-RPC error with id null and reading goes on at the next message (:class:`_Framed`); a request
with parameters of the wrong shape gets InvalidParams (:class:`_Protocol`); a buffer beyond
:data:`MAX_DOCUMENT_LINES` lines or :data:`MAX_DOCUMENT_CHARS` characters is not analysed (one
diagnostic, E006), so that the server keeps answering.
"""

from bondc.lsp.analysis import MAX_DOCUMENT_CHARS, MAX_DOCUMENT_LINES, check_text
from bondc.lsp.index import build_index
from bondc.lsp.positions import path_of
from bondc.lsp.protocol import MAX_HEADER_BYTES, MAX_MESSAGE_BYTES, _Framed
from bondc.lsp.server import DEBOUNCE, main, server

__all__ = ["DEBOUNCE", "MAX_DOCUMENT_CHARS", "MAX_DOCUMENT_LINES", "MAX_HEADER_BYTES", "MAX_MESSAGE_BYTES",
           "_Framed", "build_index", "check_text", "main", "path_of", "server"]
