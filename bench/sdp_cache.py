"""Repeated physically consistent fits: the compiled-problem cache of ``PhysicalLS`` (issue 33).

A Stribeck fit alternates a nonlinear step with a ``PhysicalLS`` polish a few hundred times on
problems of one shape (the 3-RPS study: 179 fits, 349 SDPs), and cvxpy's canonicalization of a
freshly built problem was 95 % of the SDP time there (``cProfile`` of ``bench/physical_study.py
--quick --part B``: 76.7 of 80.7 s in ``get_problem_data``). ``PhysicalLS`` now builds its two
SDPs (the constrained fit and the tie-break) with the data as cvxpy Parameters and keeps them in
a small per-thread cache, so that a problem of a shape already seen is only re-solved.

Method: ``builtin:cobot6r`` with rotor inertia, viscous and Coulomb friction; ``--fits`` problems
of one shape (2000 random states each, a parameter vector perturbed so that the constraints are
active, another noise draw each) compressed once; each round fits them all with the cache (its
size as shipped) and without it (size 0: every fit builds its problem anew), alternating which
goes first; medians over ``--repeats`` rounds of the per-fit times. The two routes must give the
same estimates to the solver's tolerance (checked: the largest difference relative to the
parameters' scale, against Clarabel's ``tol_feas`` times 100).

Run: ``.venv/bin/python bench/sdp_cache.py`` (exit status 1 when the estimates differ).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _util import median, print_machine, table

import dynid.estimation.physical as physical
from dynid.estimation import PhysicalLS, RegressionProblem
from dynid.model.base_parameters import StandardMap, robot_base_parameters
from dynid.model.loading import load_robot
from dynid.model.serial_dynamics import regressor
from dynid.tolerances import clarabel_tolerances


def _problems(k: int, n: int):
    robot = load_robot("builtin:cobot6r", extras=("Ia", "fv", "fc"))
    base = robot_base_parameters(robot)
    smap = StandardMap.of(robot, base)
    rng = np.random.default_rng(0)
    lo, hi = robot.position_limits()
    pi = robot.nominal_parameters()
    beta = base.from_standard(pi) * (1 + 0.3 * rng.standard_normal(base.n_base))  # not physical: LMIs active
    out = []
    for _ in range(k):
        q = lo + (hi - lo) * rng.random((n, robot.dof))
        dq, ddq = rng.standard_normal((n, robot.dof)), 3 * rng.standard_normal((n, robot.dof))
        W = base.regressor(regressor(robot, q, dq, ddq))
        y = W @ beta + 0.5 * rng.standard_normal((n, robot.dof))
        out.append(RegressionProblem.from_arrays(W, y, base.names, robot.joint_names, standard=smap))
    return out


def _fit_all(problems, size: int) -> tuple[float, list[np.ndarray]]:
    physical._COMPILED_SIZE = size
    physical._COMPILED_LOCAL.problems = None  # a cold cache: the first fit of the round compiles
    est = PhysicalLS(weighting="wls")
    t0 = time.perf_counter()
    params = [est.fit(p).params for p in problems]
    return (time.perf_counter() - t0) / len(problems), params


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--fits", type=int, default=10)
    ap.add_argument("--samples", type=int, default=2000)
    args = ap.parse_args(argv)
    print_machine()
    shipped = physical._COMPILED_SIZE
    problems = _problems(args.fits, args.samples)
    _fit_all(problems[:1], 0)  # imports and first-call costs out of the rounds
    cached, fresh, worst = [], [], 0.0
    for r in range(args.repeats):
        order = [(shipped, cached), (0, fresh)] if r % 2 == 0 else [(0, fresh), (shipped, cached)]
        got = {}
        for size, times in order:
            t, params = _fit_all(problems, size)
            times.append(t)
            got[size] = params
        for a, b in zip(got[shipped], got[0]):
            worst = max(worst, float(np.max(np.abs(a - b)) / np.max(np.abs(b))))
    physical._COMPILED_SIZE = shipped
    bound = 100 * clarabel_tolerances()["tol_feas"]
    rows = [("without the cache (built anew)", f"{median(fresh) * 1e3:.0f}", "1.00"),
            (f"with the cache (size {shipped})", f"{median(cached) * 1e3:.0f}", f"{median(fresh) / median(cached):.2f}")]
    print(table(("PhysicalLS.fit, cobot6r + friction", "ms per fit (median)", "speed-up"), rows))
    print(f"{args.fits} fits of one shape per round, {args.repeats} rounds; largest difference of the estimates "
          f"{worst:.2g} of the largest parameter (bound: 100 x tol_feas = {bound:.0e})")
    return 0 if worst <= bound else 1


if __name__ == "__main__":
    raise SystemExit(main())
