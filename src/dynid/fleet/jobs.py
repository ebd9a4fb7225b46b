"""One job of a fleet: one (robot, log) pair identified by ``dynid identify`` (on a Dask worker).

:func:`run_log` is a pure function of its :class:`LogJob`: it reads the log, runs
:func:`dynid.pipeline.identification.identify` on the configuration of the robot's model with
that log, and returns a :class:`LogResult` of plain arrays (the estimate, its covariance, the
held-out errors, the verdict against the prior, and the held-out rows compressed so that any
other parameter vector, the robot's pooled estimate, can be scored on them exactly). A log's
own faults (missing, unreadable, wrong columns, another robot's joints, too little excitation)
come back as a result with ``error`` set; they never raise.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from dynid.config import Config
from dynid.errors import DynidError

__all__ = ["LogJob", "LogResult", "run_log", "held_out_factors", "factor_sse", "LOG_ERRORS"]

LOG_ERRORS = (DynidError, np.linalg.LinAlgError)
"""Errors that fail one log (reported with it); anything else is a fault of dynid or of the worker:
Dask retries it and the fleet reports it if it persists."""


@dataclasses.dataclass(frozen=True)
class LogJob:
    """What a worker needs for one log: its place in the table, robot, file, date (days since the
    fleet's first date, None when undated) and the identify configuration."""

    index: int
    robot: str
    file: str
    days: float | None
    config: Config


@dataclasses.dataclass(frozen=True, eq=False)
class LogResult:
    """One identified log. Arrays: ``params`` (p,), ``cov`` (p, p); per output channel ``rmse``,
    ``rms`` (of the measured output) and ``nominal_rmse`` (the robot description's model) on the
    held-out rows; ``factors`` (channels, p + 1, p + 1): the R factor of the QR of the held-out rows
    ``[W_j  y_j]`` of each channel, ``rows`` (channels,) their numbers: the sum of squared
    errors of any parameter vector ``theta`` on channel ``j`` is ``||R_j [theta; -1]||^2``."""

    index: int
    robot: str
    file: str
    days: float | None
    error: str | None = None
    names: tuple[str, ...] = ()
    expressions: tuple[str, ...] = ()
    channels: tuple[str, ...] = ()
    method: str = ""
    params: np.ndarray | None = None
    cov: np.ndarray | None = None
    nominal: np.ndarray | None = None  # the nominal model's base parameters
    rmse: np.ndarray | None = None
    rms: np.ndarray | None = None
    nominal_rmse: np.ndarray | None = None
    factors: np.ndarray | None = None
    rows: np.ndarray | None = None
    verdict: str = ""
    beats_nominal: bool = False
    n_train: int = 0
    sha256: str | None = None
    seconds: float = float("nan")

    @property
    def ok(self) -> bool:
        return self.error is None


def _update_r(r: np.ndarray | None, block: np.ndarray) -> np.ndarray:
    """The R factor of ``[r; block]`` (rows stacked), square (p + 1, p + 1)."""
    stacked = block if r is None else np.vstack([r, block])
    rr = np.linalg.qr(stacked, mode="r")
    k = stacked.shape[1]
    if rr.shape[0] < k:  # fewer rows than columns so far
        rr = np.vstack([rr, np.zeros((k - rr.shape[0], k))])
    return rr


def held_out_factors(outcome: Any) -> tuple[np.ndarray, np.ndarray]:
    """The held-out rows of an identification (processed as identify scored them) compressed per
    channel: R factors (channels, p + 1, p + 1) of ``[W_j  y_j]`` and the row counts (channels,)."""
    from dynid.pipeline.rows import _chunks

    cfg = outcome.config
    pcfg = cfg.processing
    force_model = (outcome.prediction or {}).get("force_model")
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    factors: list[np.ndarray | None] | None = None
    rows = None
    from dynid.model.system import as_system

    system = outcome.system if outcome.system is not None else as_system(outcome.robot)
    for c in _chunks(system, outcome.base, outcome.held_out, force_model, parallel_decimate=parallel,
                     chunk_size=cfg.identification.chunk_size):
        W, y = np.asarray(c.W), np.asarray(c.y)
        if factors is None:
            factors, rows = [None] * y.shape[1], np.zeros(y.shape[1], dtype=int)
        for j in range(y.shape[1]):
            block = np.column_stack([W[:, j, :], y[:, j]])
            block = block[np.all(np.isfinite(block), axis=1)]
            if block.shape[0]:
                factors[j] = _update_r(factors[j], block)
                rows[j] += block.shape[0]
    p = len(outcome.base.names)
    return np.stack([f if f is not None else np.zeros((p + 1, p + 1)) for f in factors]), rows


def factor_sse(factors: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Per channel: the sum of squared errors ``||y_j - W_j theta||^2`` from the factors."""
    v = np.append(np.asarray(theta, float), -1.0)
    return np.sum(np.einsum("cij,j->ci", factors, v) ** 2, axis=1)


def run_log(job: LogJob) -> LogResult:
    """Identify one log (one BLAS thread, so its numbers do not depend on where it runs)."""
    from threadpoolctl import threadpool_limits

    from dynid.pipeline.identification import identify
    from dynid.pipeline.reporting import file_sha256

    head = dict(index=job.index, robot=job.robot, file=job.file, days=job.days)
    with threadpool_limits(limits=1):
        t0 = time.perf_counter()
        try:
            outcome = identify(job.config)
            if outcome.held_out is None:
                raise DynidError("the log was identified on the streamed path, which keeps no held-out rows to score "
                                 "the robot's pooled estimate on")
            res = outcome.result
            if res.cov_params is None:
                raise DynidError(f"method {res.method!r} gave no covariance: the estimate cannot be pooled or tested")
            factors, rows = held_out_factors(outcome)
        except LOG_ERRORS as exc:
            return LogResult(**head, error=f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                             seconds=time.perf_counter() - t0)
        seconds = time.perf_counter() - t0
    v, nv = outcome.validation, outcome.nominal_validation
    from dynid.model.system import as_system

    system = outcome.system if outcome.system is not None else as_system(outcome.robot)
    nominal = outcome.base.from_standard(system.nominal_parameters())
    prior = outcome.prior or {}
    return LogResult(
        **head, names=tuple(res.names), expressions=tuple(outcome.base.expressions()), channels=tuple(v.channel_names),
        method=res.method, params=np.array(res.params, float), cov=np.array(res.cov_params, float),
        nominal=np.asarray(nominal, float), rmse=np.asarray(v.rmse, float), rms=np.asarray(v.rms_measured, float),
        nominal_rmse=None if nv is None else np.asarray(nv.rmse, float), factors=factors, rows=rows,
        verdict=str(prior.get("verdict", "")), beats_nominal=bool(prior.get("beats_nominal", False)),
        n_train=int(outcome.n_train), sha256=file_sha256(job.file), seconds=seconds,
    )
