"""Virtual experiments: trajectories and simulated measurements with known ground truth."""

from dynid.simulation.measurements import simulate_serial
from dynid.simulation.paths import (
    BidirectionalVelocity,
    CirclePath,
    FourierQuintic,
    PolylinePath,
    Repeated,
    zyx_angular_velocity,
)
from dynid.simulation.trajectories import FourierTrajectory

__all__ = [
    "BidirectionalVelocity",
    "CirclePath",
    "FourierQuintic",
    "FourierTrajectory",
    "PolylinePath",
    "Repeated",
    "simulate_serial",
    "zyx_angular_velocity",
]
