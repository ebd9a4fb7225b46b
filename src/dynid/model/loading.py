"""Load a robot description: ``builtin:<name>``, URDF, MJCF, or a DH table in TOML.

:func:`load_robot` reads serial robots; :func:`load_model` sits above the closed-loop loaders
(:mod:`dynid.model.robots`, :mod:`dynid.model.mechanism_io`) and picks one. The XML helpers
shared with :mod:`dynid.model.mechanism_files` are in :mod:`dynid.model._xml`.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from dynid.errors import ModelError, existing_file
from dynid.model._xml import check_mjcf_inertials, native_stderr, parse_failure, parse_xml_file, urdf_without_dynamics
from dynid.model.robot import JOINT_EXTRAS, RobotModel
from dynid.model.transmission import Transmission

__all__ = ["load_model", "load_pin_model", "load_robot", "with_rotor_inertia"]

_UNBOUNDED = {
    "JointModelRUBX": pin.JointModelRX,
    "JointModelRUBY": pin.JointModelRY,
    "JointModelRUBZ": pin.JointModelRZ,
}


def _bounded_revolute(model: pin.Model) -> pin.Model:
    """Replace continuous (unbounded, nq=2) revolute joints by ordinary ones (nq=1).

    dynid works with joint angles; a continuous joint has no position limit (±inf: pinocchio's
    "unbounded"; :meth:`RobotModel.position_limits` samples it in ±π), and every joint keeps its
    effort and velocity limits (the alarms of :mod:`dynid.pipeline.diagnostics` read them).
    """
    if model.nq == model.nv:
        return model
    new = pin.Model()
    new.name = model.name
    new.gravity = model.gravity
    for j in range(1, model.njoints):
        jm = model.joints[j]
        short = jm.shortname()
        if short in _UNBOUNDED:
            njm = _UNBOUNDED[short]()
            lo, hi = np.array([-np.inf]), np.array([np.inf])
        elif short == "JointModelRevoluteUnboundedUnaligned":
            axis = jm.extract().axis if hasattr(jm, "extract") else None
            if axis is None:
                raise ModelError(f"continuous joint {model.names[j]!r} with an unaligned axis is not supported")
            njm = pin.JointModelRevoluteUnaligned(np.asarray(axis))
            lo, hi = np.array([-np.inf]), np.array([np.inf])
        elif jm.nq == jm.nv:
            njm = jm
            lo = model.lowerPositionLimit[jm.idx_q : jm.idx_q + jm.nq]
            hi = model.upperPositionLimit[jm.idx_q : jm.idx_q + jm.nq]
        else:
            kind = {"JointModelSpherical": "a ball joint", "JointModelFreeFlyer": "a free joint"}.get(short, f"of type {short}")
            raise ModelError(f"joint {model.names[j]!r} is {kind} ({jm.nv} DOF); a serial robot needs 1-DOF joints "
                             "(hinge/revolute or slide/prismatic)")
        jid = new.addJoint(
            model.parents[j], njm, model.jointPlacements[j], model.names[j],
            model.effortLimit[jm.idx_v : jm.idx_v + jm.nv].copy(), model.velocityLimit[jm.idx_v : jm.idx_v + jm.nv].copy(),
            np.asarray(lo, float), np.asarray(hi, float),
        )
        new.appendBodyToJoint(jid, model.inertias[j], pin.SE3.Identity())
    for f in model.frames:
        if f.name == "universe" or (f.type == pin.FrameType.JOINT):
            continue
        new.addFrame(pin.Frame(f.name, f.parentJoint, f.placement, f.type), False)
    return new


def _load_pin_model(path: Path, check: bool = True) -> tuple[pin.Model, dict[str, tuple[float, float]]]:
    """The pinocchio model and, for URDF, the ``<dynamics>`` values per joint name.
    ``check``: check the bodies' inertial data (``check_inertia`` of :func:`load_robot`)."""
    path = existing_file(path, "robot file")
    suffix = path.suffix.lower()
    dynamics: dict[str, tuple[float, float]] = {}
    if suffix == ".urdf":
        xml, dynamics = urdf_without_dynamics(path, check)
    elif suffix in (".xml", ".mjcf"):
        root = parse_xml_file(path)
        if root.tag != "mujoco":
            raise ModelError(f"{path}: not an MJCF file (its root element is <{root.tag}>, not <mujoco>)")
        if check:
            check_mjcf_inertials(root, path)
    else:
        raise ModelError(f"{path}: unknown robot file type {suffix!r} (use .urdf, .xml/.mjcf or a DH .toml)")
    with native_stderr() as native:
        try:
            model = pin.buildModelFromXML(xml) if suffix == ".urdf" else pin.buildModelFromMJCF(str(path))
        except (RuntimeError, ValueError, OSError) as exc:
            failure = exc
        else:
            failure = None
    if failure is not None:
        raise ModelError(f"{path}: cannot parse robot description ({parse_failure(failure, native)})")
    if model.nv == 0:
        raise ModelError(f"{path}: the model has no moving joints")
    try:
        return _bounded_revolute(model), dynamics
    except ModelError as exc:
        raise ModelError(f"{path}: {exc}") from None


