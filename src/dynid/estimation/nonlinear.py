"""Nonlinear constrained identification: 5-parameter Stribeck friction jointly with the
physically consistent rigid-body base parameters (paper 000 §6.1, Eq. 32; Olsson et al. 1998).

Joint friction :math:`F(v) = [F_C + (F_S - F_C) e^{-|v/v_S|^{\\delta}}]\\,\\mathrm{sign}(v) + F_v v`:
:math:`F_C, F_v` are the linear base parameters ``fc``/``fv``, the Stribeck term is linear in
:math:`\\Delta F = F_S - F_C` only. Channel :math:`j`, sample :math:`i`:

.. math::

    y_{ij} = W_{ij}\\,\\beta + \\sum_k P_{ijk}\\, \\Delta F_k\\, g(v_{ik}; v_{S,k}, \\delta_k) + e_{ij},
    \\qquad g(v; v_S, \\delta) = e^{-|v/v_S|^{\\delta}}\\,\\mathrm{sign}(v),

:math:`\\beta = B\\pi` (standard vector :math:`\\pi`), :math:`P` the projection of joint friction on
the channels (identity for a serial arm); subject to :math:`J_b(\\pi) \\succeq \\varepsilon\\mathbf 1`
per body (pseudo-inertia; Wensing, Kim & Slotine 2017), the standard map's sign constraints
(rotor inertia, :math:`F_C, F_v \\ge 0`), :math:`\\Delta F \\ge 0` and bounds on :math:`v_S` and
:math:`\\delta` (default [0.5, 3]). Paper 000 used SQP (NLPQL); here convex and smooth steps:

1. **Warm start (SDP).** At fixed :math:`(v_S, \\delta)` the model is linear in :math:`(\\beta, \\Delta F)`
   (:meth:`SampleProblem.augmented`); :class:`~dynid.estimation.physical.PhysicalLS` fits it for a
   grid of common candidates (:math:`v_S` fractions of each joint's RMS velocity, :math:`\\delta \\in
   \\{1, 2\\}`); kept: the best profile likelihood, :math:`\\sum_j n_j \\log \\mathrm{RSS}_j` (WLS) or
   :math:`N \\log \\sum_j \\mathrm{RSS}_j` (OLS) (the weighted RSS at each candidate's own ML variances).
2. **Joint refinement**: ``scipy.optimize.least_squares`` (trust-region reflective, bounds, LSMR,
   analytic Jacobian, residuals whitened by Gautier's :math:`1/\\sigma_j` of the warm start) over
   the log-Cholesky factor of each body (Rucker & Wensing, IEEE RA-L 2022, "Smooth parameterization
   of rigid-body inertia"), :math:`J_b = UU^T + \\varepsilon\\mathbf 1`, :math:`U = e^{\\alpha}[[e^{d_1},
   s_{12}, s_{13}, t_1], [0, e^{d_2}, s_{23}, t_2], [0, 0, e^{d_3}, t_3], [0, 0, 0, 1]]` (consistent by
   construction), the other standard parameters (bounds :math:`\\ge 0` as the sign constraints),
   :math:`\\Delta F \\ge 0`, :math:`\\log v_S`, :math:`\\delta`. Start: the warm start with each
   :math:`J_b - \\varepsilon\\mathbf 1` shrunk towards :math:`\\mathrm{tr}(\\cdot)/4\\,\\mathbf 1` by ``shrink``
   (log coordinates are ill-conditioned at the boundary). Over-parametrization (null space of
   :math:`B`): rows :math:`\\sqrt{\\eta}\\,c_i(\\theta_i - \\theta_{0,i})` on the standard coordinates
   (:math:`c_i` the Jacobian's column norms at the start, :math:`\\eta` = ``damping`` = 1e-10) make the
   steps unique. Everything is deterministic.
3. **Polish (SDP).** WLS re-estimates :math:`\\sigma_j` from the refinement's residuals. At the
   refined :math:`(v_S, \\delta)`, :class:`PhysicalLS` (OLS on the whitened augmented problem: the
   same objective) gives the exact constrained optimum in :math:`(\\beta, \\Delta F)`, reaching a
   binding constraint the log-Cholesky factor only approaches, naming the active constraints and
   giving the consistent standard vector closest to the reference.
4. **Interior optimum.** With no active constraint, ``least_squares`` over the identifiable
   :math:`(\\beta, \\Delta F, \\log v_S, \\delta)` (full rank: fast, exact), then the polish again (it
   checks that the optimum is still feasible).

Estimate: :math:`(\\beta, \\Delta F)` of the last polish, :math:`(v_S, \\delta)` of the last refinement.
Covariance: Gauss–Newton in :math:`\\varphi = (\\beta, \\Delta F, v_S, \\delta)`, :math:`s^2 (J_\\varphi^T
J_\\varphi)^{-1}` (whitened, :math:`s^2 = \\|r_w\\|^2/(N - p_\\varphi)`), when no constraint or bound is active
(a bound of :math:`\\log v_S` or :math:`\\delta` within 0.1 % of its range counts); else none, and a
note names the active ones.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any

import numpy as np
import scipy.linalg as sla
from threadpoolctl import threadpool_limits

from dynid._typing import FloatArray
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation.linear import check_identifiable
from dynid.estimation.physical import PhysicalConstraints, PhysicalLS
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult
from dynid.model.base_parameters import StandardMap, pseudo_inertia
from dynid.stats import condition_number

__all__ = ["SampleProblem", "StribeckLS", "stribeck_basis", "stribeck_predict"]

_MIN_MOVES = 10  # samples per direction a friction joint needs
_LOG_MAX = 60.0  # bound of the log-scale coordinates alpha, d_i (no overflow of exp)
_BOUND_ACTIVE = 1e-3  # fraction of a bound's range within which v_S / delta count as at the bound


# ---------------------------------------------------------------------- the Stribeck basis
def _basis(v: FloatArray, vs: FloatArray, delta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:math:`g`, :math:`\\partial g/\\partial \\log v_S`, :math:`\\partial g/\\partial\\delta`, each (n, n_f)."""
    u = np.abs(v) / vs
    pw = u**delta
    g = np.exp(-pw) * np.sign(v)
    return g, g * delta * pw, -g * pw * np.log(np.where(u > 0, u, 1.0))


