"""Hand-written numpy/scipy reference for the N-section chain of ``benchmarks/chain.py``.

This is the same ODE that bondc derives from the chain's bond graph, written
the way a careful scipy user would write it for ``scipy.integrate.solve_ivp``:
a vectorised right-hand side, an analytic Jacobian built once (a constant
sparse CSC matrix for Radau/BDF, the banded packed form for LSODA), all
constants precomputed, and the run split at the force step like bondc splits
at every discontinuity. It is the ``hand`` reference of the chain benchmarks.

Bond graph (``benchmarks/chain.py``), for section i = 1..N::

    force -> v1                       MSe, effort F(t) = F0*step(t, t_step)
    v_i -> m_i                        I,  f = p_i/m            (1-junction v_i: velocity v_i)
    v_i -> n_i                        0-junction n_i: effort e_i
    n_i -> v_{i+1}     (i < N)        the next mass's 1-junction
    n_i -> r_i                        1-junction r_i: flow v_i - v_{i+1}
    r_i -> k_i, r_i -> b_i            C: e = k*q_i,  R: e = b*f

Junction laws, with v_i = p_i/m and v_{N+1} = 0 (mass N's spring and damper
go to the wall: n_N has no bond to a next mass):

* 0-junction n_i (one effort, flows in = flows out):
  flow(v_i -> n_i) = flow(n_i -> v_{i+1}) + flow(n_i -> r_i), so the flow on
  r_i, i.e. on k_i and b_i, is the relative velocity ``w_i = v_i - v_{i+1}``.
* 1-junction r_i (one flow, efforts add): the effort of n_i is
  ``e_i = k*q_i + b*w_i`` (spring and damper in parallel).
* 1-junction v_i: effort in = effort out. In: F (i = 1) or e_{i-1} (bond
  n_{i-1} -> v_i); out: the mass m_i and the bond v_i -> n_i (e_i).

so the state equations are::

    dp_i/dt = e_{i-1} - e_i            with e_0 = F(t)
    dq_i/dt = v_i - v_{i+1}            with v_{N+1} = 0

Sign convention (as bondc's CSV shows it): q_i > 0 is a *compression* of
spring i (mass i moving towards mass i + 1 / the wall), and with the force
pushing mass 1 the steady state has every q_i = F0/k > 0 and every p_i = 0.

State order is bondc's, interleaved: ``y = [p_1, q_1, p_2, q_2, ..., p_N, q_N]``
(bondc's CSV columns ``m1.p, k1.q, m2.p, k2.q, ...``). This also makes the
Jacobian banded (two sub- and two super-diagonals), which LSODA exploits.

In matrix form, with the difference matrix D (N x N, D[i, i] = 1,
D[i, i+1] = -1, so ``w = D v``), the system is linear::

    dp/dt = -D^T (k q + (b/m) D p) + F(t) e_1
    dq/dt = (1/m) D p

so the Jacobian is the constant matrix [[-(b/m) D^T D, -k D^T], [(1/m) D, 0]]
(permuted to the interleaved order). ``Problem.rhs`` evaluates the system as
``J @ y + F(t) e_1``, one sparse matrix-vector product (the fastest form at
every N); ``Problem.rhs_explicit`` is the junction-by-junction form above
(``simulate(..., explicit=True)``); the two agree to rounding.

``python -m benchmarks.hand.chain [N ...]`` compares this against
``bondc simulate`` (run through its command line, files in /tmp) for N = 10
and 100 with Radau and LSODA at rtol 1e-8 and prints the differences and the
timings. Checked: every state agrees with bondc's to within 5e-9 (Radau) and
3e-7 (LSODA) of its largest magnitude at rtol 1e-8, atol 1e-12.
"""

from __future__ import annotations

import functools
import json
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp

from benchmarks.chain import PARAMETERS, chain_source

ROOT = Path(__file__).resolve().parents[2]


class Result(NamedTuple):
    """A hand simulation: times, states (2N x len(t), bondc's order) and solver counts over all pieces."""

    t: np.ndarray
    y: np.ndarray
    nfev: int
    njev: int
    nlu: int


