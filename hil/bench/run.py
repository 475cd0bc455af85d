"""``elegant-stepping bench``: performance figures, each beside its reference, taken in one run.

Figures (keys of the JSON):
  lockstep_rtf        real-time factor of the whole stack in lockstep (500 Hz control, 1 kHz physics),
                      walking with no obstacle
  stack_us_per_step   process CPU per physics step of a learning run through the whole stack
                      (:mod:`hil.bench.physics_floor`: bring-up, walking, trials to ``seconds``)
  floor_us_per_step   the physics floor of that run: its recorded joint torques and obstacle events
                      replayed into a fresh PyBullet world alone (torques, ``stepSimulation``, joint
                      states), checked to reproduce the run's joint states bit for bit
  floor_queries_us_per_step
                      the floor plus the PyBullet queries the stack made, at the steps it made them
                      (rail, contacts, range ray and profile beams, the experiment's ground truth)
  stack_vs_floor      median over the interleaved rounds of stack / floor (each round: the stack,
  stack_vs_floor_queries  then both replays); ``detail.physics_floor.pairs`` has every round
  tick_cost_us        median and p99 of one controller tick (drain, supervise, CPG, IK, send)
  codec_us            encode and decode of one frame (compiled struct codec), beside cantools's
  bus_load            fraction of a 1 Mbit/s bus used at the default rates while walking, from
                      bit-exact lengths (stuffing included) of every frame seen on the bus
  learning            learning trials per minute through the whole stack
  hil                 with ``--hil`` (:mod:`hil.bench.socketcan`): on a real SocketCAN vcan0 (in User-Mode
                      Linux where needed), the controller daemon and the simulated leg as two
                      processes: control-period jitter p99 (and median, max), late ticks per
                      10,000, command-to-feedback latency median and p99, each beside the same
                      figure for a bare loop / bare echo doing no work in the same session (the
                      platform's floor), with ratios; where it ran and the UML boot time. Without
                      ``--hil``: only whether it could run.
No figure here is asserted in a test: these machines are shared and noisy; compare ratios. No figure
compares the stack with a different motion (the bare collapsed leg of the former ``bare_physics_rtf``
cost more a step than walking, and is gone): the floor is the same motion's physics.

The JSON carries the stamp ``format: "bench"``, ``format_version`` :data:`BENCH_VERSION` and
``project_version`` first (:func:`controller.errors.stamp`).
"""

from __future__ import annotations

import platform
import statistics
import time
from typing import Any


from controller.errors import stamp
from controller.supervisor import Phase
from hil.bench.physics_floor import DEFAULT_PAIRS, measure
from hil.lockstep.harness import Lockstep, LockstepConfig
from protocol import BusContract, frame_bits

BENCH_KIND = "bench"
BENCH_VERSION = 1  # the bench JSON's format version: raise it when a reader of the old one could misread it


def _quantiles_us(samples_s: list[float]) -> dict[str, float]:
    ordered = sorted(samples_s)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    return {"median": statistics.median(ordered) * 1e6, "p99": p99 * 1e6, "n": len(ordered)}


def bench_lockstep(seconds: float, seed: int = 0) -> dict[str, Any]:
    tick_s: list[float] = []
    with Lockstep(LockstepConfig(seed=seed)) as ls:
        loop = ls.loop
        n = int(seconds * ls.config.rig.physics_hz)
        # Lockstep.step, with the tick timed (the loop's methods are not patched: compiled, they cannot be)
        leg, tick, every, clock = ls.leg, loop.tick, ls.ticks_per_control, time.perf_counter
        t0 = clock()
        for k in range(1, n + 1):
            leg.step()
            if k % every == 0:
                t1 = clock()
                tick(leg.t_s)
                tick_s.append(clock() - t1)
        wall = clock() - t0
        walked = loop.phase is Phase.WALK
        sim_s = ls.t_s
    return {"rtf": sim_s / wall, "sim_s": sim_s, "wall_s": wall, "walking": walked, "tick_cost_us": _quantiles_us(tick_s)}


def bench_physics_floor(seconds: float, seed: int = 0, pairs: int = DEFAULT_PAIRS) -> dict[str, Any]:
    """The stack beside the physics floor of the same run (:func:`hil.bench.physics_floor.measure`)."""
    return measure(seconds, seed, pairs)


