"""Motor requirements and catalogue selection for a simulated run: one call for the CLI and the report.

:func:`motor_report` takes a :class:`~bondc.simulate.SimResult`, the
:class:`~bondc.model.BondGraph` it was simulated from and a motor catalogue
(``models/data/motors.csv``) and returns ``(text, json_dict)``:

* **the profile**: the motor torque is the output named ``torque`` (the
  flagship's coupling torque ``K*theta``); the motor speed is the output
  named ``omega`` or ``speed``, or, when the model has no such output, the
  input signal of that name that the run records in ``result.variables``
  (the flagship's imposed servomotor speed ``omega``). Both names can be
  given explicitly.
* **the cycle**: the experiment's ``cycle`` setting: the last ``cycle``
  seconds of the run (the whole run when ``cycle`` equals ``t_end``, as in
  the flagship; the run's last, settled cycle when several were simulated).
  Without a ``cycle`` setting, the whole run.
* **the load inertia** for the inertia-ratio rule: given, or estimated
  from the run as the inertia that the motor shaft sees,
  J = integral(sum p*f over the mechanical I elements) dt / integral(omega^2) dt, i.e.
  twice the kinetic energy of every mass and rotating inertia per omega^2, averaged over the
  cycle (:func:`load_inertia_of`; when it cannot be known, it says why and the
  inertia-ratio rule is not applied). For a rigid transmission (every I's flow proportional to omega)
  this is exact: for the flagship it gives M*(lead/2pi)^2 + I_z =
  6.067e-5 kg*m^2 to within 0.1 % (the compliances and the dwell creep
  account for the rest).
* **rotor inertia**: ``include_rotor_inertia`` defaults to True because
  the torque found this way is the torque *delivered at the coupling*: a
  real motor must also accelerate its own rotor, tau_motor = tau +
  J_rotor*d(omega)/dt (see :func:`bondc.analysis.motors.select`). Pass
  False when the torque output is the motor's electromagnetic torque.

Raises :class:`~bondc.errors.UsageError` (E927) when the torque or the speed
cannot be found, and whatever :mod:`bondc.analysis.motors` raises for a bad
catalogue or profile (:class:`~bondc.errors.DataError`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from bondc.analysis.motors import load_catalogue, requirements, select
from bondc.errors import Diagnostic, UsageError
from bondc import codes

TORQUE_NAMES: tuple[str, ...] = ("torque",)
SPEED_NAMES: tuple[str, ...] = ("omega", "speed")


def find_signal(result, names: Sequence[str], what: str) -> tuple[str, str, np.ndarray]:
    """(name, where, values) of the first of ``names`` among the outputs, then the recorded inputs.

    ``where`` is ``"output"`` or ``"input"``. Raises UsageError E927 if none is there.
    """
    for name in names:
        if name in result.outputs:
            return name, "output", np.asarray(result.outputs[name], dtype=float)
    for name in names:
        if name in getattr(result, "variables", {}):
            return name, "input", np.asarray(result.variables[name], dtype=float)
    shown = ", ".join(f"'{n}'" for n in names)
    raise UsageError(Diagnostic(
        "error", codes.E927, f"motor selection needs the motor {what}: the model has no output or input named {shown}",
        hint=f"add e.g. 'output {names[0]} [...] = ...' to the model (outputs: {', '.join(result.outputs) or 'none'})"))


def cycle_window(result, graph) -> tuple[float, float]:
    """The experiment's cycle as (t_start, t_end): the last ``cycle`` seconds, or the whole run."""
    t_first, t_last = float(result.t[0]), float(result.t[-1])
    definition = None
    if graph is not None and getattr(result, "experiment", None):
        definition = getattr(graph, "experiments", {}).get(result.experiment)
    cycle = getattr(definition, "cycle", None)
    if cycle is None or not cycle > 0:
        return t_first, t_last
    start = t_last - float(cycle)
    # a cycle equal to t_end (up to rounding) is the whole run
    if start < t_first + 1e-9 * max(1.0, abs(t_last)):
        start = t_first
    return start, t_last


