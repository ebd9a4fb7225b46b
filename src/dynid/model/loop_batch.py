"""The position solve of :func:`dynid.model.loop_kinematics.actuator_states` on many samples at once.

A log of a parallel robot gives the actuated joints only; every sample's other joints come from
Gauss–Newton on :math:`F(q) = [c(q); S_a q - q_a] = 0` (independent constraint rows). Sample by
sample, warm-started from the previous sample, that is a Python loop of some ten calls per
iteration (about 200 us per hexapod sample; ``loop_kinematics._positions_loop``, kept as the
reference and for ``6d`` closures). Here, for point closures (``"3d"``):

* :func:`solve_from_starts`: Gauss–Newton from a starting point per sample, each iteration on
  all the samples still iterating at once: pinocchio per sample (``computeJointJacobians``, the
  joints' placements read through one strided view of ``data.oMi``, :class:`_Layout`), the
  residuals, Jacobians (their non-zero entries only) and steps batched. Per sample the stopping
  rule of the loop: stop when the step's infinity norm is below ``tol`` (that step not taken;
  with ``accept_starts`` a start whose residual is already below ``tol`` is taken as it is);
  after ``max_iter`` steps a :class:`~dynid.errors.ModelError` naming the sample and the
  condition number. Steps by block elimination of the square stacked system (the actuated joints
  move by :math:`e_a` exactly, the others by LU on :math:`J_{c,w}`), the least squares of the
  normal equations when actuation is redundant.
* :func:`continuation`: the warm-started solve along the log, in windows of ``_WINDOW``
  segments. Anchors every ``K``-th sample (``K`` = ``STRIDE``) are solved one after the other
  (:func:`solve_one`), each from the linear extrapolation of the two previous solutions; the
  samples between anchors all at once from the cubic through the four anchors around them
  (the line in a window's first and last segment), by chord steps with the Jacobian of the
  nearest anchor (no Jacobian per sample: one forward-kinematics pass and a product per step;
  the samples not converged after ``_CHORD + 1`` steps by Newton, :func:`solve_from_starts`).

**Same solution as sample by sample, to the solver's tolerance.** Gauss–Newton converges to the
root whose basin holds its start; the loop's root at each sample is the continuation of the
first sample's branch. The cubic start differs from that root by :math:`O(K^4h^4|q^{(4)}|)` (the
line by at most :math:`K^2h^2\\max|\\ddot q|/8`, the extrapolated anchor start by
:math:`K^2h^2\\max|\\ddot q|`; sample period :math:`h`), the loop's own start by
:math:`h\\max|\\dot q|`: for a log sampled finely enough all are far inside the basin (radius of
the order of :math:`1/(L\\,\\|A^{-1}\\|)`, :math:`L` the Lipschitz constant of the Jacobian), so
the same root. Checks make that an assertion rather than an assumption: an anchor may not lie
farther from its extrapolated start than the previous chord scaled to the gap (plus ``100 tol``);
a sample between anchors not farther from the line between them than the chord plus the
anchors' second difference (the line's error scale) plus ``100 tol`` (another branch is a jump
of the order of a link length). A segment that fails, whose anchor does not converge, or whose
batch raises is solved again sample by sample from the previous accepted sample (``sequential``,
the loop itself: an unreachable sample raises its own error, with its number); ``K`` is halved
for the next window and grows back by doubling after a clean one. Accuracy: the loop stops
after a Newton step below ``tol`` (error below ``tol`` to second order), the chord steps converge
linearly at the rate :math:`\\rho = \\|\\tilde A^{-1}(\\tilde A - A)\\|` (about
:math:`K h|\\dot q|\\,L\\|A^{-1}\\|/2` for the nearest anchor's :math:`\\tilde A`; 1e-3 on the
benchmark's motion) and stop with an error at most :math:`\\mathrm{tol}/(1-\\rho)`: the two
routes agree within :math:`3\\,\\mathrm{tol}` (tests/test_actuator_positions_batched.py).

Speed (bench/closed_loop_throughput.py, hexapod, 4000 samples at 1 kHz, one core): about 20 us
per sample against 390 us for the loop under load 6 (20 x, paired rounds): per sample between anchors about
two forward-kinematics passes and products; per anchor (one in 64) one Jacobian pass and LU.

The module reads only the mechanism's closures and pinocchio model (no import of
:mod:`~dynid.model.loop_kinematics`, which calls it).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack as sla_lapack

from dynid._typing import FloatArray
from dynid.errors import ModelError

# a dynid.model.mechanism.Mechanism, named, not imported (no import cycle through loop_kinematics)
Mechanism = Any

__all__ = ["continuation", "parent_placement_view", "placement_view", "solve_from_starts"]

STRIDE = 64  # samples between anchors (at most; halved after a failed segment)
_WINDOW = 32  # anchors per window
_BLOCK = 256  # samples per batched solve (the per-side Jacobians stay in cache)


class _Layout:
    """A read-only strided view of the joints' placements in ``data.oMi``: one copy per sample
    instead of one Python call per joint. pinocchio stores ``oMi`` as a contiguous vector of
    SE3 (rotation column-major, then translation: 12 doubles, padded to a constant stride); the
    view is built from the addresses eigenpy reports and checked against ``oMi[j].homogeneous``
    at two configurations; where the check fails (another layout), None and the per-joint reads.
    The layout is a property of the pinocchio build: once checked on one ``data`` of a mechanism
    (1.2 ms for the hexapod: two forward-kinematics passes and every joint read), the stride is kept
    on the mechanism and a new ``data`` (every call of ``states()`` without one) checks only that
    its first, second and last placements lie at that stride (some 10 us)."""

    @staticmethod
    def view(mech: Mechanism, data: pin.Data, attr: str = "oMi") -> FloatArray | None:
        oMi = getattr(data, attr)  # or liMi: the same vector of SE3
        nj = len(oMi)
        joints = list(range(nj))
        if nj < 2:
            return None
        known = mech.__dict__.get(f"_{attr}_stride")
        if known is not None:
            try:
                r0, t0 = oMi[0].rotation, oMi[0].translation
                a0 = r0.__array_interface__["data"][0]
                if (oMi[1].rotation.__array_interface__["data"][0] - a0 == known
                        and oMi[nj - 1].rotation.__array_interface__["data"][0] - a0 == (nj - 1) * known
                        and r0.strides == (8, 24) and t0.__array_interface__["data"][0] - a0 == 72):
                    return np.lib.stride_tricks.as_strided(r0, shape=(nj, 12), strides=(known, 8), writeable=False)
            except (AttributeError, ValueError, TypeError, IndexError, RuntimeError):  # pragma: no cover - another binding
                pass
        try:
            rot = [oMi[j].rotation for j in range(nj)]
            tr = [oMi[j].translation for j in range(nj)]
            addr = [r.__array_interface__["data"][0] for r in rot]
            stride = addr[1] - addr[0]
            ok = (
                all(b - a == stride for a, b in zip(addr, addr[1:]))
                and all(r.strides == (8, 24) for r in rot)
                and all(t.__array_interface__["data"][0] - a == 72 for t, a in zip(tr, addr))
                and stride >= 96 and stride % 8 == 0
            )
            if not ok:
                return None
            flat = np.lib.stride_tricks.as_strided(rot[0], shape=(nj, 12), strides=(stride, 8), writeable=False)
            rng = np.random.default_rng(0)
            for q in (mech.q_ref, mech.q_ref + 0.1 * rng.standard_normal(mech.nv)):
                pin.forwardKinematics(mech.pin_model, data, np.asarray(q, dtype=float))
                got = flat[joints]
                want = np.array([oMi[j].homogeneous for j in joints])
                if not (np.array_equal(got[:, :9].reshape(-1, 3, 3).transpose(0, 2, 1), want[:, :3, :3])
                        and np.array_equal(got[:, 9:], want[:, :3, 3])):
                    return None
            object.__setattr__(mech, f"_{attr}_stride", stride)
            return flat
        except (AttributeError, ValueError, TypeError, IndexError, RuntimeError):  # pragma: no cover - another binding
            return None


class _Points:
    """Constants of the batched solve for point closures: the joints whose placements are read,
    each side's slot among them (ground sides: their fixed point), the moving sides' points and
    support masks, and per closure row the two sides it subtracts."""

    def __init__(self, mech: Mechanism) -> None:
        m = mech.pin_model
        sides = []
        for c in mech.closures:
            sides += [(c.joint_a, c.placement_a), (c.joint_b, c.placement_b)]
        self.joints = sorted({j for j, _ in sides if j != 0})
        slot = {j: k for k, j in enumerate(self.joints)}
        self.moving = np.array([s for s, (j, _) in enumerate(sides) if j != 0], dtype=int)
        self.slot = np.array([slot[sides[s][0]] for s in self.moving], dtype=int)
        self.r = np.array([sides[s][1].translation for s in self.moving], dtype=float).reshape(-1, 3)
        self.fixed = np.array([pl.translation if j == 0 else np.zeros(3) for j, pl in sides], dtype=float)
        k = self.moving.size
        self.mask = np.zeros((k, m.nv))
        for i, s in enumerate(self.moving):
            for a in m.supports[sides[s][0]].tolist()[1:]:
                jm = m.joints[a]
                self.mask[i, jm.idx_v : jm.idx_v + jm.nv] = 1.0
        # closure rows: side b minus side a, as indices into the (moving sides + one zero) arrays
        index = {int(s): i for i, s in enumerate(self.moving)}
        ncl = len(sides) // 2
        ib = np.array([index.get(2 * c + 1, k) for c in range(ncl)])
        ia = np.array([index.get(2 * c, k) for c in range(ncl)])
        rows = mech.constraint_rows
        self.row_b, self.row_a = np.repeat(ib, 3)[rows], np.repeat(ia, 3)[rows]
        self.row_xyz = np.tile(np.arange(3), ncl)[rows]
        self.const = (self.fixed[1::2] - self.fixed[0::2]).reshape(-1)[rows]  # ground sides' points
        # the Jacobian's non-zero entries: closure row r (component x of side b minus side a) on the
        # support columns of each side's body, value J_v[x] - (p x J_w)[x] = J_v[x] - (p[y] J_w[z] -
        # p[z] J_w[y]), (x, y, z) a cyclic permutation; as flat indices of J (6 n_v), of the points
        # (3 k) and of J_c (rows n_v); side b's entries and side a's (subtracted after) apart, each
        # group without repeated entries
        self.entries = []
        for sides_of_row in (self.row_b, self.row_a):
            e_row, e_col, e_side, e_xyz = [], [], [], []
            for r, (side, x) in enumerate(zip(sides_of_row, self.row_xyz)):
                if side == k:  # a side on the ground: no entries
                    continue
                cols = np.flatnonzero(self.mask[side])
                e_row += [r] * cols.size
                e_col += cols.tolist()
                e_side += [side] * cols.size
                e_xyz += [x] * cols.size
            e_row, e_col, e_side, e_xyz = (np.array(v, dtype=int) for v in (e_row, e_col, e_side, e_xyz))
            y, z = (e_xyz + 1) % 3, (e_xyz + 2) % 3
            self.entries.append((e_row * m.nv + e_col, e_xyz * m.nv + e_col, 3 * e_side + y, (3 + z) * m.nv + e_col,
                                 3 * e_side + z, (3 + y) * m.nv + e_col))
        self.c_b, self.c_a = 3 * self.row_b + self.row_xyz, 3 * self.row_a + self.row_xyz
        self.jsel = np.array(self.joints, dtype=int)
        # the residual rows as one linear map of the placements read (H flat: slots x [R^T row-major,
        # t]): c = H W + const, side b's p = R r + t minus side a's (:func:`_residual_rows`)
        W = np.zeros((len(self.joints), 12, rows.size))
        for r_, (sb, sa_, x) in enumerate(zip(self.row_b, self.row_a, self.row_xyz)):
            for side, sign in ((sb, 1.0), (sa_, -1.0)):
                if side == k:
                    continue
                W[self.slot[side], 3 * np.arange(3) + x, r_] += sign * self.r[side]  # R[x, b] r[b] = R^T[b, x] r[b]
                W[self.slot[side], 9 + x, r_] += sign
        self.W = np.ascontiguousarray(W.reshape(-1, rows.size))
        self.r9 = np.repeat(self.r, 3, axis=1)  # r9[k, 3 b + a] = r[k, b]: R^T (row-major) times r, summed over b
        self.act = np.array(mech.actuated, dtype=int)
        self.free = np.setdiff1d(np.arange(mech.nv), self.act)
        self.square = rows.size + self.act.size == mech.nv


def _points(mech: Mechanism) -> _Points:
    cached = mech.__dict__.get("_loop_batch_cache")
    if cached is None:
        cached = _Points(mech)
        object.__setattr__(mech, "_loop_batch_cache", cached)
    return cached


def _residual(pt: _Points, H: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The points P (m, 3 (k + 1)) (the moving sides' :math:`R r + t`, then a zero one for the
    ground sides) and the residual rows c (m, rows) from the placements H (m, slots, 12)."""
    m, k = H.shape[0], pt.moving.size
    Hs = H[:, pt.slot]  # (m, k, 12): column-major rotation (R^T row-major), translation
    P = np.zeros((m, 3 * (k + 1)))
    P[:, : 3 * k] = ((Hs[:, :, :9].reshape(m, k, 3, 3) * pt.r[None, :, :, None]).sum(axis=2) + Hs[:, :, 9:]).reshape(m, -1)
    return P, P[:, pt.c_b] - P[:, pt.c_a] + pt.const


