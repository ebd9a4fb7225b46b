"""Small statistics helpers on arrays (pure NumPy/SciPy).

Besides the basic helpers: the confidence ellipsoid of a parameter set (paper 002,
Eq. 29), the correlation matrix of the estimates and its condition number (paper 004,
Eq. 11), and the prediction metrics of the papers: the relative absolute error
:math:`\\varepsilon_{RA}` and the average parameter error :math:`\\varepsilon_{AV}`
(paper 000, Eqs. 33–34) and the torque RSME (paper 001, Eq. 21).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as _sla
from scipy import special as _sp  # scipy.stats would add about a second of imports for two quantiles

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = [
    "nearest_distances_thinned",
    "t_quantile",
    "condition_number",
    "relative_std",
    "rmse",
    "tracking_errors",
    "chi2_radius",
    "ellipsoid_statistic",
    "correlation_matrix",
    "correlation_condition_number",
    "relative_absolute_error",
    "average_error",
    "t_rsme",
    "nearest_distances",
    "REPEAT_THRESHOLD",
]

REPEAT_THRESHOLD = 0.05
"""Median nearest-state distance (in training standard deviations) below which a validation
motion repeats the training motion (see :func:`nearest_distances`)."""


def t_quantile(alpha: float, dof: int) -> float:
    """Two-sided Student-t quantile ``t_{1-alpha/2}(dof)`` (normal when dof is huge)."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    return float(_sp.stdtrit(max(int(dof), 1), 1 - alpha / 2))  # what scipy.stats.t.ppf evaluates


