"""Estimators (``fit(problem) -> IdentificationResult``) and the compressed problem."""

from dynid.estimation.linear import OLS, WLS, check_identifiable, whitened_solve
from dynid.estimation.problem import ProblemBuilder, RegressionProblem
from dynid.estimation.results import IdentificationResult, Summary

ESTIMATORS = {"ols": OLS, "wls": WLS}
"""Estimators selectable by name in the configuration."""

__all__ = [
    "ESTIMATORS",
    "OLS",
    "WLS",
    "IdentificationResult",
    "ProblemBuilder",
    "RegressionProblem",
    "Summary",
    "check_identifiable",
    "whitened_solve",
]
