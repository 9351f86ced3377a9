"""Hand-written scipy reference for the flagship, models/electro_pneumatic_hybrid.bg.

The same six-state ODE that bondc derives from the flagship's bond graph,
written the way a careful scipy user would write it for
``scipy.integrate.solve_ivp``: a scalar right-hand side in plain Python floats
(six states: numpy per-element arithmetic would only add overhead), an analytic
6 x 6 Jacobian, every constant precomputed, the run split at the kinks of the
motor-speed profile, and the one real discontinuity -- the jump of the
friction law at abs(v) = v_th -- handled with solve_ivp events, including the
Filippov sliding mode that the jump creates. It is the ``hand`` reference of
the flagship benchmark (experiment ``cycle``: t_end 4.2 s, rtol 1e-7,
atol 1e-9, max_step 1 ms).

States, in bondc's order (the CSV columns ``coupling.q, shaft.p, nut.q,
mass.p, chamber.P, x_piston``)::

    theta  coupling twist [rad]          C coupling, q
    p_s    shaft angular momentum        I shaft, p          w_s = p_s/Iz
    delta  nut deflection [m]            C nut, q            (screw travel - mass travel)
    p_m    mass momentum                 I mass, p           v = p_m/M
    P      chamber pressure [Pa]         C chamber, own state P
    x      piston travel [m]             model-level state x_piston

Junction by junction (bond graph in the .bg header; TF laws are
``p1.e = r*p2.e, p2.f = r*p1.f``)::

    j_motor  (0, effort tau = K*theta):  omega = d(theta)/dt + w_s
    j_shaft  (1, flow w_s):              dp_s/dt = tau - tau_screw
    screw    (TF, r = lead/(2 pi)):      tau_screw = r*F_n,  v_s = r*w_s
    j_nut    (0, effort F_n):            v_s = d(delta)/dt + v
    j_gap    (1):                        F_n = F_k(delta) + c_nut*(v_s - v)
    j_mass   (1, flow v):                dp_m/dt = F_n + Ar*P - F_f(v) - M*g - P_atm*Ar
    piston   (TF, r = 1/Ar):             force Ar*P on the mass, volume flow Ar*v
    j_chamber(0, effort P):              Q = Q_chamber + Ar*v
    chamber  (C, own state):             dP/dt = kappa*P/(V0 + Ar*x) * (Q - Ar*v)
    x_piston:                            dx/dt = v

with the element laws

* ``omega(t)``: the trapezoidal speed table through (0, t1, ..., t9), linear
  between the corners; piecewise linear, so each piece of the run between
  two corners uses ``omega = w_a + slope*(t - t_a)`` (no table look-up);
* nut spring with backlash (C nut): ``F_k = 0`` if ``abs(delta) <= gap``,
  else ``k_nut*(delta - sign(delta)*gap)``; nut damper (R): ``c_nut*(v_s - v)``;
* friction (R friction): ``c0*v`` if ``abs(v) < v_th``, else
  ``a_up*abs(v)^(1 + n_up)`` for v > 0 and ``-a_dn*abs(v)^(1 + n_dn)`` for
  v < 0; it *jumps* at abs(v) = v_th (1.6 -> 204 N going up, -1.6 -> -91 N
  going down);
* valve (R valve): volume flow at chamber conditions
  ``Q = valve_mdot(P1, P)*R_air*T0/P`` with the .bg's ``fn`` orifice law:
  ``mdot = Ae*pu*psi(pd/pu)/sqrt(R_air*T0)`` from the higher pressure pu to
  the lower pd (negative when the chamber relieves), ``psi`` choked for
  ``rho <= b_cr``, a straight line for ``1 - rho < 1e-4`` (finite slope at
  zero pressure difference), else the subsonic
  ``sqrt(2 kappa/(kappa - 1)*(rho^(2/kappa) - rho^((kappa + 1)/kappa)))``;
  so ``Q = C1*P1*psi(P/P1)/P`` for P1 >= P, ``-C1*psi(P1/P)`` otherwise, with
  ``C1 = Ae*sqrt(R_air*T0)``;
* gravity ``M*g`` and atmosphere ``P_atm*Ar`` (Se, taken by j_mass);
* the motor torque output is ``torque = coupling.e = K*theta``.

Initial state: the static equilibrium of the .bg header: theta0 = r*F_n0/K,
delta0 = -gap + F_n0/k_nut, P = P0, everything else 0, with
F_n0 = M*g - (P0 - P_atm)*Ar.

Switches. The backlash and valve laws are continuous (kinks only: the valve
branches join with equal values, and even equal slopes across P = P1 inside
the linear band), so they are evaluated directly: the error control absorbs a
kink with a rejected step or two. The friction jump is not: the friction
branch is *frozen* within a segment (modes LO, UP, DN) and terminal events on
``v = +-v_th`` end the segment. At such a crossing, the accelerations on both
sides decide what follows: if the mass would accelerate away on the new
branch, the new branch is taken; if each side pushes back across the surface
(the net force on the mass lies between the two friction values, e.g.
between 1.6 N and 204 N at v = +v_th), the motion *slides* along it
(Filippov): the mass velocity stays at exactly +-v_th (``dp_m/dt = 0``, the
friction takes up the net force) until that net force leaves the interval,
which is located by two more events (modes SLIDE_UP, SLIDE_DN). This is the
same solution bondc computes with its Filippov sliding segments; without it
the frozen-mode events would switch back and forth without end at
t = 0.2065 s, and with the friction law evaluated directly (no modes, no
events) LSODA does not get past 0.2065 s in two minutes and BDF stops there
("required step size is less than spacing between numbers").

The run is split at the corners t1..t9 of the speed table (kinks in the
input) like bondc splits at known times; t9 = 4.199999999999999 coincides
with t_end = 4.2 to rounding and is not a split.

``python -m benchmarks.hand.flagship [METHOD ...]`` runs bondc's CLI on the
model (files in /tmp), compares states and torque, and times both.

Checked against bondc (CVODE, the experiment's settings): every state and the
torque agree to within 3.0e-5 of their range over the cycle at rtol 1e-7 /
atol 1e-9 (the worst: the coupling twist, i.e. the torque, at the end of the
ramps), 7e-7 at 1e-9 / 1e-11 and 1e-7 at 1e-10 / 1e-12 -- the difference is
integration error, not a difference in the equations; the friction mode
changes fall on bondc's sliding events to the microsecond. Torque peaks
+0.40124 / -0.34055 N*m, RMS 0.17497 N*m (bondc: +0.40125 / -0.34045, 0.17497;
the negative peak is the tip of a 1 ms spike at t = 2.4956 s, just after the
nut backlash closes, and each run samples it at its own steps: the hand
solution read at bondc's times gives -0.34046).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "models" / "electro_pneumatic_hybrid.bg"

# ---------------------------------------------------------------- parameters (SI), as in the .bg
M = 31.7                    # kg
g = 9.81                    # m/s^2
lead = 5.0e-3               # m per revolution
Iz = 4.06e-5                # kg*m^2
K = 120.9                   # N*m/rad
k_nut = 1.1e8               # N/m
gap = 0.1e-3                # m
c_nut = 1.0e5               # N*s/m
Ar = 2.63e-3                # m^2
V0 = 2.63e-4                # m^3
P0 = 0.224e6                # Pa
P1 = P0                     # Pa, regulator set pressure
P_atm = 101325.0            # Pa
Ae = 1.2e-5                 # m^2
kappa = 1.4
R_air = 287.3               # J/kg/K
T0 = 293.0                  # K
b_cr = (2 / (kappa + 1)) ** (kappa / (kappa - 1))
c0 = 160.0                  # N*s/m
v_th = 0.01                 # m/s
a_up, n_up = 706.59, -0.73
a_dn, n_dn = 435.61, -0.66
w_max = 1000 * 2 * math.pi / 60     # rad/s (1000 rpm)
stroke = 0.1                # m
t_rest0, t_ramp, t_dwell, t_rest_end = 0.2, 0.05, 1.0, 0.5

r_screw = lead / (2 * math.pi)
v_max = w_max * r_screw
t_cruise = stroke / v_max - t_ramp
t1 = t_rest0
t2 = t1 + t_ramp
t3 = t2 + t_cruise
t4 = t3 + t_ramp
t5 = t4 + t_dwell
t6 = t5 + t_ramp
t7 = t6 + t_cruise
t8 = t7 + t_ramp
t9 = t8 + t_rest_end

F_n0 = M * g - (P0 - P_atm) * Ar
delta0 = -gap + F_n0 / k_nut
theta0 = r_screw * F_n0 / K
Y0 = np.array([theta0, 0.0, delta0, 0.0, P0, 0.0])
STATES = ("coupling.q", "shaft.p", "nut.q", "mass.p", "chamber.P", "x_piston")

#: the speed table omega(t)
TABLE_T = (0.0, t1, t2, t3, t4, t5, t6, t7, t8, t9)
TABLE_W = (0.0, 0.0, w_max, w_max, 0.0, 0.0, -w_max, -w_max, 0.0, 0.0)

#: the experiment "cycle"
T_END, RTOL, ATOL, MAX_STEP = 4.2, 1e-7, 1e-9, 1e-3

# ---------------------------------------------------------------- derived constants of the laws
_C1 = Ae * math.sqrt(R_air * T0)                   # Q = C1*pu*psi/P (mdot*R_air*T0 = Ae*pu*psi*sqrt(R_air*T0))
_E1, _E2 = 2 / kappa, (kappa + 1) / kappa          # subsonic exponents
_SUB = 2 * kappa / (kappa - 1)
_PSI_CHOKED = math.sqrt(kappa * (2 / (kappa + 1)) ** ((kappa + 1) / (kappa - 1)))
_RHO_LIN = 1 - 1e-4
_PSI_SLOPE = math.sqrt(_SUB * (_RHO_LIN ** _E1 - _RHO_LIN ** _E2)) / 1e-4   # psi = slope*(1 - rho) in the band
_EUP, _EDN = 1 + n_up, 1 + n_dn                     # friction exponents of abs(v)
_F_LO = c0 * v_th                                   # friction on the low branch at abs(v) = v_th (1.6 N)
_F_UP = a_up * v_th ** _EUP                         # upward power-law friction at v = +v_th (204 N)
_F_DN = a_dn * v_th ** _EDN                         # downward, magnitude at v = -v_th (91 N)
_W_OUT = M * g + P_atm * Ar                         # gravity + atmosphere, taken by j_mass
_INV_IZ, _INV_M = 1 / Iz, 1 / M
_RC = r_screw * c_nut

# friction modes
LO, UP, DN, SLIDE_UP, SLIDE_DN = 0, 1, 2, 3, 4
MODE_NAMES = ("LO", "UP", "DN", "SLIDE_UP", "SLIDE_DN")


def omega(t):
    """The servomotor speed table (vectorised), rad/s."""
    return np.interp(t, TABLE_T, TABLE_W)


def _psi(rho: float) -> tuple[float, float]:
    """(psi, dpsi/drho): the orifice flow function of the model's fn psi (choked, linear near 1, subsonic)."""
    if rho <= b_cr:
        return _PSI_CHOKED, 0.0
    if 1 - rho < 1e-4:
        return _PSI_SLOPE * (1 - rho), -_PSI_SLOPE
    a, b = rho ** _E1, rho ** _E2
    psi = math.sqrt(_SUB * (a - b))
    return psi, _SUB * (_E1 * a - _E2 * b) / (2 * psi * rho)


