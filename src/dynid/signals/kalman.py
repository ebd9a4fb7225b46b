"""Kalman (Rauch-Tung-Striebel) smoothing of sampled positions: positions, velocities and
accelerations of each coordinate from its measured positions alone.

The model
---------
Each coordinate is a white noise in its :math:`m`-th derivative, sampled every :math:`T` seconds
and measured with white noise of variance :math:`R` (:math:`m = 3`: white jerk, the "constant
acceleration" model of Bar-Shalom, Li & Kirubarajan 2001, *Estimation with Applications to
Tracking and Navigation*, Sec. 6.3.3; :math:`m = 4`, the default :data:`ORDER`: white snap):
state :math:`x = (q, \\dot q, \\ddot q, \\dots)` (:math:`m` entries),
:math:`x_{k+1} = F x_k + w_k`, :math:`z_k = x_{k,1} + v_k`, with :math:`F_{ij} = T^{j-i}/(j-i)!` and
:math:`\\mathrm{Cov}(w_k)_{ij} = q\\,T^{2m-1-i-j} / ((2m-1-i-j)(m-1-i)!(m-1-j)!)` (0-based
indices; :math:`q` the spectral density of the driving noise). In the scaled state
:math:`(q, T\\dot q, T^2\\ddot q, \\dots)` (all in position units) the matrices depend on
:math:`T` only through :math:`q T^{2m-1}`, so the steady-state filter depends on one number, the
noise ratio :math:`\\lambda = R / (q T^{2m-1})`: large :math:`\\lambda`, a smooth motion and a low
bandwidth (about :math:`\\lambda^{-1/(2m)}/(2\\pi T)`); small, the measurements followed closely.

Steady state (a uniformly sampled log): the a-priori covariance :math:`P` solves the discrete
algebraic Riccati equation (:func:`scipy.linalg.solve_discrete_are`), the gain is
:math:`K = P H^T / S` with :math:`S = H P H^T + R`, the filter is the linear time-invariant
recursion :math:`x_{k|k} = (I - K H) F x_{k-1|k-1} + K z_k`, run mode by mode (:func:`_recursion`)
from a polynomial fit of the first samples (:func:`_start`). The Rauch-Tung-Striebel smoother (Rauch, Tung & Striebel 1965)
with the steady-state gain :math:`C = P_f F^T P^{-1}` (:math:`P_f = (I - K H) P`) is run on the
deviation :math:`d_k = x_{k|N} - x_{k|k}`, :math:`d_k = C (d_{k+1} + x_{k+1|k+1} - F x_{k|k})`,
:math:`d_N = 0`, exact from its last sample. The smoothed covariance :math:`P_s` solves
:math:`P_s = P_f + C (P_s - P) C^T` (a discrete Lyapunov equation): the standard deviations of the
smoothed position, velocity and acceleration, reported with the estimate.

The noise
---------
:math:`R` is the measurement noise: given (the encoder's quantization, ``resolution^2 / 12``, or a
known noise std) or estimated with :math:`\\lambda`. :math:`\\lambda` is estimated by maximum
likelihood from the log itself (Mehra 1970): the steady-state innovations
:math:`e_k = z_k - H F x_{k-1|k-1}` are white with variance :math:`S` under the model, so

.. math::

    -2 \\log L(\\lambda, R) = N \\log S + \\sum_k e_k^2 / S + \\text{const},
    \\qquad S = R\\, s(\\lambda),\\ s(\\lambda) = 1 + H \\bar P(\\lambda) H^T / \\lambda,

with :math:`\\bar P` the Riccati solution for unit :math:`q T^{2m-1}` and :math:`R = \\lambda`. With
:math:`R` unknown its maximum is at :math:`\\hat R = \\overline{e^2} / s(\\lambda)` and the profile
:math:`-2\\log L = N \\log \\overline{e^2}`: the :math:`\\lambda` of the smallest one-step prediction
error. The search is on :math:`\\log_{10}\\lambda` (a grid, then a bounded scalar search around
its best point).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["KalmanFit", "steady_state", "smooth", "fit_noise_ratio"]

import math


def _model(order: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Scaled F, Q (unit q T^(2 order - 1)) and H of a white noise in the ``order``-th derivative:
    F_ij = 1 / (j - i)!, Q_ij = 1 / ((2m - 1 - i - j) (m - 1 - i)! (m - 1 - j)!) with m = order."""
    m = order
    F = np.array([[1.0 / math.factorial(j - i) if j >= i else 0.0 for j in range(m)] for i in range(m)])
    Q = np.array([[1.0 / ((2 * m - 1 - i - j) * math.factorial(m - 1 - i) * math.factorial(m - 1 - j))
                   for j in range(m)] for i in range(m)])
    H = np.zeros((1, m))
    H[0, 0] = 1.0
    return F, Q, H


