"""Read closed-loop mechanisms from files: MJCF with ``<equality>`` loop closures, or URDF
with a closure YAML in the format of Gepetto's *example-parallel-robots*. (The built-in
``fivebar`` is such a file; :mod:`dynid.model.mechanism_io` re-exports these readers beside
:func:`~dynid.model.mechanism_io.load_mechanism`, which also takes ``builtin:`` names.)

* **MJCF** (:func:`load_mechanism_mjcf`): pinocchio's
  ``buildModelAndLegacyConstraintsFromMJCF`` gives the tree and one rigid constraint per
  ``<connect>`` (``"3d"``: point coincidence) or ``<weld>`` (``"6d"``: frame coincidence);
  both sides are (joint, placement in the joint frame), as :class:`LoopClosure` wants.
  Actuated joints come from ``<actuator>`` (``<motor joint=...>``, ``<position ...>``, ...).
  Joint ``damping`` [N·m·s/rad or N·s/m], ``frictionloss`` [N·m or N] and ``armature``
  [kg·m² or kg] become nominal values of viscous, Coulomb and inertia joint terms.
  A ``<joint type="ball">`` is rewritten, before pinocchio reads the file, as three hinges
  through two massless bodies (:func:`_balls_as_hinges`, :class:`~dynid.model.mechanism.BallJoint`).
* **URDF + YAML** (:func:`load_mechanism_urdf`): keys ``closed_loop`` (pairs of frame
  names), ``type`` (``6d``/``3d`` per pair) and ``name_mot`` (actuated joints). URDF
  ``<dynamics>`` damping/friction become nominal viscous/Coulomb values. URDF has no spherical
  joint: as in the Gepetto examples, the URDF writes a placeholder joint (its axis is
  ignored) and the YAML's ``joint_name`` / ``joint_type: SPHERICAL`` say which; each is read
  as three hinges through two massless links, like an MJCF ball (:func:`_urdf_balls_as_hinges`).
  A universal joint is what URDF writes anyway: two revolute joints through a link (the cross).

Closure check at load. Every loader assembles the loops by Gauss-Newton from the model's
reference configuration (MJCF ``qpos0``, i.e. the joints' ``ref``; URDF: zero) and refuses a
loop that does not close, naming the closure with the largest residual [m, rad]. What can
fail differs by format: a body-based MJCF ``<connect>`` closes at ``qpos0`` by construction
(MuJoCo semantics: ``anchor`` is given in ``body1``'s frame and the point on ``body2`` is
computed at ``qpos0``; pinocchio 4 reads the anchor in body1's *joint* frame, which
:func:`_mjcf_closures` corrects where the two differ), so an anchor away from ``body2``'s far end gives a
loop that closes with a link of another length, never an error; a ``<weld>`` with an explicit
``relpose`` and a URDF+YAML closure (both frames given by the file) can fail. Closing does not
have to happen *at* the reference configuration: the Gepetto examples are not assembled at
zero (largest residual 1.57 rad for ``5bar_linkage``, 3.14 rad for ``robot_delta``) and are
assembled nearby.

Idle joints. The Gepetto examples weld the child bodies of two revolute "closedloop"
joints with a ``6d`` closure: the welded pair can then spin about the common axis, a
degree of freedom that no actuator determines and that carries no dynamics worth
identifying. Such joints are found as the null space of :math:`[J_c; S_a]` at an assembled
configuration restricted to joints carrying a closure, and one joint per closure is
locked (``pinocchio.buildReducedModel``; its body is merged into its parent), which is
recorded in :attr:`Mechanism.notes`. Any other free motion is left to :class:`Mechanism`,
which refuses it.

Default joint terms: a viscous term ``fv_<joint>`` on every joint (passive ones
included), plus Coulomb ``fc_<joint>`` and rotor inertia ``Ia_<joint>`` on actuated joints
and on any joint whose file gives a non-zero friction or armature.
"""

from __future__ import annotations

import re
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from dynid.errors import ModelError, existing_file, read_file_text
from dynid.model._xml import check_mjcf_inertials, native_stderr, parse_failure, parse_xml_file, urdf_without_dynamics
from dynid.model.ball_joints import _balls_as_hinges, _given, _mjcf_written_balls, _urdf_balls_as_hinges
from dynid.model.loop_assembly import _assemble, _idle_joints, _lock, _world_aligned
from dynid.model.mechanism import BallJoint, JointCoordinates, JointTerm, LoopClosure, Mechanism, PointCoordinates

