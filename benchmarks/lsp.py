"""The language server on a 5 000-line model, driven over stdio as an editor drives it.

``python -m benchmarks.lsp [--rounds 5] [--baseline PATH] [--json out.json]``

The model is the mass-spring-damper chain of benchmarks/chain.py with enough sections for
5 000 lines. A client (a reader thread stamps every message the moment it arrives) opens it and
measures, in wall time on this machine:

- **open**: didOpen to the first diagnostics;
- **edit**: didChange (a parameter's value) to the diagnostics of that version, each round;
- **typing**: ten edits 0.3 s apart (each past the debounce, so that an analysis starts and the
  next edit supersedes it), then the time from the last edit to its diagnostics, and how many
  diagnostics were published for a version that was not the newest the client had sent (stale);
- **hover while analysing**: a hover every 50 ms for 1.5 s after an edit (while the edit's
  analysis runs): the largest and the median time to the answer;
- **hover idle**, **outline** (documentSymbol) and **completion** after a dot, with nothing running.

Targets (issue 38): diagnostics within 1 s of the last edit, hover under 100 ms at any time.
``--baseline PATH`` runs the same client against the server of another checkout (e.g. the code
before the change: ``git worktree add /tmp/before <commit>``) and prints the ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.chain import chain_source
from tests.test_lsp_robust import Client as _Client

ROOT = Path(__file__).resolve().parent.parent
LINES = 5000


def model_text() -> str:
    n = 1
    while chain_source(n).count("\n") < LINES:
        n += 50
    while chain_source(n).count("\n") > LINES + 20:
        n -= 1
    return chain_source(n)


class Client(_Client):
    """The test suite's client (a reader thread stamps each message as it arrives), timed."""

    def __init__(self, source: Path | None):
        env = dict(os.environ)
        if source is not None:
            env["PYTHONPATH"] = str(source) + os.pathsep + env.get("PYTHONPATH", "")
        super().__init__(cwd=str(source or ROOT), env=env)

    def send(self, message) -> float:
        sent = time.perf_counter()
        super().send(message)
        return sent

    def notify(self, method, params) -> float:
        return self.send({"jsonrpc": "2.0", "method": method, "params": params})

    def timed(self, method, params):
        """(seconds to the answer, the answer)."""
        self.next_id += 1
        number = self.next_id
        sent = self.send({"jsonrpc": "2.0", "id": number, "method": method, "params": params})
        message = self.reply(number)
        return self.arrived[id(message)] - sent, message.get("result")

    def published(self, uri, version):
        """(arrival time, diagnostics) of the publication of ``version`` for ``uri``."""
        message = self.wait_for(lambda m: m.get("method") == "textDocument/publishDiagnostics"
                                and m["params"]["uri"] == uri and m["params"].get("version") == version,
                                f"diagnostics of version {version}")
        return self.arrived[id(message)], message["params"]["diagnostics"]

    def publications(self, uri):
        """Every publication for ``uri`` received and not taken yet: (arrival time, version)."""
        while not self.messages.empty():
            self.seen.append(self.messages.get_nowait())
        mine = [m for m in self.seen if m and m.get("method") == "textDocument/publishDiagnostics"
                and m["params"]["uri"] == uri]
        self.seen = [m for m in self.seen if not any(m is n for n in mine)]
        return [(self.arrived[id(m)], m["params"].get("version")) for m in mine]

    def close(self):
        try:
            self.finish()
        finally:
            self.kill()


