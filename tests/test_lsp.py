"""``bondc lsp``: the language server, driven as an editor does — JSON-RPC over the process's stdio."""

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

# a server process and the flagship: with the slow tests (CI runs them all)
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
FLAGSHIP = ROOT / "models" / "electro_pneumatic_hybrid.bg"
COMPONENTS = ROOT / "tests" / "fixtures" / "components" / "circuit.bg"


class Client:
    """A minimal LSP client: requests and notifications with Content-Length framing."""

    def __init__(self, *arguments):
        self.process = subprocess.Popen([sys.executable, "-m", "bondc", "lsp", *arguments], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        self.next_id = 0
        self.notifications = []

    def send(self, message):
        body = json.dumps(message).encode()
        self.process.stdin.write(f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
        self.process.stdin.flush()

    def read(self):
        length = None
        while True:
            line = self.process.stdout.readline()
            if not line:
                raise EOFError("the server closed its output")
            if line in (b"\r\n", b"\n"):
                break
            if line.lower().startswith(b"content-length:"):
                length = int(line.split(b":")[1])
        return json.loads(self.process.stdout.read(length))

    def request(self, method, params):
        self.next_id += 1
        self.send({"jsonrpc": "2.0", "id": self.next_id, "method": method, "params": params})
        while True:
            message = self.read()
            if message.get("id") == self.next_id and "method" not in message:
                return message.get("result")
            if "method" in message and "id" not in message:
                self.notifications.append(message)

    def notify(self, method, params):
        self.send({"jsonrpc": "2.0", "method": method, "params": params})

    def diagnostics(self, uri, timeout=30.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for message in self.notifications:
                if message["method"] == "textDocument/publishDiagnostics" and message["params"]["uri"] == uri:
                    self.notifications.remove(message)
                    return message["params"]["diagnostics"]
            message = self.read()
            if "method" in message and "id" not in message:
                self.notifications.append(message)
        raise TimeoutError("no diagnostics")

    def open(self, path, text=None, version=1):
        uri = path.resolve().as_uri()
        self.notify("textDocument/didOpen", {"textDocument": {"uri": uri, "languageId": "bondgraph",
                                                               "version": version,
                                                               "text": text if text is not None else path.read_text()}})
        return uri

    def close(self):
        try:
            self.request("shutdown", None)
            self.notify("exit", None)
            self.process.wait(timeout=10)
        finally:
            if self.process.poll() is None:
                self.process.kill()


@pytest.fixture(scope="module")
def client():
    c = Client()
    c.request("initialize", {"processId": None, "rootUri": ROOT.as_uri(), "capabilities": {}})
    c.notify("initialized", {})
    yield c
    c.close()


def test_the_server_accepts_the_stdio_flag_editor_clients_pass():
    """VS Code's language client (TransportKind.stdio), vim-lsp and others start servers with
    --stdio: bondc lsp --stdio must answer initialize (it exited with E001, found by opening the
    flagship in VS Code's workbench)."""
    c = Client("--stdio")
    try:
        result = c.request("initialize", {"processId": None, "rootUri": ROOT.as_uri(), "capabilities": {}})
        assert result["serverInfo"]["name"] == "bondc" and result["capabilities"]["hoverProvider"]
    finally:
        c.close()


def _position(text, needle, offset=0):
    index = text.index(needle) + offset
    line = text.count("\n", 0, index)
    return {"line": line, "character": index - (text.rfind("\n", 0, index) + 1)}


def test_diagnostics_as_you_type_with_codes_and_ranges(client, tmp_path):
    path = tmp_path / "m.bg"
    text = "model M\n  param k = 800 [N/m]\n  Sf s : f = 1\n  C c : e = k*q\n  s -> c\nend\n"
    uri = client.open(path, text)
    assert client.diagnostics(uri) == []
    broken = text.replace("e = k*q", "e = k + kk")
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": broken}]})
    (problem,) = client.diagnostics(uri)
    assert problem["code"] == "E301" and problem["range"]["start"] == {"line": 3, "character": 16}
    assert "did you mean 'k'" in problem["message"] and problem["source"] == "bondc"
    # the link is the code's section of the diagnostics page: a heading there, as GitHub anchors it
    page, _, anchor = problem["codeDescription"]["href"].partition("#")
    assert page.endswith("docs/diagnostics.md") and anchor.startswith("e301-")
    headings = [line[3:].strip() for line in (ROOT / "docs" / "diagnostics.md").read_text().splitlines()
                if line.startswith("## ")]
    assert anchor in {"".join(c for c in h.lower() if c.isalnum() or c in "-_ ").replace(" ", "-") for h in headings}
    # every problem at once, dimensions too
    worse = text.replace("e = k*q", "e = k + q").replace("s -> c", "s -> c\n  s -> nowhere")
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 3},
                                              "contentChanges": [{"text": worse}]})
    problems = client.diagnostics(uri)
    assert "E404" in [d["code"] for d in problems]
    (unknown,) = [d for d in problems if d["code"] == "E404"]
    assert unknown["range"]["start"] == {"line": 5, "character": 7}        # 'nowhere' in 's -> nowhere'
    # edited clean again: the diagnostics are cleared
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 4},
                                              "contentChanges": [{"text": text}]})
    assert client.diagnostics(uri) == []


