"""Frequency response: a :class:`~bondc.analysis.linearize.Linearization` -> Bode data and margins.

``bondc bode`` linearises the model with :func:`bondc.analysis.linearize.linearize` (the same
operating points -- initial state or equilibrium, inputs held at ``--time`` -- and the same
diagnostics, E940/E941) and evaluates

    G(jw) = C (jw I - A)^-1 B + D

for each pair (input U, output Y) in SI units: magnitude in dB (20 log10 |G|), phase in degrees,
unwrapped along the frequency axis (``numpy.unwrap``) so that it is continuous.

Solve. A model of up to :data:`DENSE_STATES` states is balanced once (``scipy.linalg.matrix_balance``,
a diagonal similarity that evens out states of very different scales: a flux of 1e-3 Wb next to
a momentum of 10 kg*m/s) and solved densely per frequency (LAPACK ``gesv``). A larger one is
sparse -- a chain of N sections couples each state to a few neighbours -- and ``jw I - A`` is
factorised per frequency by SuperLU (``scipy.sparse.linalg.splu``): measured on the
1000-section chain (2000 states, 7000 non-zeros), 400 frequencies take 0.4 s, where the
Hessenberg route (``scipy.linalg.hessenberg`` once, then a solve per frequency) takes 26 s
for the reduction alone (``benchmarks/bode.py`` keeps the ratio).

Margins of G taken as an open loop (``control.stability_margins`` of python-control on the
computed response as an FRD): the gain margin where the phase crosses -180 deg, the phase
margin where |G| crosses 1 (0 dB), each with its crossover frequency, or None where there is no
crossing in the frequency range.

Default range: from a tenth of the slowest non-zero mode's frequency |lambda|/(2 pi) to ten
times the fastest's, :data:`DEFAULT_POINTS` points spaced logarithmically.

Verification (:func:`verify`): the nonlinear model is simulated from the operating point with
the input ``u0 + a sin(2 pi f t)`` (the input made an external one, supplied by a function of
``t`` through the simulator's external inputs), until the transients have decayed; the steady
oscillation of the output over the last whole periods is fitted by least squares
(``numpy.linalg.lstsq`` on 1, t, sin, cos) and compared with the linear prediction.

Diagnostics: E942 an unknown input or output name; E943 a name that is not an input (or not an
output); E944 a bad frequency or range; E945 a bad ``--points``; E946 ``--verify`` where it cannot
run (an operating point not at rest, an unstable model, a bad amplitude); E947 an output file of
another kind than .csv, .svg, .html; W942 an operating point on a switch or kink of a law (the
linearisation takes one side's slope there); W943 a verified frequency where the nonlinear model
differs from the linear prediction by more than 0.5 dB or 5 degrees; W944 a verification run that
did not complete.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Mapping, Sequence

import numpy as np

from bondc.errors import AnalysisError, Diagnostic, UsageError
from bondc import codes

if TYPE_CHECKING:
    from bondc.analysis.linearize import Linearization

#: Models with up to this many states are solved densely (balanced); larger ones as sparse.
DENSE_STATES = 64
DEFAULT_POINTS = 400
MAX_POINTS = 100_000
#: The range when the model has no mode to choose it from (no state, or only pure integrators).
FALLBACK_RANGE_HZ = (0.01, 100.0)
#: A verified frequency whose error is larger than these gets W943.
VERIFY_DB, VERIFY_DEG = 0.5, 5.0
VERIFY_FREQUENCIES = 5


def _usage(code: str, message: str, hint: str | None = None) -> UsageError:
    return UsageError(Diagnostic("error", code, message, hint=hint))


def _number(value) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


# ------------------------------------------------------------------ results

@dataclass(frozen=True)
class Margins:
    """Gain and phase margins of a response taken as an open loop; None where there is no crossing."""

    gain_margin_db: float | None = None
    phase_crossover_hz: float | None = None     # where the phase is -180 deg (the gain margin's)
    phase_margin_deg: float | None = None
    gain_crossover_hz: float | None = None      # where |G| = 1 (the phase margin's)

    def to_json(self) -> dict:
        return {name: None if value is None else _number(value) for name, value in dataclasses.asdict(self).items()}

    def to_text(self) -> str:
        gain = (f"gain margin {self.gain_margin_db:.4g} dB at {self.phase_crossover_hz:.4g} Hz"
                if self.gain_margin_db is not None else "gain margin: no phase crossover (-180 deg) in the range")
        phase = (f"phase margin {self.phase_margin_deg:.4g} deg at {self.gain_crossover_hz:.4g} Hz"
                 if self.phase_margin_deg is not None else "phase margin: no gain crossover (0 dB) in the range")
        return f"{gain}; {phase}"


@dataclass(frozen=True)
class Check:
    """The nonlinear model against the linear prediction at one frequency (:func:`verify`)."""

    frequency_hz: float
    predicted_db: float
    predicted_deg: float
    simulated_db: float | None
    simulated_deg: float | None
    error_db: float | None
    error_deg: float | None
    message: str | None = None      # why there is no simulated value

    def to_json(self) -> dict:
        return {name: (None if value is None else _number(value)) if not isinstance(value, str) else value
                for name, value in dataclasses.asdict(self).items()}


@dataclass(frozen=True)
class Response:
    """G(jw) of one (input, output) pair, SI."""

    input: str
    output: str
    input_unit: str | None
    output_unit: str | None
    frequency_hz: np.ndarray
    response: np.ndarray            # complex, one per frequency
    margins: Margins
    checks: tuple[Check, ...] = ()
    amplitude: float | None = None  # of the verification's sine, SI

    @property
    def unit(self) -> str:
        """The unit of Y/U in SI: ``m/N``, ``(m/s)/N``, ``1``."""
        top, bottom = self.output_unit or "1", self.input_unit or "1"
        if bottom == "1":
            return top
        top = top if "/" not in top else f"({top})"
        return f"{top}/{bottom}" if all(c not in bottom for c in "*/^") else f"{top}/({bottom})"

    @property
    def magnitude_db(self) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 20.0 * np.log10(np.abs(self.response))

    @property
    def phase_deg(self) -> np.ndarray:
        return phase_deg(self.response)

    def to_json(self) -> dict:
        data = {"input": self.input, "output": self.output, "input_unit": self.input_unit,
                "output_unit": self.output_unit,
                "frequency_hz": [_number(v) for v in self.frequency_hz],
                "magnitude_db": [_number(v) for v in self.magnitude_db],
                "phase_deg": [_number(v) for v in self.phase_deg],
                "margins": self.margins.to_json()}
        if self.checks:
            data["verify"] = {"amplitude": self.amplitude, "frequencies": [c.to_json() for c in self.checks]}
        return data


@dataclass(frozen=True)
class Bode:
    """What ``bondc bode`` computes: the linearisation it used and one response per pair."""

    linearization: Linearization
    responses: tuple[Response, ...]
    warnings: tuple[Diagnostic, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_json(self) -> dict | list:
        """One pair: its object; several: a list of them (``bondc bode --json``)."""
        rows = []
        for response in self.responses:
            row = response.to_json()
            row.update({"at": self.linearization.at, "time": self.linearization.time,
                        "diagnostics": [d.to_json() for d in self.warnings], "notes": list(self.notes)})
            rows.append(row)
        return rows[0] if len(rows) == 1 else rows

    def to_text(self) -> str:
        lin = self.linearization
        lines = [f"frequency response, linearised at the {lin.at} point, t = {lin.time:g} s"]
        for r in self.responses:
            f, mag, ph = r.frequency_hz, r.magnitude_db, r.phase_deg
            lines += ["", f"{r.output} / {r.input}  [{r.unit}, SI]: {f.size} frequencies, {f[0]:.4g} .. {f[-1]:.4g} Hz",
                      f"  at {f[0]:.4g} Hz: {mag[0]:.4g} dB, {ph[0]:.4g} deg; "
                      f"at {f[-1]:.4g} Hz: {mag[-1]:.4g} dB, {ph[-1]:.4g} deg",
                      f"  peak {np.nanmax(mag):.4g} dB at {f[int(np.nanargmax(mag))]:.4g} Hz",
                      "  " + r.margins.to_text()]
            if r.checks:
                lines.append(f"  verified against the nonlinear model (sine of amplitude {r.amplitude:.4g} "
                             f"{r.input_unit or 'SI'} on {r.input}):")
                lines.append(f"    {'f [Hz]':>10} {'linear dB':>10} {'model dB':>10} {'error dB':>9} "
                             f"{'linear deg':>11} {'model deg':>10} {'error deg':>9}")
                for c in r.checks:
                    if c.simulated_db is None:
                        lines.append(f"    {c.frequency_hz:>10.4g} {c.predicted_db:>10.4g}  not simulated: {c.message}")
                        continue
                    lines.append(f"    {c.frequency_hz:>10.4g} {c.predicted_db:>10.4g} {c.simulated_db:>10.4g} "
                                 f"{c.error_db:>9.3g} {c.predicted_deg:>11.4g} {c.simulated_deg:>10.4g} "
                                 f"{c.error_deg:>9.3g}")
        lines += [f"note: {note}" for note in self.notes]
        return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ numerics

def phase_deg(response: np.ndarray) -> np.ndarray:
    """The phase of ``response`` in degrees, continuous along it (``numpy.unwrap``), starting in
    (-270, 90]: a lag of 180 degrees at the lowest frequency (two integrators, a negative gain) is
    -180, not +180.

    >>> phase_deg(np.array([-1.0 + 0j, -1j])).tolist()
    [-180.0, -90.0]
    """
    response = np.asarray(response, dtype=complex)
    finite = np.isfinite(response)
    out = np.full(response.shape, np.nan)
    if finite.any():
        unwrapped = np.degrees(np.unwrap(np.angle(response[finite])))
        if unwrapped[0] > 90.0 + 1e-9:
            unwrapped -= 360.0
        out[finite] = unwrapped
    return out


def frequency_response(A, B, C, D, frequency_hz) -> np.ndarray:
    """``C (jw I - A)^-1 B + D`` for every frequency (Hz): an array (outputs, inputs, frequencies).

    A frequency at which ``jw I - A`` is singular (an undamped mode exactly there) gives nan."""
    A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (A, B, C, D))
    omega = 2.0 * np.pi * np.asarray(frequency_hz, dtype=float)
    n = A.shape[0] if A.size else 0
    p, m = C.shape[0], B.shape[1] if B.size else D.shape[1]
    out = np.empty((p, m, omega.size), dtype=complex)
    out[:] = np.asarray(D, dtype=float).reshape(p, m)[:, :, None]
    if n == 0 or p == 0 or m == 0:
        return out
    if n <= DENSE_STATES:
        import scipy.linalg

        balanced, T = scipy.linalg.matrix_balance(A)
        Bb, Cb = np.linalg.solve(T, B), C @ T
        identity = np.eye(n)
        for k, w in enumerate(omega):
            try:
                X = scipy.linalg.solve(1j * w * identity - balanced, Bb.astype(complex))
            except (np.linalg.LinAlgError, ValueError):
                out[:, :, k] = np.nan
                continue
            out[:, :, k] += Cb @ X
        return out
    import scipy.sparse
    import scipy.sparse.linalg

    As = scipy.sparse.csc_matrix(A)
    identity = scipy.sparse.identity(n, format="csc", dtype=complex)
    Bc = B.astype(complex)
    for k, w in enumerate(omega):
        try:
            lu = scipy.sparse.linalg.splu((1j * w * identity - As).tocsc())
        except RuntimeError:        # "Factor is exactly singular"
            out[:, :, k] = np.nan
            continue
        out[:, :, k] += C @ lu.solve(Bc)
    return out


def margins(frequency_hz, response) -> Margins:
    """Gain and phase margins of ``response`` (at ``frequency_hz``) as an open loop, by
    ``control.stability_margins`` on it as a frequency-response data model."""
    import warnings

    import control

    f = np.asarray(frequency_hz, dtype=float)
    h = np.asarray(response, dtype=complex)
    keep = np.isfinite(h) & (np.abs(h) > 0)
    if keep.sum() < 2:
        return Margins()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = control.frd(h[keep], 2.0 * np.pi * f[keep])
        gm, pm, _, wpc, wgc, _ = control.stability_margins(data)

    def finite(value):
        value = float(value)
        return value if math.isfinite(value) and not math.isnan(value) else None

    gm, pm, wpc, wgc = finite(gm), finite(pm), finite(wpc), finite(wgc)
    gain_db = 20.0 * math.log10(gm) if gm is not None and gm > 0 else None
    return Margins(gain_margin_db=gain_db if wpc is not None else None,
                   phase_crossover_hz=wpc / (2.0 * math.pi) if wpc is not None and gain_db is not None else None,
                   phase_margin_deg=pm if wgc is not None else None,
                   gain_crossover_hz=wgc / (2.0 * math.pi) if wgc is not None and pm is not None else None)


# ------------------------------------------------------------------ arguments

def parse_frequency(text, option: str) -> float:
    """A frequency given on the command line in Hz: a number (Hz), or a number with a unit of
    frequency (``"10 [rad/s]"``, ``"3 [kHz]"``, ``"600 [rpm]"``), read as ``--set`` reads its
    values (E944 for anything else)."""
    from bondc.ast import Num, Unary
    from bondc.errors import BondcError
    from bondc.parse import parse_set_value
    from bondc.units import resolve

    if isinstance(text, (int, float)) and not isinstance(text, bool):
        value = float(text)
    else:
        hint = f'e.g. {option} 0.1, {option} "10 [rad/s]" or {option} "2 [kHz]"'
        try:
            parsed = parse_set_value(f"f = {text}", option)
        except BondcError:
            raise _usage(codes.E944, f"{option} '{text}' is not a frequency", hint=hint) from None
        node, sign = parsed.value, 1.0
        while isinstance(node, Unary) and node.op in "+-":
            sign = -sign if node.op == "-" else sign
            node = node.operand
        if not isinstance(node, Num):
            raise _usage(codes.E944, f"{option} '{text}' is not a number with a unit", hint=hint)
        value = sign * float(node.value)
        if parsed.unit is not None:
            unit, _ = resolve(parsed.unit)
            s, rad = unit.dims[2] if unit else None, unit.dims[7] if unit else None
            others = [d for i, d in enumerate(unit.dims) if i not in (2, 7)] if unit else [1]
            if unit is None or s != -1 or rad not in (0, 1) or any(others):
                raise _usage(codes.E944, f"{option} '{text}': [{parsed.unit.text}] is not a unit of frequency",
                             hint="give Hz (the default), kHz, rad/s, rpm or 1/s")
            value = value * float(unit.factor) / (2.0 * math.pi if rad == 1 else 1.0)
    if not math.isfinite(value) or value <= 0:
        raise _usage(codes.E944, f"{option} must be a positive frequency, not {value:g} Hz",
                     hint="frequencies are in Hz and the plot is logarithmic: give a value above 0")
    return value


def parse_points(value) -> int:
    """``--points``: a whole number from 2 to :data:`MAX_POINTS` (E945)."""
    text = str(value).strip()
    try:
        number = int(text)
    except ValueError:
        raise _usage(codes.E945, f"--points '{text}' is not a whole number",
                     hint=f"e.g. --points {DEFAULT_POINTS}") from None
    if not 2 <= number <= MAX_POINTS:
        raise _usage(codes.E945, f"--points must be from 2 to {MAX_POINTS}, not {number}",
                     hint=f"the default is {DEFAULT_POINTS}, spaced logarithmically")
    return number


def default_range(eigenvalues) -> tuple[float, float] | None:
    """A decade below the slowest non-zero mode to a decade above the fastest, Hz; None without one."""
    magnitude = np.abs(np.asarray(eigenvalues, dtype=complex))
    magnitude = magnitude[magnitude > 0]
    if not magnitude.size:
        return None
    return float(magnitude.min()) / (2.0 * math.pi) / 10.0, float(magnitude.max()) / (2.0 * math.pi) * 10.0


def frequency_grid(eigenvalues, low=None, high=None, points: int = DEFAULT_POINTS) -> tuple[np.ndarray, list[str]]:
    """The frequencies (Hz, log-spaced) and notes on how the range was chosen. ``low``/``high``:
    given ends (Hz) or None for the default range's; E944 for an empty range."""
    notes = []
    found = default_range(eigenvalues)
    chosen = FALLBACK_RANGE_HZ if found is None else found      # (read only where an end is not given)
    if found is None and (low is None or high is None):
        notes.append(f"the model has no mode with a non-zero frequency to choose the range from: "
                     f"{chosen[0]:g} .. {chosen[1]:g} Hz unless --from and --to say otherwise")
    if low is None and high is None:
        low, high = chosen
    elif low is None:
        low = min(chosen[0], high / 100.0)
    elif high is None:
        high = max(chosen[1], low * 100.0)
    if not low < high:
        raise _usage(codes.E944, f"the frequency range is empty: --from {low:g} Hz is not below --to {high:g} Hz",
                     hint="give --from below --to (both in Hz unless a unit is given)")
    return np.geomspace(low, high, points), notes


