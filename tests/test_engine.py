"""The simulation engine on the switching laws of fluid power and mechatronics.

Each model in ``tests/fixtures/engine`` is simulated with bondc's default
engine (SUNDIALS CVODE) and compared with an independent answer: a closed
form, or the same physics written by hand here and integrated by scipy at a
much tighter tolerance.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from bondc.simulate import run, simulate
from bondc.pipeline import derive_file

ENGINE = Path(__file__).parent / "fixtures" / "engine"


def _derive(name, sets=()):
    derived = derive_file(ENGINE / f"{name}.bg", sets=sets)
    return derived.state_space, derived.experiment


# ------------------------------------------------------------ square-root laws

def test_orifice_flow_reverses_without_nan_and_matches_the_hand_written_ode():
    result = run(ENGINE / "orifice_reversing.bg")
    assert result.complete, result.message
    Cd, A, rho, beta, V, P0, fs = 0.62, 1e-6, 850.0, 1.4e9, 10e-3, 50e5, 5.0

    def chamber(t, y):
        drop = P0 * np.sin(2 * np.pi * fs * t) - y[0]
        return [beta / V * Cd * A * np.sqrt(2 / rho) * np.sign(drop) * np.sqrt(abs(drop))]

    reference = solve_ivp(chamber, (0, 2), [0.0], method="DOP853", rtol=1e-12, atol=1e-6, dense_output=True)
    expected = reference.sol(result.t)[0]
    p, flow = result.outputs["p"], result.outputs["Q"]
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(flow))
    np.testing.assert_allclose(p, expected, rtol=0, atol=1e-5 * P0)
    # the flow reverses twice per period of the supply: 20 times in 2 s
    reversals = np.count_nonzero(np.diff(np.sign(flow[np.abs(flow) > 1e-9])) != 0)
    assert reversals == 20


def test_tank_filling_from_empty_follows_the_closed_form():
    # dp/dt = (Qin - a*sqrt(p))/C from p = 0, where the law's slope is infinite. With u = sqrt(p):
    # t(u) = (2C/a) * (-u - (Qin/a) * ln(1 - a*u/Qin))
    result = run(ENGINE / "tank_filling.bg")
    assert result.complete, result.message
    Qin, a, C = 1e-4, 2e-7, 1e-10
    p = result.outputs["p"]
    assert p[0] == 0.0 and np.all(p >= 0)
    u = np.sqrt(p)
    mask = a * u / Qin < 0.999            # where t(u) is well conditioned
    t_closed = 2 * C / a * (-u[mask] - Qin / a * np.log1p(-a * u[mask] / Qin))
    np.testing.assert_allclose(t_closed, result.t[mask], rtol=0, atol=1e-6)
    # the end, where t(u) is ill conditioned: u(t_end) by root finding on the closed form
    u_end = brentq(lambda v: 2 * C / a * (-v - Qin / a * np.log1p(-a * v / Qin)) - result.t[-1], 0, Qin / a * (1 - 1e-15))
    assert abs(p[-1] - u_end**2) < 1e-7 * u_end**2


# ---------------------------------------------------------- sticking frictions

def test_three_coupled_clutches_stick_together_then_the_first_breaks_away():
    # J = 1 each, tau = t. Stuck: all four turn as one, w = t^2/8, and clutch i carries
    # (4 - i)/4 of tau. Clutch 1 reaches its 3 N*m static limit at tau = 4, t = 4 s; then it
    # slips with 2 N*m: w1 = 2 + t^2/2 - 2t, and clutches 2 and 3 (holding 4/3 and 2/3 N*m,
    # below their limits) keep w2 = w3 = w4 = 2 + 2/3 (t - 4).
    result = run(ENGINE / "coupled_clutches.bg")
    assert result.complete, result.message
    t, out = result.t, result.outputs
    before, after = t < 4.0 - 1e-6, t > 4.0 + 1e-6
    for name in ("omega1", "omega2", "omega3", "omega4"):
        np.testing.assert_allclose(out[name][before], t[before] ** 2 / 8, rtol=1e-7, atol=1e-9)
    for i, name in enumerate(("T1", "T2", "T3"), start=1):
        np.testing.assert_allclose(out[name][before], (4 - i) / 4 * t[before], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(out["omega1"][after], 2 + t[after] ** 2 / 2 - 2 * t[after], rtol=1e-7)
    for name in ("omega2", "omega3", "omega4"):
        np.testing.assert_allclose(out[name][after], 2 + 2 / 3 * (t[after] - 4), rtol=1e-7)
    np.testing.assert_allclose(out["T1"][after], 2.0, rtol=1e-12)
    np.testing.assert_allclose(out["T2"][after], 4 / 3, rtol=1e-7)
    np.testing.assert_allclose(out["T3"][after], 2 / 3, rtol=1e-7)
    ends = [time for time, label in result.events if label.endswith("ends")]
    assert ends and ends[0] == pytest.approx(4.0, abs=1e-7)


def test_breakaway_happens_at_the_static_limit_then_slides_at_the_sliding_force():
    # F = 4t against coulomb(v, 8 N, 12 N): held (friction = F) until F = 12 N at t = 3 s; then
    # M v' = 4t - 8, v = (2 (t^2 - 9) - 8 (t - 3)) / 2.
    result = run(ENGINE / "breakaway.bg")
    assert result.complete, result.message
    t, v, friction = result.t, result.outputs["v"], result.outputs["Ff"]
    stuck, sliding = t < 3.0, t > 3.0 + 1e-9
    np.testing.assert_allclose(v[stuck], 0.0, atol=1e-12)
    np.testing.assert_allclose(friction[stuck], 4 * t[stuck], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(v[sliding], (2 * (t[sliding] ** 2 - 9) - 8 * (t[sliding] - 3)) / 2, rtol=1e-7,
                               atol=1e-9)
    np.testing.assert_allclose(friction[sliding], 8.0, rtol=1e-12)
    ends = [time for time, label in result.events if label.endswith("ends")]
    assert ends == [pytest.approx(3.0, abs=1e-8)]


def test_negative_friction_limits_act_as_zero_a_free_clutch():
    ss, experiment = _derive("breakaway", sets=["Fs=-1", "Fst=-1"])
    free = simulate(ss, experiment)
    assert free.complete, free.message
    np.testing.assert_allclose(free.outputs["v"], free.t**2, rtol=1e-6, atol=1e-9)     # 2 v' = 4t
    np.testing.assert_allclose(free.outputs["Ff"], 0.0, atol=1e-12)


def test_coulomb_static_limit_defaults_to_the_sliding_force(tmp_path):
    # coulomb(f, Fs) with Fs = 8 N: the 4 N/s ramp breaks it away at t = 2 s, not 3 s
    text = (ENGINE / "breakaway.bg").read_text().replace("coulomb(f, Fs, Fst)", "coulomb(f, Fs)")
    model = tmp_path / "breakaway_default.bg"
    model.write_text(text)
    result = run(model)
    assert result.complete, result.message
    t, v = result.t, result.outputs["v"]
    np.testing.assert_allclose(v[t < 2.0], 0.0, atol=1e-12)
    late = t > 2.0
    np.testing.assert_allclose(v[late], (2 * (t[late] ** 2 - 4) - 8 * (t[late] - 2)) / 2, rtol=1e-7, atol=1e-9)


def test_two_masses_stick_at_once_and_the_first_friction_holds_the_push():
    result = run(ENGINE / "two_stuck_masses.bg")
    assert result.complete, result.message
    np.testing.assert_allclose(result.outputs["x"], 0.0, atol=1e-12)
    np.testing.assert_allclose(result.outputs["F1"], 3.0, rtol=1e-9)
    np.testing.assert_allclose(result.outputs["F2"], 0.0, atol=1e-9)
