"""Bring-up: checks a real leg before it is trusted to walk.

:mod:`controller.bringup.procedure` runs the checklist (:mod:`controller.bringup.checklist`):
heartbeats from every node and no other master (:mod:`controller.bringup.bus`); per axis its
version, errors, bus voltage, state and position; then small, slow, bounded moves, one axis at a
time (:mod:`controller.bringup.move`). Any error sends the axis IDLE.

May import: the standard library, python-can, ``protocol`` and ``controller``; never ``hil`` or
``firmware_sim``.
"""
