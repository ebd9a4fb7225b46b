"""The processing an expert derives from a log (``dynid init``, issue 34 items 2 and 7): the
low-pass cut-off from the motion's bandwidth, ``min_velocity`` from the velocity noise the
processing leaves, ``filter_effort`` from the Coulomb steps the efforts show, the decimation and
the reversal guard. :mod:`dynid.pipeline.starter` writes them into the starting config, each with
its reason."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["DerivedProcessing", "MIN_CUTOFF_HZ", "NOISE_SIGMAS", "STEP_RATIO", "SIGNAL_OVER_FLOOR", "cutoff_for",
           "derive_processing", "motion_bandwidth_hz"]

MIN_CUTOFF_HZ = 5.0
"""The default low-pass is never below this (unless the rate's fifth is): the position power
sees the dominant harmonics only, and the accelerations need more. On the KUKA LWR4 logs
(../shared/data/kuka_lwr4, run 1 whose motion is 0.12 Hz, validated on run 3) the held-out mean
relative RMSE of WLS was 109 % at 1.2 Hz, 91 % at 3, 84 % at 5, 86 % at 8 Hz."""

def motion_bandwidth_hz(q: FloatArray, fs: float, fraction: float = 0.99, *, derivative: int = 0) -> float:
    r"""The frequency below which ``fraction`` of the power of the (linearly detrended, Hann
    windowed) positions lies, the largest over the columns.

    ``derivative = 1``: of the velocities' power, read from the positions' periodogram times
    :math:`(2 \pi f)^2` (the derivative's spectrum) over the bins where the motion stands above
    the position noise: more than :data:`SIGNAL_OVER_FLOOR` times the floor, the mean periodogram
    above ``fs / 4`` (white noise's level; a noise bin's periodogram is exponential, so one
    passes 30 x its mean with probability ``e^-30``). Without that selection the noise, weighted by
    ``f^2``, would decide the band."""
    n = q.shape[0]
    if n < 8:
        return 0.0
    x = np.arange(n)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    out = 0.0
    for col in q.T:
        c = np.polyfit(x, col, 1)
        y = (col - np.polyval(c, x)) * np.hanning(n)
        p = np.abs(np.fft.rfft(y)) ** 2
        p[0] = 0.0
        if derivative:
            floor = float(np.mean(p[f > fs / 4.0])) if np.any(f > fs / 4.0) else 0.0
            p = np.where(p > SIGNAL_OVER_FLOOR * floor, p * f ** (2 * derivative), 0.0)
        if p.sum() <= 0:
            continue
        k = int(np.searchsorted(np.cumsum(p) / p.sum(), fraction))
        out = max(out, float(f[min(k, p.size - 1)]))
    return out


SIGNAL_OVER_FLOOR = 30.0
"""A periodogram bin counts as motion in :func:`motion_bandwidth_hz` (``derivative = 1``) when it
exceeds the position noise's mean level by this factor."""


BAND_FACTOR = 20.0
"""init's cut-off is this many times the motion's (velocities') bandwidth (see :func:`cutoff_for`)."""


def cutoff_for(q: FloatArray, fs: float) -> tuple[float, float, float]:
    """The positions' and the velocities' bandwidths (:func:`motion_bandwidth_hz`) and init's cut-off:
    :data:`BAND_FACTOR` x the larger, within [:data:`MIN_CUTOFF_HZ`, fs / 5], rounded to 2 significant
    digits. Paper 001 (Sec. 3) puts the cut-off above 10 x the position loop's bandwidth; a log does
    not give that bandwidth, so the motion's stands in for it: the velocities' (the regressor is made
    of velocities and accelerations, which weigh the higher harmonics more than the positions), twice
    over the paper's factor so that the filter smears the Coulomb reversals little (docs/guide/init.md, Starting
    a config: the TX40 and the MuJoCo planar twin were 10 % and 46 % worse at 10 x)."""
    band, vband = motion_bandwidth_hz(q, fs), motion_bandwidth_hz(q, fs, derivative=1)
    return band, vband, round2(min(max(BAND_FACTOR * max(band, vband), MIN_CUTOFF_HZ), fs / 5.0))


def round2(x: float) -> float:
    if x <= 0:
        return x
    e = math.floor(math.log10(x)) - 1
    return round(round(x / 10**e) * 10**e, 10)

NOISE_SIGMAS = 3.0
"""``min_velocity`` is this many standard deviations of the velocity noise the processing leaves:
below it the sign of a processed velocity (which decides the Coulomb term) is wrong on more than
0.13 % of the rows (one-sided normal tail at 3 sigma)."""
STEP_RATIO = 3.0
"""The efforts are said to carry Coulomb steps when their jump across the velocity reversals
exceeds this many times the effort noise (the filter would then smear a real discontinuity)."""


@dataclasses.dataclass(frozen=True)
class DerivedProcessing:
    """What :func:`derive_processing` read from a log, with the reason of each choice."""

    velocity_noise: FloatArray  # per actuator, of the processed velocities
    min_velocity: FloatArray
    effort_noise: FloatArray  # per actuator: robust std of what the low-pass removes from the efforts
    reversal_step: FloatArray  # per actuator: median |effort jump| across velocity reversals (nan: none)
    filter_effort: bool
    decimate: int
    reversal_guard: bool
    reasons: dict[str, str]


def _robust_std(r: FloatArray) -> FloatArray:
    return 1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0)


def derive_processing(t: FloatArray, q: FloatArray, tau: FloatArray, cutoff_hz: float, *, order: int = 4,
                      parallel: bool = False, projected: bool = False) -> DerivedProcessing:
    r"""The processing choices an expert makes from the log itself (``dynid init``; issue 34 item 2).

    * **Velocity noise** :math:`\sigma_{\dot q}`: :func:`dynid.pipeline.data.velocity_noise_std`
      (position noise read from what the low-pass removes, times the noise gain of the low-pass
      followed by central differences).
    * ``min_velocity`` = :data:`NOISE_SIGMAS` :math:`\sigma_{\dot q}` per actuator: the rows where
      the sign of the processed velocity is not decided by the motion (the Coulomb column would be
      noise) are left out of that actuator's equation.
    * ``filter_effort``: the efforts' jump across the velocity reversals (median over reversals of
      the difference of lines fitted to the 30 ms after and before, both extrapolated to the
      reversal, so that the smooth terms cancel; against the noise of that median) is
      compared with :data:`STEP_RATIO`; a log with Coulomb steps keeps its efforts unfiltered
      (paper 004 Sec. 3: the filter smears the steps while the regressor's sign stays sharp, which
      biases the Coulomb estimates), a log without them is filtered like the positions (the same
      band on both sides of the equation).
    * ``decimate``: one sample in :math:`d = \lfloor f_s / (4 f_c) \rfloor` (at least 1): the
      decimated rate's Nyquist frequency stays at twice the cut-off, where the zero-phase
      Butterworth pair has removed :math:`2 \times 6 \times` order dB; the rows kept are as
      informative and far less correlated.
    * ``reversal_guard = "auto"`` for parallel robots whose equations are per actuator (docs/guide/parallel-robots.md,
      "Which method, when": with ``min_velocity`` it gave 94 % coverage of the 95 % intervals on the
      hexapod, 69 % without selection); not with projected equations (whole samples: a guard
      around every motor's reversals leaves too few) nor on serial arms (the real logs' best
      documented configurations have none).
    """
    from dynid.config import LowpassConfig, ProcessingConfig
    from dynid.dataset import Dataset
    from dynid.pipeline.data import velocity_noise_std
    from dynid.signals import lowpass, padlen_for

    t, q, tau = np.asarray(t, float), np.asarray(q, float), np.asarray(tau, float)
    fs = 1.0 / float(np.median(np.diff(t)))
    reasons: dict[str, str] = {}
    cfg = ProcessingConfig(lowpass=LowpassConfig(cutoff_hz, order, False), derivatives="central")
    try:
        sv = np.asarray(velocity_noise_std(Dataset(t=t, q=q, tau=tau), cfg, "log"), float)
    except InputError:
        sv = np.zeros(q.shape[1])
    mv = NOISE_SIGMAS * sv
    reasons["min_velocity"] = (f"{NOISE_SIGMAS:g} x the velocity noise the processing leaves ("
                               + ", ".join(f"{x:.3g}" for x in sv) + "): slower rows have a velocity sign the noise decides")
    n_trim = min(padlen_for(order, cutoff_hz, fs), max(q.shape[0] // 4, 1))
    r = (tau - lowpass(tau, cutoff_hz, fs, order))[n_trim: tau.shape[0] - n_trim]
    se = _robust_std(r) if r.shape[0] > 10 else np.zeros(tau.shape[1])
    # velocity reversals of the filtered positions; the efforts' mean over 30 ms after minus before
    v = np.gradient(lowpass(q, cutoff_hz, fs, order), t, axis=0)
    w = max(int(round(0.03 * fs)), 3)  # 30 ms, at least 3 samples (a line needs 2, its noise 3)
    steps = np.full(q.shape[1], np.nan)
    ratio = np.zeros(q.shape[1])
    for j in range(q.shape[1]):
        flips = np.flatnonzero(np.sign(v[w:-w - 1, j]) * np.sign(v[w + 1:-w, j]) < 0) + w + 1
        if flips.size == 0:
            continue
        # a line fitted to each side, both extrapolated to the reversal: what is smooth there (the
        # viscous and inertial terms) cancels, a step remains
        x = np.arange(w) - (w - 1) / 2.0
        proj = (1.0 / w + x * ((w - 1) / 2.0 + 0.5) / np.sum(x ** 2))  # weights giving the after-line at k - 1/2
        jumps = np.array([proj[::-1] @ tau[k:k + w, j] - proj @ tau[k - w:k, j] for k in flips])
        sgn = -np.sign(v[flips - 1, j])  # the Coulomb term flips from sign(v before) to sign(v after)
        steps[j] = float(np.median(jumps * sgn))
        # std of one jump: two independent extrapolations (noise se, weights proj); of their median
        noise = se[j] * np.sqrt(2.0 * np.sum(proj ** 2)) * 1.2533 / np.sqrt(flips.size)
        ratio[j] = steps[j] / max(noise, 1e-300)
    has_steps = bool(np.any(ratio > STEP_RATIO))
    reasons["filter_effort"] = (
        ("false: the efforts step at the velocity reversals (Coulomb friction: median jump "
         + ", ".join("-" if np.isnan(x) else f"{x:.3g}" for x in steps)
         + f"; more than {STEP_RATIO:g} x its noise on "
         + ", ".join(str(j + 1) for j in np.flatnonzero(ratio > STEP_RATIO))
         + "): a low-pass would smear them while the regressor's sign stays sharp (paper 004 Sec. 3)")
        if has_steps else
        ("true: no step at the velocity reversals beyond the noise (jumps "
         + ", ".join("-" if np.isnan(x) else f"{x:.3g}" for x in steps)
         + "): the efforts are filtered like the positions, the same band on both sides"))
    d = max(int(np.floor(fs / (4.0 * cutoff_hz) * (1 + 1e-9))), 1)  # the rate from a median interval: rounding
    reasons["decimate"] = (f"keep one sample in {d}: {fs / d:.4g} Hz keeps the band the {cutoff_hz:g} Hz low-pass passes "
                           "(Nyquist at twice the cut-off); neighbouring rows of a filtered log carry the same information")
    guard = parallel and not projected
    reasons["reversal_guard"] = ("\"auto\": parallel robot, per-actuator equations (docs/guide/parallel-robots.md, Which method, when)" if guard else
                                 ("not set: projected equations keep whole samples (a guard leaves too few)" if projected
                                  else "not set: serial arm (the real logs' best configurations have none)"))
    return DerivedProcessing(sv, mv, se, steps, not has_steps, d, guard, reasons)
