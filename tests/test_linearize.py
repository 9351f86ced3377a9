"""Tests of linearisation against textbook characteristic polynomials and hand-derived matrices."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from bondc import semantic
from bondc.analysis.linearize import linearize
from bondc.causality import assign_causality
from bondc.equations import derive
from bondc.errors import AnalysisError

FIXTURES = Path(__file__).parent / "fixtures" / "textbook"


def state_space(name: str):
    graph, _ = semantic.load(FIXTURES / f"{name}.bg")
    return derive(assign_causality(graph))


def state_space_of(tmp_path, text: str):
    path = tmp_path / "model.bg"
    path.write_text(text)
    graph, _ = semantic.load(path)
    return derive(assign_causality(graph))


def params(ss) -> dict:
    return {name: value for name, (_, value) in ss.parameters.items()}


def assert_same_spectrum(actual, expected, rtol=1e-6):
    actual = np.sort_complex(np.asarray(actual, dtype=complex))
    expected = np.sort_complex(np.asarray(expected, dtype=complex))
    assert len(actual) == len(expected)
    for a, e in zip(actual, expected):
        assert abs(a - e) <= rtol * abs(e), (actual, expected)


def test_mass_spring_damper_frequency_and_damping():
    ss = state_space("mass_spring_damper")
    p = params(ss)
    lin = linearize(ss, time=0.5)
    omega_n = math.sqrt(p["k"] / p["m"])
    zeta = p["b"] / (2 * math.sqrt(p["k"] * p["m"]))
    assert lin.natural_frequencies == pytest.approx([omega_n, omega_n], rel=1e-9)
    assert lin.damping_ratios == pytest.approx([zeta, zeta], rel=1e-9)
    # States (p, q), input F, outputs x = q and v = p/m.
    assert lin.states == ("mass.p", "spring.q") and lin.inputs == ("F",) and lin.outputs == ("x", "v")
    assert lin.A == pytest.approx(np.array([[-p["b"] / p["m"], -p["k"]], [1 / p["m"], 0]]))
    assert lin.B == pytest.approx(np.array([[1.0], [0.0]]))
    assert lin.C == pytest.approx(np.array([[0.0, 1.0], [1 / p["m"], 0.0]]))
    assert lin.D == pytest.approx(np.zeros((2, 1)))
    assert lin.u0.tolist() == [p["F0"]]


def test_parameter_overrides():
    ss = state_space("mass_spring_damper")
    lin = linearize(ss, parameters={"k": 200.0})
    assert lin.natural_frequencies == pytest.approx([10.0, 10.0])
    with pytest.raises(KeyError):
        linearize(ss, parameters={"nope": 1.0})


def test_series_rlc_poles():
    ss = state_space("series_rlc")
    p = params(ss)
    expected = np.roots([p["L"] * p["Cap"], p["R"] * p["Cap"], 1.0])
    assert_same_spectrum(linearize(ss).eigenvalues, expected)


def test_parallel_rlc_poles():
    ss = state_space("parallel_rlc")
    p = params(ss)
    expected = np.roots([1.0, 1 / (p["R"] * p["Cap"]), 1 / (p["L"] * p["Cap"])])
    assert_same_spectrum(linearize(ss).eigenvalues, expected)


def test_quarter_car_matrix_from_newton():
    ss = state_space("quarter_car")
    p = params(ss)
    ms, mu, ks, bs, kt = (p[n] for n in ("ms", "mu", "ks", "bs", "kt"))
    # x = (p_s, p_u, q_susp, q_tyre); q_susp = x_u - x_s, q_tyre = x_road - x_u.
    A = np.array([
        [-bs / ms, bs / mu, ks, 0.0],
        [bs / ms, -bs / mu, -ks, kt],
        [-1 / ms, 1 / mu, 0.0, 0.0],
        [0.0, -1 / mu, 0.0, 0.0],
    ])
    lin = linearize(ss, time=0.15)
    assert lin.states == ("body.p", "wheel.p", "suspension.q", "tyre.q")
    assert lin.A == pytest.approx(A, rel=1e-12)
    assert lin.B == pytest.approx(np.array([[0.0], [0.0], [0.0], [1.0]]))
    assert_same_spectrum(lin.eigenvalues, np.linalg.eigvals(A))
    assert lin.u0 == pytest.approx([0.05 / 0.1 * 0.5])     # road speed on the falling ramp at t = 0.15


def test_dc_motor_electrical_and_mechanical_poles():
    ss = state_space("dc_motor_gear")
    p = params(ss)
    b_eq = p["bm"] + p["n"] ** 2 * p["bl"]
    expected = np.roots([1.0, p["Ra"] / p["La"] + b_eq / p["J"], (p["Ra"] * b_eq + p["K"] ** 2) / (p["La"] * p["J"])])
    lin = linearize(ss)
    assert_same_spectrum(lin.eigenvalues, expected)
    # One fast electrical pole and one slow mechanical pole, both real here.
    assert np.all(lin.eigenvalues.imag == 0) and lin.damping_ratios == pytest.approx([1.0, 1.0])


def test_gyrator_motor_poles():
    ss = state_space("gyrator_motor")
    p = params(ss)
    expected = np.roots([1.0, p["R"] / p["L"] + p["b"] / p["J"], (p["R"] * p["b"] + p["K"] ** 2) / (p["L"] * p["J"])])
    assert_same_spectrum(linearize(ss).eigenvalues, expected)


def test_rigid_gear_pole_uses_the_combined_inertia():
    ss = state_space("two_inertias_gear")
    p = params(ss)
    expected = -(p["b1"] + p["n"] ** 2 * p["b2"]) / (p["J1"] + p["n"] ** 2 * p["J2"])
    assert_same_spectrum(linearize(ss).eigenvalues, [expected])


def test_resistor_loop_time_constant():
    ss = state_space("rr_loop")
    p = params(ss)
    tau = (p["R3"] + p["R1"] * p["R2"] / (p["R1"] + p["R2"])) * p["Cap"]
    assert_same_spectrum(linearize(ss).eigenvalues, [-1 / tau])


def test_nonlinear_spring_at_its_equilibrium():
    ss = state_space("nonlinear_spring")
    p = params(ss)
    lin = linearize(ss, at="equilibrium")
    # k q + k3 q^3 = F has one real root.
    roots = np.roots([p["k3"], 0.0, p["k"], -p["F"]])
    q_eq = float(roots[np.argmin(np.abs(roots.imag))].real)
    assert lin.x0 == pytest.approx([0.0, q_eq], abs=1e-12)
    stiffness = p["k"] + 3 * p["k3"] * q_eq ** 2
    assert lin.A == pytest.approx(np.array([[-p["b"] / p["m"], -stiffness], [1 / p["m"], 0.0]]))
    assert lin.held == ()


def test_modulated_transformer_input_gain():
    ss = state_space("modulated_transformer")
    p = params(ss)
    time = 0.7
    ratio = p["r0"] + math.sin(3 * time)
    lin = linearize(ss, time=time)
    assert lin.A == pytest.approx(np.array([[-p["b"] / p["m"]]]))
    assert lin.B == pytest.approx(np.array([[-p["F"] / ratio ** 2]]))
    assert lin.u0 == pytest.approx([ratio])


def test_nonlinear_algebraic_block_is_differentiated_implicitly(tmp_path):
    ss = state_space_of(tmp_path, """model NonlinearLoop
  param c = 1e-4
  Se source : e = 10
  R  r1     : e = 100*f
  R  r2     : f = e/300 + c*e^3
  R  r3     : e = 50*f
  C  cap    : e = q/1e-3
  1  series, branch
  0  node
  source -> series
  series -> r1
  series -> node
  node -> r2
  node -> branch
  branch -> r3
  branch -> cap
