"""The VS Code TextMate grammar (editors/vscode), tokenized with vscode-textmate and vscode-oniguruma
(npm) on every model and library file, against what bondc's own parser says each piece is."""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from bondc import ast
from bondc.parse import parse_source
from bondc.source import Source

ROOT = Path(__file__).resolve().parent.parent
EDITOR = ROOT / "editors" / "vscode"
FILES = sorted(ROOT.glob("models/*.bg")) + sorted((ROOT / "bondc" / "std").glob("*.bg"))
NPM_CACHE = Path(os.environ.get("BONDC_NPM_DIR", "/tmp/bondc-test-npm-%d" % os.getuid()))


@pytest.fixture(scope="module")
def tokens():
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are needed to run VS Code's TextMate tokenizer")
    if not (NPM_CACHE / "node_modules" / "vscode-textmate").exists():
        NPM_CACHE.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--prefix", str(NPM_CACHE),
                               "vscode-textmate@9", "vscode-oniguruma@2"], capture_output=True, text=True, timeout=300)
        if done.returncode != 0:
            pytest.skip(f"npm could not install vscode-textmate: {done.stderr[-300:]}")
    env = dict(os.environ, NODE_PATH=str(NPM_CACHE / "node_modules"))
    out = subprocess.run(["node", str(EDITOR / "test" / "tokenize.js"), *map(str, FILES)], capture_output=True,
                         text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def _scopes_at(lines, line: int, column: int) -> list[str]:
    """The scopes of the token at 1-based (line, column)."""
    position = 0
    for text, scopes in lines[line - 1]:
        if position <= column - 1 < position + len(text):
            return scopes
        position += len(text)
    return []


@pytest.mark.slow
@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_the_grammar_agrees_with_the_parser(tokens, path):
    lines = tokens[str(path)]
    text = path.read_text(encoding="utf-8")
    file = parse_source(Source(str(path), text, path))
    assert len(lines) == text.count("\n") + 1
    for comment in file.comments:
        assert any(s.startswith("comment.line") for s in _scopes_at(lines, comment.span.line, comment.span.column))
    checked = 0
    for model in file.models:
        assert "entity.name.type.model.bondgraph" in _scopes_at(lines, model.name_span.line, model.name_span.column)
        for statement in model.body:
            where = (statement.span.line, statement.span.column)
            if isinstance(statement, ast.Param):
                assert "keyword.other.bondgraph" in _scopes_at(lines, *where)
                if statement.unit is not None:
                    unit = statement.unit.span
                    assert "keyword.other.unit.bondgraph" in _scopes_at(lines, unit.line, unit.column)
                checked += 1
            elif isinstance(statement, ast.Element) and len(statement.kind) <= 3:
                kind = statement.kind_span
                assert "storage.type.element.bondgraph" in _scopes_at(lines, kind.line, kind.column), statement.name
                checked += 1
            elif isinstance(statement, ast.Junction):
                assert "storage.type.junction.bondgraph" in _scopes_at(lines, *where)
            elif isinstance(statement, (ast.PortDecl, ast.Defaults)):
                assert "keyword.other.bondgraph" in _scopes_at(lines, *where)
            elif isinstance(statement, ast.BondChain) and len(statement.endpoints) > 1:
                first = statement.endpoints[0].span
                arrow = text.splitlines()[first.line - 1].index("->", first.column - 1) + 1
                assert "keyword.operator.bond.bondgraph" in _scopes_at(lines, first.line, arrow)
            for node in _expressions(statement):
                if isinstance(node, ast.Call) and node.func in ("sqrt", "abs", "sign", "table", "coulomb", "max"):
                    span = node.func_span
                    assert "support.function.builtin.bondgraph" in _scopes_at(lines, span.line, span.column)
    assert checked > 0


def _expressions(statement):
    found = []
    for value in vars(statement).values():
        for item in value if isinstance(value, tuple) else (value,):
            if isinstance(item, (ast.Num, ast.Name, ast.Ref, ast.Call, ast.Binary, ast.Unary, ast.If, ast.ListExpr)):
                found += list(ast.walk(item))
            elif isinstance(item, (ast.LawAssign, ast.LawCall)):
                found += list(ast.walk(item.value))
    return found
