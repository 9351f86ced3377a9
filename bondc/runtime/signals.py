"""Signals a generated model calls: ``table``, ``step``, measured csv signals (the one reader of
data files, :func:`load_csv`) and the external inputs a host supplies."""

import csv as _csv
import os

import numpy as np


# ------------------------------------------------------------------ signals


def table(x, breakpoints, values):
    """``table(x, [x0, x1, ...], [v0, v1, ...])``: piecewise linear, held at the ends.

    >>> float(table(0.5, (0.0, 1.0), (0.0, 10.0))), float(table(2.0, (0.0, 1.0), (0.0, 10.0)))
    (5.0, 10.0)
    """
    return np.interp(x, np.asarray(breakpoints, dtype=float), np.asarray(values, dtype=float))


def step(x, x0):
    """``step(x, x0)``: 0 before ``x0``, 1 from it.

    >>> step(0.1, 0.1), step(0.0999, 0.1)
    (1.0, 0.0)
    """
    if np.ndim(x) == 0 and np.ndim(x0) == 0:
        return 1.0 if x >= x0 else 0.0
    return np.where(np.asarray(x) >= x0, 1.0, 0.0)


def as_time(t):
    """``t`` as a numpy float (or float array), so that arithmetic on it follows numpy rules (1/0 is inf)."""
    return np.float64(t) if np.ndim(t) == 0 else np.asarray(t, dtype=float)


def stack(*values):
    """``np.array(values)``, broadcasting scalars against arrays (a constant among time series)."""
    try:
        return np.array(values, dtype=float)
    except ValueError:
        return np.array(np.broadcast_arrays(*values), dtype=float)


_CSV_CACHE = {}


class CsvError(ValueError):
    """A measured-signal file that cannot be read."""


