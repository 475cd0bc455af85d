"""The adaptive premotor module of the Elegant Stepping model: gated memory, traces, learning.

Temporal gating: at each step onset the range encoder's active cell is gated one-to-one into
short-term memory (STM). The STM holds that cell at 1 and decays as ``exp(-t / stm_tau_s)`` until
the next gate replaces it (a gate with no target in view clears it, unless ``relax_out_of_view``:
then the held cell decays on until its activity is below :data:`RELAX_FLOOR`).

Premotor output: ``burst = base + sum_i w_i * STM_i(t)``, read by the CPG at every tick and
clipped by it to its safe bounds; with one cell active this is ``base + w_k * exp(-t/tau)``. It
is smooth within a step, and it returns to the base value once the obstacle is out of view: at
once by default, or gradually, on the memory's own decay, with ``relax_out_of_view`` (the paper:
"after passing the obstacle, the burst length gradually relaxes to its former value"; off by
default, so the reproduction's records stay as they were; :mod:`hil.experiments.relaxation`
measures both).

Synaptic traces: a synapse the STM activated keeps a trace that decays as
``exp(-t / trace_tau_s)`` (each gate adds 1 to its cell's trace). On a reflex every weight moves
by ``learning_rate_s * trace_i``: up for an extension reflex (longer strides), down for a
placement reflex (shorter strides). The traces of the last few gates are alive when the crossing
goes wrong, the most recent the strongest: credit flows back over the last steps without any
model of the world.

Modelling choices the paper leaves open: one-hot STM (the encoder's cells do not overlap); the
STM and trace time constants; weights bounded to ``+-weight_limit_s`` so no single cell can ask
for a burst the CPG would clip anyway.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.settings.schema import check_settings, setting
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class LearnerConfig:
    """Memory, traces and learning rule. ``learning`` False is the no-learning baseline.

    The default ``stm_tau_s`` keeps most of the gated value alive through the swing the gate
    modulates (it starts a stance after the gate). The default ``trace_tau_s`` leaves the traces of
    the last three gates alive at the crossing, the most recent the strongest: credit reaches the
    decisions that placed the last footfall.
    """

    stm_tau_s: float = setting(1.0, "s", 0.01, 60.0, "short-term memory decay")
    trace_tau_s: float = setting(2.5, "s", 0.01, 60.0, "synaptic trace decay")
    learning_rate_s: float = setting(0.3, "s", 0.0, 1.0, "weight change per unit trace per reflex")
    weight_limit_s: float = setting(0.4, "s", 0.001, 2.0, "bound on each weight's magnitude")
    learning: bool = setting(True, doc="false freezes the weights")
    relax_out_of_view: bool = setting(False, doc="a gate with no target in view lets the held memory decay on "
                                      "(the burst relaxes gradually after the obstacle) instead of clearing it")

    def __post_init__(self) -> None:
        check_settings(self, "learner")


RELAX_FLOOR = 0.01
"""With ``relax_out_of_view``, a gate with no target in view clears a memory whose activity is
below this (4.6 time constants after its gate): nothing is held for ever, and an approach starts
from the base burst."""


class GatedMemory:
    """Short-term memory of one gated cell, decaying exponentially."""

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.cell: int | None = None
        self.gate_t_s = -math.inf

    def gate(self, cell: int | None, now_s: float) -> None:
        self.cell = cell
        self.gate_t_s = now_s

    def activity(self, now_s: float) -> float:
        """STM activity of the gated cell now (0 when nothing is held)."""
        if self.cell is None:
            return 0.0
        return math.exp(-(now_s - self.gate_t_s) / self.tau_s)


class SynapticTraces:
    """One decaying trace per synapse, decayed lazily to the time it is read."""

    def __init__(self, n: int, tau_s: float) -> None:
        self.tau_s = tau_s
        self.values = np.zeros(n)
        self.t_s = 0.0

    def _decay_to(self, now_s: float) -> None:
        if now_s > self.t_s:
            self.values *= math.exp(-(now_s - self.t_s) / self.tau_s)
            self.t_s = now_s

    def activate(self, cell: int, now_s: float, amount: float = 1.0) -> None:
        self._decay_to(now_s)
        self.values[cell] += amount

    def at(self, now_s: float) -> np.ndarray:
        self._decay_to(now_s)
        return self.values


def apply_reflex(weights: np.ndarray, traces: np.ndarray, kind: str, config: LearnerConfig) -> None:
    """The learning rule, in place: every weight moves by ``learning_rate_s * trace``, up for an
    extension reflex, down for a placement reflex, within ``+-weight_limit_s``. ``traces`` holds
    one trace per weight, in the weights' order (any shape of the same size)."""
    if kind not in ("extension", "placement"):
        raise ValueError(f"unknown reflex kind {kind!r}")
    if not config.learning or config.learning_rate_s == 0.0:
        return
    sign = 1.0 if kind == "extension" else -1.0
    weights += sign * config.learning_rate_s * traces.reshape(weights.shape)
    np.clip(weights, -config.weight_limit_s, config.weight_limit_s, out=weights)


class AdaptivePremotor:
    """Sets the CPG's burst length from gated memory; learns from reflexes (the Premotor protocol)."""

    def __init__(self, n_cells: int, base_burst_s: float, config: LearnerConfig = LearnerConfig(),
                 weights: np.ndarray | None = None) -> None:
        self.config = config
        self.base_burst_s = base_burst_s
        if weights is None:
            weights = np.zeros(n_cells)
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (n_cells,) or not np.all(np.isfinite(weights)):
            raise ValueError(f"weights must be {n_cells} finite numbers, got shape {weights.shape}")
        self.weights = np.clip(weights, -config.weight_limit_s, config.weight_limit_s)
        self.memory = GatedMemory(config.stm_tau_s)
        self.traces = SynapticTraces(n_cells, config.trace_tau_s)

    def on_step_onset(self, now_s: float, cell: int | None, context: int | None = None) -> None:
        """The gate: the encoder's active cell (or none) into STM; its synapse's trace is activated.
        The context (obstacle height bin) is ignored: one set of weights for every height. With
        ``relax_out_of_view``, a gate that sees nothing keeps a memory still above
        :data:`RELAX_FLOOR`, decaying on."""
        if cell is None and self.config.relax_out_of_view and self.memory.activity(now_s) >= RELAX_FLOOR:
            return
        self.memory.gate(cell, now_s)
        if cell is not None:
            self.traces.activate(cell, now_s)

    def modulation_s(self, now_s: float) -> float:
        cell = self.memory.cell
        if cell is None:
            return 0.0
        return float(self.weights[cell]) * self.memory.activity(now_s)

    def burst_s(self, now_s: float) -> float:
        if self.memory.cell is None:  # nothing held (most ticks): base + 0.0, without the calls (the base
            return self.base_burst_s  # is a positive burst length, so adding 0.0 changes no bit of it)
        return self.base_burst_s + self.modulation_s(now_s)

    def gated_weight(self) -> float:
        """The weight of the cell held in STM (0 when none): non-zero means the gate changes the burst."""
        return 0.0 if self.memory.cell is None else float(self.weights[self.memory.cell])

    def on_reflex(self, kind: str, now_s: float) -> None:
        """Extension reflex: longer strides; placement reflex: shorter strides."""
        apply_reflex(self.weights, self.traces.at(now_s), kind, self.config)
