"""Bring-up (controller/bringup*.py) against a silent bus and against the simulated leg in lockstep.

The leg (firmware_sim.leg.SimulatedLeg) and bring-up share a python-can ``virtual`` bus; bring-up's
clock is the leg's simulated time and its sleep steps the leg, so every run is deterministic and
takes well under a second of wall time. Nothing here reads the wall clock: the command line's
test of a silent bus gives bring-up a clock of its own too (a fake clock that moves only when
slept on), and asserts the simulated seconds.
"""

from __future__ import annotations

import json
import math
import uuid
from dataclasses import replace
from typing import Callable

import can
import pytest

from controller.bringup.procedure import BringupConfig, run_bringup
from controller.bringup.move import MoveConfig, choose_step, cosine_ramp, error_names
from controller.bringup.checklist import Status
from controller.config import ControllerConfig
from controller.io.axis import AxisConfig
from firmware_sim.leg import LegHardware, SimulatedLeg
from firmware_sim.odrive_axis import DriverConfig
from firmware_sim.plant import RigConfig
from protocol import AxisError, AxisState, BusContract
from tests.fakes import FakeBus

CONTRACT = BusContract.load()


class FakeClock:
    """A clock that moves only when slept on [s]."""

    def __init__(self) -> None:
        self.t_s = 0.0

    def __call__(self) -> float:
        return self.t_s

    def sleep(self, dt_s: float) -> None:
        self.t_s += max(dt_s, 1e-4)


class Rig:
    """The simulated leg and bring-up's bus on one virtual channel, in lockstep."""

    def __init__(self, hardware: LegHardware = LegHardware(), seed: int = 0, rig: RigConfig = RigConfig()) -> None:
        channel = f"bringup-{uuid.uuid4().hex}"
        self.leg_bus = can.Bus(interface="virtual", channel=channel)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.rogue = can.Bus(interface="virtual", channel=channel)  # another master, when a test wants one
        self.spy = can.Bus(interface="virtual", channel=channel)  # hears what bring-up sends
        self.leg = SimulatedLeg(self.leg_bus, rig=rig, hardware=hardware, seed=seed)
        self.hooks: list[Callable[[float], None]] = []
        self.sent_rev: dict[int, list[float]] = {}

    def clock(self) -> float:
        return self.leg.t_s

    def sleep(self, dt_s: float) -> None:
        if dt_s < 0.0:
            raise ValueError("sleep length must be non-negative")  # as time.sleep
        end = self.leg.t_s + dt_s - 1e-9
        while True:
            self.leg.step()
            for hook in self.hooks:
                hook(self.leg.t_s)
            if self.leg.t_s >= end:
                return

    def settle(self, seconds: float) -> None:
        """Let the leg run (and hear frames) before bring-up starts."""
        self.sleep(seconds)
        while self.bus.recv(0) is not None:
            pass

    def run(self, config: ControllerConfig = ControllerConfig(), **kw):
        return run_bringup(self.bus, config.axes, sensor_node_id=config.sensor_node_id, channel="virtual",
                           clock=self.clock, sleep=self.sleep, **kw)

    def close(self) -> None:
        self.leg.close()
        for b in (self.leg_bus, self.bus, self.rogue, self.spy):
            b.shutdown()

    def targets_rad(self, axis: AxisConfig) -> list[float]:
        """Every Set_Input_Pos bring-up sent to ``axis`` so far, as joint angles [rad] by its config."""
        codec = CONTRACT.codec("Set_Input_Pos")
        while (msg := self.spy.recv(0)) is not None:
            if msg.arbitration_id & 0x1F == codec.cmd_id:
                self.sent_rev.setdefault(msg.arbitration_id >> 5, []).append(codec.unpack(msg.data)[0])
        return [axis.rev_to_rad(rev) for rev in self.sent_rev.get(axis.node_id, [])]


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def statuses(report) -> dict[str, Status]:
    return {item.name: item.status for item in report.checklist.items}


def detail(report, name: str) -> str:
    item = report.checklist.find(name)
    assert item is not None, f"no item {name!r} in {[i.name for i in report.checklist.items]}"
    return item.detail


def with_knee(config: ControllerConfig, **changes) -> ControllerConfig:
    axes = tuple(replace(a, **changes) if a.name == "knee" else a for a in config.axes)
    return replace(config, axes=axes)


