"""[processing.periodic]: period averaging and exact frequency-domain processing inside
``dynid identify`` (paper 004 §3), on a simulated periodic experiment with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import seed
from dynid.config import parse_config
from dynid.errors import ConfigError
from dynid.model import load_robot
from dynid.pipeline import identify
from dynid.simulation import simulate_serial
from dynid.trajectories import FourierTrajectory

Q = [f"q{j}" for j in range(1, 7)]
TAU = [f"tau{j}" for j in range(1, 7)]


def _log(path, ds):
    table = np.column_stack([ds.t, ds.q, ds.tau])
    np.savetxt(path, table, delimiter=",", header=",".join(["t", *Q, *TAU]), comments="", fmt="%.17g")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("periodic")
    robot = load_robot("builtin:generic6r")
    lo, hi = robot.position_limits()
    rng = np.random.default_rng(seed(0))
    trajs = {}
    for name, k in (("train", 1), ("valid", 2)):
        traj = FourierTrajectory.random(6, 5, 0.1, np.random.default_rng(seed(k)), lo, hi, max_velocity=1.0, max_acceleration=3.0, fill=0.5)
        ds = simulate_serial(robot, robot.nominal_parameters(), traj, fs=200.0, duration=40.0,
                             torque_noise_std=[1.0, 1.0, 0.5, 0.2, 0.2, 0.1], position_noise_std=2e-4, rng=rng)
        _log(d / f"{name}.csv", ds)
        trajs[name] = traj
    return d, robot, trajs


def _config(d, processing: dict) -> dict:
    return {
        "robot": {"model": "builtin:generic6r", "extras": ["Ia", "fv", "fc", "offset"]},
        "data": {"file": str(d / "train.csv"), "time": {"column": "t", "unit": "s"},
                 "position": {"columns": Q, "unit": "rad"}, "effort": {"columns": TAU, "kind": "torque", "unit": "N*m"}},
        "validation": {"file": str(d / "valid.csv")},
        "processing": processing,
        "identification": {"method": "wls"},
        "output": {"plots": False},
    }


@pytest.mark.numerics
def test_periodic_processing_identifies_the_truth(logs):
    d, robot, _ = logs
    cfg = parse_config(_config(d, {"periodic": {"period_s": 10.0, "cutoff_hz": 0.55}}), d)
    out = identify(cfg)
    step = [s for s in out.result.provenance["processing"] if s["step"] == "periodic"][0]
    assert step["periods"] == 4 and step["averaged"] and step["samples_per_period"] == 2000
    # the noise covariance of the efforts, estimated from the 4 periods: the simulated variances (3 x 2000
    # degrees of freedom per joint: a relative std of 0.9 % on the std, 0.1 is 11 of them)
    cov = np.array(step["noise_covariance_effort"])
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [1.0, 1.0, 0.5, 0.2, 0.2, 0.1], rtol=0.1)
    true = out.base.from_standard(robot.nominal_parameters())
    z = (out.result.params - true) / out.result.bse
    assert np.abs(z).max() < 4.5, np.abs(z).max()  # 58 parameters: a false alarm of 4e-4
    assert out.train.n_samples == 2000  # one averaged period


@pytest.mark.numerics
def test_periodic_processing_beats_time_domain_on_derivatives(logs):
    """Same noisy log: the averaged, exactly differentiated period is closer to the true
    velocities and accelerations than the time-domain chain (low-pass + central differences)."""
    d, robot, trajs = logs
    per = identify(parse_config(_config(d, {"periodic": {"period_s": 10.0, "cutoff_hz": 0.55}}), d))
    tim = identify(parse_config(_config(d, {"lowpass": {"cutoff_hz": 2.0, "order": 4, "filter_effort": False}}), d))
    errors = {}
    for label, out in (("periodic", per), ("time", tim)):
        _, dq, ddq = trajs["train"].sample(out.train.t)
        errors[label] = (np.sqrt(np.mean((out.train.dq - dq) ** 2)), np.sqrt(np.mean((out.train.ddq - ddq) ** 2)))
    # 0.07-0.09 (velocities) and 0.018-0.024 (accelerations) over 4 draws: the bound is 5x and 20x that
    assert errors["periodic"][0] < 0.5 * errors["time"][0], errors
    assert errors["periodic"][1] < 0.5 * errors["time"][1], errors
    # both identify a model that predicts the held-out torques (R^2 >= 0.98 over 4 draws)
    assert min(per.validation.r2) > 0.9 and min(tim.validation.r2) > 0.9


def test_periodic_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="replaces \\['lowpass'\\]"):
        parse_config(_config(tmp_path, {"periodic": {"period_s": 10.0, "cutoff_hz": 1.0}, "lowpass": {"cutoff_hz": 2.0}}), tmp_path)
    with pytest.raises(ConfigError, match="missing required keys \\['cutoff_hz'\\]"):
        parse_config(_config(tmp_path, {"periodic": {"period_s": 10.0}}), tmp_path)


def test_pose_domain_is_for_parallel_robots(logs):
    d, _, _ = logs
    cfg = parse_config(_config(d, {"periodic": {"period_s": 10.0, "cutoff_hz": 0.55, "domain": "pose"}}), d)
    with pytest.raises(ConfigError, match="is for parallel robots"):
        identify(cfg)


@pytest.mark.numerics
def test_gauss_markov_with_the_period_averaging_covariance(logs):
    """[identification] method = "gm", noise_covariance = "periodic": the estimator uses the
    effort noise covariance measured by the period averaging (paper 004 §3.2), divided by the
    number of periods, and its intervals hold the truth."""
    d, robot, _ = logs
    doc = _config(d, {"periodic": {"period_s": 10.0, "cutoff_hz": 0.55}})
    doc["identification"] = {"method": "gm", "noise_covariance": "periodic"}
    out = identify(parse_config(doc, d))
    assert out.result.method == "GM"
    cov = np.asarray(out.result.solver["noise_covariance"])
    step = next(s for s in out.result.provenance["processing"] if s["step"] == "periodic")
    np.testing.assert_allclose(cov, np.asarray(step["noise_covariance_effort"]) / step["periods"])
    np.testing.assert_allclose(np.sqrt(np.diag(cov) * step["periods"]), [1.0, 1.0, 0.5, 0.2, 0.2, 0.1], rtol=0.1)
    true = out.base.from_standard(robot.nominal_parameters())
    z = (out.result.params - true) / out.result.bse
    assert np.abs(z).max() < 4.5, np.abs(z).max()
    # the averaged noise explains the residual: E scale = 1, with a relative std of about
    # sqrt(2 / dof) (12 000 equations: 1.3 %)
    assert out.result.scale < 2.0


def test_estimator_options_are_checked(logs):
    d, _, _ = logs
    doc = _config(d, {"lowpass": {"cutoff_hz": 2.0, "order": 4, "filter_effort": False}})
    doc["identification"] = {"method": "gm", "noise_covariance": "periodic"}
    with pytest.raises(ConfigError, match="needs \\[processing.periodic\\] averaging"):
        identify(parse_config(doc, d))
    doc["identification"] = {"method": "wls", "noise_covariance": "periodic"}
    with pytest.raises(ConfigError, match="is for method = 'gm'"):
        parse_config(doc, d)
    doc["identification"] = {"method": "gm", "noise_covariance": [[1.0, 0.0], [0.0, 1.0]]}
    with pytest.raises(ConfigError, match="is 2 x 2; there are 6 channels"):
        identify(parse_config(doc, d))
    doc["identification"] = {"method": "wls", "nominal_weighting": True}
    out = identify(parse_config(doc, d))
    assert "cond_Zww" in out.result.solver
