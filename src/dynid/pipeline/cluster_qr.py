"""One model from all the data: the streamed identification's chunks on a Dask cluster, their QR
factors tree-reduced there (issue 35 item 4).

``[identification] cluster = "local"`` (a :class:`distributed.LocalCluster` of ``workers`` processes)
or ``cluster = "tcp://host:port"`` (a running scheduler, the syntax of ``montecarlo.scheduler``) runs
the training pass of the streamed path (:mod:`dynid.pipeline.streaming`) on the cluster:

1. the driver reads the training window's time column (as the in-process path does) and cuts the
   processed rows into chunks of :meth:`~dynid.pipeline.streaming.LogStream.filter_rows` rows, the
   blocks the in-process path filters at once; it sends each worker a chunk's *row ranges*, not its
   data: the processed rows ``[f_lo, f_hi)`` and the raw rows ``[raw_lo, raw_hi)`` that cover them
   and their filter overlap;
2. each worker opens the log itself (:class:`~dynid.io.readers.RowStream`: a stored NPZ member is
   read from the chunk's first row, Parquet from its row group; a deflated NPZ member is decompressed
   and a CSV file parsed up to it, in blocks: long logs are best given as NPZ or Parquet), reads
   those raw rows and their times, filters, differentiates and decimates them exactly as
   the in-process path does (the same filter blocks: the processed rows are the same numbers), builds
   the base regressor chunk by chunk (``chunk_size`` rows), selects rows (``min_velocity``) and
   returns only a :class:`ChunkFactor`: per channel the ``(p+1) x (p+1)`` factor ``[[R, Q^T y],
   [0, rho]]`` and the row count (with ``method = "gm"`` the cross-channel factors too), the
   extremes of the positions and efforts, the constant-effort flags, the states' mean and centred
   sum of squares and the evenly spaced state rows of the motion overlap;
3. the factors are combined pairwise, level by level, on the cluster (:func:`combine`, one
   ``client.submit`` per pair): the R factor of the QR of two stacked matrices is the R factor of
   the QR of their two stacked R factors (``[A; B] = diag(Q_A, Q_B) [R_A; R_B]``), so the root is the
   problem :class:`~dynid.estimation.problem.ProblemBuilder` accumulates in one process, up to the
   signs of the factors' rows (which no least-squares quantity sees) and rounding.

The weighted least squares needs no second pass: the per-channel factors hold each channel's
residual sum of squares for any parameter vector
(:meth:`~dynid.estimation.problem.RegressionProblem.rss_per_channel`), from which the estimator takes
the OLS residual variances and the weights (paper 001 Eqs. 14-16), in the driver, on the root.

Margin against the single-process result. Householder QR is backward stable: the computed R of an
``m x n`` matrix is the exact R of ``A + dA`` with ``||da_j|| <= c m n eps ||a_j||`` per column
(Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., Thm. 19.4). Both paths factor
a sequence (in-process) or a tree (cluster) of stacked matrices: a row goes through ``d``
factorizations (the ``chunk_size`` blocks of the log, ``m_c`` rows each, stacked under the running
factor; plus the tree's levels), each of at most ``m_c + p + 1`` rows and ``p + 1`` columns, and
each step's error is relative to a matrix no larger than ``A``: the computed factor is the exact
factor of ``A + dA``, ``||dA|| <= gamma ||A||``, with ``gamma`` of the order of ``d (m_c + p + 1)
(p + 1) eps`` in the worst case. Rounding errors that add as a random walk (Higham Sec. 2.8, the
rule of thumb that replaces such constants by their square roots) give
``gamma = c_1 sqrt(d (m_c + p + 1)(p + 1)) eps``. A least-squares solution of ``A + dA`` differs from
that of ``A`` by at most (Wedin; Higham Thm. 20.1)

.. math:: \\|\\delta\\theta\\| \\le \\kappa \\gamma
   \\Big(2 \\|\\theta\\| + (\\kappa + 1) \\frac{\\|r\\|}{\\|A\\|}\\Big),

``kappa`` the condition number of the weighted regressor (its R factor), ``r`` its residual: both
the in-process and the cluster solution sit within that of the exact one, so within twice it of each
other. The standard deviations ``s sqrt(diag((R^T R)^-1))`` move by ``kappa gamma`` relatively (the
inverse of ``R``), twice that between the paths. ``tests/test_cluster_qr.py`` asserts both with
``c_1 = 10``, ``kappa``, ``||A||``, ``||r||`` and ``theta`` read from the fit (its covariance
``s^2 (R^T R)^-1``, scale ``s^2`` and degrees of freedom), and prints the differences seen.

Memory per worker. A task holds one chunk: the raw rows ``[raw_lo, raw_hi)`` (its ``filter_rows``
processed rows times the decimation, plus twice the filter overlap), their processed rows, one
``chunk_size`` block of regressor rows and its ``(p+1)^2`` factors; the state rows it returns are the
chunk's share of at most 20 000 evenly spaced rows. None of this grows with the number of chunks or
the length of the log; the driver holds the time column, as in-process.

Refused in one line (:class:`~dynid.errors.ConfigError`, :func:`check`): a run the streamed path
cannot take (the reason of :func:`dynid.pipeline.streaming.plan`), ``[output] plots = true`` (the
figures' series are thinned in one process), ``covariance`` other than ``"model"`` (its blocks are
cut across chunk boundaries), ``workers`` without ``cluster = "local"``. The validation log is
scored in the driver, streamed as in-process. ``result.json`` ``data_path.cluster`` and
``summary.txt`` give the cluster, the chunks and the workers.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from dynid._typing import FloatArray
from dynid.config import TIME_UNITS, Config, ProcessingConfig
from dynid.errors import ConfigError, IdentifiabilityError, InputError, require
from dynid.estimation import RegressionProblem
from dynid.estimation.problem import CrossBlock, ProblemBuilder, _qr_r
from dynid.io.readers import RowStream, TableReader
from dynid.pipeline.streaming import LogStream, StateSample

__all__ = ["ChunkFactor", "ClusterRun", "check", "chunk_spans", "chunk_factor", "combine", "compress_on_cluster",
           "SCHEDULER_TIMEOUT_S"]

SCHEDULER_TIMEOUT_S = 10.0
"""Seconds to wait for a Dask scheduler before giving up (as ``dynid montecarlo``)."""

OVERLAP_ROWS = 20000
"""Evenly spaced training states kept for the motion overlap (as in-process)."""


def check(cfg: Config, why: str | None) -> None:
    """Refuse a ``cluster`` the run cannot use (module docstring); ``why``: why the run is not streamed
    (None: it is)."""
    icfg = cfg.identification
    c = f"identification.cluster = {icfg.cluster!r}"
    if why is not None:
        raise ConfigError(f"{c}: the cluster runs the streamed path and this run is held in memory ({why}); "
                          "set identification.cluster = 'off'")
    if cfg.output.plots:
        raise ConfigError(f"{c}: the figures' series are thinned in one process; set [output] plots = false")
    if icfg.covariance.kind != "model":
        raise ConfigError(f"{c}: identification.covariance = {icfg.covariance.kind!r} cuts blocks across the chunks; "
                          "use covariance = 'model' or cluster = 'off'")


# ---------------------------------------------------------------------------------------------- one chunk
@dataclasses.dataclass
class ChunkFactor:
    """What a chunk (or a combination of consecutive chunks) sends back: the compressed rows of
    :class:`~dynid.estimation.problem.ProblemBuilder` and the sums the streamed path's checks and
    validation read (module docstring). ``factors`` (n_ch, p+1, p+1), ``n_obs`` (n_ch,), ``cross`` and
    ``partial`` (kept channels -> [factor, rows]) with ``method = "gm"``; ``constant``: the efforts'
    'every value equal' flags of :meth:`~dynid.pipeline.streaming.LogStream.raw_blocks`; ``states``:
    the evenly spaced state rows, ``std``: (count, mean, centred sum of squares) of every state row."""

    factors: FloatArray
    n_obs: np.ndarray
    cross: FloatArray | None
    partial: dict[tuple[int, ...], list]
    rows: int
    q_lo: FloatArray
    q_hi: FloatArray
    tau_max: FloatArray
    constant: dict[str, Any]
    notes: list[str]
    worst: float
    states: list[FloatArray]
    std: tuple[int, FloatArray, FloatArray]
    chunks: int = 1


def chunk_spans(stream: LogStream, pcfg: ProcessingConfig, out_rows: int) -> list[tuple[int, int, int, int]]:
    """The chunks ``(f_lo, f_hi, raw_lo, raw_hi)``: the processed rows of one filter block each
    (:meth:`~dynid.pipeline.streaming.LogStream.filter_rows`, so each is filtered as in-process) and
    the raw rows they need; the first chunk reads from the window's first row and the last to its end,
    and consecutive raw ranges meet, so the constant-effort flags see every raw row."""
    p = stream.processing(pcfg)
    rows, L, n = p["rows"], p["overlap"], stream.n
    per = stream.filter_rows(pcfg, out_rows)
    f_edges = list(range(0, len(rows), per)) + [len(rows)]
    spans = []
    for i, (f_lo, f_hi) in enumerate(zip(f_edges[:-1], f_edges[1:])):
        lo = 0 if i == 0 else max(0, rows[f_lo] - L)
        hi = n if f_hi == len(rows) else min(n, rows[f_hi - 1] + 1 + L)
        spans.append((f_lo, f_hi, lo, hi))
    for i in range(len(spans) - 1):  # no raw row between two chunks' ranges
        f_lo, f_hi, lo, hi = spans[i]
        spans[i] = (f_lo, f_hi, lo, max(hi, spans[i + 1][2]))
    return spans


def worker_stream(stream: LogStream) -> LogStream:
    """``stream`` as sent to a worker: no time column (:func:`_times` reads the chunk's rows), fresh
    readers (nothing of the driver's file caches), the window's length and sampling rate fixed."""
    groups = [(RowStream(TableReader(g.path, header=g.reader.header), g.names), cols) for g, cols in stream.groups]
    return dataclasses.replace(stream, groups=groups, t=np.empty(0), t0=0, n_rows=stream.n, fs_hz=stream.fs)


def _times(stream: LogStream, lo: int, hi: int) -> FloatArray:
    """The window's times of rows ``[lo, hi)``, the numbers :func:`~dynid.pipeline.streaming.open_stream`
    reads (the time column scaled to s, or row / sample rate)."""
    spec = stream.spec
    a, b = stream.start + lo, stream.start + hi
    if spec.time is None:
        return np.ascontiguousarray(np.arange(a, b) / spec.sample_rate_hz, dtype=float)
    ts = RowStream(TableReader(spec.time.file or spec.file, header=spec.header), [spec.time.column])
    t = np.concatenate(list(ts.blocks(a, b, 1 << 20)))[:, 0] * TIME_UNITS[spec.time.unit]
    return np.ascontiguousarray(t, dtype=float)


def chunk_factor(stream: LogStream, system, base, force_model: str | None, pcfg: ProcessingConfig, out_rows: int,
                 n_eff: int, span: tuple[int, int, int, int], cross: bool) -> ChunkFactor:
    """One chunk on a worker: its raw rows read, processed, regressed and compressed (module docstring)."""
    from dynid.pipeline.rows import row_mask

    f_lo, f_hi, lo, hi = span
    s = dataclasses.replace(stream, t=_times(stream, lo, hi), t0=lo)
    channels = system.channel_names(force_model)
    builder = ProblemBuilder(base.names, channels, cross=cross)
    n_a = system.n_actuators
    q_lo, q_hi, tau_max = np.full(n_a, np.inf), np.full(n_a, -np.inf), np.zeros(n_a)
    constant: dict[str, Any] = {}
    notes: list[str] = []
    sample = StateSample(n_eff, OVERLAP_ROWS, std=True)
    rows = system.rows(force_model)
    worst = 0.0
    with threadpool_limits(limits=1, user_api="blas"):  # as every trial of dynid montecarlo: one BLAS thread
        for j0, p in s.processed(system, pcfg, out_rows, constant=constant, notes=notes, span=span):
            q_lo, q_hi = np.minimum(q_lo, p["q"].min(axis=0)), np.maximum(q_hi, p["q"].max(axis=0))
            tau_max = np.maximum(tau_max, np.abs(p["tau"]).max(axis=0))
            sample.add(j0, p)
            r = rows(p["q"], p["dq"], p["ddq"], p["tau"], j0)
            W = base.regressor(r.W)
            mask = row_mask(system, force_model, p["dq"], pcfg.min_velocity, joint_dq=r.joint_dq,
                            min_velocity_passive=pcfg.min_velocity_passive)
            if mask is not None and mask.ndim == 1:
                builder.add(W[mask], r.y[mask])
            else:
                builder.add(W, r.y, mask)
            worst = max(worst, float(r.inconsistency.max(initial=0.0)))
    return ChunkFactor(builder._factors, builder._n_obs, builder._cross, builder._partial, f_hi - f_lo, q_lo, q_hi,
                       tau_max, constant, notes, worst, sample.rows, (sample.n, sample.mean, sample.m2))


def _stack(a: FloatArray, b: FloatArray) -> FloatArray:
    """R of the QR of ``[a; b]`` for two square upper-triangular factors of the same size."""
    m = a.shape[0]
    return _qr_r(np.vstack([a, b]), m)[:m]


def combine(a: ChunkFactor, b: ChunkFactor) -> ChunkFactor:
    """Two consecutive chunks' factors (``a`` first) as one: per channel the R factor of the stacked
    R factors (module docstring), counts added, extremes and flags merged, the states' mean and
    centred sum of squares merged pairwise (Chan, Golub & LeVeque 1979)."""
    with threadpool_limits(limits=1, user_api="blas"):
        factors = np.array([_stack(fa, fb) for fa, fb in zip(a.factors, b.factors)])
        cross = None if a.cross is None else _stack(a.cross, b.cross)
        partial = {ch: list(v) for ch, v in a.partial.items()}
        for ch, (f, n) in b.partial.items():
            partial[ch] = [f, n] if ch not in partial else [_stack(partial[ch][0], f), partial[ch][1] + n]
    if not a.constant or not b.constant:
        constant = a.constant or b.constant
    else:
        constant = {"first": a.constant["first"], "zero": a.constant["zero"] and b.constant["zero"],
                    "same": a.constant["same"] & b.constant["same"] & (a.constant["first"] == b.constant["first"])}
    (na, ma, sa), (nb, mb, sb) = a.std, b.std
    if ma is None or nb == 0:
        std = b.std if ma is None else a.std
    else:
        tot = na + nb
        delta = mb - ma
        std = (tot, ma + delta * nb / tot, sa + sb + delta ** 2 * na * nb / tot)
    return ChunkFactor(factors, a.n_obs + b.n_obs, cross, partial, a.rows + b.rows, np.minimum(a.q_lo, b.q_lo),
                       np.maximum(a.q_hi, b.q_hi), np.maximum(a.tau_max, b.tau_max), constant, a.notes or b.notes,
                       max(a.worst, b.worst), [*a.states, *b.states], std, a.chunks + b.chunks)


# ---------------------------------------------------------------------------------------------- the cluster
@contextlib.contextmanager
def _client(cluster: str, workers: int) -> Iterator[tuple[Any, str]]:
    """A Dask client of ``cluster`` ("local": a LocalCluster of ``workers`` processes, one thread each)
    and its description."""
    distributed = require("distributed", "montecarlo")
    if cluster == "local":
        import logging
        import os

        n = workers if workers > 0 else len(os.sched_getaffinity(0))
        # silent workers: a chunk's error (an InputError of the log) is dynid's one line, not Dask's log of it
        # (the dashboard on a free port: no clash with one already running)
        with distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                                      silence_logs=logging.CRITICAL) as lc, \
                distributed.Client(lc, set_as_default=False) as client:
            yield client, f"local Dask cluster ({n} processes)"
        return
    try:
        client = distributed.Client(cluster, timeout=SCHEDULER_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise InputError(f"identification.cluster: cannot reach the Dask scheduler at {cluster!r} ({exc})") from None
    try:
        yield client, f"Dask scheduler {cluster}"
    finally:
        client.close()


@dataclasses.dataclass
class ClusterRun:
    """The root of the tree (:class:`ChunkFactor`), the training states of the motion overlap and the
    record of ``result.json``'s ``data_path.cluster``."""

    root: ChunkFactor
    reference: StateSample
    record: dict[str, Any]


def tree_reduce(client, leaves: list) -> Any:
    """The futures ``leaves`` combined pairwise, level by level, on the cluster (:func:`combine`); an odd
    one out moves up a level unchanged. Returns the root's future. The combinations run before the
    leaves still waiting (higher priority), as soon as their pair is done, and a result is released
    once combined: a worker holds a few chunks' factors and the tree's frontier (``log2`` of the
    chunks), not every chunk's."""
    level = list(leaves)
    depth = 0
    while len(level) > 1:
        depth += 1
        nxt = [client.submit(combine, level[i], level[i + 1], priority=depth) for i in range(0, len(level) - 1, 2)]
        if len(level) % 2:
            nxt.append(level[-1])
        level = nxt
    return level[0]


def compress_on_cluster(cfg: Config, system, base, force_model: str | None, stream: LogStream, out_rows: int,
                        meta: dict[str, Any], progress) -> tuple[RegressionProblem, ClusterRun]:
    """The training problem of the streamed path computed on the cluster of ``cfg`` (module docstring):
    the :class:`RegressionProblem` and the :class:`ClusterRun`."""
    icfg, pcfg = cfg.identification, cfg.processing
    distributed = require("distributed", "montecarlo")
    spans = chunk_spans(stream, pcfg, out_rows)
    n_eff = len(stream.processing(pcfg)["rows"])
    light = worker_stream(stream)
    cross = icfg.method == "gm"
    with _client(icfg.cluster, icfg.workers) as (client, where):
        n_workers = len(client.scheduler_info()["workers"])
        if n_workers == 0:
            raise InputError(f"identification.cluster: the Dask scheduler at {icfg.cluster!r} has no workers")
        shared = client.scatter([light, system, base], broadcast=True)
        leaves = [client.submit(chunk_factor, *shared, force_model, pcfg, out_rows, n_eff, span, cross, pure=False)
                  for span in spans]
        root_future = tree_reduce(client, leaves)
        finished = distributed.as_completed(leaves, loop=client.loop)
        del leaves  # (a chunk's factors are released once combined)
        for done, fut in enumerate(finished, start=1):
            if fut.status == "error":
                fut.result()  # the worker's error (an InputError of the log: NaN at a row, a short column), here
            progress("compress", done, len(spans))
        del fut
        root = root_future.result()
    channels = system.channel_names(force_model)
    problem = RegressionProblem(
        names=base.names, channel_names=channels, factors=root.factors, n_obs=root.n_obs, cross=root.cross,
        cross_partial=tuple(CrossBlock(ch, f, n) for ch, (f, n) in sorted(root.partial.items())),
        expressions=base.expressions(), standard=system.standard_map(base), meta=meta)
    selection = [k for k, v in (("min_velocity", pcfg.min_velocity), ("min_velocity_passive", pcfg.min_velocity_passive))
                 if v is not None]
    if selection and problem.n_total <= base.n_base:  # the check of dynid.pipeline.rows._compress
        raise IdentifiabilityError(
            f"data: the row selection ({', '.join('processing.' + k for k in selection)}) keeps {problem.n_total} "
            f"equations for {base.n_base} base parameters; lower the thresholds or record a motion with fewer slow "
            "stretches and reversals")
    reference = StateSample(0, 0, std=True)
    reference.rows = root.states
    reference.n, reference.mean, reference.m2 = root.std
    record = {"cluster": icfg.cluster, "where": where, "workers": n_workers, "chunks": len(spans),
              "chunk_rows": stream.filter_rows(pcfg, out_rows), "tree_levels": int(np.ceil(np.log2(max(1, len(spans))))),
              "description": "each worker read, processed and compressed its chunks of the log; their QR factors "
                             "were combined pairwise on the cluster (dynid.pipeline.cluster_qr)"}
    return problem, ClusterRun(root, reference, record)
