"""Units in every result (the language reference, section 14): result files carry units, outputs
are written in their declared unit, and measured data is read in the units its header gives.

The round trip is the independent check: a result file written in kPa, bar, mm, L/min and rpm,
read back as measured data, must match the simulation it came from to rounding.
"""

import io
import json
import math

import numpy as np
import pytest

from bondc.cli import main
from bondc.errors import DataError
from bondc.report.build import run_validate
from bondc.report.validate import load_measured_csv
from bondc.simulate import run

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
