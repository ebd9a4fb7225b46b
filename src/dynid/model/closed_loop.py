"""Dynamics of closed-loop mechanisms in regressor form (virtual power).

For a :class:`~dynid.model.mechanism.Mechanism` with velocity map :math:`\\dot q = G\\dot u`
(DESIGN.md, "Closed-loop mechanisms"; Abdellatif & Heimann, paper 002, Jourdain's
principle; Shang et al. 2009, paper 001, Eqs. 4–6):

.. math::

    G^T\\big(Y_{tree}(q,\\dot q,\\ddot q)\\,\\pi + F(\\dot q,\\ddot q)\\,\\varphi\\big)
    = G^T S_a^T \\tau_a = G_a^T \\tau_a, \\qquad G_a = S_a G ,

with :math:`Y_{tree}` pinocchio's joint-torque regressor of the open tree (all bodies,
columns of massless bodies dropped), :math:`F` the joint-term columns (friction and rotor
inertia of **every** joint, passive ones included) and :math:`\\tau_a` the actuator forces.

* Non-redundant actuation (:math:`n_a = n_u`): :math:`\\tau_a = G_a^{-T} G^T (\\ldots)`;
  with the actuated joints as independent coordinates :math:`G_a = I`.
* Redundant actuation (:math:`n_a > n_u`) has no unique :math:`\\tau_a`. Two models:

  - ``"projected"``: the :math:`n_u` equations above, with the measured forces projected
    as :math:`y = G_a^T \\tau_a` -- no assumption about how the controller distributes
    the forces;
  - ``"min_norm"``: :math:`\\tau_a = (G_a^T)^+ G^T(\\ldots)`, the minimum-norm distribution
    that a controller such as Shang's augmented PD (paper 001, Eqs. 5 and 22) applies.
    With ``local_friction`` the actuators' own joint terms are added per actuator
    instead of being distributed, exactly as in Shang's Eq. 5
    (:math:`\\tau = (W^T)^+(M_e\\ddot q_e + C_e\\dot q_e) + f`). Both are assumptions
    about the controller; results record which model was used.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np
import pinocchio as pin
from scipy.linalg.lapack import dgesv as _gesv

from dynid.model.serial_dynamics import motor_width, smooth_sign
from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.base_parameters import BaseParameters, _base_from_stack
from dynid.model.mechanism import JointCoordinates, KinematicState, Mechanism
from dynid.model.reduction import ParameterReduction

__all__ = [
    "DISTRIBUTIONS",
    "ActuatorRegression",
    "actuator_forces",
    "actuator_regressor",
    "mechanism_base_parameters",
    "random_consistent_states",
    "term_basis",
    "term_columns",
    "term_forces",
    "tree_regressor",
]

_REGRESSOR_BLOCK = 64  # samples per block of tree regressors (actuator_regressor; 128 before, about 15 % slower on the hexapod)
_COMPILED = True  # actuator_regressor through dynid.model.loop_compiled (False: the numpy route, the tests' reference)
DISTRIBUTIONS = ("projected", "min_norm", "min_norm_local_friction")
Distribution = Literal["projected", "min_norm", "min_norm_local_friction"]


def term_basis(kind: str, v: FloatArray, a: FloatArray, width: FloatArray | None = None) -> FloatArray:
    """The basis function of a joint term of ``kind`` at velocities ``v`` and accelerations ``a``;
    ``width``: the Coulomb terms' smoothing per joint (:func:`dynid.model.serial_dynamics.smooth_sign`)."""
    if kind == "inertia":
        return a
    if kind == "viscous":
        return v
    if kind == "coulomb":
        return smooth_sign(v, width)
    if kind == "viscous+":
        return np.where(v > 0, v, 0.0)
    if kind == "viscous-":
        return np.where(v < 0, v, 0.0)
    if kind == "coulomb+":
        return (v > 0).astype(float) if width is None else 0.5 * (1.0 + smooth_sign(v, width))
    if kind == "coulomb-":
        return (v < 0).astype(float) if width is None else 0.5 * (1.0 - smooth_sign(v, width))
    return np.ones_like(v)  # offset


