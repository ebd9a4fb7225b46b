"""Nonlinear Stribeck friction jointly with physically consistent base parameters (StribeckLS):
recovery within the reported uncertainty on a simulated 6R arm, exact recovery without noise,
the SDP warm start, held-out validation against the linear Coulomb + viscous fit, errors."""

from __future__ import annotations

import numpy as np
import pytest

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


Q, DQ, DDQ, TAU = _data(1)
Y_NOISY = TAU + np.random.default_rng(5).standard_normal(TAU.shape) * SIGMA
EST = StribeckLS(constraints=PhysicalConstraints(margin=MARGIN))


@pytest.fixture(scope="module")
def noisy():
    sp = SampleProblem.from_robot(ROBOT, Q, DQ, DDQ, Y_NOISY, base=BASE)
    return sp, EST.fit(sp)


@pytest.fixture(scope="module")
def held_out():
    q, dq, ddq, tau = _data(2, n=1000)
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


def test_recovers_friction_and_base_parameters_within_reported_uncertainty(noisy):
    sp, res = noisy
    assert res.solver["status"] == "converged"
    assert res.solver["active_constraints"] == [] and res.cov_params is not None
    names = BASE.names + sp.stribeck_names("dFs") + sp.stribeck_names("vs") + sp.stribeck_names("delta")
    assert res.names == names
    z = (res.params - _truth_phi()) / res.bse
    assert np.all(np.abs(z) < 4.0), dict(zip(res.names, z.round(2)))
    assert abs(res.scale - 1) < 0.1  # the channel weights are the noise levels
    np.testing.assert_allclose(res.noise_std, SIGMA, rtol=0.1)
    # the Stribeck parameters themselves: within 5 % here
    np.testing.assert_allclose(res.params[P_BASE:], _truth_phi()[P_BASE:], rtol=0.1)
    st = res.solver["stribeck"]["joint_3"]
    assert st["Fs"] - st["Fc"] == pytest.approx(res.params[res.names.index("dFs_joint_3")])
    assert st["Fc"] == pytest.approx(res.params[res.names.index("fc3")])
    assert st["Fv"] == pytest.approx(res.params[res.names.index("fv3")])


def test_physically_consistent_with_margin(noisy):
    sp, res = noisy
    eig = res.solver["min_pseudo_inertia_eigenvalue"]
    assert len(eig) == 6 and min(eig) >= MARGIN * (1 - 1e-9)
    pi = np.array(list(res.solver["standard_params"].values()))
    assert list(res.solver["standard_params"]) == list(ROBOT.parameter_names)
    assert np.all(pi[sp.standard.nonnegative] >= 0)
    # the standard vector gives the estimate (to a small fraction of its standard errors)
    assert np.all(np.abs(BASE.from_standard(pi) - res.params[:P_BASE]) < 0.01 * res.bse[:P_BASE])


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
    assert warm["status"] == direct.solver["status"] == "optimal"
    # the refinement improves on it
    assert res.solver["rss_weighted"] < 0.9 * warm["rss_weighted"]


def test_beats_the_linear_coulomb_viscous_fit_on_held_out_data(noisy, held_out):
    sp, res = noisy
    W2, dq2, tau2 = held_out
    rmse_nl = np.sqrt(np.mean((stribeck_predict(res, W2, dq2) - tau2) ** 2, axis=0))
    lin = PhysicalLS(constraints=PhysicalConstraints(margin=MARGIN)).fit(sp.compressed())
    rmse_lin = np.sqrt(np.mean((W2 @ lin.params - tau2) ** 2, axis=0))
    assert np.all(rmse_nl < 0.25 * rmse_lin), (rmse_nl, rmse_lin)
    assert np.all(rmse_nl < 0.5 * SIGMA)  # model error well below the measurement noise


def test_noise_free_data_are_recovered_exactly():
    half = slice(0, None, 2)  # 750 samples over the whole period
    sp = SampleProblem.from_robot(ROBOT, Q[half], DQ[half], DDQ[half], TAU[half], base=BASE)
    res = EST.fit(sp)
    truth = _truth_phi()
    np.testing.assert_allclose(res.params[P_BASE:], truth[P_BASE:], rtol=1e-6)
    np.testing.assert_allclose(res.params[:P_BASE], truth[:P_BASE], rtol=1e-6, atol=1e-6 * np.abs(truth[:P_BASE]).max())
    assert res.solver["active_constraints"] == []


def test_binding_constraints_give_no_covariance_and_still_a_feasible_fit(held_out):
    # the nominal arm has thin links (smallest pseudo-inertia eigenvalue 1.5e-4): with noise the
    # unconstrained optimum is not physically consistent, the constraints bind
    q, dq, ddq, tau = _data(1, n=800, fs=80.0, truth=NOMINAL)
    y = tau + np.random.default_rng(6).standard_normal(tau.shape) * SIGMA
    res = StribeckLS().fit(SampleProblem.from_robot(ROBOT, q, dq, ddq, y, base=BASE))
    assert res.cov_params is None and any("pseudo-inertia" in a for a in res.solver["active_constraints"])
    assert any(n.startswith("no covariance") for n in res.notes)
    with pytest.raises(InputError, match="no covariance"):
        res.bse  # noqa: B018
    assert min(res.solver["min_pseudo_inertia_eigenvalue"]) >= 0
    # a sanity check (no standard errors to compare with): 800 samples, delta the least determined
    np.testing.assert_allclose(res.params[P_BASE:], _truth_phi(NOMINAL)[P_BASE:], rtol=0.3)
    assert res.solver["rss_weighted"] < 0.95 * res.solver["warm_start"]["rss_weighted"]


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
