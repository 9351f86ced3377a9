"""``bondc report --sweep study.csv``: the HTML report of a design study.

Reads the table ``bondc sweep -o study.csv`` wrote (units in the header, SI
values) and renders one self-contained page: the study's size and how its
points ended; each metric against the first varied parameter, with the points
that did not run marked on the axis; over two varied parameters on a grid, a
heat map of each metric with those points crossed out; with motor metrics and a
catalogue, every point's operating point (peak speed, peak and RMS torque)
against each motor's continuous and peak envelope, and the motors that cover
the whole study; then the table itself. Every text from the file is escaped.

Which columns are the varied parameters: those between ``index`` and the first
metric, a metric being ``OUTPUT.min/.max/.mean/.rms/.final``, ``energy.*`` or
``motor.*``.
"""

from __future__ import annotations

import csv
import hashlib
import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from markupsafe import Markup

from bondc.errors import DataError, Diagnostic
from bondc.report.render import PLOT_STYLE, content_security_policy, draw_motor_envelopes, environment, figure_svg

STATISTICS = ("min", "max", "mean", "rms", "final", "cycle_peak", "cycle_rms", "cycle_energy",
              "cycle_energy_positive", "cycle_energy_negative")
ENDINGS = ("status", "message", "wall_time", "motors")


@dataclass
class Study:
    path: str
    parameters: list[tuple[str, str | None]]      # (name, SI unit)
    metrics: list[tuple[str, str | None]]
    rows: list[dict] = field(default_factory=list)  # index, params {}, metrics {}, motors, status, message, wall_time

    @property
    def ran(self) -> list[dict]:
        return [row for row in self.rows if row["status"] in ("ok", "incomplete")]


def _split(cell: str) -> tuple[str, str | None]:
    from bondc.runtime import header_cell

    return header_cell(cell)


def _is_metric(name: str) -> bool:
    return name.startswith(("energy.", "motor.")) or name.rpartition(".")[2] in STATISTICS


def _number(text: str) -> float:
    return float(text) if text not in ("", None) else math.nan


def read_study(path) -> Study:
    """The table of ``bondc sweep -o FILE.csv``; DataError E972 when it is not one."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError) as error:
        raise DataError(Diagnostic("error", "E972", f"cannot read the sweep table '{path}': {error}")) from None
    header = [_split(cell) for cell in rows[0]] if rows else []
    names = [name for name, _ in header]
    if not names or names[0] != "index" or "status" not in names:
        raise DataError(Diagnostic("error", "E972", f"'{path}' is not a table written by bondc sweep",
                                   hint="give the .csv that 'bondc sweep -o FILE.csv' wrote"))
    end = min(names.index(n) for n in ENDINGS if n in names)
    middle = header[1:end]
    first_metric = next((i for i, (name, _) in enumerate(middle) if _is_metric(name)), len(middle))
    study = Study(str(path), middle[:first_metric], middle[first_metric:])
    column = {name: number for number, name in enumerate(names)}
    for cells in rows[1:]:
        if len(cells) != len(names):
            continue                    # a row an interruption cut short
        row = {"index": int(cells[0]), "status": cells[column["status"]],
               "message": cells[column["message"]] if "message" in column else "",
               "wall_time": _number(cells[column["wall_time"]]) if "wall_time" in column else math.nan,
               "motors": ([m for m in cells[column["motors"]].split(";") if m] if "motors" in column else None),
               "params": {name: _number(cells[1 + i]) for i, (name, _) in enumerate(study.parameters)},
               "metrics": {name: _number(cells[1 + first_metric + i]) for i, (name, _) in enumerate(study.metrics)}}
        study.rows.append(row)
    return study


def _label(name: str, unit: str | None) -> str:
    return f"{name} [{unit}]" if unit and unit != "1" else name


@contextmanager
def _figure(title: str):
    """A figure drawn in the reports' style; yields (figure, key for :func:`figure_svg`)."""
    import matplotlib
    from matplotlib.figure import Figure

    key = hashlib.sha256(title.encode()).hexdigest()
    with matplotlib.rc_context({**PLOT_STYLE, "svg.hashsalt": key}):
        yield Figure(figsize=(6.4, 3.4), layout="constrained"), key


