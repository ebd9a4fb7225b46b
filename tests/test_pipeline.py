"""The identification pipeline on simulated logs with known truth: motor-side data through a
coupled transmission with drive gains and encoder offsets, irregular timestamps, parallel
decimation (chunked == whole), and recovery within the reported uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.config import parse_config
from dynid.dataset import Dataset
from dynid.estimation import OLS
from dynid.model import Coupling, Transmission, load_robot, robot_base_parameters
from dynid.pipeline import identify
from dynid.pipeline.identification import build_problem
from dynid.simulation import FourierTrajectory, simulate_serial

TR = Transmission.from_ratios(
    [32.0, 32.0, 45.0, -48.0, 45.0, 32.0], [Coupling(6, (5, 6))], drive_gains=[0.5, 0.5, 0.4, 0.3, 0.3, 0.2],
    position_offset=[0.0, -np.pi / 2, np.pi / 2, 0.0, 0.0, 0.0],
)
ROBOT = load_robot("builtin:generic6r", transmission=TR)


def _simulate(seed, duration, fs=200.0, noise_scale=1.0, jitter=0.0, coulomb=True):
    """Log of a Fourier trajectory; with ``jitter``, samples are taken at irregular instants
    (uniform +-jitter of the period around the nominal grid) and the log holds those instants."""
    rng = np.random.default_rng(seed)
    lo, hi = ROBOT.position_limits()
    traj = FourierTrajectory.random(6, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    truth = ROBOT.nominal_parameters()
    lay = ROBOT.layout
    truth[lay.motor_index["Ia"]] = 0.02
    truth[lay.motor_index["fv"]] = 0.4
    truth[lay.motor_index["fc"]] = 0.7
    if not coulomb:
        truth[lay.extra_index["fc"]] = 0.0
        truth[lay.motor_index["fc"]] = 0.0
    sigma = np.array([0.8, 0.8, 0.4, 0.06, 0.06, 0.04]) * noise_scale
    if not jitter:
        return simulate_serial(ROBOT, truth, traj, fs=fs, duration=duration, torque_noise_std=sigma, rng=rng), truth
    from dynid.model.serial_dynamics import inverse_dynamics

    t = np.arange(int(duration * fs)) / fs + rng.uniform(-jitter, jitter, int(duration * fs)) / fs
    q, dq, ddq = traj.sample(t)
    tau = inverse_dynamics(ROBOT, truth, q, dq, ddq) + rng.standard_normal(q.shape) * sigma
    return Dataset(t=t, q=q, tau=tau), truth


def _write_motor_log(path, ds: Dataset):
    """What the controller records: motor encoder angles and motor currents."""
    theta = (ds.q - TR.position_offset) @ TR.matrix.T
    current = np.linalg.solve(TR.matrix.T, ds.tau.T).T / TR.drive_gains
    t = ds.t
    header = ",".join(["time"] + [f"enc{j}" for j in range(1, 7)] + [f"cur{j}" for j in range(1, 7)])
    np.savetxt(path, np.column_stack([t, theta, current]), delimiter=",", header=header, comments="", fmt="%.12g")


def _config(tmp_path, method="wls", resample="auto", extra_processing=None):
    doc = {
        "robot": {
            "model": "builtin:generic6r",
            "gear_ratios": TR.matrix.diagonal().tolist(),
            "couplings": [{"motor": 6, "joints": [5, 6]}],
            "drive_gains": TR.drive_gains.tolist(),
            "position_offset": TR.position_offset.tolist(),
        },
        "data": {
            "file": "train.csv",
            "time": {"column": "time"},
            "position": {"columns": [f"enc{j}" for j in range(1, 7)], "side": "motor"},
            "effort": {"columns": [f"cur{j}" for j in range(1, 7)], "kind": "current", "unit": "A"},
        },
        "validation": {"file": "valid.csv"},
        "processing": {"resample": resample, "lowpass": {"cutoff_hz": 5.0, "order": 4, "filter_effort": False},
                       **(extra_processing or {})},
        "identification": {"method": method},
        "output": {"plots": False},
    }
    return parse_config(doc, tmp_path)


def test_motor_side_log_with_coupled_wrist_recovers_truth(tmp_path):
    train, truth = _simulate(1, 40.0)
    valid, _ = _simulate(2, 15.0)
    _write_motor_log(tmp_path / "train.csv", train)
    _write_motor_log(tmp_path / "valid.csv", valid)
    out = identify(_config(tmp_path))
    base = out.base
    assert {"Iam6", "fvm6", "fcm6"} <= set(base.names)
    beta = base.from_standard(truth)
    res = out.result
    z = (res.params - beta) / res.bse
    assert np.mean(np.abs(z) < 1.96) > 0.88, np.round(z, 2)
    assert np.max(np.abs(z)) < 4.5
    # the held-out error is the sensor noise: the model is right
    np.testing.assert_allclose(out.validation.rmse, [0.8, 0.8, 0.4, 0.06, 0.06, 0.04], rtol=0.15)


def test_irregular_timestamps_are_resampled_and_recorded(tmp_path):
    """Jittered sampling instants (+-30 % of the period) are resampled onto a uniform grid.

    The truth has no Coulomb friction here: interpolating a torque that jumps at velocity
    reversals from irregular instants misplaces the jump by up to one sample, a bias that
    the resampling cannot remove (docs/guide/computes.md, "Processing notes").
    """
    train, truth = _simulate(3, 40.0, jitter=0.3, coulomb=False)
    valid, _ = _simulate(4, 15.0, jitter=0.3, coulomb=False)
    assert not train.is_uniform()
    _write_motor_log(tmp_path / "train.csv", train)
    _write_motor_log(tmp_path / "valid.csv", valid)
    from dynid.errors import InputError

    with pytest.raises(InputError, match="irregular"):
        identify(_config(tmp_path, resample="off"))
    out = identify(_config(tmp_path))
    steps = [s["step"] for s in out.result.provenance["processing"]]
    assert steps[0] == "resample"
    beta = out.base.from_standard(truth)
    z = (out.result.params - beta) / out.result.bse
    # interpolated noise is mildly correlated between neighbours, so intervals are a little optimistic
    assert np.mean(np.abs(z) < 1.96) > 0.8 and np.max(np.abs(z)) < 4.0, np.round(z, 2)
    # linear interpolation averages neighbouring noise samples: the held-out RMSE is below the noise
    rmse, sigma = out.validation.rmse, np.array([0.8, 0.8, 0.4, 0.06, 0.06, 0.04])
    assert np.all(rmse < 1.0 * sigma) and np.all(rmse > 0.6 * sigma), rmse


def test_parallel_decimation_is_independent_of_chunking():
    ds, _ = _simulate(5, 30.0, fs=500.0)
    robot = load_robot("builtin:generic6r", transmission=TR)
    base = robot_base_parameters(robot)
    from dynid.signals import central_difference

    dq = central_difference(ds.q, ds.t)
    ds = ds.replace(dq=dq, ddq=central_difference(dq, ds.t))
    whole = build_problem(robot, base, ds, parallel_decimate=10, chunk_size=10**9)
    chunked = build_problem(robot, base, ds, parallel_decimate=10, chunk_size=1000)
    assert list(whole.n_obs) == list(chunked.n_obs) == [1500] * 6
    a, b = OLS().fit(whole), OLS().fit(chunked)
    np.testing.assert_allclose(b.params, a.params, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(b.rss_per_channel, a.rss_per_channel, rtol=1e-7)


def test_parallel_decimation_config_is_consistent(tmp_path):
    from dynid.errors import ConfigError

    train, _ = _simulate(6, 20.0)
    valid, _ = _simulate(7, 10.0)
    _write_motor_log(tmp_path / "train.csv", train)
    _write_motor_log(tmp_path / "valid.csv", valid)
    cfg = _config(tmp_path, extra_processing={"decimate": 4, "decimate_method": "parallel",
                                              "lowpass": {"cutoff_hz": 5.0, "order": 4, "filter_effort": True}})
    with pytest.raises(ConfigError, match="filter_effort"):
        identify(cfg)
    cfg = _config(tmp_path, extra_processing={"decimate": 4, "decimate_method": "parallel"})
    out = identify(cfg)
    assert out.result.n_obs[0] == -(-out.train.n_samples // 4)
    assert out.validation.n_samples == -(-out.held_out.n_samples // 4)
