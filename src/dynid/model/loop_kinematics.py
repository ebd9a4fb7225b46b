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

from typing import Any, NamedTuple

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack as sla_lapack

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model import loop_batch
from dynid.model.closures import JointCoordinates, KinematicState
from dynid.tolerances import scaled

# The functions here take a dynid.model.mechanism.Mechanism, whose methods call them: the type is
# named, not imported, so that the two modules do not import each other (not even for typing).
Mechanism = Any

__all__ = ["actuator_states", "kinematic_state", "platform_pose", "pose_states", "states"]


class _Sides:
    """Closure sides (and the point coordinate) of a mechanism.

    On an assembled configuration the two points (frames) of a closure coincide, so the
    world position of only one side per closure is read from pinocchio: the side on the
    joint shared by most closures (the platform of a hexapod: one placement read per
    sample instead of seven). ``states``/``kinematic_state`` take assembled positions.
    """

    def __init__(self, mech: Mechanism) -> None:
        m = mech.pin_model
        sides = []
        for c in mech.closures:
            sides += [(c.joint_a, c.placement_a), (c.joint_b, c.placement_b)]
        ind = mech.independent
        if not isinstance(ind, JointCoordinates):
            sides.append((ind.joint, ind.placement))
        count: dict[int, int] = {}
        for j, _ in sides:
            count[j] = count.get(j, 0) + 1
        # side whose position stands for each side (its closure's reference side)
        self.source = np.arange(len(sides))
        for c in range(len(mech.closures)):
            a, b = 2 * c, 2 * c + 1
            ja, jb = sides[a][0], sides[b][0]
            ref = a if (ja == 0 or (jb != 0 and count[ja] >= count[jb])) else b
            self.source[a] = self.source[b] = ref
        self.ref = np.unique(self.source)  # sides whose positions are computed
        self.joints = sorted({sides[s][0] for s in self.ref if sides[s][0] != 0})  # placements read
        slot = {j: k for k, j in enumerate(self.joints)}
        self.slot = np.array([slot.get(sides[s][0], -1) for s in self.ref])
        self.r = np.array([sides[s][1].translation for s in self.ref])
        self.ref_index = np.searchsorted(self.ref, self.source)  # side -> row of the computed points
        self.n_sides = len(sides)
        self.side_joints = [j for j, _ in sides]  # the joint (body) of each side
        # support columns of each side: the velocity indices that move its body
        self.columns = []
        for j, _ in sides:
            cols = []
            if j != 0:
                for a in m.supports[j].tolist()[1:]:
                    jm = m.joints[a]
                    cols.extend(range(jm.idx_v, jm.idx_v + jm.nv))
            self.columns.append(np.array(sorted(cols), dtype=int))
        # column order of the assembled rows: dependent joints w first, then the independent
        # joints u (so that J_cw and J_cu are contiguous blocks); identity for point coordinates
        if isinstance(ind, JointCoordinates):
            u = np.array(ind.joints, dtype=int)
            w = np.setdiff1d(np.arange(m.nv), u)
            order = np.concatenate([w, u])
        else:
            order = np.arange(m.nv)
        self.u, self.w = (u, w) if isinstance(ind, JointCoordinates) else (None, None)
        self.order = order
        position = np.empty(m.nv, dtype=int)
        position[order] = np.arange(m.nv)
        self.out_columns = [position[c] for c in self.columns]
        self.kinds = [c.kind for c in mech.closures]
        # row offset of each closure in the full (redundant) constraint vector
        self.offsets = np.cumsum([0] + [3 if k == "3d" else 6 for k in self.kinds])
        # one sample (:func:`_one_sample`, a controller's call) takes all sides at once (the
        # batched route goes side by side: over many samples the sides' own column slices are
        # cheaper than masks over all columns): the sides on a moving body ("moving"), the
        # bodies that carry them (each with its support columns as a 0/1 mask, in the output
        # column order), and the
        # constant matrix T that stacks the sides' [linear; angular] rows (6 per moving side)
        # into the output rows: + side b - side a per closure, only the independent constraint
        # rows, then the point coordinate's rows. Its entries are 0 and +-1 and every output
        # element has at most two non-zero terms, so T @ rows is exactly the side-by-side
        # subtraction (products by +-1 and sums with 0 are exact in floating point).
        self.moving = np.array([s for s in range(len(sides)) if self.columns[s].size], dtype=int)
        bodies = sorted({sides[s][0] for s in self.moving})
        self.body_of = np.array([bodies.index(sides[s][0]) for s in self.moving], dtype=int)
        self.body_columns = [self.columns[self.moving[list(self.body_of).index(b)]] for b in range(len(bodies))]
        self.body_mask = np.zeros((len(bodies), m.nv))  # support columns of each body, output column order
        self.body_mask_q = np.zeros((len(bodies), m.nv))  # the same in the joints' own order
        for b, cols in enumerate(self.body_columns):
            self.body_mask[b, position[cols]] = 1.0
            self.body_mask_q[b, cols] = 1.0
        row_of = {int(s): k for k, s in enumerate(self.moving)}
        full = np.zeros((int(self.offsets[-1]), 6 * len(self.moving)))
        for c, kind in enumerate(self.kinds):
            r0 = int(self.offsets[c])
            for s, sign in ((2 * c + 1, 1.0), (2 * c, -1.0)):
                if s not in row_of:
                    continue
                k = 6 * row_of[s]
                full[r0 : r0 + 3, k : k + 3] += sign * np.eye(3)
                if kind == "6d":
                    full[r0 + 3 : r0 + 6, k + 3 : k + 6] += sign * np.eye(3)
        T = full[mech.constraint_rows]
        if not isinstance(ind, JointCoordinates):
            extra = np.zeros((len(ind.axes), full.shape[1]))
            s = len(sides) - 1
            if s in row_of:
                extra[np.arange(len(ind.axes)), 6 * row_of[s] + np.array(ind.axes)] = 1.0
            T = np.vstack([T, extra])
        self.T = np.ascontiguousarray(T)
        # one sample (:func:`_one_sample`): the placements' slots of the computed points, which of
        # them lie on the ground, and the computed point of every moving side
        self.slot0 = np.where(self.slot < 0, 0, self.slot)
        self.on_ground = self.slot < 0
        self.moving_ref = self.ref_index[self.moving]
        self.side_mask = self.body_mask[self.body_of][:, None, :]  # (moving sides, 1, n_v)
        self.any_ground = bool(self.on_ground.any())
        self.r1 = np.concatenate([self.r, np.ones((len(self.r), 1))], axis=1)[:, :, None]  # homogeneous
        if isinstance(ind, JointCoordinates):  # G = dq/du: the identity on the independent joints
            self.G_template = np.zeros((m.nv, ind.size))
            self.G_template[u, np.arange(ind.size)] = 1.0
        # per-call constants of :func:`_one_geometry` and :func:`_one_rates` (fewer operations on
        # small arrays, each exact: a selection of elements, or the matrix T without its all-zero
        # columns): the moving sides' own slots, homogeneous points and ground flags; whether the
        # joint order, the bodies' order are the identity; T on the linear columns only when no
        # output row reads an angular one (point closures, point coordinates); the point
        # coordinate's moving side
        k_ref = self.moving_ref
        self.slot_k, self.r1_k, self.r_k = self.slot0[k_ref], self.r1[k_ref], self.r[k_ref]
        self.ground_k = self.on_ground[k_ref]
        self.any_ground_k = bool(self.ground_k.any())
        self.identity_order = bool(np.array_equal(order, np.arange(m.nv)))
        self.identity_bodies = bool(np.array_equal(self.body_of, np.arange(self.body_of.size)))
        ang = (np.arange(self.T.shape[1]) % 6) >= 3
        self.lin_only = not self.T[:, ang].any()
        self.T_lin = np.ascontiguousarray(self.T[:, ~ang])
        self.TT, self.T_linT = np.ascontiguousarray(self.T.T), np.ascontiguousarray(self.T_lin.T)
        side = None if isinstance(ind, JointCoordinates) else row_of.get(len(sides) - 1)
        self.coordinate_side = side  # flat indices of the point coordinates among the points (k, 3)
        self.coordinate_index = None if side is None else 3 * side + np.array(ind.axes, dtype=int)


