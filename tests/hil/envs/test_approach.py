"""The approach environment (``ElegantStepping/Approach-v0``) and the stable-baselines3 baseline script.

The environment runs the whole stack (bus, drivers, plant in lockstep), so most of these are
slow tests of a few simulated approaches each (about 6 simulated seconds, a fraction of a second
of wall time, per approach). The baseline's training needs the ``rl`` extra (torch), which CI does
not install: only its summary and its one-line refusal are tested without it.
"""

from __future__ import annotations

import importlib.util
import json
import threading
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import hil.envs
from hil.envs.approach import NO_CELL, ApproachEnv
from hil.experiments import rl_baseline
from hil.experiments.learn import LearnConfig, LearningRun

NO_CHANGE = ApproachEnv().actions_s.index(0.0)


def workers() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("approach-env")]


def rollout(env: gymnasium.Env, seed: int, episodes: int, policy) -> tuple[list, list, list[bool]]:
    """Observations, rewards and successes of ``episodes`` episodes from ``reset(seed=seed)``."""
    observations, rewards, successes = [], [], []
    obs, _ = env.reset(seed=seed)
    for episode in range(episodes):
        if episode:
            obs, _ = env.reset()
        observations.append(obs.tolist())
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy())
            observations.append(obs.tolist())
            rewards.append(reward)
            done = terminated or truncated
        assert terminated and not truncated
        successes.append(info["success"])
    return observations, rewards, successes


def test_the_environment_is_registered_on_import_and_passes_the_checker():
    env = gymnasium.make("ElegantStepping/Approach-v0")
    try:
        assert hil.envs.APPROACH_ID == "ElegantStepping/Approach-v0" == env.spec.id
        raw = env.unwrapped
        assert isinstance(raw, ApproachEnv)
        # the Q-learner's six burst changes, and [cell, decision] with the encoder's 28 cells
        assert raw.action_space == gymnasium.spaces.Discrete(6)
        assert raw.observation_space.shape == (2,) and raw.observation_space.dtype == np.float32
        assert raw.observation_space.high.tolist() == [27.0, 32.0]
        check_env(raw)
    finally:
        env.close()
    assert not workers()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # gymnasium warns when an id is registered over
        importlib.reload(hil.envs)  # importing again registers nothing twice


@pytest.mark.slow
def test_three_random_episodes_run_through_the_whole_stack():
    env = gymnasium.make("ElegantStepping/Approach-v0")
    env.action_space.seed(0)
    try:
        _obs, rewards, successes = rollout(env, 11, 3, env.action_space.sample)
        raw: ApproachEnv = env.unwrapped
        assert [a.record["index"] for a in raw.approaches] == [0, 1, 2]
        for a in raw.approaches:
            r = a.record
            assert 3 <= a.decisions <= 5 and not a.truncated and not a.finished_by_reset
            # the reward is the reflexes heard and the ground truth of success, nothing else
            assert a.agent_return == pytest.approx(r["success"] - len(r["reflexes"]))
            assert r["sim_s"] > 3.0 and r["success"] == (not r["contacts"] and not r["stalled"])
        assert sum(rewards) == pytest.approx(sum(a.agent_return for a in raw.approaches))
        assert successes == [a.record["success"] for a in raw.approaches]
    finally:
        env.close()
    assert not workers()


@pytest.mark.slow
def test_a_seed_gives_the_same_observations_and_rewards():
    def run(seed: int) -> tuple[list, list, list[bool], str]:
        env = ApproachEnv()
        rng = np.random.default_rng(4)  # the same actions each time
        try:
            got = rollout(env, seed, 3, lambda: int(rng.integers(env.action_space.n)))
            return (*got, json.dumps([a.record for a in env.approaches]))
        finally:
            env.close()

    first, again, other = run(21), run(21), run(22)
    assert first == again
    assert first[0] != other[0]  # another seed: other start distances, other cells
    assert all(o[0] == NO_CELL for o, nxt in zip(first[0], first[0][1:]) if nxt[1] == 0.0)  # each episode ends on NO_CELL


@pytest.mark.slow
def test_with_no_burst_change_the_records_are_the_no_adaptation_method_s():
    """The same stack: the environment's trial records, bit for bit, are ``learn --method none``'s."""
    env = ApproachEnv()
    try:
        rollout(env, 7, 3, lambda: NO_CHANGE)
        records = [a.record for a in env.approaches]
    finally:
        env.close()
    run = LearningRun(LearnConfig(method="none", seed=7, trials=3))
    try:
        run.bring_up()
        expected = [run.trial(i) for i in range(3)]
    finally:
        run.close()
    assert json.dumps(records) == json.dumps(expected)


@pytest.mark.slow
def test_reset_mid_episode_walks_the_approach_to_its_end_and_close_leaves_no_thread():
    env = ApproachEnv(max_steps=1)
    obs, info = env.reset(seed=3)
    assert obs[0] != NO_CELL and obs[1] == 0 and info["approach"] == 0
    obs, _r, terminated, truncated, _info = env.step(NO_CHANGE)  # an approach asks for 3-4 decisions
    assert truncated and not terminated and obs[1] == 1
    with pytest.raises(RuntimeError, match="truncated: call reset"):
        env.step(NO_CHANGE)
    obs, info = env.reset()  # the truncated approach is walked to its end and kept
    assert env.approaches[0].truncated and env.approaches[0].finished_by_reset
    assert info["finished_record"]["index"] == 0 and info["approach"] == 1
    env.step(NO_CHANGE)
    env.reset(seed=3)  # a new seed mid-episode: the waiting approach is abandoned, the old run closed
    assert env.approaches == [] and len(workers()) == 1
    env.close()
    env.close()  # again: allowed
    assert not workers()
    with pytest.raises(RuntimeError, match="reset"):
        env.step(NO_CHANGE)


