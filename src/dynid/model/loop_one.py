"""One sample of a mechanism's kinematics at a time: the velocity map, the independent coordinates'
rates and the joint accelerations of a single configuration, without the batching of
:mod:`dynid.model.loop_kinematics` (the controller and the simulator call it every control period:
:mod:`dynid.simulation.closed_loop`). Split from :mod:`dynid.model.loop_kinematics`, which
re-exports these names."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack as sla_lapack

from dynid._typing import FloatArray
from dynid.errors import ModelError
from dynid.model.closure_geometry import _sides, _skew

# a dynid.model.mechanism.Mechanism, named, not imported (mechanism imports this module's users)
Mechanism = Any


def _one_sample(mech: Mechanism, q: FloatArray, du: FloatArray, ddu: FloatArray, max_cond: float,
                data: pin.Data) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """:func:`states` of one sample, ``q`` (n_v,), ``du``, ``ddu`` (n_u,): ``dq``, ``ddq``, ``G``
    and the condition number. The batched route's formulas on 2-D arrays, with the cross
    products as products by skew matrices (a controller calls it every period, and there the
    batched route's cost is the per-call overhead of some hundred operations on small arrays;
    the two agree to rounding, tests/test_closed_loop.py): :func:`_one_geometry`, then
    :func:`_one_rates`."""
    geometry = _one_geometry(mech, q, data, max_cond)
    dq, ddq = _one_rates(mech, geometry, du, ddu, data)
    return dq, ddq, geometry.G, geometry.cond


class OneGeometry(NamedTuple):
    """What :func:`_one_geometry` computes at one configuration: the world joint Jacobian ``J``
    (6, n_v) (pinocchio's ``data.J``, valid until ``data`` is used again), the skew matrices
    ``Sp`` of the moving sides' points, the assembled rows :math:`[J_c; J_u]` (columns in
    ``_Sides.order``), the inverse of the inverted block, its 1-norm condition number, ``G``,
    the moving sides' points ``pk`` (k, 3) and ``q``."""

    J: FloatArray
    Sp: FloatArray
    rows: FloatArray
    inv: FloatArray
    cond: float
    G: FloatArray
    pk: FloatArray
    q: FloatArray


def _one_geometry(mech: Mechanism, q: FloatArray, data: pin.Data, max_cond: float) -> OneGeometry:
    """The velocity map of one sample: one ``computeJointJacobians`` pass, the moving sides'
    points :math:`R r + t`, the rows :math:`J_v - [p]_\\times J_\\omega` of all sides at once
    stacked by ``_Sides.T`` (its linear columns only where no row reads an angular one: the
    same sums without the exact zeros), and the LU inverse of the square block."""
    sd = _sides(mech)
    nv = q.size
    J = pin.computeJointJacobians(mech.pin_model, data, q)
    oMi = data.oMi
    H = np.array([oMi[j].homogeneous for j in sd.joints]) if sd.joints else np.zeros((1, 4, 4))
    pk = np.matmul(H[sd.slot_k, :3], sd.r1_k)[:, :, 0]  # R r + t
    if sd.any_ground_k:
        pk[sd.ground_k] = sd.r_k[sd.ground_k]
    Sp = _skew(pk)
    Jk = (J if sd.identity_order else J[:, sd.order]) * sd.side_mask  # (moving sides, 6, n_v)
    Jw = Jk[:, 3:]
    if sd.lin_only:
        rows = sd.T_lin @ (Jk[:, :3] - Sp @ Jw).reshape(-1, nv)
    else:
        rows = sd.T @ np.concatenate([Jk[:, :3] - Sp @ Jw, Jw], axis=1).reshape(-1, nv)
    joint_coords = sd.u is not None
    nw = sd.w.size if joint_coords else nv
    inv, cond = _invert_one(rows[:, :nw] if joint_coords else rows, max_cond,
                            "the loop-closure Jacobian of the dependent joints" if joint_coords else "[J_c; J_u]")
    if joint_coords:
        G = sd.G_template.copy()
        G[sd.w] = -(inv @ rows[:, nw:])
    else:
        G = np.ascontiguousarray(inv[:, nv - mech.independent.size :])
    return OneGeometry(J, Sp, rows, inv, cond, G, pk, q)