__all__ = ["ACTUATOR_TAGS", "load_mechanism_mjcf", "load_mechanism_urdf"]

ACTUATOR_TAGS = ("motor", "position", "velocity", "general", "intvelocity", "damper", "cylinder", "muscle", "adhesion")
"""MJCF ``<actuator>`` elements whose ``joint`` attribute names an actuated joint."""

_EQUALITY_KINDS = {"connect": "3d", "weld": "6d"}

JointRefs = Sequence[str | int]
Independent = JointRefs | JointCoordinates | PointCoordinates | None


# ---------------------------------------------------------------------------- readers
def load_mechanism_mjcf(
    path: str | Path,
    *,
    actuated: JointRefs | None = None,
    independent: Independent = None,
    terms: Sequence[JointTerm] | None = None,
) -> Mechanism:
    """A closed-loop mechanism from an MJCF file with ``<equality><connect>/<weld>`` closures.

    Parameters
    ----------
    path : str or Path
        MJCF file; every body needs an ``<inertial>`` (pinocchio's parser), all bodies must
        hang from one root body under ``<worldbody>``, and joints must be hinges, slides or
        balls (three hinges, see :func:`_balls_as_hinges`).
    actuated : sequence of str or int, optional
        Actuated joints (names, or velocity indices), in actuator order. Default: the
        joints driven by the ``<actuator>`` elements, in file order.
    independent : sequence of str or int, JointCoordinates or PointCoordinates, optional
        Independent coordinates; default: those the file names (``dynid:independent``), else
        the actuated joints (redundant actuation: the best-conditioned subset of them,
        :meth:`Mechanism.rank_charts`).
    terms : sequence of JointTerm, optional
        Joint terms (velocity indices of the loaded model); default: see the module
        docstring. Nominal values from ``damping``/``frictionloss``/``armature`` are given
        to terms named ``fv_<joint>``/``fc_<joint>``/``Ia_<joint>``.

    Returns
    -------
    Mechanism
    """
    path = _existing(path, "robot file")
    root = _parse_xml(path)
    if root.tag != "mujoco":
        raise ModelError(f"{path}: not an MJCF file (its root element is <{root.tag}>, not <mujoco>)")
    check_mjcf_inertials(root, path)
    bodies = root.findall("./worldbody/body")
    if len(bodies) > 1:
        names = [b.get("name", "?") for b in bodies]
        raise ModelError(
            f"{path}: <worldbody> has {len(bodies)} top-level bodies {names}; pinocchio's MJCF parser reads only "
            "the first: put the whole mechanism under one (fixed) root body"
        )
    equalities = _mjcf_equalities(root, path)
    if not equalities:
        raise ModelError(f"{path}: no loop closures (<equality><connect>/<weld>) found: is it a serial robot? use load_robot")
    notes: list[str] = []
    balls = _balls_as_hinges(root, path, notes)
    with native_stderr() as native, tempfile.TemporaryDirectory() as tmp:
        parsed = path
        if balls:  # pinocchio reads MJCF from a file: the rewritten tree goes to a temporary copy
            parsed = Path(tmp) / path.name
            parsed.write_text(ET.tostring(root, encoding="unicode"))
        try:
            model, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(str(parsed))
            failure = None
        except (RuntimeError, ValueError, OSError) as exc:
            failure = exc
    if failure is not None:
        raise ModelError(f"{path}: cannot parse MJCF ({parse_failure(failure, native)})")
    _check_one_dof(model, path, "its type comes from a <default> class: write type=\"ball\" on the joint itself, "
                   "which dynid reads as three hinges")
    if len(constraints) != len(equalities):
        raise ModelError(f"{path}: pinocchio read {len(constraints)} of the {len(equalities)} <equality> closures")
    closures = _mjcf_closures(model, constraints, equalities)
    per_joint = {model.names[j]: model.joints[j].idx_v for j in range(1, model.njoints)}
    damping = {n: float(model.damping[v]) for n, v in per_joint.items()}
    coulomb = {n: float(model.friction[v]) for n, v in per_joint.items()}
    armature = {n: float(model.armature[v]) for n, v in per_joint.items()}
    # these live in joint terms (Mechanism refuses a tree that would add them behind the regressor)
    model.armature = np.zeros(model.nv)
    model.damping = np.zeros(model.nv)
    model.friction = np.zeros(model.nv)
    _mjcf_force_ranges(root, model, per_joint)
    if actuated is None:
        actuated = _mjcf_actuators(root, path, per_joint, notes)
    if independent is None:
        independent = _mjcf_chart(root, path, model)
    return _build(
        model, closures, actuated, independent, terms, (damping, coulomb, armature),
        name=model.name or path.stem, source=str(path), notes=notes, origin=path,
        balls=balls + _mjcf_written_balls(root, path),
    )


