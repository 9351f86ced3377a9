"""Two published validation systems, rebuilt and checked by third routes (issue 33 item 7).

The published "hydraulic_accumulator_direct" disagreed with its reference by a sample 3.1x
outside its tolerance, and the electrostatic speaker's equilibrium by 0.5 %. Neither system nor
its reference data is in this repository, so both are rebuilt here from the textbook descriptions
(tests/fixtures/published/) and bondc's answers are compared with routes that share nothing with
bondc: closed forms, scipy's root finders, and ODEs written out by hand and integrated by scipy at
tighter tolerances. What the comparisons showed is written up in docs/third-route.md.

Tolerances. bondc's solvers control the *local* error of each step (rtol*|y| + atol); the global
error of the state is a sum of such local errors and is not bounded pointwise by rtol*|y(t)|, least
of all where y(t) crosses zero (the oil volume at the precharge). The accumulator's comparisons
are therefore against rtol times the state's scale (its largest value), with the factor each
solver was measured to need, and each is repeated at a 100 times looser rtol, where the same
bound in units of that rtol holds: the error follows the tolerance (it is the solver's, not the
model's).
"""

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from bondc import semantic
from bondc.analysis.energy import energy_account
from bondc.api import linearize, simulate
from bondc.causality import assign_causality
from bondc.equations import derive
from bondc.simulate import simulate as simulate_state_space

PUBLISHED = Path(__file__).parent / "fixtures" / "published"

# ------------------------------------------------------------------ accumulator

P_PRE, V_GAS, N = 50e5, 1e-3, 1.4          # precharge [Pa], gas volume [m^3], polytropic exponent
V0, Q0, QA, W = 0.3e-3, 1e-4, 0.48e-3, 3.14159265358979   # as in accumulator_direct_flow*.bg
RTOL = 1e-10                               # the fixtures' defaults (atol 1e-16 m^3: far below)

FLOW = ["accumulator_direct_flow.bg", "accumulator_direct_flow_plain.bg"]
PRESSURE = ["accumulator_direct_pressure.bg", "accumulator_direct_pressure_plain.bg"]


def gas_law(q):
    """The gas's pressure at oil volume q: p V_g^n = p_pre V_gas^n with V_g = V_gas - q while it
    holds oil; emptied (q <= 0), the closed poppet p_pre (1 + 100 n q / V_gas)."""
    q = np.asarray(q, dtype=float)
    full = np.where(q > 0, q, 0.0)
    return np.where(q > 0, P_PRE * (V_GAS / (V_GAS - full)) ** N, P_PRE * (1 + 100 * N * q / V_GAS))


def gas_law_slope(q):
    return N * P_PRE * V_GAS ** N * (V_GAS - q) ** (-N - 1) if q > 0 else 100 * N * P_PRE / V_GAS


def gas_energy(q):
    """The polytropic work done on the gas from precharge to oil volume q, the integral of p dq:
    p_pre V_gas / (n - 1) ((V_gas / (V_gas - q))^(n - 1) - 1); below empty, the poppet's
    p_pre q + 50 n p_pre q^2 / V_gas."""
    if q > 0:
        return P_PRE * V_GAS / (N - 1) * ((V_GAS / (V_GAS - q)) ** (N - 1) - 1)
    return P_PRE * q + 50 * N * P_PRE * q * q / V_GAS


def _with(name, solver=None, rtol=None):
    """The fixture's text with another solver or rtol in its defaults."""
    text = (PUBLISHED / name).read_text()
    if rtol is not None:
        text = text.replace(f"rtol = {RTOL:g}", f"rtol = {rtol:g}")
    if solver is not None:
        text = text.replace("  defaults\n", f'  defaults\n    solver = "{solver}"\n')
    return text


def _run(name, experiment, dt=None, solver=None, rtol=None):
    sim = simulate(PUBLISHED / name, text=_with(name, solver, rtol), experiment=experiment, dt=dt)
    assert sim.complete, sim.result.message
    return sim


