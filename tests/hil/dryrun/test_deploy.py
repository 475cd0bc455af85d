"""The deployment files: the systemd unit, its install script, the dry run's pieces (no bus here).

``systemd-analyze verify`` needs a running systemd, which this machine has not: the unit is
checked by our own reader of the unit syntax (hil.dryrun.unitfile) and its ExecStart by our own CLI
parser.
"""

from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import pytest

from hil.dryrun.run import Deployment, checklist, final_record, format_report, swap_config
from hil.dryrun.notify_listener import NotifyMessage
from hil.dryrun.unitfile import command_line, environment, parse_unit, read_unit, time_span_s, value

REPO = Path(__file__).resolve().parents[3]
UNIT = REPO / "deploy" / "elegant-stepping-controller.service"
INSTALL = REPO / "deploy" / "install.sh"


@pytest.fixture(scope="module")
def unit():
    return read_unit(UNIT)


def test_the_unit_has_the_sections_and_settings_the_deployment_relies_on(unit):
    assert set(unit) == {"Unit", "Service", "Install"}
    s = lambda key: value(unit, "Service", key)  # noqa: E731
    assert s("Type") == "notify" and s("NotifyAccess") == "main"
    assert s("Restart") == "on-failure" and time_span_s(s("RestartSec")) >= 1.0
    assert value(unit, "Unit", "StartLimitBurst") and value(unit, "Unit", "StartLimitIntervalSec")
    assert s("User") == "elegant-stepping" and s("Group") == "elegant-stepping"
    assert s("StateDirectory") == "elegant-stepping" and s("ReadWritePaths") == "/var/lib/elegant-stepping"
    assert s("StandardOutput") == "journal" and s("StandardError") == "journal"
    assert s("NoNewPrivileges") == "yes" and s("ProtectSystem") == "strict"
    assert set(s("RestrictAddressFamilies").split()) == {"AF_CAN", "AF_UNIX"}  # the bus and sd_notify
    assert "PrivateNetwork" not in unit["Service"]  # it would hide can0
    assert "CapabilityBoundingSet" in unit["Service"] and s("CapabilityBoundingSet") is None  # emptied
    assert value(unit, "Install", "WantedBy") == "multi-user.target"
    # the control socket's folder (/run/elegant-stepping), reached by the daemon's group only
    assert s("RuntimeDirectory") == "elegant-stepping" and s("RuntimeDirectoryMode") == "0750"
    # usage, input (a configuration included) and a missing install part: a restart would fix none of
    # them; a bus that cannot be opened is retried (an adapter may come up late)
    from controller.errors import EXIT_BUS, EXIT_INPUT, EXIT_MISSING, EXIT_USAGE

    prevent = {int(code) for code in s("RestartPreventExitStatus").split()}
    assert prevent == {EXIT_USAGE, EXIT_INPUT, EXIT_MISSING} and EXIT_BUS not in prevent


def test_the_watchdog_and_timeouts_leave_room_for_the_loop(unit):
    watchdog = time_span_s(value(unit, "Service", "WatchdogSec"))
    assert watchdog == 1.0
    assert watchdog / 2 > 0.171 * 2  # pings at half of it, with room for the worst stall measured (171 ms)
    assert time_span_s(value(unit, "Service", "TimeoutStopSec")) >= 5.0


def test_exec_start_is_the_leg_daemon_with_a_config_and_parses_with_its_cli(unit):
    from controller.cli import VERBS
    from controller.cli.common import build_parser

    prefix, argv = command_line(value(unit, "Service", "ExecStart"))
    assert prefix == ""  # the daemon runs as User=, sandboxed
    assert argv[:2] == ["/usr/local/bin/elegant-stepping-leg", "run"]
    args = build_parser("elegant-stepping-leg", "", VERBS).parse_args(argv[1:])
    assert args.command == "run" and args.config == "/etc/elegant-stepping/leg.toml"
    assert args._verb.module == "controller.cli.run"


