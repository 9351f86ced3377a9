"""Regenerate the figures and numbers of docs/flagship.md from simulations of the flagship model.

    python docs/figures/make_figures.py            # all four experiments, about 1.5 min

writes, next to this script,

* ``flagship_torque.{svg,png}``  -- motor (coupling) torque over the cycle (the paper's Fig. 6);
* ``flagship_torque_zoom.{svg,png}`` -- the torque transients at the start of each move;
* ``flagship_power.{svg,png}``   -- motor power tau*omega (the paper's Fig. 7);
* ``flagship_motion.{svg,png}``  -- speed input, mass position and velocity, chamber pressure;
* ``flagship_variants.{svg,png}``-- torque of the four experiments;
* ``flagship_results.json``      -- every number the document quotes: per-cycle motor
  requirements, energy account, steady cruise values, motor selection, per experiment.

The images are written without timestamps (SVG ids salted with a fixed
string), so rerunning on the same versions gives the same files.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

from bondc import semantic  # noqa: E402
from bondc.analysis.energy import energy_account  # noqa: E402
from bondc.analysis.motor_report import motor_report  # noqa: E402
from bondc.causality import assign_causality  # noqa: E402
from bondc.equations import derive  # noqa: E402
from bondc.pipeline import simulate_file as run  # noqa: E402

MODEL = ROOT / "models" / "electro_pneumatic_hybrid.bg"
CATALOGUE = ROOT / "models" / "data" / "motors.csv"
EXPERIMENTS = ("cycle", "catalogue_valve", "measured_friction", "measured_speed")
PHASES = [(0.2, 1.45, "up"), (2.45, 3.70, "down")]
COLOURS = {"cycle": "#1f77b4", "catalogue_valve": "#ff7f0e", "measured_friction": "#2ca02c",
           "measured_speed": "#7f7f7f"}


def simulate_all(experiments=EXPERIMENTS) -> dict:
    runs = {}
    for name in experiments:
        print(f"simulating {name} ...", file=sys.stderr, flush=True)
        graph, _ = semantic.load(MODEL, experiment=name)
        state_space = derive(assign_causality(graph))
        result = run(MODEL, experiment=name)
        runs[name] = (graph, state_space, result)
    return runs


def _value(result, name, time):
    values = result.outputs[name] if name in result.outputs else result.variables[name]
    return float(np.interp(time, result.t, values))


def _trapezoid(values, t):
    return float(np.sum(np.diff(t) * (values[1:] + values[:-1]) / 2))


def _mean(result, name, start, end):
    inside = (result.t >= start) & (result.t <= end)
    t, values = result.t[inside], result.outputs[name][inside]
    return _trapezoid(values, t) / (t[-1] - t[0])


def numbers(graph, state_space, result) -> dict:
    """What docs/flagship.md quotes for one experiment."""
    text, motors = motor_report(result, graph, CATALOGUE)
    account = energy_account(state_space, result)
    window = account.windows[0]
    entry = window.element
    need = motors["requirements"]
    pneumatic = -entry("piston").port_work[1] - (entry("atmosphere").returned - entry("atmosphere").supplied)
    t = result.t
    up = (t >= 0.2) & (t <= 1.45)
    down = (t >= 2.45) & (t <= 3.70)
    torque, power = result.outputs["torque"], result.outputs["power"]
    friction_power = result.outputs["F_friction"] * result.outputs["v"]
    x = result.outputs["x"]
    return {
        "complete": result.complete,
        "points": int(t.size),
        "wall_time_s": result.stats.get("wall_time"),
        "peak_torque_up": float(torque[up].max()), "t_peak_torque_up": float(t[up][np.argmax(torque[up])]),
        "peak_torque_down": float(torque[down].min()),
        "t_peak_torque_down": float(t[down][np.argmin(torque[down])]),
        "rms_torque": need["rms_torque"],
        "peak_power": need["peak_power"], "t_peak_power": float(t[np.argmax(np.abs(power))]),
        "peak_power_regenerative": need["peak_power_regenerative"],
        "energy_positive": need["energy_positive"],
        "energy_regenerative": need["energy_regenerative"],
        "energy_net": need["energy_net"],
        # means over the middle of each cruise (the measured_speed torque is noisy sample by sample)
        "cruise_torque_up_mean": _mean(result, "torque", 0.5, 1.3),
        "cruise_torque_down_mean": _mean(result, "torque", 2.8, 3.5),
        "cruise_torque_up": _value(result, "torque", 0.8),
        "cruise_torque_down": _value(result, "torque", 3.0),
        "cruise_pressure_up": _value(result, "P", 0.8),
        "cruise_pressure_down": _value(result, "P", 3.0),
        "cruise_friction_up": _value(result, "F_friction", 0.8),
        "cruise_friction_down": _value(result, "F_friction", 3.0),
        "pressure_min": float(result.outputs["P"].min()), "pressure_max": float(result.outputs["P"].max()),
        "mdot_max": float(result.outputs["mdot_valve"].max()), "mdot_min": float(result.outputs["mdot_valve"].min()),
        "x_max": float(x.max()), "x_at_1.45": _value(result, "x", 1.45), "x_at_2.45": _value(result, "x", 2.45),
        "x_end": float(x[-1]),
        "energy": {
            "motor_net": entry("servomotor").supplied - entry("servomotor").returned,
            "motor_supplied": entry("servomotor").supplied, "motor_returned": entry("servomotor").returned,
            "friction": entry("friction").dissipated,
            "friction_up": _trapezoid(friction_power[up], t[up]),
            "nut_damper": entry("nut_damper").dissipated,
            "valve": entry("valve").dissipated,
            "pneumatic_work_on_mass": pneumatic,
            "supply_net": entry("supply").supplied - entry("supply").returned,
            "chamber_net_work_in": entry("chamber").net_work_in,
            "gravity_net": entry("gravity").returned - entry("gravity").supplied,
            "stored_change_mechanical": sum(entry(n).stored_change for n in ("coupling", "shaft", "nut", "mass")),
            "balance_residual": window.balance.residual,
            "balance_relative_residual": window.balance.relative_residual,
            "throughput": window.balance.throughput,
            "table": account.to_text(),
        },
        "motors": {k: motors[k] for k in ("load_inertia", "load_inertia_source", "include_rotor_inertia", "best",
                                          "cycle", "verdict")},
        "motor_candidates": [
            {"name": c["motor"]["name"], "qualifies": c["qualifies"], "margins": c["margins"],
             "inertia_ratio": c["inertia_ratio"], "reasons": c["reasons"]}
            for c in motors["candidates"]],
        "motor_text": text,
    }


def _shade(axes):
    for start, end, label in PHASES:
        axes.axvspan(start, end, color="0.92", zorder=0)
        axes.text((start + end) / 2, 0.97, label, transform=axes.get_xaxis_transform(), ha="center", va="top",
                  fontsize=8, color="0.4")


def _save(figure, stem, out):
    figure.tight_layout()
    figure.savefig(out / f"{stem}.svg", metadata={"Date": None})
    figure.savefig(out / f"{stem}.png", dpi=110, metadata={"Software": None})
    plt.close(figure)


def figures(runs, out: Path) -> None:
    plt.rcParams.update({"svg.hashsalt": "bondc-flagship", "font.size": 9, "axes.grid": True,
                         "grid.color": "0.85", "lines.linewidth": 1.0})
    _, _, cycle = runs["cycle"]
    t = cycle.t

    figure, axes = plt.subplots(figsize=(7.0, 3.2))
    _shade(axes)
    axes.plot(t, cycle.outputs["torque"], color=COLOURS["cycle"])
    axes.set(xlabel="t [s]", ylabel="torque τ = Kθ [N·m]", xlim=(0, 4.2),
             title="Servomotor torque over the cycle (experiment cycle; cf. the paper's Fig. 6)")
    _save(figure, "flagship_torque", out)

    figure, pair = plt.subplots(1, 2, figsize=(7.0, 3.0), sharey=True)
    for axes, (start, end, label) in zip(pair, [(0.19, 0.33, "start of the up move"),
                                                 (2.44, 2.58, "start of the down move")]):
        inside = (t >= start) & (t <= end)
        axes.plot(t[inside], cycle.outputs["torque"][inside], color=COLOURS["cycle"], label="torque")
        speed = axes.twinx()
        speed.plot(t[inside], cycle.variables["omega"][inside] * 60 / (2 * math.pi), color="0.5",
                   linestyle=":", label="ω_m")
        speed.set_ylim(-1100, 1100)
        speed.grid(False)
        if axes is pair[1]:
            speed.set_ylabel("ω_m [rpm] (dotted)")
        else:
            speed.set_yticklabels([])
        axes.set(xlabel="t [s]", xlim=(start, end), title=label)
    pair[0].set_ylabel("torque [N·m]")
    _save(figure, "flagship_torque_zoom", out)

    figure, axes = plt.subplots(figsize=(7.0, 3.2))
    _shade(axes)
    axes.plot(t, cycle.outputs["power"], color="#d62728")
    axes.axhline(0, color="0.3", linewidth=0.6)
    axes.set(xlabel="t [s]", ylabel="power τ·ω [W]", xlim=(0, 4.2),
             title="Servomotor power over the cycle (experiment cycle; cf. the paper's Fig. 7)")
    _save(figure, "flagship_power", out)

    figure, panels = plt.subplots(4, 1, figsize=(7.0, 7.0), sharex=True)
    series = [(cycle.variables["omega"] * 60 / (2 * math.pi), "ω_m [rpm]"),
              (cycle.outputs["x"] * 1e3, "x [mm]"),
              (cycle.outputs["v"] * 1e3, "v [mm/s]"),
              (cycle.outputs["P"] * 1e-3, "P [kPa abs]")]
    for axes, (values, label) in zip(panels, series):
        _shade(axes)
        axes.plot(t, values, color=COLOURS["cycle"])
        axes.set_ylabel(label)
    panels[3].axhline(224.0, color="0.3", linewidth=0.6, linestyle="--")
    panels[-1].set(xlabel="t [s]", xlim=(0, 4.2))
    panels[0].set_title("Speed input, mass position and velocity, chamber pressure (experiment cycle)")
    _save(figure, "flagship_motion", out)

    figure, axes = plt.subplots(figsize=(7.0, 3.6))
    _shade(axes)
    for name in ("measured_speed", "cycle", "catalogue_valve", "measured_friction"):
        if name not in runs:
            continue
        _, _, result = runs[name]
        axes.plot(result.t, result.outputs["torque"], color=COLOURS[name], label=name,
                  linewidth=0.7 if name == "measured_speed" else 1.0,
                  linestyle="--" if name == "catalogue_valve" else "-")
    axes.legend(fontsize=8, loc="lower left")
    axes.set(xlabel="t [s]", ylabel="torque [N·m]", xlim=(0, 4.2), title="Motor torque of the four experiments")
    _save(figure, "flagship_variants", out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE, help="output directory (default: docs/figures)")
    parser.add_argument("--only", nargs="*", choices=EXPERIMENTS, default=list(EXPERIMENTS),
                        help="experiments to simulate (the cycle is always included)")
    args = parser.parse_args(argv)
    chosen = ["cycle"] + [name for name in args.only if name != "cycle"]
    runs = simulate_all(chosen)
    args.out.mkdir(parents=True, exist_ok=True)
    figures(runs, args.out)
    results = {name: numbers(*runs[name]) for name in chosen}
    (args.out / "flagship_results.json").write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    print(f"wrote figures and flagship_results.json to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
