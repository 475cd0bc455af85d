"""The command audit: Set_Input_Pos targets the controller sent outside the joint limits.

One rule for the fault matrix in lockstep (:mod:`hil.faults.matrix`, every frame as the
controller sends it, before any fault) and for HIL sessions (:mod:`hil.faults.session`, the
targets the bus recorder kept from the controller's channel): a target [rev] is outside when it
is not finite or lies outside its axis's limits [rev]. Limits come from the controller's
configuration (lockstep) or from what the drivers report (HIL); a node without limits is audited
for finiteness only.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Iterable, Mapping

import can

from protocol import BusContract, split_arbitration_id

if TYPE_CHECKING:
    from controller.config import ControllerConfig

Limits = tuple[float | None, float | None]


class CommandAudit:
    """Counts Set_Input_Pos targets outside the limits, per node.

    ``limits_rev`` maps a node id to its (low, high) position limits [rev] (either may be None).
    Feed it frames (call it with a ``can.Message``: every Set_Input_Pos of a node in
    ``limits_rev`` is audited, other frames are ignored) or targets (:meth:`check`). Reads:
    ``checked``, ``outside`` and ``by_node`` (node id -> targets outside).
    """

    def __init__(self, limits_rev: Mapping[int, Limits]) -> None:
        contract = BusContract.load()
        self._unpack = contract.codec("Set_Input_Pos").unpack
        self._set_input_pos = split_arbitration_id(contract.odrive_id(0, "Set_Input_Pos"))[1]
        self.limits_rev = dict(limits_rev)
        self.checked = 0
        self.outside = 0
        self.by_node: dict[int, int] = {}

    @classmethod
    def from_config(cls, config: "ControllerConfig") -> "CommandAudit":
        """Against the joint limits of the controller's configuration (motor side, 1e-6 rev slack)."""
        limits = {}
        for a in config.axes:
            lo, hi = sorted((a.rad_to_rev(a.min_rad), a.rad_to_rev(a.max_rad)))
            limits[a.node_id] = (lo - 1e-6, hi + 1e-6)
        return cls(limits)

    def check(self, node: int, pos_rev: float) -> bool:
        """Audit one target of ``node``; True if it is outside."""
        lo, hi = self.limits_rev.get(node, (None, None))
        bad = not math.isfinite(pos_rev) or (lo is not None and pos_rev < lo) or (hi is not None and pos_rev > hi)
        self.checked += 1
        self.outside += bad
        self.by_node[node] = self.by_node.get(node, 0) + bad
        return bad

    def check_all(self, node: int, targets: Iterable[float]) -> None:
        for pos in targets:
            self.check(node, pos)

    def __call__(self, msg: can.Message) -> None:
        node, cmd = split_arbitration_id(msg.arbitration_id)
        if cmd != self._set_input_pos or node not in self.limits_rev or msg.is_remote_frame:
            return
        self.check(node, self._unpack(msg.data)[0])