class Problem:
    """The chain's right-hand side and Jacobians for N sections, every constant precomputed."""

    def __init__(self, n: int, m: float = PARAMETERS["m"], k: float = PARAMETERS["k"],
                 b: float = PARAMETERS["b"], F0: float = PARAMETERS["F0"], t_step: float = PARAMETERS["t_step"]):
        self.n, self.F0, self.t_step = n, float(F0), float(t_step)
        self.inv_m, self.k, self.b = 1.0 / m, float(k), float(b)
        self.y0 = np.zeros(2 * n)

        # Jacobian in block form [p; q], then permuted to the interleaved order.
        D = sp.diags([np.ones(n), -np.ones(n - 1)], [0, 1], shape=(n, n), format="csr")
        J_block = sp.bmat([[-(b / m) * (D.T @ D), -k * D.T], [D / m, None]], format="csr")
        order = np.empty(2 * n, dtype=int)     # interleaved position -> block position
        order[0::2] = np.arange(n)             # p_i
        order[1::2] = n + np.arange(n)         # q_i
        J = J_block[order][:, order].tocsc()
        J.eliminate_zeros()
        J.sort_indices()
        self.J = J
        self.J_csr = J.tocsr()                 # for the matrix-vector right-hand side
        # LSODA: banded packed form, jac_packed[uband + i - j, j] = J[i, j]
        coo = J.tocoo()
        self.lband = self.uband = 2
        packed = np.zeros((self.lband + self.uband + 1, 2 * n))
        assert np.all(np.abs(coo.row - coo.col) <= 2)
        packed[self.uband + coo.row - coo.col, coo.col] = coo.data
        self.J_packed = packed

    # ---------------------------------------------------------------- right-hand side

    def rhs(self, t, y):
        """dy/dt in bondc's interleaved order: ``J @ y + F(t) e_1`` (the system is linear).

        One sparse matrix-vector product (a single C call) is the fastest form
        for every N (about 4 us at N = 10 and 100, against 7-8 us for the
        explicit form below, which takes ten numpy calls); it computes
        exactly the same numbers up to rounding (see :meth:`rhs_explicit`).
        """
        out = self.J_csr @ y
        if t >= self.t_step:                   # F(t) = F0*step(t, t_step) on mass 1
            out[0] += self.F0
        return out

    def rhs_explicit(self, t, y):
        """dy/dt written junction by junction (the equations of the module docstring)."""
        p = y[0::2]
        v = p * self.inv_m                     # mass velocities (1-junctions v_i)
        w = v.copy()
        w[:-1] -= v[1:]                        # relative velocities on r_i (v_{N+1} = 0: the wall)
        e = self.k * y[1::2]
        e += self.b * w                        # efforts of the 0-junctions n_i: spring + damper
        out = np.empty_like(y)
        dp = out[0::2]
        np.negative(e, out=dp)                 # dp_i = e_{i-1} - e_i
        dp[1:] += e[:-1]
        if t >= self.t_step:                   # e_0 = F(t), the force on mass 1
            dp[0] += self.F0
        out[1::2] = w                          # dq_i = v_i - v_{i+1}
        return out

    def jacobian(self, t, y):
        """The constant sparse (CSC) Jacobian, for Radau and BDF."""
        return self.J

    def jacobian_banded(self, t, y):
        """The constant Jacobian in LSODA's banded packed form (lband = uband = 2)."""
        return self.J_packed


@functools.lru_cache(maxsize=8)
def problem(n: int) -> Problem:
    """The (cached) problem for N sections with the benchmark's PARAMETERS."""
    return Problem(n)


