"""Plots a person would rather look at than read (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from dynid.errors import require

__all__ = ["panel_pixels", "plot_design", "plot_speed_schedule", "plot_friction", "plot_montecarlo_chi2", "plot_montecarlo_history", "plot_processing", "plot_tracking", "plot_validation"]

_MAX_POINTS = 4000


def _pyplot():
    mpl = require("matplotlib", "plot")
    mpl.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


_PNG = {"compress_level": 1}
"""PNG options of the report's identify figures (:func:`plot_validation`, :func:`plot_processing`):
zlib level 1 instead of Pillow's default 6. The pixels are the same (PNG is lossless); the files are
~8 % larger and their encoding ~30 % faster (bench/README.md, "Cold start, fourth pass")."""


def _agg_figure(**kwargs: Any) -> Any:
    """A matplotlib :class:`~matplotlib.figure.Figure` on its own Agg canvas, without pyplot: the
    same figure and PNG as ``pyplot.subplots`` gives (same rcParams), but no pyplot import, no
    backend switch and no figure registry to close (the figure is freed with its last reference)."""
    require("matplotlib", "plot")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def _fixed_layout(fig: Any, *, left: float, right: float, bottom: float, top: float, hspace: float = 0.0,
                  wspace: float = 0.0) -> tuple[float, float]:
    """Margins and gaps in inches, set once (no ``tight_layout``: it draws every text of the
    figure a second time to measure it, the largest cost of a plot); returns one panel's
    width and height in inches. The margins are sized for the labels each plot draws."""
    w, h = fig.get_size_inches()
    gs = fig.axes[0].get_subplotspec().get_gridspec()
    nr, nc = gs.get_geometry()
    aw = (w - left - right - (nc - 1) * wspace) / nc
    ah = (h - top - bottom - (nr - 1) * hspace) / nr
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        hspace=hspace / ah, wspace=wspace / aw)
    return aw, ah


def panel_pixels(figure: str) -> int:
    """Pixel columns of one time panel of :func:`plot_validation` (``"validation"``) or
    :func:`plot_processing` (``"processing"``), the ``n_px`` they thin to: the streamed
    identification thins to it before the figure is drawn (:mod:`dynid.pipeline.stream_plots`).
    The same arithmetic as :func:`_fixed_layout` on each figure's width, margins and dpi."""
    w, left, right, nc, wspace, dpi = {"validation": (10.0, 0.95, 0.15, 1, 0.0, 110),
                                       "processing": (12.0, 0.75, 0.2, 2, 0.75, 100)}[figure]
    return int((w - left - right - (nc - 1) * wspace) / nc * dpi)