end
""")
    assert len(ss.algebraic_blocks) == 1
    q = 0.0     # the initial state, where linearize() works
    model = ss.numeric()
    h = 1e-7
    finite_difference = (model.derivatives(0, [q + h])[0] - model.derivatives(0, [q - h])[0]) / (2 * h)
    lin = linearize(ss)
    assert lin.A[0, 0] == pytest.approx(finite_difference, rel=1e-6)
    # By hand: node voltage v solves (10 - v)/100 = v/300 + c v^3 + (v - vc)/50 at vc = 0 (q = 0);
    # dv/dvc = (1/50) / (1/100 + 1/300 + 3 c v^2 + 1/50) and dq/dt = (v - vc)/50.
    from scipy.optimize import brentq

    v = brentq(lambda v: (10 - v) / 100 - v / 300 - 1e-4 * v ** 3 - v / 50, -100, 100, xtol=1e-14)
    dv = (1 / 50) / (1 / 100 + 1 / 300 + 3e-4 * v ** 2 + 1 / 50)
    assert lin.A[0, 0] == pytest.approx((dv - 1) / 50 / 1e-3, rel=1e-9)


def test_equilibrium_holds_pure_integrators(tmp_path):
    ss = state_space("pneumatic_piston")
    p = params(ss)
    lin = linearize(ss, time=0.0, at="equilibrium")
    # No inflow before the step: the piston stops where the pressure balances the load.
    assert lin.held == ("x",)
    assert lin.x0 == pytest.approx([p["Fl"] / p["Ar"], 0.0, 0.0], abs=1e-6)
    assert "held" in lin.notes[0]
    assert np.count_nonzero(np.abs(lin.eigenvalues) < 1e-9) >= 1


def test_no_equilibrium_is_e940(tmp_path):
    ss = state_space_of(tmp_path, """model Free
  Se push : e = 3
  I  mass : f = p/2
  push -> mass