def rhs(t, y):
    """dy/dt for a chain whose N is len(y)/2 (convenience wrapper around :class:`Problem`)."""
    return problem(len(y) // 2).rhs(t, y)


def jacobian(t, y):
    """The sparse CSC Jacobian for a chain whose N is len(y)/2."""
    return problem(len(y) // 2).J


def simulate(n: int, t_end: float = 10.0, rtol: float = 1e-6, atol: float = 1e-9, method: str = "Radau",
             t_eval=None, explicit: bool = False) -> Result:
    """Integrate the N-section chain from rest over [0, t_end].

    The run is split at t_step (integrate [0, t_step], then restart at
    [t_step, t_end]), as bondc splits at the step's known time, so neither
    solver ever steps across the discontinuity. ``method``: any solve_ivp
    method; Radau/BDF get the constant sparse Jacobian, LSODA the banded one.
    ``t_eval``: report at these times (dense output) instead of every step.
    ``explicit``: use the junction-by-junction right-hand side instead of
    the (faster, equal) sparse matrix-vector product.
    Returns ``Result(t, y, nfev, njev, nlu)`` summed over both pieces; the
    point at t_step appears once.
    """
    pb = problem(n)
    options = {"rtol": rtol, "atol": atol}
    if method.upper() == "LSODA":
        options.update(jac=pb.jacobian_banded, lband=pb.lband, uband=pb.uband)
    elif method in ("Radau", "BDF"):
        options.update(jac=pb.jacobian)
    fun = pb.rhs_explicit if explicit else pb.rhs
    pieces = [(0.0, pb.t_step), (pb.t_step, float(t_end))] if 0.0 < pb.t_step < t_end else [(0.0, float(t_end))]
    y = pb.y0
    ts, ys, nfev, njev, nlu = [], [], 0, 0, 0
    for index, (a, b) in enumerate(pieces):
        if t_eval is not None:
            # the requested times in this piece, plus its end (needed to restart the next piece)
            te = np.asarray(t_eval, dtype=float)
            te = te[(te >= a) & (te <= b)] if index == 0 else te[(te > a) & (te <= b)]
            wanted = np.ones(te.size + 1, dtype=bool)
            if te.size == 0 or te[-1] != b:
                te = np.append(te, b)
                wanted[-1] = False
            else:
                wanted = wanted[:-1]
            options["t_eval"] = te
        sol = solve_ivp(fun, (a, b), y, method=method, **options)
        if sol.status != 0:
            raise RuntimeError(f"solve_ivp failed on [{a}, {b}]: {sol.message}")
        y = sol.y[:, -1]
        if t_eval is not None:
            keep = wanted
        else:
            keep = slice(None) if index == 0 else slice(1, None)    # t_step once
        ts.append(sol.t[keep])
        ys.append(sol.y[:, keep])
        nfev, njev, nlu = nfev + sol.nfev, njev + sol.njev, nlu + sol.nlu
    return Result(np.concatenate(ts), np.concatenate(ys, axis=1), nfev, njev, nlu)


# ---------------------------------------------------------------- comparison against bondc

def bondc_model(n: int, t_end: float, rtol: float, atol: float, method: str) -> str:
    """The chain's .bg text with the experiment set to ``method``/``rtol``/``atol``."""
    text = chain_source(n, t_end)
    text = re.sub(r"^(\s*)rtol\s*=.*$", rf"\g<1>rtol = {rtol:g}", text, flags=re.M)
    text = re.sub(r"^(\s*)atol\s*=.*$", rf"\g<1>atol = {atol:g}", text, flags=re.M)
    text = re.sub(r"^(\s*experiment\s+\w+.*)$", rf'\1\n    solver = "{method}"', text, count=1, flags=re.M)
    return text


def run_bondc(n: int, t_end: float, rtol: float, atol: float, method: str):
    """Run ``bondc simulate`` on the chain (files in /tmp).

    Returns (t, states (2N x k, bondc's order), column names, bondc's stats):
    the stats are those of ``--json`` (nfev, njev, steps, wall_time of the
    integration alone, without parsing and code generation).
    """
    bondc = ROOT / ".venv" / "bin" / "bondc"
    model = Path(f"/tmp/hand_chain{n}_{method}.bg")
    out = Path(f"/tmp/hand_chain{n}_{method}.csv")
    model.write_text(bondc_model(n, t_end, rtol, atol, method))
    done = subprocess.run([str(bondc), "simulate", str(model), "-o", str(out), "--json"],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"bondc simulate failed:\n{done.stdout}\n{done.stderr}")
    stats = json.loads(done.stdout)["stats"]
    header = out.read_text().split("\n", 1)[0].split(",")
    data = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    columns = [name for i in range(1, n + 1) for name in (f"m{i}.p", f"k{i}.q")]
    index = [header.index(name) for name in columns]
    return data[:, 0], data[:, index].T, columns, stats


def compare(n: int, method: str, t_end: float = 10.0, rtol: float = 1e-8, atol: float = 1e-12) -> None:
    t_ref, y_ref, columns, stats = run_bondc(n, t_end, rtol, atol, method)
    hand = simulate(n, t_end, rtol, atol, method, t_eval=t_ref)
    assert np.array_equal(hand.t, t_ref), "hand solution not reported at bondc's times"
    diff = np.abs(hand.y - y_ref)
    scale = np.max(np.abs(y_ref), axis=1)
    rel = diff.max(axis=1) / scale
    print(f"N = {n}, {method}, rtol {rtol:g}, atol {atol:g}, t_end {t_end:g} s: {t_ref.size} bondc points")
    for kind, rows in (("p (momenta)", slice(0, None, 2)), ("q (extensions)", slice(1, None, 2))):
        worst = int(np.argmax(rel[rows])) * 2 + (0 if kind[0] == "p" else 1)
        print(f"  {kind:15s} max |diff| {diff[rows].max():.3e}   max |diff|/max|x| per state: "
              f"{rel[rows].max():.3e} (worst {columns[worst]}, max|x| {scale[worst]:.3e})")
    # timing of the hand run alone (every step reported, as bondc does), best of 3
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        result = simulate(n, t_end, rtol, atol, method)
        best = min(best, time.perf_counter() - start)
    print(f"  hand : {best * 1e3:8.1f} ms  nfev {result.nfev:6d}  njev {result.njev:4d}  nlu {result.nlu:5d}  "
          f"steps {result.t.size - 1}")
    print(f"  bondc: {stats['wall_time'] * 1e3:8.1f} ms  nfev {stats['nfev']:6d}  njev {stats['njev']:4d}  "
          f"nlu {stats['nlu']:5d}  steps {stats['steps']}  (its own integration wall time, one run)")


def main(argv=None) -> int:
    sizes = [int(a) for a in (argv if argv is not None else sys.argv[1:])] or [10, 100]
    for n in sizes:
        for method in ("Radau", "LSODA"):
            compare(n, method)
    return 0


if __name__ == "__main__":
    sys.exit(main())
