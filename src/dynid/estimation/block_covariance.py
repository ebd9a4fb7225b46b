"""Covariances of least-squares estimates that hold when the residuals are correlated in time:
a block-robust sandwich (HAC) and a block bootstrap, both on a per-block compression.

Why. OLS/WLS report :math:`s^2 (W^T \\Lambda W)^{-1}` (:mod:`dynid.estimation.linear`), which
assumes residuals independent from sample to sample. On filtered, differentiated closed-loop logs
they are not: position noise low-passed and differentiated twice lives in the regressor over
tens of samples, the controller feeds it back into the forces, and the reported intervals are too
narrow. Both covariances here keep the estimate and replace only its covariance; they need no
model of the correlation, only blocks longer than it.

Blocks. The training rows are cut, by sample position, into ``B`` contiguous blocks with equal
numbers of samples (the same boundaries for every channel; rows left out by a row selection just
leave their block shorter). Per block ``b`` and channel ``j`` the augmented rows are compressed
like the whole problem (:mod:`dynid.estimation.problem`) to a triangular factor
:math:`F_{bj}` of at most ``p + 1`` rows with :math:`F_{bj}^T F_{bj} = [W_{bj}\\,y_{bj}]^T
[W_{bj}\\,y_{bj}]`. Gram matrices add, so any union of blocks, the whole log included, is a sum:
memory is at most ``B (p + 1)`` rows per channel whatever the length of the log, and one pass over
the chunks builds the blocks next to the problem itself. With the channel weights :math:`w_j` of
the fit (1 for OLS, :math:`1/\\hat\\sigma_j^2` for WLS) the whitened factor of block ``b`` is the
QR of the stacked :math:`\\sqrt{w_j} F_{bj}`, :math:`\\tilde F_b = [\\tilde R_b\\,|\\,\\tilde f_b]`,
and

.. math::

    A_b = \\tilde R_b^T \\tilde R_b,\\quad c_b = \\tilde R_b^T \\tilde f_b,\\quad
    A = \\sum_b A_b,\\quad \\hat\\beta = A^{-1} \\sum_b c_b,\\quad
    g_b = c_b - A_b \\hat\\beta = \\tilde R_b^T u_b,\\; u_b = \\tilde f_b - \\tilde R_b \\hat\\beta .

``covariance = "hac"`` (deterministic, the recommended one). The sandwich of the block scores
:math:`g_b` with a Bartlett kernel over ``L`` neighbouring blocks (Newey & West 1987, Eq. 2; on
block sums it is the batch-means / cluster-robust estimator, Cameron & Miller 2015 §II.C and
§VI),

.. math::

    \\mathrm{cov}(\\hat\\beta) = A^{-1} M A^{-1},\\qquad
    M = \\sum_b \\tilde g_b \\tilde g_b^T + \\sum_{l=1}^{L} \\Big(1 - \\frac{l}{L+1}\\Big)
    \\sum_b (\\tilde g_b \\tilde g_{b+l}^T + \\tilde g_{b+l} \\tilde g_b^T),

positive semi-definite for any data (Newey & West 1987, Theorem 1). The scores carry the CR2
leverage correction of Bell & McCaffrey (2002, Eq. 3; Imbens & Kolesár 2016):
:math:`\\tilde g_b = \\tilde R_b^T (I - H_b)^{-1/2} u_b` with :math:`H_b = \\tilde R_b A^{-1}
\\tilde R_b^T`, which makes ``M`` unbiased for white noise (``L = 0``) however short the blocks
and however many parameters (raw residuals shrink by the leverage of their block: with ``p``
parameters and ``B`` blocks the average leverage is ``p / B``, 0.5 for the hexapod's 102
parameters in 204 blocks). The compressed form gives it exactly: :math:`[\\tilde W_b\\,\\tilde
y_b] = Q_b \\tilde F_b` with orthonormal :math:`Q_b`, so :math:`\\tilde W_b^T (I - \\tilde W_b
A^{-1} \\tilde W_b^T)^{-1/2} \\tilde e_b = \\tilde R_b^T (I - H_b)^{-1/2} u_b`. Directions that
one block determines alone (:math:`H_b` eigenvalue 1, residual 0) are left out
(pseudo-inverse). ``L = 1`` (default) counts the correlation that reaches across a block
boundary; ``L = 0`` is the plain cluster-robust (CR2) estimator.

``covariance = "block_bootstrap"``. The non-overlapping block bootstrap (Carlstein 1986;
Künsch 1989 for the moving-block version it approximates; Politis & Romano 1994 for the
review of block resampling): a replicate draws ``B`` blocks with replacement, its estimate is
the ``p x p`` solve :math:`(\\sum_b n_b A_b)^{-1} \\sum_b n_b c_b` (:math:`n_b` the times block
``b`` was drawn; WLS keeps the weights of the fit), and the covariance is the sample covariance
of ``R`` replicate estimates. It treats the blocks as independent (no cross-boundary term), is
random (deterministic for a seed) and needs ``R > p`` replicates for a full-rank covariance.

Choosing the blocks. Blocks must be longer than the residual correlation (for a zero-phase
low-pass of order ``n`` at :math:`f_c` that is a few :math:`1/f_c`), and there must be more of
them than parameters: ``M`` is a sum of ``B`` rank-one terms, so with ``B <= p`` the covariance
is singular (Cameron & Miller 2015 §VI.B) and no confidence ellipsoid exists. The default is
``B = max(50, 2 (p + 1))`` blocks (fewer when the log has fewer samples); a memory bound
independent of the log, and within the block-length rate :math:`N^{1/3}` of Künsch (1989) for
the usual lengths. Excitation periods make natural blocks when the log holds many of them (give a
multiple of the number of periods as ``covariance_blocks`` on a whole number of periods); an
averaged or short periodic log has too few periods for ``p`` parameters. The adjacent-block
correlation of the scores is reported (:attr:`solver` ``["covariance"]``): when it is large the
blocks are shorter than the correlation and the covariance is still too small.

The intervals keep the result's Student quantile with ``N - p`` degrees of freedom; the
cluster-robust reference would be ``t(B - 1)`` (Cameron & Miller 2015 §VI.D), 2.4 % wider at ``B = 50``
and 0.5 % at ``B = 200``. What the covariance cannot hold is a bias: a systematic residual
(processing error at Coulomb reversals, filtered closed-loop motion) that is the same in every
repetition of the experiment widens the intervals as far as it varies along the log, no further
(figures on the hexapod twin in ``bench/README.md`` §8).

References: Newey W., West K. (1987) Econometrica 55(3) 703–708; Bell R., McCaffrey D. (2002)
Survey Methodology 28(2) 169–181; Cameron A.C., Miller D. (2015) J. Human Resources 50(2)
317–372; Carlstein E. (1986) Ann. Statist. 14(3) 1171–1179; Künsch H. (1989) Ann. Statist. 17(3)
1217–1241; Politis D., Romano J. (1994) JASA 89(428) 1303–1313; Imbens G., Kolesár M. (2016)
Rev. Econ. Stat. 98(4) 701–712.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import numpy as np
import scipy.linalg as sla
from threadpoolctl import ThreadpoolController

from dynid._typing import BoolArray, FloatArray
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation.results import IdentificationResult

__all__ = ["COVARIANCE_KINDS", "BlockBuilder", "BlockSums", "block_covariance", "default_blocks", "robust_result"]

COVARIANCE_KINDS = ("model", "hac", "block_bootstrap")
"""``model``: the estimator's own :math:`s^2 (W^T\\Lambda W)^{-1}`; the others: this module."""