class _Closures:
    """The loop closures' sides for the residual and the Jacobian at any configuration (assembled
    or not: :meth:`Mechanism.project`, :meth:`Mechanism.solve_positions`, :func:`actuator_states`),
    each side at its own point. Built from the tree and the closures alone (the mechanism's
    constraint rows are not needed: the topology check uses it before they are known)."""

    def __init__(self, mech: Mechanism) -> None:
        m = mech.pin_model
        sides = []
        for c in mech.closures:
            sides += [(c.joint_a, c.placement_a), (c.joint_b, c.placement_b)]
        self.joints = sorted({j for j, _ in sides if j != 0})  # placements read
        slot = {j: k for k, j in enumerate(self.joints)}
        self.slot = np.array([slot.get(j, 0) for j, _ in sides], dtype=int)
        self.ground = np.array([j == 0 for j, _ in sides], dtype=bool)
        self.any_ground = bool(self.ground.any())
        self.r = np.array([pl.translation for _, pl in sides], dtype=float).reshape(-1, 3)
        self.r1 = np.concatenate([self.r, np.ones((len(sides), 1))], axis=1)[:, :, None]  # homogeneous
        self.rotations = np.array([pl.rotation for _, pl in sides], dtype=float).reshape(-1, 3, 3)
        self.kinds = [c.kind for c in mech.closures]
        self.offsets = np.cumsum([0] + [3 if k == "3d" else 6 for k in self.kinds])
        self.all_3d = all(k == "3d" for k in self.kinds)
        self.moving = np.array([s for s, (j, _) in enumerate(sides) if j != 0], dtype=int)
        self.mask = np.zeros((self.moving.size, 1, m.nv))  # support columns of each moving side's body
        for k, s in enumerate(self.moving):
            for a in m.supports[sides[s][0]].tolist()[1:]:
                jm = m.joints[a]
                self.mask[k, 0, jm.idx_v : jm.idx_v + jm.nv] = 1.0
        # [linear; angular] rows of the moving sides -> closure rows (side b minus side a; exact,
        # as _Sides.T: entries 0 and +-1, at most two non-zero terms per element)
        row_of = {int(s): k for k, s in enumerate(self.moving)}
        T = np.zeros((int(self.offsets[-1]), 6 * self.moving.size))
        for c, kind in enumerate(self.kinds):
            r0 = int(self.offsets[c])
            for s, sign in ((2 * c + 1, 1.0), (2 * c, -1.0)):
                if s in row_of:
                    k = 6 * row_of[s]
                    T[r0 : r0 + 3, k : k + 3] += sign * np.eye(3)
                    if kind == "6d":
                        T[r0 + 3 : r0 + 6, k + 3 : k + 6] += sign * np.eye(3)
        self.T = T

    def frames(self, data: pin.Data) -> tuple[FloatArray, FloatArray]:
        """World positions (sides, 3) of every side point and the joints' homogeneous placements
        (slots, 4, 4), from the placements in ``data`` (after a kinematics pass)."""
        oMi = data.oMi
        H = np.array([oMi[j].homogeneous for j in self.joints]) if self.joints else np.zeros((1, 4, 4))
        Hs = H[self.slot]
        P = np.matmul(Hs[:, :3], self.r1)[:, :, 0]  # R r + t
        if self.any_ground:
            P[self.ground] = self.r[self.ground]
        return P, Hs

    def rotation(self, Hs: FloatArray, s: int) -> FloatArray:
        """World orientation of side ``s``'s frame."""
        return self.rotations[s] if self.ground[s] else Hs[s, :3, :3] @ self.rotations[s]


