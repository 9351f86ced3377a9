"""Functional Mock-up Units: ``bondc fmu FILE [--fmi 2|3] [--kind cs|me] [-o OUT.fmu]``.

An FMU is a zip of ``modelDescription.xml`` (the variables, their units, the default experiment)
and a shared library per platform. bondc's holds, in ``binaries/linux64/<Model>.so``, the model's
C code (:mod:`bondc.export.ccode`), bondc's CVODE driver (``bondc/native/driver.c``), the engine of
an FMU instance (``bondc/native/fmi/engine.c``: its state, its steps and events, on the driver's
functions) and the FMI wrapper (``bondc/native/fmi/fmi2.c`` or ``fmi3.c``), linked with
scikit-sundae's SUNDIALS libraries, which the FMU carries beside it (found through the rpath
``$ORIGIN``): it runs where neither bondc, Python nor a C compiler is installed.

Co-Simulation (the default): ``doStep`` integrates with CVODE, locates every crossing of a
switching function and selects the modes after it; where switches sit on their surfaces (a
friction that sticks, a relay that chatters) it holds them in a Filippov sliding mode with the
engine's own sliding set (``bondc/native/filippov.c``, as ``bondc simulate``). Model Exchange: the
importer integrates the derivatives; the event indicators are the located switches' switching
functions, the modes are selected again at each event; it cannot hold a state on a surface, so a
model whose switch may slide is refused before building (E841), at that switch's law.

Everything written is deterministic: the GUID is a hash of the content, the zip's entries have
fixed dates and permissions, so the same model gives the same FMU (with the same compiler).
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import shutil
import subprocess
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from bondc.version import __version__
from bondc.errors import Diagnostic, Related
from bondc.export.ccode import CModel, ExportError, _span, c_model, export_error
from bondc import codes

NATIVE = Path(__file__).resolve().parent.parent / "native"
FMI_SOURCES = NATIVE / "fmi"
PLATFORM = "linux64"
#: The driver's own sources the FMU's library is compiled from (bondc/native)
DRIVER_FILES = ("driver.c", "driver.h", "model.h", "sundials.h", "erk_api.h", "filippov.c", "filippov.h", "events.c",
                "events.h", "locate.c", "locate.h")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


@dataclass
class BuiltFmu:
    path: Path
    model: CModel
    guid: str
    fmi: int
    kind: str
    size: int


# ------------------------------------------------------------------ checks before any build


def _modes_and_states(plan):
    """For every symbol the laws assign: (the modes it reads, the states it reads)."""
    mode_index = {s.mode: s.index for s in plan.switches}
    state_index = {s.symbol: i for i, s in enumerate(plan.states)}
    closure: dict = {}

    def reads(exprs):
        modes, states = set(), set()
        for expr in exprs:
            for symbol in expr.free_symbols:
                if symbol in mode_index:
                    modes.add(mode_index[symbol])
                elif symbol in state_index:
                    states.add(state_index[symbol])
                elif symbol in closure:
                    modes |= closure[symbol][0]
                    states |= closure[symbol][1]
        return modes, states

    for statement in plan.statements:
        exprs = statement.exprs if statement.kind == "assign" else statement.data["residuals"]
        found = reads(exprs)
        for symbol in statement.defines:
            closure[symbol] = found
    return reads


def sliding_switches(plan) -> list:
    """The located switches whose state may slide on their surface (Filippov): the switching
    function reads a state whose rate reads that switch's own mode, so the two sides' rates of g
    can point at each other (a friction's velocity, a relay's output). A switch of time only, or
    one whose states' rates do not read its mode, crosses transversally and needs no sliding."""
    reads = _modes_and_states(plan)
    rates = [reads([expr]) for expr in plan.derivatives]
    found = []
    for switch in plan.switches:
        if not switch.event or switch.time_only:
            continue
        _, states = reads([switch.g])
        modes = set()
        for i in states:
            modes |= rates[i][0]
        if switch.index in modes:
            found.append(switch)
    return found


