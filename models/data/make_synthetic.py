"""Make the synthetic stand-in for a measured servomotor speed.

Writes ``omega_measured.csv`` (columns ``t`` [s], ``omega`` [rad/s]) beside
this script: the trapezoidal speed profile of MODEL-NOTES.md item 8 (the
default input of ``electro_pneumatic_hybrid.bg``), passed through a first-order
lag (a servo drive that does not follow its reference instantly) and given
+-0.5 % multiplicative noise (a speed read from an encoder), sampled every
1 ms from 0 to 4.2 s. The noise is uniform and scales with the reading, so the
signal is exactly 0 at rest and the model starts in equilibrium.

It is NOT a measurement: it stands in for the paper's measured speed so that
the ``measured_speed`` experiment and the ``csv()`` input can be exercised.
The seed is fixed, so running it again reproduces the file byte for byte::

    python models/data/make_synthetic.py
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

# Profile (MODEL-NOTES.md item 8; the parameters of electro_pneumatic_hybrid.bg)
W_MAX = 1000 * 2 * math.pi / 60        # 1000 rpm in rad/s
LEAD = 5.0e-3                          # ball screw lead [m/rev]
STROKE = 0.100                         # travel of each move [m]
T_REST0, T_RAMP, T_DWELL, T_REST_END = 0.2, 0.05, 1.0, 0.5   # [s]

# Synthetic "measurement"
TAU_LAG = 5e-3        # first-order lag of the drive [s]
NOISE = 0.005         # +-0.5 % of the reading, uniform
DT_SAMPLE = 1e-3      # sampling period [s]
SUBSTEPS = 100        # integration substeps of the lag per sample
T_END = 4.2           # [s]
SEED = 20240521


def breakpoints() -> tuple[np.ndarray, np.ndarray]:
    """Times and values of the trapezoid: 0, 0.2, 0.25, 1.40, 1.45, 2.45, 2.50, 3.65, 3.70, 4.20 s."""
    v_max = W_MAX * LEAD / (2 * math.pi)
    t_cruise = STROKE / v_max - T_RAMP
    steps = [0.0, T_REST0, T_RAMP, t_cruise, T_RAMP, T_DWELL, T_RAMP, t_cruise, T_RAMP, T_REST_END]
    times = np.cumsum(steps)
    values = np.array([0, 0, W_MAX, W_MAX, 0, 0, -W_MAX, -W_MAX, 0, 0], dtype=float)
    return times, values


def synthetic_speed() -> tuple[np.ndarray, np.ndarray]:
    times, values = breakpoints()
    n_samples = round(T_END / DT_SAMPLE) + 1
    dt = DT_SAMPLE / SUBSTEPS
    t_fine = np.arange((n_samples - 1) * SUBSTEPS + 1) * dt
    reference = np.interp(t_fine, times, values)
    # exact discrete first-order lag for an input held over each substep
    a = math.exp(-dt / TAU_LAG)
    lagged = np.empty_like(reference)
    y = 0.0
    for k, u in enumerate(reference):
        y = a * y + (1 - a) * u
        lagged[k] = y
    t = t_fine[::SUBSTEPS]
    omega = lagged[::SUBSTEPS]
    rng = np.random.default_rng(SEED)
    omega = omega * (1 + NOISE * rng.uniform(-1.0, 1.0, size=omega.shape))
    omega[np.abs(omega) < 1e-9] = 0.0      # exact rest before the first move
    return t, omega


def main() -> None:
    t, omega = synthetic_speed()
    path = Path(__file__).with_name("omega_measured.csv")
    with path.open("w", newline="\n") as out:
        out.write("t,omega\n")
        for ti, wi in zip(t, omega):
            out.write(f"{ti:.3f},{wi:.6f}\n")
    up = np.clip(omega, 0, None)
    stroke_up = float(np.sum((up[1:] + up[:-1]) / 2 * np.diff(t))) * LEAD / (2 * math.pi)
    print(f"wrote {path.name}: {t.size} rows, up-stroke {stroke_up * 1e3:.3f} mm")


if __name__ == "__main__":
    main()
