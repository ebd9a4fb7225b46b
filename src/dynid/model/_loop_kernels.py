"""Compiled per-sample kernels of the closed-chain states and regressor (issue 37, item 1, third pass).

numba ``@njit(cache=True, error_model="numpy")`` loops over all samples of a block, each doing the per-sample work of
the numpy routes it replaces on small matrices (3 x 3 to 24 x 240), with preallocated outputs:

* :func:`closure_rows`: the side points :math:`p = t + R r` and the closure rows
  :math:`J_v - p\\times J_\\omega` (:math:`J_\\omega` for ``6d``) of all moving sides, scattered
  -side a + side b (``loop_blocks.scattered_rows`` and ``loop_kinematics._side_points``);
* :func:`states_fused`: the four below sample after sample (a sample's rows and inverse stay in
  cache), for mechanisms with legs;
* :func:`leg_inverse`: :math:`J_{c,w}^{-1}` by block elimination of the leg structure
  (``loop_blocks.inverse``; Golub & Van Loan, *Matrix Computations*, 4th ed., §3.2.11: the Schur
  complement :math:`S = -C D^{-1} B`, closed-form 3 x 3 inverses, :math:`S^{-1}` by Gauss-Jordan
  with partial pivoting), with the pivots' test :math:`\\kappa_1(D_g)\\kappa_1(S)` <= the limit;
* :func:`velocity_maps`: the 1-norm condition number of :math:`J_{c,w}`, the velocity map
  :math:`G_w = -J_{c,w}^{-1}J_{c,u}` (``loop_kinematics._Maps``) and :math:`\\dot q = G\\dot u`;
* :func:`drift_accelerations`: the drift :math:`\\dot J_c\\dot q` (the classical acceleration of
  every side point, Featherstone, *Rigid Body Dynamics Algorithms*, §2.11;
  ``loop_blocks.scattered_drift``) and :math:`\\ddot q` (``_Maps.accelerations``);
* :func:`tree_project`: :math:`G^T Y_{tree}` of a block of samples from the joints' placements,
  pinocchio's regressor recursion in the joints' frames with the body Jacobians per unit
  :math:`\\dot u` beside it (no tree regressor formed), and the joint terms;
* :func:`project_sample`: :math:`G^T Y_{tree}` of one sample, chain segment by chain segment on
  the supporting rows (``closed_loop._chain_groups``), from the array pinocchio's
  ``computeJointTorqueRegressor`` returns (no copy into a block), and :math:`G^T F` of the
  unweighted joint terms without forming :math:`F` (``closed_loop._projected_terms``).

Compiled with ``error_model="numpy"``: a division by zero gives inf or NaN as numpy's does (a
singular pivot fails the pivots' test or the condition number's), never an exception. The same
formulas as the numpy routes, element by element; sums over rows or columns may run in
another order (rounding: tests/test_closed_loop_structured.py). This module imports numba: it is
imported only inside the closed-chain functions (:mod:`dynid.model.loop_compiled`), never when
dynid handles a serial arm.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def closure_rows(J, flat, slot, r, moving_ref, cols, tgt_a, src_a, tgt_b, src_b, n_dims, rows, ps):  # pragma: no cover (compiled)
    """Closure rows of all samples. ``J`` (n, 6, n_v) world Jacobians; ``flat`` (n, k, 12) the side
    joints' placements (column-major rotation, translation); ``slot`` (e,) the placement of each
    computed point (-1: the base) and ``r`` (e, 3) its offset; ``moving_ref`` (S,) the computed
    point of each moving side; ``cols`` (S, width) its support columns; targets (flat row x column)
    and sources ((d S + k) width + t) of sides a and b. Out: ``rows`` (n, n_rows * n_v), ``ps``
    (n, S, 3) the moving sides' points."""
    S, width = cols.shape
    vals = np.empty(n_dims * S * width)
    for i in range(J.shape[0]):
        _rows_one(J[i], flat[i], slot, r, moving_ref, cols, tgt_a, src_a, tgt_b, src_b, n_dims, vals, rows[i], ps[i])


