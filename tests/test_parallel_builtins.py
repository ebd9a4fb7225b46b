"""Built-in parallel robots ``rps3`` (3-RPS, paper 000) and ``hexapod`` (PaLiDA-like 6-UPS,
papers 002/004): closed-form inverse kinematics against the loop constraints and the numeric
forward kinematics, structure (mobility, actuators, bodies, joint terms) and unreachable poses."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.errors import ModelError
from dynid.model.robots import hexapod, rps3


@pytest.fixture(scope="module")
def rps() -> object:
    return rps3.build()


@pytest.fixture(scope="module")
def hexa() -> object:
    return hexapod.build()


def _rps_poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0.65, 0.95, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n)])


def _hex_poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.1, 0.1, (n, 2)), rng.uniform(0.75, 0.95, n), rng.uniform(-0.2, 0.2, (n, 3))])


def _angle_diff(a: np.ndarray, b: np.ndarray, angular: list[int]) -> np.ndarray:
    d = a - b
    d[:, angular] = np.mod(d[:, angular] + np.pi, 2 * np.pi) - np.pi
    return d


# ---------------------------------------------------------------- 3-RPS
def test_rps3_structure(rps):
    assert (rps.dof, rps.n_actuators, rps.nv) == (3, 3, 12)
    assert not rps.redundant
    assert len(rps.bodies) == 7  # 3 cylinders, 3 pistons, platform
    assert [t.kind for t in rps.terms[:3]] == ["inertia", "viscous", "coulomb"]
    assert len(rps.terms) == 9
    assert rps.actuated_names == ["P1", "P2", "P3"]
    m = rps.pin_model
    for j in rps.massless:
        assert np.all(m.inertias[j].toDynamicParameters() == 0.0)
    assert [m.names[j] for j in rps.massless] == ["PX", "PY", "PZ", "RZ", "RY"]
    assert len(rps3.build(("fv",)).terms) == 3
    with pytest.raises(ModelError, match="unknown joint extras"):
        rps3.build(("friction",))


def test_rps3_ik_closes_loops_and_matches_forward_kinematics(rps):
    q = rps3.inverse_kinematics(_rps_poses(25))
    assert np.abs(rps.constraint_residual(q)).max() < 1e-10
    lo, hi = rps.position_limits()
    assert np.all(q >= lo) and np.all(q <= hi)
    qs = rps.solve_positions(q[:, list(rps.actuated)])
    d = _angle_diff(qs, q, [0, 2, 4, 9, 10, 11])
    assert np.abs(d).max() < 1e-9


def test_rps3_parasitic_motion():
    # level platform: no parasitic motion; a tilt about both axes gives x, y and yaw
    chain = rps3.platform_pose(np.array([[0.8, 0.0, 0.0], [0.8, 0.2, 0.1]]))
    np.testing.assert_allclose(chain[0], [0, 0, 0.8, 0, 0, 0], atol=1e-15)
    assert np.all(np.abs(chain[1, [0, 1, 3]]) > 1e-4)
    th, ph = 0.2, 0.1
    assert chain[1, 3] == pytest.approx(np.arctan2(np.sin(th) * np.sin(ph), np.cos(th) + np.cos(ph)))


def test_rps3_unreachable(rps):
    with pytest.raises(ModelError, match=r"unreachable: leg \d length .* outside the stroke") as err:
        rps3.inverse_kinematics(np.array([[0.8, 0.0, 0.0], [1.3, 0.0, 0.0]]))
    assert "\n" not in str(err.value)
    with pytest.raises(ModelError, match="unreachable|singular") as err:
        rps.solve_positions(np.array([[0.6, 0.6, 2.5]]))
    assert "\n" not in str(err.value)


# ---------------------------------------------------------------- hexapod
def test_hexapod_structure(hexa):
    assert (hexa.dof, hexa.n_actuators, hexa.nv) == (6, 6, 24)
    assert len(hexa.bodies) == 19  # platform, 6 cardan rings, 6 stators, 6 sliders
    assert len(hexa.terms) == 14
    shared = {t.name: t.joints for t in hexa.terms if len(t.joints) > 1}
    assert shared == {"fc_alpha": (0, 3, 6, 9, 12, 15), "fc_beta": (1, 4, 7, 10, 13, 16)}
    assert hexa.actuated_names == [f"P{j}" for j in range(1, 7)]
    m = hexa.pin_model
    for j in hexa.massless:
        assert np.all(m.inertias[j].toDynamicParameters() == 0.0)
    assert np.allclose(m.gravity.linear, [0, 0, -9.81])


def test_hexapod_nominal_parameters_match_table1():
    mech = hexapod.build()
    np.testing.assert_allclose(hexapod.table1_parameters(mech.nominal_parameters()), hexapod.A_PRIORI, atol=1e-12)


def test_hexapod_ik_closes_loops_and_matches_forward_kinematics(hexa):
    q = hexapod.inverse_kinematics(_hex_poses(20))
    assert np.abs(hexa.constraint_residual(q)).max() < 1e-10
    lo, hi = hexa.position_limits()
    assert np.all(q >= lo) and np.all(q <= hi)
    qs = hexa.solve_positions(q[:, list(hexa.actuated)])
    angular = [i for i in range(24) if i not in hexa.actuated and i not in (18, 19, 20)]
    assert np.abs(_angle_diff(qs, q, angular)).max() < 1e-9


def test_hexapod_chain_from_transform():
    poses = _hex_poses(5, seed=3)
    R = hexapod._rotations(poses)
    np.testing.assert_allclose(hexapod.chain_from_transform(poses[:, :3], R), poses, atol=1e-12)


def test_hexapod_unreachable(hexa):
    with pytest.raises(ModelError, match=r"unreachable: strut \d length .* outside") as err:
        hexapod.inverse_kinematics(np.array([[0.0, 0.0, 1.6, 0.0, 0.0, 0.0]]))
    assert "\n" not in str(err.value)
    u = np.full((1, 6), 1.0)
    u[0, 0] = 3.0
    with pytest.raises(ModelError, match="unreachable|singular") as err:
        hexa.solve_positions(u)
    assert "\n" not in str(err.value)


# ---------------------------------------------------------------- base parameters
def test_base_parameter_counts(rps, hexa):
    from dynid.model.closed_loop import mechanism_base_parameters

    for mech, n_rigid, n_base in ((rps, 25, 34), (hexa, 88, 102)):
        bp = mechanism_base_parameters(mech)
        assert bp.n_base == n_base
        assert int(np.sum(bp.independent < mech.n_body_params)) == n_rigid
