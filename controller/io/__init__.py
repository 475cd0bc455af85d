"""The controller's side of the CAN bus: the one place frames are made and read.

:mod:`controller.io.bus` drains the bus each tick, validates every frame against the bus contract
(:mod:`protocol`) and counts each one it drops under one reason; :mod:`controller.io.axis` is one
ODrive axis as the controller sees it (heartbeat, encoder, commands, limits; :class:`AxisConfig`
with its calibration); :mod:`controller.io.sensors` is the sensor board's frames (range, profile,
foot switch, rail).

May import: the standard library, numpy, python-can, cantools, ``protocol`` and ``controller``
modules below it (``controller.config``); never ``hil`` or ``firmware_sim``.
"""
