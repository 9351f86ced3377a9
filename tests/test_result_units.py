"""Units in every result (the language reference, section 14): result files carry units, outputs
are written in their declared unit, and measured data is read in the units its header gives.

The round trip is the independent check: a result file written in kPa, bar, mm, L/min and rpm,
read back as measured data, must match the simulation it came from to rounding.
"""

import io
import json
import math
import os

import numpy as np
import pytest

from bondc.cli import main
from bondc.errors import DataError
from bondc.report.build import run_validate
from bondc.analysis.validate import load_measured_csv
from bondc.pipeline import simulate_file as run

MODEL = """model Units "a chamber filled by a varying flow, reported in engineering units"
  param beta = 1e8   [Pa]
  param V    = 1     [L]
  param R_h  = 1e11  [Pa*s/m^3]
  param A    = 10    [cm^2]
  param D    = 1e-6  [m^3/rad]
  Sf pump : f = 1e-4*(1 + sin(5*t))
  C  tank : state p [Pa], p(0) = 1e5, der(p) = beta/V*f, e = p
  R  drain : e = R_h*f
  0  n
  pump -> n
  n -> tank
  n -> drain
  state x [m] "piston travel" : der(x) = pump.f/A, x(0) = 0
  output p_kPa [kPa]   = tank.p
  output p_bar [bar]   = tank.p
  output x_mm  [mm]    = x
  output q_lpm [L/min] = pump.f
  output w_rpm [rpm]   = pump.f/D
  output p_si  [Pa]    = tank.p
  experiment fill
    t_end = 2 [s]
    rtol  = 1e-9
    atol  = 1e-6
  end
end
"""

SCALES = {"p_kPa": 1e3, "p_bar": 1e5, "x_mm": 1e-3, "q_lpm": 1e-3 / 60, "w_rpm": 2 * math.pi / 60, "p_si": 1.0}


@pytest.fixture
def model(tmp_path):
    path = tmp_path / "units.bg"
    path.write_text(MODEL)
    return path


def test_csv_headers_carry_units_and_outputs_are_in_their_declared_unit(model, tmp_path):
    out = tmp_path / "sim.csv"
    result = run(model, dt=0.25, output=out)
    header, *rows = out.read_text().splitlines()
    columns = header.split(",")
    assert columns[:7] == ["t [s]", "p_kPa [kPa]", "p_bar [bar]", "x_mm [mm]", "q_lpm [L/min]", "w_rpm [rpm]",
                           "p_si [Pa]"]
    assert "tank.p [Pa]" in columns and "x [m]" in columns
    data = np.array([[float(cell) for cell in row.split(",")] for row in rows])
    for index, name in enumerate(columns[1:7], start=1):
        output = name.split(" ")[0]
        assert np.allclose(data[:, index] * SCALES[output], result.outputs[output], rtol=1e-14)
    # states and SI outputs are written as computed
    assert np.allclose(data[:, columns.index("tank.p [Pa]")], result.states["tank.p"], rtol=0)


def test_state_columns_of_storage_elements_get_their_si_unit(tmp_path):
    path = tmp_path / "msd.bg"
    path.write_text("model M\n  param m = 2 [kg]\n  param k = 800 [N/m]\n  param F0 = 10 [N]\n"
                    "  Se f : e = F0\n  I mass : f = p/m\n  C spring : e = k*q\n  1 j\n"
                    "  f -> j\n  j -> mass\n  j -> spring\nend\n")
    out = tmp_path / "o.csv"
    run(path, t_end=0.1, dt=0.05, output=out)
    header = out.read_text().splitlines()[0].split(",")
    assert header == ["t [s]", "mass.p [kg*m/s]", "spring.q [m]"]


@pytest.mark.slow
def test_the_round_trip_through_engineering_units_validates(model, tmp_path):
    out = tmp_path / "sim.csv"
    run(model, dt=0.001, output=out)
    specs = [f"{name}={name}:nrmse=1e-5" for name in SCALES]     # linear interpolation of a 1 ms grid
    errors = io.StringIO()
    results, code = run_validate(model, data=out, compare=specs, stream=io.StringIO(), errors=errors)
    assert code == 0, [r.summary() for r in results]
    assert all(r.nrmse < 1e-5 for r in results)
    assert "W954" not in errors.getvalue()


@pytest.mark.slow
def test_a_column_without_a_unit_is_si_and_the_warning_says_which_unit_was_assumed(model, tmp_path):
    result = run(model, dt=0.01)
    data = tmp_path / "bench.csv"
    lines = ["t,p_kPa"] + [f"{float(t)!r},{float(p) / 1e3!r}" for t, p in zip(result.t, result.outputs["p_kPa"])]
    data.write_text("\n".join(lines) + "\n")
    errors = io.StringIO()
    results, code = run_validate(model, data=data, compare=["p_kPa=p_kPa"], stream=io.StringIO(), errors=errors)
    assert code == 1                       # read as Pa: a thousand times too small
    assert "W954" in errors.getvalue() and "[kPa]" in errors.getvalue()
    data.write_text(data.read_text().replace("t,p_kPa", "t [s],p_kPa [kPa]"))
    results, code = run_validate(model, data=data, compare=["p_kPa=p_kPa"], stream=io.StringIO(),
                                 errors=io.StringIO())
    assert code == 0