def valve_flow(P: float) -> tuple[float, float]:
    """(Q, dQ/dP): the valve's volume flow into the chamber at chamber conditions, m^3/s, and its slope."""
    if P1 >= P:                      # from the supply into the chamber: pu = P1, pd = P
        psi, dpsi = _psi(P / P1)
        Q = _C1 * P1 * psi / P
        return Q, _C1 * (dpsi / P - P1 * psi / (P * P))
    psi, dpsi = _psi(P1 / P)         # relief: pu = P, pd = P1, Q = -C1*P*psi/P
    return -_C1 * psi, _C1 * dpsi * P1 / (P * P)


def net_force(y) -> float:
    """Every force on the mass except friction (j_mass): F_n + Ar*P - M*g - P_atm*Ar (y: an ndarray)."""
    theta, ps, delta, pm, P, x = y.tolist()
    Fk = k_nut * (delta - gap) if delta > gap else (k_nut * (delta + gap) if delta < -gap else 0.0)
    return Fk + c_nut * (r_screw * ps * _INV_IZ - pm * _INV_M) + Ar * P - _W_OUT


# ---------------------------------------------------------------- right-hand side and Jacobian

def make_rhs(w_a: float, t_a: float, slope: float, mode: int) -> tuple[Callable, Callable]:
    """(rhs, jac) for one segment: omega = w_a + slope*(t - t_a), friction branch ``mode`` frozen.

    In SLIDE_UP/SLIDE_DN the mass velocity is held at +-v_th: dp_m/dt = 0
    (the friction equals the net force, between its two one-sided values).
    """
    sliding = mode in (SLIDE_UP, SLIDE_DN)
    if mode == LO:
        fa, fe = c0, 1.0
    elif mode == UP:
        fa, fe = a_up, _EUP
    else:
        fa, fe = a_dn, _EDN

    def rhs(t, y):
        theta, ps, delta, pm, P, x = y.tolist()
        w_s = ps * _INV_IZ
        v = pm * _INV_M
        rel = r_screw * w_s - v                          # d(delta)/dt = v_s - v
        if delta > gap:
            Fn = k_nut * (delta - gap) + c_nut * rel
        elif delta < -gap:
            Fn = k_nut * (delta + gap) + c_nut * rel
        else:
            Fn = c_nut * rel
        if sliding:
            dpm = 0.0
        else:
            if mode == LO:
                Ff = c0 * v
            elif v >= 0:
                Ff = fa * v ** fe
            else:
                Ff = -fa * (-v) ** fe
            dpm = Fn + Ar * P - Ff - _W_OUT
        # valve volume flow (inline valve_flow, value only)
        if P1 >= P:
            rho = P / P1
            if rho <= b_cr:
                psi = _PSI_CHOKED
            elif 1 - rho < 1e-4:
                psi = _PSI_SLOPE * (1 - rho)
            else:
                psi = math.sqrt(_SUB * (rho ** _E1 - rho ** _E2))
            Q = _C1 * P1 * psi / P
        else:
            rho = P1 / P
            if rho <= b_cr:
                psi = _PSI_CHOKED
            elif 1 - rho < 1e-4:
                psi = _PSI_SLOPE * (1 - rho)
            else:
                psi = math.sqrt(_SUB * (rho ** _E1 - rho ** _E2))
            Q = -_C1 * psi
        return np.array((w_a + slope * (t - t_a) - w_s,          # d(theta)/dt = omega - w_s
                         K * theta - r_screw * Fn,                 # dp_s/dt = tau - r*F_n
                         rel,                                      # d(delta)/dt
                         dpm,                                      # dp_m/dt
                         kappa * P / (V0 + Ar * x) * (Q - Ar * v),  # dP/dt
                         v))                                       # dx/dt

    def jac(t, y):
        theta, ps, delta, pm, P, x = y.tolist()
        v = pm * _INV_M
        kk = k_nut if (delta > gap or delta < -gap) else 0.0
        Q, dQ = valve_flow(P)
        V = V0 + Ar * x
        net = Q - Ar * v
        J = np.zeros((6, 6))
        J[0, 1] = -_INV_IZ
        J[1, 0] = K
        J[1, 1] = -r_screw * _RC * _INV_IZ
        J[1, 2] = -r_screw * kk
        J[1, 3] = _RC * _INV_M
        J[2, 1] = r_screw * _INV_IZ
        J[2, 3] = -_INV_M
        if not sliding:
            if mode == LO:
                dFf = c0
            else:
                dFf = fa * fe * abs(v) ** (fe - 1)
            J[3, 1] = _RC * _INV_IZ
            J[3, 2] = kk
            J[3, 3] = -(c_nut + dFf) * _INV_M
            J[3, 4] = Ar
        J[4, 3] = -kappa * P / V * Ar * _INV_M
        J[4, 4] = kappa / V * net + kappa * P / V * dQ
        J[4, 5] = -kappa * P * net * Ar / (V * V)
        J[5, 3] = _INV_M
        return J

    return rhs, jac