def term_columns(mech: Mechanism, dq: FloatArray, ddq: FloatArray) -> FloatArray:
    """Joint-term columns :math:`F`, shape (n, n_v, n_terms) (see :class:`JointTerm`).

    Column ``k`` holds the basis function of term ``k`` on the rows of its joints; one
    broadcast product per kind of term (a weighted term, a coupled motor: the basis of
    :math:`w = c^T\\dot q` times :math:`c`)."""
    dq = np.atleast_2d(dq)
    ddq = np.atleast_2d(ddq)
    n, nv = dq.shape
    incidence = mech.term_incidence  # incidence[j, k] = 1 if term k acts on joint j
    F = np.empty((n, nv, incidence.shape[1]))
    width = mech.coulomb_width
    for kind, ks in mech.term_groups:
        F[:, :, ks] = term_basis(kind, dq, ddq, width)[:, :, None] * incidence[None, :, ks]
    for k, t in enumerate(mech.terms):
        if t.weights:  # a coupled motor: the basis of its own velocity w = c^T qd, distributed by c
            c = incidence[:, k]
            w = motor_width(width, c)
            F[:, :, k] = term_basis(t.kind, (dq @ c)[:, None], (ddq @ c)[:, None], None if w is None else [w])[:, 0][:, None] * c[None, :]
    return F


def term_forces(mech: Mechanism, params: FloatArray, dq: FloatArray, ddq: FloatArray) -> FloatArray:
    """Generalized joint forces of the joint terms, computed term by term, shape (n, n_v)."""
    params = np.asarray(params, dtype=float)
    nb = mech.n_body_params
    return np.einsum("nik,k->ni", term_columns(mech, dq, ddq), params[nb:])


