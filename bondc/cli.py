"""Command line: argument parsing, dispatch to the stages, and exit codes only.

Exit status: 0 success, 1 the model (or the data, or a validation) has errors,
2 usage or I/O error. Every problem is printed as a diagnostic (``file:line:col``,
the source line, a caret, a hint); a Python traceback is printed only for an
internal error, and only with ``--debug``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from bondc.version import __version__
from bondc.errors import BondcError, Diagnostic, UsageError, render_all
from bondc.io import json_safe
from bondc import codes

EXIT_OK, EXIT_ERRORS, EXIT_USAGE = 0, 1, 2
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


def _print_json(value) -> None:
    print(json.dumps(json_safe(value), indent=2, default=str, allow_nan=False))


def _json_failure(args, error: BondcError) -> None:
    """With --json, a command that stopped on an error still prints JSON on stdout: its diagnostics
    (a program reading stdout gets an object to parse, not nothing)."""
    if getattr(args, "json", False):
        _print_json({"complete": False, "diagnostics": [d.to_json() for d in error.diagnostics]})


#: -1 with -q (only errors), 1 with -v (notes on what was done too), else 0; set by main()
_VERBOSITY = [0]


def _quiet() -> bool:
    return _VERBOSITY[0] < 0


def _verbose(text: str) -> None:
    """A note printed with -v only (on stderr): where the caches are, how long the command took."""
    if _VERBOSITY[0] > 0:
        print(f"note: {text}", file=sys.stderr)


def _note(text: str) -> None:
    """A line about what was done (``reformatted m.bg``), on stderr; not with -q."""
    if not _quiet():
        print(text, file=sys.stderr)


def _print_diagnostics(diagnostics, sources=None, stream=None) -> None:
    if _quiet():        # -q: only errors
        diagnostics = [d for d in diagnostics if d.is_error]
    if diagnostics:
        print(render_all(diagnostics, sources or {}), file=stream or sys.stderr)


def _parse_sets(values) -> list:
    from bondc.pipeline import parse_sets

    return parse_sets(values)


def _derive(args):
    """parse -> build -> causality -> equations, with the experiment's overrides applied:
    (graph, causal, state space, experiment). See :func:`_derived`."""
    derived = _derived(args)
    return derived.graph, derived.causal, derived.state_space, derived.experiment


def _derived(args, light: bool = False):
    """The ``pipeline.Derived`` of the command's file and options. Warnings (derivative causality,
    unused parameters, ...) go to stderr. ``light``: see ``pipeline.derive_file`` (``simulate``
    takes it: a cached run then needs no sympy)."""
    from bondc.pipeline import derive_file

    derived = derive_file(Path(args.file), model=getattr(args, "model", None),
                          experiment=getattr(args, "experiment", None), sets=getattr(args, "set", None) or (),
                          cache=False if getattr(args, "no_cache", False) else None, light=light)
    _print_diagnostics(derived.notes, derived.graph.sources)
    return derived


def _status(diagnostics) -> int:
    """0 without errors; 2 when an error is about a value given on the command line (``--set k=abc``:
    the command line is at fault); else 1."""
    from bondc.pipeline import on_command_line

    if not any(d.is_error for d in diagnostics):
        return EXIT_OK
    return EXIT_USAGE if on_command_line(diagnostics) else EXIT_ERRORS


# ------------------------------------------------------------------ commands

def _check_one(args, model: str | None, component: bool, loaded=None) -> tuple:
    """Load and check one model (causality too, unless it is a component with ports); ``loaded``:
    the file already parsed (``semantic.load_files``).

    Returns (diagnostics, sources, graph, causal)."""
    from bondc import semantic

    diagnostics: list[Diagnostic] = []
    graph = causal = state_space = None
    sources = {}
    try:
        graph, warnings = semantic.load(Path(args.file), model=model, sets=_parse_sets(args.set), loaded=loaded)
        diagnostics += warnings
        if not component:       # I346: an external input that check sees nothing supply takes its default
            from bondc.model import external_input_notes

            diagnostics += external_input_notes(graph)
        sources = graph.sources
        if not component:
            from bondc.causality import assign_causality

            causal = assign_causality(graph)
            diagnostics += [d for d in causal.diagnostics if d not in diagnostics]
            # what simulate would reject about the model itself (a law that cannot be inverted,
            # E605), and the states the equations keep
            state_space, found = _equations_checked(args, model, graph, causal)
            diagnostics += [d for d in found if d not in diagnostics]
    except BondcError as error:
        if error.stage in ("usage",):
            raise
        diagnostics += error.diagnostics
        sources = error.sources or sources
    return diagnostics, sources, graph, causal, state_space


@dataclass(frozen=True)
class _CheckedEquations:
    """What ``check`` reports of the equations stage: the states they keep."""

    states: tuple


def _equations_checked(args, model, graph, causal) -> tuple:
    """(the equations' states as :class:`_CheckedEquations`, or None where the stage failed; its
    diagnostics). Taken from the check cache when bondc and every file the model read are
    unchanged (``bondc.cache.check_key``), or differ only in parameter values that the equations
    stage did not use (``bondc.cache.check_key_of_structure``): then sympy is not even imported."""
    from bondc import cache

    use_cache = cache.enabled() and not getattr(args, "no_cache", False)
    key = cache.check_key(graph.sources, model, args.set) if use_cache else None
    known = cache.load_check(key) if key else None
    # after an edit of parameter values only: the equations stage of the same model with other
    # values, when no value decided anything there
    structural, value_lines = cache.check_key_of_structure(graph.sources, graph, model, args.set) \
        if key and known is None else (None, frozenset())

    def on_edited_lines(diagnostics) -> bool:     # their columns may have moved
        return any((d.span.file, d.span.line) in value_lines for d in diagnostics)

    if structural:
        known = cache.load_check(structural)
        if known is not None and on_edited_lines(known[1]):
            known = None
    if known is None:
        from bondc.quickcheck import equations_findings

        known, consulted = equations_findings(causal)
        if key:
            cache.store_check(key, known)
        if structural and not consulted and not on_edited_lines(known[1]):
            cache.store_check(structural, known)
    states, diagnostics = known
    return (None if states is None else _CheckedEquations(states)), list(diagnostics)


def _switches_json(args, graph, loaded) -> list[dict]:
    """Every switch of a checked model's laws, a kink or a jump, with its law's file and line
    (``check --json``; :func:`bondc.pipeline.switches_of`)."""
    from bondc.pipeline import switches_of

    use_cache = not getattr(args, "no_cache", False)
    return [dict(row) for row in switches_of(args.file, graph, loaded, sets=args.set, cache=use_cache)]


def _models_to_check(args) -> tuple[list[tuple[str | None, bool]], tuple | None]:
    """(model name, is a component) for each model ``check`` looks at: the one asked for, or every
    model of the file (LANGUAGE.md section 11: a model with ports is a component); and the parsed
    files (``semantic.load_files``), or None where they do not parse."""
    from bondc import semantic
    from bondc.flatten import ports_of

    try:
        loaded = semantic.load_files(Path(args.file))
    except BondcError:
        return [(args.model, False)], None      # the single run reports it
    every = [m for f in loaded[0] for m in f.models]
    if args.model is not None:
        chosen = [m for m in every if m.name == args.model]
        return [(args.model, bool(chosen and ports_of(chosen[0])))], loaded
    own = loaded[0][0].models
    if len(own) <= 1:
        return [(None, bool(own and ports_of(own[0])))], loaded
    return [(m.name, bool(ports_of(m))) for m in own], loaded


def _cmd_check(args) -> int:
    """``bondc check FILE...``: each file in turn; the exit status is the worst of them. With
    ``--json``, one file's object, or for several files an array of them, each with its ``file``."""
    _parse_sets(args.set)       # a bad --set is E007 once, before any file
    return _each_file(args, _check_file)


