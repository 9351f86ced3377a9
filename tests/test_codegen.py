"""bondc.codegen: the printer, the freezer, and the generated module.

The generated module is checked against independent references: the
StateSpace's own numeric evaluator (``ss.numeric()``, lambdify-based) for the
right-hand side at seeded random points, central finite differences for the
analytic Jacobian, and a subprocess in which ``import bondc`` fails for the
standalone run.
"""

import ast
import hashlib
import importlib
import json
import os
import re
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import pytest
import sympy

from bondc import causality, semantic
from bondc.codegen import emit
from bondc.codegen.emit import Namer
from bondc.codegen.freeze import Freezer
from bondc.codegen.printer import BondcPrinter, UnsupportedExpression
from bondc.symbolic import Step, Table

equations = importlib.import_module("bondc.equations")    # the stage: bondc.equations is the API's function

SIM = Path(__file__).parent / "fixtures" / "sim"
ROOT = Path(__file__).parent.parent


#: A script's lines that make bondc, sympy and lark unimportable (a machine without them).
_WITHOUT_BONDC = textwrap.dedent("""
    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("bondc", "sympy", "lark"):
                raise ImportError(name + " is not available here")
            return None

    sys.meta_path.insert(0, Block())
""")


def derive(name):
    graph, _ = semantic.load(SIM / f"{name}.bg", experiment=semantic.FIRST)
    ss = equations.derive(causality.assign_causality(graph))
    experiment = next(iter(graph.experiments.values()), None)
    return graph, ss, experiment


def load_module(source):
    namespace = {"__name__": "generated", "__file__": str(SIM / "generated.py")}
    exec(compile(source, "<generated>", "exec"), namespace)
    return namespace


# ------------------------------------------------------------------ printer

t, x, y = sympy.symbols("t x y", real=True)
m0, m1 = sympy.symbols("_m0 _m1", real=True)
NAMES = {t: "t", x: "x", y: "y", m0: "m[0]", m1: "m[1]"}


@pytest.mark.parametrize("expr, text", [
    (x**2, "x**2"),
    (1 / x, "1/x"),
    (x**-2, "1/x**2"),
    (1 / (x * y), "1/(x*y)"),
    (sympy.sqrt(x), "np.sqrt(x)"),
    (x**sympy.Rational(1, 3), "np.power(x, 1/3)"),
    (x**0.27, "np.power(x, 0.27)"),
    (sympy.Float(0.1) * x, "0.1*x"),
    (sympy.Float(4.06e-5) * x, "4.06e-05*x"),
    (sympy.pi * x, "np.pi*x"),
    (sympy.atan2(y, x), "np.arctan2(y, x)"),
    (sympy.Min(x, y, t), "np.minimum(np.minimum(t, x), y)"),
    (sympy.Piecewise((x, m0 < 0), (y, True)), "(x if (m[0] < 0) else y)"),
    (sympy.Piecewise((x, x < y), (y, True)), "np.where((x < y), x, y)"),
    (Table(t, sympy.Tuple(0, 1), sympy.Tuple(x, 2)), "table(t, (0, 1), (x, 2))"),
    (Step(t, y), "step(t, y)"),
])
def test_printer(expr, text):
    assert BondcPrinter(NAMES, mode_symbols={m0, m1}).doprint(expr) == text


def test_printer_prints_floats_exactly():
    value = 0.1 + 0.2
    printed = BondcPrinter(NAMES).doprint(sympy.Float(value) * x)
    assert float(printed.split("*")[0]) == value


def test_printer_refuses_unknown_symbols_and_functions():
    with pytest.raises(UnsupportedExpression, match="unknown symbol 'z'"):
        BondcPrinter(NAMES).doprint(sympy.Symbol("z") + x)
    with pytest.raises(UnsupportedExpression, match="unsupported function"):
        BondcPrinter(NAMES).doprint(sympy.Function("mystery")(x))


def test_namer_is_deterministic_and_avoids_clashes():
    namer = Namer({"m", "x"})
    assert [namer(n) for n in ["mass.p", "m", "x", "mass_p", "_a", "3d", "class"]] == \
        ["mass_p", "m_", "x_", "mass_p_", "u_a", "v3d", "class_"]


# ------------------------------------------------------------------ freezer

def test_freezer_shares_modes_and_labels_switches():
    f, v0, F0 = sympy.symbols("f v0 F0", real=True)
    freezer = Freezer(t, states={f}, parameters={v0, F0})
    law = sympy.Piecewise((5 * f, sympy.Abs(f) < v0), (f + F0 * sympy.sign(f), True))
    frozen = freezer.freeze(law, "R.e")
    # abs is continuous: evaluated as it is, never frozen; the if's condition is taken apart at
    # the kink of its abs (two smooth switching functions), and the sign is a switch
    assert [s.g for s in freezer.switches] == [v0 + f, v0 - f, f]
    assert all(s.event for s in freezer.switches)
    m2 = sympy.Symbol("_m2", real=True)
    assert frozen == sympy.Piecewise((5 * f, (m0 > 0) & (m1 > 0)), (f + F0 * m2, True))
    assert [s.label for s in freezer.switches] == ["if v0 > abs(f) (f < 0) in R.e", "if v0 > abs(f) (f >= 0) in R.e",
                                                   "sign(f) in R.e"]
    # the same sign elsewhere shares its mode; abs, min and max outside a condition never make a switch
    assert freezer.freeze(2 * sympy.sign(f) + sympy.Max(f, 0) + sympy.Abs(f - 1), "C.e") == \
        2 * m2 + sympy.Max(f, 0) + sympy.Abs(f - 1)
    assert len(freezer.switches) == 3


