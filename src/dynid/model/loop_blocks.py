"""Structured routes of the batched closed-loop kinematics (:mod:`dynid.model.loop_kinematics`).

* :func:`leg_plan`, :func:`inverse`: the loop-closure Jacobian of the dependent joints inverted by
  its leg structure (below);
* :func:`side_scatter`, :func:`scattered_rows`, :func:`scattered_drift`: the closure rows
  :math:`J_c` and the drift :math:`\\dot J_c\\dot q` of all closure sides at once, the samples as
  the innermost axis (side by side, numpy's loops over three to six columns per side cost more
  than the arithmetic); the same products and sums as side by side.

**The leg structure.**

:class:`dynid.model.loop_kinematics._Maps` needs, per sample, :math:`J_{c,w}^{-1}` (the velocity
map :math:`G_w = -J_{c,w}^{-1}J_{c,u}`, the accelerations and the 1-norm condition number of
:math:`J_{c,w}`). A dense batched inverse of the hexapod's 18 x 18 block costs about 6 us per sample
(LAPACK on small matrices), a third of the whole kinematic state. Most parallel robots have
*legs*: the constraint rows of one closure touch its own leg's joints (columns touched by no other
closure) and the joints shared by all closures (the platform). Here that structure is **detected**
from the closures' support columns (never assumed), and the inverse is computed by block
elimination (the Schur complement, Golub & Van Loan, *Matrix Computations*, 4th ed., §3.2.11 and
§4.2.6; the leg-by-leg inverse kinematics of a Stewart platform, Merlet, *Parallel Robots*, §4.1):

With the independent coordinates' rows added, :math:`A = [J_{c,w}\\; J_{c,u};\\; 0\\; I]` (square,
:math:`n_v`), and the variables ordered [leg joints of closure 1, ..., of closure m, shared joints],
the equations [closure 1, ..., closure m, independent coordinates]:

.. math::

    A \\simeq \\begin{bmatrix} D & B \\\\ C & 0 \\end{bmatrix},\\quad
    S = -C D^{-1} B,\\quad
    A^{-1} \\simeq \\begin{bmatrix} D^{-1} + D^{-1}B S^{-1} C D^{-1} & -D^{-1}B S^{-1} \\\\
    -S^{-1} C D^{-1} & S^{-1}\\end{bmatrix},

with :math:`D` block-diagonal (one square block per closure: its rows on its leg's columns, 3 x 3
for a hexapod leg), :math:`C` the independent coordinates' rows (each selecting one leg column) and
:math:`S` (:math:`n_u \\times n_u`) the inverse-kinematics Jacobian of the platform. Since
:math:`A^{-1} = [J_{c,w}^{-1}\\; -J_{c,w}^{-1}J_{c,u};\\; 0\\; I]`, :math:`J_{c,w}^{-1}` is read off
its dependent-variable rows and closure columns. Per sample: m small inverses (closed form for
blocks up to 3 x 3), one :math:`n_u` inverse and a few small products instead of LU of the whole.

**Accuracy.** Block elimination is backward stable when the pivot blocks are well conditioned: the
computed inverse has a relative error of order :math:`\\varepsilon\\,\\kappa(D)\\,\\kappa(S)` (the
closed-form 3 x 3 inverse: :math:`\\varepsilon\\,\\kappa(D_g)` per block, each entry a 2 x 2
determinant). The plan's inverse is kept for a sample only where :math:`\\kappa_1(D_g)\\kappa_1(S)`
is below :data:`MAX_PIVOT_COND` (1e3: an error below about :math:`10^3 \\cdot 2^{-52} \\approx 2\\cdot10^{-13}`
relative, times a small multiple of :math:`n_v`; on the hexapod's benchmark motion the product is at most
about 270, :math:`\\kappa_1(J_{c,w})` 170; on random assembled states it reaches some 7000 where
:math:`\\kappa_1(J_{c,w})` is 3000: :math:`\\kappa(S)` is the platform's own conditioning); otherwise
(a leg near its own singularity while the mechanism is not, a badly conditioned platform Jacobian, or a
singular sample, whose error message is the dense route's) that sample takes the dense inverse.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import ModelError
from dynid.model.closure_geometry import _sides
from dynid.model.closures import JointCoordinates

Mechanism = Any  # a dynid.model.mechanism.Mechanism (named, not imported: no import cycle)

MAX_PIVOT_COND = 1e3
"""Largest :math:`\\kappa_1(D_g)\\,\\kappa_1(S)` for which the structured inverse is used (module docstring)."""

__all__ = ["LegPlan", "SideScatter", "check_condition", "dense_inverse", "inverse", "leg_plan", "scattered_drift", "scattered_rows", "side_scatter"]


class LegPlan:
    """Index plan of the leg structure of :math:`J_{c,w}` (see the module docstring).

    Attributes: ``rows`` (m, k) the constraint rows of each closure (indices into the independent
    constraint rows), ``local`` (m, k) its leg columns and ``shared`` (n_u,) the shared columns
    (output column order of ``_Sides``: dependent joints, then the independent ones);
    ``u_group``, ``u_pos`` the closure and position within its leg of each independent joint."""

    def __init__(self, rows: np.ndarray, local: np.ndarray, shared: np.ndarray, u_group: np.ndarray,
                 u_pos: np.ndarray, nw: int) -> None:
        self.rows, self.local, self.shared = rows, local, shared
        self.u_group, self.u_pos = u_group, u_pos
        m, k = rows.shape
        self.m, self.k, self.nw = m, k, nw
        nc = m * k
        # variables in the plan's order: leg columns (closure by closure), then the shared ones;
        # the dependent ones (output column < nw) in their own order, with the plan's position
        var = np.concatenate([local.reshape(-1), shared])
        pos = np.empty(var.size, dtype=int)
        pos[var] = np.arange(var.size)
        self.w_pos = pos[:nw]  # plan position of dependent column p
        eq = rows.reshape(-1)
        eq_pos = np.empty(nc, dtype=int)
        eq_pos[eq] = np.arange(nc)
        self.eq_pos = eq_pos  # plan position of constraint row r
        self.rows_in_order = bool(np.array_equal(eq, np.arange(nc)))
        self.flat_u = u_group * k + u_pos  # the independent joints' leg rows in D^-1 (flattened)
        n_u = shared.size
        self.nc, self.n_u = nc, n_u
        self.gi, self.ki, self.local_b = np.arange(m)[:, None, None], np.arange(k)[None, :, None], local[:, None, :]
        # flat positions: F's non-zeros (row i, leg u_group[i]'s k columns) and the output (dependent variables x constraint rows)
        self.f_idx = (np.arange(n_u)[:, None] * nc + u_group[:, None] * k + np.arange(k)).reshape(-1)
        self.out_idx = (self.w_pos[:, None] * nc + eq_pos[None, :]).reshape(-1)


def leg_plan(mech: Mechanism) -> LegPlan | None:
    """The leg structure of ``mech``'s :math:`J_{c,w}`, or None where it has none: joint
    coordinates as independent coordinates; every closure's independent rows touching a square
    block of columns that no other closure touches (its leg: the independent joints among them)
    and otherwise only columns shared by the other closures; every independent joint on a leg;
    as many shared columns as independent coordinates; all legs of one size. Cached on ``mech``."""
    cache = mech.__dict__.get("_leg_plan_cache", False)
    if cache is not False:
        return cache
    plan = _detect(mech)
    object.__setattr__(mech, "_leg_plan_cache", plan)
    return plan


def _detect(mech: Mechanism) -> LegPlan | None:
    ind = mech.independent
    if not isinstance(ind, JointCoordinates) or not mech.closures:
        return None
    sd = _sides(mech)
    nv, n_u = mech.nv, ind.size
    nw = nv - n_u
    full_rows = int(sd.offsets[-1])
    group_of_full = np.empty(full_rows, dtype=int)
    touch = np.zeros((full_rows, nv), dtype=bool)  # structural non-zeros, output column order
    for c, kind in enumerate(sd.kinds):
        r0, r1 = int(sd.offsets[c]), int(sd.offsets[c + 1])
        group_of_full[r0:r1] = c
        for s in (2 * c, 2 * c + 1):
            touch[r0:r1, sd.out_columns[s]] = True
    crow = np.asarray(mech.constraint_rows)
    if crow.size != nw:
        return None
    touch, group = touch[crow], group_of_full[crow]
    groups = np.unique(group)
    col_groups = [set(group[touch[:, j]].tolist()) for j in range(nv)]
    if any(not g for g in col_groups):
        return None
    shared = np.array([j for j in range(nv) if len(col_groups[j]) > 1], dtype=int)
    if shared.size != n_u or np.any(shared >= nw):  # the independent joints must lie on legs
        return None
    rows, local = [], []
    for g in groups:
        r = np.flatnonzero(group == g)
        cols = np.array([j for j in range(nv) if col_groups[j] == {int(g)}], dtype=int)
        if cols.size != r.size:
            return None
        rows.append(r)
        local.append(cols)
    if len({r.size for r in rows}) != 1:
        return None
    rows_a, local_a = np.array(rows), np.array(local)
    u_group = np.empty(n_u, dtype=int)
    u_pos = np.empty(n_u, dtype=int)
    for i in range(n_u):
        g, p = np.nonzero(local_a == nw + i)
        if g.size != 1:
            return None
        u_group[i], u_pos[i] = g[0], p[0]
    return LegPlan(rows_a, local_a, shared, u_group, u_pos, nw)


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise cross product of (..., 3) arrays (np.cross costs several times more on small rows)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def _inv_small(D: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverses of stacked k x k matrices (closed form, adjugate over determinant, for k <= 3, on
    the entries as rows over all matrices: long loops instead of numpy's loops over 3 columns;
    LAPACK otherwise) and their 1-norm condition numbers (inf where singular)."""
    k = D.shape[-1]
    if k > 3:
        try:
            inv = np.linalg.inv(D)
        except np.linalg.LinAlgError:
            return D, np.full(D.shape[:-2], np.inf)
        cond = np.abs(D).sum(-2).max(-1) * np.abs(inv).sum(-2).max(-1)
        return inv, np.where(np.isfinite(cond), cond, np.inf)
    lead = D.shape[:-2]
    d = np.ascontiguousarray(D.reshape(-1, k * k).T)  # (k*k, N): entry (i, j) in row i*k + j
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if k == 1:
            adj, det = np.ones_like(d), d[0]
        elif k == 2:
            adj, det = np.stack([d[3], -d[1], -d[2], d[0]]), d[0] * d[3] - d[1] * d[2]
        else:
            a, b, c, e, f, g, h, i, j = d  # rows (a b c), (e f g), (h i j)
            adj = np.stack([f * j - g * i, c * i - b * j, b * g - c * f,
                            g * h - e * j, a * j - c * h, c * e - a * g,
                            e * i - f * h, b * h - a * i, a * f - b * e])
            det = a * adj[0] + b * adj[3] + c * adj[6]
        inv = adj / det
        norm_d = np.abs(d).reshape(k, k, -1).sum(axis=0).max(axis=0)  # max column sum
        norm_i = np.abs(inv).reshape(k, k, -1).sum(axis=0).max(axis=0)
        cond = norm_d * norm_i
    cond = np.where(np.isfinite(cond), cond, np.inf)
    return np.ascontiguousarray(inv.T).reshape(*lead, k, k), cond.reshape(lead)


