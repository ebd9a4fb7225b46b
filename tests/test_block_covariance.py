"""Block-robust covariances of least-squares estimates (issue 17, item 2, second part):
:mod:`dynid.estimation.block_covariance` and ``[identification] covariance``.

A linear model with known parameters and slowly varying regressors on two channels; the noise is
AR(1) in time (``e_t = phi e_{t-1} + a_t``) or white. For a fixed design the true covariance of
the (weighted) least-squares estimate is exact, :math:`A^{-1} W^T\\Lambda\\Sigma\\Lambda W A^{-1}`
with the AR(1) Toeplitz :math:`\\Sigma`, so the reported standard errors are compared with the
truth itself, not with another Monte Carlo. The margins come from the method: averaged over
``D`` draws the block estimate of the variance has a relative sampling error of about
:math:`\\sqrt{2/(B D)}` (B blocks), and its bias is the correlation beyond the neighbouring block,
:math:`O(\\phi^{\\ell}/(1-\\phi))` for blocks of :math:`\\ell` samples.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import seed
from dynid.config import parse_config
from dynid.errors import ConfigError, InputError
from dynid.estimation import OLS, WLS, ProblemBuilder
from dynid.estimation.block_covariance import BlockBuilder, block_covariance, default_blocks, robust_result
from dynid.pipeline import identify, write_outputs

N, PHI, SIGMA = 2000, 0.8, (0.5, 2.0)
NAMES = ("a", "b", "c", "d")
TRUTH = np.array([1.0, -0.5, 2.0, 0.3])


def _design() -> np.ndarray:
    """Regressor (N, 2, 4): slowly varying columns (periods of 200-700 samples) on two channels."""
    t = np.arange(N)
    s1, c1, s2 = np.sin(2 * np.pi * t / 700), np.cos(2 * np.pi * t / 450), np.sin(2 * np.pi * t / 230 + 0.4)
    W = np.zeros((N, 2, 4))
    W[:, 0] = np.column_stack([np.ones(N), s1, c1, 0 * t])
    W[:, 1] = np.column_stack([0.5 * np.ones(N), 0 * t, c1 + 0.3 * s2, s2])
    return W


def _noise(rng, phi: float) -> np.ndarray:
    """(N, 2) AR(1) noise of stationary std SIGMA per channel (white for phi = 0)."""
    a = rng.standard_normal((N, 2)) * np.sqrt(1 - phi**2)
    e = np.empty_like(a)
    e[0] = rng.standard_normal(2)
    for i in range(1, N):
        e[i] = phi * e[i - 1] + a[i]
    return e * np.array(SIGMA)


def _true_cov(W: np.ndarray, phi: float, w: np.ndarray) -> np.ndarray:
    """Exact covariance of the weighted LS estimate under AR(1) noise (channels independent)."""
    lag = np.abs(np.subtract.outer(np.arange(N), np.arange(N)))
    T = phi**lag
    A = sum(w[j] * W[:, j].T @ W[:, j] for j in range(2))
    M = sum(w[j] ** 2 * SIGMA[j] ** 2 * W[:, j].T @ T @ W[:, j] for j in range(2))
    Ai = np.linalg.inv(A)
    return Ai @ M @ Ai


def _fit(W, y, estimator, kind, n_blocks=50, chunk=777, **kw):
    b = ProblemBuilder(NAMES, ("ch1", "ch2"))
    blocks = BlockBuilder(NAMES, ("ch1", "ch2"), n_blocks, N)
    for a in range(0, N, chunk):  # chunks that do not line up with the blocks
        b.add(W[a:a + chunk], y[a:a + chunk])
        blocks.add(W[a:a + chunk], y[a:a + chunk])
    res = estimator.fit(b.build())
    return res, robust_result(res, blocks.build(), kind=kind, **kw)


@pytest.mark.numerics
@pytest.mark.parametrize("kind, draws, margin", [("hac", 80, 0.2), ("block_bootstrap", 30, 0.25)])
def test_block_standard_errors_match_the_true_sampling_std_under_ar1_noise(kind, draws, margin):
    W = _design()
    rng = np.random.default_rng(seed(7))
    w = 1.0 / np.array(SIGMA) ** 2
    true_std = np.sqrt(np.diag(_true_cov(W, PHI, w)))
    var_block, var_model, errs = 0.0, 0.0, []
    for _ in range(draws):
        y = np.einsum("nkp,p->nk", W, TRUTH) + _noise(rng, PHI)
        res, rob = _fit(W, y, WLS(noise_std=SIGMA), kind, replicates=200, seed=int(rng.integers(1 << 30)))
        var_block = var_block + rob.bse**2 / draws
        var_model = var_model + res.bse**2 / draws
        errs.append(res.params - TRUTH)
        np.testing.assert_array_equal(rob.params, res.params)  # only the covariance changes
    ratio = np.sqrt(var_block) / true_std
    # sampling error of the averaged variance ~ sqrt(2 / (B draws)) (1.6 % at 80 x 50; 2.6 % at 30 x 50),
    # bias from correlation beyond one neighbouring 40-sample block: phi^40 / (1 - phi) ~ 1e-3 (HAC);
    # the bootstrap leaves out the cross-boundary term, about 2 phi / ((1 - phi^2) 40) ~ 11 % of the variance
    assert np.all(np.abs(ratio - 1) < margin), ratio
    # the least-squares covariance assumes white noise: for regressors this slow the AR(1) inflation is
    # close to sqrt((1 + phi) / (1 - phi)) = 3, so it reports less than half the true std
    assert np.all(np.sqrt(var_model) < 0.5 * true_std), np.sqrt(var_model) / true_std
    # and the truth of the Monte Carlo itself agrees with the exact covariance (draws-limited: a sample
    # std of `draws` has a relative std of 1 / sqrt(2 (draws - 1)); 4 of them, 4 parameters: 3e-4)
    emp = np.std(errs, axis=0, ddof=1)
    assert np.all(np.abs(emp / true_std - 1) < 4 / np.sqrt(2 * (draws - 1))), emp / true_std


@pytest.mark.numerics
def test_with_white_noise_block_and_least_squares_errors_agree():
    W = _design()
    rng = np.random.default_rng(seed(3))
    draws = 50
    true_std = np.sqrt(np.diag(_true_cov(W, 0.0, np.ones(2))))
    v_hac = v_ols = 0.0
    for _ in range(draws):
        y = np.einsum("nkp,p->nk", W, TRUTH) + _noise(rng, 0.0)
        res, rob = _fit(W, y, OLS(), "hac", lags=0)
        v_hac, v_ols = v_hac + rob.bse**2 / draws, v_ols + res.bse**2 / draws
    # OLS with unequal channel noise: its pooled s^2 (W^T W)^-1 is not exact; the sandwich is (CR2 is
    # unbiased for white noise of any variance per row); sampling error sqrt(2 / (50 x 50)) = 2.8 %
    assert np.all(np.abs(np.sqrt(v_hac) / true_std - 1) < 0.1), np.sqrt(v_hac) / true_std
    # with equal weights and white noise, WLS's model covariance is right too: both agree (the same 2.8 %
    # of sampling error in the variance, 1.4 % in the std: 0.1 is 7 of them)
    rng = np.random.default_rng(seed(4))
    w_true = np.sqrt(np.diag(_true_cov(W, 0.0, 1.0 / np.array(SIGMA) ** 2)))
    v_hac = v_wls = 0.0
    for _ in range(draws):
        y = np.einsum("nkp,p->nk", W, TRUTH) + _noise(rng, 0.0)
        res, rob = _fit(W, y, WLS(noise_std=SIGMA), "hac")
        v_hac, v_wls = v_hac + rob.bse**2 / draws, v_wls + res.bse**2 / draws
    assert np.all(np.abs(np.sqrt(v_hac) / w_true - 1) < 0.1), np.sqrt(v_hac) / w_true
    assert np.all(np.abs(np.sqrt(v_wls) / w_true - 1) < 0.1), np.sqrt(v_wls) / w_true


def _rows_sandwich(W, y, keep, w, n_blocks, lags):
    """Independent route: the CR2 sandwich from the whitened rows themselves (no compression)."""
    blk = np.minimum(n_blocks - 1, np.arange(N) * n_blocks // N)
    rows = [(i, j) for i in range(N) for j in range(2) if keep[i, j]]
    X = np.array([np.sqrt(w[j]) * W[i, j] for i, j in rows])
    z = np.array([np.sqrt(w[j]) * y[i, j] for i, j in rows])
    b_of = np.array([blk[i] for i, _ in rows])
    beta = np.linalg.lstsq(X, z, rcond=None)[0]
    Ai = np.linalg.inv(X.T @ X)
    g = np.zeros((n_blocks, len(NAMES)))
    for b in range(n_blocks):
        Xb, eb = X[b_of == b], (z - X @ beta)[b_of == b]
        lam, V = np.linalg.eigh(np.eye(len(eb)) - Xb @ Ai @ Xb.T)
        s = np.where(lam > 1e-10, 1 / np.sqrt(np.clip(lam, 1e-10, None)), 0.0)
        g[b] = Xb.T @ ((V * s) @ V.T @ eb)
    M = g.T @ g
    for lag in range(1, lags + 1):
        G = g[:-lag].T @ g[lag:]
        M += (1 - lag / (lags + 1)) * (G + G.T)
    return beta, Ai @ M @ Ai


def test_the_block_compression_equals_the_stacked_rows():
    W = _design()
    rng = np.random.default_rng(11)
    y = np.einsum("nkp,p->nk", W, TRUTH) + _noise(rng, PHI)
    keep = rng.random((N, 2)) > 0.2  # a per-channel row selection
    w = np.array([0.7, 3.0])
    n_blocks = 40
    blocks = BlockBuilder(NAMES, ("ch1", "ch2"), n_blocks, N)
    for a in range(0, N, 333):
        blocks.add(W[a:a + 333], y[a:a + 333], keep[a:a + 333])
    sums = blocks.build()
    beta, cov, info = block_covariance(sums, w, kind="hac", lags=2)
    beta_rows, cov_rows = _rows_sandwich(W, y, keep, w, n_blocks, 2)
    np.testing.assert_allclose(beta, beta_rows, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(cov, cov_rows, rtol=1e-10, atol=1e-12 * np.abs(cov_rows).max())
    # the fit of the compressed whole problem (ProblemBuilder) is the same estimate
    b = ProblemBuilder(NAMES, ("ch1", "ch2"))
    b.add(W, y, keep)
    np.testing.assert_allclose(WLS(noise_std=tuple(1 / np.sqrt(w))).fit(b.build()).params, beta, rtol=1e-10)
    assert info["blocks"] == n_blocks and info["samples_per_block"] == N / n_blocks
    # a whole-sample mask (n,) is the per-channel mask broadcast
    both = keep.all(axis=1)
    one, two = (BlockBuilder(NAMES, ("ch1", "ch2"), n_blocks, N) for _ in range(2))
    one.add(W, y, both)
    two.add(W, y, np.repeat(both[:, None], 2, axis=1))
    for fa, fb in zip(one.build().factors, two.build().factors):
        for a, b in zip(fa, fb):
            np.testing.assert_array_equal(a, b)


def test_the_bootstrap_is_deterministic_for_a_seed():
    W = _design()
    y = np.einsum("nkp,p->nk", W, TRUTH) + _noise(np.random.default_rng(5), PHI)
    _, r1 = _fit(W, y, OLS(), "block_bootstrap", replicates=100, seed=3)
    _, r2 = _fit(W, y, OLS(), "block_bootstrap", replicates=100, seed=3)
    _, r3 = _fit(W, y, OLS(), "block_bootstrap", replicates=100, seed=4)
    np.testing.assert_array_equal(r1.cov_params, r2.cov_params)
    assert not np.array_equal(r1.cov_params, r3.cov_params)
    assert r1.covariance_kind == "block_bootstrap" and r1.solver["covariance"]["replicates"] == 100


def test_block_covariance_refuses_what_it_cannot_do():
    assert default_blocks(102, 10**6) == 206 and default_blocks(3, 10**6) == 50 and default_blocks(3, 20) == 20
    with pytest.raises(InputError, match="at most one block per sample"):
        BlockBuilder(NAMES, ("ch1",), 30, 20)
    W = _design()
    y = np.einsum("nkp,p->nk", W, TRUTH)
    b = ProblemBuilder(NAMES, ("ch1", "ch2"), cross=True)
    b.add(W, y + _noise(np.random.default_rng(1), 0.0))
    from dynid.estimation import GaussMarkov

    blocks = BlockBuilder(NAMES, ("ch1", "ch2"), 10, N)
    blocks.add(W, y)
    with pytest.raises(InputError, match="for methods OLS, WLS"):
        robust_result(GaussMarkov().fit(b.build()), blocks.build(), kind="hac")


# ---------------------------------------------------------------------- dynid identify
@pytest.fixture(scope="module")
def cobot_logs(tmp_path_factory):
    from tests.test_prior import _log

    d = tmp_path_factory.mktemp("blockcov")
    joints = _log(d, "train", 0.2, 1, 0.05, 2)
    _log(d, "valid", 0.2, 2, 0.05, 1)
    return d, joints


def test_identify_reports_the_block_covariance(cobot_logs, tmp_path):
    from tests.test_prior import _doc

    d, joints = cobot_logs
    base = identify(parse_config(_doc(d, joints, method="wls"), d))
    out = identify(parse_config(_doc(d, joints, method="wls", covariance="hac", covariance_blocks=120), d))
    res = out.result
    np.testing.assert_array_equal(res.params, base.result.params)
    assert res.covariance_kind == "hac" and base.result.covariance_kind == "model"
    info = res.solver["covariance"]
    assert info["blocks"] == 120 and info["lags"] == 1
    assert ("covariance", "hac") in res.summary().info and ("covariance", "model") in base.result.summary().info
    files = write_outputs(out, tmp_path / "out")
    doc = json.loads(files["result.json"].read_text())
    assert doc["covariance"] == "hac" and doc["solver"]["covariance"]["kind"] == "hac"
    assert doc["provenance"]["config"]["identification"]["covariance"] == "hac"
    rows = files["params.csv"].read_text().splitlines()
    assert rows[0].endswith(",covariance") and all(r.endswith(",hac") for r in rows[1:])
    std = np.array([p["std"] for p in doc["params"]])
    np.testing.assert_allclose(std, res.bse, rtol=1e-12)


def test_identify_refuses_block_covariance_where_it_does_not_apply(cobot_logs):
    from tests.test_prior import _doc

    d, joints = cobot_logs
    with pytest.raises(ConfigError, match=r"covariance = 'hac' is for the linear least-squares methods 'ols' and "
                                          r"'wls' .*not method = 'tls'"):
        parse_config(_doc(d, joints, method="tls", covariance="hac"), d)
    with pytest.raises(ConfigError, match=r"covariance_blocks = 100000: the training data have \d+ processed"):
        identify(parse_config(_doc(d, joints, covariance="block_bootstrap", covariance_blocks=100000), d))


def test_montecarlo_passes_the_covariance_setting_through():
    import tomllib
    from pathlib import Path

    from dynid.config.montecarlo import parse_montecarlo_config
    from dynid.pipeline import montecarlo as mc
    from tests.test_montecarlo import SMALL

    doc = tomllib.loads(SMALL)
    doc["montecarlo"]["trials"] = 2
    plain = mc.run_montecarlo(parse_montecarlo_config(doc, Path(".")))
    doc["identify"]["identification"].update(covariance="hac", covariance_blocks=60)
    hac = mc.run_montecarlo(parse_montecarlo_config(doc, Path(".")))
    assert plain.settings["covariance"] == "model" and hac.settings["covariance"] == "hac"
    assert "WLS, hac covariance" in hac.summary_text()
    np.testing.assert_array_equal(hac.estimates, plain.estimates)  # the same trials, only the intervals differ
    assert np.all(np.isfinite(hac.std)) and not np.allclose(hac.std, plain.std, rtol=1e-3)
