"""A run's result and how it ends: :class:`Result` (variables as :class:`LazyRows`, evaluated on
first read), :func:`write_csv`, the limits on a result's size, the typed failure of a run
(:class:`RunFailure`, carried by :class:`_Stop`) and the mixins of :class:`_Run` that build the
result and diagnose failures."""

import dataclasses
import functools
import os
from collections.abc import Mapping as _Mapping

import numpy as np

from bondc.runtime.adapter import _model_memo, mode_values


# ------------------------------------------------------------------ result


class _Deferred:
    """A matrix of ``shape`` whose columns the ``tasks`` fill (each called with the matrix), on
    the first call only; read-only afterwards. The tasks hold the model, the parameters and the
    points they need, never the run."""

    __slots__ = ("shape", "tasks", "matrix")

    def __init__(self, shape, tasks):
        self.shape, self.tasks, self.matrix = shape, list(tasks), None

    def __call__(self):
        if self.matrix is None:
            matrix = np.empty(self.shape)
            with np.errstate(all="ignore"):
                for task in self.tasks:
                    task(matrix)
            # a row is shared by the variables that are one quantity: read-only, so that changing
            # one in place cannot silently change the others
            matrix.flags.writeable = False
            self.matrix, self.tasks = matrix, None
        return self.matrix


class LazyRows(_Mapping):
    """``name -> array``: the rows of a matrix that is evaluated when a value is first read
    (``rows``: name -> row index; names sharing a row share one read-only array).

    A run's variables are this: the integration stores the states, and every bond variable at
    every point is evaluated only by a caller that reads one (``bondc simulate`` reads them all,
    for the CSV, the energy account and the check that each is finite). Names, their number
    and ``in`` need no evaluation; a copy (``dict(...)``) or a pickle holds plain arrays.

    >>> lazy = LazyRows({"a": 0, "b": 1, "c": 0}, _Deferred((2, 3), [lambda m: m.__setitem__(
    ...     slice(None), [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])]))
    >>> list(lazy), "b" in lazy, lazy.evaluated
    (['a', 'b', 'c'], True, False)
    >>> lazy["b"].tolist(), lazy["a"] is lazy["c"], lazy.evaluated
    ([4.0, 5.0, 6.0], True, True)
    """

    __slots__ = ("_rows", "_deferred", "_views")

    def __init__(self, rows, deferred):
        # a dict is kept as given, never changed: the results of a model's runs share their rows
        self._rows = rows if isinstance(rows, dict) else dict(rows)
        self._deferred, self._views = deferred, None

    @property
    def evaluated(self) -> bool:
        return self._views is not None

    def _values(self) -> dict:
        if self._views is None:
            matrix = self._deferred()
            by_row = {}
            self._views = {name: by_row.setdefault(row, matrix[row]) for name, row in self._rows.items()}
            self._deferred = None
        return self._views

    def __getitem__(self, name):
        return self._values()[name]

    def __iter__(self):
        return iter(self._rows)

    def __len__(self):
        return len(self._rows)

    def __contains__(self, name):
        return name in self._rows

    def __reduce__(self):
        return dict, (dict(self._values()),)

    def __repr__(self):
        shown = ", ".join(list(self._rows)[:4]) + (", ..." if len(self._rows) > 4 else "")
        return f"<LazyRows of {len(self._rows)} ({shown}){'' if self.evaluated else ', not evaluated yet'}>"


class Result:
    """A simulation: ``t``, dicts ``states``, ``outputs``, ``variables`` of arrays by name
    (``variables`` a :class:`LazyRows`: evaluated when one is first read).

    ``complete`` is False when the run stopped early; ``message`` says why and
    ``failure`` (a dict: time, variable, law, cause, hint) gives the details (``run_failure``: the
    same as a :class:`RunFailure`).
    ``events`` lists ``(time, label)`` of every mode change, known-time break
    and chattering episode; ``stats`` the solver's counts.
    """

    def __init__(self, t, states, outputs, variables, events, complete, message, failure, stats,
                 parameters, jumps=(), sliding=(), units=None):
        self.t = t
        self.units = dict(units or {})     # name -> (unit, factor): the model's RESULT_UNITS
        self.states = states
        self.outputs = outputs
        self.variables = variables
        self.events = events
        self.complete = complete
        self.message = message
        self.run_failure = failure if isinstance(failure, RunFailure) else None
        self.failure = failure.as_dict() if isinstance(failure, RunFailure) else failure
        self.stats = stats
        self.parameters = parameters
        self.jumps = list(jumps)        # (t, states before, states after) where a when clause fired
        # (t0, t1, corners, times, weights) of each Filippov sliding mode: its points are those of
        # (t0, t1], at `times`, each the combination of the right-hand sides at the corners (mode
        # vectors, one per row) with the corners' `weights` there (one row per corner)
        self.sliding = list(sliding)

    def __repr__(self):
        end = f"{self.t[-1]:.6g}" if self.t.size else "-"
        return (f"<Result {'complete' if self.complete else 'INCOMPLETE'}: {self.t.size} points to t={end}, "
                f"{len(self.events)} events>")