METHODS = ("OLS", "WLS")
"""Estimators whose estimate is :math:`A^{-1}\\sum_b c_b` with fixed channel weights."""


def default_blocks(n_params: int, n_samples: int) -> int:
    """The default number of blocks, ``max(50, 2 (p + 1))``, at most one per sample."""
    return max(1, min(int(n_samples), max(50, 2 * (int(n_params) + 1))))


@functools.cache
def _threads() -> ThreadpoolController:
    return ThreadpoolController()


def _one_blas_thread():
    """One BLAS thread for the many small factorizations (as :class:`~dynid.estimation.ProblemBuilder`);
    the controller is found once, not per call."""
    return _threads().limit(limits=1, user_api="blas")


def _qr_rows(a: FloatArray) -> FloatArray:
    """Triangular factor of ``a`` with at most ``a.shape[1]`` rows (``R^T R = a^T a``)."""
    if a.shape[0] == 0:
        return a
    return np.linalg.qr(a, mode="r")


@dataclasses.dataclass(frozen=True, eq=False)
class BlockSums:
    """Per-block compression of the training rows (see the module docstring).

    Attributes
    ----------
    names, channel_names : tuple of str
    factors : tuple of tuple of arrays
        ``factors[b][j]``: augmented factor of block ``b``, channel ``j``, shape (m, p + 1), m <= p + 1.
    index : int array (B,)
        Position of each non-empty block among the ``n_blocks`` cut (adjacency for the lags).
    n_blocks : int
        Blocks cut (empty ones, e.g. all rows left out, are not kept).
    samples_per_block : float
        Samples per block of the cut [samples].
    """

    names: tuple[str, ...]
    channel_names: tuple[str, ...]
    factors: tuple[tuple[FloatArray, ...], ...]
    index: np.ndarray
    n_blocks: int
    samples_per_block: float

    def whitened(self, weights: FloatArray) -> list[FloatArray]:
        """The whitened factors :math:`\\tilde F_b` of every block for channel weights ``w_j``."""
        sw = np.sqrt(np.asarray(weights, dtype=float))
        with _one_blas_thread():
            return [_qr_rows(np.vstack([f * s for f, s in zip(fb, sw)])) for fb in self.factors]


