"""Conventions of the command line (issue "Robustness and conventions", item 9): a bad --set value
is a usage error, several files to check and fmt, -q/-v, JSON summaries, the cache command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bondc.cli import main

ROOT = Path(__file__).resolve().parent.parent
MSD = ROOT / "models" / "mass_spring_damper.bg"


@pytest.fixture(autouse=True)
def _no_cache(monkeypatch):
    monkeypatch.setenv("BONDC_CACHE", "0")


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


# ------------------------------------------------------------------ 1. --set values

@pytest.mark.parametrize("value, code", [("k=", "E007"), ("k", "E007"), ("k=3 +", "E007"), ("k=abc", "E301"),
                                         ("nosuch=3", "E301"), ("k=3 [s]", "E204")])
def test_a_bad_set_value_is_a_usage_error(capsys, value, code):
    """``--set k=abc`` is the command line's fault: exit 2 (it was 1, as for a model with errors)."""
    status, _, err = _run(capsys, "check", MSD, "--set", value)
    assert status == 2
    assert f"error[{code}]" in err and "--set #1" in err
    assert "Traceback" not in err


def test_a_set_value_that_is_not_name_equals_value_says_what_one_is(capsys):
    status, _, err = _run(capsys, "simulate", MSD, "--set", "k=")
    assert status == 2
    assert "error[E007]: --set 'k=' is not NAME=VALUE [unit]" in err
    assert "hint: a --set value is NAME=VALUE" in err


def test_an_undefined_name_in_a_set_value_has_the_set_hint(capsys):
    status, out, err = _run(capsys, "simulate", MSD, "--json", "--set", "k=abc")
    assert status == 2
    data = json.loads(out)
    assert data["complete"] is False
    [diagnostic] = data["diagnostics"]
    assert diagnostic["code"] == "E301" and "a --set value is NAME=VALUE" in diagnostic["hint"]


def test_a_good_set_value_and_a_model_error_keep_their_statuses(capsys, tmp_path):
    assert _run(capsys, "check", MSD, "--set", "k=900")[0] == 0
    broken = tmp_path / "broken.bg"
    broken.write_text("model M\n  Se s : e = 1\n  R r : f = e/2\n  s -> r\n  output y = nothing\nend\n")
    assert _run(capsys, "check", broken, "--set", "nothing=3")[0] == 2     # (not a parameter: the --set)
    assert _run(capsys, "check", broken)[0] == 1


# ------------------------------------------------------------------ 2. several files

UNFORMATTED = "model M\n  param k=3\n  Se s : e = k\n  R r : f = e/2\n  s -> r\nend\n"
BROKEN = "model M\n  Se s : e = 1\n  R r : f = e/2\n  s -> r\n  output y = nothing\nend\n"


def test_check_takes_several_files_and_exits_with_the_worst(capsys, tmp_path):
    (tmp_path / "broken.bg").write_text(BROKEN)
    status, out, err = _run(capsys, "check", MSD, ROOT / "models" / "series_rlc.bg")
    assert status == 0
    assert "MassSpringDamper:" in out and "SeriesRLC:" in out
    status, out, err = _run(capsys, "check", MSD, tmp_path / "broken.bg")
    assert status == 1
    assert "MassSpringDamper:" in out and "error[E301]" in err
    # a file that cannot be read is reported, and the others are still checked
    status, out, err = _run(capsys, "check", tmp_path / "missing.bg", tmp_path / "broken.bg", MSD)
    assert status == 2
    assert "error[E002]" in err and "error[E301]" in err and "MassSpringDamper:" in out


def test_check_json_of_several_files_is_an_array_keyed_by_file(capsys, tmp_path):
    (tmp_path / "broken.bg").write_text(BROKEN)
    status, out, _ = _run(capsys, "check", "--json", MSD, tmp_path / "broken.bg", tmp_path / "missing.bg")
    assert status == 2
    rows = json.loads(out)
    assert [row["file"] for row in rows] == [str(MSD), str(tmp_path / "broken.bg"), str(tmp_path / "missing.bg")]
    assert [row["ok"] for row in rows] == [True, False, False]
    assert rows[0]["model"]["name"] == "MassSpringDamper"
    assert rows[1]["diagnostics"][0]["code"] == "E301" and rows[2]["diagnostics"][0]["code"] == "E002"
    # one file: the object as before
    status, out, _ = _run(capsys, "check", "--json", MSD)
    assert status == 0 and json.loads(out)["model"]["name"] == "MassSpringDamper"