@njit(cache=True, error_model="numpy")
def _rows_one(J, flat, slot, r, moving_ref, cols, tgt_a, src_a, tgt_b, src_b, n_dims, vals, out, ps):  # pragma: no cover
    """:func:`closure_rows` of one sample (``vals``: scratch)."""
    S, width = cols.shape
    for k in range(S):
        e = moving_ref[k]
        s = slot[e]
        if s < 0:
            for a in range(3):
                ps[k, a] = r[e, a]
        else:
            f = flat[s]
            for a in range(3):  # R[a, b] = f[3 b + a]
                ps[k, a] = f[9 + a] + (f[a] * r[e, 0] + f[3 + a] * r[e, 1] + f[6 + a] * r[e, 2])
        px, py, pz = ps[k, 0], ps[k, 1], ps[k, 2]
        for t in range(width):
            c = cols[k, t]
            mx, my, mz = J[3, c], J[4, c], J[5, c]
            vals[(0 * S + k) * width + t] = J[0, c] - (py * mz - pz * my)
            vals[(1 * S + k) * width + t] = J[1, c] - (pz * mx - px * mz)
            vals[(2 * S + k) * width + t] = J[2, c] - (px * my - py * mx)
            for d in range(3, n_dims):
                vals[(d * S + k) * width + t] = J[d, c]
    out[:] = 0.0
    for x in range(tgt_a.size):
        out[tgt_a[x]] = -vals[src_a[x]]
    for x in range(tgt_b.size):
        out[tgt_b[x]] += vals[src_b[x]]


@njit(cache=True, error_model="numpy")
def _inverse_gj(S, X):  # pragma: no cover (compiled)
    """X = S^-1 by Gauss-Jordan elimination with partial pivoting; False where a pivot is zero or
    not finite (S is overwritten)."""
    m = S.shape[0]
    X[:, :] = 0.0
    for a in range(m):
        X[a, a] = 1.0
    for c in range(m):
        p, best = c, abs(S[c, c])
        for a in range(c + 1, m):
            if abs(S[a, c]) > best:
                p, best = a, abs(S[a, c])
        if not (best > 0.0) or not np.isfinite(best):
            return False
        if p != c:
            for b in range(m):
                S[c, b], S[p, b] = S[p, b], S[c, b]
                X[c, b], X[p, b] = X[p, b], X[c, b]
        piv = S[c, c]
        for a in range(m):
            if a == c:
                continue
            f = S[a, c] / piv
            if f != 0.0:
                for b in range(m):
                    S[a, b] -= f * S[c, b]
                    X[a, b] -= f * X[c, b]
    for a in range(m):
        piv = S[a, a]
        for b in range(m):
            X[a, b] /= piv
    return True


@njit(cache=True, error_model="numpy")
def _norm1(A):  # pragma: no cover (compiled)
    """1-norm (largest column sum of absolute values)."""
    best = 0.0
    for b in range(A.shape[1]):
        s = 0.0
        for a in range(A.shape[0]):
            s += abs(A[a, b])
        if not (s <= best):  # NaN propagates
            best = s
    return best


@njit(cache=True, error_model="numpy")
def leg_inverse(rows, g_rows, local, shared, flat_u, u_group, u_pos, row_out, col_out, max_pivot, inv, ok):  # pragma: no cover
    """:math:`J_{c,w}^{-1}` (n, n_w, n_c) by block elimination (``loop_blocks.LegPlan`` indices; legs
    of k <= 3 joints) where :math:`\\kappa_1(D_g)\\kappa_1(S)` <= ``max_pivot``; ``ok`` (n,) says
    where (elsewhere ``inv`` is left as it was: the caller inverts those samples densely)."""
    m, k = g_rows.shape
    n_u = shared.size
    scratch = _leg_scratch(m, k, n_u)
    for i in range(rows.shape[0]):
        ok[i] = _leg_one(rows[i], g_rows, local, shared, flat_u, u_group, u_pos, row_out, col_out, max_pivot, scratch, inv[i])


@njit(cache=True, error_model="numpy")
def _leg_scratch(m, k, n_u):  # pragma: no cover (compiled)
    nc = m * k
    return np.empty((k, k)), np.empty((m, k, k)), np.empty((nc, n_u)), np.empty((n_u, n_u)), np.empty((n_u, n_u)), np.empty((nc, n_u))


