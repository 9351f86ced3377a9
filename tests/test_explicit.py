"""The explicit Dormand-Prince solver (DOPRI5) and the default solver, ``auto``, that takes it for
a smooth model that is not stiff.

Independent expectations: closed forms (the mass-spring-damper's step response, a driven RC
circuit), scipy's RK45 (the same pair, stepped from Python: the numpy code's solver) for the C
stepper's steps, scipy's Radau at tight tolerances for a model that stiffens, and the
eigenvalues numpy finds for the spectral radius ``auto`` estimates.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bondc import runtime
from bondc.pipeline import derive_file
from bondc.simulate import compile_model

ROOT = Path(__file__).resolve().parent.parent
# a C++ compiler: the system's, else the ziglang package's (a dependency)
needs_cxx = pytest.mark.skipif(runtime.load_erk()[0] is None,
                               reason="bondc's explicit stepper cannot be built here (no C++ compiler)")


@functools.lru_cache(maxsize=None)
def _compiled(path):
    derived = derive_file(path, cache=False)
    return compile_model(derived.state_space), derived.experiment


def _from_text(tmp_path, text, name="model.bg"):
    path = tmp_path / name
    path.write_text(text)
    derived = derive_file(path, cache=False)
    return compile_model(derived.state_space), derived.experiment


def _simulate(namespace, experiment, **settings):
    settings = {"t_end": experiment.t_end, "rtol": experiment.rtol, "atol": experiment.atol,
                "max_step": experiment.max_step, **settings}
    return namespace["simulate_model"](namespace["_MODEL"], **settings)


def _underdamped(t, force=10.0, m=2.0, k=800.0, b=12.0, t_step=0.1):
    wn, zeta = math.sqrt(k / m), b / (2 * math.sqrt(k * m))
    wd, s = wn * math.sqrt(1 - zeta ** 2), t - t_step
    return np.where(s >= 0, force / k * (1 - np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / math.sqrt(
        1 - zeta ** 2) * np.sin(wd * s))), 0.0)


@needs_cxx
@pytest.mark.parametrize("native", [None, False])
def test_dopri5_gives_the_step_response_of_the_mass_spring_damper(native):
    """DOPRI5 in C (Boost.Odeint's pair in the driver) and with the numpy code (scipy's RK45): the
    closed-form step response, at every recorded point and on a grid from the interpolant."""
    namespace, experiment = _compiled(ROOT / "models" / "mass_spring_damper.bg")
    run = _simulate(namespace, experiment, method="DOPRI5", native=native)
    assert run.complete and run.stats["code"] == ("native" if native is None else "numpy")
    np.testing.assert_allclose(run.states["spring.q"], _underdamped(run.t), rtol=0, atol=1e-8)
    grid = np.linspace(0.0, experiment.t_end, 1237)
    gridded = _simulate(namespace, experiment, method="DOPRI5", native=native, t_eval=grid)
    np.testing.assert_array_equal(gridded.t, grid)
    np.testing.assert_allclose(gridded.states["spring.q"], _underdamped(grid), rtol=0, atol=1e-8)


#: Every model of models/ and tests/fixtures that auto runs on DOPRI5 (the test checks that it does),
#: but the two that stop at a singularity, where rounding alone moves two runs' last steps apart
#: (their stops are tested in test_simulate): the rest are slow.
DOPRI5_MODELS = ["models/dc_motor_gear.bg", "models/dc_motor_gear_compliant.bg", "models/mass_spring_damper.bg",
                 "models/quarter_car.bg", "models/series_rlc.bg", "tests/fixtures/engine/chirp_count.bg",
                 "tests/fixtures/engine/diode_bridge_shockley.bg", "tests/fixtures/engine/pwm_rl.bg",
                 "tests/fixtures/engine/pwm_sine_compare.bg", "tests/fixtures/language/s02_file_and_model.bg",
                 "tests/fixtures/language/s04_custom_state.bg", "tests/fixtures/language/s10_complete_model.bg",
                 "tests/fixtures/sim/csv_force.bg", "tests/fixtures/sim/exp_diode.bg",
                 "tests/fixtures/sim/geared_inertia.bg", "tests/fixtures/sim/msd.bg",
                 "tests/fixtures/sim/nonlinear_loop.bg", "tests/fixtures/sim/oscillator.bg",
                 "tests/fixtures/sim/pwm_diode.bg", "tests/fixtures/sim/rc.bg", "tests/fixtures/sim/table_force.bg",
                 "tests/fixtures/sim/thermal_wall.bg", "tests/fixtures/textbook/dc_motor_gear.bg",
                 "tests/fixtures/textbook/gyrator_motor.bg", "tests/fixtures/textbook/mass_spring_damper.bg",
                 "tests/fixtures/textbook/modulated_transformer.bg", "tests/fixtures/textbook/nonlinear_spring.bg",
                 "tests/fixtures/textbook/parallel_rlc.bg", "tests/fixtures/textbook/pneumatic_piston.bg",
                 "tests/fixtures/textbook/quarter_car.bg", "tests/fixtures/textbook/rr_loop.bg",
                 "tests/fixtures/textbook/series_rlc.bg", "tests/fixtures/textbook/two_inertias_gear.bg"]
QUICK = {"models/mass_spring_damper.bg", "models/quarter_car.bg", "tests/fixtures/engine/pwm_rl.bg",
         "models/dc_motor_gear.bg"}


@needs_cxx
@pytest.mark.parametrize("model", [pytest.param(path, marks=() if path in QUICK else (pytest.mark.slow,))
                                   for path in DOPRI5_MODELS])
def test_the_c_stepper_takes_the_steps_of_scipys_rk45(model):
    """The C driver's explicit stepper controls its steps as scipy's RK45 does (error norm, step
    factors, first step): the C code and the numpy code, each run as auto chooses (DOPRI5 for both),
    take the same steps to rounding, their events (a PWM's edges, when clauses) fall at the same
    instants, and their states agree to 1e-7 of their range (1e-3 for the bridge of Shockley
    diodes, whose algebraic loop C solves by Newton's method to rounding and numpy by MINPACK to
    its own tolerance: the two loops' values differ in the eighth digit)."""
    namespace, experiment = _compiled(ROOT / model)
    settings = {"t_end": 1.0}
    if experiment is not None:
        settings = {"t_end": experiment.t_end or 1.0, "rtol": experiment.rtol, "atol": experiment.atol,
                    "max_step": experiment.max_step}
    with np.errstate(all="ignore"):
        c_run = namespace["simulate_model"](namespace["_MODEL"], **settings)
        numpy_run = namespace["simulate_model"](namespace["_MODEL"], native=False, **settings)
    assert c_run.stats["solver"] == numpy_run.stats["solver"] == "DOPRI5"
    assert numpy_run.stats["code"] == "numpy" and c_run.complete == numpy_run.complete
    loop = "shockley" in model
    if not namespace["NATIVE_UNAVAILABLE"]:
        assert c_run.stats["code"] == "native"
    if not loop:
        assert c_run.t.size == numpy_run.t.size
        np.testing.assert_allclose(c_run.t, numpy_run.t, rtol=0, atol=1e-8 * settings["t_end"])
    assert [label for _, label in c_run.events] == [label for _, label in numpy_run.events]
    np.testing.assert_allclose([t for t, _ in c_run.events], [t for t, _ in numpy_run.events], rtol=0,
                               atol=1e-8 * settings["t_end"])
    for name, values in numpy_run.states.items():
        other = c_run.states[name] if c_run.t.size == numpy_run.t.size else np.interp(
            numpy_run.t, c_run.t, c_run.states[name])
        scale = max(float(np.max(np.abs(values))), 1e-12)
        assert float(np.max(np.abs(other - values))) <= (1e-3 if loop else 1e-7) * scale, name


@needs_cxx
def test_auto_takes_dopri5_for_a_smooth_model_that_is_not_stiff():
    """The mass-spring-damper (a step of time, no switch of the state; spectral radius 20 1/s over
    2 s): DOPRI5, with the same run as asked for by name; the result equals the closed form."""
    namespace, experiment = _compiled(ROOT / "models" / "mass_spring_damper.bg")
    auto = _simulate(namespace, experiment)
    assert experiment.solver is None and auto.stats["solver"] == "DOPRI5"
    assert auto.stats["spectral_radius"] == pytest.approx(20.0, rel=0.25)
    named = _simulate(namespace, experiment, method="DOPRI5")
    np.testing.assert_array_equal(auto.t, named.t)
    np.testing.assert_allclose(auto.states["spring.q"], _underdamped(auto.t), rtol=0, atol=1e-8)


@pytest.mark.parametrize("model", ["tests/fixtures/sim/friction.bg", "tests/fixtures/engine/bouncing_ball.bg",
                                   "tests/fixtures/engine/branch_domain_jump.bg"])
def test_auto_keeps_cvode_for_a_model_with_switches_of_the_state(model):
    """Friction (sliding modes), a when clause on a state, a drain whose law jumps where the tank
    empties (a pump stopped by a float switch): CVODE, as before."""
    namespace, experiment = _compiled(ROOT / model)
    run = _simulate(namespace, experiment)
    assert run.complete and run.stats["solver"] == "CVODE"
    named = _simulate(namespace, experiment, method="CVODE")
    np.testing.assert_array_equal(run.t, named.t)
    assert run.events == named.events


def _relief_pressure(t, beta=1.4e9, V=1e-3, Q0=2e-4, Rl=5e10, pr=50e5, kr=1e-9):
    """relief_valve.bg's chamber: p = Q0*Rl*(1 - exp(-t*beta/(V*Rl))) while the valve is closed,
    until p = pr at t1; then p relaxes to (Q0 + kr*pr)/(1/Rl + kr) at the rate (beta/V)*(1/Rl + kr)."""
    t = np.asarray(t, dtype=float)
    t1 = V * Rl / beta * math.log(Q0 * Rl / (Q0 * Rl - pr))
    settled = (Q0 + kr * pr) / (1 / Rl + kr)
    closed = Q0 * Rl * (1 - np.exp(-beta / (V * Rl) * t))
    opened = settled + (pr - settled) * np.exp(-beta / V * (1 / Rl + kr) * np.maximum(t - t1, 0.0))
    return np.where(t < t1, closed, opened)


@needs_cxx
def test_auto_takes_dopri5_for_a_relief_valve_whose_law_is_a_kink():
    """relief_valve.bg: ``if e > pr then kr*(e - pr) else 0`` is continuous where the valve opens
    (a kink): no switch of the state, no event, no mode change, the law evaluated as written. Auto
    starts on DOPRI5 (spectral radius 28 1/s with the valve closed) and goes on with CVODE once the
    open valve makes the chamber stiff (1.43e3 1/s). The pressure follows the closed form to the
    experiment's atol (1e-9 m^3 of the chamber's volume state, 1400 Pa) and settles on the
    equilibrium."""
    namespace, experiment = _compiled(ROOT / "tests" / "fixtures" / "engine" / "relief_valve.bg")
    assert not namespace["_Model"](namespace["_MODEL"]).SWITCHES
    run = _simulate(namespace, experiment)
    assert run.complete and run.stats["solver"] == "DOPRI5"
    assert run.stats["spectral_radius"] == pytest.approx(28.0, rel=1e-3)
    assert "then CVODE" in run.stats["solver_note"]
    assert not run.events and run.stats["mode_changes"] == 0
    atol = 1e-9 * 1.4e9 / 1e-3
    np.testing.assert_allclose(run.outputs["P"], _relief_pressure(run.t), rtol=0, atol=3 * atol)
    assert run.outputs["P"][-1] == pytest.approx((2e-4 + 1e-9 * 50e5) / (1 / 5e10 + 1e-9), rel=1e-9)


STIFF_RC = """model StiffRC
  param R1 = 1 [Ohm]
  param C1 = 1 [F]
  param R2 = 1 [Ohm]
  param C2 = 1e-5 [F]
  Se source : e = 1
  R  r1 : e = R1*f
  C  c1 : e = q/C1
  R  r2 : e = R2*f
  C  c2 : e = q/C2
  1  s1
  0  n1
  1  s2
  source -> s1
  s1 -> r1
  s1 -> n1
  n1 -> c1
  n1 -> s2
  s2 -> r2
  s2 -> c2
  output v2 [V] = c2.e
  experiment run
    t_end = 5 [s]
  end
end
"""


@needs_cxx
def test_auto_takes_cvode_for_a_stiff_model(tmp_path):
    """Two RC stages with time constants of 1 s and 10 us (spectral radius about 2e5 1/s): the
    explicit pair would need 300 000 steps for its stability alone over 5 s, so CVODE."""
    namespace, experiment = _from_text(tmp_path, STIFF_RC)
    run = _simulate(namespace, experiment)
    assert run.complete and run.stats["solver"] == "CVODE"
    model = namespace["_Model"](namespace["_MODEL"])
    p = namespace["param_array"](model.PARAMETERS)
    jacobian = np.asarray(model.jac(0.0, np.asarray(model.x0(p), dtype=float), p, np.zeros(0)))
    radius = float(np.max(np.abs(np.linalg.eigvals(jacobian))))
    assert run.stats["spectral_radius"] == pytest.approx(radius, rel=0.25) and radius > 1e5


STIFFENING = """model Stiffening "a current into a capacitor whose leak grows: its time constant falls from 1 s to 1 us"
  param C = 1 [F]
  input G [1/Ohm] = 1 + 1e6*t
  Sf source : f = 1
  C  cap : e = q/C
  R  leak : f = G*e
  0  n
  source -> n
  n -> cap
  n -> leak
  output v [V] = cap.e
  experiment run
    t_end = 1 [s]
  end
end
"""


@needs_cxx
def test_auto_goes_on_with_cvode_where_the_model_becomes_stiff(tmp_path):
    """At the start the model is not stiff (spectral radius 1 1/s), so DOPRI5; its leak then grows
    until the explicit pair's steps are held by its stability (h < 3.3/G): auto looks again every
    500 steps and takes CVODE for the rest of the run, where DOPRI5 alone takes 150 000 steps. The
    voltage equals scipy's Radau at tight tolerances (q' = 1 - G(t) q/C)."""
    namespace, experiment = _from_text(tmp_path, STIFFENING)
    run = _simulate(namespace, experiment)
    assert run.complete, run.message
    note = run.stats["solver_note"]
    assert note.startswith("auto: DOPRI5 until t=") and "then CVODE" in note
    switched = float(note.split("t=")[1].split(" s")[0])
    assert 0.0 < switched < 0.2
    explicit = _simulate(namespace, experiment, method="DOPRI5")
    assert run.stats["steps"] < explicit.stats["steps"] / 10

    reference = solve_ivp(lambda t, q: [1 - (1 + 1e6 * t) * q[0]], (0.0, 1.0), [0.0], method="Radau",
                          rtol=1e-11, atol=1e-14, dense_output=True, jac=lambda t, q: [[-(1 + 1e6 * t)]])
    np.testing.assert_allclose(run.outputs["v"], reference.sol(run.t)[0], rtol=1e-4, atol=1e-9)


@needs_cxx
@pytest.mark.parametrize("case", ["chain", "flagship"])
def test_the_spectral_radius_estimate_follows_the_jacobians_eigenvalues(case, tmp_path):
    """The power iteration on difference quotients (states scaled by their size) against numpy's
    eigenvalues of the analytic Jacobian: the 30-section chain (fast modes lightly damped) and the
    flagship (fast modes damped), within 25 %."""
    from benchmarks.chain import chain_source

    if case == "chain":
        path = tmp_path / "chain30.bg"
        path.write_text(chain_source(30))
    else:
        path = ROOT / "models" / "electro_pneumatic_hybrid.bg"
    namespace = compile_model(derive_file(path, cache=False).state_space)
    model = namespace["_Model"](namespace["_MODEL"])
    p = namespace["param_array"](model.PARAMETERS, None, model.derive_parameters)
    y = np.asarray(model.x0(p), dtype=float)
    modes = namespace["modes_at"](model, 0.0, y, p)
    run = namespace["_Run"].__new__(namespace["_Run"])
    run.model, run.p, run.options = model, p, {"rtol": 1e-6, "atol": 1e-9}
    radius = float(np.max(np.abs(np.linalg.eigvals(np.asarray(model.jac(0.0, y, p, modes))))))
    assert run.spectral_radius(0.0, y, modes) == pytest.approx(radius, rel=0.25)


def test_without_a_cxx_compiler_auto_takes_cvode_and_says_why(tmp_path, monkeypatch):
    """No C++ compiler ($CXX naming no program, none on PATH, no ziglang package; or no Boost
    headers): the explicit stepper cannot be built, and auto takes CVODE for every model, saying
    why; DOPRI5 asked for by name runs scipy's RK45 from Python. The model's C code is built
    before PATH is emptied (its C compiler is found)."""
    namespace, experiment = _compiled(ROOT / "models" / "mass_spring_damper.bg")
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path / "cache"))
    _simulate(namespace, experiment, t_end=0.01, method="CVODE")
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("PATH", str(tmp_path / "no-programs"))
    monkeypatch.setattr(runtime.native, "_zig", lambda: None)
    monkeypatch.setitem(namespace, "_zig", lambda: None)      # the module's own copy of the runtime
    table, why = runtime.load_erk()
    assert table is None and "no C++ compiler works here" in why and "was not found" in why
    run = _simulate(namespace, experiment)
    assert run.complete and run.stats["solver"] == "CVODE"
    assert "no C++ compiler works here" in run.stats["solver_note"]
    named = _simulate(namespace, experiment, method="DOPRI5")
    assert named.stats["solver"] == "DOPRI5" and "scipy's RK45" in named.stats["code_note"]
    np.testing.assert_allclose(named.states["spring.q"], _underdamped(named.t), rtol=0, atol=1e-8)