# -- a silent bus ----------------------------------------------------------------------------
def test_a_silent_bus_fails_fast_with_what_to_check():
    clock = FakeClock()
    channel = f"silent-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        report = run_bringup(bus, ControllerConfig().axes, channel="can0", clock=clock, sleep=clock.sleep)
    finally:
        bus.shutdown()
    assert not report.passed
    assert report.elapsed_s <= 2.0 and clock.t_s <= 2.0  # simulated seconds: fails well under 5 s
    assert [(i.name, i.status) for i in report.checklist.items] == [("bus: nodes heard", Status.FAIL)]
    text = detail(report, "bus: nodes heard")
    for words in ("no frame at all on can0", "hip (node 0)", "knee (node 1)", "sensor board (node 16)", "wiring",
                  "termination", "bitrate", "powered"):
        assert words in text, words
    assert report.checklist.summary() == "0 passed, 1 failed"


def with_clock(monkeypatch, clock: FakeClock) -> list[dict]:
    """The command line's bring-up on ``clock`` (the command passes none: the monotonic clock);
    the keyword arguments of each call are kept."""
    import controller.bringup.procedure as procedure

    calls: list[dict] = []
    original = procedure.run_bringup

    def on_clock(bus, axes, **kw):
        calls.append(kw)
        return original(bus, axes, **{**kw, "clock": clock, "sleep": clock.sleep})

    monkeypatch.setattr(procedure, "run_bringup", on_clock)
    return calls


def test_the_command_fails_fast_on_a_silent_bus(capsys, monkeypatch):
    from hil.cli import main

    clock = FakeClock()
    calls = with_clock(monkeypatch, clock)
    rc = main(["bringup", "--interface", "virtual", "--channel", f"silent-{uuid.uuid4().hex}"])
    out = capsys.readouterr().out
    assert len(calls) == 1 and "clock" not in calls[0]  # the command's own run, on the test's clock
    assert rc == 1
    assert 1.5 <= clock.t_s <= 2.0  # simulated seconds: the listen window (1.5 s), then it stops
    assert "FAIL" in out and "no frame at all" in out and "0 passed, 1 failed" in out