@njit(cache=True, error_model="numpy")
def _leg_one(R, g_rows, local, shared, flat_u, u_group, u_pos, row_out, col_out, max_pivot, scratch, out):  # pragma: no cover
    """:func:`leg_inverse` of one sample: True where the pivots allow it (``out`` written)."""
    D, Dinv, E, S, Sinv, ES = scratch
    m, k = g_rows.shape
    nc = m * k
    n_u = shared.size
    cD = 0.0
    for g in range(m):
        for a in range(k):
            for b in range(k):
                D[a, b] = R[g_rows[g, a], local[g, b]]
        Di = Dinv[g]
        if k == 1:
            det = D[0, 0]
            Di[0, 0] = 1.0 / det
        elif k == 2:
            det = D[0, 0] * D[1, 1] - D[0, 1] * D[1, 0]
            Di[0, 0], Di[0, 1], Di[1, 0], Di[1, 1] = D[1, 1] / det, -D[0, 1] / det, -D[1, 0] / det, D[0, 0] / det
        else:  # adjugate over determinant, as loop_blocks._inv_small
            a_, b_, c_ = D[0, 0], D[0, 1], D[0, 2]
            e_, f_, g_ = D[1, 0], D[1, 1], D[1, 2]
            h_, i_, j_ = D[2, 0], D[2, 1], D[2, 2]
            A0, A1, A2 = f_ * j_ - g_ * i_, c_ * i_ - b_ * j_, b_ * g_ - c_ * f_
            A3, A4, A5 = g_ * h_ - e_ * j_, a_ * j_ - c_ * h_, c_ * e_ - a_ * g_
            A6, A7, A8 = e_ * i_ - f_ * h_, b_ * h_ - a_ * i_, a_ * f_ - b_ * e_
            det = a_ * A0 + b_ * A3 + c_ * A6
            Di[0, 0], Di[0, 1], Di[0, 2] = A0 / det, A1 / det, A2 / det
            Di[1, 0], Di[1, 1], Di[1, 2] = A3 / det, A4 / det, A5 / det
            Di[2, 0], Di[2, 1], Di[2, 2] = A6 / det, A7 / det, A8 / det
        c = _norm1(D) * _norm1(Di)
        if not np.isfinite(c):
            c = np.inf
        if c > cD:
            cD = c
        for a in range(k):
            for cc in range(n_u):
                s = 0.0
                for b in range(k):
                    s += Di[a, b] * R[g_rows[g, b], shared[cc]]
                E[g * k + a, cc] = s
    for a in range(n_u):
        for b in range(n_u):
            S[a, b] = -E[flat_u[a], b]
    nS = _norm1(S)
    if not _inverse_gj(S, Sinv):
        return False
    cS = nS * _norm1(Sinv)
    if not (cD * cS <= max_pivot):  # NaN fails
        return False
    for a in range(nc):
        if row_out[a] < 0:  # an independent joint's row: not among the outputs
            continue
        for b in range(n_u):
            s = 0.0
            for x in range(n_u):
                s += E[a, x] * Sinv[x, b]
            ES[a, b] = s
    out[:, :] = 0.0
    # F = C D^-1: row x is row u_pos[x] of leg u_group[x]'s D^-1, in that leg's columns; the
    # entries written where they belong in the output (row_out, col_out: plan row and column ->
    # output row and column, -1 where a row is not an output)
    for x in range(n_u):
        g, p = u_group[x], u_pos[x]
        for b in range(k):
            fv = Dinv[g, p, b]
            qc = col_out[g * k + b]
            for a in range(nc):
                pr = row_out[a]
                if pr >= 0:
                    out[pr, qc] += ES[a, x] * fv
            for a in range(n_u):
                pr = row_out[nc + a]
                if pr >= 0:
                    out[pr, qc] += -Sinv[a, x] * fv
    for g in range(m):
        for a in range(k):
            pr = row_out[g * k + a]
            if pr >= 0:
                for b in range(k):
                    out[pr, col_out[g * k + b]] += Dinv[g, a, b]
    return True


@njit(cache=True, error_model="numpy")
def velocity_maps(rows, inv, u, w, cu_ptr, cu_rows, du, G, cond, dq):  # pragma: no cover (compiled)
    """Per sample: ``cond`` the 1-norm condition number of :math:`J_{c,w}` (``rows[:, :, :n_w]``,
    inverse ``inv``), ``G`` (n, n_v, n_u) with :math:`G_u = I`, :math:`G_w = -J_{c,w}^{-1}J_{c,u}`
    (column j of :math:`J_{c,u}` on its structurally non-zero rows
    ``cu_rows[cu_ptr[j]:cu_ptr[j + 1]]`` only: the others are exact zeros), and ``dq`` = G du."""
    for i in range(rows.shape[0]):
        cond[i] = _maps_one(rows[i], inv[i], u, w, cu_ptr, cu_rows, du[i], G[i], dq[i])


