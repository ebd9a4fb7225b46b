"""Statistics of linear results: confidence ellipsoid (paper 002 Eq. 29), correlation matrix and
its condition number (paper 004 Eq. 11), prediction metrics of the papers (paper 000 Eqs. 33-34,
paper 001 Eq. 21), and their use on IdentificationResult."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import seed

from dynid.errors import InputError
from dynid.estimation import OLS, RegressionProblem
from dynid.stats import (
    average_error,
    chi2_radius,
    correlation_condition_number,
    correlation_matrix,
    ellipsoid_statistic,
    relative_absolute_error,
    t_rsme,
)


def _spd(p, rng, spread=3.0):
    """A covariance with correlated entries and scales over `spread` decades."""
    q, _ = np.linalg.qr(rng.standard_normal((p, p)))
    c = q @ np.diag(rng.uniform(0.2, 2.0, p)) @ q.T
    d = 10.0 ** rng.uniform(-spread / 2, spread / 2, p)
    return c * np.outer(d, d)


# ---------------------------------------------------------------------- chi-square ellipsoid
def test_chi2_radius_matches_paper_002():
    assert round(chi2_radius(24), 2) == 36.42  # paper 002 §4: chi2_5%(24) = 36.42
    assert chi2_radius(1) == pytest.approx(1.959964**2, rel=1e-6)
    assert chi2_radius(24, alpha=0.01) > chi2_radius(24)
    for bad in (0, -3, 2.5):
        with pytest.raises(InputError, match="n_params"):
            chi2_radius(bad)
    with pytest.raises(InputError, match="alpha"):
        chi2_radius(5, alpha=1.5)


@pytest.mark.numerics
def test_ellipsoid_statistic_of_gaussian_estimates_is_chi2_distributed():
    rng = np.random.default_rng(seed(1))
    p, k = 24, 4000
    cov = _spd(p, rng)
    truth = rng.standard_normal(p)
    draws = rng.multivariate_normal(truth, cov, size=k)
    stat = ellipsoid_statistic(draws, truth, cov)
    assert stat.shape == (k,)
    # E[chi2(p)] = p with std of the mean sqrt(2p/k) = 0.11 (0.5: 4.6 std); the sample variance has a
    # relative std of sqrt((2 + 12 / p) / k) = 2.5 % (0.1: 4 std, 6e-5); coverage 95 % +- 0.34 % (0.015: 4.4 std)
    assert abs(stat.mean() - p) < 0.5, stat.mean()
    assert abs(stat.var() / (2 * p) - 1) < 0.1, stat.var()
    assert abs(np.mean(stat <= chi2_radius(p)) - 0.95) < 0.015
    # the same number as the explicit quadratic form, also for one vector
    d = draws[0] - truth
    one = ellipsoid_statistic(draws[0], truth, cov)
    assert isinstance(one, float)
    assert one == pytest.approx(d @ np.linalg.solve(cov, d), rel=1e-9)


def test_ellipsoid_statistic_rejects_bad_shapes_and_singular_covariance():
    cov = np.diag([1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="reference"):
        ellipsoid_statistic(np.zeros(3), np.zeros(2), cov)
    with pytest.raises(InputError, match="estimate"):
        ellipsoid_statistic(np.zeros(4), np.zeros(3), cov)
    with pytest.raises(InputError, match="square"):
        ellipsoid_statistic(np.zeros(3), np.zeros(3), np.zeros((3, 2)))
    singular = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(InputError, match="singular"):
        ellipsoid_statistic(np.ones(3), np.zeros(3), singular)


# ---------------------------------------------------------------------- correlation
def test_correlation_condition_number_of_a_known_covariance():
    rho = np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 1.0]])
    d = np.array([1e-3, 50.0, 2.0])  # very different units: cond(rho) does not see them
    cov = rho * np.outer(d, d)
    np.testing.assert_allclose(correlation_matrix(cov), rho, atol=1e-15)
    # eigenvalues of rho: 1.9, 1, 0.1 -> 19
    assert correlation_condition_number(cov) == pytest.approx(19.0, rel=1e-12)
    assert correlation_condition_number(np.diag([4.0, 1e-6, 9.0])) == pytest.approx(1.0)
    with pytest.raises(InputError, match="non-positive variances at indices \\[1\\]"):
        correlation_matrix(np.diag([1.0, 0.0, 2.0]))


# ---------------------------------------------------------------------- prediction metrics
def test_relative_absolute_error_paper_000_eq_33():
    tau = np.array([[1.0, 10.0], [2.0, 12.0], [3.0, 8.0], [4.0, 10.0]])
    pred = np.array([[1.5, 11.0], [2.0, 12.0], [2.5, 8.0], [4.0, 9.0]])
    # column 1: sum|err| = 1, mean 2.5, sum|tau - mean| = 1.5+.5+.5+1.5 = 4 -> 25 %
    # column 2: sum|err| = 2, mean 10, sum|tau - mean| = 0+2+2+0 = 4 -> 50 %
    np.testing.assert_allclose(relative_absolute_error(tau, pred), [25.0, 50.0])
    assert relative_absolute_error(tau, pred, pooled=True) == pytest.approx(100 * 3 / 8)
    assert relative_absolute_error(tau[:, 0], pred[:, 0]) == pytest.approx(25.0)
    # independent formula on random data
    rng = np.random.default_rng(2)
    a, b = rng.standard_normal((50, 3)), rng.standard_normal((50, 3))
    expect = [100 * np.abs(a[:, j] - b[:, j]).sum() / np.abs(a[:, j] - a[:, j].mean()).sum() for j in range(3)]
    np.testing.assert_allclose(relative_absolute_error(a, b), expect)
    # perfect prediction 0 %, the constant mean 100 %
    assert np.all(relative_absolute_error(a, a) == 0)
    np.testing.assert_allclose(relative_absolute_error(a, np.broadcast_to(a.mean(axis=0), a.shape)), 100.0)
    with pytest.raises(InputError, match="constant"):
        relative_absolute_error(np.ones((5, 2)), np.zeros((5, 2)))
    with pytest.raises(InputError, match="differ in shape"):
        relative_absolute_error(a, b[:-1])


def test_average_error_paper_000_eq_34():
    exact = np.array([2.0, -4.0, 0.5])
    ident = np.array([2.2, -3.0, 0.5])
    # (0.2/2 + 1/4 + 0) / 3 = 0.116667 -> 11.67 %
    assert average_error(exact, ident) == pytest.approx(100 * (0.1 + 0.25) / 3)
    with pytest.raises(InputError, match="indices \\[1\\]"):
        average_error([1.0, 0.0], [1.0, 0.1])
    with pytest.raises(InputError):
        average_error([1.0, 2.0], [1.0])


def test_t_rsme_paper_001_eq_21():
    tau_a = np.array([[1.0, 0.0], [2.0, 3.0], [3.0, 4.0]])
    tau_c = np.array([[0.0, 0.0], [3.0, 0.0], [2.0, 0.0]])
    # errors column 1: 1, -1, 1 -> 1; column 2: 0, 3, 4 -> sqrt(25/3)
    np.testing.assert_allclose(t_rsme(tau_a, tau_c), [1.0, np.sqrt(25 / 3)])
    assert t_rsme(tau_a[:, 1], tau_c[:, 1]) == pytest.approx(np.sqrt(25 / 3))
    with pytest.raises(InputError, match="NaN"):
        t_rsme([1.0, np.nan], [1.0, 2.0])


# ---------------------------------------------------------------------- on results
def _linear_problem(rng, theta, n=200, sigma=0.5):
    W = rng.standard_normal((n, 2, theta.size)) * np.array([1.0, 3.0, 0.2, 1.0, 0.5])
    W[:, :, 3] += 0.8 * W[:, :, 0]  # correlated columns
    y = W @ theta + sigma * rng.standard_normal((n, 2))
    return RegressionProblem.from_arrays(W, y, [f"p{i}" for i in range(theta.size)])


@pytest.mark.numerics
def test_result_chi2_statistic_covers_the_truth_95_percent():
    rng = np.random.default_rng(seed(3))
    theta = np.array([1.0, -0.5, 2.0, 0.3, -1.0])
    stats, inside = [], []
    trials = 1600
    for _ in range(trials):
        res = OLS().fit(_linear_problem(rng, theta))
        stats.append(res.chi2_statistic(theta))
        inside.append(res.in_confidence_ellipsoid(theta))
    # estimated noise scale: p * F(p, 395), mean 5.03 and variance 10.3 (std of the mean of 1600: 0.08;
    # 0.6 is 7 of them); coverage of the chi2 ellipsoid P(F(p, 395) <= chi2_radius(p) / p) = 94.8 %, a
    # binomial std of 0.56 % over 1600 trials: within 4.5 of them (7e-6). (0.92-0.98 over 400 trials
    # was 2.75 std, a 6e-3 false alarm)
    from scipy.stats import f

    assert abs(np.mean(stats) - 5.0) < 0.6, np.mean(stats)
    cover = f.cdf(chi2_radius(5) / 5, 5, res.dof)
    assert abs(np.mean(inside) - cover) < 4.5 * np.sqrt(cover * (1 - cover) / trials), (np.mean(inside), cover)


def test_result_statistics_summary_and_missing_covariance():
    rng = np.random.default_rng(4)
    theta = np.array([1.0, -0.5, 2.0, 0.3, -1.0])
    res = OLS().fit(_linear_problem(rng, theta))
    d = res.params - theta
    assert res.chi2_statistic(theta) == pytest.approx(d @ np.linalg.solve(res.cov_params, d), rel=1e-9)
    assert res.chi2_statistic(dict(zip(res.names, theta))) == pytest.approx(res.chi2_statistic(theta))
    assert res.in_confidence_ellipsoid(res.params)
    assert not res.in_confidence_ellipsoid(res.params + 10 * res.bse)
    s = np.sqrt(np.diag(res.cov_params))
    expect = np.linalg.cond(res.cov_params / np.outer(s, s))
    assert res.correlation_condition_number == pytest.approx(expect, rel=1e-9)
    assert res.correlation_condition_number > 1.5  # p0 and p3 are correlated
    text = str(res.summary())
    assert f"correlation cond. number : {res.correlation_condition_number:.4g}" in text
    with pytest.raises(InputError, match="reference"):
        res.chi2_statistic(theta[:3])
    with pytest.raises(InputError, match="lacks parameters"):
        res.chi2_statistic({"p0": 1.0})
    bare = dataclasses.replace(res, cov_params=None)
    for call in (lambda: bare.chi2_statistic(theta), lambda: bare.in_confidence_ellipsoid(theta),
                 lambda: bare.correlation_condition_number):
        with pytest.raises(InputError, match="gives no covariance"):
            call()
    assert "correlation cond" not in str(bare.summary())
