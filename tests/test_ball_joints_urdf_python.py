"""Ball joints from URDF + YAML (Gepetto's ``joint_name`` / ``joint_type: SPHERICAL``) and from
the Python builders (:func:`dynid.model.mechanism.add_ball_joint`, ``add_universal_joint``).

The check is an independent route: the Stewart platform of ``tests/test_ball_joints.py`` written
three ways (MJCF with ``<joint type="ball">``; URDF with a placeholder joint named SPHERICAL in
the closure YAML; pinocchio calls in Python) gives the same mechanism: the same parameter names
and nominal values, and the same actuator forces (pinocchio's RNEA through the closures) at the
same actuator positions, velocities and accelerations.
"""

from __future__ import annotations

import re

import numpy as np
import pinocchio as pin
import pytest

from dynid.cli import main
from dynid.errors import ModelError
from dynid.model.closed_loop import actuator_forces, random_consistent_states
from dynid.model.mechanism import JointCoordinates, LoopClosure, Mechanism, add_ball_joint, add_universal_joint
from dynid.model.mechanism_io import load_mechanism_mjcf, load_mechanism_urdf

from test_ball_joints import stewart_xml

RB, RP, H = 0.5, 0.3, 0.8  # the geometry of stewart_xml
AB = np.radians([-15, 15, 105, 135, 225, 255])
AP = np.radians([-45, 45, 75, 165, 195, 285])
B = np.c_[RB * np.cos(AB), RB * np.sin(AB), np.zeros(6)]
C = np.array([0.0, 0.0, H])
P = np.c_[RP * np.cos(AP), RP * np.sin(AP), np.zeros(6)]
COM = np.array([0.01, -0.02, 0.03])  # platform centre of mass in its frame (at C)
I_PLATFORM = np.array([[0.08, 0.004, -0.003], [0.004, 0.09, 0.002], [-0.003, 0.002, 0.15]])


def v(x) -> str:
    return " ".join(f"{t:.15g}" for t in x)


def stewart_urdf(placeholder: str = "revolute", damping: float | None = None) -> str:
    """The same platform in URDF: the ball of leg 1 is a placeholder joint whose frame is the ball's
    centre (the platform link's frame sits there, world-aligned at zero); the other legs close on
    the platform by '3d' closures between two massless links."""
    links, joints = ['<link name="base"/>'], []
    for i in range(6):
        d = C + P[i] - B[i]
        L = float(np.linalg.norm(d))
        u = d / L
        n = i + 1
        links += [
            f'<link name="leg{n}_ring"><inertial><origin xyz="0 0 0"/><mass value="0.1"/>'
            '<inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial></link>',
            f'<link name="leg{n}_cyl"><inertial><origin xyz="{v(0.25 * L * u)}"/><mass value="0.8"/>'
            '<inertia ixx="0.01" iyy="0.01" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial></link>',
            f'<link name="leg{n}_rod"><inertial><origin xyz="{v(0.75 * L * u)}"/><mass value="0.5"/>'
            '<inertia ixx="0.006" iyy="0.006" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>',
        ]
        joints += [
            f'<joint name="u{n}x" type="revolute"><origin xyz="{v(B[i])}"/><parent link="base"/><child link="leg{n}_ring"/>'
            '<axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>',
            f'<joint name="u{n}y" type="revolute"><parent link="leg{n}_ring"/><child link="leg{n}_cyl"/>'
            '<axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>',
            f'<joint name="s{n}" type="prismatic"><parent link="leg{n}_cyl"/><child link="leg{n}_rod"/>'
            f'<axis xyz="{v(u)}"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>',
        ]
        if i:  # closure frames: on the platform at P[i] (platform frame at the ball, i.e. at C + P[0]) and on the rod
            links += [f'<link name="loop{n}_A"/>', f'<link name="loop{n}_B"/>']
            joints += [
                f'<joint name="loop{n}_A_frame" type="fixed"><origin xyz="{v(P[i] - P[0])}"/><parent link="platform"/>'
                f'<child link="loop{n}_A"/></joint>',
                f'<joint name="loop{n}_B_frame" type="fixed"><origin xyz="{v(C + P[i] - B[i])}"/><parent link="leg{n}_rod"/>'
                f'<child link="loop{n}_B"/></joint>',
            ]
    Ic = I_PLATFORM
    links.append(
        f'<link name="platform"><inertial><origin xyz="{v(COM - P[0])}"/><mass value="3.0"/>'
        f'<inertia ixx="{Ic[0, 0]}" iyy="{Ic[1, 1]}" izz="{Ic[2, 2]}" ixy="{Ic[0, 1]}" ixz="{Ic[0, 2]}" iyz="{Ic[1, 2]}"/>'
        "</inertial></link>"
    )
    dyn = f'<dynamics damping="{damping}"/>' if damping else ""
    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>' if placeholder == "revolute" else ""
    axis = '<axis xyz="0 0 1"/>' if placeholder != "fixed" else ""
    joints.append(
        f'<joint name="platform_ball" type="{placeholder}"><origin xyz="{v(C - B[0] + P[0])}"/><parent link="leg1_rod"/>'
        f'<child link="platform"/>{axis}{limit}{dyn}</joint>'
    )
    return '<robot name="stewart">\n' + "\n".join(links + joints) + "\n</robot>\n"


