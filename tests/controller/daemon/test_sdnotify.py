"""sd_notify: the daemon's side (controller.daemon.sdnotify, controller.daemon.notify), with this test playing systemd.

The fast tests listen on a datagram socket of their own (hil.dryrun.notify_listener) and check the
messages, the ping period from WATCHDOG_USEC, WATCHDOG_PID, the abstract namespace, the no-op
without NOTIFY_SOCKET and that nothing raises. Two run ``run_controller`` in this process against a
light simulated leg (simulated ODrive axes on a fake plant, no PyBullet) on python-can's virtual
bus, in lockstep: the daemon's clock is the leg's simulated time and its sleep steps the leg, so
the ping times and gaps asserted are simulated seconds, exact on any machine (no wall clock). The
end-to-end test (``vcan``) is the deployment dry run: the unit's own command line
as a separate process, firmware-sim on vcan0 (inside User-Mode Linux where the kernel has no CAN),
READY, regular pings and STOPPING after SIGTERM.
"""

from __future__ import annotations

import os
import socket
import tempfile
import threading
import time
import uuid

import can
import numpy as np
import pytest

from controller.supervisor import Phase
from controller.daemon.notify import DaemonNotify, phase_status
from hil.dryrun.notify_listener import NotifyListener, parse_fields
from controller.daemon.sdnotify import Notifier, socket_address, watchdog_usec_from



@pytest.fixture
def listener():
    lst = NotifyListener().start()
    yield lst
    lst.stop()


def wait_messages(lst: NotifyListener, n: int, timeout_s: float = 10.0):
    deadline = time.monotonic() + timeout_s
    while len(lst.snapshot()) < n and time.monotonic() < deadline:
        time.sleep(0.01)
    return lst.snapshot()


def test_without_notify_socket_everything_is_a_no_op():
    n = Notifier({})
    assert not n.enabled and n.ping_period_s is None
    assert n.ready("x") is False and n.status("x") is False and n.stopping("x") is False
    assert n.watchdog(0.0) is False and n.watchdog(100.0) is False
    assert n.sent == n.errors == n.pings == 0
    # WATCHDOG_USEC alone (no socket to send to) pings nothing either
    assert Notifier({"WATCHDOG_USEC": "1000000"}).ping_period_s is None
    n.close()


def test_messages_are_key_value_lines_from_this_process(listener):
    n = Notifier({"NOTIFY_SOCKET": listener.address})
    assert n.enabled
    assert n.ready("axes in closed loop")
    assert n.status("walking\nsecond line")  # one line: a newline would start a new assignment
    assert n.stopping("stopping (SIGTERM)")
    got = wait_messages(listener, 3)
    assert [m.fields for m in got] == [
        {"READY": "1", "STATUS": "axes in closed loop"},
        {"STATUS": "walking second line"},
        {"STOPPING": "1", "STATUS": "stopping (SIGTERM)"},
    ]
    assert all(m.pid == os.getpid() for m in got)  # what NotifyAccess=main checks
    assert n.sent == 3 and n.errors == 0
    n.close()


def test_abstract_and_path_addresses():
    assert socket_address("@abc") == "\0abc" and socket_address("/run/x") == "/run/x"
    assert NotifyListener().address.startswith("@")
    folder = tempfile.mkdtemp(prefix="es-n-", dir="/tmp")  # short: AF_UNIX paths are limited to 107 bytes
    path = f"{folder}/notify"
    lst = NotifyListener(path).start()
    try:
        assert os.path.exists(path)
        n = Notifier({"NOTIFY_SOCKET": path})
        assert n.ready("ok")
        assert wait_messages(lst, 1)[0].fields["READY"] == "1"
        n.close()
    finally:
        lst.stop()
        os.rmdir(folder)
    assert not os.path.exists(path)


