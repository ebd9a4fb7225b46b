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
candidate, so that each cost is the likelihood of the same data: the force rows that are kept
per actuator are whitened with the covariance of the kept actuators
(:class:`~dynid.estimation.problem.CrossBlock`), and :math:`\\delta` counts at the same rows.

Covariance of the parameters: that of the Gauss–Markov estimate at the chosen cut-off,
conditional on it, with :math:`\\Sigma_{\\eta\\eta}` taken as known (``scale = "known"``, the
Fisher information of :math:`J` in :math:`p`) or scaled by the residual variance factor
(``scale = "estimated"``).
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
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult

__all__ = ["CutoffFamily", "MaximumLikelihood", "cutoff_candidates", "log_cutoff_grid", "position_cost"]


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
        of ``delta`` that count (n, n_a) (:func:`position_cost`).
    bin_width_hz : float or None
        Spacing of the harmonics (1/T) of an exact DFT window: cut-offs closer than this are
        indistinguishable. None: a continuous filter (time domain); the estimate is reported with
        its neighbours among the candidates.
    """

    cutoffs: tuple[float, ...]
    build: Callable[[float], tuple]
    bin_width_hz: float | None


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
    likelihood), the cost profile over the candidates and both covariances.
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
        for fc in family.cutoffs:
            built = family.build(float(fc))
            problem, delta = built[0], built[1]
            keep = built[2] if len(built) > 2 else None
            cov_e = _check_cov(self.noise_covariance, problem.n_channels, "force covariance Sigma_eta")
            if np.shape(delta)[-1] != cov_d.shape[0]:
                raise InputError(f"position residuals have {np.shape(delta)[-1]} channels, Sigma_dd is "
                                 f"{cov_d.shape[0]} x {cov_d.shape[0]}")
            jd = position_cost(delta, cov_d, keep)
            try:
                s = gls_solve(problem, cov_e, known_scale=self.scale == "known")
            except IdentifiabilityError as exc:  # too few harmonics kept to excite every parameter
                profile.append({"cutoff_hz": float(fc), "position_cost": jd, "force_cost": None, "cost": None,
                                "error": str(exc)})
                continue
            je = 0.5 * s.scale * s.dof
            profile.append({"cutoff_hz": float(fc), "position_cost": jd, "force_cost": je, "cost": jd + je})
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
        notes = [f"maximum likelihood (paper 004 Eq. 24): cut-off f_c = {fc:.4g} Hz, {where}; parameter covariance "
                 "conditional on f_c, Gauss-Markov with Sigma_eta" + (" as known" if self.scale == "known" else ", scaled")]
        if fc in (valid[0], valid[-1]) and len(family.cutoffs) > 1:
            notes.append(f"the likelihood is best at the edge of the searched cut-offs ({valid[0]:.4g}-{valid[-1]:.4g} Hz): "
                         "widen the range")
        solver = {"algorithm": ("1-D search over DFT bin midpoints" if w is not None else
                                "1-D search over a logarithmic grid of low-pass cut-offs") + "; Gauss-Markov at each",
                  "cutoff_hz": fc, "cutoff_interval_hz": interval, "cost": min(costs),
                  "profile": profile, "scale": self.scale,
                  "position_covariance": cov_d.tolist(), **_noise_note(cov_e)}
        return _result(problem, "ML", s, np.sqrt(np.diag(cov_e)), solver, tuple(notes))

