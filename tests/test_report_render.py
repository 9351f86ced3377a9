"""The HTML report: structure, sections, escaping, self-containment, and its building blocks."""

from __future__ import annotations

import html as html_module
import json
import re
import xml.etree.ElementTree as ET
from html.parser import HTMLParser

import numpy as np
import pytest
import sympy
from jinja2 import UndefinedError
from markupsafe import Markup

from bondc.causality import assign_causality
from bondc.parse import parse_text
from bondc.report.diagram import bond_graph_svg
from bondc.report.lexer import highlight_bg
from bondc.report.render import (
    ANSWER_SIZE, Answer, CandidateRow, HLine, RuleMargin,
    Equation, ParameterRow, Plot, ReportContext, ReportHeader, Table, ValidationSection, causality_notes,
    causality_rows, environment, equation_markup, format_number, format_unit, math_markup, parameter_rows,
    content_security_policy, plot_svg, render_report, source_sha256, zoom_script,
)
from bondc.analysis.validate import compare, parse_compare_spec
from bondc.semantic import build

SOURCE = """\
model MassSpringDamper "Force step <script>alert(1)</script> & more"
  param m = 2.0 [kg] "moving <b>mass</b>"
  param k = 800 [N/m]
  param b = 12  [N*s/m]
  param lead = 5.0 [mm]
  input F [N] = step(t, 0.1) * 10
  MSe force  : e = F
  I   mass   : f = p/m
  C   spring : e = k*q
  R   damper : e = b*f
  1   j
  force -> j
  j -> mass
  j -> spring
  j -> damper
  output x [m] = spring.q
  experiment step "step <i>response</i>"
    t_end = 2 [s]
    rtol = 1e-6
  end
end
"""

VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}