def _each_file(args, run) -> int:
    """``run(args with one file) -> (status, JSON data or None)`` for each of ``args.file``; prints
    the JSON (an object for one file, an array for several) and returns the worst status. A file
    that cannot be read (E002) is reported and the others are still done."""
    files = args.file
    if isinstance(files, str):
        files = [files]
    worst, rows = EXIT_OK, []
    for name in files:
        one = argparse.Namespace(**{**vars(args), "file": name})
        try:
            status, data = run(one)
        except UsageError as error:
            if len(files) == 1:
                raise
            _print_diagnostics(error.diagnostics, error.sources)
            status, data = EXIT_USAGE, {"ok": False, "diagnostics": [d.to_json() for d in error.diagnostics]}
        worst = max(worst, status)
        if data is not None:
            rows.append({"file": name, **data} if len(files) > 1 else data)
    if getattr(args, "json", False):
        print(json.dumps(json_safe(rows if len(files) > 1 else rows[0]), indent=2, allow_nan=False))
    return worst


def _check_file(args) -> tuple[int, dict | None]:
    diagnostics: list[Diagnostic] = []
    sources: dict = {}
    results = []
    chosen, loaded = _models_to_check(args)
    for name, component in chosen:
        found, found_sources, graph, causal, state_space = _check_one(args, name, component, loaded)
        diagnostics += [d for d in found if d not in diagnostics]
        sources.update(found_sources or {})
        results.append((graph, causal, component, state_space))
    ok = not any(d.is_error for d in diagnostics)
    if args.json:
        summaries = []
        for graph, causal, component, state_space in results:
            summary = graph.summary() if graph is not None else None
            if summary is not None and causal is not None:
                summary["causality"] = causal.summary()
            if summary is not None and state_space is not None:
                summary["states_kept"] = len(state_space.states)
                if ok:
                    summary["switches"] = _switches_json(args, graph, loaded)
            if summary is not None and component:
                summary["component"] = True
            summaries.append(summary)
        data = {"ok": ok, "diagnostics": [d.to_json() for d in diagnostics], "model": summaries[0]}
        if len(summaries) > 1:
            data["models"] = summaries
        return _status(diagnostics), data
    _print_diagnostics(diagnostics, sources)
    for graph, causal, component, state_space in results:
        if graph is None or (_quiet() and not args.causality):
            continue
        counts = graph.summary()
        line = (f"{graph.name}: {counts['elements']} elements, {counts['junctions']} junctions, "
                f"{counts['bonds']} bonds, {counts['storage_elements']} storage elements, "
                f"{counts['states']} states")
        if state_space is not None and len(state_space.states) != counts["states"]:
            line += f" ({len(state_space.states)} kept by the equations)"
        if causal is not None:
            line += f"; {causal.summary_text()}"
        if component:
            line += "; a component (its ports checked as boundaries; causality is checked where it is used)"
        print(line)
        if args.causality and causal is not None:
            from bondc.causality import format_table

            print()
            print(format_table(causal))
    errors = sum(d.is_error for d in diagnostics)
    if errors:
        print(f"{args.file}: {errors} error{'s' if errors != 1 else ''}", file=sys.stderr)
    return _status(diagnostics), None


