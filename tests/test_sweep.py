"""bondc.analysis.sweep: parameter grids on the mass-spring-damper and the flagship, checked analytically."""

from __future__ import annotations

import csv
import dataclasses
import doctest
import json
import math
from pathlib import Path

import pytest

from bondc.analysis import sweep
from bondc.analysis.sweep import MAX_RUNS, run_sweep
from bondc.errors import BondcError, UsageError

MODELS = Path(__file__).resolve().parent.parent / "models"
MSD = MODELS / "mass_spring_damper.bg"          # m = 2 kg, k = 800 N/m, b = 12 N*s/m, F0 = 10 N
FLAGSHIP = MODELS / "electro_pneumatic_hybrid.bg"
M, B, F0 = 2.0, 12.0, 10.0


def step_peak(k: float, m: float = M, b: float = B) -> float:
    """The first peak of x after a force step F0 on a mass-spring-damper from rest."""
    zeta = b / (2 * math.sqrt(k * m))
    return F0 / k * (1 + math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2)))


@pytest.fixture(scope="module")
def k_sweep():
    # the envelope decays as exp(-b/(2m) t) = exp(-3 t): settled to 1e-6 by t = 5 s
    return run_sweep(MSD, vary=["k=400,800,1600"], metrics=["x.final", "x.max", "energy.residual"], t_end=5.0)


@pytest.fixture(scope="module")
def grid():
    return run_sweep(MSD, vary=["k=0.4,0.8 [kN/m]", "b=6,12"], metrics=["x.max", "x.final"], t_end=3.0)


def test_static_deflection_is_f0_over_k(k_sweep):
    assert [point.status for point in k_sweep.points] == ["ok"] * 3
    for point, k in zip(k_sweep.points, (400.0, 800.0, 1600.0)):
        assert point.parameters == {"k": k}
        assert point.metrics["x.final"] == pytest.approx(F0 / k, rel=1e-5)


def test_peak_follows_the_step_response(k_sweep):
    peaks = k_sweep.column("x.max")
    for peak, k in zip(peaks, (400.0, 800.0, 1600.0)):
        # reported at the solver's steps (max_step 5 ms): the sampled peak is within 3e-4 of the true one
        assert peak == pytest.approx(step_peak(k), rel=1e-3)
    # stiffer spring, smaller peak: roughly 1/k, less so as the damping ratio falls
    assert peaks[0] / peaks[1] == pytest.approx(step_peak(400.0) / step_peak(800.0), rel=2e-3)
    assert peaks[0] > peaks[1] > peaks[2]


def test_energy_balance_closes(k_sweep):
    assert all(abs(residual) < 1e-6 for residual in k_sweep.column("energy.residual"))


def test_grid_rows_in_order_with_units(grid):
    assert len(grid.points) == 4
    assert [point.index for point in grid.points] == [0, 1, 2, 3]
    assert [point.values for point in grid.points] == [(0.4, 6.0), (0.4, 12.0), (0.8, 6.0), (0.8, 12.0)]
    # the values were given in kN/m: the runs used N/m
    assert [point.parameters for point in grid.points] == [
        {"k": 400.0, "b": 6.0}, {"k": 400.0, "b": 12.0}, {"k": 800.0, "b": 6.0}, {"k": 800.0, "b": 12.0}]
    for point in grid.points:
        k, b = point.parameters["k"], point.parameters["b"]
        assert point.metrics["x.max"] == pytest.approx(step_peak(k, b=b), rel=1e-3)
    assert all(point.path == "bound" for point in grid.points)     # late binding: one model, a vector per point
    assert grid.exit_code == 0

    text = grid.to_text()
    assert text.splitlines()[0] == "sweep of MassSpringDamper (step): 4 runs (2 x 2), all complete"
    header, *rows = text.splitlines()[2:7]
    assert header.split() == ["k", "[kN/m]", "b", "[N*s/m]", "x.max", "[m]", "x.final", "[m]", "status"]
    assert [row.split()[:2] for row in rows] == [["0.4", "6"], ["0.4", "12"], ["0.8", "6"], ["0.8", "12"]]


def _without_times(result):
    """A result with each point's wall time left out (a measurement, not a result)."""
    return dataclasses.replace(result, points=tuple(dataclasses.replace(p, wall_time=None) for p in result.points))