def make_events(mode: int) -> list:
    """The terminal events that end a segment in friction ``mode``, each with ``.target``: the next mode.

    LO/UP/DN: the velocity reaches +-v_th (the friction law's jump). SLIDE_*:
    the net force leaves the interval between the two one-sided friction
    values (break-away to the power-law branch, or back to the low branch).
    The target of a velocity crossing is provisional: :func:`_arrive` checks
    the accelerations on both sides and may choose sliding instead.
    """
    def v_up(t, y):
        return y[3] * _INV_M - v_th

    def v_dn(t, y):
        return y[3] * _INV_M + v_th

    def slide_up_hi(t, y):
        return net_force(y) - _F_UP

    def slide_up_lo(t, y):
        return net_force(y) - _F_LO

    def slide_dn_hi(t, y):
        return net_force(y) + _F_DN

    def slide_dn_lo(t, y):
        return net_force(y) + _F_LO

    table = {
        LO: [(v_up, +1, UP), (v_dn, -1, DN)],
        UP: [(v_up, -1, LO)],
        DN: [(v_dn, +1, LO)],
        SLIDE_UP: [(slide_up_hi, +1, UP), (slide_up_lo, -1, LO)],
        SLIDE_DN: [(slide_dn_hi, -1, DN), (slide_dn_lo, +1, LO)],
    }[mode]
    events = []
    for function, direction, target in table:
        function.terminal, function.direction, function.target = True, direction, target
        events.append(function)
    return events


