"""Load: takes a path (or a path and its text) and returns the checked
:class:`bondc.model.BondGraph` with its warnings: reads the file and the files it imports
(:func:`load_files`: ``ast.File`` values, their sources and diagnostics), then builds
(:func:`bondc.semantic.build.build`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

from bondc import ast
from bondc.errors import Diagnostic, ModelError
from bondc.io import read_source
from bondc.model import BondGraph
from bondc.parse import parse_source
from bondc.source import Source
from bondc.std import LIBRARIES as STD_LIBRARIES, path_of as std_path_of
from bondc.semantic.build import build_files, sorted_unique
from bondc.semantic.context import did_you_mean, error_at, join_hints
from bondc import codes


def _read(path: Path, name: str) -> Source:
    return read_source(path, name)


def _std_library(name: str) -> Path | None:
    """The file of a shipped component library (``import "std:hydraulics"``)."""
    found = std_path_of(name)
    return None if found is None else Path(str(found))


def _shown_path(path: str, limit: int = 80) -> str:
    """A path as a message quotes it: a path longer than any file system allows, shortened."""
    return path if len(path) <= limit else f"{path[:limit // 2]}...{path[-limit // 4:]} ({len(path)} characters)"


def _not_a_model_file(target: Path, written: str) -> str | None:
    """Why an import's path cannot be a model file, or None: its name (or, through symbolic links,
    the name of the file it is) does not end in .bg, or the system cannot look it up."""
    if not written.endswith(".bg"):
        return f"cannot import '{_shown_path(written)}': it is not a .bg model file"
    try:
        real = target.resolve()
        target.is_file()
    except (OSError, RuntimeError, ValueError) as error:
        reason = getattr(error, "strerror", None) or "the system cannot look it up"
        return f"cannot find imported file '{_shown_path(written)}': {reason.lower()}"
    if real.suffix != ".bg" and target.exists():
        return f"cannot import '{_shown_path(written)}': it is a link to a file that is not a .bg model file"
    return None


def load_files(path: str | Path, text: str | None = None) -> tuple[list[ast.File], dict[str, Source], list[Diagnostic]]:
    """Parse ``path`` and, recursively, the files it imports (each once).

    ``text``: the main file's text as an editor holds it (unsaved); imports are still read from
    disk, relative to ``path``. Returns the files (the main one first), their sources by name, and
    E307/E308 diagnostics. I/O errors on the main file raise UsageError; syntax errors raise
    ParseError.
    """
    path = Path(path)
    main = _read(path, str(path)) if text is None else Source(str(path), text, path)
    sources = {main.name: main}
    files = [parse_source(main)]
    diagnostics: list[Diagnostic] = []
    loaded = {path.resolve()}

    def visit(file: ast.File, source: Source, stack: list[tuple[Path, str]]) -> None:
        for item in file.imports:
            if item.path.startswith("std:"):
                target, name = _std_library(item.path[4:]), item.path
                if target is None:
                    diagnostics.append(error_at(codes.E307, f"no component library '{item.path}'", item.span,
                                                hint=join_hints(did_you_mean(item.path[4:], STD_LIBRARIES),
                                                                 "shipped libraries: " + ", ".join(
                                                                     f"std:{n}" for n in STD_LIBRARIES))))
                    continue
            else:
                folder = source.path.parent if source.path is not None else Path(os.path.dirname(source.name))
                target = folder / item.path
                name = os.path.normpath(os.path.join(os.path.dirname(source.name), item.path))
                problem = _not_a_model_file(target, item.path)
                if problem is not None:
                    # (a model may name any file: one that is not a model is not read, nor quoted)
                    diagnostics.append(error_at(codes.E307, problem, item.span,
                                                hint="import names a model file (.bg), relative to the importing "
                                                     "file, or a shipped library (std:NAME)"))
                    continue
            key = target.resolve()
            keys = [k for k, _ in stack]
            if key in keys:
                cycle = [n for _, n in stack[keys.index(key):]] + [name]
                diagnostics.append(error_at(codes.E308, f"cyclic import: {' -> '.join(cycle)}", item.span,
                                            hint="files cannot import each other; move what both need into a "
                                                 "third file"))
                continue
            if key in loaded:
                continue
            if not target.is_file():
                diagnostics.append(error_at(codes.E307, f"cannot find imported file '{item.path}'", item.span,
                                            hint=f"import paths are relative to the importing file: looked for "
                                                 f"'{name}'"))
                continue
            try:
                imported = Source(name, target.read_text(encoding="utf-8"), target)
            except (OSError, UnicodeDecodeError) as error:
                diagnostics.append(error_at(codes.E307, f"cannot read imported file '{item.path}': "
                                                    f"{getattr(error, 'strerror', None) or error}", item.span))
                continue
            loaded.add(key)
            sources[imported.name] = imported
            parsed = parse_source(imported)
            files.append(parsed)
            visit(parsed, imported, stack + [(key, name)])

    visit(files[0], main, [(path.resolve(), main.name)])
    return files, sources, diagnostics


def load(path: str | Path, *, model: str | None = None, experiment: str | None = None,
         sets: Sequence[ast.SetValue] = (), text: str | None = None,
         loaded: tuple | None = None) -> tuple[BondGraph, list[Diagnostic]]:
    """Read, parse and check a ``.bg`` file; return its graph and warnings, or raise ModelError.

    ``experiment`` names the experiment whose overrides apply (None: none; :data:`FIRST`: the first);
    ``sets`` are command-line ``--set`` values (from ``parse_set_value``), applied last; ``text``
    is the file's text when it is not read from disk (an editor's unsaved buffer); ``loaded`` is
    what :func:`load_files` returned for it, when the caller has parsed it already.
    """
    if loaded is not None:
        files, sources, diagnostics = list(loaded[0]), dict(loaded[1]), list(loaded[2])
    else:
        files, sources, diagnostics = load_files(path, text)
    for assignment in sets:
        if assignment.source is not None:
            sources[assignment.source.name] = assignment.source
    graph, more = build_files(files, sources, model, experiment, sets)
    diagnostics = sorted_unique(diagnostics + more)
    if graph is None or any(d.is_error for d in diagnostics):
        raise ModelError([d for d in diagnostics if d.is_error], sources)
    return graph, diagnostics
