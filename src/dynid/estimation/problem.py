"""The compressed linear regression problem ``y = W beta + e``, built chunk by chunk.

For each output channel ``j`` (joint or actuator) the rows ``(W_j, y_j)`` are reduced by
an incremental QR factorization of the augmented matrix ``[W_j | y_j]``:

.. math::

    [W_j \\;|\\; y_j] = Q_j \\begin{bmatrix} R_j & z_j \\\\ 0 & \\rho_j \\end{bmatrix},
    \\qquad \\|y_j - W_j\\beta\\|^2 = \\|z_j - R_j\\beta\\|^2 + \\rho_j^2 .

Only the ``(p+1) x (p+1)`` factor per channel is kept, so memory does not grow with the
number of samples; the full stacked regressor never exists. Keeping one factor per
channel lets OLS, WLS (per-channel weights, Gautier) and later estimators work from
the compressed form, and gives exact per-channel residual sums of squares for any
parameter vector.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from dynid._typing import BoolArray, FloatArray
from dynid.errors import InputError
from dynid.model.base_parameters import StandardMap

__all__ = ["CrossBlock", "RegressionProblem", "ProblemBuilder"]


def _qr_r(a: FloatArray, size: int) -> FloatArray:
    r = np.linalg.qr(a, mode="r")
    if r.shape[0] < size:
        r = np.vstack([r, np.zeros((size - r.shape[0], size))])
    return r


@dataclasses.dataclass(frozen=True, eq=False)
class CrossBlock:
    """Cross-channel factor of the samples in which only the channels ``channels`` are kept.

    A per-channel row selection (``processing.min_velocity``, ``processing.reversal_guard``)
    leaves some samples with a subset :math:`K` of their channels. Gauss–Markov weights such a
    sample by the inverse of :math:`\\Sigma_{KK}`, the covariance of its kept channels (the
    marginal of a Gaussian is Gaussian with that block), so those samples need the wide factor
    of their own channels: ``factor`` is the upper-triangular factor, shape
    (|K| (p + 1), |K| (p + 1)), of the rows ``[W_k(i) | y_k(i)]`` for ``k`` in ``channels``, side
    by side, over the ``n_rows`` samples with exactly that pattern.
    """

    channels: tuple[int, ...]
    factor: FloatArray
    n_rows: int


@dataclasses.dataclass(frozen=True, eq=False)
class RegressionProblem:
    """Compressed per-channel least-squares problem (see module docstring).

    Attributes
    ----------
    names : tuple of str
        Parameter names (columns of ``W``), length ``p``.
    channel_names : tuple of str
        Output channels (joints or actuators), length ``n_ch``.
    factors : array, shape (n_ch, p + 1, p + 1)
        Upper-triangular augmented factors ``[[R_j, z_j], [0, rho_j]]``.
    n_obs : int array, shape (n_ch,)
        Rows accumulated per channel.
    expressions : tuple of str, optional
        Grouping expressions of the parameters (display only).
    standard : StandardMap, optional
        Map to physical standard parameters (needed by constrained estimators).
    meta : mapping
        Provenance of the problem (data sources, processing).
    cross : array, shape (n_ch (p + 1), n_ch (p + 1)), optional
        Upper-triangular factor of the *wide* matrix whose row ``i`` holds the augmented rows
        ``[W_j(i) | y_j(i)]`` of every channel side by side (``ProblemBuilder(cross=True)``).
        Its Gram matrix holds every cross-channel product, which Gauss–Markov estimation with
        a full noise covariance across channels needs (see
        :func:`dynid.estimation.linear.gls_solve`); per-channel factors cannot give it.
        With a per-channel row selection it holds the samples in which every channel is kept.
    cross_partial : tuple of CrossBlock
        The wide factors of the samples in which only some channels are kept, one per pattern of
        kept channels (empty without a per-channel row selection).
    """

    names: tuple[str, ...]
    channel_names: tuple[str, ...]
    factors: FloatArray
    n_obs: np.ndarray
    expressions: tuple[str, ...] | None = None
    standard: StandardMap | None = None
    meta: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    cross: FloatArray | None = None
    cross_partial: tuple[CrossBlock, ...] = ()

    def __post_init__(self) -> None:
        f = np.array(self.factors, dtype=float)
        p = len(self.names)
        if f.shape != (len(self.channel_names), p + 1, p + 1):
            raise InputError(f"factors have shape {f.shape}, expected {(len(self.channel_names), p + 1, p + 1)}")
        n_obs = np.array(self.n_obs, dtype=np.int64)
        f.setflags(write=False)
        n_obs.setflags(write=False)
        object.__setattr__(self, "factors", f)
        object.__setattr__(self, "n_obs", n_obs)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "channel_names", tuple(self.channel_names))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))
        if self.cross is not None:
            c = np.array(self.cross, dtype=float)
            m = len(self.channel_names) * (p + 1)
            if c.shape != (m, m):
                raise InputError(f"cross factor has shape {c.shape}, expected {(m, m)}")
            c.setflags(write=False)
            object.__setattr__(self, "cross", c)
        blocks = []
        for blk in self.cross_partial:
            if self.cross is None:
                raise InputError("partial cross-channel factors need the full one (cross)")
            ch = tuple(int(k) for k in blk.channels)
            if not ch or len(set(ch)) != len(ch) or min(ch) < 0 or max(ch) >= len(self.channel_names):
                raise InputError(f"cross block channels {ch} are not distinct channels of the problem")
            c = np.array(blk.factor, dtype=float)
            m = len(ch) * (p + 1)
            if c.shape != (m, m):
                raise InputError(f"cross block of channels {ch} has shape {c.shape}, expected {(m, m)}")
            c.setflags(write=False)
            blocks.append(CrossBlock(ch, c, int(blk.n_rows)))
        object.__setattr__(self, "cross_partial", tuple(blocks))
        if self.standard is not None and self.standard.B.shape[0] != p:
            raise InputError(f"standard map has {self.standard.B.shape[0]} base parameters, the problem {p}")

    # ------------------------------------------------------------------ views
    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def n_channels(self) -> int:
        return len(self.channel_names)

    @property
    def n_total(self) -> int:
        return int(self.n_obs.sum())

    @property
    def R(self) -> FloatArray:
        """Per-channel triangular factors, shape (n_ch, p, p)."""
        p = self.n_params
        return self.factors[:, :p, :p]

    @property
    def z(self) -> FloatArray:
        """Per-channel projected outputs ``Q_j^T y_j``, shape (n_ch, p)."""
        p = self.n_params
        return self.factors[:, :p, p]

    @property
    def rss_floor(self) -> FloatArray:
        """Per-channel residual outside the column space, ``rho_j^2``, shape (n_ch,)."""
        p = self.n_params
        return self.factors[:, p, p] ** 2

    def rss_per_channel(self, beta: FloatArray) -> FloatArray:
        """Exact residual sum of squares ``||y_j - W_j beta||^2`` per channel."""
        beta = np.asarray(beta, dtype=float)
        r = self.z - np.einsum("jab,b->ja", self.R, beta)
        return np.sum(r**2, axis=1) + self.rss_floor

    def cross_blocks(self) -> list[CrossBlock]:
        """Every cross-channel factor: the full one (all channels) first, then the partial ones.

        The full block's sample count is the rows of channel 0 not in a partial block."""
        if self.cross is None:
            return []
        n_full = int(self.n_obs[0]) - sum(b.n_rows for b in self.cross_partial if 0 in b.channels)
        full = CrossBlock(tuple(range(self.n_channels)), self.cross, n_full)
        return [full, *self.cross_partial]

    def channel_ranks(self, rtol: float = 1e-10) -> np.ndarray:
        """Number of parameters acting on each channel (non-zero columns of ``R_j``)."""
        norms = np.linalg.norm(self.R, axis=1)  # (n_ch, p)
        top = norms.max(axis=1, keepdims=True)
        top[top == 0] = 1.0
        return np.count_nonzero(norms > rtol * top, axis=1)

    def replace(self, **changes: Any) -> RegressionProblem:
        return dataclasses.replace(self, **changes)

    def select(self, names: Sequence[str]) -> RegressionProblem:
        """The problem restricted to the parameters ``names`` (the others fixed at zero).

        Exact: the columns of the augmented factors ``[R_j | z_j]`` that are kept are
        re-triangularized, so the residual of the dropped columns moves into ``rho_j``.
        Used by model-structure searches (paper 000 §6.2). The standard map is dropped
        (a subset of base parameters no longer maps to all standard parameters).
        """
        index = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in index]
        if missing:
            raise InputError(f"unknown parameters {missing}")
        if len(set(names)) != len(names) or not names:
            raise InputError("select needs distinct parameter names, at least one")
        p = self.n_params
        cols = [index[n] for n in names] + [p]
        q = len(names)
        f = np.array([_qr_r(self.factors[j][:, cols], q + 1)[: q + 1] for j in range(self.n_channels)])
        cross, partial = None, []
        if self.cross is not None:
            wide = [j * (p + 1) + c for j in range(self.n_channels) for c in cols]
            cross = _qr_r(self.cross[:, wide], len(wide))[: len(wide)]
            for blk in self.cross_partial:
                wide = [i * (p + 1) + c for i in range(len(blk.channels)) for c in cols]
                partial.append(CrossBlock(blk.channels, _qr_r(blk.factor[:, wide], len(wide))[: len(wide)], blk.n_rows))
        exprs = None if self.expressions is None else tuple(self.expressions[index[n]] for n in names)
        return RegressionProblem(names=tuple(names), channel_names=self.channel_names, factors=f, n_obs=self.n_obs,
                                 expressions=exprs, standard=None, meta=self.meta, cross=cross,
                                 cross_partial=tuple(partial))

    @classmethod
    def from_arrays(
        cls,
        W: FloatArray,
        y: FloatArray,
        names: Sequence[str],
        channel_names: Sequence[str] | None = None,
        mask: BoolArray | None = None,
        *,
        cross: bool = False,
        **kwargs: Any,
    ) -> RegressionProblem:
        """Compress a regressor ``W`` (n, n_ch, p) and outputs ``y`` (n, n_ch) in one go."""
        W = np.asarray(W, dtype=float)
        if channel_names is None:
            channel_names = tuple(f"ch{j + 1}" for j in range(W.shape[1]))
        b = ProblemBuilder(names, channel_names, cross=cross)
        b.add(W, y, mask)
        return b.build(**kwargs)