def _cmd_fmt(args) -> int:
    """``bondc fmt FILE...``: print one file formatted, or ``--check``/``--write`` each of several;
    the exit status is the worst of them (1: a file would be reformatted, or does not parse)."""
    if len(args.file) > 1 and not (args.check or args.write):
        raise UsageError(Diagnostic("error", codes.E001, "bondc fmt: several files need --check or --write",
                                    hint="give one file to print it formatted"))
    return _each_file(args, _fmt_file)


def _fmt_file(args) -> tuple[int, dict | None]:
    from bondc.fmt import format_path
    from bondc.io import atomic_write_text

    try:
        original, formatted = format_path(Path(args.file))
    except UsageError:
        raise
    except BondcError as error:         # a file that does not parse: the others are still formatted
        _print_diagnostics(error.diagnostics, error.sources)
        return EXIT_ERRORS, {"ok": False, "formatted": False, "changed": False, "written": False,
                             "diagnostics": [d.to_json() for d in error.diagnostics]}
    changed = original != formatted
    data = {"ok": True, "formatted": not changed, "changed": changed, "written": False, "diagnostics": []}
    if args.check:
        if changed:
            print(f"{args.file}: would be reformatted", file=sys.stderr)
            data["ok"] = False
            return EXIT_ERRORS, data
        return EXIT_OK, data
    if args.write:
        if changed:
            atomic_write_text(Path(args.file), formatted)
            data["written"] = True
            _note(f"{args.file}: reformatted")
        return EXIT_OK, data
    if args.json:
        data["text"] = formatted
    else:
        sys.stdout.write(formatted)
    return EXIT_OK, data


def _cmd_equations(args) -> int:
    from bondc.equations import format_equations

    _, _, state_space, _ = _derive(args)
    text = format_equations(state_space, args.format)
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return EXIT_OK


