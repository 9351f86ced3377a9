"""The transmission ratio as a sizing variable (issue "The design answer", item 1: ``--ratio``).

Each row of a ratio study must name the motor a single ``bondc simulate --set NAME=VALUE --motors``
names at that value (the independent route: one run, its own selection), the model's own value
must be a row and agree with the plain run, and the report must show the table.
"""

from __future__ import annotations

import json
import math
from html.parser import HTMLParser
from pathlib import Path

import pytest

from bondc.analysis.ratio import RatioRow, RatioStudy
from bondc.cli import main

ROOT = Path(__file__).resolve().parent.parent
FLAGSHIP = ROOT / "models" / "electro_pneumatic_hybrid.bg"
CATALOGUE = ROOT / "models" / "data" / "motors.csv"
ORDER = ("SV-50", "SV-100", "SV-200", "SV-400")


def row(value, motor, rms=0.1, own=False, status="ok"):
    return RatioRow(value, status, motor, 1 if motor else 0, 2 * rms, rms, 100.0, own)


def test_the_best_value_is_the_one_with_the_smallest_motor_and_ties_go_to_the_lowest_rms_torque():
    study = RatioStudy("lead", "mm", (row(2, "SV-200", 0.3), row(5, "SV-100", 0.2, own=True),
                                      row(10, "SV-100", 0.15), row(20, None)), ORDER)
    assert study.best.value == 10
    assert study.sentence() == ("Over lead from 2 to 20 mm, the smallest motor that qualifies is SV-100, at "
                                "lead = 10 mm. The model's lead = 5 mm needs the same motor.")
    other = RatioStudy("n", None, (row(1, "SV-400", own=True), row(2, "SV-50")), ORDER)
    assert other.sentence() == ("Over n from 1 to 2, the smallest motor that qualifies is SV-50, at n = 2. "
                                "At the model's n = 1 it is SV-400.")
    none = RatioStudy("n", None, (row(1, None, own=True), row(2, None, status="failed")), ORDER)
    assert none.best is None and none.sentence() == "No motor of the catalogue qualifies at any n from 1 to 2."
    assert none.to_json()["best"] is None


@pytest.mark.parametrize("command", ["simulate", "report"])
def test_E973_a_ratio_without_a_catalogue_is_a_usage_error_before_any_run(command, capsys, tmp_path):
    code = main([command, str(FLAGSHIP), "--ratio", "lead=2,10", "-o", str(tmp_path / "out.html"
                                                                       if command == "report" else tmp_path / "o.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "E973" in err and "--motors" in err
    assert not list(tmp_path.iterdir())


def test_an_unknown_ratio_parameter_is_the_sweeps_usage_error(capsys):
    code = main(["simulate", str(FLAGSHIP), "--motors", str(CATALOGUE), "--ratio", "laed=2,10"])
    err = capsys.readouterr().err
    assert code == 2 and "E961" in err and "did you mean 'lead'?" in err


class _Table(HTMLParser):
    """The rows of the report's ratio table, as cell texts."""

    def __init__(self):
        super().__init__()
        self.rows, self._in, self._cell = [], False, None

    def handle_starttag(self, tag, attrs):
        if tag == "table" and "ratio" in (dict(attrs).get("class") or ""):
            self._in = True
        elif self._in and tag == "tr":
            self.rows.append([])
        elif self._in and tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag == "table":
            self._in = False
        elif self._in and tag in ("td", "th") and self._cell is not None:
            self.rows[-1].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


@pytest.mark.slow
def test_every_rows_motor_is_what_a_single_run_at_that_lead_chooses(capsys, tmp_path):
    code = main(["simulate", str(FLAGSHIP), "--motors", str(CATALOGUE), "--ratio", "lead=2,10 [mm]", "--json"])
    data = json.loads(capsys.readouterr().out)
    assert code == 0
    study = data["ratio"]
    assert [r["value"] for r in study["rows"]] == [2, 5, 10]        # the model's 5 mm added, in order
    assert [r["own"] for r in study["rows"]] == [False, True, False]
    for entry in study["rows"]:
        code = main(["simulate", str(FLAGSHIP), "--motors", str(CATALOGUE), "--set", f"lead={entry['value']!r} [mm]",
                     "--json"])
        single = json.loads(capsys.readouterr().out)["motors"]
        assert code == 0
        assert entry["motor"] == single["best"], entry
        assert entry["qualifying"] == sum(c["qualifies"] for c in single["candidates"])
        assert entry["peak_torque"] == pytest.approx(single["requirements"]["peak_torque"], rel=1e-6)
        assert entry["rms_torque"] == pytest.approx(single["requirements"]["rms_torque"], rel=1e-6)
    own = study["rows"][1]
    assert own["motor"] == data["motors"]["best"]
    # the torque falls with the lead (less force per unit torque... more torque per unit force): monotonic
    peaks = [r["peak_torque"] for r in study["rows"]]
    assert peaks == sorted(peaks)
    # the best value's motor is the smallest of the catalogue (rated power first) among the rows'
    power = {name: float(line.split(",")[4]) for line in CATALOGUE.read_text().splitlines()
             if not line.startswith(("#", "name")) for name in [line.split(",")[0]]}
    smallest = min(power[r["motor"]] for r in study["rows"] if r["motor"])
    assert power[study["best"]["motor"]] == smallest

    report = tmp_path / "r.html"
    code = main(["report", str(FLAGSHIP), "--motors", str(CATALOGUE), "--ratio", "lead=2,10 [mm]", "-o",
                 str(report), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0 and summary["ratio"]["rows"] == study["rows"]
    table = _Table()
    table.feed(report.read_text(encoding="utf-8"))
    head, *body = table.rows
    assert head[0].startswith("lead") and head[1] == "motor"
    assert [cells[1] for cells in body] == [r["motor"] for r in study["rows"]]
    assert body[1][0] == "5 (model)"
    assert all(math.isclose(float(cells[2]), r["peak_torque"], rel_tol=1e-3) for cells, r in zip(body, study["rows"]))
