"""Command line: argument parsing, dispatch to the stages, and exit codes only.

Exit status: 0 success, 1 the model (or the data, or a validation) has errors,
2 usage or I/O error. Every problem is printed as a diagnostic (``file:line:col``,
the source line, a caret, a hint); a Python traceback is printed only for an
internal error, and only with ``--debug``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
from pathlib import Path

from bondc.version import __version__
from bondc.errors import BondcError, Diagnostic, UsageError
from bondc import codes
from bondc.commands import (  # noqa: F401  (what the parser dispatches to)
    EXIT_ERRORS, EXIT_OK, EXIT_USAGE, _FitGroup, _RATIO_HELP, _VERBOSITY, _cmd_bode, _cmd_cache, _cmd_check,
    _cmd_compile, _cmd_equations, _cmd_fit, _cmd_fit_friction, _cmd_fmt, _cmd_fmu, _cmd_linearize, _cmd_lsp,
    _cmd_report, _cmd_simulate, _cmd_sweep, _cmd_validate, _json_failure, _print_diagnostics, _status, _verbose
)

#: A reader closed the pipe while output went to it through a channel the guard does not cover (a
#: binary stream): the status a shell gives a program killed by SIGPIPE (128 + 13), as git returns.
EXIT_BROKEN_PIPE = 141


class _PipeGuard:
    """A standard stream whose reader may go away (``bondc check m.bg | head -1``): once a write
    finds the pipe closed, the rest of the output is dropped and the command goes on to the end,
    so that it writes its files and exits with its own status (1 for a model with errors), never
    0 because a reader stopped listening."""

    def __init__(self, stream):
        self._stream = stream
        self.broken = False

    def write(self, text):
        if not self.broken:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self.broken = True
        return len(text)

    def flush(self):
        if not self.broken:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self.broken = True

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _silence(stream) -> None:
    """After a broken pipe: the stream's file descriptor pointed at /dev/null, so that what is left
    in its buffer is flushed there at exit (not a second BrokenPipeError, which Python reports as
    "Exception ignored" with exit status 120)."""
    try:
        descriptor = stream.fileno()
    except (AttributeError, OSError, ValueError):
        return          # (an in-memory stream: nothing to flush at exit)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, descriptor)
    finally:
        os.close(null)


class _ArgumentParser(argparse.ArgumentParser):
    """argparse that raises UsageError instead of exiting, so main() owns exit codes."""

    def error(self, message):  # noqa: D401 - argparse API
        raise UsageError(Diagnostic("error", codes.E001, f"{self.prog}: {message}",
                                    hint=f"see '{self.prog} --help'"))




# ------------------------------------------------------------------- parser

def _add_model_args(parser, *, sets=True, optional=False, several=False) -> None:
    if several:
        parser.add_argument("file", help="the .bg model files", nargs="+", metavar="FILE")
    else:
        parser.add_argument("file", help="the .bg model file", nargs="?" if optional else None)
    parser.add_argument("--model", help="the model to use when the file holds several")
    parser.add_argument("--no-cache", action="store_true",
                        help="derive and compile again instead of reusing the compile cache")
    if sets:
        parser.add_argument("--set", action="append", metavar="NAME=VALUE",
                            help='override a parameter, e.g. --set M=40 or --set "M=40 [kg]" (repeatable)')


def _add_verbosity(parser, default) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("-q", "--quiet", action="store_true", default=default,
                       help="print only errors: no warnings, notes, progress or summary lines")
    group.add_argument("-v", "--verbose", action="store_true", default=default,
                       help="also print notes on what was done: the cache folder, the time taken")


def build_parser() -> argparse.ArgumentParser:
    parser = _ArgumentParser(prog="bondc", description="bondc — a bond-graph modelling compiler")
    parser.add_argument("--version", action="version", version=f"bondc {__version__}")
    parser.add_argument("--debug", action="store_true", help="show a traceback on an internal error")
    _add_verbosity(parser, argparse.SUPPRESS)
    parser.set_defaults(quiet=False, verbose=False)
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_ArgumentParser)
    add_parser = commands.add_parser

    def add_command(*args, **kwargs):       # -q and -v after the command too (bondc check -q m.bg)
        command = add_parser(*args, **kwargs)
        _add_verbosity(command, argparse.SUPPRESS)
        return command

    commands.add_parser = add_command

    check = commands.add_parser("check", help="parse and check models; report every problem (the exit status "
                                              "is the worst of the files)")
    _add_model_args(check, several=True)
    check.add_argument("--json", action="store_true", help="machine-readable diagnostics")
    check.add_argument("--causality", action="store_true", help="print the causality table")
    check.set_defaults(run=_cmd_check)

    fmt = commands.add_parser("fmt", help="print a model in the canonical layout; check or rewrite models")
    fmt.add_argument("file", nargs="+", metavar="FILE", help="the .bg model files (several with --check or --write)")
    group = fmt.add_mutually_exclusive_group()
    group.add_argument("--check", action="store_true", help="exit 1 if a file is not formatted")
    group.add_argument("--write", action="store_true", help="rewrite the files in place")
    fmt.add_argument("--json", action="store_true",
                     help="print what was done as JSON: per file, formatted, changed, written (and the text "
                          "without --check or --write)")
    fmt.set_defaults(run=_cmd_fmt)

    equations = commands.add_parser("equations", help="print the state equations")
    _add_model_args(equations)
    equations.add_argument("--experiment", help="apply this experiment's parameter overrides (default: the first)")
    equations.add_argument("--format", choices=("text", "latex", "json"), default="text")
    equations.set_defaults(run=_cmd_equations)

    linear = commands.add_parser("linearize", help="A, B, C, D, eigenvalues, natural frequencies, damping")
    _add_model_args(linear)
    linear.add_argument("--experiment", help="apply this experiment's parameter overrides (default: the first)")
    linear.add_argument("--time", type=float, default=0.0, help="hold the inputs at their value at this time, s")
    linear.add_argument("--at", choices=("initial", "equilibrium"), default="initial",
                        help="linearise at the initial state or at the equilibrium found from it")
    linear.add_argument("--json", action="store_true")
    linear.set_defaults(run=_cmd_linearize)

    bode_ = commands.add_parser("bode", help="frequency response (Bode plot) of outputs to inputs at an operating "
                                             "point; gain and phase margins; --verify against the nonlinear model")
    _add_model_args(bode_)
    bode_.add_argument("--experiment", help="apply this experiment's parameter overrides (default: the first)")
    bode_.add_argument("--input", action="append", metavar="U",
                       help="the input to excite (repeatable; default: the model's only input)")
    bode_.add_argument("--output", action="append", dest="output_name", metavar="Y",
                       help="the output to measure (repeatable: one response per input and output; default: the "
                            "model's only output)")
    bode_.add_argument("--at", choices=("initial", "equilibrium"), default="initial",
                       help="linearise at the initial state or at the equilibrium found from it")
    bode_.add_argument("--time", type=float, default=0.0, help="hold the inputs at their value at this time, s")
    bode_.add_argument("--from", dest="low", metavar="F_LOW",
                       help='lowest frequency, Hz, or with a unit: "10 [rad/s]" (default: a decade below the '
                            "slowest mode)")
    bode_.add_argument("--to", dest="high", metavar="F_HIGH",
                       help="highest frequency, Hz or with a unit (default: a decade above the fastest mode)")
    bode_.add_argument("--points", default="400", metavar="N", help="frequencies, spaced logarithmically (default 400)")
    bode_.add_argument("--verify", action="store_true",
                       help="simulate the nonlinear model with a small sine on the input at 5 frequencies and "
                            "compare with the linear prediction")
    bode_.add_argument("--amplitude", metavar="A",
                       help="the verification sine's amplitude, in the input's unit or with a unit (default: 1 %% "
                            "of the input's value at the operating point, else 1 SI)")
    bode_.add_argument("-o", metavar="FILE", dest="output",
                       help="write the response: .csv (units in the header), .svg (the plot) or .html (a page)")
    bode_.add_argument("--json", action="store_true",
                       help="print the response as JSON: {input, output, frequency_hz, magnitude_db, phase_deg, "
                            "margins}; a list of them for several pairs")
    bode_.set_defaults(run=_cmd_bode)

    compile_ = commands.add_parser("compile", help="generate the model's Python module (imports bondc.runtime; "
                                                   "--standalone: numpy + scipy only)")
    _add_model_args(compile_)
    compile_.add_argument("--experiment", help="whose settings become the module's defaults (default: the first)")
    compile_.add_argument("-o", "--output", help="the module to write (default: MODEL_gen.py beside the model)")
    compile_.add_argument("--standalone", action="store_true",
                          help="copy bondc's runtime into the module, so that it runs where bondc is not installed")
    compile_.add_argument("--target", choices=("python", "c"), default="python",
                          help="python: the simulation module (default); c: the model's C code and header "
                               "(-o names their folder, default MODEL_c beside the model)")
    compile_.add_argument("--json", action="store_true", help="print what was written as JSON")
    compile_.set_defaults(run=_cmd_compile)

    fmu = commands.add_parser("fmu", help="export a Functional Mock-up Unit (FMI 2.0 or 3.0, Co-Simulation or "
                                          "Model Exchange, linux64) with bondc's CVODE engine inside")
    _add_model_args(fmu)
    fmu.add_argument("--experiment", help="whose t_end, rtol and atol become the FMU's default experiment "
                                          "(default: the first)")
    fmu.add_argument("--fmi", choices=("2", "3"), default="2", help="the FMI version (default: 2)")
    fmu.add_argument("--kind", choices=("cs", "me"), default="cs",
                     help="cs: Co-Simulation, bondc's engine integrates (default); me: Model Exchange, the "
                          "importer integrates")
    fmu.add_argument("-o", "--output", help="the FMU to write (default: MODEL.fmu beside the model)")
    fmu.add_argument("--json", action="store_true", help="print what was written as JSON")
    fmu.set_defaults(run=_cmd_fmu)

    sim = commands.add_parser("simulate", help="simulate an experiment; statistics, energy per cycle, CSV/NPZ")
    _add_model_args(sim)
    sim.add_argument("--experiment", help="the experiment to run (default: the first)")
    sim.add_argument("--t-end", type=float, help="end time, s (overrides the experiment's t_end)")
    sim.add_argument("--dt", type=float, help="output sampling interval, s")
    sim.add_argument("-o", "--output", help="write results: .csv (columns t, outputs, states) or .npz")
    sim.add_argument("--all", action="store_true", help="also write every bond's effort and flow")
    sim.add_argument("--input", action="append", default=[], metavar="NAME=FILE.csv[:COLUMN]",
                     help="supply external input NAME from a CSV file (time column t, time or the first; units "
                          "in the header; COLUMN defaults to NAME); repeatable")
    sim.add_argument("--json", action="store_true", help="print a JSON summary")
    sim.add_argument("--motors", metavar="CATALOGUE.csv",
                     help="size the motor from outputs 'torque' and 'omega' and list the qualifying motors")
    sim.add_argument("--inertia-ratio", metavar="LIMIT", help="load/rotor inertia-ratio limit of every motor (default: the catalogue's max_inertia_ratio, else 10)")
    sim.add_argument("--ratio", metavar="NAME=VALUES", help=_RATIO_HELP)
    sim.set_defaults(run=_cmd_simulate)

    report = commands.add_parser("report", help="one self-contained HTML report: model, bond graph, equations, "
                                                "plots, energy per cycle, motor choice")
    _add_model_args(report, optional=True)
    report.add_argument("--sweep", metavar="STUDY.csv",
                        help="instead of a model: the report of a design study (the table of bondc sweep -o)")
    report.add_argument("--experiment", help="the experiment to run (default: the first)")
    report.add_argument("--t-end", type=float, help="end time, s (overrides the experiment's t_end)")
    report.add_argument("--data", help="measured CSV to compare with (adds a validation section)")
    report.add_argument("--compare", action="append", metavar="OUT=COLUMN[:nrmse=0.05]",
                        help="compare output OUT with the measured COLUMN (repeatable)")
    report.add_argument("--motors", metavar="CATALOGUE.csv", help="judge the motors of this catalogue against the cycle")
    report.add_argument("--inertia-ratio", metavar="LIMIT", help="load/rotor inertia-ratio limit of every motor (default: the catalogue's max_inertia_ratio, else 10)")
    report.add_argument("--ratio", metavar="NAME=VALUES", help=_RATIO_HELP)
    report.add_argument("-o", "--output", help="the HTML file (default: reports/<model file>.html, "
                                                   "reports/<file>-<experiment>.html for a non-first experiment)")
    report.add_argument("--json", action="store_true",
                        help="print a JSON summary: the file written, pass/fail per compared signal, diagnostics")
    report.set_defaults(run=_cmd_report)

    validate = commands.add_parser("validate", help="compare a simulation with measured data; pass/fail per signal")
    _add_model_args(validate)
    validate.add_argument("--experiment", help="the experiment to run (default: the first)")
    validate.add_argument("--t-end", type=float, help="end time, s (overrides the experiment's t_end)")
    validate.add_argument("--data", required=True, help="measured CSV (first column or 't'/'time' is time)")
    validate.add_argument("--compare", action="append", required=True, metavar="OUT=COLUMN[:nrmse=0.05]",
                          help="output OUT against measured COLUMN with its tolerance (repeatable)")
    validate.add_argument("--junit", metavar="results.xml", help="write JUnit XML, one test case per signal")
    validate.add_argument("--motors", metavar="CATALOGUE.csv", help=argparse.SUPPRESS)
    validate.add_argument("--inertia-ratio", metavar="LIMIT", help=argparse.SUPPRESS)
    validate.add_argument("-o", "--output", help="also write the HTML report with the validation section")
    validate.add_argument("--json", action="store_true",
                          help="print a JSON summary instead of the table: pass/fail and metrics per signal, "
                               "the files written, diagnostics")
    validate.set_defaults(run=_cmd_validate)

    sweep = commands.add_parser("sweep", help="parameter study: simulate over a grid of parameter values")
    _add_model_args(sweep)
    sweep.add_argument("--experiment", help="the experiment to run (default: the first)")
    sweep.add_argument("--vary", action="append", metavar="NAME=VALUES",
                       help='values of a parameter: "k=400,800,1600", "lead=5,10 [mm]" or "M=20:40:5 [kg]" '
                            "(start:stop:count, both ends included); without a unit, the parameter's declared "
                            "unit; several --vary make a full grid")
    sweep.add_argument("--samples", type=int, metavar="N",
                       help="instead of a grid: N Latin-hypercube samples over the --range bounds")
    sweep.add_argument("--range", action="append", dest="ranges", metavar="NAME=LOW:HIGH",
                       help='bounds of a sampled parameter, e.g. "M=20:45 [kg]" (with --samples; repeatable)')
    sweep.add_argument("--seed", type=int, help="seed of the Latin hypercube (the same seed, the same points)")
    sweep.add_argument("--point-timeout", type=float, metavar="SECONDS",
                       help="stop a point that runs longer and record it as timed out (default: 20 times the "
                            "median point time, at least 60 s; 0: no limit)")
    sweep.add_argument("--executor", choices=("local", "dask"), default="local",
                       help="local: worker processes on this machine (-j of them); dask: a dask.distributed "
                            "cluster (a LocalCluster of -j workers, or --scheduler)")
    sweep.add_argument("--scheduler", metavar="ADDRESS",
                       help="an existing Dask scheduler, e.g. tcp://host:8786 (implies --executor dask)")
    sweep.add_argument("--motors", metavar="CATALOGUE.csv",
                       help="per point, which motors of the catalogue pass the sizing rules (as simulate --motors)")
    sweep.add_argument("--inertia-ratio", metavar="LIMIT", help="load/rotor inertia-ratio limit of every motor (default: the catalogue's max_inertia_ratio, else 10)")
    sweep.add_argument("--metric", action="append", metavar="NAME",
                       help="a column: OUTPUT.min, .max, .mean, .rms, .final, OUTPUT.*, energy.residual, "
                            "energy.relative_residual, motor.* (default: all but the means; repeatable)")
    sweep.add_argument("--t-end", type=float, help="end time, s (overrides the experiment's t_end)")
    sweep.add_argument("--dt", type=float, help="output sampling interval, s")
    sweep.add_argument("-j", "--jobs", type=int, default=max(1, os.cpu_count() or 1),
                       help="points run in parallel (default: one per core)")
    sweep.add_argument("--rederive", action="store_true",
                       help="derive and compile the model again for every point (slower; for laws whose "
                            "inversion depends on parameter values)")
    sweep.add_argument("-o", "--output", help="write the table: .csv (SI; rows added as points finish) or .json; "
                                              "the same command again resumes, skipping the points already there")
    sweep.add_argument("--json", action="store_true", help="print the result as JSON")
    sweep.set_defaults(run=_cmd_sweep)

    fit_ = commands.add_parser("fit", help="estimate parameters from measured data (least squares), with "
                                            "standard errors, 95 %% intervals and correlations")
    _add_model_args(fit_)
    fit_.add_argument("--data", action=_FitGroup, metavar="FILE",
                      help="measured CSV (header units honoured, as validate); each --data starts a data set, "
                           "and the --experiment and --compare after it belong to it (repeat for several)")
    fit_.add_argument("--experiment", action=_FitGroup, metavar="NAME",
                      help="the experiment the data set before it was measured in (before any --data: every "
                           "data set's default; default: the first)")
    fit_.add_argument("--compare", action=_FitGroup, metavar="OUT=COLUMN[:weight=W]",
                      help="fit output OUT to the measured COLUMN of the data set before it (repeatable)")
    fit_.add_argument("--estimate", action="append", metavar="NAME[=LOW:HIGH]",
                      help='a parameter to estimate, with bounds in its declared unit or a unit in [ ] '
                           '("b=5:30", "Ae=5:50 [mm^2]"; an empty bound is open); its --set value, else the '
                           "model's, is the start (repeatable)")
    fit_.add_argument("--max-evaluations", type=int, metavar="N",
                      help="stop the optimiser after N evaluations (default 200; the Jacobians cost more runs)")
    fit_.add_argument("-o", "--output", help="write the HTML report: estimates, correlations, measured vs model")
    fit_.add_argument("--write", metavar="FITTED.bg",
                      help="write a copy of the model with the fitted values (never over a file bondc fit did "
                           "not write)")
    fit_.add_argument("--json", action="store_true",
                      help="print converged, parameters (value, unit, initial, stderr, ci95), correlation, cost, "
                           "signals, diagnostics as JSON")
    fit_.set_defaults(run=_cmd_fit, data=None, fit_items=[])

    lsp_ = commands.add_parser("lsp", help="the language server for editors (Language Server Protocol on stdio)")
    lsp_.add_argument("--stdio", action="store_true",
                      help="talk over stdin/stdout (the only transport; accepted because editors' clients pass it)")
    lsp_.set_defaults(run=_cmd_lsp)

    cache_ = commands.add_parser("cache", help="bondc's caches: where they are and their size (info), or empty "
                                                "them (clear)")
    actions = cache_.add_subparsers(dest="action", metavar="ACTION", parser_class=_ArgumentParser)
    for action, text in (("info", "each cache's folder, entries and size, and the compile cache's cap"),
                         ("clear", "remove what bondc stored in its caches (compile, check, native libraries, "
                                   "parser); other files in the folder stay")):
        sub = actions.add_parser(action, help=text)
        _add_verbosity(sub, argparse.SUPPRESS)
        sub.add_argument("--json", action="store_true", help="print the result as JSON")
    cache_.set_defaults(run=_cmd_cache, json=False)

    fit = commands.add_parser("fit-friction", help="identify C = a*|v|^b per direction from steady-speed tests "
                                                   "(the paper's eqs. 17-20)")
    fit.add_argument("file", help="CSV with velocity [m/s], torque [N*m], pressure [Pa] columns")
    fit.add_argument("--lead", type=float, default=5.0e-3, help="ball screw lead per revolution, m (default 5e-3)")
    fit.add_argument("--area", type=float, default=2.63e-3, help="rod-side piston area, m^2 (default 2.63e-3)")
    fit.add_argument("--mass", type=float, default=31.7, help="moving mass, kg (default 31.7)")
    fit.add_argument("--gravity", type=float, default=9.81, help="m/s^2 (default 9.81)")
    fit.add_argument("--patm", type=float, default=101325.0,
                     help="atmospheric pressure, Pa, subtracted from absolute chamber pressure (0 for gauge data)")
    fit.add_argument("--json", action="store_true")
    fit.set_defaults(run=_cmd_fit_friction)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is: every command stops as on Ctrl-C (partial results kept)."""


