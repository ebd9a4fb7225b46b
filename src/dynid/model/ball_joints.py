"""Ball and universal joints. :class:`BallJoint`: a ball joint as three hinges through two massless
bodies; :func:`add_ball_joint` / :func:`add_universal_joint` build them in a pinocchio model, and the
file readers rewrite them before pinocchio reads a file: an MJCF ``<joint type="ball">`` (:func:`_balls_as_hinges`) or a URDF placeholder joint the
closure YAML declares spherical (:func:`_urdf_balls_as_hinges`); the hinges' names and their clash check
(:class:`BallJoint`). Split from :mod:`dynid.model.mechanism_files` and :mod:`dynid.model.mechanism`, which
re-export what they used to hold."""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from dynid.errors import ModelError

__all__ = ["BallJoint", "add_ball_joint", "add_universal_joint"]


@dataclasses.dataclass(frozen=True)
class BallJoint:
    r"""A spherical (ball) joint as three orthogonal revolute joints ``hinges = (x, y, z)`` in a
    chain through two massless bodies: the relative rotation is
    :math:`R_x(q_x) R_y(q_y) R_z(q_z)` (Cardan angles), an exact chart of SO(3) away from
    :math:`q_y = \pm 90°`, where the ``x`` and ``z`` axes align (gimbal lock). ``body`` is
    the body the ball joint carries, whose parameters are named after it (``m_<body>``)
    rather than after the last hinge."""

    name: str
    body: str
    hinges: tuple[str, str, str]


_AXIS_JOINTS = {"x": pin.JointModelRX, "y": pin.JointModelRY, "z": pin.JointModelRZ}


def add_ball_joint(model: pin.Model, parent: int, placement: pin.SE3, name: str, inertia: pin.Inertia,
                   *, body: str | None = None) -> BallJoint:
    r"""Add a spherical (ball) joint and the body it carries to a pinocchio model under
    construction (the Python builders' counterpart of MJCF ``<joint type="ball">``).

    The joint is three revolute joints ``<name>_x``, ``<name>_y``, ``<name>_z`` about the axes of
    the joint frame ``placement`` (in the frame of joint ``parent``), chained through two massless
    bodies; the last carries ``inertia`` (expressed in the joint frame). The relative rotation is
    :math:`R_x R_y R_z`, exact away from the middle angle ±90° (:class:`BallJoint`; pinocchio's
    ``JointModelSpherical`` gives the same poses, ``tests/test_ball_joints.py``). Pass the
    returned record in ``Mechanism(..., ball_joints=...)``: its two intermediate bodies then count
    as massless and the body's parameters are named after ``body`` (default ``name``).
    The pinocchio joint that carries the body is ``model.getJointId(ball.hinges[2])``.
    """
    hinges = tuple(f"{name}_{a}" for a in "xyz")
    taken = [h for h in hinges if model.existJointName(h)]
    if taken:
        raise ModelError(f"ball joint {name!r}: joints {taken} already exist in the model")
    j = parent
    for k, (h, a) in enumerate(zip(hinges, "xyz")):
        j = model.addJoint(j, _AXIS_JOINTS[a](), placement if k == 0 else pin.SE3.Identity(), h)
        model.appendBodyToJoint(j, inertia if k == 2 else pin.Inertia.Zero(), pin.SE3.Identity())
    return BallJoint(name, body or name, hinges)  # type: ignore[arg-type]


def add_universal_joint(model: pin.Model, parent: int, placement: pin.SE3, name: str, inertia: pin.Inertia,
                        *, axes: str = "xy", cross: pin.Inertia | None = None) -> tuple[int, int]:
    """Add a universal (Cardan) joint and the body it carries: revolute ``<name>_<axes[0]>`` about
    that axis of the joint frame ``placement``, carrying the cross (``cross``: its inertia; none by
    default), then revolute ``<name>_<axes[1]>`` carrying ``inertia``.

    Returns ``(cross_joint, body_joint)``, pinocchio joint indices; with no ``cross`` inertia, list
    ``cross_joint`` in ``Mechanism(..., massless=...)`` (a massless body has no parameters)."""
    if len(axes) != 2 or axes[0] == axes[1] or any(a not in _AXIS_JOINTS for a in axes):
        raise ModelError(f"universal joint {name!r}: axes {axes!r} must be two different letters of 'xyz'")
    first = model.addJoint(parent, _AXIS_JOINTS[axes[0]](), placement, f"{name}_{axes[0]}")
    model.appendBodyToJoint(first, pin.Inertia.Zero() if cross is None else cross, pin.SE3.Identity())
    second = model.addJoint(first, _AXIS_JOINTS[axes[1]](), pin.SE3.Identity(), f"{name}_{axes[1]}")
    model.appendBodyToJoint(second, inertia, pin.SE3.Identity())
    return first, second



