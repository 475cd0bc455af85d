"""The controller process: everything that runs on the leg's computer.

A fixed-rate loop (:mod:`controller.loop`) brings the ODrive axes up over CAN
(:mod:`controller.bringup`), runs the CPG ring oscillator (:mod:`controller.cpg`), shapes foot
trajectories (:mod:`controller.gait`) into hip and knee targets (:mod:`controller.kinematics`)
through a low-pass muscle (:mod:`controller.muscle`), and sends them as Set_Input_Pos frames
(:mod:`controller.axis`). It knows the world only through CAN frames (:mod:`controller.bus_io`).

May import: the standard library, numpy, filterpy, python-can, and ``protocol``. Never imports
``firmware_sim`` or ``hil``.
"""
