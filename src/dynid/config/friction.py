"""The configuration of ``dynid friction``: friction curves from a constant-velocity log.

``[robot]`` and ``[data]`` are those of ``dynid identify`` (the model, its drive train; the
log's file, time, position and effort columns, ``rows`` or ``time_window``). Serial robots only.

``[friction]`` (all keys optional):
    ``models``: which curves to fit, of ``"coulomb_viscous"``, ``"stribeck"``, ``"power_law"``,
    ``"smooth_stribeck"`` (paper 003, Table 4's models 1-4 as :mod:`dynid.estimation.friction_curves`
    numbers them; the default, all four) and ``"arctan_stribeck"``;
    ``joints``: the joints to analyse (names; default every joint the log tests);
    ``skip`` [s]: left out at the start of each constant-velocity window (default 0.5; with
    ``settle``, a floor);
    ``settle``: keep only each window's steady part, where its measured speed has settled
    (paper 003 Sec. 3.1, the rule in :mod:`dynid.signals.friction_points`; default false, which
    keeps every sample after ``skip`` and notes the windows still settling there);
    ``settle_block`` [s] (default 0.1), ``settle_k`` (default 3) and ``settle_tol`` (default
    0.02): the rule's block length, noise multiple and relative speed band;
    ``min_samples``: fewest paired samples for a point (default 10);
    ``held_out``: ``"alternate_speeds"`` (default: every other speed level held out),
    ``"last_repetition"`` or ``"none"``;
    ``labels``: the log's label columns, ``{ joint, speed, direction, repetition }``
    (default ``cv_joint``, ``cv_speed``, ``cv_direction``, ``cv_repetition``, as
    ``dynid simulate`` writes them for ``kind = "constant_velocity"``).
``[output]``
    ``plots`` (default true): friction.png.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config import (DataConfig, RobotConfig, _bool, _int, _list, _num, _parse_data, _parse_robot, _str, _table,
                          joint_name_list, read_toml)
from dynid.errors import ConfigError

__all__ = ["FrictionConfig", "load_friction_config", "parse_friction_config", "FRICTION_CURVES", "HELD_OUT_RULES"]

FRICTION_CURVES = ("coulomb_viscous", "stribeck", "power_law", "smooth_stribeck", "arctan_stribeck")
"""dynid.estimation.friction_curves.MODELS (config sits above estimation but reads no module of it)."""
HELD_OUT_RULES = ("alternate_speeds", "last_repetition", "none")
_LABELS = {"joint": "cv_joint", "speed": "cv_speed", "direction": "cv_direction", "repetition": "cv_repetition"}


@dataclasses.dataclass(frozen=True)
class FrictionConfig:
    robot: RobotConfig
    data: DataConfig
    models: tuple[str, ...]
    joints: tuple[str, ...] | None
    skip: float
    min_samples: int
    settle: bool
    settle_block: float
    settle_k: float
    settle_tol: float
    held_out: str
    labels: Mapping[str, str]
    plots: bool
    source: Path | None
    raw: Mapping[str, Any]


def parse_friction_config(doc: Mapping[str, Any], base_dir: Path, source: Path | None = None) -> FrictionConfig:
    """Validate a parsed TOML document (see the module docstring)."""
    doc = _table(dict(doc), "config", {"robot", "data", "friction", "output"}, {"robot", "data"})
    f = _table(doc.get("friction", {}), "friction",
               {"models", "joints", "skip", "min_samples", "held_out", "labels", "settle", "settle_block", "settle_k",
                "settle_tol"})
    models = _list(f.get("models", list(FRICTION_CURVES[:4])), "friction.models",
                   lambda v, w: _str(v, w, FRICTION_CURVES))
    if not models:
        raise ConfigError("friction.models: empty list; name the curves to fit")
    twice = sorted({m for m in models if models.count(m) > 1})
    if twice:
        raise ConfigError(f"friction.models: {twice} named more than once")
    labels = dict(_LABELS)
    if "labels" in f:
        lt = _table(f["labels"], "friction.labels", set(_LABELS))
        labels.update({k: _str(v, f"friction.labels.{k}") for k, v in lt.items()})
    settle_block = _num(f.get("settle_block", 0.1), "friction.settle_block", positive=True)
    settle_k = _num(f.get("settle_k", 3.0), "friction.settle_k", positive=True)
    settle_tol = _num(f.get("settle_tol", 0.02), "friction.settle_tol", positive=True)
    if not settle_tol < 1:
        raise ConfigError(f"friction.settle_tol: {settle_tol:g}; give a fraction of the speed in (0, 1)")
    out = _table(doc.get("output", {}), "output", {"plots"})
    data = _parse_data(doc["data"], "data", base_dir)
    if data.bag or not data.header:
        raise ConfigError("data.file: dynid friction reads the label columns of a constant-velocity log by name "
                          f"(friction.labels), from a CSV with a header row, NPZ or Parquet file, not "
                          f"{'a ROS bag' if data.bag else 'a headerless CSV'}")
    return FrictionConfig(
        robot=_parse_robot(doc["robot"], base_dir),
        data=data,
        models=models,
        joints=joint_name_list(f, "joints", "friction"),
        skip=_num(f.get("skip", 0.5), "friction.skip", minimum=0.0),
        min_samples=_int(f.get("min_samples", 10), "friction.min_samples", 2),
        settle=_bool(f.get("settle", False), "friction.settle"),
        settle_block=settle_block,
        settle_k=settle_k,
        settle_tol=settle_tol,
        held_out=_str(f.get("held_out", "alternate_speeds"), "friction.held_out", HELD_OUT_RULES),
        labels=labels,
        plots=_bool(out.get("plots", True), "output.plots"),
        source=source,
        raw=doc,
    )


def load_friction_config(path: str | Path) -> FrictionConfig:
    """Read and validate a ``dynid friction`` TOML file."""
    path = Path(path)
    doc = read_toml(path)
    return parse_friction_config(doc, path.resolve().parent, source=path.resolve())
