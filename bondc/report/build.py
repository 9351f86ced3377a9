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
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence, TextIO

import numpy as np

from bondc.analysis.validate import (
    CompareSpec, SignalResult, compare_run, measured_data, signal_json, signal_unit, unit_warnings, validation_table,
    write_junit,
)
from bondc.errors import Diagnostic, UsageError, render as render_diagnostic
from bondc.io import atomic_write_text, check_output
from bondc.pipeline import PipelineRun, run_pipeline
from bondc.report.diagram import bond_graph_svg
from bondc.report.lexer import highlight_bg
from bondc.report.motor_section import motor_sections
from bondc.report.plots import (
    MAX_SERIES_PER_PLOT, element_power, output_groups, output_plots, plot_unit, power_plots, time_plot,
)
from bondc.report.render import (
    BodeSection, ParameterRow, Plot, ReportContext, ReportHeader, Table, ValidationSection, causality_notes,
    causality_rows, parameter_rows, render_report,
)
from bondc.report.state_equations import state_equations
from bondc import codes

if TYPE_CHECKING:
    from bondc.simulate import SimResult

__all__ = ["PipelineRun", "run_pipeline", "report_context", "build_report", "run_report", "default_output",
           "write_report", "run_validate", "report_summary", "report_text", "validate_summary",
           "validate_text", "signal_json",
           "compare_run", "validation_table", "state_equations", "output_groups", "element_power",
           "MAX_SERIES_PER_PLOT", "REPORTS_DIR"]

#: Frequencies of each Bode plot in a report (the plot is small; ``bondc bode`` takes 400 by default).
REPORT_BODE_POINTS = 150

#: Where reports go unless ``output`` says otherwise (relative to the working directory).
REPORTS_DIR = Path("reports")

# ---------------------------------------------------------------- where it goes

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
    specs, measured = measured_data(data, compare)
    run = run_pipeline(path, model=model, experiment=experiment, sets=sets, t_end=t_end, progress=progress)
    study = None
    if ratio is not None and run.result is not None:
        study = ratio_study(path, ratio, motors=motors, model=model, experiment=experiment, sets=sets,
                            t_end=t_end, inertia_ratio=inertia_ratio, jobs=jobs, progress=progress)
    target = Path(output) if output is not None else default_output(path, run)
    results: list[SignalResult] = []
    try:
        validation = None
        if specs and measured is not None:
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
    interrupted = run.result.exit_status if run.result is not None else None
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


def _print_diagnostics(run: PipelineRun, stream: TextIO) -> list[Diagnostic]:
    from bondc.errors import render_all

    diagnostics = list(run.warnings)
    if run.result is not None and not run.result.complete:
        diagnostics.append(_failure(run.result))
    if diagnostics:
        print(render_all(diagnostics, run.graph.sources), file=stream)
    return diagnostics


def write_report(context: ReportContext, target: str | Path) -> None:
    """Render ``context`` in full, then replace ``target`` with it in one step (its directory is made)."""
    html = render_report(context)
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(target, html)


# ---------------------------------------------------------------- validation

def validation_section(run: PipelineRun, results: Sequence[SignalResult], data_file,
                       junit_file=None) -> ValidationSection:
    """The report's validation section: the metrics, and per signal the curves overlaid and the error."""
    plots = []
    for result in results:
        unit, _ = signal_unit(run.graph, result.output)
        simulated, measured = result.simulated, result.measured      # (in the signal's unit: compare_run)
        title = f"{result.output} simulated and {result.column} measured"
        plots.append(Plot(title, time_plot(
            result.t, {f"{result.column} (measured)": measured, f"{result.output} (simulated)": simulated},
            title, result.output + (f" [{plot_unit(unit)}]" if unit else " (SI)"), half=True,
            styles={f"{result.column} (measured)": {"color": "#8c959f", "linewidth": 1.0},
                    f"{result.output} (simulated)": {"color": "#0550ae", "linewidth": 1.4}}),
            f"NRMSE {result.nrmse:.3g}, R² {result.r2:.4g}: {'pass' if result.passed else 'FAIL'}", True))
        title = f"{result.output} error, simulated − measured"
        ylabel = "error" + (f" [{plot_unit(unit)}]" if unit else " (SI)")
        plots.append(Plot(title, time_plot(result.t, {"error": simulated - measured}, title, ylabel, half=True,
                                            styles={"error": {"color": "#a40e26", "linewidth": 1.0}}),
                          f"Largest |error| {result.maxabs:.4g}{' ' + plot_unit(unit) if unit else ''}", True))
    return ValidationSection(results, str(data_file), plots, str(junit_file) if junit_file else None)


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
    specs, measured = measured_data(data, compare)
    if not specs:
        raise UsageError(Diagnostic("error", codes.E001, "validate needs at least one comparison",
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
    interrupted = run.result.exit_status if run.result is not None else None
    return results, {
        "complete": run.complete, "passed": passed, "file": str(path), "model": run.graph.name,
        "experiment": run.experiment.name if run.experiment is not None else None, "data": str(data),
        "signals": [signal_json(result, signal_unit(run.graph, result.output)[0]) for result in results],
        "written": written, "diagnostics": [d.to_json() for d in [*diagnostics, *assumed]],
        "exit_status": interrupted or (0 if passed else 1)}


def _failure(result: SimResult) -> Diagnostic:
    """What stopped an incomplete run."""
    if result.diagnostics:
        return result.diagnostics[0]
    return Diagnostic("error", codes.E811, f"simulation stopped: {result.message}")


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
        incomplete = render_diagnostic(_failure(result), graph.sources)

    plots: list[Plot] = []
    result_tables: list[Table] = []
    power_plots: list[Plot] = []
    power_tables: list[Table] = []
    summary: list[tuple[str, Any, str | None]] = []
    motor_requirements = motor_candidates = verdict = answer = None
    if result is not None and result.t.size >= 2:
        plots = output_plots(graph, result, run.experiment)
        result_tables = _result_tables(run)
        power_plots, power_tables, energy_summary, energy_warnings = _energy_sections(run)
        warnings += energy_warnings
        motor_requirements, motor_candidates, motor_summary, verdict, answer = motor_sections(
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


# -- energy

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


# -- statistics

def _result_tables(run: PipelineRun) -> list[Table]:
    """The outputs' minimum, maximum, time average, RMS and final value; the power outputs per cycle."""
    from bondc.analysis.energy import dense_steps
    from bondc.analysis.stats import output_statistics, power_outputs, power_statistics

    # statistics from the solver's steps and between them (dense_steps); the plots show run.result
    graph, result = run.graph, dense_steps(run.state_space, run.result)
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
    if result is None:
        return []
    names = [n for n in (run.experiment.outputs if run.experiment is not None else ()) if n in result.outputs]
    items = []
    for name in names[:4]:
        definition = graph.outputs[name]
        values = np.asarray(result.outputs[name], dtype=float) / definition.display_factor
        finite = values[np.isfinite(values)]
        if finite.size:
            items.append((f"peak {name}", float(finite[np.argmax(np.abs(finite))]), definition.unit_text))
    return items
