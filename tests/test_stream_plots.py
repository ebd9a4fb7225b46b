"""Figures of a streamed identification (dynid.pipeline.stream_plots): the same thinning as the
in-memory figures, accumulated chunk by chunk, and Welch spectra in bounded memory.

The thinning keeps per run of samples its first smallest and first largest sample; the runs are
fixed by the row count and the panel's pixels, so the streamed accumulation keeps the very
indices of :func:`dynid.report.plots._thin` (exact equality on the same values; to rounding on a
whole identification, whose predictions agree to ~1e-12, test_streaming's tolerance 1e-9).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_streaming import TOL, _config, _log, _write  # noqa: E402

from dynid.config import load_config  # noqa: E402
from dynid.pipeline import stream_plots, streaming  # noqa: E402
from dynid.pipeline.identification import identify, write_outputs  # noqa: E402
from dynid.pipeline.stream_plots import MinMaxThinner, WelchSpectrum  # noqa: E402
from dynid.report import plots  # noqa: E402
from dynid.report.plots import _thin, panel_pixels  # noqa: E402


@pytest.mark.parametrize("n, n_px, chunk", [(100_003, 979, 997), (24_750, 515, 65_536), (5_000, 1_000, 7),
                                            (1_001, 2_000, 100), (2_500, 979, 1), (9_000, 515, 4_500)])
def test_streamed_thinning_is_the_whole_series_thinning(n, n_px, chunk):
    """Any chunking, ties (a quantised series: many equal extremes, the first kept), a one-sample
    spike, runs of two lengths: the same points as _thin of the whole series."""
    rng = np.random.default_rng(n + chunk)
    x = np.linspace(0.0, 7.0, n)
    y = np.column_stack([np.round(np.sin(2 * np.pi * 0.7 * x) * 20) / 20,  # quantised: ties everywhere
                         np.cos(2 * np.pi * 3.1 * x) + 0.1 * rng.standard_normal(n)])
    y[n // 3, 1] = 50.0
    th = MinMaxThinner(n, n_px, 2)
    for a in range(0, n, chunk):
        th.add(a, x[a:a + chunk], y[a:a + chunk])
    for j, (sx, sy) in enumerate(th.series(x0=x[0])):
        ex, ey = _thin(x - x[0], y[:, j], n_px)
        assert np.array_equal(sx, ex) and np.array_equal(sy, ey)
        assert sx.size <= n_px


def test_chunks_out_of_order_refused():
    th = MinMaxThinner(100, 40, 1)
    th.add(0, np.arange(10.0), np.zeros((10, 1)))
    with pytest.raises(ValueError):
        th.add(20, np.arange(10.0), np.zeros((10, 1)))


def test_welch_amplitude_and_noise_floor():
    """A sinusoid of amplitude A on a frequency bin reads A (Hann, scaled by 2/sum w: the in-memory
    scaling); white noise of variance s^2 reads, averaged over the bins, a^2 = 4 s^2 sum(w^2)/sum(w)^2
    per bin (E|X_k|^2 = s^2 sum w^2). 61 half-overlapping segments: the mean over ~500 bins x 61
    segments of a chi^2_2 power has a relative spread ~1 %, asserted at 5 %. A log no longer than one
    segment is the in-memory spectrum (one FFT of the whole signal)."""
    m, fs, amp, sd = 1024, 1000.0, 2.5, 0.3
    n = 31 * m
    rng = np.random.default_rng(3)
    t = np.arange(n) / fs
    f0 = 100 * fs / m
    y = np.column_stack([amp * np.sin(2 * np.pi * f0 * t), sd * rng.standard_normal(n)])
    w = WelchSpectrum(n, 1 / fs, 2, nperseg=m)
    for a in range(0, n, 777):
        w.add(y[a:a + 777])
    assert w.segments == 2 * 31 - 1 and "Welch" in w.note
    (f, a0), (_, a1) = w.spectra()
    assert abs(f[np.argmax(a0)] - f0) < 1e-9 and abs(a0.max() - amp) < 0.01 * amp
    win = np.hanning(m)
    floor = 4 * sd ** 2 * np.sum(win ** 2) / np.sum(win) ** 2
    assert abs(np.mean(a1[10:-10] ** 2) / floor - 1) < 0.05

    short = WelchSpectrum(900, 1 / fs, 1, nperseg=m)
    short.add(y[:500, :1])
    short.add(y[500:900, :1])
    hw = np.hanning(900)
    x = y[:900, 0]
    whole = (np.abs(np.fft.rfft((x - x.mean()) * hw)) * 2 / hw.sum())[1:]
    assert short.segments == 1
    np.testing.assert_allclose(short.spectra()[0][1], whole, rtol=1e-9, atol=1e-12 * whole.max())


def test_panel_pixels_are_the_figures_pixels(tmp_path, monkeypatch):
    """panel_pixels (what the streamed path thins to) is the n_px the figures thin to."""
    seen = []
    real = plots._thin

    def spy(x, y, n_px):
        seen.append(n_px)
        return real(x, y, n_px)

    monkeypatch.setattr(plots, "_thin", spy)
    from types import SimpleNamespace

    t = np.arange(5000) / 1000.0
    y = np.sin(t)[:, None] * np.ones((1, 3))
    m = SimpleNamespace(measured=y, predicted=y * 0.9, t=t, channel_names=("a", "b", "c"), rmse=np.ones(3),
                        rel_rmse_pct=np.ones(3), label="held-out")
    plots.plot_validation(m, tmp_path / "v.png")
    assert set(seen) == {panel_pixels("validation")}
    seen.clear()
    ds = SimpleNamespace(t=t, q=y, names=("a", "b", "c"))
    plots.plot_processing(ds, ds, tmp_path / "p.png")
    assert set(seen) == {panel_pixels("processing")}


def _plotted(cfg):
    cfg.source.write_text(cfg.source.read_text().replace("plots = false", "plots = true"))
    return load_config(cfg.source)


@pytest.fixture(scope="module")
def log12k():
    return _log(12_000)


def test_streamed_plots_equal_in_memory(tmp_path, log12k, monkeypatch):
    """Plots on: the streamed run ('on'; 'auto' no longer refuses for plots) writes the same files;
    the validation figure's series (identified and nominal) are the in-memory thinning of the
    in-memory series to rounding; the processing figure's thinned positions too, and its spectra,
    the log being shorter than one Welch segment, the in-memory FFT to rounding."""
    monkeypatch.setattr(streaming, "FILTER_ROWS", 2500)
    monkeypatch.setattr(streaming, "READ_ROWS", 1234)
    data = _write(tmp_path, log12k, "npz")
    train, valid = (137, 9_011), (9_400, 11_987)
    on = identify(_plotted(_config(tmp_path, data, train, valid, "on", chunk=997)))
    off = identify(_plotted(_config(tmp_path, data, train, valid, "off", chunk=997)))
    assert on.data_path["mode"] == "streamed" and off.data_path["mode"] == "in-memory"
    files = {}
    for name, o in (("on", on), ("off", off)):
        write_outputs(o, tmp_path / name)
        files[name] = sorted(p.name for p in (tmp_path / name).iterdir())
    assert files["on"] == files["off"] and {"validation.png", "processing.png", "report.html"} <= set(files["on"])

    def close(a, b, scale):
        (xa, ya), (xb, yb) = a, b
        assert xa.shape == xb.shape
        np.testing.assert_allclose(xa, xb, rtol=0, atol=1e-12 * max(1.0, float(np.abs(xb).max())))
        np.testing.assert_allclose(ya, yb, rtol=0, atol=TOL * scale)

    n_px = panel_pixels("validation")
    for vs, vm in ((on.validation, off.validation), (on.nominal_validation, off.nominal_validation)):
        t = vm.t - vm.t[0]
        for j in range(vm.measured.shape[1]):
            meas, pred = vm.measured[:, j], vm.predicted[:, j]
            scale = float(np.ptp(meas))
            close(vs.thinned["measured"][j], _thin(t, meas, n_px), scale)
            close(vs.thinned["predicted"][j], _thin(t, pred, n_px), scale)
            close(vs.thinned["error"][j], _thin(t, meas - pred, n_px), scale)

    raw_s, proc_s = on.streamed_plots
    raw_m, proc_m = off.raw_train, off.train
    n_px = panel_pixels("processing")
    for j in range(raw_s.n_channels):
        scale = float(np.ptp(raw_m.q[:, j]))
        close(raw_s.thinned[j], _thin(raw_m.t - raw_m.t[0], raw_m.q[:, j], n_px), scale)
        close(proc_s.thinned[j], _thin(proc_m.t - raw_m.t[0], proc_m.q[:, j], n_px), scale)
        for s, ds in ((raw_s, raw_m), (proc_s, proc_m)):
            x = ds.q[:, j]
            hw = np.hanning(x.shape[0])
            whole = (np.abs(np.fft.rfft((x - x.mean()) * hw)) * 2 / hw.sum())[1:]
            f, a = s.spectra[j]
            assert np.allclose(f, np.fft.rfftfreq(x.shape[0], float(np.median(np.diff(ds.t))))[1:], rtol=1e-9)
            np.testing.assert_allclose(a, whole, rtol=0, atol=1e-9 * whole.max())
    assert proc_s.meta["processing"] == proc_m.meta["processing"]


def test_long_log_figure_is_welch(tmp_path, log12k, monkeypatch):
    """A log longer than a segment: Welch spectra (said on the figure's note), a sinusoid-free
    check that the spectra are finite and the figure is written."""
    monkeypatch.setattr(stream_plots, "NPERSEG", 2048)
    data = _write(tmp_path, log12k, "npz")
    on = identify(_plotted(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on")))
    raw_s, proc_s = on.streamed_plots
    assert "Welch" in raw_s.spectrum_note and "Welch" in proc_s.spectrum_note
    f, a = raw_s.spectra[0]
    assert f.size == 1024 and np.all(np.isfinite(a))
    write_outputs(on, tmp_path / "out")
    assert (tmp_path / "out" / "processing.png").stat().st_size > 10_000


def test_plots_do_not_keep_a_run_in_memory(tmp_path, log12k, monkeypatch):
    monkeypatch.setattr(streaming, "AUTO_ROWS", 5_000)
    data = _write(tmp_path, log12k, "npz")
    cfg = _plotted(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "auto"))
    assert cfg.output.plots
    out = identify(cfg)
    assert out.data_path["mode"] == "streamed" and out.validation.thinned is not None


def test_memory_of_a_plotted_run_does_not_grow_with_the_log(tmp_path, log12k, monkeypatch):
    """As test_streaming's memory test, with plots on (identification and figures written): the
    traced peak at 4N is the peak at N plus at most 40 bytes a sample of the extra rows; the
    figures' accumulators are sized by pixels and one Welch segment, not by the log (the in-memory
    path holds ~700 B/sample). The segment is set to 8192 rows so that both logs are longer than
    one (a log shorter than a segment holds the whole log in its one segment: that part of the
    peak grows up to the segment's size, ~3 MB for 6 channels at the default 65536 rows, then
    stops). A plotted run first, untraced: matplotlib's imports and font cache are not the log's.
    Read/filter blocks of 4096 rows and chunk_size 2000, as in test_streaming's memory test: both
    sizes then fill several blocks and chunks in both windows (with the default 65 536-row blocks
    the N log fills none, and the peaks differ by the unfilled share: 296 B/sample measured once the
    motion-overlap distances no longer set both peaks)."""
    import tracemalloc

    monkeypatch.setattr(stream_plots, "NPERSEG", 8192)
    monkeypatch.setattr(streaming, "READ_ROWS", 4096)
    monkeypatch.setattr(streaming, "FILTER_ROWS", 4096)
    warm = _write(tmp_path, log12k, "npz")
    write_outputs(identify(_plotted(_config(tmp_path, warm, (0, 9_000), (9_000, 12_000), "on"))), tmp_path / "warm")
    peaks = {}
    for n in (40_000, 160_000):
        d = tmp_path / str(n)
        d.mkdir()
        data = _write(d, _log(n), "npz")
        cfg = _plotted(_config(d, data, (0, int(0.8 * n)), (int(0.8 * n), n), "on", chunk=2000))
        tracemalloc.start()
        try:
            out = identify(cfg)
            write_outputs(out, d / "out")
            peaks[n] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert out.data_path["mode"] == "streamed" and (d / "out" / "processing.png").is_file()
    growth = (peaks[160_000] - peaks[40_000]) / 120_000
    assert growth < 40.0, f"{growth:.1f} B per sample (peaks {peaks})"


def test_streamed_metrics_keep_the_arrays_empty(tmp_path, log12k):
    """The thinned series ride on the metrics; the metrics keep no per-sample arrays."""
    data = _write(tmp_path, log12k, "npz")
    on = identify(_plotted(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on")))
    v = on.validation
    assert v.t.size == 0 and v.measured.shape[0] == 0
    assert all(x.size <= panel_pixels("validation") for x, _ in v.thinned["measured"])
    assert dataclasses.replace(v, overlap=None).thinned is v.thinned


def test_streamed_figures_from_the_plot_worker_are_the_in_process_bytes(tmp_path, log12k, monkeypatch, capsys):
    """``dynid identify`` on a streamed plotted run: the figures drawn by the plot worker
    (``DYNID_PLOT_WORKER=1``: the validation series go to it already thinned) are byte for byte the
    ones drawn in process."""
    from dynid.cli import main

    data = _write(tmp_path, log12k, "npz")
    cfg = _plotted(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on"))
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1764000000")
    for worker in ("0", "1"):
        monkeypatch.setenv("DYNID_PLOT_WORKER", worker)
        assert main(["identify", str(cfg.source), "--out", str(tmp_path / f"w{worker}"), "-q"]) == 0, \
            capsys.readouterr().err
    doc = (tmp_path / "w1" / "result.json").read_text()
    assert '"streamed"' in doc
    for name in ("validation.png", "processing.png", "report.html"):
        assert (tmp_path / "w0" / name).read_bytes() == (tmp_path / "w1" / name).read_bytes(), name