def load_mechanism_urdf(
    urdf_path: str | Path,
    yaml_path: str | Path | None = None,
    *,
    actuated: JointRefs | None = None,
    independent: Independent = None,
    terms: Sequence[JointTerm] | None = None,
) -> Mechanism:
    """A closed-loop mechanism from a URDF and a closure YAML (Gepetto format).

    Parameters
    ----------
    urdf_path : str or Path
    yaml_path : str or Path, optional
        Closure file with ``closed_loop`` (list of pairs of frame names), ``type`` (``6d``
        or ``3d`` per pair, case-insensitive) and ``name_mot`` (actuated joint names); optional
        ``joint_name`` / ``joint_type``: joints of the URDF (written there as revolute,
        continuous or fixed placeholders) that are spherical (``SPHERICAL``), read as three
        hinges (:func:`_urdf_balls_as_hinges`). Default: ``robot.yaml`` next to the URDF.
    actuated, independent, terms
        As in :func:`load_mechanism_mjcf` (``actuated`` overrides ``name_mot``).

    Returns
    -------
    Mechanism
        Named after the URDF file, or after its folder when the file is ``robot.urdf``.
    """
    urdf_path = _existing(urdf_path, "robot file")
    yaml_path = _existing(urdf_path.parent / "robot.yaml" if yaml_path is None else yaml_path, "closure file")
    xml, dynamics = urdf_without_dynamics(urdf_path)
    pairs, kinds, motors, spherical = _read_closure_yaml(yaml_path, need_motors=actuated is None)
    notes: list[str] = []
    balls: list[BallJoint] = []
    if spherical:
        xml, balls, dynamics = _urdf_balls_as_hinges(xml, spherical, dynamics, urdf_path, yaml_path, notes)
    with native_stderr() as native:
        try:
            model = pin.buildModelFromXML(_continuous_as_revolute(xml))
            failure = None
        except (RuntimeError, ValueError, OSError) as exc:
            failure = exc
    if failure is not None:
        raise ModelError(f"{urdf_path}: cannot parse URDF ({parse_failure(failure, native)})")
    closures = [_frame_closure(model, a, b, kind, yaml_path, urdf_path) for (a, b), kind in zip(pairs, kinds)]
    _check_one_dof(model, urdf_path, "a spherical joint at a cut is a '3d' closure; elsewhere name it in the YAML's "
                   "joint_name with joint_type SPHERICAL")
    if actuated is None:
        actuated = motors
    damping = {n: d for n, (d, _) in dynamics.items()}
    coulomb = {n: f for n, (_, f) in dynamics.items()}
    name = urdf_path.parent.name if urdf_path.stem == "robot" else urdf_path.stem
    return _build(
        model, closures, actuated, independent, terms, (damping, coulomb, {}),
        name=name, source=f"{urdf_path} + {yaml_path.name}", notes=notes, origin=yaml_path, balls=balls,
    )


# ---------------------------------------------------------------------------- file helpers
def _existing(path: str | Path, what: str) -> Path:
    return existing_file(path, what)


def _continuous_as_revolute(xml: str) -> str:
    """URDF text with continuous joints (pinocchio: nq 2) turned into revolute joints limited
    to ±π, as :func:`dynid.model.loading.load_robot` does, keeping all frames intact."""
    root = ET.fromstring(xml)
    for joint in root.iter("joint"):
        if joint.get("type") == "continuous":
            joint.set("type", "revolute")
            limit = joint.find("limit")
            limit = ET.SubElement(joint, "limit", effort="1000", velocity="100") if limit is None else limit
            limit.set("lower", repr(-np.pi))
            limit.set("upper", repr(np.pi))
    return ET.tostring(root, encoding="unicode")


def _parse_xml(path: Path) -> ET.Element:
    return parse_xml_file(path)


