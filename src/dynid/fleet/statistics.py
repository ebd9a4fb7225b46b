"""Fleet statistics on estimates with their own covariances (pure numpy/scipy).

* :func:`fuse`: the logs of one robot pooled by information fusion, which equals the weighted
  least squares of their stacked compressed factors.
* :func:`spread`: median and robust spread of each parameter over the robots.
* :func:`outliers`: each robot's Mahalanobis distance to the other robots' median, against the
  largest distance of simulated homogeneous fleets.
* :func:`trend` and :func:`change_point`: drift of a parameter over dated logs.

Every test is stated with its null hypothesis and the distribution its threshold comes from; all
reject at most ``alpha`` of the time under that null (Bonferroni where several are made at once).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy import stats as _st

from dynid.errors import IdentifiabilityError, InputError

__all__ = ["Fused", "fuse", "information", "scatter_factors", "spread", "Outlier", "outliers", "OUTLIER_SEED", "Trend", "trend", "ChangePoint",
           "change_point", "MAD_TO_STD"]

MAD_TO_STD = 1.482602218505602
"""The median absolute deviation times this is the standard deviation of a normal sample (1 / Phi^-1(3/4))."""


def _scaled_inverse(cov: np.ndarray, what: str) -> np.ndarray:
    """``cov^-1`` through its correlation matrix (base-parameter variances span many decades):
    Cholesky of ``D^-1 C D^-1``; refused when ``C`` is not positive definite."""
    cov = np.asarray(cov, float)
    d = np.sqrt(np.diag(cov))
    if not np.all(np.isfinite(d)) or not np.all(d > 0):
        raise IdentifiabilityError(f"{what}: a variance is zero or not finite; the covariance cannot be inverted")
    corr = cov / np.outer(d, d)
    try:
        L = np.linalg.cholesky(corr)
    except np.linalg.LinAlgError:
        raise IdentifiabilityError(f"{what}: the covariance is not positive definite (a parameter combination the "
                                   "log does not excite)") from None
    inv_l = np.linalg.solve(L, np.eye(len(d)))
    return (inv_l.T @ inv_l) / np.outer(d, d)


def information(cov: np.ndarray, what: str = "covariance") -> np.ndarray:
    """The information matrix ``cov^-1`` (symmetric), computed on the correlation scale."""
    info = _scaled_inverse(cov, what)
    return 0.5 * (info + info.T)


@dataclasses.dataclass(frozen=True)
class Fused:
    """The pooled estimate of several logs: ``params`` (p,), ``cov`` (p, p) (the logs' covariances
    as reported: ``(sum C_i^-1)^-1``), ``cov_scaled`` (with the logs' covariances scaled by the
    between-log scatter factors, :func:`scatter_factors`; equal to ``cov`` without them), and the
    homogeneity statistic ``chi2`` = sum_i (theta_i - theta)^T C_i^-1 (theta_i - theta) with ``dof`` =
    (m - 1) p degrees of freedom and its ``p_value`` (the logs estimate one parameter vector)."""

    params: np.ndarray
    cov: np.ndarray
    cov_scaled: np.ndarray
    chi2: float
    dof: int
    p_value: float


def fuse(estimates: Sequence[np.ndarray], covs: Sequence[np.ndarray], factors: np.ndarray | None = None) -> Fused:
    """Information fusion of independent estimates of one parameter vector.

    Notes
    -----
    Log ``i`` gives the weighted least-squares estimate of its compressed, whitened problem
    ``R_i theta = z_i`` (``R_i`` upper triangular from the QR of its weighted regressor,
    ``z_i = Q_i^T y_i``): ``theta_i = R_i^-1 z_i`` with ``C_i = (R_i^T R_i)^-1`` (paper 001,
    Eqs. 14-16; paper 002 Eq. 21 with a block-diagonal noise covariance). Stacking the logs' factors,
    ``[R_1; ...; R_m] theta = [z_1; ...; z_m]``, has the normal equations

    .. math:: (\\sum_i R_i^T R_i)\\,\\theta = \\sum_i R_i^T z_i = \\sum_i C_i^{-1}\\theta_i ,

    so the stacked estimate is the information-weighted mean
    ``theta = (sum C_i^-1)^-1 sum C_i^-1 theta_i`` with covariance ``(sum C_i^-1)^-1``: fusing the
    estimates *is* the WLS of the stacked factors, exactly, when every log weighs its rows by its
    own noise variances (as each log's own identification did) and the logs share one set of base
    parameters. Each ``C_i`` must be invertible: every log must excite every base parameter (a log
    that does not is refused here; the stacked problem of ``[[data]]`` would accept it).

    ``factors`` (p,): when the logs' errors are larger than their covariances say, by ``f_j`` on
    parameter ``j`` (``C_i -> F C_i F``, ``F = diag(f)``), the same estimate has the sandwich covariance
    ``A^-1 (sum_i C_i^-1 F C_i F C_i^-1) A^-1`` with ``A = sum_i C_i^-1`` (``cov_scaled``); the
    estimate itself stays the stacked WLS.
    """
    if len(estimates) != len(covs) or not estimates:
        raise InputError(f"fuse: {len(estimates)} estimates and {len(covs)} covariances")
    thetas = [np.asarray(t, float) for t in estimates]
    infos = [information(c, f"estimate {i}") for i, c in enumerate(covs)]
    total = sum(infos)
    cov = information(total, "the sum of the information matrices")  # (sum C_i^-1)^-1
    theta = cov @ sum(info @ t for info, t in zip(infos, thetas))
    chi2 = float(sum((t - theta) @ info @ (t - theta) for info, t in zip(infos, thetas)))
    dof = (len(thetas) - 1) * theta.size
    cov = 0.5 * (cov + cov.T)
    scaled = cov
    if factors is not None:
        f = np.asarray(factors, float)
        middle = sum(info @ (np.asarray(c, float) * np.outer(f, f)) @ info for info, c in zip(infos, covs))
        scaled = cov @ middle @ cov
        scaled = 0.5 * (scaled + scaled.T)
    return Fused(params=theta, cov=cov, cov_scaled=scaled, chi2=chi2, dof=dof,
                 p_value=float(_st.chi2.sf(chi2, dof)) if dof > 0 else float("nan"))


def scatter_factors(groups: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, int]:
    """Per parameter, how much more the logs of one robot scatter than their covariances say,
    taken over the fleet: ``(f, k)`` with ``f`` (p,) >= 1 and ``k`` the robots it comes from.

    Notes
    -----
    ``groups``: per robot, its logs' estimates ``x`` (m, p) and variances ``v`` (m, p). For robot
    ``r`` and parameter ``j``, ``q_rj = sum_i (x_ij - xbar_rj)^2 / v_ij`` about the
    inverse-variance weighted mean is ``chi2(m_r - 1)`` when the variances are right and the robot
    did not change. Reported variances miss what differs systematically between runs (the
    processing's bias depends on the excitation; unmodelled friction), so ``q`` is often larger. The
    factor is ``f_j^2 = max(1, median_r q_rj / med(chi2(m_r - 1)))``: the median over robots, so one
    robot that really changed (wear) does not set it, each ``q`` divided by the median of its
    chi-square (a consistent estimate of the variance factor). Needs 3 robots with 2 logs or more;
    with fewer, ``f = 1`` and ``k`` says so.
    """
    ratios = []
    for x, v in groups:
        x, v = np.asarray(x, float), np.asarray(v, float)
        if x.shape[0] < 2:
            continue
        w = 1.0 / v
        mean = np.sum(w * x, axis=0) / np.sum(w, axis=0)
        q = np.sum(w * (x - mean) ** 2, axis=0)
        ratios.append(q / _st.chi2.median(x.shape[0] - 1))
    p = np.shape(groups[0][0])[1] if groups else 0
    if len(ratios) < 3:
        return np.ones(p), len(ratios)
    return np.sqrt(np.maximum(1.0, np.median(np.array(ratios), axis=0))), len(ratios)


def spread(estimates: np.ndarray) -> dict[str, np.ndarray]:
    """Per parameter over the robots (rows of ``estimates``, (r, p); NaN rows ignored): ``median``,
    ``std`` (robust: 1.4826 x the median absolute deviation), ``q25``, ``q75``, ``min``, ``max``."""
    x = np.asarray(estimates, float)
    x = x[np.all(np.isfinite(x), axis=1)]
    if x.shape[0] == 0:
        nan = np.full(np.shape(estimates)[1], np.nan)
        return {k: nan for k in ("median", "std", "q25", "q75", "min", "max")}
    med = np.median(x, axis=0)
    return {"median": med, "std": MAD_TO_STD * np.median(np.abs(x - med), axis=0),
            "q25": np.quantile(x, 0.25, axis=0), "q75": np.quantile(x, 0.75, axis=0),
            "min": x.min(axis=0), "max": x.max(axis=0)}


@dataclasses.dataclass(frozen=True)
class Outlier:
    """One robot against the others: the squared Mahalanobis distance ``d2`` with ``dof``
    parameters, the ``threshold`` it is compared with (the ``1 - alpha`` quantile of the largest
    distance of a homogeneous fleet, simulated), ``chi2_threshold`` (``chi2_p(1 - alpha / n)``, what
    the threshold tends to with many robots and honest spreads; for reference only), its
    family-wise ``p_value`` and the verdict; ``contributions`` (p,): the squared standardized
    distance of each parameter alone."""

    d2: float
    dof: int
    threshold: float
    chi2_threshold: float
    p_value: float
    outlier: bool
    contributions: np.ndarray


MAD_SE2 = 1.3605
"""``n`` times the relative variance of 1.4826 x the median absolute deviation of ``n`` normal values,
as an estimate of their standard deviation (asymptotic: ``1 / (4 f^2 q^2)`` with ``q = Phi^-1(3/4)`` and
``f = 2 phi(q)`` the density of ``|X|`` at its median)."""

OUTLIER_SEED = 3535
"""Seed of the simulated null distribution of the outlier distances: a rerun gives the same thresholds."""


def _loo_order(s: np.ndarray, rank: np.ndarray, j: int) -> np.ndarray:
    """(B, n, p): for each robot ``r``, the ``j``-th smallest value of the *other* robots, from the
    fleets sorted along axis 1 (``s``) and each robot's rank there (``rank``)."""
    return np.where(j < rank, s[:, j][:, None], s[:, j + 1][:, None])


def _loo_median(v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leave-one-out medians of ``v`` (B, n, p) along the robots: (B, n, p) the median of the
    other ``n - 1`` robots for each robot, with one sort (no loop over the robots). Also returns the
    sorted fleets and the ranks."""
    n = v.shape[1]
    order = np.argsort(v, axis=1, kind="stable")
    s = np.take_along_axis(v, order, axis=1)
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.broadcast_to(np.arange(n)[None, :, None], order.shape), axis=1)
    k = n - 1
    if k % 2:
        med = _loo_order(s, rank, (k - 1) // 2)
    else:
        med = 0.5 * (_loo_order(s, rank, k // 2 - 1) + _loo_order(s, rank, k // 2))
    return med, s, rank


def _loo_d2(x: np.ndarray, covs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leave-one-out squared distances of every robot in each fleet ``x`` (B, n, p), robot ``r``'s
    own covariance ``covs[r]``: (B, n) ``d2``, (B, n, p) the differences to the others' median and
    (B, n, p) the diagonal of each total covariance (:func:`outliers`, Notes)."""
    _, n, p = x.shape
    k = n - 1
    ref, s, rank = _loo_median(x)
    # the median absolute deviation of the others about their own median: their median takes at most 3
    # values per fleet and parameter (by where the left-out robot ranks), so 2 or 3 leave-one-out medians
    if k % 2:
        m = (k - 1) // 2
        cands, sel = [s[:, m + 1], s[:, m]], (rank > m).astype(int)
    else:
        h = k // 2
        cands = [0.5 * (s[:, h] + s[:, h + 1]), 0.5 * (s[:, h - 1] + s[:, h + 1]), 0.5 * (s[:, h - 1] + s[:, h])]
        sel = (rank >= h).astype(int) + (rank > h).astype(int)
    mad = np.zeros_like(x)
    for i, c in enumerate(cands):
        mad = np.where(sel == i, _loo_median(np.abs(x - c[:, None]))[0], mad)
    delta = x - ref
    total = covs[None] + ((1.0 + np.pi / (2 * k)) * (MAD_TO_STD * mad) ** 2)[..., None] * np.eye(p)
    d = np.sqrt(np.einsum("...jj->...j", total))
    z = delta / d
    y = np.linalg.solve(total / (d[..., :, None] * d[..., None, :]), z[..., None])[..., 0]
    return np.einsum("...j,...j->...", z, y), delta, d**2


def outliers(estimates: np.ndarray, covs: np.ndarray, alpha: float, draws: int | None = None) -> list[Outlier | None]:
    """Each robot's distance to the fleet, with its own covariance plus the fleet's spread.

    Notes
    -----
    For robot ``r`` the reference is the component-wise median ``m_r`` of the *other* robots'
    estimates (leave-one-out, so an outlier does not pull its own reference), and

    .. math:: d_r^2 = (\\theta_r - m_r)^T \\left(C_r + (1 + \\tfrac{\\pi}{2 k}) S_r\\right)^{-1} (\\theta_r - m_r)

    with ``C_r`` the robot's own covariance, ``S_r = diag(s^2)`` the robust spread of the ``k``
    other robots (``s`` = 1.4826 x their median absolute deviation per parameter: the real
    robot-to-robot variation, their estimation noise included) and ``pi / (2 k)`` the variance of
    a median of ``k`` normal values relative to one value.

    Null hypothesis: the robots are drawn from one population: independent normal variation per
    parameter about the fleet median ``m`` with standard deviation ``tau``, plus each robot's own
    estimation error ``N(0, C_i)``. With many robots ``d_r^2`` is then ``chi2(p)``; with few,
    ``S_r`` is itself a noisy estimate (a median absolute deviation of ``k`` values, which can come
    out near zero) and ``d_r^2`` has a much heavier tail: with 8 robots and 10 parameters the
    chi-square threshold ``chi2_p(1 - alpha / n)`` flags a robot of a homogeneous fleet almost
    every time when the robots' spread dominates their own covariances. The threshold is therefore
    simulated (a parametric bootstrap, Westfall and Young's single-step max-T): ``draws`` fleets
    from that null (fixed seed :data:`OUTLIER_SEED`, so a rerun gives the same bytes), the whole
    procedure (medians, spreads, distances) repeated on each, and the threshold is the
    ``1 - alpha`` quantile of the largest ``d^2`` of a simulated fleet. A robot is flagged when
    ``d_r^2`` exceeds it; its ``p_value`` is the fraction of simulated fleets whose largest distance
    reaches ``d_r^2`` (``(1 + count) / (draws + 1)``), family-wise over the robots.

    ``tau`` is not known. Its moment estimate is ``max(0, s_all^2 - median_i C_i,jj)`` (``s_all``
    the robust spread of all ``n`` robots), which has a relative standard error of about
    ``sqrt(1.36 / n)`` (:data:`MAD_SE2`). The tail of ``d^2`` grows with ``tau`` relative to the own
    covariances (a larger population spread makes the near-zero spreads of ``S_r`` matter more), so
    the simulation uses its one-sided 95 % upper bound, ``tau = (1 + 1.645 sqrt(1.36 / n))`` times
    the estimate: the test is then conservative, a homogeneous fleet has any robot flagged at most
    ``alpha`` of the time (8 robots, 10 parameters, ``alpha`` = 0.1, 300 simulated fleets each:
    0.077 when the spread dominates the covariances, 0.030 when they are equal, 0.007 when the
    covariances dominate; the chi-square threshold: 0.99, 0.27, 0.01; with the plain estimate of
    ``tau``: 0.13, 0.15, 0.03, too many). ``draws`` defaults to ``max(1000, 20 / alpha)`` (at most
    20 000): some 20 simulated maxima beyond the threshold. The leave-one-out medians come from one
    sort per fleet, not a loop over the robots: 20 robots with 15 parameters take 0.2-0.5 s (2 cores).

    The spread is diagonal (a few robots cannot estimate a p x p population covariance):
    correlated variation between robots is not modelled. Robots with a non-finite estimate or
    covariance are left out (``None``); fewer than 3 usable robots (2 others to take a spread
    from): all ``None``.
    """
    x, c = np.asarray(estimates, float), np.asarray(covs, float)
    n, p = x.shape
    ok = [i for i in range(n) if np.all(np.isfinite(x[i])) and np.all(np.isfinite(c[i]))]
    if len(ok) < 3:
        return [None] * n
    xo, co, m_ok = x[ok], c[ok], len(ok)
    draws = int(draws if draws is not None else min(20000, max(1000, np.ceil(20.0 / alpha))))
    # the null population, fitted to every usable robot
    all_spread = spread(xo)
    tau = np.sqrt(np.maximum(0.0, all_spread["std"] ** 2 - np.median(np.einsum("ijj->ij", co), axis=0)))
    tau = tau * (1.0 + _st.norm.ppf(0.95) * np.sqrt(MAD_SE2 / m_ok))  # its one-sided 95 % upper bound
    dg = np.sqrt(np.einsum("ijj->ij", co))
    roots = dg[:, :, None] * np.linalg.cholesky(co / (dg[:, :, None] * dg[:, None, :]) + 1e-12 * np.eye(p))
    rng = np.random.default_rng(OUTLIER_SEED)
    chunk = max(1, min(draws, 2_000_000 // (m_ok * p * p)))  # fleets at a time: the batched solves' memory bounded
    maxima = []
    for start in range(0, draws, chunk):
        b = min(chunk, draws - start)
        xs = (all_spread["median"] + tau * rng.standard_normal((b, m_ok, p))
              + np.einsum("rjk,brk->brj", roots, rng.standard_normal((b, m_ok, p))))
        maxima.append(_loo_d2(xs, co)[0].max(axis=1))
    null = np.sort(np.concatenate(maxima))
    thr = float(np.quantile(null, 1.0 - alpha))
    chi2_thr = float(_st.chi2.ppf(1.0 - alpha / m_ok, p))
    d2, delta, diag = (a[0] for a in _loo_d2(xo[None], co))
    out: list[Outlier | None] = [None] * n
    for i, r in enumerate(ok):
        count = null.size - np.searchsorted(null, d2[i], side="left")  # simulated maxima >= d2
        out[r] = Outlier(d2=float(d2[i]), dof=p, threshold=thr, chi2_threshold=chi2_thr,
                         p_value=float((1 + count) / (null.size + 1)), outlier=bool(d2[i] > thr),
                         contributions=delta[i] ** 2 / diag[i])
    return out


@dataclasses.dataclass(frozen=True)
class Trend:
    """A weighted linear trend ``x = a + b (t - t0)`` of one parameter over dated logs: ``slope``
    [parameter unit per day] with its standard error, ``interval`` (1 - alpha), the two-sided
    ``p_value`` of ``slope = 0``, the residual ``chi2`` with ``dof`` = n - 2, and ``scale`` (>= 1:
    the factor the standard error was inflated by when the residuals scatter more than the
    reported variances say); ``t0`` the weighted mean date [days]."""

    slope: float
    se: float
    interval: tuple[float, float]
    p_value: float
    intercept: float
    t0: float
    chi2: float
    dof: int
    scale: float


def trend(t: np.ndarray, x: np.ndarray, var: np.ndarray, alpha: float) -> Trend:
    """Weighted least-squares line through ``(t_i, x_i)`` with weights ``1 / var_i``.

    Notes
    -----
    With ``w_i = 1/var_i``, ``t0 = sum w t / sum w``: ``b = sum w (t - t0) x / sum w (t - t0)^2``,
    ``var(b) = 1 / sum w (t - t0)^2`` when the ``var_i`` are the estimates' true variances (Aitken's
    generalized least squares; the per-log estimates of one robot are independent). The standard
    error is multiplied by ``scale = sqrt(max(1, chi2 / (n - 2)))`` (the Birge ratio): an
    interval never narrower than the reported variances give, wider when the estimates scatter
    more about the line than they say. The test of ``b = 0`` uses the normal distribution:
    exact with true variances and ``scale = 1``, conservative otherwise.
    """
    t, x, var = (np.asarray(a, float) for a in (t, x, var))
    if t.size < 3:
        raise InputError(f"trend: {t.size} dated estimates; a trend with an interval needs at least 3")
    if np.ptp(t) <= 0:
        raise InputError("trend: every estimate has the same date")
    w = 1.0 / var
    t0 = float(np.sum(w * t) / np.sum(w))
    dt = t - t0
    sxx = float(np.sum(w * dt**2))
    a = float(np.sum(w * x) / np.sum(w))
    b = float(np.sum(w * dt * x) / sxx)
    chi2 = float(np.sum(w * (x - a - b * dt) ** 2))
    dof = t.size - 2
    scale = float(np.sqrt(max(1.0, chi2 / dof)))
    se = scale / np.sqrt(sxx)
    z = _st.norm.ppf(1.0 - alpha / 2)
    return Trend(slope=b, se=float(se), interval=(b - z * se, b + z * se), p_value=float(2 * _st.norm.sf(abs(b) / se)),
                 intercept=a, t0=t0, chi2=chi2, dof=dof, scale=scale)


@dataclasses.dataclass(frozen=True)
class ChangePoint:
    """The largest standardized shift of one parameter's mean between consecutive dated logs:
    ``statistic`` = max_k Z_k^2, ``after``: the index (in date order) of the first log after the
    shift, ``shift`` its size with standard error ``se``, ``p_value`` (Bonferroni bound over the
    ``n - 1`` possible splits)."""

    statistic: float
    after: int
    shift: float
    se: float
    p_value: float
    scale: float = 1.0


def change_point(x: np.ndarray, var: np.ndarray) -> ChangePoint:
    """Test for one step in the mean of independent estimates ``x`` (in date order) with known variances.

    Notes
    -----
    For each split ``k = 1..n-1``, ``Z_k = (xbar_after - xbar_before) / sqrt(v_before + v_after)``
    with the inverse-variance weighted means of the two sides and their variances
    ``v = 1 / sum w``. ``Z_k^2`` is the likelihood-ratio statistic of "a step after log k" against
    "one mean" for normal estimates with known variances; the statistic is the maximum over ``k``
    (Hawkins 1977, "Testing a sequence of observations for a shift in location", JASA 72:180-186;
    Worsley 1979 for the maximum's null distribution). Under the null (one mean) each ``Z_k`` is
    standard normal, so ``P(max Z_k^2 > s) <= (n - 1) P(chi2_1 > s)`` (Bonferroni): the reported
    p-value is that bound, conservative (the ``Z_k`` are positively correlated), and the test
    rejects at most ``alpha`` of the time under the null. A gradual drift raises it too: the
    trend (:func:`trend`) says how fast, the change point where the largest step is.

    As for the trend, the variances are multiplied by ``scale^2 = max(1, chi2_k / (n - 2))``, the
    residual chi-square of the two-mean fit at the chosen split over its degrees of freedom (with
    ``n >= 3``): estimates that scatter more than their variances say within the two segments do
    not make a step out of noise; a real step leaves small residuals and keeps ``scale = 1``. The
    scale is never below 1, so the test stays conservative.
    """
    x, var = np.asarray(x, float), np.asarray(var, float)
    n = x.size
    if n < 2:
        raise InputError(f"change_point: {n} estimates; a change needs at least 2")
    w = 1.0 / var
    cw, cwx = np.cumsum(w), np.cumsum(w * x)
    best = (-1.0, 1, 0.0, 0.0)
    for k in range(1, n):
        wb, wa = cw[k - 1], cw[-1] - cw[k - 1]
        mb, ma = cwx[k - 1] / wb, (cwx[-1] - cwx[k - 1]) / wa
        se = float(np.sqrt(1.0 / wb + 1.0 / wa))
        z2 = float(((ma - mb) / se) ** 2)
        if z2 > best[0]:
            best = (z2, k, float(ma - mb), se)
    s, k, shift, se = best
    scale = 1.0
    if n >= 3:
        mb, ma = cwx[k - 1] / cw[k - 1], (cwx[-1] - cwx[k - 1]) / (cw[-1] - cw[k - 1])
        resid = np.sum(w[:k] * (x[:k] - mb) ** 2) + np.sum(w[k:] * (x[k:] - ma) ** 2)
        scale = float(np.sqrt(max(1.0, resid / (n - 2))))
    s, se = s / scale**2, se * scale
    return ChangePoint(statistic=s, after=k, shift=shift, se=se, p_value=float(min(1.0, (n - 1) * _st.chi2.sf(s, 1))),
                       scale=scale)