def _cmd_linearize(args) -> int:
    from bondc.analysis.linearize import linearize

    _, _, state_space, _ = _derive(args)
    result = linearize(state_space, time=args.time, at=args.at)
    if args.json:
        _print_json(result.to_json())
    else:
        print(result.to_text())
    return EXIT_OK


def _cmd_bode(args) -> int:
    """``bondc bode``: the frequency response of outputs to inputs at the linearisation's operating
    point (``bondc.analysis.bode``), its margins, and with --verify the nonlinear model against it."""
    from bondc.analysis.bode import bode, parse_frequency, parse_points
    from bondc.report.bode_report import check_bode_output, write_bode

    if args.output:
        check_bode_output(args.output)          # before any work
    # the options' values before any work too (E944, E945)
    low = parse_frequency(args.low, "--from") if args.low is not None else None
    high = parse_frequency(args.high, "--to") if args.high is not None else None
    points = parse_points(args.points)
    derived = _derived(args)
    progress = None if args.json or _quiet() else _note
    result = bode(derived.state_space, inputs=args.input, outputs=args.output_name, at=args.at, time=args.time,
                  low=low, high=high, points=points, verify_model=args.verify, amplitude=args.amplitude,
                  progress=progress)
    _print_diagnostics(list(result.warnings), derived.graph.sources)
    if args.output:
        write_bode(result, args.output, derived.graph.name, args.file)
    if args.json:
        _print_json(result.to_json())
    else:
        print(result.to_text(), end="")
        if args.output:
            print(f"written to {args.output}")
    return EXIT_OK


def _keep_light(derived, account) -> None:
    """After a full run from the compile cache, write the entry's light form for the next one."""
    from bondc.cache import LightStateSpace, entry_of

    entry = entry_of(derived.state_space)
    if (entry is not None and account.energy_recipes is not None and not derived.sets
            and not isinstance(derived.state_space, LightStateSpace)):
        entry.store_light(derived, account.energy_recipes)


def _inertia_ratio(args) -> float | None:
    """``--inertia-ratio`` as a positive number (E928 before any work), or None."""
    from bondc.analysis.motors import check_inertia_limit

    value = getattr(args, "inertia_ratio", None)
    if value is None:
        return None
    try:
        return check_inertia_limit(value)
    except BondcError as error:
        raise UsageError(error.diagnostics) from None


_RATIO_HELP = ('with --motors: the parameter that sets the transmission ratio and values to try, as sweep --vary '
               '("lead=2,5,10,20 [mm]", "n_gear=5:40:8"); shows the smallest qualifying motor at each value and '
               'the model\'s own')


def _jobs() -> int:
    """Processes for the points of a --ratio study: one per core."""
    return max(1, os.cpu_count() or 1)