def _closures(mech: Mechanism) -> _Closures:
    cached = mech.__dict__.get("_closures_cache")
    if cached is None:
        cached = _Closures(mech)
        object.__setattr__(mech, "_closures_cache", cached)
    return cached


_EPS = float(np.finfo(float).eps)


def row_space(A: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """Householder QR of :math:`A^T` (A: m x n, m <= n, full row rank): ``Q`` (n, m) with
    orthonormal columns spanning the rows of A and ``R`` (m, m) in the upper triangle of the
    returned block (below it: Householder vectors), :math:`A = R^T Q^T`. None when A is
    (numerically) rank deficient: a diagonal element of R at or below ``max(m, n) eps`` of the
    largest (:func:`numpy.linalg.lstsq`'s default cut on the singular values), where a caller
    falls back to the SVD. Three LAPACK calls instead of an SVD: the projection onto the loop
    closures runs every control period, the position solve of :func:`actuator_states` every sample."""
    m, n = A.shape
    if m > n or not m:
        return None
    qr, tau, _, info = sla_lapack.dgeqrf(A.T)
    d = np.abs(qr.diagonal())
    if info != 0 or not d.min() > max(m, n) * _EPS * d.max():
        return None
    Q, _, info = sla_lapack.dorgqr(qr, tau)
    return (Q, qr[:m]) if info == 0 else None


def lstsq_full_rank(A: FloatArray, b: FloatArray) -> FloatArray:
    """``np.linalg.lstsq(A, b, rcond=None)[0]`` (to rounding) where A (m x n) has full rank: for
    m <= n the minimum-norm solution :math:`x = Q R^{-T} b` (:func:`row_space`), for m > n the
    least-squares solution :math:`x = R^{-1} Q^T b` of :math:`A = QR`; the SVD where A is rank
    deficient (a singular configuration)."""
    m, n = A.shape
    if m <= n:
        f = row_space(A)
        if f is not None:
            y, info = sla_lapack.dtrtrs(f[1], b, lower=0, trans=1)
            if info == 0:
                return f[0] @ y
    else:
        qr, tau, _, info = sla_lapack.dgeqrf(A)
        d = np.abs(qr.diagonal())
        if info == 0 and d.min() > m * _EPS * d.max():
            Q, _, info = sla_lapack.dorgqr(qr, tau)
            if info == 0:
                x, info = sla_lapack.dtrtrs(qr[:n], Q.T @ b, lower=0, trans=0)
                if info == 0:
                    return x
    return np.linalg.lstsq(A, b, rcond=None)[0]


def closure_geometry(mech: Mechanism, q: FloatArray, data: pin.Data, jacobian: bool = True) -> tuple:
    """One kinematics pass at ``q`` for :func:`closure_residual` and :func:`closure_jacobian`:
    the joint Jacobians (with the placements; None with ``jacobian=False``: the placements only),
    the sides' points and their joints' placements."""
    if jacobian:
        J = pin.computeJointJacobians(mech.pin_model, data, q)
    else:
        J = None
        pin.forwardKinematics(mech.pin_model, data, q)
    return (J, *_closures(mech).frames(data))


def closure_residual(mech: Mechanism, q: FloatArray, data: pin.Data, geometry: tuple | None = None) -> FloatArray:
    """:math:`c(q)` stacked over the closures (all rows): point gaps and, for ``6d``, the
    relative rotation vector :math:`R_a\\log_3(R_a^T R_b)` in world axes; one forward
    kinematics pass (or ``geometry``, :func:`closure_geometry` at ``q``), the sides' points at once."""
    cl = _closures(mech)
    _, P, Hs = closure_geometry(mech, q, data, jacobian=False) if geometry is None else geometry
    gap = P[1::2] - P[0::2]  # (closures, 3): side b minus side a
    if cl.all_3d:
        return gap.reshape(-1)
    out = []
    for c, kind in enumerate(cl.kinds):
        out.append(gap[c])
        if kind == "6d":
            Ra, Rb = cl.rotation(Hs, 2 * c), cl.rotation(Hs, 2 * c + 1)
            out.append(Ra @ pin.log3(Ra.T @ Rb))
    return np.concatenate(out)


def closure_jacobian(mech: Mechanism, q: FloatArray, data: pin.Data, exact: bool = False,
                     geometry: tuple | None = None) -> FloatArray:
    """:math:`J_c(q)` (all rows, the joints' own column order), each side at its own point:
    :math:`J_v - [p]_\\times J_\\omega` on the support of its body. ``exact``: the rotation rows of
    ``6d`` closures are :math:`\\partial\\log_3/\\partial q` (for Newton), otherwise the relative
    angular velocity in the world frame (same null space). ``geometry``: :func:`closure_geometry`
    at ``q`` (with the Jacobians)."""
    cl = _closures(mech)
    J, P, Hs = closure_geometry(mech, q, data) if geometry is None or geometry[0] is None else geometry
    if not cl.moving.size:
        return np.zeros((cl.T.shape[0], q.size))
    Jk = J * cl.mask  # (moving sides, 6, n_v)
    Jw = Jk[:, 3:]
    rows = cl.T @ np.concatenate([Jk[:, :3] - _skew(P[cl.moving]) @ Jw, Jw], axis=1).reshape(-1, q.size)
    if exact and not cl.all_3d:  # d/dt of Ra log3(Ra^T Rb), Ra held constant (exact at the solution)
        for c, kind in enumerate(cl.kinds):
            if kind == "6d":
                r0 = int(cl.offsets[c]) + 3
                Ra, Rb = cl.rotation(Hs, 2 * c), cl.rotation(Hs, 2 * c + 1)
                rows[r0 : r0 + 3] = Ra @ pin.Jlog3(Ra.T @ Rb) @ Rb.T @ rows[r0 : r0 + 3]
    return rows


class _PointRows:
    """Constants of :func:`point_closure_rows`: the moving sides' slots and homogeneous points,
    the residual's signed selection ``D`` of their coordinates and the constant ``d0`` of the
    sides on the ground, and ``_Closures.T`` on the linear columns, both on the independent
    constraint rows only. Entries 0 and +-1 with at most two non-zero terms per row: the
    products are the side-by-side differences exactly (as ``_Closures.T``)."""

    def __init__(self, mech: Mechanism) -> None:
        cl = _closures(mech)
        rows = mech.constraint_rows
        k = cl.moving.size
        self.slot, self.r1 = cl.slot[cl.moving], cl.r1[cl.moving]
        self.mask = cl.mask
        D = np.zeros((int(cl.offsets[-1]), 3 * k))
        d0 = np.zeros(int(cl.offsets[-1]))
        index = {int(s): i for i, s in enumerate(cl.moving)}
        for c in range(len(cl.kinds)):
            r0 = int(cl.offsets[c])
            for s, sign in ((2 * c + 1, 1.0), (2 * c, -1.0)):
                if s in index:
                    D[r0 : r0 + 3, 3 * index[s] : 3 * index[s] + 3] = sign * np.eye(3)
                else:
                    d0[r0 : r0 + 3] = sign * cl.r[s]
        self.D, self.d0 = np.ascontiguousarray(D[rows]), d0[rows]
        ang = (np.arange(cl.T.shape[1]) % 6) >= 3
        self.T = np.ascontiguousarray(cl.T[rows][:, ~ang])


def point_closure_rows(mech: Mechanism, q: FloatArray, data: pin.Data) -> tuple[FloatArray, FloatArray]:
    """:func:`closure_residual` and :func:`closure_jacobian` on the independent constraint rows
    for point closures only (``"3d"``; :meth:`Mechanism.project`, every control period): one
    ``computeJointJacobians`` pass, the points of the moving sides only, each row the same
    difference of two sides as there (the same values), without the angular rows' zeros."""
    pr = mech.__dict__.get("_point_rows_cache")
    if pr is None:
        pr = _PointRows(mech)
        object.__setattr__(mech, "_point_rows_cache", pr)
    J = pin.computeJointJacobians(mech.pin_model, data, q)
    oMi = data.oMi
    H = np.array([oMi[j].homogeneous for j in _closures(mech).joints])
    P = np.matmul(H[pr.slot, :3], pr.r1)[:, :, 0]  # (moving sides, 3): R r + t
    Jk = J * pr.mask  # (moving sides, 6, n_v)
    Jw = Jk[:, 3:]
    return pr.D @ P.reshape(-1) + pr.d0, pr.T @ (Jk[:, :3] - _skew(P) @ Jw).reshape(-1, q.size)


def _sides(mech: Mechanism) -> _Sides:
    cached = mech.__dict__.get("_sides_cache")
    if cached is None:
        cached = _Sides(mech)
        object.__setattr__(mech, "_sides_cache", cached)
    return cached


def _placements(mech: Mechanism, q: FloatArray, data: pin.Data) -> tuple[FloatArray, FloatArray]:
    """World Jacobians (n, 6, n_v) and homogeneous placements (n, k, 4, 4) of the side joints.

    The placements through :func:`dynid.model.loop_batch.placement_view` (one copy per sample,
    0.3 us, instead of 1 us per joint); where that view is not available ``oMi[j].homogeneous``
    rather than ``.translation`` and ``.rotation``: one conversion instead of two (about 1 us
    against 4 us per joint with pinocchio 4.1)."""
    sd = _sides(mech)
    model = mech.pin_model
    n, nv = q.shape
    J = np.empty((n, 6, nv))
    k = len(sd.joints)
    H = np.zeros((n, max(k, 1), 4, 4))
    cjj = pin.computeJointJacobians
    view = loop_batch.placement_view(mech, data) if k else None
    if view is not None:  # one copy per sample through the strided view (the same numbers)
        jsel = np.array(sd.joints, dtype=int)
        flat = np.empty((n, k, 12))
        for i in range(n):
            J[i] = cjj(model, data, q[i])
            flat[i] = view[jsel]
        H[:, :, :3, :3] = flat[:, :, :9].reshape(n, k, 3, 3).transpose(0, 1, 3, 2)
        H[:, :, :3, 3] = flat[:, :, 9:]
        H[:, :, 3, 3] = 1.0
        return J, H
    oMi = data.oMi
    joints = list(enumerate(sd.joints))
    for i in range(n):
        J[i] = cjj(model, data, q[i])
        Hi = H[i]
        for k, j in joints:
            Hi[k] = oMi[j].homogeneous
    return J, H


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


def _side_points(mech: Mechanism, H: FloatArray) -> FloatArray:
    """World position of every side point, shape (n, s, 3) (see :class:`_Sides`)."""
    sd = _sides(mech)
    slot = np.where(sd.slot < 0, 0, sd.slot)
    Hs = H[:, slot]  # (n, r, 4, 4)
    p = Hs[:, :, :3, 3] + np.einsum("nsij,sj->nsi", Hs[:, :, :3, :3], sd.r)
    base = sd.slot < 0
    p[:, base] = sd.r[base]
    return p[:, sd.ref_index]


def _assemble(mech: Mechanism, n: int, side_rows) -> FloatArray:
    """Constraint rows (independent ones) then coordinate rows, shape (n, n_rows, n_v).

    Columns are in the order of ``_Sides.out_columns``: for joint coordinates the dependent
    joints first, then the independent ones.

    ``side_rows(s)`` gives, for side ``s``, its linear and angular Jacobian rows on its
    support columns, shapes (n, 3, m_s) each."""
    sd = _sides(mech)
    nv = mech.nv
    full = np.zeros((n, int(sd.offsets[-1]), nv))
    for c, kind in enumerate(sd.kinds):
        r0 = int(sd.offsets[c])
        for s, sign in ((2 * c + 1, 1.0), (2 * c, -1.0)):
            cols = sd.columns[s]
            if cols.size == 0:
                continue
            lin, ang = side_rows(s)
            out_cols = sd.out_columns[s]
            full[:, r0 : r0 + 3, out_cols] += sign * lin
            if kind == "6d":
                full[:, r0 + 3 : r0 + 6, out_cols] += sign * ang
    rows = full[:, mech.constraint_rows]
    ind = mech.independent
    if isinstance(ind, JointCoordinates):
        return rows
    s = sd.n_sides - 1
    cols = sd.columns[s]
    extra = np.zeros((n, len(ind.axes), nv))
    if cols.size:
        extra[:, :, cols] = side_rows(s)[0][:, list(ind.axes)]
    return np.concatenate([rows, extra], axis=1)


def _cross_m(p: FloatArray, M: FloatArray) -> FloatArray:
    """``p x M[:, :, k]`` for every column k: p (n, 3), M (n, 3, m)."""
    px, py, pz = p[:, 0, None], p[:, 1, None], p[:, 2, None]
    mx, my, mz = M[:, 0], M[:, 1], M[:, 2]
    return np.stack([py * mz - pz * my, pz * mx - px * mz, px * my - py * mx], axis=1)


def _velocity_rows(mech: Mechanism, q: FloatArray, data: pin.Data | None = None) -> tuple[FloatArray, tuple]:
    """Rows :math:`[J_c; J_u]` per sample, shape (n, n_v, n_v), and the geometry for reuse.

    For joint coordinates only the independent constraint rows are returned, shape
    (n, n_v - n_u, n_v), with the columns reordered as [dependent joints, independent
    joints] (``_Sides.w``, ``_Sides.u``)."""
    data = mech.pin_model.createData() if data is None else data
    J, H = _placements(mech, q, data)
    p = _side_points(mech, H)
    cols = _sides(mech).columns

    def side_rows(s: int) -> tuple[FloatArray, FloatArray]:
        Js = J[:, :, cols[s]]
        Jw = Js[:, 3:]
        return Js[:, :3] - _cross_m(p[:, s], Jw), Jw

    return _assemble(mech, q.shape[0], side_rows), (J, p)


def _invert(A: FloatArray, max_cond: float, what: str = "[J_c; J_u]", offset: int = 0) -> tuple[FloatArray, FloatArray]:
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
            f"sample {offset + worst}: singular configuration (condition number of {what} = {cond[worst]:.3g} > {max_cond:.3g})"
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

    def __init__(self, mech: Mechanism, rows: FloatArray, max_cond: float, offset: int = 0) -> None:
        n = rows.shape[0]
        nv, n_u = mech.nv, mech.independent.size
        ind = mech.independent
        if isinstance(ind, JointCoordinates):
            sd = _sides(mech)
            u, w = sd.u, sd.w
            self.u, self.w = u, w
            nw = w.size
            self.inv, self.cond = _invert(rows[:, :, :nw], max_cond, "the loop-closure Jacobian of the dependent joints", offset)
            self.Jcu = rows[:, :, nw:]
            G = np.zeros((n, nv, n_u))
            G[:, u, np.arange(n_u)] = 1.0
            G[:, w, :] = -np.matmul(self.inv, self.Jcu)
        else:
            self.u = None
            self.inv, self.cond = _invert(rows, max_cond, offset=offset)
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
    # spatial velocity (at the world origin) and acceleration (at q-ddot = 0) of every body that
    # carries a side, once per body (the platform of a hexapod carries six sides)
    spatial: dict[int, tuple[FloatArray, FloatArray]] = {}
    moving = [s for s in range(sd.n_sides) if sd.columns[s].size]
    for s in moving:
        j = sd.side_joints[s]
        if j not in spatial:
            c = sd.columns[s]
            v = dq[:, c]
            spatial[j] = (np.einsum("nkm,nm->nk", J[:, :, c], v), np.einsum("nkm,nm->nk", dJ[:, :, c], v))
    # classical acceleration of every side point, all sides at once (n, sides, 3): element by
    # element the same arithmetic as one side at a time, without a Python call per side
    row = {s: k for k, s in enumerate(moving)}
    lin = ang = np.zeros((n, 0, 3))
    if moving:
        V = np.stack([spatial[sd.side_joints[s]][0] for s in moving], axis=1)
        A = np.stack([spatial[sd.side_joints[s]][1] for s in moving], axis=1)
        w, ps = V[:, :, 3:], p[:, moving]
        vp = V[:, :, :3] + _cross(w, ps)
        lin, ang = A[:, :, :3] + _cross(A[:, :, 3:], ps) + _cross(w, vp), A[:, :, 3:]

    full = np.zeros((n, int(sd.offsets[-1])))
    for c, kind in enumerate(sd.kinds):
        r0 = int(sd.offsets[c])
        for s, sign in ((2 * c + 1, 1.0), (2 * c, -1.0)):
            if s not in row:
                continue
            full[:, r0 : r0 + 3] += sign * lin[:, row[s]]
            if kind == "6d":
                full[:, r0 + 3 : r0 + 6] += sign * ang[:, row[s]]
    drift = full[:, mech.constraint_rows]
    ind = mech.independent
    if isinstance(ind, JointCoordinates):
        return drift
    s = sd.n_sides - 1
    extra = lin[:, row[s]][:, list(ind.axes)] if s in row else np.zeros((n, len(ind.axes)))
    return np.concatenate([drift, extra], axis=1)


def _check(mech: Mechanism, x: FloatArray, shape: tuple[int, int], name: str) -> FloatArray:
    x = np.atleast_2d(np.asarray(x, dtype=float))
    if x.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError(f"{name} contains NaN or infinite values")
    return x


_BLOCK = 256
POSITION_TOL = 1e-10  # Gauss-Newton tolerance of the position solve from actuator coordinates (dynid.tolerances)
"""Samples per block: the per-side Jacobians of a block (about 12 x 6 x 24 doubles per sample
for the hexapod) stay in cache; whole-array temporaries would not (memory-bound)."""


def states(mech: Mechanism, q: FloatArray, du: FloatArray, ddu: FloatArray, *, max_cond: float = 1e8,
           data: pin.Data | None = None) -> KinematicState:
    """See :meth:`Mechanism.states`."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    q = _check(mech, q, (n, mech.nv), "q")
    n_u = mech.independent.size
    du = _check(mech, du, (n, n_u), "du")
    ddu = _check(mech, ddu, (n, n_u), "ddu")
    data = mech.pin_model.createData() if data is None else data
    if n == 1:  # a controller's call: one sample
        dq, ddq, G, c = _one_sample(mech, q[0], du[0], ddu[0], max_cond, data)
        return KinematicState(q=q, dq=dq[None], ddq=ddq[None], G=G[None], cond=np.array([c]))
    dq, ddq = np.empty_like(q), np.empty_like(q)
    G, cond = np.empty((n, mech.nv, n_u)), np.empty(n)
    for a in range(0, n, _BLOCK):
        b = min(a + _BLOCK, n)
        rows, (J, p) = _velocity_rows(mech, q[a:b], data)
        maps = _Maps(mech, rows, max_cond, offset=a)
        dq[a:b] = np.einsum("nij,nj->ni", maps.G, du[a:b])
        drift = _drift(mech, q[a:b], dq[a:b], J, p, data)
        ddq[a:b] = maps.accelerations(ddu[a:b], drift)
        G[a:b], cond[a:b] = maps.G, maps.cond
    return KinematicState(q=q, dq=dq, ddq=ddq, G=G, cond=cond)


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


_SKEW = np.zeros((3, 9))
_SKEW[2, 1] = _SKEW[0, 5] = _SKEW[1, 6] = -1.0
_SKEW[1, 2] = _SKEW[2, 3] = _SKEW[0, 7] = 1.0


def _skew(p: FloatArray) -> FloatArray:
    """Skew matrices :math:`[p]_\\times` of rows ``p`` (k, 3), shape (k, 3, 3) (exact: each entry
    is one element of p or its negative)."""
    return (p @ _SKEW).reshape(-1, 3, 3)


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


def kinematic_state(mech: Mechanism, q: FloatArray, dq: FloatArray, ddq: FloatArray, *, max_cond: float = 1e8) -> KinematicState:
    """See :meth:`Mechanism.kinematic_state`."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    q = _check(mech, q, (n, mech.nv), "q")
    dq = _check(mech, dq, (n, mech.nv), "dq")
    ddq = _check(mech, ddq, (n, mech.nv), "ddq")
    data = mech.pin_model.createData()
    G, cond = np.empty((n, mech.nv, mech.independent.size)), np.empty(n)
    for a in range(0, n, _BLOCK):
        b = min(a + _BLOCK, n)
        maps = _Maps(mech, _velocity_rows(mech, q[a:b], data)[0], max_cond, offset=a)
        G[a:b], cond[a:b] = maps.G, maps.cond
    return KinematicState(q=q, dq=dq, ddq=ddq, G=G, cond=cond)


def actuator_states(
    mech: Mechanism,
    qa: FloatArray,
    dqa: FloatArray,
    ddqa: FloatArray,
    *,
    q0: FloatArray | None = None,
    tol: float | None = None,
    max_iter: int = 30,
    max_cond: float = 1e8,
    sample_offset: int = 0,
    q_start: FloatArray | None = None,
) -> tuple[KinematicState, FloatArray]:
    """States of all joints from measured actuator positions, velocities and accelerations.

    What a log of a parallel robot gives: the actuated joints only. Positions by
    Gauss–Newton on :math:`[c(q); S_a q - q_a] = 0` (independent constraint rows),
    warm-started along the log (the first sample from ``q0``, default ``q_ref``): for point
    closures batched over samples (:mod:`dynid.model.loop_batch`: anchors one after the other,
    the samples between them at once from the anchors' cubic; the same roots as the
    sample-by-sample loop to ``3 tol``, checked, with that loop as the fallback; some 20 times
    faster on the hexapod), for ``6d`` closures sample by sample from the previous sample;
    velocities and accelerations as the least-squares solutions of

    .. math::

        \\begin{bmatrix} J_c \\\\ S_a \\end{bmatrix}\\dot q = \\begin{bmatrix} 0 \\\\ \\dot q_a\\end{bmatrix},
        \\qquad
        \\begin{bmatrix} J_c \\\\ S_a \\end{bmatrix}\\ddot q =
        \\begin{bmatrix} -\\dot J_c\\dot q \\\\ \\ddot q_a\\end{bmatrix},

    exact for non-redundant actuation; with redundant actuators the measurements are
    over-determined and the fit residual tells how consistent they are.

    ``tol``: the Gauss–Newton tolerance [rad or m] on the step and the residual (infinity
    norm); default 1e-10 times :func:`dynid.tolerances.scale`.

    ``sample_offset`` is added to the sample numbers of error messages (chunked logs).

    ``q_start`` (n, n_v): a starting point per sample instead (the joint positions of a
    simulation, :mod:`dynid.pipeline.control_loop`); a starting point whose residual
    :math:`[c(q); S_a q - q_a]` is already below ``tol`` is taken as it is (no Jacobian), so a
    simulated motion costs one residual per sample, and the positions then differ from the
    Gauss–Newton solution at the level of ``tol``.

    Returns
    -------
    state : KinematicState
        With the velocity map of the mechanism's independent coordinates.
    inconsistency : array, shape (n,)
        Root-mean-square residual of the actuator rows of the position fit [rad or m]
        (zero up to ``tol`` for non-redundant actuation).
    """
    qa = np.atleast_2d(np.asarray(qa, dtype=float))
    n, na = qa.shape
    if na != mech.n_actuators:
        raise InputError(f"actuator positions have {na} columns; the mechanism has {mech.n_actuators} actuators")
    dqa = _check(mech, dqa, (n, na), "actuator velocities")
    ddqa = _check(mech, ddqa, (n, na), "actuator accelerations")
    if not np.all(np.isfinite(qa)):
        raise InputError("actuator positions contain NaN or infinite values")
    tol = scaled(POSITION_TOL) if tol is None else float(tol)
    data = mech.pin_model.createData()
    rows = mech.constraint_rows
    Sa = mech.actuator_selection()
    act = list(mech.actuated)
    nc = rows.size
    if q_start is not None:
        q_start = np.asarray(q_start, dtype=float)
        if q_start.shape != (n, mech.nv) or not np.all(np.isfinite(q_start)):
            raise InputError(f"starting joint positions must be finite, shape ({n}, {mech.nv}); got {q_start.shape}")
    Q = _actuator_positions(mech, qa, q0, tol, max_iter, sample_offset, data, q_start)
    resid = np.sqrt(np.mean((Q[:, act] - qa) ** 2, axis=1))
    # velocities and accelerations: least squares on [J_c; S_a] (normal equations, batched); where
    # the actuated joints are the independent joint coordinates the system is square and its
    # solution is the velocity map's (states(): only the dependent block inverted, no normal
    # equations; equal to rounding, better conditioned)
    Jrows, (J, p) = _velocity_rows(mech, Q, data)
    try:  # the velocity map from the rows above (what kinematic_state would compute again)
        maps = _Maps(mech, Jrows, max_cond)
    except ModelError as exc:
        raise ModelError(f"samples {sample_offset}..{sample_offset + n - 1}: {exc}") from None
    ind = mech.independent
    if isinstance(ind, JointCoordinates) and tuple(ind.joints) == tuple(act):
        dq = np.einsum("nij,nj->ni", maps.G, dqa)
        ddq = maps.accelerations(ddqa, _drift(mech, Q, dq, J, p, data))
    else:
        sd = _sides(mech)
        Jc = np.empty((n, nc, mech.nv))
        Jc[:, :, sd.order] = Jrows[:, :nc]
        A = np.concatenate([Jc, np.broadcast_to(Sa, (n, na, mech.nv))], axis=1)
        At = A.transpose(0, 2, 1)
        N = np.matmul(At, A)
        rhs_v = np.concatenate([np.zeros((n, nc)), dqa], axis=1)
        dq = np.linalg.solve(N, np.einsum("nij,nj->ni", At, rhs_v)[..., None])[..., 0]
        drift = _drift(mech, Q, dq, J, p, data)[:, :nc]
        rhs_a = np.concatenate([-drift, ddqa], axis=1)
        ddq = np.linalg.solve(N, np.einsum("nij,nj->ni", At, rhs_a)[..., None])[..., 0]
    dq, ddq = _check(mech, dq, (n, mech.nv), "dq"), _check(mech, ddq, (n, mech.nv), "ddq")
    return KinematicState(q=Q, dq=dq, ddq=ddq, G=maps.G, cond=maps.cond), resid


def _actuator_positions(mech: Mechanism, qa: FloatArray, q0: FloatArray | None, tol: float, max_iter: int,
                        offset: int, data: pin.Data, q_start: FloatArray | None = None,
                        sequential: bool = False) -> FloatArray:
    """:func:`actuator_states`' position solve. Point closures ("3d"): from ``q_start`` all
    samples at once (:func:`dynid.model.loop_batch.solve_from_starts`), without it the
    continuation along the log (anchors solved one after the other, the samples between them at
    once, :func:`dynid.model.loop_batch.continuation`: the same roots as the sample-by-sample
    loop to ``2 tol``). ``6d`` closures, and ``sequential=True`` (the reference of
    tests/test_closed_loop_fast_paths.py and bench/closed_loop_throughput.py): the
    sample-by-sample loop :func:`_positions_loop`."""
    q = np.array(mech.q_ref if q0 is None else q0, dtype=float)
    if sequential or not _closures(mech).all_3d:
        return _positions_loop(mech, qa, q, tol, max_iter, offset, data, q_start)
    if q_start is not None:
        return loop_batch.solve_from_starts(mech, qa, q_start, tol, max_iter, offset, data, accept_starts=True)

    def loop(qa_part: FloatArray, q_part: FloatArray, offset_part: int) -> FloatArray:
        return _positions_loop(mech, qa_part, np.array(q_part, dtype=float), tol, max_iter, offset_part, data)

    return loop_batch.continuation(mech, qa, q, tol, max_iter, offset, data, loop)


def _positions_loop(mech: Mechanism, qa: FloatArray, q: FloatArray, tol: float, max_iter: int, offset: int,
                    data: pin.Data, q_start: FloatArray | None = None) -> FloatArray:
    """The sample-by-sample Gauss-Newton loop, warm-started from the previous sample (the first
    from ``q``) or from ``q_start`` (a start whose residual is below ``tol`` taken as it is):
    the QR least-squares step of :math:`[J_c; S_a]` (:func:`lstsq_full_rank`), stop when the
    step is below ``tol`` (not taken); an unreachable sample raises naming it (``offset`` added)."""
    n = qa.shape[0]
    rows = mech.constraint_rows
    Sa = mech.actuator_selection()
    act = list(mech.actuated)
    Q = np.empty((n, mech.nv))
    for i in range(n):
        if q_start is not None:
            q = q_start[i].copy()
        for it in range(max_iter + 1):
            geometry = closure_geometry(mech, q, data)  # one pass for the residual and the Jacobian
            c = closure_residual(mech, q, data, geometry)[rows]
            ea = q[act] - qa[i]
            if q_start is not None and it == 0 and max(np.abs(c).max(initial=0.0), np.abs(ea).max()) < tol:
                break
            A = np.vstack([closure_jacobian(mech, q, data, True, geometry)[rows], Sa])
            F = np.concatenate([c, ea])
            step = lstsq_full_rank(A, F)
            if np.abs(step).max() < tol:  # the infinity norm
                break
            if it == max_iter:
                cond = np.linalg.cond(A)
                raise ModelError(
                    f"sample {offset + i}: actuator positions {np.array2string(qa[i], precision=4)} cannot be assembled "
                    f"(residual {np.linalg.norm(F, np.inf):.3g} after {max_iter} Gauss-Newton steps, condition number {cond:.3g})"
                )
            q = q - step
        Q[i] = q
    return Q


def platform_pose(mech: Mechanism, qa: FloatArray, *, q0: FloatArray | None = None) -> FloatArray:
    """The platform pose (task coordinates of ``mech``) of measured actuator positions ``qa``
    (n, n_a) by forward kinematics of every sample (step 1 of :func:`pose_states`), (n, n_task)."""
    task = mech.in_task_space()
    zeros = np.zeros_like(np.atleast_2d(np.asarray(qa, dtype=float)))
    raw, _ = actuator_states(mech, qa, zeros, zeros, q0=q0)
    return task.coordinates(raw.q)


def pose_states(mech: Mechanism, qa: FloatArray, fs: float, cutoff_hz: float, *, q0: FloatArray | None = None,
                pose: FloatArray | None = None):
    """Platform pose reconstruction from measured actuator positions (paper 004 §3.3).

    1. forward kinematics of every sample (Gauss–Newton from the actuator positions,
       warm-started from the previous sample, :func:`actuator_states`);
    2. the platform pose (the task coordinates of ``mech``), filtered and differentiated
       exactly in the frequency domain (:func:`dynid.signals.periodic.fourier_filter`: the
       record must span whole periods of the motion);
    3. all joints from the filtered pose (closed-form inverse kinematics when the mechanism
       has one, then Newton) and the velocity map of the task coordinates.

    ``pose`` (n, n_task), the result of :func:`platform_pose` for ``qa``, skips step 1 (to
    filter the same record at several cut-offs).

    Returns
    -------
    state : KinematicState
        Of the task-space mechanism (``mech.in_task_space()``).
    pose, dpose, ddpose : arrays (n, n_task)
        The filtered pose and its derivatives (z-y-x angle rates; the angular velocity of
        paper 004 Eq. 16 is :func:`dynid.trajectories.zyx_angular_velocity` of them).
    """
    from dynid.signals.periodic import fourier_filter

    task = mech.in_task_space()
    if pose is None:
        pose = platform_pose(mech, qa, q0=q0)
    pose_f, dpose, ddpose = fourier_filter(pose, fs, cutoff_hz)
    state = task.states(task.solve_positions(pose_f), dpose, ddpose)
    return state, pose_f, dpose, ddpose
