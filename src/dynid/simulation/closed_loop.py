"""Forward dynamics of closed-loop mechanisms by pinocchio's constraint dynamics.

This route shares nothing with the regressor of :mod:`dynid.model.closed_loop` except the
pinocchio tree: the loop closures become pinocchio ``RigidConstraintModel``\\ s
(``CONTACT_3D`` / ``CONTACT_6D``) and the accelerations come from pinocchio's proximal
KKT solver (``constraintDynamics``), which also copes with redundant constraint rows.
Joint terms enter as known forces: rotor inertias of single joints through
``model.armature``, everything else (friction, offsets) as generalized forces.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.closed_loop import term_columns
from dynid.model.mechanism import Mechanism

__all__ = ["ConstrainedSimulator", "SimulatedMotion"]


@dataclasses.dataclass(frozen=True, eq=False)
class SimulatedMotion:
    """Samples of a simulated motion: time [s], all joint positions, velocities, accelerations,
    and the actuator forces applied."""

    t: FloatArray
    q: FloatArray
    dq: FloatArray
    ddq: FloatArray
    tau_a: FloatArray


class ConstrainedSimulator:
    """Constrained forward dynamics :math:`\\ddot q = FD(q, \\dot q, \\tau_a)` of a mechanism.

    Parameters
    ----------
    mech : Mechanism
    params : array, shape (n_params,)
        Standard parameters (body inertias and joint terms).
    baumgarte : tuple of float
        Proportional and derivative gains of pinocchio's constraint stabilization
        (drift of the loop closures during integration).
    mu : float
        Proximal regularization of pinocchio's KKT solver (needed with redundant rows).
    """

    def __init__(self, mech: Mechanism, params: FloatArray, *, baumgarte: tuple[float, float] = (0.0, 0.0), mu: float = 1e-12) -> None:
        params = np.asarray(params, dtype=float)
        self.mech = mech
        self.params = params
        model = mech.with_parameters(params)
        nb = mech.n_body_params
        theta = params[nb:]
        arm = np.zeros(mech.nv)
        keep = np.ones(len(mech.terms), dtype=bool)
        for k, t in enumerate(mech.terms):
            if t.kind == "inertia" and len(t.joints) == 1:
                arm[t.joints[0]] += theta[k]
                keep[k] = False
            elif t.kind == "inertia":
                raise ModelError(f"shared inertia term {t.name!r} cannot be simulated as an armature")
        model.armature = arm
        self._theta = np.where(keep, theta, 0.0)
        self.model = model
        self.data = model.createData()
        self.cmodels = pin.StdVec_RigidConstraintModel()
        for c in mech.closures:
            ctype = pin.ContactType.CONTACT_3D if c.kind == "3d" else pin.ContactType.CONTACT_6D
            cm = pin.RigidConstraintModel(ctype, model, c.joint_a, c.placement_a, c.joint_b, c.placement_b, pin.ReferenceFrame.LOCAL)
            bp = cm.m_baumgarte_parameters
            bp.Kp, bp.Kd = float(baumgarte[0]), float(baumgarte[1])
            cm.setBaumgarteCorrectorParameters(bp)
            self.cmodels.append(cm)
        self.cdatas = pin.StdVec_RigidConstraintData()
        for cm in self.cmodels:
            self.cdatas.append(cm.createData())
        pin.initConstraintDynamics(model, self.data, self.cmodels, self.cdatas)
        self.prox = pin.ProximalSettings(1e-14, mu, 100)
        self.Sa = mech.actuator_selection()

    def joint_forces(self, dq: FloatArray, tau_a: FloatArray) -> FloatArray:
        """Generalized forces on the tree: actuators minus the joint terms (rotor inertia excluded)."""
        F = term_columns(self.mech, dq[None], np.zeros((1, dq.size)))[0]
        return self.Sa.T @ tau_a - F @ self._theta

    def acceleration(self, q: FloatArray, dq: FloatArray, tau_a: FloatArray) -> FloatArray:
        """Joint accelerations under actuator forces ``tau_a`` (shape (n_a,))."""
        tau_a = np.asarray(tau_a, dtype=float)
        if tau_a.shape != (self.mech.n_actuators,):
            raise InputError(f"tau_a must have shape ({self.mech.n_actuators},), got {tau_a.shape}")
        tau = self.joint_forces(dq, tau_a)
        return pin.constraintDynamics(self.model, self.data, q, dq, tau, self.cmodels, self.cdatas, self.prox).copy()

    def simulate(self, q0: FloatArray, dq0: FloatArray, tau_fn, *, duration: float, dt: float) -> SimulatedMotion:
        """Classical Runge–Kutta 4 integration with actuator forces ``tau_fn(t) -> (n_a,)``.

        Returns samples at ``t = 0, dt, ..., duration`` with the acceleration and forces
        evaluated at each sample.
        """
        n = int(round(duration / dt)) + 1
        nv = self.mech.nv
        t = np.arange(n) * dt
        Q, V, A, T = np.empty((n, nv)), np.empty((n, nv)), np.empty((n, nv)), np.empty((n, self.mech.n_actuators))
        q, v = np.array(q0, dtype=float), np.array(dq0, dtype=float)
        for i in range(n):
            ti = t[i]
            tau = np.asarray(tau_fn(ti), dtype=float)
            a = self.acceleration(q, v, tau)
            Q[i], V[i], A[i], T[i] = q, v, a, tau
            if i == n - 1:
                break
            k1q, k1v = v, a
            tau_h = np.asarray(tau_fn(ti + dt / 2), dtype=float)
            k2q = v + dt / 2 * k1v
            k2v = self.acceleration(q + dt / 2 * k1q, k2q, tau_h)
            k3q = v + dt / 2 * k2v
            k3v = self.acceleration(q + dt / 2 * k2q, k3q, tau_h)
            k4q = v + dt * k3v
            k4v = self.acceleration(q + dt * k3q, k4q, np.asarray(tau_fn(ti + dt), dtype=float))
            q = q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            v = v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        return SimulatedMotion(t=t, q=Q, dq=V, ddq=A, tau_a=T)
