"""Make the synthetic "measured" torque and chamber pressure of the calibration example.

Writes ``fit_cycle_measured.csv`` beside this script: the flagship
``electro_pneumatic_hybrid.bg`` (experiment ``cycle``) simulated with known
"true" values of the valve effective area and the upward friction factor,
sampled every 2 ms from 0 to 4.2 s, plus seeded Gaussian noise (1 % of each
signal's range). Columns: ``t`` [s], ``torque`` [N*m], ``P`` [kPa] (the header
gives the units; ``bondc fit`` converts them).

It is NOT a measurement: it lets ``bondc fit`` be shown recovering values it
did not know (``docs/calibration.md``). The seed is fixed; running it again
writes the same file::

    python models/data/make_fit_data.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
MODEL = HERE.parent / "electro_pneumatic_hybrid.bg"
OUTPUT = HERE / "fit_cycle_measured.csv"

#: The "true" values the data is made with (the model file has Ae = 1.2e-5 m^2, a_up = 706.59 N*s/m).
TRUE = {"Ae": 1.5e-5, "a_up": 600.0}
DT_SAMPLE = 2e-3        # [s]
NOISE = 0.01            # standard deviation, as a share of each signal's range
SEED = 20261129


def measured(true=TRUE, noise: float = NOISE, seed: int = SEED, dt: float = DT_SAMPLE):
    """(t [s], torque [N*m], P [kPa]) with noise."""
    import bondc

    sim = bondc.simulate(MODEL, experiment="cycle", overrides=true, dt=dt)
    rng = np.random.default_rng(seed)
    torque = np.asarray(sim["torque"], dtype=float)
    pressure = np.asarray(sim["P"], dtype=float) / 1e3
    torque = torque + rng.normal(0.0, noise * np.ptp(torque), torque.size)
    pressure = pressure + rng.normal(0.0, noise * np.ptp(pressure), pressure.size)
    return np.asarray(sim.t, dtype=float), torque, pressure


def main() -> None:
    t, torque, pressure = measured()
    lines = ["t [s],torque [N*m],P [kPa]"]
    lines += [f"{a:.4f},{b:.6g},{c:.7g}" for a, b, c in zip(t, torque, pressure)]
    OUTPUT.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {OUTPUT} ({len(t)} rows)")


if __name__ == "__main__":
    main()
