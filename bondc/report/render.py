"""Render stage: :class:`ReportContext` -> one self-contained HTML report.

Everything a report shows is gathered into a :class:`ReportContext` by the
caller (header, highlighted source, parameters, diagram, causality, equations,
plots, power/energy tables, optional motor and validation sections);
:func:`render_report` fills ``templates/report.html`` with it.

The HTML is self-contained: CSS inline, figures as inline SVG, equations as
MathML, no external fonts, images or links, and no script but bondc's own
``templates/zoom.js`` (zoom and pan of the plots' time axis, inlined when a
plot can be zoomed), which the page's Content-Security-Policy names by its
hash: nothing is fetched and no other script can run. Templates are files
loaded by one Jinja :func:`environment` with autoescaping forced on and
``StrictUndefined``; the only strings that reach the page unescaped are the
``Markup`` values made by bondc itself (:func:`~bondc.report.lexer.highlight_bg`,
:func:`~bondc.report.diagram.bond_graph_svg`, :func:`plot_svg`,
:func:`math_markup`), each of which escapes the text it contains, and
:func:`zoom_script`, bondc's own script, which holds no text of a model.

Plots stay light: each series is drawn thinned to every interval's extremes
(:func:`decimation_indices`, about one interval a pixel) and carries a finer
thinning for zooming (:func:`zoom_data`); scatter plots draw at most
:data:`MAX_MARKERS` points (:func:`scatter_indices`).

Helpers that build the pieces: :func:`plot_svg` (matplotlib, Agg/SVG),
:func:`math_markup` / :func:`equation_markup` (sympy presentation MathML),
:func:`parameter_rows` (a BondGraph's parameters in their display units),
:func:`causality_rows` / :func:`causality_notes` (a CausalGraph as a table),
:meth:`Table.from_dicts`, :meth:`ReportHeader.for_graph`.

>>> html = render_report(ReportContext(ReportHeader("M", "m.bg", "0" * 64, date="2024-01-01"),
...                                    source_html=Markup("<pre>model M</pre>")))
>>> html.startswith("<!DOCTYPE html>") and "<script" not in html
True
"""

from __future__ import annotations

import datetime
import functools
import hashlib
import html
import io
import math
import numbers
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np
import numpy.typing as npt
from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape
from markupsafe import Markup, escape

from bondc.model import BondGraph
from bondc.report.lexer import lexer_css
from bondc.version import __version__

__all__ = [
    "ReportHeader", "ParameterRow", "CausalityRow", "Table", "Equation", "Plot", "ValidationSection",
    "ReportContext", "Answer", "RuleMargin", "CandidateRow", "HLine", "render_report", "environment", "plot_svg", "math_markup", "equation_markup",
    "parameter_rows", "causality_rows", "causality_notes", "source_sha256", "format_number", "format_unit",
]


# ---------------------------------------------------------------- context

@dataclass(frozen=True)
class ReportHeader:
    """What the report is about: model, source, tool version, date, experiment and solver."""

    model_name: str
    source_file: str
    source_sha256: str
    description: str | None = None
    bondc_version: str = __version__
    date: str = ""
    experiment_name: str | None = None
    experiment_description: str | None = None
    solver_settings: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def for_graph(cls, graph: BondGraph, source_text: str, experiment: str | None = None,
                  date: str | None = None, solver_settings: Mapping[str, Any] | None = None) -> "ReportHeader":
        """The header of a report on ``graph`` (built from ``source_text``), for one experiment.

        Solver settings default to the experiment's (``t_end``, ``solver``,
        ``rtol``, ``atol``, ``max_step``, ``cycle``, as written in the model).
        """
        definition = graph.experiments.get(experiment) if experiment else None
        if solver_settings is None:
            solver_settings = {}
            if definition is not None:
                for name in ("t_end", "solver", "rtol", "atol", "max_step", "cycle"):
                    value = getattr(definition, name)
                    if value is not None:
                        solver_settings[name] = value
        return cls(
            model_name=graph.name,
            source_file=graph.file,
            source_sha256=source_sha256(source_text),
            description=graph.description,
            date=date or datetime.date.today().isoformat(),
            experiment_name=experiment,
            experiment_description=definition.description if definition is not None else None,
            solver_settings=dict(solver_settings),
        )


@dataclass(frozen=True)
class ParameterRow:
    name: str
    value: Any                      # a number (shown with 6 significant digits) or text
    unit: str | None = None
    description: str | None = None


@dataclass(frozen=True)
class CausalityRow:
    bond: int
    label: str | None
    tail: str                       # power goes from tail ...
    head: str                       # ... to head
    effort_from: str                # the node that sets the effort (the stroke is at the other end)
    flow_from: str
    element_causality: str = ""     # e.g. "C spring: integral", "R damper: resistance"