#: The formats a result is written in, by the output file's suffix (anything else: csv).
RESULT_FORMATS = {".csv": "csv", ".npz": "npz", ".parquet": "parquet"}


def result_format(path) -> str:
    """``"csv"``, ``"npz"`` or ``"parquet"`` for an output file (by its suffix; csv otherwise)."""
    name = str(path).lower()
    return next((kind for suffix, kind in RESULT_FORMATS.items() if name.endswith(suffix)), "csv")


def column_name(name, units) -> str:
    """``P_kPa [kPa]``: a column's name with its unit (the language reference, section 14)."""
    unit = units.get(name)
    return f"{name} [{unit[0]}]" if unit and unit[0] else name


def _header_cell(name, units) -> str:
    """:func:`column_name`, quoted where it holds a comma or a quote."""
    text = column_name(name, units)
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\n') else text


def shown_columns(columns, names, units) -> list:
    """Each column in its unit (SI value / factor), as the csv shows it."""
    factors = [(units.get(name) or (None, 1.0))[1] or 1.0 for name in names]
    return [np.asarray(column, dtype=float) / factor if factor != 1.0 else np.asarray(column, dtype=float)
            for column, factor in zip(columns, factors)]


def result_bytes(kind, names, columns, units, *, arrays=None, metadata=None) -> bytes:
    """A result file's bytes, the one writer of every format; ``columns`` are SI arrays (one per
    name), ``units`` each name's ``(unit, factor)`` (SI value / factor = value in that unit; a
    name without one is SI of an unknown unit).

    * ``csv``: a header of ``NAME [unit]``, then one row per point, each column in its unit, each
      value the shortest text that reads back to the same float;
    * ``parquet`` (needs pyarrow): the csv's columns and numbers, each field's ``unit`` and
      ``si_factor`` in its metadata, ``metadata`` (model, status) in the file's;
    * ``npz``: ``arrays`` (key -> SI array; default: the columns by name) as they are, and for each
      ``unit/KEY`` and ``si_factor/KEY`` (KEY's name is the part after the last ``/``): the
      array divided by its factor is in that unit; ``metadata`` entries as arrays.
    """
    import io

    if kind == "csv":
        out = io.StringIO()
        out.write(",".join(_header_cell(name, units) for name in names) + "\n")
        shown = shown_columns(columns, names, units)
        if shown and shown[0].size:
            for row in np.column_stack(shown).tolist():
                out.write(",".join(map(repr, row)) + "\n")
        return out.getvalue().encode("utf-8")
    if kind == "parquet":
        try:
            import pyarrow
            import pyarrow.parquet
        except ImportError:
            raise ImportError("writing .parquet needs pyarrow (pip install pyarrow)") from None
        fields, data = [], []
        for name, column in zip(names, shown_columns(columns, names, units)):
            unit, factor = units.get(name) or (None, 1.0)
            fields.append(pyarrow.field(name, pyarrow.float64(),
                                        metadata={"unit": unit or "", "si_factor": repr(float(factor or 1.0))}))
            data.append(pyarrow.array(column, type=pyarrow.float64()))
        schema = pyarrow.schema(fields, metadata={key: str(value) for key, value in (metadata or {}).items()})
        sink = pyarrow.BufferOutputStream()
        pyarrow.parquet.write_table(pyarrow.Table.from_arrays(data, schema=schema), sink)
        return sink.getvalue().to_pybytes()
    if kind == "npz":
        arrays = dict(arrays) if arrays is not None else dict(zip(names, columns))
        for key in list(arrays):
            unit, factor = units.get(key.rpartition("/")[2]) or (None, 1.0)
            arrays[f"unit/{key}"] = np.array(unit or "")
            arrays[f"si_factor/{key}"] = np.array(float(factor or 1.0))
        for key, value in (metadata or {}).items():
            arrays[key] = np.asarray(value)
        out = io.BytesIO()
        np.savez_compressed(out, **arrays)
        return out.getvalue()
    raise ValueError(f"unknown result format {kind!r}")


