"""Compiled model code (C through cffi): the same numbers as the numpy module, and a clean
fallback to numpy where there is no C compiler.

The independent expectation is the numpy module itself (tested against analytic
solutions elsewhere): every law printed to C must give the value the numpy printer
gives, at negative, zero and positive arguments, and whole simulations must agree
to the solver tolerance.
"""

from __future__ import annotations

import functools
import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import sympy

from bondc import runtime
from bondc.codegen.cprinter import PRELUDE, NativePrinter, c_name
from bondc.codegen.printer import BondcPrinter, UnsupportedExpression
from bondc.pipeline import derive_file
from bondc.simulate import compile_model
from bondc.symbolic import Step, Table

ROOT = Path(__file__).resolve().parent.parent
HAVE_CC = bool(shutil.which("cc") or shutil.which("gcc") or shutil.which("clang"))
needs_cc = pytest.mark.skipif(not HAVE_CC, reason="no C compiler on this machine")

x, y = sympy.symbols("x y", real=True)
LAWS = {
    "orifice": sympy.sign(x) * sympy.sqrt(sympy.Abs(x)),
    "power": sympy.Abs(x) ** sympy.Rational(7, 5) * sympy.sign(x),
    "saturation": sympy.Min(sympy.Max(x, -1), 1) + sympy.Max(y, x, 0),
    "rational": (x ** 3 - 2 * x) / (1 + x ** 2) + sympy.Rational(1, 3) * y,
    "transcendental": sympy.exp(-x) * sympy.sin(3 * x) + sympy.atan2(y, x) + sympy.tanh(x) - sympy.log(1 + x ** 2),
    "piecewise": sympy.Piecewise((x ** 2, x > 0), (-y, x < -1), (0.5 * x, True)),
    "heaviside": sympy.Heaviside(x, 0.25) * y,
    "table": Table(x, sympy.Tuple(-1.0, 0.0, 2.0), sympy.Tuple(3.0, -1.0, 5.0)),
    "step": Step(x, 0) * y + sympy.floor(x) - sympy.ceiling(y),
    "pole": 1 / x,
}
POINTS = [(-2.5, 0.7), (-1.0, -1.0), (-1e-9, 2.0), (0.0, 0.0), (0.0, -3.0), (1e-9, 1.0), (0.3, -0.2), (4.0, 2.0)]


def _native_functions(laws):
    names = {x: "v_x", y: "v_y"}
    printer = NativePrinter(names)
    lines = [PRELUDE, "void bondc_rhs(double t, const double *x, const double *p, const double *m, double *out)",
             "{", "    const double v_x = x[0];", "    const double v_y = x[1];"]
    lines += [f"    out[{k}] = {printer.doprint(law)};" for k, law in enumerate(laws)]
    lines += ["}", "void bondc_jac(double t, const double *x, const double *p, const double *m, double *out) {}",
              "void bondc_switches(double t, const double *x, const double *p, const double *m, double *out) {}"]
    ffi, lib = runtime.load_native("\n".join(lines) + "\n")
    assert ffi is not None, lib

    def evaluate(a, b):
        out = np.empty(len(laws))
        xs = np.array([a, b])
        lib.bondc_rhs(0.0, ffi.from_buffer("double[]", xs), ffi.NULL, ffi.NULL, ffi.from_buffer("double[]", out))
        return out

    return evaluate


def _numpy_value(law, a, b):
    from bondc import runtime as namespace

    text = BondcPrinter({x: "x", y: "y"}).doprint(law)
    scope = {name: getattr(namespace, name) for name in ("table", "step")}
    with np.errstate(all="ignore"):
        return float(eval(text, {"np": np, "math": math, **scope}, {"x": np.float64(a), "y": np.float64(b)}))  # noqa: S307  (test: printer output)


@needs_cc
@pytest.mark.parametrize("name", sorted(LAWS))
def test_every_law_prints_to_c_with_the_numpy_value_at_negative_zero_and_positive_arguments(name):
    evaluate = _native_functions([LAWS[name]])
    for a, b in POINTS:
        expected = _numpy_value(LAWS[name], a, b)
        got = evaluate(a, b)[0]
        if math.isnan(expected):
            assert math.isnan(got), (a, b)
        else:
            assert got == pytest.approx(expected, rel=1e-14, abs=1e-300), (a, b)


def test_c_names_are_identifiers_that_cannot_collide():
    assert c_name("mass_p", 3) == "v_mass_p"
    assert c_name("double", 4) == "v_double"          # a C keyword gets the prefix too
    assert c_name("Δp", 5) == "w5"                    # not ASCII: by position
    assert c_name('x"; system("rm', 6) == "w6"        # never text that is not an identifier


def test_a_measured_signal_has_no_native_form():
    from bondc.symbolic import Csv, _SymStr

    with pytest.raises(UnsupportedExpression):
        NativePrinter({x: "v_x"}).doprint(Csv(x, _SymStr("/data/force.csv"), _SymStr("F")))


# ------------------------------------------------------------------ whole models

MODELS = sorted([*ROOT.glob("models/*.bg"),
                 *(p for folder in ("engine", "sim", "textbook", "components", "language")
                   for p in (ROOT / "tests" / "fixtures" / folder).glob("*.bg"))])
QUICK = {"mass_spring_damper.bg", "orifice_reversing.bg", "two_stuck_masses.bg"}     # the rest: slow


def _runs(path):
    derived = derive_file(path, cache=False)
    namespace = compile_model(derived.state_space)
    experiment = derived.experiment
    # the same integrator on both paths: CVODE, unless the experiment names one (auto's DOPRI5 is
    # scipy's RK45 with the numpy code, the same pair to rounding: test_explicit compares those; near
    # a singularity, where these runs stop, rounding alone moves two runs' last steps apart)
    settings = {"method": "CVODE"}
    if experiment is not None:
        settings = {"t_end": experiment.t_end, "method": experiment.solver or "CVODE", "rtol": experiment.rtol,
                    "atol": experiment.atol, "max_step": experiment.max_step}
    if settings.get("t_end") is None:
        settings["t_end"] = 1.0
    runs = {}
    with np.errstate(all="ignore"):
        runs[None] = namespace["simulate_model"](namespace["_MODEL"], **settings)
        # the numpy code reports at the compiled run's points (from its dense output): runs that take
        # different steps are compared at the same instants, not through a linear interpolation
        runs[False] = namespace["simulate_model"](namespace["_MODEL"], native=False, t_eval=runs[None].t,
                                                  **settings)
    return namespace, runs, settings


def _model_cases():
    return [pytest.param(path, id=path.name,
                         marks=() if path.name in QUICK else (pytest.mark.slow,)) for path in MODELS]


@needs_cc
@pytest.mark.parametrize("path", _model_cases())
def test_compiled_and_numpy_code_give_the_same_run(path):
    namespace, runs, settings = _runs(path)
    numpy_run, native_run = runs[False], runs[None]
    assert numpy_run.stats["code"] == "numpy"
    if namespace["NATIVE_UNAVAILABLE"]:
        # only models whose laws C cannot print (an algebraic loop solved numerically, a csv signal)
        assert native_run.stats["code"] == "numpy"
        assert native_run.stats["code_note"] == namespace["NATIVE_UNAVAILABLE"]
    elif not namespace["STATE_NAMES"]:      # (the language reference's examples of sources alone)
        assert native_run.stats["code"] == "numpy" and "no states" in native_run.stats["code_note"]
    else:
        assert native_run.stats["code"] == "native", native_run.stats.get("code_note")
    assert native_run.complete == numpy_run.complete
    assert native_run.t[-1] == pytest.approx(numpy_run.t[-1], rel=1e-9, abs=1e-12)
    rtol = max(float(settings.get("rtol") or 1e-6), 1e-9)
    # C's and numpy's sin may differ in the last bit: an event may then be an ulp apart, and a
    # state that jumps there (a counter) differs at that one instant; such points are left out
    events = np.array(sorted({time for time, _ in numpy_run.events + native_run.events}))
    t = numpy_run.t
    nearest = np.full(t.size, np.inf)
    if events.size:
        after = np.clip(np.searchsorted(events, t), 0, events.size - 1)
        before = np.clip(after - 1, 0, events.size - 1)
        nearest = np.minimum(np.abs(t - events[after]), np.abs(t - events[before]))
    away = nearest > 8 * np.finfo(float).eps * np.maximum(np.abs(t), 1.0)
    assert np.count_nonzero(~away) <= 2 * events.size
    # the same laws in C and in numpy differ by rounding; where a sliding decision lands the other
    # way by a rounding (the flagship's friction and regulator) the two runs' steps part, and they
    # differ by their tolerance instead (3e-5 of the coupling's twist on the flagship at rtol 1e-7)
    limit = 1000 * rtol
    for name, values in numpy_run.states.items():
        other = np.interp(numpy_run.t, native_run.t, native_run.states[name])
        scale = max(float(np.max(np.abs(values))), 1e-12)
        difference = float(np.max(np.abs(other - values)[away], initial=0.0)) / scale
        assert difference <= limit, (name, difference)


