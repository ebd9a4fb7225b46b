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
   A candidate whose :math:`\\Delta F` column is undetermined on the rows kept (its :math:`v_S` far below
   every kept speed) is skipped and recorded as refused; the fit is refused only when every one is.
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
   checks that the optimum is still feasible). **On the boundary** (a constraint active after the
   polish), alternation: ``least_squares`` over :math:`(\\log v_S, \\delta)` at the polish's
   :math:`(\\beta, \\Delta F)`, then the polish at the new :math:`(v_S, \\delta)`, until the weighted RSS
   falls by less than ``ftol`` relative (each half-step minimizes over its block: the RSS never rises;
   at most 50 rounds, else the status says so).

Estimate: :math:`(\\beta, \\Delta F)` of the last polish, :math:`(v_S, \\delta)` of the last refinement.
Covariance: Gauss–Newton in :math:`\\varphi = (\\beta, \\Delta F, v_S, \\delta)`, :math:`s^2 (J_\\varphi^T
J_\\varphi)^{-1}` (whitened, :math:`s^2 = \\|r_w\\|^2/(N - p_\\varphi)`), when no constraint or bound is active
(a bound of :math:`\\log v_S` or :math:`\\delta` within 0.1 % of its range counts); else none, and a
note names the active ones.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import scipy.linalg as sla
from threadpoolctl import threadpool_limits

from dynid._typing import FloatArray
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation.linear import check_identifiable
from dynid.estimation.physical import PhysicalConstraints, PhysicalLS
from dynid.estimation.results import IdentificationResult
from dynid.estimation.stribeck_problem import SampleProblem, _friction_rows, stribeck_basis, stribeck_predict
from dynid.model.base_parameters import parameters_from_pseudo_inertia, pseudo_inertia
from dynid.stats import condition_number
from dynid.tolerances import scaled

__all__ = ["SampleProblem", "StribeckLS", "stribeck_basis", "stribeck_predict"]

_MIN_MOVES = 10  # samples per direction a friction joint needs
_LOG_MAX = 60.0  # bound of the log-scale coordinates alpha, d_i (no overflow of exp)
_BOUND_ACTIVE = 1e-3  # fraction of a bound's range within which v_S / delta count as at the bound


# ---------------------------------------------------------------------- log-Cholesky (Rucker & Wensing 2022)
_OFF = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))  # s12, s23, s13, t1, t2, t3


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
    return parameters_from_pseudo_inertia(U @ U.T + margin * np.eye(4)), parameters_from_pseudo_inertia(dJ + np.swapaxes(dJ, 1, 2)).T


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
        rw = sp.row_weights(sw)  # 0 on the rows left out
        self.M = ((sp.W * rw[:, :, None]).reshape(-1, len(sp.names))) @ sp.standard.B  # (N, p_std)
        self.yw = (sp.y * rw).reshape(-1)
        self.Pw = sp.projection_array() * rw[:, :, None]

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


_MAX_ROUNDS = 50  # of step 4's alternation on the boundary (module docstring)


def _refine_identifiable(sp: SampleProblem, sw, start, vs, delta, log_vs_lim, delta_lim, xtol: float, max_nfev: int):
    """Step 4: ``least_squares`` over :math:`(\\beta, \\Delta F, \\log v_S, \\delta)` (full rank)."""
    from scipy.optimize import least_squares

    p, f = len(sp.names), sp.n_friction
    rw = sp.row_weights(sw)
    Ww, yw = (sp.W * rw[:, :, None]).reshape(-1, p), (sp.y * rw).reshape(-1)
    Pw = sp.projection_array() * rw[:, :, None]

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
                        ftol=scaled(1e-12), xtol=scaled(xtol), gtol=scaled(xtol), max_nfev=max_nfev)
    return sol, np.exp(sol.x[p + f : p + 2 * f]), sol.x[p + 2 * f :]


def _refine_shape(sp: SampleProblem, sw, beta_dF, vs, delta, log_vs_lim, delta_lim, xtol: float, max_nfev: int):
    """Step 4 on the boundary: ``least_squares`` over :math:`(\\log v_S, \\delta)` alone at fixed
    :math:`(\\beta, \\Delta F)` (the polish's constrained optimum). Returns the solution, ``vs``,
    ``delta``."""
    from scipy.optimize import least_squares

    p, f = len(sp.names), sp.n_friction
    rw = sp.row_weights(sw)
    Pw = sp.projection_array() * rw[:, :, None]
    fixed = (sp.W * rw[:, :, None]).reshape(-1, p) @ beta_dF[:p] - (sp.y * rw).reshape(-1)
    dF = beta_dF[p:]

    def fun(z):
        return fixed + _friction_rows(sp, Pw, dF, np.exp(z[:f]), z[f:], jac=False)[0]

    def jac(z):
        return _friction_rows(sp, Pw, dF, np.exp(z[:f]), z[f:], jac=True)[1][:, f:]

    lb, ub = np.r_[log_vs_lim[0], np.full(f, delta_lim[0])], np.r_[log_vs_lim[1], np.full(f, delta_lim[1])]
    z0 = np.clip(np.r_[np.log(vs), delta], lb, ub)
    sol = least_squares(fun, z0, jac=jac, bounds=(lb, ub), method="trf", tr_solver="exact", x_scale="jac",
                        ftol=scaled(1e-12), xtol=scaled(xtol), gtol=scaled(xtol), max_nfev=max_nfev)
    return sol, np.exp(sol.x[:f]), sol.x[f:]


