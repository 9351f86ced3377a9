"""The VS Code TextMate grammar (editors/vscode), tokenized with vscode-textmate and vscode-oniguruma
(npm) on every model and library file, against what bondc's own parser says each piece is."""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from bondc import ast
from bondc.model import KINDS
from bondc.parse import parse_source
from bondc.source import Source

ROOT = Path(__file__).resolve().parent.parent
EDITOR = ROOT / "editors" / "vscode"
FILES = (sorted(ROOT.glob("models/*.bg")) + sorted((ROOT / "bondc" / "std").glob("*.bg"))
         + [ROOT / "tests" / "fixtures" / name for name in ("components/circuit.bg", "motors/dc_screw.bg",
                                                           "language/s11_submodels.bg")])
COMPONENT = "entity.name.type.component.bondgraph"
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
    instances = set()
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
            elif isinstance(statement, ast.Element) and statement.kind in KINDS:
                kind = statement.kind_span
                assert "storage.type.element.bondgraph" in _scopes_at(lines, kind.line, kind.column), statement.name
                checked += 1
            elif isinstance(statement, ast.Element):        # an instance: its type is the component's
                kind = statement.kind_span
                for column in range(kind.column, kind.end_column):
                    assert COMPONENT in _scopes_at(lines, kind.line, column), (statement.name, column)
                name = statement.name_span
                assert "entity.name.variable.instance.bondgraph" in _scopes_at(lines, name.line, name.column)
                instances.add((kind.line, kind.column))
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
    # and nothing else is taken for a component's type (a keyword, an element, a bond, a law)
    for number, tokens in enumerate(lines, start=1):
        column = 1
        for text, scopes in tokens:
            if COMPONENT in scopes and text.strip():
                assert (number, column) in instances, (number, text)
                break
            column += len(text)


def _expressions(statement):
    found = []
    for value in vars(statement).values():
        for item in value if isinstance(value, tuple) else (value,):
            if isinstance(item, (ast.Num, ast.Name, ast.Ref, ast.Call, ast.Binary, ast.Unary, ast.If, ast.ListExpr)):
                found += list(ast.walk(item))
            elif isinstance(item, (ast.LawAssign, ast.LawCall)):
                found += list(ast.walk(item.value))
    return found


@pytest.mark.slow
def test_the_extension_packages_without_warnings(tmp_path):
    """`vsce package` warned about a missing repository field, LICENSE and .vscodeignore, and
    packed the end-to-end check's screenshots and 168 unbundled JavaScript files of node_modules."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are needed to package the extension")
    manifest = (EDITOR / "package.json").read_text()
    import hashlib
    import zipfile

    modules = NPM_CACHE / ("extension-" + hashlib.sha256(manifest.encode()).hexdigest()[:12])
    if not (modules / "node_modules" / ".bin" / "vsce").exists():
        modules.mkdir(parents=True, exist_ok=True)
        (modules / "package.json").write_text(manifest)
        done = subprocess.run(["npm", "install", "--no-audit", "--no-fund"], cwd=modules, capture_output=True,
                              text=True, timeout=600)
        if done.returncode != 0:
            pytest.skip(f"npm could not install the extension's dependencies: {done.stderr[-300:]}")
    folder = tmp_path / "vscode"
    shutil.copytree(EDITOR, folder, ignore=shutil.ignore_patterns("node_modules", "dist", "*.vsix"))
    (folder / "node_modules").symlink_to(modules / "node_modules")
    out = subprocess.run([str(folder / "node_modules" / ".bin" / "vsce"), "package", "-o", str(tmp_path / "b.vsix")],
                         cwd=folder, capture_output=True, text=True, timeout=600, input="n\n")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "WARNING" not in out.stdout + out.stderr, out.stdout + out.stderr
    names = zipfile.ZipFile(tmp_path / "b.vsix").namelist()
    assert {"extension/package.json", "extension/dist/extension.js", "extension/LICENSE.txt",
            "extension/syntaxes/bondgraph.tmLanguage.json", "extension/language-configuration.json"} <= set(names)
    assert not [n for n in names if "e2e" in n or n.endswith(".png") or "node_modules" in n], names
    assert (EDITOR / "LICENSE").read_text() == (ROOT / "LICENSE").read_text()
    packed = json.loads(zipfile.ZipFile(tmp_path / "b.vsix").read("extension/package.json"))
    assert packed["main"] == "./dist/extension.js" and packed["repository"]
