"""Report stage: a ``.bg`` file -> one self-contained HTML report, and validation against measurements.

:func:`build_report` is ``bondc report`` without argument parsing. It runs the
whole pipeline (:func:`bondc.pipeline.run_pipeline`: load with the experiment's overrides,
causality, equations, simulation), gathers what a reader needs into a
:class:`~bondc.report.render.ReportContext` (:func:`report_context`: header,
highlighted source, parameters, the bond graph with causal strokes, the
causality table, the state equations as MathML, plots of the outputs, power
of every source, store and dissipator, the energy per cycle with its balance,
the motor requirements and candidates, the validation against measured data)
and writes one HTML file. The file is written atomically: it is rendered in
full first and then renamed over the target, so a failure at any stage leaves
an earlier report as it was.

A simulation that stops early does not stop the report: it shows what was
computed up to that point under a prominent "incomplete simulation" notice
with the diagnostic. :func:`run_report` is the command-line wrapper: it also
prints the run's diagnostics and returns an exit code (1 for an incomplete
simulation).

:func:`run_validate` is ``bondc validate``: it simulates, compares simulated
signals with measured columns (:func:`bondc.analysis.validate.compare`), prints
a table, writes JUnit XML and, on request, the report with a validation
section; its exit code is 1 when any signal fails (or the run is incomplete).

Measured values are compared in SI units, as ``bondc simulate`` writes them;
a comparison may name an output, a state (``mass.p``), an input or a bond
variable (``b3.e``).

>>> from pathlib import Path
>>> import tempfile
>>> model = Path(__file__).parents[2] / "tests/fixtures/sim/rc.bg"
>>> target = build_report(model, output=Path(tempfile.mkdtemp()) / "rc.html", date="2024-01-01")
>>> html = target.read_text(encoding="utf-8")
>>> html.startswith("<!DOCTYPE html>"), html.count("<script"), "<math" in html   # the script: zoom.js
(True, 1, True)
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence, TextIO

import numpy as np
import sympy
from markupsafe import Markup

from bondc.errors import Diagnostic, UsageError, render as render_diagnostic
from bondc.io import atomic_write_text, check_output
from bondc.model import KINDS, BondGraph, ExperimentDef
from bondc.pipeline import PipelineRun, run_pipeline
from bondc.report.diagram import bond_graph_svg
from bondc.report.lexer import highlight_bg
from bondc.report.render import (
    FULL_SIZE, HALF_SIZE, Answer, BodeSection, CandidateRow, Equation, HLine, ParameterRow, Plot, ReportContext, ReportHeader,
    RuleMargin, Table, ValidationSection,
    causality_notes, causality_rows, equation_markup, parameter_rows, plot_svg, render_report,
)
from bondc.analysis.validate import (
    TIME_KEY, CompareSpec, SignalResult, check_quantity, compare, load_measured_csv, parse_compare_spec, signal_unit,
    simulated_signals, write_junit,
)
from bondc.symbolic import Translator, as_sympy

if TYPE_CHECKING:
    from bondc.simulate import SimResult

__all__ = ["PipelineRun", "run_pipeline", "report_context", "build_report", "run_report", "default_output",
           "write_report", "run_validate", "report_summary", "report_text", "validate_summary",
           "validate_text", "signal_json",
           "compare_run", "validation_table", "state_equations", "output_groups", "REPORTS_DIR"]

#: Frequencies of each Bode plot in a report (the plot is small; ``bondc bode`` takes 400 by default).
REPORT_BODE_POINTS = 150

#: Where reports go unless ``output`` says otherwise (relative to the working directory).
REPORTS_DIR = Path("reports")

#: Most series drawn in one plot; signals that share a unit are drawn together up to this.
MAX_SERIES_PER_PLOT = 4

#: Signals sharing a unit are drawn apart when their peak magnitudes differ more than this.
MAX_MAGNITUDE_RATIO = 5.0

#: Element laws whose expanded form has more operations than this are kept as named
#: quantities in the state equations and written out once under "where".
LAW_OPERATIONS = 8


# ---------------------------------------------------------------- where it goes

def _steps(run: PipelineRun) -> SimResult:
    """The run at the solver's steps and between them (:func:`~bondc.analysis.energy.dense_steps`):
    statistics and motor requirements are computed from it, plots show ``run.result``."""
    from bondc.analysis.energy import dense_steps

    return dense_steps(run.state_space, run.result)


def default_output(path: str | Path, run: PipelineRun) -> Path:
    """``reports/<file stem>.html``, or ``reports/<stem>-<experiment>.html`` for an experiment not the first."""
    stem = Path(path).stem
    if run.experiment is not None and not run.default_experiment:
        stem = f"{stem}-{run.experiment.name}"
    return REPORTS_DIR / f"{stem}.html"


# ---------------------------------------------------------------- building and writing

def build_report(path: str | Path, *, model: str | None = None, experiment: str | None = None,
                 sets: Sequence = (), data: str | Path | None = None, compare: Sequence[str | CompareSpec] = (),
                 motors: str | Path | None = None, output: str | Path | None = None,
                 t_end: float | None = None, date: str | None = None, progress: bool = False,
                 inertia_ratio: float | None = None, ratio: str | None = None, jobs: int = 1) -> Path:
    """``bondc report``: run the pipeline and write one self-contained HTML report; returns its path.

    ``data`` (a measured CSV) with ``compare`` (``OUT=COLUMN[:nrmse=0.05]``
    texts or :class:`CompareSpec`) adds a validation section; failing
    signals are shown, not raised. ``motors`` is a motor catalogue CSV: the
    report judges its motors against the cycle (a model with signals named
    ``torque`` and ``omega`` always gets the motor requirements). ``output``
    defaults to :func:`default_output`; missing directories are made.
    ``inertia_ratio`` is the load/rotor inertia-ratio limit of every motor
    (``--inertia-ratio``; default: the catalogue's, else 10). ``ratio``
    (``--ratio lead=2,5,10 [mm]``, with ``motors``) adds how the smallest
    qualifying motor changes with the transmission ratio
    (:mod:`bondc.analysis.ratio`), its values run on ``jobs`` processes.
    ``t_end`` [s] overrides the experiment's end time, ``date`` the date in
    the header (ISO, default today).

    Bad measured data raises :class:`~bondc.errors.DataError` before anything
    is simulated; a model error raises its stage's error. Either way nothing
    is written and an earlier report stays as it was.
    """
    target, _, _, _ = _build(path, model=model, experiment=experiment, sets=sets, data=data, compare=compare,
                          motors=motors, output=output, t_end=t_end, date=date, progress=progress,
                          inertia_ratio=inertia_ratio, ratio=ratio, jobs=jobs)
    return target


def _build(path, *, model, experiment, sets, data, compare, motors, output, t_end, date,
           progress, inertia_ratio=None, ratio=None,
           jobs=1) -> tuple[Path, PipelineRun, list[SignalResult], Any]:
    from bondc.analysis.ratio import check_ratio, ratio_study

    check_ratio(ratio, motors)
    specs, measured = _measured(data, compare)
    run = run_pipeline(path, model=model, experiment=experiment, sets=sets, t_end=t_end, progress=progress)
    study = None
    if ratio is not None and run.result is not None:
        study = ratio_study(path, ratio, motors=motors, model=model, experiment=experiment, sets=sets,
                            t_end=t_end, inertia_ratio=inertia_ratio, jobs=jobs, progress=progress)
    target = Path(output) if output is not None else default_output(path, run)
    results: list[SignalResult] = []
    try:
        validation = None
        if specs:
            results = compare_run(run, measured, specs)
            validation = validation_section(run, results, data)
        write_report(report_context(run, validation=validation, motors=motors, date=date,
                                    inertia_ratio=inertia_ratio, ratio=study), target)
    except KeyboardInterrupt as interrupt:
        _keep_simulation(run, target, interrupt)
        raise
    return target, run, results, study


def _keep_simulation(run: PipelineRun, target: Path, interrupt: KeyboardInterrupt) -> None:
    """Ctrl-C or SIGTERM after the simulation, while the report was being built: write the simulated
    results next to the report (``<report stem>.interrupted.csv``, as ``bondc simulate`` writes them)
    and say so, so that the run is not lost; the report itself is left as it was."""
    from bondc.simulate import write_csv

    if run.result is None or not len(run.result.t):
        return
    kept = target.with_name(target.stem + ".interrupted.csv")
    try:
        write_csv(run.result, kept)
    except (OSError, UsageError):
        return
    state = "complete" if run.result.complete else "incomplete"
    setattr(interrupt, "kept", kept)
    print(f"report: interrupted while building the report; the simulation ({len(run.result.t)} points to "
          f"t = {float(run.result.t[-1]):.6g} s, {state}) is kept in {kept}", file=sys.stderr)


def run_report(path: str | Path, *, model: str | None = None, experiment: str | None = None,
               sets: Sequence = (), data: str | Path | None = None, compare: Sequence[str | CompareSpec] = (),
               motors: str | Path | None = None, output: str | Path | None = None, t_end: float | None = None,
               date: str | None = None, progress: bool = False,
               errors: TextIO | None = None, inertia_ratio: float | None = None,
               ratio: str | None = None, jobs: int = 1) -> tuple[Path, int]:
    """``bondc report`` for the command line: :func:`build_report`, then tell the user; returns (path, exit code).

    Prints the run's warnings (and an incomplete simulation's diagnostic)
    with their source context, then ``wrote PATH``, to ``errors`` (stderr).
    The exit code is 0, or 1 when the simulation stopped early or a compared
    signal fails its tolerances (the report is written all the same, with its
    notice and the validation section), as ``bondc validate`` exits.
    """
    errors = errors if errors is not None else sys.stderr
    summary = report_summary(path, model=model, experiment=experiment, sets=sets, data=data, compare=compare,
                             motors=motors, output=output, t_end=t_end, date=date, progress=progress,
                             errors=errors, inertia_ratio=inertia_ratio, ratio=ratio, jobs=jobs)
    print(report_text(summary), file=errors)
    return Path(summary["written"][0]), summary["exit_status"]


def report_summary(path: str | Path, *, model: str | None = None, experiment: str | None = None,
                   sets: Sequence = (), data: str | Path | None = None, compare: Sequence[str | CompareSpec] = (),
                   motors: str | Path | None = None, output: str | Path | None = None, t_end: float | None = None,
                   date: str | None = None, progress: bool = False,
                   errors: TextIO | None = None, inertia_ratio: float | None = None,
                   ratio: str | None = None, jobs: int = 1) -> dict:
    """:func:`run_report` without its last line: builds and writes the report, prints the run's
    warnings to ``errors``, and returns what ``bondc report --json`` prints: ``complete`` (the
    simulation ran to its end), ``written`` (the report's path), ``signals`` (with ``--data``: each
    compared signal, :func:`signal_json`), ``failing`` (their names), ``diagnostics`` and
    ``exit_status`` (as :func:`run_report` returns it)."""
    errors = errors if errors is not None else sys.stderr
    if output is not None:
        check_output(output, "the report", make_folder=True)
    target, run, results, study = _build(path, model=model, experiment=experiment, sets=sets, data=data,
                                  compare=compare, motors=motors, output=output, t_end=t_end, date=date,
                                  progress=progress, inertia_ratio=inertia_ratio, ratio=ratio, jobs=jobs)
    diagnostics = _print_diagnostics(run, errors)
    failing = [result.name for result in results if not result.passed]
    interrupted = getattr(run.result, "exit_status", None) if run.result is not None else None
    return {"complete": run.complete, "file": str(path), "model": run.graph.name,
            "experiment": run.experiment.name if run.experiment is not None else None,
            "written": [str(target)],
            "signals": [signal_json(result, signal_unit(run.graph, result.output)[0]) for result in results],
            "failing": failing, "diagnostics": [d.to_json() for d in diagnostics],
            **({"ratio": study.to_json()} if study is not None else {}),
            "exit_status": interrupted or (0 if run.complete and not failing else 1)}


def report_text(summary: Mapping) -> str:
    """``bondc report``'s line: ``wrote PATH``, and whether the run or a comparison failed."""
    failing = summary["failing"]
    ratio = summary.get("ratio")
    return ((ratio["sentence"] + "\n" if ratio else "")
            + f"wrote {summary['written'][0]}" + ("" if summary["complete"] else " (incomplete simulation)")
            + (f"; validation failed: {', '.join(failing)}" if failing else ""))