#: Flow units of the mechanical bonds (rotation, translation): the I elements whose kinetic energy the
#: motor shaft sees. An inductance (A) or a fluid inertance (m^3/s) is not a load inertia.
MECHANICAL_FLOWS = ("1/s", "m/s")


def load_inertia_of(result, graph, window: tuple[float, float] | None = None,
                    speed: np.ndarray | None = None) -> tuple[float | None, str | None]:
    """(the inertia the motor shaft sees, None) from the run, or (None, why it cannot be known).

    J = integral(sum p*f over the mechanical I elements) dt / integral(omega^2) dt: twice their
    kinetic energy per omega^2, averaged over the cycle (exact for a rigid transmission). ``p``
    is each I element's state, ``f`` its bond's flow. An I element whose bond carries a current
    or a volume flow is left out; one without a recorded state (rigidly coupled to another
    inertia: derivative causality) makes the load inertia unknown, since the run holds no
    momentum to reflect it from.
    """
    if graph is None:
        return None, "there is no model to estimate it from"
    time = np.asarray(result.t, dtype=float)
    if speed is None:
        _, _, speed = find_signal(result, SPEED_NAMES, "speed")
    units = getattr(graph, "si_units", {}) or {}
    twice_kinetic = np.zeros_like(time)
    found, unrecorded = [], []
    for element in graph.elements.values():
        if element.kind != "I" or not element.bonds:
            continue
        bond = graph.bond(element.bonds[0]).name
        if units.get(f"{bond}.f", MECHANICAL_FLOWS[0]) not in MECHANICAL_FLOWS:
            continue                        # an inductance or an inertance: not a load inertia
        state = element.states[0].qualified if element.states else None
        flow = f"{bond}.f"
        if state in result.states and flow in result.bonds:
            twice_kinetic = twice_kinetic + np.asarray(result.states[state]) * np.asarray(result.bonds[flow])
            found.append(element.name)
        else:
            unrecorded.append(element.name)
    if unrecorded:
        names = ", ".join(f"'{name}'" for name in unrecorded)
        plural = len(unrecorded) > 1
        return None, (f"the inerti{'as' if plural else 'a'} {names} {'are' if plural else 'is'} rigidly coupled "
                      f"to another inertia, in derivative causality, so the run records no momentum of "
                      f"{'them' if plural else 'it'} to reflect to the motor shaft")
    if not found:
        return None, "the model has no mass or rotating inertia, no mechanical I element, to reflect to the motor shaft"
    inside = np.ones(time.shape, dtype=bool) if window is None else (time >= window[0]) & (time <= window[1])
    t, energy, omega = time[inside], twice_kinetic[inside], np.asarray(speed, dtype=float)[inside]
    denominator = float(np.sum(np.diff(t) * (omega[1:] ** 2 + omega[:-1] ** 2) / 2))
    if not denominator > 0:
        return None, "the motor speed is zero throughout the cycle"
    value = float(np.sum(np.diff(t) * (energy[1:] + energy[:-1]) / 2)) / denominator
    if not (math.isfinite(value) and value > 0):
        return None, "the kinetic energy of the model's inertias is not positive over the cycle"
    return value, None


def estimate_load_inertia(result, graph, window: tuple[float, float] | None = None,
                          speed: np.ndarray | None = None) -> float | None:
    """The inertia the motor shaft sees, from the run (see :func:`load_inertia_of`); None when unknown."""
    return load_inertia_of(result, graph, window, speed)[0]


