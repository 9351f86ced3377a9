"""Golden files of the later stages: one small model per causality, equation, simulation and
linearisation diagnostic.

``tests/golden/stages/<CODE>_<slug>.bg`` starts with the command it is about, as a comment:
``# bondc check``, ``# bondc equations``, ``# bondc simulate --t-end 0``, ``# bondc linearize
--at equilibrium`` (options: ``--model --experiment --set --t-end --dt --time --at``). The case
is run from its own folder (so file names in messages are relative) through the library stages
that command runs -- :func:`bondc.semantic.load`, :func:`bondc.causality.assign_causality`,
:func:`bondc.equations.derive`, :func:`bondc.simulate.simulate`,
:func:`bondc.analysis.linearize.linearize` -- collecting the diagnostics the command prints on
stderr, in its order: a stage that raises ends the run, and ``equations``, ``simulate`` and
``linearize`` print the earlier stages' warnings only once every stage up to the equations has
succeeded (``bondc check`` prints them with the errors). They are compared with ``<same>.txt``
(rendered exactly as bondc prints them) and ``<same>.json`` (the ``Diagnostic.to_json()`` list);
:func:`test_the_command_prints_the_golden_output` runs the real command line too.

The absolute path of this folder, where bondc prints one, is written ``/path/to/`` in the golden
files.

``pytest --update-golden`` rewrites the expected files; review them by eye (carets, notes,
hints), then run ``python tests/golden/check/make_diagnostics_doc.py`` so that
``docs/diagnostics.md`` quotes them. Files in ``data/`` are what the cases read.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import sys
from pathlib import Path

import pytest

from bondc.errors import BondcError, render_all

GOLDEN = Path(__file__).resolve().parent / "golden" / "stages"
CASES = sorted(GOLDEN.glob("*.bg"))
DOCS = Path(__file__).resolve().parent.parent / "docs" / "diagnostics.md"
COMMANDS = ("check", "equations", "simulate", "linearize")
OPTIONS = ("--model", "--experiment", "--set", "--t-end", "--dt", "--time", "--at")


def command_line(path: Path) -> list[str]:
    """The case's command line after ``bondc``, with the file name in place: ``["simulate", "x.bg", ...]``."""
    first = path.read_text(encoding="utf-8").splitlines()[0]
    words = shlex.split(first.lstrip("#"))
    assert words[:1] == ["bondc"] and len(words) >= 2 and words[1] in COMMANDS, \
        f"{path.name}: the first line must be '# bondc {'|'.join(COMMANDS)} [options]'"
    options = words[2:]
    assert len(options) % 2 == 0 and all(flag in OPTIONS for flag in options[::2]), f"{path.name}: {options}"
    return [words[1], path.name, *options]


def _normalise(text: str) -> str:
    return text.replace(str(GOLDEN) + os.sep, "/path/to/")


def run_case(path: Path) -> list:
    """The diagnostics the case's command prints on stderr, in order (see the module docstring)."""
    from bondc import semantic
    from bondc.causality import assign_causality
    from bondc.equations import derive
    from bondc.parse import parse_set_value

    command, name, *rest = command_line(path)
    options: dict = {"sets": []}
    for flag, value in zip(rest[::2], rest[1::2]):
        if flag == "--set":
            options["sets"].append(parse_set_value(value))
        else:
            options[flag.lstrip("-").replace("-", "_")] = value
    experiment = options.get("experiment")
    printed: list = []
    try:
        chosen_experiment = None if command == "check" else experiment or semantic.FIRST
        graph, warnings = semantic.load(Path(name), model=options.get("model"), sets=options["sets"],
                                        experiment=chosen_experiment)
        if command == "check":
            printed += warnings
            causal = assign_causality(graph)
            printed += [d for d in causal.diagnostics if d not in printed]
            return printed
        causal = assign_causality(graph)
        state_space = derive(causal)
        notes = list(warnings)
        notes += [d for d in list(causal.diagnostics) + list(state_space.diagnostics) if d not in notes]
        printed += notes
        if command == "simulate":
            from bondc.simulate import simulate

            chosen = None
            if graph.experiments:
                chosen = graph.experiments[experiment] if experiment else next(iter(graph.experiments.values()))
            result = simulate(state_space, chosen, t_end=_float(options.get("t_end")), dt=_float(options.get("dt")))
            printed += result.warnings
            error = result.error()
            if error is not None:
                printed += error.diagnostics
        elif command == "linearize":
            from bondc.analysis.linearize import linearize

            linearize(state_space, time=_float(options.get("time")) or 0.0, at=options.get("at", "initial"))
    except BondcError as error:
        printed += error.diagnostics
    return printed


def _float(text):
    return None if text is None else float(text)


def _outputs(path: Path) -> tuple[str, str]:
    diagnostics = run_case(path)
    rendered = _normalise(render_all(diagnostics)) + "\n"
    as_json = _normalise(json.dumps([d.to_json() for d in diagnostics], indent=2)) + "\n"
    return rendered, as_json


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_golden(path, monkeypatch, update_golden):
    monkeypatch.chdir(GOLDEN)
    rendered, as_json = _outputs(path)
    text_file, json_file = path.with_suffix(".txt"), path.with_suffix(".json")
    if update_golden:
        text_file.write_text(rendered, encoding="utf-8")
        json_file.write_text(as_json, encoding="utf-8")
    assert rendered == text_file.read_text(encoding="utf-8")
    assert as_json == json_file.read_text(encoding="utf-8")
    code = path.stem.split("_")[0]
    assert code in {item["code"] for item in json.loads(as_json)}, f"{path.name} does not show {code}"


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_the_command_prints_the_golden_output(path, monkeypatch, capsys):
    """The real command line prints the golden diagnostics on stderr (and exits 1 on an error)."""
    from bondc.cli import main

    monkeypatch.chdir(GOLDEN)
    status = main(command_line(path))
    stderr = _normalise(capsys.readouterr().err)
    expected = path.with_suffix(".txt").read_text(encoding="utf-8").rstrip("\n")
    assert expected in stderr
    errors = [d for d in json.loads(path.with_suffix(".json").read_text(encoding="utf-8")) if d["severity"] == "error"]
    assert (status != 0) == bool(errors)


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_docs_show_the_golden_output(path):
    """docs/diagnostics.md quotes every case and its output; regenerate it when a golden changes."""
    docs = DOCS.read_text(encoding="utf-8")
    assert path.read_text(encoding="utf-8").rstrip("\n") in docs
    assert path.with_suffix(".txt").read_text(encoding="utf-8").rstrip("\n") in docs


def _generator():
    import importlib.util

    path = GOLDEN.parent / "check" / "make_diagnostics_doc.py"
    spec = importlib.util.spec_from_file_location("make_diagnostics_doc", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module     # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_every_emitted_code_is_documented():
    """Every code written in bondc/ ("E601") has a section on the page."""
    documented = set(re.findall(r"^## ([EWI][0-9]{3})\b", DOCS.read_text(encoding="utf-8"), re.MULTILINE))
    assert _generator().emitted_codes() - documented == set()


def test_the_page_is_up_to_date():
    """docs/diagnostics.md is what make_diagnostics_doc.py writes: run it after changing a diagnostic."""
    assert _generator().render_page() == DOCS.read_text(encoding="utf-8")
