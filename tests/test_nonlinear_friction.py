"""Nonlinear Stribeck friction jointly with physically consistent base parameters (StribeckLS):
recovery within the reported uncertainty on a simulated 6R arm, exact recovery without noise,
the SDP warm start, held-out validation against the linear Coulomb + viscous fit, errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from conftest import seed
from dynid.errors import IdentifiabilityError, InputError
from dynid.estimation import BodyBounds, PhysicalConstraints, PhysicalLS
from dynid.estimation.nonlinear import (
    SampleProblem,
    StribeckLS,
    _log_cholesky,
    _log_cholesky_start,
    stribeck_basis,
    stribeck_predict,
)
from dynid.model import load_robot, pseudo_inertia, regressor, robot_base_parameters
from dynid.model.friction import Stribeck
from dynid.trajectories import FourierTrajectory

ROBOT = load_robot("builtin:cobot6r")
BASE = robot_base_parameters(ROBOT)
LAY = ROBOT.layout
FC_IDX, FV_IDX = LAY.extra_index["fc"], LAY.extra_index["fv"]
NOMINAL = ROBOT.nominal_parameters()
MARGIN = 1e-4


def _thickened(pi, kappa):
    """Every body's pseudo-inertia + kappa * 1 (mass + kappa, principal moments + 2 kappa)."""
    pi = pi.copy()
    for b in range(LAY.n_bodies):
        pi[10 * b] += kappa
        pi[10 * b + np.array([4, 6, 9])] += 2 * kappa
    return pi


TRUTH = _thickened(NOMINAL, 0.01)  # physically consistent, well inside the feasible set
FRICTION = Stribeck(fc=NOMINAL[FC_IDX], fs=1.6 * NOMINAL[FC_IDX], fv=NOMINAL[FV_IDX],
                    vs=[0.05, 0.08, 0.06, 0.10, 0.12, 0.10], delta=[2.0, 1.5, 1.0, 2.0, 0.8, 1.2])
SIGMA = np.array([0.3, 0.3, 0.2, 0.1, 0.05, 0.05])  # torque noise [N m]
P_BASE = BASE.n_base


def _truth_phi(truth=TRUTH):
    return np.r_[BASE.from_standard(truth), FRICTION.fs - FRICTION.fc, FRICTION.vs, FRICTION.delta]


def _data(seed, n=1500, fs=150.0, truth=TRUTH):
    """A 10 s Fourier excitation (velocity reversals every few seconds on each joint) and the
    noise-free torques: rigid body + rotor inertia + offset + Stribeck friction (the model's own
    formula, not the regressor's)."""
    lo, hi = ROBOT.position_limits()
    traj = FourierTrajectory.random(6, 5, 0.1, np.random.default_rng(seed), lo, hi,
                                    max_velocity=1.5, max_acceleration=5.0, fill=0.7)
    q, dq, ddq = traj.sample(np.arange(n) / fs)
    Y = regressor(ROBOT, q, dq, ddq)
    pi_rest = truth.copy()
    pi_rest[FC_IDX] = pi_rest[FV_IDX] = 0.0  # friction comes from the Stribeck model
    return q, dq, ddq, Y @ pi_rest + FRICTION.force(dq)


Q, DQ, DDQ, TAU = _data(seed(1))
Y_NOISY = TAU + np.random.default_rng(seed(5)).standard_normal(TAU.shape) * SIGMA
EST = StribeckLS(constraints=PhysicalConstraints(margin=MARGIN))


@pytest.fixture(scope="module")
def noisy():
    sp = SampleProblem.from_robot(ROBOT, Q, DQ, DDQ, Y_NOISY, base=BASE)
    return sp, EST.fit(sp)


@pytest.fixture(scope="module")
def held_out():
    q, dq, ddq, tau = _data(seed(2), n=1000)
    return BASE.regressor(regressor(ROBOT, q, dq, ddq)), dq, tau


def test_log_cholesky_is_consistent_and_its_jacobian_exact():
    rng = np.random.default_rng(0)
    for _ in range(5):
        th = rng.standard_normal(10)
        block, D = _log_cholesky(th, 0.01)
        assert np.linalg.eigvalsh(pseudo_inertia(block))[0] >= 0.01 * (1 - 1e-12)
        h = 1e-6
        fd = np.column_stack([(_log_cholesky(th + h * e, 0.01)[0] - _log_cholesky(th - h * e, 0.01)[0]) / (2 * h)
                              for e in np.eye(10)])
        np.testing.assert_allclose(D, fd, rtol=1e-6, atol=1e-8)
        # the start map inverts it (shrink 0)
        np.testing.assert_allclose(_log_cholesky(_log_cholesky_start(block, 0.01, 0.0), 0.01)[0], block, atol=1e-10)


