"""The run loop's policy functions in C (``bondc/native/policy.c``: ``filippov.c`` and ``locate.c``)
as the Python run loop calls them. Filippov sliding's one implementation: the corners' weights (:func:`corner_weights`), the weights that hold the sliding switches on
their surfaces (:func:`filippov_alpha`) and the choice of the switches a sliding mode holds
(:class:`SlidingLaw`), and where values that stay positive first fail to (:func:`first_end`,
:func:`first_dip`: a sliding mode's end, a switch's hump inside a step). The C library is built once
per machine (:func:`load_policy`); the
model's laws reach it as C callbacks of whatever evaluates them (its compiled C functions or its
numpy ones), so every solver and both kinds of model use the same code as the CVODE driver and an
FMU's engine."""

import numpy as np

from bondc.runtime.native import load_policy

_LAW_SIGNATURE = "void(double, const double *, const double *, const double *, double *)"


def _is_affine(sides) -> bool:
    """Whether the corners ``sides`` (corners x switches of +-1) are the affine combination's k + 1."""
    return sides.shape[0] != 2 ** sides.shape[1]


def _doubles(ffi, array):
    return ffi.from_buffer("double[]", array)


def corner_weights(alpha, sides):
    """Weights of the corners. Multilinear (2**k corners): prod_i alpha_i (side +) or
    1 - alpha_i (side -). Affine (k + 1 corners): 1 - sum(alpha) for the all-minus corner and
    alpha_i for the corner with switch i alone on its plus side (the same combination where the
    right-hand side is affine in each switch's weight, as a friction force is).

    >>> corner_weights(np.array([0.25]), np.array([[-1.0], [1.0]])).tolist()
    [0.75, 0.25]
    """
    ffi, lib = load_policy()
    alpha = np.ascontiguousarray(alpha, dtype=float)
    out = np.empty(sides.shape[0])
    lib.bondc_corner_weights(alpha.size, int(_is_affine(sides)), _doubles(ffi, alpha), _doubles(ffi, out))
    return out


def filippov_alpha(rates, sides, guess=None):
    """The weights alpha (one per sliding switch) that make every sliding switch's rate zero.

    The rate is multilinear in alpha (exactly the Filippov / equivalent-control combination;
    linear in the affine one); Newton's method with the minimum-norm least-squares step, so a
    switch whose rate does not depend on its own weight (a free clutch) keeps its guess. The
    result is not clipped: a weight outside [0, 1] means that switch cannot be held on its surface.

    >>> filippov_alpha(np.array([[-3.0], [1.0]]), np.array([[-1.0], [1.0]])).tolist()
    [0.75]
    """
    ffi, lib = load_policy()
    count = sides.shape[1]
    rates = np.ascontiguousarray(rates, dtype=float)
    alpha = np.empty(count)
    given = ffi.NULL if guess is None else _doubles(ffi, np.ascontiguousarray(guess, dtype=float))
    lib.bondc_filippov_alpha(count, int(_is_affine(sides)), _doubles(ffi, rates), given, _doubles(ffi, alpha))
    return alpha