def stribeck_basis(velocity: FloatArray, vs: FloatArray, delta: FloatArray) -> FloatArray:
    """Stribeck regressor :math:`g(v) = e^{-|v/v_S|^{\\delta}}\\mathrm{sign}(v)` [-], shape (n, n_f), of
    velocities (n, n_f) [rad/s or m/s], Stribeck velocities ``vs`` (n_f,) (> 0, same units) and
    exponents ``delta`` (n_f,): joint :math:`k`'s friction is :math:`F_C\\mathrm{sign}(v) + F_v v + \\Delta F_k g_k`."""
    return _basis(np.atleast_2d(np.asarray(velocity, dtype=float)), np.asarray(vs, float), np.asarray(delta, float))[0]


def _identity_projection(n: int, n_f: int) -> FloatArray:
    p = np.zeros((n, n_f, n_f))
    p[:, np.arange(n_f), np.arange(n_f)] = 1.0
    return p


def _finite(name: str, a: FloatArray) -> None:
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} contains NaN/inf")


# ---------------------------------------------------------------------- the problem
@dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
class SampleProblem:
    """The uncompressed rows a nonlinear friction fit needs (the linear part plus velocities).

    Attributes
    ----------
    names : tuple of str
        Base parameter names (columns of ``W``), with the Coulomb and viscous coefficient of
        every Stribeck joint.
    channel_names : tuple of str
        Output channels, length ``n_ch``.
    W : array, shape (n, n_ch, p)
        Base regressor.
    y : array, shape (n, n_ch)
        Measured outputs [N·m or N].
    velocity : array, shape (n, n_f)
        Velocities of the joints with Stribeck friction [rad/s or m/s].
    friction_names : tuple of str
        Names of those joints (length ``n_f``).
    coulomb, viscous : tuple of int
        Index into ``names`` of each friction joint's :math:`F_C` and :math:`F_v` (their columns
        must be :math:`P\\,\\mathrm{sign}(v)` and :math:`P v`).
    standard : StandardMap
        Map to the physical standard parameters (``beta = B @ pi``).
    projection : array, shape (n, n_ch, n_f), optional
        :math:`P`, how joint friction enters each channel; ``None``: identity (channel ``j`` is
        joint ``j``, ``n_f == n_ch``).
    meta : mapping
        Provenance.
    """

    names: tuple[str, ...]
    channel_names: tuple[str, ...]
    W: FloatArray
    y: FloatArray
    velocity: FloatArray
    friction_names: tuple[str, ...]
    coulomb: tuple[int, ...]
    viscous: tuple[int, ...]
    standard: StandardMap
    projection: FloatArray | None = None
    meta: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        W, y, v = (np.array(getattr(self, k), dtype=float) for k in ("W", "y", "velocity"))
        names, chans, fnames = tuple(self.names), tuple(self.channel_names), tuple(self.friction_names)
        if W.ndim != 3 or W.shape[1:] != (len(chans), len(names)):
            raise InputError(f"W has shape {W.shape}, expected (n, {len(chans)}, {len(names)}) (channels, names)")
        n = W.shape[0]
        if y.shape != (n, len(chans)):
            raise InputError(f"y has shape {y.shape}, expected {(n, len(chans))}")
        if v.ndim != 2 or v.shape[0] != n or v.shape[1] == 0:
            raise InputError(f"velocity has shape {v.shape}, expected ({n}, n_f) with n_f >= 1")
        n_f = v.shape[1]
        if len(fnames) != n_f or len(set(fnames)) != n_f:
            raise InputError(f"friction_names must be {n_f} distinct names, got {list(fnames)}")
        for what in ("coulomb", "viscous"):
            idx = tuple(int(i) for i in getattr(self, what))
            if len(idx) != n_f or any(not 0 <= i < len(names) for i in idx):
                raise InputError(f"{what} must hold {n_f} indices into the {len(names)} names, got {list(idx)}")
            object.__setattr__(self, what, idx)
        if len(set(self.coulomb + self.viscous)) != 2 * n_f:
            raise InputError("the coulomb and viscous columns must be distinct")
        proj = None if self.projection is None else np.array(self.projection, dtype=float)
        arrays = {"W": W, "y": y, "velocity": v, "projection": proj}
        for name, a in arrays.items():
            if a is not None:
                _finite(name, a)
        if proj is None and n_f != len(chans):
            raise InputError(f"{n_f} friction joints and {len(chans)} channels: give the projection (n, n_ch, n_f)")
        if proj is not None and proj.shape != (n, len(chans), n_f):
            raise InputError(f"projection has shape {proj.shape}, expected {(n, len(chans), n_f)}")
        if not isinstance(self.standard, StandardMap) or self.standard.B.shape[0] != len(names):
            raise InputError(f"standard must be a StandardMap with {len(names)} base parameters")
        P = _identity_projection(n, n_f) if proj is None else proj
        for k, fn in enumerate(fnames):
            for what, col, x in (("Coulomb", self.coulomb[k], np.sign(v[:, k])), ("viscous", self.viscous[k], v[:, k])):
                want = P[:, :, k] * x[:, None]
                if not np.allclose(W[:, :, col], want, rtol=1e-6, atol=1e-9 * max(1.0, float(np.abs(want).max()))):
                    raise InputError(f"column {names[col]!r} is not the {what} column of friction joint {fn!r} "
                                     f"({'sign(v)' if what == 'Coulomb' else 'v'} projected on the channels)")
        for key, a in {**arrays, "names": names, "channel_names": chans, "friction_names": fnames,
                       "meta": MappingProxyType(dict(self.meta))}.items():
            if isinstance(a, np.ndarray):
                a.setflags(write=False)
            object.__setattr__(self, key, a)

    @property
    def n_samples(self) -> int:
        return int(self.W.shape[0])

    @property
    def n_friction(self) -> int:
        return int(self.velocity.shape[1])

    @property
    def rms_velocity(self) -> FloatArray:
        """RMS velocity of each friction joint, shape (n_f,)."""
        return np.sqrt(np.mean(self.velocity**2, axis=0))

    def stribeck_names(self, prefix: str) -> tuple[str, ...]:
        """``<prefix>_<joint>`` for every friction joint."""
        return tuple(f"{prefix}_{f}" for f in self.friction_names)

    def projection_array(self) -> FloatArray:
        """:math:`P` as an array (n, n_ch, n_f) (the identity expanded when ``projection`` is None)."""
        return _identity_projection(self.n_samples, self.n_friction) if self.projection is None else self.projection

    def friction_columns(self, vs: FloatArray, delta: FloatArray) -> FloatArray:
        """Regressor columns of :math:`\\Delta F` at fixed :math:`(v_S, \\delta)`, shape (n, n_ch, n_f)."""
        return self.projection_array() * stribeck_basis(self.velocity, vs, delta)[:, None, :]

    def compressed(self) -> RegressionProblem:
        """The linear part (Coulomb + viscous friction) as a compressed :class:`RegressionProblem`."""
        return RegressionProblem.from_arrays(self.W, self.y, self.names, self.channel_names,
                                             standard=self.standard, meta=self.meta)

    def augmented(self, vs: FloatArray, delta: FloatArray, *, weights: FloatArray | None = None) -> RegressionProblem:
        """The problem linear in :math:`(\\beta, \\Delta F)` at fixed :math:`(v_S, \\delta)`, compressed.

        Parameters ``dFs_<joint>`` are appended; the standard map gains one identity column per
        :math:`\\Delta F` (non-negative, reference 0). ``weights`` (n_ch,) whiten the rows
        (``sqrt(w_j)`` per channel) before compression.
        """
        n_f, smap = self.n_friction, self.standard
        vs, delta = (np.broadcast_to(np.asarray(a, dtype=float), (n_f,)) for a in (vs, delta))
        if np.any(vs <= 0) or not np.all(np.isfinite(np.r_[vs, delta])):
            raise InputError(f"Stribeck velocities must be positive and finite, got {vs.tolist()}")
        Wa, y = np.concatenate([self.W, self.friction_columns(vs, delta)], axis=2), self.y
        if weights is not None:
            sw = np.sqrt(np.asarray(weights, dtype=float))
            Wa, y = Wa * sw[None, :, None], y * sw[None, :]
        p_std = smap.B.shape[1]
        aug = StandardMap(standard_names=tuple(smap.standard_names) + self.stribeck_names("dFs"),
                          B=sla.block_diag(smap.B, np.eye(n_f)), body_blocks=smap.body_blocks,
                          nonnegative=np.r_[smap.nonnegative, p_std + np.arange(n_f)].astype(int),
                          reference=None if smap.reference is None else np.r_[smap.reference, np.zeros(n_f)],
                          nonpositive=smap.nonpositive)
        return RegressionProblem.from_arrays(Wa, y, self.names + self.stribeck_names("dFs"), self.channel_names,
                                             standard=aug, meta=self.meta)

    @classmethod
    def from_robot(cls, robot, q: FloatArray, dq: FloatArray, ddq: FloatArray, y: FloatArray, *, base=None,
                   friction_joints: Sequence[str] | None = None, meta: Mapping[str, Any] | None = None) -> SampleProblem:
        """The problem of a serial :class:`~dynid.model.robot.RobotModel` (channels = joints).

        ``q, dq, ddq, y`` are (n, n_v) [rad, rad/s, rad/s², N·m]; ``base`` defaults to
        :func:`~dynid.model.base_parameters.robot_base_parameters`, ``friction_joints`` (names)
        to every joint. The robot needs the ``fv`` and ``fc`` extras.
        """
        from dynid.model.base_parameters import robot_base_parameters
        from dynid.model.regressor import regressor

        joints, ext = tuple(robot.joint_names), robot.layout.extra_index
        chosen = joints if friction_joints is None else tuple(friction_joints)
        if not chosen or any(j not in joints for j in chosen):
            raise InputError(f"unknown friction joints {[j for j in chosen if j not in joints]}; joints: {', '.join(joints)}")
        if "fc" not in ext or "fv" not in ext:
            raise InputError("the robot has no fv/fc parameters: load it with extras including 'fv' and 'fc'")
        base = robot_base_parameters(robot) if base is None else base
        jidx = [joints.index(j) for j in chosen]
        std = {e: [robot.parameter_names[ext[e][j]] for j in jidx] for e in ("fc", "fv")}
        absent = [n for e in std for n in std[e] if n not in base.names]
        if absent:
            raise InputError(f"friction columns {absent} are not base parameters")
        cols = {e: tuple(base.names.index(n) for n in std[e]) for e in std}
        dq = np.asarray(dq, dtype=float)
        W = base.regressor(regressor(robot, q, dq, ddq))
        proj = None
        if len(jidx) != len(joints):
            proj = np.zeros((W.shape[0], len(joints), len(jidx)))
            proj[:, jidx, np.arange(len(jidx))] = 1.0
        return cls(names=base.names, channel_names=joints, W=W, y=y, velocity=dq[:, jidx], friction_names=chosen,
                   coulomb=cols["fc"], viscous=cols["fv"], standard=StandardMap.of(robot, base), projection=proj,
                   meta=dict(meta or {}))


