"""Periodic-data processing and more filters, on analytic signals (paper 004 §3.2-3.3,
paper 003 §4.3)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import seed
from scipy import signal as ss

from dynid.errors import InputError
from dynid.signals import (
    butter_sos,
    butter_spec_sos,
    central_difference,
    fourier_filter,
    fourier_fit,
    lowess,
    lowpass_sos,
    moving_average,
    period_average,
    savgol,
)


def _gain_db(sos, f, fs):
    w, h = ss.sosfreqz(sos, worN=[f], fs=fs)
    return 20 * np.log10(np.abs(h[0]))


def test_single_pass_is_minus_3_db_at_the_cutoff_and_the_pair_minus_6():
    for fs, fc in ((1000.0, 20.0), (50.0, 1.0), (200.0, 37.5)):
        sos = butter_sos(4, fc, fs)
        assert _gain_db(sos, fc, fs) == pytest.approx(-3.0103, abs=1e-3)
        assert 2 * _gain_db(sos, fc, fs) == pytest.approx(-6.0206, abs=2e-3)  # forward-backward


def test_spec_based_design_meets_paper003_spec():
    """50 Hz sampling, 1 Hz pass, 5 Hz stop, 1 dB ripple, 15 dB attenuation (paper 003)."""
    sos, order, fc = butter_spec_sos(50.0, 1.0, 5.0, 1.0, 15.0)
    assert order == ss.buttord(1.0, 5.0, 1.0, 15.0, fs=50.0)[0]
    assert _gain_db(sos, 1.0, 50.0) >= -1.0 - 1e-9
    assert _gain_db(sos, 5.0, 50.0) <= -15.0 + 1e-9
    assert _gain_db(sos, fc, 50.0) == pytest.approx(-3.0103, abs=1e-3)
    # zero-phase application: the pair doubles the attenuation in dB, measured on a sinusoid
    t = np.arange(5000) / 50.0
    y = lowpass_sos(np.sin(2 * np.pi * 5.0 * t), sos)
    amp = np.abs(y[1000:-1000]).max()
    assert 20 * np.log10(amp) <= -30.0 + 0.1
    with pytest.raises(InputError):
        butter_spec_sos(50.0, 5.0, 1.0, 1.0, 15.0)


@pytest.mark.numerics
def test_noise_covariance_from_20_periods_within_10_percent():
    """A known cross-correlated noise covariance (6 channels) recovered by period averaging.

    Margins: each element from 19 x 400 = 7600 degrees of freedom, a std of at most
    sqrt(2 / 7600) = 1.6 % of sqrt(S_ii S_jj): 10 % is 6 of them (21 elements: 4e-8); the period
    mean of 20 draws within 6 of its std, over 2400 values: 5e-6."""
    rng = np.random.default_rng(seed(0))
    n, n_m = 400, 20
    L = rng.normal(size=(6, 6))
    cov = L @ L.T + 6 * np.eye(6)
    cov *= 0.04 / np.mean(np.diag(cov))
    t = np.arange(n * n_m) / 100.0
    clean = np.stack([np.sin(2 * np.pi * 0.25 * (k + 1) * t) for k in range(6)], axis=1)
    noisy = clean + rng.multivariate_normal(np.zeros(6), cov, size=t.size)
    mean, est = period_average(noisy, n)
    rel = np.abs(est - cov) / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert rel.max() < 0.10, rel.max()
    assert np.abs(mean - clean[:n]).max() < 6 * np.sqrt(cov.diagonal().max() / n_m)
    with pytest.raises(InputError, match="whole number of periods"):
        period_average(noisy[:-1], n)


def _periodic(t, f0, harmonics=5):
    k = np.arange(1, harmonics + 1)
    w = 2 * np.pi * f0 * k
    amp = 1.0 / k
    x = np.sin(np.outer(t, w) + k) @ amp
    dx = (np.cos(np.outer(t, w) + k) * w) @ amp
    ddx = -(np.sin(np.outer(t, w) + k) * w**2) @ amp
    return x, dx, ddx


@pytest.mark.numerics
def test_frequency_domain_filter_and_derivatives_are_exact_on_band_limited_data():
    fs, f0 = 100.0, 0.5
    t = np.arange(400) / fs  # two whole periods of the real motion
    x, dx, ddx = _periodic(t, f0)
    rng = np.random.default_rng(seed(1))
    xn = x + 1e-3 * rng.standard_normal(t.size)
    xf, dxf, ddxf = fourier_filter(xn, fs, cutoff_hz=5 * f0 + 1e-9)
    # noise above the cut-off removed; what remains is the noise inside the band: 2.5 of the 50 Hz,
    # a std of 1e-3 sqrt(0.05) = 2.2e-4 over about 20 independent values (4 s x 2 x 2.5 Hz): 1e-3 is 4.5 of
    # them (a false alarm of 1e-4); its derivatives (2e-3 and 0.02 std) are far below 5 % of the signal's
    assert np.abs(xf - x).max() < 1e-3
    assert np.abs(dxf - dx).max() < 0.05 * np.abs(dx).max()
    assert np.abs(ddxf - ddx).max() < 0.05 * np.abs(ddx).max()
    # noise-free: exact to round-off
    xf, dxf, ddxf = fourier_filter(x, fs, cutoff_hz=5 * f0 + 1e-9)
    assert np.abs(ddxf - ddx).max() < 1e-9 * np.abs(ddx).max()


def test_period_mismatch_frequency_domain_beats_implicit_fit():
    """The real period is 0.5 % longer than the nominal one; the record spans one real period
    (paper 004 §3.3, Fig. 2): the DFT processing has no leakage, the fit at nominal harmonics has."""
    fs, f_nominal = 200.0, 0.5
    f_real = f_nominal / 1.005
    n = int(round(fs / f_real))
    t = np.arange(n) / fs
    x, dx, ddx = _periodic(t, fs / n)  # exactly periodic over the record
    _, dxf, ddxf = fourier_filter(x, fs, cutoff_hz=5.5 * f_nominal)
    _, dxi, ddxi = fourier_fit(x, t, f_nominal, 5)
    err_dft = np.sqrt(np.mean((ddxf - ddx) ** 2))
    err_fit = np.sqrt(np.mean((ddxi - ddx) ** 2))
    assert err_dft < 1e-9 * np.abs(ddx).max()
    assert err_fit > 1e3 * err_dft and err_fit > 1e-3 * np.abs(ddx).max()
    # with the exact frequency the implicit fit is exact too (the equivalence paper 004 states)
    _, _, ddx_exact = fourier_fit(x, t, fs / n, 5)
    assert np.abs(ddx_exact - ddx).max() < 1e-8 * np.abs(ddx).max()


@pytest.mark.numerics
def test_time_domain_differentiators_on_noisy_sinusoids():
    """Error bounds: Savitzky-Golay and filtered central differences on a 1 Hz sine sampled
    at 500 Hz with 1e-4 noise. Each bound is the method's bias plus at least 50 std of the noise it
    passes (Savitzky-Golay's first derivative: 5e-4 std against 0.063; its second: 7e-3 against 2;
    the raw second difference: 15 std against 10 x 0.02; moving average and LOWESS: 3e-5 and 2e-5 std
    against the 1e-3 beyond their curvature bias)."""
    fs = 500.0
    t = np.arange(5000) / fs
    rng = np.random.default_rng(seed(2))
    w = 2 * np.pi
    x = np.sin(w * t) + 1e-4 * rng.standard_normal(t.size)
    dx, ddx = w * np.cos(w * t), -(w**2) * np.sin(w * t)
    inner = slice(100, -100)
    d1 = savgol(x, fs, 51, 3, deriv=1)
    d2 = savgol(x, fs, 101, 3, deriv=2)
    assert np.abs(d1 - dx)[inner].max() < 0.01 * w
    assert np.abs(d2 - ddx)[inner].max() < 0.05 * w**2
    raw = central_difference(central_difference(x, t), t)
    assert np.abs(raw - ddx)[inner].max() > 10 * np.abs(d2 - ddx)[inner].max()  # why one filters
    ma = moving_average(x, 11)
    assert np.abs(ma - np.sin(w * t))[inner].max() < 2e-3
    lw = lowess(x, t, frac=0.005)  # 25 samples: the curvature bias of a local line is ~2e-3 here
    assert np.abs(lw - np.sin(w * t))[inner].max() < 3e-3
    with pytest.raises(InputError):
        moving_average(x, 10)


def test_hexapod_pose_reconstruction_from_actuator_log():
    """Paper 004 §3.3: the platform pose of the hexapod rebuilt from quantized strut encoders
    (forward kinematics of every sample, then exact frequency-domain filtering and
    differentiation), against the analytic pose of a band-limited periodic motion."""
    from dynid.model.loop_kinematics import pose_states
    from dynid.model.robots import build_mechanism, hexapod
    from dynid.trajectories import FourierTrajectory

    f0, fs = 1.0, 500.0
    rng = np.random.default_rng(3)
    home = hexapod.HOME
    traj = FourierTrajectory.random(6, 3, f0, rng, home - 0.02, home + 0.02, max_velocity=0.05, max_acceleration=0.5)
    t = np.arange(int(fs / f0)) / fs  # one period
    pose, dpose, ddpose = traj.sample(t)
    mech = build_mechanism("hexapod")
    qa = hexapod.inverse_kinematics(pose)[:, list(mech.actuated)]
    qa = np.round(qa / 1e-6) * 1e-6  # 1 um linear encoders
    state, p_f, dp_f, ddp_f = pose_states(mech, qa, fs, cutoff_hz=3.5 * f0)
    assert np.abs(p_f - pose).max() < 1e-5  # m and rad
    assert np.abs(dp_f - dpose).max() < 0.01 * np.abs(dpose).max()
    assert np.abs(ddp_f - ddpose).max() < 0.05 * np.abs(ddpose).max()
    task = mech.in_task_space()
    assert np.abs(task.constraint_residual(state.q)).max() < 1e-10
    np.testing.assert_allclose(state.dq[:, list(task.independent.joints)], dp_f, atol=1e-12)
