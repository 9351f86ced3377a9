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