@pytest.mark.numerics
def test_recovers_friction_and_base_parameters_within_reported_uncertainty(noisy):
    sp, res = noisy
    assert res.solver["status"] == "converged"
    assert res.solver["active_constraints"] == [] and res.cov_params is not None
    names = BASE.names + sp.stribeck_names("dFs") + sp.stribeck_names("vs") + sp.stribeck_names("delta")
    assert res.names == names
    z = (res.params - _truth_phi()) / res.bse
    assert np.all(np.abs(z) < 4.5), dict(zip(res.names, z.round(2)))  # 7e-6 per parameter, 5e-4 over the 76
    # the channel weights are the noise levels re-estimated from the same residuals (sigma_j^2 = RSS_j / (n - p_j)):
    # scale = sum(n - p_j) / (N - P), 1 to the parameter count's share
    assert abs(res.scale - 1) < 0.1
    # 1500 samples a channel: the sample std within 1/sqrt(2 n) = 1.8 % (1 std) of the truth; 10 % is 5.5 std
    np.testing.assert_allclose(res.noise_std, SIGMA, rtol=0.1)
    # every Stribeck parameter is determined by this experiment: its 4.5-std interval excludes 0 (the least
    # determined, delta of joint 4, to ~9 % (1 std) over 3 draws; not the 10 % of all of them once asserted here)
    assert np.all(4.5 * res.bse[P_BASE:] < np.abs(_truth_phi()[P_BASE:])), dict(zip(res.names[P_BASE:], res.bse[P_BASE:]))
    st = res.solver["stribeck"]["joint_3"]
    assert st["Fs"] - st["Fc"] == pytest.approx(res.params[res.names.index("dFs_joint_3")])
    assert st["Fc"] == pytest.approx(res.params[res.names.index("fc3")])
    assert st["Fv"] == pytest.approx(res.params[res.names.index("fv3")])


@pytest.mark.numerics
def test_physically_consistent_with_margin(noisy):
    sp, res = noisy
    eig = res.solver["min_pseudo_inertia_eigenvalue"]
    # the polish (PhysicalLS) checks its constraints as stated, widening its buffer until they hold: the
    # eigenvalues recomputed by eigvalsh differ by rounding only
    assert len(eig) == 6 and min(eig) >= MARGIN * (1 - 1e-9)
    pi = np.array(list(res.solver["standard_params"].values()))
    assert list(res.solver["standard_params"]) == list(ROBOT.parameter_names)
    assert np.all(pi[sp.standard.nonnegative] >= 0)
    # the standard vector gives the estimate: it is the polish's tie-break solve (PhysicalLS._closest), within
    # r + weight x gain + Clarabel's slack of it in the covariance's metric (r <= 1e-3 for an unchanged optimum,
    # the tie-break weight's gain <= 1e-3, the slack ~3e-7 x the tolerance scale: test_physical._tie_break_bound),
    # so each coordinate within ~2e-3 of its conditional std, below its std here (measured 1.5e-10)
    assert np.all(np.abs(BASE.from_standard(pi) - res.params[:P_BASE]) < 0.01 * res.bse[:P_BASE])


def _improvement_floor(res) -> float:
    """What the refinement gains on the warm start by chance alone, in chi^2 units: it frees the
    grid's (vs, delta), 2 n_f parameters, which on noise alone lower the weighted RSS by
    chi2_{2 n_f}; its 1e-3 quantile. (The warm start's grid misfit is systematic: the gain is
    ~1000 here, 0.80-0.87 of the warm RSS over 4 draws; a ratio of 0.9 once asserted had no
    margin of its own.)"""
    return float(stats.chi2.isf(1e-3, 2 * len(res.solver["friction_names"])))


@pytest.mark.numerics
def test_warm_start_is_the_physical_sdp_on_the_augmented_problem(noisy):
    sp, res = noisy
    warm = res.solver["warm_start"]
    nll = [c["nll"] for c in warm["candidates"]]
    assert len(nll) == 8 and min(nll) == next(c["nll"] for c in warm["candidates"]
                                             if (c["vs_relative"], c["delta"]) == (warm["vs_relative"], warm["delta"]))
    aug = sp.augmented(np.array(warm["vs"]), np.full(6, warm["delta"]))
    direct = PhysicalLS(weighting="wls", constraints=PhysicalConstraints(margin=MARGIN)).fit(aug)
    assert list(direct.names) == warm["names"]
    np.testing.assert_array_equal(direct.params, warm["params"])
    # the same solve in this process, the same status; Clarabel may stop short of its tightened tolerances
    # (x0.01) on this SDP and return its last iterate as optimal_inaccurate, its constraints checked as stated
    # (dynid.tolerances.solver_options: seen with the tolerances x0.01 and the Haswell kernel together)
    assert warm["status"] == direct.solver["status"] in ("optimal", "optimal_inaccurate")
    # the refinement improves on it, by more than chance would
    assert warm["rss_weighted"] - res.solver["rss_weighted"] > _improvement_floor(res), (warm["rss_weighted"],
                                                                                          res.solver["rss_weighted"])


