"""Robustness of the command line against hostile or broken surroundings: a reader that closes
the pipe early, output paths that are the command's own inputs, files that are not models or
CSV tables, terminal control bytes in the text it quotes, and numbers or names far beyond any
model's."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bondc.cli import main

ROOT = Path(__file__).resolve().parent.parent

#: 2000 undefined names: a few hundred kB of diagnostics, far more than a pipe's buffer (64 kB),
#: so that the writer is still writing when the reader has gone.
BROKEN = ("model M\n  Se s : e = 1\n  R r : f = e/2\n  s -> r\n"
          + "".join(f"  output y{i} = undefined_{i}\n" for i in range(2000)) + "end\n")


def _first_line_then_close(command: list[str], cwd: Path, merge_stderr: bool) -> tuple[str, int, str]:
    """Run ``python -m bondc COMMAND`` into a pipe whose reader takes one line and closes it (as
    ``| head -1`` does): (that line, the exit status, what went to stderr when not merged)."""
    environment = {**os.environ, "PYTHONPATH": str(ROOT), "BONDC_CACHE": "0"}
    errors = cwd / "stderr.txt"
    with open(errors, "w") as stderr:
        process = subprocess.Popen([sys.executable, "-m", "bondc", *command], cwd=cwd, env=environment,
                                   stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT if merge_stderr else stderr)
        line = process.stdout.readline().decode()
        process.stdout.close()
        status = process.wait(timeout=120)
    return line, status, errors.read_text()


def test_a_failing_check_into_a_closed_pipe_exits_with_its_own_status(tmp_path):
    """``bondc check broken.bg 2>&1 | head -1``: the reader goes after the first diagnostic, the
    check goes on and exits 1 (it exited 0: a closed pipe counted as success)."""
    (tmp_path / "broken.bg").write_text(BROKEN)
    line, status, _ = _first_line_then_close(["check", "broken.bg"], tmp_path, merge_stderr=True)
    assert "error[E301]" in line
    assert status == 1


def test_a_failing_check_as_json_into_a_closed_pipe_exits_1_without_a_traceback(tmp_path):
    (tmp_path / "broken.bg").write_text(BROKEN)
    line, status, errors = _first_line_then_close(["check", "--json", "broken.bg"], tmp_path, merge_stderr=False)
    assert line == "{\n"
    assert status == 1
    assert "Traceback" not in errors and "Exception ignored" not in errors and "internal error" not in errors


def _check(path: Path, *options: str) -> tuple[int, str]:
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["check", str(path), *options])
    return code, err.getvalue()


PLAIN = "model M\n  param k = 2\n  {kind} s : e = {law}\n  R r : f = e/k\n  s -> r\nend\n"


def test_an_integer_of_5000_digits_in_a_law_is_a_constant_beyond_a_doubles_range(tmp_path):
    """It was an internal error (Python converts at most 4300 digits); it is what 1e309 is there."""
    path = tmp_path / "big.bg"
    path.write_text(PLAIN.format(kind="Se", law="1" + "0" * 5000))
    code, err = _check(path)
    assert code == 1
    assert "big.bg:3:14: error[E701]: this constant is not a finite number" in err
    assert "internal error" not in err


def test_an_import_path_longer_than_the_system_allows_is_e307(tmp_path):
    path = tmp_path / "long.bg"
    path.write_text(f'import "{"a" * 5000}.bg"\n' + PLAIN.format(kind="Se", law="1"))
    code, err = _check(path)
    assert code == 1
    assert "long.bg:1:1: error[E307]: cannot find imported file 'aaaa" in err
    assert "(5003 characters)': file name too long" in err
    assert "internal error" not in err


SECRET = "alice_s3cret:x:0:0:hunter2:/home/a:/bin/sh\nbob_s3cret:x:1:1:bob:/home/b:/usr/sbin/nologin\n"


def test_an_import_of_a_file_that_is_not_a_model_quotes_none_of_it(tmp_path):
    """``import "/etc/passwd"`` quoted its lines in up to 20 syntax errors."""
    (tmp_path / "passwd").write_text(SECRET)
    path = tmp_path / "m.bg"
    path.write_text('import "passwd"\n' + PLAIN.format(kind="Se", law="1"))
    code, err = _check(path)
    assert code == 1
    assert "m.bg:1:1: error[E307]: cannot import 'passwd': it is not a .bg model file" in err
    assert "s3cret" not in err and "hunter2" not in err


def test_an_import_of_a_link_named_bg_to_a_file_that_is_not_a_model_quotes_none_of_it(tmp_path):
    (tmp_path / "passwd").write_text(SECRET)
    (tmp_path / "lib.bg").symlink_to(tmp_path / "passwd")
    path = tmp_path / "m.bg"
    path.write_text('import "lib.bg"\n' + PLAIN.format(kind="Se", law="1"))
    code, err = _check(path)
    assert code == 1 and "error[E307]: cannot import 'lib.bg': it is a link to a file that is not a .bg" in err
    assert "s3cret" not in err and "hunter2" not in err


@pytest.mark.parametrize("content", [
    SECRET,                                                             # /etc/passwd
    "HOME=/s3cret\x00API_TOKEN=hunter2,s3cret\x00SHELL=/bin/sh\x00",    # /proc/self/environ
])
def test_a_csv_call_on_a_file_that_is_not_a_table_quotes_none_of_it(tmp_path, content):
    """``csv("/etc/passwd", "root")`` showed its first line as the columns' hint, and
    ``/proc/self/environ`` the whole environment."""
    (tmp_path / "secret").write_text(content)
    path = tmp_path / "m.bg"
    path.write_text(PLAIN.format(kind="MSe", law='csv("secret", "alice")'))
    code, err = _check(path)
    assert code == 1
    assert "m.bg:3:19: error[E310]: 'secret' is not a CSV table" in err
    assert "hunter2" not in err and "s3cret" not in err


def test_a_csv_row_that_is_not_numbers_is_named_not_quoted(tmp_path):
    """A table's column names may be shown, its rows not (they were quoted whole)."""
    (tmp_path / "users.csv").write_text("t,password\n0,1\n1,hunter2\n")
    path = tmp_path / "m.bg"
    path.write_text(PLAIN.format(kind="MSe", law='csv("users.csv", "password")'))
    code, err = _check(path)
    assert code == 1
    assert "error[E310]: CSV file 'users.csv': row 3 has no number in column 'password'" in err
    assert "hunter2" not in err