def tree_regressor(mech: Mechanism, q: FloatArray, dq: FloatArray, ddq: FloatArray, *, data: pin.Data | None = None) -> FloatArray:
    """Open-tree regressor :math:`[Y_{tree}\\;F]`, shape (n, n_v, n_params).

    ``tree_regressor(...)[i] @ params`` equals pinocchio's RNEA of the tree (inertias from
    ``params``) plus the joint-term forces: the generalized forces the joints would need
    if the loops were cut.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    dq = np.atleast_2d(np.asarray(dq, dtype=float))
    ddq = np.atleast_2d(np.asarray(ddq, dtype=float))
    n, nv = q.shape
    if dq.shape != q.shape or ddq.shape != q.shape or nv != mech.nv:
        raise InputError(f"q, dq, ddq must all have shape (n, {mech.nv}); got {q.shape}, {dq.shape}, {ddq.shape}")
    model = mech.pin_model
    data = model.createData() if data is None else data
    nb = mech.n_body_params
    out = np.empty((n, nv, mech.n_standard_params))
    jtr = pin.computeJointTorqueRegressor
    all_bodies = len(mech.bodies) == model.njoints - 1
    cols = None if all_bodies else np.concatenate([np.arange(10 * (j - 1), 10 * j) for j in mech.bodies])
    block = 128
    for start in range(0, n, block):
        stop = min(start + block, n)
        Y = np.stack([jtr(model, data, qi, vi, ai) for qi, vi, ai in zip(q[start:stop], dq[start:stop], ddq[start:stop])])
        out[start:stop, :, :nb] = Y if cols is None else Y[:, :, cols]
    out[:, :, nb:] = term_columns(mech, dq, ddq)
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class ActuatorRegression:
    """Closed-loop regression rows along samples.

    Attributes
    ----------
    W : array, shape (n, n_out, n_params)
        Regressor: ``W[i] @ params`` is the model output of sample ``i``.
    distribution : str
        ``"actuators"`` (non-redundant: outputs are the actuator forces),
        ``"projected"`` (outputs are :math:`G_a^T\\tau_a`, one per independent
        coordinate) or ``"min_norm"`` / ``"min_norm_local_friction"`` (outputs are the
        actuator forces of that distribution).
    Ga : array, shape (n, n_a, n_u)
        Actuator velocity map :math:`\\dot q_a = G_a \\dot u`.
    state : KinematicState
    """

    W: FloatArray
    distribution: str
    Ga: FloatArray
    state: KinematicState

    def outputs(self, tau_a: FloatArray) -> FloatArray:
        """Measured outputs matching ``W``: the forces themselves, or :math:`G_a^T\\tau_a` (projected)."""
        tau_a = np.atleast_2d(np.asarray(tau_a, dtype=float))
        n, na = self.Ga.shape[0], self.Ga.shape[1]
        if tau_a.shape != (n, na):
            raise InputError(f"actuator forces must have shape ({n}, {na}), got {tau_a.shape}")
        if self.distribution == "projected":
            return np.einsum("nau,na->nu", self.Ga, tau_a)
        return tau_a


def actuator_regressor(
    mech: Mechanism,
    state: KinematicState,
    *,
    distribution: Distribution | None = None,
    data: pin.Data | None = None,
    out: FloatArray | None = None,
) -> ActuatorRegression:
    """Actuator-space (or projected) regressor of a closed-loop mechanism.

    Parameters
    ----------
    mech : Mechanism
    state : KinematicState
        From :meth:`Mechanism.states`.
    distribution : {"projected", "min_norm", "min_norm_local_friction"}, optional
        Required for redundant actuation, ignored (must be None) otherwise.
    data : pinocchio.Data, optional
        Working memory to reuse across calls.
    out : array, shape (n, n_out, n_params), optional
        Preallocated output (overwritten), e.g. reused chunk after chunk of a long log.

    Returns
    -------
    ActuatorRegression

    Notes
    -----
    The compiled route (:func:`dynid.model.loop_compiled.project_regressor`, the default where its
    plans apply) runs pinocchio's regressor recursion on the placements of ``forwardKinematics``
    and projects each body's regressor through its velocity per unit :math:`\\dot u`, without
    forming the tree regressor. The numpy route computes the tree regressor by pinocchio per sample
    and projects it block by block (``_REGRESSOR_BLOCK``, 64 samples: their 64 x 24 x 240 tree
    regressors of the hexapod, 3 MB, half the cache traffic of 128), chain segment by chain segment
    on the supporting rows only (see ``_chain_groups``). The two agree to rounding, exact zeros
    included (tests/test_closed_loop_structured.py).
    """
    redundant = mech.redundant
    if redundant and distribution is None:
        raise ModelError(
            f"{mech.name!r} is redundantly actuated ({mech.n_actuators} actuators, {mech.dof} DOF): "
            f"choose a force model among {list(DISTRIBUTIONS)}"
        )
    if not redundant and distribution is not None:
        raise ModelError(f"{mech.name!r} is not redundantly actuated: the actuator forces are unique, no distribution applies")
    if distribution is not None and distribution not in DISTRIBUTIONS:
        raise ModelError(f"unknown force distribution {distribution!r}; choose from {list(DISTRIBUTIONS)}")
    G = state.G
    n, nv, n_u = G.shape
    act = list(mech.actuated)
    Ga = G[:, act, :]  # (n, n_a, n_u)
    GaT = Ga.transpose(0, 2, 1)  # (n, n_u, n_a)
    # T maps projected equations (n_u rows) to outputs: tau_a = T @ G^T (...)
    if distribution == "projected":
        T, label = None, "projected"
    elif not redundant:
        label = "actuators"
        ind = mech.independent
        if isinstance(ind, JointCoordinates) and ind.joints == mech.actuated:
            T = None  # G_a = I exactly: the projected equations are the actuator forces
        else:
            T = np.linalg.inv(GaT)
    else:
        T, label = np.linalg.pinv(GaT), str(distribution)
    n_out = n_u if T is None else T.shape[1]
    shape = (n, n_out, mech.n_standard_params)
    if out is not None and (out.shape != shape or not out.flags.c_contiguous):
        raise InputError(f"out must be a C-contiguous array of shape {shape}, got {out.shape}")
    W = np.empty(shape) if out is None else out
    nb = mech.n_body_params
    model = mech.pin_model
    data = model.createData() if data is None else data
    jtr = pin.computeJointTorqueRegressor
    groups = _chain_groups(mech)
    q, dq, ddq = state.q, state.dq, state.ddq
    if _COMPILED and distribution != "min_norm_local_friction" and not any(t.weights for t in mech.terms):
        # the compiled kernels (numba imported here, never for a serial arm): G^T Y sample by
        # sample from the array pinocchio returns, G^T F without forming F
        from dynid.model import loop_compiled

        target = W if T is None else np.empty((n, n_u, mech.n_standard_params))
        bases = [term_basis(kind, dq, ddq, mech.coulomb_width) for kind, _ in mech.term_groups]
        loop_compiled.project_regressor(mech, groups, q, dq, ddq, G, bases, target, data)
        if T is not None:
            np.matmul(T, target, out=W)
        return ActuatorRegression(W=W, distribution=label, Ga=Ga, state=state)
    block = _REGRESSOR_BLOCK
    Yb = np.empty((block, nv, 10 * (model.njoints - 1)))
    Pb = np.empty((block, n_u, nb))
    for start in range(0, n, block):
        stop = min(start + block, n)
        m = stop - start
        Y, P = Yb[:m], Pb[:m]
        for k, (qi, vi, ai) in enumerate(zip(q[start:stop], dq[start:stop], ddq[start:stop])):
            Y[k] = jtr(model, data, qi, vi, ai)
        Gt = G[start:stop].transpose(0, 2, 1)
        for rows, ycols, keep, wcols in groups:
            prod = np.matmul(Gt[:, :, rows], Y[:, rows, ycols])
            P[:, :, wcols] = prod if keep is None else prod[:, :, keep]
        W[start:stop, :, :nb] = P if T is None else np.matmul(T[start:stop], P)
    # joint-term columns
    local = None
    if distribution != "min_norm_local_friction" and not any(t.weights for t in mech.terms):
        PF = _projected_terms(mech, G, dq, ddq)
    else:
        F = term_columns(mech, dq, ddq)
        if distribution == "min_norm_local_friction":
            # the actuators' own joint terms stay local (Shang 2009, Eq. 5); the rest is distributed
            local = F[:, act, :].copy()
            F[:, act, :] = 0.0
        PF = np.matmul(G.transpose(0, 2, 1), F)
    W[:, :, nb:] = PF if T is None else np.matmul(T, PF)
    if local is not None:
        W[:, :, nb:] += local
    return ActuatorRegression(W=W, distribution=label, Ga=Ga, state=state)


def _projected_terms(mech: Mechanism, G: FloatArray, dq: FloatArray, ddq: FloatArray) -> FloatArray:
    """:math:`G^T F` (n, n_u, n_terms) of unweighted joint terms without forming :math:`F`
    (:func:`term_columns`: mostly zeros, n x n_v x n_terms): per kind of term,
    :math:`\\sum_j G_{ju}\\,b_j\\,I_{jk}` (basis :math:`b`, incidence :math:`I`) as one matrix
    product over all samples. The same products as :math:`G^T F` (the incidence is 0/1), summed in
    another order (rounding)."""
    n, nv, n_u = G.shape
    inc = mech.term_incidence
    out = np.empty((n, n_u, inc.shape[1]))
    Gt = G.transpose(0, 2, 1)
    for kind, ks in mech.term_groups:
        X = np.multiply(Gt, term_basis(kind, dq, ddq, mech.coulomb_width)[:, None, :], order="C")
        out[:, :, ks] = (X.reshape(n * n_u, nv) @ inc[:, ks]).reshape(n, n_u, len(ks))
    return out


def _as_index(idx: np.ndarray):
    """A slice when the indices are consecutive (a view instead of a copy)."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


