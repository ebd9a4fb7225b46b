"""Excitation design: criteria and optimal periodic trajectories under limits."""

from dynid.excitation.optimality import CRITERIA, criteria, predicted_std
from dynid.excitation.design import DesignError, DesignLimits, ExcitationDesign, ExcitationProblem, Violation

__all__ = ["CRITERIA", "DesignError", "DesignLimits", "ExcitationDesign", "ExcitationProblem", "Violation", "criteria", "predicted_std"]
