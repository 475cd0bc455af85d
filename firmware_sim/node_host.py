"""The firmware side of the bus: hosts simulated nodes on one python-can bus.

:class:`NodeHost` drains the bus without blocking and routes each standard-id frame by its node
id (``arbitration_id >> 5``) to the node with that id, sending whatever the node replies; it
steps every node's control loop; and it sends every node's cyclic frames. A simulation step is
``poll(now)``, ``update(now, dt)``, ``publish(now)`` (or :meth:`NodeHost.step`, which does the
three in that order).

Frames for node ids not hosted here are another node's traffic: ignored, counted in
``stats["foreign"]``. Extended-id and error frames are counted in ``stats["unknown"]``. A send
that fails with :class:`can.CanError` is counted in ``stats["send_errors"]``, never raised; a
receive that fails with :class:`can.CanError` (or ``OSError``) is counted in
``stats["recv_errors"]`` and ends that poll (the next poll reads the same bus again); a node's
``handle`` that raises (it should not) is counted in ``stats["node_errors"]``. Nothing a frame
contains can raise out of :meth:`NodeHost.poll`. The hot path does no logging and allocates no
dicts.
"""

from __future__ import annotations

from typing import Any, Protocol, Sequence

import can


class Node(Protocol):
    """A simulated CAN node: a simulated ODrive axis or the sensor board."""

    node_id: int

    def handle(self, msg: can.Message, now_s: float) -> list[can.Message]:
        """Process one frame addressed to this node; return replies. Must not raise."""
        ...

    def update(self, now_s: float, dt_s: float) -> None:
        """Advance the node's internal loop by ``dt_s``."""
        ...

    def due(self, now_s: float) -> list[can.Message]:
        """Cyclic frames whose period has elapsed at ``now_s``."""
        ...


class NodeHost:
    """Route bus traffic to simulated nodes and publish their frames.

    ``stats``: ``rx`` (frames read from the bus), ``tx`` (frames sent), ``foreign``,
    ``unknown``, ``send_errors``, ``recv_errors``, ``node_errors``.
    """

    def __init__(self, bus: can.BusABC, nodes: Sequence[Node]) -> None:
        self.bus = bus
        self.nodes: tuple[Node, ...] = tuple(nodes)
        self._by_id: dict[int, Node] = {}
        for node in self.nodes:
            if node.node_id in self._by_id:
                raise ValueError(f"two nodes with node id {node.node_id}")
            self._by_id[node.node_id] = node
        self.stats: dict[str, int] = {
            "rx": 0,
            "tx": 0,
            "foreign": 0,
            "unknown": 0,
            "send_errors": 0,
            "recv_errors": 0,
            "node_errors": 0,
        }

    def _send(self, msg: can.Message) -> None:
        try:
            self.bus.send(msg)
        except can.CanError:
            self.stats["send_errors"] += 1
        else:
            self.stats["tx"] += 1

    def poll(self, now_s: float) -> int:
        """Drain the bus without blocking; route frames and send replies. Returns frames read."""
        recv = self.bus.recv
        by_id = self._by_id
        stats = self.stats
        count = 0
        msg: Any  # read without mypyc's type checks: a node must survive any frame (a numpy.bool flag too)
        while True:
            try:
                msg = recv(0)
            except (can.CanError, OSError):
                stats["recv_errors"] += 1
                break
            if msg is None:
                break
            count += 1
            if msg.is_extended_id or msg.is_error_frame:
                stats["unknown"] += 1
            else:
                replies: Sequence[can.Message]
                node = by_id.get(msg.arbitration_id >> 5)
                if node is None:
                    stats["foreign"] += 1
                else:
                    try:
                        replies = node.handle(msg, now_s)
                    except Exception:  # noqa: BLE001 - one faulty node must not stop the bus
                        stats["node_errors"] += 1
                        replies = ()
                    for reply in replies:
                        self._send(reply)
        stats["rx"] += count
        return count

    def update(self, now_s: float, dt_s: float) -> None:
        """Step every node's control loop."""
        for node in self.nodes:
            node.update(now_s, dt_s)

    def publish(self, now_s: float) -> int:
        """Send every node's due cyclic frames. Returns the number of frames handed to the bus."""
        # _send, inlined: this runs on every physics step.
        send = self.bus.send
        stats = self.stats
        sent = 0
        for node in self.nodes:
            for msg in node.due(now_s):
                try:
                    send(msg)
                except can.CanError:
                    stats["send_errors"] += 1
                else:
                    stats["tx"] += 1
                sent += 1
        return sent

    def step(self, now_s: float, dt_s: float) -> None:
        """``poll``, ``update`` and ``publish`` in that order: one firmware tick."""
        self.poll(now_s)
        self.update(now_s, dt_s)
        self.publish(now_s)