def size_motors(result, graph, catalogue, *, load_inertia: float | None = None,
                inertia_limit: float | None = None, include_rotor_inertia: bool = True,
                torque: str | None = None, speed: str | None = None):
    """The run's requirements judged against every motor of ``catalogue`` (a path or a list of Motor).

    The one place a simulated run meets the sizing rules (:func:`bondc.analysis.motors.judge`):
    ``bondc simulate --motors``, ``bondc report --motors`` and ``bondc sweep --motors`` all
    call it. Returns the :class:`~bondc.analysis.motors.Selection`, with the attributes
    ``signals`` ((name, where) of the torque and the speed), ``cycle`` and
    ``load_inertia_source`` ("given", "estimated" or None).
    """
    torque_name, torque_where, torque_values = find_signal(result, (torque,) if torque else TORQUE_NAMES, "torque")
    speed_name, speed_where, speed_values = find_signal(result, (speed,) if speed else SPEED_NAMES, "speed")
    window = cycle_window(result, graph)
    need = requirements(result.t, torque_values, speed_values, cycle=window)
    source: str | None = "given" if load_inertia is not None else None
    why: str | None = None
    if load_inertia is None:
        load_inertia, why = load_inertia_of(result, graph, window, speed_values)
        source = "estimated" if load_inertia is not None else None
    name: str | None = None
    if not isinstance(catalogue, (list, tuple)):
        name = Path(catalogue).name
        catalogue = load_catalogue(catalogue)
    selection = select(need, catalogue, load_inertia=load_inertia, include_rotor_inertia=include_rotor_inertia,
                       inertia_limit=inertia_limit, unknown_inertia=why, catalogue_name=name)
    selection.signals = ((torque_name, torque_where), (speed_name, speed_where))
    selection.cycle = window
    selection.load_inertia_source = source
    return selection


def motor_report(result, graph, catalogue_path, *, load_inertia: float | None = None,
                 include_rotor_inertia: bool = True, torque: str | None = None,
                 speed: str | None = None, inertia_limit: float | None = None) -> tuple[str, dict]:
    """Motor requirements over the experiment's cycle and the catalogue motors that meet them.

    Returns ``(text, json_dict)``: the text is what ``bondc simulate
    --motors FILE`` prints after the run, ending with the verdict paragraph; the dict holds
    ``torque`` and ``speed`` (the names and whether each is an output or an input),
    ``cycle`` [t_start, t_end], ``load_inertia`` and how it was obtained
    (``load_inertia_source``: "given", "estimated" or None, then
    ``load_inertia_unknown_because``), and everything of
    :meth:`bondc.analysis.motors.Selection.to_json` (``requirements``, ``verdict``,
    ``include_rotor_inertia``, ``best``, ``candidates``).
    """
    selection = size_motors(result, graph, catalogue_path, load_inertia=load_inertia, inertia_limit=inertia_limit,
                            include_rotor_inertia=include_rotor_inertia, torque=torque, speed=speed)
    return selection_report(selection, catalogue_path)


def selection_report(selection, catalogue_path) -> tuple[str, dict]:
    """:func:`motor_report` of a :func:`size_motors` selection already made (the report keeps the
    :class:`~bondc.analysis.motors.Selection` too, to draw the chosen motor's limits)."""
    (torque_name, torque_where), (speed_name, speed_where) = selection.signals
    source, window = selection.load_inertia_source, selection.cycle
    head = [f"motor selection from {Path(catalogue_path).name} ({len(selection)} motors)",
            f"  torque: {torque_where} '{torque_name}'; speed: {speed_where} '{speed_name}'"]
    if selection.load_inertia is not None:
        how = ("given" if source == "given" else
               "estimated from the run: integral(sum p*f of the mechanical I elements)/integral(omega^2)")
        head.append(f"  load inertia at the motor shaft: {selection.load_inertia:.4g} kg*m^2 ({how})")
    else:
        head.append(f"  load inertia: unknown ({selection.unknown_inertia}); no inertia-ratio check")
    text = "\n".join(head + ["", selection.to_text()])

    data = {
        "torque": {"name": torque_name, "from": torque_where},
        "speed": {"name": speed_name, "from": speed_where},
        "cycle": [window[0], window[1]],
        "catalogue": str(catalogue_path),
        "load_inertia_source": source,
        **selection.to_json(),
    }
    return text, data
