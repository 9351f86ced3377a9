"""Data files are regular files of bounded size: a device or a named pipe is a diagnostic at once.

Each command runs in a subprocess with a time limit, so a regression (reading /dev/zero for ever,
blocking on a pipe) fails the test instead of hanging the suite.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

SIM = Path(__file__).parent / "fixtures" / "sim"


def bondc(*args, cwd):
    return subprocess.run([sys.executable, "-m", "bondc", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=60)


@pytest.fixture(params=["device", "pipe"])
def endless(request, tmp_path):
    if request.param == "device":
        return "/dev/zero"
    path = tmp_path / "pipe.csv"
    os.mkfifo(path)
    return str(path)


def test_check_refuses_a_data_file_that_is_not_a_regular_file(tmp_path, endless):
    model = tmp_path / "model.bg"
    model.write_text(f'model M\n  input F [N] = csv("{endless}", "x")\n  Se s : e = F\n  I m : f = p/1\n  s -> m\nend\n')
    done = bondc("check", str(model), cwd=tmp_path)
    assert done.returncode == 1
    assert "error[E310]" in done.stderr and "not a regular file" in done.stderr
    assert f"{model}:2:21" in done.stderr


@pytest.mark.slow
def test_validate_and_fit_friction_refuse_it_too(tmp_path, endless):
    done = bondc("validate", str(SIM / "msd.bg"), "--data", endless, "--compare", "x=x", cwd=tmp_path)
    assert "error[E950]" in done.stderr and "not a regular file" in done.stderr
    done = bondc("fit-friction", endless, cwd=tmp_path)
    assert "error[E905]" in done.stderr and "not a regular file" in done.stderr
