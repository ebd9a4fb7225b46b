"""The reference motion of a virtual experiment (``dynid simulate``'s ``[trajectory]``): the box of the
coordinates it may use, a Fourier / quintic / circle / polyline / constant-velocity reference or a
design's file replayed, and the check that it stays within the limits. Split from
:mod:`dynid.pipeline.simulate`, which re-exports :func:`_trajectory` and :func:`_coordinate_box`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dynid.config.simulate import SimulateConfig
from dynid.errors import ConfigError, InputError, read_file_text
from dynid.model.mechanism import JointCoordinates, Mechanism
from dynid.trajectories import (CirclePath, ConstantVelocityExperiment, Embedded, FourierQuintic, FourierTrajectory,
                                PolylinePath, Repeated)


def _coordinate_box(robot) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Range of the independent coordinates: joint limits (serial robots, joint coordinates
    of a mechanism, centred on the assembled reference) or +-one link length (points)."""
    if not isinstance(robot, Mechanism):
        lo, hi = robot.position_limits()
        return lo, hi, list(robot.joint_names)
    u0 = robot.coordinates(robot.q_ref)[0]
    ind = robot.independent
    lo_j, hi_j = robot.position_limits()
    if isinstance(ind, JointCoordinates):
        half = np.array([min(u0[k] - lo_j[j], hi_j[j] - u0[k]) for k, j in enumerate(ind.joints)])
        names = [robot.pin_model.names[j + 1] for j in ind.joints]
    else:
        steps = [np.linalg.norm(robot.pin_model.jointPlacements[j].translation) for j in range(1, robot.pin_model.njoints)]
        half = np.full(ind.size, 0.5 * float(np.mean(steps)))
        names = [f"{'xyz'[a]}" for a in ind.axes]
    half = np.where(np.isfinite(half), half, 1.0)
    return u0 - half, u0 + half, names


def _trajectory(cfg: SimulateConfig, robot, rng: np.random.Generator | None = None):
    """The commanded trajectory of ``[trajectory]`` and the names of its coordinates; ``rng``: the
    generator of a random Fourier series (None: one of ``trajectory.seed``)."""
    tc = cfg.trajectory
    v = tc.values
    lo, hi, names = _coordinate_box(robot)
    n_u = lo.size
    if tc.kind == "constant_velocity":
        return _constant_velocity(v, robot, lo, hi, names, cfg.base_dir), names
    if "design" in v and tc.kind in ("circle", "fourier"):  # what `dynid design` wrote (its design.json)
        traj = _design_trajectory(cfg, names, tc.kind)
        if isinstance(traj, FourierTrajectory) and v["periods"] > 1:
            return Repeated(traj, v["periods"]), names
        if not isinstance(traj, FourierTrajectory) and tc.kind == "fourier" and v["periods"] > 1:
            raise ConfigError("trajectory.periods: a rest-to-rest (quintic) design has one period")
        return traj, names
    if tc.kind in ("circle", "polyline"):
        dim = 2 if tc.kind == "circle" else len(v["vertices"][0])
        axes = v.get("axes")
        if axes is not None:
            unknown = [a for a in axes if a not in names]
            if unknown or len(axes) != dim:
                raise ConfigError(f"trajectory.axes must name {dim} of the coordinates {names}; got {list(axes)}")
        elif n_u != dim:
            raise ConfigError(
                f"trajectory.kind = {tc.kind!r} is a path of {dim} coordinates but the robot has {n_u} independent "
                f"coordinates ({', '.join(names)}); name the ones it drives with trajectory.axes"
            )
        if tc.kind == "circle":
            traj = CirclePath(v["centre"], v["radius"], v["speed"], turns=v["turns"], clockwise=v["clockwise"], ramp=v["ramp"])
        else:
            if len({len(p) for p in v["vertices"]}) != 1:
                raise ConfigError("trajectory.vertices: every vertex needs the same number of coordinates")
            traj = PolylinePath(np.array(v["vertices"]), v["speed"], ramp=v["ramp"])
        if axes is not None:
            rest = robot.coordinates(robot.q_ref)[0] if isinstance(robot, Mechanism) else 0.5 * (lo + hi)
            traj = Embedded(traj, tuple(names.index(a) for a in axes), rest)
        return traj, names
    rng = np.random.default_rng(v["seed"]) if rng is None else rng
    try:
        four = FourierTrajectory.random(n_u, v["harmonics"], v["base_frequency_hz"], rng, lo, hi,
                                        max_velocity=v["max_velocity"], max_acceleration=v["max_acceleration"],
                                        fill=v["fill"], rest_to_rest=bool(v["quintic"]))
    except InputError as exc:
        raise ConfigError(f"trajectory: {exc}") from None
    if v["quintic"]:
        return FourierQuintic(four), names
    return (Repeated(four, v["periods"]) if v["periods"] > 1 else four), names


