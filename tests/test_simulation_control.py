"""Virtual experiments on serial robots: friction models, ABA plant, digital control loop."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from dynid.errors import ModelError
from dynid.model import load_robot
from dynid.model.closed_loop import term_forces
from dynid.model.friction import CoulombViscous, PowerLawViscous, SmoothStribeck, Stribeck
from dynid.model.robots import build_mechanism
from dynid.simulation.control import (
    ComputedTorque,
    FeedforwardPID,
    JointPID,
    SerialPlant,
    model_inverse,
    simulate_control,
)
from dynid.trajectories import FourierTrajectory


def test_friction_models_follow_their_equations():
    v = np.array([[-2.0, -0.01, 0.0, 0.01, 2.0]]).T * np.ones((1, 2))
    cv = CoulombViscous(fc=[0.5, 1.0], fv=[0.1, 0.2])
    np.testing.assert_allclose(cv.force(v)[:, 0], 0.5 * np.sign(v[:, 0]) + 0.1 * v[:, 0])
    s = Stribeck(fc=1.0, fs=1.5, fv=0.2, vs=0.1, delta=2.0)
    f = s.force(np.array([[1e-9], [-1e-9], [10.0], [0.1]]))[:, 0]
    np.testing.assert_allclose(f[:3], [1.5, -1.5, 1.0 + 2.0], rtol=1e-6)
    np.testing.assert_allclose(f[3], 1.0 + 0.5 * np.exp(-1.0) + 0.02)
    p = PowerLawViscous(fc=0.3, fv=0.5, alpha=0.5, offset=0.1)
    np.testing.assert_allclose(p.force(np.array([[4.0], [-4.0]]))[:, 0], [0.3 + 1.0 + 0.1, -0.3 - 1.0 + 0.1])
    ss = SmoothStribeck(fc=1.0, fs=1.5, fv=0.2, vs=0.1, kv=1e4, alpha=1.0)
    np.testing.assert_allclose(ss.force(np.array([[10.0]]))[0, 0], (1.0 + 0.5 * np.exp(-1e4)) * 2 / np.pi * np.arctan(1e5) + 2.0)
    assert ss.force(np.array([[0.0]]))[0, 0] == 0.0
    with pytest.raises(ModelError, match="positive"):
        Stribeck(fc=1.0, fs=1.5, fv=0.2, vs=0.0)


def test_asymmetric_coulomb_viscous_equals_shang_joint_terms():
    """The asymmetric model (Shang 2009, Eq. 2) equals the joint terms of builtin:shang2dof."""
    mech = build_mechanism("shang2dof")
    pi = mech.nominal_parameters()
    rng = np.random.default_rng(0)
    dq = rng.standard_normal((50, 6))
    val = dict(zip(mech.parameter_names, pi))
    act = [0, 2, 4]
    cv = CoulombViscous(
        fc=[val[f"fc+_qa{i}"] for i in (1, 2, 3)], fv=[val[f"fv+_qa{i}"] for i in (1, 2, 3)],
        fc_neg=[val[f"fc-_qa{i}"] for i in (1, 2, 3)], fv_neg=[val[f"fv-_qa{i}"] for i in (1, 2, 3)],
    )
    np.testing.assert_allclose(cv.force(dq[:, act]), term_forces(mech, pi, dq, np.zeros_like(dq))[:, act], atol=1e-14)


@pytest.fixture(scope="module")
def arm():
    robot = load_robot("builtin:generic6r")
    return robot, robot.nominal_parameters()


def test_plant_aba_inverts_rnea_with_friction(arm):
    robot, pi = arm
    plant = SerialPlant(robot, pi, friction=Stribeck(fc=0.8, fs=1.2, fv=0.3, vs=0.05))
    rng = np.random.default_rng(1)
    lo, hi = robot.position_limits()
    q = rng.uniform(lo, hi, (10, 6))
    dq, ddq = rng.standard_normal((10, 6)), rng.standard_normal((10, 6))
    tau = plant.torque(q, dq, ddq)
    for i in range(10):
        np.testing.assert_allclose(plant.acceleration(q[i], dq[i], tau[i]), ddq[i], atol=1e-9)
    # without a friction model the plant uses the parameters' own Ia, fv, fc, offset
    plain = SerialPlant(robot, pi)
    np.testing.assert_allclose(plain.torque(q, dq, ddq), model_inverse(robot, pi)(q, dq, ddq), atol=1e-10)


def test_free_motion_conserves_energy(arm):
    """No friction, no torque: kinetic + potential energy stays constant (pinocchio's kinetic
    energy includes the rotor inertias of ``model.armature``)."""
    robot, pi = arm
    pi = pi.copy()
    for e in ("fv", "fc", "offset"):
        pi[robot.layout.extra_index[e]] = 0.0
    plant = SerialPlant(robot, pi)
    q0 = np.array([0.3, -0.5, 0.8, 0.1, 0.4, -0.2])
    motion = simulate_control(plant, lambda dt, q, dq, ref: np.zeros(6), lambda t: (np.tile(q0, (t.size, 1)),) * 1
                              + (np.zeros((t.size, 6)),) * 2, duration=1.0, dt=1e-3, dq0=np.full(6, 0.5))
    model, data = plant.model, plant.data
    assert np.all(model.armature > 0)
    E = np.array([pin.computeKineticEnergy(model, data, q, v) + pin.computePotentialEnergy(model, data, q)
                  for q, v in zip(motion.q, motion.dq)])
    assert np.ptp(motion.q, axis=0).max() > 0.3  # it really moved
    assert np.abs(E - E[0]).max() < 1e-8 * np.abs(E).max()


def test_computed_torque_with_the_true_model_tracks_better_than_a_wrong_one(arm):
    """Without Coulomb friction (whose sign flips inside a hold period; see the module
    docstring) the true model tracks to the zero-order-hold error, a wrong one does not."""
    robot, pi = arm
    pi = pi.copy()
    pi[robot.layout.extra_index["fc"]] = 0.0
    rng = np.random.default_rng(2)
    lo, hi = robot.position_limits()
    ref = FourierTrajectory.random(6, 4, 0.2, rng, lo, hi, max_velocity=1.0, max_acceleration=3.0, fill=0.5)
    plant = SerialPlant(robot, pi)
    kp, kd = np.full(6, 400.0), np.full(6, 40.0)
    true = simulate_control(plant, ComputedTorque(model_inverse(robot, pi), kp, kd), ref.sample, duration=2.0, dt=1e-3)
    wrong_pi = pi * rng.uniform(0.7, 1.3, pi.size)
    wrong = simulate_control(plant, ComputedTorque(model_inverse(robot, wrong_pi), kp, kd), ref.sample, duration=2.0, dt=1e-3)
    err_true = np.abs(true.q - true.q_ref).max()
    err_wrong = np.abs(wrong.q - wrong.q_ref).max()
    assert err_true < 1e-4 and err_wrong > 10 * err_true
    # the recorded accelerations are the plant's response to the held torques
    np.testing.assert_allclose(plant.torque(true.q, true.dq, true.ddq), true.tau, atol=1e-8)
    # feedforward + PID also tracks, with a bounded error
    ff = FeedforwardPID(model_inverse(robot, pi), JointPID(kp=np.full(6, 2000.0), kd=np.full(6, 50.0), ki=np.full(6, 100.0)))
    m = simulate_control(plant, ff, ref.sample, duration=2.0, dt=1e-3)
    assert np.abs(m.q - m.q_ref).max() < 1e-3


def test_simulation_is_deterministic(arm):
    robot, pi = arm
    ref = FourierTrajectory.random(6, 3, 0.2, np.random.default_rng(3), *robot.position_limits(), fill=0.3)
    run = lambda: simulate_control(SerialPlant(robot, pi), JointPID(kp=np.full(6, 500.0), kd=np.full(6, 30.0)),  # noqa: E731
                                   ref.sample, duration=0.5, dt=1e-3)
    a, b = run(), run()
    assert np.array_equal(a.q, b.q) and np.array_equal(a.tau, b.tau)