class NestingChecker(HTMLParser):
    """Every opened tag is closed, in order (void elements and ``<x/>`` excepted)."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.ids: list[str] = []
        self.tags: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self.ids += [value for name, value in attrs if name == "id"]
        if tag not in VOID:
            self.stack.append(tag)

    def handle_startendtag(self, tag, attrs):
        self.tags.append(tag)
        self.ids += [value for name, value in attrs if name == "id"]

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes <{self.stack[-1] if self.stack else None}> at {self.getpos()}")
            return
        self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)


def check_html(html: str) -> NestingChecker:
    checker = NestingChecker()
    checker.feed(html)
    checker.close()
    assert checker.errors == []
    assert checker.stack == []
    return checker


@pytest.fixture(scope="module")
def model():
    graph, _ = build(parse_text(SOURCE, "msd.bg"))
    return graph, assign_causality(graph)


def full_context(graph, causal, **changes) -> ReportContext:
    t = np.linspace(0.0, 2.0, 201)
    x = 0.0125 * (1 - np.exp(-3 * t) * np.cos(20 * t))
    results = compare(t, {"x": x}, {"t": t, "x_meas": x * 1.001, "x_bad": x * 1.3},
                      [parse_compare_spec("x=x_meas"), parse_compare_spec("x=x_bad")])
    p, q = sympy.symbols("mass.p spring.q", real=True)
    m, k, b, force = sympy.symbols("m k b F", positive=True)
    fields = dict(
        header=ReportHeader.for_graph(graph, SOURCE, "step", date="2024-05-01"),
        source_html=highlight_bg(SOURCE),
        parameters=parameter_rows(graph),
        diagram_svg=bond_graph_svg(graph, causal),
        causality=causality_rows(causal),
        causality_notes=causality_notes(causal) + ["a note with <tags> & ampersands"],
        equations=[Equation(equation_markup(sympy.Symbol("dp/dt"), force - k * q - b * p / m), "mass.p"),
                   Equation(equation_markup(sympy.Symbol("dq/dt"), sympy.Piecewise((p / m, p > 0), (0, True))),
                            "spring.q")],
        plots=[Plot("Displacement", plot_svg(t, {"x": x}, "Displacement", "x [m]"), "spring deflection"),
               ("Force", plot_svg(t, {"F": 10.0 * (t > 0.1)}, "Force", "F [N]"))],
        power_tables=[Table.from_dicts("Energy per cycle", [
            {"element": "damper", "energy [J]": 0.1234567, "mean power [W]": -1.5e-7},
            {"element": "force <src>", "energy [J]": 12, "mean power [W]": None}])],
        motor_requirements=Table("Motor requirements", ("quantity", "value"), [("peak torque [N m]", 1.23)]),
        motor_candidates=Table.from_dicts("Candidates", [{"motor": "MX-<1>", "margin": 0.4}]),
        validation=ValidationSection(results, "data/x.csv",
                                     plots=[Plot("x against measured", plot_svg(t, {"sim": x, "meas": 1.3 * x},
                                                                                "x against measured", "x [m]"))],
                                     junit_file="reports/junit.xml"),
        warnings=["W602: capacitor <c> in derivative causality"],
    )
    fields.update(changes)
    return ReportContext(**fields)


@pytest.fixture(scope="module")
def html(model) -> str:
    return render_report(full_context(*model))


SECTIONS = ["bond-graph", "parameters", "causality", "equations", "results", "power", "motor-requirements",
            "motor-candidates", "validation", "source"]


def test_structure_is_well_nested(html):
    assert html.startswith("<!DOCTYPE html>\n<html lang=\"en\">")
    checker = check_html(html)
    for tag in ("head", "body", "main", "style", "svg", "math", "table", "figure", "figcaption"):
        assert tag in checker.tags
    assert len(checker.ids) == len(set(checker.ids)), "duplicate ids"


def test_every_section_present_in_order_with_contents(html):
    ids = re.findall(r'<section id="([^"]+)"', html)
    assert ids == SECTIONS
    toc = re.findall(r'<li><a href="#([^"]+)">', html)
    assert toc == SECTIONS
    for number, section in enumerate(SECTIONS, start=1):
        assert re.search(rf'<section id="{section}"[^>]*>\s*<h2><span class="secno">{number}</span>', html)


def test_optional_sections_are_hidden_when_absent(model):
    graph, causal = model
    html = render_report(ReportContext(ReportHeader.for_graph(graph, SOURCE, date="2024-05-01"),
                                       highlight_bg(SOURCE)))
    check_html(html)
    assert re.findall(r'<section id="([^"]+)"', html) == ["source"]
    html = render_report(full_context(graph, causal, motor_requirements=None, motor_candidates=None,
                                      validation=None, plots=(), warnings=()))
    ids = re.findall(r'<section id="([^"]+)"', html)
    assert "validation" not in ids and "motor-candidates" not in ids and "results" not in ids
    assert "Check before use" not in html


def test_text_is_escaped(html):
    assert "Force step &lt;script&gt;alert(1)&lt;/script&gt; &amp; more" in html
    assert "moving &lt;b&gt;mass&lt;/b&gt;" in html
    assert "a note with &lt;tags&gt; &amp; ampersands" in html
    assert "force &lt;src&gt;" in html and "MX-&lt;1&gt;" in html
    assert "W602: capacitor &lt;c&gt;" in html
    assert "step &lt;i&gt;response&lt;/i&gt;" in html
    assert "<b>mass</b>" not in html and "<i>response" not in html


def without_zoom_script(html: str) -> str:
    """``html`` without bondc's own script (``zoom.js`` exactly as packaged, at most once), which its
    Content-Security-Policy names by hash; anything else that would script the page is still there."""
    script = f"<script>{zoom_script()}</script>"
    assert html.count("<script") == html.count(script) <= 1
    policy = content_security_policy(str(zoom_script()) if script in html else None)
    assert html.count('<meta http-equiv="Content-Security-Policy"') == 1
    assert f'<meta http-equiv="Content-Security-Policy" content="{policy.replace(chr(39), "&#39;")}">' in html
    return re.sub(r'data-zoom="([^"]*)"', _zoom_data_checked, html.replace(script, ""))


def _zoom_data_checked(match: re.Match) -> str:
    """A plot's data-zoom is numbers and base64 only (no text of the model); emptied, so that its
    base64 (which may hold e.g. "src=") is not taken for markup."""
    data = json.loads(html_module.unescape(match.group(1)))
    assert set(data) == {"box", "x", "lines"}
    assert all(isinstance(v, (int, float)) for v in data["box"] + data["x"])
    assert all(re.fullmatch(r"[A-Za-z0-9+/]*={0,2}", line) for line in data["lines"])
    return 'data-zoom=""'



def test_report_is_self_contained(html):
    """No script but bondc's own and nothing fetched: the only URIs allowed are namespace names in xmlns attributes."""
    html = without_zoom_script(html)
    without_namespaces = re.sub(r'\sxmlns(:[\w-]+)?="[^"]*"', "", html)
    lowered = without_namespaces.lower()
    for forbidden in ("http://", "https://", "src=", "<script", "<link", "@import", "<iframe", "<object",
                      "<embed", "<img", "javascript:"):
        assert forbidden not in lowered, forbidden
    assert re.findall(r"\bon[a-z]+\s*=", lowered) == []                   # no event handlers
    assert all(ref.startswith("#") for ref in re.findall(r'href="([^"]*)"', without_namespaces))
    assert all(ref.startswith("#") for ref in re.findall(r"url\(([^)]*)\)", without_namespaces))