def _check_reference_limits(traj, duration: float, dt: float, robot, names: list[str]) -> None:
    """Refuse a commanded trajectory that leaves a serial robot's joint limits.

    The Fourier series is fitted inside the limits, but what the controller is asked to follow is
    the whole reference: the quintic of a rest-to-rest trajectory (``quintic = true``, paper 003
    Sec. 4.2) adds a polynomial whose size grows with the period (it cancels the series' velocity
    and acceleration at both ends), and a design or path can be scaled past the range. The
    reference is sampled on the control grid and compared with the joint limits (to 1e-9)."""
    lo, hi = robot.position_limits()
    t = np.arange(0.0, duration + 0.5 * dt, dt)
    q = np.asarray(traj.sample(t)[0], dtype=float)
    tol = 1e-9
    bad = []
    for k, name in enumerate(names):
        qmin, qmax = float(q[:, k].min()), float(q[:, k].max())
        if (np.isfinite(lo[k]) and qmin < lo[k] - tol) or (np.isfinite(hi[k]) and qmax > hi[k] + tol):
            bad.append(f"{name} reaches [{qmin:.4g}, {qmax:.4g}] outside [{lo[k]:.4g}, {hi[k]:.4g}]")
    if bad:
        hint = (" (the rest-to-rest quintic grows with the period: raise base_frequency_hz or lower fill)"
                if isinstance(traj, FourierQuintic) else "")
        raise ConfigError(f"trajectory: the commanded motion leaves the joint limits: {'; '.join(bad)}{hint}")


def _constant_velocity(v: dict, robot, lo: np.ndarray, hi: np.ndarray, names: list[str],
                       base_dir: Path = Path(".")) -> ConstantVelocityExperiment:
    """``kind = "constant_velocity"``: paper 003's friction experiment on a serial robot."""
    if isinstance(robot, Mechanism):
        raise ConfigError("trajectory.kind = 'constant_velocity' is for serial robots: an actuator of a closed chain "
                          "cannot move alone (passive joints move with it, and their friction enters every actuator "
                          "force, so (tau(q, v) - tau(q, -v)) / 2 is no single joint's friction)")
    if "design" in v:
        return _constant_velocity_design(Path(v["design"]), base_dir, lo, hi, names)
    joints = v.get("joints") or tuple(names)
    unknown = [j for j in joints if j not in names]
    if unknown:
        raise ConfigError(f"trajectory.joints: {unknown} are not joints of {robot.name!r} ({', '.join(names)})")
    finite = np.isfinite(lo) & np.isfinite(hi)
    pose = np.where(finite, 0.5 * (lo + hi), 0.0)
    if "pose" in v:
        if len(v["pose"]) != len(names):
            raise ConfigError(f"trajectory.pose has {len(v['pose'])} entries; {robot.name!r} has {len(names)} joints")
        pose = np.array(v["pose"], dtype=float)
        outside = [f"{n} = {p:g} not in [{a:g}, {b:g}]" for n, p, a, b in zip(names, pose, lo, hi) if not a <= p <= b]
        if outside:
            raise ConfigError(f"trajectory.pose: outside the joint limits: {'; '.join(outside)}")
    keys = {k: v[k] for k in ("speeds", "window", "max_acceleration", "switch", "rest", "repetitions") if k in v}
    try:
        return ConstantVelocityExperiment(pose=pose, lower=lo, upper=hi, joints=tuple(names.index(j) for j in joints),
                                          names=tuple(names), **keys)
    except InputError as exc:
        raise ConfigError(f"trajectory: {exc}") from None


