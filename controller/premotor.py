"""The premotor module's interface: what sets the CPG's burst length.

:class:`ConstantBurst` is the walking skeleton's (a fixed burst length); the learner of the
Elegant Stepping model implements the same two methods.
"""

from __future__ import annotations

from typing import Any, Protocol


class Premotor(Protocol):
    def on_step_onset(self, now_s: float, loop: Any) -> None:
        """Called on the tick the CPG's step-onset signal fires."""

    def burst_s(self, now_s: float) -> float:
        """The burst length [s] the CPG should use now (the CPG clips it to its safe bounds)."""


class ConstantBurst:
    def __init__(self, burst_s: float) -> None:
        self.value_s = burst_s

    def on_step_onset(self, now_s: float, loop: Any) -> None:
        pass

    def burst_s(self, now_s: float) -> float:
        return self.value_s