def test_pings_every_half_of_watchdog_usec_on_the_callers_clock(listener):
    n = Notifier({"NOTIFY_SOCKET": listener.address, "WATCHDOG_USEC": "200000"})
    assert n.watchdog_usec == 200_000 and n.ping_period_s == pytest.approx(0.1)
    sent = [t for t in np.arange(0.0, 1.0, 0.002) if n.watchdog(float(t))]  # a 500 Hz loop for 1 s
    assert len(sent) == 10 and n.pings == 10
    assert np.allclose(np.diff(sent), 0.1, atol=0.0021)  # never later than one tick past due
    got = wait_messages(listener, 10)
    assert len(got) == 10 and all(m.fields == {"WATCHDOG": "1"} for m in got)
    n.close()


def test_watchdog_pid_decides_who_pings(listener):
    env = {"NOTIFY_SOCKET": listener.address, "WATCHDOG_USEC": "1000000"}
    me = os.getpid()
    assert watchdog_usec_from({**env, "WATCHDOG_PID": str(me)}, me) == 1_000_000
    assert watchdog_usec_from(env, me) == 1_000_000  # unset: ours
    assert watchdog_usec_from({**env, "WATCHDOG_PID": str(me + 1)}, me) is None  # a parent's, not ours
    for bad in ("0", "-5", "soon", ""):
        assert watchdog_usec_from({**env, "WATCHDOG_USEC": bad}, me) is None
    assert watchdog_usec_from({**env, "WATCHDOG_PID": "x"}, me) is None
    other = Notifier({**env, "WATCHDOG_PID": str(me + 1)})
    assert other.enabled and other.ping_period_s is None and other.watchdog(0.0) is False
    assert other.ready("still tells READY")  # only the pings belong to WATCHDOG_PID
    other.close()


def test_send_failures_are_counted_never_raised(caplog):
    missing = f"/tmp/es-no-listener-{uuid.uuid4().hex[:8]}"
    n = Notifier({"NOTIFY_SOCKET": missing, "WATCHDOG_USEC": "100000"})
    assert n.enabled
    assert n.ready("x") is False and n.watchdog(0.0) is False and n.watchdog(0.001) is False
    assert n.errors == 3 and n.sent == 0 and n.pings == 0 and "failed" in n.last_error
    assert sum("sd_notify" in r.message for r in caplog.records) == 1  # logged once, then counted
    n.close()
    odd = Notifier({"NOTIFY_SOCKET": "vsock:2:1234"})
    assert not odd.enabled and odd.errors == 1 and odd.ready("x") is False
    # a closed socket: still no exception into the caller
    n2 = Notifier({"NOTIFY_SOCKET": "@es-nobody-" + uuid.uuid4().hex[:8]})
    n2._sock.close()
    assert n2.status("x") is False and n2.errors == 1


def test_a_full_listener_does_not_block_the_sender():
    """Never a wait: the socket is non-blocking, so a full queue is an error counted at once
    (a blocking send would hang this test instead of failing an assert on how long it took)."""
    deaf = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)  # bound, never reads
    address = "@es-deaf-" + uuid.uuid4().hex[:8]
    deaf.bind(socket_address(address))
    try:
        n = Notifier({"NOTIFY_SOCKET": address})
        assert n._sock.getblocking() is False and n._sock.gettimeout() == 0.0
        for _ in range(3000):
            n.status("x" * 200)
        assert n.errors > 0 and n.sent > 0  # its queue filled: counted as errors, never a wait
        assert n.sent + n.errors == 3000 and "BlockingIOError" in n.last_error
        n.close()
    finally:
        deaf.close()


