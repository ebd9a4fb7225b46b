"""Signal processing: zero-phase Butterworth, central differences, resampling, decimation.

Expected values come from closed-form results (the bilinear Butterworth magnitude, the
exact central-difference error on a sinusoid, interpolation error bounds), never from
the code's own output.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import seed
from scipy import signal as sps

from dynid.errors import InputError
from dynid.signals import (
    butter_sos,
    central_difference,
    decimate,
    derivatives,
    lowpass,
    padlen_for,
    resample_uniform,
)


def tone(f_hz: float, fs: float, duration: float, phase: float = 0.0):
    t = np.arange(int(round(duration * fs))) / fs
    return t, np.sin(2 * np.pi * f_hz * t + phase)


def fit_tone(t, y, f_hz: float) -> tuple[float, float]:
    """Amplitude and phase [rad] of the ``f_hz`` component by least squares."""
    w = 2 * np.pi * f_hz
    A = np.column_stack([np.sin(w * t), np.cos(w * t)])
    (s, c), *_ = np.linalg.lstsq(A, y, rcond=None)
    return float(np.hypot(s, c)), float(np.arctan2(c, s))


def middle(n: int, edge: int) -> slice:
    return slice(edge, n - edge)


def zero_phase_gain(f_hz, cutoff_hz, fs, order):
    """|H(f)|^2 of a digital Butterworth designed by the prewarped bilinear transform."""
    ratio = np.tan(np.pi * np.asarray(f_hz) / fs) / np.tan(np.pi * cutoff_hz / fs)
    return 1.0 / (1.0 + ratio ** (2 * order))


# ---------------------------------------------------------------------- lowpass
class TestLowpass:
    FS, FC, ORDER = 1000.0, 25.0, 4

    def filtered_amplitude(self, f_hz, fs=FS, fc=FC, order=ORDER):
        t, x = tone(f_hz, fs, duration=max(40.0 / f_hz, 4.0), phase=0.3)
        y = lowpass(x, fc, fs, order)
        keep = middle(t.size, padlen_for(order, fc, fs))
        return fit_tone(t[keep], y[keep], f_hz), fit_tone(t[keep], x[keep], f_hz)

    def test_cutoff_is_minus_6_db_for_the_zero_phase_pair(self):
        (amp, phase), (_, phase_in) = self.filtered_amplitude(self.FC)
        assert amp == pytest.approx(0.5, rel=0.01)  # single pass -3 dB, squared
        assert abs(phase - phase_in) < 1e-3  # zero phase: no delay at all

    def test_passband_and_stopband(self):
        (amp2, ph2), (_, ph2_in) = self.filtered_amplitude(2.0)
        assert 0.99 < amp2 <= 1.0 + 1e-9
        assert abs(ph2 - ph2_in) < 1e-3
        (amp100, _), _ = self.filtered_amplitude(100.0)
        assert amp100 < 1e-3
        # 4th order, two passes: 2 x 24 dB/octave, so 100 Hz = 2 octaves above 25 Hz is ~ -96 dB
        assert amp100 == pytest.approx(zero_phase_gain(100.0, self.FC, self.FS, self.ORDER), rel=0.05)

    @pytest.mark.parametrize("f_hz", [5.0, 15.0, 25.0, 40.0, 60.0])
    def test_measured_gain_matches_bilinear_butterworth(self, f_hz):
        (amp, _), _ = self.filtered_amplitude(f_hz)
        expected = zero_phase_gain(f_hz, self.FC, self.FS, self.ORDER)
        assert amp == pytest.approx(expected, rel=0.01, abs=1e-6)

    @pytest.mark.parametrize("fs", [500.0, 5000.0])
    def test_cutoff_is_in_hz_whatever_the_sampling_rate(self, fs):
        # A cut-off normalised by hand as ts*fc/2 would quarter the cut-off (and move with fs).
        sos = butter_sos(self.ORDER, self.FC, fs)
        f = np.array([0.25, 0.5, 1.0]) * self.FC
        _, h = sps.sosfreqz(sos, worN=f, fs=fs)
        np.testing.assert_allclose(np.abs(h) ** 2, zero_phase_gain(f, self.FC, fs, self.ORDER), rtol=1e-9)
        for f_hz, expected in ((self.FC, 0.5), (0.5 * self.FC, 1.0)):
            (amp, _), _ = self.filtered_amplitude(f_hz, fs=fs)
            assert amp == pytest.approx(expected, rel=0.01)

    def test_channels_are_filtered_independently_on_the_time_axis(self):
        fs = 1000.0
        t, slow = tone(2.0, fs, 4.0)
        _, fast = tone(100.0, fs, 4.0)
        x = np.column_stack([slow, fast])
        y = lowpass(x, 25.0, fs)
        keep = middle(t.size, padlen_for(4, 25.0, fs))
        assert fit_tone(t[keep], y[keep, 0], 2.0)[0] > 0.99
        assert np.max(np.abs(y[keep, 1])) < 1e-3
        np.testing.assert_allclose(lowpass(x.T, 25.0, fs, axis=1), y.T, atol=1e-12)

    def test_dc_passes_exactly_and_ramp_transients_die_within_padlen(self):
        # DC gain is 1 and the initial state is the step steady state: a constant is exact.
        np.testing.assert_allclose(lowpass(np.full(500, 2.5), 5.0, 100.0), 2.5, rtol=1e-12)
        # A ramp starts with an edge transient; padlen_for (5 time constants, what the
        # pipeline trims) leaves less than 1e-3 of it.
        t = np.arange(500) / 100.0
        x = 3.0 - 0.7 * t
        err = np.abs(lowpass(x, 5.0, 100.0) - x)
        p = padlen_for(4, 5.0, 100.0)
        assert err[0] > 1e-4  # there is a transient to remove
        assert np.max(err[p:-p]) < 1e-3 * np.max(err)

    def test_too_short_signal(self):
        with pytest.raises(InputError, match="3 samples is too short"):
            lowpass(np.ones(3), 5.0, 100.0)


class TestButterSos:
    @pytest.mark.parametrize("cutoff", [50.0, 60.0, 0.0, -1.0, float("nan")])
    def test_cutoff_outside_open_interval(self, cutoff):
        with pytest.raises(InputError, match=r"cut-off .* must lie in \(0, fs/2\) = \(0, 50\) Hz"):
            butter_sos(4, cutoff, 100.0)

    @pytest.mark.parametrize("order", [0, -2])
    def test_order_below_one(self, order):
        with pytest.raises(InputError, match="filter order must be >= 1"):
            butter_sos(order, 5.0, 100.0)

    @pytest.mark.parametrize("fs", [0.0, -100.0, float("inf")])
    def test_bad_sampling_rate(self, fs):
        with pytest.raises(InputError, match="sampling rate fs must be positive and finite"):
            butter_sos(4, 5.0, fs)

    def test_number_of_sections(self):
        assert butter_sos(4, 5.0, 100.0).shape == (2, 6)
        assert butter_sos(5, 5.0, 100.0).shape == (3, 6)


# ---------------------------------------------------------------------- differentiation
class TestCentralDifference:
    F, FS = 2.0, 200.0

    def test_interior_error_is_the_exact_central_difference_error(self):
        # (sin(w(t+h)) - sin(w(t-h))) / 2h = w cos(wt) * sin(wh)/(wh): error <= w^3 h^2 / 6
        t, x = tone(self.F, self.FS, 3.0)
        w, h = 2 * np.pi * self.F, 1.0 / self.FS
        err = central_difference(x, h)[1:-1] - w * np.cos(w * t[1:-1])
        np.testing.assert_allclose(err, w * np.cos(w * t[1:-1]) * (np.sin(w * h) / (w * h) - 1), atol=1e-9)
        bound = w**3 * h**2 / 6
        assert np.max(np.abs(err)) <= bound
        assert np.max(np.abs(err)) > 0.99 * bound  # second order, not better

    def test_second_order_convergence(self):
        w = 2 * np.pi * self.F
        errs = []
        for fs in (100.0, 200.0, 400.0):
            t, x = tone(self.F, fs, 2.0)
            errs.append(np.max(np.abs(central_difference(x, t) - w * np.cos(w * t))))
        assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.05)
        assert errs[1] / errs[2] == pytest.approx(4.0, rel=0.05)

    def test_end_samples_are_second_order_one_sided(self):
        # 3-point one-sided difference: error h^2/3 |x'''|, so <= w^3 h^2 / 3
        t, x = tone(self.F, self.FS, 1.0, phase=0.4)
        w, h = 2 * np.pi * self.F, 1.0 / self.FS
        d = central_difference(x, h)
        exact = w * np.cos(w * t + 0.4)
        assert abs(d[0] - exact[0]) <= w**3 * h**2 / 3
        assert abs(d[-1] - exact[-1]) <= w**3 * h**2 / 3

    @pytest.mark.numerics
    def test_with_noise(self):
        # Noise sigma on x becomes sigma / (sqrt(2) h) on the interior derivative. Asserted:
        # the noise part has that standard deviation within 5 % (6000 samples of an MA(2) noise,
        # lag-2 correlation -1/2: var(s^2) = (2 / n)(1 + 2 x 1/4) s^4, a relative std of 1.1 % on s;
        # 5 % is 4.5 of them) and every interior error is below truncation bound + 5.5 such standard
        # deviations (the largest of 6000 normal draws: a false alarm of 6000 x 3.8e-8 = 2e-4; 5 was 3e-3)
        rng = np.random.default_rng(seed(12))
        sigma = 1e-5
        t, x = tone(self.F, self.FS, 30.0)
        w, h = 2 * np.pi * self.F, 1.0 / self.FS
        d = central_difference(x + sigma * rng.standard_normal(x.shape), t)[1:-1]
        noise = d - central_difference(x, t)[1:-1]
        sd = sigma / (np.sqrt(2) * h)
        assert np.std(noise) == pytest.approx(sd, rel=0.05)
        assert np.max(np.abs(d - w * np.cos(w * t[1:-1]))) < w**3 * h**2 / 6 + 5.5 * sd

    def test_time_array_equals_period_for_uniform_sampling(self):
        t, x = tone(self.F, self.FS, 1.0)
        X = np.column_stack([x, 2 * x])
        np.testing.assert_allclose(central_difference(X, t), central_difference(X, 1 / self.FS), rtol=1e-9, atol=1e-9)

    def test_irregular_sampling_is_exact_for_a_quadratic(self):
        rng = np.random.default_rng(3)
        t = np.cumsum(rng.uniform(0.005, 0.015, 200))
        x = 1.5 * t**2 - 0.3 * t + 2.0
        np.testing.assert_allclose(central_difference(x, t), 3.0 * t - 0.3, rtol=1e-9, atol=1e-9)

    def test_needs_three_samples(self):
        with pytest.raises(InputError, match="at least 3 samples, got 2"):
            central_difference(np.ones(2), 0.01)


def test_derivatives_of_a_sine():
    # repeated central differences: ddq[i] = (x[i+2] - 2x[i] + x[i-2]) / (4h^2)
    #                                       = -sin(wt) * (sin(wh)/h)^2 exactly for a sine
    f, fs = 1.5, 250.0
    t, q = tone(f, fs, 2.0)
    w, h = 2 * np.pi * f, 1.0 / fs
    dq, ddq = derivatives(q, t)
    np.testing.assert_allclose(dq[1:-1], w * np.cos(w * t[1:-1]) * np.sin(w * h) / (w * h), atol=1e-9)
    np.testing.assert_allclose(ddq[2:-2], -np.sin(w * t[2:-2]) * (np.sin(w * h) / h) ** 2, atol=1e-7)
    assert np.max(np.abs(ddq[2:-2] + w**2 * np.sin(w * t[2:-2]))) <= w**4 * h**2 / 3


# ---------------------------------------------------------------------- resampling
def irregular_time(n=400, dt=0.01, jitter=0.3, seed=5):
    rng = np.random.default_rng(seed)
    return 0.2 + np.cumsum(dt * (1 + jitter * rng.uniform(-1, 1, n)))


class TestResampleUniform:
    def test_grid(self):
        t = irregular_time()
        t_new, _ = resample_uniform(t, np.zeros_like(t), fs=50.0)
        assert t_new[0] == t[0]
        np.testing.assert_allclose(np.diff(t_new), 0.02, rtol=1e-9)
        assert t_new[-1] <= t[-1] < t_new[-1] + 0.02

    def test_default_rate_is_the_median_rate(self):
        t = np.array([0.0, 0.1, 0.2, 0.25, 0.4, 0.5, 0.6])  # median period 0.1
        t_new, _ = resample_uniform(t, t)
        np.testing.assert_allclose(t_new, np.arange(7) * 0.1, atol=1e-12)

    def test_linear_interpolation_is_exact_for_linear_signals(self):
        t = irregular_time()
        x = np.column_stack([2.0 - 3.0 * t, 0.5 * t, np.full_like(t, 7.0)])
        t_new, x_new = resample_uniform(t, x, fs=137.0)
        assert x_new.shape == (t_new.size, 3)
        np.testing.assert_allclose(x_new, np.column_stack([2.0 - 3.0 * t_new, 0.5 * t_new, np.full_like(t_new, 7.0)]), atol=1e-12)

    def test_cubic_spline_is_accurate_for_smooth_signals(self):
        # not-a-knot spline error ~ (5/384) h^4 |x''''| = 0.013 * (0.013)^4 * (2 pi)^4 ~ 6e-7
        t = irregular_time()
        x = np.sin(2 * np.pi * 1.0 * t)
        t_new, x_cub = resample_uniform(t, x, fs=100.0, kind="cubic")
        _, x_lin = resample_uniform(t, x, fs=100.0, kind="linear")
        exact = np.sin(2 * np.pi * t_new)
        assert np.max(np.abs(x_cub - exact)) < 2e-6
        # linear: h^2/8 |x''| ~ 8e-4, so cubic is far better on the same grid
        assert np.max(np.abs(x_lin - exact)) > 100 * np.max(np.abs(x_cub - exact))

    @pytest.mark.parametrize(
        "t",
        [np.array([0.0, 0.1, 0.1, 0.3]), np.array([0.0, 0.2, 0.1, 0.3]), np.array([0.0, np.nan, 0.2, 0.3])],
        ids=["repeated", "backwards", "nan"],
    )
    def test_non_monotonic_time(self, t):
        with pytest.raises(InputError, match="time is not strictly increasing"):
            resample_uniform(t, np.arange(4.0), fs=10.0)

    def test_bad_arguments(self):
        t = np.arange(5.0)
        with pytest.raises(InputError, match="mismatched lengths"):
            resample_uniform(t, np.arange(4.0))
        with pytest.raises(InputError, match="unknown interpolation kind 'quadratic'"):
            resample_uniform(t, t, kind="quadratic")
        with pytest.raises(InputError, match="resampling rate must be positive"):
            resample_uniform(t, t, fs=-1.0)


# ---------------------------------------------------------------------- decimation
class TestDecimate:
    FS, K = 1000.0, 10

    def test_keeps_one_in_k_and_removes_aliases(self):
        t, slow = tone(5.0, self.FS, 4.0)
        _, fast = tone(80.0, self.FS, 4.0)  # above the new Nyquist 50 Hz: would alias to 20 Hz
        x = slow + fast
        y = decimate(x, self.K, self.FS)
        t_k = t[:: self.K]
        assert y.shape == t_k.shape == (400,)
        keep = middle(t_k.size, 20)
        # naive subsampling shows the alias at 100 - 80 = 20 Hz with full amplitude
        assert fit_tone(t_k[keep], x[:: self.K][keep], 20.0)[0] == pytest.approx(1.0, rel=1e-6)
        assert fit_tone(t_k[keep], y[keep], 20.0)[0] < 1e-3
        amp5, _ = fit_tone(t_k[keep], y[keep], 5.0)
        assert amp5 == pytest.approx(1.0, rel=0.01)
        np.testing.assert_allclose(y[keep], slow[:: self.K][keep], atol=0.01)

    def test_rate_only_sets_units(self):
        rng = np.random.default_rng(1)
        x = rng.standard_normal((300, 2))
        np.testing.assert_allclose(decimate(x, 3, fs=250.0), decimate(x, 3), atol=1e-12)
        np.testing.assert_allclose(decimate(x.T, 3, axis=1), decimate(x, 3).T, atol=1e-12)
        assert decimate(x, 3).shape == (100, 2)

    def test_factor_one_is_a_copy(self):
        x = np.arange(10.0)
        y = decimate(x, 1)
        np.testing.assert_array_equal(y, x)
        y[0] = 99.0
        assert x[0] == 0.0

    def test_bad_factor(self):
        with pytest.raises(InputError, match="decimation factor must be >= 1, got 0"):
            decimate(np.arange(10.0), 0)
