"""Code generation: StateSpace -> a standalone Python simulation module.

:func:`emit` (in :mod:`bondc.codegen.emit`) is the stage (``bondc compile`` as a whole is
:func:`bondc.pipeline.compile_file`, the orchestrator's). The pieces, in the order emit uses them:
:mod:`~bondc.codegen.freeze` (discontinuities -> mode-selected smooth laws),
:mod:`~bondc.codegen.plan` (the frozen laws in causal order), :mod:`~bondc.codegen.jacobian`
(their forward-mode Jacobian, by :mod:`bondc.jacobian`'s chain rule),
:mod:`~bondc.codegen.statements` (statements and cse), :mod:`~bondc.codegen.naming`
(identifiers), :mod:`~bondc.codegen.printer` and :mod:`~bondc.codegen.cprinter` (the sympy
printers), :mod:`~bondc.codegen.module` (the Python module's text around a copy or an import of
:mod:`bondc.runtime`), :mod:`~bondc.codegen.native_code` (its C functions) and
:mod:`~bondc.codegen.sources` (the runtime and C files a standalone module carries).
"""

from __future__ import annotations

from bondc.codegen.emit import emit, runtime_source

__all__ = ["emit", "runtime_source"]
