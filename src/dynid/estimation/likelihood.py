"""Maximum likelihood with the cut-off of the frequency-domain filter as an estimated
parameter (paper 004 §5, Eqs. 23–24).

With measured actuator positions and forces whose errors are :math:`\\delta(k)` (positions)
and :math:`\\eta(k)` (forces), of covariances :math:`\\Sigma_{\\delta\\delta}` and
:math:`\\Sigma_{\\eta\\eta}`, the likelihood of the parameters :math:`p` and of the processing
parameter :math:`p_z = f_c` is maximal where

.. math::

    J(p, f_c) = \\tfrac12 \\sum_k \\delta^T(k, f_c)\\, \\Sigma_{\\delta\\delta}^{-1}\\, \\delta(k, f_c)
              + \\tfrac12 \\sum_k \\eta^T(k, p, f_c)\\, \\Sigma_{\\eta\\eta}^{-1}\\, \\eta(k, p, f_c)

is minimal (Eq. 24): :math:`\\delta(k, f_c)` is what the rectangular window at :math:`f_c`
removed from the measured (period-averaged) actuator positions, :math:`\\eta(k, p, f_c)` the
force residual of the model on the states filtered at :math:`f_c`. For a fixed cut-off the
minimum over :math:`p` is the Gauss–Markov estimate with :math:`\\Sigma_{\\eta\\eta}`
(:func:`~dynid.estimation.generalized.gls_solve`), so the search is one-dimensional.

The filter is an exact DFT window over one period ``T`` (:func:`dynid.signals.periodic.fourier_filter`):
every cut-off between two harmonics ``m/T`` and ``(m+1)/T`` keeps the same bins and gives the
same cost. The candidates are therefore the bin midpoints ``(m + 1/2)/T``; the estimate is
reported as the midpoint with the interval of cut-offs that give the same likelihood, not as a
finer number the data cannot resolve (paper 004 Table II reports ``f_c`` to 1 mHz; with the
window it describes, any value in the same bin interval is equivalent).

**In the time domain** (no period averaging; :func:`dynid.pipeline.identification` with
``processing.lowpass`` and no ``processing.periodic``) the filter is the zero-phase Butterworth
low-pass, whose cost varies continuously with the cut-off: the candidates are a logarithmic
grid over the searched range and the estimate is reported with its neighbours on the grid
(``bin_width_hz = None``). The row selection (``processing.min_velocity``,
``processing.reversal_guard``) and the samples trimmed at the ends are decided once, for every
candidate, at the configured cut-off (the rows the other methods fit), so that each cost is the
likelihood of the same data: the force rows that are kept
per actuator are whitened with the covariance of the kept actuators
(:class:`~dynid.estimation.problem.CrossBlock`), and :math:`\\delta` counts at the same rows.

**The propagated position noise (time domain; a departure from Eq. 24).** Eq. 24 weights the
force residual by :math:`\\Sigma_{\\eta\\eta}` alone, as if the states of the regressor were exact.
They are not: the regressor is evaluated on the *measured* positions :math:`q_m = q + e` after the
zero-phase low-pass :math:`H_{f_c}` and two central differences :math:`D`, so at sample :math:`k`

.. math::

    \\tau_m(k) - Y(\\hat q, \\hat{\\dot q}, \\hat{\\ddot q})\\, p
    = \\eta(k) - \\frac{\\partial\\tau}{\\partial q} e_0(k) - \\frac{\\partial\\tau}{\\partial\\dot q} e_1(k)
      - M_a(q_k)\\, e_2(k) + (\\text{the signal the filter removes}),
    \\qquad e_i = D^i H_{f_c} e ,

to first order in the encoder noise :math:`e` (white, covariance :math:`\\Sigma_{\\delta\\delta}` per
sample, the matrix Eq. 24 weights the position residual with). :math:`M_a(q) = \\partial\\tau/\\partial\\ddot q_a`
is the actuator-space inertia matrix; the model is affine in the accelerations (paper 004 Eq. 7),
so :math:`M_a(q_k) u = (Y(q_k, \\dot q_k, \\ddot q_k + u) - Y(q_k, \\dot q_k, \\ddot q_k))\\, p` exactly. The
filter and the stencil act on every actuator alike, so :math:`\\mathrm{cov}\\, e_2(k) = g_2(f_c)\\,
\\Sigma_{\\delta\\delta}` with the noise gain :math:`g_2(f_c) = \\sum_j h_2(j)^2` of the impulse response
:math:`h_2 = D^2 H_{f_c}\\delta` (:func:`processing_noise_gains`; for :math:`f_c \\ll f_s` it is
:math:`0.32\\,(2\\pi)^4 f_c^5 / f_s` for the order-4 filter, i.e. it grows with the fifth power of the
cut-off). The force residual's
covariance per sample is then

.. math::

    S_k(f_c) = \\Sigma_{\\eta\\eta} + g_2(f_c)\\, M_a(q_k)\\, \\Sigma_{\\delta\\delta}\\, M_a(q_k)^T ,

and the force term of Eq. 24 becomes the negative log-likelihood of those residuals,

.. math::

    J_\\eta(p, f_c) = \\tfrac12 \\sum_k \\eta^T(k, p, f_c)\\, S_k^{-1}(f_c)\\, \\eta(k, p, f_c)
                   + \\tfrac12 \\sum_k \\log\\det\\big(S_k(f_c)\\, \\Sigma_{\\eta\\eta}^{-1}\\big)

(the log-determinant counted relative to :math:`\\Sigma_{\\eta\\eta}`, so that with
:math:`g_2 = 0` it is Eq. 24's term exactly; a sample keeping only the actuators :math:`K` counts
with the blocks :math:`(S_k)_{KK}`, :math:`(\\Sigma_{\\eta\\eta})_{KK}`). Without the log-determinant
a larger covariance would only lower the cost; with it the cost is a proper negative
log-likelihood over :math:`f_c`: the position term falls as the filter removes less noise, the
log-determinant rises as more of it reaches the accelerations, and the minimum is interior.
For a fixed cut-off the estimate is generalized least squares with a per-sample covariance: each
sample is whitened with the Cholesky factor of its :math:`S_k` before the rows are compressed
(:func:`whiten_rows`), and solved with an identity covariance.

**The errors-in-variables correction (a second departure).** The same noise sits in the regressor,
:math:`\\Delta W_k = \\sum_j A_j(q_k)\\, e_{2,j}(k)` with :math:`A_j = \\partial W/\\partial\\ddot q_{a,j}`,
and least squares uses it: the normal matrix :math:`G = \\sum_k W_k^T S_k^{-1} W_k` holds, on average,
:math:`N = \\sum_k \\mathrm{E}[\\Delta W_k^T S_k^{-1} \\Delta W_k]
= g_2(f_c) \\sum_k \\sum_{jl} (\\Sigma_{\\delta\\delta})_{jl} A_j^T S_k^{-1} A_l` more than the noise-free
regressor's, and the fit shrinks the parameters the motion excites weakly towards the values that
amplify the noise least (the attenuation of errors in the variables). Where the inertial forces are
weak against :math:`\\eta` the fit absorbs the propagated noise instead of leaving it in the residual,
the quadratic term falls as the cut-off rises and the likelihood follows it up to where the
estimate is biased (on the hexapod twin of bench/README §9 B, 40 Hz and 13 of 24 rows within
3 std). The estimate at each cut-off is therefore the corrected one (corrected least squares),

.. math::

    \\hat p_c = (G - N)^{-1} \\sum_k W_k^T S_k^{-1} \\tau_m(k), \\qquad
    \\mathrm{cov}(\\hat p_c) \\approx (G - N)^{-1} G\\, (G - N)^{-1},

and the likelihood is evaluated at it; a cut-off whose :math:`G - N` is not positive definite lets
in more noise than the motion excites in some direction and is not a candidate.

What is neglected, and why:

* the position and velocity terms :math:`\\partial\\tau/\\partial q\\, e_0` and
  :math:`\\partial\\tau/\\partial\\dot q\\, e_1` (gravity and stiffness gradients, viscous friction
  and Coriolis terms; the Coulomb term's derivative vanishes on the rows the row selection keeps,
  away from reversals). Their gains are smaller by about :math:`(2\\pi f_c)^2` per order of
  differentiation: on the hexapod twin of bench/README §9 B (viscous coefficients up to 26 N s/m,
  actuator inertia rows of about 25 kg) the velocity term is below 0.2 % of the acceleration term
  over 5–80 Hz, the position term smaller still;
* the correlation of the propagated noise between neighbouring samples (it is band-limited to
  about :math:`f_c`): the force term treats the samples as independent, so the quadratic term has
  the right expectation but is not the exact generalized least squares of a correlated record, and
  the log-determinant is the per-sample one (by Jensen's inequality it is not below the exact
  Toeplitz determinant per sample, so it penalises a high cut-off somewhat more);
* the dependence of :math:`M_a` on the unknown :math:`p`: :math:`S_k` is evaluated once, at a pilot
  estimate (:func:`dynid.pipeline.identification` uses Gauss–Markov with :math:`\\Sigma_{\\eta\\eta}`
  at the configured cut-off, on the same rows), and held fixed over the search (feasible
  generalized least squares); :math:`N` needs no parameters;
* the noise of the velocity columns in :math:`N` (the same ratio as above);
* the extra variance of :math:`\\hat p_c` from the noise in :math:`G` (second order in it).

The paper's frequency-domain variant (the rectangular window on the averaged period) keeps
Eq. 24's force term as written.

Covariance of the parameters: that of the (corrected) generalized least-squares estimate at the
chosen cut-off, conditional on it, with :math:`\\Sigma_{\\eta\\eta}` (or :math:`S_k` with the propagated noise) taken
as known (``scale = "known"``, the Fisher information of :math:`J` in :math:`p`) or scaled by the
residual variance factor (``scale = "estimated"``). With the propagated noise the intervals
account for the position noise that the processing carries into the regressor (issue 17, item 2).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import scipy.linalg as sla

from dynid._typing import FloatArray
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation.generalized import _check_cov, _noise_note, gls_solve
from dynid.estimation.linear import _result
from dynid.estimation.problem import ProblemBuilder, RegressionProblem
from dynid.estimation.results import IdentificationResult

__all__ = ["Candidate", "CandidateBuilder", "CutoffFamily", "MaximumLikelihood", "NoiseGains", "cutoff_candidates",
           "log_cutoff_grid", "position_cost", "processing_noise_gains", "whiten_rows"]


def cutoff_candidates(period_s: float, fs: float, low_hz: float, high_hz: float) -> tuple[float, ...]:
    """Bin midpoints ``(m + 1/2)/T`` in ``[low_hz, high_hz]`` below the Nyquist frequency.

    Each candidate stands for every cut-off between the harmonics ``m/T`` and ``(m+1)/T``
    (the same DFT bins are kept). Raises :class:`~dynid.errors.InputError` when none lies in
    the range.
    """
    if not period_s > 0 or not fs > 0:
        raise InputError(f"period and sampling rate must be positive, got {period_s} s, {fs} Hz")
    if not 0 < low_hz < high_hz:
        raise InputError(f"the cut-off range must satisfy 0 < low < high, got [{low_hz}, {high_hz}] Hz")
    f0 = 1.0 / period_s
    m = np.arange(int(np.floor(low_hz / f0 - 0.5)), int(np.ceil(high_hz / f0 - 0.5)) + 1)
    c = (m + 0.5) * f0
    c = c[(c >= low_hz) & (c <= high_hz) & (c < fs / 2) & (m >= 0)]
    if c.size == 0:
        raise InputError(f"no cut-off between harmonics of {f0:g} Hz lies in [{low_hz:g}, {high_hz:g}] Hz below "
                         f"fs/2 = {fs / 2:g} Hz")
    return tuple(float(x) for x in c)


def log_cutoff_grid(low_hz: float, high_hz: float, n: int) -> tuple[float, ...]:
    """``n`` cut-offs spaced logarithmically over ``[low_hz, high_hz]`` (time-domain search)."""
    if not 0 < low_hz < high_hz:
        raise InputError(f"the cut-off range must satisfy 0 < low < high, got [{low_hz}, {high_hz}] Hz")
    if n < 3:
        raise InputError(f"a cut-off search needs at least 3 candidates, got {n}")
    return tuple(float(x) for x in np.geomspace(low_hz, high_hz, n))


def position_cost(delta: FloatArray, cov: FloatArray, keep: FloatArray | None = None) -> float:
    """:math:`\\tfrac12\\sum_k \\delta_k^T \\Sigma_{\\delta\\delta}^{-1} \\delta_k` of residuals ``delta`` (n, n_a).

    ``keep`` (n, n_a): the rows counted per actuator; a sample with the actuators :math:`K`
    counts with :math:`\\Sigma_{KK}` (the marginal of its kept actuators)."""
    d = np.atleast_2d(np.asarray(delta, dtype=float))
    if keep is None:
        C = np.linalg.cholesky(cov)
        u = sla.solve_triangular(C, d.T, lower=True)
        return 0.5 * float(np.sum(u**2))
    keep = np.asarray(keep, dtype=bool)
    codes = keep.astype(np.int64) @ (1 << np.arange(d.shape[1], dtype=np.int64))
    total = 0.0
    for code in np.unique(codes[keep.any(axis=1)]):
        rows = codes == code
        K = np.flatnonzero(keep[np.argmax(rows)])
        C = np.linalg.cholesky(cov[np.ix_(K, K)])
        u = sla.solve_triangular(C, d[np.ix_(rows, K)].T, lower=True)
        total += float(np.sum(u**2))
    return 0.5 * total


@dataclasses.dataclass(frozen=True)
class NoiseGains:
    """Variance gains of the time-domain processing for white position noise of unit variance:
    the variance of the filtered position, of its central-difference velocity and acceleration
    [1, 1/s², 1/s⁴] (:func:`processing_noise_gains`)."""

    position: float
    velocity: float
    acceleration: float


def processing_noise_gains(order: int, cutoff_hz: float, fs: float) -> NoiseGains:
    """Noise gains :math:`g_i = \\sum_j h_i(j)^2` of the processing of ``method = "ml"`` in the time
    domain: the zero-phase Butterworth low-pass (:func:`dynid.signals.lowpass`) followed by one and
    two central differences (:func:`dynid.signals.central_difference`), i.e. the same functions the
    processing runs, applied to a unit impulse far from the ends of a record long enough for the
    response to die out. White noise of covariance :math:`\\Sigma` per sample leaves the processed
    acceleration with covariance :math:`g_2 \\Sigma` (module docstring)."""
    from dynid.signals import central_difference, lowpass, padlen_for

    half = 4 * padlen_for(order, cutoff_hz, fs) + 16
    x = np.zeros(2 * half + 1)
    x[half] = 1.0
    h0 = lowpass(x, cutoff_hz, fs, order)
    h1 = central_difference(h0, 1.0 / fs)
    h2 = central_difference(h1, 1.0 / fs)
    return NoiseGains(float(np.sum(h0**2)), float(np.sum(h1**2)), float(np.sum(h2**2)))


def _patterns(keep: np.ndarray):
    """``(rows, channels)`` of each pattern of kept channels (samples keeping none left out)."""
    codes = keep.astype(np.int64) @ (1 << np.arange(keep.shape[1], dtype=np.int64))
    for code in np.unique(codes[keep.any(axis=1)]):
        rows = np.flatnonzero(codes == code)
        yield rows, np.flatnonzero(keep[rows[0]])


def whiten_rows(W: FloatArray, y: FloatArray, cov: FloatArray, keep: FloatArray | None = None
                ) -> tuple[FloatArray, FloatArray, float]:
    """Rows whitened per sample by their own covariance.

    ``W`` (n, n_ch, p), ``y`` (n, n_ch), ``cov`` (n, n_ch, n_ch) or (n_ch, n_ch): :math:`S_k`;
    ``keep`` (n, n_ch): the rows that count. Each sample's kept channels :math:`K` are replaced by
    :math:`C_k^{-1} [W_K | y_K]` with :math:`C_k C_k^T = (S_k)_{KK}` (Cholesky), so that ordinary
    least squares on the whitened rows is generalized least squares with :math:`S_k`; the rows
    not kept are returned unchanged. Returns the whitened ``W``, ``y`` and
    :math:`\\tfrac12 \\sum_k \\log\\det (S_k)_{KK}` over the samples with a kept row.
    """
    W = np.asarray(W, dtype=float)
    y = np.asarray(y, dtype=float)
    n, n_ch = y.shape
    S = np.broadcast_to(np.asarray(cov, dtype=float), (n, n_ch, n_ch))
    keep = np.ones((n, n_ch), dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    Ww, yw = W.copy(), y.copy()
    half_log_det = 0.0
    p = W.shape[2]
    for rows, K in _patterns(keep):
        try:
            C = np.linalg.cholesky(S[rows][:, K][:, :, K])
        except np.linalg.LinAlgError:
            raise InputError("a per-sample force covariance is not positive definite") from None
        A = np.concatenate([W[rows][:, K, :], y[rows][:, K, None]], axis=2)
        X = np.linalg.solve(C, A)
        Ww[rows[:, None], K[None, :], :] = X[..., :p]
        yw[rows[:, None], K[None, :]] = X[..., p]
        half_log_det += float(np.sum(np.log(np.diagonal(C, axis1=1, axis2=2))))
    return Ww, yw, half_log_det


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One candidate cut-off's data for :class:`MaximumLikelihood` (what ``CutoffFamily.build``
    returns; a tuple ``(problem, delta)`` or ``(problem, delta, keep)`` stands for the Eq. 24 form).

    Attributes
    ----------
    problem : RegressionProblem
        The rows as measured (with the cross-channel factor): the residuals reported.
    delta : array (n, n_a)
        Measured minus filtered actuator positions.
    keep : array (n, n_a) or None
        The rows that count (:func:`position_cost`).
    whitened : RegressionProblem or None
        The same rows whitened per sample with :math:`S_k(f_c)` (:func:`whiten_rows`); solved with
        an identity covariance. None: the force covariance is :math:`\\Sigma_{\\eta\\eta}` (Eq. 24).
    log_det : float
        :math:`\\tfrac12 \\sum_k \\log\\det((S_k)_{KK} (\\Sigma_{\\eta\\eta})_{KK}^{-1})` (module docstring).
    propagated_std : array (n_ch,) or None
        Root mean square over the kept rows of the propagated force noise per channel (reported).
    correction : array (p, p) or None
        :math:`N = \\sum_k \\mathrm{E}[\\Delta W_k^T S_k^{-1} \\Delta W_k]`, what the noise in the
        regressor adds on average to the whitened normal matrix (module docstring); None: no
        errors-in-variables correction.
    """

    problem: RegressionProblem
    delta: FloatArray
    keep: FloatArray | None = None
    whitened: RegressionProblem | None = None
    log_det: float = 0.0
    propagated_std: FloatArray | None = None
    correction: FloatArray | None = None