@njit(cache=True, error_model="numpy")
def _maps_one(R, Ai, u, w, cu_ptr, cu_rows, du, Gi, dq):  # pragma: no cover (compiled)
    """:func:`velocity_maps` of one sample; returns the condition number."""
    nc = R.shape[0]
    nw = w.size
    n_u = u.size
    nA = 0.0
    for b in range(nw):
        s = 0.0
        for a in range(nc):
            s += abs(R[a, b])
        if not (s <= nA):
            nA = s
    nI = 0.0
    for b in range(nc):
        s = 0.0
        for a in range(nw):
            s += abs(Ai[a, b])
        if not (s <= nI):
            nI = s
    cond = nA * nI
    Gi[:, :] = 0.0
    for j in range(n_u):
        Gi[u[j], j] = 1.0
    for p in range(nw):
        for j in range(n_u):
            s = 0.0
            for x in range(cu_ptr[j], cu_ptr[j + 1]):
                a = cu_rows[x]
                s += Ai[p, a] * R[a, nw + j]
            Gi[w[p], j] = -s
    for a in range(Gi.shape[0]):
        s = 0.0
        for j in range(n_u):
            s += Gi[a, j] * du[j]
        dq[a] = s


    return cond


@njit(cache=True, error_model="numpy")
def drift_accelerations(J, dJ, from_j, dq, ps, body_ptr, body_cols, body_end, body_of, dtgt_a, dsrc_a, dtgt_b, dsrc_b,
                        n_dims, rows, inv, u, w, cu_ptr, cu_rows, ddu, ddq):  # pragma: no cover (compiled)
    r"""Per sample: each carrying body's spatial velocity :math:`V = J\dot q` and acceleration at
    :math:`\ddot q = 0`, :math:`\dot J\dot q`, on its support columns
    (``body_cols[body_ptr[b]:body_ptr[b + 1]]``, in the chain's order); the classical acceleration
    of every moving side's point; the drift rows (-side a + side b); then
    :math:`\ddot q_u = \ddot u`, :math:`\ddot q_w = J_{c,w}^{-1}(-J_{c,u}\ddot u - \text{drift})`.

    ``from_j`` False: :math:`\dot J` is pinocchio's ``computeJointJacobiansTimeVariation`` (``dJ``,
    (n, 6, n_v)). True: from :math:`J` itself, as pinocchio forms it: column k of :math:`\dot J` is
    :math:`v_k \times J_k` (spatial motion cross product, world frame at the origin; Featherstone,
    *Rigid Body Dynamics Algorithms*, Eq. 2.36 and §2.9, :math:`\dot S = v\times S` for a joint
    whose axis is fixed in its body), :math:`v_k` the velocity of joint k's body: the sum of
    :math:`J_m\dot q_m` over the supporting columns up to the last column of joint k
    (``body_end``: the position of that column); ``dJ`` is then not read."""
    scratch = _drift_scratch(body_ptr.size - 1, body_cols.size, n_dims * body_of.size, rows.shape[1])
    for i in range(J.shape[0]):
        _drift_one(J[i], dJ[i] if not from_j else dJ[0], from_j, dq[i], ps[i], body_ptr, body_cols, body_end, body_of,
                   dtgt_a, dsrc_a, dtgt_b, dsrc_b, n_dims, rows[i], inv[i], u, w, cu_ptr, cu_rows, ddu[i], ddq[i], scratch)


