"""Kinks and jumps (LANGUAGE.md section 7): a switch across which the law stays continuous is
evaluated as written, never frozen nor located; the rest are jumps.

The pump/relief circuit of tests/fixtures/engine/pump_relief.bg is the case that chattered: a
relief valve that sits at its opening and a turbulent orifice that sits at zero flow once the
piston rests. Its references: the closed form of the rest state, a hand-written scipy solution of
the same four ODEs (laws as written, no events), and the conservation of energy.
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy
from scipy.integrate import solve_ivp

from bondc.codegen.freeze import Freezer, continuous_across
from bondc.pipeline import derive_file
from bondc.simulate import simulate

ENGINE = Path(__file__).parent / "fixtures" / "engine"
CIRCUIT = ENGINE / "pump_relief.bg"

# the fixture's parameters, SI
Q, P_CR, K = 6e-3 / 60, 100e5, 1e-10
K_O = 0.61 * 1e-5 * math.sqrt(2 / 870)
BETA, V1, V2, A_P, M, K_S, B = 1.4e9, 1e-4, 2e-4, 2e-3, 20.0, 1e6, 2000.0


def _hand_rates(t, y):
    """The circuit written by hand: hose and chamber volumes, the mass's momentum, the spring."""
    q1, q2, p, x = y
    p1, p2 = BETA * q1 / V1, BETA * q2 / V2
    orifice = K_O * math.copysign(math.sqrt(abs(p1 - p2)), p1 - p2)
    relief = K * (p1 - P_CR) if p1 > P_CR else 0.0
    v = p / M
    return [Q - relief - orifice, orifice - A_P * v, A_P * p2 - K_S * x - B * v, v]


def _hand_jacobian(t, y):
    q1, q2, p, x = y
    p1, p2 = BETA * q1 / V1, BETA * q2 / V2
    slope = K_O / (2 * math.sqrt(abs(p1 - p2))) if p1 != p2 else 1e30
    relief = K if p1 > P_CR else 0.0
    return [[-(relief + slope) * BETA / V1, slope * BETA / V2, 0, 0],
            [slope * BETA / V1, -slope * BETA / V2, -A_P / M, 0],
            [0, A_P * BETA / V2, -B / M, -K_S],
            [0, 0, 1 / M, 0]]


def _run(path, text=None, tmp_path=None):
    if text is not None:
        path = tmp_path / "circuit.bg"
        path.write_text(text)
    derived = derive_file(path, cache=False)
    return derived, simulate(derived.state_space, derived.experiment)


@pytest.mark.parametrize("orifice", ["Cd*A_o*sqrt(2/rho)*sign(e)*sqrt(abs(e))",
                                     "Cd*A_o*sqrt(2/rho)*sign(e)*sqrt(max(abs(e), 0))"])
def test_the_pump_relief_circuit_runs_straight_through_to_its_closed_form_rest(orifice, tmp_path):
    from bondc.analysis.energy import energy_account

    text = CIRCUIT.read_text().replace("Cd*A_o*sqrt(2/rho)*sign(e)*sqrt(abs(e))", orifice)
    assert orifice in text
    derived, result = _run(None, text, tmp_path)
    assert result.complete, result.message
    # no mode changes at all (it was 27 000 with the laws frozen), and a grid of the solver's steps
    assert result.stats["mode_changes"] == 0 and not result.events
    assert result.t.size < 20_000
    # at rest: the whole pump flow through the relief valve, nothing through the orifice
    p_rest = P_CR + Q / K
    assert result.outputs["p1"][-1] == pytest.approx(p_rest, rel=1e-9)
    assert result.outputs["p2"][-1] == pytest.approx(p_rest, rel=1e-9)
    assert result.outputs["x"][-1] == pytest.approx(p_rest * A_P / K_S, rel=1e-9)
    # after the piston has come to rest the pressures stay there (they jittered by 2e-4 before)
    late = result.t > 1.2
    assert np.ptp(result.outputs["p1"][late]) < 1e-6 * p_rest
    # the hand-written solution of the same laws, straight through, while the piston moves (scipy's
    # solvers at this tolerance stall themselves once the orifice sits at its kink; the rest state
    # is the closed form above)
    reference = solve_ivp(_hand_rates, (0, 0.8), [0, 0, 0, 0], method="LSODA", jac=_hand_jacobian,
                          rtol=1e-9, atol=[1e-15, 1e-15, 1e-12, 1e-12], dense_output=True)
    assert reference.success
    moving = result.t <= 0.8
    expected = reference.sol(result.t[moving])
    np.testing.assert_allclose(result.outputs["p1"][moving], BETA * expected[0] / V1, rtol=0, atol=5e-5 * p_rest)
    np.testing.assert_allclose(result.outputs["p2"][moving], BETA * expected[1] / V2, rtol=0, atol=5e-5 * p_rest)
    np.testing.assert_allclose(result.outputs["x"][moving], expected[3], rtol=0, atol=1e-5 * p_rest * A_P / K_S)
    # conservation: what the pump supplies is dissipated or stored
    account = energy_account(derived.state_space, result)
    assert account.windows[0].balance.relative_residual < 1e-6