def _friction_rows(sp: SampleProblem, Pw: FloatArray, dF, vs, delta, jac: bool):
    """Whitened Stribeck term (N,) and, with ``jac``, its Jacobian in (dF, log vs, delta), (N, 3 n_f)."""
    g, d_logvs, d_delta = _basis(sp.velocity, vs, delta)
    term = np.einsum("nck,nk->nc", Pw, dF * g).reshape(-1)
    if not jac:
        return term, None
    cols = [Pw * c[:, None, :] for c in (g, dF * d_logvs, dF * d_delta)]
    return term, np.concatenate(cols, axis=2).reshape(term.size, -1)


# ---------------------------------------------------------------------- log-Cholesky (Rucker & Wensing 2022)
_OFF = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))  # s12, s23, s13, t1, t2, t3


def _vec10(J: FloatArray) -> FloatArray:
    """``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` of pseudo-inertia(s) (..., 4, 4): :math:`I = \\mathrm{tr}(\\Sigma) 1 - \\Sigma`."""
    S = J[..., :3, :3]
    return np.stack([J[..., 3, 3], J[..., 0, 3], J[..., 1, 3], J[..., 2, 3], S[..., 1, 1] + S[..., 2, 2], -S[..., 0, 1],
                     S[..., 0, 0] + S[..., 2, 2], -S[..., 0, 2], -S[..., 1, 2], S[..., 0, 0] + S[..., 1, 1]], axis=-1)