def signal_json(result: SignalResult, unit: str | None = None) -> dict:
    """One compared signal for ``--json``: its output and column, pass or fail, each metric and each
    check (metric, value, limit, passed); RMSE and the largest error in ``unit`` (the output's)."""
    return {"name": result.name, "output": result.output, "column": result.column, "passed": result.passed,
            "unit": unit, "samples": result.n_samples, "t_start": result.t_start, "t_end": result.t_end,
            "rmse": result.rmse, "nrmse": result.nrmse, "maxabs": result.maxabs, "r2": result.r2,
            "checks": [{"metric": check.metric, "value": check.value, "limit": check.limit,
                        "passed": check.passed} for check in result.checks]}


def _print_diagnostics(run: PipelineRun, stream: TextIO) -> list[Diagnostic]:
    from bondc.errors import render_all

    diagnostics = list(run.warnings)
    if run.result is not None and not run.result.complete:
        diagnostics.append(_failure(run))
    if diagnostics:
        print(render_all(diagnostics, run.graph.sources), file=stream)
    return diagnostics


def write_report(context: ReportContext, target: str | Path) -> None:
    """Render ``context`` in full, then replace ``target`` with it in one step (its directory is made)."""
    html = render_report(context)
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(target, html)


def _measured(data, compare_specs) -> tuple[list[CompareSpec], dict[str, np.ndarray] | None]:
    specs = [spec if isinstance(spec, CompareSpec) else parse_compare_spec(spec) for spec in compare_specs or ()]
    if data is None and specs:
        raise UsageError(Diagnostic("error", "E001", "--compare needs measured data",
                                    hint="give the measured CSV with --data FILE"))
    if data is not None and not specs:
        raise UsageError(Diagnostic("error", "E001", "--data needs at least one comparison",
                                    hint="say which simulated signal each measured column is: --compare OUT=COLUMN"))
    if data is None:
        return [], None
    return specs, load_measured_csv(data, columns=[spec.column for spec in specs])


# ---------------------------------------------------------------- validation

def unit_warnings(run: PipelineRun, measured, specs: Iterable[CompareSpec]) -> list[Diagnostic]:
    """W954: a measured column without a unit compared with an output declared in a non-SI unit —
    the column is taken as SI, which the engineer may not have meant."""
    units = getattr(measured, "units", {})
    found = []
    for spec in specs:
        output = run.graph.outputs.get(spec.output)
        if output is None or not output.unit_text or units.get(spec.column) is not None:
            continue
        if abs((output.display_factor or 1.0) - 1.0) > 1e-12:
            found.append(Diagnostic(
                "warning", "W954", f"measured column '{spec.column}' has no unit: it is taken as SI, while output "
                                   f"'{spec.output}' is declared in [{output.unit_text}]",
                hint=f"if the data is in {output.unit_text}, write the header as '{spec.column} "
                     f"[{output.unit_text}]'"))
    return found


def compare_run(run: PipelineRun, measured: Mapping[str, np.ndarray],
                specs: Iterable[CompareSpec]) -> list[SignalResult]:
    """:func:`~bondc.analysis.validate.compare` the run's signals with the measured columns, each pair
    in the signal's display unit (an output declared ``[mm]`` is compared in millimetres): its RMSE,
    largest error and the ``rmse``/``maxabs`` tolerances are in that unit, as the terminal table,
    the JUnit file and the report show them (NRMSE and R² do not depend on the unit). The
    comparison is at the measured samples the run covers (:func:`_at_measured_times`)."""
    if run.result is None:
        raise UsageError(Diagnostic("error", "E801", "no end time for the simulation",
                                    hint="give --t-end, or set t_end in the experiment"))
    t, signals = _at_measured_times(run, measured)
    results = []
    for spec in specs:
        check_quantity(run.graph, spec, getattr(measured, "units", {}).get(spec.column))
        _, factor = signal_unit(run.graph, spec.output)
        if spec.output not in signals or spec.column not in measured or factor == 1.0:
            results += compare(t, signals, measured, [spec])     # (its own errors, if any)
            continue
        shown = {spec.output: np.asarray(signals[spec.output], dtype=float) / factor}
        columns = {TIME_KEY: measured[TIME_KEY], spec.column: np.asarray(measured[spec.column], dtype=float) / factor}
        results += compare(t, shown, columns, [spec])
    return results


