"""Serial robots under digital control: plant, controllers, zero-order-hold simulation loop.

* :class:`SerialPlant`: forward dynamics by pinocchio's ABA with body inertias and rotor
  inertias (``model.armature``) from standard parameters, any friction model of
  :mod:`dynid.model.friction` as ground truth, gravity, and an optional payload rigidly
  attached to a body (default the last).
* Controllers, evaluated once per sampling period on the measured state and held
  (zero-order hold): :class:`JointPID`, :class:`ComputedTorque` (a given model: nominal or
  identified) and :class:`FeedforwardPID` (model feedforward on the reference + PID, paper
  002, Section 5.4).
* :func:`simulate_control`: the loop. Between samples the plant is integrated with
  classical Runge–Kutta 4 substeps under the held torque.

Discontinuous Coulomb friction: when a joint velocity changes sign inside a hold period,
the friction the controller compensated (from the velocity measured at the sample) and the
plant's differ by :math:`2 f_c` until the next sample, and an explicit integrator chatters
about zero velocity while the joint would stick. Tracking errors then grow at reversals
(millimetres for the 6R arm's 8 N·m); the smooth models of :mod:`dynid.model.friction`
(``SmoothStribeck``) avoid it. A stick-slip (Karnopp) plant is not implemented.

Friction with memory (:class:`~dynid.model.friction.FrictionMemory`): the friction state ``z``
(one per joint, starting at the steady state of the initial velocity) is integrated together with
``(q, v)``: one classical RK4 on the augmented state ``(q, v, z)`` with
:math:`\\ddot q = \\mathrm{ABA}(q, \\dot q, \\tau - z)`, :math:`\\dot z = (F_{ss}(\\dot q) - z)/T_m`
per substep (the same stages, so the coupling is integrated to the method's order). Without
memory the loop is the unchanged (q, v) RK4.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError
from dynid.model.friction import CoulombViscous, FrictionMemory, FrictionModel, force_function
from dynid.model.serial_dynamics import check_states, extras_torque
from dynid.model.robot import ASYMMETRIC_EXTRAS, RobotModel
from dynid.simulation._integrate import rk4_step

__all__ = ["ComputedTorque", "ControlledMotion", "FeedforwardPID", "JointPID", "SerialPlant", "simulate_control"]

Reference = Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray]]


@dataclasses.dataclass(frozen=True, eq=False)
class SerialPlant:
    """The true robot of a virtual experiment.

    Parameters
    ----------
    robot : RobotModel
    params : array, shape (n_params,)
        True standard parameters (body inertias; rotor inertias ``Ia`` if the layout has them).
    friction : FrictionModel, optional
        True joint friction; default: Coulomb + viscous + offset from ``params`` (``fc``,
        ``fv``, ``offset``; zero where the layout has none).
    payload : pinocchio.Inertia, optional
        A load rigidly attached to the body of joint ``payload_joint`` (in its joint frame).
    payload_joint : int, optional
        pinocchio joint index (1-based) of the body that carries the payload; default the last.
    """

    robot: RobotModel
    params: FloatArray
    friction: FrictionModel | None = None
    payload: pin.Inertia | None = None
    payload_joint: int | None = None

    def __post_init__(self) -> None:
        params = np.asarray(self.params, dtype=float)
        model = self.robot.with_parameters(params)
        if self.payload is not None:
            j = model.njoints - 1 if self.payload_joint is None else int(self.payload_joint)
            if not 1 <= j < model.njoints:
                raise InputError(f"payload_joint {j} is not a joint of {self.robot.name!r} (1 to {model.njoints - 1})")
            model.inertias[j] = model.inertias[j] + self.payload
        if self.robot.layout.coupled_motors:
            raise InputError("SerialPlant does not simulate coupled motors yet")
        friction = self.friction
        if friction is None:
            lay = self.robot.layout
            get = lambda e: params[lay.extra_index[e]] if e in lay.extra_index else np.zeros(lay.nv)  # noqa: E731
            if any(e in lay.extra_index for e in ASYMMETRIC_EXTRAS):
                friction = LayoutFriction(self.robot, params)
            else:
                friction = CoulombViscous(fc=get("fc"), fv=get("fv"), offset=get("offset"))
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "friction", friction)
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "data", model.createData())
        object.__setattr__(self, "_friction_at", force_function(friction))

    model: pin.Model = dataclasses.field(init=False, repr=False)
    data: pin.Data = dataclasses.field(init=False, repr=False)
    _friction_at: Callable[[FloatArray], FloatArray] = dataclasses.field(init=False, repr=False)
    """The friction at one sample, ``(n_v,) -> (n_v,)``: the operations of ``friction.force(dq)[0]``
    without its conversions (:func:`~dynid.model.friction.force_function`)."""

    @property
    def nv(self) -> int:
        return int(self.model.nv)

    def acceleration(self, q: FloatArray, dq: FloatArray, tau: FloatArray, friction: FloatArray | None = None) -> FloatArray:
        """Joint accelerations under joint torques ``tau`` (friction subtracted), by ABA.
        ``friction``: the friction torque now (a friction state with memory); default the
        friction model's force at ``dq``."""
        if friction is None:
            dq = np.asarray(dq, dtype=float)
            f = self._friction_at(dq) if dq.ndim == 1 else self.friction.force(dq)[0]
        else:
            f = np.asarray(friction, dtype=float)
        net = np.asarray(tau, dtype=float) - f
        return pin.aba(self.model, self.data, q, dq, net).copy()

    def torque(self, q: FloatArray, dq: FloatArray, ddq: FloatArray) -> FloatArray:
        """Inverse dynamics of the true plant (RNEA + friction), shape (n, n_v)."""
        q, dq, ddq = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, dq, ddq))
        tau = np.array([pin.rnea(self.model, self.data, a, b, c) for a, b, c in zip(q, dq, ddq)])
        return tau + self.friction.force(dq)


