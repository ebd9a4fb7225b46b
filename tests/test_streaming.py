"""The streamed identification (dynid.pipeline.streaming) against the in-memory path.

The streamed path filters each block of the log with an overlap ``L`` after which the filter state
mismatch at a cut has decayed below ``rho^L <= 1e-19`` of the signal (``rho`` the largest pole
modulus, module docstring), i.e. to rounding. What remains between the paths is rounding: the same
rows reach the same incremental QR in the same blocks. The tolerance 1e-9 relative leaves a margin of
about 1e3 over the differences seen (~1e-12: double differentiation multiplies the rounding of the
filtered positions by fs^2); a wrong overlap (one sample too few filter periods) shows at 1e-4 or more.
"""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest

from dynid.cli import main
from dynid.config import load_config
from dynid.model import load_robot
from dynid.model.serial_dynamics import regressor
from dynid.pipeline import streaming
from dynid.pipeline.identification import identify
from dynid.signals import butter_sos
from dynid.simulation import FourierTrajectory

FS = 1000.0
TOL = 1e-9


def _log(n: int, seed: int = 7) -> dict[str, np.ndarray]:
    """A puma560 log of ``n`` samples at 1 kHz: a 5-harmonic Fourier motion, torques from the
    regressor with the nominal parameters plus noise, 2e-5 rad encoder noise."""
    robot = load_robot("builtin:puma560")
    rng = np.random.default_rng(seed)
    lo, hi = robot.position_limits()
    traj = FourierTrajectory.random(robot.dof, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    t = np.arange(n) / FS
    q = np.empty((n, robot.dof))
    tau = np.empty((n, robot.dof))
    data = robot.create_data()
    p = robot.nominal_parameters()
    for s in range(0, n, 20000):
        e = min(s + 20000, n)
        qc, dqc, ddqc = traj.sample(t[s:e])
        tau[s:e] = regressor(robot, qc, dqc, ddqc, data=data) @ p + rng.standard_normal((e - s, 6)) * 0.3
        q[s:e] = qc + rng.standard_normal(qc.shape) * 2e-5
    return {"t": t, "q": q, "tau": tau}


def _write(folder, log, kind: str) -> str:
    names = [f"q{j}" for j in range(6)], [f"tau{j}" for j in range(6)]
    if kind in ("npz", "npz-deflated"):
        (np.savez if kind == "npz" else np.savez_compressed)(folder / "log.npz", **log)
        return 'file = "log.npz"\ntime = { column = "t" }\nposition = { columns = "q" }\neffort = { columns = "tau" }\n'
    import pandas as pd

    frame = pd.DataFrame({"t": log["t"], **{n: log["q"][:, j] for j, n in enumerate(names[0])},
                          **{n: log["tau"][:, j] for j, n in enumerate(names[1])}})
    name = "log.csv" if kind == "csv" else "log.parquet"
    if kind == "csv":
        frame.to_csv(folder / name, index=False, float_format="%.17g")
    else:
        pytest.importorskip("pyarrow")
        frame.to_parquet(folder / name)
    return (f'file = "{name}"\ntime = {{ column = "t" }}\nposition = {{ columns = {json.dumps(names[0])} }}\n'
            f'effort = {{ columns = {json.dumps(names[1])} }}\n')


def _config(folder, data: str, train: tuple[int, int], valid: tuple[int, int], mode: str, *, chunk: int = 20000,
            decimate: int = 1, extra: str = "") -> object:
    text = f"""[robot]
model = "builtin:puma560"

[data]
{data}rows = [{train[0]}, {train[1]}]

[validation]
rows = [{valid[0]}, {valid[1]}]

[processing]
lowpass = {{ cutoff_hz = 20.0, order = 4, filter_effort = false }}
decimate = {decimate}
{extra}
[identification]
method = "wls"
streaming = "{mode}"
chunk_size = {chunk}

[output]
plots = false
"""
    path = folder / f"{mode}-{chunk}-{decimate}.toml"
    path.write_text(text)
    return load_config(path)


def _same(a, b, tol: float = TOL) -> None:
    ra, rb = a.result, b.result
    scale = np.abs(rb.params) + rb.bse
    assert np.all(np.abs(ra.params - rb.params) <= tol * scale)
    np.testing.assert_allclose(ra.bse, rb.bse, rtol=tol)
    np.testing.assert_allclose(ra.rss_per_channel, rb.rss_per_channel, rtol=tol)
    assert ra.n_obs.tolist() == rb.n_obs.tolist()
    for va, vb in ((a.validation, b.validation), (a.nominal_validation, b.nominal_validation)):
        assert va.n_samples == vb.n_samples
        np.testing.assert_allclose(va.rmse, vb.rmse, rtol=tol)
        np.testing.assert_allclose(va.r2, vb.r2, rtol=tol, atol=tol)
        np.testing.assert_allclose(va.max_abs_error, vb.max_abs_error, rtol=tol)
        np.testing.assert_allclose(va.rms_measured, vb.rms_measured, rtol=tol)
    oa, ob = a.validation.overlap, b.validation.overlap
    assert abs(oa["median_distance"] - ob["median_distance"]) <= tol * ob["median_distance"]


@pytest.fixture(scope="module")
def log12k():
    return _log(12_000)


@pytest.fixture
def small_blocks(monkeypatch):
    """Blocks far shorter than the log: many filter cuts and read cuts at odd rows."""
    monkeypatch.setattr(streaming, "FILTER_ROWS", 2500)
    monkeypatch.setattr(streaming, "READ_ROWS", 1234)


def test_overlap_from_poles():
    """The overlap is where the slowest pole's mode has decayed to 1e-19: for order 4 at 20 Hz and
    1 kHz the slowest z-plane pole is exp(-w sin(pi/8) / fs) with w = 2 pi 20 (the -3 dB cut-off of
    one pass of butter_sos is prewarped only slightly at fs/fc = 50), about 920 samples."""
    sos = butter_sos(4, 20.0, FS)
    L = streaming.overlap_for(sos)
    rho = max(np.max(np.abs(np.roots(s[3:]))) for s in sos)
    assert rho ** L <= 1e-19 < rho ** (L - 1)
    wc = 2 * np.pi * 20.0
    predicted = np.log(1e-19) / (-wc * np.sin(np.pi / 8) / FS)
    assert abs(L - predicted) < 0.03 * predicted


@pytest.mark.parametrize("kind", ["npz", "npz-deflated", "csv", "parquet"])
def test_streamed_equals_in_memory(tmp_path, log12k, small_blocks, kind):
    """NPZ (stored and deflated), CSV and Parquet; windows that start and stop inside read and filter
    blocks; the same estimate, standard deviations, RSS, validation errors and motion overlap."""
    data = _write(tmp_path, log12k, kind)
    train, valid = (137, 9_011), (9_400, 11_987)
    on = identify(_config(tmp_path, data, train, valid, "on", chunk=997))
    off = identify(_config(tmp_path, data, train, valid, "off", chunk=997))
    assert on.data_path["mode"] == "streamed" and off.data_path["mode"] == "in-memory"
    assert on.train is None and off.train is not None
    _same(on, off)


def test_decimation_and_row_selection(tmp_path, log12k, small_blocks):
    """Decimation by 5 (kept rows at the in-memory indices) with the full-rate validation, and a
    min_velocity row selection with its selected-rows validation."""
    data = _write(tmp_path, log12k, "npz")
    extra = "min_velocity = [0.05, 0.05, 0.05, 0.05, 0.05, 0.05]\n"
    on = identify(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on", chunk=333, decimate=5, extra=extra))
    off = identify(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "off", chunk=333, decimate=5, extra=extra))
    _same(on, off)
    for fa, fb in ((on.full_rate.metrics, off.full_rate.metrics), (on.selected.metrics, off.selected.metrics)):
        np.testing.assert_allclose(fa.rmse, fb.rmse, rtol=TOL)
        assert fa.rows_per_channel.tolist() == fb.rows_per_channel.tolist()
    assert on.result.provenance["row_selection"] == off.result.provenance["row_selection"]


def test_chunk_size_does_not_change_the_answer(tmp_path, log12k, monkeypatch):
    """chunk_size 997 and 50 000 (one block): the same answer to rounding. Reads of 8 999 rows leave
    a one-row tail of the 9 000-row window (read with one more row per block instead)."""
    monkeypatch.setattr(streaming, "READ_ROWS", 8_999)
    data = _write(tmp_path, log12k, "npz")
    a = identify(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on", chunk=997))
    b = identify(_config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on", chunk=50_000))
    _same(a, b)


def test_auto_rule(tmp_path, log12k, monkeypatch):
    """'auto' streams from AUTO_ROWS training rows on, with plots on too (their series are thinned
    chunk by chunk: test_stream_plots)."""
    data = _write(tmp_path, log12k, "npz")
    cfg = _config(tmp_path, data, (0, 9_000), (9_000, 12_000), "auto")
    assert identify(cfg).data_path["mode"] == "in-memory"
    monkeypatch.setattr(streaming, "AUTO_ROWS", 5_000)
    assert identify(cfg).data_path["mode"] == "streamed"
    import dataclasses

    plotted = dataclasses.replace(cfg, output=dataclasses.replace(cfg.output, plots=True))
    from dynid.pipeline.data import build_system

    streams, record = streaming.plan(plotted, build_system(cfg.robot), {})
    assert streams is not None and record["mode"] == "streamed"


def _peak(cfg) -> int:
    tracemalloc.start()
    try:
        out = identify(cfg)
        assert out.data_path["mode"] == "streamed"
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_log(tmp_path, monkeypatch):
    """The traced peak at 4N is the peak at N plus at most 40 bytes a sample of the extra rows (the
    time column, its steps and their median's copy: 24 B); the in-memory path holds ~700 B/sample.
    chunk_size 2000 and read/filter blocks of 4096 rows: both sizes hold several full chunks and
    blocks in the training AND the validation window (8 000 rows at N), so the per-chunk part of the
    peak is the same. With the default 65 536-row blocks and 5000-row chunks the N log fills neither
    (the peaks differ by their unfilled share, ~9-35 MB); that went unseen while the 256 x 20 000
    block of motion-overlap distances (~120 MB with its temporaries) set both peaks."""
    monkeypatch.setattr(streaming, "READ_ROWS", 4096)
    monkeypatch.setattr(streaming, "FILTER_ROWS", 4096)
    peaks = {}
    for n in (40_000, 160_000):
        d = tmp_path / str(n)
        d.mkdir()
        data = _write(d, _log(n), "npz")
        peaks[n] = _peak(_config(d, data, (0, int(0.8 * n)), (int(0.8 * n), n), "on", chunk=2000))
    growth = (peaks[160_000] - peaks[40_000]) / 120_000
    assert growth < 40.0, f"{growth:.1f} B per sample (peaks {peaks})"


def _cli(tmp_path, data: str, capsys, **kw) -> tuple[int, str]:
    cfg = _config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on", **kw)
    out = tmp_path / "out"
    rc = main(["identify", str(cfg.source), "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert not out.exists(), "no output folder after an error"
    return rc, err


def test_bad_inputs_one_line_exit_2(tmp_path, log12k, small_blocks, capsys):
    """NaN in a late chunk, a short CSV column, an unknown key: one line ``dynid: error:``, exit 2,
    no output folder."""
    bad = {k: v.copy() for k, v in log12k.items()}
    bad["q"][8_500, 2] = np.nan  # read long after the first blocks
    data = _write(tmp_path, bad, "npz")
    rc, err = _cli(tmp_path, data, capsys)
    assert rc == 2 and len(err) == 1 and err[0].startswith("dynid: error:") and "NaN" in err[0] and "8500" in err[0]

    csv_dir = tmp_path / "csv"
    csv_dir.mkdir()
    data = _write(csv_dir, log12k, "csv")
    lines = (csv_dir / "log.csv").read_text().splitlines()
    lines[7_001] = ",".join(lines[7_001].split(",")[:-1]) + ","  # last effort field empty
    (csv_dir / "log.csv").write_text("\n".join(lines) + "\n")
    rc, err = _cli(csv_dir, data, capsys)
    assert rc == 2 and len(err) == 1 and err[0].startswith("dynid: error:") and "NaN" in err[0]

    key_dir = tmp_path / "key"
    key_dir.mkdir()
    data = _write(key_dir, log12k, "npz").replace('columns = "tau"', 'columns = "torque"')
    rc, err = _cli(key_dir, data, capsys)
    assert rc == 2 and len(err) == 1 and err[0].startswith("dynid: error:") and "torque" in err[0]


def test_result_json_says_which_path(tmp_path, log12k):
    data = _write(tmp_path, log12k, "npz")
    cfg = _config(tmp_path, data, (0, 9_000), (9_000, 12_000), "on")
    out = tmp_path / "out"
    assert main(["identify", str(cfg.source), "--out", str(out), "-q"]) == 0
    doc = json.loads((out / "result.json").read_text())
    assert doc["data_path"]["mode"] == "streamed"
    assert doc["training"]["n_samples"] == doc["data_path"]["training_samples"]
    assert "Data path: streamed" in (out / "summary.txt").read_text()
