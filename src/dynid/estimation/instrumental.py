"""Instrumental-variable estimation on accumulated cross products (IDIM-IV).

The inverse dynamic model :math:`y = W\\beta + e` is linear in the base parameters, but on a
closed-loop experiment the regressor :math:`W` is built from measured, filtered and
differentiated positions: its errors are correlated with the noise (the controller feeds the
noise back into the motion) and, through the filters, with each other. Least squares is then
biased. The instrumental-variable estimate replaces :math:`W^T` in the normal equations by
the transpose of an *instrument* matrix :math:`Z`, correlated with :math:`W` but not with the
errors (Janot, Vandanjon & Gautier, "A generic instrumental variable approach for industrial
robot identification", IEEE TCST 22(1), 2014, Eqs. 18–25):

.. math::

    \\hat\\beta_{IV} = \\Big(\\sum_j w_j Z_j^T W_j\\Big)^{-1} \\sum_j w_j Z_j^T y_j, \\qquad
    \\mathrm{cov}(\\hat\\beta_{IV}) = \\Big(\\sum_j w_j Z_j^T W_j\\Big)^{-1}
    \\Big(\\sum_j w_j Z_j^T Z_j\\Big) \\Big(\\sum_j w_j W_j^T Z_j\\Big)^{-1},

with per-channel weights :math:`w_j = 1/\\hat\\sigma_j^2` from the residuals
:math:`y_j - W_j\\hat\\beta_{IV}` (Gautier's weighting, as in WLS; the covariance is the
IV sandwich with the estimated noise variances, Janot 2014 Eq. 24). The instruments of IDIM-IV
are the regressor evaluated on the states of a simulation of the model with the current
estimate, under the same controller and reference as the experiment
(:mod:`dynid.pipeline.control_loop`), which composes this module with the simulator.

Only cross products of size ``p x p`` per channel are accumulated
(:class:`InstrumentBuilder`), so memory does not grow with the log.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from dynid._typing import BoolArray, FloatArray
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation.results import IdentificationResult
from dynid.stats import condition_number

__all__ = ["InstrumentBuilder", "InstrumentalProblem", "determined_directions", "fixed_point_covariance", "iv_result", "iv_solve",
           "iv_solve_truncated", "oscillation_relaxation", "reduce_instrumental"]


@dataclasses.dataclass(frozen=True)
class InstrumentalProblem:
    """Per-channel cross products of instruments ``Z``, regressor ``W`` and outputs ``y``.

    ``ZW``, ``ZZ``, ``WW`` (n_ch, p, p); ``Zy``, ``Wy`` (n_ch, p); ``yy`` (n_ch,); ``n_obs`` (n_ch,).
    """

    names: tuple[str, ...]
    channel_names: tuple[str, ...]
    ZW: FloatArray
    ZZ: FloatArray
    WW: FloatArray
    Zy: FloatArray
    Wy: FloatArray
    yy: FloatArray
    n_obs: FloatArray

    @property
    def n_params(self) -> int:
        return len(self.names)

    def rss_per_channel(self, beta: FloatArray) -> FloatArray:
        """``||y_j - W_j beta||^2`` per channel."""
        b = np.asarray(beta, dtype=float)
        return np.maximum(self.yy - 2.0 * self.Wy @ b + np.einsum("i,jik,k->j", b, self.WW, b), 0.0)


class InstrumentBuilder:
    """Accumulates chunks of (instruments, regressor, outputs) into an :class:`InstrumentalProblem`."""

    def __init__(self, names: Sequence[str], channel_names: Sequence[str]) -> None:
        self.names, self.channel_names = tuple(names), tuple(channel_names)
        n, p = len(self.channel_names), len(self.names)
        self._ZW, self._ZZ, self._WW = (np.zeros((n, p, p)) for _ in range(3))
        self._Zy, self._Wy = np.zeros((n, p)), np.zeros((n, p))
        self._yy, self._n = np.zeros(n), np.zeros(n)

    def add(self, Z: FloatArray, W: FloatArray, y: FloatArray, mask: BoolArray | None = None) -> None:
        """Accumulate rows: ``Z``, ``W`` (n, n_ch, p), ``y`` (n, n_ch); ``mask`` (n, n_ch) or (n,)."""
        Z, W, y = (np.asarray(a, dtype=float) for a in (Z, W, y))
        n_ch, p = len(self.channel_names), len(self.names)
        if Z.shape != W.shape or W.ndim != 3 or W.shape[1:] != (n_ch, p) or y.shape != W.shape[:2]:
            raise InputError(f"instrument chunk {Z.shape}, regressor {W.shape}, outputs {y.shape}: expected "
                             f"(n, {n_ch}, {p}) twice and (n, {n_ch})")
        if not (np.all(np.isfinite(Z)) and np.all(np.isfinite(W)) and np.all(np.isfinite(y))):
            raise InputError("instruments, regressor or outputs contain NaN/inf")
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.ndim == 1:
                mask = np.broadcast_to(mask[:, None], y.shape)
        for j in range(n_ch):
            rows = slice(None) if mask is None else mask[:, j]
            Zj, Wj, yj = Z[rows, j], W[rows, j], y[rows, j]
            self._ZW[j] += Zj.T @ Wj
            self._ZZ[j] += Zj.T @ Zj
            self._WW[j] += Wj.T @ Wj
            self._Zy[j] += Zj.T @ yj
            self._Wy[j] += Wj.T @ yj
            self._yy[j] += yj @ yj
            self._n[j] += Zj.shape[0]

    def build(self) -> InstrumentalProblem:
        return InstrumentalProblem(self.names, self.channel_names, self._ZW.copy(), self._ZZ.copy(), self._WW.copy(),
                                   self._Zy.copy(), self._Wy.copy(), self._yy.copy(), self._n.copy())


def iv_solve(problem: InstrumentalProblem, sigma: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """The weighted IV estimate, its covariance (Janot 2014, Eq. 24) and cond(Σ w Z^T W).

    ``sigma`` (n_ch,): the channels' noise standard deviations (weights ``1/sigma^2``).
    """
    s = np.asarray(sigma, dtype=float)
    if s.shape != (len(problem.channel_names),) or np.any(~np.isfinite(s)) or np.any(s <= 0):
        raise IdentifiabilityError(f"channel noise levels must be positive and finite, got {s}", problem.names)
    w = 1.0 / s**2
    A = np.einsum("j,jik->ik", w, problem.ZW)
    b = np.einsum("j,ji->i", w, problem.Zy)
    S = np.einsum("j,jik->ik", w, problem.ZZ)
    # scale the columns for the solve (parameters of very different magnitudes)
    d = np.sqrt(np.maximum(np.diag(S), 1e-300))
    As = A / np.outer(d, d)
    cond = condition_number(As)
    if not np.isfinite(cond) or cond > 1e14:
        raise IdentifiabilityError("the instruments do not determine the parameters (Z^T W is singular: "
                                   f"condition number {cond:.3g})", problem.names)
    beta = np.linalg.solve(As, b / d) / d
    Ainv = np.linalg.inv(As) / np.outer(d, d)
    cov = Ainv @ S @ Ainv.T
    return beta, 0.5 * (cov + cov.T), cond


def iv_solve_truncated(problem: InstrumentalProblem, sigma: FloatArray, start: FloatArray,
                       rtol: float) -> tuple[FloatArray, FloatArray, float, int]:
    """The weighted IV estimate on the directions the instruments determine; the others keep
    ``start``'s values.

    With the columns scaled as in :func:`iv_solve` (``x = d * beta``, ``d`` the weighted
    instruments' column norms), ``A = U diag(s) V^T`` the SVD of the scaled
    :math:`\\sum_j w_j Z_j^T W_j` and :math:`r = b - A x_0` the normal equations' residual at the
    start, the estimate is the truncated-SVD solution
    :math:`x = x_0 + V_k \\mathrm{diag}(1/s_k) U_k^T r` over the directions with
    ``s_i >= rtol * s_max`` (all of them: :func:`iv_solve`'s estimate). Along the other right
    singular vectors the instruments and the regressor are (nearly) uncorrelated, so the IV
    normal equations there hold noise divided by a vanishing singular value; the estimate
    stays at ``start`` along them. The covariance is the IV sandwich of that solution,
    :math:`P S P^T` with :math:`P = V_k \\mathrm{diag}(1/s_k) U_k^T` (Janot 2014 Eq. 24 with the
    pseudo-inverse): conditional on the held directions, which carry no variance.

    Returns the estimate, its covariance, the condition number of the kept directions
    (``s_max / s_min`` over them) and their number.
    """
    s_ = np.asarray(sigma, dtype=float)
    if s_.shape != (len(problem.channel_names),) or np.any(~np.isfinite(s_)) or np.any(s_ <= 0):
        raise IdentifiabilityError(f"channel noise levels must be positive and finite, got {s_}", problem.names)
    x0 = np.asarray(start, dtype=float)
    if x0.shape != (problem.n_params,) or not np.all(np.isfinite(x0)):
        raise InputError(f"start must be {problem.n_params} finite values, got shape {x0.shape}")
    w = 1.0 / s_**2
    A = np.einsum("j,jik->ik", w, problem.ZW)
    b = np.einsum("j,ji->i", w, problem.Zy)
    S = np.einsum("j,jik->ik", w, problem.ZZ)
    d = np.sqrt(np.maximum(np.diag(S), 1e-300))
    As, Ss = A / np.outer(d, d), S / np.outer(d, d)
    if not np.all(np.isfinite(As)):
        raise IdentifiabilityError("the instruments' cross products are not finite", problem.names)
    U, sv, Vt = np.linalg.svd(As)
    if not sv[0] > 0:
        raise IdentifiabilityError("the instruments do not determine the parameters (Z^T W is zero)", problem.names)
    keep = sv >= rtol * sv[0]
    P = (Vt[keep].T / sv[keep]) @ U[:, keep].T
    x = d * x0 + P @ (b / d - As @ (d * x0))
    cov = (P @ Ss @ P.T) / np.outer(d, d)
    return x / d, 0.5 * (cov + cov.T), float(sv[0] / sv[keep][-1]), int(keep.sum())


def determined_directions(A: FloatArray, S: FloatArray, rtol: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The parameter directions a step's normal equations determine, as fixed bases.

    ``A`` (p, p): the weighted cross product of the step's instruments and regressor
    (:math:`\\sum_j w_j Z_j^T W_j`; DIDIM's least squares: :math:`\\sum_j w_j W_j^T W_j`),
    ``S`` (p, p) that of the instruments with themselves (column scaling ``d = sqrt(diag S)``, as
    :func:`iv_solve`). With ``A / (d d^T) = U diag(s) V^T``, the directions with
    ``s_i >= rtol * s_max`` are kept. Returns ``(TU, TV, s / s_max)``: ``TV = V_k / d`` (p, r),
    the parameter directions (``beta = beta_0 + TV c``), ``TU = U_k / d`` (p, r), the
    combinations of the instruments that determine them (``Z TU``), and the relative singular
    values (all of them, for the record).

    Fixing these bases once per run (at the start's replay) makes the iteration a map on one
    affine subspace, ``beta_0 + range(TV)``: the parameters outside it keep their a priori
    values, the essential-parameter practice of Gautier's IDIM (the combinations the
    excitation does not determine are not estimated). Re-truncating at every iterate instead
    lets the kept subspace turn from one replay to the next (and its rank flip where a
    singular value sits at the threshold), so the held components drift with it.
    """
    A, S = np.asarray(A, dtype=float), np.asarray(S, dtype=float)
    d = np.sqrt(np.maximum(np.diag(S), 1e-300))
    As = A / np.outer(d, d)
    if not np.all(np.isfinite(As)):
        raise IdentifiabilityError("the instruments' cross products are not finite", ())
    U, sv, Vt = np.linalg.svd(As)
    if not sv[0] > 0:
        raise IdentifiabilityError("the instruments do not determine the parameters (Z^T W is zero)", ())
    keep = sv >= rtol * sv[0]
    return U[:, keep] / d[:, None], Vt[keep].T / d[:, None], sv / sv[0]


def reduce_instrumental(problem: InstrumentalProblem, TU: FloatArray, TV: FloatArray, beta0: FloatArray,
                        names: Sequence[str]) -> InstrumentalProblem:
    """The IV problem of ``beta = beta0 + TV c`` with the instruments ``Z TU`` (exact cross
    products: regressor ``W TV``, outputs ``y - W beta0``). IDIM-IV on the reduced parameters
    ``c`` (Janot 2014, Eqs. 18-25) is square and well posed when ``TU``, ``TV`` come from
    :func:`determined_directions`."""
    TU, TV, b0 = (np.asarray(a, dtype=float) for a in (TU, TV, beta0))
    ZW, WW = problem.ZW, problem.WW
    Zr = problem.Zy - np.einsum("jik,k->ji", ZW, b0)
    Wr = problem.Wy - np.einsum("jik,k->ji", WW, b0)
    yy = problem.yy - 2.0 * problem.Wy @ b0 + np.einsum("i,jik,k->j", b0, WW, b0)
    return InstrumentalProblem(tuple(names), problem.channel_names, TU.T @ ZW @ TV, TU.T @ problem.ZZ @ TU,
                               TV.T @ WW @ TV, Zr @ TU, Wr @ TV, np.maximum(yy, 0.0), problem.n_obs.copy())


def iv_result(problem: InstrumentalProblem, beta: FloatArray, cov: FloatArray, sigma: FloatArray, cond: float, *,
              method: str, solver: dict, provenance: dict, notes: tuple[str, ...],
              expressions: tuple[str, ...] | None = None) -> IdentificationResult:
    """An :class:`IdentificationResult` of an instrumental-variable (or output-error) fit."""
    rss = problem.rss_per_channel(beta)
    p = problem.n_params
    dof = int(problem.n_obs.sum()) - p
    if dof <= 0:
        raise InputError(f"fewer observations ({int(problem.n_obs.sum())}) than parameters ({p})")
    w = 1.0 / np.asarray(sigma, dtype=float) ** 2
    return IdentificationResult(
        method=method, names=problem.names, params=np.asarray(beta, dtype=float), cov_params=cov, dof=dof,
        scale=float(np.sum(w * rss) / dof), channel_names=problem.channel_names,
        n_obs=problem.n_obs.astype(np.int64), rss_per_channel=rss, noise_std=np.asarray(sigma, dtype=float),
        condition_number=float(cond), expressions=expressions, solver=solver, provenance=provenance, notes=notes)


def fixed_point_covariance(inputs: FloatArray, outputs: FloatArray, cov: FloatArray, *, rtol: float = 1e-2,
                           max_radius: float = 0.95) -> tuple[FloatArray, FloatArray]:
    """The covariance of an iteration's fixed point from that of one step, with the iteration's
    Jacobian estimated by secants.

    An iteration :math:`\\beta_{k+1} = F(\\beta_k)` whose every step is a regression with
    covariance :math:`C` (DIDIM: least squares on the regressor of the motion simulated with
    :math:`\\beta_k`) has its fixed point :math:`\\beta^* = F(\\beta^*)`. Linearized,
    :math:`\\delta^* = (I - M)^{-1}\\,\\delta_1` with :math:`M = \\partial F/\\partial\\beta` and
    :math:`\\delta_1` one step's error, so
    :math:`\\mathrm{cov}(\\beta^*) = (I - M)^{-1} C (I - M)^{-T}`. :math:`M` is estimated from
    the iterates themselves (the secant equations :math:`M\\,\\Delta\\beta_k = \\Delta F_k`,
    least squares on their span, in units of the standard deviations of :math:`C`; the
    directions the iteration never moved along keep :math:`M = 0`). The slowly contracting
    directions, which amplify the error, are those the late iterates move along, so a few
    iterates find them (a low-rank, Broyden-type estimate).

    Parameters
    ----------
    inputs, outputs : arrays (k, p)
        ``beta_k`` and ``F(beta_k)`` of the iterations (k >= 2).
    cov : array (p, p)
        The covariance of one step.

    Returns
    -------
    cov_star : array (p, p)
        The fixed point's covariance (``cov`` when fewer than two iterations, or when the
        estimated iteration does not contract: spectral radius above ``max_radius``).
    eigenvalues : array
        The eigenvalues of the estimated Jacobian on the span of the steps (empty when none).
    """
    X, Fx, C = (np.asarray(a, dtype=float) for a in (inputs, outputs, cov))
    if X.shape[0] < 2:
        return C, np.zeros(0)
    s = np.sqrt(np.maximum(np.diag(C), 1e-300))
    dX = np.diff(X, axis=0) / s
    dF = np.diff(Fx, axis=0) / s
    U, sv, Vt = np.linalg.svd(dX, full_matrices=False)  # rows of dX: the steps
    keep = sv > rtol * sv[0] if sv.size and sv[0] > 0 else np.zeros(sv.size, dtype=bool)
    if not keep.any():
        return C, np.zeros(0)
    V = Vt[keep].T  # p x r: the span of the steps
    # M dX_k = dF_k for every k: M V (V^T dX_k) = dF_k  ->  M V = dF^T pinv(dX V)^T
    MV = np.linalg.lstsq(dX @ V, dF, rcond=None)[0].T  # p x r
    eig = np.linalg.eigvals(V.T @ MV)
    if np.max(np.abs(eig)) > max_radius:
        return C, eig
    p = C.shape[0]
    M = MV @ V.T
    A = np.linalg.inv(np.eye(p) - M)
    Cs = C / np.outer(s, s)
    out = (A @ Cs @ A.T) * np.outer(s, s)
    return 0.5 * (out + out.T), eig



def oscillation_relaxation(x_prev: FloatArray, fx_prev: FloatArray, x: FloatArray, fx: FloatArray,
                           scale: FloatArray) -> tuple[FloatArray, float, float]:
    """The next iterate of a fixed-point iteration, relaxed along its last move when the step
    reversed there: ``(x_next, alpha, lam)``.

    An iteration :math:`x_{k+1} = T(x_k)` (IDIM-IV, DIDIM: :mod:`dynid.pipeline.control_loop`)
    with steps :math:`s_k = T(x_k) - x_k`; everything in units of ``scale`` (the parameters'
    standard deviations, as the stopping rule measures the moves). Along the last move
    :math:`d = x_k - x_{k-1}` the secant of :math:`G = T - I` gives the estimate
    :math:`\\lambda = 1 + (s_k - s_{k-1})^T d / d^T d` of :math:`T`'s Jacobian along ``d`` (for a
    full step, :math:`d = s_{k-1}`, the ratio of successive steps along the previous one,
    :math:`s_k^T s_{k-1} / s_{k-1}^T s_{k-1}`; for a linear :math:`T` and ``d`` along an
    eigenvector, that eigenvalue). A 2-cycle is :math:`\\lambda = -1`, a growing oscillation
    :math:`\\lambda < -1`, a damped one :math:`-1 < \\lambda < 0`.

    Rule: when, and only when, the step reversed along the move (:math:`\\lambda < 0`), the
    component of the step along :math:`\\hat d` is scaled by the secant (Aitken) factor
    :math:`\\alpha = 1 / (1 - \\lambda) \\in (0, 1)`, the root of the secant of :math:`G` along
    ``d`` (the secant method on one direction; for a full step it is Aitken's :math:`\\Delta^2`
    extrapolation of that component, A. C. Aitken, Proc. R. Soc. Edinburgh 46, 1926); the rest of
    the step is taken as it is:

    .. math::

        x_{k+1} = x_k + s_k - (1 - \\alpha)\\,(\\hat d^T s_k)\\,\\hat d .

    Otherwise (:math:`\\lambda \\ge 0`: no reversal, or no move to take a secant along)
    :math:`x_{k+1} = T(x_k)`, the plain iteration, bit for bit. Along ``d`` the relaxed map's factor
    is 0 to first order (the plain one's :math:`|\\lambda|`, 1 for a 2-cycle); the other
    directions keep the plain iteration's factors (a relaxation of the whole step,
    :math:`x_k + \\alpha s_k`, would slow every direction that contracts monotonically, from
    :math:`\\nu` to :math:`(\\nu - \\lambda)/(1 - \\lambda)`). Its fixed points are :math:`T`'s
    (:math:`s_k = 0` gives :math:`x_{k+1} = x_k`), so the converged estimate is still the method's.
    ``alpha`` is 1 when no relaxation acted; ``lam`` NaN when there is no move.
    """
    x, fx = np.asarray(x, dtype=float), np.asarray(fx, dtype=float)
    sc = np.asarray(scale, dtype=float)
    sc = np.where(sc > 0, sc, 1.0)
    d = (x - np.asarray(x_prev, dtype=float)) / sc
    dd = float(d @ d)
    if not dd > 0:
        return fx, 1.0, float("nan")
    step_prev = (np.asarray(fx_prev, dtype=float) - np.asarray(x_prev, dtype=float)) / sc
    step = (fx - x) / sc
    lam = 1.0 + float((step - step_prev) @ d) / dd
    if not (np.isfinite(lam) and lam < 0.0):
        return fx, 1.0, lam
    alpha = 1.0 / (1.0 - lam)
    along = float(step @ d) / dd  # the step's component along d, in units of d
    return fx - (1.0 - alpha) * along * d * sc, alpha, lam
