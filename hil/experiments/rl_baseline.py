"""A modern reinforcement-learning baseline: PPO or DQN (stable-baselines3) on the approach task.

Issue 19's question: how many approaches does a general-purpose deep RL agent need, against the
paper's reflex-trained learner and the tabular Q-learner (``learn --method rl``)? The agent learns
on :class:`hil.envs.approach.ApproachEnv` (``ElegantStepping/Approach-v0``): the same stack, the
same observation as the Q-learner's state (the gated cell, plus the decision index), the same six
burst changes, a reward of the same reflexes and the ground truth of success (docs/gym.md)::

    python -m hil.experiments.rl_baseline --algo ppo --seed 1000 --approaches 2000 --out runs/ppo-1000

It trains online, one approach after another, exactly as a learning run: there is no separate
evaluation, every approach counts (exploration included, as the learners' trials do), and
training stops after ``--approaches`` approaches. Into ``--out`` it writes:

- ``approaches.jsonl``: one JSON line per approach, as it finishes: ``approach`` (1-based), the
  agent's ``decisions``, ``return`` and ``truncated``, then the trial record exactly as a learning
  run writes it (``success``, ``contacts``, ``reflexes``, ``stalled``, ``gated_cells``, ...);
- ``summary.json`` (last: its presence marks a finished run): ``approaches_to_criterion`` (the
  project's definition, :func:`hil.analysis.stats.trials_to_criterion`: approaches run before the
  first 10-approach window with at least 9 successes; None if none), ``mistakes_after_100``
  (failed approaches from 101 on; None for a run of at most 100), ``mistakes_101_150`` (the
  learners' headline window, :func:`hil.analysis.metrics.mistakes_101_150`), the success rate,
  the wall time, the simulated time, the hyperparameters and the versions (torch,
  stable-baselines3, gymnasium).

The hyperparameters (:data:`PPO_SETTINGS`, :data:`DQN_SETTINGS`) are stable-baselines3's defaults
scaled to episodes of three or four decisions (shorter rollouts, an earlier start, exploration
over the first few hundred decisions) and the Q-learner's discount 0.9; they are not tuned on the
report's seeds. The observation is rescaled to [-1, 1] (a network's input; the environment keeps
cell numbers). Torch runs on one thread: deterministic for a seed on one machine, and polite to
a shared one.

Seeds: any seed runs; the report uses 1000-1004 (beyond the tuning seeds 0-99). At most
:data:`MAX_APPROACHES` approaches. Needs the ``rl`` extra (torch, stable-baselines3; not
installed by CI): without it, one line says what to install (exit 6).

May import what :mod:`hil.experiments` may, :mod:`hil.envs`, and the ``rl`` extra inside :func:`train`.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

MAX_APPROACHES = 2000
"""The most approaches one run may ask for (issue 19)."""
APPROACHES_FILE = "approaches.jsonl"
SUMMARY_FILE = "summary.json"
SUMMARY_FORMAT = "rl-baseline-summary"
SUMMARY_VERSION = 1
RL_MODULES = ("torch", "stable_baselines3")
"""The ``rl`` extra's top-level modules (pyproject.toml); gymnasium comes with ``research``."""


@dataclass(frozen=True)
class PPOSettings:
    """stable-baselines3 PPO settings (its names): rollouts of ``n_steps`` decisions (about 35
    approaches), ``n_epochs`` passes in minibatches of ``batch_size``; ``gamma`` the Q-learner's
    0.9; a little entropy bonus (``ent_coef``) against an early collapse onto one burst change;
    two hidden layers of ``net_arch`` units."""

    learning_rate: float = 3e-4
    n_steps: int = 128
    batch_size: int = 64
    n_epochs: int = 10
    gamma: float = 0.9
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.01
    net_arch: tuple[int, ...] = (64, 64)


@dataclass(frozen=True)
class DQNSettings:
    """stable-baselines3 DQN settings (its names), but exploration: epsilon falls linearly from
    ``exploration_initial_eps`` to ``exploration_final_eps`` over the first ``explore_decisions``
    decisions (about 150 approaches), whatever the run's length (stable-baselines3 counts it as a
    fraction of ``total_timesteps``, which here is only an upper bound: training stops after the
    approaches); learning starts after ``learning_starts`` decisions."""

    learning_rate: float = 1e-3
    buffer_size: int = 50_000
    learning_starts: int = 100
    batch_size: int = 64
    gamma: float = 0.9
    train_freq: int = 1
    gradient_steps: int = 1
    target_update_interval: int = 250
    exploration_initial_eps: float = 0.5
    exploration_final_eps: float = 0.05
    explore_decisions: int = 500
    net_arch: tuple[int, ...] = (64, 64)


