"""Fuzz harness: mutants of every model in the project, checked and simulated as a user would.

The corpus is every ``.bg`` file under ``models/`` and ``tests/``. Each mutant
changes one to three lines of one file with a seeded random generator:

- delete, duplicate or swap lines;
- insert a token;
- replace a number by an extreme one (0, -1, 1e308, 1e-320, 1e309);
- swap an operator.

Every mutant goes through ``bondc check``. A sample of those that pass also
goes through ``bondc simulate``, in a subprocess with a time limit, and another
through ``bondc linearize`` and ``bondc equations --format latex``. The outcome
must be a normal exit (0, 1 or 2), never an internal error (exit 3) or a
Python traceback, and never a hang. Every error diagnostic of ``check`` must
name where it is: ``file:line:col``, or the file for a whole-file problem. The
counts are printed in the test session's summary (see ``conftest.py``).

Beside the mutants, ``SHAPES`` generate small inputs of the shapes that once made bondc run
without end, crash, show another file or drive the terminal (functions or components that double
at every level, huge literals and paths, files that are not models or tables, control bytes).

Mutants are reproducible: ``FUZZ_SEED`` picks the sequence, ``FUZZ_CHECKS`` and
``FUZZ_RUNS`` its length. Both tests are marked slow, so CI runs them.
"""

from __future__ import annotations

import io
import os
import random
import re
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

from bondc.cli import main

ROOT = Path(__file__).resolve().parent.parent
CORPUS = sorted(p for p in [*ROOT.glob("models/**/*.bg"), *ROOT.glob("tests/**/*.bg")] if p.is_file())
SEED = int(os.environ.get("FUZZ_SEED", "20261124"))
CHECKS = int(os.environ.get("FUZZ_CHECKS", "400"))
RUNS = int(os.environ.get("FUZZ_RUNS", "24"))
RUN_LIMIT = 60.0        # seconds for one simulate of a mutant (no run may hang)

TOKENS = ["->", ":", "=", "(", ")", "[", "]", ",", ".", "+", "-", "*", "/", "^", "end", "model", "param",
          "if", "then", "else", "0", "1", "1e309", "x", "e", "f", "q", "p", '"s"', "#", "[kg]", "[m/s]",
          "sqrt(", "step(t, 1)", "table(t, [0, 1], [0, 1])", "0 j", "1 j", "R r", "C c", "I i", "Se s"]
EXTREME = ["0", "-1", "1e308", "1e-320", "1e309", "0.0", "-0", "123456789012345678901234567890"]
OPERATORS = {"+": "-", "-": "+", "*": "/", "/": "*", "^": "*", "<": ">=", ">": "<="}
NUMBER = re.compile(r"(?<![\w.])\d+(\.\d*)?([eE][+-]?\d+)?")

SUMMARY: dict = {}      # printed by conftest.pytest_terminal_summary


def mutate(text: str, rng: random.Random) -> str:
    lines = text.split("\n")
    for _ in range(rng.randint(1, 3)):
        if not lines:
            break
        index = rng.randrange(len(lines))
        action = rng.choice(["delete", "duplicate", "swap", "insert", "number", "number", "operator"])
        if action == "delete":
            del lines[index]
        elif action == "duplicate":
            lines.insert(index, lines[rng.randrange(len(lines))])
        elif action == "swap":
            other = rng.randrange(len(lines))
            lines[index], lines[other] = lines[other], lines[index]
        elif action == "insert":
            cut = rng.randint(0, len(lines[index]))
            lines[index] = lines[index][:cut] + " " + rng.choice(TOKENS) + " " + lines[index][cut:]
        elif action == "number":
            numbers = list(NUMBER.finditer(lines[index]))
            if numbers:
                found = rng.choice(numbers)
                lines[index] = lines[index][:found.start()] + rng.choice(EXTREME) + lines[index][found.end():]
        else:
            spots = [i for i, char in enumerate(lines[index]) if char in OPERATORS]
            if spots:
                i = rng.choice(spots)
                lines[index] = lines[index][:i] + OPERATORS[lines[index][i]] + lines[index][i + 1:]
    return "\n".join(lines)


