"""``bondc report --sweep study.csv``: the HTML report of a design study.

Reads the table ``bondc sweep -o study.csv`` wrote (units in the header, SI
values) and the record of its study beside it (``study.csv.study``: the model's
name and file, the experiment, and the unit each column is shown in -- a
metric's is its output's declared unit, ``P_kPa.min`` in kPa). It renders one
self-contained page titled by the model: the study's size and how its points
ended; a compact table (the varied parameters, the status, the chosen motor and
the key motor and per-cycle metrics), every column under a ``<details>``; each
metric that varies over the study (motor and per-cycle ones first) against the
first varied parameter, each point coloured by the second, the points that did
not run marked on the axis; over two varied parameters on a grid, a heat map of
each with those points crossed out; with motor metrics and a catalogue, every
point's operating point (peak speed, peak and RMS torque, coloured by the first
varied parameter) against each motor's continuous and peak envelope, whole and
zoomed onto the points, and the motors that cover the whole study. Without the
record (an older table) the page is titled by the file's name and shows SI
units. Every text from the files is escaped.

Which columns are the varied parameters: those between ``index`` and the first
metric, a metric being ``OUTPUT.min/.max/.mean/.rms/.final``, ``energy.*`` or
``motor.*``.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from markupsafe import Markup

from bondc.errors import DataError, Diagnostic
from bondc.report.render import (PAGE_HEAD, PLOT_STYLE, content_security_policy, draw_motor_envelopes, environment,
                                  figure_svg)
from bondc import codes

STATISTICS = ("min", "max", "mean", "rms", "final", "cycle_peak", "cycle_rms", "cycle_energy",
              "cycle_energy_positive", "cycle_energy_negative")
ENDINGS = ("status", "message", "wall_time", "motors")


@dataclass
class Study:
    path: str
    parameters: list[tuple[str, str | None]]      # (name, unit shown: as varied, else SI)
    metrics: list[tuple[str, str | None]]         # (name, unit shown: the output's declared unit, else SI)
    rows: list[dict] = field(default_factory=list)  # index, params {}, metrics {}, motors, status, message, wall_time
    model: str | None = None                      # from the study's record (``x.csv.study``)
    model_file: str | None = None
    experiment: str | None = None

    @property
    def ran(self) -> list[dict]:
        return [row for row in self.rows if row["status"] in ("ok", "incomplete")]

    @property
    def name(self) -> str:
        """The model's name; the table's file name for a table without its record."""
        return self.model or Path(self.path).stem

    @property
    def has_motors(self) -> bool:
        return any(row["motors"] is not None for row in self.rows)

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for row in self.rows:
            counts[row["status"]] = counts.get(row["status"], 0) + 1
        return counts

    def motors_for_all(self) -> list[str] | None:
        """With a motors column: the motors that qualify at every point that ran, smallest first."""
        if not self.has_motors:
            return None
        lists = [row["motors"] or [] for row in self.ran]
        shared = set(lists[0]).intersection(*map(set, lists[1:])) if lists else set()
        return [name for name in (lists[0] if lists else []) if name in shared]

    def varies(self, metric: str) -> bool:
        """The metric takes more than one value over the points that ran (``power.final`` = 0 at
        every point does not: it has no plot and no column of the compact table)."""
        values = np.array([row["metrics"][metric] for row in self.ran], dtype=float)
        values = values[np.isfinite(values)]
        if values.size < 2:
            return False
        return float(np.ptp(values)) > 1e-12 * float(np.max(np.abs(values)))


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
        raise DataError(Diagnostic("error", codes.E972, f"cannot read the sweep table '{path}': {error}")) from None
    header = [_split(cell) for cell in rows[0]] if rows else []
    names = [name for name, _ in header]
    if not names or names[0] != "index" or "status" not in names:
        raise DataError(Diagnostic("error", codes.E972, f"'{path}' is not a table written by bondc sweep",
                                   hint="give the .csv that 'bondc sweep -o FILE.csv' wrote"))
    end = min(names.index(n) for n in ENDINGS if n in names)
    middle = header[1:end]
    first_metric = next((i for i, (name, _) in enumerate(middle) if _is_metric(name)), len(middle))
    study = Study(str(path), middle[:first_metric], middle[first_metric:])
    column = {name: number for number, name in enumerate(names)}
    for line, cells in enumerate(rows[1:], 2):
        if len(cells) != len(names):
            continue                    # a row an interruption cut short
        try:
            row = {"index": int(cells[0]), "status": cells[column["status"]],
                   "message": cells[column["message"]] if "message" in column else "",
                   "wall_time": _number(cells[column["wall_time"]]) if "wall_time" in column else math.nan,
                   "motors": ([m for m in cells[column["motors"]].split(";") if m] if "motors" in column else None),
                   "params": {name: _number(cells[1 + i]) for i, (name, _) in enumerate(study.parameters)},
                   "metrics": {name: _number(cells[1 + first_metric + i])
                               for i, (name, _) in enumerate(study.metrics)}}
        except ValueError:
            raise DataError(Diagnostic("error", codes.E972, f"'{path}' row {line} is not a row bondc sweep writes",
                                       hint="give the .csv that 'bondc sweep -o FILE.csv' wrote")) from None
        study.rows.append(row)
    _apply_record(study, _record(path))
    return study


def _record(path: Path) -> dict:
    """The "report" part of the study's record beside the table (``x.csv.study``, written by
    ``bondc sweep``); {} when there is none or it is not one."""
    from bondc.analysis.sweep import study_file

    try:
        record = json.loads(study_file(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    described = record.get("report") if isinstance(record, dict) else None
    return described if isinstance(described, dict) else {}


def _shown_units(items) -> dict[str, tuple[str | None, float, float]]:
    """{name: (unit, factor, offset)} of the record's well-formed entries (shown = (SI - offset) / factor)."""
    found = {}
    for item in items if isinstance(items, list) else ():
        if not isinstance(item, dict) or not isinstance(item.get("name"), str):
            continue
        unit, factor, offset = item.get("unit"), item.get("factor", 1.0), item.get("offset", 0.0)
        if unit is not None and not isinstance(unit, str):
            continue
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                   for v in (factor, offset)) or factor == 0:
            continue
        found[item["name"]] = (unit, float(factor), float(offset))
    return found


