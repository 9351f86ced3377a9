"""A model's C code and header for embedding (``bondc compile FILE --target c -o DIR``).

:func:`c_model` prints the model's laws as C with bondc's code generation (the same plan, common
subexpressions and C printer as the compiled engine's functions, :class:`bondc.codegen.emit.
_NativeEmitter`) and describes its interface: parameters, states, external inputs and outputs with
their names (bondc's: ``valve.A``), SI units, descriptions and default values; the Jacobian's
sparsity pattern; the switching functions. :func:`write_c` writes ``DIR/<Model>.c`` and
``DIR/<Model>.h``. Both texts are byte-identical for the same model (no dates, no paths).

The layout of the parameter vector ``p`` the functions take: the model's parameters (SI, in the
header's order), then the current values of its external inputs. The modes ``m``: one per
switching function, ``sign(g)`` (``floor(g)`` for a floor switch), held between events.
FMUs (:mod:`bondc.export.fmu`) are built from the same text.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from bondc.version import __version__
from bondc.errors import BondcError, Diagnostic
from bondc.codegen.cprinter import c_double
from bondc.source import NO_SPAN
from bondc.symbolic import as_sympy
from bondc import codes

#: The C functions of an exported model (each ``void f(double t, const double *x, const double *p,
#: const double *m, double *out)``), in the header's order
FUNCTIONS = ("bondc_rhs", "bondc_jac", "bondc_switches", "bondc_outputs", "bondc_when_conditions",
             "bondc_when_actions")


@dataclass(frozen=True)
class Unit:
    """A quantity's unit: its SI unit as text (as the model writes it where that is SI, ``N/m``;
    else its dimensions, ``kg/(m*s^2)`` for ``kPa``), the exponents of that unit over m, kg, s, A,
    K, mol, cd, rad (None where not whole numbers or unknown), and the unit the model shows it in
    with its factor (display = SI / factor), or None."""

    si: str
    dims: tuple | None
    display: tuple | None = None


@dataclass(frozen=True)
class Quantity:
    name: str
    value: float            # SI: a parameter's, an input's default, a state's initial value at the defaults
    unit: Unit | None
    description: str
    derived: bool = False   # a parameter computed from others (bondc_derive_parameters)


@dataclass
class CModel:
    """A model's C text and its interface (what the header documents, and an FMU describes)."""

    name: str                       # the model's name (a C identifier: the files' names)
    source_file: str                # the model file's name
    c_text: str                     # the .c file (includes the header by ``header_name``)
    header: str                     # the .h file
    header_name: str
    parameters: list                # [Quantity]
    states: list
    inputs: list                    # external inputs, their defaults
    outputs: list
    jacobian: list                  # [(row, column)], column by column
    switch_labels: list
    floors: list                    # 1 where m = floor(g)
    located: list                   # 1 where the switch's mode can change (an event or a known time)
    switch_owners: list             # the variable whose law has each switch
    whens: list = field(default_factory=list)      # [(label, [state index])]
    vertices: list = field(default_factory=list)   # each switch's mode on its plus side (2: coulomb)
    when_native: bool = True
    experiment: dict = field(default_factory=dict)  # t_end, rtol, atol, max_step
    plan: object = None


_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def c_identifier(name: str) -> str:
    """``name`` as a C identifier (other characters as ``_``; a leading digit gets ``m``)."""
    text = re.sub(r"[^A-Za-z0-9_]", "_", name) or "model"
    return text if _IDENTIFIER.match(text) else "m" + text


