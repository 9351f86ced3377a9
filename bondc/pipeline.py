"""The compiler's front half, one function per stage; every command, the API and the analyses
run their model through these::

    check_file    file (+ model, experiment, --set)  -> Checked      semantic: names, units, dimensions
    diagnose      file (+ model, --set)              -> Diagnosis    ``bondc check``: the stages up to the
                                                                     equations, every diagnostic they find
    diagnose_file file ...                           -> Diagnoses    each model of the file, diagnosed
    derive        Checked                            -> Derived      causality, then the state equations
    derive_file   file ...                           -> Derived      both, through the compile cache
    compile_file  file ...                           -> str          codegen: the model's Python module
    simulate_derived  Derived                        -> SimResult    the engine, with the external inputs
    simulate_file file ...                           -> SimResult    ``bondc simulate``: derive, run, write
    run_pipeline  file ...                           -> PipelineRun  what a report shows: every stage's value

Each value is a frozen dataclass carrying what the later stages need of the earlier ones (a
``Derived`` keeps the checked graph and its warnings). The stages raise a model's errors, except
in a diagnosis (``bondc check``, ``bondc.api.check``, the language server), which keeps what each
stage found, the warnings gathered before a failure too. Values are bound late: ``--set`` values
reuse the ``Derived`` compiled without them (:func:`rebind`), and a sweep's points give theirs to
the compiled module of its base model, so the model is not derived and compiled again.

>>> from pathlib import Path
>>> root = Path(__file__).resolve().parent.parent
>>> run = derive_file(root / "tests" / "fixtures" / "language" / "s10_complete_model.bg", sets=["k=400"])
>>> run.graph.parameters["k"].value, run.experiment.name, [s.name for s in run.state_space.states]
(400.0, 'step', ['mass.p', 'spring.q'])
>>> result = simulate_file(root / "tests/fixtures/sim/rc.bg", dt=0.5e-3)
>>> result.complete, round(float(result.outputs["v"][-1]), 4)
(True, 9.9326)
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping, Sequence

from bondc import ast
from bondc.errors import Diagnostic
from bondc import codes

if TYPE_CHECKING:
    import os

    from bondc.causality import CausalGraph
    from bondc.errors import BondcError
    from bondc.model import BondGraph, ExperimentDef
    from bondc.simulate import SimResult
    from bondc.source import Source
    from bondc.statespace import StateSpace

    #: A set value as a command gives it: ``"M=40 [kg]"``, or already parsed.
    SetText = str | ast.SetValue
    #: A model file's path.
    PathLike = str | os.PathLike[str]
    #: A file and the files it imports, parsed: what :func:`bondc.semantic.load_files` returns.
    Files = tuple[list[ast.File], dict[str, Source], list[Diagnostic]]


@contextlib.contextmanager
def fewer_collections() -> Iterator[None]:
    """Run the garbage collector's youngest generation every 100 000 allocations, not every 700.

    A compile allocates millions of parse-tree and sympy nodes and frees few of them, so the
    default thresholds spend a third of a 6000-state check in the collector, and more the larger
    the model (measured: chain N = 3000 compile 35.9 s -> 28.7 s, peak memory +7 %). mypy's
    command line does the same. The command line wraps a whole run in this; the thresholds are
    restored afterwards.
    """
    previous = gc.get_threshold()
    gc.set_threshold(100_000, 50, 100)
    try:
        yield
    finally:
        gc.set_threshold(*previous)


def parse_sets(sets: Sequence[SetText] | None) -> list[ast.SetValue]:
    """``--set`` texts (``"M=40"``, ``"M=40 [kg]"``) parsed; already parsed values pass through.

    A text that is not ``NAME=VALUE [unit]`` is the command line's fault: a UsageError (E007, exit
    status 2), not a ParseError of the model.
    """
    from bondc.errors import ParseError, UsageError
    from bondc.parse import parse_set_value
    from bondc.semantic import SET_HINT

    parsed = []
    for index, item in enumerate(sets or (), 1):
        if not isinstance(item, str):
            parsed.append(item)
            continue
        try:
            parsed.append(parse_set_value(item, f"--set #{index}"))
        except ParseError as error:
            first = error.diagnostics[0]
            detail = first.message[:1].lower() + first.message[1:]
            raise UsageError(Diagnostic("error", codes.E007, f"--set {item!r} is not NAME=VALUE [unit]: {detail}",
                                        first.span, hint=SET_HINT), error.sources) from None
    return parsed


def on_command_line(diagnostics: Sequence[Diagnostic]) -> bool:
    """Whether an error among ``diagnostics`` is about a value given on the command line (``--set``,
    ``--vary``): the command line is at fault, and the command exits with status 2."""
    return any(d.is_error and (d.span.file.startswith("--set #") or d.span.file.startswith("--vary "))
               for d in diagnostics)


def each_once(diagnostics: Iterable[Diagnostic]) -> tuple[Diagnostic, ...]:
    """``diagnostics`` in order, each once (a stage may report what an earlier one did)."""
    return tuple(dict.fromkeys(diagnostics))


def chosen_experiment(graph: BondGraph, name: str | None) -> ExperimentDef | None:
    """The experiment called ``name``, or the model's first one (None if it has none)."""
    if not graph.experiments:
        return None
    return graph.experiments[name] if name is not None else next(iter(graph.experiments.values()))