def _chain_groups(mech: Mechanism) -> list:
    """Bodies grouped by serial chain segments, for the projection :math:`G^T Y`.

    Body ``j``'s columns of the tree regressor are non-zero only on the rows of the joints
    that support it. A segment of consecutive bodies, each the child of the previous one,
    is projected at once on the rows supporting its last body (e.g. one strut of the
    hexapod: 3 rows, 30 columns, instead of 24 rows). Returns tuples
    ``(rows, tree columns, kept columns within the group or None, output columns)``.
    """
    cached = mech.__dict__.get("_chain_groups_cache")
    if cached is not None:
        return cached
    model = mech.pin_model
    out_index = {j: k for k, j in enumerate(mech.bodies)}
    segments: list[list[int]] = []
    for j in range(1, model.njoints):
        if segments and model.parents[j] == segments[-1][-1]:
            segments[-1].append(j)
        else:
            segments.append([j])
    groups = []
    for seg in segments:
        rows = []
        for a in model.supports[seg[-1]].tolist()[1:]:
            rows.extend(range(model.joints[a].idx_v, model.joints[a].idx_v + model.joints[a].nv))
        massive = [j for j in seg if j in out_index]
        if not massive:
            continue
        # the columns of the segment's massive bodies only where they are consecutive (the hexapod's
        # platform chain: five massless joints and the platform, 10 columns multiplied instead of 60)
        first = massive[0] if massive == list(range(massive[0], massive[-1] + 1)) else seg[0]
        last = massive[-1] if first != seg[0] else seg[-1]
        tree_cols = np.arange(10 * (first - 1), 10 * last)
        keep = np.concatenate([np.arange(10 * (j - first), 10 * (j - first) + 10) for j in massive])
        wcols = np.concatenate([np.arange(10 * out_index[j], 10 * out_index[j] + 10) for j in massive])
        groups.append((
            _as_index(np.array(rows)),
            _as_index(tree_cols),
            None if keep.size == tree_cols.size else keep,
            _as_index(wcols),
        ))
    object.__setattr__(mech, "_chain_groups_cache", groups)
    return groups


