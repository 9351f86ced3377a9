"""``build_report``: the whole pipeline to one self-contained HTML file, for every model of ``models/``."""

from __future__ import annotations

import csv
import functools
import io
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from bondc.errors import DataError, ModelError, UsageError
from bondc.report import build
from bondc.report.build import build_report, default_output, output_groups, run_pipeline, state_equations
from bondc.report.render import source_sha256
from test_report_render import check_html, without_zoom_script

ROOT = Path(__file__).parent.parent
MODELS = ROOT / "models"
FLAGSHIP = MODELS / "electro_pneumatic_hybrid.bg"
CATALOGUE = MODELS / "data" / "motors.csv"
ARTIFACTS = Path(__file__).parent / "artifacts"
DATE = "2024-05-01"


@functools.lru_cache(maxsize=None)
def flagship_report() -> Path:
    """The flagship's report with the motor catalogue, built once per test session (the browser test reads it)."""
    ARTIFACTS.mkdir(exist_ok=True)
    return build_report(FLAGSHIP, motors=CATALOGUE, output=ARTIFACTS / "flagship_report.html", date=DATE)


def assert_self_contained(html: str) -> None:
    """No script but bondc's own zoom.js, no stylesheet link, nothing fetched: the only URLs are xmlns
    namespace names."""
    html = without_zoom_script(html)
    without_namespaces = re.sub(r'\sxmlns(:[\w-]+)?="[^"]*"', "", html)
    lowered = without_namespaces.lower()
    for forbidden in ("http://", "https://", "<script", "<link", "@import", "<iframe", "<object", "<embed",
                      "<img", "javascript:", "url(http", "file://"):
        assert forbidden not in lowered, forbidden
    tags = re.findall(r"<[a-z][^>]*>", lowered)                     # text may say "src=", tags may not
    assert [tag for tag in tags if re.search(r"\s(src|on[a-z]+)\s*=", tag)] == []
    assert all(ref.startswith("#") for ref in re.findall(r'href="([^"]*)"', without_namespaces))


def sections(html: str) -> list[str]:
    return re.findall(r'<section id="([^"]+)"', html)


# ---------------------------------------------------------------- every model builds

SMALL_MODELS = sorted(path.name for path in MODELS.glob("*.bg") if path != FLAGSHIP)


def test_models_folder_is_covered():
    assert "electro_pneumatic_hybrid.bg" not in SMALL_MODELS
    assert len(SMALL_MODELS) >= 5


@pytest.mark.slow
@pytest.mark.parametrize("name", SMALL_MODELS)
def test_every_model_report_builds(name, tmp_path):
    target = build_report(MODELS / name, output=tmp_path / "r.html", date=DATE)
    html = target.read_text(encoding="utf-8")
    checker = check_html(html)
    assert len(checker.ids) == len(set(checker.ids)), "duplicate ids"
    assert_self_contained(html)
    found = sections(html)
    for section in ("bond-graph", "parameters", "causality", "equations", "results", "power", "source"):
        assert section in found, section
    assert "Incomplete simulation" not in html
    assert html.count('class="causal-stroke"') == html.count('class="half-arrow"') > 0
    for math in re.findall(r"<math .*?</math>", html, flags=re.S):
        ET.fromstring(math)
    assert "Energy per element" in html and "residual" in html


