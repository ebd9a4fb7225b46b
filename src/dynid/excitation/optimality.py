"""Excitation criteria on the (base) observation matrix: condition numbers and D-, A-, E-optimality.

With the stacked base regressor :math:`\\Psi` (rows: samples x output channels), output noise
standard deviations :math:`\\sigma_j` per channel (:math:`\\Sigma = \\mathrm{diag}(\\sigma^2)`)
and the information matrix :math:`M = \\Psi^T\\Sigma^{-1}\\Psi`:

=================  =================================================================  ===================
name               value (smaller is better)                                          source
=================  =================================================================  ===================
``cond``           :math:`\\kappa(\\Psi)`                                               Gautier, paper 001
``weighted_cond``  :math:`\\kappa(\\Sigma^{-1/2}\\Psi\\,\\mathrm{diag}(|\\bar\\beta|))`       paper 001, Eq. 17
``d_opt``          :math:`-\\ln\\det(M + \\epsilon I)`                                     papers 002 Eq. 26, 004 Eq. 22
``a_opt``          :math:`\\ln\\operatorname{tr}((M + \\epsilon I)^{-1})`                 paper 003 (sum of variances)
``e_opt``          :math:`-\\ln\\lambda_{min}(M + \\epsilon I)`                           E-optimality
=================  =================================================================  ===================

:math:`\\epsilon = 10^{-10}\\,\\mathrm{tr}(M)/p` keeps the logarithmic criteria finite for a
rank-deficient design (peers report "cond = inf" and ``-log det`` of singular matrices); the
condition numbers are capped at 1e16. ``a_opt`` and ``e_opt`` are taken in logarithms so that
all criteria have comparable scales for the optimizer; the reports give them as such.
The predicted covariance of the estimates of an experiment of ``r`` repetitions of the design
is :math:`M^{-1}/r`.
"""

from __future__ import annotations

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["CRITERIA", "criteria", "information_matrix", "predicted_std"]

CRITERIA = ("cond", "weighted_cond", "d_opt", "a_opt", "e_opt")
_CAP = 1e16


def information_matrix(W: FloatArray, noise_std: FloatArray) -> FloatArray:
    """:math:`\\Psi^T\\Sigma^{-1}\\Psi` of a regressor stack ``W`` (n, n_out, p)."""
    s = np.asarray(noise_std, dtype=float)
    Wn = W / s[None, :, None]
    flat = Wn.reshape(-1, W.shape[-1])
    return flat.T @ flat


def criteria(W: FloatArray, noise_std: FloatArray, nominal: FloatArray | None = None) -> dict[str, float]:
    """All criteria of the module docstring for the regressor stack ``W`` (n, n_out, p)."""
    p = W.shape[-1]
    s = np.asarray(noise_std, dtype=float)
    if s.shape != (W.shape[1],) or np.any(s <= 0):
        raise InputError(f"noise standard deviations must be {W.shape[1]} positive numbers")
    flat = W.reshape(-1, p)
    sv = np.linalg.svd(flat, compute_uv=False)
    cond = float(min(sv[0] / sv[-1], _CAP)) if sv[-1] > 0 else _CAP
    Wn = (W / s[None, :, None]).reshape(-1, p)
    scale = np.abs(np.asarray(nominal, dtype=float)) if nominal is not None else np.ones(p)
    # parameters whose nominal value is zero (or negligible) get 1 % of the median magnitude
    floor = 1e-2 * np.median(scale[scale > 0]) if np.any(scale > 0) else 1.0
    scale = np.maximum(scale, floor)
    svw = np.linalg.svd(Wn * scale[None, :], compute_uv=False)
    wcond = float(min(svw[0] / svw[-1], _CAP)) if svw[-1] > 0 else _CAP
    M = Wn.T @ Wn
    eps = 1e-10 * np.trace(M) / p if np.trace(M) > 0 else 1e-300
    ev = np.clip(np.linalg.eigvalsh(M + eps * np.eye(p)), eps, None)
    return {
        "cond": cond,
        "weighted_cond": wcond,
        "d_opt": float(-np.sum(np.log(ev))),
        "a_opt": float(np.log(np.sum(1.0 / ev))),
        "e_opt": float(-np.log(ev[0])),
    }


def predicted_std(W: FloatArray, noise_std: FloatArray, repetitions: float = 1.0) -> FloatArray:
    """Predicted standard deviations of the base parameters estimated from ``repetitions``
    repetitions of the design (weighted least squares with the given noise)."""
    M = information_matrix(W, noise_std) * repetitions
    lam, V = np.linalg.eigh(M)
    if lam[-1] <= 0:
        return np.full(M.shape[0], np.inf)
    # diag(M^-1) from the eigen-decomposition: never negative; an unexcited direction -> inf
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(lam > 1e-14 * lam[-1], 1.0 / lam, np.inf)
        var = np.where(V**2 > 0, V**2, 0.0) @ np.where(np.isfinite(inv), inv, 0.0)
        lost = (V**2 > 1e-24) @ ~np.isfinite(inv)  # parameters that touch an unexcited direction
    return np.where(lost > 0, np.inf, np.sqrt(var))