@needs_cc
def test_a_nonlinear_algebraic_loop_is_solved_in_c_and_equals_its_closed_form():
    """The coil of nonlinear_loop.bg feeds r2 (e = a3 f^3 + a1 f) in parallel with r3 (e = R3 f):
    the loop's u solves a3 f2^3 + (a1 + R3) f2 = R3 i with u = R3 (i - f2), one real root, and
    dp/dt = V - R1 i - u. The C right-hand side (Newton's method inside C, no numpy) equals that
    root from numpy.roots, and the numpy module's (MINPACK's hybr), at states of both signs and 0,
    for random parameter values; its Jacobian equals central differences."""
    namespace, _ = _compiled(ROOT / "tests" / "fixtures" / "sim" / "nonlinear_loop.bg")
    model = namespace["_Model"](namespace["_MODEL"])
    numpy_rhs = model.rhs
    assert namespace["attach_native"](model, None)[0] and model.rhs is not numpy_rhs
    names = list(model.PARAMETERS)
    rng = np.random.default_rng(5)
    for _ in range(20):
        values = {name: float(rng.uniform(0.5, 4.0)) for name in names}
        p = namespace["param_array"](model.PARAMETERS, values, model.derive_parameters)
        for momentum in (-3.0, -1e-3, 0.0, 0.4, 7.0):
            x = np.array([momentum * values["L"]])
            i = momentum
            roots = np.roots([values["a3"], 0.0, values["a1"] + values["R3"], -values["R3"] * i])
            f2 = float(roots[np.argmin(np.abs(roots.imag))].real)
            expected = values["V"] - values["R1"] * i - values["R3"] * (i - f2)
            native = model.rhs(0.0, x, p, np.zeros(0))
            assert native[0] == pytest.approx(expected, rel=1e-12, abs=1e-12)
            assert native[0] == pytest.approx(numpy_rhs(0.0, x, p, np.zeros(0))[0], rel=1e-10, abs=1e-12)
            h = 1e-6 * max(1.0, abs(x[0]))
            difference = (model.rhs(0.0, x + h, p, np.zeros(0))[0] - model.rhs(0.0, x - h, p, np.zeros(0))[0]) / (2 * h)
            assert model.jac(0.0, x, p, np.zeros(0))[0, 0] == pytest.approx(difference, rel=1e-6, abs=1e-9)


@needs_cc
@pytest.mark.parametrize("fixture", ["engine/diode_bridge.bg", "sim/nonlinear_loop.bg", "sim/exp_diode.bg"])
def test_a_loop_models_outputs_and_variables_come_from_c_and_equal_the_numpy_modules(fixture):
    """A model with a nonlinear algebraic loop is evaluated point by point: its outputs and every
    variable are computed by C (the loop solved there) and equal the numpy module's (MINPACK's
    hybr) at states of both signs and zero and times across the input's period, to 1e-9 of each
    variable's size; a variable C cannot give (nan) comes from numpy."""
    namespace, _ = _compiled(ROOT / "tests" / "fixtures" / fixture)
    model = namespace["_Model"](namespace["_MODEL"])
    numpy_outputs, numpy_variables = model.outputs, model.variables
    assert namespace["attach_native"](model, None)[0]
    assert model.outputs is not numpy_outputs and model.variables is not numpy_variables
    ffi, lib = runtime.load_native(model.NATIVE_SOURCE)
    p = namespace["param_array"](model.PARAMETERS, {}, model.derive_parameters)
    modes = np.zeros(len(model.SWITCHES))
    rng = np.random.default_rng(7)
    for t in (0.0, 0.004, 0.011, 0.017):
        for scale in (-1.0, 0.0, 0.3, 1.0):
            x = scale * rng.uniform(0.5, 2.0, len(model.STATE_NAMES)) * np.abs(model.x0(p) + 1e-3)
            if len(modes):
                modes = np.sign(np.asarray(model.switches(t, x, p, modes), dtype=float))
            for kind, numpy_function, size in (("outputs", numpy_outputs, len(model.OUTPUT_NAMES)),
                                               ("variables", numpy_variables, len(model.VARIABLE_NAMES))):
                direct = np.zeros(size)
                getattr(lib, f"bondc_{kind}")(t, ffi.from_buffer("double[]", x), ffi.from_buffer("double[]", p),
                                              ffi.from_buffer("double[]", modes) if len(modes) else ffi.NULL,
                                              ffi.from_buffer("double[]", direct))
                expected = np.asarray(numpy_function(t, x, p, modes), dtype=float)
                assert np.all(np.isfinite(direct)), (kind, t, scale)
                np.testing.assert_allclose(direct, expected, rtol=1e-9, atol=1e-12 * max(1.0, np.max(np.abs(expected))))
                np.testing.assert_array_equal(getattr(model, kind)(t, x, p, modes), direct)


@needs_cc
@pytest.mark.parametrize("fixture", ["engine/diode_bridge.bg", "sim/nonlinear_loop.bg", "sim/exp_diode.bg"])
def test_a_loop_models_functions_over_many_points_in_one_call_are_each_points_to_the_bit(fixture):
    """The right-hand side, switching functions, outputs and variables of a loop model over the
    columns of a trajectory in one C call (``at_points``: a run's outputs and variables, the energy
    account) give exactly what one call per point gives; a point whose C value is not finite gets
    the numpy module's."""
    namespace, _ = _compiled(ROOT / "tests" / "fixtures" / fixture)
    model = namespace["_Model"](namespace["_MODEL"])
    numpy_functions = {kind: getattr(model, kind) for kind in ("rhs", "switches", "outputs", "variables")}
    assert namespace["attach_native"](model, None)[0]
    p = namespace["param_array"](model.PARAMETERS, {}, model.derive_parameters)
    rng = np.random.default_rng(11)
    n = len(model.STATE_NAMES)
    t = np.linspace(0.0, 0.02, 40)
    x = rng.uniform(-2.0, 2.0, (n, t.size)) * (np.abs(model.x0(p)) + 1e-3)[:, None]
    x[:, 3] = 0.0
    x[0, 5] = np.nan                        # C's value is not finite there: numpy's (nan too)
    modes = np.ones(len(model.SWITCHES))
    for kind, numpy_function in numpy_functions.items():
        function = getattr(model, kind)
        many = function.at_points(t, x, p, modes)
        one_by_one = np.column_stack([np.asarray(function(t[j], x[:, j].copy(), p, modes), dtype=float)
                                      for j in range(t.size)])
        np.testing.assert_array_equal(many, one_by_one, err_msg=kind)
        assert many.shape == (one_by_one.shape[0], t.size)
        np.testing.assert_array_equal(many[:, 5], np.asarray(numpy_function(t[5], x[:, 5].copy(), p, modes),
                                                             dtype=float), err_msg=kind)


@needs_cc
def test_an_exponential_diode_loop_is_solved_in_c_far_from_its_guess():
    """exp_diode.bg's loop starts at 0 V across r1, the whole source across the diode: exp(V/Vt)
    is 1e173 at 10 V (plain Newton's 50 steps move it by 50 e-folds) and overflows at 20 V. The C
    right-hand side alone (called directly: no numpy fallback) gives dq/dt = (v - q/Cf)/R3 with
    the node voltage v that bisection finds, at reverse, zero and forward bias, and so does the
    numpy module (MINPACK's hybr, then the same search with a difference Jacobian)."""
    from test_runtime import shockley_node

    namespace, _ = _compiled(ROOT / "tests" / "fixtures" / "sim" / "exp_diode.bg")
    model = namespace["_Model"](namespace["_MODEL"])
    ffi, lib = runtime.load_native(model.NATIVE_SOURCE)
    for v_source in (-20.0, 0.0, 10.0, 20.0, 40.0):
        p = namespace["param_array"](model.PARAMETERS, {"V": v_source}, model.derive_parameters)
        for v_cap in (-15.0, 0.0, 0.3, 5.0, 19.0):
            x = np.array([v_cap * 1e-3])
            expected = (shockley_node(v_source, v_cap) - v_cap) / 50.0
            out = np.zeros(1)
            lib.bondc_rhs(0.0, ffi.from_buffer("double[]", x), ffi.from_buffer("double[]", p), ffi.NULL,
                          ffi.from_buffer("double[]", out))
            assert out[0] == pytest.approx(expected, rel=1e-9, abs=1e-12), (v_source, v_cap)
            assert model.rhs(0.0, x, p, np.zeros(0))[0] == pytest.approx(expected, rel=1e-9, abs=1e-12)


@needs_cc
def test_the_exponential_diode_charges_its_capacitor_as_the_circuit_does(monkeypatch, tmp_path):
    """exp_diode.bg simulated with C and with numpy equals scipy's LSODA on the circuit written by
    hand (node voltage by bisection at every call) to the model's tolerance: at 20 V the
    capacitor settles where the diode clamps the node, near 0.48 V."""
    from scipy.integrate import solve_ivp
    from test_runtime import shockley_node

    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    namespace, runs, _ = _runs(ROOT / "tests" / "fixtures" / "sim" / "exp_diode.bg")
    reference = solve_ivp(lambda t, q: [(shockley_node(20.0, q[0] / 1e-3) - q[0] / 1e-3) / 50.0],
                          (0.0, 0.5), [0.0], method="LSODA", rtol=1e-10, atol=1e-14, dense_output=True)
    assert runs[None].stats["code"] == "native" and runs[False].stats["code"] == "numpy"
    for run in runs.values():
        assert run.complete and run.t[-1] == 0.5
        q = run.states["cap.q"]
        scale = float(np.ptp(reference.y[0]))
        assert np.max(np.abs(q - reference.sol(run.t)[0])) <= 1e-4 * scale
        assert 0.4 < run.outputs["v_diode"][-1] < 0.55
        assert run.outputs["v_diode"][-1] == pytest.approx(shockley_node(20.0, q[-1] / 1e-3), rel=1e-9)


@pytest.mark.slow
@needs_cc
def test_where_cs_newton_fails_the_numpy_module_solves_the_loop(monkeypatch, tmp_path):
    """With no Newton iteration allowed (neither attempt), the C loop gives nan at every call, and every call goes to
    the numpy module (MINPACK's hybr): the run equals the numpy module's run to the bit."""
    from bondc.codegen.emit import _NativeEmitter

    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_NativeEmitter, "LOOP_ITERATIONS", 0)
    monkeypatch.setattr(_NativeEmitter, "LOOP_SEARCHES", 0)
    namespace, runs, _ = _runs(ROOT / "tests" / "fixtures" / "sim" / "nonlinear_loop.bg")
    assert "bondc_k < 0" in namespace["NATIVE_SOURCE"]
    native, numpy_run = runs[None], runs[False]
    assert native.stats["code"] == "native" and numpy_run.stats["code"] == "numpy"
    reference = namespace["simulate_model"](namespace["_MODEL"], native=False,
                                            t_end=1.0, rtol=None, atol=None, method="CVODE")
    for name, values in reference.states.items():
        assert np.array_equal(native.states[name], values), name
    for kind in ("outputs", "variables"):       # C's outputs and variables are nan too: numpy's
        for name, values in getattr(reference, kind).items():
            assert np.array_equal(getattr(native, kind)[name], values), name


