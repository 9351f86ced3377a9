"""bondc benchmarks: ``python -m benchmarks [--quick] [--json out.json]``.

Three tables (see benchmarks/README.md for the targets and the last recorded run):

1. **Compile scaling**: the N-section mass-spring-damper chain (benchmarks/chain.py)
   from source to a loaded compiled module, each N in a fresh process: seconds
   per stage, peak memory, and the exponent of time against N fitted over the
   largest sizes.
2. **Simulation against hand-written scipy code** of the same physics
   (benchmarks/hand/), run in this process with the same tolerances: the ratio
   bondc / hand of the best of several runs (model compilation excluded), the
   right-hand side and Jacobian counts, and the largest difference of the
   trajectories (relative to each state's range).
3. **Startup**: whole-process wall time of ``bondc --help``, ``bondc check``
   (``--no-cache``, unchanged, after an edit of a parameter value, after an edit of a law), a cold
   ``bondc simulate`` (empty cache) and a cached one, on the flagship.
4. **Analysis of a large model**: ``bondc equations`` and ``bondc linearize`` of
   the 1000-section chain (100 with ``--quick``), cold and cached, with peak memory.

Times are seconds on this machine now; the ratios in table 2 are what carries
over between machines. ``--quick`` (under 2 minutes) stops the scaling at
N = 1000 and simulates the 100-section chain only.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FLAGSHIP = ROOT / "models" / "electro_pneumatic_hybrid.bg"


def best_of(repeat: int, function):
    """(fastest wall time of ``repeat`` calls, the last call's value)."""
    best, value = math.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        value = function()
        best = min(best, time.perf_counter() - start)
    return best, value


def best_of_pairs(repeat: int, first, second):
    """(fastest time of ``first``, fastest of ``second``, their last values) over ``repeat`` rounds
    that run one then the other: a machine whose load drifts over the rounds slows both alike."""
    best, values = [math.inf, math.inf], [None, None]
    for _ in range(repeat):
        for i, function in enumerate((first, second)):
            start = time.perf_counter()
            values[i] = function()
            best[i] = min(best[i], time.perf_counter() - start)
    return best[0], best[1], values[0], values[1]


def fitted_exponent(rows: list) -> float | None:
    """Slope of log(total time) against log(N), least squares over the given rows."""
    if len(rows) < 2:
        return None
    x = np.log([row["n"] for row in rows])
    y = np.log([row["total"] for row in rows])
    return float(np.polyfit(x, y, 1)[0])


# ------------------------------------------------------------------ 1. compile scaling

def compile_scaling(sizes) -> dict:
    rows = []
    for n in sizes:
        done = subprocess.run([sys.executable, "-m", "benchmarks.compile_one", str(n)], cwd=ROOT,
                              capture_output=True, text=True, timeout=3600)
        if done.returncode != 0:
            rows.append({"n": n, "error": (done.stderr.strip().splitlines() or ["failed"])[-1]})
            continue
        rows.append(json.loads(done.stdout))
        row = rows[-1]
        print(f"  N = {n:>6}: {row['total']:7.2f} s  " + "  ".join(
            f"{stage} {seconds:.2f}" for stage, seconds in row["stages"].items())
              + f"  peak {row['peak_mb']:.0f} MB", file=sys.stderr, flush=True)
    good = [row for row in rows if "error" not in row]
    large = [row for row in good if row["n"] >= 1000]
    return {"rows": rows, "exponent": fitted_exponent(large if len(large) >= 2 else good[-2:])}


# ------------------------------------------------------------------ 2. simulation

def _bondc_run(path: Path, repeat: int, hand):
    """Best times of bondc simulating ``path``'s first experiment in this process, compiled once,
    and of ``hand()``, in rounds of one run each; then bondc with every variable read (again
    against ``hand()``) and its numpy code once: (bondc s, bondc read s, numpy s, bondc's result,
    settings, hand s, hand's result)."""
    from bondc.pipeline import derive_file
    from bondc.simulate import compile_model

    derived = derive_file(path, cache=False)
    namespace = compile_model(derived.state_space)
    experiment = derived.experiment
    settings = {"t_end": experiment.t_end, "method": experiment.solver, "rtol": experiment.rtol,
                "atol": experiment.atol, "max_step": experiment.max_step}

    def run(native=None):
        return namespace["simulate_model"](namespace["_MODEL"], native=native, **settings)

    def run_read():     # and every variable read (evaluated), as `bondc simulate` reads them
        result = run()
        if result.variables:
            result.variables[next(iter(result.variables))]
        return result

    run()       # builds (or loads) the C library outside the timing
    seconds, hand_seconds, result, reference = best_of_pairs(repeat, run, lambda: hand(settings))
    read_seconds, again, _, _ = best_of_pairs(repeat, run_read, lambda: hand(settings))
    numpy_seconds, _ = best_of(1, lambda: run(False))
    return seconds, read_seconds, numpy_seconds, result, settings, min(hand_seconds, again), reference


def _difference(hand_y, result, names, atol) -> float:
    """Largest |bondc - hand| at bondc's points (``hand_y``: the hand solution there, from its
    dense output), relative to each state's range; a range below 1000 atol (or a millionth of the
    largest) counts as that, since both solvers' errors there are of the order of atol (the
    chain's far end barely moves in 10 s)."""
    ranges = np.ptp(np.asarray(hand_y), axis=1)
    floor = max(1e-6 * float(ranges.max()) if ranges.size else 0.0, 1e3 * atol)
    worst = 0.0
    for row, name in enumerate(names):
        scale = max(float(ranges[row]), floor, 1e-300)
        worst = max(worst, float(np.max(np.abs(result.states[name] - hand_y[row]))) / scale)
    return worst


def simulate_flagship(repeat: int) -> dict:
    from benchmarks.hand import flagship as hand

    ours, read_time, numpy_time, result, settings, hand_time, reference = _bondc_run(
        FLAGSHIP, repeat, lambda settings: hand.simulate(settings["rtol"], settings["atol"], settings["max_step"],
                                                         "LSODA"))
    names = list(result.states)
    dense = hand.simulate(settings["rtol"], settings["atol"], settings["max_step"], "LSODA", dense=True)
    return {"benchmark": "flagship cycle (4.2 s)", "hand": "LSODA, events for the friction jump",
            "hand_s": hand_time, "bondc_s": ours, "bondc_numpy_s": numpy_time, "ratio": ours / hand_time,
            "bondc_read_s": read_time, "ratio_read": read_time / hand_time,
            "hand_nfev": int(reference.nfev), "hand_njev": int(reference.njev),
            "bondc_nfev": int(result.stats["nfev"]), "bondc_njev": int(result.stats["njev"]),
            "code": result.stats.get("code"), "solver": result.stats.get("solver"),
            "difference": _difference(dense.sol(result.t), result, names, settings["atol"])}


def simulate_chain(n: int, repeat: int) -> dict:
    from benchmarks.chain import chain_source
    from benchmarks.hand import chain as hand

    folder = Path(tempfile.mkdtemp(prefix="bondc-bench-"))
    path = folder / f"chain{n}.bg"
    path.write_text(chain_source(n), encoding="utf-8")
    ours, read_time, numpy_time, result, settings, hand_time, reference = _bondc_run(
        path, repeat, lambda settings: hand.simulate(n, settings["t_end"], settings["rtol"], settings["atol"],
                                                     "LSODA"))
    names = [name for i in range(1, n + 1) for name in (f"m{i}.p", f"k{i}.q")]
    at_ours = hand.simulate(n, settings["t_end"], settings["rtol"], settings["atol"], "LSODA", t_eval=result.t)
    return {"benchmark": f"chain N = {n} (10 s)", "hand": "LSODA, banded Jacobian, sparse matrix RHS",
            "hand_s": hand_time, "bondc_s": ours, "bondc_numpy_s": numpy_time, "ratio": ours / hand_time,
            "bondc_read_s": read_time, "ratio_read": read_time / hand_time,
            "hand_nfev": int(reference.nfev), "hand_njev": int(reference.njev),
            "bondc_nfev": int(result.stats["nfev"]), "bondc_njev": int(result.stats["njev"]),
            "code": result.stats.get("code"), "solver": result.stats.get("solver"),
            "difference": _difference(at_ours.y, result, names, settings["atol"])}


PUMP_RELIEF = ROOT / "tests" / "fixtures" / "engine" / "pump_relief.bg"


def simulate_pump_relief(repeat: int) -> tuple[dict, dict]:
    """The pump/relief circuit (kinks at rest: a relief valve at its opening, an orifice at zero
    flow): in this process against benchmarks/hand/pump_relief.py, and as whole processes
    (``bondc simulate -o out.csv``, cached, against ``python -m benchmarks.hand.pump_relief``) in
    alternating rounds."""
    from benchmarks.hand import pump_relief as hand

    ours, read_time, numpy_time, result, settings, hand_time, reference = _bondc_run(
        PUMP_RELIEF, repeat, lambda settings: hand.simulate(settings["t_end"], settings["rtol"] or 1e-6, settings["atol"]))
    dense = hand.simulate(settings["t_end"], settings["rtol"] or 1e-6, settings["atol"], dense=True)
    row = {"benchmark": "pump/relief circuit (2 s)", "hand": "LSODA, the orifice's secant in the Jacobian",
           "hand_s": hand_time, "bondc_s": ours, "bondc_numpy_s": numpy_time, "ratio": ours / hand_time,
           "bondc_read_s": read_time, "ratio_read": read_time / hand_time,
           "hand_nfev": int(reference.nfev), "hand_njev": int(reference.njev),
           "bondc_nfev": int(result.stats["nfev"]), "bondc_njev": int(result.stats["njev"]),
           "code": result.stats.get("code"), "solver": result.stats.get("solver"),
           "difference": _difference(dense.sol(result.t), result, list(result.states), settings["atol"])}
    environment = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    environment["BONDC_CACHE_DIR"] = tempfile.mkdtemp(prefix="bondc-bench-cache-")
    out = str(Path(environment["BONDC_CACHE_DIR"]) / "out.csv")
    bondc = [sys.executable, "-m", "bondc", "simulate", str(PUMP_RELIEF), "-o", out]
    subprocess.run(bondc, env=environment, capture_output=True, check=True, cwd=ROOT)       # fills the cache
    bondc_s, hand_s, _, _ = best_of_pairs(
        repeat, lambda: subprocess.run(bondc, env=environment, capture_output=True, check=True, cwd=ROOT),
        lambda: subprocess.run([sys.executable, "-m", "benchmarks.hand.pump_relief"], env=environment,
                               capture_output=True, check=True, cwd=ROOT))
    return row, {"bondc_s": bondc_s, "hand_s": hand_s, "ratio": bondc_s / hand_s}


DRIVE = ROOT / "models" / "dc_motor_gear_compliant.bg"


def simulate_drive_radau(repeat: int) -> dict:
    """The lightly damped drive (models/dc_motor_gear_compliant.bg) over 2 s at rtol 1e-10 with
    ``solver = "Radau"``, the user's choice of scipy's Radau, against benchmarks/hand/drive.py
    (scipy's Radau, analytic Jacobian), in this process."""
    from benchmarks.hand import drive as hand

    folder = Path(tempfile.mkdtemp(prefix="bondc-bench-"))
    path = folder / "drive_radau.bg"
    text = DRIVE.read_text(encoding="utf-8")
    for old, new in (("t_end    = 0.3 [s]", "t_end = 2 [s]"), ("rtol     = 1e-8", 'rtol = 1e-10\n    solver = "Radau"'),
                     ("atol     = 1e-10", "atol = 1e-12")):
        assert old in text, old
        text = text.replace(old, new)
    path.write_text(text, encoding="utf-8")
    ours, read_time, numpy_time, result, settings, hand_time, reference = _bondc_run(
        path, repeat, lambda settings: hand.simulate(settings["t_end"], settings["rtol"], settings["atol"],
                                                     settings["max_step"]))
    dense = hand.simulate(settings["t_end"], settings["rtol"], settings["atol"], settings["max_step"], dense=True)
    steps = sum(piece.t.size for piece in reference[2])
    return {"benchmark": "lightly damped drive (2 s, rtol 1e-10), solver = \"Radau\"",
            "hand": "Radau, analytic Jacobian, max_step, split at the step",
            "hand_s": hand_time, "bondc_s": ours, "bondc_numpy_s": numpy_time, "ratio": ours / hand_time,
            "bondc_read_s": read_time, "ratio_read": read_time / hand_time,
            "hand_nfev": int(sum(piece.nfev for piece in reference[2])),
            "hand_njev": int(sum(piece.njev for piece in reference[2])), "hand_steps": steps,
            "bondc_nfev": int(result.stats["nfev"]), "bondc_njev": int(result.stats["njev"]),
            "code": result.stats.get("code"), "solver": result.stats.get("solver"),
            "difference": _difference(dense(result.t), result, list(result.states), settings["atol"])}


# ------------------------------------------------------------------ 3. startup

def startup(repeat: int) -> dict:
    bondc = [sys.executable, "-m", "bondc"]
    cache = tempfile.mkdtemp(prefix="bondc-bench-cache-")
    # as Python runs by default: its bytecode written once and reused (a shell that sets
    # PYTHONDONTWRITEBYTECODE would time the compilation of bondc's own modules in every process)
    environment = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    environment["BONDC_CACHE_DIR"] = cache
    out = str(Path(cache) / "out.csv")

    def timed(arguments):
        def run():
            done = subprocess.run(bondc + arguments, env=environment, capture_output=True, text=True, cwd=ROOT)
            if done.returncode != 0:
                raise RuntimeError(f"bondc {' '.join(arguments)} failed: {done.stderr.strip()[-300:]}")
        return best_of(repeat, run)[0]

    rows = {"bondc --help": timed(["--help"]),
            "bondc check flagship, --no-cache (nothing reused)":
                timed(["check", str(FLAGSHIP), "--no-cache"]),
            "bondc check flagship, unchanged (its equations stage from the check cache)":
                timed(["check", str(FLAGSHIP)])}
    # a copy of the flagship whose mass is edited before every check (a value only: the
    # equations stage of the same structure is reused)
    import re
    import shutil

    copy = Path(cache) / "edited" / FLAGSHIP.name
    shutil.copytree(FLAGSHIP.parent / "data", copy.parent / "data")
    text = FLAGSHIP.read_text(encoding="utf-8")
    copy.write_text(text, encoding="utf-8")
    timed(["check", str(copy)])
    masses = iter(range(1, 10 * repeat + 10))

    def edited_check():
        copy.write_text(re.sub(r"(param M\s*=\s*)[0-9.]+", lambda m: m.group(1) + f"3{next(masses) % 10}.5", text,
                               count=1), encoding="utf-8")
        done = subprocess.run(bondc + ["check", str(copy)], env=environment, capture_output=True, text=True, cwd=ROOT)
        if done.returncode != 0:
            raise RuntimeError(f"bondc check of the edited copy failed: {done.stderr.strip()[-300:]}")
    rows["bondc check flagship, after an edit of a parameter value"] = best_of(repeat, edited_check)[0]
    # ... and whose coupling's law is edited before every check (the equations stage runs; its
    # verdict comes from bondc.quickcheck, without sympy, when that is certain)
    laws = iter(range(1, 10 * repeat + 10))

    def law_check():
        edited = text.replace(": e = K*q,", f": e = K*q*(1 + {next(laws)}e-12),", 1)
        if edited == text:
            raise RuntimeError("the coupling's law `e = K*q,` is not in the flagship any more")
        copy.write_text(edited, encoding="utf-8")
        done = subprocess.run(bondc + ["check", str(copy)], env=environment, capture_output=True, text=True, cwd=ROOT)
        if done.returncode != 0:
            raise RuntimeError(f"bondc check of the edited copy failed: {done.stderr.strip()[-300:]}")
    rows["bondc check flagship, after an edit of a law"] = best_of(repeat, law_check)[0]
    rows["bondc simulate flagship, cold (no cache, C build)"] = best_of(1, lambda: subprocess.run(
        bondc + ["simulate", str(FLAGSHIP), "-o", out, "--no-cache"],
        env={**environment, "BONDC_CACHE_DIR": tempfile.mkdtemp(prefix="bondc-cold-")},
        capture_output=True, check=True))[0]
    timed(["simulate", str(FLAGSHIP), "-o", out])       # fills the cache
    rows["bondc simulate flagship, cached"] = timed(["simulate", str(FLAGSHIP), "-o", out])
    return rows


# ------------------------------------------------------------------ 4. analysis of a large model

_PEAK = ("import sys\nfrom benchmarks.compile_one import peak_kb\nfrom bondc.cli import main\ncode = main(sys.argv[1:])\n"
         "sys.stderr.write('\\nPEAK %d\\n' % peak_kb())\n"
         "sys.exit(code)")


def analysis(n: int) -> dict:
    """Whole-process time and peak memory of ``bondc equations`` and ``bondc linearize`` on the
    N-section chain: cold (no compile cache) and cached."""
    from benchmarks.chain import chain_source

    folder = Path(tempfile.mkdtemp(prefix="bondc-bench-"))
    path = folder / f"chain{n}.bg"
    path.write_text(chain_source(n), encoding="utf-8")
    environment = {**os.environ, "BONDC_CACHE_DIR": str(folder / "cache")}
    rows = {}
    for command, cache in (("equations", "cold"), ("linearize", "cold"), ("equations", "cached"),
                           ("linearize", "cached")):
        arguments = [command, str(path)] + (["--no-cache"] if cache == "cold" else [])
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", _PEAK, *arguments], env=environment, capture_output=True,
                              text=True, cwd=ROOT)
        seconds = time.perf_counter() - start
        peak = [line for line in done.stderr.splitlines() if line.startswith("PEAK ")]
        rows[f"bondc {command} chain N = {n}, {cache}"] = {
            "seconds": seconds, "peak_mb": int(peak[-1].split()[1]) / 1024 if peak else None,
            "ok": done.returncode == 0}
        if cache == "cold" and command == "linearize":
            # fill the cache for the cached runs (the cold runs bypass it)
            subprocess.run([sys.executable, "-m", "bondc", "linearize", str(path)], env=environment,
                           capture_output=True, cwd=ROOT)
    return rows