def metric_plot(study: Study, metric: tuple[str, str | None]) -> Markup:
    """A metric against the first varied parameter; points that did not run marked on the axis."""
    (x_name, x_unit), (name, unit) = study.parameters[0], metric
    title = f"{name} against {x_name}"
    ran = sorted((r["params"][x_name], r["metrics"][name]) for r in study.ran if math.isfinite(r["metrics"][name]))
    bad = [r["params"][x_name] for r in study.rows if r not in study.ran]
    with _figure(title) as (figure, key):
        axes = figure.add_subplot()
        if ran:
            xs, ys = zip(*ran)
            axes.plot(xs, ys, marker="o", markersize=3.5, linestyle="-" if len(study.parameters) == 1 else "none",
                      label="ran")
        if bad:
            axes.plot(bad, [min(ys) if ran else 0.0] * len(bad), marker="x", color="#cf222e", linestyle="none",
                      markersize=7, label="failed or timed out")
            axes.legend(loc="best")
        axes.set_xlabel(_label(x_name, x_unit))
        axes.set_ylabel(_label(name, unit))
        return figure_svg(figure, title, key)


def heat_map(study: Study, metric: tuple[str, str | None]) -> Markup | None:
    """A metric over two varied parameters on a full grid; cells that did not run crossed out."""
    (a, a_unit), (b, b_unit) = study.parameters[:2]
    xs = sorted({r["params"][a] for r in study.rows})
    ys = sorted({r["params"][b] for r in study.rows})
    if len(xs) * len(ys) != len(study.rows) or len(xs) < 2 or len(ys) < 2:
        return None                      # not a grid (a Latin hypercube): the scatter plots show it
    name, unit = metric
    grid = np.full((len(ys), len(xs)), np.nan)
    for row in study.ran:
        grid[ys.index(row["params"][b]), xs.index(row["params"][a])] = row["metrics"][name]
    title = f"{name} over {a} and {b}"
    with _figure(title) as (figure, key):
        axes = figure.add_subplot()
        mesh = axes.pcolormesh(np.arange(len(xs) + 1), np.arange(len(ys) + 1), grid, cmap="viridis",
                               shading="flat")
        bar = figure.colorbar(mesh, ax=axes, label=_label(name, unit))
        bar.solids.set_rasterized(False)        # vector shapes: no embedded image in the page
        for row in study.rows:
            if row not in study.ran:
                i, j = xs.index(row["params"][a]), ys.index(row["params"][b])
                axes.plot([i + 0.15, i + 0.85], [j + 0.15, j + 0.85], color="#cf222e", linewidth=2)
                axes.plot([i + 0.15, i + 0.85], [j + 0.85, j + 0.15], color="#cf222e", linewidth=2)
        axes.set_xticks(np.arange(len(xs)) + 0.5, [f"{x:.4g}" for x in xs])
        axes.set_yticks(np.arange(len(ys)) + 0.5, [f"{y:.4g}" for y in ys])
        axes.set_xlabel(_label(a, a_unit))
        axes.set_ylabel(_label(b, b_unit))
        axes.grid(False)
        return figure_svg(figure, title, key)


def motor_plot(study: Study, catalogue) -> Markup | None:
    """Every point's peak speed against its peak and RMS torque, over each motor's envelopes:
    continuous (rated torque up to rated speed) and peak (peak torque up to rated speed)."""
    needed = ("motor.peak_speed", "motor.peak_torque", "motor.rms_torque")
    names = [name for name, _ in study.metrics]
    if not all(n in names for n in needed):
        return None
    title = "operating points of the study against the motors' envelopes"
    speed = np.array([r["metrics"]["motor.peak_speed"] for r in study.ran]) * 60 / (2 * math.pi)
    with _figure(title) as (figure, key):
        axes = figure.add_subplot()
        axes.plot(speed, [r["metrics"]["motor.peak_torque"] for r in study.ran], "^", color="#cf222e",
                  label="peak torque", markersize=4)
        axes.plot(speed, [r["metrics"]["motor.rms_torque"] for r in study.ran], "o", color="#0969da",
                  label="RMS torque", markersize=4)
        draw_motor_envelopes(axes, catalogue, "peak speed [rpm]")
        return figure_svg(figure, title, key)


