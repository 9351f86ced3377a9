"""The compile cache: a second run of an unchanged model skips every compile stage; any change
to the model, its imports, the options or bondc itself is a miss; a broken cache is never an error."""

from __future__ import annotations

import importlib
import json
import os
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

from bondc import cache, runtime, semantic
from bondc.pipeline import derive_file
from bondc.simulate import simulate

MODEL = """fn square(x) = x*x
model Drive "mass, spring and damper"
  param m = 2 [kg]
  param k = 800 [N/m]
  param b = {b} [N*s/m]
  Se force : e = 10*step(t, 0.1)
  I mass : f = p/m
  C spring : e = k*q
  R damper : e = b*f
  1 j
  force -> j
  j -> mass
  j -> spring
  j -> damper
  output x [m] = spring.q
  experiment step
    t_end = 1 [s]
  end
end
"""


@pytest.fixture
def isolated(tmp_path, monkeypatch):
    """An empty cache folder of this test's own, and a counter of semantic loads."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("BONDC_CACHE_DIR", str(folder))
    monkeypatch.delenv("BONDC_CACHE", raising=False)
    loads = []
    real = semantic.load

    def counting(*args, **kwargs):
        loads.append(args[0])
        return real(*args, **kwargs)

    monkeypatch.setattr(semantic, "load", counting)
    return folder, loads


def _write(path, b=12):
    path.write_text(MODEL.format(b=b), encoding="utf-8")
    return path


def test_a_second_run_of_an_unchanged_model_skips_every_stage(tmp_path, isolated, monkeypatch):
    folder, loads = isolated
    path = _write(tmp_path / "drive.bg")
    first = derive_file(path)
    result = simulate(first.state_space, first.experiment)
    assert len(loads) == 1
    assert (folder / "models").is_dir()
    assert not [p for p in tmp_path.iterdir() if p.name not in ("drive.bg", "cache")]   # nothing beside the model

    def no_codegen(*args, **kwargs):
        raise AssertionError("the generated module should come from the cache")

    monkeypatch.setattr("bondc.codegen.emit", no_codegen)
    second = derive_file(path)
    assert len(loads) == 1                           # not parsed or checked again
    assert second.state_space is not first.state_space
    assert [s.name for s in second.state_space.states] == [s.name for s in first.state_space.states]
    again = simulate(second.state_space, second.experiment)
    np.testing.assert_array_equal(again.t, result.t)
    np.testing.assert_array_equal(again.states["spring.q"], result.states["spring.q"])


def test_an_edit_options_or_no_cache_are_misses(tmp_path, isolated):
    _, loads = isolated
    path = _write(tmp_path / "drive.bg")
    derive_file(path)
    derive_file(path, sets=["k=400"])                  # other values: checked with them (bound late)
    assert len(loads) == 2
    assert derive_file(path, sets=["k=400"]).graph.parameters["k"].value == 400.0
    assert len(loads) == 3
    _write(path, b=30)                                 # the file changed
    assert derive_file(path).graph.parameters["b"].value == 30.0
    assert len(loads) == 4
    derive_file(path, cache=False)
    assert len(loads) == 5


@pytest.mark.slow
def test_set_values_are_bound_late_to_the_cached_model_with_the_same_results(tmp_path, isolated, monkeypatch):
    """--set k=400 on a cached model: checked with the value, not derived or generated again; the run
    equals a derivation from scratch with the value (no cache), point for point."""
    path = _write(tmp_path / "drive.bg")
    base = derive_file(path)
    simulate(base.state_space, base.experiment)          # its module is in the cache now
    scratch = derive_file(path, sets=["k=400", "b=20 [N*s/m]"], cache=False)
    expected = simulate(scratch.state_space, scratch.experiment)

    def no_derivation(*args, **kwargs):
        raise AssertionError("the equations should not be derived again")

    monkeypatch.setattr(importlib.import_module("bondc.equations"), "derive", no_derivation)    # not the API's
    monkeypatch.setattr("bondc.codegen.emit", no_derivation)
    bound = derive_file(path, sets=["k=400", "b=20 [N*s/m]"])
    assert bound.state_space.parameters["k"][1] == 400.0 and bound.graph.parameters["b"].value == 20.0
    result = simulate(bound.state_space, bound.experiment)
    np.testing.assert_array_equal(result.t, expected.t)
    np.testing.assert_array_equal(result.outputs["x"], expected.outputs["x"])
    # the step response of m x'' + b x' + k x = 10 N from t = 0.1 s, with the bound values
    m, b, k, tau = 2.0, 20.0, 400.0, 1.0 - 0.1
    wn, zeta = np.sqrt(k / m), b / (2 * np.sqrt(k * m))
    wd = wn * np.sqrt(1 - zeta ** 2)
    x = 10 / k * (1 - np.exp(-zeta * wn * tau) * (np.cos(wd * tau) + zeta / np.sqrt(1 - zeta ** 2) * np.sin(wd * tau)))
    assert result.outputs["x"][-1] == pytest.approx(x, rel=1e-4)


@pytest.mark.slow
def test_a_changed_import_is_a_miss(tmp_path, isolated):
    _, loads = isolated
    library = tmp_path / "lib.bg"
    library.write_text("fn gain(x) = 2*x\n", encoding="utf-8")
    path = tmp_path / "main.bg"
    path.write_text('import "lib.bg"\n' + MODEL.replace("e = 10*step(t, 0.1)", "e = gain(5)*step(t, 0.1)")
                    .format(b=12), encoding="utf-8")
    derive_file(path)
    derive_file(path)
    assert len(loads) == 1
    library.write_text("fn gain(x) = 3*x\n", encoding="utf-8")
    changed = derive_file(path)
    assert len(loads) == 2
    result = simulate(changed.state_space, changed.experiment)
    # the force is now 15 N, not 10: the first peak of the step response (zeta = 0.15, overshoot
    # exp(-pi*zeta/sqrt(1 - zeta^2)) = 62 %) is 1.62*15/800 = 30 mm, not 20 mm
    overshoot = np.exp(-np.pi * 0.15 / np.sqrt(1 - 0.15 ** 2))
    assert result.states["spring.q"].max() == pytest.approx((1 + overshoot) * 15 / 800, rel=0.01)


@pytest.mark.slow
def test_a_simulation_after_an_edit_of_an_import_runs_the_edited_model_not_the_cached_module(
        tmp_path, isolated, capsys):
    """A spring defined in an imported file: after a cached simulate, its stiffness (then its law)
    is edited there. The entry is derived again; the module, its compiled code and the light entry
    made from the old derivation must go with it. The static deflection is F/k each time."""
    from bondc.cli import main

    (tmp_path / "lib").mkdir()
    library = tmp_path / "lib" / "spring.bg"
    library.write_text("model Spring\n  port a\n  param k = 800 [N/m]\n  C s : e = k*q\n  a -> s\nend\n")
    path = tmp_path / "imp.bg"
    path.write_text('''import "lib/spring.bg"
model Imp
  Se F : e = 10
  I m : f = p/2
  R d : e = 40*f
  Spring sp
  1 j
  F -> j
  j -> m
  j -> d
  j -> sp.a
  output x [m] = sp.s.q
  experiment settle
    t_end = 5 [s]
  end
end
''')

    def final_x():
        assert main(["simulate", str(path), "--json"]) == 0
        summary = json.loads(capsys.readouterr().out)
        return summary["statistics"]["x"]["final"], summary["parameters"]["sp.k"]

    assert final_x() == (pytest.approx(10 / 800, rel=1e-4), 800)
    assert final_x() == (pytest.approx(10 / 800, rel=1e-4), 800)          # the cached module
    library.write_text(library.read_text().replace("800", "3200"))
    assert final_x() == (pytest.approx(10 / 3200, rel=1e-4), 3200)
    library.write_text(library.read_text().replace("k*q", "4*k*q"))
    assert final_x() == (pytest.approx(10 / 12800, rel=1e-4), 3200)


def test_the_environment_turns_the_cache_off(tmp_path, isolated, monkeypatch):
    _, loads = isolated
    monkeypatch.setenv("BONDC_CACHE", "0")
    path = _write(tmp_path / "drive.bg")
    derive_file(path)
    derive_file(path)
    assert len(loads) == 2


def test_a_corrupt_entry_is_a_miss_not_an_error(tmp_path, isolated):
    folder, loads = isolated
    path = _write(tmp_path / "drive.bg")
    derive_file(path)
    for pickled in folder.glob("models/*/derived.pickle"):
        pickled.write_bytes(b"not a pickle")
    derived = derive_file(path)
    assert len(loads) == 2 and derived.graph.name == "Drive"
    assert derive_file(path) is not None and len(loads) == 2     # rewritten by the second run


@pytest.mark.skipif(sys.platform == "win32" or os.geteuid() == 0, reason="needs a folder the user cannot write")
def test_an_unwritable_cache_folder_only_means_no_cache(tmp_path, isolated, monkeypatch):
    _, loads = isolated
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(stat.S_IRUSR | stat.S_IXUSR)
    monkeypatch.setenv("BONDC_CACHE_DIR", str(locked / "cache"))
    try:
        path = _write(tmp_path / "drive.bg")
        derived = derive_file(path)
        assert simulate(derived.state_space, derived.experiment).complete
        derive_file(path)
        assert len(loads) == 2
    finally:
        locked.chmod(stat.S_IRWXU)


def test_the_key_covers_bondc_itself(tmp_path, isolated, monkeypatch):
    _, loads = isolated
    path = _write(tmp_path / "drive.bg")
    derive_file(path)
    monkeypatch.setattr(cache, "_CODE_HASH", ["another bondc"])
    derive_file(path)
    assert len(loads) == 2


def test_the_cli_option(tmp_path, isolated, capsys):
    from bondc.cli import main

    _, loads = isolated
    path = _write(tmp_path / "drive.bg")
    assert main(["equations", str(path)]) == 0
    assert main(["equations", str(path)]) == 0
    assert len(loads) == 1
    assert main(["equations", str(path), "--no-cache"]) == 0
    assert len(loads) == 2
    assert "der(mass.p)" in capsys.readouterr().out


# -- the light entry: a cached simulate without sympy or lark

def _energy_models():
    root = Path(__file__).resolve().parent.parent
    return sorted([*root.glob("models/*.bg"), *(root / "tests" / "fixtures" / "engine").glob("*.bg")])


@pytest.mark.parametrize("path", _energy_models(), ids=lambda p: p.stem)
def test_every_stored_energy_function_is_rebuilt_from_its_recipe_to_the_same_numbers(path):
    from bondc.analysis.energy import energy_from_recipe, energy_recipes, stored_energy_functions

    derived = derive_file(path, cache=False)
    functions = stored_energy_functions(derived.state_space, {})
    recipes = energy_recipes(functions)
    assert recipes is not None and set(recipes) == set(functions)
    for name, (kind, state, recipe) in recipes.items():
        rebuilt = energy_from_recipe(kind, state, recipe)
        original = functions[name]
        assert (rebuilt.kind, rebuilt.state_name) == (original.kind, original.state_name)
        for x in (-2.5e-3, -0.7, 0.0, 0.3, 4.0e2):        # negative, zero and positive states
            with np.errstate(all="ignore"):
                a = original.function(x) if original.kind == "analytic" else original.law(x)
                b = rebuilt.function(x) if rebuilt.kind == "analytic" else rebuilt.law(x)
            assert float(a) == float(b) or (np.isnan(float(a)) and np.isnan(float(b))), (name, x)


_IMPORTED = ("import sys\nfrom bondc.cli import main\ncode = main(sys.argv[1:])\n"
             "print('IMPORTED', sorted(m for m in ('sympy', 'lark', 'bondc.statespace') if m in sys.modules))\n"
             "print('SCIPY', sorted(m for m in ('scipy.optimize', 'scipy.integrate', 'scipy.interpolate',\n"
             "                                   'scipy.linalg', 'scipy.special') if m in sys.modules))\n"
             "sys.exit(code)\n")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["models/electro_pneumatic_hybrid.bg", "tests/fixtures/engine/hydraulic_chamber.bg"])
def test_a_cached_simulate_imports_no_sympy_or_lark_and_writes_the_same_results(tmp_path, name):
    import subprocess

    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "BONDC_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("BONDC_CACHE", None)
    runs = []
    for index in range(3):      # compiled (and the light entry written); light; light again
        out = tmp_path / f"run{index}.csv"
        done = subprocess.run([sys.executable, "-c", _IMPORTED, "simulate", str(root / name), "-o", str(out)],
                              capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
        assert done.returncode == 0, done.stderr
        text = done.stdout.replace(str(out), "OUT")
        summary, imported = text.split("IMPORTED")
        imported, scipy_modules = imported.split("SCIPY")
        runs.append((out.read_bytes(), summary, imported.strip(), scipy_modules.strip()))
    assert runs[0][0] == runs[1][0] == runs[2][0]       # byte-identical results
    assert runs[0][1] == runs[1][1] == runs[2][1]       # and the same summary and energy tables
    assert "Energy account" in runs[2][1]
    assert runs[0][2] == "['bondc.statespace', 'lark', 'sympy']"
    assert runs[1][2] == runs[2][2] == "[]"
    if runtime._sundials_link() is not None and runtime._scipy_kernel("optimize", "_zeros", runtime._zeros_probe):
        # on bondc's C driver the run, its events and its energy account (Brent's method,
        # QUADPACK, the splines of sliding spans) need none of scipy's 0.5 s of imports
        assert runs[1][3] == runs[2][3] == "[]"


@pytest.mark.slow
def test_the_light_entry_gives_the_full_state_space_for_other_parameter_values(tmp_path, isolated):
    from bondc.analysis.energy import energy_account
    from bondc.simulate import compile_model

    path = _write(tmp_path / "drive.bg")
    full = derive_file(path)
    result = simulate(full.state_space, full.experiment)
    account = energy_account(full.state_space, result)
    entry = cache.entry_of(full.state_space)
    assert account.energy_recipes is not None and entry is not None
    entry.write_module(compile_model(full.state_space)["__bondc_source__"])
    entry.store_light(full, account.energy_recipes)
    light = derive_file(path, light=True)
    assert isinstance(light.state_space, cache.LightStateSpace)
    from bondc.analysis.energy import energy_from_recipe

    recipes = light.state_space.light_recipes({})
    same = {name: energy_from_recipe(*recipe) for name, recipe in recipes.items()}
    assert set(same) == {"mass", "spring"} and same["spring"].function(0.01) == pytest.approx(800 * 0.01 ** 2 / 2)
    assert light.state_space.light_recipes({"k": 900.0}) is None      # numbers printed for k = 800
    rerun = simulate(light.state_space, light.experiment, overrides={"k": 900.0})
    other = energy_account(light.state_space, rerun)                   # from the full state space
    direct = energy_account(full.state_space, simulate(full.state_space, full.experiment, overrides={"k": 900.0}))
    assert other.to_json() == direct.to_json()
    assert light.state_space.full() is not None and light.state_space.derivatives.keys() == \
        full.state_space.derivatives.keys()


@pytest.mark.slow
def test_a_corrupt_light_entry_is_a_miss_and_the_full_entry_is_read(tmp_path, isolated):
    from bondc.analysis.energy import energy_account
    from bondc.simulate import compile_model

    path = _write(tmp_path / "drive.bg")
    full = derive_file(path)
    account = energy_account(full.state_space, simulate(full.state_space, full.experiment))
    entry = cache.entry_of(full.state_space)
    entry.write_module(compile_model(full.state_space)["__bondc_source__"])
    entry.store_light(full, account.energy_recipes)
    assert isinstance(derive_file(path, light=True).state_space, cache.LightStateSpace)
    light = entry.folder / "light.pickle"
    light.write_bytes(light.read_bytes()[:40])          # a partial write
    again = derive_file(path, light=True)
    assert not isinstance(again.state_space, cache.LightStateSpace)
    assert again.state_space.state_names == full.state_space.state_names


_CHECK = ("import sys\nfrom bondc.cli import main\ncode = main(sys.argv[1:])\n"
          "print('SYMPY', 'sympy' in sys.modules, 'numpy' in sys.modules)\nsys.exit(code)\n")

_NOT_INVERTIBLE = """model Friction
  Sf pump     : f = 2
  R  friction : e = 3*abs(f)^1.5*sign(f)
  C  tank     : e = q/0.5
  0  node
  pump -> node
  node -> friction
  node -> tank
