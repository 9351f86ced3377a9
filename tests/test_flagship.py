"""The flagship model, models/electro_pneumatic_hybrid.bg, checked against shared/seed/MODEL-NOTES.md.

Every expected number here is derived by hand from the notes (the formulas
are re-implemented below, independently of the model's own ``fn``s), never
copied from a simulation. Each experiment is simulated once per module
(module-scoped fixtures); the whole file takes 1-1.5 min, almost all of it
the four simulations (~6-10 s each; measured_speed, a noisy 1 ms signal, ~30 s).

Conventions (notes): x, v up positive, x = 0 at the lowest point;
omega > 0 drives the mass up; tau > 0 pushes the mass up.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from bondc import semantic
from bondc.analysis.motors import requirements
from bondc.causality import assign_causality
from bondc.equations import derive
from bondc.pipeline import simulate_file as run

# the whole file simulates the flagship's experiments: out of `make test-fast`
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "electro_pneumatic_hybrid.bg"
OMEGA_CSV = ROOT / "models" / "data" / "omega_measured.csv"
CATALOGUE = ROOT / "models" / "data" / "motors.csv"

# ------------------------------------------------------------------ the notes, in SI

NOTES = {
    "M": 31.7, "g": 9.81, "lead": 5.0e-3, "Iz": 4.06e-5, "K": 120.9,
    "k_nut": 1.1e8, "gap": 0.1e-3, "c_nut": 1.0e5,
    "Ar": 2.63e-3, "V0": 2.63e-4, "P0": 0.224e6, "P1": 0.224e6, "P_atm": 101325.0,
    "Ae": 1.2e-5, "Ae_catalogue": 6.0e-5, "kappa": 1.4, "R_air": 287.3, "T0": 293.0,
    # friction, eqs. (14)-(15) and Table 3; eqs. (19)-(20)
    "c0": 160.0, "v_th": 0.01, "a_up": 706.59, "n_up": -0.73, "a_dn": 435.61, "n_dn": -0.66,
    "a_up_meas": 213.7, "n_up_meas": -0.79, "a_dn_meas": 179.0, "n_dn_meas": -0.86,
    # speed profile (notes 8)
    "stroke": 0.1, "t_rest0": 0.2, "t_ramp": 0.05, "t_dwell": 1.0, "t_rest_end": 0.5,
}
M, G = NOTES["M"], NOTES["g"]
R_SCREW = NOTES["lead"] / (2 * math.pi)                 # 7.9577e-4 m/rad
W_MAX = 1000 * 2 * math.pi / 60                        # 1000 rpm = 104.7198 rad/s
V_MAX = R_SCREW * W_MAX                                # 0.083333 m/s
KAPPA, R_AIR, T0 = NOTES["kappa"], NOTES["R_air"], NOTES["T0"]
P1, P_ATM, AR = NOTES["P1"], NOTES["P_atm"], NOTES["Ar"]
B_CR = (2 / (KAPPA + 1)) ** (KAPPA / (KAPPA - 1))
BREAKPOINTS = [0.0, 0.2, 0.25, 1.40, 1.45, 2.45, 2.50, 3.65, 3.70, 4.20]      # notes 8, s
PROFILE = [0.0, 0.0, W_MAX, W_MAX, 0.0, 0.0, -W_MAX, -W_MAX, 0.0, 0.0]
F_N0 = M * G - (NOTES["P0"] - P_ATM) * AR               # notes 7: -11.658 N
DELTA0 = -NOTES["gap"] + F_N0 / NOTES["k_nut"]          # valid because F_N0 < 0
THETA0 = R_SCREW * F_N0 / NOTES["K"]

TABLE3 = (706.59, -0.73, 435.61, -0.66)                 # (a_up, n_up, a_dn, n_dn)
MEASURED = (213.7, -0.79, 179.0, -0.86)                 # eqs. (19)-(20)


def friction(v, law=TABLE3):
    """Notes 4: F = C(v)*v, C = 160 below 0.01 m/s, a*|v|^n above it (up/down fits)."""
    a_up, n_up, a_dn, n_dn = law
    v = np.asarray(v, dtype=float)
    speed = np.abs(v)
    with np.errstate(divide="ignore", invalid="ignore"):     # 0**n*0 at v = 0: the where() drops it
        up = a_up * speed ** n_up * speed
        down = -a_dn * speed ** n_dn * speed
    return np.where(speed < 0.01, 160.0 * v, np.where(v > 0, up, down))


def _psi_subsonic(rho):
    return math.sqrt(2 * KAPPA / (KAPPA - 1) * (rho ** (2 / KAPPA) - rho ** ((KAPPA + 1) / KAPPA)))


def psi(rho):
    """Eqs. (2)-(3) with the ranges the right way round, linear in 1 - rho below 1e-4 (notes 1)."""
    if rho <= B_CR:
        return math.sqrt(KAPPA * (2 / (KAPPA + 1)) ** ((KAPPA + 1) / (KAPPA - 1)))
    if 1 - rho < 1e-4:
        return _psi_subsonic(1 - 1e-4) * (1 - rho) / 1e-4
    return _psi_subsonic(rho)


def mass_flow(p_chamber, area):
    """Regulator mass flow into the chamber [kg/s]; negative (relief) when the chamber is above P1."""
    if p_chamber <= P1:
        return area * P1 * psi(p_chamber / P1) / math.sqrt(R_AIR * T0)
    return -area * p_chamber * psi(P1 / p_chamber) / math.sqrt(R_AIR * T0)


def steady_pressure(v, area):
    """Chamber pressure at constant piston speed v: R*T0*mdot(P) = P*Ar*v (eq. 4 with dP/dt = 0)."""
    balance = lambda p: R_AIR * T0 * mass_flow(p, area) - p * AR * v
    if v > 0:    # the chamber expands: the valve must feed it, so P < P1
        return brentq(balance, 0.9 * P1, P1, xtol=1e-9, rtol=1e-15)
    return brentq(balance, P1, 1.1 * P1, xtol=1e-9, rtol=1e-15)   # compressed: relieved, P > P1


def cruise_torque(v, area=NOTES["Ae"], law=TABLE3, mass=M):
    """Motor torque at steady speed: tau = r*(F_friction(v) + M*g - (P - P_atm)*Ar)."""
    pressure = steady_pressure(v, area)
    return R_SCREW * (float(friction(v, law)) + mass * G - (pressure - P_ATM) * AR), pressure


def at(result, time, name):
    """An output (or recorded input) of ``result`` at ``time``, linearly interpolated."""
    values = result.outputs[name] if name in result.outputs else result.variables[name]
    return float(np.interp(time, result.t, values))


def trapezoid(values, time):
    return float(np.sum(np.diff(time) * (values[1:] + values[:-1]) / 2))


# ------------------------------------------------------------------ fixtures: one run per experiment

_RUNS: dict = {}


def simulated(experiment):
    if experiment not in _RUNS:
        _RUNS[experiment] = run(MODEL, experiment=experiment)
    return _RUNS[experiment]


@pytest.fixture(scope="module")
def graph():
    graph, _ = semantic.load(MODEL, experiment="cycle")
    return graph


@pytest.fixture(scope="module")
def state_space(graph):
    return derive(assign_causality(graph))


@pytest.fixture(scope="module")
def cycle():
    return simulated("cycle")


@pytest.fixture(scope="module")
def catalogue_valve():
    return simulated("catalogue_valve")


@pytest.fixture(scope="module")
def measured_friction():
    return simulated("measured_friction")


@pytest.fixture(scope="module")
def measured_speed():
    return simulated("measured_speed")


# ------------------------------------------------------------------ parameters

@pytest.mark.parametrize("name", sorted(NOTES))
def test_parameter_has_the_notes_value_in_si(graph, name):
    assert graph.parameters[name].value == pytest.approx(NOTES[name], rel=1e-12, abs=0)


def test_derived_parameters(graph):
    values = {name: parameter.value for name, parameter in graph.parameters.items()}
    assert round(values["b_cr"], 5) == 0.52828
    assert values["b_cr"] == pytest.approx(B_CR, rel=1e-12)
    assert values["w_max"] == pytest.approx(104.7198, abs=1e-4)
    assert values["r_screw"] == pytest.approx(7.9577e-4, rel=1e-5)
    assert values["v_max"] == pytest.approx(0.1 / 1.2, rel=1e-12)       # 100 mm in 1.2 s of full speed
    # each move: ramp/2 + cruise + ramp/2 at full speed covers the stroke
    assert values["t_cruise"] == pytest.approx(NOTES["stroke"] / V_MAX - NOTES["t_ramp"], rel=1e-12)
    times = [0.0] + [values[f"t{i}"] for i in range(1, 10)]
    assert times == pytest.approx(BREAKPOINTS, abs=1e-12)
    assert values["F_n0"] == pytest.approx(F_N0, rel=1e-12)
    assert values["delta0"] == pytest.approx(DELTA0, rel=1e-12)
    assert values["theta0"] == pytest.approx(THETA0, rel=1e-12)


def test_pneumatic_bonds_carry_the_papers_subscripts(graph):
    """Bonds 1-6 are numbered as in the paper (docs/flagship.md relies on it)."""
    ends = {bond.number: (bond.tail, bond.head) for bond in graph.bonds}
    assert ends[1] == ("supply", "j_valve")          # P_1
    assert ends[2] == ("j_valve", "valve")           # m_2
    assert ends[4] == ("j_chamber", "chamber")       # P_4
    assert ends[5] == ("j_chamber", "piston")        # Q_5, P_5
    assert ends[6] == ("piston", "j_mass")           # F_6, v_6
    assert ends[7] == ("servomotor", "j_motor")


# ------------------------------------------------------------------ initial state

def test_initial_state_is_the_notes_static_equilibrium(state_space):
    numeric = state_space.numeric()
    x0 = dict(zip(state_space.state_names, numeric.initial_state()))
    assert F_N0 == pytest.approx(-11.658, abs=1e-3) and F_N0 < 0     # the air over-carries the weight
    assert x0["coupling.q"] == pytest.approx(THETA0, rel=1e-12)
    assert x0["nut.q"] == pytest.approx(DELTA0, rel=1e-12)
    assert abs(x0["nut.q"]) > NOTES["gap"]                          # the spring branch carries F_n0
    assert x0["chamber.P"] == pytest.approx(NOTES["P0"], rel=1e-12)
    assert x0["shaft.p"] == x0["mass.p"] == x0["x_piston"] == 0.0

    rates = dict(zip(state_space.state_names, numeric.derivatives(0.0, numeric.initial_state())))
    # zero to rounding: forces of ~300 N and torques of ~1e-2 N*m cancel to 1e-13 of themselves;
    # the valve law at P = P1 evaluates to rounding noise, ~1e-15 kg/s, i.e. ~5e-7 Pa/s
    tolerance = {"coupling.q": 1e-12, "shaft.p": 1e-12, "nut.q": 1e-12, "mass.p": 1e-9,
                 "chamber.P": 1e-3, "x_piston": 1e-12}
    for name, rate in rates.items():
        assert abs(rate) < tolerance[name], (name, rate)

    outputs = numeric.outputs(0.0, numeric.initial_state())
    assert outputs["torque"] == pytest.approx(R_SCREW * F_N0, rel=1e-9)      # tau0 = K*theta0 = r*F_n0
    assert outputs["F_nut"] == pytest.approx(F_N0, rel=1e-9)


def test_nothing_moves_before_the_first_ramp(cycle):
    before = cycle.t < BREAKPOINTS[1]
    assert before.sum() > 2
    assert np.max(np.abs(cycle.outputs["x"][before])) < 1e-12
    assert np.max(np.abs(cycle.outputs["v"][before])) < 1e-12
    assert cycle.outputs["torque"][before] == pytest.approx(R_SCREW * F_N0, rel=1e-9)


# ------------------------------------------------------------------ the cycle

def test_speed_input_is_the_trapezoid_of_the_notes(cycle):
    assert cycle.variables["omega"] == pytest.approx(np.interp(cycle.t, BREAKPOINTS, PROFILE), abs=1e-9)
    # and it moves the screw by exactly one stroke up, then one down
    screw = R_SCREW * np.array([trapezoid(np.interp(t, BREAKPOINTS, PROFILE), t) for t in
                                (np.linspace(0, 1.45, 14501), np.linspace(1.45, 4.2, 27501))])
    assert screw == pytest.approx([0.1, -0.1], rel=1e-12)


def test_cycle_completes_with_finite_outputs(cycle):
    assert cycle.complete, cycle.message
    assert cycle.t[-1] == pytest.approx(4.2)
    for name, values in cycle.outputs.items():
        assert np.all(np.isfinite(values)), name


def test_mass_rises_one_stroke_and_returns(cycle):
    """The screw travels exactly 100 mm; the mass follows it up to the nut backlash.

    At rest the nut holds the mass down (F_n0 < 0, delta0 = -gap + F_n0/k).
    Lifting, the nut crosses its backlash to the other flank: the mass lags
    the screw by 2*gap + (F_lift - F_n0)/k_nut ~ 0.203 mm. At the top the
    surplus air force pushes it back across the gap, against the nut damper,
    towards x = 100 mm exactly (delta back to delta0) but never beyond: so
    100 mm - 2*gap - 0.01 mm <= max x <= 100 mm. On the way down it is the
    same in reverse, ending at delta0, i.e. at x = 0.
    """
    x = cycle.outputs["x"]
    gap = NOTES["gap"]
    assert 0.1 - 2 * gap - 1e-5 <= x.max() <= 0.1 + 1e-6
    assert abs(x.max() - 0.1) < 1e-3
    assert abs(x[-1]) < 0.2e-3
    assert abs(x[-1]) < 1e-6              # the final rest is the initial equilibrium again
    # at the start of the deceleration (t3 = 1.40 s, 2.08 mm of screw travel still to go) the mass
    # lags by the full backlash, the nut spring's extra compression and the coupling's wind-up
    f_lift = cruise_torque(V_MAX)[0] / R_SCREW
    lag = 2 * gap + (f_lift - F_N0) / NOTES["k_nut"]
    twist = R_SCREW * R_SCREW * (f_lift - F_N0) / NOTES["K"]      # the coupling winds up by d(tau)/K
    assert lag + twist == pytest.approx(0.2051e-3, abs=1e-7)
    assert at(cycle, 1.40, "x") == pytest.approx(0.1 - V_MAX * 0.05 / 2 - lag - twist, abs=1e-7)


def test_dwell_creep_across_the_backlash(cycle):
    """During the dwell (screw at rest, nut inside its gap) only the nut damper and the low-speed
    friction hold back the surplus air force -F_n0: v = -F_n0/(c_nut + c0) = 0.1164 mm/s."""
    expected = -F_N0 / (NOTES["c_nut"] + NOTES["c0"])
    assert at(cycle, 2.0, "v") == pytest.approx(expected, rel=1e-2)
    assert at(cycle, 2.3, "x") - at(cycle, 1.7, "x") == pytest.approx(0.6 * expected, rel=2e-2)


@pytest.mark.parametrize("time, direction", [(0.8, +1), (3.0, -1)], ids=["up", "down"])
def test_steady_cruise_torque_matches_the_hand_calculation(cycle, time, direction):
    """tau = r*(F_friction(v) + M*g - (P - P_atm)*Ar) with P from R*T0*mdot(P) = P*Ar*v.

    Tolerance: at mid-cruise the transients have died out. The pressure is a
    first-order lag of time constant V/(kappa*P*dQ/dP) ~ 4 ms (dQ/dP from the
    orifice slope at |P1 - P| ~ 440 Pa) and the mechanical modes are damped
    by the nut damper within a few ms; 0.55 s after the ramp they are gone to
    rounding, so what remains is the solver tolerance (rtol 1e-6). The
    pressure is checked to 1 Pa (r*Ar*1 Pa = 2e-6 N*m of torque) and as
    settled (no change over +-0.1 s); the torque to 0.1 % -- tighter than
    0.5 %, which would hide a 670 Pa pressure error (r*Ar*670 Pa = 0.5 %).
    """
    v = direction * V_MAX
    tau, pressure = cruise_torque(v)
    # the speed to 5e-6: the integration's own noise on it over the cruise is +-2e-6 of it (the
    # mass's momentum is weighted by its absolute tolerance), whichever steps the run takes
    assert at(cycle, time, "v") == pytest.approx(v, rel=5e-6)
    assert at(cycle, time, "P") == pytest.approx(pressure, abs=1.0)
    assert abs(at(cycle, time + 0.1, "P") - at(cycle, time - 0.1, "P")) < 1e-2
    assert (pressure < P1) == (direction > 0)        # fed going up, relieved going down
    assert at(cycle, time, "torque") == pytest.approx(tau, rel=1e-3)
    assert at(cycle, time, "mdot_valve") == pytest.approx(pressure * AR * v / (R_AIR * T0), rel=1e-3)


def test_rms_torque_is_the_cruise_estimate(cycle):
    """RMS over the cycle ~ sqrt((tau_up^2 + tau_down^2)*t_full/4.2) with t_full = 1.2 s of
    full-speed-equivalent travel per move; the ramps' peaks and the rest torque add ~2 %."""
    tau_up, tau_down = cruise_torque(V_MAX)[0], cruise_torque(-V_MAX)[0]
    estimate = math.sqrt((tau_up ** 2 + tau_down ** 2) * 1.2 / 4.2)
    rms = math.sqrt(trapezoid(cycle.outputs["torque"] ** 2, cycle.t) / 4.2)
    assert rms == pytest.approx(estimate, rel=0.03)