@pytest.mark.slow
def test_flagship_report():
    html = flagship_report().read_text(encoding="utf-8")
    checker = check_html(html)
    assert len(checker.ids) == len(set(checker.ids))
    assert_self_contained(html)
    assert sections(html) == ["answer", "bond-graph", "parameters", "causality", "equations", "results", "power",
                              "motor-requirements", "motor-candidates", "source"]
    header = html[:html.index("<nav")]
    assert "ElectroPneumaticHybrid" in header and "electro_pneumatic_hybrid.bg" in header
    assert source_sha256(FLAGSHIP.read_text(encoding="utf-8")) in header and "bondc 0." in header and DATE in header
    assert "<code>cycle</code> — up 100 mm, stop, down 100 mm" in header and "CVODE" in header
    # 20 bonds, each with a half-arrow, a causal stroke and its number
    diagram = html[html.index('<svg xmlns="http://www.w3.org/2000/svg" class="bond-graph"'):]
    diagram = diagram[:diagram.index("</svg>")]
    assert diagram.count('class="half-arrow"') == diagram.count('class="causal-stroke"') == 20
    assert [int(n) for n in re.findall(r'class="bond-number"[^>]*>(\d+)', diagram)] == list(range(1, 21))
    # the equations: one per state, the long laws named once, the model's functions as functions
    equations = html[html.index('<section id="equations">'):html.index('<section id="results">')]
    assert equations.count('<span class="eq-label">') >= 6 + 3 + 5
    assert "valve_mdot" in equations and "fn psi_subsonic" in equations
    # torque and power first, then the other outputs; power per element; the energy balance
    results = html[html.index('<section id="results">'):html.index('<section id="power">')]
    captions = re.findall(r'<span class="label">Figure \d+\.</span> ([^.<]+)', results)
    assert captions[:2] == ["Output torque", "Output power"]
    power = html[html.index('<section id="power">'):html.index('<section id="motor-requirements">')]
    assert "Power delivered by the sources" in power and "Power into the storage elements" in power
    assert "Energy per element, cycle 1 of 1" in power and "Balance: the sources" in power
    for element in ("servomotor", "friction", "chamber", "supply", "mass"):
        assert f"<td>{element}</td>" in power
    # the motor: requirements and the catalogue's motors, with the choice
    motors = html[html.index('<section id="motor-requirements">'):html.index('<section id="source"')]
    assert "RMS torque" in motors and "SV-200" in motors and "Choice: SV-200" in motors
    top = header + html[:html.index('<section id="bond-graph">')]
    # the answer first, in full sentences: the choice, each rule's figures, the smaller motor and why not
    verdict = re.search(r'<p class="verdict-text">(.*?)</p>', top, flags=re.S).group(1)
    assert verdict.startswith("SV-200 is the smallest motor that qualifies: peak torque ")
    for words in (" N·m at ", "RMS torque ", "top speed 1000 of 3000 rpm", "load/rotor inertia ratio 4.33 of 10"):
        assert words in verdict, words
    assert verdict.endswith("and its load/rotor inertia ratio is 24.3, above 10.")
    assert "SV-100 is smaller but its load/rotor inertia ratio is 11.9, above 10." in verdict
    assert "<dt>motor</dt><dd>SV-200</dd>" in top
    assert "Torque against speed on SV-200&#39;s envelope" in top and "operating points" in top
    assert len(html) < 3_000_000


# ---------------------------------------------------------------- the answer first

def catalogue_motors(path: Path = CATALOGUE) -> dict[str, dict[str, float]]:
    """The catalogue read with the csv module (not bondc's reader): name -> its numeric columns."""
    lines = [line for line in path.read_text(encoding="utf-8").splitlines() if line and not line.startswith("#")]
    return {row["name"]: {key: float(value) for key, value in row.items() if key != "name" and value}
            for row in csv.DictReader(lines)}


def _x_axis(svg: str):
    """Value at an SVG x, from the plot's own x tick labels."""
    ticks = re.findall(r'<g id="[^"]*-xtick_\d+">.*?<use [^>]*\bx="([-\d.]+)".*?<text [^>]*>([^<]*)</text>',
                       svg, flags=re.S)
    (x_a, label_a), (x_b, label_b) = ticks[0], ticks[-1]
    value_a, value_b = (float(label.replace("−", "-")) for label in (label_a, label_b))
    x_a, x_b = float(x_a), float(x_b)
    return lambda x: value_a + (np.asarray(x) - x_a) * (value_b - value_a) / (x_b - x_a)


def _line_level(svg: str, gid: str) -> float:
    """The SVG y of the horizontal line drawn in the group ``gid`` (both ends at the same height)."""
    d = re.search(r'<g id="[^"]*-%s">\s*<path d="([^"]*)"' % re.escape(gid), svg).group(1)
    points = _vertices(d)
    assert len(points) == 2 and points[0, 1] == points[1, 1], d
    return float(points[0, 1])