def test_check_lists_the_circuits_switches_as_kinks_with_their_laws_lines():
    done = subprocess.run([sys.executable, "-m", "bondc", "check", str(CIRCUIT), "--json", "--no-cache"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    switches = json.loads(done.stdout)["model"]["switches"]
    lines = CIRCUIT.read_text().splitlines()
    assert [(s["switch"], s["kind"], s["variable"]) for s in switches] == [
        ("if relief.e > p_cr", "kink", "relief.f"), ("abs(orifice.e)", "kink", "orifice.f"),
        ("sign(orifice.e)", "kink", "orifice.f")]
    for switch in switches:
        assert lines[switch["line"] - 1].lstrip().startswith("R  " + switch["variable"].split(".")[0])


def test_a_jump_stays_a_jump_and_is_located(tmp_path):
    """A relief valve whose law jumps at the opening (a cracking flow of 1e-5 m^3/s) is a jump:
    located, frozen between events (here it holds the pump at p_cr as a sliding mode)."""
    text = CIRCUIT.read_text().replace("then K*(e - p_cr) else 0", "then K*(e - p_cr) + 1e-5 else 0")
    derived, result = _run(None, text, tmp_path)
    assert result.complete, result.message
    assert any("if relief.e > p_cr" in label for _, label in result.events)
    assert result.stats["mode_changes"] + result.stats.get("sliding_segments", 0) >= 1


def test_the_classification_compares_the_branches_on_the_surface():
    x, y, c, k = sympy.symbols("x y c k", real=True)
    assert continuous_across(k * (x - c) - 0, x - c)                     # relief valve
    assert continuous_across(x / 10 - x / 1e6, x)                          # diode: both 0 at 0
    assert not continuous_across(k * (x - c) + 1 - 0, x - c)               # cracking flow: a jump
    assert continuous_across(sympy.sqrt(sympy.Abs(x - y)), x - y)          # sign(x - y)*sqrt(|x - y|)
    assert not continuous_across(sympy.Abs(x) + c, x)                      # sign(x)*(|x| + c)
    assert not continuous_across(1 / x, x)                                 # 0/0 is not shown to be 0
    assert not continuous_across(x * y, x ** 2 - c)                        # no variable to solve for
    freezer = Freezer(sympy.Symbol("t", real=True), states={x}, parameters={c, k})
    relief = freezer.freeze(sympy.Piecewise((k * (x - c), x > c), (0, True)), "relief.f")
    orifice = freezer.freeze(sympy.sign(x) * sympy.sqrt(sympy.Abs(x)), "orifice.f")
    friction = freezer.freeze(sympy.sign(x) * c, "friction.e")
    assert relief == sympy.Piecewise((k * (x - c), x > c), (0, True))     # as written
    assert orifice == sympy.sign(x) * sympy.sqrt(sympy.Abs(x))
    assert friction != sympy.sign(x) * c and [s.label for s in freezer.switches] == ["sign(x) in friction.e"]
    assert [(kink.label, kink.owner) for kink in freezer.kinks] == [("if c < x", "relief.f"), ("abs(x)", "orifice.f"),
                                                                     ("sign(x)", "orifice.f")]
