"""The configuration of ``dynid payload``: a strict schema read from TOML (unknown tables and keys are errors).

``[payload]``
    ``arm`` (required): the ``result.json`` of ``dynid identify`` of the arm *without* the payload (or its
    folder), relative to this file; its robot, processing and model are used. ``body``: the joint whose body
    carries the payload (a joint name of the robot; serial robots: default the last one). ``mass``: a known
    payload mass [kg] (then the other 9 parameters are estimated). ``origin``: ``{ xyz = [...], rpy = [...] }``,
    the payload's own frame (a tool flange, the frame its URDF link / MJCF body is written in) in the mount
    body's frame [m, rad; roll-pitch-yaw as URDF]; default the mount frame itself. ``name``: the link / body
    name of the exported payload (default ``"payload"``). ``physical``: pseudo-inertia >= 0 (default true).
``[data]``
    The log with the payload mounted: the keys of ``dynid identify``'s ``[data]`` (file, time or sample rate,
    position, effort, rows or time window). It is processed as the arm's result says (its filters, derivatives,
    decimation, row selection), so the arm's prediction and the payload regressor see the same rows.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from dynid.config import DataConfig, _bool, _list, _num, _parse_data, _str, _table, read_toml
from dynid.config._schema import _path
from dynid.errors import ConfigError

__all__ = ["PayloadConfig", "parse_payload_config", "load_payload_config", "payload_fields", "parse_joint_payload"]

_PAYLOAD_KEYS = {"arm", "body", "mass", "origin", "name", "physical"}


@dataclasses.dataclass(frozen=True)
class PayloadConfig:
    """``dynid payload``'s configuration (module docstring)."""

    arm: Path | None  # None: the joint mode of dynid identify
    data: DataConfig | None
    body: str | None = None
    mass: float | None = None
    origin_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    origin_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "payload"
    physical: bool = True
    source: Path | None = None
    raw: dict[str, Any] = dataclasses.field(default_factory=dict, compare=False)


def parse_payload_config(doc: dict[str, Any], base: Path, source: Path | None = None) -> PayloadConfig:
    """The configuration of a parsed TOML document (paths relative to ``base``)."""
    other = sorted(set(doc) - {"payload", "data"})
    if other:
        raise ConfigError(f"[{other[0]}] is not read by dynid payload: give [payload] and [data] (the processing and "
                          "the model are the arm result's)")
    for t in ("payload", "data"):
        if t not in doc:
            raise ConfigError(f"no [{t}] table" + (" (arm = the arm's result.json)" if t == "payload" else
                                                 " (the log with the payload mounted)"))
    if isinstance(doc["data"], list):
        raise ConfigError("data: give one [data] table (the log with the payload mounted), not [[data]]")
    p = _table(doc["payload"], "payload", _PAYLOAD_KEYS, {"arm"})
    arm = _path(p["arm"], "payload.arm", base)
    return PayloadConfig(arm=arm, data=_parse_data(doc["data"], "data", base), source=source, raw=dict(doc),
                         **payload_fields(p))


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
    p = _table(t, "payload", _PAYLOAD_KEYS - {"arm"})
    return PayloadConfig(arm=None, data=None, **payload_fields(p))


def load_payload_config(path: str | Path) -> PayloadConfig:
    """Read and check the TOML file at ``path``."""
    path = Path(path)
    return parse_payload_config(read_toml(path), path.resolve().parent, path.resolve())