# ------------------------------------------------------------------ check


@dataclass(frozen=True)
class Checked:
    """A checked model: its graph with the experiment's overrides and the ``--set`` values applied."""

    graph: BondGraph
    warnings: tuple[Diagnostic, ...]        # of the semantic stage
    experiment: ExperimentDef | None        # the one whose overrides were applied
    sets: tuple[ast.SetValue, ...]          # the parsed --set values


def check_file(path: PathLike, *, model: str | None = None, experiment: str | None = None,
               sets: Sequence[SetText] = (), text: str | None = None, first_experiment: bool = True,
               loaded: Files | None = None) -> Checked:
    """Read and check ``path`` (``text``: its text, when it is not read from disk; ``loaded``: its
    files as :func:`bondc.semantic.load_files` parsed them, when they are parsed already) with
    ``experiment``'s overrides and ``sets``; raises ModelError (or UsageError for a ``--set`` text
    that does not parse). ``experiment`` None: the model's first experiment's overrides apply, or
    with ``first_experiment`` False none (the model as written: ``bondc check``, ``bondc.api.load``)."""
    from bondc import semantic

    parsed = parse_sets(sets)
    applied = experiment if experiment is not None else semantic.FIRST if first_experiment else None
    graph, warnings = semantic.load(Path(path), model=model, experiment=applied, sets=parsed, text=text,
                                    loaded=loaded)
    chosen = chosen_experiment(graph, experiment) if applied is not None else None
    return Checked(graph, tuple(warnings), chosen, tuple(parsed))


# ------------------------------------------------------------------ diagnose


@dataclass(frozen=True)
class Diagnosis:
    """What ``bondc check`` finds in one model: every stage's diagnostics and the values of the
    stages that ran. A stage that fails stops the later ones; what the earlier ones found stays."""

    diagnostics: tuple[Diagnostic, ...]     # every stage's, each once, in stage order
    # the failed stage's own diagnostics (an error's, or those of equations that cannot be
    # derived), None when no stage failed
    failure: tuple[Diagnostic, ...] | None
    error: BondcError | None                # what the failed stage raised (None: none raised)
    sources: Mapping[str, Source]           # the texts the diagnostics point into
    checked: Checked | None                 # the semantic stage's value (None: it failed)
    causal: CausalGraph | None              # None: a component, the stage not reached, or failed
    states: tuple[str, ...] | None          # the states the equations keep (None: not run, or failed)
    component: bool                         # a model with ports: causality is checked where it is used

    @property
    def ok(self) -> bool:
        """Whether no diagnostic is an error."""
        return not any(d.is_error for d in self.diagnostics)


def _nothing() -> None:
    return None


