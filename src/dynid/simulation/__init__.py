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
from dynid.simulation.sensors import Measurements, Sensors
from dynid.simulation.trajectories import FourierTrajectory

__all__ = [
    "BidirectionalVelocity",
    "CirclePath",
    "FourierQuintic",
    "FourierTrajectory",
    "Measurements",
    "PolylinePath",
    "Repeated",
    "Sensors",
    "simulate_serial",
    "zyx_angular_velocity",
]