def check_exportable(model: CModel, graph, kind: str) -> None:
    """The errors that stop an FMU before any build: a switch that may slide in a Model Exchange
    FMU (E841; Co-Simulation integrates sliding modes with bondc's engine), when clauses without
    C code (E840)."""
    plan = model.plan
    sliding = sliding_switches(plan) if kind == "me" else []
    if sliding:
        first, rest = sliding[0], sliding[1:]
        label = model.switch_labels[first.index]
        related = tuple(Related(_span(graph, s.owner), f"may slide too: {model.switch_labels[s.index]}")
                        for s in rest if _span(graph, s.owner).line)
        raise ExportError(Diagnostic(
            "error", codes.E841,
            f"cannot export as a Model Exchange FMU: the switch {label} may hold the state on its surface (a "
            "Filippov sliding mode: a friction that sticks, a relay that chatters), which the importer's "
            "integrator cannot do"
            + (f" ({len(rest)} more switch{'es' if len(rest) > 1 else ''} like it)" if rest else ""),
            _span(graph, first.owner),
            hint="export it as Co-Simulation (the default, --kind cs: bondc's engine inside holds sliding "
                 "modes), or make the law continuous across its switch (a kink, e.g. a small linear band "
                 "around zero velocity), which needs no mode",
            related=related))
    if model.whens and not model.when_native:
        span = None
        for when in getattr(graph, "whens", ()):
            span = when.span
            break
        raise export_error(codes.E840, "cannot export as an FMU: a when clause of the model has no C form",
                           span, hint="write the when clause's condition and statements with arithmetic and "
                                      "the built-in functions")


# ------------------------------------------------------------------ modelDescription.xml


def _attr(value) -> str:
    return quoteattr(_clean(str(value)))


def _clean(text: str) -> str:
    """Text for XML: no control characters but tab and newline."""
    return "".join(ch for ch in text if ch in "\t\n" or ord(ch) >= 32)


def _number(value: float) -> str:
    return repr(float(value))


_BASE = ("m", "kg", "s", "A", "K", "mol", "cd", "rad")


def _units(model: CModel) -> list:
    """The distinct units of the variables, sorted by name: [(name, dims, [(display, factor)])]."""
    units: dict = {}
    for quantity in (*model.parameters, *model.inputs, *model.states, *model.outputs):
        unit = quantity.unit
        if unit is None:
            continue
        entry = units.setdefault(unit.si, (unit.dims, {}))
        if unit.display is not None:
            entry[1][unit.display[0]] = unit.display[1]
    return [(name, dims, sorted(displays.items())) for name, (dims, displays) in sorted(units.items())]


def _unit_definitions(model: CModel) -> list:
    lines = ["  <UnitDefinitions>"]
    for name, dims, displays in _units(model):
        lines.append(f"    <Unit name={_attr(name)}>")
        if dims is not None:
            base = " ".join(f'{key}="{value}"' for key, value in zip(_BASE, dims) if value)
            lines.append(f"      <BaseUnit {base}/>" if base else "      <BaseUnit/>")
        for display, factor in displays:
            lines.append(f"      <DisplayUnit name={_attr(display)} factor={_attr(_number(1.0 / factor))}/>")
        lines.append("    </Unit>")
    lines.append("  </UnitDefinitions>")
    return lines if len(lines) > 2 else []


def _default_experiment(model: CModel) -> str:
    """The experiment's t_end and rtol as the FMU's default experiment."""
    default = ['startTime="0.0"', f'stopTime="{_number(model.experiment.get("t_end", 1.0))}"']
    if "rtol" in model.experiment:
        default.append(f'tolerance="{_number(model.experiment["rtol"])}"')
    return f"  <DefaultExperiment {' '.join(default)}/>"


def _variables(model: CModel):
    """[(value reference, kind, quantity, index)] in value-reference order (fmi2.c's layout)."""
    rows = []
    for i, q in enumerate(model.parameters):
        rows.append(("parameter", q, i))
    for i, q in enumerate(model.inputs):
        rows.append(("input", q, i))
    for i, q in enumerate(model.states):
        rows.append(("state", q, i))
    for i, q in enumerate(model.states):
        rows.append(("derivative", q, i))
    for i, q in enumerate(model.outputs):
        rows.append(("output", q, i))
    return [(vr, kind, q, i) for vr, (kind, q, i) in enumerate(rows)]


def _unit_attributes(q, derivative=False) -> str:
    if q.unit is None:
        return ""
    if derivative:
        return ""
    text = f" unit={_attr(q.unit.si)}"
    if q.unit.display is not None:
        text += f" displayUnit={_attr(q.unit.display[0])}"
    return text


