"""Friction with memory in the serial plant (dynid.model.friction.FrictionMemory; Hess & Soom's
frictional memory read as a first-order lag behind a steady-state curve, the plant of paper 003's
twin): the friction state the plant integrates is the lag of the steady-state curve along the
motion, it equals the curve at constant velocity, the augmented RK4 converges, and the config
refuses what it cannot simulate."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError, ModelError
from dynid.model import load_robot
from dynid.model.friction import FrictionMemory, SmoothStribeck
from dynid.simulation.control import JointPID, SerialPlant, simulate_control
from dynid.trajectories import FourierTrajectory

STEADY = SmoothStribeck(fc=[3.0, 2.5, 2.0, 1.0, 0.8, 0.6], fs=[4.0, 3.3, 2.6, 1.3, 1.0, 0.8],
                        fv=[4.0, 5.0, 3.0, 1.5, 1.2, 1.0], vs=0.08, kv=200.0, alpha=[0.7, 0.6, 0.8, 0.9, 0.7, 0.8])
T_M = 0.01


@pytest.fixture(scope="module")
def motion():
    robot = load_robot("builtin:cobot6r")
    pi = robot.nominal_parameters()
    plant = SerialPlant(robot, pi, friction=FrictionMemory(STEADY, T_M))
    lo, hi = robot.position_limits()
    ref = FourierTrajectory.random(6, 3, 0.5, np.random.default_rng(4), lo, hi, max_velocity=1.0,
                                   max_acceleration=3.0, fill=0.3)
    pid = lambda: JointPID(kp=np.array([1500, 1800, 800, 180, 200, 110.0]),  # noqa: E731
                           kd=np.array([50, 60, 27, 6, 7, 3.6]))
    run = lambda sub: simulate_control(plant, pid(), ref.sample, duration=1.0, dt=1e-3, substeps=sub)  # noqa: E731
    return plant, run(2), run(16)


def _friction_state(plant, m):
    """z at the control instants from the logged motion: tau - (M(q) ddq + h(q, dq)) (the ABA the
    plant ran with z, inverted)."""
    rigid = plant.torque(m.q, m.dq, m.ddq) - plant.friction.force(m.dq)
    return m.tau - rigid


def test_the_friction_state_is_the_lag_of_the_steady_curve(motion):
    plant, m, _ = motion
    z = _friction_state(plant, m)
    fss = STEADY.force(m.dq)
    # the lag ODE integrated on the sampled velocity (exact for F_ss linear over each 1 ms step)
    zr = np.empty_like(fss)
    zr[0] = fss[0]
    h, e = 1e-3, np.exp(-1e-3 / T_M)
    for k in range(1, len(m.t)):
        s = (fss[k] - fss[k - 1]) / h
        zr[k] = fss[k] - T_M * s + (zr[k - 1] - fss[k - 1] + T_M * s) * e
    lag = np.abs(fss - z).max(axis=0)
    assert np.all(lag > 0.02)  # the memory is felt: the friction is not the static curve along this motion
    # the 1 ms sampling of F_ss(v) is the only approximation: a few % of the lag itself
    assert np.all(np.abs(z - zr).max(axis=0) < 0.05 * lag + 1e-3), (np.abs(z - zr).max(axis=0), lag)


def test_augmented_rk4_converges(motion):
    _, coarse, fine = motion
    # RK4 with 0.5 ms against 62.5 us steps: fourth order, errors far below the 17-bit encoder
    assert np.abs(coarse.q - fine.q).max() < 1e-6
    assert np.abs(coarse.dq - fine.dq).max() < 1e-4


def test_constant_velocity_gives_the_steady_state():
    robot = load_robot("builtin:cobot6r")
    plant = SerialPlant(robot, robot.nominal_parameters(), friction=FrictionMemory(STEADY, T_M))
    v = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.3])  # the last joint at 0.3 rad/s, the others still

    def ref(t):
        q = np.zeros((t.size, 6))
        q[:, 5] = 0.3 * t
        return q, np.tile(v, (t.size, 1)), np.zeros((t.size, 6))

    m = simulate_control(plant, JointPID(kp=np.full(6, 800.0), kd=np.full(6, 30.0), ki=np.full(6, 4000.0)), ref,
                         duration=0.6, dt=1e-3, substeps=4, dq0=np.array([0, 0, 0, 0, 0, 0.2]))
    z = _friction_state(plant, m)
    # after 0.6 s = 60 time constants of settling, the state sits on Eq. 15 at the joint's speed
    np.testing.assert_allclose(z[-1, 5], STEADY.force(m.dq[-1])[0, 5], rtol=1e-4)


def test_memory_config_is_checked(tmp_path):
    base = {"robot": {"model": "builtin:cobot6r", "friction": {"model": "smooth_stribeck", "fc": 1.0, "fs": 1.2,
                                                               "fv": 1.0, "vs": 0.1, "kv": 100.0, "memory": 0.01}},
            "trajectory": {"kind": "fourier"}}
    assert parse_simulate_config(base, tmp_path).robot.friction["memory"] == 0.01
    base["robot"]["friction"]["memory"] = 0.0
    with pytest.raises(ConfigError, match="memory"):
        parse_simulate_config(base, tmp_path)
    with pytest.raises(ModelError, match="positive"):
        FrictionMemory(STEADY, [0.01, 0.0, 0.01, 0.01, 0.01, 0.01])
    # the constrained simulator has no friction state: a mechanism with memory is refused, not run without it
    from dynid.pipeline.simulate import run_simulation

    mech = {"robot": {"model": "builtin:shang2dof",
                      "friction": {"model": "coulomb_viscous", "fc": 0.3, "fv": 2.0, "memory": 0.01}},
            "trajectory": {"kind": "fourier"}}
    with pytest.raises(ConfigError, match="serial robots only"):
        run_simulation(parse_simulate_config(mech, tmp_path))
