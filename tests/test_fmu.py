"""``bondc fmu``: FMUs checked with a real importer, FMPy. Each FMU is validated by
``fmpy.validation.validate_fmu`` and simulated by ``fmpy.simulate_fmu``; every output must match
``bondc simulate`` (the Python API) within 1e-3 of its range. The FMUs are built once per module."""

from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import bondc
from bondc.cli import main
from bondc.runtime import _sundials_link, find_compiler

fmpy = pytest.importorskip("fmpy")
from fmpy import simulate_fmu  # noqa: E402
from scipy.optimize import brentq  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"
EXTERNAL = ROOT / "tests" / "fixtures" / "external" / "msd_external.bg"
ENGINE = ROOT / "tests" / "fixtures" / "engine"

pytestmark = pytest.mark.skipif(find_compiler("c")[0] is None or _sundials_link() is None,
                                reason="an FMU needs a C compiler and scikit-sundae's SUNDIALS libraries")

#: (name, model file, bondc fmu options)
BUILDS = {
    "msd": (MODELS / "mass_spring_damper.bg", []),
    "rlc": (MODELS / "series_rlc.bg", []),
    "motor": (MODELS / "dc_motor_gear.bg", []),
    "compliant": (MODELS / "dc_motor_gear_compliant.bg", []),
    "car": (MODELS / "quarter_car.bg", []),
    "msd_me": (MODELS / "mass_spring_damper.bg", ["--kind", "me"]),
    "rlc_me": (MODELS / "series_rlc.bg", ["--kind", "me"]),
    "msd_fmi3": (MODELS / "mass_spring_damper.bg", ["--fmi", "3"]),
    "motor_fmi3": (MODELS / "dc_motor_gear.bg", ["--fmi", "3"]),
    "msd_me_fmi3": (MODELS / "mass_spring_damper.bg", ["--fmi", "3", "--kind", "me"]),
    "ball_me_fmi3": (ENGINE / "bouncing_ball.bg", ["--fmi", "3", "--kind", "me"]),
    "ball": (ENGINE / "bouncing_ball.bg", []),
    "ball_me": (ENGINE / "bouncing_ball.bg", ["--kind", "me"]),
    "thermostat": (ENGINE / "thermostat.bg", []),
    "external": (EXTERNAL, []),
    "external_me": (EXTERNAL, ["--kind", "me"]),
    "relay": (ROOT / "tests" / "fixtures" / "external" / "relay_external.bg", []),
    "flagship": (MODELS / "electro_pneumatic_hybrid.bg", []),
    "flagship_components": (MODELS / "electro_pneumatic_hybrid_components.bg", []),
    "flagship_fmi3": (MODELS / "electro_pneumatic_hybrid.bg", ["--fmi", "3"]),
}


#: the FMUs `make test-fast` builds (one of each kind); the tests of the others are marked slow
FAST = {"msd", "msd_me", "msd_fmi3", "msd_me_fmi3", "ball", "external", "motor"}


def _fast(*cases):
    """pytest params of cases whose first item names a build: slow unless it is in FAST."""
    return [pytest.param(*case, marks=[] if case[0] in FAST else [pytest.mark.slow]) for case in cases]


class _Builds(dict):
    """The FMUs of BUILDS, each built on first use (once per test process)."""

    def __init__(self, folder):
        super().__init__()
        self.folder = folder

    def __missing__(self, name):
        model, options = BUILDS[name]
        path = self.folder / f"{name}.fmu"
        assert main(["fmu", str(model), "-o", str(path), "-q", *options]) == 0
        self[name] = path
        return path


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return _Builds(tmp_path_factory.mktemp("fmus"))


@pytest.mark.parametrize("name", _fast(*((name,) for name in sorted(BUILDS))))
def test_fmpy_validates_every_fmu(fmus, name):
    problems = validate_fmu(str(fmus[name]))
    print(f"validate_fmu({name}.fmu): {problems}")
    assert problems == []


