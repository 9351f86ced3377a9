"""Every module's docstring examples run, as written (``python -m doctest`` of each module of the
package, from the repository's root, where their paths such as ``models/...`` point)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil
from pathlib import Path

import pytest

import bondc

ROOT = Path(__file__).resolve().parent.parent
# __main__ runs the command line when imported
MODULES = sorted(info.name for info in pkgutil.walk_packages(bondc.__path__, "bondc.")
                 if not info.name.endswith("__main__"))


def test_every_module_of_the_package_is_found():
    assert {"bondc.api", "bondc.codegen.emit", "bondc.analysis.energy", "bondc.report.diagram"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_the_docstring_examples_run(name, monkeypatch):
    monkeypatch.chdir(ROOT)
    # importlib: a package may re-export a function under its module's name (bondc.codegen.emit)
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert not result.failed, name