STEWART_YAML = """closed_loop: [{loops}]
type: [{types}]
name_mot: [{motors}]
joint_name: ['platform_ball']
joint_type: ['SPHERICAL']
""".format(
    loops=", ".join(f"['loop{n}_A', 'loop{n}_B']" for n in range(2, 7)),
    types=", ".join(["'3d'"] * 5),
    motors=", ".join(f"'s{n}'" for n in range(1, 7)),
)


def stewart_python(mass_on: str | None = None) -> Mechanism:
    """The same platform built with pinocchio calls and the builder helpers (``mass_on``: a joint
    whose body gets 0.1 kg more, to see a wrong build refused)."""
    model = pin.Model()
    model.name = "stewart"
    act, massless, ball, rods = [], [], None, []
    for i in range(6):
        d = C + P[i] - B[i]
        L = float(np.linalg.norm(d))
        u = d / L
        n = i + 1
        cross, cyl = add_universal_joint(model, 0, pin.SE3(np.eye(3), B[i]), f"u{n}", pin.Inertia(0.8, 0.25 * L * u, np.diag([0.01, 0.01, 0.002])),
                                         axes="xy", cross=pin.Inertia(0.1, np.zeros(3), np.diag([1e-4] * 3)))
        rod = model.addJoint(cyl, pin.JointModelPrismaticUnaligned(u), pin.SE3.Identity(), f"s{n}")
        model.appendBodyToJoint(rod, pin.Inertia(0.5, 0.75 * L * u, np.diag([0.006, 0.006, 0.001])), pin.SE3.Identity())
        act.append(model.joints[rod].idx_v)
        rods.append(rod)
        if i == 0:
            ball = add_ball_joint(model, rod, pin.SE3(np.eye(3), C - B[0] + P[0]), "platform_ball",
                                  pin.Inertia(3.0, COM - P[0], I_PLATFORM), body="platform")
    platform = model.getJointId(ball.hinges[2])
    if mass_on:
        model.appendBodyToJoint(model.getJointId(mass_on), pin.Inertia.FromSphere(0.1, 0.05), pin.SE3.Identity())
    closures = [LoopClosure(f"leg{n}", platform, pin.SE3(np.eye(3), P[n - 1] - P[0]), rods[n - 1],
                            pin.SE3(np.eye(3), C + P[n - 1] - B[n - 1]), "3d") for n in range(2, 7)]
    return Mechanism(model, tuple(closures), actuated=tuple(act), independent=JointCoordinates(tuple(act)),
                     ball_joints=(ball,), name="stewart")


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ball3")
    (tmp / "stewart.xml").write_text(stewart_xml())
    (tmp / "robot.urdf").write_text(stewart_urdf())
    (tmp / "robot.yaml").write_text(STEWART_YAML)
    return tmp, load_mechanism_mjcf(tmp / "stewart.xml"), load_mechanism_urdf(tmp / "robot.urdf"), stewart_python()


