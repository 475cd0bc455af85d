"""The daemon's control socket (controller.daemon.control) and the leg verbs that use it
(status, arm, disarm, clear-faults, estop): the protocol, bad requests, "daemon busy", the socket
file's mode and life, the client's errors; then the real daemon (``run_controller`` in a thread)
against a light simulated leg on python-can's virtual bus, driven through the real socket by the
verbs' own ``main``."""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import tempfile
import threading
import time
import uuid

import pytest

from controller.cli import VERBS, main
from controller.daemon.control import (MAX_REQUEST_BYTES, ControlError, ControlPermissionError, ControlServer,
                                       ControlSocketError, parse_request, request)


@pytest.fixture
def short_dir():
    folder = tempfile.mkdtemp(prefix="es-c-", dir="/tmp")  # AF_UNIX paths: at most 107 bytes
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def raw(path: str, data: bytes, timeout_s: float = 5.0) -> dict:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout_s)
    s.connect(path)
    try:
        s.sendall(data)
        buf = b""
        while b"\n" not in buf:
            chunk = s.recv(65536)
            if not chunk:
                break
            buf += chunk
    finally:
        s.close()
    return json.loads(buf)


class Pump(threading.Thread):
    """Plays the control loop: runs the queue every 2 ms on its own thread."""

    def __init__(self, server: ControlServer, execute) -> None:
        super().__init__(daemon=True)
        self.server, self.execute, self.halt = server, execute, threading.Event()
        self.threads: set[str] = set()

    def run(self) -> None:
        def ex(verb):
            self.threads.add(threading.current_thread().name)
            return self.execute(verb)

        while not self.halt.is_set():
            self.server.run_pending(ex)
            time.sleep(0.002)


def test_the_verbs_are_registered_one_module_each():
    names = [v.name for v in VERBS]
    for name in ("status", "arm", "disarm", "clear-faults", "estop"):
        assert name in names
    assert {v.module for v in VERBS if v.name in ("arm", "clear-faults")} == {"controller.cli.arm",
                                                                            "controller.cli.clear_faults"}


def test_parse_request():
    assert parse_request(b'{"verb": "arm"}') == ("arm", None)
    assert parse_request(b"arm")[1].startswith("bad request: not a JSON line")
    assert parse_request(b"[1]")[1].startswith("bad request: a JSON object")
    assert parse_request(b'{"verb": 3}')[1].startswith("bad request: no verb")
    assert parse_request(b'{"verb": "fly"}') == ("fly", "unknown verb 'fly' (one of status, arm, disarm, "
                                                        "clear-faults, estop)")
    assert parse_request(b"\xff\xfe")[1].startswith("bad request: not a JSON line")


def test_requests_run_on_the_loops_thread_and_bad_ones_never_stop_the_server(short_dir):
    path = f"{short_dir}/c.sock"
    server = ControlServer(path).start()
    pump = Pump(server, lambda verb: (None if verb != "arm" else "cannot arm in phase walk", {"phase": "walk"}))
    pump.name = "the-loop"
    pump.start()
    try:
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o660 and stat.S_ISSOCK(os.stat(path).st_mode)
        assert request(path, "status") == {"ok": True, "verb": "status", "refused": None, "status": {"phase": "walk"}}
        assert request(path, "arm") == {"ok": False, "verb": "arm", "refused": "cannot arm in phase walk",
                                        "status": {"phase": "walk"}}
        assert pump.threads == {"the-loop"}  # executed by the loop's thread, never the server's
        bad = raw(path, b"hello\n")
        assert bad["ok"] is False and bad["refused"].startswith("bad request: not a JSON line") and bad["status"] is None
        assert raw(path, b'{"verb": "jump"}\n')["refused"].startswith("unknown verb 'jump'")
        long = raw(path, b'{"verb": "' + b"x" * (MAX_REQUEST_BYTES + 10) + b'"}\n')
        assert long["ok"] is False and "longer than" in long["refused"]
        assert raw(path, b"\n")["refused"].startswith("bad request: an empty line")
        # a client that connects and leaves without a word
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(path)
        s.close()
        assert request(path, "status")["ok"] is True  # still serving
        assert server.bad == 5 and server.executed == 3  # the silent client counts as a bad request
    finally:
        pump.halt.set()
        pump.join()
        server.close()
    assert not os.path.exists(path)  # removed at exit