def csv_rows(handle):
    """The rows of an open csv file as every stage of bondc reads them: blank lines and lines
    starting with ``#`` are skipped; the first remaining row is the header."""
    return [row for row in _csv.reader(handle)
            if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")]


#: The largest data file read (a measured signal is a few MB; /dev/zero is endless).
MAX_DATA_BYTES = 256 * 2**20


def open_data(path, encoding="utf-8"):
    """Open a data file for reading: only a regular file of at most MAX_DATA_BYTES (a device, a
    named pipe or a directory would block or never end), else CsvError saying which."""
    import stat

    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise CsvError(f"{path}: not a regular file (a device, a pipe or a directory cannot be a data file)")
    if info.st_size > MAX_DATA_BYTES:
        raise CsvError(f"{path}: {info.st_size} bytes, more than the {MAX_DATA_BYTES} a data file may have")
    return open(path, newline="", encoding=encoding)


def header_cell(cell):
    """``"omega [rpm]"`` -> ``("omega", "rpm")``; ``"omega"`` -> ``("omega", None)``: a column's name
    and the unit its header gives (the language reference, section 14)."""
    cell = cell.strip()
    if cell.endswith("]") and "[" in cell:
        name, _, unit = cell[:-1].rpartition("[")
        if name.strip():
            return name.strip(), unit.strip() or None
    return cell, None


def csv_header(path):
    """The column names of a csv file, without their units (``[]`` when it has no header line)."""
    return [name for name, _ in csv_columns(path)]


def csv_columns(path):
    """``[(name, unit or None), ...]``: the header of a csv file."""
    with open_data(path) as handle:
        rows = csv_rows(handle)
    return [header_cell(cell) for cell in rows[0]] if rows else []



def first_decrease(times) -> int | None:
    """The index i of the first sample after which ``times`` decreases (times[i + 1] < times[i]),
    or None: a csv signal's and an external input's times must not decrease."""
    drops = np.flatnonzero(np.diff(times) < 0)
    return int(drops[0]) if drops.size else None


def load_csv(path, column):
    """Time and value arrays of ``column`` in a csv file (loaded once per path and column).

    The one reader of measured signals: ``bondc check``, the equations stage
    (``linearize``) and the simulation all read files through it. The time is
    the column named ``t`` or ``time`` (any case), else the first column;
    rows as :func:`csv_rows` gives them. Times must not decrease. Columns are
    matched by name; a unit in the header (``omega [rpm]``) is not applied
    here: the compiler scales the signal (see :func:`bondc.numeric.csv_scales`).
    """
    path = os.path.abspath(path)
    try:
        info = os.stat(path)
        key = (path, column, info.st_mtime_ns, info.st_size)     # a file edited since is read again
    except OSError:
        key = (path, column)
    if key in _CSV_CACHE:
        return _CSV_CACHE[key]
    with open_data(path) as handle:
        rows = csv_rows(handle)
    if not rows:
        raise CsvError(f"{path}: empty csv file")
    header = [header_cell(cell)[0] for cell in rows[0]]
    lowered = [name.lower() for name in header]
    time_index = lowered.index("t") if "t" in lowered else (lowered.index("time") if "time" in lowered else 0)
    if column not in header:
        raise CsvError(f"{path}: no column {column!r} (columns: {', '.join(header)})")
    value_index = header.index(column)
    times, values = [], []
    for number, row in enumerate(rows[1:], start=2):
        # (the row's cells are not quoted: a model may name any file, and only its column names
        # are shown)
        for index, into in ((time_index, times), (value_index, values)):
            try:
                into.append(float(row[index]))
            except (ValueError, IndexError):
                raise CsvError(f"{path}: row {number} has no number in column {header[index]!r}") from None
    times, values = np.array(times), np.array(values)
    if times.size == 0:
        raise CsvError(f"{path}: no data rows")
    i = first_decrease(times)
    if i is not None:
        raise CsvError(f"{path}: the time column must not decrease: row {i + 3} has t = {times[i + 1]:g} "
                       f"after {times[i]:g}")
    _CSV_CACHE[key] = (times, values)
    return times, values


def csv_signal(x, base_dir, path, column, time_scale=1.0, value_scale=1.0):
    """A measured signal: ``column`` of the csv file at ``x``, linearly interpolated, held at the ends.

    ``time_scale``/``value_scale``: the SI factors of the units the file's header gives (the compiler
    reads them), so that ``x`` is in s and the result in SI."""
    times, values = load_csv(os.path.join(base_dir, path), column)
    return value_scale * np.interp(x / time_scale, times, values)


def csv_times(base_dir, path, column, time_scale=1.0):
    return load_csv(os.path.join(base_dir, path), column)[0] * time_scale


# -------------------------------------------------------- external inputs

class InputError(ValueError):
    """A signal given for an external input that cannot be used (not a table or a function of t)."""


def external_signal(x, store, name, default):
    """An external input (``input u [V] external = default``) at ``x``: what the host put in the
    module's ``EXTERNAL_INPUTS`` (``store``) under ``name`` -- a table ``(times, values)``, linearly
    interpolated and held at the ends as a csv signal is, or a function of t -- else ``default``."""
    source = store.get(name)
    if source is None:
        return default if np.ndim(x) == 0 else np.zeros(np.shape(x)) + default
    if callable(source):
        return _call_input(source, x, name)
    times, values = source
    return np.interp(x, times, values)


def _call_input(function, x, name):
    """A host's function of t at a time or at an array of times (called point by point where it
    does not take an array)."""
    if np.ndim(x) == 0:
        return _input_number(function(float(x)), name, x)
    times = np.asarray(x, dtype=float)
    try:
        values = np.asarray(function(times), dtype=float)
        if values.shape == times.shape:
            return values
    except Exception:
        pass
    return np.array([_input_number(function(float(v)), name, v) for v in times.ravel()]).reshape(times.shape)


def _input_number(value, name, t):
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(f"the function given for external input {name!r} returned {value!r} at t={float(t):g}, "
                         "not a number") from None
    return value


def external_times(store, name):
    """The sample times of the table the host gave external input ``name`` (none for a function):
    segment boundaries, as a csv signal's samples are."""
    source = store.get(name)
    if source is None or callable(source):
        return ()
    return source[0]


def external_inputs(inputs, names):
    """``{name: (times, values) or f(t)}`` checked and made ready for ``external_signal``: times and
    values are 1-D float arrays of one length (at least one sample), finite, times not decreasing.
    Raises InputError naming what is wrong."""
    prepared = {}
    for name, source in dict(inputs or {}).items():
        if name not in names:
            known = ", ".join(names) if names else "none"
            raise InputError(f"{name!r} is not an external input of this model (its external inputs: {known})")
        if callable(source):
            prepared[name] = source
            continue
        try:
            times, values = source
            times, values = np.asarray(times, dtype=float), np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"external input {name!r} takes a pair (times, values) of number sequences or a "
                             f"function of t, not {type(source).__name__}") from None
        if times.ndim != 1 or values.ndim != 1 or times.size != values.size or times.size == 0:
            raise InputError(f"external input {name!r}: times and values must be two 1-D sequences of one length "
                             f"(at least one sample), not shapes {times.shape} and {values.shape}")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(values))):
            raise InputError(f"external input {name!r}: times and values must be finite numbers (no nan or inf)")
        i = first_decrease(times)
        if i is not None:
            raise InputError(f"external input {name!r}: times must not decrease: t = {times[i + 1]:g} comes after "
                             f"{times[i]:g} (sample {i + 2})")
        prepared[name] = (times, values)
    return prepared


def _with_inputs(store, inputs, task):
    """``task`` run with ``store`` holding ``inputs`` (a run's lazily evaluated variables read the
    signals of their run, whatever later runs of the model set)."""
    def run(*args):
        saved = dict(store)
        store.clear()
        store.update(inputs)
        try:
            return task(*args)
        finally:
            store.clear()
            store.update(saved)
    return run