def canon(name: str) -> str:
    """The Python build names its universal joints' hinges ``u1_x`` (add_universal_joint); the files ``u1x``."""
    return re.sub(r"u(\d)_([xy])$", r"u\1\2", name)


def _forces_at(mech: Mechanism, ref: Mechanism, params_ref: np.ndarray, state) -> np.ndarray:
    """Actuator forces of ``mech`` at the actuator motion of ``state`` (a state of ``ref``), with
    ``ref``'s parameters mapped by name (joint terms absent from ``mech`` are zero)."""
    idx = {n: k for k, n in enumerate(ref.parameter_names)}
    params = np.array([params_ref[idx[canon(n)]] if canon(n) in idx else 0.0 for n in mech.parameter_names])
    ua = [ref.joint_names.index(n) for n in ref.actuated_names]
    u, du, ddu = state.q[:, ua], state.dq[:, ua], state.ddq[:, ua]
    ub = [mech.joint_names.index(n) for n in mech.actuated_names]
    assert [mech.joint_names[k] for k in ub] == [ref.joint_names[k] for k in ua]
    # Newton per sample from ref's joint positions mapped by name (the samples are far apart); it
    # stops at mech's own loop closure, so the forces below are mech's, not a copy of ref's state
    cols = [ref.joint_names.index(canon(n)) for n in mech.joint_names]
    q = mech.solve_positions(u, q0=state.q[:, cols])
    return actuator_forces(mech, params, mech.states(q, du, ddu))


def test_urdf_and_python_give_the_mjcf_mechanism(three):
    _, mjcf, urdf, py = three
    for mech in (urdf, py):
        assert (mech.nv, mech.dof, mech.n_actuators) == (mjcf.nv, mjcf.dof, mjcf.n_actuators)
        assert [b.body for b in mech.ball_joints] == ["platform"]
        body = [canon(n) for n in mech.parameter_names if not n.startswith(("fv_", "fc_", "Ia_"))]
        assert sorted(body) == sorted(n for n in mjcf.parameter_names if not n.startswith(("fv_", "fc_", "Ia_")))
        nom = dict(zip(map(canon, mech.parameter_names), mech.nominal_parameters()))
        ref = dict(zip(mjcf.parameter_names, mjcf.nominal_parameters()))
        np.testing.assert_allclose([nom[n] for n in body], [ref[n] for n in body], rtol=1e-12, atol=1e-14)
    assert any("platform_ball" in n and "SPHERICAL" not in n for n in urdf.notes)


def test_same_actuator_forces_three_ways(three):
    _, mjcf, urdf, py = three
    state = random_consistent_states(mjcf, 12, np.random.default_rng(3), spread=0.2)
    mid = mjcf.joint_names.index("platform_ball_y")
    assert np.abs(state.q[:, mid]).max() > 1e-2  # the ball turns about its middle axis
    params = mjcf.nominal_parameters() * np.random.default_rng(4).uniform(0.5, 1.5, mjcf.n_standard_params)
    tau = actuator_forces(mjcf, params, state)
    assert np.abs(tau).max() > 1.0
    for mech in (urdf, py):
        np.testing.assert_allclose(_forces_at(mech, mjcf, params, state), tau, rtol=0, atol=1e-8 * np.abs(tau).max())


@pytest.mark.parametrize("placeholder", ["continuous", "fixed"])
def test_placeholder_type_does_not_matter(three, placeholder):
    tmp, mjcf, urdf, _ = three
    path = tmp / f"{placeholder}.urdf"
    path.write_text(stewart_urdf(placeholder))
    mech = load_mechanism_urdf(path, tmp / "robot.yaml")
    np.testing.assert_allclose(mech.q_ref, urdf.q_ref, atol=1e-12)
    assert mech.parameter_names == urdf.parameter_names