@dataclasses.dataclass
class JointPID:
    """Independent joint PID on the position error (gains per joint)."""

    kp: FloatArray
    kd: FloatArray
    ki: FloatArray = 0.0
    _integral: FloatArray | None = dataclasses.field(default=None, repr=False)

    def __call__(self, dt: float, q: FloatArray, dq: FloatArray, ref: tuple[FloatArray, FloatArray, FloatArray]) -> FloatArray:
        e, de = ref[0] - q, ref[1] - dq
        self._integral = e * dt if self._integral is None else self._integral + e * dt
        return np.asarray(self.kp) * e + np.asarray(self.kd) * de + np.asarray(self.ki) * self._integral


@dataclasses.dataclass
class ComputedTorque:
    """:math:`\\tau = \\hat M(q)(\\ddot q_d + K_p e + K_d\\dot e) + \\hat h(q,\\dot q)` with a
    model ``inverse(q, dq, ddq) -> tau`` (nominal or identified)."""

    inverse: Callable[[FloatArray, FloatArray, FloatArray], FloatArray]
    kp: FloatArray
    kd: FloatArray

    def __call__(self, dt: float, q: FloatArray, dq: FloatArray, ref: tuple[FloatArray, FloatArray, FloatArray]) -> FloatArray:
        qd, dqd, ddqd = ref
        a = ddqd + np.asarray(self.kp) * (qd - q) + np.asarray(self.kd) * (dqd - dq)
        return np.asarray(self.inverse(q[None], dq[None], a[None]))[0]


@dataclasses.dataclass
class FeedforwardPID:
    """Model feedforward on the reference plus joint PID (paper 002, Section 5.4)."""

    inverse: Callable[[FloatArray, FloatArray, FloatArray], FloatArray]
    pid: JointPID

    def __call__(self, dt: float, q: FloatArray, dq: FloatArray, ref: tuple[FloatArray, FloatArray, FloatArray]) -> FloatArray:
        ff = np.asarray(self.inverse(ref[0][None], ref[1][None], ref[2][None]))[0]
        return ff + self.pid(dt, q, dq, ref)


