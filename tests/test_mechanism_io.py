"""Loading closed-loop mechanisms from MJCF (<equality> closures) and URDF + closure YAML."""

from __future__ import annotations

import dataclasses
import re
from importlib import resources
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from dynid.errors import DynidError, InputError, ModelError
from dynid.model.mechanism import JointTerm, Mechanism
from dynid.model.mechanism_files import _mjcf_closures, _mjcf_equalities, _parse_xml
from dynid.model.mechanism_io import load_mechanism, load_mechanism_mjcf, load_mechanism_urdf

FIVEBAR = Path(str(resources.files("dynid.model.robots") / "fivebar.xml"))
CONNECT = '<connect name="P" body1="dist1" body2="dist2" anchor="0.27 0 0.36"/>'


def _variant(tmp_path: Path, name: str, *replacements: tuple[str, str]) -> Path:
    """The shipped five-bar with text replacements, written to tmp_path."""
    text = FIVEBAR.read_text()
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


def _one_line(exc: DynidError) -> str:
    msg = str(exc)
    assert "\n" not in msg and msg
    return msg


# ---------------------------------------------------------------------------- the five-bar
def test_fivebar_loads():
    mech = load_mechanism_mjcf(FIVEBAR)
    assert (mech.nv, mech.dof, mech.n_actuators) == (4, 2, 2)
    assert mech.actuated_names == ["qa1", "qa2"] and not mech.redundant
    assert [(c.name, c.kind) for c in mech.closures] == [("P", "3d")]
    assert np.abs(mech.constraint_residual(mech.q_ref)).max() < 1e-12
    assert np.allclose(mech.q_ref, 0.0)  # MJCF: the closures hold in the file's configuration
    # nominal joint terms from damping, frictionloss and armature
    nom = dict(mech.nominal_terms)
    assert nom == pytest.approx(
        {"Ia_qa1": 0.002, "Ia_qa2": 0.002, "fv_qa1": 0.05, "fv_qa2": 0.05, "fc_qa1": 0.08, "fc_qa2": 0.08,
         "fv_qb1": 0.005, "fv_qb2": 0.005}
    )
    assert {t.name for t in mech.terms} == set(nom)  # passive joints: viscous only
    kinds = {t.name: t.kind for t in mech.terms}
    assert kinds["Ia_qa1"] == "inertia" and kinds["fv_qb2"] == "viscous" and kinds["fc_qa2"] == "coulomb"
    assert mech.n_standard_params == 4 * 10 + 8
    assert load_mechanism(str(FIVEBAR)).dof == 2


def test_fivebar_closure_point_is_the_anchor():
    """MuJoCo semantics, independently of pinocchio: the anchor (0.27, 0, 0.36) in dist1's frame
    is P = (0, 0, 0.52) in the world at q = 0, on both sides of the closure."""
    mech = load_mechanism_mjcf(FIVEBAR)
    data = mech.pin_model.createData()
    pin.forwardKinematics(mech.pin_model, data, np.zeros(mech.nv))
    (c,) = mech.closures
    for j, P in ((c.joint_a, c.placement_a), (c.joint_b, c.placement_b)):
        assert np.allclose((data.oMi[j] * P).translation, [0.0, 0.0, 0.52])


def test_fivebar_moves_and_solves():
    mech = load_mechanism_mjcf(FIVEBAR)
    u = mech.coordinates(mech.q_ref) + np.array([[0.2, -0.1], [-0.15, 0.25]])
    q = mech.solve_positions(u)
    assert np.abs(mech.constraint_residual(q)).max() < 1e-10
    assert np.allclose(q[:, [0, 2]], u)


