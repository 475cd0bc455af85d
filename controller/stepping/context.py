"""The context learner: the Elegant Stepping premotor with one set of weights per obstacle height.

The paper's future work: "object size should be used to give the weights a certain context".
:class:`ContextPremotor` keeps weights of shape ``(n_contexts, n_cells)``; the gate receives,
besides the range encoder's cell, the height context estimated by the controller from the range
profile (:mod:`controller.stepping.height`) and gates the pair ``(context, cell)``: the burst is
``base + w[context, cell] * STM(t)``. Everything else is the adaptive premotor's
(:mod:`controller.stepping.learner`): the same one-hot gated memory and decay, one synaptic trace per
``(context, cell)`` synapse, the same reflex rule (extension: every weight up by
``learning_rate_s * trace``, placement: down) and the same bound. A reflex therefore only moves
the weights of the contexts whose synapses were gated recently: learning for a low obstacle
leaves the map for a tall one alone.

Modelling choice: a gate whose context is None (the target came into view before any profile
sample voted) uses context 0, the row of "no beam sees the target".
"""

from __future__ import annotations

import numpy as np

from controller.stepping.learner import GatedMemory, LearnerConfig, SynapticTraces, apply_reflex


class ContextPremotor:
    """Sets the CPG's burst length from gated (context, cell) memory; learns from reflexes (the
    Premotor protocol).

    ``n_contexts``: context indices 0..n_contexts-1 (:attr:`controller.stepping.height.HeightEstimatorConfig.n_contexts`);
    ``n_cells``: the range encoder's cells; ``base_burst_s``: the burst length with nothing gated
    [s]; ``weights``: initial weights [s], shape ``(n_contexts, n_cells)`` (default zeros; clipped to
    the bound).
    """

    def __init__(self, n_contexts: int, n_cells: int, base_burst_s: float, config: LearnerConfig = LearnerConfig(),
                 weights: np.ndarray | None = None) -> None:
        if not (isinstance(n_contexts, int) and n_contexts >= 1):
            raise ValueError(f"n_contexts must be a positive integer, got {n_contexts!r}")
        if not (isinstance(n_cells, int) and n_cells >= 1):
            raise ValueError(f"n_cells must be a positive integer, got {n_cells!r}")
        self.config = config
        self.base_burst_s = base_burst_s
        self.n_contexts = n_contexts
        self.n_cells = n_cells
        shape = (n_contexts, n_cells)
        if weights is None:
            weights = np.zeros(shape)
        weights = np.asarray(weights, dtype=float)
        if weights.shape != shape or not np.all(np.isfinite(weights)):
            raise ValueError(f"weights must be {shape} finite numbers, got shape {weights.shape}")
        self.weights = np.clip(weights, -config.weight_limit_s, config.weight_limit_s)
        self.memory = GatedMemory(config.stm_tau_s)
        self.traces = SynapticTraces(n_contexts * n_cells, config.trace_tau_s)
        self.context: int | None = None  # the context of the cell held in STM

    def _row(self, context: int | None) -> int:
        if context is None:
            return 0
        if not (isinstance(context, (int, np.integer)) and 0 <= context < self.n_contexts):
            raise ValueError(f"context must be None or an integer in [0, {self.n_contexts - 1}], got {context!r}")
        return int(context)

    def on_step_onset(self, now_s: float, cell: int | None, context: int | None = None) -> None:
        """The gate: the (context, cell) pair into STM (none: cleared); its synapse's trace is activated."""
        row = self._row(context)
        self.memory.gate(cell, now_s)
        self.context = row if cell is not None else None
        if cell is not None:
            self.traces.activate(row * self.n_cells + cell, now_s)

    def gated_weight(self) -> float:
        """The weight of the (context, cell) held in STM (0 when none)."""
        cell = self.memory.cell
        return 0.0 if cell is None else float(self.weights[self.context, cell])

    def modulation_s(self, now_s: float) -> float:
        return self.gated_weight() * self.memory.activity(now_s)

    def burst_s(self, now_s: float) -> float:
        return self.base_burst_s + self.modulation_s(now_s)

    def on_reflex(self, kind: str, now_s: float) -> None:
        """Extension reflex: longer strides; placement reflex: shorter strides (traced synapses only)."""
        apply_reflex(self.weights, self.traces.at(now_s), kind, self.config)
