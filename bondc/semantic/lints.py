"""Warnings about legal but suspicious models: takes the checked model; reports resistors and
storage elements drawn with their bond leaving them, labels that are another bond's default
name, and unused parameters and inputs. Returns nothing: warnings go to the model.
"""

from __future__ import annotations

from bondc.errors import Related
from bondc.kinds import KINDS, RESISTOR, STORAGE
from bondc.semantic.context import CheckContext, warning_at
from bondc import codes


def check_passive_orientation(m: CheckContext) -> None:
    """W304: a resistor or storage element whose bond is drawn leaving it.

    Its ``e`` and ``f`` follow the half-arrow (LANGUAGE.md section 4), so with the
    bond drawn away from it ``e*f`` is the power it *delivers*: ``e = b*f`` makes a
    resistor a source, and ``der(q) = f`` fills a capacitor as it discharges. That
    is legal but almost never meant.
    """
    for element in m.elements:
        if element.kind not in KINDS or KINDS[element.kind].role not in (RESISTOR, STORAGE):
            continue
        ends = m.ends.get(element.name, ())
        if len(ends) != 1 or ends[0].side != "tail":
            continue
        bond = m.bonds[ends[0].bond - 1]
        role = "it stores" if KINDS[element.kind].stores else "it dissipates"
        m.report(warning_at(
            codes.W304, f"the bond of {element.kind} '{element.name}' is drawn leaving it, so its e*f is the power "
                    f"it delivers, not the power {role}", element.name_span,
            related=(Related(bond.span, f"bond {bond.number} points away from '{element.name}'"),),
            hint=f"draw the bond towards it: '{bond.head} -> {element.name}'"))


def check_label_names(m: CheckContext) -> None:
    """W305: a bond label of the form ``b<N>`` that is also the default name of bond N."""
    for bond in m.bonds:
        if not bond.label or not bond.label[1:].isdigit() or bond.label[0] != "b":
            continue
        number = int(bond.label[1:])
        if number == bond.number or not 1 <= number <= len(m.bonds) or m.bonds[number - 1].label:
            continue
        other = m.bonds[number - 1]
        m.report(warning_at(
            codes.W305, f"label '{bond.label}' names bond {bond.number}, but '{bond.label}' is also bond {number}'s "
                    f"default name; bond {number} is called 'bond{number}' in equations and results",
            bond.label_span if hasattr(bond, "label_span") else bond.span,
            related=(Related(other.span, f"bond {number}"),),
            hint=f"choose a label that is not b<number>, e.g. '{bond.label}_'"))


def check_unused(m: CheckContext) -> None:
    """W301 unused parameter, W302 unused input."""
    for decl in m.decls.values():
        if decl.name in m.used:
            continue
        if decl.category == "parameter":
            m.report(warning_at(codes.W301, f"parameter '{decl.name}' is never used", decl.span,
                                hint="remove it, or use it in a law, input or output"))
        elif decl.category == "input":
            m.report(warning_at(codes.W302, f"input '{decl.name}' is never used", decl.span,
                                hint="remove it, or use it in a law or output (e.g. MSe src : e = "
                                     f"{decl.name})"))
