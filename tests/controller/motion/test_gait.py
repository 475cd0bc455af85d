"""The swing's foot path: the half-sine up to ``tuck_from_amplitude`` (3.0: above the hardwired lift
1.9 and the 2.8 the improved learner reaches for 0.16 m), the tucked path above."""

from __future__ import annotations

import math

from controller.config import default_axes
from controller.motion.cpg import CpgConfig, CpgOutput
from controller.motion.gait import FootTrajectory, GaitConfig, tuck_fraction
from controller.motion.kinematics import LegGeometry, inverse

GAIT, CPG, GEOMETRY = GaitConfig(), CpgConfig(), LegGeometry()
PHASES = [i / 200 for i in range(201)]


def swing(phase: float, drive: float) -> CpgOutput:
    return CpgOutput(onset=False, flexing=True, phase=phase, flexor_drive=drive, step_index=7)


def half_sine(phase: float, drive: float) -> tuple[float, float]:
    """The swing as it was before the tucked one (the paper-faithful path), written out."""
    x_front = GAIT.foot_ahead_m
    x_back = GAIT.foot_ahead_m - GAIT.ground_speed_m_s * CPG.stance_s
    z_ground = -(GEOMETRY.hip_height_m - GEOMETRY.foot_radius_m)
    x = x_back + (x_front - x_back) * 0.5 * (1.0 - math.cos(math.pi * phase))
    z = z_ground + GAIT.step_height_m * drive * math.sin(math.pi * phase)
    return x, z


def knee_bound(x: float, z: float) -> tuple[float, float]:
    """(x, z) held below the circle on which the knee is bent to ``tuck_knee_rad``."""
    r = math.sqrt(GEOMETRY.thigh_m ** 2 + GEOMETRY.shank_m ** 2
                  + 2.0 * GEOMETRY.thigh_m * GEOMETRY.shank_m * math.cos(GAIT.tuck_knee_rad))
    return (x, min(z, -math.sqrt(r * r - x * x))) if x * x < r * r else (x, z)


def test_up_to_the_tuck_the_path_is_the_half_sine_float_for_float() -> None:
    path = FootTrajectory(GAIT, CPG, GEOMETRY)
    assert GAIT.tuck_from_amplitude >= 1.9  # the paper's hardwired lift never tucks
    for amplitude in (1.0, 1.3, 1.9):  # the paper's lifts: the half-sine exactly (the knee's bound never binds)
        for phase in PHASES:
            for rate in (0.0, 0.37, 1.0):
                drive = amplitude * rate
                assert path.target(swing(phase, drive), amplitude) == half_sine(phase, drive)
                assert path.target(swing(phase, drive)) == half_sine(phase, drive)  # amplitude 1 by default
    for amplitude in (2.5, 2.8, GAIT.tuck_from_amplitude):  # higher: the half-sine below the knee's bound
        for phase in PHASES:
            assert path.target(swing(phase, amplitude), amplitude) == knee_bound(*half_sine(phase, amplitude))
    assert tuck_fraction(GAIT, GAIT.tuck_from_amplitude) == 0.0 and tuck_fraction(GAIT, GAIT.tuck_full_amplitude) == 1.0


def test_the_tuck_grows_continuously_from_where_it_starts() -> None:
    path = FootTrajectory(GAIT, CPG, GEOMETRY)
    for phase in PHASES:
        a = GAIT.tuck_from_amplitude + 1e-9
        x, z = path.target(swing(phase, a), a)
        x0, z0 = knee_bound(*half_sine(phase, a))
        assert abs(x - x0) < 1e-8 and abs(z - z0) < 1e-8
    # small steps of the amplitude move the path by small amounts: no jump anywhere in the blend
    previous = None
    steps = 20
    lo, hi = GAIT.tuck_from_amplitude, GAIT.tuck_full_amplitude
    for k in range(steps + 1):
        a = lo + (hi - lo) * k / steps
        xs = [path.target(swing(p, a), a) for p in PHASES]
        if previous is not None:
            assert max(math.hypot(x - px, z - pz) for (x, z), (px, pz) in zip(xs, previous)) < 0.02
        previous = xs


