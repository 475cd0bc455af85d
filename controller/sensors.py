"""The sensor board as the controller sees it: range readings, contact switches, heartbeat.

Readings are validated here: a range frame whose sequence counter does not advance is a
duplicate or out of order and is rejected; a gap is counted as lost samples. Filtering of the
range (Kalman) belongs to the learner's range filter, not here.
"""

from __future__ import annotations

import math


class SensorLink:
    def __init__(self, node_id: int) -> None:
        self.node_id = node_id
        self.range_m = math.nan
        self.range_valid = False
        self.range_seq = -1
        self.range_t_s = -math.inf
        self.range_samples = 0
        self.range_lost = 0
        self.range_out_of_sequence = 0
        self.foot = False
        self.shin = False
        self.contacts_seq = -1
        self.contacts_t_s = -math.inf
        self.contacts_lost = 0
        self.heartbeat_t_s = -math.inf
        self.board_error = 0
        self.board_state = 0

    @staticmethod
    def _advance(last: int, seq: int) -> int:
        """Frames between the last sequence number and this one (1 = the next; <= 0 = stale)."""
        if last < 0:
            return 1
        delta = (seq - last) % 256
        return delta if delta < 128 else delta - 256

    def on_range(self, values: tuple, now_s: float) -> bool:
        range_m, valid, seq = values
        step = self._advance(self.range_seq, int(seq))
        if step <= 0:
            self.range_out_of_sequence += 1
            return False
        self.range_lost += step - 1
        self.range_seq = int(seq)
        self.range_samples += 1
        self.range_valid = bool(valid) and math.isfinite(range_m)
        self.range_m = float(range_m) if self.range_valid else math.nan
        self.range_t_s = now_s
        return True

    def on_contacts(self, values: tuple, now_s: float) -> bool:
        foot, shin, seq = values
        step = self._advance(self.contacts_seq, int(seq))
        if step <= 0:
            return False
        self.contacts_lost += step - 1
        self.contacts_seq = int(seq)
        self.foot = bool(foot)
        self.shin = bool(shin)
        self.contacts_t_s = now_s
        return True

    def on_heartbeat(self, values: tuple, now_s: float) -> bool:
        error, state, _fw, _uptime = values
        self.board_error = int(error)
        self.board_state = int(state)
        self.heartbeat_t_s = now_s
        return True
