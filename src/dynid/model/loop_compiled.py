"""The compiled route of the closed-chain states and regressor (issue 37, item 1, third pass).

Per sample only pinocchio is called from Python (states: ``computeJointJacobians`` and the
placements' copy; regressor: ``forwardKinematics`` and the copy of the joints' placements in their
parents' frames, from which :func:`dynid.model._loop_kernels.tree_project` runs pinocchio's
regressor recursion and projects it body by body without forming the tree regressor;
``computeJointJacobiansTimeVariation`` and ``computeJointTorqueRegressor`` only with
:data:`DJ_FROM_J` or :data:`TREE_FROM_J` off); everything between them runs in the numba kernels
of :mod:`dynid.model._loop_kernels`, one loop over the samples of a block each. The numpy routes
(:func:`dynid.model.loop_kinematics.states` with ``loop_kinematics._COMPILED`` off,
:func:`dynid.model.closed_loop.actuator_regressor` with ``closed_loop._COMPILED`` off) stay as the
reference; the values agree to rounding (tests/test_closed_loop_structured.py;
bench/README.md, "Compiled per-sample kernels").

Where the compiled route applies: joint coordinates as the independent coordinates, the
placements readable through :func:`dynid.model.loop_batch.placement_view`, the all-sides plan of
:func:`dynid.model.loop_blocks.side_scatter`; the leg structure (:func:`~dynid.model.loop_blocks.leg_plan`,
legs of at most three joints) for the block-elimination inverse, the dense LAPACK inverse
otherwise and for the samples whose pivots refuse it. Elsewhere the callers keep the numpy route.

This module does not import numba itself: :mod:`dynid.model._loop_kernels` is imported inside the
functions (numba's import costs about 0.2 s; a serial arm never pays it).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.model import loop_batch, loop_blocks
from dynid.model.closure_geometry import _sides
from dynid.model.closures import JointCoordinates

Mechanism = Any  # a dynid.model.mechanism.Mechanism (named, not imported: no import cycle)

__all__ = ["StatesPlan", "project_regressor", "states_block", "states_plan"]

_I = np.int64
_BLOCK = 256  # samples per block of Jacobians and placements (tree_project)
DJ_FROM_J = True
"""The drift's :math:`\\dot J\\dot q` from :math:`J` in the kernel (pinocchio's formula,
:func:`dynid.model._loop_kernels.drift_accelerations`) instead of pinocchio's
``computeJointJacobiansTimeVariation`` per sample (False): the same values to rounding, one
pinocchio pass (about 2 us a hexapod sample) less (bench/README.md, "Compiled per-sample kernels")."""


class StatesPlan:
    """Index arrays of the kernels for one mechanism (see :mod:`dynid.model._loop_kernels`)."""

    def __init__(self, mech: Mechanism, sc: loop_blocks.SideScatter) -> None:
        sd = _sides(mech)
        k = len(sd.joints)
        jsel = np.array(sd.joints, dtype=int)
        self.jsel = slice(int(jsel[0]), int(jsel[0]) + k) if np.array_equal(jsel, np.arange(jsel[0], jsel[0] + k)) else jsel
        self.k = k
        self.slot = np.ascontiguousarray(sd.slot, dtype=_I)
        self.r = np.ascontiguousarray(sd.r, dtype=float).reshape(-1, 3)
        self.moving_ref = np.ascontiguousarray(np.asarray(sd.ref_index)[sc.moving], dtype=_I)
        self.cols = np.ascontiguousarray(sc.cols, dtype=_I)
        self.n_dims = 6 if sc.any_6d else 3
        self.rows_args = tuple(np.ascontiguousarray(a, dtype=_I) for a in (sc.tgt_a, sc.src_a, sc.tgt_b, sc.src_b))
        self.n_rows = sc.n_rows
        bodies = sd.body_columns
        self.body_ptr = np.cumsum([0] + [len(c) for c in bodies]).astype(_I)
        self.body_cols = np.ascontiguousarray(np.concatenate(bodies) if bodies else np.zeros(0), dtype=_I)
        # the position (in body_cols) of the last column of each column's joint
        model = mech.pin_model
        joint_of = np.empty(model.nv, dtype=int)
        for j in range(1, model.njoints):
            joint_of[model.joints[j].idx_v : model.joints[j].idx_v + model.joints[j].nv] = j
        end = np.empty(self.body_cols.size, dtype=_I)
        for b in range(len(bodies)):
            for x in range(self.body_ptr[b], self.body_ptr[b + 1]):
                same = [y for y in range(x, self.body_ptr[b + 1]) if joint_of[self.body_cols[y]] == joint_of[self.body_cols[x]]]
                end[x] = same[-1]
        self.body_end = end
        self.body_of = np.ascontiguousarray(sc.body_of, dtype=_I)
        self.drift_args = tuple(np.ascontiguousarray(a, dtype=_I) for a in (sc.dtgt_a, sc.dsrc_a, sc.dtgt_b, sc.dsrc_b))
        self.u = np.ascontiguousarray(sd.u, dtype=_I)
        self.w = np.ascontiguousarray(sd.w, dtype=_I)
        # the structurally non-zero rows of each column of J_c,u: those the sides' rows reach
        nv, nw = mech.nv, sd.w.size
        tgt = np.concatenate([sc.tgt_a, sc.tgt_b]).astype(int)
        reach = np.zeros((sc.n_rows, nv), dtype=bool)
        reach[tgt // nv, tgt % nv] = True
        cu = [np.flatnonzero(reach[:, nw + j]) for j in range(nv - nw)]
        self.cu_ptr = np.cumsum([0] + [c.size for c in cu]).astype(_I)
        self.cu_rows = np.ascontiguousarray(np.concatenate(cu) if cu else np.zeros(0), dtype=_I)
        plan = loop_blocks.leg_plan(mech)
        self.leg = None
        if plan is not None and plan.k <= 3:
            row_out = np.full(plan.nc + plan.n_u, -1)
            row_out[plan.w_pos] = np.arange(plan.w_pos.size)
            col_out = np.empty(plan.nc, dtype=int)
            col_out[plan.eq_pos] = np.arange(plan.nc)
            self.leg = tuple(np.ascontiguousarray(a, dtype=_I) for a in (
                plan.rows, plan.local, plan.shared, plan.flat_u, plan.u_group, plan.u_pos, row_out, col_out))


def states_plan(mech: Mechanism, data: pin.Data) -> StatesPlan | None:
    """The compiled route's plan of ``mech`` (cached on it), or None where it does not apply."""
    if not isinstance(mech.independent, JointCoordinates) or not mech.closures:
        return None
    sc = loop_blocks.side_scatter(mech)
    if sc is None or not len(_sides(mech).joints) or loop_batch.placement_view(mech, data) is None:
        return None
    cached = mech.__dict__.get("_compiled_states_plan")
    if cached is None:
        cached = StatesPlan(mech, sc)
        object.__setattr__(mech, "_compiled_states_plan", cached)
    return cached