ORDER = 4
"""The default model order: white noise in the 4th derivative (snap), state (q, dq, ddq, jerk); it
tracks a band-limited motion with a steeper roll-off than the white-jerk model (bench/README,
"Kalman smoothing against the Butterworth path"); 5 and above lose precision in the
transfer-function filtering (poles near 1)."""
LOG10_RANGE = (-3.0, 15.0)
"""The search interval of :math:`\\log_{10}\\lambda`: from a filter that follows every sample (its
bandwidth, about :math:`\\lambda^{-1/6}/(2\\pi T)`, at the Nyquist frequency) to one of about 4e-4 of the
sampling rate (0.4 Hz at 1 kHz), where the Riccati solver still converges in double precision (it
fails from about 1e16)."""


@dataclasses.dataclass(frozen=True)
class SteadyState:
    """The steady-state filter and smoother of one noise ratio (scaled state, unit :math:`q T^{2m-1}`)."""

    order: int
    F: FloatArray
    ratio: float  # lambda = R / (q T^(2m-1))
    P: FloatArray  # a-priori covariance (3, 3), for R = lambda
    K: FloatArray  # gain (3,)
    A: FloatArray  # (I - K H) F
    C: FloatArray  # smoother gain (3, 3)
    Ps: FloatArray  # smoothed covariance (3, 3), for R = lambda
    s: float  # S / R


def steady_state(ratio: float, order: int = ORDER) -> SteadyState:
    """The steady-state Kalman filter and RTS smoother of noise ratio ``ratio`` for a white noise in
    the ``order``-th derivative (module docstring)."""
    from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov

    lam = float(ratio)
    if not (np.isfinite(lam) and lam > 0):
        raise InputError(f"the Kalman noise ratio must be positive and finite, got {ratio!r}")
    _F, _Q, _H = _model(order)
    P = solve_discrete_are(_F.T, _H.T, _Q, np.array([[lam]]))
    P = 0.5 * (P + P.T)
    S = float(P[0, 0] + lam)
    K = P[:, 0] / S
    A = (np.eye(order) - np.outer(K, _H[0])) @ _F
    Pf = P - np.outer(K, P[0])
    C = Pf @ _F.T @ np.linalg.inv(P)
    Ps = solve_discrete_lyapunov(C, Pf - C @ P @ C.T)
    return SteadyState(order=order, F=_F, ratio=lam, P=P, K=K, A=A, C=C, Ps=0.5 * (Ps + Ps.T), s=S / lam)


