"""Shared pytest options: ``pytest --update-golden`` rewrites golden files instead of comparing."""

import os
import tempfile

import pytest

# The compile cache and the compiled C libraries of this test run live in a folder of their own,
# never in the user's cache (tests that need an empty cache make their own).
os.environ["BONDC_CACHE_DIR"] = tempfile.mkdtemp(prefix="bondc-test-cache-")


def pytest_addoption(parser):
    parser.addoption("--update-golden", action="store_true", default=False,
                     help="rewrite the expected (golden) files from the current output")


@pytest.fixture
def update_golden(request) -> bool:
    return bool(request.config.getoption("--update-golden"))