def test_tables_have_numbers_formatted_and_captions(html):
    assert "Table 1.</span> Parameters" in html
    assert "<td><code>lead</code></td><td class=\"num\">5</td><td>mm</td>" in html   # shown as written: 5 mm
    assert "N·s/m" in html
    assert "−1.5×10<sup>−7</sup>" in html
    assert "<td class=\"num\">0.1235</td>" in html


def test_causality_table_and_figures(html):
    assert "<code>force</code> → <code>j</code>" in html
    assert "I mass: integral" in html and "R damper: resistance" in html
    captions = re.findall(r'<span class="label">Figure (\d+)\.</span>', html)
    assert captions == ["1", "2", "3", "4"]
    assert 'class="causal-stroke"' in html


def test_validation_section(html):
    section = html[html.index('<section id="validation">'):html.index('<section id="source"')]
    assert section.count('<span class="badge pass">PASS</span>') == 1
    assert section.count('<span class="badge fail">FAIL</span>') == 1
    assert "data/x.csv" in section and "reports/junit.xml" in section


def test_equations_are_mathml(html):
    section = html[html.index('<section id="equations">'):html.index('<section id="results"')]
    maths = re.findall(r"<math .*?</math>", section, flags=re.S)
    assert len(maths) == 2
    for math in maths:
        ET.fromstring(math)
    assert "<mtable" in maths[1] and "otherwise" in maths[1]


def test_rendering_is_deterministic(model):
    assert render_report(full_context(*model)) == render_report(full_context(*model))


# ---------------------------------------------------------------- environment and context

def test_environment_escapes_everything_and_is_strict():
    env = environment()
    assert env is environment()
    assert env.from_string("{{ x }}").render(x="<b>") == "&lt;b&gt;"
    assert env.get_template("report.css").environment is env
    assert {"report.html", "report.css", "macros.html"} <= set(env.list_templates())
    with pytest.raises(UndefinedError):
        env.from_string("{{ missing }}").render()
    with pytest.raises(UndefinedError):
        env.get_template("report.html").render()


def test_context_refuses_untrusted_html(model):
    graph, _ = model
    header = ReportHeader.for_graph(graph, SOURCE, date="2024-05-01")
    with pytest.raises(TypeError, match="source_html"):
        ReportContext(header, "<pre>model</pre>")
    with pytest.raises(TypeError, match="diagram_svg"):
        ReportContext(header, highlight_bg(SOURCE), diagram_svg="<svg/>")
    with pytest.raises(TypeError, match="plot"):
        ReportContext(header, highlight_bg(SOURCE), plots=[("t", "<svg/>")])
    with pytest.raises(TypeError, match="Equation"):
        ReportContext(header, highlight_bg(SOURCE), equations=[Equation("<math/>")])


