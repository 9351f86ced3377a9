"""The shipped component library (``import "std:..."``), each component against an independent answer.

Every model here is built from library components only (plus a junction or
two) and compared with a closed form or a hand-written ODE integrated by scipy
at a tighter tolerance.
"""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from bondc.flatten import ports_of
from bondc.parse import parse_source
from bondc.semantic import STD_LIBRARIES, _std_library
from bondc.pipeline import simulate_file as run
from bondc.source import Source

# each test compiles and simulates a model: the whole module runs with the slow tests (CI runs all)
pytestmark = pytest.mark.slow

TIGHT = "  defaults\n    rtol = 1e-10\n    atol = 1e-12\n  end\n"


def _run(tmp_path, text, t_end, dt, name="m.bg"):
    path = tmp_path / name
    path.write_text(text.replace("%TIGHT%", TIGHT) + "")
    result = run(path, t_end=t_end, dt=dt)
    assert result.complete, result.message
    return result


# ------------------------------------------------------------ mechanics

def test_mass_spring_damper_free_vibration(tmp_path):
    # M x'' + c x' + k x = 0, x(0) = 0.01, x'(0) = 0 (x the spring's compression):
    # wn = 20 rad/s, zeta = 0.1.
    text = '''import "std:mechanics"
model MSD
  Mass body : M = 2
  Spring spring : k = 800, x0 = 0.01
  Damper damper : c = 8
  1 v
  v -> body.a
  v -> spring.a
  v -> damper.a
%TIGHT%  experiment free
    t_end = 1 [s]
  end
end
'''
    result = _run(tmp_path, text, 1.0, 0.01)
    wn, zeta, x0 = 20.0, 0.1, 0.01
    wd = wn * math.sqrt(1 - zeta ** 2)
    t = result.t
    x = np.exp(-zeta * wn * t) * (x0 * np.cos(wd * t) + zeta * wn * x0 / wd * np.sin(wd * t))
    assert np.allclose(result.outputs["spring.x"], x, atol=1e-8)
    assert np.allclose(result.outputs["spring.F"], 800 * x, atol=1e-5)


def test_breakaway_then_sliding_with_a_static_limit_above_the_sliding_force(tmp_path):
    # Force 10*t against F_s = 8, F_c = 5 on 2 kg: stuck until t = 0.8 s, then
    # M v' = 10 t - 5, so v = (5 (t^2 - 0.64) - 5 (t - 0.8))/2.
    text = '''import "std:mechanics"
model Breakaway
  Mass body : M = 2
  Force push : F = 10*t
  CoulombFriction friction : F_c = 5, F_s = 8
  1 v
  push.a -> v
  v -> body.a
  v -> friction.a
%TIGHT%  experiment ramp
    t_end = 1.5 [s]
  end
end
'''
    result = _run(tmp_path, text, 1.5, 0.05)
    t, v = result.t, result.outputs["body.v"]
    expected = np.where(t < 0.8, 0.0, (5 * (t ** 2 - 0.64) - 5 * (t - 0.8)) / 2)
    assert np.allclose(v, expected, atol=1e-6)


def test_two_masses_on_a_spring_damper_keep_their_momentum_and_follow_the_relative_closed_form(tmp_path):
    # mu x'' + c x' + k x = 0 for the compression x, x(0) = 0, x'(0) = v0; total momentum m1 v0.
    text = '''import "std:mechanics"
model Pair
  Mass one : M = 1, v0 = 1
  Mass two : M = 3
  SpringDamper link : k = 300, c = 3
  1 v1
  1 v2
  v1 -> one.a
  v1 -> link.a
  link.b -> v2
  v2 -> two.a
%TIGHT%  experiment go
    t_end = 2 [s]
  end
end
'''
    result = _run(tmp_path, text, 2.0, 0.01)
    v1, v2 = result.outputs["one.v"], result.outputs["two.v"]
    assert np.allclose(1 * v1 + 3 * v2, 1.0, atol=1e-8)
    mu, k, c = 0.75, 300.0, 3.0
    wn, zeta = math.sqrt(k / mu), c / (2 * math.sqrt(k * mu))
    wd = wn * math.sqrt(1 - zeta ** 2)
    x = np.exp(-zeta * wn * result.t) * np.sin(wd * result.t) / wd
    assert np.allclose(result.outputs["link.x"], x, atol=1e-8)


