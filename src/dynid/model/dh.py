"""Robot models from Denavit–Hartenberg tables (standard or modified), in Python or TOML.

Conventions
-----------
Standard DH (Denavit & Hartenberg; Corke): the transform of link ``i`` is
:math:`A_i = R_z(\\theta_i) T_z(d_i) T_x(a_i) R_x(\\alpha_i)`; joint ``i`` moves
about/along :math:`z_{i-1}`; link frame ``i`` sits at the far end of link ``i``.

Modified DH (Craig): :math:`A_i = R_x(\\alpha_{i-1}) T_x(a_{i-1}) R_z(\\theta_i)
T_z(d_i)`; joint ``i`` moves about/along :math:`z_i`; rows hold
``(alpha_{i-1}, a_{i-1}, d_i, theta_i)``.

The pinocchio joint frame of joint ``i`` is the frame the joint moves (origin on the
joint axis, z along it). With modified DH it *is* link frame ``i``; with standard DH
link frame ``i`` is the joint frame followed by the constant
:math:`X_i = T_z(d_i) T_x(a_i) R_x(\\alpha_i)`, and inertial data given in link
frame ``i`` are moved to the joint frame with :math:`X_i`. Standard parameters are
always those of the pinocchio joint frame (see :mod:`dynid.model.robot`).

A frame named ``"tool"`` is attached at the last link frame.

TOML format::

    name = "my_arm"
    convention = "modified"          # or "standard"
    gravity = [0.0, 0.0, -9.81]       # optional, m/s^2

    [[joints]]
    name = "j1"                       # optional
    type = "revolute"                 # or "prismatic"
    alpha = 0.0                       # rad; strings "pi/2", "-pi/2" are accepted
    a = 0.0                           # m
    d = 0.2435                        # m
    theta = 0.0                       # joint angle offset [rad] (for prismatic joints d is the offset)
    lower = -2.79                     # optional position limits
    upper = 2.79
    effort = 150.0                    # optional effort limit [N*m or N] (default none: dynid simulate's check skips it)
    mass = 17.4                       # optional inertial data in link frame i:
    com = [0.068, 0.006, -0.016]      #   centre of mass [m]
    inertia = [0.13, 0.524, 0.539, 0.0, 0.0, 0.0]  # [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] about the CoM
    # or link-origin form (Corke / SymPyBotics order):
    # params = [Lxx, Lxy, Lxz, Lyy, Lyz, Lzz, lx, ly, lz, m]
    Ia = 1.14                         # optional nominal extras
    fv = 4.9
    fc = 6.0
    offset = 0.0
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import ModelError, read_file_text
from dynid.model.robot import check_inertia as check_body, inertia_from_parameters

__all__ = ["DHJoint", "build_dh_model", "inertia_from_link_params", "read_dh_toml"]

_CONVENTIONS = ("standard", "modified")
_EXTRA_KEYS = ("Ia", "fv", "fc", "offset")


def _rx(a: float) -> pin.SE3:
    return pin.SE3(pin.utils.rotate("x", a), np.zeros(3))


def _rz(a: float) -> pin.SE3:
    return pin.SE3(pin.utils.rotate("z", a), np.zeros(3))


def _t(x: float, y: float, z: float) -> pin.SE3:
    return pin.SE3(np.eye(3), np.array([x, y, z], dtype=float))


def inertia_from_link_params(params: Sequence[float]) -> pin.Inertia:
    """Spatial inertia from ``[Lxx, Lxy, Lxz, Lyy, Lyz, Lzz, lx, ly, lz, m]``.

    ``L`` is the inertia tensor about the link-frame origin and ``l = m c`` the first
    moment (Corke's Robotics Toolbox / SymPyBotics order). A massless entry with
    non-zero rotational inertia is allowed (e.g. the PUMA 560 link 1).
    """
    p = np.asarray(params, dtype=float)
    if p.shape != (10,):
        raise ModelError(f"link parameters need 10 numbers [Lxx,Lxy,Lxz,Lyy,Lyz,Lzz,lx,ly,lz,m], got {p.shape}")
    lxx, lxy, lxz, lyy, lyz, lzz, lx, ly, lz, m = p
    return inertia_from_parameters(np.array([m, lx, ly, lz, lxx, lxy, lyy, lxz, lyz, lzz]))


@dataclasses.dataclass(frozen=True)
class DHJoint:
    """One row of a DH table (see module docstring for the meaning per convention).

    ``inertia`` is the body's spatial inertia expressed in link frame ``i``; ``effort`` the
    joint's effort limit [N*m or N] (default the largest double, pinocchio's "no limit").
    """

    alpha: float
    a: float
    d: float
    theta: float = 0.0
    kind: str = "revolute"
    name: str = ""
    lower: float = -math.pi
    upper: float = math.pi
    inertia: pin.Inertia | None = None
    effort: float = float(np.finfo(float).max)  # pinocchio's "no limit"

    def __post_init__(self) -> None:
        if self.kind not in ("revolute", "prismatic"):
            raise ModelError(f"joint type must be 'revolute' or 'prismatic', got {self.kind!r}")
        if not self.lower < self.upper:
            raise ModelError(f"joint {self.name or '?'}: lower limit {self.lower} is not below upper {self.upper}")
        if not self.effort > 0:
            raise ModelError(f"joint {self.name or '?'}: effort limit {self.effort} must be positive")


def build_dh_model(
    joints: Sequence[DHJoint], convention: str, *, name: str = "dh_robot", gravity: Sequence[float] | None = None
) -> pin.Model:
    """A pinocchio model of a serial chain from its DH table.

    Parameters
    ----------
    joints : sequence of DHJoint
        Rows from the base outwards.
    convention : {"standard", "modified"}
    name : str
    gravity : 3 floats, optional
        Gravity acceleration [m/s²] in the base frame; default ``[0, 0, -9.81]``.
    """
    if convention not in _CONVENTIONS:
        raise ModelError(f"DH convention must be one of {_CONVENTIONS}, got {convention!r}")
    if not joints:
        raise ModelError("a DH table needs at least one joint")
    model = pin.Model()
    model.name = name
    if gravity is not None:
        model.gravity = pin.Motion(np.asarray(gravity, dtype=float), np.zeros(3))
    parent = 0
    x_prev = pin.SE3.Identity()
    for i, row in enumerate(joints):
        jname = row.name or f"joint_{i + 1}"
        if convention == "standard":
            placement = x_prev * _rz(row.theta)
            x_link = _t(0, 0, row.d) * _t(row.a, 0, 0) * _rx(row.alpha)
        else:
            placement = _rx(row.alpha) * _t(row.a, 0, 0) * _t(0, 0, row.d) * _rz(row.theta)
            x_link = pin.SE3.Identity()
        jm = pin.JointModelRZ() if row.kind == "revolute" else pin.JointModelPZ()
        jid = model.addJoint(
            parent, jm, placement, jname,
            # DH rows give no velocity limit, and an effort limit only when the row names one: none is
            # pinocchio's "no limit" (DBL_MAX), not an invented one
            np.array([row.effort]), np.array([_NO_LIMIT]), np.array([row.lower]), np.array([row.upper]),
        )
        inertia = row.inertia if row.inertia is not None else pin.Inertia.Zero()
        model.appendBodyToJoint(jid, x_link.act(inertia), pin.SE3.Identity())
        model.addFrame(pin.Frame(f"link_{i + 1}", jid, x_link, pin.FrameType.BODY), False)
        parent = jid
        x_prev = x_link
    model.addFrame(pin.Frame("tool", parent, x_prev, pin.FrameType.OP_FRAME), False)
    return model


_NO_LIMIT = float(np.finfo(float).max)


# ---------------------------------------------------------------------- TOML reader
_PI_EXPR = re.compile(r"^\s*([+-]?)\s*(\d*\.?\d*)\s*\*?\s*pi\s*(?:/\s*(\d+\.?\d*))?\s*$")


def _angle(value: Any, where: str) -> float:
    if isinstance(value, bool):
        raise ModelError(f"{where}: expected a number, got {value!r}")
    if isinstance(value, (int, float)):
        return _num(value, where)
    if isinstance(value, str):
        m = _PI_EXPR.match(value)
        if m:
            sign = -1.0 if m.group(1) == "-" else 1.0
            factor = float(m.group(2)) if m.group(2) else 1.0
            div = float(m.group(3)) if m.group(3) else 1.0
            return sign * factor * math.pi / div
    raise ModelError(f"{where}: expected a number or an expression like '-pi/2', got {value!r}")


def _num(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ModelError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _vec(value: Any, n: int, where: str) -> FloatArray:
    if not isinstance(value, list) or len(value) != n:
        raise ModelError(f"{where}: expected a list of {n} numbers, got {value!r}")
    return np.array([_num(v, where) for v in value])


def _joint_inertia(row: Mapping[str, Any], where: str) -> pin.Inertia | None:
    has_params = "params" in row
    has_com_form = any(k in row for k in ("mass", "com", "inertia"))
    if has_params and has_com_form:
        raise ModelError(f"{where}: give either 'params' or 'mass'/'com'/'inertia', not both")
    if has_params:
        return inertia_from_link_params(_vec(row["params"], 10, f"{where}.params"))
    if not has_com_form:
        return None
    missing = [k for k in ("mass", "com", "inertia") if k not in row]
    if missing:
        raise ModelError(f"{where}: missing {missing} (mass, com and inertia go together)")
    mass = _num(row["mass"], f"{where}.mass")
    if mass < 0:
        raise ModelError(f"{where}.mass is negative ({mass})")
    com = _vec(row["com"], 3, f"{where}.com")
    ixx, iyy, izz, ixy, ixz, iyz = _vec(row["inertia"], 6, f"{where}.inertia")
    rot = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return pin.Inertia(mass, com, rot)


_ROW_KEYS = {"name", "type", "alpha", "a", "d", "theta", "lower", "upper", "effort", "mass", "com", "inertia", "params", *_EXTRA_KEYS}
_TOP_KEYS = {"name", "convention", "gravity", "joints"}


def read_dh_toml(path: str | Path, *, check_inertia: bool = True) -> tuple[pin.Model, dict[str, FloatArray], str]:
    """Read a DH table from TOML (format in the module docstring).

    Returns
    -------
    model : pinocchio.Model
    nominal_extras : dict
        ``{"Ia": array, ...}`` for extras given in the file.
    name : str

    ``check_inertia``: refuse a joint row whose body no rigid body can be (negative mass,
    inertia about the centre of mass not positive semi-definite or breaking the triangle
    inequality).
    """
    path = Path(path)
    text = read_file_text(path, "robot file")
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{path}: invalid TOML ({exc})") from None
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise ModelError(f"{path}: unknown keys {unknown}; allowed {sorted(_TOP_KEYS)}")
    convention = doc.get("convention")
    if convention not in _CONVENTIONS:
        raise ModelError(f"{path}: 'convention' must be one of {list(_CONVENTIONS)}, got {convention!r}")
    rows = doc.get("joints")
    if not isinstance(rows, list) or not rows:
        raise ModelError(f"{path}: needs a non-empty [[joints]] array")
    joints: list[DHJoint] = []
    extras: dict[str, list[float]] = {k: [] for k in _EXTRA_KEYS}
    for i, row in enumerate(rows):
        where = f"{path.name}: joints[{i}]"
        if not isinstance(row, dict):
            raise ModelError(f"{where}: expected a table")
        unknown = sorted(set(row) - _ROW_KEYS)
        if unknown:
            raise ModelError(f"{where}: unknown keys {unknown}; allowed {sorted(_ROW_KEYS)}")
        for req in ("alpha", "a", "d"):
            if req not in row:
                raise ModelError(f"{where}: missing '{req}'")
        kind = row.get("type", "revolute")
        inertia = _joint_inertia(row, where)
        if check_inertia and inertia is not None:
            check_body(inertia.mass, inertia.inertia, f"{where} ({row.get('name', f'joint_{i + 1}')})")
        values = dict(
            alpha=_angle(row["alpha"], f"{where}.alpha"),
            a=_num(row["a"], f"{where}.a"),
            d=_num(row["d"], f"{where}.d"),
            theta=_angle(row.get("theta", 0.0), f"{where}.theta"),
            kind=kind,
            name=str(row.get("name", "")),
            lower=_num(row.get("lower", -math.pi), f"{where}.lower"),
            upper=_num(row.get("upper", math.pi), f"{where}.upper"),
            inertia=inertia,
            **({"effort": _num(row["effort"], f"{where}.effort")} if "effort" in row else {}),
        )
        try:
            joint = DHJoint(**values)
        except ModelError as exc:
            raise ModelError(f"{where}: {exc}") from None
        joints.append(joint)
        for k in _EXTRA_KEYS:
            extras[k].append(_num(row.get(k, 0.0), f"{where}.{k}"))
    gravity = doc.get("gravity")
    grav = None if gravity is None else _vec(gravity, 3, f"{path.name}: gravity")
    name = str(doc.get("name", path.stem))
    model = build_dh_model(joints, convention, name=name, gravity=grav)
    given = {k: np.array(v) for k, v in extras.items() if any(k in r for r in rows)}
    return model, given, name