end
""")
    with pytest.raises(AnalysisError) as info:
        linearize(ss, at="equilibrium")
    assert info.value.diagnostics[0].code == "E940"
    with pytest.raises(ValueError):
        linearize(ss, at="somewhere")


def test_json_and_text_reports():
    ss = state_space("mass_spring_damper")
    lin = linearize(ss, time=1.0)
    data = lin.to_json()
    assert json.loads(json.dumps(data)) == data
    for key in ("states", "inputs", "outputs", "A", "B", "C", "D", "eigenvalues"):
        assert key in data
    assert data["eigenvalues"] == [[pytest.approx(-3.0), pytest.approx(-math.sqrt(400 - 9))],
                                   [pytest.approx(-3.0), pytest.approx(math.sqrt(400 - 9))]]
    text = lin.to_text()
    assert "A (2 x 2)" in text and "eigenvalues" in text and "rad/s" in text


def test_a_comment_row_in_an_input_csv_reads_as_the_simulator_reads_it(tmp_path):
    # the csv reader of the equations stage skips blank and '#' lines like the runtime's
    sim = Path(__file__).parent / "fixtures" / "sim"
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "push.csv").write_text(
        "# measured on the rig\n" + (sim / "data" / "push.csv").read_text() + "\n# end\n")
    (tmp_path / "model.bg").write_text((sim / "csv_force.bg").read_text())
    graph, _ = semantic.load(tmp_path / "model.bg")
    result = linearize(derive(assign_causality(graph)))
    # a free mass: x' = p/m has no dynamics of its own, and the force enters through B = [1]
    np.testing.assert_allclose(result.A, [[0.0]])
    np.testing.assert_allclose(result.B, [[1.0]])


def test_equilibrium_behind_a_relief_valve_that_is_closed_at_the_start():
    # Q = p/Rl + kr*(p - pr) with the valve open: p = (Q + kr*pr)/(1/Rl + kr); A = -(beta/V)*(1/Rl + kr)
    path = Path(__file__).parent / "fixtures" / "engine" / "relief_valve.bg"
    graph, _ = semantic.load(path)
    result = linearize(derive(assign_causality(graph)), at="equilibrium")
    Q, Rl, kr, pr, beta, V = 2e-4, 5e10, 1e-9, 50e5, 1.4e9, 1e-3
    pressure = (Q + kr * pr) / (1 / Rl + kr)
    assert float(result.x0[0]) * beta / V == pytest.approx(pressure, rel=1e-9)
    np.testing.assert_allclose(result.A, [[-(beta / V) * (1 / Rl + kr)]], rtol=1e-9)


def test_check_equations_and_simulation_read_a_csv_file_alike(tmp_path):
    # quoted header cells, a comment row and a blank line: one reader for every stage
    from bondc.runtime import load_csv
    from bondc.pipeline import simulate_file as run
    from bondc.numeric import read_csv_column

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "push.csv").write_text('# force profile\n"time","force"\n0,0\n\n0.5,10\n# end\n2,10\n')
    sim = Path(__file__).parent / "fixtures" / "sim"
    (tmp_path / "model.bg").write_text((sim / "csv_force.bg").read_text())
    graph, _ = semantic.load(tmp_path / "model.bg")            # check: finds the column
    path = str(tmp_path / "data" / "push.csv")
    times, values = read_csv_column(path, "force")
    np.testing.assert_array_equal(times, [0.0, 0.5, 2.0])
    np.testing.assert_array_equal(values, [0.0, 10.0, 10.0])
    assert load_csv(path, "force")[0] is times                # the same reader (and its cache)
    result = run(tmp_path / "model.bg", t_end=2.0)
    # m v' = F(t), F rising linearly to 10 N at 0.5 s: v(2) = (0.5*10/2 + 1.5*10)/2 kg
    assert result.outputs["v"][-1] == pytest.approx((2.5 + 15.0) / 2.0, rel=1e-6)


def test_equilibrium_beyond_a_backlash_gap_where_the_jacobian_column_is_zero_at_the_start():
    # q = gap + F/k; then a mass on a spring and damper: wn = sqrt(k/m) = 10 rad/s, zeta = b/(2*sqrt(k*m))
    path = Path(__file__).parent / "fixtures" / "engine" / "backlash.bg"
    graph, _ = semantic.load(path)
    ss = derive(assign_causality(graph))
    result = linearize(ss, at="equilibrium")
    q = result.x0[list(ss.state_names).index("spring.q")]
    assert q == pytest.approx(0.01 + 3 / 100, rel=1e-9)
    assert result.held == ()
    assert_same_spectrum(result.eigenvalues, np.roots([1.0, 5.0, 100.0]))


def test_a_shockley_diode_loop_far_from_its_guess_linearises_as_its_circuit():
    """exp_diode.bg at its initial point (empty capacitor, 20 V): the loop's guess puts the whole
    source across the diode (exp(800) overflows), where MINPACK alone stopped `linearize` with an
    internal error. Solved as in a run (newton_search), A is the circuit's: with the node voltage v
    from bisection and the diode's conductance g = Is exp(v/Vt)/Vt, dv/dv_cap = (1/R3)/(1/R1 + g +
    1/R3) and d(dq/dt)/dq = (dv/dv_cap - 1)/(R3 Cf)."""
    from test_runtime import shockley_node

    graph, _ = semantic.load(Path(__file__).parent / "fixtures" / "sim" / "exp_diode.bg")
    lin = linearize(derive(assign_causality(graph)))
    v = shockley_node(20.0, 0.0)
    g = 1e-9 * math.exp(v / 0.025) / 0.025
    slope = (1 / 50) / (1 / 100 + g + 1 / 50)
    assert lin.states == ("cap.q",)
    assert lin.A[0, 0] == pytest.approx((slope - 1) / (50 * 1e-3), rel=1e-6)
    assert lin.C[lin.outputs.index("v_diode"), 0] == pytest.approx(slope / 1e-3, rel=1e-6)


def test_a_loop_without_a_root_at_the_operating_point_is_e941_not_an_internal_error(tmp_path):
    """r2 with e = f^2 + 10 (in SI) in parallel with r3 = 3 Ohm: at zero coil current the loop
    -3 f2 = f2^2 + 10 has no real root (discriminant 9 - 40 < 0). linearize reports E941 naming the
    loop, as a diagnostic, instead of an internal error."""
    text = (Path(__file__).parent / "fixtures" / "sim" / "nonlinear_loop.bg").read_text()
    text = text.replace("  R  r2   : e = a3*f^3 + a1*f", "  R  r2   : e = a1*f^2/I0 + V").replace(
        '  param a1 = 1   [Ohm]   "linear coefficient of r2"',
        '  param a1 = 1   [Ohm]   "linear coefficient of r2"\n  param I0 = 1   [A]')
    assert "f^2/I0" in text and "param I0" in text
    with pytest.raises(AnalysisError) as caught:
        linearize(state_space_of(tmp_path, text))
    (diagnostic,) = caught.value.diagnostics
    assert diagnostic.code == "E941" and "algebraic loop through r2, r3, j0" in diagnostic.message


@pytest.mark.parametrize("duty_time, force", [(0.01, 5.0), (0.07, 0.0)])
def test_a_model_with_dry_friction_and_a_pwm_input_linearises(tmp_path, duty_time, force):
    """coulomb() and pwm() in the laws (the linearisation's numeric model had no value for them:
    an internal error). coulomb's force F_slide*sign(v) has no slope away from v = 0, so A is the
    mass-spring-damper's; the pwm input is held at its value at the time given, 5 N on, 0 off."""
    ss = state_space_of(tmp_path, """model M
  input F [N] = 5*pwm(t, 10, 0.5)
  MSe push : e = F
  I mass : f = p/2
  C spring : e = 800*q
  R damper : e = 3*f + coulomb(f, 4, 6)
  1 v
  push -> v
  v -> mass
  v -> spring
  v -> damper
end
""")
    lin = linearize(ss, time=duty_time)
    assert lin.A == pytest.approx(np.array([[-3 / 2, -800.0], [1 / 2, 0.0]]))
    assert lin.u0.tolist() == [force]