def test_a_law_error_and_a_causal_conflict_are_both_published(client, tmp_path):
    """Every problem at once: an undefined name in one law, two flow sources on one 1-junction."""
    path = tmp_path / "issue.bg"
    text = ("model Issue\n  param m = 2 [kg]\n  Sf pump : f = 1\n  Sf fan : f = 2\n  I mass : f = p/mm\n"
            "  1 j\n  pump -> j\n  fan -> j\n  j -> mass\nend\n")
    uri = client.open(path, text)
    problems = client.diagnostics(uri)
    assert [(d["code"], d["range"]["start"]) for d in problems] == [
        ("E601", {"line": 3, "character": 5}), ("E301", {"line": 4, "character": 17})]
    assert "flow source 'pump' and flow source 'fan'" in problems[0]["message"]
    # the name fixed: the conflict alone, as the causality stage reports it
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": text.replace("p/mm", "p/m")}]})
    assert [(d["code"], d["message"]) for d in client.diagnostics(uri)] == [("E601", problems[0]["message"])]


def test_the_flagship_is_checked_quickly_after_an_edit(client):
    uri = client.open(FLAGSHIP)
    assert [d for d in client.diagnostics(uri) if d["severity"] == 1] == []
    text = FLAGSHIP.read_text()
    started = time.monotonic()
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": text.replace("31.7", "31.8")}]})
    client.diagnostics(uri)
    # the debounce (0.05 s) plus the check; a generous bound for a loaded CI machine
    assert time.monotonic() - started < 3.0


def test_hover_definition_references_in_a_model(client):
    text = FLAGSHIP.read_text()
    uri = client.open(FLAGSHIP, text)
    client.diagnostics(uri)
    use = _position(text, "e = K*q", 4)                     # the K in the coupling's law
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri}, "position": use})
    assert "param K" in hover["contents"]["value"] and "SI value: `120.9`" in hover["contents"]["value"]
    definition = client.request("textDocument/definition", {"textDocument": {"uri": uri}, "position": use})
    assert definition["range"]["start"]["line"] == text[:text.index("param K ")].count("\n")
    refs = client.request("textDocument/references", {"textDocument": {"uri": uri}, "position": use,
                                                       "context": {"includeDeclaration": True}})
    assert len(refs) >= 3                                   # the declaration, the law, theta0
    element = _position(text, "C  coupling", 4)
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri}, "position": element})
    assert "capacitor" in hover["contents"]["value"] and "e = K*q" in hover["contents"]["value"]
    # completion after a dot on the flagship: a two-port's port variables
    line = text[:text.index("output F_nut")].count("\n")
    items = client.request("textDocument/completion", {"textDocument": {"uri": uri},
                                                       "position": {"line": line, "character": 0}})
    assert {"M", "mass", "TF", "table"} <= {item["label"] for item in items["items"]}
    # formatting the flagship: it is formatted already, so nothing to change
    edits = client.request("textDocument/formatting", {"textDocument": {"uri": uri},
                                                       "options": {"tabSize": 2, "insertSpaces": True}})
    assert edits == []


