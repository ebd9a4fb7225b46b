"""The loop-closure Jacobian of the dependent joints inverted by its leg structure, batched over samples.

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
determinant). The plan is used on a block of samples only when every :math:`\\kappa_1(D_g)\\kappa_1(S)`
is below :data:`MAX_PIVOT_COND` (1e4: an error below about :math:`10^4 \\cdot 2^{-52} \\approx 2\\cdot10^{-12}`
relative); otherwise (a leg near its own singularity while the mechanism is not, or a singular
sample, whose error message is the dense route's) the block takes the dense inverse.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.model.closure_geometry import _sides
from dynid.model.closures import JointCoordinates

Mechanism = Any  # a dynid.model.mechanism.Mechanism (named, not imported: no import cycle)

MAX_PIVOT_COND = 1e4
"""Largest :math:`\\kappa_1(D_g)\\,\\kappa_1(S)` for which the structured inverse is used (module docstring)."""

__all__ = ["LegPlan", "leg_plan"]


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
        self.flat_u = u_group * k + u_pos  # the independent joints' leg rows in D^-1 (flattened)
        n_u = shared.size
        self.nc, self.n_u = nc, n_u
        self.gi, self.ki, self.local_b = np.arange(m)[:, None, None], np.arange(k)[None, :, None], local[:, None, :]
        # flat positions: F's non-zeros (row i, leg u_group[i]'s k columns), D^-1's blocks in the
        # (nc + n_u, nc) inverse, and the output (dependent variables x constraint rows)
        self.f_idx = (np.arange(n_u)[:, None] * nc + u_group[:, None] * k + np.arange(k)).reshape(-1)
        g, a, b = np.meshgrid(np.arange(m), np.arange(k), np.arange(k), indexing="ij")
        self.d_idx = ((g * k + a) * nc + g * k + b).reshape(-1)
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
    """Inverses of stacked k x k matrices (closed form, adjugate over determinant, for k <= 3;
    LAPACK otherwise) and their 1-norm condition numbers (inf where singular)."""
    k = D.shape[-1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if k == 1:
            inv = 1.0 / D
        elif k == 2:
            a, b, c, d = D[..., 0, 0], D[..., 0, 1], D[..., 1, 0], D[..., 1, 1]
            det = a * d - b * c
            inv = np.stack([d, -b, -c, a], -1).reshape(D.shape) / det[..., None, None]
        elif k == 3:
            r0, r1, r2 = D[..., 0, :], D[..., 1, :], D[..., 2, :]
            adjT = np.stack([_cross(r1, r2), _cross(r2, r0), _cross(r0, r1)], -2)  # rows: the adjugate's columns
            det = (r0 * adjT[..., 0, :]).sum(-1)
            inv = adjT.swapaxes(-1, -2) / det[..., None, None]
        else:
            try:
                inv = np.linalg.inv(D)
            except np.linalg.LinAlgError:
                return D, np.full(D.shape[:-2], np.inf)
        cond = np.abs(D).sum(-2).max(-1) * np.abs(inv).sum(-2).max(-1)
    return inv, np.where(np.isfinite(cond), cond, np.inf)


def inverse(plan: LegPlan, rows: FloatArray) -> FloatArray | None:
    """:math:`J_{c,w}^{-1}` of ``rows`` (n, n_c, n_v) (the independent constraint rows, columns in
    ``_Sides``' output order) by block elimination (module docstring), shape (n, n_c, n_c); None
    where a pivot block is too ill-conditioned for it (the caller takes the dense inverse)."""
    n = rows.shape[0]
    m, k, nc, n_u = plan.m, plan.k, plan.nc, plan.n_u
    Rg = rows[:, plan.rows]  # (n, m, k, n_v): each closure's rows
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
    if not np.all(cD.max(axis=1, initial=0.0) * cS <= MAX_PIVOT_COND):  # NaN fails too
        return None
    # F = C D^-1 (n, n_u, nc): row i is row u_pos[i] of leg u_group[i]'s D^-1, in that leg's columns
    F = np.zeros((n, n_u * nc))
    F[:, plan.f_idx] = Dflat[:, plan.flat_u].reshape(n, -1)
    F = F.reshape(n, n_u, nc)
    inv = np.empty((n, nc + n_u, nc))  # A^-1 on the closure equations, in the plan's order
    np.matmul(np.matmul(E, Sinv), F, out=inv[:, :nc])  # D^-1 B S^-1 C D^-1
    inv.reshape(n, -1)[:, plan.d_idx] += Dinv.reshape(n, -1)  # + D^-1 (block diagonal)
    np.matmul(-Sinv, F, out=inv[:, nc:])
    return inv.reshape(n, -1)[:, plan.out_idx].reshape(n, plan.nw, nc)
