"""Motion: from the ring oscillator to joint targets.

:mod:`controller.motion.cpg` is the ring-oscillator CPG whose flexion burst sets the swing;
:mod:`controller.motion.gait` shapes the CPG's output into a foot trajectory;
:mod:`controller.motion.kinematics` turns it into hip and knee angles (two-link inverse
kinematics, with :class:`LegGeometry`); :mod:`controller.motion.muscle` low-passes the targets.
:mod:`controller.motion.reach` computes the tallest obstacle the leg can clear at all (its
geometry, joint limits, torques and the longest swing), for an experiment to refuse taller ones.
Each module's configuration dataclass lives beside it.

May import: the standard library and numpy; never ``hil``, ``firmware_sim`` or the bus.
"""