def _arrive(y: np.ndarray, old: int, target: int) -> tuple[int, np.ndarray]:
    """The mode after an event from ``old`` towards ``target``, and the state to restart from.

    At a velocity crossing the net force N decides: at v = +v_th the low
    branch accelerates the mass by N - 1.6 N and the power-law branch by
    N - 204 N. Both positive: UP; both negative: LO; opposite signs (each
    side pushes back across the surface): sliding, with p_m set to exactly
    M*v_th (the event located it to rounding). Mirrored at v = -v_th.
    """
    if old in (SLIDE_UP, SLIDE_DN):
        return target, y
    N = net_force(y)
    if (old, target) in ((LO, UP), (UP, LO)):           # the surface v = +v_th
        if N - _F_UP >= 0:
            return UP, y
        if N - _F_LO <= 0:
            return LO, y
        mode, v = SLIDE_UP, v_th
    else:                                                # the surface v = -v_th
        if N + _F_DN <= 0:
            return DN, y
        if N + _F_LO >= 0:
            return LO, y
        mode, v = SLIDE_DN, -v_th
    y = y.copy()
    y[3] = M * v
    return mode, y


def _initial_mode(y) -> int:
    v = y[3] * _INV_M
    return LO if abs(v) < v_th else (UP if v > 0 else DN)


