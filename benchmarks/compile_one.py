"""One compile-scaling measurement, in a fresh process: ``python -m benchmarks.compile_one N``.

Writes the N-section chain (benchmarks/chain.py) to a temporary folder and takes
it from source to a loaded, compiled module, timing each stage; prints one JSON
object: the stage times in seconds, the total, and the process's peak resident
memory in MB. The garbage collector runs as under the command line
(``pipeline.fewer_collections``). Run in its own process so that the peak memory and sympy's caches
belong to this model alone; the compile cache is off and the C library is built
into an empty cache folder.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path


def measure(n: int) -> dict:
    folder = Path(tempfile.mkdtemp(prefix=f"bondc-chain{n}-"))
    os.environ["BONDC_CACHE_DIR"] = str(folder / "cache")
    os.environ["BONDC_CACHE"] = "0"
    from benchmarks.chain import chain_source

    path = folder / f"chain{n}.bg"
    path.write_text(chain_source(n), encoding="utf-8")
    stages = {}
    start = time.perf_counter()
    from bondc import semantic
    from bondc.causality import assign_causality
    from bondc.codegen import emit
    from bondc.equations import derive
    from bondc.runtime import load_native, native_text, start_native

    stages["import"] = time.perf_counter() - start
    mark = time.perf_counter()
    graph, _ = semantic.load(path, experiment=semantic.FIRST)
    stages["parse+check"] = time.perf_counter() - mark
    mark = time.perf_counter()
    causal = assign_causality(graph)
    stages["causality"] = time.perf_counter() - mark
    mark = time.perf_counter()
    state_space = derive(causal)
    stages["equations"] = time.perf_counter() - mark
    mark = time.perf_counter()
    source = emit(state_space, next(iter(graph.experiments.values())), module_dir=folder)
    stages["codegen"] = time.perf_counter() - mark
    mark = time.perf_counter()
    start_native(native_text(source))      # as bondc.simulate.compile_model does
    namespace = {"__name__": "chain", "__file__": str(folder / "chain_gen.py")}
    exec(compile(source, "chain_gen.py", "exec"), namespace)  # noqa: S102  (bondc's own generated module)
    ffi, lib = load_native(namespace["NATIVE_SOURCE"])
    stages["C build"] = time.perf_counter() - mark
    return {"n": n, "states": len(state_space.states), "stages": stages,
            "total": sum(stages.values()), "native": ffi is not None,
            "native_note": "" if ffi is not None else lib,
            "peak_mb": peak_kb() / 1024}


def peak_kb() -> int:
    """This process's peak resident memory in KiB: Linux's VmHWM, which starts afresh at exec
    (``ru_maxrss`` keeps the high-water mark of the parent forked into this process, a benchmark
    process of hundreds of MB); ``ru_maxrss`` elsewhere."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


if __name__ == "__main__":
    from bondc.pipeline import fewer_collections       # (light: bondc's own imports are timed in measure)

    with fewer_collections():       # as the command line runs
        print(json.dumps(measure(int(sys.argv[1]))))
