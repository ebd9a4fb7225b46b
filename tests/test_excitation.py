"""Excitation design: feasibility on a fine grid (checked independently), every criterion
improves on its start, infeasible requests fail clearly, predicted standard deviations match
the spread of simulated identifications."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from conftest import seed
from dynid.errors import DynidError
from dynid.estimation.linear import OLS
from dynid.estimation.problem import ProblemBuilder
from dynid.excitation import CRITERIA, DesignError, DesignLimits, ExcitationProblem, predicted_std
from dynid.model import inverse_dynamics, load_robot, regressor
from dynid.model.robots import build_mechanism

ARM_LIMITS = DesignLimits(velocity=np.full(6, 1.5), acceleration=np.full(6, 6.0))


@pytest.fixture(scope="module")
def arm():
    return load_robot("builtin:generic6r")


def _fine(traj, n):
    T = traj.period if hasattr(traj, "period") else traj.duration
    return np.linspace(0.0, T, n)


def _check_grid(traj, samples: int, factor: int = 8) -> np.ndarray:
    """The instants of the design's own feasibility check (ExcitationProblem.check: ``factor`` x
    ``samples`` per period, the end excluded), where it guarantees its limits."""
    return np.arange(factor * samples) * (traj.period / (factor * samples))


def _between_samples(harmonics: int, samples: int, factor: int = 8) -> float:
    """How far a trigonometric polynomial of harmonics <= K may rise between the samples of the
    design's feasibility check (``factor`` x ``samples`` per period: ExcitationProblem.check) above
    its largest sampled magnitude, relative to its largest magnitude: between samples dt apart a
    function exceeds the larger one by at most max|s''| dt^2 / 8, and max|s''| <= (2 pi K / T)^2
    max|s| (Bernstein). The design is feasible on that grid, not between its samples."""
    return (2 * np.pi * harmonics / (factor * samples)) ** 2 / 8


@pytest.mark.numerics
@pytest.mark.parametrize("criterion", CRITERIA)
def test_serial_design_is_feasible_and_improves(arm, criterion):
    pb = ExcitationProblem(arm, harmonics=3, base_frequency_hz=0.2, samples=24, criterion=criterion, limits=ARM_LIMITS)
    d = pb.optimize(starts=1, seed=seed(3), max_iter=25)
    assert d.success and d.violation is None
    assert d.value <= d.initial_value  # never worse than the (feasible) start: the search's guarantee
    # and this search moves: a random start (amplitudes rolling off as 1/k, shrunk into the limits) is far from
    # a local optimum of every criterion, and 25 SLSQP iterations leave it
    assert d.value < d.initial_value
    # independent feasibility check on a grid 20 times finer than the optimizer's, within what the signals
    # can do between the samples of the design's own check (_between_samples, 1.2e-3 here)
    eps = _between_samples(3, 24)
    q, dq, ddq = d.trajectory.sample(_fine(d.trajectory, 20 * 24))
    lo, hi = arm.position_limits()
    assert np.all(q >= lo - eps * (hi - lo)) and np.all(q <= hi + eps * (hi - lo))
    assert np.abs(dq).max() <= 1.5 * (1 + eps) and np.abs(ddq).max() <= 6.0 * (1 + eps)


@pytest.mark.numerics
def test_hexapod_task_space_design_is_feasible(tmp_path):
    mech = build_mechanism("hexapod")
    box = (np.array([-0.03, -0.03, 0.82, -0.05, -0.05, -0.05]), np.array([0.03, 0.03, 0.88, 0.05, 0.05, 0.05]))
    lim = DesignLimits(velocity=np.full(6, 0.2), acceleration=np.full(6, 2.0), max_condition=1e3)
    pb = ExcitationProblem(mech, coordinates="task", harmonics=2, base_frequency_hz=0.5, samples=24,
                           criterion="d_opt", limits=lim, box=box)
    d = pb.optimize(starts=1, seed=seed(0), max_iter=15)
    assert d.success and d.value < d.initial_value
    task = mech.in_task_space()
    # on the design's check grid, where it guarantees the limits: the actuator coordinates are not trigonometric
    # polynomials of the design's harmonics, so no bound between those samples (_between_samples) applies to them
    t = _check_grid(d.trajectory, 24)
    u, du, ddu = d.trajectory.sample(t)
    assert np.all(u >= box[0] - 1e-9) and np.all(u <= box[1] + 1e-9)
    st = task.states(task.solve_positions(u), du, ddu)  # Newton, independent of the closed form
    act = list(mech.actuated)
    lo, hi = mech.position_limits()
    qa = st.q[:, act]
    assert np.all(qa >= lo[act] - 1e-9) and np.all(qa <= hi[act] + 1e-9)
    assert np.abs(st.dq[:, act]).max() <= 0.2 + 1e-9 and np.abs(st.ddq[:, act]).max() <= 2.0 + 1e-9
    assert st.cond.max() <= 1e3


def test_infeasible_request_fails_clearly(arm):
    lo, hi = arm.position_limits()
    # offsets forced outside the actuator position limits: nothing can be feasible
    lim = DesignLimits(position=(lo + 0.5 * (hi - lo) + 0.1, hi), velocity=np.full(6, 1.0))
    with pytest.raises(DesignError, match="position of joint_"):  # refused before the search starts
        pb = ExcitationProblem(arm, harmonics=2, samples=16, limits=lim, box=(lo, lo + 0.05 * (hi - lo)))
        pb.optimize(starts=1, seed=0, max_iter=5)
    with pytest.raises(DynidError, match="unknown criterion"):
        ExcitationProblem(arm, criterion="magic")


def test_cli_infeasible_design_is_one_line(tmp_path):
    (tmp_path / "d.toml").write_text(
        '[robot]\nmodel = "builtin:generic6r"\n[design]\nharmonics = 2\nsamples = 16\nstarts = 1\nmax_iter = 5\n'
        "box = { lower = [-3.0, -2.0, -2.5, -3.0, -2.0, -3.0], upper = [-2.9, -1.9, -2.4, -2.9, -1.9, -2.9] }\n"
        "[limits]\nposition = { lower = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0], upper = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0] }\n"
    )
    r = subprocess.run([sys.executable, "-m", "dynid.cli", "design", "d.toml", "--out", "o"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no feasible excitation" in r.stderr, r.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.numerics
def test_predicted_std_matches_simulated_spread(arm):
    """The design's predicted standard deviations against the spread of 100 identifications
    from simulated torques (pinocchio RNEA along the design + white noise). The estimate is linear
    in the noise, so the predicted std is its exact std, and each sample std of the 100 is
    sigma_i sqrt(chi2_99 / 99): within the two-sided quantiles at 1e-3 over the parameters
    (Bonferroni: 0.71-1.31 here), and each mean within 4.5 of its std pred / 10 (7e-6 each)."""
    pb = ExcitationProblem(arm, harmonics=3, base_frequency_hz=0.2, samples=24, criterion="d_opt", limits=ARM_LIMITS)
    d = pb.optimize(starts=1, seed=seed(5), max_iter=25)
    t = np.arange(400) * (d.trajectory.period / 400)
    q, dq, ddq = d.trajectory.sample(t)
    W = pb.base.regressor(regressor(arm, q, dq, ddq))
    sigma = np.array([0.5, 0.5, 0.3, 0.1, 0.1, 0.05])
    pred = predicted_std(W, sigma)
    tau = inverse_dynamics(arm, arm.nominal_parameters(), q, dq, ddq)
    rng = np.random.default_rng(seed(0))
    est = []
    for _ in range(100):
        b = ProblemBuilder(pb.base.names, arm.joint_names)
        b.add(W / sigma[None, :, None], (tau + sigma * rng.standard_normal(tau.shape)) / sigma)
        est.append(OLS().fit(b.build()).params)
    spread = np.std(est, axis=0, ddof=1)
    ratio = spread / pred
    alpha = 1e-3 / (2 * pred.size)
    lo, hi = np.sqrt(stats.chi2.ppf(alpha, 99) / 99), np.sqrt(stats.chi2.isf(alpha, 99) / 99)
    assert np.all((ratio > lo) & (ratio < hi)), (ratio, lo, hi)
    # and the estimates are unbiased: their mean is within 4.5 standard errors of the truth
    assert np.all(np.abs(np.mean(est, axis=0) - pb.base.from_standard(arm.nominal_parameters())) < 4.5 * pred / 10)


def test_paper001_circle_as_a_one_line_design(tmp_path):
    from dynid.config.design import parse_design_config
    from dynid.pipeline.design import run_design, write_design

    cfg = parse_design_config({"robot": {"model": "builtin:shang2dof"},
                               "design": {"kind": "circle", "centre": [0.29, 0.25], "radius": 0.04, "speed": 0.2,
                                          "criterion": "weighted_cond", "samples": 32},
                               "limits": {"velocity": 10.0, "acceleration": 100.0}}, tmp_path)
    out = run_design(cfg)
    assert out.design.success and np.isfinite(out.design.criteria["weighted_cond"])
    names = write_design(out, tmp_path / "o")
    assert {"design.json", "trajectory.csv", "params.csv"} <= set(names)


@pytest.mark.numerics
def test_force_limits_and_reproducibility(arm):
    """Actuator-force limits hold on a fine grid (forces by pinocchio's RNEA, not the design's
    regressor); the same seed gives the same design."""
    # joint 1's 15 N*m binds (the unconstrained design needs about 20); the others do not
    lim = DesignLimits(velocity=np.full(6, 1.5), acceleration=np.full(6, 6.0), force=np.array([15.0, 80.0, 30.0, 8.0, 8.0, 4.0]))

    def run():
        pb = ExcitationProblem(arm, harmonics=2, base_frequency_hz=0.2, samples=20, criterion="d_opt", limits=lim)
        return pb.optimize(starts=1, seed=seed(11), max_iter=15)

    d = run()
    assert d.success
    # on the design's check grid, where it guarantees the limits (forces are not trigonometric polynomials of the
    # design's harmonics: no bound between those samples); the forces by RNEA, rounding only
    q, dq, ddq = d.trajectory.sample(_check_grid(d.trajectory, 20))
    tau = inverse_dynamics(arm, arm.nominal_parameters(), q, dq, ddq)
    assert np.all(np.abs(tau) <= lim.force + 1e-6), np.abs(tau).max(axis=0)
    assert np.abs(tau[:, 0]).max() > 0.9 * 15.0  # the limit is used, not avoided by a timid design
    again = run()
    assert np.array_equal(again.trajectory.a, d.trajectory.a) and again.value == d.value
    # gravity alone on joint 2 exceeds 50 N*m near the offsets: the failure names it
    tight = DesignLimits(velocity=np.full(6, 1.5), force=np.array([60.0, 50.0, 30.0, 8.0, 8.0, 4.0]))
    with pytest.raises(DesignError, match="force of joint_2"):
        ExcitationProblem(arm, harmonics=2, samples=16, limits=tight).optimize(starts=1, seed=0, max_iter=5)


def test_a_design_is_simulated_as_designed(tmp_path):
    """dynid design -> design.json -> dynid simulate (trajectory.design): the commanded motion is
    the designed one."""
    from dynid.config.design import parse_design_config
    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.design import run_design, write_design
    from dynid.pipeline.simulate import run_simulation

    dcfg = parse_design_config({"robot": {"model": "builtin:generic6r"},
                                "design": {"harmonics": 2, "base_frequency_hz": 0.5, "samples": 16, "starts": 1, "max_iter": 5},
                                "limits": {"velocity": 1.0, "acceleration": 4.0}, "output": {"plots": False}}, tmp_path)
    out = run_design(dcfg)
    write_design(out, tmp_path / "design")
    scfg = parse_simulate_config({"robot": {"model": "builtin:generic6r"},
                                  "trajectory": {"kind": "fourier", "design": "design/design.json", "periods": 2},
                                  "control": {"rate_hz": 200, "model": "true"}}, tmp_path)
    sim = run_simulation(scfg)
    t = sim.columns["t"]
    q_ref = out.design.trajectory.sample(t)[0]
    np.testing.assert_allclose(sim.columns["ref_joint_3"], q_ref[:, 2], atol=1e-12)
    assert sim.metadata["duration_s"] == pytest.approx(2 * out.design.trajectory.period)
    with pytest.raises(DynidError, match="describe a random series"):
        parse_simulate_config({"robot": {"model": "builtin:generic6r"},
                               "trajectory": {"kind": "fourier", "design": "design/design.json", "harmonics": 3}}, tmp_path)