def _apply_record(study: Study, record: dict) -> None:
    """The model's name, file and experiment, and every column in the unit it is shown in: a metric
    in its output's declared unit (``P_kPa.min`` in kPa, not the SI dimensions of the csv header), a
    varied parameter in the unit it was varied in."""
    for key, attribute in (("model name", "model"), ("model file", "model_file"), ("experiment", "experiment")):
        if isinstance(record.get(key), str) and record[key]:
            setattr(study, attribute, record[key])
    for columns, units, field_name in ((study.parameters, _shown_units(record.get("parameters")), "params"),
                                       (study.metrics, _shown_units(record.get("metrics")), "metrics")):
        for number, (name, si_unit) in enumerate(columns):
            if name not in units:
                continue
            unit, factor, offset = units[name]
            columns[number] = (name, unit if unit is not None else si_unit)
            for row in study.rows:
                row[field_name][name] = (row[field_name][name] - offset) / factor


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


def _rank(name: str) -> int:
    """Which metrics the design answer shows first: the motor's requirements, then the energy per
    cycle, the other per-cycle figures, the outputs' statistics, and last the energy balance's residual."""
    statistic = name.rpartition(".")[2]
    if name.startswith("motor."):
        return 0
    if statistic == "cycle_energy":
        return 1
    if statistic.startswith("cycle_"):
        return 2
    if name.startswith("energy."):
        return 4
    return 3


def design_metrics(study: Study) -> list[tuple[str, str | None]]:
    """The metrics that vary over the study, motor and per-cycle ones first."""
    return sorted((m for m in study.metrics if study.varies(m[0])), key=lambda m: _rank(m[0]))


