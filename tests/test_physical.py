"""Physically consistent identification (issue 8): LMI/SDP constraints on the standard
parameters, estimate of the base parameters, regularization, serial and closed-loop robots.

Independent routes: minimality of the residual increase against a nonlinear least-squares
search over a parametrization that is physically consistent by construction (log-Cholesky
factors of the pseudo-inertias, scipy), eigenvalues recomputed with numpy from the reported
standard parameters, mass matrices from pinocchio's CRBA on the recovered standard parameters.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import scipy.optimize as so

from conftest import sdp_chi2_slack, sdp_norm_slack, seed
from dynid.errors import ConfigError, DynidError, InputError
from dynid.estimation import OLS, WLS, BodyBounds, PhysicalConstraints, PhysicalLS, RegressionProblem, is_feasible
from dynid.estimation import logdet_divergence, make_estimator
from dynid.model.base_parameters import StandardMap, pseudo_inertia, robot_base_parameters
from dynid.model.closed_loop import actuator_regressor, mechanism_base_parameters, random_consistent_states
from dynid.model.loading import load_robot
from dynid.model.serial_dynamics import regressor
from dynid.model.robots import build_mechanism

ROBOT = load_robot("builtin:cobot6r", extras=("Ia", "fv", "fc"))
BASE = robot_base_parameters(ROBOT)
SMAP = StandardMap.of(ROBOT, BASE)
TRUE_PI = ROBOT.nominal_parameters()
TRUE_BETA = BASE.from_standard(TRUE_PI)


def _states(n, k, scale=1.0):
    rng = np.random.default_rng(seed(k))
    lo, hi = ROBOT.position_limits()
    q = lo + (hi - lo) * rng.random((n, ROBOT.dof))
    return q, scale * rng.standard_normal((n, ROBOT.dof)), scale * 3 * rng.standard_normal((n, ROBOT.dof))


def _serial_problem(n, k, noise, scale=1.0):
    q, dq, ddq = _states(n, k, scale)
    W = BASE.regressor(regressor(ROBOT, q, dq, ddq))
    y = W @ TRUE_BETA + noise * np.random.default_rng(seed(k + 100)).standard_normal((n, ROBOT.dof))
    return RegressionProblem.from_arrays(W, y, BASE.names, ROBOT.joint_names, standard=SMAP)


def _std(res):
    return np.array([res.solver["standard_params"][n] for n in SMAP.standard_names])


def _tie_break_bound(res) -> float:
    """The guarantee of the standard vector reported with a PhysicalLS estimate (physical._closest):
    the tie-break solve (residual norm + weight x distance to the reference) could have kept the
    first solve's point, so its residual norm exceeds the estimate's by at most weight x (the
    distance to the reference it gained) plus both solves' slack (conftest.sdp_norm_slack), and is
    below it by at most the first solve's slack. Asserts both sides; returns the upper bound on the
    reported standard vector's residual norm."""
    st, first = res.solver["stages"]["standard"], res.solver["stages"]["sdp"]
    tb = st["tie_break"]
    r = np.sqrt(max(res.solver["residual_increase_chi2"], 0.0))
    g = sdp_norm_slack(r, first) + sdp_norm_slack(r + tb["weight"] * tb["reference_distance_before"], st)
    up = np.sqrt(max(res.solver["residual_increase_chi2"] + st["residual_increase_chi2"], 0.0)) - r
    gain = tb["weight"] * (tb["reference_distance_before"] - tb["reference_distance_after"])
    assert -g <= up <= gain + g, (up, gain, g)
    return r + gain + g


def _chi2_increase(problem, fit_beta, ls):
    """Residual increase over the unconstrained optimum, in units of its residual variance."""
    return float(np.sum(problem.rss_per_channel(fit_beta)) - np.sum(ls.rss_per_channel)) / ls.scale


@pytest.mark.numerics
def test_a_feasible_ols_solution_is_returned_unchanged():
    prob = _serial_problem(2000, 1, noise=0.005)
    assert is_feasible(TRUE_BETA, SMAP)  # the truth is physical
    ols = OLS().fit(prob)
    assert is_feasible(ols.params, SMAP), "precondition: a rich excitation gives a feasible OLS estimate"
    phys = PhysicalLS(weighting="ols").fit(prob)
    assert phys.solver["unchanged"] and phys.solver["active_constraints"] == []
    np.testing.assert_array_equal(phys.params, ols.params)
    np.testing.assert_array_equal(phys.cov_params, ols.cov_params)
    # the reported standard vector is physically consistent and gives the estimate up to the tie-break's
    # guarantee: its distance to the estimate in the metric of the OLS covariance (the solver's own
    # residual norm, A = R B / s, here by another route) within _tie_break_bound
    pi = _std(phys)
    assert min(np.linalg.eigvalsh(pseudo_inertia(pi[b]))[0] for b in SMAP.body_blocks) >= 0
    e = BASE.from_standard(pi) - ols.params
    assert np.sqrt(e @ np.linalg.solve(ols.cov_params, e)) <= _tie_break_bound(phys)