_TEMPLATE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="{{ csp }}">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{{ name }} — bondc design study</title>
<style>
{% include "report.css" %}
</style>
</head>
<body>
<header class="report-header">
  <p class="kicker">Design study</p>
  <h1>{{ name }}</h1>
  <table class="meta"><tbody>
    <tr><th scope="row">Sweep table</th><td><code>{{ study.path }}</code></td></tr>
    <tr><th scope="row">Points</th><td>{{ study.rows | length }}{% for status, n in counts.items() if n %}; {{ n }} {{ status }}{% endfor %}</td></tr>
{% for name, unit, low, high in ranges %}
    <tr><th scope="row">{{ name }}</th><td>{{ low | num(6) }} .. {{ high | num(6) }}{% if unit %} {{ unit }}{% endif %}</td></tr>
{% endfor %}
{% if common is not none %}
    <tr><th scope="row">Motors that cover every point</th><td>{% if common %}{{ common | join(", ") }} (smallest: <strong>{{ common[0] }}</strong>){% else %}none{% endif %}</td></tr>
{% endif %}
  </tbody></table>
</header>
<main>
{% for title, svg in figures %}
<figure class="plot"><div class="figure-body">{{ svg }}</div><figcaption>{{ title }}</figcaption></figure>
{% endfor %}
<section id="table">
<h2>Points</h2>
<div class="table-wrap"><table class="data">
<thead><tr><th>index</th>{% for name, unit in study.parameters + study.metrics %}<th>{{ name }}{% if unit and unit != "1" %} [{{ unit }}]{% endif %}</th>{% endfor %}{% if has_motors %}<th>motors</th>{% endif %}<th>status</th><th>wall time [s]</th><th>message</th></tr></thead>
<tbody>
{% for row in study.rows %}
<tr class="{{ 'bad' if row.status not in ('ok',) else '' }}"><td>{{ row.index }}</td>{% for name, _ in study.parameters %}<td class="num">{{ row.params[name] | num(6) }}</td>{% endfor %}{% for name, _ in study.metrics %}<td class="num">{{ row.metrics[name] | num(5) }}</td>{% endfor %}{% if has_motors %}<td>{{ (row.motors or []) | join(", ") }}</td>{% endif %}<td>{{ row.status }}</td><td class="num">{{ row.wall_time | num(3) }}</td><td>{{ row.message }}</td></tr>
{% endfor %}
</tbody></table></div>
</section>
</main>
</body>
</html>
"""


def render_study(study: Study, catalogue=None) -> str:
    figures = []
    if study.parameters:
        for metric in study.metrics[:12]:
            figures.append((f"{metric[0]} against {study.parameters[0][0]}", metric_plot(study, metric)))
        if len(study.parameters) >= 2:
            for metric in study.metrics[:6]:
                svg = heat_map(study, metric)
                if svg is not None:
                    figures.append((f"{metric[0]} over {study.parameters[0][0]} and {study.parameters[1][0]}", svg))
    if catalogue:
        svg = motor_plot(study, catalogue)
        if svg is not None:
            figures.append(("Operating points against the motors' continuous (solid) and peak (dashed) envelopes",
                            svg))
    has_motors = any(row["motors"] is not None for row in study.rows)
    common = None
    if has_motors:
        lists = [row["motors"] for row in study.ran]
        shared = set(lists[0]).intersection(*map(set, lists[1:])) if lists else set()
        common = [name for name in (lists[0] if lists else []) if name in shared]
    counts = {}
    for row in study.rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    ranges = [(name, unit, min(r["params"][name] for r in study.rows), max(r["params"][name] for r in study.rows))
              for name, unit in study.parameters] if study.rows else []
    template = environment().from_string(_TEMPLATE)
    return template.render(name=Path(study.path).stem, study=study, figures=figures, counts=counts,
                           ranges=ranges, has_motors=has_motors, common=common,
                           csp=content_security_policy(None))      # no script: it fetches and runs nothing


def build_sweep_report(table, output=None, motors=None) -> Path:
    """Read ``table`` (a sweep's csv), write the HTML report (atomically); returns its path."""
    from bondc.analysis.motors import load_catalogue
    from bondc.io import atomic_write_text, check_output

    output = Path(output) if output is not None else Path("reports") / (Path(table).stem + ".html")
    check_output(output, "the report", make_folder=True)
    study = read_study(table)
    catalogue = load_catalogue(motors) if motors is not None else None
    html = render_study(study, catalogue)
    output.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(output, html)
    return output