def test_only_exec_start_pre_runs_privileged_and_it_brings_can0_up_at_1_mbit(unit):
    pre = [command_line(line) for line in unit["Service"]["ExecStartPre"]]
    assert all("+" in prefix for prefix, _ in pre)
    words = [" ".join(argv) for _, argv in pre]
    assert any("can0 type can bitrate 1000000" in w for w in words) and words[-1].endswith("can0 up")
    assert environment(unit)["PYTHONFAULTHANDLER"] == "1"  # a watchdog kill (SIGABRT) dumps every thread's stack


def test_the_example_leg_config_matches_the_unit():
    from controller.settings.file import load_config

    leg = load_config(REPO / "configs" / "odrive-leg.toml")
    u = read_unit(UNIT)
    assert (leg.bus.interface, leg.bus.channel, leg.bus.bitrate) == ("socketcan", "can0", 1_000_000)
    pre = " ".join(" ".join(command_line(line)[1]) for line in u["Service"]["ExecStartPre"])
    assert f"{leg.bus.channel} type can bitrate {leg.bus.bitrate}" in pre
    assert Path(leg.weights.path).parent == Path("/var/lib") / value(u, "Service", "StateDirectory")
    assert Path(leg.service.control_socket).parent == Path("/run") / value(u, "Service", "RuntimeDirectory")
    # READY may take Python's start-up plus two bring-up timeouts (nodes, then arming)
    assert time_span_s(value(u, "Service", "TimeoutStartSec")) >= 2 * leg.controller.bringup_timeout_s + 10.0
    # the daemon's own safe stop and the drivers' watchdog act long before systemd's watchdog
    assert leg.drivers.watchdog_timeout_s < leg.controller.heartbeat_timeout_s < time_span_s(value(u, "Service", "WatchdogSec"))


def test_unit_syntax_reader():
    text = "# c\n[A]\nK=1\nK=2\n; c\nL=a \\\n  b\nM=x\nM=\n[B]\nE=\"X=1 2\" Y=3\n"
    u = parse_unit(text)
    assert u["A"]["K"] == ["1", "2"] and value(u, "A", "K") == "2"
    assert u["A"]["L"] == ["a  b"] and u["A"]["M"] == []
    assert environment({"Service": {"Environment": ['"X=1 2" Y=3']}}) == {"X": "1 2", "Y": "3"}
    for bad in ("K=1\n", "[A]\nnot an assignment\n", "[A\n", "[A]\nK=1 \\\n"):
        with pytest.raises(ValueError):
            parse_unit(bad)
    assert command_line("+-/sbin/ip link set 'can 0' up") == ("+-", ["/sbin/ip", "link", "set", "can 0", "up"])


@pytest.mark.parametrize("text,seconds", [("1", 1.0), ("1s", 1.0), ("500ms", 0.5), ("2min", 120.0),
                                          ("1min 30s", 90.0), ("1h", 3600.0), ("250 ms", 0.25), ("infinity", math.inf)])
def test_time_spans(text, seconds):
    assert time_span_s(text) == pytest.approx(seconds)


@pytest.mark.parametrize("bad", ["", "soon", "5 parsecs", "ms"])
def test_bad_time_spans(bad):
    with pytest.raises(ValueError):
        time_span_s(bad)


UNCONFIRMED = "# a leg\n[calibration]\nconfirmed = false\n"
CONFIRMED = "# a confirmed leg\n[calibration]  # by config confirm\nconfirmed = true  # yes\n"


def _dry_run(config: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(INSTALL), "--dry-run", "--config", str(config)], capture_output=True, text=True,
                          timeout=30)