def write_result(result, path, variables=False):
    """Write ``t``, the outputs, the states (and with ``variables`` every variable) of a generated
    module's run, as csv with units (the module's ``RESULT_UNITS``), or as npz or parquet where
    ``path``'s suffix says so (:func:`result_bytes`).

    ``path`` may be a file name or an open text file (csv).
    """
    names = ["t"] + list(result.outputs) + [name for name in result.states if name not in result.outputs]
    columns = [result.t] + list(result.outputs.values()) + [result.states[name] for name in names[1 + len(result.outputs):]]
    if variables:
        extra = [name for name in result.variables if name not in names]
        names += extra
        columns += [result.variables[name] for name in extra]
    units = getattr(result, "units", None) or {}
    if not isinstance(path, (str, os.PathLike)):
        path.write(result_bytes("csv", names, columns, units).decode("utf-8"))
        return
    data = result_bytes(result_format(path), names, columns, units,
                        metadata={"complete": result.complete, "message": result.message})
    # written beside it and renamed into place, as bondc.io.atomic_write does (a standalone module
    # carries the runtime without bondc.io)
    temporary = f"{os.fspath(path)}.{os.getpid()}.tmp"
    try:
        with open(temporary, "wb") as handle:
            handle.write(data)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


#: the name generated modules and scripts have called it by
write_csv = write_result


#: A state beyond this magnitude (in SI units) has left every physical range: the run has diverged.
DIVERGED = 1e30

#: At most this many numbers in a run's result, points x (states + outputs + variables), and at
#: most MAX_POINTS points: recording, the result and its analyses take about 1.2 kB per point of a
#: small model (measured: 17 GB for 14 million points), so a run stays near 1 GB.
MAX_VALUES = 20_000_000
MAX_POINTS = 1_000_000


