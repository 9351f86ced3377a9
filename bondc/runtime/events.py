"""Events: switches of time found before the run (:func:`bracketed_roots`, :func:`_hidden_changes`),
crossings located on the solver's dense output, the modes at a restart, when clauses, Zeno
detection (:class:`_EventLocation`, a mixin of ``_Run``)."""


import numpy as np

from bondc.runtime.kernels import _EPS
from bondc.runtime.loops import _BLOCK_SOLUTIONS, _ModeReader, _ReadingModes
from bondc.runtime.adapter import mode_values
from bondc.runtime.policy import first_crossing, when_rounds, zeno, zeno_firings
from bondc.runtime.results import RunFailure, _Stop


def bracketed_roots(function, a, b, fa, fb, xtol, rtol):
    """Roots of ``function`` in many brackets ``[a[i], b[i]]`` at once, by bisection of every
    bracket together: ``function(times, rows)`` gives the values at ``times`` (one per bracket
    of ``rows``, an index array), ``fa``/``fb`` its values at the ends. As :func:`brentq` (the
    same tolerance ``xtol + rtol*|x|``; an end where the value is 0 is the root; a value that is
    nan inside gives the right end), but one vectorised call per halving for all brackets, not
    ten Python calls per bracket; a jump (a pwm edge) is found like a zero. The root returned is
    the bracket's end on the far side of the change (where ``function`` has the sign of ``fb``).
    """
    a, b = np.array(a, dtype=float), np.array(b, dtype=float)
    fa, fb = np.asarray(fa, dtype=float), np.asarray(fb, dtype=float)
    roots = b.copy()
    roots[fa == 0] = a[fa == 0]
    side = np.sign(fa)
    active = np.flatnonzero((fa != 0) & (fb != 0) & (side * np.sign(fb) < 0))
    lo, hi = a[active], b[active]
    for _ in range(1100):       # halving the widest double interval down to one ulp takes < 1100
        if not active.size:
            break
        middle = lo + 0.5 * (hi - lo)
        done = (hi - lo <= xtol + rtol * np.abs(hi)) | (middle <= lo) | (middle >= hi)
        if done.any():
            roots[active[done]] = hi[done]
            keep = ~done
            active, lo, hi, middle = active[keep], lo[keep], hi[keep], middle[keep]
            if not active.size:
                break
        with np.errstate(all="ignore"):
            value = np.asarray(function(middle, active), dtype=float)
        lost = np.isnan(value)
        if lost.any():                  # brentq's ValueError: its caller takes the right end
            keep = ~lost
            active, lo, hi, middle, value = active[keep], lo[keep], hi[keep], middle[keep], value[keep]
        before = side[active] * value > 0           # still on the side of a: the change is after
        lo = np.where(before, middle, lo)
        hi = np.where(before, hi, middle)
    return roots


#: Cells that may hide a pulse between two samples of a switch of time are sampled this many times
#: finer, up to this many times over, at most this many values at a time (see _hidden_changes).
_HIDDEN_SPLIT, _HIDDEN_LEVELS, _HIDDEN_VALUES = 64, 3, 1 << 22


