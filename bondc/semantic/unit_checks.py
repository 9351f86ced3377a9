"""Declared units: takes the model; resolves each unit written in it to SI
(:mod:`bondc.units`), requires a coherent unit where a value is computed in SI, and suggests
one (:func:`coherent_suggestion`). Returns the resolved units (``m.units``) and diagnostics.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Mapping

from bondc import ast, units
from bondc.semantic.context import CheckContext, error_at
from bondc.semantic.expressions import names_in
from bondc import codes


def resolve_unit(m: CheckContext, unit: ast.Unit | None) -> units.SIUnit | None:
    """The SI meaning of a written unit; E201/E203 reported once per unit."""
    if unit is None:
        return None
    if id(unit) in m.units:
        return m.units[id(unit)]
    numbers = [f for f in unit.factors if f.name != "1" and not f.name[:1].isalpha() and f.name[:1] != "_"]
    if numbers:
        bad = numbers[0]
        m.report(error_at(codes.E203, f"[{unit.text}] is not a unit: '{bad.name}' is a number", bad.span,
                          hint="a unit is a product of unit names (and 1); put a scale factor in the value, "
                               f"e.g. {bad.name}*x [{_without(unit, bad)}]"))
        resolved = None
    else:
        resolved, diagnostics = units.resolve(unit)
        for diagnostic in diagnostics:
            m.report(diagnostic)
    m.units[id(unit)] = resolved
    return resolved


def _without(unit: ast.Unit, factor: ast.UnitFactor) -> str:
    rest = [f for f in unit.factors if f is not factor]
    return units._factors_text(tuple(rest)) if rest else "1"


# Coherent replacements for units that take no prefix.
_COHERENT: Mapping[str, tuple[tuple[str, int], ...]] = {
    "deg": (("rad", 1),), "rev": (("rad", 1),), "rpm": (("rad", 1), ("s", -1)), "min": (("s", 1),),
    "h": (("s", 1),), "bar": (("Pa", 1),), "mbar": (("Pa", 1),), "L": (("m", 3),), "l": (("m", 3),),
}


def _coherent_factors(name: str) -> tuple[tuple[str, int], ...] | None:
    """The coherent SI unit names (with powers) for one unit name: ``kN`` -> N, ``mg`` -> kg."""
    if name in _COHERENT:
        return _COHERENT[name]
    si = units.lookup(name)
    if si is None or si.is_coherent:
        return ((name, 1),)
    if si.dims == _MASS:
        return (("kg", 1),)
    for prefix in units.PREFIXES:
        base = units.lookup(name[len(prefix):]) if name.startswith(prefix) else None
        if base is not None and base.is_coherent and base.dims == si.dims:
            return ((name[len(prefix):], 1),)
    return None


def coherent_suggestion(unit: ast.Unit) -> str:
    """The coherent SI unit measuring the same as ``unit``: ``ms`` -> ``s``, ``kN*m`` -> ``N*m``, ``rpm`` -> ``rad/s``.

    >>> from bondc.parse import parse_set_value
    >>> [coherent_suggestion(parse_set_value(f"x = 1 [{u}]").unit) for u in ("ms", "kN*m", "rpm", "L/min", "mm^2")]
    ['s', 'N*m', 'rad/s', 'm^3/s', 'm^2']
    """
    powers: dict[str, Fraction] = {}
    for factor in unit.factors:
        replacement = _coherent_factors(factor.name)
        if replacement is None:
            powers = {}
            break
        for name, power in replacement:
            if name != "1":
                powers[name] = powers.get(name, Fraction(0)) + power * Fraction(factor.exponent)
    factors = tuple(ast.UnitFactor(name, power) for name, power in powers.items() if power != 0)
    text = units._factors_text(factors) if factors else "1"
    candidate, problems = units.resolve(ast.Unit(factors, text))
    original, _ = units.resolve(unit)
    if original is None:
        return text
    if problems or candidate is None or not candidate.is_coherent or candidate.dims != original.dims:
        return original.dimension_text()
    return text


#: The dimensions of a mass (the kilogram's).
_MASS = tuple(int(base == "kg") for base in units.BASE_DIMENSIONS)


def require_coherent(m: CheckContext, unit: ast.Unit | None, who: str, why: str) -> units.SIUnit | None:
    """E202 unless ``unit`` (if any) is coherent SI; returns the resolved unit."""
    resolved = resolve_unit(m, unit)
    if unit is not None and resolved is not None and not resolved.is_coherent:
        m.report(error_at(codes.E202, f"the unit of {who} must be a coherent SI unit, not [{unit.text}]", unit.span,
                          hint=f"{why}: write [{coherent_suggestion(unit)}]"))
    return resolved


def is_constant(expr: ast.Expr) -> bool:
    """No parameter names: a number written with a unit, converted to SI by it."""
    return all(name == "pi" for name in names_in(expr))


COMPUTED_WHY = ("{} uses other parameters, which are in SI, so it is computed in SI and its unit only declares "
                 "the result")


def check_units(m: CheckContext) -> None:
    """E201 unknown unit, E202 non-coherent unit on a computed value, E203 not a plain unit."""
    for param in m.params:
        if is_constant(param.value):
            resolve_unit(m, param.unit)
        else:
            require_coherent(m, param.unit, f"parameter '{param.name}'",
                              COMPUTED_WHY.format(f"'{param.name}'"))
    for signal in m.inputs:
        require_coherent(m, signal.unit, f"input '{signal.name}'", "an input is computed in SI")
    for output in m.outputs:
        resolve_unit(m, output.unit)
    for state in m.statements(ast.StateDecl):
        require_coherent(m, state.unit, f"state '{state.name}'", "states are integrated in SI")
    for discrete in m.statements(ast.Discrete):
        require_coherent(m, discrete.unit, f"discrete variable '{discrete.name}'", "it is computed in SI")
    for element in m.elements:
        for law in element.laws:
            if isinstance(law, ast.LawState):
                require_coherent(m, law.unit, f"state '{law.name}'", "states are integrated in SI")
