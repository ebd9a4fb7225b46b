"""Export identified standard parameters as robot description files.

* :func:`write_urdf`: a serial (tree) :class:`~dynid.model.robot.RobotModel` as URDF
  (`URDF XML specification <http://wiki.ros.org/urdf/XML>`_: ``<link>/<inertial>``,
  ``<joint>`` with ``<origin>``, ``<axis>``, ``<limit>``, ``<dynamics>``).
* :func:`write_mjcf`: a closed-loop :class:`~dynid.model.mechanism.Mechanism` as MJCF
  (`MuJoCo XML reference <https://mujoco.readthedocs.io/en/stable/XMLreference.html>`_:
  ``<body>``, ``<joint>``, ``<inertial>``, ``<equality><connect>/<weld>``,
  ``<actuator><motor>``), read back by :func:`dynid.model.mechanism_io.load_mechanism_mjcf`.

Both files are generated from the pinocchio model (never by editing a source file): one
link/body per pinocchio joint, placed by ``model.jointPlacements``, so the link (body)
frame **is** the joint frame. The standard parameters of a body,
``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` about the joint-frame origin, are
written as mass [kg], centre of mass :math:`c = h/m` [m] and inertia about the centre of
mass [kg·m²], both formats' convention:

.. math::

    I_c = I_o - m\\,(c^T c\\,\\mathbb{1} - c\\,c^T).

A body with zero mass (allowed with zero first moments) is written with mass 0, its
centre of mass at the origin and its rotational inertia as is; pinocchio's parsers read
that back exactly. Numbers are written with ``repr`` (17 significant digits), so a
re-read model reproduces the parameters to rounding (about 1e-16 relative).

What the formats cannot hold is written as XML comments starting with ``dynid:`` so a
reader of the file sees it: rotor inertias and torque offsets (URDF), motor-side terms of
coupled transmissions, asymmetric friction and offsets (MJCF), independent coordinates
and notes of a mechanism, and a flag on every body whose parameters are not physically
consistent (negative mass, inertia about the centre of mass not positive semi-definite or
violating the triangle inequality). Such bodies are still written by :func:`write_urdf` and
:func:`write_mjcf` (an export of estimates), except where the MJCF format itself forbids the
value (see :func:`write_mjcf`); :func:`write_model`, which writes the ``model.urdf`` /
``model.mjcf`` of ``dynid identify``, refuses them.

Files are written whole: the text is built first, then written to a temporary file in the
target folder and moved into place.
"""

from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.base_parameters import body_violation, inertia_violation
from dynid.model.closures import PointCoordinates
from dynid.model.mechanism import Mechanism
from dynid.model.robot import RobotModel

__all__ = [
    "RANGE_CONVENTIONS", "inertia_about_com", "write_mjcf", "write_model", "write_urdf"]

RANGE_CONVENTIONS = ("pinocchio", "mujoco")
"""How :func:`write_mjcf` writes joint ranges of joints with a ``ref`` (see there)."""

_DBL_MAX = float(np.finfo(float).max)
_UNIT = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}


# ---------------------------------------------------------------------------- numbers and inertias
def _num(x: float) -> str:
    x = float(x)
    return "0" if x == 0.0 else repr(x)


def _vec(v: Sequence[float]) -> str:
    return " ".join(_num(x) for x in v)


def inertia_about_com(block: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """Mass, centre of mass and inertia about it from one body's standard parameters.

    Parameters
    ----------
    block : array, shape (10,)
        ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``: mass [kg], first moments [kg·m]
        and inertia about the joint-frame origin [kg·m²] (pinocchio's order).

    Returns
    -------
    m : float
        Mass [kg].
    c : array, shape (3,)
        Centre of mass :math:`h/m` [m] in the joint frame (zero when ``m == 0``).
    I_c : array, shape (3, 3)
        Inertia about the centre of mass, joint-frame axes [kg·m²]:
        :math:`I_o - m(c^Tc\\,\\mathbb{1} - cc^T)`.

    Raises
    ------
    ModelError
        Zero mass with non-zero first moments (no centre of mass exists).
    """
    block = np.asarray(block, dtype=float)
    m, h = float(block[0]), block[1:4]
    ixx, ixy, iyy, ixz, iyz, izz = block[4:10]
    I_o = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if m == 0.0:
        if np.any(h != 0.0):
            raise ModelError(f"zero mass with non-zero first moments {h.tolist()}: no centre of mass to write")
        return 0.0, np.zeros(3), I_o
    c = h / m
    return m, c, I_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c))