@pytest.mark.parametrize("condition", [
    lambda u, r: sympy.Abs(u) < r, lambda u, r: sympy.Abs(u) <= r, lambda u, r: sympy.Abs(u) > r,
    lambda u, r: sympy.Abs(u) >= r, lambda u, r: 2 * sympy.Abs(u - 1) - 3 * sympy.Abs(r) < u,
    lambda u, r: sympy.Max(u, r, 1) - sympy.Min(u, -r) >= 0.5, lambda u, r: -sympy.Abs(sympy.Abs(u) - 1) > r - 1,
    lambda u, r: sympy.Min(u, 2 * r) <= sympy.Abs(r)])
def test_a_condition_taken_apart_at_its_kinks_holds_exactly_where_the_written_one_does(condition):
    """The frozen condition, its modes set to the signs of their switching functions, against the
    condition as written, at a grid of values that includes the kinks and both signs of r."""
    u, r = sympy.symbols("u r", real=True)
    freezer = Freezer(t, states={u, r}, parameters=set())
    written = condition(u, r)
    frozen = freezer._condition(written)
    assert not any(s.g.has(sympy.Abs, sympy.Max, sympy.Min) for s in freezer.switches)
    values = [-2.5, -2, -1, -0.5, 0, 0.5, 1, 2, 3]
    for uv in values:
        for rv in values:
            point = {u: uv, r: rv}
            modes = {s.mode: int(np.sign(float(s.g.subs(point)))) for s in freezer.switches}
            assert bool(frozen.subs(modes)) == bool(written.subs(point)), (uv, rv)


def test_freezer_turns_time_switches_into_known_times():
    t1, k = sympy.symbols("t1 k", real=True)
    freezer = Freezer(t, states={x}, parameters={t1, k})
    freezer.freeze(Step(t, t1) + sympy.Piecewise((1, t < 2 * t1), (0, True)) + sympy.Piecewise((1, sympy.sin(t) > 0.5), (0, True)))
    freezer.freeze(Table(t, sympy.Tuple(0, t1), sympy.Tuple(0, k)))
    events = {s.g: s.event for s in freezer.switches}
    assert events == {t - t1: False, t - 2 * t1: False, sympy.sin(t) - 0.5: True}   # known, known, located
    assert sorted((str(b.time), b.kind) for b in freezer.time_breaks) == \
        [("0", "table"), ("2*t1", "if"), ("t1", "step"), ("t1", "table")]


def test_freezer_freezes_a_table_of_a_state_into_linear_pieces():
    freezer = Freezer(t, states={x}, parameters=set())
    frozen = freezer.freeze(Table(x, sympy.Tuple(0, 1, 2), sympy.Tuple(0, 10, 0)))
    assert [s.g for s in freezer.switches] == [x, x - 1, x - 2]
    m2 = sympy.Symbol("_m2", real=True)
    values = {x: 1.5, m0: 1, m1: 1, m2: -1}
    assert float(frozen.subs(values)) == pytest.approx(5.0)


# ----------------------------------------------------------- the module

def test_header_names_the_source_file_only():
    graph, ss, experiment = derive("msd")
    source = emit(ss, experiment)
    first = source.splitlines()[0]
    assert first == "# generated by bondc 0.1.0 from 'msd.bg' (model MassSpringDamper, experiment step) — do not edit"
    assert str(SIM) not in source


def test_module_imports_only_numpy_scipy_sundials_and_the_standard_library():
    _, ss, experiment = derive("friction")
    tree = ast.parse(emit(ss, experiment))
    imported, top_level = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module.split(".")[0])
    for node in tree.body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            top_level |= {(node.module if isinstance(node, ast.ImportFrom) else a.name).split(".")[0]
                          for a in node.names}
    standard = {"math", "os", "stat", "sys", "time", "argparse", "warnings", "csv", "importlib", "hashlib", "glob",
                "shutil", "subprocess", "tempfile", "atexit", "ast", "functools", "collections", "shlex", "json",
                "dataclasses", "weakref", "io"}
    optional = {"sksundae", "cffi", "platformdirs", "boost_headers", "pyarrow"}
    assert imported <= {"numpy", "scipy"} | standard | optional
    # SUNDIALS, cffi (native code), platformdirs (where native code is cached) and the Boost headers
    # (the explicit stepper's build), pyarrow (a .parquet result) are imported only where they are
    # used: without them the module loads, runs LSODA and its numpy code
    assert not top_level & optional