def test_daemon_notify_ready_once_when_inactive_status_on_phases_ping_in_fault(listener):
    d = DaemonNotify(Notifier({"NOTIFY_SOCKET": listener.address, "WATCHDOG_USEC": "1000000"}))
    d.tick(0.0)
    for p in (Phase.WAIT_NODES, Phase.INACTIVE, Phase.ARMING, Phase.RAMP, Phase.WALK):
        d.phase(p)
    d.phase(Phase.FAULT, "axis hip left closed loop")
    d.tick(0.6)  # FAULT: the loop is alive and keeps the axes IDLE, so it keeps pinging
    d.phase(Phase.WAIT_NODES)  # faults cleared: no second READY
    d.phase(Phase.INACTIVE)
    d.stopping("SIGTERM")
    got = [m.fields for m in wait_messages(listener, 11)]
    assert got[0] == {"WATCHDOG": "1"}
    assert got[1] == {"STATUS": phase_status(Phase.WAIT_NODES)} and got[1]["STATUS"].startswith("inactive: ")
    assert got[2] == {"READY": "1", "STATUS": phase_status(Phase.INACTIVE)}  # inactive and healthy
    assert got[3] == {"STATUS": phase_status(Phase.ARMING)} and got[3]["STATUS"].startswith("active: ")
    assert got[4] == {"STATUS": phase_status(Phase.RAMP)}
    assert got[5] == {"STATUS": "active: walking"}
    assert got[6]["STATUS"].startswith("fault: ") and "hip left closed loop" in got[6]["STATUS"]
    assert got[7] == {"WATCHDOG": "1"}
    assert got[8] == {"STATUS": phase_status(Phase.WAIT_NODES)} and got[9] == {"STATUS": phase_status(Phase.INACTIVE)}
    assert got[10]["STOPPING"] == "1" and "SIGTERM" in got[10]["STATUS"]
    assert sum("READY" in m for m in got) == 1 and d.summary()["ready_sent"]
    d.close()


def test_ready_comes_with_auto_arm_in_the_tick_inactive_is_passed():
    from controller.daemon.notify import READY_PHASES

    assert Phase.INACTIVE in READY_PHASES and Phase.ARMING in READY_PHASES
    assert Phase.WAIT_NODES not in READY_PHASES and Phase.FAULT not in READY_PHASES


def test_parse_fields():
    assert parse_fields(b"READY=1\nSTATUS=a=b\n\njunk") == {"READY": "1", "STATUS": "a=b"}


# -- run_controller in this process, against a light simulated leg on the virtual bus -----------
class LightLeg(threading.Thread):
    """Simulated ODrive axes (hip node 0, knee node 1: the real firmware model) on a fake plant
    of two inertias, and the sensor board, on python-can's virtual bus, stepped at 1 kHz: either
    in lockstep (not started: :meth:`clock` and :meth:`sleep` are the daemon's clock and sleep, and
    the daemon's sleep steps the leg), or as a thread on wall-clock time (started; catching up
    when late) for the tests that need the daemon in a thread of its own."""

    DT_S = 0.001

    def __init__(self, channel: str) -> None:
        super().__init__(name="light-leg", daemon=True)
        from firmware_sim.motor import MotorJoint, Transmission
        from firmware_sim.node_host import NodeHost
        from firmware_sim.odrive_axis import DriverConfig, SimOdriveAxis
        from firmware_sim.sensor_board import SensorBoard, SensorBoardConfig
        from tests.fakes import FakeJointPlant, FakeSensorSource

        self.bus = can.Bus(interface="virtual", channel=channel)
        self.plant = FakeJointPlant({"hip": 0.0, "knee": -0.3}, inertia_kg_m2=0.01, damping_nm_s=0.05)
        self.axes = [
            SimOdriveAxis(DriverConfig(node_id=0, watchdog_timeout_s=0.1), MotorJoint(self.plant, "hip", Transmission())),
            SimOdriveAxis(DriverConfig(node_id=1, watchdog_timeout_s=0.1),
                          MotorJoint(self.plant, "knee", Transmission(direction=-1))),
        ]
        board = SensorBoard(SensorBoardConfig(), FakeSensorSource(range_value=None), np.random.default_rng(0))
        self.host = NodeHost(self.bus, [*self.axes, board])
        self.halt = threading.Event()
        self.steps = 0  # the leg's time is steps * DT_S: no drift from adding floats
        self.hooks: list = []  # called with the time after each step (lockstep)

    def clock(self) -> float:
        """The leg's simulated time [s]: the daemon's monotonic clock in lockstep."""
        return self.steps * self.DT_S

    def step_until(self, t_s: float) -> None:
        while self.steps * self.DT_S < t_s - 1e-9:
            self.host.step(self.steps * self.DT_S, self.DT_S)
            self.plant.step(self.DT_S)
            self.steps += 1
            for hook in self.hooks:
                hook(self.clock())

    def sleep(self, dt_s: float) -> None:
        """The daemon's sleep in lockstep: the leg runs ``dt_s`` of its time."""
        if dt_s < 0:
            raise ValueError("sleep length must be non-negative")  # as time.sleep
        self.step_until(self.clock() + dt_s)

    def run(self) -> None:
        t0 = time.monotonic()
        while not self.halt.is_set():
            self.step_until(time.monotonic() - t0)
            time.sleep(0.001)

    def close(self) -> None:
        self.halt.set()
        if self.is_alive():
            self.join(timeout=5)
        self.bus.shutdown()