def test_terminal_control_bytes_are_escaped_in_excerpts_with_the_caret_under_them(tmp_path):
    """ESC and BEL from a model line were written to the terminal as they are."""
    path = tmp_path / "m.bg"
    path.write_text(PLAIN.format(kind="Se", law="1 + \x1b[31mx\x07").replace("param k = 2", "param k = 2\x07"))
    code, err = _check(path)
    assert code == 1
    assert "\x1b" not in err and "\x07" not in err
    lines = err.splitlines()
    shown = lines.index("3 |   Se s : e = 1 + \\x1b[31mx\\x07")
    caret = lines[shown + 1]
    assert caret.index("^") == lines[shown].index("\\x1b") and caret.count("^") == len("\\x1b")


def test_terminal_control_bytes_of_a_csv_header_are_escaped(tmp_path):
    (tmp_path / "w.csv").write_text("t,om\x1b]0;pwned\x07ega\n0,1\n")
    path = tmp_path / "m.bg"
    path.write_text(PLAIN.format(kind="MSe", law='csv("w.csv", "omega")'))
    code, err = _check(path)
    assert code == 1 and "\x1b" not in err and "\x07" not in err


def test_a_parameter_whose_si_value_is_not_finite_is_e311(tmp_path):
    """1e308 kN/m is 1e311 N/m: the generated module held a bare `inf` (NameError, exit 3)."""
    path = tmp_path / "m.bg"
    path.write_text("model M\n  param k = 1e308 [kN/m]\n  Se s : e = 1\n  C c : e = k*q\n  R r : e = 2*f\n"
                    "  1 j\n  s -> j\n  j -> c\n  j -> r\n  experiment x\n    t_end = 1\n  end\nend\n")
    code, err = _check(path)
    assert code == 1
    assert "m.bg:2:13: error[E311]: cannot evaluate: 1e+308 [kN/m] is an infinite number in SI units" in err