def _kind_of(ss, name: str) -> str | None:
    """What ``name`` is in the model, when it is no input or output: "a parameter", "a state", ..."""
    graph = getattr(ss, "graph", None)
    if name in ss.parameters:
        return "a parameter"
    if name in ss.inputs:
        return "an input"
    if name in ss.outputs:
        return "an output"
    if name in ss.state_names:
        return "a state"
    if graph is not None and name in getattr(graph, "elements", {}):
        return "an element"
    return None


def chosen_names(ss, names: Sequence[str] | None, what: str) -> list[str]:
    """The inputs (``what="input"``) or outputs asked for, checked: E942 for an unknown name (with
    the closest one), E943 for a name of another kind. None or empty: the model's only one."""
    option = f"--{what}"
    known = list(ss.inputs if what == "input" else ss.outputs)
    if not known:
        raise _usage(codes.E942, f"the model has no {what}s",
                     hint=(f"declare the signal to excite as 'input U [UNIT] = ...' (a source's law "
                           f"'e = U')" if what == "input" else
                           "declare what to measure as 'output Y [UNIT] = ...'"))
    if not names:
        if len(known) == 1:
            return known
        raise _usage(codes.E942, f"the model has {len(known)} {what}s: say which with {option}",
                     hint=f"its {what}s: {', '.join(known)}")
    chosen = []
    for name in names:
        if name in known:
            if name not in chosen:
                chosen.append(name)
            continue
        kind = _kind_of(ss, name)
        if kind is not None:
            raise _usage(codes.E943, f"{option} '{name}' is {kind}, not an {what}",
                         hint=(f"the model's {what}s: {', '.join(known)}"
                               + ("; to excite a parameter, make it an input ('input U [UNIT] = value') and use it "
                                  "in the law" if what == "input" and kind == "a parameter" else "")
                               + ("; to see a state, declare 'output Y = STATE'" if what == "output" and kind == "a state"
                                  else "")))
        close = difflib.get_close_matches(name, known, n=1)
        raise _usage(codes.E942, f"the model has no {what} '{name}'",
                     hint=(f"did you mean '{close[0]}'? " if close else "") + f"its {what}s: {', '.join(known)}")
    return chosen


