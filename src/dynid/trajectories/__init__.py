"""Trajectories with analytic position, velocity and acceleration (a time function and its
derivatives; no robot model): Fourier series, Fourier + quintic, constant-velocity segments,
circles and polylines, periodic repetition. Used by excitation design and virtual experiments."""

from dynid.trajectories.constant_velocity import ConstantVelocityExperiment
from dynid.trajectories.fourier import FourierTrajectory
from dynid.trajectories.paths import (
    BidirectionalVelocity,
    CirclePath,
    Embedded,
    FourierQuintic,
    PolylinePath,
    Repeated,
    zyx_angular_velocity,
)

__all__ = [
    "BidirectionalVelocity",
    "CirclePath",
    "ConstantVelocityExperiment",
    "Embedded",
    "FourierQuintic",
    "FourierTrajectory",
    "PolylinePath",
    "Repeated",
    "zyx_angular_velocity",
]
