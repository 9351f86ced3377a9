"""bondc.simulate against analytic solutions, located events, failures and output files.

Every expectation is computed here from the physics (closed-form solutions,
crossing times, table breakpoints), never from an earlier run.
"""

import importlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from bondc.errors import SimulationError, UsageError
from bondc.pipeline import simulate_file as run
from bondc.simulate import ProgressBar, simulate, write_csv, write_npz

from test_codegen import SIM, derive


# ------------------------------------------------------------ analytic models

def test_rc_charging_matches_one_minus_exp():
    # the experiment's settings (default solver, rtol 1e-6, atol 1e-12 C): a few parts in 1e6 of 10 V
    result = run(SIM / "rc.bg", dt=1e-4)
    assert result.complete
    tau = 1e3 * 1e-6
    expected = 10.0 * (1.0 - np.exp(-result.t / tau))
    np.testing.assert_allclose(result.outputs["v"], expected, rtol=0, atol=10 * 1e-6 * 10.0)
    np.testing.assert_allclose(result.t, np.arange(51) * 1e-4, rtol=0, atol=1e-15)
    # and it converges: with rtol 1e-10 the error is 1e4 times smaller
    _, ss, experiment = derive("rc")
    tight = simulate(ss, experiment, dt=1e-4, rtol=1e-10, atol=1e-16)
    np.testing.assert_allclose(tight.outputs["v"], expected, rtol=0, atol=1e-8)
    np.testing.assert_allclose(tight.outputs["i"], (10.0 - expected) / 1e3, rtol=0, atol=1e-11)


@pytest.mark.parametrize("method", ["LSODA", "Radau", "BDF"])
def test_mass_spring_damper_step_response_is_the_underdamped_solution(method):
    _, ss, experiment = derive("msd")
    result = simulate(ss, experiment, method=method, rtol=1e-9, atol=1e-13)
    assert result.complete
    m, k, b, force, t0 = 2.0, 800.0, 12.0, 10.0, 0.1
    wn, zeta = np.sqrt(k / m), b / (2 * np.sqrt(k * m))
    wd = wn * np.sqrt(1 - zeta**2)
    s = result.t - t0
    expected = np.where(s >= 0, force / k * (1 - np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / np.sqrt(1 - zeta**2)
                                                                            * np.sin(wd * s))), 0.0)
    np.testing.assert_allclose(result.outputs["x"], expected, rtol=0, atol=1e-6 * force / k)
    assert result.outputs["x"][result.t < t0].max() == 0.0          # nothing moves before the step
    assert [e[0] for e in result.events] == [t0]


@pytest.mark.parametrize("method, drift", [("CVODE", 1e-6), ("CVODE-Adams", 1e-6), ("LSODA", 1e-7)])
def test_undamped_oscillator_period_and_energy(method, drift):
    # 20 periods at rtol 1e-9: CVODE's error control (per step, in the weighted RMS norm) lets the
    # energy drift by a few parts in 1e7 (BDF damps a little); LSODA's by less than 1e-7
    _, ss, experiment = derive("oscillator")
    result = simulate(ss, experiment, method=method)
    assert result.complete
    q, t = result.states["spring.q"], result.t
    down = np.flatnonzero((q[:-1] > 0) & (q[1:] <= 0))
    # crossing times by cubic interpolation on 4 points around each sign change
    crossings = []
    for i in down:
        window = slice(max(i - 1, 0), i + 3)
        coefficients = np.polyfit(t[window] - t[i], q[window], 3)
        roots = [r.real + t[i] for r in np.roots(coefficients) if abs(r.imag) < 1e-12 and 0 <= r.real <= t[i + 1] - t[i]]
        crossings.append(roots[0])
    period = 2 * np.pi * np.sqrt(0.5 / 200.0)
    assert len(crossings) >= 5
    np.testing.assert_allclose(np.diff(crossings), period, rtol=1e-6)
    energy = result.outputs["E"]
    assert energy[0] == pytest.approx(0.5 * 200.0 * 0.01**2)
    assert np.ptp(energy) / energy[0] < drift


def test_overrides_change_the_physics():
    _, ss, experiment = derive("oscillator")
    stiff = simulate(ss, experiment, overrides={"k": 800.0}, t_end=0.5)
    q, t = stiff.states["spring.q"], stiff.t
    i = np.flatnonzero((q[:-1] > 0) & (q[1:] <= 0))[0]
    first = t[i] - q[i] * (t[i + 1] - t[i]) / (q[i + 1] - q[i])
    assert first == pytest.approx(0.25 * 2 * np.pi * np.sqrt(0.5 / 800.0), rel=1e-3)
    assert stiff.parameters["k"] == 800.0
    assert stiff.parameters["E0"] == pytest.approx(0.5 * 800.0 * 0.01**2)     # derived from k: recomputed
    np.testing.assert_allclose(stiff.outputs["E_rel"], 1.0, rtol=1e-6)
    pinned = simulate(ss, experiment, overrides={"k": 800.0, "E0": 1.0}, t_end=0.1)
    assert pinned.parameters["E0"] == 1.0                                       # given explicitly: kept
    with pytest.raises(UsageError, match="unknown parameter 'kk'"):
        simulate(ss, experiment, overrides={"kk": 1.0})


