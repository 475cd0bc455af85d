"""Our sensor board (CAN node ``SENSOR_BOARD_NODE_ID``): a noisy range finder with a vertical profile, and two
contact switches.

:class:`SensorBoard` samples a :class:`SensorSource` (the plant's ray cast and contact tests)
and publishes, with the layouts of the DBC:

- ``SB_Range`` every ``range_period_s``: each sample is a dropout with probability
  ``range_dropout_prob`` (Range_Valid=0, Range=0), no target within range when the source returns
  None (likewise invalid), otherwise the true distance plus Gaussian noise of sigma
  ``range_noise_m``, clipped to [0, ``range_max_m``], with Range_Valid=1. Range_Seq counts samples
  (valid or not) modulo 256.
- ``SB_Profile`` with every range sample (same instant, right after SB_Range) while
  ``profile_enabled``: the source's horizontal profile beams (lowest first, at most 3), each
  with the range's model: a dropout with probability ``range_dropout_prob``, no return when the
  source returns None; otherwise the true distance plus Gaussian noise of sigma
  ``range_noise_m``, clipped to [0, ``range_max_m``]. A dropout, no return or an unfitted slot
  is sent as 0xFFFF (65.535 m). Profile_Seq counts profile samples modulo 256. Its random draws
  (two per slot, whatever the outcome) come from a generator of its own, spawned from the
  board's, so switching the profile on or off never changes the range samples.
- ``SB_Contacts`` every ``contacts_period_s``, and at once (in the same :meth:`SensorBoard.due`
  call) when the switches differ from the last frame sent. Contacts_Seq counts contacts frames
  modulo 256 (an RTR reply is a contacts frame too).
- ``SB_Heartbeat`` every ``heartbeat_period_s``: Board_Error 0, Board_State 1 (running),
  Fw_Version, Uptime_ds (wraps after 6553.5 s).

A period of 0 disables that cyclic frame (contact changes are still sent). Every random draw
comes from the ``numpy.random.Generator`` given to the constructor, two draws a range sample
whatever the outcome, so a run is reproducible for a given seed and source.

:meth:`SensorBoard.handle` answers an RTR for any of the four messages with the current values
(the last range or profile sample with its sequence number; the switches as they are now). A data frame
with one of the board's ids is malformed, an unknown id or an extended id is unknown; all are
counted and ignored, and :meth:`SensorBoard.handle` never raises.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final, Protocol

import can
import numpy as np

from protocol.contract import CMD_ID_MASK, SENSOR_BOARD_NODE_ID, BusContract, arbitration_id
from protocol.frame import data_frame
from protocol.compiled import interpreted

# (Final: C constants when compiled, not a module-dict lookup per use)
BOARD_STATE_RUNNING: Final = 1
_SCHEDULE_EPS_S: Final = 1e-9
_RANGE_RESOLUTION_MAX_M = 65.535  # 16 bits at 1 mm
PROFILE_NO_RETURN_M: Final = 65.535  # raw 0xFFFF in SB_Profile: dropout, nothing within range, or no beam
PROFILE_SLOTS: Final = 3  # beams in one SB_Profile frame


class SensorSource(Protocol):
    """What the board measures: supplied by the plant."""

    def range_m(self) -> float | None:
        """True distance along the ray (m), or None when nothing is hit within range."""
        ...

    def range_profile_m(self) -> tuple[float | None, ...]:
        """True distance along each horizontal profile beam (m, lowest first), None: no hit."""
        ...

    def contacts(self) -> tuple[bool, bool]:
        """(foot, shin) contact switches."""
        ...


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class SensorBoardConfig:
    """Configuration of the sensor board.

    ========================  =====  =========  ==================================================
    Field                     Unit   Default    Meaning
    ========================  =====  =========  ==================================================
    ``range_period_s``        s      ``0.02``   SB_Range period (50 Hz); 0 disables
    ``range_noise_m``         m      ``0.02``   standard deviation of the Gaussian range noise
    ``range_dropout_prob``    –      ``0.05``   probability that a sample is a dropout (invalid)
    ``range_max_m``           m      ``3.0``    readings are clipped to [0, range_max_m]
                                                (at most 65.535, the signal's range)
    ``contacts_period_s``     s      ``0.005``  SB_Contacts period (200 Hz); 0 disables the cyclic
                                                frame (changes are still sent)
    ``heartbeat_period_s``    s      ``0.1``    SB_Heartbeat period; 0 disables
    ``fw_version``            –      ``1``      firmware version in SB_Heartbeat, 0..255
    ``profile_enabled``       –      ``True``   send SB_Profile with every range sample
    ========================  =====  =========  ==================================================
    """

    range_period_s: float = 0.02
    range_noise_m: float = 0.02
    range_dropout_prob: float = 0.05
    range_max_m: float = 3.0
    contacts_period_s: float = 0.005
    heartbeat_period_s: float = 0.1
    fw_version: int = 1
    profile_enabled: bool = True

    def __post_init__(self) -> None:
        for name in ("range_period_s", "range_noise_m", "contacts_period_s", "heartbeat_period_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        if not 0.0 <= self.range_dropout_prob <= 1.0:
            raise ValueError(f"range_dropout_prob must be in [0, 1], got {self.range_dropout_prob!r}")
        if not 0.0 < self.range_max_m <= _RANGE_RESOLUTION_MAX_M:
            raise ValueError(f"range_max_m must be in (0, {_RANGE_RESOLUTION_MAX_M}], got {self.range_max_m!r}")
        if not (isinstance(self.fw_version, int) and 0 <= self.fw_version <= 255):
            raise ValueError(f"fw_version must be an integer 0..255, got {self.fw_version!r}")
        if not isinstance(self.profile_enabled, bool):
            raise ValueError(f"profile_enabled must be a bool, got {self.profile_enabled!r}")


class SensorBoard:
    """The sensor board as a CAN node (``node_id``: the bus contract's ``SENSOR_BOARD_NODE_ID``).

    ``stats``: ``{"rx": {name: n}, "tx": {name: n}, "malformed", "unknown", "foreign",
    "internal_errors", "range_samples", "range_invalid", "profile_samples"}``. ``last_range`` is
    the last sample as ``(range_m, valid, seq)``; ``last_profile`` the last profile sample as
    ``(beam_0_m, beam_1_m, beam_2_m, seq)`` (65.535 m: no return).

    ``profile_rng``: the generator of the profile's noise and dropouts; default a child spawned
    from ``rng`` (which leaves ``rng``'s own stream untouched).
    """

    node_id = SENSOR_BOARD_NODE_ID

    def __init__(
        self,
        config: SensorBoardConfig,
        source: SensorSource,
        rng: np.random.Generator,
        contract: BusContract | None = None,
        boot_s: float = 0.0,
        profile_rng: np.random.Generator | None = None,
    ) -> None:
        self.config = config
        self.source = source
        self.rng = rng
        self.profile_rng = profile_rng if profile_rng is not None else rng.spawn(1)[0]
        self.boot_s = boot_s
        contract = contract if contract is not None else BusContract.load()
        self._range_codec = contract.codec("SB_Range")
        self._contacts_codec = contract.codec("SB_Contacts")
        self._hb_codec = contract.codec("SB_Heartbeat")
        self._profile_codec = contract.codec("SB_Profile")
        if self._profile_codec.dlc != 2 * PROFILE_SLOTS + 1 or len(self._profile_codec.signal_names) != PROFILE_SLOTS + 1:
            raise ValueError(f"SB_Profile must carry {PROFILE_SLOTS} u16 beams and a u8 sequence number")
        self._codecs = {c.cmd_id: c for c in (self._range_codec, self._contacts_codec, self._hb_codec,
                                               self._profile_codec)}
        for cmd in self._codecs:
            if contract.sensor_board.get(cmd) is not self._codecs[cmd]:
                raise ValueError(f"sensor board messages must be defined at node {self.node_id} in the DBC")
        self._range_id = arbitration_id(self.node_id, self._range_codec.cmd_id)
        self._contacts_id = arbitration_id(self.node_id, self._contacts_codec.cmd_id)
        self._hb_id = arbitration_id(self.node_id, self._hb_codec.cmd_id)
        self._profile_id = arbitration_id(self.node_id, self._profile_codec.cmd_id)
        names = [c.name for c in self._codecs.values()]
        self.stats: dict[str, Any] = {
            "rx": {n: 0 for n in names},
            "tx": {n: 0 for n in names},
            "malformed": 0,
            "unknown": 0,
            "foreign": 0,
            "internal_errors": 0,
            "range_samples": 0,
            "range_invalid": 0,
            "profile_samples": 0,
        }
        self._tx: dict[str, int] = self.stats["tx"]
        self._range_seq = 0
        self._contacts_seq = 0
        self.last_range: tuple[float, int, int] = (0.0, 0, 0)
        self._profile_seq = 0
        self.last_profile: tuple[float, ...] = (PROFILE_NO_RETURN_M,) * PROFILE_SLOTS + (0,)
        self._last_contacts: tuple[bool, bool] | None = None
        self._next_range = -math.inf
        self._next_contacts = -math.inf
        self._next_hb = -math.inf
        # The config is frozen: its periods, read on every step, as plain attributes.
        self._range_period_s = config.range_period_s
        self._contacts_period_s = config.contacts_period_s
        self._hb_period_s = config.heartbeat_period_s

    # ------------------------------------------------------------------ frames
    def _sample_range(self) -> tuple[float, int, int]:
        cfg = self.config
        u = self.rng.random()
        noise = self.rng.standard_normal()
        true_range = self.source.range_m()
        seq = self._range_seq
        self._range_seq = (seq + 1) & 0xFF
        self.stats["range_samples"] += 1
        if u < cfg.range_dropout_prob or true_range is None or not math.isfinite(true_range):
            self.stats["range_invalid"] += 1
            sample = (0.0, 0, seq)
        else:
            reading = float(true_range) + cfg.range_noise_m * float(noise)
            sample = (min(max(reading, 0.0), cfg.range_max_m), 1, seq)
        self.last_range = sample
        return sample

    def _sample_profile(self) -> tuple[float, ...]:
        cfg = self.config
        rng = self.profile_rng
        u = rng.random(PROFILE_SLOTS)
        noise = rng.standard_normal(PROFILE_SLOTS)
        beams = tuple(self.source.range_profile_m())
        if len(beams) > PROFILE_SLOTS:
            raise ValueError(f"the source has {len(beams)} profile beams; SB_Profile carries {PROFILE_SLOTS}")
        seq = self._profile_seq
        self._profile_seq = (seq + 1) & 0xFF
        self.stats["profile_samples"] += 1
        top = min(cfg.range_max_m, PROFILE_NO_RETURN_M - 0.001)
        values: list[float] = []
        for i in range(PROFILE_SLOTS):
            true_m = beams[i] if i < len(beams) else None
            if u[i] < cfg.range_dropout_prob or true_m is None or not math.isfinite(true_m):
                values.append(PROFILE_NO_RETURN_M)
            else:
                reading = float(true_m) + cfg.range_noise_m * float(noise[i])
                values.append(min(max(reading, 0.0), top))
        sample = (*values, seq)
        self.last_profile = sample
        return sample

    def _profile_frame(self, values: tuple[float, ...]) -> can.Message:
        self._tx[self._profile_codec.name] += 1
        return data_frame(self._profile_id, self._profile_codec.pack(*values))

    def _range_frame(self, values: tuple[float, int, int]) -> can.Message:
        self._tx[self._range_codec.name] += 1
        return data_frame(self._range_id, self._range_codec.pack(*values))

    def _contacts_frame(self, contacts: tuple[bool, bool]) -> can.Message:
        seq = self._contacts_seq
        self._contacts_seq = (seq + 1) & 0xFF
        self._last_contacts = contacts
        self._tx[self._contacts_codec.name] += 1
        data = self._contacts_codec.pack(int(contacts[0]), int(contacts[1]), seq)
        return data_frame(self._contacts_id, data)

    def _heartbeat_frame(self, now_s: float) -> can.Message:
        uptime_ds = int(max(0.0, now_s - self.boot_s) * 10.0 + 1e-6) & 0xFFFF
        data = self._hb_codec.pack(0, BOARD_STATE_RUNNING, self.config.fw_version, uptime_ds * 0.1)
        self._tx[self._hb_codec.name] += 1
        return data_frame(self._hb_id, data)

    def _read_contacts(self) -> tuple[bool, bool]:
        foot, shin = self.source.contacts()
        return bool(foot), bool(shin)

    # ------------------------------------------------------------------ node interface
    def update(self, now_s: float, dt_s: float) -> None:
        """Nothing to do between frames: sampling happens when a frame is due."""

    def due(self, now_s: float) -> list[can.Message]:
        """Frames due at ``now_s``: range sample (and profile), contacts (cyclic or changed), heartbeat."""
        out: list[can.Message] = []
        period = self._range_period_s
        if period > 0.0 and now_s >= self._next_range - _SCHEDULE_EPS_S:
            nxt = self._next_range + period
            self._next_range = nxt if nxt > now_s else now_s + period
            out.append(self._range_frame(self._sample_range()))
            if self.config.profile_enabled:
                out.append(self._profile_frame(self._sample_profile()))
        contacts = self._read_contacts()
        period = self._contacts_period_s
        cyclic = period > 0.0 and now_s >= self._next_contacts - _SCHEDULE_EPS_S
        if cyclic:
            nxt = self._next_contacts + period
            self._next_contacts = nxt if nxt > now_s else now_s + period
        if cyclic or contacts != self._last_contacts:
            out.append(self._contacts_frame(contacts))
        period = self._hb_period_s
        if period > 0.0 and now_s >= self._next_hb - _SCHEDULE_EPS_S:
            nxt = self._next_hb + period
            self._next_hb = nxt if nxt > now_s else now_s + period
            out.append(self._heartbeat_frame(now_s))
        return out

    def handle(self, msg: can.Message, now_s: float) -> list[can.Message]:
        """Answer an RTR for SB_Range / SB_Profile / SB_Contacts / SB_Heartbeat; count and ignore
        anything else."""
        try:
            return self._handle(msg, now_s)
        except Exception:  # noqa: BLE001 - a simulated node must never bring the bus down
            self.stats["internal_errors"] += 1
            return []

    def _handle(self, msg: Any, now_s: float) -> list[can.Message]:
        # msg: Any, read without mypyc's type checks: a node must survive any frame (a numpy.bool flag too)
        if msg.is_extended_id or msg.is_error_frame:
            self.stats["unknown"] += 1
            return []
        arb = msg.arbitration_id
        if arb >> 5 != self.node_id:
            self.stats["foreign"] += 1
            return []
        codec = self._codecs.get(arb & CMD_ID_MASK)
        if codec is None:
            self.stats["unknown"] += 1
            return []
        self.stats["rx"][codec.name] += 1
        if not msg.is_remote_frame:
            self.stats["malformed"] += 1
            return []
        if codec is self._range_codec:
            return [self._range_frame(self.last_range)]
        if codec is self._profile_codec:
            return [self._profile_frame(self.last_profile)]
        if codec is self._contacts_codec:
            return [self._contacts_frame(self._read_contacts())]
        return [self._heartbeat_frame(now_s)]
