"""Sensor models of virtual experiments and tracking metrics."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import seed
from dynid.errors import InputError
from dynid.simulation.sensors import Sensors
from dynid.stats import tracking_errors


def _signals(n=20000, nq=3, na=2):
    t = np.arange(n) * 1e-3
    q = np.stack([np.sin(t * (k + 1)) for k in range(nq)], axis=1)
    tau = np.stack([np.cos(t * (k + 2)) for k in range(na)], axis=1)
    return t, q, tau


@pytest.mark.numerics
def test_quantization_noise_covariance_and_currents():
    t, q, tau = _signals()
    cov = np.array([[0.04, 0.018], [0.018, 0.01]])  # correlation 0.9
    s = Sensors(encoder_resolution=1e-3, position_noise_std=0.0, force_covariance=cov, torque_constants=[2.0, 0.5], seed=seed(3))
    m = s.measure(t, q, tau)
    # quantized to the encoder grid, error at most half a count
    assert np.allclose(np.round(m.q / 1e-3) * 1e-3, m.q)
    assert np.abs(m.q - q).max() <= 0.5e-3 + 1e-15
    # currents: tau / k; the torque noise has the given covariance (to sampling error: 20 000 samples,
    # a std of 1 % on a variance, sqrt((s1^2 s2^2 + c^2) / n) = 2e-4 on the covariance; the tolerance
    # is 7.5, 15 and 10 of them)
    assert m.effort_kind == "current"
    noise = m.effort * [2.0, 0.5] - tau
    np.testing.assert_allclose(np.cov(noise.T), cov, rtol=0.05, atol=1e-3)
    # the same seed gives bit-identical output, another seed does not
    again = s.measure(t, q, tau)
    assert np.array_equal(again.effort, m.effort)
    other = Sensors(force_covariance=cov, seed=seed(4)).measure(t, q, tau)
    assert not np.array_equal(other.effort, tau + noise)


@pytest.mark.numerics
def test_decimation_and_jitter():
    t, q, tau = _signals(1000)
    m = Sensors(decimation=4, time_jitter_std=1e-4, position_noise_std=1e-4, seed=seed(1)).measure(t, q, tau)
    assert m.t.shape == (250,) and np.array_equal(m.index, np.arange(0, 1000, 4))
    assert np.all(np.diff(m.t) > 0)  # stays increasing
    assert 0 < np.abs(m.t - t[::4]).max() <= 0.45 * 4e-3  # 1e-4 of jitter std: 18 std
    np.testing.assert_allclose(m.effort, tau[::4])  # no force noise asked for
    assert 5e-5 < np.std(m.q - q[::4]) < 2e-4  # the std of 250 samples: 4.5 % relative std, 11+ of them


def test_bad_sensor_settings():
    t, q, tau = _signals(10)
    with pytest.raises(InputError, match="positive semi-definite"):
        Sensors(force_covariance=np.array([[1.0, 2.0], [2.0, 1.0]])).measure(t, q, tau)
    with pytest.raises(InputError, match=r"\(2, 2\)"):
        Sensors(force_covariance=np.eye(3)).measure(t, q, tau)
    with pytest.raises(InputError, match="decimation"):
        Sensors(decimation=0)
    with pytest.raises(InputError, match="mismatched lengths"):
        Sensors().measure(t[:5], q, tau)


def test_tracking_errors_p_rsme():
    ref = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    act = ref + np.array([[0.3, 0.4], [0.0, 0.0], [-0.3, -0.4], [0.0, 0.0]])
    m = tracking_errors(ref, act)
    # Shang 2009, Eq. 23: sqrt(mean over samples of the squared Euclidean error)
    assert m["p_rsme"] == pytest.approx(np.sqrt((0.25 + 0.25) / 4))
    np.testing.assert_allclose(m["rms_per_axis"], [np.sqrt(0.18 / 4), np.sqrt(0.32 / 4)])
    np.testing.assert_allclose(m["max_abs_per_axis"], [0.3, 0.4])
    with pytest.raises(InputError):
        tracking_errors(ref, act[:2])
