"""The report's time plots: a run's outputs grouped by unit and magnitude (:func:`output_groups`,
:func:`output_plots`) and the power of every source, store and dissipator (:func:`power_plots`),
each an SVG figure (:func:`bondc.report.render.plot_svg`).

>>> plot_unit("N*m")
'N·m'
"""

from __future__ import annotations

import re
from markupsafe import Markup
from typing import Sequence

import numpy as np

from bondc.model import BondGraph, ExperimentDef, KINDS
from bondc.report.render import FULL_SIZE, HALF_SIZE, Plot, plot_svg


#: Most series drawn in one plot; signals that share a unit are drawn together up to this.
MAX_SERIES_PER_PLOT = 4


#: Signals sharing a unit are drawn apart when their peak magnitudes differ more than this.
MAX_MAGNITUDE_RATIO = 5.0


def output_groups(graph: BondGraph, result, experiment: ExperimentDef | None) -> list[list[str]]:
    """The outputs to plot, grouped: the experiment's ``outputs`` first, then the rest in declaration order.

    Outputs that share a unit go in one plot (up to :data:`MAX_SERIES_PER_PLOT`)
    unless their peak magnitudes differ by more than :data:`MAX_MAGNITUDE_RATIO`.
    A model without outputs plots its states instead.
    """
    names = [n for n in (experiment.outputs if experiment is not None else ()) if n in result.outputs]
    names += [n for n in result.outputs if n not in names]
    if not names:
        return [[name] for name in result.states]
    groups: list[list[str]] = []
    keys: list[tuple] = []

    def peak(name):
        values = np.asarray(result.outputs[name], dtype=float)
        finite = values[np.isfinite(values)]
        return float(np.max(np.abs(finite))) if finite.size else 0.0

    for name in names:
        unit = graph.outputs[name].unit_text if name in graph.outputs else None
        placed = False
        for group, key in zip(groups, keys):
            if unit is None or key != (unit,) or len(group) >= MAX_SERIES_PER_PLOT:
                continue
            peaks = [peak(n) for n in group] + [peak(name)]
            nonzero = [p for p in peaks if p > 0]
            if nonzero and max(nonzero) / min(nonzero) > MAX_MAGNITUDE_RATIO:
                continue
            group.append(name)
            placed = True
            break
        if not placed:
            groups.append([name])
            keys.append((unit,))
    return groups


def plot_unit(text: str | None) -> str:
    """A unit as written, for an axis label: ``N*m/s^2`` -> ``N·m/s²``.

    >>> plot_unit("kg*m^2/s^-1")
    'kg·m²/s⁻¹'
    """
    if not text:
        return ""
    superscripts = str.maketrans("0123456789-.", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻·")
    text = re.sub(r"\^\(?([-0-9.]+)\)?", lambda m: m.group(1).translate(superscripts), text)
    return text.replace("*", "·")


def time_axis(t) -> tuple[np.ndarray, str]:
    """Times for a plot's axis and its label: seconds, or milliseconds for a run shorter than 0.1 s.

    >>> time_axis([0.0, 0.02])[1], time_axis([0.0, 4.2])[1]
    ('t [ms]', 't [s]')
    """
    t = np.asarray(t, dtype=float)
    span = float(t[-1] - t[0]) if t.size else 0.0
    if 0 < span < 0.1:
        return t * 1e3, "t [ms]"
    return t, "t [s]"


def time_plot(t, series, title, ylabel, *, half=False, styles=None) -> Markup:
    times, xlabel = time_axis(t)
    return plot_svg(times, series, title, ylabel, xlabel=xlabel, size=HALF_SIZE if half else FULL_SIZE,
                    styles=styles)


def _names(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:] if text else text


def output_plots(graph: BondGraph, result, experiment: ExperimentDef | None) -> list[Plot]:
    """One plot per group of :func:`output_groups`, in the outputs' display units."""
    plots = []
    featured = set(experiment.outputs if experiment is not None else ())
    for number, group in enumerate(output_groups(graph, result, experiment)):
        # the experiment's outputs (else the first plot) full width, the others two to a row
        half = not (featured & set(group) or (not featured and number == 0))
        series, notes = {}, []
        unit = None
        kind = "output"
        for name in group:
            if name in result.outputs:
                definition = graph.outputs[name]
                unit = definition.unit_text
                series[name] = np.asarray(result.outputs[name], dtype=float) / definition.display_factor
                description = definition.description
            else:
                kind = "state"
                state = next(s for s in graph.states if s.qualified == name)
                unit = state.unit_text
                series[name] = np.asarray(result.states[name], dtype=float)
                description = state.description
            if description:
                notes.append(f"{name}: {description}" if len(group) > 1 else _sentence(description))
        title = f"{_sentence(kind)}{'s' if len(group) > 1 else ''} {_names(group)}"
        label = group[0] if len(group) == 1 else ""
        if unit:
            label += f" [{plot_unit(unit)}]"
        plots.append(Plot(title, time_plot(result.t, series, title, label.strip(), half=half), "; ".join(notes),
                          half))
    return plots


#: Plots of power: (title, roles, sign, caption). ``sign`` turns "power into the element" into what is shown.
POWER_PLOTS = (
    ("Power delivered by the sources", ("source",), -1.0, "Positive: the source delivers power to the system"),
    ("Power into the storage elements", ("storage",), 1.0, "Positive: the element stores energy"),
    ("Power dissipated in the resistors", ("dissipator",), 1.0, ""),
)


def element_power(graph: BondGraph, result) -> dict[str, np.ndarray]:
    """Power into every one-port element [W] over the run: e*f when its bond points at it, else -e*f."""
    power = {}
    for element in graph.elements.values():
        if KINDS[element.kind].ports != 1:
            continue
        bond = graph.bond(element.bond)
        effort, flow = result.bonds.get(f"{bond.name}.e"), result.bonds.get(f"{bond.name}.f")
        if effort is None or flow is None:
            continue
        product = np.asarray(effort, dtype=float) * np.asarray(flow, dtype=float)
        power[element.name] = product if bond.head == element.name else -product
    return power


def _role(kind: str) -> str:
    from bondc.analysis.energy import ROLES

    return ROLES[kind]


def power_plots(graph: BondGraph, result) -> list[Plot]:
    """Power of the sources, storage elements and resistors against time, one plot per role."""
    power = element_power(graph, result)
    plots = []
    for title, roles, sign, caption in POWER_PLOTS:
        series = {name: sign * values for name, values in power.items()
                  if _role(graph.elements[name].kind) in roles}
        if series:
            half = roles != ("source",)
            plots.append(Plot(title, time_plot(result.t, series, title, "power [W]", half=half), caption, half))
    return plots