def test_components_definitions_across_files_and_dotted_completion(client):
    text = COMPONENTS.read_text()
    uri = client.open(COMPONENTS, text)
    assert client.diagnostics(uri) == []
    kind = _position(text, "Orifice valve", 1)
    definition = client.request("textDocument/definition", {"textDocument": {"uri": uri}, "position": kind})
    assert definition["uri"].endswith("lib/hydraulics.bg")
    dotted = _position(text, "valve.Q", 7)                  # the Q of valve.Q: the component's output
    definition = client.request("textDocument/definition", {"textDocument": {"uri": uri}, "position": dotted})
    assert definition["uri"].endswith("lib/hydraulics.bg") and definition["range"]["start"]["line"] == 9
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri}, "position": kind})
    assert "ports: a, b" in hover["contents"]["value"]
    line = text[:text.index("output Q")].count("\n")
    items = client.request("textDocument/completion", {"textDocument": {"uri": uri},
                                                       "position": {"line": line, "character": 27}})
    labels = {item["label"] for item in items["items"]}
    # in an expression, what valve.X may name (flatten.py): values, elements, junctions; a port has no
    # variables there (valve.a is E312)
    assert labels == {"Cd", "A", "rho", "loss", "j", "Q"}
    line = text[:text.index("supply -> valve.a")].count("\n")
    items = client.request("textDocument/completion", {"textDocument": {"uri": uri},
                                                       "position": {"line": line, "character": 18}})
    assert {item["label"] for item in items["items"]} == {"a", "b"}         # in a bond: its ports


def test_outline_completion_and_formatting(client, tmp_path):
    path = tmp_path / "f.bg"
    text = "model F\n  param  k = 800   [N/m]\n  Sf s : f = 1\n  C c : e = k*q\n  s -> c\nend\n"
    uri = client.open(path, text)
    client.diagnostics(uri)
    symbols = client.request("textDocument/documentSymbol", {"textDocument": {"uri": uri}})
    assert symbols[0]["name"] == "F" and {c["name"] for c in symbols[0]["children"]} >= {"k", "s", "c"}
    items = client.request("textDocument/completion", {"textDocument": {"uri": uri},
                                                       "position": {"line": 3, "character": 12}})
    labels = {item["label"] for item in items["items"]}
    assert {"k", "Se", "coulomb", "table"} <= labels
    edits = client.request("textDocument/formatting", {"textDocument": {"uri": uri},
                                                       "options": {"tabSize": 2, "insertSpaces": True}})
    from bondc.fmt import fmt

    assert edits[0]["newText"] == fmt(text)


def test_columns_are_in_utf16_code_units_as_the_server_announced(client, tmp_path):
    """A description with two emoji (each two UTF-16 code units, one character) before an error on the
    same line: the range starts where an editor counting UTF-16 puts it, and hover at that column
    finds the name."""
    path = tmp_path / "u.bg"
    text = ('model U\n  param gain = 2\n  MSe force "\U0001F600\U0001F600 \u00fc" : e = 10 + sprung.e\n'
            '  R r : e = gain*f\n  force -> r\nend\n')
    uri = client.open(path, text)
    (problem,) = [d for d in client.diagnostics(uri) if d["code"] == "E301"]
    line = text.splitlines()[2]
    characters = line.index("sprung")
    utf16 = len(line[:characters].encode("utf-16-le")) // 2
    assert utf16 == characters + 2
    assert problem["range"]["start"] == {"line": 2, "character": utf16}
    assert problem["range"]["end"] == {"line": 2, "character": utf16 + len("sprung.e")}
    fixed = text.replace("10 + sprung.e", "10*gain")
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": fixed}]})
    assert client.diagnostics(uri) == []
    line = fixed.splitlines()[2]
    at = len(line[:line.index("gain")].encode("utf-16-le")) // 2 + 1
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri},
                                                  "position": {"line": 2, "character": at}})
    assert hover is not None and "param gain" in hover["contents"]["value"]