def test_header_for_graph(model):
    graph, _ = model
    header = ReportHeader.for_graph(graph, SOURCE, "step", date="2024-05-01")
    assert header.model_name == "MassSpringDamper" and header.source_file == "msd.bg"
    assert header.source_sha256 == source_sha256(SOURCE) and len(header.source_sha256) == 64
    assert header.experiment_description == "step <i>response</i>"
    assert dict(header.solver_settings) == {"t_end": 2.0, "rtol": 1e-6}
    assert "<span class=\"setting\">t_end</span> = 2 s" in render_report(ReportContext(header, highlight_bg(SOURCE)))
    assert re.fullmatch(r"\d{4}-\d\d-\d\d", ReportHeader.for_graph(graph, SOURCE).date)


def test_parameter_rows_in_written_units(model):
    rows = {row.name: row for row in parameter_rows(model[0])}
    assert rows["lead"] == ParameterRow("lead", pytest.approx(5.0), "mm", None)
    assert rows["m"].description == "moving <b>mass</b>"


def test_table_from_dicts_and_shape_check():
    table = Table.from_dicts("T", [{"a": 1}, {"b": 2, "a": 3}])
    assert table.columns == ("a", "b") and table.rows == ((1, None), (3, 2))
    with pytest.raises(ValueError, match="row 1"):
        Table("T", ("a", "b"), [(1,)])


@pytest.mark.parametrize("value, text", [
    (None, "—"), (True, "yes"), (3, "3"), (0.1234567, "0.1235"), (-2.5, "−2.5"),
    (1.5e-7, "1.5×10<sup>−7</sup>"), (224000.0, "2.24×10<sup>5</sup>"), (float("nan"), "n/a"),
    (float("inf"), "∞"), ("a<b", "a&lt;b"), (np.float64(2.0), "2"),
])
def test_format_number(value, text):
    assert str(format_number(value)) == text


def test_format_unit():
    assert str(format_unit("kg*m^2")) == "kg·m<sup>2</sup>"
    assert str(format_unit("1/s")) == "1/s"
    assert str(format_unit("<x>")) == "&lt;x&gt;"
    assert str(format_unit(None)) == ""


# ---------------------------------------------------------------- plots and MathML

def test_plot_svg_is_clean_inline_svg():
    t = np.linspace(0, 1, 50)
    svg = plot_svg(t, {"x <a&b>": np.sin(t), "y": np.cos(t)}, "Signals <1>", "value [m]")
    assert isinstance(svg, Markup)
    assert svg.startswith("<svg ") and svg.rstrip().endswith("</svg>")
    assert "<?xml" not in svg and "<!DOCTYPE" not in svg and "<style" not in svg and "<metadata" not in svg
    root = ET.fromstring(svg)
    texts = ["".join(e.itertext()) for e in root.iter("{http://www.w3.org/2000/svg}text")]
    assert "x <a&b>" in texts and "value [m]" in texts          # fonttype none: text stays text
    assert root.find("{http://www.w3.org/2000/svg}title").text == "Signals <1>"
    assert float(root.get("width").rstrip("pt")) > 0 and float(root.get("height").rstrip("pt")) > 0
    assert plot_svg(t, {"x <a&b>": np.sin(t), "y": np.cos(t)}, "Signals <1>", "value [m]") == svg


def test_plot_ids_are_unique_per_plot_and_references_resolve():
    t = np.linspace(0, 1, 50)
    first = plot_svg(t, {"x": t}, "A", "x")
    second = plot_svg(t, {"x": t ** 2}, "B", "x")
    ids_first = set(re.findall(r'\bid="([^"]+)"', first))
    ids_second = set(re.findall(r'\bid="([^"]+)"', second))
    assert ids_first and not ids_first & ids_second
    for svg, ids in ((first, ids_first), (second, ids_second)):
        refs = set(re.findall(r'href="#([^"]+)"', svg)) | set(re.findall(r"url\(#([^)]+)\)", svg))
        assert refs and refs <= ids


def test_plot_rejects_mismatched_lengths():
    with pytest.raises(ValueError, match="series 'x'"):
        plot_svg(np.arange(3.0), {"x": np.arange(4.0)}, "T", "x")