_ORIENTATION = ("quat", "axisangle", "xyaxes", "zaxis", "euler")
BALL_AXES = ("x", "y", "z")


def _ball_names(name: str, joints, bodies, what: str, kind: str) -> tuple[tuple[str, ...], tuple[str, str]]:
    """The hinges ``<name>_x/_y/_z`` and massless ``<name>_bx/_by`` a ball joint becomes, refused
    when the file already uses one of those names."""
    hinges = tuple(f"{name}_{a}" for a in BALL_AXES)
    mids = (f"{name}_bx", f"{name}_by")
    taken = [n for n in hinges if n in joints] + [n for n in mids if n in bodies]
    if taken:
        raise ModelError(f"{what} {name!r} becomes hinges {list(hinges)} through {kind} {list(mids)}, "
                         f"but {taken} already exist in the file: rename them")
    return hinges, mids


def _balls_as_hinges(root: ET.Element, path: Path, notes: list[str]) -> list[BallJoint]:
    """Rewrite (in place) each ``<joint type="ball">`` of a body B as three hinges about B's
    x, y and z axes through B's joint point, in a chain through two massless bodies.

    The body ``<ball>_bx`` takes B's place (B's ``pos`` and orientation) and carries the
    hinge ``<ball>_x``; ``<ball>_by`` (at its origin) carries ``<ball>_y``; B itself (now at
    the origin of ``<ball>_by``) carries ``<ball>_z``. The relative rotation of B is then
    :math:`R_x R_y R_z` about the joint point, which is every rotation away from the middle
    angle ±90° (:class:`~dynid.model.mechanism.BallJoint`): at the reference (all angles 0,
    MuJoCo's ``qpos0`` of a ball is the identity) it is the file's pose. A ball's
    ``damping`` [N·m·s/rad] is MuJoCo's viscous friction per degree of freedom and goes to
    each hinge (terms ``fv_<ball>_x`` ... on the chart's angle rates, equal to the relative
    angular velocity's components at the reference); ``frictionloss``, ``armature`` and
    ``range`` (a cone of rotation angles in MuJoCo) have no equivalent here and are noted, not
    used."""
    bodies = {b.get("name") for b in root.iter("body")}
    joints = {j.get("name") for j in root.iter("joint")}
    out = []
    parents = {child: parent for parent in root.iter() for child in parent}
    for body in list(root.iter("body")):
        balls = [j for j in body.findall("joint") if j.get("type") == "ball"]
        if not balls:
            continue
        bname = body.get("name") or "?"
        if len(body.findall("joint")) > 1 or body.find("freejoint") is not None:
            raise ModelError(f"{path}: body {bname!r} has a ball joint and other joints; give each joint its own body")
        ball = balls[0]
        name = ball.get("name") or f"{bname}_ball"
        hinges, mids = _ball_names(name, joints, bodies, f"{path}: ball joint", "bodies")
        parent = parents[body]
        k = list(parent).index(body)
        outer = ET.Element("body", name=mids[0])
        for key in ("pos", *_ORIENTATION):
            if body.get(key) is not None:
                outer.set(key, body.attrib.pop(key))
        middle = ET.SubElement(outer, "body", name=mids[1])
        for el, hinge, axis in ((outer, hinges[0], "1 0 0"), (middle, hinges[1], "0 1 0")):
            ET.SubElement(el, "inertial", pos="0 0 0", mass="0", diaginertia="0 0 0")
            ET.SubElement(el, "joint", _hinge_attrs(ball, hinge, axis))
        body.remove(ball)
        body.insert(0, ET.Element("joint", _hinge_attrs(ball, hinges[2], "0 0 1")))
        parent.remove(body)
        parent.insert(k, outer)
        middle.append(body)
        lost = [key for key in ("frictionloss", "armature", "range") if _given(ball.get(key))]
        if lost:
            notes.append(f"ball joint {name}: {' and '.join(lost)} not modelled (no such term on ball joints)")
        out.append(BallJoint(name, bname, hinges))
    return out


def _given(value: str | None) -> bool:
    """An attribute that says something: present and not all zeros (text that is not numbers counts)."""
    try:
        return value is not None and any(float(v) != 0.0 for v in value.split())
    except ValueError:
        return True


