"""``builtin:shang2dof``: the planar 2-DOF parallel manipulator with actuation redundancy
of Shang, Cong & Kong, Mechatronics 2009 (paper 001).

Geometry (paper 001, Section 2 and Fig. 1; units m)
----------------------------------------------------
Three RR chains in the horizontal plane (gravity does no work) meet at the common
point O, which carries the end-effector. Chain ``i`` has an actuated revolute joint
``qa{i}`` at its base A_i and a passive revolute joint ``qb{i}`` at the elbow B_i:

* A1 = (0, 0.25), A2 = (0.433, 0), A3 = (0.433, 0.5);
* every link is 0.244 m long (A_i B_i = B_i O = 0.244);
* pinocchio coordinates: ``qa{i}`` is the absolute angle of link A_iB_i from the x axis,
  ``qb{i}`` is the **relative** elbow angle (paper 001 uses the absolute angle
  ``qa + qb`` of link B_iO);
* the tree is the three open chains; O is closed by two ``"3d"`` point closures
  (chain 1 to chain 2, chain 1 to chain 3). Their ``z`` rows vanish identically
  (planar loops), so 4 of the 6 constraint rows are independent and the mobility is 2;
* independent coordinates: the position (x, y) of O; the three actuators make the
  actuation redundant (3 actuators, 2 DOF).

Parameters (paper 001, Eqs. 1–3 and 7–9, Table 3)
---------------------------------------------------
Shang's model of chain ``i`` in absolute angles is
:math:`M_i = [[a_i, c_i\\cos(q_{ai}-q_{bi})], [c_i\\cos(q_{ai}-q_{bi}), b_i]]`, i.e.
:math:`a_i = I_{zz,A_i} + I_{a,i} + m_{b,i} l^2` (link A_iB_i about A_i, rotor, elbow
mass), :math:`b_i = I_{zz,B_i}` (link B_iO about B_i), :math:`c_i = l\\,m x_{b,i}`.
The body values below are chosen so that these combinations equal Table 3 exactly
(a = 0.0932, 0.0427, 0.0427; b = 0.0381, 0.0085, 0.0085; c = 0.0426, 0.0111, 0.0111
kg·m²); masses, centres of mass and the split between link and rotor inertia are
plausible choices of ours (they are not in the paper and do not affect the dynamics
beyond a, b, c). First moments perpendicular to the links (``my``) are zero nominally
but are parameters of the model.

Friction (paper 001, Eqs. 2–3): asymmetric Coulomb + viscous at each active joint
(``fv+``, ``fv-``, ``fc+``, ``fc-``; the ``fc-`` coefficient multiplies the indicator of
negative velocity and is negative, as in Table 2), viscous at each passive joint (on the
relative elbow rate, where the friction acts). Nominal values are the WLS estimates of
Table 2 (the paper gives no others). With a, b, c these are the 24 parameters of
Eqs. 7–9.

Identifiability (a finding, checked by the base-parameter computation): a point mass at
O can be attributed to any of the three chains without changing the dynamics, so the
nine a, b, c are **not** all identifiable: two combinations are lost (see
:func:`point_mass_null_space`); with the ``my`` first moments the rigid-body part has
4 x 3 - 2 = 10 base parameters.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import ModelError
from dynid.model.mechanism import JointTerm, LoopClosure, Mechanism, PointCoordinates

__all__ = ["BASES", "LINK", "TABLE3", "build", "closed_form_forces", "inverse_kinematics", "point_mass_null_space"]

BASES = np.array([[0.0, 0.25], [0.433, 0.0], [0.433, 0.5]])
"""A1, A2, A3 [m] (paper 001, Section 2)."""
LINK = 0.244
"""Length of every link [m]."""
CENTRE = np.array([0.29, 0.25])
"""Centre of the excitation circle [m] (paper 001, Section 4)."""

TABLE3 = {
    "a": (0.0932, 0.0427, 0.0427),
    "b": (0.0381, 0.0085, 0.0085),
    "c": (0.0426, 0.0111, 0.0111),
}
"""Nominal dynamic parameters of paper 001, Table 3 [kg·m²]."""

TABLE2 = {
    "fv+": (1.6962, 2.1255, 2.3718),
    "fv-": (2.2900, 1.8330, 2.2086),
    "fc+": (0.5156, 0.2647, 0.2762),
    "fc-": (-0.3521, -0.4462, -0.1815),
    "fvb": (0.0026, 0.0013, 0.0004),
}
"""WLS friction estimates of paper 001, Table 2 (weighted observation matrix); N·m·s/rad and N·m."""

# our split of a_i, b_i, c_i into bodies (see module docstring)
_LINK_A = (0.8, 0.10)  # mass [kg], centre of mass along the link [m]
_R_B = (0.15, 0.122, 0.122)  # centre of mass of link B_iO along the link [m]


def _link_inertia(mass: float, r: float, izz_joint: float) -> pin.Inertia:
    """Planar link: mass, COM at (r, 0, 0), Izz about the joint axis."""
    izz_c = izz_joint - mass * r**2
    if izz_c <= 0:
        raise ModelError("inconsistent nominal link inertia")  # pragma: no cover - constants
    return pin.Inertia(mass, np.array([r, 0.0, 0.0]), np.diag([1e-4, izz_c, izz_c]))


def build(extras: object = None) -> Mechanism:
    """The shang2dof mechanism (``extras`` is accepted for the loader's signature and ignored:
    its joint terms are those of paper 001)."""
    model = pin.Model()
    model.name = "shang2dof"
    lo, hi = [], []
    for i in range(3):
        a, b, c = TABLE3["a"][i], TABLE3["b"][i], TABLE3["c"][i]
        mxb = c / LINK
        rb = _R_B[i]
        mb = mxb / rb
        ma, ra = _LINK_A
        izz_a = a - mb * LINK**2  # includes the reflected rotor inertia
        base = pin.SE3(np.eye(3), np.array([BASES[i, 0], BASES[i, 1], 0.0]))
        ja = model.addJoint(0, pin.JointModelRZ(), base, f"qa{i + 1}")
        model.appendBodyToJoint(ja, _link_inertia(ma, ra, izz_a), pin.SE3.Identity())
        jb = model.addJoint(ja, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([LINK, 0.0, 0.0])), f"qb{i + 1}")
        model.appendBodyToJoint(jb, _link_inertia(mb, rb, b), pin.SE3.Identity())
        lo += [-2 * np.pi, 0.0]  # the motors turn freely: no wrap at +-pi (chain 3 rests near -pi)
        hi += [2 * np.pi, np.pi]
    model.lowerPositionLimit = np.array(lo)
    model.upperPositionLimit = np.array(hi)
    tip = pin.SE3(np.eye(3), np.array([LINK, 0.0, 0.0]))
    closures = (
        LoopClosure("O12", 2, tip, 4, tip, "3d"),
        LoopClosure("O13", 2, tip, 6, tip, "3d"),
    )
    terms, nominal = [], {}
    for i in range(3):
        ja = 2 * i
        for kind, key in (("viscous+", "fv+"), ("viscous-", "fv-"), ("coulomb+", "fc+"), ("coulomb-", "fc-")):
            name = f"{key}_qa{i + 1}"
            terms.append(JointTerm(name, kind, (ja,)))
            nominal[name] = TABLE2[key][i]
    for i in range(3):
        name = f"fv_qb{i + 1}"
        terms.append(JointTerm(name, "viscous", (2 * i + 1,)))
        nominal[name] = TABLE2["fvb"][i]
    return Mechanism(
        model,
        closures,
        actuated=(0, 2, 4),
        independent=PointCoordinates(2, tip, (0, 1)),
        terms=tuple(terms),
        nominal_terms=nominal,
        q_guess=inverse_kinematics(CENTRE[None])[0],
        name="shang2dof",
        source="builtin:shang2dof",
        notes=(
            "paper 001 (Shang, Cong & Kong 2009): 3 RR chains meeting at O; 3 actuators for 2 DOF (redundant)",
            "rotor inertia of each actuator is lumped into Izz of its link (a_i of paper 001)",
            "passive-joint viscous friction acts on the relative elbow rate",
            "a point mass at O belongs to any chain: 2 of the 9 a, b, c combinations are not identifiable",
        ),
    )


def inverse_kinematics(xy: FloatArray) -> FloatArray:
    """All six joint positions from the position of O (closed form, elbow angles in (0, π)).

    Parameters
    ----------
    xy : array, shape (n, 2) [m]

    Returns
    -------
    array, shape (n, 6)
        ``[qa1, qb1, qa2, qb2, qa3, qb3]`` with ``qb`` relative (see module docstring).
    """
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    out = np.empty((xy.shape[0], 6))
    for i in range(3):
        d = xy - BASES[i]
        r = np.hypot(d[:, 0], d[:, 1])
        if np.any(r >= 2 * LINK) or np.any(r <= 0):
            bad = int(np.argmax((r >= 2 * LINK) | (r <= 0)))
            raise ModelError(f"point {xy[bad]} is out of reach of chain {i + 1} (distance {r[bad]:.4f} m, reach {2 * LINK} m)")
        half = np.arccos(r / (2 * LINK))  # base angle between A_iO and link A_iB_i
        out[:, 2 * i] = np.arctan2(d[:, 1], d[:, 0]) - half
        out[:, 2 * i + 1] = 2 * half
    out[:, ::2] = np.mod(out[:, ::2] + np.pi, 2 * np.pi) - np.pi
    return out


def closed_form_forces(
    xy: FloatArray,
    dxy: FloatArray,
    ddxy: FloatArray,
    abc: dict[str, FloatArray],
    friction: dict[str, FloatArray],
) -> tuple[FloatArray, FloatArray]:
    """Paper 001, Eqs. 1–6 written out for one set of a, b, c and friction values.

    Independent of the general closed-loop machinery: absolute angles from
    :func:`inverse_kinematics`, chain Jacobians :math:`W_i` by hand, Eq. 1 per chain,
    Eq. 4 for the task-space (projected) equations and Eq. 5 for the minimum-norm
    distribution with the actuator friction added per actuator.

    Parameters
    ----------
    xy, dxy, ddxy : array, shape (n, 2)
        Position, velocity and acceleration of O.
    abc : dict
        ``{"a": (3,), "b": (3,), "c": (3,)}``.
    friction : dict
        Keys of :data:`TABLE2`, each (3,).

    Returns
    -------
    projected : array, shape (n, 2)
        :math:`M_e\\ddot x + C_e\\dot x + W^T f` (Eq. 4; equals :math:`W_a^T\\tau_a`).
    tau : array, shape (n, 3)
        Eq. 5: :math:`(W_a^T)^+ (M_e\\ddot x + C_e\\dot x + W_p^T f_p) + f_a`.
    """
    q = inverse_kinematics(xy)
    n = q.shape[0]
    proj = np.zeros((n, 2))
    rigid_passive = np.zeros((n, 2))
    Wa = np.zeros((n, 3, 2))
    fa = np.zeros((n, 3))
    for i in range(3):
        qa = q[:, 2 * i]
        qb = q[:, 2 * i] + q[:, 2 * i + 1]  # absolute angle of link B_iO
        # x = A + l (cos qa + cos qb, sin qa + sin qb): J = l [[-s_a, -s_b], [c_a, c_b]]
        J = LINK * np.stack([np.stack([-np.sin(qa), -np.sin(qb)], -1), np.stack([np.cos(qa), np.cos(qb)], -1)], 1)
        Jinv = np.linalg.inv(J)
        dqi = np.einsum("nij,nj->ni", Jinv, dxy)
        Jdot_dq = -LINK * np.stack(
            [np.cos(qa) * dqi[:, 0] ** 2 + np.cos(qb) * dqi[:, 1] ** 2, np.sin(qa) * dqi[:, 0] ** 2 + np.sin(qb) * dqi[:, 1] ** 2], -1
        )
        ddqi = np.einsum("nij,nj->ni", Jinv, ddxy - Jdot_dq)
        a, b, c = abc["a"][i], abc["b"][i], abc["c"][i]
        cd, sd = np.cos(qa - qb), np.sin(qa - qb)
        # Eq. 1 with M_i, C_i of paper 001
        t_a = a * ddqi[:, 0] + c * cd * ddqi[:, 1] + c * sd * dqi[:, 1] ** 2
        t_b = c * cd * ddqi[:, 0] + b * ddqi[:, 1] - c * sd * dqi[:, 0] ** 2
        # Eq. 2 (active) and Eq. 3 (passive, on the relative elbow rate)
        va = dqi[:, 0]
        f_act = np.where(va > 0, friction["fc+"][i] + friction["fv+"][i] * va, 0.0) + np.where(
            va < 0, friction["fc-"][i] + friction["fv-"][i] * va, 0.0
        )
        f_rel = friction["fvb"][i] * (dqi[:, 1] - dqi[:, 0])
        # generalized forces in the absolute coordinates (qa, qb) of the chain
        W = Jinv  # (q_a, q_b)-dot = W x-dot
        rigid = np.stack([t_a, t_b], -1)
        passive = np.stack([-f_rel, f_rel], -1)
        proj += np.einsum("nji,nj->ni", W, rigid + passive) + W[:, 0, :] * f_act[:, None]
        rigid_passive += np.einsum("nji,nj->ni", W, rigid + passive)
        Wa[:, i, :] = W[:, 0, :]
        fa[:, i] = f_act
    tau = np.einsum("nak,nk->na", np.linalg.pinv(Wa.transpose(0, 2, 1)), rigid_passive) + fa
    return proj, tau


def point_mass_null_space() -> FloatArray:
    """Two directions of (a1, a2, a3, b1, b2, b3, c1, c2, c3) that leave the dynamics unchanged.

    Moving a point mass at O from chain 1 to chain k adds ``(l², l², l²)`` to ``(a, b, c)``
    of chain k and removes it from chain 1 (all links have length l).
    """
    out = np.zeros((2, 9))
    for row, k in enumerate((1, 2)):
        for off in (0, 3, 6):
            out[row, off + 0] = -LINK**2
            out[row, off + k] = LINK**2
    return out