@dataclass(frozen=True)
class Table:
    """A generic table: column headings and rows of cells (numbers are formatted, text escaped)."""

    title: str
    columns: tuple[str, ...]
    rows: Sequence[tuple[Any, ...]]
    caption: str = ""
    notes: Sequence[str] = ()
    total_row: bool = False         # the last row sums the others: drawn in bold

    @property
    def numeric_columns(self) -> tuple[bool, ...]:
        """Per column: does it hold numbers (its cells, and empty ones, are right-aligned)?"""
        return tuple(any(_is_number(row[i]) for row in self.rows) for i in range(len(self.columns)))

    def __post_init__(self) -> None:
        object.__setattr__(self, "columns", tuple(self.columns))
        object.__setattr__(self, "rows", tuple(tuple(row) for row in self.rows))
        object.__setattr__(self, "notes", tuple(self.notes))
        for number, row in enumerate(self.rows, start=1):
            if len(row) != len(self.columns):
                raise ValueError(f"table '{self.title}': row {number} has {len(row)} cells "
                                 f"for {len(self.columns)} columns")

    @classmethod
    def from_dicts(cls, title: str, rows: Iterable[Mapping[str, Any]], columns: Sequence[str] | None = None,
                   caption: str = "", notes: Sequence[str] = ()) -> "Table":
        """A table from rows of dicts; columns default to the keys in order of first appearance."""
        rows = list(rows)
        if columns is None:
            columns = []
            for row in rows:
                columns += [key for key in row if key not in columns]
        return cls(title, tuple(columns), tuple(tuple(row.get(c) for c in columns) for row in rows),
                   caption, tuple(notes))


@dataclass(frozen=True)
class Equation:
    mathml: Markup                  # from math_markup / equation_markup
    label: str = ""                 # e.g. "mass.p" or "(3)"


class BodeSection(NamedTuple):
    """The frequency responses an experiment asks for (``bode = [U -> Y]``): where they were linearised,
    and per pair (``bondc.report.bode_report.section_rows``) its plot, margins and verification."""

    at: str
    time: float
    rows: Sequence[Mapping[str, Any]] = ()
    warnings: Sequence[str] = ()
    notes: Sequence[str] = ()


class Plot(NamedTuple):
    title: str
    svg: Markup                     # from plot_svg
    caption: str = ""
    half: bool = False              # drawn at half the width, two to a row (make it with size=HALF_SIZE)


#: Figure sizes of plot_svg, inches: a full-width plot and a half-width one (two to a row).
FULL_SIZE = (7.0, 2.9)
HALF_SIZE = (4.6, 2.7)

#: The size of the two plots of the answer, side by side on the report's first screen.
ANSWER_SIZE = (4.6, 2.5)


class HLine(NamedTuple):
    """A horizontal line across a :func:`plot_svg` plot: a limit or a level."""

    value: float
    label: str
    style: tuple[tuple[str, Any], ...] = ()    # matplotlib line properties, e.g. (("color", "#0550ae"),)
    gid: str = ""                             # the SVG group's id (prefixed per plot): "limit-peak"
    legend: bool = True                       # listed in the legend (a twin at -value is not)


class RuleMargin(NamedTuple):
    """One sizing rule of the answer's motor: what the cycle needs, what the motor offers, the margin."""

    rule: str                       # "peak torque"
    needed: str                     # "0.43 N·m at 996 rpm"
    offered: str                    # "1.91 N·m"
    margin: float | None            # available / required
    headroom: float | None          # 1 - required / available (the verdict's "% margin")
    passed: bool | None             # None: not applied, or information only


class CandidateRow(NamedTuple):
    """One catalogue motor in the answer's compact table: each rule's margin and whether it passes."""

    motor: str
    checks: tuple[tuple[float | None, bool | None], ...]     # (margin, passed) per rule of Answer.rules
    verdict: str                                              # "the choice", "qualifies", "fails"
    chosen: bool = False


@dataclass(frozen=True)
class Answer:
    """The design answer the report leads with: the verdict, the chosen motor's margins, the cycle's
    torque over time against its limits, the torque-speed points on its envelope, the other motors."""

    verdict: str
    motor: str | None                           # the choice (None: no motor of the catalogue qualifies)
    shown: str                                  # whose margins and limits are shown: the choice, else the largest
    margins: Sequence[RuleMargin]
    torque_plot: Plot                           # torque over time against the motor's limits (zoomable)
    speed_plot: Plot                            # torque against speed on the motor's envelope
    candidates: Sequence[CandidateRow] = ()
    rules: Sequence[str] = ("peak τ", "RMS τ", "speed", "J limit")      # the columns of ``candidates``
    notes: Sequence[str] = ()                   # sentences after the compact table's caption

    def __post_init__(self) -> None:
        for plot in (self.torque_plot, self.speed_plot):
            if not isinstance(plot.svg, Markup):
                raise TypeError(f"plot '{plot.title}': svg must be Markup from plot_svg")


@dataclass(frozen=True)
class ValidationSection:
    """Validation against measured data: the results of :func:`bondc.analysis.validate.compare`."""

    results: Sequence[Any]          # SignalResult
    data_file: str
    plots: Sequence[Plot] = ()
    junit_file: str | None = None


_TRUSTED = ("source_html", "diagram_svg", "diagram_expanded_svg")

#: SI units of the experiment settings that have one (the model stores them in SI).
SETTING_UNITS: Mapping[str, str] = {"t_end": "s", "max_step": "s", "cycle": "s", "first_step": "s", "dt": "s"}


