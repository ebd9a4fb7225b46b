"""One contract over every identification method (issue 36, item 1): each method of
``[identification] method`` (:data:`dynid.config.identification._METHODS`), and WLS with
``physical_consistency``, recovers a simulated truth within its own joint confidence ellipsoid on
data where that method's assumptions hold, through the route a user takes (``dynid.pipeline.identify``
with a configuration; TLS through the estimator API, the only place its columns' error scales can be
given).

The parameter list is derived from ``_METHODS``: a method added there without a case here fails
:func:`test_contract` with "no contract case".

What each case asserts: the result reports a covariance (or says why it has none, and then that
statement is asserted), and the truth's statistic

    chi2 = (estimate - truth)^T C^-1 (estimate - truth)

under the reported covariance C is below the 1 - 1e-3 quantile of chi-square with p degrees of
freedom. Why this margin holds on any machine: under each method's own assumptions the estimate is
(asymptotically) Gaussian about the truth with the covariance it reports, so the statistic *is*
chi-square with p degrees of freedom whatever the BLAS kernel or thread count (those move the
estimate by rounding, ~1e-12 of a standard deviation for the linear methods, 1e-3 for the replays
of IV and DIDIM: tests/test_control_loop.py's rounding test; the statistics here are 6.7 or more below
their bounds); the seeds are fixed, so a case fails on
correct code with probability 1e-3 per draw (the draws were not chosen: seed k of conftest.seed for
every case), and a systematic failure is a method whose intervals do not hold.

The robots: a serial arm (examples/serial_arm/arm3.urdf with rotor inertia, viscous friction and
offsets: 22 base parameters) and a closed chain (builtin:fivebar, 2 actuators, 17 base parameters),
each along a smooth periodic motion whose positions, velocities and accelerations are known exactly
(the "exact states": ``processing.derivatives = "measured"``); the forces are the robot's own
regressor rows at those states times a 10 %-perturbed truth plus the noise each case names. The
methods that replay the experiment under its controller (IV, DIDIM, CLOE) run on a closed chain only,
tests/test_control_loop.py's shang2dof twin (1 turn; a serial arm's replays would double their share
of this file's time budget), logged with the measurement noise their covariances assume.

Where a method does not cover on such data the case is a strict xfail whose reason and comment give
the figures (:data:`FINDINGS`): a fix makes it pass, which fails the suite until the mark is removed.

A method that holds directions of the base parameters at its start's values (IV, DIDIM, CLOE:
``solver["estimated_directions"]``) says its standard errors are conditional on them (asserted); the
statistic is then taken in the estimated directions (the covariance's range, as many degrees of
freedom), and those cases start at the truth so that the held values are the true ones.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from conftest import REPO, seed
from dynid._files import save_npz
from dynid.config import parse_config
from dynid.config.identification import _METHODS
from dynid.pipeline import identify

FALSE_ALARM = 1e-3
ARM = REPO / "examples" / "serial_arm" / "arm3.urdf"
EXTRAS = ("Ia", "fv", "offset")  # no Coulomb friction: its sign is not smooth in the states (EKF/UKF, ML)
F0, HARMONICS, FS, PERIODS = 0.5, 4, 100.0, 4  # 4 periods of 2 s at 100 Hz: 800 samples
N_PER = int(round(FS / F0))


# ------------------------------------------------------------------------------------ the data
@functools.cache
def _motion(robot: str):
    """The robot's system, model table, true standard parameters and exact periodic motion
    (t, q, dq, ddq) of its actuators, and the base regressor rows at those states."""
    from dynid.model import load_robot
    from dynid.model.base_parameters import perturb_bodies
    from dynid.model.loading import load_model
    from dynid.model.system import SerialSystem, as_system
    from dynid.simulation import FourierTrajectory

    rng = np.random.default_rng(seed(81 if robot == "arm" else 82))
    t = np.arange(PERIODS * N_PER) / FS
    if robot == "arm":
        model = load_robot(str(ARM), extras=EXTRAS)
        system, table = SerialSystem(model), {"model": str(ARM), "extras": list(EXTRAS)}
        lo, hi = model.position_limits()
        traj = FourierTrajectory.random(3, HARMONICS, F0, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
        q, dq, ddq = traj.sample(t)
    else:
        system = as_system(load_model("builtin:fivebar"))
        # "full": the perturbed truth's two chains differ, so the data must not tie them
        table = {"model": "builtin:fivebar"}
        k = np.arange(1, HARMONICS + 1)
        w = 2 * np.pi * F0 * k
        A, B = (rng.standard_normal((2, HARMONICS)) * 0.3 / k**2 for _ in range(2))
        s, c = np.sin(np.outer(t, w)), np.cos(np.outer(t, w))
        qa0 = system.model.q_guess[list(system.model.actuated)]
        q = qa0 + s @ A.T + c @ B.T - B.sum(axis=1)
        dq, ddq = c @ (A * w).T - s @ (B * w).T, -s @ (A * w**2).T - c @ (B * w**2).T
    # 10 % away from the nominal model body by body, physically consistent by construction (a truth
    # drawn parameter by parameter is not, for some draws: the LMI case needs a feasible truth)
    truth = perturb_bodies(system.nominal_parameters(), system.body_blocks(), 0.1, rng)
    base = system.base_parameters()
    W = base.regressor(system.rows(None)(q, dq, ddq, np.zeros_like(q)).W)
    return system, table, truth, t, q, dq, ddq, W


def _cov(sigma, corr: float = 0.0) -> np.ndarray:
    """A force-noise covariance: standard deviations ``sigma``, one correlation between channels."""
    sigma = np.asarray(sigma, dtype=float)
    C = corr * np.ones((sigma.size, sigma.size)) + (1 - corr) * np.eye(sigma.size)
    return C * np.outer(sigma, sigma)


def _identify(tmp: Path, robot: str, method: str, force_cov, position_std: float = 0.0, k: int = 0,
              processing: dict | None = None, train_periods: int = PERIODS - 1, **identification):
    """The log (exact states, forces W truth + Gaussian noise of covariance ``force_cov``, positions
    with white noise ``position_std``), its configuration (3 periods trained, the last held out)
    and ``dynid.pipeline.identify``'s outcome; with the true base parameters. ``train_periods``: the
    periods trained on, from the first (the last period is held out)."""
    system, table, truth, t, q, dq, ddq, W = _motion(robot)
    rng = np.random.default_rng(seed(k))
    base = system.base_parameters()
    tau = W @ base.from_standard(truth) + rng.multivariate_normal(np.zeros(q.shape[1]), force_cov, size=t.size)
    names = system.actuator_names
    cols = {"t": t}
    for j, a in enumerate(names):
        cols[f"q_{a}"] = q[:, j] + position_std * rng.standard_normal(t.size)
        cols[f"dq_{a}"], cols[f"ddq_{a}"], cols[f"tau_{a}"] = dq[:, j], ddq[:, j], tau[:, j]
    save_npz(tmp / "log.npz", cols)
    col = lambda p: {"columns": [f"{p}_{a}" for a in names]}  # noqa: E731
    split = (PERIODS - 1) * N_PER
    data = {"file": str(tmp / "log.npz"), "time": {"column": "t", "unit": "s"}, "position": col("q"),
            "effort": col("tau"), "rows": [0, train_periods * N_PER]}
    if processing is None:  # the exact states
        data.update(velocity=col("dq"), acceleration=col("ddq"))
        processing = {"derivatives": "measured"}
    if robot != "arm":
        identification.setdefault("structure", "full")
    out = identify(parse_config({"robot": table, "data": data, "validation": {"rows": [split, t.size]},
                                 "processing": processing, "identification": {"method": method, **identification},
                                 "output": {"plots": False}}, tmp))
    return out.result, out.base.from_standard(truth)


# ------------------------------------------------------------------------------------ the cases
# Each case: (result, true base parameters) on data that meet the method's assumptions.
SIGMA = {"arm": np.array([0.05, 0.08, 0.03]), "fivebar": np.array([0.02, 0.03])}


def _ols(tmp, robot):
    # OLS: white force noise of ONE variance on every channel (its covariance s^2 (W^T W)^-1)
    return _identify(tmp, robot, "ols", _cov(np.full(SIGMA[robot].size, 0.04)), k=1)


def _wls(tmp, robot):
    # WLS (Gautier): white noise, independent between channels, each channel its own variance
    return _identify(tmp, robot, "wls", _cov(SIGMA[robot]), k=2)


def _wls_physical(tmp, robot):
    # WLS + LMI: WLS's assumptions and a physically consistent truth inside the feasible set
    # (checked below): no constraint active, the least-squares covariance (physical.py, Uncertainty)
    return _identify(tmp, robot, "wls", _cov(SIGMA[robot]), k=3, physical_consistency=True)


def _gm(tmp, robot):
    # Gauss-Markov: white in time, cross-correlated between channels (correlation 0.6), the
    # covariance estimated from the residuals (feasible GLS)
    return _identify(tmp, robot, "gm", _cov(SIGMA[robot], 0.6), k=4, iterations=2)


def _irls(tmp, robot):
    # IRLS: WLS's assumptions (independent channels of their own variances), reweighted to the fixed point
    return _identify(tmp, robot, "irls", _cov(SIGMA[robot]), k=5)


def _tls(tmp, robot):
    # generalized TLS (estimator API: the columns' error scales are given there only): every entry of
    # the regressor carries white noise of its column's standard deviation (a fraction of the column's
    # RMS: 1 % on the fivebar, 5e-5 on the arm, whose weakest direction is weakly excited: in units of the
    # column errors its singular value is 1.3 at 1 % against sqrt(n) = 49 for the errors, and TLS refuses,
    # kappa = 185; at 5e-5 it is 265, kappa - 1 = (49 / 265)^2 = 0.03),
    # the output white noise of one standard deviation; TLS told those scales (weighting "ols": no
    # whitening), the model of its first-order covariance (Van Huffel & Vandewalle 1991, section 8)
    from dynid.estimation import TLS, ProblemBuilder

    system, _, truth, t, q, _, _, W = _motion(robot)
    base = system.base_parameters()
    beta = base.from_standard(truth)
    rng = np.random.default_rng(seed(6))
    s_col = (5e-5 if robot == "arm" else 0.01) * np.sqrt(np.mean(W**2, axis=(0, 1)))
    s_y = 0.04
    y = W @ beta + s_y * rng.standard_normal(q.shape)
    b = ProblemBuilder(base.names, system.channel_names(None))
    b.add(W + s_col * rng.standard_normal(W.shape), y)
    return TLS(weighting="ols", error_std=(*s_col, s_y)).fit(b.build()), beta


def _ml(tmp, robot):
    # maximum likelihood with the cut-off (paper 004 Eq. 24): a periodic motion (whole periods of the
    # excitation's base frequency, band-limited to its harmonics), white position noise and white
    # force noise correlated between channels, both estimated from the period averaging (its default
    # "periodic" covariances); the positions are the only states it is given (it filters them)
    periodic = {"periodic": {"period_s": 1 / F0, "cutoff_hz": (HARMONICS + 0.5) * F0}}
    return _identify(tmp, robot, "ml", _cov(SIGMA[robot], 0.3), position_std=1e-5, k=7, processing=periodic)


def _kalman(kind):
    def case(tmp, robot):
        # EKF / UKF: white position noise and white force noise, independent between channels (the
        # filters' measurement model, dynid.pipeline.kalman_estimate), a smooth motion (the white-snap
        # process model), no Coulomb friction (its sign is not differentiable). Two periods (400
        # samples): the filters' cost is per sample (the file's time budget)
        return _identify(tmp, robot, kind, _cov(SIGMA[robot]), position_std=1e-4, k=8, train_periods=2)
    return case


def _loop(tmp, method, sensors: dict, processing: dict, k: int, turns: int = 1, perturbation: float = 0.1,
          **identification):
    """A closed-loop twin (tests/test_control_loop.py's shang2dof under its computed torque, a circle of
    ``turns`` turns) logged with the ``sensors`` given and no encoder quantization (the sensors' noise
    is then the only measurement error, added to the log, not seen by the controller:
    dynid.simulation.sensors), identified by ``method`` replaying that experiment (its simulate config)."""
    import json

    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.simulate import run_simulation, write_simulation
    from test_control_loop import _SIM, _TRAIN, _toml

    doc = {**_SIM, "robot": {**_SIM["robot"], "perturbation": perturbation},
           "trajectory": {**_TRAIN, "turns": turns}, "sensors": {**sensors, "seed": seed(k)}}
    (tmp / "train.toml").write_text(_toml(doc))
    write_simulation(run_simulation(parse_simulate_config(doc, tmp)), tmp / "train")
    n = sum(1 for _ in open(tmp / "train" / "log.csv")) - 1
    cols = lambda p: {"columns": [f"{p}_qa{j}" for j in (1, 2, 3)], "unit": "rad" if p == "q" else "N*m"}  # noqa: E731
    out = identify(parse_config({
        "robot": {"model": "builtin:shang2dof"},
        "data": {"file": "train/log.csv", "time": {"column": "t", "unit": "s"}, "position": cols("q"),
                 "effort": {**cols("tau"), "kind": "torque"}, "rows": [0, 3 * n // 4]},
        "validation": {"rows": [3 * n // 4, n]},
        "processing": processing,
        # "full": the perturbed truth's chains differ; "projected": no assumption on the force distribution
        "identification": {"method": method, "experiment": "train.toml", "force_model": "projected",
                           "structure": "full", **identification},
        "output": {"plots": False}}, tmp))
    truth = json.loads((tmp / "train" / "truth.json").read_text())
    return out.result, out.base.from_standard(np.array(truth["true_parameters"]))


# the positions low-pass filtered at 40 Hz (exact positions: the filter only smooths the 500 Hz control
# steps; at 20 Hz its distortion of the motion moved DIDIM's fixed point to a statistic of 36.7 for 14
# on the draw DYNID_TEST_SEED=1, beyond the 1e-3 bound; at 40 Hz, draws 0-5, converged cases: DIDIM
# 37.0, 11.8, 13.0, 9.5, 28.5 for 16 (bound 39.3; a mean of 1.25 x the degrees of freedom: its
# covariance is somewhat optimistic here, a finding), IV 15.8, 21.2, 19.1, 16.5, 16.5, 8.9),
# the forces as measured (white), every sample kept: a parallel decimation would filter the force
# noise and colour it. The force noise, 0.2 N*m, is 10 times the twin's of tests/test_control_loop.py:
# the processed states (filtered, central differences) differ from the true ones by a deterministic
# error, and at 0.02 N*m that error's share of the forces decides the statistic (IV one step from
# the truth: chi-square 125 for 22 directions at 0.02, 26.7 at 0.2; the statistic of an error that
# is not noise grows as 1 / noise^2)
_LOOP_PROCESSING = {"lowpass": {"cutoff_hz": 40.0, "order": 4, "filter_effort": False}, "derivatives": "central"}
_FORCE_NOISE = {"force_noise_std": 0.2}


# IV and DIDIM start at the truth (the twin's truth is its nominal model) and iterate to their fixed
# point: the covariance each reports there is what is asserted, in the 14 of 25 directions that
# directions_rtol = 1e-3 estimates (held at the start's values, here the true ones). Figures of this
# twin (seeds 9 and 10): IV moves 2.09 then 0.02 standard deviations, DIDIM 2.3 then 0.11: converged
# at iteration 2 (tolerance 0.5), statistics 18.1 and 14.9 for 14 (bound 36.1). Found, not asserted:
# with directions_rtol = 1e-6 (22 and 23 directions) neither converges from the truth (moves 2.4,
# 2.12 and 1.63, 1.14 at iterations 1-2) and a replay fails to simulate at iteration 3 (IV) and 7
# (DIDIM); from a 10 % perturbed truth (IV's default start "wls" or "nominal") a replay fails at
# iteration 1-5; the 4-turn twin that DIDIM needs there costs 20 s, did not converge in 10
# iterations and gave the truth's statistic 178 for 25 (bound 52.6)
def _iv(tmp, robot):
    # IDIM-IV (Janot 2014): force noise that is measurement noise (white, added to the log, not in the
    # loop): the instruments from the replays are independent of it
    return _loop(tmp, "iv", _FORCE_NOISE, _LOOP_PROCESSING, k=9, perturbation=0.0, start="nominal",
                 directions_rtol=1e-3)


def _didim(tmp, robot):
    # DIDIM (Gautier 2013): the same data (its output error is that of the forces: white measurement noise)
    return _loop(tmp, "didim", _FORCE_NOISE, _LOOP_PROCESSING, k=10, perturbation=0.0, directions_rtol=1e-3)


def _cloe(tmp, robot):
    # CLOE: white position measurement noise only (no force noise, no low-pass: the position output
    # errors at the truth are that white noise, the assumption of its covariance, dynid.pipeline.cloe).
    # Cost: 26 replays per iteration; from a 10 % perturbed truth it converges in 7 iterations, 80 s,
    # over this suite's budget, so the twin's truth is its nominal model (the start) and CLOE runs 1
    # iteration: the estimate is then the noise's fit about the truth, where its covariance is meant.
    # directions_rtol 1e-3 (17 directions: 19 replays, 7 s; the default 1e-6 estimates 25 in 27 replays).
    # Here the forces are exact, so the start's force regression fits to rounding: before the floor of
    # dynid.pipeline.cloe._coordinate_scale its finite-difference steps were rounding and the covariance
    # had rank 9 of 17 (tests/test_cloe.py, the refusal). Figures with the floor (seeds 11-14): the truth's
    # statistic 19.9, 18.2, 16.9 for 17 (bound 40.8), the undamped step accepted at once on 11 and 12
    # (cost down 1.1 %, about the 17 units of a noise fit), after 2 rejections on 14; on seed 13 the
    # replay's Coulomb jumps (about 10 cost units between neighbouring steps) reject it 5 times and the
    # step taken moves 0.024 standard deviations: statistic below 0.01, a pass that tests nothing
    return _loop(tmp, "cloe", {"position_noise_std": 1e-5}, {"derivatives": "central"}, k=11, perturbation=0.0,
                 max_iterations=1, directions_rtol=1e-3)


CASES = {
    "ols": _ols,
    "wls": _wls,
    "wls+physical_consistency": _wls_physical,
    "gm": _gm,
    "irls": _irls,
    "tls": _tls,
    "ml": _ml,
    "ekf": _kalman("ekf"),
    "ukf": _kalman("ukf"),
    "iv": _iv,
    "didim": _didim,
    "cloe": _cloe,
}
LOOP = ("iv", "didim", "cloe")  # the experiment replayed under its controller: one closed chain (cost)
ROBOTS = ("arm", "fivebar")
FINDINGS = {
    # (fixed, not a finding any more) the UKF was optimistic on the arm's 2 s periodic motion: the
    # truth's chi-square for p = 22 on draws seed(8..11) 67.6, 494, 673, 5.1e5, because its 2L sigma
    # points moved the kinematic state or the parameters along a square root whose rows separate
    # them, and so left out the product of their uncertainties in W(u) beta (the EKF adds it:
    # bilinear_second_order). The partially linear unscented update (dynid.estimation.kalman_filters)
    # marginalizes the parameters exactly: 21.7, 22.7, 22.9 (EKF 22.1, 22.4, 23.0; WLS on the exact
    # states 20.5, 18.9, 19.5); fivebar 28.2, 32.1, 15.9, 12.2 (was 34.1, 64.8, 14.9, 15.0). On draw
    # 11 both filters still diverge from the 100 % prior (innovations' normalized mean square 596 and
    # 644 on a position channel; with a 10 % prior the UKF gives 17.0): the NIS test then withholds
    # the covariance and says so (solver["nis_test"]), and this case would fail on that draw
}


def _params():
    out = []
    for method in (*_METHODS, "wls+physical_consistency"):
        for robot in (("shang2dof",) if method in LOOP else ROBOTS):
            why = FINDINGS.get((method, robot))
            marks = [pytest.mark.xfail(strict=True, reason=why)] if why else []
            out.append(pytest.param(method, robot, id=f"{method}-{robot}", marks=marks))
    return out


def _statistic(d: np.ndarray, cov: np.ndarray, rank: int | None = None) -> float:
    """d^T C^+ d on the ``rank`` largest eigenvalues' directions of C (all by default), which must be
    positive: a covariance is positive semi-definite, and a negative eigenvalue beyond rounding
    (1e-12 of the largest, for a symmetric eigensolver's backward error ~n eps ||C||) is a failure,
    not a statistic."""
    w, V = np.linalg.eigh(cov)
    rank = d.size if rank is None else rank
    assert w[0] >= -1e-12 * w[-1], f"the covariance is not positive semi-definite: eigenvalues {w[0]:.3g} to {w[-1]:.3g}"
    assert w[-rank] > 0, f"the covariance is singular in the {rank} directions it claims: eigenvalues {w[-rank:]}"
    z = (V[:, -rank:].T @ d) / np.sqrt(w[-rank:])
    return float(z @ z)


@pytest.mark.numerics
@pytest.mark.parametrize("method, robot", _params())
def test_contract(tmp_path, method, robot):
    assert method in CASES, f"no contract case for identification.method = {method!r}: add one to CASES"
    result, truth = CASES[method](tmp_path, robot)
    if method == "wls+physical_consistency" and result.cov_params is None:
        # the estimate on the boundary of the feasible set: no covariance, and the result says so
        # (physical.py, Uncertainty). Still a contract: the estimate is the projection of the WLS
        # estimate of the same data onto the (convex) feasible set in the metric of WLS's covariance,
        # and the truth is feasible, so it is no further from the truth in that metric than WLS is
        # (a projection onto a convex set does not move a point away from any point of the set), up
        # to the SDP's gap (a fraction of a chi-square unit at its tolerances: 1 is far above it)
        assert any("no covariance is reported" in n and "active:" in n for n in result.notes), result.notes
        from dynid.estimation import is_feasible

        system = _motion(robot)[0]
        assert is_feasible(system.base_parameters().from_standard(_motion(robot)[2]),
                           system.standard_map(system.base_parameters())).feasible  # the premise
        wls, truth = _identify(tmp_path, robot, "wls", _cov(SIGMA[robot]), k=3)
        limit = chi2.ppf(1 - FALSE_ALARM, truth.size)
        free = _statistic(wls.params - truth, wls.cov_params)
        assert free < limit, free
        assert _statistic(result.params - truth, wls.cov_params) <= free + 1.0
        return
    assert result.cov_params is not None, (method, result.notes)
    p = truth.size
    assert result.cov_params.shape == (p, p)
    held = result.solver.get("estimated_directions", {}) if method in LOOP else {}
    if held and held["count"] < p:
        # directions held at the start's values: the covariance is zero along them and the method says
        # its standard errors are conditional on them; the statistic in the estimated directions (the
        # covariance's range), chi-square with that many degrees of freedom
        assert any(f"{p - held['count']} of {p} directions" in n and "conditional" in n for n in result.notes)
        p = held["count"]
    if method in ("iv", "didim") and not result.solver["converged"]:
        # the iteration need not contract (the replay switches at velocity reversals: bench/README,
        # "DIDIM on the 3-period hexapod benchmark"); on some draws it ends in a 2-cycle of moves of
        # 0.6-0.8 sd (seed draws 0 and 3 of DYNID_TEST_SEED with 40 and 20 Hz). Then there is no fixed
        # point whose covariance could be checked, and the contract is that the result says so
        moves = [h["max_change_in_std"] for h in result.solver["iterations"]]
        assert any("not converged" in n for n in result.notes), (result.notes, moves)
        return
    stat = _statistic(result.params - truth, result.cov_params, p)
    assert stat < chi2.ppf(1 - FALSE_ALARM, p), (method, robot, stat, p)