@njit(cache=True, error_model="numpy")
def states_fused(J, flat, slot, r, moving_ref, cols, tgt_a, src_a, tgt_b, src_b, n_dims,
                 g_rows, local, shared, flat_u, u_group, u_pos, row_out, col_out, max_pivot,
                 u, w, cu_ptr, cu_rows, body_ptr, body_cols, body_end, body_of, dtgt_a, dsrc_a, dtgt_b, dsrc_b,
                 du, ddu, G, cond, dq, ddq, ok):  # pragma: no cover (compiled)
    """:func:`closure_rows`, :func:`leg_inverse`, :func:`velocity_maps` and
    :func:`drift_accelerations` (:math:`\\dot J` from :math:`J`) sample after sample, the rows and
    the inverse of a sample in scratch arrays (in cache) instead of whole-block arrays (some 6 kB a
    hexapod sample, 1.5 MB a block of 256: the four passes over them cost more than their
    arithmetic under load). ``ok`` False: the pivots refused the block elimination; that sample's
    outputs are not written (the caller takes the separate kernels and the dense inverse)."""
    nv = J.shape[2]
    nc = g_rows.size
    S, width = cols.shape
    vals = np.empty(n_dims * S * width)
    R = np.empty((nc, nv))
    Ai = np.empty((w.size, nc))
    ps = np.empty((S, 3))
    m, k = g_rows.shape
    leg = _leg_scratch(m, k, shared.size)
    drift = _drift_scratch(body_ptr.size - 1, body_cols.size, n_dims * body_of.size, nc)
    Rf = R.reshape(nc * nv)
    for i in range(J.shape[0]):
        _rows_one(J[i], flat[i], slot, r, moving_ref, cols, tgt_a, src_a, tgt_b, src_b, n_dims, vals, Rf, ps)
        ok[i] = _leg_one(R, g_rows, local, shared, flat_u, u_group, u_pos, row_out, col_out, max_pivot, leg, Ai)
        if not ok[i]:
            continue
        cond[i] = _maps_one(R, Ai, u, w, cu_ptr, cu_rows, du[i], G[i], dq[i])
        _drift_one(J[i], J[i], True, dq[i], ps, body_ptr, body_cols, body_end, body_of, dtgt_a, dsrc_a, dtgt_b, dsrc_b,
                   n_dims, R, Ai, u, w, cu_ptr, cu_rows, ddu[i], ddq[i], drift)


@njit(cache=True, error_model="numpy")
def _drift_scratch(nb, ncols, nvals, nc):  # pragma: no cover (compiled)
    return np.empty((nb, 6)), np.empty((nb, 6)), np.empty((ncols, 6)), np.empty(6), np.empty(nvals), np.empty(nc), np.empty(nc)


@njit(cache=True, error_model="numpy")
def _drift_one(J, dJ, from_j, dq, ps, body_ptr, body_cols, body_end, body_of, dtgt_a, dsrc_a, dtgt_b, dsrc_b, n_dims,
               R, Ai, u, w, cu_ptr, cu_rows, ddu, ddq, scratch):  # pragma: no cover (compiled)
    """:func:`drift_accelerations` of one sample."""
    V, A, cum, v, vals, drift, rhs = scratch
    nb = body_ptr.size - 1
    S = body_of.size
    nc = R.shape[0]
    nw = w.size
    n_u = u.size
    if from_j:
        for b in range(nb):
            v[:] = 0.0
            for x in range(body_ptr[b], body_ptr[b + 1]):
                c = body_cols[x]
                for d in range(6):
                    v[d] += J[d, c] * dq[c]
                    cum[x, d] = v[d]
            for d in range(6):
                V[b, d] = v[d]
                A[b, d] = 0.0
            for x in range(body_ptr[b], body_ptr[b + 1]):
                c = body_cols[x]
                e = body_end[x]
                lx, ly, lz, ox, oy, oz = cum[e, 0], cum[e, 1], cum[e, 2], cum[e, 3], cum[e, 4], cum[e, 5]
                jx, jy, jz, kx, ky, kz = J[0, c], J[1, c], J[2, c], J[3, c], J[4, c], J[5, c]
                qd = dq[c]
                # (l, o) x (j, k) = (o x j + l x k, o x k)
                A[b, 0] += ((oy * jz - oz * jy) + (ly * kz - lz * ky)) * qd
                A[b, 1] += ((oz * jx - ox * jz) + (lz * kx - lx * kz)) * qd
                A[b, 2] += ((ox * jy - oy * jx) + (lx * ky - ly * kx)) * qd
                A[b, 3] += (oy * kz - oz * ky) * qd
                A[b, 4] += (oz * kx - ox * kz) * qd
                A[b, 5] += (ox * ky - oy * kx) * qd
    else:
        for b in range(nb):
            for d in range(6):
                sv = 0.0
                sa = 0.0
                for x in range(body_ptr[b], body_ptr[b + 1]):
                    c = body_cols[x]
                    sv += J[d, c] * dq[c]
                    sa += dJ[d, c] * dq[c]
                V[b, d] = sv
                A[b, d] = sa
    for k in range(S):
        b = body_of[k]
        px, py, pz = ps[k, 0], ps[k, 1], ps[k, 2]
        wx, wy, wz = V[b, 3], V[b, 4], V[b, 5]
        vx = V[b, 0] + (wy * pz - wz * py)
        vy = V[b, 1] + (wz * px - wx * pz)
        vz = V[b, 2] + (wx * py - wy * px)
        ax, ay, az = A[b, 3], A[b, 4], A[b, 5]
        vals[0 * S + k] = A[b, 0] + (ay * pz - az * py) + (wy * vz - wz * vy)
        vals[1 * S + k] = A[b, 1] + (az * px - ax * pz) + (wz * vx - wx * vz)
        vals[2 * S + k] = A[b, 2] + (ax * py - ay * px) + (wx * vy - wy * vx)
        for d in range(3, n_dims):
            vals[d * S + k] = A[b, d]
    drift[:] = 0.0
    for x in range(dtgt_a.size):
        drift[dtgt_a[x]] = -vals[dsrc_a[x]]
    for x in range(dtgt_b.size):
        drift[dtgt_b[x]] += vals[dsrc_b[x]]
    rhs[:] = 0.0
    for j in range(n_u):  # J_c,u ddu on its structurally non-zero entries (velocity_maps)
        for x in range(cu_ptr[j], cu_ptr[j + 1]):
            a = cu_rows[x]
            rhs[a] += R[a, nw + j] * ddu[j]
    for a in range(nc):
        rhs[a] = -rhs[a] - drift[a]
    for j in range(n_u):
        ddq[u[j]] = ddu[j]
    for p in range(nw):
        s = 0.0
        for a in range(nc):
            s += Ai[p, a] * rhs[a]
        ddq[w[p]] = s


