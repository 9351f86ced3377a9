"""Freezing discontinuities: laws with if/sign/step/table -> smooth laws of mode symbols.

:class:`Freezer` takes the expressions of a StateSpace in causal order and
returns them with every *discontinuous* construct replaced by a smooth piece
selected by a *mode symbol* ``_m<k>`` (-1, 0 or +1: the sign of the switching
function ``g_k``), and the list of :class:`Switch` es it found:

=========================  =====================  ==================================
construct                  switching function g   frozen form
=========================  =====================  ==================================
``if a < b then u else v``  ``a - b``             ``Piecewise((u, m < 0), (v, True))``
``sign(a)``                ``a``                  ``m``
``step(x, x0)``            ``x - x0``             ``Piecewise((1, m >= 0), (0, True))``
``table(x, xs, vs)``       ``x - xs[i]`` each     the linear piece of the segment
=========================  =====================  ==================================

``abs``, ``min`` and ``max`` are continuous: they are *not* frozen but
evaluated as they are at every point. A frozen ``abs(a)`` would be ``m*a``,
which is negative at the solver's trial points beyond its switch, so
``sign(e)*sqrt(abs(e))`` (the turbulent orifice) or ``sqrt(max(1 - q, 0))``
would be evaluated outside the square root's domain. Only a construct whose
value jumps needs a frozen mode and a located switch; the solver's error
control handles the kinks of continuous ones (and ``sign(e)*sqrt(abs(e))``
stays finite on both sides of its frozen ``sign``: it is continuous at 0).

The same holds for every other switch across which the law stays continuous, a *kink*
(LANGUAGE.md section 7): an ``if`` of one comparison whose two branches agree on its surface (a
relief valve ``if p > p_cr then K*(p - p_cr) else 0``, a diode, a backlash), and a ``sign(a)``
whose product's other factors vanish at ``a = 0`` (a turbulent orifice). :func:`continuous_across`
decides, from the law alone; a kink is kept as written (recorded in :attr:`Freezer.kinks`, no
mode, no event), and everything it cannot show continuous stays a jump.

A condition's ``abs``, ``min`` or ``max`` term is taken apart instead: ``abs(v) < v_th`` is
``v < v_th and -v < v_th`` (:func:`_split_kink`), two switches with smooth switching functions. A
velocity that crosses the whole band within one solver step changes the sign of each once, where
``v_th - abs(v)`` has the same sign at both ends of the step.

Identical switching functions (or opposite ones) share one mode. A switching
function is itself frozen (a ``sign`` inside a condition is its mode), so it is
smooth along a frozen segment and its zero is found by root finding.

Switches of time only are *known in advance*: when ``g`` (with the inputs it
uses substituted) is linear in ``t``, its zero is a parameter expression, a
segment boundary rather than an event; a ``table`` of such an argument is left
as it is (``np.interp`` is continuous, its corners are segment boundaries),
and the sample times of a ``csv`` signal (and of the table the host gives an external
input) are listed the same way.

>>> import sympy
>>> t, f, v0 = sympy.symbols("t f v0", real=True)
>>> freezer = Freezer(t, states={f}, parameters={v0})
>>> freezer.freeze(sympy.Piecewise((f, sympy.Abs(f) < v0), (2*f, True)), "R.e")
Piecewise((f, (_m0 > 0) & (_m1 > 0)), (2*f, True))
>>> [(s.g, s.label) for s in freezer.switches]
[(f + v0, 'if v0 > abs(f) (f < 0) in R.e'), (-f + v0, 'if v0 > abs(f) (f >= 0) in R.e')]
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import sympy
from sympy.core.relational import Relational

from bondc.symbolic import Csv, External, Table, as_sympy

_LABEL_LIMIT = 120


#: An ``if`` condition's comparison, for its events' labels: the sign of the mode where it holds
#: (g = a - b), 2 where it also holds at g = 0 (a non-strict comparison); 3 for ``==``, -3 for ``!=``.
_TRUTH = {sympy.StrictGreaterThan: 1, sympy.GreaterThan: 2, sympy.StrictLessThan: -1, sympy.LessThan: -2,
          sympy.Eq: 3, sympy.Ne: -3}


@dataclass
class Switch:
    """One switching function ``g`` and the mode symbol that freezes it."""

    index: int
    g: sympy.Expr                   # frozen switching function
    mode: sympy.Symbol
    label: str
    event: bool = True              # located by root finding; False: changes only at known times
    vertex: float = 1.0             # mode value of each side while sliding (2: coulomb's static limit)
    kind: str = "sign"              # "sign": m = sign(g); "floor": m = floor(g), an integer held between events
    time_only: bool = False         # g is a function of time alone (no state, no mode): its zeros can be found ahead
    owner: str = ""                 # the variable whose law has it (for diagnostics: its line)
    breaks: list = field(default_factory=list)   # [(time expr, label)] when known in advance
    truth: int = 0                  # an if's condition: _TRUTH of its comparison (the mode where it holds)


@dataclass
class TimeBreak:
    """A time known in advance at which a law changes: a segment boundary."""

    time: sympy.Expr | None          # a parameter expression, or None for csv samples
    label: str
    kind: str                       # "step", "table", "if", "csv", ...
    csv: Csv | None = None
    external: str | None = None     # the samples of the table the host gives this external input


@dataclass(frozen=True)
class Kink:
    """A switch where the law stays continuous: evaluated as written, never frozen nor located."""

    label: str
    owner: str                      # the variable whose law has it


#: The size (sympy operations) up to which a difference of branches is simplified on a switching
#: surface; a larger one is left undecided (a jump), so classifying stays cheap for any law.
_SIMPLIFY_LIMIT = 400


def continuous_across(difference, g) -> bool:
    """Whether ``difference`` (the jump of a law across ``g = 0``: its two branches' difference, or
    the factor of a ``sign(g)``) is 0 everywhere on the surface ``g = 0``.

    ``g`` is solved for a symbol it is linear in, and the difference simplified there; a surface
    that cannot be solved so, or a difference that does not simplify to 0, is not shown continuous
    (the caller treats it as a jump).

    >>> x, c = sympy.symbols("x c", real=True)
    >>> continuous_across(2*(x - c) - 0, x - c), continuous_across(x, x - c)
    (True, False)
    >>> continuous_across(sympy.sqrt(sympy.Abs(x)), x), continuous_across(sympy.sqrt(sympy.Abs(x)) + c, x)
    (True, False)
    """
    if difference.is_number:
        return difference == 0
    if sympy.count_ops(difference) > _SIMPLIFY_LIMIT or difference.has(Table, Csv):
        return False
    for symbol in sorted(g.free_symbols, key=sympy.default_sort_key):
        slope = sympy.diff(g, symbol)
        if slope == 0 or symbol in slope.free_symbols:
            continue
        on_surface = sympy.simplify(difference.subs(symbol, symbol - g / slope))
        return on_surface == 0
    return False


def _split_kink(relation, g):
    """``g < 0`` (or ``<=``, ``>``, ``>=``) as an ``And``/``Or`` of comparisons without the kink of
    an ``abs``, ``max`` or ``min`` term of ``g``, and for each comparison the side of the kink it
    stands for; None when ``g`` has no such term.

    ``abs(v) < v_th`` is ``v < v_th and -v < v_th``: each part's switching function is smooth
    where ``v_th - abs(v)`` has a corner, so a velocity that crosses the whole band within one
    solver step changes the sign of each part once, where ``v_th - abs(v)`` is the same sign at
    both ends of the step and the band would be stepped over. With ``a*max(x, y) + r`` (a > 0)
    the comparison holds below 0 when both ``a*x + r`` and ``a*y + r`` do, above 0 when either
    does; ``abs(u)`` is ``max(u, -u)`` and a negative ``a`` turns a max into a min. The rewrite
    is exact for every value: no case is lost where ``r`` is a number of either sign.
    """
    if relation not in (sympy.StrictLessThan, sympy.LessThan, sympy.StrictGreaterThan, sympy.GreaterThan):
        return None
    for term in sympy.Add.make_args(g):
        coefficient, kink = term.as_coeff_Mul()
        if not isinstance(kink, (sympy.Abs, sympy.Max, sympy.Min)) or coefficient == 0:
            continue
        if isinstance(kink, sympy.Abs):
            largest, pieces = True, (kink.args[0], -kink.args[0])
            sides = (f"{_short(kink.args[0])} >= 0", f"{_short(kink.args[0])} < 0")
        else:
            largest, pieces = isinstance(kink, sympy.Max), kink.args
            sides = tuple(f"{_short(kink)} = {_short(piece)}" for piece in pieces)
        if coefficient < 0:
            largest = not largest
        rest = g - term
        parts = [relation(coefficient * piece + rest, 0) for piece in pieces]
        below = relation in (sympy.StrictLessThan, sympy.LessThan)
        return (sympy.And if below == largest else sympy.Or)(*parts), dict(zip(parts, sides))
    return None


def _short(expr) -> str:
    """A switch's expression for its label, as a model would write it (``abs(v)``, ``x^2``)."""
    from bondc.equations import bg_text

    text = bg_text(expr)
    return text if len(text) <= _LABEL_LIMIT else text[: _LABEL_LIMIT - 3] + "..."