def inverse(plan: LegPlan, rows: FloatArray) -> tuple[FloatArray, np.ndarray] | None:
    """:math:`J_{c,w}^{-1}` of ``rows`` (n, n_c, n_v) (the independent constraint rows, columns in
    ``_Sides``' output order) by block elimination (module docstring), shape (n, n_c, n_c), and the
    samples where it holds (pivots below :data:`MAX_PIVOT_COND`; the caller inverts the others
    densely); None where no sample's pivots allow it (or :math:`S` is exactly singular)."""
    n = rows.shape[0]
    m, k, nc, n_u = plan.m, plan.k, plan.nc, plan.n_u
    Rg = rows.reshape(n, m, k, -1) if plan.rows_in_order else rows[:, plan.rows]  # (n, m, k, n_v): each closure's rows
    D = Rg[:, plan.gi, plan.ki, plan.local_b]  # (n, m, k, k): its leg block
    B = Rg[:, :, :, plan.shared]  # (n, m, k, n_u): its shared columns
    Dinv, cD = _inv_small(D)
    E = np.matmul(Dinv, B).reshape(n, nc, n_u)  # D^-1 B
    Dflat = Dinv.reshape(n, nc, k)
    S = -E[:, plan.flat_u]  # S = -C D^-1 B: the independent joints' rows of D^-1 B
    try:
        Sinv = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return None
    cS = np.abs(S).sum(-2).max(-1) * np.abs(Sinv).sum(-2).max(-1)
    ok = cD.max(axis=1, initial=0.0) * cS <= MAX_PIVOT_COND  # NaN fails too
    if not ok.any():
        return None
    # F = C D^-1 (n, n_u, nc): row i is row u_pos[i] of leg u_group[i]'s D^-1, in that leg's columns
    F = np.zeros((n, n_u * nc))
    F[:, plan.f_idx] = Dflat[:, plan.flat_u].reshape(n, -1)
    F = F.reshape(n, n_u, nc)
    inv = np.empty((n, nc + n_u, nc))  # A^-1 on the closure equations, in the plan's order
    np.matmul(np.matmul(E, Sinv), F, out=inv[:, :nc])  # D^-1 B S^-1 C D^-1
    # + D^-1 on the block diagonal, through a strided view of those blocks
    st = inv.strides
    np.lib.stride_tricks.as_strided(inv, (n, m, k, k), (st[0], k * (st[1] + st[2]), st[1], st[2]))[...] += Dinv
    np.matmul(-Sinv, F, out=inv[:, nc:])
    return inv.reshape(n, -1)[:, plan.out_idx].reshape(n, plan.nw, nc), ok