# ------------------------------------------------------------------ switches at the operating point

def point_values(ss, lin) -> dict:
    """Every symbol's value at the operating point of ``lin`` (states, inputs held, assigned
    symbols, parameters, ``t``): what the switching functions are evaluated with."""
    numeric = ss.numeric()
    x = numeric.initial_state()
    index = {name: i for i, name in enumerate(ss.state_names)}
    for name, value in zip(lin.states, lin.x0):
        x[index[name]] = value
    inputs = dict(zip(lin.inputs, (float(v) for v in lin.u0)))
    values = numeric.values(lin.time, x, inputs)
    out = {symbol: value for symbol, value in ((ss.symbols.get(n), v) for n, v in values.items()) if symbol is not None}
    for block in ss.algebraic_blocks:
        for unknown in block.unknowns:
            if unknown.name in values:
                out[unknown] = values[unknown.name]
    out.update({symbol: float(v) for symbol, v in zip(ss.state_symbols, x)})
    out.update({symbol: float(value) for symbol, value in numeric.parameter_values.items()})
    out[ss.time] = float(lin.time)
    return out


def switches_at_point(ss, lin) -> list[Diagnostic]:
    """W942 for each switching function of the model's laws (``ss.discontinuities``: an ``if``'s
    comparison, the argument of ``sign``/``abs``/``coulomb``, a table's breakpoint, ...) that is
    zero at the operating point while depending on a state or an input: there the law has a kink or
    a jump (a dry friction stuck at zero speed, a valve at its opening pressure), and the linear
    model takes the slope of one side."""
    import sympy

    from bondc.symbolic import as_sympy

    values = None
    found = []
    fixed = set(numeric_parameters(ss)) | {ss.time}
    for g in ss.discontinuities:
        g = as_sympy(g)
        moving = [s for s in g.free_symbols if s not in fixed]
        if not moving:
            continue        # a switch of time alone (a step of an input): not a slope of the model
        if values is None:
            values = point_values(ss, lin)
        if any(s not in values for s in moving):
            continue        # a mode symbol or a block unknown not evaluated: undecided
        try:
            value = float(g.xreplace({s: sympy.Float(v) for s, v in values.items() if s in g.free_symbols}))
            terms = g.args if isinstance(g, sympy.Add) else (g,)
            scale = sum(abs(float(t.xreplace({s: sympy.Float(v) for s, v in values.items()
                                              if s in t.free_symbols}))) for t in terms)
        except (TypeError, ValueError):
            continue
        if abs(value) <= 1e-9 * scale + 1e-12:
            from bondc.errors import NO_SPAN
            from bondc.model import readable, readable_names
            from bondc.model import law_span

            graph = getattr(ss, "graph", None)
            spans = [law_span(graph, s.name) for s in sorted(moving, key=lambda s: s.name)] if graph else []
            span = next((span for span in spans if span is not None), NO_SPAN)
            text = readable(readable_names(graph), str(g)) if graph is not None else str(g)
            found.append(Diagnostic(
                "warning", codes.W942,
                f"the operating point sits on a switch of the model: {text} = 0 there, where the law has a kink or a "
                f"jump (a stuck friction, a valve at its opening, a backlash at its edge); the linear model "
                f"takes the slope of one side, and the response holds only for motion to that side",
                span=span, hint="linearise where the law is smooth (another --time, another initial state, or "
                                "--at equilibrium), and check with --verify"))
    return found


