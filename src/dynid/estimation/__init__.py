"""Estimators (``fit(problem) -> IdentificationResult``) and the compressed problem."""

from dynid.estimation.linear import OLS, WLS, check_identifiable, whitened_solve
from dynid.estimation.physical import PhysicalLS
from dynid.estimation.problem import ProblemBuilder, RegressionProblem
from dynid.estimation.results import IdentificationResult, Summary

ESTIMATORS = {
    ("ols", False): OLS,
    ("wls", False): WLS,
    ("ols", True): lambda: PhysicalLS(weighting="ols"),
    ("wls", True): lambda: PhysicalLS(weighting="wls"),
}
"""Estimators by (method, physically consistent) as selected in the configuration."""

__all__ = [
    "ESTIMATORS",
    "OLS",
    "PhysicalLS",
    "WLS",
    "IdentificationResult",
    "ProblemBuilder",
    "RegressionProblem",
    "Summary",
    "check_identifiable",
    "whitened_solve",
]