PPO_SETTINGS = PPOSettings()
DQN_SETTINGS = DQNSettings()
ALGOS = ("ppo", "dqn")


@dataclass(frozen=True)
class BaselineConfig:
    """One baseline run.

    Attributes:
        algo: ``"ppo"`` or ``"dqn"``.
        seed: the run's seed (the environment's run, the network's initialisation, the sampling);
            default 1000.
        approaches: approaches to run, 1-:data:`MAX_APPROACHES`; default 2000.
        obstacle_height_m: the obstacle's height [m]; default 0.08.
        max_steps: the environment's decisions per approach before truncation; default 32.
    """

    algo: str
    seed: int = 1000
    approaches: int = MAX_APPROACHES
    obstacle_height_m: float = 0.08
    max_steps: int = 32
    settings: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"algo must be one of {', '.join(ALGOS)}, got {self.algo!r}")
        if not 0 <= self.seed < 2**32:
            raise ValueError(f"seed must be in [0, 2**32), got {self.seed}")
        if not 1 <= self.approaches <= MAX_APPROACHES:
            raise ValueError(f"approaches must be in [1, {MAX_APPROACHES}], got {self.approaches}")
        if not self.settings:
            object.__setattr__(self, "settings", asdict(PPO_SETTINGS if self.algo == "ppo" else DQN_SETTINGS))


def missing_rl_modules() -> list[str]:
    """The ``rl`` extra's modules (and gymnasium) that cannot be imported here."""
    return [m for m in (*RL_MODULES, "gymnasium") if importlib.util.find_spec(m) is None]


def summarize(rows: list[dict[str, Any]], config: BaselineConfig, wall_s: float, versions: dict[str, str]
              ) -> dict[str, Any]:
    """The run's summary from its approach rows (see the module docstring)."""
    from controller.errors import stamp
    from hil.analysis.metrics import mistakes_101_150
    from hil.analysis.stats import trials_to_criterion

    success = [bool(r["success"]) for r in rows]
    n = len(rows)
    return {
        **stamp(SUMMARY_FORMAT, SUMMARY_VERSION),
        "config": asdict(config),
        "approaches": n,
        "approaches_to_criterion": trials_to_criterion(success),
        "criterion": "approaches before the first 10-approach window with at least 9 successes",
        "mistakes_after_100": sum(not s for s in success[100:]) if n > 100 else None,
        "mistakes_101_150": mistakes_101_150(rows),
        "success_rate": sum(success) / n if n else None,
        "reflexes": sum(len(r["reflexes"]) for r in rows),
        "decisions": sum(r["decisions"] for r in rows),
        "truncated": sum(bool(r["truncated"]) for r in rows),
        "wall_s": wall_s,
        "wall_s_per_approach": wall_s / n if n else None,
        "sim_s": sum(r["sim_s"] for r in rows),
        "versions": versions,
    }


def _build(config: BaselineConfig, env: Any) -> Any:
    """The stable-baselines3 model of ``config`` on ``env``."""
    from stable_baselines3 import DQN, PPO

    s = dict(config.settings)
    policy_kwargs = {"net_arch": list(s.pop("net_arch"))}
    if config.algo == "ppo":
        return PPO("MlpPolicy", env, seed=config.seed, device="cpu", policy_kwargs=policy_kwargs, verbose=0, **s)
    explore = s.pop("explore_decisions")
    total = _total_timesteps(config)
    return DQN("MlpPolicy", env, seed=config.seed, device="cpu", policy_kwargs=policy_kwargs, verbose=0,
               exploration_fraction=min(1.0, explore / total), **s)


def _total_timesteps(config: BaselineConfig) -> int:
    """An upper bound of the run's decisions: training stops at the approaches, never here."""
    return config.approaches * (config.max_steps + 1)