def _compare(result, sim, names=None):
    """The largest deviation of the FMU's outputs from bondc's over their range (bondc's run
    interpolated at the FMU's times: a grid of its own where they coincide)."""
    t = result["time"]
    worst = {}
    for name in names or result.dtype.names[1:]:
        reference = np.interp(t, np.asarray(sim["t"]), np.asarray(sim[name], dtype=float))
        span = float(np.ptp(reference)) or 1.0
        worst[name] = float(np.max(np.abs(result[name] - reference))) / span
    return worst


@pytest.mark.parametrize("name, model, overrides", _fast(
    ("msd", "mass_spring_damper.bg", {}),
    ("rlc", "series_rlc.bg", {}),
    ("motor", "dc_motor_gear.bg", {}),
    ("compliant", "dc_motor_gear_compliant.bg", {}),
    ("car", "quarter_car.bg", {}),
    ("ball", ENGINE / "bouncing_ball.bg", {}),
    ("thermostat", ENGINE / "thermostat.bg", {}),
    ("msd_fmi3", "mass_spring_damper.bg", {}),
    ("motor_fmi3", "dc_motor_gear.bg", {}),
    ("msd", "mass_spring_damper.bg", {"k": 1600.0, "m": 3.0}),
    ("motor", "dc_motor_gear.bg", {"J_L": 0.02, "t_on": 0.02}),
    # the friction sticks and breaks away (Filippov sliding modes held by the engine inside)
    ("flagship", "electro_pneumatic_hybrid.bg", {}),
    ("flagship", "electro_pneumatic_hybrid.bg", {"M": 45.0}),
    ("flagship_components", "electro_pneumatic_hybrid_components.bg", {}),
    ("flagship_fmi3", "electro_pneumatic_hybrid.bg", {}),
))
def test_co_simulation_matches_bondc_simulate(fmus, name, model, overrides):
    """FMPy's run of the Co-Simulation FMU (start_values for the parameter changes, in SI) against
    bondc's with the same parameters (overrides, as --set NAME=VALUE [SI unit]), on the same output
    grid."""
    result = simulate_fmu(str(fmus[name]), start_values=dict(overrides))
    t = result["time"]
    units = {"t_on": "s", "J_L": "kg*m^2", "k": "N/m", "m": "kg", "M": "kg"}
    given = {key: (value, units[key]) for key, value in overrides.items()}
    sim = bondc.simulate(MODELS / model, overrides=given or None, dt=float(t[1] - t[0]))
    if name in ("ball", "thermostat"):      # when clauses fired: impacts, the relay switching
        assert len(sim.result.events) >= 4
    assert np.array_equal(np.asarray(sim["t"]), t)      # the same grid: no interpolation
    worst = _compare(result, sim)
    print(f"{name} {overrides}: max deviation / range = {max(worst.values()):.2e} ({worst})")
    assert max(worst.values()) < 1e-3


def test_a_parameter_change_changes_the_answer(fmus):
    """(the comparison above can fail: a stiffer spring settles at half the deflection)"""
    stiff = simulate_fmu(str(fmus["msd"]), start_values={"k": 1600.0})
    plain = simulate_fmu(str(fmus["msd"]))
    assert stiff["x"][-1] == pytest.approx(10 / 1600, rel=2e-2)
    assert plain["x"][-1] == pytest.approx(10 / 800, rel=2e-2)


@pytest.mark.parametrize("name, model", _fast(("msd_me", "mass_spring_damper.bg"), ("rlc_me", "series_rlc.bg"),
                                             ("ball_me", ENGINE / "bouncing_ball.bg"),
                                             ("msd_me_fmi3", "mass_spring_damper.bg"),
                                             ("ball_me_fmi3", ENGINE / "bouncing_ball.bg")))