def test_module_constants():
    _, ss, experiment = derive("friction")
    module = load_module(emit(ss, experiment))
    assert module["STATE_NAMES"] == ("mass.p", "x")
    assert module["OUTPUT_NAMES"] == ("v", "Ff")
    assert module["PARAMETERS"] == {"m": 1.0, "F": 10.0, "v0": 1.0, "c0": 5.0, "c1": 1.0, "F0": 3.0}
    assert module["DEFAULTS"] == {"t_end": 2.0, "rtol": 1e-8, "atol": 1e-10}
    assert set(module["BOND_VARIABLES"]) == {"b1.e", "b1.f", "b2.e", "b2.f", "b3.e", "b3.f"}
    np.testing.assert_array_equal(module["x0"](), [0.0, 0.0])


@pytest.mark.slow
def test_emit_is_byte_identical_across_hash_seeds(tmp_path):
    script = tmp_path / "emit.py"
    script.write_text(textwrap.dedent(f"""
        import hashlib, sys
        from pathlib import Path
        import importlib
        from bondc import semantic, causality
        equations = importlib.import_module('bondc.equations')
        from bondc.codegen import emit
        for name in ("friction", "table_force"):
            graph, _ = semantic.load(Path({str(SIM)!r}) / (name + ".bg"), experiment=semantic.FIRST)
            ss = equations.derive(causality.assign_causality(graph))
            print(hashlib.sha256(emit(ss, next(iter(graph.experiments.values()))).encode()).hexdigest())
    """))
    digests = set()
    for seed in ("1", "12345"):
        env = dict(os.environ, PYTHONHASHSEED=seed)
        out = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, check=True)
        digests.add(out.stdout)
    assert len(digests) == 1
    graph, ss, experiment = derive("friction")
    assert hashlib.sha256(emit(ss, experiment).encode()).hexdigest() == digests.pop().split()[0]


@pytest.mark.parametrize("name", ["msd", "friction", "friction_stick", "table_force", "oscillator", "rc",
                                  "nonlinear_loop", "csv_force"])
def test_rhs_matches_the_statespace_evaluator_at_random_points(name):
    _, ss, experiment = derive(name)
    module = load_module(emit(ss, experiment))
    reference = ss.numeric()
    rng = np.random.default_rng(7)
    n = len(ss.states)
    for _ in range(40):
        t_point = rng.uniform(0.0, 2.0)
        state = rng.uniform(-3.0, 3.0, n)
        expected = reference.derivatives(t_point, state)
        np.testing.assert_allclose(module["rhs"](t_point, state), expected, rtol=1e-12, atol=1e-12)
        outputs = reference.outputs(t_point, state)
        np.testing.assert_allclose(module["outputs"](t_point, state), list(outputs.values()), rtol=1e-12,
                                   atol=1e-12)


@pytest.mark.parametrize("name", ["oscillator", "table_force", "rc"])
def test_derived_parameters_reproduce_the_checked_values(name):
    _, ss, experiment = derive(name)
    module = load_module(emit(ss, experiment))
    defaults = module["param_array"](module["PARAMETERS"])
    np.testing.assert_allclose(module["_derive_parameters"](defaults), defaults, rtol=1e-15)


def test_rhs_follows_the_language_at_a_switching_surface():
    # abs(f) < v0 is false at f = v0 exactly: the Coulomb branch applies
    _, ss, experiment = derive("friction")
    module = load_module(emit(ss, experiment))
    at_threshold = np.array([1.0, 0.0])     # p = m*v0
    np.testing.assert_allclose(module["rhs"](0.0, at_threshold), ss.numeric().derivatives(0.0, at_threshold))
    np.testing.assert_allclose(module["rhs"](0.0, at_threshold)[0], 10.0 - (1.0 + 3.0))


def test_event_functions_work_with_plain_solve_ivp():
    from scipy.integrate import solve_ivp

    _, ss, experiment = derive("friction")
    module = load_module(emit(ss, experiment))
    events = module["event_functions"]()
    assert len(events) == len(module["SWITCHES"]) == 3
    # switches 0 and 1 are the threshold abs(f) < v0 on each side of f = 0; switch 2 is sign(f), zero at
    # the start (solve_ivp would stop there)
    assert module["SWITCHES"][1] == "if v0 > abs(friction.f) (friction.f >= 0) in friction.e"
    solution = solve_ivp(lambda t, x: module["rhs"](t, x), (0.0, 1.0), [0.0, 0.0], events=events[1], rtol=1e-10,
                         atol=1e-12)
    assert solution.status == 1                                    # stopped by the threshold event
    assert solution.t_events[0][0] == pytest.approx(np.log(2) / 5, abs=1e-8)


