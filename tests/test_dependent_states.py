"""Dependent states: a storage element in derivative causality (the load inertia behind a rigid gear)
has no state of its own to integrate, yet its momentum is in the result, computed from the
independent states at every point.

The independent expectation is the gear's kinematics: for a rigid gear of ratio n (motor turns per
load turn) the load speed is w_m/n, so its momentum is J_L*w_m/n, with w_m = p_rotor/J_m from the
kept state. That closed form is checked in the csv, the DataFrame, the npz and the summary, with a
gear ratio other than the model's so that nothing holds only for the declared value.
"""

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

import bondc
from bondc.cli import main
from bondc.pipeline import simulate_file as run

ROOT = Path(__file__).resolve().parent.parent
GEAR = ROOT / "models" / "dc_motor_gear.bg"
J_M, J_L = 2.0e-5, 5.0e-3          # the model's rotor and load inertia, kg*m^2
N = 4.0                             # a gear ratio of the test's own (the model declares 10)


def expected_load_p(rotor_p):
    """J_L*w_L with w_L = w_m/n and w_m = p_rotor/J_m."""
    return J_L * (np.asarray(rotor_p) / J_M) / N


def close(actual, expected):
    scale = max(float(np.max(np.abs(expected))), 1e-30)
    return np.max(np.abs(np.asarray(actual) - expected)) <= 1e-9 * scale


@pytest.fixture(scope="module")
def sim():
    return bondc.simulate(GEAR, overrides={"n_gear": N}, t_end=0.05)


def test_dependent_state_in_the_result(sim):
    assert list(sim.states) == ["armature_L.p", "rotor.p"]          # the integrated states are unchanged
    assert list(sim.dependent_states) == ["load.p"]
    load_p = sim.dependent_states["load.p"]
    assert load_p.shape == sim.t.shape
    assert close(load_p, expected_load_p(sim.states["rotor.p"]))
    assert np.max(np.abs(load_p)) > 1e-3                             # the motor really turns the load
    assert sim["load.p"] is load_p
    # its flow is a bond variable already (b10, j_load -> load): the load speed, w_m/n
    assert close(sim["b10.f"], sim.states["rotor.p"] / J_M / N)
    assert sim.units["load.p"] == ("kg*m^2/s", 1.0)


def test_dependent_state_in_the_dataframe(sim):
    pytest.importorskip("pandas")
    frame = sim.to_dataframe()
    assert list(frame.columns)[-3:] == ["armature_L.p [kg*m^2/(s^2*A)]", "rotor.p [kg*m^2/s]", "load.p [kg*m^2/s]"]
    assert close(frame["load.p [kg*m^2/s]"].to_numpy(), expected_load_p(frame["rotor.p [kg*m^2/s]"].to_numpy()))


def test_dependent_state_in_the_csv_and_npz(tmp_path):
    out = tmp_path / "gear.csv"
    result = run(GEAR, sets=[f"n_gear={N}"], t_end=0.05, output=out)
    rows = list(csv.reader(io.StringIO(out.read_text())))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    assert header[-2:] == ["rotor.p [kg*m^2/s]", "load.p [kg*m^2/s]"]
    assert header.count("load.p [kg*m^2/s]") == 1
    assert data.shape[0] == result.t.size > 10
    assert close(data[:, header.index("load.p [kg*m^2/s]")], expected_load_p(data[:, header.index("rotor.p [kg*m^2/s]")]))

    npz = tmp_path / "gear.npz"
    run(GEAR, sets=[f"n_gear={N}"], t_end=0.05, output=npz)
    with np.load(npz) as arrays:
        assert "states/load.p" not in arrays.files
        assert close(arrays["dependent/load.p"], expected_load_p(arrays["states/rotor.p"]))


def test_dependent_state_in_the_json_summary(capsys):
    assert main(["simulate", str(GEAR), "--set", f"n_gear={N}", "--t-end", "0.05", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["states"] == ["armature_L.p", "rotor.p"]
    assert summary["dependent_states"] == ["load.p"]
    assert summary["final"]["load.p"] == pytest.approx(float(expected_load_p(summary["final"]["rotor.p"])), rel=1e-9)


def test_equations_mark_the_dependent_state(capsys):
    assert main(["equations", str(GEAR)]) == 0
    text = capsys.readouterr().out
    section = text.split("eliminated states (derivative causality)\n", 1)[1]
    assert section.splitlines()[0].strip() == "load.p = J_L*rotor.p/(J_m*n_gear)"
    assert "load.p" not in text.split("state equations", 1)[0].split("states", 1)[1].split("inputs", 1)[0]


def test_no_dependent_states_without_derivative_causality():
    sim = bondc.simulate(ROOT / "models" / "mass_spring_damper.bg", t_end=0.1)
    assert sim.dependent_states == {}
    assert list(sim.to_dataframe().columns)[-len(sim.states):] == [f"{n} [{sim.units[n][0]}]" for n in sim.states]