def _data_area(svg: str) -> tuple[float, float, float, float]:
    """(left, top, right, bottom) of the axes' background, in SVG units."""
    d = re.search(r'<g id="[^"]*-patch_2">\s*<path d="([^"]*)"', svg).group(1)
    points = _vertices(d)
    return (float(points[:, 0].min()), float(points[:, 1].min()), float(points[:, 0].max()),
            float(points[:, 1].max()))


def check_answer_first(html: str, catalogue: Path = CATALOGUE) -> dict:
    """The report leads with the answer: the verdict and the torque-time plot come before the model's
    sections; the plot's limit lines are the chosen motor's catalogue values; the torque-speed plot is
    zoomed to the operating region with the chosen motor's envelope only. Returns what it measured."""
    chosen = re.search(r'<h2 class="summary-title">The answer: ([^<]+)</h2>', html).group(1)
    verdict = re.search(r'<p class="verdict-text">(.*?)</p>', html, flags=re.S).group(1)
    assert verdict.startswith(f"{chosen} is the smallest motor that qualifies: ")
    torque_svg = _plot(html, f"Torque over the cycle against {chosen}'s limits")
    speed_svg = _plot(html, f"Torque against speed on {chosen}'s envelope")
    # first: the verdict and both plots before every section of the model
    first = max(html.index('<p class="verdict-text">'), html.index(torque_svg), html.index(speed_svg))
    found = sections(html)
    assert found[0] == "answer" and {"bond-graph", "parameters", "source"} <= set(found)
    for section in found[1:]:
        assert first < html.index(f'<section id="{section}"'), section
    assert html.index('<nav class="toc"') > first and html.index('<table class="meta">') > first
    # the limit lines at the chosen motor's catalogue values (read here with the csv module)
    motors = catalogue_motors(catalogue)
    motor = motors[chosen]
    value = _y_axis(torque_svg)
    tolerance = 2e-3 * motor["peak_torque"]
    for gid, expected in (("limit-peak", motor["peak_torque"]), ("limit-peak-negative", -motor["peak_torque"]),
                          ("limit-continuous", motor["rated_torque"]),
                          ("limit-continuous-negative", -motor["rated_torque"])):
        assert abs(float(value(_line_level(torque_svg, gid))) - expected) < tolerance, gid
    rms = float(re.search(r"RMS torque ([\d.]+) of ", verdict).group(1))
    assert float(value(_line_level(torque_svg, "rms"))) == pytest.approx(rms, rel=5e-3, abs=tolerance)
    assert "data-zoom" in torque_svg                               # the torque over time zooms like the others
    drawn = _vertices(re.search(r'id="[^"]*-zoomline0">\s*<path d="([^"]*)"', torque_svg).group(1))
    peak = float(re.search(r"peak torque ([\d.]+) of ", verdict).group(1))
    assert float(np.max(np.abs(value(drawn[:, 1])))) == pytest.approx(peak, rel=5e-3)
    # torque against speed: zoomed to the operating points and the chosen motor's limits, not the catalogue's
    left, top, right, bottom = _data_area(speed_svg)
    x_value, y_value = _x_axis(speed_svg), _y_axis(speed_svg)
    x_range = (float(x_value(left)), float(x_value(right)))
    y_range = (float(y_value(bottom)), float(y_value(top)))
    group = speed_svg[speed_svg.index("-operating-points\">"):speed_svg.index("-rms-point\">")]
    points = np.array([[float(x), float(y)] for x, y in re.findall(r'<use [^>]*\bx="([-\d.]+)" y="([-\d.]+)"', group)])
    speeds, torques = x_value(points[:, 0]), y_value(points[:, 1])
    assert len(points) > 10
    assert abs(x_range[0]) < 1e-4 * x_range[1] and abs(y_range[0]) < 1e-4 * y_range[1]     # from 0 (to 0.01 pt)
    assert speeds.max() <= x_range[1] and torques.max() <= y_range[1]          # every point inside
    assert float(torques.max()) == pytest.approx(peak, rel=5e-3)
    assert motor["peak_torque"] < y_range[1] <= 1.5 * max(float(torques.max()), motor["peak_torque"])
    assert motor["rated_speed"] < x_range[1] <= 1.5 * max(float(speeds.max()), motor["rated_speed"])
    # the chosen motor's envelope alone, in the legend; the points in a colour no envelope uses
    legend = re.findall(r"<text [^>]*>([^<]*)</text>", speed_svg)
    assert f"{chosen} continuous" in legend and f"{chosen} peak" in legend
    assert not any(name in text for name in motors if name != chosen and name not in chosen for text in legend)
    envelope_colours = set(re.findall(r'-envelope-[a-z]+">\s*<path [^>]*stroke: (#[0-9a-f]{6})', speed_svg))
    point_colours = set(re.findall(r"fill: (#[0-9a-f]{6})", group))
    assert len(envelope_colours) == 1 and len(point_colours) == 1 and not envelope_colours & point_colours
    # the other motors: a compact table, each with its rules' margins
    table = html[html.index('<table class="data candidates">'):]
    table = table[:table.index("</table>")]
    assert sorted(re.findall(r"<tr[^>]*><td>([^<]+)</td>", table)) == sorted(motors)
    assert re.search(r'<tr class="chosen"><td>%s</td>' % re.escape(chosen), table)
    assert table.count("<tr") == len(motors) + 1
    return {"chosen": chosen, "x_range": x_range, "y_range": y_range, "peak": peak, "speeds": speeds}


