"""A payload's inertia as a URDF ``<link>`` + fixed ``<joint>`` snippet and as an MJCF ``<body>``.

Both are written in the payload's own frame (``[payload] origin`` of ``dynid payload``, default the mount
joint's frame): the inertial element holds the mass, the centre of mass and the inertia about it in that frame's
axes (URDF ``<inertia>`` and MJCF ``fullinertia``: about the centre of mass, in the ``<inertial>``'s frame)."""

from __future__ import annotations

import numpy as np

from dynid._typing import FloatArray

__all__ = ["payload_urdf", "payload_mjcf", "rpy_matrix", "matrix_quat"]


def _f(x: float) -> str:
    return repr(float(x))


def _v(v) -> str:
    return " ".join(_f(x) for x in v)


def rpy_matrix(rpy) -> FloatArray:
    """Rotation of URDF roll-pitch-yaw [rad]: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def matrix_quat(R: FloatArray) -> FloatArray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (MJCF's order)."""
    import pinocchio as pin

    q = pin.Quaternion(np.asarray(R, dtype=float)).coeffs()  # x, y, z, w
    return np.array([q[3], q[0], q[1], q[2]])


def payload_urdf(name: str, parent: str, xyz, rpy, mass: float, com: FloatArray, inertia: FloatArray,
                 comment: str = "") -> str:
    """A ``<robot>`` holding the payload ``<link>`` and the fixed ``<joint>`` that attaches it to link ``parent``
    at ``xyz``/``rpy`` (the payload frame in the parent link's frame); ``com`` [m] and ``inertia`` (3x3, about the
    centre of mass) in the payload frame. Paste the link and the joint into the arm's ``<robot>``."""
    I = np.asarray(inertia, dtype=float)
    note = f"  <!-- {comment} -->\n" if comment else ""
    return (f'<?xml version="1.0"?>\n<robot name="{name}">\n{note}'
            f"  <!-- paste the link and the joint into the arm's <robot>; the parent link is the mount body's -->\n"
            f'  <link name="{name}">\n    <inertial>\n      <origin xyz="{_v(com)}" rpy="0 0 0" />\n'
            f'      <mass value="{_f(mass)}" />\n'
            f'      <inertia ixx="{_f(I[0, 0])}" ixy="{_f(I[0, 1])}" ixz="{_f(I[0, 2])}" iyy="{_f(I[1, 1])}" '
            f'iyz="{_f(I[1, 2])}" izz="{_f(I[2, 2])}" />\n    </inertial>\n  </link>\n'
            f'  <joint name="{name}_joint" type="fixed">\n    <parent link="{parent}" />\n    <child link="{name}" />\n'
            f'    <origin xyz="{_v(xyz)}" rpy="{_v(rpy)}" />\n  </joint>\n</robot>\n')


def payload_mjcf(name: str, mount: str, pos, R: FloatArray, mass: float, com: FloatArray, inertia: FloatArray,
                 comment: str = "") -> str:
    """An MJCF model whose world holds the payload ``<body>`` (at ``pos``, rotation ``R`` in the mount joint's
    frame) with its ``<inertial>`` (``com`` and ``inertia`` about it in the payload frame); paste the body as a
    child of the body that holds joint ``mount``. Loadable as it is (the body then welded to the world)."""
    I = np.asarray(inertia, dtype=float)
    note = f"  <!-- {comment} -->\n" if comment else ""
    return (f'<mujoco model="{name}">\n{note}'
            f"  <!-- paste the <body> as a child of the body that holds joint {mount!r} (pos/quat in that joint's "
            "frame) -->\n  <worldbody>\n"
            f'    <body name="{name}" pos="{_v(pos)}" quat="{_v(matrix_quat(R))}">\n'
            f'      <inertial pos="{_v(com)}" mass="{_f(mass)}" '
            f'fullinertia="{_v([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])}" />\n'
            "    </body>\n  </worldbody>\n</mujoco>\n")