def _residual_rows(pt: _Points, H: FloatArray) -> FloatArray:
    """The residual rows c (m, rows) from the placements H (m, slots, 12) as one product by the
    constant ``_Points.W`` (the same sums as :func:`_residual` in another order: equal to rounding)."""
    return H.reshape(H.shape[0], -1) @ pt.W + pt.const


def _stacked(pt: _Points, J: FloatArray, H: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Residual rows :math:`c` (m, rows) and Jacobian rows :math:`J_c` (m, rows, n_v) of a block
    from its joint Jacobians J (m, 6, n_v) and placements H (m, slots, 12) (column-major rotation,
    translation): each side :math:`p = R r + t`, rows :math:`J_v - p\\times J_\\omega` on the
    support of its body (the entries of ``_Points.entries`` only), each closure row side b minus
    side a."""
    m, nv = J.shape[0], J.shape[2]
    P, c = _residual(pt, H)
    Jf = J.reshape(m, -1)
    Jc = np.zeros((m, pt.row_b.size * nv))
    for sign, (out, v, py, wz, pz, wy) in zip((1.0, -1.0), pt.entries):
        val = Jf[:, v] - (P[:, py] * Jf[:, wz] - P[:, pz] * Jf[:, wy])
        if sign > 0:
            Jc[:, out] = val
        else:
            Jc[:, out] -= val
    return c, Jc.reshape(m, -1, nv)


def solve_from_starts(mech: Mechanism, qa: FloatArray, q_start: FloatArray, tol: float, max_iter: int, offset: int,
                      data: pin.Data, accept_starts: bool = False, frozen: bool = False) -> FloatArray:
    """Gauss–Newton from a starting point per sample (point closures), all samples at once in
    blocks (module docstring). ``offset``: the number of the first sample in error messages.
    ``frozen``: after the first (Newton) step, up to ``_CHORD`` steps with that step's Jacobian
    (the chord method: a residual, no Jacobian, per sample; it converges linearly at the rate
    :math:`\\rho \\approx L\\|A^{-1}\\|\\,|q_0 - q^*|`, about 1e-5 from the continuation's
    starts, so the first such step is the loop's last, below ``tol``), then Newton again."""
    out = np.array(q_start, dtype=float)
    for a in range(0, qa.shape[0], _BLOCK):
        b = min(a + _BLOCK, qa.shape[0])
        out[a:b] = _solve_block(mech, qa[a:b], out[a:b], tol, max_iter, offset + a, data, accept_starts, frozen)
    return out


_CHORD = 3  # chord steps after the first Newton step of a frozen solve


def placement_view(mech: Mechanism, data: pin.Data) -> FloatArray | None:
    """The placements of all joints in ``data`` (after a kinematics pass) as a read-only view
    (n_joints, 12): column-major rotation (that is :math:`R^T` row-major), then translation;
    None where pinocchio's layout is not the one expected (:class:`_Layout`). Kept with ``data``."""
    view = data.__dict__.get("_oMi_view", False)
    if view is False:
        view = _Layout.view(mech, data)
        data.__dict__["_oMi_view"] = view
    return view


def parent_placement_view(mech: Mechanism, data: pin.Data) -> FloatArray | None:
    """:func:`placement_view` of ``data.liMi``, each joint's placement in its parent's frame (filled
    by every kinematics pass: pinocchio's ``jointPlacements[i] * M_i(q)``)."""
    view = data.__dict__.get("_liMi_view", False)
    if view is False:
        view = _Layout.view(mech, data, "liMi")
        data.__dict__["_liMi_view"] = view
    return view


def _layout(mech: Mechanism, pt: _Points, data: pin.Data) -> FloatArray | None:
    return placement_view(mech, data)


def _placements(pt: _Points, data: pin.Data, view: FloatArray | None, out: FloatArray) -> None:
    if view is not None:
        out[...] = view[pt.jsel]
    else:
        for s, j in enumerate(pt.joints):
            M = data.oMi[j]
            out[s, :9] = M.rotation.T.reshape(-1)
            out[s, 9:] = M.translation


def _solve_block(mech: Mechanism, qa: FloatArray, Q: FloatArray, tol: float, max_iter: int, offset: int,
                 data: pin.Data, accept_starts: bool, frozen: bool) -> FloatArray:
    pt = _points(mech)
    model = mech.pin_model
    nv = mech.nv
    view = _layout(mech, pt, data)
    cjj, fk = pin.computeJointJacobians, pin.forwardKinematics
    act, free = pt.act, pt.free
    frozen = frozen and pt.square
    inv = jca = None  # the frozen matrix J_c,w and J_c,a
    todo = np.arange(qa.shape[0])
    for it in range(max_iter + 1):
        m = todo.size
        if not m:
            break
        chord = inv is not None and it <= min(_CHORD, max_iter - 1)
        H = np.empty((m, len(pt.joints), 12))
        if chord:
            for k, i in enumerate(todo):
                fk(model, data, Q[i])
                _placements(pt, data, view, H[k])
            c = _residual(pt, H)[1]
        else:
            J = np.empty((m, 6, nv))
            for k, i in enumerate(todo):
                J[k] = cjj(model, data, Q[i])
                _placements(pt, data, view, H[k])
            c, Jc = _stacked(pt, J, H)
        ea = Q[todo][:, act] - qa[todo]
        if it == 0 and accept_starts:  # starts that solve it already are taken as they are
            go = np.maximum(np.abs(c).max(axis=1, initial=0.0), np.abs(ea).max(axis=1)) >= tol
            todo, c, Jc, ea, m = todo[go], c[go], Jc[go], ea[go], int(go.sum())
            if not m:
                break
        if chord:  # the first step's matrix again (LU: 18 x 18 costs less than an inverse)
            step = np.empty((m, nv))
            step[:, act] = ea
            rhs = c - np.einsum("mra,ma->mr", jca, ea)
            try:
                step[:, free] = np.linalg.solve(inv, rhs[..., None])[..., 0]
            except np.linalg.LinAlgError:  # pragma: no cover - a first step was solved on it
                step[:, free] = np.array([np.linalg.lstsq(Ak, bk, rcond=None)[0] for Ak, bk in zip(inv, rhs)])
        else:
            inv = None
            step = _steps(pt, Jc, c, ea, nv)
            if frozen and it == 0 and np.all(np.isfinite(step)):
                inv, jca = Jc[:, :, free], Jc[:, :, act]
        big = ~(np.abs(step).max(axis=1) < tol)  # the steps not taken: below tol
        if it == max_iter and big.any():
            k = int(np.flatnonzero(big)[0])
            i = int(todo[k])
            A = np.concatenate([Jc[k], mech.actuator_selection()])
            F = np.concatenate([c[k], ea[k]])
            raise ModelError(
                f"sample {offset + i}: actuator positions {np.array2string(qa[i], precision=4)} cannot be assembled "
                f"(residual {np.abs(F).max():.3g} after {max_iter} Gauss-Newton steps, condition number "
                f"{np.linalg.cond(A):.3g})"
            )
        Q[todo[big]] -= step[big]
        todo = todo[big]
        if inv is not None:
            inv, jca = inv[big], jca[big]
            if it + 1 > min(_CHORD, max_iter - 1):
                inv = None
    return Q


def solve_one(mech: Mechanism, qa: FloatArray, q: FloatArray, tol: float, max_iter: int, sample: int,
              data: pin.Data) -> FloatArray:
    """:func:`solve_from_starts` with ``frozen`` of one sample on one-dimensional arrays (the
    anchors of :func:`continuation`, one after the other: the batched route's per-call overhead
    of some ten operations on small arrays would dominate there): the same rows and steps (LAPACK's
    LU directly, its factors kept for the chord steps), the least squares where A is not square."""
    pt = _points(mech)
    view = _layout(mech, pt, data)
    model, nv = mech.pin_model, mech.nv
    act, free = pt.act, pt.free
    q = np.array(q, dtype=float)
    H = np.empty((len(pt.joints), 12))
    lu = piv = jca = None
    chords = 0
    for it in range(max_iter + 1):
        chord = lu is not None and chords < _CHORD and it < max_iter
        if chord:
            pin.forwardKinematics(model, data, q)
            chords += 1
        else:
            J = pin.computeJointJacobians(model, data, q)
            lu = None
        _placements(pt, data, view, H)
        Hs = H[pt.slot]
        P = np.zeros(3 * (pt.moving.size + 1))
        P[: 3 * pt.moving.size] = ((Hs[:, :9] * pt.r9).reshape(-1, 3, 3).sum(axis=1) + Hs[:, 9:]).reshape(-1)
        c = P[pt.c_b] - P[pt.c_a] + pt.const
        ea = q[act] - qa
        step = np.empty(nv)
        if not chord:
            Jf = J.reshape(-1)
            Jc = np.zeros(pt.row_b.size * nv)
            (out, v, py, wz, pz, wy), (out_a, v_a, py_a, wz_a, pz_a, wy_a) = pt.entries
            Jc[out] = Jf[v] - (P[py] * Jf[wz] - P[pz] * Jf[wy])
            Jc[out_a] -= Jf[v_a] - (P[py_a] * Jf[wz_a] - P[pz_a] * Jf[wy_a])
            Jc = Jc.reshape(-1, nv)
            if pt.square:
                jca = Jc[:, act]
                lu, piv, info = sla_lapack.dgetrf(Jc[:, free])
                if info != 0:
                    lu = None
                chords = 0
        if lu is not None:
            step[act] = ea
            step[free], info = sla_lapack.dgetrs(lu, piv, c - jca @ ea)
        else:
            A, F = _full(pt, Jc[None], c[None], ea[None], nv)
            step = np.linalg.lstsq(A[0], F[0], rcond=None)[0]
        if np.abs(step).max() < tol:
            break
        if it == max_iter:
            A = np.concatenate([Jc, mech.actuator_selection()])
            raise ModelError(
                f"sample {sample}: actuator positions {np.array2string(qa, precision=4)} cannot be assembled "
                f"(residual {max(np.abs(c).max(initial=0.0), np.abs(ea).max()):.3g} after {max_iter} Gauss-Newton "
                f"steps, condition number {np.linalg.cond(A):.3g})"
            )
        q -= step
    return q


def _steps(pt: _Points, Jc: FloatArray, c: FloatArray, ea: FloatArray, nv: int) -> FloatArray:
    """Gauss–Newton steps of :math:`A = [J_c; S_a]`, :math:`F = [c; e_a]`: block elimination
    where A is square (:math:`\\delta q_a = e_a`, :math:`J_{c,w}\\delta q_w = c - J_{c,a} e_a`),
    the normal equations otherwise; a singular sample by least squares (SVD)."""
    m = c.shape[0]
    step = np.empty((m, nv))
    try:
        if pt.square:
            step[:, pt.act] = ea
            rhs = c - np.einsum("mra,ma->mr", Jc[:, :, pt.act], ea)
            step[:, pt.free] = np.linalg.solve(Jc[:, :, pt.free], rhs[..., None])[..., 0]
        else:
            A, F = _full(pt, Jc, c, ea, nv)
            At = A.transpose(0, 2, 1)
            step = np.linalg.solve(At @ A, At @ F[..., None])[..., 0]
    except np.linalg.LinAlgError:
        A, F = _full(pt, Jc, c, ea, nv)
        step = np.array([np.linalg.lstsq(Ak, Fk, rcond=None)[0] for Ak, Fk in zip(A, F)])
    return step


def _full(pt: _Points, Jc: FloatArray, c: FloatArray, ea: FloatArray, nv: int) -> tuple[FloatArray, FloatArray]:
    m = c.shape[0]
    Sa = np.zeros((pt.act.size, nv))
    Sa[np.arange(pt.act.size), pt.act] = 1.0
    return np.concatenate([Jc, np.broadcast_to(Sa, (m, *Sa.shape))], axis=1), np.concatenate([c, ea], axis=1)


Sequential = Callable[[FloatArray, FloatArray, int], FloatArray]
"""``sequential(qa, q0, offset)``: the sample-by-sample loop on the rows ``qa``, warm-started
from ``q0``, sample numbers from ``offset`` in its errors; returns the joint positions."""


def continuation(mech: Mechanism, qa: FloatArray, q0: FloatArray, tol: float, max_iter: int, offset: int,
                 data: pin.Data, sequential: Sequential, stride: int = STRIDE) -> FloatArray:
    """The joint positions of actuator positions ``qa`` (n, n_a) along a log, warm-started from
    ``q0`` (module docstring: anchors, batched samples between them, checks and fallback)."""
    n = qa.shape[0]
    Q = np.empty((n, mech.nv))
    if n <= 2 * stride:
        return sequential(qa, q0, offset)
    Q[:2] = sequential(qa[:2], q0, offset)  # the first two: the first anchor's extrapolation
    a, K = 1, stride
    while a < n - 1:
        end = min(a + _WINDOW * K, n - 1)
        knots = np.unique(np.r_[np.arange(a, end, K), end])
        ok_until = _window(mech, qa, Q, knots, tol, max_iter, offset, data)
        if ok_until == end:
            a, K = end, min(2 * K, stride)
            continue
        # the first failing segment (knots[s], knots[s+1]] again sample by sample from its start
        s = int(np.searchsorted(knots, ok_until))
        lo, hi = int(knots[s]), int(knots[s + 1])
        Q[lo + 1 : hi + 1] = sequential(qa[lo + 1 : hi + 1], Q[lo], offset + lo + 1)
        a, K = hi, max(K // 2, 1)
    return Q


def _window(mech: Mechanism, qa: FloatArray, Q: FloatArray, knots: FloatArray, tol: float, max_iter: int,
            offset: int, data: pin.Data) -> int:
    """Solve the samples knots[0] + 1 .. knots[-1] (``Q[knots[0]]`` known) into ``Q``: the anchors
    one after the other, then the others at once. Returns the last sample of the leading run of
    accepted segments (``knots[-1]`` when all are)."""
    a = int(knots[0])
    # anchors: each from the linear extrapolation of the two previous solutions (the first from
    # Q[a - 1] and Q[a]); its error is ~ the chain's second difference, so a solution farther from
    # its start than this chord plus the previous chord (scaled to this gap) plus 100 tol is
    # another branch or a start too far: the window stops before it
    prev2, prev1, t2, t1 = Q[a - 1], Q[a], a - 1, a
    for s in range(1, knots.size):
        i = int(knots[s])
        ratio = (i - t1) / (t1 - t2)
        start = prev1 + (prev1 - prev2) * ratio
        try:
            q = solve_one(mech, qa[i], start, tol, max_iter, offset + i, data)
        except ModelError:
            q = None
        if q is None or not np.abs(q - start).max() <= (1 + ratio) * np.abs(prev1 - prev2).max() + 100 * tol:
            knots = knots[:s]
            break
        Q[i] = q
        prev2, prev1, t2, t1 = prev1, q, t1, i
    idx = np.setdiff1d(np.arange(a + 1, int(knots[-1])), knots)
    if idx.size:
        seg = np.searchsorted(knots, idx) - 1  # segment of each sample
        k0, k1 = knots[seg], knots[seg + 1]
        w = ((idx - k0) / (k1 - k0))[:, None]
        lin = (1 - w) * Q[k0] + w * Q[k1]
        start = _cubic(Q, knots, idx, seg, lin)
        try:
            Q[idx] = _interior(mech, qa[idx], start, knots, idx, seg, Q, tol, max_iter, offset, data)
        except (ModelError, np.linalg.LinAlgError):
            return a
        start = lin
        # per segment: deviation from the chord below chord + second difference + 100 tol
        dev = np.abs(Q[idx] - start).max(axis=1)
        chord = np.abs(Q[knots[1:]] - Q[knots[:-1]]).max(axis=1)
        second = np.zeros(knots.size - 1)
        if knots.size > 2:
            d2 = np.abs(Q[knots[2:]] - 2 * Q[knots[1:-1]] + Q[knots[:-2]]).max(axis=1)
            second[:-1] = d2
            second[1:] = np.maximum(second[1:], d2)
        bound = chord + second + 100 * tol
        bad = ~(dev <= bound[seg])  # NaN fails too
        if bad.any():
            return int(knots[seg[np.flatnonzero(bad)[0]]])
    return int(knots[-1])


def _cubic(Q: FloatArray, knots: FloatArray, idx: FloatArray, seg: FloatArray, lin: FloatArray) -> FloatArray:
    """Starts of the samples between anchors: the cubic through the four anchors around each
    segment (Lagrange; error :math:`O(K^4h^4|q^{(4)}|)` against the line's
    :math:`K^2h^2|\\ddot q|/8`), the line ``lin`` in the first and last segments."""
    start = lin.copy()
    inner = (seg >= 1) & (seg + 2 < knots.size)
    if inner.any():
        s, t = seg[inner], idx[inner].astype(float)
        x = np.stack([knots[s - 1], knots[s], knots[s + 1], knots[s + 2]], axis=1).astype(float)
        out = np.zeros((s.size, Q.shape[1]))
        for j in range(4):
            wj = np.ones(s.size)
            for m in range(4):
                if m != j:
                    wj *= (t - x[:, m]) / (x[:, j] - x[:, m])
            out += wj[:, None] * Q[knots[s - 1 + j]]
        start[inner] = out
    return start


def _interior(mech: Mechanism, qa: FloatArray, start: FloatArray, knots: FloatArray, idx: FloatArray,
              seg: FloatArray, Q: FloatArray,
              tol: float, max_iter: int, offset: int, data: pin.Data) -> FloatArray:
    """The samples between anchors: chord steps with the Jacobian of the nearest anchor (square
    systems: :math:`\\delta q_a = e_a`, :math:`\\delta q_w = J_{c,w}^{-1}(c - J_{c,a}e_a)`, the
    inverse per anchor, once), at most ``_CHORD + 1`` of them; the samples not converged then by
    :func:`solve_from_starts` (Newton, frozen) from where they are. The chord method with an
    approximate Jacobian :math:`\\tilde A` converges linearly at the rate
    :math:`\\rho = \\|\\tilde A^{-1}(\\tilde A - A)\\|` (anchor half a segment away: about
    :math:`K h |\\dot q|\\,L\\|A^{-1}\\|/2`, 1e-3 on the benchmark's motion), and a step below
    ``tol`` leaves :math:`|q - q^*| \\le \\mathrm{tol}/(1 - \\rho)`."""
    pt = _points(mech)
    if not pt.square:
        return solve_from_starts(mech, qa, start, tol, max_iter, offset, data, frozen=True)
    model, nv = mech.pin_model, mech.nv
    view = _layout(mech, pt, data)
    act, free = pt.act, pt.free
    # the anchors' matrices (their solutions: one Jacobian pass each)
    J = np.empty((knots.size, 6, nv))
    H = np.empty((knots.size, len(pt.joints), 12))
    for k, i in enumerate(knots):
        J[k] = pin.computeJointJacobians(model, data, Q[i])
        _placements(pt, data, view, H[k])
    Jc = _stacked(pt, J, H)[1]
    inv_all, jca_all = np.linalg.inv(Jc[:, :, free]), Jc[:, :, act]
    near = np.where(idx - knots[seg] <= knots[seg + 1] - idx, seg, seg + 1)  # the nearest anchor
    Qi = np.array(start, dtype=float)
    todo = np.arange(qa.shape[0])
    fk = pin.forwardKinematics
    for _ in range(_CHORD + 1):
        m = todo.size
        if not m:
            break
        Hs = np.empty((m, len(pt.joints), 12))
        if view is not None:
            jsel = pt.jsel
            for k, i in enumerate(todo):
                fk(model, data, Qi[i])
                Hs[k] = view[jsel]
        else:
            for k, i in enumerate(todo):
                fk(model, data, Qi[i])
                _placements(pt, data, view, Hs[k])
        c = _residual_rows(pt, Hs)
        ea = Qi[todo][:, act] - qa[todo]
        a_ = near[todo]
        step = np.empty((m, nv))
        step[:, act] = ea
        step[:, free] = np.einsum("mij,mj->mi", inv_all[a_], c - np.einsum("mra,ma->mr", jca_all[a_], ea))
        big = ~(np.abs(step).max(axis=1) < tol)
        Qi[todo[big]] -= step[big]
        todo = todo[big]
    if todo.size:
        Qi[todo] = solve_from_starts(mech, qa[todo], Qi[todo], tol, max_iter, offset, data, frozen=True)
    return Qi