# ---------------------------------------------------------------- simulate

class Result(NamedTuple):
    """A hand simulation: times, states (6 x len(t), bondc's order), solver counts and the segments."""

    t: np.ndarray
    y: np.ndarray
    nfev: int
    njev: int
    nlu: int
    events: list                 # (time, "OLD -> NEW") of every friction mode change
    segments: int
    sol: Callable | None         # y(t) from the dense outputs (``dense=True``), else None


def _pieces(t_end: float) -> list[tuple[float, float, float, float]]:
    """(t_a, t_b, omega(t_a), slope) of the pieces between the speed table's corners inside (0, t_end)."""
    corners = [tc for tc in TABLE_T if 0.0 < tc < t_end - 1e-12 * max(1.0, t_end)]
    bounds = [0.0] + corners + [t_end]
    pieces = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        k = int(np.searchsorted(TABLE_T, a, side="right")) - 1       # the table interval that holds [a, b]
        if k + 1 < len(TABLE_T):
            slope = (TABLE_W[k + 1] - TABLE_W[k]) / (TABLE_T[k + 1] - TABLE_T[k])
        else:
            slope = 0.0
        pieces.append((a, b, float(omega(a)), slope))
    return pieces


def _joined(parts) -> Callable:
    """y(t) over the whole run from the segments' dense outputs ``(t_start, t_end, sol)``."""
    starts = np.array([part[0] for part in parts])

    def sol(tt):
        tt = np.atleast_1d(np.asarray(tt, dtype=float))
        out = np.empty((6, tt.size))
        index = np.clip(np.searchsorted(starts, tt, side="right") - 1, 0, len(parts) - 1)
        for j in np.unique(index):
            chosen = index == j
            out[:, chosen] = parts[j][2](tt[chosen])
        return out

    return sol