def key_metrics(study: Study, limit: int = 6) -> list[tuple[str, str | None]]:
    """The compact table's metrics: the varying motor and per-cycle ones; without any, the first
    four varying outputs' statistics."""
    varying = design_metrics(study)
    chosen = [m for m in varying if _rank(m[0]) <= 2]
    return chosen[:limit] if chosen else [m for m in varying if _rank(m[0]) == 3][:4]


def metric_plot(study: Study, metric: tuple[str, str | None]) -> Markup:
    """A metric against the first varied parameter; over more than one, each point coloured by the
    second (its colour bar); points that did not run marked on the axis."""
    (x_name, x_unit), (name, unit) = study.parameters[0], metric
    title = f"{name} against {x_name}"
    ran = [r for r in study.ran if math.isfinite(r["metrics"][name])]
    bad = [r["params"][x_name] for r in study.rows if r not in study.ran]
    with _figure(title) as (figure, key):
        axes = figure.add_subplot()
        ys = [r["metrics"][name] for r in ran]
        if ran and len(study.parameters) == 1:
            xs, ys = zip(*sorted((r["params"][x_name], r["metrics"][name]) for r in ran))
            axes.plot(xs, ys, marker="o", markersize=3.5, linestyle="-", label="ran")
        elif ran:
            c_name, c_unit = study.parameters[1]
            dots = axes.scatter([r["params"][x_name] for r in ran], ys, c=[r["params"][c_name] for r in ran],
                                cmap="viridis", s=22, edgecolors="#1f2328", linewidths=0.3, label="ran")
            bar = figure.colorbar(dots, ax=axes, label=_label(c_name, c_unit))
            bar.solids.set_rasterized(False)        # vector shapes: no embedded image in the page
        if bad:
            axes.plot(bad, [min(ys) if ys else 0.0] * len(bad), marker="x", color="#cf222e", linestyle="none",
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
    """Every point's peak speed against its peak torque (triangles) and RMS torque (dots), coloured
    by the first varied parameter: on the left over each motor's envelopes, continuous (solid) and
    peak (dashed); on the right the same, zoomed onto the operating points so they stay apart."""
    needed = ("motor.peak_speed", "motor.peak_torque", "motor.rms_torque")
    names = [name for name, _ in study.metrics]
    if not all(n in names for n in needed):
        return None
    ran = [r for r in study.ran if all(math.isfinite(r["metrics"][n]) for n in needed)]
    title = "operating points of the study against the motors' envelopes"
    speed = np.array([r["metrics"]["motor.peak_speed"] for r in ran]) * 60 / (2 * math.pi)
    peak = np.array([r["metrics"]["motor.peak_torque"] for r in ran])
    rms = np.array([r["metrics"]["motor.rms_torque"] for r in ran])
    colour_name, colour_unit = study.parameters[0] if study.parameters else ("index", None)
    colour = [r["params"][colour_name] if study.parameters else r["index"] for r in ran]
    with _figure(title) as (figure, key):
        figure.set_size_inches(9.6, 3.8)
        whole, zoom = figure.subplots(1, 2)
        dots = None
        for axes in (whole, zoom):
            axes.scatter(speed, peak, c=colour, cmap="viridis", marker="^", s=26, edgecolors="#cf222e",
                         linewidths=0.6, label="peak torque")
            dots = axes.scatter(speed, rms, c=colour, cmap="viridis", marker="o", s=20, edgecolors="#0969da",
                                linewidths=0.6, label="RMS torque")
        draw_motor_envelopes(whole, catalogue, "peak speed [rpm]")
        for number, motor in enumerate(catalogue):
            colour_of = f"C{number % 10}"
            zoom.plot([0, motor.rated_speed, motor.rated_speed], [motor.rated_torque] * 2 + [0], color=colour_of,
                      linewidth=1.0)
            zoom.plot([0, motor.rated_speed], [motor.peak_torque] * 2, color=colour_of, linewidth=1.0,
                      linestyle="--")
        whole.get_legend().remove()
        figure.legend(*whole.get_legend_handles_labels(), loc="outside lower center", ncol=4, fontsize=7)
        if len(ran):
            for values, set_limits in ((speed, zoom.set_xlim), (np.concatenate([peak, rms]), zoom.set_ylim)):
                low, high = float(values.min()), float(values.max())
                margin = 0.15 * (high - low) or 0.1 * abs(high) or 1.0
                set_limits(low - margin, high + margin)
        zoom.set_xlabel("peak speed [rpm]")
        zoom.set_title("zoomed onto the points", fontsize=8)
        if dots is not None:
            bar = figure.colorbar(dots, ax=zoom, label=_label(colour_name, colour_unit))
            bar.solids.set_rasterized(False)        # vector shapes: no embedded image in the page
        return figure_svg(figure, title, key)


_TEMPLATE = PAGE_HEAD + """<title>{{ study.name }} — bondc design study</title>
<style>
{% include "report.css" %}
.table-wrap { overflow-x: auto; max-width: 100%; }
table.study th, table.study td { white-space: nowrap; padding: 0.14rem 0.5rem; vertical-align: top; }
table.study td.message { white-space: normal; min-width: 16rem; max-width: 32rem; }
details.all-columns { margin-top: 1rem; }
details.all-columns > summary { cursor: pointer; font-weight: 600; }
</style>
</head>
<body>
<header class="report-header">
  <p class="kicker">Design study</p>
  <h1>{{ study.name }}</h1>
  <table class="meta"><tbody>
{% if study.model_file %}
    <tr><th scope="row">Model file</th><td><code>{{ study.model_file }}</code></td></tr>
{% endif %}
{% if study.experiment %}
    <tr><th scope="row">Experiment</th><td>{{ study.experiment }}</td></tr>
{% endif %}
    <tr><th scope="row">Sweep table</th><td><code>{{ study.path }}</code></td></tr>
    <tr><th scope="row">Points</th><td>{{ study.rows | length }}{% for status, n in counts.items() if n %}; {{ n }} {{ status }}{% endfor %}</td></tr>
{% for name, unit, low, high in ranges %}
    <tr><th scope="row">{{ name }}</th><td>{{ low | num(6) }} .. {{ high | num(6) }}{% if unit and unit != "1" %} {{ unit }}{% endif %}</td></tr>
{% endfor %}
{% if common is not none %}
    <tr><th scope="row">Motors that cover every point</th><td>{% if common %}{{ common | join(", ") }} (smallest: <strong>{{ common[0] }}</strong>){% else %}none{% endif %}</td></tr>
{% endif %}
  </tbody></table>
</header>
<main>
<section id="table">
<h2>Points</h2>
<div class="table-wrap"><table class="data study compact">
<thead><tr><th>index</th>{% for name, unit in study.parameters %}<th>{{ name | label(unit) }}</th>{% endfor %}<th>status</th>{% if has_motors %}<th>motor</th>{% endif %}{% for name, unit in key %}<th>{{ name | label(unit) }}</th>{% endfor %}</tr></thead>
<tbody>
{% for row in study.rows %}
<tr class="{{ 'bad' if row.status != 'ok' else '' }}"><td>{{ row.index }}</td>{% for name, _ in study.parameters %}<td class="num">{{ row.params[name] | num(6) }}</td>{% endfor %}<td>{{ row.status }}</td>{% if has_motors %}<td>{{ (row.motors or ["none"])[0] if row.status in ("ok", "incomplete") else "" }}</td>{% endif %}{% for name, _ in key %}<td class="num">{{ row.metrics[name] | num(5) }}</td>{% endfor %}</tr>
{% endfor %}
</tbody></table></div>
<details class="all-columns">
<summary>All {{ all_columns }} columns{% if constant %} (constant over the study: {{ constant | join(", ") }}){% endif %}</summary>
<div class="table-wrap"><table class="data study all">
<thead><tr><th>index</th>{% for name, unit in study.parameters + study.metrics %}<th>{{ name | label(unit) }}</th>{% endfor %}{% if has_motors %}<th>motors</th>{% endif %}<th>status</th><th>wall time [s]</th><th>message</th></tr></thead>
<tbody>
{% for row in study.rows %}
<tr class="{{ 'bad' if row.status != 'ok' else '' }}"><td>{{ row.index }}</td>{% for name, _ in study.parameters %}<td class="num">{{ row.params[name] | num(6) }}</td>{% endfor %}{% for name, _ in study.metrics %}<td class="num">{{ row.metrics[name] | num(5) }}</td>{% endfor %}{% if has_motors %}<td>{{ (row.motors or []) | join(", ") }}</td>{% endif %}<td>{{ row.status }}</td><td class="num">{{ row.wall_time | num(3) }}</td><td class="message">{{ row.message }}</td></tr>
{% endfor %}
</tbody></table></div>
</details>
</section>
{% for title, svg in figures %}
<figure class="plot"><div class="figure-body">{{ svg }}</div><figcaption>{{ title }}</figcaption></figure>
{% endfor %}
</main>
</body>
</html>
"""


def render_study(study: Study, catalogue=None) -> str:
    figures = []
    plotted = design_metrics(study)
    if study.parameters:
        for metric in plotted[:12]:
            figures.append((f"{metric[0]} against {study.parameters[0][0]}", metric_plot(study, metric)))
        if len(study.parameters) >= 2:
            for metric in plotted[:6]:
                svg = heat_map(study, metric)
                if svg is not None:
                    figures.append((f"{metric[0]} over {study.parameters[0][0]} and {study.parameters[1][0]}", svg))
    if catalogue:
        svg = motor_plot(study, catalogue)
        if svg is not None:
            figures.append(("Operating points (peak torque ▲, RMS torque ●, coloured by "
                            f"{study.parameters[0][0] if study.parameters else 'index'}) against the motors' "
                            "continuous (solid) and peak (dashed) envelopes", svg))
    ranges = [(name, unit, min(r["params"][name] for r in study.rows), max(r["params"][name] for r in study.rows))
              for name, unit in study.parameters] if study.rows else []
    has_motors = study.has_motors
    env = environment()
    env.filters["label"] = _label
    template = env.from_string(_TEMPLATE)
    return template.render(study=study, figures=figures, counts=study.counts(), ranges=ranges,
                           has_motors=has_motors, common=study.motors_for_all(), key=key_metrics(study),
                           constant=[name for name, _ in study.metrics if not study.varies(name)],
                           all_columns=1 + len(study.parameters) + len(study.metrics) + 3 + (1 if has_motors else 0),
                           csp=content_security_policy(None))      # no script: it fetches and runs nothing


def summary(study: Study) -> list[str]:
    """What ``bondc report --sweep`` prints: the points and how they ended, and the motors that
    cover every point."""
    counts = study.counts()
    ended = ", ".join(f"{n} {status}" for status, n in counts.items() if n)
    lines = [f"{study.name}: {len(study.rows)} point{'s' if len(study.rows) != 1 else ''}"
             + (f" ({ended})" if ended else "")]
    common = study.motors_for_all()
    if common is not None:
        lines.append("motors that cover every point: " + (f"{', '.join(common)} (smallest: {common[0]})"
                                                          if common else "none"))
    return lines


def build_sweep_report(table, output=None, motors=None) -> Path:
    """Read ``table`` (a sweep's csv), write the HTML report (atomically); returns its path."""
    return sweep_report(table, output, motors)[0]


def sweep_report(table, output=None, motors=None) -> tuple[Path, Study]:
    """:func:`build_sweep_report`, also returning the study read (for :func:`summary`)."""
    from bondc.analysis.motors import load_catalogue
    from bondc.io import atomic_write_text, check_output

    output = Path(output) if output is not None else Path("reports") / (Path(table).stem + ".html")
    check_output(output, "the report", make_folder=True)
    study = read_study(table)
    catalogue = load_catalogue(motors) if motors is not None else None
    html = render_study(study, catalogue)
    output.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(output, html)
    return output, study