def mutants(count: int, seed: int):
    """``count`` (source path, mutant text) pairs, the same for the same seed."""
    rng = random.Random(seed)
    texts = {path: path.read_text(encoding="utf-8") for path in CORPUS}
    for _ in range(count):
        path = rng.choice(CORPUS)
        yield path, mutate(texts[path], rng)


def _place(tmp_path: Path, source: Path, text: str, number: int) -> Path:
    """The mutant beside a copy of its source's data files (imports and csv paths resolve alike)."""
    folder = tmp_path / f"m{number}"
    folder.mkdir()
    for sibling in source.parent.iterdir():
        if sibling.is_dir() and sibling.name in ("data", "lib"):
            (folder / sibling.name).symlink_to(sibling)
        elif sibling.suffix in (".csv", ".bg") and sibling != source:
            (folder / sibling.name).symlink_to(sibling)
    path = folder / source.name
    path.write_text(text, encoding="utf-8")
    return path


def _check(path: Path) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(["check", str(path)])
    return code, err.getvalue()


def _tally(what: str, outcomes: dict, problems: list) -> str:
    """The summary line of a fuzz test: what ran, its exit codes and the problems."""
    return (f"{what}: " + ", ".join(f"exit {code}: {count}" for code, count in sorted(outcomes.items()))
            + f"; {len(problems)} problems")


@pytest.mark.slow
def test_mutants_of_every_model_are_checked_without_an_internal_error(tmp_path, monkeypatch):
    monkeypatch.setenv("BONDC_CACHE", "0")
    outcomes = {0: 0, 1: 0, 2: 0}
    problems = []
    for number, (source, text) in enumerate(mutants(CHECKS, SEED)):
        path = _place(tmp_path, source, text, number)
        code, err = _check(path)
        if code not in outcomes or "Traceback" in err or "internal error" in err:
            problems.append(f"{source.relative_to(ROOT)} mutant {number}: exit {code}\n{err[-800:]}")
            continue
        outcomes[code] += 1
        for line in err.splitlines():
            # every model error names where: file:line:col, or the file for a whole-file one (E309 "no
            # model in"); only command-line errors (E0xx) name no file
            if line.startswith("error[") and not line.startswith("error[E0"):
                problems.append(f"{source.relative_to(ROOT)} mutant {number}: an error without a position: {line}")
    SUMMARY["check"] = (f"{CHECKS} mutants of {len(CORPUS)} models (seed {SEED}): {outcomes[0]} valid, "
                        f"{outcomes[1]} with model errors, {outcomes[2]} usage errors, {len(problems)} problems")
    assert not problems, "\n\n".join(problems[:5])


# -- hostile shapes: small inputs that once made bondc work without end, crash or show other files

_SHAPE_MODEL = "model M\n  param k = 2\n  {kind} s : e = {law}\n  R r : f = e/k\n  s -> r\n{extra}end\n"


def _exploding_functions(rng: random.Random) -> tuple[str, dict, str]:
    depth = rng.randint(25, 40)
    twice = rng.choice(["f{p}(x + 1) + f{p}(2*x)", "f{p}(3*x) + f{p}(x + 1)", "f{p}(x + 1) - f{p}(x/2)"])
    lines = ["fn f0(x) = x*x"] + [f"fn f{i}(x) = " + twice.format(p=i - 1) for i in range(1, depth + 1)]
    where = rng.choice(["param", "law", "setting"])
    law = f"f{depth}(k)" if where == "law" else "k"
    extra = f"  experiment x\n    t_end = f{depth}(0.5)\n  end\n" if where == "setting" else ""
    text = "\n".join(lines) + "\n" + _SHAPE_MODEL.format(kind="Se", law=law, extra=extra)
    if where == "param":
        text = text.replace("param k = 2", f"param k = 1 + f{depth}(0.5)")
    return text, {}, "E319"


