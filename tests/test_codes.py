"""The registry of diagnostic codes (bondc/codes.py): every code bondc emits is there, once, with a
title, a meaning and a fix, in its stage; the page docs/diagnostics.md has a section for each."""

from __future__ import annotations

import re
from pathlib import Path

from bondc.codes import CODES, STAGES, anchor

ROOT = Path(__file__).resolve().parent.parent


def emitted() -> set[str]:
    """Every code a raise site of bondc/ names (``codes.E201``; as the diagnostics page's generator finds them)."""
    found = set()
    for path in (ROOT / "bondc").rglob("*.py"):
        if path.name == "codes.py":
            continue
        found |= set(re.findall(r"""\bcodes\.([EWI]\d{3})\b""", path.read_text(encoding="utf-8")))
    return found


def test_every_emitted_code_is_in_the_registry_with_its_explanation():
    codes = emitted()
    assert len(codes) > 150                              # (the search finds them)
    missing = codes - set(CODES)
    assert not missing, sorted(missing)
    for code, entry in CODES.items():
        assert entry.code == code and entry.title and entry.meaning and entry.fix, code
        assert entry.stage in {title for title, _ in STAGES}, code
        assert entry.severity == {"E": "error", "W": "warning", "I": "information"}[code[0]]


def test_each_code_has_its_section_on_the_page_at_its_anchor():
    page = (ROOT / "docs" / "diagnostics.md").read_text(encoding="utf-8")
    headings = re.findall(r"^## ([EWI]\d{3} .*)$", page, re.M)
    assert [h.split(" ")[0] for h in headings] and set(h.split(" ")[0] for h in headings) == set(CODES)
    for heading in headings:
        code = heading.split(" ")[0]
        # GitHub's anchor of a heading, written out here: lower case, punctuation dropped, spaces to '-'
        expected = "".join(c for c in heading.lower() if c.isalnum() or c in "-_ ").replace(" ", "-")
        assert anchor(code) == expected, heading


def test_no_code_is_spelled_as_a_string_literal_outside_the_registry():
    """Raise sites name registry entries (``codes.E201``); a code as a bare string literal
    (``"E201"``, a typo the registry would not catch) appears nowhere else in the package."""
    import io
    import tokenize

    spelled = []
    for path in sorted((ROOT / "bondc").rglob("*.py")):
        if path == ROOT / "bondc" / "codes.py":
            continue
        tokens = tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
        spelled += [f"{path.relative_to(ROOT)}:{tok.start[0]}: {tok.string}" for tok in tokens
                    if tok.type == tokenize.STRING and re.fullmatch(r"""(["'])[EWI]\d{3}\1""", tok.string)]
    assert spelled == []
