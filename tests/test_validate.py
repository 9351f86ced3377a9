"""Validation against measured data: CSV loading, compare specs, metrics, pass/fail, JUnit XML."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from bondc.errors import DataError
from bondc.analysis.validate import (
    DEFAULT_TOLERANCES, CompareSpec, compare, junit_xml, load_measured_csv, metrics, parse_compare_spec,
    write_junit,
)


def write(tmp_path: Path, text: str, name: str = "data.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def error_of(excinfo) -> tuple[str, str, object]:
    [diagnostic] = excinfo.value.diagnostics
    return diagnostic.code, diagnostic.message, diagnostic


# ---------------------------------------------------------------- load_measured_csv

def test_first_column_is_time_by_default(tmp_path):
    data = load_measured_csv(write(tmp_path, "seconds,x,y\n0,1,2\n0.5,3,4\n1.0,5,6\n"))
    assert list(data) == ["t", "x", "y"]
    np.testing.assert_array_equal(data["t"], [0, 0.5, 1.0])
    np.testing.assert_array_equal(data["y"], [2, 4, 6])
    assert all(a.dtype == float for a in data.values())


@pytest.mark.parametrize("header", ["x,t,y", "x,time,y", "x,Time,y", "x,T,y"])
def test_column_named_t_or_time_is_time(tmp_path, header):
    data = load_measured_csv(write(tmp_path, f"{header}\n5,0,1\n6,1,2\n"))
    assert list(data) == ["t", "x", "y"]
    np.testing.assert_array_equal(data["t"], [0, 1])
    np.testing.assert_array_equal(data["x"], [5, 6])


def test_comments_blank_lines_spaces_and_bom_are_accepted(tmp_path):
    path = tmp_path / "d.csv"
    path.write_bytes("\ufeff# measured on rig 2\nt, omega\n\n0, 1.5\n 1 ,2e1\n".encode("utf-8"))
    data = load_measured_csv(path)
    np.testing.assert_array_equal(data["omega"], [1.5, 20.0])


def test_required_columns(tmp_path):
    path = write(tmp_path, "t,omega,torque\n0,1,2\n1,2,3\n")
    assert set(load_measured_csv(path, columns=["omega"])) == {"t", "omega", "torque"}
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(path, columns=["omgea"])
    code, message, diagnostic = error_of(excinfo)
    assert code == "E953" and "'omgea'" in message
    assert diagnostic.hint == "did you mean 'omega'?"


def test_missing_file(tmp_path):
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(tmp_path / "nope.csv")
    assert error_of(excinfo)[0] == "E950" and "does not exist" in error_of(excinfo)[1]


@pytest.mark.parametrize("text, words", [
    ("", "is empty"),
    ("# only a comment\n\n", "is empty"),
    ("t,x\n", "no data rows"),
])
def test_empty_file(tmp_path, text, words):
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(write(tmp_path, text))
    code, message, _ = error_of(excinfo)
    assert code == "E950" and words in message


@pytest.mark.parametrize("cell, words", [("abc", "'abc' is not a number"), ("", "the cell is empty"),
                                         ("nan", "'nan' is not a number"), ("inf", "'inf' is not a number")])
def test_non_numeric_cell_names_line_and_column(tmp_path, cell, words):
    path = write(tmp_path, f"t,x,y\n0,1,2\n0.1,{cell},3\n")
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(path)
    code, message, diagnostic = error_of(excinfo)
    assert code == "E951"
    assert "line 3" in message and "column 'x'" in message and words in message
    assert (diagnostic.span.file, diagnostic.span.line, diagnostic.span.column) == (str(path), 3, 5)


@pytest.mark.parametrize("times, line", [("0,1,0.5", 4), ("0,1,1", 4), ("2,1,3", 3)])
def test_time_must_increase_strictly(tmp_path, times, line):
    rows = "".join(f"{t},{i}\n" for i, t in enumerate(times.split(",")))
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(write(tmp_path, "t,x\n" + rows))
    code, message, diagnostic = error_of(excinfo)
    assert code == "E952" and f"line {line}" in message and diagnostic.span.line == line


def test_time_error_explains_which_column_is_time(tmp_path):
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(write(tmp_path, "x,y\n1,0\n0,1\n"))
    assert "first column" in error_of(excinfo)[2].hint


def test_ragged_row_and_bad_header(tmp_path):
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(write(tmp_path, "t,x\n0,1\n1,2,3\n"))
    assert error_of(excinfo)[0] == "E957" and "line 3 " in error_of(excinfo)[1]
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(write(tmp_path, "t,x,x\n0,1,2\n"))
    assert error_of(excinfo)[0] == "E957" and "twice" in error_of(excinfo)[1]
    with pytest.raises(DataError) as excinfo:
        load_measured_csv(write(tmp_path, "t,,x\n0,1,2\n"))
    assert error_of(excinfo)[0] == "E957" and "no name" in error_of(excinfo)[1]


# ---------------------------------------------------------------- parse_compare_spec

def test_spec_default_tolerance():
    spec = parse_compare_spec("torque=tau_meas")
    assert (spec.output, spec.column, dict(spec.tolerances)) == ("torque", "tau_meas", {"nrmse": 0.05})
    assert dict(DEFAULT_TOLERANCES) == {"nrmse": 0.05}


@pytest.mark.parametrize("text, expected", [
    ("x=x_meas:nrmse=0.1", {"nrmse": 0.1}),
    ("x=x_meas:rmse=1e-3", {"rmse": 0.001}),
    ("x=x_meas:maxabs=2", {"maxabs": 2.0}),
    ("x=x_meas:r2=0.9", {"r2": 0.9}),
    (" x = x_meas : NRMSE = 0.02 , r2=0.95 ", {"nrmse": 0.02, "r2": 0.95}),
])
def test_spec_tolerances(text, expected):
    spec = parse_compare_spec(text)
    assert (spec.output, spec.column, dict(spec.tolerances)) == ("x", "x_meas", expected)


def test_spec_column_may_contain_spaces_and_output_dots():
    spec = parse_compare_spec("spring.q=rod travel [mm]")
    assert (spec.output, spec.column) == ("spring.q", "rod travel [mm]")


@pytest.mark.parametrize("text, words", [
    ("x", "cannot read the comparison"),
    ("=col", "cannot read the comparison"),
    ("x=", "cannot read the comparison"),
    ("x y=col", "is not a signal name"),
    ("x=a=b", "more than one '='"),
    ("x=col:", "no tolerances"),
    ("x=col:nrmse", "cannot read the tolerance"),
    ("x=col:nrmse=", "cannot read the tolerance"),
    ("x=col:nrsme=0.1", "unknown metric 'nrsme'"),
    ("x=col:rmse=abc", "is not a number"),
    ("x=col:rmse=nan", "is not a number"),
    ("x=col:rmse=-1", "is negative"),
    ("x=col:r2=1.5", "above 1"),
    ("x=col:rmse=1,rmse=2", "twice"),
])
def test_spec_errors(text, words):
    with pytest.raises(DataError) as excinfo:
        parse_compare_spec(text)
    code, message, diagnostic = error_of(excinfo)
    assert code == "E955" and words in message, message


def test_spec_unknown_metric_suggests():
    with pytest.raises(DataError) as excinfo:
        parse_compare_spec("x=col:nrsme=0.1")
    assert error_of(excinfo)[2].hint == "did you mean 'nrmse'?"


# ---------------------------------------------------------------- metrics and compare

def test_metrics_by_hand():
    m = metrics(np.array([1.0, 2.0, 4.0]), np.array([1.0, 3.0, 3.0]))
    # errors 0, -1, 1: RMSE sqrt(2/3); measured range 2; max 1;
    # SS_res 2, measured mean 7/3, SS_tot 16/9 + 4/9 + 4/9 = 8/3, R² = 1 - 2/(8/3) = 0.25
    assert m["rmse"] == pytest.approx(math.sqrt(2 / 3))
    assert m["nrmse"] == pytest.approx(math.sqrt(2 / 3) / 2)
    assert m["maxabs"] == pytest.approx(1.0)
    assert m["r2"] == pytest.approx(0.25)


def test_metrics_of_a_perfect_and_a_constant_signal():
    assert metrics(np.array([1.0, 2.0]), np.array([1.0, 2.0])) == {"rmse": 0.0, "nrmse": 0.0, "maxabs": 0.0, "r2": 1.0}
    flat = metrics(np.array([1.0, 1.0]), np.array([1.0, 1.0]))
    assert flat["nrmse"] == 0.0 and flat["r2"] == 1.0
    off = metrics(np.array([2.0, 2.0]), np.array([1.0, 1.0]))
    assert off["nrmse"] == math.inf and math.isnan(off["r2"])


def simulated():
    t = np.linspace(0.0, 2.0, 401)
    return t, {"x": 0.0125 * (1 - np.exp(-3 * t) * np.cos(20 * t)), "v": np.sin(3 * t)}


def test_measured_with_small_noise_passes_and_scaled_fails():
    t, sim = simulated()
    rng = np.random.default_rng(42)
    t_meas = np.linspace(0.0, 2.0, 157)                 # another grid: interpolation aligns them
    x_meas = np.interp(t_meas, t, sim["x"])
    measured = {"t": t_meas,
                "x_noisy": x_meas + rng.normal(0.0, 0.002 * np.ptp(x_meas), t_meas.size),
                "x_scaled": 1.3 * x_meas}
    specs = [parse_compare_spec("x=x_noisy"), parse_compare_spec("x=x_scaled")]
    noisy, scaled = compare(t, sim, measured, specs)
    assert noisy.passed and noisy.nrmse < 0.01 and noisy.r2 > 0.99
    assert not scaled.passed and scaled.nrmse > 0.05
    assert [c.passed for c in scaled.checks] == [False]
    assert noisy.n_samples == t.size


def test_compare_by_hand_on_tiny_arrays():
    sim_t = np.array([0.0, 1.0, 2.0, 3.0])
    sim = {"y": np.array([0.0, 1.0, 2.0, 3.0])}
    measured = {"t": np.array([0.5, 2.5]), "m": np.array([1.0, 3.0])}   # y_meas = t + 0.5 on [0.5, 2.5]
    [result] = compare(sim_t, sim, measured, [parse_compare_spec("y=m:rmse=0.6,maxabs=0.5,r2=0.5")])
    # overlap [0.5, 2.5] holds simulated t = 1, 2: simulated 1, 2; measured 1.5, 2.5
    assert (result.n_samples, result.t_start, result.t_end) == (2, 1.0, 2.0)
    np.testing.assert_allclose(result.measured, [1.5, 2.5])
    assert result.rmse == pytest.approx(0.5)
    assert result.nrmse == pytest.approx(0.5)
    assert result.maxabs == pytest.approx(0.5)
    assert result.r2 == pytest.approx(1 - 0.5 / 0.5)
    assert {c.metric: c.passed for c in result.checks} == {"rmse": True, "maxabs": True, "r2": False}
    assert not result.passed


def test_compare_errors():
    t, sim = simulated()
    measured = {"t": t, "x_meas": sim["x"]}
    with pytest.raises(DataError) as excinfo:
        compare(t, sim, measured, [parse_compare_spec("xx=x_meas")])
    assert error_of(excinfo)[0] == "E954" and error_of(excinfo)[2].hint == "did you mean 'x'?"
    with pytest.raises(DataError) as excinfo:
        compare(t, sim, measured, [parse_compare_spec("x=x_mes")])
    assert error_of(excinfo)[0] == "E953" and error_of(excinfo)[2].hint == "did you mean 'x_meas'?"
    with pytest.raises(DataError) as excinfo:
        compare(t, sim, measured, [parse_compare_spec("x=t")])
    assert error_of(excinfo)[0] == "E953"


@pytest.mark.parametrize("t_meas, words", [
    ([5.0, 6.0], "share no time"),
    ([2.0, 3.0], "fewer than two"),               # touches the simulation at its last point only
])
def test_no_overlap_in_time(t_meas, words):
    t, sim = simulated()
    with pytest.raises(DataError) as excinfo:
        compare(t, sim, {"t": np.array(t_meas), "x_meas": np.array([1.0, 2.0])}, [parse_compare_spec("x=x_meas")])
    code, message, _ = error_of(excinfo)
    assert code == "E956" and words in message


# ---------------------------------------------------------------- JUnit

def results_pass_and_fail():
    t, sim = simulated()
    measured = {"t": t, "x_good": sim["x"] * 1.001, "v_bad": sim["v"] * 1.3}
    return compare(t, sim, measured, [parse_compare_spec("x=x_good"), parse_compare_spec("v=v_bad:nrmse=0.05,r2=0.99")])


def test_junit_lists_both_signals_and_parses():
    text = junit_xml(results_pass_and_fail(), "validation <rig & 2>")
    assert text.startswith('<?xml version="1.0" encoding="utf-8"?>')
    root = ET.fromstring(text.split("\n", 1)[1])
    assert root.tag == "testsuites"
    [suite] = root.findall("testsuite")
    assert (suite.get("name"), suite.get("tests"), suite.get("failures"), suite.get("errors")) == \
        ("validation <rig & 2>", "2", "1", "0")
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == ["x=x_good", "v=v_bad"]
    assert cases[0].find("failure") is None
    failure = cases[1].find("failure")
    assert failure is not None and failure.get("type") == "ToleranceExceeded"
    assert "nrmse = " in failure.get("message") and "required <= 0.05" in failure.get("message")
    assert "rmse = " in failure.text and "r2 = " in failure.text
    properties = {p.get("name"): float(p.get("value")) for p in cases[1].find("properties")}
    assert set(properties) == {"rmse", "nrmse", "maxabs", "r2"} and properties["nrmse"] > 0.05


def test_write_junit(tmp_path):
    results = results_pass_and_fail()
    path = tmp_path / "junit.xml"
    write_junit(results, "suite", path)
    assert path.read_text(encoding="utf-8") == junit_xml(results, "suite")
    assert [p.name for p in tmp_path.iterdir()] == ["junit.xml"]      # no temporary left behind


def test_result_summary_and_spec_text():
    result = results_pass_and_fail()[1]
    assert result.name == "v=v_bad" and str(result.spec) == "v=v_bad:nrmse=0.05,r2=0.99"
    assert "FAILED" in result.summary()
    assert isinstance(result.spec, CompareSpec)


def test_junit_with_control_characters_in_names_is_still_xml():
    # a measured column named "v\x01bad" (from --compare "v=v\x01bad") and a suite name with \x0b
    t, sim = simulated()
    measured = {"t": t, "x\x01good": sim["x"] * 1.001}
    results = compare(t, sim, measured, [parse_compare_spec("x=x\x01good")])
    text = junit_xml(results, "rig\x0b2")
    root = ET.fromstring(text.split("\n", 1)[1])             # parses: no character XML cannot hold
    [suite] = root.findall("testsuite")
    assert suite.get("name") == "rig\\x0b2"
    assert [case.get("name") for case in suite.findall("testcase")] == ["x=x\\x01good"]
