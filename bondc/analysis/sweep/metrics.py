"""What a sweep measures at each point: the metric names a model offers (:func:`select_metrics`),
and a finished run -> ``{metric: value}`` (output statistics, power per cycle, the energy balance,
the motor requirements) and the catalogue motors that qualify (:func:`_qualifying_motors`)."""

from __future__ import annotations

import difflib
import math
import statistics
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

from bondc.analysis.sweep.grid import _si_unit_text, _usage
from bondc.errors import BondcError, Diagnostic, UsageError
from bondc import codes


if TYPE_CHECKING:
    from bondc.analysis.sweep.point import _Setup

OUTPUT_STATISTICS = ("min", "max", "mean", "rms", "final")


DEFAULT_OUTPUT_STATISTICS = ("min", "max", "rms", "final")


ENERGY_METRICS = {"energy.residual": "J", "energy.relative_residual": None}


#: Of every power output, over the experiment's first cycle (stats.power_statistics): SI units.
CYCLE_STATISTICS = {"cycle_peak": "W", "cycle_rms": "W", "cycle_energy": "J", "cycle_energy_positive": "J",
                    "cycle_energy_negative": "J"}


_CYCLE_KEYS = {"cycle_peak": "peak", "cycle_rms": "rms", "cycle_energy": "net_energy",
               "cycle_energy_positive": "positive_energy", "cycle_energy_negative": "negative_energy"}


MOTOR_METRICS = {"motor.peak_torque": "N*m", "motor.rms_torque": "N*m", "motor.peak_speed": "rad/s",
                 "motor.peak_power": "W", "motor.energy": "J"}


_MOTOR_FIELDS = {"motor.peak_torque": "peak_torque", "motor.rms_torque": "rms_torque",
                 "motor.peak_speed": "peak_speed", "motor.peak_power": "peak_power", "motor.energy": "energy_net"}


@dataclass(frozen=True)
class Metric:
    """A column: its name, the unit of its SI value and how the text table shows it."""

    name: str
    si_unit: str | None
    unit: str | None = None          # the display unit (an output's declared unit)
    display_factor: float = 1.0      # display value = SI value / display_factor


def _available_metrics(graph, motor: bool) -> dict[str, Metric]:
    found: dict[str, Metric] = {}
    for name, output in graph.outputs.items():
        for statistic in OUTPUT_STATISTICS:
            found[f"{name}.{statistic}"] = Metric(f"{name}.{statistic}", _si_unit_text(output.unit_text),
                                                  output.unit_text, output.display_factor or 1.0)
    from bondc.analysis.stats import power_outputs

    for name in power_outputs(graph):          # per cycle (the experiment's first): peak, RMS, energies
        for statistic, unit in CYCLE_STATISTICS.items():
            shown = graph.outputs[name].unit_text if unit == "W" else "J"
            factor = (graph.outputs[name].display_factor or 1.0) if unit == "W" else 1.0
            found[f"{name}.{statistic}"] = Metric(f"{name}.{statistic}", unit, shown, factor)
    for name, unit in ENERGY_METRICS.items():
        found[name] = Metric(name, unit, unit)
    if motor:
        for name, unit in MOTOR_METRICS.items():
            found[name] = Metric(name, unit, unit)
    return found


def _has_motor(graph) -> bool:
    from bondc.analysis.motor_report import SPEED_NAMES, TORQUE_NAMES

    torque = any(name in graph.outputs for name in TORQUE_NAMES)
    speed = any(name in graph.outputs or name in graph.inputs for name in SPEED_NAMES)
    return torque and speed


def select_metrics(graph, metrics: Sequence[str] | None) -> tuple[Metric, ...]:
    """The columns ``metrics`` asks for (None: every default column), in the order asked; E965."""
    motor = _has_motor(graph)
    available = _available_metrics(graph, motor)
    if metrics is None:
        return tuple(m for name, m in available.items() if _default(name))
    chosen: dict[str, Metric] = {}
    for requested in metrics:
        for text in (part.strip() for part in requested.split(",")):
            if not text:
                continue
            if text.endswith(".*"):
                head = text[:-2]
                group = [m for name, m in available.items() if name.rpartition(".")[0] == head and _default(name)]
                if group:
                    chosen.update((m.name, m) for m in group)
                    continue
            elif text in available:
                chosen[text] = available[text]
                continue
            raise _unknown_metric(text, available, graph, motor)
    if not chosen:
        raise _usage(codes.E965, "no metrics selected", hint="e.g. --metric x.max --metric energy.residual")
    return tuple(chosen.values())


def _default(name: str) -> bool:
    """Whether a metric is a column when none are asked for (every one but the means)."""
    return (name in ENERGY_METRICS or name in MOTOR_METRICS
            or name.rpartition(".")[2] in DEFAULT_OUTPUT_STATISTICS or name.rpartition(".")[2] in CYCLE_STATISTICS)