def _at_measured_times(run: PipelineRun, measured: Mapping[str, np.ndarray]) -> tuple[np.ndarray, dict]:
    """(times, signals) to compare at: the measured samples the run covers, the model evaluated there
    (the run repeated with those report times, from the solver's own interpolant), so that a
    measurement sampled more coarsely than the solver steps is compared sample by sample and not
    interpolated between them. The run's own points where that is not possible (fewer than two
    samples inside the run, more than a run may record, or a repeat that does not reach as far)."""
    from bondc.analysis.energy import repeat_run
    from bondc.runtime import MAX_POINTS

    result = run.result
    own = (np.asarray(result.t, dtype=float), simulated_signals(result))
    times = np.asarray(measured.get(TIME_KEY, ()), dtype=float)
    if not len(own[0]) or times.size < 2:
        return own
    inside = times[(times >= own[0][0]) & (times <= own[0][-1])]
    if inside.size < 2 or inside.size > MAX_POINTS:
        return own
    again = repeat_run(run.state_space, result, t_eval=inside)
    reached = np.asarray(again.t, dtype=float)
    if reached.size != inside.size or not np.array_equal(reached, inside):
        return own
    return reached, simulated_signals(again)


def validation_section(run: PipelineRun, results: Sequence[SignalResult], data_file,
                       junit_file=None) -> ValidationSection:
    """The report's validation section: the metrics, and per signal the curves overlaid and the error."""
    plots = []
    for result in results:
        unit, _ = signal_unit(run.graph, result.output)
        simulated, measured = result.simulated, result.measured      # (in the signal's unit: compare_run)
        title = f"{result.output} simulated and {result.column} measured"
        plots.append(Plot(title, _time_plot(
            result.t, {f"{result.column} (measured)": measured, f"{result.output} (simulated)": simulated},
            title, result.output + (f" [{plot_unit(unit)}]" if unit else " (SI)"), half=True,
            styles={f"{result.column} (measured)": {"color": "#8c959f", "linewidth": 1.0},
                    f"{result.output} (simulated)": {"color": "#0550ae", "linewidth": 1.4}}),
            f"NRMSE {result.nrmse:.3g}, R² {result.r2:.4g}: {'pass' if result.passed else 'FAIL'}", True))
        title = f"{result.output} error, simulated − measured"
        ylabel = "error" + (f" [{plot_unit(unit)}]" if unit else " (SI)")
        plots.append(Plot(title, _time_plot(result.t, {"error": simulated - measured}, title, ylabel, half=True,
                                            styles={"error": {"color": "#a40e26", "linewidth": 1.0}}),
                          f"Largest |error| {result.maxabs:.4g}{' ' + plot_unit(unit) if unit else ''}", True))
    return ValidationSection(results, str(data_file), plots, str(junit_file) if junit_file else None)


def validation_table(results: Sequence[SignalResult], units: Mapping[str, str | None] | None = None) -> str:
    """The metrics of every compared signal as a text table, then what failed; ``units``: each
    signal's display unit (RMSE and max |err| are in it; "SI" where it has none)."""
    units = units or {}
    header = ("signal", "measured", "unit", "samples", "RMSE", "NRMSE", "max |err|", "R²", "result")
    rows = [(r.output, r.column, units.get(r.output) or "SI", str(r.n_samples), f"{r.rmse:.4g}", f"{r.nrmse:.4g}",
             f"{r.maxabs:.4g}", f"{r.r2:.4g}", "pass" if r.passed else "FAIL") for r in results]
    widths = [max(len(cell) for cell in column) for column in zip(header, *rows)]
    numeric = {3, 4, 5, 6, 7}

    def line(cells):
        return "  ".join(cell.rjust(w) if i in numeric else cell.ljust(w)
                         for i, (cell, w) in enumerate(zip(cells, widths))).rstrip()

    lines = [line(header), line(["-" * w for w in widths])] + [line(row) for row in rows]
    for result in results:
        for check in result.checks:
            if not check.passed:
                lines.append(f"{result.name}: {check.describe()}")
    failed = sum(not r.passed for r in results)
    lines.append(f"{len(results) - failed} of {len(results)} signal{'s' if len(results) != 1 else ''} passed")
    return "\n".join(lines)


def run_validate(path: str | Path, *, data: str | Path, compare: Sequence[str | CompareSpec],
                 junit: str | Path | None = None, output: str | Path | None = None, model: str | None = None,
                 experiment: str | None = None, sets: Sequence = (), t_end: float | None = None,
                 motors: str | Path | None = None, date: str | None = None, stream: TextIO | None = None,
                 errors: TextIO | None = None, progress: bool = False,
                 inertia_ratio: float | None = None) -> tuple[list[SignalResult], int]:
    """``bondc validate``: simulate, compare with the measured data, report; returns (results, exit code).

    Prints :func:`validation_table` to ``stream`` (stdout) and the run's
    warnings, with an incomplete simulation's diagnostic, to ``errors``
    (stderr); writes JUnit XML to ``junit`` (one test case per signal) and
    the HTML report with its validation section to ``output`` when given.
    The exit code is 0 when every signal passes, 1 when one fails or the
    simulation stopped early. Raises DataError for bad measured data
    (missing column, time not increasing, no overlap in time) and the
    stages' errors for a bad model; then nothing is written.
    """
    stream = stream if stream is not None else sys.stdout
    results, summary = validate_summary(path, data=data, compare=compare, junit=junit, output=output, model=model,
                                        experiment=experiment, sets=sets, t_end=t_end, motors=motors, date=date,
                                        errors=errors, progress=progress, inertia_ratio=inertia_ratio)
    print(validate_text(results, summary), file=stream)
    return results, summary["exit_status"]


def validate_text(results: Sequence[SignalResult], summary: Mapping) -> str:
    """``bondc validate``'s table (:func:`validation_table`, each output in its declared unit)."""
    return validation_table(results, {signal["output"]: signal["unit"] for signal in summary["signals"]})


def validate_summary(path: str | Path, *, data: str | Path, compare: Sequence[str | CompareSpec],
                     junit: str | Path | None = None, output: str | Path | None = None, model: str | None = None,
                     experiment: str | None = None, sets: Sequence = (), t_end: float | None = None,
                     motors: str | Path | None = None, date: str | None = None, errors: TextIO | None = None,
                     progress: bool = False, inertia_ratio: float | None = None) -> tuple[list[SignalResult], dict]:
    """:func:`run_validate` without its table: (results, what ``bondc validate --json`` prints):
    ``complete`` (the simulation ran to its end), ``passed`` (every signal passed and the run is
    complete), ``signals`` (:func:`signal_json`, pass or fail per signal), ``written`` (the JUnit XML
    and the report, when asked for), ``data``, ``diagnostics`` and ``exit_status``."""
    errors = errors if errors is not None else sys.stderr
    for given, what in ((junit, "the JUnit XML"), (output, "the report")):
        if given is not None:
            check_output(given, what, make_folder=True)
    specs, measured = _measured(data, compare)
    if not specs:
        raise UsageError(Diagnostic("error", "E001", "validate needs at least one comparison",
                                    hint="--compare OUT=COLUMN[:nrmse=0.05]"))
    run = run_pipeline(path, model=model, experiment=experiment, sets=sets, t_end=t_end, progress=progress)
    results = compare_run(run, measured, specs)
    diagnostics = _print_diagnostics(run, errors)
    assumed = unit_warnings(run, measured, specs)
    if assumed:
        from bondc.errors import render_all

        print(render_all(assumed), file=errors)
    suite = run.graph.name + (f".{run.experiment.name}" if run.experiment is not None else "")
    written = []
    if junit is not None:
        Path(junit).parent.mkdir(parents=True, exist_ok=True)
        write_junit(results, suite, junit)
        written.append(str(junit))
    if output is not None:
        section = validation_section(run, results, data, junit)
        try:
            write_report(report_context(run, validation=section, motors=motors, date=date,
                                        inertia_ratio=inertia_ratio), Path(output))
        except KeyboardInterrupt as interrupt:
            _keep_simulation(run, Path(output), interrupt)
            raise
        written.append(str(output))
    passed = all(result.passed for result in results) and run.complete
    interrupted = getattr(run.result, "exit_status", None)
    return results, {
        "complete": run.complete, "passed": passed, "file": str(path), "model": run.graph.name,
        "experiment": run.experiment.name if run.experiment is not None else None, "data": str(data),
        "signals": [signal_json(result, signal_unit(run.graph, result.output)[0]) for result in results],
        "written": written, "diagnostics": [d.to_json() for d in [*diagnostics, *assumed]],
        "exit_status": interrupted or (0 if passed else 1)}