def _hinge_attrs(ball: ET.Element, name: str, axis: str) -> dict[str, str]:
    attrs = {"name": name, "type": "hinge", "axis": axis, "pos": ball.get("pos", "0 0 0")}
    if ball.get("damping") is not None:
        attrs["damping"] = ball.get("damping")
    return attrs


def _mjcf_written_balls(root: ET.Element, path: Path) -> list[BallJoint]:
    """Ball joints written by :func:`dynid.io.export.write_mjcf` as three hinges, recorded in
    ``<custom><text name="dynid:ball" data="<ball> <body> <hinge x> <hinge y> <hinge z>"/>``."""
    out = []
    for text in root.findall("./custom/text"):
        if text.get("name") == "dynid:ball":
            words = text.get("data", "").split()
            if len(words) != 5:
                raise ModelError(f"{path}: <text name='dynid:ball' data={text.get('data')!r}>: expected "
                                 "'ball body hinge_x hinge_y hinge_z'")
            out.append(BallJoint(words[0], words[1], tuple(words[2:])))
    return out


def _urdf_balls_as_hinges(xml: str, spherical: list[str], dynamics: dict[str, tuple[float, float]], urdf_path: Path,
                          yaml_path: Path, notes: list[str]) -> tuple[str, list[BallJoint], dict[str, tuple[float, float]]]:
    """URDF text with each joint named in ``spherical`` (the YAML's ``joint_name``) replaced by
    three revolute joints ``<j>_x``, ``<j>_y``, ``<j>_z`` about the axes of that joint's frame
    (its ``<origin>``, which is the child link's frame at zero), through two massless links
    ``<j>_bx``, ``<j>_by``: the same chart as an MJCF ball (:func:`_balls_as_hinges`), at the
    file's pose when all three angles are zero. The placeholder's type (revolute, continuous or
    fixed) and axis are ignored. Its ``<dynamics damping>`` goes to each hinge (viscous per
    angle rate); ``friction`` (Coulomb) is noted and not used. The ball's parameters are named
    after the child link. Returns the text, the balls and the dynamics table without the
    placeholders (with the hinges' damping)."""
    root = ET.fromstring(xml)
    joints = {j.get("name"): j for j in root.findall("joint")}
    links = {link.get("name") for link in root.findall("link")}
    missing = [n for n in spherical if n not in joints]
    if missing:
        raise ModelError(f"{yaml_path}: joint_name {missing} are not joints of {urdf_path.name}; joints: {sorted(joints)}")
    dynamics = dict(dynamics)
    out = []
    for name in spherical:
        joint = joints[name]
        kind = joint.get("type")
        if kind not in ("revolute", "continuous", "fixed"):
            raise ModelError(f"{urdf_path}: joint {name!r} is declared SPHERICAL in {yaml_path.name} but is a {kind!r} joint; "
                             "write the placeholder as revolute, continuous or fixed")
        hinges, mids = _ball_names(name, joints, links, f"{urdf_path}: spherical joint", "links")
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise ModelError(f"{urdf_path}: joint {name!r} lacks <parent> or <child>")
        chain = [parent.get("link"), *mids, child.get("link")]
        k = list(root).index(joint)
        root.remove(joint)
        for n, (hinge, axis) in enumerate(zip(hinges, ("1 0 0", "0 1 0", "0 0 1"))):
            el = ET.Element("joint", name=hinge, type="revolute")
            origin = joint.find("origin")
            if n == 0 and origin is not None:
                el.append(origin)
            ET.SubElement(el, "parent", link=chain[n])
            ET.SubElement(el, "child", link=chain[n + 1])
            ET.SubElement(el, "axis", xyz=axis)
            ET.SubElement(el, "limit", lower=repr(-np.pi), upper=repr(np.pi), effort="1000", velocity="100")
            root.insert(k + n, el)
        for mid in mids:
            link = ET.SubElement(root, "link", name=mid)
            inertial = ET.SubElement(link, "inertial")
            ET.SubElement(inertial, "mass", value="0")
            ET.SubElement(inertial, "inertia", ixx="0", ixy="0", ixz="0", iyy="0", iyz="0", izz="0")
        damping, friction = dynamics.pop(name, (0.0, 0.0))
        if damping:
            dynamics.update({h: (damping, 0.0) for h in hinges})
        if friction:
            notes.append(f"ball joint {name}: friction (Coulomb) not modelled (no such term on ball joints)")
        out.append(BallJoint(name, chain[-1], hinges))
    return ET.tostring(root, encoding="unicode"), out, dynamics
