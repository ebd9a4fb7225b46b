"""Robot models, parameters, regressors and base parameters (pinocchio lives here)."""

from dynid.model.base_parameters import (
    BaseParameters,
    StandardMap,
    compute_base_parameters,
    pseudo_inertia,
    robot_base_parameters,
)
from dynid.model.loading import load_model, load_robot
from dynid.model.serial_dynamics import extras_torque, inverse_dynamics, regressor
from dynid.model.robot import BODY_PARAMS, JOINT_EXTRAS, ParameterLayout, RobotModel
from dynid.model.transmission import Coupling, Transmission

__all__ = [
    "BODY_PARAMS",
    "JOINT_EXTRAS",
    "BaseParameters",
    "Coupling",
    "StandardMap",
    "pseudo_inertia",
    "ParameterLayout",
    "RobotModel",
    "Transmission",
    "compute_base_parameters",
    "extras_torque",
    "inverse_dynamics",
    "load_model",
    "load_robot",
    "regressor",
    "robot_base_parameters",
]