def _log_cholesky(th: FloatArray, margin: float) -> tuple[FloatArray, FloatArray]:
    """Body parameters (10,) of :math:`J = UU^T + \\varepsilon 1` and their Jacobian (10, 10) in ``th``."""
    ea, ed = np.exp(th[0]), np.exp(th[1:4])
    Ut = np.eye(4)
    Ut[np.arange(3), np.arange(3)] = ed
    for (i, j), x in zip(_OFF, th[4:]):
        Ut[i, j] = x
    U = ea * Ut
    dU = np.zeros((10, 4, 4))
    dU[0] = U
    dU[1 + np.arange(3), np.arange(3), np.arange(3)] = ea * ed
    for m, (i, j) in enumerate(_OFF):
        dU[4 + m, i, j] = ea
    dJ = dU @ U.T
    return _vec10(U @ U.T + margin * np.eye(4)), _vec10(dJ + np.swapaxes(dJ, 1, 2)).T


def _log_cholesky_start(block: FloatArray, margin: float, shrink: float) -> FloatArray:
    """``th`` of :math:`UU^T = (1-\\lambda) J_0 + \\lambda\\,\\mathrm{tr}(J_0)/4\\,\\mathbf 1`,
    :math:`J_0 = J(\\mathrm{block}) - \\varepsilon\\mathbf 1` (eigenvalues floored at 1e-12 of the largest), :math:`\\lambda` = ``shrink``."""
    lam, V = np.linalg.eigh(pseudo_inertia(block) - margin * np.eye(4))
    lam = np.maximum(lam, 0.0)
    lam = (1.0 - shrink) * lam + shrink * float(np.mean(lam))
    lam = np.maximum(lam, 1e-12 * max(float(lam[-1]), 1e-12))  # a Cholesky factor exists
    rev = np.arange(3, -1, -1)
    U = np.linalg.cholesky(((V * lam) @ V.T)[np.ix_(rev, rev)])[np.ix_(rev, rev)]  # upper triangular
    return np.r_[np.log(U[3, 3]), np.log(np.diag(U)[:3] / U[3, 3]), [U[i, j] / U[3, 3] for i, j in _OFF]]