def record_notifications(monkeypatch, clock, listener: NotifyListener) -> list[tuple[float, dict[str, str]]]:
    """Every notification the daemon hands to its socket, with ``clock()`` when it did (the
    lockstep leg's time), as ``(t_s, fields)``. Each send waits until the listener (systemd) has
    it: in lockstep the daemon runs faster than real time, and a listener thread that is not
    scheduled for a moment would let the socket's queue (``net.unix.max_dgram_qlen``, 10) fill; a
    real systemd is never 10 messages behind a daemon on the wall clock. Simulated time stands
    still meanwhile, so nothing asserted depends on the wait."""
    from controller.daemon.sdnotify import Notifier as RealNotifier

    sent: list[tuple[float, dict[str, str]]] = []
    original = RealNotifier.notify

    def notify(self, **fields):
        ok = original(self, **fields)
        if ok:
            sent.append((clock(), {k: str(v) for k, v in fields.items()}))
            got = wait_messages(listener, len(sent))
            assert len(got) >= len(sent), f"the listener never received {fields}"
        return ok

    monkeypatch.setattr(RealNotifier, "notify", notify)
    return sent


def test_run_controller_tells_systemd_ready_pings_and_stopping(listener, monkeypatch):
    from controller.config import ControllerConfig
    from controller.daemon.run import run_controller
    from protocol import AxisState

    channel = f"sdnotify-{uuid.uuid4().hex}"
    leg = LightLeg(channel)  # in lockstep: the daemon's clock and sleep
    monkeypatch.setenv("NOTIFY_SOCKET", listener.address)
    monkeypatch.setenv("WATCHDOG_USEC", "200000")  # a ping every 0.1 s
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    sent = record_notifications(monkeypatch, leg.clock, listener)
    config = ControllerConfig(auto_arm=True)
    try:
        final = run_controller({"interface": "virtual", "channel": channel}, config, duration_s=3.0,
                               clock=leg.clock, sleep=leg.sleep)
    finally:
        leg.close()
    got = wait_messages(listener, len(sent))
    assert [m.fields for m in got] == [fields for _, fields in sent]  # each reached systemd's socket, in order
    ready = [m for m in got if m.has("READY", "1")]
    # auto_arm arms in the tick INACTIVE is reached: READY comes with ARMING's status
    assert len(ready) == 1 and ready[0].fields["STATUS"] in (phase_status(Phase.INACTIVE), phase_status(Phase.ARMING)), \
        [m.fields for m in got]
    statuses = [m.fields["STATUS"] for m in got if "STATUS" in m.fields]
    assert phase_status(Phase.ARMING) in statuses and "active: walking" in statuses
    assert not any(s.startswith("fault") for s in statuses), statuses
    pings = [t for t, fields in sent if fields == {"WATCHDOG": "1"}]
    # from the first tick (one period after the start) to the last
    assert pings[0] == pytest.approx(config.period_s) and pings[-1] > 3.0 - 0.1 - config.period_s
    # every half of WATCHDOG_USEC, at the first tick due (simulated seconds, exact): never near the limit
    assert max(np.diff(pings)) <= 0.1 + config.period_s + 1e-9 and min(np.diff(pings)) >= 0.1 - 1e-9
    assert len(pings) == pytest.approx(3.0 / 0.1, abs=2)
    assert got[-1].has("STOPPING", "1") and all(m.pid == os.getpid() for m in got)
    assert final["stopped_by"] == "duration" and final["phase"] == "walk"
    assert final["sd_notify"]["errors"] == 0 and final["sd_notify"]["ready_sent"] is True
    assert final["sd_notify"]["pings"] == len(pings)
    assert all(a.state is AxisState.IDLE for a in leg.axes)  # the clean stop's IDLE reached the drivers
    assert not any(int(a.errors) for a in leg.axes)  # on our word, not a watchdog trip