class SideScatter:
    """Index plan of :func:`dynid.model.loop_kinematics._velocity_rows` for all moving sides at once: every moving side's
    support columns padded to the widest (repeating its first column), and the flat positions
    (constraint row x output column) their linear (and for ``6d`` angular) rows go to, for the
    sides ``a`` (subtracted) and ``b`` (added) of the closures separately (within each set no two
    entries share a position: one side per closure)."""

    def __init__(self, mech: Mechanism) -> None:
        sd = _sides(mech)
        nv = mech.nv
        moving = [s for s in range(sd.n_sides) if sd.columns[s].size]
        width = max((sd.columns[s].size for s in moving), default=1)
        self.moving = np.array(moving, dtype=int)
        self.cols = np.array([np.r_[sd.columns[s], np.repeat(sd.columns[s][:1], width - sd.columns[s].size)] for s in moving],
                             dtype=int).reshape(len(moving), width)
        row_pos = np.full(int(sd.offsets[-1]), -1)
        row_pos[mech.constraint_rows] = np.arange(mech.constraint_rows.size)
        self.n_rows = int(mech.constraint_rows.size)
        self.any_6d = "6d" in sd.kinds
        # vals: (n, 6, S, width) flattened; source index of (d, k, t) = (d * S + k) * width + t
        S = len(moving)
        sets: dict[float, tuple[list, list]] = {1.0: ([], []), -1.0: ([], [])}
        for k, s in enumerate(moving):
            c, sign = s // 2, (1.0 if s % 2 else -1.0)
            if c >= len(sd.kinds):  # the point coordinate's side: its own rows (see loop_kinematics._assemble)
                continue
            r0 = int(sd.offsets[c])
            dims = range(6) if sd.kinds[c] == "6d" else range(3)
            for d in dims:
                r = row_pos[r0 + d]
                if r < 0:
                    continue
                for t, oc in enumerate(sd.out_columns[s]):
                    sets[sign][0].append(r * nv + oc)
                    sets[sign][1].append((d * S + k) * width + t)
        self.tgt_a, self.src_a = (np.array(v, dtype=int) for v in sets[-1.0])
        self.tgt_b, self.src_b = (np.array(v, dtype=int) for v in sets[1.0])
        # the drift (one value per row and side): source (d * S + k), target row; the bodies
        # carrying the moving sides as 0/1 masks of their support columns (joint order)
        dsets: dict[float, tuple[list, list]] = {1.0: ([], []), -1.0: ([], [])}
        for k, s in enumerate(moving):
            c, sign = s // 2, (1.0 if s % 2 else -1.0)
            if c >= len(sd.kinds):
                continue
            for d in range(6 if sd.kinds[c] == "6d" else 3):
                r = row_pos[int(sd.offsets[c]) + d]
                if r >= 0:
                    dsets[sign][0].append(r)
                    dsets[sign][1].append(d * S + k)
        self.dtgt_a, self.dsrc_a = (np.array(v, dtype=int) for v in dsets[-1.0])
        self.dtgt_b, self.dsrc_b = (np.array(v, dtype=int) for v in dsets[1.0])
        self.body_of = np.asarray(sd.body_of, dtype=int)
        self.body_mask_T = np.ascontiguousarray(sd.body_mask_q.T)  # (n_v, bodies)