def _cycle_volume(t):
    """Oil volume under Q = -Qa sin(w t): V0 - Qa/w (1 - cos w t)."""
    return V0 - QA / W * (1 - np.cos(W * t))


@pytest.mark.parametrize("name", FLOW)
def test_a_constant_flow_charges_the_accumulator_along_the_closed_form(name):
    """Third route: the closed form. The oil volume is V0 + Q0 t and the pressure the gas law at
    it, p_pre (V_gas / (V_gas - V))^n, from 0.3 L to 0.8 L (82 to 475 bar), at the solver's steps
    and at a 0.01 s grid. The rate is constant, so every solver integrates it exactly: rounding."""
    for dt in (None, 0.01):
        sim = _run(name, "charge", dt)
        volume = V0 + Q0 * sim.t
        np.testing.assert_allclose(sim["V_oil"], volume, rtol=1e-13, atol=1e-18)
        np.testing.assert_allclose(sim["p"], gas_law(volume), rtol=1e-12)
    assert sim["p"][-1] == pytest.approx(P_PRE * 5 ** 1.4, rel=1e-12)


@pytest.mark.parametrize("name", FLOW)
def test_a_sinusoidal_flow_empties_the_accumulator_past_its_precharge_and_refills_it(name):
    """Third route: the closed form V(t) = V0 - Qa/w (1 - cos w t), p = the gas law at V. The flow
    empties it twice (V < 0: below the precharge, onto the closed poppet) and refills it. The
    poppet's corner at V = 0 is a kink of the law (the pressure is continuous, its slope 100 times
    steeper below), so no event is located there and the law holds on both sides at every sample.
    The run (DOPRI5 under "auto") is compared at its own steps and at a 0.01 s grid interpolated
    between them; the bounds hold in units of each run's own rtol, at 1e-10 and at 1e-8 (the error
    follows the tolerance: 80 times larger at the looser one)."""
    errors = {}
    for rtol in (RTOL, 100 * RTOL):
        for dt in (None, 0.01):
            sim = _run(name, "cycle", dt, rtol=rtol)
            volume = sim["V_oil"]
            assert not sim.result.events                       # the poppet is a kink, not a jump
            assert volume.min() < -5e-6 and volume.max() > 0.29e-3
            errors[rtol, dt] = np.max(np.abs(volume - _cycle_volume(sim.t))) / (rtol * V0)
            # the law as written on both sides of empty, at bondc's own oil volume
            np.testing.assert_allclose(sim["p"], gas_law(volume), rtol=1e-12)
    # at the steps within the local tolerance of the state's scale (measured 0.6 and 0.8 rtol*V0);
    # between them 7 times that (measured 5.7 and 6.6): DOPRI5's 4th-order continuous extension,
    # the same interpolant as scipy's (test below)
    for rtol in (RTOL, 100 * RTOL):
        assert errors[rtol, None] < 2
        assert errors[rtol, 0.01] < 10


def test_samples_between_steps_are_the_dormand_prince_dense_output_and_cvodes_interpolant():
    """Third route: scipy's RK45 (the same Dormand-Prince pair, its own dense output) on the
    hand-written dV/dt = -Qa sin(w t). At rtol 1e-6 bondc's DOPRI5 samples on a 0.01 s grid are
    scipy's interpolated values to 2 % of their error against the closed form: bondc samples
    with the method's own continuous extension (4th order), not a cubic between the steps, and
    that extension is what makes a sample several times less accurate than the steps. With CVODE
    (forced), a sample is no further from the closed form than the steps on both sides of it plus
    a tenth of rtol*V0 (CVodeGetDky, the BDF interpolating polynomial)."""
    name, rtol = "accumulator_direct_flow_plain.bg", 1e-6
    sim = _run(name, "cycle", 0.01, solver="DOPRI5", rtol=rtol)
    reference = solve_ivp(lambda t, y: [-QA * math.sin(W * t)], (0, 4), [V0], method="RK45", rtol=rtol,
                          atol=1e-16, dense_output=True)
    error = np.max(np.abs(sim["V_oil"] - _cycle_volume(sim.t)))
    assert error > 2 * rtol * V0                        # the interpolant's error: well above the steps'
    assert np.max(np.abs(sim["V_oil"] - reference.sol(sim.t)[0])) < 0.02 * error

    for rtol in (RTOL, 1e-6):
        steps = _run(name, "cycle", solver="CVODE", rtol=rtol)
        samples = _run(name, "cycle", 0.01, solver="CVODE", rtol=rtol)
        at_steps = np.abs(steps["V_oil"] - _cycle_volume(steps.t))
        at_samples = np.abs(samples["V_oil"] - _cycle_volume(samples.t))
        right = np.clip(np.searchsorted(steps.t, samples.t), 1, steps.t.size - 1)
        bracket = np.maximum(at_steps[right - 1], at_steps[right])
        assert np.max(at_samples - bracket) < 0.1 * rtol * V0


