"""The controller daemon: the process that runs a leg.

:mod:`controller.daemon.run` ticks :class:`controller.loop.ControlLoop` at its fixed rate on the
monotonic clock (:mod:`controller.daemon.pacing`), through a lean SocketCAN front
(:mod:`controller.daemon.fastbus`), saves the learned weights while walking and at exit
(:mod:`controller.daemon.autosave`), writes its records, and talks to systemd
(:mod:`controller.daemon.sdnotify`, :mod:`controller.daemon.notify`). A bus that will not open is
one line (:mod:`controller.daemon.openbus`). On simulated time (HIL only, not yet a daemon mode),
:mod:`controller.daemon.simclock` ticks once per sync frame of the plant and answers with an
end-of-period frame.

May import: the standard library, numpy, python-can, ``protocol`` and ``controller``; never
``hil``, ``firmware_sim``, pybullet, matplotlib, tqdm or dask (the leg installs the core only).
"""
