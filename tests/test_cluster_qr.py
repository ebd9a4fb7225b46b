"""One model from all the data (issue 35 item 4): the streamed path's chunks on a Dask cluster, their
QR factors tree-reduced there (dynid.pipeline.cluster_qr), against the single-process streamed path.

The margin is the one the module docstring derives from backward stability: with ``gamma =
C1 sqrt(d (m_c + p + 1)(p + 1)) eps`` (``d`` the stacked factorizations a row goes through: the log's
``chunk_size`` blocks of ``m_c`` rows plus the tree's levels), the two estimates differ by at most
``2 kappa gamma (2 ||theta|| + (kappa + 1) ||r|| / ||A||)`` and the standard deviations by
``2 kappa gamma`` relatively, ``kappa``, ``||A||`` and ``||r||`` those of the weighted regressor, read
from the fit. C1 = 10. It is a worst case over the direction of the rounding errors: the differences
seen are 4 to 7 orders below it (printed), and what it guards against is far above it (a wrong filter
overlap shows at 1e-4, a chunk lost or read twice at the size of the parameters).
"""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

from dynid.cli import main
from dynid.config import load_config
from dynid.errors import ConfigError
from dynid.pipeline import cluster_qr, streaming
from dynid.pipeline.identification import identify
from test_streaming import _log, _write

distributed = pytest.importorskip("distributed")

EPS = np.finfo(float).eps
C1 = 10.0
CHUNK = 2000
FILTER = 8192  # streaming.FILTER_ROWS in the driver: chunks of 10 000 processed rows at 1 kHz, 20 Hz, order 4


def _cfg(folder, data: str, n: int, *, cluster: str = "local", workers: int | None = 2, method: str = "wls",
         processing: str = "", identification: str = "", plots: bool = False, streaming_mode: str = "on",
         name: str | None = None):
    cut = int(0.8 * n)
    text = f"""[robot]
model = "builtin:puma560"

[data]
{data}rows = [0, {cut}]

[validation]
rows = [{cut}, {n}]

[processing]
lowpass = {{ cutoff_hz = 20.0, order = 4, filter_effort = false }}
{processing}
[identification]
method = "{method}"
streaming = "{streaming_mode}"
chunk_size = {CHUNK}
cluster = "{cluster}"
{f"workers = {workers}" if workers is not None else ""}
{identification}
[output]
plots = {"true" if plots else "false"}
"""
    path = folder / f"{name or f'{method}-{abs(hash(text))}'}.toml"
    path.write_text(text)
    return load_config(path)


@pytest.fixture(scope="module")
def log60k(tmp_path_factory):
    folder = tmp_path_factory.mktemp("log60k")
    return folder, _write(folder, _log(60_000), "npz")


def _margins(res, depth: int, rows: int) -> tuple[float, float]:
    """(bound on ||theta_a - theta_b||, relative bound on the standard deviations) of the module docstring,
    from the fit ``res``: cov = s^2 (R^T R)^-1, so ||A|| = s / sqrt(lambda_min(cov)), ||r|| = s sqrt(dof)."""
    kappa = res.condition_number
    p = len(res.params)
    gamma = C1 * np.sqrt(depth * (rows + p + 1) * (p + 1)) * EPS
    s = np.sqrt(res.scale)
    norm_a = s / np.sqrt(np.linalg.eigvalsh(res.cov_params).min())
    norm_r = s * np.sqrt(res.dof)
    return (2 * kappa * gamma * (2 * np.linalg.norm(res.params) + (kappa + 1) * norm_r / norm_a),
            2 * kappa * gamma)


