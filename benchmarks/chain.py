"""The N-section mass-spring-damper chain used by the scaling benchmarks.

A force step F0 at t = 0.01 s pushes mass 1. Section i is a mass m on a
1-junction (velocity v_i) and a spring k in parallel with a damper b between
mass i and mass i + 1 (mass N's spring and damper go to the wall):

    MSe force -> 1 v1 -> I m1
                      -> 0 n1 -> 1 v2 ...
                              -> 1 r1 -> C k1, R b1      (r1 carries v1 - v2)

States: the N momenta p_i and the N spring extensions q_i (2N states, 6N + 1 bonds).
``python -m benchmarks.chain N > chainN.bg`` writes the model.
"""

from __future__ import annotations

import sys

PARAMETERS = {"m": 1.0, "k": 1000.0, "b": 2.0, "F0": 1.0, "t_step": 0.01}


def chain_source(n: int, t_end: float = 10.0) -> str:
    """The .bg text of the N-section chain."""
    lines = [f'model Chain{n} "{n}-section mass-spring-damper chain"',
             f'  param m = {PARAMETERS["m"]} [kg]',
             f'  param k = {PARAMETERS["k"]} [N/m]',
             f'  param b = {PARAMETERS["b"]} [N*s/m]',
             f'  param F0 = {PARAMETERS["F0"]} [N]',
             f'  param t_step = {PARAMETERS["t_step"]} [s]',
             '  input F [N] = step(t, t_step) * F0',
             '  MSe force : e = F']
    for i in range(1, n + 1):
        lines += [f'  I m{i} : f = p/m', f'  C k{i} : e = k*q', f'  R b{i} : e = b*f',
                  f'  1 v{i}', f'  0 n{i}', f'  1 r{i}']
    lines.append('  force -> v1')
    for i in range(1, n + 1):
        lines += [f'  v{i} -> m{i}', f'  v{i} -> n{i}']
        if i < n:
            lines.append(f'  n{i} -> v{i + 1}')
        lines += [f'  n{i} -> r{i}', f'  r{i} -> k{i}', f'  r{i} -> b{i}']
    lines += ['  output speed1 [m/s] = m1.f', f'  output stretch_end [m] = k{n}.q',
              '  experiment run', f'    t_end = {t_end:g} [s]', '    rtol = 1e-6', '    atol = 1e-9', '  end',
              'end']
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.stdout.write(chain_source(int(sys.argv[1])))
