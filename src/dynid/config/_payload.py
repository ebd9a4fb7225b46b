"""The ``[payload]`` table's mount keys and :class:`PayloadConfig`, shared by ``dynid payload``
(:mod:`dynid.config.payload`) and the joint mode of ``dynid identify`` (:func:`dynid.config.parse_config`);
imports the schema helpers only, so that :mod:`dynid.config` can read it."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from dynid.config._schema import _bool, _list, _num, _str, _table
from dynid.errors import ConfigError

__all__ = ["PayloadConfig", "PAYLOAD_KEYS", "payload_fields", "parse_joint_payload"]

PAYLOAD_KEYS = {"arm", "body", "mass", "origin", "name", "physical"}


@dataclasses.dataclass(frozen=True)
class PayloadConfig:
    """``dynid payload``'s configuration (module docstring)."""

    arm: Path | None  # None: the joint mode of dynid identify
    data: Any  # dynid.config.DataConfig (None: the joint mode)
    body: str | None = None  # the joint whose body carries the payload (serial robots: default the last one)
    mass: float | None = None  # kg: a known payload mass (then the other 9 parameters are estimated)
    origin_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)  # origin.xyz, m: the payload's frame in the mount body's frame
    origin_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)  # origin.rpy, rad: its roll-pitch-yaw (as URDF)
    name: str = "payload"  # the URDF link / MJCF body name of the exported payload
    physical: bool = True  # pseudo-inertia >= 0 (false: plain WLS)
    source: Path | None = None
    raw: dict[str, Any] = dataclasses.field(default_factory=dict, compare=False)


def payload_fields(p: dict[str, Any]) -> dict[str, Any]:
    """The mount keys of a ``[payload]`` table (body, mass, origin, name, physical), shared by ``dynid payload`` and
    the joint mode of ``dynid identify`` (its ``[payload]`` table, without ``arm``)."""
    mass = _num(p["mass"], "payload.mass", True) if "mass" in p else None
    xyz, rpy = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    if "origin" in p:
        o = _table(p["origin"], "payload.origin", {"xyz", "rpy"})
        xyz = _list(o.get("xyz", [0.0, 0.0, 0.0]), "payload.origin.xyz", _num, 3)
        rpy = _list(o.get("rpy", [0.0, 0.0, 0.0]), "payload.origin.rpy", _num, 3)
        if not all(math.isfinite(v) for v in (*xyz, *rpy)):
            raise ConfigError("payload.origin: xyz and rpy must be finite")
    name = _str(p.get("name", "payload"), "payload.name")
    if not name or not all(ch.isalnum() or ch in "_-" for ch in name):
        raise ConfigError(f"payload.name {name!r}: letters, digits, '_' and '-' only (a URDF link / MJCF body name)")
    return {"body": _str(p["body"], "payload.body") if "body" in p else None, "mass": mass,
            "origin_xyz": tuple(xyz), "origin_rpy": tuple(rpy), "name": name,
            "physical": _bool(p.get("physical", True), "payload.physical")}


def parse_joint_payload(t: Any) -> PayloadConfig:
    """``dynid identify``'s ``[payload]`` table (the joint mode: the arm and the payload from ``[[data]]``
    experiments with ``payload = true`` and without): the keys of ``dynid payload``'s but ``arm``."""
    p = _table(t, "payload", PAYLOAD_KEYS - {"arm"})
    return PayloadConfig(arm=None, data=None, **payload_fields(p))
