"""The abstract syntax tree of a .bg file: frozen dataclasses with spans.

``parse`` produces these; every later stage reads them and never the text.
Spans (and comment positions) are excluded from equality, so two parses of
differently laid-out but equivalent text compare equal: that is what makes
``parse(fmt(x)) == parse(x)`` a meaningful test.

>>> from bondc.parse import parse_text
>>> f = parse_text("model M\\n  param k = 800 [N/m]\\nend\\n", "m.bg")
>>> f.models[0].body[0].name, f.models[0].body[0].value
('k', Num(value=800.0, text='800'))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from typing import Iterator, Union

from bondc.source import NO_SPAN, Source, Span


def _span() -> Span:
    return field(default=NO_SPAN, compare=False, repr=False)


# ---------------------------------------------------------------- expressions

@dataclass(frozen=True)
class Num:
    value: float
    text: str
    span: Span = _span()


@dataclass(frozen=True)
class Str:
    value: str
    span: Span = _span()


@dataclass(frozen=True)
class Name:
    name: str
    span: Span = _span()


@dataclass(frozen=True)
class Ref:
    """A dotted reference to a graph variable: ``mass.f``, ``screw.p1.e``, ``b9.e``."""

    parts: tuple[str, ...]
    span: Span = _span()

    @property
    def dotted(self) -> str:
        return ".".join(self.parts)


@dataclass(frozen=True)
class Call:
    func: str
    args: tuple["Expr", ...]
    span: Span = _span()
    func_span: Span = _span()


@dataclass(frozen=True)
class ListExpr:
    items: tuple["Expr", ...]
    span: Span = _span()


@dataclass(frozen=True)
class Unary:
    op: str  # "-", "+", "not"
    operand: "Expr"
    span: Span = _span()


@dataclass(frozen=True)
class Binary:
    op: str  # + - * / ^ < <= > >= == != and or
    left: "Expr"
    right: "Expr"
    span: Span = _span()


@dataclass(frozen=True)
class If:
    cond: "Expr"
    then: "Expr"
    orelse: "Expr"
    span: Span = _span()


@dataclass(frozen=True)
class Transfer:
    """``U -> Y`` in the experiment setting ``bode = [U -> Y, ...]``: from input U to output Y (only
    there: the grammar allows it nowhere else)."""

    source: Name
    target: Name
    span: Span = _span()


Expr = Union[Num, Str, Name, Ref, Call, ListExpr, Unary, Binary, If]


# ---------------------------------------------------------------------- units

@dataclass(frozen=True)
class UnitFactor:
    """One unit name raised to a power; ``name`` is ``"1"`` for a bare number."""

    name: str
    exponent: Fraction
    span: Span = _span()


@dataclass(frozen=True)
class Unit:
    """A unit as written, flattened to factors: ``N*m/rad`` -> N^1 m^1 rad^-1."""

    factors: tuple[UnitFactor, ...]
    text: str
    span: Span = _span()


# ---------------------------------------------------------------------- laws

@dataclass(frozen=True)
class LawAssign:
    """``e = expr``, ``f = expr``, ``r = expr``."""

    target: str
    value: Expr
    span: Span = _span()
    target_span: Span = _span()
    unit: "Unit | None" = None   # only an instance's binding may carry one: ``A = 2e-5 [m^2]``


@dataclass(frozen=True)
class LawCall:
    """``q(0) = expr`` (initial value) or ``der(P) = expr`` (rate law)."""

    func: str
    arg: Expr
    value: Expr
    span: Span = _span()
    func_span: Span = _span()


@dataclass(frozen=True)
class LawState:
    """``state P [Pa] "description"``: a storage element's own state."""

    name: str
    unit: Unit | None
    description: str | None
    span: Span = _span()
    name_span: Span = _span()


Law = Union[LawAssign, LawCall, LawState]


# ---------------------------------------------------------------- statements

@dataclass(frozen=True)
class Import:
    path: str
    span: Span = _span()


@dataclass(frozen=True)
class FnDef:
    name: str
    params: tuple[str, ...]
    body: Expr
    description: str | None = None
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class Param:
    name: str
    value: Expr
    unit: Unit | None
    description: str | None
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class Element:
    kind: str
    name: str
    description: str | None
    laws: tuple[Law, ...]
    span: Span = _span()
    kind_span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class Junction:
    kind: str  # "0" or "1"
    names: tuple[str, ...]
    span: Span = _span()
    kind_span: Span = _span()
    name_spans: tuple[Span, ...] = field(default=(), compare=False, repr=False)