def condition_number(a: FloatArray) -> float:
    """2-norm condition number (ratio of extreme singular values); inf when singular."""
    s = np.linalg.svd(np.asarray(a, dtype=float), compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def relative_std(values: FloatArray, std: FloatArray) -> FloatArray:
    """Relative standard deviation in percent, ``100 * std / |value|`` (inf for zero values)."""
    values = np.abs(np.asarray(values, dtype=float))
    std = np.asarray(std, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * std / values
    return np.where(values == 0, np.inf, out)


def rmse(residuals: FloatArray) -> FloatArray:
    """Root-mean-square over axis 0."""
    r = np.asarray(residuals, dtype=float)
    return np.sqrt(np.mean(r**2, axis=0))


def tracking_errors(reference: FloatArray, actual: FloatArray) -> dict[str, FloatArray | float]:
    """Tracking metrics of a path, arrays (n, n_axes) [m or rad].

    Returns ``rms_per_axis`` (root mean square error of each axis), ``max_abs_per_axis`` and
    ``p_rsme``: :math:`\\sqrt{\\tfrac1r\\sum_m \\|x_d(m) - x(m)\\|^2}` over all axes, the
    position RSME of Shang et al. 2009, Eq. 23 (there with the x, y of the end-effector).
    """
    ref = np.atleast_2d(np.asarray(reference, dtype=float))
    act = np.atleast_2d(np.asarray(actual, dtype=float))
    if ref.shape != act.shape:
        raise InputError(f"reference {ref.shape} and actual {act.shape} differ in shape")
    e = ref - act
    return {
        "rms_per_axis": np.sqrt(np.mean(e**2, axis=0)),
        "max_abs_per_axis": np.abs(e).max(axis=0),
        "p_rsme": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
    }


# ---------------------------------------------------------------------- confidence ellipsoid
def chi2_radius(n_params: int, alpha: float = 0.05) -> float:
    """Squared radius :math:`\\chi^2_{n_p,\\,1-\\alpha}` of the ``100(1-alpha)`` % confidence ellipsoid.

    Parameters
    ----------
    n_params : int
        Dimension :math:`n_p` of the parameter vector (degrees of freedom of the
        :math:`\\chi^2` distribution), at least 1.
    alpha : float
        Level in (0, 1); 0.05 gives the 95 % ellipsoid.

    Returns
    -------
    float
        The :math:`1-\\alpha` quantile of :math:`\\chi^2(n_p)`.

    Notes
    -----
    Abdellatif & Heimann (paper 002), Eq. 29:

    .. math::

        \\mathcal E_\\alpha = \\{p : (p - \\hat p)^T P^{-1} (p - \\hat p) \\le \\chi^2_\\alpha(n_p)\\},

    where the paper's :math:`\\chi^2_\\alpha` is the value exceeded with probability
    :math:`\\alpha` (36.42 for :math:`n_p = 24`, :math:`\\alpha = 5\\%`, paper 002 §4).
    The :math:`\\chi^2` law holds for a known covariance :math:`P` (Gauss–Markov); with
    the noise scale estimated from :math:`\\nu` residual degrees of freedom the exact
    quantile is :math:`n_p F_{n_p,\\nu,1-\\alpha}`, which tends to the :math:`\\chi^2` one as
    :math:`\\nu` grows (identification logs have :math:`\\nu` in the thousands).
    """
    n = int(n_params)
    if n != n_params or n < 1:
        raise InputError(f"n_params must be a positive integer, got {n_params!r}")
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha}")
    return float(2.0 * _sp.gammaincinv(n / 2.0, 1.0 - alpha))  # what scipy.stats.chi2.ppf evaluates


def ellipsoid_statistic(estimate: FloatArray, reference: FloatArray, cov: FloatArray) -> FloatArray | float:
    """Mahalanobis statistic :math:`(\\hat\\theta - \\theta)^T \\Sigma^{-1} (\\hat\\theta - \\theta)`.

    Parameters
    ----------
    estimate : array, shape (p,) or (k, p)
        One estimate, or ``k`` estimates (one per row, e.g. repeated trials).
    reference : array, shape (p,)
        The point tested (true or nominal parameters).
    cov : array, shape (p, p)
        Covariance :math:`\\Sigma` of the estimate, symmetric positive definite.

    Returns
    -------
    float or array of shape (k,)
        The statistic; it follows :math:`\\chi^2(p)` when the estimate is Gaussian with
        mean ``reference`` and covariance ``cov``. The reference lies inside the
        ``100(1-alpha)`` % confidence ellipsoid iff the statistic is at most
        :func:`chi2_radius` ``(p, alpha)`` (paper 002, Eq. 29; Fig. 9 plots it per trial).

    Notes
    -----
    Computed with a Cholesky factor :math:`\\Sigma = L L^T` as :math:`\\|L^{-1} d\\|^2`
    (no explicit inverse). A covariance that is not positive definite raises
    :class:`~dynid.errors.InputError`.
    """
    est = np.asarray(estimate, dtype=float)
    ref = np.asarray(reference, dtype=float)
    S = np.asarray(cov, dtype=float)
    if S.ndim != 2 or S.shape[0] != S.shape[1]:
        raise InputError(f"covariance must be a square matrix, got shape {S.shape}")
    p = S.shape[0]
    if ref.shape != (p,):
        raise InputError(f"reference has shape {ref.shape}, the covariance is {S.shape}")
    if est.shape[-1:] != (p,) or est.ndim > 2:
        raise InputError(f"estimate has shape {est.shape}, expected ({p},) or (k, {p})")
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(est)) and np.all(np.isfinite(ref))):
        raise InputError("estimate, reference or covariance contain NaN/inf")
    try:
        L = np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        raise InputError(f"covariance ({p}x{p}) is singular or not positive definite") from None
    d = (est - ref).T  # (p,) or (p, k)
    u = _sla.solve_triangular(L, d, lower=True)
    out = np.sum(u**2, axis=0)
    return float(out) if est.ndim == 1 else out