def _pinocchio_vs_mechanism(path: Path, **kw):
    """Mechanism.constraint_residual against pinocchio's own constraint placements (cd.oMc1,
    cd.oMc2, cd.c1Mc2) at non-assembled configurations: an independent check of the conversion."""
    mech = load_mechanism_mjcf(path, **kw)
    model, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    data = model.createData()
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, model.nq)
        res = mech.constraint_residual(q)
        pin.forwardKinematics(model, data, q)
        k = 0
        for cm, c in zip(constraints, mech.closures):
            cd = cm.createData()
            cm.calc(model, data, cd)
            gap = cd.oMc2.translation - cd.oMc1.translation
            assert np.linalg.norm(gap) > 1e-3  # really not assembled
            assert np.allclose(res[k : k + 3], gap, atol=1e-12)
            assert np.allclose(cd.oMc1.rotation.T @ res[k : k + 3], cd.c1Mc2.translation, atol=1e-12)
            if c.kind == "6d":
                # same frames up to one rotation R0 applied to both sides (world-aligned at q_ref)
                R0 = cm.joint1_placement.rotation.T @ c.placement_a.rotation
                assert np.allclose(cm.joint2_placement.rotation @ R0, c.placement_b.rotation)
                assert np.allclose(R0 @ res[k + 3 : k + 6], pin.log3(cd.c1Mc2.rotation), atol=1e-12)
            k += c.rows
        assert k == res.size
    return mech


def test_connect_conversion_matches_pinocchio():
    _pinocchio_vs_mechanism(FIVEBAR)


def test_weld_conversion_matches_pinocchio(tmp_path):
    """A weld at P makes the two distal links one rigid body: a four-bar, 1 DOF, one actuator."""
    path = _variant(tmp_path, "weld.xml", (CONNECT, '<weld name="W" body1="dist1" body2="dist2"/>'))
    mech = _pinocchio_vs_mechanism(path, actuated=["qa1"])
    assert (mech.dof, mech.n_actuators, mech.closures[0].kind) == (1, 1, "6d")
    assert np.abs(mech.constraint_residual(mech.q_ref)).max() < 1e-12


def test_connect_to_world_and_names(tmp_path):
    """Two connects, one unnamed and one to the world: matched to their XML elements although
    pinocchio sorts them by name and leaves their names empty."""
    path = _variant(
        tmp_path, "two.xml",
        (CONNECT, '<connect body1="dist2" body2="dist1" anchor="-0.27 0 0.36"/>\n    '
                  '<connect name="A_world" body1="dist1" anchor="0.27 0 0.36"/>'),
    )
    with pytest.raises(ModelError, match="cannot move: the loop closures remove all 4 degrees of freedom"):
        load_mechanism_mjcf(path)  # P pinned to the world: the five-bar cannot move
    model, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    assert [c.name for c in constraints] == ["", ""]
    closures = _mjcf_closures(model, constraints, _mjcf_equalities(_parse_xml(path), path))
    assert [(c.name, c.joint_b) for c in closures] == [("A_world", 0), ("dist2-dist1", 2)]


def test_custom_terms():
    terms = [JointTerm("fv_qa1", "viscous", (0,)), JointTerm("fs_all", "coulomb", (0, 1, 2, 3))]
    mech = load_mechanism_mjcf(FIVEBAR, terms=terms)
    assert [t.name for t in mech.terms] == ["fv_qa1", "fs_all"]
    assert dict(mech.nominal_terms) == {"fv_qa1": 0.05}  # file values only for matching names
    assert mech.notes[-1].startswith("file values without a joint term are not used: ['fv_qb1', 'fv_qa2'")
    assert not np.any(mech.pin_model.armature)  # the armature lives in the Ia terms


def test_massless_body(tmp_path):
    zero = '<inertial pos="0 0 0" mass="0" diaginertia="0 0 0"/>'
    dist2 = '<inertial pos="-0.135 0 0.18" mass="0.35" fullinertia="0.00380678 0.00592594 0.00215854 0 0.00282555 0"/>'
    path = _variant(tmp_path, "m.xml", (dist2, zero))
    mech = load_mechanism_mjcf(path)
    assert mech.massless == (4,) and mech.n_body_params == 30
    assert mech.notes == ("bodies of joints ['qb2'] have no inertia in the file: no parameters",)


# ---------------------------------------------------------------------------- Gepetto examples
def test_gepetto_5bar(shared):
    urdf = shared("parallel_examples", "5bar_linkage", "robot.urdf")
    mech = load_mechanism_urdf(urdf)
    assert (mech.nv, mech.dof, mech.n_actuators) == (5, 2, 2)
    assert mech.actuated_names == ["mot1", "mot2"]
    assert "closedloop1_B" not in mech.joint_names and "closedloop1_A" in mech.joint_names
    assert any(n.startswith("locked idle joint closedloop1_B:") for n in mech.notes)
    assert mech.closures[0].kind == "6d"
    assert np.abs(mech.constraint_residual(mech.q_ref)).max() < 1e-10
    u = mech.coordinates(mech.q_ref) + np.array([[0.05, -0.05]])
    q = mech.solve_positions(u)
    assert np.abs(mech.constraint_residual(q)).max() < 1e-10
    assert load_mechanism(urdf).dof == 2