def _failure(run: PipelineRun) -> Diagnostic:
    result = run.result
    if result.diagnostics:
        return result.diagnostics[0]
    return Diagnostic("error", "E811", f"simulation stopped: {result.message}")


# ---------------------------------------------------------------- the report's contents

def _diagram(graph, causal):
    """The bond graph as drawn first: each top-level component a box (its contents expand below)."""
    from bondc.report.diagram import collapsed_graph, collapsed_setters

    collapsed = collapsed_graph(graph)
    if collapsed is None:
        return bond_graph_svg(graph, causal)
    return bond_graph_svg(collapsed, collapsed_setters(causal, graph, collapsed) if causal is not None else None)


def report_context(run: PipelineRun, *, validation: ValidationSection | None = None,
                   motors: str | Path | None = None, date: str | None = None,
                   inertia_ratio: float | None = None, ratio=None) -> ReportContext:
    """Everything the report of ``run`` shows (see the module docstring)."""
    graph, result = run.graph, run.result
    equations, laws, state_table = state_equations(run.state_space)
    # The causality section shows the causality stage's own notes.
    warnings = [_warning_text(d) for d in run.warnings
                if d.severity != "error" and d not in run.causal.diagnostics]
    incomplete = None
    if result is None:
        warnings.insert(0, "Not simulated: no experiment of this model sets t_end (give an end time to simulate).")
    elif not result.complete:
        incomplete = render_diagnostic(_failure(run), graph.sources)

    plots, result_tables, power_plots, power_tables = [], [], [], []
    summary: list[tuple[str, Any, str | None]] = []
    motor_requirements = motor_candidates = verdict = answer = None
    if result is not None and result.t.size >= 2:
        plots = output_plots(graph, result, run.experiment)
        result_tables = _result_tables(run)
        power_plots, power_tables, energy_summary, energy_warnings = _energy_sections(run)
        warnings += energy_warnings
        motor_requirements, motor_candidates, motor_summary, verdict, answer = _motor_sections(
            run, motors, inertia_ratio)
        summary = (motor_summary or _summary(run)) + energy_summary
    return ReportContext(
        bode=_bode_section(run),
        header=_header(run, date),
        source_html=highlight_bg(run.source_text),
        parameters=_parameter_rows(run),
        diagram_svg=_diagram(graph, run.causal),
        diagram_expanded_svg=(bond_graph_svg(graph, run.causal, id_prefix="expanded-")
                              if getattr(graph, "instances", ()) else None),
        causality=causality_rows(run.causal),
        causality_notes=causality_notes(run.causal),
        equations=equations,
        laws=laws,
        equation_tables=[state_table] if state_table is not None else [],
        plots=plots,
        result_tables=result_tables,
        power_plots=power_plots,
        power_tables=power_tables,
        motor_requirements=motor_requirements,
        motor_candidates=motor_candidates,
        validation=validation,
        warnings=warnings,
        incomplete=incomplete,
        summary=summary,
        verdict=verdict,
        answer=answer,
        ratio=ratio,
    )


def _bode_section(run: PipelineRun) -> BodeSection | None:
    """The frequency responses the experiment asks for (``bode = [U -> Y]``, linearised where
    ``bode_at`` says, else at the initial point), or None; a linearisation that fails (no
    equilibrium) is said in the section instead."""
    from bondc.analysis.bode import bode
    from bondc.errors import BondcError
    from bondc.report.bode_report import section_rows

    experiment = run.experiment
    pairs = experiment.settings.get("bode") if experiment is not None else None
    if not pairs:
        return None
    at = str(experiment.settings.get("bode_at", "initial"))
    try:
        result = bode(run.state_space, pairs=pairs, at=at, points=REPORT_BODE_POINTS)
    except BondcError as error:
        return BodeSection(at, 0.0, (), [_warning_text(d) for d in error.diagnostics])
    return BodeSection(at, result.linearization.time, section_rows(result),
                       [_warning_text(d) for d in result.warnings], list(result.notes))


def _warning_text(diagnostic: Diagnostic) -> str:
    where = f"{diagnostic.span}: " if getattr(diagnostic.span, "line", 0) else ""
    text = f"{where}{diagnostic.code}: {diagnostic.message}"
    return text + (f" ({diagnostic.hint})" if diagnostic.hint else "")


def _header(run: PipelineRun, date: str | None) -> ReportHeader:
    settings: dict[str, Any] = {}
    result = run.result
    if result is not None:
        used = result.settings
        for key, name in (("t_end", "t_end"), ("method", "solver"), ("rtol", "rtol"), ("atol", "atol"),
                          ("max_step", "max_step"), ("dt", "dt")):
            if used.get(key) is not None:
                settings[name] = used[key]
    if run.experiment is not None and run.experiment.cycle is not None:
        settings["cycle"] = run.experiment.cycle
    header = ReportHeader.for_graph(run.graph, run.source_text,
                                    run.experiment.name if run.experiment is not None else None,
                                    date=date, solver_settings=settings)
    # The file's name, not the path it was given by: the report does not depend on the working directory.
    return replace(header, source_file=Path(run.graph.file).name)


def _parameter_rows(run: PipelineRun) -> list[ParameterRow]:
    rows = []
    set_by_experiment = set(run.experiment.parameters) if run.experiment is not None else set()
    for row in parameter_rows(run.graph):
        if row.name in run.overridden:
            who = (f"experiment {run.experiment.name}" if row.name in set_by_experiment else "--set")
            note = f"set by {who}"
            row = ParameterRow(row.name, row.value, row.unit,
                               f"{row.description} ({note})" if row.description else f"({note})")
        rows.append(row)
    return rows


# -- equations

def _display_names(ss) -> dict[sympy.Symbol, sympy.Symbol]:
    """Symbols renamed for reading: ``mass.p`` -> p_mass, a bond's effort -> e_<element that sets it>."""
    graph = ss.graph
    taken = set(ss.symbols)
    renamed: dict[sympy.Symbol, sympy.Symbol] = {}

    def rename(symbol, name):
        if name not in taken:
            taken.add(name)
            renamed[symbol] = sympy.Symbol(name, real=True)

    owned = {s.qualified: s for s in graph.states if s.owner is not None}     # the graph says whose
    for state in ss.states:
        own = owned.get(state.name)
        if own is not None:                               # valve.chamber.p: p of valve.chamber
            rename(state.symbol, f"{own.name}_{own.owner}")
    for name, symbol in ss.eliminated.items():
        own = owned.get(name)
        if own is not None:
            rename(symbol, f"{own.name}_{own.owner}")
    for number, (effort, flow) in ss.bond_symbols.items():
        bond = graph.bond(number)
        for which, symbol in (("e", effort), ("f", flow)):
            ends = [(end, port) for end, port in ((bond.head, bond.head_port), (bond.tail, bond.tail_port))
                    if end in graph.elements]
            setting = [(end, port) for end, port in ends if which in graph.elements[end].laws]
            chosen = (setting or ends or [(None, None)])[0]
            if bond.label:
                rename(symbol, f"{which}_{bond.label}")
            elif chosen[0] is not None:
                end, port = chosen
                rename(symbol, f"{which}_{end}" + (f".{port}" if port else ""))
    return renamed


def _law_owner(ss, symbol) -> str | None:
    """The element whose own law computes the bond variable ``symbol`` (a store, resistor or source)."""
    graph = ss.graph
    for number, (effort, flow) in ss.bond_symbols.items():
        if symbol in (effort, flow):
            which = "e" if symbol == effort else "f"
            bond = graph.bond(number)
            for end in (bond.head, bond.tail):
                element = graph.elements.get(end)
                if element is not None and KINDS[element.kind].ports == 1 and which in element.laws:
                    return end
    return None


