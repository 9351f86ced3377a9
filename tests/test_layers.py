"""The package's shape: no import cycle among its modules (counting imports inside functions), at
every level, and its layers -- the command line over the editor's server over the API over the
reports and exports over the analyses -- as import-linter checks the contracts in pyproject.toml.
(The 18-module cycle of issue 39 was broken at its edges: the cache folder and the version in
modules of their own, a unit's text parsed by bondc.units, the hint of --set in semantic, the
stored-energy recipes read by the energy account, compile_file in the pipeline, measured-data
comparison under analysis, a law's span in bondc.model.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_import_linter_keeps_every_contract(tmp_path):
    done = subprocess.run([sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
                           "sys.argv = ['lint-imports', '--no-cache']; lint_imports_command()"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "2 kept, 0 broken" in done.stdout