def max_points(width: int) -> int:
    """How many points a result of ``width`` numbers per point may hold."""
    return max(1000, min(MAX_POINTS, MAX_VALUES // max(1, width)))


@dataclasses.dataclass(frozen=True)
class RunFailure:
    """Why a run stopped early: what :class:`_Stop` carries between the run's parts, and what
    :class:`Result` keeps (``Result.run_failure``; ``Result.failure`` is :meth:`as_dict`).

    ``kind``: ``nonfinite`` (a nan or inf: ``variable`` is the first in causal order, ``law`` its
    law), ``diverged``, ``solver``, ``events`` (stalled, chattering, too many events, Zeno:
    ``when`` names the clause), ``points`` (the result's size limit) or ``interrupted``
    (``terminated``: by SIGTERM). ``time``: where it stopped; ``cause`` and ``hint`` for the
    diagnostic; ``solver_message``: the solver's own words where it gave up."""

    # The fields and their types, as objects rather than annotations: a standalone module's copy of
    # this class may be compiled with ``from __future__ import annotations`` (exec'd by a module
    # that has it) in a namespace no module in sys.modules holds, where dataclasses cannot read
    # string annotations. (RunSpec's likewise.)
    __annotations__ = {"message": str, "time": float, "kind": str, "variable": str | None, "law": str | None,
                       "cause": str | None, "hint": str | None, "when": str | None,
                       "solver_message": str | None, "terminated": bool | None}
    variable = law = cause = hint = when = solver_message = terminated = None

    #: the keys of a failure's dict, in the order a non-finite value's had; the last three only where set
    _KEYS = ("message", "time", "variable", "law", "cause", "hint", "kind", "when", "solver_message", "terminated")

    def as_dict(self) -> dict:
        """The failure as the dict ``Result.failure`` has always been (message, time, variable, law,
        cause, hint, kind; and when, solver_message, terminated where set)."""
        return {key: getattr(self, key) for key in self._KEYS
                if key in self._KEYS[:7] or getattr(self, key) is not None}

    def __getitem__(self, name):
        """``failure["message"]``: read as the dict it replaces (KeyError for an optional field not set)."""
        return self.as_dict()[name]

    def get(self, name, default=None):
        return self.as_dict().get(name, default)

    def replace(self, **changes) -> "RunFailure":
        return dataclasses.replace(self, **changes)


class _CountedBlocks(list):
    """A run's ``blocks_mode``: a block's mode is appended last (after its times and states), and
    then its points count against the run's limit; past it the run stops with what it has."""

    def __init__(self, run):
        super().__init__()
        self.run = run

    def append(self, mode):
        super().append(mode)
        run = self.run
        run.points += int(run.blocks_t[-1].size)
        if run.points > run.max_points:
            t = float(run.blocks_t[-1][-1])
            raise _Stop(RunFailure(message=f"the result reached {run.points} points at t={t:.6g}, more than the "
                                           f"{run.max_points} a run of this model records (at most "
                                           f"{MAX_VALUES:.0e} numbers, about 1 GB with its analyses)",
                                   time=t, kind="points",
                                   cause="every point keeps every state, output and bond variable",
                                   hint="report on a coarser grid (--dt or dt in the experiment) or simulate a "
                                        "shorter time"))


class _Stop(Exception):
    """Ends the run early; carries its :class:`RunFailure`."""

    def __init__(self, failure: RunFailure):
        super().__init__(failure.message)
        self.failure = failure


class _Stalled(_Stop):
    """The unfrozen law stalled at (t, y): the switches there may be held on their surfaces."""

    def __init__(self, failure, t, y):
        super().__init__(failure)
        self.t, self.y = float(t), np.array(y, dtype=float)


def _evaluate_columns(model, p, function, t, x, modes, rows, out=None, columns=slice(None)):
    """``function(t, x, p, modes)`` over columns: at once when the model is vectorized, else one by one.

    Written into ``out[:, columns]`` when given (no matrix of its own: the result's matrices
    of every variable at every point are filled in place), else into a new matrix."""
    if out is None:
        out = np.full((rows, t.size), np.nan)
    if getattr(model, "VECTORIZED", True):
        values = function(t, x, p, modes)
        # rows written into a view (or a block scattered once): not a fancy index per row
        target = out[:, columns] if isinstance(columns, slice) else np.empty((rows, t.size))
        for row, value in enumerate(values):
            target[row] = value
        if not isinstance(columns, slice):
            out[:, columns] = target
    elif getattr(function, "at_points", None) is not None and t.size > 1:
        out[:, columns] = function.at_points(t, x, p, modes)
    else:
        indices = np.arange(out.shape[1])[columns]
        for j in range(t.size):
            out[:, indices[j]] = np.asarray(function(t[j], x[:, j], p, modes), dtype=float)
    return out


def _unique_rows(rows):
    """``np.unique(rows, axis=0, return_inverse=True)``, at once for the common case of a segment
    whose points are all in one mode (numpy sorts the rows as bytes, slow for long segments)."""
    if len(rows) and (rows == rows[0]).all():
        return rows[:1], np.zeros(len(rows), dtype=np.intp)
    if rows.ndim == 2 and rows.size and np.isfinite(rows).all() and (rows == np.round(rows)).all():
        low = rows.min(axis=0)
        base = rows.max(axis=0) - low + 1
        if np.sum(np.log2(base)) < 52:         # each row as one exact integer: a 1-d unique
            weights = np.concatenate(([1.0], np.cumprod(base[:-1])))
            keys = (rows - low) @ weights
            _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
            return rows[first], inverse.ravel()
    return np.unique(rows, axis=0, return_inverse=True)


class _ResultBuilder:
    """What a run recorded made into a :class:`Result`: points' modes, outputs, lazily evaluated
    variables and sliding blends. A collaborator of :class:`_Run`: made from the model, the
    parameters and the start time; :meth:`build` takes the recorded blocks (times, states and
    the mode or sliding combination of each), the mode table, the events, the when clauses'
    jumps and the counts, and reads nothing else of the run."""

    def __init__(self, model, p, t_start):
        self.model, self.p, self.t_start = model, p, float(t_start)
        self.switch_count = len(model.SWITCHES)

    def switch_columns(self, t, x, modes):
        """Switching functions at many points with one mode vector: shape (switches, points)."""
        if getattr(self.model, "VECTORIZED", True):
            return np.asarray(np.broadcast_to(self.model.switches(t, x, self.p, modes),
                                              (self.switch_count, t.size)), dtype=float)
        return _evaluate_columns(self.model, self.p, self.model.switches, t, x, modes, self.switch_count)

    def point_modes(self, t, x, modes, relevant):
        """Modes at every point of a frozen segment: the segment's for the switches that were located,
        ``sign(g)`` at the point for the others (those whose crossings were not events)."""
        rows = np.repeat(np.asarray(modes, dtype=float)[None, :], t.size, axis=0)
        free = np.flatnonzero(~np.asarray(relevant, dtype=bool))
        if free.size == 0 or t.size == 0:
            return rows
        read = self.model.modes_read_by_switches
        # when no switching function reads a free mode, one pass is the fixed point
        passes = 1 if read is not None and not read[free].any() else self.switch_count + 1
        for _ in range(passes):
            changed = False
            unique, inverse = _unique_rows(rows)
            for r, row in enumerate(unique):
                columns = np.flatnonzero(inverse.ravel() == r)
                new = mode_values(self.switch_columns(t[columns], x[:, columns], row)[free],
                            self.model.floor_switches[free]).T
                if not np.array_equal(new, rows[np.ix_(columns, free)]):
                    rows[np.ix_(columns, free)] = new
                    changed = True
            if not changed:
                break
        return rows

    def evaluate_columns(self, function, t, x, modes, rows, out=None, columns=slice(None)):
        """``function(t, x, p, modes)`` over columns: see :func:`_evaluate_columns`."""
        return _evaluate_columns(self.model, self.p, function, t, x, modes, rows, out, columns)

    def _blend(self, function, p, times, x, corner_ids, weights, modes_by_id, rows, columns):
        """The function that writes into ``out[:, columns]`` ``function`` on a Filippov sliding
        mode's points: its corners' values weighted (a corner of weight 0 counts 0, even where its
        value is not finite)."""
        model = self.model
        corners = [(modes_by_id[corner_id], weight) for corner_id, weight in zip(corner_ids, weights)]

        def blend(out):
            total = np.zeros((rows, times.size))
            for modes, weight in corners:
                if np.any(weight != 0):
                    corner = _evaluate_columns(model, p, function, times, x, modes, rows)
                    total += weight * np.where(weight != 0, corner, 0.0)
            out[:, columns] = total
        return blend

    def variable_rows(self) -> dict:
        """Each variable's row of the result's matrix of variables, made once per model (a
        1000-section chain has 6 000 variables); the results share it and never change it."""
        memo = _model_memo(self.model, "variable rows")
        if not memo:
            memo.update(zip(self.model.VARIABLE_NAMES, self.model.VARIABLE_ROWS))
        return memo

    def build(self, complete, failure, blocks_t, blocks_x, blocks_mode, mode_table, events, jumps, stats):
        """The :class:`Result`; ``stats`` (the run's counts) gets the number of points."""
        model = self.model
        n = len(model.STATE_NAMES)
        n_out, n_var = len(model.OUTPUT_NAMES), len(model.VARIABLE_NAMES)
        modes_by_id = {index: np.array(key) for key, index in mode_table.items()}
        if blocks_t:
            t = np.concatenate(blocks_t)
            # point by point in memory (the driver's batches are stored so, as (points, states) copies
            # seen transposed): the batches are copied whole, not state by state (2 ms of a 10 s run
            # of the 1000-section chain), and a point's states are together, as a CSV row takes them
            x = np.empty((n, t.size), order="F")
            np.concatenate(blocks_x, axis=1, out=x)
        else:
            t, x = np.zeros(0), np.zeros((n, 0))
        # restarts that made no progress (a switch re-decided at the same instant) repeat a point:
        # keep its first record, so the time of the result strictly increases. Dropped before the
        # outputs and variables are evaluated (not a copy of every variable at every point after)
        keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.ones(0, dtype=bool)
        kept_blocks = list(zip(blocks_t, blocks_mode))
        if not keep.all():
            t, x, start, kept_blocks = t[keep], x[:, keep], 0, []
            for times, mode in zip(blocks_t, blocks_mode):
                kept = keep[start:start + times.size]
                start += times.size
                if kept.all():
                    kept_blocks.append((times, mode))
                elif kept.any():
                    if isinstance(mode, tuple) and mode[0] == "slide":
                        mode = ("slide", mode[1], np.asarray(mode[2])[:, kept])
                    kept_blocks.append((times[kept], mode))
        # every column is written below, by the sliding blend or by its mode's group; variables that
        # are one quantity (a junction's common effort or flow) are one row, evaluated once
        outputs = np.empty((n_out, t.size))
        picked = model.row_variables
        n_rows = len(picked)
        variable_tasks = []     # each fills its columns of the variables' matrix, when one is read
        # the parameters as they are now (the caller's array may be changed after the run)
        parameters = np.array(self.p, dtype=float)
        if n_rows == n_var:
            variables_of = model.variables
        else:
            def variables_of(tt, xx, p, m, evaluate=model.variables):
                values = evaluate(tt, xx, p, m)
                return [values[i] for i in picked]
            if getattr(model.variables, "at_points", None) is not None:
                variables_of.at_points = (lambda tt, xx, p, m, at=model.variables.at_points, rows=list(picked):
                                          at(tt, xx, p, m)[rows])
        groups = {}             # (mode id, relevant mask) -> column indices
        all_relevant = (True,) * self.switch_count
        sliding = []            # (time before, last time, corners) of each sliding block
        start = 0
        with np.errstate(all="ignore"):
            blocks = []         # consecutive blocks of one sliding mode merged: one evaluation per corner
            for times, mode in kept_blocks:
                if (blocks and isinstance(mode, tuple) and mode[0] == "slide" and isinstance(blocks[-1][1], tuple)
                        and blocks[-1][1][0] == "slide" and blocks[-1][1][1] == mode[1]):
                    last_times, last = blocks[-1]
                    blocks[-1] = (np.concatenate([last_times, times]),
                                  ("slide", mode[1], np.concatenate([last[2], mode[2]], axis=1)))
                else:
                    blocks.append((times, mode))
            for times, mode in blocks:
                columns = np.arange(start, start + times.size)
                start += times.size
                if isinstance(mode, tuple) and mode[0] == "slide":     # the Filippov combination
                    _, corner_ids, weights = mode
                    before = t[columns[0] - 1] if columns[0] > 0 else times[0]
                    sliding.append((float(before), float(times[-1]),
                                    np.array([modes_by_id[c] for c in corner_ids], dtype=float), times, weights))
                    xx = x[:, start - times.size:start]
                    self._blend(model.outputs, self.p, times, xx, corner_ids, weights, modes_by_id, n_out,
                                columns)(outputs)
                    variable_tasks.append(self._blend(variables_of, parameters, times, xx, corner_ids, weights,
                                                      modes_by_id, n_rows, columns))
                    continue
                key = (mode[1], mode[2]) if isinstance(mode, tuple) else (mode, all_relevant)
                groups.setdefault(key, []).append(columns)
            for (mode, relevant), parts in groups.items():
                columns = np.concatenate(parts)
                # contiguous (a run without mode changes): views of the states, not copies
                whole = slice(int(columns[0]), int(columns[-1]) + 1) \
                    if columns.size and columns[-1] - columns[0] + 1 == columns.size else columns
                tt, xx = t[whole], x[:, whole]
                per_point = self.point_modes(tt, xx, modes_by_id[int(mode)], relevant)
                unique, inverse = _unique_rows(per_point)
                for r, row in enumerate(unique):
                    if len(unique) == 1:
                        chosen, cols = slice(None), columns
                    else:
                        chosen = np.flatnonzero(inverse.ravel() == r)
                        cols = columns[chosen]
                    if cols.size and cols[-1] - cols[0] + 1 == cols.size:     # contiguous: a view, no scatter
                        cols = slice(int(cols[0]), int(cols[-1]) + 1)
                    points, states = (tt, xx) if len(unique) == 1 else (tt[chosen], xx[:, chosen])
                    self.evaluate_columns(model.outputs, points, states, row, n_out, outputs, cols)
                    variable_tasks.append(functools.partial(_evaluate_columns, model, parameters, variables_of,
                                                            points, states, row, n_rows, columns=cols))
        # the variables are evaluated from these when first read: read-only, like the variables
        t.flags.writeable = x.flags.writeable = False
        reached = float(t[-1]) if t.size else self.t_start
        if complete:
            message = f"completed: {t.size} points to t={reached:.6g}, {len(events)} events"
        else:
            message = failure.message
        stats["points"] = int(t.size)
        return Result(
            t=t,
            states=dict(zip(model.STATE_NAMES, x)),
            outputs=dict(zip(model.OUTPUT_NAMES, outputs)),
            variables=LazyRows(self.variable_rows(), _Deferred((n_rows, t.size), variable_tasks)),
            events=list(events),
            complete=complete,
            message=message,
            failure=failure,
            stats=dict(stats),
            parameters={name: float(v) for name, v in zip(model.parameter_names, self.p)},
            jumps=[(time, dict(zip(model.STATE_NAMES, before)), dict(zip(model.STATE_NAMES, after)))
                   for time, before, after in jumps],
            sliding=sliding,
            units=model.RESULT_UNITS,
        )


class _Diagnosis:
    """What went wrong at a point, as a :class:`RunFailure`: which quantity first became
    non-finite (a state, a variable in causal order with its law, a derivative) and why, or
    which state diverged. A collaborator of :class:`_Run`, made from the model and the
    parameters; it reads nothing else of the run."""

    def __init__(self, model, p):
        self.model, self.p = model, p

    def nonfinite(self, t, x, modes, context):
        """Name the first non-finite quantity at (t, x): a state, a variable in causal order, a derivative."""
        model = self.model
        variable, law, value = None, None, None
        for name, xi in zip(model.STATE_NAMES, x):
            if not np.isfinite(xi):
                variable, value = name, xi
                break
        if variable is None:
            with np.errstate(all="ignore"):
                values = model.variables(t, x, self.p, modes)
            for name, text, vi in zip(model.VARIABLE_NAMES, model.VARIABLE_LAWS, values):
                if not np.all(np.isfinite(vi)):
                    variable, law, value = name, text, float(np.asarray(vi).ravel()[0])
                    break
        if variable is None:
            with np.errstate(all="ignore"):
                derivatives = np.asarray(model.rhs(t, x, self.p, modes), dtype=float)
            for name, di in zip(model.STATE_NAMES, derivatives):
                if not np.isfinite(di):
                    variable, value = f"der({name})", di
                    break
        what = "nan" if value is None or np.isnan(value) else "inf"
        where = f"'{variable}' became {what} at t={t:.6g}" if variable else f"a {what} appeared at t={t:.6g}"
        if law:
            where += f" (its law: {variable} = {law})"
        states = ", ".join(f"{name}={float(xi):.6g}" for name, xi in zip(model.STATE_NAMES, x))
        if what == "nan" and law and law.startswith("root of the algebraic loop"):
            cause = ("the nonlinear algebraic loop was not solved at this state (Newton's method with a line "
                     "search from its guesses, then MINPACK's hybr): a law in the loop with an infinite slope "
                     "(sign(e)*sqrt(abs(e)) at e = 0) or that leaves its domain on the way, unknowns of very "
                     "different sizes (flows of 1e-8 m^3/s beside pressures of 1e5 Pa), or no solution there")
            hint = (f"the states at t={t:.6g}: {states}. A small storage element in the loop (a node volume, "
                    "a line capacitance, a mass) removes the loop and its solve; a law with a finite slope at "
                    "zero (a laminar band around zero flow) lets Newton's method through")
        else:
            if what == "nan":
                cause = ("a law was evaluated outside its domain: the square root or logarithm of a negative "
                         "number, 0/0 or inf - inf")
            else:
                cause = "a division by zero or an overflow (a quantity growing without bound)"
            hint = (f"check the law of '{variable or '?'}' for the states at t={t:.6g} ({states}); a state that "
                    "left its physical range (a negative pressure, a closed gap) is the usual reason")
        return RunFailure(message=f"{context}{where}", time=float(t), variable=variable,
                          law=law, cause=cause, hint=hint, kind="nonfinite")

    def diverged(self, t, y):
        """The failure of a run whose state left every physical range (DIVERGED)."""
        k = int(np.argmax(np.abs(y)))
        name = self.model.STATE_NAMES[k]
        return RunFailure(message=f"the state '{name}' grew beyond {DIVERGED:g} (to {float(y[k]):.3g}) at t={t:.6g}",
                          time=float(t), variable=name, kind="diverged",
                          cause="the model is unstable (a negative damping or resistance, a positive feedback) "
                                "or a law grows without bound",
                          hint="check the signs and values of the parameters that damp this state")
