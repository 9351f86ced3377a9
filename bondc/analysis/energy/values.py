"""The energy account's values: :class:`ElementEnergy` (one element over one window),
:class:`Balance` (a window's balance and residual), :class:`Window` and :class:`EnergyAccount`
(every window, its table, rows and JSON).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

from bondc.analysis.energy.quadrature import METHOD
from bondc.errors import AnalysisError, Diagnostic

@dataclass(frozen=True)
class ElementEnergy:
    """One element's energies over one window, in J (None where they do not apply).

    ``work_in`` is the integral of the power into the element (every kind);
    ``gross`` the integral of its absolute value. Storage elements with an
    energy function have ``stored_start``/``stored_end``/``stored_change``;
    those without have ``net_work_in`` (= ``work_in``). Two-ports have
    ``port_work`` (work in at p1, at p2) and ``work_in`` their sum.
    """

    element: str
    kind: str
    role: str                                   # source, dissipator, storage, converter
    work_in: float
    gross: float
    supplied: float | None = None
    returned: float | None = None
    dissipated: float | None = None
    stored_start: float | None = None
    stored_end: float | None = None
    stored_change: float | None = None
    net_work_in: float | None = None
    port_work: tuple[float, float] | None = None
    energy_function: str | None = None          # "analytic", "numeric" or None
    event_change: float | None = None           # stored energy changed by when clauses (reinit) in the window
    unit: str = "J"                             # a pseudo bond graph's own unit (e*f*s), e.g. K*J for heat

    @property
    def storage_defect(self) -> float | None:
        """``work_in - stored_change``: this storage element's share of the balance residual."""
        if self.stored_change is None:
            return None
        return self.work_in - self.stored_change


@dataclass(frozen=True)
class Balance:
    """sources' net energy = dissipated + stored_change + net_work_in (+ residual)."""

    supplied: float
    returned: float
    dissipated: float
    stored_change: float
    net_work_in: float
    converter_work: float                       # sum over two-ports of the work in at both ports (~0)
    throughput: float
    event_change: float = 0.0                   # stored energy changed at when clauses (an impact's loss < 0)

    @property
    def sources_net(self) -> float:
        return self.supplied - self.returned

    @property
    def residual(self) -> float:
        # what the ports delivered plus what the events changed is what is stored or dissipated
        return self.sources_net + self.event_change - (self.dissipated + self.stored_change + self.net_work_in)

    @property
    def relative_residual(self) -> float | None:
        return abs(self.residual) / self.throughput if self.throughput > 0 else None

    def to_json(self) -> dict:
        return {
            "supplied": self.supplied, "returned": self.returned, "sources_net": self.sources_net,
            "dissipated": self.dissipated, "stored_change": self.stored_change,
            "net_work_in": self.net_work_in, "converter_work": self.converter_work,
            "event_change": self.event_change, "residual": self.residual, "throughput": self.throughput,
            "relative_residual": self.relative_residual,
        }


@dataclass(frozen=True)
class Window:
    """One cycle (or the whole run): its span, every element's energies and the balance."""

    index: int
    t_start: float
    t_end: float
    partial: bool
    elements: tuple[ElementEnergy, ...]
    balance: Balance

    def element(self, name: str) -> ElementEnergy:
        for entry in self.elements:
            if entry.element == name:
                return entry
        raise KeyError(name)


ROW_KEYS = ("cycle", "t_start", "t_end", "element", "kind", "role", "supplied", "returned", "dissipated",
            "stored_change", "net_work_in", "work_in", "energy_function")
BALANCE_KEYS = ("cycle", "t_start", "t_end", "supplied", "returned", "sources_net", "dissipated",
                "stored_change", "net_work_in", "converter_work", "residual", "throughput", "relative_residual")


