"""More time-domain filters and differentiators (papers 001 §4, 003 §4.3).

* :func:`butter_spec_sos`: the lowest-order Butterworth meeting a specification (pass-band
  edge, stop-band edge, pass-band ripple, stop-band attenuation; ``buttord`` as in paper 003:
  50 Hz sampling, 1 Hz pass, 5 Hz stop, 1 dB, 15 dB) in SOS form. The specification holds for
  one pass; the zero-phase pair (:func:`dynid.signals.lowpass_sos`) doubles both the ripple
  and the attenuation in dB.
* :func:`moving_average`: centred moving-average prefilter (paper 003's "average filtering").
* :func:`lowess`: locally weighted linear regression with tricube weights (Cleveland 1979),
  paper 003's final smoothing.
* :func:`savgol`: Savitzky–Golay smoothing and derivatives (a local polynomial fit).

Time on axis 0, frequencies in Hz.
"""

from __future__ import annotations

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["butter_spec_sos", "lowess", "moving_average", "savgol"]


def butter_spec_sos(fs: float, pass_hz: float, stop_hz: float, ripple_db: float, attenuation_db: float) -> tuple[FloatArray, int, float]:
    """Lowest-order low-pass Butterworth with at most ``ripple_db`` loss up to ``pass_hz`` and at
    least ``attenuation_db`` from ``stop_hz`` (one pass).

    Returns
    -------
    sos : array, shape (n_sections, 6)
    order : int
    cutoff_hz : float
        The -3 dB frequency of the designed filter.
    """
    if not 0 < pass_hz < stop_hz < fs / 2:
        raise InputError(f"need 0 < pass_hz < stop_hz < fs/2; got {pass_hz}, {stop_hz}, fs = {fs}")
    if not 0 < ripple_db < attenuation_db:
        raise InputError(f"need 0 < ripple_db < attenuation_db; got {ripple_db}, {attenuation_db}")
    from scipy import signal as ss

    order, wn = ss.buttord(pass_hz, stop_hz, ripple_db, attenuation_db, fs=fs)
    return ss.butter(order, wn, btype="low", output="sos", fs=fs), int(order), float(wn)


def moving_average(x: FloatArray, window: int, axis: int = 0) -> FloatArray:
    """Centred moving average over ``window`` (odd) samples; edges use the nearest sample."""
    if window < 1 or window % 2 == 0:
        raise InputError(f"the moving-average window must be an odd number of samples, got {window}")
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(np.asarray(x, dtype=float), size=window, axis=axis, mode="nearest")


def lowess(x: FloatArray, t: FloatArray, frac: float = 0.05) -> FloatArray:
    """LOWESS smoothing: at each sample, a linear fit to the ``frac`` nearest samples in time with
    tricube weights (no robustness iterations). Shape (n,) or (n, channels)."""
    a = np.asarray(x, dtype=float)
    flat = a.ndim == 1
    a = a[:, None] if flat else a
    t = np.asarray(t, dtype=float)
    n = t.size
    if a.shape[0] != n:
        raise InputError(f"x has {a.shape[0]} samples for {n} times")
    k = max(3, int(np.ceil(frac * n)))
    if k > n:
        raise InputError(f"frac = {frac} asks for more samples than the {n} there are")
    out = np.empty_like(a)
    half = k // 2
    for i in range(n):
        lo = min(max(0, i - half), n - k)
        tt = t[lo : lo + k] - t[i]
        h = np.abs(tt).max() * 1.0001
        w = (1 - (np.abs(tt) / h) ** 3) ** 3
        sw, swt, swtt = w.sum(), (w * tt).sum(), (w * tt * tt).sum()
        y = a[lo : lo + k]
        swy, swty = w @ y, (w * tt) @ y
        det = sw * swtt - swt**2
        out[i] = (swtt * swy - swt * swty) / det  # the fitted line at tt = 0
    return out[:, 0] if flat else out


def savgol(x: FloatArray, fs: float, window: int, polyorder: int = 3, deriv: int = 0, axis: int = 0) -> FloatArray:
    """Savitzky–Golay smoothing (``deriv = 0``) or derivative of order ``deriv`` [per s^deriv]."""
    if window % 2 == 0 or window <= polyorder:
        raise InputError(f"the Savitzky-Golay window must be odd and longer than the polynomial order, got {window}, {polyorder}")
    from scipy import signal as ss

    return ss.savgol_filter(np.asarray(x, dtype=float), window, polyorder, deriv=deriv, delta=1.0 / fs, axis=axis, mode="interp")
