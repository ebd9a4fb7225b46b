"""Signal processing on arrays: filtering, differentiation, resampling, decimation.

Pure NumPy/SciPy functions. Time is axis 0 of every array and frequencies are in Hz
(``cutoff_hz``, ``fs``). Cut-offs are passed to SciPy with ``fs=`` so they are never
normalized by hand (a common bug in peer tools is to pass ``ts*fc/2`` as the
normalized frequency, which silently quarters the cut-off; see ../shared/DESIGN.md).

Notes
-----
A zero-phase (forward-backward) Butterworth filter of order ``n`` has magnitude
``|H(f)|^2`` where ``|H|`` is that of the single pass: the single pass is -3 dB at
``cutoff_hz``, the zero-phase pair -6 dB. Shang et al. 2009 (paper 001, §4) and Ku et
al. 2026 (paper 003, §4.3) use this filter before central differences.
"""

from __future__ import annotations

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = [
    "butter_sos",
    "lowpass",
    "central_difference",
    "derivatives",
    "resample_uniform",
    "decimate",
    "padlen_for",
    "decimation_filter",
    "decimation_segments",
    "lowpass_sos",
    "zero_phase_settling_time",
]


def _check_cutoff(cutoff_hz: float, fs: float) -> None:
    if not (fs > 0 and np.isfinite(fs)):
        raise InputError(f"sampling rate fs must be positive and finite, got {fs!r} Hz")
    if not (0 < cutoff_hz < fs / 2):
        raise InputError(
            f"cut-off {cutoff_hz!r} Hz must lie in (0, fs/2) = (0, {fs / 2:g}) Hz"
        )


def butter_sos(order: int, cutoff_hz: float, fs: float) -> FloatArray:
    """Second-order sections of a low-pass Butterworth filter.

    Parameters
    ----------
    order : int
        Filter order (>= 1).
    cutoff_hz : float
        -3 dB frequency of one pass [Hz].
    fs : float
        Sampling rate [Hz].
    """
    if int(order) < 1:
        raise InputError(f"filter order must be >= 1, got {order!r}")
    _check_cutoff(cutoff_hz, fs)
    from scipy import signal  # here, not at import: scipy.signal alone is about a second

    return signal.butter(int(order), cutoff_hz, btype="low", output="sos", fs=fs)


def padlen_for(order: int, cutoff_hz: float, fs: float) -> int:
    """Samples of edge transient of the zero-phase filter (about 5 time constants)."""
    return int(np.ceil(5.0 * order * fs / (2.0 * np.pi * cutoff_hz)))


def zero_phase_settling_time(order: int, cutoff_hz: float, tol: float = 0.01) -> float:
    """Seconds over which the zero-phase Butterworth low-pass of :func:`lowpass` smears a step:
    the largest distance from the step at which its output differs from the step by more than
    ``tol`` (relative), on either side (the forward-backward pair is symmetric up to a sample).

    A property of the continuous filter (computed at 200 samples per cut-off period, where the
    discrete filter has converged to it): 0.12 s for order 4 at 10 Hz, 0.08 s for order 2.
    Used by ``processing.reversal_guard = "auto"``: a velocity reversal is a step in the
    acceleration (Coulomb friction flips), and a sample within this distance of it carries the
    filter's smear of that step into the regressor while the measured effort does not.
    """
    fs = 200.0 * cutoff_hz
    half = int(np.ceil(fs * (2.0 + 2.0 * order) / cutoff_hz))
    step = np.r_[np.zeros(half), np.ones(half)]
    err = np.abs(lowpass(step, cutoff_hz, fs, order) - step)
    far = np.nonzero(err > tol)[0]
    if far.size == 0:
        return 0.0
    return float(max(half - far.min(), far.max() + 1 - half) / fs)


def lowpass(x: FloatArray, cutoff_hz: float, fs: float, order: int = 4, axis: int = 0) -> FloatArray:
    """Zero-phase Butterworth low-pass filter (``sosfiltfilt``).

    Parameters
    ----------
    x : array, shape (n, ...)
        Signal, time on ``axis``.
    cutoff_hz, fs, order
        See :func:`butter_sos`. The zero-phase result is -6 dB at ``cutoff_hz``.

    Returns
    -------
    array, same shape as ``x``
    """
    return lowpass_sos(np.asarray(x, dtype=float), butter_sos(order, cutoff_hz, fs), axis=axis)


