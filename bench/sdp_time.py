"""Time of the physically consistent SDP for a 7-DOF arm with friction (issue 8).

Target: under 1 s after compression.

Method
------
* KUKA LWR4+ model (``../shared/data/kuka_lwr4/kuka_lwr4.urdf``, required) with rotor inertia,
  viscous and Coulomb friction and offsets on every joint: 98 standard and 69 base parameters
  (the count of ../shared/data/README.md).
* 20 000 random states within the joint limits (140 000 rows), torques from the model's own
  parameters perturbed so that unconstrained least squares is not physical on a weak log, plus
  noise; the rows are compressed once (``ProblemBuilder``, QR per joint to 70 x 70).
* Timed on the compressed problem, in the same run: ``WLS`` (baseline: the unconstrained
  solve), ``PhysicalLS`` (WLS + LMI: SDP and tie-break SDP, margin 1e-6), and
  ``PhysicalLS`` with log-det regularization. ``--repeats`` runs each, alternating, median.
  The compression itself is timed once and reported separately.

Run: ``.venv/bin/python bench/sdp_time.py`` (exit status 1 when the SDP is over 1 s).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from _util import median, print_machine, table

from dynid.estimation import WLS, PhysicalConstraints, PhysicalLS, ProblemBuilder
from dynid.model.base_parameters import StandardMap, robot_base_parameters
from dynid.model.loading import load_robot
from dynid.model.serial_dynamics import regressor

TARGET_S = 1.0
URDF = Path(__file__).resolve().parents[2] / "shared" / "data" / "kuka_lwr4" / "kuka_lwr4.urdf"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--samples", type=int, default=20000)
    args = ap.parse_args(argv)
    if not URDF.is_file():
        print(f"needs {URDF} (../shared/data beside the repository)", file=sys.stderr)
        return 2
    print_machine()
    robot = load_robot(str(URDF), extras=("Ia", "fv", "fc", "offset"))
    base = robot_base_parameters(robot)
    smap = StandardMap.of(robot, base)
    rng = np.random.default_rng(0)
    lo, hi = robot.position_limits()
    n = args.samples
    q = lo + (hi - lo) * rng.random((n, robot.dof))
    dq, ddq = 0.3 * rng.standard_normal((n, robot.dof)), rng.standard_normal((n, robot.dof))
    truth = robot.nominal_parameters() * (1 + 0.3 * rng.standard_normal(robot.n_standard_params))
    t0 = time.perf_counter()
    b = ProblemBuilder(base.names, robot.joint_names)
    for a in range(0, n, 5000):
        W = base.regressor(regressor(robot, q[a:a + 5000], dq[a:a + 5000], ddq[a:a + 5000]))
        Wf = regressor(robot, q[a:a + 5000], dq[a:a + 5000], ddq[a:a + 5000])
        b.add(W, Wf @ truth + 2.0 * rng.standard_normal((W.shape[0], robot.dof)))
    problem = b.build(standard=smap)
    t_compress = time.perf_counter() - t0
    variants = {
        "WLS (baseline)": WLS(),
        "WLS+LMI": PhysicalLS(weighting="wls", constraints=PhysicalConstraints(margin=1e-6)),
        "WLS+LMI+LogDet": PhysicalLS(weighting="wls", regularization="logdet", regularization_weight=1.0),
    }
    times: dict[str, list[float]] = {k: [] for k in variants}
    last = {}
    for _ in range(args.repeats):
        for name, est in variants.items():
            t = time.perf_counter()
            last[name] = est.fit(problem)
            times[name].append(time.perf_counter() - t)
    rows = []
    for name, ts in times.items():
        res = last[name]
        rows.append([name, f"{median(ts):.3f}", f"{median(ts) / median(times['WLS (baseline)']):.0f}x",
                     str(res.solver.get("status", "-")), str(len(res.solver.get("active_constraints", []))),
                     f"{min(res.solver['min_pseudo_inertia_eigenvalue']):.2e}" if "min_pseudo_inertia_eigenvalue" in res.solver else "-"])
    print(f"7-DOF KUKA LWR4+ with Ia, fv, fc, offset: {robot.n_standard_params} standard, {base.n_base} base parameters; "
          f"{n} samples ({n * robot.dof} rows) compressed in {t_compress:.2f} s")
    print(table(["estimator", "median s", "vs WLS", "status", "active", "min eig"], rows))
    worst = max(median(times["WLS+LMI"]), median(times["WLS+LMI+LogDet"]))
    print(f"target: SDP under {TARGET_S} s after compression -> {'met' if worst < TARGET_S else 'MISSED'} ({worst:.3f} s)")
    return 0 if worst < TARGET_S else 1


if __name__ == "__main__":
    sys.exit(main())