def _check_one_dof(model: pin.Model, path: Path, hint: str) -> None:
    for j in range(1, model.njoints):
        jm = model.joints[j]
        if jm.nv == 1 and jm.nq == 1:
            continue
        short, name = jm.shortname(), model.names[j]
        if "Composite" in short:
            raise ModelError(
                f"{path}: joint {name!r} combines several joints of one body; give each joint its own "
                "body (massless intermediate bodies)"
            )
        if short == "JointModelFreeFlyer":
            hint = "a floating body is not supported (chain 1-DOF joints through massless bodies)"
        kind = "a ball joint" if short == "JointModelSpherical" else "a free joint" if short == "JointModelFreeFlyer" else short
        raise ModelError(f"{path}: joint {name!r} is {kind} ({jm.nv} DOF); mechanisms need 1-DOF joints: {hint}")


def _mjcf_chart(root: ET.Element, path: Path, model: pin.Model) -> Independent:
    """The independent coordinates written by :func:`dynid.io.export.write_mjcf` in
    ``<custom><text name="dynid:independent" data="j1 j2"/>`` (joint names) or
    ``<text name="dynid:independent_point" data="body=B pos=x y z axes=0 1"/>`` (a point of
    body ``B`` [m, in its frame], world axes); None when the file has neither."""
    for text in root.findall("./custom/text"):
        name, data = text.get("name", ""), text.get("data", "")
        if name == "dynid:independent":
            return data.split()
        if name != "dynid:independent_point":
            continue
        fields = dict(re.findall(r"(\w+)=([^=]*?)(?=\s+\w+=|$)", data.strip()))
        try:
            body = fields["body"].strip()
            pos = np.array([float(v) for v in fields["pos"].split()])
            axes = tuple(int(v) for v in fields["axes"].split())
        except (KeyError, ValueError) as exc:
            raise ModelError(f"{path}: <text name='dynid:independent_point' data={data!r}>: expected "
                             f"'body=B pos=x y z axes=0 1' ({exc})") from None
        if pos.shape != (3,) or not model.existBodyName(body):
            raise ModelError(f"{path}: <text name='dynid:independent_point'>: {'no body ' + repr(body) if pos.shape == (3,) else 'pos needs 3 numbers'}")
        frame = model.frames[model.getBodyId(body)]
        return PointCoordinates(int(frame.parentJoint), frame.placement * pin.SE3(np.eye(3), pos), axes)
    return None


def _mjcf_equalities(root: ET.Element, path: Path) -> list[dict]:
    out = []
    for eq in root.iter("equality"):
        for el in eq:
            if not isinstance(el.tag, str):  # comments
                continue
            if el.tag not in _EQUALITY_KINDS:
                raise ModelError(
                    f"{path}: <equality><{el.tag}> {el.get('name', '')!r} is not supported (pinocchio ignores it); "
                    "only <connect> and <weld> loop closures"
                )
            if el.get("body1") is None:
                raise ModelError(f"{path}: <{el.tag}> {el.get('name', '')!r} needs body1 (site-based closures are not supported)")
            body2 = el.get("body2") or "world"
            relpose = el.get("relpose")
            explicit = relpose is not None and _given(" ".join(relpose.split()[3:]))  # a zero quaternion: from qpos0
            out.append({"kind": _EQUALITY_KINDS[el.tag], "name": el.get("name") or f"{el.get('body1')}-{body2}",
                        "body1": el.get("body1"), "body2": body2, "relpose": el.tag == "weld" and explicit})
    return out


def _body_joint(model: pin.Model, body: str) -> int | None:
    if body == "world" or not model.existFrame(body, pin.FrameType.BODY):
        return 0 if body == "world" else None
    return int(model.frames[model.getFrameId(body, pin.FrameType.BODY)].parentJoint)


def _body_frame(model: pin.Model, body: str) -> pin.SE3:
    """Placement of MJCF body ``body`` in the frame of its pinocchio joint (not the identity when
    the body's joint has a ``pos``: pinocchio puts the joint frame at the joint's position)."""
    if body == "world" or not model.existFrame(body, pin.FrameType.BODY):
        return pin.SE3.Identity()
    return pin.SE3(model.frames[model.getFrameId(body, pin.FrameType.BODY)].placement)