@pytest.mark.slow
@needs_cc
def test_without_a_compiler_a_model_with_switches_stops_and_says_why(tmp_path, monkeypatch):
    """No compiler at all: $CC names no program, none on PATH, no ziglang package (a standalone
    module's environment may lack it). The engine's functions that locate, select and hold the
    switches are C (runtime.policy): the run of a model with switches (the mass-spring-damper's
    step input) stops at its start with a failure that says why and what to do; with a compiler
    the same module runs, in C."""
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    runtime._NATIVE_LIBRARIES.clear()
    path = ROOT / "models" / "mass_spring_damper.bg"
    derived = derive_file(path, cache=False)
    namespace = compile_model(derived.state_space)
    assert namespace["SWITCHES"]
    with monkeypatch.context() as hidden:
        hidden.setenv("CC", str(tmp_path / "no-such-compiler"))
        hidden.setenv("PATH", str(tmp_path / "no-programs"))
        hidden.setitem(namespace, "_zig", lambda: None)
        run = namespace["simulate_model"](namespace["_MODEL"], t_end=0.5, method="CVODE")    # (auto: no C++ either)
    assert not run.complete and run.t.size == 1
    failure = run.failure
    assert failure["kind"] == "solver" and "cannot be built here" in failure["message"]
    assert "no C compiler works here" in failure["message"] and "ziglang package is not installed" in failure["message"]
    assert "set CC" in failure["hint"]
    again = namespace["simulate_model"](namespace["_MODEL"], t_end=0.5, method="CVODE")
    assert again.complete and again.stats["code"] == "native"


@needs_cc
def test_an_unusable_cc_gives_way_to_the_system_compiler_and_the_choice_is_recorded(tmp_path, monkeypatch):
    """$CC naming no program: the compiler on PATH builds, and says $CC was passed over; the
    machine's record of the compiler's probe spares the next process a second probe."""
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setattr(runtime.native, "_COMPILERS", {})
    compiler, why = runtime.find_compiler("c")
    assert compiler is not None and why == ""
    assert not compiler.command[0].startswith(str(tmp_path)) and "was not found" in compiler.label
    assert len(list((tmp_path / "native").glob("compiler_*.json"))) == 1
    probes = []
    monkeypatch.setattr(runtime.native, "_COMPILERS", {})      # a new process
    monkeypatch.setattr(subprocess, "run", lambda *a, **k: probes.append(a))
    assert runtime.find_compiler("c") == (compiler, "") and not probes


def test_the_compiler_is_part_of_a_librarys_cache_key():
    """A library built by one compiler is never taken for another's: the same text gets another
    digest, and so another file, with another compiler."""
    gcc = runtime.Compiler(("gcc",), "gcc 12", "/usr/bin/gcc-12 gcc 12")
    zig = runtime.Compiler(("zig", "cc"), "zig cc 0.17.1", "/venv/ziglang/zig zig 0.17.1")
    text = PRELUDE + "void bondc_rhs(double t, const double *x, const double *p, const double *m, double *out) {}\n"
    assert runtime._native_plan(text, (), gcc)[2:] != runtime._native_plan(text, (), zig)[2:]
    assert runtime._native_plan(text, (), gcc) == runtime._native_plan(text, (), gcc)


#: the flagship simulated in a process of its own, its states saved to argv[2], its stats printed
_RUN_ELSEWHERE = """
import json, sys
import numpy as np
from bondc.pipeline import derive_file
from bondc.simulate import compile_model
namespace = compile_model(derive_file(sys.argv[1], cache=False).state_space)
run = namespace["simulate_model"](namespace["_MODEL"], t_end=float(sys.argv[4]), method=sys.argv[3])
np.savez(sys.argv[2], t=run.t, **run.states)
print(json.dumps({key: value for key, value in run.stats.items() if isinstance(value, str)}))
"""


def _run_without_a_system_compiler(tmp_path, model, method, t_end):
    """(stats, t, states) of ``model`` run in a process that sees no system compiler: PATH is an
    empty folder and $CC/$CXX are unset, so the ziglang package's zig builds (zig's own cache,
    ~/.cache/zig, is kept: a machine builds zig's C library parts once)."""
    import json
    import sys

    (tmp_path / "no-programs").mkdir(exist_ok=True)
    environment = {key: value for key, value in os.environ.items() if key not in ("CC", "CXX")}
    environment.update(PATH=str(tmp_path / "no-programs"), BONDC_CACHE_DIR=str(tmp_path))
    saved = tmp_path / f"{method}.npz"
    done = subprocess.run([sys.executable, "-c", _RUN_ELSEWHERE, str(model), str(saved), method, repr(t_end)],
                          capture_output=True, text=True, env=environment, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    with np.load(saved) as stored:
        states = {name: stored[name] for name in stored.files if name != "t"}
        return json.loads(done.stdout.strip().splitlines()[-1]), stored["t"], states


@pytest.mark.slow       # 3 s, and 7 s more once per machine: zig builds its C library parts
@pytest.mark.skipif(runtime._zig() is None, reason="the ziglang package is not installed")
@needs_cc
def test_without_a_system_compiler_zig_builds_the_flagship_and_runs_it_as_the_system_compiler_does(tmp_path,
                                                                                                    monkeypatch):
    """A machine without cc, gcc or clang: the ziglang package's compiler builds the flagship's C
    code with bondc's CVODE driver (auto takes CVODE: the flagship's frictions switch on its
    states), stats say so, and the run is the system compiler's run (the same C, the same libm)."""
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    model = ROOT / "models" / "electro_pneumatic_hybrid.bg"
    derived = derive_file(model, cache=False)
    namespace = compile_model(derived.state_space)
    system = namespace["simulate_model"](namespace["_MODEL"], t_end=derived.experiment.t_end, method="auto")
    assert system.stats["code"] == "native" and not system.stats["compiler"].startswith("zig")
    stats, t, states = _run_without_a_system_compiler(tmp_path, model, "auto", derived.experiment.t_end)
    assert stats["code"] == "native" and stats["solver"] == "CVODE", stats
    assert stats["compiler"].startswith("zig cc ") and "no C compiler on PATH" in stats["compiler"]
    assert len(list((tmp_path / "native").glob("model_*.so"))) == 2       # one per compiler
    np.testing.assert_allclose(t, system.t, rtol=1e-12, atol=0)
    for name, values in system.states.items():
        np.testing.assert_allclose(states[name], values, rtol=1e-9, atol=1e-12 * np.max(np.abs(values)), err_msg=name)


@pytest.mark.slow       # 5 s, and a minute more once per machine: zig builds its C++ library (libc++)
@pytest.mark.skipif(not os.environ.get("BONDC_TEST_ZIG_CXX"),
                    reason="zig's first C++ build takes a minute: set BONDC_TEST_ZIG_CXX=1 to run it")
@pytest.mark.skipif(runtime._zig() is None, reason="the ziglang package is not installed")
def test_without_a_system_compiler_zig_builds_the_explicit_stepper_and_runs_it_as_the_system_compiler_does(
        tmp_path, monkeypatch):
    """A machine without c++, g++ or clang++: zig's C++ compiler builds bondc's DOPRI5 stepper
    (Boost.Odeint's headers) and auto takes it for the mass-spring-damper, as with g++."""
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    model = ROOT / "models" / "mass_spring_damper.bg"
    derived = derive_file(model, cache=False)
    namespace = compile_model(derived.state_space)
    system = namespace["simulate_model"](namespace["_MODEL"], t_end=derived.experiment.t_end, method="auto")
    if system.stats["solver"] != "DOPRI5":
        pytest.skip("the explicit stepper cannot be built with the system's compiler here")
    stats, t, states = _run_without_a_system_compiler(tmp_path, model, "auto", derived.experiment.t_end)
    assert stats["code"] == "native" and stats["solver"] == "DOPRI5", stats
    assert stats["compiler_cxx"].startswith("zig c++ ") and stats["compiler"].startswith("zig cc ")
    assert len(list((tmp_path / "native").glob("erk_*.so"))) == 2       # one per compiler
    np.testing.assert_allclose(t, system.t, rtol=1e-12, atol=0)
    for name, values in system.states.items():
        np.testing.assert_allclose(states[name], values, rtol=1e-9, atol=1e-12 * np.max(np.abs(values)), err_msg=name)


@needs_cc
def test_the_library_is_built_once_per_text_and_reused_from_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    runtime._NATIVE_LIBRARIES.clear()
    source = PRELUDE + "".join(
        f"void {name}(double t, const double *x, const double *p, const double *m, double *out) {{ out[0] = 2*t; }}\n"
        for name in runtime._NATIVE_FUNCTIONS)      # (the driver calls all of them)
    ffi, lib = runtime.load_native(source)
    built = sorted((tmp_path / "native").glob("*.so"))
    assert len(built) == 1
    runtime._NATIVE_LIBRARIES.clear()       # a new process: found on disk, not rebuilt
    stamp = built[0].stat().st_ino          # a build is renamed into place: a new file (loading marks it used)
    ffi, lib = runtime.load_native(source)
    assert built[0].stat().st_ino == stamp
    out = np.zeros(1)
    lib.bondc_rhs(1.5, ffi.NULL, ffi.NULL, ffi.NULL, ffi.from_buffer("double[]", out))
    assert out[0] == 3.0
    assert not [p for p in (tmp_path / "native").iterdir() if p.name.startswith("build-")]


def test_native_code_can_be_turned_off(monkeypatch):
    monkeypatch.setenv("BONDC_NATIVE", "0")
    ffi, why = runtime.load_native("int x;")
    assert ffi is None and "BONDC_NATIVE=0" in why


@needs_cc
def test_the_cvode_driver_integrates_whole_segments_in_c():
    """With scikit-sundae's SUNDIALS at hand, the model's C code carries bondc's CVODE driver:
    segments run in C (no Python per step) and the step response is still the analytic one."""
    if runtime._sundials_link() is None:
        pytest.skip("scikit-sundae's SUNDIALS libraries are not linkable here")
    derived = derive_file(ROOT / "models" / "mass_spring_damper.bg", cache=False)
    namespace = compile_model(derived.state_space)
    run = namespace["simulate_model"](namespace["_MODEL"], t_end=2.0, rtol=1e-9, atol=1e-12)
    assert run.stats["code"] == "native" and run.stats["driver_segments"] >= 2     # before and after the step
    m, k, b, force, t0 = 2.0, 800.0, 12.0, 10.0, 0.1
    wn, zeta = math.sqrt(k / m), b / (2 * math.sqrt(k * m))
    wd, s = wn * math.sqrt(1 - zeta ** 2), run.t - t0
    expected = np.where(s >= 0, force / k * (1 - np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / math.sqrt(
        1 - zeta ** 2) * np.sin(wd * s))), 0.0)
    np.testing.assert_allclose(run.states["spring.q"], expected, rtol=0, atol=1e-7 * force / k)
    assert run.stats["nfev"] > 0 and run.stats["steps"] == run.t.size - 1      # every step recorded once


