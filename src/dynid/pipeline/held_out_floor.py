"""The held-out-fit floor (issue 36, item 3): the model structure the identification used, fitted
by least squares to the held-out rows themselves and scored on those same rows.

A held-out error says little on its own: on a log whose rows no model of the structure predicts
well (reversals where the friction chatters, rows where only the noise is left) even the truth
scores badly. The floor says what the structure can reach *on that log*: no base-parameter vector,
fitted on any training log by any method, predicts those rows with a smaller pooled RMS error,
because ordinary least squares on exactly those rows minimises it (the guarantee is on the
pooled squared error :math:`\\sum_k n_k\\,\\mathrm{RMSE}_k^2`, the quantity least squares
minimises; a per-channel RMSE or their sum is not guaranteed, only close).

Accumulated over the chunks of the held-out pass (:func:`~dynid.pipeline.validation.validate_with_prior`)
without holding the regressor: the R factor of the augmented rows :math:`[W\\;y]` (QR updated chunk
by chunk, accurate for an ill-conditioned regressor) gives the estimate, the per-channel Gram
matrices :math:`W_k^T W_k`, :math:`W_k^T y_k`, :math:`y_k^T y_k` its per-channel errors.
Only for a model linear in its parameters (a Stribeck or hierarchical fit has none).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dynid._typing import FloatArray

__all__ = ["HeldOutFloor", "FloorAccumulator", "pooled_rmse"]

RCOND = 1e-10
"""Singular values of the column-scaled R below this fraction of the largest are dropped (a held-out
log, or its kept rows, that does not excite every base parameter: the minimum-norm solution of the
rest still minimises the error)."""


def pooled_rmse(rmse: FloatArray, rows: FloatArray) -> float:
    """:math:`\\sqrt{\\sum_k n_k \\mathrm{RMSE}_k^2 / \\sum_k n_k}` over the channels with rows."""
    rmse, rows = np.asarray(rmse, float), np.asarray(rows, float)
    ok = rows > 0
    return float(np.sqrt(np.sum(rows[ok] * rmse[ok] ** 2) / np.sum(rows[ok]))) if ok.any() else float("nan")


@dataclasses.dataclass(frozen=True)
class HeldOutFloor:
    """The floor on some held-out rows: per-channel RMSE of the least-squares fit to those rows,
    its pooled RMS (the guaranteed one), the rows per channel, the rank the rows gave the regressor."""

    channel_names: tuple[str, ...]
    rmse: FloatArray
    pooled: float
    rows_per_channel: FloatArray
    rank: int
    n_params: int
    params: FloatArray

    def to_dict(self) -> dict[str, Any]:
        return {"method": "ols on these held-out rows", "joints": list(self.channel_names),
                "rmse_per_joint": [None if not np.isfinite(x) else float(x) for x in self.rmse],
                "pooled_rmse": None if not np.isfinite(self.pooled) else self.pooled,
                "rows_per_joint": [int(k) for k in self.rows_per_channel], "rank": self.rank, "n_params": self.n_params}


class FloorAccumulator:
    """Least squares of ``y`` on ``W`` over the rows of a mask, chunk by chunk."""

    def __init__(self, channel_names, n_params: int):
        self.names = tuple(channel_names)
        p, c = n_params, len(self.names)
        self.p = p
        self.R = np.zeros((0, p + 1))
        self.G = np.zeros((c, p, p))
        self.b = np.zeros((c, p))
        self.yy = np.zeros(c)
        self.n = np.zeros(c, dtype=np.int64)

    def add(self, W: FloatArray, y: FloatArray, mask: np.ndarray | None = None) -> None:
        """Rows ``W`` (n, n_ch, p), ``y`` (n, n_ch); ``mask`` (n, n_ch) bool: the equations kept."""
        W, y = np.asarray(W, float), np.asarray(y, float)
        m = np.ones(y.shape, dtype=bool) if mask is None else np.broadcast_to(np.asarray(mask, bool), y.shape)
        for k in range(len(self.names)):
            Wk, yk = W[m[:, k], k, :], y[m[:, k], k]
            self.G[k] += Wk.T @ Wk
            self.b[k] += Wk.T @ yk
            self.yy[k] += yk @ yk
            self.n[k] += yk.size
        A = np.concatenate([W[m], y[m][:, None]], axis=1)  # the kept equations, [W y]
        if A.shape[0]:
            self.R = np.linalg.qr(np.vstack([self.R, A]), mode="r")

    def result(self) -> HeldOutFloor:
        p = self.p
        R = np.zeros((p + 1, p + 1))
        R[: self.R.shape[0]] = self.R[: p + 1]
        d = np.linalg.norm(R[:, :p], axis=0)  # column norms of W (those of R)
        d = np.where(d > 0, d, 1.0)
        U, s, Vt = np.linalg.svd(R[:p, :p] / d, full_matrices=False)
        rank = int(np.sum(s > RCOND * s[0])) if s.size and s[0] > 0 else 0
        z = (U[:, :rank].T @ R[:p, p]) / s[:rank]
        beta = (Vt[:rank].T @ z) / d
        # per-channel squared error from the Gram matrices (cancellation: eps |y|^2, negligible
        # unless the fit explains all but 1e-12 of the output's energy; clipped at 0)
        sse = self.yy - 2 * self.b @ beta + np.einsum("i,kij,j->k", beta, self.G, beta)
        sse = np.maximum(sse, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            rmse = np.where(self.n > 0, np.sqrt(sse / np.maximum(self.n, 1)), np.nan)
        return HeldOutFloor(self.names, rmse, pooled_rmse(rmse, self.n), self.n.copy(), rank, p, beta)