def _terminate(signum, frame):
    from bondc.io import hold_termination

    if not hold_termination(Terminated()):      # a file being written is finished first
        raise Terminated()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    else:       # (signal handlers can only be set in the main thread)
        previous = None
    from bondc.pipeline import fewer_collections

    streams = sys.stdout, sys.stderr
    guards = _PipeGuard(sys.stdout), _PipeGuard(sys.stderr)
    sys.stdout, sys.stderr = guards
    try:
        with fewer_collections():
            return _main(argv, debug)
    finally:
        _VERBOSITY[0] = 0
        sys.stdout, sys.stderr = streams
        for guard, stream in zip(guards, streams):
            if guard.broken:
                _silence(stream)
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _inputs(args) -> list[tuple[Path, str]]:
    """(path, what it is) of every file the command reads: the model file, the files it imports,
    the data files its csv() calls name, and the data files of the options."""
    found: list[tuple[Path, str]] = []
    for option, what in (("data", "the measured data"), ("motors", "the motor catalogue"),
                         ("sweep", "the sweep table")):
        if getattr(args, option, None):
            found.append((Path(getattr(args, option)), what))
    model = getattr(args, "file", None)
    if not model or getattr(args, "command", None) == "fit-friction":
        return found + ([(Path(model), "the data file")] if model else [])
    found.append((Path(model), "the model file"))
    from bondc import ast
    from bondc.semantic import load_files

    try:
        files, sources, _ = load_files(Path(model))
    except (BondcError, OSError, ValueError):
        return found            # (the command reports it)
    for file in files:
        source = sources.get(file.path)
        if source is None or source.path is None:
            continue
        if source.path != Path(model):
            found.append((source.path, f"the imported model '{file.path}'"))
        for node in _nodes(file):
            if isinstance(node, ast.Call) and node.func == "csv" and node.args and isinstance(node.args[0], ast.Str):
                found.append((source.path.parent / node.args[0].value, f"the data file '{node.args[0].value}'"))
    return found