# ------------------------------------------------------------------ main

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes, fewer repeats (under 2 minutes)")
    parser.add_argument("--json", metavar="OUT.json", help="also write every figure as JSON")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    os.environ.setdefault("BONDC_CACHE_DIR", tempfile.mkdtemp(prefix="bondc-bench-cache-"))
    repeat = 2 if args.quick else 3
    sizes = (10, 100, 1000) if args.quick else (10, 100, 1000, 3000, 10000)

    print("compile scaling (N-section chain: parse .. loaded C library)", file=sys.stderr, flush=True)
    scaling = compile_scaling(sizes)
    print("simulation against hand-written scipy code", file=sys.stderr, flush=True)
    rounds = 3 if args.quick else 5     # a run of either side takes 0.01-0.6 s: rounds are cheap
    relief, relief_process = simulate_pump_relief(rounds)
    simulations = [simulate_flagship(rounds), relief, simulate_drive_radau(rounds), simulate_chain(100, rounds)]
    if not args.quick:
        simulations.append(simulate_chain(1000, rounds))
    print("startup", file=sys.stderr, flush=True)
    starts = startup(repeat)
    print("equations and linearize of a large model", file=sys.stderr, flush=True)
    analyses = analysis(100 if args.quick else 1000)

    print("\n## Compile scaling\n")
    stages = list(next(row for row in scaling["rows"] if "error" not in row)["stages"])
    print("| N | states | " + " | ".join(stages) + " | total s | peak MB |")
    print("|" + " --- |" * (len(stages) + 4))
    for row in scaling["rows"]:
        if "error" in row:
            print(f"| {row['n']} | failed: {row['error']} |")
            continue
        print(f"| {row['n']} | {row['states']} | " + " | ".join(f"{row['stages'][s]:.2f}" for s in stages)
              + f" | {row['total']:.2f} | {row['peak_mb']:.0f} |")
    exponent = scaling["exponent"]
    print(f"\nfitted exponent (time ~ N^k, largest sizes): k = {exponent:.2f}" if exponent else "")
    print("\n## Simulation (bondc / hand-written scipy, same tolerances, best of runs)\n")
    print("| benchmark | bondc solver | hand s | bondc s | ratio | bondc s, every variable read | ratio "
          "| bondc numpy-code s | nfev hand / bondc | njev hand / bondc | max difference |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for row in simulations:
        print(f"| {row['benchmark']} | {row['solver']} | {row['hand_s']:.3f} | {row['bondc_s']:.3f} | {row['ratio']:.2f} | "
              f"{row['bondc_read_s']:.3f} | {row['ratio_read']:.2f} | "
              f"{row['bondc_numpy_s']:.3f} | {row['hand_nfev']} / {row['bondc_nfev']} | "
              f"{row['hand_njev']} / {row['bondc_njev']} | {row['difference']:.1e} |")
    print("\n## The pump/relief circuit, whole process (cached `bondc simulate -o out.csv` against "
          "`python -m benchmarks.hand.pump_relief`, alternating rounds)\n")
    print("| hand s | bondc s | ratio |")
    print("| --- | --- | --- |")
    print(f"| {relief_process['hand_s']:.2f} | {relief_process['bondc_s']:.2f} | {relief_process['ratio']:.2f} |")
    print("\n## Startup (whole process, best of runs)\n")
    print("| command | s |")
    print("| --- | --- |")
    for name, seconds in starts.items():
        print(f"| {name} | {seconds:.2f} |")
    print("\n## Equations and linearisation of a large model (whole process)\n")
    print("| command | s | peak MB |")
    print("| --- | --- | --- |")
    for name, row in analyses.items():
        peak = f"{row['peak_mb']:.0f}" if row["peak_mb"] is not None else "-"
        print(f"| {name} | {row['seconds']:.2f}{'' if row['ok'] else ' (failed)'} | {peak} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"scaling": scaling, "simulation": simulations,
                                               "pump_relief_process": relief_process, "startup": starts,
                                               "analysis": analyses}, indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
