"""Friction identification (eqs. 17-20): known laws recovered, every data problem a DataError.

Synthetic data are made here from C = a*|v|^b with a seeded generator, then
turned into torques by inverting eq. 17, independently of the shipped
models/data/friction_tests.csv.
"""

from __future__ import annotations

import doctest
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from bondc.analysis import friction
from bondc.analysis.friction import (
    FrictionData,
    fit_friction,
    load_friction_csv,
    parse_unit_text,
    run_fit_friction,
    split_header,
)
from bondc.errors import DataError
from bondc.source import NO_SPAN

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "models" / "data" / "friction_tests.csv"
GENERATOR = ROOT / "models" / "data" / "make_friction_data.py"

LEAD, AREA, MASS, G, PATM = 5e-3, 2.63e-3, 31.7, 9.81, 101325.0
UP, DOWN = (706.59, -0.73), (435.61, -0.66)  # Table 3
GEOMETRY = dict(lead=LEAD, area=AREA, mass=MASS, gravity=G)


def torque_for(v, C, P, patm=PATM):
    """Eq. 17 solved for the torque: what a motor must give for friction C at speed v."""
    return LEAD / (2 * math.pi) * (C * v - (P - patm) * AREA + MASS * G)


def synthetic(rows_per_direction=12, noise=0.0, seed=0, up=UP, down=DOWN, pressure=224e3):
    """Rows at speeds 0.01..0.2 m/s each way; C with multiplicative noise; P = pressure +- 1 kPa."""
    rng = np.random.default_rng(seed)
    speed = np.geomspace(0.01, 0.2, rows_per_direction)
    v = np.concatenate([speed, -speed])
    C = np.where(v > 0, up[0] * np.abs(v) ** up[1], down[0] * np.abs(v) ** down[1])
    C = C * (1 + noise * rng.standard_normal(v.shape))
    P = pressure + 1e3 * rng.standard_normal(v.shape)
    return {"v": v, "tau": torque_for(v, C, P), "P": P}