def numeric_parameters(ss) -> list:
    return [symbol for symbol, _ in ss.parameters.values()]


# ------------------------------------------------------------------ verification

def _fit(t, y, omega):
    """Amplitude and phase of the oscillation at ``omega`` in ``y(t)``: least squares on 1, t
    (a drift), sin and cos; the complex amplitude ``s + j c`` of ``s sin + c cos``."""
    middle = 0.5 * (t[0] + t[-1])
    basis = np.column_stack([np.ones_like(t), t - middle, np.sin(omega * t), np.cos(omega * t)])
    coefficients, *_ = np.linalg.lstsq(basis, y, rcond=None)
    return complex(coefficients[2], coefficients[3])


def _at_rest(ss, lin) -> bool:
    numeric = ss.numeric()
    x = numeric.initial_state()
    index = {name: i for i, name in enumerate(ss.state_names)}
    for name, value in zip(lin.states, lin.x0):
        x[index[name]] = value
    rates = numeric.derivatives(lin.time, x, dict(zip(lin.inputs, (float(v) for v in lin.u0))))
    keep = [index[name] for name in lin.states]
    scale = np.abs(lin.A) @ np.abs(lin.x0) + np.abs(lin.B) @ np.abs(lin.u0)
    return bool(np.all(np.abs(rates[keep]) <= 1e-6 * scale + 1e-10))


