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

For joint coordinates the closure rows and the drift of all sides are computed at once, and where
the mechanism has legs (a hexapod) :math:`J_{c,w}` is inverted by block elimination
(:mod:`dynid.model.loop_blocks`: structure detected, the dense inverse where it is absent or its
pivots are ill-conditioned; bench/README.md, "Closed-loop regressor speed, second pass").
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model import loop_batch, loop_blocks
from dynid.model.closure_geometry import (  # noqa: F401  (re-exported: their home before the split)
    _EPS, _SKEW, _closures, _PointRows, _sides, _skew, closure_geometry, closure_jacobian, closure_residual,
    lstsq_full_rank, point_closure_rows, row_space)
from dynid.model.loop_one import (  # noqa: F401  (re-exported)
    OneGeometry, _invert_one, _one_coordinates, _one_geometry, _one_rates, _one_sample)
from dynid.model.closures import JointCoordinates, KinematicState
from dynid.tolerances import scaled

# The functions here take a dynid.model.mechanism.Mechanism, whose methods call them: the type is
# named, not imported, so that the two modules do not import each other (not even for typing).
Mechanism = Any

__all__ = ["actuator_states", "kinematic_state", "platform_pose", "pose_states", "states"]


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
        if np.array_equal(jsel, np.arange(jsel[0], jsel[0] + k)):  # consecutive joints: a slice, not a gather
            jsel = slice(int(jsel[0]), int(jsel[0]) + k)
        flat = np.empty((n, k, 12))
        for i, qi in enumerate(q):
            J[i] = cjj(model, data, qi)
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
    sc = loop_blocks.side_scatter(mech)
    if sc is not None:  # all sides at once (the same products and sums as side by side)
        return loop_blocks.scattered_rows(sc, J, p), (J, p)
    cols = _sides(mech).columns

    def side_rows(s: int) -> tuple[FloatArray, FloatArray]:
        Js = J[:, :, cols[s]]
        Jw = Js[:, 3:]
        return Js[:, :3] - _cross_m(p[:, s], Jw), Jw

    return _assemble(mech, q.shape[0], side_rows), (J, p)


def _invert(A: FloatArray, max_cond: float, what: str = "[J_c; J_u]", offset: int = 0,
            plan: loop_blocks.LegPlan | None = None, full: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Batched inverse and 1-norm condition numbers; a one-line error at the first singular sample.
    With a leg ``plan`` (:func:`dynid.model.loop_blocks.leg_plan`) of the rows ``full`` whose
    dependent block is ``A``, the inverse by block elimination where its pivots allow, else dense
    (sample by sample)."""
    structured = None if plan is None else loop_blocks.inverse(plan, full)
    if structured is None:
        Ainv = _dense_inverse(A)
    else:
        Ainv, ok = structured
        if not ok.all():  # pivots too ill-conditioned for block elimination: these samples densely
            Ainv[~ok] = _dense_inverse(A[~ok])
    cond = np.abs(A).sum(axis=1).max(axis=1) * np.abs(Ainv).sum(axis=1).max(axis=1)
    loop_blocks.check_condition(cond, max_cond, what, offset)
    return Ainv, cond


_dense_inverse = loop_blocks.dense_inverse  # its home before the compiled route (re-exported)


class _Maps:
    """Solution of :math:`A x = [0; b_u] - [d_c; d_u]` per sample, and :math:`G`.

    Joint coordinates: with :math:`J_c = [J_{cu}\\; J_{cw}]` (independent joints u, the
    others w), :math:`\\dot q_w = -J_{cw}^{-1}J_{cu}\\dot u` -- only the
    :math:`(n_v - n_u)`-square block is inverted. Point coordinates: the full
    :math:`A = [J_c; J_u]` is. The condition number reported is that of the inverted matrix
    (1-norm).
    """

    def __init__(self, mech: Mechanism, rows: FloatArray, max_cond: float, offset: int = 0, structured: bool = True) -> None:
        n = rows.shape[0]
        nv, n_u = mech.nv, mech.independent.size
        ind = mech.independent
        if isinstance(ind, JointCoordinates):
            sd = _sides(mech)
            u, w = sd.u, sd.w
            self.u, self.w = u, w
            nw = w.size
            self.inv, self.cond = _invert(rows[:, :, :nw], max_cond, "the loop-closure Jacobian of the dependent joints", offset,
                                          plan=loop_blocks.leg_plan(mech) if structured else None, full=rows)
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
    sc = loop_blocks.side_scatter(mech)
    if sc is not None:
        return loop_blocks.scattered_drift(sc, J, dJ, dq, p)
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
_COMPILED = True
"""Joint-coordinate mechanisms take :mod:`dynid.model.loop_compiled` (numba kernels, the same values
to rounding); False: the numpy route below (the reference of tests/test_closed_loop_structured.py)."""


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
    compiled = None
    if _COMPILED:  # the compiled kernels (numba imported here, never for a serial arm)
        from dynid.model import loop_compiled

        compiled = loop_compiled.states_plan(mech, data)
    for a in range(0, n, _BLOCK):
        b = min(a + _BLOCK, n)
        if compiled is not None:
            loop_compiled.states_block(mech, compiled, q[a:b], du[a:b], ddu[a:b], max_cond, a, data,
                                       dq[a:b], ddq[a:b], G[a:b], cond[a:b])
            continue
        rows, (J, p) = _velocity_rows(mech, q[a:b], data)
        maps = _Maps(mech, rows, max_cond, offset=a)
        dq[a:b] = np.einsum("nij,nj->ni", maps.G, du[a:b])
        drift = _drift(mech, q[a:b], dq[a:b], J, p, data)
        ddq[a:b] = maps.accelerations(ddu[a:b], drift)
        G[a:b], cond[a:b] = maps.G, maps.cond
    return KinematicState(q=q, dq=dq, ddq=ddq, G=G, cond=cond)


_SKEW[2, 1] = _SKEW[0, 5] = _SKEW[1, 6] = -1.0
_SKEW[1, 2] = _SKEW[2, 3] = _SKEW[0, 7] = 1.0


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