def _nodes(node):
    """Every syntax node under ``node`` (a file: its statements, laws and expressions)."""
    import dataclasses

    todo = [node]
    while todo:
        node = todo.pop()
        if isinstance(node, (tuple, list)):
            todo.extend(node)
        elif dataclasses.is_dataclass(node) and not isinstance(node, type):
            yield node
            todo.extend(getattr(node, f.name) for f in dataclasses.fields(node)
                        if not isinstance(getattr(node, f.name), (str, int, float, type(None))))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _refuse_inputs_as_outputs(args) -> None:
    """E003 before any work for an output path that is one of the command's inputs (``bondc
    compile -o m.bg m.bg`` replaced the model with the generated module)."""
    from bondc.errors import UsageError

    outputs = [(option, getattr(args, attribute)) for option, attribute in (("-o", "output"), ("--junit", "junit"))
               if getattr(args, attribute, None)]
    outputs = [(option, Path(path)) for option, path in outputs if Path(path).exists()]   # (new files read nothing)
    if not outputs:
        return
    inputs = _inputs(args)
    for option, output in outputs:
        for path, what in inputs:
            if _same_file(output, path):
                raise UsageError(Diagnostic(
                    "error", codes.E003, f"cannot write the output '{output}' ({option}): it is {what} the command reads",
                    hint="give another path for the output; bondc never writes over its inputs"))


