"""``bondc compile FILE --target c``: the model's C code and header, compiled here with bondc's
compiler discovery and called through cffi against the Python module, and embedded in a small C
program that integrates the mass-spring-damper against its closed form."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bondc.cli import main
from bondc.runtime import find_compiler

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"

compiler = find_compiler("c")[0]
needs_compiler = pytest.mark.skipif(compiler is None, reason="no C compiler")


def export(tmp_path, model, *extra):
    folder = tmp_path / "c"
    assert main(["compile", str(MODELS / model), "--target", "c", "-o", str(folder), "-q", *extra]) == 0
    return folder


def test_the_c_code_is_byte_identical_on_a_rerun(tmp_path):
    first = export(tmp_path, "electro_pneumatic_hybrid.bg")
    texts = {path.name: path.read_bytes() for path in first.iterdir()}
    assert sorted(texts) == ["ElectroPneumaticHybrid.c", "ElectroPneumaticHybrid.h"]
    again = export(tmp_path, "electro_pneumatic_hybrid.bg")
    assert {path.name: path.read_bytes() for path in again.iterdir()} == texts
    header = texts["ElectroPneumaticHybrid.h"].decode()
    # the documented interface: sizes, names with units, the functions
    assert "#define BONDC_N_STATES 6" in header and "#define BONDC_N_SWITCHES 9" in header
    assert "chamber.P [Pa]" in header and "void bondc_jac(" in header and "bondc_jacobian_rows" in header


def _build(folder: Path, name: str, sources=(), flags=()) -> Path:
    library = folder / f"lib{name}.so"
    command = [*compiler.command, "-O2", "-fPIC", "-shared", "-I", str(folder), "-o", str(library),
               str(folder / f"{name}.c"), *map(str, sources), *flags, "-lm"]
    subprocess.run(command, check=True, capture_output=True, text=True)
    return library


@needs_compiler
@pytest.mark.parametrize("model, name", [("electro_pneumatic_hybrid.bg", "ElectroPneumaticHybrid"),
                                         ("quarter_car.bg", "QuarterCar")])
def test_the_c_functions_equal_the_python_module(tmp_path, model, name):
    """rhs, Jacobian, switching functions and outputs of the C code, called through cffi, equal the
    generated Python module's at random points (their modes: the unfrozen law's there)."""
    import cffi

    from bondc.pipeline import compile_file

    folder = export(tmp_path, model)
    library = _build(folder, name)
    ffi = cffi.FFI()
    signature = "(double t, const double *x, const double *p, const double *m, double *out);"
    ffi.cdef("".join(f"void {f}{signature}\n" for f in ("bondc_rhs", "bondc_jac", "bondc_switches", "bondc_outputs"))
             + "void bondc_x0(const double *p, double *x);\n")
    lib = ffi.dlopen(str(library))
    module_path = tmp_path / "module.py"
    compile_file(MODELS / model, module_path)
    namespace: dict = {"__file__": str(module_path)}
    exec(compile(module_path.read_text(), str(module_path), "exec"), namespace)  # noqa: S102  (bondc's own output)
    p = np.array(list(namespace["PARAMETERS"].values()), dtype=float)
    n, switches, outputs = len(namespace["STATE_NAMES"]), len(namespace["SWITCHES"]), len(namespace["OUTPUT_NAMES"])
    x0 = np.empty(n)
    lib.bondc_x0(ffi.from_buffer("double[]", p), ffi.from_buffer("double[]", x0))
    assert np.allclose(x0, namespace["x0"](), rtol=1e-14, atol=0)
    rng = np.random.default_rng(7)
    buffer = lambda a: ffi.from_buffer("double[]", a)       # noqa: E731
    for _ in range(5):
        t = float(rng.uniform(0, 3))
        x = x0 + rng.normal(size=n) * np.maximum(np.abs(x0), 1e-3) * 0.1
        m = np.asarray(namespace["modes"](t, x), dtype=float)
        rhs, jac = np.empty(n), np.empty(len(namespace["JACOBIAN_PATTERN"]))
        g, out = np.empty(max(switches, 1)), np.empty(outputs)
        for function, into in (("bondc_rhs", rhs), ("bondc_jac", jac), ("bondc_switches", g), ("bondc_outputs", out)):
            getattr(lib, function)(t, buffer(x), buffer(p), buffer(m if switches else np.zeros(1)), buffer(into))
        model = namespace["_MODEL"]
        assert np.allclose(rhs, model.rhs(t, x, p, m), rtol=1e-12, atol=1e-12 * np.abs(rhs).max())
        dense = np.asarray(model.jac(t, x, p, m), dtype=float)
        assert np.allclose(jac, [dense[i, j] for i, j in namespace["JACOBIAN_PATTERN"]], rtol=1e-10, atol=1e-12)
        if switches:
            assert np.allclose(g[:switches], model.switches(t, x, p, m), rtol=1e-12, atol=1e-15)
        assert np.allclose(out, namespace["outputs"](t, x), rtol=1e-12, atol=1e-12)


EMBED = r"""
#include <math.h>
#include <stdio.h>
#include "MassSpringDamper.h"