_TABLE_T = [0.0, 0.5, 1.5, 2.0, 3.0, 3.5]
_TABLE_P = [P_PRE, 120e5, 120e5, 20e5, 20e5, 120e5]


def _pressure_reference(t_end=4.5, turbulent=False):
    """dV/dt = (p_s(t) - p(V))/R_in (or K sign(dp) sqrt|dp|), written out and integrated by scipy
    (Radau with the analytic Jacobian, rtol 1e-12; LSODA for the orifice) piece by piece between the
    table's corners, where p_s has a corner; a callable V(t)."""
    R_in, K = 1e9, 1e-6
    if turbulent:
        def rates(t, y):
            drop = 80e5 + 50e5 * math.sin(2 * math.pi * t) - float(gas_law(y[0]))
            return [K * math.copysign(math.sqrt(abs(drop)), drop)]
        solution = solve_ivp(rates, (0, t_end), [0.0], method="LSODA", rtol=1e-12, atol=1e-18, dense_output=True)
        assert solution.success
        return lambda t: solution.sol(t)[0]

    def rates(t, y):
        return [(np.interp(t, _TABLE_T, _TABLE_P) - float(gas_law(y[0]))) / R_in]

    pieces, y = [], [0.0]
    corners = [*_TABLE_T, t_end]
    for a, b in zip(corners[:-1], corners[1:]):
        piece = solve_ivp(rates, (a, b), y, method="Radau", rtol=1e-12, atol=1e-18, dense_output=True,
                          jac=lambda t, y: [[-gas_law_slope(y[0]) / R_in]])
        assert piece.success
        pieces.append(piece.sol)
        y = piece.y[:, -1]

    def volume(t):
        t = np.atleast_1d(t)
        which = np.clip(np.searchsorted(corners, t, side="right") - 1, 0, len(pieces) - 1)
        return np.array([pieces[i](tt)[0] for i, tt in zip(which, t)])
    return volume


@pytest.fixture(scope="module")
def laminar_reference():
    return _pressure_reference()


@pytest.mark.parametrize("name", PRESSURE)
@pytest.mark.parametrize("solver, factor", [(None, 3), ("CVODE", 30)])
def test_a_pressure_source_through_a_laminar_inlet_follows_the_hand_written_ode(laminar_reference, name,
                                                                                solver, factor):
    """Third route: dV/dt = (p_s(t) - p(V))/R_in written out and integrated by scipy's Radau at
    rtol 1e-12 (LSODA agrees with it to 2e-15 m^3). The line pressure's table rises from the
    precharge to 120 bar, falls to 20 bar (the accumulator empties onto its poppet, V = V_gas
    (20/50 - 1)/140) and rises again; a 0.05 s grid puts samples exactly on its five corners,
    which are events of the run (known times) and as accurate as the samples between them. The
    std Accumulator (its inlet R_in) and the plain elements give the same run. Bounds in rtol
    times the largest oil volume (0.465 L), at rtol 1e-10 and 1e-8 alike: DOPRI5 (auto) measured
    1.2 and 0.7, CVODE 13 and 6.6 (its BDF's global error)."""
    v_max = 0.465e-3
    for rtol in (RTOL, 100 * RTOL):
        for dt in (None, 0.05):
            sim = _run(name, "cycle", dt, solver=solver, rtol=rtol)
            volume = sim["V_oil"]
            error = np.abs(volume - laminar_reference(sim.t))
            assert np.max(error) < factor * rtol * v_max, (rtol, dt, np.max(error) / (rtol * v_max))
            np.testing.assert_allclose(sim["p"], gas_law(volume), rtol=1e-12)
            np.testing.assert_allclose(sim["Q"], (np.interp(sim.t, _TABLE_T, _TABLE_P) - gas_law(volume)) / 1e9,
                                       rtol=1e-9, atol=1e-12 * 7e-3)
            if dt is not None:
                on_corners = np.isin(np.round(sim.t, 9), _TABLE_T[1:])
                assert on_corners.sum() == 5
        assert sorted(round(t, 9) for t, _ in sim.result.events) == _TABLE_T[1:]
    # emptied at 20 bar, onto the poppet: V = V_gas (p_lo/p_pre - 1)/(100 n)
    held = (sim.t > 2.9) & (sim.t < 3.0)
    np.testing.assert_allclose(volume[held], V_GAS * (20 / 50 - 1) / 140, rtol=1e-6)