def verification_model(ss, lin):
    """The model of ``ss`` with every input external (its default its value at the operating
    point) and every state starting at the operating point: what :func:`verify` simulates."""
    import sympy

    from bondc import ast
    from bondc.causality import assign_causality
    from bondc.equations import derive

    graph = ss.graph
    held = dict(zip(lin.inputs, (float(v) for v in lin.u0)))
    inputs = {}
    for name, signal in graph.inputs.items():
        value = held.get(name, 0.0)
        inputs[name] = dataclasses.replace(signal, expr=ast.Num(value, repr(value)), external=True, default=value)
    derived = derive(assign_causality(dataclasses.replace(graph, inputs=inputs)))
    start = dict(zip(lin.states, (float(v) for v in lin.x0)))
    states = tuple(dataclasses.replace(s, initial=sympy.Float(start[s.name], 17)) if s.name in start else s
                   for s in derived.states)
    return dataclasses.replace(derived, states=states)


def verify(ss, lin, pairs: Sequence[tuple[str, str]], frequencies_hz, amplitudes: Mapping[str, float],
           progress=None) -> tuple[dict, list[Diagnostic]]:
    """Simulate the nonlinear model with ``u0 + a sin(2 pi f t)`` on each input of ``pairs`` at each
    frequency and measure every output of its pairs: ``{(input, output): [Check, ...]}`` and
    warnings (W943 large errors, W944 runs that did not complete).

    The run starts at the operating point with the other inputs held; it lasts until the slowest
    mode has decayed to e^-12 of its start (12 / its decay rate) plus the fitted window, the last
    whole periods (at least 5, and a fifth of the run). E946 where the operating point is not at
    rest, or a mode grows (there is no steady oscillation to measure)."""
    from bondc.simulate import simulate

    if not _at_rest(ss, lin):
        raise AnalysisError(Diagnostic(
            "error", codes.E946, f"--verify needs an operating point at rest, and the model is moving at the {lin.at} point "
                             f"(t = {lin.time:g} s): the linear model describes small motions around a trajectory there, "
                             "which a sine on the input cannot be compared with",
            hint="verify at an equilibrium: --at equilibrium"))
    real = np.real(lin.eigenvalues)
    scale = max(float(np.max(np.abs(lin.eigenvalues))) if lin.eigenvalues.size else 1.0, 1e-300)
    if np.any(real > 1e-9 * scale):
        raise AnalysisError(Diagnostic(
            "error", codes.E946, "--verify cannot measure a steady response: the linear model has a growing mode "
                             f"(eigenvalue {lin.eigenvalues[int(np.argmax(real))]:.4g}), so the simulated model drifts "
                             "away from the operating point",
            hint="verify a stable operating point (an equilibrium that is stable), or close the loop in the model"))
    decaying = -real[real < -1e-9 * scale]
    settle = 12.0 / float(decaying.min()) if decaying.size else 0.0
    model = verification_model(ss, lin)
    held = dict(zip(lin.inputs, (float(v) for v in lin.u0)))
    checks: dict = {pair: [] for pair in pairs}
    warnings: list[Diagnostic] = []
    response = frequency_response(lin.A, lin.B, lin.C, lin.D, frequencies_hz)
    for input_name in dict.fromkeys(u for u, _ in pairs):
        j = lin.inputs.index(input_name)
        a = amplitudes[input_name]
        outputs = [y for u, y in pairs if u == input_name]
        for k, f in enumerate(frequencies_hz):
            omega = 2.0 * math.pi * float(f)
            period = 1.0 / float(f)
            whole = max(5, math.ceil(0.2 * settle / period))
            t_end = settle + whole * period
            t_eval = np.linspace(t_end - whole * period, t_end, 64 * whole + 1)
            u0 = held[input_name]

            def signal(t, u0=u0, a=a, omega=omega):
                return u0 + a * np.sin(omega * np.asarray(t, dtype=float))

            supplied = {name: (lambda t, v=value: v + 0.0 * np.asarray(t, dtype=float)) for name, value in held.items()}
            supplied[input_name] = signal
            # absolute tolerance: far below the states' predicted oscillation
            states = np.linalg.solve(1j * omega * np.eye(lin.A.shape[0]) - lin.A, lin.B[:, j]) * a \
                if lin.A.size else np.zeros(0)
            moving = np.abs(states)[np.abs(states) > 0]
            atol = max(1e-6 * float(moving.min()), 1e-300) if moving.size else 1e-12
            if progress is not None:
                progress(f"--verify: simulating {t_end:.4g} s with a sine of {f:.4g} Hz on {input_name}")
            result = simulate(model, None, t_end=t_end, t_eval=t_eval, rtol=1e-9, atol=atol,
                              max_step=period / 40.0, inputs=supplied)
            for output in outputs:
                i = lin.outputs.index(output)
                predicted = response[i, j, k]
                pred_db, pred_deg = 20.0 * math.log10(abs(predicted)), math.degrees(np.angle(predicted))
                if not result.complete:
                    message = result.message or "the run stopped early"
                    warnings.append(Diagnostic("warning", codes.W944, f"--verify: the run at {f:.4g} Hz did not complete "
                                                                  f"({message})",
                                               hint="a smaller --amplitude, or a model that runs at this input"))
                    checks[(input_name, output)].append(Check(float(f), pred_db, pred_deg, None, None, None, None,
                                                              message))
                    continue
                t = np.asarray(result.t, dtype=float)
                y = np.asarray(result.outputs[output], dtype=float)
                measured = _fit(t, y, omega) / a
                error_db = 20.0 * math.log10(abs(measured) / abs(predicted))
                error_deg = math.degrees(np.angle(measured / predicted))
                sim_deg = pred_deg + error_deg
                checks[(input_name, output)].append(Check(float(f), pred_db, pred_deg, 20.0 * math.log10(abs(measured)),
                                                          sim_deg, error_db, error_deg))
                if abs(error_db) > VERIFY_DB or abs(error_deg) > VERIFY_DEG:
                    warnings.append(Diagnostic(
                        "warning", codes.W943,
                        f"--verify: at {f:.4g} Hz the model's {output}/{input_name} differs from the linear prediction by "
                        f"{error_db:+.3g} dB and {error_deg:+.3g} deg",
                        hint="the model is not linear over the sine's amplitude there (a smaller --amplitude), or the "
                             "operating point sits on a switch of a law"))
    return checks, warnings