end
"""


def _check_runs(tmp_path, path, *options):
    import subprocess

    env = {**os.environ, "BONDC_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("BONDC_CACHE", None)
    done = subprocess.run([sys.executable, "-c", _CHECK, "check", str(path), *options], capture_output=True,
                          text=True, env=env, cwd=tmp_path, timeout=300)
    output, imported = done.stdout.rsplit("SYMPY", 1)
    sympy, numpy = imported.split()
    return done.returncode, output, done.stderr, sympy == "True", numpy == "True"


@pytest.mark.slow
def test_a_second_check_of_unchanged_files_reports_the_same_without_sympy(tmp_path):
    """check runs the equations stage (E605, the states kept) once per content of the files: the
    next check of the same files reports the same, text and JSON, and imports no sympy (nor numpy,
    for a model that reads no csv file); an edit that makes a law not invertible is reported at
    once; --no-cache always decides afresh. A model whose stage has certainly nothing to report
    (bondc.quickcheck: here a linear law to invert) is checked without sympy even the first time."""
    path = tmp_path / "cubic.bg"
    path.write_text(_NOT_INVERTIBLE.replace("e = 3*abs(f)^1.5*sign(f)", "e = 3*f^3 + f"), encoding="utf-8")
    first = _check_runs(tmp_path, path, "--json")
    again = _check_runs(tmp_path, path, "--json")
    assert first[0] == again[0] == 0 and first[1] == again[1] and first[3] and not again[3]
    assert not again[4]
    assert '"states_kept": 1' in again[1]
    assert _check_runs(tmp_path, path)[1] == _check_runs(tmp_path, path, "--no-cache")[1]
    assert _check_runs(tmp_path, path, "--no-cache")[3]
    path.write_text(_NOT_INVERTIBLE, encoding="utf-8")
    for expected_sympy in (True, False):
        code, _, stderr, imported, _ = _check_runs(tmp_path, path)
        assert code == 1 and "E605" in stderr and imported == expected_sympy
    path.write_text(_NOT_INVERTIBLE.replace("e = 3*abs(f)^1.5*sign(f)", "e = 3*f"), encoding="utf-8")
    for options in ((), ("--no-cache",)):
        code, output, stderr, imported, _ = _check_runs(tmp_path, path, *options)
        assert code == 0 and "E605" not in stderr and not imported
    msd = _write(tmp_path / "msd.bg")
    code, output, _, imported, _ = _check_runs(tmp_path, msd, "--no-cache")
    assert code == 0 and "2 states" in output and not imported
    # --json also lists the model's switches (its force's step): that derives the model, once per
    # content of the files
    code, output, _, imported, _ = _check_runs(tmp_path, msd, "--json")
    assert code == 0 and '"states_kept": 2' in output and '"kind": "jump (known times)"' in output and imported
    code, again, _, imported, _ = _check_runs(tmp_path, msd, "--json")
    assert again == output and not imported


def test_the_cache_folder_is_the_runtimes(tmp_path, monkeypatch):
    """``bondc.cache.cache_dir`` writes out the runtime's rule (the runtime imports numpy, which
    ``check`` does not need): both give the same folder, with and without ``BONDC_CACHE_DIR``."""
    from bondc import runtime

    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path / "here"))
    assert cache.cache_dir() == Path(runtime.cache_dir()) == tmp_path / "here"
    monkeypatch.delenv("BONDC_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.cache_dir() == Path(runtime.cache_dir())
    assert str(cache.cache_dir()).startswith(str(tmp_path / "xdg"))


@pytest.mark.slow
def test_the_generated_module_is_kept_compiled_and_checked_against_its_text(tmp_path, isolated, monkeypatch):
    """The entry keeps the module compiled by this Python (as a ``.pyc``): the next process runs it
    without compiling, with the same results; a damaged file, or a text that does not match the
    one it was compiled from, is compiled again."""
    simulate_module = importlib.import_module("bondc.simulate")     # bondc.simulate is the API's function

    path = _write(tmp_path / "drive.bg")
    first = derive_file(path)
    result = simulate(first.state_space, first.experiment)
    (kept,) = list((isolated[0] / "models").glob(f"*/module.{sys.implementation.cache_tag}.code"))
    compiled = []
    real_compile = compile

    def counting(*args, **kwargs):
        compiled.append(args[1])
        return real_compile(*args, **kwargs)

    monkeypatch.setattr(cache, "compile", counting, raising=False)
    for damage in (None, "bytes", "text"):
        simulate_module._COMPILED.clear()           # as a new process: the module from the entry
        if damage == "bytes":
            kept.write_bytes(kept.read_bytes()[:40] + b"\0garbage")
        again = derive_file(path)
        entry = cache.entry_of(again.state_space)
        if damage == "text":
            assert entry.module_code("x = 1\n", "<other>") is not None and compiled[-1] == "<other>"
            continue
        run = simulate(again.state_space, again.experiment)
        assert len(compiled) == (0 if damage is None else 1)
        np.testing.assert_array_equal(run.t, result.t)
        np.testing.assert_array_equal(run.states["spring.q"], result.states["spring.q"])
    assert kept.read_bytes().startswith(__import__("importlib.util").util.MAGIC_NUMBER)


_GEARED = (Path(__file__).parent / "fixtures" / "sim" / "geared_inertia.bg").read_text(encoding="utf-8")


def _check_counting_derive(path, monkeypatch, capsys, *options):
    """(exit code, stdout, stderr, how many times the equations stage ran) of ``bondc check``."""
    from bondc import cli

    equations = importlib.import_module("bondc.equations")     # bondc.equations is the API's function

    calls = []
    real = equations.derive
    monkeypatch.setattr(equations, "derive", lambda causal: calls.append(1) or real(causal))
    code = cli.main(["check", str(path), *options])
    out, err = capsys.readouterr()
    return code, out, err, len(calls)


def test_a_check_after_an_edit_of_parameter_values_only_reuses_the_equations_stage(tmp_path, isolated,
                                                                                    monkeypatch, capsys):
    """The equations stage is kept per content of the files with each parameter value written as
    a number left out, when no value decided anything there: a check after an edit of values
    only skips it (no sympy) and reports what a fresh check of the edited file reports (here
    W704, on a line the edit did not touch); any other edit runs it."""
    path = tmp_path / "geared.bg"
    path.write_text(_GEARED, encoding="utf-8")
    code, out, err, derived = _check_counting_derive(path, monkeypatch, capsys)
    assert (code, derived) == (0, 1) and "W704" in err
    path.write_text(_GEARED.replace("J = 0.1 [", "J = 0.25 ["), encoding="utf-8")
    edited = _check_counting_derive(path, monkeypatch, capsys)
    fresh = _check_counting_derive(path, monkeypatch, capsys, "--no-cache")
    assert edited[3] == 0 and fresh[3] == 1
    assert edited[:3] == fresh[:3]
    assert "geared.bg:6:" in edited[2]          # the warning's place in the edited file
    # a change of anything but a value (here a law) runs the stage again
    path.write_text(_GEARED.replace("J = 0.1 [", "J = 0.25 [").replace("f = p/2", "f = p/3"), encoding="utf-8")
    assert _check_counting_derive(path, monkeypatch, capsys)[3] == 1


def test_a_parameter_value_that_decides_a_laws_inverse_is_checked_again_after_each_edit(tmp_path, isolated,
                                                                                      monkeypatch, capsys):
    """``e = f^3 + a*f`` solved for f: for a > 0 the law is monotonic and its inverse is found; for
    a < 0 it is not invertible (E605). The stage used a's value, so an edit of a alone is never
    answered from the check cache."""
    path = tmp_path / "inverse.bg"
    source = "model T\n  param a = {}\n  Se s : e = 1\n  R r : e = f^3 + a*f\n  s -> r\nend\n"
    results = []
    for a in ("1", "-1", "2.5", "-0.5"):
        path.write_text(source.format(a), encoding="utf-8")
        code, _, err, derived = _check_counting_derive(path, monkeypatch, capsys)
        results.append((code, "E605" in err, derived))
    assert results == [(0, False, 1), (1, True, 1), (0, False, 1), (1, True, 1)]


@pytest.mark.slow
def test_the_energy_account_of_a_run_with_set_values_uses_the_base_module(tmp_path, isolated, monkeypatch):
    """``--set`` values are bound late to the base model's module; its energy account evaluates
    that module with the run's values too (no second code generation) and gives the account of
    the model with those values written in the file."""
    import bondc.codegen
    from bondc.analysis.energy import energy_account

    bound = derive_file(_write(tmp_path / "drive.bg"), sets=["b=20"])
    assert getattr(bound.state_space, "bound_base", None) is not None
    run = simulate(bound.state_space, bound.experiment)
    emitted = []
    real = bondc.codegen.emit
    monkeypatch.setattr(bondc.codegen, "emit", lambda *args, **kwargs: emitted.append(1) or real(*args, **kwargs))
    account = energy_account(bound.state_space, run)
    assert emitted == []
    written = derive_file(_write(tmp_path / "written.bg", b=20), cache=False)
    expected = energy_account(written.state_space, simulate(written.state_space, written.experiment))
    ours, theirs = account.to_json(), expected.to_json()
    assert json.dumps(ours["cycles"], sort_keys=True) == json.dumps(theirs["cycles"], sort_keys=True)


# ------------------------------------------------------------------ bondc cache info / clear, the cap

def _cache_cli(capsys, *argv):
    from bondc.cli import main

    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def test_cache_info_reports_what_a_run_stored_and_clear_empties_it(tmp_path, isolated, capsys, monkeypatch):
    folder, loads = isolated
    monkeypatch.setenv("BONDC_NATIVE", "0")
    path = _write(tmp_path / "drive.bg")
    status, out, _ = _cache_cli(capsys, "cache", "info", "--json")
    assert status == 0 and json.loads(out)["bytes"] == 0             # nothing yet (no folder at all)
    assert _cache_cli(capsys, "simulate", path)[0] == 0
    status, out, _ = _cache_cli(capsys, "cache", "info", "--json")
    found = json.loads(out)
    assert status == 0 and found["folder"] == str(folder) and found["enabled"]
    compile_ = next(c for c in found["caches"] if c["name"] == "compile")
    assert compile_["entries"] == 1 and compile_["bytes"] > 0 and compile_["folder"] == str(folder / "models")
    assert found["bytes"] >= compile_["bytes"]
    status, out, _ = _cache_cli(capsys, "cache", "info")
    assert status == 0 and str(folder) in out and "compile" in out and "1 entries" in out
    status, out, _ = _cache_cli(capsys, "cache", "clear")
    assert status == 0 and out.startswith("removed ")
    assert json.loads(_cache_cli(capsys, "cache", "info", "--json")[1])["bytes"] == 0
    before = len(loads)
    derive_file(path)                                   # a miss: derived again, and stored again
    assert len(loads) == before + 1
    assert json.loads(_cache_cli(capsys, "cache", "info", "--json")[1])["caches"][0]["entries"] == 1


def test_cache_clear_removes_only_what_bondc_wrote(tmp_path, isolated, capsys):
    folder, _ = isolated
    path = _write(tmp_path / "drive.bg")
    derive_file(path)
    # a BONDC_CACHE_DIR that is also someone's folder: their files, even in folders named as bondc's
    theirs = [folder / "notes.txt", folder / "models" / "mine.bg", folder / "native" / "README",
              folder / "check" / "keep.pickle", folder / "other" / "data.csv"]
    for file in theirs:
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_text("not bondc's", encoding="utf-8")
    (folder / "models" / ("a" * 40 + "-x")).mkdir()     # a name bondc never gives
    found = json.loads(_cache_cli(capsys, "cache", "info", "--json")[1])
    assert found["caches"][0]["entries"] == 1           # their files not counted
    status, out, _ = _cache_cli(capsys, "cache", "clear", "--json")
    removed = json.loads(out)["removed"]
    assert status == 0 and removed[0]["name"] == "compile" and removed[0]["entries"] == 1
    for file in theirs:
        assert file.read_text(encoding="utf-8") == "not bondc's"
    assert (folder / "models" / ("a" * 40 + "-x")).is_dir()
    assert not [p for p in (folder / "models").iterdir() if p.name not in ("mine.bg", "a" * 40 + "-x")]


def test_cache_clear_follows_no_link(tmp_path, isolated, capsys):
    folder, _ = isolated
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / ("b" * 40)).mkdir(parents=True)
    (elsewhere / ("b" * 40) / "precious").write_text("x", encoding="utf-8")
    folder.mkdir()
    (folder / "models").symlink_to(elsewhere, target_is_directory=True)
    assert _cache_cli(capsys, "cache", "clear")[0] == 0
    assert (elsewhere / ("b" * 40) / "precious").is_file()


def test_a_bad_cap_is_a_usage_error(isolated, capsys, monkeypatch):
    monkeypatch.setenv("BONDC_CACHE_MAX_MB", "lots")
    status, _, err = _cache_cli(capsys, "cache", "info")
    assert status == 2 and "E001" in err and "BONDC_CACHE_MAX_MB" in err
    assert _cache_cli(capsys, "cache")[0] == 2            # no action


def test_the_cap_evicts_the_least_recently_used_entries_first(tmp_path, isolated, monkeypatch):
    folder, loads = isolated
    monkeypatch.setenv("BONDC_CACHE_MAX_MB", "0")         # no cap while filling it
    paths = {name: _write(tmp_path / f"{name}.bg", b=b) for name, b in (("a", 1), ("b", 2), ("c", 3), ("d", 4))}
    entries = {}
    for name in "abc":
        derive_file(paths[name])
        entries[name] = cache.Entry.for_model(paths[name]).folder
    for when, name in enumerate("abc"):                   # a oldest, then b, then c
        os.utime(entries[name], (1000.0 + when, 1000.0 + when))
    derive_file(paths["a"])                               # a hit: a is the most recently used now
    assert len(loads) == 3
    largest = max(cache._size(str(entry)) for entry in entries.values())
    monkeypatch.setenv("BONDC_CACHE_MAX_MB", str(2.5 * largest / 1e6))
    derive_file(paths["d"])                               # stored: over the cap, b then c go
    entries["d"] = cache.Entry.for_model(paths["d"]).folder
    assert {name for name, entry in entries.items() if entry.is_dir()} == {"a", "d"}
    assert json.loads((folder / "models" / ".size.json").read_text())["bytes"] <= 2.5 * largest
    derive_file(paths["b"])                               # evicted: derived again
    assert len(loads) == 5


def test_the_cap_counts_the_models_c_libraries_and_keeps_the_stepper(tmp_path, isolated, monkeypatch):
    """The native libraries of models (``native/model_*.so``) are entries of the cap, evicted least
    recently used first with the compiled models; bondc's explicit stepper (``erk_*.so``, built once
    per machine) and the compiler probes are kept. A library loaded again is marked used."""
    folder, _ = isolated
    monkeypatch.setenv("BONDC_CACHE_MAX_MB", "0")
    native = folder / "native"
    native.mkdir(parents=True)
    size = 200_000
    old = native / ("model_" + "1" * 40 + ".so")
    newer = native / ("model_" + "2" * 40 + ".so")
    stepper = native / ("erk_" + "3" * 40 + ".so")
    probe = native / ("compiler_" + "4" * 24 + ".json")
    for when, path in enumerate((old, newer, stepper, probe)):
        path.write_bytes(b"\0" * size)
        os.utime(path, (1000.0 + when, 1000.0 + when))
    model = _write(tmp_path / "m.bg", b=1)
    derive_file(model)                                    # a compiled model: the newest entry
    monkeypatch.setenv("BONDC_CACHE_MAX_MB", str((1.5 * size + cache._size(str(folder / "models"))) / 1e6))
    left = cache._trim(cache.max_bytes())
    assert not old.exists() and newer.exists()            # the older library went first, then enough
    assert stepper.exists() and probe.exists()            # never evicted
    assert cache.Entry.for_model(model).folder.is_dir()   # the newest entry stays
    assert left <= cache.max_bytes()


def test_loading_a_models_c_library_marks_it_used(tmp_path, isolated):
    """A hit on a built library touches it (the cap's least recently used order). The C compiler
    is always there (the system's, else the ziglang package's)."""
    from bondc import runtime
    from bondc.pipeline import simulate_file as run

    folder, _ = isolated
    model = _write(tmp_path / "m.bg", b=1)
    run(model, t_end=0.01)
    (library,) = (folder / "native").glob("model_*.so")
    os.utime(library, (1000.0, 1000.0))
    runtime.native._NATIVE_LIBRARIES.clear()              # loaded again, from the cache folder
    run(model, t_end=0.01)
    assert library.stat().st_mtime > 2000.0