def test_outputs_are_consistent(cycle):
    assert cycle.outputs["torque"] == pytest.approx(NOTES["K"] * cycle.states["coupling.q"], rel=1e-9, abs=1e-12)
    assert cycle.outputs["power"] == pytest.approx(cycle.outputs["torque"] * cycle.variables["omega"], abs=1e-9)
    assert cycle.outputs["x"] == pytest.approx(cycle.states["x_piston"], rel=1e-12, abs=1e-15)


# ------------------------------------------------------------------ friction law

@pytest.mark.parametrize("experiment, law", [("cycle", TABLE3), ("measured_friction", MEASURED)],
                         ids=["table3", "eqs19-20"])
def test_friction_law_through_the_compiled_model(experiment, law):
    graph, _ = semantic.load(MODEL, experiment=experiment)
    state_space = derive(assign_causality(graph))
    numeric = state_space.numeric()
    x0 = numeric.initial_state()
    index = state_space.state_names.index("mass.p")
    speeds = [-0.3, -V_MAX, -0.0101, -0.0099, -1e-3, 0.0, 1e-3, 0.0099, 0.0101, V_MAX, 0.3]
    for v in speeds:
        x = x0.copy()
        x[index] = M * v
        value = numeric.outputs(0.0, x)["F_friction"]
        assert math.isfinite(value)
        assert value == pytest.approx(float(friction(v, law)), rel=1e-9, abs=1e-12), v
    # the jump the notes warn about, at 0.01 m/s: 1.6 N to 204 N up, -1.6 N to -91 N down (Table 3)
    if law is TABLE3:
        assert float(friction(0.01 + 1e-12)) == pytest.approx(203.8, abs=0.1)
        assert float(friction(-0.01 - 1e-12)) == pytest.approx(-91.0, abs=0.1)


