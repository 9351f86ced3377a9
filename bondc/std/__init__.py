"""The component libraries shipped with bondc: ``import "std:NAME"`` (docs/language.md, section 11).

Each ``NAME.bg`` here is an ordinary ``.bg`` file of models with ports. The
file's leading comment states the conventions every component follows (what
the ports carry, which way power flows, where the laws come from); each model's
description states its law, and each parameter its meaning.
:func:`describe` renders them all as ``docs/components.md``::

    python -m bondc.std > docs/components.md
"""

from __future__ import annotations

from importlib import resources

LIBRARIES = ("mechanics", "rotational", "electrical", "hydraulics", "pneumatics", "transmissions")


def path_of(name: str):
    """The file of library ``name`` (one of :data:`LIBRARIES`), or None."""
    if name not in LIBRARIES:
        return None
    return resources.files(__name__).joinpath(f"{name}.bg")


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def describe() -> str:
    """Markdown listing every library component: ports, parameters, inputs, outputs."""
    from bondc import ast
    from bondc.flatten import ports_of
    from bondc.fmt import format_expr, unit_text
    from bondc.parse import parse_text

    lines = ["# Component library", "",
             "Generated from `bondc/std/*.bg` by `python -m bondc.std > docs/components.md`; a test keeps it "
             "up to date.", "",
             'A model imports a library with `import "std:NAME"` at file level and instantiates a component '
             "like an element: `Orifice valve : A = 2e-5 [m^2]` (see `docs/language.md`, section 11). "
             "Unbound parameters keep the defaults below; inputs without a default must be bound.", ""]
    for name in LIBRARIES:
        text = path_of(name).read_text(encoding="utf-8")
        header = []
        for line in text.splitlines():
            if not line.startswith("#"):
                break
            header.append(line.lstrip("#").strip())
        lines += [f"## std:{name}", "", " ".join(h for h in header[1:] if h) or header[0], ""]
        file = parse_text(text, f"std:{name}")
        for model in file.models:
            lines += [f"### {model.name}", "", model.description or "", "",
                      f"Ports: {', '.join(f'`{p}`' for p in ports_of(model))}", ""]
            params = [s for s in model.body if isinstance(s, ast.Param)]
            if params:
                lines += ["| parameter | default | unit | meaning |", "| --- | --- | --- | --- |"]
                lines += [f"| `{p.name}` | `{_cell(format_expr(p.value))}` | {unit_text(p.unit) if p.unit else ''} "
                          f"| {_cell(p.description or '')} |" for p in params]
                lines.append("")
            inputs = [s for s in model.body if isinstance(s, ast.Input)]
            for item in inputs:
                default = "must be bound" if item.value is None else f"default `{_cell(format_expr(item.value))}`"
                unit = f" {unit_text(item.unit)}" if item.unit else ""
                lines.append(f"- input `{item.name}`{unit}: {item.description or ''} ({default})")
            outputs = [s for s in model.body if isinstance(s, ast.Output)]
            for item in outputs:
                unit = f" {unit_text(item.unit)}" if item.unit else ""
                lines.append(f"- output `{item.name}`{unit}: {item.description or ''}")
            if inputs or outputs:
                lines.append("")
    return "\n".join(lines).rstrip() + "\n"
