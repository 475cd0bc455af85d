"""The approach task as a Gymnasium environment: ``ElegantStepping/Approach-v0``.

One episode is one approach: one trial of a learning run (:meth:`hil.experiments.learn.LearningRun.trial`).
The obstacle is placed ahead, the leg walks to it and over it (or into it), and the episode ends
when the carriage is past it, exactly as in a learning trial; the leg keeps walking between
episodes, so the next approach is the run's next trial. Everything runs through the same stack as
every learning run (the CAN bus, the drivers, the PyBullet plant, stepped in lockstep by
:class:`hil.lockstep.harness.Lockstep`); the agent takes the premotor's place.

Decisions (the agent's steps). The controller decides at each step onset: its gate reads the
filtered range, encodes it as one cell (:mod:`controller.stepping.encoder`) and hands the cell to
the premotor. The agent is asked at every gate that sees a cell (the obstacle is within the
encoded range, the last three or four step cycles before it); a gate that sees none (the obstacle
still beyond the encoded range, or passed) keeps the natural burst, as the tabular Q-learner does.
So an episode has as many steps as the approach has gates with a cell: three or four with the
default conditions.

Observation: ``Box(float32, (2,))`` = ``[cell, decision]``:

- ``cell``: the encoder's cell the gate sees (0 .. n_cells - 1; 28 cells of 0.04 m by default),
  or :data:`NO_CELL` (-1) in the observation that ends an episode (and at the start of an
  approach that ended before any gate saw a cell, which the default conditions never give: the
  obstacle comes into view at least 2.2 m ahead, the encoded range is 1.12 m).
- ``decision``: how many decisions of this approach came before this one (0 at the first gate
  that sees the obstacle), saturating at ``max_steps``.

Why these two. The cell is what the premotor is given at the gate (the range it was encoded from
is not: :meth:`controller.stepping.premotor.Premotor.on_step_onset` takes the cell), and it is the
whole state of the tabular Q-learner (:mod:`controller.stepping.rl`), so a network agent here and
the ``rl`` method learn from the same input: the comparison is like for like. The decision index
is the "step before the obstacle" of issue 19; the Q-learner could count it from the gates it saw
(it is a function of the approach's history, not new information about the world). The filtered
range itself is in ``info["gated_range_m"]`` for analysis, not in the observation: it would give
a network finer information than any premotor gets. The cell is a number, so a network sees the
cells in order, which the tabular learner (and the paper's learner) do not assume; that is the
one advantage the network agents have, and it is theirs by construction.

Action: ``Discrete(len(actions_s))``: index ``a`` asks for the burst change ``actions_s[a]`` [s]
for the coming swing, through the same decaying short-term memory as the Q-learner
(``burst = base + actions_s[a] * exp(-(t - t_gate) / stm_tau_s)``, clipped by the CPG to its
bounds). The default ``actions_s`` and ``stm_tau_s`` are :class:`controller.stepping.rl.QLearnerConfig`'s:
the same six burst changes, -0.15 .. +0.30 s (index 2 is no change). Discrete, so DQN can use it.

Reward: only what the learner gets, plus the ground truth of success at the end.

- ``-1`` for each contact reflex (extension or placement) the controller fires, counted in the
  step in which it fires (from the decision to the next decision, or to the episode's end; a
  reflex before the first decision counts in the first step);
- ``+1`` at the end of an approach that succeeded: no contact between any leg link and the
  obstacle (ground truth from the plant) and not stalled, the trial record's ``success``.

So an episode's return is ``success - len(record["reflexes"])``. The Q-learner's terminal reward
(+1 without a reflex, -1 with one) is the same signal in one number.

Episodes, reset and truncation:

- ``reset(seed=s)`` starts a new run seeded ``s`` (the :class:`~hil.experiments.learn.LearnConfig`
  seed: the obstacles' start distances, the sensor's noise), brings the leg up and begins its
  first approach: a seed gives the same episodes, observation for observation.
- ``reset()`` without a seed continues the run: the next approach is the next trial. Before any
  seeded reset the run is ``seed`` (constructor; default 0), so an environment is deterministic
  even if nobody seeds it. Gymnasium's ``np_random`` is seeded by ``reset`` as usual but unused:
  the run draws from its own generators.
- An approach in progress at ``reset()`` (a reset in the middle of an episode, or after a
  truncation) is walked to its end with no burst change at its remaining gates, and its record is
  kept: the leg is never teleported, the next approach starts from where the leg is.
- An approach asking for more than ``max_steps`` decisions (a leg caught on the block) is
  truncated: ``truncated`` True with the next gate's observation; the next ``reset()`` walks it
  to its end as above.

Design: the trial loop (:meth:`~hil.experiments.learn.LearningRun.trial`) is closed (it runs
physics steps until the carriage is past the obstacle) and its records are what every method's
results are made of, so it is left exactly as it is. The run lives in a worker thread, with a
premotor (:class:`HandoffPremotor`) whose ``on_step_onset`` hands the gate to the environment
and blocks until ``step`` gives the action. The handoff is synchronous (one of the two threads
runs at a time, the other waits on a queue), so the run is exactly as deterministic as a learning
run: the same seed and actions give the same records. The worker builds, walks and closes the run
(PyBullet is only ever called from it). ``close()`` (and a seeded ``reset``, which replaces the
run) aborts a waiting approach by raising inside the gate, which unwinds the trial; the run is
then closed and the thread joined, so no thread is left behind. A coroutine would need the trial
loop rewritten as a generator; a hook in the loop would change code every method runs.

Records: every finished approach's trial record, unchanged, with the agent's side (decisions,
return, truncated) is kept in :attr:`ApproachEnv.approaches` (a few kB each), and the record is
in the ``info`` of the step that ends it (``info["record"]``).

May import what :mod:`hil.envs` may.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import queue
import threading
import weakref
from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping

import gymnasium
import numpy as np
from gymnasium import spaces

from controller.stepping.rl import QLearnerConfig
from hil.experiments.learn import LearnConfig, LearningRun

log = logging.getLogger(__name__)

NO_CELL = -1
"""The observation's ``cell`` when the gate sees none (the end of an episode)."""

