"""Sessions: the controller and the simulated leg as two processes on a real SocketCAN bus.

:mod:`hil.session.run` starts both (the controller as the leg runs it, ``elegant-stepping
controller``; the leg as ``firmware-sim``, :mod:`hil.session.firmware`), drives the trials through
the scenario side channel (:mod:`hil.session.scenario`, server and client), records the bus
(:mod:`hil.session.recorder`), watches the leg's heartbeats (:mod:`hil.session.legwatch`) and
judges the outcome (:mod:`hil.session.outcome`). Where the kernel has no CAN it runs inside User-Mode
Linux (:mod:`hil.uml`), with that platform's allowances (:mod:`hil.profile`). In simulated time
(``hil --clock sim``) :mod:`hil.session.simsession` runs the session and :mod:`hil.session.simplant`
is the plant's process: one controller tick per sync frame, the records of ``learn`` for a seed.

May import: ``controller``, ``firmware_sim``, ``protocol``, :mod:`hil.uml`, :mod:`hil.profile`,
:mod:`hil.faults`, :mod:`hil.experiments`, :mod:`hil.analysis`.
"""