def diagnose(path: PathLike, *, model: str | None = None, sets: Sequence[SetText] = (), text: str | None = None,
             loaded: Files | None = None, component: bool = False, editing: bool = False,
             cache: bool | None = None, checkpoint: Callable[[], None] = _nothing) -> Diagnosis:
    """Check one model of ``path`` as ``bondc check`` does, never raising for the model: the
    semantic stage (:func:`check_file`, no experiment's overrides), then, unless it is a
    ``component``, the I346 notes of its external inputs, causality and what the equations stage
    would report (:func:`equations_checked`).

    ``editing``: what an editor shows as the model is typed: semantic and causality only (neither
    I346 nor the equations stage, which imports sympy). ``cache``: see :func:`equations_checked`.
    ``checkpoint`` is called between stages (the language server stops a superseded analysis
    there). ``loaded``, ``text``: see :func:`check_file`."""
    from bondc.errors import BondcError

    found: list[Diagnostic] = []       # every stage's, in order (each once: see the end)
    checked: Checked | None = None
    causal: CausalGraph | None = None
    states: tuple[str, ...] | None = None
    failure: tuple[Diagnostic, ...] | None = None
    error: BondcError | None = None
    sources: Mapping[str, Source] = {}
    try:
        checked = check_file(path, model=model, sets=sets, text=text, first_experiment=False, loaded=loaded)
        graph = checked.graph
        sources = graph.sources
        found += checked.warnings
        if not component:
            if not editing:
                from bondc.model import external_input_notes

                found += external_input_notes(graph)
            checkpoint()
            from bondc.causality import assign_causality

            causal = assign_causality(graph)
            found += causal.diagnostics
            if not editing:
                states, notes = equations_checked(graph, causal, model=model, sets=sets, cache=cache)
                found += notes
                if states is None:
                    failure = notes
    except BondcError as raised:
        error, failure = raised, tuple(raised.diagnostics)
        found += raised.diagnostics
        sources = raised.sources or sources
    return Diagnosis(each_once(found), failure, error, sources, checked, causal, states, component)


def _failed(error: BondcError) -> Diagnosis:
    """The diagnosis of a file whose text does not parse or cannot be read."""
    return Diagnosis(each_once(error.diagnostics), tuple(error.diagnostics), error, error.sources, None, None, None, False)


@dataclass(frozen=True)
class Diagnoses:
    """Every model of a file diagnosed (:func:`diagnose_file`), and the file's parse."""

    models: tuple[Diagnosis, ...]
    loaded: Files | None                    # the parsed files (None: the file does not parse)

    @property
    def diagnostics(self) -> tuple[Diagnostic, ...]:
        """Every model's diagnostics, each once, in the models' order."""
        return each_once(d for diagnosis in self.models for d in diagnosis.diagnostics)

    @property
    def sources(self) -> dict[str, Source]:
        """Every model's sources."""
        return {name: source for diagnosis in self.models for name, source in diagnosis.sources.items()}


def diagnose_file(path: PathLike, *, model: str | None = None, sets: Sequence[SetText] = (),
                  text: str | None = None, editing: bool = False, cache: bool | None = None,
                  checkpoint: Callable[[], None] = _nothing) -> Diagnoses:
    """:func:`diagnose` each model ``bondc check`` looks at in ``path``, parsing it once: ``model``,
    or every model the file defines (LANGUAGE.md section 11: one with ports is a component, its
    causality checked where it is used). ``checkpoint`` is also called before each model."""
    from bondc import semantic
    from bondc.errors import BondcError
    from bondc.flatten import ports_of

    try:
        loaded = semantic.load_files(Path(path), text)
    except BondcError as error:
        return Diagnoses((_failed(error),), None)
    own = loaded[0][0].models
    chosen: list[tuple[str | None, bool]]
    if model is not None:
        named = [m for file in loaded[0] for m in file.models if m.name == model]
        chosen = [(model, bool(named and ports_of(named[0])))]
    elif len(own) <= 1:
        chosen = [(None, bool(own and ports_of(own[0])))]
    else:
        chosen = [(m.name, bool(ports_of(m))) for m in own]
    found: list[Diagnosis] = []
    for name, component in chosen:
        checkpoint()
        found.append(diagnose(path, model=name, sets=sets, text=text, loaded=loaded, component=component,
                              editing=editing, cache=cache, checkpoint=checkpoint))
    return Diagnoses(tuple(found), loaded)