def test_sets_reach_the_model_through_run():
    result = run(SIM / "rc.bg", sets=["R=2 [kOhm]"], dt=1e-3)
    tau = 2e3 * 1e-6
    np.testing.assert_allclose(result.outputs["v"], 10.0 * (1 - np.exp(-result.t / tau)), atol=1e-4)
    assert result.parameters["R"] == 2000.0


# ------------------------------------------------------------------ events

def _friction_expected(t):
    """Mass 1 kg, push 10 N; friction 5*v below v0 = 1 m/s, 1*v + 3 N above."""
    crossing = np.log(2.0) / 5.0
    below = t < crossing
    v = np.where(below, 2 * (1 - np.exp(-5 * t)), 7 - 6 * np.exp(-(t - crossing)))
    x_cross = 2 * crossing - 0.4 * (1 - np.exp(-5 * crossing))
    x = np.where(below, 2 * t - 0.4 * (1 - np.exp(-5 * t)), x_cross + 7 * (t - crossing) - 6 * (1 - np.exp(-(t - crossing))))
    return crossing, v, x


def test_friction_threshold_crossing_is_located():
    result = run(SIM / "friction.bg")
    assert result.complete
    crossing, v, x = _friction_expected(result.t)
    (time, label), = result.events
    assert time == pytest.approx(crossing, abs=1e-8)
    assert "if" in label and "friction.e" in label and "b3.e" not in label     # the bond named by its element
    np.testing.assert_allclose(result.outputs["v"], v, atol=1e-7)
    np.testing.assert_allclose(result.states["x"], x, atol=1e-7)
    # the friction force jumps from 5 N to 4 N at the crossing; the event point keeps the value before it
    at = np.flatnonzero(result.t == time)[0]
    assert result.outputs["Ff"][at] == pytest.approx(5.0, abs=1e-6)
    assert result.outputs["Ff"][at + 1] == pytest.approx(4.0 + (result.outputs["v"][at + 1] - 1.0), abs=1e-6)


def test_friction_results_do_not_depend_on_max_step():
    _, ss, experiment = derive("friction")
    grid = np.linspace(0.0, 2.0, 201)
    free = simulate(ss, experiment, t_eval=grid)
    small = simulate(ss, experiment, t_eval=grid, max_step=1e-3)
    assert free.stats["steps"] < small.stats["steps"]
    np.testing.assert_allclose(free.outputs["v"], small.outputs["v"], atol=1e-7)
    np.testing.assert_allclose(free.states["x"], small.states["x"], atol=1e-7)
    assert free.events[0][0] == pytest.approx(small.events[0][0], abs=1e-9)


def test_table_breakpoints_split_the_integration():
    result = run(SIM / "table_force.bg")
    assert result.complete
    assert [e[0] for e in result.events] == [0.5, 1.0, 1.5]
    t = result.t
    for corner in (0.5, 1.0, 1.5):
        assert corner in t                       # a segment ends exactly at every corner
    expected = np.select([t < 0.5, t < 1.0, t < 1.5],
                         [10 * t**2, 2.5 + 10 * (t - 0.5), 7.5 + 10 * (t - 1) - 10 * (t - 1) ** 2], 10.0)
    np.testing.assert_allclose(result.states["mass.p"], expected, atol=10 * 1e-6 * 10.0)   # rtol 1e-6 of 10
    _, ss, experiment = derive("table_force")
    # Radau integrates a quadratic exactly within each segment: exact to rounding when nothing is stepped across
    exact = simulate(ss, experiment, method="Radau", t_eval=t)
    np.testing.assert_allclose(exact.states["mass.p"], expected, atol=1e-12)
    small = simulate(ss, experiment, method="Radau", max_step=1e-2, t_eval=t)
    np.testing.assert_allclose(small.states["mass.p"], expected, atol=1e-12)


def test_friction_that_sticks_at_the_threshold_slides_there():
    result = run(SIM / "friction_stick.bg", dt=0.01)
    assert result.complete
    crossing = -np.log(1 - 5.0 / 6.0) / 5.0       # v = 1.2*(1 - exp(-5t)) reaches 1 m/s
    assert result.events[0][0] == pytest.approx(crossing, abs=1e-7)
    assert result.events[0][1].startswith("sliding on")
    after = result.t > crossing
    np.testing.assert_allclose(result.outputs["v"][after], 1.0, atol=1e-7)
    np.testing.assert_allclose(result.outputs["Ff"][after], 6.0, atol=1e-5)   # friction balances the push
    assert result.stats["segments"] <= 5