def side_scatter(mech: Mechanism) -> SideScatter | None:
    """The cached :class:`SideScatter` of joint-coordinate mechanisms (None for point coordinates:
    their extra rows take :func:`dynid.model.loop_kinematics._assemble`)."""
    if not isinstance(mech.independent, JointCoordinates):
        return None
    sc = mech.__dict__.get("_side_scatter_cache")
    if sc is None:
        sc = SideScatter(mech)
        object.__setattr__(mech, "_side_scatter_cache", sc)
    return sc


def scattered_rows(sc: SideScatter, J: FloatArray, p: FloatArray) -> FloatArray:
    """The independent constraint rows (n, n_c, n_v) of all moving sides at once: per side and
    column :math:`J_v - p \\times J_\\omega` (and :math:`J_\\omega`), then -side a + side b;
    element by element the arithmetic of :func:`dynid.model.loop_kinematics._cross_m` and :func:`dynid.model.loop_kinematics._assemble` (the same
    numbers), computed with the samples as the innermost axis (numpy's loops over 3 to 6
    columns per side would cost more than the arithmetic)."""
    n, _, nv = J.shape
    Js = np.ascontiguousarray(J.transpose(1, 2, 0))[:, sc.cols]  # (6, S, width, n)
    ps = p[:, sc.moving].transpose(2, 1, 0)[:, :, None]  # (3, S, 1, n)
    vals = np.empty((6 if sc.any_6d else 3, *Js.shape[1:]))
    px, py, pz = ps[0], ps[1], ps[2]
    mx, my, mz = Js[3], Js[4], Js[5]
    np.subtract(Js[0], py * mz - pz * my, out=vals[0])
    np.subtract(Js[1], pz * mx - px * mz, out=vals[1])
    np.subtract(Js[2], px * my - py * mx, out=vals[2])
    if sc.any_6d:
        vals[3:] = Js[3:]
    flat = vals.reshape(-1, n)
    rows = np.zeros((sc.n_rows * nv, n))
    rows[sc.tgt_a] = -flat[sc.src_a]
    rows[sc.tgt_b] += flat[sc.src_b]
    return np.ascontiguousarray(rows.reshape(sc.n_rows, nv, n).transpose(2, 0, 1))