def test_install_script_parses_and_prints_its_plan_without_running_anything(tmp_path):
    assert subprocess.run(["bash", "-n", str(INSTALL)]).returncode == 0
    config = tmp_path / "leg.toml"
    config.write_text(CONFIRMED)
    done = _dry_run(config)
    assert done.returncode == 0, done.stderr
    plan = done.stdout
    for step in ("python3 -m venv /opt/elegant-stepping/venv", "ln -sfn /opt/elegant-stepping/venv/bin/elegant-stepping-leg "
                 "/usr/local/bin/elegant-stepping-leg", "/etc/systemd/system/elegant-stepping-controller.service",
                 "/etc/elegant-stepping/leg.toml", "systemctl daemon-reload",
                 "+ systemctl enable elegant-stepping-controller.service"):
        assert step in plan, step
    assert not any(line.startswith("+ systemctl start") for line in plan.splitlines())  # a person starts it
    # sourcing it runs nothing
    sourced = subprocess.run(["bash", "-c", f"source {INSTALL} && echo sourced"], capture_output=True, text=True,
                             timeout=30)
    assert sourced.stdout.strip() == "sourced"


@pytest.mark.parametrize("text", [UNCONFIRMED, "# no calibration table at all\n",
                                  "[calibration]\nconfirmed = false\n[bus]\nconfirmed = true\n",
                                  "[calibrations]\nconfirmed = true\n", "[calibration]\n# confirmed = true\n"])
def test_install_script_does_not_enable_an_unconfirmed_leg_and_says_how_to_confirm_it(text, tmp_path):
    config = tmp_path / "leg.toml"
    config.write_text(text)
    done = _dry_run(config)
    assert done.returncode == 0, done.stderr
    plan = done.stdout
    assert "+ systemctl daemon-reload" in plan
    assert not any(line.startswith("+ systemctl enable") for line in plan.splitlines())
    assert "NOT enabling elegant-stepping-controller.service" in plan and "not confirmed" in plan
    for step in ("elegant-stepping-leg bringup --config /etc/elegant-stepping/leg.toml --json report.json",
                 "elegant-stepping-leg config confirm /etc/elegant-stepping/leg.toml --bringup report.json",
                 "systemctl enable --now elegant-stepping-controller.service"):
        assert step in plan, step


def test_install_script_reads_the_examples_as_their_configs_do():
    from controller.settings.file import load_config

    for name in ("odrive-leg", "sim"):
        path = REPO / "configs" / f"{name}.toml"
        enabled = "+ systemctl enable" in _dry_run(path).stdout
        assert enabled is load_config(path).calibration.confirmed, name
    no = subprocess.run(["bash", str(INSTALL), "--dry-run", "--no-enable", "--config", str(REPO / "configs/sim.toml")],
                        capture_output=True, text=True, timeout=30)
    assert no.returncode == 0 and "+ systemctl enable" not in no.stdout and "(--no-enable)" in no.stdout


def test_install_script_stages_the_files_under_a_root_and_keeps_an_existing_config(tmp_path):
    root, config = tmp_path / "root", tmp_path / "leg.toml"
    config.write_text("# a leg\n")  # not confirmed: installed, not enabled
    run = lambda: subprocess.run(["bash", str(INSTALL), "--root", str(root), "--config", str(config)],  # noqa: E731
                                 capture_output=True, text=True, timeout=30)
    done = run()
    assert done.returncode == 0, done.stdout + done.stderr
    installed = root / "etc/systemd/system/elegant-stepping-controller.service"
    assert installed.read_text() == UNIT.read_text()
    assert (root / "etc/elegant-stepping/leg.toml").read_text() == "# a leg\n"
    assert (root / "usr/local/share/doc/elegant-stepping/deploy.md").exists()
    assert (root / "usr/local/share/elegant-stepping/sim.toml").read_text() == (REPO / "configs/sim.toml").read_text()
    assert (root / "usr/local/bin/elegant-stepping-leg").is_symlink()
    assert "(skipped under --root) systemctl daemon-reload" in done.stdout
    assert "systemctl enable elegant-stepping" not in done.stdout and "NOT enabling" in done.stdout
    (root / "etc/elegant-stepping/leg.toml").write_text("# calibrated\n" + CONFIRMED)
    config.write_text("# a newer example\n")
    again = run()
    assert again.returncode == 0
    assert (root / "etc/elegant-stepping/leg.toml").read_text() == "# calibrated\n" + CONFIRMED  # never overwritten
    assert (root / "etc/elegant-stepping/leg.toml.new").read_text() == "# a newer example\n"
    # the configuration in force is the existing, confirmed one (the new example only lies beside it)
    assert "(skipped under --root) systemctl enable elegant-stepping-controller.service" in again.stdout