def central_difference(x: FloatArray, t: FloatArray | float) -> FloatArray:
    """Derivative along axis 0 by central differences.

    For uniform sampling interior samples use ``(x[i+1] - x[i-1]) / (t[i+1] - t[i-1])``
    (for irregular ``t``, ``np.gradient``'s second-order weighted form); the two end
    samples use second-order one-sided differences.

    Parameters
    ----------
    x : array, shape (n, ...)
    t : array, shape (n,), or float
        Sample times [s] or the uniform sampling period [s].
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] < 3:
        raise InputError(f"central differences need at least 3 samples, got {x.shape[0]}")
    return np.gradient(x, t, axis=0, edge_order=2)


def derivatives(q: FloatArray, t: FloatArray | float) -> tuple[FloatArray, FloatArray]:
    """Velocity and acceleration of ``q`` by repeated central differences."""
    dq = central_difference(q, t)
    return dq, central_difference(dq, t)


def resample_uniform(
    t: FloatArray, x: FloatArray, fs: float | None = None, kind: str = "linear"
) -> tuple[FloatArray, FloatArray]:
    """Interpolate irregularly sampled data onto a uniform time grid.

    Parameters
    ----------
    t : array, shape (n,)
        Strictly increasing sample times [s].
    x : array, shape (n, ...)
        Samples.
    fs : float, optional
        New sampling rate [Hz]; default ``1 / median(diff(t))``.
    kind : {"linear", "cubic"}
        Linear interpolation, or a not-a-knot cubic spline (smooth derivatives).

    Returns
    -------
    t_new : array, shape (m,)
        ``t[0] + k / fs`` for all ``k`` with ``t_new <= t[-1]``.
    x_new : array, shape (m, ...)
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1 or t.shape[0] != x.shape[0]:
        raise InputError(f"mismatched lengths: time has {t.shape} samples, data {x.shape}")
    if not np.all(np.diff(t) > 0):  # also catches NaN
        raise InputError("time is not strictly increasing (or not finite); cannot resample")
    if fs is None:
        fs = 1.0 / float(np.median(np.diff(t)))
    if not (fs > 0 and np.isfinite(fs)):
        raise InputError(f"resampling rate must be positive, got {fs!r} Hz")
    m = int(np.floor((t[-1] - t[0]) * fs + 1e-9)) + 1
    t_new = t[0] + np.arange(m) / fs
    if kind == "linear":
        flat = x.reshape(x.shape[0], -1)
        out = np.empty((m, flat.shape[1]))
        for j in range(flat.shape[1]):
            out[:, j] = np.interp(t_new, t, flat[:, j])
        x_new = out.reshape((m,) + x.shape[1:])
    elif kind == "cubic":
        from scipy.interpolate import CubicSpline

        x_new = CubicSpline(t, x, axis=0)(t_new)
    else:
        raise InputError(f"unknown interpolation kind {kind!r} (use 'linear' or 'cubic')")
    return t_new, x_new


def decimate(x: FloatArray, factor: int, fs: float | None = None, order: int = 8, axis: int = 0) -> FloatArray:
    """Keep one sample in ``factor`` after a zero-phase anti-aliasing low-pass.

    The anti-aliasing filter is a zero-phase Butterworth at 0.8 of the new Nyquist
    frequency (``0.8 * fs / (2 * factor)``), so decimated data carry no alias.
    ``fs`` only sets the units; the result does not depend on it.
    """
    factor = int(factor)
    if factor < 1:
        raise InputError(f"decimation factor must be >= 1, got {factor}")
    x = np.asarray(x, dtype=float)
    if factor == 1:
        return x.copy()
    sos, _ = decimation_filter(factor, 1.0 if fs is None else float(fs), order)
    y = lowpass_sos(x, sos, axis=axis)
    return np.take(y, np.arange(0, x.shape[axis], factor), axis=axis)


def decimation_filter(factor: int, fs: float, order: int = 8) -> tuple[FloatArray, int]:
    """Anti-aliasing filter of :func:`decimate` and the overlap a chunked version needs.

    Returns the SOS of a Butterworth low-pass at ``0.8 * fs / (2 * factor)`` and the
    number of samples (15 time constants of the filter) by which chunks must overlap
    so that chunk-wise zero-phase filtering equals whole-signal filtering to ~1e-12.
    """
    cutoff = 0.8 * fs / (2 * int(factor))
    sos = butter_sos(order, cutoff, fs)
    margin = int(np.ceil(15.0 * order * fs / (2.0 * np.pi * cutoff)))
    return sos, margin


def decimation_segments(n: int, factor: int, margin: int, chunk: int):
    """Plan chunk-wise zero-phase filtering followed by keeping samples ``0, k, 2k, ...``.

    Yields ``(a, b, keep)``: filter input rows ``a:b`` (the chunk plus ``margin`` rows
    on each side, clipped to the signal), then keep the rows ``keep`` (indices into
    the segment) of the filtered segment. Concatenating the kept rows of all segments
    gives the decimated signal.
    """
    factor, chunk = int(factor), max(int(chunk), int(factor))
    chunk -= chunk % factor  # chunk boundaries on the output grid
    for s in range(0, n, chunk):
        e = min(s + chunk, n)
        a, b = max(0, s - margin), min(n, e + margin)
        yield a, b, np.arange(s, e, factor) - a


def lowpass_sos(x: FloatArray, sos: FloatArray, axis: int = 0) -> FloatArray:
    """Zero-phase filtering with given second-order sections (same padding as :func:`lowpass`)."""
    n = x.shape[axis]
    if n < 4:
        raise InputError(f"signal of {n} samples is too short to filter")
    from scipy import signal

    return signal.sosfiltfilt(sos, x, axis=axis, padtype="odd", padlen=min(3 * (2 * sos.shape[0] + 1), n - 1))


from dynid.signals.filters import butter_spec_sos, lowess, moving_average, savgol  # noqa: E402
from dynid.signals.periodic import fourier_filter, fourier_fit, period_average  # noqa: E402

__all__ += [
    "butter_spec_sos",
    "fourier_filter",
    "fourier_fit",
    "lowess",
    "moving_average",
    "period_average",
    "savgol",
]