def test_a_stuck_loop_stops_pinging_the_drivers_stop_the_leg_and_fault_keeps_pinging(listener, monkeypatch):
    """The chain of docs/deploy.md section 7, in this process: the loop stalls 0.4 s while walking;
    no ping comes during the stall (they come from the loop, not from a thread); the drivers'
    watchdogs (0.1 s) disarm both axes; the supervisor then sees them out of closed loop: FAULT,
    latched; the loop, alive again, keeps pinging in FAULT."""
    from controller.config import ControllerConfig
    from controller.loop import ControlLoop
    from controller.daemon.run import run_controller
    from protocol import AxisError, AxisState

    channel = f"sdnotify-{uuid.uuid4().hex}"
    leg = LightLeg(channel)  # in lockstep: the daemon's clock and sleep
    original = ControlLoop.tick
    stall: dict[str, float] = {}

    def tick(self, now_s: float) -> None:
        original(self, now_s)
        if "from" not in stall and self.phase is Phase.WALK:
            stall.setdefault("walk", now_s)
            if now_s - stall["walk"] > 0.5:
                stall["from"] = leg.clock()
                leg.sleep(0.4)  # stuck: 0.4 s of the leg's time pass inside one tick
                stall["to"] = leg.clock()

    monkeypatch.setattr(ControlLoop, "tick", tick)
    monkeypatch.setenv("NOTIFY_SOCKET", listener.address)
    monkeypatch.setenv("WATCHDOG_USEC", "200000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    sent = record_notifications(monkeypatch, leg.clock, listener)
    tripped: dict[str, float] = {}
    leg.hooks.append(lambda t: tripped.setdefault("t", t) if "t" not in tripped and all(
        int(a.errors) & AxisError.WATCHDOG_TIMER_EXPIRED for a in leg.axes) else None)
    try:
        final = run_controller({"interface": "virtual", "channel": channel}, ControllerConfig(auto_arm=True),
                               duration_s=4.0, clock=leg.clock, sleep=leg.sleep)
    finally:
        leg.close()
    assert "to" in stall, "the loop never walked"
    got = wait_messages(listener, len(sent))
    assert [m.fields for m in got] == [fields for _, fields in sent]  # each reached systemd's socket, in order
    pings = [t for t, fields in sent if fields == {"WATCHDOG": "1"}]
    assert not [t for t in pings if stall["from"] < t < stall["to"]]  # silent while stuck
    gap = max(b - a for a, b in zip(pings, pings[1:]))
    assert gap >= 0.4 > 0.2  # longer than WATCHDOG_USEC: systemd would act
    assert all(int(a.errors) & AxisError.WATCHDOG_TIMER_EXPIRED for a in leg.axes)  # the drivers stopped the leg
    assert stall["from"] < tripped["t"] <= stall["from"] + 0.1 + 0.01  # their 0.1 s watchdog, during the stall
    assert all(a.state is AxisState.IDLE for a in leg.axes)
    t_fault, fault = next((t, f) for t, f in sent if f.get("STATUS", "").startswith("fault"))
    assert t_fault >= stall["to"] and "closed loop" in fault["STATUS"]
    assert len([t for t in pings if t > t_fault]) >= 5  # alive and safe in FAULT: still pinging
    assert final["phase"] == "fault" and got[-1].has("STOPPING", "1")
