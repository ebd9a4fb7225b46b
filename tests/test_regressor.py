"""Regressor x parameters == inverse dynamics by an independent route (pinocchio RNEA with the
rotor inertia as armature, friction and offsets added term by term in the test)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dynid.model import Coupling, Transmission, load_robot, regressor
from dynid.model.serial_dynamics import inverse_dynamics

ROBOTS = {name: load_robot(f"builtin:{name}") for name in ("puma560", "generic6r")}
TX40_LIKE = load_robot(
    "builtin:generic6r",
    transmission=Transmission.from_ratios([32, 32, 45, -48, 45, 32], [Coupling(6, (5, 6))]),
)


def _random_physical_params(robot, rng):
    """Random but physically meaningful standard parameters (m > 0, positive-definite inertia)."""
    lay = robot.layout
    pi = np.zeros(lay.n_params)
    for j in range(lay.n_bodies):
        m = rng.uniform(0.2, 10)
        c = rng.uniform(-0.2, 0.2, 3)
        a = rng.standard_normal((3, 3))
        ic = a @ a.T * 0.05 + 0.01 * np.eye(3)
        pi[10 * j : 10 * j + 10] = pin.Inertia(m, c, ic).toDynamicParameters()
    for idx in lay.extra_index.values():
        pi[idx] = rng.uniform(0.05, 5.0, idx.size)
    for idx in lay.motor_index.values():
        pi[idx] = rng.uniform(0.01, 2.0, idx.size)
    return pi


def _independent_torque(robot, pi, q, dq, ddq):
    """RNEA on a model rebuilt from pi (armature = Ia) + friction/offset/coupled terms, explicitly."""
    lay = robot.layout
    model = pin.Model(robot.pin_model)
    for j in range(1, model.njoints):
        model.inertias[j] = pin.Inertia.FromDynamicParameters(pi[10 * (j - 1) : 10 * j])
    model.armature = pi[lay.extra_index["Ia"]]
    data = model.createData()
    tau = pin.rnea(model, data, q, dq, ddq).copy()
    tau += pi[lay.extra_index["fv"]] * dq + pi[lay.extra_index["fc"]] * np.sign(dq) + pi[lay.extra_index["offset"]]
    if lay.coupled_motors:  # TX40 wrist: motor 6 turns with q5 + q6, acting on joints 5 and 6
        iam, fvm, fcm = (pi[lay.names.index(n)] for n in ("Iam6", "fvm6", "fcm6"))
        motor = iam * (ddq[4] + ddq[5]) + fvm * (dq[4] + dq[5]) + fcm * np.sign(dq[4] + dq[5])
        tau[4] += motor
        tau[5] += motor
    return tau


states = st.integers(min_value=0, max_value=2**32 - 1)


@pytest.mark.parametrize("robot", [*ROBOTS.values(), TX40_LIKE], ids=["puma560", "generic6r", "tx40-like-coupled"])
@settings(max_examples=40, deadline=None)
@given(seed=states)
def test_regressor_times_params_equals_inverse_dynamics(robot, seed):
    rng = np.random.default_rng(seed)
    lo, hi = robot.position_limits()
    q = rng.uniform(lo, hi)
    dq = rng.normal(0, 2, robot.dof)
    ddq = rng.normal(0, 5, robot.dof)
    pi = _random_physical_params(robot, rng)
    Y = regressor(robot, q, dq, ddq)[0]
    expected = _independent_torque(robot, pi, q, dq, ddq)
    np.testing.assert_allclose(Y @ pi, expected, rtol=0, atol=1e-10 * max(1.0, np.abs(expected).max()))
    # the library's own inverse dynamics (used by the simulator) agrees too
    np.testing.assert_allclose(inverse_dynamics(robot, pi, q, dq, ddq)[0], expected, atol=1e-10 * max(1.0, np.abs(expected).max()))


def test_regressor_shapes_and_names():
    robot = TX40_LIKE
    n = 7
    rng = np.random.default_rng(0)
    Y = regressor(robot, rng.normal(size=(n, 6)), rng.normal(size=(n, 6)), rng.normal(size=(n, 6)))
    assert Y.shape == (n, 6, robot.n_standard_params)
    assert robot.parameter_names[:10] == ("m1", "mx1", "my1", "mz1", "Ixx1", "Ixy1", "Iyy1", "Ixz1", "Iyz1", "Izz1")
    assert robot.parameter_names[60:64] == ("Ia1", "fv1", "fc1", "off1")
    assert robot.parameter_names[-3:] == ("Iam6", "fvm6", "fcm6")
    assert len(set(robot.parameter_names)) == robot.n_standard_params == 60 + 24 + 3


def test_regressor_rejects_wrong_shapes():
    from dynid.errors import InputError

    robot = ROBOTS["puma560"]
    with pytest.raises(InputError, match="shape"):
        regressor(robot, np.zeros((3, 5)), np.zeros((3, 5)), np.zeros((3, 5)))
    with pytest.raises(InputError, match="mismatched lengths"):
        regressor(robot, np.zeros((3, 6)), np.zeros((2, 6)), np.zeros((3, 6)))
