"""Per-stage cost of the hexapod's actuator-space regressor (states + regressor), the reference
routes against the structured ones and the compiled ones, in the same process (issue 37, item 1,
second and third pass).

Method
------
* ``builtin:hexapod`` along the motion of ``closed_loop_throughput.py`` (``--n`` samples, default
  1024, the library's own blocks: 256 for the states, 64 for the regressor), one BLAS thread.
* Every stage is timed by the CPU time of this thread (``time.thread_time``: on a shared machine
  the wall time of a loaded core counts other processes' slices; the CPU time does not, though
  their cache traffic still does), ``--rounds`` rounds alternating the two routes, median.
* ``reference``: ``loop_blocks.leg_plan`` and ``loop_blocks.side_scatter`` off (dense LAPACK
  inverse of J_c,w, the closure sides one by one), the regressor in blocks of 128 with the
  platform chain's 60 columns multiplied (10 kept) and G^T F from the formed term columns F:
  the routes before the second pass. ``structured``: the numpy routes of the second pass
  (``loop_kinematics._COMPILED`` and ``closed_loop._COMPILED`` off). ``compiled``: the library as
  it is (:mod:`dynid.model.loop_compiled`: numba kernels between the pinocchio calls; the drift's
  :math:`\dot J\dot q` from :math:`J`, no time-variation pass; stages timed by calling its kernels
  on the same inputs: the separate kernels where the library fuses them, so the stage rows sum to
  slightly more than the fused total). With ``loop_compiled.TREE_FROM_J`` (the default) the
  compiled regressor calls pinocchio's ``forwardKinematics`` per sample (its row) instead of the
  tree regressor, and the kernel's row holds the recursion, the body regressors, the projection
  and the joint terms' sums.
* Stages (us per sample): the three pinocchio passes (each with the copy of its result, the
  tree regressor's copy apart), the numpy work between them, totals; the serial 6R regressor of
  ``closed_loop_throughput.py`` and pinocchio's regressor call of the 6R alone as the yardstick.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/closed_loop_stages.py``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import pinocchio as pin
from threadpoolctl import threadpool_limits

from closed_loop_throughput import hexapod_motion
from _util import print_machine

from dynid.model import _loop_kernels as kern
from dynid.model import closed_loop as cl
from dynid.model import load_robot
from dynid.model import loop_batch, loop_compiled
from dynid.model import loop_blocks as lb
from dynid.model import loop_kinematics as lk
from dynid.model.base_parameters import random_states
from dynid.model.robots import build_mechanism, hexapod
from dynid.model.serial_dynamics import regressor


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=15)
    args = ap.parse_args(argv)
    print_machine()
    n, B = args.n, lk._BLOCK
    rng = np.random.default_rng(2026)
    mech = build_mechanism("hexapod")
    model = mech.pin_model
    data = model.createData()
    q = hexapod.inverse_kinematics(hexapod_motion(n, rng))
    du, ddu = 0.1 * rng.standard_normal((n, 6)), rng.standard_normal((n, 6))
    robot = load_robot("builtin:generic6r")
    lo, hi = robot.position_limits()
    sq, sdq, sddq = random_states(lo, hi, n, rng)
    sbuf = np.empty((n, robot.dof, robot.n_standard_params))
    sdata = robot.create_data()
    smodel = robot.pin_model
    st = mech.states(q, du, ddu)
    out = np.empty((n, 6, mech.n_standard_params))
    fast = dict(leg_plan=lb.leg_plan, side_scatter=lb.side_scatter, terms=cl._projected_terms,
                block=cl._REGRESSOR_BLOCK, groups=cl._chain_groups(mech))
    rows, _, _, wcols = fast["groups"][-1]
    old_groups = list(fast["groups"][:-1]) + [(rows, slice(180, 240), np.arange(50, 60), wcols)]

    def mode(structured: bool) -> None:
        lk._COMPILED = cl._COMPILED = False
        lb.leg_plan = fast["leg_plan"] if structured else (lambda m: None)
        lb.side_scatter = fast["side_scatter"] if structured else (lambda m: None)
        cl._projected_terms = fast["terms"] if structured else (
            lambda m, G, dq, ddq: np.matmul(G.transpose(0, 2, 1), cl.term_columns(m, dq, ddq)))
        cl._REGRESSOR_BLOCK = fast["block"] if structured else 128
        object.__setattr__(mech, "_chain_groups_cache", fast["groups"] if structured else old_groups)

    def cpu(f) -> float:
        t = time.thread_time()
        f()
        return (time.thread_time() - t) / n * 1e6

    blocks = [slice(a, min(a + B, n)) for a in range(0, n, B)]

    def stages() -> dict[str, float]:
        r: dict[str, float] = {}
        J = np.empty((n, 6, mech.nv))

        def cjj() -> None:
            for i in range(n):
                J[i] = pin.computeJointJacobians(model, data, q[i])

        r["pinocchio computeJointJacobians (+ copy)"] = cjj_t = cpu(cjj)
        r["closure rows J_c: placements, points, assembly"] = cpu(lambda: [lk._velocity_rows(mech, q[b], data) for b in blocks]) - cjj_t
        vr = [lk._velocity_rows(mech, q[b], data) for b in blocks]
        r["inverse of J_c,w, its condition number, G"] = cpu(lambda: [lk._Maps(mech, v[0], 1e8) for v in vr])
        maps = [lk._Maps(mech, v[0], 1e8) for v in vr]
        dqs = [np.einsum("nij,nj->ni", m.G, du[b]) for m, b in zip(maps, blocks)]
        dJ = np.empty((n, 6, mech.nv))

        def tv() -> None:
            for i in range(n):
                pin.computeJointJacobiansTimeVariation(model, data, q[i], st.dq[i])
                dJ[i] = data.dJ

        r["pinocchio computeJointJacobiansTimeVariation (+ copy)"] = tv_t = cpu(tv)
        r["drift: body velocities, point accelerations, rows"] = cpu(
            lambda: [lk._drift(mech, q[b], d, v[1][0], v[1][1], data) for b, d, v in zip(blocks, dqs, vr)]) - tv_t
        r["states, total (mech.states)"] = cpu(lambda: mech.states(q, du, ddu))
        Y = np.empty((cl._REGRESSOR_BLOCK, mech.nv, 10 * (model.njoints - 1)))
        m = Y.shape[0]

        def jtr_only() -> None:
            for i in range(n):
                pin.computeJointTorqueRegressor(model, data, st.q[i], st.dq[i], st.ddq[i])

        def jtr_copy() -> None:
            for i in range(n):
                Y[i % m] = pin.computeJointTorqueRegressor(model, data, st.q[i], st.dq[i], st.ddq[i])

        r["pinocchio computeJointTorqueRegressor"] = jtr_t = cpu(jtr_only)
        r["pinocchio forwardKinematics (+ liMi copy)"] = 0.0
        r["  its copy into the block"] = copy_t = cpu(jtr_copy) - jtr_t
        r["joint terms G^T F"] = terms_t = cpu(lambda: cl._projected_terms(mech, st.G, st.dq, st.ddq))
        r["regressor given the states, total"] = tot = cpu(lambda: cl.actuator_regressor(mech, st, data=data, out=out))
        r["  projection G^T Y (compiled: tree kernel), the rest"] = tot - jtr_t - copy_t - terms_t
        r["states + regressor"] = r["states, total (mech.states)"] + tot
        r["serial 6R regressor (one sample)"] = cpu(lambda: regressor(robot, sq, sdq, sddq, data=sdata, out=sbuf))
        r["  pinocchio computeJointTorqueRegressor of the 6R"] = cpu(
            lambda: [pin.computeJointTorqueRegressor(smodel, sdata, a, b, c) for a, b, c in zip(sq, sdq, sddq)])
        r["hexapod's three pinocchio passes alone"] = cjj_t + tv_t + jtr_t
        return r

    def compiled_stages() -> dict[str, float]:
        """The same rows for the compiled route (its kernels on the same inputs, block by block)."""
        lk._COMPILED = cl._COMPILED = True
        r: dict[str, float] = {}
        plan = loop_compiled.states_plan(mech, data)
        view = loop_batch.placement_view(mech, data)[plan.jsel]
        J = np.empty((n, 6, mech.nv))
        flat = np.empty((n, plan.k, 12))

        def cjj() -> None:
            for i in range(n):
                J[i] = pin.computeJointJacobians(model, data, q[i])
                flat[i] = view

        r["pinocchio computeJointJacobians (+ copy)"] = cpu(cjj)
        nc = plan.n_rows
        rows = np.empty((n, nc, mech.nv))
        ps = np.empty((n, plan.cols.shape[0], 3))
        r["closure rows J_c: placements, points, assembly"] = cpu(lambda: kern.closure_rows(
            J, flat, plan.slot, plan.r, plan.moving_ref, plan.cols, *plan.rows_args, plan.n_dims, rows.reshape(n, -1), ps))
        inv, ok = np.empty((n, plan.w.size, nc)), np.empty(n, dtype=bool)
        G, cond, dq, ddq = np.empty((n, mech.nv, 6)), np.empty(n), np.empty((n, mech.nv)), np.empty((n, mech.nv))

        def inverse() -> None:
            kern.leg_inverse(rows, *plan.leg, lb.MAX_PIVOT_COND, inv, ok)
            kern.velocity_maps(rows, inv, plan.u, plan.w, plan.cu_ptr, plan.cu_rows, du, G, cond, dq)

        r["inverse of J_c,w, its condition number, G"] = cpu(inverse)
        r["pinocchio computeJointJacobiansTimeVariation (+ copy)"] = 0.0
        r["drift: body velocities, point accelerations, rows"] = cpu(lambda: kern.drift_accelerations(
            J, J[:1], True, dq, ps, plan.body_ptr, plan.body_cols, plan.body_end, plan.body_of, *plan.drift_args,
            plan.n_dims, rows, inv, plan.u, plan.w, plan.cu_ptr, plan.cu_rows, ddu, ddq))
        r["states, total (mech.states)"] = cpu(lambda: mech.states(q, du, ddu))

        if loop_compiled.TREE_FROM_J:  # the tree kernel's pass: forwardKinematics and the parents' placements
            lview = loop_batch.parent_placement_view(mech, data)
            L = np.empty((n, lview.shape[0], 12))

            def fk() -> None:
                for i in range(n):
                    pin.forwardKinematics(model, data, st.q[i])
                    L[i] = lview

            r["pinocchio computeJointTorqueRegressor"] = 0.0
            r["pinocchio forwardKinematics (+ liMi copy)"] = jtr_t = cpu(fk)
        else:
            def jtr_only() -> None:
                for i in range(n):
                    pin.computeJointTorqueRegressor(model, data, st.q[i], st.dq[i], st.ddq[i])

            r["pinocchio computeJointTorqueRegressor"] = jtr_t = cpu(jtr_only)
            r["pinocchio forwardKinematics (+ liMi copy)"] = 0.0
        r["  its copy into the block"] = 0.0

        def terms() -> None:  # the bases; their sums G^T F run in the projection's kernel call (the row below)
            [cl.term_basis(kind, st.dq, st.ddq, mech.coulomb_width) for kind, _ in mech.term_groups]

        r["joint terms G^T F"] = terms_t = cpu(terms)
        r["regressor given the states, total"] = tot = cpu(lambda: cl.actuator_regressor(mech, st, data=data, out=out))
        r["  projection G^T Y (compiled: tree kernel), the rest"] = tot - jtr_t - terms_t
        r["states + regressor"] = r["states, total (mech.states)"] + tot
        r["serial 6R regressor (one sample)"] = cpu(lambda: regressor(robot, sq, sdq, sddq, data=sdata, out=sbuf))
        r["  pinocchio computeJointTorqueRegressor of the 6R"] = cpu(
            lambda: [pin.computeJointTorqueRegressor(smodel, sdata, a, b, c) for a, b, c in zip(sq, sdq, sddq)])
        r["hexapod's three pinocchio passes alone"] = float("nan")
        return r

    routes = ("reference", "structured", "compiled")
    res: dict[str, list] = {k: [] for k in routes}
    with threadpool_limits(1):
        for k in range(args.rounds):
            for route in (routes if k % 2 == 0 else routes[::-1]):
                if route == "compiled":
                    mode(True)
                    res[route].append(compiled_stages())
                else:
                    mode(route == "structured")
                    res[route].append(stages())
    mode(True)
    lk._COMPILED = cl._COMPILED = True
    print(f"hexapod, n = {n}, {args.rounds} rounds, CPU time of this thread, median (us per sample)\n")
    print(f"| {'stage':54s} | reference | structured | compiled |")
    print(f"|{'-' * 56}|-----------|------------|----------|")
    for key in res["structured"][0]:
        b, a, c = (statistics.median(r[key] for r in res[k]) for k in routes)
        print(f"| {key:54s} | {b:9.2f} | {a:10.2f} | {c:8.2f} |")
    ser = statistics.median(r["serial 6R regressor (one sample)"] for r in res["structured"])
    for label in routes:
        tot = statistics.median(r["states + regressor"] / r["serial 6R regressor (one sample)"] for r in res[label])
        print(f"\n{label}: states + regressor = {tot:.2f} serial 6R samples (median of the rounds' ratios)", end="")
    floor = statistics.median(r["hexapod's three pinocchio passes alone"] for r in res["structured"])
    jtr = statistics.median(r["pinocchio computeJointTorqueRegressor"] + r["pinocchio forwardKinematics (+ liMi copy)"]
                            + r["pinocchio computeJointJacobians (+ copy)"] for r in res["compiled"])
    second = "forwardKinematics, liMi's copy" if loop_compiled.TREE_FROM_J else "tree regressor"
    print(f"\nfloor: the hexapod's three pinocchio passes alone = {floor:.2f} us = {floor / ser:.2f} serial 6R samples;"
          f" the compiled route's two (Jacobians with the copies; {second}) = {jtr:.2f} us = {jtr / ser:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