def test_friction_along_the_cycle_follows_the_law_or_slides_on_the_threshold(cycle):
    """Everywhere F = F(v), except while the mass slides on |v| = v_th (Filippov): there F lies
    between the two one-sided limits of the law (1.6 N and 203.8 N up, -1.6 N and -91.0 N down)."""
    v, force = cycle.outputs["v"], cycle.outputs["F_friction"]
    assert np.all(np.isfinite(force))
    assert (v < -0.01).any() and (v > 0.01).any() and (np.abs(v) < 0.01).any() and (v == 0).any()
    expected = friction(v)
    off = np.abs(force - expected) > 1e-9 * np.maximum(1.0, np.abs(expected))
    assert off.sum() < 0.01 * v.size
    on_threshold = np.abs(np.abs(v[off]) - 0.01) < 1e-7
    assert on_threshold.all(), cycle.t[off][~on_threshold]
    side = np.sign(v[off])
    low = np.where(side > 0, float(friction(0.01 - 1e-12)), float(friction(-0.01 - 1e-12)))
    high = np.where(side > 0, float(friction(0.01 + 1e-12)), float(friction(-0.01 + 1e-12)))
    lower, upper = np.minimum(low, high), np.maximum(low, high)
    assert np.all((force[off] >= lower - 1e-6) & (force[off] <= upper + 1e-6))