def verify_frequencies(frequency_hz, count: int = VERIFY_FREQUENCIES) -> np.ndarray:
    """``count`` frequencies spaced logarithmically inside the range (its ends left out)."""
    return np.geomspace(float(frequency_hz[0]), float(frequency_hz[-1]), count + 2)[1:-1]


def default_amplitude(u0: float) -> float:
    """The verification's sine: 1 % of the input's value at the operating point, else 1 (SI)."""
    return 0.01 * abs(u0) if u0 != 0 else 1.0


def parse_amplitude(text, unit_text: str | None, name: str) -> float:
    """``--amplitude``: a positive number in the input's declared unit, or with a unit of its
    dimension (E946); SI."""
    from bondc.ast import Num
    from bondc.errors import BondcError
    from bondc.units import unit_of
    from bondc.parse import parse_set_value
    from bondc.units import resolve

    hint = "e.g. --amplitude 0.1 (in the input's declared unit) or --amplitude \"0.1 [V]\""
    try:
        parsed = parse_set_value(f"a = {text}", "--amplitude")
    except BondcError:
        raise _usage(codes.E946, f"--amplitude '{text}' is not a number", hint=hint) from None
    if not isinstance(parsed.value, Num):
        raise _usage(codes.E946, f"--amplitude '{text}' is not a positive number", hint=hint)
    value = float(parsed.value.value)
    declared = unit_of(unit_text) if unit_text else None
    if parsed.unit is not None:
        unit, _ = resolve(parsed.unit)
        if unit is None or (declared is not None and tuple(unit.dims) != tuple(declared.dims)):
            raise _usage(codes.E946, f"--amplitude '{text}': [{parsed.unit.text}] is not a unit of input '{name}'"
                                 + (f" [{unit_text}]" if unit_text else ""), hint=hint)
        value *= float(unit.factor)
    elif declared is not None:
        value *= float(declared.factor)
    if not math.isfinite(value) or value <= 0:
        raise _usage(codes.E946, f"--amplitude must be positive, not {value:g}", hint=hint)
    return value


