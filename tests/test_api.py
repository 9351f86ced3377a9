"""The Python API (docs/api.md): its examples run as written, and its results convert."""

import doctest
import os
from pathlib import Path

import numpy as np
import pytest

import bondc

ROOT = Path(__file__).resolve().parent.parent
MSD_PATH = ROOT / "models" / "mass_spring_damper.bg"


def test_the_api_page_examples_run_as_written(monkeypatch):
    monkeypatch.chdir(ROOT)
    failures, tests = doctest.testfile(str(ROOT / "docs" / "api.md"), module_relative=False,
                                       optionflags=doctest.ELLIPSIS)
    assert tests > 10 and failures == 0


def test_the_api_docstrings_run(monkeypatch):
    from bondc import api

    monkeypatch.chdir(ROOT)
    assert doctest.testmod(api).failed == 0


def test_every_exported_name_is_there():
    for name in bondc.__all__:
        assert getattr(bondc, name) is not None
    assert callable(bondc.simulate) and callable(bondc.equations)     # modules of the pipeline, callable


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