class BlockBuilder:
    """Working memory that accumulates chunks of rows into :class:`BlockSums`.

    Rows arrive in sample order (chunk after chunk); sample ``i`` belongs to block
    ``min(B - 1, i B // n_samples)``.

    Parameters
    ----------
    names, channel_names : sequences of str
        Parameters and output channels of the problem.
    n_blocks : int
        ``B``, at least 2.
    n_samples : int
        Samples the chunks will hold in all (sets the block boundaries).
    """

    def __init__(self, names: Sequence[str], channel_names: Sequence[str], n_blocks: int, n_samples: int) -> None:
        if int(n_blocks) < 2:
            raise InputError(f"covariance blocks must be at least 2, got {n_blocks}")
        if int(n_samples) < int(n_blocks):
            raise InputError(f"{n_blocks} covariance blocks for {n_samples} processed samples: at most one block "
                             "per sample (choose fewer blocks)")
        self.names, self.channel_names = tuple(names), tuple(channel_names)
        self.n_blocks, self.n_samples = int(n_blocks), int(n_samples)
        p1 = len(self.names) + 1
        self._f = [[np.zeros((0, p1)) for _ in self.channel_names] for _ in range(self.n_blocks)]
        self._pos = 0

    def add(self, W: FloatArray, y: FloatArray, mask: BoolArray | None = None) -> None:
        """Accumulate the next ``n`` samples: ``W`` (n, n_ch, p), ``y`` (n, n_ch), ``mask`` the rows
        kept: None (all), (n,) whole samples or (n, n_ch) per channel."""
        W, y = np.asarray(W, dtype=float), np.asarray(y, dtype=float)
        n, n_ch = y.shape
        keep = np.ones((n, n_ch), bool) if mask is None else np.broadcast_to(
            np.asarray(mask, bool).reshape(n, -1), (n, n_ch))
        blk = np.minimum(self.n_blocks - 1, (self._pos + np.arange(n)) * self.n_blocks // self.n_samples)
        self._pos += n
        aug = np.concatenate([W, y[:, :, None]], axis=2)
        with _one_blas_thread():
            for b in np.unique(blk):
                rows = blk == b
                for j in range(n_ch):
                    sel = aug[rows & keep[:, j], j, :]
                    if sel.shape[0]:
                        self._f[b][j] = _qr_rows(np.vstack([self._f[b][j], sel]))

    def build(self) -> BlockSums:
        kept = [b for b in range(self.n_blocks) if any(f.shape[0] for f in self._f[b])]
        return BlockSums(names=self.names, channel_names=self.channel_names,
                         factors=tuple(tuple(f.copy() for f in self._f[b]) for b in kept),
                         index=np.array(kept, dtype=np.int64), n_blocks=self.n_blocks,
                         samples_per_block=self._pos / self.n_blocks)


def _inv_sqrt_complement(H: FloatArray, tol: float = 1e-10) -> FloatArray:
    """:math:`(I - H)^{-1/2}` of a symmetric ``H`` with eigenvalues in [0, 1] (pseudo-inverse where 1)."""
    lam, V = np.linalg.eigh(H)
    d = 1.0 - lam
    s = np.where(d > tol, 1.0 / np.sqrt(np.clip(d, tol, None)), 0.0)
    return (V * s) @ V.T


def block_covariance(blocks: BlockSums, weights: FloatArray, *, kind: str = "hac", lags: int = 1,
                     replicates: int = 500, seed: int = 0) -> tuple[FloatArray, FloatArray, dict]:
    """The estimate and its block-robust covariance from the block sums (module docstring).

    Parameters
    ----------
    blocks : BlockSums
    weights : array (n_ch,)
        Channel weights of the fit (ones for OLS).
    kind : {"hac", "block_bootstrap"}
    lags : int
        Neighbouring blocks in the Bartlett kernel (``hac``).
    replicates, seed : int
        Bootstrap replicates and the seed of their draws (``block_bootstrap``).

    Returns
    -------
    beta : array (p,)
        The weighted least-squares estimate from the blocks (equals the fit of the whole problem).
    cov : array (p, p)
    info : dict
        What was computed (for the result's ``solver["covariance"]``).
    """
    if kind not in ("hac", "block_bootstrap"):
        raise InputError(f"block covariance kind must be 'hac' or 'block_bootstrap', got {kind!r}")
    if lags < 0 or replicates < 2:
        raise InputError(f"lags must be >= 0 and replicates >= 2, got {lags} and {replicates}")
    p = len(blocks.names)
    F = blocks.whitened(weights)
    Ab = np.array([f[:, :p].T @ f[:, :p] for f in F])
    cb = np.array([f[:, :p].T @ f[:, p] for f in F])
    with _one_blas_thread():  # the estimate by QR, as the whole problem's
        Rall = _qr_rows(np.vstack(F))
    d = np.abs(np.diag(Rall[:p, :p])) if Rall.shape[0] >= p else np.zeros(1)
    if not d.min() > 1e-13 * d.max():
        raise IdentifiabilityError("the blocks do not determine every parameter (singular regressor)", blocks.names)
    beta = sla.solve_triangular(Rall[:p, :p], Rall[:p, p])
    Rinv = sla.solve_triangular(Rall[:p, :p], np.eye(p))
    Ainv = Rinv @ Rinv.T
    B = len(F)
    info: dict = {"kind": kind, "blocks": int(B), "blocks_cut": blocks.n_blocks,
                  "samples_per_block": float(blocks.samples_per_block)}
    if kind == "hac":
        g = np.empty((B, p))
        for b, f in enumerate(F):
            R, u = f[:, :p], f[:, p] - f[:, :p] @ beta
            T = R @ Rinv  # H_b = R A^-1 R^T = T T^T
            g[b] = R.T @ (_inv_sqrt_complement(T @ T.T) @ u)
        cov = _bartlett_sandwich(g, blocks.index, blocks.n_blocks, lags, Rinv)
        info.update(lags=int(lags), kernel="Bartlett (Newey-West) over neighbouring blocks",
                    leverage="CR2 (Bell-McCaffrey)", adjacent_score_correlation=_adjacent_correlation(g, blocks.index, Ainv))
    else:
        rng = np.random.default_rng(seed)
        est = np.empty((replicates, p))
        Af, cf = Ab.reshape(B, -1), cb
        for k0 in range(0, replicates, 64):
            k1 = min(replicates, k0 + 64)
            counts = np.stack([np.bincount(rng.integers(0, B, B), minlength=B) for _ in range(k0, k1)]).astype(float)
            As, cs = (counts @ Af).reshape(-1, p, p), counts @ cf
            try:
                est[k0:k1] = np.linalg.solve(As, cs[:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                raise IdentifiabilityError("a block-bootstrap replicate does not determine every parameter: use "
                                           "fewer, longer blocks (identification.covariance_blocks)",
                                           blocks.names) from None
        cov = np.cov(est, rowvar=False, ddof=1).reshape(p, p)
        info.update(replicates=int(replicates), seed=int(seed), scheme="non-overlapping blocks drawn with replacement")
    cov = 0.5 * (cov + cov.T)
    return beta, cov, info


def _bartlett_sandwich(g: FloatArray, index: np.ndarray, n_blocks: int, lags: int, Rinv: FloatArray) -> FloatArray:
    """:math:`A^{-1} M A^{-1}` as a Gram matrix, so that it is positive semi-definite in floating
    point too: with :math:`S_t = \\sum_{s=t}^{t+L} \\tilde g_s` (empty blocks count as zero),
    :math:`M = \\frac{1}{L+1}\\sum_t S_t S_t^T` is exactly the Bartlett-weighted sum of the module
    docstring (Newey & West 1987, proof of Theorem 1), and the covariance is :math:`U^T U` with the
    rows :math:`A^{-1} S_t / \\sqrt{L+1}`."""
    full = np.zeros((n_blocks + 2 * lags, g.shape[1]))
    full[lags + index] = g
    c = np.cumsum(np.vstack([np.zeros((1, g.shape[1])), full]), axis=0)
    S = c[lags + 1:] - c[: -(lags + 1)]  # window sums of L + 1 neighbouring blocks, every window that meets a block
    U = (S @ Rinv) @ Rinv.T / np.sqrt(lags + 1.0)  # rows A^-1 S_t (A^-1 = Rinv Rinv^T)
    return U.T @ U


def _adjacent_correlation(g: FloatArray, idx: np.ndarray, Ainv: FloatArray) -> float | None:
    """Correlation of the scores of adjacent blocks, in the metric of the estimate
    (:math:`\\sum_b g_b^T A^{-2} g_{b+1} / \\sum_b g_b^T A^{-2} g_b`): near 0 when the blocks are
    longer than the residual correlation."""
    h = g @ Ainv  # the scores as parameter shifts
    nxt = {int(i): k for k, i in enumerate(idx)}
    pairs = [(k, nxt[int(i) + 1]) for k, i in enumerate(idx) if int(i) + 1 in nxt]
    den = float(np.sum(h * h))
    if not pairs or den <= 0:
        return None
    a, c = np.array(pairs).T
    return float(np.sum(h[a] * h[c]) / den)


def robust_result(result: IdentificationResult, blocks: BlockSums, *, kind: str, lags: int = 1,
                  replicates: int = 500, seed: int = 0) -> IdentificationResult:
    """``result`` (OLS or WLS) with its covariance replaced by the block-robust one of ``kind``.

    The estimate is recomputed from the blocks as a check of the compression (it must equal the
    result's to rounding). ``solver["covariance"]`` says what was computed; a note says which
    covariance the intervals use and how it compares with the least-squares one.
    """
    if kind == "model":
        return result
    if result.method not in METHODS:
        raise InputError(f"block covariances are for methods {', '.join(METHODS)} (fixed channel weights), "
                         f"not {result.method}")
    if tuple(result.names) != blocks.names or tuple(result.channel_names) != blocks.channel_names:
        raise InputError("the blocks were built for other parameters or channels than the result's")
    w = np.ones(len(blocks.channel_names)) if result.method == "OLS" else 1.0 / np.asarray(result.noise_std) ** 2
    beta, cov, info = block_covariance(blocks, w, kind=kind, lags=lags, replicates=replicates, seed=seed)
    scale = np.maximum(np.abs(result.params), 1e-300)
    dev = float(np.max(np.abs(beta - result.params) / np.maximum(scale, np.sqrt(np.diag(result.cov_params)))))
    if not dev < 1e-6:
        raise InputError(f"the block sums do not reproduce the estimate (relative deviation {dev:.3g})")
    ratio = np.sqrt(np.clip(np.diag(cov), 0, None)) / np.sqrt(np.clip(np.diag(result.cov_params), 1e-300, None))
    info.update(model_std_ratio_median=float(np.median(ratio)), model_std_ratio_max=float(np.max(ratio)))
    p = len(result.names)
    what = {"hac": f"block-robust sandwich (HAC, CR2, Bartlett over {lags} neighbouring blocks)",
            "block_bootstrap": f"block bootstrap ({replicates} replicates, seed {seed})"}[kind]
    note = (f"covariance: {what} over {info['blocks']} blocks of {info['samples_per_block']:.4g} samples; "
            f"std / least-squares std: median {info['model_std_ratio_median']:.3g}, max {info['model_std_ratio_max']:.3g}")
    notes = [note]
    if info["blocks"] <= p:
        notes.append(f"covariance from {info['blocks']} blocks for {p} parameters is singular: no confidence "
                     "ellipsoid (more blocks, identification.covariance_blocks)")
    rho = info.get("adjacent_score_correlation")
    if rho is not None and abs(rho) > 0.3 and lags == 0:
        notes.append(f"scores of adjacent blocks correlate ({rho:.2f}): blocks shorter than the residual "
                     "correlation; use covariance_lags >= 1 or fewer, longer blocks")
    solver = {**result.solver, "covariance": info}
    return dataclasses.replace(result, cov_params=cov, solver=solver, notes=result.notes + tuple(notes))
