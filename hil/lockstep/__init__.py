"""Lockstep: the controller and the simulated leg in one process, stepped together.

:mod:`hil.lockstep.harness` joins :class:`controller.loop.ControlLoop` and the simulated leg
(:mod:`firmware_sim`) on python-can's in-process ``virtual`` bus, one physics step and one control
tick at a time, so a seed gives the same records on any machine, however loaded;
:mod:`hil.lockstep.groundtruth` reads what only the simulation knows (footfalls, clearance);
:mod:`hil.lockstep.synced` runs the same lockstep through the simulated-time protocol (the plant's
sync frame, the controller's end-of-period frame), proving in one process that the protocol keeps
the records.

May import: ``controller``, ``firmware_sim``, ``protocol``, and :mod:`hil.faults` (faulty buses).
"""
