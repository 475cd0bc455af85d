"""The sensor board as the controller sees it: range readings, range profile, contact switches,
heartbeat.

Readings are validated here, and a frame is applied whole or not at all: a handler returns
False (the frame is counted ``invalid`` and dropped by :class:`controller.io.bus.BusIO`) for

- a range, profile or contacts frame whose sequence counter does not advance (a duplicate or
  out of order; a gap is counted as lost samples), or jumps by more than ``MAX_SEQ_GAP`` (16)
  either way until the stream's next frame confirms the jump (a corrupted counter costs one
  frame; a restarted board is followed after two);
- a range frame whose Range_Valid is neither 0 nor 1, or which is valid with a range that is
  NaN or outside [0, ``range_max_m``] (the sensor's reach; the board clips to it);
- a profile frame with a beam that is neither "no return" (0xFFFF, 65.535 m) nor a distance in
  [0, ``profile_max_m``] (or is NaN): rejected whole;
- a contacts frame with a switch that is neither 0 nor 1.

A switch that closes and opens again between two control ticks is not lost: the board sends a
contacts frame at each change, and :meth:`SensorLink.take_contacts` answers closed for a switch
that any accepted frame since the last call said closed (a latch the loop reads once a tick). The
reflexes then hear a 1 ms brush of the shin as a real switch's interrupt latch would.

Values are checked before the sequence number, so a bad frame does not move the counter.
Filtering of the range (Kalman) belongs to the learner's range filter, and the height estimate
to :mod:`controller.stepping.height`, not here.
"""

from __future__ import annotations

import math
from typing import Final

# (Final: C constants when compiled, not a module-dict lookup per use)
PROFILE_NO_RETURN_M: Final = 65.535  # SB_Profile's raw 0xFFFF at 1 mm: no return in that beam
PROFILE_MAX_M: Final = 3.0  # the profile beams' reach [m]; a closer-than-no-return reading beyond it is invalid
RANGE_MAX_M: Final = 3.0  # the range finder's reach [m] (the board clips its readings to it)
_NO_RETURN_FROM_M: Final = PROFILE_NO_RETURN_M - 0.0005  # half a raw step below the sentinel
_HALF_MM: Final = 0.0005  # half a raw step of SB_Range / SB_Profile (1 mm): decoding rounds within it
MAX_SEQ_GAP: Final = 16  # a sequence number further from the last than this is believed only once confirmed


class SensorLink:
    """The last values from the sensor board (``node_id``) and counts of what arrived.

    ``profile_m``: the last accepted profile, one entry per beam (lowest first), each a distance
    [m] or None (no return); empty until the first profile frame. ``profile_max_m``: the
    beams' reach [m], default 3.0 (readings beyond it, other than "no return", are invalid).
    ``range_max_m``: the range finder's reach [m], default 3.0 (a valid reading beyond it is
    invalid). ``*_invalid`` and ``*_out_of_sequence`` count the frames each check rejected.
    """

    def __init__(self, node_id: int, profile_max_m: float = PROFILE_MAX_M, range_max_m: float = RANGE_MAX_M) -> None:
        if not (math.isfinite(profile_max_m) and 0.0 < profile_max_m < PROFILE_NO_RETURN_M):
            raise ValueError(f"profile_max_m must be in (0, {PROFILE_NO_RETURN_M}) m, got {profile_max_m!r}")
        if not (math.isfinite(range_max_m) and 0.0 < range_max_m <= PROFILE_NO_RETURN_M):
            raise ValueError(f"range_max_m must be in (0, {PROFILE_NO_RETURN_M}] m, got {range_max_m!r}")
        self.node_id = node_id
        self.profile_max_m = profile_max_m
        self.range_max_m = range_max_m
        self._range_top_m = range_max_m + _HALF_MM
        self.range_m = math.nan
        self.range_valid = False
        self.range_seq = -1
        self.range_t_s = -math.inf
        self.range_samples = 0
        self.range_lost = 0
        self.range_out_of_sequence = 0
        self.range_invalid = 0
        self.foot = False
        self.shin = False
        self._foot_latched = False  # closed in some frame since take_contacts last ran
        self._shin_latched = False
        self.contacts_seq = -1
        self.contacts_t_s = -math.inf
        self.contacts_lost = 0
        self.contacts_out_of_sequence = 0
        self.contacts_invalid = 0
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
        self._jumps: dict[str, int] = {}  # per stream: the sequence number of a jump not yet believed

    def _advance(self, stream: str, last: int, seq: int) -> int:
        """Frames between the last sequence number of ``stream`` and this one (1 = the next;
        <= 0 = stale: rejected).

        A jump of more than :data:`MAX_SEQ_GAP` either way is a corrupted counter or a board that
        restarted. It is not believed (0: rejected) until the stream's next frame follows it,
        which then resynchronises the stream (1). So one corrupted counter costs one frame, not
        the 100-odd genuine frames that would look stale behind a counter that jumped ahead.
        """
        if last < 0:
            return 1
        delta = (seq - last) % 256
        step = delta if delta < 128 else delta - 256
        jumps = self._jumps
        if -MAX_SEQ_GAP < step <= MAX_SEQ_GAP:
            if step > 0 and stream in jumps:
                del jumps[stream]
            return step
        candidate = jumps.get(stream)
        jumps[stream] = seq
        if candidate is not None and (seq - candidate) % 256 == 1:
            del jumps[stream]
            return 1
        return 0

    def on_range(self, values: tuple, now_s: float) -> bool:
        """SB_Range: (range_m, valid, seq). False (dropped) for a Range_Valid other than 0/1, a
        valid range that is NaN or outside [0, range_max_m], or a sequence number that does not
        advance. An invalid sample (Range_Valid 0: a dropout) is accepted, with no range."""
        range_m, valid, seq = values
        if valid:
            if valid != 1 or not 0.0 <= range_m <= self._range_top_m:  # False for NaN too
                self.range_invalid += 1
                return False
        step = self._advance("range", self.range_seq, int(seq))
        if step <= 0:
            self.range_out_of_sequence += 1
            return False
        self.range_lost += step - 1
        self.range_seq = int(seq)
        self.range_samples += 1
        self.range_valid = bool(valid)
        self.range_m = float(range_m) if valid else math.nan
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
        step = self._advance("profile", self.profile_seq, int(seq))
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
        """SB_Contacts: (foot, shin, seq). False (dropped) for a switch other than 0/1 or a
        sequence number that does not advance."""
        foot, shin, seq = values
        if foot not in (0, 1) or shin not in (0, 1):
            self.contacts_invalid += 1
            return False
        step = self._advance("contacts", self.contacts_seq, int(seq))
        if step <= 0:
            self.contacts_out_of_sequence += 1
            return False
        self.contacts_lost += step - 1
        self.contacts_seq = int(seq)
        self.foot = bool(foot)
        self.shin = bool(shin)
        if self.foot:
            self._foot_latched = True
        if self.shin:
            self._shin_latched = True
        self.contacts_t_s = now_s
        return True

    def take_contacts(self) -> tuple[bool, bool]:
        """(foot, shin): each closed if it is closed now or any contacts frame accepted since the
        last call said so (then the latch is empty again: a brush is heard once, and an opening
        is heard the tick its frame arrives)."""
        foot = self.foot or self._foot_latched
        shin = self.shin or self._shin_latched
        self._foot_latched = False
        self._shin_latched = False
        return foot, shin

    def on_heartbeat(self, values: tuple, now_s: float) -> bool:
        error, state, _fw, _uptime = values
        self.board_error = int(error)
        self.board_state = int(state)
        self.heartbeat_t_s = now_s
        return True