def test_csv_signal_corners_split_the_integration():
    result = run(SIM / "csv_force.bg")
    assert result.complete
    assert [e for e in result.events] == [(0.5, "csv sample of force"), (1.0, "csv sample of force"),
                                          (1.5, "csv sample of force")]
    t = result.t
    expected = np.select([t < 0.5, t < 1.0, t < 1.5],
                         [10 * t**2, 2.5 + 10 * (t - 0.5), 7.5 + 10 * (t - 1) - 10 * (t - 1) ** 2], 10.0)
    np.testing.assert_allclose(result.states["mass.p"], expected, atol=1e-8)      # rtol 1e-10 of 10


def test_dense_csv_signal_caps_the_step_instead_of_splitting(tmp_path):
    samples = np.linspace(0.0, 1.0, 1001)
    force = np.sin(2 * np.pi * 3 * samples)
    rows = "\n".join(f"{a!r},{b!r}" for a, b in zip(samples.tolist(), force.tolist()))
    (tmp_path / "force.csv").write_text("t,F\n" + rows + "\n")
    (tmp_path / "m.bg").write_text(
        'model Dense\n  input F [N] = csv("force.csv", "F")\n  MSe push : e = F\n  I mass : f = p/1\n'
        '  push -> mass\n  experiment run\n    t_end = 1 [s]\n    rtol = 1e-10\n    atol = 1e-12\n  end\nend\n')
    result = run(tmp_path / "m.bg")
    assert result.complete and result.events == []                    # no segment per sample
    assert result.stats["steps"] >= 1000                               # max_step = the 1 ms spacing
    # p is the integral of the interpolated force: the trapezoid rule on the samples is exact
    exact = np.concatenate([[0.0], np.cumsum(np.diff(samples) * (force[1:] + force[:-1]) / 2)])
    i = np.clip(np.searchsorted(samples, result.t, side="right") - 1, 0, samples.size - 2)
    slope = (force[i + 1] - force[i]) / (samples[i + 1] - samples[i])
    s = result.t - samples[i]
    np.testing.assert_allclose(result.states["mass.p"], exact[i] + force[i] * s + slope * s**2 / 2, atol=1e-7)


@pytest.mark.parametrize("tolerances", [{"rtol": 1e-10, "atol": 1e-12}, {}], ids=["tight", "experiment"])
def test_nonlinear_algebraic_loop_is_solved_at_every_step(tolerances):
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    _, ss, experiment = derive("nonlinear_loop")
    assert len(ss.algebraic_blocks) == 1
    grid = np.linspace(0.0, 1.0, 11)
    # With the experiment's own (default) tolerances the loop's solver once gave up on a
    # residual already at rounding level; the run must complete either way.
    result = simulate(ss, experiment, t_eval=grid, **tolerances)
    assert result.complete
    loose = not tolerances

    def voltage(i):         # r2 (u = f^3 + f) and r3 (u = 3 f) in parallel carry i
        return brentq(lambda u: brentq(lambda f: f**3 + f - u, -50, 50) + u / 3.0 - i, -100, 100, xtol=1e-14)

    reference = solve_ivp(lambda t, y: [(10.0 - 2.0 * y[0] - voltage(y[0])) / 0.5], (0.0, 1.0), [0.0],
                          t_eval=grid, rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(result.outputs["i"], reference.y[0], atol=1e-4 if loose else 1e-7)
    np.testing.assert_allclose(result.outputs["u"], [voltage(i) for i in reference.y[0]],
                               atol=1e-4 if loose else 1e-6)


# ----------------------------------------------------------------- failures

def test_nan_is_reported_with_time_variable_and_law(tmp_path):
    target = tmp_path / "drain.csv"
    with pytest.raises(SimulationError) as caught:
        run(SIM / "sqrt_drain.bg", output=target)
    error = caught.value
    result = error.result
    assert not result.complete
    assert result.failure["variable"] == "b1.e"
    # q = 2 - t reaches 1 at t = 1: the solver stops just before, where its trial steps first see the nan
    assert 0.999 < result.failure["time"] <= 1.0 + 1e-12
    assert result.t[-1] == pytest.approx(result.failure["time"], abs=1e-12)
    diagnostic, = error.diagnostics
    assert diagnostic.code == "E810"
    assert "'b1.e' (tank.e) became nan" in diagnostic.message and "sqrt(tank.q - 1)" in diagnostic.message
    assert diagnostic.span.line == 4                      # the tank's law
    assert diagnostic.hint
    data = np.loadtxt(target, delimiter=",", skiprows=1)  # what was computed is written
    assert data[-1, 0] == result.t[-1]
    np.testing.assert_allclose(data[:, 2], 2.0 - data[:, 0], atol=1e-9)


def test_a_nan_is_reported_at_the_law_that_computes_it_not_at_the_storage_element_across_the_bond(tmp_path):
    """An effort source's law leaves its domain; the bond's other end is an I element whose law
    computes the flow. The diagnostic points at the source's law (line 3), which computes the
    effort that became nan, not at the mass's."""
    path = tmp_path / "push.bg"
    path.write_text("model Push\n  param m = 2 [kg]\n  Se force : e = sqrt(1 - t)\n  I mass : f = p/m\n"
                    "  force -> mass\n  experiment run\n    t_end = 2 [s]\n  end\nend\n", encoding="utf-8")
    with pytest.raises(SimulationError) as caught:
        run(path)
    diagnostic, = caught.value.diagnostics
    assert diagnostic.code == "E810" and "'b1.e' (force.e) became nan" in diagnostic.message
    assert (diagnostic.span.line, diagnostic.span.column) == (3, 14)


def test_a_singularity_stops_the_run_instead_of_creeping_forever():
    with pytest.raises(SimulationError) as caught:
        run(SIM / "singular_force.bg")
    result = caught.value.result
    assert not result.complete
    assert caught.value.diagnostics[0].code == "E811"
    assert 0.49 < result.t[-1] <= 0.5
    # Up to where it stopped the trajectory is the analytic one: p = log(0.5) - log(0.5 - t).
    inside = result.t < 0.49
    exact = np.log(0.5) - np.log(0.5 - result.t[inside])
    np.testing.assert_allclose(result.states["mass.p"][inside], exact, rtol=1e-4, atol=1e-6)


def test_two_frictions_on_one_mass_hold_it_with_the_pushing_force():
    # 3 N + 2 N of sign() friction against a 2 N push: the mass sticks (a sliding mode on v = 0)
    # and the two frictions together hold exactly the push
    result = run(SIM / "stuck_two_frictions.bg")
    assert result.complete, result.message
    np.testing.assert_allclose(result.states["mass.p"], 0.0, atol=1e-12)
    held = result.variables["b3.e"] + result.variables["b4.e"]
    np.testing.assert_allclose(held, 2.0, rtol=1e-9)
    assert any("sliding on sign" in label for _, label in result.events)


def test_missing_end_time_is_a_usage_error():
    _, ss, _ = derive("rc")
    with pytest.raises(UsageError, match="no end time"):
        simulate(ss, None)


# -------------------------------------------------------------------- files

def test_csv_columns_and_all_bonds(tmp_path):
    result = run(SIM / "msd.bg", dt=0.1)
    path = tmp_path / "out.csv"
    write_csv(result, path)
    lines = path.read_text().splitlines()
    # every column with its unit: outputs as declared, states and bond variables in SI (inferred)
    assert lines[0] == "t [s],x [m],mass.p [kg*m/s],spring.q [m]"
    assert len(lines) == 1 + 21
    write_csv(result, path, all_bonds=True)
    header = path.read_text().splitlines()[0].split(",")
    assert header[:4] == ["t [s]", "x [m]", "mass.p [kg*m/s]", "spring.q [m]"]
    assert sorted(header[4:]) == sorted(f"b{i}.{v} [{'kg*m/s^2' if v == 'e' else 'm/s'}]"
                                        for i in range(1, 5) for v in "ef")
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 0], result.t)                  # exact round trip
    np.testing.assert_array_equal(data[:, header.index("b4.e [kg*m/s^2]")], result.bonds["b4.e"])
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]           # no temporary left