def write(tmp_path, text, name="data.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def error_of(call, *args, **kwargs) -> DataError:
    with pytest.raises(DataError) as info:
        call(*args, **kwargs)
    return info.value


def codes(error: DataError) -> list[str]:
    return [d.code for d in error.diagnostics]


GOOD_CSV = "v,tau,P\n" + "\n".join(
    f"{v},{torque_for(v, (UP if v > 0 else DOWN)[0] * abs(v) ** (UP if v > 0 else DOWN)[1], 224e3)!r},224000"
    for v in (0.02, 0.05, 0.1, -0.02, -0.05, -0.1)) + "\n"


# ------------------------------------------------------------------ recovery

def test_module_docstring_example_runs():
    result = doctest.testmod(friction)
    assert result.failed == 0 and result.attempted > 0


def test_exact_recovery_on_noiseless_data():
    fit = fit_friction(synthetic(), **GEOMETRY)
    for direction, (a, b) in ((fit.up, UP), (fit.down, DOWN)):
        assert direction.a == pytest.approx(a, rel=1e-6)
        assert direction.b == pytest.approx(b, abs=1e-6)
        assert direction.a_log == pytest.approx(a, rel=1e-6)  # the log-space start is already exact
        assert direction.r_squared == pytest.approx(1.0, abs=1e-10)
        assert np.max(np.abs(direction.residuals)) < 1e-6 * np.max(direction.coefficient)
        assert direction.n == 12


def test_recovers_known_coefficients_from_noisy_data():
    """2 % multiplicative noise, 40 rows per direction over 0.01..0.2 m/s.

    Tolerances from 2000 seeded repetitions of exactly this design (4000
    direction fits): |a/a_true - 1| had median 1.4 %, 99.9th percentile
    6.9 %, worst 7.4 %; |b - b_true| median 0.004, worst 0.022; the fitted C
    over 0.01..0.2 m/s was never more than 4.2 % off. a is the extrapolation
    to |v| = 1 m/s, far outside the data, hence its wider tolerance.
    """
    fit = fit_friction(synthetic(rows_per_direction=40, noise=0.02, seed=20240501), **GEOMETRY)
    speeds = np.geomspace(0.01, 0.2, 50)
    for direction, (a, b) in ((fit.up, UP), (fit.down, DOWN)):
        assert direction.a == pytest.approx(a, rel=0.10)
        assert direction.b == pytest.approx(b, abs=0.05)
        assert np.max(np.abs(direction.predict(speeds) / (a * speeds ** b) - 1)) < 0.05
        assert direction.r_squared > 0.99
        # The nonlinear refinement lowers the residual on C against the log-space start.
        start = direction.a_log * direction.speed ** direction.b_log
        assert np.sum(direction.residuals ** 2) <= np.sum((direction.coefficient - start) ** 2) + 1e-9


def test_paper_measured_law_is_recovered_too():
    """Eqs. 19-20 (the paper's measured fit) through the same pipeline."""
    fit = fit_friction(synthetic(up=(213.7, -0.79), down=(179.0, -0.86)), **GEOMETRY)
    assert (fit.up.a, fit.up.b) == pytest.approx((213.7, -0.79), rel=1e-6)
    assert (fit.down.a, fit.down.b) == pytest.approx((179.0, -0.86), rel=1e-6)


def test_friction_force_and_coefficient_follow_eqs_17_and_18():
    v, tau, P = 0.1, 0.3, 224e3
    data = {"v": [v, 0.05, 0.2, -0.1, -0.05, -0.2], "tau": [tau, 0.25, 0.35, -0.2, -0.15, -0.25],
            "P": [P] * 6}
    fit = fit_friction(data, **GEOMETRY)
    expected_force = 2 * math.pi / LEAD * tau + (P - PATM) * AREA - MASS * G
    index = list(fit.up.speed).index(0.1)
    assert fit.up.force[index] == pytest.approx(expected_force, rel=1e-12)
    assert fit.up.coefficient[index] == pytest.approx(expected_force / v, rel=1e-12)


def test_gauge_pressure_with_patm_zero_gives_the_same_fit():
    data = synthetic(noise=0.02, seed=3)
    gauge = dict(data, P=data["P"] - PATM)
    absolute_fit = fit_friction(data, **GEOMETRY)
    gauge_fit = fit_friction(gauge, **GEOMETRY, patm=0.0)
    assert gauge_fit.up.a == pytest.approx(absolute_fit.up.a, rel=1e-9)
    assert gauge_fit.down.b == pytest.approx(absolute_fit.down.b, rel=1e-9)


def test_all_input_forms_agree():
    data = synthetic(noise=0.02, seed=5)
    array = np.column_stack([data["v"], data["tau"], data["P"]])
    rows = [{"Velocity": v, "Torque": t, "Pressure": p} for v, t, p in array]
    fits = [fit_friction(form, **GEOMETRY) for form in (data, array, array.tolist(), rows)]
    for fit in fits[1:]:
        assert fit.up.a == pytest.approx(fits[0].up.a, rel=1e-12)
        assert fit.down.b == pytest.approx(fits[0].down.b, rel=1e-12)


def test_coefficient_picks_the_law_by_direction():
    fit = fit_friction(synthetic(), **GEOMETRY)
    assert fit.coefficient(0.1) == pytest.approx(UP[0] * 0.1 ** UP[1], rel=1e-6)
    assert fit.coefficient(-0.1) == pytest.approx(DOWN[0] * 0.1 ** DOWN[1], rel=1e-6)


# -------------------------------------------------------------------- CSV

def test_csv_header_names_any_case_any_order_with_units(tmp_path):
    data = synthetic(noise=0.02, seed=9)
    plain = fit_friction(data, **GEOMETRY)
    lines = ["# a comment", "", "  # an indented comment", "PRESSURE [MPa], extra, Velocity [mm/s], TAU (N*m)"]
    lines += [f"{float(p) / 1e6!r}, x, {float(v) * 1e3!r}, {float(t)!r}"
              for v, t, p in zip(data["v"], data["tau"], data["P"])]
    loaded = load_friction_csv(write(tmp_path, "\n".join(lines) + "\n"))
    assert loaded.velocity == pytest.approx(data["v"], rel=1e-12)
    assert loaded.pressure == pytest.approx(data["P"], rel=1e-12)
    assert loaded.labels[0] == "line 5"
    fit = fit_friction(loaded, **GEOMETRY)
    assert fit.up.a == pytest.approx(plain.up.a, rel=1e-9)
    assert fit.down.b == pytest.approx(plain.down.b, rel=1e-9)


def test_csv_with_windows_line_endings_and_bom(tmp_path):
    path = tmp_path / "crlf.csv"
    path.write_bytes(("\ufeff" + GOOD_CSV.replace("\n", "\r\n")).encode("utf-8"))
    fit = fit_friction(load_friction_csv(path), **GEOMETRY)
    assert fit.up.a == pytest.approx(UP[0], rel=1e-6)


def test_header_and_unit_helpers():
    assert split_header("  Velocity [mm/s] ") == ("velocity", "mm/s")
    assert split_header("tau") == ("tau", None)
    unit = parse_unit_text("kg*m^2/s^2")
    assert [(f.name, int(f.exponent)) for f in unit.factors] == [("kg", 1), ("m", 2), ("s", -2)]
    assert parse_unit_text("m//s") is None


def test_shipped_file_is_reproduced_by_its_generator():
    spec = importlib.util.spec_from_file_location("make_friction_data", GENERATOR)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    text = SHIPPED.read_text(encoding="utf-8")
    assert text == module.render(module.make_rows())
    assert text.splitlines()[0] == ("# synthetic: generated by make_friction_data.py from C = 706.59|v|^-0.73 "
                                    "(up), 435.61|v|^-0.66 (down), 2% noise, seed 1")


def test_shipped_file_fits_near_table_3():
    fit = fit_friction(load_friction_csv(SHIPPED))  # the defaults are the flagship's Table 3 values
    assert (fit.up.n, fit.down.n) == (12, 12)
    speeds = np.geomspace(0.01, 0.2, 20)
    for direction, (a, b) in ((fit.up, UP), (fit.down, DOWN)):
        assert direction.a == pytest.approx(a, rel=0.10)
        assert direction.b == pytest.approx(b, abs=0.05)
        assert np.max(np.abs(direction.predict(speeds) / (a * speeds ** b) - 1)) < 0.05
        assert direction.r_squared > 0.99


def test_run_fit_friction_text_and_json():
    text, status = run_fit_friction(SHIPPED)
    assert status == 0
    assert "up" in text and "down" in text and "R^2" in text
    output, status = run_fit_friction(SHIPPED, json=True)
    result = json.loads(output)
    assert status == 0 and result["ok"] is True
    assert result["fit"]["up"]["n"] == 12
    assert result["fit"]["parameters"] == {"lead": LEAD, "area": AREA, "mass": MASS, "gravity": G, "patm": PATM}


def test_run_fit_friction_reports_data_errors_with_context(tmp_path):
    path = write(tmp_path, GOOD_CSV.replace("0.05,", "0.05x,", 1))
    text, status = run_fit_friction(path)
    assert status == 1
    assert f"{path}:3:1: error[E903]" in text
    assert "^^^^^" in text  # a caret under the bad cell
    output, status = run_fit_friction(path, json=True)
    assert status == 1 and json.loads(output)["diagnostics"][0]["code"] == "E903"


def test_run_fit_friction_missing_file_is_exit_2(tmp_path):
    text, status = run_fit_friction(tmp_path / "nope.csv")
    assert status == 2
    assert "E905" in text and "nope.csv" in text


# ------------------------------------------------------------------ errors

def test_E901_empty_file(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, ""))
    assert codes(error) == ["E901"] and "empty" in error.diagnostics[0].message
    error = error_of(load_friction_csv, write(tmp_path, "# only a comment\n\n"))
    assert codes(error) == ["E901"]


