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


# --------------------------------------------------------------------------- armed: leaving closed loop
# Deterministic (the test's own clock, direct calls): what the threaded whole-loop tests show in real time.
def armed(phase: Phase = Phase.RAMP) -> Supervisor:
    """A supervisor with both axes in closed loop, in RAMP (or WALK), every node heard at t = 0.1 s."""
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(0.0)
    hear(sup, 0.1, AxisState.CLOSED_LOOP_CONTROL)
    sup.update(0.1)
    assert sup.phase is Phase.RAMP
    if phase is Phase.WALK:
        sup.enter(Phase.WALK, 0.1)
    return sup


@pytest.mark.parametrize("phase", [Phase.RAMP, Phase.WALK])
@pytest.mark.parametrize("axis", ["hip", "knee"])
@pytest.mark.parametrize("state", [AxisState.IDLE, AxisState.FULL_CALIBRATION_SEQUENCE, AxisState.UNDEFINED],
                         ids=lambda s: s.name)
def test_an_axis_leaving_closed_loop_without_an_error_is_a_fault_in_that_update(phase, axis, state):
    sup = armed(phase)
    for k in range(1, 4):  # a healthy stretch first: no fault while both stay in closed loop
        hear(sup, 0.1 + 0.05 * k, AxisState.CLOSED_LOOP_CONTROL)
        sup.update(0.1 + 0.05 * k)
        assert sup.phase is phase
    hear(sup, 0.3, AxisState.CLOSED_LOOP_CONTROL)
    link = next(a for a in sup.axes if a.name == axis)
    assert link.on_heartbeat((0, int(state), 0, 0), 0.3)  # no error: it just left closed loop
    sup.update(0.3)
    assert sup.phase is Phase.FAULT and sup.lifecycle == "fault" and sup.fault_t_s == 0.3
    assert sup.fault_cause == f"axis {axis} left closed loop: state {state.name}, error none (0x0)"
    hear(sup, 0.35, AxisState.CLOSED_LOOP_CONTROL)  # back in closed loop: the fault stays latched
    sup.update(0.35)
    assert sup.phase is Phase.FAULT and sup.fault_t_s == 0.3


@pytest.mark.parametrize("phase", [Phase.RAMP, Phase.WALK])
def test_an_error_reported_in_closed_loop_is_a_fault_by_name_in_that_update(phase):
    sup = armed(phase)
    hear(sup, 0.2, AxisState.CLOSED_LOOP_CONTROL)
    knee = sup.axes[1]
    assert knee.on_heartbeat((int(AxisError.WATCHDOG_TIMER_EXPIRED), int(AxisState.CLOSED_LOOP_CONTROL), 0, 0), 0.2)
    sup.update(0.2)
    assert sup.phase is Phase.FAULT and sup.fault_t_s == 0.2
    assert sup.fault_cause == "axis knee reported WATCHDOG_TIMER_EXPIRED (0x1000000) in closed loop"


def test_the_first_axis_out_of_closed_loop_is_named_and_a_later_cause_never_replaces_it():
    sup = armed()
    hear(sup, 0.2, AxisState.IDLE)  # both left; the hip is checked first
    sup.update(0.2)
    assert sup.fault_cause.startswith("axis hip left closed loop")
    sup.fault("estop by operator", 0.25)  # FAULT is latched: the first cause and time are kept
    sup.update(0.9)
    assert sup.fault_cause.startswith("axis hip left closed loop") and sup.fault_t_s == 0.2


# --------------------------------------------------------------------------- the rest, found by mutation testing
import logging  # noqa: E402

from protocol.contract import sdo_bits_value, sdo_value_bits  # noqa: E402
from protocol.endpoints import WATCHDOG_TIMEOUT  # noqa: E402

LOG = "controller.supervisor"


def messages(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOG]


def reply(axis, value_s: float, t: float) -> None:
    """The driver's TxSdo answering a read of the watchdog timeout with ``value_s``."""
    assert axis.on_txsdo((0, WATCHDOG_TIMEOUT.id, 0, sdo_value_bits(value_s)), t)