def _prediction_var(res, W2, dq2) -> np.ndarray:
    """Per channel, the mean over the samples of the variance of the prediction (delta method: the
    Jacobian of stribeck_predict in the parameters, by central differences of a hundredth of each
    std, times the reported covariance)."""
    L = np.linalg.cholesky(res.cov_params)
    J = []
    for k, h in enumerate(1e-2 * res.bse):
        up, dn = res.params.copy(), res.params.copy()
        up[k] += h
        dn[k] -= h
        J.append((stribeck_predict(dataclasses.replace(res, params=up), W2, dq2)
                  - stribeck_predict(dataclasses.replace(res, params=dn), W2, dq2)) / (2 * h))
    JL = np.einsum("knc,kl->ncl", np.array(J), L)
    return np.mean(np.sum(JL**2, axis=2), axis=0)


@pytest.mark.numerics
def test_beats_the_linear_coulomb_viscous_fit_on_held_out_data(noisy, held_out):
    """Noise-free held-out torques: the error of the prediction is the estimate's error alone, a
    linear function of it (to first order), so its mean square per channel is a weighted sum of
    chi^2_1 whose mean is the prediction variance V_j; for any weights its 1e-3/6 tail is below
    chi2_1(1e-3/6) V_j (Szekely & Bakirov 2003; Bonferroni over the 6 joints). The prediction std
    sqrt(V_j) is well below the measurement noise (0.10-0.21 sigma_j over 3 draws), and the linear
    Coulomb + viscous model misses the Stribeck hump by far more (its error 12-70 x the nonlinear
    model's over 3 draws)."""
    sp, res = noisy
    W2, dq2, tau2 = held_out
    rmse_nl = np.sqrt(np.mean((stribeck_predict(res, W2, dq2) - tau2) ** 2, axis=0))
    V = _prediction_var(res, W2, dq2)
    assert np.all(rmse_nl <= np.sqrt(stats.chi2.isf(1e-3 / 6, 1) * V)), (rmse_nl, np.sqrt(V))
    assert np.all(np.sqrt(V) < 0.5 * SIGMA), (np.sqrt(V), SIGMA)  # model error well below the measurement noise
    lin = PhysicalLS(constraints=PhysicalConstraints(margin=MARGIN)).fit(sp.compressed())
    rmse_lin = np.sqrt(np.mean((W2 @ lin.params - tau2) ** 2, axis=0))
    assert np.all(rmse_nl < 0.25 * rmse_lin), (rmse_nl, rmse_lin)


@pytest.mark.numerics
def test_noise_free_data_are_recovered_exactly():
    half = slice(0, None, 2)  # 750 samples over the whole period
    sp = SampleProblem.from_robot(ROBOT, Q[half], DQ[half], DDQ[half], TAU[half], base=BASE)
    res = EST.fit(sp)
    truth = _truth_phi()
    # zero residual: Gauss-Newton converges quadratically past its step tolerance (xtol 1e-10 x the tolerance
    # scale): 3e-15 relative measured at scales 0.01, 1 and 10; 1e-6 bounds it with room for the conditioning
    np.testing.assert_allclose(res.params[P_BASE:], truth[P_BASE:], rtol=1e-6)
    np.testing.assert_allclose(res.params[:P_BASE], truth[:P_BASE], rtol=1e-6, atol=1e-6 * np.abs(truth[:P_BASE]).max())
    assert res.solver["active_constraints"] == []


