"""Code generation: StateSpace -> a standalone Python simulation module.

:func:`emit` (in :mod:`bondc.codegen.emit`) is the stage; :func:`compile_file`
is the whole ``bondc compile`` command without argument parsing. The pieces:
:mod:`~bondc.codegen.freeze` (discontinuities -> mode-selected smooth laws),
:mod:`~bondc.codegen.printer` (the sympy printer), :mod:`~bondc.codegen.emit`
(Jacobian, cse, module text around a verbatim copy of :mod:`bondc.runtime`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from bondc.codegen.emit import emit, runtime_source

__all__ = ["emit", "runtime_source", "compile_file", "default_output"]


def default_output(path) -> Path:
    """Where ``bondc compile model.bg`` writes without ``-o``: ``model_gen.py`` next to the model."""
    path = Path(path)
    return path.with_name(path.stem + "_gen.py")


def compile_file(path, output=None, *, model: str | None = None, experiment: str | None = None,
                 sets: Sequence = (), standalone: bool = False) -> str:
    """``bondc compile``: load, check, derive and emit; write ``output`` (atomically) if given.

    The module imports ``bondc.runtime``; ``standalone`` copies the runtime in instead, so the
    module runs where bondc is not installed (numpy and scipy, and scikit-sundae for CVODE).

    ``experiment`` None takes the model's first experiment (its settings become
    the module's defaults); ``sets`` are ``--set`` texts or parsed SetValues;
    csv data paths are written relative to ``output``'s directory. Returns the
    module's source. Raises the stage errors (ModelError, CausalityError,
    EquationError, UsageError) for a model that cannot be compiled.
    """
    from bondc.io import atomic_write_text, check_output
    from bondc.pipeline import derive_file

    if output is not None:
        check_output(output)
    derived = derive_file(path, model=model, experiment=experiment, sets=sets)
    module_dir = Path(output).resolve().parent if output is not None else Path(path).resolve().parent
    source = emit(derived.state_space, derived.experiment, source=Path(path).name, module_dir=module_dir,
                  standalone=standalone)
    if output is not None:
        atomic_write_text(Path(output), source)
    return source