@njit(cache=True, error_model="numpy")
def project_sample(Y, G, out, i, plan, fdata):  # pragma: no cover (compiled)
    """``out[i, u, w0 + c] = sum_r G[i, r, u] Y[r, t0 + c]`` over each chain group's rows and each
    of its runs of consecutive columns (tree column ``t0``, output column ``w0``, ``L`` columns);
    ``Y`` (n_v, 10 n_joints) the tree regressor of sample ``i``. The rows outermost, the columns
    innermost (contiguous in ``Y`` and ``out``: vectorized); the sum over the rows in their order.
    Then the joint terms of the sample (``closed_loop._projected_terms``' sums, while its output
    row is in cache): ``out[i, u, col0 + k] = sum_j G[i, j, u] b_k[i, j] I[j, k]``.

    Two arguments pack all the rest (each argument costs the call's dispatch some 0.1 us):
    ``plan`` (integers) ``[t_at, n_groups, (n_rows, rows..., n_runs, (t0, w0, L)...)..., col0,
    n_terms, n_weights, (kind, n_joints, joints...)...]`` (the terms' part from ``t_at``),
    ``fdata`` (floats) the incidence of each listed joint (``n_weights``), then the bases
    (kinds, n, n_v) of the terms' kinds, flattened."""
    n_u = G.shape[2]
    Gi, Oi = G[i], out[i]
    x = 2
    for _ in range(plan[1]):
        nr = plan[x]
        r_at = x + 1
        x = r_at + nr
        for _ in range(plan[x]):
            t0, w0, L = plan[x + 1], plan[x + 2], plan[x + 3]
            x += 3
            for uu in range(n_u):
                Oi[uu, w0 : w0 + L] = 0.0
            for y in range(r_at, r_at + nr):
                r = plan[y]
                Yr = Y[r, t0 : t0 + L]
                for uu in range(n_u):
                    gv = Gi[r, uu]
                    if gv == 0.0:  # an independent joint's row of G: one 1, the rest exact zeros
                        continue
                    o = Oi[uu, w0 : w0 + L]
                    for c in range(L):
                        o[c] += gv * Yr[c]
        x += 1
    _terms_one(Gi, Oi, i, G.shape[0], plan, fdata)


@njit(cache=True, error_model="numpy")
def _terms_one(Gi, Oi, i, n, plan, fdata):  # pragma: no cover (compiled)
    """The joint terms' part of :func:`project_sample` for sample ``i`` of ``n``:
    ``Oi[u, col0 + k] = sum_j Gi[j, u] b_k[i, j] I[j, k]``."""
    n_u, nv = Gi.shape[1], Gi.shape[0]
    t = plan[0]
    col, nw_ = plan[t], plan[t + 2]
    x, z = t + 3, 0
    for k in range(plan[t + 1]):
        kb, nj = plan[x], plan[x + 1]
        x += 2
        b0 = nw_ + (kb * n + i) * nv
        for uu in range(n_u):
            s = 0.0
            for y in range(nj):
                j = plan[x + y]
                s += (Gi[j, uu] * fdata[b0 + j]) * fdata[z + y]
            Oi[uu, col + k] = s
        x += nj
        z += nj