def _nested_components(rng: random.Random) -> tuple[str, dict, str]:
    depth, copies = rng.randint(16, 40), rng.randint(2, 3)
    parts = ["model C0\n  port a, b\n  R r : e = 2*f\n  1 j\n  a -> j -> b\n  j -> r\nend\n"]
    for i in range(1, depth + 1):
        names = [f"x{c}" for c in range(copies)]
        body = "".join(f"  C{i - 1} {name}\n" for name in names)
        chain = " -> ".join(["a"] + [f"{n}.a" for n in names[:1]]) + "\n"
        links = "".join(f"  {a}.b -> {b}.a\n" for a, b in zip(names, names[1:]))
        parts.append(f"model C{i}\n  port a, b\n{body}  {chain}{links}  {names[-1]}.b -> b\nend\n")
    parts.append(f"model Top\n  Se s : e = 1\n  C{depth} c\n  R load : e = f\n  s -> c.a\n  c.b -> load\nend\n")
    return "\n".join(parts), {}, "E319"


def _huge_literal(rng: random.Random) -> tuple[str, dict, str]:
    return _SHAPE_MODEL.format(kind="Se", law="1" * rng.randint(4301, 20000), extra=""), {}, "E701"


def _long_import(rng: random.Random) -> tuple[str, dict, str]:
    return f'import "{"d/" * rng.randint(3000, 6000)}x.bg"\n' + _SHAPE_MODEL.format(kind="Se", law="1", extra=""), \
        {}, "E307"


def _foreign_files(rng: random.Random) -> tuple[str, dict, str]:
    secret = "".join(rng.choice("abcdefghij:=,/\x00\n") for _ in range(200)) + "SECRET_TOKEN"
    if rng.random() < 0.5:
        return 'import "notes.txt"\n' + _SHAPE_MODEL.format(kind="Se", law="1", extra=""), \
            {"notes.txt": secret}, "E307"
    return _SHAPE_MODEL.format(kind="MSe", law='csv("notes.txt", "x")', extra=""), {"notes.txt": secret}, "E310"


def _control_bytes(rng: random.Random) -> tuple[str, dict, str]:
    junk = "".join(rng.choice("\x1b\x07\x08\x0b\x0c\x7f[]31m;") for _ in range(rng.randint(1, 30)))
    return _SHAPE_MODEL.format(kind="Se", law="1 + " + junk, extra=""), {}, "E10"


def _huge_unit(rng: random.Random) -> tuple[str, dict, str]:
    unit = "".join(rng.choice("kgmNsx") for _ in range(rng.randint(10_000, 300_000)))
    return _SHAPE_MODEL.format(kind="Se", law="1", extra="").replace("param k = 2", f"param k = 2 [{unit}]"), {}, "E201"


def _infinite_si(rng: random.Random) -> tuple[str, dict, str]:
    unit, value = rng.choice([("kN/m", "1e308"), ("MPa", "1e303"), ("h", "1e305"), ("GW", "1.7e300")])
    return _SHAPE_MODEL.format(kind="Se", law="1", extra="").replace("param k = 2", f"param k = {value} [{unit}]"), \
        {}, "E311"


SHAPES = [_exploding_functions, _nested_components, _huge_literal, _long_import, _foreign_files, _control_bytes,
          _huge_unit, _infinite_si]