def _mjcf_closures(model: pin.Model, constraints, equalities: list[dict]) -> list[LoopClosure]:
    """One :class:`LoopClosure` per pinocchio constraint, named after its XML element.

    pinocchio orders the constraints by name and leaves ``cm.name`` empty, so each is
    matched to the first unused element of the same type and joints.

    MuJoCo gives a ``<connect>`` anchor and a ``<weld>`` relpose in the frame of *body1*;
    pinocchio 4's ``buildModelAndLegacyConstraintsFromMJCF`` puts them in the frame of body1's
    *joint*, which is not the body's frame when that joint has a ``pos`` (pinocchio places the
    joint frame at the joint's position, the body frame stays where the file puts it), and then
    computes the point on body2 at ``qpos0`` from that misplaced point: a loop that closes, with
    links of other lengths than the file's (seen on a ball joint with ``pos``, which dynid's
    rewrite passes on to its hinges). Corrected here: the body1 side is composed with body1's
    placement in its joint (body2's likewise for a weld with an explicit ``relpose``), and the body2
    side of a ``<connect>`` (or of a weld without ``relpose``) is recomputed at ``qpos0``, MuJoCo's
    rule. Without joint offsets nothing changes.
    """
    data = model.createData()
    q0 = model.referenceConfigurations["qpos0"] if "qpos0" in model.referenceConfigurations else pin.neutral(model)
    pin.forwardKinematics(model, data, q0)
    kinds = {pin.ContactType.CONTACT_3D: "3d", pin.ContactType.CONTACT_6D: "6d"}
    used: set[int] = set()
    out = []
    for k, cm in enumerate(constraints):
        kind = kinds.get(cm.type)
        if kind is None:  # pragma: no cover - pinocchio only builds these two
            raise ModelError(f"unsupported constraint type {cm.type}")
        j1, j2 = int(cm.joint1_id), int(cm.joint2_id)
        name = cm.name or f"closure{k + 1}"
        match = None
        for i, eq in enumerate(equalities):
            joints = (_body_joint(model, eq["body1"]), _body_joint(model, eq["body2"]))
            if i not in used and eq["kind"] == kind and joints == (j1, j2):
                used.add(i)
                name, match = eq["name"], eq
                break
        pa, pb = pin.SE3(cm.joint1_placement), pin.SE3(cm.joint2_placement)
        if match is not None:
            f1, f2 = _body_frame(model, match["body1"]), _body_frame(model, match["body2"])
            if not (f1.isIdentity(1e-15) and f2.isIdentity(1e-15)):
                pa = f1 * pa
                if match["relpose"]:
                    pb = f2 * pb
                else:  # the point (frame) on body2 where body1's is at qpos0
                    pb = data.oMi[j2].actInv(data.oMi[j1] * pa)
        out.append(LoopClosure(name, j1, pa, j2, pb, kind))
    return out


def _mjcf_force_ranges(root: ET.Element, model: pin.Model, joints: dict[str, int]) -> None:
    """The effort limit of each joint an actuator with a ``forcerange`` drives (MuJoCo's
    ``forcelimited`` "auto": limited when the range is given; "false": not), written as the actuator's
    largest force times its gear, the joint-side effort (pinocchio reads the joint's own
    ``actuatorfrcrange``, not the actuator's): the smaller of the two when both are given. Only
    attributes on the actuator itself; a range from a ``<default>`` class is not read."""
    for act in root.iter("actuator"):
        for el in act:
            joint = el.get("joint") or el.get("jointinparent") if isinstance(el.tag, str) else None
            rng = el.get("forcerange")
            if joint not in joints or rng is None or el.get("forcelimited", "auto") == "false":
                continue
            try:
                lo, hi = (float(x) for x in rng.split())
                gear = abs(float((el.get("gear") or "1").split()[0]))
            except ValueError:
                continue  # MuJoCo refuses such a file; the limit is then not used for anything here
            effort = max(abs(lo), abs(hi)) * gear
            v = joints[joint]
            have = float(model.effortLimit[v])
            if effort > 0 and not (0 < have < effort):
                model.effortLimit[v] = effort


def _mjcf_actuators(root: ET.Element, path: Path, joints: dict[str, int], notes: list[str]) -> list[str]:
    names = []
    for act in root.iter("actuator"):
        for el in act:
            if not isinstance(el.tag, str) or el.tag not in ACTUATOR_TAGS:
                continue
            label = el.get("name") or f"<{el.tag}> #{len(names) + 1}"
            joint = el.get("joint") or el.get("jointinparent")
            if joint is None:
                raise ModelError(f"{path}: actuator {label!r} drives no joint (tendon/site/body transmissions are not supported)")
            if joint not in joints:
                raise ModelError(f"{path}: actuator {label!r} drives {joint!r}, which is not a joint; joints: {list(joints)}")
            gear = (el.get("gear") or "1").split()
            if gear and float(gear[0]) != 1.0:
                notes.append(f"actuator {label} has gear {gear[0]}: actuator forces are expressed on the joint side")
            names.append(joint)
    if not names:
        raise ModelError(f"{path}: no <actuator> drives a joint; give the actuated joints explicitly")
    return names


