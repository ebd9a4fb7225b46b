"""truth.json's true base parameters include a simulated payload: they are what an identification of
the log estimates, so the base regressor along the true motion times them gives the logged efforts
(no sensor noise), for a serial arm and for a parallel robot's platform."""

from __future__ import annotations

import numpy as np

from conftest import REPO
from dynid.config.simulate import parse_simulate_config
from dynid.model import regressor, robot_base_parameters
from dynid.model.closed_loop import actuator_regressor, mechanism_base_parameters
from dynid.model.loading import load_model
from dynid.pipeline.simulate import run_simulation

ARM = str(REPO / "examples" / "serial_arm" / "arm3.urdf")
PAYLOAD = {"mass": 1.5, "com": [0.05, 0.0, 0.02], "inertia": [0.002, 0.003, 0.004]}


def test_serial_truth_base_parameters_carry_the_payload(tmp_path):
    cfg = parse_simulate_config(
        {"robot": {"model": ARM, "perturbation": 0.1, "perturbation_seed": 3, "rotor_inertia": [0.05, 0.04, 0.02],
                   "payload": PAYLOAD},
         "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 2, "fill": 0.5, "seed": 2},
         "control": {"rate_hz": 500}, "simulation": {"duration": 1.0}}, tmp_path)
    out = run_simulation(cfg)
    robot = load_model(ARM, rotor_inertia=[0.05, 0.04, 0.02])
    base = robot_base_parameters(robot)
    truth = out.truth["base_parameters"]
    assert truth["names"] == list(base.names) and truth["payload_included"]
    m = out.motion  # the true states; ddq the acceleration under each held torque
    W = base.regressor(regressor(robot, m.q, m.dq, m.ddq))
    tau = np.column_stack([out.columns[f"tau_{j}"] for j in robot.joint_names])
    # the held torque is inverse dynamics of the plant at (q, dq, ddq) exactly: rounding of a sum of
    # terms of the size of the largest torque
    np.testing.assert_allclose(np.einsum("njb,b->nj", W, truth["true_values"]), tau, rtol=0,
                               atol=1e-9 * np.abs(tau).max())
    # the robot alone does not: 1.5 kg at the tip is several N*m on the shoulder
    alone = np.einsum("njb,b->nj", W, truth["true_values_without_payload"])
    assert np.abs(alone - tau)[:, 1].max() > 1.0
    # the standard vector with the payload: the payload's [m, m c, I at the joint origin] on the last body
    std = np.array(out.truth["true_parameters_with_payload"]) - np.array(out.truth["true_parameters"])
    assert std[20] == 1.5 and np.count_nonzero(std) and np.all(std[:20] == 0) and np.all(std[30:] == 0)


def test_parallel_truth_base_parameters_carry_the_payload(tmp_path):
    cfg = parse_simulate_config(
        {"robot": {"model": "builtin:rps3", "perturbation": 0.1, "payload": {**PAYLOAD, "com": [0.0, 0.0, 0.02]}},
         "trajectory": {"kind": "fourier", "base_frequency_hz": 1.0, "harmonics": 2, "fill": 0.1, "seed": 1},
         "control": {"rate_hz": 500}, "simulation": {"duration": 0.2}}, tmp_path)
    out = run_simulation(cfg)
    mech = load_model("builtin:rps3")
    base = mechanism_base_parameters(mech)
    truth = out.truth["base_parameters"]
    m = out.motion
    reg = actuator_regressor(mech, mech.kinematic_state(m.q, m.dq, m.ddq))  # 3 actuators, 3 DOF
    logged = np.column_stack([out.columns[f"tau_{a}"] for a in mech.actuated_names])
    measured = reg.outputs(logged)
    std_with = np.array(out.truth["true_parameters_with_payload"])
    np.testing.assert_allclose(reg.W @ std_with, measured, atol=1e-8 * np.abs(measured).max())
    # the base parameters are a linear map of the standard ones: base.to_standard of the truth's
    # base values gives the same forces as the standard vector with the payload
    np.testing.assert_allclose(reg.W @ base.to_standard(np.array(truth["true_values"])), measured,
                               atol=1e-7 * np.abs(measured).max())
    # the platform alone does not: 1.5 kg weigh about 5 N on each of the three legs, 5000 times the tolerance above
    assert np.abs(reg.W @ base.to_standard(np.array(truth["true_values_without_payload"])) - measured).max() > 2.0
