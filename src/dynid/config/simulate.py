"""The configuration of ``dynid simulate``: a strict, typed schema read from TOML.

Sections (all keys optional unless said; unknown keys are errors naming the dotted key):

``[robot]``
    ``model`` (required): anything ``dynid info`` loads (serial or closed-loop);
    ``perturbation``: relative standard deviation of a multiplicative perturbation of the
    true parameters (body parameters and joint terms) away from the model's nominal values
    (default 0: the truth is the nominal model); ``perturbation_seed``; ``rotor_inertia``
    (serial robots: one per joint, reflected to the joint side [kg·m² or kg], the nominal and
    true ``Ia``; a URDF has no element for it), ``actuated`` and ``independent`` (mechanisms).
``[robot.friction]``
    Ground-truth friction replacing the linear joint terms of the joints of a serial robot or
    the actuated joints of a parallel one (passive joints keep theirs): ``model`` =
    ``"coulomb_viscous"`` (``fc``, ``fv``, optional ``fc_neg``, ``fv_neg``, ``offset``),
    ``"stribeck"`` (paper 000 Eq. 32: ``fc``, ``fs``, ``fv``, ``vs``, ``delta``), ``"power_law"``
    or ``"smooth_stribeck"`` (paper 003: ``fc``, ``fv``, ``alpha``, ``offset`` / ``fc``, ``fs``,
    ``fv``, ``vs``, ``kv``, ``alpha``); any model (serial robots) may add ``memory``: the time
    constant [s] (> 0, one or one per joint) of a friction with memory whose steady state is that
    model (Hess & Soom's frictional memory as a first-order lag,
    :class:`dynid.model.friction.FrictionMemory`; the plant integrates the friction state).
``[robot.payload]``
    A load rigidly attached to one body of the true robot: ``body``, the pinocchio joint name
    whose body carries it (serial robots: default the last body; mechanisms: default the
    platform, i.e. the joint of the last task coordinate, when the mechanism declares task
    coordinates, otherwise required; a massless virtual body is refused), ``mass`` [kg],
    ``com`` [m] and principal ``inertia`` about the centre of mass [kg·m²] in that joint's
    frame. The controller's models (``control.model``) do not know the payload.
``[trajectory]``
    ``coordinates``: ``"independent"`` (default: the robot's independent coordinates) or
    ``"task"`` (the platform pose of a parallel robot that declares one: x, y, z and the
    z-y-x angles; the commanded angular velocity of paper 004, Eq. 16 is logged too);
    ``kind`` (required): ``"circle"`` (``centre``, ``radius``, ``speed``, ``turns``,
    ``clockwise``, ``ramp``; or ``design``: the ``design.json`` of ``dynid design``'s
    ``kind = "circle"``), ``"polyline"`` (``vertices``, ``speed``, ``ramp``) — with
    ``axes`` (coordinate names) when the robot has more coordinates than the path, the others
    staying at the reference assembly — or
    ``"fourier"`` (``base_frequency_hz``, ``harmonics``, ``fill``: fraction of the half range
    of each coordinate, ``max_velocity``, ``max_acceleration``, ``periods``, ``quintic``:
    rest-to-rest Fourier + quintic, ``seed``; or ``design``: the ``design.json`` of
    ``dynid design``, whose coefficients, coordinates and rest-to-rest quintic (if designed) are
    used, with ``periods`` for a periodic design), or
    ``"constant_velocity"`` (serial robots: the friction experiment of paper 003, Sec. 3.1, one
    joint at a time: ``joints`` (names, default all), ``speeds`` [rad/s or m/s] (default sixteen
    log-spaced from 0.002 to 0.8), ``window`` [s] (each constant-velocity window, default 2),
    ``pose`` (where the joints are held and each stroke centred, default the middle of the
    limits), ``max_acceleration`` (default 5), ``switch`` (shortest switching phase [s],
    default 0.1), ``rest`` [s] (default 0.3), ``repetitions`` (default 1); the log gains the
    columns ``cv_joint``, ``cv_speed``, ``cv_direction``, ``cv_repetition``, see
    :mod:`dynid.trajectories.constant_velocity`; or ``design``: the ``design.json`` of ``dynid
    design`` with ``kind = "constant_velocity"``, whose schedule is replayed as designed, alone).
    Circles and polylines are paths of the
    independent coordinates of a planar mechanism (its end-effector); Fourier series run
    in the independent coordinates (the joints of a serial robot).
``[control]``
    ``kind``: ``"computed_torque"`` (default: computed torque in the independent coordinates;
    for a mechanism the model-based control of :class:`~dynid.simulation.closed_loop.AugmentedPD`),
    ``"pid"`` (independent joint PID; for a mechanism a decentralized PID per actuator on the
    actuator positions that the mechanism's kinematics give for the reference, paper 002,
    Section 5.4) or ``"feedforward_pid"`` (the model's joint or actuator forces along the
    reference plus that PID, paper 002, Section 5.4, Figs. 10–12); ``rate_hz`` (default 1000);
    ``kp``, ``kd``, ``ki`` (numbers or lists: one per independent coordinate for computed
    torque, one per joint / actuator for the PIDs); ``model``: the controller's model,
    ``"nominal"`` (default), ``"true"`` (the robot's true parameters) or the path of a
    ``result.json`` of ``dynid identify`` (or its folder), relative to this file: its base
    parameters mapped to the standard vector closest to the nominal one (any standard vector
    with the same base parameters gives the same forces); a Stribeck result is refused;
    ``distribution`` for redundant actuation (default ``"min_norm_local_friction"``, Shang
    2009: how computed torque and the feedforward share the forces among the actuators);
    ``substeps`` (RK4 steps per period, default 4).
``[sensors]``
    ``log_rate_hz`` (default: the control rate, which it must divide), ``encoder_resolution``,
    ``position_noise_std``, ``force_noise_std``, ``force_correlation`` (one correlation
    coefficient between all actuators) or ``force_covariance`` (full matrix),
    ``torque_constants`` (log currents), ``time_jitter_std``, ``seed``.
``[simulation]``
    ``duration`` [s] (default: the trajectory's).
``[output]``
    ``format``: ``"csv"`` (default) or ``"npz"``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config import (_bool, _int, _list, _num, _num_or_list, _str, _table, joint_name_list, read_toml,
                          rotor_inertia_list)
from dynid.errors import ConfigError

__all__ = [
    "ControlSimConfig",
    "RobotSimConfig",
    "SensorsConfig",
    "SimulateConfig",
    "TrajectoryConfig",
    "load_simulate_config",
    "parse_simulate_config",
]

_TRAJ_KEYS = {
    "circle": {"centre", "radius", "speed", "turns", "clockwise", "ramp", "axes", "design"},
    "polyline": {"vertices", "speed", "ramp", "axes"},
    "fourier": {"base_frequency_hz", "harmonics", "fill", "max_velocity", "max_acceleration", "periods", "quintic", "seed", "design"},
    "constant_velocity": {"joints", "speeds", "window", "pose", "max_acceleration", "switch", "rest", "repetitions", "design"},
}


@dataclasses.dataclass(frozen=True)
class RobotSimConfig:
    model: str
    perturbation: float = 0.0
    perturbation_seed: int = 0
    friction: Mapping[str, Any] | None = None
    payload: Mapping[str, Any] | None = None
    actuated: tuple[str, ...] | None = None  # mechanisms: as [robot] actuated / independent of dynid identify
    independent: tuple[str, ...] | None = None
    rotor_inertia: tuple[float, ...] | None = None  # serial robots: as [robot] rotor_inertia of dynid identify


@dataclasses.dataclass(frozen=True)
class TrajectoryConfig:
    kind: str
    values: Mapping[str, Any]


@dataclasses.dataclass(frozen=True)
class ControlSimConfig:
    kind: str = "computed_torque"
    rate_hz: float = 1000.0
    kp: tuple[float, ...] | float = 400.0
    kd: tuple[float, ...] | float = 40.0
    ki: tuple[float, ...] | float = 0.0
    model: str = "nominal"
    distribution: str = "min_norm_local_friction"
    substeps: int = 4


@dataclasses.dataclass(frozen=True)
class SensorsConfig:
    log_rate_hz: float | None = None
    encoder_resolution: tuple[float, ...] | float | None = None
    position_noise_std: tuple[float, ...] | float = 0.0
    force_noise_std: tuple[float, ...] | float = 0.0
    force_correlation: float = 0.0
    force_covariance: tuple[tuple[float, ...], ...] | None = None
    torque_constants: tuple[float, ...] | None = None
    time_jitter_std: float = 0.0
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class SimulateConfig:
    robot: RobotSimConfig
    trajectory: TrajectoryConfig
    control: ControlSimConfig
    sensors: SensorsConfig
    duration: float | None
    output_format: str
    base_dir: Path
    source: Path | None
    raw: Mapping[str, Any]


FRICTION_MODELS = {
    "coulomb_viscous": ({"fc", "fv"}, {"fc_neg", "fv_neg", "offset"}),
    "stribeck": ({"fc", "fs", "fv", "vs"}, {"delta"}),
    "power_law": ({"fc", "fv", "alpha"}, {"offset"}),
    "smooth_stribeck": ({"fc", "fs", "fv", "vs", "kv"}, {"alpha"}),
}
"""Ground-truth friction models of ``[robot.friction]``: required and optional coefficients
(numbers or one per joint / actuator; see :mod:`dynid.model.friction`)."""


def _parse_friction(t: Any) -> dict[str, Any]:
    where = "robot.friction"
    keys = {"model", "memory"} | set().union(*(a | b for a, b in FRICTION_MODELS.values()))
    t = _table(t, where, keys, {"model"})
    model = _str(t["model"], f"{where}.model", tuple(FRICTION_MODELS))
    required, optional = FRICTION_MODELS[model]
    missing = sorted(required - set(t))
    extra = sorted(set(t) - {"model", "memory"} - required - optional)
    if missing:
        raise ConfigError(f"{where}: model {model!r} needs {missing}")
    if extra:
        raise ConfigError(f"{where}: keys {extra} do not apply to model {model!r}")
    out: dict[str, Any] = {"model": model}
    for k, v in t.items():
        if k == "model":
            continue
        sign = _FRICTION_SIGN.get(k)
        out[k] = _num_or_list(v, f"{where}.{k}", sign == "positive", minimum=0.0 if sign == "nonnegative" else None)
    return out


_FRICTION_SIGN = {"memory": "positive", "fc": "nonnegative", "fv": "nonnegative", "fs": "nonnegative", "fv_neg": "nonnegative",
                  "vs": "positive", "delta": "positive", "alpha": "positive", "kv": "positive"}
"""Physical sign of each friction coefficient (``fc_neg``, the force at negative velocity, and
``offset`` may have either sign)."""


def _parse_payload(t: Any) -> dict[str, Any]:
    where = "robot.payload"
    t = _table(t, where, {"body", "mass", "com", "inertia"}, {"mass"})
    inertia = _list(t.get("inertia", [0.0, 0.0, 0.0]), f"{where}.inertia", lambda v, w: _num(v, w, minimum=0.0), 3)
    big = max(inertia)
    if big > sum(inertia) - big + 1e-9 * big:
        raise ConfigError(f"{where}.inertia {list(inertia)}: principal moments must satisfy the triangle inequality "
                          "(each at most the sum of the other two); no rigid body has these")
    body = {"body": _str(t["body"], f"{where}.body")} if "body" in t else {}
    return {
        **body,
        "mass": _num(t["mass"], f"{where}.mass", True),
        "com": _list(t.get("com", [0.0, 0.0, 0.0]), f"{where}.com", _num, 3),
        "inertia": inertia,
    }


def _parse_trajectory(t: Any) -> TrajectoryConfig:
    t = _table(t, "trajectory", {"kind", "coordinates"} | set().union(*_TRAJ_KEYS.values()), {"kind"})
    kind = _str(t["kind"], "trajectory.kind", tuple(_TRAJ_KEYS))
    extra = sorted(set(t) - {"kind", "coordinates"} - _TRAJ_KEYS[kind])
    if extra:
        raise ConfigError(f"trajectory: keys {extra} do not apply to kind {kind!r}; it takes {sorted(_TRAJ_KEYS[kind])}")
    v: dict[str, Any] = {"coordinates": _str(t.get("coordinates", "independent"), "trajectory.coordinates", ("independent", "task"))}
    w = "trajectory"
    if kind == "circle" and "design" in t:  # the circle `dynid design` evaluated (its design.json)
        given = sorted(set(t) - {"kind", "coordinates", "design"})
        if given:
            raise ConfigError(f"trajectory: {given} are set by the design file; give design alone")
        v["design"] = str(Path(_str(t["design"], f"{w}.design")).expanduser())
    elif kind == "circle":
        for k in ("centre", "radius", "speed"):
            if k not in t:
                raise ConfigError(f"trajectory: a circle needs {k!r}")
        v["centre"] = _list(t["centre"], f"{w}.centre", _num, 2)
        v["radius"] = _num(t["radius"], f"{w}.radius", True)
        v["speed"] = _num(t["speed"], f"{w}.speed", True)
        v["turns"] = _num(t.get("turns", 1.0), f"{w}.turns", True)
        v["clockwise"] = _bool(t.get("clockwise", True), f"{w}.clockwise")
        v["ramp"] = _num(t.get("ramp", 0.2), f"{w}.ramp", True)
    elif kind == "constant_velocity":
        v.update(_parse_constant_velocity(t))
    elif kind == "polyline":
        for k in ("vertices", "speed"):
            if k not in t:
                raise ConfigError(f"trajectory: a polyline needs {k!r}")
        v["vertices"] = _list(t["vertices"], f"{w}.vertices", lambda x, ww: _list(x, ww, _num))
        if len(v["vertices"]) < 2:
            raise ConfigError(f"{w}.vertices: a polyline needs at least 2 vertices, got {len(v['vertices'])}")
        if len({len(p) for p in v["vertices"]}) != 1 or not v["vertices"][0]:
            raise ConfigError(f"{w}.vertices: every vertex needs the same number (>= 1) of coordinates")
        v["speed"] = _num(t["speed"], f"{w}.speed", True)
        v["ramp"] = _num(t.get("ramp", 0.1), f"{w}.ramp", True)
    else:
        v["base_frequency_hz"] = _num(t.get("base_frequency_hz", 0.1), f"{w}.base_frequency_hz", True)
        v["harmonics"] = _int(t.get("harmonics", 5), f"{w}.harmonics", 1)
        v["fill"] = _num(t.get("fill", 0.5), f"{w}.fill", True)
        v["max_velocity"] = _num_or_list(t.get("max_velocity", 1.0), f"{w}.max_velocity", True)
        v["max_acceleration"] = _num_or_list(t.get("max_acceleration", 5.0), f"{w}.max_acceleration", True)
        v["periods"] = _int(t.get("periods", 1), f"{w}.periods", 1)
        v["quintic"] = _bool(t.get("quintic", False), f"{w}.quintic")
        v["seed"] = _int(t.get("seed", 0), f"{w}.seed", 0)
        if "design" in t:  # the optimized excitation of `dynid design` (its design.json)
            p = Path(_str(t["design"], f"{w}.design")).expanduser()
            v["design"] = str(p if p.is_absolute() else p)
            random_keys = sorted({"base_frequency_hz", "harmonics", "fill", "max_velocity", "max_acceleration", "seed"} & set(t))
            if random_keys:
                raise ConfigError(f"trajectory: {random_keys} describe a random series; a design file gives its own coefficients")
            if "quintic" in t:
                raise ConfigError("trajectory.quintic: the design file says whether its excitation is rest-to-rest "
                                  "(dynid design's quintic = true); give design without quintic")
        if v["fill"] > 1:
            raise ConfigError(f"trajectory.fill must be in (0, 1], got {v['fill']}")
        if v["quintic"] and v["periods"] != 1:
            raise ConfigError("trajectory: a rest-to-rest (quintic) Fourier trajectory has one period")
    if kind in ("circle", "polyline") and "axes" in t:
        v["axes"] = _list(t["axes"], f"{w}.axes", _str)
    return TrajectoryConfig(kind, v)


def _parse_constant_velocity(t: Mapping[str, Any]) -> dict[str, Any]:
    """The keys of ``kind = "constant_velocity"`` (paper 003, Sec. 3.1; defaults in
    :class:`~dynid.trajectories.constant_velocity.ConstantVelocityExperiment`)."""
    w = "trajectory"
    v: dict[str, Any] = {}
    if "design" in t:  # the experiment `dynid design` sized (its design.json)
        given = sorted(set(t) - {"kind", "coordinates", "design"})
        if given:
            raise ConfigError(f"trajectory: {given} are set by the design file; give design alone")
        v["design"] = str(Path(_str(t["design"], f"{w}.design")).expanduser())
        return v
    if "joints" in t:
        v["joints"] = joint_name_list(t, "joints", w)
    if "speeds" in t:
        speeds = _list(t["speeds"], f"{w}.speeds", lambda x, ww: _num(x, ww, True))
        if not speeds:
            raise ConfigError(f"{w}.speeds: empty list; give the speed levels [rad/s or m/s]")
        twice = sorted({x for x in speeds if speeds.count(x) > 1})
        if twice:
            raise ConfigError(f"{w}.speeds: {twice} given more than once")
        v["speeds"] = speeds
    if "pose" in t:
        v["pose"] = _list(t["pose"], f"{w}.pose", _num)
    for key in ("window", "max_acceleration", "switch"):
        if key in t:
            v[key] = _num(t[key], f"{w}.{key}", True)
    if "rest" in t:
        v["rest"] = _num(t["rest"], f"{w}.rest", minimum=0.0)
    if "repetitions" in t:
        v["repetitions"] = _int(t["repetitions"], f"{w}.repetitions", 1)
    return v


def _parse_control(t: Any) -> ControlSimConfig:
    t = _table(t, "control", {"kind", "rate_hz", "kp", "kd", "ki", "model", "distribution", "substeps"})
    c = ControlSimConfig(
        kind=_str(t.get("kind", "computed_torque"), "control.kind", ("computed_torque", "pid", "feedforward_pid")),
        rate_hz=_num(t.get("rate_hz", 1000.0), "control.rate_hz", True),
        kp=_num_or_list(t.get("kp", 400.0), "control.kp", True),
        kd=_num_or_list(t.get("kd", 40.0), "control.kd", minimum=0.0),
        ki=_num_or_list(t.get("ki", 0.0), "control.ki", minimum=0.0),
        model=_control_model(t.get("model", "nominal")),
        distribution=_str(t.get("distribution", "min_norm_local_friction"), "control.distribution",
                          ("min_norm", "min_norm_local_friction")),
        substeps=_int(t.get("substeps", 4), "control.substeps", 1),
    )
    if "ki" in t and c.kind == "computed_torque":
        raise ConfigError("control.ki applies to kind 'pid' or 'feedforward_pid', not 'computed_torque'")
    return c


def _control_model(value: Any) -> str:
    """``"nominal"``, ``"true"`` or the path of a ``result.json`` as written (relative to the
    config file; resolved where it is read, so that the outputs record it as given)."""
    model = _str(value, "control.model")
    if not model.strip():
        raise ConfigError("control.model: empty; give 'nominal', 'true' or the path of a result.json of dynid identify")
    return model


def _check_covariance(cov: tuple[tuple[float, ...], ...], where: str) -> None:
    import numpy as np

    n = len(cov)
    if n == 0 or any(len(r) != n for r in cov):
        raise ConfigError(f"{where}: expected a square matrix (a list of {n} rows of {n} numbers)")
    c = np.array(cov, dtype=float)
    scale = max(float(np.abs(c).max()), 1e-300)
    if not np.allclose(c, c.T, rtol=0.0, atol=1e-12 * scale):
        raise ConfigError(f"{where}: the matrix is not symmetric")
    w = np.linalg.eigvalsh(c)
    if w[0] < -1e-12 * scale:
        raise ConfigError(f"{where}: not positive semi-definite (smallest eigenvalue {w[0]:.3g}); a covariance cannot be")


def _torque_constants(value: Any) -> tuple[float, ...]:
    k = _list(value, "sensors.torque_constants", _num)
    if not k:
        raise ConfigError("sensors.torque_constants: empty list; give one per actuator")
    zero = [i for i, x in enumerate(k) if x == 0]
    if zero:
        raise ConfigError(f"sensors.torque_constants[{zero[0]}] is 0; currents i = tau / k need non-zero constants")
    return k


def _parse_sensors(t: Any) -> SensorsConfig:
    keys = {f.name for f in dataclasses.fields(SensorsConfig)}
    t = _table(t, "sensors", keys)
    cov = None
    if "force_covariance" in t:
        if "force_noise_std" in t or "force_correlation" in t:
            raise ConfigError("sensors: give force_covariance or force_noise_std/force_correlation, not both")
        cov = _list(t["force_covariance"], "sensors.force_covariance", lambda x, w: _list(x, w, _num))
        _check_covariance(cov, "sensors.force_covariance")
    corr = _num(t.get("force_correlation", 0.0), "sensors.force_correlation")
    if not -1 < corr < 1:
        raise ConfigError(f"sensors.force_correlation must be in (-1, 1), got {corr}")
    return SensorsConfig(
        log_rate_hz=_num(t["log_rate_hz"], "sensors.log_rate_hz", True) if "log_rate_hz" in t else None,
        encoder_resolution=_num_or_list(t["encoder_resolution"], "sensors.encoder_resolution", True)
        if "encoder_resolution" in t else None,
        position_noise_std=_num_or_list(t.get("position_noise_std", 0.0), "sensors.position_noise_std", minimum=0.0),
        force_noise_std=_num_or_list(t.get("force_noise_std", 0.0), "sensors.force_noise_std", minimum=0.0),
        force_correlation=corr,
        force_covariance=cov,
        torque_constants=_torque_constants(t["torque_constants"]) if "torque_constants" in t else None,
        time_jitter_std=_num(t.get("time_jitter_std", 0.0), "sensors.time_jitter_std", minimum=0.0),
        seed=_int(t.get("seed", 0), "sensors.seed", 0),
    )


def parse_simulate_config(doc: Mapping[str, Any], base_dir: Path, source: Path | None = None) -> SimulateConfig:
    """Validate a parsed TOML document (see module docstring)."""
    doc = _table(dict(doc), "config", {"robot", "trajectory", "control", "sensors", "simulation", "output"},
                 {"robot", "trajectory"})
    r = _table(doc["robot"], "robot", {"model", "perturbation", "perturbation_seed", "friction", "payload", "actuated",
                                       "independent", "rotor_inertia"}, {"model"})
    robot = RobotSimConfig(
        model=_str(r["model"], "robot.model"),
        perturbation=_num(r.get("perturbation", 0.0), "robot.perturbation"),
        perturbation_seed=_int(r.get("perturbation_seed", 0), "robot.perturbation_seed", 0),
        friction=_parse_friction(r["friction"]) if "friction" in r else None,
        payload=_parse_payload(r["payload"]) if "payload" in r else None,
        actuated=joint_name_list(r, "actuated", "robot"),
        independent=joint_name_list(r, "independent", "robot"),
        rotor_inertia=rotor_inertia_list(r, "robot"),
    )
    if robot.perturbation < 0:
        raise ConfigError(f"robot.perturbation must be >= 0, got {robot.perturbation}")
    sim = _table(doc.get("simulation", {}), "simulation", {"duration"})
    out = _table(doc.get("output", {}), "output", {"format"})
    model = robot.model
    if not model.startswith("builtin:"):
        p = Path(model).expanduser()
        model = str((p if p.is_absolute() else base_dir / p).resolve())
        robot = dataclasses.replace(robot, model=model)
    return SimulateConfig(
        robot=robot,
        trajectory=_parse_trajectory(doc["trajectory"]),
        control=_parse_control(doc.get("control", {})),
        sensors=_parse_sensors(doc.get("sensors", {})),
        duration=_num(sim["duration"], "simulation.duration", True) if "duration" in sim else None,
        output_format=_str(out.get("format", "csv"), "output.format", ("csv", "npz")),
        base_dir=base_dir,
        source=source,
        raw=doc,
    )


def load_simulate_config(path: str | Path) -> SimulateConfig:
    """Read and validate a ``dynid simulate`` TOML file."""
    path = Path(path)
    doc = read_toml(path)
    return parse_simulate_config(doc, path.resolve().parent, source=path.resolve())
