"""The energy account: a :class:`~bondc.statespace.StateSpace` and a run of it -> an
:class:`~bondc.analysis.energy.values.EnergyAccount` (:func:`energy_account`), with the
residual's diagnostics (W930-W932) and their hints.
"""

from __future__ import annotations

import math

import numpy as np

from bondc.analysis.energy.cycles import cycle_windows, experiment_cycle
from bondc.analysis.energy.quadrature import _integrals
from bondc.analysis.energy.roles import ROLES
from bondc.analysis.energy.steps import _at_solver_steps, _run_nodes, steps_of
from bondc.analysis.energy.stored import energy_recipes, stored_energy_functions
from bondc.analysis.energy.values import Balance, ElementEnergy, EnergyAccount, Window, _error
from bondc.errors import Diagnostic
from bondc import codes

#: A residual above this fraction of the throughput gets warning W930.
RESIDUAL_TOLERANCE = 1e-6


def atol_limited(result, rtol, atol) -> list:
    """(state, its span over the run) of each state that ``atol`` resolves more than ten times
    more coarsely than ``rtol`` asks (atol > 10 rtol span) while it moves by 10 atol at least: a
    hydraulic chamber's volume in m^3 (1e-6) at the default atol of 1e-9 is resolved to 1e-3 of
    its span, whatever rtol is."""
    try:
        rtol, atol = float(rtol), float(atol)
    except (TypeError, ValueError):
        return []
    limited = []
    for name, values in result.states.items():
        values = np.asarray(values, dtype=float)
        finite = values[np.isfinite(values)]
        span = float(np.ptp(finite)) if finite.size else 0.0
        # (a state that never moves by more than a few atol is at the solver's noise level: tightening
        # atol for it is no remedy, as for the springs of a run stopped after 2 us)
        if 10.0 * atol <= span and atol > 10.0 * rtol * span:
            limited.append((name, span))
    return limited


def _drawn_outward(graph) -> list[str]:
    """The R, C and I elements whose bond leaves them (W304): their laws deliver the power they
    should dissipate or store, so no tolerance closes the balance."""
    names = []
    for element in graph.elements.values():
        if element.kind in ("R", "C", "I") and len(element.bonds) == 1:
            if graph.bond(element.bonds[0]).head != element.name:
                names.append(f"{element.kind} '{element.name}'")
    return names


def _residual_hint(result, settings, graph=None) -> str:
    rtol, atol = settings.get("rtol"), settings.get("atol")
    outward = _drawn_outward(graph) if graph is not None else []
    if outward:
        return (f"{', '.join(outward[:3])}{' and more' if len(outward) > 3 else ''} "
                f"{'is' if len(outward) == 1 else 'are'} drawn with the bond leaving "
                f"{'it' if len(outward) == 1 else 'them'} (W304): a law written for power in then delivers "
                "the power it should dissipate or store, which no tolerance closes; draw the bond towards "
                "the element")
    limited = atol_limited(result, rtol, atol)
    if not limited:
        return (f"the residual is the simulation's accumulated error (rtol={rtol}, atol={atol}); tighten the "
                "tolerances to shrink it")
    name, span = min(limited, key=lambda item: item[1])
    wanted = 10.0 ** math.floor(math.log10(float(rtol) * span))
    others = f" (and {len(limited) - 1} more)" if len(limited) > 1 else ""
    return (f"the residual is the simulation's accumulated error, here set by atol={atol}: '{name}'{others} "
            f"spans only {span:.3g} over the run, which atol resolves to {float(atol) / span:.1e} of that "
            f"whatever rtol ({rtol}) is; set atol = {wanted:.0e} (rtol times its span) in the experiment")


