"""Every test in this folder needs a SocketCAN vcan0: natively where the kernel has vcan, else
inside User-Mode Linux (hil/uml/). Without either they FAIL with what to install, never skip; to
leave them out on purpose: ``python3 -m pytest -m 'not vcan'``."""

import pytest

from hil.uml.runner import VcanUnavailable, where


def pytest_collection_modifyitems(config, items):  # noqa: ARG001
    for item in items:
        if "tests/vcan/" in item.nodeid.replace("\\", "/"):
            item.add_marker(pytest.mark.vcan)


@pytest.fixture(scope="module")
def vcan_place() -> str:
    """Where vcan0 is had: "native" or "uml"; a test that needs it fails, loudly, where it is not."""
    try:
        return where("auto")
    except VcanUnavailable as exc:
        pytest.fail(f"this test needs a SocketCAN vcan0: {exc}", pytrace=False)