@njit(cache=True, error_model="numpy")
def _to_child(R, t, m, out):  # pragma: no cover (compiled)
    """The motion vector ``m`` (linear, angular; in the parent's frame) in the frame of a child placed
    at ``(R, t)`` in it (``R`` as (9,) column-major): pinocchio's ``SE3.actInv``,
    :math:`(R^T(v + \\omega\\times t), R^T\\omega)`."""
    vx, vy, vz, ox, oy, oz = m[0], m[1], m[2], m[3], m[4], m[5]
    ex, ey, ez = vx + (oy * t[2] - oz * t[1]), vy + (oz * t[0] - ox * t[2]), vz + (ox * t[1] - oy * t[0])
    out[0] = R[0] * ex + R[1] * ey + R[2] * ez
    out[1] = R[3] * ex + R[4] * ey + R[5] * ez
    out[2] = R[6] * ex + R[7] * ey + R[8] * ez
    out[3] = R[0] * ox + R[1] * oy + R[2] * oz
    out[4] = R[3] * ox + R[4] * oy + R[5] * oz
    out[5] = R[6] * ox + R[7] * oy + R[8] * oz


@njit(cache=True, error_model="numpy")
def tree_project(L, start, G, dq, ddq, parent, col, axis, slot, gravity, out, plan, fdata):  # pragma: no cover (compiled)
    """:math:`G^T Y_{tree}` of samples ``start .. start + len(L)`` without forming the tree regressor,
    and the joint terms (:func:`_terms_one`).

    ``L`` (m, n_joints, 12): each joint's placement in its parent's frame (``data.liMi`` after a
    kinematics pass of pinocchio: column-major rotation, translation) for those samples; ``G``,
    ``dq``, ``ddq``, ``out`` of all samples; per joint (pinocchio's order, parents first) its
    ``parent``, its velocity column ``col``, ``axis`` (its motion subspace :math:`S = e_{axis}`:
    0-2 prismatic along x, y, z, 3-5 revolute about x, y, z; constant in the joint frame) and
    ``slot``, its block of 10 output columns (-1: no body parameters); ``gravity`` (6,)
    pinocchio's ``model.gravity``.

    The recursion of pinocchio's ``computeJointTorqueRegressor`` (its forward pass, in the joints'
    frames; Featherstone, *Rigid Body Dynamics Algorithms*, Eqs. 5.7-5.8): from
    :math:`a_0 = -g`, :math:`v_j = {}^jX_{\\lambda} v_{\\lambda} + S_j\\dot q_j` and
    :math:`a_j = {}^jX_{\\lambda} a_{\\lambda} + S_j\\ddot q_j + v_j\\times S_j\\dot q_j`; beside them
    :math:`B_j = {}^jX_{\\lambda} B_{\\lambda} + S_j G_j` (6 x n_u, :math:`B_0 = 0`: the body's
    velocity per unit :math:`\\dot u`, in its frame). The tree regressor's columns of body ``j`` are
    :math:`S_k^T\\,{}^kX_j^* Y_j` on every supporting joint ``k`` (its backward pass), with
    :math:`Y_j` the body regressor (pinocchio's ``bodyRegressor``, parameters
    ``[m, mc, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` about the joint origin): so
    :math:`\\sum_k G_k^T S_k^T\\,{}^kX_j^* Y_j = B_j^T Y_j` (:math:`({}^kX_j^*)^T = {}^jX_k`).
    :math:`f = I a + v\\times^* I v` gives, with :math:`\\alpha = a_{lin} + \\omega\\times v_{lin}`,
    :math:`f_{lin} = m\\alpha + ([\\dot\\omega]_\\times + [\\omega]_\\times^2)\\,mc` and
    :math:`f_{ang} = mc\\times\\alpha + I\\dot\\omega + \\omega\\times I\\omega`. Exact zeros of the tree
    regressor (a joint's own axis, joints at one point) stay exact zeros: :math:`S` is a unit
    vector and a zero translation transforms without rounding."""
    m = L.shape[0]
    nj = parent.size
    n_u = G.shape[2]
    n = G.shape[0]
    V = np.zeros((nj, 6))
    A = np.zeros((nj, 6))
    B = np.zeros((nj, n_u, 6))
    Y = np.zeros((6, 10))
    for d in range(6):
        A[0, d] = -gravity[d]
    for s in range(m):
        i = start + s
        Gi, Oi, Li = G[i], out[i], L[s]
        for j in range(1, nj):
            p, c, e = parent[j], col[j], axis[j]
            R, t = Li[j, 0:9], Li[j, 9:12]
            qd = dq[i, c]
            _to_child(R, t, V[p], V[j])
            V[j, e] += qd
            _to_child(R, t, A[p], A[j])
            A[j, e] += ddq[i, c]
            # + v_j x (S qd): (l, o) x (sl, so) = (o x sl + l x so, o x so), S qd = qd e_axis
            if e < 3:  # prismatic: (o x sl, 0)
                A[j, (e + 1) % 3] += V[j, 3 + (e + 2) % 3] * qd
                A[j, (e + 2) % 3] -= V[j, 3 + (e + 1) % 3] * qd
            else:  # revolute: (l x so, o x so)
                f = e - 3
                A[j, (f + 1) % 3] += V[j, (f + 2) % 3] * qd
                A[j, (f + 2) % 3] -= V[j, (f + 1) % 3] * qd
                A[j, 3 + (f + 1) % 3] += V[j, 3 + (f + 2) % 3] * qd
                A[j, 3 + (f + 2) % 3] -= V[j, 3 + (f + 1) % 3] * qd
            for uu in range(n_u):
                _to_child(R, t, B[p, uu], B[j, uu])
                B[j, uu, e] += Gi[c, uu]
            w0 = slot[j]
            if w0 < 0:
                continue
            w0 *= 10
            vx, vy, vz, wx, wy, wz = V[j, 0], V[j, 1], V[j, 2], V[j, 3], V[j, 4], V[j, 5]
            ax, ay, az, dx, dy, dz = A[j, 0], A[j, 1], A[j, 2], A[j, 3], A[j, 4], A[j, 5]
            # the body regressor (6 x 10, joint frame); mass: (alpha, 0)
            alx, aly, alz = ax + (wy * vz - wz * vy), ay + (wz * vx - wx * vz), az + (wx * vy - wy * vx)
            Y[0, 0], Y[1, 0], Y[2, 0] = alx, aly, alz
            # mc: [dw]x + [w]x^2 (linear) and mc x alpha = -[alpha]x mc (angular)
            Y[0, 1], Y[0, 2], Y[0, 3] = -(wy * wy + wz * wz), wx * wy - dz, wx * wz + dy
            Y[1, 1], Y[1, 2], Y[1, 3] = wx * wy + dz, -(wx * wx + wz * wz), wy * wz - dx
            Y[2, 1], Y[2, 2], Y[2, 3] = wx * wz - dy, wy * wz + dx, -(wx * wx + wy * wy)
            Y[3, 1], Y[3, 2], Y[3, 3] = 0.0, alz, -aly
            Y[4, 1], Y[4, 2], Y[4, 3] = -alz, 0.0, alx
            Y[5, 1], Y[5, 2], Y[5, 3] = aly, -alx, 0.0
            # inertia: I dw + w x (I w), I = [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], per entry L(dw) + w x L(w)
            Y[3, 4], Y[4, 4], Y[5, 4] = dx, wz * wx, -wy * wx  # xx: L(x) = (x0, 0, 0)
            Y[3, 5], Y[4, 5], Y[5, 5] = dy - wz * wx, dx + wz * wy, wx * wx - wy * wy  # xy: (x1, x0, 0)
            Y[3, 6], Y[4, 6], Y[5, 6] = -wz * wy, dy, wx * wy  # yy: (0, x1, 0)
            Y[3, 7], Y[4, 7], Y[5, 7] = dz + wy * wx, wz * wz - wx * wx, dx - wy * wz  # xz: (x2, 0, x0)
            Y[3, 8], Y[4, 8], Y[5, 8] = wy * wy - wz * wz, dz - wx * wy, dy + wx * wz  # yz: (0, x2, x1)
            Y[3, 9], Y[4, 9], Y[5, 9] = wy * wz, -wx * wz, dz  # zz: (0, 0, x2)
            for uu in range(n_u):
                b = B[j, uu]
                o = Oi[uu, w0 : w0 + 10]
                o[0] = b[0] * Y[0, 0] + b[1] * Y[1, 0] + b[2] * Y[2, 0]
                for k in range(1, 4):
                    o[k] = (b[0] * Y[0, k] + b[1] * Y[1, k] + b[2] * Y[2, k]
                            + b[3] * Y[3, k] + b[4] * Y[4, k] + b[5] * Y[5, k])
                for k in range(4, 10):
                    o[k] = b[3] * Y[3, k] + b[4] * Y[4, k] + b[5] * Y[5, k]
        _terms_one(Gi, Oi, i, n, plan, fdata)