def actuator_forces(
    mech: Mechanism, params: FloatArray, state: KinematicState, *, distribution: Distribution | None = None,
    model: pin.Model | None = None, data: pin.Data | None = None,
) -> FloatArray:
    """Actuator forces by pinocchio's RNEA on the tree plus the joint terms, then projected.

    A second route to the forces (no regressor): :math:`\\tau_{tree}` = RNEA with inertias
    from ``params`` + :func:`term_forces`; then the same projection/distribution as
    :func:`actuator_regressor`. Shape (n, n_a) (or (n, n_u) for ``"projected"``). ``model``
    (``mech.with_parameters(params)``) and ``data`` may be passed to reuse them call after call
    (a controller).
    """
    params = np.asarray(params, dtype=float)
    model = mech.with_parameters(params) if model is None else model
    data = model.createData() if data is None else data
    if state.q.shape[0] == 1:  # a controller's call
        return _actuator_forces_one(mech, params, state, distribution, model, data)[None]
    tau = np.array([pin.rnea(model, data, q, v, a) for q, v, a in zip(state.q, state.dq, state.ddq)])
    terms = term_columns(mech, state.dq, state.ddq) * params[mech.n_body_params :]
    act = list(mech.actuated)
    local = np.zeros_like(tau)
    if distribution == "min_norm_local_friction":
        local[:, act] = terms[:, act, :].sum(axis=2)
    tau = tau + terms.sum(axis=2) - local
    G = state.G
    proj = np.einsum("niu,ni->nu", G, tau)
    Ga = G[:, act, :]
    if distribution == "projected":
        return proj
    if not mech.redundant:
        return np.linalg.solve(Ga.transpose(0, 2, 1), proj[..., None])[..., 0]
    return np.einsum("nau,nu->na", np.linalg.pinv(Ga.transpose(0, 2, 1)), proj) + local[:, act]


def _actuator_forces_one(mech: Mechanism, params: FloatArray, state: KinematicState, distribution, model: pin.Model,
                         data: pin.Data) -> FloatArray:
    """:func:`actuator_forces` of one sample (:class:`OneSampleForces`, the joint terms by
    :func:`term_columns`: nothing to sum once for a single call)."""
    forces = OneSampleForces(mech, params, distribution, per_joint=False)
    return forces(state.q[0], state.dq[0], state.ddq[0], state.G[0], model, data)


def piecewise_linear_terms(mech: Mechanism, theta: FloatArray) -> FloatArray:
    """The velocity-dependent joint terms (viscous, Coulomb, their one-sided forms, offsets) summed
    per joint, as coefficients ``(a, b, c, d, e)``, each (n_v,), of
    :math:`a\\,v^+ + b\\,v^- + c\\,[v>0] + d\\,[v<0] + e` (one vectorized evaluation per
    call instead of one per kind of term); unweighted terms with the Coulomb law
    :math:`\\mathrm{sign}(v)` (no ``coulomb_width``).

    Every such basis function is piecewise linear in the joint velocity with a jump at 0, so its
    five coefficients follow exactly from :func:`term_basis` at v = 0, +-1, +-2 (no second copy
    of the basis definitions). Rotor inertia (``inertia`` terms) is not among them."""
    probe = np.array([0.0, 1.0, 2.0, -1.0, -2.0])
    coef = np.zeros((5, mech.nv))
    for kind, ks in mech.term_groups:
        if kind == "inertia":
            continue
        b0, b1, b2, bm1, bm2 = term_basis(kind, probe, np.zeros_like(probe))
        slope_pos, slope_neg = b2 - b1, bm1 - bm2
        k = np.array([slope_pos, slope_neg, b1 - slope_pos - b0, bm1 + slope_neg - b0, b0])
        coef += np.outer(k, mech.term_incidence[:, ks] @ theta[ks])
    return coef


