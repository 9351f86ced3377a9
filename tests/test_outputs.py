"""Output paths are checked before any work (E003), only regular files are replaced, and a write
that fails at the end keeps the content in a file it names (E004): no result is lost, no internal error."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from bondc.cli import main
from bondc.errors import UsageError
from bondc.io import atomic_write_text, check_output

ROOT = Path(__file__).resolve().parent.parent
MSD = str(ROOT / "models" / "mass_spring_damper.bg")


def _code(capsys):
    return capsys.readouterr().err


@pytest.fixture
def no_simulation(monkeypatch):
    """Fails the test if a command starts deriving the model: the path check must come first."""
    def refuse(*args, **kwargs):
        raise AssertionError("the model was derived before the output path was checked")

    monkeypatch.setattr("bondc.pipeline.derive_file", refuse)


@pytest.mark.parametrize("command", [
    ["simulate", MSD, "-o", "{missing}/out.csv"],
    ["compile", MSD, "-o", "{missing}/out.py"],
    ["sweep", MSD, "--vary", "k=400,800", "-o", "{missing}/sweep.csv"],
])
def test_a_missing_folder_is_reported_before_any_work(tmp_path, capsys, no_simulation, command):
    arguments = [part.format(missing=tmp_path / "nowhere") for part in command]
    assert main(arguments) == 2
    err = _code(capsys)
    assert "error[E003]" in err and "does not exist" in err and "mkdir -p" in err


@pytest.mark.parametrize("kind", ["folder", "named pipe", "symbolic link"])
def test_only_regular_files_are_replaced(tmp_path, capsys, no_simulation, kind):
    target = tmp_path / "out.csv"
    if kind == "folder":
        target.mkdir()
    elif kind == "named pipe":
        if not hasattr(os, "mkfifo"):
            pytest.skip("no named pipes here")
        os.mkfifo(target)
    else:
        (tmp_path / "real.csv").write_text("keep me\n")
        target.symlink_to(tmp_path / "real.csv")
    assert main(["simulate", MSD, "-o", str(target)]) == 2
    assert f"it is a {kind}" in _code(capsys)
    if kind == "symbolic link":
        assert target.is_symlink() and (tmp_path / "real.csv").read_text() == "keep me\n"


def test_report_and_junit_paths_are_checked_first(tmp_path, capsys, no_simulation):
    folder = tmp_path / "taken"
    folder.mkdir()
    assert main(["report", MSD, "-o", str(folder)]) == 2
    assert "cannot write the report" in _code(capsys)
    data = tmp_path / "m.csv"
    data.write_text("t,x\n0,0\n1,0\n")
    assert main(["validate", MSD, "--data", str(data), "--compare", "x=x", "--junit", str(folder)]) == 2
    assert "cannot write the JUnit XML" in _code(capsys)


def test_a_device_is_never_replaced():
    if not Path("/dev/null").exists():
        pytest.skip("no /dev/null")
    with pytest.raises(UsageError) as raised:
        check_output("/dev/null")
    assert raised.value.diagnostics[0].code == "E003" and "a device" in str(raised.value)


@pytest.mark.skipif(sys.platform == "win32" or os.geteuid() == 0, reason="needs a folder the user cannot write")
def test_a_read_only_folder(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(UsageError, match="not writable"):
            check_output(locked / "out.csv")
    finally:
        locked.chmod(0o700)


def test_a_write_that_fails_at_the_end_keeps_the_content(tmp_path, monkeypatch):
    """The disk fills up (the rename fails): E004 names a file that holds the whole content."""
    target = tmp_path / "out.csv"

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("bondc.io.os.replace", full)
    with pytest.raises(UsageError) as raised:
        atomic_write_text(target, "t,x\n0,1\n")
    diagnostic = raised.value.diagnostics[0]
    assert diagnostic.code == "E004" and "No space left on device" in diagnostic.message
    kept = Path(diagnostic.message.split("kept in '")[1].rstrip("'"))
    try:
        assert kept.read_text() == "t,x\n0,1\n"
        assert not target.exists() and not list(tmp_path.glob(".out.csv.*"))    # no half-written file
    finally:
        kept.unlink()


@pytest.mark.slow
def test_sigterm_ends_a_command_quietly_with_exit_143(tmp_path):
    """SIGTERM while the model is being compiled: no traceback, 'terminated', exit status 143."""
    import signal
    import subprocess
    import time

    from benchmarks.chain import chain_source

    model = tmp_path / "chain.bg"
    model.write_text(chain_source(2000))            # some seconds of compiling
    environment = {**os.environ, "BONDC_CACHE": "0", "PYTHONPATH": str(ROOT)}
    process = subprocess.Popen([sys.executable, "-m", "bondc", "simulate", str(model), "-o",
                                str(tmp_path / "out.csv")], stderr=subprocess.PIPE, text=True, env=environment)
    time.sleep(3)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143, err
    assert "terminated" in err and "Traceback" not in err


def test_a_termination_during_a_write_lets_the_write_finish(tmp_path):
    from bondc import io
    from bondc.cli import Terminated, _terminate

    target = tmp_path / "out.csv"

    def write(handle):
        handle.write(b"first half,")
        _terminate(15, None)                # SIGTERM arrives in the middle of the write
        handle.write(b"second half\n")

    with pytest.raises(Terminated):
        io.atomic_write(target, write)
    assert target.read_text() == "first half,second half\n"
    assert io._WRITES == {"depth": 0, "pending": None}


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads the process table in /proc")
def test_sigterm_to_a_parallel_sweep_ends_its_workers_too(tmp_path):
    import signal
    import subprocess
    import time

    def children(pid):
        found = []
        for stat_file in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat_file.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.append(int(stat_file.parent.name))
        return found

    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    process = subprocess.Popen([sys.executable, "-m", "bondc", "sweep", str(ROOT / "models" / "electro_pneumatic_hybrid.bg"),
                                "--vary", "M=30:40:8", "-j", "2"], stderr=subprocess.PIPE, stdout=subprocess.PIPE,
                               text=True, env=environment)
    deadline = time.time() + 60
    while not children(process.pid) and time.time() < deadline:
        time.sleep(0.2)
    workers = children(process.pid)
    assert workers, "the sweep started no worker processes"
    time.sleep(1.0)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143 and "Traceback" not in err, err
    time.sleep(0.5)
    alive = [pid for pid in workers if Path(f"/proc/{pid}").exists()
             and "Z" not in Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]]
    assert not alive, f"worker processes still running: {alive}"


def test_sigterm_while_the_report_is_built_keeps_the_simulation(tmp_path, monkeypatch, capsys):
    """SIGTERM after the simulation, during the report's post-processing: exit 143, the report is not
    written, and the simulated results are kept beside it exactly as ``bondc simulate`` writes them."""
    from bondc import cli
    from bondc.report import build

    model = ROOT / "tests/fixtures/sim/rc.bg"
    assert cli.main(["simulate", str(model), "-o", str(tmp_path / "simulated.csv")]) == 0

    def terminated(*args, **kwargs):
        cli._terminate(15, None)            # the signal arrives while the energy account is computed

    monkeypatch.setattr(build, "report_context", terminated)
    capsys.readouterr()
    assert cli.main(["report", str(model), "-o", str(tmp_path / "rc.html")]) == 143
    err = capsys.readouterr().err
    kept = tmp_path / "rc.interrupted.csv"
    assert not (tmp_path / "rc.html").exists()
    assert kept.read_text() == (tmp_path / "simulated.csv").read_text()
    assert f"kept in {kept}" in err and "terminated" in err and "Traceback" not in err