def test_backlash_between_a_velocity_source_and_a_spring_follows_the_hand_written_ode(tmp_path):
    text = '''import "std:mechanics"
model Slack
  Velocity drive : v = 0.01
  Backlash play : k = 1e4, gap = 1 [mm], c = 50
  RigidCoupling rod
  Spring load : k = 2000
  drive.a -> play.a
  play.b -> rod.a
  rod.b -> load.a
%TIGHT%  experiment push
    t_end = 0.5 [s]
  end
end
'''
    result = _run(tmp_path, text, 0.5, 0.01)
    k, gap, c, k2, v0 = 1e4, 1e-3, 50.0, 2000.0, 0.01

    def rates(t, y):
        x1, x2 = y
        spring = 0.0 if abs(x1) <= gap else k * (x1 - math.copysign(gap, x1))
        v_rel = (k2 * x2 - spring) / c
        return [v_rel, v0 - v_rel]

    reference = solve_ivp(rates, (0, 0.5), [0.0, 0.0], method="LSODA", rtol=1e-11, atol=1e-14,
                          dense_output=True, max_step=1e-3)
    assert np.allclose(result.outputs["play.x"], reference.sol(result.t)[0], atol=1e-8)
    assert np.allclose(result.outputs["load.x"], reference.sol(result.t)[1], atol=1e-8)


def test_gravity_and_a_force_balance_leave_a_mass_at_rest(tmp_path):
    text = '''import "std:mechanics"
model Hold
  Mass body : M = 4
  Gravity weight : M = 4, g = 9.81
  Force lift : F = 4*9.81
  1 v
  lift.a -> v
  v -> body.a
  v -> weight.a
end
'''
    result = _run(tmp_path, text, 1.0, 0.5)
    assert np.allclose(result.outputs["body.v"], 0.0, atol=1e-12)
    unbalanced = _run(tmp_path, text.replace("F = 4*9.81", "F = 0"), 1.0, 0.5, name="fall.bg")
    assert np.allclose(unbalanced.outputs["body.v"], -9.81 * unbalanced.t, rtol=1e-9)


# ------------------------------------------------------------ rotational

def test_inertia_spun_up_by_a_torque_against_a_damper(tmp_path):
    text = '''import "std:rotational"
model SpinUp
  Inertia rotor : J = 0.02
  Torque motor : T = 0.5
  RotationalDamper bearing : c = 0.01
  RotationalFriction seal : T_c = 0.1
  1 w
  motor.a -> w
  w -> rotor.a
  w -> bearing.a
  w -> seal.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 5.0, 0.5)
    # J w' = 0.5 - 0.1 - 0.01 w (sliding from the first instant: 0.5 > 0.1)
    expected = 0.4 / 0.01 * (1 - np.exp(-0.01 * result.t / 0.02))
    assert np.allclose(result.outputs["rotor.w"], expected, rtol=1e-7, atol=1e-9)


def test_torsional_coupling_from_a_speed_source_rings_as_a_damped_oscillator(tmp_path):
    text = '''import "std:rotational"
model Shaft
  Speed motor : w = 10
  TorsionalCoupling coupling : k = 50, c = 0.02
  Inertia load : J = 0.01
  TorsionSpring anchor : k = 0
  motor.a -> coupling.a
  coupling.b -> load.a
%TIGHT%end
'''.replace("  TorsionSpring anchor : k = 0\n", "")
    result = _run(tmp_path, text, 1.0, 0.01)
    # u = w0 - w: J u' = -k theta - c u, theta' = u, u(0) = w0 = 10
    J, k, c = 0.01, 50.0, 0.02
    wn, zeta = math.sqrt(k / J), c / (2 * math.sqrt(k * J))
    wd = wn * math.sqrt(1 - zeta ** 2)
    theta = 10 * np.exp(-zeta * wn * result.t) * np.sin(wd * result.t) / wd
    assert np.allclose(result.outputs["coupling.theta"], theta, atol=1e-8)
    assert np.allclose(result.outputs["coupling.T"], k * theta + c * (10 - result.outputs["load.w"]), atol=1e-6)


# ------------------------------------------------------------ electrical

def test_rc_charging_and_rl_current_rise(tmp_path):
    text = '''import "std:electrical"