def simulate(rtol: float = RTOL, atol: float = ATOL, max_step: float = MAX_STEP, method: str = "LSODA",
             t_end: float = T_END, dense: bool = False, max_events: int = 1000) -> Result:
    """Integrate the cycle; returns ``Result(t, y, nfev, njev, nlu, events, segments, sol)``.

    One solve_ivp call per segment: the run is split at the speed table's
    corners and at every friction mode change (terminal events). Every solver
    step is reported (as bondc does); a segment's first point is dropped when
    it repeats the previous segment's last. ``dense=True`` also returns
    ``sol(t)``, the states at any times from the segments' dense outputs.
    ``max_events`` guards against friction modes switching without end
    (which does not happen with this model: 8 mode changes per cycle).
    LSODA (the default) is by far the fastest scipy method here; BDF and
    Radau work too (about 10 times slower, scipy's pure-Python steppers).
    """
    y = Y0.copy()
    mode = _initial_mode(y)
    ts, ys = [np.array([0.0])], [Y0[:, None].copy()]
    nfev = njev = nlu = segments = 0
    events, dense_parts = [], []
    for a, b, w_a, slope in _pieces(t_end):
        t = a
        while t < b:
            rhs, jac = make_rhs(w_a, a, slope, mode)
            event_functions = make_events(mode)
            options = dict(rtol=rtol, atol=atol, max_step=max_step, dense_output=dense, events=event_functions)
            if method != "RK45" and method != "RK23" and method != "DOP853":
                options["jac"] = jac
            sol = solve_ivp(rhs, (t, b), y, method=method, **options)
            segments += 1
            if sol.status < 0:
                raise RuntimeError(f"solve_ivp failed at t={sol.t[-1]:.9g} in mode {MODE_NAMES[mode]}: "
                                   f"{sol.message}")
            nfev, njev, nlu = nfev + sol.nfev, njev + sol.njev, nlu + sol.nlu
            ts.append(sol.t[1:])
            ys.append(sol.y[:, 1:])
            if dense:
                dense_parts.append((t, sol.t[-1], sol.sol))
            if sol.status == 1:          # a friction event (the solution ends there): restart in the next mode
                k = next(k for k, te in enumerate(sol.t_events) if te.size)
                t = float(sol.t_events[k][0])
                new, y = _arrive(sol.y_events[k][0], mode, event_functions[k].target)
                events.append((t, f"{MODE_NAMES[mode]} -> {MODE_NAMES[new]}"))
                if len(events) > max_events:
                    raise RuntimeError(f"more than {max_events} friction mode changes by t={t:.9g}")
                mode = new
            else:
                t, y = b, sol.y[:, -1].copy()
    sol_fn = _joined(dense_parts) if dense else None
    return Result(np.concatenate(ts), np.concatenate(ys, axis=1), nfev, njev, nlu, events, segments, sol_fn)


def torque(y) -> np.ndarray:
    """The model's output ``torque = coupling.e = K*theta`` [N*m] at states ``y`` (6 x k or 6)."""
    return K * np.asarray(y)[0]


def outputs(t, y) -> dict[str, np.ndarray]:
    """The model's outputs at (t, y): torque, power, x, v, P, F_nut (as the .bg defines them)."""
    t = np.asarray(t, dtype=float)
    theta, ps, delta, pm, P, x = np.asarray(y, dtype=float)
    Fk = np.where(np.abs(delta) <= gap, 0.0, k_nut * (delta - np.sign(delta) * gap))
    F_nut = Fk + c_nut * (r_screw * ps / Iz - pm / M)
    tau = K * theta
    return {"torque": tau, "power": tau * omega(t), "x": x, "v": pm / M, "P": P, "F_nut": F_nut}