def _hidden_changes(values, grid, g, changes):
    """Sign changes of ``g`` (a switch of time, sampled on ``grid``) that the grid's samples do not
    show: a pulse narrower than a cell, whose two samples have the same sign. A cell is suspect
    when its samples are no further from zero than the largest slope seen at it (its own and its
    neighbours') could carry ``g`` across it: the V of ``abs(t - t0) < w``, a ramp that turns. A
    suspect cell is sampled ``_HIDDEN_SPLIT`` times finer, and so are its suspect parts, up to
    ``_HIDDEN_LEVELS`` times. Returns the brackets found (lo, hi, g(lo), g(hi)). A narrow smooth
    bump whose slope the samples never see can still hide: a pulse whose times are known is best
    written with ``step(t, t1) - step(t, t2)``.

    A sample where ``g`` is exactly 0 between samples of one sign may be where a pulse narrower
    than a cell begins or ends (a 50 ps ``pwm`` pulse whose edge falls on the grid): the two cells
    around it are sampled finer as one (:func:`_zero_touches`), the zero in its middle again, so
    that at the finest level the edge is the sample itself."""
    lo, hi, g_lo, g_hi = grid[:-1], grid[1:], g[:-1], g[1:]
    ends = (grid[0], grid[-1])
    spans = _zero_touches(grid[None, :], g[None, :], ends)
    forced = np.zeros(lo.size + spans[0].size, dtype=bool)
    forced[lo.size:] = True
    lo, hi, g_lo, g_hi = (np.concatenate(pair) for pair in zip((lo, hi, g_lo, g_hi), spans))
    found = [[], [], [], []]
    fraction = np.linspace(0.0, 1.0, _HIDDEN_SPLIT + 1)
    for _ in range(_HIDDEN_LEVELS):
        with np.errstate(all="ignore"):
            width = hi - lo
            slope = np.abs(g_hi - g_lo) / width
            bound = slope.copy()
            joined = lo[1:] == hi[:-1]          # neighbours: cells that share an end
            bound[1:] = np.where(joined, np.maximum(bound[1:], slope[:-1]), bound[1:])
            bound[:-1] = np.where(joined, np.maximum(bound[:-1], slope[1:]), bound[:-1])
            suspect = np.flatnonzero(((np.sign(g_lo) * np.sign(g_hi) > 0)
                                      & (np.abs(g_lo) + np.abs(g_hi) <= bound * width)) | forced)
        if not suspect.size or suspect.size * fraction.size > _HIDDEN_VALUES:
            break
        times = lo[suspect, None] + width[suspect, None] * fraction[None, :]
        times[:, -1] = hi[suspect]
        samples = values(times.ravel())
        if not np.all(np.isfinite(samples)):
            break
        at = changes(samples)
        at = at[at % fraction.size != fraction.size - 1]        # not across two cells' ends
        flat = times.ravel()
        for part, value in zip(found, (flat[at], flat[at + 1], samples[at], samples[at + 1])):
            part.append(value)
        cells = samples.reshape(times.shape)
        lo, hi = times[:, :-1].ravel(), times[:, 1:].ravel()
        g_lo, g_hi = cells[:, :-1].ravel(), cells[:, 1:].ravel()
        spans = _zero_touches(times, cells, ends)
        forced = np.zeros(lo.size + spans[0].size, dtype=bool)
        forced[lo.size:] = True
        lo, hi, g_lo, g_hi = (np.concatenate(pair) for pair in zip((lo, hi, g_lo, g_hi), spans))
    return tuple(np.concatenate(part) if part else np.zeros(0) for part in found)


def _zero_touches(times, samples, ends):
    """Spans to sample finer around the zeros of ``samples`` (rows of samples of ``g`` at
    ``times``) that a sign change does not count: a 0 inside a row between samples of one sign
    gives the span of its two neighbours (the zero in its middle); a 0 at ``ends`` (the run's
    first or last time) beside a non-zero sample gives the cell it ends. Returns (lo, hi, g(lo),
    g(hi))."""
    rows, columns = np.nonzero(samples == 0)
    spans = []
    last = samples.shape[1] - 1
    for r, j in zip(rows.tolist(), columns.tolist()):
        if 0 < j < last and np.sign(samples[r, j - 1]) * np.sign(samples[r, j + 1]) > 0:
            spans.append((r, j - 1, j + 1))
        elif j == 0 and times[r, 0] == ends[0] and samples[r, 1] != 0:
            spans.append((r, 0, 1))
        elif j == last and times[r, last] == ends[1] and samples[r, last - 1] != 0:
            spans.append((r, last - 1, last))
    if not spans:
        return (np.zeros(0),) * 4
    r, a, b = (np.array(column) for column in zip(*spans))
    return times[r, a], times[r, b], samples[r, a], samples[r, b]


