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


def test_hexapod_base_count_reduces_to_the_papers_10(hexa):
    """The 88 rigid-body base parameters become 23 with identical struts and exactly the 10 of
    paper 002's Table 1 when the bodies are also symmetric (only Table 1's 15 standard
    parameters), as the module docstring explains."""
    from dynid.model.closed_loop import actuator_regressor, random_consistent_states

    state = random_consistent_states(hexa, 60, np.random.default_rng(11))
    W = actuator_regressor(hexa, state).W[:, :, : hexa.n_body_params].reshape(-1, hexa.n_body_params)
    # bodies in order: 6 x (ring, stator, slider), then the platform
    assert len(hexa.bodies) == 19

    def tied(selection: dict[str, list[str]]) -> np.ndarray:
        """Map shared parameters (per body type) to the 190 standard body parameters."""
        names = ["m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz"]
        cols = []
        for kind, params in selection.items():
            bodies = [18] if kind == "platform" else [3 * j + ("ring", "stator", "slider").index(kind) for j in range(6)]
            for p in params:
                c = np.zeros(hexa.n_body_params)
                for b in bodies:
                    c[10 * b + names.index(p)] = 1.0
                cols.append(c)
        return np.array(cols).T

    def rank(M: np.ndarray) -> int:
        s = np.linalg.svd(M / np.linalg.norm(M, axis=0).clip(1e-300), compute_uv=False)
        return int(np.sum(s > 1e-9 * s[0]))

    every = ["m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz"]
    identical = tied({"ring": every, "stator": every, "slider": every, "platform": every})
    assert rank(W @ identical) == 23
    table1 = tied({
        "ring": ["Ixx"],
        "stator": ["Ixx", "Iyy", "Izz", "mz"],
        "slider": ["m", "Ixx", "Iyy", "Izz", "mz"],
        "platform": ["m", "mz", "Ixx", "Iyy", "Izz"],
    })
    assert table1.shape[1] == 15
    assert rank(W @ table1) == 10


def test_cobot6r_after_paper003():
    """builtin:cobot6r: the reading of paper 003's Table 2 gives the 580 mm reach, Table 3's
    friction is its nominal friction, and the inertial values are physically consistent."""
    import pinocchio as pin

    from dynid.model import load_robot
    from dynid.model.base_parameters import pseudo_inertia

    robot = load_robot("builtin:cobot6r")
    model, data = robot.pin_model, robot.pin_model.createData()
    tool = model.getFrameId("tool")
    rng = np.random.default_rng(0)
    reach = 0.0
    for q in rng.uniform(*robot.position_limits(), size=(2000, 6)):
        pin.framesForwardKinematics(model, data, q)
        shoulder = data.oMi[2].translation
        reach = max(reach, np.linalg.norm(data.oMf[tool].translation - shoulder))
    assert 0.55 < reach <= 0.210 + 0.210 + 0.159 + 0.006 + 1e-9
    pi = robot.nominal_parameters()
    lay = robot.layout
    np.testing.assert_allclose(pi[lay.extra_index["fc"]], [6.321, 4.831, 7.781, 1.033, 1.601, 1.109])
    np.testing.assert_allclose(pi[lay.extra_index["fv"]], [7.167, 8.341, 8.516, 2.536, 3.175, 2.327])
    for j in range(6):
        assert np.linalg.eigvalsh(pseudo_inertia(pi[10 * j : 10 * j + 10])).min() > 0