def c_string(text: str) -> str:
    """A C string literal of ``text``: printable ASCII as it is (``\\``, ``"`` and ``?`` escaped),
    everything else as octal escapes of its UTF-8 bytes."""
    out = []
    for byte in (text or "").encode("utf-8"):
        char = chr(byte)
        if char in '\\"?':
            out.append("\\" + char)
        elif 32 <= byte < 127:
            out.append(char)
        else:
            out.append(f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def si_unit(text: str | None, display_factor: float = 1.0) -> Unit | None:
    """The :class:`Unit` of a unit as the model writes it (``kPa``, ``kg*m/s``), or None."""
    if not text:
        return None
    from bondc.parse import parse_set_value
    from bondc.units import resolve

    try:
        unit = parse_set_value(f"x=1 [{text}]").unit
    except BondcError:
        return None
    if unit is None:
        return None
    resolved, problems = resolve(unit)
    if resolved is None or problems:
        return None
    dims = tuple(int(d) for d in resolved.dims) if all(d.denominator == 1 for d in resolved.dims) else None
    if resolved.is_coherent:        # an SI unit already (N/m, W, kg*m/s): under its own name
        return Unit(text.replace(" ", ""), dims)
    return Unit(resolved.dimension_text(), dims, (text, float(resolved.factor)))


class ExportError(BondcError):
    """A model bondc cannot export as asked (E840-E859)."""

    stage = "export"


def export_error(code: str, message: str, span=NO_SPAN, hint: str | None = None) -> ExportError:
    return ExportError(Diagnostic("error", code, message, span or NO_SPAN, hint=hint))


def _span(graph, variable):
    from bondc.model import law_span

    if variable.startswith("output "):
        variable = variable.removeprefix("output ")
    return law_span(graph, variable) or NO_SPAN


def _emitters(ss, source_name):
    """The numpy emitter (its names and common subexpressions) and the export's C emitter."""
    from bondc.codegen.cprinter import NativePrinter
    from bondc.codegen.emit import _Emitter, _NativeEmitter, _plan
    from bondc.symbolic import External

    plan = _plan(ss)
    emitter = _Emitter(plan, source_name, None, None, standalone=False)
    emitter.share()
    external = [name for name, (_, expr) in (ss.inputs or {}).items() if isinstance(expr, External)]
    offset = len(plan.parameters)
    where = {name: offset + k for k, name in enumerate(external)}

    class ExportPrinter(NativePrinter):
        """The engine's C printer, with each external input read from the parameter vector."""

        def _print_External(self, expr):
            return f"p[{where[expr.name]}]"

    class ExportEmitter(_NativeEmitter):
        def printer(self, extra_frozen=()):
            return ExportPrinter(self.names)

    return plan, emitter, ExportEmitter(emitter), external


def _first_failure(plan, emitter, graph):
    """The law (its variable) whose expression C cannot print, and why: (variable, reason), or None."""
    from bondc.codegen.printer import UnsupportedExpression

    printer = emitter.printer()
    for statement in plan.statements:
        exprs = statement.exprs if statement.kind == "assign" else statement.data["residuals"]
        for expr in exprs:
            try:
                printer.doprint(expr)
            except UnsupportedExpression as error:
                return statement.defines[0].name, str(error)
    for name, expr in plan.outputs:
        try:
            printer.doprint(expr)
        except UnsupportedExpression as error:
            return f"output {name}", str(error)
    return None


def c_model(ss, experiment=None, *, source_name: str | None = None, header_name: str | None = None) -> CModel:
    """The model's C code and interface; raises :class:`ExportError` (E840) at the law C cannot
    print (a measured csv signal)."""
    from bondc.codegen.cprinter import LOOP_PRELUDE, PRELUDE, NativePrinter
    from bondc.codegen.printer import UnsupportedExpression

    graph = getattr(ss, "graph", None)
    model_name = c_identifier(getattr(graph, "name", None) or "model")
    graph_file = getattr(graph, "file", None)
    source_name = Path(source_name or graph_file or "<model>").name
    header_name = header_name or f"{model_name}.h"
    plan, emitter, native, external = _emitters(ss, source_name)
    pattern = sorted(plan.jacobian_entries, key=lambda key: (key[1], key[0]))
    try:
        functions = [
            native.c_function("bondc_rhs", plan.statements, plan.derivatives),
            native.c_function("bondc_jac", plan.jacobian_statements, [plan.jacobian_entries[key] for key in pattern]),
            native.c_function("bondc_switches", plan.statements, [s.g for s in plan.switches]),
            native.c_function("bondc_outputs", plan.statements, [expr for _, expr in plan.outputs]),
        ]
    except UnsupportedExpression as error:
        failure = _first_failure(plan, native, graph) or ("", str(error))
        raise export_error(codes.E840, f"the law of '{failure[0]}' has no C form: {failure[1]}",
                           _span(graph, failure[0]) if failure[0] else NO_SPAN,
                           hint="a measured csv signal is read by bondc's Python runtime; give it as an "
                                "external input (input u [..] external) the host supplies") from None
    when_parts = native.c_when_functions()
    when_native = bool(plan.events) and "return 1;" in when_parts[-1]
    # the initial state and the derived parameters, from p
    parameter_names = {symbol: f"p[{i}]" for i, (_, symbol, _) in enumerate(plan.parameters)}
    printer = NativePrinter(parameter_names)
    try:
        initial = [printer.doprint(state.initial) for state in plan.states]
        derived = [(name, printer.doprint(expr)) for name, expr in plan.derived]
    except UnsupportedExpression as error:
        raise export_error(codes.E840, f"an initial value or a derived parameter has no C form: {error}") from None
    position = {name: i for i, (name, _, _) in enumerate(plan.parameters)}
    x0_lines = ["void bondc_x0(const double *p, double *x)", "{", "    (void)p;"]
    x0_lines += [f"    x[{i}] = {text};" for i, text in enumerate(initial)]
    derive_lines = ["void bondc_derive_parameters(double *p)", "{", "    (void)p;"]
    derive_lines += [f"    p[{position[name]}] = {text};" for name, text in derived]

    # the interface
    values = {symbol: value for _, symbol, value in plan.parameters}
    derived_names = {name for name, _ in plan.derived}
    si_units = dict(getattr(graph, "si_units", {}) or {})

    def described(name, kind):
        item = (getattr(graph, kind, {}) or {}).get(name) if graph is not None else None
        return getattr(item, "description", None) or ""

    parameters = []
    for name, _, value in plan.parameters:
        declared = (getattr(graph, "parameters", {}) or {}).get(name) if graph is not None else None
        unit = si_unit(getattr(declared, "unit_text", None))
        parameters.append(Quantity(name, float(value), unit, described(name, "parameters"), name in derived_names))
    states = []
    graph_states = {s.qualified: s for s in getattr(graph, "states", ())} if graph is not None else {}
    for state in plan.states:
        text = state.unit_text or si_units.get(state.name)
        try:
            start = float(state.initial.xreplace(values))
        except (TypeError, ValueError):
            start = 0.0
        description = state.description or getattr(graph_states.get(state.name), "description", None) or ""
        states.append(Quantity(state.name, start, si_unit(text), description))
    inputs = []
    for name in external:
        _, expr = ss.inputs[name]
        try:
            default = float(as_sympy(expr.default).xreplace(values))
        except (TypeError, ValueError):
            default = 0.0
        declared = (getattr(graph, "inputs", {}) or {}).get(name) if graph is not None else None
        inputs.append(Quantity(name, default, si_unit(getattr(declared, "unit_text", None)),
                               described(name, "inputs")))
    outputs = []
    for name, _ in plan.outputs:
        declared = (getattr(graph, "outputs", {}) or {}).get(name) if graph is not None else None
        outputs.append(Quantity(name, 0.0, si_unit(getattr(declared, "unit_text", None) or si_units.get(name)),
                                described(name, "outputs")))
    floors = [1 if s.kind == "floor" else 0 for s in plan.switches]
    located = [1 if (s.event or s.breaks) else 0 for s in plan.switches]
    labels = [emitter.label(s.label) for s in plan.switches]
    owners = [s.owner for s in plan.switches]
    whens = [(label, [index for index, _ in actions]) for label, _, actions in plan.events]
    settings = {}
    if experiment is not None:
        for key in ("t_end", "rtol", "atol", "max_step"):
            value = getattr(experiment, key, None)
            if value is not None:
                settings[key] = float(value)
    model = CModel(model_name, source_name, "", "", header_name, parameters, states, inputs, outputs,
                   pattern, labels, floors, located, owners, whens=whens, when_native=when_native,
                   experiment=settings, plan=plan, vertices=[float(s.vertex) for s in plan.switches])
    model.header = _header(model)
    tables = _tables(model)
    prelude = PRELUDE + (LOOP_PRELUDE if plan.blocks else "")
    parts = [f"/* {model_name}: the C code of the model {model_name} ({source_name}), generated by bondc "
             f"{__version__}.\n   The interface is documented in {header_name}. */",
             f'#include "{header_name}"\n' + prelude.rstrip("\n"), tables]
    parts += functions + when_parts + ["\n".join(x0_lines + ["}"]), "\n".join(derive_lines + ["}"])]
    model.c_text = "\n\n".join(part.rstrip("\n") for part in parts) + "\n"
    return model


def _array(kind, name, items, size=None):
    size = size if size is not None else len(items)
    body = ", ".join(items) if items else "0"
    return f"const {kind} {name}[{max(size, 1)}] = {{{body}}};"


def _quantities(name, quantities):
    rows = []
    for q in quantities:
        unit = q.unit.si if q.unit is not None else ""
        rows.append(f"    {{{c_string(q.name)}, {c_string(unit)}, {c_string(q.description)}, {c_double(float(q.value))}}},")
    if not rows:
        rows = ['    {"", "", "", 0.0},']
    return "\n".join([f"const bondc_quantity {name}[{max(len(quantities), 1)}] = {{"] + rows + ["};"])


def _tables(model: CModel) -> str:
    starts, targets = [0], []
    for _, indices in model.whens:
        targets += indices
        starts.append(len(targets))
    experiment = model.experiment
    lines = [
        _quantities("bondc_parameters", model.parameters),
        _array("int", "bondc_parameter_derived", [str(int(q.derived)) for q in model.parameters]),
        _quantities("bondc_states", model.states),
        _quantities("bondc_inputs", model.inputs),
        _quantities("bondc_outputs_info", model.outputs),
        _array("int", "bondc_jacobian_rows", [str(i) for i, _ in model.jacobian]),
        _array("int", "bondc_jacobian_cols", [str(j) for _, j in model.jacobian]),
        _array("char *const", "bondc_switch_labels", [c_string(text) for text in model.switch_labels]),
        _array("int", "bondc_switch_floor", [str(v) for v in model.floors]),
        _array("int", "bondc_switch_located", [str(v) for v in model.located]),
        _array("double", "bondc_switch_vertices", [repr(float(v)) for v in model.vertices]),
        _array("char *const", "bondc_when_labels", [c_string(label) for label, _ in model.whens]),
        _array("int", "bondc_when_target_start", [str(v) for v in starts]),
        _array("int", "bondc_when_targets", [str(v) for v in targets]),
        "const double bondc_experiment[4] = {" + ", ".join(
            c_double(float(experiment.get(key, default))) for key, default in
            (("t_end", 1.0), ("rtol", 1e-6), ("atol", 1e-8), ("max_step", 0.0))) + "};",
    ]
    return "\n".join(lines)


def _header(model: CModel) -> str:
    guard = "BONDC_MODEL_" + model.name.upper() + "_H"
    n_targets = sum(len(indices) for _, indices in model.whens)

    def listing(title, quantities):
        rows = [f"     {k:3d}  {q.name}" + (f" [{q.unit.si}]" if q.unit else "")
                for k, q in enumerate(quantities)]
        return [f"   {title}:"] + (rows or ["     (none)"])

    doc = [f"/* {model.name}: the C interface of the bond-graph model {model.name} ({model.source_file}),",
           f"   generated by bondc {__version__} (bondc compile --target c).",
           "",
           "   Every function of the model evaluates at time t, state x, parameter vector p and modes m:",
           "     void f(double t, const double *x, const double *p, const double *m, double *out);",
           "   x   BONDC_N_STATES values, SI (bondc_states);",
           "   p   BONDC_N_P values: the BONDC_N_PARAMETERS parameters (bondc_parameters, SI; call",
           "       bondc_derive_parameters(p) after changing one, to recompute those computed from others),",
           "       then the current values of the BONDC_N_INPUTS external inputs (bondc_inputs, SI);",
           "   m   BONDC_N_SWITCHES modes, one per switching function g_k: m_k = sign(g_k) (floor(g_k) where",
           "       bondc_switch_floor[k]), found at a start or an event by iterating m = sign(g(t, x, p, m))",
           "       until it repeats, and held between events (the laws are smooth while m is held).",
           "   bondc_rhs            dx/dt (BONDC_N_STATES values)",
           "   bondc_jac            d(dx/dt)/dx: its BONDC_N_JACOBIAN structural non-zeros, entry k at row",
           "                        bondc_jacobian_rows[k], column bondc_jacobian_cols[k] (column by column)",
           "   bondc_switches       the switching functions g (BONDC_N_SWITCHES values): the event indicators;",
           "                        a switch with bondc_switch_located[k] = 0 never changes mode",
           "   bondc_outputs        the outputs (BONDC_N_OUTPUTS values, SI; bondc_outputs_info)",
           "   bondc_when_conditions, bondc_when_actions: the when clauses (BONDC_N_WHENS): each one's",
           "                        condition (held where not 0), and the new values of every clause's",
           "                        target states, clause after clause (bondc_when_target_start/targets)",
           "   bondc_x0(p, x)       the initial state",
           "   Kinks (laws continuous across a switch: abs, min, max, an orifice's sign(e)*sqrt(abs(e)))",
           "   have no mode: they are evaluated as written.",
           "",
           ]
    doc += listing("parameters (p[k])", model.parameters)
    doc += listing(f"external inputs (p[{len(model.parameters)} + k])", model.inputs)
    doc += listing("states (x[k])", model.states)
    doc += listing("outputs (out[k] of bondc_outputs)", model.outputs)
    doc += [f"   switching functions: {len(model.switch_labels)}", "*/"]
    lines = doc + [
        f"#ifndef {guard}", f"#define {guard}", "",
        f"#define BONDC_N_STATES {len(model.states)}",
        f"#define BONDC_N_PARAMETERS {len(model.parameters)}",
        f"#define BONDC_N_INPUTS {len(model.inputs)}",
        "#define BONDC_N_P (BONDC_N_PARAMETERS + BONDC_N_INPUTS)",
        f"#define BONDC_N_OUTPUTS {len(model.outputs)}",
        f"#define BONDC_N_SWITCHES {len(model.switch_labels)}",
        f"#define BONDC_N_JACOBIAN {len(model.jacobian)}",
        f"#define BONDC_N_WHENS {len(model.whens)}",
        f"#define BONDC_N_WHEN_TARGETS {n_targets}",
        f"#define BONDC_MODEL_NAME {c_string(model.name)}",
        "",
        "/* a named quantity: its name (bondc's), SI unit, description and value (a parameter's and an",
        "   input's default, a state's initial value at the default parameters) */",
        "typedef struct { const char *name, *unit, *description; double value; } bondc_quantity;",
        "",
        "extern const bondc_quantity bondc_parameters[], bondc_states[], bondc_inputs[], bondc_outputs_info[];",
        "extern const int bondc_parameter_derived[];    /* 1: computed from others by bondc_derive_parameters */",
        "extern const int bondc_jacobian_rows[], bondc_jacobian_cols[];",
        "extern const char *const bondc_switch_labels[];",
        "extern const int bondc_switch_floor[], bondc_switch_located[];",
        "/* each switch's mode on its plus side where a sliding mode holds it: 1 (sign, if), 2 (coulomb) */",
        "extern const double bondc_switch_vertices[];",
        "extern const char *const bondc_when_labels[];",
        "extern const int bondc_when_target_start[], bondc_when_targets[];",
        "/* the experiment's t_end [s], rtol, atol and max_step [s] (0: none) */",
        "extern const double bondc_experiment[4];",
        "",
    ]
    lines += [f"void {name}(double t, const double *x, const double *p, const double *m, double *out);"
              for name in FUNCTIONS]
    lines += ["/* 1 where the when clauses have C code (0: none, or a statement C cannot print) */",
              "int bondc_when_native(void);",
              "void bondc_x0(const double *p, double *x);",
              "void bondc_derive_parameters(double *p);", "", f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def write_c(model: CModel, directory) -> list[Path]:
    """Write ``<Model>.c`` and ``<Model>.h`` into ``directory`` (made if missing), atomically."""
    from bondc.io import atomic_write_text

    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in ((f"{model.name}.c", model.c_text), (model.header_name, model.header)):
        atomic_write_text(folder / name, text)
        written.append(folder / name)
    return written