@pytest.mark.numerics
def test_binding_constraints_give_no_covariance_and_still_a_feasible_fit(noisy):
    # the nominal arm has thin links (smallest pseudo-inertia eigenvalue 1.5e-4): with noise the
    # unconstrained optimum is not physically consistent, the constraints bind
    q, dq, ddq, tau = _data(seed(1), n=800, fs=80.0, truth=NOMINAL)
    y = tau + np.random.default_rng(seed(6)).standard_normal(tau.shape) * SIGMA
    res = StribeckLS().fit(SampleProblem.from_robot(ROBOT, q, dq, ddq, y, base=BASE))
    assert res.cov_params is None and any("pseudo-inertia" in a for a in res.solver["active_constraints"])
    assert any(n.startswith("no covariance") for n in res.notes)
    with pytest.raises(InputError, match="no covariance"):
        res.bse  # noqa: B018
    assert min(res.solver["min_pseudo_inertia_eigenvalue"]) >= 0
    # no standard errors at a binding constraint: the Stribeck parameters against those of the interior fit
    # of the same motion and noise (the noisy fixture: 1500 samples of it, here 800, so std x sqrt(1500/800));
    # the binding constraints act on the bodies, which these parameters are nearly independent of.
    # 4.5 of those std: 7e-6 per parameter. (The 30 % once asserted is 2.5 std of delta of joint 4.)
    std = noisy[1].bse[P_BASE:] * np.sqrt(1500 / 800)
    z = (res.params[P_BASE:] - _truth_phi(NOMINAL)[P_BASE:]) / std
    assert np.all(np.abs(z) < 4.5), dict(zip(res.names[P_BASE:], z.round(2)))
    assert res.solver["warm_start"]["rss_weighted"] - res.solver["rss_weighted"] > _improvement_floor(res)


def test_basis_and_projection_of_a_subset_of_joints():
    v = np.array([[-0.2, 0.0, 0.05]])
    g = stribeck_basis(v, np.array([0.1, 0.1, 0.05]), np.array([2.0, 1.0, 1.0]))
    np.testing.assert_allclose(g, [[-np.exp(-4.0), 0.0, np.exp(-1.0)]])
    sp = SampleProblem.from_robot(ROBOT, Q[:300], DQ[:300], DDQ[:300], TAU[:300], base=BASE,
                                  friction_joints=["joint_2", "joint_5"])
    assert sp.friction_names == ("joint_2", "joint_5") and sp.projection.shape == (300, 6, 2)
    cols = sp.friction_columns(np.array([0.1, 0.1]), np.array([1.0, 1.0]))
    assert np.all(cols[:, [0, 2, 3, 5], :] == 0) and np.all(cols[:, 1, 1] == 0)


# ---------------------------------------------------------------------- errors
SUB = slice(0, 1500, 5)  # 300 samples over the whole period: every joint reverses


def _small(dq=None):
    dq = DQ[SUB] if dq is None else dq
    W = BASE.regressor(regressor(ROBOT, Q[SUB], dq, DDQ[SUB]))
    coulomb = tuple(BASE.names.index(f"fc{j}") for j in range(1, 7))
    viscous = tuple(BASE.names.index(f"fv{j}") for j in range(1, 7))
    sp = SampleProblem.from_robot(ROBOT, Q[SUB], dq, DDQ[SUB], TAU[SUB], base=BASE)
    return W, coulomb, viscous, sp


def _one_line(exc):
    assert "\n" not in str(exc.value)


def test_bad_inputs_raise_one_line_errors():
    W, coulomb, viscous, sp = _small()
    kw = dict(names=BASE.names, channel_names=ROBOT.joint_names, W=W, y=TAU[SUB], velocity=DQ[SUB],
              friction_names=ROBOT.joint_names, coulomb=coulomb, viscous=viscous, standard=sp.standard)
    SampleProblem(**kw)  # valid
    cases = [
        (dict(y=TAU[SUB][1:]), "y has shape"),
        (dict(W=W[:, :, :-1]), "W has shape"),
        (dict(velocity=np.where(np.arange(300)[:, None] == 3, np.nan, DQ[SUB])), "velocity contains NaN"),
        (dict(coulomb=coulomb[1:] + coulomb[:1]), "is not the Coulomb column"),
        (dict(viscous=coulomb), "must be distinct"),
        (dict(coulomb=coulomb[:5]), "coulomb must hold 6 indices"),
        (dict(velocity=DQ[SUB][:, :3], friction_names=ROBOT.joint_names[:3], coulomb=coulomb[:3], viscous=viscous[:3]),
         "give the projection"),
    ]
    for change, msg in cases:
        with pytest.raises(InputError, match=msg) as err:
            SampleProblem(**{**kw, **change})
        _one_line(err)
    with pytest.raises(InputError, match="fv/fc") as err:
        SampleProblem.from_robot(load_robot("builtin:cobot6r", extras=("Ia", "offset")), Q[:50], DQ[:50], DDQ[:50], TAU[:50])
    _one_line(err)
    for est, msg in ((StribeckLS(weighting="gm"), "weighting"),
                     (StribeckLS(constraints=PhysicalConstraints(bodies={"2": BodyBounds(mass=(1.0, 5.0))})), "per-body"),
                     (StribeckLS(vs_grid=(5.0,)), "vs_grid")):
        with pytest.raises(InputError, match=msg) as err:
            est.fit(sp)
        _one_line(err)
    with pytest.raises(InputError, match="not a StribeckLS result"):
        stribeck_predict(PhysicalLS().fit(sp.compressed()), W, DQ[SUB])