@dataclasses.dataclass(frozen=True, eq=False)
class LayoutFriction(FrictionModel):
    """The friction and offset extras of a serial layout with their values in ``params`` (the
    asymmetric ones of Shang 2009 Eq. 2 included), as a plant's ground truth; rotor inertia is
    not friction (the plant's ABA has it in the armature)."""

    robot: RobotModel
    params: FloatArray

    def force(self, dq: FloatArray) -> FloatArray:
        dq = np.atleast_2d(np.asarray(dq, dtype=float))
        p = np.array(self.params, dtype=float)
        if "Ia" in self.robot.layout.extra_index:
            p[self.robot.layout.extra_index["Ia"]] = 0.0
        return extras_torque(self.robot, p, dq, np.zeros_like(dq))


class _ModelInverse:
    """``inverse(q, dq, ddq)``: :func:`~dynid.model.serial_dynamics.inverse_dynamics` with the
    parameterized pinocchio model, its data and the extras' parameters prepared once (a controller
    calls it every control period; rebuilding the model per call was a third of a serial
    simulation's time). The same operations, so the same torques to the last bit."""

    def __init__(self, robot: RobotModel, params: FloatArray) -> None:
        self.robot = robot
        params = np.array(params, dtype=float, copy=True)
        self.model = robot.with_parameters(params)
        self.data = self.model.createData()
        if "Ia" in robot.layout.extra_index:
            params[robot.layout.extra_index["Ia"]] = 0.0  # armature already in rnea
        self.no_ia = params

    def __call__(self, q: FloatArray, dq: FloatArray, ddq: FloatArray) -> FloatArray:
        q, dq, ddq = check_states(self.robot, q, dq, ddq)
        tau = np.empty_like(q)
        for i in range(q.shape[0]):
            tau[i] = pin.rnea(self.model, self.data, q[i], dq[i], ddq[i])
        return tau + extras_torque(self.robot, self.no_ia, dq, ddq)


def model_inverse(robot: RobotModel, params: FloatArray) -> Callable[[FloatArray, FloatArray, FloatArray], FloatArray]:
    """``inverse(q, dq, ddq)`` of a model (RNEA with rotor inertia + the layout's friction), for the
    parameters as they are now (a copy is kept)."""
    return _ModelInverse(robot, params)


@dataclasses.dataclass(frozen=True, eq=False)
class ControlledMotion:
    """Samples at the control instants: time, true positions, velocities, accelerations
    (at the start of each hold), the held torques, and the reference."""

    t: FloatArray
    q: FloatArray
    dq: FloatArray
    ddq: FloatArray
    tau: FloatArray
    q_ref: FloatArray
    dq_ref: FloatArray
    ddq_ref: FloatArray


def simulate_control(
    plant: SerialPlant,
    controller,
    reference: Reference,
    *,
    duration: float,
    dt: float,
    substeps: int = 4,
    q0: FloatArray | None = None,
    dq0: FloatArray | None = None,
    measure: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]] | None = None,
) -> ControlledMotion:
    """Digital control loop with zero-order hold.

    Parameters
    ----------
    plant : SerialPlant
    controller : callable ``(dt, q_meas, dq_meas, (q_d, dq_d, ddq_d)) -> tau``
    reference : callable ``t (n,) -> (q_d, dq_d, ddq_d)``, each (n, n_v) (e.g. a trajectory's ``sample``)
    duration, dt : float
        Simulated time and control period [s].
    substeps : int
        RK4 steps per control period.
    q0, dq0 : array, optional
        Initial state (default: the reference at t = 0).
    measure : callable, optional
        ``(q, dq) -> (q_meas, dq_meas)`` (sensors); default perfect measurements.
    """
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    qr, dqr, ddqr = reference(t)
    nv = plant.nv
    if qr.shape != (n, nv):
        raise InputError(f"the reference has {qr.shape[1]} coordinates, the plant {nv} joints")
    q = np.array(qr[0] if q0 is None else q0, dtype=float)
    v = np.array(dqr[0] if dq0 is None else dq0, dtype=float)
    if isinstance(plant.friction, FrictionMemory):
        return _simulate_memory(plant, controller, (t, qr, dqr, ddqr), q, v, dt, substeps, measure)
    Q, V, A, T = (np.empty((n, nv)) for _ in range(4))
    h = dt / substeps
    model, data, friction_at, aba = plant.model, plant.data, plant._friction_at, pin.aba
    for k in range(n):
        qm, vm = (q, v) if measure is None else measure(q, v)
        tau = np.asarray(controller(dt, qm, vm, (qr[k], dqr[k], ddqr[k])), dtype=float)

        def acc(a: FloatArray, b: FloatArray, tau: FloatArray = tau) -> FloatArray:  # plant.acceleration(a, b, tau)
            return aba(model, data, a, b, tau - friction_at(b)).copy()

        Q[k], V[k], T[k] = q, v, tau
        A[k] = first = acc(q, v)
        if k == n - 1:
            break
        for _ in range(substeps):
            q, v = rk4_step(acc, q, v, h, k1=first)
            first = None
    return ControlledMotion(t=t, q=Q, dq=V, ddq=A, tau=T, q_ref=qr, dq_ref=dqr, ddq_ref=ddqr)


