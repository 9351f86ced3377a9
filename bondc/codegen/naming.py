"""Names in a generated module: the arguments and module-level names it defines, and
:class:`Namer`, which makes deterministic Python identifiers of qualified names
(``mass.p`` -> ``mass_p``; a keyword, a runtime name or an earlier identifier gets ``_``).
"""

from __future__ import annotations

import ast as _python_ast
import functools
import keyword
import re


ARGUMENTS = ("t", "x", "p", "m")
#: Module-level names of the generated model code (besides the runtime's).
MODULE_NAMES = (
    "STATE_NAMES", "STATE_UNITS", "OUTPUT_NAMES", "RESULT_UNITS", "VARIABLE_NAMES", "VARIABLE_LAWS", "VARIABLE_ROWS", "BOND_VARIABLES",
    "PARAMETERS", "DERIVED_PARAMETERS", "SWITCHES", "EVENT_SWITCHES", "SWITCH_DEPENDS", "SWITCH_VERTICES",
    "SWITCH_KINDS", "SWITCH_TRUTH", "SWITCH_OWNERS", "JACOBIAN_PATTERN", "TIME_SWITCHES", "WHEN_LABELS", "WHEN_TARGETS", "WHEN_SWITCHES", "WHEN_ACTIONS",
    "_when_conditions", "DEFAULTS",
    "MODEL_NAME", "SOURCE_FILE", "DATA_DIR", "VECTORIZED", "x0", "rhs", "jacobian", "outputs", "variables",
    "modes", "event_functions", "simulate", "main", "_derive_parameters", "_rhs", "_jac", "_outputs", "_variables", "_switches",
    "_time_breaks", "_MODEL", "_dae", "_loop_values", "_za", "_ra", "DAE_SIZE", "_time_switches",
    "EXTERNAL_INPUTS", "EXTERNAL_INPUT_NAMES",
)


@functools.lru_cache(maxsize=8)
def _top_level_names(source: str, imports: bool = True) -> frozenset[str]:
    """The names ``source`` binds at its top level: its functions, classes and assigned names, and
    (``imports``) what it imports."""
    names = set()
    for node in _python_ast.parse(source).body:
        if isinstance(node, (_python_ast.FunctionDef, _python_ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, _python_ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, _python_ast.Name))
        elif imports and isinstance(node, (_python_ast.Import, _python_ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return frozenset(names)


class Namer:
    """Deterministic Python identifiers for qualified names (see the module docstring).

    >>> namer = Namer({"m"})
    >>> namer("mass.p"), namer("m"), namer("mass_p"), namer("_x")
    ('mass_p', 'm_', 'mass_p_', 'u_x')
    """

    def __init__(self, reserved=()):
        self.used = set(reserved)

    def __call__(self, name: str) -> str:
        ident = re.sub(r"\W", "_", name, flags=re.ASCII) or "v"
        if ident[0].isdigit() or ident[0] == "_":
            ident = ("v" if ident[0].isdigit() else "u") + ident
        while ident in self.used or keyword.iskeyword(ident):
            ident += "_"
        self.used.add(ident)
        return ident
