"""The sources a standalone generated module carries: the runtime package's modules
(:func:`runtime_parts`, :func:`runtime_source`) and bondc's C and C++ files
(:func:`native_files_source`), read from the installed package, the same text for the same
files.
"""

from __future__ import annotations

import ast as _python_ast
import functools
from pathlib import Path

from bondc.runtime import native_file


#: The runtime package, whose modules a standalone module carries (see :func:`runtime_source`).
RUNTIME_DIR = Path(__file__).resolve().parent.parent / "runtime"


def _runtime_files() -> tuple:
    """(path, stat) of each module of bondc/runtime in ``MODULES`` order."""
    from bondc.runtime import MODULES

    files = []
    for name in MODULES:
        path = RUNTIME_DIR / f"{name}.py"
        info = path.stat()
        files.append((str(path), (info.st_mtime_ns, info.st_size)))
    return tuple(files)


@functools.lru_cache(maxsize=4)
def _runtime_parts(files: tuple) -> tuple:
    parts = []
    for path, _ in files:
        text = Path(path).read_text(encoding="utf-8")
        lines = text.splitlines(keepends=True)
        for node in _python_ast.parse(text).body:
            if isinstance(node, _python_ast.ImportFrom) and (node.module or "").startswith("bondc.runtime"):
                for i in range(node.lineno - 1, node.end_lineno or node.lineno):
                    lines[i] = "# " + lines[i]
        parts.append((path, "".join(lines)))
    return tuple(parts)


def runtime_parts() -> tuple:
    """``(path, text)`` of each module of the runtime package, in ``bondc.runtime.MODULES`` order (each
    imports only earlier ones), as a standalone module carries it: the module's text with its imports
    of the other runtime modules commented out, line for line (the lines stay those of the file)."""
    return _runtime_parts(_runtime_files())


def runtime_source() -> str:
    """The runtime every standalone generated module carries: the text of each module of
    ``bondc/runtime`` (:func:`runtime_parts`), in order, each after a comment naming its file. One
    namespace, as one file was: no two modules define the same name (tests/test_runtime_layout.py)."""
    return "\n\n\n".join(f"# ---- bondc/runtime/{Path(path).name}\n{text.rstrip()}\n"
                          for path, text in runtime_parts())


# -- bondc's native sources in a standalone module

#: bondc's C and C++ sources (the CVODE driver, the explicit stepper, their headers): package data
NATIVE_PATH = RUNTIME_DIR.parent / "native"
NATIVE_SUFFIXES = (".c", ".h", ".cpp")


def native_files_source() -> str:
    """``_NATIVE_FILES = {name: text}`` of every file of ``bondc/native``, which a standalone module
    writes after its copy of the runtime: the runtime then builds its CVODE driver and explicit
    stepper from these texts (``runtime.native_file``) where bondc is not installed. Each line of a
    file is one literal, so the module reads as the files do; sorted by name, the same text for the
    same files."""
    rule = "# " + "=" * 76
    lines = [rule, "# bondc's native sources: verbatim copies of bondc/native/*, from which the runtime",
             "# above builds its CVODE driver and explicit stepper (runtime.native_file).", rule,
             "_NATIVE_FILES = {"]
    for name in sorted(p.name for p in NATIVE_PATH.iterdir() if p.suffix in NATIVE_SUFFIXES):
        lines.append(f"    {name!r}: (")
        lines += [f"        {line!r}" for line in native_file(name).splitlines(keepends=True)]
        lines.append("    ),")
    return "\n".join(lines + ["}"])