def test_an_error_inside_an_imported_file_is_shown_on_the_import_and_in_that_file(client, tmp_path):
    """`bondc check` reports an undefined name inside an imported component at its place; the editor
    showed the model as clean (only the open file's diagnostics were published)."""
    (tmp_path / "lib").mkdir()
    library = tmp_path / "lib" / "parts.bg"
    library.write_text("model Spring\n  port a\n  param k = 1\n  C c : e = k*q + zz\n  a -> c\nend\n", encoding="utf-8")
    path = tmp_path / "top.bg"
    text = 'import "lib/parts.bg"\nmodel Top\n  Sf s : f = 1\n  Spring sp : k = 3\n  s -> sp.a\nend\n'
    uri = client.open(path, text)
    (shown,) = client.diagnostics(uri)
    assert shown["code"] == "E301" and "zz" in shown["message"]
    assert shown["range"]["start"] == {"line": 0, "character": 0}          # on the import line
    (related,) = shown["relatedInformation"]
    assert related["location"]["uri"] == library.resolve().as_uri()
    assert related["location"]["range"]["start"] == {"line": 3, "character": 18}
    (own,) = client.diagnostics(library.resolve().as_uri())
    assert own["code"] == "E301" and own["range"]["start"] == {"line": 3, "character": 18}
    # fixed: cleared in both
    library.write_text("model Spring\n  port a\n  param k = 1\n  C c : e = k*q\n  a -> c\nend\n", encoding="utf-8")
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": text}]})
    assert client.diagnostics(uri) == []
    assert client.diagnostics(library.resolve().as_uri()) == []


def test_a_closed_file_leaves_the_problem_list_and_formatting_an_unopened_one_is_no_error(client, tmp_path):
    path = tmp_path / "closed.bg"
    uri = client.open(path, "model M\n  Sf s : f = 1\n  C c : e = q/k\n  s -> c\nend\n")
    assert [d["code"] for d in client.diagnostics(uri)] == ["E301"]
    client.notify("textDocument/didClose", {"textDocument": {"uri": uri}})
    assert client.diagnostics(uri) == []
    missing = (tmp_path / "never_written.bg").resolve().as_uri()
    assert client.request("textDocument/formatting", {"textDocument": {"uri": missing},
                                                       "options": {"tabSize": 2, "insertSpaces": True}}) is None


def test_a_new_file_that_never_parsed_still_gets_completion(client, tmp_path):
    """Writing a new model, the file does not parse until its 'end': completion returned nothing,
    not even units inside '['."""
    path = tmp_path / "new.bg"
    text = "model A\n  param stiffness = 800 [N/m]\n  C c : e = sti"
    uri = client.open(path, text)
    client.diagnostics(uri)
    items = client.request("textDocument/completion", {"textDocument": {"uri": uri},
                                                       "position": {"line": 2, "character": len("  C c : e = sti")}})
    labels = {item["label"] for item in items["items"]}
    assert {"stiffness", "sqrt", "table", "Se"} <= labels
    unit = text + "\n  param m = 2 [k"
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": unit}]})
    client.diagnostics(uri)
    items = client.request("textDocument/completion", {"textDocument": {"uri": uri},
                                                       "position": {"line": 3, "character": len("  param m = 2 [k")}})
    assert "kg" in {item["label"] for item in items["items"]}