def test_the_dry_run_swaps_only_the_config_and_the_bus(tmp_path):
    dep = Deployment.from_unit(UNIT, "/x/sim.toml")
    _, argv = command_line(value(read_unit(UNIT), "Service", "ExecStart"))
    assert dep.exec_start == argv
    n = len(dep.argv) - len(argv)  # the program may become this environment's (one word, or python -m controller.cli)
    assert dep.argv[n + 1:] == [w if w != "/etc/elegant-stepping/leg.toml" else "/x/sim.toml" for w in argv[1:]]
    assert dep.env == environment(read_unit(UNIT))  # the unit's Environment=, as it is
    assert dep.watchdog_s == 1.0 and dep.start_timeout_s == 45.0 and dep.stop_timeout_s == 10.0
    assert any("leg.toml -> /x/sim.toml" in s for s in dep.swaps)
    assert swap_config(["controller", "--config=a"], "b") == (["controller", "--config=b"], "a")
    assert swap_config(["controller"], "b") == (["controller", "--config", "b"], None)
    bad = tmp_path / "bad.service"
    bad.write_text("[Service]\nType=simple\nExecStart=/bin/true\n")
    with pytest.raises(ValueError, match="Type=notify"):
        Deployment.from_unit(bad, "c")


def _dep() -> Deployment:
    return Deployment(unit_path="u", exec_start=["x"], argv=["x"], env={}, watchdog_s=1.0, start_timeout_s=30.0,
                      stop_timeout_s=10.0, swaps=[])


def _good_run(pid: int = 42, gap: float = 0.5):
    msgs = [NotifyMessage(0.1, pid, {"STATUS": "bring-up: waiting for the nodes' heartbeats"}),
            NotifyMessage(2.0, pid, {"READY": "1", "STATUS": "axes in closed loop: ramping to the start pose"}),
            NotifyMessage(3.0, pid, {"STATUS": "walking"})]
    t = 0.2
    while t < 12.0:
        msgs.append(NotifyMessage(t, pid, {"WATCHDOG": "1"}))
        t += gap
    msgs.append(NotifyMessage(12.01, pid, {"STOPPING": "1", "STATUS": "stopping (SIGTERM)"}))
    msgs.sort(key=lambda m: m.t_s)
    final = {"steps": 12, "phase": "walk", "sd_notify": {"errors": 0}, "stopped_by": "SIGTERM"}
    running = {"axes": {"hip": {"state": "CLOSED_LOOP_CONTROL"}, "knee": {"state": "CLOSED_LOOP_CONTROL"}}}
    bye = {"axes": {"hip": {"state": "IDLE"}, "knee": {"state": "IDLE"}}, "watchdog_trips": 0}
    return dict(messages=msgs, pid=pid, t_start=0.0, t_term=12.0, rc=0, final=final, status_running=running, bye=bye,
                dep=_dep())


