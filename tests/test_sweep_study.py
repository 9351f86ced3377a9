"""Design studies (issue 12): a grid equals single runs, Latin hypercubes are reproducible, a
point that hangs is timed out, an interrupted sweep keeps its points and resumes, and each point
says which motors qualify."""

import csv
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bondc.analysis.energy import dense_steps
from bondc.analysis.motor_report import size_motors
from bondc.analysis.motors import load_catalogue
from bondc.analysis.stats import output_statistics
from bondc.analysis.sweep import latin_hypercube, parse_range, run_sweep
from bondc.pipeline import derive_file
from bondc.pipeline import simulate_file as run

ROOT = Path(__file__).resolve().parent.parent
MSD = ROOT / "models" / "mass_spring_damper.bg"
MOTOR_MODEL = ROOT / "models" / "dc_motor_gear.bg"
CATALOGUE = ROOT / "models" / "data" / "motors.csv"


@pytest.mark.slow
def test_a_3x3_grid_equals_nine_single_runs():
    from bondc.analysis.energy import dense_steps

    study = run_sweep(MSD, vary=["k=400,800,1600", "b=6,12,24"], metrics=["x.max", "x.rms", "v.min"], t_end=2.0)
    assert [p.status for p in study.points] == ["ok"] * 9
    state_space = derive_file(MSD, cache=False).state_space
    for point in study.points:
        k, b = point.values
        single = run(MSD, sets=[f"k={k}", f"b={b}"], t_end=2.0)
        # the statistics of `bondc simulate`: of the run between its steps too
        stats = output_statistics(dense_steps(state_space, single))
        for metric in ("x.max", "x.rms", "v.min"):
            output, _, statistic = metric.partition(".")
            assert point.metrics[metric] == pytest.approx(stats[output][statistic], rel=1e-9, abs=1e-15)


def test_latin_hypercube_samples_are_reproducible_and_stratified():
    axes = [parse_range("k=400:1600"), parse_range("b=5:20 [N*s/m]")]
    first = latin_hypercube(axes, 8, seed=7)
    assert first == latin_hypercube(axes, 8, seed=7) and first != latin_hypercube(axes, 8, seed=8)
    values = np.array(first)
    for column, (low, high) in enumerate([(400, 1600), (5, 20)]):
        strata = np.floor((values[:, column] - low) / (high - low) * 8).astype(int)
        assert sorted(strata) == list(range(8))          # one sample in each eighth of each range
    study = run_sweep(MSD, samples=8, ranges=["k=400:1600", "b=5:20 [N*s/m]"], seed=7, metrics=["x.final"],
                      t_end=1.0)
    assert [p.values for p in study.points] == first
    assert all(p.parameters["k"] == pytest.approx(v[0]) for p, v in zip(study.points, first))
    assert "Latin hypercube, seed 7" in study.to_text()


HANGING = """model Slow
  param m = 2   [kg]
  param k = 800 [N/m]
  param h = 1   [ms]   "largest step"
  Se push : e = 10
  I mass : f = p/m
  C spring : e = k*q
  1 j
  push -> j
  j -> mass
  j -> spring
  output x [m] = spring.q
  experiment run
    t_end    = 100 [s]
    max_step = h
  end
end
"""


@pytest.mark.slow
def test_a_point_that_hangs_is_timed_out_and_the_others_complete(tmp_path):
    # h = 1e-7 ms: 1e12 steps (reported every second, so no point limit stops it); the time limit
    # stops it and the sweep goes on
    path = tmp_path / "slow.bg"
    path.write_text(HANGING)
    started = time.monotonic()
    out = tmp_path / "slow.csv"
    study = run_sweep(path, vary=["h=10,1e-7,20"], metrics=["x.final"], point_timeout=3.0, jobs=2, dt=1.0,
                      output=out)
    assert [p.status for p in study.points] == ["ok", "timed out", "ok"]
    assert "stopped after 3 s" in study.points[1].message and study.points[1].wall_time >= 3.0
    assert time.monotonic() - started < 60
    assert study.exit_code == 1
    # the timed-out point keeps its value in the table (SI: 1e-7 ms), and the same sweep resumes
    assert [float(row[1]) for row in _rows(out)[1:]] == [pytest.approx(v) for v in (1e-2, 1e-10, 2e-2)]
    again = run_sweep(path, vary=["h=10,1e-7,20"], metrics=["x.final"], point_timeout=3.0, jobs=2, dt=1.0,
                      output=out)
    assert [p.status for p in again.points] == ["ok", "timed out", "ok"]
    assert [p.parameters["h"] for p in again.points] == [pytest.approx(v) for v in (1e-2, 1e-10, 2e-2)]
    # undamped: the spring swings between 0 and twice the static deflection
    assert all(0 <= p.metrics["x.final"] <= 2 * 10 / 800 * (1 + 1e-6) for p in (study.points[0], study.points[2]))


