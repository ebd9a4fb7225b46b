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

__all__ = ["CutoffFamily", "MaximumLikelihood", "cutoff_candidates", "position_cost"]


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


def position_cost(delta: FloatArray, cov: FloatArray) -> float:
    """:math:`\\tfrac12\\sum_k \\delta_k^T \\Sigma_{\\delta\\delta}^{-1} \\delta_k` of residuals ``delta`` (n, n_a)."""
    d = np.atleast_2d(np.asarray(delta, dtype=float))
    C = np.linalg.cholesky(cov)
    u = sla.solve_triangular(C, d.T, lower=True)
    return 0.5 * float(np.sum(u**2))


@dataclasses.dataclass(frozen=True)
class CutoffFamily:
    """The regression problems of one record processed at each candidate cut-off.

    Attributes
    ----------
    cutoffs : tuple of float
        Candidate cut-offs [Hz], e.g. :func:`cutoff_candidates`.
    build : callable
        ``build(fc) -> (problem, delta)``: the regression problem (with the cross-channel
        factor) of the record filtered at ``fc`` and the position residuals ``delta``
        (n, n_a): measured minus filtered actuator positions.
    bin_width_hz : float
        Spacing of the harmonics (1/T): cut-offs closer than this are indistinguishable.
    """

    cutoffs: tuple[float, ...]
    build: Callable[[float], tuple[RegressionProblem, FloatArray]]
    bin_width_hz: float


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
            problem, delta = family.build(float(fc))
            cov_e = _check_cov(self.noise_covariance, problem.n_channels, "force covariance Sigma_eta")
            if np.shape(delta)[-1] != cov_d.shape[0]:
                raise InputError(f"position residuals have {np.shape(delta)[-1]} channels, Sigma_dd is "
                                 f"{cov_d.shape[0]} x {cov_d.shape[0]}")
            jd = position_cost(delta, cov_d)
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
        interval = [fc - 0.5 * w, fc + 0.5 * w]
        costs = [r["cost"] for r in profile if r["cost"] is not None]
        notes = [f"maximum likelihood (paper 004 Eq. 24): cut-off f_c = {fc:.4g} Hz, i.e. any value in "
                 f"[{interval[0]:.4g}, {interval[1]:.4g}) Hz (the same DFT bins); parameter covariance "
                 "conditional on f_c, Gauss-Markov with Sigma_eta" + (" as known" if self.scale == "known" else ", scaled")]
        valid = [r["cutoff_hz"] for r in profile if r["cost"] is not None]
        if fc in (valid[0], valid[-1]) and len(family.cutoffs) > 1:
            notes.append(f"the likelihood is best at the edge of the searched cut-offs ({valid[0]:.4g}-{valid[-1]:.4g} Hz): "
                         "widen the range")
        solver = {"algorithm": "1-D search over DFT bin midpoints; Gauss-Markov at each",
                  "cutoff_hz": fc, "cutoff_interval_hz": interval, "cost": min(costs),
                  "profile": profile, "scale": self.scale,
                  "position_covariance": cov_d.tolist(), **_noise_note(cov_e)}
        return _result(problem, "ML", s, np.sqrt(np.diag(cov_e)), solver, tuple(notes))