class _CallsKept(Translator):
    """Translates a law as the model writes it: calls of its ``fn`` functions stay calls, recorded in ``called``.

    The equations stage inlines every function; for reading, ``f_valve =
    valve_mdot(P1, P_chamber, ...)`` and the function once are clearer than
    the function's body pasted into every law that calls it.
    """

    def __init__(self, ss, owner=None):
        self.ss = ss
        self.called: list[str] = []
        local: dict = {}
        if owner is not None:
            if len(owner.bonds) == 1:
                local["e"], local["f"] = ss.bond_symbols[owner.bond]
            for state in owner.states:
                if state.qualified in ss.symbols:
                    local[state.name] = ss.symbols[state.qualified]

        def resolve_name(name, node):
            if name in local:
                return local[name]
            if name == "t":
                return ss.time
            if name in ss.parameters:
                return ss.parameters[name][0]
            if name in ss.inputs:
                return ss.inputs[name][0]
            if name in ss.symbols:
                return ss.symbols[name]
            if name == "pi":
                return sympy.pi
            raise KeyError(f"'{name}' is not a name of the model (the equations stage accepted it)")

        def resolve_ref(node):
            kind, what = ss.causal.reference(node.parts, owner.name if owner is not None else None)
            if kind == "state":
                return ss.symbols[what]
            return ss.bond_symbols[what][0 if kind == "e" else 1]

        graph = ss.graph
        super().__init__(resolve_name, resolve_ref, graph.functions,
                         Path(graph.file).parent if graph.file else None, ss.time)

    def _inline(self, node, function):
        if function.name not in self.called:
            self.called.append(function.name)
        return sympy.Function(function.name, real=True)(*[self(arg) for arg in node.args])

    def law(self, element, which: str):
        """The law of ``element`` for its ``which`` ("e" or "f") variable."""
        return self(element.laws[which])

    def function(self, function) -> tuple[Any, Any]:
        """``name(params)`` and its body, calls kept."""
        parameters = [sympy.Symbol(name, real=True) for name in function.params]
        self._bound.append(dict(zip(function.params, parameters)))
        try:
            body = self(function.body)
        finally:
            self._bound.pop()
        return sympy.Function(function.name, real=True)(*parameters), body


def state_equations(ss) -> tuple[list[Equation], list[Equation], Table | None]:
    """The state equations for reading: (d(state)/dt = ..., the laws they name, a table of the states).

    Every assignment is expanded into the derivatives except the inputs (kept
    by name) and the element laws that are long or piecewise (friction,
    orifice flow, backlash): those stay named (e_friction) and are written out
    once under "where", as the model writes them (its ``fn`` functions called,
    not inlined; the functions follow), in causal order.
    """
    names = _display_names(ss)
    keep = set(ss.input_symbols)
    mapping: dict = {}
    laws: list[tuple[sympy.Symbol, str]] = []
    for symbol, rhs in ss.assignments:
        if symbol in keep:
            continue
        value = rhs.xreplace(mapping)
        owner = _law_owner(ss, symbol)
        if owner is not None and (value.has(sympy.Piecewise) or sympy.count_ops(value) > LAW_OPERATIONS):
            laws.append((symbol, owner))
            continue
        mapping[symbol] = value

    def show(expr):
        return as_sympy(expr).xreplace(mapping).xreplace(names)

    time = ss.time
    equations = []
    for state in ss.states:
        lhs = sympy.Derivative(names.get(state.symbol, state.symbol), time)
        equations.append(Equation(equation_markup(lhs, show(ss.derivatives[state.name])), state.name))
    where = []
    functions: list[str] = []
    for symbol, owner in laws:
        element = ss.graph.elements[owner]
        which = "e" if symbol == ss.bond_symbols[element.bond][0] else "f"
        written = _CallsKept(ss, element)
        law = written.law(element, which)
        functions += [name for name in written.called if name not in functions]
        where.append(Equation(equation_markup(names.get(symbol, symbol), show(law)), f"{element.kind} {owner}"))
    for name, symbol in ss.eliminated.items():
        where.append(Equation(equation_markup(names.get(symbol, symbol), show(symbol)),
                              f"{name} (derivative causality)"))
    for number, block in enumerate(ss.algebraic_blocks, start=1):
        for residual in block.residuals:
            where.append(Equation(equation_markup(sympy.Integer(0), show(residual)), f"algebraic loop {number}"))
    index = 0
    while index < len(functions):      # functions called by functions follow the ones that call them
        written = _CallsKept(ss)
        head, body = written.function(ss.graph.functions[functions[index]])
        functions += [name for name in written.called if name not in functions]
        where.append(Equation(equation_markup(head, body.xreplace(names)), f"fn {functions[index]}"))
        index += 1

    table = None
    if ss.states:
        initial = ss.initial_values()
        with_units = any(s.unit_text for s in ss.states)
        rows = []
        for s in ss.states:
            row = {"state": s.name}
            if with_units:
                row["unit"] = s.unit_text or ""
            row["initial value (SI)"] = initial[s.name]
            row["description"] = s.description or _state_description(ss.graph, s)
            rows.append(row)
        table = Table.from_dicts("States and their initial values", rows)
    return equations, where, table


def _state_description(graph: BondGraph, state) -> str:
    if state.element is None or state.element not in graph.elements:
        return ""
    element = graph.elements[state.element]
    own = next((s for s in element.states if s.qualified == state.name), None)
    default = own is not None and own.rate is None          # q of a C, p of an I (not a custom state)
    what = {"q": "generalised displacement", "p": "generalised momentum"}.get(own.name, "state") if default else "state"
    return f"{what} of {element.kind} {element.name}"


# -- plots of the outputs

def output_groups(graph: BondGraph, result, experiment: ExperimentDef | None) -> list[list[str]]:
    """The outputs to plot, grouped: the experiment's ``outputs`` first, then the rest in declaration order.

    Outputs that share a unit go in one plot (up to :data:`MAX_SERIES_PER_PLOT`)
    unless their peak magnitudes differ by more than :data:`MAX_MAGNITUDE_RATIO`.
    A model without outputs plots its states instead.
    """
    names = [n for n in (experiment.outputs if experiment is not None else ()) if n in result.outputs]
    names += [n for n in result.outputs if n not in names]
    if not names:
        return [[name] for name in result.states]
    groups: list[list[str]] = []
    keys: list[tuple] = []

    def peak(name):
        values = np.asarray(result.outputs[name], dtype=float)
        finite = values[np.isfinite(values)]
        return float(np.max(np.abs(finite))) if finite.size else 0.0

    for name in names:
        unit = graph.outputs[name].unit_text if name in graph.outputs else None
        placed = False
        for group, key in zip(groups, keys):
            if unit is None or key != (unit,) or len(group) >= MAX_SERIES_PER_PLOT:
                continue
            peaks = [peak(n) for n in group] + [peak(name)]
            nonzero = [p for p in peaks if p > 0]
            if nonzero and max(nonzero) / min(nonzero) > MAX_MAGNITUDE_RATIO:
                continue
            group.append(name)
            placed = True
            break
        if not placed:
            groups.append([name])
            keys.append((unit,))
    return groups


