"""Contact reflexes classified by the leg's phase; the hardwired lift reflex."""

from __future__ import annotations

import pytest

from controller.motion.cpg import CpgOutput
from controller.stepping.reflexes import ContactReflexes, ReflexConfig, lift_amplitude


def cpg(swing: bool, phase: float) -> CpgOutput:
    return CpgOutput(onset=False, flexing=swing, phase=phase, flexor_drive=1.0 if swing else 0.0, step_index=3)


@pytest.mark.parametrize(
    "swing,phase,kind",
    [(True, 0.2, "placement"), (True, 0.49, "placement"), (False, 0.8, "placement"),
     (True, 0.6, "extension"), (False, 0.1, "extension"), (True, 0.75, "extension")],
)
def test_shin_contact_kind_follows_the_phase(swing, phase, kind):
    r = ContactReflexes()
    assert r.update(0.0, cpg(swing, phase), foot=False, shin=False, foot_height_m=lambda: 0.1) is None
    reflex = r.update(0.002, cpg(swing, phase), foot=False, shin=True, foot_height_m=lambda: 0.1)
    assert reflex is not None and reflex.kind == kind and reflex.cause == "shin"


def test_foot_striking_in_the_air_is_a_reflex_but_a_touchdown_is_not():
    r = ContactReflexes()
    r.update(0.0, cpg(True, 0.3), False, False, lambda: 0.08)
    assert r.update(0.002, cpg(True, 0.3), True, False, lambda: 0.08).cause == "foot_in_air"
    r2 = ContactReflexes()
    r2.update(0.0, cpg(True, 0.97), False, False, lambda: 0.005)
    assert r2.update(0.002, cpg(True, 0.97), True, False, lambda: 0.005) is None  # a normal touchdown
    r3 = ContactReflexes()
    r3.update(0.0, cpg(False, 0.01), False, False, lambda: 0.08)
    reflex = r3.update(0.002, cpg(False, 0.01), True, False, lambda: 0.08)
    assert reflex.cause == "foot_on_top" and reflex.kind == "extension"


def test_one_collision_is_one_reflex():
    r = ContactReflexes(ReflexConfig(refractory_s=1.0))
    r.update(0.0, cpg(True, 0.3), False, False, lambda: 0.1)
    assert r.update(0.01, cpg(True, 0.3), False, True, lambda: 0.1) is not None
    r.update(0.02, cpg(True, 0.3), False, False, lambda: 0.1)
    assert r.update(0.5, cpg(True, 0.6), False, True, lambda: 0.1) is None
    r.update(0.6, cpg(True, 0.6), False, False, lambda: 0.1)
    assert r.update(1.2, cpg(True, 0.6), False, True, lambda: 0.1) is not None


def test_lift_reflex_fires_only_when_the_obstacle_is_within_reach():
    cfg = ReflexConfig(lift_range_m=0.4, lift_amplitude=1.9)
    assert lift_amplitude(cfg, 0.3) == 1.9
    assert lift_amplitude(cfg, 0.5) == 1.0
    assert lift_amplitude(cfg, None) == 1.0
