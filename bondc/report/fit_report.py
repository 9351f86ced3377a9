"""The HTML report of ``bondc fit -o report.html``: one self-contained page (no script, nothing
fetched; the reports' CSS inlined; every text escaped by the reports' Jinja environment) with the
estimates and their intervals, the correlation matrix, the residuals per signal, and per signal the
measured data against the model before and after the fit, and the residuals after it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bondc.report.render import PAGE_HEAD

_TEMPLATE = PAGE_HEAD + """<title>{{ fit.model }} — bondc fit</title>
<style>
{% include "report.css" %}
.table-wrap { overflow-x: auto; max-width: 100%; }
table.fit th, table.fit td { white-space: nowrap; padding: 0.14rem 0.5rem; }
</style>
</head>
<body>
<header class="report-header">
  <p class="kicker">Calibration</p>
  <h1>{{ fit.model }}</h1>
  <table class="meta"><tbody>
    <tr><th scope="row">Model file</th><td><code>{{ fit.file }}</code></td></tr>
{% for dataset in fit.datasets %}
    <tr><th scope="row">Measured data</th><td><code>{{ dataset.data }}</code>{% if dataset.experiment %} (experiment {{ dataset.experiment }}){% endif %}: {% for c in dataset.compare %}{{ c.output }} = {{ c.column }}{% if c.weight != 1 %} (weight {{ c.weight | num(4) }}){% endif %}{% if not loop.last %}, {% endif %}{% endfor %}</td></tr>
{% endfor %}
    <tr><th scope="row">Result</th><td>{% if fit.converged %}converged{% else %}<strong>not converged</strong>{% endif %}: {{ fit.message }}</td></tr>
    <tr><th scope="row">Cost</th><td>{{ fit.cost_initial | num(6) }} before, {{ fit.cost | num(6) }} after ({{ fit.residuals }} residuals, {{ fit.evaluations }} evaluations, {{ fit.runs }} runs)</td></tr>
  </tbody></table>
</header>
<main>
{% if fit.diagnostics %}
<section id="diagnostics">
<h2>Warnings</h2>
<ul>
{% for d in fit.diagnostics %}
<li><code>{{ d.code }}</code> {{ d.message }}{% if d.hint %} — {{ d.hint }}{% endif %}</li>
{% endfor %}
</ul>
</section>
{% endif %}
<section id="estimates">
<h2>Estimates</h2>
<div class="table-wrap"><table class="data fit" id="estimates-table">
<thead><tr><th>parameter</th><th>unit</th><th>initial</th><th>estimate</th><th>std. error</th><th>95 % low</th><th>95 % high</th><th>bounds</th></tr></thead>
<tbody>
{% for p in fit.parameters %}
<tr><td>{{ p.name }}</td><td>{{ p.unit or "1" }}</td><td class="num">{{ p.initial | num(6) }}</td><td class="num">{{ p.value | num(6) }}</td><td class="num">{{ p.stderr | num(3) }}</td><td class="num">{{ p.ci95[0] | num(6) }}</td><td class="num">{{ p.ci95[1] | num(6) }}</td><td>{{ "" if p.low is none else p.low | num(6) }} .. {{ "" if p.high is none else p.high | num(6) }}</td></tr>
{% endfor %}
</tbody></table></div>
</section>
<section id="correlation">
<h2>Correlation of the estimates</h2>
<div class="table-wrap"><table class="data fit" id="correlation-table">
<thead><tr><th></th>{% for p in fit.parameters %}<th>{{ p.name }}</th>{% endfor %}</tr></thead>
<tbody>
{% for row in correlation %}
<tr><th scope="row">{{ fit.parameters[loop.index0].name }}</th>{% for value in row %}<td class="num">{{ "%+.3f" | format(value) }}</td>{% endfor %}</tr>
{% endfor %}
</tbody></table></div>
</section>
<section id="signals">
<h2>Residuals per signal</h2>
<div class="table-wrap"><table class="data fit" id="signals-table">
<thead><tr><th>signal</th><th>measured</th><th>data</th><th>unit</th><th>RMSE before</th><th>RMSE after</th><th>NRMSE before</th><th>NRMSE after</th></tr></thead>
<tbody>
{% for s in fit.signals %}
<tr><td>{{ s.output }}</td><td>{{ s.column }}</td><td><code>{{ s.data }}</code></td><td>{{ s.unit or "SI" }}</td><td class="num">{{ s.rmse_before | num(4) }}</td><td class="num">{{ s.rmse | num(4) }}</td><td class="num">{{ s.nrmse_before | num(4) }}</td><td class="num">{{ s.nrmse | num(4) }}</td></tr>
{% endfor %}
</tbody></table></div>
</section>
<section id="plots">
<h2>Measured and model, before and after</h2>
{% for title, svg in figures %}
<figure class="plot"><div class="figure-body">{{ svg }}</div><figcaption>{{ title }}</figcaption></figure>
{% endfor %}
</section>
</main>
</body>
</html>
"""


def render_fit(fit) -> str:
    """The report of a :class:`bondc.analysis.fit.FitResult` as one HTML document."""
    from bondc.report.plots import plot_unit, time_plot
    from bondc.report.render import content_security_policy, environment

    figures = []
    for signal in fit.signals:
        label = signal.output + (f" [{plot_unit(signal.unit)}]" if signal.unit else " (SI)")
        title = f"{signal.output} against {signal.column} ({Path(signal.data).name})"
        series = {f"{signal.column} (measured)": signal.measured, "model before the fit": signal.before,
                  "model after the fit": signal.after}
        styles = {f"{signal.column} (measured)": {"color": "#8c959f", "linewidth": 1.0},
                  "model before the fit": {"color": "#bc4c00", "linewidth": 1.0, "linestyle": "--"},
                  "model after the fit": {"color": "#0550ae", "linewidth": 1.4}}
        figures.append((title, time_plot(signal.t, series, title, label, half=True, styles=styles)))
        title = f"{signal.output} residual after the fit, model − measured"
        figures.append((title, time_plot(signal.t, {"residual": signal.after - signal.measured}, title,
                                          "residual" + (f" [{plot_unit(signal.unit)}]" if signal.unit else " (SI)"),
                                          half=True, styles={"residual": {"color": "#a40e26", "linewidth": 1.0}})))
    correlation = [[float(v) for v in row] for row in np.asarray(fit.correlation)]
    template = environment().from_string(_TEMPLATE)
    return template.render(fit=fit, figures=figures, correlation=correlation, csp=content_security_policy(None))


def write_fit_report(fit, target) -> None:
    """:func:`render_fit`, written atomically to ``target`` (its folder made)."""
    from bondc.io import atomic_write_text

    html = render_fit(fit)
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(target, html)