model RC
  VoltageSource supply : u = 12
  Resistor r : R = 1 [kOhm]
  Capacitor cap : C = 100 [uF]
  Inductor coil : L = 10 [mH]
  Resistor r2 : R = 5
  VoltageSource supply2 : u = 12
  1 loop
  1 loop2
  supply.a -> loop
  loop -> r.a
  loop -> cap.a
  supply2.a -> loop2
  loop2 -> coil.a
  loop2 -> r2.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.5, 0.01)
    assert np.allclose(result.outputs["cap.v"], 12 * (1 - np.exp(-result.t / 0.1)), atol=1e-8)
    assert np.allclose(result.outputs["coil.i"], 12 / 5 * (1 - np.exp(-result.t * 5 / 10e-3)), atol=1e-8)


def test_current_source_into_a_capacitor_ramps_its_voltage(tmp_path):
    text = '''import "std:electrical"
model Ramp
  CurrentSource feed : i = 2 [mA]*0 + 0.002
  Capacitor cap : C = 10 [uF]
  feed.a -> cap.a
end
'''.replace("2 [mA]*0 + 0.002", "0.002")
    result = _run(tmp_path, text, 1.0, 0.25)
    assert np.allclose(result.outputs["cap.v"], 0.002 * result.t / 10e-6, rtol=1e-9)


def test_dc_motor_step_response_matches_the_linear_ode(tmp_path):
    text = '''import "std:electrical"
import "std:rotational"
model Drive
  VoltageSource supply : u = 24
  DCMotor motor : R_a = 2, L_a = 5 [mH], k = 0.1, J = 1e-4, c = 1e-5
  RotationalDamper load : c = 2e-4
  supply.a -> motor.elec
  motor.shaft -> load.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.5, 0.01)
    R, L, k, J, c = 2.0, 5e-3, 0.1, 1e-4, 1e-5 + 2e-4
    A = np.array([[-R / L, -k / L], [k / J, -c / J]])
    b = np.array([24 / L, 0.0])
    reference = solve_ivp(lambda t, y: A @ y + b, (0, 0.5), [0, 0], method="DOP853", rtol=1e-12, atol=1e-12,
                          dense_output=True)
    i, w = reference.sol(result.t)
    assert np.allclose(result.outputs["motor.i"], i, atol=1e-7)
    assert np.allclose(result.outputs["motor.w"], w, atol=1e-6)
    assert result.outputs["motor.w"][-1] == pytest.approx(k * 24 / (k * k + R * c), rel=1e-6)  # steady state
    assert np.allclose(result.outputs["motor.T"], k * i, atol=1e-7)


def test_half_wave_rectifier_current_solves_the_diode_and_resistor_in_series(tmp_path):
    text = '''import "std:electrical"
model Rectifier
  VoltageSource mains : u = 10*sin(2*pi*50*t)
  Diode d : V_f = 0.7, R_on = 0.1, G_off = 1e-6
  Resistor load : R = 100
  1 loop
  mains.a -> loop
  loop -> d.a
  loop -> load.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.04, 0.001)

    def current(u):
        def residual(i):
            v = u - 100 * i
            return (v - 0.7) / 0.1 + 0.7e-6 - i if v > 0.7 else v * 1e-6 - i
        return brentq(residual, -1, 1, xtol=1e-14)

    expected = [current(10 * math.sin(2 * math.pi * 50 * t)) for t in result.t]
    assert np.allclose(result.outputs["d.i"], expected, atol=1e-9)
    assert max(expected) == pytest.approx((10 - 0.7) / 100.1, rel=1e-3)


# ------------------------------------------------------------ hydraulics

_FILL = '''import "std:hydraulics"
model Fill
  PressureSource pump : p = 100e5
  %VALVE%, Cd = 0.6, rho = 870
  Chamber tank : V = 1 [L], beta = 1.5e9
  pump.a -> valve.a
  valve.b -> tank.a
%TIGHT%end
'''