@pytest.mark.slow
def test_flagship_report_leads_with_the_answer():
    html = flagship_report().read_text(encoding="utf-8")
    found = check_answer_first(html)
    assert found["chosen"] == "SV-200"
    # not the 0-10 N·m of the whole catalogue: SV-200's peak 1.91 N·m with room, the points no longer
    # in the bottom 4 % of the axis
    assert found["y_range"][1] < 3.0 and found["peak"] / found["y_range"][1] > 0.15
    # the rule margins of SV-200, as the verdict states them
    margins = html[html.index('<table class="data margins">'):]
    margins = margins[:margins.index("</table>")]
    for words in ("1.91 N·m", "0.64 N·m", "3000 rpm", "1000 rpm", "load/rotor 4.33", "up to 10", "✓ 4.44× (77 %)"):
        assert words in margins, words


def test_a_pwm_drive_report_leads_with_the_answer():
    check_answer_first(pwm_report().read_text(encoding="utf-8"))


SPINDLE = Path(__file__).parent / "fixtures" / "motors" / "spindle.bg"


def test_an_answer_without_a_known_load_inertia(tmp_path):
    html = build_report(SPINDLE, motors=CATALOGUE, output=tmp_path / "r.html", date=DATE).read_text(encoding="utf-8")
    assert check_answer_first(html)["chosen"] == "SV-200"
    margins = html[html.index('<table class="data margins">'):]
    assert "load inertia unknown: not checked" in margins[:margins.index("</table>")]


def test_when_no_motor_qualifies_the_largest_is_shown(tmp_path):
    small = tmp_path / "small.csv"
    small.write_text("\n".join(line for line in CATALOGUE.read_text(encoding="utf-8").splitlines()
                               if not line.startswith("SV-") or line.split(",")[0] in ("SV-50", "SV-100")) + "\n",
                     encoding="utf-8")
    html = build_report(SPINDLE, motors=small, output=tmp_path / "r.html", date=DATE).read_text(encoding="utf-8")
    check_html(html)
    verdict = re.search(r'<p class="verdict-text">(.*?)</p>', html, flags=re.S).group(1)
    assert verdict.startswith("No motor of the catalogue qualifies: the largest, SV-100, fails because ")
    assert '<h2 class="summary-title">The answer</h2>' in html and 'class="chosen"' not in html
    svg = _plot(html, "Torque over the cycle against SV-100's limits")
    value, motor = _y_axis(svg), catalogue_motors(small)["SV-100"]
    assert float(value(_line_level(svg, "limit-continuous"))) == pytest.approx(motor["rated_torque"], abs=2e-3)
    assert float(value(_line_level(svg, "limit-peak"))) == pytest.approx(motor["peak_torque"], abs=2e-3)
    margins = html[html.index('<table class="data margins">'):]
    margins = margins[:margins.index("</table>")]
    assert '<td class="fail">✗ ' in margins and "(−" in margins           # RMS torque: a negative headroom
    assert html.count("No motor qualifies: SV-100 is the largest.") == 2   # both captions say why it is shown