def test_jobs_two_gives_the_same_result(grid):
    parallel = run_sweep(MSD, vary=["k=0.4,0.8 [kN/m]", "b=6,12"], metrics=["x.max", "x.final"], t_end=3.0, jobs=2)
    assert _without_times(parallel).to_json() == _without_times(grid).to_json()
    assert _without_times(parallel).csv_text() == _without_times(grid).csv_text()
    assert all(p.wall_time > 0 for p in parallel.points)


def test_csv_and_json_files(tmp_path):
    csv_path, json_path = tmp_path / "sweep.csv", tmp_path / "sweep.json"
    result = run_sweep(MSD, vary=["k=400:1600:2"], metrics=["x.final"], t_end=5.0, output=csv_path)
    result.write(json_path)
    with open(csv_path, newline="") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["index", "k [N/m]", "x.final [m]", "status", "message", "wall_time [s]"]
    assert [row[:2] for row in rows[1:]] == [["0", "400.0"], ["1", "1600.0"]]
    assert float(rows[2][2]) == pytest.approx(F0 / 1600, rel=1e-5)
    assert [p.name for p in tmp_path.iterdir()] and not list(tmp_path.glob(".*.tmp"))
    data = json.loads(json_path.read_text())
    assert data["runs"] == 2 and data["failed"] == 0
    assert data["parameters"] == [{"name": "k", "vary": "k=400:1600:2", "unit": "N/m", "si_unit": "N/m",
                                   "values": [400.0, 1600.0]}]
    assert data["points"][1]["metrics"]["x.final"] == pytest.approx(F0 / 1600, rel=1e-5)


def test_a_failed_point_is_reported_and_the_others_computed():
    # m = 0: the mass law f = p/m divides by zero, E311 at the divisor as `check --set m=0` says,
    # whether the point is first (the file is checked with its values) or later (bound late)
    for order, failing in ((["m=2,0,1"], 1), (["m=0,2,1"], 0)):
        result = run_sweep(MSD, vary=order, metrics=["x.final"], t_end=5.0)
        assert [point.status == "ok" for point in result.points] == [k != failing for k in range(3)]
        failed = result.points[failing]
        assert failed.message == "E311: a division by zero: the divisor is 0 with m = 0"
        assert failed.metrics == {} and failed.parameters == {"m": 0.0}
    result = run_sweep(MSD, vary=["m=2,0,1"], metrics=["x.final"], t_end=5.0)
    for point in (result.points[0], result.points[2]):
        assert point.metrics["x.final"] == pytest.approx(F0 / 800, rel=1e-5)
    assert result.exit_code == 1
    [diagnostic] = result.diagnostics()
    assert diagnostic.code == "E311" and diagnostic.message.startswith("point 1 (m=0 kg): a division by zero")
    assert (diagnostic.span.line, diagnostic.span.column) == (29, 74)          # the m of f = p/m
    text = result.to_text()
    assert "3 runs, 2 ok, 1 failed" in text and "point 1 (m=0 kg) failed: E311" in text
    data = result.to_json()
    assert data["failed"] == 1 and data["points"][1]["status"] == "failed"
    assert data["points"][1]["diagnostics"][0]["code"] == "E311"
    assert data["points"][0]["metrics"]["x.final"] == pytest.approx(F0 / 800, rel=1e-5)


