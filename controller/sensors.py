"""The sensor board as the controller sees it: range readings, range profile, contact switches,
heartbeat.

Readings are validated here: a range or profile frame whose sequence counter does not advance
is a duplicate or out of order and is rejected; a gap is counted as lost samples. A profile
frame with a beam that is neither "no return" (0xFFFF, 65.535 m) nor a distance in
[0, ``profile_max_m``] (or is NaN) is rejected whole. Filtering of the range (Kalman) belongs to
the learner's range filter, and the height estimate to :mod:`controller.height`, not here.
"""

from __future__ import annotations

import math

PROFILE_NO_RETURN_M = 65.535  # SB_Profile's raw 0xFFFF at 1 mm: no return in that beam
PROFILE_MAX_M = 3.0  # the profile beams' reach [m]; a closer-than-no-return reading beyond it is invalid
_NO_RETURN_FROM_M = PROFILE_NO_RETURN_M - 0.0005  # half a raw step below the sentinel


class SensorLink:
    """The last values from the sensor board (``node_id``) and counts of what arrived.

    ``profile_m``: the last accepted profile, one entry per beam (lowest first), each a distance
    [m] or None (no return); empty until the first profile frame. ``profile_max_m``: the
    beams' reach [m], default 3.0 (readings beyond it, other than "no return", are invalid).
    """

    def __init__(self, node_id: int, profile_max_m: float = PROFILE_MAX_M) -> None:
        if not (math.isfinite(profile_max_m) and 0.0 < profile_max_m < PROFILE_NO_RETURN_M):
            raise ValueError(f"profile_max_m must be in (0, {PROFILE_NO_RETURN_M}) m, got {profile_max_m!r}")
        self.node_id = node_id
        self.profile_max_m = profile_max_m
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
        self.profile_m: tuple[float | None, ...] = ()
        self.profile_seq = -1
        self.profile_t_s = -math.inf
        self.profile_samples = 0
        self.profile_lost = 0
        self.profile_out_of_sequence = 0
        self.profile_invalid = 0
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

    def on_profile(self, values: tuple, now_s: float) -> bool:
        """SB_Profile: (beam_0_m, beam_1_m, beam_2_m, seq). False (the frame is dropped) for a NaN or
        out-of-range beam, or a sequence number that does not advance."""
        *beams, seq = values
        profile: list[float | None] = []
        for b in beams:
            b = float(b)
            if not math.isfinite(b):
                self.profile_invalid += 1
                return False
            if b >= _NO_RETURN_FROM_M:
                profile.append(None)
            elif 0.0 <= b <= self.profile_max_m:
                profile.append(b)
            else:
                self.profile_invalid += 1
                return False
        step = self._advance(self.profile_seq, int(seq))
        if step <= 0:
            self.profile_out_of_sequence += 1
            return False
        self.profile_lost += step - 1
        self.profile_seq = int(seq)
        self.profile_samples += 1
        self.profile_m = tuple(profile)
        self.profile_t_s = now_s
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