class Freezer:
    """Replaces discontinuous constructs by mode-selected smooth pieces; collects the switches.

    ``states`` and ``parameters`` are sets of symbols; :meth:`define` tells the
    freezer the frozen law of each assigned symbol in causal order, so it
    knows which switches are of time only.
    """

    def __init__(self, time: sympy.Symbol, states=(), parameters=()):
        self.time = time
        self.states = frozenset(states)
        self.parameters = frozenset(parameters)
        self.switches: list[Switch] = []
        self.time_breaks: list[TimeBreak] = []
        self._by_g: dict = {}
        self._explicit: dict = {}        # time-only assigned symbol -> expression of t and parameters
        self._time_only: set = set(self.parameters) | {time}
        self._time_modes: set = set()
        self._owner = ""
        self.kinks: list[Kink] = []
        self._in_condition = 0          # inside a condition's comparison: its abs/min/max become jumps

    # -- bookkeeping

    def define(self, symbol: sympy.Symbol, frozen: sympy.Expr) -> None:
        """Record the frozen law of an assigned symbol (call in causal order)."""
        if frozen.free_symbols <= (self._time_only | self._time_modes):
            self._time_only.add(symbol)
            if not (frozen.free_symbols & self._time_modes):
                self._explicit[symbol] = frozen.xreplace(self._explicit)

    def is_time_only(self, expr) -> bool:
        return expr.free_symbols <= (self._time_only | self._time_modes)

    def _linear_time_root(self, g):
        """The time where ``g`` vanishes when ``g`` is a linear function of t alone, else None."""
        if not (g.free_symbols <= (self._time_only | self._time_modes)):
            return None
        explicit = g.xreplace(self._explicit)
        if not (explicit.free_symbols <= (self.parameters | {self.time})) or self.time not in explicit.free_symbols:
            return None
        if explicit.has(External):     # a signal the host supplies: no closed form in t (and no derivative)
            return None
        slope = sympy.diff(explicit, self.time)
        if slope.free_symbols & {self.time} or slope.has(sympy.Derivative) or slope == 0:
            return None
        offset = explicit.xreplace({self.time: sympy.Integer(0)})
        if sympy.expand(explicit - (slope * self.time + offset)) != 0:
            return None
        return -offset / slope

    def switch(self, g, label: str, kind: str, shared: bool = True, truth: int = 0):
        """The mode expression (``m`` or ``-m``) of switching function ``g``, registering it if new.

        ``shared=False`` gives a switch of its own even when another has the same ``g``
        (a ``coulomb`` friction, whose sliding sides are its static limits). ``kind="floor"``
        makes an integer mode ``m = floor(g)``, shared only with other floors of ``g``. ``truth``:
        for the condition of an ``if`` (its label), the mode in which it holds.
        """
        g = as_sympy(g)
        floor = kind == "floor"
        if g.is_number:
            value = float(g)
            if floor:
                return sympy.Integer(int(np.floor(value)))
            return sympy.Integer(0 if value == 0 else (1 if value > 0 else -1))
        key = ("floor", g) if floor else g
        if shared and key in self._by_g:
            return self._by_g[key].mode
        if shared and not floor and -g in self._by_g:
            return -self._by_g[-g].mode
        index = len(self.switches)
        mode = sympy.Symbol(f"_m{index}", real=True)
        switch = Switch(index, g, mode, f"{label} in {self._owner}" if self._owner else label,
                        kind="floor" if floor else "sign", owner=self._owner, truth=truth)
        # a floor of a linear function of time jumps at every integer: found ahead, not one root
        root = None if floor else self._linear_time_root(g)
        if not (g.free_symbols - self.parameters):
            switch.event = False            # of parameters only: its mode never changes
        elif root is not None:
            switch.event = False
            switch.breaks.append((root, switch.label))
            self.time_breaks.append(TimeBreak(root, switch.label, kind))
        if self.is_time_only(g):
            self._time_modes.add(mode)
            switch.time_only = not (g.free_symbols & set(self.mode_symbols))
        self.switches.append(switch)
        if shared:
            self._by_g[key] = switch
        return mode

    @property
    def mode_symbols(self) -> list[sympy.Symbol]:
        return [s.mode for s in self.switches]

    # -- freezing

    def freeze(self, expr, owner: str = ""):
        """``expr`` with every discontinuity frozen; ``owner`` names it in switch labels."""
        self._owner = owner
        return self._freeze(as_sympy(expr))

    def _freeze(self, expr):
        if expr.is_Atom:
            return expr
        method = getattr(self, "_freeze_" + type(expr).__name__, None)
        if method is not None:
            return method(expr)
        if isinstance(expr, Relational):
            return self._condition(expr)
        if isinstance(expr, sympy.Piecewise):
            return self._freeze_Piecewise(expr)
        args = [self._freeze(arg) if isinstance(arg, sympy.Basic) else arg for arg in expr.args]
        if all(a is b for a, b in zip(args, expr.args)):
            return expr
        return expr.func(*args)

    def _freeze_Piecewise(self, expr):
        kink = self._kink_condition(expr)
        if kink is not None:
            (value, cond), (other, _) = expr.args
            return sympy.Piecewise((self._freeze(value), kink), (self._freeze(other), True))
        pieces = [(self._freeze(value), self._condition(cond)) for value, cond in expr.args]
        return sympy.Piecewise(*pieces)

    def _kink_condition(self, expr):
        """The condition of ``if c then u else v`` kept as written (its sides frozen), when the
        ``if`` is a kink: one comparison of a state-dependent ``g`` whose branches agree on ``g = 0``
        (a relief valve ``if p > p_cr then K*(p - p_cr) else 0``). None: a jump, or undecided."""
        if len(expr.args) != 2 or expr.args[1][1] != sympy.true:
            return None
        (value, cond), (other, _) = expr.args
        if not isinstance(cond, Relational) or isinstance(cond, (sympy.Eq, sympy.Ne)):
            return None
        g = cond.lhs - cond.rhs
        if self.is_time_only(g) or not continuous_across(value - other, g):
            return None
        lhs, rhs = self._freeze(cond.lhs), self._freeze(cond.rhs)
        self._kink(f"if {_short(cond)}")
        return type(cond)(lhs, rhs)

    def _freeze_Mul(self, expr):
        """A product with a ``sign(a)`` factor whose other factors vanish at ``a = 0`` (an orifice's
        ``sign(dp)*sqrt(abs(dp))``) is continuous there: that ``sign`` is a kink, kept as written."""
        args = []
        for arg in expr.args:
            if isinstance(arg, sympy.sign) and not self.is_time_only(arg.args[0]):
                rest = sympy.Mul(*[other for other in expr.args if other is not arg])
                if continuous_across(rest, arg.args[0]):
                    self._kink(f"sign({_short(arg.args[0])})")
                    args.append(sympy.sign(self._freeze(arg.args[0])))
                    continue
            args.append(self._freeze(arg))
        if all(a is b for a, b in zip(args, expr.args)):
            return expr
        return sympy.Mul(*args)

    def _condition(self, cond, written: str = "", sides=None):
        """``cond`` with its comparisons replaced by their switches' modes. ``written``: the
        condition as the model wrote it, when ``cond`` is a part of it made by :func:`_split_kink`
        (for the labels), ``sides`` the side of the kink each part stands for."""
        if cond in (sympy.true, sympy.false):
            return cond
        if isinstance(cond, Relational):
            self._in_condition += 1
            try:
                lhs, rhs = self._freeze(cond.lhs), self._freeze(cond.rhs)
            finally:
                self._in_condition -= 1
            split = _split_kink(type(cond), lhs - rhs)
            if split is not None:
                return self._condition(split[0], written or _short(cond), split[1])
            truth = _TRUTH.get(type(cond), 0)
            side = (sides or {}).get(cond)
            label = f"if {written or _short(cond)}" + (f" ({side})" if side else "")
            mode = self.switch(lhs - rhs, label, "if", truth=truth)
            return type(cond)(mode, 0) if not isinstance(cond, (sympy.Eq, sympy.Ne)) else \
                type(cond)(mode, 0, evaluate=False)
        if isinstance(cond, (sympy.And, sympy.Or, sympy.Not, sympy.Xor)):
            return cond.func(*[self._condition(arg, written, sides) for arg in cond.args])
        if isinstance(cond, sympy.Symbol):
            raise TypeError(f"boolean symbol {cond} in a condition")
        return self._freeze(cond)

    def _continuous(self, expr, label: str):
        """``abs``, ``min``, ``max``: always kinks, evaluated as written; listed as kinks where they
        depend on the state (inside a condition they are taken apart into jumps instead)."""
        if not self._in_condition and not self.is_time_only(expr):
            self._kink(label)
        return expr

    def _kink(self, label: str) -> None:
        kink = Kink(label, self._owner)
        if kink not in self.kinks:
            self.kinks.append(kink)

    def _freeze_Abs(self, expr):
        return self._continuous(sympy.Abs(self._freeze(expr.args[0])), f"abs({_short(expr.args[0])})")

    def _freeze_sign(self, expr):
        arg = self._freeze(expr.args[0])
        return self.switch(arg, f"sign({_short(expr.args[0])})", "sign")

    def _freeze_Coulomb(self, expr):
        """``F_slide*m`` for the sliding modes m = -1, 0, +1; ``F_static*m/2`` for the sticking
        vertices m = -2, +2 that the sliding-mode solver blends to find the holding force."""
        velocity, slide, static = (self._freeze(arg) for arg in expr.args)
        mode = self.switch(velocity, f"coulomb({_short(expr.args[0])})", "coulomb", shared=False)
        self.switches[-1].vertex = 2.0
        slide, static = sympy.Max(slide, 0), sympy.Max(static, 0)
        return sympy.Piecewise((static * mode / 2, sympy.Or(sympy.StrictGreaterThan(mode, 1),
                                                              sympy.StrictLessThan(mode, -1))),
                               (slide * mode, True))

    def _freeze_floor(self, expr):
        """``floor(a)``: an integer mode ``m = floor(g)``, held until ``g`` leaves ``[m, m + 1)``."""
        return self.switch(self._freeze(expr.args[0]), f"floor({_short(expr.args[0])})", "floor")

    def _freeze_ceiling(self, expr):
        return -self._freeze_floor(sympy.floor(-expr.args[0]))

    def _freeze_Pwm(self, expr):
        """``pwm(x, f, d)`` is 1 where ``g = cos(2*pi*(x*f - d/2)) - cos(pi*d)`` is positive: ``g``
        is smooth and vanishes exactly at the edges ``x*f = k`` and ``x*f = k + d``."""
        x, frequency, duty = (self._freeze(arg) for arg in expr.args)
        duty = sympy.Min(sympy.Max(duty, 0), 1)
        g = sympy.cos(2 * sympy.pi * (x * frequency - duty / 2)) - sympy.cos(sympy.pi * duty)
        mode = self.switch(g, f"pwm({', '.join(_short(a) for a in expr.args)})", "pwm")
        return sympy.Piecewise((sympy.Integer(1), sympy.StrictGreaterThan(mode, 0)), (sympy.Integer(0), True))

    def _freeze_Heaviside(self, expr):
        arg = self._freeze(expr.args[0])
        h0 = expr.args[1] if len(expr.args) > 1 else sympy.S.Half
        mode = self.switch(arg, f"heaviside({_short(expr.args[0])})", "heaviside")
        return sympy.Piecewise((1, sympy.StrictGreaterThan(mode, 0)), (h0, sympy.Eq(mode, 0, evaluate=False)),
                               (0, True))

    def _freeze_Min(self, expr):
        return self._continuous(sympy.Min(*[self._freeze(arg) for arg in expr.args]), _short(expr))

    def _freeze_Max(self, expr):
        return self._continuous(sympy.Max(*[self._freeze(arg) for arg in expr.args]), _short(expr))

    def _freeze_Step(self, expr):
        arg, x0 = self._freeze(expr.args[0]), self._freeze(expr.args[1])
        mode = self.switch(arg - x0, f"step({_short(expr.args[0])}, {_short(expr.args[1])})", "step")
        return sympy.Piecewise((sympy.Integer(1), sympy.GreaterThan(mode, 0)), (sympy.Integer(0), True))

    def _freeze_Table(self, expr):
        arg = self._freeze(expr.args[0])
        xs = [self._freeze(v) for v in expr.breakpoints]
        vs = [self._freeze(v) for v in expr.values]
        if len(xs) == 1:
            return vs[0]
        roots = [self._linear_time_root(arg - x) for x in xs]
        if all(root is not None for root in roots):
            # np.interp is continuous; its corners are known times: leave it, split there
            for root, x in zip(roots, xs):
                self.time_breaks.append(TimeBreak(root, f"table corner {_short(expr.args[0])} = {_short(x)}"
                                                  + (f" in {self._owner}" if self._owner else ""), "table"))
            return Table(arg, sympy.Tuple(*xs), sympy.Tuple(*vs))
        modes = [self.switch(arg - x, f"table corner {_short(expr.args[0])} = {_short(x)}", "table")
                 for x in xs]
        pieces = [(vs[0], sympy.StrictLessThan(modes[0], 0))]
        for i in range(len(xs) - 1):
            slope = (vs[i + 1] - vs[i]) / (xs[i + 1] - xs[i])
            pieces.append((vs[i] + slope * (arg - xs[i]), sympy.StrictLessThan(modes[i + 1], 0)))
        pieces.append((vs[-1], True))
        return sympy.Piecewise(*pieces)

    def _freeze_Csv(self, expr):
        self.time_breaks.append(TimeBreak(None, f"csv sample of {expr.column}", "csv", csv=expr))
        return expr

    def _freeze_External(self, expr):
        # the host's table is known when the run starts: its samples are listed as a csv's are
        self.time_breaks.append(TimeBreak(None, f"sample of external input {expr.name}", "csv", external=expr.name))
        return expr