def _weighted_rss(sp: SampleProblem, sw, beta_dF, vs, delta) -> float:
    """The weighted residual sum of squares of ``(beta, dF, vs, delta)`` over the kept rows."""
    p = len(sp.names)
    resid = sp.y - np.einsum("ncp,p->nc", sp.W, beta_dF[:p]) - np.einsum("nck,k->nc", sp.friction_columns(vs, delta),
                                                                        beta_dF[p:])
    return float(np.sum(np.sum((resid * sp.row_mask) ** 2, axis=0) * sw**2))


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
    return np.sqrt(np.sum((resid * sp.row_mask) ** 2, axis=0) / np.maximum(sp.n_obs - p_j, 1))


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
        used = sp.row_mask.any(axis=1)  # samples with at least one equation kept
        for k, name in enumerate(sp.friction_names):
            n_pos, n_neg = int(np.sum(used & (sp.velocity[:, k] > 0))), int(np.sum(used & (sp.velocity[:, k] < 0)))
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
        # A candidate whose dFs column is numerically zero on the kept rows (v_S far below every kept
        # speed, e.g. min_velocity 2 mm/s against 0.02 x an RMS speed of 19 mm/s: exp(-(2/0.38)^2) ~ 4e-13)
        # is refused by the rank test for that dFs: it is skipped (its model, dFs = 0, is nested in the
        # others) and the fit raises only when every candidate is refused. A refusal that names no dFs
        # does not depend on the candidate (the rigid-body or friction columns): raised at once.
        dfs_names = set(sp.stribeck_names("dFs"))
        cands, best, refused = [], None, []
        for c in self.vs_grid:
            for d in self.delta_grid:
                try:
                    res = phys.fit(sp.augmented(c * rms, np.full(n_f, d)))
                except IdentifiabilityError as exc:
                    if not dfs_names.intersection(exc.names):
                        raise
                    refused.append(exc)
                    cands.append({"vs_relative": float(c), "delta": float(d), "nll": None,
                                  "status": "refused: " + str(exc).splitlines()[0]})
                    continue
                nll = _profile_nll(res.rss_per_channel, res.n_obs, pooled=self.weighting == "ols")
                cands.append({"vs_relative": float(c), "delta": float(d), "nll": nll, "status": res.solver["status"]})
                if best is None or nll < best[0]:
                    best = (nll, float(c), float(d), res)
        if best is None:
            bad = tuple(n for n in sp.stribeck_names("dFs") if any(n in e.names for e in refused))
            raise IdentifiabilityError(
                f"unidentifiable Stribeck terms: {', '.join(bad)}: every warm-start grid candidate (v_S = "
                f"{list(self.vs_grid)} x the RMS speed, delta = {list(self.delta_grid)}) left it undetermined (its "
                "column exp(-|v/v_S|^delta) is zero or dependent on the rows kept; are there rows in the Stribeck "
                "speed band, above processing.min_velocity?)", bad)
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
                            tr_solver="lsmr", ftol=scaled(self.ftol), xtol=scaled(self.xtol), gtol=scaled(self.xtol),
                            max_nfev=self.max_nfev)
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
        else:
            # 4'. on the boundary the log-Cholesky pass only approaches the optimum (its coordinates are
            # ill-conditioned there) and (vs, delta) would keep its last values: alternate least_squares
            # over (log vs, delta) at the polish's (beta, dF) with the polish at the new (vs, delta). Each
            # half-step is a minimum over its block from the current point (the polish: the exact constrained
            # optimum, up to the SDP's tolerance), so the weighted RSS falls monotonically; stop when it falls
            # by less than ftol relative (block coordinate descent, a fixed point of both half-steps)
            sw = 1.0 / sigma
            rss = _weighted_rss(sp, sw, np.asarray(pol.params), vs, delta)
            rounds, stop = 0, "limit"
            while rounds < _MAX_ROUNDS:
                rounds += 1
                sol, vs1, delta1 = _refine_shape(sp, sw, np.asarray(pol.params), vs, delta, log_vs_lim,
                                                 self.delta_bounds, self.xtol, self.max_nfev)
                try:
                    pol1 = polish.fit(sp.augmented(vs1, delta1, weights=sw**2))
                except IdentifiabilityError:  # the new shape leaves a dFs column ~0 (vs at its bound): not taken
                    stop = "undetermined"
                    break
                rss1 = _weighted_rss(sp, sw, np.asarray(pol1.params), vs1, delta1)
                if rss1 < rss:
                    pol, vs, delta = pol1, vs1, delta1
                if not rss1 < rss * (1.0 - scaled(self.ftol)):
                    stop = "tolerance"
                    break
                rss = rss1
            # converged: the RSS stopped falling; a shape step that would leave a Stribeck term undetermined
            # is not taken, and then the status is the log-Cholesky pass's
            status = 1 if stop == "tolerance" else (passes[-1]["status"] if stop == "undetermined" else 0)
            message = {"tolerance": "the weighted RSS stopped falling",
                       "undetermined": "the next (vs, delta) step would leave a dFs undetermined: not taken",
                       "limit": f"stopped at the limit of {_MAX_ROUNDS} rounds"}[stop]
            passes.append({"stage": "boundary alternation", "status": status,
                           "message": f"{rounds} rounds of (vs, delta) least squares and the SDP polish; {message}",
                           "nfev": rounds, "njev": rounds,
                           "rss_weighted": _weighted_rss(sp, sw, np.asarray(pol.params), vs, delta)})
        return self._result(sp, sigma, np.asarray(pol.params), vs, delta, pol, warm, (c0, d0, cands), passes,
                            (log_vs_lim, self.delta_bounds), t0)

    def _result(self, sp, sigma, beta_dF, vs, delta, pol, warm, grid, passes, box, t0) -> IdentificationResult:
        n_f, p = sp.n_friction, len(sp.names)
        beta, dF = beta_dF[:p], beta_dF[p:]
        c0, d0, cands = grid
        sw = 1.0 / sigma
        resid = sp.y - np.einsum("ncp,p->nc", sp.W, beta) - np.einsum("nck,k->nc", sp.friction_columns(vs, delta), dF)
        resid = resid * sp.row_mask  # the rows left out do not count
        rss = np.sum(resid**2, axis=0)
        rss_w = float(np.sum(rss * sw**2))
        names = sp.names + sp.stribeck_names("dFs") + sp.stribeck_names("vs") + sp.stribeck_names("delta")
        params = np.r_[beta, dF, vs, delta]
        n_rows = int(sp.n_obs.sum())
        dof = n_rows - params.size
        if dof <= 0:
            raise InputError(f"fewer observations ({n_rows}) than parameters ({params.size})")
        scale = rss_w / dof
        active = list(pol.solver["active_constraints"])
        for what, val, (lo, hi) in (("vs", np.log(vs), box[0]), ("delta", delta, box[1])):
            lo, hi = np.broadcast_to(lo, (n_f,)), np.broadcast_to(hi, (n_f,))
            for k, fname in enumerate(sp.friction_names):
                span = _BOUND_ACTIVE * (hi[k] - lo[k])
                if min(val[k] - lo[k], hi[k] - val[k]) <= span:
                    active.append(f"{what}_{fname} at its {'lower' if val[k] - lo[k] <= span else 'upper'} bound")
        # Gauss-Newton Jacobian in phi = (beta, dF, vs, delta), whitened
        rw = sp.row_weights(sw)
        Pw = sp.projection_array() * rw[:, :, None]
        Jf = _friction_rows(sp, Pw, dF, vs, delta, jac=True)[1]
        Jf[:, n_f : 2 * n_f] /= vs  # d/d vs = (d/d log vs) / vs
        R = np.linalg.qr(np.hstack([(sp.W * rw[:, :, None]).reshape(-1, p), Jf]), mode="r")
        notes = [f"Stribeck friction (paper 000 Eq. 32) on {', '.join(sp.friction_names)} with physically consistent base "
                 f"parameters (pseudo-inertia >= {self.constraints.margin:g} I" + (", rotor inertia and friction >= 0"
                 if self.constraints.sign else "") + ", dFs = Fs - Fc >= 0); SDP warm start, log-Cholesky refinement, "
                 "SDP polish", "unweighted (OLS)" if self.weighting == "ols" else "weights 1/sigma_j^2 per channel, sigma_j "
                 + ("from the refinement's residuals" if self.reweight else "from the warm start's OLS residuals (Gautier)")]
        skipped = [q for q in cands if q["status"].startswith("refused")]
        if skipped:
            notes.append(f"warm start: {len(skipped)} of {len(cands)} grid candidates (vs_relative, delta) skipped, "
                         "their dFs undetermined: " + ", ".join(f"({q['vs_relative']:g}, {q['delta']:g})" for q in skipped))
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
            scale=scale, channel_names=sp.channel_names, n_obs=sp.n_obs, rss_per_channel=rss,
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
                               "active_constraints": list(warm.solver["active_constraints"]), "candidates": cands,
                               "refused_candidates": len(skipped)},
                "polish": {"status": pol.solver["status"], "unchanged": pol.solver.get("unchanged")},
                "rss_weighted": rss_w, "margin": self.constraints.margin,
                "standard_params": dict(zip(smap.standard_names, pi.tolist())),
                "min_pseudo_inertia_eigenvalue": list(min_eigs.values()),
                "min_pseudo_inertia_eigenvalue_by_body": min_eigs,
                "active_constraints": active, "stribeck": stribeck,
                "n_base": p, "friction_names": list(sp.friction_names), "wall_time_s": time.perf_counter() - t0,
            },
            provenance=dict(sp.meta), notes=tuple(notes))