def _rows(path):
    with open(path, newline="") as handle:
        return list(csv.reader(handle))


@pytest.mark.slow
def test_an_interrupted_sweep_keeps_every_finished_point_and_the_same_command_resumes(tmp_path):
    out = tmp_path / "study.csv"
    command = [sys.executable, "-m", "bondc", "sweep", str(MSD), "--vary", "k=400:1600:400",
               "--metric", "x.final", "--t-end", "5", "-o", str(out), "--point-timeout", "0"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not out.exists() or len(_rows(out)) < 4):
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "sweep stopped after" in err and "the same command resumes" in err
    kept = _rows(out)[1:]
    assert 3 <= len(kept) < 400
    # the same command again: only the missing points run, and every point appears once
    again = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert again.returncode == 0, again.stderr
    rows = _rows(out)[1:]
    assert [int(row[0]) for row in rows] == list(range(400))
    assert {row[0] for row in kept} <= {row[0] for row in rows}
    for row in rows:
        assert float(row[2]) == pytest.approx(10 / float(row[1]), rel=1e-3)     # x.final = F0/k
    # a third run has nothing left to do and changes nothing but the order
    third = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert third.returncode == 0 and _rows(out)[1:] == rows


def test_resuming_skips_the_points_already_in_the_file(tmp_path):
    out = tmp_path / "study.csv"
    first = run_sweep(MSD, vary=["k=400,800"], metrics=["x.final"], t_end=2.0, output=out, point_timeout=0)
    calls = []
    second = run_sweep(MSD, vary=["k=400,800,1600"], metrics=["x.final"], t_end=2.0, output=out,
                       point_timeout=0, progress=lambda point, done, total: calls.append(point.index))
    assert calls == [2]                               # only the new point ran
    assert [p.metrics["x.final"] for p in second.points[:2]] == [p.metrics["x.final"] for p in first.points]
    other = tmp_path / "other.csv"
    other.write_text("index,z [m],status\n")
    from bondc.errors import UsageError

    with pytest.raises(UsageError) as caught:
        run_sweep(MSD, vary=["k=400"], metrics=["x.final"], t_end=2.0, output=other)
    assert caught.value.diagnostics[0].code == "E970"


@pytest.mark.slow
def test_each_point_lists_the_motors_that_qualify():
    catalogue = load_catalogue(CATALOGUE)
    study = run_sweep(MOTOR_MODEL, vary=["U_s=12,48"], metrics=["torque.max"], motors=CATALOGUE, point_timeout=0)
    assert study.motors and [p.status for p in study.points] == ["ok", "ok"]
    for point in study.points:
        # what `bondc simulate --motors` judges at the same value: the run between its steps, the
        # rotor inertia added, the load inertia estimated (the same rules, inertia ratio included)
        derived = derive_file(MOTOR_MODEL, sets=[f"U_s={point.values[0]}"])
        single = dense_steps(derived.state_space, run(MOTOR_MODEL, sets=[f"U_s={point.values[0]}"]))
        expected = tuple(c.motor.name for c in size_motors(single, derived.graph, catalogue).qualified)
        assert point.motors == expected
        assert point.chosen_motor == (expected[0] if expected else None)
    assert len(study.points[0].motors) >= len(study.points[1].motors)     # more voltage, more torque
    assert "motors" in study.csv_header()


def test_a_point_without_its_metrics_is_incomplete_not_ok():
    # the mass-spring-damper has no torque output: no motor can be chosen for its points
    study = run_sweep(MSD, vary=["k=400"], metrics=["x.final"], t_end=1.0, motors=CATALOGUE, point_timeout=0)
    (point,) = study.points
    assert point.status == "incomplete" and "no motor selection" in point.message
    assert 0 < point.metrics["x.final"] < 2 * 10 / 400 and study.exit_code == 1