def test_phase_changes_faults_and_clearing_are_logged_with_their_times(caplog):
    sup = make()
    with caplog.at_level(logging.INFO, logger=LOG):
        hear(sup, 0.0)
        sup.update(0.0)
        sup.arm(0.25)
        sup.fault("estop by operator", 0.5)
        sup.fault("a second cause", 0.6)  # latched: neither kept nor logged
        sup.clear_fault(0.75)
    assert messages(caplog) == [
        "phase wait_nodes -> inactive at t=0.000 s",
        "phase inactive -> arming at t=0.250 s",
        "safe stop at t=0.500 s: estop by operator",
        "phase arming -> fault at t=0.500 s",
        "fault cleared at t=0.750 s (was: estop by operator at t=0.500 s)",
        "phase fault -> wait_nodes at t=0.750 s",
    ]
    levels = [r.levelno for r in caplog.records if r.name == LOG]
    assert levels == [logging.INFO, logging.INFO, logging.ERROR, logging.INFO, logging.WARNING, logging.INFO]
    assert sup.phase_t_s == 0.75 and sup.heard_after_s == 0.75


def test_a_new_supervisor_waits_for_nodes_and_its_clock_starts_at_the_first_update():
    sup = make(bringup_timeout_s=0.5)
    assert sup.phase is Phase.WAIT_NODES and math.isnan(sup.phase_t_s) and sup.fault_cause == ""
    assert math.isnan(sup.fault_t_s) and sup.pending_watchdog == {} and sup.last_arm_request_s == -math.inf
    sup.update(10.0)  # the clock of the bring-up timeout starts here, not at 0
    assert sup.phase_t_s == 10.0
    sup.update(10.5)  # not yet: the timeout is "longer than", at exactly 0.5 s it waits on
    assert sup.phase is Phase.WAIT_NODES
    sup.update(10.500001)
    assert sup.phase is Phase.FAULT and sup.fault_t_s == 10.500001
    # nobody at all: every node is named
    assert sup.fault_cause == "no heartbeat or encoder from ['hip', 'knee', 'sensor_board']"


def test_the_stale_heartbeat_bound_is_never_below_the_silence_timeout():
    axes = [AxisLink(cfg, C) for cfg in default_axes()]
    assert Supervisor(axes, SensorLink(SENSOR_BOARD_NODE_ID), 0.35, 1.0, 0.1).stale_heartbeat_s == 0.35
    assert Supervisor(axes, SensorLink(SENSOR_BOARD_NODE_ID), 0.35, 1.0, 2.0).stale_heartbeat_s == 2.0
    assert Supervisor(axes, SensorLink(SENSOR_BOARD_NODE_ID), 0.35, 1.0).stale_heartbeat_s == math.inf


def test_any_valid_frame_is_a_sign_of_life_and_silence_is_strictly_longer_than_the_timeout():
    sup = make()  # silence 0.35 s, stale heartbeat 1.0 s
    hear(sup, 0.0)
    assert sup.silent_nodes(0.35) == []  # exactly the timeout: not yet silent
    assert sup.silent_nodes(0.36) == ["hip", "knee", "sensor_board"]
    # encoder estimates keep an axis alive, range/contacts/profile frames keep the board alive
    for a in sup.axes:
        assert a.on_encoder((0.0, 0.0), 0.3)
    assert sup.silent_nodes(0.6) == ["sensor_board"]
    for stream in ("range", "contacts", "profile"):  # each stream alone keeps the board alive
        board = SensorLink(SENSOR_BOARD_NODE_ID)
        assert board.on_heartbeat((0, 1, 1, 0.0), 0.0)
        setattr(board, f"{stream}_t_s", 0.5)
        sup.sensors = board
        assert "sensor_board" not in sup.silent_nodes(0.8) and "sensor_board" in sup.silent_nodes(0.851)
    sup.sensors = SensorLink(SENSOR_BOARD_NODE_ID)
    assert sup.sensors.on_heartbeat((0, 1, 1, 0.0), 0.0)
    # but a heartbeat older than stale_heartbeat_s is stale whatever else comes
    for a in sup.axes:
        assert a.on_encoder((0.0, 0.0), 0.95)
    sup.sensors.range_t_s = 0.95
    assert sup.silent_nodes(1.0) == []  # exactly 1.0 s after the heartbeats: not yet stale
    assert sup.silent_nodes(1.01) == ["hip", "knee", "sensor_board"]


