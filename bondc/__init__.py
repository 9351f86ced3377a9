"""bondc — a bond-graph modelling compiler.

The compiler is a pipeline of typed stages, each one function in one module::

    text --parse--> ast.File --build--> BondGraph --assign_causality--> CausalGraph
         --derive--> StateSpace --emit--> Python module --simulate--> SimResult --render--> HTML
"""

__version__ = "0.1.0"

__all__ = ["load", "check", "equations", "linearize", "compile", "simulate", "__version__"]


def __getattr__(name):
    """The API (``bondc.simulate(...)``, ``docs/api.md``), imported on first use so that ``import
    bondc`` stays light."""
    if name in ("simulate", "equations"):       # modules of the pipeline too: calling them calls the API
        import importlib

        return importlib.import_module(f"bondc.{name}")
    if name in ("load", "check", "linearize", "compile", "Model", "CheckResult", "Simulation"):
        from bondc import api

        return getattr(api, name)
    raise AttributeError(f"module 'bondc' has no attribute {name!r}")