def states_block(mech: Mechanism, plan: StatesPlan, q: FloatArray, du: FloatArray, ddu: FloatArray, max_cond: float,
                 offset: int, data: pin.Data, dq: FloatArray, ddq: FloatArray, G: FloatArray, cond: FloatArray) -> None:
    """:func:`dynid.model.loop_kinematics.states` of one block of samples into ``dq``, ``ddq``,
    ``G``, ``cond`` (C-contiguous, the block's length); the one-line error of the numpy route at
    the first sample whose :math:`J_{c,w}` is singular or too ill-conditioned."""
    from dynid.model import _loop_kernels as kern

    model = mech.pin_model
    q, du, ddu = (np.ascontiguousarray(x) for x in (q, du, ddu))
    n, nv = q.shape
    J = np.empty((n, 6, nv))
    flat = np.empty((n, plan.k, 12))
    view = loop_batch.placement_view(mech, data)[plan.jsel]  # the side joints' rows: data's memory, read per sample
    cjj = pin.computeJointJacobians
    for i, qi in enumerate(q):
        J[i] = cjj(model, data, qi)
        flat[i] = view
    if plan.leg is not None and DJ_FROM_J:  # all in one pass, sample after sample
        ok = np.empty(n, dtype=np.bool_)
        kern.states_fused(J, flat, plan.slot, plan.r, plan.moving_ref, plan.cols, *plan.rows_args, plan.n_dims,
                          *plan.leg, loop_blocks.MAX_PIVOT_COND, plan.u, plan.w, plan.cu_ptr, plan.cu_rows,
                          plan.body_ptr, plan.body_cols, plan.body_end, plan.body_of, *plan.drift_args,
                          du, ddu, G, cond, dq, ddq, ok)
        if not ok.all():  # pivots too ill-conditioned for block elimination: these samples densely
            bad = np.flatnonzero(~ok)
            out = [np.empty((bad.size, *x.shape[1:])) for x in (G, cond, dq, ddq)]
            _separate(mech, plan, q[bad], J[bad], flat[bad], du[bad], ddu[bad], data, False, *out)
            G[bad], cond[bad], dq[bad], ddq[bad] = out
    else:
        _separate(mech, plan, q, J, flat, du, ddu, data, plan.leg is not None, G, cond, dq, ddq)
    loop_blocks.check_condition(cond, max_cond, "the loop-closure Jacobian of the dependent joints", offset)