def energy_account(ss, result, *, cycle: float | None = None) -> EnergyAccount:
    """Energies of every element per cycle and the energy balance; see the module docstring.

    ``cycle`` [s]: the window length; None takes the experiment's ``cycle``
    (the whole run if it has none). Raises :class:`AnalysisError` E930 (the
    result is not a run of ``ss``), E931 (fewer than two points), E932 (a
    cycle that is not a positive number).
    """
    graph = ss.graph
    if set(result.states) != set(ss.state_names):
        raise _error(codes.E930, "the simulation result is not a run of this model: its states are "
                             f"{', '.join(result.states) or 'none'}, the model's {', '.join(ss.state_names)}",
                     hint="pass the StateSpace the result was simulated from")
    t = np.asarray(result.t, dtype=float)
    if t.size < 2 or not t[-1] > t[0]:
        raise _error(codes.E931, "the simulation result has no time span to account energy over",
                     hint="simulate past the start time")
    if cycle is None:
        cycle = experiment_cycle(ss, result)
    resimulated = not _at_solver_steps(result)
    steps = steps_of(ss, result)
    # a run on a grid is accounted from the same run at its solver's steps, which may have stopped
    # earlier (over a million steps, E814): the account then covers only that, and says so
    covered = float(np.asarray(steps.t, dtype=float)[-1]) if len(steps.t) else float(t[0])
    truncated = covered < float(t[-1]) - 1e-9 * max(abs(float(t[-1])), 1.0)
    windows = cycle_windows(float(t[0]), covered if truncated else float(t[-1]), cycle)
    if truncated and windows and windows[-1][1] == covered:
        windows[-1] = (windows[-1][0], windows[-1][1], True)

    units = getattr(graph, "si_units", {}) or {}
    # values bound late (--set, an edit of values only): the base's module, given the run's values
    boundaries = sorted({edge for start, end, _ in windows for edge in (start, end)})
    model, trajectory, times, values = _run_nodes(ss, steps, boundaries)
    quadrature = {"steps": int(times.shape[0]), "corrected": int(np.sum(trajectory.corrected)),
                  "hermite": int(np.sum(~trajectory.corrected & ~trajectory.sliding)),
                  "sliding": int(np.sum(trajectory.sliding))}

    # power into each element (per port for two-ports), at the Lobatto nodes
    def power_into(element, port_index):
        bond = graph.bond(element.bonds[port_index])
        product = values[f"{bond.name}.e"] * values[f"{bond.name}.f"]
        return product if bond.head == element.name else -product

    functions = stored_energy_functions(ss, steps.parameters)
    energies = {name: energy for name, energy in functions.items()
                if energy.state_name in model.state_names or energy.state_name in values}
    step_start, step_end = trajectory.ta, trajectory.tb
    if not step_start.size:     # (a run again at its steps that stopped before its first step)
        raise _error(codes.E931, "the simulation result has no solver step to account energy over",
                     hint="simulate past the start time")
    state_bounds = trajectory.states_at_bounds()
    scale = max(abs(windows[-1][1]), 1.0)
    masks = [(step_start >= start - 1e-12 * scale) & (step_end <= end + 1e-12 * scale)
             for start, end, _ in windows]

    def value_at(name, time, at_end):
        """A state (or eliminated state) at a window edge: the end of the step ending there, or the
        start of the step starting there."""
        index = np.argmin(np.abs((step_end if at_end else step_start) - time))
        if name in state_bounds:
            return float(state_bounds[name][1 if at_end else 0][index])
        return float(values[name][index, -1 if at_end else 0])

    event_times = np.array(sorted({float(time) for time, _ in getattr(result, "events", ())}))

    def switch_values(name):
        """The state's values at the run's events: where a law may switch (a hard stop's
        ``if q > gap``), breakpoints of its numeric energy function's quadrature."""
        if not event_times.size or name not in state_bounds:
            return ()
        index = np.clip(np.searchsorted(step_end, event_times), 0, step_end.size - 1)
        return tuple(float(v) for v in np.asarray(state_bounds[name][1])[index] if math.isfinite(v))

    per_element: dict[str, list[ElementEnergy]] = {}
    diagnostics: list[Diagnostic] = []
    if truncated:
        diagnostics.append(Diagnostic(
            "warning", codes.W932,
            f"the energy account covers t = {float(t[0]):.6g} to {covered:.6g} s of the run's {float(t[0]):.6g} to "
            f"{float(t[-1]):.6g} s: the run at the solver's own steps that it is computed from stopped there "
            f"({getattr(steps, 'message', '') or 'incomplete'})",
            hint="the figures after that time are missing, not zero: shorten the run or loosen its tolerances "
                 "so that it takes fewer steps"))
    for element in graph.elements.values():
        role = ROLES[element.kind]
        ports = [power_into(element, i) for i in range(len(element.bonds))]
        for power in ports:
            bad = ~np.isfinite(power)
            if np.any(bad):
                first = float(np.min(times[bad]))
                raise _error(codes.E934, f"the power into '{element.name}' is not finite from t={first:.6g} s: "
                                     "no energy account for this run",
                             hint="a law gives inf or nan there (W821 names the variable): a division by a "
                                  "parameter that is zero or tiny, or a state out of its range")
        integrals = [_integrals(times, p) for p in ports]
        entries = []
        for mask, (start, end, _) in zip(masks, windows):
            net = [float(np.sum(i[0][mask])) for i in integrals]
            positive = [float(np.sum(i[1][mask])) for i in integrals]
            negative = [float(np.sum(i[2][mask])) for i in integrals]
            work_in = sum(net)
            gross = sum(positive) - sum(negative)
            common = dict(element=element.name, kind=element.kind, role=role, work_in=work_in, gross=gross,
                          unit=units.get(f"energy:{element.name}", "J"))
            if role == "source":
                entries.append(ElementEnergy(**common, supplied=-negative[0], returned=positive[0]))
            elif role == "dissipator":
                entries.append(ElementEnergy(**common, dissipated=work_in))
            elif role == "converter":
                entries.append(ElementEnergy(**common, port_work=(net[0], net[1])))
            elif element.name in energies:
                energy = energies[element.name]
                breaks = switch_values(energy.state_name) if energy.kind == "numeric" else ()
                h0, h1, change = energy.change(value_at(energy.state_name, start, False),
                                               value_at(energy.state_name, end, True), breaks)
                jumps = [energy.change(before[energy.state_name], after[energy.state_name], breaks)[2]
                         for time, before, after in getattr(result, "jumps", ())
                         if start < time <= end and energy.state_name in before]
                if math.isfinite(change):
                    entries.append(ElementEnergy(**common, stored_start=h0, stored_end=h1, stored_change=change,
                                                 energy_function=energy.kind,
                                                 event_change=float(sum(jumps)) if jumps else None))
                else:       # its law left its domain on the way: count the work in instead
                    entries.append(ElementEnergy(**common, net_work_in=work_in))
            else:
                entries.append(ElementEnergy(**common, net_work_in=work_in))
        per_element[element.name] = entries

    result_windows = []
    for index, (start, end, partial) in enumerate(windows):
        window_entries = tuple(per_element[name][index] for name in graph.elements)
        total = lambda attribute: float(sum(getattr(e, attribute) or 0.0 for e in window_entries))
        converters = [e for e in window_entries if e.role == "converter"]
        balance = Balance(
            supplied=total("supplied"), returned=total("returned"), dissipated=total("dissipated"),
            stored_change=total("stored_change"), net_work_in=total("net_work_in"),
            converter_work=float(sum(e.work_in for e in converters)),
            throughput=float(sum(e.gross for e in window_entries if e.role != "converter")),
            event_change=total("event_change"))
        result_windows.append(Window(index, float(start), float(end), partial, window_entries, balance))
        for entry in converters:
            if abs(entry.work_in) > 1e-9 * max(entry.gross, 1e-300):
                diagnostics.append(Diagnostic(
                    "warning", codes.W931, f"two-port '{entry.element}' does not conserve power in cycle {index + 1}: "
                                       f"the work in at its ports sums to {entry.work_in:.3e} J",
                    hint="a transformer's or gyrator's port laws must give p1.e*p1.f = p2.e*p2.f"))
        relative = balance.relative_residual
        if relative is not None and relative > RESIDUAL_TOLERANCE:
            settings = getattr(result, "settings", {}) or {}
            units_of = {e.unit for e in window_entries}        # a pseudo bond graph's own (K*J), as the table says
            unit = " " + units_of.pop() if len(units_of) == 1 else ""
            diagnostics.append(Diagnostic(
                "warning", codes.W930,
                f"the energy balance of cycle {index + 1} does not close: residual {balance.residual:.3e}{unit}, "
                f"{relative:.2e} of the throughput {balance.throughput:.6g}{unit}",
                hint=_residual_hint(result, settings, graph)))
    return EnergyAccount(
        model=getattr(graph, "name", ""), experiment=getattr(result, "experiment", None),
        cycle=cycle, windows=tuple(result_windows), complete=bool(result.complete) and not truncated,
        resimulated=resimulated,
        quadrature=quadrature, diagnostics=tuple(diagnostics), energy_recipes=energy_recipes(functions))