def test_npz_holds_arrays_and_status(tmp_path):
    result = run(SIM / "msd.bg", dt=0.1)
    path = tmp_path / "out.npz"
    write_npz(result, path)
    with np.load(path) as data:
        np.testing.assert_array_equal(data["t"], result.t)
        np.testing.assert_array_equal(data["states/spring.q"], result.states["spring.q"])
        np.testing.assert_array_equal(data["bonds/b2.f"], result.bonds["b2.f"])
        assert bool(data["complete"]) and str(data["message"]).startswith("completed")
        assert list(data["parameter_names"]) == ["m", "k", "b"]


def test_summary_is_json_ready():
    result = run(SIM / "friction.bg", dt=0.1)
    summary = json.loads(json.dumps(result.summary()))
    assert summary["complete"] and summary["model"] == "FrictionJump" and summary["experiment"] == "run"
    assert summary["events"][0]["time"] == pytest.approx(np.log(2) / 5, abs=1e-8)
    assert summary["final"]["v"] == pytest.approx(7 - 6 * np.exp(-(2 - np.log(2) / 5)), abs=1e-6)


def test_progress_bar_is_quiet_off_a_terminal_and_drawn_on_one():
    quiet = io.StringIO()
    bar = ProgressBar(0.0, 1.0, stream=quiet, delay=0.0)
    bar(0.5)
    bar.close()
    assert quiet.getvalue() == ""

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    bar = ProgressBar(0.0, 2.0, stream=terminal, delay=0.0)
    bar(1.0)
    bar.close()
    assert "50.0%" in terminal.getvalue() and "note:" not in terminal.getvalue()


def test_a_run_on_scipys_solver_that_takes_long_says_why_once():
    """solver = "Radau" (the user's choice) on a lightly damped drive at rtol 1e-10 ran for over
    300 s where CVODE took 2.7 s: scipy's solvers take their steps in Python. Once the run has
    taken long enough for the bar to be drawn, a note above it says so, once; CVODE's bar has none."""
    from bondc.simulate import _solver_note

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    bar = ProgressBar(0.0, 2.0, stream=terminal, delay=0.0, note=_solver_note("radau"))
    bar(0.5)
    bar.last = 0.0
    bar(1.0)
    bar.close()
    text = terminal.getvalue()
    assert text.count("note: solver 'Radau' is scipy's: it takes its steps in Python") == 1
    assert text.index("note:") < text.index("50.0%")
    assert _solver_note("CVODE") is None and _solver_note("auto") is None and _solver_note("DOPRI5") is None
    assert _solver_note("LSODA") is not None and _solver_note("RK45") is not None