def _separate(mech: Mechanism, plan: StatesPlan, q: FloatArray, J: FloatArray, flat: FloatArray, du: FloatArray,
              ddu: FloatArray, data: pin.Data, leg: bool, G: FloatArray, cond: FloatArray, dq: FloatArray,
              ddq: FloatArray) -> None:
    """The states by the separate kernels over the block (rows, inverse: by the leg plan where
    ``leg`` and its pivots allow, else dense; maps; drift, :math:`\\dot J` from pinocchio unless
    :data:`DJ_FROM_J`)."""
    from dynid.model import _loop_kernels as kern

    n, nv = q.shape
    nc = plan.n_rows
    rows = np.empty((n, nc, nv))
    ps = np.empty((n, plan.cols.shape[0], 3))
    kern.closure_rows(J, flat, plan.slot, plan.r, plan.moving_ref, plan.cols, *plan.rows_args, plan.n_dims,
                      rows.reshape(n, -1), ps)
    nw = plan.w.size
    if leg:
        inv = np.empty((n, nw, nc))
        ok = np.empty(n, dtype=np.bool_)
        kern.leg_inverse(rows, *plan.leg, loop_blocks.MAX_PIVOT_COND, inv, ok)
        if not ok.all():
            inv[~ok] = loop_blocks.dense_inverse(rows[~ok][:, :, :nw])
    else:
        inv = np.ascontiguousarray(loop_blocks.dense_inverse(rows[:, :, :nw]))
    kern.velocity_maps(rows, inv, plan.u, plan.w, plan.cu_ptr, plan.cu_rows, du, G, cond, dq)
    if DJ_FROM_J:
        dJ = J[:1]  # not read
    else:
        dJ = np.empty((n, 6, nv))
        tv, model = pin.computeJointJacobiansTimeVariation, mech.pin_model
        for i, (qi, vi) in enumerate(zip(q, dq)):
            dJ[i] = tv(model, data, qi, vi)
    kern.drift_accelerations(J, dJ, DJ_FROM_J, dq, ps, plan.body_ptr, plan.body_cols, plan.body_end, plan.body_of,
                             *plan.drift_args, plan.n_dims, rows, inv, plan.u, plan.w, plan.cu_ptr, plan.cu_rows, ddu, ddq)


