"""Velocity and acceleration maps of closed-loop mechanisms, batched over samples.

Per sample only pinocchio is called (``computeJointJacobians`` for :math:`J` and the joint
placements, ``computeJointJacobiansTimeVariation`` for :math:`\\dot J`); everything else is
numpy on whole arrays. With the world-frame joint Jacobian :math:`J = [J_v; J_\\omega]`
(spatial velocity at the world origin) restricted to the support of a body, a point
:math:`p` (world coordinates) of that body has

.. math::

    v_p = J_v\\dot q - p\\times(J_\\omega\\dot q), \\qquad
    a_p = \\dot J_v\\dot q - p\\times(\\dot J_\\omega \\dot q) + \\omega\\times v_p
    \\quad (\\ddot q = 0),

(Featherstone, *Rigid Body Dynamics Algorithms*, §2.11: classical from spatial
acceleration). Loop closures stack :math:`v_{p,b} - v_{p,a}` (and
:math:`\\omega_b - \\omega_a` for ``6d``); their independent rows plus the independent
coordinates form the square matrix :math:`A = [J_c; J_u]`, inverted in batch:
:math:`G = A^{-1}[0; I]`, :math:`\\ddot q = G\\ddot u - A^{-1}[\\dot J_c\\dot q; \\dot J_u \\dot q]`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.mechanism import JointCoordinates, KinematicState, Mechanism

__all__ = ["kinematic_state", "states", "velocity_matrices"]


class _Sides:
    """Closure sides (and the point coordinate) of a mechanism, grouped by joint."""

    def __init__(self, mech: Mechanism) -> None:
        m = mech.pin_model
        sides = []
        for c in mech.closures:
            sides += [(c.joint_a, c.placement_a), (c.joint_b, c.placement_b)]
        ind = mech.independent
        if not isinstance(ind, JointCoordinates):
            sides.append((ind.joint, ind.placement))
        self.joints = sorted({j for j, _ in sides if j != 0})
        slot = {j: k for k, j in enumerate(self.joints)}
        self.slot = np.array([slot.get(j, -1) for j, _ in sides])
        self.r = np.array([pl.translation for _, pl in sides])
        self.masks = np.zeros((len(sides), m.nv))
        for s, (j, _) in enumerate(sides):
            if j != 0:
                for k in m.supports[j].tolist()[1:]:
                    jm = m.joints[k]
                    self.masks[s, jm.idx_v : jm.idx_v + jm.nv] = 1.0
        self.kinds = [c.kind for c in mech.closures]


def _sides(mech: Mechanism) -> _Sides:
    cached = mech.__dict__.get("_sides_cache")
    if cached is None:
        cached = _Sides(mech)
        object.__setattr__(mech, "_sides_cache", cached)
    return cached


def _placements(mech: Mechanism, q: FloatArray, data: pin.Data) -> tuple[FloatArray, FloatArray, FloatArray]:
    """World Jacobians (n, 6, n_v) and placements (n, k, 3), (n, k, 3, 3) of the side joints."""
    sd = _sides(mech)
    model = mech.pin_model
    n, nv = q.shape
    J = np.empty((n, 6, nv))
    T = np.zeros((n, max(len(sd.joints), 1), 3))
    R = np.zeros((n, max(len(sd.joints), 1), 3, 3))
    cjj = pin.computeJointJacobians
    oMi = data.oMi
    joints = sd.joints
    for i in range(n):
        J[i] = cjj(model, data, q[i])
        for k, j in enumerate(joints):
            M = oMi[j]
            T[i, k] = M.translation
            R[i, k] = M.rotation
    return J, T, R


def _cross_cols(p: FloatArray, M: FloatArray) -> FloatArray:
    """``p x M[..., :, k]`` for every column k: p (n, s, 3), M (n, s, 3, m)."""
    px, py, pz = (p[..., i, None] for i in range(3))
    mx, my, mz = M[..., 0, :], M[..., 1, :], M[..., 2, :]
    return np.stack([py * mz - pz * my, pz * mx - px * mz, px * my - py * mx], axis=-2)


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise cross product of (..., 3) arrays (faster than np.cross on small rows)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def _side_geometry(mech: Mechanism, J: FloatArray, T: FloatArray, R: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per side: world point (n, s, 3), linear (n, s, 3, n_v) and angular (n, s, 3, n_v) Jacobians."""
    sd = _sides(mech)
    n = J.shape[0]
    ns = sd.slot.size
    p = np.zeros((n, ns, 3))
    base = sd.slot < 0
    on = ~base
    p[:, on] = T[:, sd.slot[on]] + np.einsum("nsij,sj->nsi", R[:, sd.slot[on]], sd.r[on])
    p[:, base] = sd.r[base]
    Jv = J[:, None, :3, :] * sd.masks[None, :, None, :]
    Jw = J[:, None, 3:, :] * sd.masks[None, :, None, :]
    Jp = Jv - _cross_cols(p, Jw)
    return p, Jp, Jw