@dataclass(frozen=True)
class ReportContext:
    """Everything one report shows. ``None`` or empty hides an optional section."""

    header: ReportHeader
    source_html: Markup                         # highlight_bg(source text)
    parameters: Sequence[ParameterRow] = ()
    diagram_svg: Markup | None = None           # bond_graph_svg(graph, causal), components as boxes
    diagram_expanded_svg: Markup | None = None  # with components: every component's contents drawn
    causality: Sequence[CausalityRow] = ()
    causality_notes: Sequence[str] = ()
    equations: Sequence[Equation] = ()
    plots: Sequence[Plot] = ()
    power_tables: Sequence[Table] = ()
    motor_requirements: Table | None = None
    motor_candidates: Table | None = None
    validation: ValidationSection | None = None
    warnings: Sequence[str] = ()                # diagnostics worth a reader's attention
    incomplete: str | None = None               # the diagnostic of a simulation that stopped early
    summary: Sequence[tuple[str, Any, str | None]] = ()   # key results under the header: (label, value, unit)
    verdict: str | None = None                  # the motor sizing's answer in sentences, shown first
    answer: Answer | None = None                # the design answer with its margins and plots, shown first
    equation_tables: Sequence[Table] = ()       # e.g. the states with their initial values
    laws: Sequence[Equation] = ()               # "where": the laws the state equations name
    result_tables: Sequence[Table] = ()         # e.g. statistics of the outputs
    power_plots: Sequence[Plot] = ()            # power of the elements against time
    ratio: Any = None                           # --ratio: a bondc.analysis.ratio.RatioStudy, after the answer
    bode: BodeSection | None = None             # the experiment's bode = [U -> Y]: frequency responses

    def __post_init__(self) -> None:
        # Trusted HTML must come from bondc's own producers, which return Markup; a
        # plain str here is a mistake that would otherwise show as escaped markup.
        for name in _TRUSTED:
            value = getattr(self, name)
            if value is not None and not isinstance(value, Markup):
                raise TypeError(f"ReportContext.{name} must be markupsafe.Markup (made by bondc), "
                                f"not {type(value).__name__}")
        for name in ("plots", "power_plots"):
            plots = tuple(p if isinstance(p, Plot) else Plot(*p) for p in getattr(self, name))
            for plot in plots:
                if not isinstance(plot.svg, Markup):
                    raise TypeError(f"plot '{plot.title}': svg must be Markup from plot_svg")
            object.__setattr__(self, name, plots)
        for equation in tuple(self.equations) + tuple(self.laws):
            if not isinstance(equation.mathml, Markup):
                raise TypeError("Equation.mathml must be Markup from math_markup")


# ---------------------------------------------------------------- environment and rendering

def format_number(value: Any, digits: int = 4) -> Markup:
    """A number for a table: ``digits`` significant digits, powers of ten as ``×10<sup>n</sup>``.

    >>> str(format_number(224000.0)), str(format_number(0.005)), str(format_number(None))
    ('2.24×10<sup>5</sup>', '0.005', '—')
    """
    if value is None:
        return Markup("—")
    if isinstance(value, bool):
        return Markup("yes" if value else "no")
    if isinstance(value, numbers.Integral):
        return escape(str(int(value)))
    if isinstance(value, numbers.Real):
        value = float(value)
        if math.isnan(value):
            return Markup("n/a")
        if math.isinf(value):
            return Markup("∞" if value > 0 else "−∞")
        text = f"{value:.{digits}g}"
        if "e" in text:
            mantissa, exponent = text.split("e")
            mantissa = mantissa.replace("-", "−")
            return Markup("{}×10<sup>{}</sup>").format(mantissa, str(int(exponent)).replace("-", "−"))
        return escape(text.replace("-", "−"))
    return escape(value)


def format_unit(text: str | None) -> Markup:
    """A unit as written, typeset: ``N*m/s^2`` -> ``N·m/s<sup>2</sup>``.

    >>> str(format_unit("kg*m^2/s^-1"))
    'kg·m<sup>2</sup>/s<sup>−1</sup>'
    """
    if not text:
        return Markup("")
    out = Markup("")
    for part in re.split(r"(\^(?:\([-+]?[0-9./]+\)|[-+]?[0-9.]+))", text):
        if part.startswith("^"):
            out += Markup("<sup>{}</sup>").format(part[1:].strip("()").replace("-", "−"))
        else:
            out += escape(part.replace("*", "·"))
    return out


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


