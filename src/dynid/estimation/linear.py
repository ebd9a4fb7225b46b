"""Linear least-squares estimators on the compressed problem: OLS and WLS.

All linear estimators share :func:`whitened_solve`: the per-channel factors are
scaled by ``sqrt(w_j)`` (whitening with a diagonal channel covariance), stacked and
reduced once more by QR; OLS is the case ``w_j = 1``. Covariance is computed in one
place:

.. math::

    \\hat\\beta = \\arg\\min \\sum_j w_j \\|y_j - W_j\\beta\\|^2, \\qquad
    \\mathrm{cov}(\\hat\\beta) = s^2 \\Big(\\sum_j w_j R_j^T R_j\\Big)^{-1}, \\qquad
    s^2 = \\frac{\\sum_j w_j \\,\\mathrm{RSS}_j(\\hat\\beta)}{N - p}.

WLS follows Gautier (1997) and Shang et al. 2009 (paper 001, Eqs. 10–16): OLS first;
the noise variance of each joint equation is
:math:`\\hat\\sigma_j^2 = \\|y_j - W_j\\hat\\beta_{OLS}\\|^2 / (n_j - p_j)` with
:math:`p_j` the number of parameters acting on joint ``j``; then the weighted solve
with :math:`w_j = 1/\\hat\\sigma_j^2`. With correct weights the scale :math:`s^2` is
close to 1 (it is reported).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg as sla

from dynid._typing import FloatArray
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult
from dynid.stats import condition_number

__all__ = ["OLS", "WLS", "whitened_solve", "check_identifiable", "gautier_noise_std"]

_RANK_RTOL = 1e-10


def check_identifiable(R: FloatArray, names: tuple[str, ...], rtol: float = _RANK_RTOL) -> None:
    """Raise :class:`IdentifiabilityError` naming the parameters the data do not determine.

    ``R`` is the triangular factor of the (whitened) stacked regressor. Columns are
    scaled to unit norm; a zero column, or a pivot of the column-pivoted QR below
    ``rtol``, marks a parameter whose column is zero or a combination of others.
    """
    norms = np.linalg.norm(R, axis=0)
    top = norms.max() if norms.size else 0.0
    if top == 0.0:
        raise IdentifiabilityError("no data: the regressor is zero", names)
    zero = np.flatnonzero(norms <= 1e-14 * top)
    bad: list[int] = list(zero)
    keep = np.setdiff1d(np.arange(R.shape[1]), zero)
    if keep.size:
        rs, piv = sla.qr(R[:, keep] / norms[keep], mode="r", pivoting=True)
        d = np.abs(np.diag(rs))
        rank = int(np.count_nonzero(d > rtol * d[0]))
        bad += [int(keep[i]) for i in piv[rank:]]
    if bad:
        bad_names = tuple(names[i] for i in sorted(bad))
        raise IdentifiabilityError(
            f"unidentifiable parameters with these data: {', '.join(bad_names)} "
            "(their regressor columns are zero or linear combinations of others; does every joint move?)",
            bad_names,
        )


@dataclasses.dataclass(frozen=True)
class _Solve:
    beta: FloatArray
    R: FloatArray  # p x p triangular factor of the whitened stacked regressor
    c: FloatArray  # whitened outputs projected on it: the fit minimizes ||R beta - c||
    rss: FloatArray  # per-channel RSS at beta (unweighted)
    scale: float
    cov: FloatArray
    dof: int
    cond: float


def whitened_solve(problem: RegressionProblem, weights: FloatArray, *, check: bool = True) -> _Solve:
    """Weighted least squares with per-channel weights on the compressed problem
    (``check=False`` skips the identifiability test, for a problem already checked)."""
    p = problem.n_params
    w = np.asarray(weights, dtype=float)
    if w.shape != (problem.n_channels,) or np.any(~np.isfinite(w)) or np.any(w <= 0):
        raise ValueError(f"channel weights must be {problem.n_channels} positive finite numbers, got {w}")
    sw = np.sqrt(w)
    A = (problem.R * sw[:, None, None]).reshape(-1, p)
    b = (problem.z * sw[:, None]).reshape(-1)
    q, r = np.linalg.qr(A, mode="reduced")
    if check:
        check_identifiable(r, problem.names)
    c = q.T @ b
    beta = sla.solve_triangular(r, c)
    rss = problem.rss_per_channel(beta)
    dof = problem.n_total - p
    if dof <= 0:
        raise InputError(f"fewer observations ({problem.n_total}) than parameters ({p})")
    scale = float(np.sum(w * rss) / dof)
    rinv = sla.solve_triangular(r, np.eye(p))
    cov = scale * (rinv @ rinv.T)
    return _Solve(beta=beta, R=r, c=c, rss=rss, scale=scale, cov=cov, dof=dof, cond=condition_number(r))


def _channel_noise_std(problem: RegressionProblem, rss: FloatArray) -> FloatArray:
    """Per-channel noise std from residuals: ``sqrt(RSS_j / (n_j - p_j))``."""
    dof_j = problem.n_obs - problem.channel_ranks()
    return np.sqrt(rss / np.maximum(dof_j, 1))


def gautier_noise_std(problem: RegressionProblem) -> FloatArray:
    """Per-joint noise std from OLS residuals (Gautier 1997), the WLS weights' source."""
    sigma = _channel_noise_std(problem, whitened_solve(problem, np.ones(problem.n_channels)).rss)
    if np.any(sigma <= 0):
        zero = [c for c, s in zip(problem.channel_names, sigma) if s <= 0]
        raise IdentifiabilityError(f"zero residual on channels {zero}: cannot weight by noise variance")
    return sigma