def test_the_checklist_passes_a_good_run_and_names_each_failure():
    items = checklist(**_good_run())
    assert [i["check"] for i in items] == ["READY", "NotifyAccess=main", "WATCHDOG pings regular", "walked",
                                           "axes in closed loop while running", "STOPPING", "exit 0",
                                           "axes IDLE at the end", "sd_notify errors"]
    assert all(i["ok"] for i in items), items
    stalled = _good_run()
    stalled["messages"] = [m for m in stalled["messages"] if not (m.has("WATCHDOG") and 5.0 < m.t_s < 6.3)]
    assert [i["check"] for i in checklist(**stalled) if not i["ok"]] == ["WATCHDOG pings regular"]
    tripped = _good_run()
    tripped["bye"] = {**tripped["bye"], "watchdog_trips": 2}  # IDLE, but by the drivers' watchdogs
    assert [i["check"] for i in checklist(**tripped) if not i["ok"]] == ["axes IDLE at the end"]
    other = _good_run()
    other["messages"].append(NotifyMessage(4.0, 43, {"STATUS": "a child"}))
    assert [i["check"] for i in checklist(**other) if not i["ok"]] == ["NotifyAccess=main"]
    nothing = {**_good_run(), "messages": [], "rc": 1, "final": {}}
    assert {"READY", "STOPPING", "exit 0", "walked"} <= {i["check"] for i in checklist(**nothing) if not i["ok"]}
    report = {"where": "native", "exec_start": ["x"], "swaps": ["a"], "checks": items, "notes": ["n"], "error": None,
              "ok": True}
    assert "[ok] READY" in format_report(report) and format_report(report).endswith("all checks passed")


def _gap_run(gap_s: float):
    """A good run but for one ping gap of ``gap_s`` [s] (from t = 5.2 s), on the test's clock."""
    run = _good_run()
    pings = [m for m in run["messages"] if m.has("WATCHDOG")]
    late = [m for m in pings if m.t_s > 5.0]
    shift = gap_s - 0.5
    moved = {id(m): NotifyMessage(m.t_s + shift, m.pid, m.fields) for m in late}
    run["messages"] = sorted((moved.get(id(m), m) for m in run["messages"]), key=lambda m: m.t_s)
    run["t_term"] += shift
    return run


def test_a_ping_gap_is_judged_against_watchdogsec_plus_the_stall_measured_beside_the_daemon():
    """The pings exist only in real time: the limit is WatchdogSec plus the platform's longest
    stall measured beside the daemon in the same run (twice: the daemon's loop, the harness's
    listener) and one wake-up, never a fixed budget. Times here are the test's own."""
    from hil.profile import NATIVE, SCHEDULING_S

    def ping_check(run, stall_s):
        return next(i for i in checklist(**run, stall_s=stall_s, profile=NATIVE) if i["check"] == "WATCHDOG pings regular")

    steady = ping_check(_good_run(), 0.002)
    assert steady["ok"] and "limit 1.005 s" in steady["detail"] and "0.002 s" in steady["detail"]
    assert 1.0 + 2 * 0.002 + SCHEDULING_S == pytest.approx(1.005)
    late = _gap_run(1.2)
    assert not ping_check(late, 0.010)["ok"]  # a 1.2 s gap where the platform stalled 10 ms: the daemon's
    explained = ping_check(late, 0.15)  # the platform itself stalled 150 ms: the limit is 1.301 s
    assert explained["ok"] and "longest 1.200 s" in explained["detail"] and "limit 1.301 s" in explained["detail"]
    assert not ping_check(_gap_run(1.35), 0.15)["ok"]  # and no more
    # not measured: the platform's fixed fallback (20 ms natively) for each of the two
    fallback = ping_check(_gap_run(1.03), None)
    assert fallback["ok"] and "not measured" in fallback["detail"] and "limit 1.041 s" in fallback["detail"]
    assert not ping_check(_gap_run(1.05), None)["ok"]


def test_the_report_is_stamped_and_read_back(tmp_path):
    import json

    from controller.errors import InputError
    from hil.dryrun.run import REPORT_KIND, REPORT_VERSION, read_report
    from controller.errors import stamp

    path = tmp_path / "dryrun.json"
    path.write_text(json.dumps({**stamp(REPORT_KIND, REPORT_VERSION), "ok": True, "checks": []}))
    assert read_report(path)["ok"] is True and REPORT_KIND == "dryrun" and REPORT_VERSION == 1
    for bad, words in (({"format": "dryrun", "format_version": 99, "project_version": "9.9"}, "format version 99"),
                       ({"format": "bench", "format_version": 1}, "not a dryrun file"),
                       ({"ok": True}, "no 'format' stamp"),  # an unstamped report is never read: each run writes anew
                       ("{cut", "not JSON")):
        path.write_text(bad if isinstance(bad, str) else json.dumps(bad))
        with pytest.raises(InputError) as info:
            read_report(path)
        assert words in str(info.value) and str(path) in str(info.value) and "\n" not in str(info.value)


