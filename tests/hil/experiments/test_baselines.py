"""The sweep's baselines: the oracle planner and the Q-learning premotor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.config import ControllerConfig
from controller.stepping.rl import QLearnerConfig, QLearningPremotor
from hil.experiments.oracle import OracleConfig, OraclePremotor

CTL = ControllerConfig()


def oracle(distance: list[float | None]) -> OraclePremotor:
    return OraclePremotor(CTL, lambda: distance[0])


@pytest.mark.parametrize("start_m", [0.9, 1.23, 1.6, 2.2, 2.57, 2.9])
def test_oracle_plan_lands_the_last_footfall_on_the_takeoff(start_m):
    """Following its own plan step by step, the foot ends at the planned take-off."""
    o = oracle([None])
    d = start_m
    for _ in range(20):
        burst = o.plan(d)
        assert CTL.cpg.burst_min_s - 1e-9 <= burst <= CTL.cpg.burst_max_s + 1e-9
        if not o.plans or o.plans[-1][0] != d:
            break  # the take-off step: no plan made
        d -= o.stride_m(burst)
    assert d == pytest.approx(-OracleConfig().takeoff_m, abs=1e-6)


def test_oracle_reads_the_truth_at_each_gate_and_never_learns():
    dist = [1.5]
    o = oracle(dist)
    o.on_step_onset(0.0, None)
    first = o.burst_s(0.1)
    assert first != CTL.cpg.burst_s and o.gated_weight() == pytest.approx(first - CTL.cpg.burst_s)
    o.on_reflex("extension", 0.2)
    assert o.burst_s(0.3) == first
    dist[0] = None
    o.on_step_onset(1.0, 3)
    assert o.burst_s(1.1) == CTL.cpg.burst_s


def approach(agent: QLearningPremotor, cells: list[int], fail: bool, t0: float = 0.0) -> float:
    t = t0
    for c in cells:
        agent.on_step_onset(t, c)
        t += 0.7
    if fail:
        agent.on_reflex("placement", t - 0.3)
    agent.on_step_onset(t, None)
    agent.on_step_onset(t + 0.7, None)
    return t + 1.4


def test_q_learning_terminal_reward_sign():
    cfg = QLearnerConfig(epsilon=0.0)
    ok, bad = QLearningPremotor(10, 0.3, cfg), QLearningPremotor(10, 0.3, cfg)
    approach(ok, [7, 4, 1], fail=False)
    approach(bad, [7, 4, 1], fail=True)
    a0 = int(np.argmin(np.abs(ok.actions)))  # greedy on zeros: no change
    assert ok.q[1, a0] == pytest.approx(cfg.alpha * 1.0) and bad.q[1, a0] == pytest.approx(-cfg.alpha)
    assert ok.returns == [1.0] and bad.returns == [-1.0] and ok.episodes == bad.episodes == 1
    # one-step backups: the earlier states see the value only on a later episode
    assert ok.q[4, a0] == 0.0
    approach(ok, [7, 4, 1], fail=False, t0=10.0)
    # the second approach backs the terminal value up one gate: Q(4) += alpha * gamma * Q(1)
    assert ok.q[4, a0] == pytest.approx(cfg.alpha * cfg.gamma * cfg.alpha)
    assert ok.q[7, a0] == 0.0


def test_q_learning_a_late_reflex_counts_until_the_second_empty_gate():
    agent = QLearningPremotor(10, 0.3, QLearnerConfig(epsilon=0.0))
    agent.on_step_onset(0.0, 3)
    agent.on_step_onset(0.7, None)
    agent.on_reflex("extension", 0.9)  # the trailing stance touches the far edge
    agent.on_step_onset(1.4, None)
    assert agent.returns == [-1.0]


def test_q_learning_action_decays_through_memory_and_is_seeded():
    cfg = QLearnerConfig(epsilon=1.0, seed=5)
    a, b = QLearningPremotor(10, 0.3, cfg), QLearningPremotor(10, 0.3, cfg)
    picks_a, picks_b = [], []
    for i in range(30):
        a.on_step_onset(i, i % 10)
        b.on_step_onset(i, i % 10)
        picks_a.append(a.gated_weight())
        picks_b.append(b.gated_weight())
    assert picks_a == picks_b and len(set(picks_a)) > 2
    act = a.gated_weight()
    assert a.burst_s(29.0 + cfg.stm_tau_s) == pytest.approx(0.3 + act * math.exp(-1.0))


def test_q_learning_rejects_bad_config_and_reflex():
    with pytest.raises(ValueError, match="epsilon"):
        QLearnerConfig(epsilon=1.5)
    with pytest.raises(ValueError, match="actions_s"):
        QLearnerConfig(actions_s=())
    with pytest.raises(ValueError, match="reflex kind"):
        QLearningPremotor(3, 0.3).on_reflex("sneeze", 0.0)


def test_oracle_steps_over_through_the_whole_stack():
    from hil.experiments.learn import run_method

    m = run_method("oracle", seed=4, trials=3, obstacle_height_m=0.08)
    last = [t["footfalls_m"][-1] for t in m["trials"]]
    assert all(t["success"] for t in m["trials"]), last
    assert all(-0.2 < x < -0.08 for x in last), last
    assert all(t["gated_decisions"] >= 1 for t in m["trials"])  # it planned, it did not walk naturally


def test_rl_runs_through_the_whole_stack_and_closes_its_episodes():
    from hil.experiments.learn import LearnConfig, LearningRun

    run = LearningRun(LearnConfig(trials=2, seed=1, method="rl"))
    try:
        run.run()
        agent = run.premotor
        assert isinstance(agent, QLearningPremotor)
        assert agent.episodes == 2 and len(agent.returns) == 2
        assert [r == 1.0 for r in agent.returns] == [t["success"] for t in run.trials]
    finally:
        run.close()
