"""Equations stage: :class:`~bondc.causality.CausalGraph` -> :class:`~bondc.statespace.StateSpace`.

Every node of the causal graph contributes the equations for the variables its
causality makes it compute (a ``C`` in integral causality its bond's effort, a
0-junction the efforts of its other bonds and the flow of its strong bond, a
transformer one effort and one flow, ...). Laws are translated from the AST by
:class:`bondc.symbolic.Translator`. The equations are then put in causal order
(strongly connected components of their dependencies, topologically sorted):

- an acyclic equation becomes one assignment;
- an algebraic loop (a cyclic component) is torn: a few tearing variables
  (resistors' outputs first) are chosen so the rest of the loop is a chain,
  the chain is substituted into the tearing equations, and those are solved
  symbolically when they are linear in the tearing variables (a square linear
  system), else kept as an :class:`~bondc.statespace.AlgebraicBlock` solved
  numerically at run time (``W604``);
- storage elements in derivative causality are eliminated: their state is
  assigned from the law inverted (``q = C*e``), the time derivative of that
  expression in the independent states (chain rule with their state
  equations, plus the explicit time dependence through inputs) is equated to
  their rate law, and the resulting implicit equations are solved for their
  port variables (two inertias joined by a gear become one state with the
  combined inertia).

A law that causality needs in the other form (``f = ...`` when only
``e = ...`` is written) is inverted symbolically: directly when it is linear in
the variable, else with ``sympy.solve`` when exactly one solution reproduces
the law at sample points on both sides of zero; otherwise ``E605``.

Nothing is simplified: laws keep the form they were written in.

Diagnostics: ``E605`` law cannot be inverted, ``E701`` expression cannot be
translated, ``E702`` singular algebraic loop, ``E703`` derivative causality
that cannot be resolved, ``W604`` nonlinear algebraic loop solved numerically,
``W704`` initial value of an eliminated state ignored.

The derivation is one object, :class:`_Deriver`, whose steps are in a module each:

    laws.py        Laws         the symbols; a law translated (E701), or inverted (E605)
    rules.py       NodeRules    build: each node's equations, as its causality makes it compute (W704)
    loops.py       Ordering     order: causal order, algebraic loops torn and solved (W604, E702)
    derivative.py  Elimination  eliminate: storage elements in derivative causality (E703)
    assemble.py    Assembly     result: the StateSpace
    display.py                  ``bondc equations``: text, LaTeX, JSON
"""

from __future__ import annotations

from bondc.causality import CausalGraph
from bondc.equations.assemble import Assembly
from bondc.equations.derivative import Elimination
from bondc.equations.display import FORMATS, BgPrinter, _display, bg_text, format_equations
from bondc.equations.rules import NodeRules
from bondc.statespace import StateSpace

__all__ = ["derive", "FORMATS", "BgPrinter", "bg_text", "format_equations", "_display"]


class _Deriver(NodeRules, Elimination, Assembly):
    """A causal graph's derivation: :meth:`build`, :meth:`order`, :meth:`eliminate`, :meth:`result`."""


def derive(causal: CausalGraph) -> StateSpace:
    """State equations of a causal graph, as a sorted sequence of sympy assignments.

    >>> from bondc.causality import assign_causality
    >>> from bondc.parse import parse_text
    >>> from bondc.semantic import build
    >>> text = "model M\\n Se force : e = 10\\n I mass : f = p/m\\n R damper : e = b*f\\n" \\
    ...        " param m = 2\\n param b = 3\\n 1 j\\n force -> j\\n j -> mass\\n j -> damper\\nend\\n"
    >>> ss = derive(assign_causality(build(parse_text(text, "m.bg"))[0]))
    >>> ss.derivatives["mass.p"], ss.substituted(ss.derivatives["mass.p"])
    (b2.e, -b*mass.p/m + 10)
    """
    deriver = _Deriver(causal)
    deriver.build()
    deriver.order()
    deriver.eliminate()
    return deriver.result()
