"""The controller process: everything that runs on the leg's computer.

A fixed-rate loop (:mod:`controller.loop`) brings the ODrive axes up over CAN and supervises them
(:mod:`controller.supervisor`), runs the CPG ring oscillator (:mod:`controller.cpg`), shapes foot
trajectories (:mod:`controller.gait`) into hip and knee targets (:mod:`controller.kinematics`)
through a low-pass muscle (:mod:`controller.muscle`), and sends them as Set_Input_Pos frames
(:mod:`controller.axis`). The Elegant Stepping model: the Kalman-filtered range
(:mod:`controller.range_filter`), the range encoder (:mod:`controller.encoder`), gated memory,
traces and learning (:mod:`controller.learner`), the reflexes (:mod:`controller.reflexes`), the
height context and its learner (:mod:`controller.height`, :mod:`controller.context`), and the
Q-learning baseline (:mod:`controller.rl`), all behind the Premotor protocol
(:mod:`controller.premotor`). It knows the world only through CAN frames (:mod:`controller.bus_io`).
A leg is configured by one TOML file, validated on load (:mod:`controller.settings`), and checked
before it runs by the bring-up procedure (:mod:`controller.bringup`: nodes, versions, errors, bus
voltage, small bounded moves; :mod:`controller.bringup_bus`, :mod:`controller.bringup_move`,
:mod:`controller.checklist`).

May import: the standard library, numpy, filterpy, python-can, and ``protocol`` (and, on Python
3.10 only, ``tomli``: the standard library's ``tomllib`` before 3.11). Never imports
``firmware_sim`` or ``hil``.
"""