# ------------------------------------------------------------------ energy

def test_mechanical_energy_balance_closes(cycle, graph):
    """Notes: net motor energy = friction + damper losses - pneumatic work + M*g*dx + d(stored).

    Every term integrated (trapezoid) from the recorded bond variables; the
    bonds are found from the elements, not by number. Stored: the coupling
    and nut springs (the nut's only beyond the gap) and both inertias.
    """
    bonds, states = cycle.bonds, cycle.states

    def bond(element, port=0):
        return f"b{graph.elements[element].bonds[port]}"

    def power(name):
        return bonds[f"{name}.e"] * bonds[f"{name}.f"]

    motor = trapezoid(power(bond("servomotor")), cycle.t)
    friction_loss = trapezoid(power(bond("friction")), cycle.t)
    damper_loss = trapezoid(power(bond("nut_damper")), cycle.t)
    # net air force (P - P_atm)*Ar on the mass times v: piston port 2 minus the atmosphere
    pneumatic = trapezoid((bonds[f"{bond('piston', 1)}.e"] - bonds[f"{bond('atmosphere')}.e"])
                          * bonds[f"{bond('piston', 1)}.f"], cycle.t)
    lift = M * G * (cycle.outputs["x"][-1] - cycle.outputs["x"][0])

    def stored(i):
        theta, delta = states["coupling.q"][i], states["nut.q"][i]
        spring = 0.5 * NOTES["K"] * theta ** 2 + 0.5 * NOTES["k_nut"] * max(abs(delta) - NOTES["gap"], 0.0) ** 2
        return spring + states["shaft.p"][i] ** 2 / (2 * NOTES["Iz"]) + states["mass.p"][i] ** 2 / (2 * M)

    residual = motor - (friction_loss + damper_loss - pneumatic + lift + stored(-1) - stored(0))
    assert motor == pytest.approx(55.0, rel=0.05)           # ~ friction over 2 strokes, see below
    # the friction work is ~ (F_up + |F_down|)*stroke = (361.2 + 187.1 N)*0.1 m = 54.8 J
    assert friction_loss == pytest.approx((float(friction(V_MAX)) - float(friction(-V_MAX))) * 0.1, rel=0.01)
    assert abs(residual) < 1e-3                               # J, of ~55 J: trapezoid on 1 ms steps


