"""``run_validate`` (``bondc validate``) and the validation section of ``bondc report``, on real runs."""

from __future__ import annotations

import io
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from bondc.errors import DataError
from bondc.report.build import build_report, run_validate
from bondc.pipeline import simulate_file as simulate_run
from test_report_build import assert_self_contained, check_html

MODEL = Path(__file__).parent.parent / "models" / "series_rlc.bg"
SPECS = ["i=i_meas", "v_C=v_C_meas:nrmse=0.05,r2=0.95"]


@pytest.fixture(scope="module")
def simulated():
    """A real run of the series RLC circuit: t, i [A], v_C [V] (SI, as bondc simulate writes them)."""
    result = simulate_run(MODEL)
    return result.t, result.outputs["i"], result.outputs["v_C"]


def write_measured(path: Path, t, i, v) -> Path:
    lines = ["# measured on the bench (here: simulated, perturbed)", "time,i_meas,v_C_meas"]
    lines += [f"{float(a)!r},{float(b)!r},{float(c)!r}" for a, b, c in zip(t, i, v)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def noisy(simulated, scale: float = 1.0):
    """The run resampled on a 0.1 ms grid with 1 % (of the range) Gaussian noise, seeded, times ``scale``."""
    t, i, v = simulated
    rng = np.random.default_rng(20240501)
    grid = np.arange(0.0, float(t[-1]) + 1e-12, 1e-4)
    out = []
    for values in (i, v):
        resampled = np.interp(grid, t, values)
        noise = 0.01 * (resampled.max() - resampled.min()) * rng.standard_normal(grid.size)
        out.append(scale * (resampled + noise))
    return grid, out[0], out[1]


def test_measurements_within_noise_pass(simulated, tmp_path):
    data = write_measured(tmp_path / "bench.csv", *noisy(simulated))
    stream = io.StringIO()
    results, code = run_validate(MODEL, data=data, compare=SPECS, junit=tmp_path / "junit.xml", stream=stream)
    assert code == 0
    assert [r.passed for r in results] == [True, True]
    for result in results:
        assert result.nrmse == pytest.approx(0.01, rel=0.3)       # the noise put in, found again
        assert result.r2 > 0.99
    text = stream.getvalue()
    assert "RMSE" in text and "NRMSE" in text and "R²" in text and "2 of 2 signals passed" in text
    assert text.count("pass") >= 2 and "FAIL" not in text
    suite = ET.parse(tmp_path / "junit.xml").getroot()
    assert suite.get("tests") == "2" and suite.get("failures") == "0"


@pytest.mark.slow
def test_scaled_measurements_fail_with_exit_1(simulated, tmp_path):
    data = write_measured(tmp_path / "bench.csv", *noisy(simulated, scale=1.3))
    stream = io.StringIO()
    junit = tmp_path / "results" / "junit.xml"
    report = tmp_path / "out" / "validation.html"
    results, code = run_validate(MODEL, data=data, compare=SPECS, junit=junit, output=report, stream=stream,
                                 date="2024-05-01")
    assert code == 1
    assert [r.passed for r in results] == [False, False]
    text = stream.getvalue()
    assert text.count("FAIL") >= 2 and "0 of 2 signals passed" in text
    assert re.search(r"v_C=v_C_meas: nrmse = [0-9.]+ \(required <= 0.05\): FAILED", text)

    root = ET.parse(junit).getroot()
    cases = root.iter("testcase")
    names = [case.get("name") for case in cases]
    assert names == ["i=i_meas", "v_C=v_C_meas"]
    assert root.get("tests") == "2" and root.get("failures") == "2"
    assert all(case.find("failure") is not None for case in root.iter("testcase"))

    html = report.read_text(encoding="utf-8")
    check_html(html)
    assert_self_contained(html)
    section = html[html.index('<section id="validation">'):html.index('<section id="source"')]
    assert section.count('<span class="badge fail">FAIL</span>') == 2
    assert "bench.csv" in section and "junit.xml" in section
    assert section.count('<svg ') == 4                            # overlay and error for each signal
    assert "i_meas (measured)" in section and "i (simulated)" in section


@pytest.mark.slow      # 7 s: a whole report
def test_report_with_data_adds_the_section_and_exits_1_when_a_signal_fails(simulated, tmp_path):
    from bondc.report.build import run_report

    data = write_measured(tmp_path / "bench.csv", *noisy(simulated, scale=1.3))
    target = build_report(MODEL, data=data, compare=SPECS, output=tmp_path / "r.html", date="2024-05-01")
    html = target.read_text(encoding="utf-8")
    assert '<section id="validation">' in html and html.count("badge fail") == 2
    errors = io.StringIO()
    target, code = run_report(MODEL, data=data, compare=SPECS, output=tmp_path / "r2.html", errors=errors)
    assert code == 1 and target.exists() and "validation failed: i=i_meas, v_C=v_C_meas" in errors.getvalue()
    good = write_measured(tmp_path / "good.csv", *noisy(simulated))
    _, code = run_report(MODEL, data=good, compare=SPECS, output=tmp_path / "r3.html", errors=io.StringIO())
    assert code == 0


@pytest.mark.parametrize("csv, spec, code, words", [
    ("time,i_meas\n0,1\n0.001,2\n", "i=current", "E953", "no column 'current'"),
    ("time,i_meas\n0,1\n0.002,2\n0.001,3\n", "i=i_meas", "E952", "time must increase strictly"),
    ("time,i_meas\n5,1\n6,2\n", "i=i_meas", "E956", "share no time"),
    ("time,i_meas\n0,1\n0.001,2\n", "speed=i_meas", "E954", "not a simulated signal"),
])
def test_bad_measured_data_is_a_clear_data_error(tmp_path, csv, spec, code, words):
    data = tmp_path / "bad.csv"
    data.write_text(csv, encoding="utf-8")
    junit = tmp_path / "junit.xml"
    with pytest.raises(DataError) as excinfo:
        run_validate(MODEL, data=data, compare=[spec], junit=junit, output=tmp_path / "r.html")
    [diagnostic] = excinfo.value.diagnostics
    assert diagnostic.code == code and words in diagnostic.message
    assert not junit.exists() and not (tmp_path / "r.html").exists()


def test_incomplete_simulation_does_not_validate(simulated, tmp_path, capsys):
    """A run that stops early is compared over what it computed, and validation fails (exit 1)."""
    model = tmp_path / "failing.bg"
    original = MODEL.read_text(encoding="utf-8")
    text = original.replace("input u [V] = step(t, t_step)*U0", "input u [V] = step(t, t_step)*U0*sqrt(0.01 - t)/0.1")
    assert text != original
    model.write_text(text, encoding="utf-8")
    data = write_measured(tmp_path / "bench.csv", *noisy(simulated))
    results, code = run_validate(model, data=data, compare=["v_C=v_C_meas:r2=-100,nrmse=10"],
                                 stream=io.StringIO())
    assert code == 1 and results[0].passed
    assert results[0].t_end < 0.0101
    assert "E810" in capsys.readouterr().err


def test_an_output_declared_in_millimetres_is_validated_in_millimetres(tmp_path):
    """An output declared [mm] against a column measured in [mm] that is off by 0.5 mm everywhere: the
    RMSE and the largest error are 0.5 (mm) in the table and the JUnit file, and an rmse tolerance
    is read in millimetres too (0.4 fails, 0.6 passes). In SI, 5e-4 m, both would have passed."""
    model = tmp_path / "msd.bg"
    model.write_text((Path(__file__).parent.parent / "models" / "mass_spring_damper.bg").read_text()
                     .replace("output x        [m]   = spring.q", "output x [mm] = spring.q"), encoding="utf-8")
    assert "output x [mm] = spring.q" in model.read_text()
    result = simulate_run(model)
    lines = ["t [s],x_meas [mm]"] + [f"{float(t)!r},{float(x) * 1e3 + 0.5!r}"
                                       for t, x in zip(result.t, result.outputs["x"])]
    data = tmp_path / "bench.csv"
    data.write_text("\n".join(lines) + "\n", encoding="utf-8")
    outcomes = {}
    for limit in (0.4, 0.6):
        stream = io.StringIO()
        results, code = run_validate(model, data=data, compare=[f"x=x_meas:rmse={limit}"],
                                     junit=tmp_path / f"junit{limit}.xml", stream=stream)
        (signal,) = results
        assert signal.rmse == pytest.approx(0.5, rel=1e-9) and signal.maxabs == pytest.approx(0.5, rel=1e-9)
        outcomes[limit] = (code, signal.passed)
        row = next(line for line in stream.getvalue().splitlines() if line.startswith("x "))
        assert row.split()[2:5] == ["mm", str(result.t.size), "0.5"]
        junit = ET.parse(tmp_path / f"junit{limit}.xml").getroot()
        rmse = [p.get("value") for p in junit.iter("property") if p.get("name") == "rmse"]
        assert [float(value) for value in rmse] == pytest.approx([0.5], rel=1e-6)
    assert outcomes == {0.4: (1, False), 0.6: (0, True)}


def test_a_measurement_sampled_more_coarsely_than_the_signal_changes_is_compared_sample_by_sample(tmp_path):
    """A 100 Hz PWM (duty 0.3) into an RL circuit (tau = 1 ms): the current measured every 1.3 ms,
    written from its closed form (exponentials between the edges). The model evaluated at those
    samples equals them to the solver's tolerance; interpolating the samples onto the solver's
    steps instead would miss the ripple between them (an NRMSE of several tenths)."""
    U, R, L, f, duty = 12.0, 2.0, 2e-3, 100.0, 0.3
    tau = L / R
    model = tmp_path / "rl.bg"
    model.write_text(f"""model PwmRL
  MSe bridge : e = {U}*pwm(t, {f}, {duty})
  R winding : e = {R}*f
  I coil : f = p/{L}
  1 loop
  bridge -> loop
  loop -> winding
  loop -> coil
  output i [A] = coil.f
  experiment run
    t_end = 50 [ms]
    rtol = 1e-9
    atol = 1e-12
  end
end
""")

    def current(time):
        i, t0 = 0.0, 0.0
        edges = sorted({k / f for k in range(6)} | {(k + duty) / f for k in range(5)})
        for edge in edges[1:] + [np.inf]:
            on = ((t0 * f) % 1.0) < duty - 1e-9
            end = min(edge, time)
            target = U / R if on else 0.0
            i = target + (i - target) * np.exp(-(end - t0) / tau)
            if end >= time:
                return i
            t0 = edge
        return i

    times = np.arange(0.0, 0.05, 1.3e-3)
    data = tmp_path / "bench.csv"
    data.write_text("t,i_meas\n" + "".join(f"{float(t)!r},{float(current(t))!r}\n" for t in times))
    results, code = run_validate(model, data=data, compare=["i=i_meas:nrmse=1e-6"], stream=io.StringIO())
    (result,) = results
    assert code == 0 and result.n_samples == times.size
    np.testing.assert_allclose(result.t, times)
    assert result.maxabs < 1e-7 * U / R


def test_a_measured_column_of_another_quantity_is_an_error_not_a_comparison(tmp_path):
    """v_C [V] against a column in A, i [A] against a column in kg: E958 each; i against a column in mA
    (the same quantity) is compared, in amperes."""
    t = np.linspace(0.0, 0.01, 11)
    for column, spec, code in (("v [A]", "v_C=v", "E958"), ("i_meas [kg]", "i=i_meas", "E958")):
        data = tmp_path / "bench.csv"
        data.write_text(f"t,{column}\n" + "".join(f"{float(x)!r},0.0\n" for x in t))
        with pytest.raises(DataError) as caught:
            run_validate(MODEL, data=data, compare=[spec], stream=io.StringIO())
        assert caught.value.diagnostics[0].code == code
        assert "measure different quantities" in caught.value.diagnostics[0].message
    data.write_text("t,i_meas [mA]\n" + "".join(f"{float(x)!r},0.0\n" for x in t))
    (result,), _ = run_validate(MODEL, data=data, compare=["i=i_meas"], stream=io.StringIO())
    assert result.n_samples == t.size


@pytest.mark.parametrize("name, text, status", [
    ("missing.csv", None, 2),           # a file that cannot be read: an I/O error, as the README says
    ("folder", "", 2),
    ("empty.csv", "time,i_meas\n", 1),  # a file read whose data is wrong: an error of the data
])
def test_validate_exits_2_for_a_data_file_it_cannot_read_and_1_for_bad_data(tmp_path, name, text, status):
    from bondc.cli import main

    data = tmp_path / name
    if name == "folder":
        data.mkdir()
    elif text is not None:
        data.write_text(text, encoding="utf-8")
    assert main(["validate", str(MODEL), "--data", str(data), "--compare", "i=i_meas"]) == status
