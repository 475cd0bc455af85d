"""Gymnasium environments of the leg's tasks, for reinforcement-learning libraries.

:mod:`hil.envs.approach` is the approach task (one episode is one approach to an obstacle, as one
learning trial) as ``ElegantStepping/Approach-v0``; it runs through the same stack as every
learning run (the bus, the drivers, the plant in lockstep: :class:`hil.experiments.learn.LearningRun`),
with the agent in the premotor's place. docs/gym.md says how to use it and how the stable-baselines3
baseline (:mod:`hil.experiments.rl_baseline`) runs on it.

Importing this package registers the environments with Gymnasium (once: importing it again does
not register them twice), so ``import hil.envs`` then ``gymnasium.make("ElegantStepping/Approach-v0")``
works. The module itself is imported by Gymnasium only when an environment is made.

May import: gymnasium (the ``research`` extra), ``controller``, ``firmware_sim``, ``protocol``,
:mod:`hil.experiments`, :mod:`hil.lockstep`, :mod:`hil.analysis`. No RL library (stable-baselines3,
torch: the ``rl`` extra): only the baseline script imports those.
"""

from __future__ import annotations

import gymnasium

APPROACH_ID = "ElegantStepping/Approach-v0"
"""The registered id of :class:`hil.envs.approach.ApproachEnv`."""

if APPROACH_ID not in gymnasium.registry:  # registering twice would warn of an override
    gymnasium.register(id=APPROACH_ID, entry_point="hil.envs.approach:ApproachEnv")