# ---------------------------------------------------------------------------- closure YAML
def _read_closure_yaml(path: Path, *, need_motors: bool) -> tuple[list[tuple[str, str]], list[str], list[str], list[str]]:
    doc = _load_yaml(path)
    if not isinstance(doc, dict):
        raise ModelError(f"{path}: the closure file must be a mapping with keys closed_loop, type, name_mot")
    required = ["closed_loop", "type"] + (["name_mot"] if need_motors else [])
    missing = [k for k in required if k not in doc]
    if missing:
        raise ModelError(f"{path}: missing key(s) {missing} (Gepetto closure format: closed_loop, type, name_mot)")
    loops, types = doc["closed_loop"], doc["type"]
    if not isinstance(loops, list) or not loops:
        raise ModelError(f"{path}: 'closed_loop' must be a non-empty list of [frame_a, frame_b] pairs")
    if not isinstance(types, list):
        raise ModelError(f"{path}: 'type' must be a list with one '6d' or '3d' per pair")
    if len(loops) != len(types):
        raise ModelError(f"{path}: 'closed_loop' has {len(loops)} pair(s) but 'type' has {len(types)} entries")
    pairs = []
    for pair in loops:
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(s, str) for s in pair)):
            raise ModelError(f"{path}: closed_loop entry {pair!r} is not a pair of frame names")
        pairs.append((pair[0], pair[1]))
    kinds = []
    for pair, t in zip(pairs, types):
        kind = str(t).strip().lower()
        if kind not in ("3d", "6d"):
            raise ModelError(f"{path}: closure type {t!r} of {list(pair)} is unknown; use '6d' or '3d'")
        kinds.append(kind)
    motors = doc.get("name_mot", [])
    if not isinstance(motors, list) or not all(isinstance(s, str) for s in motors):
        raise ModelError(f"{path}: 'name_mot' must be a list of joint names")
    return pairs, kinds, motors, _spherical_joints(doc, path)


def _spherical_joints(doc: dict, path: Path) -> list[str]:
    """The YAML's ``joint_name`` whose ``joint_type`` is ``SPHERICAL`` (or ``ball``), Gepetto's keys."""
    names, types = doc.get("joint_name", []), doc.get("joint_type", [])
    for key, value in (("joint_name", names), ("joint_type", types)):
        if not isinstance(value, list) or not all(isinstance(s, str) for s in value):
            raise ModelError(f"{path}: {key!r} must be a list of strings")
    if len(names) != len(types):
        raise ModelError(f"{path}: 'joint_name' has {len(names)} entries but 'joint_type' has {len(types)}")
    bad = [t for t in types if t.strip().lower() not in ("spherical", "ball")]
    if bad:
        raise ModelError(f"{path}: joint_type {bad[0]!r} is not supported; use 'SPHERICAL' (a universal joint is two "
                         "revolute joints through a link in the URDF)")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ModelError(f"{path}: joint_name lists {dup} more than once")
    return list(names)


def _load_yaml(path: Path):
    import yaml

    try:
        return yaml.safe_load(read_file_text(path, "closure file"))
    except yaml.YAMLError as exc:
        raise ModelError(f"{path}: invalid YAML ({' '.join(str(exc).split())})") from None


def _frame_closure(model: pin.Model, fa: str, fb: str, kind: str, yaml_path: Path, urdf_path: Path) -> LoopClosure:
    missing = [f for f in (fa, fb) if not model.existFrame(f)]
    if missing:
        names = [f.name for f in model.frames if f.name != "universe"]
        hint = [n for n in names if "loop" in n.lower()] or names
        more = ", ..." if len(hint) > 8 else ""
        raise ModelError(
            f"{yaml_path}: closure frame(s) {missing} not found in {urdf_path.name}; frames include {', '.join(hint[:8])}{more}"
        )
    sides = [model.frames[model.getFrameId(f)] for f in (fa, fb)]
    return LoopClosure(f"{fa}-{fb}", int(sides[0].parentJoint), pin.SE3(sides[0].placement),
                       int(sides[1].parentJoint), pin.SE3(sides[1].placement), kind)


