"""Virtual experiments on serial robots: torques from inverse dynamics plus sensor noise."""

from __future__ import annotations

import numpy as np

from dynid._typing import FloatArray
from dynid.dataset import Dataset
from dynid.model.serial_dynamics import inverse_dynamics
from dynid.model.robot import RobotModel
from dynid.trajectories import FourierTrajectory

__all__ = ["simulate_serial"]


def simulate_serial(
    robot: RobotModel,
    params: FloatArray,
    trajectory: FourierTrajectory,
    *,
    fs: float,
    duration: float,
    torque_noise_std: FloatArray | float,
    position_noise_std: float = 0.0,
    rng: np.random.Generator,
) -> Dataset:
    """Measurements along a commanded trajectory tracked perfectly.

    Torques are the inverse dynamics (pinocchio RNEA + extras) of the true
    ``params`` along the trajectory, plus white Gaussian noise of standard deviation
    ``torque_noise_std`` per joint [N·m]; positions get ``position_noise_std`` [rad].
    The true parameters and the trajectory are recorded in ``meta``.
    """
    t = np.arange(int(round(duration * fs))) / fs
    q, dq, ddq = trajectory.sample(t)
    tau = inverse_dynamics(robot, params, q, dq, ddq)
    sigma = np.broadcast_to(np.asarray(torque_noise_std, dtype=float), (robot.dof,))
    tau_meas = tau + rng.standard_normal(tau.shape) * sigma
    q_meas = q + rng.standard_normal(q.shape) * position_noise_std
    return Dataset(
        t=t,
        q=q_meas,
        tau=tau_meas,
        names=robot.joint_names,
        meta={
            "position_side": "joint",
            "effort_kind": "torque",
            "effort_side": "joint",
            "source": "simulation",
            "true_params": np.asarray(params, float).tolist(),
            "torque_noise_std": sigma.tolist(),
            "position_noise_std": float(position_noise_std),
            "trajectory": {
                "base_frequency_hz": trajectory.base_frequency_hz,
                "a": trajectory.a.tolist(),
                "b": trajectory.b.tolist(),
                "q0": trajectory.q0.tolist(),
            },
        },
    )