@pytest.mark.parametrize("value, what", [("10^309", "is not a finite number"), ("1/(1-1)", "a division by zero")])
def test_a_constant_that_is_not_a_finite_number_is_a_diagnostic_at_its_position(tmp_path, value, what):
    model = tmp_path / "constant.bg"
    model.write_text(f"model Constant\n  input u = {value}\n  Se s : e = u\n  I mass : f = p/2\n  s -> mass\n"
                     "  experiment run\n    t_end = 1 [s]\n  end\nend\n")
    from bondc.errors import BondcError

    with pytest.raises(BondcError) as caught:
        run(model)
    diagnostic = caught.value.diagnostics[0]
    assert diagnostic.code == "E701" and what in diagnostic.message
    assert (diagnostic.span.line, diagnostic.span.column) == (2, 13)


def test_an_infinite_power_stops_the_energy_account_with_a_diagnostic(tmp_path):
    from bondc.analysis.energy import energy_account
    from bondc.errors import AnalysisError
    from bondc.pipeline import derive_file

    model = tmp_path / "tiny.bg"
    model.write_text("model Tiny\n  param m = 1e-320 [kg]\n  Se push : e = 1\n  I mass : f = p/m\n  push -> mass\n"
                     "  experiment run\n    t_end = 1 [s]\n  end\nend\n")
    derived = derive_file(model)
    result = simulate(derived.state_space, derived.experiment)
    assert any(w.code == "W821" for w in result.warnings)          # the velocity p/m is infinite
    with pytest.raises(AnalysisError) as caught:
        energy_account(derived.state_space, result)
    assert caught.value.diagnostics[0].code == "E934"


def test_an_output_grid_too_fine_for_memory_is_refused_before_the_run():
    _, ss, experiment = derive("msd")
    with pytest.raises(UsageError) as raised:
        simulate(ss, experiment, dt=1e-9)
    message = str(raised.value)
    assert raised.value.diagnostics[0].code == "E803"
    assert "gives 2e+09 points" in message and "give a larger dt" in message


def test_a_run_past_its_point_limit_stops_and_keeps_what_it_computed(monkeypatch):
    from bondc.simulate import compile_model

    _, ss, experiment = derive("msd")
    namespace = compile_model(ss)
    monkeypatch.setitem(namespace, "MAX_POINTS", 2000)      # the generated module's own limit
    result = simulate(ss, experiment, t_end=100.0, max_step=1e-3)      # 100 000 steps would be needed
    assert not result.complete
    assert result.diagnostics[0].code == "E814"
    assert 2000 < result.t.size <= 2000 + 4096           # stops at the first block past the limit
    assert np.all(np.diff(result.t) > 0) and np.all(np.isfinite(result.states["spring.q"]))


def test_a_diverging_run_stops_naming_the_state_and_keeps_its_results(tmp_path):
    """Negative damping: the amplitude grows as exp(sigma t), sigma = |b|/(2m) = 3 /s, until a
    state leaves every physical range (1e30); the run stops there with E815 and keeps the rest."""
    text = (SIM / "msd.bg").read_text().replace("param b = 12", "param b = -12")
    assert "param b = -12" in text
    path = tmp_path / "unstable.bg"
    path.write_text(text)
    with pytest.raises(SimulationError) as raised:
        run(path, t_end=200.0)
    result = raised.value.result
    diagnostic = result.diagnostics[0]
    assert diagnostic.code == "E815" and "'mass.p' grew beyond 1e+30" in diagnostic.message
    assert diagnostic.span.line > 0                       # at the mass's declaration
    p, t = result.states["mass.p"], result.t
    assert abs(p[-1]) >= 1e30 and np.all(np.abs(p[:-1]) < 1e30) and t[-1] < 200.0
    peaks = [i for i in range(1, p.size - 1) if abs(p[i]) >= abs(p[i - 1]) and abs(p[i]) >= abs(p[i + 1])]
    late = [i for i in peaks if t[i] > t[-1] / 2]
    slope = np.polyfit(t[late], np.log(np.abs(p[late])), 1)[0]
    assert slope == pytest.approx(12 / (2 * 2.0), rel=0.02)