def test_a_silent_node_in_an_active_phase_is_a_fault_naming_it_and_the_timeouts():
    sup = armed()  # heard at 0.1
    for a in sup.axes:
        assert a.on_heartbeat((0, int(AxisState.CLOSED_LOOP_CONTROL), 0, 0), 0.3)
        assert a.on_encoder((0.0, 0.0), 0.3)
    sup.update(0.46)  # the sensor board is silent since 0.1
    assert sup.phase is Phase.FAULT and sup.fault_t_s == 0.46
    assert sup.fault_cause == ("node(s) silent for more than 0.35 s (or no heartbeat for 1 s): ['sensor_board']")


def test_wait_nodes_needs_every_heartbeat_after_the_clearing_and_every_axis_position():
    sup = make()
    hear(sup, 0.0)
    sup.fault("x", 0.0)
    sup.clear_fault(0.1)
    hear(sup, 0.1)  # at the very instant of the clearing: not after it
    sup.update(0.1)
    assert sup.phase is Phase.WAIT_NODES
    hear(sup, 0.2)
    sup.axes[1].pos_rad = math.nan  # no encoder estimate from the knee yet
    sup.update(0.2)
    assert sup.phase is Phase.WAIT_NODES
    assert sup.axes[1].on_encoder((0.0, 0.0), 0.25)
    sup.update(0.25)
    assert sup.phase is Phase.INACTIVE and sup.phase_t_s == 0.25
    sup2 = make()
    hear(sup2, 0.0)
    sup2.update(0.35)  # heard exactly silence_timeout_s ago: still heard
    assert sup2.phase is Phase.INACTIVE
    sup3 = make()
    hear(sup3, 0.0)
    sup3.update(0.36)
    assert sup3.phase is Phase.WAIT_NODES


def test_arming_faults_on_silence_and_its_timeout_counts_from_the_arm_command():
    sup = make(bringup_timeout_s=0.5)
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(1.0)  # the timeout counts from here
    for k in range(1, 6):
        hear(sup, 1.0 + 0.1 * k)  # IDLE: not yet in closed loop
        sup.update(1.0 + 0.1 * k)
    assert sup.phase is Phase.ARMING  # 0.5 s after the arm command: not longer than the timeout
    sup.update(1.5001)
    assert sup.phase is Phase.FAULT and sup.fault_cause == (
        "axes did not reach closed loop: {'hip': ('IDLE', '0x0'), 'knee': ('IDLE', '0x0')}")
    sup2 = make(bringup_timeout_s=5.0)
    hear(sup2, 0.0)
    sup2.update(0.0)
    sup2.arm(0.0)
    sup2.update(0.4)  # nobody heard since 0.0
    assert sup2.phase is Phase.FAULT and "silent" in sup2.fault_cause and sup2.fault_t_s == 0.4


def test_one_axis_in_closed_loop_is_not_enough_to_leave_arming():
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(0.0)
    hear(sup, 0.1)
    assert sup.axes[0].on_heartbeat((0, int(AxisState.CLOSED_LOOP_CONTROL), 0, 0), 0.1)
    sup.update(0.1)
    assert sup.phase is Phase.ARMING
    assert sup.axes[1].on_heartbeat((0, int(AxisState.CLOSED_LOOP_CONTROL), 0, 0), 0.15)
    sup.update(0.15)
    assert sup.phase is Phase.RAMP and sup.phase_t_s == 0.15


@pytest.mark.parametrize("phase", [Phase.ARMING, Phase.RAMP, Phase.WALK])
def test_a_health_reading_beyond_its_bound_is_a_fault_in_an_active_phase_only(phase):
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.axes[1].motor_temp_c = 95.0  # above the default 90 C
    sup.update(0.05)
    assert sup.phase is Phase.INACTIVE  # not armed: nothing to stop
    sup.arm(0.1)
    if phase is not Phase.ARMING:
        hear(sup, 0.1, AxisState.CLOSED_LOOP_CONTROL)
        sup.axes[1].motor_temp_c = None
        sup.update(0.1)
        sup.enter(phase, 0.1)
        sup.axes[1].motor_temp_c = 95.0
        hear(sup, 0.15, AxisState.CLOSED_LOOP_CONTROL)
    sup.update(0.15)
    assert sup.phase is Phase.FAULT and sup.fault_t_s == 0.15
    assert sup.fault_cause == "knee motor temperature 95.0 C above 90 C"