@pytest.mark.numerics
@pytest.mark.parametrize("method, processing", [
    ("wls", ""),
    # cross-channel and partial factors (a row selection), decimated rows
    ("gm", "decimate = 5\nmin_velocity = [0.05, 0.05, 0.05, 0.05, 0.05, 0.05]\n"),
])
def test_cluster_equals_single_process(log60k, monkeypatch, method, processing):
    """A LocalCluster of 2 processes, 5 chunks, a 3-level tree: the same estimate, standard deviations,
    residuals and validation as the single-process streamed path, within the conditioning's margin
    (decimated by 5: chunks of 2 000 processed rows, 10 000 log rows)."""
    monkeypatch.setattr(streaming, "FILTER_ROWS", FILTER)
    folder, data = log60k
    on = identify(_cfg(folder, data, 60_000, method=method, processing=processing))
    off = identify(_cfg(folder, data, 60_000, cluster="off", workers=None, method=method, processing=processing))
    cl = on.data_path["cluster"]
    assert on.data_path["mode"] == "streamed" and "cluster" not in off.data_path
    assert (cl["chunks"], cl["workers"], cl["tree_levels"]) == (5, 2, 3)
    assert json.loads(json.dumps(on.data_path))["cluster"]["chunks"] == 5  # result.json's data_path, as written
    assert f"on the cluster: local Dask cluster (2 processes), 5 chunks of {cl['chunk_rows']} processed rows on 2 " \
           "workers" in on.summary_text()
    a, b = on.result, off.result
    assert a.n_obs.tolist() == b.n_obs.tolist()
    depth = -(-on.data_path["training_samples"] // CHUNK) + cl["tree_levels"]
    bound, rel = _margins(b, depth, CHUNK)
    dtheta = float(np.linalg.norm(a.params - b.params))
    dbse = float(np.max(np.abs(a.bse / b.bse - 1)))
    drss = float(np.max(np.abs(a.rss_per_channel / b.rss_per_channel - 1)))
    print(f"\n{method}: kappa {b.condition_number:.4g}, |theta| {np.linalg.norm(b.params):.4g}; |dtheta| {dtheta:.3g} "
          f"(bound {bound:.3g}; kappa eps |theta| = {b.condition_number * EPS * np.linalg.norm(b.params):.3g}); "
          f"bse {dbse:.3g} relative (bound {rel:.3g}); rss {drss:.3g} relative")
    assert dtheta <= bound
    assert dbse <= rel
    assert drss <= rel
    for va, vb in ((on.validation, off.validation), (on.nominal_validation, off.nominal_validation)):
        assert va.n_samples == vb.n_samples
        np.testing.assert_allclose(va.rmse, vb.rmse, rtol=rel)
    assert abs(on.validation.overlap["median_distance"] - off.validation.overlap["median_distance"]) <= \
        1e-9 * off.validation.overlap["median_distance"]  # the same rows, the std merged in another order


@pytest.mark.numerics
def test_tree_of_stacked_factors_is_the_factor_of_the_stack():
    """combine / tree_reduce on 7 blocks of a random tall problem (an odd count at two levels): the
    Gram matrix and the least-squares solution of the one-shot QR, to the backward-stability margin."""
    rng = np.random.default_rng(3)
    p = 8
    a = rng.standard_normal((7 * 300, p)) @ np.diag(np.logspace(0, 3, p))
    y = a @ rng.standard_normal(p) + 0.1 * rng.standard_normal(a.shape[0])
    aug = np.column_stack([a, y])

    def leaf(rows):
        r = np.linalg.qr(rows, mode="r")
        return cluster_qr.ChunkFactor(r[None], np.array([rows.shape[0]]), None, {}, rows.shape[0], np.zeros(1), np.zeros(1),
                                      np.zeros(1), {}, [], 0.0, [], (0, None, None))

    class Now:  # a client that runs each task at once
        def submit(self, f, *args, **kw):
            return f(*args)

    root = cluster_qr.tree_reduce(Now(), [leaf(b) for b in np.split(aug, 7)])
    one = np.linalg.qr(aug, mode="r")
    assert root.n_obs.tolist() == [aug.shape[0]] and root.chunks == 7
    f = root.factors[0]
    # both R factors are exact for A + dA with |dA| <= c m n eps |A| (Householder, Higham Thm 19.4): their Gram
    # matrices differ by ~2 c m n eps |A|^2, about 1e-13 of its largest entry at these sizes; 1e-12 leaves 10x
    np.testing.assert_allclose(f.T @ f, one.T @ one, rtol=0, atol=1e-12 * np.abs(one.T @ one).max())
    sol = np.linalg.solve(f[:p, :p], f[:p, p])
    ref = np.linalg.lstsq(a, y, rcond=None)[0]
    kappa = np.linalg.cond(a)
    gamma = C1 * np.sqrt(4 * (300 + p + 2) * (p + 2)) * EPS  # blocks of 300 rows, 3 levels
    resid = np.linalg.norm(y - a @ ref)
    bound = 2 * kappa * gamma * (2 * np.linalg.norm(ref) + (kappa + 1) * resid / np.linalg.norm(a, 2))
    print(f"\n|dtheta| {np.linalg.norm(sol - ref):.3g} (bound {bound:.3g}, kappa {kappa:.3g})")
    assert np.linalg.norm(sol - ref) <= bound
    assert abs(abs(f[p, p]) - resid) <= 1e-12 * resid  # rho: the residual norm


@pytest.fixture(scope="module")
def scheduler():
    """A running cluster (2 processes, one thread each) for the tests that reach one by its address."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as lc:
        yield lc.scheduler_address


@pytest.mark.numerics
def test_a_running_scheduler(log60k, monkeypatch, scheduler):
    """``cluster = "tcp://..."``: the scheduler's workers run the chunks; the same model as one process."""
    monkeypatch.setattr(streaming, "FILTER_ROWS", FILTER)
    folder, data = log60k
    on = identify(_cfg(folder, data, 60_000, cluster=scheduler, workers=None))
    off = identify(_cfg(folder, data, 60_000, cluster="off", workers=None))
    cl = on.data_path["cluster"]
    assert (cl["where"], cl["workers"], cl["chunks"]) == (f"Dask scheduler {scheduler}", 2, 5)
    bound, rel = _margins(off.result, -(-on.data_path["training_samples"] // CHUNK) + cl["tree_levels"], CHUNK)
    assert np.linalg.norm(on.result.params - off.result.params) <= bound
    assert np.max(np.abs(on.result.bse / off.result.bse - 1)) <= rel


def test_worker_memory_does_not_grow_with_the_chunks(tmp_path, monkeypatch, scheduler):
    """The traced peak of each chunk's task on a worker (tracemalloc inside the task): the same (within
    10 %) for a log of 5 and of 10 chunks, larger for chunks of twice the rows (the raw rows a task
    holds: the peak follows the chunk, not the log); what a task returns does not grow either (its
    state rows are its share of at most 20 000). The first pass warms the workers up (imports and
    caches inside the first traced task) and is not compared."""
    from dynid.pipeline.data import build_system

    def traced(*args):
        import tracemalloc

        tracemalloc.start()
        try:
            out = cluster_qr.chunk_factor(*args)
            return tracemalloc.get_traced_memory()[1], len(pickle.dumps(out))
        finally:
            tracemalloc.stop()

    def rows_of(spans):
        return max(hi - lo for _, _, lo, hi in spans)

    logs = {}
    for n in (60_000, 120_000):
        d = tmp_path / str(n)
        d.mkdir()
        logs[n] = d, _write(d, _log(n), "npz")
    peaks, sizes, rows = {}, {}, {}
    with distributed.Client(scheduler, set_as_default=False) as client:
        for label, n, block in (("warm-up", 60_000, FILTER), ("5 chunks", 60_000, FILTER), ("10 chunks", 120_000, FILTER),
                                ("twice the rows", 120_000, 2 * FILTER)):
            monkeypatch.setattr(streaming, "FILTER_ROWS", block)
            cfg = _cfg(*logs[n], n)
            system = build_system(cfg.robot)
            (tr, _), _ = streaming.plan(cfg, system, {})
            base = system.base_parameters(None, n_samples=cfg.identification.base_samples, seed=cfg.identification.base_seed)
            spans = cluster_qr.chunk_spans(tr, cfg.processing, CHUNK)
            n_eff = len(tr.processing(cfg.processing)["rows"])
            light = cluster_qr.worker_stream(tr)
            futs = [client.submit(traced, light, system, base, None, cfg.processing, CHUNK, n_eff, s, False, pure=False)
                    for s in spans]
            out = client.gather(futs)
            key = f"{label} ({len(spans)} x {rows_of(spans)} raw rows)"
            peaks[key] = max(o[0] for o in out)
            sizes[key] = max(o[1] for o in out)
            rows[key] = rows_of(spans)
        rss = client.run(lambda: __import__("resource").getrusage(__import__("resource").RUSAGE_SELF).ru_maxrss)
    print(f"\ntask peak [MB]: { {k: round(v / 2**20, 2) for k, v in peaks.items()} }; "
          f"returned [KB]: { {k: round(v / 1024, 1) for k, v in sizes.items()} }; "
          f"workers' max RSS [MB]: {[round(v / 1024) for v in rss.values()]}")
    small, long, wide = (next(k for k in peaks if k.startswith(w)) for w in ("5 chunks", "10 chunks", "twice"))
    assert peaks[long] <= 1.1 * peaks[small]
    assert sizes[long] <= 1.1 * sizes[small]
    assert rows[wide] > 1.5 * rows[long] and peaks[wide] > peaks[long]


def _cli(cfg, tmp_path, capsys) -> tuple[int, list[str]]:
    out = tmp_path / "out"
    rc = main(["identify", str(cfg.source), "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert not out.exists(), "no output folder after an error"
    return rc, err


def test_refusals_one_line_exit_2(log60k, tmp_path, capsys):
    """The cluster with a run held in memory, with plots, with a block covariance; workers without a
    local cluster; a malformed scheduler address: one line ``dynid: error:``, exit 2."""
    folder, data = log60k
    cases = [
        (dict(streaming_mode="off"), "held in memory"),
        (dict(plots=True), "plots = false"),
        (dict(identification='covariance = "hac"\n'), "covariance = 'model'"),
    ]
    for kw, says in cases:
        rc, err = _cli(_cfg(folder, data, 60_000, **kw), tmp_path, capsys)
        assert rc == 2 and len(err) == 1 and err[0].startswith("dynid: error: identification.cluster"), err
        assert says in err[0], err
    for kw, says in ((dict(cluster="off"), "identification.workers"), (dict(cluster="tcp://host:99999"), "not a Dask"),
                     (dict(cluster="lokal", workers=None), "expected 'off', 'local' or a Dask scheduler address")):
        with pytest.raises(ConfigError) as exc:
            _cfg(folder, data, 60_000, name="refused", **kw)
        assert says in str(exc.value)
        path = folder / "refused.toml"
        assert main(["identify", str(path), "--out", str(tmp_path / "o"), "-q"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("dynid: error:") and says in err[0]


def test_worker_error_is_one_line(tmp_path, capfd, monkeypatch):
    """A NaN in the third chunk of the log, found on a worker: dynid's one line, exit 2, no output (the
    workers' own logs silenced: ``capfd`` reads what the worker processes write to the same stderr)."""
    monkeypatch.setattr(streaming, "FILTER_ROWS", FILTER)
    log = _log(30_000)
    log["q"][20_500, 2] = np.nan
    rc, err = _cli(_cfg(tmp_path, _write(tmp_path, log, "npz"), 30_000), tmp_path, capfd)
    assert rc == 2 and err == ["dynid: error: data: positions contains NaN values (first at sample 20500)"], err
