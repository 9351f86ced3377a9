"""Unit resolution: an ``ast.Unit`` as written to a scale factor and dimensions in SI.

``resolve`` takes an :class:`bondc.ast.Unit` (already flattened by the parser
into name^exponent factors) and returns ``(SIUnit | None, diagnostics)``: the
unit's factor to SI and its dimensions, or ``None`` with one ``E201``
diagnostic per unknown name (all of them, not just the first). Nothing here
raises; the calling stage decides whether to stop.

Dimensions are counted over the seven SI base dimensions plus an eighth,
angle, so that ``rad/s`` and ``1/s`` display differently while
:func:`compatible` still treats them as the same quantity.

>>> from fractions import Fraction
>>> from bondc.ast import Unit, UnitFactor
>>> rpm = Unit(factors=(UnitFactor("rpm", Fraction(1)),), text="rpm")
>>> si, diagnostics = resolve(rpm)
>>> round(si.to_si(1000), 6), si.dimension_text(), diagnostics
(104.719755, 'rad/s', [])
>>> bad = Unit(factors=(UnitFactor("kgg", Fraction(1)),), text="kgg")
>>> unit, diagnostics = resolve(bad)
>>> unit, diagnostics[0].code, diagnostics[0].hint
(None, 'E201', "did you mean 'kg'?")
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Union

from bondc import ast
from bondc.errors import Diagnostic
from bondc import codes

# Storage order of SIUnit.dims. "rad" is the angle pseudo-dimension.
BASE_DIMENSIONS = ("m", "kg", "s", "A", "K", "mol", "cd", "rad")
_ANGLE = BASE_DIMENSIONS.index("rad")
# Display order: the conventional kg*m^2/s^2 reading, angle last.
_DISPLAY_ORDER = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")

# A scale kept as a Fraction while it is exact, so that e.g. km^3 or mg come out
# as exact powers of ten instead of accumulating float rounding; angle units
# involve pi and are floats.
Scale = Union[Fraction, float]

Dims = tuple[Fraction, ...]


def _dims(m=0, kg=0, s=0, A=0, K=0, mol=0, cd=0, rad=0) -> Dims:
    return tuple(Fraction(x) for x in (m, kg, s, A, K, mol, cd, rad))


_NO_DIMS = _dims()


def _format_exponent(exponent: Fraction) -> str:
    if exponent == 1:
        return ""
    if exponent.denominator == 1:
        return f"^{exponent.numerator}"
    return f"^({exponent.numerator}/{exponent.denominator})"


@dataclass(frozen=True)
class SIUnit:
    """A resolved unit: ``value [unit]`` is ``value * factor`` in SI with dimensions ``dims``.

    ``dims`` holds exponents over :data:`BASE_DIMENSIONS` (m, kg, s, A, K, mol,
    cd, rad); ``text`` is the unit as written, for messages and reports.
    """

    factor: float
    dims: Dims
    text: str

    @property
    def is_coherent(self) -> bool:
        """True when the unit is plain SI (factor 1), e.g. ``m^2``, ``N*m/rad``; not ``ms``."""
        return abs(self.factor - 1.0) <= 1e-12

    @property
    def is_dimensionless(self) -> bool:
        """True for ``1``, ``rad``, ``deg``, ``m/m``: angle counts as dimensionless."""
        return all(d == 0 for i, d in enumerate(self.dims) if i != _ANGLE)

    def to_si(self, value: float) -> float:
        """``value`` in this unit, converted to SI."""
        divisor = self._integral_inverse()
        # Dividing by 1000 is correctly rounded; multiplying by the inexact float
        # 0.001 can be off by one ulp, so decimal sub-units divide.
        if divisor is not None:
            return value / divisor
        return value * self.factor

    def from_si(self, value: float) -> float:
        """An SI ``value`` expressed in this unit."""
        multiplier = self._integral_inverse()
        if multiplier is not None:
            return value * multiplier
        return value / self.factor

    def _integral_inverse(self) -> int | None:
        """``1/factor`` when it is a whole number (``mm`` -> 1000), else None."""
        if not 0.0 < self.factor < 1.0:
            return None
        inverse = 1.0 / self.factor
        nearest = round(inverse)
        if abs(inverse - nearest) <= 1e-12 * nearest:
            return nearest
        return None

    def dimension_text(self) -> str:
        """The SI dimensions as a unit expression: ``kg*m/s^2``, ``rad/s``, ``1``."""
        numerator: list[str] = []
        denominator: list[str] = []
        for name in _DISPLAY_ORDER:
            exponent = self.dims[BASE_DIMENSIONS.index(name)]
            if exponent > 0:
                numerator.append(name + _format_exponent(exponent))
            elif exponent < 0:
                denominator.append(name + _format_exponent(-exponent))
        top = "*".join(numerator) or "1"
        if not denominator:
            return top
        if len(denominator) == 1:
            return f"{top}/{denominator[0]}"
        return f"{top}/({'*'.join(denominator)})"

    # Arithmetic, so that later stages can derive the unit of an expression.

    def __mul__(self, other: "SIUnit") -> "SIUnit":
        return SIUnit(self.factor * other.factor,
                      tuple(a + b for a, b in zip(self.dims, other.dims)),
                      f"{self.text}*{other.text}")

    def __truediv__(self, other: "SIUnit") -> "SIUnit":
        right = other.text if _is_simple(other.text) else f"({other.text})"
        return SIUnit(self.factor / other.factor,
                      tuple(a - b for a, b in zip(self.dims, other.dims)),
                      f"{self.text}/{right}")

    def __pow__(self, exponent: Fraction | int) -> "SIUnit":
        exponent = Fraction(exponent)
        base = self.text if _is_simple(self.text) else f"({self.text})"
        return SIUnit(self.factor ** float(exponent),
                      tuple(d * exponent for d in self.dims),
                      base + (_format_exponent(exponent) if exponent != 1 else ""))

    def __str__(self) -> str:
        return self.text


def _is_simple(text: str) -> bool:
    return not any(op in text for op in "*/^")


def compatible(a: SIUnit, b: SIUnit) -> bool:
    """Whether two units measure the same quantity, ignoring angle (``rad/s`` ~ ``1/s``)."""
    return all(x == y for i, (x, y) in enumerate(zip(a.dims, b.dims)) if i != _ANGLE)


DIMENSIONLESS = SIUnit(1.0, _NO_DIMS, "1")


# ----------------------------------------------------------------- unit table

@dataclass(frozen=True)
class _Entry:
    scale: Scale
    dims: Dims


_NEWTON = _dims(kg=1, m=1, s=-2)
_PASCAL = _dims(kg=1, m=-1, s=-2)
_JOULE = _dims(kg=1, m=2, s=-2)

# Units that take the prefixes below. "g" rather than "kg" is the base so that
# kg, mg and ug all come from one entry, as in the SI brochure.
_PREFIXABLE: dict[str, tuple[Scale, Dims]] = {
    "m": (Fraction(1), _dims(m=1)),
    "g": (Fraction(1, 1000), _dims(kg=1)),
    "s": (Fraction(1), _dims(s=1)),
    "A": (Fraction(1), _dims(A=1)),
    "K": (Fraction(1), _dims(K=1)),
    "mol": (Fraction(1), _dims(mol=1)),
    "cd": (Fraction(1), _dims(cd=1)),
    "N": (Fraction(1), _NEWTON),
    "Pa": (Fraction(1), _PASCAL),
    "J": (Fraction(1), _JOULE),
    "W": (Fraction(1), _dims(kg=1, m=2, s=-3)),
    "V": (Fraction(1), _dims(kg=1, m=2, s=-3, A=-1)),
    "Ohm": (Fraction(1), _dims(kg=1, m=2, s=-3, A=-2)),
    "F": (Fraction(1), _dims(kg=-1, m=-2, s=4, A=2)),
    "H": (Fraction(1), _dims(kg=1, m=2, s=-2, A=-2)),
    "C": (Fraction(1), _dims(s=1, A=1)),
    "Hz": (Fraction(1), _dims(s=-1)),
    "T": (Fraction(1), _dims(kg=1, s=-2, A=-1)),
    "Wb": (Fraction(1), _dims(kg=1, m=2, s=-2, A=-1)),
    "S": (Fraction(1), _dims(kg=-1, m=-2, s=3, A=2)),
    "L": (Fraction(1, 1000), _dims(m=3)),
    "l": (Fraction(1, 1000), _dims(m=3)),
}

# Units that take no prefix: a "krpm" or "mrad" is rejected rather than guessed.
# mbar is listed whole because it is the one prefixed bar in common use.
_FIXED: dict[str, tuple[Scale, Dims]] = {
    "1": (Fraction(1), _NO_DIMS),
    "rad": (Fraction(1), _dims(rad=1)),
    "deg": (math.pi / 180, _dims(rad=1)),
    "rev": (2 * math.pi, _dims(rad=1)),
    "rpm": (2 * math.pi / 60, _dims(rad=1, s=-1)),
    "min": (Fraction(60), _dims(s=1)),
    "h": (Fraction(3600), _dims(s=1)),
    "bar": (Fraction(100000), _PASCAL),
    "mbar": (Fraction(100), _PASCAL),
    "Nm": (Fraction(1), _JOULE),
}

PREFIXES: dict[str, Fraction] = {
    "n": Fraction(1, 10**9),
    "u": Fraction(1, 10**6),
    "m": Fraction(1, 1000),
    "c": Fraction(1, 100),
    "k": Fraction(1000),
    "M": Fraction(10**6),
    "G": Fraction(10**9),
}


def _build_table() -> dict[str, _Entry]:
    table: dict[str, _Entry] = {}
    # Prefixed forms first, so that a whole name written in the table (min,
    # mol, cd, mbar, ...) overwrites any prefix reading of the same letters.
    for base, (scale, dims) in _PREFIXABLE.items():
        for prefix, prefix_scale in PREFIXES.items():
            table[prefix + base] = _Entry(prefix_scale * scale, dims)
    for base, (scale, dims) in _PREFIXABLE.items():
        table[base] = _Entry(scale, dims)
    for name, (scale, dims) in _FIXED.items():
        table[name] = _Entry(scale, dims)
    return table


# Every accepted name, prefixed forms included: "mm", "kg", "MPa", "min", ...
_TABLE = _build_table()
KNOWN_NAMES: tuple[str, ...] = tuple(name for name in _TABLE if name != "1")


def unit_names() -> list[str]:
    """Every unit name bondc knows, without prefixes (``m``, ``N``, ``bar``, ``rpm``, ...), sorted."""
    return sorted(_TABLE)


def lookup(name: str) -> SIUnit | None:
    """The SI meaning of one unit name (``"kPa"``, ``"rpm"``, ``"1"``), or None if unknown."""
    entry = _TABLE.get(name)
    if entry is None:
        return None
    return SIUnit(float(entry.scale), entry.dims, name)


# ----------------------------------------------------------------- suggestions

# Spelled-out and informal names engineers write; keys are lower case.
_ALIASES = {
    **dict.fromkeys(("sec", "secs", "second", "seconds"), "s"),
    **dict.fromkeys(("meter", "meters", "metre", "metres"), "m"),
    **dict.fromkeys(("kilogram", "kilograms", "kgs"), "kg"),
    **dict.fromkeys(("gram", "grams"), "g"),
    **dict.fromkeys(("hr", "hrs", "hour", "hours"), "h"),
    **dict.fromkeys(("mins", "minute", "minutes"), "min"),
    **dict.fromkeys(("radian", "radians"), "rad"),
    **dict.fromkeys(("degree", "degrees", "degs"), "deg"),
    **dict.fromkeys(("revs", "revolution", "revolutions"), "rev"),
    **dict.fromkeys(("liter", "liters", "litre", "litres"), "L"),
    **dict.fromkeys(("amp", "amps", "ampere", "amperes"), "A"),
    **dict.fromkeys(("ohms",), "Ohm"),
    **dict.fromkeys(("rps",), "rev/s"),
    **dict.fromkeys(("mps",), "m/s"),
    "newton": "N", "pascal": "Pa", "joule": "J", "watt": "W", "volt": "V",
    "kelvin": "K", "hertz": "Hz", "farad": "F", "henry": "H", "coulomb": "C",
}


def _case_score(name: str, candidate: str) -> int:
    return sum(a == b for a, b in zip(name, candidate))


#: Names longer than this get no suggestion: no unit is spelt with more letters (the longest,
#: "revolutions", has 11), and the search below is quadratic in the length (a unit name of
#: 300 kB took 19 s).
MAX_SUGGESTED = 32


def _suggestions(name: str) -> list[str]:
    """Known spellings close to ``name``, most likely first (at most three)."""
    if len(name) > MAX_SUGGESTED:
        return []
    # A wrong case is the commonest slip (Mpa, KG, hz). Ties (mpa: mPa or MPa)
    # keep the one agreeing in more letters first.
    folded = [known for known in KNOWN_NAMES if known.lower() == name.lower()]
    folded.sort(key=lambda known: -_case_score(name, known))
    alias = [_ALIASES[name.lower()]] if name.lower() in _ALIASES else []

    # A product written without '*' (Ns, kWh, Nmm). A doubled letter at the
    # split point (kgg -> kg*g) is more likely a typo than a product, so such
    # splits are offered only when nothing else is. A prefix on a unit that
    # takes none (mrad) is not read as a product with metres.
    prefixed_fixed = _prefixed_fixed(name)
    products, doubled = [], []
    for cut in range(1, len(name)):
        left, right = name[:cut], name[cut:]
        if left not in _TABLE or right not in _TABLE or "1" in (left, right):
            continue
        if prefixed_fixed and cut == 1:
            continue
        (doubled if left[-1] == right[0] else products).append(f"{left}*{right}")

    # Close spellings only when the case or a known alias has not explained it.
    close = [] if folded or alias else difflib.get_close_matches(name, KNOWN_NAMES, n=3, cutoff=0.6)
    ordered = folded + alias + products + close
    if not ordered:
        ordered = doubled
    return list(dict.fromkeys(ordered))[:3]


def _prefixed_fixed(name: str) -> tuple[str, str] | None:
    """``(prefix, unit)`` when ``name`` is a prefix on a unit that takes none: mrad, krpm."""
    if name[:1] in PREFIXES and name[1:] in _FIXED and name[1:] != "1":
        return name[:1], name[1:]
    return None


def suggest(name: str) -> str | None:
    """The most likely intended unit for an unknown ``name`` (``'kgg'`` -> ``'kg'``), or None."""
    found = _suggestions(name)
    return found[0] if found else None


#: Temperature scales with an offset: not units a factor converts (20 degC is 293.15 K, not 20 K).
_OFFSET_SCALES = {"degc": "°C", "°c": "°C", "celsius": "°C", "degf": "°F", "°f": "°F", "fahrenheit": "°F",
                  "c°": "°C", "f°": "°F"}


def _hint(name: str, found: list[str] | None = None) -> str:
    scale = _OFFSET_SCALES.get(name.lower())
    if scale is not None:
        example = "20 °C is 293.15 [K]" if scale == "°C" else "68 °F is 293.15 [K]"
        return (f"{scale} is a temperature scale with an offset, which no unit factor converts: give "
                f"temperatures in K ({example})")
    parts = []
    found = _suggestions(name) if found is None else found
    if found:
        quoted = [f"'{s}'" for s in found]
        choice = quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]
        parts.append(f"did you mean {choice}?")
    misuse = _prefixed_fixed(name)
    if misuse:
        prefix, unit = misuse
        parts.append(f"the prefix '{prefix}' cannot be used with '{unit}'; give the value in '{unit}'")
    elif _is_number(name):
        parts.append("the only number allowed in a unit is '1'; put scale factors in the value")
    if not parts:
        parts.append("units are SI names with the prefixes n u m c k M G "
                     "(m, g, s, N, Pa, J, W, V, Ohm, ...), or rad deg rev rpm min h bar L l Nm, or 1")
    # Later sentences start with a capital; the first stays lower case like
    # every other hint ("did you mean 'kg'?").
    return " ".join([parts[0]] + [part[0].upper() + part[1:] + "." for part in parts[1:]])


def _is_number(name: str) -> bool:
    return name.replace(".", "", 1).isdigit()


# --------------------------------------------------------------------- resolve

def resolve(unit: ast.Unit) -> tuple[SIUnit | None, list[Diagnostic]]:
    """The SI factor and dimensions of ``unit``, or None and an E201 per unknown name."""
    diagnostics: list[Diagnostic] = []
    scale: Scale = Fraction(1)
    dims = list(_NO_DIMS)
    for factor in unit.factors:
        entry = _TABLE.get(factor.name)
        if entry is None:
            found = _suggestions(factor.name)
            diagnostics.append(Diagnostic(
                "error", codes.E201, f"unknown unit '{factor.name}'", factor.span,
                hint=_hint(factor.name, found),
                suggestions=() if factor.name.lower() in _OFFSET_SCALES else tuple(found)))
            continue
        exponent = Fraction(factor.exponent)
        if exponent.denominator == 1:
            # Integer powers keep an exact scale exact (km^3 is exactly 1e9).
            scale *= entry.scale ** exponent.numerator
        else:
            scale *= float(entry.scale) ** float(exponent)
        for index, count in enumerate(entry.dims):
            dims[index] += count * exponent
    if diagnostics:
        return None, diagnostics
    text = unit.text or _factors_text(unit.factors)
    return SIUnit(float(scale), tuple(dims), text), []


def _factors_text(factors: tuple[ast.UnitFactor, ...]) -> str:
    """A readable text for factors when the parser gave none: ``N*m/rad``."""
    top = [f.name + _format_exponent(f.exponent) for f in factors if f.exponent > 0]
    bottom = [f.name + _format_exponent(-f.exponent) for f in factors if f.exponent < 0]
    text = "*".join(top) or "1"
    for name in bottom:
        text += "/" + name
    return text


def unit_of(text: str):
    """The :class:`~bondc.units.SIUnit` of a unit written as text (``"kPa"``, ``"kg*m/s"``), or None
    where it is not one."""
    from bondc.errors import BondcError
    from bondc.parse import parse_set_value

    try:
        unit = parse_set_value(f"x = 1 [{text}]", "<header>").unit
    except BondcError:
        return None
    return resolve(unit)[0] if unit is not None else None
