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
import functools

import numpy as np
from threadpoolctl import ThreadpoolController
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model import loop_kinematics
from dynid.model.closed_loop import OneSampleForces, actuator_forces, piecewise_linear_terms
from dynid.model.mechanism import Mechanism
from dynid.simulation._integrate import rk4_step
from dynid.simulation._joint_laws import piecewise_law
from dynid.simulation.control import JointPID

__all__ = ["ActuatorReference", "AugmentedPD", "ConstrainedSimulator", "DecentralizedPID", "SimulatedMotion",
           "simulate_mechanism_control"]


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
    friction : callable, optional
        Ground-truth friction ``friction(dq (n_v,)) -> generalized forces (n_v,)`` replacing
        the joint terms' friction and offsets (rotor inertias stay), e.g. a Stribeck model of
        :mod:`dynid.model.friction` on some joints.
    coulomb_band : float, optional
        Velocity band of a regularized Coulomb law for the joint terms' friction: the Coulomb
        levels act through ``tanh(dq / coulomb_band)`` instead of ``sign(dq)`` (the same forces
        outside a few bands of zero velocity). An explicit integrator chatters about zero
        velocity under the discontinuous law (:mod:`dynid.simulation.control`), and the motion
        then depends discontinuously on the parameters; the continuous law is the usual remedy
        (Olsson, Åström, Canudas de Wit, Gäfvert & Lischinsky, "Friction models and friction
        compensation", Eur. J. Control 4(3), 1998, Section 2: the classical models regularized
        near zero velocity for simulation). The model replays of IDIM-IV and DIDIM use it
        (:mod:`dynid.pipeline.control_loop`). Default: the discontinuous law.
    """

    def __init__(
        self,
        mech: Mechanism,
        params: FloatArray,
        *,
        baumgarte: tuple[float, float] = (0.0, 0.0),
        mu: float = 1e-12,
        friction=None,
        coulomb_band: float | None = None,
    ) -> None:
        params = np.asarray(params, dtype=float)
        self.mech = mech
        self.params = params
        model = mech.with_parameters(params)
        nb = mech.n_body_params
        theta = params[nb:]
        arm = np.zeros(mech.nv)
        keep = np.ones(len(mech.terms), dtype=bool)
        for k, t in enumerate(mech.terms):
            if t.weights:
                raise ModelError(f"joint term {t.name!r} acts through a combination of joint velocities (a coupled "
                                 "motor); the constrained simulator takes per-joint terms")
            if t.kind == "inertia" and len(t.joints) == 1:
                arm[t.joints[0]] += theta[k]
                keep[k] = False
            elif t.kind == "inertia":
                raise ModelError(f"shared inertia term {t.name!r} cannot be simulated as an armature")
        model.armature = arm
        self._theta = np.where(keep, theta, 0.0)
        self._friction_coefficients = piecewise_linear_terms(mech, self._theta)
        a, b, c, d, e = self._friction_coefficients
        self._symmetric_friction = bool(np.array_equal(a, b) and np.array_equal(d, -c) and not np.any(e))
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
        self.friction = friction
        if coulomb_band is not None and not (np.isfinite(coulomb_band) and coulomb_band > 0):
            raise InputError(f"coulomb_band must be positive and finite, got {coulomb_band}")
        self.coulomb_band = coulomb_band
        # tau_joint minus the joint terms, built once (:mod:`dynid.simulation._joint_laws`)
        self._law = (_friction_law(friction) if friction is not None
                     else piecewise_law(self._friction_coefficients, coulomb_band))

    def joint_forces(self, dq: FloatArray, tau_a: FloatArray) -> FloatArray:
        """Generalized forces on the tree: actuators minus the joint terms (rotor inertia excluded)."""
        return self._joint_forces(dq, self.Sa.T @ tau_a)

    def _joint_forces(self, dq: FloatArray, tau_joint: FloatArray) -> FloatArray:
        """:meth:`joint_forces` with the actuator forces already on the joints (``S_a^T tau_a``):
        :math:`a v^+ + b v^- + c[v>0] + d[v<0] + e` per joint (``_friction_coefficients``), with
        the regularized Coulomb law :math:`\\tfrac12(c-d)\\tanh(v/v_b) + \\tfrac12(c+d)|\\tanh(v/v_b)|`
        in place of the levels when ``coulomb_band`` is set, or ``friction(dq)``; evaluated by
        :func:`dynid.simulation._joint_laws.piecewise_law` (the same values in fewer operations)."""
        return self._law(dq, tau_joint)

    def acceleration(self, q: FloatArray, dq: FloatArray, tau_a: FloatArray) -> FloatArray:
        """Joint accelerations under actuator forces ``tau_a`` (shape (n_a,))."""
        tau_a = np.asarray(tau_a, dtype=float)
        if tau_a.shape != (self.mech.n_actuators,):
            raise InputError(f"tau_a must have shape ({self.mech.n_actuators},), got {tau_a.shape}")
        return self._acceleration(q, dq, self.Sa.T @ tau_a)

    def _acceleration(self, q: FloatArray, dq: FloatArray, tau_joint: FloatArray) -> FloatArray:
        tau = self._joint_forces(dq, tau_joint)
        return pin.constraintDynamics(self.model, self.data, q, dq, tau, self.cmodels, self.cdatas, self.prox).copy()

    def held(self, tau_a: FloatArray):
        """``acc(q, dq)``: :meth:`acceleration` under the actuator forces ``tau_a`` held (a
        zero-order hold), their joint forces computed once for the whole period."""
        tau_a = np.asarray(tau_a, dtype=float)
        if tau_a.shape != (self.mech.n_actuators,):
            raise InputError(f"tau_a must have shape ({self.mech.n_actuators},), got {tau_a.shape}")
        return self._held(self.Sa.T @ tau_a)

    def _held(self, tau_joint: FloatArray):
        """:meth:`held` with the forces on the joints: :meth:`_acceleration` with everything it
        reads bound once (called four times per RK4 step)."""
        dynamics, forces = pin.constraintDynamics, self._law
        model, data, cmodels, cdatas, prox = self.model, self.data, self.cmodels, self.cdatas, self.prox

        def acc(q: FloatArray, dq: FloatArray) -> FloatArray:
            return dynamics(model, data, q, dq, forces(dq, tau_joint), cmodels, cdatas, prox).copy()

        return acc

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


def _friction_law(friction):
    """``law(dq, tau_joint)`` of a ground-truth friction model ``friction(dq) -> (n_v,)``."""
    return lambda dq, tau: tau - np.asarray(friction(dq), dtype=float).reshape(-1)


class AugmentedPD:
    """Model-based control of a mechanism in its independent coordinates.

    :math:`\\tau_a = D\\,G^T\\big(Y(q,\\dot q,\\ddot q(a_u))\\hat\\pi\\big)` with
    :math:`a_u = \\ddot u_d + K_v(\\dot u_d - \\dot u) + K_p(u_d - u)`: the closed-loop model
    (:func:`~dynid.model.closed_loop.actuator_regressor`) evaluated at the commanded
    acceleration and distributed to the actuators by ``distribution``. With
    ``"min_norm_local_friction"`` this is the augmented PD of Shang et al. 2009 (Eq. 22:
    :math:`\\tau = (S^T)^+(M_e(\\ddot x_d + K_v\\dot e + K_p e) + C_e\\dot x) + f_a`, paper gains
    :math:`K_p = \\mathrm{diag}(35000)`, :math:`K_v = \\mathrm{diag}(300)`); for
    non-redundant actuation the distribution is None (computed torque in ``u``).

    Parameters
    ----------
    mech : Mechanism
    params : array
        Model parameters (nominal or identified standard parameters).
    kp, kv : array, shape (n_u,)
    distribution : str or None
    """

    def __init__(self, mech: Mechanism, params: FloatArray, kp: FloatArray, kv: FloatArray, distribution: str | None = None) -> None:
        self.mech, self.params = mech, np.asarray(params, dtype=float)
        self.kp, self.kv = np.asarray(kp, dtype=float), np.asarray(kv, dtype=float)
        self.distribution = distribution
        self._model = mech.with_parameters(self.params)  # the model's inertias, for RNEA at every period
        self._data = self._model.createData()
        self._kinematics = mech.pin_model.createData()  # working memory of the kinematics, reused every period
        self._forces = OneSampleForces(mech, self.params, distribution)  # the parameters' joint terms summed once

    def __call__(self, dt: float, q: FloatArray, dq: FloatArray, ref: tuple[FloatArray, FloatArray, FloatArray]) -> FloatArray:
        # Mechanism.states and actuator_forces of one sample, fused: one kinematics pass gives the
        # coordinates, their rates and the velocity map (loop_kinematics._one_geometry), one more
        # the accelerations at the commanded a_u (_one_rates); the same formulas, the coordinates
        # from the same placements (tests/test_closed_loop_fast_paths.py)
        mech, data = self.mech, self._kinematics
        q, dq = np.asarray(q, dtype=float), np.asarray(dq, dtype=float)
        if q.shape != (mech.nv,) or dq.shape != (mech.nv,) or not (np.isfinite(q).all() and np.isfinite(dq).all()):
            raise InputError(f"the controller needs finite joint positions and velocities of shape ({mech.nv},)")
        mech.check_ball_charts(q, "states")
        geometry = loop_kinematics._one_geometry(mech, q, data, 1e8)
        coords = loop_kinematics._one_coordinates(mech, geometry, dq)
        if coords is None:  # a point on the fixed base (no motion to control)
            coords = mech.coordinates(q, data=data)[0], mech.coordinate_velocities(q, dq, data=data)[0]
        u, du = coords
        a = ref[2] + self.kv * (ref[1] - du) + self.kp * (ref[0] - u)
        if not np.isfinite(a).all():
            raise InputError("the commanded acceleration of the independent coordinates is not finite")
        dq_u, ddq = loop_kinematics._one_rates(mech, geometry, du, a, data)
        # RNEA + joint terms, projected: equal to the closed-loop regressor times the parameters
        # (tests/test_closed_loop.py checks the two routes against each other)
        return self._forces(q, dq_u, ddq, geometry.G, self._model, self._data)


class ActuatorReference:
    """The reference of a mechanism's drives along a reference of its independent coordinates.

    Each drive of a decentralized controller follows its own actuator position (paper 002,
    Section 5.4: the PaLiDA drives are position-controlled one by one): the commanded
    :math:`u_d(t)` is turned into all joint positions by the mechanism's kinematics
    (:meth:`Mechanism.solve_positions`, the loop closures solved), velocities and
    accelerations by :meth:`Mechanism.states` (:math:`\\dot q = G\\dot u`,
    :math:`\\ddot q = G\\ddot u + \\ddot q_0`), and the actuated columns are kept. With a
    model (``params``) the feedforward is the model's actuator forces along the reference,
    :func:`~dynid.model.closed_loop.actuator_forces` (the inverse dynamics
    :math:`Q_a = A(x, v, a)\\,p` of paper 002, Eq. 1 with Eqs. 12–13, distributed by
    ``distribution`` for redundant actuation); it depends on the
    reference only, so it is computed once for all control instants.

    Calling it with the control instants ``t`` (n,) gives
    ``(u_d, du_d, ddu_d, q_a, dq_a, ddq_a, tau_ff)``: the independent coordinates (n, n_u),
    the actuator positions, velocities, accelerations and the feedforward forces (n, n_a)
    (zero without a model), the rows that :func:`simulate_mechanism_control` hands to
    :class:`DecentralizedPID` one control period at a time. The last evaluation is kept, so
    asking again for the same instants (the actuator tracking errors after a simulation)
    costs nothing.

    Parameters
    ----------
    mech : Mechanism
    reference : callable ``t (n,) -> (u_d, du_d, ddu_d)``, each (n, n_u)
    params : array, shape (n_params,), optional
        Standard parameters of the feedforward model (nominal, true or identified).
    distribution : str or None
        Force distribution of a redundantly actuated mechanism (``"min_norm"`` or
        ``"min_norm_local_friction"``); None otherwise.
    """

    def __init__(self, mech: Mechanism, reference, params: FloatArray | None = None, distribution: str | None = None) -> None:
        if mech.redundant and params is not None and distribution not in ("min_norm", "min_norm_local_friction"):
            raise InputError(f"a feedforward of the redundantly actuated {mech.name!r} needs a distribution of the forces "
                             f"('min_norm' or 'min_norm_local_friction'), got {distribution!r}")
        self.mech, self.reference = mech, reference
        self.params = None if params is None else np.asarray(params, dtype=float)
        self.distribution = distribution if mech.redundant else None
        self._last: tuple[FloatArray, tuple[FloatArray, ...]] | None = None

    def __call__(self, t: FloatArray) -> tuple[FloatArray, ...]:
        t = np.asarray(t, dtype=float)
        if self._last is not None and np.array_equal(self._last[0], t):
            return self._last[1]
        rows = self._evaluate(t)
        self._last = (t.copy(), rows)
        return rows

    def _evaluate(self, t: FloatArray) -> tuple[FloatArray, ...]:
        mech = self.mech
        u, du, ddu = (np.atleast_2d(np.asarray(x, dtype=float)) for x in self.reference(t))
        state = mech.states(mech.solve_positions(u), du, ddu)
        act = list(mech.actuated)
        if self.params is None:
            ff = np.zeros((u.shape[0], mech.n_actuators))
        else:
            ff = actuator_forces(mech, self.params, state, distribution=self.distribution)
        return u, du, ddu, state.q[:, act], state.dq[:, act], state.ddq[:, act], ff


@dataclasses.dataclass
class DecentralizedPID:
    """Decentralized control of a mechanism: one PID per actuator on its own position error,
    plus a feedforward force (paper 002, Section 5.4, Figs. 10–12: PID with the nominal or
    the identified model's forces along the reference).

    :math:`\\tau_{a,i} = \\tau_{ff,i} + K_{p,i} e_i + K_{d,i}\\dot e_i + K_{i,i}\\int e_i\\,dt`,
    :math:`e_i = q_{a,i}^d - q_{a,i}`, for every actuator i (redundant ones included: each
    drive has its own loop). The reference rows come from :class:`ActuatorReference`
    (``(u_d, du_d, ddu_d, q_a^d, dq_a^d, ddq_a^d, tau_ff)``); the controller reads only the
    actuated joints of the measured state.

    Parameters
    ----------
    mech : Mechanism
    pid : JointPID
        Gains per actuator, shape (n_a,) each (the integral state lives in it).
    """

    mech: Mechanism
    pid: JointPID

    def __post_init__(self) -> None:
        self._act = list(self.mech.actuated)

    def __call__(self, dt: float, q: FloatArray, dq: FloatArray, ref: tuple[FloatArray, ...]) -> FloatArray:
        if len(ref) != 7:
            raise InputError("DecentralizedPID needs the reference rows of ActuatorReference (actuator positions and feedforward)")
        _, _, _, qa, dqa, ddqa, ff = ref
        return ff + self.pid(dt, q[self._act], dq[self._act], (qa, dqa, ddqa))


def simulate_mechanism_control(
    sim: ConstrainedSimulator,
    controller,
    reference,
    *,
    duration: float,
    dt: float,
    substeps: int = 4,
    q0: FloatArray | None = None,
    exact_projection: bool = True,
) -> SimulatedMotion:
    """Digital control of a mechanism with zero-order hold (see :func:`dynid.simulation.control.simulate_control`).

    The controller ``(dt, q, dq, (u_d, du_d, ddu_d, ...)) -> tau_a`` sees all joint positions and
    velocities (true ones); ``reference(t)`` gives the independent coordinates, followed by any
    further per-instant signals of the controller (e.g. the actuator references and the
    feedforward of :class:`ActuatorReference`), all evaluated once on the control instants and
    handed over row by row. After every
    control period the state is projected back on the loop closures
    (:meth:`Mechanism.project`), so the constraint error stays at the 1e-12 level instead of
    drifting. The initial state is the assembly at ``u_d(0)`` at rest unless ``q0`` is given.

    ``exact_projection = False`` (the model replays of IV and DIDIM with the regularized Coulomb
    law, :func:`dynid.pipeline.simulate.run_simulation`): the projection leaves a state alone
    that is already on the closures within the tolerances: positions within ``1e-12``
    (:meth:`Mechanism.project`'s ``tol``: no Gauss–Newton step) and velocities whose constraint
    residual :math:`\\|J_c\\dot q\\|_\\infty` is at most ``1e-12 / dt`` (a residual that moves
    the closures by less than the position tolerance over a control period;
    :meth:`Mechanism.project`'s ``vtol``); past either, the full projection runs. On the hexapod
    twin of ``bench/control_loop_time.py`` the residual after a period is about 4e-14 m/s
    (median; at most 6e-9), so the QR of :math:`J_c` is skipped on 92 % of the periods, and the
    replayed motion is that of the every-period projection to 1e-5 of the integrator's own error
    (tests/test_closed_loop_replay.py). Not the default: under the discontinuous Coulomb law
    (chatter about zero velocity) or very stiff gains a residual of that size is not always
    negligible against the 1e-9 agreement with the reference formulas that
    tests/test_simulation_mechanism.py asks (shang2dof, Kp = 35000: 1.4e-7 of the scale).
    """
    with _threads().limit(limits=1, user_api="blas"):  # small matrices, step after step: threads only cost
        return _simulate_mechanism_control(sim, controller, reference, duration, dt, substeps, q0, exact_projection)


_PROJECTION_TOL = 1e-12  # Mechanism.project's default position tolerance [m or rad]


@functools.cache
def _threads() -> ThreadpoolController:
    """The BLAS libraries, found once (a scan of the loaded libraries costs about 20 ms, as long as a
    short replay of DIDIM; as :mod:`dynid.estimation.block_covariance`)."""
    return ThreadpoolController()


def _simulate_mechanism_control(sim, controller, reference, duration, dt, substeps, q0,
                                exact_projection: bool = False) -> SimulatedMotion:
    mech = sim.mech
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    refs = tuple(reference(t))
    ur, dur, ddur = refs[:3]
    if ur.shape != (n, mech.dof):
        raise InputError(f"the reference has {ur.shape[1]} coordinates, the mechanism {mech.dof} degrees of freedom")
    q = mech.solve_positions(ur[:1])[0] if q0 is None else np.array(q0, dtype=float)
    v = mech.states(q[None], dur[:1], ddur[:1]).dq[0]
    nv, na = mech.nv, mech.n_actuators
    Q, V, A, T = np.empty((n, nv)), np.empty((n, nv)), np.empty((n, nv)), np.empty((n, na))
    h = dt / substeps
    vtol = None if exact_projection else _PROJECTION_TOL / dt
    data = mech.pin_model.createData()  # the projection's working memory, reused every period
    rows = list(zip(*refs))  # the reference rows handed over period by period (row k of each signal)
    for k in range(n):
        tau = np.asarray(controller(dt, q, v, rows[k]), dtype=float)
        Q[k], V[k], T[k] = q, v, tau
        acc = sim.held(tau)
        A[k] = first = acc(q, v)
        if k == n - 1:
            break
        for _ in range(substeps):  # the logged acceleration is the first stage of the first step
            q, v = rk4_step(acc, q, v, h, k1=first)
            first = None
        q, v = mech.project(q, v, data=data, vtol=vtol)
    return SimulatedMotion(t=t, q=Q, dq=V, ddq=A, tau_a=T)
