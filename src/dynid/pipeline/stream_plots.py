"""What the figures of ``dynid identify`` need, accumulated chunk by chunk on the streamed path
(:mod:`dynid.pipeline.streaming`), in memory bounded by the figures' pixels, not by the log.

* :class:`MinMaxThinner`: the thinning of :func:`dynid.report.plots._thin` (at most one point a
  pixel column, in time order, each run's smallest and largest value kept) of a series whose
  length is known before its first sample arrives: the runs are fixed by the row count and the
  panel's pixel width (:func:`dynid.report.plots.panel_pixels`), so each chunk updates the running
  extremes of the runs it touches. Ties keep the first sample (``argmin``'s rule), so the kept
  indices are those of the whole-series thinning, and the kept values the same samples.
* :class:`WelchSpectrum`: the amplitude spectrum of the processing figure. In memory it is one
  Hann-windowed FFT of the whole signal, which needs the whole signal; streamed, it is Welch's
  averaged periodogram (Welch 1967, IEEE Trans. Audio Electroacoust. 15(2), Eq. 3-5: segments of
  ``nperseg`` samples overlapping by half, each Hann-windowed, their squared moduli averaged),
  scaled like the in-memory one (``2 / sum(w)``: a sinusoid of amplitude ``A`` peaks at ``A``).
  A log no longer than one segment gives exactly the in-memory spectrum (one segment, the whole
  signal); a longer one gives a coarser frequency grid (``fs / nperseg``) and a smoother, lower
  variance noise floor (a broadband floor reads higher per bin, a sinusoid's peak the same). The
  figure says which it shows. Mean removal is per segment (Welch's), the whole log's in memory.
  Nothing below ``1 / (nperseg dt)`` is resolved: the default segment (65 s at 1 kHz) is longer
  than an excitation period of the papers' designs (10-20 s), not necessarily of every log.
* :class:`ValidationPlot`, :class:`ProcessingPlot`: the accumulators of the two figures and the
  objects handed to :func:`dynid.report.plots.plot_validation` (the ``thinned`` field of
  :class:`~dynid.estimation.validation.ValidationMetrics`) and
  :func:`dynid.report.plots.plot_processing` (:class:`StreamedSignals` in place of the datasets).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dynid._typing import FloatArray

__all__ = ["MinMaxThinner", "WelchSpectrum", "StreamedSignals", "ValidationPlot", "ProcessingPlot", "NPERSEG"]

NPERSEG = 65536
"""Samples per Welch segment (streamed processing figure): 65 s at 1 kHz, a frequency step of
0.015 Hz; a log shorter than this is one segment (the in-memory spectrum)."""


class MinMaxThinner:
    """:func:`dynid.report.plots._thin` of ``c`` series of ``n`` samples over a panel ``n_px``
    pixels wide, fed in consecutive chunks (module docstring)."""

    def __init__(self, n: int, n_px: int, c: int) -> None:
        self.n, self.c = int(n), int(c)
        from dynid.report.plots import _thin_edges

        self.edges = _thin_edges(self.n, n_px)  # the runs of _thin
        self.all = self.edges is None  # _thin returns such a series whole (at most n_px samples)
        nb = self.n if self.all else self.edges.size - 1
        self.lo_v = np.full((nb, c), np.inf)
        self.hi_v = np.full((nb, c), -np.inf)
        self.lo_i = np.zeros((nb, c), dtype=np.int64)
        self.hi_i = np.zeros((nb, c), dtype=np.int64)
        self.lo_x = np.zeros((nb, c))
        self.hi_x = np.zeros((nb, c))
        self.seen = 0

    def add(self, j0: int, x: FloatArray, y: FloatArray) -> None:
        """Rows ``j0 .. j0 + len(x)`` of the series: times ``x`` (r,), values ``y`` (r, c)."""
        r = x.shape[0]
        if r == 0:
            return
        if j0 != self.seen:
            raise ValueError(f"rows {j0}.. after {self.seen}: the chunks must come in order")
        self.seen = j0 + r
        y = np.asarray(y, dtype=float).reshape(r, self.c)
        if self.all:
            s = slice(j0, j0 + r)
            self.lo_v[s] = self.hi_v[s] = y
            self.lo_i[s] = self.hi_i[s] = np.arange(j0, j0 + r)[:, None]
            self.lo_x[s] = self.hi_x[s] = x[:, None]
            return
        e_ = self.edges
        b0 = int(np.searchsorted(e_, j0, side="right")) - 1
        b1 = int(np.searchsorted(e_, j0 + r - 1, side="right")) - 1
        cols = np.arange(self.c)
        for bb in range(b0, b1 + 1):
            a = max(j0, int(e_[bb])) - j0
            e = min(j0 + r, int(e_[bb + 1])) - j0
            if e <= a:
                continue
            seg = y[a:e]
            imin, imax = seg.argmin(axis=0), seg.argmax(axis=0)
            vmin, vmax = seg[imin, cols], seg[imax, cols]
            lo = vmin < self.lo_v[bb]  # strictly: a tie keeps the earlier sample, as argmin does
            hi = vmax > self.hi_v[bb]
            self.lo_v[bb] = np.where(lo, vmin, self.lo_v[bb])
            self.lo_i[bb] = np.where(lo, j0 + a + imin, self.lo_i[bb])
            self.lo_x[bb] = np.where(lo, x[a + imin], self.lo_x[bb])
            self.hi_v[bb] = np.where(hi, vmax, self.hi_v[bb])
            self.hi_i[bb] = np.where(hi, j0 + a + imax, self.hi_i[bb])
            self.hi_x[bb] = np.where(hi, x[a + imax], self.hi_x[bb])

    def series(self, x0: float = 0.0) -> list[tuple[FloatArray, FloatArray]]:
        """Per series, its kept ``(x - x0, y)`` in time order (the indices of ``_thin``)."""
        if self.seen != self.n:
            raise ValueError(f"{self.seen} of {self.n} rows seen")
        out = []
        for j in range(self.c):
            idx = np.concatenate([self.lo_i[:, j], self.hi_i[:, j]])
            xs = np.concatenate([self.lo_x[:, j], self.hi_x[:, j]])
            ys = np.concatenate([self.lo_v[:, j], self.hi_v[:, j]])
            u, first = np.unique(idx, return_index=True)
            out.append((xs[first] - x0, ys[first]))
        return out


class WelchSpectrum:
    """Welch-averaged amplitude spectra of ``c`` channels sampled every ``dt`` seconds, fed in
    consecutive chunks (module docstring): memory of one segment, ``nperseg`` x ``c``."""

    def __init__(self, n: int, dt: float, c: int, nperseg: int | None = None) -> None:
        self.m = int(min(n, NPERSEG if nperseg is None else nperseg))
        self.dt, self.c = float(dt), int(c)
        self.w = np.hanning(self.m)
        self.buf = np.empty((self.m, c))  # one segment, filled in place (no copy of a chunk)
        self.fill = 0
        self.power = np.zeros((self.m // 2 + 1, c))
        self.segments = 0

    def add(self, y: FloatArray) -> None:
        y = np.asarray(y, dtype=float).reshape(-1, self.c)
        m, step = self.m, max(1, self.m // 2)
        pos = 0
        while pos < y.shape[0]:
            take = min(m - self.fill, y.shape[0] - pos)
            self.buf[self.fill:self.fill + take] = y[pos:pos + take]
            self.fill += take
            pos += take
            if self.fill == m:
                seg = self.buf
                spec = np.abs(np.fft.rfft((seg - seg.mean(axis=0)) * self.w[:, None], axis=0)) * 2 / self.w.sum()
                self.power += spec ** 2
                self.segments += 1
                self.buf[:m - step] = self.buf[step:].copy()
                self.fill = m - step

    def spectra(self) -> list[tuple[FloatArray, FloatArray]]:
        """Per channel ``(f, amplitude)`` without the zero frequency (as in memory)."""
        f = np.fft.rfftfreq(self.m, self.dt)[1:]
        a = np.sqrt(self.power / max(self.segments, 1))[1:]
        return [(f, a[:, j]) for j in range(self.c)]

    @property
    def note(self) -> str:
        if self.segments <= 1:
            return "one Hann-windowed FFT of the whole log"
        return f"Welch, {self.segments} half-overlapping Hann segments of {self.m} samples"


@dataclasses.dataclass
class StreamedSignals:
    """What :func:`dynid.report.plots.plot_processing` reads of a signal (raw or processed) on the
    streamed path: its thinned positions (times from the raw log's start) and their spectra."""

    names: tuple[str, ...]
    n_channels: int
    thinned: list[tuple[FloatArray, FloatArray]]
    spectra: list[tuple[FloatArray, FloatArray]]
    spectrum_note: str
    meta: dict[str, Any]


class ValidationPlot:
    """Thinned measured, predicted (identified and nominal) and error series of the validation
    log, for :func:`dynid.report.plots.plot_validation`."""

    def __init__(self, n: int, c: int) -> None:
        from dynid.report.plots import panel_pixels

        self.n_px = panel_pixels("validation")
        self.t0: float | None = None
        self.parts = {w: MinMaxThinner(n, self.n_px, c) for w in ("measured", "predicted", "error", "nominal",
                                                                    "nominal_error")}

    def add(self, j0: int, t: FloatArray, measured: FloatArray, predicted: FloatArray, nominal: FloatArray) -> None:
        if self.t0 is None:
            self.t0 = float(t[0])
        for w, y in (("measured", measured), ("predicted", predicted), ("error", measured - predicted),
                     ("nominal", nominal), ("nominal_error", measured - nominal)):
            self.parts[w].add(j0, t, y)

    def thinned(self, nominal: bool = False) -> dict[str, Any]:
        """The ``thinned`` field of the identified (or, ``nominal``, the nominal) model's metrics."""
        p, e = ("nominal", "nominal_error") if nominal else ("predicted", "error")
        return {"n_px": self.n_px, "measured": self.parts["measured"].series(self.t0),
                "predicted": self.parts[p].series(self.t0), "error": self.parts[e].series(self.t0)}


class ProcessingPlot:
    """Thinned raw and processed positions of the training log and their spectra, for
    :func:`dynid.report.plots.plot_processing` (its first ``max_channels`` channels)."""

    def __init__(self, t: FloatArray, n_processed: int, k: int, c: int, max_channels: int = 6) -> None:
        from dynid.report.plots import panel_pixels

        n_px = panel_pixels("processing")
        self.c = min(c, max_channels)
        self.t0 = float(t[0])
        dt = float(np.median(np.diff(t)))
        self.raw = MinMaxThinner(t.shape[0], n_px, self.c)
        self.proc = MinMaxThinner(n_processed, n_px, self.c)
        self.raw_spec = WelchSpectrum(t.shape[0], dt, self.c)
        self.proc_spec = WelchSpectrum(n_processed, dt * k, self.c)

    def add_raw(self, a: int, arrays: dict[str, FloatArray]) -> None:
        q = arrays["q"][:, :self.c]
        self.raw.add(a, arrays["t"], q)
        self.raw_spec.add(q)

    def add_processed(self, j0: int, p: dict[str, FloatArray]) -> None:
        q = p["q"][:, :self.c]
        self.proc.add(j0, p["t"], q)
        self.proc_spec.add(q)

    def signals(self, names: tuple[str, ...], steps: Any) -> tuple[StreamedSignals, StreamedSignals]:
        raw = StreamedSignals(tuple(names), self.c, self.raw.series(self.t0), self.raw_spec.spectra(),
                              self.raw_spec.note, {})
        proc = StreamedSignals(tuple(names), self.c, self.proc.series(self.t0), self.proc_spec.spectra(),
                               self.proc_spec.note, {"processing": steps})
        return raw, proc