def test_mathml_escapes_and_is_well_formed():
    symbol = sympy.Symbol("a<b&c")
    markup = math_markup(symbol + sympy.pi * sympy.Symbol("x") ** 2)
    assert "<mi>a&lt;b&amp;c</mi>" in markup and "π" in markup
    root = ET.fromstring(markup)
    assert root.tag == "math" and root.get("display") == "block"
    relation = math_markup(sympy.Symbol("x") < 1, display="inline")
    assert "<mo>&lt;</mo>" in relation
    equation = equation_markup(sympy.Derivative(sympy.Function("p")(sympy.Symbol("t")), sympy.Symbol("t")),
                               sympy.Symbol("e"))
    ET.fromstring(equation)
    assert "<mo>=</mo>" in equation


def test_docstring_examples():
    import doctest

    from bondc.report import render

    result = doctest.testmod(render)
    assert result.attempted > 0 and result.failed == 0


def test_plot_labels_from_data_are_text_never_mathtext():
    # a measured column named "$\foo$" made matplotlib's mathtext parser raise; it is drawn as written
    from bondc.report.render import plot_svg

    t = np.linspace(0.0, 1.0, 11)
    svg = str(plot_svg(t, {"$\\foo$": t, "x_1^2 $": 2 * t}, "title $a$", "$\\bar{y}$ [m]"))
    root = ET.fromstring(svg)
    texts = "".join(root.itertext())
    assert "$\\foo$" in texts and "x_1^2 $" in texts and "$\\bar{y}$ [m]" in texts


def test_plot_draws_each_series_thinned_to_its_extremes_and_carries_zoom_data():
    from bondc.report.render import DISPLAY_POINTS, ZOOM_POINTS, zoom_samples

    t = np.linspace(0.0, 1.0, 200_001)
    square = np.where(np.sin(2 * np.pi * 2000 * t) > 0, 1.0, -1.0) + 0.001 * t      # a 2 kHz PWM-like signal
    ramp = t.copy()
    svg = str(plot_svg(t, {"pwm": square, "ramp": ramp}, "Two", "u"))
    for number in (0, 1):
        d = re.search(rf'id="[^"]*-zoomline{number}">\s*<path d="([^"]*)"', svg).group(1)
        assert 2 <= d.count("L") + 1 <= DISPLAY_POINTS                  # each series on its own budget
    zoom = json.loads(html_module.unescape(re.search(r'data-zoom="([^"]*)"', svg).group(1)))
    assert zoom["x"] == [0.0, 1.0] and len(zoom["lines"]) == 2
    x, q = zoom_samples(zoom["lines"][0])
    assert len(q) == len(x) <= ZOOM_POINTS and q.max() > 60000 and q.min() < 5000    # both levels of the PWM
    assert x[0] == 0 and x[-1] == 2 ** 32 - 1 and np.all(np.diff(x.astype(float)) > 0)
    clip = re.search(r'<clipPath[^>]*>\s*<rect x="([^"]*)" y="([^"]*)" width="([^"]*)" height="([^"]*)"', svg)
    assert zoom["box"] == pytest.approx([float(v) for v in clip.groups()], abs=0.01)   # the data area
    # markers cannot be redrawn by the zoom: such a plot has no data-zoom
    assert "data-zoom" not in str(plot_svg(t[:100], {"m": t[:100]}, "M", "m", styles={"m": {"marker": "."}}))


def test_only_a_report_with_zoomable_plots_has_a_script(model):
    graph, causal = model
    html = render_report(ReportContext(ReportHeader.for_graph(graph, SOURCE, date="2024-05-01"),
                                       highlight_bg(SOURCE)))
    assert "<script" not in html and "script-src &#39;none&#39;" in html
    without_zoom_script(html)
    html = render_report(full_context(graph, causal))
    assert html.count("<script>") == 1 and "script-src &#39;sha256-" in html
    without_zoom_script(html)


# ---------------------------------------------------------------- the answer first

