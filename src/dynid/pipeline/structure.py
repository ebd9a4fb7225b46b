"""Identical chains tied or not, decided from the training log: ``identification.structure = "auto"``.

A parallel robot whose legs are identical in its description can be identified with one set of
parameters per leg body (:mod:`dynid.model.reduction`, structure ``identical_chains``) or with
every body its own (``full``). The tied model has fewer parameters, so it is better determined,
but it is wrong where the real legs differ. ``auto`` (the default for parallel robots) fits both
and keeps the tied model unless the data say it is wrong:

1. **Nested-model F test** on the training data. The tied model is the full model restricted
   (its base regressor is :math:`Y T`, inside the column space of :math:`Y`). With both fitted by
   weighted least squares at the same per-channel weights :math:`w_j = 1/\\hat\\sigma_j^2`
   (:math:`\\hat\\sigma_j` from the full model's OLS residuals, as WLS takes them, paper 001 Eq. 13),

   .. math::

      F = \\frac{(RSS_t - RSS_f) / (p_f - p_t)}{RSS_f / (n - p_f)} \\sim F(p_f - p_t,\\; n - p_f)

   under the tied model with Gaussian, independent errors; the test rejects the tie at level
   :data:`ALPHA` (1 %). The BIC of both, :math:`n \\ln(RSS/n) + p \\ln n`, is reported beside it.
2. **Cross-validation over time segments**: the training log cut into :data:`N_SEGMENTS`
   contiguous segments; each is held out in turn, both models fitted (the same weights) on the
   others, and the held-out weighted RMSE :math:`\\sqrt{\\sum_j w_j RSS_j / n_k}` averaged.

**Rule**: the tied model is chosen unless the F test rejects it **and** cross-validation prefers
the full model (lower mean held-out RMSE). The F test alone is too eager on real logs (filtered,
correlated residuals inflate F); cross-validation alone is noisy on short logs; a tie that both
reject is wrong for these data.

The test and the cross-validation never compute a regressor twice: the log is compressed once
per segment in the full model's base parameters (per-channel QR factors,
:class:`~dynid.estimation.problem.RegressionProblem`), and the tied model's factors follow from
them exactly: with :math:`Y = Y_b B_f` (the full model's base map) the tied base regressor is
:math:`Y T_{[:, I_t]} = Y_b\\,(B_f T_{[:, I_t]})`, a linear map of the full base columns.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats

from dynid._typing import FloatArray
from dynid.estimation.problem import RegressionProblem
from dynid.model.base_parameters import BaseParameters
from dynid.model.reduction import CHAIN_TOL, chain_groups, detect_identical_chains

__all__ = ["ALPHA", "N_SEGMENTS", "StructureDecision", "candidate_chains", "decide_structure", "tied_factors"]

ALPHA = 0.01
"""Significance level of the F test that rejects the tied model (a 1 % false rejection when the legs are identical)."""

N_SEGMENTS = 5
"""Contiguous time segments of the training log in the cross-validation."""

_RCOND = 1e-10  # singular values of the column-scaled, whitened regressor below this (relative) count as rank loss

RULE = ("identical_chains unless the F test rejects it at the 1 % level and the cross-validation over time segments "
        "prefers the full model")


@dataclasses.dataclass(frozen=True)
class StructureDecision:
    """The structure chosen and its evidence (``record``: result.json ``"structure"``)."""

    chosen: str
    chains: tuple
    record: dict[str, Any]


def candidate_chains(mech, chains: Any) -> tuple[tuple, str]:
    """The groups of identical chains ``auto`` may tie, and where they come from: named in the
    config, declared by the description (a built-in's symmetry), or found in it
    (:func:`~dynid.model.reduction.detect_identical_chains`); empty when none."""
    if chains:
        return chain_groups(chains), "named in identification.identical_chains"
    if mech.identical_chains:
        return tuple(mech.identical_chains), "declared by the robot description"
    return detect_identical_chains(mech), (f"found in the robot description (same joint types, axes, placements and "
                                           f"bodies in their own frames to {CHAIN_TOL:g})")


def _triangular(A: FloatArray, k: int) -> FloatArray:
    """The (k, k) upper-triangular factor of the rows ``A`` (zero-padded when A has fewer rows)."""
    r = np.linalg.qr(A, mode="r")
    out = np.zeros((k, k))
    out[: r.shape[0]] = r[:k]
    return out


def _merge(factors: Sequence[FloatArray]) -> FloatArray:
    """Per-channel augmented factors of the union of several problems' rows."""
    F = np.concatenate(factors, axis=1)
    k = F.shape[2]
    return np.stack([_triangular(F[j], k) for j in range(F.shape[0])])


def tied_factors(factors: FloatArray, M: FloatArray) -> FloatArray:
    """The augmented factors ``[R_j M | z_j; 0 | rho_j]`` re-triangularized: the problem in the
    parameters ``beta_t`` with ``beta = M beta_t`` (module docstring)."""
    p = M.shape[0]
    E = np.zeros((p + 1, M.shape[1] + 1))
    E[:p, :-1] = M
    E[p, -1] = 1.0
    return np.stack([_triangular(F @ E, M.shape[1] + 1) for F in factors])


def _wls(factors: FloatArray, w: FloatArray) -> tuple[FloatArray, int]:
    """Weighted least squares on augmented factors: minimum-norm estimate (columns scaled to unit
    norm) and the numerical rank."""
    p = factors.shape[2] - 1
    sw = np.sqrt(w)[:, None, None]
    A = (sw * factors[:, :, :p]).reshape(-1, p)
    b = (sw[:, :, 0] * factors[:, :, p]).reshape(-1)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    x, _, rank, _ = np.linalg.lstsq(A / scale, b, rcond=_RCOND)
    return x / scale, int(rank)


def _rss(factors: FloatArray, beta: FloatArray) -> FloatArray:
    """Per-channel residual sum of squares ``||y_j - W_j beta||^2`` from augmented factors."""
    p = factors.shape[2] - 1
    r = factors[:, :, :p] @ beta - factors[:, :, p]
    return np.sum(r**2, axis=1)


def decide_structure(segments: Sequence[RegressionProblem], base_full: BaseParameters, base_tied: BaseParameters,
                     T: FloatArray, chains: tuple, source: str, *, alpha: float = ALPHA) -> StructureDecision:
    """Choose ``"full"`` or ``"identical_chains"`` (module docstring).

    Parameters
    ----------
    segments : sequence of RegressionProblem
        The training log's contiguous segments, each compressed in the full model's base
        parameters (all with the same columns and channels); fewer than two with equations (a
        row selection may keep none of a segment): no cross-validation (the rule then rests on
        the F test alone, and says so).
    base_full, base_tied : BaseParameters
        Base parameters of the full model and of the tied one (the latter over :math:`\\psi`).
    T : array (p, p_psi)
        The reduction :math:`\\pi = T\\psi` (:class:`~dynid.model.reduction.ParameterReduction`).
    chains, source
        The tied groups and where they come from (recorded).
    alpha : float
        Level of the F test.
    """
    M = base_full.B @ T[:, base_tied.independent]  # full base -> tied base columns (module docstring)
    seg_f = [np.asarray(s.factors) for s in segments]
    seg_t = [tied_factors(f, M) for f in seg_f]
    n_seg = np.array([int(s.n_total) for s in segments])
    n_obs = np.sum([s.n_obs for s in segments], axis=0)
    all_f, all_t = _merge(seg_f), _merge(seg_t)
    n = int(n_obs.sum())
    # weights: the full model's OLS residual variance per channel (WLS's, paper 001 Eq. 13)
    beta_ols, p_f = _wls(all_f, np.ones(len(n_obs)))
    sigma2 = _rss(all_f, beta_ols) / np.maximum(n_obs - p_f * n_obs / n, 1.0)
    w = 1.0 / np.maximum(sigma2, np.finfo(float).tiny)
    beta_f, p_f = _wls(all_f, w)
    beta_t, p_t = _wls(all_t, w)
    rss_f, rss_t = float(w @ _rss(all_f, beta_f)), float(w @ _rss(all_t, beta_t))
    df1, df2 = p_f - p_t, n - p_f
    if df1 > 0 and df2 > 0 and rss_f > 0:
        F = max(rss_t - rss_f, 0.0) / df1 / (rss_f / df2)
        p_value = float(stats.f.sf(F, df1, df2))
    else:  # the tie removes nothing these data determine: nothing to test
        F, p_value = None, 1.0
    bic = {name: float(n * np.log(rss / n) + p * np.log(n))
           for name, rss, p in (("full", rss_f, p_f), ("identical_chains", rss_t, p_t))}
    cv: dict[str, Any] | None = None
    held = [k for k in range(len(segments)) if n_seg[k] > 0]  # a row selection may keep nothing of a segment
    if len(held) >= 2:
        per = {"full": [], "identical_chains": []}
        for k in held:
            rest = [i for i in range(len(segments)) if i != k]
            for name, seg in (("full", seg_f), ("identical_chains", seg_t)):
                beta, _ = _wls(_merge([seg[i] for i in rest]), w)
                per[name].append(float(np.sqrt(w @ _rss(seg[k], beta) / max(n_seg[k], 1))))
        cv = {"segments": len(held), "full": float(np.mean(per["full"])),
              "identical_chains": float(np.mean(per["identical_chains"])), "per_segment": per}
    rejected = p_value < alpha
    cv_prefers_full = cv is None or cv["full"] < cv["identical_chains"]
    chosen = "full" if rejected and cv_prefers_full else "identical_chains"
    record = {
        "mode": "auto",
        "chosen": chosen,
        "chains": [[list(c) for c in g] for g in chains],
        "chains_source": source,
        "rule": RULE + ("" if cv is not None else " (fewer than two segments with equations: no cross-validation, "
                                                  "the F test alone)"),
        "n_base_params": {"full": base_full.n_base, "identical_chains": base_tied.n_base},
        "rank": {"full": p_f, "identical_chains": p_t},
        "n_equations": n,
        "F": None if F is None else float(F),
        "df": [int(df1), int(df2)],
        "p_value": p_value,
        "alpha": alpha,
        "rejected": bool(rejected),
        "bic": bic,
        "cv": cv,
        "weights": "1/sigma_j^2 per channel, sigma_j from the full model's OLS residuals on the whole training log",
    }
    return StructureDecision(chosen, chains if chosen == "identical_chains" else (), record)
