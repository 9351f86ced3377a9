"""bondc fit: calibration against synthetic measurements made from known parameter values.

The data are simulations with known "true" values plus seeded Gaussian noise; the checks are
against those values, against the closed-form step response of a mass-spring-damper (its
sensitivity to the damping and the stiffness), and against what a second, independent route
computes (the fitted copy simulated again)."""

from __future__ import annotations

import cmath
import json
import math
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

import bondc
from bondc.analysis.fit import DataSet, parse_groups, prepare_fit, run_fit
from bondc.cli import main
from bondc.errors import BondcError

ROOT = Path(__file__).resolve().parent.parent
MSD = ROOT / "models" / "mass_spring_damper.bg"
FLAGSHIP = ROOT / "models" / "electro_pneumatic_hybrid.bg"
FLAGSHIP_DATA = ROOT / "models" / "data" / "fit_cycle_measured.csv"
PRODUCT = ROOT / "tests" / "fixtures" / "fit" / "rc_product.bg"

# the mass-spring-damper file's values, and the "true" ones the data is made with
M, K, B, F0, T_STEP = 2.0, 800.0, 12.0, 10.0, 0.1
TRUE_B, TRUE_K = 15.0, 900.0


def closed_form_x(t, b, k, m=M):
    """The step response x(t) of m x'' + b x' + k x = F0 step(t - T_STEP), from rest (underdamped);
    works for complex b and k (the complex-step derivative below)."""
    out = []
    for time_ in np.asarray(t, dtype=float):
        tau = time_ - T_STEP
        if tau <= 0:
            out.append(0.0 * b * k)
            continue
        sigma = b / (2 * m)
        wd = cmath.sqrt(k / m - sigma ** 2)
        out.append(F0 / k * (1 - cmath.exp(-sigma * tau) * (cmath.cos(wd * tau) + sigma / wd * cmath.sin(wd * tau))))
    return np.array(out)


def closed_form_derivative(t, b, k, which: str):
    """d x / d b or d x / d k of the closed form, by the complex step (exact to rounding)."""
    h = 1e-20
    if which == "b":
        return np.imag(closed_form_x(t, b + 1j * h, k)) / h
    return np.imag(closed_form_x(t, b, k + 1j * h)) / h