def _filled(t, opened=0.0):
    """The chamber's pressure filled through the orifice from ``opened`` on (closed form):
    dp/dt = beta/V*k*sqrt(p_s - p), so sqrt(p_s - p) = sqrt(p_s) - beta*k/(2V)*(t - opened)."""
    k = 0.6 * 1e-6 * math.sqrt(2 / 870)
    root = np.maximum(math.sqrt(100e5) - 1.5e9 * k / (2 * 1e-3) * np.maximum(t - opened, 0), 0)
    return 100e5 - root ** 2


def test_orifice_fills_a_chamber_as_the_closed_form(tmp_path):
    result = _run(tmp_path, _FILL.replace("%VALVE%", "Orifice valve : A = 1e-6"), 0.02, 0.002)
    assert np.allclose(result.outputs["tank.p"], _filled(result.t), rtol=1e-7, atol=10)


def test_a_variable_orifice_opened_at_5_ms_fills_a_chamber_as_the_closed_form(tmp_path):
    # closed (A <= 0) until 5 ms, then as the fixed orifice from there
    valve = "VariableOrifice valve : A = 2e-6*step(t, 0.005) - 1e-6"
    result = _run(tmp_path, _FILL.replace("%VALVE%", valve), 0.02, 0.001)
    assert np.allclose(result.outputs["tank.p"], _filled(result.t, 0.005), rtol=1e-7, atol=10)
    assert np.all(result.outputs["valve.Q"][result.t < 0.005] == 0)


@pytest.mark.parametrize("p0", [0.0, 150e5])
def test_an_orifice_with_a_laminar_band_fills_and_drains_a_chamber_as_the_closed_form(tmp_path, p0):
    """Turbulent while the drop d = p_s - p is beyond dp_l (sqrt(|d|) linear in time, as the plain
    orifice), then laminar inside the band: d decays exponentially with tau = sqrt(dp_l)*V/(beta*k),
    to 0 (where the plain orifice's slope is infinite). From an empty chamber the drop is positive;
    from 150 bar the chamber drains back into the 100 bar supply, the drop negative."""
    valve = "LaminarTurbulentOrifice valve : A = 1e-6, dp_l = 1e5"
    text = _FILL.replace("%VALVE%", valve).replace("beta = 1.5e9", f"beta = 1.5e9, p0 = {p0}")
    result = _run(tmp_path, text, 0.25, 0.001)
    k, rate, dp_l, ps = 0.6 * 1e-6 * math.sqrt(2 / 870), 1.5e9 / 1e-3, 1e5, 100e5
    d0 = ps - p0
    t1 = (math.sqrt(abs(d0)) - math.sqrt(dp_l)) * 2 / (rate * k)       # the drop reaches the band
    tau = math.sqrt(dp_l) / (rate * k)
    t = result.t
    turbulent = np.sign(d0) * np.maximum(math.sqrt(abs(d0)) - rate * k / 2 * t, 0) ** 2
    laminar = np.sign(d0) * dp_l * np.exp(-np.maximum(t - t1, 0) / tau)
    expected = ps - np.where(t < t1, turbulent, laminar)
    assert 0.05 < t1 < 0.15 and t[-1] - t1 > 10 * tau
    np.testing.assert_allclose(result.outputs["tank.p"], expected, rtol=0, atol=2e-7 * ps)
    flow = result.outputs["valve.Q"]
    np.testing.assert_allclose(flow, k * np.sign(ps - result.outputs["tank.p"]) * np.minimum(
        np.sqrt(np.abs(ps - result.outputs["tank.p"])), np.abs(ps - result.outputs["tank.p"]) / math.sqrt(dp_l)),
        rtol=1e-9, atol=1e-18)