def test_a_call_of_step_is_the_built_in_even_beside_a_parameter_named_step(client, tmp_path):
    path = tmp_path / "steps.bg"
    text = ("model S\n  param step = 3\n  Se s : e = step*step(t, 0.1)\n  I m : f = p\n  s -> m\n"
            "  experiment step\n    t_end = 1 [s]\n  end\nend\n")
    uri = client.open(path, text)
    client.diagnostics(uri)
    call = {"line": 2, "character": text.splitlines()[2].index("step(") + 1}
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri}, "position": call})
    assert "built-in" in hover["contents"]["value"] and "0 before t0" in hover["contents"]["value"]
    assert client.request("textDocument/definition", {"textDocument": {"uri": uri}, "position": call}) is None
    name = {"line": 2, "character": text.splitlines()[2].index("step*") + 1}
    (found,) = [client.request("textDocument/definition", {"textDocument": {"uri": uri}, "position": name})]
    found = found[0] if isinstance(found, list) else found
    assert found["range"]["start"] == {"line": 1, "character": 8}          # the parameter


def test_a_request_after_shutdown_is_refused_with_invalid_request():
    """The specification: requests after 'shutdown' error with InvalidRequest (-32600). pygls
    dropped them, and a client waiting for the answer waited for ever."""
    c = Client()
    try:
        c.request("initialize", {"processId": None, "rootUri": ROOT.as_uri(), "capabilities": {}})
        c.notify("initialized", {})
        assert c.request("shutdown", None) is None
        c.next_id += 1
        c.send({"jsonrpc": "2.0", "id": c.next_id, "method": "textDocument/hover",
                "params": {"textDocument": {"uri": FLAGSHIP.as_uri()}, "position": {"line": 0, "character": 0}}})
        replies = []

        def answer():
            reply = c.read()
            while "method" in reply:        # notifications still queued
                reply = c.read()
            replies.append(reply)
        reader = threading.Thread(target=answer, daemon=True)
        reader.start()
        reader.join(timeout=30)
        assert replies, "no answer to a request after shutdown"
        reply = replies[0]
        assert reply["id"] == c.next_id and reply["error"]["code"] == -32600, reply
        c.notify("exit", None)
        assert c.process.wait(timeout=10) == 0
    finally:
        if c.process.poll() is None:
            c.process.kill()


RIG = ('import "std:hydraulics"\n\nfn smooth(x, w) = x/sqrt(x^2 + w^2)\n\nmodel Rig\n  param k = 800 [N/m]\n'
       '  param m = 2 [kg]\n  Se s : e = 10*smooth(t - 1, 0.1)\n'
       '  C chamber : state V [m], V(0) = 0, der(V) = f, e = k*V\n  I mass : f = p/m\n  R damper : e = 3*f\n'
       '  1 j\n  s -> j\n  j -> chamber\n  j -> mass\n  j -> damper\n  output stroke [m] = chamber.V\nend\n')


def _labels(client, uri, text, needle, offset):
    items = client.request("textDocument/completion", {"textDocument": {"uri": uri},
                                                       "position": _position(text, needle, offset)})
    return {item["label"] for item in items["items"]}


def test_member_completion_offers_only_the_members_that_exist(client, tmp_path):
    """`chamber.` offered q (an error: the chamber declares its own state) and missed its state."""
    uri = client.open(tmp_path / "rig.bg", RIG)
    assert client.diagnostics(uri) == []
    assert _labels(client, uri, RIG, "chamber.V", len("chamber.")) == {"e", "f", "V"}
    assert _labels(client, uri, RIG, "mass : f", 0) >= {"k", "m", "chamber", "smooth"}
    # the issue's case, on the flagship: its chamber's state is P
    text = FLAGSHIP.read_text()
    uri = client.open(FLAGSHIP, text)
    client.diagnostics(uri)
    assert _labels(client, uri, text, "chamber.P, Ae", len("chamber.")) == {"e", "f", "P"}
    assert _labels(client, uri, text, "piston.p1  #", len("piston.")) == {"p1", "p2"}     # a two-port in a bond
    two_port = RIG.replace("output stroke [m] = chamber.V", "TF lever : r = 2\n  output stroke [m] = lever.p1.f")
    uri = client.open(tmp_path / "lever.bg", two_port)
    client.diagnostics(uri)
    assert _labels(client, uri, two_port, "lever.p1.f", len("lever.")) == {"p1.e", "p1.f", "p2.e", "p2.f"}