def _unknown_metric(text: str, available: dict, graph, motor: bool) -> UsageError:
    if text.startswith("motor.") and not motor:
        return _usage(codes.E965, f"unknown metric '{text}': motor requirements need an output 'torque' and an "
                              "output or input 'omega' or 'speed'",
                      hint=f"outputs: {', '.join(graph.outputs) or 'none'}")
    head, dot, _ = text.rpartition(".")
    listing = (f"outputs: {', '.join(graph.outputs) or 'none'}, each with .min .max .mean .rms .final; "
               "also energy.residual, energy.relative_residual" + (", motor.*" if motor else ""))
    if dot and head not in graph.outputs and head not in ("energy", "motor"):
        close = difflib.get_close_matches(head, list(graph.outputs), n=1)
        return _usage(codes.E965, f"unknown metric '{text}': the model has no output '{head}'",
                      hint=f"did you mean '{close[0]}'?" if close else listing)
    close = difflib.get_close_matches(text, list(available), n=1)
    return _usage(codes.E965, f"unknown metric '{text}'", hint=f"did you mean '{close[0]}'?" if close else listing)


_CATALOGUES: dict[str, list] = {}


#: The version of the sizing rules a study's motors column was made with (part of its identity).
MOTOR_RULES = "peak envelope, RMS at RMS speed, top speed, inertia ratio (2)"


def _qualifying_motors(setup: _Setup, result, graph, warnings: list) -> tuple[str, ...] | None:
    """The catalogue motors that pass every sizing rule at this point, smallest first (the first is the
    point's choice); None: no selection possible. The same call as ``bondc simulate --motors``
    (:func:`bondc.analysis.motor_report.size_motors`): rotor inertia added, the load inertia
    estimated from the point's run, the inertia-ratio rule applied."""
    from bondc.analysis.motor_report import size_motors
    from bondc.analysis.motors import load_catalogue

    if setup.motors is None:
        return None
    try:
        catalogue = _CATALOGUES.get(setup.motors)
        if catalogue is None:
            catalogue = _CATALOGUES[setup.motors] = load_catalogue(setup.motors)
        selection = size_motors(result, graph, catalogue, inertia_limit=setup.inertia_ratio)
        return tuple(candidate.motor.name for candidate in selection.qualified)
    except BondcError as error:
        warnings += [Diagnostic("warning", d.code, f"no motor selection: {d.message}", d.span, d.hint)
                     for d in error.diagnostics]
        return None


def _measure(setup: _Setup, state_space, graph, experiment, result, warnings: list) -> dict:
    from bondc.analysis.stats import output_statistics

    wanted = setup.metrics
    metrics: dict[str, float] = {}
    statistics = output_statistics(result) if result.t.size else {}
    for name in wanted:
        output, _, statistic = name.rpartition(".")
        if output in statistics and statistic in OUTPUT_STATISTICS:
            metrics[name] = float(statistics[output][statistic])
    cycled = [name for name in wanted if name.rpartition(".")[2] in CYCLE_STATISTICS]
    if cycled and result.t.size > 1:
        from bondc.analysis.stats import power_statistics

        outputs = sorted({name.rpartition(".")[0] for name in cycled})
        per_cycle = power_statistics(result, outputs, experiment.cycle if experiment is not None else None)
        for name in cycled:
            output, _, statistic = name.rpartition(".")
            first = (per_cycle.get(output) or [None])[0]
            if first is not None:
                metrics[name] = float(first[_CYCLE_KEYS[statistic]])
    if any(name in ENERGY_METRICS for name in wanted):
        metrics.update(_energy_metrics(state_space, result, experiment, warnings))
    if any(name in MOTOR_METRICS for name in wanted):
        metrics.update(_motor_metrics(result, graph, warnings))
    return {name: metrics.get(name, math.nan) for name in wanted}


def _energy_metrics(state_space, result, experiment, warnings: list) -> dict:
    from bondc.analysis.energy import energy_account

    cycle = experiment.cycle if experiment is not None else None
    try:
        account = energy_account(state_space, result, cycle=cycle)
    except BondcError as error:
        warnings += [Diagnostic("warning", d.code, f"no energy balance: {d.message}", d.span, d.hint)
                     for d in error.diagnostics]
        return {}
    warnings += [d for d in account.diagnostics if d not in warnings]
    return {"energy.residual": float(sum(window.balance.residual for window in account.windows)),
            "energy.relative_residual": float(account.max_relative_residual)}


def _motor_metrics(result, graph, warnings: list) -> dict:
    from bondc.analysis.motor_report import SPEED_NAMES, TORQUE_NAMES, cycle_window, find_signal
    from bondc.analysis.motors import requirements

    try:
        _, _, torque = find_signal(result, TORQUE_NAMES, "torque")
        _, _, speed = find_signal(result, SPEED_NAMES, "speed")
        need = requirements(result.t, torque, speed, cycle=cycle_window(result, graph))
    except BondcError as error:
        warnings += [Diagnostic("warning", d.code, f"no motor requirements: {d.message}", d.span, d.hint)
                     for d in error.diagnostics]
        return {}
    return {name: float(getattr(need, attribute)) for name, attribute in _MOTOR_FIELDS.items()}
