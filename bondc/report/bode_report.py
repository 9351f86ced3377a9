"""Bode plots and files: a :class:`~bondc.analysis.bode.Bode` as SVG, CSV or a self-contained HTML page.

:func:`bode_svg` draws one (input, output) pair on two stacked axes sharing a logarithmic
frequency axis, magnitude in dB above and phase in degrees below, with the margins' crossover
frequencies marked; it is made as the report's plots are (:func:`~bondc.report.render.figure_svg`:
matplotlib's object API, text as text, ``svg.hashsalt`` from the data and no date, so the same
response gives the same bytes). :func:`write_bode` writes ``bondc bode -o`` by the file's
extension, atomically: ``.csv`` (a header of names with units, ``frequency [Hz]``,
``x/F gain [m/N]``, ``x/F magnitude [dB]``, ``x/F phase [deg]``), ``.svg`` (the first pair's
plot; several pairs stacked in one file) or ``.html`` (a page with every pair's plot, its margins
and its verification, escaped by the report's Jinja environment and self-contained).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from markupsafe import Markup

from bondc.errors import Diagnostic, UsageError
from bondc import codes

#: Extensions ``bondc bode -o`` writes.
KINDS = (".csv", ".svg", ".html")
BODE_SIZE = (7.0, 4.4)


def check_bode_output(path) -> Path:
    """E947 before any work for an output that is no .csv, .svg or .html; then the usual checks."""
    from bondc.io import check_output

    path = Path(path)
    if path.suffix.lower() not in KINDS:
        raise UsageError(Diagnostic("error", codes.E947, f"bondc bode -o '{path}': cannot write a '{path.suffix or 'file without extension'}' file",
                                    hint="give a .csv (the table), .svg (the plot) or .html (a page with plots and margins)"))
    return check_output(path)


def _label(response) -> str:
    return f"{response.output}/{response.input}"


def bode_svg(responses, title: str, size=BODE_SIZE) -> Markup:
    """The Bode plot of ``responses`` (one or several pairs, one line each) as an inline SVG."""
    import matplotlib
    from matplotlib import ticker
    from matplotlib.figure import Figure

    from bondc.report.render import PLOT_STYLE, figure_svg

    digest = hashlib.sha256(repr((title, size)).encode())
    for r in responses:
        digest.update(_label(r).encode())
        digest.update(np.asarray(r.frequency_hz, dtype=float).tobytes())
        digest.update(np.asarray(r.response, dtype=complex).tobytes())
    key = digest.hexdigest()
    with matplotlib.rc_context({**PLOT_STYLE, "svg.hashsalt": key}):
        figure = Figure(figsize=size, layout="constrained")
        top, bottom = figure.subplots(2, 1, sharex=True)
        for number, r in enumerate(responses):
            colour = f"C{number % 10}"
            label = f"{_label(r)} [{r.unit}]"
            top.semilogx(r.frequency_hz, r.magnitude_db, color=colour, label=label)
            bottom.semilogx(r.frequency_hz, r.phase_deg, color=colour, label=label)
            m = r.margins
            if m.gain_crossover_hz is not None:
                top.axvline(m.gain_crossover_hz, color=colour, linestyle=":", linewidth=0.9)
                bottom.axvline(m.gain_crossover_hz, color=colour, linestyle=":", linewidth=0.9)
            if m.phase_crossover_hz is not None:
                top.axvline(m.phase_crossover_hz, color=colour, linestyle="--", linewidth=0.9)
                bottom.axvline(m.phase_crossover_hz, color=colour, linestyle="--", linewidth=0.9)
            if r.checks:
                done = [c for c in r.checks if c.simulated_db is not None]
                if done:
                    top.plot([c.frequency_hz for c in done], [c.simulated_db for c in done], "o", color=colour,
                             markersize=4, fillstyle="none", label=f"{_label(r)}: simulated model")
                    bottom.plot([c.frequency_hz for c in done], [c.simulated_deg for c in done], "o",
                                color=colour, markersize=4, fillstyle="none")
        if any(r.margins.phase_margin_deg is not None for r in responses):
            top.axhline(0.0, color="#8c959f", linewidth=0.8)
        if any(r.margins.gain_margin_db is not None for r in responses):
            bottom.axhline(-180.0, color="#8c959f", linewidth=0.8)
        # plain numbers on the log axis (the report's text is never mathtext: text.parse_math is off)
        bottom.xaxis.set_major_formatter(ticker.FuncFormatter(lambda value, _: f"{value:g}"))
        bottom.xaxis.set_minor_formatter(ticker.NullFormatter())
        top.set_ylabel("magnitude [dB]")
        bottom.set_ylabel("phase [deg]")
        bottom.set_xlabel("frequency [Hz]")
        if responses:
            f = responses[0].frequency_hz
            top.set_xlim(float(f[0]), float(f[-1]))
        if len(responses) > 1 or any(r.checks for r in responses):
            top.legend(loc="best", fontsize=8)
        return figure_svg(figure, title, key)


def csv_text(bode) -> str:
    """The responses as CSV (bondc's one writer of tables, :func:`bondc.runtime.result_bytes`):
    frequency, then per pair its gain (SI ratio), magnitude (dB) and phase (deg), units in the header."""
    from bondc.runtime import result_bytes

    names, units = ["frequency"], {"frequency": ("Hz", 1.0)}
    columns = [np.asarray(bode.responses[0].frequency_hz, dtype=float)]
    for r in bode.responses:
        for what, unit, values in (("gain", r.unit, np.abs(r.response)), ("magnitude", "dB", r.magnitude_db),
                                   ("phase", "deg", r.phase_deg)):
            name = f"{_label(r)} {what}"
            names.append(name)
            units[name] = (unit, 1.0)
            columns.append(values)
    return result_bytes("csv", names, columns, units).decode("utf-8")


#: The page after its head (render.PAGE_HEAD, the sweep's and the fit's too).
_PAGE_BODY = """<title>{{ name }} — bondc frequency response</title>
<style>
{% include "report.css" %}
</style>
</head>
<body>
<header class="report-header">
  <p class="kicker">Frequency response</p>
  <h1>{{ name }}</h1>
  <table class="meta"><tbody>
    <tr><th scope="row">Model file</th><td><code>{{ file }}</code></td></tr>
    <tr><th scope="row">Operating point</th><td>{{ at }}, t = {{ time | num(6) }} s</td></tr>
  </tbody></table>
</header>
<main>
{% include "bode_section.html" %}
</main>
</body>
</html>
"""


def section_rows(bode) -> list[dict]:
    """What the report's and the page's Bode section shows per pair: its plot, margins and checks."""
    rows = []
    for r in bode.responses:
        rows.append({"label": _label(r), "unit": r.unit, "svg": bode_svg([r], f"Bode plot of {_label(r)}"),
                     "margins": r.margins, "checks": r.checks, "amplitude": r.amplitude,
                     "input_unit": r.input_unit})
    return rows


def html_page(bode, name: str, file: str) -> str:
    from bondc.report.render import PAGE_HEAD, content_security_policy, environment

    template = environment().from_string(PAGE_HEAD + _PAGE_BODY)
    lin = bode.linearization
    return template.render(name=name, file=file, at=lin.at, time=lin.time, bode_rows=section_rows(bode),
                           bode_warnings=[d.message for d in bode.warnings], bode_notes=list(bode.notes),
                           csp=content_security_policy(None))


def write_bode(bode, path, name: str, file: str) -> Path:
    """``bondc bode -o``: the file ``path`` by its extension (:data:`KINDS`), written atomically."""
    from bondc.io import atomic_write_text

    path = Path(path)
    kind = path.suffix.lower()
    if kind == ".csv":
        text = csv_text(bode)
    elif kind == ".svg":
        lin = bode.linearization
        text = str(bode_svg(list(bode.responses), f"Bode plot of {name} at the {lin.at} point")) + "\n"
    else:
        text = html_page(bode, name, file)
    atomic_write_text(path, text)
    return path