def test_measured_time_in_milliseconds_and_an_unknown_unit(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("t [ms],P [bar],Q [L/min]\n0,1,60\n500,2,120\n")
    data = load_measured_csv(path)
    assert np.allclose(data["t"], [0, 0.5]) and np.allclose(data["P"], [1e5, 2e5])
    assert np.allclose(data["Q"], [1e-3, 2e-3])
    assert data.units == {"P": "bar", "Q": "L/min"}
    path.write_text("t,P [barr]\n0,1\n1,2\n")
    with pytest.raises(DataError) as caught:
        load_measured_csv(path)
    assert caught.value.diagnostics[0].code == "E957" and "barr" in caught.value.diagnostics[0].message


def test_a_measured_input_signal_is_read_in_the_units_of_its_header(tmp_path):
    (tmp_path / "w.csv").write_text("t [ms],omega [rpm]\n0,0\n1000,1000\n2000,1000\n")
    path = tmp_path / "m.bg"
    path.write_text('model M\n  input w [rad/s] = csv("w.csv", "omega")\n  Sf motor : f = w\n  R load : e = 0.1*f\n'
                    "  motor -> load\n  output speed [rad/s] = w\nend\n")
    result = run(path, t_end=2.0, dt=0.25)
    expected = np.interp(result.t, [0, 1, 2], [0, 1000 * 2 * math.pi / 60, 1000 * 2 * math.pi / 60])
    assert np.allclose(result.outputs["speed"], expected, rtol=1e-12)
    # a unit bondc does not know is reported at the csv() call
    (tmp_path / "w.csv").write_text("t [ms],omega [rpmm]\n0,0\n1000,1000\n")
    assert main(["check", str(path)]) == 1


@pytest.mark.slow
def test_json_statistics_give_each_output_in_its_unit(model, capsys):
    assert main(["simulate", str(model), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    stats = summary["statistics"]
    assert stats["p_kPa"]["unit"] == "kPa" and stats["p_si"]["unit"] == "Pa"
    assert stats["p_kPa"]["final"] == pytest.approx(stats["p_si"]["final"] / 1e3, rel=1e-12)
    assert stats["p_bar"]["max"] == pytest.approx(stats["p_si"]["max"] / 1e5, rel=1e-12)
    # the final values of the outputs too (states stay in SI)
    assert summary["final"]["p_kPa"] == stats["p_kPa"]["final"] and summary["final"]["p_si"] == stats["p_si"]["final"]


def test_every_result_format_records_the_csvs_units(model, tmp_path):
    """One writer: the csv, the Parquet file and the npz of one run hold the same numbers, each
    column with its unit -- the csv in its header, Parquet in each field's metadata (the csv's
    numbers), npz beside each SI array (``unit/KEY``, ``si_factor/KEY``). The factors are the
    hand-written SCALES (1 kPa = 1e3 Pa, 1 rpm = 2 pi/60 rad/s, ...)."""
    import pyarrow.parquet

    paths = {kind: tmp_path / f"sim.{kind}" for kind in ("csv", "parquet", "npz")}
    for path in paths.values():
        assert main(["simulate", str(model), "--dt", "0.25", "-o", str(path)]) == 0
    header, *rows = paths["csv"].read_text().splitlines()
    csv = {cell.split(" [")[0]: (cell.split(" [")[1].rstrip("]") if " [" in cell else None, i)
           for i, cell in enumerate(header.split(","))}
    data = np.array([[float(cell) for cell in row.split(",")] for row in rows])
    table = pyarrow.parquet.read_table(paths["parquet"])
    assert table.column_names == list(csv)
    for field in table.schema:
        unit, index = csv[field.name]
        assert field.metadata[b"unit"].decode() == (unit or "")
        np.testing.assert_array_equal(table.column(field.name).to_numpy(), data[:, index])
    assert table.schema.metadata[b"complete"] == b"True"
    with np.load(paths["npz"]) as arrays:
        for output, scale in SCALES.items():
            key = f"outputs/{output}"
            assert str(arrays[f"unit/{key}"]) == csv[output][0]
            assert float(arrays[f"si_factor/{key}"]) == pytest.approx(scale, rel=1e-15)
            np.testing.assert_allclose(arrays[key] / scale, data[:, csv[output][1]], rtol=1e-15)
        assert str(arrays["unit/states/tank.p"]) == "Pa" and float(arrays["si_factor/states/tank.p"]) == 1.0
        assert str(arrays["unit/t"]) == "s"


def test_the_standalone_modules_csv_is_bondcs(model, tmp_path):
    """The module `bondc compile --standalone` writes (run without bondc) writes the same csv as
    `bondc simulate -o`: the same header with units, outputs in their declared units."""
    import subprocess
    import sys

    module = tmp_path / "units_gen.py"
    assert main(["compile", str(model), "--standalone", "-o", str(module)]) == 0
    mine = tmp_path / "mine.csv"
    env = {key: value for key, value in os.environ.items() if not key.startswith("PYTHON")}
    done = subprocess.run([sys.executable, "-I", str(module), "--dt", "0.25", "-o", str(mine)], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    theirs = tmp_path / "theirs.csv"
    assert main(["simulate", str(model), "--dt", "0.25", "-o", str(theirs)]) == 0
    mine_header, *mine_rows = mine.read_text().splitlines()
    header, *rows = theirs.read_text().splitlines()
    assert mine_header == header == ("t [s],p_kPa [kPa],p_bar [bar],x_mm [mm],q_lpm [L/min],w_rpm [rpm],p_si [Pa],"
                                     "tank.p [Pa],x [m]")
    a = np.array([[float(c) for c in r.split(",")] for r in mine_rows])
    b = np.array([[float(c) for c in r.split(",")] for r in rows])
    np.testing.assert_allclose(a, b, rtol=1e-12)