@needs_cc
@pytest.mark.parametrize("model, points, capacity", [
    ("models/mass_spring_damper.bg", 401, None),
    ("models/mass_spring_damper.bg", 20_001, 16),          # many points per step: the buffer fills
    pytest.param("models/electro_pneumatic_hybrid.bg", 2_001, None,     # friction sticking and sliding too
                 marks=pytest.mark.slow),
    ("tests/fixtures/engine/pwm_rl.bg", 1_001, None),
])
def test_a_run_reported_on_a_grid_takes_its_points_from_the_driver_as_the_step_loop_does(
        model, points, capacity, monkeypatch):
    """A run with ``dt`` (the points at t_eval) is integrated by the C driver too, its report
    points from CVODE's interpolant of each step (CVodeGetDky in C; where the batch's buffer is
    full, the rest of that step's from Python through the same interpolant). It is the run the
    step loop (scikit-sundae's CVODE stepped from Python, the only way before) gives, to the bit:
    the same steps, events and points. A sliding mode's report points come from the driver too (the
    weights of the combination taken there as the step loop takes them): the same as the step
    loop's sliding to rounding. The mass-spring-damper's points also equal the closed form."""
    if runtime._sundials_link() is None:
        pytest.skip("scikit-sundae's SUNDIALS libraries are not linkable here")
    namespace, experiment = _compiled(ROOT / model)
    t_end = experiment.t_end
    grid = np.linspace(0.0, t_end, points)

    def run():      # CVODE: the driver's and scikit-sundae's are the same integrator, to the bit
        return namespace["simulate_model"](namespace["_MODEL"], t_eval=grid, t_end=t_end, rtol=experiment.rtol,
                                           atol=experiment.atol, max_step=experiment.max_step, method="CVODE")

    with monkeypatch.context() as patch:
        if capacity is not None:
            patch.setattr(namespace["_NativeDriver"], "capacity_for", classmethod(lambda cls, n: capacity))
        driven = run()
    handover = lambda self, driver, t, y, *rest, **named: ("handover", t, np.array(y, dtype=float))  # noqa: E731
    with monkeypatch.context() as patch:
        patch.setattr(namespace["_Run"], "driver_segment", handover)
        stepped = run()
        patch.setattr(namespace["_Run"], "driver_sliding", handover)
        all_stepped = run()
    assert driven.complete and stepped.complete and all_stepped.complete
    assert driven.stats["driver_segments"] >= 1 and "driver_segments" not in stepped.stats
    np.testing.assert_array_equal(driven.t, grid)
    np.testing.assert_array_equal(stepped.t, grid)
    assert driven.events == stepped.events and driven.stats["steps"] == stepped.stats["steps"]
    for name in driven.states:
        np.testing.assert_array_equal(driven.states[name], stepped.states[name], err_msg=name)
    # sliding modes too: the driver's combination in C against the step loop's. The two step a
    # sliding mode in their own order, so they agree to the run's tolerance at the grid's points
    # (1e-4 of each span: the flagship's coupling twist differs by 1.5e-5), not to rounding; the
    # regulator's change of direction at balance ('in valve.f') is an ill-conditioned instant
    # that the two may place apart (see the random designs below)
    if driven.stats.get("sliding_segments"):
        assert driven.stats["driver_sliding_segments"] == driven.stats["sliding_segments"]
        assert "driver_sliding_segments" not in all_stepped.stats
        for group in ("states", "outputs"):
            for name, values in getattr(all_stepped, group).items():
                scale = max(float(np.ptp(values)), 1e-300)
                np.testing.assert_allclose(getattr(driven, group)[name], values, rtol=0, atol=1e-4 * scale,
                                           err_msg=name)
        labels = lambda run: [label for _, label in run.events if "in valve.f" not in label]
        assert labels(driven) == labels(all_stepped)
    if "mass_spring_damper" in model:
        m, k, b, force, t0 = 2.0, 800.0, 12.0, 10.0, 0.1
        wn, zeta = math.sqrt(k / m), b / (2 * math.sqrt(k * m))
        wd, s = wn * math.sqrt(1 - zeta ** 2), grid - t0
        expected = np.where(s >= 0, force / k * (1 - np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / math.sqrt(
            1 - zeta ** 2) * np.sin(wd * s))), 0.0)
        np.testing.assert_allclose(driven.states["spring.q"], expected, rtol=0, atol=1e-4 * force / k)


HYDRAULIC_POWER_UNIT = """import "std:hydraulics"
import "std:mechanics"
import "std:rotational"

model HPU "pump, check valve, accumulator, proportional valve, cylinder lifting a load"
  param w_pump = 1500 [rpm]
  param t_stop = 3 [s]
  param M = 300 [kg]
  param k_stop = 1e7 [N/m]
  param x_max = 0.2 [m]
  param p_check = 2 [bar]
  param K_check = 1e-9 [m^3/(s*Pa)]
  input spool [m^2] = table(t, [0, 0.5, 0.6, 4, 4.1], [0, 0, 2e-5, 2e-5, 0])

  Speed motor : w = w_pump*(1 - step(t, t_stop))
  Pump pump : D = 10e-6/(2*pi)
  Chamber line : V = 0.2e-3 [m^3], p0 = 1e5
  R check "check valve: opens above p_check" : f = if e > p_check then K_check*(e - p_check) else 0
  Chamber rail : V = 0.5e-3 [m^3], p0 = 1e5
  ReliefValve relief : p_crack = 150 [bar], K_v = 5e-9
  Accumulator acc : p_pre = 60 [bar], V_gas = 1 [L]
  VariableOrifice valve : A = spool
  Cylinder cyl : A = 2e-3, V0 = 0.05e-3, p0 = 1e5
  Mass load : M = M
  Gravity weight : M = M
  C endstop : e = if q > x_max then k_stop*(q - x_max) else 0
  1 jc
  0 nline, nrail, nport
  1 jrod

  motor.a -> pump.shaft
  pump.a -> nline
  nline -> line.a
  nline -> jc
  jc -> check
  jc -> nrail
  nrail -> rail.a
  nrail -> relief.a
  nrail -> acc.a
  nrail -> valve.a
  valve.b -> nport
  nport -> cyl.a
  cyl.rod -> jrod
  jrod -> load.a
  jrod -> weight.a
  jrod -> endstop
  output x [mm] = cyl.travel
  output p_rail [bar] = rail.p
  output p_acc [bar] = acc.p
  output Q_relief [L/min] = relief.Q
  experiment run
    t_end = 60 [s]
    dt = 10 [ms]
  end
end
"""


def _unfrozen_both_ways(path, monkeypatch):
    """The model's first experiment with its chattering intervals (the unfrozen law) in the C driver,
    then in the step loop (scikit-sundae's CVODE stepped from Python, the only way before); the
    number of intervals that stalled in each."""
    if runtime._sundials_link() is None:
        pytest.skip("scikit-sundae's SUNDIALS libraries are not linkable here")
    namespace, experiment = _compiled(path)
    runs, stalls = [], []
    for in_c in (True, False):
        count = []
        with monkeypatch.context() as patch:
            original = namespace["_Run"].unfrozen_stalled
            patch.setattr(namespace["_Run"], "unfrozen_stalled",
                          lambda self, t, y: count.append(t) or original(self, t, y))
            if not in_c:
                patch.setattr(namespace["_Run"], "driver_unfrozen", lambda self, *rest: None)
            runs.append(namespace["simulate_model"](namespace["_MODEL"], t_end=experiment.t_end,
                                                    dt=experiment.settings.get("dt"),
                                                    rtol=experiment.rtol, atol=experiment.atol,
                                                    max_step=experiment.max_step))
        stalls.append(count)
    return runs, stalls


def _same_to_the_bit(ours, loop):
    np.testing.assert_array_equal(ours.t, loop.t)
    for group in ("states", "outputs"):
        for name, values in getattr(loop, group).items():
            np.testing.assert_array_equal(getattr(ours, group)[name], values, err_msg=name)
    assert ours.events == loop.events
    for count in ("steps", "segments", "mode_changes", "chattering_intervals"):
        assert ours.stats[count] == loop.stats[count], count


@pytest.mark.slow
@needs_cc
def test_a_chattering_interval_runs_in_the_driver_and_is_the_step_loops_to_the_bit(monkeypatch):
    """twisting.bg chatters: its unfrozen law (the modes found again at every evaluation) is
    integrated in C, the modes found by the same fixed point from the last ones, each step recorded
    with the modes at its end. The independent expectation is the step loop on the same law: the same
    CVODE, so the same steps, points, states and events, to the bit."""
    (ours, loop), _ = _unfrozen_both_ways(ROOT / "tests" / "fixtures" / "engine" / "twisting.bg", monkeypatch)
    assert ours.complete and loop.complete
    assert ours.stats["chattering_intervals"] >= 3
    assert ours.stats["driver_unfrozen_segments"] == ours.stats["chattering_intervals"]
    assert "driver_unfrozen_segments" not in loop.stats
    _same_to_the_bit(ours, loop)