def test_hover_on_a_function_call_and_on_an_import(client, tmp_path):
    uri = client.open(tmp_path / "rig.bg", RIG)
    client.diagnostics(uri)
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri},
                                                  "position": _position(RIG, "smooth(t", 2)})
    assert "fn smooth(x, w) = x/sqrt(x^2 + w^2)" in hover["contents"]["value"]
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri},
                                                  "position": _position(RIG, "std:hydraulics", 3)})
    value = hover["contents"]["value"]
    # what std:hydraulics provides, from its own file: its leading comment, each model with its ports
    library = (ROOT / "bondc" / "std" / "hydraulics.bg").read_text()
    import re

    models = re.findall(r"^model (\w+)", library, re.M)
    assert len(models) > 3 and all(f"**{name}**" in value for name in models)
    assert "**Orifice** (a, b)" in value and "hydraulic circuits" in value
    # a file of the project's own: its models
    text = COMPONENTS.read_text()
    uri = client.open(COMPONENTS, text)
    client.diagnostics(uri)
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri},
                                                  "position": _position(text, '"lib/hydraulics.bg"', 2)})
    assert "**Orifice** (a, b): turbulent orifice" in hover["contents"]["value"]


def _apply(text, edits):
    """``text`` with LSP text edits applied (ranges in the original text; ASCII here)."""
    lines = text.splitlines(keepends=True)
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line))

    def offset(position):
        return offsets[position["line"]] + position["character"]
    for edit in sorted(edits, key=lambda e: offset(e["range"]["start"]), reverse=True):
        start, end = offset(edit["range"]["start"]), offset(edit["range"]["end"])
        text = text[:start] + edit["newText"] + text[end:]
    return text


def _rename(client, uri, text, needle, offset, new_name):
    position = _position(text, needle, offset)
    prepared = client.request("textDocument/prepareRename", {"textDocument": {"uri": uri}, "position": position})
    edit = client.request("textDocument/rename", {"textDocument": {"uri": uri}, "position": position,
                                                  "newName": new_name})
    return prepared, _apply(text, edit["changes"][uri])


def test_rename_parameters_elements_functions_and_components(client, tmp_path):
    uri = client.open(tmp_path / "rig.bg", RIG)
    client.diagnostics(uri)
    prepared, renamed = _rename(client, uri, RIG, "k*V", 0, "stiffness")       # from a use
    assert prepared["placeholder"] == "k"
    assert renamed == RIG.replace("param k =", "param stiffness =").replace("k*V", "stiffness*V")
    _, renamed = _rename(client, uri, RIG, "C chamber", 2, "tank")              # in laws and bonds
    assert renamed == RIG.replace("chamber", "tank")
    _, renamed = _rename(client, uri, RIG, "fn smooth", 3, "soft")
    assert renamed == RIG.replace("smooth", "soft")
    # a component, its parameter (bound in the instance) and an instance, across the document
    text = ("model Spring\n  port a\n  param k = 1 [N/m]\n  C c : e = k*q\n  a -> c\n  output x [m] = c.q\nend\n"
            "model Top\n  Sf s : f = 1\n  Spring sp : k = 3 [N/m]\n  s -> sp.a\n  output y [m] = 2*sp.x\nend\n")
    uri = client.open(tmp_path / "parts.bg", text)
    assert client.diagnostics(uri) == []
    _, renamed = _rename(client, uri, text, "Spring sp", 0, "Coil")
    assert renamed == text.replace("Spring", "Coil")
    _, renamed = _rename(client, uri, text, "k*q", 0, "stiffness")
    assert renamed == text.replace("k = ", "stiffness = ").replace("k*q", "stiffness*q")
    _, renamed = _rename(client, uri, text, "sp : k", 0, "spring")
    assert renamed == text.replace("sp :", "spring :").replace("sp.", "spring.")
    _, renamed = _rename(client, uri, text, "output x", 7, "stretch")
    assert renamed == text.replace("output x", "output stretch").replace("sp.x", "sp.stretch")