def test_a_first_step_of_1e_300_runs_and_accounts_energy(tmp_path):
    """It stopped after 200 steps that did not advance (E811), and the energy account then failed
    on an empty run (ValueError, exit 3). The step starts where it advances; the run ends at t_end
    and its energy balance closes: the source's work is what the damper took plus what the mass
    holds."""
    import contextlib
    import io
    import json

    path = tmp_path / "m.bg"
    path.write_text("model M\n  Se s : e = 1\n  I m : f = p/2\n  R r : e = f\n  1 j\n  s -> j\n  j -> m\n  j -> r\n"
                    "  experiment x\n    t_end = 1\n    first_step = 1e-300\n  end\nend\n")
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = main(["simulate", str(path), "--json"])
    assert code == 0
    summary = json.loads(out.getvalue())
    # p(t) = 2 (1 - exp(-t/2)): the mass stores p^2/4 at t = 1
    p = 2 * (1 - 2.718281828459045 ** -0.5)
    assert summary["final"]["m.p"] == pytest.approx(p, rel=1e-4)
    balance = summary["energy"]["cycles"][0]["balance"]
    assert balance["stored_change"] == pytest.approx(p ** 2 / 4, rel=1e-4)
    assert balance["supplied"] == pytest.approx(balance["dissipated"] + balance["stored_change"], rel=1e-6)


def test_an_absurdly_long_unknown_unit_is_e201_without_a_search_for_a_spelling(tmp_path, monkeypatch):
    """A unit name of 300 kB took 19 s in the "did you mean" search (quadratic in its length); no
    unit is spelt with more than 11 letters, so such a name gets no search at all."""
    from bondc import units

    searched = []
    real = units.difflib.get_close_matches
    monkeypatch.setattr(units.difflib, "get_close_matches",
                        lambda name, *args, **kw: searched.append(len(name)) or real(name, *args, **kw))
    path = tmp_path / "m.bg"
    path.write_text(PLAIN.format(kind="Se", law="1").replace("param k = 2", "param k = 2 [" + "x" * 300_000 + "]"))
    code, err = _check(path)
    assert code == 1 and "m.bg:2:16: error[E201]: unknown unit 'xxxx" in err
    assert all(length <= units.MAX_SUGGESTED for length in searched)


MODEL = ("model M\n  input F [N] = csv(\"push.csv\", \"F\")\n  MSe s : e = F\n  R r : f = e/2\n  s -> r\n"
         "  experiment x\n    t_end = 1\n  end\nend\n")


@pytest.mark.parametrize("command, output", [
    ("compile", "m.bg"), ("simulate", "m.bg"), ("report", "m.bg"),      # the model file itself
    ("compile", "lib.bg"),                                              # a file it imports
    ("simulate", "push.csv"),                                           # a data file it reads
])
def test_an_output_that_is_one_of_the_inputs_is_refused_before_any_work(tmp_path, monkeypatch, capsys,
                                                                          command, output):
    """``bondc compile -o m.bg m.bg`` replaced the model with the generated module."""
    monkeypatch.chdir(tmp_path)
    files = {"m.bg": 'import "lib.bg"\n' + MODEL, "lib.bg": "fn twice(x) = 2*x\n", "push.csv": "t,F\n0,1\n1,2\n"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    assert main([command, "m.bg", "-o", output]) == 2
    err = capsys.readouterr().err
    assert f"error[E003]: cannot write the output '{output}' (-o): it is the" in err
    assert {name: (tmp_path / name).read_text() for name in files} == files
