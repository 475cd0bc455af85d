"""The supervisor's phases on what the bus has said (it never sends anything itself)."""

from __future__ import annotations

import math

import pytest

from controller.config import default_axes
from controller.io.axis import AxisLink
from controller.io.sensors import SensorLink
from controller.supervisor import LIFECYCLE, Phase, Supervisor, error_names, error_text
from protocol import SENSOR_BOARD_NODE_ID, AxisError, AxisState, BusContract

C = BusContract.load()


def make(bringup_timeout_s: float = 1.0) -> Supervisor:
    axes = [AxisLink(cfg, C) for cfg in default_axes()]
    return Supervisor(axes, SensorLink(SENSOR_BOARD_NODE_ID), 0.35, bringup_timeout_s, 1.0)


def hear(sup: Supervisor, t: float, state: AxisState = AxisState.IDLE, error: int = 0, skip: str = "") -> None:
    for a in sup.axes:
        if a.name != skip:
            assert a.on_heartbeat((error, int(state), 0, 1), t)
            assert a.on_encoder((0.0, 0.0), t)
    assert sup.sensors.on_heartbeat((0, 1, 1, 0.0), t)


def test_every_phase_has_its_lifecycle_state():
    assert LIFECYCLE == {Phase.WAIT_NODES: "inactive", Phase.INACTIVE: "inactive", Phase.ARMING: "active",
                         Phase.RAMP: "active", Phase.WALK: "active", Phase.FAULT: "fault"}
    assert [p.value for p in Phase] == ["wait_nodes", "inactive", "arming", "ramp", "walk", "fault"]


def test_every_node_heard_is_inactive_not_arming():
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    assert sup.phase is Phase.INACTIVE and sup.lifecycle == "inactive"
    for k in range(1, 50):  # it stays there while the nodes talk
        hear(sup, k * 0.1)
        sup.update(k * 0.1)
    assert sup.phase is Phase.INACTIVE


def test_wait_nodes_keeps_its_bring_up_timeout():
    sup = make(bringup_timeout_s=0.5)
    hear(sup, 0.0, skip="knee")
    sup.update(0.0)
    sup.update(0.6)
    assert sup.phase is Phase.FAULT and "knee" in sup.fault_cause


def test_an_error_in_inactive_is_not_a_fault_but_a_silent_node_is():
    sup = make()
    hear(sup, 0.0, error=int(AxisError.ESTOP_REQUESTED))
    sup.update(0.0)
    assert sup.phase is Phase.INACTIVE
    hear(sup, 0.3, skip="hip")
    sup.update(0.3)
    assert sup.phase is Phase.INACTIVE
    sup.update(0.36)
    assert sup.phase is Phase.FAULT and "hip" in sup.fault_cause and "silent" in sup.fault_cause


def test_arming_faults_on_an_axis_error_naming_it():
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(0.0)
    assert sup.phase is Phase.ARMING and sup.arm_due(0.0) and not sup.arm_due(0.1)
    hear(sup, 0.1, error=int(AxisError.WATCHDOG_TIMER_EXPIRED))
    sup.update(0.1)
    assert sup.phase is Phase.FAULT
    assert sup.fault_cause.startswith("axis hip reported WATCHDOG_TIMER_EXPIRED (0x1000000) while arming")


def test_arming_reaches_ramp_on_closed_loop_and_times_out_otherwise():
    sup = make(bringup_timeout_s=0.5)
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(0.0)
    hear(sup, 0.1, AxisState.CLOSED_LOOP_CONTROL)
    sup.update(0.1)
    assert sup.phase is Phase.RAMP
    sup2 = make(bringup_timeout_s=0.5)
    hear(sup2, 0.0)
    sup2.update(0.0)
    sup2.arm(0.0)
    for k in range(1, 7):
        hear(sup2, k * 0.1)
        sup2.update(k * 0.1)
    assert sup2.phase is Phase.FAULT and "did not reach closed loop" in sup2.fault_cause


def test_a_cleared_fault_waits_for_heartbeats_after_the_clearing():
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.fault("estop by operator", 0.05)
    sup.update(0.06)
    assert sup.phase is Phase.FAULT and sup.lifecycle == "fault"  # latched
    sup.clear_fault(0.1)
    assert sup.phase is Phase.WAIT_NODES and sup.fault_cause == "" and math.isnan(sup.fault_t_s)
    sup.update(0.1)
    assert sup.phase is Phase.WAIT_NODES  # the heartbeats it has are older than the clearing
    hear(sup, 0.2)
    sup.update(0.2)
    assert sup.phase is Phase.INACTIVE


def test_disarm_is_inactive_not_a_fault():
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(0.0)
    sup.disarm(0.1)
    assert sup.phase is Phase.INACTIVE and sup.fault_cause == ""


@pytest.mark.parametrize("bits, names", [(0, []), (0x2000000, ["ESTOP_REQUESTED"]),
                                         (0x1000001, ["INITIALIZING", "WATCHDOG_TIMER_EXPIRED"]),
                                         (0x80000000, ["0x80000000"])])
def test_error_names(bits, names):
    assert error_names(bits) == names
    assert error_text(bits).endswith(f"({bits:#x})")
