"""Semantic stage: ``ast.File`` (and its imports) -> checked :class:`bondc.model.BondGraph`.

:func:`load` reads a ``.bg`` file and the files it imports, picks a model,
applies an experiment's and the command line's overrides and builds the graph;
:func:`build` does the same for a file already parsed. Building runs every
``check_<what>`` function below on the chosen model; each collects diagnostics instead of stopping, so one run
reports every problem. If any is an error, :class:`bondc.errors.ModelError`
is raised carrying all of them, sorted by position; otherwise the graph is
returned with the warnings. Errors in laws, parameters or experiments leave the
graph's structure known: unless the structural checks (names, kinds, bonds,
ports) found an error too, the causal conflicts (E601) of that structure are
among them (``build._structural_conflicts``), so one run reports both.

The stage, one job per module, in the order :func:`build` runs them:

- :mod:`~bondc.semantic.load`: a path -> the parsed file and its imports (:func:`load_files`);
- :mod:`~bondc.semantic.context`: the model being built and its declarations (one namespace);
- :mod:`~bondc.semantic.names`: reserved, duplicate and hidden names, element and junction kinds;
- :mod:`~bondc.semantic.bonds`: bonds numbered and oriented, endpoints, junctions and ports;
- :mod:`~bondc.semantic.laws`: the laws and states each element kind takes, model states;
- :mod:`~bondc.semantic.expressions` and :mod:`~bondc.semantic.rules`: the names each
  expression may use, functions, ``when`` clauses, signal cycles;
- :mod:`~bondc.semantic.unit_checks`: units resolved to SI, coherent where computed;
- :mod:`~bondc.semantic.parameters`: parameter values in SI, overrides, divisors;
- :mod:`~bondc.semantic.experiments`: defaults and experiments;
- :mod:`~bondc.semantic.lints`: warnings about legal but suspicious models;
- :mod:`~bondc.semantic.build`: the checks in order, dimensions, the :class:`~bondc.model.BondGraph`.

What the checks enforce is the language reference (``docs/language.md``); the
codes are listed in ``docs/diagnostics.md``.

>>> from bondc.parse import parse_text
>>> text = '''model M
...   param m = 2 [kg]
...   param lead = 5.0 [mm]
...   MSe force : e = 10
...   I mass : f = p/m
...   TF screw : r = lead/(2*pi)
...   force -> screw -> mass
... end
... '''
>>> graph, warnings = build(parse_text(text, "m.bg"), {})
>>> graph.parameters["lead"].value, [(b.number, b.tail, b.head) for b in graph.bonds]
(0.005, [(1, 'force', 'screw'), (2, 'screw', 'mass')])
>>> graph.elements["screw"].bonds, graph.elements["screw"].port_signs
((1, 2), (1, 1))
"""

from __future__ import annotations

from bondc.semantic.context import BUILTINS, FIRST, OPERATING_POINTS, RESERVED, SET_HINT, SETTINGS, SOLVERS
from bondc.semantic.names import check_duplicate_names, check_kinds, check_reserved_names, check_shadowing
from bondc.semantic.bonds import check_bonds, check_ports
from bondc.semantic.laws import check_laws, check_model_states
from bondc.semantic.expressions import CONSTANT, DISCRETE_START, GENERAL, SIGNAL
from bondc.semantic.rules import check_expressions, check_functions, check_signal_cycles
from bondc.semantic.unit_checks import check_units, coherent_suggestion
from bondc.semantic.parameters import check_bindings, check_constants, check_divisors, zero_divisors
from bondc.semantic.experiments import check_defaults, check_experiments
from bondc.semantic.lints import check_label_names, check_passive_orientation, check_unused
from bondc.semantic.build import build, check_dimensions, check_experiment_values, check_parameters, check_sets
from bondc.semantic.load import STD_LIBRARIES, _std_library, load, load_files

__all__ = [
    "BUILTINS", "CONSTANT", "DISCRETE_START", "FIRST", "GENERAL", "OPERATING_POINTS", "RESERVED", "SETTINGS",
    "SET_HINT", "SIGNAL", "SOLVERS", "STD_LIBRARIES", "build", "check_bindings", "check_bonds", "check_constants",
    "check_defaults", "check_dimensions", "check_divisors", "check_duplicate_names", "check_experiment_values",
    "check_experiments", "check_expressions", "check_functions", "check_kinds", "check_label_names", "check_laws",
    "check_model_states", "check_parameters", "check_passive_orientation", "check_ports", "check_reserved_names",
    "check_sets", "check_shadowing", "check_signal_cycles", "check_units", "check_unused", "coherent_suggestion",
    "load", "load_files", "zero_divisors",
]