def test_a_turbulent_orifice_between_a_sine_and_the_accumulator_follows_the_hand_written_ode():
    """Third route: dV/dt = K sign(dp) sqrt|dp|, dp = p_s(t) - p(V), p_s = 80 + 50 sin(2 pi t) bar,
    written out and integrated by scipy's LSODA at rtol 1e-12 (DOP853 at 1e-13 agrees to 2e-14 m^3). The drop crosses zero transversally
    four times a period (the square root's infinite slope there costs the solver order, not
    accuracy) and the accumulator empties onto its poppet once a period. Bound: 100 rtol times the
    largest volume (measured 30); the run at 100 times looser rtol is at least 20 times worse
    (measured 50)."""
    reference = _pressure_reference(t_end=3.0, turbulent=True)
    errors = {}
    for rtol in (RTOL, 100 * RTOL):
        sim = _run("accumulator_direct_pressure_plain.bg", "turbulent", 0.01, rtol=rtol)
        errors[rtol] = np.max(np.abs(sim["V_oil"] - reference(sim.t)))
    assert sim["V_oil"].min() < 0
    assert errors[RTOL] < 100 * RTOL * 0.49e-3
    assert errors[100 * RTOL] > 20 * errors[RTOL]


def _account(name, experiment, max_step=None):
    graph, _ = semantic.load(PUBLISHED / name, experiment=experiment)
    state_space = derive(assign_causality(graph))
    result = simulate_state_space(state_space, graph.experiments[experiment], max_step=max_step)
    assert result.complete, result.message
    return result, energy_account(state_space, result).windows[0]


@pytest.mark.parametrize("name, gas, source", [("accumulator_direct_pressure_plain.bg", "gas", "line"),
                                               ("accumulator_direct_pressure.bg", "acc.gas", "line.source")])
def test_the_gas_stores_the_closed_form_polytropic_work(name, gas, source):
    """Third route: the closed-form polytropic work, the integral of p dV from the precharge,
    p_pre V_gas/(n - 1) ((V_gas/(V_gas - V))^(n - 1) - 1) (the poppet's quadratic below empty), at
    the run's last oil volume; and the balance: what the line supplied is what the gas stores plus
    what the laminar inlet dissipated, the inlet's loss the integral of (p_s - p)^2/R_in."""
    result, window = _account(name, "cycle")
    volume = result.states[f"{gas}.q"]
    stored = window.element(gas)
    assert stored.energy_function == "numeric"
    assert stored.stored_change == pytest.approx(gas_energy(volume[-1]) - gas_energy(volume[0]), rel=1e-12)
    supplied = window.element(source)
    inlet = window.element("inlet" if gas == "gas" else "acc.inlet")
    assert supplied.supplied - supplied.returned == pytest.approx(stored.stored_change + inlet.dissipated, rel=1e-8)
    assert window.balance.relative_residual < 1e-8


