"""The walking skeleton through the whole stack in lockstep: every command and reading is a frame."""

from __future__ import annotations

import json

import pytest

from controller.supervisor import Phase
from hil.lockstep.harness import Lockstep, LockstepConfig
from hil.experiments.walk import run_walk
from protocol import AxisError, AxisState


@pytest.fixture(scope="module")
def walk20():
    return run_walk(20.0, seed=0)


def test_a_20_s_walk_takes_15_steps_with_clearance_and_within_limits(walk20):
    m = walk20
    assert m["phase"] == "walk", m["fault_cause"]
    assert m["steps"] >= 15
    assert m["swing_clearance_min_m"] >= 0.02
    assert m["commands_outside_limits"] == 0
    assert m["late_ticks"] == 0
    assert m["sim_s"] == pytest.approx(20.0)
    strides = m["stride_m"][2:]
    assert min(strides) > 0.3 and max(strides) < 0.4  # v * (stance + burst) = 0.5 * 0.7 = 0.35 m


def test_every_position_command_crosses_the_bus(walk20):
    m = walk20
    assert m["frames_tx"]["Set_Input_Pos"] == 2 * m["command_ticks"]
    assert m["frames_rx"]["Get_Encoder_Estimates"] >= 0.99 * 2 * 500 * 20.0
    assert m["frames_rx"]["Heartbeat"] >= 2 * 10 * 19


def test_driver_sees_exactly_the_frames_the_controller_sent():
    with Lockstep(LockstepConfig(seed=3)) as ls:
        for _ in range(3000):
            ls.step()
        ls.step()  # an odd step: the firmware polls the last tick's frames, the controller does not tick
        received = sum(a.stats["rx"].get("Set_Input_Pos", 0) for a in ls.leg.axes.values())
        assert received == ls.loop.io.tx["Set_Input_Pos"] == 2 * ls.loop.stats.command_ticks
        assert all(a.state == AxisState.CLOSED_LOOP_CONTROL for a in ls.leg.axes.values())


def _max_foot_height_m(ls: Lockstep, seconds: float) -> float:
    """Highest foot over ``seconds``: a walking foot lifts ~8 cm each swing, a limp one drags."""
    top = -1.0
    for _ in range(int(seconds * 1000)):
        ls.step()
        top = max(top, ls.plant.foot_position()[1])
    return top


def test_the_foot_lifts_while_walking():
    with Lockstep(LockstepConfig(seed=0)) as ls:
        while ls.t_s < 3.0:
            ls.step()
        assert _max_foot_height_m(ls, 2.0) > 0.05


def test_with_the_bus_cut_from_the_start_the_leg_does_not_walk():
    with Lockstep(LockstepConfig(seed=0)) as ls:
        ls.cut_bus()
        while ls.t_s < 3.0:
            ls.step()
        assert _max_foot_height_m(ls, 3.0) < 0.01
        assert ls.loop.phase is Phase.FAULT
        assert all(a.state == AxisState.IDLE for a in ls.leg.axes.values())
        assert sum(a.stats["rx"].get("Set_Input_Pos", 0) for a in ls.leg.axes.values()) == 0


def test_cutting_the_bus_mid_walk_trips_the_watchdogs_and_the_leg_stops():
    with Lockstep(LockstepConfig(seed=0)) as ls:
        while ls.t_s < 4.0:
            ls.step()
        assert ls.loop.phase is Phase.WALK
        ls.cut_bus()
        t_cut = ls.t_s
        idle_at = None
        while ls.t_s < t_cut + 0.5:
            ls.step()
            if idle_at is None and all(a.state == AxisState.IDLE for a in ls.leg.axes.values()):
                idle_at = ls.t_s
        assert idle_at is not None and idle_at - t_cut <= 0.1 + 0.002
        for axis in ls.leg.axes.values():
            assert axis.errors & AxisError.WATCHDOG_TIMER_EXPIRED
        while ls.t_s < t_cut + 1.5:
            ls.step()
        assert _max_foot_height_m(ls, 3.0) < 0.01


def test_stride_grows_monotonically_with_burst_length():
    means = []
    for burst in (0.2, 0.3, 0.4, 0.5):
        m = run_walk(8.0, seed=1, burst_s=burst)
        assert m["phase"] == "walk"
        strides = m["stride_m"][2:]
        means.append(sum(strides) / len(strides))
    assert all(b > a + 0.02 for a, b in zip(means, means[1:])), means


def test_same_seed_same_walk():
    a = run_walk(5.0, seed=7)
    b = run_walk(5.0, seed=7)
    for m in (a, b):
        m.pop("wall_s")
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_the_walk_metrics_are_stamped_first(walk20):
    assert list(walk20)[:3] == ["format", "format_version", "project_version"]
    assert walk20["format"] == "walk" and walk20["format_version"] == 1 and walk20["project_version"]


def test_walk_json_is_a_stamped_file(tmp_path):
    from hil.cli import main

    out = tmp_path / "walk.json"
    rc = main(["walk", "--seconds", "2", "--quiet", "--json", str(out)])
    written = json.loads(out.read_text())
    assert written["format"] == "walk" and written["format_version"] == 1 and written["sim_s"] > 1.9
    assert rc == (0 if written["phase"] == "walk" else 1)  # written either way
