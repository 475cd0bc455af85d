"""The gait rig and its obstacles as URDF: data, with the few helpers that locate or make it.

``gait_rig.urdf``: a carriage on a rail (prismatic x) with a hip and a knee (pitch) and a foot.
``ground.urdf``: flat ground. Obstacles are rectangular blocks made from their size parameters
by :func:`obstacle_urdf`. May import the standard library only.
"""

from __future__ import annotations

from pathlib import Path

URDF_DIR = Path(__file__).resolve().parent
GAIT_RIG = URDF_DIR / "gait_rig.urdf"
GROUND = URDF_DIR / "ground.urdf"

_OBSTACLE_TEMPLATE = """<?xml version="1.0"?>
<!-- Rectangular obstacle: {height_m} m high, {depth_m} m deep (along the rail), {width_m} m wide.
     Origin at the middle of its near (leg-side) bottom edge. -->
<robot name="obstacle">
  <link name="block">
    <inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
    <visual><origin xyz="{cx} 0 {cz}"/><geometry><box size="{depth_m} {width_m} {height_m}"/></geometry>
      <material name="red"><color rgba="0.8 0.2 0.2 1"/></material></visual>
    <collision><origin xyz="{cx} 0 {cz}"/><geometry><box size="{depth_m} {width_m} {height_m}"/></geometry></collision>
  </link>
</robot>
"""


def obstacle_urdf(height_m: float, depth_m: float, width_m: float = 0.4) -> str:
    """URDF text of a rectangular block whose origin is its near bottom edge (x = 0, z = 0)."""
    for name, value in (("height_m", height_m), ("depth_m", depth_m), ("width_m", width_m)):
        if not (value > 0.0 and value < 10.0):
            raise ValueError(f"obstacle {name} must be in (0, 10) m, got {value!r}")
    return _OBSTACLE_TEMPLATE.format(
        height_m=height_m, depth_m=depth_m, width_m=width_m, cx=depth_m / 2.0, cz=height_m / 2.0
    )