class _KnownTimes:
    """The switching times a run knows before it starts: the model's known breaks (``_time_breaks``:
    steps, table corners in t, csv samples) and the roots of its switches of time alone, found by
    sampling (:meth:`time_switch_roots`). A collaborator of :class:`_Run`, made from the model, the
    parameters, the span and the run's ``max_step``; after :meth:`breaks`, ``max_step`` is the
    step limit a dense measured signal sets and ``located`` the switches whose changes are all
    known (the run no longer watches them as events)."""

    def __init__(self, model, p, t_start, t_end, max_step):
        self.model, self.p = model, p
        self.t_start, self.t_end = float(t_start), float(t_end)
        self.switch_count = len(model.SWITCHES)
        self.max_step = max_step
        self.located = set()

    def breaks(self):
        """Known switching times inside (t_start, t_end) with their labels, merged when equal. Sets
        ``max_step`` (capped by a dense measured signal's spacing) and ``located``."""
        listed = [(float(tb), label, kind) for tb, label, kind in self.model.time_breaks(self.p)]
        inside = lambda items: [(tb, label) for tb, label in items
                                if np.isfinite(tb) and self.t_start < tb < self.t_end]
        csv = inside((tb, label) for tb, label, kind in listed if kind == "csv")
        other = [(tb, label) for tb, label, kind in listed if kind != "csv"]
        if len(csv) > 200:
            # a dense measured signal: no segment per sample, but no step longer than its typical spacing
            times = np.unique([tb for tb, _ in csv])
            spacing = float(np.median(np.diff(times))) if times.size > 1 else np.inf
            if spacing > 0 and spacing < self.max_step:
                self.max_step = spacing
            csv = []
        found = sorted(inside(other) + csv + self.time_switch_roots())
        merged = []
        tolerance = 4 * _EPS * max(abs(self.t_end), abs(self.t_start), 1.0)
        for tb, label in found:
            if merged and tb - merged[-1][0] <= tolerance:
                if label not in merged[-1][1]:
                    merged[-1][1].append(label)
            else:
                merged.append((tb, [label]))
        return [(tb, "; ".join(labels)) for tb, labels in merged]

    def time_switch_roots(self):
        """The zeros inside the run of the switches of time alone (``if sin(2*pi*f*t) > c``, ``pwm``,
        ``floor(t*f)``), found before integrating: such a switch can change twice within one solver
        step, so it is not left to event location. ``g`` is sampled on a grid refined until the
        number of sign changes (level crossings for ``floor``) stops changing, and every change
        is refined by ``brentq``. Those switches then end segments at known times.

        A switch of time may read the modes of other switches of time (``pwm(t, f, d)`` with a
        duty ``d`` that steps at 50 ms): its ``g`` is evaluated with those modes as they are at
        each time, piece by piece between their own changes (known breaks, or the roots found
        for them first), not with every mode +1."""
        model = self.model
        if not model.TIME_SWITCHES:
            return []
        n = len(model.STATE_NAMES)
        ones = np.ones(self.switch_count)
        vectorized = getattr(model, "VECTORIZED", True)
        if vectorized:
            switches, row_of, rows_count = model.switches, {k: k for k in model.TIME_SWITCHES}, self.switch_count
        elif getattr(model, "time_switches", None) is not None:
            # a model with an algebraic loop: its switches of time alone, without the loop
            switches, row_of = model.time_switches, {k: i for i, k in enumerate(model.TIME_SWITCHES)}
            rows_count = len(row_of)
        else:
            return []
        inner_of = self._inner_time_modes()
        known = {}
        for tb, label, kind in model.time_breaks(self.p):
            if kind != "csv" and np.isfinite(float(tb)):
                known.setdefault(label, []).append(float(tb))

        def changes(g, k):
            if model.floor_switches[k]:
                return np.flatnonzero(np.diff(np.floor(g)) != 0)
            signs = np.sign(g)
            zero = signs == 0
            if zero.any():
                # g exactly 0 at a sample (pwm's edge at t = 0.1 s on a grid through 0.1 s) takes the
                # sign after it: the change then falls in the interval ending there, and brentq
                # returns that sample (g(b) = 0); a product of signs through the zero saw none
                after = np.where(zero, signs.size, np.arange(signs.size))
                after = np.minimum.accumulate(after[::-1])[::-1]
                signs = np.where(after < signs.size, signs[np.minimum(after, signs.size - 1)], 0.0)
            return np.flatnonzero(signs[:-1] * signs[1:] < 0)

        roots, located, found = [], set(), {}
        for k in sorted(model.TIME_SWITCHES, key=lambda k: len(inner_of[k])):
            inner = inner_of[k]
            cuts, resolvable = [], True
            for j in inner:
                if j in found:
                    cuts += found[j]
                elif j in model.TIME_SWITCHES:
                    resolvable = False          # its own roots were not found: left to event location
                else:
                    cuts += known.get(model.SWITCHES[j], [])
            if not resolvable:
                continue
            cuts = np.unique([c for c in cuts if self.t_start < c < self.t_end])
            modes_of = self._piece_modes(inner, cuts, n, ones)
            if modes_of is None:
                continue                    # an inner switch without a value: left to event location

            def values(times, k=k, cuts=cuts, modes_of=modes_of):
                out = np.empty(times.size)
                piece = np.searchsorted(cuts, times, side="right")
                for index in np.unique(piece):
                    chosen = np.flatnonzero(piece == index)
                    for start in range(0, chosen.size, 65536):
                        columns = chosen[start:start + 65536]
                        with np.errstate(all="ignore"):
                            rows = np.broadcast_to(switches(times[columns], np.zeros((n, columns.size)), self.p,
                                                            modes_of[index]), (rows_count, columns.size))
                        out[columns] = rows[row_of[k]]
                return out

            count, previous, size, settled = None, None, 4096, False
            while size <= 2 ** 22:
                grid = np.linspace(self.t_start, self.t_end, size + 1)
                g = values(grid)
                if not np.all(np.isfinite(g)):
                    break
                count = changes(g, k).size
                if count == previous:
                    settled = True
                    break
                previous, size = count, 2 * size
            if not settled:
                continue            # not resolvable by sampling: left to event location
            label = model.SWITCHES[k]

            at = changes(g, k)
            lo, hi, g_lo, g_hi = grid[at], grid[at + 1], g[at], g[at + 1]
            levels = np.zeros(at.size)
            if model.floor_switches[k]:     # the level crossed: g - level changes sign there
                levels = np.where(g[at + 1] > g[at], np.floor(g[at + 1]), np.floor(g[at]))
            else:
                hidden = _hidden_changes(values, grid, g, lambda samples, k=k: changes(samples, k))
                if hidden[0].size:
                    order = np.argsort(np.concatenate((lo, hidden[0])), kind="stable")
                    lo, hi, g_lo, g_hi = (np.concatenate(pair)[order] for pair in zip((lo, hi, g_lo, g_hi), hidden))
                    levels = np.zeros(lo.size)
            found[k] = [float(root) for root in bracketed_roots(
                lambda times, rows, values=values, levels=levels: values(times) - levels[rows],
                lo, hi, g_lo - levels, g_hi - levels, 4 * _EPS, 4 * _EPS)]
            roots += [(root, label) for root in found[k]]
            located.add(k)
        self.located = located
        return roots

    def _inner_time_modes(self) -> dict:
        """Switch of time -> the switches whose modes its ``g`` reads, directly or through them
        (SWITCH_DEPENDS; none where the module does not say)."""
        depends = self.model.SWITCH_DEPENDS
        inner = {}
        for k in self.model.TIME_SWITCHES:
            seen, stack_ = set(), list(depends[k]) if depends is not None else []
            while stack_:
                j = stack_.pop()
                if j not in seen and j != k:
                    seen.add(j)
                    stack_.extend(depends[j])
            inner[k] = sorted(seen)
        return inner

    def _piece_modes(self, inner, cuts, n, ones) -> list | None:
        """The mode vector on each piece between ``cuts``: +1 everywhere but for the ``inner``
        switches, whose modes are taken at the piece's middle (a fixed point, as nested switches
        read one another; every switching function at one point, the state's value irrelevant to
        these: a loop model's loop is solved there). None where one of them has no value."""
        edges = np.concatenate(([self.t_start], cuts, [self.t_end]))
        pieces = []
        for a, b in zip(edges[:-1], edges[1:]):
            modes = ones.copy()
            if inner:
                middle = 0.5 * (a + b)
                for _ in range(len(inner) + 1):
                    with np.errstate(all="ignore"):
                        g = np.ravel(self.model.switches(middle, np.zeros(n), self.p, modes))
                    if not np.all(np.isfinite(g[inner])):
                        return None
                    new = modes.copy()
                    new[inner] = mode_values(g[inner], self.model.floor_switches[inner])
                    if np.array_equal(new, modes):
                        break
                    modes = new
            pieces.append(modes)
        return pieces