def test_energy_account_closes_per_cycle(cycle, state_space):
    """bondc.analysis.energy over the experiment's cycle (4.2 s: one window). The notes' balance,
    net motor energy = friction + damper - pneumatic work + M*g*dx + d(stored), from its entries;
    and the whole graph's balance (sources = dissipated + stored + net work into the chamber)."""
    from bondc.analysis.energy import energy_account

    account = energy_account(state_space, cycle)
    assert len(account.windows) == 1 and not account.resimulated
    window = account.windows[0]
    assert (window.t_start, window.t_end) == pytest.approx((0.0, 4.2))
    entry = window.element
    motor = entry("servomotor").supplied - entry("servomotor").returned
    # power into the piston at p2 is -F*v: the air's work on the mass is minus that, less the atmosphere's
    pneumatic = -entry("piston").port_work[1] - (entry("atmosphere").returned - entry("atmosphere").supplied)
    lift = entry("gravity").returned - entry("gravity").supplied
    stored = sum(entry(name).stored_change for name in ("coupling", "shaft", "nut", "mass"))
    losses = entry("friction").dissipated + entry("nut_damper").dissipated
    residual = motor - (losses - pneumatic + lift + stored)
    assert abs(residual) < 1e-6 * motor
    # back at x = 0: gravity takes 31.08 J going up and gives it back going down (M*g*0.1 m = 31.10 J,
    # less the 0.2 mm backlash lag) -- to quadrature error
    assert entry("gravity").supplied == pytest.approx(M * G * 0.1, rel=2e-3)
    assert lift == pytest.approx(0.0, abs=1e-6)
    assert abs(stored) < 1e-9                                       # back at the initial equilibrium
    # the air takes work from the mechanism: below P1 going up, above it going down
    assert pneumatic < 0
    # the same motor energy as the plain trapezoid of tau*omega
    assert motor == pytest.approx(trapezoid(cycle.outputs["power"], cycle.t), abs=1e-3)
    assert window.balance.relative_residual < 1e-6
    assert not [d for d in account.diagnostics if d.code == "W930"]