def _stack_rows(mech: Mechanism, lin: FloatArray, ang: FloatArray) -> FloatArray:
    """Constraint rows (independent ones) and coordinate rows from per-side quantities.

    ``lin``/``ang`` have shape (n, s, 3, ...) ; returns (n, n_v, ...)."""
    sd = _sides(mech)
    rows = []
    for c, kind in enumerate(sd.kinds):
        a, b = 2 * c, 2 * c + 1
        rows.append(lin[:, b] - lin[:, a])
        if kind == "6d":
            rows.append(ang[:, b] - ang[:, a])
    stacked = np.concatenate(rows, axis=1)[:, mech.constraint_rows]
    ind = mech.independent
    if isinstance(ind, JointCoordinates):
        return stacked
    return np.concatenate([stacked, lin[:, -1][:, list(ind.axes)]], axis=1)


def velocity_matrices(mech: Mechanism, q: FloatArray, data: pin.Data | None = None) -> tuple[FloatArray, tuple]:
    """Rows :math:`[J_c; J_u]` per sample, shape (n, n_v, n_v) (for joint coordinates only the
    constraint rows, shape (n, n_v - n_u, n_v)), and the geometry for reuse."""
    data = mech.pin_model.createData() if data is None else data
    J, T, R = _placements(mech, q, data)
    p, Jp, Jw = _side_geometry(mech, J, T, R)
    return _stack_rows(mech, Jp, Jw), (J, p)


def _invert(A: FloatArray, max_cond: float, what: str = "[J_c; J_u]") -> tuple[FloatArray, FloatArray]:
    """Batched inverse and 1-norm condition numbers; a one-line error at the first singular sample."""
    try:
        Ainv = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        Ainv = np.full_like(A, np.inf)
        for i in range(A.shape[0]):
            try:
                Ainv[i] = np.linalg.inv(A[i])
            except np.linalg.LinAlgError:
                pass
    cond = np.abs(A).sum(axis=1).max(axis=1) * np.abs(Ainv).sum(axis=1).max(axis=1)
    bad = ~np.isfinite(cond) | (cond > max_cond)
    if np.any(bad):
        worst = int(np.flatnonzero(bad)[0])
        raise ModelError(
            f"sample {worst}: singular configuration (condition number of {what} = {cond[worst]:.3g} > {max_cond:.3g})"
        )
    return Ainv, cond