def _nonphysical(m: float, I_c: FloatArray) -> str:
    """Why a body's parameters are not physically consistent ('' when they are):
    :func:`dynid.model.base_parameters.inertia_violation`."""
    return inertia_violation(m, I_c)


# ---------------------------------------------------------------------------- joints and names
def _joint_kind(model: pin.Model, j: int) -> tuple[str, FloatArray]:
    """URDF-style type (``revolute``/``prismatic``/``continuous``) and unit axis of joint ``j``."""
    jm = model.joints[j]
    short = jm.shortname()
    if short in ("JointModelRX", "JointModelRY", "JointModelRZ"):
        return "revolute", _UNIT[short[-1]]
    if short in ("JointModelPX", "JointModelPY", "JointModelPZ"):
        return "prismatic", _UNIT[short[-1]]
    if short in ("JointModelRUBX", "JointModelRUBY", "JointModelRUBZ"):
        return "continuous", _UNIT[short[-1]]
    kinds = {
        "JointModelRevoluteUnaligned": "revolute",
        "JointModelPrismaticUnaligned": "prismatic",
        "JointModelRevoluteUnboundedUnaligned": "continuous",
    }
    if short in kinds:
        axis = np.asarray(jm.extract().axis, dtype=float)
        return kinds[short], axis / np.linalg.norm(axis)
    raise ModelError(
        f"joint {model.names[j]!r} is a {short}: only revolute, prismatic and continuous 1-DOF joints can be exported"
    )


def _unique(base: str, taken: set[str]) -> str:
    name, k = base, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def _body_names(model: pin.Model, root_default: str) -> list[str]:
    """One link/body name per pinocchio joint (index 0: the base): the BODY frame attached at
    the joint frame when the model has one (a URDF link), else ``<joint>_link``."""
    frames = {}
    for f in model.frames:
        if f.type == pin.FrameType.BODY and f.parentJoint not in frames and f.placement.isIdentity(0.0):
            frames[f.parentJoint] = f.name
    taken: set[str] = set()
    names = [_unique(frames.get(0, root_default), taken)]
    for j in range(1, model.njoints):
        names.append(_unique(frames.get(j, f"{model.names[j]}_link"), taken))
    return names


def _extra_frames(model: pin.Model, body_names: list[str]) -> list[pin.Frame]:
    """Operational frames and BODY frames that are not a joint's own link."""
    own = set(body_names)
    return [
        f for f in model.frames
        if f.type == pin.FrameType.OP_FRAME or (f.type == pin.FrameType.BODY and f.name not in own)
    ]


def _limit(x: float) -> float:
    """Finite value for a URDF limit: ±inf is written as ±DBL_MAX (pinocchio's own default)."""
    return float(np.clip(x, -_DBL_MAX, _DBL_MAX))


def _comment(text: str) -> ET.Element:
    return ET.Comment(" " + " ".join(text.replace("--", "- -").split()) + " ")


