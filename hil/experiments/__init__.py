"""Experiments: walking, learning runs and sweeps, each seeded.

:mod:`hil.experiments.methods` is the method registry, the only place a method is added
(``paper``, ``context``, ``none``, ``oracle``, ``rl``, ``improved``); :mod:`hil.experiments.learn` runs learning
trials with one of them; :mod:`hil.experiments.sweep` runs seeds x heights x methods on a process
pool or Dask; :mod:`hil.experiments.journal` keeps a run's trials on disk as they finish (the
append-only record a stopped run resumes from, the folder lock); :mod:`hil.experiments.walk` walks on flat ground; :mod:`hil.experiments.oracle` is the
planner given the true distance (and height); :mod:`hil.experiments.tuning` tries the improved
learner's settings on the tuning seeds (0-99) only; :mod:`hil.experiments.window` measures, with the
oracle, from where before a block the last swing clears it (the take-off window);
:mod:`hil.experiments.touches` replays a trial and prints its obstacle contacts step by step (the
contacts no reflex heard); :mod:`hil.experiments.credit` prints every reflex that moved one of the
improved learner's weights;
:mod:`hil.experiments.relaxation` runs the paper learner with and without the memory relaxing after
the obstacle (the paper's claim R5); :mod:`hil.experiments.rl_baseline` trains stable-baselines3's
PPO or DQN on the approach task (:mod:`hil.envs`).

May import: ``controller``, ``firmware_sim``, ``protocol``, :mod:`hil.lockstep`,
:mod:`hil.analysis`; tqdm and dask inside the functions that need them; :mod:`hil.envs` (gymnasium) and
the ``rl`` extra (stable-baselines3, torch) inside :mod:`hil.experiments.rl_baseline` only.
"""