@needs_cc
@pytest.mark.slow
def test_a_hydraulic_power_unit_whose_orifice_chattered_at_an_end_stop_runs_to_its_end(tmp_path, monkeypatch):
    """A user's hydraulic power unit (a metering orifice whose flow chattered at an end stop),
    reported every 10 ms. Its valve's sign(dp)*sqrt(abs(dp)), its check valve and its end stop are
    kinks (continuous laws): evaluated as written, never frozen. The run used to chatter there,
    integrate the unfrozen law over short intervals and stall at t = 4.6 s (E812: the square root
    'infinitely steep'). It now runs to its end, in the C driver and in the step loop alike, with
    no chattering interval and nothing held on a surface. Once the pump has stopped and the valve
    closed, nothing flows into or out of the rail: its pressure and the line's hold, and the line
    sits less than the check valve's cracking pressure above the rail (the check closed)."""
    path = tmp_path / "hpu.bg"
    path.write_text(HYDRAULIC_POWER_UNIT, encoding="utf-8")
    (ours, loop), (stalls_c, stalls_loop) = _unfrozen_both_ways(path, monkeypatch)
    for run in (ours, loop):
        assert run.complete, run.message
        assert run.stats["chattering_intervals"] == 0 and not stalls_c and not stalls_loop
        assert not [label for _, label in run.events if "valve.loss" in label or label.startswith("sliding on")]
        after = run.t > 5.0
        rail, line = run.outputs["p_rail"][after], run.states["line.chamber.p"][after]
        assert np.ptp(rail) <= 1e-9 * rail[-1] and np.ptp(line) <= 1e-9 * line[-1]
        assert 0.0 < line[-1] - rail[-1] < 2e5
    for name, values in loop.states.items():
        scale = max(float(np.ptp(values)), 1e-300)
        assert abs(ours.states[name][-1] - values[-1]) <= 1e-6 * scale, name


@functools.lru_cache(maxsize=None)
def _compiled(path):
    """(generated module's namespace, first experiment) of a model, compiled once for this module."""
    derived = derive_file(path, cache=False)
    return compile_model(derived.state_space), derived.experiment


def _driver_run(path, monkeypatch, *, sliding_in_c=True, truncate=None):
    """The model's first experiment through the C driver; with ``sliding_in_c`` False its sliding
    modes go to the step loop (scikit-sundae's CVODE stepped from Python), and with ``truncate`` the
    driver hands a sliding mode over to that loop after its first few steps (as it does where a
    law is not finite at a trial point), appending the time of each handover to ``truncate``."""
    if runtime._sundials_link() is None:
        pytest.skip("scikit-sundae's SUNDIALS libraries are not linkable here")
    namespace, experiment = _compiled(path)
    with monkeypatch.context() as patch:
        if not sliding_in_c:
            patch.setattr(namespace["_Run"], "driver_sliding",
                          lambda self, driver, t, y, *rest: ("handover", t, np.array(y, dtype=float)))
        if truncate is not None:
            original = namespace["_NativeDriver"].slide_advance

            def first_steps_then_handover(driver, old):
                code, ts, ys, alphas = original(driver, old)
                if len(ts) < 4:
                    return code, ts, ys, alphas
                truncate.append(float(ts[2]))
                return 3, ts[:3], ys[:3], alphas[:3]
            patch.setattr(namespace["_NativeDriver"], "slide_advance", first_steps_then_handover)
        return namespace["simulate_model"](namespace["_MODEL"], t_end=experiment.t_end, method="CVODE",
                                           rtol=experiment.rtol, atol=experiment.atol, max_step=experiment.max_step)


@needs_cc
@pytest.mark.parametrize("model", ["models/electro_pneumatic_hybrid.bg", "tests/fixtures/engine/breakaway.bg",
                                   "tests/fixtures/sim/friction_stick.bg", "tests/fixtures/sim/stuck_two_frictions.bg",
                                   "tests/fixtures/engine/twisting.bg"])
def test_a_sliding_mode_on_one_switch_runs_in_the_driver_and_agrees_with_the_step_loop(model, monkeypatch):
    """A Filippov sliding mode (stuck friction; two switches in the last two models) is integrated
    by the C driver: the corners' combination, its Jacobian and the exits in C. The independent
    expectation is the step loop (tested against analytic solutions in test_engine): CVODE on the
    same combination at the same tolerances. The two take their steps in their own order (the
    driver's sliding steps are not the loop's: 51 against 63 points on breakaway.bg), so they agree
    to the run's tolerance, not to rounding: the same events in the same order at the same times,
    and the same end state. A switch toggling on its surface at the run's last instant (the
    flagship's valve at rest between equal pressures) changes nothing that follows and is left out."""
    path = ROOT / model
    ours = _driver_run(path, monkeypatch)
    loop = _driver_run(path, monkeypatch, sliding_in_c=False)
    assert ours.stats["code"] == "native" and ours.stats["sliding_segments"] >= 1
    assert ours.stats["driver_sliding_segments"] == ours.stats["sliding_segments"]
    assert "driver_sliding_segments" not in loop.stats
    t_end = float(loop.t[-1])
    assert float(ours.t[-1]) == t_end
    before_end = lambda run: [(t, label) for t, label in run.events if t < t_end - 1e-9]
    assert [label for _, label in before_end(ours)] == [label for _, label in before_end(loop)]
    np.testing.assert_allclose([t for t, _ in before_end(ours)], [t for t, _ in before_end(loop)], rtol=0, atol=1e-7)
    atol = _compiled(path)[1].atol or 1e-9      # (the run's; a state held at 0 throughout spans rounding alone)
    for name, values in loop.states.items():
        scale = max(float(np.ptp(values)), 1e-300)
        assert abs(ours.states[name][-1] - values[-1]) <= 1e-6 * scale + atol, name


def _carts(count: int) -> str:
    """``count`` carts on dry friction joined by springs, cart i pushed by i*t N against a static
    limit of 5 + i N (test_engine has the closed form of its first breakaway)."""
    lines = ["model Carts"]
    for i in range(1, count + 1):
        lines += [f"  MSe push{i} : e = {i}*t", f"  I m{i} : f = p/{1 + 0.1 * i}",
                  f"  R fr{i} : e = coulomb(f, {4 + i}, {5 + i})", f"  1 v{i}", f"  push{i} -> v{i}",
                  f"  v{i} -> m{i}", f"  v{i} -> fr{i}", f"  output F{i} [N] = fr{i}.e"]
        if i < count:
            lines += [f"  C k{i} : e = 500*q", f"  0 n{i}", f"  1 r{i}", f"  v{i} -> n{i}", f"  n{i} -> v{i + 1}",
                      f"  n{i} -> r{i}", f"  r{i} -> k{i}"]
    return "\n".join(lines + ["  experiment run", "    t_end = 3 [s]", "  end", "end"]) + "\n"


@needs_cc
@pytest.mark.parametrize("model", ["coupled_clutches", pytest.param("carts", marks=pytest.mark.slow)])
def test_a_sliding_mode_on_several_switches_runs_in_the_driver_and_agrees_with_the_step_loop(
        model, monkeypatch, tmp_path):
    """Three clutches stuck at once, and twelve carts (the affine combination of 13 corners), are
    integrated by the C driver: Newton's method on the weights with Gaussian elimination where the
    step loop takes numpy's least squares. The combinations agree to rounding, but where the
    solution is a polynomial (or at rest) the solver's error estimate is rounding, so the steps
    differ: the same events and end, to the tolerance, and every sliding segment in C."""
    if model == "carts":
        path = tmp_path / "carts.bg"
        path.write_text(_carts(12), encoding="utf-8")
    else:
        path = ROOT / "tests/fixtures/engine/coupled_clutches.bg"
    ours = _driver_run(path, monkeypatch)
    loop = _driver_run(path, monkeypatch, sliding_in_c=False)
    assert ours.complete and loop.complete
    assert ours.stats["driver_sliding_segments"] == ours.stats["sliding_segments"] >= 2
    assert "driver_sliding_segments" not in loop.stats
    assert max(label.count(";") for _, label in ours.events) >= 2      # three switches or more held at once
    assert [label for _, label in ours.events] == [label for _, label in loop.events]
    # once the steps part, each run is as exact as the tolerance (rtol 1e-6) makes it
    np.testing.assert_allclose([t for t, _ in ours.events], [t for t, _ in loop.events], rtol=1e-7, atol=1e-12)
    for name, values in loop.outputs.items():
        scale = max(float(np.ptp(values)), 1e-300)
        assert abs(ours.outputs[name][-1] - values[-1]) <= 1e-6 * scale, name