# ------------------------------------------------------------------ variants

def test_catalogue_valve_holds_the_pressure_closer(cycle, catalogue_valve):
    """Steady deviation |P - P1| from R*T0*mdot = P*Ar*v. Near rho = 1, psi ~ sqrt(2*(1 - rho)),
    so |dP| ~ (Ar*v*sqrt(R*T0)/Ae)^2 * P1/2 ~ 1/Ae^2: the 5x area would give 1/25 of the
    deviation. But the catalogue deviation (~20 Pa) falls inside the linear band of notes 1
    (|dP| < 1e-4*P1 = 22.4 Pa), where psi = sqrt(2e-4)*(1 - rho)/1e-4 and |dP| ~ 1/Ae:
    ratio = sqrt(2e-4)*Ae_est^2/(c*Ae_cat), c = Ar*v/sqrt(R*T0), = 0.0449."""
    assert catalogue_valve.complete, catalogue_valve.message
    c = AR * V_MAX / math.sqrt(R_AIR * T0)
    closed_form = math.sqrt(2e-4) * NOTES["Ae"] ** 2 / (c * NOTES["Ae_catalogue"])
    assert closed_form == pytest.approx(0.0449, abs=5e-4)
    for time, direction in ((0.8, +1), (3.0, -1)):
        v = direction * V_MAX
        estimated = steady_pressure(v, NOTES["Ae"]) - P1
        catalogue = steady_pressure(v, NOTES["Ae_catalogue"]) - P1
        assert abs(catalogue) < 1e-4 * P1 < abs(estimated)
        assert at(catalogue_valve, time, "P") - P1 == pytest.approx(catalogue, abs=0.5)
        ratio = (at(catalogue_valve, time, "P") - P1) / (at(cycle, time, "P") - P1)
        assert 1 / 25 < ratio < 1 / 5
        assert ratio == pytest.approx(closed_form, rel=0.02)
        tau, _ = cruise_torque(v, NOTES["Ae_catalogue"])
        assert at(catalogue_valve, time, "torque") == pytest.approx(tau, rel=1e-3)