def _cmd_simulate(args) -> int:
    from bondc.analysis.energy import dense_steps, energy_account
    from bondc.analysis.stats import output_statistics, power_outputs, power_statistics
    from bondc.io import check_output
    from bondc.pipeline import simulate_derived
    from bondc.simulate import check_result_path, write

    if args.output:
        check_result_path(args.output)
        check_output(args.output)       # before any work
    inertia_ratio = _inertia_ratio(args)
    from bondc.analysis.ratio import check_ratio

    check_ratio(args.ratio, args.motors)
    if args.motors:
        from bondc.analysis.motors import load_catalogue

        load_catalogue(args.motors)     # a catalogue that cannot be read is an error before the run
    derived = _derived(args, light=True)
    graph, state_space, experiment = derived.graph, derived.state_space, derived.experiment
    result = simulate_derived(derived, t_end=args.t_end, dt=args.dt, progress=not args.json and not _quiet(),
                              input_files=args.input)       # --input u=FILE.csv[:COLUMN]
    _print_diagnostics(result.warnings, graph.sources)
    if args.output:
        write(result, Path(args.output), args.all)
    error = result.error()
    summary = result.summary()

    def shown(name, value):
        """An output's value in its declared unit (the SI value of anything else)."""
        unit, scale = result.units.get(name, (None, 1.0))
        return value / scale if name in result.outputs and unit is not None and isinstance(value, float) else value

    summary["final"] = {name: shown(name, value) for name, value in summary["final"].items()}
    account = None
    steps = result
    if result.t.size > 1:
        steps = dense_steps(state_space, result)   # the solver's steps and the solution between them
        summary["statistics"] = output_statistics(steps)
        for name, row in summary["statistics"].items():         # each output in its declared unit
            unit, _ = result.units.get(name, (None, 1.0))
            if unit is not None:
                row.update({key: shown(name, value) for key, value in row.items()}, unit=unit)
        cycle = experiment.cycle if experiment is not None else None
        summary["power"] = power_statistics(steps, power_outputs(graph), cycle)
        try:
            account = energy_account(state_space, result, cycle=cycle)
            summary["energy"] = account.to_json()
            _keep_light(derived, account)
        except BondcError as problem:
            _print_diagnostics(problem.diagnostics, graph.sources)
    motors_text = None
    failed = False                      # an analysis asked for (--motors) that could not be made
    if args.motors:
        from bondc.analysis.motor_report import motor_report

        try:
            motors_text, summary["motors"] = motor_report(steps, graph, Path(args.motors),
                                                          inertia_limit=inertia_ratio)
        except BondcError as problem:
            _print_diagnostics(problem.diagnostics, graph.sources)
            summary.setdefault("diagnostics", []).extend(d.to_json() for d in problem.diagnostics)
            failed = any(d.is_error for d in problem.diagnostics)
    study = None
    if args.ratio and result.complete:
        from bondc.analysis.ratio import ratio_study

        study = ratio_study(args.file, args.ratio, motors=args.motors, model=args.model,
                            experiment=args.experiment, sets=args.set or (), t_end=args.t_end,
                            inertia_ratio=inertia_ratio, jobs=_jobs(), progress=not args.json and not _quiet())
        summary["ratio"] = study.to_json()
    if args.json:
        _print_json(summary)
    else:
        state = "complete" if result.complete else f"INCOMPLETE at t = {result.t_reached:g} s"
        print(f"{graph.name}: simulated {summary['points']} points to t = {result.t_reached:g} s ({state}), "
              f"{len(result.events)} events")
        if args.output:
            print(f"results written to {args.output}" + ("" if result.complete else " (incomplete)"))
        stats = summary.get("statistics", {})
        if stats:
            print()
            print(f"  {'output':<14} {'unit':<8} {'min':>12} {'max':>12} {'rms':>12} {'final':>12}")
            for name, row in stats.items():
                unit = row.get("unit") or ""
                print(f"  {name:<14} {unit:<8} " + " ".join(f"{row[key]:>12.5g}"
                                                          for key in ("min", "max", "rms", "final")))
        if account is not None:
            print()
            print(account.to_text())
        if motors_text:
            print()
            print(motors_text)
        if study is not None:
            print()
            print(study.to_text())
    if error is not None:
        _print_diagnostics(error.diagnostics, graph.sources)
        return result.exit_status or EXIT_ERRORS
    return EXIT_ERRORS if failed else EXIT_OK


def _cmd_compile(args) -> int:
    from bondc.pipeline import compile_file, default_output

    if args.target == "c":
        return _compile_c(args)
    output = Path(args.output) if args.output else default_output(args.file)
    compile_file(Path(args.file), output, model=args.model, experiment=args.experiment,
                 sets=_parse_sets(args.set), standalone=args.standalone)
    if args.json:
        _print_json({"complete": True, "file": args.file, "model": args.model, "experiment": args.experiment,
                     "standalone": args.standalone, "written": [str(output)]})
    elif not _quiet():
        print(f"wrote {output}")
    return EXIT_OK


def _compile_c(args) -> int:
    """``bondc compile FILE --target c -o DIR``: the model's C code and header (bondc.export.ccode)."""
    from bondc.export.ccode import c_model, write_c
    from bondc.io import check_output

    derived = _derived(args)
    model = c_model(derived.state_space, derived.experiment)
    folder = Path(args.output) if args.output else Path(args.file).with_name(f"{model.name}_c")
    if folder.exists() and not folder.is_dir():
        raise UsageError(Diagnostic("error", codes.E001, f"--target c writes a folder: {folder} is a file",
                                    hint="give -o a folder (made if missing)"))
    check_output(folder / f"{model.name}.c", "the C code", make_folder=True)
    written = write_c(model, folder)
    if args.json:
        _print_json({"complete": True, "file": args.file, "model": args.model, "experiment": args.experiment,
                     "target": "c", "written": [str(path) for path in written]})
    elif not _quiet():
        for path in written:
            print(f"wrote {path}")
    return EXIT_OK


