"""The Python API (docs/api.md): its examples run as written, and its results convert."""

import base64
import doctest
import importlib
import inspect
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bondc
from bondc import api

ROOT = Path(__file__).resolve().parent.parent
MSD_PATH = ROOT / "models" / "mass_spring_damper.bg"


def test_the_api_page_examples_run_as_written(monkeypatch):
    monkeypatch.chdir(ROOT)
    failures, tests = doctest.testfile(str(ROOT / "docs" / "api.md"), module_relative=False,
                                       optionflags=doctest.ELLIPSIS)
    assert tests > 10 and failures == 0


def test_every_exported_name_is_there():
    for name in bondc.__all__:
        assert getattr(bondc, name) is not None


API_FUNCTIONS = ("load", "check", "equations", "linearize", "compile", "simulate")


def _assert_the_api_functions(namespace):
    for name in API_FUNCTIONS:
        function = getattr(namespace, name)
        assert inspect.isfunction(function) and function is getattr(api, name), name
        assert function.__doc__ and "path" in inspect.signature(function).parameters, name
        assert inspect.signature(function).return_annotation not in (inspect.Signature.empty, "Any"), name


def test_the_api_functions_are_functions_with_signatures_and_docstrings():
    """bondc.simulate and bondc.equations were the pipeline's modules made callable, with the
    signature (*args, **kwargs) and the module's docstring; the modules stay importable."""
    import bondc.equations
    import bondc.simulate
    from bondc.simulate import SimResult

    _assert_the_api_functions(bondc)
    assert list(inspect.signature(bondc.simulate).parameters) == ["path", "text", "model", "experiment",
                                                                     "overrides", "t_end", "dt", "inputs"]
    assert inspect.signature(bondc.equations).parameters["format"].default == "text"
    assert sys.modules["bondc.simulate"].SimResult is SimResult
    assert hasattr(importlib.import_module("bondc.equations"), "derive")


def test_the_api_functions_stay_functions_whatever_was_imported_first():
    """In a fresh interpreter, the stage modules imported before and after the package's names."""
    code = ("import inspect, bondc.simulate, bondc.equations, bondc\n"
            "from bondc.simulate import simulate as stage\n"
            "print(inspect.isfunction(bondc.simulate), inspect.isfunction(bondc.equations), "
            "bondc.simulate.__module__, stage.__module__, list(inspect.signature(bondc.simulate).parameters)[:2])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "True", "bondc.api", "bondc.simulate", "['path',", "'text']"]


def test_bondc_ships_its_types():
    """PEP 561: without py.typed in the installed package, mypy ignores bondc's annotations."""
    tomllib = pytest.importorskip("tomllib")
    assert (ROOT / "bondc" / "py.typed").is_file()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "py.typed" in project["tool"]["setuptools"]["package-data"]["bondc"]
    assert any(requirement.startswith("mypy") for requirement in project["project"]["optional-dependencies"]["test"])


@pytest.mark.slow
def test_a_user_script_type_checks_with_mypy_strict(tmp_path):
    """tests/fixtures/api/user_script.py uses the API as docs/api.md shows, with assert_type on what it
    returns: mypy --strict finds nothing in it (an untyped or Any-returning API function fails it).
    bondc is read from the repository (an editable install is an import hook mypy cannot follow);
    errors inside bondc's own modules are not the script's (--follow-imports=silent), as for an
    installed package."""
    pytest.importorskip("mypy")
    script = ROOT / "tests" / "fixtures" / "api" / "user_script.py"
    out = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--follow-imports=silent", "--no-color-output",
                          "--cache-dir", str(tmp_path / "cache"), str(script)],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path,
                         env={**os.environ, "MYPYPATH": str(ROOT)})
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Success: no issues found in 1 source file" in out.stdout
    # and it runs as typed
    ran = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert ran.returncode == 0, ran.stderr
    assert "E810 0.5" in ran.stdout and "<text>.bg:2:20: unknown unit 'mm2'" in ran.stdout


def test_a_model_error_says_where_in_its_message(tmp_path):
    """str(error) was only the messages: a script printing it did not say where the problem is."""
    path = tmp_path / "spring.bg"
    path.write_text("model M\n  param k = 800 [N/mm2]\n  C c : e = k*q\n  Se s : e = 1\n  s -> c\nend\n")
    with pytest.raises(bondc.errors.ModelError) as raised:
        bondc.load(path)
    first = raised.value.diagnostics[0]
    assert (first.span.line, first.span.column) == (2, 20)      # the unit mm2
    assert str(raised.value).startswith(f"{path}:2:20: ") and first.message in str(raised.value)
    assert not str(bondc.errors.ModelError("no model")).startswith(":")      # no place: the message only


def test_a_simulation_error_declares_its_result():
    from bondc.errors import SimulationError

    assert "result" in inspect.get_annotations(SimulationError)
    assert SimulationError("stopped").result is None