def test_gepetto_delta(shared):
    urdf = shared("parallel_examples", "robot_delta", "robot.urdf")
    mech = load_mechanism_urdf(urdf, urdf.parent / "robot.yaml")
    # 14 joints, 3 planar 6d closures (3 independent rows each) -> mobility 5 = 2 + 3 idle spins
    assert (mech.nv, mech.dof, mech.n_actuators) == (11, 2, 2)
    locked = sorted(n.split(":")[0].split()[-1] for n in mech.notes if n.startswith("locked idle joint"))
    assert locked == ["closedloop1_B", "closedloop2_A", "closedloop3_B"]
    assert mech.constraint_rows.size == 9
    assert np.abs(mech.constraint_residual(mech.q_ref)).max() < 1e-10


def test_gepetto_delta_base_parameters_cut_in_the_regressors_gap(shared):
    """The delta robot's unit-norm regressor columns have levels 2.6e-3, then 2.0e-7 ... 8.5e-10
    around the rank tolerance 1e-8 (its locked idle spins): counted at the tolerance itself the rank
    depended on which side 1.3e-8 fell ("ambiguous base parameters" from `dynid info`). The cut goes
    in the widest gap near the tolerance (model.base_parameters.rank_cut): a gap of at least 1e3
    between the levels on either side, and the base regressor reproduces the full one (checked inside, relative
    residual < 1e-6). (Which levels lie above the gap depends on the sampled poses of this robot:
    most random poses do not assemble and the sampler shrinks its box, so other seeds give 21-24
    base parameters; the default seed is what `dynid info` reports.)"""
    import scipy.linalg as sla

    from dynid.model.base_parameters import rank_cut
    from dynid.model.closed_loop import actuator_regressor, mechanism_base_parameters, random_consistent_states

    urdf = shared("parallel_examples", "robot_delta", "robot.urdf")
    mech = load_mechanism_urdf(urdf, urdf.parent / "robot.yaml")
    bases = [mechanism_base_parameters(mech)]
    assert 0 < bases[0].n_base < mech.n_standard_params
    W = actuator_regressor(mech, random_consistent_states(mech, bases[0].n_samples, np.random.default_rng(0), spread=0.3)).W
    W = W.reshape(-1, W.shape[2])
    norms = np.linalg.norm(W, axis=0)
    keep = norms > 1e-12 * norms.max()
    d = np.abs(np.diag(sla.qr(W[:, keep] / norms[keep], mode="r", pivoting=True)[0]))
    levels = d / d[0]
    cut = rank_cut(levels, 1e-8)
    r = bases[0].n_base
    assert levels[r - 1] > cut > levels[r] and levels[r - 1] > 1e3 * levels[r], (levels[r - 2:r + 2], cut)
    # a clear spectrum keeps the tolerance itself
    assert rank_cut(np.array([1.0, 1e-2, 1e-14]), 1e-8) == 1e-8


def test_gepetto_under_actuated_message_intact(shared, tmp_path):
    urdf = shared("parallel_examples", "5bar_linkage", "robot.urdf")
    y = tmp_path / "c.yaml"
    y.write_text("closed_loop: [['closedloop1_A', 'closedloop1_B']]\ntype: ['6D']\nname_mot: ['mot1']\n")
    with pytest.raises(ModelError) as err:
        load_mechanism_urdf(urdf, y)
    msg = _one_line(err.value)  # Mechanism's own message, prefixed with the files
    assert msg == f"{urdf} + c.yaml: actuated joints ['mot1'] are fewer than the mobility 2: the mechanism is under-actuated"


