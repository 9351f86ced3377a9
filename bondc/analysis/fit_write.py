"""``bondc fit --write FITTED.bg``: a copy of the model file with the fitted values in it.

The language has no separate file of parameter values (a ``defaults`` block
holds experiment settings only, ``docs/language.md`` J), so the fitted values
are written where every command reads them: the copy is the model file with
each estimated parameter's declaration (``param Ae = 1.2e-5 [m^2]``) given the
fitted value in its declared unit, and, where the experiment the fit ran
overrides that parameter (``param Ae = Ae_catalogue [m^2]`` inside it), that
override too. Everything else stays as it was; a comment at the top says what
was fitted, from which data, with which intervals. ``bondc check``,
``simulate``, ``report``, ``validate`` and ``fit`` take the copy as they take
the model.

The copy is written atomically, never over the model file or a data file, and
never over a file that ``bondc fit`` did not write (its first line is
:data:`MARKER`). It is written beside the model when the model reads other
files by relative paths (``import "lib.bg"``, ``csv("data/x.csv")``), which
would not be found from elsewhere. Problems: E890.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Sequence

from bondc.errors import Diagnostic, UsageError
from bondc import codes

#: The first line of every file ``bondc fit --write`` writes.
MARKER = "# bondc fit: fitted values written by bondc fit"


def _refuse(message: str, hint: str, span=None) -> UsageError:
    from bondc.source import NO_SPAN

    return UsageError(Diagnostic("error", codes.E890, message, span or NO_SPAN, hint=hint))


def _same(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _reads_relative_files(text: str) -> bool:
    """Whether a model text reads other files by relative paths: an ``import`` of a file (not
    ``std:``) or a ``csv(...)`` call."""
    return bool(re.search(r'^\s*import\s+"(?!std:)', text, re.M) or re.search(r"\bcsv\s*\(", text))


def check_write_target(target, model_path, data_paths: Sequence) -> Path:
    """E890 before any work: a target that is the model or a data file, not a .bg file, an existing
    file bondc fit did not write, or a folder other than the model's when the model reads files by
    relative paths; E003 for a path bondc may not write (:func:`bondc.io.check_output`)."""
    from bondc.io import check_output

    target = check_output(target, "the fitted model")
    if target.suffix != ".bg":
        raise _refuse(f"--write '{target}': the fitted model is a model file and needs the .bg suffix",
                      "e.g. --write fitted.bg")
    for path, what in [(model_path, "the model file")] + [(p, "a measured data file") for p in data_paths]:
        if _same(target, path):
            raise _refuse(f"--write '{target}' is {what} the fit reads",
                          "give the path of a new file; bondc fit never writes over its inputs")
    if target.exists():
        try:
            first = target.read_text(encoding="utf-8").split("\n", 1)[0]
        except (OSError, UnicodeDecodeError):
            first = ""
        if not first.startswith(MARKER):
            raise _refuse(f"--write '{target}' exists and was not written by bondc fit",
                          "bondc fit replaces only a file it wrote (its first line says so); give a new path")
    try:
        text = Path(model_path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return target           # (loading the model reports it)
    if _reads_relative_files(text) and \
            Path(model_path).resolve().parent != (target.parent if str(target.parent) else Path(".")).resolve():
        raise _refuse(f"--write '{target}': the model reads other files by relative paths (an import or a "
                      "csv() call), which would not be found from another folder",
                      f"write the fitted model beside the model, in '{Path(model_path).parent}'")
    return target


def _top_model(path, graph):
    from bondc import ast, semantic

    files, sources, _ = semantic.load_files(Path(path))
    top = files[0]
    for item in top.items:
        if isinstance(item, ast.Model) and item.name == graph.name:
            return item, sources
    return None, sources


def check_writable(path, graph, names: Sequence[str]) -> None:
    """E890 before the fit for an estimated parameter that is not declared in the model file's own
    model (a parameter inside a component, ``valve.Ae``): the copy cannot place its value."""
    from bondc import ast

    model, _ = _top_model(path, graph)
    declared = {s.name for s in (model.body if model is not None else ()) if isinstance(s, ast.Param)}
    for name in names:
        if name not in declared:
            raise _refuse(f"--write: '{name}' is not declared in the model file's own model (it is a parameter of "
                          "a component), so the fitted copy cannot hold its value",
                          f"leave out --write and give the fitted value with --set {name}=VALUE, or bind it in "
                          "the instance statement")


def _replacement(statement, value: float) -> tuple[int, int, str]:
    """(start, end, text): a ``param`` statement's value (and unit) replaced by ``value`` in its
    declared unit."""
    start = statement.value.span.start
    end = statement.unit.span.end if statement.unit is not None else statement.value.span.end
    unit = f" [{statement.unit.text}]" if statement.unit is not None else ""
    return start, end, f"{value!r}{unit}"


def fitted_text(path, graph, result, experiments: Sequence[str | None], sets: Sequence = ()) -> str:
    """The text of the fitted copy of ``path`` (see the module docstring)."""
    from bondc import ast

    model, sources = _top_model(path, graph)
    text = next(iter(sources.values())).text
    values = result.values
    edits = []
    for statement in model.body:
        if isinstance(statement, ast.Param) and statement.name in values:
            edits.append(_replacement(statement, values[statement.name]))
    chosen = [e for e in model.body if isinstance(e, ast.Experiment)]
    names = {name for name in experiments if name is not None}
    if any(name is None for name in experiments) and chosen:
        names.add(chosen[0].name)
    for experiment in chosen:
        if experiment.name not in names:
            continue
        for statement in experiment.body:
            if isinstance(statement, ast.Param) and statement.name in values:
                edits.append(_replacement(statement, values[statement.name]))
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    header = [MARKER + f" from {Path(path).name}; it may replace this file",
              "# data: " + ", ".join(str(d.data) for d in result.datasets)]
    for p in result.parameters:
        unit = f" {p.unit}" if p.unit else ""
        header.append(f"# {p.name} = {p.value:.6g}{unit} (95 % interval {p.ci95[0]:.6g} .. {p.ci95[1]:.6g}; "
                      f"was {p.initial:.6g})")
    if sets:
        header.append("# fitted with --set " + " --set ".join(str(s) for s in sets)
                      + ": give them again to reproduce the fit")
    if not result.converged:
        header.append("# the fit did NOT converge: these are the values it reached")
    return "\n".join(header) + "\n" + text


def write_fitted(target, path, graph, result, experiments, sets=()) -> None:
    from bondc.io import atomic_write_text

    atomic_write_text(target, fitted_text(path, graph, result, experiments,
                                          [s if isinstance(s, str) else getattr(s, "name", s) for s in sets]))
