"""Export of identified standard parameters: URDF (serial robots) and MJCF (closed loops).

Every check re-reads the written file by an independent route (pinocchio's own parsers,
dynid's loaders) and compares dynamics or kinematics, not the writer's own numbers.
"""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from dynid.errors import InputError, ModelError
from dynid.io.export import inertia_about_com, write_mjcf, write_urdf
from dynid.model.closures import PointCoordinates
from dynid.model.loading import load_robot
from dynid.model.mechanism_io import load_mechanism, load_mechanism_mjcf
from dynid.model.robot import RobotModel

MECHANISMS = ["fivebar", "shang2dof", "rps3", "hexapod"]
SYMMETRIC = {"viscous": "damping", "coulomb": "friction", "inertia": "armature"}


# ---------------------------------------------------------------------------- helpers
def _rotation(rng: np.random.Generator) -> np.ndarray:
    w, x, y, z = rng.normal(size=4)
    return pin.Quaternion(w, x, y, z).normalized().toRotationMatrix()


def _random_body(rng: np.random.Generator, block: np.ndarray) -> np.ndarray:
    """A physically consistent body near ``block``: a solid box of random size, turned."""
    nominal = pin.Inertia.FromDynamicParameters(block) if block[0] > 0 else None
    m = (nominal.mass if nominal is not None else 1.0) * rng.uniform(0.8, 1.2)
    c = (nominal.lever if nominal is not None else np.zeros(3)) + rng.normal(scale=0.02, size=3)
    a, b, d = rng.uniform(0.05, 0.3, size=3)
    box = m / 12.0 * np.diag([b * b + d * d, a * a + d * d, a * a + b * b])
    R = _rotation(rng)
    return pin.Inertia(m, c, R @ box @ R.T).toDynamicParameters()


