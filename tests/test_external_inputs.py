"""External inputs (language reference section 15): ``input u [V] external = default``, a signal the
host running the model supplies -- a table or a function of t through the Python API, a CSV file
through ``bondc simulate --input`` -- and its default where nothing supplies it.

The expectations are independent of the implementation: the same circuit with the signal written
as ``csv(...)`` of the same file (which bondc already simulates), and closed forms of an RC
circuit (tau = R*C = 1 s) driven by a step and by a ramp.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import bondc
from bondc import cli
from bondc.errors import BondcError
from bondc.fmt import format_file
from bondc.parse import parse_text

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "external"
RC = FIXTURES / "rc_external.bg"            # input u [V] external (default 0), tau = 1 s
RC_CSV = FIXTURES / "rc_csv.bg"             # the same circuit, u = csv("drive.csv", "u")
MSD = FIXTURES / "msd_external.bg"          # input F_ext [N] external = 25
DRIVE = FIXTURES / "drive.csv"


def _drive() -> tuple[np.ndarray, np.ndarray]:
    rows = [line.split(",") for line in DRIVE.read_text().splitlines()[1:] if line.strip()]
    return np.array([float(r[0]) for r in rows]), np.array([float(r[1]) for r in rows])


# ------------------------------------------------------------------ language

def test_fmt_round_trip_keeps_external():
    text = ('model M\n  param V0 = 12 [V]\n  input u [V] external "supplied"\n  input F [N] external = 25\n'
            '  input w external = V0\n  param external = 3\nend\n')
    original = parse_text(text, "m.bg")
    inputs = [s for s in original.models[0].body if type(s).__name__ == "Input"]
    assert [(i.name, i.external, i.value is None) for i in inputs] == [("u", True, True), ("F", True, False),
                                                                       ("w", True, False)]
    formatted = format_file(original, text)
    assert "input u [V] external" in formatted and "input F [N] external = 25" in formatted
    again = parse_text(formatted, "m.bg")
    assert again == original
    assert format_file(again, formatted) == formatted


def test_default_must_be_constant():
    for default, what in (("t", "time 't'"), ("w", "input 'w'"), ("c.q", None)):
        text = (f"model M\n  input w [V] = 1\n  input u [V] external = {default}\n  Se s : e = u + w\n"
                f"  C c : e = q/1e-3\n  s -> c\nend\n")
        errors = bondc.check(text=text).errors
        assert [d.code for d in errors] == ["E344"], (default, errors)
        if what:
            assert what in errors[0].message


def test_default_is_checked_for_units():
    text = "model M\n  param R = 10 [Ohm]\n  input u [V] external = R\n  Se s : e = u\n  R r : e = R*f\n  s -> r\nend\n"
    assert [d.code for d in bondc.check(text=text).errors] == ["E210"]


def test_external_in_an_experiment_is_an_error():
    text = ("model M\n  input u [V] external = 1\n  Se s : e = u\n  R r : e = 10*f\n  s -> r\n"
            "  experiment run\n    t_end = 1\n    input u [V] external = 2\n  end\nend\n")
    assert [d.code for d in bondc.check(text=text).errors] == ["E345"]


def test_external_is_a_name_elsewhere():
    text = "model M\n  param external = 3 [V]\n  Se s : e = external\n  R r : e = 10*f\n  s -> r\nend\n"
    assert bondc.check(text=text).ok


def test_a_components_plain_input_is_not_external(tmp_path):
    lib = ("model Source\n  port a\n  input u [V]\n  input v [V] external = 2\n  Se s : e = u + v\n  s -> a\nend\n")
    top = ("model Top\n  Source src : u = 3\n  R r : e = 10*f\n  src.a -> r\n  output i [A] = r.f\nend\n")
    (tmp_path / "m.bg").write_text(lib + top)
    unbound = lib + top.replace("Source src : u = 3", "Source src")
    assert "E334" in [d.code for d in bondc.check(text=unbound, model="Top").errors]
    model = bondc.load(tmp_path / "m.bg", model="Top")
    # neither the component's plain input nor its external one is supplied by a host
    assert not any(s.external for s in model.graph.inputs.values())
    sim = bondc.simulate(tmp_path / "m.bg", model="Top", t_end=0.1)
    assert abs(float(sim["i"][-1]) - (3 + 2) / 10) < 1e-12       # the component's default: v = 2
    with pytest.raises(BondcError) as raised:
        bondc.simulate(tmp_path / "m.bg", model="Top", t_end=0.1, inputs={"src.v": ([0], [1])})
    assert raised.value.diagnostics[0].code == "E806"


def test_equations_and_linearisation_see_an_input():
    assert "u = external (default 0)" in bondc.equations(RC)
    lin = bondc.linearize(MSD)
    assert list(lin.inputs) == ["F_ext"]
    assert abs(float(lin.B[0][0]) - 1.0) < 1e-12            # der(mass.p) = F_ext - ...
    assert abs(float(lin.u0[0]) - 25.0) < 1e-12             # at its default


# ------------------------------------------------------------------ engine and host paths

def test_table_matches_the_same_data_as_csv(tmp_path):
    for name in ("rc_external.bg", "rc_csv.bg", "drive.csv"):
        shutil.copy(FIXTURES / name, tmp_path / name)
    times, values = _drive()
    external = bondc.simulate(tmp_path / "rc_external.bg", dt=0.01, inputs={"u": (times, values)})
    measured = bondc.simulate(tmp_path / "rc_csv.bg", dt=0.01)
    assert np.max(np.abs(external["v"] - measured["v"])) < 1e-9
    # the table's samples are known breaks, as a csv's are
    breaks = [time for time, label in external.result.events if "external input u" in label]
    assert breaks == pytest.approx([0.5, 0.7, 1.2, 1.5, 2.2])
    assert external.result.stats["external_inputs"] == "u: table"
    assert external.result.stats["code"] == "numpy" and "external input" in external.result.stats["code_note"]


def test_step_and_ramp_closed_forms():
    # a step of 10 V at t = 0: v = 10*(1 - exp(-t)); a ramp u = 4*t: v = 4*(t - 1 + exp(-t))
    step = bondc.simulate(RC, dt=0.05, inputs={"u": ([0.0], [10.0])})
    assert np.max(np.abs(step["v"] - 10 * (1 - np.exp(-step.t)))) < 1e-5
    for ramp in ({"u": ([0.0, 3.0], [0.0, 12.0])}, {"u": lambda t: 4.0 * t}):
        sim = bondc.simulate(RC, dt=0.05, inputs=ramp)
        assert np.max(np.abs(sim["v"] - 4 * (sim.t - 1 + np.exp(-sim.t)))) < 1e-5


def test_callable_and_table_agree():
    times = np.linspace(0.0, 3.0, 3001)
    table = bondc.simulate(RC, dt=0.05, inputs={"u": (times, 5 * np.sin(2 * times))})
    scalar_only = bondc.simulate(RC, dt=0.05, inputs={"u": lambda t: 5 * math.sin(2 * t)})
    assert np.max(np.abs(table["v"] - scalar_only["v"])) < 1e-4
    assert scalar_only.result.stats["external_inputs"] == "u: function"


def test_default_used_and_said_once(capsys):
    sim = bondc.simulate(MSD, t_end=3.0, dt=0.01)
    assert abs(float(sim["x"][-1]) - 25 / 800) < 1e-5            # F_ext = 25 N settles at F/k
    assert [d.code for d in sim.warnings] == ["I346"]
    assert sim.warnings[0].message == "input F_ext is external: nothing supplies it, so its default 25 N is used"
    assert [d.code for d in bondc.check(MSD).diagnostics] == ["I346"]
    assert cli.main(["check", str(RC)]) == 0
    err = capsys.readouterr().err
    assert err.count("I346") == 1
    assert "input u is external: nothing supplies it, so its default 0 V is used" in err
    assert cli.main(["simulate", str(RC), "--t-end", "0.1"]) == 0
    assert capsys.readouterr().err.count("I346") == 1
    supplied = bondc.simulate(MSD, t_end=0.1, inputs={"F_ext": lambda t: 0.0})
    assert not supplied.warnings and float(np.max(np.abs(supplied["x"]))) == 0.0


def test_cli_input_file_matches_csv(tmp_path, capsys):
    for name in ("rc_external.bg", "rc_csv.bg"):
        shutil.copy(FIXTURES / name, tmp_path / name)
    # the same signal in ms and mV: the header's units are converted as csv() converts them
    times, values = _drive()
    lines = ["time [ms],other,volts [mV]"] + [f"{t * 1000:g},7,{v * 1000:g}" for t, v in zip(times, values)]
    (tmp_path / "drive_mv.csv").write_text("\n".join(lines) + "\n")
    shutil.copy(DRIVE, tmp_path / "drive.csv")
    out_external, out_csv = tmp_path / "a.csv", tmp_path / "b.csv"
    assert cli.main(["simulate", str(tmp_path / "rc_external.bg"), "--dt", "0.01", "-o", str(out_external),
                     "--input", f"u={tmp_path / 'drive_mv.csv'}:volts"]) == 0
    assert "I346" not in capsys.readouterr().err
    assert cli.main(["simulate", str(tmp_path / "rc_csv.bg"), "--dt", "0.01", "-o", str(out_csv)]) == 0
    a = np.loadtxt(out_external, delimiter=",", skiprows=1)
    b = np.loadtxt(out_csv, delimiter=",", skiprows=1)
    assert a.shape == b.shape and np.max(np.abs(a - b)) < 1e-9
    # COLUMN defaults to the input's name
    assert cli.main(["simulate", str(tmp_path / "rc_external.bg"), "--dt", "0.01", "-o", str(out_external),
                     "--input", f"u={tmp_path / 'drive.csv'}"]) == 0
    assert np.max(np.abs(np.loadtxt(out_external, delimiter=",", skiprows=1) - b)) < 1e-9


@pytest.mark.parametrize("argument, code, words", [
    ("x=drive.csv", "E805", "no input 'x'"),
    ("w=drive.csv", "E806", "input 'w' is not external"),
    ("u=missing.csv", "E807", "no file 'missing.csv'"),
    ("u=drive.csv:volts", "E807", "no column 'volts'"),
    ("u", "E807", "NAME=FILE.csv[:COLUMN]"),
    ("u=bad.csv", "E807", "must not decrease"),
    ("u=force.csv", "E807", "not a unit of input 'u'"),
])
def test_cli_input_errors(tmp_path, monkeypatch, capsys, argument, code, words):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.bg").write_text(RC.read_text().replace("  Se supply : e = u\n",
                                                         "  input w [V] = 0\n  Se supply : e = u + w\n"))
    shutil.copy(DRIVE, tmp_path / "drive.csv")
    (tmp_path / "bad.csv").write_text("t,u\n0,1\n2,1\n1,1\n")
    (tmp_path / "force.csv").write_text("t,u [N]\n0,1\n1,1\n")
    status = cli.main(["simulate", "m.bg", "--t-end", "1", "--input", argument])
    err = capsys.readouterr().err
    assert status != 0
    assert f"error[{code}]" in err and words in err and "Traceback" not in err


@pytest.mark.parametrize("inputs, code", [
    ({"x": ([0], [1])}, "E805"),
    ({"u": ([0, 1], [1])}, "E807"),
    ({"u": ([0, 1], [1, float("nan")])}, "E807"),
    ({"u": ([1, 0], [1, 1])}, "E807"),
    ({"u": "drive.csv"}, "E807"),
    ({"u": lambda t: "ten"}, "E807"),
    ([("u", ([0], [1]))], "E807"),
])
def test_api_input_errors(inputs, code):
    with pytest.raises(BondcError) as raised:
        bondc.simulate(RC, t_end=0.5, inputs=inputs)
    assert raised.value.diagnostics[0].code == code


def test_compiled_module_takes_inputs(tmp_path):
    module = bondc.compile(RC, tmp_path / "rc_gen.py")
    namespace = {"__name__": "rc_gen", "__file__": str(module)}
    exec(compile(module.read_text(), str(module), "exec"), namespace)   # bondc's own generated module
    assert namespace["EXTERNAL_INPUT_NAMES"] == ("u",)
    step = namespace["simulate"](1.0, inputs={"u": ([0.0], [10.0])}, dt=0.5)
    assert abs(float(step.outputs["v"][-1]) - 10 * (1 - math.exp(-1))) < 1e-5
    default = namespace["simulate"](1.0, dt=0.5)        # a run never keeps the signals of the one before
    assert float(np.max(np.abs(default.outputs["v"]))) == 0.0
    # the first run's variables, read after the second, are those of its own signal
    assert float(step.variables["u"][-1]) == 10.0


RELAY = (Path(__file__).resolve().parent / "fixtures" / "external" / "relay_external.bg").read_text()


@pytest.mark.parametrize("given", ["table", "function"])
def test_a_switch_on_an_external_input_switches_where_the_signal_does(given):
    """A condition on an external input is a switch like any other (bondc derived it as a switch of
    time with a closed-form root, and differentiating the host's signal failed with E703). The
    command steps from 0 to 1 at t0 = 2 ms: i(t) = U/R (1 - exp(-(t - t0) R/L)) after it, 0 before."""
    U, R, L, t0 = 12.0, 2.0, 1e-3, 2e-3
    signal = (np.array([0.0, t0, t0, 0.01]), np.array([0.0, 0.0, 1.0, 1.0])) if given == "table" else \
        (lambda t: 1.0 if t >= t0 else 0.0)
    sim = bondc.simulate(text=RELAY, inputs={"cmd": signal}, dt=1e-4)
    t, i = np.asarray(sim["t"]), np.asarray(sim["i"])
    expected = np.where(t > t0, U / R * (1 - np.exp(-(t - t0) * R / L)), 0.0)
    np.testing.assert_allclose(i, expected, atol=1e-6 * U / R)
    assert any("cmd > 0.5" in label for _, label in sim.result.events)