class OneSampleForces:
    """:func:`actuator_forces` of one sample, with the parameters' per-joint sums computed once (a
    controller calls it every period, Shang et al. 2009, Eq. 22: :math:`(S^T)^+` of the model's
    forces plus the actuators' own friction).

    The joint terms are summed per joint: rotor inertia times :math:`\\ddot q` plus the
    piecewise-linear law of :func:`piecewise_linear_terms`,
    :math:`s(v)\\,v + l(v) + e` with slope :math:`s = a` or :math:`b` and level
    :math:`l = c`, :math:`d` or 0 by the sign of :math:`v` (the same value as
    :math:`a v^+ + b v^- + c[v>0] + d[v<0] + e`: the other terms are exact zeros; the same value
    as the batched route's sum of :func:`term_columns` wherever a joint has at most two non-zero
    terms at a time, e.g. one-sided viscous and Coulomb friction without rotor inertia, otherwise
    the same sum in another order). Weighted terms (coupled motors) and smoothed Coulomb terms
    take :func:`term_columns`. The projection and the distribution are those of the batched
    route, operation for operation (numpy's SVD pseudo-inverse for the minimum-norm distribution).
    Agreement with the batched route: tests/test_closed_loop_fast_paths.py.

    Parameters
    ----------
    mech : Mechanism
    params : array, shape (n_params,)
    distribution : str or None
        As in :func:`actuator_forces`.
    per_joint : bool
        Sum the joint terms per joint once (default); False: :func:`term_columns` at every call.
    """

    def __init__(self, mech: Mechanism, params: FloatArray, distribution: Distribution | None = None, *,
                 per_joint: bool = True) -> None:
        params = np.asarray(params, dtype=float)
        theta = params[mech.n_body_params :]
        self.mech, self.theta, self.distribution = mech, theta, distribution
        self.act = np.array(mech.actuated, dtype=int)
        self.redundant = mech.redundant
        ind = mech.independent
        self.identity = isinstance(ind, JointCoordinates) and ind.joints == mech.actuated  # G_a = I exactly
        self.general = not per_joint or mech.coulomb_width is not None or any(t.weights for t in mech.terms)
        if not self.general:
            a, b, c, d, e = piecewise_linear_terms(mech, theta)
            self.a, self.b, self.c, self.d, self.e = a, b, c, d, e
            self.has_e = bool(np.any(e))
            # a = b, d = -c, e = 0 (the hexapod's model): a v + c sign(v), the same values in fewer
            # operations (where(v > 0, a, b) v = a v; the levels c, -c, 0 are c sign(v))
            self.symmetric = bool(np.array_equal(a, b) and np.array_equal(d, -c) and not self.has_e)
            inertia = np.zeros(mech.nv)
            for kind, ks in mech.term_groups:
                if kind == "inertia":
                    inertia += mech.term_incidence[:, ks] @ theta[ks]
            self.inertia = inertia if np.any(inertia) else None
        self.local = distribution == "min_norm_local_friction"
        self.own = np.zeros(mech.nv)  # 1 on the actuated joints: their own terms stay local
        self.own[self.act] = 1.0

    def terms(self, dq: FloatArray, ddq: FloatArray) -> FloatArray:
        """Generalized forces of the joint terms, (n_v,)."""
        if self.general:
            return (term_columns(self.mech, dq[None], ddq[None])[0] * self.theta).sum(axis=1)
        if self.symmetric:
            f = self.a * dq + self.c * np.sign(dq)
        else:
            pos = dq > 0
            f = np.where(pos, self.a, self.b) * dq + np.where(pos, self.c, np.where(dq < 0, self.d, 0.0))
        if self.has_e:
            f = f + self.e
        if self.inertia is not None:
            f = f + self.inertia * ddq
        return f

    def __call__(self, q: FloatArray, dq: FloatArray, ddq: FloatArray, G: FloatArray, model: pin.Model,
                 data: pin.Data) -> FloatArray:
        """The forces at one state (``G``: its velocity map), with ``model`` the tree of the
        parameters' inertias and ``data`` its working memory; (n_a,), or (n_u,) projected."""
        f = self.terms(dq, ddq)
        tau = pin.rnea(model, data, q, dq, ddq) + f
        if self.local:  # the actuators' own terms are added per actuator below, not distributed
            tau = tau - f * self.own
        proj = G.T @ tau
        if self.distribution == "projected" or self.identity:
            return proj
        Ga = G[self.act]
        if not self.redundant:  # LAPACK's gesv directly (numpy.linalg.solve's own: the same LU, less overhead)
            lu, piv, x, info = _gesv(Ga.T, proj)
            if info != 0:
                raise np.linalg.LinAlgError("Singular matrix")
            return x
        return np.linalg.pinv(Ga.T) @ proj + (f[self.act] if self.local else 0.0)


