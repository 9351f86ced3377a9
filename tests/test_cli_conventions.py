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