def _one_coordinates(mech: Mechanism, geometry: OneGeometry, dq: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """The independent coordinates and their rates at ``geometry``'s configuration with joint
    velocities ``dq``: joint coordinates read off ``q`` and ``dq``; point coordinates from the
    computed point and the coordinate rows of :math:`[J_c; J_u]`. None where the point lies on
    the fixed base."""
    sd = _sides(mech)
    if sd.u is not None:
        return geometry.q[sd.u], dq[sd.u]
    if sd.coordinate_side is None:
        return None
    return geometry.pk.take(sd.coordinate_index), geometry.rows[-sd.coordinate_index.size :] @ dq


def _one_rates(mech: Mechanism, geometry: OneGeometry, du: FloatArray, ddu: FloatArray,
               data: pin.Data) -> tuple[FloatArray, FloatArray]:
    """``dq`` and ``ddq`` of one sample from those of the independent coordinates
    (:math:`\\dot q = G\\dot u`, :math:`\\ddot q = G\\ddot u + \\ddot q_0`): one
    ``computeJointJacobiansTimeVariation`` pass for the drift :math:`\\dot J \\dot q` of the
    sides' points (classical accelerations, module docstring)."""
    sd = _sides(mech)
    J, Sp, rows, inv, _, G, _, q = geometry
    dq = G @ du
    n_rows = rows.shape[0]
    drift = np.zeros(n_rows)
    if sd.moving.size:
        pin.computeJointJacobiansTimeVariation(mech.pin_model, data, q, dq)
        # spatial velocity and acceleration (at q-ddot = 0) of every body at the world origin,
        # rows [v, omega, a, alpha] of 3 (J and dJ stacked: one product)
        X = (dq * sd.body_mask_q) @ np.concatenate([J, data.dJ]).T  # (bodies, 12)
        X = (X if sd.identity_bodies else X[sd.body_of]).reshape(-1, 4, 3)  # (moving sides, 4, 3)
        w = X[:, 1]
        # p x [omega; alpha] as rows: v_p = v + omega x p, a_p = a + alpha x p + omega x v_p
        px = X[:, 1::2] @ Sp.transpose(0, 2, 1)
        vp = X[:, 0] - px[:, 0]
        lin = X[:, 2] - px[:, 1] + (_skew(w) @ vp[:, :, None])[:, :, 0]
        if sd.lin_only:
            drift = lin.reshape(-1) @ sd.T_linT
        else:
            drift = np.concatenate([lin, X[:, 3]], axis=1).reshape(-1) @ sd.TT
    if sd.u is not None:
        ddq = np.empty(q.size)
        ddq[sd.u] = ddu
        ddq[sd.w] = inv @ (-(rows[:, sd.w.size :] @ ddu) - drift)
    else:
        ddq = G @ ddu - inv @ drift
    return dq, ddq


def _invert_one(A: FloatArray, max_cond: float, what: str) -> tuple[FloatArray, float]:
    """:func:`_invert` of one square matrix, by LAPACK's LU directly."""
    lu, piv, info = sla_lapack.dgetrf(A)
    inv = None
    if info == 0:
        inv, info = sla_lapack.dgetri(lu, piv)
    cond = float(np.abs(A).sum(axis=0).max() * np.abs(inv).sum(axis=0).max()) if info == 0 else np.inf
    if not cond <= max_cond:  # above it, infinite or NaN
        raise ModelError(f"sample 0: singular configuration (condition number of {what} = {cond:.3g} > {max_cond:.3g})")
    return inv, cond