def random_consistent_states(
    mech: Mechanism,
    n_samples: int,
    rng: np.random.Generator,
    *,
    spread: float = 0.3,
    vel_scale: float = 1.0,
    acc_scale: float = 3.0,
    max_cond: float = 1e6,
) -> KinematicState:
    """Random constraint-consistent states around the reference configuration.

    Independent coordinates are drawn uniformly in a box around ``u(q_ref)`` whose half-width
    is ``spread / 2`` times the range of each coordinate (joint limits; for point
    coordinates twice the mean link length); each pose is solved by Newton from ``q_ref``
    and kept only if it converges, is well conditioned and respects the joint limits (20
    rejections in a row halve the box). Velocities and accelerations of ``u`` are Gaussian.
    """
    u_ref = mech.coordinates(mech.q_ref)[0]
    lo, hi = mech.position_limits()
    ind = mech.independent
    if isinstance(ind, JointCoordinates):
        rng_u = np.array([hi[j] - lo[j] if np.isfinite(hi[j] - lo[j]) else 2.0 for j in ind.joints])
    else:
        # a length scale of the mechanism: the mean distance between consecutive joint origins
        steps = [np.linalg.norm(mech.pin_model.jointPlacements[j].translation) for j in range(1, mech.pin_model.njoints)]
        rng_u = np.full(ind.size, 2.0 * max(float(np.mean(steps)), 1e-3))
    radius = 0.5 * spread * rng_u
    qs: list[FloatArray] = []
    tries, fails = 0, 0
    while len(qs) < n_samples:
        tries += 1
        if tries > 50 * n_samples + 100:
            raise ModelError(f"could not draw {n_samples} assembled configurations of {mech.name!r} (got {len(qs)})")
        if fails >= 20:  # mostly out of reach: shrink the sampling box
            radius, fails = radius / 2, 0
        u = u_ref + radius * rng.uniform(-1.0, 1.0, size=u_ref.shape)
        try:
            q = mech.solve_positions(u[None], max_cond=max_cond)[0]
        except ModelError:
            fails += 1
            continue
        if np.any(q < lo - 1e-9) or np.any(q > hi + 1e-9):
            fails += 1
            continue
        fails = 0
        qs.append(q)
    q = np.array(qs)
    du = vel_scale * rng.standard_normal((n_samples, u_ref.size))
    ddu = acc_scale * rng.standard_normal((n_samples, u_ref.size))
    return mech.states(q, du, ddu, max_cond=max_cond)


def mechanism_base_parameters(
    mech: Mechanism,
    *,
    distribution: Distribution | None = None,
    n_samples: int | None = None,
    seed: int = 0,
    spread: float = 0.3,
    rank_tol: float = 1e-8,
    reduction: ParameterReduction | None = None,
) -> BaseParameters:
    """Base parameters of a closed-loop mechanism, on constraint-consistent random samples.

    With a ``reduction`` (:mod:`dynid.model.reduction`), those of the reduced regressor
    :math:`Y T` in the parameters :math:`\\psi` (:math:`\\pi = T\\psi`).

    The projected equations :math:`G^T[Y\\;F]` are used for redundant actuation unless
    another distribution is asked for (the minimum-norm rows span the same column space
    only through the pseudo-inverse, which cannot create or remove dependencies among
    the body parameters, but can among actuator terms with ``local_friction``).
    """
    p = mech.n_standard_params
    n_samples = int(n_samples) if n_samples is not None else max(100, 2 * p // max(mech.dof, 1) + 20)
    rng = np.random.default_rng(seed)
    state = random_consistent_states(mech, n_samples, rng, spread=spread)
    dist = distribution if mech.redundant else None
    if mech.redundant and dist is None:
        dist = "projected"
    W = actuator_regressor(mech, state, distribution=dist).W
    if reduction is not None:
        W, p = W @ reduction.T, reduction.n_params
        return _base_from_stack(W.reshape(-1, p), reduction.names, rank_tol, n_samples, seed)
    return _base_from_stack(W.reshape(-1, p), mech.parameter_names, rank_tol, n_samples, seed)