def test_disarm_and_arm_reset_the_arming_clock_and_the_arm_retry():
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(0.0)
    assert sup.arm_due(0.0) and not sup.arm_due(0.49) and sup.arm_due(0.5) and not sup.arm_due(0.99)
    assert sup.arm_due(1.0) and sup.last_arm_request_s == 1.0
    sup.disarm(1.2)
    assert sup.phase is Phase.INACTIVE and sup.phase_t_s == 1.2
    sup.arm(1.3)  # a new arming: its first frames are due at once
    assert sup.phase_t_s == 1.3 and sup.arm_due(1.3)


# -- the drivers' watchdog timeout: written with the arming frames, read back --------------------------
def arming() -> Supervisor:
    sup = make()
    hear(sup, 0.0)
    sup.update(0.0)
    sup.arm(0.0)
    return sup


def test_a_read_back_of_the_value_written_confirms_it_and_is_logged(caplog):
    sup = arming()
    hip, knee = sup.axes
    sup.expect_watchdog(hip, 0.1, 0.0)
    sup.expect_watchdog(knee, 0.1, 0.0)
    assert set(sup.pending_watchdog) == {"hip", "knee"}
    assert sup.check_watchdog_confirmations(0.01) == []  # no reply yet, not yet time to ask again
    reply(hip, 0.1, 0.02)
    with caplog.at_level(logging.INFO, logger=LOG):
        assert sup.check_watchdog_confirmations(0.03) == []
    assert set(sup.pending_watchdog) == {"knee"}
    assert messages(caplog) == [f"watchdog timeout confirmed: hip reads {sdo_bits_value(sdo_value_bits(0.1)):g} s"]
    reply(knee, 0.1, 0.04)
    assert sup.check_watchdog_confirmations(0.05) == [] and sup.pending_watchdog == {}
    assert sup.phase is Phase.ARMING


def test_a_reply_older_than_the_last_exchange_does_not_confirm_it():
    sup = arming()
    hip = sup.axes[0]
    reply(hip, 0.1, 0.0)  # an answer to an earlier exchange
    sup.expect_watchdog(hip, 0.1, 0.01)
    assert sup.check_watchdog_confirmations(0.02) == [] and "hip" in sup.pending_watchdog


def test_no_reply_is_asked_again_after_the_retry_period_and_a_fault_after_the_deadline():
    sup = arming()
    hip = sup.axes[0]
    sup.expect_watchdog(hip, 0.1, 0.0)
    assert sup.check_watchdog_confirmations(0.099) == []
    assert sup.check_watchdog_confirmations(0.1) == [hip]  # SDO_RETRY_S after the exchange: again
    sup.expect_watchdog(hip, 0.1, 0.1)  # the loop writes and reads again: the first deadline stays
    assert sup.pending_watchdog["hip"][2] == 0.0 and sup.pending_watchdog["hip"][3] == 0.1
    assert sup.check_watchdog_confirmations(0.5) == [hip] and sup.phase is Phase.ARMING  # 0.5 s: not past it
    assert sup.check_watchdog_confirmations(0.5001) == []
    assert sup.phase is Phase.FAULT and sup.fault_t_s == 0.5001 and sup.pending_watchdog == {}
    assert sup.fault_cause == (f"watchdog timeout not confirmed: hip wrote {sdo_bits_value(sdo_value_bits(0.1)):g} s, "
                               "no reply within 0.5 s")


def test_another_value_read_back_is_asked_again_at_once_and_named_in_the_fault():
    sup = arming()
    knee = sup.axes[1]
    sup.expect_watchdog(knee, 0.1, 0.0)
    reply(knee, 0.8, 0.01)  # the write was lost: the old value
    assert sup.check_watchdog_confirmations(0.02) == [knee]  # at once, not after SDO_RETRY_S
    assert sup.pending_watchdog["knee"][4] == pytest.approx(0.8)
    sup.expect_watchdog(knee, 0.1, 0.02)
    assert sup.pending_watchdog["knee"][4] is None  # a new exchange: nothing read yet
    reply(knee, 0.8, 0.03)  # lost again
    assert sup.check_watchdog_confirmations(0.04) == [knee]
    assert sup.check_watchdog_confirmations(0.6) == []
    assert sup.phase is Phase.FAULT
    assert sup.fault_cause == (f"watchdog timeout not confirmed: knee wrote {sdo_bits_value(sdo_value_bits(0.1)):g} s, "
                               f"read {sdo_bits_value(sdo_value_bits(0.8)):g} s (written and read again for 0.5 s)")


