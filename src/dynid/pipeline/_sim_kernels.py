"""The model replays of IDIM-IV and DIDIM with their per-period NumPy work compiled (issue 37, item 3,
third pass; bench/README, "Closed-loop estimators, compiled replay").

A replay (:func:`dynid.pipeline.simulate.run_simulation` with ``plant`` and ``coulomb_band``) is
the digital control loop of :func:`dynid.simulation.closed_loop.simulate_mechanism_control` with
the projection's shortcut (``exact_projection = False``): per control period of the hexapod twin,
some 100 us of pinocchio (the controller's kinematics and inverse dynamics, eight constrained
forward dynamics) and about 180 us of NumPy on one sample's small arrays, a few hundred calls of
0.5-3 us each. Here the pinocchio calls stay (``computeJointJacobians``,
``computeJointJacobiansTimeVariation``, ``rnea``, ``constraintDynamics``: all rigid-body dynamics)
and everything between them runs in ``numba.njit`` kernels on buffers allocated once per replay:

* :func:`_geometry`: the controller's velocity map at one configuration, the formulas of
  :func:`dynid.model.loop_one._one_geometry` and :func:`~dynid.model.loop_one._one_coordinates`
  (the rows :math:`J_v - [p]_\\times J_\\omega` of the closure sides, stacked by the constant
  matrix ``T`` of ``_Sides``, whose rows have at most two entries of +-1, taken here as index
  and sign; the LU inverse of the dependent joints' block and its 1-norm condition number; ``G``;
  the independent joints' positions and rates), then the commanded acceleration
  :math:`a_u = \\ddot u_d + K_v(\\dot u_d - \\dot u) + K_p(u_d - u)` (the augmented PD of
  Shang et al. 2009, Eq. 22) and :math:`\\dot q = G\\dot u`;
* :func:`_accelerations`: the drift :math:`\\dot J\\dot q` of the sides' points and the joint
  accelerations (:func:`~dynid.model.loop_one._one_rates`);
* :func:`_forces`: the joint terms, :math:`G^T(\\text{RNEA} + \\text{terms})` and the solve by
  :math:`G_a^T` (:class:`dynid.model.closed_loop.OneSampleForces`), then the period's logging
  and the first RK4 stage's generalized forces (the plant's regularized Coulomb law, Olsson et
  al. 1998, Section 2, :mod:`dynid.simulation._joint_laws`);
* :func:`_rk4_stage`: one stage of classical RK4 (:func:`dynid.simulation._integrate.rk4_step`,
  the same combination) and the next stage's state and forces;
* :func:`_closure_check`: the point closures' residual and :math:`\\|J_c\\dot q\\|_\\infty`
  (:func:`dynid.model.closure_geometry.point_closure_rows`) for the projection's shortcut; a state
  past the tolerances takes :meth:`Mechanism.project` as before.

The same formulas in the same order of operations where that is cheap, not bit for bit (sums of
products run in loops instead of BLAS): the replay equals the Python loop's to rounding, far below
the integrator's own error (tests/test_closed_loop_replay.py). numba is imported by this module
only, and this module only by the closed-chain replay (``import dynid`` and serial arms never
load it; tests/test_closed_loop_replay.py checks it).
"""

from __future__ import annotations

import numba
import numpy as np
import pinocchio as pin

from dynid.errors import InputError, ModelError
from dynid.model.closure_geometry import _closures, _PointRows, _sides
from dynid.simulation.closed_loop import (
    _PROJECTION_TOL, AugmentedPD, ConstrainedSimulator, SimulatedMotion, _threads)

__all__ = ["compiled_replay", "supports"]

_MAX_COND = 1e8  # AugmentedPD's bound on the condition number of the inverted block (loop_one._one_geometry)


# ----------------------------------------------------------------------------- kernels

