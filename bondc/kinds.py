"""Element and junction kinds as data: the one table every stage reads.

Takes nothing and returns nothing: it is the library of kinds. Checking
(:mod:`bondc.semantic`) reads a kind's ports and laws, causality
(:mod:`bondc.causality`) its role and causalities, dimension inference
(:mod:`bondc.dimensions`) its tier, state integral and port ratios, the energy
account its energy role, the report's highlighter, the editor grammar, the
language server and the language reference its name and description. A new
kind is one entry here (CONTRIBUTING.md, "Adding an element kind");
``tests/test_kinds.py`` fails when a kind is missing anywhere.

>>> KINDS["C"].role, KINDS["C"].state, KINDS["C"].integrates, KINDS["C"].stores
('storage', 'q', 'f', True)
>>> [c.name for c in KINDS["R"].causalities]
['resistance', 'conductance']
>>> KINDS["GY"].ratios
(('p1.e', 'p2.f'), ('p2.e', 'p1.f'))
>>> JUNCTIONS["0"].common, JUNCTIONS["0"].summed, JUNCTIONS["1"].common_word
('e', 'f', 'flow')
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

#: Causal roles: the order in which causality is assigned and what a kind's laws compute.
SOURCE, STORAGE, RESISTOR, TRANSFORMER, GYRATOR = "source", "storage", "resistor", "transformer", "gyrator"
#: Energy roles: how the energy account books a kind's power.
ENERGY_SOURCE, ENERGY_STORAGE, DISSIPATOR, CONVERTER = "source", "storage", "dissipator", "converter"


#: A bond variable's name in words.
WORDS: Mapping[str, str] = {"e": "effort", "f": "flow"}


@dataclass(frozen=True)
class Causality:
    """One causality a one-port may take: its name and whether the element sets its bond's effort."""

    name: str                       # "effort", "flow", "integral", "derivative", "resistance", "conductance"
    sets_effort: bool


@dataclass(frozen=True)
class Kind:
    """What an element kind is: ports, laws, causal and energy role, dimension rules, state."""

    name: str
    ports: int                      # 1 for one-ports, 2 for TF/GY
    laws: frozenset[str]            # law targets allowed: "e", "f", "r"
    required: tuple[frozenset[str], ...]  # each set: at least one of these laws must be given
    role: str                       # causal role: SOURCE, STORAGE, RESISTOR, TRANSFORMER, GYRATOR
    energy: str                     # energy role: ENERGY_SOURCE, ENERGY_STORAGE, DISSIPATOR, CONVERTER
    causalities: tuple[Causality, ...] = ()  # a one-port's causalities, preferred first
    state: str | None = None        # default energy state of a storage element: "q" or "p"
    integrates: str | None = None   # the bond variable the default state integrates: "f" (q) or "e" (p)
    storage: str | None = None      # "C" or "I" for storage elements
    source: str | None = None       # "effort" or "flow" for sources
    # a two-port's dimension rule: each (left, right) reads ``left = r * right``
    ratios: tuple[tuple[str, str], ...] = ()
    modulated: bool = False
    description: str = ""

    @property
    def stores(self) -> bool:
        """Whether the kind stores energy in states (C, I)."""
        return self.storage is not None

    @property
    def two_port(self) -> bool:
        return self.ports == 2

    @property
    def tier(self) -> int:
        """Dimension inference trusts laws in this order: sources and two-ports (0), storage (1),
        resistors (2), so a conflict is reported at the least trusted law."""
        return {SOURCE: 0, TRANSFORMER: 0, GYRATOR: 0, STORAGE: 1}.get(self.role, 2)

    @property
    def law_variable(self) -> str | None:
        """The port variable a storage element's law computes from its state: "e" (C) or "f" (I)."""
        if self.integrates is None:
            return None
        return "e" if self.integrates == "f" else "f"

    @property
    def stored_variable(self) -> str | None:
        """The port variable a storage element's state integrates, in words ("flow f" for C)."""
        if self.integrates is None:
            return None
        return f"{WORDS[self.integrates]} {self.integrates}"


