"""Estimators (``fit(problem) -> IdentificationResult``) and the compressed problem."""

from __future__ import annotations

from typing import Any

from dynid.errors import ConfigError
from dynid.estimation.generalized import IRLS, TLS, GaussMarkov, gls_solve, residual_covariance
from dynid.estimation.identifiability import (
    Feasibility,
    ModelSequence,
    ModelStep,
    RankedStructure,
    StructureRanking,
    essential_parameters,
    identified,
    identified_names,
    is_feasible,
    select_friction_structure,
    structure_search,
)
from dynid.estimation.linear import OLS, WLS, check_identifiable, whitened_solve
from dynid.estimation.nonlinear import SampleProblem, StribeckLS, stribeck_basis, stribeck_predict
from dynid.estimation.physical import BodyBounds, PhysicalConstraints, PhysicalLS, logdet_divergence
from dynid.estimation.problem import ProblemBuilder, RegressionProblem
from dynid.estimation.results import IdentificationResult, Summary

METHODS = ("ols", "wls", "gm", "irls", "tls")
"""Linear estimators selectable by name (``[identification] method``)."""


def make_estimator(method: str, physical_consistency: bool = False, *, noise_covariance: Any = None,
                   nominal: Any = None, iterations: int = 1, physical: dict | None = None) -> Any:
    """The estimator named ``method`` with its options (the configuration's choices).

    ``noise_covariance`` (n_ch x n_ch) is for ``"gm"`` (None: estimated from residuals);
    ``nominal`` (p,) weights the observation matrix for ``"wls"`` (paper 001 Eq. 17);
    ``iterations`` are GM's residual-covariance rounds; ``physical`` holds the options of
    :class:`PhysicalLS` (constraints, regularization, reference, solver) with
    ``physical_consistency``. Options that do not apply to the method raise instead of being
    ignored.
    """
    if physical and not physical_consistency:
        raise ConfigError("constraints and regularization need physical_consistency = true")
    if method not in METHODS:
        raise ConfigError(f"unknown identification method {method!r} (expected one of {', '.join(METHODS)})")
    if noise_covariance is not None and method != "gm":
        raise ConfigError(f"a noise covariance is for method 'gm', not {method!r}")
    if nominal is not None and method != "wls":
        raise ConfigError(f"weighting by nominal values is for method 'wls', not {method!r}")
    if physical_consistency:
        if method not in ("ols", "wls", "gm") or nominal is not None:
            raise ConfigError(f"physical_consistency = true is available with methods 'ols', 'wls' and 'gm', not {method!r}"
                              + (" with nominal weighting" if nominal is not None else ""))
        cov = None if noise_covariance is None else tuple(tuple(float(v) for v in row) for row in noise_covariance)
        return PhysicalLS(weighting=method, noise_covariance=cov, **(physical or {}))
    if method == "ols":
        return OLS()
    if method == "wls":
        return WLS(nominal=None if nominal is None else tuple(float(v) for v in nominal))
    if method == "gm":
        cov = None if noise_covariance is None else tuple(tuple(float(v) for v in row) for row in noise_covariance)
        return GaussMarkov(noise_covariance=cov, iterations=iterations)
    if method == "irls":
        return IRLS()
    return TLS()


__all__ = [
    "Feasibility",
    "ModelSequence",
    "ModelStep",
    "RankedStructure",
    "StructureRanking",
    "essential_parameters",
    "identified",
    "identified_names",
    "is_feasible",
    "SampleProblem",
    "StribeckLS",
    "stribeck_basis",
    "stribeck_predict",
    "select_friction_structure",
    "structure_search",
    "IRLS",
    "METHODS",
    "OLS",
    "TLS",
    "WLS",
    "GaussMarkov",
    "IdentificationResult",
    "BodyBounds",
    "PhysicalConstraints",
    "PhysicalLS",
    "logdet_divergence",
    "ProblemBuilder",
    "RegressionProblem",
    "Summary",
    "check_identifiable",
    "gls_solve",
    "make_estimator",
    "residual_covariance",
    "whitened_solve",
]
