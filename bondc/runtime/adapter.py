"""The model adapter: a generated module's namespace as a :class:`_Model`, its parameters, the
modes of the unfrozen law (:func:`modes_at`) and :func:`evaluate` of its functions at given points."""


import numpy as np


# ------------------------------------------------------------ model access

_MODEL_NAMES = ("STATE_NAMES", "OUTPUT_NAMES", "VARIABLE_NAMES", "VARIABLE_LAWS", "PARAMETERS",
                "SWITCHES", "EVENT_SWITCHES", "x0", "_rhs", "_jac", "_outputs", "_variables",
                "_switches", "_time_breaks")


class _Model:
    """The names :func:`simulate_model` needs, from a namespace dict or any object."""

    def __init__(self, source):
        if isinstance(source, _Model):
            self.__dict__.update(source.__dict__)
            return
        get = source.__getitem__ if isinstance(source, dict) else (lambda name: getattr(source, name))
        for name in _MODEL_NAMES:
            setattr(self, name.lstrip("_"), get(name))
        count = len(self.SWITCHES)

        def optional(name, convert, default):
            """A name modules from older bondc versions (or hand-made models) may lack."""
            try:
                return convert(get(name))
            except (KeyError, AttributeError):
                return default

        self.derive_parameters = optional("_derive_parameters", lambda f: f, None)
        self.DEFAULTS = optional("DEFAULTS", dict, {})
        self.VECTORIZED = optional("VECTORIZED", bool, True)
        self.SWITCH_DEPENDS = optional("SWITCH_DEPENDS", lambda d: tuple(map(tuple, d)), None)
        self.SWITCH_VERTICES = optional("SWITCH_VERTICES", lambda v: tuple(map(float, v)), (1.0,) * count)
        self.SWITCH_KINDS = optional("SWITCH_KINDS", tuple, ("sign",) * count)
        self.SWITCH_TRUTH = optional("SWITCH_TRUTH", lambda v: tuple(map(int, v)), (0,) * count)
        self.SWITCH_OWNERS = optional("SWITCH_OWNERS", tuple, ("",) * count)
        self.TIME_SWITCHES = optional("TIME_SWITCHES", lambda k: tuple(map(int, k)), ())
        # a model with an algebraic loop: its switches of time alone, over arrays of times
        self.time_switches = optional("_time_switches", lambda f: f, None)
        # variables that are one quantity share a row of the result (VARIABLE_ROWS[i]: variable
        # i's row, rows numbered in order of first use); ``row_variables``: each row's first variable
        rows = optional("VARIABLE_ROWS", lambda r: tuple(map(int, r)), None)
        firsts: dict = {}
        for i, row in enumerate(rows or ()):
            firsts.setdefault(row, i)
        if rows is None or len(rows) != len(self.VARIABLE_NAMES) or list(firsts) != list(range(len(firsts))):
            rows, firsts = tuple(range(len(self.VARIABLE_NAMES))), dict(enumerate(range(len(self.VARIABLE_NAMES))))
        self.VARIABLE_ROWS, self.row_variables = rows, tuple(firsts.values())
        self.JACOBIAN_PATTERN = optional("JACOBIAN_PATTERN", tuple, None)
        # each result column's (unit, factor): SI value / factor = value in that unit
        self.RESULT_UNITS = optional("RESULT_UNITS", lambda u: {k: tuple(v) for k, v in u.items()}, {})
        self.WHEN_LABELS = optional("WHEN_LABELS", tuple, ())
        self.WHEN_TARGETS = optional("WHEN_TARGETS", lambda w: tuple(map(tuple, w)), ())
        self.WHEN_SWITCHES = optional("WHEN_SWITCHES", tuple, ())
        self.WHEN_ACTIONS = optional("WHEN_ACTIONS", tuple, ())
        self.when_conditions = optional("_when_conditions", lambda f: f, None)
        self.dae = optional("_dae", lambda f: f, None)
        self.loop_values = optional("_loop_values", lambda f: f, None)
        self.NATIVE_SOURCE = optional("NATIVE_SOURCE", lambda text: "".join(text), "")
        self.NATIVE_UNAVAILABLE = optional("NATIVE_UNAVAILABLE", str, "")
        # the external inputs the host supplies: the module's own dict, which its functions read
        self.EXTERNAL_INPUT_NAMES = optional("EXTERNAL_INPUT_NAMES", tuple, ())
        self.EXTERNAL_INPUTS = optional("EXTERNAL_INPUTS", lambda store: store, None)
        self.native_library = None      # (ffi, lib) when the model's C code carries the CVODE driver
        self.when_offsets = None        # clause k sets targets offsets[k]:offsets[k + 1], where C runs them
        self.floor_switches = np.array([kind == "floor" for kind in self.SWITCH_KINDS], dtype=bool)
        # the modes some switching function reads (a nested switch's); None: not known
        self.modes_read_by_switches = None if self.SWITCH_DEPENDS is None else np.array(
            [any(k in read for read in self.SWITCH_DEPENDS) for k in range(count)], dtype=bool)
        self.parameter_names = tuple(self.PARAMETERS)


