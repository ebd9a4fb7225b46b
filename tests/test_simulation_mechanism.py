"""Closed-loop mechanisms under digital control: drift-free constrained simulation, augmented
PD with the minimum-norm distribution (Shang 2009, Eq. 22), computed torque in u."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.model.closed_loop import actuator_regressor
from dynid.model.friction import Stribeck
from dynid.model.robots import build_mechanism, hexapod
from dynid.simulation.closed_loop import AugmentedPD, ConstrainedSimulator, simulate_mechanism_control
from dynid.trajectories import CirclePath
from dynid.trajectories import FourierTrajectory
from dynid.stats import tracking_errors


@pytest.fixture(scope="module")
def shang():
    return build_mechanism("shang2dof")


def test_augmented_pd_tracks_paper001_circle(shang):
    pi = shang.nominal_parameters()
    sim = ConstrainedSimulator(shang, pi)
    path = CirclePath((0.29, 0.25), 0.04, 0.2, turns=1, ramp=0.2)  # paper 001's circle, one turn
    gains = np.full(2, 35000.0), np.full(2, 300.0)  # paper 001, Eq. 22
    true = simulate_mechanism_control(sim, AugmentedPD(shang, pi, *gains, "min_norm_local_friction"), path.sample,
                                      duration=path.duration, dt=0.002)  # 500 Hz
    u_ref = path.sample(true.t)[0]
    err_true = np.abs(shang.coordinates(true.q) - u_ref).max()
    assert np.abs(shang.constraint_residual(true.q)).max() < 1e-8  # drift removed every period
    assert err_true < 5e-5  # m
    # the recorded forces are those of the model: their u-space projection equals the model's
    state = shang.kinematic_state(true.q, true.dq, true.ddq)
    reg = actuator_regressor(shang, state, distribution="projected")
    np.testing.assert_allclose(reg.outputs(true.tau_a), reg.W @ pi, atol=1e-8 * np.abs(true.tau_a).max())
    # a model 40 % off tracks worse
    wrong = pi * np.random.default_rng(0).uniform(0.6, 1.4, pi.size)
    off = simulate_mechanism_control(sim, AugmentedPD(shang, wrong, *gains, "min_norm_local_friction"), path.sample,
                                     duration=path.duration, dt=0.002)
    assert np.abs(shang.coordinates(off.q) - u_ref).max() > 1.5 * err_true
    # paper 001's metric (Eq. 23): the true model's P-RSME is the smaller
    p_true = tracking_errors(u_ref, shang.coordinates(true.q))["p_rsme"]
    p_off = tracking_errors(u_ref, shang.coordinates(off.q))["p_rsme"]
    assert p_true < p_off


def test_hexapod_computed_torque_with_stribeck_friction():
    mech = build_mechanism("hexapod")
    pi = mech.nominal_parameters()
    act = np.array(mech.actuated)

    def friction(dq):  # true friction of the six drives: Stribeck (paper 000, Eq. 32), no cardan friction
        f = np.zeros(mech.nv)
        f[act] = Stribeck(fc=20.0, fs=30.0, fv=50.0, vs=0.01).force(dq[act])[0]
        return f

    rng = np.random.default_rng(1)
    u0 = mech.coordinates(mech.q_ref)[0]
    ref = FourierTrajectory.random(6, 3, 1.0, rng, u0 - 0.02, u0 + 0.02, max_velocity=0.1, max_acceleration=2.0)
    ctrl = AugmentedPD(mech, pi, np.full(6, 2500.0), np.full(6, 100.0))
    errors = {}
    for name, fr in (("model friction", None), ("Stribeck drives", friction)):
        m = simulate_mechanism_control(ConstrainedSimulator(mech, pi, friction=fr), ctrl, ref.sample,
                                       duration=0.2, dt=1e-3, substeps=2)
        assert np.abs(mech.constraint_residual(m.q)).max() < 1e-8
        errors[name] = np.abs(mech.coordinates(m.q) - ref.sample(m.t)[0]).max()
    # the controller's model has the linear joint-term friction: it tracks its own plant to
    # within the Coulomb reversal effects and the Stribeck plant clearly worse
    assert errors["model friction"] < 1e-3 and errors["Stribeck drives"] > 2 * errors["model friction"]
    # the pose follows from the slider positions: closed-form IK of the simulated platform pose agrees
    pose = m.q[:, [mech.joint_names.index(n) for n in hexapod.PLATFORM_JOINTS]]
    np.testing.assert_allclose(hexapod.inverse_kinematics(pose), m.q, atol=1e-9)


def test_mechanism_simulation_is_deterministic(shang):
    pi = shang.nominal_parameters()
    path = CirclePath((0.29, 0.25), 0.03, 0.1, turns=0.25, ramp=0.1)

    def run():
        sim = ConstrainedSimulator(shang, pi)
        return simulate_mechanism_control(sim, AugmentedPD(shang, pi, np.full(2, 1e4), np.full(2, 200.0), "min_norm"),
                                          path.sample, duration=0.3, dt=0.002)

    a, b = run(), run()
    assert np.array_equal(a.q, b.q) and np.array_equal(a.tau_a, b.tau_a)


def test_free_closed_loop_motion_conserves_energy():
    """The MJCF five-bar (gravity in its plane) released from rest without friction or torque:
    kinetic + potential energy stays constant while it swings; the loop stays closed."""
    import pinocchio as pin

    mech = build_mechanism("fivebar")
    pi = mech.nominal_parameters()
    pi[mech.n_body_params:] = 0.0  # no friction, no rotor inertia
    sim = ConstrainedSimulator(mech, pi)
    q0 = mech.solve_positions(mech.coordinates(mech.q_ref) + 0.3)[0]

    def zero(dt, q, dq, ref):
        return np.zeros(mech.n_actuators)

    still = lambda t: (np.tile(mech.coordinates(q0)[0], (t.size, 1)), np.zeros((t.size, 2)), np.zeros((t.size, 2)))  # noqa: E731
    m = simulate_mechanism_control(sim, zero, still, duration=1.0, dt=1e-3, substeps=4, q0=q0)
    model = mech.with_parameters(pi)
    data = model.createData()
    E = np.array([pin.computeKineticEnergy(model, data, q, v) + pin.computePotentialEnergy(model, data, q)
                  for q, v in zip(m.q, m.dq)])
    swing = np.ptp(mech.coordinates(m.q), axis=0).max()
    assert swing > 0.3  # it really moved (rad)
    assert np.abs(mech.constraint_residual(m.q)).max() < 1e-8
    assert np.abs(E - E[0]).max() < 1e-6 * np.abs(E).max()


def test_reused_working_memory_leaves_no_trace():
    """The controller and the projection reuse one pinocchio Data from call to call (bench/README,
    control-loop identification time): every quantity read from it is recomputed first, so a call
    gives bit for bit what a fresh Data gives, whatever was computed before (task-space hexapod:
    point coordinates; shang2dof: joint coordinates, redundant actuation)."""
    rng = np.random.default_rng(7)
    for mech, dist in ((build_mechanism("hexapod").in_task_space(), None), (build_mechanism("shang2dof"), "min_norm_local_friction")):
        pi = mech.nominal_parameters()
        u0 = mech.coordinates(mech.q_ref)[0]
        qs = mech.solve_positions(u0 + 1e-3 * rng.standard_normal((3, u0.size)))
        vs = mech.states(qs, 0.05 * rng.standard_normal((3, u0.size)), np.zeros((3, u0.size))).dq
        ref = tuple(u0 + 1e-3 * rng.standard_normal(u0.size) for _ in range(3))
        gains = np.full(u0.size, 2500.0), np.full(u0.size, 100.0)
        ctrl = AugmentedPD(mech, pi, *gains, dist)
        used = [ctrl(1e-3, q, v, ref) for q, v in zip(qs, vs)]  # one controller, three states in a row
        for q, v, tau in zip(qs, vs, used):
            assert np.array_equal(tau, AugmentedPD(mech, pi, *gains, dist)(1e-3, q, v, ref))  # a fresh one
        data = mech.pin_model.createData()
        for q, v in zip(qs[::-1], vs[::-1]):
            q1 = q + 1e-7 * rng.standard_normal(q.size)  # off the closures: the projection iterates
            fresh = mech.project(q1, v)
            reused = mech.project(q1, v, data=data)
            assert all(np.array_equal(a, b) for a, b in zip(fresh, reused))


def test_a_diverged_configuration_is_a_model_error_not_a_lapack_message(capfd):
    """A NaN configuration (a diverged integration) stops the projection with a ModelError that the
    control-loop identification turns into a halved step; LAPACK never sees the NaN (it would print
    'On entry to DLASCL ...' to the terminal)."""
    from dynid.errors import ModelError

    mech = build_mechanism("shang2dof")
    q = mech.solve_positions(np.array([[0.29, 0.25]]))[0]
    bad = q.copy()
    bad[0] = np.nan
    with pytest.raises(ModelError, match="not finite"):
        mech.project(bad)
    with pytest.raises(ModelError, match="not finite"):
        mech.project(q, np.full_like(q, np.nan))
    assert "DLASCL" not in capfd.readouterr().out
    np.testing.assert_allclose(mech.project(q), q, atol=1e-12)  # an assembled configuration stays


@pytest.mark.parametrize("name", ["hexapod", "shang2dof"])
def test_control_loop_equals_the_reference_formulas(name):
    """The closed-loop simulation that IV and DIDIM replay at every iteration (bench/README,
    control-loop identification time) runs its control periods on faster routes: the controller's
    one-sample kinematics and forces, the closures' rows for all sides at once, QR instead of the
    SVD in the projection, the held forces' joint terms once per period, the logged acceleration
    reused as the first RK4 stage. The motion, accelerations and forces equal those of the
    reference formulas (tests/_loop_reference.py) to 1e-9 of their scale over 0.1 s (the routes
    differ by rounding, 1e-13 here; the tracking loop does not amplify it). Task-space hexapod
    (joint coordinates, computed torque) and shang2dof (point coordinates, redundant actuation,
    augmented PD with the minimum-norm distribution)."""
    from _loop_reference import control_loop

    mech = build_mechanism(name)
    if name == "hexapod":
        mech, dist, gains, dt = mech.in_task_space(), None, (2500.0, 100.0), 2e-3
    else:
        dist, gains, dt = "min_norm_local_friction", (35000.0, 300.0), 2e-3
    pi = mech.nominal_parameters()
    plant = pi * np.random.default_rng(4).uniform(0.9, 1.1, pi.size)  # a plant off the controller's model
    u0 = mech.coordinates(mech.q_ref)[0]
    amp = 0.01 if name == "hexapod" else 0.005
    ref = FourierTrajectory.random(u0.size, 2, 2.0, np.random.default_rng(2), u0 - amp, u0 + amp,
                                   max_velocity=0.1, max_acceleration=2.0)
    kp, kv = np.full(u0.size, gains[0]), np.full(u0.size, gains[1])
    sim = ConstrainedSimulator(mech, plant)
    fast = simulate_mechanism_control(sim, AugmentedPD(mech, pi, kp, kv, dist), ref.sample, duration=0.1, dt=dt, substeps=2)
    slow = control_loop(ConstrainedSimulator(mech, plant), mech, pi, kp, kv, dist, ref.sample, 0.1, dt, 2)
    for what, a, b in zip(("q", "dq", "ddq", "tau_a"), (fast.q, fast.dq, fast.ddq, fast.tau_a), slow):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(b).max(), err_msg=what)
    assert np.abs(fast.q - fast.q[0]).max() > 1e-3  # it moved