def test_an_operating_point_where_a_law_has_no_slope_or_no_value_is_a_clear_error(tmp_path):
    """A turbulent orifice at zero pressure difference (sqrt(abs(e)): an infinite slope) and an
    input that divides by a step still at 0 are E941 naming the derivative or the cause, not an
    internal error (numpy's eigenvalues of a matrix with nan; Python's float division by zero)."""
    orifice = """model Tank
  param k = 1e-7
  Se supply : e = 0
  R valve : f = k*sign(e)*sqrt(abs(e))
  C tank : e = 1e9*q
  1 j
  supply -> j
  j -> valve
  j -> tank
end
"""
    with pytest.raises(AnalysisError) as caught:
        linearize(state_space_of(tmp_path, orifice))
    (error,) = caught.value.diagnostics
    assert error.code == "E941" and "partial derivative of der(tank.q) with respect to tank.q" in error.message
    divided = """model Free
  input u [N] = 10/step(t, 1)
  MSe push : e = u
  I mass : f = p/2
  push -> mass
end
"""
    with pytest.raises(AnalysisError) as caught:
        linearize(state_space_of(tmp_path, divided))
    (error,) = caught.value.diagnostics
    assert error.code == "E941" and "division by zero" in error.message


def test_a_staircase_law_linearises_with_no_slope(tmp_path):
    """A drain whose flow is 0.5*floor(p): floor is constant between its jumps, so its slope is 0
    (sympy keeps d floor(p)/dp unevaluated: it was an internal error, ValueError "Can't calculate
    derivative wrt 0.0"). der(tank.q) = 1 - 0.5*floor(q): A = [[0]]; the outputs q, ceil(q) and
    mod(q, 0.3) = q - 0.3*floor(q/0.3) have slopes 1, 0 and 1."""
    ss = state_space_of(tmp_path, """model Drain
  Sf inflow : f = 1
  C  tank   : e = q
  R  drain  : f = 0.5*floor(e)
  0  n
  inflow -> n
  n -> tank
  n -> drain
  output level [m^3] = tank.q
  output up [m^3] = ceil(tank.q)
  output rest [m^3] = mod(tank.q, 0.3)
end
""")
    lin = linearize(ss)
    assert lin.A.tolist() == [[0.0]] and lin.C.tolist() == [[1.0], [0.0], [1.0]]


