"""Built-in ``puma560``: the Unimation PUMA 560 in standard DH (Corke's model).

Geometry and link inertial parameters are those of P. Corke's Robotics Toolbox
``mdl_puma560`` (inertias after Armstrong, Khatib & Burdick 1986 / Corke & Armstrong-Hélouvry
1994), exactly the ``params_set1_corke_puma`` set of
``../shared/data/puma560/puma560_golden_inverse_dynamics.json`` (whose expected torques the
tests reproduce to 1e-10). Link parameters are given in the DH link frame in the order
``[Lxx, Lxy, Lxz, Lyy, Lyz, Lzz, lx, ly, lz, m]`` (inertia about the link-frame origin,
``l = m c``) and moved to pinocchio's joint frames by :mod:`dynid.model.dh`.

Nominal extras, joint side, from the same toolbox's motor data (motor inertia ``Jm``,
gear ratio ``G``, motor viscous ``B``, motor Coulomb ``Tc = [Tc+, Tc-]``):
``Ia = Jm G²``, ``fv = B G²``, ``fc = mean(|Tc+|, |Tc-|) |G|``, offsets 0.
"""

from __future__ import annotations

import math

import numpy as np

from dynid.model.dh import DHJoint, build_dh_model, inertia_from_link_params
from dynid.model.robot import JOINT_EXTRAS, RobotModel

# standard DH rows (alpha [rad], a [m], d [m])
_DH = [
    (math.pi / 2, 0.0, 0.0),
    (0.0, 0.4318, 0.0),
    (-math.pi / 2, 0.0203, 0.15005),
    (math.pi / 2, 0.0, 0.4318),
    (-math.pi / 2, 0.0, 0.0),
    (0.0, 0.0, 0.0),
]
# [Lxx, Lxy, Lxz, Lyy, Lyz, Lzz, lx, ly, lz, m] in the DH link frame
_LINKS = [
    [0.0, 0.0, 0.0, 0.35, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [1.03118515, 0.03798072, 1.4401023, 3.727456406, -0.023751, 2.842524056, -6.33012, 0.1044, 3.9585, 17.4],
    [0.090474288, -0.001373904, 0.0068208, 0.111498032, 0.0047376, 0.01543232, -0.09744, -0.06768, 0.336, 4.8],
    [0.00209602, 0.0, 0.0, 0.0013, 0.0, 0.00209602, 0.0, 0.01558, 0.0, 0.82],
    [0.0003, 0.0, 0.0, 0.0004, 0.0, 0.0003, 0.0, 0.0, 0.0, 0.34],
    [0.00024216, 0.0, 0.0, 0.00024216, 0.0, 4e-05, 0.0, 0.0, 0.00288, 0.09],
]
# joint limits [deg] (Corke)
_QLIM_DEG = [(-160, 160), (-45, 225), (-225, 45), (-110, 170), (-100, 100), (-266, 266)]
# motor data (Corke mdl_puma560)
_G = np.array([-62.6111, 107.815, -53.7063, 76.0364, 71.923, 76.686])
_JM = np.array([200e-6, 200e-6, 200e-6, 33e-6, 33e-6, 33e-6])
_B = np.array([1.48e-3, 0.817e-3, 1.38e-3, 71.2e-6, 82.6e-6, 36.7e-6])
_TC = np.array([[0.395, -0.435], [0.126, -0.071], [0.132, -0.105], [11.2e-3, -16.9e-3], [9.26e-3, -14.5e-3], [3.96e-3, -10.5e-3]])

LINK_PARAMS = np.array(_LINKS)
"""Link inertial parameters in DH link frames, shape (6, 10)."""


def build(extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    joints = [
        DHJoint(
            alpha=al, a=a, d=d, name=f"joint_{i + 1}",
            lower=math.radians(_QLIM_DEG[i][0]), upper=math.radians(_QLIM_DEG[i][1]),
            inertia=inertia_from_link_params(_LINKS[i]),
        )
        for i, (al, a, d) in enumerate(_DH)
    ]
    model = build_dh_model(joints, "standard", name="puma560", gravity=[0.0, 0.0, -9.81])
    nominal = {
        "Ia": _JM * _G**2,
        "fv": _B * _G**2,
        "fc": np.abs(_TC).mean(axis=1) * np.abs(_G),
        "offset": np.zeros(6),
    }
    return RobotModel(model, name="puma560", extras=extras, nominal_extras=nominal, source="builtin:puma560")