DEFAULT_ACTIONS_S: tuple[float, ...] = QLearnerConfig().actions_s
"""The burst changes [s] the agent chooses from: the tabular Q-learner's."""

OWN_FIELDS = ("trials", "seed", "method", "trace_trials", "obstacle_height_m")
"""The :class:`~hil.experiments.learn.LearnConfig` fields the environment sets itself (not in
``config_overrides``): the run is endless, seeded by ``reset``, its premotor is the agent, it
traces nothing, and the height is an argument of its own."""

WORKER_POLL_S = 0.5
"""How often [s] a wait for the worker checks that the worker is still alive."""

JOIN_TIMEOUT_S = 60.0
"""How long [s] ``close`` waits for the worker to finish (at most one trial's remaining physics)."""


class _Abort(Exception):
    """Raised inside the gate to unwind an approach the environment no longer wants."""


class HandoffPremotor:
    """The premotor of the environment's run: at a gate that sees a cell it asks ``ask(cell)`` for
    the burst change [s] and holds it through short-term memory (the Q-learner's
    ``base + change * exp(-(t - t_gate) / stm_tau_s)``); a gate without a cell keeps the natural
    burst. Counts the contact reflexes (``reflexes``); it learns nothing itself."""

    def __init__(self, base_burst_s: float, stm_tau_s: float, ask: Callable[[int], float]) -> None:
        self.base_burst_s = base_burst_s
        self.stm_tau_s = stm_tau_s
        self._ask = ask
        self._change_s = 0.0
        self._gate_t_s = -math.inf
        self.reflexes = 0

    def on_step_onset(self, now_s: float, cell: int | None, context: int | None = None) -> None:
        self._change_s = 0.0 if cell is None else self._ask(cell)
        self._gate_t_s = now_s

    def burst_s(self, now_s: float) -> float:
        if self._change_s == 0.0:
            return self.base_burst_s
        return self.base_burst_s + self._change_s * math.exp(-(now_s - self._gate_t_s) / self.stm_tau_s)

    def on_reflex(self, kind: str, now_s: float) -> None:
        if kind not in ("extension", "placement"):
            raise ValueError(f"unknown reflex kind {kind!r}")
        self.reflexes += 1

    def gated_weight(self) -> float:
        return self._change_s


@dataclass(frozen=True)
class _Event:
    """What the worker tells the environment: ``kind`` ``"ready"`` (the leg is up), ``"decide"``
    (a gate waits for an action: ``cell``, ``gated_range_m``), ``"done"`` (the approach ended:
    ``record``), ``"error"`` (``error``); ``reflexes``: the run's contact reflexes so far."""

    kind: str
    reflexes: int = 0
    cell: int | None = None
    gated_range_m: float | None = None
    record: dict[str, Any] | None = None
    error: BaseException | None = None