def _main(argv: list[str], debug: bool) -> int:
    args = None
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "run", None):
            parser.print_help(sys.stderr)
            return EXIT_USAGE
        if args.quiet and args.verbose:
            raise UsageError(Diagnostic("error", codes.E001, "bondc: -q and -v cannot be given together",
                                        hint="-q prints only errors, -v notes too"))
        _VERBOSITY[0] = -1 if args.quiet else 1 if args.verbose else 0
        _refuse_inputs_as_outputs(args)         # before any work
        if args.verbose:
            from bondc import cache

            _verbose(f"cache folder {cache.cache_dir()}" + ("" if cache.enabled() else " (off: BONDC_CACHE=0)"))
        started = time.perf_counter()
        status = args.run(args)
        _verbose(f"bondc {args.command} took {time.perf_counter() - started:.3g} s (exit status {status})")
        return status
    except UsageError as error:
        _print_diagnostics(error.diagnostics, error.sources)
        _json_failure(args, error)
        return EXIT_USAGE
    except BondcError as error:
        _print_diagnostics(error.diagnostics, error.sources)
        _json_failure(args, error)
        if getattr(error, "io", False):     # (a file that cannot be read)
            return EXIT_USAGE
        return _status(error.diagnostics) if error.diagnostics else EXIT_ERRORS
    except KeyboardInterrupt as interrupt:
        terminated = isinstance(interrupt, Terminated)
        print(f"bondc: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
        return 143 if terminated else 130
    except BrokenPipeError:     # (a binary stream: the text streams are guarded, see _PipeGuard)
        _silence(sys.stdout)
        return EXIT_BROKEN_PIPE
    except SystemExit as exit_:  # --help / --version
        return int(exit_.code or 0)
    except RecursionError:
        _print_diagnostics([Diagnostic(
            "error", codes.E005, "an expression is nested too deeply for bondc (a single sum, product or call "
                             "chain of many thousands of terms)",
            hint="split it: give parts of it names with param, or as fn definitions")])
        return EXIT_ERRORS
    except Exception as error:  # an internal error: a bug in bondc, not in the model
        print(f"bondc: internal error: {type(error).__name__}: {error}", file=sys.stderr)
        print("This is a bug in bondc; please report it with the model file.", file=sys.stderr)
        if debug:
            traceback.print_exc()
        return 3