@pytest.mark.slow
@pytest.mark.parametrize("native", ["1", "0"])
def test_a_derivative_near_the_largest_float_stops_the_run_instead_of_hanging(tmp_path, native):
    """A relief valve whose closed branch gives a flow of 1e308: the chamber's derivative at the
    start is -1e308, finite, but CVODE's error estimate overflows and its step size becomes nan,
    after which SUNDIALS asks for derivatives at t = nan forever (the run hung). It now stops at
    once with E811, with the C driver and with the numpy code."""
    import os
    import subprocess
    import sys

    path = tmp_path / "relief.bg"
    path.write_text("model Relief\n  param beta = 1.4e9 [Pa]\n  param V = 1 [L]\n  param Q0 = 0.2 [L/s]\n"
                    "  param Rl = 5e10 [Pa*s/m^3]\n  param pr = 0 [Pa]\n  param kr = 1e-9 [m^3/(s*Pa)]\n"
                    "  Sf pump : f = Q0\n  C chamber : e = q*beta/V\n  R leak : f = e/Rl\n"
                    "  R relief : f = if e > pr then kr*(e - pr) else 1e308\n  0 n\n  pump -> n\n"
                    "  n -> chamber\n  n -> leak\n  n -> relief\n  experiment run\n    t_end = 10 [s]\n  end\nend\n",
                    encoding="utf-8")
    environment = {**os.environ, "BONDC_CACHE": "0", "BONDC_NATIVE": native}
    done = subprocess.run([sys.executable, "-m", "bondc", "simulate", str(path), "-o", str(tmp_path / "out.csv")],
                          capture_output=True, text=True, env=environment, timeout=120)
    assert done.returncode == 1, done.stderr
    assert "error[E811]" in done.stderr and "failed at t=0" in done.stderr and "step size became nan" in done.stderr
    assert "Traceback" not in done.stderr
    assert (tmp_path / "out.csv").read_text(encoding="utf-8").splitlines()[1] == "0.0,0.0"     # the start, kept


def test_switch_labels_name_the_elements_inside_components_too(tmp_path):
    """Events and messages name a bond variable by the element variable it is, inside an instance
    too (``fr.friction.e``, not ``fr.b2.e``), and print the law as a model writes it."""
    import re

    path = tmp_path / "pushed.bg"
    path.write_text('import "std:mechanics"\n'
                    "model Pushed\n"
                    "  Mass body : M = 2 [kg]\n"
                    "  CoulombFriction fr : F_c = 4 [N], F_s = 6 [N]\n"
                    "  Force push : F = 4*t\n"
                    "  1 v\n"
                    "  push.a -> v\n  v -> body.a\n  v -> fr.a\n"
                    "  experiment run\n    t_end = 2 [s]\n  end\nend\n")
    result = run(path)
    assert result.complete, result.message
    labels = [label for _, label in result.events]
    assert labels and all("coulomb(fr.friction.f) in fr.friction.e" in label for label in labels)
    assert not any(re.search(r"\bb\d+\.[ef]\b", label) for label in labels)
    ends = [time for time, label in result.events if label.endswith("ends")]
    assert ends == [pytest.approx(1.5, abs=1e-7)]          # 4 t reaches the 6 N static limit


def test_a_run_on_a_grid_takes_its_statistics_and_motor_requirements_from_the_solvers_steps(tmp_path, capsys):
    """A 2 N m torque pulse (Gaussian, 4 ms wide, at t = 0.333 s) on top of 0.5 N m: a 0.1 s grid
    steps over it. simulate --dt gives the same peak torque, statistics and motor requirements as
    the run without dt (computed from the solver's steps, which resolve the pulse), not the grid's
    0.5 N m."""
    from bondc.cli import main

    path = tmp_path / "pulse.bg"
    path.write_text("""model Pulse
  input T [N*m] = 0.5 + 2*exp(-((t - 0.333)/0.004)^2)
  MSe motor : e = T
  I rotor : f = p/0.01
  R drag : e = 0.05*f
  1 shaft
  motor -> shaft
  shaft -> rotor
  shaft -> drag
  output torque [N*m] = motor.e
  output omega [rad/s] = rotor.f
  experiment run
    t_end = 1 [s]
  end
end
""")
    catalogue = Path(__file__).parent.parent / "models" / "data" / "motors.csv"
    summaries = []
    for grid in ([], ["--dt", "0.1"]):
        assert main(["simulate", str(path), "--json", "--motors", str(catalogue), *grid]) == 0
        summaries.append(json.loads(capsys.readouterr().out))
    plain, gridded = summaries
    assert gridded["points"] == 11
    peak = gridded["statistics"]["torque"]["max"]
    assert peak == plain["statistics"]["torque"]["max"] and peak == pytest.approx(2.5, rel=5e-3)
    assert gridded["motors"]["requirements"] == plain["motors"]["requirements"]
    assert gridded["motors"]["requirements"]["peak_torque"] == pytest.approx(2.5, rel=5e-3)