def test_fmt_check_takes_several_files_and_exits_with_the_worst(capsys, tmp_path):
    good = tmp_path / "good.bg"
    good.write_text(MSD.read_text())
    (tmp_path / "messy.bg").write_text(UNFORMATTED)
    (tmp_path / "broken.bg").write_text("model M\n")
    assert _run(capsys, "fmt", "--check", good)[0] == 0
    status, _, err = _run(capsys, "fmt", "--check", good, tmp_path / "messy.bg", tmp_path / "broken.bg")
    assert status == 1
    assert "messy.bg: would be reformatted" in err and "error[E103]" in err and "good.bg" not in err
    status, out, _ = _run(capsys, "fmt", "--check", "--json", good, tmp_path / "messy.bg")
    assert status == 1
    assert [(row["file"].rsplit("/", 1)[-1], row["formatted"]) for row in json.loads(out)] == \
        [("good.bg", True), ("messy.bg", False)]


def test_fmt_write_rewrites_several_files(capsys, tmp_path):
    for name in ("a.bg", "b.bg"):
        (tmp_path / name).write_text(UNFORMATTED)
    status, out, err = _run(capsys, "fmt", "--write", "--json", tmp_path / "a.bg", tmp_path / "b.bg")
    assert status == 0
    assert [row["written"] for row in json.loads(out)] == [True, True]
    assert _run(capsys, "fmt", "--check", tmp_path / "a.bg", tmp_path / "b.bg")[0] == 0


def test_fmt_prints_only_one_file(capsys, tmp_path):
    status, out, err = _run(capsys, "fmt", MSD, MSD)
    assert status == 2 and "error[E001]" in err and out == ""


# ------------------------------------------------------------------ 3. -q and -v

def test_quiet_prints_only_errors(capsys, tmp_path):
    gear = ROOT / "models" / "dc_motor_gear.bg"         # a warning (W602) and a summary line
    status, out, err = _run(capsys, "check", gear)
    assert status == 0 and "warning[W602]" in err and "DCMotorGear:" in out
    for argv in (("-q", "check", gear), ("check", "-q", gear), ("check", "--quiet", gear)):
        assert _run(capsys, *argv) == (0, "", "")
    (tmp_path / "broken.bg").write_text(BROKEN)
    status, out, err = _run(capsys, "-q", "check", gear, tmp_path / "broken.bg")
    assert status == 1 and "error[E301]" in err and "W602" not in err and out == ""