def load_pin_model(path: str | Path) -> pin.Model:
    """A pinocchio model (no geometry) from a URDF or MJCF file, as written (for comparing with
    another tool's model: its inertial data are not checked, unlike :func:`load_robot`)."""
    return _load_pin_model(Path(path), check=False)[0]


def load_robot(
    spec: str,
    *,
    extras: Sequence[str] = JOINT_EXTRAS,
    transmission: Transmission | None = None,
    nominal_extras: Mapping[str, object] | None = None,
    check_inertia: bool = True,
) -> RobotModel:
    """Load a serial robot.

    Parameters
    ----------
    spec : str
        ``builtin:<name>``, or a path to ``.urdf``, ``.xml``/``.mjcf`` or a DH ``.toml``.
    extras : sequence of str
        Joint extras to include in the parameter vector (subset of ``Ia, fv, fc, offset``).
    transmission : Transmission, optional
        Motor-joint map (gear ratios, couplings, drive gains, encoder offsets).
    nominal_extras : mapping, optional
        Nominal extras overriding those of the description.
    check_inertia : bool
        Check the bodies' inertial data: a negative mass is refused, naming the body; an inertia
        no rigid body can have (not positive semi-definite, or breaking the triangle inequality)
        is refused in MJCF and DH files and accepted with one :class:`~dynid.errors.ModelWarning`
        per link in URDF files, which vendors ship and users cannot fix
        (:func:`~dynid.model._xml.check_urdf_inertials`). Off only to reproduce others'
        computations with such values (e.g. Corke's PUMA 560 link 1).
    """
    extras = tuple(extras)
    if spec.startswith("builtin:"):
        from dynid.model.robots import build_builtin

        robot = build_builtin(spec.split(":", 1)[1], extras)
    else:
        path = Path(spec)
        if path.suffix.lower() == ".toml":
            from dynid.model.dh import read_dh_toml

            model, nominal, name = read_dh_toml(path, check_inertia=check_inertia)
            robot = RobotModel(model, name=name, extras=extras, nominal_extras=nominal, source=str(path))
        else:
            model, dyn = _load_pin_model(path, check_inertia)
            nominal: dict[str, object] = {}
            names = list(model.names)[1:]
            if any(n in dyn for n in names):
                nominal = {
                    "fv": np.array([dyn.get(n, (0.0, 0.0))[0] for n in names]),
                    "fc": np.array([dyn.get(n, (0.0, 0.0))[1] for n in names]),
                }
            try:
                robot = RobotModel(model, name=model.name or path.stem, extras=extras, nominal_extras=nominal, source=str(path))
            except ModelError as exc:
                raise ModelError(f"{path}: {exc}") from None
    changes: dict[str, object] = {}
    if transmission is not None:
        changes["transmission"] = transmission
    if nominal_extras:
        changes["nominal_extras"] = {**robot.nominal_extras, **nominal_extras}
    return robot.replace(**changes) if changes else robot


def _mjcf_has_closures(path: Path) -> bool:
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, ValueError):
        return False  # let the serial loader report the problem
    return any(len(eq) > 0 for eq in root.iter("equality"))