class CandidateBuilder:
    """Accumulates one candidate's rows chunk by chunk, as measured and whitened per sample with
    :math:`S_k = \\Sigma_{\\eta\\eta} + ` ``extra`` (the propagated position noise), into a
    :class:`Candidate`. Without ``propagated`` only the measured rows are kept (Eq. 24)."""

    def __init__(self, names, channel_names, noise_covariance: FloatArray, *, propagated: bool = True) -> None:
        self._plain = ProblemBuilder(names, channel_names, cross=True)
        self._white = ProblemBuilder(names, channel_names, cross=True) if propagated else None
        self._cov = np.asarray(noise_covariance, dtype=float)
        n_ch = len(tuple(channel_names))
        self._log_det = 0.0
        self._corr: FloatArray | None = None
        self._var = np.zeros(n_ch)
        self._count = np.zeros(n_ch)

    def add(self, W: FloatArray, y: FloatArray, keep: FloatArray | None = None, extra: FloatArray | None = None,
            noisy: tuple[FloatArray, FloatArray] | None = None) -> None:
        """``W`` (n, n_ch, p), ``y`` (n, n_ch), ``keep`` (n, n_ch) or None, ``extra`` (n, n_ch, n_ch):
        the propagated covariance of these samples (required when built with ``propagated``).
        ``noisy = (A, C)``: the regressor's noise as ``sum_j A[:, :, j, :] e_j`` with ``A`` (n, n_ch,
        n_e, p) and ``e`` of covariance ``C`` (n_e, n_e) per sample, e.g. ``A`` the derivative of the
        regressor in the actuator accelerations and ``C = g2 Sigma_dd``: accumulates the
        errors-in-variables correction :math:`N` (module docstring)."""
        self._plain.add(W, y, keep)
        if self._white is None:
            return
        if extra is None:
            raise InputError("the propagated force covariance of these rows is missing")
        extra = np.asarray(extra, dtype=float)
        S = self._cov + extra
        Ww, yw, ld = whiten_rows(W, y, S, keep)
        k = np.ones(y.shape, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
        ld0 = sum(rows.size * float(np.sum(np.log(np.diag(np.linalg.cholesky(self._cov[np.ix_(K, K)])))))
                  for rows, K in _patterns(k))
        self._white.add(Ww, yw, keep)
        self._log_det += ld - ld0
        self._var += np.sum(np.where(k, np.diagonal(extra, axis1=1, axis2=2), 0.0), axis=0)
        self._count += k.sum(axis=0)
        if noisy is not None:
            A, C = np.asarray(noisy[0], dtype=float), np.asarray(noisy[1], dtype=float)
            n, n_ch, n_e, p = A.shape
            L = np.linalg.cholesky(C)  # e = L u with u of unit covariance
            X = np.einsum("kcjp,jm->kcmp", A, L).reshape(n, n_ch, n_e * p)
            Xw, _, _ = whiten_rows(X, np.zeros((n, n_ch)), S, keep)
            Xw = np.where(k[:, :, None], Xw, 0.0).reshape(n, n_ch, n_e, p)
            N = np.einsum("kcmp,kcmq->pq", Xw, Xw)
            self._corr = N if self._corr is None else self._corr + N

    def build(self, delta: FloatArray, keep: FloatArray | None = None, **kwargs) -> Candidate:
        plain = self._plain.build(**kwargs)
        if self._white is None:
            return Candidate(plain, delta, keep)
        std = np.sqrt(self._var / np.maximum(self._count, 1))
        return Candidate(plain, delta, keep, self._white.build(**kwargs), self._log_det, std, self._corr)


@dataclasses.dataclass(frozen=True)
class CutoffFamily:
    """The regression problems of one record processed at each candidate cut-off.

    Attributes
    ----------
    cutoffs : tuple of float
        Candidate cut-offs [Hz], e.g. :func:`cutoff_candidates`.
    build : callable
        ``build(fc) -> (problem, delta)`` or ``(problem, delta, keep)``: the regression problem
        (with the cross-channel factor) of the record filtered at ``fc``, the position residuals
        ``delta`` (n, n_a): measured minus filtered actuator positions, and optionally the rows
        of ``delta`` that count (n, n_a) (:func:`position_cost`); or a :class:`Candidate`, which
        can also carry the rows whitened with the propagated position noise.
    bin_width_hz : float or None
        Spacing of the harmonics (1/T) of an exact DFT window: cut-offs closer than this are
        indistinguishable. None: a continuous filter (time domain); the estimate is reported with
        its neighbours among the candidates.
    """

    cutoffs: tuple[float, ...]
    build: Callable[[float], tuple]
    bin_width_hz: float | None


def _corrected(s, N: FloatArray, known: bool):
    """The errors-in-variables corrected estimate from the whitened solve ``s`` (its factor
    :math:`R`, :math:`c`): :math:`\\beta_c = (R^T R - N)^{-1} R^T c`; its cost
    :math:`\\|c - R\\beta\\|^2 + \\rho^2` at :math:`\\beta_c` and the sandwich covariance
    :math:`(R^T R - N)^{-1} R^T R (R^T R - N)^{-1}`. Raises :class:`IdentifiabilityError` where the
    correction takes all the information of some direction (the cut-off lets in more noise than
    the motion excites).

    Computed in the coordinates of :math:`R`, never through :math:`G = R^T R`: with
    :math:`M = R^{-T} N R^{-1}` (the share of each direction's information that is noise, its
    eigenvalues :math:`\\lambda` those of :math:`N v = \\lambda G v`),
    :math:`G - N = R^T (I - M) R`, so :math:`\\beta_c = R^{-1} (I - M)^{-1} c` and the covariance is
    :math:`R^{-1} (I - M)^{-2} R^{-T}`. Forming :math:`G` squares the condition number of :math:`R`;
    on the parallel twins of the estimator benchmark (bench/README.md, "Estimator benchmark") it is
    about 1e9, so :math:`G` is singular in double precision and a Cholesky factor of :math:`G - N`
    that happens to complete returns estimates of 1e5 where the truth is 1 (issue 36)."""
    p = s.R.shape[0]
    Ri = sla.solve_triangular(s.R, np.eye(p))
    M = Ri.T @ np.asarray(N, dtype=float) @ Ri
    lam, V = np.linalg.eigh(0.5 * (M + M.T))
    keep = 1.0 - lam  # the share of each direction's information left after the correction
    if not keep.min() > 0:
        raise IdentifiabilityError("the noise the processing carries into the regressor outweighs the information of "
                                   f"the motion in some direction (errors-in-variables correction: {lam.max():.3g} of "
                                   "its information is noise)")
    u = V @ ((V.T @ s.c) / keep)  # (I - M)^{-1} c
    beta = Ri @ u
    cost = s.scale * s.dof + float(np.sum((s.R @ (beta - s.beta)) ** 2))
    B = Ri @ (V / keep)  # R^{-1} V (I - Lambda)^{-1}
    scale = cost / s.dof
    cov = (1.0 if known else scale) * (B @ B.T)
    return dataclasses.replace(s, beta=beta, scale=scale, cov=cov)


@dataclasses.dataclass(frozen=True, kw_only=True)
class MaximumLikelihood:
    """Maximum likelihood over the parameters and the filter cut-off (paper 004 Eq. 24).

    Parameters
    ----------
    noise_covariance : array (n_ch, n_ch)
        :math:`\\Sigma_{\\eta\\eta}` of the force errors of the processed record (e.g. from
        period averaging, divided by the number of periods) [N², N²m²].
    position_covariance : array (n_a, n_a)
        :math:`\\Sigma_{\\delta\\delta}` of the actuator position errors of the processed
        record [m², rad²]; positive definite.
    scale : {"known", "estimated"}
        Covariance of the parameters from :math:`\\Sigma_{\\eta\\eta}` as given (default) or
        scaled by the residual variance factor.

    ``fit(family)`` takes a :class:`CutoffFamily`. The result's ``solver`` holds
    ``cutoff_hz`` (the bin midpoint), ``cutoff_interval_hz`` (every cut-off with the same
    likelihood), the cost profile over the candidates and both covariances. Candidates that carry
    their rows whitened with the propagated position noise (:class:`Candidate`) are solved with
    their per-sample covariances :math:`S_k(f_c)` and their force cost includes the log-determinant
    (module docstring); their profile entries also hold ``log_det`` and ``propagated_std``.
    """

    noise_covariance: tuple[tuple[float, ...], ...] | FloatArray
    position_covariance: tuple[tuple[float, ...], ...] | FloatArray
    scale: str = "known"

    def fit(self, family: CutoffFamily) -> IdentificationResult:
        if self.scale not in ("estimated", "known"):
            raise ValueError(f"scale must be 'estimated' or 'known', got {self.scale!r}")
        if not family.cutoffs:
            raise InputError("maximum likelihood needs at least one candidate cut-off")
        cov_d = np.asarray(self.position_covariance, dtype=float)
        if cov_d.ndim != 2:
            raise InputError(f"position covariance Sigma_dd must be a square matrix, got shape {cov_d.shape}")
        cov_d = _check_cov(cov_d, cov_d.shape[0], "position covariance Sigma_dd")
        profile: list[dict] = []
        best = None
        propagated = False
        for fc in family.cutoffs:
            built = family.build(float(fc))
            cand = built if isinstance(built, Candidate) else Candidate(*built)
            problem, delta, keep = cand.problem, cand.delta, cand.keep
            cov_e = _check_cov(self.noise_covariance, problem.n_channels, "force covariance Sigma_eta")
            if np.shape(delta)[-1] != cov_d.shape[0]:
                raise InputError(f"position residuals have {np.shape(delta)[-1]} channels, Sigma_dd is "
                                 f"{cov_d.shape[0]} x {cov_d.shape[0]}")
            jd = position_cost(delta, cov_d, keep)
            extra: dict = {}
            try:
                if cand.whitened is None:
                    s = gls_solve(problem, cov_e, known_scale=self.scale == "known")
                    je = 0.5 * s.scale * s.dof
                else:  # generalized least squares with S_k: the whitened rows, identity covariance
                    propagated = True
                    s = gls_solve(cand.whitened, np.eye(problem.n_channels), known_scale=self.scale == "known")
                    if cand.correction is not None:
                        s = _corrected(s, cand.correction, self.scale == "known")
                    s = dataclasses.replace(s, rss=problem.rss_per_channel(s.beta))
                    je = 0.5 * s.scale * s.dof + cand.log_det
                    extra = {"log_det": float(cand.log_det),
                             "propagated_std": None if cand.propagated_std is None else
                             [float(x) for x in cand.propagated_std]}
            except IdentifiabilityError as exc:  # too few harmonics kept to excite every parameter
                profile.append({"cutoff_hz": float(fc), "position_cost": jd, "force_cost": None, "cost": None,
                                "error": str(exc)})
                continue
            profile.append({"cutoff_hz": float(fc), "position_cost": jd, "force_cost": je, "cost": jd + je, **extra})
            if best is None or jd + je < best[0]:
                best = (jd + je, float(fc), problem, s, cov_e)
        if best is None:
            raise IdentifiabilityError(f"no candidate cut-off identifies every parameter ({profile[-1]['error']})")
        _, fc, problem, s, cov_e = best
        w = family.bin_width_hz
        costs = [r["cost"] for r in profile if r["cost"] is not None]
        valid = [r["cutoff_hz"] for r in profile if r["cost"] is not None]
        if w is not None:
            interval = [fc - 0.5 * w, fc + 0.5 * w]
            where = f"i.e. any value in [{interval[0]:.4g}, {interval[1]:.4g}) Hz (the same DFT bins)"
        else:
            i = valid.index(fc)
            interval = [valid[max(i - 1, 0)], valid[min(i + 1, len(valid) - 1)]]
            where = f"between its neighbouring candidates {interval[0]:.4g} and {interval[1]:.4g} Hz"
        cov_text = ("Sigma_eta + the propagated position noise per sample" if propagated else "Sigma_eta")
        notes = [f"maximum likelihood (paper 004 Eq. 24): cut-off f_c = {fc:.4g} Hz, {where}; parameter covariance "
                 f"conditional on f_c, generalized least squares with {cov_text}"
                 + (" as known" if self.scale == "known" else ", scaled")]
        if fc in (valid[0], valid[-1]) and len(family.cutoffs) > 1:
            notes.append(f"the likelihood is best at the edge of the searched cut-offs ({valid[0]:.4g}-{valid[-1]:.4g} Hz): "
                         "widen the range")
        solver = {"algorithm": ("1-D search over DFT bin midpoints" if w is not None else
                                "1-D search over a logarithmic grid of low-pass cut-offs") + "; Gauss-Markov at each",
                  "cutoff_hz": fc, "cutoff_interval_hz": interval, "cost": min(costs),
                  "profile": profile, "scale": self.scale, "propagated_position_noise": propagated,
                  "position_covariance": cov_d.tolist(), **_noise_note(cov_e)}
        return _result(problem, "ML", s, np.sqrt(np.diag(cov_e)), solver, tuple(notes))