def test_laminar_restriction_relief_valve_pump_and_accumulator(tmp_path):
    # Pump D*w into a chamber relieved above p_crack: steady state p = p_crack + D*w/K_v.
    text = '''import "std:hydraulics"
import "std:rotational"
model Relief
  Speed motor : w = 100
  Pump pump : D = 1e-6
  Chamber line : V = 0.1 [L], beta = 1.4e9
  ReliefValve relief : p_crack = 100 [bar], K_v = 1e-10
  0 node
  motor.a -> pump.shaft
  pump.a -> node
  node -> line.a
  node -> relief.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.5, 0.05)
    # before cracking: p = beta/V*D*w*t, reached at t = 100e5*V/(beta*D*w)
    t_crack = 100e5 * 1e-4 / (1.4e9 * 1e-6 * 100)
    early = result.t < t_crack
    assert np.allclose(result.outputs["line.p"][early], 1.4e9 / 1e-4 * 1e-4 * result.t[early], rtol=1e-7)
    # after: p' = beta/V*(D w - K_v (p - p_crack)), an exponential to the steady state
    tau = 1e-4 / (1.4e9 * 1e-10)
    late = result.t > t_crack
    steady = 100e5 + 1e-4 / 1e-10
    expected = steady - (steady - 100e5) * np.exp(-(result.t[late] - t_crack) / tau)
    assert np.allclose(result.outputs["line.p"][late], expected, rtol=1e-6)

    text = '''import "std:hydraulics"
model Charge
  FlowSource feed : Q = 1e-4
  Accumulator acc : p_pre = 20 [bar], V_gas = 2 [L], n = 1.4
  LaminarRestriction pipe : R_h = 1e12
  Chamber tank : V = 1 [L], beta = 1.4e9, p0 = 0
  PressureSource supply : p = 10 [bar]*0 + 1e6
  feed.a -> acc.a
  supply.a -> pipe.a
  pipe.b -> tank.a
%TIGHT%end
'''.replace("10 [bar]*0 + 1e6", "1e6")
    result = _run(tmp_path, text, 10.0, 1.0, name="charge.bg")
    assert np.allclose(result.outputs["acc.p"], 20e5 * (2e-3 / (2e-3 - 1e-4 * result.t)) ** 1.4, rtol=1e-8)
    # a tank behind a laminar restriction: p = p_s*(1 - exp(-t/tau)), tau = R_h*V/beta
    tau = 1e12 * 1e-3 / 1.4e9
    assert np.allclose(result.outputs["tank.p"], 1e6 * (1 - np.exp(-result.t / tau)), rtol=1e-7, atol=1e-3)
    assert np.allclose(result.outputs["pipe.Q"], (1e6 - result.outputs["tank.p"]) / 1e12, rtol=1e-7, atol=1e-15)


def test_an_accumulator_discharged_below_precharge_empties_and_its_poppet_holds(tmp_path):
    """An accumulator holding 0.5 L of its 1 L gas volume (p = 50 bar * 2^1.4) is opened to a
    10 bar line through its inlet R_in: the oil leaves as dV/dt = (p_line - p(V))/R_in, through
    V = 0 (the gas back at precharge), and stops where the closed poppet's law, p_pre*(1 +
    100 n V/V_gas), meets the line: V = V_gas*(10/50 - 1)/(100*1.4), not the gas expanding past
    its volume. The same accumulator beside a line volume has integral causality (its inlet
    separates them)."""
    text = '''import "std:hydraulics"
model Discharge
  PressureSource line : p = 10e5
  Accumulator acc : p_pre = 50 [bar], V_gas = 1 [L], n = 1.4, V0 = 0.5e-3, R_in = 1e8
  line.a -> acc.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 2.0, 0.01, name="discharge.bg")
    V = result.outputs["acc.V_oil"]
    p = result.outputs["acc.p"]
    assert p[0] == pytest.approx(50e5 * 2 ** 1.4, rel=1e-12)
    assert V[-1] == pytest.approx(1e-3 * (10 / 50 - 1) / (100 * 1.4), rel=1e-6)
    assert p[-1] == pytest.approx(10e5, rel=1e-6)
    # the law on both sides of empty, and the flow through the inlet
    full = V > 0
    assert np.allclose(p[full], 50e5 * (1e-3 / (1e-3 - V[full])) ** 1.4, rtol=1e-12)
    assert np.allclose(p[~full], 50e5 * (1 + 100 * 1.4 * V[~full] / 1e-3), rtol=1e-12)
    assert np.allclose(result.outputs["acc.Q"], (10e5 - p) / 1e8, rtol=1e-9, atol=1e-15)
    beside = '''import "std:hydraulics"
model Beside
  FlowSource pump : Q = 1e-4
  Chamber line : V = 0.5 [L], beta = 1.4e9, p0 = 60 [bar]
  Accumulator acc : p_pre = 50 [bar]
  0 n
  pump.a -> n
  n -> line.a
  n -> acc.a
end
'''
    from bondc.causality import assign_causality
    from bondc.semantic import load

    path = tmp_path / "beside.bg"
    path.write_text(beside)
    causal = assign_causality(load(path)[0])
    assert not causal.derivative_storage