def test_rename_refuses_clashes_bad_names_and_built_ins(client, tmp_path):
    uri = client.open(tmp_path / "rig.bg", RIG)
    client.diagnostics(uri)

    def error(method, needle, offset, **extra):
        client.next_id += 1
        client.send({"jsonrpc": "2.0", "id": client.next_id, "method": method,
                     "params": {"textDocument": {"uri": uri}, "position": _position(RIG, needle, offset), **extra}})
        while True:
            message = client.read()
            if message.get("id") == client.next_id:
                return message["error"]
            client.notifications.append(message)
    clash = error("textDocument/rename", "param k", 6, newName="m")
    assert clash["code"] == -32803 and "already parameter 'm'" in clash["message"]
    assert "not a name" in error("textDocument/rename", "param k", 6, newName="2k")["message"]
    assert "not a name" in error("textDocument/rename", "param k", 6, newName="model")["message"]
    assert error("textDocument/prepareRename", "sqrt(", 1)["code"] == -32803          # a built-in


def test_quick_fixes_for_did_you_mean(client, tmp_path):
    broken = RIG.replace("e = k*V", "e = kk*V").replace("= chamber.V", "= chamber.VV").replace("[kg]", "[kgg]")
    uri = client.open(tmp_path / "fix.bg", broken)
    problems = client.diagnostics(uri)
    assert sorted(d["code"] for d in problems) == ["E201", "E301", "E312"]
    for problem in problems:
        actions = client.request("textDocument/codeAction", {
            "textDocument": {"uri": uri}, "range": problem["range"],
            "context": {"diagnostics": [problem]}})
        (preferred,) = [a for a in actions if a.get("isPreferred")]
        assert preferred["kind"] == "quickfix" and preferred["diagnostics"][0]["code"] == problem["code"]
        edits = preferred["edit"]["changes"][uri]
        broken_line = broken.splitlines()[problem["range"]["start"]["line"]]
        (edit,) = edits
        written = broken_line[edit["range"]["start"]["character"]:edit["range"]["end"]["character"]]
        assert (written, edit["newText"]) in (("kk", "k"), ("chamber.VV", "chamber.V"), ("kgg", "kg"))
    # all three applied at once (their ranges do not overlap): the model as it was
    every = [client.request("textDocument/codeAction", {"textDocument": {"uri": uri}, "range": p["range"],
                                                        "context": {"diagnostics": [p]}})[0]["edit"]["changes"][uri][0]
             for p in problems]
    assert _apply(broken, every) == RIG


def _big(sections, broken=None):
    """The N-section chain of the benchmarks (11 lines a section); ``broken``: a name that is not
    defined, used in the first spring's law (E301 names it)."""
    from benchmarks.chain import chain_source

    text = chain_source(sections)
    return text if broken is None else text.replace("C k1 : e = k*q", f"C k1 : e = k*q + 0*{broken}")


def _published(client, uri, until_version):
    """Every diagnostics publication for ``uri`` up to and including the one of ``until_version``."""
    found = []
    while not found or found[-1]["version"] != until_version:
        for message in list(client.notifications):
            if message["method"] == "textDocument/publishDiagnostics" and message["params"]["uri"] == uri:
                client.notifications.remove(message)
                found.append(message["params"])
                break
        else:
            message = client.read()
            if "method" in message and "id" not in message:
                client.notifications.append(message)
    return found