def test_missing_files(tmp_path):
    with pytest.raises(InputError, match="robot file not found"):
        load_mechanism_mjcf(tmp_path / "nope.xml")
    with pytest.raises(InputError, match="robot file not found"):
        load_mechanism_urdf(tmp_path / "nope.urdf")
    (tmp_path / "r.urdf").write_text('<robot name="r"><link name="a"/></robot>')
    with pytest.raises(InputError, match=r"closure file not found: .*robot\.yaml"):
        load_mechanism_urdf(tmp_path / "r.urdf")
    with pytest.raises(ModelError, match="unknown mechanism file type"):
        load_mechanism(tmp_path / "r.toml")


def test_mjcf_without_closures(tmp_path):
    path = _variant(tmp_path, "serial.xml", (CONNECT, ""))
    with pytest.raises(ModelError) as err:
        load_mechanism_mjcf(path)
    assert "no loop closures" in _one_line(err.value) and "use load_robot" in str(err.value)


_QB2 = '<joint name="qb2" type="hinge" axis="0 1 0" range="-2.8 2.8" damping="0.005"/>'


@pytest.mark.parametrize(
    ("replacements", "expected"),
    [
        ([('joint="qa2"', 'joint="nope"')], r"actuator 'm2' drives 'nope', which is not a joint"),
        ([('<motor name="m1" joint="qa1" gear="1"/>', '<motor name="m1" tendon="t1"/>')], "drives no joint"),
        ([("<actuator>", "<!-- <actuator>"), ("</actuator>", "</actuator> -->")], "no <actuator> drives a joint"),
        # a ball joint is three hinges (tests/test_ball_joints.py): here the distal link, ball at one end and a
        # point closure at the other, spins freely about its axis
        ([(_QB2, '<joint name="qb2" type="ball"/>')], r"are fewer than the mobility 3: the mechanism is under-actuated"),
        ([(_QB2, '<joint name="qb2" type="ball"/><joint name="qc2" axis="1 0 0"/>')],
         "body 'dist2' has a ball joint and other joints; give each joint its own body"),
        ([(_QB2, '<joint name="qb2" class="sph"/>'), ("<worldbody>", '<default><default class="sph"><joint type="ball"/>'
                                                                       "</default></default><worldbody>")],
         r"joint 'qb2' is a ball joint \(3 DOF\).*<default> class: write type=\"ball\" on the joint itself"),
        ([(_QB2, '<joint name="qb2" type="ball"/>'), ('name="dist2"', 'name="qb2_bx"')],
         r"ball joint 'qb2' becomes hinges .* but \['qb2_bx'\] already exist in the file"),
        ([(_QB2, '<freejoint name="fj"/>')], r"joint 'fj' is a free joint \(6 DOF\).*floating body is not supported"),
        ([(_QB2, _QB2 + '<joint name="qc2" axis="1 0 0"/>')], "joint 'Composite_qb2' combines several joints of one body"),
        ([(CONNECT, CONNECT + '<joint joint1="qa1" joint2="qa2"/>')], r"<equality><joint> .* is not supported"),
        ([('    <body name="base">', '    <body name="b0"><inertial mass="1" diaginertia="1 1 1"/></body><body name="base">')],
         "2 top-level bodies"),
    ],
)
def test_bad_mjcf(tmp_path, replacements, expected):
    path = _variant(tmp_path, "bad.xml", *replacements)
    with pytest.raises(ModelError) as err:
        load_mechanism_mjcf(path)
    assert re.search(expected, _one_line(err.value)), str(err.value)


def test_bad_actuated_arguments():
    with pytest.raises(ModelError, match=r"actuated joints \['qz'\] are not joints"):
        load_mechanism_mjcf(FIVEBAR, actuated=["qa1", "qz"])
    with pytest.raises(ModelError) as err:
        load_mechanism_mjcf(FIVEBAR, actuated=["qa1"])
    assert _one_line(err.value) == f"{FIVEBAR}: actuated joints ['qa1'] are fewer than the mobility 2: the mechanism is under-actuated"
    with pytest.raises(ModelError) as err:
        load_mechanism_mjcf(FIVEBAR, actuated=["qa1", "qa2"], independent=["qa1"])
    assert _one_line(err.value).startswith(f"{FIVEBAR}: mechanism 'fivebar' has mobility 2")
    with pytest.raises(ModelError) as err:
        load_mechanism_mjcf(FIVEBAR, actuated=["qa1"], independent=["qa1", "qa2"])
    assert "['qa1'] are fewer than the mobility 2: the mechanism is under-actuated" in _one_line(err.value)
    redundant = load_mechanism_mjcf(FIVEBAR, actuated=["qa1", "qa2", "qb1"], independent=["qa1", "qa2"])
    assert redundant.redundant and redundant.dof == 2


