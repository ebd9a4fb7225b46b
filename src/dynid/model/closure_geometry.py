"""Loop closures of a mechanism as rows: each closure's two sides (a body point, or the fixed base),
their placements and points from one kinematics pass, the closure residual :math:`c(q)` and its
Jacobian :math:`J_c(q)` (each side at its own point: :math:`J_v - [p]_\\times J_\\omega` on the
support of its body; Featherstone, *Rigid Body Dynamics Algorithms*, §2.11), and the small
least-squares helpers of the position solve (:func:`row_space`, :func:`lstsq_full_rank`). Split from
:mod:`dynid.model.loop_kinematics`, which re-exports the public names."""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack as sla_lapack

from dynid._typing import FloatArray
from dynid.model.closures import JointCoordinates

# a dynid.model.mechanism.Mechanism, named, not imported (mechanism imports this module's users)
Mechanism = Any


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


_SKEW = np.zeros((3, 9))


def _skew(p: FloatArray) -> FloatArray:
    """Skew matrices :math:`[p]_\\times` of rows ``p`` (k, 3), shape (k, 3, 3) (exact: each entry
    is one element of p or its negative)."""
    return (p @ _SKEW).reshape(-1, 3, 3)
