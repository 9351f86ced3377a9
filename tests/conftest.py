"""Shared pytest options: ``pytest --update-golden`` rewrites golden files instead of comparing."""

import os
import sys
import tempfile

import pytest

# Tests never reuse a derived model from the compile cache (a test that changes bondc's behaviour
# must see it run; tests/test_cache.py turns the cache on in folders of its own). The compiled C
# libraries, keyed by their exact text and flags, are kept between test sessions in a folder of
# the tests' own, never in the user's cache.
os.environ["BONDC_CACHE"] = "0"
os.environ["BONDC_CACHE_DIR"] = os.path.join(tempfile.gettempdir(), f"bondc-test-cache-{os.getuid() if hasattr(os, 'getuid') else 'user'}")


def pytest_addoption(parser):
    parser.addoption("--update-golden", action="store_true", default=False,
                     help="rewrite the expected (golden) files from the current output")


@pytest.fixture
def update_golden(request) -> bool:
    return bool(request.config.getoption("--update-golden"))


def pytest_terminal_summary(terminalreporter):
    """The fuzz harness's counts (tests/test_fuzz.py), when it ran."""
    fuzz = sys.modules.get("test_fuzz")
    if fuzz is not None and fuzz.SUMMARY:
        terminalreporter.section("fuzz harness")
        for line in fuzz.SUMMARY.values():
            terminalreporter.write_line(line)
