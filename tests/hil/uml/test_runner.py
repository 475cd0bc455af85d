"""The User-Mode Linux runner without booting it: where it says vcan can be had, what it ships."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.uml.runner import VcanUnavailable


def test_where_fails_with_an_instruction_when_nothing_gives_vcan(monkeypatch):
    import hil.uml.runner as uml

    monkeypatch.setattr(uml, "native_vcan", lambda channel="vcan0", create=True: False)
    monkeypatch.setattr(uml, "uml_missing", lambda: "linux.uml not found")
    monkeypatch.delenv(uml.ENV_IN_UML, raising=False)
    with pytest.raises(VcanUnavailable, match="apt-get install -y user-mode-linux kmod"):
        uml.where("auto")
    with pytest.raises(VcanUnavailable, match="not vcan"):
        uml.where("auto")


def test_the_runner_is_shipped_with_the_project():
    root = Path(__file__).resolve().parents[3]
    for name in ("run-in-uml.sh", "uml-init", "xstate-shim.c", "coarse-time.c"):
        assert (root / "hil" / "uml" / name).exists(), name