@pytest.mark.slow      # 4 s: flagship runs
def test_flagship_dependent_parameters_follow_the_varied_mass():
    # F_n0 = M*g - (P0 - P_atm)*Ar, delta0 and theta0 depend on M: the run starts at rest at the new
    # equilibrium only if they were recomputed (the values of the model: g, P0, P_atm, Ar, lead)
    metrics = ["F_nut.final", "torque.final", "motor.peak_torque"]
    result = run_sweep(FLAGSHIP, vary=["M=20,25 [kg]"], metrics=metrics, t_end=0.01)
    assert [point.path for point in result.points] == ["bound", "bound"]
    for point, mass in zip(result.points, (20.0, 25.0)):
        nut_force = mass * 9.81 - (0.224e6 - 101325) * 2.63e-3
        assert point.metrics["F_nut.final"] == pytest.approx(nut_force, rel=1e-9)
        assert point.metrics["torque.final"] == pytest.approx(5e-3 / (2 * math.pi) * nut_force, rel=1e-9)
        assert point.metrics["motor.peak_torque"] == pytest.approx(abs(point.metrics["torque.final"]), rel=1e-9)
    again = run_sweep(FLAGSHIP, vary=["M=25 [kg]"], metrics=metrics, t_end=0.01, rederive=True)
    assert again.points[0].path == "rederived"
    for name, value in again.points[0].metrics.items():          # checked again from the file: the same
        assert value == pytest.approx(result.points[1].metrics[name], rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("spec, code, words", [
    ("kk=1,2", "E961", "did you mean 'k'?"),
    ("k=400,abc", "E962", "'abc' is not a number"),
    ("k=400,inf", "E962", "not a finite number"),
    ("k=", "E960", "gives no values"),
    ("k=400,,800", "E960", "empty value"),
    ("k 400", "E960", "is not NAME=VALUES"),
    ("k=1:2", "E962", "is not start:stop:count"),
    ("k=1:2:1", "E962", "whole number >= 2"),
    ("k=1:2:2.5", "E962", "whole number >= 2"),
    ("k=1,2 [kgg]", "E963", "kgg"),
    ("k=1,2 [kg]", "E963", "does not measure the same quantity as [N/m]"),
    (f"k=1:2:{MAX_RUNS + 1}", "E964", f"at most {MAX_RUNS}"),
])
def test_bad_vary_specs(spec, code, words):
    with pytest.raises(UsageError) as caught:
        run_sweep(MSD, vary=[spec], metrics=None, t_end=1.0)
    [diagnostic] = caught.value.diagnostics
    assert diagnostic.code == code
    assert words in diagnostic.message + " " + (diagnostic.hint or "")


@pytest.mark.parametrize("request_, code, words", [
    (dict(vary=["k=1,2", "k=3"]), "E966", "varied twice"),
    (dict(vary=["k=1,2"], sets=["k=3"]), "E966", "both varied and set"),
    (dict(vary=["k=1,2"], metrics=["x.maxx"]), "E965", "did you mean 'x.max'?"),
    (dict(vary=["k=1,2"], metrics=["motor.peak_torque"]), "E965", "an output 'torque'"),
    (dict(vary=["k=1,2"], jobs=0), "E967", "jobs"),
    (dict(vary=["k=1,2"], output="sweep.txt"), "E969", ".csv or .json"),
    (dict(vary=[]), "E960", "nothing to vary"),
    (dict(vary=["k=1:2:400", "b=1:2:400"]), "E964", "160000 runs (400 x 400)"),
])
def test_bad_requests(request_, code, words):
    arguments = {"metrics": None, "t_end": 1.0, **request_}
    with pytest.raises(BondcError) as caught:
        run_sweep(MSD, **arguments)
    [diagnostic] = caught.value.diagnostics
    assert diagnostic.code == code
    assert words in diagnostic.message + " " + (diagnostic.hint or "")


def test_sets_apply_to_every_point():
    result = run_sweep(MSD, sets=["F0=0.02 [kN]"], vary=["k=400,800"], metrics=["x.final"], t_end=5.0)
    assert [point.metrics["x.final"] for point in result.points] == [
        pytest.approx(20.0 / 400, rel=1e-5), pytest.approx(20.0 / 800, rel=1e-5)]


def test_a_components_parameter_is_varied_by_its_dotted_name(tmp_path):
    """--vary takes 'spring.k' as --set and --range do: the static deflection F0/k of a
    std:mechanics spring at each value."""
    path = tmp_path / "msd.bg"
    path.write_text('''import "std:mechanics"
model MSD
  Force push : F = 10
  Mass body : M = 2
  Spring spring : k = 800
  Damper damper : c = 12
  1 v
  push.a -> v
  v -> body.a
  v -> spring.a
  v -> damper.a
  output x [m] = spring.x
end
''')
    result = run_sweep(path, vary=["spring.k=0.4,1.6 [kN/m]"], metrics=["x.final"], t_end=5.0)
    assert [point.parameters for point in result.points] == [{"spring.k": 400.0}, {"spring.k": 1600.0}]
    assert result.column("x.final") == [pytest.approx(10 / 400, rel=1e-5), pytest.approx(10 / 1600, rel=1e-5)]
    with pytest.raises(UsageError) as caught:
        run_sweep(path, vary=["spring.kk=1,2"], metrics=None, t_end=1.0)
    assert caught.value.diagnostics[0].code == "E961"


@pytest.mark.parametrize("suffix", [".csv", ".json"])
def test_a_resume_after_the_model_or_an_option_changed_is_refused_not_mixed(tmp_path, suffix):
    """Points computed with b = 12 must not be kept for a sweep of the model with b = 40 (nor with
    another --set or t_end); the unchanged sweep still resumes without running anything."""
    path = tmp_path / "msd.bg"
    path.write_text(MSD.read_text())
    output = tmp_path / f"study{suffix}"
    first = run_sweep(path, vary=["k=400,800"], metrics=["x.max"], t_end=3.0, output=output, point_timeout=0)
    again = run_sweep(path, vary=["k=400,800"], metrics=["x.max"], t_end=3.0, output=output, point_timeout=0)
    assert again.column("x.max") == first.column("x.max")
    for change in (dict(sets=["F0=20"]), dict(t_end=2.0)):
        arguments = dict(vary=["k=400,800"], metrics=["x.max"], t_end=3.0, output=output, point_timeout=0)
        with pytest.raises(UsageError) as caught:
            run_sweep(path, **{**arguments, **change})
        assert caught.value.diagnostics[0].code == "E970"
    path.write_text(MSD.read_text().replace("b      = 12 ", "b      = 40 "))
    with pytest.raises(UsageError) as caught:
        run_sweep(path, vary=["k=400,800"], metrics=["x.max"], t_end=3.0, output=output, point_timeout=0)
    assert "a different text of the model file" in caught.value.diagnostics[0].message
    output.unlink()
    fresh = run_sweep(path, vary=["k=400,800"], metrics=["x.max"], t_end=3.0, output=output, point_timeout=0)
    assert fresh.column("x.max")[0] < first.column("x.max")[0]         # more damping, a lower peak


def test_a_model_file_edited_during_the_sweep_does_not_change_the_study(tmp_path):
    # late binding: every point runs the model as it was checked and compiled at the start
    model = tmp_path / "msd.bg"
    model.write_text(MSD.read_text())

    def edit_after_the_first_point(point, done, total):
        if done == 1:
            model.write_text(MSD.read_text().replace("param F0     = 10", "param F0     = 20"))

    result = run_sweep(model, vary=["k=400,800"], metrics=["x.final"], t_end=5.0, progress=edit_after_the_first_point,
                       point_timeout=0)
    assert [point.status for point in result.points] == ["ok", "ok"]
    assert result.points[1].metrics["x.final"] == pytest.approx(10 / 800, rel=1e-3)


def test_a_model_file_edited_during_a_reloading_sweep_fails_the_later_points(tmp_path):
    model = tmp_path / "msd.bg"
    model.write_text(MSD.read_text())
    seen = []

    def edit_after_the_first_point(point, done, total):
        seen.append((point.index, done, total))
        if done == 1:
            model.write_text(MSD.read_text().replace("param F0     = 10", "param F0     = 20"))

    result = run_sweep(model, vary=["k=400,800"], metrics=["x.final"], t_end=5.0, progress=edit_after_the_first_point,
                       rederive=True, point_timeout=0)
    assert seen == [(0, 1, 2), (1, 2, 2)]
    assert [point.status for point in result.points] == ["ok", "failed"]
    assert result.points[1].message == "E968: the model file changed during the sweep"


def test_default_metrics_are_every_output_statistic_and_the_energy():
    result = run_sweep(MSD, vary=["k=800"], metrics=None, t_end=0.5)
    names = [metric.name for metric in result.metrics]
    assert names[:4] == ["x.min", "x.max", "x.rms", "x.final"]
    assert names[-2:] == ["energy.residual", "energy.relative_residual"]
    assert not any(name.endswith(".mean") for name in names)
    assert len(names) == 3 * 4 + 2


def test_doctests():
    assert doctest.testmod(sweep).failed == 0