def test_E901_header_without_rows(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, "v,tau,P\n"))
    assert codes(error) == ["E901"] and "no data rows" in error.diagnostics[0].message
    assert codes(error_of(fit_friction, {"v": [], "tau": [], "P": []})) == ["E901"]


def test_E902_missing_column_lists_header_and_suggests(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, "velocty,tau,pressure,temp\n0.1,0.3,224000,20\n"))
    assert codes(error) == ["E902"]
    diagnostic = error.diagnostics[0]
    assert diagnostic.message == "no velocity column; the header has 'velocty', 'tau', 'pressure', 'temp'"
    assert diagnostic.hint.startswith("did you mean 'velocity' for 'velocty'? name the velocity column 'v' or")
    assert (diagnostic.span.line, diagnostic.span.column, diagnostic.span.end_column) == (1, 1, 8)


def test_E902_every_missing_column_at_once(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, "a,b\n1,2\n"))
    assert codes(error) == ["E902", "E902", "E902"]
    assert [d.message.split(";")[0] for d in error.diagnostics] == [
        "no velocity column", "no torque column", "no pressure column"]


def test_E902_semicolon_separated_file_gets_a_hint(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, "v;tau;P\n0.1;0.3;224000\n"))
    assert codes(error) == ["E902"] * 3
    assert error.diagnostics[0].hint.startswith("the header is one cell, 'v;tau;P': separate the columns with commas")


