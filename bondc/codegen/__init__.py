"""Code generation: StateSpace -> a standalone Python simulation module (see :mod:`bondc.codegen.emit`)."""

from bondc.codegen.emit import emit, runtime_source

__all__ = ["emit", "runtime_source"]
