"""The excitation comparisons of the papers, as a reproducible study.

1. Hexapod (papers 002/004, Fig. 5 of paper 004): a *deterministic* design (minimum condition
   number of the base regressor) and a *statistical* one (D-optimal with the noise
   covariance), both of 5 harmonics in task space under the same actuator limits. Each is run
   ``repetitions`` times in simulation (actuator forces of the nominal model by pinocchio's RNEA
   route along the design, white noise), identified by least squares; the spread of every
   rigid-body base parameter is compared between the designs, and with the spread the design
   predicted.
2. shang2dof (paper 001): the weighted condition number (Eq. 17) of the paper's excitation
   circle and of an optimized design with the same limits.

Run: ``python -m dynid.studies.excitation [--repetitions 50] [--quick]``; the figures of the
last run are in ``bench/README.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from dynid.estimation.linear import OLS
from dynid.estimation.problem import ProblemBuilder
from dynid.excitation import DesignLimits, ExcitationProblem, criteria, predicted_std
from dynid.model.closed_loop import actuator_forces, actuator_regressor
from dynid.model.robots import build_mechanism
from dynid.trajectories import CirclePath

__all__ = ["hexapod_designs", "shang_circle", "main"]

HEXAPOD_BOX = (np.array([-0.03, -0.03, 0.82, -0.06, -0.06, -0.06]), np.array([0.03, 0.03, 0.88, 0.06, 0.06, 0.06]))
HEXAPOD_LIMITS = DesignLimits(velocity=np.full(6, 0.25), acceleration=np.full(6, 3.0), max_condition=1e3)


def _spread(pb: ExcitationProblem, traj, repetitions: int, noise: float, samples: int, rng: np.random.Generator):
    """Empirical and predicted standard deviations of the base parameters for one design."""
    mech = pb.robot
    t = np.arange(samples) * (traj.period / samples)
    u, du, ddu = traj.sample(t)
    st = mech.states(mech.solve_positions(u), du, ddu)
    W = pb.base.regressor(actuator_regressor(mech, st).W)
    tau = actuator_forces(mech, mech.nominal_parameters(), st)  # RNEA route, not the regressor
    sigma = np.full(mech.n_actuators, noise)
    est = []
    for _ in range(repetitions):
        b = ProblemBuilder(pb.base.names, mech.actuated_names)
        b.add(W, tau + sigma * rng.standard_normal(tau.shape))
        est.append(OLS().fit(b.build()).params)
    return np.std(est, axis=0, ddof=1), predicted_std(W, sigma)


def hexapod_designs(*, repetitions: int = 50, harmonics: int = 5, samples: int = 40, max_iter: int = 100,
                    starts: int = 1, seed: int = 0, noise: float = 2.0, progress=None) -> dict:
    """Deterministic (``cond``) against statistical (``d_opt``) design of the hexapod."""
    mech = build_mechanism("hexapod")
    out: dict = {"harmonics": harmonics, "repetitions": repetitions, "noise_std_N": noise}
    spreads, preds = {}, {}
    for criterion in ("cond", "d_opt"):
        pb = ExcitationProblem(mech, coordinates="task", harmonics=harmonics, base_frequency_hz=0.2, samples=samples,
                               criterion=criterion, limits=HEXAPOD_LIMITS, box=HEXAPOD_BOX,
                               noise_std=np.full(6, noise))
        t0 = time.perf_counter()
        d = pb.optimize(starts=starts, seed=seed, max_iter=max_iter, progress=progress)
        out[criterion] = {"success": d.success, "criteria": d.criteria, "design_s": time.perf_counter() - t0}
        spreads[criterion], preds[criterion] = _spread(pb, d.trajectory, repetitions, noise, 8 * samples,
                                                      np.random.default_rng(seed + 1))
    base = ExcitationProblem(mech, coordinates="task", harmonics=1, samples=8, limits=HEXAPOD_LIMITS, box=HEXAPOD_BOX).base
    rigid = np.array([i < mech.n_body_params for i in base.independent])
    s_c, s_d = spreads["cond"][rigid], spreads["d_opt"][rigid]
    ok = np.isfinite(s_c) & np.isfinite(s_d)
    out["rigid_body"] = {
        "n": int(rigid.sum()),
        "d_opt_smaller_std": int(np.sum(s_d[ok] < s_c[ok])),
        "median_std_ratio_dopt_over_cond": float(np.median(s_d[ok] / s_c[ok])),
    }
    for criterion in ("cond", "d_opt"):
        r = spreads[criterion] / preds[criterion]
        out[criterion]["empirical_over_predicted_std"] = {"median": float(np.median(r)), "min": float(np.min(r)),
                                                         "max": float(np.max(r))}
    return out


def shang_circle(*, optimize: bool = True, max_iter: int = 60, seed: int = 0) -> dict:
    """Weighted condition numbers (paper 001, Eq. 17) of the paper's circle and of an optimized design."""
    mech = build_mechanism("shang2dof")
    lim = DesignLimits(velocity=np.full(3, 6.0), acceleration=np.full(3, 60.0))
    pb = ExcitationProblem(mech, harmonics=4, base_frequency_hz=0.5, samples=48, criterion="weighted_cond", limits=lim)
    circle = CirclePath((0.29, 0.25), 0.04, 0.2, turns=1, ramp=0.2)
    t = np.linspace(0.2, circle.duration - 0.2, 400)  # the constant-speed part
    u, du, ddu = circle.sample(t)
    st = mech.states(mech.solve_positions(u), du, ddu)
    W = pb.base.regressor(actuator_regressor(mech, st, distribution="projected").W)
    out = {"paper_circle": criteria(W, pb.noise, pb.nominal_base), "paper_reports_weighted_cond": 12.7}
    if optimize:
        d = pb.optimize(starts=1, seed=seed, max_iter=max_iter)
        out["optimized"] = {"success": d.success, "criteria": d.criteria}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repetitions", type=int, default=50)
    ap.add_argument("--quick", action="store_true", help="10 repetitions, short searches")
    args = ap.parse_args(argv)
    if args.quick:
        hexa = hexapod_designs(repetitions=10, harmonics=5, samples=30, max_iter=10)
        shang = shang_circle(max_iter=15)
    else:
        hexa = hexapod_designs(repetitions=args.repetitions)
        shang = shang_circle()
    print(json.dumps({"hexapod": hexa, "shang2dof": shang}, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
