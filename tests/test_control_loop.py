"""Identification through the control loop: IDIM-IV and DIDIM (``method = "iv"`` / ``"didim"``).

* The IV solve with the regressor as its own instrument is weighted least squares (estimate and
  covariance checked against the WLS estimator, an independent route).
* On a linear model with errors in the variables, least squares is biased by the attenuation
  factor and the IV estimate with noise-free instruments is not (Janot 2014): checked at margins
  derived from the reported standard deviations.
* DIDIM on shang2dof twins (paper 001's robot under its augmented PD, filtered positions, parallel
  decimation): with the truth as the nominal model and noise-free forces the replayed experiment is
  the experiment itself and DIDIM returns the truth up to the noise; with a 10 % perturbed
  truth and noise, DIDIM converges from the nominal model and predicts the held-out path better
  than the nominal model.
* Bad settings give one-line errors.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import sdp_chi2_slack, seed
from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError
from dynid.estimation import WLS, ProblemBuilder
from dynid.estimation.instrumental import InstrumentBuilder, iv_solve, iv_solve_truncated
from dynid.pipeline import identify
from dynid.pipeline.simulate import run_simulation, write_simulation


def test_iv_with_the_regressor_as_instrument_is_wls():
    rng = np.random.default_rng(0)
    n, p = 400, 4
    W = rng.standard_normal((n, 2, p))
    beta = np.array([1.0, -2.0, 0.5, 3.0])
    y = W @ beta + np.array([0.1, 0.3]) * rng.standard_normal((n, 2))
    ib = InstrumentBuilder([f"b{k}" for k in range(p)], ["c0", "c1"])
    pb = ProblemBuilder([f"b{k}" for k in range(p)], ["c0", "c1"])
    for a in range(0, n, 150):  # chunks
        ib.add(W[a:a + 150], W[a:a + 150], y[a:a + 150])
        pb.add(W[a:a + 150], y[a:a + 150])
    wls = WLS().fit(pb.build())
    est, cov, _ = iv_solve(ib.build(), wls.noise_std)
    np.testing.assert_allclose(est, wls.params, rtol=1e-9, atol=1e-12)
    # WLS scales its covariance by the weighted residual variance (close to, not exactly, 1)
    np.testing.assert_allclose(cov * wls.scale, wls.cov_params, rtol=1e-8, atol=1e-14)


@pytest.mark.numerics
def test_iv_removes_the_errors_in_variables_bias():
    """y = x beta + e with x measured as x + u: least squares shrinks beta by
    var(x) / (var(x) + var(u)) (here 0.8), IV with the true x as instrument does not."""
    rng = np.random.default_rng(seed(1))
    n, beta = 20000, np.array([2.0, -1.0])
    x = rng.standard_normal((n, 1, 2))
    y = x @ beta + 0.2 * rng.standard_normal((n, 1))
    x_meas = x + 0.5 * rng.standard_normal(x.shape)
    ib = InstrumentBuilder(["b0", "b1"], ["c"])
    ib.add(x, x_meas, y)
    pb = ProblemBuilder(["b0", "b1"], ["c"])
    pb.add(x_meas, y)
    ls = WLS().fit(pb.build())
    problem = ib.build()
    sigma = np.sqrt(problem.rss_per_channel(ls.params) / n)
    for _ in range(3):
        est, cov, _ = iv_solve(problem, sigma)
        sigma = np.sqrt(problem.rss_per_channel(est) / n)
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(est - beta) < 4.5 * sd)  # false alarm < 1e-5 per parameter
    assert np.all(np.abs(ls.params - 0.8 * beta) < 4.5 * ls.bse)  # the attenuation, as the theory says
    assert np.all(np.abs(ls.params - beta) > 10 * ls.bse)  # far outside its own intervals


@pytest.mark.numerics
def test_truncated_iv_holds_the_directions_the_instruments_do_not_determine():
    """b2 = b0 + 1e-7 xi in the instruments and the regressor (plus regressor noise): Z^T W has one
    singular value near 1e-7 of the others. With rtol = 0 the truncated solve is :func:`iv_solve`;
    with rtol = 1e-4 the estimate moves from the start only along the two determined directions (the
    held one keeps the start's component exactly), and there it is the truth within its standard
    deviations."""
    rng = np.random.default_rng(seed(2))
    n = 5000
    z = rng.standard_normal((n, 1, 3))
    z[:, :, 2] = z[:, :, 0] + 1e-7 * rng.standard_normal((n, 1))
    beta = np.array([1.0, -2.0, 0.5])
    y = z @ beta + 0.1 * rng.standard_normal((n, 1))
    W = z + 0.05 * rng.standard_normal(z.shape)
    ib = InstrumentBuilder(["b0", "b1", "b2"], ["c"])
    ib.add(z, W, y)
    problem, sigma = ib.build(), np.array([0.1])
    start = np.array([0.7, -1.0, 0.8])
    full, _, full_cond = iv_solve(problem, sigma)
    same, _, same_cond, rank = iv_solve_truncated(problem, sigma, start, 0.0)
    w = 1.0 / sigma**2
    d = np.sqrt(np.diag(np.einsum("j,jik->ik", w, problem.ZZ)))
    # the same solution by another factorization: equal up to the rounding of a system of condition cond
    assert rank == 3 and 0.5 < same_cond / full_cond < 2
    assert np.linalg.norm(d * (same - full)) < 100 * np.finfo(float).eps * full_cond * np.linalg.norm(d * full)
    est, cov, cond, rank = iv_solve_truncated(problem, sigma, start, 1e-4)
    assert rank == 2 and cond < 1e3
    # the held direction: in the solve's scaled coordinates, the last right singular vector
    vt = np.linalg.svd(np.einsum("j,jik->ik", w, problem.ZW) / np.outer(d, d))[2]
    assert abs(vt[-1] @ (d * (est - start))) < 1e-9 * np.linalg.norm(d * start)
    # the determined directions: b1 and b0 + b2, at the truth within 4.5 sd (false alarm < 1e-5 each)
    for a in (np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 1.0])):
        sd = np.sqrt(a @ cov @ a)
        assert abs(a @ (est - beta)) < 4.5 * sd


_SIM = {
    "robot": {"model": "builtin:shang2dof", "perturbation": 0.1, "perturbation_seed": 3},
    "control": {"kind": "computed_torque", "rate_hz": 500.0, "kp": 35000.0, "kd": 300.0, "model": "nominal",
                "distribution": "min_norm_local_friction"},
    "sensors": {"encoder_resolution": 5.992e-6, "force_noise_std": 0.02, "force_correlation": 0.3},
}
_TRAIN = {"kind": "circle", "centre": [0.29, 0.25], "radius": 0.04, "speed": 0.2, "turns": 4, "clockwise": True,
          "ramp": 0.2}
_VALID = {"kind": "polyline", "vertices": [[0.244, 0.286], [0.343, 0.21], [0.343, 0.286], [0.244, 0.21],
                                            [0.244, 0.286]], "speed": 0.1, "ramp": 0.1}


def _toml(doc: dict) -> str:
    """A simulate config as TOML (flat tables of numbers, strings and lists)."""
    lines = []
    for section, table in doc.items():
        lines.append(f"[{section}]")
        for k, v in table.items():
            lines.append(f"{k} = {json.dumps(v)}")
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    d = tmp_path_factory.mktemp("didim")
    for name, traj, k in (("train", _TRAIN, 1), ("valid", _VALID, 2)):  # the true robot keeps its perturbation_seed
        doc = {**_SIM, "trajectory": traj, "sensors": {**_SIM["sensors"], "seed": seed(k)}}
        (d / f"{name}.toml").write_text(_toml(doc))
        write_simulation(run_simulation(parse_simulate_config(doc, d)), d / name)
    return d


def _config(d, method: str, **identification):
    cols = lambda p: [f"{p}_qa{k}" for k in (1, 2, 3)]  # noqa: E731
    return parse_config({
        "robot": {"model": "builtin:shang2dof"},
        "data": {"file": "train/log.csv", "time": {"column": "t", "unit": "s"},
                 "position": {"columns": cols("q"), "unit": "rad"},
                 "effort": {"columns": cols("tau"), "kind": "torque", "unit": "N*m"}},
        "validation": {"file": "valid/log.csv"},
        "processing": {"lowpass": {"cutoff_hz": 20.0, "order": 4, "filter_effort": False}, "derivatives": "central",
                       "decimate": 5, "decimate_method": "parallel"},
        # "full": the truth's chains differ (perturbation) and the tests compare with its base parameters
        "identification": {"method": method, "force_model": "projected", "structure": "full", **identification},
    }, d)


def _z(outcome, d) -> np.ndarray:
    truth = json.loads((d / "train" / "truth.json").read_text())
    true_base = outcome.base.from_standard(np.array(truth["true_parameters"]))
    r = outcome.result
    return (r.params - true_base) / r.bse


@pytest.mark.numerics
def test_didim_replays_the_experiment_exactly(tmp_path):
    """Truth = nominal model, noise-free forces: the experiment replayed on the nominal model is the
    experiment itself (same controller, reference, instants and processing), so the first DIDIM
    step returns the true base parameters up to the 1e-9 N*m noise, and the iteration stays there
    (with the experiment's discontinuous Coulomb law in the replay, DIDIM's default; IV's default
    regularized law is another model near reversals)."""
    doc = {**_SIM, "robot": {"model": "builtin:shang2dof"}, "trajectory": {**_TRAIN, "turns": 2},
           "sensors": {"encoder_resolution": 5.992e-6, "force_noise_std": 1e-9, "seed": seed(1)}}
    (tmp_path / "train.toml").write_text(_toml(doc))
    write_simulation(run_simulation(parse_simulate_config(doc, tmp_path)), tmp_path / "train")
    write_simulation(run_simulation(parse_simulate_config({**doc, "trajectory": _VALID}, tmp_path)), tmp_path / "valid")
    # the replay with the experiment's own (discontinuous) Coulomb law: DIDIM's default
    assert _config(tmp_path, "didim", experiment="train.toml").identification.replay_coulomb_band == 0.0
    out = identify(_config(tmp_path, "didim", experiment="train.toml"))
    r = out.result
    true_base = out.base.from_standard(np.array(json.loads((tmp_path / "train" / "truth.json").read_text())["true_parameters"]))
    # exact replay: the forces are predicted to the 1e-9 N*m noise sample by sample (a controller,
    # reference, instant or processing that differed would leave orders of magnitude more) ...
    assert np.all(np.sqrt(r.rss_per_channel / r.n_obs) < 1e-7)
    # ... and the truth comes back up to that noise through the short log's conditioning (< 1e4)
    np.testing.assert_allclose(r.params, true_base, rtol=0, atol=1e-5 * np.abs(true_base).max())
    assert r.solver["converged"]


@pytest.mark.numerics
def test_didim_from_the_nominal_model_beats_it(twin):
    """A 10 % perturbed truth with noise: DIDIM converges from the nominal model, predicts the held-out
    path better than the nominal model, and is no further from the truth than the nominal model in
    the metric of its own covariance (the short log's intervals are not asserted to cover: see
    bench/README, identification through the control loop)."""
    didim = identify(_config(twin, "didim", experiment="train.toml"))
    r = didim.result
    assert r.method == "DIDIM" and r.solver["start"] == "nominal"
    hist = r.solver["iterations"]
    assert 1 <= len(hist) <= 10 and r.solver["converged"]
    assert hist[-1]["max_change_in_std"] < 0.5 < hist[0]["max_change_in_std"]
    # a step that reversed along the previous move (negative secant eigenvalue) and only such a step
    # had its component along that move relaxed by 1 / (1 - lambda) (oscillation_relaxation), and
    # the result's notes say after which iterations
    for h in hist:
        lam = h.get("secant_eigenvalue")
        assert ("relaxation" in h) == (lam is not None and lam < 0.0), h
        if "relaxation" in h:
            assert h["relaxation"] == pytest.approx(1.0 / (1.0 - lam), rel=1e-12)
    assert any("oscillated" in n for n in r.notes) == any("relaxation" in h for h in hist)
    # the criterion DIDIM minimizes: the output error of the forces simulated with the iterate
    # (W(q_s(beta_k)) beta_k), recorded per iteration, lower at the converged iterate than at the
    # nominal model it started from (10 % from the truth: far outside the noise)
    oe = [np.sum(np.square(h["output_error_rmse_per_channel"])) for h in hist]
    assert oe[-1] < oe[0], oe
    prior = didim.prior
    assert prior["beats_nominal"], prior["verdict"]
    truth = json.loads((twin / "train" / "truth.json").read_text())
    nominal_base = didim.base.from_standard(np.array(truth["nominal_parameters"]))
    z_nominal = (nominal_base - didim.base.from_standard(np.array(truth["true_parameters"]))) / r.bse
    assert np.linalg.norm(_z(didim, twin)) < np.linalg.norm(z_nominal)


@pytest.mark.numerics
def test_physically_consistent_didim_is_the_projection_of_its_unconstrained_fixed_point(twin):
    """DIDIM with physical_consistency: consistent iterates, and the reported estimate is the
    unconstrained step at the last iterate projected onto the consistent set in the metric of the
    reported covariance (checked by an independent route: no consistent point of a random family
    near the estimate is closer in that metric), with no friction of the wrong sign."""
    from dynid.estimation import is_feasible

    out = identify(_config(twin, "didim", experiment="train.toml", physical_consistency=True))
    r = out.result
    assert r.method == "DIDIM + WLS+LMI (projected)" and r.cov_params is not None
    assert np.all(np.isfinite(r.bse)) and np.all(r.bse > 0)
    smap = out.system.standard_map(out.base)
    assert is_feasible(r.params, smap)
    for name, v in zip(r.names, r.params):
        if name.startswith(("fv", "fc+")):
            assert v >= 0, (name, v)
        if name.startswith("fc-"):
            assert v <= 0, (name, v)
    free = np.array(r.solver["unconstrained_params"])
    Sinv = np.linalg.inv(r.cov_params)
    d = float((r.params - free) @ Sinv @ (r.params - free))
    # the reported distance is the SDP's own ||A pi - d||^2 (A = U^-1 B, Sigma = U U^T): the same number
    # by another factorization, equal to rounding amplified by cond(Sigma) (~1e6 here: ~1e-10 relative)
    np.testing.assert_allclose(d, r.solver["projection_distance_chi2"], rtol=1e-6, atol=1e-9)
    # the standard vector reported with it solves the same projection with a tie-break towards the
    # nominal model, which may cost up to its reported residual increase (delta). For every consistent
    # x, ||x - P||^2 <= f(x) - f(P) in the metric (f the squared distance to the unconstrained estimate,
    # P the exact projection: the Pythagorean inequality of a projection onto a convex set), and the
    # first solve stops at most eps above f(P) (Clarabel's gap, conftest.sdp_chi2_slack); so B pi_std
    # is within sqrt(delta + eps) + sqrt(eps) of the reported estimate in the covariance's metric (on
    # the issue-33 machine the two differed by 4e-4 relative: a fixed atol was not what the method gives)
    st = r.solver["projection_stages"]
    assert st["standard"]["buffer"] == st["sdp"]["buffer"]  # the same feasible set for both solves
    eps = max(sdp_chi2_slack(np.sqrt(d), st[k]) for k in ("sdp", "standard"))
    delta = max(st["standard"]["residual_increase_chi2"], 0.0)
    std = np.array(list(r.solver["standard_params"].values()))
    e = smap.B @ std - r.params
    assert np.sqrt(e @ Sinv @ e) <= np.sqrt(delta + eps) + np.sqrt(eps), (e @ Sinv @ e, delta, eps)
    # the projection is the closest consistent point: moving towards the unconstrained estimate
    # along any segment from it leaves the set or gets no closer (convexity: checked on a segment
    # to the truth, which is consistent, and its convex combinations)
    truth = json.loads((twin / "train" / "truth.json").read_text())
    true_base = out.base.from_standard(np.array(truth["true_parameters"]))
    dist = lambda x: float((x - free) @ Sinv @ (x - free))  # noqa: E731
    for a in (0.25, 0.5, 0.75, 1.0):
        assert dist(r.params + a * (true_base - r.params)) >= d - eps  # the solve's own suboptimality
    assert out.prior["beats_nominal"], out.prior["verdict"]


@pytest.mark.numerics
def test_iv_runs_through_the_loop(twin, monkeypatch):
    """IV runs; its instrument rows start the loop-closure solve from the simulated joint positions
    (bench/README, control-loop identification time): the same estimate as starting from the
    previous sample, whose solves converge to the same positions (Gauss-Newton to a 1e-10 step,
    quadratically: tests/test_closed_loop.py) - asserted to 1e-6 of the standard deviations."""
    import dynid.pipeline.control_loop as cl

    iv = identify(_config(twin, "iv", experiment="train.toml", max_iterations=2))
    r = iv.result
    assert r.method == "IV" and r.solver["start"] == "wls" and len(r.solver["iterations"]) <= 2
    assert 0 < r.solver["instrumented_directions"] <= len(r.params)
    assert r.cov_params is not None and np.all(np.isfinite(r.bse)) and np.all(r.bse > 0)
    assert "instruments" in " ".join(r.notes)
    simulated = cl._simulated_states
    starts = []

    def without_joint_positions(*args, **kwargs):
        out = simulated(*args, **kwargs)
        starts.append(out[3] is not None)
        return (*out[:3], None)

    monkeypatch.setattr(cl, "_simulated_states", without_joint_positions)
    old = identify(_config(twin, "iv", experiment="train.toml", max_iterations=2)).result
    assert starts and all(starts)  # the replays do have the joint positions
    assert len(old.solver["iterations"]) == len(r.solver["iterations"])
    np.testing.assert_allclose(r.params, old.params, rtol=0, atol=1e-6 * r.bse.min())


@pytest.mark.parametrize("identification, fragment", [
    ({"method": "iv"}, "set identification.experiment"),
    ({"method": "wls", "experiment": "train.toml"}, "is for method = 'iv', 'didim' or 'cloe'"),
    ({"method": "didim", "experiment": "train.toml", "start": "truth"}, "identification.start"),
    ({"method": "iv", "experiment": "train.toml", "physical_consistency": True}, "physical_consistency"),
])
def test_bad_settings(twin, identification, fragment):
    with pytest.raises(ConfigError, match=fragment):
        _config(twin, **identification)


def test_the_experiment_must_simulate_the_identified_robot(twin):
    (twin / "other.toml").write_text(_toml({**_SIM, "robot": {"model": "builtin:fivebar"}, "trajectory": _TRAIN}))
    with pytest.raises(ConfigError, match="the experiment must simulate the robot being identified"):
        identify(_config(twin, "didim", experiment="other.toml"))


def test_fixed_point_covariance_of_a_linear_iteration():
    """beta_{k+1} = b + M beta_k with one-step covariance C: the fixed point (I - M)^-1 b has the
    covariance (I - M)^-1 C (I - M)^-T; the secants of the iterates recover M exactly on a
    linear map (here the iterates span the whole space)."""
    from dynid.estimation.instrumental import fixed_point_covariance

    rng = np.random.default_rng(3)
    Q = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    M = Q @ np.diag([0.6, -0.3, 0.1]) @ Q.T
    b = np.array([1.0, -2.0, 0.5])
    C = np.diag([0.04, 0.01, 0.09])
    x = np.array([5.0, 5.0, -5.0])
    xs, fs = [], []
    for _ in range(6):
        fx = b + M @ x
        xs.append(x)
        fs.append(fx)
        x = fx
    cov, eig = fixed_point_covariance(np.array(xs), np.array(fs), C, rtol=1e-9)
    A = np.linalg.inv(np.eye(3) - M)
    np.testing.assert_allclose(cov, A @ C @ A.T, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(np.sort(eig.real), [-0.3, 0.1, 0.6], atol=1e-6)
    # a diverging iteration is not corrected (its fixed point is not what it converges to)
    xs2 = [np.zeros(3), np.ones(3), 3 * np.ones(3)]
    cov2, _ = fixed_point_covariance(np.array(xs2[:2]), np.array(xs2[1:]), C)
    assert cov2 is C or np.array_equal(cov2, C)


def test_regularized_coulomb_law_of_the_replay():
    """The replays' Coulomb law tanh(v / v_b): continuous at rest (no Coulomb force at v = 0), the
    discontinuous law's forces to 1 - tanh(3) < 0.5 % of the Coulomb level beyond 3 bands, the
    viscous terms unchanged; a band that is not positive is refused."""
    from dynid.errors import InputError
    from dynid.model.loading import load_model
    from dynid.simulation.closed_loop import ConstrainedSimulator

    mech = load_model("builtin:shang2dof")
    pi = mech.nominal_parameters()
    sign_law, band = ConstrainedSimulator(mech, pi), 0.05
    smooth = ConstrainedSimulator(mech, pi, coulomb_band=band)
    n_v = sign_law.model.nv
    tau = np.zeros(n_v)
    a, b, c, d, e = sign_law._friction_coefficients  # levels c (v > 0) and d (v < 0), asymmetric here
    assert np.any(c != 0) and not np.any(e)  # the twin has Coulomb terms: the checks below are not vacuous
    for v in (3.0 * band, 10.0 * band, -4.0 * band):
        dq = np.full(n_v, v)
        diff = smooth.joint_forces(dq, np.zeros(mech.n_actuators)) - sign_law.joint_forces(dq, np.zeros(mech.n_actuators))
        level = np.abs(c if v > 0 else d)
        assert np.all(np.abs(diff) <= (1.0 - np.tanh(abs(v) / band)) * level + 1e-12)
    # continuous: at rest the Coulomb force is the mean of the two levels times |tanh(0)| = 0, and a
    # velocity of 1e-9 bands gives 1e-9 of the levels
    np.testing.assert_allclose(smooth._joint_forces(np.zeros(n_v), tau), 0.0, atol=1e-15)
    eps = 1e-9 * band
    bound = 1.01e-9 * (np.abs(c) + np.abs(d)) + np.abs(a) * eps + 1e-15
    assert np.all(np.abs(smooth._joint_forces(np.full(n_v, eps), tau)) <= bound)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="coulomb_band"):
            ConstrainedSimulator(mech, pi, coulomb_band=bad)


def test_fixed_directions_give_the_truncated_solve_at_the_start():
    """determined_directions + reduce_instrumental (IV on the fixed combinations ``Z TU``, ``W TV``)
    is, on the problem the directions were chosen from, the truncated-SVD solve
    (:func:`iv_solve_truncated`): the same estimate and covariance up to rounding; the estimate
    moves from the start only within range(TV)."""
    from dynid.estimation.instrumental import determined_directions, reduce_instrumental

    rng = np.random.default_rng(5)
    n = 4000
    z = rng.standard_normal((n, 2, 4))
    z[:, :, 3] = z[:, :, 0] + 1e-7 * rng.standard_normal((n, 2))
    beta = np.array([1.0, -2.0, 0.5, 0.3])
    y = z @ beta + 0.1 * rng.standard_normal((n, 2))
    W = z + 0.05 * rng.standard_normal(z.shape)
    ib = InstrumentBuilder([f"b{k}" for k in range(4)], ["c0", "c1"])
    ib.add(z, W, y)
    problem, sigma, start = ib.build(), np.array([0.1, 0.12]), np.array([0.7, -1.0, 0.8, 0.1])
    ref, ref_cov, _, rank = iv_solve_truncated(problem, sigma, start, 1e-4)
    w = 1.0 / sigma**2
    TU, TV, rel = determined_directions(np.einsum("j,jik->ik", w, problem.ZW), np.einsum("j,jik->ik", w, problem.ZZ), 1e-4)
    assert TV.shape == (4, rank) and rank == 3 and rel[-1] < 1e-4 <= rel[rank - 1]
    c, cov_c, _ = iv_solve(reduce_instrumental(problem, TU, TV, start, ["c1", "c2", "c3"]), sigma)
    est, cov = start + TV @ c, TV @ cov_c @ TV.T
    np.testing.assert_allclose(est, ref, rtol=0, atol=1e-9 * np.abs(ref).max())
    np.testing.assert_allclose(cov, ref_cov, rtol=0, atol=1e-8 * np.abs(ref_cov).max())
    move = est - start
    np.testing.assert_allclose(TV @ np.linalg.lstsq(TV, move, rcond=None)[0], move, atol=1e-12 * np.abs(move).max())


def _rounded_copy(twin, dest, rel: float = 1e-12):
    """The twin's logs with the training forces changed by ``rel`` relative (a rounding-level
    difference, as between two builds' simulations of the same experiment)."""
    import shutil

    shutil.copytree(twin, dest)
    log = dest / "train" / "log.csv"
    lines = log.read_text().splitlines()
    head = lines[0].split(",")
    cols = [k for k, h in enumerate(head) if h.startswith("tau_")]
    rng = np.random.default_rng(11)
    out = [lines[0]]
    for line in lines[1:]:
        v = line.split(",")
        for k in cols:
            v[k] = repr(float(v[k]) * (1.0 + rel * rng.standard_normal()))
        out.append(",".join(v))
    log.write_text("\n".join(out) + "\n")
    return dest


@pytest.mark.numerics
@pytest.mark.parametrize("method", ["iv", "didim"])
def test_converges_to_the_same_estimate_on_logs_that_differ_by_rounding(twin, tmp_path, method):
    """IV and DIDIM from the nominal model converge on the shang2dof twin, and on the same logs with
    forces changed by 1e-12 (relative) they take the same path: the same number of iterations, no
    halving, the same estimate to 1e-3 of its standard deviations (the rounding grows by at most the
    iteration's contraction factor per step, below 1 in a smooth replay; bench/README: with the
    re-truncated directions and the discontinuous Coulomb law in IV's replays a 1e-13 difference of
    the data changed the outcome). Both beat the nominal model they start from on the held-out log
    (the prior is the first baseline; draws 0-3 of the noise: mean relative RMSE 6.0-6.7 % against
    9.8 %), and DIDIM is nearer the truth than WLS on the filtered data in the metric of WLS's own
    covariance (WLS's errors in the variables: chi2 740-900 for WLS, 12-26 for DIDIM on draws 0-3).
    The held-out RMSE of WLS against IV and DIDIM is not asserted: its ordering depends on the draw
    (WLS 0.35-0.57 N*m, IV 0.34-0.35, DIDIM 0.34-0.38; DIDIM above WLS on draw 1)."""
    outs = [identify(_config(d, method, experiment="train.toml", start="nominal"))
            for d in (twin, _rounded_copy(twin, tmp_path / "rounded"))]
    for o in outs:
        hist = o.result.solver["iterations"]
        assert o.result.solver["converged"] and all(h["step"] == 1.0 for h in hist), hist
    a, b = (o.result for o in outs)
    assert len(a.solver["iterations"]) == len(b.solver["iterations"])
    assert np.max(np.abs(a.params - b.params) / a.bse) < 1e-3
    assert a.solver["estimated_directions"]["count"] == b.solver["estimated_directions"]["count"]
    assert outs[0].prior["beats_nominal"], outs[0].prior["verdict"]
    if method == "didim":
        wls = identify(_config(twin, "wls"))
        truth = json.loads((twin / "train" / "truth.json").read_text())
        err = lambda r: r.params - outs[0].base.from_standard(np.array(truth["true_parameters"]))  # noqa: E731
        chi2 = lambda r: float(err(r) @ np.linalg.solve(wls.result.cov_params, err(r)))  # noqa: E731
        assert chi2(a) < chi2(wls.result)



_HEXAPOD = {
    "robot": {"model": "builtin:hexapod", "perturbation": 0.1, "perturbation_seed": 4},
    "trajectory": {"coordinates": "task", "kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.05,
                   "max_velocity": 0.1, "max_acceleration": 1.0, "periods": 1, "seed": 4},
    "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "substeps": 2},
    "sensors": {"encoder_resolution": 1e-6, "force_noise_std": 2.0, "force_correlation": 0.2, "seed": 4},
}


@pytest.mark.numerics
def test_didim_replay_rows_take_the_replay_coulomb_law(tmp_path, monkeypatch):
    """With ``replay_coulomb_band`` the replay's plant has the Coulomb law tanh(v / v_b); DIDIM's
    rows of that replay take the smooth sign of the same slope at zero (erf, width sqrt(2/pi) v_b,
    control_loop._replay_rows_system), so W(q_s) beta is the replayed force (Gautier 2013's
    premise: the simulated force is the model's own) to the 3.5 % of a Coulomb level by which the
    two laws differ, where rows with sign(v_s) miss it by up to the whole level wherever a joint is
    slower than v_b (the non-smooth output error that kept DIDIM from converging on this twin:
    bench/README). The hexapod twin of bench/control_loop_time.py (symmetric Coulomb levels), one
    period; checked on the replay's noise-free actuator forces, sample by sample after the same
    processing as the rows (a linear filter keeps the identity). The shang2dof twin's asymmetric
    levels keep sign rows (no matching smooth law)."""
    import dynid.pipeline.control_loop as CL
    from dynid.pipeline.simulate import actuator_states

    hexapod = {**_HEXAPOD, "trajectory": {**_HEXAPOD["trajectory"], "seed": seed(4)},
               "sensors": {**_HEXAPOD["sensors"], "seed": seed(4)}}
    (tmp_path / "train.toml").write_text(_toml(hexapod))
    write_simulation(run_simulation(parse_simulate_config(hexapod, tmp_path)), tmp_path / "train")
    valid = {**hexapod, "trajectory": {**hexapod["trajectory"], "seed": seed(5)}}
    write_simulation(run_simulation(parse_simulate_config(valid, tmp_path)), tmp_path / "valid")
    captured = {}
    original = CL.control_loop_estimate

    def capture(*args, **kwargs):
        captured["args"] = args
        return original(*args, **kwargs)

    monkeypatch.setattr(CL, "control_loop_estimate", capture)
    act = [f"P{k}" for k in range(1, 7)]
    out = identify(parse_config({
        "robot": {"model": "builtin:hexapod"},
        "data": {"file": "train/log.csv", "time": {"column": "t", "unit": "s"},
                 "position": {"columns": [f"q_{a}" for a in act], "unit": "m"},
                 "effort": {"columns": [f"tau_{a}" for a in act], "kind": "torque", "unit": "N"}},
        "validation": {"file": "valid/log.csv"},  # not what is checked
        "processing": {"lowpass": {"cutoff_hz": 10.0, "order": 4, "filter_effort": False},
                       "decimate": 5, "decimate_method": "parallel"},
        "identification": {"method": "didim", "experiment": "train.toml", "max_iterations": 1,
                           "replay_coulomb_band": 0.05, "directions_rtol": 1e-3},
        "output": {"plots": False}}, tmp_path))
    cfg, system, base, train, force_model, _, chunks = captured["args"][:7]
    band = 0.05 * float(np.max(np.abs(train.dq)))
    assert out.result.solver["replay_rows_coulomb_width"] == pytest.approx(np.sqrt(2 / np.pi) * band, rel=1e-12)
    exp = CL._experiment(cfg, system)
    std = system.expand_parameters(system.nominal_parameters())
    outcome = run_simulation(exp.cfg, plant=std[exp.index], coulomb_band=band)
    ts = actuator_states(outcome)[0]
    t = np.asarray(train.t, dtype=float)
    assert np.allclose(t, ts[np.searchsorted(ts, t - 1e-9)], rtol=0, atol=1e-9)  # the log's instants are control instants
    q, dq, ddq, joint_q = CL._simulated_states(exp, std, t, None, band)
    effort = np.column_stack([np.interp(t, ts, e) for e in outcome.signals.effort.T])
    sim = train.replace(q=q, dq=dq, ddq=ddq, tau=effort)
    beta = base.from_standard(system.nominal_parameters())

    def error(rows_system):
        res = [c.y - c.W @ beta for c in chunks(sim, joint_q, rows_system)]
        return float(np.max(np.abs(np.concatenate(res))))

    smooth, sign = error(CL._replay_rows_system(system, band)), error(None)
    # the log has samples well inside the band (reversals), where sign(v) misses >= 70 % of a level
    assert np.min(np.abs(dq)) < 0.3 * band
    assert smooth < 0.05 * sign, (smooth, sign)


def test_asymmetric_coulomb_levels_keep_sign_rows():
    """The shang2dof mechanism's fc+/fc- terms: no smooth law of the rows matches the replay's
    regularized asymmetric law (control_loop._replay_rows_system), so none is substituted."""
    import dynid.pipeline.control_loop as CL
    from dynid.model.loading import load_model
    from dynid.model.system import ClosedLoopSystem

    system = ClosedLoopSystem(load_model("builtin:shang2dof"))
    assert CL._replay_rows_system(system, 0.01) is None


@pytest.mark.numerics
@pytest.mark.parametrize("method", ["iv", "didim"])
def test_loop_results_predict_as_identify_validated(twin, tmp_path, capsys, method):
    """``dynid predict`` (issue 20 item 3) on a saved IV / DIDIM result of the redundant shang2dof
    (projected equations, parallel decimation): its own validation log gives the per-channel RMSE
    identify reported, identified and nominal, from what result.json holds (no replay is needed to
    predict: the estimate is base parameters of the same regressor)."""
    from dynid.cli import main
    from dynid.pipeline.identification import write_outputs

    o = identify(_config(twin, method, experiment="train.toml"))
    write_outputs(o, tmp_path / "out")
    cols = lambda p: [f"{p}_qa{k}" for k in (1, 2, 3)]  # noqa: E731
    log = tmp_path / "log.toml"
    log.write_text(f'[data]\nfile = "{twin / "valid" / "log.csv"}"\ntime = {{ column = "t", unit = "s" }}\n'
                   f'position = {{ columns = {cols("q")}, unit = "rad" }}\n'
                   f'effort = {{ columns = {cols("tau")}, kind = "torque", unit = "N*m" }}\n'.replace("'", '"'))
    rc = main(["predict", str(tmp_path / "out"), str(log), "--out", str(tmp_path / "pred"), "-q", "--no-plots"])
    assert rc == 0, capsys.readouterr().err
    pred = json.loads((tmp_path / "pred" / "predict.json").read_text())
    saved = json.loads((tmp_path / "out" / "result.json").read_text())
    assert saved["method"].startswith(method.upper())
    for mine, theirs in ((pred["identified"], saved["validation"]), (pred["nominal"], saved["nominal_validation"])):
        np.testing.assert_allclose(mine["rmse_per_joint"], theirs["rmse_per_joint"], rtol=1e-10)
    # and the loop's estimate predicts better than the nominal model it started from, on every channel
    assert all(r["better"] == "identified" for r in pred["per_joint"])
