"""Everything that would be hardware: the PyBullet plant and the nodes on the CAN bus.

The plant (:mod:`firmware_sim.plant`) is the gait rig in PyBullet; the motor model
(:mod:`firmware_sim.motor`) lives apart from it; each joint is driven by a simulated ODrive axis
(:mod:`firmware_sim.odrive_axis`, CANSimple firmware 0.6), and the sensor board
(:mod:`firmware_sim.sensor_board`) reports range and contacts. :mod:`firmware_sim.node_host`
connects the nodes to a python-can bus; :mod:`firmware_sim.leg` assembles the whole leg.

May import: the standard library, numpy, pybullet, python-can, ``protocol`` and ``urdf``.
Never imports ``controller`` or ``hil``.
"""

# first, before any hot module: ELEGANT_STEPPING_PURE_PYTHON=1 runs them as pure Python (protocol.compiled)
from protocol.compiled import install_pure_python_finder as _install_pure_python_finder

_install_pure_python_finder()
