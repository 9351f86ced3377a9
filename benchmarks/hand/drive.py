"""Hand-written scipy reference for the lightly damped drive of models/dc_motor_gear_compliant.bg,
run with ``solver = "Radau"`` at rtol 1e-10 (a user's choice of scipy's Radau, which ran for over
300 s in bondc before scipy's solvers stepped the model's compiled functions).

The same four linear ODEs bondc derives, for ``scipy.integrate.solve_ivp`` with the analytic
Jacobian (constant), the model's max_step (0.5 ms) and the run split at the supply's step (t_on). States, in bondc's order
(``armature_L.p, rotor.p, shaft.q, load.p``)::

    dl/dt    = u(t) - R_a*i - Kt*w_m            i = l/L_a
    dp_m/dt  = Kt*i - b_m*w_m - T/n_gear       w_m = p_m/J_m, T = k_s*phi
    dphi/dt  = w_m/n_gear - w_L                w_L = p_L/J_L
    dp_L/dt  = T - b_L*w_L - tau_L

``python -m benchmarks.hand.drive`` prints the final state against the steady state's closed form.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

U_S, T_ON = 24.0, 10e-3
R_A, L_A, KT = 1.2, 2.5e-3, 0.05
J_M, B_M, N_GEAR = 2.0e-5, 1.0e-5, 10.0
K_S, J_L, B_L, TAU_L = 50.0, 5.0e-3, 1.0e-3, 0.2

A = np.array([[-R_A / L_A, -KT / J_M, 0.0, 0.0],
              [KT / L_A, -B_M / J_M, -K_S / N_GEAR, 0.0],
              [0.0, 1 / (N_GEAR * J_M), 0.0, -1 / J_L],
              [0.0, 0.0, K_S, -B_L / J_L]])


def _rates(u):
    force = np.array([u, 0.0, 0.0, -TAU_L])

    def rates(t, y):
        return A @ y + force
    return rates


def _jacobian(t, y):
    return A


def simulate(t_end=2.0, rtol=1e-10, atol=1e-12, max_step=0.5e-3, method="Radau", t_eval=None, dense=False):
    """The run in two pieces, before and after the supply's step: (times, states (4, N)), or with
    ``dense`` a function of time giving the states."""
    pieces, y0 = [], np.zeros(4)
    for (a, b), u in (((0.0, T_ON), 0.0), ((T_ON, t_end), U_S)):
        inside = None if t_eval is None else t_eval[(t_eval >= a) & (t_eval <= b) if b == t_end else
                                                    (t_eval >= a) & (t_eval < b)]
        piece = solve_ivp(_rates(u), (a, b), y0, method=method, jac=_jacobian, rtol=rtol, atol=atol,
                          max_step=max_step or np.inf, t_eval=inside, dense_output=dense)
        pieces.append(piece)
        y0 = piece.y[:, -1]
    if dense:
        def at(t):
            t = np.asarray(t, dtype=float)
            return np.where(t < T_ON, pieces[0].sol(np.minimum(t, T_ON)), pieces[1].sol(np.maximum(t, T_ON)))
        return at
    return np.concatenate([p.t for p in pieces]), np.hstack([p.y for p in pieces]), pieces


def steady_state():
    """The state at rest with the supply on: A y + force = 0."""
    return np.linalg.solve(A, -np.array([U_S, 0.0, 0.0, -TAU_L]))


if __name__ == "__main__":
    t, y, pieces = simulate()
    print(f"{sum(p.t.size for p in pieces)} steps; final {y[:, -1]} (at rest: {steady_state()})")