def test_model_exchange_matches_bondc_simulate(fmus, name, model):
    """FMPy integrates the Model Exchange FMU (its CVODE, the switches as event indicators, the
    bouncing ball's impacts as when clauses that change the state at an event)."""
    result = simulate_fmu(str(fmus[name]))
    # FMPy's grid has each event twice (before and after it): compared off the events, with bondc's
    # run on a grid ten times as fine
    t = result["time"]
    step = float(np.median(np.diff(t)))
    at_event = np.zeros(t.size, dtype=bool)
    at_event[1:] |= t[1:] == t[:-1]
    at_event[:-1] |= t[1:] == t[:-1]
    sim = bondc.simulate(MODELS / model, dt=step / 10)
    worst = _compare(result[~at_event], sim)
    print(f"{name}: max deviation / range = {max(worst.values()):.2e} ({worst})")
    assert max(worst.values()) < 1e-3


@pytest.mark.parametrize("name", _fast(("external",), ("external_me",)))
def test_an_external_input_from_fmpy_matches_the_same_signal_from_a_csv(fmus, name, tmp_path):
    """FMPy feeds the external input F_ext (steps at communication points, held between them: what a
    co-simulation master does); bondc reads the same samples from a CSV (--input F_ext=FILE.csv)."""
    from bondc.pipeline import derive_file
    from bondc.simulate import read_input_files, simulate

    times = [0.0, 0.1, 0.1, 0.5, 0.5, 1.0]
    values = [0.0, 0.0, 25.0, 25.0, -10.0, -10.0]
    signal = np.array(list(zip(times, values)), dtype=[("time", float), ("F_ext", float)])
    result = simulate_fmu(str(fmus[name]), input=signal, stop_time=1.0, output_interval=0.01)
    csv = tmp_path / "force.csv"
    csv.write_text("t [s],F_ext [N]\n" + "".join(f"{t!r},{v!r}\n" for t, v in zip(times, values)))
    derived = derive_file(EXTERNAL)
    inputs = read_input_files(derived.state_space, [f"F_ext={csv}"])
    sim = simulate(derived.state_space, derived.experiment, t_end=1.0, dt=1e-3, inputs=inputs)
    worst = _compare(result, {"t": sim.t, "x": sim.outputs["x"]}, ["x"])
    print(f"{name}: max deviation / range = {worst['x']:.2e}")
    assert worst["x"] < 1e-3
    # the force moved the mass: 25 N on 800 N/m (overshooting 25/800), then -10 N
    assert np.max(result["x"]) > 25 / 800 and np.min(result["x"]) < -10 / 800


def test_an_fmu_is_byte_identical_when_built_again(fmus, tmp_path):
    again = tmp_path / "again.fmu"
    assert main(["fmu", str(MODELS / "mass_spring_damper.bg"), "-o", str(again), "-q"]) == 0
    assert again.read_bytes() == fmus["msd"].read_bytes()


def test_the_fmu_is_self_contained(fmus):
    """The binary finds SUNDIALS beside it ($ORIGIN); everything it needs besides the C library is
    in the FMU; the model description has every parameter, state, input and output."""
    with zipfile.ZipFile(fmus["external"]) as archive:
        names = set(archive.namelist())
        description = archive.read("modelDescription.xml").decode()
        binary = archive.read("binaries/linux64/MassSpringDamper.so")
    assert {info for info in names if info.startswith("binaries/linux64/libsundials_core")}
    assert b"$ORIGIN" in binary
    assert 'name="F_ext"' in description and 'causality="input"' in description and 'start="25.0"' in description
    assert 'name="k"' in description and 'causality="parameter" variability="tunable"' in description
    assert 'name="spring.q"' in description and 'name="der(spring.q)"' in description
    assert 'causality="output"' in description and '<Unit name="N/m">' in description
    # values in SI; a unit the model shows otherwise is the display unit (display = factor * SI)
    with zipfile.ZipFile(fmus["motor"]) as archive:
        motor = archive.read("modelDescription.xml").decode()
    assert '<DisplayUnit name="ms" factor="1000.0"/>' in motor and 'name="t_on"' in motor
    assert re.search(r'name="speed_rpm".*\n\s*<Real unit="rad/s" displayUnit="rpm"/>', motor)
    assert '<DefaultExperiment startTime="0.0" stopTime="0.3" tolerance="1e-08"/>' in motor


