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

from pathlib import Path
from typing import Any

from dynid.config import _parse_data, _table, read_toml
from dynid.config._payload import PAYLOAD_KEYS as _PAYLOAD_KEYS
from dynid.config._payload import PayloadConfig, parse_joint_payload, payload_fields
from dynid.config._schema import _path
from dynid.errors import ConfigError

__all__ = ["PayloadConfig", "parse_payload_config", "load_payload_config", "payload_fields", "parse_joint_payload"]



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


def load_payload_config(path: str | Path) -> PayloadConfig:
    """Read and check the TOML file at ``path``."""
    path = Path(path)
    return parse_payload_config(read_toml(path), path.resolve().parent, path.resolve())