def test_urdf_ball_damping_per_hinge(tmp_path):
    (tmp_path / "robot.urdf").write_text(stewart_urdf(damping=0.03))
    (tmp_path / "robot.yaml").write_text(STEWART_YAML)
    mech = load_mechanism_urdf(tmp_path / "robot.urdf")
    assert {k: v for k, v in mech.nominal_terms.items() if "platform_ball" in k} == {
        f"fv_platform_ball_{a}": 0.03 for a in "xyz"}


def test_dynid_info_on_the_urdf(three, capsys):
    tmp = three[0]
    assert main(["info", str(tmp / "robot.urdf")]) == 0
    out = capsys.readouterr().out
    assert "ball joint platform_ball (body platform)" in out


@pytest.mark.parametrize(
    ("yaml_edit", "message"),
    [
        (lambda y: y.replace("['platform_ball']", "['platform_bal']"), "joint_name ['platform_bal'] are not joints"),
        (lambda y: y.replace("['SPHERICAL']", "['PLANAR']"), "joint_type 'PLANAR' is not supported"),
        (lambda y: y.replace("['SPHERICAL']", "['SPHERICAL', 'SPHERICAL']"), "'joint_name' has 1 entries but 'joint_type' has 2"),
        (lambda y: y.replace("['platform_ball']", "['s2']"), "is a 'prismatic' joint"),
    ],
)
def test_bad_spherical_declarations_are_one_line_errors(tmp_path, capsys, yaml_edit, message):
    (tmp_path / "robot.urdf").write_text(stewart_urdf())
    (tmp_path / "robot.yaml").write_text(yaml_edit(STEWART_YAML))
    with pytest.raises(ModelError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(")):
        load_mechanism_urdf(tmp_path / "robot.urdf")
    assert main(["info", str(tmp_path / "robot.urdf")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dynid: error:")


def test_python_ball_with_mass_on_a_middle_hinge_is_refused():
    with pytest.raises(ModelError, match="ball joint 'platform_ball': the body of its hinge 'platform_ball_y' must be massless"):
        stewart_python(mass_on="platform_ball_y")
    model = pin.Model()
    add_ball_joint(model, 0, pin.SE3.Identity(), "b", pin.Inertia.Zero())
    with pytest.raises(ModelError, match=r"joints \['b_x', 'b_y', 'b_z'\] already exist"):
        add_ball_joint(model, 0, pin.SE3.Identity(), "b", pin.Inertia.Zero())
    with pytest.raises(ModelError, match="axes 'xx' must be two different letters"):
        add_universal_joint(model, 0, pin.SE3.Identity(), "u", pin.Inertia.Zero(), axes="xx")


@pytest.mark.parametrize("which", ["urdf", "python"])
def test_export_of_a_urdf_or_python_ball_loads_back(three, tmp_path, which):
    """Issue 18 item 4 for these routes: the MJCF that identify exports loads back with the ball
    (name, body, hinges) and the same regressor."""
    from dynid.io.export import write_mjcf
    from dynid.model.closed_loop import actuator_regressor

    mech = three[2] if which == "urdf" else three[3]
    out = write_mjcf(mech, mech.nominal_parameters(), tmp_path / "back.xml")
    back = load_mechanism_mjcf(out)
    nb = mech.n_body_params  # the Python build has no joint terms; the file gets the loader's defaults
    assert back.parameter_names[:nb] == mech.parameter_names[:nb]
    assert [(b.name, b.body, b.hinges) for b in back.ball_joints] == [(b.name, b.body, b.hinges) for b in mech.ball_joints]
    state = random_consistent_states(mech, 5, np.random.default_rng(3), spread=0.2)
    np.testing.assert_allclose(actuator_regressor(back, state).W[..., :nb], actuator_regressor(mech, state).W[..., :nb], atol=1e-9)
