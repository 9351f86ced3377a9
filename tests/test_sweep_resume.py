"""A sweep's output file is never rewritten with fewer finished rows than it holds.

``bondc sweep -o FILE`` resumes from the points already in FILE. A run whose grid, samples,
metrics, motor catalogue, model or --set differ from those of the run that wrote FILE must not
replace it: it is refused with E970 and FILE (and its ``.study`` record) keeps every byte. A grid
that contains every point already in FILE extends the study (tests/test_sweep_study.py)."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bondc.analysis.sweep import run_sweep, study_file
from bondc.errors import UsageError

ROOT = Path(__file__).resolve().parent.parent
MSD = ROOT / "models" / "mass_spring_damper.bg"
CATALOGUE = ROOT / "models" / "data" / "motors.csv"

REQUEST = dict(metrics=["x.final"], t_end=1.0, point_timeout=0)


def _snapshot(output: Path) -> dict[str, bytes | None]:
    """The bytes of the table and of its .study record (None: absent)."""
    return {str(path): path.read_bytes() if path.exists() else None for path in (output, study_file(output))}


def _refused(output: Path, **request) -> str:
    """Run the sweep on ``output`` and return the E970 message; the files must not change."""
    before = _snapshot(output)
    with pytest.raises(UsageError) as caught:
        run_sweep(request.pop("path", MSD), output=output, **{**REQUEST, **request})
    (diagnostic,) = caught.value.diagnostics
    assert diagnostic.code == "E970", diagnostic
    assert diagnostic.hint and ("another file" in diagnostic.hint or "-o" in diagnostic.hint)
    assert _snapshot(output) == before
    return diagnostic.message


def _rows(path: Path) -> list[list[str]]:
    with open(path, newline="", encoding="utf-8") as handle:
        return list(csv.reader(handle))


@pytest.mark.parametrize("suffix", [".csv", ".json"])
def test_a_grid_without_the_points_already_in_the_file_is_refused(tmp_path, suffix):
    # the trial that lost rows: k=400,800 then k=400,1600 kept only 400 and 1600
    output = tmp_path / f"study{suffix}"
    run_sweep(MSD, vary=["k=400,800"], output=output, **REQUEST)
    message = _refused(output, vary=["k=400,1600"])
    assert "k=800" in message                      # names a point it would have dropped
    # the same command still resumes, and a grid with every point of the file extends it
    again = run_sweep(MSD, vary=["k=400,800"], output=output, **REQUEST)
    assert [p.parameters["k"] for p in again.points] == [400.0, 800.0]
    grown = run_sweep(MSD, vary=["k=400,800,1600"], output=output, **REQUEST)
    assert [p.parameters["k"] for p in grown.points] == [400.0, 800.0, 1600.0]
    assert grown.column("x.final")[:2] == again.column("x.final")


def test_a_latin_hypercube_with_other_samples_or_another_seed_is_refused(tmp_path):
    output = tmp_path / "study.csv"
    request = dict(samples=4, ranges=["k=400:1600"])
    run_sweep(MSD, seed=1, output=output, **request, **REQUEST)
    _refused(output, seed=2, **request)
    _refused(output, seed=1, samples=6, ranges=["k=400:1600"])
    _refused(output, seed=None, **request)         # without a seed, other points every run
    assert len(_rows(output)) == 5


def test_other_metrics_are_refused(tmp_path):
    output = tmp_path / "study.csv"
    run_sweep(MSD, vary=["k=400,800"], output=output, **REQUEST)
    _refused(output, vary=["k=400,800"], metrics=["x.max"])
    _refused(output, vary=["k=400,800"], metrics=["x.final", "x.max"])


def test_another_motor_catalogue_is_refused(tmp_path):
    output = tmp_path / "study.csv"
    catalogue = tmp_path / "motors.csv"
    catalogue.write_bytes(CATALOGUE.read_bytes())
    run_sweep(MSD, vary=["k=400"], motors=catalogue, output=output, **REQUEST)
    _refused(output, vary=["k=400"])                                  # no motors column this time
    lines = CATALOGUE.read_text(encoding="utf-8").splitlines(keepends=True)
    catalogue.write_text("".join(lines[:-1]), encoding="utf-8")      # one motor fewer
    assert "another motor catalogue" in _refused(output, vary=["k=400"], motors=catalogue)


def test_another_model_or_other_set_values_are_refused(tmp_path):
    output = tmp_path / "study.csv"
    run_sweep(MSD, vary=["k=400,800"], output=output, **REQUEST)
    other = tmp_path / "msd.bg"
    other.write_text(MSD.read_text(encoding="utf-8").replace("param F0     = 10", "param F0     = 20"),
                     encoding="utf-8")
    assert "a different text of the model file" in _refused(output, path=other, vary=["k=400,800"])
    assert "other --set values" in _refused(output, vary=["k=400,800"], sets=["b=40"])


@pytest.mark.parametrize("content", [
    b"a,b\n1,2\n",                                               # another table
    b"\xff\xfe\x00 not text",                                    # not text at all
    b"index,k [N/m],x.final [m],status,message,wall_time [s]\n"  # a sweep's header, then rows not of bondc
    b"0,400.0,0.02,ok,,0.1,extra,cells\n",
    b"index,k [N/m],x.final [m],status,message,wall_time [s]\n"
    b"first,400.0,0.02,ok,,0.1\n",
    b"index,k [N/m],x.final [m],status,message,wall_time [s]\n"
    b"0,400.0,0.02,fine,,0.1\n",
], ids=["other-table", "binary", "extra-cells", "bad-index", "bad-status"])
def test_a_csv_that_is_not_a_bondc_study_is_refused(tmp_path, content):
    output = tmp_path / "study.csv"
    output.write_bytes(content)
    _refused(output, vary=["k=400,800"])


@pytest.mark.parametrize("content", [b"[1, 2, 3]\n", b'"text"\n', b'{"parameters": 3}\n', b"not json\n",
                                     b'{"parameters": [{"name": "k"}], "metrics": [{"name": "x.final"}], '
                                     b'"points": [7]}\n'],
                         ids=["list", "string", "parameters-not-a-list", "not-json", "point-not-an-object"])
def test_a_json_that_is_not_a_bondc_study_is_refused(tmp_path, content):
    output = tmp_path / "study.json"
    output.write_bytes(content)
    _refused(output, vary=["k=400,800"])


def test_a_table_cut_short_by_a_killed_run_keeps_its_rows(tmp_path):
    output = tmp_path / "study.csv"
    run_sweep(MSD, vary=["k=400,800,1600"], output=output, **REQUEST)
    rows = _rows(output)
    text = output.read_bytes()
    output.write_bytes(text[:text.rindex(b"\n", 0, len(text) - 1) + 1] + b"2,1600.0,0.00")   # the last row cut
    _refused(output, vary=["k=400,1600"])          # would drop k=800's row
    _refused(output, vary=["k=400,800"], metrics=["x.max"])
    # the same command resumes: the two whole rows kept as they were, the cut one run again
    calls = []
    again = run_sweep(MSD, vary=["k=400,800,1600"], output=output, **REQUEST,
                      progress=lambda point, done, total: calls.append(point.index))
    assert calls == [2] and [p.status for p in again.points] == ["ok"] * 3
    assert _rows(output)[:3] == rows[:3] and _rows(output)[3][:3] == rows[3][:3]


def test_the_command_line_refuses_with_e970_and_a_hint(tmp_path):
    output = tmp_path / "study.csv"
    base = [sys.executable, "-m", "bondc", "sweep", str(MSD), "--metric", "x.final", "--t-end", "1",
            "--point-timeout", "0", "-o", str(output)]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    first = subprocess.run(base + ["--vary", "k=400,800,1200"], capture_output=True, text=True, env=env,
                           timeout=300)
    assert first.returncode == 0, first.stderr
    before = _snapshot(output)
    second = subprocess.run(base + ["--vary", "k=400,1600,2000"], capture_output=True, text=True, env=env,
                            timeout=300)
    assert second.returncode == 2, second.stderr
    assert "error[E970]" in second.stderr and "Traceback" not in second.stderr
    assert "another file" in second.stderr or "-o" in second.stderr
    assert _snapshot(output) == before