# ------------------------------------------------------------------ the analysis

def bode(ss, *, inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None, at: str = "initial",
         time: float = 0.0, low=None, high=None, points: int = DEFAULT_POINTS, verify_model: bool = False,
         amplitude=None, progress=None, pairs: Sequence[tuple[str, str]] | None = None) -> Bode:
    """The frequency response of ``ss`` from each of ``inputs`` to each of ``outputs`` (names; None:
    the model's only one), linearised at ``at`` (see :func:`bondc.analysis.linearize.linearize`).
    ``low``/``high``: the range's ends in Hz (numbers) or texts with a unit (``"10 [rad/s]"``);
    ``verify_model``: also :func:`verify`, with a sine of ``amplitude`` (a number in the input's
    declared unit or a text with a unit; default :func:`default_amplitude`). ``pairs``: instead of every
    input with every output, these (input, output) pairs only (an experiment's ``bode`` setting)."""
    from bondc.analysis.linearize import linearize

    if pairs:
        inputs = list(dict.fromkeys(u for u, _ in pairs))
        outputs = list(dict.fromkeys(y for _, y in pairs))
    input_names = chosen_names(ss, inputs, "input")
    output_names = chosen_names(ss, outputs, "output")
    low = None if low is None else parse_frequency(low, "--from")
    high = None if high is None else parse_frequency(high, "--to")
    points = parse_points(points)
    lin = linearize(ss, time=time, at=at)
    frequencies, notes = frequency_grid(lin.eigenvalues, low, high, points)
    notes = list(lin.notes) + notes
    warnings = switches_at_point(ss, lin)
    columns = [lin.inputs.index(name) for name in input_names]
    rows = [lin.outputs.index(name) for name in output_names]
    full = frequency_response(lin.A, lin.B[:, columns], lin.C[rows], lin.D[np.ix_(rows, columns)], frequencies)
    graph = getattr(ss, "graph", None)
    signals = getattr(graph, "inputs", None) or {}
    declared = getattr(graph, "outputs", None) or {}
    pairs = list(dict.fromkeys(pairs)) if pairs else [(u, y) for u in input_names for y in output_names]
    checks: dict = {}
    amplitudes: dict = {}
    if verify_model:
        for u in input_names:
            unit_text = getattr(signals.get(u), "unit_text", None)
            amplitudes[u] = parse_amplitude(amplitude, unit_text, u) if amplitude is not None else \
                default_amplitude(float(lin.u0[lin.inputs.index(u)]))
        checks, found = verify(ss, lin, pairs, verify_frequencies(frequencies), amplitudes, progress=progress)
        warnings += found
    responses = []
    for u, y in pairs:
        h = full[output_names.index(y), input_names.index(u)]
        responses.append(Response(
            input=u, output=y, input_unit=_si_unit(getattr(signals.get(u), "unit_text", None)),
            output_unit=_si_unit(getattr(declared.get(y), "unit_text", None)),
            frequency_hz=frequencies, response=h, margins=margins(frequencies, h),
            checks=tuple(checks.get((u, y), ())), amplitude=amplitudes.get(u)))
    return Bode(lin, tuple(responses), tuple(warnings), tuple(notes))


def _si_unit(text: str | None) -> str | None:
    """The SI unit the response is in for a signal declared in ``text`` (``kPa`` -> ``Pa``)."""
    if not text:
        return None
    from bondc.units import unit_of

    unit = unit_of(text)
    if unit is None or abs(float(unit.factor) - 1.0) < 1e-12:
        return text
    return unit.dimension_text()
