"""bondc — a bond-graph modelling compiler.

The compiler is a pipeline of typed stages, each one function in one module, each taking a frozen
value and returning a new one; :mod:`bondc.pipeline` runs them, in this order, for every command,
the API and the analyses (its function in brackets)::

    parse.parse_file            .bg text     -> ast.File
    semantic.load               ast.File     -> BondGraph     names, units, dimensions  [check_file -> Checked]
    causality.assign_causality  BondGraph    -> CausalGraph
    equations.derive            CausalGraph  -> StateSpace                              [derive -> Derived]
    codegen.emit                StateSpace   -> Python module                           [compile_file]
    simulate.simulate           StateSpace   -> SimResult     the engine, bondc.runtime [simulate_file]
    report.build.report_context PipelineRun  -> HTML report                             [run_pipeline]

``bondc check``, :func:`check` and the language server run the stages up to the equations through
``pipeline.diagnose_file`` (``-> Diagnoses``), which gathers every stage's diagnostics instead of
raising the first error.

The Python API (``docs/api.md``) is exported from here: :func:`load`, :func:`check`,
:func:`equations`, :func:`linearize`, :func:`bode`, :func:`compile`, :func:`simulate`, :func:`fit` and their
results :class:`Model`, :class:`CheckResult`, :class:`Simulation` (all defined in :mod:`bondc.api`).
"""

from __future__ import annotations

import sys
import types
from typing import TYPE_CHECKING

from bondc.version import __version__

__all__ = ["load", "check", "equations", "linearize", "bode", "compile", "simulate", "fit", "Model", "CheckResult",
           "Simulation", "__version__"]

#: The API's names, imported from :mod:`bondc.api` on first use so that ``import bondc`` stays light.
_API = ("load", "check", "equations", "linearize", "bode", "compile", "simulate", "fit", "Model", "CheckResult",
        "Simulation")

if TYPE_CHECKING:       # what type checkers see: the functions and classes themselves
    from bondc.api import (CheckResult as CheckResult, Model as Model, Simulation as Simulation, bode as bode,
                           check as check, compile as compile, equations as equations, fit as fit,
                           linearize as linearize, load as load, simulate as simulate)
else:
    def __getattr__(name):
        if name in _API:
            from bondc import api

            return getattr(api, name)
        raise AttributeError(f"module 'bondc' has no attribute {name!r}")


class _Package(types.ModuleType):
    """``bondc.simulate`` and ``bondc.equations`` are the API's functions, although bondc has modules
    of those names (stages of the pipeline, ``from bondc.simulate import SimResult``).

    Importing a submodule makes it an attribute of its package: ``bondc.simulate`` would become the
    module once anything imported it. The package keeps the function instead; the modules are
    reached by importing them (``import bondc.simulate`` then ``sys.modules["bondc.simulate"]``,
    ``importlib.import_module``, ``from bondc.simulate import ...``)."""

    def __setattr__(self, name: str, value: object) -> None:
        if name in _API and isinstance(value, types.ModuleType) and value.__name__ == f"{__name__}.{name}":
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