def model_description(model: CModel, guid: str, fmi: int, kind: str) -> str:
    """The modelDescription.xml text (FMI 2.0 or 3.0) of ``model``."""
    if fmi == 3:
        return _model_description3(model, guid, kind)
    rows = _variables(model)
    description = f"{model.name}, exported by bondc {__version__} from {model.source_file}"
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f'<fmiModelDescription fmiVersion="2.0" modelName={_attr(model.name)} guid={_attr(guid)}',
             f"  description={_attr(description)} generationTool={_attr('bondc ' + __version__)}",
             f'  variableNamingConvention="flat" numberOfEventIndicators="{sum(model.located)}">']
    if kind == "me":
        lines.append(f"  <ModelExchange modelIdentifier={_attr(model.name)} canNotUseMemoryManagementFunctions=\"true\"/>")
    else:
        lines.append(f"  <CoSimulation modelIdentifier={_attr(model.name)} "
                     'canHandleVariableCommunicationStepSize="true" canNotUseMemoryManagementFunctions="true"/>')
    lines += _unit_definitions(model)
    lines.append(_default_experiment(model))
    lines.append("  <ModelVariables>")
    index = {}
    for vr, kind_, q, i in rows:
        index[(kind_, i)] = vr + 1
        name = f"der({q.name})" if kind_ == "derivative" else q.name
        if kind_ == "parameter":
            desc = q.description
            if q.derived:
                attributes = 'causality="calculatedParameter" variability="tunable" initial="calculated"'
                real = f"<Real{_unit_attributes(q)}/>"
            else:
                attributes = 'causality="parameter" variability="tunable"'
                real = f'<Real start="{_number(q.value)}"{_unit_attributes(q)}/>'
        elif kind_ == "input":
            desc = q.description or f"external input {q.name}"
            attributes = 'causality="input" variability="continuous"'
            real = f'<Real start="{_number(q.value)}"{_unit_attributes(q)}/>'
        elif kind_ == "state":
            desc = q.description or f"state {q.name}"
            attributes = 'causality="local" variability="continuous" initial="calculated"'
            real = f"<Real{_unit_attributes(q)}/>"
        elif kind_ == "derivative":
            desc = f"time derivative of {q.name}"
            attributes = 'causality="local" variability="continuous" initial="calculated"'
            real = f'<Real derivative="{index[("state", i)]}"/>'
        else:
            desc = q.description or f"output {q.name}"
            attributes = 'causality="output" variability="continuous" initial="calculated"'
            real = f"<Real{_unit_attributes(q)}/>"
        lines.append(f'    <ScalarVariable name={_attr(name)} valueReference="{vr}" description={_attr(desc)} '
                     f"{attributes}>")
        lines.append(f"      {real}")
        lines.append("    </ScalarVariable>")
    lines.append("  </ModelVariables>")
    lines.append("  <ModelStructure>")
    outputs = [index[("output", i)] for i in range(len(model.outputs))]
    derivatives = [index[("derivative", i)] for i in range(len(model.states))]
    if outputs:
        lines += ["    <Outputs>"] + [f'      <Unknown index="{k}"/>' for k in outputs] + ["    </Outputs>"]
    if derivatives:
        lines += ["    <Derivatives>"] + [f'      <Unknown index="{k}"/>' for k in derivatives] + ["    </Derivatives>"]
    initial = sorted(outputs + derivatives + [index[("state", i)] for i in range(len(model.states))]
                     + [index[("parameter", i)] for i, q in enumerate(model.parameters) if q.derived])
    if initial:
        lines += (["    <InitialUnknowns>"] + [f'      <Unknown index="{k}"/>' for k in initial]
                  + ["    </InitialUnknowns>"])
    lines += ["  </ModelStructure>", "</fmiModelDescription>", ""]
    return "\n".join(lines)