@pytest.mark.parametrize("name", ["msd", "friction", "oscillator", "nonlinear_loop"])
def test_analytic_jacobian_matches_finite_differences(name):
    _, ss, experiment = derive(name)
    module = load_module(emit(ss, experiment))
    rng = np.random.default_rng(3)
    n = len(ss.states)
    for _ in range(20):
        t_point, state = rng.uniform(0.0, 2.0), rng.uniform(-3.0, 3.0, n)
        analytic = module["jacobian"](t_point, state)
        numeric = np.empty((n, n))
        for j in range(n):
            h = 1e-6 * max(1.0, abs(state[j]))
            up, down = state.copy(), state.copy()
            up[j] += h
            down[j] -= h
            numeric[:, j] = (module["rhs"](t_point, up) - module["rhs"](t_point, down)) / (2 * h)
        np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-8)


def test_equal_jacobian_entries_are_named_once_and_stay_right(tmp_path):
    """A Jacobian entry equal to one named before is that name: the entries of a uniform chain are
    a handful of expressions (-k, 1/m, b/m, ...) whatever its length, so the number of named entries
    does not grow with N (it grew by seven per section). The Jacobian still equals central
    differences of the right-hand side at random states (the chain is linear: exact but rounding)."""
    from benchmarks.chain import chain_source

    counts = []
    for sections in (4, 24):
        path = tmp_path / f"chain{sections}.bg"
        path.write_text(chain_source(sections), encoding="utf-8")
        graph, _ = semantic.load(path, experiment=semantic.FIRST)
        ss = equations.derive(causality.assign_causality(graph))
        source = emit(ss, next(iter(graph.experiments.values())))
        body = source[source.index("\ndef _jac("):]
        body = body[:body.index("\ndef ", 1)]
        counts.append(len(re.findall(r"^ +_d\d+ = ", body, flags=re.M)))
        module = load_module(source)
        rng = np.random.default_rng(sections)
        n = len(ss.states)
        for _ in range(3):
            state = rng.uniform(-1.0, 1.0, n)
            numeric = np.empty((n, n))
            for j in range(n):
                up, down = state.copy(), state.copy()
                up[j] += 1e-3
                down[j] -= 1e-3
                numeric[:, j] = (module["rhs"](0.1, up) - module["rhs"](0.1, down)) / 2e-3
            np.testing.assert_allclose(module["jacobian"](0.1, state), numeric, rtol=1e-9, atol=1e-9)
    assert 0 < counts[0] == counts[1] <= 10, counts