def test_measured_friction_changes_the_cruise_torque_by_r_times_dF(cycle, measured_friction):
    """Eqs. (19)-(20) at v_max: 213.7*v^0.21 = 126.8 N up (Table 3: 361.2 N) and 179.0*v^0.14 =
    126.4 N down (Table 3: 187.1 N). The pressure does not depend on friction, so the cruise
    torques differ by exactly r*dF."""
    assert measured_friction.complete, measured_friction.message
    for time, v in ((0.8, V_MAX), (3.0, -V_MAX)):
        d_force = float(friction(v, MEASURED) - friction(v, TABLE3))
        d_tau = at(measured_friction, time, "torque") - at(cycle, time, "torque")
        assert d_tau == pytest.approx(R_SCREW * d_force, rel=1e-3)
        assert at(measured_friction, time, "F_friction") == pytest.approx(float(friction(v, MEASURED)), rel=1e-6)
    assert float(friction(V_MAX, MEASURED)) == pytest.approx(126.8, abs=0.1)
    assert float(friction(-V_MAX, MEASURED)) == pytest.approx(-126.4, abs=0.1)


def _csv_speed():
    data = np.genfromtxt(OMEGA_CSV, delimiter=",", names=True)
    return data["t"], data["omega"]


def test_measured_speed_drives_the_cycle_from_the_csv(measured_speed):
    assert measured_speed.complete, measured_speed.message
    for name, values in measured_speed.outputs.items():
        assert np.all(np.isfinite(values)), name
    t_csv, omega_csv = _csv_speed()
    # the run's input is the recorded signal, joined linearly between the samples
    assert measured_speed.variables["omega"] == pytest.approx(np.interp(measured_speed.t, t_csv, omega_csv),
                                                              abs=1e-6 * W_MAX)
    # the signal moves the screw one stroke up and one down (hand integral of the CSV), up to the
    # noise: +-0.5 % uniform on 1200 samples of ~0.083 mm each is ~8e-6 m (1 sigma) per move
    top = np.searchsorted(t_csv, 2.0)
    assert R_SCREW * trapezoid(omega_csv[:top + 1], t_csv[:top + 1]) == pytest.approx(0.1, abs=3e-5)
    assert R_SCREW * trapezoid(omega_csv, t_csv) == pytest.approx(0.0, abs=3e-5)
    x = measured_speed.outputs["x"]
    assert 0.1 - 2 * NOTES["gap"] - 2e-5 <= x.max() <= 0.1 + 1e-5
    assert abs(x[-1]) < 0.2e-3
    # back at the initial equilibrium, the mass ends where the screw ends: the signal's net travel
    assert x[-1] == pytest.approx(R_SCREW * trapezoid(omega_csv, t_csv), abs=1e-7)
    # the 0.5 % speed noise averages out: the mean cruise torque is the hand value (the friction
    # is concave in v, so the noise lowers the mean by ~(0.27*0.73/2)*(0.5 %)^2/3: negligible)
    for (start, end), v in (((0.5, 1.3), V_MAX), ((2.8, 3.5), -V_MAX)):
        inside = (measured_speed.t >= start) & (measured_speed.t <= end)
        mean = trapezoid(measured_speed.outputs["torque"][inside], measured_speed.t[inside]) / (end - start)
        assert mean == pytest.approx(cruise_torque(v)[0], rel=5e-3)


# ------------------------------------------------------------------ motor selection

