"""Hand-written scipy reference for the pump/relief circuit, tests/fixtures/engine/pump_relief.bg.

The same four ODEs that bondc derives, written for ``scipy.integrate.solve_ivp`` the way a careful
user would: a scalar right-hand side in plain floats, every constant precomputed, the laws as
written (the relief valve's ``if`` and the orifice's ``sign(dp)*sqrt(abs(dp))``, no events: both
are continuous) and an analytic Jacobian. States, in bondc's order (CSV columns ``hose.q,
chamber.q, mass.p, spring.q``)::

    q1  hose volume [m^3]           p1 = beta*q1/V1
    q2  chamber volume [m^3]        p2 = beta*q2/V2
    p   piston and mass momentum    v = p/m
    x   spring compression [m]

    dq1/dt = Q - relief(p1) - orifice(p1 - p2)
    dq2/dt = orifice(p1 - p2) - A_p*v
    dp/dt  = A_p*p2 - k*x - b*v
    dx/dt  = v

The orifice's slope ``K_o/(2*sqrt(abs(dp)))`` is infinite at dp = 0, where the circuit comes to
rest. With that tangent in the Jacobian, scipy's BDF stops ("required step size is less than
spacing between numbers"), and LSODA and Radau run for minutes, at the model's tolerances (rtol
1e-6, atol 1e-12): Newton's method steps from dp to -dp and back. This reference uses what bondc
uses, the secant through the kink, ``K_o/sqrt(abs(dp))`` (0 at dp = 0), with LSODA.

``python -m benchmarks.hand.pump_relief`` runs it and prints the rest state against the closed form.
"""

from __future__ import annotations

import math

from scipy.integrate import solve_ivp

Q = 6e-3 / 60                      # pump, 6 L/min
P_CR, K = 100e5, 1e-10             # relief valve: cracking pressure, flow gain
K_O = 0.61 * 1e-5 * math.sqrt(2 / 870)   # orifice: Cd*A*sqrt(2/rho)
BETA, V1, V2 = 1.4e9, 1e-4, 2e-4
A_P, M, K_S, B = 2e-3, 20.0, 1e6, 2000.0
C1, C2 = BETA / V1, BETA / V2


def rates(t, y):
    q1, q2, p, x = y
    p1, p2 = C1 * q1, C2 * q2
    drop = p1 - p2
    orifice = K_O * math.copysign(math.sqrt(abs(drop)), drop)
    relief = K * (p1 - P_CR) if p1 > P_CR else 0.0
    v = p / M
    return [Q - relief - orifice, orifice - A_P * v, A_P * p2 - K_S * x - B * v, v]


def jacobian(t, y):
    q1, q2, p, x = y
    p1, p2 = C1 * q1, C2 * q2
    drop = p1 - p2
    slope = K_O / math.sqrt(abs(drop)) if drop != 0 else 0.0      # the secant through the kink
    relief = K if p1 > P_CR else 0.0
    return [[-(relief + slope) * C1, slope * C2, 0.0, 0.0],
            [slope * C1, -slope * C2, -A_P / M, 0.0],
            [0.0, A_P * C2, -B / M, -K_S],
            [0.0, 0.0, 1 / M, 0.0]]


def simulate(t_end=2.0, rtol=1e-6, atol=1e-12, method="LSODA", dense=False):
    return solve_ivp(rates, (0.0, t_end), [0.0, 0.0, 0.0, 0.0], method=method, jac=jacobian, rtol=rtol, atol=atol,
                     dense_output=dense)


if __name__ == "__main__":
    solution = simulate()
    rest = P_CR + Q / K
    print(f"{solution.message} {solution.t.size} steps; p1 = {C1 * solution.y[0, -1]:.9g} Pa, "
          f"p2 = {C2 * solution.y[1, -1]:.9g} Pa, x = {solution.y[3, -1]:.9g} m "
          f"(closed form {rest:.9g} Pa, {rest * A_P / K_S:.9g} m)")
