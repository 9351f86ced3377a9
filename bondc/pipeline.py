"""The front half of every command: file -> checked graph -> causality -> state equations.

``derive_file`` runs ``semantic.load`` (with the experiment's overrides and the
command line's ``--set`` values), ``assign_causality`` and ``derive``, and
picks the experiment to run. ``simulate``, ``compile``, ``report``,
``equations``, ``linearize`` and ``sweep`` all start here.

>>> from pathlib import Path
>>> root = Path(__file__).resolve().parent.parent
>>> run = derive_file(root / "tests" / "fixtures" / "language" / "s10_complete_model.bg", sets=["k=400"])
>>> run.graph.parameters["k"].value, run.experiment.name, [s.name for s in run.state_space.states]
(400.0, 'step', ['mass.p', 'spring.q'])
"""

from __future__ import annotations

import contextlib
import gc
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from bondc import ast
from bondc.errors import Diagnostic


@contextlib.contextmanager
def fewer_collections():
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


def parse_sets(sets: Sequence) -> list[ast.SetValue]:
    """``--set`` texts (``"M=40"``, ``"M=40 [kg]"``) parsed; already parsed values pass through.

    A text that is not ``NAME=VALUE [unit]`` is the command line's fault: a UsageError (E007, exit
    status 2), not a ParseError of the model.
    """
    from bondc.errors import Diagnostic, ParseError, UsageError
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
            raise UsageError(Diagnostic("error", "E007", f"--set {item!r} is not NAME=VALUE [unit]: {detail}",
                                        first.span, hint=SET_HINT), error.sources) from None
    return parsed


def on_command_line(diagnostics) -> bool:
    """Whether an error among ``diagnostics`` is about a value given on the command line (``--set``,
    ``--vary``): the command line is at fault, and the command exits with status 2."""
    return any(d.is_error and (d.span.file.startswith("--set #") or d.span.file.startswith("--vary "))
               for d in diagnostics)


def chosen_experiment(graph, name: str | None):
    """The experiment called ``name``, or the model's first one (None if it has none)."""
    if not graph.experiments:
        return None
    return graph.experiments[name] if name is not None else next(iter(graph.experiments.values()))


@dataclass(frozen=True)
class Derived:
    graph: object            # model.BondGraph
    warnings: tuple          # from the semantic stage
    causal: object           # causality.CausalGraph
    state_space: object      # statespace.StateSpace
    experiment: object       # model.ExperimentDef | None: the one whose overrides were applied
    sets: tuple              # the parsed --set values

    @property
    def notes(self) -> tuple[Diagnostic, ...]:
        """Every warning and note of the three stages, each once, in stage order."""
        notes: list[Diagnostic] = []
        for diagnostic in (*self.warnings, *self.causal.diagnostics, *self.state_space.diagnostics):
            if diagnostic not in notes:
                notes.append(diagnostic)
        return tuple(notes)


def derive_file(path, *, model: str | None = None, experiment: str | None = None,
                sets: Sequence = (), cache: bool | None = None, light: bool = False) -> Derived:
    """Load ``path`` with ``experiment``'s overrides (default: the first experiment) and ``sets``,
    assign causality and derive the state equations. Raises the stages' errors.

    ``cache`` (default: on unless ``BONDC_CACHE=0``): reuse the result of an earlier run on the
    same files with the same model, experiment and ``--set`` values (see :mod:`bondc.cache`).
    ``light``: a cached entry may give a :class:`bondc.cache.LightStateSpace` (what a simulation
    and its energy account need, without sympy); anything else it is asked for loads the rest.
    """
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

    from bondc import semantic
    from bondc.causality import assign_causality
    from bondc.equations import derive

    parsed = parse_sets(sets)
    graph, warnings = semantic.load(Path(path), model=model,
                                    experiment=experiment if experiment is not None else semantic.FIRST,
                                    sets=parsed)
    if parsed and use_cache:
        bound = _bind_to_base(path, model, experiment, graph, warnings, parsed)
        if bound is not None:
            return bound
    causal = assign_causality(graph)
    derived = Derived(graph, tuple(warnings), causal, derive(causal), chosen_experiment(graph, experiment),
                      tuple(parsed))
    if entry is not None:
        entry.store(derived)
    return derived