def _log_cholesky_fit(problem, ls, starts, seed):
    """Independent route: min ||R (B pi(theta) - beta_ls)||^2 / s^2 over pi(theta) physically
    consistent by construction (J_k = L_k L_k^T, non-negative terms as squares)."""
    A = (ls_R := _whitened_R(problem, ls)) @ SMAP.B / np.sqrt(ls.scale)
    d = ls_R @ ls.params / np.sqrt(ls.scale)
    nb = len(SMAP.body_blocks)
    rest = np.arange(10 * nb, SMAP.B.shape[1])
    nonneg = np.isin(rest, SMAP.nonnegative)
    tril = np.tril_indices(4)

    def pi_of(theta):
        pi = np.empty(SMAP.B.shape[1])
        for k, blk in enumerate(SMAP.body_blocks):
            L = np.zeros((4, 4))
            L[tril] = theta[10 * k: 10 * k + 10]
            J = L @ L.T
            sigma, h, m = J[:3, :3], J[:3, 3], J[3, 3]
            inertia = np.trace(sigma) * np.eye(3) - sigma
            pi[blk] = [m, *h, inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2], inertia[1, 2], inertia[2, 2]]
        t = theta[10 * nb:]
        pi[rest] = np.where(nonneg, t**2, t)
        return pi

    def theta_of(pi):
        th = []
        for blk in SMAP.body_blocks:
            L = np.linalg.cholesky(pseudo_inertia(pi[blk]) + 1e-9 * np.eye(4))
            th.extend(L[tril])
        t = pi[rest]
        return np.array(th + list(np.where(nonneg, np.sqrt(np.abs(t)), t)))

    rng = np.random.default_rng(seed)
    best = np.inf
    for start in starts:
        th0 = theta_of(start) * (1 + 0.05 * rng.standard_normal(10 * nb + rest.size))
        sol = so.least_squares(lambda th: A @ pi_of(th) - d, th0, method="trf", max_nfev=200, xtol=1e-12, ftol=1e-12)
        best = min(best, float(np.sum(sol.fun**2)))
    return best


def _whitened_R(problem, ls):
    from dynid.estimation import whitened_solve

    return whitened_solve(problem, np.ones(problem.n_channels)).R


@pytest.mark.numerics
def test_an_infeasible_estimate_becomes_feasible_with_the_smallest_residual_increase():
    # too little excitation (slow, short) and much noise: OLS returns a non-physical estimate
    prob = _serial_problem(120, 7, noise=3.0, scale=0.3)
    ols = OLS().fit(prob)
    assert not is_feasible(ols.params, SMAP), "precondition: the unconstrained estimate is not physical"
    phys = PhysicalLS(weighting="ols").fit(prob)
    assert not phys.solver["unchanged"] and phys.solver["active_constraints"]
    assert phys.cov_params is None and "not defined" in phys.solver["standard_error"]
    assert is_feasible(phys.params, SMAP)
    pi = _std(phys)
    assert min(np.linalg.eigvalsh(pseudo_inertia(pi[b]))[0] for b in SMAP.body_blocks) >= 0
    assert np.all(pi[SMAP.nonnegative] >= 0)
    inc = _chi2_increase(prob, phys.params, ols)
    assert inc > 0
    # the same number by two routes (the solver's whitened A, the problem's RSS): equal to the rounding
    # of the compressed RSS (||y||^2 ~ 1e3 x the residual's here: ~1e-12 relative)
    np.testing.assert_allclose(inc, phys.solver["residual_increase_chi2"], rtol=1e-6)
    _tie_break_bound(phys)
    # smallest possible: no physically consistent parameter set found by an independent
    # nonlinear search (log-Cholesky, several starts, one at the SDP's own solution) does better than
    # the SDP's optimum, up to where Clarabel stops (conftest.sdp_chi2_slack) and the cost of the
    # buffer by which the SDP tightens every constraint: the buffer (2e-8) relative to the smallest
    # body's pseudo-inertia scale, times 10, of the increase (the search's set has no buffer)
    ref_start = TRUE_PI.copy()
    best = _log_cholesky_fit(prob, ols, [ref_start, pi], seed=3)
    body_scale = min(np.linalg.eigvalsh(pseudo_inertia(TRUE_PI[b]))[-1] for b in SMAP.body_blocks)
    buffer = 10 * phys.solver["stages"]["sdp"]["buffer"] / body_scale * inc
    assert inc <= best + sdp_chi2_slack(np.sqrt(inc), phys.solver["stages"]["sdp"]) + buffer, (inc, best)
    # and other feasible candidates (the truth) cost more
    assert inc <= _chi2_increase(prob, TRUE_BETA, ols)


