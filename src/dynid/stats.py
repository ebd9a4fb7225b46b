"""Small statistics helpers on arrays (pure NumPy/SciPy)."""

from __future__ import annotations

import numpy as np
from scipy import stats as _st

from dynid._typing import FloatArray

__all__ = ["t_quantile", "condition_number", "relative_std", "rmse"]


def t_quantile(alpha: float, dof: int) -> float:
    """Two-sided Student-t quantile ``t_{1-alpha/2}(dof)`` (normal when dof is huge)."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    return float(_st.t.ppf(1 - alpha / 2, max(int(dof), 1)))


def condition_number(a: FloatArray) -> float:
    """2-norm condition number (ratio of extreme singular values); inf when singular."""
    s = np.linalg.svd(np.asarray(a, dtype=float), compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def relative_std(values: FloatArray, std: FloatArray) -> FloatArray:
    """Relative standard deviation in percent, ``100 * std / |value|`` (inf for zero values)."""
    values = np.abs(np.asarray(values, dtype=float))
    std = np.asarray(std, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * std / values
    return np.where(values == 0, np.inf, out)


def rmse(residuals: FloatArray) -> FloatArray:
    """Root-mean-square over axis 0."""
    r = np.asarray(residuals, dtype=float)
    return np.sqrt(np.mean(r**2, axis=0))