@dataclass(frozen=True)
class JunctionKind:
    """A junction kind: which bond variable all its bonds share and which one sums to zero."""

    name: str                       # "0" or "1"
    common: str                     # "e" (0-junction) or "f" (1-junction)
    description: str = ""

    @property
    def summed(self) -> str:
        return "f" if self.common == "e" else "e"

    @property
    def common_word(self) -> str:
        return WORDS[self.common]

    @property
    def summed_word(self) -> str:
        return WORDS[self.summed]

    def strong(self, junction_sets_effort: bool) -> bool:
        """Whether a bond is the one that brings the common variable in: at a 0-junction the bond
        whose other end sets the effort, at a 1-junction the bond on which the junction sets it."""
        return junction_sets_effort != (self.common == "e")


def _one_port(name: str, laws: str, role: str, energy: str, causalities: tuple[tuple[str, bool], ...],
              **extra) -> Kind:
    return Kind(name, 1, frozenset(laws), (frozenset(laws),), role, energy,
                tuple(Causality(c, sets) for c, sets in causalities), **extra)


def _two_port(name: str, role: str, ratios: tuple[tuple[str, str], ...], **extra) -> Kind:
    return Kind(name, 2, frozenset("r"), (frozenset("r"),), role, CONVERTER, ratios=ratios, **extra)


_EFFORT_SOURCE = (("effort", True),)
_FLOW_SOURCE = (("flow", False),)
_TRANSFORMER = (("p1.e", "p2.e"), ("p2.f", "p1.f"))
_GYRATOR = (("p1.e", "p2.f"), ("p2.e", "p1.f"))

#: Every element kind, in the order the language reference lists them.
KINDS: Mapping[str, Kind] = {
    "Se": _one_port("Se", "e", SOURCE, ENERGY_SOURCE, _EFFORT_SOURCE, source="effort", description="effort source"),
    "MSe": _one_port("MSe", "e", SOURCE, ENERGY_SOURCE, _EFFORT_SOURCE, source="effort", modulated=True,
                     description="modulated effort source"),
    "Sf": _one_port("Sf", "f", SOURCE, ENERGY_SOURCE, _FLOW_SOURCE, source="flow", description="flow source"),
    "MSf": _one_port("MSf", "f", SOURCE, ENERGY_SOURCE, _FLOW_SOURCE, source="flow", modulated=True,
                     description="modulated flow source"),
    "R": _one_port("R", "ef", RESISTOR, DISSIPATOR, (("resistance", True), ("conductance", False)),
                   description="resistor"),
    "C": _one_port("C", "e", STORAGE, ENERGY_STORAGE, (("integral", True), ("derivative", False)),
                   state="q", integrates="f", storage="C", description="capacitor (effort store)"),
    "I": _one_port("I", "f", STORAGE, ENERGY_STORAGE, (("integral", False), ("derivative", True)),
                   state="p", integrates="e", storage="I", description="inertia (flow store)"),
    "TF": _two_port("TF", TRANSFORMER, _TRANSFORMER, description="transformer"),
    "MTF": _two_port("MTF", TRANSFORMER, _TRANSFORMER, modulated=True, description="modulated transformer"),
    "GY": _two_port("GY", GYRATOR, _GYRATOR, description="gyrator"),
    "MGY": _two_port("MGY", GYRATOR, _GYRATOR, modulated=True, description="modulated gyrator"),
}

#: The junction kinds.
JUNCTIONS: Mapping[str, JunctionKind] = {
    "0": JunctionKind("0", "e", "0-junction: common effort, flows sum to zero"),
    "1": JunctionKind("1", "f", "1-junction: common flow, efforts sum to zero"),
}
JUNCTION_KINDS = tuple(JUNCTIONS)

#: Kind names longest first, for a regular-expression alternation that must try ``MSe`` before ``Se``.
NAMES_LONGEST_FIRST = tuple(sorted(KINDS, key=len, reverse=True))


def kinds_with(role: str) -> tuple[str, ...]:
    """The kinds of one causal role, in table order.

    >>> kinds_with(STORAGE)
    ('C', 'I')
    """
    return tuple(name for name, kind in KINDS.items() if kind.role == role)