class _Runner:
    """A learning run in its own thread, one approach at a time, its gates handed over.

    Commands (:meth:`send`): ``("trial",)`` begins the next approach (then events ``decide``...
    ``done``); ``("act", change_s)`` answers a ``decide``; ``("finish",)`` answers it with no
    change, and every later gate of the approach too; ``("abort",)`` ends the thread, unwinding a
    waiting approach."""

    def __init__(self, config: LearnConfig, stm_tau_s: float) -> None:
        self.config = config
        self._commands: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self._events: queue.Queue[_Event] = queue.Queue()
        self._asking = False
        self.run: LearningRun | None = None
        self.premotor = HandoffPremotor(config.controller.cpg.burst_s, stm_tau_s, self._ask)
        self.thread = threading.Thread(target=self._main, name=f"approach-env-seed-{config.seed}", daemon=True)
        self.dead = False
        self.thread.start()
        self.expect("ready")

    # ---- the worker's side
    def _ask(self, cell: int) -> float:
        if not self._asking:  # between approaches, or an approach walked to its end
            return 0.0
        estimate = self.run.ls.loop.range_filter.estimate_m if self.run is not None else None
        self._events.put(_Event("decide", self.premotor.reflexes, cell=cell,
                                gated_range_m=None if estimate is None else float(estimate)))
        command = self._commands.get()
        if command[0] == "act":
            return float(command[1])
        if command[0] == "finish":
            self._asking = False
            return 0.0
        raise _Abort

    def _main(self) -> None:
        try:
            self.run = LearningRun(self.config, premotor=self.premotor)
            self.run.bring_up()
            self._events.put(_Event("ready"))
            index = 0
            while self._commands.get()[0] == "trial":
                self._asking = True
                record = self.run.trial(index)
                self._asking = False
                index += 1
                self._events.put(_Event("done", self.premotor.reflexes, record=record))
        except _Abort:
            log.debug("approach env: seed %d: approach abandoned", self.config.seed)
        except BaseException as exc:  # noqa: BLE001 - handed to the environment's thread, raised there
            self._events.put(_Event("error", error=exc))
        finally:
            if self.run is not None:
                self.run.close()

    # ---- the environment's side
    def send(self, *command: Any) -> None:
        self._commands.put(command)

    def wait(self) -> _Event:
        """The worker's next event; an error in the worker is raised here."""
        while True:
            try:
                event = self._events.get(timeout=WORKER_POLL_S)
                break
            except queue.Empty:
                if not self.thread.is_alive() and self._events.empty():
                    self.dead = True
                    raise RuntimeError(f"the approach environment's run (seed {self.config.seed}) stopped "
                                       f"without a word") from None
        if event.kind == "error":
            self.dead = True
            raise RuntimeError(f"the approach environment's run (seed {self.config.seed}) failed: "
                               f"{event.error}") from event.error
        return event

    def expect(self, kind: str) -> _Event:
        event = self.wait()
        if event.kind != kind:
            raise AssertionError(f"approach env: expected the worker's {kind!r}, got {event.kind!r}")
        return event

    def close(self) -> None:
        """Abort whatever the worker waits for, close the run, join the thread."""
        if self.thread.is_alive():
            self.send("abort")
            self.thread.join(JOIN_TIMEOUT_S)
            if self.thread.is_alive():
                log.warning("approach env: the worker of seed %d did not stop within %.0f s", self.config.seed,
                            JOIN_TIMEOUT_S)
        self.dead = True


@dataclass(frozen=True)
class Approach:
    """One finished approach: the trial ``record`` exactly as :meth:`LearningRun.trial` wrote it,
    the agent's ``decisions`` in it, its ``agent_return`` (the rewards the agent was given:
    partial if the approach was truncated or reset), whether it was ``truncated``, and whether a
    ``reset`` walked its remaining gates (``finished_by_reset``)."""

    record: dict[str, Any]
    decisions: int
    agent_return: float
    truncated: bool
    finished_by_reset: bool


