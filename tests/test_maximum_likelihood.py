"""Maximum likelihood with the filter cut-off as an estimated parameter (paper 004 Eq. 24).

A virtual 3-RPS (builtin:rps3) follows a periodic excitation of its leg lengths with 3
harmonics of 0.5 Hz for 8 periods; the log carries leg-position noise (20 um) and force noise
(5 N). ``[identification] method = "ml"`` searches the cut-off over the bin midpoints and, at
each, solves Gauss–Markov with the force covariance of the period averaging; the cost adds the
positions the window removed, weighted by their covariance.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError, IdentifiabilityError, InputError
from dynid.estimation import ProblemBuilder
from dynid.estimation.likelihood import CutoffFamily, MaximumLikelihood, cutoff_candidates, position_cost
from dynid.pipeline import identify
from dynid._files import save_npz
from dynid.pipeline.simulate import run_simulation

F0, H, PERIODS = 0.5, 3, 8
N_PER = int(round(250 / F0))  # samples per period of the log
TRAIN = 6  # periods averaged for training; the last 2 validate


@pytest.fixture(scope="module")
def rps3_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("ml")
    sim = run_simulation(parse_simulate_config({
        "robot": {"model": "builtin:rps3", "perturbation": 0.1, "perturbation_seed": 3},
        "trajectory": {"kind": "fourier", "base_frequency_hz": F0, "harmonics": H, "fill": 0.4, "max_velocity": 0.1,
                       "max_acceleration": 1.0, "periods": PERIODS + 1, "seed": 3},
        "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
        "sensors": {"position_noise_std": 2e-5, "force_noise_std": 5.0, "seed": 3, "log_rate_hz": 250},
    }, d))
    cols = sim.columns
    # drop the first period (start-up transient of the controller), keep 8 whole periods
    keep = slice(N_PER, N_PER + PERIODS * N_PER)
    save_npz(d / "log.npz", {k: v[keep] - (cols["t"][N_PER] if k == "t" else 0.0) for k, v in cols.items()})
    return d, sim


def _doc(d, identification: dict, processing: dict | None = None) -> dict:
    acts = ["q_P1", "q_P2", "q_P3"]
    return {
        "robot": {"model": "builtin:rps3"},
        "data": {"file": str(d / "log.npz"), "time": {"column": "t", "unit": "s"},
                 "position": {"columns": acts, "unit": "m"},
                 "effort": {"columns": [a.replace("q_", "tau_") for a in acts], "kind": "torque", "unit": "N"},
                 "rows": [0, TRAIN * N_PER]},
        "validation": {"rows": [TRAIN * N_PER, PERIODS * N_PER]},
        "processing": processing or {"periodic": {"period_s": 1 / F0, "cutoff_hz": (H + 0.5) * F0}},
        "identification": identification,
        "output": {"plots": False},
    }


@pytest.fixture(scope="module")
def ml_run(rps3_log):
    d, _ = rps3_log
    return identify(parse_config(_doc(d, {"method": "ml", "cutoff_range_hz": [0.6, 30.0]}), d))


def test_ml_keeps_the_excited_band_and_picks_the_best_total_cost(ml_run):
    res = ml_run.result
    assert res.method == "ML"
    fc, (lo, hi) = res.solver["cutoff_hz"], res.solver["cutoff_interval_hz"]
    assert hi - lo == pytest.approx(F0) and lo < fc < hi
    profile = [r for r in res.solver["profile"] if r["cost"] is not None]
    assert [r["cutoff_hz"] for r in res.solver["profile"]] == list(cutoff_candidates(1 / F0, 250.0, 0.6, 30.0))
    best = min(profile, key=lambda r: r["cost"])
    assert best["cutoff_hz"] == fc and best["cost"] == pytest.approx(res.solver["cost"])
    # every excited harmonic is kept: below H * f0 the removed positions are signal, and cost
    # orders of magnitude more than the noise they would remove above
    assert fc > H * F0
    below = [r for r in res.solver["profile"] if r["cutoff_hz"] < H * F0]
    assert all(r["position_cost"] > 100 * best["position_cost"] for r in below)
    # the window at f_c removes noise, and the motion's own response above the excited band
    # (the legs' Coulomb reversals, 200+ N steps): the likelihood keeps that response
    band = next(r for r in profile if r["cutoff_hz"] == (H + 0.5) * F0)
    assert best["force_cost"] < band["force_cost"] and best["position_cost"] < band["position_cost"]


def test_ml_predicts_better_than_the_excited_band(rps3_log, ml_run):
    """Gauss–Markov with the window at the excited band ((n_h + 1/2) f0, paper 004's choice)
    against ML's cut-off on the held-out periods: the cut-off ML finds predicts the forces
    better, and it lowers the training cost where the band leaves the closed loop's response
    to the Coulomb reversals out of the regressor."""
    d, _ = rps3_log
    band = identify(parse_config(_doc(d, {"method": "gm", "noise_covariance": "periodic"}), d))
    assert band.config.processing.periodic.cutoff_hz == (H + 0.5) * F0
    ml = np.asarray(ml_run.validation.rel_rmse_pct)
    gm = np.asarray(band.validation.rel_rmse_pct)
    assert np.mean(ml) < np.mean(gm), (ml, gm)


def test_ml_equals_gauss_markov_at_its_cut_off(rps3_log, ml_run):
    """Independent route: dynid's Gauss–Markov with the period covariance, run with the
    processing cut-off set to the one ML chose, gives the same estimate and the force cost."""
    d, _ = rps3_log
    fc = ml_run.result.solver["cutoff_hz"]
    gm = identify(parse_config(_doc(d, {"method": "gm", "noise_covariance": "periodic"},
                                    {"periodic": {"period_s": 1 / F0, "cutoff_hz": fc}}), d)).result
    np.testing.assert_allclose(ml_run.result.params, gm.params, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(gm.solver["noise_covariance"], ml_run.result.solver["noise_covariance"], rtol=1e-12)
    best = next(r for r in ml_run.result.solver["profile"] if r["cutoff_hz"] == fc)
    assert best["force_cost"] == pytest.approx(0.5 * gm.scale * gm.dof, rel=1e-9)
    # the held-out check, and the processed training log the outcome carries, use the chosen cut-off
    for ds in (ml_run.held_out, ml_run.train):
        step = next(s for s in ds.meta["processing"] if s["step"] == "periodic")
        assert step["cutoff_hz"] == fc


TIME_COV = {"noise_covariance": (25.0 * np.eye(3)).tolist(), "position_covariance": (4e-10 * np.eye(3)).tolist()}


@pytest.fixture(scope="module")
def ml_time(rps3_log):
    d, _ = rps3_log
    return identify(parse_config(_doc(d, {"method": "ml", "cutoff_range_hz": [2.0, 32.0], **TIME_COV},
                                      {"lowpass": {"cutoff_hz": 8.0, "filter_effort": False}}), d))


def test_ml_in_the_time_domain_searches_the_lowpass_cut_off(rps3_log, ml_time):
    """Without period averaging the filter is the zero-phase Butterworth low-pass: the search runs
    over a logarithmic grid of its cut-off, every candidate scores the same samples (the ends
    trimmed for the lowest), and the estimate at the best one is Gauss–Markov with the given
    force covariance there: checked by running that GM through the product with the same
    processing."""
    from dynid.estimation.likelihood import log_cutoff_grid

    d, _ = rps3_log
    res = ml_time.result
    profile = res.solver["profile"]
    grid = log_cutoff_grid(2.0, 32.0, len(profile))
    assert [r["cutoff_hz"] for r in profile] == list(grid)
    best = min((r for r in profile if r["cost"] is not None), key=lambda r: r["cost"])
    fc = res.solver["cutoff_hz"]
    assert best["cutoff_hz"] == fc
    i = grid.index(fc)
    assert res.solver["cutoff_interval_hz"] == [grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]]
    # positions: the lower the cut-off, the more the filter removes (signal below the band)
    pos = [r["position_cost"] for r in profile]
    assert pos[0] > pos[-1]
    lp = {"lowpass": {"cutoff_hz": fc, "filter_effort": False}, "trim_samples": res.solver["trim_samples"]}
    gm = identify(parse_config(_doc(d, {"method": "gm", "noise_covariance": TIME_COV["noise_covariance"]}, lp), d)).result
    np.testing.assert_allclose(res.params, gm.params, rtol=1e-8, atol=1e-10 * np.abs(gm.params).max())
    assert best["force_cost"] == pytest.approx(0.5 * gm.scale * gm.dof, rel=1e-8)
    for ds in (ml_time.held_out, ml_time.train):
        step = next(s for s in ds.meta["processing"] if s["step"] == "lowpass")
        assert step["cutoff_hz"] == fc


def test_position_cost_is_half_the_mahalanobis_sum():
    rng = np.random.default_rng(0)
    delta = rng.normal(size=(50, 2))
    cov = np.array([[2.0, 0.5], [0.5, 1.0]])
    direct = 0.5 * sum(d @ np.linalg.solve(cov, d) for d in delta)
    assert position_cost(delta, cov) == pytest.approx(direct, rel=1e-12)
    # rows kept per channel: each sample counts with the covariance of its kept channels
    keep = rng.random(delta.shape) > 0.4
    direct = 0.5 * sum(d[k] @ np.linalg.solve(cov[np.ix_(k, k)], d[k]) for d, k in zip(delta, keep) if k.any())
    assert position_cost(delta, cov, keep) == pytest.approx(direct, rel=1e-12)


def test_noisier_positions_lower_the_cut_off():
    """The trade-off of Eq. 24 on a synthetic record: a signal of harmonics 1-3 with noise on
    the positions. Weighting the removed positions less (a larger Sigma_dd) lets the window
    drop more; the cut-off never drops signal when the positions are weighted correctly."""
    n, fs = 400, 100.0
    t = np.arange(n) / fs
    f0 = fs / n
    rng = np.random.default_rng(1)
    signal = sum(np.sin(2 * np.pi * k * f0 * t + k) / k for k in (1, 2, 3))
    meas = signal + 0.01 * rng.normal(size=n)
    force = 2.0 * signal + 0.05 * rng.normal(size=n)

    from dynid.signals.periodic import fourier_filter

    def build(fc):
        q_f = fourier_filter(meas, fs, fc)[0]
        b = ProblemBuilder(("k",), ("f",), cross=True)
        b.add(q_f[:, None, None], force[:, None])
        return b.build(), (meas - q_f)[:, None]

    cut = cutoff_candidates(n / fs, fs, 0.5 * f0, 20 * f0)
    right = MaximumLikelihood(noise_covariance=[[0.05**2]], position_covariance=[[0.01**2]]).fit(CutoffFamily(cut, build, f0))
    assert right.solver["cutoff_hz"] > 3 * f0
    assert right.params[0] == pytest.approx(2.0, abs=5 * right.bse[0])
    loose = MaximumLikelihood(noise_covariance=[[0.05**2]], position_covariance=[[1e4]]).fit(CutoffFamily(cut, build, f0))
    assert loose.solver["cutoff_hz"] < right.solver["cutoff_hz"]


def test_candidates_are_bin_midpoints():
    assert cutoff_candidates(2.0, 100.0, 1.0, 3.0) == (1.25, 1.75, 2.25, 2.75)
    with pytest.raises(InputError, match="no cut-off between harmonics"):
        cutoff_candidates(2.0, 100.0, 1.01, 1.2)


def test_ml_errors_name_the_problem(rps3_log, tmp_path):
    d, _ = rps3_log
    with pytest.raises(ConfigError, match="no period averaging to estimate it from; give it as a matrix"):
        identify(parse_config(_doc(d, {"method": "ml"}, {"lowpass": {"cutoff_hz": 5.0, "filter_effort": False}}), d))
    with pytest.raises(ConfigError, match="set processing.lowpass \\(time domain\\) or \\[processing.periodic\\]"):
        identify(parse_config(_doc(d, {"method": "ml", **TIME_COV}, {"derivatives": "central"}), d))
    with pytest.raises(ConfigError, match="processing.decimate must be 1"):
        identify(parse_config(_doc(d, {"method": "ml", **TIME_COV}, {"lowpass": {"cutoff_hz": 5.0, "filter_effort": False},
                                                                  "decimate": 2}), d))
    with pytest.raises(ConfigError, match="filter_effort = false"):
        identify(parse_config(_doc(d, {"method": "ml"}, {"periodic": {"period_s": 2.0, "cutoff_hz": 1.75,
                                                                      "filter_effort": True}}), d))
    with pytest.raises(InputError, match="position covariance Sigma_dd is singular"):
        identify(parse_config(_doc(d, {"method": "ml", "position_covariance": [[1e-10, 0, 0], [0, 1e-10, 0], [0, 0, 0]]}), d))
    with pytest.raises(ConfigError, match="cutoff_range_hz is for method = 'ml'"):
        parse_config(_doc(d, {"method": "gm", "cutoff_range_hz": [1.0, 2.0]}), d)
    with pytest.raises(ConfigError, match="noise_covariance: must be one of \\['periodic'\\]"):
        parse_config(_doc(d, {"method": "ml", "noise_covariance": "residuals"}), d)
    with pytest.raises(ConfigError, match="0 < low < high"):
        parse_config(_doc(d, {"method": "ml", "cutoff_range_hz": [3.0, 1.0]}), d)
    with pytest.raises(IdentifiabilityError, match="no candidate cut-off identifies every parameter"):
        identify(parse_config(_doc(d, {"method": "ml", "cutoff_range_hz": [0.1, 0.4]}), d))
