"""A real SocketCAN bus where the kernel has none: User-Mode Linux, and native vcan detection.

Desktop Linux and most CI runners have vcan (``modprobe vcan``); then vcan0 is used natively.
Kernels built without CAN (``socket.AF_CAN`` fails, ``ip link add ... type vcan`` says "Unknown
device type") run the session inside User-Mode Linux instead: ``linux.uml`` is a Linux kernel
that runs as ordinary processes and has SocketCAN. ``hil/uml/run-in-uml.sh`` boots it with the
host's ``/`` as its root, loads the CAN modules, brings vcan0 up, runs a command in the current
directory and environment, and carries its exit status out through a file. Install step (Debian,
Ubuntu)::

    apt-get install -y user-mode-linux kmod

``python -m hil.uml.runner check`` says where vcan is available; ``python -m hil.uml.runner smoke`` sends and
receives frames over vcan0 with python-can (run it inside UML with ``python -m hil.uml.runner run --
python3 -m hil.uml.runner smoke``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

RUNNER = Path(__file__).resolve().parent / "run-in-uml.sh"
INSTALL = "apt-get install -y user-mode-linux kmod"
NATIVE_SETUP = "sudo modprobe vcan && sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0"
ENV_IN_UML = "ELEGANT_STEPPING_IN_UML"


class VcanUnavailable(RuntimeError):
    """Neither a native vcan nor User-Mode Linux is available; the message says what to do."""


def instruction(channel: str = "vcan0", uml_considered: bool = True) -> str:
    why = "and no User-Mode Linux to make one" if uml_considered else "(native run requested)"
    return (f"no SocketCAN interface {channel!r} here {why}. Either give this "
            f"kernel vcan ({NATIVE_SETUP.replace('vcan0', channel)}) or install User-Mode Linux "
            f"({INSTALL}); to skip the vcan tests on purpose, deselect them with -m 'not vcan'.")


def in_uml() -> bool:
    """True inside a VM started by our runner."""
    return os.environ.get(ENV_IN_UML) == "1"


def kernel_has_can() -> bool:
    if not hasattr(socket, "AF_CAN"):
        return False
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError:
        return False
    s.close()
    return True


def _link_up(channel: str) -> bool:
    try:
        socket.if_nametoindex(channel)
    except OSError:
        return False
    try:
        flags = int(Path(f"/sys/class/net/{channel}/flags").read_text(), 16)
    except (OSError, ValueError):
        return True  # exists; assume usable
    return bool(flags & 0x1)


def native_vcan(channel: str = "vcan0", create: bool = True) -> bool:
    """True if ``channel`` is a usable SocketCAN interface here; with ``create``, try to make a vcan
    of that name (works as root on a kernel with the vcan module)."""
    if not kernel_has_can():
        return False
    if _link_up(channel):
        return True
    if not create or not channel.startswith("vcan") or shutil.which("ip") is None:
        return False
    if os.geteuid() == 0 and shutil.which("modprobe"):
        subprocess.run(["modprobe", "vcan"], capture_output=True, timeout=20)
    for cmd in (["ip", "link", "add", "dev", channel, "type", "vcan"], ["ip", "link", "set", "up", channel]):
        if subprocess.run(cmd, capture_output=True, timeout=20).returncode != 0 and cmd[2] == "set":
            return False
    return _link_up(channel)


def uml_missing() -> str | None:
    """None if User-Mode Linux can be used here, else what is missing."""
    if shutil.which("linux.uml") is None:
        return f"linux.uml not found (install: {INSTALL})"
    if not any(shutil.which(x) or Path(f"/usr/sbin/{x}").exists() for x in ("insmod",)):
        return f"insmod not found (install: {INSTALL})"
    mods = Path("/usr/lib/uml/modules")
    if not any(mods.glob("*/kernel/drivers/net/can/vcan.ko*")):
        return f"no vcan module under {mods} (install: {INSTALL})"
    if not RUNNER.exists():
        return f"runner {RUNNER} missing"
    return None


def where(mode: str = "auto", channel: str = "vcan0") -> str:
    """Where a vcan session runs: "native" or "uml". ``mode`` is "auto", "native" or "uml".

    Raises :class:`VcanUnavailable` with an instruction when the requested place cannot work.
    """
    if mode not in ("auto", "native", "uml"):
        raise ValueError(f"mode must be auto, native or uml, got {mode!r}")
    if in_uml() or mode == "native":
        if native_vcan(channel):
            return "native"
        raise VcanUnavailable(instruction(channel, uml_considered=False))
    if mode == "auto" and native_vcan(channel):
        return "native"
    missing = uml_missing()
    if missing is not None:
        raise VcanUnavailable(f"{instruction(channel)} [{missing}]")
    return "uml"


def run_in_uml(argv: Sequence[str], *, timeout_s: float = 900.0, mem: str = "1536M", cpu: int = 0,
               cwd: str | Path | None = None, env: dict[str, str] | None = None,
               capture: bool = False) -> subprocess.CompletedProcess:
    """Run ``argv`` inside User-Mode Linux with vcan0 up; the result carries its exit status
    (124: the time limit was reached; 125: the VM died without reporting one)."""
    missing = uml_missing()
    if missing is not None:
        raise VcanUnavailable(f"cannot start User-Mode Linux: {missing}")
    cmd = ["bash", str(RUNNER), "--timeout", str(int(timeout_s)), "--mem", mem, "--cpu", str(cpu), "--", *argv]
    full_env = dict(os.environ if env is None else env)
    full_env.setdefault("HOME", "/root")
    full_env.setdefault("PYTHONUNBUFFERED", "1")
    return subprocess.run(cmd, cwd=cwd, env=full_env, timeout=timeout_s + 60, stdin=subprocess.DEVNULL,
                          capture_output=capture, text=True if capture else None)


def smoke(channel: str = "vcan0", frames: int = 200) -> dict:
    """Send ``frames`` frames from one python-can socketcan bus to another, echo them back, and
    check they all arrive intact; returns counts and round-trip times."""
    import can

    a = can.Bus(interface="socketcan", channel=channel)
    b = can.Bus(interface="socketcan", channel=channel)
    rtt = []
    lost = 0
    try:
        for i in range(frames):
            data = bytes([(i + k) & 0xFF for k in range(8)])
            t0 = time.perf_counter()
            a.send(can.Message(arbitration_id=0x123, data=data, is_extended_id=False))
            got = b.recv(timeout=1.0)
            if got is None or got.arbitration_id != 0x123 or bytes(got.data) != data:
                lost += 1
                continue
            b.send(can.Message(arbitration_id=0x124, data=data[::-1], is_extended_id=False))
            back = a.recv(timeout=1.0)
            if back is None or back.arbitration_id != 0x124 or bytes(back.data) != data[::-1]:
                lost += 1
                continue
            rtt.append((time.perf_counter() - t0) * 1e6)
    finally:
        a.shutdown()
        b.shutdown()
    rtt.sort()
    return {
        "channel": channel,
        "frames": frames,
        "round_trips": len(rtt),
        "lost": lost,
        "rtt_us_median": rtt[len(rtt) // 2] if rtt else None,
        "rtt_us_p99": rtt[min(len(rtt) - 1, int(0.99 * len(rtt)))] if rtt else None,
        "in_uml": in_uml(),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hil.uml.runner", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    chk = sub.add_parser("check", help="say where a vcan session would run")
    chk.add_argument("--channel", default="vcan0")
    sm = sub.add_parser("smoke", help="python-can socketcan send/receive on vcan")
    sm.add_argument("--channel", default="vcan0")
    sm.add_argument("--frames", type=int, default=200)
    run = sub.add_parser("run", help="run a command inside User-Mode Linux with vcan0 up")
    run.add_argument("--timeout", type=float, default=900.0)
    run.add_argument("--mem", default="1536M")
    run.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    if args.cmd == "check":
        try:
            print(where("auto", args.channel))
        except VcanUnavailable as exc:
            print(f"unavailable: {exc}", file=sys.stderr)
            return 1
        return 0
    if args.cmd == "smoke":
        result = smoke(args.channel, args.frames)
        print(json.dumps(result))
        return 0 if result["lost"] == 0 and result["round_trips"] == args.frames else 1
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("run: give a command")
    return run_in_uml(command, timeout_s=args.timeout, mem=args.mem).returncode


if __name__ == "__main__":
    sys.exit(main())