def train(config: BaselineConfig, out_dir: str | Path, overwrite: bool = False) -> dict[str, Any]:
    """Run ``config`` into ``out_dir`` (see the module docstring); return the summary.

    Raises:
        FileExistsError: ``out_dir`` already holds a run's files and not ``overwrite``.
    """
    import gymnasium
    import numpy as np
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from controller.atomic import write_json_atomic
    import hil.envs  # registers the environment
    from hil.envs.approach import ApproachEnv

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name in (APPROACHES_FILE, SUMMARY_FILE):
        if (out / name).exists() and not overwrite:
            raise FileExistsError(f"--out {out}: already holds {name}; give a new folder, or --overwrite")
    (out / SUMMARY_FILE).unlink(missing_ok=True)
    torch.set_num_threads(1)
    versions = {"torch": torch.__version__, "stable_baselines3": stable_baselines3.__version__,
                "gymnasium": gymnasium.__version__, "numpy": np.__version__, "python": platform.python_version()}
    env = gymnasium.make(hil.envs.APPROACH_ID, obstacle_height_m=config.obstacle_height_m, seed=config.seed,
                         max_steps=config.max_steps)
    raw: ApproachEnv = env.unwrapped
    space = env.observation_space
    env = gymnasium.wrappers.RescaleObservation(env, np.float32(-1.0), np.float32(1.0))
    assert space.shape == env.observation_space.shape
    rows: list[dict[str, Any]] = []

    class Recorder(BaseCallback):
        """Writes each finished approach as it finishes; stops training after the last."""

        def __init__(self, sink) -> None:
            super().__init__()
            self.sink = sink

        def _on_step(self) -> bool:
            while len(rows) < min(len(raw.approaches), config.approaches):
                a = raw.approaches[len(rows)]
                row = {"approach": len(rows) + 1, "decisions": a.decisions, "return": a.agent_return,
                       "truncated": a.truncated, **a.record}
                rows.append(row)
                self.sink.write(json.dumps(row) + "\n")
                self.sink.flush()
                if len(rows) % 100 == 0:
                    recent = rows[-100:]
                    log.info("%s seed %d: %d approaches, %.0f%% of the last 100 succeeded", config.algo,
                             config.seed, len(rows), 100.0 * sum(r["success"] for r in recent) / len(recent))
            return len(rows) < config.approaches

    wall0 = time.perf_counter()
    try:
        with open(out / APPROACHES_FILE, "w") as sink:
            model = _build(config, env)
            model.learn(total_timesteps=_total_timesteps(config), callback=Recorder(sink))
    finally:
        env.close()
    wall_s = time.perf_counter() - wall0
    if len(rows) < config.approaches:
        raise RuntimeError(f"training stopped after {len(rows)} of {config.approaches} approaches")
    summary = summarize(rows, config, wall_s, versions)
    write_json_atomic(out / SUMMARY_FILE, summary, indent=1)
    return summary


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.experiments.rl_baseline", description=__doc__.split("\n")[0])
    p.add_argument("--algo", choices=ALGOS, required=True, help="the stable-baselines3 algorithm")
    p.add_argument("--seed", type=int, default=1000, help="the run's seed (the report uses 1000-1004)")
    p.add_argument("--approaches", type=int, default=MAX_APPROACHES,
                   help=f"approaches to run, 1-{MAX_APPROACHES} (default {MAX_APPROACHES})")
    p.add_argument("--obstacle-height-m", type=float, default=0.08, help="obstacle height [m] (default 0.08)")
    p.add_argument("--out", required=True, help="the folder to write approaches.jsonl and summary.json into")
    p.add_argument("--overwrite", action="store_true", help="replace a finished or stopped run in --out")
    p.add_argument("-v", "--verbose", action="count", default=0, help="progress every 100 approaches (-v); every module's log (-vv)")
    args = p.parse_args(argv)
    # -v: this script's progress; -vv: every module's (the controller's phases too)
    logging.basicConfig(level=logging.DEBUG if args.verbose >= 2 else logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.verbose:
        log.setLevel(logging.INFO)
    from controller.errors import EXIT_INPUT, EXIT_INTERRUPTED, EXIT_MISSING

    missing = missing_rl_modules()
    if missing:
        print(f"rl_baseline: needs {', '.join(missing)}, not installed here: pip install "
              f"'elegant-stepping[rl]' (or '.[rl]' in a clone)", file=sys.stderr)
        return EXIT_MISSING
    try:
        config = BaselineConfig(algo=args.algo, seed=args.seed, approaches=args.approaches,
                                obstacle_height_m=args.obstacle_height_m)
        from hil.experiments.learn import LearnConfig

        LearnConfig(obstacle_height_m=config.obstacle_height_m)  # the height's range, before torch starts
        summary = train(config, args.out, overwrite=args.overwrite)
    except (ValueError, FileExistsError) as exc:
        print(f"rl_baseline: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print(f"rl_baseline: interrupted; the finished approaches are in {Path(args.out) / APPROACHES_FILE}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    print(json.dumps({k: summary[k] for k in ("approaches", "approaches_to_criterion", "mistakes_after_100",
                                              "success_rate", "wall_s")}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