def _model_description3(model: CModel, guid: str, kind: str) -> str:
    rows = _variables(model)
    description = f"{model.name}, exported by bondc {__version__} from {model.source_file}"
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f'<fmiModelDescription fmiVersion="3.0" modelName={_attr(model.name)} instantiationToken={_attr(guid)}',
             f"  description={_attr(description)} generationTool={_attr('bondc ' + __version__)}",
             '  variableNamingConvention="flat">']
    if kind == "me":
        lines.append(f"  <ModelExchange modelIdentifier={_attr(model.name)}/>")
    else:
        lines.append(f"  <CoSimulation modelIdentifier={_attr(model.name)} "
                     'canHandleVariableCommunicationStepSize="true" hasEventMode="false"/>')
    lines += _unit_definitions(model)
    lines.append(_default_experiment(model))
    lines.append("  <ModelVariables>")
    lines.append('    <Float64 name="time" valueReference="0" causality="independent" variability="continuous" '
                 'description="the time"/>')
    vrs = {}
    for vr, kind_, q, i in rows:
        vr += 1         # 0 is the time
        vrs[(kind_, i)] = vr
        name = f"der({q.name})" if kind_ == "derivative" else q.name
        unit = _unit_attributes(q, kind_ == "derivative")
        if kind_ == "parameter":
            desc = q.description
            if q.derived:
                attributes = 'causality="calculatedParameter" variability="tunable" initial="calculated"'
            else:
                attributes = f'causality="parameter" variability="tunable" start="{_number(q.value)}"'
        elif kind_ == "input":
            desc = q.description or f"external input {q.name}"
            attributes = f'causality="input" variability="continuous" start="{_number(q.value)}"'
        elif kind_ == "state":
            desc = q.description or f"state {q.name}"
            attributes = 'causality="local" variability="continuous" initial="calculated"'
        elif kind_ == "derivative":
            desc = f"time derivative of {q.name}"
            attributes = f'causality="local" variability="continuous" initial="calculated" ' \
                         f'derivative="{vrs[("state", i)]}"'
        else:
            desc = q.description or f"output {q.name}"
            attributes = 'causality="output" variability="continuous" initial="calculated"'
        lines.append(f'    <Float64 name={_attr(name)} valueReference="{vr}" description={_attr(desc)} '
                     f"{attributes}{unit}/>")
    if kind == "me":        # the event indicators: the located switches' switching functions
        for j, k in enumerate(k for k, located in enumerate(model.located) if located):
            lines.append(f'    <Float64 name="switch[{j + 1}]" valueReference="{len(rows) + 1 + j}" '
                         f"description={_attr('switching function of ' + model.switch_labels[k])} "
                         'causality="local" variability="continuous" initial="calculated"/>')
    lines.append("  </ModelVariables>")
    lines.append("  <ModelStructure>")
    for i in range(len(model.outputs)):
        lines.append(f'    <Output valueReference="{vrs[("output", i)]}"/>')
    indicators = [k for k, located in enumerate(model.located) if located] if kind == "me" else []
    first_indicator = len(rows) + 1
    for i in range(len(model.states)):
        lines.append(f'    <ContinuousStateDerivative valueReference="{vrs[("derivative", i)]}"/>')
    initial = sorted([vrs[("output", i)] for i in range(len(model.outputs))]
                     + [vrs[("derivative", i)] for i in range(len(model.states))]
                     + [vrs[("state", i)] for i in range(len(model.states))]
                     + [vrs[("parameter", i)] for i, q in enumerate(model.parameters) if q.derived])
    for vr in initial:
        lines.append(f'    <InitialUnknown valueReference="{vr}"/>')
    for j in range(len(indicators)):
        lines.append(f'    <EventIndicator valueReference="{first_indicator + j}"/>')
    lines += ["  </ModelStructure>", "</fmiModelDescription>", ""]
    return "\n".join(lines)


# ------------------------------------------------------------------ build


def guid_of(*texts: str) -> str:
    """A GUID made from a hash of the texts (the same content, the same GUID)."""
    digest = hashlib.sha256("\0".join(texts).encode("utf-8")).hexdigest()
    return "{" + f"{digest[:8]}-{digest[8:12]}-{digest[12:16]}-{digest[16:20]}-{digest[20:32]}" + "}"


def _sundials():
    from bondc.runtime import _sundials_link

    link = _sundials_link()
    if link is None:
        raise export_error(codes.E843, "cannot build an FMU: scikit-sundae's SUNDIALS libraries (Linux wheels) were "
                                   "not found", hint="pip install scikit-sundae (a Linux x86-64 wheel)")
    return link


def _licence_texts() -> list:
    """(name in the FMU, text) of the licences of what the FMU carries."""
    texts = [("documentation/licenses/FMI-headers.txt", (FMI_SOURCES / "LICENSE.txt").read_text(encoding="utf-8"))]
    try:
        from importlib import metadata

        distribution = metadata.distribution("scikit-sundae")
        for file in distribution.files or ():
            if file.name in ("LICENSES_bundled",):
                texts.append(("documentation/licenses/SUNDIALS.txt", file.read_text(encoding="utf-8")))
    except Exception:       # noqa: BLE001  (a licence text that cannot be read is not shipped)
        pass
    return texts