def test_a_joint_that_never_moves_or_moves_one_way_is_not_identifiable():
    still = DQ[SUB].copy()
    still[:, 5] = 0.0
    with pytest.raises(IdentifiabilityError, match="'joint_6' never moves") as err:
        StribeckLS().fit(_small(still)[3])
    _one_line(err)
    one_way = DQ[SUB].copy()
    one_way[:, 2] = np.abs(one_way[:, 2]) + 0.01
    with pytest.raises(IdentifiabilityError, match="'joint_3' moves only in the positive direction") as err:
        StribeckLS().fit(_small(one_way)[3])
    assert "dFs_joint_3" in err.value.names


# ---------------------------------------------------------------------- warm-start candidates left undetermined
def _above(frac):
    """The noise-free problem of ``SUB`` with every joint's rows slower than ``frac`` x its RMS speed
    left out (``processing.min_velocity``'s row selection)."""
    sp = _small()[3]
    return dataclasses.replace(sp, mask=np.abs(sp.velocity) >= frac * sp.rms_velocity)


@pytest.mark.numerics
def test_a_warm_start_candidate_with_an_undetermined_hump_is_skipped():
    # bench/README B10: rows kept above 0.15 x the RMS speed; at the default grid's candidate
    # (v_S, delta) = (0.02 x RMS, 2) the dFs column exp(-(|v|/v_S)^2) is at most exp(-7.5^2) = 4e-25 on
    # them, against the Coulomb columns' entries of 1: 1e10 below the rank test's 1e-14 on any machine,
    # so that candidate is refused for every dFs. At (0.02, 1) the column reaches exp(-7.5) = 5.5e-4 and
    # at 0.05 x RMS exp(-3) = 0.05 (delta 1), 1.2e-4 (delta 2): far above it. The truth's humps
    # (v_S = 0.05-0.12 rad/s, 0.07-0.18 x RMS) reach the kept rows, so the fit is determined.
    sp = _above(0.15)
    res = EST.fit(sp)
    cands = res.solver["warm_start"]["candidates"]
    refused = [(c["vs_relative"], c["delta"]) for c in cands if c["status"].startswith("refused")]
    assert refused == [(0.02, 2.0)], cands
    why = next(c["status"] for c in cands if c["status"].startswith("refused"))
    assert "dFs_joint_1" in why and next(c for c in cands if c["delta"] == 2.0)["nll"] is None
    assert len(cands) == len(EST.vs_grid) * len(EST.delta_grid) and res.solver["warm_start"]["refused_candidates"] == 1
    assert (res.solver["warm_start"]["vs_relative"], res.solver["warm_start"]["delta"]) not in refused
    assert any("1 of 8 grid candidates" in n for n in res.notes), res.notes
    # noise-free data: the truth is the optimum and it is interior, so the fit recovers it to Gauss-Newton's
    # quadratic convergence past xtol (as test_noise_free_data_are_recovered_exactly: 1e-13 relative
    # measured here; 1e-6 leaves room for the conditioning of the rows kept)
    assert res.solver["status"] == "converged" and res.solver["active_constraints"] == []
    truth = _truth_phi()
    np.testing.assert_allclose(res.params[P_BASE:], truth[P_BASE:], rtol=1e-6)
    np.testing.assert_allclose(res.params[:P_BASE], truth[:P_BASE], rtol=1e-6, atol=1e-6 * np.abs(truth[:P_BASE]).max())


def test_every_warm_start_candidate_undetermined_is_refused():
    # on the same rows a grid of v_S <= 0.02 x RMS with delta >= 2 leaves every candidate's dFs column
    # below exp(-7.5^2) = 4e-25 (above): every candidate refused, one error naming each dFs
    est = StribeckLS(vs_grid=(0.01, 0.02), delta_grid=(2.0, 2.5))
    with pytest.raises(IdentifiabilityError, match="every warm-start grid candidate") as err:
        est.fit(_above(0.15))
    _one_line(err)
    assert err.value.names == _small()[3].stribeck_names("dFs")