def test_a_loop_that_does_not_take_the_request_in_2_s_is_daemon_busy_and_it_never_runs(short_dir):
    """The connection waits for the loop with the server's ``wait``: here the test's, which says at
    once that the reply timeout passed (no wall clock); the request asked for is withdrawn."""
    path = f"{short_dir}/c.sock"
    waits: list[float] = []

    def timed_out(event: threading.Event, timeout_s: float) -> bool:
        waits.append(timeout_s)
        return event.is_set()  # the loop never ran it: the timeout has passed

    server = ControlServer(path, reply_timeout_s=0.3, wait=timed_out).start()
    ran = []
    try:
        out = request(path, "estop")
        assert out == {"ok": False, "verb": "estop", "refused": "daemon busy", "status": None}
        assert waits == [0.3]  # it waited for the loop once, as long as its reply timeout
        assert server.run_pending(lambda verb: ran.append(verb) or (None, {})) == 0
        assert ran == [] and server.busy == 1  # withdrawn: an estop answered "busy" never happens later
    finally:
        server.close()
    assert ControlServer(path).reply_timeout_s == 2.0
    assert ControlServer(path).wait is threading.Event.wait  # the real one by default


def test_a_request_the_loop_is_running_at_the_timeout_gets_its_reply(short_dir):
    """Taken by the loop just as the reply timeout passed: the connection waits once more, and the
    reply is the loop's, not "daemon busy"."""
    path = f"{short_dir}/c.sock"
    server: ControlServer

    def loop_takes_it_at_the_timeout(event: threading.Event, timeout_s: float) -> bool:
        if not event.is_set():
            runner = threading.Thread(target=server.run_pending, args=(lambda verb: (None, {"phase": "walk"}),))
            runner.start()
            runner.join()
        return event.is_set()

    server = ControlServer(path, reply_timeout_s=0.3, wait=loop_takes_it_at_the_timeout).start()
    try:
        assert request(path, "status") == {"ok": True, "verb": "status", "refused": None, "status": {"phase": "walk"}}
        assert server.busy == 0 and server.executed == 1
    finally:
        server.close()


def test_stale_socket_removed_live_one_refused_other_files_untouched(short_dir):
    path = f"{short_dir}/c.sock"
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(path)
    stale.close()  # a dead daemon's file: nothing listens
    first = ControlServer(path).start()
    try:
        with pytest.raises(ControlSocketError, match="another daemon listens"):
            ControlServer(path).start()
        assert os.path.exists(path)  # the live one's file was not removed
    finally:
        first.close()
    other = f"{short_dir}/notes.txt"
    with open(other, "w") as f:
        f.write("mine")
    with pytest.raises(ControlSocketError, match="not a socket"):
        ControlServer(other).start()
    assert open(other).read() == "mine"
    with pytest.raises(ControlSocketError, match="does not exist"):
        ControlServer(f"{short_dir}/g.sock", group=f"no-such-group-{uuid.uuid4().hex[:6]}").start()
    with pytest.raises(ControlSocketError, match="107 bytes"):
        ControlServer(f"{short_dir}/{'x' * 120}.sock").start()


def test_the_socket_gets_the_control_group(short_dir):
    import grp

    path = f"{short_dir}/c.sock"
    group = grp.getgrgid(os.getgid()).gr_name
    server = ControlServer(path, group=group).start()
    try:
        assert os.stat(path).st_gid == os.getgid()
    finally:
        server.close()


def test_client_errors_are_one_line(short_dir, monkeypatch, capsys):
    path = f"{short_dir}/none.sock"
    with pytest.raises(ControlError) as exc:
        request(path, "status")
    assert str(exc.value) == f"no daemon at {path} (is it running? systemctl status elegant-stepping-controller)"
    assert exc.value.exit_code == 4  # no daemon answers: the leg's link does not answer
    assert main(["arm", "--socket", path]) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"elegant-stepping-leg arm: error: no daemon at {path} (is it running? systemctl status "
                   f"elegant-stepping-controller)"]

    server = ControlServer(f"{short_dir}/c.sock").start()
    try:
        def denied(self, address):
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr(socket.socket, "connect", denied)
        with pytest.raises(ControlPermissionError, match="permission denied on .*c.sock: commanding the leg needs "
                                                         "the group ") as denied_exc:
            request(server.path, "status")
        assert isinstance(denied_exc.value, ControlError) and denied_exc.value.exit_code == 3  # an input to fix
        capsys.readouterr()
        assert main(["status", "--socket", str(server.path)]) == 3
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"elegant-stepping-leg status: error: permission denied on "
                                                   f"{server.path}: commanding the leg needs the group "), err
    finally:
        monkeypatch.undo()
        server.close()