def _compile(model: CModel, guid: str, fmi: int, kind: str, link, work: Path) -> Path:
    from bondc.runtime import find_compiler, native_file

    compiler, why = find_compiler("c")
    if compiler is None:
        raise export_error(codes.E843, f"cannot build an FMU: {why}", hint="install a C compiler (gcc, clang) or "
                                                                         "the ziglang package")
    (work / f"{model.name}_model.c").write_text(model.c_text, encoding="utf-8")
    (work / model.header_name).write_text(model.header, encoding="utf-8")
    for name in DRIVER_FILES:
        (work / name).write_text(native_file(name), encoding="utf-8")
    wrapper = "fmi3.c" if fmi == 3 else "fmi2.c"
    for path in sorted(FMI_SOURCES.iterdir()):
        if path.suffix in (".c", ".h"):
            shutil.copyfile(path, work / path.name)
    libraries = []
    binaries = work / "binaries"
    binaries.mkdir()
    for library in link[1]:
        shutil.copyfile(library, binaries / os.path.basename(library))
        libraries.append(os.path.join("binaries", os.path.basename(library)))
    output = os.path.join("binaries", f"{model.name}.so")
    command = [*compiler.command, "-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fvisibility=hidden",
               f"-DBONDC_INDEX_TYPE={link[0]}", f'-DBONDC_FMU_GUID="{guid}"', "-I.",
               *(["-DBONDC_FMU_ME"] if kind == "me" else []),
               "-o", output, f"{model.name}_model.c", "driver.c", "engine.c", wrapper, *libraries,
               "-Wl,-rpath,$ORIGIN", "-lm"]
    done = subprocess.run(command, cwd=work, capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines() or ["no message"]
        first = next((line for line in lines if "error" in line), lines[0])
        raise export_error(codes.E844, f"the C compiler failed to build the FMU: {first.strip()}",
                           hint="this is a bug of bondc's FMU export: please report it with the model")
    return binaries


def _zip(entries) -> bytes:
    """A zip of (name, bytes, executable) with fixed dates and permissions, in name order."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data, executable in sorted(entries, key=lambda entry: entry[0]):
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = ((0o755 if executable else 0o644) | 0o100000) << 16
            info.create_system = 3
            archive.writestr(info, data)
    return buffer.getvalue()


def build_fmu(derived, output, *, fmi: int = 2, kind: str = "cs") -> BuiltFmu:
    """Build the FMU of ``derived`` (a :class:`bondc.pipeline.Derived`) into ``output``; raises
    :class:`~bondc.export.ccode.ExportError` (E840-E859) before any build where the model cannot be
    exported so."""
    from bondc.io import atomic_write

    graph, ss, experiment = derived.graph, derived.state_space, derived.experiment
    model = c_model(ss, experiment, header_name="bondc_model.h")
    check_exportable(model, graph, kind)
    link = _sundials()
    wrapper = (FMI_SOURCES / ("fmi3.c" if fmi == 3 else "fmi2.c")).read_text(encoding="utf-8")
    engine = (FMI_SOURCES / "engine.c").read_text(encoding="utf-8")
    skeleton = model_description(model, "{}", fmi, kind)
    guid = guid_of(skeleton, model.c_text, model.header, wrapper, engine, str(fmi), kind)
    description = model_description(model, guid, fmi, kind)
    with tempfile.TemporaryDirectory(prefix="bondc-fmu-") as folder:
        work = Path(folder)
        binaries = _compile(model, guid, fmi, kind, link, work)
        platform = "x86_64-linux" if fmi == 3 else PLATFORM
        entries = [("modelDescription.xml", description.encode("utf-8"), False)]
        for path in sorted(binaries.iterdir()):
            entries.append((f"binaries/{platform}/{path.name}", path.read_bytes(), True))
        entries += [(name, text.encode("utf-8"), False) for name, text in _licence_texts()]
    data = _zip(entries)
    output = Path(output)
    def write(stream) -> None:
        stream.write(data)

    atomic_write(output, write)
    return BuiltFmu(output, model, guid, fmi, kind, len(data))


def default_output(path, model_name: str) -> Path:
    return Path(path).with_name(f"{re.sub(r'[^A-Za-z0-9_]', '_', model_name)}.fmu")


__all__ = ["build_fmu", "model_description", "sliding_switches", "check_exportable", "guid_of"]