def test_a_newer_edit_supersedes_the_analysis_and_stale_diagnostics_are_never_published(client, tmp_path):
    """Each edit names a different undefined name; what is published for a version names that
    version's name, versions only go up, and the last edit's diagnostics come last. Edits sent at
    at once get one publication, for the last of them."""
    path = tmp_path / "big.bg"
    uri = client.open(path, _big(300))
    assert client.diagnostics(uri) == []

    def edit(version):
        body = json.dumps({"jsonrpc": "2.0", "method": "textDocument/didChange", "params": {
            "textDocument": {"uri": uri, "version": version},
            "contentChanges": [{"text": _big(300, f"zz{version}")}]}}).encode()
        return f"Content-Length: {len(body)}\r\n\r\n".encode() + body

    client.process.stdin.write(b"".join(edit(version) for version in range(2, 12)))    # one write
    client.process.stdin.flush()
    (only,) = _published(client, uri, 11)
    (problem,) = only["diagnostics"]
    assert "'zz11'" in problem["message"]
    # edits 0.2 s apart, past the debounce (0.05 s): each starts an analysis of 3 300 lines (a few
    # tenths of a second at least), which the next edit supersedes. The server of before analysed
    # on its event loop and published each version, stale ones included (12 after 13 was sent).
    for version in range(12, 18):
        client.process.stdin.write(edit(version))
        client.process.stdin.flush()
        time.sleep(0.2)
    (last,) = _published(client, uri, 17)
    (problem,) = last["diagnostics"]
    assert "'zz17'" in problem["message"]


def test_a_hover_is_answered_from_the_last_analysis_while_the_next_one_runs(client, tmp_path):
    """Analysis ran on the event loop: a hover sent after an edit waited for the edit's check
    (4-6 s on a 5 000-line model). Now it is answered from the analysis before, ahead of the
    edit's diagnostics."""
    text = _big(600)
    uri = client.open(tmp_path / "hover.bg", text)
    client.diagnostics(uri)
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": _big(600, "zz")}]})
    time.sleep(0.3)         # past the debounce: the edit's analysis (of 6 600 lines, a second or so) has started
    hover = client.request("textDocument/hover", {"textDocument": {"uri": uri},
                                                  "position": _position(text, "k*q", 0)})
    assert "param k" in hover["contents"]["value"]
    assert not [m for m in client.notifications if m["method"] == "textDocument/publishDiagnostics"
                and m["params"]["uri"] == uri]          # the edit's diagnostics had not come yet
    (problem,) = client.diagnostics(uri)
    assert "'zz'" in problem["message"]


@pytest.mark.parametrize("name, declared", [("x_piston", "state x_piston"), ("Ar", "param Ar"), ("psi", "fn psi("),
                                            ("mass", "I  mass"), ("j_chamber", "0  j_chamber"), ("K", "param K")])
def test_renaming_a_name_of_the_flagship_keeps_it_a_valid_model(client, tmp_path, name, declared):
    """Every occurrence is renamed (the state's initial-value law x(0) = ... included), nothing in a
    comment, a string or a unit ([K]), and the result checks as cleanly as the flagship does."""
    import re
    import shutil

    text = FLAGSHIP.read_text()
    copy = tmp_path / FLAGSHIP.name
    shutil.copytree(FLAGSHIP.parent / "data", tmp_path / "data")
    uri = client.open(copy, text)
    assert [d for d in client.diagnostics(uri) if d["severity"] == 1] == []
    _, renamed = _rename(client, uri, text, declared, declared.index(name), "renamed_name")
    code = lambda t: re.sub(r'#.*|"[^"\n]*"|\[[^\]\n]*\]', "", t)      # noqa: E731
    pattern = r"(?<![\w.])%s\b"
    assert len(re.findall(pattern % name, code(renamed))) == 0
    assert len(re.findall(pattern % "renamed_name", code(renamed))) == len(re.findall(pattern % name, code(text)))
    assert re.sub(r"\brenamed_name\b", name, renamed) == text
    client.notify("textDocument/didChange", {"textDocument": {"uri": uri, "version": 2},
                                              "contentChanges": [{"text": renamed}]})
    assert [d for d in client.diagnostics(uri) if d["severity"] == 1] == []
