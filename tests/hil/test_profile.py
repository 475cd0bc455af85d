"""The platform profile (hil.profile): every allowance that differs inside User-Mode Linux, decided once."""

from __future__ import annotations

from pathlib import Path

from controller.config import ControllerConfig
from hil import profile


def test_the_profile_is_decided_by_the_uml_runner(monkeypatch):
    monkeypatch.delenv("ELEGANT_STEPPING_IN_UML", raising=False)
    assert profile.current() is profile.NATIVE and not profile.current().uml
    monkeypatch.setenv("ELEGANT_STEPPING_IN_UML", "1")
    assert profile.current() is profile.UML and profile.current().uml
    assert profile.named("uml") is profile.UML and profile.named("native") is profile.NATIVE
    assert profile.named("elsewhere") is profile.NATIVE


def test_the_allowances_of_each_platform():
    n, u = profile.NATIVE, profile.UML
    assert (n.mitm_poll_s, u.mitm_poll_s) == (0.0005, 0.002)
    assert (n.plant_steps_per_wake, u.plant_steps_per_wake) == (1, 2)
    assert (n.safe_state_tolerance_ms, u.safe_state_tolerance_ms) == (20.0, 50.0)
    assert (n.work_on_shm, u.work_on_shm) == (False, True)
    assert (n.driver_watchdog_s, u.driver_watchdog_s) == (None, 0.3)
    ctl = ControllerConfig()
    assert n.controller_config(ctl) is ctl
    patient = u.controller_config(ctl)
    assert patient.silence_periods == max(10.0, ctl.silence_periods)
    assert patient.stale_heartbeat_periods == max(10.0, ctl.stale_heartbeat_periods)
    assert n.work_folder(Path("/x"), "p-") == Path("/x")