def _check_params(params: FloatArray, n: int, what: str) -> FloatArray:
    arr = np.asarray(params, dtype=float)
    if arr.shape != (n,):
        raise InputError(f"{what} has {n} standard parameters; got an array of shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr))
        raise InputError(f"standard parameters contain NaN or infinite values at positions {bad.tolist()}")
    return arr


def _write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same folder."""
    path = Path(path)
    folder = path.parent
    if not folder.is_dir():
        raise InputError(f"output folder does not exist: {folder}")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _to_text(root: ET.Element, header: list[str]) -> str:
    ET.indent(root, space="  ")
    lines = ['<?xml version="1.0" encoding="utf-8"?>', "<!--"]
    lines += ["  " + h.replace("--", "- -") for h in header]
    lines.append("-->")
    return "\n".join(lines) + "\n" + ET.tostring(root, encoding="unicode") + "\n"


def _inertial_comment(m: float, I_c: FloatArray, body: str) -> ET.Element | None:
    why = _nonphysical(m, I_c)
    return _comment(f"dynid: body {body} is not physically consistent ({why})") if why else None


# ---------------------------------------------------------------------------- URDF
def write_model(robot: RobotModel | Mechanism, params: FloatArray, folder: str | Path, *, name: str | None = None,
                notes: Sequence[str] = ()) -> Path:
    """The robot with standard parameters ``params`` as a description a simulator loads:
    ``model.urdf`` for a serial robot, ``model.mjcf`` for a closed-loop mechanism (whose loop
    closures URDF cannot express), in ``folder``; ``notes``: lines for the file's header comment
    (e.g. that the vector is one of many with the same base parameters). Returns the path.

    Unlike :func:`write_urdf` and :func:`write_mjcf` (an export of any estimate, flagged), this is
    the file a simulator is told to trust: every body must be physically consistent (mass >= 0,
    inertia about the centre of mass positive semidefinite and within the triangle inequalities,
    :func:`~dynid.model.base_parameters.body_violation`), else :class:`~dynid.errors.InputError`
    and nothing is written (:func:`dynid.estimation.consistent_standard.consistent_standard` gives
    such a vector from base parameters)."""
    folder = Path(folder)
    params = _check_params(params, robot.n_standard_params, f"{type(robot).__name__} {robot.name!r}")
    bad = [(k, why) for k, blk in enumerate(robot.body_blocks()) if (why := body_violation(params[blk]))]
    if bad:
        k, why = bad[0]
        raise InputError(f"refusing to write model.{'mjcf' if isinstance(robot, Mechanism) else 'urdf'}: "
                         f"{len(bad)} bod{'y is' if len(bad) == 1 else 'ies are'} not physically consistent "
                         f"(body {k + 1}: {why})")
    if isinstance(robot, Mechanism):
        return write_mjcf(robot, params, folder / "model.mjcf", name=name, notes=notes)
    return write_urdf(robot, params, folder / "model.urdf", name=name, notes=notes)


def write_urdf(robot: RobotModel, params: FloatArray, path: str | Path, *, name: str | None = None,
               notes: Sequence[str] = ()) -> Path:
    """Write a serial robot with the given standard parameters as a URDF file.

    Parameters
    ----------
    robot : RobotModel
        Kinematic tree (1-DOF revolute, prismatic or continuous joints) and parameter layout.
    params : array, shape (robot.n_standard_params,)
        Standard parameters in ``robot.layout`` order (see :mod:`dynid.model.robot`).
    path : str or Path
        Output file (its folder must exist); overwritten.
    name : str, optional
        ``<robot name>``; default ``robot.name``.

    Returns
    -------
    Path
        The file written.

    Notes
    -----
    What is written (URDF XML specification):

    * a base link (the root BODY frame's name, else ``base``), then per pinocchio joint a
      link (its BODY frame's name, else ``<joint>_link``) and a joint with ``<origin xyz
      rpy>`` = ``model.jointPlacements[j]`` (roll-pitch-yaw, :math:`R = R_z R_y R_x`),
      ``<axis>`` from the joint type, ``<limit lower upper effort velocity>`` [rad or m,
      N·m or N, rad/s or m/s]; infinite limits are written as ±DBL_MAX (±1.8e308), which
      is pinocchio's own "no limit" and what its URDF parser gives back;
    * ``<inertial>``: mass, ``<origin xyz>`` = centre of mass, ``rpy`` 0, inertia about
      the centre of mass in link axes;
    * ``<dynamics damping>`` = viscous ``fv`` [N·m·s/rad or N·s/m] and ``friction`` =
      Coulomb ``fc`` [N·m or N], when the layout has them;
    * operational frames (and BODY frames that are not a joint's link) as fixed joints to
      empty links, so tool frames survive.

    Not representable in URDF, written as comments (``<!-- dynid: ... -->``): rotor
    inertia ``Ia`` and torque offset ``off`` per joint (inside the ``<joint>`` element,
    e.g. ``dynid: joint joint_1 Ia=0.2 off=2.3``), motor-side terms of coupled
    transmissions, the transmission itself and gravity.

    Non-physical parameters (negative mass, an inertia about the centre of mass that is
    not positive semi-definite) are written as they are and flagged by a comment; note
    that pinocchio's URDF parser misreads a negative mass (the centre of mass comes back
    wrong) and refuses a negative ``friction``, which dynid's loader
    (:func:`dynid.model.loading.load_robot`) strips before parsing and keeps as nominal
    Coulomb friction.

    pinocchio's URDF parser orders the joints of the re-read model itself (depth first);
    for a chain that is the original order, for a tree compare joints by name.
    """
    if not isinstance(robot, RobotModel):
        raise ModelError(f"write_urdf needs a RobotModel, got {type(robot).__name__} (use write_mjcf for a Mechanism)")
    model = robot.pin_model
    lay = robot.layout
    params = _check_params(params, lay.n_params, f"robot {robot.name!r}")
    kinds = [_joint_kind(model, j) if j else ("", np.zeros(3)) for j in range(model.njoints)]
    links = _body_names(model, "base")
    extras = {e: params[idx] for e, idx in lay.extra_index.items()}

    root = ET.Element("robot", name=name or robot.name)
    ET.SubElement(root, "link", name=links[0])
    for j in range(1, model.njoints):
        kind, axis = kinds[j]
        v = model.joints[j].idx_v
        jname = model.names[j]
        link = ET.SubElement(root, "link", name=links[j])
        try:
            m, c, I_c = inertia_about_com(params[10 * (j - 1) : 10 * j])
        except ModelError as exc:
            raise ModelError(f"body of joint {jname!r}: {exc}") from None
        flag = _inertial_comment(m, I_c, links[j])
        if flag is not None:
            link.append(flag)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", xyz=_vec(c), rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=_num(m))
        ET.SubElement(
            inertial, "inertia", ixx=_num(I_c[0, 0]), ixy=_num(I_c[0, 1]), ixz=_num(I_c[0, 2]),
            iyy=_num(I_c[1, 1]), iyz=_num(I_c[1, 2]), izz=_num(I_c[2, 2]),
        )

        joint = ET.SubElement(root, "joint", name=jname, type=kind)
        slide = kind == "prismatic"
        force = "N" if slide else "N m"
        lost = {"Ia": ("Ia", f"rotor inertia [{'kg' if slide else 'kg m^2'}]"),
                "offset": ("off", f"offset [{force}]"),
                **{e: (e, f"asymmetric {'viscous' if e[1] == 'v' else 'Coulomb'} friction "
                          f"[{force}{' s/' + ('m' if slide else 'rad') if e[1] == 'v' else ''}]")
                   for e in ("fv+", "fv-", "fc+", "fc-")}}
        lost = {e: lost[e] for e in lost if e in extras}
        if lost:
            values = " ".join(f"{p}={_num(extras[e][v])}" for e, (p, _) in lost.items())
            what = ", ".join(f"{p}: {w}" for p, w in lost.values())
            joint.append(_comment(f"dynid: joint {jname} {values} ({what}; no URDF element)"))
        ET.SubElement(joint, "parent", link=links[model.parents[j]])
        ET.SubElement(joint, "child", link=links[j])
        M = model.jointPlacements[j]
        ET.SubElement(joint, "origin", xyz=_vec(M.translation), rpy=_vec(pin.rpy.matrixToRpy(M.rotation)))
        ET.SubElement(joint, "axis", xyz=_vec(axis))
        lim = {}
        if kind != "continuous":
            lim["lower"] = _num(_limit(model.lowerPositionLimit[model.joints[j].idx_q]))
            lim["upper"] = _num(_limit(model.upperPositionLimit[model.joints[j].idx_q]))
        lim["effort"] = _num(_limit(model.effortLimit[v]))
        lim["velocity"] = _num(_limit(model.velocityLimit[v]))
        ET.SubElement(joint, "limit", lim)
        dyn = {a: _num(extras[e][v]) for e, a in (("fv", "damping"), ("fc", "friction")) if e in extras}
        if dyn:
            ET.SubElement(joint, "dynamics", dyn)

    taken_joints = set(model.names)
    taken_links = set(links)
    for f in _extra_frames(model, links):
        parent = model.frames[f.parentFrame] if 0 < f.parentFrame < len(model.frames) else None
        fixed_parent = parent is not None and parent.type == pin.FrameType.FIXED_JOINT  # a merged URDF fixed joint
        base = parent.name if fixed_parent else f"{f.name}_joint"
        lname = _unique(f.name, taken_links)
        fixed = ET.SubElement(root, "joint", name=_unique(base, taken_joints), type="fixed")
        ET.SubElement(fixed, "parent", link=links[f.parentJoint])
        ET.SubElement(fixed, "child", link=lname)
        ET.SubElement(fixed, "origin", xyz=_vec(f.placement.translation), rpy=_vec(pin.rpy.matrixToRpy(f.placement.rotation)))
        ET.SubElement(root, "link", name=lname)

    header = [
        f"Written by dynid (dynid.io.export.write_urdf) from the standard parameters of {robot.name!r}"
        + (f" ({robot.source})" if robot.source else "") + ".",
        "Units SI, angles in rad. <inertial>: mass [kg], origin = centre of mass [m], inertia about the",
        "centre of mass in link axes [kg m^2]. <dynamics>: damping = viscous friction fv, friction = Coulomb fc.",
    ]
    if "Ia" in extras or "offset" in extras:
        header.append("Rotor inertia Ia and torque offsets have no URDF element: see the 'dynid: joint' comments.")
    if any(len(idx) for idx in lay.motor_index.values()):
        terms = [f"{lay.names[i]}={_num(params[i])}" for idx in lay.motor_index.values() for i in idx]
        header.append(f"Motor-side terms of coupled motors (no URDF element): {' '.join(terms)}")
    if robot.transmission is not None:
        header.append("The robot has a transmission (gear ratios, couplings): not part of URDF, not written.")
    g = np.asarray(model.gravity.linear)
    if not np.allclose(g, [0.0, 0.0, -9.81]):
        header.append(f"Gravity of the model: {_vec(g)} m/s^2 (URDF has no gravity).")
    header += [f"dynid: {n}" for n in notes]
    return _write_text(path, _to_text(root, header))


# ---------------------------------------------------------------------------- MJCF
def _joint_motion(kind: str, axis: FloatArray, q: float) -> pin.SE3:
    if kind == "prismatic":
        return pin.SE3(np.eye(3), axis * q)
    return pin.SE3(pin.exp3(axis * q), np.zeros(3))


def _pose_attrs(M: pin.SE3) -> dict[str, str]:
    out = {"pos": _vec(M.translation)}
    if not np.array_equal(M.rotation, np.eye(3)):
        x, y, z, w = pin.Quaternion(M.rotation).coeffs()
        out["quat"] = _vec((w, x, y, z))
    return out


def _joint_terms(mech: Mechanism, params: FloatArray) -> tuple[dict[str, FloatArray], list[str]]:
    """Per-joint damping, frictionloss and armature (sums of symmetric terms), and the
    descriptions of the terms MJCF cannot hold."""
    nv, names = mech.nv, mech.joint_names
    attrs = {"damping": np.zeros(nv), "frictionloss": np.zeros(nv), "armature": np.zeros(nv)}
    target = {"viscous": "damping", "coulomb": "frictionloss", "inertia": "armature"}
    lost = []
    for k, t in enumerate(mech.terms):
        value = params[mech.n_body_params + k]
        joints = ", ".join(names[v] for v in t.joints)
        if t.weights:
            lost.append(f"term {t.name} ({t.kind}) = {_num(value)} acts on the combined velocity "
                        f"{' + '.join(f'{_num(w)} {names[v]}' for v, w in zip(t.joints, t.weights))} (a coupled motor): "
                        "no MJCF attribute, not in the model")
        elif t.kind in target:
            attrs[target[t.kind]][list(t.joints)] += value
            if len(t.joints) > 1:
                lost.append(f"term {t.name} ({t.kind}) = {_num(value)} is shared by joints {joints}: written on each "
                            "(the re-read mechanism has one term per joint)")
        else:
            lost.append(f"term {t.name} ({t.kind}, joints {joints}) = {_num(value)}: no MJCF attribute, not in the model")
    return attrs, lost


def write_mjcf(
    mech: Mechanism,
    params: FloatArray,
    path: str | Path,
    *,
    name: str | None = None,
    range_convention: str = "pinocchio",
    notes: Sequence[str] = (),
) -> Path:
    """Write a closed-loop mechanism with the given standard parameters as an MJCF file.

    The file is read back by :func:`dynid.model.mechanism_io.load_mechanism_mjcf` (and
    pinocchio's ``buildModelAndLegacyConstraintsFromMJCF``) into the same tree, body
    inertias, loop closures and actuated joints.

    Parameters
    ----------
    mech : Mechanism
        Kinematic tree, loop closures, actuated joints and joint terms.
    params : array, shape (mech.n_standard_params,)
        Standard parameters in ``mech.parameter_names`` order.
    path : str or Path
        Output file (its folder must exist); overwritten.
    name : str, optional
        ``<mujoco model>``; default ``mech.name``.
    range_convention : {"pinocchio", "mujoco"}
        How joint ranges are written for joints with a ``ref`` (below): ``"pinocchio"``
        (default) writes ``limits + ref`` because pinocchio's MJCF parser (4.x) subtracts
        ``ref`` from ``range``; pinocchio and dynid then read back the original limits.
        ``"mujoco"`` writes the limits as they are, MuJoCo's convention (``range``
        bounds the absolute ``qpos``); pinocchio then reads ``limits - ref``.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    InputError
        Wrong number of parameters, NaN/inf, unknown ``range_convention``, missing folder.
    ModelError
        A body with a negative mass, or a negative Coulomb (``frictionloss``) value:
        MJCF forbids both (pinocchio's parser and MuJoCo's compiler refuse the file). A
        body whose inertia about the centre of mass has a negative diagonal entry: MuJoCo
        refuses it and pinocchio 4.1's parser reads it as 0, so the file would not hold the
        parameters (found exporting an OLS result's closest-to-nominal vector, issue 20).

    Notes
    -----
    What is written (MuJoCo XML reference):

    * ``<compiler angle="radian" autolimits="true" inertiafromgeom="false"/>`` and
      ``<option gravity>``;
    * one root body (``base``, no joint, zero mass) under ``<worldbody>``, and per
      pinocchio joint a nested ``<body>`` with one ``<joint>`` (``hinge``/``slide``,
      ``axis``, ``range`` [rad or m], ``actuatorfrcrange`` for a finite effort limit) at
      the body origin, so the body frame is the joint frame;
    * the bodies are posed at the mechanism's assembled reference configuration
      ``q_ref``, with ``ref = q_ref`` on each joint: MuJoCo and pinocchio compute the
      second side of a ``<connect>`` at ``qpos0 = ref``, where the loops are closed;
      joint coordinates are unchanged (pinocchio's and MuJoCo's ``q`` are the
      mechanism's);
    * ``<inertial pos mass fullinertia>``: centre of mass [m], mass [kg], inertia about
      the centre of mass [kg·m²]; massless bodies get mass 0 and zero inertia (pinocchio
      reads them exactly; MuJoCo's compiler wants positive mass and inertia on moving
      bodies: for simulation there, set ``<compiler boundmass boundinertia>``, which
      pinocchio would also apply);
    * ``<equality>``: a ``"3d"`` closure as ``<connect body1 body2 anchor>`` (anchor =
      side-a point in body1's frame); a ``"6d"`` closure as ``<weld body1 body2 anchor
      relpose>`` with ``anchor`` = side-b origin in body2's frame and ``relpose`` =
      :math:`P_a P_b^{-1}`, which is the same frame constraint;
    * ``<actuator>``: one ``<motor joint gear="1">`` per actuated joint, in order;
    * joint terms: the sum of the symmetric ``viscous``, ``coulomb`` and ``inertia``
      terms of a joint as ``damping`` [N·m·s/rad or N·s/m], ``frictionloss`` [N·m or N]
      and ``armature`` [kg·m² or kg]. A term shared by several joints is written on each
      (the re-read mechanism has one term per joint, with the reader's default terms).

    * the independent coordinates, where they are not the actuated joints (a redundantly
      actuated or point-coordinate mechanism), in MJCF's user-data element ``<custom>``:
      ``<text name="dynid:independent" data="qa1 qa2"/>`` or ``<text
      name="dynid:independent_point" data="body=B pos=x y z axes=0 1"/>``, which
      :func:`~dynid.model.mechanism_io.load_mechanism_mjcf` reads back (MuJoCo and pinocchio
      ignore it);
    * ball joints (:class:`~dynid.model.mechanism.BallJoint`) as their three hinges and two
      massless bodies, with ``<custom><text name="dynid:ball" data="ball body hx hy hz"/>``
      so that dynid reads them back as a ball (parameter names, chart check, no default
      friction).

    Not representable in MJCF, written as ``dynid:`` comments: asymmetric friction
    (``viscous+/-``, ``coulomb+/-``) and ``offset`` terms, task coordinates, velocity limits
    and the mechanism's notes.
    Negative damping or armature and inertias that are not physically consistent are
    written (pinocchio reads them; MuJoCo's compiler may refuse them) and flagged.
    """
    if not isinstance(mech, Mechanism):
        raise ModelError(f"write_mjcf needs a Mechanism, got {type(mech).__name__} (use write_urdf for a serial robot)")
    if range_convention not in RANGE_CONVENTIONS:
        raise InputError(f"range_convention must be one of {list(RANGE_CONVENTIONS)}, got {range_convention!r}")
    model = mech.pin_model
    params = _check_params(params, mech.n_standard_params, f"mechanism {mech.name!r}")
    kinds = [_joint_kind(model, j) if j else ("", np.zeros(3)) for j in range(model.njoints)]
    bodies = _body_names(model, "base")
    attrs, lost = _joint_terms(mech, params)
    negative = [mech.joint_names[v] for v in np.flatnonzero(attrs["frictionloss"] < 0.0)]
    if negative:
        raise ModelError(
            f"negative Coulomb friction on joints {negative}: MJCF frictionloss must be >= 0 "
            "(pinocchio and MuJoCo refuse the file); clip the estimates to export them"
        )
    blocks = {j: np.zeros(10) for j in range(1, model.njoints)}
    for k, j in enumerate(mech.bodies):
        blocks[j] = params[10 * k : 10 * k + 10]
    q_ref = np.asarray(mech.q_ref, dtype=float)

    root = ET.Element("mujoco", model=name or mech.name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")
    ET.SubElement(root, "option", gravity=_vec(model.gravity.linear))
    world = ET.SubElement(root, "worldbody")
    elems = {0: ET.SubElement(world, "body", name=bodies[0])}
    ET.SubElement(elems[0], "inertial", pos="0 0 0", mass="0", diaginertia="0 0 0")
    sites = {}
    for f in _extra_frames(model, bodies):
        sites.setdefault(f.parentJoint, []).append(f)
    site_names: set[str] = set()
    for j in range(model.njoints):  # parents come first in a pinocchio model
        if j:
            kind, axis = kinds[j]
            v, iq = model.joints[j].idx_v, model.joints[j].idx_q
            jname = model.names[j]
            ref = float(q_ref[iq])
            pose = model.jointPlacements[j] * _joint_motion(kind, axis, ref)
            body = ET.SubElement(elems[model.parents[j]], "body", name=bodies[j], **_pose_attrs(pose))
            elems[j] = body
            jattr = {"name": jname, "type": "slide" if kind == "prismatic" else "hinge", "axis": _vec(axis)}
            lo, hi = float(model.lowerPositionLimit[iq]), float(model.upperPositionLimit[iq])
            shift = ref if range_convention == "pinocchio" else 0.0
            if max(abs(lo), abs(hi)) < _DBL_MAX:
                jattr["range"] = _vec((lo + shift, hi + shift))
            elif min(abs(lo), abs(hi)) < _DBL_MAX:
                body.append(_comment(f"dynid: joint {jname} has one-sided limits [{_num(lo)}, {_num(hi)}]: written unlimited"))
            if ref != 0.0:
                jattr["ref"] = _num(ref)
            effort = float(model.effortLimit[v])
            if abs(effort) < _DBL_MAX:
                jattr["actuatorfrcrange"] = _vec((-effort, effort))
            for key in ("damping", "frictionloss", "armature"):
                if attrs[key][v] != 0.0:
                    jattr[key] = _num(attrs[key][v])
            ET.SubElement(body, "joint", jattr)
            neg = [key for key in ("damping", "armature") if attrs[key][v] < 0.0]
            if neg:
                body.append(_comment(f"dynid: joint {jname} has negative {' and '.join(neg)} (not physical)"))
            try:
                m, c, I_c = inertia_about_com(blocks[j])
            except ModelError as exc:
                raise ModelError(f"body of joint {jname!r}: {exc}") from None
            if m < 0.0:
                raise ModelError(
                    f"body of joint {jname!r} has a negative mass {m:.6g} kg: MJCF masses must be >= 0 "
                    "(pinocchio and MuJoCo refuse the file)"
                )
            neg_diag = [a for a, x in zip(("Ixx", "Iyy", "Izz"), np.diag(I_c)) if x < 0.0]
            if neg_diag:  # pinocchio 4's MJCF parser reads a negative diagonal entry as 0: the file would lie
                raise ModelError(
                    f"body of joint {jname!r} has a negative {', '.join(neg_diag)} about its centre of mass "
                    f"({', '.join(f'{x:.6g}' for x in np.diag(I_c))} kg*m^2): pinocchio's MJCF parser reads such an "
                    "entry as 0 and MuJoCo refuses it"
                )
            flag = _inertial_comment(m, I_c, bodies[j])
            if flag is not None:
                body.append(flag)
            ET.SubElement(
                body, "inertial", pos=_vec(c), mass=_num(m),
                fullinertia=_vec((I_c[0, 0], I_c[1, 1], I_c[2, 2], I_c[0, 1], I_c[0, 2], I_c[1, 2])),
            )
        for f in sites.get(j, []):
            ET.SubElement(elems[j], "site", name=_unique(f.name, site_names), **_pose_attrs(f.placement))

    equality = ET.SubElement(root, "equality")
    for c in mech.closures:
        if c.kind == "3d":
            ET.SubElement(equality, "connect", name=c.name, body1=bodies[c.joint_a], body2=bodies[c.joint_b],
                          anchor=_vec(c.placement_a.translation))
        else:
            rel = c.placement_a * c.placement_b.inverse()
            x, y, z, w = pin.Quaternion(rel.rotation).coeffs()
            ET.SubElement(equality, "weld", name=c.name, body1=bodies[c.joint_a], body2=bodies[c.joint_b],
                          anchor=_vec(c.placement_b.translation), relpose=_vec((*rel.translation, w, x, y, z)))
    ind = mech.independent
    chart = None  # MJCF's <custom><text> holds the chart, which the format has no element for
    if isinstance(ind, PointCoordinates):
        chart = ("dynid:independent_point", f"body={bodies[ind.joint]} pos={_vec(ind.placement.translation)} "
                                            f"axes={' '.join(str(a) for a in ind.axes)}")
    elif list(ind.joints) != list(mech.actuated):
        chart = ("dynid:independent", " ".join(mech.joint_names[v] for v in ind.joints))
    custom = ET.SubElement(root, "custom") if chart is not None or mech.ball_joints else None
    if chart is not None:
        ET.SubElement(custom, "text", name=chart[0], data=chart[1])
    for b in mech.ball_joints:  # its three hinges are written as such; the record keeps the ball's name and body
        ET.SubElement(custom, "text", name="dynid:ball", data=" ".join((b.name, b.body, *b.hinges)))
    actuator = ET.SubElement(root, "actuator")
    taken: set[str] = set()
    for a in mech.actuated:
        jname = model.names[a + 1]  # 1-DOF joints: joint index = velocity index + 1
        ET.SubElement(actuator, "motor", name=_unique(f"{jname}_motor", taken), joint=jname, gear="1")

    header = [
        f"Written by dynid (dynid.io.export.write_mjcf) from the standard parameters of {mech.name!r}"
        + (f" ({mech.source})" if mech.source else "") + ".",
        "Units SI, angles in rad. Bodies are posed at the assembled configuration q_ref (joint 'ref'),",
        f"joint ranges follow the {range_convention!r} convention for 'ref' (see dynid.io.export.write_mjcf).",
        "<inertial>: centre of mass [m], mass [kg], inertia about the centre of mass [kg m^2].",
        "damping / frictionloss / armature = symmetric viscous / Coulomb / rotor-inertia joint terms.",
        "dynid: velocity limits have no MJCF attribute and are not written.",
    ]
    header += [f"dynid: {text}" for text in lost]
    if chart is not None:
        header.append(f"dynid: independent coordinates in <custom><text name={chart[0]!r}> (read back by dynid; "
                      "other readers ignore it)")
    if mech.ball_joints:
        header.append(f"dynid: ball joints {[b.name for b in mech.ball_joints]} written as three hinges through two "
                      "massless bodies, recorded in <custom><text name='dynid:ball'> (read back by dynid)")
    if mech.task_coordinates:
        header.append(f"dynid: task coordinates: {list(mech.task_coordinates)}")
    header += [f"dynid note: {n}" for n in mech.notes]
    header += [f"dynid: {n}" for n in notes]
    return _write_text(path, _to_text(root, header))