def test_the_statistics_take_the_solution_between_the_solvers_steps():
    """dense_steps: the run at its solver's steps and at the three interior Lobatto nodes of every
    step, its outputs evaluated on the energy account's interpolant. The mass-spring-damper's
    position there is the closed-form step response (the recorded points alone are 5 times
    sparser than the nodes), and its maximum is the first peak's, 20.3 mm at 0.1 + pi/wd s."""
    import math

    from bondc.analysis.energy import dense_steps
    from bondc.analysis.stats import output_statistics
    from bondc.pipeline import derive_file

    derived = derive_file(Path(__file__).parent.parent / "models" / "mass_spring_damper.bg", cache=False)
    result = simulate(derived.state_space, derived.experiment)
    dense = dense_steps(derived.state_space, result)
    assert dense_steps(derived.state_space, result) is dense      # made once
    assert dense.t.size == 4 * (result.t.size - 1) + 1 and np.all(np.diff(dense.t) > 0)
    assert set(result.t) <= set(dense.t)
    wn, zeta = 20.0, 0.15
    wd, s = wn * math.sqrt(1 - zeta ** 2), dense.t - 0.1
    expected = np.where(s >= 0, 10 / 800 * (1 - np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / math.sqrt(
        1 - zeta ** 2) * np.sin(wd * s))), 0.0)
    np.testing.assert_allclose(dense.outputs["x"], expected, rtol=0, atol=2e-8)
    peak = 10 / 800 * (1 + math.exp(-zeta * wn * math.pi / wd))
    assert output_statistics(dense)["x"]["max"] == pytest.approx(peak, rel=2e-5)
    assert abs(output_statistics(result)["x"]["max"] - peak) > abs(output_statistics(dense)["x"]["max"] - peak)


def test_simulate_with_a_motor_catalogue_that_cannot_be_used_exits_1(tmp_path, capsys, monkeypatch):
    """A missing catalogue is an error before the run (nothing simulated); a model without a torque
    output cannot be sized: the run is printed, the error too, exit 1 (not 0 as if all went well)."""
    from bondc.cli import main

    simulate_module = importlib.import_module("bondc.simulate")     # bondc.simulate is the API's function

    ran = []
    real = simulate_module.simulate
    monkeypatch.setattr(simulate_module, "simulate", lambda *a, **k: ran.append(1) or real(*a, **k))
    path = SIM / "msd.bg"
    assert main(["simulate", str(path), "--motors", str(tmp_path / "absent.csv")]) == 1
    assert "E905" in capsys.readouterr().err and not ran
    catalogue = Path(__file__).parent.parent / "models" / "data" / "motors.csv"
    assert main(["simulate", str(path), "--json", "--motors", str(catalogue)]) == 1
    summary = json.loads(capsys.readouterr().out)
    assert summary["complete"] and [d["code"] for d in summary["diagnostics"]] == ["E927"]


@pytest.mark.parametrize("interrupt_at", [2, 3])
def test_an_interruption_between_recording_a_batchs_times_and_its_states_keeps_a_consistent_run(
        interrupt_at, monkeypatch):
    """Ctrl-C lands between any two statements: here between appending a batch's times and its
    states. The run keeps what it recorded before, every array the length of its times, stops with
    'interrupted' at the time it got to, and its energy account can be made."""
    from bondc.analysis.energy import energy_account
    from bondc.simulate import compile_model

    _, ss, experiment = derive("msd")
    namespace = compile_model(ss)
    run_class = namespace["_Run"]

    class Interrupting(list):
        calls = 0

        def append(self, item):
            Interrupting.calls += 1
            if Interrupting.calls == interrupt_at:
                raise KeyboardInterrupt
            super().append(item)

    original = run_class.__init__

    def init(self, *args, **kwargs):
        original(self, *args, **kwargs)
        self.blocks_x = Interrupting()

    monkeypatch.setattr(run_class, "__init__", init)
    result = simulate(ss, experiment)
    assert not result.complete and result.failure["kind"] == "interrupted"
    assert result.t.size >= 1 and all(len(values) == result.t.size for values in result.states.values())
    assert all(len(values) == result.t.size for values in result.outputs.values())
    assert f"interrupted at t={result.t[-1]:.6g}" in result.message
    if result.t.size > 1 and result.t[-1] > result.t[0]:
        energy_account(ss, result)


def test_an_interrupted_simulate_keeps_what_it_computed_and_exits_130(tmp_path, monkeypatch, capsys):
    """Ctrl-C during the run (here at its second batch): E813 with the time it got to, the file
    written with what was computed, exit status 130 as the README says (143 for SIGTERM)."""
    from bondc.cli import main

    module = importlib.import_module("bondc.simulate")

    class Interrupting(list):
        def append(self, item):
            if len(self) == 1:
                raise KeyboardInterrupt
            super().append(item)

    real = module.compile_model

    def compile_model(ss):
        namespace = real(ss)
        original = namespace["_Run"].__init__

        def init(self, *args, **kwargs):
            original(self, *args, **kwargs)
            self.blocks_x = Interrupting()

        monkeypatch.setattr(namespace["_Run"], "__init__", init)
        return namespace

    monkeypatch.setattr(module, "compile_model", compile_model)
    out = tmp_path / "run.csv"
    assert main(["simulate", str(SIM / "msd.bg"), "--no-cache", "-o", str(out)]) == 130
    err = capsys.readouterr().err
    assert "E813" in err and "interrupted at t=" in err
    rows = out.read_text().splitlines()
    assert len(rows) >= 2 and rows[0].startswith("t [s],")