def test_hydraulic_cylinder_follows_the_hand_written_ode(tmp_path):
    text = '''import "std:hydraulics"
import "std:mechanics"
model Lift
  FlowSource pump : Q = 1e-5
  Cylinder cyl : A = 1e-3, V0 = 1e-4, beta = 1e9
  Mass load : M = 50
  Spring stop : k = 1e5
  1 v
  pump.a -> cyl.a
  cyl.rod -> v
  v -> load.a
  v -> stop.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.2, 0.01)
    A, V0, beta, M, k, Q = 1e-3, 1e-4, 1e9, 50.0, 1e5, 1e-5

    def rates(t, y):
        p, x, v, s = y     # pressure, piston travel, velocity, spring compression
        return [beta / (V0 + A * x) * (Q - A * v), v, (p * A - k * s) / M, v]

    reference = solve_ivp(rates, (0, 0.2), [0, 0, 0, 0], method="DOP853", rtol=1e-12, atol=1e-12,
                          dense_output=True)
    p, x, v, _ = reference.sol(result.t)
    assert np.allclose(result.outputs["cyl.p"], p, rtol=1e-6, atol=1e-2)
    assert np.allclose(result.outputs["cyl.travel"], x, atol=1e-10)
    assert np.allclose(result.outputs["load.v"], v, atol=1e-8)


# ------------------------------------------------------------ pneumatics

@pytest.mark.parametrize("valve, mdot", [
    # isentropic nozzle, choked: Ae*p_s*psi*/sqrt(R*T), psi* = sqrt(k*(2/(k+1))^((k+1)/(k-1)))
    ("Nozzle valve : Ae = 2e-6, R_gas = 287, T = 293",
     2e-6 * 6e5 * math.sqrt(1.4 * (2 / 2.4) ** (2.4 / 0.4)) / math.sqrt(287 * 293)),
    # ISO 6358, choked: C*rho0*p_s*sqrt(T0/T)
    ("ISO6358Valve valve : C = 1e-8, b_cr = 0.3, R_gas = 287, T = 293",
     1e-8 * 1.185 * 6e5 * math.sqrt(293.15 / 293)),
])
def test_a_chamber_filled_through_a_choked_valve_rises_linearly(tmp_path, valve, mdot):
    # choked: constant mass flow; adiabatic chamber p' = kappa*R*T/V * mdot (p*Q = mdot*R*T)
    text = f'''import "std:pneumatics"
model Fill
  PressureSupply supply : p_s = 6 [bar]
  {valve}
  AdiabaticChamber tank : V = 1 [L], p0 = 1 [bar]
  supply.a -> valve.a
  valve.b -> tank.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.2, 0.01)
    rise = 1.4 * 287 * 293 / 1e-3 * mdot
    choked = result.outputs["tank.p"] < 0.25 * 6e5
    assert choked.sum() > 3
    assert np.allclose(result.outputs["tank.p"][choked], 1e5 + rise * result.t[choked], rtol=1e-6)
    assert np.allclose(result.outputs["valve.mdot"][choked], mdot, rtol=1e-6)
    assert np.all(np.diff(result.outputs["tank.p"]) >= 0) and result.outputs["tank.p"][-1] < 6e5 * (1 + 1e-9)