def test_a_daemon_that_never_replies_is_exit_4_after_the_timeout(short_dir, capsys):
    path = f"{short_dir}/deaf.sock"
    deaf = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)  # listens, never accepts: connect works, no reply
    deaf.bind(path)
    deaf.listen(1)
    try:
        assert main(["status", "--socket", path, "--timeout-s", "0.2"]) == 4
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"elegant-stepping-leg status: error: no reply from the daemon at {path} within 0.2 s"]
    finally:
        deaf.close()


def test_a_bad_timeout_is_a_usage_error(short_dir, capsys):
    for bad in ("0", "-1", "nan"):
        with pytest.raises(SystemExit) as exc:
            main(["status", "--socket", f"{short_dir}/c.sock", "--timeout-s", bad])
        assert exc.value.code == 2 and "--timeout-s" in capsys.readouterr().err


def test_the_socket_path_from_a_configuration_file(short_dir, tmp_path, capsys):
    config = tmp_path / "leg.toml"
    config.write_text(f'[bus]\ninterface = "virtual"\nchannel = "x"\n[service]\ncontrol_socket = "{short_dir}/cfg.sock"\n')
    assert main(["status", "--config", str(config)]) == 4
    assert f"no daemon at {short_dir}/cfg.sock" in capsys.readouterr().err