def _cmd_fmu(args) -> int:
    """``bondc fmu FILE``: a Functional Mock-up Unit (bondc.export.fmu)."""
    from bondc.export.fmu import build_fmu, default_output
    from bondc.io import check_output

    if args.output:
        check_output(args.output, "the FMU")
    derived = _derived(args)
    output = Path(args.output) if args.output else default_output(args.file, derived.graph.name)
    check_output(output, "the FMU")
    built = build_fmu(derived, output, fmi=int(args.fmi), kind=args.kind)
    summary = {"complete": True, "file": args.file, "model": derived.graph.name,
               "experiment": getattr(derived.experiment, "name", None),
               "fmi": built.fmi, "kind": built.kind, "guid": built.guid, "platforms": ["linux64"],
               "states": len(built.model.states), "parameters": len(built.model.parameters),
               "inputs": len(built.model.inputs), "outputs": len(built.model.outputs),
               "event_indicators": sum(built.model.located), "written": [str(output)]}
    if args.json:
        _print_json(summary)
    elif not _quiet():
        kind = "Co-Simulation" if built.kind == "cs" else "Model Exchange"
        print(f"wrote {output} (FMI {built.fmi}.0 {kind}, linux64: {summary['states']} states, "
              f"{summary['parameters']} parameters, {summary['inputs']} inputs, {summary['outputs']} outputs)")
    return EXIT_OK


def _cmd_report(args) -> int:
    from bondc.report.build import report_summary, report_text

    inertia_ratio = _inertia_ratio(args)
    if args.sweep:
        from bondc.report.sweep_report import summary as study_summary, sweep_report

        target, study = sweep_report(args.sweep, args.output, args.motors)
        if args.json:
            _print_json({"complete": True, "sweep": args.sweep, "written": [str(target)],
                         "summary": study_summary(study), "exit_status": EXIT_OK})
        elif not _quiet():
            for line in study_summary(study):
                print(line)
            print(f"wrote {target}")
        return EXIT_OK
    if not args.file:
        raise UsageError(Diagnostic("error", codes.E001, "bondc report: give a model file, or --sweep STUDY.csv",
                                    hint="see 'bondc report --help'"))
    summary = report_summary(Path(args.file), model=args.model, experiment=args.experiment,
                             sets=_parse_sets(args.set), data=args.data, compare=args.compare or (),
                             motors=args.motors, output=args.output, t_end=args.t_end,
                             progress=not args.json and not _quiet(), inertia_ratio=inertia_ratio,
                             ratio=args.ratio, jobs=_jobs())
    if args.json:
        _print_json(summary)
    elif not _quiet() or summary["exit_status"]:
        print(report_text(summary), file=sys.stderr)
    return summary["exit_status"]


def _cmd_validate(args) -> int:
    from bondc.report.build import validate_summary, validate_text

    results, summary = validate_summary(Path(args.file), data=args.data, compare=args.compare, junit=args.junit,
                                        output=args.output, model=args.model, experiment=args.experiment,
                                        sets=_parse_sets(args.set), t_end=args.t_end, motors=args.motors,
                                        progress=not args.json and not _quiet(), inertia_ratio=_inertia_ratio(args))
    if args.json:
        _print_json(summary)
    else:
        print(validate_text(results, summary))
    return summary["exit_status"]


def _cmd_sweep(args) -> int:
    from bondc.analysis.sweep import run_sweep

    try:
        result = run_sweep(args.file, model=args.model, experiment=args.experiment, sets=args.set or (),
                           vary=args.vary or (), samples=args.samples, ranges=args.ranges or (), seed=args.seed,
                           metrics=args.metric, output=args.output, jobs=args.jobs, t_end=args.t_end, dt=args.dt,
                           rederive=args.rederive, progress=not args.json and not _quiet(), point_timeout=args.point_timeout,
                           motors=args.motors, executor=args.executor, scheduler=args.scheduler,
                           inertia_ratio=_inertia_ratio(args))
    except KeyboardInterrupt as interrupt:
        partial = getattr(interrupt, "sweep_result", None)
        if partial is not None:
            where = f"; they are in {args.output}, and the same command resumes" if args.output else \
                    " (give -o FILE to keep them and resume)"
            print(f"sweep stopped after {len(partial.points)} of {partial.total} points{where}", file=sys.stderr)
        raise
    _print_diagnostics(list(result.warnings) + result.diagnostics())
    if args.json:
        _print_json(result.to_json())
    else:
        print(result.to_text())
        if args.output:
            print(f"results written to {args.output}")
    return EXIT_ERRORS if result.exit_code else EXIT_OK


