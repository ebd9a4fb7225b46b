"""The Kalman-filter estimators ``method = "ekf"`` / ``"ukf"`` (dynid.estimation.kalman_filters,
dynid.pipeline.kalman_estimate): the square-root array updates against the covariance form, the
filter against batch weighted least squares (an exact identity on a linear measurement), the
recovery of a simulated arm's base parameters, and the configuration's refusals."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import seed
from scipy.stats import chi2

from dynid.errors import ConfigError

EPS = np.finfo(float).eps
FALSE_ALARM = 1e-3
"""Each statistical assertion below fails on correct code with probability 1e-3 per draw."""


def _random_spd(rng, n, cond):
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.geomspace(1.0, 1.0 / cond, n)) @ Q.T


# ------------------------------------------------------------------ (b) the square-root update
def test_square_root_updates_equal_the_covariance_form():
    """Prediction and measurement update in array form (QR of the pre-arrays) against
    ``F P F^T + Q`` and ``P - P H^T (H P H^T + R)^-1 H P``, computed independently.

    Margin: a Householder QR is backward stable, so the computed factor is exact for a pre-array
    perturbed by ``c n eps ||A||`` (c a small constant); the product ``S^T S`` then moves by about
    ``2 c n eps ||A||^2 = 2 c n eps ||P||``-sized terms. The covariance form loses
    ``eps cond(P_zz)`` relatively in its inverse. ``100 n eps cond(P_zz) ||P||`` bounds both
    with a factor of 10 or more to spare for c <= 5 (about 1e-11 here: 20 orders of magnitude
    below any error of the algebra, such as a missing term, which is O(||P||))."""
    from dynid.estimation.kalman_filters import predict, root, unscented_arrays, update

    rng = np.random.default_rng(seed(71))
    n, m = 7, 3
    P = _random_spd(rng, n, 1e3)
    Q = _random_spd(rng, n, 1e2) * 0.1
    R = _random_spd(rng, m, 10.0) * 0.5
    F = np.eye(n) + 0.3 * rng.standard_normal((n, n))
    H = rng.standard_normal((m, n))
    x, e = rng.standard_normal(n), rng.standard_normal(m)
    S = root(P)
    assert np.allclose(S.T @ S, P, rtol=0, atol=100 * n * EPS * np.linalg.norm(P, 2))

    Sp = predict(S, F, root(Q))
    Pp = F @ P @ F.T + Q
    assert np.max(np.abs(Sp.T @ Sp - Pp)) <= 100 * n * EPS * np.linalg.norm(Pp, 2) * np.linalg.cond(F) ** 2

    Pzz = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(Pzz)
    x_ref, P_ref = x + K @ e, P - K @ H @ P
    tol = 100 * n * EPS * np.linalg.cond(Pzz) * np.linalg.norm(P, 2)
    x1, S1, X = update(x, S, S @ H.T, root(R), e)
    assert np.max(np.abs(S1.T @ S1 - P_ref)) <= tol
    assert np.max(np.abs(X.T @ X - Pzz)) <= tol
    assert np.max(np.abs(x1 - x_ref)) <= tol * np.linalg.norm(np.linalg.solve(Pzz, e)) * 10
    # the unscented update of a linear measurement is the same update (its second-order rows vanish)
    L = S.shape[0]
    sig = np.sqrt(L) * S
    Zp, Zm = (x + sig) @ H.T, (x - sig) @ H.T
    zhat, SHt, extra = unscented_arrays(S, Zp, Zm)
    assert np.max(np.abs(extra)) <= 100 * EPS * np.max(np.abs(Zp))
    x2, S2, _ = update(x, S, SHt, root(R), H @ x + e - zhat, extra)
    assert np.max(np.abs(S2.T @ S2 - P_ref)) <= tol
    assert np.max(np.abs(x2 - x_ref)) <= tol * np.linalg.norm(np.linalg.solve(Pzz, e)) * 10


def test_bilinear_second_order_terms_are_the_gaussian_moments_of_the_quadratic_form():
    """The EKF's second-order terms of ``h_c = W_c(u) beta`` from the mixed Hessian, against the
    moments of the quadratic form ``1/2 x^T H_c x`` of a Gaussian ``x`` (mean ``1/2 tr(H_c P)``,
    covariance ``1/2 tr(H_c P H_d P)``) with the Hessians and ``P`` formed explicitly (another
    route to the same numbers). Margin: sums of ``L^2`` products of size ``||S||^2 ||G||``;
    1e3 L^2 eps of that scale."""
    from dynid.estimation.kalman_filters import bilinear_second_order, root

    rng = np.random.default_rng(seed(75))
    a, p, m = 4, 3, 2  # u, beta, channels
    L = a + p + 2  # two more state entries that enter neither
    P = _random_spd(rng, L, 1e2)
    S = root(P)
    iu, ib = np.arange(a), np.arange(a, a + p)
    G = rng.standard_normal((a, m, p))
    shift, R2 = bilinear_second_order(S[:, iu], S[:, ib], G)
    Hs = np.zeros((m, L, L))
    for c in range(m):
        Hs[c][np.ix_(iu, ib)] = G[:, c, :]
        Hs[c][np.ix_(ib, iu)] = G[:, c, :].T
    mean = np.array([0.5 * np.trace(Hs[c] @ P) for c in range(m)])
    cov = np.array([[0.5 * np.trace(Hs[c] @ P @ Hs[d] @ P) for d in range(m)] for c in range(m)])
    scale = np.linalg.norm(P, 2) * np.max(np.abs(G))
    assert np.max(np.abs(shift - mean)) <= 1e3 * L**2 * EPS * scale
    assert np.max(np.abs(R2.T @ R2 - cov)) <= 1e3 * L**2 * EPS * scale**2


def test_partially_linear_unscented_update_is_the_exact_gaussian_update_of_a_bilinear_measurement():
    """The UKF's update for ``h = (u_0, W(u) beta)`` with ``W`` affine in ``u``, ``u`` and ``beta``
    independent Gaussians (the arm's measurement with the parameters uncertain and the kinematic
    state's rows of ``W`` linearized): the first two moments of ``h`` and its cross-covariance with
    the state are then closed-form (``E[d_i d_j] = P_uu,ij`` and the independence of ``beta``), and
    the update with them is the exact Gaussian (linear-MMSE) update. The partially linear unscented
    update (sigma points over ``u`` only, ``beta`` marginalized exactly) must reproduce it: its
    conditional mean is affine in ``u`` and its conditional covariance quadratic, which the unscented
    transform integrates exactly. The square root is given in a basis that mixes ``u`` and ``beta``
    (any square root of P is valid). Margin: backward-stable QR as in the first test,
    1e3 n eps cond(P_zz) ||.|| (about 1e-9 here; a missing term is O(1) of P_zz: asserted below,
    the product term ``sum P_uu,ij G_i P_bb G_j^T`` that the plain 2L-point transform on a
    block-diagonal square root leaves out)."""
    from dynid.estimation.kalman_filters import root, run, unscented_arrays

    rng = np.random.default_rng(seed(77))
    a, p, mf = 3, 4, 2  # kinematic entries u, linear entries beta, force channels
    n, m = a + p, 1 + mf
    Puu, Pbb = _random_spd(rng, a, 10.0) * 0.3, _random_spd(rng, p, 10.0) * 2.0
    P = np.zeros((n, n))
    P[:a, :a], P[a:, a:] = Puu, Pbb
    x = rng.standard_normal(n)
    ub, bb = x[:a], x[a:]
    W0, G = rng.standard_normal((mf, p)), rng.standard_normal((a, mf, p))
    R = np.diag([0.1, 0.3, 0.2]) ** 2
    z = rng.standard_normal(m)

    def W(U):  # (c, mf, p) at the rows of U (c, a)
        return W0 + np.einsum("ci,imp->cmp", U - ub, G)

    def measure(k, X):
        Wc = W(X[:, :a])
        h = np.column_stack([X[:, 0], np.einsum("cmp,cp->cm", Wc, X[:, a:])])
        return h, np.concatenate([np.zeros((X.shape[0], 1, p)), Wc], axis=1)

    # the exact moments
    Gb = np.einsum("imp,p->im", G, bb)  # (a, mf): G_i beta_hat
    cross = np.einsum("ij,imp,pq,jnq->mn", Puu, G, Pbb + np.outer(bb, bb), G)
    Pzz = np.zeros((m, m))
    Pzz[0, 0] = Puu[0, 0]
    Pzz[0, 1:] = Pzz[1:, 0] = Puu[0] @ Gb
    Pzz[1:, 1:] = W0 @ Pbb @ W0.T + cross
    Pzz += R
    Pxz = np.zeros((n, m))
    Pxz[:a, 0], Pxz[:a, 1:], Pxz[a:, 1:] = Puu[:, 0], Puu @ Gb, Pbb @ W0.T
    K = Pxz @ np.linalg.inv(Pzz)
    zhat = np.concatenate([[ub[0]], W0 @ bb])
    x_ref, P_ref = x + K @ (z - zhat), P - K @ Pzz @ K.T

    Qo, _ = np.linalg.qr(rng.standard_normal((n, n)))
    S = Qo @ root(P)  # rows mixing u and beta
    fr = run("ukf", z[None], x, S, np.eye(n), np.zeros((0, n)), root(R), measure=measure, linear=p)
    tol = 1e3 * n * EPS * np.linalg.cond(Pzz)
    assert np.max(np.abs(fr.innovations[0] - (z - zhat))) <= tol * np.max(np.abs(z - zhat))
    assert np.max(np.abs(fr.innovation_var[0] - np.diag(Pzz))) <= tol * np.linalg.norm(Pzz, 2)
    assert np.max(np.abs(fr.P - P_ref)) <= tol * np.linalg.norm(P, 2)
    assert np.max(np.abs(fr.x - x_ref)) <= tol * np.linalg.norm(x_ref) * 10
    # the term the plain transform on a block-diagonal root misses (its sigma points move u or beta,
    # never both) is a sizable part of the force channels' innovation variance here
    Sb = root(P)
    sig = np.sqrt(n) * Sb
    Zp, Zm = measure(0, x + sig)[0], measure(0, x - sig)[0]
    _, A, B = unscented_arrays(Sb, Zp, Zm)
    plain = A.T @ A + B.T @ B + R
    assert np.all(np.diag(Pzz - plain)[1:] >= 0.5 * np.diag(cross - np.einsum("ij,imp,p,q,jnq->mn", Puu, G, bb,
                                                                               bb, G)))
    assert np.min(np.diag(Pzz - plain)[1:] / np.diag(Pzz)[1:]) > 0.1


# ------------------------------------------------------------------ (c) recursive least squares
@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_filter_on_a_linear_measurement_is_batch_weighted_least_squares(kind):
    """Constant parameters measured linearly, ``y_k = W_k beta + v_k``: the Kalman filter is
    recursive least squares, so its final estimate and covariance are the batch weighted least
    squares with the same prior, ``(P0^-1 + sum W^T R^-1 W)^-1 (P0^-1 beta0 + sum W^T R^-1 y)``
    (an identity). Margin: both are rounding-exact up to ``eps cond(information)`` relatively per
    step; 1e3 N eps cond over 300 steps is about 1e-8 of the scale (an error of the algebra, e.g.
    a wrong weight, is O(1))."""
    from dynid.estimation.kalman_filters import root, run

    rng = np.random.default_rng(seed(72))
    p, m, N = 5, 2, 300
    Ws = rng.standard_normal((N, m, p)) * np.array([1.0, 3.0, 0.3, 1.0, 2.0])
    beta = rng.standard_normal(p)
    R = np.diag([0.2, 0.05]) ** 2
    y = np.einsum("kmp,p->km", Ws, beta) + rng.standard_normal((N, m)) * np.sqrt(np.diag(R))
    beta0, P0 = np.zeros(p), np.diag(np.full(p, 4.0))

    fr = run(kind, y, beta0, root(P0), np.eye(p), np.zeros((0, p)), root(R),
             linearize=lambda k, x, S: (Ws[k] @ x, Ws[k], None), measure=lambda k, X: X @ Ws[k].T)
    Ri = np.linalg.inv(R)
    info = np.linalg.inv(P0) + np.einsum("kmp,mn,knq->pq", Ws, Ri, Ws)
    rhs = np.linalg.solve(P0, beta0) + np.einsum("kmp,mn,kn->p", Ws, Ri, y)
    cov = np.linalg.inv(info)
    est = cov @ rhs
    tol = 1e3 * N * EPS * np.linalg.cond(info)
    assert np.max(np.abs(fr.x - est)) <= tol * np.max(np.abs(est))
    assert np.max(np.abs(fr.P - cov)) <= tol * np.max(np.abs(cov))


# ------------------------------------------------------------------ (a) a simulated serial arm
EXTRAS = ("Ia", "fv", "offset")
"""The arm's extras: rotor inertia, viscous friction, offset. Coulomb friction is left out: its sign
makes the measurement discontinuous at the velocity reversals, where no linearization (first order or
unscented) describes it, and the filters' covariance is then optimistic (module docstring of
dynid.pipeline.kalman_estimate, "Limits")."""
ARM = "examples/serial_arm/arm3.urdf"


@pytest.fixture(scope="module")
def arm_log():
    """arm3 (3 joints, 22 base parameters), a random 10 %-perturbed truth, 20 s at 100 Hz of a
    random Fourier trajectory, white position noise 1e-4 rad and force noise 0.05 N*m; the
    processed log carries the exact velocities and accelerations (the WLS on exact states)."""
    from conftest import REPO

    from dynid.dataset import Dataset
    from dynid.model import load_robot
    from dynid.model.system import SerialSystem
    from dynid.simulation import FourierTrajectory, simulate_serial

    robot = load_robot(str(REPO / ARM), extras=EXTRAS)
    system = SerialSystem(robot)
    base = system.base_parameters()
    rng = np.random.default_rng(seed(73))
    truth = robot.nominal_parameters() * (1 + 0.1 * rng.standard_normal(robot.n_standard_params))
    lo, hi = robot.position_limits()
    traj = FourierTrajectory.random(3, 5, 0.1, np.random.default_rng(seed(74)), lo, hi, max_velocity=1.5,
                                    max_acceleration=4.0, fill=0.6)
    ds = simulate_serial(robot, truth, traj, fs=100.0, duration=20.0, torque_noise_std=np.full(3, 0.05),
                         position_noise_std=1e-4, rng=rng)
    q_true, dq, ddq = traj.sample(ds.t)
    exact = Dataset(t=ds.t, q=ds.q, tau=ds.tau, dq=dq, ddq=ddq, names=ds.names, meta=ds.meta)
    return system, base, base.from_standard(truth), exact, q_true


@pytest.fixture(scope="module")
def wls_exact(arm_log):
    """WLS on the exact states (true positions, velocities, accelerations) of the same log."""
    from dynid.estimation import WLS, ProblemBuilder

    system, base, _, ds, q_true = arm_log
    rows = system.rows(None)(q_true, ds.dq, ds.ddq, ds.tau)
    pb = ProblemBuilder(base.names, system.channel_names(None))
    pb.add(base.regressor(rows.W), ds.tau)
    return WLS().fit(pb.build())


def _statistic(d, cov):
    return float(d @ np.linalg.solve(cov, d))


@pytest.mark.numerics
@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_filters_recover_the_simulated_arm(arm_log, wls_exact, kind):
    """The truth lies in the filter's confidence ellipsoid, and the filter agrees with WLS on
    (nearly) exact states within their combined uncertainty.

    Margin: under the model the estimate is Gaussian with the reported covariance (to the
    filter's linearization), so ``d^T C^-1 d`` with ``d = estimate - truth`` is chi-square with p
    degrees of freedom: it exceeds its 1 - 1e-3 quantile with probability 1e-3. For the
    difference with WLS, ``Var(a - b) = C_a + C_b - 2 C_ab``; WLS is efficient for the rows it is
    given, and the covariance of an efficient estimator with any unbiased one is its own, so
    ``C_ab = C_b`` and ``Var(a - b) = C_a - C_b <= C_a + C_b``: the sum is conservative, the same
    quantile a bound on the false-alarm rate."""
    from dynid.pipeline.kalman_estimate import kalman_identify

    system, base, truth, ds, _ = arm_log
    res, worst = kalman_identify(kind, system, base, ds)
    p = base.n_base
    limit = chi2.ppf(1 - FALSE_ALARM, p)
    assert res.method == kind.upper() and worst == 0.0
    assert _statistic(res.params - truth, res.cov_params) <= limit
    assert _statistic(res.params - wls_exact.params, res.cov_params + wls_exact.cov_params) <= limit
    # the reported noise and the consistency check: the force noise std is estimated from
    # ~2000 residuals (relative std about 1.6 %); the position noise by maximum likelihood
    assert np.allclose(res.noise_std, 0.05, rtol=0.1)
    assert np.allclose(res.solver["position_noise_std"], 1e-4, rtol=0.2)
    assert all(0.8 < v < 1.25 for v in res.solver["innovation_nms"].values()) and res.solver["nis_test"]["passed"]
    assert res.solver["prior"]["center"] == "nominal base parameters" and len(res.solver["prior"]["std"]) == p
    assert any("assumes the model's noise levels" in n for n in res.notes)


@pytest.mark.numerics
def test_an_inconsistent_filter_reports_no_covariance(arm_log):
    """The NIS test: told a position noise 10 times below the log's (1e-5 rad given, 1e-4 in the
    log), the UKF's position innovations are about 1e-4 / sqrt(P_zz) times too large, so their
    normalized mean square is far above the test's bound (about 1.12 for 1800 steps and 6
    channels at false alarm 1e-3; the predicted innovation std is at most that of the state's
    a-priori position plus 1e-5, well below 1e-4 for the white-snap model fitted to this smooth
    motion): the result must carry no covariance and say why, with the figures in ``solver``.
    The same log with its own noise estimate passes (test_filters_recover_the_simulated_arm)."""
    from dynid.estimation.kalman_filters import nis_bound
    from dynid.pipeline.kalman_estimate import kalman_identify

    system, base, _, ds, _ = arm_log
    res, _ = kalman_identify("ukf", system, base, ds, position_noise_std=np.full(3, 1e-5))
    test = res.solver["nis_test"]
    assert not test["passed"] and res.cov_params is None
    assert test["bound"] == pytest.approx(nis_bound(test["steps"], 6, FALSE_ALARM))
    assert max(res.solver["innovation_nms"].values()) > test["bound"]
    assert any("no covariance is reported" in n and "NIS test" in n for n in res.notes)


@pytest.fixture(scope="module")
def fivebar_log():
    """builtin:fivebar (a closed chain, 2 actuators) along a smooth random motion of its actuators
    about the assembly guess (5 harmonics of 0.1 Hz, about 0.3 rad), 10 s at 100 Hz: forces from
    its actuator-space rows at the exact states with a 10 %-perturbed truth, white force noise
    0.02 N*m and position noise 1e-4 rad."""
    from dynid.dataset import Dataset
    from dynid.model.loading import load_model
    from dynid.model.system import as_system

    system = as_system(load_model("builtin:fivebar"))
    base = system.base_parameters()
    rng = np.random.default_rng(seed(76))
    t = np.arange(1000) / 100.0
    k = np.arange(1, 6)
    w = 2 * np.pi * 0.1 * k
    A, B = (rng.standard_normal((2, 5)) * 0.3 / k for _ in range(2))
    s, c = np.sin(np.outer(t, w)), np.cos(np.outer(t, w))
    qa0 = system.model.q_guess[list(system.model.actuated)]
    q = qa0 + s @ A.T + c @ B.T - B.sum(axis=1)
    dq, ddq = c @ (A * w).T - s @ (B * w).T, -s @ (A * w**2).T - c @ (B * w**2).T
    nominal = system.nominal_parameters()
    truth = base.from_standard(nominal * (1 + 0.1 * rng.standard_normal(nominal.size)))
    W = base.regressor(system.rows(None)(q, dq, ddq, np.zeros_like(q)).W)
    tau = W @ truth + 0.02 * rng.standard_normal(q.shape)
    ds = Dataset(t=t, q=q + 1e-4 * rng.standard_normal(q.shape), tau=tau, dq=dq, ddq=ddq, names=system.actuator_names)
    return system, base, truth, ds


@pytest.mark.numerics
@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_filters_recover_a_closed_chain(fivebar_log, kind):
    """The same filters through a closed chain's rows (the loop closures solved at each state):
    the truth in the reported ellipsoid (chi-square with p degrees of freedom, false alarm 1e-3,
    as for the serial arm)."""
    from dynid.pipeline.kalman_estimate import kalman_identify

    system, base, truth, ds = fivebar_log
    res, _ = kalman_identify(kind, system, base, ds)
    assert _statistic(res.params - truth, res.cov_params) <= chi2.ppf(1 - FALSE_ALARM, base.n_base)
    assert all(0.8 < v < 1.25 for v in res.solver["innovation_nms"].values())


# ------------------------------------------------------------------ the pipeline and (e) configuration
def _doc(method: str = "ekf") -> dict:
    return {"robot": {"model": "builtin:puma560"},
            "data": {"file": "train.csv", "time": {"column": "t"}, "position": {"columns": ["q1", "q2"]},
                     "effort": {"columns": ["tau1", "tau2"]}},
            "validation": {"file": "valid.csv"}, "identification": {"method": method}}


@pytest.mark.parametrize("method", ["ekf", "ukf"])
@pytest.mark.parametrize("key, value, message", [
    ("physical_consistency", True, "physical_consistency = true is available with methods"),
    ("noise_covariance", "residuals", "noise_covariance is for method"),
    ("covariance", "hac", "covariance = 'hac' is for the linear least-squares methods"),
    ("coulomb_smoothing", "auto", "coulomb_smoothing is available with methods"),
    ("experiment", "sim.toml", "experiment is for method = 'iv', 'didim' or 'cloe'"),
])
def test_settings_that_do_not_apply_are_refused(method, key, value, message):
    from dynid.config import parse_config

    doc = _doc(method)
    doc["identification"][key] = value
    with pytest.raises(ConfigError, match=message) as err:
        parse_config(doc, Path("/cfg"))
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_streaming_cluster_and_several_logs_are_refused(method):
    from dynid.config import parse_config
    from dynid.model import load_robot
    from dynid.model.system import SerialSystem
    from dynid.pipeline import streaming
    from dynid.pipeline.cluster_qr import check
    from dynid.pipeline.experiments import check_several

    cfg = parse_config(_doc(method), Path("/cfg"))
    why = streaming._why_not(cfg, SerialSystem(load_robot("builtin:puma560")))
    assert why == f"method {method!r} is not one compressed least-squares problem"
    doc = _doc(method)
    doc["identification"]["cluster"] = "local"
    with pytest.raises(ConfigError, match="the cluster runs the streamed path and this run is held in memory"):
        check(parse_config(doc, Path("/cfg")), why)
    doc = _doc(method)
    doc["data"] = [copy.deepcopy(doc["data"]), {**copy.deepcopy(doc["data"]), "file": "train2.csv"}]
    with pytest.raises(ConfigError, match=f"identification.method = {method!r}") as err:
        check_several(parse_config(doc, Path("/cfg")))
    assert "\n" not in str(err.value)


@pytest.fixture(scope="module")
def arrays(arm_log):
    ds = arm_log[3]
    return ds.t, ds.q, ds.tau, ds.t.size


def test_pipeline_runs_the_filters_and_refuses_what_they_cannot_filter(arrays):
    """``identify_arrays(method="ukf")`` (the dispatch of ``dynid identify``) gives a UKF result
    scored on the held-out rows; a periodic processing and parallel decimation are refused in
    one line (the filter needs the processed log as a uniformly sampled sequence)."""
    from conftest import REPO

    import dynid

    t, q, tau, n = arrays
    out = dynid.identify_arrays(str(REPO / ARM), t, q, tau, method="ukf", extras=list(EXTRAS), derivatives="kalman")
    assert out.result.method == "UKF" and out.result.cov_params is not None
    assert np.all(out.validation.rmse < 0.06)  # the force noise is 0.05 N*m
    record = json.loads(json.dumps(out.result.to_dict()))  # result.json's content
    assert record["method"] == "UKF" and "innovation_nms" in record["solver"]
    with pytest.raises(ConfigError, match="decimate_method = 'parallel' filters the regressor rows") as err:
        dynid.identify_arrays(str(REPO / ARM), t, q, tau, method="ekf", extras=list(EXTRAS), decimate=2,
                              decimate_method="parallel")
    assert "\n" not in str(err.value)