class SlidingLaw:
    """A model's laws at the parameters ``p`` as the engine's C functions call them (``bondc_law``):
    its compiled ``bondc_rhs`` and ``bondc_switches`` where the model has them (``native_functions``),
    else C callbacks of ``model.rhs`` and ``model.switches``."""

    def __init__(self, model, p):
        ffi, lib = load_policy()
        self.ffi, self.lib, self.model = ffi, lib, model
        n, count = len(model.STATE_NAMES), len(model.SWITCHES)
        self.n, self.count = n, count
        self.p = np.ascontiguousarray(p, dtype=float)
        self.vertices = np.ascontiguousarray(model.SWITCH_VERTICES, dtype=float)
        self.failure = None         # an exception a callback met (raised again after the call)
        self._whens = None          # the when clauses' table (bondc_whens), made at the first use

        if getattr(model, "native_functions", None) is not None:   # the model's compiled functions: no Python
            self._callbacks = self._compiled("bondc_rhs", "bondc_switches")
        else:
            self._callbacks = (self._callback(model.rhs, n), self._callback(model.switches, count))
        self.law = ffi.new("bondc_law *")
        self.law.n, self.law.switches = n, count
        self.law.p = _doubles(ffi, self.p)
        self.law.rhs, self.law.switching = self._callbacks
        self.law.vertices = _doubles(ffi, self.vertices)

    def _compiled(self, *names):
        """The model library's functions ``names`` as C ``bondc_law_function`` pointers."""
        model_ffi, model_lib = self.model.native_functions
        return tuple(self.ffi.cast("bondc_law_function", int(model_ffi.cast("uintptr_t", model_ffi.addressof(
            model_lib, name)))) for name in names)

    def _callback(self, function, size):
        """``function(t, x, p, modes)`` (``size`` values) as a C ``bondc_law_function``: an exception
        it raises gives NaN, and is raised again after the C call (``_raise_failure``)."""
        ffi, n, count = self.ffi, self.n, self.count

        def evaluate(t, x, p, m, out):
            try:
                state = np.frombuffer(ffi.buffer(x, 8 * n), dtype=float).copy()
                modes = np.frombuffer(ffi.buffer(m, 8 * count), dtype=float).copy() if count else np.zeros(0)
                with np.errstate(all="ignore"):
                    values = np.asarray(function(float(t), state, self.p, modes), dtype=float).reshape(-1)
                ffi.buffer(out, 8 * size)[:] = values.tobytes()
            except Exception as error:      # C cannot take an exception: NaN, and raised after
                self.failure = self.failure or error
                ffi.buffer(out, 8 * size)[:] = np.full(size, np.nan).tobytes()
        return ffi.callback(_LAW_SIGNATURE, evaluate)

    def _when_table(self):
        """The model's when clauses as events.c calls them (``bondc_whens``), made at the first use:
        its compiled ``bondc_when_conditions`` and ``bondc_when_actions`` where its library has them
        and the run takes C's values as they come, else C callbacks of ``model.when_conditions`` and
        of each clause's ``WHEN_ACTIONS`` (one whose statements cannot be evaluated gives NaN, which
        the round reports as a state that is not finite)."""
        if self._whens is not None:
            return self._whens
        ffi, model = self.ffi, self.model
        count = len(model.WHEN_LABELS)
        sizes = [len(targets) for targets in model.WHEN_TARGETS]
        offsets = np.ascontiguousarray(np.concatenate(([0], np.cumsum(sizes))), dtype=np.intc)
        targets = np.ascontiguousarray([i for clause in model.WHEN_TARGETS for i in clause] or [0], dtype=np.intc)
        total = int(offsets[-1])

        def actions(t, x, p, m):
            values = np.full(total, np.nan)
            for k, action in enumerate(model.WHEN_ACTIONS):
                try:
                    values[offsets[k]:offsets[k + 1]] = np.asarray(action(t, x, p, m), dtype=float).reshape(-1)
                except Exception:           # a clause that fires with it: a state not finite
                    pass
            return values

        if getattr(model, "native_functions", None) is not None and getattr(model, "when_offsets", None) is not None:
            functions = self._compiled("bondc_when_conditions", "bondc_when_actions")
        else:
            functions = (self._callback(model.when_conditions, count), self._callback(actions, total))
        whens = ffi.new("bondc_whens *")
        whens.count = count
        whens.target_start, whens.targets = ffi.from_buffer("int[]", offsets), ffi.from_buffer("int[]", targets)
        whens.conditions, whens.actions = functions
        self._whens = whens
        self._when_keep = (offsets, targets, functions, np.empty(max(total, 1)), np.empty(max(count, 1), dtype=np.intc))
        return whens

    def when_conditions(self, t, y, modes):
        """Each when clause's condition at (t, y) with the modes frozen (not 0 where it holds)."""
        whens = self._when_table()
        y = np.ascontiguousarray(y, dtype=float)
        modes = np.ascontiguousarray(modes, dtype=float)
        out = np.zeros(max(whens.count, 1))
        if whens.count:
            whens.conditions(float(t), _doubles(self.ffi, y), _doubles(self.ffi, self.p), _doubles(self.ffi, modes),
                             _doubles(self.ffi, out))
        self._raise_failure()
        return out[:whens.count]

    def when_round(self, t, y, before, modes):
        """``bondc_when_round``, one round of the when clauses at (t, y): (the clauses that fired, the
        state after them (maybe not finite: the caller's diagnosis), the conditions now, with
        ``modes``: the next round's ``before``)."""
        whens = self._when_table()
        ffi = self.ffi
        y = np.ascontiguousarray(y, dtype=float)
        before = np.ascontiguousarray(before, dtype=float)
        modes = np.ascontiguousarray(modes, dtype=float)
        after = np.zeros(max(whens.count, 1))
        new = np.empty(max(self.n, 1))
        values, fired = self._when_keep[3], self._when_keep[4]
        code = self.lib.bondc_when_round(whens, self.n, float(t), _doubles(ffi, y), _doubles(ffi, self.p),
                                         _doubles(ffi, before), _doubles(ffi, modes), _doubles(ffi, after),
                                         _doubles(ffi, new), ffi.from_buffer("int[]", fired), _doubles(ffi, values))
        self._raise_failure()
        firing = [int(k) for k in np.flatnonzero(fired[:whens.count])] if code != 0 else []
        return firing, new[:self.n].copy(), after[:whens.count].copy()

    def _raise_failure(self):
        failure, self.failure = self.failure, None
        if failure is not None:
            raise failure

    def modes_at(self, t, y, guess, floors):
        """``bondc_modes_at``: the modes of the unfrozen law at (t, y), from ``guess`` (None: all +1)."""
        ffi = self.ffi
        count = self.count
        if count == 0:
            return np.zeros(0)
        y = np.ascontiguousarray(y, dtype=float)
        guess = np.ones(count) if guess is None else np.ascontiguousarray(guess, dtype=float)
        out, scratch = np.empty(count), np.empty(2 * count)
        self.lib.bondc_modes_at(self.law, ffi.from_buffer("int[]", floors), float(t), _doubles(ffi, y),
                                _doubles(ffi, guess), _doubles(ffi, out), _doubles(ffi, scratch))
        self._raise_failure()
        return out

    def select(self, t, y, guess, floors, probe):
        """``bondc_select_modes``: (the modes just after (t, y), the switches that flip where they
        cycle (a sliding mode; [] where they agree a probe ahead), the cycle's mode vectors)."""
        ffi = self.ffi
        count = self.count
        y = np.ascontiguousarray(y, dtype=float)
        guess = np.ascontiguousarray(guess, dtype=float)
        out, rows = np.empty(max(count, 1)), np.empty((10, max(count, 1)))
        flips = np.zeros(max(count, 1), dtype=np.intc)
        row_count = ffi.new("int *")
        code = self.lib.bondc_select_modes(self.law, ffi.from_buffer("int[]", floors), float(t), _doubles(ffi, y),
                                           _doubles(ffi, guess), float(probe), _doubles(ffi, out),
                                           ffi.from_buffer("int[]", flips), _doubles(ffi, rows), row_count)
        self._raise_failure()
        if code < 0:
            raise MemoryError("bondc's mode selection ran out of memory")
        flipping = [int(k) for k in np.flatnonzero(flips[:count])] if code == 1 else []
        return out[:count], flipping, rows[:row_count[0], :count].copy()

    def candidates(self, t, y, modes, chattering, scale, located, slid, relevant, vertices, floors):
        """``bondc_sliding_candidates``: the switches that may slide at (t, y), sorted."""
        ffi = self.ffi
        y = np.ascontiguousarray(y, dtype=float)
        modes = np.ascontiguousarray(modes, dtype=float)
        chattering = np.ascontiguousarray(chattering, dtype=np.intc)
        scale = np.ascontiguousarray(np.broadcast_to(scale, y.shape), dtype=float)
        masks = [np.ascontiguousarray(mask, dtype=np.intc) for mask in (located, slid, relevant)]
        vertices = np.ascontiguousarray(vertices, dtype=float)
        out = np.empty(max(self.count, 1), dtype=np.intc)
        found = self.lib.bondc_sliding_candidates(
            self.law, ffi.from_buffer("int[]", floors), *(ffi.from_buffer("int[]", mask) for mask in masks),
            _doubles(ffi, vertices), float(t), _doubles(ffi, y), _doubles(ffi, modes),
            ffi.from_buffer("int[]", chattering), int(chattering.size), _doubles(ffi, scale),
            ffi.from_buffer("int[]", out))
        self._raise_failure()
        if found < 0:
            raise MemoryError("bondc's sliding candidates ran out of memory")
        return [int(k) for k in out[:found]]

    def near(self, which, t, y, modes, k, vertex, scale, floors, probe=0.0, span=0.0):
        """``bondc_continuous_across`` (``which`` "continuous") or ``bondc_keeps_to`` ("keeps") for
        switch ``k`` near its surface at (t, y)."""
        ffi = self.ffi
        y = np.ascontiguousarray(y, dtype=float)
        modes = np.ascontiguousarray(modes, dtype=float)
        scale = np.ascontiguousarray(np.broadcast_to(scale, y.shape), dtype=float)
        arguments = (self.law, ffi.from_buffer("int[]", floors), float(vertex), float(t), _doubles(ffi, y),
                     _doubles(ffi, modes), int(k), _doubles(ffi, scale))
        if which == "continuous":
            code = self.lib.bondc_continuous_across(*arguments)
        else:
            code = self.lib.bondc_keeps_to(*arguments, float(probe), float(span))
        self._raise_failure()
        if code < 0:
            raise MemoryError("bondc's look at a switch's surface ran out of memory")
        return bool(code)

    def onto_surfaces(self, t, y, modes, held, affine, vertices, alpha, probe, scale, floors):
        """``bondc_onto_surfaces``: the state at a sliding mode's end back on the held switches'
        surfaces where they drifted off but are still held (a new array), else y itself."""
        ffi = self.ffi
        corrected = np.array(y, dtype=float)
        modes = np.ascontiguousarray(modes, dtype=float)
        held = np.ascontiguousarray(held, dtype=np.intc)
        vertices = np.ascontiguousarray(vertices, dtype=float)
        alpha = np.ascontiguousarray(alpha, dtype=float)
        scale = np.ascontiguousarray(np.broadcast_to(scale, corrected.shape), dtype=float)
        code = self.lib.bondc_onto_surfaces(self.law, ffi.from_buffer("int[]", floors), float(t),
                                            _doubles(ffi, corrected), _doubles(ffi, modes),
                                            ffi.from_buffer("int[]", held), int(held.size), int(bool(affine)),
                                            _doubles(ffi, vertices), _doubles(ffi, alpha), float(probe),
                                            _doubles(ffi, scale))
        self._raise_failure()
        if code < 0:
            raise MemoryError("bondc's return onto the surfaces ran out of memory")
        return corrected if code == 1 else y

    def deadbands(self, t, y, modes, index, scale):
        """``bondc_law_deadbands``: how far each switching function of ``index`` moves when each
        state moves by its tolerance ``scale``, summed over the states (not finite: 0)."""
        ffi = self.ffi
        y = np.ascontiguousarray(y, dtype=float)
        modes = np.ascontiguousarray(modes, dtype=float)
        index = np.ascontiguousarray(index, dtype=np.intc)
        scale = np.ascontiguousarray(np.broadcast_to(scale, y.shape), dtype=float)
        out = np.empty(max(index.size, 1))
        code = self.lib.bondc_law_deadbands(self.law, float(t), _doubles(ffi, y), _doubles(ffi, modes),
                                            _doubles(ffi, scale), int(index.size), ffi.from_buffer("int[]", index),
                                            _doubles(ffi, out))
        self._raise_failure()
        if code != 0:
            raise MemoryError("bondc's deadbands ran out of memory")
        return out[:index.size].copy()

    def sliding_set(self, t, y, modes, candidates, probe, span, scale, located, relevant=None, floors=None):
        """``bondc_consistent_sliding_set`` at (t, y): (the held switches, the modes of the others,
        the held switches' weights or None, each switch's vertex, whether the held ones combine
        affinely). ``located`` marks the switches watched as events, ``relevant(modes)`` says which
        switches matter for a law (None: all). Raises :class:`TooManyHeld` where more than 8
        switches would be held whose laws do not combine affinely."""
        ffi = self.ffi
        y = np.ascontiguousarray(y, dtype=float)
        modes = np.array(modes, dtype=float)
        chosen = np.ascontiguousarray(candidates, dtype=np.intc)
        scale = np.ascontiguousarray(np.broadcast_to(scale, y.shape), dtype=float)
        floors = np.zeros(max(self.count, 1), dtype=np.intc) if floors is None else floors
        located = np.ascontiguousarray(located, dtype=np.intc)
        vertices = np.empty(max(self.count, 1))
        held = np.empty(max(self.count, 1), dtype=np.intc)
        alpha = np.empty(max(self.count, 1))
        affine = ffi.new("int *")
        callback = ffi.NULL
        if relevant is not None:
            def matters(_context, m, out):
                try:
                    mask = np.asarray(relevant(np.frombuffer(ffi.buffer(m, 8 * self.count), dtype=float).copy()))
                    ffi.buffer(out, 4 * self.count)[:] = mask.astype(np.intc).tobytes()
                    return 0
                except Exception as error:
                    self.failure = self.failure or error
                    return -1
            callback = ffi.callback("int(void *, const double *, int *)", matters)
        code = self.lib.bondc_consistent_sliding_set(
            self.law, ffi.from_buffer("int[]", floors), ffi.from_buffer("int[]", located), callback, ffi.NULL,
            float(t), _doubles(ffi, y), _doubles(ffi, modes), ffi.from_buffer("int[]", chosen), int(chosen.size),
            float(probe), float(span), _doubles(ffi, scale), _doubles(ffi, vertices), ffi.from_buffer("int[]", held),
            _doubles(ffi, alpha), affine)
        self._raise_failure()
        if code == -1:
            raise MemoryError("bondc's sliding set ran out of memory")
        if code == -2:
            raise TooManyHeld()
        if code == 0:
            return [], modes, None, vertices[:self.count], False
        return [int(k) for k in held[:code]], modes, alpha[:code].copy(), vertices[:self.count], bool(affine[0])