def _result(problem: RegressionProblem, method: str, s: _Solve, noise_std: FloatArray, solver: dict, notes: tuple[str, ...]) -> IdentificationResult:
    return IdentificationResult(
        method=method,
        names=problem.names,
        params=s.beta,
        cov_params=s.cov,
        dof=s.dof,
        scale=s.scale,
        channel_names=problem.channel_names,
        n_obs=problem.n_obs,
        rss_per_channel=s.rss,
        noise_std=noise_std,
        condition_number=s.cond,
        expressions=problem.expressions,
        solver=solver,
        provenance=dict(problem.meta),
        notes=notes,
    )


@dataclasses.dataclass(frozen=True, kw_only=True)
class OLS:
    """Ordinary least squares: ``min sum_j ||y_j - W_j beta||^2``.

    Covariance :math:`\\hat\\sigma^2 (W^T W)^{-1}` with the pooled residual variance
    (all channels assumed to share one noise level).
    """

    def fit(self, problem: RegressionProblem) -> IdentificationResult:
        s = whitened_solve(problem, np.ones(problem.n_channels))
        noise = _channel_noise_std(problem, s.rss)
        return _result(problem, "OLS", s, noise, {"algorithm": "QR of stacked per-channel factors"}, ())


@dataclasses.dataclass(frozen=True, kw_only=True)
class WLS:
    """Weighted least squares with per-joint noise variances from OLS residuals (Gautier).

    Parameters
    ----------
    noise_std : array of shape (n_ch,), optional
        Known per-channel noise standard deviations; when given they set the weights
        directly instead of the OLS residual estimate.
    nominal : array of shape (p,), optional
        Nominal parameter values weighting the observation matrix, :math:`Z_{ww} = Z_w
        \\mathrm{diag}(\\bar\\phi)` (paper 001 Eq. 17). The solve runs in the scaled variables
        :math:`\\psi = \\phi / \\bar\\phi` and the result reports :math:`\\mathrm{cond}(Z_{ww})`: 1 means
        every parameter is estimated with the same *relative* accuracy. The least-squares
        estimate itself is invariant to this column scaling (exactly so in exact arithmetic);
        what the weighting changes is the condition number, i.e. the excitation criterion
        ``weighted_cond`` of :func:`dynid.excitation.optimality.criteria`. Parameters with a
        zero nominal value keep unit weight (named in the notes).
    """

    noise_std: tuple[float, ...] | None = None
    nominal: tuple[float, ...] | None = None

    def fit(self, problem: RegressionProblem) -> IdentificationResult:
        if self.noise_std is not None:
            sigma = np.asarray(self.noise_std, dtype=float)
            if sigma.shape != (problem.n_channels,) or np.any(sigma <= 0):
                raise ValueError(f"noise_std must be {problem.n_channels} positive numbers")
            source = "given"
        else:
            sigma = gautier_noise_std(problem)
            source = "OLS residuals (Gautier)"
        notes = [f"weights 1/sigma_j^2 per channel; sigma_j from {source}"]
        solver = {"algorithm": "QR of whitened stacked per-channel factors", "weights_from": source, "sigma": sigma.tolist()}
        if self.nominal is None:
            s = whitened_solve(problem, 1.0 / sigma**2)
            return _result(problem, "WLS", s, sigma, solver, tuple(notes))
        nom = np.asarray(self.nominal, dtype=float)
        if nom.shape != (problem.n_params,) or not np.all(np.isfinite(nom)):
            raise InputError(f"nominal must be {problem.n_params} finite values (one per parameter), got shape {nom.shape}")
        scale = np.where(nom != 0, np.abs(nom), 1.0)
        scaled = problem.replace(factors=problem.factors * np.append(scale, 1.0)[None, None, :], standard=None, cross=None,
                                 cross_partial=())
        w_unscaled = whitened_solve(problem, 1.0 / sigma**2).cond  # also the identifiability check
        s = whitened_solve(scaled, 1.0 / sigma**2, check=False)
        s = dataclasses.replace(s, beta=s.beta * scale, cov=s.cov * np.outer(scale, scale), rss=problem.rss_per_channel(s.beta * scale))
        solver.update(nominal_weighting=True, cond_Zw=w_unscaled, cond_Zww=s.cond)
        zero = [n for n, v in zip(problem.names, nom) if v == 0]
        notes.append(f"observation matrix weighted by nominal values (Shang 2009 Eq. 17): cond(Z_ww) = {s.cond:.4g} "
                     f"against cond(Z_w) = {w_unscaled:.4g}")
        if zero:
            notes.append(f"zero nominal value, unit weight: {', '.join(zero)}")
        return _result(problem, "WLS", s, sigma, solver, tuple(notes))
