"""Golden files of the semantic stage: one small bad model per diagnostic code.

``tests/golden/check/<CODE>_<slug>.bg`` is checked from its own folder (so file
names in messages are relative) and compared with ``<same>.txt`` (the rendered
diagnostics, exactly as ``bondc check`` prints them) and ``<same>.json`` (the
``Diagnostic.to_json()`` list). A first line ``# check: --model M --experiment E
--set "k=2"`` passes those options. ``pytest --update-golden`` rewrites the
expected files; review the carets by eye before committing them.

Files in ``lib/`` and ``data/`` are what the cases import and read.
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

from bondc import semantic
from bondc.errors import ModelError, render_all
from bondc.parse import parse_set_value

GOLDEN = Path(__file__).resolve().parent / "golden" / "check"
CASES = sorted(GOLDEN.glob("*.bg"))
DOCS = Path(__file__).resolve().parent.parent / "docs" / "diagnostics.md"


def _options(path: Path) -> dict:
    first = path.read_text(encoding="utf-8").splitlines()[0]
    if not first.startswith("# check:"):
        return {}
    words = shlex.split(first[len("# check:"):])
    options: dict = {"sets": []}
    for flag, value in zip(words[::2], words[1::2]):
        if flag == "--set":
            options["sets"].append(parse_set_value(value))
        else:
            options[flag.lstrip("-")] = value
    return options


def check(path: Path) -> list:
    """The diagnostics ``bondc check`` reports for one golden case (errors, or else warnings)."""
    try:
        _, diagnostics = semantic.load(path.name, **_options(path))
    except ModelError as error:
        diagnostics = error.diagnostics
    return diagnostics


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_golden(path, monkeypatch, update_golden):
    monkeypatch.chdir(GOLDEN)
    diagnostics = check(path)
    rendered = render_all(diagnostics) + "\n"
    as_json = json.dumps([d.to_json() for d in diagnostics], indent=2) + "\n"
    text_file, json_file = path.with_suffix(".txt"), path.with_suffix(".json")
    if update_golden:
        text_file.write_text(rendered, encoding="utf-8")
        json_file.write_text(as_json, encoding="utf-8")
    assert rendered == text_file.read_text(encoding="utf-8")
    assert as_json == json_file.read_text(encoding="utf-8")


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_case_shows_its_code(path, monkeypatch):
    monkeypatch.chdir(GOLDEN)
    code = path.stem.split("_")[0]
    assert code in {d.code for d in check(path)}


def _codes_in_semantic() -> set[str]:
    source = "".join(path.read_text(encoding="utf-8") for path in sorted(Path(semantic.__file__).parent.glob("*.py")))
    return set(re.findall(r"\bcodes\.([EW][2-6][0-9]{2})\b", source)) | {"E201", "E311"}


def test_every_code_has_a_golden_case():
    cased = {path.stem.split("_")[0] for path in CASES}
    assert _codes_in_semantic() - cased == set()


def test_every_code_is_documented():
    documented = set(re.findall(r"^## ([EW][0-9]{3})\b", DOCS.read_text(encoding="utf-8"), re.MULTILINE))
    assert _codes_in_semantic() - documented == set()


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_docs_show_the_golden_output(path):
    """docs/diagnostics.md quotes every case and its output; update it when a golden changes."""
    docs = DOCS.read_text(encoding="utf-8")
    assert path.read_text(encoding="utf-8").rstrip("\n") in docs
    assert path.with_suffix(".txt").read_text(encoding="utf-8").rstrip("\n") in docs