def test_E902_two_columns_for_one_quantity(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, "v,velocity,tau,P\n0.1,0.1,0.3,224000\n"))
    assert codes(error) == ["E902"]
    assert error.diagnostics[0].message == "two columns hold the velocity: 'v' and 'velocity'"


def test_E903_non_numeric_cell_names_line_and_column(tmp_path):
    text = "v,tau,P\n0.02,0.2,224000\n0.05,abc,224000\n0.1,0.3,nan\n0.2,,224000\n"
    error = error_of(load_friction_csv, write(tmp_path, text))
    assert codes(error) == ["E903", "E903", "E903"]
    first, second, third = error.diagnostics
    assert first.message == "line 3, column 'tau': 'abc' is not a number"
    assert (first.span.line, first.span.column, first.span.end_column) == (3, 6, 9)
    assert second.message == "line 4, column 'P': 'nan' is not a finite number"
    assert third.message == "line 5, column 'tau': empty cell"


def test_E903_from_arrays_names_the_row():
    error = error_of(fit_friction, {"v": [0.1, "fast"], "tau": [0.3, 0.3], "P": [2e5, 2e5]})
    assert codes(error) == ["E903"]
    assert error.diagnostics[0].message == "row 2, column 'v': 'fast' is not a number"


def test_E904_ragged_row(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, "v,tau,P\n0.1,0.3\n0.2,0.3,224000,9\n"))
    assert codes(error) == ["E904", "E904"]
    assert error.diagnostics[0].message == "line 2 has 2 cells; the header has 3"
    assert codes(error_of(fit_friction, {"v": [0.1, 0.2], "tau": [0.3], "P": [2e5, 2e5]})) == ["E904"]


def test_E905_unreadable_file(tmp_path):
    error = error_of(load_friction_csv, tmp_path / "missing.csv")
    assert codes(error) == ["E905"] and "cannot read" in error.diagnostics[0].message


def test_E906_header_units(tmp_path):
    error = error_of(load_friction_csv, write(tmp_path, "v [kg],tau,P [furlong]\n0.1,0.3,224000\n"))
    assert codes(error) == ["E906", "E906"]
    assert error.diagnostics[0].message == "the velocity column is in 'kg' (kg), which is not a velocity"
    assert error.diagnostics[1].message == "unknown unit 'furlong' in the pressure column"