def bench_codec(n: int = 20000) -> dict[str, float]:
    contract = BusContract.load()
    pos = contract.codec("Set_Input_Pos")
    enc = contract.codec("Get_Encoder_Estimates")
    data = enc.pack(1.25, -0.5)

    def per_call_us(fn, count: int) -> float:
        t0 = time.perf_counter()
        for _ in range(count):
            fn()
        return (time.perf_counter() - t0) / count * 1e6

    signals = {"Input_Pos": 1.25, "Vel_FF": 0.5, "Torque_FF": 0.0}
    return {
        "encode": per_call_us(lambda: pos.pack(1.25, 0.5, 0.0), n),
        "decode": per_call_us(lambda: enc.unpack(data), n),
        "cantools_encode": per_call_us(lambda: pos.message.encode(signals), n // 10),
        "cantools_decode": per_call_us(lambda: enc.message.decode(data), n // 10),
    }


def bench_bus_load(seconds: float, seed: int = 0, bitrate: int = 1_000_000) -> dict[str, Any]:
    """Walk with a listener on the bus; load over the walking window from bit-exact frame lengths."""
    with Lockstep(LockstepConfig(seed=seed)) as ls:
        tap = ls.observer()
        try:
            # bring the leg up without recording, then record a steady walking window
            while ls.loop.phase is not Phase.WALK and ls.t_s < 10.0:
                ls.step()
            while tap.recv(timeout=0.0) is not None:
                pass
            t_start = ls.t_s
            bits = frames = 0
            by_id: dict[str, int] = {}
            for _ in range(int(seconds * ls.config.rig.physics_hz)):
                ls.step()
                while (msg := tap.recv(timeout=0.0)) is not None:
                    data = bytes(msg.dlc) if msg.is_remote_frame else bytes(msg.data)
                    bits += frame_bits(msg.arbitration_id, data, extended=msg.is_extended_id, remote=msg.is_remote_frame)
                    frames += 1
                    route = BusContract.load().route(msg.arbitration_id)
                    name = route.codec.name if route else hex(msg.arbitration_id)
                    by_id[name] = by_id.get(name, 0) + 1
            window = ls.t_s - t_start
        finally:
            tap.shutdown()
    return {
        "fraction": bits / window / bitrate,
        "bitrate": bitrate,
        "frames_per_s": frames / window,
        "bits_per_frame": bits / max(frames, 1),
        "frames_per_s_by_message": {k: v / window for k, v in sorted(by_id.items())},
        "window_s": window,
    }


def bench_learning(trials: int, seed: int = 0) -> dict[str, Any]:
    """Learning trials through the whole stack: trials per minute of wall time."""
    from hil.experiments.learn import LearnConfig, run_learning

    s = run_learning(LearnConfig(trials=trials, seed=seed))["summary"]
    return {"trials_per_minute": s["trials_per_minute"], "trials": trials, "wall_s": s["wall_s"], "sim_s": s["sim_s"],
            "projected_150_trials_s": 150 / s["trials_per_minute"] * 60.0}


def run_bench(seconds: float = 10.0, seed: int = 0, learn_trials: int = 10,
              hil_seconds: float | None = None, floor_pairs: int = DEFAULT_PAIRS) -> dict[str, Any]:
    """All figures; ``hil_seconds``: also the HIL figures (that many seconds of walking);
    ``floor_pairs``: interleaved rounds of the stack against its physics floor (at least 3)."""
    from hil.bench.socketcan import hil_availability, run_hil_bench
    from protocol.compiled import compiled_modules

    floor = bench_physics_floor(seconds, seed, floor_pairs)
    lock = bench_lockstep(seconds, seed)
    # last, so the HIL session does not share the machine with the runs above
    hil = (lambda: hil_availability()) if hil_seconds is None else (lambda: run_hil_bench(hil_seconds, seed))
    return {
        **stamp(BENCH_KIND, BENCH_VERSION),
        "lockstep_rtf": lock["rtf"],
        **{k: v for k, v in floor.items() if k != "detail"},
        "tick_cost_us": lock["tick_cost_us"],
        "codec_us": bench_codec(),
        "bus_load": bench_bus_load(min(seconds, 5.0), seed),
        "learning": bench_learning(learn_trials, seed),
        "hil": hil(),
        "detail": {"lockstep": {k: v for k, v in lock.items() if k != "tick_cost_us"}, "physics_floor": floor["detail"]},
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "cpus": _cpus()},
        # which hot modules ran compiled (mypyc, protocol.compiled): the figures depend on it
        "compiled": compiled_modules(),
    }


def _cpus() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