CHILD = r"""
import importlib.abc, sys
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("bondc", "sksundae", "cffi", "ziglang"):
            raise ImportError(f"{name} is hidden from this process")
        return None
sys.meta_path.insert(0, Refuse())
try:
    import bondc
except ImportError:
    pass
else:
    raise SystemExit("bondc could be imported")
from fmpy import simulate_fmu
result = simulate_fmu(sys.argv[1], start_values={"k": 1600.0})
print(repr(float(result["x"][-1])), len(result))
"""


def test_an_fmu_runs_where_bondc_cannot_be_imported(fmus, tmp_path):
    """A fresh, isolated Python (-I: no user site, no PYTHONPATH, no current folder) that refuses to
    import bondc, scikit-sundae, cffi or zig, with no compiler on PATH and an empty bondc cache
    folder, runs the FMU copied elsewhere."""
    fmu = tmp_path / "elsewhere" / "msd.fmu"
    fmu.parent.mkdir()
    fmu.write_bytes(fmus["msd"].read_bytes())
    (tmp_path / "empty").mkdir()
    env = {"PATH": str(tmp_path / "empty"), "HOME": str(tmp_path), "BONDC_CACHE_DIR": str(tmp_path / "empty"),
           "LANG": "C"}
    done = subprocess.run([sys.executable, "-I", "-c", CHILD, str(fmu)], capture_output=True, text=True, env=env,
                          cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    final, points = done.stdout.split()
    assert float(final) == pytest.approx(10 / 1600, rel=2e-2) and int(points) > 100


@pytest.mark.parametrize("model", ["electro_pneumatic_hybrid.bg", "electro_pneumatic_hybrid_components.bg"])
def test_the_flagship_as_model_exchange_is_refused_at_a_switch_that_may_slide(tmp_path, capsys, model):
    """The flagship's friction sticks (and its valve's switches cannot be shown not to slide): an
    importer's integrator cannot hold it there, so the Model Exchange build stops before compiling,
    at the valve's law, with notes at the others (the friction's)."""
    output = tmp_path / "flagship.fmu"
    assert main(["fmu", str(MODELS / model), "--kind", "me", "-o", str(output)]) == 1
    err = capsys.readouterr().err
    assert "error[E841]" in err and "more switches like it" in err and "may slide too: sign(friction.f)" in err
    assert "--kind cs" in err
    # at a law: the model's (the flagship), or the library component's it instantiates (std:pneumatics)
    assert re.match(r"\S+:\d+:\d+: error\[E841\]", err.splitlines()[0])
    assert not output.exists()


SLIDE = ("model Slide\n  param M = 1 [kg]\n  param F_c = 2 [N]\n  param A = 3 [N]\n"
         "  Se push : e = A*sin(6.283185307179586*t)\n"
         "  I block : f = p/M\n  R friction : e = F_c*sign(f)\n  1 j\n  push -> j\n  j -> block\n"
         "  j -> friction\n  output v [m/s] = block.f\n  output F [N] = friction.e\n"
         "  experiment run\n    t_end = 2 [s]\n  end\nend\n")


def test_a_coulomb_friction_is_refused_at_its_law_in_model_exchange(tmp_path, capsys):
    model = tmp_path / "slide.bg"
    model.write_text(SLIDE)
    assert main(["fmu", str(model), "--kind", "me", "--json"]) == 1
    err = capsys.readouterr().err
    assert "error[E841]" in err and "slide.bg:7:" in err


def test_a_block_that_sticks_and_slips_in_co_simulation_holds_against_the_closed_form(tmp_path):
    """A 1 kg block pushed by 3 sin(2 pi t) N against a 2 N dry friction: it sticks while
    |push| <= 2 N (the friction force equals the push there: Filippov), slides from
    t1 = asin(2/3)/(2 pi) with dv/dt = 3 sin(2 pi t) - 2 until v returns to 0, then sticks again.
    The FMU's run (FMPy) against that closed form: the velocity, and the force while it sticks."""
    model = tmp_path / "slide.bg"
    model.write_text(SLIDE)
    fmu = tmp_path / "slide.fmu"
    assert main(["fmu", str(model), "-o", str(fmu), "-q"]) == 0
    result = simulate_fmu(str(fmu), stop_time=1.0, output_interval=1e-3)
    t, v, force = result["time"], result["v"], result["F"]
    w = 2 * np.pi
    t1 = np.arcsin(2 / 3) / w

    def velocity(tt):      # the slide from t1: v = (3/w)(cos(w t1) - cos(w t)) - 2 (t - t1)
        return (3 / w) * (np.cos(w * t1) - np.cos(w * tt)) - 2 * (tt - t1)

    t2 = brentq(velocity, 0.3, 0.9)
    assert t2 < t1 + 0.5        # it sticks again before the push passes -2 N: the next half mirrors it
    first = (t > t1) & (t < t2)
    second = (t > t1 + 0.5) & (t < t2 + 0.5)
    expected = np.where(first, velocity(np.clip(t, t1, t2)),
                        np.where(second, -velocity(np.clip(t - 0.5, t1, t2)), 0.0))
    assert np.max(np.abs(v - expected)) < 1e-4 * np.ptp(expected)
    stuck = ~((t > t1 - 1e-3) & (t < t2 + 1e-3)) & ~((t > t1 + 0.5 - 1e-3) & (t < t2 + 0.5 + 1e-3))
    assert stuck.sum() > 100
    assert np.max(np.abs(force[stuck] - 3 * np.sin(w * t[stuck]))) < 1e-6


def test_a_tunable_parameter_changed_during_the_run_takes_effect_from_there(fmus):
    """k set from 800 to 1600 N/m at t = 1 s, between two communication steps: the run goes on from
    its state with the stiffer spring and settles at F0/k = 10/1600 m (it was at 10/800 before)."""
    changed = []

    def stiffen(time, recorder):
        if time >= 1.0 and not changed:
            recorder.fmu.setReal([1], [1600.0])     # value reference 1: k (modelDescription.xml)
            changed.append(time)
        return True

    result = simulate_fmu(str(fmus["msd"]), stop_time=4.0, step_finished=stiffen)
    t, x = result["time"], result["x"]
    assert changed
    assert x[np.searchsorted(t, 0.99)] == pytest.approx(10 / 800, rel=0.02)
    assert x[-1] == pytest.approx(10 / 1600, rel=0.002)
    # from its state at the change, m x'' + b x' + k x = F0 with the new k (scipy, an independent solver)
    from scipy.integrate import solve_ivp

    i = int(np.searchsorted(t, changed[0]))
    m, b, k, f0 = 2.0, 12.0, 1600.0, 10.0
    after = solve_ivp(lambda _, y: [y[1], (f0 - b * y[1] - k * y[0]) / m], (t[i], t[-1]), [x[i], result["v"][i]],
                      t_eval=t[i:], rtol=1e-10, atol=1e-13)
    deviation = np.max(np.abs(after.y[0] - x[i:])) / np.ptp(x)
    print(f"k changed at t = {changed[0]:g}: max deviation / range = {deviation:.2e}")
    assert deviation < 1e-3


DIVIDER = """model Divider "a voltage step on two resistors: no state, an algebraic loop solved in C"
  param R1 = 1000 [Ohm]
  param R2 = 3000 [Ohm]
  input u [V] = step(t, 0.5)*10
  Se supply : e = u
  R  r1 : e = R1*f
  R  r2 : e = R2*f
  1  j
  supply -> j
  j -> r1
  j -> r2
  output i [A] = r1.f
  experiment run
    t_end = 1 [s]
  end
end
"""


@pytest.mark.parametrize("kind", ["cs", "me"])
def test_a_model_without_states_exports(tmp_path, kind):
    model = tmp_path / "divider.bg"
    model.write_text(DIVIDER)
    fmu = tmp_path / "divider.fmu"
    assert main(["fmu", str(model), "-o", str(fmu), "-q", "--kind", kind]) == 0
    assert validate_fmu(str(fmu)) == []
    result = simulate_fmu(str(fmu))
    t, i = result["time"], result["i"]
    # Ohm's law: 10 V over 4 kOhm from t = 0.5 s on
    assert np.allclose(i[t < 0.499], 0.0) and np.allclose(i[t > 0.501], 10 / 4000, rtol=1e-12)


def test_fmu_json_says_what_it_wrote(tmp_path, capsys):
    import json

    output = tmp_path / "msd.fmu"
    assert main(["fmu", str(MODELS / "mass_spring_damper.bg"), "--kind", "me", "-o", str(output), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["complete"] and summary["written"] == [str(output)] and output.exists()
    assert (summary["fmi"], summary["kind"], summary["platforms"]) == (2, "me", ["linux64"])
    assert (summary["states"], summary["parameters"], summary["outputs"], summary["event_indicators"]) == (2, 5, 3, 1)


@pytest.mark.slow
def test_a_switch_on_an_external_input_switches_inside_the_fmu(fmus):
    """The relay's source switches on the host's command (cmd > 0.5), a step from 0 to 1 at t0 = 2 ms:
    i(t) = U/R (1 - exp(-(t - t0) R/L)) after it (U = 12 V, R = 2 Ohm, L = 1 mH)."""
    signal = np.array([(0.0, 0.0), (0.002, 0.0), (0.002, 1.0), (0.01, 1.0)], dtype=[("time", float), ("cmd", float)])
    result = simulate_fmu(str(fmus["relay"]), input=signal, stop_time=0.01, output_interval=1e-4)
    t = result["time"]
    expected = np.where(t > 0.002, 6.0 * (1 - np.exp(-(t - 0.002) * 2000.0)), 0.0)
    assert np.max(np.abs(result["i"] - expected)) < 1e-3 * 6.0


@pytest.mark.slow
def test_an_fmus_when_clause_whose_firings_accumulate_stops_at_the_zeno_time(tmp_path):
    """The ball of bouncing_ball.bg run to 6 s as a Co-Simulation FMU: past t_inf = t1 +
    (2*v1/g)*e/(1 - e) its impacts accumulate. The FMU's engine runs the test bondc simulate runs
    (events.c's bondc_zeno), so doStep fails there, saying where the impacts accumulate (the closed
    form, as bondc simulate states it) and naming the when clause; the ball never falls through."""
    model = tmp_path / "ball.bg"
    model.write_text((ENGINE / "bouncing_ball.bg").read_text().replace("t_end = 3 [s]", "t_end = 6 [s]"))
    fmu = tmp_path / "ball.fmu"
    assert main(["fmu", str(model), "-o", str(fmu), "-q"]) == 0
    messages = []

    def logger(_environment, _instance, _status, _category, message):
        messages.append(message.decode() if isinstance(message, bytes) else str(message))

    with pytest.raises(Exception):
        simulate_fmu(str(fmu), stop_time=6.0, output_interval=0.01, logger=logger)
    said = [text for text in messages if "accumulate" in text]
    assert said, messages
    g, e, h0 = 9.81, 0.8, 1.0
    t1, v1 = np.sqrt(2 * h0 / g), np.sqrt(2 * g * h0)
    zeno = t1 + 2 * v1 / g * e / (1 - e)                                # 4.06371 s
    stated = float(said[0].split("accumulate at t=")[1].split()[0])
    assert stated == pytest.approx(zeno, rel=1e-5)
    assert "when h < 0" in said[0] and "Zeno" in said[0]
    # the same run to just before it: complete, the ball above the floor
    result = simulate_fmu(str(fmu), stop_time=4.0, output_interval=0.01)
    assert result["height"].min() > -1e-9 and result["time"][-1] == pytest.approx(4.0)
