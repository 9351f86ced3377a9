"""bondc bode: frequency responses against closed-form transfer functions, margins against hand-derived
values, the verification against the nonlinear model, the files it writes and its diagnostics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from bondc.analysis.bode import bode, frequency_response, parse_frequency
from bondc.cli import main
from bondc.pipeline import derive_file

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"
FIXTURES = Path(__file__).parent / "fixtures" / "bode"

DB, DEG = 0.01, 0.1         # the tolerances of the issue: 0.01 dB and 0.1 degree


def response_of(path, **options):
    return bode(derive_file(Path(path), cache=False).state_space, **options)


def assert_matches(response, expected):
    """``response`` against ``expected(s)``, a closed form evaluated at s = j*2*pi*f."""
    s = 2j * np.pi * response.frequency_hz
    g = expected(s)
    magnitude = 20 * np.log10(np.abs(g))
    assert np.max(np.abs(response.magnitude_db - magnitude)) < DB
    # the closed form's phase, made continuous the same way and compared modulo nothing: the
    # reported phase starts at its principal value and never jumps
    phase = np.degrees(np.unwrap(np.angle(g)))
    assert np.max(np.abs(response.phase_deg - phase)) < DEG
    assert np.max(np.abs(np.diff(response.phase_deg))) < 90


# ----------------------------------------------------------------- closed forms

def test_mass_spring_damper_force_to_position_and_velocity():
    m, k, b = 2.0, 800.0, 12.0
    result = response_of(MODELS / "mass_spring_damper.bg", inputs=["F"], outputs=["x", "v"])
    x, v = result.responses
    assert (x.input, x.output, v.output) == ("F", "x", "v")
    assert_matches(x, lambda s: 1 / (m * s**2 + b * s + k))
    assert_matches(v, lambda s: s / (m * s**2 + b * s + k))
    # the default range: a decade around the one mode, sqrt(k/m) = 20 rad/s
    wn = math.sqrt(k / m) / (2 * math.pi)
    assert x.frequency_hz[0] == pytest.approx(wn / 10) and x.frequency_hz[-1] == pytest.approx(wn * 10)
    assert x.frequency_hz.size == 400
    assert x.unit == "m/N" and v.unit == "(m/s)/N"


def test_series_rlc_voltage_to_current():
    R, L, C = 10.0, 10e-3, 100e-6
    result = response_of(MODELS / "series_rlc.bg", outputs=["i"], low="10 [rad/s]", high="1 [MHz]", points=300)
    (i,) = result.responses
    assert i.frequency_hz[0] == pytest.approx(10 / (2 * math.pi))
    assert i.frequency_hz[-1] == pytest.approx(1e6)
    assert_matches(i, lambda s: s * C / (L * C * s**2 + R * C * s + 1))
    # resonance at 1/sqrt(LC): the current is u/R there (0 deg)
    peak = int(np.argmax(i.magnitude_db))
    assert i.frequency_hz[peak] == pytest.approx(1000 / (2 * math.pi), rel=0.03)


def test_dc_motor_with_inductance_and_gear_voltage_to_speed():
    Ra, La, Kt, Jm, bm, n, JL, bL = 1.2, 2.5e-3, 0.05, 2.0e-5, 1.0e-5, 10.0, 5.0e-3, 1.0e-3
    J, bv = Jm + JL / n**2, bm + bL / n**2       # the load reflected through the gear

    def motor(s):
        return Kt / ((La * s + Ra) * (J * s + bv) + Kt**2)

    result = response_of(MODELS / "dc_motor_gear.bg", outputs=["speed_motor", "speed", "speed_rpm", "current"])
    motor_speed, load_speed, load_rpm, current = result.responses
    assert_matches(motor_speed, motor)
    assert_matches(load_speed, lambda s: motor(s) / n)
    # an output declared in rpm: the response is of its SI value (rad/s), as A, B, C, D are
    assert_matches(load_rpm, lambda s: motor(s) / n)
    assert load_rpm.unit == "(rad/s)/V"
    assert_matches(current, lambda s: (J * s + bv) / ((La * s + Ra) * (J * s + bv) + Kt**2))


def test_nonlinear_spring_at_equilibrium_against_its_small_signal_transfer_function():
    m, k1, k3, b, F0 = 1.0, 100.0, 1e4, 4.0, 10.0
    # the equilibrium by hand: k3*x^3 + k1*x - F0 = 0 (Cardano: one real root)
    p, q = k1 / k3, -F0 / k3
    root = math.sqrt(q**2 / 4 + p**3 / 27)
    x0 = math.copysign(abs(-q / 2 + root) ** (1 / 3), -q / 2 + root) + math.copysign(abs(-q / 2 - root) ** (1 / 3),
                                                                                      -q / 2 - root)
    assert k1 * x0 + k3 * x0**3 == pytest.approx(F0)
    stiffness = k1 + 3 * k3 * x0**2
    result = response_of(FIXTURES / "cubic_spring.bg", outputs=["x"], at="equilibrium")
    assert result.linearization.x0[list(result.linearization.states).index("spring.q")] == pytest.approx(x0)
    assert_matches(result.responses[0], lambda s: 1 / (m * s**2 + b * s + stiffness))
    assert not result.warnings


def test_sparse_and_dense_solves_agree():
    """The sparse path (more than DENSE_STATES states) against the dense one on the same matrices:
    a random stable system of 80 states."""
    from bondc.analysis import bode as module

    rng = np.random.default_rng(1)
    n = 80
    A = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.05) - 3 * np.eye(n)
    B, C, D = rng.normal(size=(n, 2)), rng.normal(size=(3, n)), rng.normal(size=(3, 2))
    f = np.geomspace(0.01, 100, 50)
    sparse = frequency_response(A, B, C, D, f)
    dense = np.stack([C @ np.linalg.solve(2j * np.pi * fk * np.eye(n) - A, B) + D for fk in f], axis=-1)
    assert n > module.DENSE_STATES
    np.testing.assert_allclose(sparse, dense, rtol=1e-9, atol=1e-12)


# ----------------------------------------------------------------- margins

def test_margins_of_three_lags_against_hand_derived_values():
    K = 4.0
    result = response_of(FIXTURES / "third_order_loop.bg", points=2000)
    margins = result.responses[0].margins
    # phase -180 deg where each lag gives -60 deg: w = sqrt(3); there |L| = K/8
    assert margins.gain_margin_db == pytest.approx(20 * math.log10(8 / K), abs=DB)
    assert margins.phase_crossover_hz == pytest.approx(math.sqrt(3) / (2 * math.pi), rel=1e-3)
    w = math.sqrt(K ** (2 / 3) - 1)
    assert margins.phase_margin_deg == pytest.approx(180 - 3 * math.degrees(math.atan(w)), abs=DEG)
    assert margins.gain_crossover_hz == pytest.approx(w / (2 * math.pi), rel=1e-3)


def test_margins_agree_with_python_control_on_the_state_space_model():
    import control

    result = response_of(FIXTURES / "third_order_loop.bg", points=2000)
    lin = result.linearization
    gm, pm, _, wpc, wgc, _ = control.stability_margins(control.ss(lin.A, lin.B, lin.C, lin.D))
    margins = result.responses[0].margins
    assert margins.gain_margin_db == pytest.approx(20 * math.log10(gm), abs=DB)
    assert margins.phase_margin_deg == pytest.approx(pm, abs=DEG)


def test_no_crossing_no_margin():
    margins = response_of(MODELS / "mass_spring_damper.bg", outputs=["x"]).responses[0].margins
    assert margins.gain_margin_db is None and margins.phase_margin_deg is None
    assert margins.gain_crossover_hz is None and margins.phase_crossover_hz is None


# ----------------------------------------------------------------- verification

def test_verify_on_a_smooth_nonlinear_model_agrees_within_one_percent():
    result = response_of(FIXTURES / "cubic_spring.bg", outputs=["x"], at="equilibrium", verify_model=True)
    response = result.responses[0]
    assert response.amplitude == pytest.approx(0.1)      # 1 % of F0
    assert len(response.checks) == 5
    band = (response.frequency_hz[0], response.frequency_hz[-1])
    for check in response.checks:
        assert band[0] < check.frequency_hz < band[1]
        assert abs(check.error_db) < 20 * math.log10(1.01)
        assert abs(check.error_deg) < math.degrees(0.01)
    assert not [d for d in result.warnings if d.code == "W943"]


def test_verify_sees_the_nonlinearity_at_a_large_amplitude():
    """The same check is not blind: a sine as large as the force itself moves the mass far along
    the hardening spring, and the response at resonance differs from the linear one."""
    result = response_of(FIXTURES / "cubic_spring.bg", outputs=["x"], at="equilibrium", verify_model=True,
                         amplitude="8 [N]")
    errors = [abs(c.error_db) for c in result.responses[0].checks]
    assert max(errors) > 0.5
    assert any(d.code == "W943" for d in result.warnings)


# ----------------------------------------------------------------- large models

@pytest.mark.slow
def test_the_1000_section_chain(tmp_path):
    from benchmarks.chain import chain_source

    path = tmp_path / "chain.bg"
    path.write_text(chain_source(1000))
    result = response_of(path, outputs=["speed1"], points=100)
    response = result.responses[0]
    assert np.all(np.isfinite(response.magnitude_db))
    # at low frequency the chain is one spring column fixed at the wall: x_end/F -> 1/k per section
    low = response_of(path, outputs=["stretch_end"], points=2, low=1e-5, high=1e-4).responses[0]
    assert abs(low.response[0]) == pytest.approx(1 / 1000.0, rel=1e-3)


# ----------------------------------------------------------------- command line and files

def run(capsys, *argv):
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_json_shape(capsys):
    status, out, _ = run(capsys, "bode", str(MODELS / "mass_spring_damper.bg"), "--output", "x", "--points", "50",
                         "--json")
    assert status == 0
    data = json.loads(out)
    assert {"input", "output", "frequency_hz", "magnitude_db", "phase_deg", "margins"} <= set(data)
    assert (data["input"], data["output"]) == ("F", "x")
    assert len(data["frequency_hz"]) == len(data["magnitude_db"]) == len(data["phase_deg"]) == 50
    assert set(data["margins"]) == {"gain_margin_db", "phase_crossover_hz", "phase_margin_deg", "gain_crossover_hz"}
    status, out, _ = run(capsys, "bode", str(MODELS / "mass_spring_damper.bg"), "--output", "x", "--output", "v",
                         "--points", "5", "--json")
    pairs = json.loads(out)
    assert isinstance(pairs, list) and [(p["input"], p["output"]) for p in pairs] == [("F", "x"), ("F", "v")]


def test_csv_has_units_in_its_header(tmp_path, capsys):
    target = tmp_path / "bode.csv"
    status, _, _ = run(capsys, "bode", str(MODELS / "series_rlc.bg"), "--output", "i", "--output", "v_C",
                       "--points", "7", "-o", str(target))
    assert status == 0
    lines = target.read_text().splitlines()
    assert lines[0].split(",") == ["frequency [Hz]", "i/u gain [A/V]", "i/u magnitude [dB]", "i/u phase [deg]",
                                   "v_C/u gain [V/V]", "v_C/u magnitude [dB]", "v_C/u phase [deg]"]
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    assert rows.shape == (7, 7)
    np.testing.assert_allclose(20 * np.log10(rows[:, 1]), rows[:, 2])


def test_svg_is_deterministic(tmp_path, capsys):
    first, second = tmp_path / "a.svg", tmp_path / "b.svg"
    for target in (first, second):
        assert run(capsys, "bode", str(MODELS / "series_rlc.bg"), "--output", "i", "--points", "60",
                   "-o", str(target))[0] == 0
    text = first.read_text()
    assert text == second.read_text()
    assert text.startswith("<svg") and 'xmlns="http://www.w3.org/2000/svg"' in text
    assert "magnitude [dB]" in text and "phase [deg]" in text and "<metadata" not in text


def test_html_page_is_self_contained_and_escaped(tmp_path, capsys):
    model = tmp_path / "a&b<c>.bg"
    model.write_text((MODELS / "series_rlc.bg").read_text())
    target = tmp_path / "bode.html"
    assert run(capsys, "bode", str(model), "--output", "i", "--points", "30", "-o", str(target))[0] == 0
    page = target.read_text()
    assert "a&amp;b&lt;c&gt;.bg" in page and "a&b<c>" not in page
    assert "<script" not in page and "http://" not in page.replace('xmlns="http://www.w3.org/2000/svg"', "") \
        .replace('xmlns:xlink="http://www.w3.org/1999/xlink"', "")
    assert "Bode plot of i/u" in page


# ----------------------------------------------------------------- diagnostics

@pytest.mark.parametrize("argv, code, words", [
    (["--output", "xx"], "E942", "did you mean 'x'"),
    (["--input", "G", "--output", "x"], "E942", "no input 'G'"),
    (["--input", "k", "--output", "x"], "E943", "'k' is a parameter, not an input"),
    (["--output", "F"], "E943", "'F' is an input"),
    (["--output", "x", "--from", "10", "--to", "1"], "E944", "not below"),
    (["--output", "x", "--from", "-1"], "E944", "positive"),
    (["--output", "x", "--from", "3 [m]"], "E944", "not a unit of frequency"),
    (["--output", "x", "--from", "abc"], "E944", "not a number"),
    (["--output", "x", "--points", "1"], "E945", "from 2"),
    (["--output", "x", "--points", "many"], "E945", "whole number"),
    (["--output", "x", "-o", "bode.png"], "E947", ".png"),
    ([], "E942", "say which with --output"),
])
def test_bad_input_is_a_diagnostic(capsys, argv, code, words):
    status, out, err = run(capsys, "bode", str(MODELS / "mass_spring_damper.bg"), *argv)
    assert status == 2
    assert f"[{code}]" in err and words in err
    assert "Traceback" not in err + out


def test_no_equilibrium_is_the_linearisation_diagnostic(tmp_path, capsys):
    model = tmp_path / "free.bg"
    model.write_text("model Free\n  input F [N] = 1\n  MSe push : e = F\n  I mass : f = p/2\n  push -> mass\n"
                     "  output v [m/s] = mass.f\nend\n")
    status, _, err = run(capsys, "bode", str(model), "--at", "equilibrium")
    assert status == 1 and "[E940]" in err


def test_verify_needs_an_operating_point_at_rest(capsys):
    status, _, err = run(capsys, "bode", str(FIXTURES / "cubic_spring.bg"), "--output", "x", "--verify")
    assert status == 1 and "[E946]" in err and "--at equilibrium" in err


def test_an_operating_point_on_a_friction_switch_is_a_warning(capsys):
    status, _, err = run(capsys, "bode", str(FIXTURES / "stuck_friction.bg"), "--points", "5")
    assert status == 0
    assert "[W942]" in err and "friction.f = 0" in err and "stuck_friction.bg:15" in err
    # a smooth model at its equilibrium has none
    assert not response_of(FIXTURES / "cubic_spring.bg", outputs=["x"], at="equilibrium", points=5).warnings


def test_frequencies_with_units():
    assert parse_frequency("10 [rad/s]", "--from") == pytest.approx(10 / (2 * math.pi))
    assert parse_frequency("2 [kHz]", "--to") == pytest.approx(2000)
    assert parse_frequency("600 [rpm]", "--to") == pytest.approx(10)
    assert parse_frequency("5", "--to") == 5


# ----------------------------------------------------------------- the experiment setting and the report

def _with_setting(text: str, settings: str) -> str:
    return text.replace("    t_end = 1 [s]\n", "    t_end = 1 [s]\n" + settings, 1)


def test_the_report_shows_the_bode_plots_the_experiment_asks_for(tmp_path):
    from bondc.report.build import build_report

    model = tmp_path / "spring.bg"
    model.write_text(_with_setting((FIXTURES / "cubic_spring.bg").read_text(),
                                   '    bode = [F -> x]\n    bode_at = "equilibrium"\n'))
    page = build_report(model, output=tmp_path / "spring.html", date="2024-01-01").read_text()
    assert '<section id="frequency-response">' in page
    assert "Bode plot of x/F" in page and "Bode plot of v/F" not in page
    assert "linearised at its equilibrium point" in page
    plain = tmp_path / "plain.bg"
    plain.write_text((FIXTURES / "cubic_spring.bg").read_text())
    assert "frequency-response" not in build_report(plain, output=tmp_path / "plain.html", date="2024-01-01").read_text()


def test_the_report_says_why_a_bode_plot_is_missing(tmp_path):
    from bondc.report.build import build_report

    model = tmp_path / "free.bg"
    model.write_text("model Free\n  input F [N] = 1\n  MSe push : e = F\n  I mass : f = p/2\n  push -> mass\n"
                     "  output v [m/s] = mass.f\n  experiment run\n    t_end = 1 [s]\n    bode = [F -> v]\n"
                     "    bode_at = \"equilibrium\"\n  end\nend\n")
    page = build_report(model, output=tmp_path / "free.html", date="2024-01-01").read_text()
    assert '<section id="frequency-response">' in page and "E940" in page


@pytest.mark.parametrize("settings, code, words", [
    ("    bode = [F -> xx]\n", "E301", "no output named 'xx'"),
    ("    bode = [k1 -> x]\n", "E301", "no input named 'k1'"),
    ("    bode = 3\n", "E313", "bode lists pairs INPUT -> OUTPUT"),
    ('    bode_at = "rest"\n', "E313", '"initial" or "equilibrium"'),
])
def test_the_bode_setting_is_checked(tmp_path, capsys, settings, code, words):
    model = tmp_path / "spring.bg"
    model.write_text(_with_setting((FIXTURES / "cubic_spring.bg").read_text(), settings))
    status, _, err = run(capsys, "check", str(model))
    assert status == 1 and f"[{code}]" in err and words in err


def test_fmt_keeps_the_bode_setting(tmp_path, capsys):
    model = tmp_path / "spring.bg"
    model.write_text(_with_setting((FIXTURES / "cubic_spring.bg").read_text(), "    bode = [F->x,F  ->  v]\n"))
    status, out, _ = run(capsys, "fmt", str(model))
    assert status == 0 and "bode  = [F -> x, F -> v]" in out


def test_a_free_mass_lags_by_180_degrees_over_the_fallback_range(tmp_path):
    """x/F = 1/(m s^2): -40 dB per decade and -180 deg (not +180) at every frequency; the model has no
    mode with a frequency to choose the range from, so the fallback range is used and said."""
    from bondc.analysis.bode import FALLBACK_RANGE_HZ

    model = tmp_path / "free.bg"
    model.write_text("model Free\n  param m = 2 [kg]\n  input F [N] = 0\n  MSe push : e = F\n  I mass : f = p/m\n"
                     "  push -> mass\n  state x [m] : der(x) = mass.f, x(0) = 0\n  output y [m] = x\nend\n")
    result = response_of(model, points=50)
    response = result.responses[0]
    assert (response.frequency_hz[0], response.frequency_hz[-1]) == pytest.approx(FALLBACK_RANGE_HZ)
    np.testing.assert_allclose(response.phase_deg, -180.0, atol=1e-9)
    w = 2 * np.pi * response.frequency_hz
    np.testing.assert_allclose(response.magnitude_db, 20 * np.log10(1 / (2.0 * w**2)), atol=1e-9)
    assert any("no mode" in note for note in result.notes)


def test_doctests():
    import doctest

    from bondc.analysis import bode as module

    assert doctest.testmod(module).failed == 0


def test_the_api_checks_its_arguments():
    import bondc
    from bondc.errors import UsageError

    with pytest.raises(UsageError, match="list of names"):
        bondc.bode(MODELS / "mass_spring_damper.bg", outputs="x")
    with pytest.raises(UsageError, match="at must be one of"):
        bondc.bode(MODELS / "mass_spring_damper.bg", outputs=["x"], at="rest")
