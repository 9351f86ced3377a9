"""Reports: a simulated, checked model -> one self-contained HTML file.

The building blocks, each taking plain values and returning text:

- :mod:`bondc.report.lexer`: ``.bg`` source -> highlighted HTML (Pygments);
- :mod:`bondc.report.diagram`: BondGraph (+ causality) -> SVG drawing;
- :mod:`bondc.report.validate`: simulated signals + measured CSV -> metrics,
  pass/fail and JUnit XML;
- :mod:`bondc.report.render`: :class:`ReportContext` -> HTML, through the Jinja
  templates in ``bondc/report/templates`` (plus plots and MathML helpers).
"""

from bondc.report.diagram import bond_graph_svg
from bondc.report.lexer import highlight_bg, lexer_css
from bondc.report.render import ReportContext, ReportHeader, plot_svg, render_report

__all__ = ["highlight_bg", "lexer_css", "bond_graph_svg", "ReportContext", "ReportHeader", "plot_svg",
           "render_report"]