# ---------------------------------------------------------------------------- building the mechanism
def _velocity_indices(model: pin.Model, refs: JointRefs, what: str, origin: Path) -> list[int]:
    names = list(model.names)[1:]
    out = [names.index(r) if isinstance(r, str) and r in names else r for r in refs]  # 1-DOF: index = velocity index
    bad = [r for r, v in zip(refs, out) if not isinstance(v, (int, np.integer)) or not 0 <= v < model.nv]
    if bad:
        raise ModelError(f"{origin}: {what} {bad} are not joints of the model; joints: {names}")
    return [int(v) for v in out]


def _default_terms(model: pin.Model, actuated: list[int], values: tuple[dict, dict, dict],
                   ball_hinges: set[str] = frozenset()) -> list[JointTerm]:
    damping, coulomb, armature = values
    terms = []
    for j in range(1, model.njoints):
        n, v = model.names[j], model.joints[j].idx_v
        if n in ball_hinges and v not in actuated:  # ball joints: no friction unless the file gives damping
            if damping.get(n, 0.0):
                terms.append(JointTerm(f"fv_{n}", "viscous", (v,)))
            continue
        if v in actuated or armature.get(n, 0.0):
            terms.append(JointTerm(f"Ia_{n}", "inertia", (v,)))
        terms.append(JointTerm(f"fv_{n}", "viscous", (v,)))
        if v in actuated or coulomb.get(n, 0.0):
            terms.append(JointTerm(f"fc_{n}", "coulomb", (v,)))
    return terms


def _build(model, closures, actuated, independent, terms, values, *, name, source, notes, origin, balls=()) -> Mechanism:
    act = _velocity_indices(model, actuated, "actuated joints", origin)
    # an MJCF file written at an assembled configuration (``ref`` on each joint, as dynid's
    # export does) says so in its qpos0; start the assembly there
    start = model.referenceConfigurations["qpos0"] if "qpos0" in model.referenceConfigurations else pin.neutral(model)
    try:
        q = _assemble(model, closures, start, name)
    except ModelError as exc:
        raise ModelError(f"{source}: {exc}") from None
    locked = _idle_joints(model, closures, act, q)
    if locked:
        act_names = [model.names[v + 1] for v in act]  # 1-DOF joints: joint index = velocity index + 1
        model, closures, q = _lock(model, closures, locked, q, name, notes)
        act = [model.joints[model.getJointId(n)].idx_v for n in act_names]
    closures = _world_aligned(model, closures, q)
    if independent is None or isinstance(independent, (JointCoordinates, PointCoordinates)):
        indep = independent
    else:
        indep = JointCoordinates(tuple(_velocity_indices(model, independent, "independent coordinates", origin)))
    if terms is None:
        terms = _default_terms(model, act, values, {h for b in balls for h in b.hinges})
    tnames = {t.name for t in terms}
    in_file = {f"{p}_{n}": float(v) for p, table in zip(("fv", "fc", "Ia"), values) for n, v in table.items() if v}
    nominal = {k: v for k, v in in_file.items() if k in tnames}
    if len(nominal) < len(in_file):
        notes.append(f"file values without a joint term are not used: {[k for k in in_file if k not in tnames]}")
    massless = [j for j in range(1, model.njoints) if not np.any(model.inertias[j].toDynamicParameters())]
    chart = {h for b in balls for h in b.hinges[:2]}
    plain = [model.names[j] for j in massless if model.names[j] not in chart]
    if plain:
        notes.append(f"bodies of joints {plain} have no inertia in the file: no parameters")
    for b in balls:
        notes.append(f"ball joint {b.name} (body {b.body}): hinges {', '.join(b.hinges)} through two massless bodies, "
                     f"exact away from {b.hinges[1]} = ±90 deg (refused within 10 deg)")
    try:
        return Mechanism(
            model, tuple(closures), actuated=tuple(act), independent=indep, terms=tuple(terms),
            massless=tuple(massless), nominal_terms=nominal, q_guess=q, name=name, source=source, notes=tuple(notes),
            ball_joints=tuple(balls),
        )
    except ModelError as exc:
        raise ModelError(f"{source}: {exc}") from None