def _values_callback(ffi, values_at, count):
    """``values_at(t)`` (count values) as locate.h's ``bondc_values_at``, and a list that keeps the
    first exception it met (raised again after the call)."""
    failures = []

    def values(_context, t, out):
        try:
            with np.errstate(all="ignore"):
                got = np.asarray(values_at(float(t)), dtype=float).reshape(-1)
            ffi.buffer(out, 8 * count)[:] = got.tobytes()
            return 0
        except Exception as error:      # C cannot take an exception: NaN, and raised after
            failures.append(error)
            ffi.buffer(out, 8 * count)[:] = np.full(count, np.nan).tobytes()
            return -1
    return ffi.callback("int(void *, double, double *)", values), failures


def _locate(name, values_at, a, b, left, right, *rest):
    """locate.c's ``name`` (``bondc_first_end``, ``bondc_first_dip``) over (a, b] for the values
    ``values_at(t)``, ``left`` and ``right`` at the ends: the time found, or None."""
    ffi, lib = load_policy()
    left, right = (np.ascontiguousarray(v, dtype=float) for v in (left, right))
    callback, failures = _values_callback(ffi, values_at, left.size)
    t_end = ffi.new("double *")
    code = getattr(lib, name)(callback, ffi.NULL, left.size, a, b, _doubles(ffi, left), _doubles(ffi, right),
                              *rest, t_end)
    if failures:
        raise failures[0]
    if code < 0:
        raise MemoryError("bondc's location of an end ran out of memory")
    return float(t_end[0]) if code == 0 else None