/* explicit RK4 with the modes taken at each step's middle (the force step lies on a step boundary) */
int main(void)
{
    double p[BONDC_N_P], x[BONDC_N_STATES], m[BONDC_N_SWITCHES], g[BONDC_N_SWITCHES], y[BONDC_N_OUTPUTS];
    double k1[BONDC_N_STATES], k2[BONDC_N_STATES], k3[BONDC_N_STATES], k4[BONDC_N_STATES], s[BONDC_N_STATES];
    for (int i = 0; i < BONDC_N_PARAMETERS; i++) p[i] = bondc_parameters[i].value;
    bondc_derive_parameters(p);
    bondc_x0(p, x);
    const double h = 1e-4;
    for (int step = 0; step < 10000; step++) {
        double t = step * h;
        for (int k = 0; k < BONDC_N_SWITCHES; k++) m[k] = 1.0;
        bondc_switches(t + 0.5 * h, x, p, m, g);
        for (int k = 0; k < BONDC_N_SWITCHES; k++) m[k] = g[k] > 0 ? 1.0 : (g[k] < 0 ? -1.0 : 0.0);
        bondc_rhs(t, x, p, m, k1);
        for (int i = 0; i < BONDC_N_STATES; i++) s[i] = x[i] + 0.5 * h * k1[i];
        bondc_rhs(t + 0.5 * h, s, p, m, k2);
        for (int i = 0; i < BONDC_N_STATES; i++) s[i] = x[i] + 0.5 * h * k2[i];
        bondc_rhs(t + 0.5 * h, s, p, m, k3);
        for (int i = 0; i < BONDC_N_STATES; i++) s[i] = x[i] + h * k3[i];
        bondc_rhs(t + h, s, p, m, k4);
        for (int i = 0; i < BONDC_N_STATES; i++) x[i] += h / 6.0 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i]);
        if ((step + 1) % 1000 == 0) {
            bondc_outputs(t + h, x, p, m, y);
            printf("%.17g %.17g\n", t + h, y[0]);
        }
    }
    return 0;
}
"""


@needs_compiler
def test_a_c_program_integrates_the_exported_mass_spring_damper_to_its_closed_form(tmp_path):
    folder = export(tmp_path, "mass_spring_damper.bg")
    (folder / "main.c").write_text(EMBED)
    program = folder / "msd"
    subprocess.run([*compiler.command, "-O2", "-I", str(folder), "-o", str(program), str(folder / "main.c"),
                    str(folder / "MassSpringDamper.c"), "-lm"], check=True, capture_output=True, text=True)
    rows = [line.split() for line in subprocess.run([str(program)], check=True, capture_output=True,
                                                    text=True).stdout.splitlines()]
    assert len(rows) == 10
    # m x'' + b x' + k x = F0 step(t - t_step), from rest (the model's documented numbers)
    m, k, b, f0, t_step = 2.0, 800.0, 12.0, 10.0, 0.1
    wn, zeta = math.sqrt(k / m), b / (2 * math.sqrt(k * m))
    wd = wn * math.sqrt(1 - zeta ** 2)
    for t, x in ((float(a), float(c)) for a, c in rows):
        tau = t - t_step
        exact = f0 / k * (1 - math.exp(-zeta * wn * tau) * (math.cos(wd * tau) + zeta * wn / wd * math.sin(wd * tau)))
        assert x == pytest.approx(exact, abs=1e-9 * f0 / k * 1e3)


def test_a_measured_signal_has_no_c_form(tmp_path, capsys):
    model = ROOT / "tests" / "fixtures" / "external" / "rc_csv.bg"
    assert main(["compile", str(model), "--target", "c", "-o", str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err
    assert "error[E840]" in err and "rc_csv.bg:5:" in err
    assert not (tmp_path / "c").exists()