def _sparse_rows(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index and value of the (at most two) non-zero entries of each row of ``T`` (value 0: none);
    the constant matrices of :mod:`dynid.model.closure_geometry` have entries 0 and +-1 and at most
    two non-zero per row, so the kernels' sums over them are those products exactly."""
    idx = np.zeros((T.shape[0], 2), dtype=np.int64)
    val = np.zeros((T.shape[0], 2))
    for r, row in enumerate(T):
        nz = np.flatnonzero(row)
        if nz.size > 2:
            raise ValueError("a constant row with more than two non-zero entries")
        idx[r, : nz.size], val[r, : nz.size] = nz, row[nz]
    return idx, val


@numba.njit(cache=True)
def _lu(A, piv):
    """In-place LU factorization with partial pivoting (LAPACK ``dgetf2``'s algorithm, unblocked):
    ``A`` holds L (unit diagonal) and U, ``piv`` the row swaps; False where a pivot is zero or
    not finite."""
    n = A.shape[0]
    for c in range(n):
        p, big = c, abs(A[c, c])
        for i in range(c + 1, n):
            if abs(A[i, c]) > big:
                p, big = i, abs(A[i, c])
        if not (big > 0.0 and big < np.inf):
            return False
        piv[c] = p
        if p != c:
            for j in range(n):
                A[c, j], A[p, j] = A[p, j], A[c, j]
        d = 1.0 / A[c, c]
        for i in range(c + 1, n):
            A[i, c] *= d
            f = A[i, c]
            if f != 0.0:
                for j in range(c + 1, n):
                    A[i, j] -= f * A[c, j]
    return True


@numba.njit(cache=True)
def _lu_solve(LU, piv, b):
    """``x`` with ``A x = b`` from :func:`_lu`'s factors (in place in ``b``)."""
    n = b.size
    for c in range(n):
        p = piv[c]
        if p != c:
            b[c], b[p] = b[p], b[c]
    for i in range(n):
        x = b[i]
        for j in range(i):
            x -= LU[i, j] * b[j]
        b[i] = x
    for i in range(n - 1, -1, -1):
        x = b[i]
        for j in range(i + 1, n):
            x -= LU[i, j] * b[j]
        b[i] = x / LU[i, i]


@numba.njit(cache=True)
def _lu_inverse(LU, piv, inv):
    """The inverse from :func:`_lu`'s factors, column by column (forward substitution from the
    unit vector's first non-zero entry: the entries above it are exact zeros)."""
    n = piv.size
    e = np.empty(n)
    for j in range(n):
        for i in range(n):
            e[i] = 0.0
        e[j] = 1.0
        first = n
        for c in range(n):
            p = piv[c]
            if p != c:
                e[c], e[p] = e[p], e[c]
        for i in range(n):
            if e[i] != 0.0:
                first = i
                break
        for i in range(first + 1, n):
            x = e[i]
            for m in range(first, i):
                x -= LU[i, m] * e[m]
            e[i] = x
        for i in range(n - 1, -1, -1):
            x = e[i]
            for m in range(i + 1, n):
                x -= LU[i, m] * e[m]
            e[i] = x / LU[i, i]
        for i in range(n):
            inv[i, j] = e[i]


@numba.njit(cache=True)
def _norm1(A):
    """The 1-norm (largest column sum of absolute values)."""
    m = 0.0
    for j in range(A.shape[1]):
        x = 0.0
        for i in range(A.shape[0]):
            x += abs(A[i, j])
        m = max(m, x)
    return m


@numba.njit(cache=True)
def _points(H, slot, ground, r, pk):
    """``pk[s] = R r + t`` of each side's body placement ``H[slot[s]]`` (``r`` itself on the ground)."""
    for s in range(slot.size):
        if ground[s]:
            for i in range(3):
                pk[s, i] = r[s, i]
        else:
            Hs = H[slot[s]]
            for i in range(3):
                pk[s, i] = Hs[i, 0] * r[s, 0] + Hs[i, 1] * r[s, 1] + Hs[i, 2] * r[s, 2] + Hs[i, 3]


@numba.njit(cache=True)
def _geometry(J, H, q, dq, k, ur, dur, ddur, kp, kv, slot, ground, r, order, mask, t_idx, t_val,
              w, u, pk, rows, G, du, acc, dq_u):
    """The controller's geometry and commanded motion at period ``k``, in joint coordinates (``u``,
    ``w``: the independent and dependent joints; :func:`supports`): fills ``pk``, ``rows``,
    ``G``, ``du``, ``acc`` (the commanded :math:`a_u`), ``dq_u`` (:math:`G\\dot u`); returns the
    inverse of the dependent joints' block, its condition number (inf: singular) and a status: 0,
    or 1 where the state is not finite (nothing computed), 2 singular, 3 where the commanded
    acceleration is not finite."""
    nv = q.size
    nw = w.size
    inv = np.zeros((nw, nw))
    for i in range(nv):
        if not (np.isfinite(q[i]) and np.isfinite(dq[i])):
            return inv, np.inf, 1
    _points(H, slot, ground, r, pk)
    nr = rows.shape[0]
    for i in range(nr):  # rows = T @ [J_v - [p]x J_w; J_w] per moving side, T's +-1 entries only
        for j in range(nv):
            rows[i, j] = 0.0
        for e in range(2):
            v = t_val[i, e]
            if v == 0.0:
                continue
            c = t_idx[i, e]
            s, comp = c // 6, c % 6
            p0, p1, p2 = pk[s, 0], pk[s, 1], pk[s, 2]
            for j in range(nv):
                jj = order[j]
                m = mask[s, j]
                if comp < 3:  # (J_v - p x J_w)[comp]
                    if comp == 0:
                        x = m * J[0, jj] - (p1 * (m * J[5, jj]) - p2 * (m * J[4, jj]))
                    elif comp == 1:
                        x = m * J[1, jj] - (p2 * (m * J[3, jj]) - p0 * (m * J[5, jj]))
                    else:
                        x = m * J[2, jj] - (p0 * (m * J[4, jj]) - p1 * (m * J[3, jj]))
                else:
                    x = m * J[comp, jj]
                rows[i, j] += v * x
    LU = np.empty((nw, nw))
    for i in range(nw):
        for j in range(nw):
            LU[i, j] = rows[i, j]
    piv = np.empty(nw, dtype=np.int64)
    if not _lu(LU, piv):
        return inv, np.inf, 2
    _lu_inverse(LU, piv, inv)  # LAPACK's getri: the same matrix to rounding
    cond = _norm1(rows[:, :nw]) * _norm1(inv)
    if not cond <= 1e300:  # not finite
        return inv, np.inf, 2
    nu = G.shape[1]
    for i in range(nv):
        for j in range(nu):
            G[i, j] = 0.0
    for j in range(nu):
        G[u[j], j] = 1.0
    for i in range(nw):
        for j in range(nu):
            x = 0.0
            for m in range(nw):
                x += inv[i, m] * rows[m, nw + j]
            G[w[i], j] = -x
    for j in range(nu):
        du[j] = dq[u[j]]
        acc[j] = ddur[k, j] + kv[j] * (dur[k, j] - du[j]) + kp[j] * (ur[k, j] - q[u[j]])
    for i in range(nv):
        x = 0.0
        for j in range(nu):
            x += G[i, j] * du[j]
        dq_u[i] = x
    for j in range(nu):
        if not np.isfinite(acc[j]):
            return inv, cond, 3
    return inv, cond, 0


@numba.njit(cache=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True)
def _accelerations(J, dJ, dq_u, body_mask_q, body_of, pk, t_idx, t_val, rows, inv, acc, w, u, ddq):
    """Joint accelerations at the commanded :math:`a_u`: the drift :math:`\\dot J\\dot q` of the
    sides' points (classical accelerations: :math:`v_p = v + \\omega\\times p`,
    :math:`a_p = a + \\alpha\\times p + \\omega\\times v_p`, at :math:`\\ddot q = 0`), then
    :math:`\\ddot q_u = a_u`, :math:`\\ddot q_w = A_w^{-1}(-A_u a_u - \\dot J\\dot q)`."""
    nv = dq_u.size
    nb = body_mask_q.shape[0]
    X = np.zeros((nb, 12))
    for b in range(nb):
        for i in range(6):
            x = 0.0
            y = 0.0
            for j in range(nv):
                z = dq_u[j] * body_mask_q[b, j]
                x += J[i, j] * z
                y += dJ[i, j] * z
            X[b, i] = x
            X[b, 6 + i] = y
    ns = body_of.size
    S6 = np.zeros((ns, 6))  # [lin, alpha] of each moving side
    for s in range(ns):
        Xb = X[body_of[s]]
        p0, p1, p2 = pk[s, 0], pk[s, 1], pk[s, 2]
        c0, c1, c2 = _cross(p0, p1, p2, Xb[3], Xb[4], Xb[5])  # p x omega
        vp0, vp1, vp2 = Xb[0] - c0, Xb[1] - c1, Xb[2] - c2
        d0, d1, d2 = _cross(p0, p1, p2, Xb[9], Xb[10], Xb[11])  # p x alpha
        e0, e1, e2 = _cross(Xb[3], Xb[4], Xb[5], vp0, vp1, vp2)  # omega x v_p
        S6[s, 0] = Xb[6] - d0 + e0
        S6[s, 1] = Xb[7] - d1 + e1
        S6[s, 2] = Xb[8] - d2 + e2
        S6[s, 3] = Xb[9]
        S6[s, 4] = Xb[10]
        S6[s, 5] = Xb[11]
    nr = rows.shape[0]
    drift = np.zeros(nr)
    for i in range(nr):
        x = 0.0
        for e in range(2):
            v = t_val[i, e]
            if v != 0.0:
                c = t_idx[i, e]
                x += v * S6[c // 6, c % 6]
        drift[i] = x
    nu, nw = acc.size, w.size
    for j in range(nu):
        ddq[u[j]] = acc[j]
    rhs = np.empty(nw)
    for i in range(nw):
        x = 0.0
        for j in range(nu):
            x += rows[i, nw + j] * acc[j]
        rhs[i] = -x - drift[i]
    for i in range(nw):
        x = 0.0
        for m in range(nw):
            x += inv[i, m] * rhs[m]
        ddq[w[i]] = x


@numba.njit(cache=True)
def _terms(coef, v, i):
    """The piecewise-linear joint law :math:`s(v) v + l(v) + e` of joint ``i`` (coef rows a, b, c, d, e)."""
    if v > 0:
        return coef[0, i] * v + coef[2, i] + coef[4, i]
    if v < 0:
        return coef[1, i] * v + coef[3, i] + coef[4, i]
    return coef[1, i] * v + coef[4, i]


@numba.njit(cache=True)
def _law(coef, band, v, tau_joint, out):
    """The plant's generalized forces: ``tau_joint`` minus the joint terms; with ``band > 0`` the
    regularized Coulomb law :math:`\\tfrac12(c-d)\\tanh(v/v_b) + \\tfrac12(c+d)|\\tanh(v/v_b)|`
    in place of the levels (:func:`dynid.simulation._joint_laws.piecewise_law`)."""
    for i in range(v.size):
        x = v[i]
        if band > 0:
            th = np.tanh(x / band)
            s = coef[0, i] if x > 0 else coef[1, i]
            f = s * x + 0.5 * (coef[2, i] - coef[3, i]) * th + 0.5 * (coef[2, i] + coef[3, i]) * abs(th) + coef[4, i]
        else:
            f = _terms(coef, x, i)
        out[i] = tau_joint[i] - f


@numba.njit(cache=True)
def _forces(tau_rnea, dq_u, ddq, G, ctrl_coef, inertia, own, local, solve, act, k, W, plant_coef, band, Q, V, T):
    """The actuator forces of the controller (:class:`~dynid.model.closed_loop.OneSampleForces`:
    :math:`G^T(\\text{RNEA} + f)`, solved by :math:`G_a^T` unless ``solve`` is 0), logged in row
    ``k`` of ``Q``, ``V``, ``T`` with the state ``W[0]``, ``W[1]``; then the hold's joint forces
    ``W[5]`` and the first stage's state and forces ``W[2:5]``. Returns False where the forces are
    not finite or :math:`G_a^T` is singular."""
    nv, nu = dq_u.size, G.shape[1]
    tau = np.empty(nv)
    for i in range(nv):
        f = _terms(ctrl_coef, dq_u[i], i) + inertia[i] * ddq[i]
        tau[i] = tau_rnea[i] + f
        if local:
            tau[i] -= f * own[i]
    proj = np.empty(nu)
    for j in range(nu):
        x = 0.0
        for i in range(nv):
            x += G[i, j] * tau[i]
        proj[j] = x
    na = act.size
    out = proj
    if solve:  # G_a^T x = proj by LU with partial pivoting (LAPACK's gesv, unblocked)
        Ga_T = np.empty((na, na))
        for i in range(na):
            for j in range(na):
                Ga_T[i, j] = G[act[j], i]
        piv = np.empty(na, dtype=np.int64)
        if not _lu(Ga_T, piv):
            return False
        _lu_solve(Ga_T, piv, out)
    for i in range(nv):
        Q[k, i] = W[0, i]
        V[k, i] = W[1, i]
        W[5, i] = 0.0
    ok = True
    for i in range(out.size):
        T[k, i] = out[i]
        ok = ok and np.isfinite(out[i])
    for i in range(na):
        W[5, act[i]] += out[i]
    for i in range(nv):
        W[2, i] = W[0, i]
        W[3, i] = W[1, i]
    _law(plant_coef, band, W[1], W[5], W[4])
    return ok


@numba.njit(cache=True)
def _rk4_stage(i, acc, W, h, plant_coef, band, last):
    """Stage ``i % 4`` of an RK4 step (:func:`dynid.simulation._integrate.rk4_step`): keep its
    acceleration in ``W[6 + i % 4]`` and put the next stage's positions, velocities and forces in
    ``W[2:5]``; after the fourth, the step's positions and velocities in ``W[0:2]`` (and, unless
    ``last``, the next step's first stage). Rows of ``W``: q, v, stage q, stage v, stage forces,
    held joint forces, k1..k4."""
    j = i % 4
    nv = acc.size
    for m in range(nv):
        W[6 + j, m] = acc[m]
    h2 = h / 2
    q, v = W[0], W[1]
    if j == 0:
        for m in range(nv):
            W[3, m] = v[m] + h2 * W[6, m]
            W[2, m] = q[m] + h2 * v[m]
    elif j == 1:
        for m in range(nv):
            W[3, m] = v[m] + h2 * W[7, m]
            W[2, m] = q[m] + h2 * (v[m] + h2 * W[6, m])
    elif j == 2:
        for m in range(nv):
            W[3, m] = v[m] + h * W[8, m]
            W[2, m] = q[m] + h * (v[m] + h2 * W[7, m])
    else:
        c = h**2 / 6
        d = h / 6
        for m in range(nv):
            k1, k2, k3, k4 = W[6, m], W[7, m], W[8, m], W[9, m]
            q[m] = q[m] + h * v[m] + c * (k1 + k2 + k3)
            v[m] = v[m] + d * (k1 + 2 * k2 + 2 * k3 + k4)
        if last:
            return
        for m in range(nv):
            W[2, m] = q[m]
            W[3, m] = v[m]
    _law(plant_coef, band, W[3], W[5], W[4])


@numba.njit(cache=True)
def _closure_check(J, H, q, dq, slot, r1, mask, d_idx, d_val, d0, t_idx, t_val):
    """The point closures' residual (infinity norm) and :math:`\\|J_c\\dot q\\|_\\infty` at
    ``(q, dq)`` (:func:`dynid.model.closure_geometry.point_closure_rows`: the same rows, ``D`` and
    ``T`` by their +-1 entries); NaN where the state is not finite."""
    nv = q.size
    ns = slot.size
    P = np.empty((ns, 3))
    for s in range(ns):
        Hs = H[slot[s]]
        for i in range(3):
            P[s, i] = Hs[i, 0] * r1[s, 0] + Hs[i, 1] * r1[s, 1] + Hs[i, 2] * r1[s, 2] + Hs[i, 3] * r1[s, 3]
    nr = d0.size
    gap = 0.0
    vres = 0.0
    for i in range(nr):
        c = d0[i]
        for e in range(2):
            if d_val[i, e] != 0.0:
                x = d_idx[i, e]
                c += d_val[i, e] * P[x // 3, x % 3]
        if not np.isfinite(c):
            return np.nan, np.nan
        gap = max(gap, abs(c))
        y = 0.0
        for e in range(2):
            v = t_val[i, e]
            if v == 0.0:
                continue
            x = t_idx[i, e]
            s, comp = x // 3, x % 3
            p0, p1, p2 = P[s, 0], P[s, 1], P[s, 2]
            lin = 0.0
            for j in range(nv):
                m = mask[s, j] * dq[j]
                if comp == 0:
                    lin += (J[0, j] - (p1 * J[5, j] - p2 * J[4, j])) * m
                elif comp == 1:
                    lin += (J[1, j] - (p2 * J[3, j] - p0 * J[5, j])) * m
                else:
                    lin += (J[2, j] - (p0 * J[4, j] - p1 * J[3, j])) * m
            y += v * lin
        if not np.isfinite(y):
            return np.nan, np.nan
        vres = max(vres, abs(y))
    return gap, vres


# ----------------------------------------------------------------------------- the replay loop

def supports(sim, controller) -> bool:
    """Whether :func:`compiled_replay` runs this plant and controller: the constrained simulator
    with its piecewise-linear joint law (no ground-truth friction callable) and the augmented PD
    whose forces take the per-joint route without a redundant distribution, in joint coordinates
    (the replays of IV and DIDIM on the hexapod, the 3-RPS, the five-bar); anything else (point
    coordinates, redundant actuation: shang2dof) keeps
    :func:`~dynid.simulation.closed_loop.simulate_mechanism_control`."""
    if not (isinstance(sim, ConstrainedSimulator) and type(controller) is AugmentedPD and sim.friction is None):
        return False
    f = controller._forces
    sd = _sides(sim.mech)
    return not f.general and not f.redundant and sd.u is not None


class _Kinematics:
    """The placements of the bodies that carry closure sides, read from one pinocchio ``Data``
    after ``computeJointJacobians`` (shared by the controller and the closure check).

    Read through the strided view of ``data.oMi`` (:func:`dynid.model.loop_batch.placement_view`:
    one fancy-indexed copy instead of a Python call and a new 4x4 array per joint; the same numbers)
    into one buffer, rewritten at every call: a period's kernels use the placements before the next
    call. Where pinocchio's layout is not the one the view expects, the per-joint reads."""

    def __init__(self, mech) -> None:
        from dynid.model.loop_batch import placement_view

        self.model, self.data = mech.pin_model, mech.pin_model.createData()
        self.joints = sorted(set(_sides(mech).joints) | set(_closures(mech).joints)) or [0]
        self._view = placement_view(mech, self.data)
        m = len(self.joints)
        self._sel = np.array(self.joints, dtype=np.int64)
        self._H = np.zeros((m, 4, 4))
        self._H[:, 3, 3] = 1.0

    def __call__(self, q):
        J = pin.computeJointJacobians(self.model, self.data, q)
        if self._view is None:
            oMi = self.data.oMi
            return J, np.array([oMi[j].homogeneous for j in self.joints])
        v = self._view[self._sel]  # (m, 12): rotation column-major (R^T row-major), translation
        H = self._H
        H[:, :3, :3] = v[:, :9].reshape(-1, 3, 3).transpose(0, 2, 1)
        H[:, :3, 3] = v[:, 9:]
        return J, H


def compiled_replay(sim, controller, reference, *, duration: float, dt: float, substeps: int,
                    q0=None) -> SimulatedMotion:
    """:func:`~dynid.simulation.closed_loop.simulate_mechanism_control` with
    ``exact_projection = False`` (its motion to rounding; module docstring), for a plant and
    controller that :func:`supports` accepts."""
    with _threads().limit(limits=1, user_api="blas"):
        return _replay(sim, controller, reference, duration, dt, substeps, q0)


def _replay(sim, controller, reference, duration, dt, substeps, q0) -> SimulatedMotion:
    mech = sim.mech
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    refs = tuple(reference(t))
    ur, dur, ddur = (np.ascontiguousarray(x, dtype=float) for x in refs[:3])
    if ur.shape != (n, mech.dof):
        raise InputError(f"the reference has {ur.shape[1]} coordinates, the mechanism {mech.dof} degrees of freedom")
    q = mech.solve_positions(ur[:1])[0] if q0 is None else np.array(q0, dtype=float)
    v = mech.states(q[None], dur[:1], ddur[:1]).dq[0]
    nv, na = mech.nv, mech.n_actuators
    Q, V, A, T = np.empty((n, nv)), np.empty((n, nv)), np.empty((n, nv)), np.empty((n, na))
    h = dt / substeps
    vtol = _PROJECTION_TOL / dt

    # the controller's constants (loop_one._one_geometry, OneSampleForces)
    sd, f = _sides(mech), controller._forces
    kin = _Kinematics(mech)
    slot_of = {j: i for i, j in enumerate(kin.joints)}
    slot = np.array([slot_of[sd.joints[s]] if not g else 0 for s, g in zip(sd.slot_k, sd.ground_k)], dtype=np.int64)
    ground = np.asarray(sd.ground_k, dtype=np.bool_)
    r = np.ascontiguousarray(sd.r_k, dtype=float)
    order = np.ascontiguousarray(sd.order, dtype=np.int64)
    mask = np.ascontiguousarray(sd.side_mask.reshape(len(sd.moving), nv))
    t_idx, t_val = _sparse_rows(np.ascontiguousarray(sd.T))
    u_idx, w_idx = np.asarray(sd.u, dtype=np.int64), np.asarray(sd.w, dtype=np.int64)
    nu = mech.dof
    kp, kv = (np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=float), (nu,))) for x in (controller.kp, controller.kv))
    body_mask_q = np.ascontiguousarray(sd.body_mask_q)
    body_of = np.ascontiguousarray(sd.body_of, dtype=np.int64)
    ctrl_coef = np.array([f.a, f.b, f.c, f.d, f.e], dtype=float)
    inertia = np.zeros(nv) if f.inertia is None else np.asarray(f.inertia, dtype=float)
    own = np.asarray(f.own, dtype=float)
    solve = not (f.distribution == "projected" or f.identity)
    act = np.asarray(mech.actuated, dtype=np.int64)
    # the plant's law and the closure check's constants (closure_geometry.point_closure_rows)
    plant_coef = np.array(sim._friction_coefficients, dtype=float)
    band = float(sim.coulomb_band) if sim.coulomb_band is not None else 0.0
    point = _closures(mech).all_3d
    if point:
        pr = mech.__dict__.get("_point_rows_cache")
        if pr is None:
            pr = _PointRows(mech)
            object.__setattr__(mech, "_point_rows_cache", pr)
        cl = _closures(mech)
        p_slot = np.array([slot_of[cl.joints[s]] for s in pr.slot], dtype=np.int64)
        p_r1 = np.ascontiguousarray(pr.r1.reshape(-1, 4))
        p_mask = np.ascontiguousarray(pr.mask.reshape(-1, nv))
        d_idx, d_val = _sparse_rows(np.ascontiguousarray(pr.D))
        d0 = np.ascontiguousarray(pr.d0, dtype=float)
        pt_idx, pt_val = _sparse_rows(np.ascontiguousarray(pr.T))

    # buffers of one period
    pk = np.empty((len(sd.moving), 3))
    rows = np.empty((sd.T.shape[0], nv))
    G = np.empty((nv, nu))
    du, acc, dq_u, ddq = np.empty(nu), np.empty(nu), np.empty(nv), np.empty(nv)
    W = np.zeros((10, nv))
    W[0], W[1] = q, v
    model, cdata = controller._model, controller._data
    dynamics, pmodel, pdata, cmodels, cdatas, prox = (pin.constraintDynamics, sim.model, sim.data, sim.cmodels,
                                                     sim.cdatas, sim.prox)
    rnea, time_variation = pin.rnea, pin.computeJointJacobiansTimeVariation
    qs, vs, fs = W[2], W[3], W[4]
    n_stages = 4 * substeps
    check_charts = bool(mech._ball_middle)
    J, H = kin(W[0])
    q, v = W[0], W[1]  # views: the state, updated in place by the kernels (and by a projection below)
    for k in range(n):
        if check_charts:
            mech.check_ball_charts(q, "states")
        inv, cond, status = _geometry(J, H, q, v, k, ur, dur, ddur, kp, kv, slot, ground, r, order, mask, t_idx,
                                      t_val, w_idx, u_idx, pk, rows, G, du, acc, dq_u)
        if status == 1:
            raise InputError(f"the controller needs finite joint positions and velocities of shape ({nv},)")
        if not cond <= _MAX_COND:
            raise ModelError("sample 0: singular configuration (condition number of the loop-closure Jacobian of the "
                             f"dependent joints = {cond:.3g} > {_MAX_COND:.3g})")
        if status == 3:
            raise InputError("the commanded acceleration of the independent coordinates is not finite")
        time_variation(kin.model, kin.data, q, dq_u)
        _accelerations(J, kin.data.dJ, dq_u, body_mask_q, body_of, pk, t_idx, t_val, rows, inv, acc, w_idx, u_idx,
                       ddq)
        tau_rnea = rnea(model, cdata, q, dq_u, ddq)
        if not _forces(tau_rnea, dq_u, ddq, G, ctrl_coef, inertia, own, f.local, solve, act, k, W, plant_coef,
                       band, Q, V, T):
            if not np.isfinite(T[k]).all():
                raise ModelError("the controller's actuator forces are not finite")
            raise np.linalg.LinAlgError("Singular matrix")
        A[k] = dynamics(pmodel, pdata, qs, vs, fs, cmodels, cdatas, prox)
        if k == n - 1:
            break
        _rk4_stage(0, A[k], W, h, plant_coef, band, False)
        for i in range(1, n_stages):
            _rk4_stage(i, dynamics(pmodel, pdata, qs, vs, fs, cmodels, cdatas, prox), W, h, plant_coef, band,
                       i == n_stages - 1)
        # the projection's shortcut (simulate_mechanism_control, exact_projection=False)
        J, H = kin(q)
        if point:
            gap, vres = _closure_check(J, H, q, v, p_slot, p_r1, p_mask, d_idx, d_val, d0, pt_idx, pt_val)
            if gap < _PROJECTION_TOL and vres <= vtol:
                continue
        q[:], v[:] = mech.project(q, v, data=kin.data, vtol=vtol)
        J, H = kin(q)
    return SimulatedMotion(t=t, q=Q, dq=V, ddq=A, tau_a=T)
