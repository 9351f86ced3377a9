"""bondc — a bond-graph modelling compiler.

The compiler is a pipeline of typed stages, each one function in one module::

    text --parse--> ast.File --build--> BondGraph --assign_causality--> CausalGraph
         --derive--> StateSpace --emit--> Python module --simulate--> SimResult --render--> HTML
"""

__version__ = "0.1.0"
