"""Energy account: :class:`~bondc.statespace.StateSpace` + :class:`~bondc.simulate.SimResult` -> :class:`EnergyAccount`.

For every element the power *into* it is ``e*f`` when its bond points at it and
``-e*f`` when the bond leaves it (a two-port gets one power per port). Per
cycle (the experiment's ``cycle``; windows of that length from the start of the
run, a last partial window dropped unless it is the only one) the account
gives:

- sources (Se, MSe, Sf, MSf): energy *supplied* to the graph and energy
  *returned* into the source (both >= 0);
- resistors: energy *dissipated* (the integral of the power into the R);
- storage elements with a stored-energy function: the *change of stored
  energy*, the function evaluated at the state at both window ends. The
  function is ``StateSpace.energy`` (polynomial laws, analytic) or, for a law
  of the element's own default state alone that is not polynomial (a spring
  with backlash, a tyre that lifts off), ``integral of law dx`` between the two
  end states by adaptive quadrature ("numeric"), in pieces split at the state's
  values at the run's events, where such a law switches (a hard stop's law is
  zero on all but the last 3e-4 of the way: in one piece, every node of the
  quadrature can fall where it is zero);
- a storage element with a state of its own whose rate is proportional to
  its port flow (C) or effort (I), ``der(x) = k(x)*f``, and whose law depends
  on that state alone (a hydraulic chamber ``state p, der(p) = beta/V*f,
  e = p``): the port power is ``e(x)/k(x) * dx/dt``, so its stored energy is
  the integral of ``e/k dx`` ("numeric", like the above);
- storage elements without one (a chamber whose volume changes with a
  piston, laws that depend on other variables): the *net work in*, the
  integral of the power into the element;
- two-ports: the power in at each port and their sum, which must be ~0.

The **balance** per cycle: sources' net energy (supplied - returned) =
dissipated + change of stored energy + net work into storage without an energy
function, and its *residual*. Junctions, transformers and gyrators conserve
power at every instant, so the residual is the sum over the storage elements
with an energy function of ``integral(power in) - change of stored energy``:
it measures how far the simulated states are from integrating their own rates
(the solver's accumulated local error), plus the error of the quadrature
below, which is made far smaller. ``throughput`` is the sum over every element
(two-ports excepted) of ``integral(|power|)``, the energy that moved;
``relative_residual = |residual| / throughput``.

How the powers are integrated: the result must hold the solver's own step
points (a run without ``dt``; otherwise the run is repeated with the same
settings, which reproduces the same steps, and ``resimulated`` says so).
Steps never straddle an event or a known switching time. Each step is
evaluated with its modes frozen (the modes at its midpoint), as the solver
integrated it. The states inside a step start as the cubic Hermite
interpolant of the states and rates at both ends and are refined by
deferred-correction sweeps at the 5 Gauss-Lobatto nodes (see
:func:`_corrected_nodes`; steps where the sweeps would not contract, stiff
modes stepped over, keep the Hermite states); the powers there are
integrated with the 5-point Lobatto rule (exact for degree 7), a step halved
where that rule and Simpson's on its ends and middle disagree
(:func:`~bondc.analysis.energy.quadrature.under_resolved`: a long explicit
step over a law curved in its states). The
quadrature's own error is then far below the solver's: the residual follows
the solver tolerance down to about 1e-12 of the throughput (see
``tests/test_energy.py``). A window edge inside a step splits the step at the
refined interpolant. Positive and negative parts of a power come from the
degree-4 interpolant of the five samples where they change sign, so
``supplied - returned`` is the net integral exactly. Steps of a Filippov
sliding mode (the law there is a convex combination only the runtime
computes) use the result's recorded values, through a cubic spline over the
points of each sliding span (the motion is smooth there).
``EnergyAccount.quadrature`` counts the steps of each kind.

>>> from pathlib import Path
>>> from bondc import semantic
>>> from bondc.causality import assign_causality
>>> from bondc.equations import derive
>>> path = Path(__file__).parents[3] / "models/series_rlc.bg"
>>> graph, _ = semantic.load(path, experiment=semantic.FIRST)
>>> ss = derive(assign_causality(graph))
>>> from bondc.simulate import simulate
>>> account = energy_account(ss, simulate(ss, graph.experiments["step"], t_end=0.1))
>>> cycle = account.windows[0]
>>> round(cycle.balance.sources_net * 1e3, 6), round(cycle.element("resistor").dissipated * 1e3, 6)
(10.0, 5.0)
>>> account.windows[0].balance.relative_residual < 1e-8
True

The package, one job per module: :mod:`~bondc.analysis.energy.roles` (each kind's role),
:mod:`~bondc.analysis.energy.values` (the account's values), :mod:`~bondc.analysis.energy.cycles`
(the windows), :mod:`~bondc.analysis.energy.model` (the generated module over columns),
:mod:`~bondc.analysis.energy.trajectory` (the steps and their interpolant),
:mod:`~bondc.analysis.energy.quadrature` (a power's integral per step),
:mod:`~bondc.analysis.energy.stored` (stored-energy functions), :mod:`~bondc.analysis.energy.steps`
(a run at its solver's steps) and :mod:`~bondc.analysis.energy.account` (the account).
"""

from __future__ import annotations

from bondc.analysis.energy.account import RESIDUAL_TOLERANCE, atol_limited, energy_account
from bondc.analysis.energy.cycles import MAX_CYCLES, cycle_windows, experiment_cycle
from bondc.analysis.energy.model import _Model
from bondc.analysis.energy.quadrature import METHOD
from bondc.analysis.energy.roles import ROLES
from bondc.analysis.energy.steps import _at_solver_steps, dense_steps, repeat_run, steps_of
from bondc.analysis.energy.stored import _StoredEnergy, energy_from_recipe, energy_recipes, stored_energy_functions
from bondc.analysis.energy.trajectory import _sliding_spans
from bondc.analysis.energy.values import BALANCE_KEYS, ROW_KEYS, Balance, ElementEnergy, EnergyAccount, Window

__all__ = ["BALANCE_KEYS", "MAX_CYCLES", "METHOD", "RESIDUAL_TOLERANCE", "ROLES", "ROW_KEYS", "Balance",
           "ElementEnergy", "EnergyAccount", "Window", "atol_limited", "cycle_windows", "dense_steps",
           "energy_account", "energy_from_recipe", "energy_recipes", "experiment_cycle", "repeat_run",
           "steps_of", "stored_energy_functions"]
