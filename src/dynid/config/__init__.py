"""The configuration of ``dynid identify``: a strict, typed schema read from TOML.

Unknown keys, wrong types and out-of-range values are :class:`~dynid.errors.ConfigError`
with the dotted key in the message. Relative paths are relative to the config file.
The complete schema with one example is documented in the README ("Configuration").
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config._schema import (  # noqa: F401 - re-exported to the other schemas
    _bool,
    _int,
    _list,
    _num,
    _num_or_list,
    _path,
    _reject_unknown,
    _str,
    _table,
    parse_scheduler,
    parse_workers,
    read_toml,
)
from dynid.errors import ConfigError

__all__ = [
    "Config",
    "RobotConfig",
    "CouplingConfig",
    "SignalConfig",
    "TimeConfig",
    "DataConfig",
    "LowpassConfig",
    "PeriodicConfig",
    "ProcessingConfig",
    "IdentificationConfig",
    "CovarianceConfig",
    "OutputConfig",
    "load_config",
    "parse_config",
    "POSITION_UNITS",
    "TIME_UNITS",
    "EFFORT_UNITS",
    "ROBOT_KEYS",
    "PROCESSING_KEYS",
    "IDENTIFICATION_KEYS",
]

POSITION_UNITS = {"rad": 1.0, "deg": 0.017453292519943295, "m": 1.0, "mm": 1e-3}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
EFFORT_UNITS = {
    "torque": {"N*m": 1.0, "Nm": 1.0, "N.m": 1.0, "mN*m": 1e-3, "N": 1.0},
    "current": {"A": 1.0, "mA": 1e-3},
}
_METHODS = ("ols", "wls", "gm", "irls", "tls", "ml", "iv", "didim")
_FORCE_MODELS = ("projected", "min_norm", "min_norm_local_friction")
_EXTRAS = ("Ia", "fv", "fc", "offset")
_ALL_EXTRAS = _EXTRAS + ("fv+", "fv-", "fc+", "fc-")  # dynid.model.robot.ALL_EXTRAS (config sits above model)


# ---------------------------------------------------------------------- schema
@dataclasses.dataclass(frozen=True)
class CouplingConfig:
    motor: int
    joints: tuple[int, ...]
    weights: tuple[float, ...] = ()


@dataclasses.dataclass(frozen=True)
class RobotConfig:
    """``[robot]``: the model and its drive train."""

    model: str
    extras: tuple[str, ...] = _EXTRAS
    gear_ratios: tuple[float, ...] | None = None
    couplings: tuple[CouplingConfig, ...] = ()
    drive_gains: tuple[float, ...] | None = None
    position_offset: tuple[float, ...] | None = None
    extras_given: bool = False  # extras named in the file (a mechanism then gains them on its actuated joints)
    actuated: tuple[str, ...] | None = None  # mechanisms: actuated joints, in actuator order (default: the model's)
    independent: tuple[str, ...] | None = None  # mechanisms: joints whose positions are the independent coordinates
    rotor_inertia: tuple[float, ...] | None = None  # serial robots: nominal Ia per joint [kg*m^2 or kg, joint side]

    @property
    def has_transmission(self) -> bool:
        return any(
            x for x in (self.gear_ratios, self.couplings, self.drive_gains, self.position_offset)
        )


@dataclasses.dataclass(frozen=True)
class SignalConfig:
    """A group of columns: ``{ columns = [...], unit = ..., side = ..., kind = ..., file = ... }``."""

    columns: tuple[str, ...]
    unit: str | tuple[str, ...] | None  # one for all columns, one per column, None: SI (rad or m; N*m or N; A)
    side: str = "joint"
    kind: str = "torque"
    file: Path | None = None
    topic: str | None = None  # ROS bags: the JointState topic of this signal (None: [data] topic)
    # effort kind = "current": this log's current-to-torque gains per motor, in place of robot.drive_gains
    # (a log recorded with other current sensors or another calibration; [[data]] experiments differ)
    drive_gains: tuple[float, ...] | None = None


@dataclasses.dataclass(frozen=True)
class TimeConfig:
    column: str  # ROS bags: "header" (header.stamp) or "receive" (the bag's receive time)
    unit: str = "s"
    file: Path | None = None


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """``[data]`` (training log) or ``[validation]`` (held-out log)."""

    position: SignalConfig
    effort: SignalConfig
    file: Path | None = None
    time: TimeConfig | None = None
    sample_rate_hz: float | None = None
    velocity: SignalConfig | None = None
    acceleration: SignalConfig | None = None
    rows: tuple[int, int] | None = None
    time_window: tuple[float, float] | None = None
    header: bool = True  # CSV: False reads a headerless file whose columns are named by index (0, 1, ...)
    topic: str | None = None  # ROS bags: the JointState topic of every signal without its own topic
    bag: bool = False  # file is a ROS bag (dynid.io.bags): columns are joint names, time the messages' stamps
    payload: bool | None = None  # [[data]] payload = true|false: the experiment carries the payload (None: not said)

    def files(self) -> tuple[Path, ...]:
        """Every file this spec reads."""
        out = []
        for s in (self.time, self.position, self.effort, self.velocity, self.acceleration):
            if s is not None:
                f = s.file or self.file
                if f is not None and f not in out:
                    out.append(f)
        return tuple(out)


@dataclasses.dataclass(frozen=True)
class LowpassConfig:
    cutoff_hz: float
    order: int = 4
    filter_effort: bool = True


@dataclasses.dataclass(frozen=True)
class PeriodicConfig:
    """``[processing.periodic]``: frequency-domain processing of periodic excitation data
    (paper 004 §3): period averaging and exact DFT filtering and differentiation."""

    period_s: float
    cutoff_hz: float
    average: bool = True
    filter_effort: bool = False
    domain: str = "actuators"  # "pose": parallel robots, filter the reconstructed platform pose (paper 004)


@dataclasses.dataclass(frozen=True)
class ProcessingConfig:
    """``[processing]``: how raw logs become positions, velocities, accelerations, torques."""

    resample: str | float = "auto"
    lowpass: LowpassConfig | None = None
    derivatives: str = "central"  # "central" | "measured" | "kalman" (RTS smoother: dynid.signals.kalman)
    # derivatives = "kalman": the positions' measurement noise std per coordinate (SI, actuator space), e.g.
    # an encoder's resolution / sqrt(12); None: estimated from the log with the smoother's noise ratio
    position_noise_std: tuple[float, ...] | None = None
    decimate: int = 1
    decimate_method: str = "samples"
    trim_samples: int | None = None
    min_velocity: tuple[float, ...] | None = None
    min_velocity_passive: float | None = None  # mechanisms: samples with a slower passive friction joint left out
    periodic: PeriodicConfig | None = None
    reversal_guard: float | str | None = None  # seconds, or "auto" (the low-pass's settling time): rows near a reversal left out

    def reversal_guard_s(self) -> float | None:
        """``reversal_guard`` in seconds (``"auto"``: :func:`dynid.signals.zero_phase_settling_time`
        of ``lowpass``), None when unset."""
        if self.reversal_guard is None:
            return None
        if self.reversal_guard == "auto":
            from dynid.signals import zero_phase_settling_time

            assert self.lowpass is not None  # checked when parsed
            return zero_phase_settling_time(self.lowpass.order, self.lowpass.cutoff_hz)
        return float(self.reversal_guard)

    @property
    def selects_rows(self) -> bool:
        """Whether a row selection (``min_velocity``, ``min_velocity_passive``, ``reversal_guard``) is set."""
        return self.min_velocity is not None or self.min_velocity_passive is not None or self.reversal_guard is not None


@dataclasses.dataclass(frozen=True)
class CovarianceConfig:
    """``[identification] covariance`` and its keys: which covariance of the estimates is reported
    (:mod:`dynid.estimation.block_covariance`). ``blocks`` None: the default number."""

    kind: str = "model"
    blocks: int | None = None
    lags: int = 1
    replicates: int = 500
    seed: int = 0


_COVARIANCE_KINDS = ("model", "hac", "block_bootstrap")  # dynid.estimation.block_covariance.COVARIANCE_KINDS
_COVARIANCE_KEYS = ("covariance", "covariance_blocks", "covariance_lags", "bootstrap_replicates", "bootstrap_seed")


def _parse_covariance(t: Mapping[str, Any], method: str, physical: bool, friction_model: str) -> CovarianceConfig:
    """The covariance keys of ``[identification]``; each only where it applies."""
    where = "identification"
    kind = _str(t.get("covariance", "model"), f"{where}.covariance", _COVARIANCE_KINDS)
    for key, kinds in (("covariance_blocks", ("hac", "block_bootstrap")), ("covariance_lags", ("hac",)),
                       ("bootstrap_replicates", ("block_bootstrap",)), ("bootstrap_seed", ("block_bootstrap",))):
        if key in t and kind not in kinds:
            raise ConfigError(f"{where}.{key} is for covariance = {' or '.join(repr(k) for k in kinds)}, not {kind!r}")
    if kind != "model":
        if method not in ("ols", "wls") or physical or friction_model != "linear":
            what = ("physical_consistency = true" if physical else "friction_model = 'stribeck'" if friction_model != "linear"
                    else f"method = {method!r}")
            raise ConfigError(f"{where}.covariance = {kind!r} is for the linear least-squares methods 'ols' and 'wls' "
                              f"(an estimate that is a sum over blocks), not {what}")
    return CovarianceConfig(
        kind=kind,
        blocks=_int(t["covariance_blocks"], f"{where}.covariance_blocks", 2) if "covariance_blocks" in t else None,
        lags=_int(t.get("covariance_lags", 1), f"{where}.covariance_lags", 0),
        replicates=_int(t.get("bootstrap_replicates", 500), f"{where}.bootstrap_replicates", 2),
        seed=_int(t.get("bootstrap_seed", 0), f"{where}.bootstrap_seed", 0),
    )


@dataclasses.dataclass(frozen=True)
class IdentificationConfig:
    method: str = "wls"
    physical_consistency: bool = False
    chunk_size: int = 20000
    # "auto": a long log (at least dynid.pipeline.streaming.AUTO_ROWS rows) read, processed and compressed
    # chunk by chunk when the configuration allows it; "on": streamed or a ConfigError saying why not;
    # "off": held in memory (dynid.pipeline.streaming)
    streaming: str = "auto"
    # the streamed path's chunks on a Dask cluster (dynid.pipeline.cluster_qr): "off", "local" (a LocalCluster
    # of `workers` processes; 0: the cores this process may use) or a scheduler address (montecarlo.scheduler's
    # syntax; its workers are the cluster's)
    cluster: str = "off"
    workers: int = 0
    base_seed: int = 0
    base_samples: int | None = None
    min_joint_motion: float = 1e-3
    force_model: str | None = None
    noise_covariance: str | tuple[tuple[float, ...], ...] = "residuals"  # ml: "periodic" by default
    iterations: int = 1
    nominal_weighting: bool = False
    position_covariance: str | tuple[tuple[float, ...], ...] = "periodic"  # ml only
    cutoff_range_hz: tuple[float, float] | None = None  # ml only; None: 0.5-2 x processing.periodic.cutoff_hz
    # physically consistent identification (physical_consistency = true; issue 8)
    margin: float = 0.0
    regularization: str = "none"
    regularization_weight: float = 0.0
    solver: str = "CLARABEL"
    bodies: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    friction_model: str = "linear"  # "stribeck": nonlinear friction (paper 000 Eq. 32)
    max_samples: int = 4000  # friction_model = "stribeck": samples used by the nonlinear fit
    # structural reduction (dynid.model.reduction): "auto" (parallel robots: "full" or "identical_chains"
    # chosen from the training data, dynid.pipeline.structure; serial robots: "full"), "full",
    # "identical_chains" or "paper"
    structure: str = "auto"
    identical_chains: tuple[tuple[tuple[str, ...], ...], ...] | None = None  # None: the mechanism's own chains
    covariance: CovarianceConfig = CovarianceConfig()  # the covariance the intervals use (issue 17)
    # methods "iv" and "didim" (issue 17): the experiment replayed on the model under its controller
    experiment: Path | None = None  # the dynid simulate config of the training experiment
    start: str = "wls"  # "wls" (IDIM-WLS estimate) or "nominal" (the robot description's values)
    max_iterations: int = 10
    tolerance: float = 0.5  # stop when no parameter moves by more than this many standard deviations
    # the replays' regularized Coulomb law: tanh(v / v_b), v_b this fraction of the largest measured
    # actuator speed; 0: the discontinuous law (dynid.pipeline.control_loop). Default 0.05 for "iv", 0 for "didim"
    replay_coulomb_band: float = 0.05
    # the directions estimated (fixed at the start's replay): singular values of the scaled step matrix
    # (IV: Z^T W; DIDIM: W_s^T W_s) above this fraction of the largest. Default 1e-3 for "iv", 1e-6 for "didim"
    directions_rtol: float = 1e-3
    # the Coulomb terms' sign: "none" (the sign), "auto" (erf of the data's velocity-noise std), or widths per actuator
    coulomb_smoothing: str | tuple[float, ...] = "none"
    # hierarchical iterative identification (paper 003 Sec. 3.3, Algorithm 1; dynid.pipeline.hierarchical):
    # friction_model then names a paper-003 family ("linear", "stribeck", "powerlaw", "arctan")
    hierarchical: bool = False
    friction_prior: Path | None = None  # a dynid friction result (friction.json): the starting friction


HIERARCHICAL_FAMILIES = ("linear", "stribeck", "powerlaw", "arctan")
"""``friction_model`` with ``hierarchical = true``: paper 003 Eq. 2, 14, 13 and 15 (the improved Stribeck
model); see :data:`dynid.pipeline.hierarchical.FAMILIES`."""


_PHYSICAL_KEYS = ("margin", "regularization", "regularization_weight", "solver", "bodies", "friction_model", "max_samples")
_BODY_KEYS = {"mass", "com_box", "com_ellipsoid"}


def _parse_bodies(t: Any, where: str) -> dict[str, dict[str, Any]]:
    """``[identification.bodies.<name>]``: mass = [lo, hi], com_box = [[x,y,z], [x,y,z]],
    com_ellipsoid = {center = [x,y,z], semi_axes = [a,b,c]}."""
    if not isinstance(t, dict):
        raise ConfigError(f"{where}: expected a table of bodies")

    def vec(v, w, n):
        if not (isinstance(v, list) and len(v) == n):
            raise ConfigError(f"{w} must be a list of {n} numbers")
        return tuple(_num(x, w) for x in v)

    out: dict[str, dict[str, Any]] = {}
    for name, b in t.items():
        w = f"{where}.{name}"
        b = _table(b, w, _BODY_KEYS)
        entry: dict[str, Any] = {}
        if "mass" in b:
            entry["mass"] = vec(b["mass"], f"{w}.mass", 2)
        if "com_box" in b:
            v = b["com_box"]
            if not (isinstance(v, list) and len(v) == 2):
                raise ConfigError(f"{w}.com_box must be [[x, y, z] low, [x, y, z] high] in m")
            entry["com_box"] = (vec(v[0], f"{w}.com_box", 3), vec(v[1], f"{w}.com_box", 3))
        if "com_ellipsoid" in b:
            e = _table(b["com_ellipsoid"], f"{w}.com_ellipsoid", {"center", "semi_axes"}, {"center", "semi_axes"})
            entry["com_ellipsoid"] = (vec(e["center"], f"{w}.com_ellipsoid.center", 3),
                                      vec(e["semi_axes"], f"{w}.com_ellipsoid.semi_axes", 3))
        out[str(name)] = entry
    return out


@dataclasses.dataclass(frozen=True)
class OutputConfig:
    plots: bool = True


@dataclasses.dataclass(frozen=True)
class Config:
    robot: RobotConfig
    data: DataConfig
    validation: DataConfig
    processing: ProcessingConfig = ProcessingConfig()
    identification: IdentificationConfig = IdentificationConfig()
    output: OutputConfig = OutputConfig()
    source: Path | None = None
    learning: Any = None  # dynid.learning.LearningConfig: [learning] (config/learning.py), None without
    raw: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    # [[data]] / [[validation]] (arrays of tables): every experiment, ``data`` / ``validation`` their first;
    # empty with a single [data] / [validation] table (dynid.pipeline.experiments)
    experiments: tuple[DataConfig, ...] = ()
    validations: tuple[DataConfig, ...] = ()
    # [payload] of dynid identify: the joint arm + payload mode (dynid.config.payload.PayloadConfig; None: no payload)
    payload: Any = None

    @property
    def training_logs(self) -> tuple[DataConfig, ...]:
        """Every training experiment: the [[data]] entries, or the single [data]."""
        return self.experiments or (self.data,)

    @property
    def validation_logs(self) -> tuple[DataConfig, ...]:
        """Every held-out log: the [[validation]] entries, or the single [validation]."""
        return self.validations or (self.validation,)


# ---------------------------------------------------------------------- parsing
ROBOT_KEYS = ("extras", "gear_ratios", "couplings", "drive_gains", "position_offset", "actuated", "independent",
              "rotor_inertia")
"""The keys of ``[robot]`` besides ``model``."""
PROCESSING_KEYS = ("resample", "lowpass", "derivatives", "position_noise_std", "decimate", "decimate_method", "trim_samples", "min_velocity",
                   "min_velocity_passive", "periodic", "reversal_guard")
"""The keys of ``[processing]``."""


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


def _column(v: Any, where: str, header: bool) -> str:
    """A column name; without a header row (``header = false``) a column index 0, 1, ... (kept as its text)."""
    if header:
        return _str(v, where)
    if isinstance(v, str):
        raise ConfigError(f"{where}: the file has no header row (header = false): name columns by index "
                          f"(0 is the first column), got {v!r}")
    return str(_int(v, where, 0))


def _parse_signal(t: Any, where: str, base: Path, what: str, header: bool = True, bag: bool = False) -> SignalConfig:
    allowed = {"columns", "unit", "side", "file", "topic"} | ({"kind", "drive_gains"} if what == "effort" else set())
    t = _table(t, where, allowed, {"columns"})
    if bag and "file" in t:
        raise ConfigError(f"{where}.file: every signal of a ROS bag log comes from the bag of {where.split('.')[0]}.file; "
                          f"give a signal its own topic with {where}.topic")
    if "topic" in t and not bag:
        raise ConfigError(f"{where}.topic is for ROS bags (file = a .bag, a ROS 2 bag folder, .db3 or .mcap)")
    cols = t["columns"]
    column = lambda v, w: _column(v, w, header)  # noqa: E731
    columns = (column(cols, f"{where}.columns"),) if not isinstance(cols, list) else _list(cols, f"{where}.columns", column)
    if not columns:
        raise ConfigError(f"{where}.columns: empty")
    twice = sorted({c for c in columns if columns.count(c) > 1})
    if twice:
        raise ConfigError(f"{where}.columns: {', '.join(repr(c) for c in twice)} named more than once "
                          "(one column per joint or actuator)")
    side = _str(t.get("side", "joint"), f"{where}.side", ("joint", "motor"))
    # a unit, one per column, or none (SI: rad or m, N*m or N, A); checked against the joints
    # once the model is known (dynid.pipeline.data.check_units)
    if what == "effort":
        kind = _str(t.get("kind", "torque"), f"{where}.kind", ("torque", "current"))
        units = tuple(EFFORT_UNITS[kind])
    else:
        kind = "torque"
        units = tuple(POSITION_UNITS)
    unit = None
    if "unit" in t:
        u = t["unit"]
        unit = _list(u, f"{where}.unit", lambda v, w: _str(v, w, units)) if isinstance(u, list) else _str(u, f"{where}.unit", units)
        if isinstance(unit, tuple) and len(unit) != len(columns) and len(columns) > 1:
            raise ConfigError(f"{where}.unit: {len(unit)} units for {len(columns)} columns")
    file = _path(t["file"], f"{where}.file", base) if "file" in t else None
    if file is not None and is_bag(file):
        raise ConfigError(f"{where}.file: {file.name} is a ROS bag; a bag is the file of the whole log ({where.split('.')[0]}.file)")
    topic = _str(t["topic"], f"{where}.topic") if "topic" in t else None
    gains = None
    if "drive_gains" in t:
        if kind != "current":
            raise ConfigError(f"{where}.drive_gains convert motor currents: they need {where}.kind = 'current'")
        g = _num_or_list(t["drive_gains"], f"{where}.drive_gains")
        gains = g if isinstance(g, tuple) else (g,)
        if any(v == 0 or not math.isfinite(v) for v in gains):
            raise ConfigError(f"{where}.drive_gains: every gain must be finite and non-zero, got {list(gains)}")
        if len(gains) not in (1, len(columns)):
            raise ConfigError(f"{where}.drive_gains: {len(gains)} gains for {len(columns)} columns")
    return SignalConfig(columns=columns, unit=unit, side=side, kind=kind, file=file, topic=topic, drive_gains=gains)


_DATA_KEYS = {"file", "time", "sample_rate_hz", "position", "effort", "velocity", "acceleration", "rows", "time_window",
              "header", "topic"}
_BAG_ONLY = ("topic",)


def _reads_bag(file: Path, t: Mapping[str, Any]) -> bool:
    """Whether a [data] table whose file is ``file`` reads a ROS bag: a .bag, .db3, .mcap, a ROS 2 bag folder, or
    a path without a suffix given a topic (a folder that is not a bag, or is not there: the bag reader says so)."""
    return is_bag(file) or ("topic" in t and file.suffix == "")


def is_bag(path: Path) -> bool:
    """A ROS bag (:func:`dynid.io.bags.is_bag`: .bag, .db3, .mcap, or a folder with metadata.yaml)."""
    return path.suffix.lower() in (".bag", ".db3", ".mcap") or (path / "metadata.yaml").is_file()


def _parse_bag_time(t: Mapping[str, Any], where: str) -> TimeConfig:
    """``time`` of a ROS bag log: ``"header"`` (default) or ``"receive"``."""
    if "sample_rate_hz" in t:
        raise ConfigError(f"{where}.sample_rate_hz: a ROS bag's messages carry their own time; use {where}.time = "
                          "'header' (the messages' header stamps, default) or 'receive' (the bag's receive time)")
    v = t.get("time", "header")
    if not isinstance(v, str):
        raise ConfigError(f"{where}.time of a ROS bag log is 'header' (the messages' header stamps, default) or "
                          f"'receive' (the bag's receive time), got {v!r}")
    return TimeConfig(column=_str(v, f"{where}.time", ("header", "receive")))


def _parse_data(t: Any, where: str, base: Path) -> DataConfig:
    t = _table(t, where, _DATA_KEYS, {"position", "effort"})
    file = _path(t["file"], f"{where}.file", base) if "file" in t else None
    bag = file is not None and _reads_bag(file, t)
    if bag:
        if "header" in t:
            raise ConfigError(f"{where}.header is for CSV files; {file.name} is a ROS bag")
        if "topic" not in t and not all(isinstance(t.get(k), dict) and "topic" in t[k]
                                        for k in ("position", "effort", "velocity", "acceleration") if k in t):
            raise ConfigError(f"{where}.topic: name the sensor_msgs/JointState topic of the bag {file.name} "
                              f"(or a topic per signal)")
        if "acceleration" in t:
            raise ConfigError(f"{where}.acceleration: a JointState message has no accelerations (position, velocity, effort)")
        return _parse_bag_data(t, where, base, file)
    given = [k for k in _BAG_ONLY if k in t]
    if given:
        raise ConfigError(f"{where}.{given[0]} is for ROS bags (file = a .bag, a ROS 2 bag folder, .db3 or .mcap)")
    header = _bool(t.get("header", True), f"{where}.header")
    time = None
    if "time" in t:
        if isinstance(t["time"], str):
            raise ConfigError(f"{where}.time: expected a table, got str ({t['time']!r}); a table's time is a column, "
                              f"{where}.time = {{ column = ... }} (time = 'header' or 'receive' is for ROS bags)")
        tt = _table(t["time"], f"{where}.time", {"column", "unit", "file"}, {"column"})
        time = TimeConfig(
            column=_column(tt["column"], f"{where}.time.column", header),
            unit=_str(tt.get("unit", "s"), f"{where}.time.unit", tuple(TIME_UNITS)),
            file=_path(tt["file"], f"{where}.time.file", base) if "file" in tt else None,
        )
    fs = _num(t["sample_rate_hz"], f"{where}.sample_rate_hz", positive=True) if "sample_rate_hz" in t else None
    if (time is None) == (fs is None):
        raise ConfigError(f"{where}: give exactly one of 'time' (a time column) or 'sample_rate_hz'")
    rows, window = _windows(t, where)
    spec = DataConfig(
        file=file,
        time=time,
        sample_rate_hz=fs,
        position=_parse_signal(t["position"], f"{where}.position", base, "position", header),
        effort=_parse_signal(t["effort"], f"{where}.effort", base, "effort", header),
        velocity=_parse_signal(t["velocity"], f"{where}.velocity", base, "velocity", header) if "velocity" in t else None,
        acceleration=_parse_signal(t["acceleration"], f"{where}.acceleration", base, "acceleration", header)
        if "acceleration" in t
        else None,
        rows=rows,
        time_window=window,
        header=header,
    )
    for s, label in ((spec.position, "position"), (spec.effort, "effort"), (spec.velocity, "velocity"),
                     (spec.acceleration, "acceleration"), (spec.time, "time")):
        if s is not None and s.file is None and spec.file is None:
            raise ConfigError(f"{where}.{label}: no file (set {where}.file or {where}.{label}.file)")
    return spec


def _parse_bag_data(t: Mapping[str, Any], where: str, base: Path, file: Path) -> DataConfig:
    """``[data]`` reading a ROS bag: columns are joint names of sensor_msgs/JointState messages."""
    rows, window = _windows(t, where)
    signal = lambda key: _parse_signal(t[key], f"{where}.{key}", base, key, bag=True) if key in t else None  # noqa: E731
    return DataConfig(
        file=file,
        time=_parse_bag_time(t, where),
        position=signal("position"),
        effort=signal("effort"),
        velocity=signal("velocity"),
        rows=rows,
        time_window=window,
        topic=_str(t["topic"], f"{where}.topic") if "topic" in t else None,
        bag=True,
    )


def _windows(t: Mapping[str, Any], where: str) -> tuple[tuple[int, int] | None, tuple[float, float] | None]:
    """``rows`` and ``time_window`` (at most one)."""
    rows = None
    if "rows" in t:
        rows = _list(t["rows"], f"{where}.rows", lambda v, w: _int(v, w, 0), 2)
        if rows[1] <= rows[0]:
            raise ConfigError(f"{where}.rows: stop {rows[1]} must exceed start {rows[0]}")
    window = None
    if "time_window" in t:
        window = _list(t["time_window"], f"{where}.time_window", _num, 2)
        if window[1] <= window[0]:
            raise ConfigError(f"{where}.time_window: end must exceed start")
    if rows is not None and window is not None:
        raise ConfigError(f"{where}: give 'rows' or 'time_window', not both")
    return rows, window


def _noise_std(t: dict, where: str) -> tuple[float, ...] | None:
    """``processing.position_noise_std``: one value or one per coordinate, only with derivatives = 'kalman'."""
    if "position_noise_std" not in t:
        return None
    if t.get("derivatives") != "kalman":
        raise ConfigError(f"{where}.position_noise_std is the measurement noise of the Kalman smoother: it needs "
                          f"{where}.derivatives = 'kalman'")
    v = _num_or_list(t["position_noise_std"], f"{where}.position_noise_std", positive=True)
    return v if isinstance(v, tuple) else (v,)


def _parse_processing(t: Any) -> ProcessingConfig:
    where = "processing"
    t = _table(t, where, set(PROCESSING_KEYS))
    resample: str | float = "auto"
    if "resample" in t:
        r = t["resample"]
        resample = _str(r, f"{where}.resample", ("auto", "off")) if isinstance(r, str) else _num(r, f"{where}.resample", positive=True)
    lowpass = None
    if "lowpass" in t:
        lp = _table(t["lowpass"], f"{where}.lowpass", {"cutoff_hz", "order", "filter_effort"}, {"cutoff_hz"})
        lowpass = LowpassConfig(
            cutoff_hz=_num(lp["cutoff_hz"], f"{where}.lowpass.cutoff_hz", positive=True),
            order=_int(lp.get("order", 4), f"{where}.lowpass.order", 1),
            filter_effort=_bool(lp.get("filter_effort", True), f"{where}.lowpass.filter_effort"),
        )
    mv = None
    if "min_velocity" in t:
        v = t["min_velocity"]
        mv = _num_or_list(v, f"{where}.min_velocity", minimum=0.0)
        mv = mv if isinstance(mv, tuple) else (mv,)
    guard: float | str | None = None
    if "reversal_guard" in t:
        g = t["reversal_guard"]
        guard = (_str(g, f"{where}.reversal_guard", ("auto",)) if isinstance(g, str)
                 else _num(g, f"{where}.reversal_guard", minimum=0.0))
        if "periodic" in t:
            raise ConfigError(f"{where}.reversal_guard applies to the time-domain processing (lowpass, central "
                              f"differences); {where}.periodic filters whole periods in the frequency domain")
        if guard == "auto" and lowpass is None:
            raise ConfigError(f"{where}.reversal_guard = 'auto' is the settling time of {where}.lowpass, which is not "
                              "set; give the guard in seconds or set the low-pass")
    periodic = None
    if "periodic" in t:
        pt = _table(t["periodic"], f"{where}.periodic", {"period_s", "cutoff_hz", "average", "filter_effort", "domain"}, {"period_s", "cutoff_hz"})
        periodic = PeriodicConfig(
            period_s=_num(pt["period_s"], f"{where}.periodic.period_s", positive=True),
            cutoff_hz=_num(pt["cutoff_hz"], f"{where}.periodic.cutoff_hz", positive=True),
            average=_bool(pt.get("average", True), f"{where}.periodic.average"),
            filter_effort=_bool(pt.get("filter_effort", False), f"{where}.periodic.filter_effort"),
            domain=_str(pt.get("domain", "actuators"), f"{where}.periodic.domain", ("actuators", "pose")),
        )
        clash = [k for k in ("lowpass", "decimate", "trim_samples") if k in t] + (["derivatives"] if t.get("derivatives") in ("measured", "kalman") else [])
        if clash:
            raise ConfigError(f"{where}.periodic replaces {clash}: the frequency-domain processing filters, differentiates and keeps whole periods itself")
    return ProcessingConfig(
        periodic=periodic,
        resample=resample,
        lowpass=lowpass,
        derivatives=_str(t.get("derivatives", "central"), f"{where}.derivatives", ("central", "measured", "kalman")),
        position_noise_std=_noise_std(t, where),
        decimate=_int(t.get("decimate", 1), f"{where}.decimate", 1),
        decimate_method=_str(t.get("decimate_method", "samples"), f"{where}.decimate_method", ("samples", "parallel")),
        trim_samples=_int(t["trim_samples"], f"{where}.trim_samples", 0) if "trim_samples" in t else None,
        min_velocity=mv,
        min_velocity_passive=(_num(t["min_velocity_passive"], f"{where}.min_velocity_passive", minimum=0.0)
                              if "min_velocity_passive" in t else None),
        reversal_guard=guard,
    )


_STRUCTURES = ("auto", "full", "identical_chains", "paper")  # "auto" + dynid.model.reduction.STRUCTURES (config sits above model)


def _chain_groups(spec: Any, where: str) -> tuple[tuple[tuple[str, ...], ...], ...]:
    """``identical_chains``: one group of chains ``[["a1", "b1", "P1"], ["a2", "b2", "P2"], ...]`` (each chain
    its joint names in corresponding order) or several groups ``[[["a1", "b1"], ["a2", "b2"]], [...]]``."""
    if not isinstance(spec, list) or not spec:
        raise ConfigError(f"{where} must be a non-empty list of chains (lists of joint names)")
    nested = all(isinstance(c, list) and c and isinstance(c[0], list) for c in spec)
    out = []
    for g in spec if nested else [spec]:
        if not isinstance(g, list) or len(g) < 2:
            raise ConfigError(f"{where}: a group needs at least two chains, got {g!r}")
        for c in g:
            if not isinstance(c, list) or not c or not all(isinstance(j, str) for j in c):
                raise ConfigError(f"{where}: a chain is a list of joint names, got {c!r}")
        out.append(tuple(tuple(c) for c in g))
    return tuple(out)


_LOOP_KEYS = ("experiment", "start", "max_iterations", "tolerance", "replay_coulomb_band", "directions_rtol")


IDENTIFICATION_KEYS = ("method", "physical_consistency", "chunk_size", "streaming", "cluster", "workers", "base_seed", "base_samples", "min_joint_motion",
                       "force_model", "noise_covariance", "iterations", "nominal_weighting", "position_covariance",
                       "cutoff_range_hz", "structure", "identical_chains", "coulomb_smoothing", "hierarchical",
                       "friction_prior", *_PHYSICAL_KEYS, *_COVARIANCE_KEYS, *_LOOP_KEYS)
"""The keys of ``[identification]``."""


def _parse_cluster(t: Mapping[str, Any], where: str) -> dict[str, Any]:
    """``cluster`` ("off", "local" or a Dask scheduler address) and ``workers`` (with "local" only)."""
    cluster = t.get("cluster", "off")
    if cluster not in ("off", "local"):
        if not (isinstance(cluster, str) and "://" in cluster):  # a bare word is a typo of a choice, not a host
            raise ConfigError(f"{where}.cluster: expected 'off', 'local' or a Dask scheduler address with its scheme "
                              f"(tcp://host:8786), got {cluster!r}")
        cluster = parse_scheduler(cluster, f"{where}.cluster")
    if "workers" in t and cluster != "local":
        raise ConfigError(f"{where}.workers is the size of the local cluster (cluster = 'local'); with cluster = "
                          f"{cluster!r} " + ("nothing runs on workers" if cluster == "off" else "the scheduler's workers run it"))
    return {"cluster": cluster, "workers": parse_workers(t.get("workers", 0), f"{where}.workers")}


def _parse_identification(t: Any, base: Path = Path(".")) -> IdentificationConfig:
    where = "identification"
    t = _table(t, where, set(IDENTIFICATION_KEYS))
    method = _str(t.get("method", "wls"), f"{where}.method", _METHODS)
    physical = _bool(t.get("physical_consistency", False), f"{where}.physical_consistency")
    hierarchical = _bool(t.get("hierarchical", False), f"{where}.hierarchical")
    if not hierarchical and t.get("friction_model") in ("powerlaw", "arctan"):
        raise ConfigError(f"{where}.friction_model = {t['friction_model']!r} is a family of the hierarchical "
                          f"identification (paper 003 Sec. 3.3): set {where}.hierarchical = true")
    given = [k for k in _PHYSICAL_KEYS if k in t and not (hierarchical and k == "friction_model")]
    if given and not physical:
        raise ConfigError(f"{where}.{given[0]} is for physically consistent identification: set "
                          f"{where}.physical_consistency = true")
    if physical and method not in ("ols", "wls", "gm", "didim"):
        raise ConfigError(f"{where}.physical_consistency = true is available with methods 'ols', 'wls', 'gm' and "
                          f"'didim', not {method!r}")
    loop = method in ("iv", "didim")
    extra = [k for k in _LOOP_KEYS if k in t]
    if extra and not loop:
        raise ConfigError(f"{where}.{extra[0]} is for method = 'iv' or 'didim' (the experiment replayed on the model)")
    if loop and "experiment" not in t:
        raise ConfigError(f"{where}.method = {method!r} simulates the experiment with the current estimate under its "
                          f"controller: set {where}.experiment to the dynid simulate config of the training experiment "
                          "(controller, gains, reference, rates)")
    reg = _str(t.get("regularization", "none"), f"{where}.regularization", ("none", "euclidean", "logdet"))
    # a named regularization weighs 1 by default: lambda is in units of the residual chi^2 (PhysicalLS), so at 1 a
    # unit divergence from the nominal model costs as much as one noise variance of extra residual; "none" has none
    reg_w = _num(t.get("regularization_weight", 0.0 if reg == "none" else 1.0), f"{where}.regularization_weight")
    if reg == "none" and reg_w != 0.0:
        raise ConfigError(f"{where}.regularization_weight = {reg_w:g} needs a regularization: set "
                          f"{where}.regularization = 'euclidean' or 'logdet'")
    if reg != "none" and not reg_w > 0:
        raise ConfigError(f"{where}.regularization = {reg!r} needs regularization_weight > 0 (default 1), got {reg_w:g}")
    margin = _num(t.get("margin", 0.0), f"{where}.margin")
    if margin < 0:
        raise ConfigError(f"{where}.margin must be >= 0, got {margin}")
    if hierarchical:
        if "friction_model" not in t:
            raise ConfigError(f"{where}.hierarchical = true alternates rigid-body and friction fits: name the friction "
                              f"family, {where}.friction_model = 'stribeck', 'powerlaw', 'arctan' or 'linear' "
                              "(paper 003 Eq. 14, 13, 15, 2)")
        friction_model = _str(t["friction_model"], f"{where}.friction_model", HIERARCHICAL_FAMILIES)
        if method not in ("ols", "wls"):
            raise ConfigError(f"{where}.hierarchical = true fits the rigid-body part by 'ols' or 'wls' (+ LMI with "
                              f"physical_consistency), not method {method!r}")
        if "max_samples" in t:
            raise ConfigError(f"{where}.max_samples is for the paper-000 Stribeck fit; hierarchical = true uses every "
                              "processed training sample")
        if "covariance" in t and t["covariance"] != "model":
            raise ConfigError(f"{where}.covariance = {t['covariance']!r} is not available with hierarchical = true "
                              "(the rigid-body fit is repeated on friction-corrected torques; only the model covariance)")
        if "coulomb_smoothing" in t:
            raise ConfigError(f"{where}.coulomb_smoothing is for the linear friction columns; hierarchical = true fits "
                              "the friction curve itself (friction_model = 'arctan' smooths with arctan, Eq. 15)")
    else:
        friction_model = _str(t.get("friction_model", "linear"), f"{where}.friction_model", ("linear", "stribeck"))
        if "friction_prior" in t:
            raise ConfigError(f"{where}.friction_prior is the starting friction of hierarchical = true; set "
                              f"{where}.hierarchical = true or remove it")
    if "max_samples" in t and friction_model != "stribeck":
        raise ConfigError(f"{where}.max_samples is for friction_model = 'stribeck' (the rows of the nonlinear fit)")
    for key, need in (("noise_covariance", ("gm", "ml")), ("iterations", ("gm",)), ("nominal_weighting", ("wls",)),
                      ("position_covariance", ("ml",)), ("cutoff_range_hz", ("ml",))):
        if key in t and method not in need:
            raise ConfigError(f"{where}.{key} is for method = {' or '.join(repr(m) for m in need)}, not {method!r}")

    def matrix(key: str, words: tuple[str, ...]) -> Any:
        v = t[key]
        if isinstance(v, str):
            return _str(v, f"{where}.{key}", words)
        if isinstance(v, list) and v and all(isinstance(r, list) and len(r) == len(v) for r in v):
            return tuple(tuple(_num(x, f"{where}.{key}") for x in r) for r in v)
        raise ConfigError(f"{where}.{key} must be {' or '.join(repr(w) for w in words)} or a square matrix (list of rows)")

    ncov: Any = "periodic" if method == "ml" else "residuals"
    if "noise_covariance" in t:
        ncov = matrix("noise_covariance", ("periodic",) if method == "ml" else ("residuals", "periodic"))
    pcov = matrix("position_covariance", ("periodic",)) if "position_covariance" in t else "periodic"
    crange = None
    if "cutoff_range_hz" in t:
        v = t["cutoff_range_hz"]
        if not (isinstance(v, list) and len(v) == 2):
            raise ConfigError(f"{where}.cutoff_range_hz must be [low, high] in Hz")
        crange = (_num(v[0], f"{where}.cutoff_range_hz"), _num(v[1], f"{where}.cutoff_range_hz"))
        if not 0 < crange[0] < crange[1]:
            raise ConfigError(f"{where}.cutoff_range_hz must satisfy 0 < low < high, got {list(crange)}")
    smoothing: str | tuple[float, ...] = "none"
    if "coulomb_smoothing" in t:
        v = t["coulomb_smoothing"]
        if isinstance(v, str):
            smoothing = _str(v, f"{where}.coulomb_smoothing", ("none", "auto"))
        elif isinstance(v, list) and v:
            smoothing = tuple(_num(x, f"{where}.coulomb_smoothing", minimum=0.0) for x in v)
        else:
            raise ConfigError(f"{where}.coulomb_smoothing must be 'none', 'auto' or a list of velocity widths per actuator "
                              "[rad/s or m/s]")
        if smoothing != "none" and (method not in ("ols", "wls", "gm", "ml") or friction_model != "linear"):
            raise ConfigError(f"{where}.coulomb_smoothing is available with methods 'ols', 'wls', 'gm' and 'ml' and the linear "
                              f"friction model, not method {method!r}" + (" with friction_model = 'stribeck'"
                                                                            if friction_model != "linear" else ""))
    chains = _chain_groups(t["identical_chains"], f"{where}.identical_chains") if "identical_chains" in t else None
    # chains named by hand tie them unless the structure says otherwise ("auto": tied or full, from the data)
    structure = _str(t.get("structure", "identical_chains" if chains else "auto"), f"{where}.structure", _STRUCTURES)
    if chains and structure == "full":
        raise ConfigError(f"{where}.identical_chains needs {where}.structure = 'identical_chains', 'paper' or 'auto', "
                          "not 'full'")
    return IdentificationConfig(
        structure=structure,
        identical_chains=chains,
        coulomb_smoothing=smoothing,
        hierarchical=hierarchical,
        friction_prior=_path(t["friction_prior"], f"{where}.friction_prior", base) if "friction_prior" in t else None,
        experiment=_path(t["experiment"], f"{where}.experiment", base) if loop else None,
        start=_str(t.get("start", "wls" if method == "iv" else "nominal"), f"{where}.start", ("wls", "nominal")),
        max_iterations=_int(t.get("max_iterations", 10), f"{where}.max_iterations", 1),
        tolerance=_num(t.get("tolerance", 0.5), f"{where}.tolerance", minimum=0.0),
        replay_coulomb_band=_num(t.get("replay_coulomb_band", 0.05 if method == "iv" else 0.0), f"{where}.replay_coulomb_band",
                                 minimum=0.0),
        directions_rtol=_num(t.get("directions_rtol", 1e-3 if method == "iv" else 1e-6), f"{where}.directions_rtol",
                             positive=True),
        noise_covariance=ncov,
        position_covariance=pcov,
        cutoff_range_hz=crange,
        iterations=_int(t.get("iterations", 1), f"{where}.iterations", 1),
        nominal_weighting=_bool(t.get("nominal_weighting", False), f"{where}.nominal_weighting"),
        method=method,
        physical_consistency=physical,
        margin=margin,
        regularization=reg,
        regularization_weight=reg_w,
        solver=_str(t.get("solver", "CLARABEL"), f"{where}.solver"),
        bodies=_parse_bodies(t["bodies"], f"{where}.bodies") if "bodies" in t else {},
        friction_model=friction_model,
        covariance=_parse_covariance(t, method, physical, "linear" if hierarchical else friction_model),
        max_samples=_int(t.get("max_samples", 4000), f"{where}.max_samples", 100),
        chunk_size=_int(t.get("chunk_size", 20000), f"{where}.chunk_size", 1),
        streaming=_str(t.get("streaming", "auto"), f"{where}.streaming", ("auto", "on", "off")),
        **_parse_cluster(t, where),
        base_seed=_int(t.get("base_seed", 0), f"{where}.base_seed", 0),
        base_samples=_int(t["base_samples"], f"{where}.base_samples", 1) if "base_samples" in t else None,
        min_joint_motion=_num(t.get("min_joint_motion", 1e-3), f"{where}.min_joint_motion", minimum=0.0),
        force_model=_str(t["force_model"], f"{where}.force_model", _FORCE_MODELS) if "force_model" in t else None,
    )


def parse_config(doc: Mapping[str, Any], base_dir: Path, source: Path | None = None) -> Config:
    """Validate a parsed TOML document into a :class:`Config`."""
    doc = _table(dict(doc), "config", {"robot", "data", "validation", "processing", "identification", "output", "learning",
                                       "data_root", "payload"}, {"robot", "data", "validation"})
    data_base = data_root(doc, base_dir)
    data_list, val_list = _tables_or_array(doc["data"], "data"), _tables_or_array(doc["validation"], "validation")
    many = isinstance(doc["data"], list) or isinstance(doc["validation"], list)
    method = doc.get("identification", {}).get("method") if isinstance(doc.get("identification"), dict) else None
    if len(data_list) > 1 and method in ("iv", "didim", "ml", "gm"):  # before the methods' own checks
        raise ConfigError(f"data: {len(data_list)} [[data]] experiments, but identification.method = {method!r} (only "
                          "'ols' and 'wls' stack experiments' factors; iv/didim run the control loop over one log, ml "
                          "cuts one log's filter, gm needs one log's cross-channel factor); give one [data] table")
    payloads = []
    for i, t in enumerate(data_list):
        where = f"data[{i}]" if isinstance(doc["data"], list) else "data"
        payloads.append(_bool(t.pop("payload"), f"{where}.payload") if "payload" in t else None)
    experiments = tuple(dataclasses.replace(_parse_data(t, f"data[{i}]", data_base), payload=pl)
                        for i, (t, pl) in enumerate(zip(data_list, payloads))) if many else ()
    val_payloads = []
    for i, t in enumerate(val_list):
        where = f"validation[{i}]" if isinstance(doc["validation"], list) else "validation"
        val_payloads.append(_bool(t.pop("payload"), f"{where}.payload") if "payload" in t else None)
    validations = tuple(dataclasses.replace(_validation_spec(data_list[0], v, data_base, f"validation[{i}]"), payload=pl)
                        for i, (v, pl) in enumerate(zip(val_list, val_payloads))) if many else ()
    payload = _joint_payload(doc, payloads, val_payloads, method)
    if many:
        for i, v in enumerate(validations):
            for j, d in enumerate(experiments):
                _check_held_out_windows(d, v, f"data[{j}]", f"validation[{i}]")
    data, validation = _validation_pair(data_list[0], val_list[0], data_base)
    if payloads[0] is not None:
        data = dataclasses.replace(data, payload=payloads[0])
    if val_payloads[0] is not None:
        validation = dataclasses.replace(validation, payload=val_payloads[0])
    out_t = _table(doc.get("output", {}), "output", {"plots"})
    processing = _parse_processing(doc.get("processing", {}))
    for label, spec in (("data", data), ("validation", validation), *((f"data[{i}]", d) for i, d in enumerate(experiments)),
                        *((f"validation[{i}]", d) for i, d in enumerate(validations))):
        given = [k for k in ("velocity", "acceleration") if getattr(spec, k) is not None]
        if given and processing.derivatives != "measured":
            raise ConfigError(f"{label}.{given[0]} columns are given but processing.derivatives = "
                              f"{processing.derivatives!r} differentiates the positions and would ignore them: "
                              "set processing.derivatives = 'measured' or drop them")
    return Config(
        robot=_parse_robot(doc["robot"], base_dir),
        data=data,
        validation=validation,
        processing=processing,
        identification=_parse_identification(doc.get("identification", {}), base_dir),
        output=OutputConfig(plots=_bool(out_t.get("plots", True), "output.plots")),
        source=source,
        raw=doc,
        learning=_learning(doc.get("learning")),
        experiments=experiments,
        validations=validations,
        payload=payload,
    )


def _joint_payload(doc: Mapping[str, Any], payloads: list, val_payloads: list, method: Any):
    """``[payload]`` of ``dynid identify`` (the joint mode, :mod:`dynid.pipeline.joint_payload`) and its refusals."""
    loaded = [i for i, v in enumerate(payloads) if v]
    if "payload" not in doc:
        marked = [f"data[{i}]" for i in loaded] + [f"validation[{i}]" for i, v in enumerate(val_payloads) if v]
        if marked:
            raise ConfigError(f"{marked[0]}.payload = true but there is no [payload] table (body, optional mass, "
                              "origin): give it to identify the payload jointly with the arm")
        return None
    from dynid.config._payload import parse_joint_payload

    if isinstance(doc["payload"], dict) and "arm" in doc["payload"]:
        raise ConfigError("payload.arm: dynid identify identifies the arm itself (jointly); 'arm' is read by "
                          "dynid payload (the given-arm mode)")
    spec = parse_joint_payload(doc["payload"])
    if not isinstance(doc["data"], list):
        raise ConfigError("payload: the joint mode needs [[data]] experiments, some with payload = true and some "
                          "without; a single [data] table cannot tell the payload from its body")
    if not loaded:
        raise ConfigError("payload: a [payload] table but no [[data]] experiment has payload = true (mark the "
                          "experiments recorded with the payload mounted)")
    if len(loaded) == len(payloads):
        raise ConfigError("payload: every [[data]] experiment has payload = true; the arm and the payload cannot be "
                          "told apart (their mount body's columns coincide): add an experiment without it")
    if method not in (None, "ols", "wls"):
        raise ConfigError(f"payload: identification.method = {method!r}; the joint arm + payload fit supports "
                          "'ols' and 'wls' (the payload block physically consistent with payload.physical)")
    return spec


def _tables_or_array(v: Any, where: str) -> list[dict[str, Any]]:
    """``[where]`` (one table) or ``[[where]]`` (a non-empty array of tables), as a list of copies."""
    if isinstance(v, list):
        if not v:
            raise ConfigError(f"{where}: an empty array; give at least one [[{where}]] table")
        for i, t in enumerate(v):
            if not isinstance(t, dict):
                raise ConfigError(f"{where}[{i}]: expected a table, got {type(t).__name__}")
        return [dict(t) for t in v]
    if not isinstance(v, dict):
        raise ConfigError(f"{where}: expected a table, got {type(v).__name__}")
    return [dict(v)]


def _validation_spec(data_t: Mapping[str, Any], val_t: Mapping[str, Any], data_base: Path, where: str) -> DataConfig:
    """A held-out log's spec: its keys over the (first) training table's, as for a single [validation]."""
    return _parse_data(_inherit(dict(data_t), dict(val_t), data_base, where), where, data_base)


def _check_held_out_windows(data: DataConfig, validation: DataConfig, dl: str, vl: str) -> None:
    """A held-out log reading a training file holds out other samples."""
    if set(validation.files()) != set(data.files()):
        return
    if validation.rows is None and validation.time_window is None:
        raise ConfigError(f"{vl}: uses the training file of {dl} without 'rows' or 'time_window'; hold out samples")
    if data.rows is None and data.time_window is None:
        raise ConfigError(f"{dl}: training uses the whole file that {vl} also reads; set rows or time_window")
    if (data.rows is None) != (validation.rows is None):
        raise ConfigError(f"{dl} and {vl} windows must both be 'rows' or both 'time_window'")
    a, b = (data.rows, validation.rows) if data.rows is not None else (data.time_window, validation.time_window)
    if a[0] < b[1] and b[0] < a[1]:
        raise ConfigError(f"{vl} window {list(b)} overlaps the training window {list(a)} of {dl}")


def _inherit(data_t: dict[str, Any], val_t: dict[str, Any], data_base: Path, where: str = "validation") -> dict[str, Any]:
    _reject_unknown(val_t, where, _DATA_KEYS)
    inherited = {k: v for k, v in data_t.items() if k not in ("rows", "time_window")}
    # A time source given in [validation] replaces the inherited one (time column or rate).
    if "sample_rate_hz" in val_t:
        inherited.pop("time", None)
    if "time" in val_t:
        inherited.pop("sample_rate_hz", None)
    # [validation] file = ... replaces the files of inherited signals, so that no signal
    # is silently read from a training file named in [data].<signal>.file.
    if "file" in val_t:
        for key in ("time", "position", "effort", "velocity", "acceleration"):
            if key in inherited and key not in val_t and isinstance(inherited[key], dict):
                inherited[key] = {k: v for k, v in inherited[key].items() if k != "file"}
        # a validation log of the other kind (a bag for a CSV, a CSV for a bag) inherits no keys of that kind
        if isinstance(val_t["file"], str) and isinstance(data_t.get("file"), str):
            val_bag = _reads_bag(_path(val_t["file"], "validation.file", data_base), {**data_t, **val_t})
            if val_bag != _reads_bag(_path(data_t["file"], "data.file", data_base), data_t):
                for key in ("topic", "header", "time", "sample_rate_hz"):
                    inherited.pop(key, None)
                for key in ("position", "effort", "velocity"):
                    if isinstance(inherited.get(key), dict):
                        inherited[key] = {k: v for k, v in inherited[key].items() if k != "topic"}
    return {**inherited, **val_t}


def _validation_pair(data_t: dict[str, Any], val_t: dict[str, Any], data_base: Path) -> tuple[DataConfig, DataConfig]:
    """The single [data] / [validation] pair (with [[...]] arrays: their first entries)."""
    data_t = _table(data_t, "data", _DATA_KEYS)
    merged = _inherit(data_t, val_t, data_base)
    data = _parse_data(data_t, "data", data_base)
    validation = _parse_data(merged, "validation", data_base)
    if set(validation.files()) == set(data.files()):
        if validation.rows is None and validation.time_window is None:
            raise ConfigError("validation: uses the training file without 'rows' or 'time_window'; hold out samples")
        if data.rows is None and data.time_window is None:
            raise ConfigError("data: training uses the whole file that validation also reads; set data.rows or data.time_window")
        if (data.rows is None) != (validation.rows is None):
            raise ConfigError("data and validation windows must both be 'rows' or both 'time_window'")
        a, b = (data.rows, validation.rows) if data.rows is not None else (data.time_window, validation.time_window)
        if a[0] < b[1] and b[0] < a[1]:
            raise ConfigError(f"validation window {list(b)} overlaps the training window {list(a)}")
    return data, validation


def data_root(doc: Mapping[str, Any], base_dir: Path) -> Path:
    """``data_root``: the folder the logs' relative paths start from (``${VAR}`` expanded; itself relative
    to the config file); without it, the config file's folder."""
    if "data_root" not in doc:
        return base_dir
    root = _path(doc["data_root"], "data_root", base_dir)
    if not root.is_dir():
        raise ConfigError(f"data_root: {root} is {'not a folder' if root.exists() else 'not found'}")
    return root


def _learning(t: Any):
    from dynid.config.learning import parse_learning  # its own module (and dynid.learning's defaults)

    return parse_learning(t)


def load_config(path: str | Path) -> Config:
    """Read and validate a TOML configuration file."""
    path = Path(path)
    doc = read_toml(path)
    return parse_config(doc, path.resolve().parent, source=path.resolve())