def _simulate_memory(plant: SerialPlant, controller, ref, q: FloatArray, v: FloatArray, dt: float, substeps: int,
                     measure) -> ControlledMotion:
    """:func:`simulate_control` for a plant whose friction has memory: RK4 on (q, v, z).

    The state is one vector ``y = (q, v, z)`` (3 n_v), so each stage's update is one array
    operation: elementwise the same operations as on the three parts (the same result to the last
    bit). Per stage, :math:`\\dot y = (v,\\ \\mathrm{ABA}(q, v, \\tau - z),\\ (F_{ss}(v) - z)/T_m)`
    (:meth:`SerialPlant.acceleration` with the friction state, :meth:`FrictionMemory.rate` through
    :func:`~dynid.model.friction.force_function`); the acceleration logged at a control instant is
    the first stage of the hold's first step. Nothing handed to the controller, ``measure`` or the
    log is modified afterwards (``y`` is replaced, never written in place)."""
    t, qr, dqr, ddqr = ref
    fm: FrictionMemory = plant.friction  # type: ignore[assignment]
    n, nv = t.size, plant.nv
    steady, tm = force_function(fm.steady), fm.time_constant
    model, data, aba, concatenate = plant.model, plant.data, pin.aba, np.concatenate
    iq, iv, iz = slice(0, nv), slice(nv, 2 * nv), slice(2 * nv, 3 * nv)
    y = np.concatenate([q, v, steady(v)])  # z: the steady state of the initial velocity

    def f(yy: FloatArray, tau: FloatArray, a: FloatArray | None = None) -> FloatArray:
        vv, zz = yy[iv], yy[iz]
        return concatenate((vv, aba(model, data, yy[iq], vv, tau - zz) if a is None else a, (steady(vv) - zz) / tm))

    Q, V, A, T = (np.empty((n, nv)) for _ in range(4))
    h = dt / substeps
    h2, h6 = h / 2, h / 6
    for k in range(n):
        q, v, z = y[iq], y[iv], y[iz]
        qm, vm = (q, v) if measure is None else measure(q, v)
        tau = np.asarray(controller(dt, qm, vm, (qr[k], dqr[k], ddqr[k])), dtype=float)
        Q[k], V[k], T[k] = q, v, tau
        A[k] = aba(model, data, q, v, tau - z)
        if k == n - 1:
            break
        for i in range(substeps):
            k1 = f(y, tau, A[k] if i == 0 else None)
            k2 = f(y + h2 * k1, tau)
            k3 = f(y + h2 * k2, tau)
            k4 = f(y + h * k3, tau)
            y = y + h6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ControlledMotion(t=t, q=Q, dq=V, ddq=A, tau=T, q_ref=qr, dq_ref=dqr, ddq_ref=ddqr)