def measure(source: Path | None, rounds: int) -> dict:
    text = model_text()
    folder = Path(tempfile.mkdtemp(prefix="bondc-lsp-bench-"))
    path = folder / "chain.bg"
    path.write_text(text)
    uri = path.resolve().as_uri()
    lines = text.splitlines()
    param = next(i for i, line in enumerate(lines) if line.startswith("  param k ="))
    use = next(i for i, line in enumerate(lines) if line.startswith("  C k1 :"))
    hover_at = {"line": use, "character": lines[use].index("k*q") + 0}
    client = Client(source)
    figures: dict = {"lines": text.count("\n")}
    try:
        client.timed("initialize", {"processId": None, "rootUri": folder.as_uri(), "capabilities": {}})
        client.notify("initialized", {})
        sent = client.notify("textDocument/didOpen", {"textDocument": {"uri": uri, "languageId": "bondgraph",
                                                                       "version": 1, "text": text}})
        arrived, found = client.published(uri, 1)
        figures["open s"] = arrived - sent
        version = 1

        def edit(value):
            nonlocal version
            version += 1
            changed = text.replace("param k = 1000.0", f"param k = {value}")
            return version, client.notify("textDocument/didChange", {
                "textDocument": {"uri": uri, "version": version}, "contentChanges": [{"text": changed}]})

        edits = []
        for number in range(rounds):
            edited, sent = edit(1000 + number + 1)
            arrived, _ = client.published(uri, edited)
            edits.append(arrived - sent)
        figures["edit s"] = edits

        client.publications(uri)
        sent_at = {}
        for number in range(10):
            edited, sent_at[edited] = edit(2000 + number)
            time.sleep(0.3)
        arrived, _ = client.published(uri, edited)
        figures["typing: last edit to its diagnostics s"] = arrived - sent_at[edited]
        published = client.publications(uri)
        stale = 0
        for when, published_version in published:
            newer = [v for v, t in sent_at.items() if t < when and (published_version is None or v > published_version)]
            stale += bool(newer)
        figures["typing: stale publications"] = stale
        figures["typing: publications"] = len(published) + 1

        hovers = []
        edited, sent = edit(3000)
        until = sent + 1.5
        while time.perf_counter() < until:
            took, answer = client.timed("textDocument/hover", {"textDocument": {"uri": uri}, "position": hover_at})
            hovers.append(took)
            time.sleep(0.05)
        client.published(uri, edited)
        figures["hover while analysing s"] = hovers
        figures["hover answered"] = bool(answer)
        idle = [client.timed("textDocument/hover", {"textDocument": {"uri": uri}, "position": hover_at})[0]
                for _ in range(rounds)]
        figures["hover idle s"] = idle
        figures["outline s"] = [client.timed("textDocument/documentSymbol", {"textDocument": {"uri": uri}})[0]
                                for _ in range(rounds)]
        dot = {"line": param, "character": 0}
        figures["completion s"] = [client.timed("textDocument/completion",
                                                  {"textDocument": {"uri": uri}, "position": dot})[0]
                                   for _ in range(rounds)]
    finally:
        client.close()
    return figures


def _summary(values) -> str:
    if isinstance(values, list):
        return f"{min(values):.3f} / {statistics.median(values):.3f} / {max(values):.3f}"
    return f"{values:.3f}" if isinstance(values, float) else str(values)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--baseline", type=Path, help="a checkout whose server to measure as well")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    runs = {"this": measure(None, args.rounds)}
    if args.baseline is not None:
        runs["baseline"] = measure(args.baseline.resolve(), args.rounds)
    keys = [k for k in runs["this"] if k != "lines"]
    print(f"\n### Language server, {runs['this']['lines']}-line model (min / median / max, seconds)\n")
    header = "| measure | this server |" + (" baseline | baseline / this (median) |" if "baseline" in runs else "")
    print(header)
    print("|" + " --- |" * (header.count("|") - 1))
    for key in keys:
        row = f"| {key} | {_summary(runs['this'][key])} |"
        if "baseline" in runs:
            base, this = runs["baseline"].get(key), runs["this"][key]
            ratio = ""
            if isinstance(this, (list, float)) and isinstance(base, (list, float)):
                median = statistics.median(this) if isinstance(this, list) else this
                ratio = f"{(statistics.median(base) if isinstance(base, list) else base) / median:.1f}" if median else ""
            row += f" {_summary(base) if base is not None else ''} | {ratio} |"
        print(row)
    this = runs["this"]
    print(f"\ntargets: diagnostics within 1 s of the last edit: "
          f"{'met' if max(this['edit s']) < 1 and this['typing: last edit to its diagnostics s'] < 1 else 'NOT met'}"
          f"; hover under 0.1 s at any time: "
          f"{'met' if max(this['hover while analysing s'] + this['hover idle s']) < 0.1 else 'NOT met'}")
    if args.json:
        args.json.write_text(json.dumps(runs, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