def _start(z: FloatArray, ss: SteadyState) -> FloatArray:
    """The scaled state before the first sample (3, m): a quadratic least-squares fit of the first
    ``L`` samples, ``L`` about the filter's memory ``1 / (1 - rho)`` (``rho`` its slowest pole), at
    least 8 and at most a quarter of the log, extrapolated one sample back."""
    n = z.shape[0]
    rho = float(np.max(np.abs(np.linalg.eigvals(ss.A))))
    L = int(min(max(8, np.ceil(1.0 / max(1.0 - rho, 1e-12))), max(8, n // 4), n))
    k = np.arange(L, dtype=float)
    V = np.column_stack([k**i / math.factorial(i) for i in range(ss.order)])  # z_k = sum c_i k^i / i! (scaled)
    c = np.linalg.lstsq(V, z[:L], rcond=None)[0]  # (ORDER, m): the state at k = 0
    return np.linalg.solve(ss.F, c)  # the state at k = -1


def _recursion(A: FloatArray, u: FloatArray) -> FloatArray:
    """``s_k = A s_{k-1} + u_k`` from ``s_{-1} = 0`` for inputs ``u`` (n, m, ...), in the modal
    coordinates of ``A`` (its eigenvalues are distinct: a stable steady-state filter): one
    first-order recursion per mode (:func:`scipy.signal.lfilter`, complex), mapped back. A
    transfer-function (or second-order-section) form of the same filter loses up to 1e-7 of the
    signal to the rounding of its polynomial coefficients when the poles are near 1; the modal form
    loses the eigenvector matrix's condition number times the rounding (about 1e-13 here)."""
    from scipy.signal import lfilter

    lam, V = np.linalg.eig(A)
    y = np.einsum("ij,nj...->ni...", np.linalg.inv(V), u.astype(complex))
    for i, li in enumerate(lam):
        y[:, i] = lfilter([1.0], [1.0, -li], y[:, i], axis=0)
    return np.einsum("ij,nj...->ni...", V, y).real


def _forward(z: FloatArray, ss: SteadyState) -> FloatArray:
    """Filtered scaled states (n, 3, m) of measurements ``z`` (n, m), from the state :func:`_start`
    gives before the first sample: the response to ``z - z[0]`` from rest (:func:`_recursion`;
    the rest state of ``z[0]`` is ``(z[0], 0, 0)``) plus the free response of the start's difference
    from that rest state, carried until it is below 1e-12 of its size."""
    n = z.shape[0]
    z0 = z[0]
    dz = z - z0
    # x_k = A x_{k-1} + K z_k: state s_k = x_{k-1}, output x_k = A s_k + K z_k
    x = _recursion(ss.A, ss.K[None, :, None] * dz[:, None, :])
    x[:, 0] += z0
    free = _start(z, ss)
    free[0] -= z0
    scale = float(np.abs(free).max())
    for k in range(n):
        free = ss.A @ free
        x[k] += free
        if float(np.abs(free).max()) <= 1e-12 * scale:
            break
    return x


def _backward(x: FloatArray, ss: SteadyState) -> FloatArray:
    """RTS deviations d (n, order, m): d_k = C (d_{k+1} + v_k), v_k = x_{k+1} - F x_k, d_{n-1} = 0."""
    n = x.shape[0]
    v = x[1:] - np.einsum("ij,njm->nim", ss.F, x[:-1])  # (n-1, order, m)
    u = np.einsum("ij,njm->nim", ss.C, v)[::-1]
    d = np.zeros_like(x)
    d[:-1] = _recursion(ss.C, u)[::-1]  # reversed time: d'_j = C d'_{j-1} + u_j, d'_{-1} = d_{n-1} = 0
    return d


def _innovations(z: FloatArray, x: FloatArray, ss: SteadyState) -> FloatArray:
    pred = np.einsum("j,njm->nm", ss.F[0], x[:-1])
    return z[1:] - pred


def fit_noise_ratio(z: FloatArray, noise_var: float | None = None, order: int = ORDER) -> tuple[float, float]:
    """Maximum-likelihood noise ratio of one coordinate's measurements ``z`` (n,) and the
    measurement noise variance (``noise_var`` when given, else its estimate): ``(lambda, R)``
    (module docstring)."""
    from scipy.optimize import minimize_scalar

    z = np.asarray(z, dtype=float)[:, None]
    n = z.shape[0]
    skip = min(n // 10, 200)  # the filter's start from rest: left out of the likelihood

    def cost(log_ratio: float) -> float:
        try:
            ss = steady_state(10.0**log_ratio, order)
        except (ValueError, np.linalg.LinAlgError):  # the Riccati solver's limit (LOG10_RANGE)
            return float("inf")
        e = _innovations(z, _forward(z, ss), ss)[skip:, 0]
        m = float(np.mean(e * e))
        if noise_var is None:
            return float(np.log(max(m, 1e-300)))
        S = noise_var * ss.s
        return float(np.log(S) + m / S)

    grid = np.linspace(*LOG10_RANGE, 37)
    values = [cost(g) for g in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    best = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    log_ratio = float(best.x) if best.fun <= values[i] else float(grid[i])
    ratio = 10.0**log_ratio
    if noise_var is None:
        ss = steady_state(ratio, order)
        e = _innovations(z, _forward(z, ss), ss)[skip:, 0]
        noise_var = float(np.mean(e * e)) / ss.s
    return ratio, float(noise_var)


@dataclasses.dataclass(frozen=True)
class KalmanFit:
    """Smoothed positions, velocities, accelerations (n, m) and, per coordinate, the noise ratio,
    the measurement noise std and the smoothed estimates' standard deviations (steady state)."""

    q: FloatArray
    dq: FloatArray
    ddq: FloatArray
    ratio: FloatArray
    noise_std: FloatArray
    std: FloatArray  # (m, 3): position, velocity, acceleration
    settle: int  # samples after which the start-from-rest transient is below 1e-6 of its size


def smooth(q: FloatArray, dt: float, noise_std: float | FloatArray | None = None, order: int = ORDER) -> KalmanFit:
    """RTS smoothing of positions ``q`` (n, m) sampled every ``dt`` seconds (module docstring).

    ``noise_std``: the measurement noise std per coordinate (or one for all), e.g. an encoder's
    ``resolution / sqrt(12)``; None: estimated from the log with the noise ratio.
    """
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[:, None]
    n, m = q.shape
    if n < 20:
        raise InputError(f"Kalman smoothing needs at least 20 samples, got {n}")
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f"sampling period must be positive, got {dt!r}")
    given = None if noise_std is None else np.broadcast_to(np.asarray(noise_std, dtype=float), (m,))
    if given is not None and not np.all(np.isfinite(given) & (given > 0)):
        raise InputError(f"position noise std must be positive, got {noise_std!r}")
    Q, V, A = (np.empty((n, m)) for _ in range(3))
    ratios, stds, sig = np.empty(m), np.empty((m, 3)), np.empty(m)
    settle = 0
    for j in range(m):
        ratio, R = fit_noise_ratio(q[:, j], None if given is None else float(given[j]) ** 2, order)
        ss = steady_state(ratio, order)
        x = _forward(q[:, j : j + 1], ss)
        s = x + _backward(x, ss)
        Q[:, j], V[:, j], A[:, j] = s[:, 0, 0], s[:, 1, 0] / dt, s[:, 2, 0] / dt**2
        scale = R / ratio  # q T^(2 order - 1) of this coordinate
        stds[j] = np.sqrt(np.diag(ss.Ps)[:3] * scale) / np.array([1.0, dt, dt**2])
        ratios[j], sig[j] = ratio, np.sqrt(R)
        rho = float(np.max(np.abs(np.linalg.eigvals(ss.A))))
        settle = max(settle, int(np.ceil(np.log(1e-6) / np.log(rho))) if rho < 1 else n)
    return KalmanFit(q=Q, dq=V, ddq=A, ratio=ratios, noise_std=sig, std=stds, settle=settle)