class ApproachEnv(gymnasium.Env):
    """The approach task (module docstring: observation, action, reward, episodes, design).

    Args:
        obstacle_height_m: the obstacle's height [m]; default 0.08 (the paper's). Checked by
            :class:`~hil.experiments.learn.LearnConfig` (its declared range and what the leg can
            clear at all).
        seed: the run's seed until a ``reset(seed=...)`` gives one; default 0.
        max_steps: decisions per approach before the episode is truncated; default 32 (an
            approach has three or four; more only when the leg is caught on the block), 1-1000.
        actions_s: the burst changes [s] to choose from, each within +-1 s; default the
            Q-learner's (-0.15, -0.075, 0.0, 0.075, 0.15, 0.30).
        stm_tau_s: the decay of a chosen change through short-term memory [s]; default 1.0 (the
            Q-learner's and the paper learner's), 0.01-60.
        config_overrides: other :class:`~hil.experiments.learn.LearnConfig` fields by name (the
            conditions: ``obstacle_depth_m``, ``range_noise_m``, ``range_dropout_prob``,
            ``rail_speed_m_s``, ``start_min_m``, ...; ``controller``); not those in
            :data:`OWN_FIELDS`. Default none: the declared default conditions.
        render_mode: None only (nothing is drawn; ``elegant-stepping animate`` draws trials).

    Raises:
        ValueError: an argument out of its range, or an unknown or reserved override, naming it.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, obstacle_height_m: float = 0.08, *, seed: int = 0, max_steps: int = 32,
                 actions_s: tuple[float, ...] = DEFAULT_ACTIONS_S, stm_tau_s: float = 1.0,
                 config_overrides: Mapping[str, Any] | None = None, render_mode: str | None = None) -> None:
        super().__init__()
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (the approach environment draws nothing), got {render_mode!r}")
        if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or not 1 <= max_steps <= 1000:
            raise ValueError(f"max_steps must be a whole number of decisions in [1, 1000], got {max_steps!r}")
        _check_seed(seed, "seed")
        try:  # the Q-learner's own checks of the same two settings
            QLearnerConfig(actions_s=tuple(float(a) for a in actions_s), stm_tau_s=float(stm_tau_s))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"actions_s / stm_tau_s: {exc}") from None
        overrides = dict(config_overrides or {})
        known = {f.name for f in dataclasses.fields(LearnConfig)}
        for name in overrides:
            if name in OWN_FIELDS:
                raise ValueError(f"config_overrides: {name!r} is set by the environment itself "
                                 f"({', '.join(OWN_FIELDS)} are not overrides)")
            if name not in known:
                raise ValueError(f"config_overrides: {name!r} is not a LearnConfig field; "
                                 f"choose from {', '.join(sorted(known - set(OWN_FIELDS)))}")
        if isinstance(obstacle_height_m, bool) or not isinstance(obstacle_height_m, (int, float, np.floating)):
            raise ValueError(f"obstacle_height_m must be a number [m], got {obstacle_height_m!r}")
        try:  # trials: the run is endless; LearnConfig's bound only sizes a trace, which is off here
            self.config = LearnConfig(trials=100000, seed=int(seed), method="rl",
                                      obstacle_height_m=float(obstacle_height_m), **overrides)
        except (TypeError, ValueError) as exc:  # its checks name the condition; say which argument set it
            given = f"obstacle_height_m {float(obstacle_height_m)!r} m" + (f", config_overrides {overrides!r}"
                                                                           if overrides else "")
            raise ValueError(f"{exc} ({given})") from None
        self.max_steps = int(max_steps)
        self.actions_s = tuple(float(a) for a in actions_s)
        self.stm_tau_s = float(stm_tau_s)
        self.n_cells = self.config.controller.encoder.n_cells
        self.action_space = spaces.Discrete(len(self.actions_s))
        self.observation_space = spaces.Box(low=np.array([NO_CELL, 0], dtype=np.float32),
                                            high=np.array([self.n_cells - 1, self.max_steps], dtype=np.float32),
                                            dtype=np.float32)
        self.approaches: list[Approach] = []
        """Every finished approach of the current run, in order (a new seeded reset starts it anew)."""
        self._runner: _Runner | None = None
        self._finalizer: weakref.finalize | None = None
        self._state = "idle"  # "deciding": a gate waits for step's action; "empty": the approach ended undecided
        self._pending: _Event | None = None  # the waiting gate, or the undecided approach's "done"
        self._decisions = 0
        self._reflexes_seen = 0
        self._return = 0.0
        self._truncated = False

    @property
    def run_seed(self) -> int:
        """The seed of the current run (or of the next one, before the first reset)."""
        return self.config.seed

    # ---- Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:
            _check_seed(seed, "reset seed")
        if options:
            raise ValueError(f"the approach environment takes no reset options, got {sorted(options)}")
        super().reset(seed=seed)
        finished: dict[str, Any] | None = None
        if seed is not None:
            self._close_runner()
            self.config = replace(self.config, seed=int(seed))
        elif self._runner is not None and self._runner.dead:
            raise RuntimeError(f"the run of seed {self.config.seed} failed; reset(seed=...) starts a new one")
        if self._runner is None:
            self.approaches = []
            self._runner = _Runner(self.config, self.stm_tau_s)
            # an environment dropped without close(), or still open at exit, stops its run all the same
            self._finalizer = weakref.finalize(self, self._runner.close)
            self._reflexes_seen = 0
        elif self._state == "deciding":  # walk the approach in progress to its end
            self._runner.send("finish")
            event = self._runner.expect("done")
            finished = self._finish(event, truncated=self._truncated, by_reset=True)
        elif self._state == "empty":
            finished = self._finish(self._pending, truncated=False, by_reset=True)
        self._state, self._pending = "idle", None
        self._decisions, self._return, self._truncated = 0, 0.0, False
        self._runner.send("trial")
        event = self._runner.wait()
        info = {"approach": len(self.approaches), "run_seed": self.config.seed}
        if finished is not None:
            info["finished_record"] = copy.deepcopy(finished)
        self._pending = event
        if event.kind == "decide":
            self._state = "deciding"
            info.update(cell=event.cell, gated_range_m=event.gated_range_m)
            return self._obs(event.cell, 0), info
        self._state = "empty"  # no gate saw the obstacle: the first step ends the episode
        info.update(cell=None, gated_range_m=None)
        return self._obs(None, 0), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._state == "idle" or self._runner is None:
            raise RuntimeError("the approach environment needs reset() before step() (and after an episode's end)")
        if self._truncated:
            raise RuntimeError("the episode was truncated: call reset() (it walks the approach to its end)")
        if not self.action_space.contains(action):
            raise ValueError(f"action must be an integer in [0, {self.action_space.n}), got {action!r}")
        if self._state == "empty":
            event, self._pending = self._pending, None
        else:
            self._runner.send("act", self.actions_s[int(action)])
            self._decisions += 1
            event = self._runner.wait()
        reward = float(self._reflexes_seen - event.reflexes)
        self._reflexes_seen = event.reflexes
        info: dict[str, Any] = {"approach": len(self.approaches), "decision": self._decisions}
        if event.kind == "decide":
            self._pending = event
            self._return += reward
            self._truncated = self._decisions >= self.max_steps
            info.update(cell=event.cell, gated_range_m=event.gated_range_m)
            return self._obs(event.cell, self._decisions), reward, False, self._truncated, info
        record = event.record
        reward += 1.0 if record["success"] else 0.0
        self._return += reward
        self._finish(event, truncated=False, by_reset=False)
        self._state, self._pending = "idle", None
        info.update(cell=None, gated_range_m=None, success=bool(record["success"]),
                    reflexes=len(record["reflexes"]), record=copy.deepcopy(record))
        return self._obs(None, self._decisions), reward, True, False, info

    def close(self) -> None:
        """Stop the run (a waiting approach is abandoned, not recorded) and its thread; may be called again."""
        self._close_runner()
        super().close()

    # ---- helpers
    def _obs(self, cell: int | None, decision: int) -> np.ndarray:
        return np.array([NO_CELL if cell is None else cell, min(decision, self.max_steps)], dtype=np.float32)

    def _finish(self, event: _Event, *, truncated: bool, by_reset: bool) -> dict[str, Any]:
        """Keep a finished approach; by a reset, its reflexes since the last step go to no one."""
        record = event.record
        self._reflexes_seen = event.reflexes
        self.approaches.append(Approach(record, self._decisions, self._return, truncated, by_reset))
        return record

    def _close_runner(self) -> None:
        if self._finalizer is not None:
            self._finalizer()  # the runner's close, once
        self._runner, self._finalizer = None, None
        self._state, self._pending = "idle", None
        self._decisions, self._return, self._truncated = 0, 0.0, False


def _check_seed(seed: Any, what: str) -> None:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**32:
        raise ValueError(f"{what} must be a whole number in [0, 2**32), got {seed!r}")