@pytest.mark.numerics
def test_projection_in_the_covariance_metric_is_the_constrained_fit_and_non_expansive():
    """PhysicalLS.project (used by DIDIM): projecting the OLS estimate onto the consistent set in
    the metric of its covariance solves the constrained least-squares problem (the objective is
    the residual's increase), and a projection onto a convex set brings the estimate no farther
    from any consistent point, the truth included, in that metric."""
    prob = _serial_problem(120, 7, noise=3.0, scale=0.3)
    ols = OLS().fit(prob)
    assert not is_feasible(ols.params, SMAP), "precondition: the unconstrained estimate is not physical"
    phys = PhysicalLS(weighting="ols").fit(prob)
    proj = PhysicalLS(weighting="ols").project(ols.params, ols.cov_params, SMAP)
    assert not proj["unchanged"] and proj["active_constraints"]
    assert is_feasible(proj["params"], SMAP)
    # the same optimum by both routes: equal objective values up to where each solve stops
    inc = phys.solver["residual_increase_chi2"]
    eps = sdp_chi2_slack(np.sqrt(inc), phys.solver["stages"]["sdp"])
    assert abs(proj["distance_chi2"] - inc) <= 2 * eps, (proj["distance_chi2"], inc, eps)
    # the projection's own objective by another route (the problem's RSS): rounding only
    np.testing.assert_allclose(_chi2_increase(prob, proj["params"], ols), proj["distance_chi2"], rtol=1e-6)
    Sinv = np.linalg.inv(ols.cov_params)
    dist = lambda a, b: float((a - b) @ Sinv @ (a - b))  # noqa: E731
    # the Pythagorean inequality of a projection P onto a convex set, for every consistent y:
    # |P - y|^2 <= |x - y|^2 - |x - P|^2; the solve's point is within sqrt(eps) of P, and |x - P|^2 is
    # at least the reported distance minus eps
    for point in (TRUE_BETA, phys.params):
        exact = np.sqrt(max(dist(ols.params, point) - proj["distance_chi2"] + eps, 0.0))
        assert np.sqrt(dist(proj["params"], point)) <= exact + np.sqrt(eps), (point, exact)
    # a consistent estimate is returned unchanged
    same = PhysicalLS(weighting="ols").project(TRUE_BETA, ols.cov_params, SMAP)
    assert same["unchanged"] and np.array_equal(same["params"], TRUE_BETA)
    with pytest.raises(InputError, match="regularization"):
        PhysicalLS(regularization="euclidean", regularization_weight=1.0).project(ols.params, ols.cov_params, SMAP)
    with pytest.raises(InputError, match="positive definite"):
        PhysicalLS().project(ols.params, -ols.cov_params, SMAP)