def equations_checked(graph: BondGraph, causal: CausalGraph, *, model: str | None = None,
                      sets: Sequence[SetText] = (), cache: bool | None = None
                      ) -> tuple[tuple[str, ...] | None, tuple[Diagnostic, ...]]:
    """What the equations stage reports of a model, for ``check``: (the names of the states it
    keeps, or None where it fails; its diagnostics), e.g. a law that cannot be inverted (E605).

    Without sympy where :func:`bondc.quickcheck.equations_findings` is certain. ``cache`` (default:
    on unless ``BONDC_CACHE=0``): taken from the check cache when bondc and every file the model
    read are unchanged (``bondc.cache.check_key``), or differ only in parameter values that the
    equations stage did not use (``bondc.cache.check_key_of_structure``); then sympy is not even
    imported. ``model`` and ``sets`` (as given) are part of the key."""
    from bondc import cache as check_cache

    use_cache = check_cache.enabled() if cache is None else cache
    key = check_cache.check_key(graph.sources, model, sets) if use_cache else None
    known = check_cache.load_check(key) if key else None
    # after an edit of parameter values only: the equations stage of the same model with other
    # values, when no value decided anything there
    structural, value_lines = check_cache.check_key_of_structure(graph.sources, graph, model, sets) \
        if key and known is None else (None, frozenset())

    def on_edited_lines(diagnostics: Sequence[Diagnostic]) -> bool:     # their columns may have moved
        return any((d.span.file, d.span.line) in value_lines for d in diagnostics)

    if structural:
        known = check_cache.load_check(structural)
        if known is not None and on_edited_lines(known[1]):
            known = None
    if known is None:
        from bondc.quickcheck import equations_findings

        known, consulted = equations_findings(causal)
        if key:
            check_cache.store_check(key, known)
        if structural and not consulted and not on_edited_lines(known[1]):
            check_cache.store_check(structural, known)
    states, diagnostics = known
    return (None if states is None else tuple(states)), tuple(diagnostics)


# ------------------------------------------------------------------ derive


@dataclass(frozen=True)
class Derived:
    """A model's state equations and every value they were derived from."""

    graph: BondGraph
    warnings: tuple[Diagnostic, ...]        # of the semantic stage
    causal: CausalGraph
    # ``derive_file(light=True)`` may give a cache.LightStateSpace in its place: what a simulation
    # needs without sympy, loading the full StateSpace when asked for anything else
    state_space: StateSpace
    experiment: ExperimentDef | None        # the one whose overrides were applied
    sets: tuple[ast.SetValue, ...]          # the parsed --set values

    @property
    def notes(self) -> tuple[Diagnostic, ...]:
        """Every warning and note of the three stages, each once, in stage order."""
        return each_once((*self.warnings, *self.causal.diagnostics, *self.state_space.diagnostics))


def derive(checked: Checked) -> Derived:
    """Assign causality to a checked model and derive its state equations; raises CausalityError
    or EquationError."""
    from bondc.causality import assign_causality
    from bondc.equations import derive as state_equations

    causal = assign_causality(checked.graph)
    return Derived(checked.graph, checked.warnings, causal, state_equations(causal), checked.experiment,
                   checked.sets)


