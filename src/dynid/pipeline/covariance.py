"""The ``[identification] covariance`` setting in ``dynid identify``: the per-block compression
next to the problem's, in the same pass over the chunks, and the block-robust covariance of the
fit (:mod:`dynid.estimation.block_covariance`)."""

from __future__ import annotations

from collections.abc import Sequence

from dynid.config import CovarianceConfig
from dynid.errors import ConfigError
from dynid.estimation.block_covariance import BlockBuilder, default_blocks, robust_result
from dynid.estimation.results import IdentificationResult

__all__ = ["block_builder", "with_covariance"]


def block_builder(cfg: CovarianceConfig, names: Sequence[str], channels: Sequence[str],
                  n_samples: int) -> BlockBuilder | None:
    """Working memory for the blocks of ``n_samples`` processed samples (None: ``covariance = "model"``)."""
    if cfg.kind == "model":
        return None
    blocks = default_blocks(len(names), n_samples) if cfg.blocks is None else cfg.blocks
    if blocks > n_samples or blocks < 2:
        raise ConfigError(f"identification.covariance_blocks = {blocks}: the training data have {n_samples} processed "
                          "samples; give between 2 and that many blocks")
    return BlockBuilder(names, channels, blocks, n_samples)


def with_covariance(result: IdentificationResult, builder: BlockBuilder | None,
                    cfg: CovarianceConfig) -> IdentificationResult:
    """``result`` with the covariance of ``cfg`` (unchanged for ``"model"``)."""
    if builder is None:
        return result
    return robust_result(result, builder.build(), kind=cfg.kind, lags=cfg.lags, replicates=cfg.replicates,
                         seed=cfg.seed)