def test_discrete_variables_are_held_at_their_value_and_are_not_states_of_the_linear_model(tmp_path):
    """An oven whose heater (P = 100 W) a thermostat's when clauses switch: heater = 1 at the start,
    so the equilibrium is T_amb + P R_th = 343.15 K with one eigenvalue -1/(R_th C_th); the heater is
    neither solved for (der = 0 holds for any value: an equilibrium with it at 0 is T_amb) nor a
    state of the linear model (it would add an eigenvalue 0)."""
    ss = state_space_of(tmp_path, """
model Oven
  param P = 100 [W]
  param R_th = 0.5 [K/W]
  param C_th = 2000 [J/K]
  param T_amb = 293.15 [K]
  discrete heater [1] = 1
  Se ambient : e = T_amb
  MSf element "heat flow in, pseudo bond graph (e = T, f = heat flow)" : f = P*heater
  C air : state T [K], T(0) = T_amb, der(T) = f/C_th, e = T
  R wall : f = e/R_th
  0 node
  1 loss
  element -> node
  node -> air
  node -> loss
  loss -> ambient
  loss -> wall
  output T [K] = air.T
  when air.T > 350 then heater = 0 end
  when air.T < 340 then heater = 1 end
end
""")
    for at in ("initial", "equilibrium"):
        lin = linearize(ss, at=at)
        assert lin.states == ("air.T",) and lin.A.shape == (1, 1) and lin.C.shape == (1, 1)
        assert any("heater = 1" in note for note in lin.notes)
    lin = linearize(ss, at="equilibrium")
    assert lin.x0[0] == pytest.approx(293.15 + 100 * 0.5, rel=1e-9)
    assert lin.eigenvalues[0].real == pytest.approx(-1 / (0.5 * 2000), rel=1e-6)


def test_outputs_declared_in_other_units_are_rows_in_si_and_a_note_says_so(tmp_path):
    """A rotor J = 1e-5 kg m^2: C of w = p/J is 1e5 per kg m^2/s in rad/s whichever unit w is
    declared in; the note gives the factor of rpm (2 pi/60)."""
    ss = state_space_of(tmp_path, """
model Spin
  Se torque : e = 0.1
  I rotor : f = p/1e-5
  R bearing : e = 1e-4*f
  1 shaft
  torque -> shaft
  shaft -> rotor
  shaft -> bearing
  output w [rpm] = rotor.f
  output w_si [rad/s] = rotor.f
end
""")
    lin = linearize(ss)
    assert lin.C[:, 0].tolist() == pytest.approx([1e5, 1e5])
    (note,) = [note for note in lin.notes if "SI" in note]
    assert "w (declared in rpm: 1 rpm = 0.10472 SI)" in note and "w_si" not in note
