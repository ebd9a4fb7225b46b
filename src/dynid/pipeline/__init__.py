"""Composition: configuration -> objects -> results (identify, demo)."""

from dynid.pipeline.data import build_robot, preprocess, read_log, to_joint_space
from dynid.pipeline.identification import IdentifyOutcome, ValidationMetrics, build_problem, identify, validate, write_outputs

__all__ = [
    "IdentifyOutcome",
    "ValidationMetrics",
    "build_problem",
    "build_robot",
    "identify",
    "preprocess",
    "read_log",
    "to_joint_space",
    "validate",
    "write_outputs",
]