def test_a_bad_or_missing_configuration_is_exit_3_naming_the_file(tmp_path, capsys):
    missing = tmp_path / "none.toml"
    assert main(["arm", "--config", str(missing)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"elegant-stepping-leg arm: error: {missing}: cannot read the configuration: No such file or "
                   "directory"]
    bad = tmp_path / "bad.toml"
    bad.write_text("[bus]\ninterface = \"virtual\"\nchannel = \"x\"\n[cpg]\nstance_s = 0\nburst_s = 9\n")
    assert main(["status", "--config", str(bad)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith(f"{bad}: cpg.") for line in err[:2]), err  # each problem, then one
    assert err[-1] == (f"elegant-stepping-leg status: error: {bad}: 2 problems in the configuration (each on its "
                       "own line above)")


# -- the real daemon, in a thread, against a light simulated leg ------------------------------------
OUTCOME_TIMEOUT_S = 30.0
"""How long a test waits for an outcome of the threaded daemon (a phase, the drivers' errors) before
it fails naming the outcome: generous, for a loaded machine; nothing here asserts how long anything
took. Where a test needs "a while" it counts the daemon's own ticks."""


def wait_for(outcome: str, done, timeout_s: float = OUTCOME_TIMEOUT_S, poll_s: float = 0.02):
    """Poll ``done()`` until it is truthy (returned); fail naming ``outcome`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        got = done()
        if got:
            return got
        assert time.monotonic() < deadline, f"not within {timeout_s:g} s: {outcome}"
        time.sleep(poll_s)


class Daemon:
    def __init__(self, path: str, **kw) -> None:
        from tests.controller.daemon.test_sdnotify import LightLeg

        from controller.config import ControllerConfig
        from controller.daemon.run import run_controller

        self.channel = f"control-{uuid.uuid4().hex}"
        self.leg = LightLeg(self.channel)
        self.path = path
        self.stop = threading.Event()
        self.final: dict | None = None
        self.error: BaseException | None = None

        def go():
            try:
                self.final = run_controller({"interface": "virtual", "channel": self.channel},
                                            kw.pop("config", ControllerConfig()), control_socket=path,
                                            stop_event=self.stop, duration_s=60, **kw)
            except BaseException as exc:  # noqa: BLE001
                self.error = exc

        self.thread = threading.Thread(target=go, name="daemon", daemon=True)

    def __enter__(self) -> "Daemon":
        self.leg.start()
        self.thread.start()

        def answering() -> bool:  # the file exists once bound, but a connect is refused until listen()
            assert self.error is None, self.error
            if not os.path.exists(self.path):
                return False
            try:
                request(self.path, "status")
            except ControlError:
                return False
            return True

        wait_for(f"the daemon answering on its control socket {self.path}", answering)
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(timeout=20)
        self.leg.close()

    def wait_phase(self, phase: str) -> dict:
        seen: list[str] = []

        def there():
            st = request(self.path, "status")["status"]
            seen.append(st["phase"])
            return st if st["phase"] == phase else None

        return wait_for(f"phase {phase} (phases seen: {sorted(set(seen))})", there, poll_s=0.05)

    def wait_ticks(self, n: int) -> dict:
        """The status once the daemon's loop has ticked ``n`` more times (its clock, not the test's)."""
        start = request(self.path, "status")["status"]["ticks"]

        def ticked():
            st = request(self.path, "status")["status"]
            return st if st["ticks"] >= start + n else None

        return wait_for(f"{n} more ticks of the daemon's loop", ticked)


def test_the_daemon_starts_inactive_and_a_person_arms_estops_clears_and_disarms_it(short_dir, capsys):
    from protocol import AxisError, AxisState

    path = f"{short_dir}/c.sock"
    with Daemon(path) as d:
        st = d.wait_phase("inactive")
        assert st["lifecycle"] == "inactive" and st["arm_blocked"] is None
        assert d.wait_ticks(75)["phase"] == "inactive"  # it never arms by itself (75 ticks: 0.3 s of its clock)
        assert all(a.state is AxisState.IDLE for a in d.leg.axes)

        capsys.readouterr()
        assert main(["status", "--socket", path]) == 0
        out = capsys.readouterr().out
        assert "lifecycle inactive, phase inactive" in out and "hip" in out and "knee" in out and "IDLE" in out
        assert "ticks" in out and "weights: not persisted" in out
        assert main(["status", "--socket", path, "--json"]) == 0
        reply = json.loads(capsys.readouterr().out)
        assert reply["ok"] and set(reply["status"]["axes"]) == {"hip", "knee"} and reply["status"]["version"]

        assert main(["disarm", "--socket", path]) == 1  # not armed
        assert "elegant-stepping-leg disarm: refused: not armed" in capsys.readouterr().err

        assert main(["arm", "--socket", path]) == 0
        assert "arm: accepted" in capsys.readouterr().out
        d.wait_phase("walk")
        assert main(["arm", "--socket", path]) == 1
        assert "only from inactive" in capsys.readouterr().err

        assert main(["estop", "--socket", path]) == 0
        st = d.wait_phase("fault")
        assert st["fault_cause"] == "estop by operator" and st["lifecycle"] == "fault"
        wait_for("ESTOP_REQUESTED latched by both drivers",
                 lambda: all(int(a.errors) & AxisError.ESTOP_REQUESTED for a in d.leg.axes))
        assert all(a.state is AxisState.IDLE for a in d.leg.axes)

        assert main(["arm", "--socket", path]) == 1  # a fault is latched
        capsys.readouterr()
        assert main(["clear-faults", "--socket", path]) == 0
        st = d.wait_phase("inactive")
        assert not any(a["error"] for a in st["axes"].values())
        assert main(["arm", "--socket", path]) == 0
        d.wait_phase("walk")
        assert main(["disarm", "--socket", path]) == 0
        st = d.wait_phase("inactive")
        assert st["fault_cause"] == ""
    assert d.error is None and d.final is not None
    assert not os.path.exists(path)  # removed at exit
    verbs = [(c["verb"], c["refused"] is None) for c in d.final["commands"]]
    assert verbs == [("disarm", False), ("arm", True), ("arm", False), ("estop", True), ("arm", False),
                     ("clear-faults", True), ("arm", True), ("disarm", True)]
    assert d.final["stopped_by"] == "event" and d.final["control"]["executed"] >= len(verbs)


def test_an_unconfirmed_calibration_refuses_arm_with_the_reason(short_dir, capsys):
    from controller.settings.file import DeployConfig

    deploy = DeployConfig()
    reason = deploy.armable_reason()
    assert reason and "calibration not confirmed" in reason
    path = f"{short_dir}/c.sock"
    with Daemon(path, deploy=deploy) as d:
        st = d.wait_phase("inactive")
        assert st["arm_blocked"] == reason
        capsys.readouterr()
        assert main(["arm", "--socket", path]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"elegant-stepping-leg arm: refused: {reason}"]
        assert main(["status", "--socket", path]) == 0
        assert "arming blocked: calibration not confirmed" in capsys.readouterr().out
        assert d.wait_ticks(50)["phase"] == "inactive"  # the refused arm did not arm it later
    assert d.error is None


def test_auto_arm_walks_without_a_command(short_dir):
    from controller.config import ControllerConfig

    path = f"{short_dir}/c.sock"
    with Daemon(path, config=ControllerConfig(auto_arm=True)) as d:
        d.wait_phase("walk")
    assert d.error is None and d.final["commands"] == []