def test_verbose_adds_notes_and_quiet_with_verbose_is_a_usage_error(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("BONDC_CACHE_DIR", str(tmp_path / "cache"))
    status, out, err = _run(capsys, "-v", "check", MSD)
    assert status == 0 and "MassSpringDamper:" in out
    assert f"note: cache folder {tmp_path / 'cache'}" in err and "note: bondc check took" in err
    status, _, err = _run(capsys, "-q", "-v", "check", MSD)
    assert status == 2 and "error[E001]" in err
    assert "note:" not in _run(capsys, "check", MSD)[2]        # (not left on for the next run)


# ------------------------------------------------------------------ 4. licence and metadata

def test_the_licence_is_mit_in_the_repository_and_the_metadata():
    tomllib = pytest.importorskip("tomllib")
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("MIT License") and "Copyright (c) the bondc authors" in text
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    project = pyproject["project"]
    assert project["license"] == "MIT"              # SPDX (PEP 639), not the deprecated table
    assert project["license-files"] == ["LICENSE"]
    assert project["authors"] == [{"name": "the bondc authors"}]
    assert project["classifiers"] and not any(c.startswith("License ::") for c in project["classifiers"])
    assert "setuptools>=77" in pyproject["build-system"]["requires"]


@pytest.mark.slow
def test_the_wheel_carries_the_licence_without_a_deprecation_warning(tmp_path):
    import subprocess
    import sys
    import zipfile

    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-v", "-w", str(tmp_path), str(ROOT)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "SetuptoolsDeprecationWarning" not in out.stdout + out.stderr
    [wheel] = tmp_path.glob("bondc-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert any(name.endswith(".dist-info/licenses/LICENSE") for name in names)
    metadata = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert "License-Expression: MIT" in metadata


# ------------------------------------------------------------------ 6. --json summaries

def test_compile_json_says_what_it_wrote(capsys, tmp_path):
    target = tmp_path / "msd_gen.py"
    status, out, _ = _run(capsys, "compile", MSD, "-o", target, "--json")
    assert status == 0 and target.is_file()
    data = json.loads(out)
    assert data["complete"] is True and data["written"] == [str(target)] and data["standalone"] is False
    status, out, _ = _run(capsys, "compile", MSD, "-o", target, "--json", "--set", "k=")
    assert status == 2 and json.loads(out)["diagnostics"][0]["code"] == "E007"


# ------------------------------------------------------------------ validate --json, report --json

def _rlc_measured(tmp_path, scale=1.0):
    from bondc.pipeline import simulate_file as simulate_run

    result = simulate_run(ROOT / "models" / "series_rlc.bg")
    lines = ["time,i_meas,v_C_meas"] + [f"{float(t)!r},{scale * float(i)!r},{float(v)!r}"
                                         for t, i, v in zip(result.t, result.outputs["i"], result.outputs["v_C"])]
    data = tmp_path / "bench.csv"
    data.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return data


def test_validate_json_says_pass_or_fail_per_signal_and_what_it_wrote(capsys, tmp_path):
    data = _rlc_measured(tmp_path, scale=1.3)
    junit = tmp_path / "out" / "junit.xml"
    status, out, _ = _run(capsys, "validate", ROOT / "models" / "series_rlc.bg", "--data", data, "--json",
                          "--compare", "i=i_meas", "--compare", "v_C=v_C_meas", "--junit", junit)
    summary = json.loads(out)
    assert status == 1 and summary["exit_status"] == 1 and summary["complete"] and not summary["passed"]
    assert [(s["name"], s["passed"]) for s in summary["signals"]] == [("i=i_meas", False), ("v_C=v_C_meas", True)]
    assert summary["signals"][0]["checks"][0]["metric"] and summary["signals"][0]["unit"] == "A"
    assert summary["written"] == [str(junit)] and junit.is_file()
    status, out, _ = _run(capsys, "validate", ROOT / "models" / "series_rlc.bg", "--data", _rlc_measured(tmp_path),
                          "--compare", "i=i_meas")
    assert status == 0 and "1 of 1 signal passed" in out and not out.lstrip().startswith("{")


def test_validate_json_of_bad_input_is_json_with_the_code(capsys, tmp_path):
    data = tmp_path / "bench.csv"
    data.write_text("time,x\n0,1\n1,2\n", encoding="utf-8")
    status, out, err = _run(capsys, "validate", ROOT / "models" / "series_rlc.bg", "--data", data, "--json",
                            "--compare", "i=missing")
    failure = json.loads(out)
    assert status != 0 and failure["complete"] is False and failure["diagnostics"][0]["code"] in err


@pytest.mark.slow       # a whole report
def test_report_json_says_what_it_wrote(capsys, tmp_path):
    target = tmp_path / "r.html"
    status, out, _ = _run(capsys, "report", ROOT / "models" / "series_rlc.bg", "--json", "-o", target)
    summary = json.loads(out)
    assert status == 0 and summary["written"] == [str(target)] and target.is_file()
    assert summary["complete"] and summary["signals"] == [] and summary["failing"] == []


def test_help_of_bondc_and_of_every_command_prints_usage(capsys):
    """``bondc --help`` and ``bondc COMMAND --help`` print their usage and exit 0 (a help text with a
    bare '%' made argparse's formatting fail, as an internal error)."""
    from bondc.cli import build_parser, main

    commands = next(action for action in build_parser()._actions if hasattr(action, "_choices_actions"))
    for arguments in [["--help"]] + [[name, "--help"] for name in commands.choices]:
        try:
            code = main(arguments)
        except SystemExit as stop:
            code = stop.code
        assert code == 0, arguments
        captured = capsys.readouterr()
        assert captured.out.startswith("usage: bondc"), arguments
        assert "internal error" not in captured.err