class _Refiner:
    """Working memory of the log-Cholesky refinement (module docstring, step 2)."""

    def __init__(self, sp: SampleProblem, margin: float, sw: FloatArray) -> None:
        self.sp, self.margin, self.sw = sp, margin, sw
        self.p_std = sp.standard.B.shape[1]
        self.blocks = [np.asarray(b, dtype=int) for b in sp.standard.body_blocks]
        body = np.concatenate(self.blocks) if self.blocks else np.zeros(0, dtype=int)
        self.other = np.setdiff1d(np.arange(self.p_std), body)
        self.n_std = 10 * len(self.blocks) + self.other.size  # standard coordinates of theta
        self.M = ((sp.W * sw[None, :, None]).reshape(-1, len(sp.names))) @ sp.standard.B  # (N, p_std)
        self.yw = (sp.y * sw[None, :]).reshape(-1)
        self.Pw = sp.projection_array() * sw[None, :, None]

    def split(self, th: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        f, o = self.sp.n_friction, self.n_std
        return th[o : o + f], np.exp(th[o + f : o + 2 * f]), th[o + 2 * f :]

    def standard(self, th: FloatArray) -> tuple[FloatArray, list[FloatArray]]:
        pi, jacs = np.empty(self.p_std), []
        for b, blk in enumerate(self.blocks):
            pi[blk], D = _log_cholesky(th[10 * b : 10 * b + 10], self.margin)
            jacs.append(D)
        pi[self.other] = th[10 * len(self.blocks) : self.n_std]
        return pi, jacs

    def theta(self, pi: FloatArray, dF: FloatArray, vs: FloatArray, delta: FloatArray, shrink: float) -> FloatArray:
        body = [_log_cholesky_start(pi[blk], self.margin, shrink) for blk in self.blocks]
        return np.concatenate(body + [pi[self.other], dF, np.log(vs), delta])

    def residual(self, th: FloatArray) -> FloatArray:
        """Whitened model minus data, (N,)."""
        return self.M @ self.standard(th)[0] + _friction_rows(self.sp, self.Pw, *self.split(th), jac=False)[0] - self.yw

    def jacobian(self, th: FloatArray) -> FloatArray:
        _, jacs = self.standard(th)
        nb = 10 * len(self.blocks)
        J = np.empty((self.M.shape[0], th.size))
        for b, (blk, D) in enumerate(zip(self.blocks, jacs)):
            J[:, 10 * b : 10 * b + 10] = self.M[:, blk] @ D
        J[:, nb : self.n_std] = self.M[:, self.other]
        J[:, self.n_std :] = _friction_rows(self.sp, self.Pw, *self.split(th), jac=True)[1]
        return J

    def bounds(self, sign: bool, log_vs_lim, delta_lim) -> tuple[FloatArray, FloatArray]:
        smap, f, o = self.sp.standard, self.sp.n_friction, self.n_std
        lb, ub = np.full(o + 3 * f, -np.inf), np.full(o + 3 * f, np.inf)
        for b in range(len(self.blocks)):
            lb[10 * b : 10 * b + 4], ub[10 * b : 10 * b + 4] = -_LOG_MAX, _LOG_MAX
        if sign:
            pos = {int(i): 10 * len(self.blocks) + k for k, i in enumerate(self.other)}
            lb[[pos[int(i)] for i in smap.nonnegative if int(i) in pos]] = 0.0
            ub[[pos[int(i)] for i in smap.nonpositive if int(i) in pos]] = 0.0
        lb[o : o + f] = 0.0
        lb[o + f : o + 2 * f], ub[o + f : o + 2 * f] = log_vs_lim
        lb[o + 2 * f :], ub[o + 2 * f :] = delta_lim
        return lb, ub


def _refine_identifiable(sp: SampleProblem, sw, start, vs, delta, log_vs_lim, delta_lim, xtol: float, max_nfev: int):
    """Step 4: ``least_squares`` over :math:`(\\beta, \\Delta F, \\log v_S, \\delta)` (full rank)."""
    from scipy.optimize import least_squares

    p, f = len(sp.names), sp.n_friction
    Ww, yw = (sp.W * sw[None, :, None]).reshape(-1, p), (sp.y * sw[None, :]).reshape(-1)
    Pw = sp.projection_array() * sw[None, :, None]

    def split(z):
        return z[:p], (z[p : p + f], np.exp(z[p + f : p + 2 * f]), z[p + 2 * f :])

    def fun(z):
        beta, fr = split(z)
        return Ww @ beta + _friction_rows(sp, Pw, *fr, jac=False)[0] - yw

    def jac(z):
        return np.hstack([Ww, _friction_rows(sp, Pw, *split(z)[1], jac=True)[1]])

    lb = np.r_[np.full(p, -np.inf), np.zeros(f), log_vs_lim[0], np.full(f, delta_lim[0])]
    ub = np.r_[np.full(p + f, np.inf), log_vs_lim[1], np.full(f, delta_lim[1])]
    z0 = np.clip(np.r_[start, np.log(vs), delta], lb, ub)
    sol = least_squares(fun, z0, jac=jac, bounds=(lb, ub), method="trf", tr_solver="exact", x_scale="jac",
                        ftol=1e-12, xtol=xtol, gtol=xtol, max_nfev=max_nfev)
    return sol, np.exp(sol.x[p + f : p + 2 * f]), sol.x[p + 2 * f :]


def _profile_nll(rss: FloatArray, n_obs: FloatArray, pooled: bool) -> float:
    """Profile Gaussian negative log-likelihood (up to constants) of residual sums of squares."""
    rss = np.maximum(np.asarray(rss, dtype=float), 1e-300)
    if pooled:
        return float(np.sum(n_obs) * np.log(np.sum(rss) / np.sum(n_obs)))
    return float(np.sum(n_obs * np.log(rss / n_obs)))


def _channel_std(sp: SampleProblem, resid: FloatArray) -> FloatArray:
    """:math:`\\sigma_j = \\sqrt{\\mathrm{RSS}_j / (n - p_j)}`, :math:`p_j` the parameters acting on channel j."""
    p_j = (np.count_nonzero(np.linalg.norm(sp.W, axis=0) > 0, axis=1)
           + 3 * np.count_nonzero(np.linalg.norm(sp.projection_array(), axis=0) > 0, axis=1))
    return np.sqrt(np.sum(resid**2, axis=0) / np.maximum(sp.n_samples - p_j, 1))


def _pass_info(stage: str, sol) -> dict:
    return {"stage": stage, "status": int(sol.status), "message": str(sol.message), "nfev": int(sol.nfev),
            "njev": int(sol.njev or 0), "rss_weighted": float(2 * sol.cost)}


# ---------------------------------------------------------------------- the estimator
@dataclasses.dataclass(frozen=True, kw_only=True)
class StribeckLS:
    """Physically consistent identification with 5-parameter Stribeck friction (module docstring).

    Parameters
    ----------
    weighting : {"wls", "ols"}
        Per-channel weights :math:`1/\\sigma_j^2` (Gautier: from the warm start's residuals,
        re-estimated after the refinement with ``reweight``), or none.
    constraints : PhysicalConstraints
        Margin :math:`\\varepsilon` and sign constraints (per-body bounds are not supported).
    solver : str
        cvxpy solver of the SDPs.
    vs_grid, delta_grid : tuple of float
        Warm-start :math:`v_S` (fractions of each joint's RMS velocity) and :math:`\\delta` [-].
    vs_bounds, delta_bounds : (float, float)
        Bounds of :math:`v_S` (fractions of each joint's RMS velocity) and :math:`\\delta` [-].
    shrink, damping : float
        :math:`\\lambda \\in [0, 1)` and :math:`\\eta \\ge 0` of the refinement (module docstring).
    reweight : bool
        With WLS, re-estimate :math:`\\sigma_j` from the refinement's residuals.
    max_nfev : int
        Function evaluations per ``least_squares`` run.
    ftol, xtol : float
        ``least_squares`` tolerances (``gtol = xtol``). ``ftol`` (relative decrease of the RSS)
        ends the log-Cholesky refinement; 1e-6 is statistical, about :math:`10^{-6} N` in
        :math:`\\chi^2` units: a binding constraint is only approached asymptotically there (the
        polish reaches it exactly).
    """

    weighting: str = "wls"
    constraints: PhysicalConstraints = PhysicalConstraints()
    solver: str = "CLARABEL"
    vs_grid: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2)
    delta_grid: tuple[float, ...] = (1.0, 2.0)
    vs_bounds: tuple[float, float] = (1e-3, 1.0)
    delta_bounds: tuple[float, float] = (0.5, 3.0)
    shrink: float = 0.1
    damping: float = 1e-10
    reweight: bool = True
    max_nfev: int = 100
    ftol: float = 1e-6
    xtol: float = 1e-10

    def _check(self, sp: SampleProblem) -> None:
        if not isinstance(sp, SampleProblem):
            raise InputError(f"StribeckLS fits a SampleProblem, got {type(sp).__name__}")
        if self.weighting not in ("wls", "ols"):
            raise InputError(f"weighting must be 'wls' or 'ols', got {self.weighting!r}")
        if self.constraints.bodies:
            raise InputError("StribeckLS supports the margin and sign constraints, not per-body bounds "
                             f"(given for bodies {', '.join(self.constraints.bodies)})")
        (vlo, vhi), (dlo, dhi) = self.vs_bounds, self.delta_bounds
        if not (0 < vlo < vhi < np.inf and 0 < dlo < dhi < np.inf):
            raise InputError(f"need 0 < low < high for vs_bounds {self.vs_bounds} and delta_bounds {self.delta_bounds}")
        if not self.vs_grid or any(not vlo < c < vhi for c in self.vs_grid):
            raise InputError(f"vs_grid {list(self.vs_grid)} must be non-empty and inside vs_bounds {self.vs_bounds}")
        if not self.delta_grid or any(not dlo < d < dhi for d in self.delta_grid):
            raise InputError(f"delta_grid {list(self.delta_grid)} must be non-empty and inside delta_bounds {self.delta_bounds}")
        if not (0 <= self.shrink < 1 and 0 <= self.damping < np.inf and self.max_nfev >= 1 and self.ftol > 0 and self.xtol > 0):
            raise InputError("need 0 <= shrink < 1, damping >= 0, max_nfev >= 1, ftol > 0 and xtol > 0")
        for k, name in enumerate(sp.friction_names):
            n_pos, n_neg = int(np.sum(sp.velocity[:, k] > 0)), int(np.sum(sp.velocity[:, k] < 0))
            if n_pos + n_neg < _MIN_MOVES:
                raise IdentifiabilityError(f"friction joint {name!r} never moves: its friction parameters are not identifiable",
                                           (f"dFs_{name}", f"vs_{name}", f"delta_{name}"))
            if min(n_pos, n_neg) < _MIN_MOVES:
                raise IdentifiabilityError(f"friction joint {name!r} moves only in the {'positive' if n_neg < n_pos else 'negative'} "
                                           f"direction ({n_pos} samples > 0, {n_neg} < 0): its Coulomb and Stribeck terms "
                                           "are confounded with the offset", (f"dFs_{name}", f"vs_{name}", f"delta_{name}"))

    def fit(self, problem: SampleProblem) -> IdentificationResult:
        """Estimate (see the module docstring); never prints."""
        # one BLAS thread: many small products and a tall matrix gain nothing from threads,
        # and multi-threaded OpenBLAS is many times slower on a loaded machine
        with threadpool_limits(limits=1, user_api="blas"):
            return self._fit(problem)

    def _fit(self, sp: SampleProblem) -> IdentificationResult:
        from scipy.optimize import least_squares

        t0 = time.perf_counter()
        self._check(sp)
        n_f, n, n_ch, rms = sp.n_friction, sp.n_samples, len(sp.channel_names), sp.rms_velocity
        # 1. warm start: the physically consistent SDP on a grid of (vs, delta)
        phys = PhysicalLS(weighting=self.weighting, constraints=self.constraints, solver=self.solver)
        cands, best = [], None
        for c in self.vs_grid:
            for d in self.delta_grid:
                res = phys.fit(sp.augmented(c * rms, np.full(n_f, d)))
                nll = _profile_nll(res.rss_per_channel, res.n_obs, pooled=self.weighting == "ols")
                cands.append({"vs_relative": float(c), "delta": float(d), "nll": nll, "status": res.solver["status"]})
                if best is None or nll < best[0]:
                    best = (nll, float(c), float(d), res)
        _, c0, d0, warm = best
        sigma = np.asarray(warm.noise_std, dtype=float) if self.weighting == "wls" else np.ones(n_ch)
        # 2. joint refinement over log-Cholesky factors, the other standard and the friction parameters
        ref = _Refiner(sp, self.constraints.margin, 1.0 / sigma)
        pi_aug = np.array(list(warm.solver["standard_params"].values()), dtype=float)
        log_vs_lim = (np.log(self.vs_bounds[0] * rms), np.log(self.vs_bounds[1] * rms))
        lb, ub = ref.bounds(self.constraints.sign, log_vs_lim, self.delta_bounds)
        x0 = np.clip(ref.theta(pi_aug[: ref.p_std], pi_aug[ref.p_std :], c0 * rms, np.full(n_f, d0), self.shrink), lb, ub)
        c = np.linalg.norm(ref.jacobian(x0), axis=0)
        c = np.sqrt(self.damping) * np.maximum(c, 1e-12 * max(float(c.max()), 1e-300))
        c[ref.n_std :] = 0.0  # damping on the standard coordinates only (their null space)
        sol = least_squares(lambda th: np.r_[ref.residual(th), c * (th - x0)], x0,
                            jac=lambda th: np.vstack([ref.jacobian(th), np.diag(c)]), bounds=(lb, ub), method="trf",
                            tr_solver="lsmr", ftol=self.ftol, xtol=self.xtol, gtol=self.xtol, max_nfev=self.max_nfev)
        passes = [_pass_info("log-Cholesky", sol)]
        _, vs, delta = ref.split(sol.x)
        if self.reweight and self.weighting == "wls":
            sigma = _channel_std(sp, ref.residual(sol.x).reshape(n, n_ch) / ref.sw)
            if np.any(sigma <= 0):
                raise IdentifiabilityError(f"zero residual on channels {[ch for ch, s in zip(sp.channel_names, sigma) if s <= 0]}: "
                                           "cannot weight by noise variance (use weighting='ols')")
        # 3. polish: the exact constrained optimum in (beta, dF) at the refined (vs, delta)
        polish = PhysicalLS(weighting="ols", constraints=self.constraints, solver=self.solver)
        pol = polish.fit(sp.augmented(vs, delta, weights=1.0 / sigma**2))
        if not pol.solver["active_constraints"]:
            # 4. interior optimum: the identifiable parameters (full rank), then the polish again
            sol, vs, delta = _refine_identifiable(sp, 1.0 / sigma, np.asarray(pol.params), vs, delta, log_vs_lim,
                                                  self.delta_bounds, self.xtol, self.max_nfev)
            passes.append(_pass_info("identifiable", sol))
            pol = polish.fit(sp.augmented(vs, delta, weights=1.0 / sigma**2))
        return self._result(sp, sigma, np.asarray(pol.params), vs, delta, pol, warm, (c0, d0, cands), passes,
                            (log_vs_lim, self.delta_bounds), t0)

    def _result(self, sp, sigma, beta_dF, vs, delta, pol, warm, grid, passes, box, t0) -> IdentificationResult:
        n_f, p, n, n_ch = sp.n_friction, len(sp.names), sp.n_samples, len(sp.channel_names)
        beta, dF = beta_dF[:p], beta_dF[p:]
        c0, d0, cands = grid
        sw = 1.0 / sigma
        resid = sp.y - np.einsum("ncp,p->nc", sp.W, beta) - np.einsum("nck,k->nc", sp.friction_columns(vs, delta), dF)
        rss = np.sum(resid**2, axis=0)
        rss_w = float(np.sum(rss * sw**2))
        names = sp.names + sp.stribeck_names("dFs") + sp.stribeck_names("vs") + sp.stribeck_names("delta")
        params = np.r_[beta, dF, vs, delta]
        dof = n * n_ch - params.size
        if dof <= 0:
            raise InputError(f"fewer observations ({n * n_ch}) than parameters ({params.size})")
        scale = rss_w / dof
        active = list(pol.solver["active_constraints"])
        for what, val, (lo, hi) in (("vs", np.log(vs), box[0]), ("delta", delta, box[1])):
            lo, hi = np.broadcast_to(lo, (n_f,)), np.broadcast_to(hi, (n_f,))
            for k, fname in enumerate(sp.friction_names):
                span = _BOUND_ACTIVE * (hi[k] - lo[k])
                if min(val[k] - lo[k], hi[k] - val[k]) <= span:
                    active.append(f"{what}_{fname} at its {'lower' if val[k] - lo[k] <= span else 'upper'} bound")
        # Gauss-Newton Jacobian in phi = (beta, dF, vs, delta), whitened
        Pw = sp.projection_array() * sw[None, :, None]
        Jf = _friction_rows(sp, Pw, dF, vs, delta, jac=True)[1]
        Jf[:, n_f : 2 * n_f] /= vs  # d/d vs = (d/d log vs) / vs
        R = np.linalg.qr(np.hstack([(sp.W * sw[None, :, None]).reshape(-1, p), Jf]), mode="r")
        notes = [f"Stribeck friction (paper 000 Eq. 32) on {', '.join(sp.friction_names)} with physically consistent base "
                 f"parameters (pseudo-inertia >= {self.constraints.margin:g} I" + (", rotor inertia and friction >= 0"
                 if self.constraints.sign else "") + ", dFs = Fs - Fc >= 0); SDP warm start, log-Cholesky refinement, "
                 "SDP polish", "unweighted (OLS)" if self.weighting == "ols" else "weights 1/sigma_j^2 per channel, sigma_j "
                 + ("from the refinement's residuals" if self.reweight else "from the warm start's OLS residuals (Gautier)")]
        cov = None
        if active:
            notes.append("no covariance: the estimate lies on the boundary of the feasible set (active: "
                         + ", ".join(active) + ")")
        else:
            try:
                check_identifiable(R, names)
            except IdentifiabilityError as exc:
                notes.append(f"no covariance: the Gauss-Newton information matrix is singular ({exc})")
            else:
                rinv = sla.solve_triangular(R, np.eye(R.shape[0]))
                cov = scale * (rinv @ rinv.T)
                notes.append("covariance: Gauss-Newton s^2 (J^T J)^-1 in (beta, dFs, vs, delta); no constraint active")
        smap = sp.standard
        pi = np.array(list(pol.solver["standard_params"].values()), dtype=float)[: smap.B.shape[1]]
        min_eigs = {name: float(np.linalg.eigvalsh(pseudo_inertia(pi[blk]))[0])
                    for name, blk in zip(smap.body_names, smap.body_blocks)}
        stribeck = {f: {"Fc": float(beta[sp.coulomb[k]]), "Fs": float(beta[sp.coulomb[k]] + dF[k]),
                        "Fv": float(beta[sp.viscous[k]]), "vs": float(vs[k]), "delta": float(delta[k])}
                    for k, f in enumerate(sp.friction_names)}
        return IdentificationResult(
            method=f"{self.weighting.upper()}+LMI+Stribeck", names=names, params=params, cov_params=cov, dof=dof,
            scale=scale, channel_names=sp.channel_names, n_obs=np.full(n_ch, n), rss_per_channel=rss,
            noise_std=sigma if self.weighting == "wls" else _channel_std(sp, resid),
            condition_number=condition_number(R), expressions=None,
            solver={
                "algorithm": "SDP warm start, least_squares (TRF) over log-Cholesky factors, SDP polish",
                "solver": self.solver,
                "status": "converged" if passes[-1]["status"] > 0 else "max_nfev reached",
                "nfev": sum(q["nfev"] for q in passes), "iterations": sum(q["njev"] for q in passes), "passes": passes,
                "warm_start": {"status": warm.solver["status"], "vs_relative": c0, "delta": d0,
                               "vs": (c0 * sp.rms_velocity).tolist(), "names": list(warm.names),
                               "params": warm.params.tolist(), "rss": warm.rss_per_channel.tolist(),
                               "rss_weighted": float(np.sum(warm.rss_per_channel * sw**2)),
                               "active_constraints": list(warm.solver["active_constraints"]), "candidates": cands},
                "polish": {"status": pol.solver["status"], "unchanged": pol.solver.get("unchanged")},
                "rss_weighted": rss_w, "margin": self.constraints.margin,
                "standard_params": dict(zip(smap.standard_names, pi.tolist())),
                "min_pseudo_inertia_eigenvalue": list(min_eigs.values()),
                "min_pseudo_inertia_eigenvalue_by_body": min_eigs,
                "active_constraints": active, "stribeck": stribeck,
                "n_base": p, "friction_names": list(sp.friction_names), "wall_time_s": time.perf_counter() - t0,
            },
            provenance=dict(sp.meta), notes=tuple(notes))


