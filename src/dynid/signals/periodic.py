"""Processing of periodic excitation data (paper 004, §3.2–3.3; Swevers et al. 1997).

* :func:`period_average`: mean over ``N_m`` periods and the full noise covariance across
  channels, paper 004 §3.2:
  :math:`\\hat\\sigma^2_{ij} = \\frac{1}{N}\\frac{1}{N_m - 1}\\sum_k (x_{i,k} - \\bar x_i)^T(x_{j,k} - \\bar x_j)`
  (cross-correlations included: the actuators of a parallel robot are coupled);
* :func:`fourier_filter`: *exact* frequency-domain filtering and differentiation of a record
  that spans whole periods of the real motion: DFT, rectangular window at the cut-off,
  multiplication by :math:`j\\omega` and :math:`-\\omega^2`, inverse DFT (paper 004 §3.3). The
  frequency grid is the record's own, so a fundamental frequency that differs from the
  nominal one causes no leakage;
* :func:`fourier_fit`: the *implicit* alternative (Olsen & Swevers; paper 004 Eqs. 17–18): least
  squares fit of the Fourier coefficients at the *nominal* harmonic frequencies; exact only
  when the real fundamental frequency equals the nominal one.

Time on axis 0, frequencies in Hz.
"""

from __future__ import annotations

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["fourier_filter", "fourier_fit", "period_average"]


def _as_2d(x: FloatArray, name: str) -> tuple[FloatArray, bool]:
    a = np.asarray(x, dtype=float)
    if a.ndim not in (1, 2):
        raise InputError(f"{name} must be 1-D or 2-D (samples, channels), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} contains NaN or infinite values")
    return (a[:, None], True) if a.ndim == 1 else (a, False)


def period_average(x: FloatArray, samples_per_period: int) -> tuple[FloatArray, FloatArray]:
    """Average over whole periods and the noise covariance across channels.

    Parameters
    ----------
    x : array, shape (N_m * N, n_channels)
        ``N_m`` consecutive periods of ``N`` samples each (a trailing partial period is an error).
    samples_per_period : int
        ``N``.

    Returns
    -------
    mean : array, shape (N, n_channels)
        :math:`\\bar x`, the average period.
    cov : array, shape (n_channels, n_channels)
        :math:`\\hat\\Sigma` of the noise of a single sample (paper 004 §3.2). The noise of the
        averaged signal is :math:`\\hat\\Sigma / N_m`.
    """
    a, _ = _as_2d(x, "x")
    n = int(samples_per_period)
    if n < 2 or a.shape[0] % n:
        raise InputError(f"{a.shape[0]} samples are not a whole number of periods of {n} samples")
    n_m = a.shape[0] // n
    if n_m < 2:
        raise InputError("period averaging needs at least 2 periods to estimate a covariance")
    periods = a.reshape(n_m, n, a.shape[1])
    mean = periods.mean(axis=0)
    dev = periods - mean
    cov = np.einsum("kti,ktj->ij", dev, dev) / (n * (n_m - 1))
    return mean, cov


def fourier_filter(x: FloatArray, fs: float, cutoff_hz: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Exact frequency-domain low-pass and first two derivatives of a periodic record.

    Parameters
    ----------
    x : array, shape (N,) or (N, n_channels)
        A record spanning a whole number of periods of the motion (e.g. an averaged period).
    fs : float
        Sampling rate [Hz].
    cutoff_hz : float
        Rectangular window: DFT bins above it are set to zero (e.g. the highest harmonic of
        the excitation).

    Returns
    -------
    x_f, dx, ddx : arrays like ``x``
        Filtered signal, its first and second time derivatives (units per s, per s²).
    """
    a, flat = _as_2d(x, "x")
    n = a.shape[0]
    if not fs > 0 or not 0 < cutoff_hz < fs / 2:
        raise InputError(f"the cut-off must lie in (0, fs/2 = {fs / 2:g}) Hz and fs be positive; got {cutoff_hz}, {fs}")
    X = np.fft.rfft(a, axis=0)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    X[f > cutoff_hz] = 0.0
    if n % 2 == 0:
        X[-1] = 0.0  # the Nyquist bin has no sign for a derivative
    jw = (2j * np.pi * f)[:, None]
    out = [np.fft.irfft(X * m, n=n, axis=0) for m in (1.0, jw, jw**2)]
    return tuple(o[:, 0] if flat else o for o in out)  # type: ignore[return-value]


def fourier_fit(x: FloatArray, t: FloatArray, f0_hz: float, harmonics: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Implicit Fourier filtering: least-squares coefficients at the nominal harmonics.

    Fits :math:`x(t) = c_0 + \\sum_{k=1}^{n_h} a_k \\sin(k\\omega_f t) + b_k\\cos(k\\omega_f t)`
    with :math:`\\omega_f = 2\\pi f_0` (paper 004, Eqs. 17–18) and returns the fitted signal and
    its analytic derivatives.
    """
    a, flat = _as_2d(x, "x")
    t = np.asarray(t, dtype=float)
    if t.shape != (a.shape[0],):
        raise InputError(f"t has {t.shape} samples for {a.shape[0]} signal samples")
    w = 2 * np.pi * f0_hz * np.arange(1, harmonics + 1)
    s, c = np.sin(np.outer(t, w)), np.cos(np.outer(t, w))
    B = np.hstack([np.ones((t.size, 1)), s, c])
    coef, *_ = np.linalg.lstsq(B, a, rcond=None)
    cs, cc = coef[1 : 1 + harmonics], coef[1 + harmonics :]
    xf = B @ coef
    dx = (c * w) @ cs - (s * w) @ cc
    ddx = -(s * w**2) @ cs - (c * w**2) @ cc
    out = (xf, dx, ddx)
    return tuple(o[:, 0] if flat else o for o in out)  # type: ignore[return-value]
