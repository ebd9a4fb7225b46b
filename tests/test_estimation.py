"""Estimators on the compressed problem: exactness, recovery of known parameters within the
uncertainty they report, weighting, identifiability, physical consistency, persistence."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import sdp_norm_slack, seed
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation import OLS, WLS, IdentificationResult, PhysicalLS, ProblemBuilder, RegressionProblem
from dynid.model import StandardMap, load_robot, pseudo_inertia, regressor, robot_base_parameters
from dynid.simulation import FourierTrajectory

ROBOT = load_robot("builtin:puma560")
BASE = robot_base_parameters(ROBOT)
TRUTH = ROBOT.nominal_parameters()
BETA = BASE.from_standard(TRUTH)
SIGMA = np.array([1.0, 1.5, 0.6, 0.08, 0.08, 0.05])


def _trajectory(k=7, n=1500, fs=100.0, harmonics=5):
    rng = np.random.default_rng(seed(k))
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


def _coverage(estimator, sigma, trials=80):
    """Mean coverage of the 95 % intervals and mean chi^2 of the truth over ``trials`` noise draws,
    and the coverage's margin: 4.5 std of its mean (a false alarm of 7e-6). The 58 estimates are
    correlated, so a trial's covered fraction varies more than for independent ones (0.04-0.05 here,
    like 20-30 independent indicators): its std is integrated over z ~ N(0, R), R the estimates'
    correlation (an integral, not data: its own fixed seed). 80 trials: about +-0.02."""
    rng = np.random.default_rng(seed(11))
    inside, chi2 = [], []
    for _ in range(trials):
        res = estimator.fit(_problem(TAU + rng.standard_normal(TAU.shape) * sigma))
        ci = res.conf_int(0.05)
        inside.append((ci[:, 0] <= BETA) & (BETA <= ci[:, 1]))
        d = res.params - BETA
        chi2.append(d @ np.linalg.solve(res.cov_params, d))
    R = res.cov_params / np.outer(res.bse, res.bse)
    z = np.random.default_rng(0).multivariate_normal(np.zeros(len(BETA)), R, size=20000)
    margin = 4.5 * np.mean(np.abs(z) < 1.959964, axis=1).std() / np.sqrt(trials)
    return np.mean(inside), margin, np.mean(chi2)


# E chi^2 = p (times nu / (nu - 2) = 1.0002 for the estimated scale); the mean of 80 has a relative
# std of sqrt(2 / (80 p)) = 1.9 %: 0.15 is 8 of them


@pytest.mark.numerics
def test_ols_intervals_cover_truth_with_homoscedastic_noise():
    cover, margin, chi2 = _coverage(OLS(), 0.5)
    assert abs(cover - 0.95) < margin, (cover, margin)
    assert abs(chi2 / BASE.n_base - 1) < 0.15, chi2  # E[chi2] = p


@pytest.mark.numerics
def test_wls_intervals_cover_truth_with_per_joint_noise():
    cover, margin, chi2 = _coverage(WLS(), SIGMA)
    assert abs(cover - 0.95) < margin, (cover, margin)
    assert abs(chi2 / BASE.n_base - 1) < 0.15, chi2


def _ols_residual_std_law():
    """Mean and relative std of each joint's OLS residual std sqrt(rss_j / dof_j) under white noise of
    std SIGMA, exactly for this design: the joint's residuals e_j - W_j (b - beta) have the covariance
    K_j = sigma_j^2 (I - 2 W_j C W_j^T) + W_j C_b W_j^T (C = (W^T W)^-1, C_b the estimate's
    covariance), so E rss_j = tr K_j and var rss_j = 2 tr K_j^2 (the leak is correlated across rows)."""
    C = np.linalg.inv(np.einsum("nip,niq->pq", W, W))
    Cb = C @ np.einsum("nip,i,niq->pq", W, SIGMA**2, W) @ C
    mean, rel = np.zeros(6), np.zeros(6)
    for j in range(6):
        Wj = W[:, j]
        K = SIGMA[j] ** 2 * (np.eye(W.shape[0]) - 2 * Wj @ C @ Wj.T) + Wj @ Cb @ Wj.T
        mean[j], rel[j] = np.trace(K), np.sqrt(2 * np.sum(K * K)) / (2 * np.trace(K))
    return mean, rel


@pytest.mark.numerics
def test_wls_estimates_per_joint_noise_and_beats_ols():
    rng = np.random.default_rng(seed(3))
    prob = _problem(TAU + rng.standard_normal(TAU.shape) * SIGMA)
    wls, ols = WLS().fit(prob), OLS().fit(prob)
    # Gautier's sigma_j come from OLS residuals, in which parameter errors driven by the noisy
    # joints leak into the quiet ones: a few percent high on the wrist (the known bias of the method).
    # Held to its exact law (+1 % on the arm, +7-9 % on the wrist; relative std 1.8-5.3 %): within 4.5
    # std (7e-6 per joint). rtol 0.12 and >= 0.95 SIGMA were 0.6 and 2.6 std on the wrist
    rss, rel = _ols_residual_std_law()
    dof = prob.n_obs - prob.channel_ranks()
    expected = np.sqrt(rss / dof)
    assert np.all(expected >= SIGMA), expected / SIGMA  # the leak only adds
    assert np.all(np.abs(wls.noise_std / expected - 1) < 4.5 * rel), (wls.noise_std / expected - 1) / rel
    # the scale of the whitened residuals: each joint's WLS residual over its (leaky) weight, about
    # (sigma_j / expected_j)^2 on average (0.92 here: 0.88-0.95 over 6 draws); its std counts each weight's
    # own fluctuation, 2 rel_j in the variance (an upper bound: a joint's residuals move with its weight).
    # |scale - 1| < 0.12 was 1.8 std from that mean
    w = dof / dof.sum()
    ratio = (SIGMA / expected) ** 2
    sd = np.sqrt(np.sum((w * ratio * 2 * rel) ** 2))
    assert abs(wls.scale - np.sum(w * ratio)) < 4.5 * sd, (wls.scale, np.sum(w * ratio), sd)
    # weighting makes the well-measured wrist parameters much more precise (0.11 over 6 draws)
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


@pytest.mark.numerics
def test_physical_ls_equals_wls_when_no_constraint_is_active():
    rng = np.random.default_rng(seed(4))
    prob = _problem(TAU + rng.standard_normal(TAU.shape) * SIGMA * 0.01)
    phys, wls = PhysicalLS().fit(prob), WLS().fit(prob)
    # with the unconstrained optimum feasible, the SDP's cost is its gap squared (sdp_norm_slack(0)^2:
    # 1e-11 chi^2 with the tolerances loosened 10x, 1e-15 seen), far below the 1e-6 under which PhysicalLS
    # returns the WLS estimate itself (physical._UNCHANGED): equal to rounding, whatever the tolerances
    assert phys.solver["active_constraints"] == [], phys.solver["active_constraints"]
    np.testing.assert_allclose(phys.params, wls.params, atol=2e-5 * np.abs(wls.params).max())
    np.testing.assert_allclose(phys.cov_params, wls.cov_params)


@pytest.mark.numerics
def test_physical_ls_makes_an_infeasible_estimate_feasible():
    # little excitation and large noise: unconstrained WLS returns non-physical parameters
    q, dq, ddq = _trajectory(3, n=600, harmonics=3)
    Ws = BASE.regressor(regressor(ROBOT, q, dq, ddq))
    rng = np.random.default_rng(seed(5))
    y = Ws @ BETA + rng.standard_normal((600, 6)) * SIGMA * 8
    prob = _problem(y, W=Ws)
    wls = WLS().fit(prob)
    smap = prob.standard
    pi_wls = BASE.to_standard(wls.params, reference=smap.reference)
    assert min(np.linalg.eigvalsh(pseudo_inertia(pi_wls[b]))[0] for b in smap.body_blocks) < 0 or np.any(pi_wls[smap.nonnegative] < 0)
    phys = PhysicalLS().fit(prob)
    # Clarabel may stop short of tightened tolerances (InsufficientProgress: with them x0.01 on this
    # problem); PhysicalLS then returns its last iterate, constraints checked, as optimal_inaccurate
    assert phys.solver["status"] in ("optimal", "optimal_inaccurate"), phys.solver["status"]
    pi = np.array(list(phys.solver["standard_params"].values()))
    # the standard vector (tie-break towards the reference) gives the estimate up to its reported cost:
    # the tie-break solve could have kept the first solve's point, so its residual norm exceeds the
    # estimate's by at most weight x (the distance to the reference it gained), and falls below it by
    # neither more than the two solves' slack. That slack is Clarabel's on the objective ||A pi - d||:
    # its feasibility residual is relative to the data, |d| (150 here, against an optimum of 2.9), so
    # sdp_norm_slack of |d| (|d|^2 = beta_wls^T C^-1 beta_wls); with the tolerances loosened 10x the
    # tie-break's norm fell 5e-5 below the first solve's, 3.5x beyond sdp_norm_slack of the optimum's norm.
    # (0.05 x max(chi^2, 1) and -1e-6 held for one setting: -3e-4 chi^2 at 10x)
    st, first = phys.solver["stages"]["standard"], phys.solver["stages"]["sdp"]
    tb, inc = st["tie_break"], phys.solver["residual_increase_chi2"]
    d_norm = float(np.sqrt(wls.params @ np.linalg.solve(wls.cov_params, wls.params)))
    g = sdp_norm_slack(d_norm, first) + sdp_norm_slack(d_norm, st)
    up = np.sqrt(max(inc + st["residual_increase_chi2"], 0.0)) - np.sqrt(max(inc, 0.0))
    gain = tb["weight"] * (tb["reference_distance_before"] - tb["reference_distance_after"])
    assert -g <= up <= gain + g, (up, gain, g)
    # PhysicalLS checks its solution's constraints after the solve and widens its buffer until they
    # hold (dynid.estimation.physical): -1e-7 is eigvalsh's rounding, not the solver's tolerance
    assert min(phys.solver["min_pseudo_inertia_eigenvalue"]) > -1e-7
    assert np.all(pi[smap.nonnegative] > -1e-7)
    assert phys.cov_params is None and any("no covariance" in n for n in phys.notes)
    with pytest.raises(InputError, match="no covariance"):
        phys.bse  # noqa: B018
    # the constrained fit cannot fit the training data better than the unconstrained one (exact: the
    # rounding of the RSS sums; 4-8 chi^2 above it here)
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
