"""``builtin:rps3``: a 3-RPS parallel manipulator (passive revolute at the base, actuated
prismatic leg, spherical joint at the platform), after the robot of Mata, Farhat et al.
(paper 000, Section 6: a 3-RPS built at the Polytechnic University of Valencia).

Geometry (our choice; units m, rad)
-----------------------------------
The extracted chapter (paper 000) gives no dimensions, so the values below are
plausible choices of ours for a ball-screw 3-RPS of that size (actuator forces of a
few hundred N, paper 000, Figs. 3–4):

* base joints A_i = r_b (cos γ_i, sin γ_i, 0), r_b = 0.45, γ_i = 0, 2π/3, 4π/3;
  the revolute joint ``R{i}`` turns about the tangent t_i = (-sin γ_i, cos γ_i, 0),
  so leg i moves in the vertical plane through the z axis and A_i;
* platform joints b_i = r_p (cos γ_i, sin γ_i, 0) in the platform frame, r_p = 0.25;
* the leg is a cylinder (motor and screw housing, body of ``R{i}``) and a piston (body of
  ``P{i}``); ``P{i}`` is the leg length |A_i B_i| (stroke 0.55–1.15); ``R{i}`` = 0 is a
  vertical leg, positive towards the outside (the leg direction is Ry(R{i}) e_z in the
  frame (radial, t_i, z) of leg i);
* the platform pose is the chain ``PX, PY, PZ, RZ, RY, RX`` (x, y, z, ψ, θ, φ with
  R = Rz(ψ) Ry(θ) Rx(φ)) whose first five bodies are massless; each spherical joint is a
  ``"3d"`` closure between the piston tip and b_i: 12 joints, 9 independent constraint
  rows, mobility 3; the three actuated leg lengths are the independent coordinates;
* gravity: pinocchio's default (0, 0, -9.81), base z up, the platform above the base.

Closed-form inverse kinematics (:func:`inverse_kinematics`)
-----------------------------------------------------------
The independent pose components are (z, θ, φ) (:data:`INDEPENDENT_POSE`). Each sphere
centre stays in its leg plane, :math:`(p + R b_i)\\cdot t_i = 0`; for i = 1, the
difference of i = 2 and 3, and their sum combined with i = 1:

.. math::

    y = -r_p R_{21}, \\qquad x = \\tfrac{r_p}{2}(R_{11} - R_{22}), \\qquad
    R_{12} = R_{21} \\iff \\tan\\psi = \\frac{\\sin\\theta\\sin\\varphi}{\\cos\\theta + \\cos\\varphi},

(the classic parasitic motion of the 3-RPS). Then with d_i = p + R b_i - A_i written in
the leg frame, :math:`l_i = \\sqrt{d_r^2 + d_z^2}` and :math:`R_i = \\mathrm{atan2}(d_r, d_z)`.

Parameters (our choices, except the actuator terms)
---------------------------------------------------
Bodies (mass, centre of mass in the joint frame, inertia at the centre of mass): cylinder
7.0 kg at (0.03, 0, 0.20) (motor beside the screw), piston 2.5 kg at 0.30 below the tip,
platform 15 kg triangular plate, centre of mass 0.02 above the joint plane. Actuator terms
(paper 000, Table 5, "exact values" of the simulated robot, actuator 1, used for all three;
Section 6.2 identifies symmetric Coulomb + viscous friction): reflected rotor + screw
inertia ``Ia`` Jr + Js = 483.10 kg, viscous ``fv`` 3272.0 N·s/m, Coulomb ``fc`` 228.0 N
(mean of Fc+ = 227.96 and Fc- = 228.04 N).

Base parameters: :func:`dynid.model.closed_loop.mechanism_base_parameters` finds 25
rigid-body base parameters (+ 9 actuator terms = 34), the count of paper 000's model 1
(34 parameters "including friction and rotor and screw inertias", Section 6.2; Tables 6–7
list 37 = 25 + 12, consistent with asymmetric Coulomb Fc+ / Fc- as in Table 5); its
model 4 keeps 3 rigid-body ones + the 9 actuator terms.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.mechanism import JointCoordinates, JointTerm, LoopClosure, Mechanism
from dynid.model.robot import JOINT_EXTRAS

__all__ = [
    "ACTUATOR_TERMS",
    "HOME",
    "INDEPENDENT_POSE",
    "PLATFORM_JOINTS",
    "build",
    "inverse_kinematics",
    "platform_pose",
]

R_BASE = 0.45
"""Radius of the base joint circle [m] (our choice)."""
R_PLATFORM = 0.25
"""Radius of the platform joint circle [m] (our choice)."""
GAMMA = np.array([0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0])
"""Angular positions of the legs [rad]."""
STROKE = (0.55, 1.15)
"""Leg-length limits [m]."""
R_LIMIT = np.pi / 3
"""Limit of the revolute joints, ±[rad]."""
HOME = np.array([0.80, 0.0, 0.0])
"""Home pose (z [m], θ, φ [rad]): platform level, 0.8 m above the base."""
PLATFORM_JOINTS = ("PX", "PY", "PZ", "RZ", "RY", "RX")
INDEPENDENT_POSE = ("PZ", "RY", "RX")
"""Independent pose components: z, θ (about y), φ (about x); x, y, ψ are parasitic."""

ACTUATOR_TERMS = {"Ia": ("inertia", 483.10), "fv": ("viscous", 3272.0), "fc": ("coulomb", 228.0), "offset": ("offset", 0.0)}
"""Actuator joint terms: kind and nominal value (paper 000, Table 5; kg, N·s/m, N, N)."""
_DEFAULT_EXTRAS = ("Ia", "fv", "fc")

# bodies: mass [kg], centre of mass [m] (joint frame), inertia at the centre of mass [kg m^2]
_CYLINDER = (7.0, (0.03, 0.0, 0.20), (0.150, 0.150, 0.009))
_PISTON = (2.5, (0.0, 0.0, -0.30), (0.075, 0.075, 0.0005))
_PLATFORM = (15.0, (0.0, 0.0, 0.02), (0.117, 0.117, 0.234))


def _inertia(spec: tuple[float, tuple[float, float, float], tuple[float, float, float]]) -> pin.Inertia:
    m, c, d = spec
    return pin.Inertia(m, np.array(c), np.diag(d))


def _rz(g: float) -> FloatArray:
    return np.array([[np.cos(g), -np.sin(g), 0.0], [np.sin(g), np.cos(g), 0.0], [0.0, 0.0, 1.0]])


def _base_points() -> FloatArray:
    return R_BASE * np.stack([np.cos(GAMMA), np.sin(GAMMA), np.zeros(3)], -1)


def _platform_points() -> FloatArray:
    return R_PLATFORM * np.stack([np.cos(GAMMA), np.sin(GAMMA), np.zeros(3)], -1)


def build(extras: Sequence[str] | None = None) -> Mechanism:
    """The rps3 mechanism.

    Parameters
    ----------
    extras : sequence of str, optional
        Actuator joint terms, a subset of ``("Ia", "fv", "fc", "offset")``; default
        ``("Ia", "fv", "fc")`` (paper 000's models 1–4). Each is one parameter per actuator.
    """
    extras = _DEFAULT_EXTRAS if extras is None else tuple(extras)
    unknown = [e for e in extras if e not in JOINT_EXTRAS]
    if unknown:
        raise ModelError(f"unknown joint extras {unknown} for rps3; choose from {list(JOINT_EXTRAS)}")
    model = pin.Model()
    model.name = "rps3"
    lo, hi = [], []
    A = _base_points()
    for i in range(3):
        jr = model.addJoint(0, pin.JointModelRY(), pin.SE3(_rz(GAMMA[i]), A[i]), f"R{i + 1}")
        model.appendBodyToJoint(jr, _inertia(_CYLINDER), pin.SE3.Identity())
        jp = model.addJoint(jr, pin.JointModelPZ(), pin.SE3.Identity(), f"P{i + 1}")
        model.appendBodyToJoint(jp, _inertia(_PISTON), pin.SE3.Identity())
        lo += [-R_LIMIT, STROKE[0]]
        hi += [R_LIMIT, STROKE[1]]
    parent, massless = 0, []
    joint_models = (pin.JointModelPX, pin.JointModelPY, pin.JointModelPZ, pin.JointModelRZ, pin.JointModelRY, pin.JointModelRX)
    for name, jm in zip(PLATFORM_JOINTS, joint_models):
        parent = model.addJoint(parent, jm(), pin.SE3.Identity(), name)
        if name != "RX":
            model.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
            massless.append(parent)
    model.appendBodyToJoint(parent, _inertia(_PLATFORM), pin.SE3.Identity())
    lo += [-0.3, -0.3, 0.3, -np.pi / 3, -np.pi / 3, -np.pi / 3]
    hi += [0.3, 0.3, 1.3, np.pi / 3, np.pi / 3, np.pi / 3]
    model.lowerPositionLimit = np.array(lo)
    model.upperPositionLimit = np.array(hi)
    b = _platform_points()
    closures = tuple(
        LoopClosure(f"S{i + 1}", 2 * i + 2, pin.SE3.Identity(), parent, pin.SE3(np.eye(3), b[i]), "3d") for i in range(3)
    )
    terms, nominal = [], {}
    for i in range(3):
        for e in extras:
            kind, value = ACTUATOR_TERMS[e]
            name = f"{e}_P{i + 1}"
            terms.append(JointTerm(name, kind, (2 * i + 1,)))
            nominal[name] = value
    actuated = (1, 3, 5)
    return Mechanism(
        model,
        closures,
        actuated=actuated,
        independent=JointCoordinates(actuated),
        terms=tuple(terms),
        massless=tuple(massless),
        nominal_terms=nominal,
        q_guess=inverse_kinematics(HOME[None])[0],
        name="rps3",
        source="builtin:rps3",
        task_coordinates=INDEPENDENT_POSE,
        task_ik=inverse_kinematics,
        identical_chains=(tuple((f"R{i}", f"P{i}") for i in range(1, 4)),),  # the three legs (same bodies in own frames)
        notes=(
            "3-RPS after paper 000 (Mata, Farhat et al.); dimensions and body values are our choices (the chapter gives none)",
            "platform pose: chain PX, PY, PZ, RZ, RY, RX with massless intermediate bodies; (z, θ, φ) independent",
            "actuator terms per leg: reflected rotor + screw inertia, viscous and Coulomb friction (paper 000, Table 5)",
        ),
    )


def platform_pose(pose: FloatArray) -> FloatArray:
    """The six platform-chain values (x, y, z, ψ, θ, φ) from the independent (z, θ, φ).

    Parameters
    ----------
    pose : array, shape (n, 3)
        z [m], θ (about y) [rad], φ (about x) [rad].

    Returns
    -------
    array, shape (n, 6)
        With the parasitic x, y [m] and ψ [rad] of the module docstring.
    """
    pose = np.atleast_2d(np.asarray(pose, dtype=float))
    if pose.ndim != 2 or pose.shape[1] != 3:
        raise InputError(f"rps3 pose must have shape (n, 3) (z, θ, φ), got {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise InputError("rps3 pose contains NaN or infinite values")
    z, th, ph = pose.T
    den = np.cos(th) + np.cos(ph)
    if np.any(den <= 1e-6):
        bad = int(np.argmax(den <= 1e-6))
        raise ModelError(f"rps3 pose {pose[bad]}: tilt angles too large (cos θ + cos φ <= 0), the yaw is undefined")
    psi = np.arctan2(np.sin(th) * np.sin(ph), den)
    R = _rotations(psi, th, ph)
    x = 0.5 * R_PLATFORM * (R[:, 0, 0] - R[:, 1, 1])
    y = -R_PLATFORM * R[:, 1, 0]
    return np.stack([x, y, z, psi, th, ph], -1)


def _rotations(psi: FloatArray, th: FloatArray, ph: FloatArray) -> FloatArray:
    """R = Rz(ψ) Ry(θ) Rx(φ), shape (n, 3, 3)."""
    cs, ss, ct, st, cp, sp = np.cos(psi), np.sin(psi), np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
    return np.stack(
        [
            np.stack([cs * ct, cs * st * sp - ss * cp, cs * st * cp + ss * sp], -1),
            np.stack([ss * ct, ss * st * sp + cs * cp, ss * st * cp - cs * sp], -1),
            np.stack([-st, ct * sp, ct * cp], -1),
        ],
        1,
    )


def inverse_kinematics(pose: FloatArray) -> FloatArray:
    """All twelve joint positions from the independent pose (closed form).

    Parameters
    ----------
    pose : array, shape (n, 3)
        z [m], θ, φ [rad] (see :func:`platform_pose`).

    Returns
    -------
    array, shape (n, 12)
        ``[R1, P1, R2, P2, R3, P3, x, y, z, ψ, θ, φ]`` (revolute angles [rad], leg lengths [m]).

    Raises
    ------
    ModelError
        When a leg length leaves the stroke or a revolute angle its limit.
    """
    chain = platform_pose(pose)
    n = chain.shape[0]
    R = _rotations(chain[:, 3], chain[:, 4], chain[:, 5])
    A, b = _base_points(), _platform_points()
    out = np.empty((n, 12))
    out[:, 6:] = chain
    for i in range(3):
        d = chain[:, :3] + R @ b[i] - A[i]
        dr = d @ np.array([np.cos(GAMMA[i]), np.sin(GAMMA[i]), 0.0])
        length = np.hypot(dr, d[:, 2])
        angle = np.arctan2(dr, d[:, 2])
        bad = (length < STROKE[0]) | (length > STROKE[1])
        if np.any(bad):
            k = int(np.argmax(bad))
            raise ModelError(
                f"rps3 pose {_pose_row(pose, k)} is unreachable: leg {i + 1} length {length[k]:.4f} m "
                f"is outside the stroke [{STROKE[0]}, {STROKE[1]}] m"
            )
        bad = np.abs(angle) > R_LIMIT
        if np.any(bad):
            k = int(np.argmax(bad))
            raise ModelError(
                f"rps3 pose {_pose_row(pose, k)} is unreachable: revolute R{i + 1} angle {angle[k]:.4f} rad exceeds ±{R_LIMIT:.4f} rad"
            )
        out[:, 2 * i] = angle
        out[:, 2 * i + 1] = length
    return out


def _pose_row(pose: FloatArray, k: int) -> str:
    """One pose row for an error message."""
    return np.array2string(np.atleast_2d(np.asarray(pose, dtype=float))[k], precision=4)
