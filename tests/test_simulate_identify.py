"""Simulate, then identify: the estimators recover the true base parameters of a virtual
experiment (closed-loop shang2dof and the serial 6R cobot of paper 003) within the intervals they
report; on noise-free data to 1e-6 relative.

The regressors are evaluated on the simulated motion's exact states (positions, velocities,
accelerations of all joints at the control instants); the efforts are the logged ones, with the
sensor noise of :class:`dynid.simulation.sensors.Sensors` drawn again for each repetition.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import seed
from dynid.config.simulate import parse_simulate_config
from dynid.estimation.linear import OLS, WLS
from dynid.estimation.problem import ProblemBuilder
from dynid.model import load_robot, regressor, robot_base_parameters
from dynid.model.closed_loop import actuator_regressor, mechanism_base_parameters
from dynid.model.robots import build_mechanism
from dynid.pipeline.simulate import run_simulation
from dynid.simulation.sensors import Sensors

FOURIER = {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 4, "fill": 0.6, "periods": 2, "seed": seed(1)}


def _scaled_error(est, true):
    return np.abs(est - true) / np.maximum(np.abs(true), 1e-3 * np.abs(true).max())


def _coverage(W, y_of, base_names, channels, true, draws):
    """Over ``draws`` noise draws: the mean fraction of the 95 % intervals that cover the truth and
    the mean of z^2 over the parameters, each with its margin: 4.5 std of its mean over the draws
    (a false alarm of 7e-6 each). The parameters' estimates are correlated, so a draw's fraction
    and mean z^2 vary more than for independent parameters: their law follows from the
    estimates' correlation R (the same in every draw: OLS's covariance up to its scale); mean z^2
    has the std sqrt(2 tr R^2) / p, the covered fraction's std is integrated over z ~ N(0, R)."""
    inside, z2, corr = [], [], None
    for k in range(draws):
        b = ProblemBuilder(base_names, channels)
        b.add(W, y_of(seed(k)))
        r = OLS().fit(b.build())
        ci = r.conf_int()
        inside.append(np.mean((ci[:, 0] <= true) & (true <= ci[:, 1])))
        z2.append(np.mean(((r.params - true) / r.bse) ** 2))
        corr = r.cov_params / np.outer(r.bse, r.bse)
    p = len(true)
    z = np.random.default_rng(0).multivariate_normal(np.zeros(p), corr, size=20000)  # an integral, not data
    sd_inside = np.mean(np.abs(z) < 1.959964, axis=1).std()
    sd_z2 = np.sqrt(2 * np.sum(corr * corr)) / p
    return (float(np.mean(inside)), 4.5 * sd_inside / np.sqrt(draws)), (float(np.mean(z2)), 4.5 * sd_z2 / np.sqrt(draws))


@pytest.fixture(scope="module")
def shang_run():
    cfg = parse_simulate_config(
        {"robot": {"model": "builtin:shang2dof", "perturbation": 0.1},
         "trajectory": {**FOURIER, "max_velocity": 0.3, "max_acceleration": 3.0},
         "control": {"rate_hz": 500, "kp": 20000, "kd": 250}},
        Path("."),
    )
    return run_simulation(cfg)


def test_shang2dof_noise_free_recovery(shang_run):
    mech = build_mechanism("shang2dof")
    base = mechanism_base_parameters(mech)
    m = shang_run.motion
    reg = actuator_regressor(mech, mech.kinematic_state(m.q, m.dq, m.ddq), distribution="projected")
    tau = np.column_stack([shang_run.columns[f"tau_qa{i}"] for i in (1, 2, 3)])
    b = ProblemBuilder(base.names, ["x", "y"])
    b.add(base.regressor(reg.W), reg.outputs(tau))
    est = WLS().fit(b.build()).params
    true = base.from_standard(np.array(shang_run.truth["true_parameters"]))
    assert np.array_equal(true, np.array(shang_run.truth["base_parameters"]["true_values"]))
    assert _scaled_error(est, true).max() < 1e-6


@pytest.mark.numerics
def test_shang2dof_intervals_cover_the_truth(shang_run):
    mech = build_mechanism("shang2dof")
    base = mechanism_base_parameters(mech)
    m = shang_run.motion
    reg = actuator_regressor(mech, mech.kinematic_state(m.q, m.dq, m.ddq), distribution="projected")
    true = base.from_standard(np.array(shang_run.truth["true_parameters"]))

    def y_of(s):  # 0.05 N*m of white noise on each motor torque
        meas = Sensors(force_covariance=0.05**2, seed=s).measure(m.t, m.q[:, [0, 2, 4]], m.tau_a)
        return reg.outputs(meas.effort)

    # 25 strongly correlated estimates: 160 draws for margins of about 0.03 and 0.2 (0.08 and 0.6 per draw)
    (coverage, dc), (z2, dz) = _coverage(base.regressor(reg.W), y_of, base.names, ["x", "y"], true, draws=160)
    assert abs(coverage - 0.95) < dc and abs(z2 - 1) < dz, (coverage, dc, z2, dz)


@pytest.mark.numerics
def test_cobot6r_simulate_identify(tmp_path):
    """The 6R arm after paper 003 (builtin:cobot6r) under computed torque."""
    cfg = parse_simulate_config(
        {"robot": {"model": "builtin:cobot6r", "perturbation": 0.1},
         "trajectory": {**FOURIER, "base_frequency_hz": 0.2, "max_velocity": 1.5, "max_acceleration": 6.0, "periods": 1},
         "control": {"rate_hz": 1000, "kp": 400, "kd": 40, "substeps": 2}},
        tmp_path,
    )
    out = run_simulation(cfg)
    robot = load_robot("builtin:cobot6r")
    base = robot_base_parameters(robot)
    m = out.motion
    W = base.regressor(regressor(robot, m.q, m.dq, m.ddq))
    true = base.from_standard(np.array(out.truth["true_parameters"]))
    b = ProblemBuilder(base.names, robot.joint_names)
    b.add(W, m.tau)
    assert _scaled_error(OLS().fit(b.build()).params, true).max() < 1e-6

    def y_of(s):
        return Sensors(force_covariance=0.2**2, seed=s).measure(m.t, m.q, m.tau).effort

    # 58 estimates: 40 draws for margins of about 0.03 and 0.2 (0.04 and 0.3 per draw)
    (coverage, dc), (z2, dz) = _coverage(W, y_of, base.names, robot.joint_names, true, draws=40)
    assert abs(coverage - 0.95) < dc and abs(z2 - 1) < dz, (coverage, dc, z2, dz)