_INERTIAL = '<inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>'
_URDF = f"""<robot name="fourbar">
  <link name="base"/>
  <link name="l1">{_INERTIAL}</link> <link name="l2">{_INERTIAL}</link> <link name="l3">{_INERTIAL}</link>
  <link name="t2"/> <link name="t3"/>
  <joint name="j1" type="continuous"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <dynamics damping="0.3" friction="-0.1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="1 0 0"/><axis xyz="0 0 1"/>
    <limit effort="1" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="tip2" type="fixed"><parent link="l2"/><child link="t2"/><origin xyz="0 1.2 0"/></joint>
  <joint name="j3" type="revolute"><parent link="base"/><child link="l3"/><origin xyz="-0.5 1.2 0"/><axis xyz="0 0 1"/>
    <limit effort="1" velocity="1" lower="-3" upper="3"/></joint>
  <joint name="tip3" type="fixed"><parent link="l3"/><child link="t3"/><origin xyz="1.5 0 0"/></joint>
</robot>
"""


def test_urdf_four_bar(tmp_path):
    """A planar four-bar closed by a '3d' point closure between two fixed frames; the crank
    joint is continuous (made an ordinary revolute with limits of ±π) and has <dynamics>."""
    urdf = tmp_path / "fourbar.urdf"
    urdf.write_text(_URDF)
    (tmp_path / "robot.yaml").write_text("closed_loop: [[tip2, tip3]]\ntype: [3D]\nname_mot: [j1]\n")
    mech = load_mechanism(urdf)
    assert (mech.name, mech.nv, mech.dof, mech.n_actuators, mech.notes) == ("fourbar", 3, 1, 1, ())
    assert mech.closures[0].kind == "3d" and np.allclose(mech.q_ref, 0.0)
    assert dict(mech.nominal_terms) == pytest.approx({"fv_j1": 0.3, "fc_j1": -0.1})
    assert [t.name for t in mech.terms] == ["Ia_j1", "fv_j1", "fc_j1", "fv_j2", "fv_j3"]
    assert np.allclose(mech.position_limits()[1], [np.pi, 3.0, 3.0])
    q = mech.solve_positions(np.array([[0.3], [-0.2]]))
    assert np.abs(mech.constraint_residual(q)).max() < 1e-10


def test_urdf_idle_spin_is_locked(tmp_path):
    """Gepetto-style closure on the four-bar: revolute "closedloop" joints at both tips whose
    child bodies are welded ('6d'): their common spin is idle and one of them is locked."""
    extra = (
        '<link name="s2">{i}</link> <link name="s3">{i}</link>\n'
        '  <joint name="cl_A" type="revolute"><parent link="t2"/><child link="s2"/><axis xyz="0 0 1"/>'
        '<limit effort="1" velocity="1"/></joint>\n'
        '  <joint name="cl_B" type="revolute"><parent link="l3"/><child link="s3"/><origin xyz="1.5 0 0" rpy="0 0 0.3"/>'
        '<axis xyz="0 0 1"/><limit effort="1" velocity="1"/></joint>\n</robot>'
    ).format(i=_INERTIAL)
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(_URDF.replace("</robot>", extra))
    (tmp_path / "robot.yaml").write_text("closed_loop: [[cl_A, cl_B]]\ntype: [6d]\nname_mot: [j1]\n")
    mech = load_mechanism_urdf(urdf)
    assert (mech.name, mech.nv, mech.dof, mech.n_actuators) == (tmp_path.name, 4, 1, 1)
    assert mech.joint_names == ("j1", "j2", "cl_A", "j3")
    (note,) = mech.notes
    assert note.startswith("locked idle joint cl_B: closure 'cl_A-cl_B' (6d)") and "locked at 0 rad" in note
    assert np.abs(mech.constraint_residual(mech.q_ref)).max() < 1e-10
    q = mech.solve_positions(np.array([[0.2], [-0.3]]))
    assert np.abs(mech.constraint_residual(q)).max() < 1e-10
    # cl_A turns with the coupler against the welded s2-s3 (attached to l3): angle j3 - j1 - j2 + const
    assert np.allclose(np.diff(q[:, 2] + q[:, 1] + q[:, 0] - q[:, 3]), 0.0, atol=1e-9)
    with pytest.raises(ModelError, match="under-actuated|independent coordinates"):
        load_mechanism_urdf(urdf, actuated=["j1"], independent=["j1", "j2"])