def _thin_edges(n: int, n_px: int):
    """The runs of :func:`_thin`: ``None`` when a series of ``n`` samples is drawn whole, else the
    edges (``buckets + 1`` indices from 0 to ``n``) of ``n_px // 2`` runs of equal length to one
    sample (runs of ``n // buckets`` with the rest in one short run drew up to a third of a series
    as two points when ``n`` was just below a multiple of the run count)."""
    import numpy as np

    buckets = max(1, n_px // 2)
    if n <= 2 * buckets:
        return None
    return (np.arange(buckets + 1) * n) // buckets


def _thin(x: Any, y: Any, n_px: int) -> tuple[Any, Any]:
    """At most ``n_px`` points of the series ``(x, y)`` (x increasing) for a panel ``n_px``
    pixels wide: in each of ``n_px // 2`` consecutive runs of samples (:func:`_thin_edges`: equal
    lengths to one sample), its smallest and its largest value, in their order (the drawn envelope
    is that of the full series, spikes kept; a stride would drop them)."""
    import numpy as np

    n = x.shape[0]
    edges = _thin_edges(n, n_px)
    if edges is None:
        return x, y
    start, length = edges[:-1], np.diff(edges)
    # runs of k or k + 1 samples: a (buckets, k + 1) gather that repeats a short run's last sample
    # (a repeat is later than the original: argmin/argmax still take the first occurrence)
    idx = np.minimum(start[:, None] + np.arange(int(length.max()))[None, :], (edges[1:] - 1)[:, None])
    blocks = y[idx]
    rows = np.arange(idx.shape[0])
    keep = np.unique(np.concatenate([idx[rows, blocks.argmin(axis=1)], idx[rows, blocks.argmax(axis=1)]]))
    return x[keep], y[keep]


def plot_validation(metrics: Any, path: str | Path, units: Any = None) -> Path:
    """Measured vs predicted efforts on the validation data, one panel per joint, with errors
    (titled held-out or in-sample, as ``metrics.label`` says).

    ``metrics`` is a :class:`dynid.estimation.validation.ValidationMetrics`; ``units``: the unit
    of each channel (:func:`dynid.pipeline.reporting.effort_units`: N·m, N, or A for motor
    currents without drive gains); default N·m or N.
    """
    n = metrics.measured.shape[1]
    dpi = 110
    fig = _agg_figure(figsize=(10, 1.9 * n + 0.6))
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)
    aw, _ = _fixed_layout(fig, left=0.95, right=0.15, bottom=0.5, top=0.45, hspace=0.12)
    n_px = int(aw * dpi)
    pre = getattr(metrics, "thinned", None)  # a streamed run: the series already thinned to n_px (panel_pixels)
    t = metrics.t - metrics.t[0] if pre is None else None
    for j, ax in enumerate(axes[:, 0]):
        if pre is None:
            meas, pred = metrics.measured[:, j], metrics.predicted[:, j]
            lines = _thin(t, meas, n_px), _thin(t, pred, n_px), _thin(t, meas - pred, n_px)
        else:
            lines = pre["measured"][j], pre["predicted"][j], pre["error"][j]
        ax.plot(*lines[0], lw=0.9, color="0.35", label="measured")
        ax.plot(*lines[1], lw=0.9, color="tab:blue", label="predicted")
        ax.plot(*lines[2], lw=0.7, color="tab:red", alpha=0.8, label="error")
        ax.set_ylabel(f"{metrics.channel_names[j]}\n[{units[j] if units is not None else 'N·m or N'}]", fontsize=8)
        ax.text(0.995, 0.95, f"RMSE {metrics.rmse[j]:.3g} ({metrics.rel_rmse_pct[j]:.2g} %)",
                transform=ax.transAxes, ha="right", va="top", fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[0, 0].legend(loc="upper left", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    label = getattr(metrics, "label", "held-out")
    fig.suptitle(f"{label.capitalize()} validation: measured vs predicted "
                 + ("motor currents" if units is not None and set(units) == {"A"} else "actuator efforts")
                 + (" (the validation motion repeats the training motion)" if label == "in-sample" else ""), fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=dpi, pil_kwargs=_PNG)
    return path


def plot_tracking(reference, paths: dict[str, Any], path: str | Path, *, title: str = "") -> Path:
    """End-effector paths of a planar robot under several controllers, and their errors.

    ``reference`` (n, 2) and each of ``paths`` (label -> (n, 2)) in metres.
    """
    import numpy as np

    plt = _pyplot()
    ref = np.asarray(reference)
    fig, (ax, axe) = plt.subplots(1, 2, figsize=(11, 4.6))
    ax.plot(ref[:, 0], ref[:, 1], color="0.3", lw=1.0, ls="--", label="commanded")
    t = np.arange(ref.shape[0])
    for label, p in paths.items():
        p = np.asarray(p)
        ax.plot(p[:, 0], p[:, 1], lw=0.9, label=label)
        axe.plot(t, 1e6 * np.linalg.norm(p - ref, axis=1), lw=0.8, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    axe.set_xlabel("sample")
    axe.set_ylabel("position error [µm]")
    axe.legend(fontsize=8)
    axe.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_design(t, qa, dqa, ddqa, actuators, limits, u, coordinates, path_traj, path_spectrum) -> None:
    """Actuator positions, velocities, accelerations of a design against their limits, and the
    amplitude spectrum of the design coordinates."""
    import numpy as np

    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    lo, hi = limits.position
    for ax, arr, label, lim in ((axes[0], qa, "position", None), (axes[1], dqa, "velocity", limits.velocity),
                                (axes[2], ddqa, "acceleration", limits.acceleration)):
        for j, name in enumerate(actuators):
            line, = ax.plot(t, arr[:, j], lw=0.9, label=name)
            if label == "position":
                ax.axhline(lo[j], color=line.get_color(), lw=0.6, ls=":")
                ax.axhline(hi[j], color=line.get_color(), lw=0.6, ls=":")
            elif lim is not None:
                b = np.broadcast_to(np.asarray(lim, float), (arr.shape[1],))[j]
                ax.axhline(b, color=line.get_color(), lw=0.6, ls=":")
                ax.axhline(-b, color=line.get_color(), lw=0.6, ls=":")
        ax.set_ylabel(label, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=min(6, len(actuators)), loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("actuators along the design (dotted: limits)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path_traj, dpi=100)
    plt.close(fig)
    n = u.shape[0]
    dt = t[1] - t[0]
    f = np.fft.rfftfreq(n, dt)
    amp = np.abs(np.fft.rfft(u - u.mean(axis=0), axis=0)) * 2 / n
    fig, ax = plt.subplots(figsize=(8, 4))
    for k, name in enumerate(coordinates):
        ax.semilogy(f[1:], np.maximum(amp[1:, k], 1e-12), marker="o", ms=3, lw=0.8, label=name)
    ax.set_xlim(0, min(f[-1], 20 * f[1]))
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("amplitude")
    ax.legend(fontsize=7, ncol=3)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path_spectrum, dpi=100)
    plt.close(fig)


def plot_speed_schedule(design: Any, t, dq, path: str | Path) -> Path:
    """A designed constant-velocity experiment (:mod:`dynid.excitation.friction_design`): per
    tested joint, its commanded velocity over its part of the experiment (left) and the steady
    seconds per direction of each speed (right, log speed axis; dropped speeds are not drawn,
    summary.txt lists them)."""
    import numpy as np

    plt = _pyplot()
    joints = design.joints
    fig, axes = plt.subplots(len(joints), 2, figsize=(11, 1.9 * len(joints) + 0.8), squeeze=False,
                             gridspec_kw={"width_ratios": [2.2, 1]})
    step = max(1, t.shape[0] // (4 * _MAX_POINTS))
    for row, j in zip(axes, joints):
        row[0].plot(t[::step], dq[::step, j.index], lw=0.8, color="tab:blue")
        row[0].axhline(j.velocity_limit, color="0.5", lw=0.6, ls=":")
        row[0].axhline(-j.velocity_limit, color="0.5", lw=0.6, ls=":")
        row[0].set_ylabel(f"{j.name}\n[rad/s or m/s]", fontsize=8)
        row[0].grid(alpha=0.3)
        v = np.array([lv.speed for lv in j.levels])
        w = np.array([lv.window for lv in j.levels])
        row[1].semilogx(v, w, marker="o", ms=4, lw=0.8, color="tab:orange")
        row[1].axhline(design.window, color="0.5", lw=0.6, ls=":")
        row[1].set_ylabel("steady s", fontsize=8)
        row[1].set_title(f"stroke {j.stroke:.3g}, {len(j.levels)} speeds" + (f", {len(j.dropped)} dropped" if j.dropped else ""),
                         fontsize=8)
        row[1].grid(alpha=0.3, which="both")
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("speed [rad/s or m/s]")
    fig.suptitle("constant-velocity friction experiment (paper 003, Sec. 3.1): velocity per joint (dotted: limit) "
                 "and steady seconds per speed (dotted: window)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def _step_sos(step: dict, order: int, cutoff_hz: float, fs: float) -> Any:
    """The second-order sections of a processing step's Butterworth filter: ``step["sos"]`` when
    the caller designed them already (:func:`with_filter_sections`: the plot worker then needs no
    scipy.signal, about a second of import), else designed here."""
    if "sos" in step:
        return step["sos"]
    from dynid.signals import butter_sos

    return butter_sos(order, cutoff_hz, fs)


def with_filter_sections(steps: Any) -> Any:
    """``steps`` (the processing record) with each Butterworth step's second-order sections
    added (key ``"sos"``), designed exactly as :func:`_filter_gain` would design them."""
    out = []
    for st in steps or ():
        kind = st.get("step")
        if kind == "lowpass":
            st = {**st, "sos": _step_sos(st, st["order"], st["cutoff_hz"], st["fs_hz"])}
        elif kind == "decimate" and str(st.get("method", "")).startswith("parallel"):
            nyq = 0.5 * st["fs_hz"]
            st = {**st, "sos": _step_sos(st, 8, 0.8 * nyq, st["fs_hz"] * st["factor"])}
        out.append(st)
    return out if steps is not None else None


def _sos_power_gain(sos: Any, f: Any, fs: float) -> Any:
    """:math:`|H(e^{j 2\\pi f / f_s})|^2` of cascaded second-order sections (rows
    ``b0 b1 b2 a0 a1 a2``): the product of the sections' ratios of polynomials in
    :math:`z^{-1}` (what ``scipy.signal.sosfreqz`` evaluates, here with numpy alone)."""
    import numpy as np

    w = np.exp(-2j * np.pi * np.asarray(f, dtype=float) / fs)  # z^-1 on the unit circle
    h = np.ones_like(w)
    for b0, b1, b2, a0, a1, a2 in np.asarray(sos, dtype=float):
        h = h * ((b0 + w * (b1 + w * b2)) / (a0 + w * (a1 + w * a2)))
    return np.abs(h) ** 2


def _filter_gain(steps: Any, f: Any) -> tuple[Any, list[tuple[float, str]]]:
    """Amplitude gain of the processing's filters at the frequencies ``f`` [Hz] (None without a
    filter) and the frequencies to mark (cut-off, Nyquist frequency after decimation).

    A zero-phase Butterworth filter (``sosfiltfilt``) applies :math:`|H(f)|^2`; the periodic
    DFT filter of paper 004 §3.3 keeps the harmonics up to the cut-off and zeroes the rest;
    Gautier's parallel decimation low-passes at 0.8 x the new Nyquist frequency (order 8, zero
    phase) before keeping one sample in ``factor``."""
    import numpy as np

    gain, marks = None, []
    for st in steps or ():
        kind = st.get("step")
        if kind == "lowpass":
            g = _sos_power_gain(_step_sos(st, st["order"], st["cutoff_hz"], st["fs_hz"]), f, st["fs_hz"])
            marks.append((st["cutoff_hz"], f"low-pass {st['cutoff_hz']:g} Hz"))
        elif kind == "periodic":
            g = (f <= st["cutoff_hz"]).astype(float)
            marks.append((st["cutoff_hz"], f"DFT cut-off {st['cutoff_hz']:g} Hz"))
        elif kind == "decimate":
            nyq = 0.5 * st["fs_hz"]
            marks.append((nyq, f"Nyquist after decimation by {st['factor']} ({nyq:g} Hz)"))
            if not str(st.get("method", "")).startswith("parallel"):
                continue
            fs = st["fs_hz"] * st["factor"]
            g = _sos_power_gain(_step_sos(st, 8, 0.8 * nyq, fs), f, fs)
        else:
            continue
        gain = g if gain is None else gain * g
    return gain, marks


def plot_processing(raw: Any, processed: Any, path: str | Path, max_channels: int = 6, steps: Any = None) -> Path:
    """Raw against processed positions (left) and their amplitude spectra (right), one row per
    channel: what the filters removed and what they kept. With ``steps`` (the processing record,
    ``Dataset.meta["processing"]``) the filters' amplitude gain (:func:`_filter_gain`), scaled to
    the raw spectrum's peak, is drawn over the spectra, with the cut-off and the Nyquist frequency
    after decimation marked.

    A streamed identification hands :class:`dynid.pipeline.stream_plots.StreamedSignals` for
    ``raw`` and ``processed``: the positions already thinned to the panel's pixels and Welch-averaged
    spectra (a bounded-memory equivalent of the whole-log FFT, said in the title)."""
    import numpy as np

    pre = getattr(raw, "thinned", None) is not None
    n = min(raw.n_channels if pre else raw.q.shape[1], max_channels)
    dpi = 100
    fig = _agg_figure(figsize=(12, 1.8 * n + 0.8))
    axes = fig.subplots(n, 2, squeeze=False)
    from matplotlib.ticker import LogLocator

    aw, _ = _fixed_layout(fig, left=0.75, right=0.2, bottom=0.5, top=0.8, hspace=0.35, wspace=0.75)
    n_px = int(aw * dpi)

    def spectrum(ds, j):  # Hann-windowed amplitude spectrum (records are not whole periods)
        if pre:
            f, a = ds.spectra[j]
        else:
            t, x = ds.t, ds.q[:, j]
            dt = float(np.median(np.diff(t)))
            f = np.fft.rfftfreq(x.shape[0], dt)
            w = np.hanning(x.shape[0])
            f, a = f[1:], (np.abs(np.fft.rfft((x - x.mean()) * w)) * 2 / w.sum())[1:]
        if f.size > n_px:  # long logs: the largest amplitude in each of log-spaced bins, one a pixel (peaks kept)
            edges = np.unique(np.geomspace(1, f.size, n_px).astype(int) - 1)
            f, a = f[edges], np.maximum.reduceat(a, edges)
        return f, a

    gain, marks = None, []
    if steps:  # one response for every channel (the same filters), on the raw spectrum's frequencies
        f_raw = spectrum(raw, 0)[0]
        fg = np.geomspace(f_raw[0], f_raw[-1], 400)
        gain, marks = _filter_gain(steps, fg)
    for j in range(n):
        ax, axs = axes[j, 0], axes[j, 1]
        ax.plot(*(raw.thinned[j] if pre else _thin(raw.t - raw.t[0], raw.q[:, j], n_px)), lw=0.7, color="0.6",
                label="raw")
        ax.plot(*(processed.thinned[j] if pre else _thin(processed.t - raw.t[0], processed.q[:, j], n_px)), lw=0.9,
                color="tab:blue", label="processed")
        ax.set_ylabel(f"{processed.names[j] if processed.names else j}", fontsize=8)
        ax.grid(alpha=0.3)
        peak, floor = 1e-14, 1e-14
        for label, ds, color in (("raw", raw, "0.6"), ("processed", processed, "tab:blue")):
            f, a = spectrum(ds, j)
            if label == "raw":
                peak, floor = max(peak, float(a.max())), max(floor, float(a.min()))
            axs.plot(f, np.maximum(a, 1e-14), lw=0.8, color=color, label=label)
        if gain is not None:  # on the same axes (a twin axis per row doubles the drawing time)
            axs.plot(fg, np.maximum(gain * peak, floor), lw=1.0, ls="--", color="tab:green",
                     label="filter gain x raw peak")
        axs.set_xscale("log")  # once per axis, after the lines (not a rescale per line)
        axs.set_yscale("log")
        # minor grid at 2 and 5 of each decade: every tick is an object to build and draw, and the
        # default eight a decade over four decades of frequency were most of this figure's time
        axs.xaxis.set_minor_locator(LogLocator(base=10.0, subs=(2.0, 5.0)))
        axs.grid(alpha=0.3, which="both")
        for fm, text in marks:
            axs.axvline(fm, color="tab:red" if "Nyquist" in text else "tab:green", lw=0.7, ls=":")
            if j == 0:
                axs.text(fm, 0.03, " " + text, transform=axs.get_xaxis_transform(), fontsize=6, va="bottom",
                         rotation=90, color="0.25")
    axes[0, 0].legend(fontsize=7)
    axes[0, 1].legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("frequency [Hz]")
    fig.suptitle("positions before and after processing, and their amplitude spectra"
                 + (" (dashed: the filters' amplitude gain, scaled to the raw spectrum's peak)" if gain is not None else "")
                 + ((f"\nstreamed log, spectra: {raw.spectrum_note}" if raw.spectrum_note == processed.spectrum_note else
                     f"\nstreamed log, spectra: raw {raw.spectrum_note}; processed {processed.spectrum_note}") if pre else ""),
                 fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=dpi, pil_kwargs=_PNG)
    return path


def _montecarlo_selection(n_params: int, max_params: int) -> list[int]:
    """Up to ``max_params`` parameter indices spread evenly over the list (first and last kept)."""
    import numpy as np

    return sorted({int(round(x)) for x in np.linspace(0, n_params - 1, min(n_params, max_params))})


def plot_montecarlo_history(result: Any, path: str | Path, *, select: Any = None, max_params: int = 12) -> Path:
    """Each selected base parameter's estimate per trial with its interval and the truth
    (paper 002 Fig. 8), one panel per parameter.

    ``result`` is a :class:`dynid.pipeline.montecarlo.MonteCarloResult` (``names``, ``trial``,
    ``ok``, ``estimates``, ``ci``, ``truth``, ``coverage``, ``alpha``). ``select``: parameter
    names; default: up to ``max_params`` spread evenly over the base parameters. Intervals that
    miss the truth are drawn in red.
    """
    import numpy as np

    plt = _pyplot()
    if select is None:
        idx = _montecarlo_selection(len(result.names), max_params)
    else:
        idx = [list(result.names).index(n) for n in select]
    ncols = 3 if len(idx) > 4 else min(2, len(idx))
    nrows = -(-len(idx) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.2 * ncols, 2.4 * nrows + 0.8), squeeze=False, sharex=True)
    ok = np.asarray(result.ok)
    trial = np.asarray(result.trial)[ok]
    coverage = result.coverage
    level = 100 * (1 - result.alpha)
    for ax, i in zip(axes.ravel(), idx):
        est = result.estimates[ok, i]
        lo, hi = result.ci[ok, i, 0], result.ci[ok, i, 1]
        tru = result.truth[ok, i]
        has = np.isfinite(lo) & np.isfinite(hi)
        miss = has & ((tru < lo) | (tru > hi))
        good = has & ~miss
        ax.vlines(trial[good], lo[good], hi[good], color="tab:blue", alpha=0.45, lw=1.0)
        ax.vlines(trial[miss], lo[miss], hi[miss], color="tab:red", alpha=0.9, lw=1.2)
        ax.plot(trial, est, "o", ms=2.5, color="tab:blue")
        ax.plot(trial[miss], est[miss], "o", ms=3, color="tab:red")
        ax.step(trial, tru, where="mid", color="0.15", lw=1.1)
        ax.set_title(f"{result.names[i]}   coverage {coverage[i]:.0f} %", fontsize=9)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 4))
        ax.yaxis.get_offset_text().set_fontsize(7)
    for ax in axes.ravel()[len(idx):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("trial", fontsize=8)
    fig.suptitle(f"Estimates over {trial.size} trials with their {level:g} % intervals (red: the interval misses the "
                 f"truth; black: truth), {len(idx)} of {len(result.names)} base parameters", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_montecarlo_chi2(result: Any, path: str | Path) -> Path:
    """Per trial, the statistic (est - truth)^T Sigma^-1 (est - truth) against the radius of the
    confidence ellipsoid chi2(p, 1 - alpha) (paper 002 Fig. 9).

    ``result`` is a :class:`dynid.pipeline.montecarlo.MonteCarloResult` (``trial``, ``chi2``,
    ``radius``, ``alpha``, ``names``, ``ellipsoid_share``, ``mean_chi2``).
    """
    import numpy as np

    plt = _pyplot()
    c = np.asarray(result.chi2, dtype=float)
    t = np.asarray(result.trial)
    m = np.isfinite(c)
    t, c = t[m], c[m]
    r, p = result.radius, len(result.names)
    out = c > r
    fig, ax = plt.subplots(figsize=(9, 4.2))
    ax.vlines(t, 0, c, color="tab:blue", alpha=0.35, lw=1.0)
    ax.plot(t[~out], c[~out], "o", ms=3.5, color="tab:blue", label="trials")
    ax.plot(t[out], c[out], "o", ms=4, color="tab:red", label="outside the ellipsoid")
    level = 100 * (1 - result.alpha)
    ax.axhline(r, color="tab:red", ls="--", lw=1.2, label=f"radius chi2({p}, {level:g} %) = {r:.2f}")
    ax.axhline(p, color="0.3", ls=":", lw=1.0, label=f"expected mean p = {p}")
    if c.size and c.max() > 20 * max(r, 1e-300):
        ax.set_yscale("log")
    else:
        ax.set_ylim(0, max(r, float(c.max()) if c.size else r) * 1.1)
    ax.set_xlabel("trial")
    ax.set_ylabel("chi2 of the estimate")
    ax.set_title(f"{result.ellipsoid_share:.0f} % of {c.size} trials inside the {level:g} % confidence ellipsoid; "
                 f"mean chi2 {result.mean_chi2:.1f}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_friction(joints: Any, models: Any, path: str | Path, *, labels: dict[str, str] | None = None) -> Path:
    """Paper 003, Fig. 7 in kind: per joint the extracted friction points (mean over the matched
    stroke, error bars ±2 standard errors; held-out points open) and the fitted curves of each
    model, against the speed on a logarithmic axis (the speeds are log-spaced).

    ``joints``: items with ``name``, ``points`` (a :class:`dynid.signals.friction_points.FrictionPoints`),
    ``fits`` (model -> fit with ``force(v)``) and ``held_out`` (mask of the points).
    """
    import numpy as np

    plt = _pyplot()
    joints = list(joints)
    n = len(joints)
    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.5 * rows + 0.5), squeeze=False)
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]
    for ax, j in zip(axes.flat, joints):
        p = j.points
        v = np.geomspace(p.speed.min() / 1.5, p.speed.max() * 1.2, 300)
        for c, m in zip(colors, models):
            ax.plot(v, j.fits[m].force(v), color=c, lw=1.2, label=(labels or {}).get(m, m))
        held = np.asarray(j.held_out, dtype=bool)
        for mask, face, lab in ((~held, "k", "points (fit)"), (held, "white", "points (held out)")):
            if mask.any():
                ax.errorbar(p.speed[mask], p.force[mask], yerr=2 * p.sigma[mask], fmt="o", ms=4, mfc=face, mec="k",
                            ecolor="k", elinewidth=0.8, capsize=2, label=lab, zorder=5)
        ax.set_xscale("log")
        ax.set_title(j.name, fontsize=9)
        ax.set_xlabel("speed [rad/s or m/s]", fontsize=8)
        ax.set_ylabel("friction [N·m or N]", fontsize=8)
        ax.grid(alpha=0.3, which="both")
        ax.tick_params(labelsize=8)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.suptitle("Friction from constant-velocity runs:\nextracted points and fitted models (paper 003, Fig. 7)",
                 fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