PIECE_MODELS = {
    "pwm_rl": (ROOT / "tests/fixtures/engine/pwm_rl.bg").read_text(encoding="utf-8"),
    "pwm_sine_compare": (ROOT / "tests/fixtures/engine/pwm_sine_compare.bg").read_text(encoding="utf-8"),
    # a pwm whose duty steps: nested switches of time, the inner one's mode read by the outer
    "duty_step": ("model PwmDuty\n  input d [1] = 0.2 + 0.6*step(t, 0.05)\n  MSe src : e = 5*pwm(t, 1000, d)\n"
                  "  R r : e = 10*f\n  C c : e = q/1e-3\n  1 j\n  src -> j\n  j -> r\n  j -> c\n"
                  "  experiment run\n    t_end = 0.1 [s]\n  end\nend\n"),
    # a staircase of time (a floor switch: integer modes)
    "staircase": ("model Staircase\n  input u [V] = floor(t*200)/20\n  MSe src : e = u\n  R r : e = 10*f\n"
                  "  C c : e = q/1e-3\n  1 j\n  src -> j\n  j -> r\n  j -> c\n"
                  "  experiment run\n    t_end = 0.1 [s]\n  end\nend\n"),
    # switches of the state besides: a 20 kHz pwm on a DC motor whose load sticks by dry friction at
    # first (sliding segments, left to the run), then turns (every edge a restart in C)
    "motor_pwm": ("model MotorPwm\n  input u [V] = 24*pwm(t, 20000, 0.4)\n  MSe source : e = u\n"
                  "  R winding : e = 1.2*f\n  I coil : f = p/2e-3\n  GY motor : r = 0.05\n  I rotor : f = p/2e-5\n"
                  "  R fric : e = 1e-5*f + coulomb(f, 0.02, 0.03)\n  1 el\n  1 mech\n  source -> el\n"
                  "  el -> winding\n  el -> coil\n  el -> motor\n  motor -> mech\n  mech -> rotor\n  mech -> fric\n"
                  "  experiment run\n    t_end = 0.02 [s]\n  end\nend\n"),
    # a reversing flow through a turbulent orifice and a flow regulator: the regulator's sign switch
    # (a jump; the orifice's sign(e)*sqrt(abs(e)) is a kink, no switch) crosses inside pieces
    "orifice_reversing_jump": (ROOT / "tests/fixtures/engine/orifice_reversing_jump.bg").read_text(encoding="utf-8"),
    # 1 % pulses into a Shockley diode in a nonlinear algebraic loop (its switches and laws in C's
    # Newton, numpy's MINPACK where that fails)
    "pwm_diode": (ROOT / "tests/fixtures/sim/pwm_diode.bg").read_text(encoding="utf-8"),
}
PIECE_MODELS.update({
    # a PI controller sampled at 5 kHz by a when clause on a pwm's rising edges (zero-order hold):
    # the clause's statements at every other break, run in C with the restart after them
    "sampled_pi": ("model SampledPI\n  param Ts = 0.2 [ms]\n  param Kp = 0.5 [V*s/rad]\n  param Ki = 20 [V/rad]\n"
                   "  param w_ref = 100 [rad/s]\n  discrete u_k [V] = 0\n  discrete i_k [V] = 0\n"
                   "  MSe drive : e = u_k\n  R winding : e = 1*f\n  I coil : f = p/1e-3\n  GY emf : r = 0.05\n"
                   "  I rotor : f = p/2e-4\n  R fric : e = 1e-4*f\n  1 el\n  1 mech\n  drive -> el\n"
                   "  el -> winding\n  el -> coil\n  el -> emf\n  emf -> mech\n  mech -> rotor\n  mech -> fric\n"
                   "  when pwm(t, 1/Ts, 0.5) > 0.5 then\n    i_k = i_k + Ki*Ts*(w_ref - rotor.f),\n"
                   "    u_k = min(max(Kp*(w_ref - rotor.f) + i_k + Ki*Ts*(w_ref - rotor.f), -24), 24)\n  end\n"
                   "  experiment run\n    t_end = 0.05 [s]\n  end\nend\n"),
    # a when clause counting a chirp's zero crossings (a switch of time that is no pwm)
    "chirp_count": (ROOT / "tests/fixtures/engine/chirp_count.bg").read_text(encoding="utf-8"),
    # statements with transcendental functions (C's libm and numpy may differ in the last bit: the
    # run takes C's statements, so that every piece ahead is its own)
    "held_exp_sin": ("model HeldExpSin\n  discrete u [V] = 0\n  MSe src : e = u\n  R r : e = 10*f\n"
                     "  C c : e = q/1e-3\n  1 j\n  src -> j\n  j -> r\n  j -> c\n"
                     "  when pwm(t, 2000, 0.5) > 0.5 then u = 5*exp(-30*c.q)*sin(2*pi*7*t) + tanh(c.q*1e3) end\n"
                     "  experiment run\n    t_end = 0.05 [s]\n  end\nend\n"),
    # a clause whose statements make a second clause's condition true at the same instant: a
    # second round, left to the run
    "two_rounds": ("model TwoRounds\n  discrete a [1] = 0\n  discrete b [1] = 0\n  MSe src : e = a - b + 1\n"
                   "  R r : e = 10*f\n  C c : e = q/1e-3\n  1 j\n  src -> j\n  j -> r\n  j -> c\n"
                   "  when pwm(t, 1000, 0.5) > 0.5 then a = a + 1 end\n  when a > b + 0.5 then b = a end\n"
                   "  experiment run\n    t_end = 0.02 [s]\n  end\nend\n"),
})
#: the models above whose every segment is a known piece (all their switches of time), and those
#: in which a switch of the state crosses inside a piece
TIME_ALONE = {"pwm_rl", "pwm_sine_compare", "duty_step", "staircase", "pwm_diode", "sampled_pi", "chirp_count",
              "held_exp_sin"}
CROSSING = {"orifice_reversing_jump"}


def _same_run_with_pieces_ahead(path, ahead, monkeypatch, every_segment, resumed=False):
    """Run ``path``'s first experiment with the pieces between its known breaks integrated ahead
    (``ahead`` at a time) and segment by segment, and check that the two runs are the same to the bit."""
    if runtime._sundials_link() is None:
        pytest.skip("scikit-sundae's SUNDIALS libraries are not linkable here")
    namespace, experiment = _compiled(path)
    settings = {"t_end": experiment.t_end, "rtol": experiment.rtol, "atol": experiment.atol,
                "max_step": experiment.max_step}
    with monkeypatch.context() as patch:
        patch.setattr(namespace["_Run"], "PIECES_AHEAD", ahead)
        ours = namespace["simulate_model"](namespace["_MODEL"], **settings)
        patch.setattr(namespace["_Run"], "pieces_apply", lambda self: False)
        alone = namespace["simulate_model"](namespace["_MODEL"], **settings)
    assert ours.complete and alone.complete
    assert "pieces_ahead" not in alone.stats
    if every_segment:
        assert ours.stats["pieces_ahead"] == ours.stats["segments"] > 10
    else:       # (a friction's sliding segments are the run's own)
        assert ours.stats["segments"] >= ours.stats["pieces_ahead"] >= 1
    if resumed:     # a crossing inside a piece: the run went on from where the C call stopped
        assert ours.stats["pieces_resumed"] >= 1
    assert np.array_equal(ours.t, alone.t)
    for group in ("states", "outputs", "variables"):
        for key, values in getattr(alone, group).items():
            assert np.array_equal(getattr(ours, group)[key], values), (group, key)
    assert ours.events == alone.events and len(ours.events) > 10
    for count in ("nfev", "njev", "nlu", "steps", "segments", "mode_changes", "driver_segments"):
        assert ours.stats[count] == alone.stats[count], count


@needs_cc
@pytest.mark.parametrize("ahead", [512, pytest.param(7, marks=pytest.mark.slow)])
@pytest.mark.parametrize("name", sorted(PIECE_MODELS))
def test_the_pieces_between_known_breaks_run_in_one_call_and_equal_the_run_segment_by_segment(
        name, ahead, tmp_path, monkeypatch):
    """The segments between a run's known breaks (a pwm's edges, steps and staircases of time), and
    the restarts at those breaks, are integrated ahead in one C call for many breaks, with the
    statements of the when clauses that fire there; a restart that is not simple (a friction on
    its surface, switches that chatter, a second round of when clauses) and a piece in which a
    switch of the state may cross are left to the run. The independent expectation is the run segment by
    segment (each segment one driver call, each restart from Python: tested against closed forms
    in test_engine): the same points, states, outputs, variables, events and solver counts, to the
    bit, with the queue refilled every 512 pieces or every 7."""
    path = tmp_path / f"{name}.bg"
    path.write_text(PIECE_MODELS[name], encoding="utf-8")
    _same_run_with_pieces_ahead(path, ahead, monkeypatch, every_segment=name in TIME_ALONE, resumed=name in CROSSING)


@needs_cc
@pytest.mark.slow
@pytest.mark.parametrize("model", ["electro_pneumatic_hybrid.bg", "electro_pneumatic_hybrid_components.bg"])
def test_the_flagships_pieces_ahead_equal_its_run_segment_by_segment(model, monkeypatch):
    """The flagship cycle: its motion profile's corners are known breaks, its frictions and backlash
    switches of the state (43 events, sliding segments): the pieces between breaks that no event
    interrupts come from the queue, the rest from the run, and the cycle is the same to the bit."""
    _same_run_with_pieces_ahead(ROOT / "models" / model, 512, monkeypatch, every_segment=False, resumed=True)


@needs_cc
@pytest.mark.slow
def test_the_drivers_sliding_modes_equal_the_step_loops_over_random_flagship_designs(monkeypatch):
    """The flagship with its mass, inertias, stiffnesses, damping, backlash and friction law scaled
    at random (0.6 to 1.6 times): every design sticks and slips differently (40 to 130 events), and
    the driver's sliding modes give the step loop's run each time, to the run's tolerance: the
    same stick and slip events at the same times (to 1e-7 s; a friction's sign change at the
    instant it sticks counted with the stick) and the same end state (to 1e-5 of each state's span). The two take their steps in their own order, so not to rounding; and the
    regulator's change of direction ('if P1 >= chamber.P in valve.f', a law continuous there that
    the compiler cannot show to be: a jump) is crossed while the chamber sits at the supply pressure,
    an ill-conditioned instant that the two place up to 1 ms apart, or not at all: left out."""
    if runtime._sundials_link() is None:
        pytest.skip("scikit-sundae's SUNDIALS libraries are not linkable here")
    namespace, experiment = _compiled(ROOT / "models" / "electro_pneumatic_hybrid.bg")
    varied = ("M", "Iz", "K", "k_nut", "c_nut", "gap", "c0", "v_th", "a_up", "n_up", "a_dn", "n_dn", "b_cr")
    rng = np.random.default_rng(1)
    settings = {"t_end": experiment.t_end, "method": "CVODE", "rtol": experiment.rtol, "atol": experiment.atol,
                "max_step": experiment.max_step}
    for _ in range(6):
        design = {name: namespace["PARAMETERS"][name] * rng.uniform(0.6, 1.6) for name in varied}
        ours = namespace["simulate_model"](namespace["_MODEL"], p=design, **settings)
        with monkeypatch.context() as patch:
            patch.setattr(namespace["_Run"], "driver_sliding",
                          lambda self, driver, t, y, *rest: ("handover", t, np.array(y, dtype=float)))
            loop = namespace["simulate_model"](namespace["_MODEL"], p=design, **settings)
        assert ours.complete and ours.stats["driver_sliding_segments"] == ours.stats["sliding_segments"] >= 1
        def events(run):
            # a friction's velocity that passes 0 where it sticks: one run notes the sign change as an
            # event of its own, the other only the sliding mode that starts there (within 1e-7 s): the
            # same stick, bookkept apart
            kept = [(t, label) for t, label in run.events if "in valve.f" not in label]
            starts = [t for t, label in kept if label.startswith("sliding on ") and not label.endswith(" ends")]
            return [(t, label) for t, label in kept
                    if not (label.startswith("sign(friction.f)") and any(abs(t - s) <= 1e-7 for s in starts))]

        assert [label for _, label in events(ours)] == [label for _, label in events(loop)]
        np.testing.assert_allclose([t for t, _ in events(ours)], [t for t, _ in events(loop)], rtol=0, atol=1e-7)
        for name, values in loop.states.items():
            scale = max(float(np.ptp(values)), 1e-300)
            assert abs(ours.states[name][-1] - values[-1]) <= 1e-5 * scale, name