def test_a_read_back_kept_from_an_earlier_check_is_named_at_the_deadline():
    sup = arming()
    knee = sup.axes[1]
    sup.expect_watchdog(knee, 0.1, 0.0)
    reply(knee, 0.8, 0.01)
    assert sup.check_watchdog_confirmations(0.02) == [knee]
    assert sup.check_watchdog_confirmations(0.51) == []  # no new reply since: the one read is named
    assert "read 0.8 s" in sup.fault_cause


def test_expectations_are_dropped_outside_the_active_phases():
    sup = arming()
    sup.expect_watchdog(sup.axes[0], 0.1, 0.0)
    sup.disarm(0.05)
    assert sup.check_watchdog_confirmations(0.9) == [] and sup.pending_watchdog == {}
    assert sup.phase is Phase.INACTIVE  # no fault for an arming that was given up
    assert Supervisor.SDO_REPLY_TIMEOUT_S == 0.5 and Supervisor.SDO_RETRY_S == 0.1 and Supervisor.ARM_RETRY_S == 0.5


def test_error_text_names_no_error_as_none():
    assert error_text(0) == "none (0x0)"
    assert error_text(0x1000001) == "INITIALIZING|WATCHDOG_TIMER_EXPIRED (0x1000001)"


def test_an_axis_heard_without_any_encoder_estimate_is_named_as_an_axis_at_the_bring_up_timeout():
    sup = make(bringup_timeout_s=0.5)
    for k in range(7):  # every node keeps sending heartbeats, but no encoder estimate ever comes
        t = 0.1 * k
        for a in sup.axes:
            assert a.on_heartbeat((0, int(AxisState.IDLE), 0, 1), t)
        assert sup.sensors.on_heartbeat((0, 1, 1, 0.0), t)
        sup.update(t)
    assert sup.phase is Phase.FAULT and sup.fault_cause == "no heartbeat or encoder from an axis"


def test_the_watchdog_exchange_keeps_its_first_deadline_and_checks_every_axis_at_any_time():
    t0 = 64.0  # not at t = 0 (the deadlines are differences of times); steps exact in binary
    sup = make()
    hear(sup, t0)
    sup.update(t0)
    sup.arm(t0)
    hip, knee = sup.axes
    sup.expect_watchdog(hip, 0.1, t0)
    sup.expect_watchdog(knee, 0.1, t0)
    assert sup.check_watchdog_confirmations(t0 + 0.0625) == []  # not yet time to ask again
    assert sup.check_watchdog_confirmations(t0 + 0.125) == [hip, knee]
    sup.expect_watchdog(hip, 0.1, t0 + 0.125)
    sup.expect_watchdog(hip, 0.1, t0 + 0.25)  # a third exchange: still the first one's deadline
    assert sup.pending_watchdog["hip"][2] == t0 and sup.pending_watchdog["hip"][3] == t0 + 0.25
    reply(hip, 0.1, t0 + 0.25)
    reply(knee, 0.1, t0 + 0.25)
    assert sup.check_watchdog_confirmations(t0 + 0.375) == [] and sup.pending_watchdog == {}  # both in one call
    sup.expect_watchdog(hip, 0.1, t0 + 0.5)
    assert sup.check_watchdog_confirmations(t0 + 1.0) == [hip] and sup.phase is Phase.ARMING  # 0.5 s: not past
    assert sup.check_watchdog_confirmations(t0 + 1.0001) == [] and sup.phase is Phase.FAULT


def test_latest_chooses_as_builtin_max_does_bit_for_bit():
    """_latest (the supervisor's max of two times, without the builtin's call) keeps its first
    argument unless the second is greater: NaN, infinities and signed zeros included."""
    import itertools
    import struct

    from controller.supervisor import _latest

    values = [math.nan, -math.inf, math.inf, 0.0, -0.0, 1.0, 1.5, -2.0]
    for a, b in itertools.product(values, repeat=2):
        assert struct.pack("<d", _latest(a, b)) == struct.pack("<d", max(a, b)), (a, b)
    for a, b, c, d in itertools.product(values[:5], repeat=4):
        assert struct.pack("<d", _latest(_latest(_latest(a, b), c), d)) == struct.pack("<d", max(a, b, c, d))


def test_active_phases_are_arming_ramp_and_walk():
    from controller.supervisor import ACTIVE_PHASES

    assert {p for p in Phase if p in ACTIVE_PHASES} == {Phase.ARMING, Phase.RAMP, Phase.WALK}