def time_average_rms(t, values) -> float:
    """RMS over time (trapezoid rule over the points), as bondc's statistics compute it."""
    t, values = np.asarray(t), np.asarray(values)
    return math.sqrt(np.sum(0.5 * (values[1:] ** 2 + values[:-1] ** 2) * np.diff(t)) / (t[-1] - t[0]))


# ---------------------------------------------------------------- comparison against bondc

def run_bondc(out: Path = Path("/tmp/hand_flagship_bondc.csv")):
    """``bondc simulate`` of the flagship's first experiment (cycle) through the CLI; (t, columns, stats)."""
    bondc = ROOT / ".venv" / "bin" / "bondc"
    done = subprocess.run([str(bondc), "simulate", str(MODEL), "-o", str(out), "--json"],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"bondc simulate failed:\n{done.stdout}\n{done.stderr}")
    summary = json.loads(done.stdout)
    header = out.read_text().split("\n", 1)[0].split(",")
    data = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    return data[:, 0], {name: data[:, i] for i, name in enumerate(header)}, summary


def compare(methods=("LSODA", "BDF", "Radau")) -> None:
    """Run bondc's CLI and the hand code with each method; print differences, torque figures and timings."""
    t_ref, columns, summary = run_bondc()
    stats = summary["stats"]
    print(f"bondc: {summary['experiment']}, {summary['message']}; solver {summary['settings']['method']}, "
          f"rtol {summary['settings']['rtol']:g}, atol {summary['settings']['atol']:g}, "
          f"max_step {summary['settings']['max_step']:g}")
    print(f"bondc: integration {stats['wall_time'] * 1e3:.0f} ms, nfev {stats['nfev']}, njev {stats['njev']}, "
          f"steps {stats['steps']}, segments {stats['segments']}")
    ref_torque = columns["torque"]
    print(f"bondc: torque peak {ref_torque.max():+.4f} / {ref_torque.min():+.4f} N*m, "
          f"RMS {time_average_rms(t_ref, ref_torque):.4f} N*m")
    for method in methods:
        hand = simulate(method=method, dense=True)
        y_at = hand.sol(t_ref)
        print(f"\nhand {method}: {hand.t.size - 1} steps, {hand.segments} segments, nfev {hand.nfev}, "
              f"njev {hand.njev}, nlu {hand.nlu}; friction mode changes:")
        print("   " + ", ".join(f"{te:.6f} {what}" for te, what in hand.events))
        print(f"  {'quantity':<12} {'max |diff|':>12} {'range':>12} {'max|diff|/range':>16} {'at t':>10}")
        rows = [(name, y_at[i], columns[name]) for i, name in enumerate(STATES)]
        rows.append(("torque", torque(y_at), ref_torque))
        rows.append(("F_nut", outputs(t_ref, y_at)["F_nut"], columns["F_nut"]))
        for name, mine, ref in rows:
            diff = np.abs(mine - ref)
            span = ref.max() - ref.min()
            worst = int(np.argmax(diff))
            print(f"  {name:<12} {diff[worst]:12.4e} {span:12.4e} {diff[worst] / span:16.3e} {t_ref[worst]:10.6f}")
        tq, tq_at = torque(hand.y), torque(y_at)
        print(f"  torque at the hand's own steps: peak {tq.max():+.5f} / {tq.min():+.5f} N*m, "
              f"RMS {time_average_rms(hand.t, tq):.5f} N*m;  at bondc's times: peak {tq_at.max():+.5f} / "
              f"{tq_at.min():+.5f}, RMS {time_average_rms(t_ref, tq_at):.5f}  (bondc {ref_torque.max():+.5f} / "
              f"{ref_torque.min():+.5f}, RMS {time_average_rms(t_ref, ref_torque):.5f})")
        best = np.inf
        for _ in range(3):
            start = time.perf_counter()
            result = simulate(method=method)
            best = min(best, time.perf_counter() - start)
        print(f"  hand {method} timing (best of 3, no dense output): {best * 1e3:.0f} ms, nfev {result.nfev}, "
              f"njev {result.njev}, nlu {result.nlu}")


def main(argv=None) -> int:
    methods = tuple(argv if argv is not None else sys.argv[1:]) or ("LSODA", "BDF", "Radau")
    compare(methods)
    return 0


if __name__ == "__main__":
    sys.exit(main())
