"""The configuration of ``dynid design``: a strict, typed schema read from TOML.

``[robot]``
    ``model`` (required): anything ``dynid info`` loads; ``rotor_inertia`` (serial robots: one
    per joint [kg·m² or kg], as in ``dynid identify``); ``actuated``, ``independent`` (mechanisms).
``[design]``
    ``kind``: ``"fourier"`` (default: optimized Fourier series), ``"circle"`` (paper 001's
    one-line design, evaluated, not optimized: ``centre``, ``radius``, ``speed``, ``turns``) or
    ``"constant_velocity"`` (serial robots: paper 003, Sec. 3.1's friction experiment sized from
    ``[limits]``: ``joints``, ``speeds`` or ``speed_range`` with ``n_speeds``, ``stroke``,
    ``window``, ``max_window``, ``min_span``, ``pose``, ``repetitions``, ``switch``, ``rest``, ``skip``,
    ``min_samples``; see :mod:`dynid.excitation.friction_design`; the Fourier keys below do not
    apply to it);
    ``coordinates``: ``"independent"`` or ``"task"`` (platform pose of a parallel robot);
    ``harmonics``, ``base_frequency_hz``, ``optimize_frequency``, ``quintic``, ``criterion``
    (``cond``, ``weighted_cond``, ``d_opt``, ``a_opt``, ``e_opt``), ``samples`` per period,
    ``starts``, ``seed``, ``max_iter``, ``noise_std`` (per output channel), ``box``
    (``{ lower = [...], upper = [...] }``: range of the design coordinates).
``[limits]``
    Actuator space: ``position = { lower, upper }`` (default: joint limits), ``velocity``,
    ``acceleration``, ``force`` (numbers or one per actuator), ``max_condition``.
``[output]``
    ``rate_hz`` of the sampled trajectory (default 100), ``plots`` (default true).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config import (_bool, _int, _list, _num, _num_or_list, _str, _table, joint_name_list, read_toml,
                          rotor_inertia_list)
from dynid.errors import ConfigError

__all__ = ["DesignConfig", "load_design_config", "parse_design_config"]

_CRITERIA = ("cond", "weighted_cond", "d_opt", "a_opt", "e_opt")


@dataclasses.dataclass(frozen=True)
class DesignConfig:
    model: str
    kind: str
    coordinates: str
    harmonics: int
    base_frequency_hz: float
    optimize_frequency: bool
    quintic: bool
    criterion: str
    samples: int
    starts: int
    seed: int
    max_iter: int
    noise_std: tuple[float, ...] | float | None
    box: tuple[tuple[float, ...], tuple[float, ...]] | None
    circle: Mapping[str, Any] | None
    limits: Mapping[str, Any]
    rate_hz: float
    plots: bool
    source: Path | None
    raw: Mapping[str, Any]
    actuated: tuple[str, ...] | None = None  # mechanisms: as [robot] actuated / independent of dynid identify
    independent: tuple[str, ...] | None = None
    constant_velocity: Mapping[str, Any] | None = None  # kind = "constant_velocity": its keys, parsed
    rotor_inertia: tuple[float, ...] | None = None  # serial robots: as [robot] rotor_inertia of dynid identify


def _range(t: Any, where: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    t = _table(t, where, {"lower", "upper"}, {"lower", "upper"})
    lo, hi = _list(t["lower"], f"{where}.lower", _num), _list(t["upper"], f"{where}.upper", _num)
    if len(lo) != len(hi) or any(h <= l for l, h in zip(lo, hi)):
        raise ConfigError(f"{where}: lower and upper need the same length and lower < upper")
    return lo, hi


def parse_design_config(doc: Mapping[str, Any], base_dir: Path, source: Path | None = None) -> DesignConfig:
    doc = _table(dict(doc), "config", {"robot", "design", "limits", "output"}, {"robot"})
    r = _table(doc["robot"], "robot", {"model", "actuated", "independent", "rotor_inertia"}, {"model"})
    model = _str(r["model"], "robot.model")
    if not model.startswith("builtin:"):
        p = Path(model).expanduser()
        model = str((p if p.is_absolute() else base_dir / p).resolve())
    keys = {"kind", "coordinates", "harmonics", "base_frequency_hz", "optimize_frequency", "quintic", "criterion",
            "samples", "starts", "seed", "max_iter", "noise_std", "box", "centre", "radius", "speed", "turns"}
    d = _table(doc.get("design", {}), "design", keys | _CV_KEYS)
    kind = _str(d.get("kind", "fourier"), "design.kind", ("fourier", "circle", "constant_velocity"))
    cv = None
    if kind == "constant_velocity":
        extra = sorted(set(d) - _CV_KEYS - {"kind"})
        if extra:
            raise ConfigError(f"design: keys {extra} do not apply to kind 'constant_velocity'; it takes {sorted(_CV_KEYS)}")
        cv = _parse_constant_velocity(d)
    elif _CV_KEYS & set(d) - keys:
        raise ConfigError(f"design: keys {sorted(_CV_KEYS & set(d) - keys)} are for kind = 'constant_velocity'")
    circle_keys = {"centre", "radius", "speed", "turns"}
    if kind == "fourier" and circle_keys & set(d):
        raise ConfigError(f"design: keys {sorted(circle_keys & set(d))} are for kind = 'circle'")
    circle = None
    if kind == "circle":
        missing = sorted({"centre", "radius", "speed"} - set(d))
        if missing:
            raise ConfigError(f"design: a circle needs {missing}")
        circle = {"centre": _list(d["centre"], "design.centre", _num, 2), "radius": _num(d["radius"], "design.radius", True),
                  "speed": _num(d["speed"], "design.speed", True), "turns": _num(d.get("turns", 1.0), "design.turns", True)}
    lim_t = _table(doc.get("limits", {}), "limits", {"position", "velocity", "acceleration", "force", "max_condition"})
    if kind == "constant_velocity":
        unchecked = sorted({"force", "max_condition"} & set(lim_t))
        if unchecked:
            raise ConfigError(f"limits: {unchecked} are not checked by design.kind = 'constant_velocity' (it bounds "
                              "positions, velocities and accelerations); remove them")
    limits: dict[str, Any] = {}
    if "position" in lim_t:
        limits["position"] = _range(lim_t["position"], "limits.position")
    for k in ("velocity", "acceleration", "force"):
        if k in lim_t:
            limits[k] = _num_or_list(lim_t[k], f"limits.{k}", True)
    limits["max_condition"] = _num(lim_t.get("max_condition", 1e4), "limits.max_condition", True)
    if limits["max_condition"] <= 1:
        raise ConfigError(f"limits.max_condition must be > 1 (a condition number is at least 1), got {limits['max_condition']:g}")
    out = _table(doc.get("output", {}), "output", {"rate_hz", "plots"})
    return DesignConfig(
        model=model,
        actuated=joint_name_list(r, "actuated", "robot"),
        independent=joint_name_list(r, "independent", "robot"),
        rotor_inertia=rotor_inertia_list(r, "robot"),
        kind=kind,
        coordinates=_str(d.get("coordinates", "independent"), "design.coordinates", ("independent", "task")),
        harmonics=_int(d.get("harmonics", 5), "design.harmonics", 1),
        base_frequency_hz=_num(d.get("base_frequency_hz", 0.1), "design.base_frequency_hz", True),
        optimize_frequency=_bool(d.get("optimize_frequency", False), "design.optimize_frequency"),
        quintic=_bool(d.get("quintic", False), "design.quintic"),
        criterion=_str(d.get("criterion", "d_opt"), "design.criterion", _CRITERIA),
        samples=_int(d.get("samples", 64), "design.samples", 8),
        starts=_int(d.get("starts", 3), "design.starts", 1),
        seed=_int(d.get("seed", 0), "design.seed", 0),
        max_iter=_int(d.get("max_iter", 100), "design.max_iter", 1),
        noise_std=_num_or_list(d["noise_std"], "design.noise_std", True) if "noise_std" in d else None,
        box=_range(d["box"], "design.box") if "box" in d else None,
        circle=circle,
        limits=limits,
        rate_hz=_num(out.get("rate_hz", 100.0), "output.rate_hz", True),
        plots=_bool(out.get("plots", True), "output.plots"),
        source=source,
        raw=doc,
        constant_velocity=cv,
    )


_CV_KEYS = {"kind", "joints", "speeds", "speed_range", "n_speeds", "stroke", "window", "max_window", "min_span", "pose",
            "repetitions",
            "switch", "rest", "skip", "min_samples"}


def _parse_constant_velocity(d: Mapping[str, Any]) -> dict[str, Any]:
    """The keys of ``kind = "constant_velocity"`` (defaults and meaning in
    :func:`dynid.excitation.friction_design.design_constant_velocity`)."""
    w = "design"
    v: dict[str, Any] = {}
    if "joints" in d:
        v["joints"] = joint_name_list(d, "joints", w)
    if "speeds" in d:
        if "speed_range" in d or "n_speeds" in d:
            raise ConfigError(f"{w}: give speeds or speed_range / n_speeds, not both")
        speeds = _list(d["speeds"], f"{w}.speeds", lambda x, ww: _num(x, ww, True))
        if not speeds:
            raise ConfigError(f"{w}.speeds: empty list; give the speed levels [rad/s or m/s]")
        twice = sorted({x for x in speeds if speeds.count(x) > 1})
        if twice:
            raise ConfigError(f"{w}.speeds: {twice} given more than once")
        v["speeds"] = tuple(sorted(speeds))
    if "speed_range" in d:
        rng = _list(d["speed_range"], f"{w}.speed_range", lambda x, ww: _num(x, ww, True), 2)
        if not rng[0] < rng[1]:
            raise ConfigError(f"{w}.speed_range: [low, high] with low < high, got {list(rng)}")
        v["speed_range"] = rng
    if "n_speeds" in d:
        v["n_speeds"] = _int(d["n_speeds"], f"{w}.n_speeds", 1)
    if "stroke" in d:
        v["stroke"] = _num_or_list(d["stroke"], f"{w}.stroke", True)
    if "pose" in d:
        v["pose"] = _list(d["pose"], f"{w}.pose", _num)
    for key in ("window", "switch"):
        if key in d:
            v[key] = _num(d[key], f"{w}.{key}", True)
    for key in ("max_window", "min_span"):
        if key in d:
            v[key] = _num(d[key], f"{w}.{key}", True)
    for key in ("rest", "skip"):
        if key in d:
            v[key] = _num(d[key], f"{w}.{key}", minimum=0.0)
    if "repetitions" in d:
        v["repetitions"] = _int(d["repetitions"], f"{w}.repetitions", 1)
    if "min_samples" in d:
        v["min_samples"] = _int(d["min_samples"], f"{w}.min_samples", 2)
    return v


def load_design_config(path: str | Path) -> DesignConfig:
    """Read and validate a ``dynid design`` TOML file."""
    path = Path(path)
    doc = read_toml(path)
    return parse_design_config(doc, path.resolve().parent, source=path.resolve())
