"""Estimators on the compressed problem: exactness, recovery of known parameters within the
uncertainty they report, weighting, identifiability, physical consistency, persistence."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation import OLS, WLS, IdentificationResult, PhysicalLS, ProblemBuilder, RegressionProblem
from dynid.model import StandardMap, load_robot, pseudo_inertia, regressor, robot_base_parameters
from dynid.simulation import FourierTrajectory

ROBOT = load_robot("builtin:puma560")
BASE = robot_base_parameters(ROBOT)
TRUTH = ROBOT.nominal_parameters()
BETA = BASE.from_standard(TRUTH)
SIGMA = np.array([1.0, 1.5, 0.6, 0.08, 0.08, 0.05])


def _trajectory(seed=7, n=1500, fs=100.0, harmonics=5):
    rng = np.random.default_rng(seed)
    lo, hi = ROBOT.position_limits()
    traj = FourierTrajectory.random(6, harmonics, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    return traj.sample(np.arange(n) / fs)


Q, DQ, DDQ = _trajectory()
W = BASE.regressor(regressor(ROBOT, Q, DQ, DDQ))  # (n, 6, 58), exact states
TAU = W @ BETA


def _problem(y, W=W, chunk=None, mask=None):
    b = ProblemBuilder(BASE.names, ROBOT.joint_names)
    n = W.shape[0]
    step = chunk or n
    for s in range(0, n, step):
        b.add(W[s : s + step], y[s : s + step], None if mask is None else mask[s : s + step])
    return b.build(expressions=BASE.expressions(), standard=StandardMap.of(ROBOT, BASE))


def test_compressed_equals_direct_least_squares_for_any_chunking():
    rng = np.random.default_rng(0)
    y = TAU + rng.standard_normal(TAU.shape) * SIGMA
    mask = rng.random(y.shape) > 0.2  # drop 20 % of rows per joint equation
    direct_A = np.vstack([W[mask[:, j], j, :] for j in range(6)])
    direct_b = np.concatenate([y[mask[:, j], j] for j in range(6)])
    direct = np.linalg.lstsq(direct_A, direct_b, rcond=None)[0]
    for chunk in (None, 97, 500):
        prob = _problem(y, chunk=chunk, mask=mask)
        est = OLS().fit(prob)
        np.testing.assert_allclose(est.params, direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())
        rss_direct = [np.sum((y[mask[:, j], j] - W[mask[:, j], j, :] @ direct) ** 2) for j in range(6)]
        np.testing.assert_allclose(est.rss_per_channel, rss_direct, rtol=1e-8)
        assert list(est.n_obs) == list(mask.sum(axis=0))


def _coverage(estimator, sigma, trials=30):
    rng = np.random.default_rng(11)
    inside, chi2 = [], []
    for _ in range(trials):
        res = estimator.fit(_problem(TAU + rng.standard_normal(TAU.shape) * sigma))
        ci = res.conf_int(0.05)
        inside.append((ci[:, 0] <= BETA) & (BETA <= ci[:, 1]))
        d = res.params - BETA
        chi2.append(d @ np.linalg.solve(res.cov_params, d))
    return np.mean(inside), np.mean(chi2)


def test_ols_intervals_cover_truth_with_homoscedastic_noise():
    cover, chi2 = _coverage(OLS(), 0.5)
    assert 0.93 <= cover <= 0.97, cover
    assert abs(chi2 / BASE.n_base - 1) < 0.15, chi2  # E[chi2] = p


def test_wls_intervals_cover_truth_with_per_joint_noise():
    cover, chi2 = _coverage(WLS(), SIGMA)
    assert 0.93 <= cover <= 0.97, cover
    assert abs(chi2 / BASE.n_base - 1) < 0.15, chi2


def test_wls_estimates_per_joint_noise_and_beats_ols():
    rng = np.random.default_rng(3)
    prob = _problem(TAU + rng.standard_normal(TAU.shape) * SIGMA)
    wls, ols = WLS().fit(prob), OLS().fit(prob)
    # Gautier's sigma_j come from OLS residuals, in which parameter errors driven by the noisy
    # joints leak into the quiet ones: a few percent high on the wrist (the known bias of the method)
    np.testing.assert_allclose(wls.noise_std, SIGMA, rtol=0.12)
    assert np.all(wls.noise_std >= 0.95 * SIGMA)
    assert abs(wls.scale - 1) < 0.12
    # weighting makes the well-measured wrist parameters much more precise
    wrist = [i for i, n in enumerate(BASE.names) if n.endswith(("5", "6"))]
    assert np.median(wls.bse[wrist] / ols.bse[wrist]) < 0.5


def test_identifiability_error_names_parameters():
    still = W.copy()
    dq_col = [i for i, n in enumerate(BASE.names) if n in ("fv6", "fc6", "Ia6")]
    still[:, :, dq_col] = 0.0  # as if joint 6 never moved
    with pytest.raises(IdentifiabilityError) as err:
        OLS().fit(_problem(TAU, W=still))
    assert set(err.value.names) == {"Ia6", "fv6", "fc6"}
    assert "Ia6" in str(err.value) and "\n" not in str(err.value)


def test_too_few_samples():
    with pytest.raises((InputError, IdentifiabilityError)):
        OLS().fit(_problem(TAU[:5], W=W[:5]))


def test_physical_ls_equals_wls_when_no_constraint_is_active():
    rng = np.random.default_rng(4)
    prob = _problem(TAU + rng.standard_normal(TAU.shape) * SIGMA * 0.01)
    phys, wls = PhysicalLS().fit(prob), WLS().fit(prob)
    assert phys.solver["active_constraints"] == [], phys.solver["active_constraints"]
    np.testing.assert_allclose(phys.params, wls.params, atol=2e-5 * np.abs(wls.params).max())
    np.testing.assert_allclose(phys.cov_params, wls.cov_params)


def test_physical_ls_makes_an_infeasible_estimate_feasible():
    # little excitation and large noise: unconstrained WLS returns non-physical parameters
    q, dq, ddq = _trajectory(seed=3, n=600, harmonics=3)
    Ws = BASE.regressor(regressor(ROBOT, q, dq, ddq))
    rng = np.random.default_rng(5)
    y = Ws @ BETA + rng.standard_normal((600, 6)) * SIGMA * 8
    prob = _problem(y, W=Ws)
    wls = WLS().fit(prob)
    smap = prob.standard
    pi_wls = BASE.to_standard(wls.params, reference=smap.reference)
    assert min(np.linalg.eigvalsh(pseudo_inertia(pi_wls[b]))[0] for b in smap.body_blocks) < 0 or np.any(pi_wls[smap.nonnegative] < 0)
    phys = PhysicalLS().fit(prob)
    assert phys.solver["status"] == "optimal"
    pi = np.array(list(phys.solver["standard_params"].values()))
    # the standard vector (tie-break towards the reference) gives the estimate up to its reported cost
    extra = phys.solver["stages"]["standard"]["residual_increase_chi2"]
    assert -1e-6 <= extra <= 0.05 * max(phys.solver["residual_increase_chi2"], 1.0)
    assert min(phys.solver["min_pseudo_inertia_eigenvalue"]) > -1e-7
    assert np.all(pi[smap.nonnegative] > -1e-7)
    assert phys.cov_params is None and any("no covariance" in n for n in phys.notes)
    with pytest.raises(InputError, match="no covariance"):
        phys.bse  # noqa: B018
    # the constrained fit cannot fit the training data better than the unconstrained one
    assert np.sum(phys.rss_per_channel / wls.noise_std**2) >= np.sum(wls.rss_per_channel / wls.noise_std**2) - 1e-6


def test_physical_ls_requires_the_standard_map():
    rng = np.random.default_rng(0)
    prob = _problem(TAU + rng.standard_normal(TAU.shape)).replace(standard=None)
    with pytest.raises(InputError, match="standard parameters"):
        PhysicalLS().fit(prob)


def test_result_statistics_save_load_and_summary(tmp_path):
    rng = np.random.default_rng(8)
    res = WLS().fit(_problem(TAU + rng.standard_normal(TAU.shape) * SIGMA))
    from scipy import stats

    t = stats.t.ppf(0.975, res.dof)
    np.testing.assert_allclose(res.conf_int(), np.column_stack([res.params - t * res.bse, res.params + t * res.bse]))
    np.testing.assert_allclose(res.rel_std, 100 * res.bse / np.abs(res.params))
    res.save(tmp_path / "r", extra={"validation": {"rmse": [1.0, 2.0]}})
    back = IdentificationResult.load(tmp_path / "r.json")
    np.testing.assert_array_equal(back.params, res.params)
    np.testing.assert_array_equal(back.cov_params, res.cov_params)
    assert back.names == res.names and back.method == "WLS" and back.expressions == res.expressions
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["validation"] == {"rmse": [1.0, 2.0]}
    rec = doc["params"][0]
    assert set(rec) >= {"name", "value", "std", "rel_std_pct", "ci_low", "ci_high"}
    text = str(res.summary())
    assert "WLS" in text and "Izz1" in text and "condition number" in text
    assert "<table>" in res._repr_html_()
    frame = res.to_frame()
    assert list(frame.columns[:5]) == ["value", "std", "rel_std_pct", "ci_low", "ci_high"]
    with pytest.raises(InputError, match="not found"):
        IdentificationResult.load(tmp_path / "missing.json")


def test_problem_rejects_inconsistent_chunks():
    b = ProblemBuilder(BASE.names, ROBOT.joint_names)
    with pytest.raises(InputError):
        b.add(W[:10], TAU[:9])
    bad = TAU[:10].copy()
    bad[3, 2] = np.nan
    with pytest.raises(InputError, match="NaN"):
        b.add(W[:10], bad)
    assert isinstance(_problem(TAU), RegressionProblem)
