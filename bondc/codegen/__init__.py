"""Code generation: StateSpace -> a standalone Python simulation module.

:func:`emit` (in :mod:`bondc.codegen.emit`) is the stage (``bondc compile`` as a whole is
:func:`bondc.pipeline.compile_file`, the orchestrator's). The pieces:
:mod:`~bondc.codegen.freeze` (discontinuities -> mode-selected smooth laws),
:mod:`~bondc.codegen.printer` (the sympy printer), :mod:`~bondc.codegen.emit`
(Jacobian, cse, module text around a verbatim copy of :mod:`bondc.runtime`).
"""

from __future__ import annotations

from bondc.codegen.emit import emit, runtime_source

__all__ = ["emit", "runtime_source"]