def first_end(values_at, t_old, t_new, old, new, longest):
    """The earliest end inside the step (t_old, t_new] of values (``values_at(t)``, positive while
    nothing happens; ``old``, ``new`` at the step's ends): where one went from > 0 to <= 0 or from
    >= 0 to < 0, tested every ``longest`` (inf or 0: at the ends only) and for dips between the
    tests (``bondc_first_end``), or None.

    >>> first_end(lambda t: [1.0 - t], 0.0, 2.0, [1.0], [-1.0], 0.0)
    1.0
    """
    return _locate("bondc_first_end", values_at, float(t_old), float(t_new), old, new,
                   float(longest) if np.isfinite(longest) else 0.0)


def first_dip(values_at, a, b, left, right):
    """Where one of the values, positive at both ends of (a, b), dips below 0 inside it
    (``bondc_first_dip``), or None.

    >>> round(first_dip(lambda t: [abs(t - 0.3) - 0.01], 0.0, 1.0, [0.29], [0.69]), 6)
    0.29
    """
    return _locate("bondc_first_dip", values_at, float(a), float(b), left, right)


def first_crossing(values_at, switches, index, floors, signs, band, old, new, t_old, t_new):
    """The earliest crossing in the step (t_old, t_new] of the switches ``index`` (``bondc_first_crossing``,
    the engine's one implementation): ``values_at(t)`` gives every switching function on the step's
    interpolant with the modes frozen, ``signs`` the switches' modes, ``band`` their deadbands, ``old`` and
    ``new`` their values at the step's ends, ``floors`` a mask of floor switches. (time, switch) or None.

    >>> first_crossing(lambda t: [0.5 - t], 1, [0], [False], [1.0], [0.0], [0.5], [-0.5], 0.0, 1.0)
    (0.5, 0)
    """
    ffi, lib = load_policy()
    watch = np.ascontiguousarray(index, dtype=np.intc)
    floors = np.ascontiguousarray(floors, dtype=np.intc)
    signs, band, old, new = (np.ascontiguousarray(v, dtype=float) for v in (signs, band, old, new))
    callback, failures = _values_callback(ffi, values_at, switches)
    t_event = ffi.new("double *")
    j = lib.bondc_first_crossing(callback, ffi.NULL, int(switches), int(watch.size), ffi.from_buffer("int[]", watch),
                                 ffi.from_buffer("int[]", floors), _doubles(ffi, signs), _doubles(ffi, band),
                                 _doubles(ffi, old), _doubles(ffi, new), float(t_old), float(t_new), t_event)
    if failures:
        raise failures[0]
    if j == -2:
        raise MemoryError("bondc's crossing location ran out of memory")
    return None if j < 0 else (float(t_event[0]), int(watch[j]))


