"""The test suite's own set-up: plain ``pytest`` and ``python3 -m pytest`` both work from the
repository's root (``pythonpath = ["."]`` in pyproject.toml puts it on the path, so
``tests.fakes`` and the packages import the same either way).

The suite needs every extra (``pip install -e '.[test]'``): where one is missing, the run stops
at once with the command to install it, rather than skipping the tests that need it.
"""

from __future__ import annotations

import importlib.util

import pytest

from controller.cli.common import EXTRAS, missing_extras


def pytest_sessionstart(session):  # noqa: ARG001
    missing = missing_extras(tuple(EXTRAS))
    if missing:
        mods = ", ".join(m for extra in missing for m in EXTRAS[extra] if importlib.util.find_spec(m) is None)
        raise pytest.UsageError(f"the tests need {mods}, not installed here: pip install -e '.[test]'")
