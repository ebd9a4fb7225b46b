"""Composition: configuration -> objects -> results (identify, demo)."""

from dynid.pipeline.data import build_robot, preprocess, read_log, to_joint_space
from dynid.estimation.validation import ValidationMetrics
from dynid.pipeline.identification import identify
from dynid.pipeline.outcome import IdentifyOutcome
from dynid.pipeline.outputs import write_outputs
from dynid.pipeline.rows import build_problem
from dynid.pipeline.validation import validate

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