def write_csv(path: Path, t, columns: dict) -> Path:
    names = list(columns)
    lines = [",".join(["t"] + names)]
    lines += [",".join([repr(float(a))] + [repr(float(columns[n][i])) for n in names]) for i, a in enumerate(t)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def msd_data(tmp_path: Path, seed: int, noise: float = 2e-4, b: float = TRUE_B, k: float = TRUE_K,
             dt: float = 0.02, name: str | None = None) -> Path:
    t = np.round(np.arange(0.0, 2.0 + dt / 2, dt), 10)
    rng = np.random.default_rng(seed)
    x = np.real(closed_form_x(t, b, k)) + rng.normal(0.0, noise, t.size)
    return write_csv(tmp_path / (name or f"msd-{seed}.csv"), t, {"x_meas": x})


# ---------------------------------------------------------------- recovery and intervals

def test_mass_spring_damper_recovers_damping_and_stiffness_within_intervals(tmp_path):
    data = msd_data(tmp_path, seed=1)
    result = bondc.fit(MSD, data=data, compare=["x=x_meas"], estimate=["b=1:50", "k=100:5000"])
    assert result.converged
    values = {p.name: p for p in result.parameters}
    for name, truth in (("b", TRUE_B), ("k", TRUE_K)):
        low, high = values[name].ci95
        assert low < truth < high, (name, values[name])
        assert values[name].stderr > 0
    assert values["b"].initial == B and values["k"].initial == K
    assert result.cost < result.cost_initial / 10
    # the residual RMSE after the fit is the noise's standard deviation
    assert result.signals[0].rmse == pytest.approx(2e-4, rel=0.2)


def test_interval_coverage_over_seeds(tmp_path):
    """95 % intervals of the damping cover the true value in most of 20 independent data sets
    (expected 19 of 20; fewer than 16 would happen with probability < 2 % for honest intervals),
    and they are not so wide that they always would: their half-width is near 1.96 standard
    deviations of the estimates over the seeds."""
    covered, estimates, halfwidths = 0, [], []
    for seed in range(20):
        data = msd_data(tmp_path, seed=100 + seed, noise=5e-4, k=K)
        result = run_fit(MSD, datasets=[DataSet(str(data), ("x=x_meas",))], estimates=["b=1:50"])
        [p] = result.parameters
        covered += p.ci95[0] <= TRUE_B <= p.ci95[1]
        estimates.append(p.value)
        halfwidths.append((p.ci95[1] - p.ci95[0]) / 2)
    assert covered >= 16, covered
    spread = float(np.std(estimates, ddof=1))
    assert 0.5 < np.mean(halfwidths) / (1.96 * spread) < 2.0


def test_two_data_sets_of_two_experiments_fit_one_parameter_set(tmp_path):
    model = tmp_path / "msd2.bg"
    model.write_text(MSD.read_text().replace(
        "  experiment step ", "  experiment big \"20 N\"\n    t_end = 2 [s]\n    rtol = 1e-8\n    atol = 1e-10\n"
                              "    param F0 = 20 [N]\n  end\n\n  experiment step "), encoding="utf-8")
    small = msd_data(tmp_path, seed=5, name="small.csv")
    t = np.round(np.arange(0.0, 2.01, 0.02), 10)
    big = write_csv(tmp_path / "big.csv", t, {"x_big": 2 * np.real(closed_form_x(t, TRUE_B, TRUE_K))
                                              + np.random.default_rng(6).normal(0, 2e-4, t.size)})
    groups = parse_groups([("data", str(small)), ("experiment", "step"), ("compare", "x=x_meas"),
                           ("data", str(big)), ("compare", "x=x_big"), ("experiment", "big")])
    assert [(g.experiment, [c.column for c in g.compare]) for g in groups] == [("step", ["x_meas"]),
                                                                              ("big", ["x_big"])]
    result = run_fit(model, datasets=groups, estimates=["b=1:50", "k=100:5000"])
    alone = run_fit(model, datasets=groups[:1], estimates=["b=1:50", "k=100:5000"])
    assert result.converged
    for p, single, truth in zip(result.parameters, alone.parameters, (TRUE_B, TRUE_K)):
        assert abs(p.value - truth) < 4 * p.stderr          # (a 95 % interval misses one time in 20)
        assert p.stderr < single.stderr                     # the second data set adds information
    assert [s.column for s in result.signals] == ["x_meas", "x_big"]


@pytest.mark.slow
def test_flagship_valve_area_and_friction_factor_recovered():
    """The calibration example of docs/calibration.md: models/data/make_fit_data.py made the data
    with Ae = 1.5e-5 m^2 and a_up = 600 N*s/m (the model file has 1.2e-5 and 706.59)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_fit_data", ROOT / "models" / "data" / "make_fit_data.py")
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    truth = generator.TRUE
    result = bondc.fit(FLAGSHIP, data=FLAGSHIP_DATA, compare=["torque=torque", "P=P"],
                       estimate=["Ae=2:60 [mm^2]", "a_up=100:2000"])
    assert result.converged
    for p in result.parameters:
        assert p.ci95[0] < truth[p.name] < p.ci95[1], p
        assert p.value == pytest.approx(truth[p.name], rel=0.01)
    assert {p.name: p.initial for p in result.parameters} == {"Ae": 1.2e-5, "a_up": 706.59}
    assert not [d for d in result.diagnostics if d.code.startswith("W88")]


# ---------------------------------------------------------------- identifiability

def test_parameters_entering_only_as_a_product_are_reported(tmp_path):
    sim = bondc.simulate(PRODUCT, overrides={"a": 150}, dt=0.05)
    noisy = np.asarray(sim["v"]) + np.random.default_rng(3).normal(0, 0.02, sim.t.size)
    data = write_csv(tmp_path / "rc.csv", sim.t, {"v_meas": noisy})
    result = bondc.fit(PRODUCT, data=data, compare=["v=v_meas"], estimate=["a=1:1000", "b=0.1:100"])
    codes = {d.code: d.message for d in result.diagnostics}
    assert "W881" in codes and "W880" in codes
    for code in ("W880", "W881"):
        assert "'a'" in codes[code] and "'b'" in codes[code]
    assert all(math.isinf(p.stderr) for p in result.parameters)
    assert result.correlation[0][1] == pytest.approx(-1.0, abs=1e-3)
    # what the data does determine is the product: a*b = 150*10
    a, b = (p.value for p in result.parameters)
    assert a * b == pytest.approx(1500, rel=0.01)


def test_one_of_the_pair_fixed_is_identifiable(tmp_path):
    sim = bondc.simulate(PRODUCT, overrides={"a": 150}, dt=0.05)
    noisy = np.asarray(sim["v"]) + np.random.default_rng(4).normal(0, 0.02, sim.t.size)
    data = write_csv(tmp_path / "rc.csv", sim.t, {"v_meas": noisy})
    result = bondc.fit(PRODUCT, data=data, compare=["v=v_meas"], estimate=["a=1:1000"])
    assert not [d for d in result.diagnostics if d.code in ("W880", "W881")]
    [p] = result.parameters
    assert p.ci95[0] < 150 < p.ci95[1]


# ---------------------------------------------------------------- gradients

def test_finite_difference_jacobian_matches_the_closed_form_sensitivity(tmp_path):
    t = np.round(np.arange(0.0, 2.0 + 1e-9, 0.01), 10)
    data = write_csv(tmp_path / "exact.csv", t, {"x_meas": np.real(closed_form_x(t, B, K))})
    problem = prepare_fit(MSD, datasets=[DataSet(str(data), ("x=x_meas",))], estimates=["b", "k"])
    scale = np.ptp(np.real(closed_form_x(t, B, K)))       # residuals are divided by the measured range
    J = problem.jacobian(problem.x0)
    for column, name in enumerate(("b", "k")):
        expected = closed_form_derivative(t, B, K, name) / scale
        error = np.max(np.abs(J[:, column] - expected)) / np.max(np.abs(expected))
        assert error < 1e-4, (name, error)
    # and the residuals at the true values are the solver's error only
    assert np.max(np.abs(problem.r0)) < 1e-6


# ---------------------------------------------------------------- outputs: json, report, --write

def test_json_shape(tmp_path, capsys):
    data = msd_data(tmp_path, seed=2)
    status = main(["fit", str(MSD), "--data", str(data), "--compare", "x=x_meas", "--estimate", "b=1:50",
                   "--estimate", "k", "--json"])
    assert status == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"converged", "parameters", "correlation", "cost", "signals", "diagnostics"}
    assert out["converged"] is True
    assert [set(p) for p in out["parameters"]] == [{"name", "value", "unit", "initial", "stderr", "ci95"}] * 2
    assert [(p["name"], p["unit"], p["initial"]) for p in out["parameters"]] == [("b", "N*s/m", 12.0),
                                                                                 ("k", "N/m", 800.0)]
    assert all(len(p["ci95"]) == 2 and p["ci95"][0] < p["value"] < p["ci95"][1] for p in out["parameters"])
    assert np.asarray(out["correlation"]).shape == (2, 2)
    assert set(out["cost"]) == {"initial", "final"} and out["cost"]["final"] < out["cost"]["initial"]
    [signal] = out["signals"]
    assert {"output", "column", "rmse", "nrmse"} <= set(signal)
    assert (signal["output"], signal["column"]) == ("x", "x_meas")


def test_not_converged_exits_1_with_what_was_reached(tmp_path, capsys):
    data = msd_data(tmp_path, seed=2)
    status = main(["fit", str(MSD), "--data", str(data), "--compare", "x=x_meas", "--estimate", "b=1:50",
                   "--estimate", "k", "--max-evaluations", "1", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert status == 1 and out["converged"] is False
    assert [d["code"] for d in out["diagnostics"]] == ["W883"]
    assert len(out["parameters"]) == 2


class _Tables(HTMLParser):
    """The tables of a page by id: rows of cell texts (header cells too)."""

    def __init__(self):
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self.current = None
        self.cell = None
        self.text_outside: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "table" and attrs.get("id"):
            self.current = self.tables.setdefault(attrs["id"], [])
        elif tag == "tr" and self.current is not None:
            self.current.append([])
        elif tag in ("td", "th") and self.current is not None:
            self.cell = []

    def handle_endtag(self, tag):
        if tag == "table":
            self.current = None
        elif tag in ("td", "th") and self.cell is not None:
            self.current[-1].append("".join(self.cell).strip())
            self.cell = None

    def handle_data(self, data):
        if self.cell is not None:
            self.cell.append(data)


def test_report_shows_estimates_correlation_and_signals(tmp_path):
    data = msd_data(tmp_path, seed=3, name="<m&d>.csv")
    report = tmp_path / "out" / "fit.html"
    result = bondc.fit(MSD, data=data, compare=["x=x_meas"], estimate=["b=1:50", "k"], output=report)
    assert str(report) in result.written
    text = report.read_text(encoding="utf-8")
    assert "<m&d>" not in text and "&lt;m&amp;d&gt;" in text          # escaped
    assert "<script" not in text and "http" not in text.split("</head>")[0].replace("http-equiv", "")
    parser = _Tables()
    parser.feed(text)
    estimates = parser.tables["estimates-table"]
    assert estimates[0][:4] == ["parameter", "unit", "initial", "estimate"]
    rows = {row[0]: row for row in estimates[1:]}
    assert set(rows) == {"b", "k"}
    assert float(rows["b"][3]) == pytest.approx(result.values["b"], rel=1e-4)
    assert float(rows["b"][5]) < TRUE_B < float(rows["b"][6])
    correlation = parser.tables["correlation-table"]
    assert correlation[0] == ["", "b", "k"] and [row[0] for row in correlation[1:]] == ["b", "k"]
    assert float(correlation[1][1]) == 1.0 and float(correlation[1][2]) == pytest.approx(result.correlation[0][1],
                                                                                           abs=1e-3)
    signals = parser.tables["signals-table"]
    assert signals[1][:2] == ["x", "x_meas"]
    assert text.count("<svg") >= 2          # measured vs model before and after, and the residuals


def test_write_gives_a_model_the_other_commands_accept_and_that_reproduces_the_fit(tmp_path, capsys):
    model = tmp_path / "msd.bg"
    model.write_text(MSD.read_text(), encoding="utf-8")
    data = msd_data(tmp_path, seed=4)
    fitted = tmp_path / "fitted.bg"
    result = bondc.fit(model, data=data, compare=["x=x_meas"], estimate=["b=1:50", "k"], write=fitted)
    assert str(fitted) in result.written
    assert model.read_text() == MSD.read_text()           # the model itself is untouched
    assert main(["check", str(fitted)]) == 0
    capsys.readouterr()
    loaded = bondc.load(fitted)
    assert loaded.parameters["b"] == result.values["b"] and loaded.parameters["k"] == result.values["k"]
    again = bondc.simulate(fitted, dt=0.01)
    direct = bondc.simulate(model, overrides=result.values, dt=0.01)
    assert np.allclose(again["x"], direct["x"], rtol=0, atol=1e-12)
    # fitting again from the fitted copy starts where the first fit ended
    second = bondc.fit(fitted, data=data, compare=["x=x_meas"], estimate=["b=1:50", "k"],
                       write=tmp_path / "fitted2.bg")
    assert second.cost_initial == pytest.approx(result.cost, rel=1e-6)
    # a file bondc fit wrote may be replaced by the next fit
    bondc.fit(model, data=data, compare=["x=x_meas"], estimate=["b=1:50"], write=fitted)
    assert bondc.load(fitted).parameters["k"] == K


# ---------------------------------------------------------------- diagnostics

LATE = MSD.read_text().replace('  param t_step = 0.1 [s]     "time at which the force is applied"\n',
                               '  param t_step = 0.1 [s]     "time at which the force is applied"\n'
                               '  param h = 5 [ms] "largest step"\n').replace("max_step = 5 [ms]", "max_step = h")


def _code(tmp_path, capsys, argv, files=None) -> tuple[int, str]:
    for name, text in (files or {}).items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    status = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, err


@pytest.mark.parametrize("argv_tail, code, words", [
    (["--compare", "x", "--estimate", "b"], "E880", ["OUT=COLUMN"]),
    (["--compare", "x=x_meas:nrmse=0.1", "--estimate", "b"], "E880", ["weight=W"]),
    (["--compare", "x=x_meas", "--estimate", "b=5"], "E881", ["LOW:HIGH"]),
    (["--compare", "x=x_meas", "--estimate", "bb=1:50"], "E882", ["did you mean 'b'"]),
    (["--compare", "x=x_meas", "--estimate", "b=50:1"], "E884", ["not below"]),
    (["--compare", "x=x_meas", "--estimate", "b=20:50"], "E885", ["outside its bounds", "12"]),
    (["--compare", "x=x_mes", "--estimate", "b"], "E886", ["x_meas"]),
    (["--compare", "y=x_meas", "--estimate", "b"], "E887", ["outputs: x, v, F_spring"]),
    (["--compare", "x=x_meas", "--estimate", "b", "--estimate", "b=1:50"], "E888", ["twice"]),
    (["--compare", "x=x_meas", "--estimate", "m=0:5"], "E892", ["m = 0"]),
])
def test_diagnostics(tmp_path, capsys, argv_tail, code, words):
    data = msd_data(tmp_path, seed=0, name="measured.csv")
    status, err = _code(tmp_path, capsys, ["fit", str(MSD), "--data", str(data)] + argv_tail)
    assert status in (1, 2)
    assert f"[{code}]" in err, err
    for word in words:
        assert word in err, err


def test_an_unknown_parameter_and_a_missing_column_are_reported_in_one_run(tmp_path, capsys):
    """The estimates and the data sets are checked independently: both problems at once."""
    data = msd_data(tmp_path, seed=0, name="measured.csv")
    status, err = _code(tmp_path, capsys, ["fit", str(MSD), "--data", str(data), "--compare", "x=x_mes",
                                           "--estimate", "bb=1:50"])
    assert status == 2
    assert "[E882]" in err and "did you mean 'b'" in err
    assert "[E886]" in err and "x_meas" in err


def test_diagnostic_compare_before_data(tmp_path, capsys):
    data = msd_data(tmp_path, seed=0, name="measured.csv")
    status, err = _code(tmp_path, capsys, ["fit", str(MSD), "--compare", "x=x_meas", "--data", str(data),
                                           "--estimate", "b"])
    assert status == 2 and "[E889]" in err and "before any --data" in err


def test_diagnostic_parameter_that_cannot_be_taken_late(tmp_path, capsys):
    data = msd_data(tmp_path, seed=0, name="measured.csv")
    status, err = _code(tmp_path, capsys, ["fit", str(tmp_path / "late.bg"), "--data", str(data), "--compare", "x=x_meas",
                                           "--estimate", "h=1:10"], {"late.bg": LATE})
    assert status == 2 and "[E883]" in err and "max_step" in err and "fixed before a run" in err
    assert "late.bg:" in err          # where the parameter is declared


def test_diagnostic_run_that_fails_at_the_start(tmp_path, capsys):
    bad = ("model Bad\n  param c = 0.5 [s]\n  Se s : e = sqrt(c - t)\n  I m : f = p\n  s -> m\n"
           "  output y = m.p\n  experiment run\n    t_end = 1 [s]\n  end\nend\n")
    data = write_csv(tmp_path / "y.csv", [0, 0.5, 1.0], {"y": [0, 0.2, 0.3]})
    status, err = _code(tmp_path, capsys, ["fit", str(tmp_path / "bad.bg"), "--data", str(data), "--compare", "y=y",
                                           "--estimate", "c=0.1:2"], {"bad.bg": bad})
    assert status == 1 and "[E891]" in err


def test_diagnostic_write_over_a_file_bondc_did_not_write(tmp_path, capsys):
    data = msd_data(tmp_path, seed=0, name="measured.csv")
    mine = tmp_path / "mine.bg"
    mine.write_text("# my own model\n", encoding="utf-8")
    status, err = _code(tmp_path, capsys, ["fit", str(MSD), "--data", str(data), "--compare", "x=x_meas",
                                           "--estimate", "b", "--write", str(mine)])
    assert status == 2 and "[E890]" in err and "not written by bondc fit" in err
    assert mine.read_text() == "# my own model\n"
    status, err = _code(tmp_path, capsys, ["fit", str(MSD), "--data", str(data), "--compare", "x=x_meas",
                                           "--estimate", "b", "--write", str(MSD)])
    assert status == 2 and ("[E890]" in err or "[E003]" in err)


def test_api_errors_are_bondc_errors(tmp_path):
    data = msd_data(tmp_path, seed=0)
    with pytest.raises(BondcError) as raised:
        bondc.fit(MSD, data=data, compare=["x=x_meas"], estimate=["q"])
    assert raised.value.diagnostics[0].code == "E882"
