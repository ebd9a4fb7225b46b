"""Assembly of a mechanism read from a file, and its idle joints (:mod:`dynid.model.mechanism_files`,
which this was split from; see its docstring, "Closure check at load" and "Idle joints"): the loops
closed by Gauss-Newton from the reference configuration, the joints no actuator determines found as
the null space of :math:`[J_c; S_a]` and locked (``pinocchio.buildReducedModel``), the closures'
frames aligned with the world."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import scipy.linalg as sla

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.closures import LoopClosure

_TOL = 1e-9


def _kinematics(model: pin.Model, data: pin.Data, closures, q: FloatArray, exact: bool) -> tuple[FloatArray, FloatArray]:
    """Residual c(q) and Jacobian, with the conventions of :class:`Mechanism`."""
    pin.computeJointJacobians(model, data, q)
    res, rows = [], []
    for c in closures:
        M = [data.oMi[c.joint_a] * c.placement_a, data.oMi[c.joint_b] * c.placement_b]
        lin, ang = [], []
        for j, Mj in zip((c.joint_a, c.joint_b), M):
            J = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.WORLD) if j else np.zeros((6, model.nv))
            lin.append(J[:3] - pin.skew(Mj.translation) @ J[3:])
            ang.append(J[3:])
        res.append(M[1].translation - M[0].translation)
        rows.append(lin[1] - lin[0])
        if c.kind == "6d":
            Rrel = M[0].rotation.T @ M[1].rotation
            res.append(pin.log3(Rrel))
            rows.append(pin.Jlog3(Rrel) @ M[1].rotation.T @ (ang[1] - ang[0]) if exact else ang[1] - ang[0])
    return np.concatenate(res), np.vstack(rows)


def _assemble(model: pin.Model, closures, q0: FloatArray, name: str) -> FloatArray:
    """The assembly nearest ``q0`` (Gauss-Newton); a closure that cannot close is named with
    its residual [m, rad]."""
    data = model.createData()
    q = q0.copy()
    for _ in range(100):
        c, J = _kinematics(model, data, closures, q, exact=True)
        if np.linalg.norm(c, np.inf) < 1e-12:
            return q
        q = q + np.linalg.lstsq(J, -c, rcond=1e-10)[0]
    per, k = [], 0
    for cl in closures:
        rows = 6 if cl.kind == "6d" else 3
        per.append(float(np.linalg.norm(c[k : k + rows], np.inf)))
        k += rows
    worst = int(np.argmax(per))
    cl = closures[worst]
    raise ModelError(f"cannot assemble the loops of {name!r}: closure {cl.name!r} ({cl.kind}) cannot close "
                     f"(constraint residual {per[worst]:.3g} after 100 Gauss-Newton steps from the reference configuration)")


def _null(A: FloatArray) -> FloatArray:
    return sla.null_space(A, rcond=_TOL) if A.shape[0] else np.eye(A.shape[1])


def _idle_joints(model: pin.Model, closures, actuated: list[int], q: FloatArray) -> list[int]:
    """pinocchio joints to lock: one per closure whose welded pair spins freely (see module docstring)."""
    nv = model.nv
    Jc = _kinematics(model, model.createData(), closures, q, exact=False)[1]
    side = {model.joints[j].idx_v for c in closures for j in (c.joint_a, c.joint_b) if j > 0} - set(actuated)
    fixed = [v for v in range(nv) if v not in side]
    E = np.eye(nv)
    N = _null(np.vstack([Jc, E[fixed]]))
    locked: list[int] = []
    for c in closures:
        if N.shape[1] == 0:
            break
        for j in (c.joint_b, c.joint_a):
            v = model.joints[j].idx_v if j > 0 else -1
            if v in side and np.linalg.norm(N[v]) > 1e-6:
                fixed.append(v)
                locked.append(j)
                N = _null(np.vstack([Jc, E[fixed]]))
                break
    return locked


def _reduce(model: pin.Model, closures, locked: list[int], q: FloatArray):
    """Reduced model, closures re-attached to the nearest moving ancestor, reduced q."""
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    red = pin.buildReducedModel(model, locked, q)
    gone = set(locked)

    def side(j: int, P: pin.SE3) -> tuple[int, pin.SE3]:
        a = j
        while a in gone:
            a = model.parents[a]
        if a != j:
            P = data.oMi[a].actInv(data.oMi[j]) * P
        return (red.getJointId(model.names[a]) if a else 0), P

    new = []
    for c in closures:
        ja, Pa = side(c.joint_a, c.placement_a)
        jb, Pb = side(c.joint_b, c.placement_b)
        new.append(LoopClosure(c.name, ja, Pa, jb, Pb, c.kind))
    qr = np.array([q[model.joints[model.getJointId(red.names[j])].idx_q] for j in range(1, red.njoints)])
    return red, new, qr


def _lock(model: pin.Model, closures, locked: list[int], q: FloatArray, name: str, notes: list[str]):
    """Lock the idle joints at 0 (their pose in the file) if the loops still close so, else at
    their assembled values; note each. Returns the reduced model, closures and assembled q."""
    q0 = q.copy()
    q0[[model.joints[j].idx_q for j in locked]] = 0.0
    try:
        red, new, qr = _reduce(model, closures, locked, q0)
        qr, at = _assemble(red, new, qr, name), q0
    except ModelError:
        (red, new, qr), at = _reduce(model, closures, locked, q), q
    for j in locked:
        c = next(c for c in closures if j in (c.joint_a, c.joint_b))
        notes.append(
            f"locked idle joint {model.names[j]}: closure {c.name!r} ({c.kind}) leaves it free to spin with the joint at "
            f"the other side, a motion no actuator determines; locked at {at[model.joints[j].idx_q]:.4g} rad, its body "
            "merged into its parent"
        )
    return red, new, qr


def _world_aligned(model: pin.Model, closures, q: FloatArray) -> list[LoopClosure]:
    """``6d`` closures with both frames turned (by the same rotation, which leaves the
    constraint unchanged) to be world-aligned at the assembly ``q``.

    :class:`Mechanism` picks the independent rows of a planar loop on world-frame angular
    rows but its Newton solver uses the ``log3`` rows, expressed in the closure frame:
    the two agree only when the closure frames are world-aligned (and stay so in planar
    motion about a world axis)."""
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    out = []
    for c in closures:
        if c.kind == "6d":
            turn = pin.SE3((data.oMi[c.joint_a] * c.placement_a).rotation.T, np.zeros(3))
            c = LoopClosure(c.name, c.joint_a, c.placement_a * turn, c.joint_b, c.placement_b * turn, c.kind)
        out.append(c)
    return out


def solve_positions(mech, u: FloatArray, q0: FloatArray | None, tol: float, max_iter: int, max_cond: float) -> FloatArray:
    """:meth:`Mechanism.solve_positions <dynid.model.mechanism.Mechanism.solve_positions>` (its docstring):
    Newton's method on :math:`[c(q); u(q) - u^*] = 0`, warm-started along the samples."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    n_u = mech.independent.size
    if u.ndim != 2 or u.shape[1] != n_u:
        raise InputError(f"independent coordinates must have shape (n, {n_u}), got {u.shape}")
    if not np.all(np.isfinite(u)):
        raise InputError("independent coordinates contain NaN or infinite values")
    n = u.shape[0]
    if q0 is None and mech.position_guess is not None:
        try:
            q0 = np.asarray(mech.position_guess(u), dtype=float)
        except ModelError:
            q0 = None  # out of the closed form's reach: Newton from q_ref says why
    per_sample = q0 is not None and np.ndim(q0) == 2
    if per_sample and np.shape(q0) != (n, mech.nv):
        raise InputError(f"q0 must have shape ({n}, {mech.nv}), got {np.shape(q0)}")
    guess = mech.q_ref if q0 is None else np.asarray(q0, dtype=float)
    data = mech.pin_model.createData()
    rows = mech.constraint_rows
    out = np.empty((n, mech.nv))
    q = (guess[0] if per_sample else guess).copy()
    for i in range(n):
        if per_sample:
            q = guess[i].copy()
        for it in range(max_iter + 1):
            F = np.concatenate([mech._constraint_residual(q, data)[rows], mech._coordinate_values(q, data) - u[i]])
            if np.linalg.norm(F, np.inf) < tol:
                break
            A = np.vstack([mech._constraint_jacobian(q, data, exact=True)[rows], mech._coordinate_jacobian(q, data)])
            cond = np.linalg.cond(A)
            if not np.isfinite(cond) or cond > max_cond:
                raise ModelError(
                    f"sample {i}: singular configuration while solving the loops "
                    f"(condition number of [J_c; J_u] = {cond:.3g}, residual {np.linalg.norm(F, np.inf):.3g})"
                )
            if it == max_iter:
                raise ModelError(
                    f"sample {i}: pose u = {np.array2string(u[i], precision=4)} is unreachable or too far from "
                    f"the initial guess (residual {np.linalg.norm(F, np.inf):.3g} after {max_iter} Newton steps, "
                    f"condition number {cond:.3g})"
                )
            q = q - np.linalg.solve(A, F)
        out[i] = q
    mech.check_ball_charts(out, "solve_positions")
    return out