def hostile_answer() -> Answer:
    """An answer whose every text could be markup: a motor named ``MX-<1>``."""
    t = np.linspace(0.0, 1.0, 5001)
    torque = 0.4 * np.sin(2 * np.pi * 3 * t)
    limits = [HLine(1.2, "peak <±1.2>", (("color", "#0550ae"), ("linestyle", "--")), "limit-peak"),
              HLine(-1.2, "peak", (("color", "#0550ae"), ("linestyle", "--")), "limit-peak-negative", legend=False)]
    torque_plot = Plot("Torque of MX-<1>", plot_svg(t, {"motor <torque>": torque}, "Torque of MX-<1>", "τ [N·m]",
                                                    size=ANSWER_SIZE, hlines=limits, ylim=(-1.4, 1.4),
                                                    legend_above=True, max_points=1000), "limits <b>bold</b>")
    speed_plot = Plot("Speed <i>plot</i>", plot_svg(t, {"s": np.abs(torque)}, "Speed <i>plot</i>", "τ", zoom_points=0,
                                                    size=ANSWER_SIZE), "caption & more")
    margins = [RuleMargin("peak torque", "0.4 N·m at <300> rpm", "1.2 N·m", 3.0, 2 / 3, True),
               RuleMargin("inertia ratio", "load inertia unknown: not checked", "up to 10", None, None, None),
               RuleMargin("peak power", "12 W", "<50> W rated", 50 / 12, 1 - 12 / 50, None)]
    rows = [CandidateRow("MX-<0>", ((0.8, False), (1.5, True), (2.0, True), (None, None)), "fails"),
            CandidateRow("MX-<1>", ((3.0, True), (2.5, True), (2.0, True), (None, None)), "the choice", True)]
    return Answer("MX-<1> is the smallest motor that <b>qualifies</b>.", "MX-<1>", "MX-<1>", margins, torque_plot,
                  speed_plot, rows)


def test_the_answer_comes_first_escaped(model):
    html = render_report(full_context(*model, answer=hostile_answer(), verdict="the verdict as a plain paragraph"))
    check_html(html)
    answer = html.index('<section id="answer"')
    for later in ('<table class="meta">', '<nav class="toc"', '<section id="bond-graph">',
                  '<section id="parameters">', '<section id="equations">', '<section id="source"'):
        assert answer < html.index(later), later
    assert html.index('<header class="report-header">') < answer
    assert html.count('<p class="verdict-text">') == 1                     # the answer's, not a second one
    top = html[answer:html.index("</section>", answer)]
    assert "MX-&lt;1&gt; is the smallest motor that &lt;b&gt;qualifies&lt;/b&gt;." in top
    assert "The answer: MX-&lt;1&gt;" in top and "0.4 N·m at &lt;300&gt; rpm" in top and "&lt;50&gt; W rated" in top
    assert "limits &lt;b&gt;bold&lt;/b&gt;" in top and "Speed &lt;i&gt;plot&lt;/i&gt;." in top
    assert '<tr class="chosen"><td>MX-&lt;1&gt;</td>' in top and "<td>MX-&lt;0&gt;</td>" in top
    assert '<td class="pass">✓ 3×' in top and '<td class="num fail">✗ 0.8</td>' in top
    assert "not checked" in top and "information" in top
    assert "<b>" not in top and "<i>plot" not in top
    # the SVG's own texts are escaped by plot_svg: the legend of the limit, the title
    assert "peak &lt;±1.2&gt;" in top and "<title>Torque of MX-&lt;1&gt;</title>" in top
    assert re.search(r'<g id="plot[0-9a-f]{8}-limit-peak">', top)


def test_the_answers_torque_plot_zooms(model):
    """The torque over time is thinned for display and carries zoom data, and its limit lines are no
    zoom lines (they stay across the plot); a report whose only zoomable plot is it has the script."""
    graph, causal = model
    answer = hostile_answer()
    svg = str(answer.torque_plot.svg)
    zoom = json.loads(html_module.unescape(re.search(r'data-zoom="([^"]*)"', svg).group(1)))
    assert len(zoom["lines"]) == 1 and zoom["x"] == [0.0, 1.0]
    drawn = re.search(r'id="[^"]*-zoomline0">\s*<path d="([^"]*)"', svg).group(1)
    assert len(re.findall(r"[ML]", drawn)) <= 1000
    html = render_report(ReportContext(ReportHeader.for_graph(graph, SOURCE, date="2024-05-01"),
                                       highlight_bg(SOURCE), answer=answer))
    assert html.count("<script>") == 1
    without_zoom_script(html)