@pytest.mark.numerics
def test_margin_and_bounds_hold_and_bind():
    prob = _serial_problem(300, 11, noise=1.0, scale=0.5)
    margin = 1e-3
    m3 = TRUE_PI[SMAP.body_blocks[2][0]]
    bounds = {"3": BodyBounds(mass=(0.5 * m3, 0.9 * m3)),  # excludes the true mass
              "4": BodyBounds(com_box=((-0.1, -0.1, -0.1), (0.1, 0.1, 0.1))),
              "5": BodyBounds(com_ellipsoid=((0.0, 0.0, 0.0), (0.05, 0.05, 0.08)))}
    res = PhysicalLS(weighting="wls", constraints=PhysicalConstraints(margin=margin, bodies=bounds)).fit(prob)
    pi = _std(res)
    eig = [np.linalg.eigvalsh(pseudo_inertia(pi[b]))[0] for b in SMAP.body_blocks]
    assert min(eig) >= margin, eig
    np.testing.assert_allclose(eig, res.solver["min_pseudo_inertia_eigenvalue"], rtol=1e-9)
    b3, b4, b5 = (SMAP.body_blocks[k] for k in (2, 3, 4))
    assert 0.5 * m3 <= pi[b3[0]] <= 0.9 * m3
    c4 = pi[b4[1:4]] / pi[b4[0]]
    assert np.all(np.abs(c4) <= 0.1)
    c5 = pi[b5[1:4]] / pi[b5[0]]
    assert np.sum((c5 / [0.05, 0.05, 0.08]) ** 2) <= 1 + 1e-9
    with pytest.raises(InputError, match="unknown bodies"):
        PhysicalLS(constraints=PhysicalConstraints(bodies={"link9": BodyBounds(mass=(0, 1))})).fit(prob)
    with pytest.raises(DynidError, match="infeasible"):  # bounds that exclude every consistent body
        PhysicalLS(constraints=PhysicalConstraints(bodies={"2": BodyBounds(
            mass=(1.0, 2.0), com_box=((0.5, 0.5, 0.5), (0.6, 0.6, 0.6)))}, margin=10.0)).fit(prob)


@pytest.mark.numerics
def test_regularization_pulls_towards_the_reference():
    prob = _serial_problem(120, 7, noise=3.0, scale=0.3)
    ref = SMAP.reference
    plain = PhysicalLS(weighting="ols").fit(prob)
    d_plain = logdet_divergence(_std(plain), ref, SMAP.body_blocks)
    last = {}
    for kind in ("euclidean", "logdet"):
        prev = None
        for lam in (1e-2, 1.0, 1e4):
            res = PhysicalLS(weighting="ols", regularization=kind, regularization_weight=lam).fit(prob)
            pi = _std(res)
            assert is_feasible(res.params, SMAP)
            dist = np.linalg.norm(pi - ref) if kind == "euclidean" else logdet_divergence(pi, ref, SMAP.body_blocks)
            # exact optima are monotone in lambda; successive lambdas here are 100x apart and the
            # distances fall by factors > 3, far more than a solve stopped at its 1e-8 gap can move them
            assert prev is None or dist <= prev * (1 + 1e-6)
            prev = dist
            last[kind] = (res, pi)
        # a strong pull lands (almost) on the reference, which is physical here
        assert np.linalg.norm(pi - ref) < 0.05 * np.linalg.norm(ref)
    assert logdet_divergence(last["logdet"][1], ref, SMAP.body_blocks) < d_plain
    assert last["logdet"][0].method == "OLS+LMI+LogDet" and last["euclidean"][0].method == "OLS+LMI+Reg"


@pytest.mark.numerics
def test_regularized_covariance_is_the_least_squares_one_for_a_weak_pull():
    # rich data, feasible optimum, inactive constraints: the sandwich covariance of a weakly
    # regularized fit must approach the least-squares covariance (independent closed form): with
    # H = A^T A + lambda I, each direction's variance shrinks by (mu / (mu + lambda))^2, mu >= the
    # smallest non-zero eigenvalue of A^T A (A the whitened problem in standard parameters)
    # (lambda = 1e-2: a pull the solver resolves, lambda |pi - ref|^2 far above its absolute gap; at
    # 1e-8 it is below it, and the free standard directions end wherever the solver stops)
    lam = 1e-2
    prob = _serial_problem(2000, 1, noise=0.005)
    ls = OLS().fit(prob)
    res = PhysicalLS(weighting="ols", regularization="euclidean", regularization_weight=lam).fit(prob)
    assert res.solver["active_constraints"] == [] and res.cov_params is not None
    A = _whitened_R(prob, ls) @ SMAP.B / np.sqrt(ls.scale)
    mu = np.linalg.svd(A, compute_uv=False)[: SMAP.B.shape[0]].min() ** 2
    np.testing.assert_allclose(np.sqrt(np.diag(res.cov_params)), ls.bse, rtol=2 * lam / mu + 1e-9)
    # the estimate: the pull moves it by at most lambda |pi - ref| / sqrt(mu); the solve minimizes the
    # squared residual (+ the pull, ~0 here) and stops within its gap g of it (sdp_norm_slack, in the
    # objective's units), so within sqrt(g) ~ 5e-4 of the optimum, both in standard deviations
    e = res.params - ls.params
    pull = lam * np.linalg.norm(_std(res) - SMAP.reference) / np.sqrt(mu)
    assert np.sqrt(e @ np.linalg.solve(ls.cov_params, e)) <= pull + np.sqrt(sdp_norm_slack(0.0, res.solver["stages"]["sdp"]))