def test_motor_report_for_the_cycle(cycle, graph):
    from bondc.analysis.motor_report import motor_report

    text, data = motor_report(cycle, graph, CATALOGUE)
    assert data["torque"] == {"name": "torque", "from": "output"}
    assert data["speed"] == {"name": "omega", "from": "input"}
    assert data["cycle"] == pytest.approx([0.0, 4.2])
    assert data["include_rotor_inertia"] is True
    # load seen by the motor: M*r^2 + I_z = 6.0674e-5 kg*m^2
    assert data["load_inertia"] == pytest.approx(M * R_SCREW ** 2 + NOTES["Iz"], rel=2e-3)
    need = data["requirements"]
    assert need["peak_speed"] == pytest.approx(W_MAX, rel=1e-9)
    assert need["energy_net"] == pytest.approx(need["energy_positive"] - need["energy_regenerative"], rel=1e-12)
    # the RMS torque (~0.17 N*m by the cruise estimate) exceeds SV-50's 0.16 N*m rated torque;
    # SV-100 (0.32 N*m rated, 0.95 peak) meets the torque and speed rules, but its rotor
    # (0.051e-4 kg*m^2) is 1/11.9 of the load: the inertia-ratio rule (<= 10) rejects it
    assert data["best"] == "SV-200"
    rejected = {c["motor"]["name"]: [rule for rule, check in c["checks"].items() if check["passed"] is False]
                for c in data["candidates"] if not c["qualifies"]}
    assert rejected == {"SV-50": ["rms_torque", "inertia_ratio"], "SV-100": ["inertia_ratio"]}
    assert "SV-100 is smaller but its load/rotor inertia ratio is 11.9, above 10." in data["verdict"]
    assert text.rstrip().endswith("above 10.") and "RMS torque" in text


def test_motor_report_options(cycle, graph):
    """A given load inertia is used as given; without the rotor inertia every motor sees the same
    profile, so the margins are catalogue value / cycle requirement exactly."""
    from bondc.analysis.motor_report import motor_report
    from bondc.analysis.motors import reflected_inertia

    inertia = reflected_inertia(M, NOTES["lead"], shaft_inertia=NOTES["Iz"])
    _, data = motor_report(cycle, graph, CATALOGUE, load_inertia=inertia, include_rotor_inertia=False)
    assert data["load_inertia"] == inertia and data["load_inertia_source"] == "given"
    need = data["requirements"]
    for candidate in data["candidates"]:
        motor = candidate["motor"]
        assert candidate["margins"]["peak_torque"] == pytest.approx(motor["peak_torque"] / need["peak_torque"])
        assert candidate["inertia_ratio"] == pytest.approx(inertia / motor["rotor_inertia"])


def test_motor_report_without_a_torque_output_is_a_usage_error():
    from bondc.analysis.motor_report import motor_report
    from bondc.errors import UsageError

    path = ROOT / "tests" / "fixtures" / "sim" / "rc.bg"
    result = run(path)
    graph, _ = semantic.load(path, experiment=semantic.FIRST)
    with pytest.raises(UsageError) as info:
        motor_report(result, graph, CATALOGUE)
    assert [d.code for d in info.value.diagnostics] == ["E927"]


@pytest.mark.slow
@pytest.mark.parametrize("mass", [20.0, 25.0, 30.0, 35.0, 40.0, 45.0])
def test_every_mass_from_20_to_45_kg_completes_with_the_hand_calculated_cruise_torque(mass):
    """The cycle for other payloads: it completes without chattering, the steady cruise torque up and
    down is the hand calculation at that mass, and the motor requirements can be computed."""
    result = run(MODEL, experiment="cycle", sets=[f"M={mass}"])
    assert result.complete, result.message
    assert not [label for _, label in result.events if label.startswith("chattering")]
    assert np.all(np.diff(result.t) > 0)
    for time, direction in ((0.8, +1), (3.0, -1)):
        tau, pressure = cruise_torque(direction * V_MAX, mass=mass)
        assert at(result, time, "P") == pytest.approx(pressure, abs=1.0)
        assert at(result, time, "torque") == pytest.approx(tau, rel=1e-3)
    need = requirements(result.t, result.outputs["torque"], result.variables["omega"])
    assert need.peak_torque >= max(abs(cruise_torque(V_MAX, mass=mass)[0]), abs(cruise_torque(-V_MAX, mass=mass)[0]))
    assert need.energy_net > 0
    # every mass starts in static equilibrium (notes 7), the nut in contact on the side its force
    # pushes (above 32.89 kg the weight is no longer over-carried by the air): nothing moves before
    # the first ramp
    f_n0 = mass * NOTES["g"] - (NOTES["P0"] - NOTES["P_atm"]) * NOTES["Ar"]
    before = result.t < BREAKPOINTS[1]
    assert np.max(np.abs(result.outputs["x"][before])) < 1e-12, f_n0
    assert np.max(np.abs(result.outputs["torque"][before] - R_SCREW * f_n0)) < 1e-9 * abs(R_SCREW * f_n0), f_n0
