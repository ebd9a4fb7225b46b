"""Reference formulas for the loop-closure kinematics and a mechanism's control loop, written the
direct way (closure by closure with pinocchio's placements and joint Jacobians, SVD least
squares, batched kinematics, the joint terms column by column): tests compare the product's
faster routes with them (tests/test_closed_loop.py, tests/test_simulation_mechanism.py)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dynid.model.closed_loop import actuator_forces, term_forces
from dynid.simulation._integrate import rk4_step


def closure_rows(mech, q, exact):
    """c(q) and J_c(q) (all rows) closure by closure: SE3 products, one Jacobian per side."""
    model, data = mech.pin_model, mech.pin_model.createData()
    pin.computeJointJacobians(model, data, q)

    def side(j, placement):
        M = data.oMi[j] * placement
        if j == 0:
            return M, np.zeros((3, model.nv)), np.zeros((3, model.nv))
        J = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.WORLD)
        p = M.translation
        skew = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
        return M, J[:3] - skew @ J[3:], J[3:]

    res, rows = [], []
    for c in mech.closures:
        Ma, la, aa = side(c.joint_a, c.placement_a)
        Mb, lb, ab = side(c.joint_b, c.placement_b)
        res.append(Mb.translation - Ma.translation)
        rows.append(lb - la)
        if c.kind == "6d":
            Rrel = Ma.rotation.T @ Mb.rotation
            res.append(Ma.rotation @ pin.log3(Rrel))
            rows.append(Ma.rotation @ pin.Jlog3(Rrel) @ Mb.rotation.T @ (ab - aa) if exact else ab - aa)
    return np.concatenate(res), np.vstack(rows)


def project(mech, q, dq, tol=1e-12, max_iter=10):
    """The nearest assembly by minimum-norm Gauss-Newton (SVD least squares) and the velocity
    minus its component off the constraint tangent space."""
    rows = mech.constraint_rows
    for _ in range(max_iter):
        c = closure_rows(mech, q, True)[0][rows]
        if np.linalg.norm(c, np.inf) < tol:
            break
        q = q - np.linalg.lstsq(closure_rows(mech, q, True)[1][rows], c, rcond=None)[0]
    J = closure_rows(mech, q, False)[1][rows]
    return q, dq - np.linalg.lstsq(J, J @ dq, rcond=None)[0]


def control_loop(sim, mech, params, kp, kv, distribution, reference, duration, dt, substeps):
    """simulate_mechanism_control with AugmentedPD, from the reference formulas: the controller's
    kinematics by the batched route (two copies of the sample), its forces by the batched
    actuator_forces, the plant's joint terms column by column (term_forces; single-joint rotor
    inertias in the armature, as the simulator has them), every RK4 stage evaluated, the
    projection by :func:`project`."""
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    ur, dur, ddur = reference(t)
    two = lambda x: np.repeat(np.asarray(x)[None], 2, axis=0)  # noqa: E731
    Sa = mech.actuator_selection()
    theta = np.array(sim.params, dtype=float)
    nb = mech.n_body_params
    for k, term in enumerate(mech.terms):
        if term.kind == "inertia" and len(term.joints) == 1:
            theta[nb + k] = 0.0

    def acc(q, v, tau_a):
        tau = Sa.T @ tau_a - term_forces(mech, theta, v[None], np.zeros((1, mech.nv)))[0]
        return pin.constraintDynamics(sim.model, sim.data, q, v, tau, sim.cmodels, sim.cdatas, sim.prox).copy()

    def control(q, v, k):
        u, du = mech.coordinates(q)[0], mech.coordinate_velocities(q, v)[0]
        a = ddur[k] + kv * (dur[k] - du) + kp * (ur[k] - u)
        state = mech.states(two(q), two(du), two(a))
        return actuator_forces(mech, params, state, distribution=distribution)[0]

    q = mech.solve_positions(ur[:1])[0]
    v = mech.states(two(q), two(dur[0]), two(ddur[0])).dq[0]
    Q, V, A, T = (np.empty((n, m)) for m in (mech.nv, mech.nv, mech.nv, mech.n_actuators))
    h = dt / substeps
    for k in range(n):
        tau = control(q, v, k)
        Q[k], V[k], T[k], A[k] = q, v, tau, acc(q, v, tau)
        if k == n - 1:
            break
        for _ in range(substeps):
            q, v = rk4_step(lambda a, b: acc(a, b, tau), q, v, h)
        q, v = project(mech, q, v)
    return Q, V, A, T
