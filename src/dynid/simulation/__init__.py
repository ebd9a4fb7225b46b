"""Virtual experiments: plants, controllers, sensors and simulated measurements with known
ground truth (the trajectories they follow are in :mod:`dynid.trajectories`)."""

from dynid.simulation.measurements import simulate_serial
from dynid.simulation.sensors import Measurements, Sensors
from dynid.trajectories import FourierTrajectory

__all__ = ["FourierTrajectory", "Measurements", "Sensors", "simulate_serial"]