def _runs(t: np.ndarray, w: np.ndarray) -> list[tuple[int, int, int]]:
    """(tree column, output column, length) runs where both index lists are consecutive."""
    runs: list[list[int]] = []
    for a, b in zip(t.tolist(), w.tolist()):
        if runs and a == runs[-1][0] + runs[-1][2] and b == runs[-1][1] + runs[-1][2]:
            runs[-1][2] += 1
        else:
            runs.append([a, b, 1])
    return [tuple(r) for r in runs]


def _regressor_plan(mech: Mechanism, groups: list) -> np.ndarray:
    """The chain groups of ``closed_loop._chain_groups`` and the joint terms (:func:`_terms_plan`)
    packed for :func:`dynid.model._loop_kernels.project_sample` (cached on ``mech``)."""
    cached = mech.__dict__.get("_compiled_regressor_plan")
    if cached is not None and cached[0] is groups:
        return cached[1]
    nv, nt = mech.nv, 10 * (mech.pin_model.njoints - 1)
    nb = mech.n_body_params
    packed = [0, len(groups)]
    for rows, ycols, keep, wcols in groups:
        r = np.arange(nv)[rows]
        t = np.arange(nt)[ycols]
        t = t if keep is None else t[keep]
        runs = _runs(t, np.arange(nb)[wcols])
        packed += [r.size, *r.tolist(), len(runs)]
        for run in runs:
            packed += list(run)
    packed[0] = len(packed)  # the terms' part starts here
    tplan, tweight = _terms_plan(mech)
    plan = np.concatenate([np.array(packed, dtype=_I), tplan])
    object.__setattr__(mech, "_compiled_regressor_plan", (groups, plan))
    return plan


def project_regressor(mech: Mechanism, groups: list, q: FloatArray, dq: FloatArray, ddq: FloatArray, G: FloatArray,
                      bases: list[FloatArray], out: FloatArray, data: pin.Data) -> None:
    """``out[:, :, :n_body_params]`` = :math:`G^T Y_{tree}` (``out`` (n, n_u, n_params), C-contiguous)
    and ``out[:, :, n_body_params:]`` = :math:`G^T F` of the unweighted joint terms (``bases``: the
    basis of each of ``mech.term_groups``, (n, n_v) each) in the same kernel call, sample by sample.

    :math:`G^T Y_{tree}`: where :func:`tree_plan` applies and :data:`TREE_FROM_J` is on, from
    pinocchio's ``computeJointJacobians`` per sample (the Jacobians and all placements, in blocks of
    ``_BLOCK``) by :func:`dynid.model._loop_kernels.tree_project` (the bodies' velocities,
    accelerations and regressors along the tree); otherwise pinocchio's tree regressor of each
    sample (``computeJointTorqueRegressor``) projected as pinocchio returns it
    (:func:`dynid.model._loop_kernels.project_sample`, chain segment by chain segment)."""
    from dynid.model import _loop_kernels as kern

    plan = _regressor_plan(mech, groups)
    tweight = _terms_plan(mech)[1]
    G = np.ascontiguousarray(G)
    n, nv = G.shape[:2]
    fdata = np.empty(tweight.size + len(bases) * n * nv)  # the weights, then the bases
    fdata[: tweight.size] = tweight
    for k, b in enumerate(bases):
        fdata[tweight.size + k * n * nv : tweight.size + (k + 1) * n * nv] = b.reshape(-1)
    model = mech.pin_model
    tree = tree_plan(mech, data) if TREE_FROM_J else None
    if tree is not None:
        dq, ddq = np.ascontiguousarray(dq), np.ascontiguousarray(ddq)
        view = loop_batch.parent_placement_view(mech, data)
        m = max(1, min(_BLOCK, n))  # no sample: no block, the loop below does nothing
        L = np.empty((m, view.shape[0], 12))
        fk = pin.forwardKinematics
        for a in range(0, n, m):
            b = min(a + m, n)
            for s, qi in enumerate(q[a:b]):
                fk(model, data, qi)
                L[s] = view
            kern.tree_project(L[: b - a], a, G, dq, ddq, *tree, out, plan, fdata)
        return
    jtr = pin.computeJointTorqueRegressor
    proj = kern.project_sample
    for i, (qi, vi, ai) in enumerate(zip(q, dq, ddq)):
        proj(jtr(model, data, qi, vi, ai), G, out, i, plan, fdata)