@pytest.mark.parametrize(
    ("yaml_text", "expected"),
    [
        ("type: ['6d']\nname_mot: ['j1']\n", r"missing key\(s\) \['closed_loop'\]"),
        ("closed_loop: [['j1', 'j2']]\ntype: ['6d']\n", r"missing key\(s\) \['name_mot'\]"),
        ("closed_loop: [['j1', 'j2'], ['j1', 'l2']]\ntype: ['6d']\nname_mot: ['j1']\n", "has 2 pair\\(s\\) but 'type' has 1"),
        ("closed_loop: [['j1', 'j2']]\ntype: ['4d']\nname_mot: ['j1']\n", "closure type '4d' .* is unknown; use '6d' or '3d'"),
        ("closed_loop: [['j1', 'tip']]\ntype: ['3d']\nname_mot: ['j1']\n",
         r"closure frame\(s\) \['tip'\] not found in r.urdf; frames include .*tip2"),
        ("closed_loop: [['tip2', 'tip3']]\ntype: ['3d']\nname_mot: ['motor']\n", r"actuated joints \['motor'\] are not joints"),
        ("closed_loop: [j1, j2]\ntype: ['3d', '3d']\nname_mot: ['j1']\n", "is not a pair of frame names"),
        ("- a\n- b\n", "must be a mapping"),
        ("closed_loop: [[a, b]\n", "invalid YAML"),
    ],
)
def test_bad_closure_yaml(tmp_path, yaml_text, expected):
    urdf = tmp_path / "r.urdf"
    urdf.write_text(_URDF)
    y = tmp_path / "c.yaml"
    y.write_text(yaml_text)
    with pytest.raises(ModelError) as err:
        load_mechanism_urdf(urdf, y)
    assert re.search(expected, _one_line(err.value)), str(err.value)


def test_loop_that_cannot_close_is_refused_naming_the_closure(tmp_path):
    """The four-bar with the rocker tip moved from 1.5 m to 5 m along l3: tip2 stays within
    |l1| + |tip2| = 1 + 1.2 = 2.2 m of the base origin, tip3 runs on a 5 m circle whose centre is
    |(-0.5, 1.2)| = 1.3 m from it, so the gap is at least 5 - 1.3 - 2.2 = 1.5 m in any
    configuration (planar: its z row is 0, so the largest component is >= 1.5/sqrt(2) m). Both the
    URDF+YAML reader and the Python builder (Mechanism) refuse it and name the closure."""
    urdf = tmp_path / "r.urdf"
    urdf.write_text(_URDF.replace('<child link="t3"/><origin xyz="1.5 0 0"/>', '<child link="t3"/><origin xyz="5 0 0"/>'))
    (tmp_path / "robot.yaml").write_text("closed_loop: [[tip2, tip3]]\ntype: [3D]\nname_mot: [j1]\n")
    pattern = r"cannot assemble the loops of '(r|fourbar)': closure 'tip2-tip3' \(3d\) cannot close .*constraint residual (\S+) after 100"
    with pytest.raises(ModelError) as err:
        load_mechanism_urdf(urdf)
    msg = _one_line(err.value)
    m = re.search(pattern, msg)
    assert m and msg.startswith(f"{urdf} + robot.yaml: "), msg
    assert float(m.group(2)) >= 1.5 / np.sqrt(2) - 1e-9
    # the Python builder, from the good four-bar's tree and closure with the tip moved the same way
    good = tmp_path / "good"
    good.mkdir()
    (good / "fourbar.urdf").write_text(_URDF)
    (good / "robot.yaml").write_text("closed_loop: [[tip2, tip3]]\ntype: [3D]\nname_mot: [j1]\n")
    mech = load_mechanism_urdf(good / "fourbar.urdf")
    c = mech.closures[0]
    assert mech.pin_model.names[c.joint_b] == "j3"  # side b is tip3, 1.5 m along l3: move it to 5 m
    far = dataclasses.replace(c, placement_b=c.placement_b * pin.SE3(np.eye(3), np.array([3.5, 0.0, 0.0])))
    with pytest.raises(ModelError) as err:
        Mechanism(mech.pin_model, (far,), actuated=mech.actuated, terms=mech.terms, q_guess=mech.q_ref, name="fourbar")
    msg = _one_line(err.value)
    m = re.search(pattern, msg)
    assert m, msg
    assert float(m.group(2)) >= 1.5 / np.sqrt(2) - 1e-9


