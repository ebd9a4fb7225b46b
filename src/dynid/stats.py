"""Small statistics helpers on arrays (pure NumPy/SciPy)."""

from __future__ import annotations

import numpy as np
from scipy import stats as _st

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["t_quantile", "condition_number", "relative_std", "rmse", "tracking_errors"]


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


def tracking_errors(reference: FloatArray, actual: FloatArray) -> dict[str, FloatArray | float]:
    """Tracking metrics of a path, arrays (n, n_axes) [m or rad].

    Returns ``rms_per_axis`` (root mean square error of each axis), ``max_abs_per_axis`` and
    ``p_rsme``: :math:`\\sqrt{\\tfrac1r\\sum_m \\|x_d(m) - x(m)\\|^2}` over all axes, the
    position RSME of Shang et al. 2009, Eq. 23 (there with the x, y of the end-effector).
    """
    ref = np.atleast_2d(np.asarray(reference, dtype=float))
    act = np.atleast_2d(np.asarray(actual, dtype=float))
    if ref.shape != act.shape:
        raise InputError(f"reference {ref.shape} and actual {act.shape} differ in shape")
    e = ref - act
    return {
        "rms_per_axis": np.sqrt(np.mean(e**2, axis=0)),
        "max_abs_per_axis": np.abs(e).max(axis=0),
        "p_rsme": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
    }