TREE_FROM_J = True
"""The projected tree regressor by :func:`dynid.model._loop_kernels.tree_project` (pinocchio's
regressor recursion on the placements of ``forwardKinematics``, projected body by body without
forming the tree regressor) instead of pinocchio's ``computeJointTorqueRegressor`` per sample and
:func:`dynid.model._loop_kernels.project_sample` (False): the same values to rounding, the same
exact zeros (bench/README.md, "Item 1, fourth pass: the tree regressor without pinocchio's tree
regressor")."""

_AXIS = {f"JointModel{kind}{x}": k + off for kind, off in (("P", 0), ("R", 3), ("RUB", 3)) for k, x in enumerate("XYZ")}
"""Joints of one velocity coordinate whose motion subspace is a unit vector constant in the joint
frame (no bias acceleration), and that vector's index: what
:func:`dynid.model._loop_kernels.tree_project`'s recursion handles."""


def tree_plan(mech: Mechanism, data: pin.Data) -> tuple | None:
    """``(parent, col, axis, slot, gravity)`` of :func:`dynid.model._loop_kernels.tree_project` (the
    integer arrays cached on ``mech``), or None where it does not apply: a joint outside
    :data:`_AXIS`, or the placements not readable through
    :func:`dynid.model.loop_batch.parent_placement_view`."""
    cached = mech.__dict__.get("_compiled_tree_plan", False)
    if cached is False:
        model = mech.pin_model
        cached = None
        if all(jm.shortname() in _AXIS for jm in model.joints[1:]):
            slot = np.full(model.njoints, -1, dtype=_I)
            slot[list(mech.bodies)] = np.arange(len(mech.bodies))
            col = np.array([0] + [jm.idx_v for jm in model.joints[1:]], dtype=_I)
            axis = np.array([0] + [_AXIS[jm.shortname()] for jm in model.joints[1:]], dtype=_I)
            cached = (np.array(model.parents, dtype=_I), col, axis, slot)
        object.__setattr__(mech, "_compiled_tree_plan", cached)
    if cached is None or loop_batch.parent_placement_view(mech, data) is None:
        return None
    return (*cached, np.array(mech.pin_model.gravity.vector, dtype=float))


def _terms_plan(mech: Mechanism) -> tuple[np.ndarray, np.ndarray]:
    """The joint terms packed for :func:`dynid.model._loop_kernels.project_sample` (cached on ``mech``):
    ``[n_body_params, n_terms, n_weights, (kind group, n_joints, joints...)...]`` and the incidence
    weights."""
    cached = mech.__dict__.get("_compiled_terms_plan")
    if cached is None:
        inc = mech.term_incidence
        kind_of = np.empty(inc.shape[1], dtype=int)
        for g, (_, ks) in enumerate(mech.term_groups):
            kind_of[ks] = g
        packed, weight = [mech.n_body_params, inc.shape[1], 0], []
        for k in range(inc.shape[1]):
            j = np.flatnonzero(inc[:, k])
            packed += [int(kind_of[k]), j.size, *j.tolist()]
            weight += inc[j, k].tolist()
        packed[2] = len(weight)
        cached = (np.array(packed, dtype=_I), np.array(weight, dtype=float))
        object.__setattr__(mech, "_compiled_terms_plan", cached)
    return cached