@pytest.mark.slow
@pytest.mark.parametrize("shape", SHAPES, ids=lambda shape: shape.__name__.strip("_"))
def test_hostile_shapes_are_diagnosed_without_a_hang_a_crash_or_a_leak(tmp_path, monkeypatch, shape):
    """Generated inputs of the shapes that once ran without end (2^40 function bodies, 2^40
    component copies), crashed (a 5000-digit integer in a law, an import path longer than the
    system allows, an SI value beyond a double), showed another file (import or csv() of a file
    that is not a model or a table) or drove the terminal (control bytes): each is a diagnostic
    with its code, with nothing of the other file and no raw control byte in the output. A bound
    enforced, not a speed: the limits are E319's."""
    monkeypatch.setenv("BONDC_CACHE", "0")
    rng = random.Random(f"{SEED}-{shape.__name__}")
    for number in range(3):
        text, files, code = shape(rng)
        folder = tmp_path / f"s{number}"
        folder.mkdir()
        for name, content in files.items():
            (folder / name).write_text(content)
        path = folder / "shape.bg"
        path.write_text(text)
        options = ["--model", "Top"] if "model Top" in text else []
        out, err = io.StringIO(), io.StringIO()
        with redirect_stdout(out), redirect_stderr(err):
            status = main(["check", str(path), *options])
        shown = err.getvalue()
        assert status == 1, f"{shape.__name__} #{number}: exit {status}\n{shown[-800:]}"
        assert f"error[{code}" in shown, shown[-800:]
        assert "Traceback" not in shown and "internal error" not in shown
        assert "SECRET_TOKEN" not in shown and not any(c in shown for c in "\x1b\x07\x00")


@pytest.mark.slow
def test_mutants_that_check_are_simulated_without_a_crash_or_a_hang(tmp_path):
    environment = {**os.environ, "BONDC_CACHE": "0", "PYTHONPATH": str(ROOT)}
    ran, outcomes, problems = 0, {}, []
    for number, (source, text) in enumerate(mutants(CHECKS, SEED + 1)):
        if ran >= RUNS:
            break
        path = _place(tmp_path, source, text, number)
        if _check(path)[0] != 0 or "experiment" not in text:
            continue
        ran += 1
        try:
            done = subprocess.run([sys.executable, "-m", "bondc", "simulate", str(path), "--json"],
                                  capture_output=True, text=True, timeout=RUN_LIMIT, env=environment)
        except subprocess.TimeoutExpired:
            problems.append(f"{source.relative_to(ROOT)} mutant {number}: no result in {RUN_LIMIT:g} s")
            continue
        outcomes[done.returncode] = outcomes.get(done.returncode, 0) + 1
        if done.returncode not in (0, 1, 2) or "Traceback" in done.stderr or "internal error" in done.stderr:
            problems.append(f"{source.relative_to(ROOT)} mutant {number}: exit {done.returncode}\n"
                            f"{done.stderr[-800:]}")
    SUMMARY["simulate"] = _tally(f"{ran} mutants that check simulated (limit {RUN_LIMIT:g} s each)", outcomes,
                                 problems)
    assert ran >= min(RUNS, 5), "too few mutants passed check to simulate"
    assert not problems, "\n\n".join(problems[:5])


@pytest.mark.slow
def test_mutants_that_check_are_linearised_and_printed_without_an_internal_error(tmp_path, monkeypatch):
    """``linearize`` evaluates the equations at an operating point (a law's infinite slope there, a
    division by zero, a measured signal file it cannot read) and ``equations`` prints them: model
    errors both, never an internal error."""
    monkeypatch.setenv("BONDC_CACHE", "0")
    ran, outcomes, problems = 0, {}, []
    for number, (source, text) in enumerate(mutants(CHECKS, SEED + 2)):
        if ran >= 2 * RUNS:
            break
        path = _place(tmp_path, source, text, number)
        if _check(path)[0] != 0:
            continue
        ran += 1
        for command in (["linearize", str(path)], ["equations", "--format", "latex", str(path)]):
            out, err = io.StringIO(), io.StringIO()
            with redirect_stdout(out), redirect_stderr(err):
                code = main(command)
            outcomes[code] = outcomes.get(code, 0) + 1
            if code not in (0, 1, 2) or "Traceback" in err.getvalue() or "internal error" in err.getvalue():
                problems.append(f"{source.relative_to(ROOT)} mutant {number}, {command[0]}: exit {code}\n"
                                f"{err.getvalue()[-800:]}")
    SUMMARY["linearize"] = _tally(f"{ran} mutants that check linearised and printed", outcomes, problems)
    assert ran >= min(RUNS, 5), "too few mutants passed check to linearise"
    assert not problems, "\n\n".join(problems[:5])