class ProblemBuilder:
    """Working memory that accumulates chunks into a :class:`RegressionProblem`.

    Examples
    --------
    >>> b = ProblemBuilder(names, joint_names)          # doctest: +SKIP
    >>> for W, y in chunks: b.add(W, y)                  # doctest: +SKIP
    >>> problem = b.build()                              # doctest: +SKIP
    """

    def __init__(self, names: Sequence[str], channel_names: Sequence[str], *, cross: bool = False) -> None:
        self.names = tuple(names)
        self.channel_names = tuple(channel_names)
        p = len(self.names)
        self._factors = np.zeros((len(self.channel_names), p + 1, p + 1))
        self._n_obs = np.zeros(len(self.channel_names), dtype=np.int64)
        m = len(self.channel_names) * (p + 1)
        self._cross = np.zeros((m, m)) if cross else None
        self._partial: dict[tuple[int, ...], list] = {}  # kept channels -> [factor, rows]

    def add(self, W: FloatArray, y: FloatArray, mask: BoolArray | None = None) -> None:
        """Accumulate rows.

        Parameters
        ----------
        W : array, shape (n, n_ch, p)
            Regressor chunk.
        y : array, shape (n, n_ch)
            Measured outputs.
        mask : bool array, shape (n, n_ch), optional
            Rows to use per channel (e.g. to drop near-zero-velocity samples of one joint).
            With ``cross=True`` the samples that keep only some channels go into the wide
            factor of their pattern of kept channels (:class:`CrossBlock`).
        """
        W = np.asarray(W, dtype=float)
        y = np.asarray(y, dtype=float)
        n_ch, p = len(self.channel_names), len(self.names)
        if W.ndim != 3 or W.shape[1:] != (n_ch, p):
            raise InputError(f"regressor chunk has shape {W.shape}, expected (n, {n_ch}, {p})")
        if y.shape != W.shape[:2]:
            raise InputError(f"mismatched lengths: regressor {W.shape[:2]} vs outputs {y.shape}")
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != y.shape:
                raise InputError(f"row mask has shape {mask.shape}, expected {y.shape}")
        if not (np.all(np.isfinite(W)) and np.all(np.isfinite(y))):
            raise InputError("regressor or outputs contain NaN/inf")
        # one BLAS thread: the QR of a tall, narrow block gains nothing from threads and
        # multi-threaded OpenBLAS is many times slower on a loaded machine (bench/README.md)
        with threadpool_limits(limits=1, user_api="blas"):
            self._add(W, y, mask)

    def _add(self, W: FloatArray, y: FloatArray, mask: BoolArray | None) -> None:
        n_ch, p = len(self.channel_names), len(self.names)
        for j in range(n_ch):
            rows = slice(None) if mask is None else mask[:, j]
            Wj, yj = W[rows, j, :], y[rows, j]
            m = Wj.shape[0]
            if m == 0:
                continue
            a = np.empty((p + 1 + m, p + 1))
            a[: p + 1] = self._factors[j]
            a[p + 1 :, :p] = Wj
            a[p + 1 :, p] = yj
            self._factors[j] = _qr_r(a, p + 1)[: p + 1]
            self._n_obs[j] += m
        if self._cross is not None and W.shape[0] > 0:
            aug = np.concatenate([W, y[:, :, None]], axis=2)
            if mask is None:
                full = slice(None)
            else:
                full = mask.all(axis=1)
                codes = mask.astype(np.int64) @ (1 << np.arange(n_ch, dtype=np.int64))
                for code in np.unique(codes[~full & mask.any(axis=1)]):
                    rows = codes == code
                    ch = tuple(int(k) for k in np.flatnonzero(mask[np.argmax(rows)]))
                    wide = aug[rows][:, ch, :].reshape(int(rows.sum()), -1)
                    m = wide.shape[1]
                    blk = self._partial.setdefault(ch, [np.zeros((m, m)), 0])
                    blk[0] = _qr_r(np.vstack([blk[0], wide]), m)[:m]
                    blk[1] += int(rows.sum())
            wide = aug[full].reshape(-1, n_ch * (p + 1))
            if wide.shape[0]:
                self._cross = _qr_r(np.vstack([self._cross, wide]), self._cross.shape[0])[: self._cross.shape[0]]

    def build(self, **kwargs: Any) -> RegressionProblem:
        return RegressionProblem(
            names=self.names,
            channel_names=self.channel_names,
            factors=self._factors.copy(),
            n_obs=self._n_obs.copy(),
            cross=None if self._cross is None else self._cross.copy(),
            cross_partial=tuple(CrossBlock(ch, f.copy(), n) for ch, (f, n) in sorted(self._partial.items())),
            **kwargs,
        )