@needs_cc
def test_a_sliding_mode_the_driver_hands_over_goes_on_in_the_step_loop(monkeypatch):
    """Where the driver gives a sliding mode up (a law not finite at a trial point, a failed step),
    the step loop goes on from the last step it stored: the run still reaches the end with the same
    events, and agrees with the step loop's own run to the solver tolerance (compared at the loop's
    points, interpolating linearly between the other run's steps)."""
    path = ROOT / "models" / "electro_pneumatic_hybrid.bg"
    handovers = []
    handed = _driver_run(path, monkeypatch, truncate=handovers)
    loop = _driver_run(path, monkeypatch, sliding_in_c=False)
    assert len(handovers) >= 2 and set(handovers) <= set(handed.t.tolist())
    assert handed.complete and handed.stats["driver_sliding_segments"] == handed.stats["sliding_segments"]
    # the regulator's change of direction ('if P1 >= chamber.P in valve.f') is left out, as in the
    # test above: crossed while the chamber sits at the supply pressure, an ill-conditioned instant
    # that two runs place apart, or not at all
    events = lambda run: [(t, label) for t, label in run.events if "in valve.f" not in label]
    assert [label for _, label in events(handed)] == [label for _, label in events(loop)]
    np.testing.assert_allclose([t for t, _ in events(handed)], [t for t, _ in events(loop)], rtol=0, atol=1e-5)
    for name, values in loop.states.items():
        scale = max(float(np.ptp(values)), 1e-12)
        difference = np.abs(np.interp(loop.t, handed.t, handed.states[name]) - values)
        assert difference.max() <= 1e-3 * scale, name


@pytest.mark.parametrize("model", ["models/electro_pneumatic_hybrid.bg", "tests/fixtures/engine/diode_bridge_jump.bg"])
def test_the_modes_a_right_hand_side_reads_depend_on_the_modes_alone(model):
    """The step loop keeps, per mode vector, which switches matter (the modes the active branches
    read): every condition of a jump is a switch, so the state cannot change which of its branches
    run (a kink's condition is evaluated as written and reads no mode). Checked on the generated
    numpy code at random states for random mode vectors."""
    namespace, _ = _compiled(ROOT / model)
    runtime_model = namespace["_Model"](namespace["_MODEL"])
    p = namespace["param_array"](runtime_model.PARAMETERS, None, runtime_model.derive_parameters)
    x0, count = runtime_model.x0(p), len(runtime_model.SWITCHES)
    rng = np.random.default_rng(2)
    for _ in range(8):
        modes = rng.choice([-1.0, 1.0], count)
        seen = set()
        for _ in range(10):
            reader = namespace["_ModeReader"](modes)
            with np.errstate(all="ignore"):
                runtime_model.rhs(float(rng.uniform(0, 1)), x0 * rng.uniform(-2, 2, x0.size), p, reader)
            seen.add(frozenset(reader.read))
        assert len(seen) == 1 and next(iter(seen))


@needs_cc
def test_the_deadbands_are_the_sums_of_each_states_tolerance_move_to_the_bit():
    """The deadbands (how far each switching function moves when each state moves by its tolerance,
    summed over the states) have one implementation, ``bondc_law_deadbands`` (the driver's and an
    FMU's too): the run's, through runtime.policy with the model's C functions or its numpy ones
    called back, equals the sums written out here, at random states and modes of the flagship."""
    if runtime._sundials_link() is None:
        pytest.skip("scikit-sundae's SUNDIALS libraries are not linkable here")
    namespace, _ = _compiled(ROOT / "models" / "electro_pneumatic_hybrid.bg")
    model = namespace["_Model"](namespace["_MODEL"])
    numpy_model = namespace["_Model"](namespace["_MODEL"])
    assert namespace["attach_native"](model, None)[0]
    p = namespace["param_array"](model.PARAMETERS, None, model.derive_parameters)
    runs = [namespace["_Run"](namespace["RunSpec"](model=m, parameters=p, t_start=0.0, t_end=4.2, t_eval=None,
                                                   method="CVODE", rtol=1e-6, atol=1e-9, max_step=np.inf,
                                                   max_events=1000, max_event_rate=100))
            for m in (model, numpy_model)]
    assert model.native_functions is not None and numpy_model.native_functions is None
    rng = np.random.default_rng(11)
    x0, count = model.x0(p), len(model.SWITCHES)
    index = np.arange(count)
    for _ in range(10):
        y = x0 * rng.uniform(0.5, 1.5, x0.size) + rng.normal(0, 1e-3, x0.size)
        modes = rng.choice([-1.0, 1.0], count)
        t = float(rng.uniform(0, 4.2))
        base = numpy_model.switches(t, y, p, modes)
        expected = np.zeros(count)
        for i in range(y.size):
            moved = y.copy()
            moved[i] += 1e-9 + 1e-6 * abs(y[i])
            expected += np.abs(numpy_model.switches(t, moved, p, modes) - base)
        expected[~np.isfinite(expected)] = 0.0
        assert np.any(expected > 0)
        for run in runs:
            np.testing.assert_array_equal(run.deadbands(t, y, modes, index), expected)


@pytest.mark.slow      # 3 s: a large model's C build
@needs_cc
def test_a_large_models_functions_are_compiled_as_units_of_their_own_and_compute_the_same(tmp_path, monkeypatch):
    """From ``_NATIVE_SPLIT_FROM`` characters on, each C function (and the driver) is a translation
    unit of its own, compiled in parallel and linked. Forced here on the flagship: the library built
    that way gives bit-identical right-hand sides, Jacobians and switching functions, and the run
    through its driver equals the one through the single-unit library."""
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    derived = derive_file(ROOT / "models" / "electro_pneumatic_hybrid.bg", cache=False)
    namespace = compile_model(derived.state_space)
    source = namespace["NATIVE_SOURCE"]
    assert len(runtime._native_units(source)) == 1
    # the whole library one unit (the model's text and the driver's together pass the size from
    # which it is split by default)
    monkeypatch.setattr(runtime.native, "_NATIVE_SPLIT_FROM", float("inf"))
    runtime._NATIVE_LIBRARIES.clear()
    whole_ffi, whole = runtime.load_native(source)
    monkeypatch.setattr(runtime.native, "_NATIVE_SPLIT_FROM", 0)
    units = runtime._native_units(source + "\n" + runtime.UNIT_MARK + "int bondc_unit_probe;\n")
    # its six functions (right-hand side, Jacobian, switches, when conditions, when statements and
    # whether those are in C) and the probe
    assert len(units) == 7 and all(unit.startswith(source[:source.index(runtime.UNIT_MARK)]) for unit in units)
    runtime._NATIVE_LIBRARIES.clear()
    split_ffi, split = runtime.load_native(source)
    assert split is not whole and len(list((tmp_path / "native").glob("*.so"))) == 2
    rng = np.random.default_rng(3)
    n, modes = len(namespace["STATE_NAMES"]), len(namespace["SWITCHES"])
    p = np.array(list(namespace["PARAMETERS"].values()), dtype=float)
    sizes = {"bondc_rhs": n, "bondc_jac": len(namespace["JACOBIAN_PATTERN"]), "bondc_switches": modes}
    for _ in range(20):
        x = namespace["x0"]() * rng.uniform(0.5, 1.5, n) + rng.normal(0, 1e-3, n)
        m = rng.choice([-1.0, 1.0], modes)
        t = rng.uniform(0, 4.2)
        for name, size in sizes.items():
            outs = []
            for ffi, lib in ((whole_ffi, whole), (split_ffi, split)):
                out = np.zeros(size)
                getattr(lib, name)(t, ffi.from_buffer("double[]", x), ffi.from_buffer("double[]", p),
                                   ffi.from_buffer("double[]", m), ffi.from_buffer("double[]", out))
                outs.append(out)
            np.testing.assert_array_equal(outs[0], outs[1])
    assert hasattr(split, "bondc_driver_new") == hasattr(whole, "bondc_driver_new")


@pytest.mark.slow
@needs_cc
def test_a_build_started_ahead_is_the_one_load_native_finishes_and_an_unused_one_is_removed(tmp_path, monkeypatch):
    """start_native begins a large model's build in the background (here forced on the flagship):
    load_native waits for that build instead of starting another, and gives the same library as a
    build from scratch; a build nobody loads is stopped and its folder removed (at exit)."""
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(runtime.native, "_NATIVE_SPLIT_FROM", 0)
    derived = derive_file(ROOT / "models" / "electro_pneumatic_hybrid.bg", cache=False)
    namespace = compile_model(derived.state_space)
    source = runtime.native_text(namespace["__bondc_source__"])
    assert source == "".join(namespace["NATIVE_SOURCE"])
    runtime._discard_pending()        # builds an earlier test started ahead and never loaded
    runtime._NATIVE_LIBRARIES.clear()
    for path in (tmp_path / "native").glob("*.so"):
        path.unlink()
    runtime.start_native(source)
    assert len(runtime._NATIVE_PENDING) == 1
    (pending,) = runtime._NATIVE_PENDING.values()
    started = []
    monkeypatch.setattr(runtime.native, "_NativeBuild", lambda *a, **k: started.append(a))   # no second build
    ffi, lib = runtime.load_native(source)
    assert ffi is not None and not started and not runtime._NATIVE_PENDING
    assert not os.path.exists(pending.work) and len(list((tmp_path / "native").glob("*.so"))) == 1
    x = namespace["x0"]()
    p = np.array(list(namespace["PARAMETERS"].values()), dtype=float)
    m = np.ones(len(namespace["SWITCHES"]))
    out = np.zeros(x.size)
    lib.bondc_rhs(0.3, ffi.from_buffer("double[]", x), ffi.from_buffer("double[]", p), ffi.from_buffer("double[]", m),
                  ffi.from_buffer("double[]", out))
    np.testing.assert_allclose(out, namespace["_rhs"](0.3, x, p, m), rtol=1e-12, atol=1e-12)
    monkeypatch.undo()
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path / "other"))
    monkeypatch.setattr(runtime.native, "_NATIVE_SPLIT_FROM", 0)
    runtime._NATIVE_LIBRARIES.clear()
    runtime.start_native(source)
    (unused,) = runtime._NATIVE_PENDING.values()
    runtime._discard_pending()
    assert not runtime._NATIVE_PENDING and not os.path.exists(unused.work)
    assert all(run.poll() is not None for run in unused.runs)


