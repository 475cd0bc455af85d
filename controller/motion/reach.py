"""The tallest obstacle this leg can clear at all: a limit of the leg, not of any reflex or learner.

:func:`max_clearable_height_m` finds it from the leg's own parameters; :func:`check_height`
refuses a taller obstacle with the reason (for the experiment's configuration to call).

The question: over a block of depth ``d`` across the rail, can the foot pass in one swing without
any link touching it? The answer is the highest the foot's lowest point can be while the foot
crosses the block, under these rules (each with its reason):

1. **Planar, rigid leg** in the hip frame of :mod:`controller.motion.kinematics` (x forward, z up,
   angles from vertical, knee <= 0): thigh ``l1``, shank ``l2``, foot sphere of radius ``r`` at
   the shank's end, hip axis ``H`` above the ground (:class:`~controller.motion.kinematics.LegGeometry`).
   The foot's lowest point is ``H + z_foot - r``.
2. **Joint angles inside the controller's commanded limits** (``min_rad``/``max_rad`` of the
   axes given, :func:`controller.config.default_axes` for the controller's): the controller never commands beyond them
   (the rig's hard stops lie 0.05 rad outside). The knee is also kept at or below the bend at
   which :func:`~controller.motion.kinematics.inverse` stops stretching the leg
   (:data:`~controller.motion.kinematics.REACH` of thigh + shank): every foot target the
   controller sends goes through that inverse, so a straighter knee is never commanded.
3. **The foot is the leg's lowest part**: in a pose held over the block, no part of the thigh's or
   the shank's collision box (widths in :class:`LegLoads`; the shank's box ends
   ``shank_box_end_m`` below the knee, as in the rig's URDF) is lower than the foot's lowest
   point, so a block the foot clears, every link clears.
4. **Static torque within the effort limit, with a margin for dynamics**: the gravity torque
   at each joint in the held pose is at most ``(1 - dynamics_margin)`` of the joint's effort
   limit ``Kt x current_limit_a x gear_ratio`` (the driver's current clamp seen at the joint).
   The default margin 0.5 keeps half the torque for accelerating the leg up and stopping it.
5. **One swing** (the CPG's longest burst ``burst_max_s``, the carriage at the gait's
   ``ground_speed_m_s``): the swing starts with the leg where stance leaves it (the foot at
   ``foot_ahead_m - ground_speed_m_s x stance_s``) behind the block, and ends with the foot on
   the ground beyond it, at most ``sqrt(R^2 - (H - r)^2)`` ahead of the hip (``R``: the
   kinematics' reach). While the foot's world x (carriage + x) crosses the block's depth plus
   the foot's diameter, the foot stays at poses of rules 1-4 at least ``h`` high; before, no
   part of the leg below ``h`` may be past the block's near edge: not the foot, nor the knee,
   which starts low and ahead of the hip and, swinging forward, rises to ``h`` only once the
   thigh is steep enough; after, the foot may not slip back over the far edge while it comes
   down (:func:`shortest_swing_s`). Joints move instantly here, so this is an upper bound: the
   result states the swing time it needs (``swing_needed_s``), the rest being the lift's and the
   descent's. A pose held far ahead (the leg stretched forward, up to 0.27 m) must come back
   0.25 m to a reachable touchdown without sliding back over the block: at 0.5 m/s that alone is
   0.5 s. A pose held far behind (the leg folded back, 0.275 m) is reached only by moving the
   foot back 0.32 m first: 0.64 s.

Not modelled: joint speed and the dynamics of the lift and the descent (beyond the torque
margin); the connection, in joint space, of poses at neighbouring foot x (the envelope of rule 5
is taken per 2 mm of foot x over a 300 x 300 grid of the joint ranges); the range-sensor boom, a
visual only in the rig's model; contact friction. Link masses and centres of mass are
:class:`LegLoads` (the controller's model of the rig's URDF, checked against PyBullet in
``tests/controller/motion/test_reach.py``).

The default rig (depth 0.10 m, rail 0.5 m/s, burst at most 0.60 s): **0.223 m**, the leg tucked:
the knee at its -2.15 rad limit, the hip at 0.76 rad, the foot 0.07 m behind the hip; with
instant joints that swing takes 0.597 of the 0.60 s (the block's near edge may start only past
where the knee rises above it, 0.11 m ahead of the hip; it then travels to the tucked foot, and
on 0.14 m). Static torques 0.63 N m (hip) and 0.49 N m (knee) of 9.96 N m: torque does not bind;
the knee's flexion limit and the swing's length do. The same leg held, swing aside, reaches
0.275 m (folded back); a 1.0 s burst would allow that. Other depths: 0.236 m at 0.04 m, 0.220 m
at 0.12 m, 0.216 m at 0.20 m. In PyBullet a plain joint-space swing (gravity-compensated PD
within the effort limits) clears 0.18 m in one 0.6 s swing and found no way over 0.20 m: the
true limit lies between. See ``docs/leg_limits.md``.

Pure Python: not a hot module (it runs once, when an experiment is configured).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Protocol

from controller.motion.cpg import CpgConfig
from controller.motion.gait import GaitConfig
from controller.motion.kinematics import REACH, LegGeometry, forward, inverse
from controller.settings.schema import check_settings, setting

GRAVITY_M_S2 = 9.81
"""Standard gravity [m/s^2] (the plant's default, ``RigConfig.gravity_m_s2``)."""

_GRID_STEPS = 300
"""Grid intervals per joint range (the ends included, where a joint limit binds)."""
_BIN_M = 0.002
"""Width of the foot-x bins of the height envelope [m]."""
_LIMIT_TOL_RAD = 1e-9
_TIE_M = 0.002
"""A link within this of the foot's lowest point counts as binding rule 3 (the grid's resolution)."""


@dataclass(frozen=True)
class LegLoads:
    """What the reach computation needs beyond the geometry: link masses, where their centres of
    mass lie, the collision boxes' widths, and the motors' torque constant (the controller has no
    other record of them; the rig's URDF ``urdf/gait_rig.urdf`` and the simulated motor's
    ``torque_constant_nm_per_a`` are the source, and the tests compare)."""

    thigh_mass_kg: float = setting(0.60, "kg", 0.0, 100.0, "thigh mass")
    thigh_com_m: float = setting(0.11, "m", 0.0, 2.0, "thigh centre of mass below the hip, along the thigh")
    shank_mass_kg: float = setting(0.35, "kg", 0.0, 100.0, "shank mass")
    shank_com_m: float = setting(0.11, "m", 0.0, 2.0, "shank centre of mass below the knee, along the shank")
    foot_mass_kg: float = setting(0.05, "kg", 0.0, 100.0, "foot mass, at the foot sphere's centre")
    thigh_width_m: float = setting(0.03, "m", 0.0, 0.5, "thigh collision box width (x and y)")
    shank_width_m: float = setting(0.025, "m", 0.0, 0.5, "shank collision box width (x and y)")
    shank_box_start_m: float = setting(0.01, "m", 0.0, 2.0, "shank collision box's top, below the knee")
    shank_box_end_m: float = setting(0.22, "m", 0.0, 2.0, "shank collision box's bottom, below the knee")
    motor_torque_constant_nm_per_a: float = setting(0.083, "N m/A", 0.001, 10.0, "motor Kt (8.27 / KV)")

    def __post_init__(self) -> None:
        check_settings(self, "loads")


@dataclass(frozen=True)
class ClearanceLimit:
    """The result of :func:`max_clearable_height_m` (hip frame, SI units).

    ``height_m``: the tallest obstacle; ``hip_rad``, ``knee_rad``: the pose that sets it (the
    lowest the foot is while over the block), ``foot_x_m``, ``foot_z_m`` its foot centre relative
    to the hip, ``hip_torque_nm``, ``knee_torque_nm`` its static torques (positive forward) and
    ``hip_effort_nm``, ``knee_effort_nm`` the effort limits. ``cross_from_x_m``..``cross_to_x_m``:
    the foot's x while over the block; ``swing_needed_s``: the shortest swing that crossing allows
    with joints moving instantly (rule 5), ``swing_max_s`` the longest burst. ``held_height_m``:
    the highest the foot can be held at all, swing time aside (rules 1-4), at ``held_x_m``.
    ``reason``: what binds, in words."""

    height_m: float
    hip_rad: float
    knee_rad: float
    foot_x_m: float
    foot_z_m: float
    hip_torque_nm: float
    knee_torque_nm: float
    hip_effort_nm: float
    knee_effort_nm: float
    cross_from_x_m: float
    cross_to_x_m: float
    swing_needed_s: float
    swing_max_s: float
    held_height_m: float
    held_x_m: float
    reason: str


class JointAxis(Protocol):
    """What this module reads of an axis's configuration (:class:`controller.io.axis.AxisConfig`
    has it; passed in, so that this package imports no bus module)."""

    name: str
    min_rad: float
    max_rad: float
    current_limit_a: float
    gear_ratio: float


def _axis(axes: tuple[JointAxis, ...], name: str) -> JointAxis:
    for a in axes:
        if a.name == name:
            return a
    raise ValueError(f"no {name} axis among {[a.name for a in axes]}")


def effort_nm(axis: JointAxis, loads: LegLoads) -> float:
    """The joint's effort limit [N m]: the driver's current clamp through Kt and the gear."""
    return loads.motor_torque_constant_nm_per_a * axis.current_limit_a * axis.gear_ratio


def knee_at_reach_rad(geometry: LegGeometry, reach: float = REACH) -> float:
    """The knee (<= 0) at which the foot is ``reach`` x (thigh + shank) from the hip: the
    straightest knee :func:`~controller.motion.kinematics.inverse` commands."""
    l1, l2 = geometry.thigh_m, geometry.shank_m
    r = (l1 + l2) * reach
    cos_knee = (r * r - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    return -math.acos(max(-1.0, min(1.0, cos_knee)))


def static_torques_nm(geometry: LegGeometry, loads: LegLoads, hip_rad: float, knee_rad: float,
                      gravity_m_s2: float = GRAVITY_M_S2) -> tuple[float, float]:
    """Gravity torques (hip, knee) [N m] the joints must hold in a pose at rest, positive in the
    joints' positive (forward) direction: each mass's weight times its lever arm (horizontal
    distance ahead of the joint)."""
    l1 = geometry.thigh_m
    sh, sk = math.sin(hip_rad), math.sin(hip_rad + knee_rad)
    knee_x = l1 * sh
    shank_com_x = knee_x + loads.shank_com_m * sk
    foot_x = knee_x + geometry.shank_m * sk
    # a weight ahead of a joint swings it back towards hanging: holding it takes a forward torque
    knee_moment = loads.shank_mass_kg * (shank_com_x - knee_x) + loads.foot_mass_kg * (foot_x - knee_x)
    hip_moment = loads.thigh_mass_kg * loads.thigh_com_m * sh + loads.shank_mass_kg * shank_com_x \
        + loads.foot_mass_kg * foot_x
    return gravity_m_s2 * hip_moment, gravity_m_s2 * knee_moment


def _box_extent(ax: float, az: float, bx: float, bz: float, width_m: float) -> tuple[float, float]:
    """(lowest z, front-most x) of a box of square section ``width_m`` whose axis runs from
    (ax, az) to (bx, bz) in the x-z plane: its corners are the axis's ends +- half the width along
    the axis's normal, whose z part is the axis's x extent over its length (and x part the z's)."""
    length = math.hypot(bx - ax, bz - az)
    half = 0.5 * width_m
    return min(az, bz) - half * abs(bx - ax) / length, max(ax, bx) + half * abs(bz - az) / length


def link_extent(geometry: LegGeometry, loads: LegLoads, hip_rad: float, knee_rad: float) -> tuple[float, float]:
    """(lowest z, front-most x) over the thigh's and the shank's collision boxes in a pose, in the
    hip frame [m]."""
    l1 = geometry.thigh_m
    kx, kz = l1 * math.sin(hip_rad), -l1 * math.cos(hip_rad)
    s, c = math.sin(hip_rad + knee_rad), math.cos(hip_rad + knee_rad)
    thigh = _box_extent(0.0, 0.0, kx, kz, loads.thigh_width_m)
    shank = _box_extent(kx + loads.shank_box_start_m * s, kz - loads.shank_box_start_m * c,
                        kx + loads.shank_box_end_m * s, kz - loads.shank_box_end_m * c, loads.shank_width_m)
    return min(thigh[0], shank[0]), max(thigh[1], shank[1])


def _grid(lo: float, hi: float, steps: int) -> list[float]:
    return [lo + (hi - lo) * i / steps for i in range(steps)] + [hi]


def shortest_swing_s(lo_m: float, hi_m: float, start_x_m: float, land_x_m: float, carry_m: float,
                     speed_m_s: float) -> tuple[float, float, float]:
    """Rule 5: the shortest swing that carries the foot over the block while the foot stays in
    ``[lo_m, hi_m]`` (hip-frame x where it is high enough), joints moving instantly; returns
    (time [s], x where the crossing starts, x where it ends).

    The swing starts with the foot at ``start_x_m`` behind the block and ends with it on the
    ground at most ``land_x_m`` ahead of the hip, beyond the block. In the world the foot is at
    carriage + x. Three parts, each at least zero: before the crossing, the foot may not pass the
    block's near edge low, so reaching x = ``a`` takes ``(start - a) / v``; the crossing, the
    world x gaining ``carry_m`` while the foot goes from ``a`` to ``b``, takes
    ``(carry - (b - a)) / v``; after it, the foot may not slip back over the far edge while it
    comes down, so returning from ``b`` to the landing takes ``(b - land) / v``. The sum is
    convex and piecewise linear in (a, b): its minimum lies where two of its break lines or the
    bounds meet, and only those points are tried."""
    v = speed_m_s

    def clip(x: float) -> float:
        return lo_m if x < lo_m else (hi_m if x > hi_m else x)

    best = (math.inf, lo_m, lo_m)
    for a in {clip(x) for x in (lo_m, hi_m, start_x_m, lo_m - carry_m, hi_m - carry_m, land_x_m - carry_m,
                                land_x_m)}:
        for b in {clip(x) for x in (lo_m, hi_m, land_x_m, a + carry_m, a)}:
            if b < a:
                continue
            t = (max(0.0, (start_x_m - a) / v) + max(0.0, (carry_m - (b - a)) / v)
                 + max(0.0, (b - land_x_m) / v))
            if t < best[0]:
                best = (t, a, b)
    return best


@functools.lru_cache(maxsize=64)  # ~0.5 s of search; an experiment's configuration may ask often
def max_clearable_height_m(
    depth_m: float = 0.10,
    *,
    geometry: LegGeometry = LegGeometry(),
    axes: tuple[JointAxis, ...],
    loads: LegLoads = LegLoads(),
    cpg: CpgConfig = CpgConfig(),
    gait: GaitConfig = GaitConfig(),
    reach: float = REACH,
    dynamics_margin: float = 0.5,
    gravity_m_s2: float = GRAVITY_M_S2,
) -> ClearanceLimit:
    """The tallest obstacle of depth ``depth_m`` [m] the leg can pass its foot over in one swing
    without any link touching it (the rules are the module's docstring). ``axes``: the leg's
    axis configurations (the controller's are :func:`controller.config.default_axes`). Defaults:
    the controller's configurations (the longest
    swing ``cpg.burst_max_s``; the rail speed ``gait.ground_speed_m_s``; the swing's start
    ``gait.foot_ahead_m - gait.ground_speed_m_s * cpg.stance_s``, where stance leaves the foot).

    Raises ValueError when no height is clearable."""
    if not 0.0 < depth_m < 10.0:
        raise ValueError(f"the obstacle's depth must be in (0, 10) m, got {depth_m!r}")
    if not 0.0 <= dynamics_margin < 1.0:
        raise ValueError(f"dynamics_margin must be in [0, 1), got {dynamics_margin!r}")
    v, swing_max_s = gait.ground_speed_m_s, cpg.burst_max_s
    if v <= 0.0:
        raise ValueError(f"the rail speed must be above 0 m/s to carry the leg over anything, got {v!r}")
    r = geometry.foot_radius_m
    carry_m = depth_m + 2.0 * r
    start_x_m = gait.foot_ahead_m - v * cpg.stance_s
    ground_z_m = -(geometry.hip_height_m - r)
    reach_m = (geometry.thigh_m + geometry.shank_m) * reach
    land_x_m = math.sqrt(max(0.0, reach_m * reach_m - ground_z_m * ground_z_m))
    hip_start = inverse(geometry, start_x_m, ground_z_m - gait.stance_press_m)[0]
    hip_axis, knee_axis = _axis(axes, "hip"), _axis(axes, "knee")
    hip_effort, knee_effort = effort_nm(hip_axis, loads), effort_nm(knee_axis, loads)
    knee_reach = knee_at_reach_rad(geometry, reach)
    hip_lo, hip_hi = hip_axis.min_rad, hip_axis.max_rad
    knee_lo, knee_hi = knee_axis.min_rad, min(knee_axis.max_rad, knee_reach)
    if knee_hi < knee_lo:
        raise ValueError(f"the knee's limits [{knee_axis.min_rad:g}, {knee_axis.max_rad:g}] rad leave no bend "
                         f"inside the kinematics' reach ({knee_reach:.4f} rad)")
    allowed = 1.0 - dynamics_margin

    # rules 1-4: the highest foot (lowest point above the ground) over the poses at each foot x
    envelope: dict[int, tuple[float, float, float]] = {}
    for hip in _grid(hip_lo, hip_hi, _GRID_STEPS):
        for knee in _grid(knee_lo, knee_hi, _GRID_STEPS):
            x, z = forward(geometry, hip, knee)
            if link_extent(geometry, loads, hip, knee)[0] < z - r:
                continue  # a link below the foot
            th, tk = static_torques_nm(geometry, loads, hip, knee, gravity_m_s2)
            if abs(th) > allowed * hip_effort or abs(tk) > allowed * knee_effort:
                continue
            h = geometry.hip_height_m + z - r
            k = round(x / _BIN_M)
            if k not in envelope or h > envelope[k][0]:
                envelope[k] = (h, hip, knee)
    if not envelope:
        raise ValueError("no pose inside the joint limits holds the foot lowest with the static torques "
                         f"within {allowed:.0%} of the effort limits")
    keys = sorted(envelope)
    held_k = max(keys, key=lambda k: envelope[k][0])

    # rule 5: the tallest h for which a run of neighbouring x bins, all at least h high, admits a swing
    found = None
    for h in sorted({e[0] for e in envelope.values()}, reverse=True):
        runs: list[list[int]] = []
        run: list[int] = []
        for k in keys:
            if envelope[k][0] >= h and (not run or k == run[-1] + 1):
                run.append(k)
            elif envelope[k][0] >= h:
                runs.append(run)
                run = [k]
            elif run:
                runs.append(run)
                run = []
        if run:
            runs.append(run)
        # the knee, low and ahead of the hip where stance ends, rises to h only once the thigh is
        # steep enough: swinging forward, it must pass that x before the block's near edge gets there
        cos_rise = (geometry.hip_height_m - h - 0.5 * loads.thigh_width_m) / geometry.thigh_m
        knee_rise_x_m = (geometry.thigh_m * math.sqrt(1.0 - cos_rise * cos_rise) + 0.5 * loads.thigh_width_m
                         if -1.0 < cos_rise < 1.0 and hip_start < math.acos(cos_rise) else None)
        for run in runs:
            start = start_x_m
            # only where every pose of the run has the knee ahead of its start (a mixed run is let
            # off: the bound stays an upper one)
            if knee_rise_x_m is not None and all(envelope[k][1] > hip_start for k in run):
                start = max(start, knee_rise_x_m - r)
            # a bin stands for the x within half a bin of its centre
            t, a, b = shortest_swing_s((run[0] - 0.5) * _BIN_M, (run[-1] + 0.5) * _BIN_M, start, land_x_m,
                                       carry_m, v)
            if t <= swing_max_s and (found is None or t < found[1]):
                found = (h, t, a, b, run)
        if found is not None:
            break
    if found is None:
        raise ValueError(f"no swing of at most {swing_max_s:g} s at {v:g} m/s carries the foot over a {depth_m:g} m "
                         f"deep obstacle and lands it")
    h, t, a, b, run = found
    inside = [k for k in run if (k + 0.5) * _BIN_M >= a and (k - 0.5) * _BIN_M <= b] or run
    k_low = min(inside, key=lambda k: envelope[k][0])
    _, hip, knee = envelope[k_low]
    x, z = forward(geometry, hip, knee)
    th, tk = static_torques_nm(geometry, loads, hip, knee, gravity_m_s2)

    binding = []
    for name, q, lo, hi in (("hip", hip, hip_lo, hip_hi), ("knee", knee, knee_lo, knee_hi)):
        for bound in (lo, hi):
            if abs(q - bound) < _LIMIT_TOL_RAD:
                stretched = name == "knee" and bound == knee_reach
                binding.append(f"the {name}'s {bound:.3f} rad limit (the kinematics' reach, {reach:g} of thigh + "
                               f"shank)" if stretched else f"the {name}'s {bound:g} rad limit")
    if abs(th) > 0.99 * allowed * hip_effort or abs(tk) > 0.99 * allowed * knee_effort:
        binding.append(f"the static torque at {allowed:.0%} of the effort limit")
    if link_extent(geometry, loads, hip, knee)[0] < z - r + _TIE_M:
        binding.append("the shank or the thigh as low as the foot")
    what = " and ".join(binding) if binding else "the leg's geometry"
    verb = "hold" if len(binding) > 1 else "holds"
    held_h = envelope[held_k][0]
    swing = (f"; the foot can be held up to {held_h:.3f} m (at x = {held_k * _BIN_M:+.2f} m), but from there "
             f"no swing of at most {swing_max_s:g} s at {v:g} m/s carries it over and lands it" if held_h > h else "")
    reason = (f"{what} {verb} the foot's lowest point at most {h:.3f} m above the ground where one swing "
              f"({t:.2f} s of at most {swing_max_s:g} s, the carriage at {v:g} m/s) can carry it over the block and "
              f"land it (foot x {a:+.2f}..{b:+.2f} m from the hip; {geometry.thigh_m:g} + {geometry.shank_m:g} m "
              f"links, hip {geometry.hip_height_m:g} m up){swing}")
    return ClearanceLimit(height_m=h, hip_rad=hip, knee_rad=knee, foot_x_m=x, foot_z_m=z,
                          hip_torque_nm=th, knee_torque_nm=tk, hip_effort_nm=hip_effort, knee_effort_nm=knee_effort,
                          cross_from_x_m=a, cross_to_x_m=b, swing_needed_s=t, swing_max_s=swing_max_s,
                          held_height_m=held_h, held_x_m=held_k * _BIN_M, reason=reason)


def max_lift_amplitude(**leg) -> float:
    """The highest lift amplitude (x the gait's step height) the leg allows: the highest its foot
    can be held at all within its joint and torque limits (``held_height_m`` of
    :func:`max_clearable_height_m`, whose keyword arguments ``leg`` are, ``axes`` required) over
    ``gait.step_height_m``. A lift beyond it asks for poses the joints cannot take."""
    gait = leg.get("gait", GaitConfig())
    return max_clearable_height_m(**leg).held_height_m / gait.step_height_m


def check_height(height_m: float, depth_m: float = 0.10, **leg) -> None:
    """Refuse an obstacle taller than the leg can clear at all (ValueError with the reason);
    ``leg``: :func:`max_clearable_height_m`'s keyword arguments (``axes`` required)."""
    limit = max_clearable_height_m(depth_m, **leg)
    if height_m > limit.height_m:
        raise ValueError(f"{height_m:.3f} m is above the leg's {limit.height_m:.3f} m limit for a "
                         f"{depth_m:g} m deep obstacle: {limit.reason}")


__all__ = ["JointAxis", "LegLoads", "ClearanceLimit", "max_clearable_height_m", "max_lift_amplitude",
           "check_height", "static_torques_nm",
           "link_extent", "knee_at_reach_rad", "effort_nm", "shortest_swing_s", "GRAVITY_M_S2"]