class TooManyHeld(Exception):
    """More than 8 switches would be held whose laws do not combine affinely."""


def when_rounds() -> int:
    """The most rounds of when clauses at one instant (events.c's ``bondc_when_rounds``)."""
    return int(load_policy()[1].bondc_when_rounds())


def zeno(times, span, t_end):
    """Where the firing ``times`` of one when clause (oldest first) accumulate (``bondc_zeno``: Zeno
    behaviour, a bouncing ball coming to rest): (the accumulation time, the intervals' mean ratio),
    or None. Only the last :func:`zeno_firings` times count.

    >>> gaps = 0.5 ** np.arange(20) * 1e-3
    >>> limit, ratio = zeno(np.cumsum(gaps), 10.0, 10.0)
    >>> round(limit, 9), round(ratio, 9)
    (0.002, 0.5)
    >>> zeno(np.arange(20.0) * 1e-6, 10.0, 10.0) is None         # evenly spaced: a fast clock, not Zeno
    True
    """
    ffi, lib = load_policy()
    times = np.ascontiguousarray(times, dtype=float)
    limit, ratio = ffi.new("double *"), ffi.new("double *")
    if not lib.bondc_zeno(int(times.size), _doubles(ffi, times), float(span), float(t_end), limit, ratio):
        return None
    return float(limit[0]), float(ratio[0])


def zeno_firings() -> int:
    """How many of a when clause's last firing times :func:`zeno` looks at."""
    return int(load_policy()[1].bondc_zeno_firings())