def test_the_command_exits_3_on_a_missing_or_bad_config(capsys, tmp_path):
    from hil.cli import main

    missing = tmp_path / "none.toml"
    assert main(["bringup", "--interface", "virtual", "--channel", "x", "--config", str(missing)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"elegant-stepping bringup: error: {missing}: cannot read the configuration: No such file or "
                   "directory"]
    deep = tmp_path / "deep.toml"
    deep.write_text("[axes.hip]\nnode_id = " + "[" * 500 + "]" * 500 + "\n")
    assert main(["bringup", "--interface", "virtual", "--channel", "x", "--config", str(deep)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{deep}: " in err[0] and "nested" in err[0] and "Traceback" not in err[0]


def test_the_command_exits_4_in_one_line_when_the_bus_cannot_be_opened(capsys, tmp_path):
    from controller.cli import main

    assert main(["bringup", "--interface", "no-such-interface", "--channel", "x"]) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("elegant-stepping-leg bringup: error: cannot open the CAN bus "
                                               "(interface no-such-interface, channel x): "), err
    assert main(["bringup", "--interface", "socketcan", "--channel", "can9"]) == 4  # no such device, or no SocketCAN
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "(interface socketcan, channel can9): [Errno " in err[0] and "Traceback" not in err[0]


def test_a_report_path_that_cannot_be_written_is_refused_before_the_bus_is_opened(capsys, tmp_path, monkeypatch):
    from controller.cli import main

    opened = []
    import controller.daemon.openbus as openbus

    monkeypatch.setattr(openbus, "open_bus", lambda kw: opened.append(kw))
    (tmp_path / "file").write_text("x")
    for path, words in ((tmp_path, "is a folder"), (tmp_path / "file" / "r.json", "its folder cannot be made")):
        assert main(["bringup", "--interface", "virtual", "--channel", "x", "--json", str(path)]) == 3
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"--json {path}: {words}" in err[0], err
    assert opened == []  # refused before anything ran


# -- the simulated leg -----------------------------------------------------------------------
def test_every_item_passes_against_the_simulated_leg(rig):
    report = rig.run()
    bad = [i.line() for i in report.checklist.items if i.status is not Status.PASS]
    assert report.passed and not bad, "\n".join(bad)
    names = set(statuses(report))
    for axis in ("hip", "knee"):
        for suffix in ("firmware", "errors", "bus voltage", "state", "position", "closed loop", "move", "move back",
                       "IDLE"):
            assert f"{axis}: {suffix}" in names
    assert {"hip (node 0): heartbeat", "knee (node 1): heartbeat", "sensor board (node 16): heartbeat",
            "sensor board: state", "all axes IDLE"} <= names
    for name, axis in rig.leg.axes.items():
        assert axis.state is AxisState.IDLE and axis.errors == AxisError.NONE, name
        assert axis.stats["watchdog_trips"] == 0 and axis.stats["targets_outside_limits"] == 0, name
        assert axis.stats["rx"]["Set_Input_Pos"] > 400, name  # ~200 Hz over the moves
    for axis in ControllerConfig().axes:
        targets = rig.targets_rad(axis)
        assert len(targets) > 400 and all(axis.min_rad <= q <= axis.max_rad for q in targets)
    hip = report.axes["hip"]
    assert hip["fw_version"] == "0.6.10" and hip["bus_voltage_v"] == pytest.approx(24.0)
    assert abs(hip["move"]["change_rad"] - hip["move"]["step_rad"]) < 0.05
    assert report.elapsed_s < 12.0  # simulated seconds
    json.dumps(report.to_dict())  # the --json report


def test_the_run_is_deterministic():
    lines = []
    for _ in range(2):
        r = Rig()
        try:
            lines.append(r.run().checklist.lines())
        finally:
            r.close()
    assert lines[0] == lines[1]


def test_a_clock_that_runs_between_calls_and_stalls_of_30_ms_change_nothing(rig):
    # As on a loaded machine (or inside User-Mode Linux): time passes between two clock reads,
    # and now and then the process stalls for 30 ms (the drivers' watchdog is 100 ms).
    calls = {"n": 0}

    def clock() -> float:
        calls["n"] += 1
        return rig.leg.t_s + 1e-7 * calls["n"]

    def sleep(dt_s: float) -> None:
        rig.sleep(dt_s + (0.03 if calls["n"] % 97 == 0 else 0.0))

    report = run_bringup(rig.bus, ControllerConfig().axes, clock=clock, sleep=sleep)
    assert report.passed, "\n".join(report.checklist.lines())
    assert all(a.stats["watchdog_trips"] == 0 for a in rig.leg.axes.values())


def test_no_move_only_listens_and_asks(rig):
    report = rig.run(move=False)
    assert report.passed
    assert all(statuses(report)[f"{a}: move"] is Status.SKIP for a in ("hip", "knee"))
    for axis in rig.leg.axes.values():
        assert axis.stats["rx"]["Set_Axis_State"] == 0 and axis.stats["rx"]["Set_Input_Pos"] == 0


def test_a_wrong_knee_direction_fails_and_the_knee_is_never_armed(rig):
    report = rig.run(with_knee(ControllerConfig(), direction=1))
    s = statuses(report)
    assert not report.passed
    assert s["knee: position"] is Status.FAIL
    assert "direction +1 wrong" in detail(report, "knee: position")
    assert s["knee: move"] is Status.SKIP and "position failed" in detail(report, "knee: move")
    assert s["hip: move"] is Status.PASS and s["all axes IDLE"] is Status.PASS
    knee = rig.leg.axes["knee"]
    assert knee.state is AxisState.IDLE and knee.stats["rx"]["Set_Input_Pos"] == 0
    assert knee.stats["rx"]["Set_Axis_State"] == 0


def test_a_missing_node_fails_and_the_unknown_one_is_reported():
    r = Rig(LegHardware(knee_node_id=2))  # the config still says knee = node 1
    try:
        report = r.run()
        s = statuses(report)
        assert not report.passed
        assert s["knee (node 1): heartbeat"] is Status.FAIL
        assert "nothing from node 1" in detail(report, "knee (node 1): heartbeat")
        assert "node(s) 2" in detail(report, "knee (node 1): heartbeat")
        assert s["bus: unknown nodes"] is Status.WARN and "node 2: " in detail(report, "bus: unknown nodes")
        assert not any(name.startswith("knee: ") for name in s)  # nothing asked of a node not heard
        assert s["hip: move"] is Status.PASS and s["all axes IDLE"] is Status.PASS
        assert "not heard: knee" in detail(report, "all axes IDLE")
        knee = r.leg.axes["knee"]
        assert knee.state is AxisState.IDLE and knee.stats["rx"]["Set_Input_Pos"] == 0
    finally:
        r.close()


def test_a_silent_sensor_board_fails():
    r = Rig(LegHardware(sensor=replace(LegHardware().sensor, heartbeat_period_s=0.0)))
    try:
        report = r.run(move=False)
        assert statuses(report)["sensor board (node 16): heartbeat"] is Status.FAIL
        assert "but no SB_Heartbeat" in detail(report, "sensor board (node 16): heartbeat")
    finally:
        r.close()


def test_latched_errors_are_reported_and_not_cleared_without_the_flag(rig):
    rig.bus.send(_estop(0))
    rig.settle(0.05)
    report = rig.run()
    s = statuses(report)
    assert not report.passed
    assert s["hip: errors"] is Status.FAIL
    text = detail(report, "hip: errors")
    assert "ESTOP_REQUESTED" in text and "--clear-errors" in text
    assert s["hip: move"] is Status.SKIP and s["knee: move"] is Status.PASS
    hip = rig.leg.axes["hip"]
    assert hip.errors & AxisError.ESTOP_REQUESTED  # still latched: nobody cleared it
    assert hip.stats["rx"]["Clear_Errors"] == 0 and hip.stats["rx"]["Set_Axis_State"] == 0


def test_latched_errors_are_cleared_with_the_flag(rig):
    rig.bus.send(_estop(0))
    rig.settle(0.05)
    report = rig.run(clear_errors=True)
    s = statuses(report)
    assert report.passed, "\n".join(report.checklist.lines())
    assert s["hip: errors"] is Status.WARN and "cleared" in detail(report, "hip: errors")
    assert s["hip: move"] is Status.PASS
    assert rig.leg.axes["hip"].errors == AxisError.NONE and rig.leg.axes["hip"].state is AxisState.IDLE


def test_wrong_firmware_fails_and_blocks_the_move():
    r = Rig(LegHardware(driver=DriverConfig(node_id=0, fw_version=(0, 5, 6))))
    try:
        report = r.run()
        s = statuses(report)
        assert s["hip: firmware"] is Status.FAIL and "0.5.6" in detail(report, "hip: firmware")
        assert s["hip: move"] is Status.SKIP and s["knee: move"] is Status.SKIP
    finally:
        r.close()


def test_another_master_on_the_bus_fails_and_nothing_is_commanded(rig):
    pos = CONTRACT.codec("Set_Input_Pos")
    frame = can.Message(arbitration_id=CONTRACT.odrive_id(0, "Set_Input_Pos"), data=pos.pack(0.5, 0.0, 0.0),
                        is_extended_id=False)
    rig.hooks.append(lambda t: rig.rogue.send(frame) if round(t * 1000) % 10 == 0 else None)
    report = rig.run()
    s = statuses(report)
    assert s["bus: no other master"] is Status.FAIL
    assert "Set_Input_Pos to node 0" in detail(report, "bus: no other master")
    assert all(s[f"{a}: move"] is Status.SKIP for a in ("hip", "knee"))
    for axis in rig.leg.axes.values():
        assert axis.stats["rx"]["Set_Axis_State"] == 0 and axis.stats["rx"]["Clear_Errors"] == 0


def test_an_error_during_the_move_aborts_it_and_leaves_the_axis_idle(rig):
    state = {"armed_at": None, "sent": False}

    def estop_mid_move(t: float) -> None:
        hip = rig.leg.axes["hip"]
        if hip.state is AxisState.CLOSED_LOOP_CONTROL and state["armed_at"] is None:
            state["armed_at"] = t
        if state["armed_at"] is not None and not state["sent"] and t > state["armed_at"] + 0.6:
            rig.rogue.send(_estop(0))
            state["sent"] = True

    rig.hooks.append(estop_mid_move)
    report = rig.run()
    s = statuses(report)
    assert s["hip: move"] is Status.FAIL and "aborted" in detail(report, "hip: move")
    assert "ESTOP_REQUESTED" in detail(report, "hip: move")
    assert s["hip: move back"] is Status.SKIP
    assert rig.leg.axes["hip"].state is AxisState.IDLE
    assert s["all axes IDLE"] is Status.PASS


def test_a_joint_near_its_upper_limit_moves_towards_the_middle():
    r = Rig(rig=RigConfig(rail_speed_m_s=0.0))  # the rail stopped: the leg comes to rest, foot down
    try:
        r.settle(0.6)
        knee_rad = ControllerConfig().axis("knee").rev_to_rad(r.leg.axes["knee"].encoder_estimates()[0])
        # the knee's configured range ends 0.05 rad above where it rests: +0.1 would cross it
        config = with_knee(ControllerConfig(), max_rad=knee_rad + 0.05, min_rad=knee_rad - 1.0)
        report = r.run(config)
        assert statuses(report)["knee: move"] is Status.PASS, detail(report, "knee: move")
        assert report.axes["knee"]["move"]["step_rad"] == pytest.approx(-0.1)
        knee = config.axis("knee")
        targets = r.targets_rad(knee)
        assert len(targets) > 400 and all(knee.min_rad <= q <= knee.max_rad for q in targets)
        assert max(targets) < report.axes["knee"]["move"]["start_rad"] + 0.01  # it never went up
    finally:
        r.close()


# -- pieces ----------------------------------------------------------------------------------
def test_cosine_ramp_starts_and_ends_at_rest():
    assert cosine_ramp(0.0, 1.0, 0.2, 0.1) == (0.2, 0.0)
    assert cosine_ramp(1.0, 1.0, 0.2, 0.1) == (pytest.approx(0.3), 0.0)
    q, qd = cosine_ramp(0.5, 1.0, 0.2, 0.1)
    assert q == pytest.approx(0.25) and qd == pytest.approx(0.05 * math.pi)
    assert cosine_ramp(2.0, 1.0, 0.2, 0.1)[0] == pytest.approx(0.3)  # never beyond the end


def test_choose_step_stays_inside_the_limits():
    cfg = MoveConfig()
    assert choose_step(0.0, -1.0, 1.0, cfg) == 0.1
    assert choose_step(0.95, -1.0, 1.0, cfg) == -0.1  # towards the middle
    assert choose_step(0.0, -0.05, 0.05, cfg) is None  # no room
    assert choose_step(-0.99, -1.0, 1.0, cfg) == 0.1


def test_error_names():
    assert error_names(0) == "none"
    assert error_names(int(AxisError.ESTOP_REQUESTED | AxisError.WATCHDOG_TIMER_EXPIRED)) == \
        "WATCHDOG_TIMER_EXPIRED|ESTOP_REQUESTED"
    assert "unknown bits 0x80" in error_names(0x80)


def test_the_checklist_counts_and_renders():
    from controller.bringup.checklist import Checklist

    c = Checklist()
    assert not c.passed  # an empty checklist proves nothing
    c.add("hip: a", Status.PASS, "fine")
    c.add("knee: longer name", Status.WARN, "hm")
    c.add("x", Status.SKIP, "not run")
    assert c.passed and c.summary() == "1 passed, 0 failed, 1 warnings, 1 skipped"
    c.add("y", Status.FAIL, "bad")
    assert not c.passed and c.to_dict()["counts"] == {"PASS": 1, "WARN": 1, "FAIL": 1, "SKIP": 1}
    assert c.lines()[0] == "PASS  hip: a             fine"


def test_configs_are_validated():
    with pytest.raises(ValueError):
        MoveConfig(rate_hz=50.0)  # the driver's 0.1 s watchdog needs at least 100 Hz
    with pytest.raises(ValueError):
        BringupConfig(listen_s=0.0)
    with pytest.raises(ValueError):
        BringupConfig(bus_voltage_min_v=60.0)


def _estop(node_id: int) -> can.Message:
    return can.Message(arbitration_id=CONTRACT.odrive_id(node_id, "Estop"), data=b"", is_extended_id=False)


def test_the_move_stops_when_the_joint_leaves_its_limits():
    from controller.io.axis import AxisLink
    from controller.bringup.bus import BusWatch, EncoderReading, Heartbeat
    from controller.bringup.move import AxisMove
    from controller.bringup.checklist import Checklist

    clock = FakeClock()
    hip = ControllerConfig().axis("hip")
    watch = BusWatch(FakeBus(), CONTRACT, [hip.node_id], clock=clock, sleep=clock.sleep)
    move = AxisMove(watch, AxisLink(hip, CONTRACT), MoveConfig(), Checklist())
    move.armed_s = 0.0
    clock.t_s = 1.0
    watch.heartbeats[0] = Heartbeat(0.95, 0, int(AxisState.CLOSED_LOOP_CONTROL), 0)
    watch.encoders[0] = EncoderReading(0.999, hip.rad_to_rev(0.5), 0.0)
    assert move._problem(1.0) is None
    watch.encoders[0] = EncoderReading(0.999, hip.rad_to_rev(hip.max_rad + 0.01), 0.0)
    assert "left the joint limits" in move._problem(1.0)
    watch.encoders[0] = EncoderReading(0.5, hip.rad_to_rev(0.5), 0.0)
    assert "no encoder estimate" in move._problem(1.0)
    watch.encoders[0] = EncoderReading(0.999, hip.rad_to_rev(0.5), 0.0)
    watch.heartbeats[0] = Heartbeat(0.99, int(AxisError.WATCHDOG_TIMER_EXPIRED), int(AxisState.IDLE), 3)
    assert "WATCHDOG_TIMER_EXPIRED" in move._problem(1.0)