@pytest.mark.parametrize("kwargs, message", [
    ({"obstacle_height_m": -0.05}, r"must be in \[0.03, 0.5\] m.*\(obstacle_height_m -0.05 m\)"),
    ({"obstacle_height_m": 0.45}, r"obstacle height.*\(obstacle_height_m 0.45 m\)"),  # beyond what the leg clears
    ({"obstacle_height_m": "high"}, "obstacle_height_m must be a number"),
    ({"max_steps": 0}, "max_steps must be a whole number"),
    ({"max_steps": 2.5}, "max_steps must be a whole number"),
    ({"seed": -1}, "seed must be a whole number"),
    ({"actions_s": ()}, "actions_s"),
    ({"actions_s": (0.0, 2.0)}, "actions_s"),
    ({"stm_tau_s": 0.0}, "stm_tau_s"),
    ({"config_overrides": {"seed": 4}}, "'seed' is set by the environment itself"),
    ({"config_overrides": {"rail_speed": 0.5}}, "'rail_speed' is not a LearnConfig field; choose from"),
    ({"config_overrides": {"range_noise_m": -1.0}}, r"range_noise_m.*config_overrides \{'range_noise_m': -1.0\}"),
    ({"render_mode": "human"}, "render_mode must be None"),
])
@pytest.mark.filterwarnings("ignore:.*render_mode")  # gymnasium's own warning before ours
def test_a_bad_argument_is_a_clear_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gymnasium.make("ElegantStepping/Approach-v0", **kwargs)
    assert not workers()  # refused before any run starts


def test_a_bad_seed_or_action_is_a_clear_value_error():
    env = ApproachEnv()
    try:
        with pytest.raises(ValueError, match="reset seed must be a whole number"):
            env.reset(seed=-3)
        with pytest.raises(ValueError, match="no reset options"):
            env.reset(options={"height": 1})
        env.reset(seed=0)
        with pytest.raises(ValueError, match=r"action must be an integer in \[0, 6\)"):
            env.step(6)
    finally:
        env.close()


# ---- the stable-baselines3 baseline ---------------------------------------------------------------------------------

def test_the_baseline_summary_uses_the_project_s_criterion():
    rows = [{"success": i >= 30 or i % 2 == 0, "reflexes": [] if i >= 30 else [{}], "decisions": 4,
             "truncated": False, "sim_s": 6.0} for i in range(160)]
    rows[120]["success"] = rows[140]["success"] = False
    config = rl_baseline.BaselineConfig(algo="dqn", seed=1000, approaches=160)
    s = rl_baseline.summarize(rows, config, wall_s=32.0, versions={"torch": "x"})
    # approaches 29-38 (1-based) are the first 10 with 9 successes (only 30 failed): 28 ran before them
    assert s["approaches_to_criterion"] == 28
    assert (s["mistakes_after_100"], s["mistakes_101_150"]) == (2, 2)
    assert s["wall_s_per_approach"] == pytest.approx(0.2) and s["decisions"] == 640
    assert s["config"]["settings"]["explore_decisions"] == rl_baseline.DQN_SETTINGS.explore_decisions
    with pytest.raises(ValueError, match="approaches must be in \\[1, 2000\\]"):
        rl_baseline.BaselineConfig(algo="ppo", approaches=2001)


def test_the_baseline_without_the_rl_extra_says_so_in_one_line(monkeypatch, capsys, tmp_path):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("torch", "stable_baselines3") else real(name, *a))
    code = rl_baseline.main(["--algo", "ppo", "--seed", "1000", "--approaches", "5", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 6 and err.count("\n") == 1 and "Traceback" not in err
    assert "needs torch, stable_baselines3" in err and "pip install 'elegant-stepping[rl]'" in err
    assert not (tmp_path / "o").exists()


NO_SB3 = importlib.util.find_spec("stable_baselines3") is None


@pytest.mark.slow
@pytest.mark.skipif(NO_SB3, reason="SKIPPED LOUDLY: stable-baselines3 is not installed (the 'rl' extra, "
                                   "torch, is not installed by CI): the baseline's training is not tested here")
@pytest.mark.parametrize("algo", rl_baseline.ALGOS)
def test_the_baseline_trains_and_writes_its_records(algo, tmp_path, capsys):
    out = tmp_path / algo
    assert rl_baseline.main(["--algo", algo, "--seed", "1000", "--approaches", "4", "--out", str(out)]) == 0
    rows = [json.loads(line) for line in (out / "approaches.jsonl").read_text().splitlines()]
    assert [r["approach"] for r in rows] == [1, 2, 3, 4] and [r["index"] for r in rows] == [0, 1, 2, 3]
    assert all({"success", "contacts", "reflexes", "decisions", "return"} <= set(r) for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["approaches"] == 4 and summary["versions"]["torch"]
    assert summary["success_rate"] == sum(r["success"] for r in rows) / 4
    assert json.loads(capsys.readouterr().out)["approaches"] == 4
    assert rl_baseline.main(["--algo", algo, "--approaches", "4", "--out", str(out)]) == 3  # not over a run
    assert not workers()