def stribeck_predict(result: IdentificationResult, W: FloatArray, velocity: FloatArray,
                     projection: FloatArray | None = None) -> FloatArray:
    """Outputs :math:`W\\beta + \\sum_k P_{:,:,k}\\,\\Delta F_k\\, g(v_k)` (n, n_ch) [N·m or N] of a
    :class:`StribeckLS` result on other data (validation): base regressor ``W`` (n, n_ch, p),
    friction-joint ``velocity`` (n, n_f), ``projection`` (n, n_ch, n_f) as in :class:`SampleProblem`."""
    if "n_base" not in result.solver or "friction_names" not in result.solver:
        raise InputError(f"not a StribeckLS result (method {result.method!r})")
    p, n_f = int(result.solver["n_base"]), len(result.solver["friction_names"])
    W, v = np.asarray(W, dtype=float), np.asarray(velocity, dtype=float)
    if W.ndim != 3 or W.shape[2] != p:
        raise InputError(f"W has shape {W.shape}, expected (n, n_ch, {p})")
    if v.shape != (W.shape[0], n_f):
        raise InputError(f"velocity has shape {v.shape}, expected {(W.shape[0], n_f)}")
    if projection is None and W.shape[1] != n_f:
        raise InputError(f"{n_f} friction joints and {W.shape[1]} channels: give the projection")
    P = _identity_projection(W.shape[0], n_f) if projection is None else np.asarray(projection, dtype=float)
    if P.shape != (W.shape[0], W.shape[1], n_f):
        raise InputError(f"projection has shape {P.shape}, expected {(W.shape[0], W.shape[1], n_f)}")
    for name, a in (("W", W), ("velocity", v), ("projection", P)):
        _finite(name, a)
    th = np.asarray(result.params)
    beta, dF, vs, delta = th[:p], th[p : p + n_f], th[p + n_f : p + 2 * n_f], th[p + 2 * n_f :]
    return W @ beta + np.einsum("nck,nk->nc", P, dF * stribeck_basis(v, vs, delta))