@pytest.mark.parametrize("bleed", [
    "atmosphere -> bleed.a\n  bleed.b -> node",          # chamber at the bleed's port b: flow from b to a
    "node -> bleed.a\n  bleed.b -> atmosphere",          # chamber at its port a: flow from a to b
])
def test_a_chamber_between_a_supply_and_the_atmosphere_settles_where_the_two_iso_valves_pass_the_same_mass_flow(
        tmp_path, bleed):
    """Supply (6 bar) -> ISO 6358 valve C1 -> chamber -> valve C2 -> the atmosphere (1.01325 bar),
    the bleed valve drawn either way round: each port's volume flow is taken at its own pressure,
    so the chamber fills and empties by the same mass flows. In steady state the two mass flows are
    equal: C1 p_s phi(p/p_s) = C2 p phi(p_a/p), phi(r) = 1 for r <= b, sqrt(1 - ((r - b)/(1 - b))^2)
    above (rho0 and sqrt(T0/T) cancel); the pressure is that equation's root."""
    from scipy.optimize import brentq

    text = '''import "std:pneumatics"
model Bleed
  PressureSupply supply : p_s = 6 [bar]
  ISO6358Valve inlet : C = 2e-9, b_cr = 0.3
  AdiabaticChamber chamber : V = 0.1 [L], p0 = 101325
  ISO6358Valve bleed : C = 3e-9, b_cr = 0.3
  Se atmosphere "ambient, power in" : e = 101325
  0 node
  supply.a -> inlet.a
  inlet.b -> node
  node -> chamber.a
  %BLEED%
%TIGHT%end
'''.replace("%BLEED%", bleed)
    result = _run(tmp_path, text, 3.0, 0.01)
    outward = 1.0 if bleed.startswith("node") else -1.0
    phi = lambda r: 1.0 if r <= 0.3 else math.sqrt(1 - ((r - 0.3) / 0.7) ** 2)      # noqa: E731
    p_s, p_a = 6e5, 101325.0
    p = brentq(lambda x: 2e-9 * p_s * phi(x / p_s) - 3e-9 * x * phi(p_a / x), p_a * 1.001, p_s * 0.999,
               xtol=1e-9, rtol=1e-15)
    assert result.outputs["chamber.p"][-1] == pytest.approx(p, rel=1e-6)
    assert outward * result.outputs["bleed.mdot"][-1] == pytest.approx(result.outputs["inlet.mdot"][-1], rel=1e-6)
    assert outward * result.outputs["bleed.mdot"][-1] == pytest.approx(
        3e-9 * 1.185 * p * math.sqrt(293.15 / 293) * phi(p_a / p), rel=1e-6)


@pytest.mark.parametrize("valve", ["Nozzle valve : Ae = 1e-6", "ISO6358Valve valve : C = 3e-9, b_cr = 0.3"])
@pytest.mark.parametrize("wiring", ["one -> valve.a\n  valve.b -> two", "two -> valve.a\n  valve.b -> one"])
def test_two_closed_chambers_through_a_valve_keep_their_internal_energy_and_end_at_its_mean_pressure(
        tmp_path, valve, wiring):
    """Two adiabatic chambers (2 L at 6 bar, 0.5 L at 1 bar) joined by a valve, drawn either way:
    the same mass flow leaves one and enters the other at the same temperature, so
    d(p1 V1 + p2 V2)/dt = kappa R T (mdot_in1 + mdot_in2) = 0, and both end at
    (p1 V1 + p2 V2)/(V1 + V2) = 5 bar. A valve that took both volume flows at one port's pressure
    breaks the sum whenever the pressures differ."""
    text = f'''import "std:pneumatics"
model Pair
  AdiabaticChamber high : V = 2 [L], p0 = 6 [bar]
  AdiabaticChamber low : V = 0.5 [L], p0 = 1 [bar]
  {valve}
  0 one
  0 two
  one -> high.a
  two -> low.a
  {wiring}
%TIGHT%end
'''
    result = _run(tmp_path, text, 3.0, 0.01)
    p1, p2 = result.outputs["high.p"], result.outputs["low.p"]
    energy = p1 * 2e-3 + p2 * 0.5e-3
    assert np.max(np.abs(energy - 1250.0)) < 1e-6 * 1250.0
    assert p2[1] > 1e5 and np.all(np.diff(p2) >= -1e-6 * 5e5)          # the small one fills ...
    assert p1[-1] == pytest.approx(5e5, rel=1e-6) and p2[-1] == pytest.approx(5e5, rel=1e-6)


