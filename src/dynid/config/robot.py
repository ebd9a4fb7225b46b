"""``[robot]`` of the identify configuration: the model and its drive train (couplings, gains,
offsets, rotor inertias, a mechanism's actuated and independent joints)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config._schema import _int, _list, _num, _path, _str, _table
from dynid.errors import ConfigError

_EXTRAS = ("Ia", "fv", "fc", "offset")
_ALL_EXTRAS = _EXTRAS + ("fv+", "fv-", "fc+", "fc-")  # dynid.model.robot.ALL_EXTRAS (config sits above model)


@dataclasses.dataclass(frozen=True)
class CouplingConfig:
    motor: int
    joints: tuple[int, ...]
    weights: tuple[float, ...] = ()


@dataclasses.dataclass(frozen=True)
class RobotConfig:
    """``[robot]``: the model and its drive train."""

    model: str  # "builtin:<name>", or a .urdf, .xml (MJCF) or DH .toml file (relative to the config file)
    # the joint extras identified with the bodies: rotor inertia Ia, viscous fv, Coulomb fc, torque offset
    # (any subset, fixed order); fv+, fv-, fc+, fc-: friction per direction of motion
    extras: tuple[str, ...] = _EXTRAS
    gear_ratios: tuple[float, ...] | None = None  # motor angle per joint angle, one per joint (non-zero; motor-side signals)
    # motors that turn with several joints: [{ motor = 6, joints = [5, 6] }] (numbered from 1); optional
    # weights = [1, 1], per joint, multiply the motor's gear ratio (default 1)
    couplings: tuple[CouplingConfig, ...] = ()
    drive_gains: tuple[float, ...] | None = None  # N*m/A at the motor, one per motor (effort kind = "current")
    position_offset: tuple[float, ...] | None = None  # rad (or m) per joint: the joint position at encoder zero
    extras_given: bool = False  # extras named in the file (a mechanism then gains them on its actuated joints)
    actuated: tuple[str, ...] | None = None  # mechanisms: actuated joints, in actuator order (default: the model's)
    independent: tuple[str, ...] | None = None  # mechanisms: joints whose positions are the independent coordinates
    rotor_inertia: tuple[float, ...] | None = None  # serial robots: nominal Ia per joint [kg*m^2 or kg, joint side]

    @property
    def has_transmission(self) -> bool:
        return any(
            x for x in (self.gear_ratios, self.couplings, self.drive_gains, self.position_offset)
        )



ROBOT_KEYS = ("extras", "gear_ratios", "couplings", "drive_gains", "position_offset", "actuated", "independent",
              "rotor_inertia")
"""The keys of ``[robot]`` besides ``model``."""


def _parse_robot(t: Any, base: Path) -> RobotConfig:
    where = "robot"
    t = _table(t, where, {"model", *ROBOT_KEYS}, {"model"})
    model = _str(t["model"], f"{where}.model")
    if not model.startswith("builtin:"):
        model = str(_path(model, f"{where}.model", base))
    extras = _list(t.get("extras", list(_EXTRAS)), f"{where}.extras", lambda v, w: _str(v, w, _ALL_EXTRAS))
    if "couplings" in t and not isinstance(t["couplings"], list):
        raise ConfigError(f"{where}.couplings: expected a list of tables")
    couplings = []
    for i, c in enumerate(t.get("couplings", [])):
        cw = f"{where}.couplings[{i}]"
        c = _table(c, cw, {"motor", "joints", "weights"}, {"motor", "joints"})
        couplings.append(
            CouplingConfig(
                motor=_int(c["motor"], f"{cw}.motor", 1),
                joints=_list(c["joints"], f"{cw}.joints", lambda v, w: _int(v, w, 1)),
                weights=_list(c.get("weights", []), f"{cw}.weights", _num),
            )
        )
    def num_list(key: str, nonzero: bool = False):
        if key not in t:
            return None
        values = _list(t[key], f"{where}.{key}", _num)
        if not values:
            raise ConfigError(f"{where}.{key}: empty list; give one value per joint")
        zero = [i for i, v in enumerate(values) if nonzero and v == 0]
        if zero:
            raise ConfigError(f"{where}.{key}[{zero[0]}] is 0; {key.replace('_', ' ')} must be non-zero")
        return values

    return RobotConfig(
        model=model,
        extras=extras,
        gear_ratios=num_list("gear_ratios", nonzero=True),
        couplings=tuple(couplings),
        drive_gains=num_list("drive_gains", nonzero=True),
        position_offset=num_list("position_offset"),
        extras_given="extras" in t,
        actuated=joint_name_list(t, "actuated", where),
        independent=joint_name_list(t, "independent", where),
        rotor_inertia=rotor_inertia_list(t, where),
    )


def rotor_inertia_list(t: Mapping[str, Any], where: str) -> tuple[float, ...] | None:
    """``[robot] rotor_inertia``: the nominal rotor inertias of a serial robot's joints, reflected to
    the joint side [kg*m^2 or kg], one per joint, each >= 0 (None: absent; the description's, if any).
    URDF has no element for them; they become the nominal ``Ia`` (:func:`dynid.model.loading.with_rotor_inertia`)."""
    if "rotor_inertia" not in t:
        return None
    values = _list(t["rotor_inertia"], f"{where}.rotor_inertia", lambda v, w: _num(v, w, minimum=0.0))
    if not values:
        raise ConfigError(f"{where}.rotor_inertia: empty list; give one value per joint [kg*m^2]")
    return values


def joint_name_list(t: Mapping[str, Any], key: str, where: str) -> tuple[str, ...] | None:
    """``[robot] actuated`` / ``independent``: a non-empty list of distinct joint names (None: absent)."""
    if key not in t:
        return None
    names = _list(t[key], f"{where}.{key}", _str)
    if not names:
        raise ConfigError(f"{where}.{key}: empty list; name the joints")
    if len(set(names)) != len(names):
        raise ConfigError(f"{where}.{key}: {list(names)} names a joint twice")
    return tuple(names)