def test_progress_without_a_terminal_is_a_plain_line(capsys):
    run_sweep(MSD, vary=["k=400,800"], metrics=["x.final"], t_end=1.0, point_timeout=0, progress=True)
    err = capsys.readouterr().err
    assert "sweep: 2/2 points" in err and "points/s" in err
    assert math.isfinite(float(err.split("sweep: 2/2 points, ")[1].split(" ")[0]))


def _without_times(result):
    import dataclasses

    return dataclasses.replace(result, points=tuple(dataclasses.replace(p, wall_time=None) for p in result.points),
                               settings={k: v for k, v in result.settings.items() if k != "executor"})


@pytest.mark.slow
def test_local_workers_and_a_dask_cluster_give_identical_rows():
    pytest.importorskip("distributed")
    request = dict(vary=["k=400,1600", "b=6,24"], metrics=["x.max", "x.final", "energy.residual"], t_end=2.0)
    local = run_sweep(MSD, jobs=2, **request)
    dask = run_sweep(MSD, executor="dask", jobs=2, **request)
    assert _without_times(dask).csv_text() == _without_times(local).csv_text()
    assert _without_times(dask).to_json() == _without_times(local).to_json()


@pytest.mark.slow
def test_a_sweep_on_a_dask_scheduler_with_two_workers_started_from_the_command_line(tmp_path):
    # what README's "Sweeps on a Dask cluster" says to do, with the scheduler and workers as processes here
    pytest.importorskip("distributed")
    scheduler_file = tmp_path / "scheduler.json"
    bin_dir = Path(sys.executable).parent
    dask_cli = [str(bin_dir / "dask")] if (bin_dir / "dask").exists() else [sys.executable, "-m", "dask"]
    processes = [subprocess.Popen(dask_cli + ["scheduler", "--scheduler-file", str(scheduler_file),
                                              "--port", "0", "--dashboard-address", ":0"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        import json

        address = json.loads(scheduler_file.read_text())["address"]
        for _ in range(2):
            processes.append(subprocess.Popen(dask_cli + ["worker", address, "--nthreads", "1",
                                                          "--dashboard-address", ":0"],
                                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        out = tmp_path / "study.csv"
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        done = subprocess.run([sys.executable, "-m", "bondc", "sweep", str(MSD), "--vary", "k=400,800,1600",
                               "--metric", "x.final", "--t-end", "5", "--scheduler", address, "-o", str(out)],
                              capture_output=True, text=True, env=env, timeout=300)
        assert done.returncode == 0, done.stderr
        rows = _rows(out)[1:]
        assert [row[-3] for row in rows] == ["ok"] * 3
        local = run_sweep(MSD, vary=["k=400,800,1600"], metrics=["x.final"], t_end=5.0)
        assert [float(row[2]) for row in rows] == [p.metrics["x.final"] for p in local.points]
    finally:
        for process in processes:
            process.terminate()
        for process in processes:
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()


@pytest.mark.slow
def test_the_motors_that_cover_the_whole_study():
    study = run_sweep(MOTOR_MODEL, vary=["U_s=12,24,48"], metrics=["torque.max"], motors=CATALOGUE, point_timeout=0)
    common = study.motors_for_all()
    for point in study.points:
        assert set(common) <= set(point.motors)
    every = set(load_catalogue_names())
    for name in every - set(common):
        assert any(name not in point.motors for point in study.points)
    assert f"smallest: {common[0]}" in study.to_text() and study.to_json()["motors_for_all"] == common


def load_catalogue_names():
    return [motor.name for motor in load_catalogue(CATALOGUE)]


@pytest.mark.slow
def test_the_report_of_a_study_shows_its_metrics_heat_maps_failures_and_motors(tmp_path):
    import re

    from bondc.report.sweep_report import build_sweep_report, read_study
    from test_report_build import assert_self_contained
    from test_report_render import check_html

    table = tmp_path / "grid.csv"
    run_sweep(MSD, vary=["k=400,1600", "m=0,2"], metrics=["x.max", "x.final"], t_end=2.0, output=table)
    study = read_study(table)
    assert [name for name, _ in study.parameters] == ["k", "m"] and len(study.rows) == 4
    html = build_sweep_report(table, tmp_path / "grid.html").read_text(encoding="utf-8")
    check_html(html)
    assert_self_contained(html)
    assert html.count('<figure class="plot">') == 4              # 2 metrics x (against k, heat map)
    assert html.count("failed or timed out") == 2 and "2 failed" in html
    # f = p/m with m = 0: marked in the compact table and in the table of all columns
    assert len(re.findall(r"<tr class=\"bad\">", html)) == 2 * 2 and "E311" in html
    # a motor study: the operating points against every catalogue motor's envelopes
    table = tmp_path / "motors.csv"
    run_sweep(MOTOR_MODEL, vary=["U_s=12,48"], metrics=["motor.peak_speed", "motor.peak_torque",
                                                       "motor.rms_torque"], motors=CATALOGUE, output=table)
    html = build_sweep_report(table, tmp_path / "motors.html", motors=CATALOGUE).read_text(encoding="utf-8")
    for motor in load_catalogue(CATALOGUE):
        assert f"{motor.name} continuous" in html
    assert "Motors that cover every point" in html


def test_report_sweep_from_the_command_line(tmp_path):
    from bondc.cli import main

    table = tmp_path / "s.csv"
    run_sweep(MSD, vary=["k=400,800"], metrics=["x.final"], t_end=1.0, output=table, point_timeout=0)
    assert main(["report", "--sweep", str(table), "-o", str(tmp_path / "s.html")]) == 0
    assert "x.final" in (tmp_path / "s.html").read_text(encoding="utf-8")
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    assert main(["report", "--sweep", str(tmp_path / "bad.csv"), "-o", str(tmp_path / "b.html")]) == 1


@pytest.mark.slow
def test_points_with_an_algebraic_loop_do_not_depend_on_the_points_run_before():
    # a nonlinear loop is solved from a warm start within a run; a run never starts from another's
    loop = ROOT / "tests" / "fixtures" / "sim" / "nonlinear_loop.bg"
    request = dict(metrics=["i.final", "u.max"], point_timeout=0)
    forward = run_sweep(loop, vary=["V=5,10,20"], **request)
    backward = run_sweep(loop, vary=["V=20,10,5"], **request)
    assert [p.metrics for p in forward.points] == [p.metrics for p in reversed(backward.points)]
    alone = run_sweep(loop, vary=["V=10"], **request)
    assert alone.points[0].metrics == forward.points[1].metrics


@pytest.mark.slow
def test_every_power_output_gets_its_per_cycle_peak_rms_and_energies():
    from bondc.analysis.energy import dense_steps
    from bondc.analysis.stats import power_statistics

    study = run_sweep(MOTOR_MODEL, vary=["U_s=12,24"], metrics=["power_el.*"], point_timeout=0)
    names = [m.name for m in study.metrics]
    assert "power_el.cycle_peak" in names and "power_el.cycle_energy" in names
    state_space = derive_file(MOTOR_MODEL, cache=False).state_space
    for point in study.points:
        single = run(MOTOR_MODEL, sets=[f"U_s={point.values[0]}"])
        (first, *_) = power_statistics(dense_steps(state_space, single), ["power_el"], None)["power_el"]
        assert point.metrics["power_el.cycle_peak"] == pytest.approx(first["peak"], rel=1e-9)
        assert point.metrics["power_el.cycle_rms"] == pytest.approx(first["rms"], rel=1e-9)
        assert point.metrics["power_el.cycle_energy"] == pytest.approx(first["net_energy"], rel=1e-9)


RIG = """model PressureRig
  param m = 2   [kg]
  param k = 800 [N/m]
  param b = 20  [N*s/m]
  param x0 = 0.01 [m]
  param A = 0.001 [m^2]
  Se push : e = 10
  I mass : f = p/m
  C spring : e = k*q
  R damper : e = b*f
  1 j
  push -> j
  j -> mass
  j -> spring
  j -> damper
  output x [m] = spring.q
  output P_kPa [kPa] = (spring.e + k*x0)/A   "chamber pressure"
  experiment run
    t_end = 1 [s]
  end
end
"""


def _compact_header(html):
    import re

    table = re.search(r'<table class="data study compact">(.*?)</table>', html, re.S).group(1)
    return re.findall(r"<th>(.*?)</th>", re.search(r"<thead>(.*?)</thead>", table, re.S).group(1))


def test_the_report_of_a_study_is_titled_by_its_model_in_its_outputs_units_without_constant_metrics(tmp_path,
                                                                                                     capsys):
    from bondc.cli import main
    from bondc.report.sweep_report import read_study

    model = tmp_path / "rig.bg"
    model.write_text(RIG, encoding="utf-8")
    table = tmp_path / "results-2026.csv"
    run_sweep(model, vary=["k=400,800,1600"], metrics=["P_kPa.min", "P_kPa.max", "x.min"], output=table,
              point_timeout=0)
    assert "P_kPa.min [kg/(m*s^2)]" in table.read_text()          # the csv stays SI
    capsys.readouterr()
    assert main(["report", "--sweep", str(table), "-o", str(tmp_path / "r.html")]) == 0
    printed = capsys.readouterr().out
    assert "3 points (3 ok)" in printed and "motors" not in printed
    html = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "<h1>PressureRig</h1>" in html and "<title>PressureRig — " in html and "results-2026</h1>" not in html
    # a metric's unit is its output's declared unit: P = k*x0/A at rest, 400*0.01/0.001 Pa = 4 kPa
    assert "P_kPa.min [kPa]" in html and "kg/(m*s^2)" not in html
    assert [row["metrics"]["P_kPa.min"] for row in read_study(table).rows] == pytest.approx([4.0, 8.0, 16.0])
    # compact: index, k, status and the two metrics that vary (x.min is 0 at every point)
    assert _compact_header(html) == ["index", "k [N/m]", "status", "P_kPa.min [kPa]", "P_kPa.max [kPa]"]
    assert "All 8 columns" in html and "x.min [m]" in html          # the rest: in the table of all columns
    assert "P_kPa.max against k</figcaption>" in html and "x.min against k" not in html
    assert html.count('<figure class="plot">') == 2


def test_a_study_table_without_its_record_or_with_a_broken_one_still_gets_a_report(tmp_path, capsys):
    from bondc.cli import main

    table = tmp_path / "plain.csv"
    table.write_text("index,k [N/m],power.final [W],x.max [m],status,message,wall_time [s]\n"
                     "0,400,0,0.1,ok,,0.1\n1,800,0,0.05,ok,,0.1\n2,1600,,,failed,<b>E311</b>,0.1\n")
    (tmp_path / "plain.csv.study").write_text("{not json")
    assert main(["report", "--sweep", str(table), "-o", str(tmp_path / "p.html")]) == 0
    html = (tmp_path / "p.html").read_text(encoding="utf-8")
    assert "<h1>plain</h1>" in html and "&lt;b&gt;E311&lt;/b&gt;" in html and "<b>E311" not in html
    assert "power.final against k" not in html and "x.max against k" in html       # power.final = 0 throughout
    assert "3 points (2 ok, 1 failed)" in capsys.readouterr().out
    table.write_text("index,k [N/m],x.max [m],status,message,wall_time [s]\nzero,400,0.1,ok,,0.1\n")
    assert main(["report", "--sweep", str(table), "-o", str(tmp_path / "q.html")]) == 1     # no traceback


@pytest.mark.slow
def test_the_report_of_a_motor_study_shows_the_chosen_motor_and_the_motors_for_every_point(tmp_path, capsys):
    from bondc.cli import main

    table = tmp_path / "motors.csv"
    study = run_sweep(MOTOR_MODEL, vary=["U_s=12,24,48"], motors=CATALOGUE, output=table, point_timeout=0)
    common = study.motors_for_all()
    capsys.readouterr()
    assert main(["report", "--sweep", str(table), "--motors", str(CATALOGUE), "-o", str(tmp_path / "m.html")]) == 0
    printed = capsys.readouterr().out
    assert f"motors that cover every point: {', '.join(common)} (smallest: {common[0]})" in printed
    html = (tmp_path / "m.html").read_text(encoding="utf-8")
    header = _compact_header(html)
    assert header[:4] == ["index", "U_s [V]", "status", "motor"]
    assert "power_el.cycle_energy [J]" in header and any(name.startswith("motor.peak_torque") for name in header)
    assert len(header) <= 4 + 6
    assert "motor.peak_torque against U_s" in html and "power_el.cycle_energy against U_s" in html
    for point in study.points:
        assert f"<td>{point.chosen_motor}</td>" in html
