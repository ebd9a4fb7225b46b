"""The Kalman (RTS) smoother of sampled positions (dynid.signals.kalman; issue 36, item 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynid.errors import InputError
from dynid.signals import kalman

from conftest import seed


def _process(n: int, order: int, scale: float, ratio: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """A white noise in the order-th derivative (scaled state, driving covariance scale * Q) and
    its positions measured with noise variance ratio * scale."""
    F, Q, _ = kalman._model(order)
    L = np.linalg.cholesky(Q * scale)
    x = np.zeros((n, order))
    for k in range(1, n):
        x[k] = F @ x[k - 1] + L @ rng.standard_normal(order)
    z = x[:, 0] + math.sqrt(ratio * scale) * rng.standard_normal(n)
    return x, z


def _loop(z: np.ndarray, ss) -> tuple[np.ndarray, np.ndarray]:
    """The steady-state filter and RTS smoother as plain recursions (an independent route)."""
    n, m = z.size, ss.order
    x = np.zeros((n, m))
    prev = kalman._start(z[:, None], ss)[:, 0]
    for k in range(n):
        pred = ss.F @ prev
        x[k] = pred + ss.K * (z[k] - pred[0])
        prev = x[k]
    s = x.copy()
    for k in range(n - 2, -1, -1):
        s[k] = x[k] + ss.C @ (s[k + 1] - ss.F @ x[k])
    return x, s


@pytest.mark.parametrize("order", [3, 4])
def test_lfilter_route_equals_the_recursions(order):
    rng = np.random.default_rng(seed(11))
    _, z = _process(3000, order, 1e-10, 1e4, rng)
    ss = kalman.steady_state(1e4, order)
    x = kalman._forward(z[:, None], ss)[..., 0]
    s = x + kalman._backward(kalman._forward(z[:, None], ss), ss)[..., 0]
    xl, sl = _loop(z, ss)
    # both are the same linear recursions in double precision; the transfer-function route loses
    # a few digits to poles near 1 (here |pole| ~0.9): 1e-9 of the signal's range is ample
    span = np.ptp(z)
    np.testing.assert_allclose(x, xl, atol=1e-9 * span)
    np.testing.assert_allclose(s, sl, atol=1e-9 * span)


@pytest.mark.numerics
def test_on_its_own_model_the_noise_is_recovered_and_the_errors_match_the_reported_std():
    rng = np.random.default_rng(seed(12))
    # a 4th-order random walk grows as n^3.5: 3000 samples at this scale stay within a few units,
    # measured with noise std 1e-6 (ratio 1e10)
    order, scale, ratio, n, dt = 4, 1e-22, 1e10, 3000, 1e-3
    x, z = _process(n, order, scale, ratio, rng)
    fit = kalman.smooth(z, dt, order=order)
    # the innovations are white, N = 3000: the variance's relative std is sqrt(2/N) = 2.6 %, and the
    # ratio's estimate moves R by less than that near the optimum: 12 % is over 4 std
    assert fit.noise_std[0] ** 2 == pytest.approx(ratio * scale, rel=0.12)
    # the smoothed errors against the steady-state std they report: they are correlated over about
    # 1 / (1 - rho) samples (~50 here), so the RMS over 3000 samples rests on ~60 independent
    # values: its relative std is ~9 %; 0.6-1.5 is more than 4 std either way
    k = slice(fit.settle, n - fit.settle)
    truth = (x[:, 0], x[:, 1] / dt, x[:, 2] / dt**2)
    for i, (est, tr) in enumerate(zip((fit.q[:, 0], fit.dq[:, 0], fit.ddq[:, 0]), truth)):
        rms = float(np.sqrt(np.mean((est[k] - tr[k]) ** 2)))
        assert 0.6 < rms / fit.std[0, i] < 1.5, (i, rms, fit.std[0, i])


def test_a_given_noise_std_is_used_and_bad_input_is_refused():
    rng = np.random.default_rng(seed(13))
    _, z = _process(2000, 4, 1e-12, 1e6, rng)
    fit = kalman.smooth(np.column_stack([z, z]), 1e-3, noise_std=[1e-3, 2e-3])
    np.testing.assert_array_equal(fit.noise_std, [1e-3, 2e-3])
    assert fit.ratio[1] > fit.ratio[0]  # more noise given: a smoother motion is the likelier model
    with pytest.raises(InputError, match="at least 20 samples"):
        kalman.smooth(z[:10], 1e-3)
    with pytest.raises(InputError, match="noise std must be positive"):
        kalman.smooth(z, 1e-3, noise_std=0.0)


@pytest.mark.numerics
def test_identify_with_kalman_derivatives_beats_the_prior(tmp_path):
    """``processing.derivatives = "kalman"`` through ``dynid init`` + ``identify`` on the shipped
    quickstart arm: the steps record the smoother and its noise, and the identified model beats
    the prior on every held-out channel (prior 5.5-12.8 %, identified 2.8-7.5 % on this log: the
    Butterworth path gives 2.5-7.8 %)."""
    import json

    from conftest import REPO
    from dynid.cli import main

    ex = REPO / "examples" / "serial_arm"
    cfg = tmp_path / "identify.toml"
    assert main(["init", str(ex / "arm3.urdf"), str(ex / "log.csv"), "--out", str(cfg)]) == 0
    text = cfg.read_text()
    assert 'derivatives = "central"' in text
    cfg.write_text(text.replace('derivatives = "central"', 'derivatives = "kalman"', 1))
    assert main(["identify", str(cfg), "--out", str(tmp_path / "out"), "-q"]) == 0
    res = json.loads((tmp_path / "out" / "result.json").read_text())
    text = json.dumps(res)
    assert "Kalman (RTS) smoother" in text and "noise_ratio" in text
    a = np.asarray(res["validation"]["rmse_per_joint"], float)
    b = np.asarray(res["nominal_validation"]["rmse_per_joint"], float)
    assert np.all(a < b), (a, b)


def test_position_noise_std_needs_kalman(tmp_path):
    from conftest import REPO
    from dynid.cli import main
    from dynid.config import load_config
    from dynid.errors import ConfigError

    ex = REPO / "examples" / "serial_arm"
    cfg = tmp_path / "identify.toml"
    assert main(["init", str(ex / "arm3.urdf"), str(ex / "log.csv"), "--out", str(cfg)]) == 0
    text = cfg.read_text().replace('derivatives = "central"', 'derivatives = "central"\nposition_noise_std = 1e-6', 1)
    cfg.write_text(text)
    with pytest.raises(ConfigError, match="position_noise_std .* needs processing.derivatives = 'kalman'"):
        load_config(cfg)
    cfg.write_text(text.replace('derivatives = "central"', 'derivatives = "kalman"', 1))
    assert load_config(cfg).processing.position_noise_std == (1e-6,)
