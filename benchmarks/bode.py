"""How ``bondc bode`` solves a large model: sparse LU per frequency against the dense routes.

``python -m benchmarks.bode [N] [--points P]`` linearises the N-section chain of
[chain.py](chain.py) (2N states; default N = 1000) and times G(jw) = C (jw I - A)^-1 B + D
over P log-spaced frequencies (default 400) three ways:

- **sparse**: what ``bondc.analysis.bode.frequency_response`` does above ``DENSE_STATES``
  states: ``scipy.sparse.linalg.splu`` of ``jw I - A`` per frequency;
- **dense**: LAPACK ``gesv`` of the dense ``jw I - A`` per frequency (timed on a tenth of the
  frequencies and scaled);
- **hessenberg**: ``scipy.linalg.hessenberg`` of A once (the reduction alone; a solve per
  frequency would come on top).

It prints the seconds of each and their ratios to the sparse route, which are what carries over
between machines, and checks that the three agree. Not a test: nothing here is asserted on time.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("n", nargs="?", type=int, default=1000, help="chain sections (2N states)")
    parser.add_argument("--points", type=int, default=400)
    args = parser.parse_args(argv)

    import scipy.linalg

    import bondc
    from benchmarks.chain import chain_source
    from bondc.analysis.bode import frequency_response

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "chain.bg"
        path.write_text(chain_source(args.n))
        start = time.perf_counter()
        lin = bondc.linearize(path)
        linearise = time.perf_counter() - start
    A, B, C, D = lin.A, lin.B, lin.C, lin.D
    n = A.shape[0]
    f = np.geomspace(1e-3, 1e2, args.points)

    start = time.perf_counter()
    sparse = frequency_response(A, B, C, D, f)
    t_sparse = time.perf_counter() - start

    subset = f[:: max(1, args.points // 10)]
    start = time.perf_counter()
    dense = np.stack([C @ np.linalg.solve(2j * np.pi * fk * np.eye(n) - A, B) + D for fk in subset], axis=-1)
    t_dense = (time.perf_counter() - start) * args.points / subset.size

    start = time.perf_counter()
    H, Q = scipy.linalg.hessenberg(A, calc_q=True)
    t_hessenberg = time.perf_counter() - start
    first = C @ Q @ np.linalg.solve(2j * np.pi * f[0] * np.eye(n) - H, Q.T @ B) + D

    index = np.arange(0, args.points, max(1, args.points // 10))
    agree = float(np.max(np.abs(sparse[:, :, index] - dense)) / np.max(np.abs(dense)))
    agree = max(agree, float(np.max(np.abs(sparse[:, :, 0] - first)) / np.max(np.abs(first))))
    print(f"chain of {args.n} sections: {n} states, {np.count_nonzero(A)} non-zeros in A; linearised in "
          f"{linearise:.3g} s")
    print(f"| route | {args.points} frequencies [s] | ratio to sparse |")
    print("| --- | ---: | ---: |")
    print(f"| sparse (splu per frequency) | {t_sparse:.3g} | 1 |")
    print(f"| dense (gesv per frequency, scaled from {subset.size}) | {t_dense:.3g} | {t_dense / t_sparse:.3g} |")
    print(f"| hessenberg (the reduction alone) | {t_hessenberg:.3g} | {t_hessenberg / t_sparse:.3g} |")
    print(f"largest relative difference between the routes: {agree:.2g}")


if __name__ == "__main__":
    main()