def test_mjcf_connect_closes_at_qpos0_by_construction(tmp_path):
    """MuJoCo semantics (followed by pinocchio): a body-based <connect> gives the anchor in
    body1's frame and computes the point on body2 at qpos0, so moving the anchor 1.73 m away
    (out of reach of the 0.45 m distal link of the real linkage) still closes: the point on dist2
    becomes (2.0 - 0.54, 0, 0.36) m (dist2's origin is 0.54 m right of dist1's at q = 0)."""
    path = _variant(tmp_path, "far.xml", (CONNECT, CONNECT.replace("0.27 0 0.36", "2.0 0 0.36")))
    mech = load_mechanism_mjcf(path)
    c = mech.closures[0]
    assert np.allclose(mech.q_ref, 0.0) and np.abs(mech.constraint_residual(mech.q_ref)).max() < 1e-12
    pa, pb = c.placement_a.translation, c.placement_b.translation
    assert np.allclose(sorted([pa[0], pb[0]]), [1.46, 2.0]) and np.allclose([pa[2], pb[2]], 0.36)


FOURBAR_OFFSET = """<mujoco model="fourbar_offset">
  <worldbody>
    <body name="base">
      <inertial pos="0 0 0" mass="0" diaginertia="0 0 0"/>
      <body name="crank">
        <joint name="ja" type="hinge" axis="0 0 1"/>
        <inertial pos="0.5 0 0" mass="1" diaginertia="0.01 0.1 0.1"/>
        <body name="coupler" pos="1 0 0">
          <joint name="jb" type="hinge" axis="0 0 1" pos="0.2 0 0"/>
          <inertial pos="0.8 0 0" mass="1" diaginertia="0.01 0.1 0.1"/>
        </body>
      </body>
      <body name="rocker" pos="2.5 -1 0">
        <joint name="jc" type="hinge" axis="0 0 1"/>
        <inertial pos="0 0.5 0" mass="1" diaginertia="0.1 0.01 0.1"/>
      </body>
    </body>
  </worldbody>
  <equality><connect body1="coupler" body2="rocker" anchor="1.5 0 0"/></equality>
  <actuator><motor joint="ja"/></actuator>
</mujoco>
"""


def test_connect_anchor_is_in_body1_frame_when_its_joint_has_pos(tmp_path):
    """MuJoCo: a <connect> anchor is in body1's frame. pinocchio 4 puts it in the frame of body1's
    joint, which sits at the joint's ``pos`` (0.2 m along x here): the loop would close 0.2 m
    further out, a rocker 0.2 m longer than the file's. The loader corrects it: at the reference
    the closure point is body1's origin (1, 0, 0) + anchor (1.5, 0, 0) = (2.5, 0, 0) on both sides,
    and the rocker's arm is the file's 1 m."""
    path = tmp_path / "fourbar.xml"
    path.write_text(FOURBAR_OFFSET)
    model, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    raw = data.oMi[int(constraints[0].joint1_id)] * constraints[0].joint1_placement
    assert np.allclose(raw.translation, [2.7, 0, 0])  # pinocchio's own reading (if this fails, pinocchio changed)
    mech = load_mechanism_mjcf(path)
    c = mech.closures[0]
    d = mech.pin_model.createData()
    pin.forwardKinematics(mech.pin_model, d, np.zeros(mech.nv))
    for j, P in ((c.joint_a, c.placement_a), (c.joint_b, c.placement_b)):
        np.testing.assert_allclose((d.oMi[j] * P).translation, [2.5, 0, 0], atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(c.placement_b.translation), 1.0, atol=1e-14)
    assert np.abs(mech.constraint_residual(mech.q_ref)).max() < 1e-12
