"""The commands of ``bondc``: what each subcommand does with its parsed arguments (``_cmd_check``,
``_cmd_simulate``, ...), and the printing they share (diagnostics, JSON, notes by verbosity). Each
returns its exit status; :mod:`bondc.cli` parses the command line and dispatches to them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from bondc.errors import BondcError, Diagnostic, UsageError, render_all
from bondc.io import json_safe
from bondc import codes

EXIT_OK, EXIT_ERRORS, EXIT_USAGE = 0, 1, 2


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

def _switches_json(args, graph, loaded) -> list[dict]:
    """Every switch of a checked model's laws, a kink or a jump, with its law's file and line
    (``check --json``; :func:`bondc.pipeline.switches_of`)."""
    from bondc.pipeline import switches_of

    use_cache = not getattr(args, "no_cache", False)
    return [dict(row) for row in switches_of(args.file, graph, loaded, sets=args.set, cache=use_cache)]


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
    """Every model of one file through the stages up to the equations (:func:`bondc.pipeline.diagnose_file`)."""
    from bondc.pipeline import diagnose_file

    checks = diagnose_file(args.file, model=args.model, sets=args.set,
                           cache=False if getattr(args, "no_cache", False) else None)
    for diagnosis in checks.models:
        if diagnosis.error is not None and diagnosis.error.stage in ("usage",):
            raise diagnosis.error
    diagnostics = list(checks.diagnostics)
    ok = not any(d.is_error for d in diagnostics)
    results = [(d.checked.graph if d.checked is not None else None, d.causal, d.component, d.states)
               for d in checks.models]
    if args.json:
        summaries = []
        for graph, causal, component, states in results:
            summary = graph.summary() if graph is not None else None
            if summary is not None and causal is not None:
                summary["causality"] = causal.summary()
            if summary is not None and states is not None:
                summary["states_kept"] = len(states)
                if ok:
                    summary["switches"] = _switches_json(args, graph, checks.loaded)
            if summary is not None and component:
                summary["component"] = True
            summaries.append(summary)
        data = {"ok": ok, "diagnostics": [d.to_json() for d in diagnostics], "model": summaries[0]}
        if len(summaries) > 1:
            data["models"] = summaries
        return _status(diagnostics), data
    _print_diagnostics(diagnostics, checks.sources)
    for graph, causal, component, states in results:
        if graph is None or (_quiet() and not args.causality):
            continue
        counts = graph.summary()
        line = (f"{graph.name}: {counts['elements']} elements, {counts['junctions']} junctions, "
                f"{counts['bonds']} bonds, {counts['storage_elements']} storage elements, "
                f"{counts['states']} states")
        if states is not None and len(states) != counts["states"]:
            line += f" ({len(states)} kept by the equations)"
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