def derive_file(path: PathLike, *, model: str | None = None, experiment: str | None = None,
                sets: Sequence[SetText] = (), cache: bool | None = None, light: bool = False,
                text: str | None = None) -> Derived:
    """Load ``path`` with ``experiment``'s overrides (default: the first experiment) and ``sets``,
    assign causality and derive the state equations. Raises the stages' errors.

    ``cache`` (default: on unless ``BONDC_CACHE=0``): reuse the result of an earlier run on the
    same files with the same model, experiment and ``--set`` values (see :mod:`bondc.cache`).
    ``light``: a cached entry may give a :class:`bondc.cache.LightStateSpace` (what a simulation
    and its energy account need, without sympy); anything else it is asked for loads the rest.
    ``text``: the file's text, not read from disk (never cached).
    """
    if text is not None:
        return derive(check_file(path, model=model, experiment=experiment, sets=sets, text=text))
    from bondc import cache as compile_cache

    use_cache = compile_cache.enabled() if cache is None else cache
    entry = compile_cache.Entry.for_model(path, model, experiment, sets) if use_cache else None
    if entry is not None and light and not sets:
        derived = entry.load_light()
        if derived is not None:
            return derived
    if entry is not None:
        derived = entry.load()
        if derived is not None:
            return derived

    checked = check_file(path, model=model, experiment=experiment, sets=sets)
    if checked.sets and use_cache:
        bound = _bind_to_base(path, model, experiment, checked)
        if bound is not None:
            return bound
    derived = derive(checked)
    if entry is not None:
        entry.store(derived)
    return derived


def structure(graph: BondGraph) -> tuple[object, ...]:
    """What a model's derivation and compiled module are built from besides parameter values: the
    parameters' names, the inputs (the experiments' too). Two checks of one file with the same
    structure differ only in values, which the compiled module takes as its parameter vector."""
    experiment_inputs = tuple(sorted((name, repr(signal)) for experiment in graph.experiments.values()
                                     for name, signal in experiment.inputs.items()))
    return (tuple(graph.parameters), tuple((name, repr(signal)) for name, signal in graph.inputs.items()),
            experiment_inputs)


def _bind_to_base(path: PathLike, model: str | None, experiment: str | None, checked: Checked) -> Derived | None:
    """``--set`` values bound late: the model derived and compiled without them (from the compile
    cache, or derived now and stored there) with ``checked``'s values (checked with them) as its
    parameters. None when the base model does not check or differs in structure."""
    from bondc.errors import BondcError

    try:
        base = derive_file(path, model=model, experiment=experiment, sets=(), cache=True)
    except BondcError:
        return None
    graph = checked.graph
    if structure(base.graph) != structure(graph) or file_texts(base.graph) != file_texts(graph):
        return None
    return Derived(graph, checked.warnings, base.causal, rebind(base.state_space, graph), checked.experiment,
                   checked.sets)


def file_texts(graph: BondGraph) -> dict[str, str]:
    """The text of every file a checked model read (not the --set texts), by file name."""
    return {name: source.text for name, source in graph.sources.items() if source.path is not None}


def rebind(state_space: StateSpace, graph: BondGraph) -> StateSpace:
    """``state_space`` with ``graph``'s parameter values (and ``graph``); its compiled module is
    ``state_space``'s, given every parameter value (``bound_base``, used by ``simulate``)."""
    values = {name: (symbol, float(graph.parameters[name].value) if name in graph.parameters else value)
              for name, (symbol, value) in state_space.parameters.items()}
    return dataclasses.replace(state_space, parameters=values, graph=graph,
                               bound_base=state_space.bound_base or state_space)


#: The built-in functions whose every use is a switch (LANGUAGE.md section 7); an ``if`` is one too.
SWITCH_FUNCTIONS = frozenset({"abs", "sign", "min", "max", "step", "table", "floor", "ceil", "mod", "pwm",
                              "coulomb", "heaviside"})


def _has_switch(node: object) -> bool:
    """Whether a parsed file (or any node of it) writes an ``if`` or a switching built-in."""
    if isinstance(node, ast.If) or (isinstance(node, ast.Call) and node.func in SWITCH_FUNCTIONS):
        return True
    if isinstance(node, (tuple, list)):
        return any(_has_switch(item) for item in node)
    if not dataclasses.is_dataclass(node):
        return False
    return any(_has_switch(getattr(node, field.name)) for field in dataclasses.fields(node)
               if field.name not in ("span", "func_span"))