@pytest.mark.slow
def test_flagship_numbers_match_the_reference():
    """The key results agree with models/README.md (independent scipy reference, about 1 %)."""
    html = flagship_report().read_text(encoding="utf-8")
    summary = dict(re.findall(r"<dt>([^<]+)</dt><dd>([^<]+)", html))
    # the load's figures (the answer above them adds the chosen motor's rotor inertia: 0.43 N*m)
    assert float(summary["peak load torque"]) == pytest.approx(0.401, rel=0.01)
    assert float(summary["RMS load torque"]) == pytest.approx(0.175, rel=0.01)
    assert float(summary["peak load power"]) == pytest.approx(42.0, rel=0.01)
    assert float(summary["motor energy per cycle"]) == pytest.approx(54.7, rel=0.01)


@pytest.mark.slow
def test_non_default_experiment_file_name_and_overrides(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    target = build_report(FLAGSHIP, experiment="catalogue_valve", sets=["M=40 [kg]"], t_end=0.05, date=DATE)
    assert target == Path("reports/electro_pneumatic_hybrid-catalogue_valve.html")
    html = target.read_text(encoding="utf-8")
    check_html(html)
    assert "<code>catalogue_valve</code>" in html
    assert "<span class=\"setting\">t_end</span> = 0.05 s" in html
    assert "(set by experiment catalogue_valve)" in html and "(set by --set)" in html
    row = re.search(r"<td><code>M</code></td><td class=\"num\">([^<]+)</td>", html)
    assert row.group(1) == "40"
    # the first experiment, named or not, writes the plain name
    run = run_pipeline(MODELS / "series_rlc.bg", experiment="step", t_end=1e-3)
    assert default_output(MODELS / "series_rlc.bg", run) == Path("reports/series_rlc.html")


# ---------------------------------------------------------------- escaping, failures, atomic writing

HOSTILE = """\
model Hostile "Description <script>alert('x')</script> & <b>bold</b>"
  param m = 1 [kg] "mass </td></tr></table><script>bad()</script>"
  input F [N] = 1
  MSe force "a <img src=x onerror=alert(1)> source" : e = F
  I mass : f = p/m
  1 j
  force -> j
  j -> mass
  output v [m/s] = mass.f "speed <i>of</i> the mass"
  experiment run "<style>body{display:none}</style>"
    t_end = 0.1 [s]
  end
end
"""


@pytest.mark.slow
def test_hostile_text_is_shown_as_text(tmp_path):
    model = tmp_path / "hostile.bg"
    model.write_text(HOSTILE, encoding="utf-8")
    html = build_report(model, output=tmp_path / "h.html", date=DATE).read_text(encoding="utf-8")
    check_html(html)
    assert_self_contained(html)
    assert "Description &lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; &amp; &lt;b&gt;bold&lt;/b&gt;" in html
    assert "<script" not in without_zoom_script(html) and "<b>bold" not in html and "<img" not in html
    assert "&lt;style&gt;body{display:none}&lt;/style&gt;" in html
    assert html.count("<style>") == 1


FAILING = """\
model Failing "A force that becomes nan at t = 0.5 s"
  param m = 1
  Se push : e = sqrt(0.5 - t)
  I mass : f = p/m
  1 j
  push -> j
  j -> mass
  output v [m/s] = mass.f
  experiment run
    t_end = 1 [s]
  end
end
"""


def test_incomplete_simulation_still_reports(tmp_path):
    model = tmp_path / "failing.bg"
    model.write_text(FAILING, encoding="utf-8")
    html = build_report(model, output=tmp_path / "f.html", date=DATE).read_text(encoding="utf-8")
    check_html(html)
    notice = html[html.index('<aside class="callout incomplete"'):]
    notice = notice[:notice.index("</aside>")]
    assert "Incomplete simulation" in notice and "E810" in notice and "sqrt(0.5 - t)" in notice
    assert html.index("Incomplete simulation") < html.index('<section id="bond-graph">')
    assert "results" in sections(html) and "power" in sections(html)     # what was computed is shown


def test_run_report_prints_diagnostics_and_exits_1_when_incomplete(tmp_path):
    model = tmp_path / "failing.bg"
    model.write_text(FAILING, encoding="utf-8")
    errors = io.StringIO()
    target, code = build.run_report(model, output=tmp_path / "f.html", errors=errors, date=DATE)
    assert code == 1 and target.exists()
    text = errors.getvalue()
    assert "error[E810]" in text and "sqrt(0.5 - t)" in text and "^^^" in text       # with source context
    assert text.rstrip().endswith(f"wrote {target} (incomplete simulation)")
    errors = io.StringIO()
    model.write_text(FAILING.replace("sqrt(0.5 - t)", "1"), encoding="utf-8")
    assert build.run_report(model, output=tmp_path / "f.html", errors=errors, date=DATE)[1] == 0
    assert errors.getvalue() == f"wrote {tmp_path / 'f.html'}\n"


def test_model_without_end_time_is_reported_unsimulated(tmp_path):
    model = tmp_path / "static.bg"
    model.write_text(FAILING.replace("  experiment run\n    t_end = 1 [s]\n  end\n", ""), encoding="utf-8")
    html = build_report(model, output=tmp_path / "s.html", date=DATE).read_text(encoding="utf-8")
    check_html(html)
    assert "Not simulated" in html and "results" not in sections(html) and "equations" in sections(html)


@pytest.mark.slow
def test_a_failure_leaves_the_earlier_report_intact(tmp_path, monkeypatch):
    model = tmp_path / "m.bg"
    model.write_text(FAILING.replace("sqrt(0.5 - t)", "1"), encoding="utf-8")
    target = tmp_path / "out" / "m.html"
    build_report(model, output=target, date=DATE)
    earlier = target.read_bytes()
    assert earlier.startswith(b"<!DOCTYPE html>")

    def listing():
        return sorted(os.listdir(target.parent))

    # a model error: nothing is written
    model.write_text(FAILING.replace("I mass : f = p/m", "I mass : f = p/undefined_name"), encoding="utf-8")
    with pytest.raises(ModelError):
        build_report(model, output=target, date=DATE)
    assert target.read_bytes() == earlier
    # bad measured data: found before anything is simulated
    model.write_text(FAILING.replace("sqrt(0.5 - t)", "1"), encoding="utf-8")
    bad = tmp_path / "bad.csv"
    bad.write_text("t,v\n0,1\n0,2\n", encoding="utf-8")
    with pytest.raises(DataError):
        build_report(model, data=bad, compare=["v=v"], output=target, date=DATE)
    assert target.read_bytes() == earlier
    # rendering fails half-way
    monkeypatch.setattr(build, "render_report", lambda context: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        build_report(model, output=target, date="2030-01-01")
    monkeypatch.undo()
    assert target.read_bytes() == earlier
    # the write itself fails after the temporary file is complete: the rename never happens
    import bondc.io

    def broken_replace(source, destination):
        raise OSError("disk full")

    monkeypatch.setattr(bondc.io.os, "replace", broken_replace)
    with pytest.raises(UsageError, match="disk full") as raised:     # E004, naming where the report is kept
        build_report(model, output=target, date="2030-01-01")
    monkeypatch.undo()
    kept = Path(raised.value.diagnostics[0].message.split("kept in '")[1].rstrip("'"))
    assert raised.value.diagnostics[0].code == "E004" and b"2030-01-01" in kept.read_bytes()
    kept.unlink()
    assert target.read_bytes() == earlier
    assert listing() == ["m.html"]                                       # no temporary file left behind
    # and a successful build replaces it
    build_report(model, output=target, date="2030-01-01")
    assert b"2030-01-01" in target.read_bytes()


def test_data_and_compare_go_together(tmp_path):
    with pytest.raises(UsageError, match="needs measured data"):
        build_report(MODELS / "series_rlc.bg", compare=["i=i"], output=tmp_path / "x.html")
    with pytest.raises(UsageError, match="comparison"):
        build_report(MODELS / "series_rlc.bg", data=tmp_path / "x.csv", output=tmp_path / "x.html")
    assert not (tmp_path / "x.html").exists()


# ---------------------------------------------------------------- pieces

def test_outputs_are_grouped_by_unit_and_magnitude():
    run = run_pipeline(MODELS / "quarter_car.bg", t_end=0.2)
    groups = output_groups(run.graph, run.result, run.experiment)
    flat = [name for group in groups for name in group]
    assert sorted(flat) == sorted(run.result.outputs)
    millimetres = [g for g in groups if "body_displacement" in g][0]
    assert "road_height" in millimetres or "suspension_deflection" in millimetres
    assert all(len(group) <= build.MAX_SERIES_PER_PLOT for group in groups)
    flagship = run_pipeline(FLAGSHIP, t_end=0.05)
    assert output_groups(flagship.graph, flagship.result, flagship.experiment)[:2] == [["torque"], ["power"]]


def test_state_equations_keep_long_laws_named():
    run = run_pipeline(MODELS / "dc_motor_gear.bg", t_end=0.01)
    equations, laws, table = state_equations(run.state_space)
    assert [e.label for e in equations] == list(run.state_space.state_names)
    assert any("derivative causality" in law.label for law in laws)       # the eliminated load inertia
    assert [row[0] for row in table.rows] == list(run.state_space.state_names)
    for equation in equations + laws:
        ET.fromstring(equation.mathml)


def test_element_power_sums_to_zero_at_every_instant():
    """Junctions and two-ports conserve power, so the powers into all one-ports sum to zero."""
    run = run_pipeline(MODELS / "series_rlc.bg")
    power = build.element_power(run.graph, run.result)
    total = sum(power.values())
    scale = max(np.max(np.abs(values)) for values in power.values())
    assert np.max(np.abs(total)) < 1e-9 * scale


def test_docstring_examples():
    import doctest

    result = doctest.testmod(build)
    assert result.attempted > 0 and result.failed == 0


def test_a_component_is_drawn_as_a_box_whose_contents_expand(tmp_path):
    model = Path(__file__).parent / "fixtures" / "components" / "circuit.bg"
    html = build_report(model, output=tmp_path / "r.html", date=DATE).read_text(encoding="utf-8")
    checker = check_html(html)
    assert len(checker.ids) == len(set(checker.ids)), "duplicate ids"
    collapsed, expanded = re.findall(r'<svg[^>]*class="bond-graph".*?</svg>', html, flags=re.S)
    # the top view: the instance as one box bonded at its two ports, its insides left out
    assert collapsed.count('class="component"') == 1 and "Orifice:valve" in collapsed
    assert "valve.loss" not in collapsed and collapsed.count('class="bond"') == 3
    # expanded: every element of the flat graph, under its dotted name, every bond
    assert "<details" in html and "R:valve.loss" in expanded and expanded.count('class="bond"') == 4


def test_the_states_of_a_component_model_are_described_by_their_own_element():
    model = Path(__file__).parent.parent / "models" / "electro_pneumatic_hybrid_components.bg"
    run = run_pipeline(model, t_end=0.01)
    _, _, states = state_equations(run.state_space)
    text = " ".join(str(cell) for row in states.rows for cell in row)
    assert "generalised momentum of I mass.body" in text and "state of C cylinder.chamber" in text


# ---------------------------------------------------------------- heavy runs stay light

PWM_MOTOR = Path(__file__).parent / "fixtures" / "report" / "pwm_motor.bg"


@functools.lru_cache(maxsize=None)
def pwm_report() -> Path:
    """The report of a DC motor on a 2 kHz PWM drive (12 000 solver points, 48 000 operating points),
    built once per test session (the browser test zooms it)."""
    ARTIFACTS.mkdir(exist_ok=True)
    return build_report(PWM_MOTOR, motors=CATALOGUE, output=ARTIFACTS / "pwm_motor_report.html", date=DATE)


def _plot(html: str, title: str) -> str:
    [svg] = [svg for svg in re.findall(r'<svg class="plot".*?</svg>', html, flags=re.S)
             if f"<title>{title}</title>" in svg]
    return svg


def _vertices(d: str) -> np.ndarray:
    return np.array([[float(x), float(y)] for x, y in re.findall(r"[ML]\s*(-?[\d.]+)\s+(-?[\d.]+)", d)])


def _y_axis(svg: str):
    """Value at an SVG y, from the plot's own y tick labels (the axis a reader sees)."""
    ticks = re.findall(r'<g id="[^"]*-ytick_\d+">.*?<use [^>]*\by="([-\d.]+)".*?<text [^>]*>([^<]*)</text>',
                       svg, flags=re.S)
    (y_a, label_a), (y_b, label_b) = ticks[0], ticks[-1]
    value_a, value_b = (float(label.replace("−", "-")) for label in (label_a, label_b))
    y_a, y_b = float(y_a), float(y_b)
    return lambda y: value_a + (np.asarray(y) - y_a) * (value_b - value_a) / (y_b - y_a)


def test_a_pwm_drive_report_stays_light_and_keeps_every_extreme(tmp_path):
    import html as html_module
    import json

    from bondc.cli import main
    from bondc.report.render import DISPLAY_POINTS, MAX_MARKERS, ZOOM_POINTS, zoom_samples

    html = pwm_report().read_text(encoding="utf-8")
    assert len(html.encode("utf-8")) < 3_000_000              # it was 6.3 MB: 48 021 markers in one plot
    assert_self_contained(html)
    # the independent expectation: the CSV `bondc simulate` writes, every solver point
    assert main(["simulate", str(PWM_MOTOR), "-o", str(tmp_path / "run.csv")]) == 0
    csv = np.genfromtxt(tmp_path / "run.csv", delimiter=",", names=True)
    assert csv.size > 4 * DISPLAY_POINTS
    for name, column in (("current", "current_A"), ("torque", "torque_Nm"), ("omega", "omega_rads")):
        svg = _plot(html, f"Output {name}")
        value = _y_axis(svg)
        low, high = float(np.min(csv[column])), float(np.max(csv[column]))
        tolerance = 1e-3 * (high - low)
        drawn = _vertices(re.search(r'id="[^"]*-zoomline0">\s*<path d="([^"]*)"', svg).group(1))
        assert 100 < len(drawn) <= DISPLAY_POINTS
        assert abs(float(value(drawn[:, 1]).min()) - low) < tolerance, name     # SVG y grows downwards
        assert abs(float(value(drawn[:, 1]).max()) - high) < tolerance, name
        # the finer samples the zoom draws from hold the same extremes
        zoom = json.loads(html_module.unescape(re.search(r'data-zoom="([^"]*)"', svg).group(1)))
        [line] = zoom["lines"]
        times, q = zoom_samples(line)
        assert len(q) == len(times) <= ZOOM_POINTS and np.all(np.diff(times.astype(float)) > 0)
        x0, y0, w, h = zoom["box"]
        fine = value(y0 + h * (1 - q / 65534.0))
        assert abs(float(fine.min()) - low) < tolerance and abs(float(fine.max()) - high) < tolerance, name
    # the operating points: a few thousand markers of the 48 000, and the caption says so
    motor = _plot(html, "Torque against speed on SV-200's envelope")
    assert 100 < motor.count("<use ") <= MAX_MARKERS + 50
    assert re.search(r"\d[\d\u202f]* of the 48\u202f\d{3} operating points are drawn", html)
    # the torque over time against the motor's limits: thinned for display, finer for zooming, same extremes
    svg = _plot(html, "Torque over the cycle against SV-200's limits")
    value = _y_axis(svg)
    drawn = value(_vertices(re.search(r'id="[^"]*-zoomline0">\s*<path d="([^"]*)"', svg).group(1))[:, 1])
    assert 100 < len(drawn) <= DISPLAY_POINTS
    zoom = json.loads(html_module.unescape(re.search(r'data-zoom="([^"]*)"', svg).group(1)))
    [line] = zoom["lines"]
    times, q = zoom_samples(line)
    assert DISPLAY_POINTS < len(q) <= ZOOM_POINTS
    x0, y0, w, h = zoom["box"]
    fine = value(y0 + h * (1 - q / 65534.0))
    span = float(drawn.max() - drawn.min())
    assert abs(float(fine.max()) - float(drawn.max())) < 2e-3 * span
    assert abs(float(fine.min()) - float(drawn.min())) < 2e-3 * span