@dataclass(frozen=True)
class EnergyAccount:
    """Energies per element and cycle, and the energy balance of each cycle (see the module docstring)."""

    model: str
    experiment: str | None
    cycle: float | None
    windows: tuple[Window, ...]
    complete: bool                              # False: the run stopped early; the account covers what ran
    resimulated: bool                           # True: the run was repeated to get the solver's steps
    method: str = METHOD
    quadrature: Mapping[str, int] = field(default_factory=dict)   # steps: all, corrected, hermite, sliding
    diagnostics: tuple[Diagnostic, ...] = ()
    #: the stored-energy functions' recipes (for the compile cache's light entry); None if one has none
    energy_recipes: Mapping | None = field(default=None, repr=False, compare=False)

    @property
    def unit(self) -> str:
        """The unit of every energy: J, a pseudo bond graph's own (``kg*m^2*K/s^2`` for temperature and
        heat flow), or "mixed" when elements differ (then the balance adds unlike quantities)."""
        found = {e.unit for w in self.windows for e in w.elements}
        return found.pop() if len(found) == 1 else ("J" if not found else "mixed")

    @property
    def max_relative_residual(self) -> float:
        values = [w.balance.relative_residual for w in self.windows if w.balance.relative_residual is not None]
        return max(values) if values else 0.0

    def rows(self) -> list[dict]:
        """One dict per (cycle, element), keys :data:`ROW_KEYS`, energies in J."""
        rows = []
        for window in self.windows:
            for entry in window.elements:
                rows.append({
                    "cycle": window.index, "t_start": window.t_start, "t_end": window.t_end,
                    "element": entry.element, "kind": entry.kind, "role": entry.role,
                    "supplied": entry.supplied, "returned": entry.returned, "dissipated": entry.dissipated,
                    "stored_change": entry.stored_change, "net_work_in": entry.net_work_in,
                    "work_in": entry.work_in, "energy_function": entry.energy_function,
                })
        return rows

    def balance_rows(self) -> list[dict]:
        """One dict per cycle, keys :data:`BALANCE_KEYS`, energies in J."""
        rows = []
        for window in self.windows:
            row = {"cycle": window.index, "t_start": window.t_start, "t_end": window.t_end}
            row.update(window.balance.to_json())
            rows.append({key: row[key] for key in BALANCE_KEYS})
        return rows

    def to_json(self) -> dict:
        return {
            "model": self.model,
            "experiment": self.experiment,
            "cycle": self.cycle,
            "complete": self.complete,
            "resimulated": self.resimulated,
            "method": self.method,
            "quadrature": dict(self.quadrature),
            "max_relative_residual": self.max_relative_residual,
            "unit": self.unit,
            "cycles": [
                {
                    "index": window.index, "t_start": window.t_start, "t_end": window.t_end,
                    "partial": window.partial,
                    "balance": window.balance.to_json(),
                    "elements": [_element_json(entry) for entry in window.elements],
                }
                for window in self.windows
            ],
            "diagnostics": [d.to_json() for d in self.diagnostics],
        }

    def to_text(self) -> str:
        """Readable tables, one per cycle: element, kind, supplied, returned, dissipated, change of
        stored energy and net work in, in J; then the balance."""
        out = [f"Energy account of {self.model}" + (f" ({self.experiment})" if self.experiment else "")]
        unit = self.unit
        if unit != "J":
            pseudo = sorted({e.element for w in self.windows for e in w.elements if e.unit != "J"})
            out.append(f"(a pseudo bond graph: effort times flow is not a power for {', '.join(pseudo)}; "
                       + (f"its integrals are in {unit}, not joules)" if unit != "mixed" else
                          "each element's integrals are in its own unit, so the balance adds unlike quantities)"))
        J = "J" if unit == "J" else ("" if unit == "mixed" else unit)
        if not self.complete:
            out.append("(the run stopped early: the account covers what was simulated)")
        for window in self.windows:
            head = (f"cycle {window.index + 1}: t = {window.t_start:g} .. {window.t_end:g} s"
                    + (" (partial)" if window.partial else ""))
            out += ["", head]
            out += _table(window)
            b = window.balance
            relative = "-" if b.relative_residual is None else f"{b.relative_residual:.2e}"
            events = f" - changed at events {_j(b.event_change)} {J}" if b.event_change else ""
            out.append(f"balance: sources net {_j(b.sources_net)} {J} = dissipated {_j(b.dissipated)} {J}"
                       f" + stored {_j(b.stored_change)} {J} + net work in {_j(b.net_work_in)} {J}{events}"
                       f"; residual {b.residual:.3e} {J} ({relative} of throughput {_j(b.throughput)} {J})")
            if any(e.role == "converter" for e in window.elements):
                out.append(f"two-ports: work in at both ports {b.converter_work:.3e} {J} (ideally 0)")
        for diagnostic in self.diagnostics:
            out.append(f"{diagnostic.severity}[{diagnostic.code}]: {diagnostic.message}")
            if diagnostic.hint:
                out.append(f" = hint: {diagnostic.hint}")
        return "\n".join(out)


def _element_json(entry: ElementEnergy) -> dict:
    data = {
        "element": entry.element, "kind": entry.kind, "role": entry.role,
        "work_in": entry.work_in, "gross": entry.gross,
    }
    for key in ("supplied", "returned", "dissipated", "stored_start", "stored_end", "stored_change",
                "net_work_in", "energy_function"):
        value = getattr(entry, key)
        if value is not None:
            data[key] = value
    if entry.port_work is not None:
        data["port_work"] = {"p1": entry.port_work[0], "p2": entry.port_work[1]}
    if entry.unit != "J":
        data["unit"] = entry.unit
    if entry.storage_defect is not None:
        data["storage_defect"] = entry.storage_defect
    return data


def _j(value: float) -> str:
    return f"{value:.6g}"


def _table(window: Window) -> list[str]:
    columns = ("supplied", "returned", "dissipated", "stored_change", "net_work_in")
    titles = ("element", "kind", "supplied", "returned", "dissipated", "Δstored", "net work in")
    largest = max([abs(getattr(e, c)) for e in window.elements for c in columns
                   if getattr(e, c) is not None] + [0.0])
    # six significant digits for the largest entry of the table, at most nine decimals
    decimals = 3 if largest == 0 else min(max(5 - int(math.floor(math.log10(largest))), 0), 9)
    rows = []
    for entry in window.elements:
        cells = [entry.element, entry.kind]
        for column in columns:
            value = getattr(entry, column)
            cells.append("-" if value is None else f"{value:.{decimals}f}")
        rows.append(cells)
    widths = [max(len(titles[i]), *(len(r[i]) for r in rows)) if rows else len(titles[i])
              for i in range(len(titles))]
    line = lambda cells: "  ".join(c.ljust(w) if i < 2 else c.rjust(w)
                                   for i, (c, w) in enumerate(zip(cells, widths))).rstrip()
    return [line(titles), line(["-" * w for w in widths])] + [line(r) for r in rows]


def _error(code: str, message: str, hint: str | None = None) -> AnalysisError:
    return AnalysisError(Diagnostic("error", code, message, hint=hint))