def switches_of(path: PathLike, graph: BondGraph, loaded: tuple[Any, ...] | None = None, *,
                sets: Sequence[SetText] = (), cache: bool = True) -> tuple[dict[str, Any], ...]:
    """Every switch of ``graph``'s laws as the engine treats it (``codegen.emit.switch_kinds``),
    each ``{"switch", "kind", "variable", "file", "line"}`` with its law's place: ``check --json``.

    A model whose files (``loaded``: ``semantic.load_files``'s, else read again) write no switch has
    none, found without sympy; the others are derived once per content of the files and kept in
    the check cache, so that checking them again imports no sympy either."""
    from bondc import cache as compile_cache
    from bondc import semantic

    files = (loaded or semantic.load_files(Path(path)))[0]
    if not _has_switch(files):
        return ()
    key = compile_cache.check_key(graph.sources, graph.name, sets) + "-switches" if cache else None
    known = compile_cache.load_check(key) if key else None
    if known is not None:
        return tuple(known)
    from bondc.codegen.emit import switch_kinds
    from bondc.model import law_span, readable, readable_names

    derived = derive_file(path, model=graph.name, sets=sets, cache=cache)
    names = readable_names(graph)
    rows = []
    for label, kind, variable in switch_kinds(derived.state_space):
        span = law_span(graph, variable.removeprefix("output "))
        rows.append({"switch": readable(names, label), "kind": kind, "variable": readable(names, variable),
                     "file": span.file if span else None, "line": span.line if span else None})
    found = tuple(rows)
    if key:
        compile_cache.store_check(key, found)
    return found


# ------------------------------------------------------------------ compile


def default_output(path: PathLike) -> Path:
    """Where ``bondc compile model.bg`` writes without ``-o``: ``model_gen.py`` next to the model."""
    path = Path(path)
    return path.with_name(path.stem + "_gen.py")


def compile_file(path: PathLike, output: PathLike | None = None, *, model: str | None = None,
                 experiment: str | None = None, sets: Sequence[SetText] = (), standalone: bool = False) -> str:
    """``bondc compile``: load, check, derive and emit; write ``output`` (atomically) if given.

    The module imports ``bondc.runtime``; ``standalone`` copies the runtime in instead, so the
    module runs where bondc is not installed (numpy and scipy, and scikit-sundae for CVODE).

    ``experiment`` None takes the model's first experiment (its settings become
    the module's defaults); ``sets`` are ``--set`` texts or parsed SetValues;
    csv data paths are written relative to ``output``'s directory. Returns the
    module's source. Raises the stage errors (ModelError, CausalityError,
    EquationError, UsageError) for a model that cannot be compiled.
    """
    from bondc.codegen.emit import emit
    from bondc.io import atomic_write_text, check_output

    if output is not None:
        check_output(output)
    derived = derive_file(path, model=model, experiment=experiment, sets=sets)
    module_dir = Path(output).resolve().parent if output is not None else Path(path).resolve().parent
    source: str = emit(derived.state_space, derived.experiment, source=Path(path).name, module_dir=module_dir,
                       standalone=standalone)
    if output is not None:
        atomic_write_text(Path(output), source)
    return source


# ------------------------------------------------------------------ simulate


def simulate_derived(derived: Derived, *, t_end: float | None = None, dt: float | None = None,
                     progress: bool = False, inputs: Mapping[str, Any] | None = None,
                     input_files: Sequence[str] | None = ()) -> SimResult:
    """Run ``derived`` with its experiment's settings (``t_end`` [s] and ``dt`` override them);
    ``inputs`` and ``input_files`` (``"u=FILE.csv[:COLUMN]"`` texts, as ``--input``) supply its
    external inputs. Never raises for a failed run (see ``SimResult.complete``)."""
    from bondc.simulate import read_input_files, simulate

    supplied = inputs
    if input_files:
        supplied = {**read_input_files(derived.state_space, input_files), **dict(inputs or {})}
    return simulate(derived.state_space, derived.experiment, t_end=t_end, dt=dt, progress=progress,
                    inputs=supplied)