@dataclass(frozen=True)
class Endpoint:
    name: str
    port: str | None
    span: Span = _span()


@dataclass(frozen=True)
class BondChain:
    """``A -> B -> C`` (two bonds), optionally labelled: ``b9: A -> B``."""

    label: str | None
    endpoints: tuple[Endpoint, ...]
    span: Span = _span()
    label_span: Span = _span()


@dataclass(frozen=True)
class Input:
    name: str
    unit: Unit | None
    value: Expr | None          # None: a component's input that every instance must bind (or, external, 0)
    description: str | None
    span: Span = _span()
    name_span: Span = _span()
    external: bool = False      # ``input u [V] external = default``: supplied by the host (section 15)


@dataclass(frozen=True)
class Output:
    name: str
    unit: Unit | None
    value: Expr
    description: str | None
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class StateDecl:
    """A model-level state: ``state x [m] "travel" : der(x) = mass.f, x(0) = 0``."""

    name: str
    unit: Unit | None
    description: str | None
    laws: tuple[Law, ...]
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class Discrete:
    """``discrete heater [1] = 0 "relay state"``: piecewise constant, changed only by ``when``."""

    name: str
    unit: Unit | None
    value: Expr
    description: str | None
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class WhenAssign:
    """``heater = 1`` inside a ``when``: a discrete variable takes a new value."""

    name: str
    value: Expr
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class WhenCall:
    """``reinit(ball.p, -e*ball.p)`` inside a ``when``."""

    func: str
    args: tuple[Expr, ...]
    span: Span = _span()
    func_span: Span = _span()


@dataclass(frozen=True)
class When:
    """``when CONDITION then STATEMENT, ... end``: runs at the instant the condition becomes true."""

    condition: Expr
    actions: tuple[Union[WhenAssign, WhenCall], ...]
    span: Span = _span()


@dataclass(frozen=True)
class Setting:
    name: str
    value: Expr
    unit: Unit | None
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class Experiment:
    """An experiment; ``param`` and ``input`` inside it override the model's."""

    name: str
    description: str | None
    body: tuple[Union[Setting, Param, Input], ...]
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class PortDecl:
    """``port a, b``: the power ports of a model used as a component (LANGUAGE.md section 11)."""

    names: tuple[str, ...]
    span: Span = _span()
    name_spans: tuple[Span, ...] = field(default=(), compare=False, repr=False)


@dataclass(frozen=True)
class Defaults:
    """``defaults ... end``: settings every experiment of the model inherits (section 13)."""

    body: tuple[Setting, ...]
    span: Span = _span()


Statement = Union[Param, Element, Junction, BondChain, FnDef, Input, Output, StateDecl, Discrete, When, Experiment,
                  PortDecl, Defaults]


@dataclass(frozen=True)
class Model:
    name: str
    description: str | None
    body: tuple[Statement, ...]
    span: Span = _span()
    name_span: Span = _span()


@dataclass(frozen=True)
class Comment:
    text: str
    span: Span = _span()


@dataclass(frozen=True)
class File:
    items: tuple[Union[Import, FnDef, Model], ...]
    path: str = field(default="", compare=False)
    comments: tuple[Comment, ...] = ()

    @property
    def models(self) -> tuple[Model, ...]:
        return tuple(item for item in self.items if isinstance(item, Model))

    @property
    def functions(self) -> tuple[FnDef, ...]:
        return tuple(item for item in self.items if isinstance(item, FnDef))

    @property
    def imports(self) -> tuple[Import, ...]:
        return tuple(item for item in self.items if isinstance(item, Import))


@dataclass(frozen=True)
class SetValue:
    """``NAME=VALUE [unit]`` from the command line's ``--set``."""

    name: str
    value: Expr
    unit: Unit | None
    span: Span = _span()
    source: Source | None = field(default=None, compare=False, repr=False)  # the Source it was parsed from


def walk(expr: Expr) -> Iterator[Expr]:
    """Every sub-expression of ``expr``, depth first, ``expr`` first."""
    yield expr
    if isinstance(expr, Call):
        for arg in expr.args:
            yield from walk(arg)
    elif isinstance(expr, ListExpr):
        for item in expr.items:
            yield from walk(item)
    elif isinstance(expr, Transfer):
        yield expr.source
        yield expr.target
    elif isinstance(expr, Unary):
        yield from walk(expr.operand)
    elif isinstance(expr, Binary):
        yield from walk(expr.left)
        yield from walk(expr.right)
    elif isinstance(expr, If):
        yield from walk(expr.cond)
        yield from walk(expr.then)
        yield from walk(expr.orelse)