def param_array(parameters, p=None, derive=None):
    """Parameter vector from ``None`` (the defaults), a dict of overrides or an array.

    With a dict, ``derive(array, given_names)`` recomputes the parameters
    defined by others that were not given (the generated ``_derive_parameters``).

    >>> param_array({"m": 2.0, "k": 800.0}, {"k": 100})
    array([  2., 100.])
    """
    names = tuple(parameters)
    if p is None:
        return np.array([float(parameters[name]) for name in names], dtype=float)
    if isinstance(p, dict):
        unknown = sorted(set(p) - set(names))
        if unknown:
            raise KeyError(f"unknown parameter{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                           f"the parameters are: {', '.join(names)}")
        array = np.array([float(p.get(name, parameters[name])) for name in names], dtype=float)
        return derive(array, frozenset(p)) if derive is not None and p else array
    array = np.asarray(p, dtype=float)
    if array.shape != (len(names),):
        raise ValueError(f"p must have {len(names)} entries ({', '.join(names)}), got shape {array.shape}")
    return array


def mode_values(values, floors=None):
    """Modes from switching-function values: their signs, and for ``floor`` switches their floors
    (``floors`` a boolean mask over the first axis); nan gives 0."""
    values = np.asarray(values, dtype=float)
    modes = np.sign(values)
    if floors is not None and np.any(floors):
        modes[floors] = np.floor(values[floors])
    modes[np.isnan(modes)] = 0.0
    return modes


def modes_at(model, t, x, p, guess=None):
    """The mode vector of the unfrozen law at one point: ``m = sign(g(t, x, m))``.

    Switching functions of nested switches depend on inner modes only, so the
    fixed point is reached in at most depth + 1 evaluations.
    """
    count = len(model.SWITCHES)
    if count == 0:
        return np.zeros(0)
    modes = np.ones(count) if guess is None else np.array(guess, dtype=float)
    read = getattr(model, "modes_read_by_switches", None)
    for _ in range(count + 1):
        new = mode_values(model.switches(t, x, p, modes), getattr(model, "floor_switches", None))
        if np.array_equal(new, modes):
            break
        if read is not None and not read[new != modes].any():
            return new      # no switching function reads a mode that changed: the next pass gives new again
        modes = new
    return modes


def _columns_by_mode(model, t, x, p):
    """Group the columns of a trajectory by their modes: {modes tuple: column indices}."""
    groups = {}
    guess = None
    for j in range(t.size):
        guess = modes_at(model, t[j], x[:, j], p, guess)
        groups.setdefault(tuple(guess), []).append(j)
    return groups


def evaluate(model, what, t, x, p=None):
    """Evaluate ``outputs``/``variables``/``rhs``/``jacobian`` with the unfrozen law.

    ``t`` a number and ``x`` a state vector, or ``t`` of shape (N,) and ``x``
    of shape (n, N) for ``outputs`` and ``variables``.
    """
    model = model if isinstance(model, _Model) else _Model(model)
    p = param_array(model.PARAMETERS, p, model.derive_parameters)
    function = {"outputs": model.outputs, "variables": model.variables,
                "rhs": model.rhs, "jacobian": model.jac, "switches": model.switches}[what]
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        modes = modes_at(model, t, x, p)
        value = function(t, x, p, modes)
        return np.asarray(value, dtype=float) if what in ("rhs", "jacobian", "switches") else \
            tuple(float(v) for v in value)
    t = np.broadcast_to(np.asarray(t, dtype=float), x.shape[1:])
    names = model.OUTPUT_NAMES if what == "outputs" else model.VARIABLE_NAMES
    out = np.full((len(names), t.size), np.nan)
    for modes, columns in _columns_by_mode(model, t, x, p).items():
        columns = np.asarray(columns)
        values = function(t[columns], x[:, columns], p, np.array(modes))
        for i, value in enumerate(values):
            out[i, columns] = value
    return tuple(out)


_PATTERNS: dict = {}        # id of a Jacobian pattern -> (it, rows, columns)
_MEMOS: dict = {}           # id of a model's x0 function -> (it, {what: memo})


def _model_memo(model, what) -> dict:
    """A dict kept for ``what`` of a model across its runs in this process (a run works on a copy
    of the model, :class:`_Model`; the generated module's own ``x0`` function names it)."""
    key = model.x0
    known = _MEMOS.get(id(key))
    if known is None or known[0] is not key:
        known = _MEMOS[id(key)] = (key, {})
    return known[1].setdefault(what, {})


def pattern_arrays(pattern):
    """(rows, columns) of a Jacobian pattern (``(row, column)`` pairs; None: none) as arrays, made
    once per pattern object: a model's every run asks (6 000 entries for a 1000-section chain).

    >>> rows, cols = pattern_arrays(((0, 1), (1, 0)))
    >>> rows.tolist(), cols.tolist()
    ([0, 1], [1, 0])
    """
    known = _PATTERNS.get(id(pattern))
    if known is None or known[0] is not pattern:
        entries = np.array(pattern or (), dtype=np.intp).reshape(-1, 2)
        known = _PATTERNS[id(pattern)] = (pattern, entries[:, 0].copy(), entries[:, 1].copy())
    return known[1], known[2]