def simulate_file(path: PathLike, *, model: str | None = None, experiment: str | None = None,
                  sets: Sequence[SetText] = (), t_end: float | None = None, dt: float | None = None,
                  output: PathLike | None = None, all_bonds: bool = False, progress: bool = False,
                  inputs: Mapping[str, Any] | None = None, input_files: Sequence[str] = (),
                  text: str | None = None) -> SimResult:
    """``bondc simulate``: load, check, derive, simulate and write; returns the result, its
    warnings those of every stage.

    ``experiment`` None uses the model's first experiment (if any); ``sets``
    are ``--set`` texts (``"M=40"``, ``"M=40 [kg]"``) or parsed
    ``ast.SetValue``; ``inputs``/``input_files`` supply external inputs (``{name: (times, values)
    or f(t)}``; ``"u=FILE.csv[:COLUMN]"`` texts as ``--input``); ``output`` a ``.csv``, ``.npz`` or
    ``.parquet`` path (None: write nothing); ``text`` the model's text when it is not read from
    ``path``. Raises ModelError/CausalityError/EquationError/UsageError for a
    model or usage problem. A failed run writes what it computed, then raises
    :class:`SimulationError` whose ``.result`` is the incomplete result.
    """
    from bondc.io import check_output
    from bondc.simulate import check_result_path, write

    if output is not None:
        check_result_path(output)
        check_output(output)        # before any work: a bad path is not found after the run
    derived = derive_file(path, model=model, experiment=experiment, sets=sets, text=text)
    ran = simulate_derived(derived, t_end=t_end, dt=dt, progress=progress, inputs=inputs, input_files=input_files)
    result = dataclasses.replace(ran, warnings=(*derived.notes, *ran.warnings))
    if output is not None:
        write(result, output, all_bonds)
    error = result.error()
    if error is not None:
        raise error
    return result


# ------------------------------------------------------------------ report inputs


@dataclass(frozen=True)
class PipelineRun:
    """What the pipeline computed for one report: each stage's result, the simulation possibly partial.

    ``result`` is None when the model could not be simulated because nothing
    gives an end time (no experiment sets ``t_end`` and none was passed).
    ``experiment`` is the experiment applied (None for a model without one),
    ``default_experiment`` whether it is the model's first.
    """

    path: Path
    source_text: str
    graph: BondGraph
    causal: CausalGraph
    state_space: StateSpace
    experiment: ExperimentDef | None
    default_experiment: bool
    result: SimResult | None
    warnings: tuple[Diagnostic, ...]
    overridden: tuple[str, ...]     # parameters set by the experiment or by ``sets``

    @property
    def complete(self) -> bool:
        return self.result is not None and bool(self.result.complete)


def run_pipeline(path: PathLike, *, model: str | None = None, experiment: str | None = None,
                 sets: Sequence[SetText] = (), t_end: float | None = None, progress: bool = False) -> PipelineRun:
    """Load ``path`` with the experiment's overrides (default: the first), assign causality, derive, simulate.

    ``sets`` are ``--set`` texts (``"M=40"``, ``"M=40 [kg]"``) or parsed
    ``ast.SetValue``; ``t_end`` [s] overrides the experiment's end time.
    Raises what the stages raise for a bad model (ParseError, ModelError,
    CausalityError, EquationError, UsageError); a simulation that fails does
    not raise: see :attr:`PipelineRun.complete`.
    """
    path = Path(path)
    derived = derive_file(path, model=model, experiment=experiment, sets=sets)
    graph, chosen = derived.graph, derived.experiment
    default = chosen is None or chosen.name == next(iter(graph.experiments))
    result = None
    if t_end is not None or (chosen is not None and chosen.t_end is not None):
        result = simulate_derived(derived, t_end=t_end, progress=progress)
    notes = list(derived.notes)
    if result is not None:
        notes += [d for d in result.warnings if d not in notes]
    overridden = list(chosen.parameters) if chosen is not None else []
    overridden += [item.name for item in derived.sets if item.name not in overridden]
    source = graph.sources.get(graph.file)
    text = source.text if source is not None else path.read_text(encoding="utf-8")
    return PipelineRun(path, text, graph, derived.causal, derived.state_space, chosen, default, result,
                       tuple(notes), tuple(overridden))
