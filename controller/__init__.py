"""The controller process: everything that runs on the leg's computer.

A fixed-rate loop (:mod:`controller.loop`) brings the ODrive axes up over CAN and supervises them
(:mod:`controller.supervisor`), runs the CPG ring oscillator (:mod:`controller.motion.cpg`), shapes foot
trajectories (:mod:`controller.motion.gait`) into hip and knee targets (:mod:`controller.motion.kinematics`)
through a low-pass muscle (:mod:`controller.motion.muscle`), and sends them as Set_Input_Pos frames
(:mod:`controller.io.axis`). The Elegant Stepping model: the Kalman-filtered range
(:mod:`controller.stepping.range_filter`), the range encoder (:mod:`controller.stepping.encoder`), gated memory,
traces and learning (:mod:`controller.stepping.learner`), the reflexes (:mod:`controller.stepping.reflexes`), the
height context and its learner (:mod:`controller.stepping.height`, :mod:`controller.stepping.context`), and the
Q-learning baseline (:mod:`controller.stepping.rl`), all behind the Premotor protocol
(:mod:`controller.stepping.premotor`). It knows the world only through CAN frames (:mod:`controller.io.bus`).
A leg is configured by one TOML file, validated on load (:mod:`controller.settings.file`), and checked
before it runs by the bring-up procedure (:mod:`controller.bringup.procedure`: nodes, versions, errors, bus
voltage, small bounded moves; :mod:`controller.bringup.bus`, :mod:`controller.bringup.move`,
:mod:`controller.bringup.checklist`).

May import: the standard library, numpy, filterpy, python-can, and ``protocol`` (and, on Python
3.10 only, ``tomli``: the standard library's ``tomllib`` before 3.11). Never imports
``firmware_sim`` or ``hil``.
"""

# first, before any hot module: ELEGANT_STEPPING_PURE_PYTHON=1 runs them as pure Python (protocol.compiled)
from protocol.compiled import install_pure_python_finder as _install_pure_python_finder

_install_pure_python_finder()
