"""A reinforcement-learning premotor: tabular Q-learning on the same gated range encoder.

The baseline for the paper's claim that reflex-supervised learning needs far fewer trials than
reinforcement learning. It sees exactly what the Elegant Stepping learner sees (the encoder's
cell gated at each step onset; the contact reflexes) but learns from a scalar reward instead of a
signed error:

- State: the gated cell. Action: one of ``actions_s`` burst changes, chosen epsilon-greedily at
  the gate; it acts through the same decaying short-term memory as the learner
  (``burst = base + a * exp(-t / stm_tau_s)``).
- Episode: one approach, from the first gate that sees a cell until the second gate that sees
  none again (the sensor has passed the obstacle; the foot may touch it until the next onset).
- Reward: at the episode's end, ``+1`` if no contact reflex fired during it, ``-1`` if one did;
  0 for every other transition. One-step Q-learning,
  ``Q(s, a) += alpha * (r + gamma * max_a' Q(s', a') - Q(s, a))``, with a terminal update.

Exploration draws from a ``numpy`` generator seeded by ``seed``, so a run is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class QLearnerConfig:
    """Attributes:
    actions_s: the burst changes the agent chooses from [s]; default -0.15 to +0.30, the same
        authority as the learner's bounded weights within the CPG's burst bounds.
    alpha: learning rate; default 0.3.
    gamma: discount per gate; default 0.9.
    epsilon: exploration probability at a gate; default 0.1.
    stm_tau_s: decay of the chosen action through short-term memory [s]; default 1.0 (as the
        learner's).
    seed: seed of the exploration; default 0.
    """

    actions_s: tuple[float, ...] = (-0.15, -0.075, 0.0, 0.075, 0.15, 0.30)
    alpha: float = 0.3
    gamma: float = 0.9
    epsilon: float = 0.1
    stm_tau_s: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.actions_s or not all(math.isfinite(a) and abs(a) <= 1.0 for a in self.actions_s):
            raise ValueError(f"rl.actions_s must be burst changes within +-1 s, got {self.actions_s!r}")
        for name, lo, hi in (("alpha", 0.0, 1.0), ("gamma", 0.0, 1.0), ("epsilon", 0.0, 1.0)):
            value = getattr(self, name)
            if not (math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"rl.{name} must be in [{lo}, {hi}], got {value!r}")
        if not (math.isfinite(self.stm_tau_s) and 0.01 <= self.stm_tau_s <= 60.0):
            raise ValueError(f"rl.stm_tau_s must be in [0.01, 60] s, got {self.stm_tau_s!r}")


class QLearningPremotor:
    """Tabular Q-learning over (gated cell, burst change); a Premotor."""

    def __init__(self, n_cells: int, base_burst_s: float, config: QLearnerConfig = QLearnerConfig()) -> None:
        self.config = config
        self.base_burst_s = base_burst_s
        self.actions = np.asarray(config.actions_s, dtype=float)
        self.q = np.zeros((n_cells, len(self.actions)))
        self.rng = np.random.default_rng(config.seed)
        self._prev: tuple[int, int] | None = None  # (cell, action) awaiting its next state
        self._action = 0.0
        self._gate_t_s = -math.inf
        self._failed = False
        self._closing = False
        self.episodes = 0
        self.returns: list[float] = []

    def _choose(self, cell: int) -> int:
        if self.rng.random() < self.config.epsilon:
            return int(self.rng.integers(len(self.actions)))
        row = self.q[cell]
        best = np.flatnonzero(row == row.max())
        # ties go to the action nearest no change, so an untrained agent walks naturally
        return int(best[np.argmin(np.abs(self.actions[best]))])

    def _update(self, target: float) -> None:
        cell, a = self._prev
        self.q[cell, a] += self.config.alpha * (target - self.q[cell, a])

    def _close_episode(self) -> None:
        """The terminal update: +1 for an approach without a contact reflex, -1 with one."""
        reward = -1.0 if self._failed else 1.0
        self._update(reward)
        self.returns.append(reward)
        self.episodes += 1
        self._prev = None
        self._failed = False
        self._closing = False

    def on_step_onset(self, now_s: float, cell: int | None, context: int | None = None) -> None:
        c = self.config
        if cell is None:
            # the obstacle has left the encoded range; the foot may still touch it until the
            # next step onset, so the terminal reward waits for the second empty gate
            if self._prev is not None:
                if self._closing:
                    self._close_episode()
                else:
                    self._closing = True
            self._action = 0.0
            return
        if self._prev is not None and not self._closing:
            self._update(c.gamma * float(self.q[cell].max()))
        elif self._prev is not None:  # a new approach before the last one closed: close it now
            self._close_episode()
        a = self._choose(cell)
        self._prev = (cell, a)
        self._action = float(self.actions[a])
        self._gate_t_s = now_s

    def burst_s(self, now_s: float) -> float:
        if self._action == 0.0:
            return self.base_burst_s
        return self.base_burst_s + self._action * math.exp(-(now_s - self._gate_t_s) / self.config.stm_tau_s)

    def on_reflex(self, kind: str, now_s: float) -> None:
        if kind not in ("extension", "placement"):
            raise ValueError(f"unknown reflex kind {kind!r}")
        self._failed = True

    def gated_weight(self) -> float:
        return self._action