class _EventLocation:
    """Events: crossing location on the solver's dense output, the modes at a restart, when
    clauses, Zeno and event-rate limits (the known times are :class:`_KnownTimes`'). A mixin of
    :class:`_Run`: it reads and sets the run's modes, its solver's dense output, its events and
    counts, and calls the sliding and driver parts back."""

    def breaks(self):
        """The run's known switching times (see :class:`_KnownTimes`); the switches of time whose
        roots were all found are no longer watched as events, and a dense measured signal caps
        the step."""
        known = _KnownTimes(self.model, self.p, self.t_start, self.t_end, self.options["max_step"])
        breaks = known.breaks()
        self.options["max_step"] = known.max_step
        if known.located:
            self.event_switches = np.array([k for k in self.event_switches if k not in known.located], dtype=int)
            self.stats["switches_found_ahead"] = len(known.located)
        return breaks

    def restart_modes(self, t, y, guess):
        """Modes just after (t, y), and the switches that chatter there (``bondc_select_modes``,
        the engine's one implementation).

        The modes are probed a step ``h`` ahead along the law they select and
        re-chosen until they agree with it. When they cycle instead (each law
        pushes the state back across the surface of the other), the switches
        that flip within the cycle and matter for one of its laws are returned:
        a sliding mode.
        """
        if self.switch_count == 0:
            return np.zeros(0), []
        if self.queue and guess is not None:
            piece = self.queue[0]       # a restart found with the pieces integrated ahead
            if (piece.t0 == t and piece.guess is not None
                    and piece.guess.tobytes() == np.asarray(guess, dtype=float).tobytes()
                    and piece.y0.tobytes() == np.asarray(y, dtype=float).tobytes()):
                return piece.modes.copy(), []
        modes, flipping, cycle = self.law().select(t, y, np.ones(self.switch_count) if guess is None else guess,
                                                   self.floors_c, self.probe)
        return modes, (self.only_relevant(t, y, cycle, flipping) if flipping else [])

    def only_relevant(self, t, y, rows, switches):
        """The switches among ``switches`` that matter for the law of any of the mode vectors ``rows``."""
        relevant = np.zeros(self.switch_count, dtype=bool)
        for row in rows:
            relevant |= self.relevant(t, y, np.asarray(row, dtype=float))
        return [k for k in switches if relevant[k]]

    def mode_label(self, k, mode) -> str:
        """What an event says of switch ``k`` entering ``mode``: an ``if``'s condition becoming true
        or false (``if h < 0.4 in pump.f -> false``), else the mode (``sign(v) in friction.e -> -1``)."""
        truth = self.model.SWITCH_TRUTH[k]
        if truth in (3, -3):            # == and !=: the condition holds at g = 0 and off it
            holds = (mode == 0) == (truth == 3)
        elif truth:                     # > >= < <=: on the side of its sign, and at g = 0 where not strict
            holds = mode * truth > 0 if mode != 0 else abs(truth) == 2
        else:
            return f"{self.model.SWITCHES[k]} -> {int(mode):+d}"
        return f"{self.model.SWITCHES[k]} -> {'true' if holds else 'false'}"

    def note_event(self, t, label):
        self.events.append((float(t), label))

    def note_break(self, t_break, label, changed=()):
        """Note a known switching time, but of its labels only those not noted otherwise: neither
        switches that changed there (``changed``, noted with their modes) nor switches of when
        conditions."""
        quiet = {self.model.SWITCHES[k] for k in (*changed, *self.condition_switches)}
        rest = [part for part in label.split("; ") if part not in quiet]
        if rest:
            self.note_event(t_break, "; ".join(rest))

    def fire_when_clauses(self, t, y, before_modes, modes, chattering):
        """Run the ``when`` clauses whose condition became true at this restart (false with the modes
        before it, true with those just after), in the order written, every right-hand side with the
        values just before; then the restart's modes again and the conditions again, up to
        ``bondc_when_rounds()`` times (``bondc_when_round``, events.c: the engine's one
        implementation, as the CVODE driver and an FMU fire them)."""
        model = self.model
        law = self.law()
        before = law.when_conditions(t, y, before_modes)
        rounds = when_rounds()
        for round_ in range(rounds + 1):
            firing, new, after = law.when_round(t, y, before, modes)
            if not firing:
                return y, modes, chattering
            if round_ == rounds:
                break
            for k in firing:
                self.note_event(t, model.WHEN_LABELS[k])
                self.stats["when_fired"] = self.stats.get("when_fired", 0) + 1
                self.check_zeno(k, t)
            if not np.all(np.isfinite(new)):
                raise _Stop(self.diagnosis.nonfinite(t, new, modes, f"after {model.WHEN_LABELS[firing[0]]} at t={t:.6g}, "))
            self.jumps.append((float(t), np.array(y, dtype=float), new.copy()))
            y = new
            modes, chattering = self.restart_modes(t, y, modes)
            before = after
        labels = "; ".join(model.WHEN_LABELS[k] for k in firing)
        raise _Stop(RunFailure(message=f"when clauses kept firing at t={t:.6g}: after {rounds} rounds at "
                                       f"the same instant, {labels} became true again",
                               time=float(t), kind="events",
                               cause="the statements of a when clause make another (or its own) condition true "
                                     "again",
                               hint="make the conditions exclusive (a hysteresis band), or the statements move "
                                    "the state out of the condition"))

    def check_zeno(self, k, t):
        """Stop the run where the firings of when clause ``k`` accumulate (Zeno behaviour, a bouncing
        ball coming to rest): the model says nothing about what follows the accumulation point, and
        past it the events can no longer be told apart at the solver's precision (the ball would fall
        through the floor). The test is events.c's ``bondc_zeno`` (an FMU's engine runs the same):
        the clause fired often enough with ever shorter intervals, geometrically (the cycles of a
        frequency sweep shorten far more slowly), the last a small fraction of the run, and the
        intervals' geometric limit before the end of the run."""
        times = self.when_times.setdefault(k, [])
        times.append(float(t))
        del times[:-zeno_firings()]
        found = zeno(times, self.span, self.t_end)
        if found is None:
            return
        limit, ratio = found
        label = self.model.WHEN_LABELS[k]
        raise _Stop(RunFailure(message=f"the events of '{label}' accumulate at t={limit:.6g} (Zeno behaviour): "
                                       f"{len(times)} firings, each interval about {ratio:.3g} times the one "
                                       f"before, the last {times[-1] - times[-2]:.3g} s",
                               time=float(t), kind="events", when=label,
                               cause="infinitely many events before a finite time, as a bouncing ball coming to "
                                     "rest; the model does not say what happens after that time",
                               hint="give the model a law for what follows: e.g. a discrete variable that a when "
                                    "clause sets when the rebound is too small to matter, and that switches the "
                                    "motion off"))

    def note_passing(self, t, modes, held):
        """Note the switches that were candidates for sliding at the restart at ``t`` and are not
        held, where their mode changed there: a friction whose velocity passes through 0 (the force
        to hold it beyond its static limit) is an event like any switch's crossing. Only the event
        list and its count: the run goes on as it would."""
        if self.passing is None or self.passing[0] != t:
            return
        _, before, switches, counted, noting = self.passing
        self.passing = None
        flipped = [k for k in switches if k not in held and modes[k] != before[k]]
        if not flipped or not noting:
            return
        for k in flipped:
            self.note_event(t, self.mode_label(k, modes[k]))
        if not counted:
            self.stats["mode_changes"] += 1

    def too_many_events(self, t):
        window = self.span / 1000.0
        self.recent_events = [te for te in self.recent_events if te > t - window]
        return len(self.recent_events) > self.max_event_rate

    def relevant(self, t, y, modes):
        """Which switches matter for the law selected by ``modes``: those whose modes the right-hand
        side reads (only the active branch of an if reads its modes), and, through SWITCH_DEPENDS,
        the modes their switching functions read. A crossing of any other switch changes nothing the
        solver sees, so it is not located (outputs still get the right mode at every point)."""
        relevant = np.ones(self.switch_count, dtype=bool)
        depends = self.model.SWITCH_DEPENDS
        if depends is None or self.switch_count == 0:
            return relevant
        # which branches are active, so which modes are read, depends on the modes alone (every
        # condition of a law is a switch): once per mode vector and model
        key = tuple(modes)
        known = self.relevant_by_modes.get(key)
        if known is not None:
            return known.copy()
        reader = _ModeReader(modes)
        try:
            with np.errstate(all="ignore"), _ReadingModes():
                self.model.rhs(t, y, self.p, reader)
        except Exception:       # a law that needs a real array of modes: keep every switch
            return relevant
        # a when clause's condition is always watched
        needed, stack_ = set(), list(reader.read) + list(self.model.WHEN_SWITCHES)
        while stack_:
            k = stack_.pop()
            if k not in needed:
                needed.add(k)
                stack_.extend(depends[k])
        relevant[:] = False
        relevant[sorted(needed)] = True
        self.relevant_by_modes[key] = relevant.copy()
        return relevant

    def switches_at(self, t, y, modes, index):
        with np.errstate(all="ignore"):
            return np.asarray(self.model.switches(t, y, self.p, modes), dtype=float)[index]

    def deadbands(self, t, y, modes, index):
        """How far each switching function moves when the state moves by its error tolerance
        (``atol + rtol*|x|``, state by state): crossings shallower than that are integration noise
        (a chamber pressure sitting at its regulator's set point) and are not events
        (``bondc_law_deadbands``, the engine's one implementation)."""
        if index.size == 0:
            return np.zeros(0)
        scale = self.options["atol"] + self.options["rtol"] * np.abs(np.asarray(y, dtype=float))
        return self.law().deadbands(t, y, modes, index, scale)

    def crossing(self, solver, modes, index, signs, old, new, deadband):
        """The earliest switch crossing in the last step: (time, switch index), or None.

        The engine's one implementation (``bondc_first_crossing``, bondc/native/locate.c): a switch
        in mode +-1 crosses when ``m*g`` falls below ``-deadband`` (the zero itself located where it
        lies in the step), a switch in mode 0 when ``|g|`` exceeds it, a floor switch when g leaves
        [m, m + 1); where none changed sign at the step's ends, one that crosses and comes back
        inside the step (a hump of a state passing a threshold). The driver's step is located on
        its interpolant in C; any other solver's on its dense output, called back.
        """
        t_old, t_new = solver.t_old, solver.t
        index = np.asarray(index, dtype=int)
        frozen = np.ascontiguousarray(modes, dtype=float)
        # an algebraic loop's switches, evaluated between the steps, would move the warm starts of
        # its Newton iteration (its last solutions) that the run's next points start from
        kept = dict(_BLOCK_SOLUTIONS)
        try:
            driver = getattr(solver, "driver", None)
            if driver is not None:      # the driver's step: located in C on its interpolant
                return driver.crossing(index, signs, deadband, old, self.floors_c, frozen, t_old, t_new, solver.y)
            if self._dense is None:
                self._dense = solver.dense_output()
            dense = self._dense
            with np.errstate(all="ignore"):
                return first_crossing(lambda tt: self.model.switches(tt, dense(tt), self.p, frozen), self.switch_count,
                                      index, self.model.floor_switches, signs, deadband, old, new, t_old, t_new)
        finally:
            _BLOCK_SOLUTIONS.clear()
            _BLOCK_SOLUTIONS.update(kept)

    def collect(self, solver):
        self.stats["njev"] += int(getattr(solver, "njev", 0) or 0)
        self.stats["nlu"] += int(getattr(solver, "nlu", 0) or 0)
        if getattr(solver, "linear_solver", None):
            self.stats["linear_solver"] = solver.linear_solver
        solver = getattr(solver, "finite_jacobian", solver)     # (scipy's: counted by its Jacobian)
        fallbacks = int(getattr(solver, "jacobian_fallbacks", 0) or 0)
        if fallbacks:
            if not self.stats.get("jacobian_fallbacks"):
                self.note_event(solver.first_fallback, "the analytic Jacobian is not finite here (a law with an infinite "
                                          "slope, like sqrt at 0): finite differences replace it where needed")
            self.stats["jacobian_fallbacks"] = self.stats.get("jacobian_fallbacks", 0) + fallbacks
