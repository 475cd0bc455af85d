"""Sessions: the controller and the simulated leg as two processes on a real SocketCAN bus.

:mod:`hil.session.run` starts both (the controller as the leg runs it, ``elegant-stepping
controller``; the leg as ``firmware-sim``, :mod:`hil.session.firmware`), drives the trials through
the scenario side channel (:mod:`hil.session.scenario`, server and client), records the bus
(:mod:`hil.session.recorder`), watches the leg's heartbeats (:mod:`hil.session.legwatch`) and
judges the outcome (:mod:`hil.session.outcome`). Where the kernel has no CAN it runs inside User-Mode
Linux (:mod:`hil.uml`), with that platform's allowances (:mod:`hil.profile`).

May import: ``controller``, ``firmware_sim``, ``protocol``, :mod:`hil.uml`, :mod:`hil.profile`,
:mod:`hil.faults`, :mod:`hil.experiments`, :mod:`hil.analysis`.
"""