@pytest.mark.numerics
def test_gauss_markov_weighting():
    from dynid.estimation import ProblemBuilder

    q, dq, ddq = _states(1500, 5)
    W = BASE.regressor(regressor(ROBOT, q, dq, ddq))
    rng = np.random.default_rng(seed(5))
    C = np.full((6, 6), 0.6) + 0.4 * np.eye(6)
    y = W @ TRUE_BETA + rng.multivariate_normal(np.zeros(6), C * 0.25, size=1500)
    b = ProblemBuilder(BASE.names, ROBOT.joint_names, cross=True)
    b.add(W, y)
    prob = b.build(standard=SMAP)
    res = make_estimator("gm", True, physical={"constraints": PhysicalConstraints(margin=1e-6)}).fit(prob)
    assert res.method.startswith("GM+LMI")
    assert min(res.solver["min_pseudo_inertia_eigenvalue"]) >= 1e-6
    with pytest.raises(ConfigError, match="need physical_consistency"):
        make_estimator("wls", False, physical={"regularization": "logdet"})


def _mechanism_problem(name, n, noise, k, spread=0.3):
    mech = build_mechanism(name)
    dist = "projected" if mech.redundant else None
    base = mechanism_base_parameters(mech, distribution=dist)
    state = random_consistent_states(mech, n, np.random.default_rng(seed(k)), spread=spread)
    W = base.regressor(actuator_regressor(mech, state, distribution=dist).W)
    pi = mech.nominal_parameters()
    y = W @ base.from_standard(pi) + noise * np.random.default_rng(seed(k + 1)).standard_normal(W.shape[:2])
    smap = StandardMap(standard_names=mech.parameter_names, B=base.B, body_blocks=mech.body_blocks(),
                       nonnegative=mech.nonnegative_parameters(), reference=pi,
                       nonpositive=mech.nonpositive_parameters())
    return RegressionProblem.from_arrays(W, y, base.names, [f"ch{j}" for j in range(W.shape[1])], standard=smap), base


@pytest.mark.numerics
@pytest.mark.parametrize("name", ["shang2dof", "rps3", "hexapod"])
def test_closed_loop_mechanisms(name):
    # legs and platform bodies: weak, noisy data make WLS infeasible; the SDP repairs it
    prob, base = _mechanism_problem(name, 40, noise=5.0, k=2)
    smap = prob.standard
    res = PhysicalLS(weighting="wls", constraints=PhysicalConstraints(margin=1e-6)).fit(prob)
    pi = np.array([res.solver["standard_params"][n] for n in smap.standard_names])
    eig = [np.linalg.eigvalsh(pseudo_inertia(pi[b]))[0] for b in smap.body_blocks]
    assert len(eig) == len(smap.body_blocks) and min(eig) >= 1e-6
    assert np.all(pi[smap.nonnegative] >= 0) and np.all(pi[smap.nonpositive] <= 0)
    # the standard vector reproduces the estimate up to the tie-break's guarantee
    _tie_break_bound(res)
    # no constrained point fits better than the unconstrained optimum (exact; the rounding of RSS sums)
    wls = WLS().fit(prob)
    assert np.sum(res.rss_per_channel / res.noise_std**2) >= np.sum(wls.rss_per_channel / wls.noise_std**2) - 1e-6


def test_unknown_solver_and_bad_options_are_one_line_errors():
    prob = _serial_problem(300, 11, noise=1.0)
    for est, match in [(PhysicalLS(solver="NOPE"), "not installed"),
                       (PhysicalLS(regularization="logdet"), "go together"),
                       (PhysicalLS(weighting="tls"), "weighting must be"),
                       (PhysicalLS(regularization="euclidean", regularization_weight=1.0, reference=(1.0,)), "reference")]:
        with pytest.raises((InputError, DynidError), match=match) as err:
            est.fit(prob)
        assert "\n" not in str(err.value)
    bad_ref = SMAP.reference.copy()
    bad_ref[SMAP.body_blocks[0][0]] = -1.0
    with pytest.raises(InputError, match="positive definite"):
        PhysicalLS(regularization="logdet", regularization_weight=1.0, reference=tuple(bad_ref)).fit(prob)