def plot_unit(text: str | None) -> str:
    """A unit as written, for an axis label: ``N*m/s^2`` -> ``N·m/s²``.

    >>> plot_unit("kg*m^2/s^-1")
    'kg·m²/s⁻¹'
    """
    if not text:
        return ""
    superscripts = str.maketrans("0123456789-.", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻·")
    text = re.sub(r"\^\(?([-0-9.]+)\)?", lambda m: m.group(1).translate(superscripts), text)
    return text.replace("*", "·")


def time_axis(t) -> tuple[np.ndarray, str]:
    """Times for a plot's axis and its label: seconds, or milliseconds for a run shorter than 0.1 s.

    >>> time_axis([0.0, 0.02])[1], time_axis([0.0, 4.2])[1]
    ('t [ms]', 't [s]')
    """
    t = np.asarray(t, dtype=float)
    span = float(t[-1] - t[0]) if t.size else 0.0
    if 0 < span < 0.1:
        return t * 1e3, "t [ms]"
    return t, "t [s]"


def _time_plot(t, series, title, ylabel, *, half=False, styles=None) -> Markup:
    times, xlabel = time_axis(t)
    return plot_svg(times, series, title, ylabel, xlabel=xlabel, size=HALF_SIZE if half else FULL_SIZE,
                    styles=styles)


def _names(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:] if text else text


def output_plots(graph: BondGraph, result, experiment: ExperimentDef | None) -> list[Plot]:
    """One plot per group of :func:`output_groups`, in the outputs' display units."""
    plots = []
    featured = set(experiment.outputs if experiment is not None else ())
    for number, group in enumerate(output_groups(graph, result, experiment)):
        # the experiment's outputs (else the first plot) full width, the others two to a row
        half = not (featured & set(group) or (not featured and number == 0))
        series, notes = {}, []
        unit = None
        kind = "output"
        for name in group:
            if name in result.outputs:
                definition = graph.outputs[name]
                unit = definition.unit_text
                series[name] = np.asarray(result.outputs[name], dtype=float) / definition.display_factor
                description = definition.description
            else:
                kind = "state"
                state = next(s for s in graph.states if s.qualified == name)
                unit = state.unit_text
                series[name] = np.asarray(result.states[name], dtype=float)
                description = state.description
            if description:
                notes.append(f"{name}: {description}" if len(group) > 1 else _sentence(description))
        title = f"{_sentence(kind)}{'s' if len(group) > 1 else ''} {_names(group)}"
        label = group[0] if len(group) == 1 else ""
        if unit:
            label += f" [{plot_unit(unit)}]"
        plots.append(Plot(title, _time_plot(result.t, series, title, label.strip(), half=half), "; ".join(notes),
                          half))
    return plots


# -- power and energy

#: Plots of power: (title, roles, sign, caption). ``sign`` turns "power into the element" into what is shown.
POWER_PLOTS = (
    ("Power delivered by the sources", ("source",), -1.0, "Positive: the source delivers power to the system"),
    ("Power into the storage elements", ("storage",), 1.0, "Positive: the element stores energy"),
    ("Power dissipated in the resistors", ("dissipator",), 1.0, ""),
)


def element_power(graph: BondGraph, result) -> dict[str, np.ndarray]:
    """Power into every one-port element [W] over the run: e*f when its bond points at it, else -e*f."""
    power = {}
    for element in graph.elements.values():
        if KINDS[element.kind].ports != 1:
            continue
        bond = graph.bond(element.bond)
        effort, flow = result.bonds.get(f"{bond.name}.e"), result.bonds.get(f"{bond.name}.f")
        if effort is None or flow is None:
            continue
        product = np.asarray(effort, dtype=float) * np.asarray(flow, dtype=float)
        power[element.name] = product if bond.head == element.name else -product
    return power


def _role(kind: str) -> str:
    from bondc.analysis.energy import ROLES

    return ROLES[kind]


def power_plots(graph: BondGraph, result) -> list[Plot]:
    """Power of the sources, storage elements and resistors against time, one plot per role."""
    power = element_power(graph, result)
    plots = []
    for title, roles, sign, caption in POWER_PLOTS:
        series = {name: sign * values for name, values in power.items()
                  if _role(graph.elements[name].kind) in roles}
        if series:
            half = roles != ("source",)
            plots.append(Plot(title, _time_plot(result.t, series, title, "power [W]", half=half), caption, half))
    return plots


ENERGY_COLUMNS = ("supplied", "returned", "dissipated", "stored_change", "net_work_in")
ENERGY_HEADINGS = ("supplied [J]", "returned [J]", "dissipated [J]", "Δ stored [J]", "net work in [J]")

#: At most this many cycles get a table of their own; with more, the last one does.
MAX_CYCLE_TABLES = 3


def _energy_decimals(window) -> int:
    """Decimals that give the largest energy of a table six significant digits (at most nine)."""
    largest = max([abs(getattr(e, key)) for e in window.elements for key in ENERGY_COLUMNS
                   if getattr(e, key) is not None] + [abs(window.balance.supplied), 0.0])
    return 3 if largest == 0 else min(max(5 - int(math.floor(math.log10(largest))), 0), 9)


def energy_tables(account) -> list[Table]:
    """The energy of every element per cycle, each table closed by the balance and its residual.

    Energies are shown to a common number of decimals (six significant digits
    for the largest): a change of stored energy of 1e-21 J over a cycle that
    returns to its start is a zero, not a number to read.
    """
    tables = []
    windows = list(account.windows)
    shown = windows if len(windows) <= MAX_CYCLE_TABLES else windows[-1:]
    for window in shown:
        decimals = _energy_decimals(window)

        def cut(value):
            return None if value is None else round(float(value), decimals) + 0.0

        def text(value):
            return f"{round(float(value), decimals) + 0.0:.{decimals}f} J"

        rows, converters = [], []
        for entry in window.elements:
            if entry.role == "converter":
                converters.append(entry)
                continue
            rows.append((entry.element, entry.kind) + tuple(cut(getattr(entry, key)) for key in ENERGY_COLUMNS))
        b = window.balance
        rows.append(("total", "") + tuple(cut(v) for v in (b.supplied, b.returned, b.dissipated, b.stored_change,
                                                           b.net_work_in)))
        span = f"t = {window.t_start:g} – {window.t_end:g} s"
        title = (f"Energy per element, cycle {window.index + 1} of {len(windows)} ({span})"
                 if account.cycle is not None else f"Energy per element over the run ({span})")
        if window.partial:
            title += ", a partial cycle"
        relative = b.relative_residual
        notes = [
            f"Balance: the sources' net energy {text(b.sources_net)} (supplied − returned) = dissipated "
            f"{text(b.dissipated)} + change of stored energy {text(b.stored_change)} + net work into stores "
            f"without an energy function {text(b.net_work_in)}; residual {b.residual:.2g} J"
            + (f", {relative:.2g} of the {text(b.throughput)} that moved through the elements."
               if relative is not None else "."),
        ]
        if converters:
            notes.append("Two-ports (" + ", ".join(f"{e.kind} {e.element}" for e in converters)
                         + f") pass power on without loss: net work in {b.converter_work:.2g} J.")
        notes.append(f"Δ stored is the change of the stored-energy function over the cycle; net work in, the "
                     f"integral of the power into a store whose law has no energy function (custom state). "
                     f"Integration: {account.method}.")
        tables.append(Table(title, ("element", "kind") + ENERGY_HEADINGS, rows, notes=notes, total_row=True))
    if len(windows) > 1:
        rows = [(w.index + 1, w.t_start, w.t_end, w.balance.supplied, w.balance.returned, w.balance.dissipated,
                 w.balance.stored_change, w.balance.net_work_in, w.balance.residual) for w in windows]
        tables.append(Table("Energy balance per cycle",
                            ("cycle", "from [s]", "to [s]") + ENERGY_HEADINGS + ("residual [J]",), rows))
    return tables


def _energy_sections(run: PipelineRun) -> tuple[list[Plot], list[Table], list, list[str]]:
    """(power plots, energy tables, key results, warnings)."""
    from bondc.analysis.energy import energy_account
    from bondc.errors import AnalysisError

    plots = power_plots(run.graph, run.result)
    try:
        account = energy_account(run.state_space, run.result)
    except AnalysisError as error:
        return plots, [], [], [_warning_text(d) for d in error.diagnostics]
    summary = []
    if account.windows:
        balance = account.windows[-1].balance
        if balance.relative_residual is not None:
            summary.append(("energy balance residual, relative", balance.relative_residual, None))
    return plots, energy_tables(account), summary, [_warning_text(d) for d in account.diagnostics]


# -- motors

#: The signals the motor analysis reads: the motor torque and the motor speed (an output or an input).
MOTOR_TORQUE, MOTOR_SPEED = "torque", "omega"


def _answer(selection) -> Answer | None:
    """The design answer the report leads with, from the catalogue's :class:`~bondc.analysis.motors.Selection`:
    the verdict, the chosen motor's rule margins, the cycle's torque over time against its continuous and
    peak limits, the torque-speed points on its envelope (zoomed to the operating region) and every motor
    in a compact table. When no motor qualifies, the largest (the one the verdict names) is shown.
    None for an empty catalogue."""
    from bondc.analysis.motors import RULES

    by_size = sorted(selection, key=lambda candidate: candidate.motor.size)
    if not by_size:
        return None
    chosen = selection.best
    shown = chosen if chosen is not None else by_size[-1]
    need = selection.requirements
    torque = need.torque
    if selection.include_rotor_inertia:
        from bondc.analysis.motors import motor_torque

        torque = motor_torque(shown.motor, need)
    why = "" if chosen is not None else f". No motor qualifies: {shown.motor.name} is the largest"
    torque_plot, speed_plot = _answer_plots(selection, shown, need, torque, why)
    rows = [CandidateRow(c.motor.name, tuple((c.check(rule).margin, c.check(rule).passed) for rule in RULES),
                         "the choice" if c is chosen else "qualifies" if c.qualifies else "fails", c is chosen)
            for c in by_size]
    return Answer(selection.verdict(), chosen.motor.name if chosen is not None else None, shown.motor.name,
                  _rule_margins(shown), torque_plot, speed_plot, rows)


def _rule_margins(candidate) -> list[RuleMargin]:
    """The rules of one motor as the answer's table shows them, with units (the verdict's figures)."""
    from bondc.analysis.motors import figure

    rows = []
    for check in candidate.checks:
        speed = f" at {figure(check.speed)} rpm" if check.speed is not None and check.speed > 0 else ""
        if check.rule == "peak_torque":
            row = ("peak torque", f"{figure(check.required)} N·m{speed}", f"{figure(check.available)} N·m")
        elif check.rule == "rms_torque":
            row = ("RMS torque", f"{figure(check.required)} N·m{speed}",
                   f"{figure(check.available)} N·m")
        elif check.rule == "speed":
            row = ("top speed", f"{figure(check.required)} rpm", f"{figure(check.available)} rpm")
        elif check.rule == "inertia_ratio":
            needed = (f"load/rotor {figure(check.required)}" if check.required is not None
                      else "load inertia unknown: not checked")
            row = ("inertia ratio", needed, f"up to {figure(check.available)}")
        else:
            row = ("peak power", f"{figure(check.required or 0.0)} W",
                   f"{figure(check.available)} W rated")
        rows.append(RuleMargin(*row, check.margin, check.headroom, check.passed))
    return rows


def _answer_plots(selection, shown, need, torque: np.ndarray, why: str = "") -> tuple[Plot, Plot]:
    """(the torque over the cycle against the motor's limits, the torque-speed points on its envelope);
    ``why`` ends both captions (why this motor is shown when none qualifies)."""
    import hashlib
    import math

    import matplotlib
    from matplotlib.figure import Figure

    from bondc.analysis.motors import figure as fig_text
    from bondc.report.render import (
        ANSWER_SIZE, LIMIT_COLOR, PLOT_STYLE, POINTS_COLOR, RMS_COLOR, draw_motor_envelope, figure_svg,
        legend_on_top, scatter_indices,
    )

    motor = shown.motor
    rms = shown.check("rms_torque")
    time = np.asarray(need.time, dtype=float)
    torque = np.asarray(torque, dtype=float)
    peak = max(float(motor.peak_torque), float(np.max(np.abs(torque))))
    limits = [HLine(motor.peak_torque, f"peak ±{fig_text(motor.peak_torque)} N·m",
                    (("color", LIMIT_COLOR), ("linestyle", "--"), ("linewidth", 1.2)), "limit-peak"),
              HLine(-motor.peak_torque, "peak", (("color", LIMIT_COLOR), ("linestyle", "--"), ("linewidth", 1.2)),
                    "limit-peak-negative", legend=False),
              HLine(motor.rated_torque, f"continuous ±{fig_text(motor.rated_torque)} N·m",
                    (("color", LIMIT_COLOR), ("linewidth", 1.2)), "limit-continuous"),
              HLine(-motor.rated_torque, "continuous", (("color", LIMIT_COLOR), ("linewidth", 1.2)),
                    "limit-continuous-negative", legend=False),
              HLine(rms.required, f"RMS {fig_text(rms.required)} N·m",
                    (("color", RMS_COLOR), ("linestyle", ":"), ("linewidth", 1.2)), "rms"),
              HLine(-rms.required, "RMS", (("color", RMS_COLOR), ("linestyle", ":"), ("linewidth", 1.2)),
                    "rms-negative", legend=False)]
    title = f"Torque over the cycle against {motor.name}'s limits"
    torque_svg = plot_svg(time, {"motor torque": torque}, title, "torque [N·m]", size=ANSWER_SIZE,
                          styles={"motor torque": {"color": POINTS_COLOR, "linewidth": 1.1}}, hlines=limits,
                          ylim=(-1.15 * peak, 1.15 * peak), legend_above=True)
    delivered = (f"The torque at the coupling + {motor.name}'s rotor inertia × dω/dt"
                 if selection.include_rotor_inertia else "The motor torque")
    torque_caption = (f"{delivered}, against {motor.name}'s continuous (rated) and peak torque, and the cycle's "
                      f"RMS torque; drag to zoom{why}")
    torque_plot = Plot(title, torque_svg, torque_caption)

    rpm = np.abs(np.asarray(need.speed, dtype=float)) / (2 * math.pi / 60)
    load = np.abs(torque)
    title = f"Torque against speed on {motor.name}'s envelope"
    key = hashlib.sha256((title + repr((rpm.tobytes(), load.tobytes()))).encode()).hexdigest()
    with matplotlib.rc_context({**PLOT_STYLE, "svg.hashsalt": key}):
        chart = Figure(figsize=ANSWER_SIZE, layout="constrained")
        axes = chart.add_subplot()
        draw_motor_envelope(axes, motor, LIMIT_COLOR)
        kept = scatter_indices(rpm, load)
        axes.plot(rpm[kept], load[kept], ".", markersize=2.5, color=POINTS_COLOR, label="operating points",
                  gid="operating-points")
        axes.plot([rms.speed or 0.0], [rms.required], "D", markersize=5, color=RMS_COLOR,
                  label="RMS torque at RMS speed", gid="rms-point")
        top_speed = max(float(np.max(rpm)), float(motor.top_speed))
        top_torque = max(float(np.max(load)), float(motor.peak_torque))
        axes.set_xlim(0, 1.3 * top_speed)
        axes.set_ylim(0, 1.3 * top_torque)
        axes.set_xlabel("speed |ω| [rpm]")
        axes.set_ylabel("torque |τ| [N·m]")
        legend_on_top(axes)
        speed_svg = figure_svg(chart, title, key)
    caption = (f"The cycle's operating points (the torque beside) and its RMS torque at the RMS speed, on "
               f"{motor.name}'s continuous (solid) and peak (dashed) envelope")
    if kept.size < rpm.size:
        shown_n, total = (f"{n:,}".replace(",", "\u202f") for n in (kept.size, rpm.size))
        caption += (f"; {shown_n} of the {total} operating points are drawn, one in each small cell: the cloud "
                    "of them all")
    caption += why
    return torque_plot, Plot(title, speed_svg, caption)


def _motor_sections(run: PipelineRun, motors, inertia_ratio: float | None = None
                    ) -> tuple[Table | None, Table | None, list, str | None, Answer | None]:
    """Motor requirements when the model has signals ``torque`` and ``omega``; candidates from ``motors``,
    the verdict (:meth:`bondc.analysis.motors.Selection.verdict`, the same paragraph as
    ``bondc simulate --motors``) and the answer (:func:`_answer`) that the report leads with.

    Raises UsageError (E927) when a catalogue is given but the signals are missing.
    """
    from bondc.analysis.motor_report import (
        cycle_window, estimate_load_inertia, find_signal, selection_report, size_motors,
    )
    from bondc.analysis.motors import requirements

    result, graph = _steps(run), run.graph
    try:
        torque = find_signal(result, (MOTOR_TORQUE,), "torque")
        speed = find_signal(result, (MOTOR_SPEED,), "speed")
    except UsageError:
        if motors is not None:
            raise
        return None, None, [], None, None
    answer = None
    if motors is not None:
        selection = size_motors(result, graph, motors, torque=MOTOR_TORQUE, speed=MOTOR_SPEED,
                                inertia_limit=inertia_ratio)
        _, data = selection_report(selection, motors)
        need, load_inertia = data["requirements"], data["load_inertia"]
        answer = _answer(selection)
    else:
        window = cycle_window(result, graph)
        need = requirements(result.t, torque[2], speed[2], cycle=window).to_json()
        load_inertia = estimate_load_inertia(result, graph, window, speed[2])
        data = None
    rows = [
        ("cycle", f"{need['t_start']:g} – {need['t_end']:g}", "s"),
        ("peak torque |τ|", need["peak_torque"], "N·m"),
        ("largest positive torque", need["peak_torque_positive"], "N·m"),
        ("most negative torque", need["peak_torque_negative"], "N·m"),
        ("RMS torque", need["rms_torque"], "N·m"),
        ("peak speed", need["peak_speed"], "rad/s"),
        ("peak speed", need["peak_speed_rpm"], "rpm"),
        ("RMS speed", need["rms_speed_rpm"], "rpm"),
        ("peak power |τ·ω|", need["peak_power"], "W"),
        ("peak motoring power", need["peak_power_motoring"], "W"),
        ("peak regenerative power", need["peak_power_regenerative"], "W"),
        ("motoring energy per cycle", need["energy_positive"], "J"),
        ("regenerative energy per cycle", need["energy_regenerative"], "J"),
        ("net energy per cycle", need["energy_net"], "J"),
    ]
    if load_inertia is not None:
        rows.append(("load inertia at the motor shaft (estimated from the run)", load_inertia, "kg·m²"))
    described = []
    for name, where, _ in (torque, speed):
        definition = graph.outputs.get(name) if where == "output" else graph.inputs.get(name)
        text = f"{where} {name}"
        if definition is not None and definition.description:
            text += f" ({definition.description})"
        described.append(text)
    requirements_table = Table(
        "What the cycle asks of the motor", ("quantity", "value", "unit"), rows,
        caption=f"Torque: {described[0]}; speed: {described[1]}",
        notes=["Energies integrate τ·ω over the cycle, split at its zero crossings (regenerative energy is "
               "returned by the load to the motor)."])
    # the load's figures, without a motor's rotor inertia (the answer's are the chosen motor's, with it)
    summary = [("peak load torque", need["peak_torque"], "N*m"), ("RMS load torque", need["rms_torque"], "N*m"),
               ("peak load power", need["peak_power"], "W"), ("motor energy per cycle", need["energy_net"], "J")]
    if data is None:
        return requirements_table, None, summary, None, None
    return (requirements_table, _candidates_table(data, motors), summary + _motor_choice(data), data["verdict"],
            answer)


def _motor_choice(data: Mapping) -> list:
    return [("motor", data.get("best") or "none of the catalogue qualifies", None)]


def _candidates_table(data: Mapping, catalogue) -> Table:
    rows = []
    for candidate in data["candidates"]:
        motor, checks = candidate["motor"], candidate["checks"]
        if candidate["motor"]["name"] == data.get("best"):
            verdict = "the choice"
        elif candidate["qualifies"]:
            verdict = "qualifies"
        else:
            verdict = "fails: " + ", ".join(label for key, label in MARGIN_LABELS if checks[key]["passed"] is False)
        rows.append((motor["name"], motor["rated_power"])
                    + tuple(_two_decimals(checks[key]["margin"]) for key, _ in MARGIN_LABELS)
                    + (_two_decimals(candidate.get("inertia_ratio")), _two_decimals(checks["power"]["margin"]),
                       verdict))
    limit = data.get("inertia_limit")
    limit_text = (f"{limit:g} (--inertia-ratio)" if limit is not None
                  else "the catalogue's max_inertia_ratio for the motor, else 10")
    notes = ["The rules, each a margin available / required (a motor qualifies when every margin is at least 1): "
             "peak τ, the peak (intermittent) torque envelope at each instant's speed over |τ| (the worst "
             "instant); RMS τ, the continuous envelope at the RMS speed over the RMS torque (the thermal check); "
             "speed, the top speed (max_speed, else the rated speed) over the peak speed; J limit, the "
             f"inertia-ratio limit ({limit_text}) over the load/rotor inertia ratio. Power, the rated power over "
             "the peak |τ·ω|, is information, not a rule."]
    if data.get("include_rotor_inertia"):
        notes.append("Each motor is judged with its own rotor inertia added to the torque: τ + J_rotor·dω/dt.")
    if data.get("load_inertia") is not None:
        notes.append(f"J ratio: the load inertia at the motor shaft ({data['load_inertia']:.4g} kg·m², "
                     f"{data.get('load_inertia_source') or 'given'}) over the rotor inertia.")
    else:
        notes.append(f"The load inertia is unknown ({data.get('load_inertia_unknown_because')}): no inertia-ratio "
                     "check was made.")
    best = data.get("best")
    notes.append(f"Choice: {best}, the smallest motor that passes every rule." if best is not None
                 else "No motor of the catalogue qualifies.")
    return Table(f"Motors of {Path(catalogue).name}, qualifying first, smallest first",
                 ("motor", "rated power [W]") + tuple(label for _, label in MARGIN_LABELS)
                 + ("J ratio", "power (info)", "verdict"),
                 rows, caption="The columns peak τ, RMS τ, speed, J limit and power are margins: available / required",
                 notes=notes)


MARGIN_LABELS = (("peak_torque", "peak τ"), ("rms_torque", "RMS τ"), ("speed", "speed"),
                 ("inertia_ratio", "J limit"))


def _two_decimals(value):
    return None if value is None else round(float(value), 2)


# -- statistics

def _result_tables(run: PipelineRun) -> list[Table]:
    """The outputs' minimum, maximum, time average, RMS and final value; the power outputs per cycle."""
    from bondc.analysis.stats import output_statistics, power_outputs, power_statistics

    graph, result = run.graph, _steps(run)
    statistics = output_statistics(result)
    rows = []
    for name, values in statistics.items():
        definition = graph.outputs[name]
        shown = [values[key] / definition.display_factor for key in ("min", "max", "mean", "rms", "final")]
        rows.append((name, format_unit_text(definition.unit_text)) + tuple(_without_noise(shown)))
    tables = []
    if rows:
        span = f"t = {float(result.t[0]):g} – {float(result.t[-1]):g} s"
        tables.append(Table(f"Outputs over the run ({span})", ("output", "unit", "min", "max", "mean", "RMS",
                                                               "final"), rows,
                            notes=["Mean and RMS are time averages (trapezoid rule over the solver's points)."]))
    powers = power_outputs(graph)
    if powers:
        cycle = run.experiment.cycle if run.experiment is not None else None
        per_cycle = power_statistics(result, powers, cycle=cycle)
        rows = [(name, window["cycle"] + 1, window["peak"], window["peak_negative"], window["rms"],
                 window["positive_energy"], window["negative_energy"], window["net_energy"])
                for name, windows in per_cycle.items() for window in windows]
        tables.append(Table(
            "Power outputs " + ("per cycle" if cycle is not None else "over the run"),
            ("output", "cycle", "peak |p| [W]", "min [W]", "RMS [W]", "positive [J]", "negative [J]", "net [J]"),
            rows, caption="Energies: the integral of the positive and of the negative part, and their sum",
            notes=["Energies integrate the output with the trapezoid rule, split at its zero crossings."]))
    return tables


#: Statistics smaller than this fraction of the largest of their row are rounding noise, shown as 0.
NOISE = 1e-9


def _without_noise(values: Sequence[float]) -> list[float]:
    """``values`` with the ones below :data:`NOISE` times the largest magnitude set to 0 (and no -0).

    >>> _without_noise([-1.3e-15, 0.09992, -0.0])
    [0.0, 0.09992, 0.0]
    """
    finite = [abs(v) for v in values if math.isfinite(v)]
    scale = max(finite, default=0.0)
    return [0.0 if math.isfinite(v) and abs(v) <= NOISE * scale else v + 0.0 for v in values]


def format_unit_text(text: str | None) -> str:
    """A unit for a table cell (plain text): ``N*m`` -> ``N·m``, ``m/s^2`` -> ``m/s²``."""
    return plot_unit(text)


def _summary(run: PipelineRun) -> list[tuple[str, Any, str | None]]:
    """Key results: the peak of each of the experiment's outputs."""
    result, graph = run.result, run.graph
    names = [n for n in (run.experiment.outputs if run.experiment is not None else ()) if n in result.outputs]
    items = []
    for name in names[:4]:
        definition = graph.outputs[name]
        values = np.asarray(result.outputs[name], dtype=float) / definition.display_factor
        finite = values[np.isfinite(values)]
        if finite.size:
            items.append((f"peak {name}", float(finite[np.argmax(np.abs(finite))]), definition.unit_text))
    return items
