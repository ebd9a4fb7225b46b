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

from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.closures import JointCoordinates, KinematicState

if TYPE_CHECKING:  # Mechanism.states and Mechanism.kinematic_state call this module
    from dynid.model.mechanism import Mechanism

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


def _sides(mech: Mechanism) -> _Sides:
    cached = mech.__dict__.get("_sides_cache")
    if cached is None:
        cached = _Sides(mech)
        object.__setattr__(mech, "_sides_cache", cached)
    return cached


def _placements(mech: Mechanism, q: FloatArray, data: pin.Data) -> tuple[FloatArray, FloatArray]:
    """World Jacobians (n, 6, n_v) and homogeneous placements (n, k, 4, 4) of the side joints.

    ``oMi[j].homogeneous`` is read rather than ``.translation`` and ``.rotation``: one
    conversion instead of two (about 1 us against 4 us per joint with pinocchio 4.1)."""
    sd = _sides(mech)
    model = mech.pin_model
    n, nv = q.shape
    J = np.empty((n, 6, nv))
    H = np.zeros((n, max(len(sd.joints), 1), 4, 4))
    cjj = pin.computeJointJacobians
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
    tol: float = 1e-10,
    max_iter: int = 30,
    max_cond: float = 1e8,
    sample_offset: int = 0,
    q_start: FloatArray | None = None,
) -> tuple[KinematicState, FloatArray]:
    """States of all joints from measured actuator positions, velocities and accelerations.

    What a log of a parallel robot gives: the actuated joints only. Positions by
    Gauss–Newton on :math:`[c(q); S_a q - q_a] = 0` (independent constraint rows),
    warm-started from the previous sample (the first from ``q0``, default ``q_ref``);
    velocities and accelerations as the least-squares solutions of

    .. math::

        \\begin{bmatrix} J_c \\\\ S_a \\end{bmatrix}\\dot q = \\begin{bmatrix} 0 \\\\ \\dot q_a\\end{bmatrix},
        \\qquad
        \\begin{bmatrix} J_c \\\\ S_a \\end{bmatrix}\\ddot q =
        \\begin{bmatrix} -\\dot J_c\\dot q \\\\ \\ddot q_a\\end{bmatrix},

    exact for non-redundant actuation; with redundant actuators the measurements are
    over-determined and the fit residual tells how consistent they are.

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
    data = mech.pin_model.createData()
    rows = mech.constraint_rows
    Sa = mech.actuator_selection()
    act = list(mech.actuated)
    nc = rows.size
    q = np.array(mech.q_ref if q0 is None else q0, dtype=float)
    Q = np.empty((n, mech.nv))
    resid = np.empty(n)
    if q_start is not None:
        q_start = np.asarray(q_start, dtype=float)
        if q_start.shape != (n, mech.nv) or not np.all(np.isfinite(q_start)):
            raise InputError(f"starting joint positions must be finite, shape ({n}, {mech.nv}); got {q_start.shape}")
    for i in range(n):
        if q_start is not None:
            q = q_start[i].copy()
        for it in range(max_iter + 1):
            c = mech._constraint_residual(q, data)[rows]
            ea = q[act] - qa[i]
            if q_start is not None and it == 0 and max(np.linalg.norm(c, np.inf), np.linalg.norm(ea, np.inf)) < tol:
                break
            A = np.vstack([mech._constraint_jacobian(q, data, exact=True)[rows], Sa])
            F = np.concatenate([c, ea])
            step, *_ = np.linalg.lstsq(A, F, rcond=None)
            if np.linalg.norm(step, np.inf) < tol:
                break
            if it == max_iter:
                cond = np.linalg.cond(A)
                raise ModelError(
                    f"sample {sample_offset + i}: actuator positions {np.array2string(qa[i], precision=4)} cannot be assembled "
                    f"(residual {np.linalg.norm(F, np.inf):.3g} after {max_iter} Gauss-Newton steps, condition number {cond:.3g})"
                )
            q = q - step
        Q[i] = q
        resid[i] = float(np.sqrt(np.mean((q[act] - qa[i]) ** 2)))
    # velocities and accelerations: least squares on [J_c; S_a] (normal equations, batched)
    Jrows, (J, p) = _velocity_rows(mech, Q, data)
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
    try:
        state = kinematic_state(mech, Q, dq, ddq, max_cond=max_cond)
    except ModelError as exc:
        raise ModelError(f"samples {sample_offset}..{sample_offset + n - 1}: {exc}") from None
    return state, resid


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