def _cmd_lsp(args) -> int:
    from bondc.lsp import main as serve

    return serve()


def _cmd_fit_friction(args) -> int:
    from bondc.analysis.friction import run_fit_friction

    text, code = run_fit_friction(args.file, lead=args.lead, area=args.area, mass=args.mass,
                                  gravity=args.gravity, patm=args.patm, json=args.json)
    stream = sys.stdout if code == EXIT_OK or args.json else sys.stderr
    print(text, file=stream)
    return code


class _FitGroup(argparse.Action):
    """``bondc fit``'s --data, --experiment and --compare, kept in command-line order: each --data
    starts a data set, the --experiment and --compare after it belong to it."""

    def __call__(self, parser, namespace, values, option_string=None):
        items = list(getattr(namespace, "fit_items", None) or [])
        items.append((self.dest, values))
        namespace.fit_items = items
        if self.dest == "data" and getattr(namespace, "data", None) is None:
            namespace.data = values         # (the first: the inputs an output must not replace)


def _cmd_fit(args) -> int:
    from bondc.analysis.fit import parse_groups, run_fit

    datasets = parse_groups(getattr(args, "fit_items", None) or [])
    from bondc.report.fit_report import write_fit_report

    result = run_fit(args.file, datasets=datasets, estimates=args.estimate or [], model=args.model,
                     sets=args.set or (), max_evaluations=args.max_evaluations, output=args.output,
                     report=write_fit_report,
                     write=args.write, progress=not args.json and not _quiet(),
                     cache=False if args.no_cache else None)
    if args.json:
        _print_json(result.to_json())
    else:
        _print_diagnostics(result.diagnostics)
        print(result.to_text())
        for path in result.written:
            print(f"wrote {path}")
    return result.exit_status


def _megabytes(size: int) -> str:
    """A size for people: 0 B, 812 kB, 3.4 MB, 1.2 GB (powers of 1000, as BONDC_CACHE_MAX_MB)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{size} B"


def _cmd_cache(args) -> int:
    """``bondc cache info``: where each cache is, its entries and size; ``bondc cache clear``: remove
    what bondc wrote there (nothing else: see :func:`bondc.cache.clear`)."""
    from bondc import cache

    if args.action is None:
        raise UsageError(Diagnostic("error", codes.E001, "bondc cache: say what to do: info or clear",
                                    hint="bondc cache info [--json], bondc cache clear [--json]"))
    try:
        cache.max_bytes()
    except ValueError as error:
        raise UsageError(Diagnostic("error", codes.E001, str(error),
                                    hint="e.g. BONDC_CACHE_MAX_MB=500 (megabytes); 0 for no cap")) from None
    if args.action == "clear":
        removed = cache.clear()
        if args.json:
            _print_json({"complete": True, "folder": str(cache.cache_dir()),
                         "removed": [{"name": name, "entries": count, "bytes": size}
                                     for name, (count, size) in removed.items()]})
        elif not _quiet():
            count = sum(count for count, _ in removed.values())
            size = sum(size for _, size in removed.values())
            print(f"removed {count} cache entries ({_megabytes(size)}) from {cache.cache_dir()}")
        return EXIT_OK
    found = cache.info()
    if args.json:
        _print_json({"complete": True, **found})
        return EXIT_OK
    state = "on" if found["enabled"] else "off (BONDC_CACHE=0)"
    cap = "no cap" if found["max_bytes"] is None else f"cap {_megabytes(found['max_bytes'])}"
    print(f"cache folder {found['folder']} ({state}; compile cache {cap}, BONDC_CACHE_MAX_MB)")
    width = max(len(item["name"]) for item in found["caches"])
    for item in found["caches"]:
        print(f"  {item['name']:<{width}}  {item['entries']:>6} entries  {_megabytes(item['bytes']):>9}  "
              f"{item['folder']}")
    print(f"  {'total':<{width}}  {sum(i['entries'] for i in found['caches']):>6} entries  "
          f"{_megabytes(found['bytes']):>9}")
    return EXIT_OK


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