def test_a_constant_flow_supplies_the_closed_form_polytropic_work_in_short_steps():
    """Third route: the closed-form polytropic work. A flow source bonded straight to the gas has
    nothing to lose: what it supplies, the integral of p Q dt, is the gas's work
    W(0.8 L) - W(0.3 L) = 9378.81 J. With steps of at most 0.1 s the account's quadrature agrees to
    1e-12."""
    result, window = _account("accumulator_direct_flow_plain.bg", "charge", max_step=0.1)
    work = gas_energy(0.8e-3) - gas_energy(0.3e-3)
    supplied = window.element("feed")
    assert supplied.supplied - supplied.returned == pytest.approx(work, rel=1e-12)
    assert window.element("gas").stored_change == pytest.approx(work, rel=1e-12)


def test_a_constant_flow_supplies_the_closed_form_polytropic_work_in_the_solvers_own_steps():
    """Third route: the closed-form polytropic work W(0.8 L) - W(0.3 L) = 9378.81 J, as above, in the
    run's own steps (DOPRI5 takes four, the rate being constant, the last 4.45 s long, over which the
    power p(V(t)) Q, 82 to 475 bar, is no polynomial: one 5-point Lobatto rule over it gave
    9380.71 J, 2.0e-4 high; the account halves such steps until the rule agrees with Simpson's)."""
    result, window = _account("accumulator_direct_flow_plain.bg", "charge")
    work = gas_energy(0.8e-3) - gas_energy(0.3e-3)
    supplied = window.element("feed")
    assert window.element("gas").stored_change == pytest.approx(work, rel=1e-12)
    assert supplied.supplied - supplied.returned == pytest.approx(work, rel=1e-9)
    assert window.balance.relative_residual < 1e-9


@pytest.mark.xfail(strict=True, reason=(
    "bondc bug: the statistics of `bondc simulate` (output_statistics of dense_steps) integrate y^2 "
    "by the trapezoid rule through the steps and their three interior Lobatto nodes; over the 4.45 s "
    "last step of a constant charging flow the pressure (82 to 475 bar) was too curved for it: rms "
    "223.63 bar for the closed form's 212.26 (+5.4 %). The energy account's halving of long steps "
    "brings it to 1.9e-4; the trapezoid rule through the nodes is the rest (the Lobatto weights of "
    "each step would be exact)"))
def test_the_pressures_mean_and_rms_over_a_constant_charge_are_the_closed_forms():
    """Third route: the closed form, the time averages of p(t) = p_pre (V_gas/(V_gas - V0 - Q0 t))^n
    over 0..5 s by scipy's quad: the mean and the rms, against the statistics `bondc
    simulate` prints (its solver's steps and the solution between them)."""
    from scipy.integrate import quad

    from bondc.analysis.energy import dense_steps
    from bondc.analysis.stats import output_statistics

    graph, _ = semantic.load(PUBLISHED / "accumulator_direct_flow_plain.bg", experiment="charge")
    state_space = derive(assign_causality(graph))
    result = simulate_state_space(state_space, graph.experiments["charge"])
    statistics = output_statistics(dense_steps(state_space, result))["p"]

    def pressure(t):
        return float(gas_law(V0 + Q0 * t))

    mean = quad(pressure, 0, 5, epsabs=0, epsrel=1e-12)[0] / 5
    rms = math.sqrt(quad(lambda t: pressure(t) ** 2, 0, 5, epsabs=0, epsrel=1e-12)[0] / 5)
    assert statistics["rms"] == pytest.approx(rms, rel=1e-6)
    assert statistics["mean"] == pytest.approx(mean, rel=1e-6)


# ------------------------------------------------------------------ electrostatic speaker

SPEAKER = PUBLISHED / "electrostatic_speaker.bg"
EPS, AREA, GAP, MASS, K_SPRING, B_DAMP, R_S = 8.854e-12, 0.01, 1e-3, 1e-3, 1000.0, 0.5, 1e4


