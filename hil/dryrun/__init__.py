"""The deployment dry run: the systemd unit's own command line against the simulated leg.

:mod:`hil.dryrun.run` reads the unit (:mod:`hil.dryrun.unitfile`), runs its ``ExecStart`` (the
leg's ``elegant-stepping-leg run``) with only ``--config`` swapped for the simulated leg's, plays
systemd's notify socket (:mod:`hil.dryrun.notify_listener`) and prints a checklist.

May import: ``controller``, :mod:`hil.session`, :mod:`hil.uml`, :mod:`hil.profile`.
"""