@pytest.mark.numerics
def test_mass_matrix_of_the_constrained_model_matches_pinocchio():
    """Independent route for the exported physics: the mass matrix from the base regressor equals
    pinocchio's CRBA on the recovered standard parameters, and is positive definite."""
    prob = _serial_problem(120, 7, noise=3.0, scale=0.3)
    res = PhysicalLS(weighting="ols").fit(prob)
    model = ROBOT.with_parameters(_std(res))
    data = model.createData()
    q = _states(5, 9)[0]
    for qi in q:
        M = pin.crba(model, data, qi)
        M = np.triu(M) + np.triu(M, 1).T
        z = np.zeros((ROBOT.dof, ROBOT.dof))
        Wq = BASE.regressor(regressor(ROBOT, np.tile(qi, (ROBOT.dof, 1)), z, np.eye(ROBOT.dof)))
        W0 = BASE.regressor(regressor(ROBOT, qi[None], z[:1], z[:1]))
        beta = BASE.from_standard(_std(res))  # the exported model's own base parameters
        M_reg = (Wq @ beta - W0 @ beta).T
        np.testing.assert_allclose(M_reg, M, atol=1e-6 * np.abs(M).max())
        assert np.linalg.eigvalsh(M)[0] > 0


@pytest.mark.parametrize("ident, message", [
    ({"margin": 1e-3}, "physical_consistency = true"),
    ({"physical_consistency": True, "method": "tls"}, "'ols', 'wls', 'gm' and 'didim'"),
    ({"physical_consistency": True, "regularization": "logdet", "regularization_weight": 0.0}, "regularization_weight > 0"),
    ({"physical_consistency": True, "regularization_weight": 2.0}, "needs a regularization"),
    ({"physical_consistency": True, "bodies": {"3": {"mass": [1.0]}}}, "list of 2 numbers"),
    ({"physical_consistency": True, "bodies": {"3": {"volume": 1.0}}}, "volume"),
    ({"physical_consistency": True, "margin": -1.0}, "margin must be >= 0"),
])
def test_config_errors_are_one_line(ident, message):
    from dynid.config import _parse_identification

    with pytest.raises(ConfigError, match=message) as err:
        _parse_identification(ident)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("kind", ["euclidean", "logdet"])
def test_named_regularization_weighs_one_by_default(kind):
    """A named regularization without a weight weighs 1 (a unit divergence = one noise variance of
    residual), and the estimator the pipeline builds carries it; no regularization, no weight."""
    from dynid.config import _parse_identification
    from dynid.pipeline.data import physical_options

    icfg = _parse_identification({"physical_consistency": True, "regularization": kind})
    assert icfg.regularization_weight == 1.0
    est = make_estimator(icfg.method, True, physical=physical_options(icfg))
    assert est.regularization == kind and est.regularization_weight == 1.0
    assert _parse_identification({"physical_consistency": True}).regularization_weight == 0.0


def test_config_builds_the_estimator():
    from dynid.config import _parse_identification
    from dynid.pipeline.data import physical_options

    icfg = _parse_identification({"physical_consistency": True, "method": "wls", "margin": 1e-4,
                                  "regularization": "logdet", "regularization_weight": 2.0,
                                  "bodies": {"3": {"mass": [0.1, 9.0], "com_ellipsoid": {"center": [0, 0, 0], "semi_axes": [1, 1, 1]}}}})
    est = make_estimator(icfg.method, True, physical=physical_options(icfg))
    assert est.constraints.margin == 1e-4 and est.regularization == "logdet" and est.regularization_weight == 2.0
    assert est.constraints.bodies["3"].mass == (0.1, 9.0)
    with pytest.raises(ConfigError, match="mass bounds"):
        physical_options(_parse_identification({"physical_consistency": True, "bodies": {"3": {"mass": [5.0, 1.0]}}}))


def test_friction_model_and_max_samples_are_parsed():
    from dynid.config import _parse_identification

    icfg = _parse_identification({"physical_consistency": True, "friction_model": "stribeck", "max_samples": 800})
    assert icfg.friction_model == "stribeck" and icfg.max_samples == 800
    with pytest.raises(ConfigError, match="friction_model"):
        _parse_identification({"physical_consistency": True, "friction_model": "lugre"})
    with pytest.raises(ConfigError, match="physical_consistency = true"):
        _parse_identification({"friction_model": "stribeck"})
    with pytest.raises(ConfigError, match="max_samples"):
        _parse_identification({"physical_consistency": True, "friction_model": "stribeck", "max_samples": 10})
    with pytest.raises(ConfigError, match="max_samples is for friction_model"):
        _parse_identification({"physical_consistency": True, "max_samples": 1000})
