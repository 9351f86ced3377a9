"""The report's motor section: a run (and a motor catalogue) -> the motor requirements over the cycle,
the smallest qualifying motor with its margins and plots, and the catalogue's candidates table."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

import numpy as np

from bondc.errors import UsageError
from bondc.report.render import Answer, CandidateRow, HLine, Plot, RuleMargin, Table, plot_svg

if TYPE_CHECKING:
    from bondc.pipeline import PipelineRun


#: The signals the motor analysis reads: the motor torque and the motor speed (an output or an input).
MOTOR_TORQUE, MOTOR_SPEED = "torque", "omega"


def _answer(selection) -> Answer | None:
    """The design answer the report leads with, from the catalogue's :class:`~bondc.analysis.motors.Selection`:
    the verdict, the chosen motor's rule margins, the cycle's torque over time against its continuous and
    peak limits, the torque-speed points on its envelope (zoomed to the operating region) and every motor
    in a compact table. When no motor qualifies, the largest (the one the verdict names) is shown.
    None for an empty catalogue."""
    from bondc.analysis.motors import RULES

    by_size = sorted(selection, key=lambda candidate: candidate.motor.size)
    if not by_size:
        return None
    chosen = selection.best
    shown = chosen if chosen is not None else by_size[-1]
    need = selection.requirements
    torque = need.torque
    if selection.include_rotor_inertia:
        from bondc.analysis.motors import motor_torque

        torque = motor_torque(shown.motor, need)
    why = "" if chosen is not None else f". No motor qualifies: {shown.motor.name} is the largest"
    torque_plot, speed_plot = _answer_plots(selection, shown, need, torque, why)
    rows = [CandidateRow(c.motor.name, tuple((c.check(rule).margin, c.check(rule).passed) for rule in RULES),
                         "the choice" if c is chosen else "qualifies" if c.qualifies else "fails", c is chosen)
            for c in by_size]
    return Answer(selection.verdict(), chosen.motor.name if chosen is not None else None, shown.motor.name,
                  _rule_margins(shown), torque_plot, speed_plot, rows)


def _rule_margins(candidate) -> list[RuleMargin]:
    """The rules of one motor as the answer's table shows them, with units (the verdict's figures)."""
    from bondc.analysis.motors import figure

    rows = []
    for check in candidate.checks:
        speed = f" at {figure(check.speed)} rpm" if check.speed is not None and check.speed > 0 else ""
        if check.rule == "peak_torque":
            row = ("peak torque", f"{figure(check.required)} N·m{speed}", f"{figure(check.available)} N·m")
        elif check.rule == "rms_torque":
            row = ("RMS torque", f"{figure(check.required)} N·m{speed}",
                   f"{figure(check.available)} N·m")
        elif check.rule == "speed":
            row = ("top speed", f"{figure(check.required)} rpm", f"{figure(check.available)} rpm")
        elif check.rule == "inertia_ratio":
            needed = (f"load/rotor {figure(check.required)}" if check.required is not None
                      else "load inertia unknown: not checked")
            row = ("inertia ratio", needed, f"up to {figure(check.available)}")
        else:
            row = ("peak power", f"{figure(check.required or 0.0)} W",
                   f"{figure(check.available)} W rated")
        rows.append(RuleMargin(*row, check.margin, check.headroom, check.passed))
    return rows


def _answer_plots(selection, shown, need, torque: np.ndarray, why: str = "") -> tuple[Plot, Plot]:
    """(the torque over the cycle against the motor's limits, the torque-speed points on its envelope);
    ``why`` ends both captions (why this motor is shown when none qualifies)."""
    import hashlib
    import math

    import matplotlib
    from matplotlib.figure import Figure

    from bondc.analysis.motors import figure as fig_text
    from bondc.report.render import (
        ANSWER_SIZE, LIMIT_COLOR, PLOT_STYLE, POINTS_COLOR, RMS_COLOR, draw_motor_envelope, figure_svg,
        legend_on_top, scatter_indices,
    )

    motor = shown.motor
    rms = shown.check("rms_torque")
    time = np.asarray(need.time, dtype=float)
    torque = np.asarray(torque, dtype=float)
    peak = max(float(motor.peak_torque), float(np.max(np.abs(torque))))
    limits = [HLine(motor.peak_torque, f"peak ±{fig_text(motor.peak_torque)} N·m",
                    (("color", LIMIT_COLOR), ("linestyle", "--"), ("linewidth", 1.2)), "limit-peak"),
              HLine(-motor.peak_torque, "peak", (("color", LIMIT_COLOR), ("linestyle", "--"), ("linewidth", 1.2)),
                    "limit-peak-negative", legend=False),
              HLine(motor.rated_torque, f"continuous ±{fig_text(motor.rated_torque)} N·m",
                    (("color", LIMIT_COLOR), ("linewidth", 1.2)), "limit-continuous"),
              HLine(-motor.rated_torque, "continuous", (("color", LIMIT_COLOR), ("linewidth", 1.2)),
                    "limit-continuous-negative", legend=False),
              HLine(rms.required, f"RMS {fig_text(rms.required)} N·m",
                    (("color", RMS_COLOR), ("linestyle", ":"), ("linewidth", 1.2)), "rms"),
              HLine(-rms.required, "RMS", (("color", RMS_COLOR), ("linestyle", ":"), ("linewidth", 1.2)),
                    "rms-negative", legend=False)]
    title = f"Torque over the cycle against {motor.name}'s limits"
    torque_svg = plot_svg(time, {"motor torque": torque}, title, "torque [N·m]", size=ANSWER_SIZE,
                          styles={"motor torque": {"color": POINTS_COLOR, "linewidth": 1.1}}, hlines=limits,
                          ylim=(-1.15 * peak, 1.15 * peak), legend_above=True)
    delivered = (f"The torque at the coupling + {motor.name}'s rotor inertia × dω/dt"
                 if selection.include_rotor_inertia else "The motor torque")
    torque_caption = (f"{delivered}, against {motor.name}'s continuous (rated) and peak torque, and the cycle's "
                      f"RMS torque; drag to zoom{why}")
    torque_plot = Plot(title, torque_svg, torque_caption)

    rpm = np.abs(np.asarray(need.speed, dtype=float)) / (2 * math.pi / 60)
    load = np.abs(torque)
    title = f"Torque against speed on {motor.name}'s envelope"
    key = hashlib.sha256((title + repr((rpm.tobytes(), load.tobytes()))).encode()).hexdigest()
    with matplotlib.rc_context({**PLOT_STYLE, "svg.hashsalt": key}):
        chart = Figure(figsize=ANSWER_SIZE, layout="constrained")
        axes = chart.add_subplot()
        draw_motor_envelope(axes, motor, LIMIT_COLOR)
        kept = scatter_indices(rpm, load)
        axes.plot(rpm[kept], load[kept], ".", markersize=2.5, color=POINTS_COLOR, label="operating points",
                  gid="operating-points")
        axes.plot([rms.speed or 0.0], [rms.required], "D", markersize=5, color=RMS_COLOR,
                  label="RMS torque at RMS speed", gid="rms-point")
        top_speed = max(float(np.max(rpm)), float(motor.top_speed))
        top_torque = max(float(np.max(load)), float(motor.peak_torque))
        axes.set_xlim(0, 1.3 * top_speed)
        axes.set_ylim(0, 1.3 * top_torque)
        axes.set_xlabel("speed |ω| [rpm]")
        axes.set_ylabel("torque |τ| [N·m]")
        legend_on_top(axes)
        speed_svg = figure_svg(chart, title, key)
    caption = (f"The cycle's operating points (the torque beside) and its RMS torque at the RMS speed, on "
               f"{motor.name}'s continuous (solid) and peak (dashed) envelope")
    if kept.size < rpm.size:
        shown_n, total = (f"{n:,}".replace(",", "\u202f") for n in (kept.size, rpm.size))
        caption += (f"; {shown_n} of the {total} operating points are drawn, one in each small cell: the cloud "
                    "of them all")
    caption += why
    return torque_plot, Plot(title, speed_svg, caption)


def motor_sections(run: PipelineRun, motors, inertia_ratio: float | None = None
                    ) -> tuple[Table | None, Table | None, list, str | None, Answer | None]:
    """Motor requirements when the model has signals ``torque`` and ``omega``; candidates from ``motors``,
    the verdict (:meth:`bondc.analysis.motors.Selection.verdict`, the same paragraph as
    ``bondc simulate --motors``) and the answer (:func:`_answer`) that the report leads with.

    Raises UsageError (E927) when a catalogue is given but the signals are missing.
    """
    from bondc.analysis.motor_report import (
        cycle_window, estimate_load_inertia, find_signal, selection_report, size_motors,
    )
    from bondc.analysis.energy import dense_steps
    from bondc.analysis.motors import requirements

    # requirements from the solver's steps and between them (dense_steps); the plots show run.result
    result, graph = dense_steps(run.state_space, run.result), run.graph
    try:
        torque = find_signal(result, (MOTOR_TORQUE,), "torque")
        speed = find_signal(result, (MOTOR_SPEED,), "speed")
    except UsageError:
        if motors is not None:
            raise
        return None, None, [], None, None
    answer = None
    if motors is not None:
        selection = size_motors(result, graph, motors, torque=MOTOR_TORQUE, speed=MOTOR_SPEED,
                                inertia_limit=inertia_ratio)
        _, data = selection_report(selection, motors)
        need, load_inertia = data["requirements"], data["load_inertia"]
        answer = _answer(selection)
    else:
        window = cycle_window(result, graph)
        need = requirements(result.t, torque[2], speed[2], cycle=window).to_json()
        load_inertia = estimate_load_inertia(result, graph, window, speed[2])
        data = None
    rows = [
        ("cycle", f"{need['t_start']:g} – {need['t_end']:g}", "s"),
        ("peak torque |τ|", need["peak_torque"], "N·m"),
        ("largest positive torque", need["peak_torque_positive"], "N·m"),
        ("most negative torque", need["peak_torque_negative"], "N·m"),
        ("RMS torque", need["rms_torque"], "N·m"),
        ("peak speed", need["peak_speed"], "rad/s"),
        ("peak speed", need["peak_speed_rpm"], "rpm"),
        ("RMS speed", need["rms_speed_rpm"], "rpm"),
        ("peak power |τ·ω|", need["peak_power"], "W"),
        ("peak motoring power", need["peak_power_motoring"], "W"),
        ("peak regenerative power", need["peak_power_regenerative"], "W"),
        ("motoring energy per cycle", need["energy_positive"], "J"),
        ("regenerative energy per cycle", need["energy_regenerative"], "J"),
        ("net energy per cycle", need["energy_net"], "J"),
    ]
    if load_inertia is not None:
        rows.append(("load inertia at the motor shaft (estimated from the run)", load_inertia, "kg·m²"))
    described = []
    for name, where, _ in (torque, speed):
        definition = graph.outputs.get(name) if where == "output" else graph.inputs.get(name)
        text = f"{where} {name}"
        if definition is not None and definition.description:
            text += f" ({definition.description})"
        described.append(text)
    requirements_table = Table(
        "What the cycle asks of the motor", ("quantity", "value", "unit"), rows,
        caption=f"Torque: {described[0]}; speed: {described[1]}",
        notes=["Energies integrate τ·ω over the cycle, split at its zero crossings (regenerative energy is "
               "returned by the load to the motor)."])
    # the load's figures, without a motor's rotor inertia (the answer's are the chosen motor's, with it)
    summary = [("peak load torque", need["peak_torque"], "N*m"), ("RMS load torque", need["rms_torque"], "N*m"),
               ("peak load power", need["peak_power"], "W"), ("motor energy per cycle", need["energy_net"], "J")]
    if data is None:
        return requirements_table, None, summary, None, None
    return (requirements_table, _candidates_table(data, motors), summary + _motor_choice(data), data["verdict"],
            answer)


def _motor_choice(data: Mapping) -> list:
    return [("motor", data.get("best") or "none of the catalogue qualifies", None)]


def _candidates_table(data: Mapping, catalogue) -> Table:
    rows = []
    for candidate in data["candidates"]:
        motor, checks = candidate["motor"], candidate["checks"]
        if candidate["motor"]["name"] == data.get("best"):
            verdict = "the choice"
        elif candidate["qualifies"]:
            verdict = "qualifies"
        else:
            verdict = "fails: " + ", ".join(label for key, label in MARGIN_LABELS if checks[key]["passed"] is False)
        rows.append((motor["name"], motor["rated_power"])
                    + tuple(_two_decimals(checks[key]["margin"]) for key, _ in MARGIN_LABELS)
                    + (_two_decimals(candidate.get("inertia_ratio")), _two_decimals(checks["power"]["margin"]),
                       verdict))
    limit = data.get("inertia_limit")
    limit_text = (f"{limit:g} (--inertia-ratio)" if limit is not None
                  else "the catalogue's max_inertia_ratio for the motor, else 10")
    notes = ["The rules, each a margin available / required (a motor qualifies when every margin is at least 1): "
             "peak τ, the peak (intermittent) torque envelope at each instant's speed over |τ| (the worst "
             "instant); RMS τ, the continuous envelope at the RMS speed over the RMS torque (the thermal check); "
             "speed, the top speed (max_speed, else the rated speed) over the peak speed; J limit, the "
             f"inertia-ratio limit ({limit_text}) over the load/rotor inertia ratio. Power, the rated power over "
             "the peak |τ·ω|, is information, not a rule."]
    if data.get("include_rotor_inertia"):
        notes.append("Each motor is judged with its own rotor inertia added to the torque: τ + J_rotor·dω/dt.")
    if data.get("load_inertia") is not None:
        notes.append(f"J ratio: the load inertia at the motor shaft ({data['load_inertia']:.4g} kg·m², "
                     f"{data.get('load_inertia_source') or 'given'}) over the rotor inertia.")
    else:
        notes.append(f"The load inertia is unknown ({data.get('load_inertia_unknown_because')}): no inertia-ratio "
                     "check was made.")
    best = data.get("best")
    notes.append(f"Choice: {best}, the smallest motor that passes every rule." if best is not None
                 else "No motor of the catalogue qualifies.")
    return Table(f"Motors of {Path(catalogue).name}, qualifying first, smallest first",
                 ("motor", "rated power [W]") + tuple(label for _, label in MARGIN_LABELS)
                 + ("J ratio", "power (info)", "verdict"),
                 rows, caption="The columns peak τ, RMS τ, speed, J limit and power are margins: available / required",
                 notes=notes)


MARGIN_LABELS = (("peak_torque", "peak τ"), ("rms_torque", "RMS τ"), ("speed", "speed"),
                 ("inertia_ratio", "J limit"))


def _two_decimals(value):
    return None if value is None else round(float(value), 2)