def _constant_velocity_design(path: Path, base_dir: Path, lo: np.ndarray, hi: np.ndarray,
                              names: list[str]) -> ConstantVelocityExperiment:
    """The experiment a ``dynid design`` of ``kind = "constant_velocity"`` sized (its design.json),
    rebuilt with the same generator and the same numbers (JSON floats round-trip)."""
    path = path if path.is_absolute() else base_dir / path
    text = read_file_text(path, "design file")
    try:
        doc = json.loads(text)
        traj = doc["trajectory"]
        if not isinstance(traj, dict):
            raise ValueError("'trajectory' must be an object")
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: not a design.json of dynid design ({exc})") from None
    if traj.get("kind") != "constant_velocity":
        raise ConfigError(f"{path}: a {traj.get('kind')!r} design; trajectory.kind = 'constant_velocity' replays "
                          "constant_velocity designs")
    try:
        if list(traj["names"]) != list(names):
            raise ConfigError(f"{path}: the design is for the joints {traj['names']}, the simulated robot has {names}")
        lower, upper = np.array(traj["lower"], dtype=float), np.array(traj["upper"], dtype=float)
        outside = [n for n, a, b, c, d in zip(names, lower, upper, lo, hi) if a < c or b > d]
        if lower.shape != lo.shape or upper.shape != hi.shape or outside:
            raise ConfigError(f"{path}: the design's position limits leave the joint limits of {outside or names}")
        return ConstantVelocityExperiment(
            pose=np.array(traj["pose"], dtype=float), lower=lower, upper=upper,
            joints=tuple(names.index(j) for j in traj["joints"]),
            plan=tuple(tuple((float(sp), float(w)) for sp, w in p) for p in traj["plan"]),
            max_acceleration=np.array(traj["max_acceleration"], dtype=float), switch=float(traj["switch"]),
            rest=float(traj["rest"]), repetitions=int(traj["repetitions"]), names=tuple(names))
    except ConfigError:
        raise
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise ConfigError(f"{path}: not a constant_velocity design.json of dynid design ({exc})") from None


_DESIGN_KINDS = {"fourier": ("fourier", "fourier_quintic"), "circle": ("circle",)}
"""The ``trajectory`` kinds of a ``dynid design`` design.json that each ``[trajectory] kind`` replays
(``constant_velocity`` designs: :func:`_constant_velocity_design`)."""


def _design_trajectory(cfg: SimulateConfig, names: list[str], kind: str = "fourier"):
    """The trajectory of a ``dynid design`` result (its design.json), as the design evaluated it:
    a periodic Fourier series, the rest-to-rest Fourier + quintic of ``quintic = true``
    (:class:`~dynid.trajectories.FourierQuintic`), or paper 001's circle."""
    path = Path(cfg.trajectory.values["design"])
    path = path if path.is_absolute() else cfg.base_dir / path
    text = read_file_text(path, "design file")
    try:
        doc = json.loads(text)
        traj = doc["trajectory"]
        coords = doc["coordinates"]
        if not isinstance(traj, dict) or not isinstance(coords, list):
            raise ValueError("'trajectory' must be an object and 'coordinates' a list")
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: not a design.json of dynid design ({exc})") from None
    got = traj.get("kind")
    if got not in _DESIGN_KINDS[kind]:
        replay = next((k for k, kinds in _DESIGN_KINDS.items() if got in kinds),
                      "constant_velocity" if got == "constant_velocity" else None)
        hint = f"; replay it with trajectory.kind = {replay!r}" if replay else ""
        raise ConfigError(f"{path}: a {got!r} design; trajectory.kind = {kind!r} replays {' or '.join(_DESIGN_KINDS[kind])} "
                          f"designs{hint}")
    if list(coords) != list(names):
        raise ConfigError(f"{path}: the design moves {coords}, the simulated robot's coordinates are {names} "
                          "(set trajectory.coordinates as the design did)")
    try:
        if got == "circle":
            return CirclePath(tuple(float(x) for x in traj["centre"]), float(traj["radius"]), float(traj["speed"]),
                              turns=float(traj["turns"]), clockwise=bool(traj["clockwise"]), ramp=float(traj["ramp"]))
        four = FourierTrajectory(float(traj["base_frequency_hz"]), np.array(traj["a"], dtype=float),
                                 np.array(traj["b"], dtype=float), np.array(traj["q0"], dtype=float))
        return FourierQuintic(four) if got == "fourier_quintic" else four
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise ConfigError(f"{path}: not a design.json of dynid design (its {got} trajectory: {exc})") from None