def _drained(t, b=0.5):
    """branch_domain_jump.bg's level: with s = sqrt(q), t = (1 - s) - (b/2)*ln((2 + b)/(2s + b))
    (decreasing in s, inverted by bisection) until the tank empties at t = 1 - (b/2)*ln((2 + b)/b)."""
    t = np.asarray(t, dtype=float)
    low, high = np.zeros_like(t), np.ones_like(t)
    for _ in range(80):
        s = 0.5 * (low + high)
        late = (1 - s) - 0.5 * b * np.log((2 + b) / (2 * s + b)) > t
        low, high = np.where(late, s, low), np.where(late, high, s)
    return np.where(t < 1 - 0.5 * b * math.log((2 + b) / b), (0.5 * (low + high)) ** 2, 0.0)


@needs_cxx
def test_a_rate_that_is_not_finite_at_a_trial_point_hands_the_step_to_the_step_loop():
    """A tank drained through ``if e > 0 then a*sqrt(e) + b else 0`` (an outlet and a pump that a
    float switch stops: a jump, the branch frozen between events): trial points past the empty tank
    take the square root of a negative number. The C stepper hands the step over (as CVODE's driver
    does), the step loop takes the branch that holds there, and the tank empties at
    t = 1 - ln(5)/4 s as the closed form says."""
    namespace, experiment = _compiled(ROOT / "tests" / "fixtures" / "engine" / "branch_domain_jump.bg")
    run = _simulate(namespace, experiment, method="DOPRI5")
    assert run.complete and run.stats["branch_extensions"] > 0 and run.stats["driver_segments"] >= 1
    level = run.outputs["level"]
    np.testing.assert_allclose(level, _drained(run.t), rtol=0, atol=1e-6)
    emptied = [time for time, label in run.events if "drain.e > 0" in label]
    assert emptied and emptied[0] == pytest.approx(1 - math.log(5) / 4, abs=1e-6)


@needs_cxx
def test_a_branch_beyond_a_kink_is_never_evaluated_by_the_c_stepper():
    """branch_domain.bg: ``if e > 0 then a*sqrt(e) else 0`` is 0 on both sides of e = 0, a kink
    evaluated as written: C takes the else branch past the empty tank (no square root of a negative
    level, nothing handed over), no event, no mode change, and q = (1 - t)^2 until t = 1 s."""
    namespace, experiment = _compiled(ROOT / "tests" / "fixtures" / "engine" / "branch_domain.bg")
    assert not namespace["_Model"](namespace["_MODEL"]).SWITCHES
    run = _simulate(namespace, experiment, method="DOPRI5")
    assert run.complete and run.stats["solver"] == "DOPRI5" and run.stats["driver_segments"] == 1
    assert "branch_extensions" not in run.stats
    assert not run.events and run.stats["mode_changes"] == 0
    level = run.outputs["level"]
    assert np.all(np.isfinite(level))
    np.testing.assert_allclose(level, np.where(run.t < 1, (1 - run.t) ** 2, 0.0), rtol=0, atol=1e-6)