def _speaker_equilibrium(volts):
    """The closed form: k x (x0 - x)^2 = eps A V0^2 / 2, the root below x0/3 (brentq, to rounding),
    q = eps A V0 / (x0 - x); and all three roots of the cubic (numpy.roots)."""
    pull = EPS * AREA * volts ** 2 / 2
    x = brentq(lambda x: K_SPRING * x * (GAP - x) ** 2 - pull, 0.0, GAP / 3, xtol=1e-300, rtol=1e-15)
    roots = np.sort(np.roots([K_SPRING, -2 * K_SPRING * GAP, K_SPRING * GAP ** 2, -pull]).real)
    return x, EPS * AREA * volts / (GAP - x), roots


def _speaker_jacobian(x, q):
    """The hand-derived Jacobian of (q, p, x)' = ((V0 - q (x0 - x)/(eps A))/R_s,
    q^2/(2 eps A) - k x - b p/m, p/m) at (q, 0, x)."""
    return np.array([[-(GAP - x) / (EPS * AREA * R_S), 0.0, q / (EPS * AREA * R_S)],
                     [q / (EPS * AREA), -B_DAMP / MASS, -K_SPRING],
                     [0.0, 1.0 / MASS, 0.0]])


@pytest.mark.parametrize("volts", [1000.0, 250.0, 1800.0])
def test_the_speakers_equilibrium_by_three_routes(volts):
    """Third route: the closed form (the cubic's stable root by brentq, checked against
    numpy.roots) against (1) bondc's equilibrium finder (`linearize --at equilibrium`, from rest
    uncharged) and (2) a 0.5 s run from rest settling to it (the slowest mode decays as
    exp(-250 t)). All three agree to 1e-9 relative (measured: to rounding, 2e-16); at 1800 V, just
    below pull-in (1829 V), the finder still lands on the stable root, not the unstable one beside
    it. The linearisation's eigenvalues are those of the hand-derived Jacobian there."""
    x, q, roots = _speaker_equilibrium(volts)
    assert roots[0] == pytest.approx(x, rel=1e-9) and roots[0] < GAP / 3 < roots[1] < GAP < roots[2]
    lin = linearize(SPEAKER, overrides={"V0": volts}, at="equilibrium")
    found = dict(zip(lin.states, lin.x0))
    assert found["plate.q"] == pytest.approx(x, rel=1e-9)
    assert found["cap.q"] == pytest.approx(q, rel=1e-9)
    assert abs(found["mass.p"]) < 1e-25
    expected = np.sort_complex(np.linalg.eigvals(_speaker_jacobian(x, q)))
    np.testing.assert_allclose(np.sort_complex(lin.eigenvalues), expected, rtol=1e-9)
    assert np.all(lin.eigenvalues.real < 0)
    if volts == 1800.0:
        return          # the settling run near pull-in is slow (the slowest mode's damping): not repeated
    sim = simulate(SPEAKER, overrides={"V0": volts})
    assert sim["x"][-1] == pytest.approx(x, rel=1e-9)
    assert sim["q"][-1] == pytest.approx(q, rel=1e-9)
    assert sim["F"][-1] == pytest.approx(K_SPRING * x, rel=1e-9)


def test_a_small_signal_equilibrium_with_the_undeflected_gap_is_off_by_twice_the_travel():
    """Third route: the closed form. A reference that takes the force at the undeflected gap,
    x = eps A V0^2 / (2 k x0^2) (the small-signal formula), misses the equilibrium by about
    2 x/x0: at 250 V (x/x0 = 0.28 %) by 0.56 %, the size of the published 0.5 % disagreement,
    while bondc's equilibrium is the exact root to rounding; at 1000 V by 9.5 %."""
    for volts, miss in ((250.0, 0.0056), (1000.0, 0.095)):
        x, _, _ = _speaker_equilibrium(volts)
        small_signal = EPS * AREA * volts ** 2 / (2 * K_SPRING * GAP ** 2)
        assert 1 - small_signal / x == pytest.approx(miss, rel=0.02)
        assert 1 - small_signal / x == pytest.approx(2 * x / GAP, rel=0.03)
        lin = linearize(SPEAKER, overrides={"V0": volts}, at="equilibrium")
        assert dict(zip(lin.states, lin.x0))["plate.q"] == pytest.approx(x, rel=1e-12)