# ---------------------------------------------------------------------- correlation
def correlation_matrix(cov: FloatArray) -> FloatArray:
    """Correlation coefficients of the estimates, :math:`\\varrho_{ij} = P_{ij}/\\sqrt{P_{ii}P_{jj}}`.

    Parameters
    ----------
    cov : array, shape (p, p)
        Covariance :math:`P` of the estimates; every variance must be positive.

    Returns
    -------
    array, shape (p, p)
        Symmetric, unit diagonal, entries in [-1, 1] (paper 004, Eq. 11).
    """
    P = np.asarray(cov, dtype=float)
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise InputError(f"covariance must be a square matrix, got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise InputError("covariance contains NaN/inf")
    var = np.diag(P)
    bad = np.flatnonzero(var <= 0)
    if bad.size:
        raise InputError(f"covariance has non-positive variances at indices {bad.tolist()}: no correlation defined")
    s = np.sqrt(var)
    rho = 0.5 * (P + P.T) / np.outer(s, s)
    np.fill_diagonal(rho, 1.0)
    return np.clip(rho, -1.0, 1.0)


def correlation_condition_number(cov: FloatArray) -> float:
    """Condition number :math:`\\upsilon = \\mathrm{cond}(\\varrho)` of the correlation matrix.

    Parameters
    ----------
    cov : array, shape (p, p)
        Covariance of the estimates.

    Returns
    -------
    float
        Ratio of the extreme singular values (for the symmetric positive semidefinite
        :math:`\\varrho`, of the extreme eigenvalues); 1 for uncorrelated estimates,
        ``inf`` when :math:`\\varrho` is singular.

    Notes
    -----
    Abdellatif & Heimann (paper 004), Eq. 11 and the text after it: since
    :math:`\\varrho` has unit diagonal whatever the units and sizes of the parameters,
    its condition number compares models of different dimensions and is the criterion
    for choosing the friction structure (a lower :math:`\\upsilon` means less
    correlated, better separable parameters). Unlike the condition number of the
    regressor it does not depend on the parameter scaling.
    """
    return condition_number(correlation_matrix(cov))


# ---------------------------------------------------------------------- prediction metrics
def _paired(measured: FloatArray, predicted: FloatArray) -> tuple[FloatArray, FloatArray]:
    a = np.asarray(measured, dtype=float)
    b = np.asarray(predicted, dtype=float)
    if a.shape != b.shape:
        raise InputError(f"measured {a.shape} and predicted {b.shape} differ in shape")
    if a.ndim not in (1, 2) or a.shape[0] < 1:
        raise InputError(f"expected arrays of shape (n,) or (n, n_actuators), got {a.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise InputError("measured or predicted values contain NaN/inf")
    return a, b


def relative_absolute_error(measured: FloatArray, predicted: FloatArray, *, pooled: bool = False) -> FloatArray | float:
    """Relative absolute error :math:`\\varepsilon_{RA}` in percent (paper 000, Eq. 33).

    Parameters
    ----------
    measured : array, shape (n,) or (n, m)
        Actually applied forces/torques :math:`\\tau^*`, time on axis 0, one column per
        actuator.
    predicted : array, same shape
        Forces computed with the identified parameters :math:`\\tau_{idnt}`.
    pooled : bool
        If true, one number for all actuators: numerator and denominator are summed
        over all samples and all actuators (each actuator about its own mean).

    Returns
    -------
    float or array of shape (m,)
        Per actuator :math:`j` (a float for 1-D input or ``pooled=True``):

        .. math::

            \\varepsilon_{RA,j} = 100\\,\\frac{\\sum_i |\\tau^*_{ij} - \\tau_{idnt,ij}|}
            {\\sum_i |\\tau^*_{ij} - \\bar\\tau^*_j|} \\quad [\\%],

        with :math:`\\bar\\tau^*_j` the time average of the measured force. 0 for a
        perfect prediction, 100 for one no better than the constant mean.

    Notes
    -----
    Mata / Farhat et al. (paper 000), Eq. 33, as a ratio of sums of absolute values;
    the paper reports it in percent (Tables 3, 4, 6, 7), hence the factor 100 here. A
    measured signal that is constant (zero denominator) raises
    :class:`~dynid.errors.InputError`.
    """
    a, b = _paired(measured, predicted)
    num = np.sum(np.abs(a - b), axis=0)
    den = np.sum(np.abs(a - a.mean(axis=0)), axis=0)
    if pooled:
        num, den = np.sum(num), np.sum(den)
    bad = np.flatnonzero(np.atleast_1d(den) <= 0)
    if bad.size:
        raise InputError(f"measured signal is constant (columns {bad.tolist()}): relative absolute error undefined")
    out = 100.0 * num / den
    return float(out) if np.ndim(out) == 0 else out


def average_error(exact: FloatArray, identified: FloatArray) -> float:
    """Average relative parameter error :math:`\\varepsilon_{AV}` in percent (paper 000, Eq. 34).

    Parameters
    ----------
    exact : array, shape (n_p,)
        Exact parameter values :math:`\\Phi_i` (simulation ground truth); none may be 0.
    identified : array, shape (n_p,)
        Identified values :math:`\\hat\\Phi_i`.

    Returns
    -------
    float
        .. math::

            \\varepsilon_{AV} = \\frac{100}{n_p} \\sum_{i=1}^{n_p}
            \\frac{|\\Phi_i - \\hat\\Phi_i|}{|\\Phi_i|} \\quad [\\%].

    Notes
    -----
    Mata / Farhat et al. (paper 000), Eq. 34, reported in percent in Table 6. Each
    parameter's error is relative to its own exact value, so an exact value of 0 makes
    it undefined and raises :class:`~dynid.errors.InputError` naming the index.
    """
    x = np.asarray(exact, dtype=float)
    y = np.asarray(identified, dtype=float)
    if x.shape != y.shape or x.ndim != 1 or x.size == 0:
        raise InputError(f"exact {x.shape} and identified {y.shape} must be equal-length 1-D arrays")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise InputError("exact or identified parameters contain NaN/inf")
    zero = np.flatnonzero(x == 0)
    if zero.size:
        raise InputError(f"exact parameters are zero at indices {zero.tolist()}: relative error undefined")
    return float(100.0 * np.mean(np.abs(x - y) / np.abs(x)))


def t_rsme(measured: FloatArray, predicted: FloatArray) -> FloatArray | float:
    """Torque root-square mean error per actuator, T-RSME (paper 001, Eq. 21).

    Parameters
    ----------
    measured : array, shape (r,) or (r, m)
        Actual torques/forces :math:`\\tau^a_i(m)` [N·m or N], time on axis 0, one column
        per active joint.
    predicted : array, same shape
        Torques :math:`\\tau^c_i(m)` computed with the model.

    Returns
    -------
    float or array of shape (m,)
        .. math::

            \\text{T-RSME}_i = \\sqrt{\\frac1r \\sum_{m=1}^{r} (\\tau^a_i(m) - \\tau^c_i(m))^2},

        in the units of the inputs (not normalized; Shang et al. 2009, Table 4, in N·m).
    """
    a, b = _paired(measured, predicted)
    out = np.sqrt(np.mean((a - b) ** 2, axis=0))
    return float(out) if np.ndim(out) == 0 else out


def _even(n: int, m: int) -> np.ndarray:
    """``min(n, m)`` indices spread evenly over ``range(n)`` (first and last included)."""
    return np.unique(np.linspace(0, n - 1, min(n, m)).round().astype(int))


def nearest_distances(reference: FloatArray, query: FloatArray, *, max_reference: int = 20000,
                      max_query: int = 1000) -> FloatArray:
    """Distance of each query state to the nearest reference state, in reference standard deviations.

    Both arrays are ``(n_samples, n_channels)`` (e.g. positions, velocities and accelerations of
    every joint side by side). Each channel is divided by its standard deviation over
    ``reference`` (channels that do not vary keep unit scale), and the Euclidean distance of
    each query row to its nearest reference row is returned, shape ``(m,)``. Long arrays are
    thinned to evenly spaced rows (at most ``max_reference`` and ``max_query``), so the cost is
    bounded; the thinning is deterministic.

    Used to tell a held-out motion that repeats the training motion (a tail window of a
    periodic excitation: distances at the noise level, far below :data:`REPEAT_THRESHOLD`) from
    a new one (distances of the order of one standard deviation): sampled states fill a space
    of 3 x n_joints dimensions far too sparsely for a new motion to come that close by chance.
    """
    ref = np.asarray(reference, dtype=float)
    qry = np.asarray(query, dtype=float)
    if ref.ndim != 2 or qry.ndim != 2 or ref.shape[1] != qry.shape[1] or not len(ref) or not len(qry):
        raise InputError(f"nearest_distances: expected two non-empty (n, k) arrays of the same k, got {ref.shape}, {qry.shape}")
    return nearest_distances_thinned(ref[_even(len(ref), max_reference)], qry[_even(len(qry), max_query)],
                                     ref.std(axis=0))


_DISTANCE_BYTES = 4 * 2**20
"""Bytes of one block of squared distances (query rows x reference rows) in :func:`nearest_distances_thinned`."""


def nearest_distances_thinned(ref: FloatArray, qry: FloatArray, std: FloatArray) -> FloatArray:
    """:func:`nearest_distances` of rows already thinned, with the standard deviation ``std`` of every
    reference row (the streamed identification samples the rows and merges the deviation chunk by
    chunk, :mod:`dynid.pipeline.streaming`)."""
    scale = np.where(std > 0, std, 1.0)
    ref = ref / scale
    qry = qry / scale
    r2 = np.einsum("ij,ij->i", ref, ref)
    best = np.empty(len(qry))
    step = max(1, _DISTANCE_BYTES // (8 * max(1, len(ref))))  # blocks of query rows: bounded memory
    for a in range(0, len(qry), step):
        block = qry[a : a + step]
        d2 = np.einsum("ij,ij->i", block, block)[:, None] + r2[None, :] - 2.0 * block @ ref.T
        best[a : a + step] = np.sqrt(np.maximum(d2.min(axis=1), 0.0))
    return best
