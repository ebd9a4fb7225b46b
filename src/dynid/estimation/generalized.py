"""Gauss–Markov (generalized least squares) with a full noise covariance across channels,
iteratively reweighted least squares, and total least squares, on the compressed problem.

Gauss–Markov (paper 002 Eq. 21; paper 004 §2): with the noise of the ``n_ch`` channels of one
sample correlated, :math:`\\mathrm{cov}(e_i) = \\Sigma` (e.g. :math:`\\Sigma_{\\eta\\eta}` of the
actuator forces from period averaging, paper 004 §3.2),

.. math::

    \\hat\\beta = \\arg\\min \\sum_i (y_i - W_i\\beta)^T \\Sigma^{-1} (y_i - W_i\\beta)
    = (W^T \\bar\\Sigma^{-1} W)^{-1} W^T \\bar\\Sigma^{-1} y,
    \\qquad \\mathrm{cov}(\\hat\\beta) = s^2 (W^T \\bar\\Sigma^{-1} W)^{-1}

(:math:`\\bar\\Sigma = I_N \\otimes \\Sigma`). Per-channel factors cannot give the cross-channel
products this needs, so the problem carries the triangular factor ``R_c`` of the *wide* matrix
:math:`X` whose row ``i`` is :math:`[W_1(i)\\,y_1(i) \\cdots W_{n}(i)\\,y_{n}(i)]`
(:class:`~dynid.estimation.problem.ProblemBuilder` with ``cross=True``). With
:math:`\\Sigma^{-1} = L L^T` and :math:`r_i = X_i V(\\beta)`,

.. math::

    \\sum_i r_i^T \\Sigma^{-1} r_i = \\| R_c V(\\beta) L \\|_F^2
    = \\sum_m \\Big\\| \\underbrace{\\textstyle\\sum_k L_{km} R_c^{(y_k)}}_{b_m}
      - \\underbrace{\\textstyle\\sum_k L_{km} R_c^{(W_k)}}_{A_m} \\beta \\Big\\|^2,

a small least-squares problem of :math:`n_{ch}^2 (p+1)` rows, solved by the same QR route as
OLS/WLS (:func:`dynid.estimation.linear.whitened_solve` is its diagonal special case). The
residual cross-covariance, for the feasible (estimated-:math:`\\Sigma`) version, is
:math:`\\hat\\Sigma_{jk} = (R_c v_j)^T (R_c v_k) / \\sqrt{(n_j - p_j)(n_k - p_k)}` (Zellner's SUR
estimate with Gautier's per-channel degrees of freedom).

Scale: ``scale="estimated"`` (default) multiplies the covariance by
:math:`s^2 = \\text{cost}/(N - p)`, which is close to 1 when :math:`\\Sigma` is right and grows
with modelling error; ``scale="known"`` trusts the given :math:`\\Sigma` absolutely (paper 002).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg as sla
from threadpoolctl import threadpool_limits

from dynid._typing import FloatArray
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation.linear import _channel_noise_std, _result, _Solve, check_identifiable, whitened_solve
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult
from dynid.stats import condition_number
from dynid.tolerances import scaled

__all__ = ["GaussMarkov", "IRLS", "TLS", "gls_solve", "residual_covariance"]


def _check_cov(cov: FloatArray, n: int, what: str) -> FloatArray:
    c = np.asarray(cov, dtype=float)
    if c.shape != (n, n):
        raise InputError(f"{what} must be {n} x {n} (one row per channel), got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise InputError(f"{what} contains NaN/inf")
    if not np.allclose(c, c.T, rtol=1e-8, atol=1e-12 * np.abs(c).max()):
        raise InputError(f"{what} is not symmetric")
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        w = np.linalg.eigvalsh(c).min()
        raise InputError(f"{what} is not positive definite (smallest eigenvalue {w:.3g})") from None
    return c


def _need_cross(problem: RegressionProblem, who: str) -> FloatArray:
    if problem.cross is None:
        raise InputError(f"{who} with a full noise covariance needs the cross-channel factor: "
                         "build the problem with ProblemBuilder(..., cross=True)")
    return problem.cross


def _split(problem: RegressionProblem, factor: FloatArray, n: int) -> tuple[FloatArray, FloatArray]:
    """Columns of a wide factor of ``n`` channels: ``W`` blocks (n, P, p) and ``y`` columns (P, n)."""
    p = problem.n_params
    Rw = np.stack([factor[:, k * (p + 1): k * (p + 1) + p] for k in range(n)])
    Ry = np.stack([factor[:, k * (p + 1) + p] for k in range(n)], axis=1)
    return Rw, Ry


def _blocks(problem: RegressionProblem) -> list[tuple[np.ndarray, FloatArray, FloatArray, int]]:
    """Every cross-channel factor as ``(channels, W blocks, y columns, samples)``: the samples
    with every channel kept, then one per pattern of kept channels
    (:class:`~dynid.estimation.problem.CrossBlock`)."""
    _need_cross(problem, "Gauss–Markov")
    out = []
    for blk in problem.cross_blocks():
        ch = np.asarray(blk.channels, dtype=int)
        out.append((ch, *_split(problem, blk.factor, ch.size), blk.n_rows))
    return out


def residual_covariance(problem: RegressionProblem, beta: FloatArray) -> FloatArray:
    """Cross-channel covariance of the residuals at ``beta`` (see the module docstring), (n_ch, n_ch).

    With a per-channel row selection (partial cross blocks) each pair of channels is estimated
    from the samples that keep both: the correlation from those samples' residual products,
    the variances from every kept row of each channel (pairwise deletion); without one this is
    the formula of the module docstring exactly."""
    n = problem.n_channels
    beta = np.asarray(beta, dtype=float)
    S = np.zeros((n, n))      # residual products over the samples keeping both channels
    Sjj = np.zeros((n, n))    # sum of squares of channel j over the samples keeping j and k
    for ch, Rw, Ry, _ in _blocks(problem):
        E = Ry - np.einsum("kPp,p->Pk", Rw, beta)
        G = E.T @ E
        S[np.ix_(ch, ch)] += G
        Sjj[np.ix_(ch, ch)] += np.diag(G)[:, None]
    dof = np.maximum(problem.n_obs - problem.channel_ranks(), 1).astype(float)
    var = np.diag(S) / dof
    denom = np.sqrt(Sjj * Sjj.T)
    corr = np.divide(S, denom, out=np.zeros((n, n)), where=denom > 0)
    np.fill_diagonal(corr, 1.0)
    sd = np.sqrt(var)
    return corr * np.outer(sd, sd)


def gls_solve(problem: RegressionProblem, cov: FloatArray, *, known_scale: bool = False) -> _Solve:
    """Generalized least squares with the channel noise covariance ``cov`` (n_ch, n_ch).

    A sample that keeps only the channels :math:`K` (per-channel row selection) is whitened with
    :math:`\\Sigma_{KK}` (the covariance of its kept channels). The covariance of the estimate is
    :math:`s^2 (A^T A)^{-1}` with the estimated scale, or :math:`(A^T A)^{-1}` when
    ``known_scale`` (``cov`` in absolute units).
    """
    with threadpool_limits(limits=1, user_api="blas"):  # small dense problems: threads only cost (bench/README.md)
        return _gls_solve(problem, cov, known_scale)


def _whitener(cov: FloatArray) -> FloatArray:
    """``L`` with ``cov^-1 = L L^T``."""
    C = np.linalg.cholesky(cov)
    return sla.solve_triangular(C, np.eye(cov.shape[0]), lower=True).T


def _gls_solve(problem: RegressionProblem, cov: FloatArray, known_scale: bool) -> _Solve:
    n, p = problem.n_channels, problem.n_params
    cov = _check_cov(cov, n, "noise covariance")
    As, bs = [], []
    for ch, Rw, Ry, _ in _blocks(problem):
        L = _whitener(cov[np.ix_(ch, ch)])
        As.append(np.einsum("km,kPp->mPp", L, Rw).reshape(-1, p))
        bs.append(np.einsum("km,Pk->mP", L, Ry).reshape(-1))
    A, b = np.vstack(As), np.concatenate(bs)
    q, r = np.linalg.qr(A, mode="reduced")
    check_identifiable(r, problem.names)
    c = q.T @ b
    beta = sla.solve_triangular(r, c)
    cost = float(np.sum((b - A @ beta) ** 2))
    dof = problem.n_total - p
    if dof <= 0:
        raise InputError(f"fewer observations ({problem.n_total}) than parameters ({p})")
    scale = cost / dof
    rinv = sla.solve_triangular(r, np.eye(p))
    cov_beta = (1.0 if known_scale else scale) * (rinv @ rinv.T)
    return _Solve(beta=beta, R=r, c=c, rss=problem.rss_per_channel(beta), scale=scale, cov=cov_beta, dof=dof,
                  cond=condition_number(r))


def _noise_note(cov: FloatArray) -> dict:
    s = np.sqrt(np.diag(cov))
    return {"noise_covariance": cov.tolist(), "noise_std": s.tolist(), "noise_correlation": (cov / np.outer(s, s)).tolist()}


@dataclasses.dataclass(frozen=True, kw_only=True)
class GaussMarkov:
    """Gauss–Markov estimate with a full cross-channel noise covariance (paper 002 Eq. 21).

    Parameters
    ----------
    noise_covariance : array (n_ch, n_ch), optional
        :math:`\\Sigma` of one sample's output noise [N² or N²m²], e.g. :math:`\\Sigma_{\\eta\\eta}`
        from period averaging divided by the number of averaged periods. When omitted it is
        estimated from the residuals: OLS first, then ``iterations`` rounds of
        (covariance from residuals -> GLS) (feasible GLS; 1 = the two-step estimate).
    scale : {"estimated", "known"}
        Whether the covariance of the estimates is scaled by the residual variance factor
        :math:`s^2` (default) or uses the given :math:`\\Sigma` as exact (paper 002).
    iterations : int
        Rounds of residual-covariance re-estimation (only without ``noise_covariance``).
    """

    noise_covariance: tuple[tuple[float, ...], ...] | None = None
    scale: str = "estimated"
    iterations: int = 1
    tol: float = 1e-10

    def fit(self, problem: RegressionProblem) -> IdentificationResult:
        if self.scale not in ("estimated", "known"):
            raise ValueError(f"scale must be 'estimated' or 'known', got {self.scale!r}")
        if self.iterations < 1:
            raise ValueError("iterations must be >= 1")
        known = self.scale == "known"
        if self.noise_covariance is not None:
            cov = _check_cov(self.noise_covariance, problem.n_channels, "noise_covariance")
            s = gls_solve(problem, cov, known_scale=known)
            source, rounds = "given", 0
        else:
            if known:
                raise InputError("scale = 'known' needs a given noise_covariance (an estimated one is not known)")
            s = gls_solve(problem, np.eye(problem.n_channels))
            rounds = 0
            for rounds in range(1, self.iterations + 1):
                cov = residual_covariance(problem, s.beta)
                _check_cov(cov, problem.n_channels, "residual covariance")
                prev = s.beta
                s = gls_solve(problem, cov)
                if np.linalg.norm(s.beta - prev) <= scaled(self.tol) * max(np.linalg.norm(prev), 1e-300):
                    break
            source = "residuals (feasible GLS, OLS start)"
        solver = {"algorithm": "QR of the Sigma-whitened wide factor (cross-channel products)",
                  "covariance_from": source, "iterations": rounds, "scale": self.scale, **_noise_note(cov)}
        notes = (f"Gauss-Markov: full {problem.n_channels}x{problem.n_channels} noise covariance across channels from {source}"
                 + ("; covariance of the estimates uses it as exact (scale = 'known')" if known else ""),)
        return _result(problem, "GM", s, np.sqrt(np.diag(cov)), solver, notes)


@dataclasses.dataclass(frozen=True, kw_only=True)
class IRLS:
    """Iteratively reweighted least squares: the noise model is re-estimated from the residuals
    of the previous weighted fit until the estimates settle (iterated feasible GLS).

    ``covariance="diagonal"`` iterates Gautier's per-channel variances (WLS, paper 001 Eqs.
    14–16) to a fixed point; ``"full"`` iterates the cross-channel covariance (Gauss–Markov).
    Sample-wise robust weights (Huber and the like) would need the raw rows, which the
    compressed problem does not keep; they are not offered.
    """

    covariance: str = "diagonal"
    max_iter: int = 50
    tol: float = 1e-9

    def fit(self, problem: RegressionProblem) -> IdentificationResult:
        if self.covariance not in ("diagonal", "full"):
            raise ValueError(f"covariance must be 'diagonal' or 'full', got {self.covariance!r}")
        if self.covariance == "full":
            res = GaussMarkov(iterations=self.max_iter, tol=self.tol).fit(problem)
            it = res.solver["iterations"]
            return dataclasses.replace(res, method="IRLS", solver={**res.solver, "covariance": "full"},
                                       notes=(f"IRLS: cross-channel noise covariance re-estimated {it} times",))
        s = whitened_solve(problem, np.ones(problem.n_channels))
        sigma = np.ones(problem.n_channels)
        it = 0
        for it in range(1, self.max_iter + 1):
            sigma = _channel_noise_std(problem, s.rss)
            if np.any(sigma <= 0):
                zero = [c for c, v in zip(problem.channel_names, sigma) if v <= 0]
                raise IdentifiabilityError(f"zero residual on channels {zero}: cannot weight by noise variance")
            prev = s.beta
            s = whitened_solve(problem, 1.0 / sigma**2)
            if np.linalg.norm(s.beta - prev) <= scaled(self.tol) * max(np.linalg.norm(prev), 1e-300):
                break
        else:
            raise IdentifiabilityError(f"IRLS did not settle in {self.max_iter} iterations")
        solver = {"algorithm": "iterated per-channel reweighting", "covariance": "diagonal", "iterations": it,
                  "sigma": sigma.tolist()}
        return _result(problem, "IRLS", s, sigma, solver, (f"IRLS: per-channel noise variances re-estimated {it} times",))


TLS_MAX_AMPLIFICATION = 2.0
"""The largest factor :class:`TLS` may multiply the weakest direction of the least-squares solution by:
beyond it the regressor's weakest direction carries less signal than the errors TLS assumes in it
(signal-to-error ratio below 1; see :class:`TLS`)."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class TLS:
    """Total least squares for a noisy regressor (errors in the variables).

    The rows are first whitened per channel (``weighting="wls"``: Gautier variances from OLS;
    ``"ols"``: none) and every column of :math:`[W\\;y]` divided by the standard deviation of its
    errors (``error_std``, p + 1 values, in whitened units), or, when these are not known,
    scaled to unit norm (a common heuristic that assumes errors proportional to the column
    norms); the estimate is
    the smallest right singular vector of the scaled, stacked augmented factors (their Gram
    matrix equals that of all rows, so the compression is exact). Covariance: the first-order
    asymptotic expression :math:`\\hat\\sigma^2 (1 + \\|x\\|^2) (A^T A - s_{min}^2 I)^{-1}` in the
    scaled variables (Van Huffel & Vandewalle 1991, §8), valid when the scaled regressor and
    output errors are independent with equal variance; a note says so.

    Well-posedness (refused otherwise). With :math:`\\sigma'_p` the smallest singular value of the
    scaled regressor :math:`A` and :math:`s_{p+1}` the smallest of the scaled :math:`[A\\;y]`, the TLS
    solution exists and is unique only when :math:`\\sigma'_p > s_{p+1}` (Van Huffel & Vandewalle
    1991, Thm 2.7), and the TLS correction of the least-squares solution,
    :math:`x = (A^TA - s_{p+1}^2 I)^{-1} A^T y`, multiplies the weakest direction by

    .. math:: \\kappa = \\frac{\\sigma'^2_p}{\\sigma'^2_p - s^2_{p+1}}.

    Under the TLS model (errors of variance :math:`s^2` per row in every scaled column, n rows)
    :math:`s^2_{p+1} \\approx n s^2` and :math:`\\sigma'^2_p \\approx \\sigma^2_p(A_0) + n s^2`, so
    :math:`\\kappa - 1 \\approx n s^2 / \\sigma_p^2(A_0)`: the inverse squared signal-to-error ratio of the
    regressor's weakest direction. Above :data:`TLS_MAX_AMPLIFICATION` (2: that direction carries
    less signal than the errors TLS assumes in it) the smallest singular vector of :math:`[A\\;y]` is
    a near-collinearity of the regressor columns, not the noise; the first-order covariance above
    (an expansion in error over signal) does not hold either. The fit is then refused with the
    figures (:class:`~dynid.errors.IdentifiabilityError`, one line from the CLI). This is what
    happens with unit column norms on an ill-conditioned closed-chain regressor, where the errors
    are mostly in the outputs: a MuJoCo Stewart platform (examples/mujoco_twins, 53 base
    parameters, condition number 1.9e3) gave :math:`\\sigma'_p` = 1.2130e-3 against :math:`s_{p+1}` =
    1.2121e-3, :math:`\\kappa` = 750, and held-out errors of 150-230 % per leg where WLS has 1.3-1.6 %
    and the prior 3-33 % (bench/README, "TLS on a closed chain").
    """

    weighting: str = "wls"
    error_std: tuple[float, ...] | None = None

    def fit(self, problem: RegressionProblem) -> IdentificationResult:
        if self.weighting not in ("ols", "wls"):
            raise ValueError(f"weighting must be 'ols' or 'wls', got {self.weighting!r}")
        p = problem.n_params
        first = whitened_solve(problem, np.ones(problem.n_channels))
        sigma = _channel_noise_std(problem, first.rss) if self.weighting == "wls" else np.ones(problem.n_channels)
        if np.any(sigma <= 0):
            raise IdentifiabilityError("zero residual on a channel: cannot weight by noise variance")
        M = (problem.factors / sigma[:, None, None]).reshape(-1, p + 1)
        if self.error_std is not None:
            d = np.asarray(self.error_std, dtype=float)
            if d.shape != (p + 1,) or np.any(~np.isfinite(d)) or np.any(d <= 0):
                raise InputError(f"error_std must be {p + 1} positive numbers (regressor columns, then the output)")
            scaling = "by the given error standard deviations"
        else:
            d = np.linalg.norm(M, axis=0)
            d[d == 0] = 1.0
            scaling = "unit column norms (error standard deviations not given)"
        Ms = M / d
        _, sv, vt = np.linalg.svd(Ms, full_matrices=False)
        v = vt[-1]
        if abs(v[p]) < 1e-12 or sv[-1] >= sv[-2] * (1 - 1e-12):
            raise IdentifiabilityError("the total-least-squares problem has no unique solution "
                                       "(smallest singular value repeated or its vector has no output component)")
        A = Ms[:, :p]
        sa = float(np.linalg.svd(A, compute_uv=False)[-1])
        kappa = sa**2 / (sa**2 - sv[-1] ** 2) if sa > sv[-1] else float("inf")
        if not kappa <= TLS_MAX_AMPLIFICATION:
            snr = 1.0 / np.sqrt(kappa - 1.0) if np.isfinite(kappa) and kappa > 1 else 0.0
            raise IdentifiabilityError(
                f"TLS is ill-posed on these data: the scaled regressor's smallest singular value {sa:.5g} is within "
                f"{100 * (sa - sv[-1]) / sa:.2g} % of the smallest of [regressor, output] ({sv[-1]:.5g}), so TLS would "
                f"multiply the weakest parameter direction by {kappa:.3g} (its signal-to-error ratio under TLS's "
                f"error model is {snr:.2g}, below 1) and fit a near-collinearity of the regressor instead of the noise "
                f"({scaling}); use method = 'wls' or 'iv' (or, from Python, TLS(error_std=...) with the regressor columns' error scales)")
        x = -v[:p] / v[p]
        beta = x * d[p] / d[:p]
        dof = problem.n_total - p
        s2 = sv[-1] ** 2 / dof
        G = A.T @ A - sv[-1] ** 2 * np.eye(p)
        try:
            cov_x = s2 * (1 + x @ x) * np.linalg.inv(G)
        except np.linalg.LinAlgError:
            raise IdentifiabilityError("TLS covariance undefined: A^T A - s_min^2 I is singular") from None
        D = d[p] / d[:p]
        cov = cov_x * np.outer(D, D)
        rss = problem.rss_per_channel(beta)
        r = np.linalg.qr(A, mode="r")
        check_identifiable(r, problem.names)
        s = _Solve(beta=beta, R=r, c=np.zeros(p), rss=rss, scale=float(s2), cov=cov, dof=dof, cond=condition_number(r))
        solver = {"algorithm": "SVD of the column-scaled, whitened augmented factors", "weighting": self.weighting,
                  "column_scaling": scaling, "smallest_singular_values": sv[-2:].tolist(),
                  "regressor_smallest_singular_value": sa, "amplification": kappa}
        notes = ("TLS covariance is first-order asymptotic and assumes equal, independent errors in the scaled "
                 "regressor columns and outputs",)
        return _result(problem, "TLS", s, sigma, solver, notes)