class _Maps:
    """Solution of :math:`A x = [0; b_u] - [d_c; d_u]` per sample, and :math:`G`.

    Joint coordinates: with :math:`J_c = [J_{cu}\\; J_{cw}]` (independent joints u, the
    others w), :math:`\\dot q_w = -J_{cw}^{-1}J_{cu}\\dot u` -- only the
    :math:`(n_v - n_u)`-square block is inverted. Point coordinates: the full
    :math:`A = [J_c; J_u]` is. The condition number reported is that of the inverted matrix
    (1-norm).
    """

    def __init__(self, mech: Mechanism, rows: FloatArray, max_cond: float) -> None:
        n = rows.shape[0]
        nv, n_u = mech.nv, mech.independent.size
        ind = mech.independent
        if isinstance(ind, JointCoordinates):
            u = np.array(ind.joints)
            w = np.setdiff1d(np.arange(nv), u)
            self.u, self.w = u, w
            Jcw = rows[:, :, w]
            self.inv, self.cond = _invert(Jcw, max_cond, "the loop-closure Jacobian of the dependent joints")
            X = np.matmul(self.inv, rows[:, :, u])
            G = np.zeros((n, nv, n_u))
            G[:, u, np.arange(n_u)] = 1.0
            G[:, w, :] = -X
            self.Jcu = rows[:, :, u]
        else:
            self.u = None
            self.inv, self.cond = _invert(rows, max_cond)
            G = np.ascontiguousarray(self.inv[:, :, nv - n_u :])
        self.G = G

    def accelerations(self, ddu: FloatArray, drift: FloatArray) -> FloatArray:
        """:math:`\\ddot q` from :math:`\\ddot u` and the drift terms (n, rows)."""
        if self.u is None:
            return np.einsum("nij,nj->ni", self.G, ddu) - np.einsum("nij,nj->ni", self.inv, drift)
        n = ddu.shape[0]
        ddq = np.empty((n, self.G.shape[1]))
        ddq[:, self.u] = ddu
        rhs = -np.einsum("nij,nj->ni", self.Jcu, ddu) - drift
        ddq[:, self.w] = np.einsum("nij,nj->ni", self.inv, rhs)
        return ddq


def _drift(mech: Mechanism, q: FloatArray, dq: FloatArray, J: FloatArray, p: FloatArray, data: pin.Data) -> FloatArray:
    """:math:`[\\dot J_c\\dot q; \\dot J_u\\dot q]` per sample, shape (n, n_v)."""
    sd = _sides(mech)
    model = mech.pin_model
    n, nv = q.shape
    dJ = np.empty((n, 6, nv))
    tv = pin.computeJointJacobiansTimeVariation
    for i in range(n):
        tv(model, data, q[i], dq[i])
        dJ[i] = data.dJ
    V = np.einsum("nkv,sv,nv->nsk", J, sd.masks, dq)  # (n, s, 6) spatial velocity at the origin
    Ad = np.einsum("nkv,sv,nv->nsk", dJ, sd.masks, dq)
    w = V[..., 3:]
    vp = V[..., :3] + _cross(w, p)
    ap = Ad[..., :3] + _cross(Ad[..., 3:], p) + _cross(w, vp)
    return _stack_rows(mech, ap, Ad[..., 3:])


def _check(mech: Mechanism, x: FloatArray, shape: tuple[int, int], name: str) -> FloatArray:
    x = np.atleast_2d(np.asarray(x, dtype=float))
    if x.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError(f"{name} contains NaN or infinite values")
    return x


def states(mech: Mechanism, q: FloatArray, du: FloatArray, ddu: FloatArray, *, max_cond: float = 1e8) -> KinematicState:
    """See :meth:`Mechanism.states`."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    q = _check(mech, q, (n, mech.nv), "q")
    n_u = mech.independent.size
    du = _check(mech, du, (n, n_u), "du")
    ddu = _check(mech, ddu, (n, n_u), "ddu")
    data = mech.pin_model.createData()
    rows, (J, p) = velocity_matrices(mech, q, data)
    maps = _Maps(mech, rows, max_cond)
    dq = np.einsum("nij,nj->ni", maps.G, du)
    drift = _drift(mech, q, dq, J, p, data)
    return KinematicState(q=q, dq=dq, ddq=maps.accelerations(ddu, drift), G=maps.G, cond=maps.cond)


def kinematic_state(mech: Mechanism, q: FloatArray, dq: FloatArray, ddq: FloatArray, *, max_cond: float = 1e8) -> KinematicState:
    """See :meth:`Mechanism.kinematic_state`."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    q = _check(mech, q, (n, mech.nv), "q")
    dq = _check(mech, dq, (n, mech.nv), "dq")
    ddq = _check(mech, ddq, (n, mech.nv), "ddq")
    maps = _Maps(mech, velocity_matrices(mech, q)[0], max_cond)
    return KinematicState(q=q, dq=dq, ddq=ddq, G=maps.G, cond=maps.cond)