def test_the_final_record_is_read_from_the_daemons_output():
    log = 'WARNING x\n{"kind": "final", "stopped_by": "SIGTERM", "steps": 3}\n'
    assert final_record(log)["steps"] == 3 and final_record("nothing\n{broken") == {}


def test_the_deploy_doc_covers_what_the_issue_asks():
    doc = (REPO / "docs" / "deploy.md").read_text()
    for needle in ("120", "1 Mbit/s", "node_id", "heartbeat_msg_rate_ms", "encoder_msg_rate_ms", "watchdog_timeout",
                   "POSITION_CONTROL", "PASSTHROUGH", "elegant-stepping-leg bringup", "WatchdogSec", "install.sh",
                   "elegant-stepping dryrun", "zero_offset_rev", "direction", "## First power-on",
                   "elegant-stepping-leg bringup --config /etc/elegant-stepping/leg.toml --json report.json",
                   "elegant-stepping-leg config confirm /etc/elegant-stepping/leg.toml --bringup report.json",
                   "systemctl enable --now elegant-stepping-controller", "elegant-stepping-leg status",
                   "elegant-stepping-leg arm", "elegant-stepping-leg disarm", "elegant-stepping-leg estop",
                   "elegant-stepping-leg clear-faults", "RuntimeDirectory", "RestartPreventExitStatus"):
        assert needle in doc, needle


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed (Debian: systemd)")
def test_systemd_analyze_verify_accepts_the_unit(tmp_path):
    # verify also checks that the program exists: point a copy at this environment's command
    program = shutil.which("elegant-stepping") or shutil.which("python3")
    copy = tmp_path / UNIT.name
    copy.write_text(UNIT.read_text().replace("/usr/local/bin/elegant-stepping", program))
    done = subprocess.run(["systemd-analyze", "verify", "--man=no", str(copy)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and not done.stderr.strip(), done.stderr


def test_the_dry_run_config_waits_for_a_person(tmp_path, monkeypatch):
    import dataclasses

    from controller.settings.file import load_config
    from hil.dryrun.run import SIM_CONFIG, platform_config
    from hil.profile import UML

    monkeypatch.delenv("ELEGANT_STEPPING_IN_UML", raising=False)
    original = load_config(SIM_CONFIG)
    copy, swaps = platform_config(SIM_CONFIG, tmp_path, "vcan0")
    changed = load_config(copy)
    assert copy.parent.resolve() == tmp_path.resolve() and len(swaps) == 2
    assert original.controller.auto_arm and not changed.controller.auto_arm  # the dry run plays the person
    assert changed.service.control_socket == str(tmp_path / "control.sock")
    assert dataclasses.replace(changed.controller, auto_arm=True) == original.controller  # nothing else
    assert changed.bus == original.bus and changed.calibration == original.calibration
    with pytest.raises(ValueError, match="socketcan vcan0"):
        platform_config(REPO / "configs" / "odrive-leg.toml", tmp_path, "vcan0")  # the real leg's bus: refused
    monkeypatch.setenv("ELEGANT_STEPPING_IN_UML", "1")
    copy, swaps = platform_config(SIM_CONFIG, tmp_path, "vcan0")
    assert len(swaps) == 3 and "silence_periods 3.5 -> 10" in swaps[2]
    changed = load_config(copy)
    assert changed.controller.silence_periods == UML.min_silence_periods
    assert changed.bus == original.bus and changed.controller.axes == original.controller.axes