def structure(graph) -> tuple:
    """What a model's derivation and compiled module are built from besides parameter values: the
    parameters' names, the inputs (the experiments' too). Two checks of one file with the same
    structure differ only in values, which the compiled module takes as its parameter vector."""
    experiment_inputs = tuple(sorted((name, repr(signal)) for experiment in graph.experiments.values()
                                     for name, signal in experiment.inputs.items()))
    return (tuple(graph.parameters), tuple((name, repr(signal)) for name, signal in graph.inputs.items()),
            experiment_inputs)


def _bind_to_base(path, model, experiment, graph, warnings, parsed) -> Derived | None:
    """``--set`` values bound late: the model derived and compiled without them (from the compile
    cache, or derived now and stored there) with ``graph``'s values (checked with them) as its
    parameters. None when the base model does not check or differs in structure."""
    from bondc.errors import BondcError

    try:
        base = derive_file(path, model=model, experiment=experiment, sets=(), cache=True)
    except BondcError:
        return None
    if structure(base.graph) != structure(graph) or _texts(base.graph) != _texts(graph):
        return None
    return Derived(graph, tuple(warnings), base.causal, rebind(base.state_space, graph),
                   chosen_experiment(graph, experiment), tuple(parsed))


def _texts(graph) -> tuple:
    """The text of every file a checked model read (not the --set texts)."""
    return tuple(sorted((name, source.text) for name, source in graph.sources.items() if source.path is not None))


def rebind(state_space, graph):
    """``state_space`` with ``graph``'s parameter values (and ``graph``); its compiled module is
    ``state_space``'s, given every parameter value (``bound_base``, used by ``simulate``)."""
    import dataclasses

    values = {name: (symbol, float(graph.parameters[name].value) if name in graph.parameters else value)
              for name, (symbol, value) in state_space.parameters.items()}
    bound = dataclasses.replace(state_space, parameters=values, graph=graph)
    object.__setattr__(bound, "bound_base", getattr(state_space, "bound_base", None) or state_space)
    return bound


#: The built-in functions whose every use is a switch (LANGUAGE.md section 7); an ``if`` is one too.
SWITCH_FUNCTIONS = frozenset({"abs", "sign", "min", "max", "step", "table", "floor", "ceil", "mod", "pwm",
                              "coulomb", "heaviside"})


def _has_switch(node) -> bool:
    """Whether a parsed file (or any node of it) writes an ``if`` or a switching built-in."""
    if isinstance(node, ast.If) or (isinstance(node, ast.Call) and node.func in SWITCH_FUNCTIONS):
        return True
    if isinstance(node, (tuple, list)):
        return any(_has_switch(item) for item in node)
    fields = getattr(node, "__dataclass_fields__", None)
    if not fields:
        return False
    return any(_has_switch(getattr(node, name)) for name in fields if name not in ("span", "func_span"))


def switches_of(path, graph, loaded=None, *, sets: Sequence = (), cache: bool = True) -> tuple:
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
        return known
    from bondc.codegen.emit import switch_kinds
    from bondc.model import readable, readable_names
    from bondc.model import law_span

    derived = derive_file(path, model=graph.name, sets=sets, cache=cache)
    names = readable_names(graph)
    rows = []
    for label, kind, variable in switch_kinds(derived.state_space):
        span = law_span(graph, variable.removeprefix("output "))
        rows.append({"switch": readable(names, label), "kind": kind, "variable": readable(names, variable),
                     "file": span.file if span else None, "line": span.line if span else None})
    rows = tuple(rows)
    if key:
        compile_cache.store_check(key, rows)
    return rows


def default_output(path) -> Path:
    """Where ``bondc compile model.bg`` writes without ``-o``: ``model_gen.py`` next to the model."""
    path = Path(path)
    return path.with_name(path.stem + "_gen.py")


def compile_file(path, output=None, *, model: str | None = None, experiment: str | None = None,
                 sets: Sequence = (), standalone: bool = False) -> str:
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
    source = emit(derived.state_space, derived.experiment, source=Path(path).name, module_dir=module_dir,
                  standalone=standalone)
    if output is not None:
        atomic_write_text(Path(output), source)
    return source