class _TooMuchWork(Exception):
    pass


def test_beyond_pull_in_the_equilibrium_finder_gives_up_instead_of_following_the_snap_through(monkeypatch):
    """Third route: the closed form. Above the pull-in voltage sqrt(8 k x0^3 / (27 eps A)) = 1829 V
    the cubic has no root in (0, x0): the plate has no equilibrium in front of the fixed electrode
    and a run snaps it through (bondc's run stops with a clear message). `linearize --at
    equilibrium` must then say E940 (no equilibrium) or return the cubic's one real root (behind
    the electrode: an equilibrium of the equations as written); it must not follow the runaway
    without end (it did: minutes and gigabytes of LSODA steps through inf and nan, until its
    settling integration stopped where the state leaves 1e9 times its scale). Its integrations are counted (a model of three states that settles takes a few
    thousand evaluations) and stopped past 20 000."""
    import scipy.integrate

    from bondc.errors import AnalysisError

    volts = 1850.0
    assert volts > math.sqrt(8 * K_SPRING * GAP ** 3 / (27 * EPS * AREA))
    pull = EPS * AREA * volts ** 2 / 2
    roots = np.roots([K_SPRING, -2 * K_SPRING * GAP, K_SPRING * GAP ** 2, -pull])
    real = roots[np.abs(roots.imag) < 1e-9 * GAP].real
    assert real.size == 1 and real[0] > GAP
    original, calls = scipy.integrate.solve_ivp, [0]

    def counted(fun, *args, **kwargs):
        def rates(t, y):
            calls[0] += 1
            if calls[0] > 20_000:
                raise _TooMuchWork
            return fun(t, y)
        return original(rates, *args, **kwargs)

    monkeypatch.setattr(scipy.integrate, "solve_ivp", counted)
    try:
        lin = linearize(SPEAKER, overrides={"V0": volts}, at="equilibrium")
    except AnalysisError as error:
        assert error.diagnostics[0].code == "E940"
    else:
        assert dict(zip(lin.states, lin.x0))["plate.q"] == pytest.approx(real[0], rel=1e-9)


def test_the_speaker_switched_on_follows_the_hand_written_ode_through_its_transients():
    """Third route: (q, p, x)' = ((V0 - q (x0 - x)/(eps A))/R_s, q^2/(2 eps A) - k x - b p/m, p/m)
    written out and integrated by scipy's Radau with its analytic Jacobian at rtol 1e-12 (BDF
    agrees to 5e-11 of the equilibrium). Switched on at rest: the charge rises in a microsecond
    (the electrical mode, -1.07e6 s^-1), then the plate rings down at 145 Hz, 0.25 damped. bondc's
    run (CVODE, rtol 1e-10) at its steps and on a 10 us grid: within 50 rtol of the equilibrium
    values (measured 16 for the travel, 5 for the charge), the first 100 us included."""
    volts = 1000.0
    x_eq, q_eq, _ = _speaker_equilibrium(volts)

    def rates(t, y):
        q, p, x = y
        return [(volts - q * (GAP - x) / (EPS * AREA)) / R_S,
                q * q / (2 * EPS * AREA) - K_SPRING * x - B_DAMP * p / MASS, p / MASS]

    reference = solve_ivp(rates, (0, 0.5), [0.0, 0.0, 0.0], method="Radau", rtol=1e-12,
                          atol=[1e-22, 1e-18, 1e-18], dense_output=True,
                          jac=lambda t, y: _speaker_jacobian(y[2], y[0]))
    assert reference.success
    for dt in (None, 1e-5):
        sim = simulate(SPEAKER, dt=dt)
        q, _, x = reference.sol(sim.t)
        assert np.max(np.abs(sim["x"] - x)) < 50 * RTOL * x_eq
        assert np.max(np.abs(sim["q"] - q)) < 50 * RTOL * q_eq
        early = sim.t < 1e-4
        assert early.sum() > 3 and np.max(np.abs(sim["q"] - q)[early]) < 50 * RTOL * q_eq
