"""Reports: a simulated, checked model -> one self-contained HTML file.

The building blocks, each taking plain values and returning text:

- :mod:`bondc.report.lexer`: ``.bg`` source -> highlighted HTML (Pygments);
- :mod:`bondc.report.diagram`: BondGraph (+ causality) -> SVG drawing;
- :mod:`bondc.analysis.validate`: simulated signals + measured CSV -> metrics,
  pass/fail and JUnit XML;
- :mod:`bondc.report.render`: :class:`ReportContext` -> HTML, through the Jinja
  templates in ``bondc/report/templates`` (plus plots and MathML helpers);
- :mod:`bondc.report.build`: a ``.bg`` file -> the whole pipeline -> one HTML
  file written atomically (:func:`build_report`, ``bondc report``), and
  validation against measured data (:func:`run_validate`, ``bondc validate``).
"""

from bondc.report.build import build_report, run_report, run_validate
from bondc.report.diagram import bond_graph_svg
from bondc.report.lexer import highlight_bg, lexer_css
from bondc.report.render import ReportContext, ReportHeader, plot_svg, render_report

__all__ = ["highlight_bg", "lexer_css", "bond_graph_svg", "ReportContext", "ReportHeader", "plot_svg",
           "render_report", "build_report", "run_report", "run_validate"]