def _load_in_forked_child(source, work, queue):
    ffi, lib = runtime.load_native(source)
    queue.put((ffi is not None, os.path.isdir(work)))


@pytest.mark.slow      # 4 s: a forked build
@needs_cc
def test_a_forked_process_never_finishes_or_removes_its_parents_build(tmp_path, monkeypatch):
    """Sweep workers are forked: a child inherits its parent's build started ahead, but only the
    parent waits for those compilers. The child builds (or finds) the library itself and leaves
    the parent's build folder alone; the parent then loads the library and removes its own."""
    import multiprocessing

    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(runtime.native, "_NATIVE_SPLIT_FROM", 0)
    derived = derive_file(ROOT / "models" / "mass_spring_damper.bg", cache=False)
    source = "".join(compile_model(derived.state_space)["NATIVE_SOURCE"])
    runtime._discard_pending()
    runtime._NATIVE_LIBRARIES.clear()
    for path in (tmp_path / "native").glob("*.so"):
        path.unlink()
    runtime.start_native(source)
    (pending,) = runtime._NATIVE_PENDING.values()
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_load_in_forked_child, args=(source, pending.work, queue))
    child.start()
    loaded, parents_folder_left = queue.get(timeout=300)
    child.join(timeout=60)
    assert child.exitcode == 0 and loaded and parents_folder_left
    ffi, lib = runtime.load_native(source)
    assert ffi is not None and not runtime._NATIVE_PENDING and not os.path.exists(pending.work)


@pytest.mark.parametrize("name", ["tests/fixtures/sim/friction_stick.bg", "models/electro_pneumatic_hybrid.bg"])
def test_a_repeated_point_is_dropped_before_the_results_are_evaluated(name, monkeypatch):
    """A restart that made no progress repeats a point; the result keeps its first record. The
    repeated points are now dropped before the outputs and variables are evaluated: a point
    repeated inside a sliding block (its Filippov weights too) and inside an ordinary block
    gives the very result of the run without them."""
    namespace, experiment = _compiled(ROOT / name)

    def run():
        return namespace["simulate_model"](namespace["_MODEL"], t_end=experiment.t_end, method="CVODE",
                                           rtol=experiment.rtol, atol=experiment.atol,
                                           max_step=experiment.max_step)

    clean = run()
    original = namespace["_Run"].result
    repeated = []

    def with_repeats(self, complete, failure):
        kinds = set()
        for i, (times, mode) in enumerate(zip(self.blocks_t, self.blocks_mode)):
            sliding = isinstance(mode, tuple) and mode[0] == "slide"
            # (a sliding mode's long steps are recorded one by one: bondc_driver_check)
            if times.size < (1 if sliding else 3) or sliding in kinds:
                continue
            kinds.add(sliding)
            k = times.size // 2
            self.blocks_t[i] = np.insert(times, k + 1, times[k])
            # the repeat's record differs: only the first record may be kept
            self.blocks_x[i] = np.insert(self.blocks_x[i], k + 1, 1.5 * self.blocks_x[i][:, k] + 1.0, axis=1)
            if sliding:
                weights = np.asarray(mode[2])
                self.blocks_mode[i] = ("slide", mode[1], np.insert(weights, k + 1, 1.0 - weights[:, k], axis=1))
            repeated.append(sliding)
        return original(self, complete, failure)

    monkeypatch.setattr(namespace["_Run"], "result", with_repeats)
    again = run()
    assert sorted(repeated) == [False, True]          # one repeat in each kind of block
    assert np.array_equal(again.t, clean.t)
    for group in ("states", "outputs", "variables"):
        ours, theirs = getattr(again, group), getattr(clean, group)
        assert list(ours) == list(theirs)
        assert all(np.array_equal(ours[key], theirs[key], equal_nan=True) for key in ours), group


@needs_cc
def test_a_loaded_models_library_is_found_again_by_its_text_without_building(tmp_path, monkeypatch):
    """Every run of a loaded model asks for its library: the same text object gives the same
    library without joining, hashing or building anything; once the process forgets the library
    (as a new process would), it is loaded again."""
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path))
    source = (PRELUDE, "".join(
        f"void {name}(double t, const double *x, const double *p, const double *m, double *out) {{ out[0] = 3*t; }}\n"
        for name in runtime._NATIVE_FUNCTIONS))
    first = runtime.load_native(source)
    assert first[0] is not None
    real = runtime._build_native
    monkeypatch.setattr(runtime.native, "_build_native", lambda *args: pytest.fail("built or hashed again"))
    assert runtime.load_native(source)[1] is first[1]
    monkeypatch.setattr(runtime.native, "_build_native", real)
    runtime._NATIVE_LIBRARIES.clear()
    again = runtime.load_native(source)
    assert again[1] is not first[1]
    out = np.zeros(1)
    again[1].bondc_rhs(2.0, again[0].NULL, again[0].NULL, again[0].NULL, again[0].from_buffer("double[]", out))
    assert out[0] == 6.0


@pytest.mark.parametrize("fixture", ["engine/diode_bridge_jump.bg", "sim/pwm_diode.bg"])
def test_the_modes_a_loop_models_laws_read_are_found_without_solving_the_loop(fixture):
    """Which switches matter for a mode vector is found by evaluating the right-hand side with a
    mode reader; in a model with a nonlinear loop the loop's residual is then evaluated once, not
    solved (its branches depend on the modes alone): the modes read are those a full solve reads,
    for every mode vector tried."""
    namespace, _ = _compiled(ROOT / "tests" / "fixtures" / fixture)
    model = namespace["_Model"](namespace["_MODEL"])        # the numpy module (MINPACK solves the loop)
    p = namespace["param_array"](model.PARAMETERS, {}, model.derive_parameters)
    reader = namespace["_ModeReader"]
    count = len(model.SWITCHES)
    assert count and model.SWITCH_DEPENDS is not None and not model.VECTORIZED      # switches, a loop
    rng = np.random.default_rng(3)
    x = model.x0(p) + rng.uniform(-1.0, 1.0, len(model.STATE_NAMES))
    for _ in range(12):
        modes = rng.choice([-1.0, 1.0], count)
        solved = reader(modes)
        with np.errstate(all="ignore"):
            model.rhs(0.003, x, p, solved)
            namespace["_READING_MODES"], solve = True, namespace["solve_loop"]
            namespace["solve_loop"] = lambda *args: pytest.fail("the loop was solved to read modes")
            try:
                read = reader(modes)
                model.rhs(0.003, x, p, read)
            finally:
                namespace["_READING_MODES"], namespace["solve_loop"] = False, solve
        assert read.read == solved.read and read.read


# ------------------------------------------------------------ bondc's C and C++ sources (bondc/native)

NATIVE = ROOT / "bondc" / "native"


def test_the_engines_sources_are_files_of_the_package_and_are_built_with_their_headers_inlined():
    """The CVODE driver and the explicit stepper are package files (bondc/native), each with one job;
    a build inlines their ``#include "..."`` headers, so the compiled text (what the cache key
    hashes) holds every file, and cffi's cdef reads driver.h as it is."""
    assert sorted(p.name for p in NATIVE.iterdir() if p.suffix in (".c", ".h", ".cpp")) == [
        "driver.c", "driver.h", "erk.cpp", "erk_api.h", "events.c", "events.h", "filippov.c", "filippov.h", "locate.c",
        "locate.h", "model.h", "policy.c", "sundials.h"]
    for name in ("driver.c", "erk.cpp"):
        built = runtime.native_build_text(name)
        assert not [line for line in built.splitlines() if line.startswith('#include "')], name
        assert built.count("typedef struct {\n    int version;") == 1, name     # erk_api.h's table, once
    driver = runtime.native_build_text("driver.c")
    for header in ("driver.h", "model.h", "sundials.h", "erk_api.h", "filippov.h", "events.h", "locate.h"):
        assert runtime.native_file(header) in driver, header
    import cffi

    # the run loop's functions are built into the driver, and alone (policy.c) for the Python run
    # loop: the same texts
    for source in ("filippov.c", "events.c", "locate.c"):
        assert runtime.native_build_text(source) in driver
        assert runtime.native_build_text(source) in runtime.native_build_text("policy.c")
    for headers in (("filippov.h",), ("filippov.h", "events.h"), ("locate.h",)):     # events.h uses filippov.h's types
        assert not ["#" for header in headers if "#" in runtime.native_file(header)]
        cffi.FFI().cdef("".join(runtime.native_file(header) for header in headers))
    assert "bondc_driver_new" in runtime.native_file("driver.h")
    assert "#" not in runtime.native_file("driver.h")        # no preprocessor line: cffi's cdef reads it
    cffi.FFI().cdef(runtime.native_file("driver.h"))
    # model.h declares the model's functions the driver calls, as the code generation defines them
    assert runtime.native_file("model.h").count("void bondc_") == len(runtime._NATIVE_FUNCTIONS)
    for name in runtime._NATIVE_FUNCTIONS:
        assert (f"void {name}(double t, const double *x, const double *p, const double *m, double *out);\n"
                in runtime.native_file("model.h")), name


@needs_cc
def test_the_driver_compiles_on_its_own_as_an_editor_sees_it(tmp_path):
    """driver.c with its headers beside it, and no model: what an editor or IDE checks (every
    warning of -Wall -Wextra is an error)."""
    compiler = runtime.find_compiler("c")[0]
    assert compiler is not None
    done = subprocess.run([*compiler.command, "-fsyntax-only", "-std=c99", "-Wall", "-Wextra", "-Werror",
                           str(NATIVE / "driver.c")], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