def _robot_params(robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    p = robot.nominal_parameters()
    for j in range(robot.layout.n_bodies):
        p[10 * j : 10 * j + 10] = _random_body(rng, p[10 * j : 10 * j + 10])
    n = robot.layout.n_body_params
    p[n:] = np.abs(p[n:]) * rng.uniform(0.8, 1.2, size=p.size - n) + rng.uniform(0.01, 0.1, size=p.size - n)
    return p


def _mech_params(mech, rng: np.random.Generator) -> np.ndarray:
    p = mech.nominal_parameters()
    for k in range(len(mech.bodies)):
        p[10 * k : 10 * k + 10] = _random_body(rng, p[10 * k : 10 * k + 10])
    for k, t in enumerate(mech.terms):
        i = mech.n_body_params + k
        value = abs(p[i]) * rng.uniform(0.8, 1.2) + rng.uniform(0.01, 0.1)
        p[i] = -value if t.kind == "coulomb-" else value
    return p


def _states(rng: np.random.Generator, nv: int, n: int = 5):
    return [rng.normal(size=(3, nv)) for _ in range(n)]


def _expected_joint_values(mech, params) -> dict[str, np.ndarray]:
    """damping / friction / armature per joint from the symmetric terms (summed)."""
    out = {k: np.zeros(mech.nv) for k in SYMMETRIC.values()}
    for k, t in enumerate(mech.terms):
        if t.kind in SYMMETRIC:
            for v in t.joints:
                out[SYMMETRIC[t.kind]][v] += params[mech.n_body_params + k]
    return out


def _residual(model: pin.Model, constraints, q: np.ndarray) -> float:
    """Largest gap of pinocchio's constraint models at ``q`` (point gap, or frame log)."""
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    worst = 0.0
    for cm in constraints:
        Ma = data.oMi[cm.joint1_id] * cm.joint1_placement
        Mb = data.oMi[cm.joint2_id] * cm.joint2_placement
        if cm.type == pin.ContactType.CONTACT_3D:
            gap = Mb.translation - Ma.translation
        else:
            gap = pin.log6(Ma.actInv(Mb)).vector
        worst = max(worst, float(np.abs(gap).max()))
    return worst


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert msg and "\n" not in msg
    return msg


# ---------------------------------------------------------------------------- inertia conversion
def test_inertia_about_com_is_the_inverse_of_pinocchio_parallel_axis():
    rng = np.random.default_rng(1)
    block = _random_body(rng, np.zeros(10))
    m, c, I_c = inertia_about_com(block)
    np.testing.assert_allclose(pin.Inertia(m, c, I_c).toDynamicParameters(), block, rtol=1e-13, atol=1e-15)
    rotor = np.array([0.0, 0, 0, 0, 0.1, 0.01, 0.2, 0.0, 0.0, 0.3])
    m, c, I_c = inertia_about_com(rotor)
    assert m == 0.0 and not np.any(c)
    np.testing.assert_array_equal(I_c, [[0.1, 0.01, 0.0], [0.01, 0.2, 0.0], [0.0, 0.0, 0.3]])
    with pytest.raises(ModelError, match="first moments"):
        inertia_about_com(np.r_[0.0, 0.1, np.zeros(8)])


# ---------------------------------------------------------------------------- URDF
@pytest.mark.parametrize("builtin", ["cobot6r", "puma560"])
def test_urdf_reproduces_inverse_dynamics_and_friction(tmp_path, builtin):
    rng = np.random.default_rng(7)
    robot = load_robot(f"builtin:{builtin}")
    params = _robot_params(robot, rng)
    path = write_urdf(robot, params, tmp_path / f"{builtin}.urdf", name="identified")
    assert path.is_file()

    loaded = pin.buildModelFromUrdf(str(path))  # pinocchio's own parser
    assert loaded.name == "identified"
    assert list(loaded.names) == list(robot.pin_model.names)
    truth = robot.with_parameters(params)  # armature = Ia: pinocchio's rnea adds Ia * ddq
    lay = robot.layout
    Ia = params[lay.extra_index["Ia"]]
    for q, v, a in _states(rng, robot.dof):
        tau_file = pin.rnea(loaded, loaded.createData(), q, v, a) + Ia * a
        tau_true = pin.rnea(truth, truth.createData(), q, v, a)
        np.testing.assert_allclose(tau_file, tau_true, rtol=1e-9, atol=1e-9 * np.abs(tau_true).max())
    np.testing.assert_array_equal(loaded.damping, params[lay.extra_index["fv"]])
    np.testing.assert_array_equal(loaded.friction, params[lay.extra_index["fc"]])
    for attr in ("lowerPositionLimit", "upperPositionLimit", "effortLimit", "velocityLimit"):
        np.testing.assert_array_equal(getattr(loaded, attr), getattr(robot.pin_model, attr))
    # the DH link frames and the tool frame survive as fixed links
    q = rng.normal(size=robot.dof)
    d0, d1 = robot.pin_model.createData(), loaded.createData()
    pin.framesForwardKinematics(robot.pin_model, d0, q)
    pin.framesForwardKinematics(loaded, d1, q)
    for name in ("tool", "link_3"):
        a0 = d0.oMf[robot.pin_model.getFrameId(name)]
        a1 = d1.oMf[loaded.getFrameId(name, pin.FrameType.BODY)]
        assert np.allclose(a0.homogeneous, a1.homogeneous, atol=1e-12)
    # rotor inertia and offsets, which URDF cannot hold, are recorded exactly in comments
    found = re.findall(r"dynid: joint (\S+) Ia=(\S+) off=(\S+)", path.read_text())
    assert [f[0] for f in found] == list(robot.joint_names)
    np.testing.assert_array_equal([float(f[1]) for f in found], Ia)
    np.testing.assert_array_equal([float(f[2]) for f in found], params[lay.extra_index["offset"]])


def test_urdf_read_by_dynid_loader_gives_the_parameters(tmp_path):
    rng = np.random.default_rng(3)
    robot = load_robot("builtin:generic6r")
    params = _robot_params(robot, rng)
    params[robot.layout.extra_index["fc"][2]] = -0.25  # an estimate may be negative: still written
    path = write_urdf(robot, params, tmp_path / "g.urdf")
    again = load_robot(str(path))  # strips <dynamics> before parsing, keeps fv/fc as nominal
    nb = robot.layout.n_body_params
    np.testing.assert_allclose(again.nominal_parameters()[:nb], params[:nb], rtol=1e-12, atol=1e-14)
    lay = robot.layout
    for e in ("fv", "fc"):
        np.testing.assert_array_equal(again.nominal_parameters()[lay.extra_index[e]], params[lay.extra_index[e]])


def _tree_robot() -> RobotModel:
    """A tree with unaligned axes, prismatic and continuous joints, a massless rotor-like
    body, an all-zero body and a joint without limits."""
    rng = np.random.default_rng(11)
    m = pin.Model()
    inf = np.full(1, np.inf)

    def add(parent, jm, name, lo=-1.0, hi=1.0):
        placement = pin.SE3(_rotation(rng), rng.normal(scale=0.2, size=3))
        jid = m.addJoint(parent, jm, placement, name, np.full(1, 50.0), np.full(1, 3.0), np.full(jm.nq, lo), np.full(jm.nq, hi))
        m.appendBodyToJoint(jid, pin.Inertia.Random(), pin.SE3.Identity())
        return jid

    j1 = add(0, pin.JointModelRevoluteUnaligned(np.array([0.0, 0.6, 0.8])), "hip")
    j2 = add(j1, pin.JointModelPrismaticUnaligned(np.array([0.6, 0.0, 0.8])), "slide")
    add(j2, pin.JointModelRUBZ(), "wheel", -np.inf, np.inf)
    add(j1, pin.JointModelPY(), "lift")
    j5 = add(0, pin.JointModelRX(), "free_range")
    m.lowerPositionLimit[m.joints[j5].idx_q] = -inf[0]
    m.upperPositionLimit[m.joints[j5].idx_q] = inf[0]
    return RobotModel(m, name="tree", extras=("fv",))


def _to_model(src: pin.Model, dst: pin.Model, x: np.ndarray, conf: bool) -> np.ndarray:
    """A configuration (``conf``) or velocity-like vector of ``src`` in ``dst``'s joint order."""
    out = np.empty(dst.nq if conf else dst.nv)
    for j in range(1, src.njoints):
        js, jd = src.joints[j], dst.joints[dst.getJointId(src.names[j])]
        a, b, n = (js.idx_q, jd.idx_q, js.nq) if conf else (js.idx_v, jd.idx_v, js.nv)
        out[b : b + n] = x[a : a + n]
    return out


def test_urdf_tree_with_unaligned_prismatic_continuous_and_massless_bodies(tmp_path):
    robot = _tree_robot()
    rng = np.random.default_rng(5)
    params = _robot_params(robot, rng)
    params[10:20] = [0.0, 0, 0, 0, 0.02, 0.001, 0.03, 0.0, 0.002, 0.04]  # rotor-like: inertia, no mass
    params[30:40] = 0.0  # a body without any parameter
    path = write_urdf(robot, params, tmp_path / "tree.urdf")
    loaded = pin.buildModelFromUrdf(str(path))
    src = robot.pin_model
    # pinocchio's URDF parser orders a tree itself (siblings by name): compare by joint name
    assert sorted(loaded.names) == sorted(src.names) and list(loaded.names) != list(src.names)
    for j in range(1, src.njoints):
        jl = loaded.getJointId(src.names[j])
        assert loaded.names[loaded.parents[jl]] == src.names[src.parents[j]]
        assert loaded.joints[jl].shortname() == src.joints[j].shortname()
        np.testing.assert_allclose(loaded.inertias[jl].toDynamicParameters(), params[10 * (j - 1) : 10 * j],
                                   rtol=1e-12, atol=1e-15)
        assert np.allclose(loaded.jointPlacements[jl].homogeneous, src.jointPlacements[j].homogeneous, atol=1e-14)
    truth = robot.with_parameters(params)
    for _ in range(3):
        q = pin.randomConfiguration(truth, -np.ones(truth.nq), np.ones(truth.nq))
        v, a = rng.normal(size=(2, truth.nv))
        tau = pin.rnea(loaded, loaded.createData(), _to_model(src, loaded, q, True), _to_model(src, loaded, v, False),
                       _to_model(src, loaded, a, False))
        np.testing.assert_allclose(tau, _to_model(src, loaded, pin.rnea(truth, truth.createData(), q, v, a), False),
                                   rtol=1e-9, atol=1e-12)
    fv = params[robot.layout.extra_index["fv"]]
    np.testing.assert_array_equal(loaded.damping, _to_model(src, loaded, fv, False))
    np.testing.assert_array_equal(loaded.friction, np.zeros(robot.dof))  # no fc in the layout: no friction written
    big = np.finfo(float).max  # "no limit" as pinocchio itself writes it
    free = loaded.joints[loaded.getJointId("free_range")].idx_q
    assert loaded.lowerPositionLimit[free] == -big and loaded.upperPositionLimit[free] == big
    assert "dynid: joint" not in path.read_text()  # no Ia, no offset in this layout


def test_urdf_writes_and_flags_non_physical_parameters(tmp_path):
    robot = load_robot("builtin:generic6r")
    params = robot.nominal_parameters()
    params[20] = -params[20]  # body 3: negative mass and first moments
    params[21:24] = -params[21:24]
    text = write_urdf(robot, params, tmp_path / "neg.urdf").read_text()
    root = ET.fromstring(text.split("-->", 1)[1])
    link = root.find("./joint[@name='joint_3']/child").get("link")
    mass = root.find(f"./link[@name='{link}']/inertial/mass").get("value")
    assert float(mass) == params[20]
    assert f"body {link} is not physically consistent (negative mass" in text


def test_urdf_errors_are_one_line(tmp_path):
    robot = load_robot("builtin:cobot6r")
    p = robot.nominal_parameters()
    with pytest.raises(InputError) as exc:
        write_urdf(robot, p[:-1], tmp_path / "x.urdf")
    assert f"{p.size} standard parameters" in _one_line(exc)
    bad = p.copy()
    bad[3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        write_urdf(robot, bad, tmp_path / "x.urdf")
    with pytest.raises(InputError) as exc:
        write_urdf(robot, p, tmp_path / "missing" / "x.urdf")
    assert "does not exist" in _one_line(exc)
    bad = p.copy()
    bad[0], bad[1] = 0.0, 0.1  # zero mass with a first moment
    with pytest.raises(ModelError) as exc:
        write_urdf(robot, bad, tmp_path / "x.urdf")
    assert "joint_1" in _one_line(exc)
    mech = load_mechanism("builtin:fivebar")
    with pytest.raises(ModelError, match="write_mjcf"):
        write_urdf(mech, mech.nominal_parameters(), tmp_path / "x.urdf")
    assert not list(tmp_path.iterdir())  # nothing half-written


# ---------------------------------------------------------------------------- MJCF
@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Each built-in mechanism exported once with perturbed parameters."""
    folder = tmp_path_factory.mktemp("mjcf")
    out = {}
    for k, name in enumerate(MECHANISMS):
        mech = load_mechanism(f"builtin:{name}")
        params = _mech_params(mech, np.random.default_rng(100 + k))
        out[name] = (mech, params, write_mjcf(mech, params, folder / f"{name}.xml"))
    return out


def _second_assembly(mech) -> np.ndarray:
    """Another assembled configuration: the independent coordinates moved a little."""
    u = mech.coordinates(mech.q_ref[None]) + 0.01
    q = mech.solve_positions(u)[0]
    assert np.abs(mech.constraint_residual(q)).max() < 1e-10
    return q


@pytest.mark.parametrize("name", MECHANISMS)
def test_mjcf_read_by_pinocchio_gives_tree_inertias_terms_and_closures(exported, name):
    mech, params, path = exported[name]
    loaded, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    model = mech.pin_model
    assert list(loaded.names) == list(model.names)
    for j in range(1, model.njoints):
        assert loaded.joints[j].shortname() == model.joints[j].shortname()
        assert np.allclose(loaded.jointPlacements[j].homogeneous, model.jointPlacements[j].homogeneous, atol=1e-13)
    np.testing.assert_allclose(loaded.lowerPositionLimit, model.lowerPositionLimit, atol=1e-14)
    np.testing.assert_allclose(loaded.upperPositionLimit, model.upperPositionLimit, atol=1e-14)
    # tree dynamics with the exported inertias (joint terms excluded on both sides)
    expected = _expected_joint_values(mech, params)
    np.testing.assert_allclose(loaded.armature, expected["armature"], rtol=1e-15)
    np.testing.assert_allclose(loaded.damping, expected["damping"], rtol=1e-15)
    np.testing.assert_allclose(loaded.friction, expected["friction"], rtol=1e-15)
    loaded.armature = np.zeros(loaded.nv)
    truth = mech.with_parameters(params)
    rng = np.random.default_rng(0)
    for q, v, a in _states(rng, mech.nv, 3):
        tau = pin.rnea(truth, truth.createData(), q, v, a)
        np.testing.assert_allclose(pin.rnea(loaded, loaded.createData(), q, v, a), tau, rtol=1e-9,
                                   atol=1e-9 * np.abs(tau).max())
    # the closures are the same constraints: closed at q_ref and at another assembly
    assert len(constraints) == len(mech.closures)
    assert sorted(str(c.type)[-2:] for c in constraints) == sorted(c.kind.upper() for c in mech.closures)
    for q in (mech.q_ref, _second_assembly(mech)):
        assert _residual(loaded, constraints, q) < 1e-10
    motors = ET.parse(path).getroot().findall("./actuator/motor")
    assert [m.get("joint") for m in motors] == mech.actuated_names


@pytest.mark.parametrize(
    "name",
    [
        "fivebar",
        "hexapod",
        "shang2dof",
        "rps3",
    ],
)
def test_mjcf_read_back_by_dynid_is_an_equivalent_mechanism(exported, name):
    mech, params, path = exported[name]
    loaded = load_mechanism_mjcf(path)  # the chart comes back from <custom> (shang2dof: a point)
    assert loaded.joint_names == mech.joint_names
    assert loaded.actuated_names == mech.actuated_names
    a, b = loaded.independent, mech.independent
    if isinstance(b, PointCoordinates):
        assert isinstance(a, PointCoordinates) and a.joint == b.joint and a.axes == b.axes
        np.testing.assert_allclose(a.placement.translation, b.placement.translation, atol=1e-15)
        # the same coordinates by an independent route: the point's position at an assembly
        q = _second_assembly(mech)
        np.testing.assert_allclose(loaded.coordinates(q[None]), mech.coordinates(q[None]), atol=1e-12)
    else:
        assert a == b
    assert [(c.name, c.kind) for c in loaded.closures] == [(c.name, c.kind) for c in mech.closures]
    index = [mech.joint_names.index(n) for n in loaded.joint_names]
    assert np.abs(loaded.constraint_residual(mech.q_ref[index])).max() < 1e-10
    # body inertias, by joint name
    for k, j in enumerate(mech.bodies):
        jl = loaded.pin_model.getJointId(mech.pin_model.names[j])
        np.testing.assert_allclose(loaded.pin_model.inertias[jl].toDynamicParameters(), params[10 * k : 10 * k + 10],
                                   rtol=1e-12, atol=1e-14)
    # symmetric joint terms come back as the reader's per-joint nominal values
    expected = _expected_joint_values(mech, params)
    prefix = {"damping": "fv", "friction": "fc", "armature": "Ia"}
    for key, values in expected.items():
        for v, value in enumerate(values):
            got = loaded.nominal_terms.get(f"{prefix[key]}_{mech.joint_names[v]}", 0.0)
            assert got == pytest.approx(value, rel=1e-15), (key, mech.joint_names[v])


def test_mjcf_records_what_it_cannot_hold(exported):
    mech, params, path = exported["shang2dof"]
    text = path.read_text()
    for k, t in enumerate(mech.terms):
        if t.kind not in SYMMETRIC:
            assert f"term {t.name} ({t.kind}, joints" in text
            assert f"= {float(params[mech.n_body_params + k])!r}:" in text
    chart = ET.parse(path).getroot().findall("./custom/text")
    assert [(t.get("name"), t.get("data").split("axes=")[1]) for t in chart] == [("dynid:independent_point", "0 1")]
    hexa = exported["hexapod"][2].read_text()
    assert "term fc_alpha (coulomb)" in hexa and "shared by joints a1, a2, a3, a4, a5, a6" in hexa


@pytest.mark.parametrize("name", MECHANISMS)
def test_dynid_info_reads_every_exported_mechanism(exported, name, capsys):
    from dynid.cli import main

    mech, _, path = exported[name]
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["dof"] == mech.dof and info["n_actuators"] == len(mech.actuated)


def test_a_redundant_joint_chart_survives_the_round_trip(tmp_path):
    five = load_mechanism("builtin:fivebar")
    redundant = five.with_chart(actuated=["qa1", "qa2", "qb1"], independent=["qa2", "qb1"])
    path = write_mjcf(redundant, redundant.nominal_parameters(), tmp_path / "five3.xml")
    again = load_mechanism_mjcf(path)
    assert again.actuated_names == ["qa1", "qa2", "qb1"] and again.redundant
    assert [again.joint_names[j] for j in again.independent.joints] == ["qa2", "qb1"]


def test_mjcf_range_conventions(tmp_path):
    mech = load_mechanism("builtin:rps3")
    p = mech.nominal_parameters()
    path = write_mjcf(mech, p, tmp_path / "m.xml", range_convention="mujoco")
    joint = ET.parse(path).getroot().find(".//joint[@name='P1']")
    lo, hi = (float(x) for x in joint.get("range").split())
    assert (lo, hi) == (mech.pin_model.lowerPositionLimit[1], mech.pin_model.upperPositionLimit[1])
    assert float(joint.get("ref")) == mech.q_ref[1]
    loaded, _ = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    np.testing.assert_allclose(loaded.lowerPositionLimit, mech.pin_model.lowerPositionLimit - mech.q_ref, atol=1e-14)


def test_mjcf_errors_are_one_line(tmp_path):
    mech = load_mechanism("builtin:hexapod")
    p = mech.nominal_parameters()
    with pytest.raises(InputError) as exc:
        write_mjcf(mech, np.r_[p, 1.0], tmp_path / "x.xml")
    assert f"{p.size} standard parameters" in _one_line(exc)
    with pytest.raises(InputError, match="range_convention"):
        write_mjcf(mech, p, tmp_path / "x.xml", range_convention="urdf")
    neg = p.copy()
    neg[0] = -1.0
    with pytest.raises(ModelError) as exc:
        write_mjcf(mech, neg, tmp_path / "x.xml")
    assert "negative mass" in _one_line(exc)
    neg = p.copy()
    neg[mech.term_index("fc_P1")] = -0.5
    with pytest.raises(ModelError) as exc:
        write_mjcf(mech, neg, tmp_path / "x.xml")
    assert "['P1']" in _one_line(exc)
    robot = load_robot("builtin:cobot6r")
    with pytest.raises(ModelError, match="write_urdf"):
        write_mjcf(robot, robot.nominal_parameters(), tmp_path / "x.xml")
    assert not list(tmp_path.iterdir())


def test_mjcf_weld_closure_is_the_same_frame_constraint(tmp_path):
    """A "6d" closure (not in the built-ins): the five-bar welded at its distal point, with
    a rotated contact frame, becomes a 1-DOF mechanism driven by qa1."""
    import dataclasses

    from dynid.model.closures import JointCoordinates, LoopClosure

    five = load_mechanism("builtin:fivebar")
    c = five.closures[0]
    model, data = five.pin_model, five.pin_model.createData()
    pin.forwardKinematics(model, data, five.q_ref)
    Pa = c.placement_a * pin.SE3(_rotation(np.random.default_rng(2)), np.zeros(3))
    Pb = data.oMi[c.joint_b].actInv(data.oMi[c.joint_a] * Pa)
    weld = LoopClosure("W", c.joint_a, Pa, c.joint_b, Pb, "6d")
    mech = dataclasses.replace(five, closures=(weld,), actuated=(0,), independent=JointCoordinates((0,)),
                               q_guess=five.q_ref)
    path = write_mjcf(mech, mech.nominal_parameters(), tmp_path / "weld.xml")
    assert ET.parse(path).getroot().find("./equality/weld").get("relpose")
    loaded, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    assert [cm.type for cm in constraints] == [pin.ContactType.CONTACT_6D]
    for q in (mech.q_ref, _second_assembly(mech)):
        assert _residual(loaded, constraints, q) < 1e-10
    again = load_mechanism_mjcf(path, independent=["qa1"])  # q_ref = 0 here: the reader assembles it
    assert [(w.name, w.kind) for w in again.closures] == [("W", "6d")] and again.actuated_names == ["qa1"]
    assert np.abs(again.constraint_residual(_second_assembly(mech))).max() < 1e-10
    q_open = mech.q_ref + 0.05  # not assembled: the file's constraint sees the same gap
    gap = float(np.abs(mech.constraint_residual(q_open)).max())
    assert gap > 1e-3 and _residual(loaded, constraints, q_open) > 1e-3