def test_a_return_line_to_a_tank_holds_the_orifice_drop_above_the_tank_pressure(tmp_path):
    """FlowSource Q -> chamber -> turbulent orifice -> Tank at p_t (power in at its port): the
    chamber settles at p_t + (Q/(Cd A sqrt(2/rho)))^2."""
    text = '''import "std:hydraulics"
model Return
  FlowSource pump : Q = 1e-4
  Chamber line : V = 1e-4, p0 = 0
  Orifice restrictor : Cd = 0.62, A = 1e-5, rho = 850
  Tank tank : p_t = 2 [bar]
  0 node
  pump.a -> node
  node -> line.a
  node -> restrictor.a
  restrictor.b -> tank.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.2, 0.01)
    expected = 2e5 + (1e-4 / (0.62 * 1e-5 * math.sqrt(2 / 850))) ** 2
    assert result.outputs["line.p"][-1] == pytest.approx(expected, rel=1e-6)
    assert result.outputs["restrictor.Q"][-1] == pytest.approx(1e-4, rel=1e-6)


# ------------------------------------------------------------ transmissions

def test_gear_ball_screw_lead_screw_and_belt(tmp_path):
    text = '''import "std:transmissions"
import "std:rotational"
import "std:mechanics"
model Trains
  Torque t1 : T = 0.2
  Gear gear : n = 4
  Inertia drum : J = 0.5
  t1.a -> gear.a
  gear.b -> drum.a

  Torque t2 : T = 0.1
  BallScrew screw : lead = 10 [mm]
  Mass table : M = 20
  t2.a -> screw.shaft
  screw.nut -> table.a

  Torque t3 : T = 0.05
  LeadScrew lead_screw : lead = 2 [mm], F_c = 20, c = 50
  Mass slide : M = 5
  t3.a -> lead_screw.shaft
  lead_screw.nut -> slide.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 1.0, 0.1)
    t = result.t
    assert np.allclose(result.outputs["drum.w"], 4 * 0.2 * t / 0.5, rtol=1e-9)      # T_b = n*T_a
    r = 0.01 / (2 * math.pi)
    assert np.allclose(result.outputs["table.v"], 0.1 / r * t / 20, rtol=1e-9)     # F = T/r
    r = 0.002 / (2 * math.pi)
    force = 0.05 / r - 20                                                          # sliding from the start
    assert np.allclose(result.outputs["slide.v"], force / 50 * (1 - np.exp(-50 * t / 5)), rtol=1e-8, atol=1e-12)


def test_belt_drive_follows_the_hand_written_ode(tmp_path):
    text = '''import "std:transmissions"
import "std:rotational"
import "std:mechanics"
model BeltDrive
  Torque motor : T = 1
  Inertia pulley_inertia : J = 1e-3
  Belt belt : r_p = 20 [mm], k_b = 1e5, c_b = 50
  Mass carriage : M = 2
  1 w
  motor.a -> w
  w -> pulley_inertia.a
  w -> belt.shaft
  belt.belt -> carriage.a
%TIGHT%end
'''
    result = _run(tmp_path, text, 0.2, 0.01)
    J, r, k, c, M = 1e-3, 0.02, 1e5, 50.0, 2.0

    def rates(_, y):
        w, s, v = y
        force = k * s + c * (r * w - v)
        return [(1 - r * force) / J, r * w - v, force / M]

    reference = solve_ivp(rates, (0, 0.2), [0, 0, 0], method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True)
    w, s, v = reference.sol(result.t)
    assert np.allclose(result.outputs["pulley_inertia.w"], w, rtol=1e-6, atol=1e-6)
    assert np.allclose(result.outputs["carriage.v"], v, rtol=1e-6, atol=1e-8)


# ------------------------------------------------------------ the library as a whole

@pytest.mark.parametrize("name", STD_LIBRARIES)
def test_every_library_component_declares_ports_and_describes_itself(name):
    path = _std_library(name)
    file = parse_source(Source(f"std:{name}", path.read_text(encoding="utf-8"), path))
    assert file.models
    for model in file.models:
        assert ports_of(model), model.name
        assert model.description and len(model.description) > 20, model.name
        for statement in model.body:
            if type(statement).__name__ == "Param":
                assert statement.description, f"{model.name}.{statement.name} has no description"


def test_the_component_page_is_up_to_date():
    from pathlib import Path

    from bondc.std import describe

    page = Path(__file__).parent.parent / "docs" / "components.md"
    assert page.read_text(encoding="utf-8") == describe(), "run: python -m bondc.std > docs/components.md"