def test_E910_zero_velocity():
    data = synthetic(rows_per_direction=4)
    data["v"] = data["v"].copy()
    data["v"][0] = 0.0
    error = error_of(fit_friction, data, **GEOMETRY)
    assert codes(error) == ["E910"]
    assert error.diagnostics[0].message == "row 1: velocity is zero, so C = F/v is undefined"


def test_E911_too_few_rows_per_direction():
    data = {"v": [0.02, 0.1, -0.02, -0.05, -0.1], "tau": [0.2, 0.3, -0.1, -0.12, -0.15], "P": [224e3] * 5}
    error = error_of(fit_friction, data, **GEOMETRY)
    assert codes(error) == ["E911"]
    assert error.diagnostics[0].message == ("2 rows for upward motion (v > 0); the fit needs at least 3")


def test_E911_one_direction_missing_entirely():
    data = {"v": [0.02, 0.05, 0.1], "tau": [0.2, 0.25, 0.3], "P": [224e3] * 3}
    error = error_of(fit_friction, data, **GEOMETRY)
    assert error.diagnostics[0].message.startswith("0 rows for downward motion (v < 0)")


def test_E912_non_positive_coefficient_names_the_rows(tmp_path):
    text = GOOD_CSV.splitlines()
    v, tau, P = text[2].split(",")  # the second upward row, file line 3
    text[2] = f"{v},-{tau},{P}"  # torque sign flipped: friction would push the mass along
    error = error_of(lambda: fit_friction(load_friction_csv(write(tmp_path, "\n".join(text) + "\n"))))
    assert codes(error) == ["E912"]
    diagnostic = error.diagnostics[0]
    assert diagnostic.message.startswith("line 3: friction coefficient C = F/v = -")
    assert "is not positive" in diagnostic.message and diagnostic.span.line == 3
    assert "--patm 0" in diagnostic.hint


def test_E913_one_speed_only():
    data = {"v": [0.1, 0.1, 0.1, -0.02, -0.05, -0.1], "tau": [0.3, 0.3, 0.3, -0.1, -0.12, -0.15],
            "P": [224e3] * 6}
    error = error_of(fit_friction, data, **GEOMETRY)
    assert codes(error) == ["E913"] and "same speed" in error.diagnostics[0].message


def test_E914_bad_parameters():
    error = error_of(fit_friction, synthetic(), lead=0.0, area=-1.0, mass=31.7)
    assert codes(error) == ["E914", "E914"]
    assert error.diagnostics[0].message == "lead must be a positive number, got 0.0"


def test_E915_pressure_below_atmospheric_warns_but_fits():
    fit = fit_friction(synthetic(pressure=9e4), **GEOMETRY)  # looks like gauge data read as absolute
    assert fit.up.a == pytest.approx(UP[0], rel=1e-6)
    assert [d.code for d in fit.warnings] == ["E915"] and fit.warnings[0].severity == "warning"
    assert "E915" in fit.to_text()


def test_several_problems_reported_in_one_run():
    data = {"v": [0.0, 0.02, 0.05, -0.1], "tau": [0.1, 0.2, 0.25, -0.1], "P": [224e3] * 4}
    error = error_of(fit_friction, data, **GEOMETRY)
    assert codes(error) == ["E910", "E911", "E911"]


def test_errors_never_escape_as_other_exceptions(tmp_path):
    for text in ("v,tau,P\n\"0.1,0.3,224000\n", "v;tau;P\n0.1;0.2;3\n", ",,,\n,,,\n", "v,tau,P\n,,\n"):
        with pytest.raises(DataError):
            fit_friction(load_friction_csv(write(tmp_path, text)))


def test_json_is_plain():
    fit = fit_friction(FrictionData(*[np.asarray(x) for x in synthetic().values()],
                                    labels=tuple(f"row {i}" for i in range(24)), spans=(NO_SPAN,) * 24))
    assert json.loads(json.dumps(fit.to_json()))["down"]["n"] == 12
