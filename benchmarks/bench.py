"""bondc benchmarks: every timing is reported as a ratio to a reference run in the same process.

Absolute seconds depend on the machine and on what else it is doing; a ratio to
a reference workload measured a moment earlier in the same process does not
(much). Two kinds of reference:

* ``hand``: the same ODE written by hand in numpy and integrated with the same
  scipy solver, tolerances and time span — the ratio is bondc's overhead
  (generated code, frozen-mode event handling) over the plainest possible code;
* ``unit``: a fixed workload (a hand-written Van der Pol oscillator, mu = 100,
  integrated with Radau) — stages that have no hand-written equivalent
  (parsing, causality, sympy derivation, code generation) are reported in
  multiples of it.

Run: ``python benchmarks/bench.py [--repeat N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"


def best_of(repeat: int, function) -> float:
    """The fastest of ``repeat`` runs, in seconds (the least disturbed by other load)."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


# ------------------------------------------------------------------ references

def reference_unit() -> None:
    """Van der Pol, mu = 100, over 200 s with Radau and an analytic Jacobian."""
    mu = 100.0

    def rhs(t, y):
        return [y[1], mu * (1 - y[0] ** 2) * y[1] - y[0]]

    def jac(t, y):
        return [[0.0, 1.0], [-2 * mu * y[0] * y[1] - 1, mu * (1 - y[0] ** 2)]]

    solve_ivp(rhs, (0, 200), [2.0, 0.0], method="Radau", jac=jac, rtol=1e-6, atol=1e-9)


def hand_mass_spring_damper(t_end: float, rtol: float, atol: float, method: str):
    """models/mass_spring_damper.bg written by hand (same parameters, same step input)."""
    m, k, b, force, t_step = 2.0, 800.0, 12.0, 10.0, 0.1

    def rhs(t, x):
        p, q = x
        return [(force if t >= t_step else 0.0) - b * p / m - k * q, p / m]

    def jac(t, x):
        return [[-b / m, -k], [1 / m, 0.0]]

    def run():
        # Split at the step like bondc does, so both integrate the same smooth pieces.
        first = solve_ivp(rhs, (0, t_step), [0.0, 0.0], method=method, jac=jac, rtol=rtol, atol=atol)
        solve_ivp(rhs, (t_step, t_end), first.y[:, -1], method=method, jac=jac, rtol=rtol, atol=atol)

    return run


# ------------------------------------------------------------------ bondc runs

def pipeline(path: Path):
    from bondc.codegen import emit
    from bondc.pipeline import derive_file

    def run():
        derived = derive_file(path)
        emit(derived.state_space, derived.experiment)

    return run


def prepared(path: Path, **settings):
    """Everything up to the simulation done once; the returned function simulates."""
    from bondc.pipeline import derive_file
    from bondc.simulate import simulate

    derived = derive_file(path)
    simulate(derived.state_space, derived.experiment, **settings)  # compile once, outside the timing

    return lambda: simulate(derived.state_space, derived.experiment, **settings)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    unit = best_of(args.repeat, reference_unit)
    rows = []

    msd = MODELS / "mass_spring_damper.bg"
    for method in ("LSODA", "Radau"):
        hand = best_of(args.repeat, hand_mass_spring_damper(2.0, 1e-6, 1e-9, method))
        ours = best_of(args.repeat, prepared(msd, method=method, rtol=1e-6, atol=1e-9))
        rows.append({"benchmark": f"simulate mass_spring_damper ({method})", "reference": "hand",
                     "ratio": ours / hand})

    for name in ("mass_spring_damper", "electro_pneumatic_hybrid"):
        path = MODELS / f"{name}.bg"
        rows.append({"benchmark": f"compile {name} (parse .. emit)", "reference": "unit",
                     "ratio": best_of(args.repeat, pipeline(path)) / unit})

    flagship = MODELS / "electro_pneumatic_hybrid.bg"
    rows.append({"benchmark": "simulate electro_pneumatic_hybrid cycle (4.2 s)", "reference": "unit",
                 "ratio": best_of(max(1, args.repeat - 1), prepared(flagship)) / unit})

    if args.json:
        print(json.dumps({"reference_unit_seconds": unit, "results": rows}, indent=2))
    else:
        print(f"reference unit (Van der Pol mu=100, Radau): {unit * 1e3:.1f} ms on this machine, now")
        print(f"{'benchmark':<52} {'vs':<5} {'ratio':>8}")
        for row in rows:
            print(f"{row['benchmark']:<52} {row['reference']:<5} {row['ratio']:>8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