def with_rotor_inertia(robot, rotor_inertia: Sequence[float]):
    """``robot`` with the nominal rotor inertias ``rotor_inertia`` (one per joint, reflected to the
    joint side: kg·m² for a revolute joint, kg for a prismatic one), replacing the description's
    (MJCF ``armature``; URDF has no element for it). They are the nominal ``Ia`` parameters, so
    :meth:`RobotModel.with_parameters` puts them in ``model.armature``: pinocchio's RNEA and ABA,
    the simulated plant and every nominal model include them. Serial robots with the ``Ia`` extra."""
    from dynid.model.mechanism import Mechanism

    if isinstance(robot, Mechanism):
        raise ModelError(f"rotor_inertia is given per joint of a serial robot; {robot.name!r} is a closed-loop mechanism, "
                         "whose rotor inertias are its Ia_<joint> terms (MJCF armature)")
    ia = np.array(rotor_inertia, dtype=float, ndmin=1)
    if ia.shape != (robot.dof,):
        raise ModelError(f"rotor_inertia has {ia.size} entries; {robot.name!r} has {robot.dof} joints "
                         f"({', '.join(robot.joint_names)})")
    if not np.all(np.isfinite(ia)) or np.any(ia < 0):
        raise ModelError(f"rotor_inertia must be finite and >= 0 (a reflected rotor inertia), got {ia.tolist()}")
    if "Ia" not in robot.extras:
        raise ModelError(f"rotor_inertia needs the joint extra 'Ia' in the parameters (extras are {list(robot.extras)}); "
                         "link-side torque sensors do not measure the rotor: leave rotor_inertia out then")
    return robot.replace(nominal_extras={**robot.nominal_extras, "Ia": ia})


def load_model(spec: str, *, extras: Sequence[str] = JOINT_EXTRAS, closures: str | Path | None = None,
               actuated: Sequence[str] | None = None, independent: Sequence[str] | None = None,
               rotor_inertia: Sequence[float] | None = None):
    """A serial :class:`RobotModel` or a closed-loop :class:`~dynid.model.mechanism.Mechanism`.

    Closed-loop models are: ``builtin:`` mechanisms (shang2dof, rps3, hexapod, fivebar),
    MJCF files with an ``<equality>`` section (``<connect>``/``<weld>`` loop closures), and
    URDF files given with a closure YAML (``closures``, or a ``robot.yaml`` next to the URDF).
    Everything else is loaded by :func:`load_robot`.

    ``actuated`` / ``independent`` (joint names, mechanisms only; ``[robot] actuated`` and
    ``independent`` of the configs): the actuated joints in actuator order (default: the file's
    actuators, or the built-in's) and the joints whose positions are the independent coordinates
    (default: the actuated joints; a redundantly actuated robot needs as many as its mobility).

    ``rotor_inertia`` (``[robot] rotor_inertia`` of the configs; serial robots): the nominal rotor
    inertias, one per joint (:func:`with_rotor_inertia`).
    """
    if rotor_inertia is not None:
        return with_rotor_inertia(load_model(spec, extras=extras, closures=closures, actuated=actuated,
                                             independent=independent), rotor_inertia)
    chart = actuated is not None or independent is not None
    if spec.startswith("builtin:"):
        from dynid.model.robots import MECHANISMS, build_mechanism

        name = spec.split(":", 1)[1]
        if name in MECHANISMS:
            mech = build_mechanism(name)
            return mech.with_chart(actuated, independent) if chart else mech
        robot = load_robot(spec, extras=extras)
    else:
        path = Path(spec)
        suffix = path.suffix.lower()
        if suffix in (".xml", ".mjcf") and path.is_file() and _mjcf_has_closures(path):
            from dynid.model.mechanism_io import load_mechanism_mjcf

            return load_mechanism_mjcf(path, actuated=actuated, independent=independent)
        if suffix == ".urdf" and (closures is not None or (path.parent / "robot.yaml").is_file()):
            from dynid.model.mechanism_io import load_mechanism_urdf

            return load_mechanism_urdf(path, closures, actuated=actuated, independent=independent)
        if closures is not None:
            raise ModelError(f"a closure file was given but {spec} is not a URDF")
        robot = load_robot(spec, extras=extras)
    if chart:
        raise ModelError(f"{spec} is a serial robot: actuated joints and independent coordinates are for closed-loop "
                         "mechanisms (every joint of a serial robot is both)")
    return robot