def scattered_drift(sc: SideScatter, J: FloatArray, dJ: FloatArray, dq: FloatArray, p: FloatArray) -> FloatArray:
    """:func:`dynid.model.loop_kinematics._drift`'s rows of joint-coordinate mechanisms, all sides at once with the samples as
    the innermost axis: each carrying body's spatial velocity :math:`V = J\\dot q` and acceleration
    at :math:`\\ddot q = 0`, :math:`\\dot J\\dot q` (its support columns: one product with the 0/1
    masks), the classical acceleration of every side point
    :math:`\\dot v + \\dot\\omega\\times p + \\omega\\times(v + \\omega\\times p)`, then -side a + side b.
    The same formulas as :func:`dynid.model.loop_kinematics._drift`; sums over the support columns in another order (rounding)."""
    n = J.shape[0]
    S = sc.moving.size
    VA = np.matmul(np.stack([J, dJ]) * dq[None, :, None, :], sc.body_mask_T)  # (2, n, 6, bodies)
    VA = np.ascontiguousarray(VA.transpose(0, 2, 3, 1))[:, :, sc.body_of]  # (2, 6, S, n)
    V, A = VA[0], VA[1]
    ps = p[:, sc.moving].transpose(2, 1, 0)  # (3, S, n)
    w = V[3:]
    vp = V[:3] + _cross0(w, ps)
    lin = A[:3] + _cross0(A[3:], ps) + _cross0(w, vp)
    vals = np.concatenate([lin, A[3:]]) if sc.any_6d else lin
    flat = vals.reshape(-1, n)
    drift = np.zeros((sc.n_rows, n))
    drift[sc.dtgt_a] = -flat[sc.dsrc_a]
    drift[sc.dtgt_b] += flat[sc.dsrc_b]
    return np.ascontiguousarray(drift.T)


def _cross0(a: FloatArray, b: FloatArray) -> FloatArray:
    """Cross product along the first axis of (3, ...) arrays."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def dense_inverse(A: FloatArray) -> FloatArray:
    """Batched LAPACK inverse; inf where a sample is singular."""
    try:
        return np.linalg.inv(A)
    except np.linalg.LinAlgError:
        Ainv = np.full_like(A, np.inf)
        for i in range(A.shape[0]):
            try:
                Ainv[i] = np.linalg.inv(A[i])
            except np.linalg.LinAlgError:
                pass
        return Ainv


def check_condition(cond: FloatArray, max_cond: float, what: str, offset: int) -> None:
    """A one-line :class:`~dynid.errors.ModelError` at the first sample whose condition number is
    not finite or above ``max_cond`` (sample numbers from ``offset``)."""
    bad = ~np.isfinite(cond) | (cond > max_cond)
    if np.any(bad):
        worst = int(np.flatnonzero(bad)[0])
        raise ModelError(
            f"sample {offset + worst}: singular configuration (condition number of {what} = {cond[worst]:.3g} > {max_cond:.3g})"
        )