@pytest.mark.slow
def test_simulation_results_convert_to_a_plot_a_table_and_a_dataframe():
    sim = bondc.simulate(ROOT / "models" / "electro_pneumatic_hybrid.bg", dt=0.1, t_end=0.5)
    figure = sim.plot(["P_kPa", "x"])
    assert len(figure.axes) == 2                          # one axis per unit: kPa and m
    html = sim._repr_html_()
    assert "P_kPa" in html and "kPa" in html and "<table>" in html
    assert np.allclose(sim.in_unit("P_kPa"), sim["P_kPa"] / 1000)
    pytest.importorskip("pandas")
    frame = sim.to_dataframe()
    assert "P_kPa [kPa]" in frame.columns and frame.index.name == "t [s]"
    assert np.allclose(frame["P_kPa [kPa]"].to_numpy(), sim["P_kPa"] / 1000)


def test_check_returns_problems_instead_of_raising(tmp_path):
    result = bondc.check(text="model M\n  R r : e = f\n  r -> nowhere\nend\n")
    assert not result.ok and result.errors[0].code == "E404" and "E404" in str(result)
    assert "<table>" in result._repr_html_()


def test_load_with_overrides_in_units():
    model = bondc.load(ROOT / "models" / "mass_spring_damper.bg", overrides={"k": "1.2 [kN/m]", "m": (500, "g")})
    assert model.parameters["k"] == 1200.0 and model.parameters["m"] == 0.5


def test_compile_writes_a_module_that_runs(tmp_path):
    out = bondc.compile(ROOT / "models" / "mass_spring_damper.bg", tmp_path / "msd_gen.py")
    import runpy

    namespace = runpy.run_path(str(out))
    result = namespace["simulate"](t_end=1.0)
    assert result.complete


@pytest.mark.slow
def test_the_example_notebook_runs(tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    notebook = nbformat.read(ROOT / "docs" / "example.ipynb", as_version=4)
    client = nbclient.NotebookClient(notebook, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(ROOT / "docs")}})
    client.execute()
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("text/html" in o.get("data", {}) for o in outputs)           # the summary tables
    assert any("image/png" in o.get("data", {}) or "image/svg+xml" in o.get("data", {}) for o in outputs)


def test_a_plot_shows_in_a_fresh_notebook_kernel_without_matplotlib_magic(tmp_path):
    """sim.plot() ending a cell showed only '<Figure size 700x480 with 1 Axes>' in a fresh kernel: its
    Figure is not pyplot's, and nothing had set up the inline backend's formatters."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    notebook = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_code_cell("import bondc"),
        nbformat.v4.new_code_cell(f"sim = bondc.simulate({str(MSD_PATH)!r}, dt=0.01)\nsim.plot(['x', 'v'])"),
        nbformat.v4.new_code_cell("import sys\n'matplotlib.pyplot' in sys.modules"),
    ])
    client = nbclient.NotebookClient(notebook, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    outputs = notebook.cells[1].outputs
    assert not [o for o in outputs if o.output_type == "error"], outputs
    (shown,) = [o for o in outputs if o.output_type == "execute_result"]
    assert "image/png" in shown.data, shown.data
    png = base64.b64decode(shown.data["image/png"])
    assert png.startswith(b"\x89PNG") and len(png) > 5000          # a picture of the two axes
    assert notebook.cells[2].outputs[0].data["text/plain"] == "False"   # shown without pyplot


@pytest.mark.parametrize("call, words", [
    (lambda: bondc.simulate(MSD_PATH, overrides={"k": None}), "overrides['k'] must be a number"),
    (lambda: bondc.simulate(MSD_PATH, overrides={"k": [1, 2]}), "overrides['k'] must be a number"),
    (lambda: bondc.simulate(MSD_PATH, overrides={"k": float("nan")}), "must be a finite number"),
    (lambda: bondc.simulate(MSD_PATH, overrides={"k": True}), "not bool"),
    (lambda: bondc.simulate(MSD_PATH, overrides=[("k", 1)]), "overrides must be a dict"),
    (lambda: bondc.simulate(MSD_PATH, overrides={"k": (1, 2, 3)}), "(number, unit) pair"),
    (lambda: bondc.simulate(MSD_PATH, t_end="2 [s]"), "t_end must be a number"),
    (lambda: bondc.simulate(text=b"model M\nend\n"), "text must be a str"),
    (lambda: bondc.simulate(), "give the model"),
    (lambda: bondc.equations(MSD_PATH, format="html"), "format must be one of text, latex, json"),
    (lambda: bondc.linearize(MSD_PATH, at="steady"), "at must be one of initial, equilibrium"),
])
def test_misused_arguments_are_bondc_errors_that_name_them(call, words):
    """The API raised Python's own TypeError, AttributeError or ValueError for these (and took True as
    1); docs/api.md promises bondc errors with diagnostics."""
    with pytest.raises(bondc.errors.UsageError) as excinfo:
        call()
    (diagnostic,) = excinfo.value.diagnostics
    assert diagnostic.code == "E001" and words in diagnostic.message


def test_a_simulations_time_and_unknown_names_are_answered():
    sim = bondc.simulate(MSD_PATH, dt=0.5)
    np.testing.assert_array_equal(sim["t"], sim.t)
    with pytest.raises(KeyError, match="did you mean 'spring.q'"):
        sim["spring.qq"]
