"""Virtual experiments: trajectories and simulated measurements with known ground truth."""

from dynid.simulation.measurements import simulate_serial
from dynid.simulation.trajectories import FourierTrajectory

__all__ = ["FourierTrajectory", "simulate_serial"]