def test_generated_module_runs_without_bondc_and_matches_in_process(tmp_path):
    from bondc.simulate import simulate

    from bondc.pipeline import compile_file

    graph, ss, experiment = derive("friction")
    work = tmp_path / "elsewhere"
    work.mkdir()
    source = compile_file(SIM / "friction.bg", work / "friction_gen.py", standalone=True)
    assert (work / "friction_gen.py").read_text(encoding="utf-8") == source == emit(ss, experiment)
    (work / "launch.py").write_text(textwrap.dedent("""
        import importlib.abc, runpy, sys
    """) + _WITHOUT_BONDC + textwrap.dedent("""        try:
            import bondc
        except ImportError:
            print("bondc not importable")
        else:
            raise SystemExit("bondc is importable")
        sys.argv = ["friction_gen.py"] + sys.argv[1:]
        try:
            runpy.run_path("friction_gen.py", run_name="__main__")
        except SystemExit as done:
            assert "sympy" not in sys.modules and "bondc" not in sys.modules
            raise
    """))
    env = {key: value for key, value in os.environ.items() if not key.startswith("PYTHON")}
    env["PYTHONPATH"] = ""
    out = subprocess.run([sys.executable, "-I", "launch.py", "--dt", "0.01", "-o", "out.csv"], cwd=work, env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "bondc not importable"
    header = (work / "out.csv").read_text().splitlines()[0]
    assert header == "t [s],v [m/s],Ff [N],mass.p [kg*m/s],x [m]"        # units, as bondc simulate -o writes
    data = np.loadtxt(work / "out.csv", delimiter=",", skiprows=1)
    reference = simulate(ss, experiment, dt=0.01)
    np.testing.assert_allclose(data[:, 0], reference.t, rtol=0, atol=1e-15)
    np.testing.assert_allclose(data[:, 1], reference.outputs["v"], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(data[:, 3], reference.states["mass.p"], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(data[:, 4], reference.states["x"], rtol=1e-13, atol=1e-15)
    # the module carries bondc's C and C++ sources: in an empty cache folder it builds the CVODE
    # driver from them, where a C compiler and scikit-sundae's SUNDIALS are at hand (as here)
    from bondc import runtime

    (work / "native.py").write_text(textwrap.dedent("""
        import hashlib, importlib.abc, json, runpy, sys
    """) + _WITHOUT_BONDC + textwrap.dedent("""        module = runpy.run_path("friction_gen.py")
        assert "bondc" not in sys.modules
        run = module["simulate"]()
        print(json.dumps({"code": run.stats["code"], "note": run.stats.get("code_note", ""),
                          "driver_segments": run.stats.get("driver_segments", 0),
                          "files": sorted(module["_NATIVE_FILES"]),
                          "erk": hashlib.sha256(module["native_build_text"]("erk.cpp").encode()).hexdigest()}))
    """))
    env["BONDC_CACHE_DIR"] = str(tmp_path / "empty cache")
    out = subprocess.run([sys.executable, "-I", "native.py"], cwd=work, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    told = json.loads(out.stdout.splitlines()[-1])
    assert told["files"] == sorted(p.name for p in (ROOT / "bondc" / "native").iterdir()
                                   if p.suffix in (".c", ".h", ".cpp"))
    assert told["erk"] == hashlib.sha256(runtime.native_build_text("erk.cpp").encode()).hexdigest()
    if runtime.find_compiler("c")[0] is not None and runtime._sundials_link() is not None:
        assert told["code"] == "native", told["note"]
        assert told["driver_segments"] >= 1
        assert list((tmp_path / "empty cache" / "native").glob("model_*.so"))


@pytest.mark.slow
def test_generated_module_finds_its_csv_data_relative_to_itself(tmp_path):
    from bondc.simulate import simulate

    _, ss, experiment = derive("csv_force")
    work = tmp_path / "out"
    work.mkdir()
    source = emit(ss, experiment, module_dir=work)
    import re

    paths = set(re.findall(r"csv_signal\(t, DATA_DIR, '([^']*)'", source))
    assert len(paths) == 1 and not os.path.isabs(paths.pop())      # relative to the module, not absolute
    (work / "csv_gen.py").write_text(source, encoding="utf-8")
    env = {key: value for key, value in os.environ.items() if not key.startswith("PYTHON")}
    out = subprocess.run([sys.executable, "-I", "out/csv_gen.py", "--dt", "0.25"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=60)     # run from another directory
    assert out.returncode == 0, out.stderr
    data = np.loadtxt(out.stdout.splitlines()[1:], delimiter=",")
    reference = simulate(ss, experiment, dt=0.25)
    np.testing.assert_allclose(data[:, 2], reference.states["mass.p"], rtol=1e-13, atol=1e-15)
    # moved away from its data: a message and a hint, exit 2, no traceback; BONDC_DATA_DIR finds it again
    moved = tmp_path / "moved" / "deeper"
    moved.mkdir(parents=True)
    (moved / "csv_gen.py").write_text(source, encoding="utf-8")
    out = subprocess.run([sys.executable, "-I", str(moved / "csv_gen.py")], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert "cannot simulate" in out.stderr and "BONDC_DATA_DIR" in out.stderr
    out = subprocess.run([sys.executable, "-I", str(moved / "csv_gen.py"), "--dt", "0.25"], cwd=tmp_path,
                         env={**env, "BONDC_DATA_DIR": str(work)}, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr


def test_generated_module_copy_of_the_runtime_is_verbatim():
    """A standalone module carries every module of bondc/runtime, in order, verbatim but for its
    imports of the other runtime modules, which are commented out line for line."""
    from bondc.runtime import MODULES

    _, ss, experiment = derive("msd")
    source = emit(ss, experiment)
    at, commented = 0, 0
    for name in MODULES:
        text = (ROOT / "bondc" / "runtime" / f"{name}.py").read_text(encoding="utf-8")
        imports = {line for node in ast.parse(text).body if isinstance(node, ast.ImportFrom)
                   and node.module.startswith("bondc.runtime") for line in range(node.lineno, node.end_lineno + 1)}
        commented += len(imports)
        lines = ["# " + line if number in imports else line
                 for number, line in enumerate(text.splitlines(), start=1)]
        found = source.find("\n".join(lines), at)
        assert found > at, name
        at = found + len("\n".join(lines))
    assert commented > len(MODULES)
    assert "\nfrom bondc.runtime" not in source and "\nimport bondc" not in source


def test_a_module_compiled_with_its_runtime_once_per_process_is_the_whole_text_compiled():
    """compile_model compiles a module's copy of the runtime once per process (under runtime.py's
    own name and lines) and the rest numbered as in the whole text: the same functions at the
    same lines, and the same run to the bit, as the text compiled whole."""
    from bondc.simulate import _module_codes

    simulate_module = importlib.import_module("bondc.simulate")     # bondc.simulate is the API's function

    _, ss, experiment = derive("friction")
    source = emit(ss, experiment)
    whole = load_module(source)
    from bondc.runtime import MODULES

    codes = _module_codes(source, "<generated>")
    # compiled once: one code per runtime module, then the text before it and the model
    assert len(codes) == len(MODULES) + 2 and _module_codes(source, "<other>")[:-2] == codes[:-2]
    parts = {"__name__": "generated", "__file__": str(SIM / "generated.py")}
    for code in codes:
        exec(code, parts)
    functions = {name: value for name, value in whole.items() if isinstance(value, types.FunctionType)}
    assert functions and set(functions) == {name for name, value in parts.items()
                                            if isinstance(value, types.FunctionType)}
    runtime_files = {str(ROOT / "bondc" / "runtime" / f"{module}.py") for module in MODULES}
    source_lines = source.splitlines()
    for name, function in functions.items():
        mine = parts[name].__code__
        if mine.co_filename in runtime_files:       # the runtime's: its own file's line
            runtime_lines = Path(mine.co_filename).read_text(encoding="utf-8").splitlines()
            assert runtime_lines[mine.co_firstlineno - 1] in source_lines[function.__code__.co_firstlineno - 1:][:1]
        else:                                       # the model's: the line of the whole text
            assert (mine.co_filename, mine.co_firstlineno) == ("<generated>", function.__code__.co_firstlineno)
    assert parts["_rhs"].__code__.co_filename == "<generated>"
    assert parts["simulate_model"].__code__.co_filename == str(ROOT / "bondc" / "runtime" / "run.py")
    assert parts["load_csv"].__code__.co_filename == str(ROOT / "bondc" / "runtime" / "signals.py")
    assert parts["__doc__"] == whole["__doc__"]
    a = whole["simulate_model"](whole["_MODEL"], t_end=0.5, native=False)
    b = parts["simulate_model"](parts["_MODEL"], t_end=0.5, native=False)
    assert np.array_equal(a.t, b.t) and all(np.array_equal(a.states[k], b.states[k]) for k in a.states)
    # a text without the runtime's copy (another version's) is compiled whole
    assert len(_module_codes(source.replace("def simulate_model(", "def simulate_model_(", 1), "<x>")) == 1
    assert simulate_module._RUNTIME_CODE["codes"] == codes[:len(MODULES)]


def test_model_code_golden(update_golden):
    """The model section generated for msd.bg (``pytest --update-golden`` rewrites it)."""
    _, ss, experiment = derive("msd")
    source = emit(ss, experiment)
    model_part = source[source.index("MODEL_NAME = "):]
    golden = SIM / "msd.expected.py.txt"
    if update_golden or not golden.exists():
        golden.write_text(model_part, encoding="utf-8")
    assert model_part == golden.read_text(encoding="utf-8")


HOSTILE_NAMES = [
    'q""";import os;os.system("touch PWNED");"""x.bg',
    "line\nimport os; os.system('touch PWNED')\n#.bg",
    "sep\u2028import os; os.system('touch PWNED')\u2029.bg",
    "back\\slash'quote\"x.bg",
]


@pytest.mark.parametrize("name", [HOSTILE_NAMES[0]] + [pytest.param(name, marks=pytest.mark.slow)
                                                          for name in HOSTILE_NAMES[1:]],
                         ids=["triple-quotes", "newline", "line-separators", "quotes"])
@pytest.mark.parametrize("standalone", [pytest.param(False, marks=pytest.mark.slow), True],
                         ids=["imports-runtime", "standalone"])
def test_a_hostile_file_name_never_runs_as_code(tmp_path, monkeypatch, name, standalone):
    from bondc.pipeline import compile_file

    model = tmp_path / name
    model.write_text((SIM / "msd.bg").read_text())
    monkeypatch.chdir(tmp_path)
    source = compile_file(model, tmp_path / "module.py", standalone=standalone)
    compile(source, "module.py", "exec")            # valid Python whatever the name
    marker = tmp_path / "PWNED"
    result = subprocess.run([sys.executable, str(tmp_path / "module.py"), "--t-end", "0.5", "--dt", "0.25"],
                            capture_output=True, text=True, cwd=tmp_path, check=True)
    assert not marker.exists()
    module = load_module(source)
    assert not marker.exists()
    assert module["SOURCE_FILE"] == name
    # and the module still computes the model: the same rows as the one from a plain name
    plain = tmp_path / "plain.bg"
    plain.write_text((SIM / "msd.bg").read_text())
    compile_file(plain, tmp_path / "plain_module.py", standalone=standalone)
    expected = subprocess.run([sys.executable, str(tmp_path / "plain_module.py"), "--t-end", "0.5", "--dt", "0.25"],
                              capture_output=True, text=True, cwd=tmp_path, check=True)
    assert result.stdout == expected.stdout and result.stdout.count("\n") == 4      # header and 3 rows


# ------------------------------------------------------------------ the quick printing path

def _printable_models():
    """Every model of models/ and tests/ that derives: the corpus the quick path is checked on."""
    paths = sorted(p for p in [*ROOT.glob("models/*.bg"), *ROOT.glob("tests/**/*.bg")] if p.is_file())
    return [p for p in paths if "std" not in p.parts]


@pytest.mark.parametrize("expr", [
    x * y, -x * y, 2 * x * y, -2 * x, sympy.Float(-1.0) * x, sympy.Float(1e9) * x, sympy.Float(0.1) + x, sympy.Float(1.0) * x * y, sympy.Float(-2.5) * x / y,
    -1 / x, 1 / (x * y), -x / (y * t), x / y**2, -x**3 / y**2, x**2 * y, 3 / x, sympy.Float(0.5) / (x * y**2),
    x - y, -x - y, x - 2 * y + t, sympy.Float(-0.1) + x, 2 - x, -x + y**2 / t - 3, x * y - t / x,
    sympy.Integer(-4), sympy.Float(-1e-300), x**-2, x**5,
])
def test_quick_printing_writes_what_sympy_writes(expr):
    from bondc.codegen.cprinter import NativePrinter

    from bondc.codegen.emit import _LawPrinter

    for printer in (BondcPrinter(NAMES), NativePrinter({s: f"v_{n[0]}" for s, n in NAMES.items()}), _LawPrinter()):
        assert printer.quick(expr) == printer.doprint(expr)


def test_quick_printing_declines_what_it_does_not_know():
    from bondc.codegen.cprinter import NativePrinter

    z = sympy.Symbol("z", real=True)        # not in the name table: doprint refuses it
    for expr in (sympy.sqrt(x), sympy.Rational(1, 3) * x, x + z, sympy.Piecewise((x, m0 < 0), (y, True)) + y,
                 sympy.Float("nan") * x, sympy.pi * x, (x + y) ** 2, x**y):
        assert BondcPrinter(NAMES).quick(expr) is None
        assert NativePrinter(NAMES).quick(expr) is None


@pytest.mark.slow
def test_quick_printing_equals_sympys_printing_on_every_model(monkeypatch):
    """Every expression the quick path prints, in every generated function (numpy and C) and law
    text (VARIABLE_LAWS) of every model of the corpus, is compared with sympy's own printing of it."""
    from bondc.codegen.printer import QuickPrinting
    from bondc.errors import BondcError

    quick = QuickPrinting.quick
    compared, printers = [], set()

    def checked(self, expr):
        text = quick(self, expr)
        if text is not None:
            assert text == self.doprint(expr), (type(self).__name__, expr)
            compared.append(text)
            printers.add(type(self).__name__)
        return text

    monkeypatch.setattr(QuickPrinting, "quick", checked)
    models = 0
    for path in _printable_models():
        try:
            graph, _ = semantic.load(path, experiment=semantic.FIRST)
            ss = equations.derive(causality.assign_causality(graph))
        except BondcError:
            continue                # a model the corpus keeps for its error
        emit(ss, next(iter(graph.experiments.values()), None))
        models += 1
    assert models >= 40 and len(compared) > 2000
    assert {"_LawPrinter", "BondcPrinter", "NativePrinter"} <= printers


@pytest.mark.slow
def test_common_subexpressions_are_sympys_on_every_model(monkeypatch):
    """bondc's tree cse (which keeps a node whose arguments did not change, where sympy rebuilds
    every node, and never makes 1/name or -name a temporary) finds sympy's ``tree_cse``
    temporaries, with the same expressions once sympy's temporaries for 1/name and -name are put
    back, on every pass of every model of the corpus."""
    from sympy.simplify.cse_main import tree_cse

    from bondc.errors import BondcError

    emit_module = sys.modules["bondc.codegen.module"]       # where the emitter reads _cse
    ours = emit_module._cse
    passes = []

    def of_a_name(expr, temporaries):
        """1/x or -x of a name of the model (not of a temporary)"""
        if expr.is_Pow and expr.exp == -1:
            return expr.base.is_Symbol and expr.base not in temporaries
        return (expr.is_Mul and len(expr.args) == 2 and expr.args[0] == -1 and expr.args[1].is_Symbol
                and expr.args[1] not in temporaries)

    def without_reciprocals(replacements, reduced):
        """sympy's result with its temporaries for reciprocals and negations of names put back"""
        back, kept, temporaries = {}, [], {symbol for symbol, _ in replacements}
        for symbol, expr in replacements:
            expr = expr.xreplace(back)
            if of_a_name(expr, temporaries):
                back[symbol] = expr
            else:
                kept.append((symbol, expr))
        return kept, [expr.xreplace(back) for expr in reduced]

    def compared(exprs):
        replacements, reduced = ours(exprs)
        expected, expected_reduced = without_reciprocals(
            *tree_cse(exprs, sympy.numbered_symbols("_c", real=True), {}, "none", ()))
        assert len(replacements) == len(expected)
        rename = {theirs: mine for (theirs, _), (mine, _) in zip(expected, replacements)}
        assert replacements == [(rename[symbol], expr.xreplace(rename)) for symbol, expr in expected]
        assert reduced == [expr.xreplace(rename) for expr in expected_reduced]
        temporaries = {symbol for symbol, _ in replacements}
        assert not any(of_a_name(expr, temporaries) for _, expr in replacements)
        passes.append(len(replacements))
        return replacements, reduced

    monkeypatch.setattr(emit_module, "_cse", compared)
    for path in _printable_models():
        try:
            graph, _ = semantic.load(path, experiment=semantic.FIRST)
            ss = equations.derive(causality.assign_causality(graph))
        except BondcError:
            continue
        emit(ss, next(iter(graph.experiments.values()), None))
    assert len(passes) > 80 and sum(passes) > 50       # passes that found temporaries were compared


def test_symbols_are_ordered_as_sympys_default_sort_key_orders_them():
    from bondc.codegen.emit import _ordered

    rng = np.random.default_rng(5)
    names = ["mass.p", "mass_p", "m10", "m9", "A", "a", "b3_f", "b12_f", "_c0", "Z.q"]
    symbols = [sympy.Symbol(name, real=True) for name in names] + [sympy.Symbol("plain")]
    for _ in range(20):
        chosen = set(rng.choice(symbols, size=6, replace=False))
        assert _ordered(chosen) == sorted(chosen, key=sympy.default_sort_key)
    twins = {sympy.Dummy("x"), sympy.Dummy("x"), sympy.Symbol("x")}
    assert _ordered(twins) == sorted(twins, key=sympy.default_sort_key)


@pytest.mark.parametrize("a", [sympy.Integer(-1), sympy.Integer(3), sympy.Float(2.5), sympy.Float(-1.0),
                               sympy.Float(1.0), sympy.Integer(0), sympy.Rational(1, 3), x + 1, sympy.oo])
def test_the_jacobians_products_are_sympys(a):
    from bondc.codegen.emit import _times

    product = _times(a, y)
    assert product == a * y and hash(product) == hash(a * y) and product.args == (a * y).args
    assert product + y == a * y + y


def test_quick_printing_leaves_unevaluated_products_to_sympy():
    from bondc.codegen.cprinter import NativePrinter
    from bondc.codegen.emit import _LawPrinter

    for expr in (sympy.Mul(x, 2, evaluate=False), sympy.Mul(1, x, evaluate=False),
                 sympy.Mul(x, sympy.Float(0.5), y, evaluate=False)):
        for printer in (BondcPrinter(NAMES), NativePrinter(NAMES), _LawPrinter()):
            assert printer.quick(expr) is None
            assert printer.doprint(expr)        # sympy prints it


@pytest.mark.slow
@pytest.mark.parametrize("name", ["models/electro_pneumatic_hybrid.bg", "tests/fixtures/engine/diode_bridge.bg",
                                  "models/mass_spring_damper.bg", "CHAIN"])
def test_variables_that_share_a_row_of_the_result_are_equal_in_every_mode(name, tmp_path):
    """``VARIABLE_ROWS`` groups the variables that ``_variables`` returns as one expression (a
    junction's common effort or flow): the result keeps one row for them. Checked against the
    generated function itself, at random states in random mode vectors (every branch of every
    law), and in the result of a run: the shared rows are the same numbers, read-only."""
    from benchmarks.chain import chain_source
    from bondc.pipeline import derive_file
    from bondc.simulate import compile_model

    path = ROOT / name
    if name == "CHAIN":
        path = tmp_path / "chain.bg"
        path.write_text(chain_source(10), encoding="utf-8")
    derived = derive_file(path, cache=False)
    namespace = compile_model(derived.state_space)
    names, rows = namespace["VARIABLE_NAMES"], namespace["VARIABLE_ROWS"]
    assert len(rows) == len(names) and sorted(set(rows)) == list(range(max(rows) + 1))
    if name == "CHAIN":     # 12N + 1 variables, of which each junction's common ones are one row
        assert (len(names), len(set(rows))) == (121, 60)
    p = np.array(list(namespace["PARAMETERS"].values()), dtype=float)
    if namespace.get("_derive_parameters") is not None:
        p = namespace["_derive_parameters"](p)
    rng = np.random.default_rng(3)
    n, k = len(namespace["STATE_NAMES"]), len(namespace["SWITCHES"])
    for _ in range(12):
        t = rng.uniform(0.0, 2.0, 5)
        x = rng.normal(size=(n, 5)) * rng.uniform(0.01, 10.0)
        m = rng.choice([-1.0, 1.0], size=k) if k else np.zeros(0)
        with np.errstate(all="ignore"):     # point by point (a model with a loop is not vectorized)
            values = np.array([np.asarray(namespace["_variables"](t[j], x[:, j], p, m), dtype=float)
                               for j in range(t.size)]).T
        first = {}
        for i, row in enumerate(rows):
            j = first.setdefault(row, i)
            assert np.array_equal(values[i], values[j], equal_nan=True), (names[i], names[j])
    experiment = derived.experiment
    result = namespace["simulate_model"](namespace["_MODEL"], t_end=min(experiment.t_end, 0.5), method="CVODE",
                                         rtol=experiment.rtol, atol=experiment.atol, max_step=experiment.max_step)
    for i, row in enumerate(rows):
        j = rows.index(row)
        assert np.shares_memory(result.variables[names[i]], result.variables[names[j]])
    column = result.variables[names[0]]
    assert not column.flags.writeable
    with pytest.raises(ValueError):
        column[0] = 1.0
