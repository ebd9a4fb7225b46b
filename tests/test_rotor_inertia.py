"""Rotor inertia of a serial robot, one route: `[robot] rotor_inertia` (URDF has no element for
it) and an MJCF description's `armature` both become the nominal Ia, which reaches pinocchio's
model.armature through the parameters only, so that RNEA, the simulated plant and the regressor
agree."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from conftest import REPO
from dynid.errors import ConfigError, DynidError
from dynid.model import inverse_dynamics, regressor
from dynid.model.loading import load_model

ARM = REPO / "examples" / "serial_arm" / "arm3.urdf"
IA = [0.05, 0.04, 0.02]


def _states(rng, n: int, k: int = 5):
    return [(rng.uniform(-1, 1, n), rng.normal(size=n), rng.normal(size=n)) for _ in range(k)]


def test_rotor_inertia_adds_armature_times_acceleration_to_rnea():
    plain, rotor = load_model(str(ARM)), load_model(str(ARM), rotor_inertia=IA)
    assert np.all(plain.pin_model.armature == 0) and np.all(rotor.pin_model.armature == 0)  # only through the parameters
    p_plain, p_rotor = plain.nominal_parameters(), rotor.nominal_parameters()
    np.testing.assert_array_equal(p_rotor[rotor.layout.extra_index["Ia"]], IA)
    m0, m1 = plain.with_parameters(p_plain), rotor.with_parameters(p_rotor)
    np.testing.assert_array_equal(m1.armature, IA)
    d0, d1 = m0.createData(), m1.createData()
    for q, v, a in _states(np.random.default_rng(0), 3):
        tau0, tau1 = pin.rnea(m0, d0, q, v, a), pin.rnea(m1, d1, q, v, a)
        # the same rigid bodies; the armature adds Ia * ddq joint by joint (rounding of a few-N*m sum)
        np.testing.assert_allclose(tau1, tau0 + np.asarray(IA) * a, rtol=0, atol=1e-12 * max(1.0, np.abs(tau0).max()))


def test_the_identification_model_knows_it():
    """regressor . nominal parameters == inverse dynamics with the rotor inertia (the identify and
    design pipelines load the robot the same way), and the Ia column is ddq."""
    robot = load_model(str(ARM), rotor_inertia=IA)
    rng = np.random.default_rng(1)
    q, dq, ddq = (np.array(x) for x in zip(*_states(rng, 3, 8)))
    Y = regressor(robot, q, dq, ddq)
    theta = robot.nominal_parameters()
    tau = inverse_dynamics(robot, theta, q, dq, ddq)
    np.testing.assert_allclose(np.einsum("njp,p->nj", Y, theta), tau, rtol=0, atol=1e-10 * np.abs(tau).max())
    # the physics, by an independent route: RNEA of the description plus Ia * ddq plus its friction
    m = robot.pin_model
    d = m.createData()
    lay = robot.layout
    for i in range(q.shape[0]):
        rb = pin.rnea(m, d, q[i], dq[i], ddq[i])
        fr = theta[lay.extra_index["fv"]] * dq[i] + theta[lay.extra_index["fc"]] * np.sign(dq[i])
        np.testing.assert_allclose(tau[i], rb + np.asarray(IA) * ddq[i] + fr, rtol=0, atol=1e-10 * np.abs(tau).max())


def test_mjcf_armature_takes_the_same_route(tmp_path):
    """A serial MJCF's armature becomes the nominal Ia (it used to stay in the pinocchio model, outside
    the parameters: the nominal Ia was 0 and rnea and the regressor disagreed)."""
    (tmp_path / "arm.xml").write_text("""<mujoco model="two">
 <worldbody><body name="l1"><joint name="j1" type="hinge" axis="0 0 1" range="-2 2" armature="0.05"/>
  <inertial pos="0.1 0 0" mass="1" diaginertia="0.01 0.012 0.013"/>
  <body name="l2" pos="0.2 0 0"><joint name="j2" type="hinge" axis="0 1 0" range="-2 2" armature="0.02"/>
   <inertial pos="0.1 0 0" mass="0.8" diaginertia="0.004 0.01 0.011"/></body></body></worldbody></mujoco>""")
    robot = load_model(str(tmp_path / "arm.xml"))
    theta = robot.nominal_parameters()
    np.testing.assert_array_equal(theta[robot.layout.extra_index["Ia"]], [0.05, 0.02])
    reference = pin.buildModelFromMJCF(str(tmp_path / "arm.xml"))  # pinocchio's own reading, armature inside
    assert np.all(reference.armature == [0.05, 0.02])
    for q, v, a in _states(np.random.default_rng(2), 2):
        tau = inverse_dynamics(robot, theta, q[None], v[None], a[None])[0]
        fr = theta[robot.layout.extra_index["fv"]] * v + theta[robot.layout.extra_index["fc"]] * np.sign(v)
        np.testing.assert_allclose(tau - fr, pin.rnea(reference, reference.createData(), q, v, a), rtol=0, atol=1e-12)
    # the config's value replaces the description's
    again = load_model(str(tmp_path / "arm.xml"), rotor_inertia=[0.1, 0.0])
    np.testing.assert_array_equal(again.nominal_parameters()[again.layout.extra_index["Ia"]], [0.1, 0.0])


@pytest.mark.parametrize("kwargs, message", [
    ({"rotor_inertia": [0.1, 0.1]}, "rotor_inertia has 2 entries; 'arm3' has 3 joints"),
    ({"rotor_inertia": [0.1, -0.1, 0.1]}, "must be finite and >= 0"),
    ({"rotor_inertia": [0.1, 0.1, 0.1], "extras": ("fv", "fc")}, "needs the joint extra 'Ia'"),
])
def test_bad_rotor_inertia_is_refused(kwargs, message):
    with pytest.raises(DynidError, match=message):
        load_model(str(ARM), **kwargs)


def test_mechanisms_keep_their_own_route():
    with pytest.raises(DynidError, match="closed-loop mechanism, whose rotor inertias are its Ia_<joint> terms"):
        load_model("builtin:shang2dof", rotor_inertia=[0.1, 0.1, 0.1])


def test_every_config_reads_it(tmp_path: Path):
    """[robot] rotor_inertia in the identify, simulate and design configs; a negative one refused."""
    from dynid.config import _parse_robot
    from dynid.config.design import parse_design_config
    from dynid.config.simulate import parse_simulate_config

    robot = {"model": str(ARM), "rotor_inertia": IA}
    assert _parse_robot(robot, tmp_path).rotor_inertia == tuple(IA)
    assert parse_simulate_config({"robot": robot, "trajectory": {"kind": "fourier"}}, tmp_path).robot.rotor_inertia == tuple(IA)
    assert parse_design_config({"robot": robot}, tmp_path).rotor_inertia == tuple(IA)
    with pytest.raises(ConfigError, match="robot.rotor_inertia"):
        _parse_robot({"model": str(ARM), "rotor_inertia": [0.1, -1.0, 0.1]}, tmp_path)