def test_an_output_file_named_for_another_format_is_refused_before_the_run(tmp_path, capsys):
    from bondc.cli import main

    assert main(["simulate", str(SIM / "msd.bg"), "-o", str(tmp_path / "run.json")]) == 2
    assert "E001" in capsys.readouterr().err and not (tmp_path / "run.json").exists()
    assert main(["simulate", str(SIM / "msd.bg"), "-o", str(tmp_path / "run.csv")]) == 0


def test_with_json_a_command_stopped_by_an_error_still_prints_json(capsys):
    from bondc.cli import main

    assert main(["simulate", str(SIM / "msd.bg"), "--dt", "1e-9", "--json"]) == 2
    captured = capsys.readouterr()
    printed = json.loads(captured.out)
    assert printed["complete"] is False and [d["code"] for d in printed["diagnostics"]] == ["E803"]
    assert "E803" in captured.err


def test_w821_brackets_where_a_quantity_stops_being_finite_and_claims_nothing_of_a_stopped_run(tmp_path):
    """A store drained at 1 unit/s from q = 1 makes sqrt(q) nan at t = 1 s; the run only records a
    few points, and W821 said 'from t=2 s'. It now names the first point that is not finite and the
    finite one before it, which bracket the instant. Where the run stopped on that quantity (E810),
    its hint no longer says that the states are unaffected."""
    from bondc.pipeline import derive_file

    drain = tmp_path / "drain.bg"
    drain.write_text("model Drain\n  Sf s : f = -1\n  C c : e = sqrt(q), q(0) = 1\n  s -> c\n  output E = c.e\n"
                     "  experiment run\n    t_end = 2 [s]\n  end\nend\n")
    derived = derive_file(drain, cache=False)
    result = simulate(derived.state_space, derived.experiment)
    assert result.complete
    (warning,) = [w for w in result.warnings if w.code == "W821" and "'E'" in w.message]
    bad = np.flatnonzero(~np.isfinite(result.outputs["E"]))[0]
    assert result.t[bad - 1] < 1.0 <= result.t[bad]
    assert f"the first at t={result.t[bad]:.6g} s" in warning.message
    assert f"the point before it, at t={result.t[bad - 1]:.6g} s, is finite" in warning.message
    assert "unaffected" in warning.hint
    stopped = tmp_path / "stopped.bg"
    stopped.write_text("model L\n  param a = -1\n  Se s : e = log(a)\n  I m : f = p\n  s -> m\n"
                       "  experiment run\n    t_end = 1 [s]\n  end\nend\n")
    derived = derive_file(stopped, cache=False)
    result = simulate(derived.state_space, derived.experiment)
    assert not result.complete
    assert [w for w in result.warnings if w.code == "W821"] and \
        all("unaffected" not in w.hint for w in result.warnings if w.code == "W821")


def test_a_result_cannot_be_changed_after_it_is_made():
    """A SimResult is frozen, its mappings too: a write raises, a changed copy is a new dict;
    the result still pickles (a sweep's workers send theirs) and its summary is JSON."""
    import dataclasses
    import pickle

    result = run(SIM / "rc.bg", dt=0.5e-3)
    final = float(result.outputs["v"][-1])
    for mapping in (result.outputs, result.states, result.bonds, result.variables, result.stats, result.parameters,
                    result.settings, result.units, result.dependent):
        with pytest.raises(TypeError):
            mapping["new"] = 1
        with pytest.raises(TypeError):
            mapping.update({"new": 1})
        with pytest.raises(TypeError):
            mapping.clear()
    with pytest.raises(TypeError):
        del result.outputs["v"]
    with pytest.raises(TypeError):
        result.outputs.pop("v")
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.outputs = {}
    assert float(result.outputs["v"][-1]) == final and "new" not in result.stats
    changed = {**result.parameters, "R": 2.0}      # a changed copy leaves the result as it was: R = 1 kOhm
    assert changed["R"] == 2.0 and result.parameters["R"] == 1000.0
    # a variant made with plain dicts holds read-only ones too
    variant = dataclasses.replace(result, outputs={"v": result.outputs["v"]})
    with pytest.raises(TypeError):
        variant.outputs["w"] = result.outputs["v"]
    back = pickle.loads(pickle.dumps(result))
    assert back.outputs.keys() == result.outputs.keys() and np.array_equal(back.outputs["v"], result.outputs["v"])
    with pytest.raises(TypeError):
        back.outputs["new"] = 1
    assert json.loads(json.dumps(result.summary()))["settings"] == dict(result.settings)
    # its lists (events, when clauses' jumps, sliding modes) too, still equal to the lists they hold
    events = list(result.events)
    for listed in (result.events, result.jumps, result.sliding, back.events):
        with pytest.raises(TypeError):
            listed.append((0.0, "new"))
        with pytest.raises(TypeError):
            listed += [(0.0, "new")]
        with pytest.raises(TypeError):
            listed.sort()
    assert result.events == events and back.events == events and isinstance(result.events, list)