def test_a_high_lift_raises_the_foot_early_and_stays_inside_the_joint_limits() -> None:
    path = FootTrajectory(GAIT, CPG, GEOMETRY)
    hip_axis, knee_axis = default_axes()
    for amplitude in (3.1, 3.2, 3.3, 3.44):
        for phase in PHASES:
            x, z = path.target(swing(phase, amplitude), amplitude)
            hip, knee = inverse(GEOMETRY, x, z)
            assert hip_axis.min_rad - 1e-9 <= hip <= hip_axis.max_rad + 1e-9, (amplitude, phase, hip)
            assert knee_axis.min_rad - 1e-9 <= knee <= knee_axis.max_rad + 1e-9, (amplitude, phase, knee)
            assert math.hypot(x, z) <= GEOMETRY.thigh_m + GEOMETRY.shank_m
        if amplitude >= GAIT.tuck_full_amplitude:
            for phase in (0.1, 0.15, 0.2, 0.25, 0.3):  # early in the swing: higher than the half-sine
                assert path.target(swing(phase, amplitude), amplitude)[1] > half_sine(phase, amplitude)[1] + 0.02
            # and it holds the foot back early (the shank clears the near edge), forward by the end
            assert path.target(swing(0.3, amplitude), amplitude)[0] < half_sine(0.3, amplitude)[0]
        start = path.target(swing(0.0, amplitude), amplitude)
        end = path.target(swing(1.0, amplitude), amplitude)
        assert start == half_sine(0.0, amplitude) or math.isclose(start[0], half_sine(0.0, amplitude)[0])
        assert math.isclose(end[0], GAIT.foot_ahead_m) and math.isclose(end[1], half_sine(1.0, amplitude)[1],
                                                                          abs_tol=1e-12)


def test_stance_is_unchanged_by_the_amplitude() -> None:
    path = FootTrajectory(GAIT, CPG, GEOMETRY)
    for phase in PHASES:
        out = CpgOutput(onset=False, flexing=False, phase=phase, flexor_drive=0.1, step_index=2)
        assert path.target(out, 3.44) == path.target(out) == path.target(out, 1.9)


def test_a_swing_told_to_descend_later_stays_up_longer_and_lands_where_the_gait_does() -> None:
    """Rule 18 of controller.stepping.improved: a premotor may move this cycle's tucked descent
    later; before it the path is the gait's, after it the foot is higher, and it lands at the same
    place. NaN, or a phase outside (tuck_rise_phase, 1), keeps the gait's own path float for float."""
    path = FootTrajectory(GAIT, CPG, GEOMETRY)
    amplitude = GAIT.tuck_full_amplitude
    late = 0.84
    for phase in PHASES:
        out = swing(phase, amplitude)
        own = path.target(out, amplitude)
        assert path.target(out, amplitude, math.nan) == own
        assert path.target(out, amplitude, GAIT.tuck_rise_phase) == own  # not after the rise: ignored
        assert path.target(out, amplitude, 1.0) == own
        told = path.target(out, amplitude, late)
        assert told[0] == own[0]  # the forward motion is the gait's
        if phase <= GAIT.tuck_descend_phase:
            assert told == own
        else:  # no lower (both may be held at the knee's circle), and clearly higher late on
            assert told[1] >= own[1], phase
            if 0.85 <= phase <= 0.95:
                assert told[1] > own[1] + 0.01, phase
    end = path.target(swing(1.0, amplitude), amplitude, late)
    assert math.isclose(end[1], path.target(swing(1.0, amplitude), amplitude)[1], abs_tol=1e-12)
    # a lift that does not tuck ignores it (the half-sine, float for float)
    assert path.target(swing(0.9, 1.9), 1.9, late) == half_sine(0.9, 1.9)


def test_a_stance_told_the_ground_speed_sweeps_back_at_it_and_the_belief_gives_the_gaits_own() -> None:
    """Rule 19 of controller.stepping.improved: a premotor that senses the ground speed may tell
    the stance how fast to sweep back (the loop tells it at a touchdown). The gait's own speed
    gives its own sweep float for float; NaN, 0 or a speed beyond 3 m/s leaves it as it is."""
    path = FootTrajectory(GAIT, CPG, GEOMETRY)
    own = path.x_back_m
    stance = CpgOutput(onset=False, flexing=False, phase=1.0, flexor_drive=0.0, step_index=7)
    path.follow_ground_speed(0.45)
    assert math.isclose(path.target(stance)[0], GAIT.foot_ahead_m - 0.45 * CPG.stance_s, abs_tol=1e-15)
    assert path.target(swing(0.0, 1.0))[0] == path.x_back_m  # the swing starts where the stance ended
    for ignored in (math.nan, 0.0, -0.5, 3.5):
        path.follow_ground_speed(ignored)
        assert math.isclose(path.x_back_m, GAIT.foot_ahead_m - 0.45 * CPG.stance_s, abs_tol=1e-15)
    path.follow_ground_speed(GAIT.ground_speed_m_s)
    assert path.x_back_m == own