#: The start of a standalone page's template (the sweep's and the fit's reports): its doctype, the
#: Content-Security-Policy ``csp`` and the viewport; the template goes on with its title and style.
PAGE_HEAD = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="{{ csp }}">
<meta name="viewport" content="width=device-width, initial-scale=1">
"""


@functools.lru_cache(maxsize=1)
def environment() -> Environment:
    """The one Jinja environment of bondc's reports (templates in ``bondc/report/templates``)."""
    env = Environment(
        loader=PackageLoader("bondc.report", "templates"),
        # On for .html as select_autoescape would have it, and forced on for
        # everything else too: nothing is ever rendered unescaped by accident.
        autoescape=select_autoescape(enabled_extensions=("html",), default_for_string=True, default=True),
        undefined=StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters["num"] = format_number
    env.filters["unit"] = format_unit
    env.tests["number"] = _is_number
    return env


def _sections(context: ReportContext) -> list[tuple[str, str]]:
    """(id, title) of the sections the report will show, in order."""
    sections = []
    if context.diagram_svg is not None:
        sections.append(("bond-graph", "Bond graph"))
    if context.parameters:
        sections.append(("parameters", "Parameters"))
    if context.causality or context.causality_notes:
        sections.append(("causality", "Causality"))
    if context.equations:
        sections.append(("equations", "State equations"))
    if context.plots or context.result_tables:
        sections.append(("results", "Simulation results"))
    if context.power_tables or context.power_plots:
        sections.append(("power", "Power and energy"))
    if context.bode is not None:
        sections.append(("frequency-response", "Frequency response"))
    if context.motor_requirements is not None:
        sections.append(("motor-requirements", "Motor requirements"))
    if context.motor_candidates is not None:
        sections.append(("motor-candidates", "Motor candidates"))
    if context.validation is not None:
        sections.append(("validation", "Validation against measurements"))
    sections.append(("source", "Model source"))
    return sections


@functools.lru_cache(maxsize=1)
def zoom_script() -> Markup:
    """The report's one script, ``templates/zoom.js`` (zoom and pan of the plots): bondc's own text,
    inserted as it is in a ``<script>`` when a plot can be zoomed; no text of a model reaches it."""
    env = environment()
    text = env.loader.get_source(env, "zoom.js")[0]
    if re.search(r"</|<!--", text):
        raise ValueError("zoom.js must not contain '</' or '<!--' (it is inlined in a <script>)")
    return Markup(text)


def content_security_policy(script: str | None) -> str:
    """The report's Content-Security-Policy: nothing is fetched, inline styles are allowed and the one
    script that runs is bondc's own, named by its SHA-256 (no script at all without one)."""
    import base64

    scripts = "'none'" if script is None else \
        "'sha256-" + base64.b64encode(hashlib.sha256(script.encode("utf-8")).digest()).decode("ascii") + "'"
    return f"default-src 'none'; style-src 'unsafe-inline'; script-src {scripts}"


def _zoomable(context: ReportContext) -> bool:
    plots = list(context.plots) + list(context.power_plots)
    if context.answer is not None:
        plots += [context.answer.torque_plot, context.answer.speed_plot]
    if context.validation is not None:
        plots += list(context.validation.plots)
    return any(str(plot.svg).startswith('<svg class="plot" data-zoom="') for plot in plots)


def render_report(context: ReportContext) -> str:
    """The report as one HTML document (a string)."""
    script = zoom_script() if _zoomable(context) else None
    sections = _sections(context)
    numbers_ = {section_id: index for index, (section_id, _) in enumerate(sections, start=1)}
    template = environment().get_template("report.html")
    return template.render(
        ctx=context,
        header=context.header,
        sections=[(section_id, numbers_[section_id], title) for section_id, title in sections],
        number=numbers_,
        setting_units=SETTING_UNITS,
        lexer_css=Markup(lexer_css()),
        zoom_script=script,
        csp=content_security_policy(script),
    )


# ---------------------------------------------------------------- builders of the pieces

def source_sha256(text: str) -> str:
    """Hex SHA-256 of a source text (UTF-8)."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def parameter_rows(graph: BondGraph) -> list[ParameterRow]:
    """The graph's parameters, each in the unit it was written in."""
    return [ParameterRow(p.name, p.value / p.display_factor, p.unit_text, p.description)
            for p in graph.parameters.values()]


def causality_rows(causal: Any) -> list[CausalityRow]:
    """A :class:`bondc.causality.CausalGraph` as table rows, one per bond."""
    graph = causal.graph
    rows = []
    for bond in graph.bonds:
        notes = []
        for name in (bond.tail, bond.head):
            if name in causal.storage:
                notes.append(f"{graph.elements[name].kind} {name}: {causal.storage[name]}")
            elif name in causal.resistors:
                notes.append(f"R {name}: {causal.resistors[name]}")
        effort = causal.effort_setter[bond.number]
        flow = bond.head if effort == bond.tail else bond.tail
        rows.append(CausalityRow(bond.number, bond.label, bond.tail, bond.head, effort, flow, "; ".join(notes)))
    return rows


def causality_notes(causal: Any) -> list[str]:
    """The causality stage's warnings and notes (derivative causality, algebraic loops) as text."""
    return [f"{d.code}: {d.message}" + (f" ({d.hint})" if d.hint else "") for d in causal.diagnostics]


# -- plots

def _svg_ids_prefixed(svg: str, prefix: str) -> str:
    """Prefix every id (and reference to it) so several inline SVGs never share one."""
    ids = re.findall(r'\bid="([^"]+)"', svg)
    if not ids:
        return svg
    pattern = re.compile(r'(\bid="|href="#|url\(#)(%s)(?=[")])' % "|".join(re.escape(i) for i in sorted(ids, key=len, reverse=True)))
    return pattern.sub(lambda m: f"{m.group(1)}{prefix}-{m.group(2)}", svg)


def decimation_indices(t: np.ndarray, series: Sequence[np.ndarray], max_points: int) -> np.ndarray | None:
    """Indices of the samples worth drawing when there are more than ``max_points``; None keeps all.

    The time axis is cut into equal intervals; each keeps its first and last
    sample and, for every series, its smallest and largest value, so peaks,
    steps and corners survive exactly while a 7000-step run draws in a
    fraction of the points.

    >>> t = np.linspace(0, 1, 10001)
    >>> kept = decimation_indices(t, [np.sin(40 * t)], 1000)
    >>> peak_kept = np.isclose(np.sin(40 * t[kept]).max(), np.sin(40 * t).max())
    >>> len(kept) <= 1000, int(kept[0]), int(kept[-1]), bool(peak_kept)
    (True, 0, 10000, True)
    """
    if t.size <= max_points:
        return None
    buckets = max(max_points // (2 + 2 * max(len(series), 1)), 1)
    edges = np.linspace(t[0], t[-1], buckets + 1)[1:-1]
    bucket = np.searchsorted(edges, t, side="right")               # the interval of every sample
    change = np.flatnonzero(np.diff(bucket)) + 1
    kept = [np.array([0, t.size - 1]), change, change - 1]         # first and last sample of each interval
    for values in series:
        values = np.asarray(values, dtype=float)
        for extreme in (np.where(np.isnan(values), np.inf, values), np.where(np.isnan(values), -np.inf, -values)):
            order = np.lexsort((extreme, bucket))                  # by interval, smallest first within it
            first = np.concatenate(([True], np.diff(bucket[order]) != 0))
            kept.append(order[first])
    return np.unique(np.concatenate(kept).astype(int))


#: Most markers of a scatter plot (e.g. a cycle's operating points): more are thinned by
#: :func:`scatter_indices` and the caption says how many of how many are shown.
MAX_MARKERS = 2500


def scatter_indices(x: npt.ArrayLike, y: npt.ArrayLike, max_points: int = MAX_MARKERS,
                    cells: tuple[int, int] = (400, 225)) -> np.ndarray:
    """Indices of at most ``max_points`` of the points (x, y) that draw the same cloud: one point per
    occupied cell of a grid over their range (the grid halved until few enough cells are occupied),
    and always the points with the smallest and largest x and y. Non-finite points are left out.

    A grid of 400 x 225 cells over a 6.4 x 3.6 in plot is about a point (1/72 in) a cell, less than
    a 2-point marker: what is drawn looks like all the points, at a fraction of the size.

    >>> rng = np.random.default_rng(0)
    >>> x, y = rng.normal(size=100_000), rng.normal(size=100_000)
    >>> kept = scatter_indices(x, y, 2000)
    >>> len(kept) <= 2000, bool(x[kept].max() == x.max() and y[kept].min() == y.min())
    (True, True)
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    finite = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    if finite.size <= max_points:
        return finite
    fx, fy = x[finite], y[finite]
    extremes = finite[[np.argmin(fx), np.argmax(fx), np.argmin(fy), np.argmax(fy)]]
    nx, ny = cells
    while True:
        def cell(values, n):
            low, span = values.min(), np.ptp(values)
            return np.zeros(values.size, dtype=np.int64) if span == 0 else \
                np.minimum(((values - low) / span * n).astype(np.int64), n - 1)
        _, first = np.unique(cell(fx, nx) * ny + cell(fy, ny), return_index=True)
        if first.size + 4 <= max_points or (nx == 1 and ny == 1):
            break
        nx, ny = max(nx // 2, 1), max(ny // 2, 1)
    return np.unique(np.concatenate([finite[first], extremes]))


#: Most samples a plot draws of each series (the rest thinned by :func:`decimation_indices`, which
#: keeps every interval's extremes: about 750 intervals, more than a full-width plot has pixels).
DISPLAY_POINTS = 3000

#: Most samples of each series a plot carries for zooming (``data-zoom``): the zoomed view is drawn from
#: them, so a tenfold zoom still shows each interval's extremes at about the screen's resolution.
ZOOM_POINTS = 16000


def plot_svg(t: npt.ArrayLike, series: Mapping[str, npt.ArrayLike], title: str, ylabel: str,
             xlabel: str = "t [s]", show_title: bool = False, size: tuple[float, float] = FULL_SIZE,
             max_points: int = DISPLAY_POINTS, styles: Mapping[str, Mapping[str, Any]] | None = None,
             zoom_points: int = ZOOM_POINTS, hlines: Sequence[HLine] = (),
             ylim: tuple[float, float] | None = None, legend_above: bool = False) -> Markup:
    """A line plot of ``series`` (label -> values over ``t``) as an inline SVG element.

    Each series is drawn with at most ``max_points`` of its samples, thinned
    with :func:`decimation_indices` (every interval's first, last, smallest and
    largest sample: peaks survive, a 2 kHz PWM keeps its extremes). ``styles``
    gives matplotlib line properties per label (e.g. ``{"measured": {"color":
    "#8c959f"}}``).

    ``hlines`` are horizontal lines across the whole plot (:class:`HLine`: a limit, a level); they
    stay where they are when the plot is zoomed along x. ``ylim`` fixes the y range; ``legend_above``
    puts the legend above the plot, in columns, where it hides nothing.

    A plot of lines (no markers) can be zoomed along x in the report (see
    ``templates/zoom.js``): the ``<svg>`` carries ``data-zoom``, a JSON of
    numbers only (no label or other text of the model or data) with the data
    area, the x range and each series thinned to ``zoom_points`` samples
    (:func:`zoom_data`); ``zoom_points=0`` leaves it out.

    Drawn with matplotlib's object-oriented API and its SVG canvas, never
    through pyplot, so no GUI backend is selected whatever ``MPLBACKEND`` says
    and no global figure state is touched. Text stays text (``svg.fonttype = none``), ids are deterministic and
    unique to the plot's content, there is no XML prolog, DOCTYPE, metadata
    or external reference, and the document-wide ``<style>`` matplotlib adds
    is replaced by attributes. The title goes into ``<title>`` (and is drawn
    only with ``show_title``; a report's caption shows it).
    """
    import matplotlib
    from matplotlib.figure import Figure

    t = np.asarray(t, dtype=float)
    digest = hashlib.sha256(repr((title, ylabel, xlabel, max_points, zoom_points, tuple(hlines), ylim)).encode())
    digest.update(t.tobytes())
    arrays = {}
    for label, values in series.items():
        values = np.asarray(values, dtype=float)
        if values.shape != t.shape:
            raise ValueError(f"plot '{title}': series '{label}' has {values.size} values for {t.size} times")
        arrays[label] = values
        digest.update(str(label).encode())
        digest.update(values.tobytes())
    key = digest.hexdigest()
    styles = styles or {}
    zoomable = zoom_points > 0 and t.size >= 2 and bool(arrays) and float(t.max()) > float(t.min()) and not any(
        str(style.get("marker", "none")).lower() not in ("", "none") for style in styles.values())

    # text.parse_math off: labels come from model and data files; a header "$\\foo$" is not mathtext.
    # path.simplify off: the samples are thinned already, and every extreme kept must be drawn.
    with matplotlib.rc_context({**PLOT_STYLE, "svg.hashsalt": key, "path.simplify": False}):
        figure = Figure(figsize=size, layout="constrained")
        axes = figure.add_subplot()
        for number, (label, values) in enumerate(arrays.items()):
            kept = decimation_indices(t, [values], max_points)
            shown = slice(None) if kept is None else kept
            axes.plot(t[shown], values[shown], label=str(label), gid=f"zoomline{number}",
                      **dict(styles.get(label, {})))
        for line in hlines:
            axes.axhline(line.value, label=line.label if line.legend else "_" + line.label,
                         gid=line.gid or None, **dict(line.style))
        axes.set_xlabel(xlabel)
        axes.set_ylabel(ylabel)
        if t.size:
            axes.set_xlim(float(t.min()), float(t.max()))
        if ylim is not None:
            axes.set_ylim(*ylim)
        if show_title:
            axes.set_title(title, loc="left")
        if len(arrays) + sum(line.legend for line in hlines) > 1:
            if legend_above:
                legend_on_top(axes)
            elif size[0] >= FULL_SIZE[0]:     # room beside a full-width plot: the legend never hides a curve
                axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
            else:
                axes.legend(loc="best")
        svg = figure_svg(figure, title, key)
        if not zoomable:
            return svg
        attribute = html.escape(zoom_data(figure, axes, t, list(arrays.values()), zoom_points), quote=True)
        return Markup(str(svg).replace('<svg class="plot" ', f'<svg class="plot" data-zoom="{attribute}" ', 1))


def zoom_data(figure, axes, t: np.ndarray, series: Sequence[np.ndarray], max_points: int) -> str:
    """The JSON a zoomable plot carries (after ``figure`` was drawn, so its layout is final).

    ``box``: the data area in the SVG's units (x, y of its top left corner, width, height);
    ``x``: the x range it shows; ``lines``: per series (in order: the ``zoomline<i>`` groups) its
    samples thinned to ``max_points`` with :func:`decimation_indices`, in one base64 string
    (:func:`zoom_samples` reads it): zlib of the differences of x as uint32 fractions of the x
    range (0 to 2**32 - 1), then of y as uint16 fractions of the data area's height from its
    bottom (0 to 65534; 65535 is a gap: NaN), little-endian, each difference modulo 2**32 or 2**16.
    Differences compress some sevenfold. Only numbers and base64: nothing of the model's or the
    data's text.
    """
    import base64
    import json
    import zlib

    width, height = figure.get_size_inches() * 72.0          # the SVG's units are points
    box = axes.get_position()
    x0, x1 = (float(v) for v in axes.get_xlim())
    y0, y1 = (float(v) for v in axes.get_ylim())
    lines = []
    for values in series:
        kept = decimation_indices(t, [values], max_points)
        times, values = (t, values) if kept is None else (t[kept], values[kept])
        fx = np.clip((times - x0) / (x1 - x0), 0.0, 1.0)
        fy = np.clip((values - y0) / (y1 - y0) if y1 > y0 else np.full(values.shape, 0.5), 0.0, 1.0)
        qx = np.round(fx * 4294967295.0).astype(np.uint32)
        qy = np.where(np.isfinite(values), np.round(np.nan_to_num(fy) * 65534.0), 65535).astype(np.uint16)
        raw = (np.diff(qx, prepend=np.uint32(0)).astype("<u4").tobytes()
               + np.diff(qy, prepend=np.uint16(0)).astype("<u2").tobytes())
        lines.append(base64.b64encode(zlib.compress(raw, 9)).decode("ascii"))
    data = {"box": [round(box.x0 * width, 3), round((1.0 - box.y1) * height, 3), round(box.width * width, 3),
                    round(box.height * height, 3)],
            "x": [x0, x1], "lines": lines}
    return json.dumps(data, separators=(",", ":"), allow_nan=False)


def zoom_samples(text: str) -> tuple[np.ndarray, np.ndarray]:
    """One line of :func:`zoom_data` back as arrays: x as uint32 fractions of the x range, y as uint16
    fractions of the data area's height (65535: a gap), as ``templates/zoom.js`` reads them."""
    import base64
    import zlib

    raw = zlib.decompress(base64.b64decode(text))
    n = len(raw) // 6
    x = np.cumsum(np.frombuffer(raw[:4 * n], dtype="<u4"), dtype=np.uint32)
    y = np.cumsum(np.frombuffer(raw[4 * n:], dtype="<u2"), dtype=np.uint16)
    return x, y


PLOT_STYLE = {"svg.fonttype": "none", "text.parse_math": False, "axes.spines.top": False,
              "axes.spines.right": False, "axes.grid": True, "grid.color": "#dddddd", "grid.linewidth": 0.6,
              "font.size": 9, "axes.titlesize": 10, "legend.frameon": False, "lines.linewidth": 1.4}


def draw_motor_envelopes(axes, catalogue, speed_label: str = "speed [rpm]") -> None:
    """Each catalogue motor's continuous envelope (its rated torque up to its rated speed, solid,
    labelled "NAME continuous") and peak envelope (its peak torque, dashed), on torque-speed axes
    in N*m and rpm (as catalogues give speeds), which start at 0."""
    for number, motor in enumerate(catalogue):
        rated = motor.rated_speed
        color = f"C{number % 10}"
        axes.plot([0, rated, rated], [motor.rated_torque, motor.rated_torque, 0], color=color, linewidth=1.0,
                  label=f"{motor.name} continuous")
        axes.plot([0, rated], [motor.peak_torque, motor.peak_torque], color=color, linewidth=1.0, linestyle="--")
    axes.set_xlabel(speed_label)
    axes.set_ylabel("torque [N*m]")
    axes.set_xlim(left=0)
    axes.set_ylim(bottom=0)
    axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)


#: Colours of the answer's plots: the motor's limits (its envelope), the cycle's operating points and
#: its torque over time, and the RMS torque. The operating points' orange is no envelope's colour.
LIMIT_COLOR, POINTS_COLOR, RMS_COLOR = "#0550ae", "#d4700a", "#1f2328"


def legend_on_top(axes, columns: int = 2) -> None:
    """The legend above the data area, in ``columns`` columns: it never hides a line or a point."""
    axes.legend(loc="lower left", bbox_to_anchor=(0.0, 1.01, 1.0, 0.2), mode="expand", ncol=columns,
                borderaxespad=0.0, fontsize=7.5, handlelength=2.2, columnspacing=1.0)


def draw_motor_envelope(axes, motor, color: str = LIMIT_COLOR) -> None:
    """One motor's continuous envelope (solid: the rated torque up to the rated speed, constant power
    up to the top speed) and peak envelope (dashed, the same shape from the peak torque), both in the
    legend, on torque-speed axes in N*m and rpm."""
    top = float(motor.top_speed)
    speeds = np.array([0.0, float(motor.rated_speed)])
    if top > motor.rated_speed:
        speeds = np.concatenate([speeds, np.linspace(motor.rated_speed, top, 24)[1:]])
    for torque_at, label, style, gid in ((motor.continuous_torque_at, "continuous", "-", "envelope-continuous"),
                                         (motor.peak_torque_at, "peak", "--", "envelope-peak")):
        torques = np.asarray(torque_at(speeds), dtype=float)
        axes.plot(np.append(speeds, top), np.append(torques, 0.0), color=color, linewidth=1.3, linestyle=style,
                  label=f"{motor.name} {label}", gid=gid)


def _short_path(match: re.Match) -> str:
    """A path's ``d`` on one line with coordinates to 0.01 pt (matplotlib writes 1e-6 pt, a line each):
    a third of the size, the same drawing."""
    d = re.sub(r"-?\d+\.\d+", lambda m: f"{float(m.group()):.2f}".rstrip("0").rstrip("."), match.group(1))
    return f' d="{" ".join(d.split())}"'


def figure_svg(figure, title: str, key: str) -> Markup:
    """A matplotlib ``Figure`` as an inline SVG element, as :func:`plot_svg` makes them: text as
    text, ids deterministic (from ``key``) and unique, no prolog, metadata or external reference,
    the title in ``<title>``. Call it inside ``matplotlib.rc_context(PLOT_STYLE | {"svg.hashsalt": key})``."""
    buffer = io.StringIO()
    figure.savefig(buffer, format="svg", metadata={"Date": None, "Creator": None, "Format": None, "Type": None})
    svg = buffer.getvalue()
    svg = svg[svg.index("<svg"):]
    svg = re.sub(r"<metadata>.*?</metadata>\s*", "", svg, flags=re.S)
    svg = re.sub(r'\s*<defs>\s*<style type="text/css">[^<]*</style>\s*</defs>', "", svg, count=1)
    svg = svg.replace("<svg ", '<svg class="plot" role="img" stroke-linejoin="round" stroke-linecap="butt" ', 1)
    svg = _svg_ids_prefixed(svg, "plot" + key[:8])
    svg = re.sub(r'\sd="([^"]*)"', _short_path, svg)
    # A <title> as the first child names the figure for screen readers and tooltips.
    head_end = svg.index(">", svg.index("<svg")) + 1
    svg = svg[:head_end] + f"\n <title>{html.escape(title, quote=False)}</title>" + svg[head_end:]
    return Markup(svg.strip())


# -- MathML

def _presentation_printer():
    from sympy.printing.mathml import MathMLPresentationPrinter

    class Printer(MathMLPresentationPrinter):
        """sympy's presentation printer with ``Piecewise`` as a brace over cases.

        A name with several underscores keeps them after the first:
        ``a_up_meas`` is *a* with the subscript ``up_meas`` (sympy would write
        ``up meas``), so a reader finds the name of the model source.
        """

        def _print_Symbol(self, sym, style="plain"):
            head, _, rest = sym.name.partition("_")
            if head and "_" in rest and "^" not in sym.name and not rest.endswith("_"):
                import sympy

                node = self.dom.createElement("msub")
                node.appendChild(self._print(sympy.Symbol(head)))
                sub = self.dom.createElement("mi")
                sub.appendChild(self.dom.createTextNode(rest))
                node.appendChild(sub)
                return node
            return super()._print_Symbol(sym, style)

        def _print_Piecewise(self, expr):
            row = self.dom.createElement("mrow")
            brace = self.dom.createElement("mo")
            brace.setAttribute("stretchy", "true")
            brace.appendChild(self.dom.createTextNode("{"))
            row.appendChild(brace)
            table = self.dom.createElement("mtable")
            table.setAttribute("columnalign", "left left")
            for value, condition in expr.args:
                line = self.dom.createElement("mtr")
                cell = self.dom.createElement("mtd")
                cell.appendChild(self._print(value))
                line.appendChild(cell)
                cell = self.dom.createElement("mtd")
                if condition is True or getattr(condition, "is_Boolean", False) and str(condition) == "True":
                    text = self.dom.createElement("mtext")
                    text.appendChild(self.dom.createTextNode("otherwise"))
                    cell.appendChild(text)
                else:
                    inner = self.dom.createElement("mrow")
                    text = self.dom.createElement("mtext")
                    text.appendChild(self.dom.createTextNode("if\u2002"))
                    inner.appendChild(text)
                    inner.appendChild(self._print(condition))
                    cell.appendChild(inner)
                line.appendChild(cell)
                table.appendChild(line)
            row.appendChild(table)
            return row

    return Printer


_ENTITY = re.compile(r"&(#x[0-9A-Fa-f]+|#[0-9]+|[A-Za-z][A-Za-z0-9]*);")


#: Entities written as plain characters rather than their Unicode symbol: the differential
#: ``&dd;`` (U+2146, missing from most fonts) is an upright d.
_PLAIN_ENTITIES = {"dd": "d"}


def _decode_entities(text: str) -> str:
    """sympy writes some symbols as entity text (``&pi;``, ``&dd;``); make them characters."""
    return _ENTITY.sub(lambda m: _PLAIN_ENTITIES.get(m.group(1)) or html.unescape(m.group(0)), text)


def _to_etree(node) -> ET.Element:
    """A minidom element -> ElementTree, so that serialisation escapes every text."""
    element = ET.Element(node.tagName, {k: v for k, v in node.attributes.items()})
    last = None
    for child in node.childNodes:
        if child.nodeType == child.TEXT_NODE:
            text = _decode_entities(child.data)
            if last is None:
                element.text = (element.text or "") + text
            else:
                last.tail = (last.tail or "") + text
        elif child.nodeType == child.ELEMENT_NODE:
            last = _to_etree(child)
            element.append(last)
    return element


def math_markup(expr: Any, display: str = "block") -> Markup:
    """A sympy expression as a ``<math>`` element (presentation MathML), every text escaped.

    sympy's own serialiser writes text unescaped (a symbol ``a<b`` would become
    markup), so the printer's DOM is re-serialised with ElementTree.

    >>> import sympy
    >>> str(math_markup(sympy.Symbol("a<b"), display="inline"))
    '<math display="inline"><mi>a&lt;b</mi></math>'
    """
    printer = _presentation_printer()({"mul_symbol": "dot"})
    tree = _to_etree(printer._print(expr))
    root = ET.Element("math", {"display": display})
    root.append(tree)
    return Markup(ET.tostring(root, encoding="unicode", short_empty_elements=False))


def equation_markup(lhs: Any, rhs: Any, display: str = "block") -> Markup:
    """``lhs = rhs`` as MathML (no evaluation of the equality)."""
    import sympy

    return math_markup(sympy.Eq(lhs, rhs, evaluate=False), display=display)

